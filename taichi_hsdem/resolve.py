"""From a validated scene to the numbers a run needs: shapes, walls, fluid grid,
per-species mechanics, and every ``auto`` value with the reason it was chosen.

Everything here is plain numpy and runs before any kernel, so a scene that cannot
work (a grid too coarse for its particles, a time step above the critical step,
particles that do not fit) is refused with a :class:`~taichi_hsdem.scene.SceneError`
naming the key, before any compute is spent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import limits
from .dem.layout import DISK_HISTORY_SLOTS, LS_HISTORY_SLOTS
from .fluid import PressureSolver
from .fluid.pool import usable_cpus
from .geometry import shapes as shp
from .geometry import walls as wl
from .geometry.placement import check_initial, count_for_fraction
from .laws import free_permeability, harmonic_mean, kozeny_carman, restitution_factor
from .limits import Part
from .scene import Scene, SceneError
from .scene.keys import AUTO, MAX_PACKING_FRACTION, shape_vertex_count

# Resolution limits: below these a particle (or the constriction) is not seen by
# the grid that has to represent it.
MIN_FLUID_CELLS_PER_DIAMETER = 2.0
MIN_WALL_CELLS_PER_DIAMETER = 4.0
MIN_LS_CELLS_PER_DIAMETER = 5.0
MIN_FLUID_CELLS_ACROSS_CONSTRICTION = 3.0
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
# Taichi backends on which "auto" stepping stays per-step (one realization per thread
# would leave a GPU idle).
GPU_ARCHS = ("cuda", "vulkan", "metal", "opengl", "dx11", "dx12", "amdgpu", "gles")
# Taichi backends without float64 kernels (the multigrid solve needs them).
F32_ONLY_ARCHS = ("vulkan", "metal", "opengl", "dx11", "dx12", "gles")


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
    ls_spacing: float | None


@dataclass
class Model:
    """The resolved set-up of one scene (no Taichi objects)."""
    scene: Scene
    geometry: wl.Geometry
    wall_field: wl.WallField
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
    # mean fluid speed through the constriction of the open channel (no particles)
    open_channel_speed: float | None = None
    notes: dict[str, str] = field(default_factory=dict)

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


def species_shape(sp, spacing: float | None = None) -> shp.Shape:
    """The shape template of one species table of a scene; ``nodes = "auto"``: at
    most ``spacing`` apart on every edge (:func:`auto_node_spacing`), or without a
    spacing the paper's count (a provisional template to measure the shape on)."""
    n = sp.nodes
    if n == AUTO:
        n = max(PAPER_NODES, shape_vertex_count(sp.shape, sp.to_dict()))
    if sp.shape == "circle":
        t = shp.circle(sp.diameter, n)
    elif sp.shape == "square":
        t = shp.square(sp.side, n)
    elif sp.shape == "rectangle":
        t = shp.rectangle(sp.width, sp.height, n)
    elif sp.shape == "regular_polygon":
        t = shp.regular_polygon(sp.n_vertices, sp.diameter, n)
    else:
        t = shp.polygon(np.asarray(sp.vertices, dtype=float), n)
    if sp.nodes == AUTO and spacing is not None:
        t = shp.respaced(t, spacing)
    return t


def auto_node_spacing(shape: shp.Shape, thinnest: float, depth: float,
                      thinnest_of: str = "") -> tuple[float, str]:
    """``nodes = "auto"``: the largest node spacing that hides nothing, and why.

    At most ``perimeter / PAPER_NODES`` (the paper's count), at most
    ``NODE_WIDTH_FRACTION`` of ``thinnest`` (the thinnest part of any particle of
    the scene: an arm that thin crossing this outline meets one of its nodes; two
    thin arms can then not lie across each other unseen by both, and finer
    spacings change no force of the concave contact study), and for a circle at most
    the spacing whose sagitta is ``depth`` (the overlap target: the surface
    between two nodes lies no deeper). Every vertex, convex or concave, is a node
    and every edge is split into equal intervals, so short edges and concave
    corners are seen and a regular polygon's faces get equal counts.
    ``thinnest_of`` names the particle that ``thinnest`` belongs to, for the reason.
    """
    rules = [(shape.perimeter / PAPER_NODES, f"perimeter / {PAPER_NODES} (the paper's count)"),
             (NODE_WIDTH_FRACTION * thinnest,
              ("" if NODE_WIDTH_FRACTION == 1 else f"{NODE_WIDTH_FRACTION:g} x ")
              + f"the thinnest part of the scene's particles ({thinnest:.4g}{thinnest_of}): "
              "an arm that thin crossing the outline meets a node")]
    if shape.kind == "circle" and depth < shape.radius:
        rules.append((2.0 * shape.radius * math.acos(1.0 - depth / shape.radius),
                      "the surface between two nodes no deeper than contact.overlap_target"))
    return min(rules, key=lambda r: r[0])


def node_gap(shape: shp.Shape) -> float:
    """The longest stretch of outline between two consecutive surface nodes."""
    return float(np.hypot(*(np.roll(shape.nodes, -1, axis=0) - shape.nodes).T).max())


def _geometry(g) -> wl.Geometry:
    if g.kind == "hourglass":
        return wl.hourglass(g.length, g.width, g.neck_width, neck_x=g.neck_x,
                            taper_length=g.taper_length)
    if g.kind == "converging":
        return wl.converging(g.width_in, g.length_in, g.constriction_width, g.length_out,
                             angle=g.angle, constriction_length=g.constriction_length,
                             width_out=g.width_out)
    return wl.from_polygon(np.asarray(g.outline, dtype=float),
                           [np.asarray(o, dtype=float) for o in (g.obstacles or ())],
                           constriction_x=g.constriction_x)


