"""The Hele-Shaw pressure solve on the fixed fluid grid (MODEL.md section 2)."""
from .solver import (FluxImbalanceError, PressureSolver, SolveInfo, circular_inclusion_error,
                     circular_inclusion_pressure, free_permeability, kozeny_carman)

__all__ = ["FluxImbalanceError", "PressureSolver", "SolveInfo", "circular_inclusion_error",
           "circular_inclusion_pressure", "free_permeability", "kozeny_carman"]
