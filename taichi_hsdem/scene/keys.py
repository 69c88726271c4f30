"""The keys of a scene: one frozen dataclass per TOML table, one field per key.

Each key's kind, unit, allowed range and documentation live in the field's
``metadata["spec"]`` (a :class:`Spec`) and drive both the validation
(:mod:`.load`) and ``docs/scene.md``, so the documentation of a key and its check
cannot drift apart.
"""
from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

from ..geometry.polygon import signed_area
from ..limits import (MAX_FRAMES, MAX_NODES, MAX_OUTLINE_VERTICES, MAX_PARTICLE_VERTICES,
                      MAX_VIDEO_WIDTH)

AUTO = "auto"
#: Packing fractions of all species together must stay below this (docs/scene.md).
MAX_PACKING_FRACTION = 0.6
#: Kozeny-Carman inside a particle needs gap > this * d_eq (docs/scene.md, Conventions).
MIN_GAP_OVER_DEQ = 2.0 / 3.0
#: Every number of a scene (but 0) lies between these in magnitude: products of a
#: few of them, as the derived quantities are, then stay finite and normal in f64.
MIN_MAGNITUDE, MAX_MAGNITUDE = 1e-100, 1e100


class SceneError(ValueError):
    """An invalid scene; ``problems`` lists each one as ``"FILE: key: problem"``."""

    def __init__(self, problems: str | Iterable[str]):
        problems = [problems] if isinstance(problems, str) else problems
        # One line per problem, even when a key or an override holds a newline.
        self.problems = [re.sub(r"[\x00-\x1f\x7f]",
                                lambda m: repr(m.group())[1:-1], p) for p in problems]
        super().__init__("\n".join(self.problems))

    def __str__(self) -> str:
        return "\n".join(self.problems)


# --------------------------------------------------------------------------- keys

@dataclass(frozen=True)
class Spec:
    """What one scene key accepts."""

    kind: str  # "float", "int", "bool", "str", "choice", "points", "poses", "polygons", "interval"
    doc: str
    required: bool = False
    auto: bool = False  # the string "auto" is accepted besides the kind
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] = ()
    min_len: int = 0
    max_len: int | None = None  # arrays: most entries (points: vertices) the run can afford
    only: tuple[str, ...] = ()  # used only by these geometry kinds / particle shapes


def keyfield(kind: str, doc: str, default: Any = None, **spec: Any) -> Any:
    return field(default=default, metadata={"spec": Spec(kind, doc, **spec)})


def key_specs(cls) -> dict[str, Spec]:
    return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls)
            if "spec" in f.metadata}


def document(cls):
    """Append a numpydoc ``Attributes`` section built from the keys' docs."""
    lines = ["", "Attributes", "----------"]
    for name, spec in key_specs(cls).items():
        lines += [name, "    " + spec.doc]
    cls.__doc__ = (cls.__doc__ or "").rstrip() + "\n" + "\n".join(lines) + "\n"
    return cls


class Config:
    """Shared behaviour of the frozen config dataclasses."""

    def replace(self, **changes: Any):
        """A copy with ``changes`` applied (not re-validated; see `Scene.with_values`)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the keys that have a value (lists for tuples, no ``None``)."""
        return {name: _plain(getattr(self, name)) for name in key_specs(type(self))
                if getattr(self, name) is not None}


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


