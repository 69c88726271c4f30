"""The resolved set-up of a scene (:class:`Model`, :class:`Species`), the
constants of the ``auto`` rules, and the bookkeeping of one resolution: the values
it fills in, the reasons it records, the problems it finds."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..geometry import shapes as shp
from ..geometry import walls as wl
from ..geometry.wallfield import WallField
from ..scene import Scene, SceneError

# Resolution limits: below these a particle (or the constriction) is not seen by
# the grid that has to represent it.
MIN_FLUID_CELLS_PER_DIAMETER = 2.0
MIN_WALL_CELLS_PER_DIAMETER = 4.0
MIN_LS_CELLS_PER_DIAMETER = 5.0
MIN_FLUID_CELLS_ACROSS_CONSTRICTION = 3.0
# fluid.cell_size = "auto": the smallest particle's d_eq over this (README,
# Accuracy: the pressure study and tools/convergence.py grid)
FLUID_CELLS_PER_D = 6.0
# Surface nodes and level sets that follow the shape ("auto"; README, Accuracy):
PAPER_NODES = 40              # the paper's count: "auto" spaces nodes at most perimeter / 40
NODE_WIDTH_FRACTION = 1.0     # and at most this fraction of the thinnest part of any
                              # particle of the scene, so an arm that thin crossing an
                              # outline meets one of its nodes (finer changes no force
                              # of tools/convergence.py contact's concave cases);
                              # spaced wider, an explicit count is refused
LS_DIAMETER_CELLS = 40.0      # "auto" level-set spacing: at most d_eq / 40 ...
LS_THINNEST_CELLS = 8.0       # ... and at most the thinnest part / 8
MIN_LS_THINNEST_CELLS = 2.0   # refused: fewer cells across the thinnest part
# Bytes per surface node of a template (positions, lengths, normals, boundary vectors).
NODE_BYTES = 64
# Derived numbers must lie this far inside the kernels' float range.
REPRESENTABLE_MARGIN = 1.0e6

# How often things happen, for the "auto" values decided at the end of resolve().
CHECK_INTERVAL = 100          # steps between host-side checks, at least
CHECK_TRAVEL = 0.05           # with fluid: d_min a particle at the constriction's mean
                              # speed may move between checks (sets a longer interval)
SKIN_FRACTION = 0.25          # Verlet skin as a fraction of the smallest d_eq
UPDATE_CELL_FRACTION = 1.0    # fluid cells a particle may cross between auto-interval solves:
                              # the knee of `tools/convergence.py interval` (vani scene, 100
                              # realizations per point: 0.5 and 1 cell agree, 2 and 3 cells
                              # give fewer escapees; README, Accuracy)
MAX_TRAVEL_BETWEEN_SOLVES = 0.5  # diameters a particle may move between solves, at most
# Plate friction is regularised below the creep speed PLATE_CREEP * d_eq * xi (a
# millionth of a diameter per damping time): a particle held below the Coulomb
# limit creeps at most that fast, 6.5e-4 d/s in the vani scene (xi = 650/s), 0.002 d
# over a 3 s run, against the flow's few d/s; the drag that regularises it,
# limit / creep (1e6 xi times the limit over the load of a free particle), is
# implicit, so its stiffness costs no stability.
PLATE_CREEP = 1.0e-6
# Taichi backends on which "auto" stepping stays per-step (one realization per thread
# would leave a GPU idle).
GPU_ARCHS = ("cuda", "vulkan", "metal", "opengl", "dx11", "dx12", "amdgpu", "gles")


@dataclass
class Species:
    """One particle species with everything the kernels need."""
    name: str
    shape: shp.Shape
    count: int
    density: float
    mass: float
    inertia: float
    d_eq: float
    kn: float
    ks: float
    friction: float
    restitution: float
    xi: float
    kappa: float          # Kozeny-Carman permeability inside the particle (0 without fluid)
    carried: float        # share of its velocity its cells carry in the pressure solve
    ls_spacing: float | None
    spin_drag: float = 0.0  # viscous torque per unit spin beyond xi I, N m s (implicit)
    plate: float = 0.0      # plate friction limit over the mass, N/kg (0: no plate contact)
    creep: float = 0.0      # speed below which plate friction turns viscous, m/s
    rolling: float = 0.0    # rolling friction coefficient (disks only; 0: none)


def has_rolling(species: list[Species]) -> bool:
    """Whether some species has rolling friction (disks only): their shear
    history then keeps each contact's rolling moment beside its force."""
    return any(s.rolling > 0.0 for s in species)


