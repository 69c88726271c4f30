"""The Hele-Shaw pressure solve on the fixed fluid grid (docs/model.md section 2):
the finite-volume system (:mod:`.system`), the pyamg multigrid solve
(:mod:`.solver`, worker processes in :mod:`.pool`), the Taichi geometric-multigrid
CG that is the default where Taichi has float64 (:mod:`.gmg`, with the kernels of
:mod:`._gmg_setup`, :mod:`._gmg_cycle` and :mod:`._gmg_cg`), and exact solutions to
test them against (:mod:`.gallery`). Importing this package does not load Taichi; importing
:mod:`.gmg` does."""
from .gallery import circular_inclusion_error, circular_inclusion_pressure
from .solver import FluxImbalanceError, PressureSolver, SolveInfo
from .system import FiniteVolumeSystem

__all__ = ["FiniteVolumeSystem", "FluxImbalanceError", "PressureSolver", "SolveInfo",
           "circular_inclusion_error", "circular_inclusion_pressure"]