@document
@dataclass(frozen=True)
class RunConfig(Config):
    """``[run]``: duration, time step, realizations, backend."""

    t_end: float = keyfield("float", "physical time to simulate, s", required=True, gt=0)
    dt: float | str = keyfield("float", 'DEM time step, s, or "auto" (dt_safety times the '
                              "critical step 2 / omega_max of the stiffest, lightest normal or tangential "
                                   "contact mode, with rolling friction its rolling spring "
                                   "added)", AUTO, auto=True, gt=0)
    dt_safety: float = keyfield("float", 'fraction of the critical step that dt = "auto" '
                               "uses, dimensionless", 0.15, gt=0, le=1)
    realizations: int = keyfield("int", "independent random realizations run together",
                                1, ge=1)
    seed: int = keyfield("int", "seed of realization 0; realization k uses seed + k", 0,
                        ge=0)
    arch: str = keyfield("choice", "Taichi backend: gpu the first GPU Taichi finds (a "
                        "software driver refused), auto a GPU when present and fast (else "
                        "the CPU), cuda/vulkan/metal/opengl that backend whatever its driver",
                        "cpu", choices=("cpu", "gpu", "auto", "cuda", "vulkan", "metal",
                                        "opengl"))
    precision: str = keyfield("choice", "floating point type of the kernels", "f64",
                             choices=("f64", "f32"))
    stepping: str = keyfield("choice", '"fused": many DEM steps per kernel launch, one '
                            'realization per thread (CPU only); "per_step": three launches '
                            'per step, bodies in parallel; "auto": fused on the CPU',
                            AUTO, choices=("auto", "fused", "per_step"))
    stop_at_clog: bool = keyfield("bool", "stop a realization once it has clogged", True)
    force_dt: bool = keyfield("bool", "accept a dt above the critical step (stability "
                             "studies); the run is then watched and reported unstable", False)


@document
@dataclass(frozen=True)
class FluidConfig(Config):
    """``[fluid]``: the Hele-Shaw pressure solve."""

    enabled: bool = keyfield("bool", "false: no pressure solve, no fluid force", True)
    viscosity: float | None = keyfield("float", "eta, Pa s (required while enabled)", gt=0)
    density: float = keyfield("float", "fluid density, kg/m^3: with the particles' density "
                             "it sets their buoyant weight against the plates "
                             "(particles.plate_friction; 0: dry particles)", 1000.0, ge=0)
    gravity: float = keyfield("float", "gravity normal to the plates, m/s^2 (0: a cell on "
                             "edge, or weightless)", 9.81, ge=0)
    gap: float = keyfield("float", "H, plate spacing and particle thickness, m",
                         required=True, gt=0)
    cell_size: float | str = keyfield("float", 'fluid cell edge, m; "auto": smallest '
                                     "particle d_eq / 6", AUTO, auto=True, gt=0)
    bc: str = keyfield("choice", '"pressure": p_in and p_out; "flow_rate": flow_rate in, '
                      "p_out out", "pressure", choices=("pressure", "flow_rate"))
    p_in: float | None = keyfield("float", 'inlet pressure, Pa (required for bc = "pressure")')
    p_out: float = keyfield("float", "outlet pressure, Pa", 0.0)
    flow_rate: float | None = keyfield("float", "Q through the whole gap, m^3/s (required "
                                      'for bc = "flow_rate")', gt=0)
    update_interval: int | str = keyfield("int", 'DEM steps between pressure solves, or "auto" '
                                         "(the fastest expected particle crosses one fluid "
                                         "cell between solves)", AUTO, auto=True, ge=1)
    resolve_fraction: float = keyfield("float", "re-solve only if more than this fraction "
                                      "of cells changed permeability (0: always), "
                                      "dimensionless", 0.0, ge=0, lt=1)
    solver: str = keyfield("choice", '"gmg": geometric-multigrid CG in Taichi (matrix-free, '
                           "every realization at once, on the device); \"amg\": pyamg's "
                           "Ruge-Stuben CG on the host (the reference); \"auto\": gmg where "
                           "the backend has float64 kernels (CPU, CUDA), else amg", AUTO,
                           choices=("auto", "gmg", "amg"))
    solver_tol: float = keyfield("float", "relative residual of the multigrid solve, "
                                "dimensionless", 1e-6, gt=0, le=1e-2)
    workers: int | str = keyfield("int", "processes that share the realizations' pressure "
                                 'solves; "auto": one per usable CPU, at most one per '
                                 "realization (the answer does not depend on it)", AUTO,
                                 auto=True, ge=1)
    pressure_sampling: str = keyfield("choice", "how a surface node reads the pressure",
                                     "bilinear", choices=("bilinear", "cell"))
    particle_flux: bool | str = keyfield("bool", "conserve the mixture: moving particles "
                                        "carry their volume (div((kappa/eta) grad p) = "
                                        "div(chi v)); false: fluid alone, particles as fixed "
                                        'obstacles (docs/model.md); "auto": true where the pressure '
                                        'solve is "gmg", which holds the implicit coupling, '
                                        'else false', AUTO, auto=True)
    flux_coupling: str = keyfield("choice", "how the particles' carried volume enters the "
                                 'pressure (with particle_flux = true): "implicit": solved '
                                 "together with their velocities over the next fluid "
                                 "interval (stable in a clog; fluid.solver gmg); "
                                 '"lagged": from their velocities at the last solve',
                                 "implicit", choices=("implicit", "lagged"))
    force_update: str = keyfield("choice", "when the pressure force on the particles is "
                                "evaluated: at each pressure solve and held in between "
                                '("solve"), or at every DEM step from the last pressure field '
                                '("step")', "solve", choices=("solve", "step"))
    pair_mobility: bool | str = keyfield(
           "bool", "correct how close particles (surface gap under d_eq) drift together: "
           "a resistance per pair fitted to 3D Stokes pairs of confined spheres "
           "(docs/model.md section 3.5); \"auto\": on where it was measured, the carried "
           "volume with every species' drift_ratio and carried_fraction \"auto\" and d_eq/H "
           "within 0.05 of 0.875", AUTO, auto=True)