def _driving_pressure(scene: Scene, geom: wl.Geometry, species: list[Species]) -> tuple[float, str]:
    """The largest pressure drop one particle layer is expected to hold (a clog)."""
    f = scene.fluid
    if f.bc == "pressure":
        return abs(f.p_in - f.p_out), "the whole pressure drop |p_in - p_out| held by an arch"
    # Flow-rate inlet: once clogged the whole flow seeps through one particle layer
    # of Kozeny-Carman permeability spanning the constriction.
    d = max(s.d_eq for s in species)
    kp = min(s.kappa for s in species)
    q = f.flow_rate / f.gap
    return (q * f.viscosity * d / (kp * geom.constriction_width),
            "Q/H seeping through one particle layer across the constriction (clogged)")


def node_sagitta(shape: shp.Shape) -> float:
    """Deepest point of the outline between two consecutive surface nodes, below
    their chord: how far another body can sink into this one unseen by its nodes."""
    nodes = shape.nodes
    nxt = np.roll(nodes, -1, axis=0)
    ts = np.linspace(0.0, 1.0, 9)[1:-1]
    pts = nodes[:, None, :] * (1 - ts[None, :, None]) + nxt[:, None, :] * ts[None, :, None]
    # points on the chord inside the body lie below the surface by -phi
    return float(max(0.0, -shp.signed_distance(shape, pts.reshape(-1, 2)).min()))


def critical_time_step(species: list[Species], all_disks: bool, normalize: bool) -> float:
    """``2 / omega_max`` over every species pair and every species against a wall.

    ``omega^2`` is the larger of ``k_n,eff / m_eff`` (normal) and ``k_s,eff / m_t``
    (tangential, ``1/m_t`` adding each body's ``1/m + r_b^2/I``). Without
    normalisation every node of the longest straight edge can be in contact at once.
    """
    if all_disks or normalize:
        factor = 1.0
    else:
        factor = float(max(_face_nodes(s.shape) for s in species))
    omega2 = 0.0
    for a in species:
        inv_ta = 1.0 / a.mass + a.shape.bounding_radius ** 2 / a.inertia
        # against a wall
        omega2 = max(omega2, factor * a.kn / a.mass, factor * a.ks / (1.0 / inv_ta))
        for b in species:
            kn = harmonic_mean(a.kn, b.kn)
            ks = harmonic_mean(a.ks, b.ks)
            meff = a.mass * b.mass / (a.mass + b.mass)
            inv_t = inv_ta + 1.0 / b.mass + b.shape.bounding_radius ** 2 / b.inertia
            omega2 = max(omega2, factor * kn / meff, factor * ks * inv_t)
    return 2.0 / math.sqrt(omega2)


