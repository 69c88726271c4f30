"""Small problems with known answers that the tests, the tools and the docs share
(like pyamg's ``gallery``): scenes to build, and reference laws to hold the
simulator against. The fluid's exact solutions are in
:mod:`taichi_hsdem.fluid.gallery`.

* :func:`arena_scene`: a closed box without fluid, for contact mechanics.
* :func:`head_on`: two disks meeting head on; their rebound ratio is ``e``.
* :func:`node_law_disks`: the LS-DEM node law for two equal disks with the exact
  signed distance (no level-set grid), the reference of the contact studies.
* :func:`rayleigh_square_array`, :func:`pillar_lattice_gradient`: the permeability
  of a Hele-Shaw cell holding a square array of circular pillars, exact and as the
  run's fluid grid solves it (docs/micromodels.md).

Examples
--------
>>> from taichi_hsdem import gallery
>>> f, n_i, n_j = gallery.node_law_disks(40000, 0.001, 0.0, normalize=True)
>>> round(f, 3), n_i == n_j               # a shallow lens: 2/3 with many nodes
(0.667, True)
"""
from __future__ import annotations

import copy
from collections import namedtuple

import numpy as np


def arena_scene(particles, *, kn=1.0e4, friction=0.0, restitution=1.0, xi=0.0, length=20.0,
                height=10.0, dt="auto", dt_safety=0.05, normalize=True, fast_path=True,
                realizations=1, precision="f64", **extra):
    """A closed box without fluid (a scene dict): an outline whose open inlet and
    outlet ends are sealed by two solid blocks leaving slits far narrower than
    any particle.

    ``particles``: list of species tables (shape keys, count, density...); the
    contact keys given here are filled in where a species does not set them.
    ``extra``: ``section__key=value`` entries set in the scene.
    """
    species = []
    for sp in particles:
        sp = dict(sp)
        sp.setdefault("density", 1.0)
        sp.setdefault("kn", kn)
        sp.setdefault("friction", friction)
        sp.setdefault("restitution", restitution)
        species.append(sp)
    scene = {
        "name": "arena",
        "units": "dimensionless",
        "run": {"t_end": 1.0, "dt": dt, "dt_safety": dt_safety, "realizations": realizations,
                "precision": precision},
        "fluid": {"enabled": False, "gap": 1.0},
        "geometry": {
            "kind": "polygon",
            "outline": [[0.0, 0.0], [length, 0.0], [length, height], [0.0, height]],
            "obstacles": [
                [[1.0, 0.02], [2.0, 0.02], [2.0, height - 0.02], [1.0, height - 0.02]],
                [[length - 2.0, 0.02], [length - 1.0, 0.02], [length - 1.0, height - 0.02],
                 [length - 2.0, height - 0.02]],
            ],
            "constriction_x": length - 0.5,
            "escape_offset": 0.25,
        },
        "particles": species,
        "contact": {"normalize_by_nodes": normalize, "disk_fast_path": fast_path},
        "damping": {"xi": xi},
        "feed": {"mode": "none", "region": [2.5, length - 2.5]},
    }
    for key, value in extra.items():
        section, name = key.split("__")
        scene.setdefault(section, {})[name] = value
    return copy.deepcopy(scene)


def make_sim(scene_dict):
    """A :class:`~taichi_hsdem.simulation.Simulation` of ``scene_dict`` whose
    particles the caller places (``set_state``)."""
    from . import Simulation, load_scene
    return Simulation(load_scene(scene_dict), place_particles=False)


HeadOn = namedtuple("HeadOn", "ratio v dt")


def head_on(e, fast_path=True, dt_safety=0.02, nodes=40, precision="f64"):
    """Two unit disks (kn 1e4, no fluid) meet head on at relative speed 2: the
    rebound ratio, which the continuous spring-dashpot makes exactly ``e``, the
    final velocities and the time step."""
    sim = make_sim(arena_scene([{"shape": "circle", "diameter": 1.0, "count": 2,
                                 "nodes": nodes}], restitution=e, fast_path=fast_path,
                               dt_safety=dt_safety, precision=precision))
    sim.set_state([[[8.0, 5.0], [10.0, 5.0]]], v=[[[1.0, 0.0], [-1.0, 0.0]]])
    sim.advance(int(1.2 / sim.dt))          # approach (0.5), contact, separation
    v = sim.state()["v"][0]
    return HeadOn((v[1, 0] - v[0, 0]) / 2.0, v, sim.dt)