_HOURGLASS, _CONVERGING, _POLYGON = ("hourglass",), ("converging",), ("polygon",)
_MICROMODEL = ("micromodel",)


@document
@dataclass(frozen=True)
class GeometryConfig(Config):
    """``[geometry]``: the fluid region; keys of the other kinds are ``None``."""

    kind: str = keyfield("choice", "the outline generator", required=True,
                        choices=("hourglass", "converging", "polygon", "micromodel"))
    wall_cell_size: float | str = keyfield("float", 'wall level-set spacing, m; "auto": '
                                          "smallest d_eq / 10", AUTO, auto=True, gt=0)
    escape_offset: float | None = keyfield("float", "escape line distance downstream of "
                                          "the constriction's exit, m (None: 0.5 max "
                                          "d_eq, resolved by the run)", ge=0)
    # kind = "hourglass"
    length: float | None = keyfield("float", "channel length, m", required=True, gt=0,
                                   only=_HOURGLASS)
    width: float | None = keyfield("float", "channel width, m", required=True, gt=0,
                                  only=_HOURGLASS)
    neck_width: float | None = keyfield("float", "narrowest width, m, < width",
                                       required=True, gt=0, only=_HOURGLASS)
    neck_x: float | None = keyfield("float", "neck position from the inlet, m (default "
                                   "length / 2)", only=_HOURGLASS)
    taper_length: float | None = keyfield("float", "length over which each side narrows, "
                                         "m (default width)", gt=0, only=_HOURGLASS)
    # kind = "converging"
    width_in: float | None = keyfield("float", "upstream channel width, m", required=True,
                                     gt=0, only=_CONVERGING)
    length_in: float | None = keyfield("float", "upstream straight length, m",
                                      required=True, gt=0, only=_CONVERGING)
    angle: float | None = keyfield("float", "convergence half-angle, degrees", 45.0, gt=0,
                                  le=90, only=_CONVERGING)
    constriction_width: float | None = keyfield("float", "W, m, < width_in", required=True,
                                               gt=0, only=_CONVERGING)
    constriction_length: float | None = keyfield("float", "straight constriction length, "
                                                "m", 0.0, ge=0, only=_CONVERGING)
    width_out: float | None = keyfield("float", "outlet channel width, m, >= "
                                      "constriction_width (default width_in)", gt=0,
                                      only=_CONVERGING)
    length_out: float | None = keyfield("float", "outlet channel length, m", required=True,
                                       gt=0, only=_CONVERGING)
    # kind = "polygon"
    outline: tuple[tuple[float, float], ...] | None = keyfield(
           "points", "the fluid region, a simple polygon of [x, y] vertices, m",
           required=True, min_len=3, max_len=MAX_OUTLINE_VERTICES, only=_POLYGON)
    obstacles: tuple[tuple[tuple[float, float], ...], ...] | None = keyfield(
           "polygons", "solid islands inside the outline, polygons of [x, y], m", (),
           max_len=MAX_OUTLINE_VERTICES, only=_POLYGON)
    constriction_x: float | None = keyfield("float", "where escape is measured from, m "
                                           "(None: x of the narrowest section, resolved "
                                           "by the run)", only=_POLYGON)
    # kind = "micromodel" (geometry/micromodel.py; resolved into kind = "polygon")
    pillar_array: str | None = keyfield("choice", "how the pillars are laid out: a square "
                                       "lattice, staggered columns, or at random", "square",
                                       choices=("square", "staggered", "random"),
                                       only=_MICROMODEL)
    pillar_shape: str | None = keyfield("choice", "circle: a polygon of pillar_sides "
                                       "standing for the circle of pillar_diameter; "
                                       "polygon: the regular polygon of pillar_sides around "
                                       "that circle (its inscribed one; 4: a square of side "
                                       "pillar_diameter)",
                                       "circle", choices=("circle", "polygon"),
                                       only=_MICROMODEL)
    rows: int | None = keyfield("int", "pillars per column (staggered: every other column "
                               "holds rows - 1)", required=True, ge=1, only=_MICROMODEL)
    columns: int | None = keyfield("int", "pillar columns (random: rows x columns pillars "
                                  "in their box)", required=True, ge=1, only=_MICROMODEL)
    pillar_diameter: float | None = keyfield("float", "pillar diameter (random: the mean), "
                                            "m", required=True, gt=0, only=_MICROMODEL)
    pillar_spacing: float | None = keyfield("float", "centre-to-centre distance of the "
                                           "pillars, m, > pillar_diameter", required=True,
                                           gt=0, only=_MICROMODEL)
    pillar_sides: int = keyfield("int", "vertices of each pillar's polygon (circle: 8 or "
                                "more; a gap is within 2 r tan^2(pi / (2 sides)) of the "
                                "circles')", 24, ge=3, only=_MICROMODEL)
    diameter_spread: float = keyfield("float", "random arrays: standard deviation of the "
                                     "pillar diameters, a fraction of their mean (cut at 2 "
                                     "sigma)",
                                     0.0, ge=0, lt=0.5, only=_MICROMODEL)
    min_throat: float | None = keyfield("float", "smallest gap between two pillars or a "
                                       "pillar and a wall, m (random: kept, default "
                                       "(pillar_spacing - pillar_diameter) / 2; square, "
                                       "staggered: checked)", gt=0, only=_MICROMODEL)
    inlet_length: float | None = keyfield("float", "pillar-free channel before the array "
                                         "(where particles are fed), m", required=True,
                                         gt=0, only=_MICROMODEL)
    outlet_length: float | None = keyfield("float", "pillar-free channel after the array "
                                          "(where the escape line lies), m", required=True,
                                          gt=0, only=_MICROMODEL)
    pillar_seed: int = keyfield("int", "seed of a random array (the same seed, the same "
                               "array in every realization)", 0, ge=0, only=_MICROMODEL)