def _face_nodes(s: shp.Shape) -> int:
    if s.kind == "circle":
        return max(1, len(s.nodes) // 8)
    edges = np.linalg.norm(np.roll(s.vertices, -1, axis=0) - s.vertices, axis=1)
    return int(math.ceil(len(s.nodes) * edges.max() / s.perimeter)) + 1


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


def _bounding_box(g) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) of the geometry a scene asks for, from its keys
    alone (before the outline is built)."""
    if g.kind == "hourglass":
        return 0.0, g.length, -g.width / 2, g.width / 2
    if g.kind == "converging":
        taper = 0.0 if g.angle == 90 else \
            (g.width_in - g.constriction_width) / 2 / math.tan(math.radians(g.angle))
        half = max(g.width_in, g.width_out) / 2
        return 0.0, g.length_in + taper + g.constriction_length + g.length_out, -half, half
    pts = np.asarray(g.outline, dtype=float)
    return (float(pts[:, 0].min()), float(pts[:, 0].max()), float(pts[:, 1].min()),
            float(pts[:, 1].max()))


def _grid_nodes(box, h: float, pad: float) -> float:
    """Nodes of a grid of spacing ``h`` over ``box`` grown by ``pad`` on every side."""
    return ((box[1] - box[0] + 2 * pad) / h + 2) * ((box[3] - box[2] + 2 * pad) / h + 2)


def _wall_grid_part(scene: Scene, box, wall_h: float) -> Part:
    nodes = _grid_nodes(box, wall_h, 4 * wall_h)
    what = (f"the wall level set ({nodes:.3g} nodes of {wall_h:.3g} over the "
            f"{box[1] - box[0]:.3g} x {box[3] - box[2]:.3g} channel)")
    g = scene.geometry
    if g.kind == "converging" and box[1] > 100 * (box[3] - box[2]):
        # the channel is long because the taper is
        taper = box[1] - g.length_in - g.constriction_length - g.length_out
        return Part("geometry.angle", what, nodes * limits.WALL_NODE_BYTES,
                    f"a half-angle of {g.angle:g} degrees makes the converging section "
                    f"{taper:.3g} long; use a larger angle")
    need = _cell_for(nodes * wall_h ** 2 * limits.WALL_NODE_BYTES)
    if g.wall_cell_size == "auto":
        k = min(range(len(scene.particles)), key=lambda i: scene.particles[i].d_eq())
        what += (f', its spacing "auto": d_eq / 10 of the smallest particle, particles[{k}] '
                 f"(d_eq {scene.particles[k].d_eq():.3g}),")
    return Part("geometry.wall_cell_size", what, nodes * limits.WALL_NODE_BYTES,
                f"use geometry.wall_cell_size >= {need:.3g}, larger particles, or a "
                "smaller channel")


def _cell_for(area_bytes: float) -> float:
    """The grid spacing at which a grid over an area (given as area x bytes per node)
    uses half the available memory."""
    available = limits.available_memory() or 16e9
    return math.sqrt(area_bytes / (0.5 * limits.MEMORY_FRACTION * available))


def _check_feed(res: _Resolution, geom: wl.Geometry, key: str, strip, d_max: float):
    """A feed strip must lie in the channel and hold fluid a particle fits in."""
    x0, x1 = strip
    if x1 <= geom.x_min or x0 >= geom.x_max:
        res.bad(key, f"[{x0:g}, {x1:g}] lies outside the channel, which spans x = "
                     f"[{geom.x_min:g}, {geom.x_max:g}]")
        return
    lo, hi = max(x0, geom.x_min), min(x1, geom.x_max)
    if wl.fluid_area(geom, lo, hi) < 0.25 * math.pi * d_max ** 2:
        res.bad(key, f"[{x0:g}, {x1:g}] holds less fluid than one particle of d = "
                     f"{d_max:g} covers")


def resolve(scene: Scene, arch: str = "x64") -> Model:
    """Resolve every derived and ``auto`` value of ``scene``; refuse what cannot work.

    ``arch`` is the Taichi backend the run uses (``backend.init``'s answer:
    ``x64``/``arm64`` for the CPU, ``cuda``, ``vulkan``, ...): it decides
    ``run.stepping = "auto"``. Sizes are estimated before anything large is built:
    a scene whose grids and arrays would not fit in memory, or whose step count
    could never finish, is refused with the key to change (:mod:`.limits`).
    """
    # Every derived number is checked (Resolution.derived) and reported in the
    # user's terms: numpy's own overflow warnings would only repeat it on stderr.
    with np.errstate(all="ignore"):
        try:
            return _resolve(scene, arch)
        except ArithmeticError as exc:   # a combination no check above foresaw
            raise SceneError([f"{scene.source}: the scene's numbers overflow or vanish in "
                              f"its derived quantities ({exc}); use values of ordinary size "
                              "(SI, or dimensionless numbers near 1)"]) from None


def _resolve(scene: Scene, arch: str) -> Model:
    res = _Resolution(scene)
    src = scene.source
    budget = limits.available_memory()
    # Shapes: surface nodes are arrays of the node count, before anything is built.
    for k, sp in enumerate(scene.particles):
        if sp.nodes != AUTO:
            part = Part(f"particles[{k}].nodes", f"a template of {sp.nodes} surface nodes",
                        sp.nodes * NODE_BYTES, "use far fewer (40 to a few hundred)")
            res.problems += limits.memory_problems([part], src, budget)
    res.stop_if_bad()
    try:
        templates = [species_shape(sp) for sp in scene.particles]
    except ValueError as exc:
        raise SceneError([f"{src}: particles: {exc}"]) from None
    widths = [shp.thinnest_width(t) for t in templates]   # do not depend on the nodes
    templates = _auto_nodes(res, scene, templates, widths, budget)
    d_eq = [t.equivalent_diameter for t in templates]
    d_min, d_max = min(d_eq), max(d_eq)
    all_disks = scene.contact.disk_fast_path and all(t.kind == "circle" for t in templates)

    # Walls: the grid's size is known from the keys; refuse one that cannot fit
    # before the outline is built.
    g = scene.geometry
    wall_h = d_min / 10.0 if g.wall_cell_size == "auto" else g.wall_cell_size
    if g.wall_cell_size == "auto":
        res.note("geometry.wall_cell_size", wall_h, "smallest particle d_eq / 10")
    elif wall_h > d_min / MIN_WALL_CELLS_PER_DIAMETER:
        res.bad("geometry.wall_cell_size", f"{wall_h:g} is too coarse for particles of "
                f"d = {d_min:g}: use at most d/{MIN_WALL_CELLS_PER_DIAMETER:g} = "
                f"{d_min / MIN_WALL_CELLS_PER_DIAMETER:g}")
    box = _bounding_box(g)
    res.problems += limits.memory_problems([_wall_grid_part(scene, box, wall_h)], src, budget)
    res.stop_if_bad()
    try:
        geom = _geometry(g)
    except ValueError as exc:
        raise SceneError([f"{src}: geometry: {exc}"]) from None
    if geom.constriction_width < d_min:
        res.notes["geometry"] = (f"the constriction ({geom.constriction_width:g}) is narrower "
                                 f"than the smallest particle ({d_min:g}): nothing can pass")
    esc = 0.5 * d_max if g.escape_offset is None else g.escape_offset
    if g.escape_offset is None:
        res.note("geometry.escape_offset", esc, "half the largest particle d_eq")
    else:
        res.values["geometry.escape_offset"] = esc
    x_escape = geom.constriction_x1 + esc
    if x_escape >= geom.x_max:
        res.bad("geometry.escape_offset", f"the escape line x = {x_escape:g} lies beyond the "
                f"outlet x = {geom.x_max:g}")

    # Fluid.
    f = scene.fluid
    kappa_free = (res.derived("free permeability H^2/12", lambda: free_permeability(f.gap),
                              "fluid.gap", "m^2") if f.enabled else 0.0)
    kps = []
    for k, (sp, t) in enumerate(zip(scene.particles, templates)):
        if f.enabled:
            try:
                kps.append(res.derived(
                    f"Kozeny-Carman permeability inside particles[{k}]",
                    lambda: kozeny_carman(t.sphericity, t.equivalent_diameter, t.area, f.gap),
                    f"fluid.gap, {_size_keys(k, sp)}", "m^2"))
            except ValueError as exc:
                res.bad("fluid.gap", f"{exc} (species '{sp.name}')")
                kps.append(kappa_free)
        else:
            kps.append(0.0)
    fluid_dx = None
    if f.enabled:
        fluid_dx = d_min / 6.0 if f.cell_size == "auto" else f.cell_size
        if f.cell_size != "auto" and fluid_dx > d_min / MIN_FLUID_CELLS_PER_DIAMETER:
            res.bad("fluid.cell_size", f"{fluid_dx:g} is too coarse for particles of d = "
                    f"{d_min:g}: a particle must span at least "
                    f"{MIN_FLUID_CELLS_PER_DIAMETER:g} cells (cell_size <= "
                    f"{d_min / MIN_FLUID_CELLS_PER_DIAMETER:g})")
        if geom.constriction_width / fluid_dx < MIN_FLUID_CELLS_ACROSS_CONSTRICTION:
            res.bad("fluid.cell_size", f"{fluid_dx:g} leaves fewer than "
                    f"{MIN_FLUID_CELLS_ACROSS_CONSTRICTION:g} cells across the constriction "
                    f"(width {geom.constriction_width:g})")
        if f.bc == "pressure":
            for key in ("fluid.p_in", "fluid.p_out"):
                value = getattr(f, key.split(".")[1])
                if abs(value) > res.largest:
                    res.bad(key, f"{value:g} is outside what the {scene.run.precision} "
                                 f"kernels can hold (|p| <= {res.largest:.3g})")

    # Species: counts, surface nodes, masses, damping.
    species: list[Species] = []
    if scene.feed.region is not None:
        region = tuple(scene.feed.region)
        res.values["feed.region"] = list(region)
    else:
        region = tuple(geom.upstream_region)
        res.note("feed.region", list(region), "the straight section upstream of the "
                 "constriction")
    _check_feed(res, geom, "feed.region", region, d_max)
    res.stop_if_bad()
    for k, (sp, t, kp) in enumerate(zip(scene.particles, templates, kps)):
        key = f"particles[{k}]"
        if sp.count is not None:
            count = int(sp.count)
        else:
            count = count_for_fraction(sp.packing_fraction, geom, region, t)
            res.values[f"particles.{k}.packing_fraction"] = None
            res.note(f"particles.{k}.count", count, f"packing fraction "
                     f"{sp.packing_fraction:g} of the control volume x in "
                     f"[{region[0]:g}, {region[1]:g}]")
        _check_nodes(res, scene, k, sp, t, widths)
        depth = f.gap if f.gap else 1.0
        mass = res.derived(f"mass of particles[{k}]", lambda: sp.density * t.area * depth,
                           f"{key}.density, {_size_keys(k, sp)}, fluid.gap", "kg",
                           squared=True)
        inertia = res.derived(f"moment of inertia of particles[{k}]",
                              lambda: mass * t.inertia_per_mass,
                              f"{key}.density, {_size_keys(k, sp)}, fluid.gap", "kg m^2")
        ls = _ls_spacing(res, k, sp, t, widths[k], all_disks)
        xi = _damping(res, scene, sp, kp, kappa_free, k)
        species.append(Species(name=sp.name, shape=t, count=count, density=sp.density,
                               mass=mass, inertia=inertia, d_eq=t.equivalent_diameter, kn=0.0,
                               ks=0.0, friction=sp.friction, restitution=sp.restitution,
                               xi=xi, kappa=kp, ls_spacing=ls))
    # "auto" depends on each species' density and permeability: record every
    # species' value, and as damping.xi their count-weighted mean (then unused).
    for k, s in enumerate(species):
        res.values[f"particles.{k}.xi"] = s.xi
    if scene.damping.xi == "auto":
        counts = np.array([max(s.count, 1) for s in species], dtype=float)
        res.values["damping.xi"] = float(np.average([s.xi for s in species], weights=counts))
    if sum(s.count for s in species) == 0:
        res.bad("particles", "the scene has no particles (every count is 0)")
    _check_fit(res, geom, region, scene, species)
    res.stop_if_bad()

    _stiffness(res, scene, geom, species)
    initial = _initial_poses(scene, geom, templates, [s.count for s in species], res.bad)
    res.stop_if_bad()

    # Time step, and how many steps the run takes.
    dt_crit = res.derived("critical time step", lambda: critical_time_step(
        species, all_disks, scene.contact.normalize_by_nodes),
        "particles.kn (with kn = \"auto\": the driving pressure or flow rate), "
        "particles.density", "s")
    res.stop_if_bad()
    if scene.run.dt == "auto":
        dt = scene.run.dt_safety * dt_crit
        res.note("run.dt", dt, f"{scene.run.dt_safety:g} of the critical step {dt_crit:.4g} s")
    else:
        dt = float(scene.run.dt)
        if dt > dt_crit and not scene.run.force_dt:
            raise SceneError([f"{src}: run.dt: {dt:g} s is above the critical time step "
                              f"{dt_crit:.4g} s of the stiffest, lightest contact; use "
                              f"dt <= {scene.run.dt_safety * dt_crit:.4g} s (dt_safety * "
                              f"critical) or dt = \"auto\""])
    _check_steps(res, scene, dt)
    res.stop_if_bad()

    # Memory of everything the run allocates, before any of it is.
    nx = ny = 0
    if f.enabled:
        lx = geom.x_max - geom.x_min
        nx = max(1, int(math.ceil(lx / fluid_dx - 1e-9)))
        ny = max(1, int(math.ceil((geom.y_max - geom.y_min) / (lx / nx) - 1e-9)))
    res.problems += limits.memory_problems(
        _memory_parts(scene, species, all_disks, wall_h, geom, nx * ny), src, budget)
    res.stop_if_bad()

    model = Model(scene=scene, geometry=geom, wall_field=None, species=species,
                  species_of_particle=np.repeat(np.arange(len(species), dtype=np.int32),
                                                [s.count for s in species]),
                  all_disks=all_disks, dt=dt, dt_crit=dt_crit, x_escape=x_escape,
                  feed_region=region, feed_inlet=(0.0, 0.0), kappa_free=kappa_free,
                  initial_poses=initial, notes=res.notes)
    inlet = scene.feed.inlet
    if inlet is None:
        inlet = (region[0], min(region[1], region[0] + 2.0 * d_max))
        res.note("feed.inlet", list(inlet), "the first two largest diameters of feed.region")
    elif scene.feed.mode == "count":
        _check_feed(res, geom, "feed.inlet", inlet, d_max)
        res.stop_if_bad()
    model.feed_inlet = tuple(inlet)
    model.wall_field = wl.make_wall_field(geom, wall_h)
    if f.enabled:
        _fluid_grid(res, model, nx, ny)
    model.skin = SKIN_FRACTION * d_min
    _resolve_stepping(model, arch, res.values, res.notes)
    if f.enabled:
        _resolve_solver(model, arch, res)
        _resolve_intervals(model, res.values, res.notes)
    model.scene = scene.with_values(res.values)
    return model


def _auto_nodes(res: _Resolution, scene: Scene, templates: list[shp.Shape],
                widths: list[float], budget) -> list[shp.Shape]:
    """The templates with ``nodes = "auto"`` respaced (:func:`auto_node_spacing`;
    ``widths``: each template's thinnest part), each choice recorded with its
    reason."""
    if all(sp.nodes != AUTO for sp in scene.particles):
        return templates
    j = int(np.argmin(widths))
    out = []
    for k, (sp, t) in enumerate(zip(scene.particles, templates)):
        if sp.nodes != AUTO:
            out.append(t)
            continue
        depth = scene.contact.overlap_target * t.equivalent_diameter
        thin = f", particles[{j}]" if len(templates) > 1 else ""
        spacing, why = auto_node_spacing(t, widths[j], depth, thin)
        count = (t.perimeter / spacing if t.kind == "circle" else
                 np.ceil(np.hypot(*(np.roll(t.vertices, -1, axis=0) - t.vertices).T)
                         / spacing).sum())
        part = Part(f"particles[{k}].nodes", f'a template of {count:.3g} surface nodes ("auto")',
                    count * NODE_BYTES, "give a count (40 to a few hundred), or make the "
                    "scene's thinnest particle less thin against this one")
        res.problems += limits.memory_problems([part], scene.source, budget)
        res.stop_if_bad()
        t = shp.respaced(t, spacing)
        res.note(f"particles.{k}.nodes", len(t.nodes),
                 f"at most {spacing:.4g} apart on every edge: {why}"
                 + ("" if t.kind == "circle" else "; every vertex a node, each edge in "
                    "equal intervals"))
        out.append(t)
    return out


def _check_nodes(res: _Resolution, scene: Scene, k: int, sp, t: shp.Shape,
                 widths: list[float]) -> None:
    """Refuse a given node count that hides surface between nodes: a circle's arc
    sunk deeper than the overlap target, or a stretch wider than the thinnest part
    of the scene's particles (``widths``, per template: an arm that thin could
    cross it unseen by its nodes). ``"auto"`` meets both by construction."""
    if sp.nodes == AUTO:
        return
    key = f"particles[{k}]"
    target = scene.contact.overlap_target * t.equivalent_diameter
    hidden = node_sagitta(t)
    if hidden > target:
        need = sp.nodes
        while need < 100000 and node_sagitta(species_shape(sp.replace(nodes=need))) > target:
            need *= 2
        res.bad(f"{key}.nodes", f"{sp.nodes} surface nodes leave up to {hidden:.3g} "
                f"({hidden / t.equivalent_diameter:.3g} d) of the surface between two "
                f"nodes, where another body can sink unseen: more than "
                f"contact.overlap_target ({scene.contact.overlap_target:g} d); use about "
                f"{need} nodes or more")
        return
    j = int(np.argmin(widths))
    gap = node_gap(t)
    if gap > widths[j]:
        need = len(shp.respaced(t, min(NODE_WIDTH_FRACTION, 1.0) * widths[j]).nodes)
        res.bad(f"{key}.nodes", f"{sp.nodes} surface nodes leave {gap:.3g} of outline "
                f"between two nodes, more than the thinnest part of the scene's particles "
                f"({widths[j]:.3g}, particles[{j}]): an arm that thin can cross the outline "
                f"there with no node inside it; use about {need} nodes or more, or \"auto\"")


def _ls_spacing(res: _Resolution, k: int, sp, t: shp.Shape, w: float,
                all_disks: bool) -> float:
    """Level-set spacing of species ``k``: given, or ``"auto"``: ``d_eq /
    LS_DIAMETER_CELLS`` and ``LS_THINNEST_CELLS`` cells across the thinnest part
    ``w``; one too coarse for either is refused."""
    key = f"particles[{k}]"
    d = t.equivalent_diameter
    if sp.ls_spacing == AUTO:
        ls = min(d / LS_DIAMETER_CELLS, w / LS_THINNEST_CELLS)
        if all_disks:
            res.note(f"particles.{k}.ls_spacing", ls, "not used: disks take the analytic path")
        elif ls < d / LS_DIAMETER_CELLS:
            res.note(f"particles.{k}.ls_spacing", ls, f"thinnest part ({w:.4g}) / "
                     f"{LS_THINNEST_CELLS:g}: finer than d_eq / {LS_DIAMETER_CELLS:g}")
        else:
            res.note(f"particles.{k}.ls_spacing", ls, f"d_eq / {LS_DIAMETER_CELLS:g} (the "
                     f"thinnest part, {w:.4g}, spans {w / ls:.3g} cells, at least "
                     f"{LS_THINNEST_CELLS:g})")
        return ls
    ls = float(sp.ls_spacing)
    if ls > d / MIN_LS_CELLS_PER_DIAMETER:
        res.bad(f"{key}.ls_spacing", f"{ls:g} is too coarse for a particle of d = "
                f"{d:g}: use at most d/{MIN_LS_CELLS_PER_DIAMETER:g}")
    elif ls > w / MIN_LS_THINNEST_CELLS:
        res.bad(f"{key}.ls_spacing", f"{ls:g} is too coarse for the thinnest part of the "
                f"particle ({w:.3g} across): use at most {w / MIN_LS_THINNEST_CELLS:.3g} "
                f"({MIN_LS_THINNEST_CELLS:g} cells across it), or \"auto\"")
    res.values[f"particles.{k}.ls_spacing"] = ls
    return ls


def _damping(res: _Resolution, scene: Scene, sp, kp: float, kappa_free: float, k: int) -> float:
    """Global damping of species ``k`` (``damping.xi = "auto"``: the plate drag)."""
    f = scene.fluid
    if sp.xi is not None:
        return float(sp.xi)
    if scene.damping.xi != "auto":
        return float(scene.damping.xi)
    keys = f"particles[{k}].density, fluid.viscosity, fluid.gap"
    if f.enabled and f.particle_flux:
        res.notes["damping.xi"] = ("eta / (rho (H^2/12 + kappa_p)): an isolated particle "
                                   "carried by the flow drifts at the mean fluid velocity")
        return res.derived(f"damping of particles[{k}]",
                           lambda: f.viscosity / (sp.density * (kappa_free + kp)), keys, "1/s")
    if f.enabled:
        res.notes["damping.xi"] = ("(1 + beta) eta / (rho H^2/12): an isolated particle held "
                                   "in the pressure solve drifts at the mean fluid velocity")
        beta = (kappa_free - kp) / (kappa_free + kp)
        return res.derived(f"damping of particles[{k}]",
                           lambda: (1.0 + beta) * f.viscosity / (sp.density * kappa_free),
                           keys, "1/s")
    res.notes["damping.xi"] = "no fluid: no plate drag"
    return 0.0


def _stiffness(res: _Resolution, scene: Scene, geom, species: list[Species]) -> None:
    """``kn = "auto"``: the largest driving force over the overlap target; ``ks``
    half of it."""
    f = scene.fluid
    for k, (sp, s) in enumerate(zip(scene.particles, species)):
        if sp.kn == "auto":
            if not f.enabled:
                res.bad(f"particles[{k}].kn", "'auto' needs a driving force, and this scene "
                        "has no fluid: give kn in N/m")
                continue
            dp, why = _driving_pressure(scene, geom, species)
            drivers = ("fluid.p_in, fluid.p_out" if f.bc == "pressure"
                       else "fluid.flow_rate, fluid.viscosity")
            s.kn = res.derived(f"auto contact stiffness of particles[{k}]",
                               lambda: dp * f.gap / scene.contact.overlap_target,
                               f"{drivers}, fluid.gap, contact.overlap_target", "N/m",
                               squared=True)
            if math.isfinite(s.kn):
                res.note(f"particles.{k}.kn", s.kn, f"driving force {dp * s.d_eq * f.gap:.4g} "
                         f"N ({why}) over overlap_target * d_eq")
        else:
            s.kn = res.derived(f"contact stiffness of particles[{k}]", lambda: float(sp.kn),
                               f"particles[{k}].kn", "N/m", squared=True)
        if sp.ks == "auto":
            s.ks = s.kn / 2.0
            if math.isfinite(s.ks):
                res.note(f"particles.{k}.ks", s.ks, "kn / 2")
        else:
            s.ks = float(sp.ks)


def _check_fit(res: _Resolution, geom, region, scene: Scene, species: list[Species]) -> None:
    """Particles given by count must fit in the control volume."""
    area = wl.fluid_area(geom, max(region[0], geom.x_min), min(region[1], geom.x_max))
    solid = sum(s.count * s.shape.area for s in species)
    if area > 0 and solid > MAX_PACKING_FRACTION * area:
        k = max(range(len(species)), key=lambda i: species[i].count * species[i].shape.area)
        res.bad(f"particles[{k}].count", f"{sum(s.count for s in species)} particles would "
                f"cover {solid / area:.3g} of the control volume x in [{region[0]:g}, "
                f"{region[1]:g}]; at most {MAX_PACKING_FRACTION:g} fits")


def _check_steps(res: _Resolution, scene: Scene, dt: float) -> None:
    """A run must take at least one step and not more than ``limits.MAX_STEPS``."""
    t_end = scene.run.t_end
    steps = t_end / dt
    why = "the auto time step" if scene.run.dt == "auto" else "run.dt"
    key = "run.dt" if scene.run.dt != "auto" else "run.t_end"
    if steps < 0.5:
        res.bad("run.t_end", f"{t_end:g} s is shorter than half a time step ({why} "
                f"{dt:.3g} s): the run would take no step; raise run.t_end")
    elif steps > limits.MAX_STEPS:
        driver = ("" if scene.run.dt != "auto" else
                  " (the critical step of the stiffest contact: with kn = \"auto\" it "
                  "follows the driving pressure or flow rate)")
        res.bad(key, f"{why} {dt:.3g} s{driver} would take {steps:.3g} steps to reach "
                f"t_end = {t_end:g} s, more than the {limits.MAX_STEPS:.0e} a run can finish; "
                f"lower run.t_end, or soften the contacts / the driving")


def _memory_parts(scene: Scene, species: list[Species], all_disks: bool, wall_h: float,
                  geom, fluid_cells: int) -> list[Part]:
    """Every large array a run of ``scene`` allocates, with the key that sizes it."""
    R = scene.run.realizations
    n = sum(s.count for s in species)
    box = (geom.x_min, geom.x_max, geom.y_min, geom.y_max)
    parts = [_wall_grid_part(scene, box, wall_h),
             Part("run.realizations" if R > 1 else "particles.count",
                  f"the state of {R} x {n} bodies", R * n * limits.BODY_BYTES,
                  "use fewer realizations per run (sweeps and figures batch them) or "
                  "fewer particles")]
    nodes = 1 if all_disks else max(len(s.shape.nodes) for s in species)
    slots = DISK_HISTORY_SLOTS if all_disks else LS_HISTORY_SLOTS
    parts.append(Part("particles.nodes", f"the shear history of {R} x {n} bodies x {nodes} "
                      "nodes", R * n * nodes * slots * limits.HISTORY_SLOT_BYTES,
                      "use fewer surface nodes, realizations or particles"))
    if not all_disks:
        for k, s in enumerate(species):
            per = (2 * s.shape.bounding_radius / s.ls_spacing + 8) ** 2
            parts.append(Part(f"particles[{k}].ls_spacing", f"the level set of particles[{k}] "
                              f"({per:.3g} nodes)", per * limits.LEVEL_SET_NODE_BYTES,
                              "use ls_spacing = \"auto\" (d_eq / 40, finer only for thin "
                              "parts) or coarser"))
    if fluid_cells:
        parts.append(Part("fluid.cell_size", f"the fluid grid ({fluid_cells:.3g} cells)",
                          fluid_cells * limits.FLUID_CELL_BYTES,
                          "use a coarser fluid.cell_size (\"auto\": d_eq / 6)"))
        parts.append(Part("run.realizations" if R > 1 else "fluid.cell_size",
                          f"the pressure solves of {R} realization(s) on {fluid_cells:.3g} "
                          "cells", R * fluid_cells * limits.FLUID_CELL_REALIZATION_BYTES,
                          "use fewer realizations per run or a coarser fluid.cell_size"))
    return parts


def _fluid_grid(res: _Resolution, model: Model, nx: int, ny: int) -> None:
    """The fluid cells (centres in the fluid are unknowns) and the solver workers."""
    scene, geom = model.scene, model.geometry
    f = scene.fluid
    dx = (geom.x_max - geom.x_min) / nx
    xc = geom.x_min + (np.arange(nx) + 0.5) * dx
    yc = geom.y_min + (np.arange(ny) + 0.5) * dx
    pts = np.stack(np.meshgrid(xc, yc, indexing="ij"), axis=-1).reshape(-1, 2)
    model.fluid_active = (wl.wall_distance(geom, pts) > 0).reshape(nx, ny)
    model.fluid_dx = dx
    model.fluid_shape = (nx, ny)
    if f.cell_size == "auto":
        res.note("fluid.cell_size", dx, "smallest particle d_eq / 6, fitted to the channel "
                 "length")
    else:
        res.values["fluid.cell_size"] = dx
    workers = f.workers
    if workers == "auto":
        cpus = usable_cpus()
        workers = max(1, min(cpus, scene.run.realizations))
        res.note("fluid.workers", workers, f"one process per usable CPU ({cpus}), at most "
                 f"one per realization ({scene.run.realizations})")
    model.fluid_workers = int(workers)  # the solver uses at most one per realization


def _resolve_stepping(model: Model, arch: str, values: dict, notes: dict) -> None:
    """``run.stepping``: the fused stepper for disks with held fluid forces on the
    CPU (many steps per kernel launch, one realization per thread)."""
    sc = model.scene
    given = sc.run.stepping
    blockers = []
    if not model.all_disks:
        blockers.append("the particles are not all disks on the analytic path")
    if sc.fluid.enabled and sc.fluid.force_update == "step":
        blockers.append('fluid.force_update = "step" re-evaluates the fluid force every step')
    if given == "fused" and blockers:
        raise SceneError([f"{sc.source}: run.stepping = \"fused\" is not available: "
                          + "; ".join(blockers) + ' (use "auto" or "per_step")'])
    if given != "auto":
        model.stepping = given
        return
    fused = arch not in GPU_ARCHS and not blockers
    if fused:
        why = ("disks with held fluid forces on the CPU: many steps per kernel "
               "launch, one realization per thread")
    elif blockers:
        why = "per_step: " + "; ".join(blockers)
    else:
        why = f"per_step on {arch}: one realization per thread would leave a GPU idle"
    model.stepping = "fused" if fused else "per_step"
    values["run.stepping"] = model.stepping
    notes["run.stepping"] = why


def _resolve_solver(model: Model, arch: str, res: _Resolution) -> None:
    """``fluid.solver``: the Taichi multigrid where the backend has float64 kernels
    (README, Speed: 2.8 times pyamg on the vani grid, 19 times at 1.1M cells)."""
    given = model.scene.fluid.solver
    f64 = arch not in F32_ONLY_ARCHS
    if given == "gmg" and not f64:
        res.bad("fluid.solver", f'"gmg" solves in float64, which Taichi\'s {arch} backend '
                'lacks; use "amg" (or "auto")')
        res.stop_if_bad()
    if given != "auto":
        model.fluid_solver = given
        return
    model.fluid_solver = "gmg" if f64 else "amg"
    res.note("fluid.solver", model.fluid_solver,
             "Taichi multigrid CG: every realization at once, on the device" if f64 else
             f"pyamg on the host: Taichi's {arch} backend has no float64 kernels")


def open_channel_speed(model: Model) -> float:
    """Mean fluid speed through the constriction of the channel without particles:
    a property of the scene, the same for every realization, so that no
    realization's numbers depend on the others run beside it."""
    fl = model.scene.fluid
    solver = PressureSolver(model.fluid_active, model.fluid_dx, model.fluid_dx, fl.viscosity,
                            model.bc(), n_batch=1, tol=fl.solver_tol, gap=fl.gap)
    _, info = solver.solve(np.where(model.fluid_active, model.kappa_free, 0.0))
    return float(np.abs(info.flux_out).max()) / model.geometry.constriction_width


