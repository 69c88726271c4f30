"""The channel side of a resolution: walls, feed strips, the fluid grid, memory,
the step count, and the ``auto`` stepping, solver and intervals decided last."""
from __future__ import annotations

import math

import numpy as np

from .. import limits
from ..layout import DISK_HISTORY_SLOTS, LS_HISTORY_SLOTS
from ..fluid import PressureSolver
from ..limits import usable_cpus
from ..geometry import walls as wl
from ..geometry.micromodel import MICROMODEL_KEYS, array_of, channel_size
from ..geometry.placement import check_initial
from ..limits import Part
from ..scene import Scene, SceneError
from ..scene.keys import AUTO, MAX_PACKING_FRACTION
from .. import backend
from .model import (CHECK_INTERVAL, CHECK_TRAVEL, FLUID_CELLS_PER_D, GPU_ARCHS,
                    MAX_TRAVEL_BETWEEN_SOLVES, UPDATE_CELL_FRACTION, Model, Species,
                    _Resolution, has_rolling)


def _geometry(g) -> wl.Geometry:
    if g.kind == "micromodel":
        # escape is measured from the array's downstream end, so that every
        # throat sees the particles that reach it
        m = array_of(g)
        return wl.from_polygon(m.outline, m.obstacles, constriction_x=m.x_exit)
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




def micromodel_values(g, geom: wl.Geometry) -> tuple[dict, str]:
    """The resolved-scene values that replace a micromodel's pillar keys by the
    polygons generated from them (kind = "polygon", its outline, obstacles and
    constriction_x), and the note saying so."""
    values = {"geometry.kind": "polygon",
              "geometry.outline": [[float(x), float(y)] for x, y in geom.outline],
              "geometry.obstacles": [[[float(x), float(y)] for x, y in o]
                                     for o in geom.obstacles],
              "geometry.constriction_x": float(geom.constriction_x0)}
    values.update({f"geometry.{k}": None for k in MICROMODEL_KEYS})
    keys = ", ".join(f"{k} = {getattr(g, k)!r}" for k in MICROMODEL_KEYS
                     if getattr(g, k) is not None)
    note = (f'polygon: the micromodel ({keys}) as the {len(geom.obstacles)} pillar polygons '
            "it generates; constriction_x is the array's downstream end, where escape is "
            "measured from")
    return values, note


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
    if g.kind == "micromodel":
        length, width = channel_size(g.rows, g.columns, g.pillar_diameter, g.pillar_spacing,
                                     g.inlet_length, g.outlet_length)
        return 0.0, length, -width / 2, width / 2
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
    """A feed strip must lie in the channel, end upstream of the constriction's exit
    and hold fluid a particle fits in."""
    x0, x1 = strip
    if x1 <= geom.x_min or x0 >= geom.x_max:
        res.bad(key, f"[{x0:g}, {x1:g}] lies outside the channel, which spans x = "
                     f"[{geom.x_min:g}, {geom.x_max:g}]")
        return
    # A body centred downstream of the constriction would count as an escapee
    # without having crossed it: at the first step when past the escape line. The
    # slack lets the exit as the message prints it (6 digits) through.
    if x1 > geom.constriction_x1 + 1e-5 * max(abs(geom.x_min), abs(geom.x_max)):
        # (resolve records the escape offset before it checks the feed strips)
        x_escape = geom.constriction_x1 + res.values["geometry.escape_offset"]
        res.bad(key, f"[{x0:g}, {x1:g}] reaches past the constriction's exit at x = "
                     f"{geom.constriction_x1:g} (the escape line is at x = {x_escape:g}): "
                     f"particles placed there would count as escapees without crossing "
                     f"it; end the strip at x <= {geom.constriction_x1:g}")
        return
    lo, hi = max(x0, geom.x_min), min(x1, geom.x_max)
    if wl.fluid_area(geom, lo, hi) < 0.25 * math.pi * d_max ** 2:
        res.bad(key, f"[{x0:g}, {x1:g}] holds less fluid than one particle of d = "
                     f"{d_max:g} covers")


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
                + ("lower run.t_end, or raise run.dt" if scene.run.dt != "auto" else
                   "lower run.t_end, or soften the contacts / the driving"))


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
    if all_disks:   # the disk's one contact point, and its rolling moment beside it
        nodes = 2 if has_rolling(species) else 1
    else:
        nodes = max(len(s.shape.nodes) for s in species)
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
                          "use a coarser fluid.cell_size "
                          f"(\"auto\": d_eq / {FLUID_CELLS_PER_D:g})"))
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
        res.note("fluid.cell_size", dx, f"smallest particle d_eq / {FLUID_CELLS_PER_D:g}, fitted "
                 "to the channel length")
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
    """``run.stepping``: the fused stepper with held fluid forces on the CPU (many
    steps per kernel launch, one realization per thread; disks and level-set
    shapes alike); on a GPU the
    per-step path, whose kernels take a thread per body (docs/performance.md,
    "GPU-shaped kernels"). Also notes what ``run.arch = "auto"`` chose and why."""
    sc = model.scene
    if sc.run.arch == AUTO and backend.auto_reason():
        notes["run.arch"] = f"{arch}: {backend.auto_reason()}"
    given = sc.run.stepping
    blockers = []
    if sc.fluid.enabled and sc.fluid.force_update == "step":
        blockers.append('fluid.force_update = "step" re-evaluates the fluid force every step')
    if given == "fused" and arch in GPU_ARCHS:
        # one realization per thread, and 42 arrays in one task where a GPU shader
        # binds at most 31 (dem/fused.py)
        blockers.append(f"the fused stepper runs on the CPU only, and this run is on {arch}")
    if given == "fused" and blockers:
        raise SceneError([f"{sc.source}: run.stepping = \"fused\" is not available: "
                          + "; ".join(blockers) + ' (use "auto" or "per_step")'])
    if given != "auto":
        model.stepping = given
        return
    fused = arch not in GPU_ARCHS and not blockers
    if fused:
        why = ("held fluid forces on the CPU: many steps per kernel launch, one "
               "realization per thread")
    elif blockers:
        why = "per_step: " + "; ".join(blockers)
    else:
        why = (f"per_step on {arch}: a thread per body; the fused stepper's one "
               "realization per thread would leave a GPU idle")
    model.stepping = "fused" if fused else "per_step"
    values["run.stepping"] = model.stepping
    notes["run.stepping"] = why