_ROUND, _SQUARE, _RECT, _REGULAR = (("circle", "regular_polygon"), ("square",),
                                    ("rectangle",), ("regular_polygon",))


@document
@dataclass(frozen=True)
class SpeciesConfig(Config):
    """One ``[[particles]]`` table; keys of the other shapes are ``None``."""

    name: str = keyfield("str", 'label (default "species<k>")')
    shape: str = keyfield("choice", "particle outline", required=True,
                         choices=("circle", "square", "rectangle", "regular_polygon",
                                  "polygon"))
    diameter: float | None = keyfield("float", "circle diameter, or circumscribed diameter "
                                     "of a regular polygon, m", required=True, gt=0,
                                     only=_ROUND)
    side: float | None = keyfield("float", "square side, m", required=True, gt=0,
                                 only=_SQUARE)
    width: float | None = keyfield("float", "rectangle width, m", required=True, gt=0,
                                  only=_RECT)
    height: float | None = keyfield("float", "rectangle height, m", required=True, gt=0,
                                   only=_RECT)
    n_vertices: int | None = keyfield("int", "vertices of a regular polygon", required=True,
                                     ge=3, le=MAX_PARTICLE_VERTICES, only=_REGULAR)
    vertices: tuple[tuple[float, float], ...] | None = keyfield(
           "points", "body-frame outline [x, y] (recentred on its centroid by the run), m",
           required=True, min_len=3, max_len=MAX_PARTICLE_VERTICES, only=("polygon",))
    diameter_spread: float = keyfield(
           "float", "relative standard deviation of the particle size, dimensionless; 0: "
           "all alike. A spread s > 0 splits the species, when the scene is loaded, into "
           "five equally populated size classes <name>/1 to <name>/5 (smallest first): "
           "ordinary species whose sizes (diameter, side, width and height, or vertices) "
           "are this species' times 1 + s z_k, z_k the mean of a standard normal within "
           "each fifth of its probability (-1.3998, -0.5319, 0, 0.5319, 1.3998) rescaled "
           "to unit standard deviation (-1.4780, -0.5616, 0, 0.5616, 1.4780), so that the "
           "five factors have mean 1 and standard deviation s exactly. count (at least 5) "
           "is split as evenly as possible, the remainder to the middle classes first "
           "(3, 2, 4, 1), packing_fraction into five equal parts, every other key copied; "
           "not with positions. The resolved scene lists the five classes (spread 0, so "
           "that it reruns the same particles) and summary.json counts escapees per class",
           0.0, ge=0, le=0.25)
    count: int | None = keyfield("int", "particles in the control volume (or "
                                "packing_fraction, or positions)", ge=0)
    positions: tuple[tuple[float, float, float], ...] | None = keyfield(
           "poses", "initial [x, y] or [x, y, theta] of every particle of this species "
           "(m, m, rad; theta 0 if left out), instead of a random placement; the same in "
           "every realization, checked against the walls and each other", min_len=1)
    packing_fraction: float | None = keyfield("float", "areal fraction in the control "
                                             "volume (or count), dimensionless", gt=0,
                                             lt=MAX_PACKING_FRACTION)
    density: float = keyfield("float", "kg/m^3", required=True, gt=0)
    kn: float | str = keyfield("float", 'normal stiffness of the prism, N/m; "auto": '
                              "largest driving force / (overlap_target d_eq)", AUTO,
                              auto=True, gt=0)
    ks: float | str = keyfield("float", 'tangential stiffness, N/m; "auto": kn / 2', AUTO,
                              auto=True, ge=0)
    friction: float = keyfield("float", "Coulomb coefficient mu, dimensionless", 0.25,
                              ge=0)
    restitution: float = keyfield("float", "coefficient of restitution e, dimensionless",
                                 0.5, gt=0, le=1)
    nodes: int | str = keyfield("int", 'surface nodes (at least the shape\'s vertices); '
                               '"auto": at most perimeter / 40 apart, and half the thinnest '
                               "part of the scene's particles, on every edge", AUTO,
                               auto=True, ge=3, le=MAX_NODES)
    ls_spacing: float | str = keyfield("float", 'level-set grid spacing, m; "auto": d_eq '
                                      "/ 40, finer where the thinnest part would span "
                                      "fewer than 8 cells", AUTO, auto=True, gt=0)
    xi: float | None = keyfield("float", "global damping of this species, 1/s; unset: "
                               "damping.xi (the resolved scene records each species' value)",
                               None, ge=0)
    permeability: float | str = keyfield(
           "float", 'permeability of the fluid cells a particle covers, m^2; "auto": '
           "Kozeny-Carman of the cell column holding it (docs/model.md section 2.2)", AUTO,
           auto=True, gt=0)
    drift_ratio: float | str = keyfield(
           "float", "speed of a lone particle of this species carried by the flow over the "
           "mean (depth-averaged) fluid speed, dimensionless; sets damping.xi = \"auto\" "
           "(the plate drag); \"auto\": a sphere of diameter d_eq at mid-gap (3D Stokes, "
           "taichi_hsdem/data/sphere_in_gap.csv)", AUTO, auto=True, gt=0, le=2)
    carried_fraction: float | str = keyfield(
           "float", "share of a moving particle's velocity that its cells carry in the "
           "pressure solve (fluid.particle_flux = true), dimensionless: 1 a tracer of the "
           "depth-averaged flow (no disturbance when it drifts at the fluid's speed), 0 a "
           "moving obstacle; \"auto\": the share at which a lone drifting particle, a "
           "disk of d_eq on the fluid grid, leaves the depth-averaged pressure dipole of a "
           "sphere of diameter d_eq at mid-gap (3D Stokes)", AUTO, auto=True, ge=0, le=2)
    spin_drag: float | str = keyfield(
           "float", "viscous torque per unit spin of a particle of this species about the "
           "plates' normal, beyond what the global damping gives (xi I), N m s: implicit in "
           "the integrator, stable at any time step; \"auto\": a sphere of diameter d_eq at "
           "mid-gap spinning between the plates, 8 pi eta (d_eq/2)^3 times its 3D Stokes "
           "factor (taichi_hsdem/data/sphere_spin.csv; below d/H = 0.3 its images' sum), "
           "less xi I, at least 0; 0 without fluid or above the table (d/H > 0.975)", AUTO,
           auto=True, ge=0)
    plate_friction: float = keyfield(
           "float", "Coulomb coefficient between a particle and the plate it rests on, "
           "dimensionless; 0: no plate contact. A particle denser (lighter) than the fluid "
           "settles on the lower (upper) plate and meets a friction force of at most this "
           "times its buoyant weight, |rho_p - rho_f| g pi d_eq^3 / 6, against its sliding "
           "(regularised: below the limit it creeps at 1e-6 d_eq xi times the load over the "
           "limit)", 0.0, ge=0)
    rolling_friction: float = keyfield(
           "float", "rolling friction coefficient mu_r at this species' contacts, "
           "dimensionless (disks only): the contacts resist the relative spin of two disks "
           "(or of a disk on a wall) with a moment of at most mu_r r_eff |F_n| (r_eff = r_i "
           "r_j / (r_i + r_j); r against a wall), elastic below the limit (stiffness k_s "
           "r_eff^2, with a dashpot of the contact's restitution); a pair takes the mean "
           "of its two species'. 0: smooth spheres, no "
           "rolling resistance (docs/model.md section 1.2)", 0.0, ge=0, le=1)

    def area(self) -> float:
        """Area of the shape, m^2."""
        return shape_area(self.shape, dataclasses.asdict(self))

    def d_eq(self) -> float:
        """Equivalent diameter ``sqrt(4 A / pi)``, m."""
        return math.sqrt(4.0 * self.area() / math.pi)