@dataclass
class Model:
    """The resolved set-up of one scene (no Taichi objects)."""
    scene: Scene
    geometry: wl.Geometry
    wall_field: WallField
    species: list[Species]
    species_of_particle: np.ndarray
    all_disks: bool
    dt: float
    dt_crit: float
    x_escape: float
    feed_region: tuple[float, float]
    feed_inlet: tuple[float, float]
    fluid_dx: float | None = None
    fluid_shape: tuple[int, int] | None = None
    fluid_active: np.ndarray | None = None
    fluid_workers: int = 1
    # (N, 3) x, y, theta of the particles with given positions, NaN for the others
    # (placed at random); None when no species gives positions
    initial_poses: np.ndarray | None = None
    kappa_free: float = 0.0
    stepping: str = "per_step"    # "fused" or "per_step" (run.stepping resolved)
    fluid_solver: str = "amg"     # "gmg" or "amg" (fluid.solver resolved)
    check_every: int = CHECK_INTERVAL  # steps between host-side checks
    skin: float = 0.0             # Verlet skin
    pair_mobility: bool = False   # fluid.pair_mobility resolved (dem/pairs.py)
    # mean fluid speed through the constriction of the open channel (no particles)
    open_channel_speed: float | None = None
    notes: dict[str, str] = field(default_factory=dict)

    @property
    def rolling(self) -> bool:
        """Whether some species has rolling friction (:func:`has_rolling`)."""
        return has_rolling(self.species)

    @property
    def n_particles(self) -> int:
        return int(self.species_of_particle.size)

    @property
    def d_min(self) -> float:
        return min(s.d_eq for s in self.species)

    @property
    def d_max(self) -> float:
        return max(s.d_eq for s in self.species)

    def bc(self) -> dict:
        f = self.scene.fluid
        if f.bc == "pressure":
            return {"kind": "pressure", "p_in": f.p_in, "p_out": f.p_out}
        return {"kind": "flow_rate", "Q": f.flow_rate, "p_out": f.p_out}


class _Resolution:
    """The state of one :func:`resolve`: the values it fills into the scene, the
    reasons it records, and the problems it finds (raised together per stage)."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self.src = scene.source
        self.problems: list[str] = []
        self.values: dict = {}
        self.notes: dict[str, str] = {}
        fi = np.finfo(np.float32 if scene.run.precision == "f32" else np.float64)
        # A derived number must sit well inside the kernels' float range (kernels
        # multiply a few of them together).
        self.smallest, self.largest = float(fi.tiny) * REPRESENTABLE_MARGIN, \
            float(fi.max) / REPRESENTABLE_MARGIN

    def bad(self, key: str, msg: str):
        self.problems.append(f"{self.src}: {key}: {msg}")

    def stop_if_bad(self):
        if self.problems:
            raise SceneError(self.problems)

    def note(self, key: str, value, why: str):
        """Record an ``auto`` (or derived) value and why, and fill it into the scene."""
        self.values[key] = value
        self.notes[key] = f"{_show(value)}: {why}"

    def derived(self, what: str, compute, keys: str, unit: str = "",
                squared: bool = False) -> float:
        """``compute()``, a number the kernels hold, checked: finite, positive and
        representable in the run's precision (``squared``: its square too, for the
        stiffnesses and masses the kernels multiply in pairs); else a problem naming
        ``keys`` (the scene keys it comes from) and nan."""
        try:
            value = float(compute())
        except (ArithmeticError, ValueError):
            value = math.inf
        lo, hi = ((math.sqrt(self.smallest), math.sqrt(self.largest)) if squared
                  else (self.smallest, self.largest))
        if math.isfinite(value) and lo <= value <= hi:
            return value
        prec = self.scene.run.precision
        shown = f"{value:.3g}{' ' + unit if unit and math.isfinite(value) else ''}"
        self.bad(keys, f"these values make the {what} {shown}, outside what the "
                       f"{prec} kernels can compute with ({lo:.3g} to {hi:.3g}); use values "
                       "of ordinary size (SI, or dimensionless numbers near 1)")
        return math.nan


def _show(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    return str(value)


def _size_keys(k: int, sp) -> str:
    """The keys that set the size of species ``k``'s shape."""
    keys = {"circle": ("diameter",), "regular_polygon": ("diameter",), "square": ("side",),
            "rectangle": ("width", "height"), "polygon": ("vertices",)}[sp.shape]
    return ", ".join(f"particles[{k}].{name}" for name in keys)
