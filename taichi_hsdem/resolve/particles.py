"""The particle side of a resolution: each species' template and its surface
nodes, level-set spacing, mass, damping and contact stiffness, the critical time
step, and the pair and wall tables the kernels read."""
from __future__ import annotations

import math

import numpy as np

from .. import limits
from ..geometry import distance as dist
from ..geometry import shapes as shp
from ..geometry import walls as wl
from .. import laws as lgs
from ..laws import harmonic_mean, restitution_factor
from ..layout import N_PAIR, PAIR_CE, PAIR_KN, PAIR_KS, PAIR_MU, PAIR_MUR
from ..limits import Part
from ..fluid.grid_dipole import carried_speed
from ..scene import Scene
from ..scene.keys import AUTO, shape_vertex_count
from .model import (LS_DIAMETER_CELLS, LS_THINNEST_CELLS, MIN_LS_CELLS_PER_DIAMETER,
                    MIN_LS_THINNEST_CELLS, NODE_BYTES, NODE_WIDTH_FRACTION, PAPER_NODES,
                    PLATE_CREEP, Species, _Resolution)


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


def node_sagitta(shape: shp.Shape) -> float:
    """Deepest point of the outline between two consecutive surface nodes, below
    their chord: how far another body can sink into this one unseen by its nodes."""
    nodes = shape.nodes
    nxt = np.roll(nodes, -1, axis=0)
    ts = np.linspace(0.0, 1.0, 9)[1:-1]
    pts = nodes[:, None, :] * (1 - ts[None, :, None]) + nxt[:, None, :] * ts[None, :, None]
    # points on the chord inside the body lie below the surface by -phi
    return float(max(0.0, -dist.signed_distance(shape, pts.reshape(-1, 2)).min()))


def critical_time_step(species: list[Species], all_disks: bool, normalize: bool) -> float:
    """``2 / omega_max`` over every species pair and every species against a wall.

    ``omega^2`` is the larger of ``k_n,eff / m_eff`` (normal) and ``k_s,eff / m_t``
    (tangential, ``1/m_t`` adding each body's ``1/m + r_b^2/I``; with rolling
    friction, plus the rolling spring's ``k_s r_eff^2 (1/I_a + 1/I_b)``). Without
    normalisation every node of the longest straight edge can be in contact at once.
    """
    if all_disks or normalize:
        factor = 1.0
    else:
        factor = float(max(_face_nodes(s.shape) for s in species))
    omega2 = 0.0
    for a in species:
        inv_ta = 1.0 / a.mass + a.shape.bounding_radius ** 2 / a.inertia
        ra = a.shape.bounding_radius
        # against a wall (the rolling spring, k_s r^2 on the spin, adds to the shear's)
        roll = a.ks * ra ** 2 / a.inertia if a.rolling > 0.0 else 0.0
        omega2 = max(omega2, factor * a.kn / a.mass, factor * a.ks / (1.0 / inv_ta) + roll)
        for b in species:
            kn = harmonic_mean(a.kn, b.kn)
            ks = harmonic_mean(a.ks, b.ks)
            meff = a.mass * b.mass / (a.mass + b.mass)
            inv_t = inv_ta + 1.0 / b.mass + b.shape.bounding_radius ** 2 / b.inertia
            rb = b.shape.bounding_radius
            roll = 0.0
            if a.rolling + b.rolling > 0.0:
                roll = ks * (ra * rb / (ra + rb)) ** 2 * (1.0 / a.inertia + 1.0 / b.inertia)
            omega2 = max(omega2, factor * kn / meff, factor * ks * inv_t + roll)
    return 2.0 / math.sqrt(omega2)