def node_law_disks(nodes, depth, angle, normalize, diameter=1.0, turn=0.0):
    """The LS-DEM node law for two equal disks evaluated with the *exact* signed
    distance (no level-set grid): ``(F / (kn delta), n_i, n_j)``, the force on the
    first disk along the line of centres at overlap ``delta = depth * diameter``,
    and how many nodes of each disk are in contact.

    Disk ``i`` at the origin, unrotated, ``j`` at ``(diameter - delta) (cos angle,
    sin angle)`` turned by ``turn``, ``nodes`` surface nodes each at body angles
    ``2 pi k / nodes``. Each direction (``i``'s nodes in ``j``, ``j``'s nodes in
    ``i``) sums ``-phi n`` over its nodes in contact, divided by their number when
    ``normalize``; when both see the contact the pair force is the mean
    (docs/model.md, section 1). With ``nodes -> infinity`` and ``normalize`` this
    tends to the mean node depth over the overlapped arc, ``2/3`` of ``delta`` as
    ``delta -> 0`` (a parabolic lens): the law's own limit, which differs from the
    analytic disk's ``kn delta``.
    """
    r = 0.5 * diameter
    delta = depth * diameter
    u = np.array([np.cos(angle), np.sin(angle)])
    ci, cj = np.zeros(2), (diameter - delta) * u
    ang = 2.0 * np.pi * np.arange(nodes) / nodes

    def ring(turn_):
        return r * np.stack([np.cos(ang + turn_), np.sin(ang + turn_)], axis=1)

    def side(own, other, turn_):
        p = own + ring(turn_)
        dist = np.linalg.norm(p - other, axis=1)
        inside = dist < r
        f = ((r - dist[inside]) / dist[inside])[:, None] * (p[inside] - other)
        total = f.sum(axis=0)
        return (total / max(1, inside.sum()) if normalize else total), int(inside.sum())

    fa, na = side(ci, cj, 0.0)            # nodes of i in j: force on i
    fb, nb = side(cj, ci, turn)           # nodes of j in i: force on j, reaction on i
    f_i = fa - fb
    if na and nb:
        f_i = 0.5 * f_i
    return float(-f_i @ u / delta), na, nb


def rayleigh_square_array(fraction: float) -> float:
    """Effective conductivity of a square array of non-conducting circular
    cylinders at area ``fraction`` in a matrix of conductivity 1 (Rayleigh 1892,
    with the coefficients of Perrins, McKenzie and McPhedran 1979, Proc. R. Soc.
    A 369, 207; Keller's reciprocal theorem relates it to the perfectly
    conducting array): the Darcy permeability of a Hele-Shaw cell holding such an
    array of pillars, over the empty cell's ``H^2/12``, is this number (the depth
    averaged pressure is harmonic with no flux into the pillars).

    >>> round(rayleigh_square_array(0.2565), 5)
    0.59129
    """
    f = float(fraction)
    return 1.0 - 2.0 * f / (1.0 + f - 0.305827 * f ** 4 / (1.0 - 1.402958 * f ** 8)
                            - 0.013362 * f ** 8)


def pillar_lattice_gradient(cells_per_period: int, rows: int = 2, columns: int = 10,
                            diameter: float = 200e-6, spacing: float = 350e-6,
                            sides: int = 96) -> tuple[float, float]:
    """The mean pressure gradient across the middle of a channel of ``rows`` x
    ``columns`` circular pillars (``sides``-gons) on a square lattice whose walls lie
    on the lattice's symmetry lines (half a spacing from the outer pillars' centres,
    so the channel is an exact strip of the infinite array), solved on the fluid
    grid of the run (cells whose centre is fluid, ``cells_per_period`` cells per
    spacing, the finite volumes of :mod:`taichi_hsdem.fluid.system`, pyamg's CG
    to 1e-12) under a flow-rate inlet. Returns ``(computed, exact)`` as
    ``K_eff / (H^2/12)``: the computed one from the difference of the mean
    pressures of the fluid cells of two unit cells two periods apart in the middle
    (exact for a periodic field: the mean of ``p + G x`` is the same in every unit
    cell), the exact one :func:`rayleigh_square_array` at the polygons' area
    fraction."""
    from .fluid import PressureSolver
    from .geometry import walls
    from .geometry.micromodel import pillar_polygon
    from .geometry.polygon import signed_area
    from .laws import free_permeability
    s, n = float(spacing), int(cells_per_period)
    inlet = outlet = 2.0 * s
    length, width = inlet + columns * s + outlet, rows * s
    pillars = [pillar_polygon((inlet + (j + 0.5) * s, (i + 0.5) * s - width / 2),
                              diameter / 2, sides) for j in range(columns) for i in range(rows)]
    outline = [[0.0, -width / 2], [length, -width / 2], [length, width / 2],
               [0.0, width / 2]]
    g = walls.from_polygon(outline, pillars, constriction_x=inlet + columns * s)
    dx = s / n
    nx, ny = int(round(length / dx)), rows * n
    xc = (np.arange(nx) + 0.5) * dx
    yc = -width / 2 + (np.arange(ny) + 0.5) * dx
    pts = np.stack(np.meshgrid(xc, yc, indexing="ij"), axis=-1).reshape(-1, 2)
    active = (walls.wall_distance(g, pts) > 0).reshape(nx, ny)
    viscosity, gap, q = 1e-3, 100e-6, 1e-10
    k0 = free_permeability(gap)
    solver = PressureSolver(active, dx, dx, viscosity, {"kind": "flow_rate", "Q": q,
                                                         "p_out": 0.0},
                            tol=1e-12, gap=gap)
    try:
        p, _ = solver.solve(np.where(active, k0, 0.0))
    finally:
        solver.close()
    p = np.asarray(p)

    def cell_mean(j):            # unit cell j of the array, all rows
        i0 = int(round((inlet + j * s) / dx))
        block = p[i0:i0 + n]
        return float(np.nanmean(block))
    middle = columns // 2 - 1
    gradient = (cell_mean(middle) - cell_mean(middle + 2)) / (2 * s)
    flux = q / gap                                  # per unit depth
    computed = viscosity * flux / (gradient * width * k0)
    fraction = abs(signed_area(pillars[0])) / s ** 2
    return computed, rayleigh_square_array(fraction)