@document
@dataclass(frozen=True)
class ContactConfig(Config):
    """``[contact]``: contact law options."""

    normalize_by_nodes: bool = keyfield("bool", "divide a contact's resultant by its "
                                       "number of nodes in contact (the paper)", True)
    overlap_target: float = keyfield("float", 'overlap kn = "auto" aims at, fraction of '
                                    "d_eq", 0.02, gt=0, le=0.2)
    overlap_limit: float = keyfield("float", "deepest overlap before a realization is "
                                   "stopped as unstable, fraction of d_eq", 0.25, gt=0,
                                   lt=1)
    disk_fast_path: bool = keyfield("bool", "use analytic disk contacts when every particle "
                                   "is a circle (false: level sets for disks too)", True)


@document
@dataclass(frozen=True)
class DampingConfig(Config):
    """``[damping]``: global (plate drag) damping."""

    xi: float | str = keyfield("float", 'global damping, 1/s; "auto": the plate drag',
                              AUTO, auto=True, ge=0)


@document
@dataclass(frozen=True)
class FeedConfig(Config):
    """``[feed]``: where particles start and re-enter."""

    mode: str = keyfield("choice", "keep the particle count, or let the domain empty",
                        "count", choices=("count", "none"))
    region: tuple[float, float] | None = keyfield("interval", "control volume [x0, x1], m "
                                                 "(None: upstream straight section, "
                                                 "resolved by the run)")
    inlet: tuple[float, float] | None = keyfield("interval", "re-entry strip [x0, x1], m "
                                                "(None: first 2 max d_eq of region, "
                                                "resolved by the run)")