def _face_nodes(s: shp.Shape) -> int:
    if s.kind == "circle":
        return max(1, len(s.nodes) // 8)
    edges = np.linalg.norm(np.roll(s.vertices, -1, axis=0) - s.vertices, axis=1)
    return int(math.ceil(len(s.nodes) * edges.max() / s.perimeter)) + 1


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


#: d/H of the 3D Stokes pairs the pair mobility is fitted to, and how far from it
#: "auto" applies it (docs/model.md section 3.5).
PAIR_MOBILITY_DH, PAIR_MOBILITY_DH_SPAN = 0.875, 0.05


def _pair_mobility(res: _Resolution, scene: Scene, species) -> bool:
    """``fluid.pair_mobility`` resolved: whether close pairs get the 3D near-field
    resistance (:mod:`taichi_hsdem.dem.pairs`)."""
    f = scene.fluid
    given = f.pair_mobility
    if not f.enabled:
        res.note("fluid.pair_mobility", False, "no fluid")
        return False
    if given != AUTO:
        res.values["fluid.pair_mobility"] = bool(given)
        return bool(given)
    why = None
    if not f.particle_flux:
        why = "fluid.particle_flux = false (it was fitted with the carried volume)"
    elif scene.damping.xi != AUTO:
        why = "damping.xi is given (it was fitted with the sphere's drift)"
    for k, (sp, s) in enumerate(zip(scene.particles, species)):
        if why:
            break
        dh = s.d_eq / f.gap
        if sp.drift_ratio != AUTO or sp.carried_fraction != AUTO or sp.xi is not None:
            why = (f"particles.{k} gives its drift (drift_ratio, carried_fraction or xi): "
                   f"it was fitted with the sphere's")
        elif abs(dh - PAIR_MOBILITY_DH) > PAIR_MOBILITY_DH_SPAN:
            why = (f"particles.{k}: d_eq/H = {dh:.3g}, more than {PAIR_MOBILITY_DH_SPAN:g} "
                   f"from the 3D pairs' {PAIR_MOBILITY_DH:g}")
    res.note("fluid.pair_mobility", why is None,
             f"off: {why}" if why else "the 3D Stokes pairs of spheres at d/H = "
             f"{PAIR_MOBILITY_DH:g}, fitted on the model's own pair lattices")
    return why is None


def _drift(res: _Resolution, scene: Scene, sp, t: shp.Shape, kp: float, kappa_free: float,
           k: int, cell: float | None) -> tuple[float, float]:
    """``(xi, carried)`` of species ``k``: its global damping (``damping.xi =
    "auto"``: the plate drag at which a lone particle drifts at ``drift_ratio``
    times the mean fluid speed) and the share of its velocity its cells carry in
    the pressure solve (1 where it is not used; ``"auto"``: the share at which the
    lone particle, a staircase disk of ``d_eq`` on the fluid grid of ``cell``,
    leaves the sphere's dipole; docs/model.md sections 3.4, 5.2)."""
    f = scene.fluid
    key = f"particles[{k}]"
    given = sp.xi if sp.xi is not None else (None if scene.damping.xi == "auto"
                                              else scene.damping.xi)
    if not f.enabled:
        res.notes["damping.xi"] = "no fluid: no plate drag"
        return (0.0 if given is None else float(given)), 1.0
    carries = bool(f.particle_flux)
    uses = {"drift_ratio": given is None, "carried_fraction": carries}
    table = what = None
    tracer = False
    if any(uses[name] and getattr(sp, name) == AUTO for name in uses):
        ratio = t.equivalent_diameter / f.gap
        lo, hi = lgs.sphere_in_gap_range()
        if lo <= ratio <= hi:
            table = lgs.sphere_in_gap(ratio)
            what = (("a sphere" if t.kind == "circle" else "a sphere of the same d_eq (the "
                     "table is for spheres)") + f" at mid-gap, d/H = {ratio:.4g} (3D Stokes)")
        else:
            # no sphere of this size fits the table (or the gap): the tracer of the
            # depth-averaged flow, which moves at its speed and leaves no dipole
            tracer = True
            what = (f"the tracer of the depth-averaged flow (d_eq/H = {ratio:.3g} is outside "
                    f"the 3D Stokes table of a sphere at mid-gap, {lo:g} to {hi:g})")
    values = {}
    for name, why in (("drift_ratio", "the free speed of"),
                      ("carried_fraction", "the share at which a lone drifting particle "
                                           "leaves the depth-averaged dipole of")):
        value = getattr(sp, name)
        if not uses[name]:
            res.note(f"particles.{k}.{name}", value, "not used: " + (
                "the damping is given" if name == "drift_ratio" else
                "fluid.particle_flux = false holds the particles fixed in each pressure solve"))
        elif value == AUTO and tracer:
            values[name] = 1.0
            res.note(f"particles.{k}.{name}", 1.0, what)
        elif value == AUTO and name == "drift_ratio":
            values[name] = table[0]
            res.note(f"particles.{k}.{name}", values[name], f"{why} {what}")
        elif value == AUTO:
            lam = values.get("drift_ratio", table[0])
            cells = t.equivalent_diameter / cell
            continuum = lgs.carried_fraction(kappa_free, kp, lam, table[1])
            values[name] = carried_speed(cells, kp / kappa_free, table[1],
                                         continuum * lam) / lam
            res.note(f"particles.{k}.{name}", values[name], f"{why} {what} (B/a^2 = "
                     f"{table[1]:.4g}) on the fluid grid, d_eq/cell = {cells:.4g}"
                     + ("" if t.kind == "circle" else " (a disk of d_eq)")
                     + f"; the exact circle would need {continuum:.4g}")
        else:
            values[name] = float(value)
            res.values[f"particles.{k}.{name}"] = values[name]
    carried = values.get("carried_fraction")
    if carried is not None and not 0.0 <= carried <= 2.0:
        # only "auto" can get here (a given value is range-checked with the scene)
        res.bad(f"{key}.carried_fraction", f'"auto" gives {carried:.3g}, outside [0, 2]: the '
                f"sphere's dipole ({table[1]:.3g}) is beyond what a disk of this "
                f"permeability can leave; give carried_fraction")
    if given is not None:
        return float(given), 1.0 if carried is None else carried
    drift = values["drift_ratio"]
    if carries:
        res.notes["damping.xi"] = ("(2 - c lambda) eta / (rho lambda (H^2/12 + kappa_p)): a "
                                   "lone particle whose cells carry c (carried_fraction) of "
                                   "its velocity drifts at lambda (drift_ratio) times the mean "
                                   "fluid velocity")
    else:
        res.notes["damping.xi"] = ("(1 + beta) eta / (rho lambda H^2/12): a lone particle "
                                   "held in the pressure solve drifts at lambda (drift_ratio) "
                                   "times the mean fluid velocity")
    keys = (f"{key}.density, {key}.drift_ratio, fluid.viscosity, fluid.gap"
            + (f", {key}.carried_fraction" if carries else ""))
    xi = res.derived(f"damping of particles[{k}]",
                     lambda: lgs.drift_damping(f.viscosity, sp.density, kappa_free, kp, drift,
                                               carried), keys, "1/s")
    return xi, 1.0 if carried is None else carried


def _spin_drag(res: _Resolution, scene: Scene, sp, t: shp.Shape, xi: float, inertia: float,
               k: int) -> float:
    """Spin resistance of species ``k`` beyond its global damping, N m s.

    ``"auto"``: the torque per unit spin of a sphere of diameter ``d_eq`` at
    mid-gap turning about the plates' normal, ``8 pi eta a^3 f(d/H)`` (3D
    Stokes, :func:`taichi_hsdem.laws.sphere_spin_torque`), less the ``xi I``
    that the global damping already applies to the spin, so that a lone
    particle's spin decays at the sphere's rate (docs/model.md section 1.3); 0
    without fluid, above the table or where the damping already resists more.
    A non-circular particle takes the sphere of its ``d_eq`` (an approximation:
    the table is for spheres)."""
    key = f"particles.{k}.spin_drag"
    if sp.spin_drag != AUTO:
        res.values[key] = float(sp.spin_drag)
        return float(sp.spin_drag)
    f = scene.fluid
    if not f.enabled:
        res.note(key, 0.0, "no fluid: no viscous torque")
        return 0.0
    d = t.equivalent_diameter
    try:
        factor = lgs.sphere_spin_torque(d / f.gap)
    except ValueError as exc:
        res.note(key, 0.0, f"{exc}: none beyond the global damping")
        return 0.0
    sphere = 8.0 * math.pi * f.viscosity * (0.5 * d) ** 3 * factor
    extra = max(0.0, sphere - xi * inertia)
    what = "a sphere" if t.kind == "circle" else "a sphere of the same d_eq"
    res.note(key, extra, f"{what} at mid-gap, d/H = {d / f.gap:.4g}, spinning about the "
             f"plates' normal: 8 pi eta a^3 x {factor:.4g} (3D Stokes) = {sphere:.4g} N m s, "
             f"less xi I = {xi * inertia:.4g}")
    return extra


def _plate(res: _Resolution, scene: Scene, sp, t: shp.Shape, mass: float, xi: float,
           k: int) -> tuple[float, float]:
    """``(limit, creep)`` of species ``k``'s contact with the plate it settles on:
    the Coulomb limit ``mu_p |rho_p - rho_f| g pi d_eq^3 / 6`` over the mass
    (N/kg; the buoyant weight of the sphere of diameter ``d_eq``, the 3D particle,
    whatever the prism's mass) and the speed below which it turns viscous
    (docs/model.md section 1.4); ``(0, 0)`` without plate friction."""
    key = f"particles[{k}]"
    if sp.plate_friction == 0.0:
        return 0.0, 0.0
    f = scene.fluid
    d = t.equivalent_diameter
    weight = abs(sp.density - f.density) * f.gravity * math.pi * d ** 3 / 6.0
    if weight == 0.0:
        res.notes[f"particles.{k}.plate_friction"] = (
            "no buoyant weight (neutrally buoyant, or fluid.gravity = 0): no plate contact")
        return 0.0, 0.0
    limit = res.derived(f"plate friction of particles[{k}]",
                        lambda: sp.plate_friction * weight / mass,
                        f"{key}.plate_friction, {key}.density, fluid.density, fluid.gravity",
                        "N/kg")
    plate = "lower" if sp.density > f.density else "upper"
    res.notes[f"particles.{k}.plate_friction"] = (
        f"settles on the {plate} plate: friction up to {sp.plate_friction:g} x "
        f"{weight:.4g} N (buoyant weight of the sphere of d_eq)")
    return limit, PLATE_CREEP * d * xi


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


def pair_table(species: list[Species]) -> np.ndarray:
    """(S, S, N_PAIR) kn, ks, mu, c_e, mu_r of every species pair, in the columns
    ``layout.PAIR_*`` the kernels read (see docs/scene.md)."""
    n = len(species)
    out = np.zeros((n, n, N_PAIR))
    for a, sa in enumerate(species):
        for b, sb in enumerate(species):
            out[a, b, PAIR_KN] = harmonic_mean(sa.kn, sb.kn)
            out[a, b, PAIR_KS] = harmonic_mean(sa.ks, sb.ks)
            out[a, b, PAIR_MU] = 0.5 * (sa.friction + sb.friction)
            out[a, b, PAIR_CE] = restitution_factor(0.5 * (sa.restitution + sb.restitution))
            out[a, b, PAIR_MUR] = 0.5 * (sa.rolling + sb.rolling)
    return out


def wall_table(species: list[Species]) -> np.ndarray:
    """(S, N_PAIR) kn, ks, mu, c_e, mu_r of every species against a wall."""
    out = np.zeros((len(species), N_PAIR))
    for a, s in enumerate(species):
        out[a, PAIR_KN], out[a, PAIR_KS], out[a, PAIR_MU] = s.kn, s.ks, s.friction
        out[a, PAIR_CE] = restitution_factor(s.restitution)
        out[a, PAIR_MUR] = s.rolling
    return out