def _has_f64(arch: str) -> bool:
    """Whether Taichi's ``arch`` has float64 kernels: the running backend's probe
    (backend.has_f64) where that is ``arch``, else by name (Metal and GLES never)."""
    if backend.current_arch() == arch:
        return backend.has_f64()
    return arch not in backend.NO_F64_ARCHS


def _solver_for(given: str, arch: str) -> str:
    """The pressure solver ``fluid.solver = given`` runs with on ``arch``: ``auto``
    is the Taichi multigrid on every backend (in float32 where it has no
    float64 kernels)."""
    return "gmg" if given == AUTO else given


def resolve_particle_flux(scene: Scene, arch: str, res: _Resolution) -> Scene:
    """``scene`` with ``fluid.particle_flux`` decided, first of all (the damping's
    ``auto`` rule depends on it), and the reason noted. ``auto``: true where the
    pressure is solved by the Taichi multigrid CG (the default on every backend),
    whose implicit coupling stays stable in a clog; false where it is solved by
    pyamg (``fluid.solver = "amg"``), where only the lagged coupling exists and
    it goes unstable once particles jam."""
    fl = scene.fluid
    auto = fl.particle_flux == AUTO
    carried = _solver_for(fl.solver, arch) == "gmg" if auto else fl.particle_flux
    if fl.enabled:
        res.notes["fluid.particle_flux"] = (
            "true: the particles carry their volume, so a stream runs at the fluid's speed "
            "(docs/scene.md, Carried volume)" if carried else
            "false: particles as fixed obstacles in each solve (docs/model.md, the paper's "
            "model); the imposed flow squeezes round them and a stream outruns the fluid "
            "(tools/stream_rate.py)")
        if auto:
            res.notes["fluid.particle_flux"] += (
                " (auto: the Taichi multigrid CG solves the pressure, and its implicit "
                "coupling keeps a clog stable; the stream's rate is within 10 % of the "
                "experiments' law, README Fig. 8)" if carried else
                " (auto: pyamg solves the pressure here, and the carried volume's stable "
                'coupling, flux_coupling = "implicit", needs solver = "gmg")')
    if not auto:
        return scene
    res.values["fluid.particle_flux"] = carried
    return scene.with_values({"fluid.particle_flux": carried})


def _resolve_solver(model: Model, arch: str, res: _Resolution) -> None:
    """``fluid.solver``: the Taichi multigrid on every backend (README, Speed: 2.8
    times pyamg on the vani grid, 19 times at 1.1M cells), in float64 where the
    backend has it, else in float32 with its floors (fluid.gmg.F32_TOL_FLOOR)."""
    from ..fluid.gmg import F32_FLUX_FLOOR, F32_TOL_FLOOR
    given = model.scene.fluid.solver
    f64 = _has_f64(arch)
    model.fluid_solver = _solver_for(given, arch)
    if model.fluid_solver == "gmg" and (given == AUTO or not f64):
        res.note("fluid.solver", model.fluid_solver,
                 f"Taichi multigrid CG on {arch}: every realization at once, on the device, "
                 + ("in float64" if f64 else
                    f"in float32 (Taichi's {arch} backend has no float64 kernels): tolerance "
                    f"at least {F32_TOL_FLOOR:g}, inflow and outflow balanced to "
                    f"{F32_FLUX_FLOOR:g}"))
    fl = model.scene.fluid
    if fl.particle_flux and fl.flux_coupling == "implicit":
        if model.fluid_solver != "gmg":
            res.bad("fluid.flux_coupling", '"implicit" solves the particles\' velocities '
                    'inside the Taichi multigrid CG (fluid.solver = "gmg"), and this run '
                    f'uses "{model.fluid_solver}"; use flux_coupling = "lagged" '
                    "or solver = \"gmg\"")
            res.stop_if_bad()
        res.note("fluid.flux_coupling", "implicit",
                 "the pressure and the particles' mean velocities over the next fluid "
                 "interval are solved together (docs/scene.md, Carried volume)")


def open_channel_speed(model: Model) -> float:
    """Mean fluid speed through the constriction of the channel without particles:
    a property of the scene, the same for every realization, so that no
    realization's numbers depend on the others run beside it."""
    fl = model.scene.fluid
    try:
        solver = PressureSolver(model.fluid_active, model.fluid_dx, model.fluid_dx,
                                fl.viscosity, model.bc(), n_batch=1, tol=fl.solver_tol,
                                gap=fl.gap)
    except ValueError:              # the grid's open cells do not join inlet and outlet
        unit = " m" if model.scene.units == "SI" else ""
        raise SceneError([f"{model.scene.source}: geometry: on the fluid grid (cells of "
                          f"{model.fluid_dx:.3g}{unit}) no open path joins the inlet to the "
                          "outlet: a gap of the geometry narrower than about a cell is "
                          "closed; widen the narrowest gap (e.g. geometry.pillar_spacing "
                          "against pillar_diameter) or refine fluid.cell_size"]) from None
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