@document
@dataclass(frozen=True)
class ClogConfig(Config):
    """``[clog]``: the clog criterion."""

    window: float = keyfield("float", "time without escape that signals a clog, s "
                            "(default 0.1 t_end)", gt=0)
    speed_fraction: float = keyfield("float", "speed threshold near the constriction, "
                                    "fraction of the mean fluid speed", 0.02, gt=0, lt=1)


@document
@dataclass(frozen=True)
class OutputConfig(Config):
    """``[output]``: files written by a run."""

    dir: str = keyfield("str", 'output folder (default "runs/<name>")')
    video: bool = keyfield("bool", "write video.mp4", False)
    video_realization: int = keyfield("int", "which realization the video shows, < "
                                     "run.realizations", 0, ge=0)
    fps: int = keyfield("int", "video frame rate, 1/s", 30, ge=1)
    frames: int = keyfield("int", "frames over t_end (frame 0 is the initial state; at "
                          "most one per step, the run records fewer where t_end has fewer "
                          "steps)", 150, ge=2, le=MAX_FRAMES)
    width: int = keyfield("int", "video width, pixels, even", 960, ge=64, le=MAX_VIDEO_WIDTH)
    series_interval: float = keyfield("float", "time between rows of escapees.csv, s "
                                     "(default t_end / 200)", gt=0)
    vtk: bool = keyfield("bool", "write a ParaView series (series.pvd: particle outlines, "
                         "pressure and permeability) at the video's frame times", False)
    vtk_realizations: str = keyfield("str", 'the realizations the ParaView series holds: '
                                     '"video" (output.video_realization), "all", or '
                                     'indices such as "0,2,5" (each < run.realizations)',
                                     "video")
    checkpoint_every: float = keyfield("float", "wall-clock seconds between checkpoints "
                                       "(checkpoint.npz, also written at the end and when "
                                       "interrupted, also by SIGTERM or SIGHUP; --resume "
                                       "continues one); 0: only then, s",
                                       60.0, ge=0)


