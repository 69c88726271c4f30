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

from .geometry import shapes as shp
from .geometry import walls as wl
from .laws import free_permeability, harmonic_mean, kozeny_carman, restitution_factor
from .fluid import PressureSolver
from .geometry.placement import check_initial, count_for_fraction
from .scene import Scene, SceneError

# Resolution limits: below these a particle (or the constriction) is not seen by
# the grid that has to represent it.
MIN_FLUID_CELLS_PER_DIAMETER = 2.0
MIN_WALL_CELLS_PER_DIAMETER = 4.0
MIN_LS_CELLS_PER_DIAMETER = 5.0
MIN_FLUID_CELLS_ACROSS_CONSTRICTION = 3.0

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


def species_shape(sp) -> shp.Shape:
    """The shape template of one species table of a scene."""
    n = sp.nodes
    if sp.shape == "circle":
        return shp.circle(sp.diameter, n)
    if sp.shape == "square":
        return shp.square(sp.side, n)
    if sp.shape == "rectangle":
        return shp.rectangle(sp.width, sp.height, n)
    if sp.shape == "regular_polygon":
        return shp.regular_polygon(sp.n_vertices, sp.diameter, n)
    return shp.polygon(np.asarray(sp.vertices, dtype=float), n)


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


def resolve(scene: Scene, arch: str = "x64") -> Model:
    """Resolve every derived and ``auto`` value of ``scene``; refuse what cannot work.

    ``arch`` is the Taichi backend the run uses (``backend.init``'s answer:
    ``x64``/``arm64`` for the CPU, ``cuda``, ``vulkan``, ...): it decides
    ``run.stepping = "auto"``.
    """
    src = scene.source
    problems: list[str] = []

    def bad(key, msg):
        problems.append(f"{src}: {key}: {msg}")

    try:
        templates = [species_shape(sp) for sp in scene.particles]
    except ValueError as exc:
        raise SceneError([f"{src}: particles: {exc}"]) from None
    try:
        geom = _geometry(scene.geometry)
    except ValueError as exc:
        raise SceneError([f"{src}: geometry: {exc}"]) from None
    d_eq = [t.equivalent_diameter for t in templates]
    d_min, d_max = min(d_eq), max(d_eq)
    values: dict = {}
    notes: dict[str, str] = {}
    all_disks = scene.contact.disk_fast_path and all(t.kind == "circle" for t in templates)

    # Walls.
    g = scene.geometry
    wall_h = d_min / 10.0 if g.wall_cell_size == "auto" else g.wall_cell_size
    if g.wall_cell_size == "auto":
        values["geometry.wall_cell_size"] = wall_h
        notes["geometry.wall_cell_size"] = "smallest particle d_eq / 10"
    elif wall_h > d_min / MIN_WALL_CELLS_PER_DIAMETER:
        bad("geometry.wall_cell_size", f"{wall_h:g} is too coarse for particles of d = {d_min:g}: "
            f"use at most d/{MIN_WALL_CELLS_PER_DIAMETER:g} = {d_min / MIN_WALL_CELLS_PER_DIAMETER:g}")
    if geom.constriction_width < d_min:
        notes["geometry"] = (f"the constriction ({geom.constriction_width:g}) is narrower than the "
                             f"smallest particle ({d_min:g}): nothing can pass")
    esc = 0.5 * d_max if g.escape_offset is None else g.escape_offset
    values["geometry.escape_offset"] = esc
    x_escape = geom.constriction_x1 + esc
    if x_escape >= geom.x_max:
        bad("geometry.escape_offset", f"the escape line x = {x_escape:g} lies beyond the outlet "
            f"x = {geom.x_max:g}")

    # Fluid.
    f = scene.fluid
    kappa_free = free_permeability(f.gap) if f.enabled else 0.0
    kps = []
    for sp, t in zip(scene.particles, templates):
        if f.enabled:
            try:
                kps.append(kozeny_carman(t.sphericity, t.equivalent_diameter, t.area, f.gap))
            except ValueError as exc:
                bad("fluid.gap", f"{exc} (species '{sp.name}')")
                kps.append(kappa_free)
        else:
            kps.append(0.0)
    fluid_dx = None
    if f.enabled:
        fluid_dx = d_min / 6.0 if f.cell_size == "auto" else f.cell_size
        if f.cell_size == "auto":
            notes["fluid.cell_size"] = "smallest particle d_eq / 6"
        elif fluid_dx > d_min / MIN_FLUID_CELLS_PER_DIAMETER:
            bad("fluid.cell_size", f"{fluid_dx:g} is too coarse for particles of d = {d_min:g}: "
                f"a particle must span at least {MIN_FLUID_CELLS_PER_DIAMETER:g} cells "
                f"(cell_size <= {d_min / MIN_FLUID_CELLS_PER_DIAMETER:g})")
        if geom.constriction_width / fluid_dx < MIN_FLUID_CELLS_ACROSS_CONSTRICTION:
            bad("fluid.cell_size", f"{fluid_dx:g} leaves fewer than "
                f"{MIN_FLUID_CELLS_ACROSS_CONSTRICTION:g} cells across the constriction "
                f"(width {geom.constriction_width:g})")

    # Species mechanics.
    species: list[Species] = []
    region = tuple(scene.feed.region) if scene.feed.region is not None else tuple(geom.upstream_region)
    values["feed.region"] = list(region)
    for k, (sp, t, kp) in enumerate(zip(scene.particles, templates, kps)):
        key = f"particles[{k}]"
        if sp.count is not None:
            count = int(sp.count)
        else:
            count = count_for_fraction(sp.packing_fraction, geom, region, t)
            values[f"particles.{k}.count"] = count
            values[f"particles.{k}.packing_fraction"] = None
            notes[f"particles.{k}.count"] = (f"packing fraction {sp.packing_fraction:g} of the control "
                                             f"volume x in [{region[0]:g}, {region[1]:g}]")
        hidden = node_sagitta(t)
        if hidden > scene.contact.overlap_target * t.equivalent_diameter:
            need = sp.nodes
            while need < 100000 and node_sagitta(species_shape(sp.replace(nodes=need))) > \
                    scene.contact.overlap_target * t.equivalent_diameter:
                need *= 2
            bad(f"{key}.nodes", f"{sp.nodes} surface nodes leave up to {hidden:.3g} "
                f"({hidden / t.equivalent_diameter:.3g} d) of the surface between two nodes, "
                f"where another body can sink unseen: more than contact.overlap_target "
                f"({scene.contact.overlap_target:g} d); use about {need} nodes or more")
        mass = sp.density * t.area * (f.gap if f.gap else 1.0)
        inertia = mass * t.inertia_per_mass
        ls = t.equivalent_diameter / 40.0 if sp.ls_spacing == "auto" else sp.ls_spacing
        if sp.ls_spacing != "auto" and ls > t.equivalent_diameter / MIN_LS_CELLS_PER_DIAMETER:
            bad(f"{key}.ls_spacing", f"{ls:g} is too coarse for a particle of d = "
                f"{t.equivalent_diameter:g}: use at most d/{MIN_LS_CELLS_PER_DIAMETER:g}")
        values[f"particles.{k}.ls_spacing"] = ls
        if all_disks:
            notes[f"particles.{k}.ls_spacing"] = "not used: disks take the analytic path"
        if sp.xi is not None:
            xi = float(sp.xi)
        elif scene.damping.xi == "auto":
            if f.enabled and f.particle_flux:
                xi = f.viscosity / (sp.density * (kappa_free + kp))
                notes["damping.xi"] = ("eta / (rho (H^2/12 + kappa_p)): an isolated particle "
                                       "carried by the flow drifts at the mean fluid velocity")
            elif f.enabled:
                beta = (kappa_free - kp) / (kappa_free + kp)
                xi = (1.0 + beta) * f.viscosity / (sp.density * kappa_free)
                notes["damping.xi"] = ("(1 + beta) eta / (rho H^2/12): an isolated particle held "
                                       "in the pressure solve drifts at the mean fluid velocity")
            else:
                xi = 0.0
                notes["damping.xi"] = "no fluid: no plate drag"
        else:
            xi = float(scene.damping.xi)
        species.append(Species(name=sp.name, shape=t, count=count, density=sp.density, mass=mass,
                               inertia=inertia, d_eq=t.equivalent_diameter, kn=0.0, ks=0.0,
                               friction=sp.friction, restitution=sp.restitution, xi=xi,
                               kappa=kp, ls_spacing=ls))
    # "auto" depends on each species' density and permeability: record every
    # species' value, and as damping.xi their count-weighted mean (then unused).
    for k, s in enumerate(species):
        values[f"particles.{k}.xi"] = s.xi
    if scene.damping.xi == "auto":
        counts = np.array([max(s.count, 1) for s in species], dtype=float)
        values["damping.xi"] = float(np.average([s.xi for s in species], weights=counts))
    if problems:
        raise SceneError(problems)

    # Stiffness.
    for k, (sp, s) in enumerate(zip(scene.particles, species)):
        if sp.kn == "auto":
            if not f.enabled:
                problems.append(f"{src}: particles[{k}].kn: 'auto' needs a driving force, and this "
                                f"scene has no fluid: give kn in N/m")
                continue
            dp, why = _driving_pressure(scene, geom, species)
            s.kn = dp * s.d_eq * f.gap / (scene.contact.overlap_target * s.d_eq)
            values[f"particles.{k}.kn"] = s.kn
            notes[f"particles.{k}.kn"] = (f"driving force {dp * s.d_eq * f.gap:.4g} N ({why}) over "
                                          f"overlap_target * d_eq")
        else:
            s.kn = float(sp.kn)
        s.ks = s.kn / 2.0 if sp.ks == "auto" else float(sp.ks)
        if sp.ks == "auto":
            values[f"particles.{k}.ks"] = s.ks
    initial = _initial_poses(scene, geom, templates, [s.count for s in species], bad)
    if problems:
        raise SceneError(problems)

    # Time step.
    dt_crit = critical_time_step(species, all_disks, scene.contact.normalize_by_nodes)
    if scene.run.dt == "auto":
        dt = scene.run.dt_safety * dt_crit
        values["run.dt"] = dt
        notes["run.dt"] = f"{scene.run.dt_safety:g} of the critical step {dt_crit:.4g} s"
    else:
        dt = float(scene.run.dt)
        if dt > dt_crit and not scene.run.force_dt:
            raise SceneError([f"{src}: run.dt: {dt:g} s is above the critical time step "
                              f"{dt_crit:.4g} s of the stiffest, lightest contact; use "
                              f"dt <= {scene.run.dt_safety * dt_crit:.4g} s (dt_safety * critical) "
                              f"or dt = \"auto\""])

    # Fluid grid.
    model = Model(scene=scene, geometry=geom, wall_field=None, species=species,
                  species_of_particle=np.repeat(np.arange(len(species), dtype=np.int32),
                                                [s.count for s in species]),
                  all_disks=all_disks, dt=dt, dt_crit=dt_crit, x_escape=x_escape,
                  feed_region=region, feed_inlet=(0.0, 0.0), kappa_free=kappa_free,
                  initial_poses=initial, notes=notes)
    if model.n_particles == 0:
        raise SceneError([f"{src}: particles: the scene has no particles (every count is 0)"])
    inlet = scene.feed.inlet
    if inlet is None:
        inlet = (region[0], min(region[1], region[0] + 2.0 * d_max))
        values["feed.inlet"] = list(inlet)
    model.feed_inlet = tuple(inlet)
    model.wall_field = wl.make_wall_field(geom, wall_h)
    if f.enabled:
        lx = geom.x_max - geom.x_min
        nx = max(1, int(math.ceil(lx / fluid_dx - 1e-9)))
        dx = lx / nx
        ny = max(1, int(math.ceil((geom.y_max - geom.y_min) / dx - 1e-9)))
        xc = geom.x_min + (np.arange(nx) + 0.5) * dx
        yc = geom.y_min + (np.arange(ny) + 0.5) * dx
        pts = np.stack(np.meshgrid(xc, yc, indexing="ij"), axis=-1).reshape(-1, 2)
        model.fluid_active = (wl.wall_distance(geom, pts) > 0).reshape(nx, ny)
        model.fluid_dx = dx
        model.fluid_shape = (nx, ny)
        values["fluid.cell_size"] = dx
        workers = f.workers
        if workers == "auto":
            from .fluid.pool import usable_cpus
            cpus = usable_cpus()
            workers = max(1, min(cpus, scene.run.realizations))
            notes["fluid.workers"] = (f"one process per usable CPU ({cpus}), at most one per "
                                      f"realization ({scene.run.realizations})")
            values["fluid.workers"] = workers
        model.fluid_workers = int(workers)  # the solver uses at most one per realization
    model.skin = SKIN_FRACTION * d_min
    _resolve_stepping(model, arch, values, notes)
    if f.enabled:
        _resolve_intervals(model, values, notes)
    model.scene = scene.with_values(values)
    return model


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