def _resolve_intervals(model: Model, values: dict, notes: dict) -> None:
    """``run.check_every`` and ``fluid.update_interval = "auto"``: the fastest
    expected particle (the mean fluid speed through the open constriction) moves
    ``CHECK_TRAVEL`` d between checks and crosses ``UPDATE_CELL_FRACTION`` fluid
    cell between solves; a given interval that lets it overrun the pressure is
    refused."""
    sc = model.scene
    u = model.open_channel_speed = open_channel_speed(model)
    dt, d_min = model.dt, model.d_min
    if u > 0:
        # The paper's small time step would otherwise check every 4e-5 s, far finer
        # than anything changes.
        model.check_every = max(CHECK_INTERVAL, int(CHECK_TRAVEL * d_min / (u * dt)))
        notes["run.check_every"] = (
            f"{model.check_every} steps: a particle at the mean constriction speed "
            f"{u:.4g} moves at most {CHECK_TRAVEL:g} d between checks "
            f"(and at least {CHECK_INTERVAL} steps)")
    given = sc.fluid.update_interval
    if given != "auto":
        travel = given * dt * u
        if travel > MAX_TRAVEL_BETWEEN_SOLVES * d_min:
            most = int(MAX_TRAVEL_BETWEEN_SOLVES * d_min / (u * dt))
            raise SceneError([
                f"{sc.source}: fluid.update_interval: {given} steps let a particle "
                f"at the constriction's mean fluid speed ({u:.3g}) move "
                f"{travel / d_min:.2g} diameters between pressure solves, "
                f"overrunning the pressure that pushes it; use at most {most} "
                f"(or \"auto\")"])
        return
    n = max(1, int(UPDATE_CELL_FRACTION * model.fluid_dx / (u * dt))) if u > 0 else 1
    values["fluid.update_interval"] = n
    notes["fluid.update_interval"] = (
        f"{UPDATE_CELL_FRACTION:g} cell / (u_c {u:.4g} * dt): a particle at the mean "
        f"constriction speed crosses {UPDATE_CELL_FRACTION:g} cell between solves")