def vtk_indices(text: str, realizations: int, video: int) -> list[int]:
    """The realizations ``output.vtk_realizations`` names, sorted; ValueError (its
    message in the user's terms) when it names none or one out of range.

    >>> vtk_indices("2, 0", 4, 1), vtk_indices("video", 4, 1), vtk_indices("all", 3, 0)
    ([0, 2], [1], [0, 1, 2])
    """
    text = text.strip()
    if text == "video":
        return [video]
    if text == "all":
        return list(range(realizations))
    try:
        chosen = sorted({int(part) for part in text.split(",")})
    except ValueError:
        raise ValueError(f'expected "video", "all" or indices such as "0,2,5", got '
                         f"{text[:40]!r}") from None
    if chosen[0] < 0 or chosen[-1] >= realizations:
        raise ValueError(f"indices must lie in [0, {realizations - 1}] (run.realizations = "
                         f"{realizations}), got {text[:40]!r}")
    return chosen


SECTIONS = {"run": RunConfig, "fluid": FluidConfig, "geometry": GeometryConfig,
             "contact": ContactConfig, "damping": DampingConfig, "feed": FeedConfig,
             "clog": ClogConfig, "output": OutputConfig}


# ----------------------------------------------------------------- shape geometry

def shape_area(shape: str, keys: Mapping[str, Any]) -> float:
    if shape == "circle":
        return math.pi * keys["diameter"] ** 2 / 4.0
    if shape == "square":
        return keys["side"] ** 2
    if shape == "rectangle":
        return keys["width"] * keys["height"]
    if shape == "regular_polygon":
        n, radius = keys["n_vertices"], keys["diameter"] / 2.0
        return 0.5 * n * radius ** 2 * math.sin(2.0 * math.pi / n)
    return abs(signed_area(keys["vertices"]))


def shape_vertex_count(shape: str, keys: Mapping[str, Any]) -> int:
    fixed = {"circle": 0, "square": 4, "rectangle": 4}
    if shape in fixed:
        return fixed[shape]
    return keys["n_vertices"] if shape == "regular_polygon" else len(keys["vertices"])
