"""From a validated scene to the numbers a run needs: shapes, walls, fluid grid,
per-species mechanics, and every ``auto`` value with the reason it was chosen.

Everything here is plain numpy and runs before any kernel, so a scene that cannot
work (a grid too coarse for its particles, a time step above the critical step,
particles that do not fit) is refused with a :class:`~taichi_hsdem.scene.SceneError`
naming the key, before any compute is spent.

:mod:`.model` holds the result (:class:`Model`, :class:`Species`), the constants
of the ``auto`` rules and the bookkeeping of one resolution; :mod:`.particles`
the particle side (templates, nodes, level sets, masses, damping, stiffness,
critical step); :mod:`.domain` the channel side (walls, feed, fluid grid, memory,
steps, and the stepping, solver and intervals decided last). :func:`resolve`
runs them in that order.
"""
from __future__ import annotations

import math

import numpy as np

from .. import limits
from ..geometry import distance as dist
from ..geometry.placement import count_for_fraction
from ..geometry.wallfield import make_wall_field
from ..laws import free_permeability, kozeny_carman
from ..limits import Part
from ..scene import Scene, SceneError
from ..scene.keys import AUTO
from .domain import (_bounding_box, _check_feed, _check_fit, _check_steps, _fluid_grid,
                     _geometry, _initial_poses, _memory_parts, _resolve_intervals,
                     _resolve_solver, _resolve_stepping, _wall_grid_part, micromodel_values,
                     open_channel_speed, resolve_particle_flux)
from .model import (FLUID_CELLS_PER_D, MIN_FLUID_CELLS_ACROSS_CONSTRICTION,
                    MIN_FLUID_CELLS_PER_DIAMETER, MIN_WALL_CELLS_PER_DIAMETER, NODE_BYTES,
                    SKIN_FRACTION, UPDATE_CELL_FRACTION, Model, Species, _Resolution, _size_keys)
from .particles import (_auto_nodes, _check_nodes, _drift, _ls_spacing, _pair_mobility, _plate,
                        _spin_drag, _stiffness, auto_node_spacing, critical_time_step,
                        node_gap, node_sagitta, pair_table, species_shape, wall_table)

__all__ = ["resolve", "Model", "Species", "species_shape", "auto_node_spacing", "node_gap",
           "node_sagitta", "critical_time_step", "open_channel_speed", "pair_table",
           "wall_table", "UPDATE_CELL_FRACTION", "FLUID_CELLS_PER_D"]


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
    scene = resolve_particle_flux(scene, arch, res)
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
    widths = [dist.thinnest_width(t) for t in templates]   # do not depend on the nodes
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
    if g.kind == "micromodel":
        values, res.notes["geometry.kind"] = micromodel_values(g, geom)
        res.values.update(values)
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
        if f.enabled and sp.permeability != "auto":
            kps.append(res.derived(f"permeability inside particles[{k}]",
                                   lambda: float(sp.permeability),
                                   f"particles[{k}].permeability", "m^2"))
            res.values[f"particles.{k}.permeability"] = kps[-1]
            if kps[-1] >= kappa_free:
                res.bad(f"particles[{k}].permeability", f"{kps[-1]:g} m^2 is not below the "
                        f"open gap's H^2/12 = {kappa_free:.4g} m^2: such a particle would not "
                        f"hinder the flow")
        elif f.enabled:
            try:
                kps.append(res.derived(
                    f"Kozeny-Carman permeability inside particles[{k}]",
                    lambda: kozeny_carman(t.sphericity, t.equivalent_diameter, t.area, f.gap),
                    f"fluid.gap, {_size_keys(k, sp)}", "m^2"))
                res.note(f"particles.{k}.permeability", kps[-1],
                         f"Kozeny-Carman, {kps[-1] / kappa_free:.3g} of the open gap's H^2/12")
            except ValueError as exc:
                res.bad("fluid.gap", f"{exc} (species '{sp.name}')")
                kps.append(kappa_free)
        else:
            kps.append(0.0)
    fluid_dx = None
    if f.enabled:
        fluid_dx = d_min / FLUID_CELLS_PER_D if f.cell_size == "auto" else f.cell_size
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
    if scene.feed.mode == "count" or any(sp.positions is None for sp in scene.particles):
        # the region places particles (none when every species gives its positions)
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
        xi, carried = _drift(res, scene, sp, t, kp, kappa_free, k, fluid_dx)
        spin = _spin_drag(res, scene, sp, t, xi, inertia, k)
        plate, creep = _plate(res, scene, sp, t, mass, xi, k)
        species.append(Species(name=sp.name, shape=t, count=count, density=sp.density,
                               mass=mass, inertia=inertia, d_eq=t.equivalent_diameter, kn=0.0,
                               ks=0.0, friction=sp.friction, restitution=sp.restitution,
                               xi=xi, kappa=kp, carried=carried, ls_spacing=ls,
                               spin_drag=spin, plate=plate, creep=creep,
                               rolling=sp.rolling_friction))
        if sp.rolling_friction > 0.0 and not all_disks:
            res.bad(f"particles.{k}.rolling_friction",
                    "rolling friction is modelled for disks only (every species a circle "
                    "and contact.disk_fast_path = true); other shapes resist rolling by "
                    "their corners: set it to 0")
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
    # A frame per step at most: more would draw (and encode) the same state again and
    # again (a million frames over 5 steps took hours).
    steps = int(math.ceil(scene.run.t_end / dt - 0.5))
    if scene.output.frames > steps + 1:
        res.note("output.frames", steps + 1, f"one frame per step: the {scene.output.frames} "
                 f"frames asked would repeat the states of the run's {steps} steps")

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
    model.wall_field = make_wall_field(geom, wall_h)
    if f.enabled:
        _fluid_grid(res, model, nx, ny)
    model.skin = SKIN_FRACTION * d_min
    model.pair_mobility = _pair_mobility(res, scene, species)
    _resolve_stepping(model, arch, res.values, res.notes)
    if f.enabled:
        _resolve_solver(model, arch, res)
        _resolve_intervals(model, res.values, res.notes)
    model.scene = scene.with_values(res.values)
    return model