def _initial_poses(scene: Scene, geom, templates, counts, bad):
    """(N, 3) poses of the particles given by ``particles.positions`` (NaN rows for
    the randomly placed ones, ``counts[k]`` of species k), or None; wall and particle
    overlaps are refused."""
    if all(sp.positions is None for sp in scene.particles):
        return None
    rows, given_species = [], []
    for k, sp in enumerate(scene.particles):
        if sp.positions is None:
            rows += [(np.nan, np.nan, np.nan)] * counts[k]
        else:
            rows += list(sp.positions)
            given_species += [k] * len(sp.positions)
    poses = np.array(rows, dtype=float).reshape(-1, 3)
    given = np.isfinite(poses[:, 0])
    names = [sp.name for sp in scene.particles]
    problems = check_initial(geom, templates, poses[given, :2], poses[given, 2],
                             given_species, names=names)
    for line in problems:
        bad("particles.positions", line + " (particles numbered from 0 in the order "
            "their positions are given, species after species)")
    return poses


def pair_table(species: list[Species]) -> np.ndarray:
    """(S, S, 4) kn, ks, mu, c_e of every species pair (see docs/scene.md)."""
    n = len(species)
    out = np.zeros((n, n, 4))
    for a, sa in enumerate(species):
        for b, sb in enumerate(species):
            out[a, b] = (harmonic_mean(sa.kn, sb.kn), harmonic_mean(sa.ks, sb.ks),
                         0.5 * (sa.friction + sb.friction),
                         restitution_factor(0.5 * (sa.restitution + sb.restitution)))
    return out


def wall_table(species: list[Species]) -> np.ndarray:
    """(S, 4) kn, ks, mu, c_e of every species against a wall."""
    return np.array([(s.kn, s.ks, s.friction, restitution_factor(s.restitution))
                     for s in species])
