"""The Hele-Shaw pressure solve on the fixed fluid grid (MODEL.md section 2):
the finite-volume system (:mod:`.system`), its multigrid solve (:mod:`.solver`,
worker processes in :mod:`.pool`), and exact solutions to test it against
(:mod:`.gallery`). Nothing here loads Taichi."""
from .gallery import circular_inclusion_error, circular_inclusion_pressure
from .solver import FluxImbalanceError, PressureSolver, SolveInfo
from .system import FiniteVolumeSystem

__all__ = ["FiniteVolumeSystem", "FluxImbalanceError", "PressureSolver", "SolveInfo",
           "circular_inclusion_error", "circular_inclusion_pressure"]
