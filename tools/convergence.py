"""Accuracy against cost: convergence studies with a CSV and a Pareto chart each.

    python tools/convergence.py pressure [--quick] [--out DIR]
    python tools/convergence.py contact  [--quick] [--out DIR]
    python tools/convergence.py timestep [--quick] [--out DIR]
    python tools/convergence.py escapees [--quick] [--out DIR] [--realizations N] [--set K=V]
    python tools/convergence.py paper    [--quick] [--out DIR] [--realizations N] [--set K=V]
    python tools/convergence.py interval [--quick] [--out DIR] [--realizations N] [--set K=V]
    python tools/convergence.py solve    [--quick] [--out DIR] [--realizations N] [--set K=V]
    python tools/convergence.py grid     [--quick] [--out DIR] [--realizations N] [--set K=V]

``pressure``: the hourglass scene's pressure field (particles as placed) at
3 ... 12 fluid cells per smallest diameter against a 16-cell reference, sampled at
the same points; error against the wall time of one solve (set-up + solve).
(The exact-solution study is ``tools/inclusion_convergence.py``.)

``timestep``: a head-on collision of two disks (analytic path, linear
spring-dashpot) at restitution 0.3 ... 0.9 and time steps of 0.01 ... 0.5 of the
critical step (``run.dt_safety``): the rebound ratio against the exact ``e``,
error against the steps per unit time the setting costs (``1 / dt_safety``).

``contact``: the force of a level-set disk pressed into another by a fixed
overlap, against the analytic disk's ``kn * delta``, as the surface-node count and
the level-set spacing vary, with and without the paper's node normalisation;
error against the time of one contact step. Two more references split the
error: the same nodes with the exact distance (:func:`node_law_disks`; what is
left is the level-set grid's error, charted against the spacing in
``contact-grid.png``) and the law's many-node limit (what is left is the node
discretisation). Then the concave cases (:func:`concave_cases`: a star's tip on an
L's face, a star's tip in another star's notch, a disk in an L's inner corner) as
the ``auto`` node spacing (a fraction of the scene's thinnest part) and level-set
grid (cells across it) move off their defaults: the force along the press over
``kn delta`` and across it, in ``contact-concave.csv`` and ``contact-concave.png``.

``paper``: the auto defaults against the paper's settings (time step 3.75e-7 s, a
pressure solve every 1e4 steps) on the vani scene, 60 realizations each by
default: the speed-up and the change in mean escapees with its 95 % bootstrap
interval, in ``paper.json`` and ``paper.csv``.

``interval``: the fluid update interval alone, with more realizations than the
knob study (100 per point by default, seeds from 3000): a particle at the
constriction's mean speed crossing 0.5, 1, 2 and 3 fluid cells between pressure
solves (3 cells = half a diameter, the longest interval a scene may set); each
point's mean escapees, its change from the 0.5-cell point with a 95 % bootstrap
interval, and the wall time, in ``interval.csv`` and ``interval.png``;
``interval.json`` adds the points up to the default
(``resolve.UPDATE_CELL_FRACTION``) pooled against the longer ones.

``grid``: the fluid grid alone, like ``interval``: 6 (the default), 5 and 4
fluid cells per diameter, 100 realizations per point (seeds from 5000), a
pressure solve every 328 steps at each (the default's one cell, so every point
solves as often per distance travelled); each point's change from 6 cells, and
5 and 4 pooled against 6, in ``grid.csv``, ``grid.json`` and ``grid.png``.

``solve``: how little pressure solving the vani scene needs: the solve
tolerance (``fluid.solver_tol``, relative residual) and re-solving only when
more than a fraction of the fluid cells changed permeability
(``fluid.resolve_fraction``), one knob at a time off the defaults (1e-6, 0), 20
realizations per point on the same seeds (from 4000): mean escapees with its 95 %
interval, the paired change from the default with its BCa interval, the solves
actually done and the wall time, in ``solve.csv`` and ``solve.png``.

``escapees``: the clogging statistics of the vani scene (mean escapees before a
clog, censoring-aware, with its 95 % interval) as one knob at a time moves off its
``auto`` value: the time step (``run.dt_safety``), the contact stiffness
(``contact.overlap_target``), the fluid update interval and the fluid grid. Every
point runs the same seeds. Plotted against the wall time per simulated
realization-second. It is a sweep (``tools/sweep.py`` machinery): interrupted, it
resumes without redoing finished points; the runs are in ``<out>/escapees/``.

Outputs go to ``--out`` (default ``runs/convergence/``): ``<study>.csv`` and
``<study>.png``.
"""
import argparse
import csv
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _write(out, name, header, rows):
    out.mkdir(parents=True, exist_ok=True)
    with open(out / f"{name}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return out / f"{name}.csv"


def _pareto(out, name, series, xlabel, ylabel, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for label, xs, ys, tags in series:
        ax.loglog(xs, ys, "o-", label=label)
        for x, y, t in zip(xs, ys, tags):
            ax.annotate(str(t), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=120)
    plt.close(fig)
    return out / f"{name}.png"


def pressure_study(out, quick):
    from scipy.interpolate import RegularGridInterpolator
    from taichi_hsdem import Simulation, load_scene
    scene_path = ROOT / "scenes" / "hourglass24.toml"
    levels = (3, 4, 6, 8) if quick else (3, 4, 6, 8, 12)
    ref_level = 12 if quick else 16
    fields = {}
    for cpd in levels + (ref_level,):
        scene = load_scene(scene_path, [f"fluid.cell_size={1.0 / cpd}"])
        sim = Simulation(scene)
        t0 = time.perf_counter()
        sim.update_fluid(force=True)          # rebuild + solve, timed alone
        wall = time.perf_counter() - t0
        g = sim.model.geometry
        nx, ny = sim.model.fluid_shape
        dx = sim.model.fluid_dx
        xc = g.x_min + (np.arange(nx) + 0.5) * dx
        yc = g.y_min + (np.arange(ny) + 0.5) * dx
        fields[cpd] = (xc, yc, sim.pressure()[0], wall, nx * ny)
    # compare on the coarsest grid's active cell centres, away from walls by a cell
    xr, yr, pr, _, _ = fields[ref_level]
    ref = RegularGridInterpolator((xr, yr), np.nan_to_num(pr, nan=np.nan), bounds_error=False)
    xc, yc, p3, _, _ = fields[levels[0]]
    pts = np.stack(np.meshgrid(xc, yc, indexing="ij"), -1).reshape(-1, 2)
    drop = 100.0                                # p_in - p_out of the scene
    rows = []
    for cpd in levels:
        x, y, p, wall, cells = fields[cpd]
        mine = RegularGridInterpolator((x, y), p, bounds_error=False)(pts)
        truth = ref(pts)
        ok = np.isfinite(mine) & np.isfinite(truth)
        err = np.abs(mine[ok] - truth[ok]) / drop
        rows.append([cpd, cells, float(np.mean(err)), float(np.max(err)), wall])
    csv_path = _write(out, "pressure", ["cells_per_diameter", "cells", "mean_abs_error_over_dp",
                                       "max_abs_error_over_dp", "solve_wall_s"], rows)
    png = _pareto(out, "pressure", [("mean |p - p_ref| / dp", [r[4] for r in rows],
                                     [r[2] for r in rows], [r[0] for r in rows])],
                  "wall time of one solve (s)", "error", f"hourglass24 pressure vs {ref_level} cells/d "
                  "(labels: cells per diameter)")
    return rows, csv_path, png


def contact_study(out, quick):
    from taichi_hsdem.gallery import arena_scene, make_sim, node_law_disks
    from taichi_hsdem import backend
    backend.init("cpu", "f64")
    kn, depth = 1.0e4, 0.02
    nodes_list = (10, 20, 40, 80) if quick else (10, 20, 40, 80, 160, 320)
    spacings = (1 / 10, 1 / 20, 1 / 40) if quick else (1 / 10, 1 / 20, 1 / 40, 1 / 80)
    rows = []
    rng = np.random.default_rng(0)
    angles = rng.uniform(0, 2 * np.pi, 8)      # contact directions relative to the nodes
    for normalize in (True, False):
        # the law with nodes -> infinity (a sum scales with the node count)
        limit_all = node_law_disks(CONTINUUM_NODES, depth, 0.0, normalize)[0]
        for nodes in nodes_list:
            # the same nodes with the exact distance: what is left is grid error
            exact = np.array([node_law_disks(nodes, depth, a, normalize)[0] for a in angles])
            limit = limit_all * (1.0 if normalize else nodes / CONTINUUM_NODES)
            for h in spacings:
                ratios = []
                sim = make_sim(arena_scene([{"shape": "circle", "diameter": 1.0, "count": 2,
                                             "nodes": nodes, "ls_spacing": h}], kn=kn,
                                           fast_path=False, normalize=normalize,
                                           # let sparse node sets through: they are studied here
                                           contact__overlap_target=0.2))
                for a in angles:
                    c = np.array([10.0, 5.0])
                    u = np.array([np.cos(a), np.sin(a)])
                    sim.set_state([[c, c + (1.0 - depth) * u]])
                    sim.advance(1)
                    f, _ = sim.forces()
                    ratios.append(-f[0, 0] @ u / (kn * depth))
                t0 = time.perf_counter()
                sim.advance(200)
                per_step = (time.perf_counter() - t0) / 200
                ratios = np.array(ratios)
                rows.append([normalize, nodes, h, float(np.mean(ratios)), float(np.std(ratios)),
                             float(np.mean(np.abs(ratios - 1.0))), per_step,
                             float(np.mean(exact)), _rel_error(ratios, exact),
                             limit, float(np.mean(np.abs(ratios / limit - 1.0)))])
    csv_path = _write(out, "contact", ["normalize_by_nodes", "nodes", "ls_spacing_over_d",
                                      "force_ratio_mean", "force_ratio_std",
                                      "mean_abs_error", "step_wall_s",
                                      "exact_distance_ratio_mean", "grid_error",
                                      "law_limit_ratio", "error_vs_law_limit"], rows)
    finest = spacings[-1]
    series = []
    for normalize in (True, False):
        sel = [r for r in rows if r[0] == normalize and r[2] == finest]
        series.append((f"normalize={normalize} vs kn delta (h = d/{round(1 / finest)})",
                       [r[6] for r in sel], [max(r[5], 1e-6) for r in sel], [r[1] for r in sel]))
    sel = [r for r in rows if r[0] and r[2] == finest]
    series.append((f"normalize=True vs the law's own limit {sel[0][9]:.3f} kn delta",
                   [r[6] for r in sel], [max(r[10], 1e-6) for r in sel], [r[1] for r in sel]))
    png = _pareto(out, "contact", series, "wall time of one step, 2 disks (s)",
                  "mean |F_ls / F_ref - 1|",
                  f"level-set disk at overlap {depth} d (labels: nodes)")
    # the level-set grid's own error (against the same nodes on the exact distance)
    grid = []
    for n in nodes_list:
        sel = sorted((r for r in rows if r[0] and r[1] == n), key=lambda r: r[2])
        grid.append((f"{n} nodes", [1.0 / r[2] for r in sel], [max(r[8], 1e-7) for r in sel],
                     [""] * len(sel)))
    _pareto(out, "contact-grid", grid, "level-set cells per diameter (d / h)",
            "mean |F_ls / F_exact distance - 1|",
            f"level-set grid error, disk pair at overlap {depth} d (normalize=True)")
    return rows, csv_path, png


# Concave contacts: the "auto" rules of resolve/particles.py at other constants. Node
# spacing at most perimeter / 40 and at most `fraction` x the scene's thinnest
# part (auto: resolve.NODE_WIDTH_FRACTION); level-set spacing at most d_eq / 40
# and at most the thinnest part / `cells` (auto: resolve.LS_THINNEST_CELLS).
CONCAVE_FRACTIONS = (2.0, 1.0, 0.5, 0.25, 0.125)
CONCAVE_CELLS = (4, 8, 16, 32)
CONCAVE_REFERENCE = (1 / 16, 64)          # the finest point, both rules at once
CONCAVE_SAMPLES = 8


def concave_cases():
    """The concave contacts of the study, in units of 100 um: (name, species, the
    pose of the second body as a function of its offset, the pressing direction).

    * ``star-tip/L-face``: a ten-point star (arms 0.207 wide) driving a tip into the
      outer face of an L's arm (0.45 x 1.4), at an offset along the face;
    * ``star/star-notch``: a star's tip in another star's notch, turned a little;
    * ``disk/L-corner``: a level-set disk (d 0.3) in an L's inner corner, turned.
    """
    L = [[0.0, 0.0], [1.4, 0.0], [1.4, 0.45], [0.45, 0.45], [0.45, 1.4], [0.0, 1.4]]
    a = np.pi * np.arange(20) / 10
    r = np.where(np.arange(20) % 2 == 0, 0.7, 0.35)
    star = np.column_stack([r * np.cos(a), r * np.sin(a)]).tolist()
    L_sp = {"shape": "polygon", "vertices": L, "count": 1}
    star_sp = {"shape": "polygon", "vertices": star, "count": 1}
    disk_sp = {"shape": "circle", "diameter": 0.3, "count": 1}
    return [
        # the L's bottom face at y = 4.5 - 0.508 (centroid at (10, 5)); the star
        # below with a tip pointing up (+y: theta = pi/2), slid along the face
        ("star-tip/L-face", [L_sp, star_sp], lambda u: ((0.45 + 0.4 * u, np.pi / 2),),
         (0.0, 1.0)),
        # a tip of the second star (turned pi/10 + a little) into the first one's
        # notch at angle pi/10, pressed along it
        ("star/star-notch", [star_sp, star_sp],
         lambda u: ((0.0, np.pi / 10 + 0.02 * (2 * u - 1) + np.pi),), None),
        ("disk/L-corner", [L_sp, disk_sp], lambda u: ((0.0, 2 * np.pi * u),),
         (-1.0 / np.sqrt(2), -1.0 / np.sqrt(2))),
    ]


def _press(sim, shapes, name, offset_angle, direction, depth):
    """Put the second body in contact with the first (at (10, 5), unturned) and
    pressed ``depth`` into it along ``direction``; the force on it along the press."""
    from taichi_hsdem.geometry import distance as dist
    a, b = shapes
    xa = np.array([10.0, 5.0])
    offset, theta = offset_angle
    if name == "star-tip/L-face":
        start = xa + [offset, -4.0]
    elif name == "star/star-notch":
        u = np.array([np.cos(np.pi / 10), np.sin(np.pi / 10)])
        start, direction = xa + 4.0 * u, -u
    else:                                    # disk/L-corner: from inside the notch
        inner = xa + (np.array([0.45, 0.45]) + a.vertices[0])
        start = inner + 2.0 * np.array([1.0, 1.0])
    d = np.asarray(direction, dtype=float)
    lo, hi = 0.0, 4.0                       # along d from `start`: apart at lo, overlapping at hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if dist.overlaps(a, xa, 0.0, b, start + mid * d, theta):
            hi = mid
        else:
            lo = mid
    xb = start + (lo + depth) * d
    sim.set_state([[xa, xb]], theta=[[0.0, theta]])
    sim.advance(1)
    f, _ = sim.forces()
    return float(-f[0, 1] @ d), float(abs(f[0, 1, 0] * d[1] - f[0, 1, 1] * d[0]))


def concave_contact_study(out, quick):
    """The concave cases of `concave_cases` pressed 0.02 d_eq (of the smaller body)
    at `CONCAVE_SAMPLES` offsets, as the auto node rule's width fraction and the
    grid's cells across the thinnest part move one at a time off the defaults, up
    to `CONCAVE_REFERENCE`: the force along the press over ``kn delta`` (mean, least
    and most over the offsets), the force across it, and the change from the
    defaults, against the surface nodes and the time of one step."""
    from taichi_hsdem.gallery import arena_scene, make_sim
    from taichi_hsdem.resolve import particles as rs
    kn, depth = 1.0e4, 0.02
    fractions = (2.0, 1.0, 0.5, 0.25) if quick else CONCAVE_FRACTIONS
    cells = (4, 8, 16) if quick else CONCAVE_CELLS
    samples = 3 if quick else CONCAVE_SAMPLES
    default = (rs.NODE_WIDTH_FRACTION, rs.LS_THINNEST_CELLS)
    settings = [(f, default[1]) for f in fractions] + \
        [(default[0], c) for c in cells if c != default[1]] + [CONCAVE_REFERENCE]
    settings = list(dict.fromkeys([default] + settings))
    rng = np.random.default_rng(1)
    offsets = rng.uniform(0, 1, samples)
    rows = []
    for name, species, pose, direction in concave_cases():
        forces = {}
        for f, c in settings:
            rs.NODE_WIDTH_FRACTION, rs.LS_THINNEST_CELLS = f, c
            try:
                sim = make_sim(arena_scene([dict(sp) for sp in species], kn=kn, fast_path=False,
                                           contact__overlap_target=0.2))
            finally:
                rs.NODE_WIDTH_FRACTION, rs.LS_THINNEST_CELLS = default
            shapes = [s.shape for s in sim.model.species]
            d = min(s.equivalent_diameter for s in shapes)
            fl = np.array([_press(sim, shapes, name, pose(u)[0], direction, depth * d)
                           for u in offsets]) / (kn * depth * d)
            forces[(f, c)] = fl[:, 0]
            t0 = time.perf_counter()
            sim.advance(100)
            per_step = (time.perf_counter() - t0) / 100
            rows.append([name, f, c, sum(len(s.shape.nodes) for s in sim.model.species),
                         min(s.ls_spacing for s in sim.model.species), float(fl[:, 0].mean()),
                         float(fl[:, 0].min()), float(fl[:, 0].max()), float(fl[:, 1].mean()),
                         _rel_error(fl[:, 0], forces[default]), per_step, (f, c) == default])
    csv_path = _write(out, "contact-concave", ["case", "node_width_fraction",
                                               "ls_cells_across_thinnest", "nodes_of_pair",
                                               "ls_spacing_min", "force_over_kn_delta",
                                               "force_min", "force_max", "lateral_over_kn_delta",
                                               "change_from_default", "step_wall_s",
                                               "is_default"], rows)
    png = _concave_chart(out, rows, default, depth)
    return rows, csv_path, png


def _concave_chart(out, rows, default, depth):
    """Force along the press (band: least to most over the offsets) against the
    nodes of the pair (left, grid at its default) and the level-set cells across
    the thinnest part (right, nodes at their default); the default ringed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for ax, col, keep, label in ((axes[0], 3, lambda r: r[2] == default[1],
                                  "surface nodes of the pair (labels: node spacing / "
                                  "thinnest part)"),
                                 (axes[1], 2, lambda r: r[1] == default[0],
                                  "level-set cells across the thinnest part")):
        for name in dict.fromkeys(r[0] for r in rows):
            sel = sorted((r for r in rows if r[0] == name and keep(r)), key=lambda r: r[col])
            xs = [r[col] for r in sel]
            line, = ax.semilogx(xs, [r[5] for r in sel], "o-", label=name)
            ax.fill_between(xs, [r[6] for r in sel], [r[7] for r in sel], alpha=0.15,
                            color=line.get_color())
            for r in sel:
                if r[11]:
                    ax.plot(r[col], r[5], "o", ms=12, mfc="none", color="k")
                if col == 3:
                    ax.annotate(f"{r[1]:g}", (r[col], r[5]), textcoords="offset points",
                                xytext=(4, 4), fontsize=7)
            if col == 3:            # the finest point, both rules at once
                for r in rows:
                    if r[0] == name and (r[1], r[2]) == CONCAVE_REFERENCE:
                        ax.plot(r[3], r[5], "x", ms=8, color=line.get_color())
                        ax.annotate(f"{r[1]:g}, {r[2]:g} cells", (r[3], r[5]),
                                    textcoords="offset points", xytext=(-30, -12), fontsize=7)
        ax.set_xlabel(label, fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("force along the press / (kn delta)")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"concave contacts pressed {depth} d (band: over offsets; ringed: the "
                 "defaults)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "contact-concave.png", dpi=120)
    plt.close(fig)
    return out / "contact-concave.png"


def _rel_error(values, refs):
    """Mean ``|value / ref - 1|``, a zero value against a zero reference (no node in
    contact either way) counting as exact and against a non-zero one as 100 %."""
    values, refs = np.asarray(values, float), np.asarray(refs, float)
    safe = np.where(refs != 0.0, refs, 1.0)
    err = np.where(refs != 0.0, np.abs(values / safe - 1.0), np.where(values == 0.0, 0.0, 1.0))
    return float(np.mean(err))


CONTINUUM_NODES = 100_000     # node_law_disks at this count stands for nodes -> infinity


TIMESTEP_SAFETIES = (0.01, 0.02, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.5)
TIMESTEP_RESTITUTIONS = (0.3, 0.5, 0.7, 0.9)


def timestep_study(out, quick):
    from taichi_hsdem.gallery import head_on  # the collision tests/test_mechanics.py checks
    from taichi_hsdem import backend
    backend.init("cpu", "f64")
    safeties = (0.02, 0.15, 0.3) if quick else TIMESTEP_SAFETIES
    rows = []
    for s in safeties:
        errs = [head_on(e, dt_safety=s)[0] / e - 1.0 for e in TIMESTEP_RESTITUTIONS]
        rows.append([s, 1.0 / s, *errs, float(np.max(np.abs(errs)))])
    csv_path = _write(out, "timestep", ["dt_safety", "steps_per_critical_step",
                                        *[f"rel_error_e{e:g}" for e in TIMESTEP_RESTITUTIONS],
                                        "max_abs_rel_error"], rows)
    png = _pareto(out, "timestep", [("max over e = " + ", ".join(
        f"{e:g}" for e in TIMESTEP_RESTITUTIONS), [r[1] for r in rows],
        [max(r[-1], 1e-6) for r in rows], [r[0] for r in rows])],
        "steps per critical time step (cost, 1 / dt_safety)",
        "max |rebound ratio / e - 1|", "head-on disk collision (labels: dt_safety)")
    return rows, csv_path, png


# The escapee study's knobs: (label, override key, values off the default). The
# vani scene's auto values: dt_safety 0.15, overlap_target 0.02, update_interval
# 328 steps (one cell at the constriction's mean speed), cell_size d/6.
D_VANI = 140e-6
ESCAPEE_KNOBS = (
    ("time step (dt_safety)", "run.dt_safety", (0.075, 0.3)),
    ("contact stiffness (overlap_target)", "contact.overlap_target", (0.01, 0.04)),
    ("fluid update interval (steps)", "fluid.update_interval", (164, 656)),
    ("fluid cells per d", "fluid.cell_size", (D_VANI / 8, D_VANI / 4)),
)
ESCAPEE_DEFAULTS = {"run.dt_safety": 0.15, "contact.overlap_target": 0.02,
                    "fluid.update_interval": 328, "fluid.cell_size": D_VANI / 6}
# The paper's settings (Zhou et al.: a time step of 3.75e-7 s and a pressure solve
# every 1e4 steps) on the same scene and seeds, for the speed-up of the auto
# defaults and the change in <s> between the two.
PAPER_POINT = {"run.dt": 3.75e-7, "fluid.update_interval": 10000}


def _knob_value(key, value):
    return round(D_VANI / value, 3) if key == "fluid.cell_size" else value


# --set: the "section.key=value" overrides of every point of the sweep studies
# (main fills it)
SETS: list = []


def _sweep(study, points, folder, n, seed, quick):
    """Run ``points`` of the vani scene (``n`` realizations from ``seed``, with
    :data:`SETS`); every point must give a result."""
    from taichi_hsdem import SceneError, Simulation, load_scene
    from taichi_hsdem.scene.toml import parse_override_value
    from taichi_hsdem.studies.sweep import run_sweep
    # compile (or load) every kernel first, so that no point's wall time holds it;
    # this load checks the --set overrides too
    try:
        Simulation(load_scene(ROOT / "scenes" / "vani_phi026.toml",
                              SETS + [f"run.realizations={n}", "run.t_end=0.01"])).run()
    except SceneError as exc:      # a bad --set: the scene's own message, exit 2
        print(exc, file=sys.stderr)
        raise SystemExit(2) from None
    common = {k.strip(): parse_override_value(v.strip())
              for k, _, v in (text.partition("=") for text in SETS)}
    common.update({"run.realizations": n, "run.seed": seed})
    if quick:
        common["run.t_end"] = 0.3
    rows = run_sweep(ROOT / "scenes" / "vani_phi026.toml", points, folder, common=common,
                     progress=lambda m: print(m, file=sys.stderr))
    bad = [r for r in rows if r["status"] not in ("ran", "skipped", "unstable")]
    if bad:
        raise SystemExit(f"{study} study: points without results: "
                         f"{[(r['folder'], r['status'], r['message']) for r in bad]}")
    return rows


def _point(folder, r):
    """One sweep point: its statistics, cost and the stable realizations' samples."""
    real = json.loads((folder / r["folder"] / "summary.json").read_text())["realizations"]
    sim_s = sum((x["t_stop"] or 0.0) for x in real)
    ok = [x for x in real if x["status"] == "ok"]
    return {"n_ok": r["n_ok"], "n_clogged": r["n_clogged"], "n_unstable": r["n_unstable"],
            "mean": r["mean_escapees"], "ci": list(r["mean_escapees_ci"]),
            "wall_s": r["wall_time_s"],
            "wall_per_sim_s": r["wall_time_s"] / sim_s if sim_s else float("nan"),
            "escapees": [x["escapees"] for x in ok],
            "clogged": [bool(x["clogged"]) for x in ok],
            "seeds": [x["seed"] for x in ok]}


def _row(label, value, pt):
    return [label, value, pt["n_ok"], pt["n_clogged"], pt["n_unstable"], pt["mean"],
            *pt["ci"], pt["wall_s"], pt["wall_per_sim_s"]]


def _mean_ci_columns(rows):
    """Wall-s per realization-s, mean escapees and its interval bounds of
    :func:`_row` rows (NaN where a point has no estimate), as float arrays."""
    def col(i):
        return np.array([np.nan if r[i] is None else r[i] for r in rows], dtype=float)
    return col(9), col(5), col(6), col(7)


ROW_HEADER = ["realizations_ok", "clogged", "unstable", "mean_escapees",
              "mean_escapees_ci_lo", "mean_escapees_ci_hi", "wall_s",
              "wall_s_per_realization_s"]


def escapee_study(out, quick, realizations=None):
    n = realizations or (2 if quick else 20)
    folder = out / ("escapees-quick" if quick else "escapees")
    # the default and the paper-like point first: they are the comparison
    points = [{}, PAPER_POINT] + [{key: v} for _, key, values in ESCAPEE_KNOBS for v in values]
    sweep_rows = _sweep("escapee", points, folder, n, 1000, quick)
    default, paper = _point(folder, sweep_rows[0]), _point(folder, sweep_rows[1])
    rows = []
    for label, key, values in ESCAPEE_KNOBS:
        rows.append(_row(key, _knob_value(key, ESCAPEE_DEFAULTS[key]), default))
        for r in sweep_rows[2:]:
            if key in r["overrides"]:
                rows.append(_row(key, _knob_value(key, r["overrides"][key]), _point(folder, r)))
    rows.append(_row("paper-like", "dt 3.75e-7 s, solve every 1e4 steps", paper))
    csv_path = _write(out, "escapees", ["knob", "value"] + ROW_HEADER, rows)
    _compare_paper(out / "escapees-paper.json", default, paper)
    png = _escapee_chart(out, rows, n)
    return rows, csv_path, png


def paper_study(out, quick, realizations=None):
    """The auto defaults against the paper's settings alone, with more
    realizations than the knob study (seeds from 2000, apart from its 1000...)."""
    n = realizations or (2 if quick else 60)
    folder = out / ("paper-quick" if quick else "paper")
    default, paper = (_point(folder, r) for r in
                      _sweep("paper", [{}, PAPER_POINT], folder, n, 2000, quick))
    rows = [[label] + _row(label, None, pt)[2:]
            for label, pt in (("auto", default), ("paper-like", paper))]
    csv_path = _write(out, "paper", ["settings"] + ROW_HEADER, rows)
    json_path = out / "paper.json"
    _compare_paper(json_path, default, paper)
    return rows, csv_path, json_path


# Fluid cells a particle at the constriction's mean speed crosses between solves
# (resolve.UPDATE_CELL_FRACTION is one of them); 164 steps is half a cell in the
# vani scene at the auto time step, so the intervals are multiples of it. Given as
# steps (not "auto") so that a point's folder stays the same run whatever the
# default is.
INTERVAL_CELLS = (0.5, 1.0, 2.0, 3.0)
HALF_CELL_STEPS = 164


def interval_study(out, quick, realizations=None):
    from taichi_hsdem.resolve import UPDATE_CELL_FRACTION
    steps = [int(round(c / 0.5 * HALF_CELL_STEPS)) for c in INTERVAL_CELLS]
    return _ladder_study(
        out, quick, realizations, "interval", 3000,
        [{"fluid.update_interval": k} for k in steps],
        ["cells_per_solve", "steps"], [[c, k] for c, k in zip(INTERVAL_CELLS, steps)],
        "half_cell", "default_cells_per_solve", UPDATE_CELL_FRACTION,
        beyond=lambda c: c > UPDATE_CELL_FRACTION,
        tag=lambda c, k: f"{c:g} cell{'' if c == 1 else 's'} ({k} steps)",
        title="fluid cells crossed between pressure solves")


# The grid study's fluid cells per diameter (fluid.cell_size = d / c): the default
# (resolve.FLUID_CELLS_PER_D) first, the reference, then coarser grids, the
# question being how coarse a grid the statistics allow (finer ones were charted
# by the escapee study and the pressure study). The solve interval stays at the
# default's 328 steps, so every point solves as often per distance travelled:
# only the grid moves.
GRID_CELLS = (6, 5, 4)
GRID_INTERVAL_STEPS = 2 * HALF_CELL_STEPS


def grid_study(out, quick, realizations=None):
    from taichi_hsdem.resolve import FLUID_CELLS_PER_D
    return _ladder_study(
        out, quick, realizations, "grid", 5000,
        [{"fluid.cell_size": D_VANI / c, "fluid.update_interval": GRID_INTERVAL_STEPS}
         for c in GRID_CELLS],
        ["cells_per_d", "cell_size"], [[c, D_VANI / c] for c in GRID_CELLS],
        "default", "default_cells_per_d", FLUID_CELLS_PER_D,
        beyond=lambda c: c < FLUID_CELLS_PER_D,
        tag=lambda c, h: f"{c:g} cells per d",
        title=f"fluid cells per diameter (a solve every {GRID_INTERVAL_STEPS} steps)")


def _ladder_study(out, quick, realizations, name, seed, points, value_header, value_rows,
                  ref_name, default_name, default, beyond, tag, title):
    """One knob at several values, 100 realizations per point on the same seeds:
    each point's <s>, its paired change from the first point, the wall time, and
    the points at or before the default pooled against those beyond it, in
    ``<name>.csv``, ``<name>.json`` and ``<name>.png``."""
    from taichi_hsdem.stats import mean_difference
    n = realizations or (2 if quick else 100)
    folder = out / (f"{name}-quick" if quick else name)
    pts = [_point(folder, r) for r in _sweep(name, points, folder, n, seed, quick)]
    ref = pts[0]
    rows = []
    for head, pt in zip(value_rows, pts):
        if pt is ref or not pt["escapees"] or not ref["escapees"]:
            diff, lo, hi = (0.0, 0.0, 0.0) if pt is ref else (None, None, None)
        else:
            diff, (lo, hi) = _paired_difference(ref, pt)
        rows.append(head + _row(None, None, pt)[2:] + [diff, lo, hi])
    header = (value_header + ROW_HEADER
              + [f"change_from_{ref_name}", "change_ci_lo", "change_ci_hi"])
    csv_path = _write(out, name, header, rows)

    # the points up to the default pooled against those beyond: is there a change
    # beyond the default that one point's sample is too small to show?
    def pool(sel):
        chosen = [pt for head, pt in zip(value_rows, pts) if sel(head[0])]
        return ([s for pt in chosen for s in pt["escapees"]],
                [k for pt in chosen for k in pt["clogged"]])
    upto, past = pool(lambda v: not beyond(v)), pool(beyond)
    pooled = None
    if upto[0] and past[0]:
        diff, (lo, hi) = mean_difference(upto[0], upto[1], past[0], past[1])
        pooled = {default_name: default, "realizations_up_to_default": len(upto[0]),
                  "realizations_beyond_default": len(past[0]),
                  "change_beyond_minus_up_to": diff, "change_ci95": [lo, hi]}
    from taichi_hsdem.output import json_safe
    (out / f"{name}.json").write_text(json.dumps(json_safe(
        {"points": [dict(zip(header, r)) for r in rows], "pooled": pooled}), indent=1,
        allow_nan=False) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    k = len(value_header)
    xs, ys, lo, hi = _mean_ci_columns([r[k - 2:] for r in rows])
    ax.errorbar(xs, ys, yerr=[ys - lo, hi - ys], fmt="o-", capsize=3)
    for x, y, r in zip(xs, ys, rows):
        ax.annotate(tag(r[0], r[1]), (x, y), textcoords="offset points", xytext=(4, 4),
                    fontsize=7)
    ax.set_xscale("log")
    # plain numbers: a range within one decade gets no decade ticks to label
    plain = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}")
    ax.xaxis.set_major_formatter(plain)
    ax.xaxis.set_minor_formatter(plain)
    ax.tick_params(axis="x", which="minor", labelsize=7)
    ax.set_xlabel("wall seconds per simulated realization-second")
    ax.set_ylabel("mean escapees before a clog <s> (95 % interval)")
    ax.set_title(f"vani scene: {title}, {n} realizations per point", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=120)
    plt.close(fig)
    return rows, csv_path, out / f"{name}.png"


def _paired_difference(a, b):
    """``<s>_b - <s>_a`` and its 95 % interval. Points run on the same seeds are
    paired (one realization each per seed, all stable): the BCa bootstrap resamples
    the seeds; otherwise the intervals of the two are combined (MOVER)."""
    from taichi_hsdem.stats import mean_difference
    paired = len(a["escapees"]) == len(b["escapees"]) and a.get("seeds") == b.get("seeds") \
        and a.get("seeds") is not None
    return mean_difference(a["escapees"], a["clogged"], b["escapees"], b["clogged"],
                           method="bca" if paired else "mover", paired=paired)


def _compare_paper(path, auto, paper):
    """The auto defaults against the paper's settings (two :func:`_point` results):
    speed-up and the change in <s> (paper-like minus auto) with its bootstrap
    interval, written to ``path``."""
    diff, (lo, hi) = _paired_difference(auto, paper)

    def part(pt):
        return {"mean_escapees": pt["mean"], "ci": pt["ci"], "realizations": pt["n_ok"],
                "clogged": pt["n_clogged"], "wall_s_per_realization_s": pt["wall_per_sim_s"]}
    result = {
        "auto": part(auto), "paper_like": part(paper),
        "speedup_auto_over_paper": paper["wall_per_sim_s"] / auto["wall_per_sim_s"],
        "mean_change_paper_minus_auto": diff, "mean_change_ci95": [lo, hi],
    }
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"auto against paper-like: {result['speedup_auto_over_paper']:.3g}x faster; "
          f"<s> paper - auto = {diff:.3g} (95 % interval {lo:.3g} to {hi:.3g})",
          file=sys.stderr)


SOLVE_KNOBS = (
    ("solve tolerance (solver_tol)", "fluid.solver_tol", (1e-4, 1e-8, 1e-10)),
    ("re-solve above a changed fraction (resolve_fraction)", "fluid.resolve_fraction",
     (0.01, 0.05, 0.1)),
)
SOLVE_DEFAULTS = {"fluid.solver_tol": 1e-6, "fluid.resolve_fraction": 0.0}


def _solves_done(folder, r):
    """Pressure solves (batch solves of all realizations) of a sweep point."""
    summary = json.loads((folder / r["folder"] / "summary.json").read_text())
    return summary["fluid"]["solves"] if summary.get("fluid") else None


def solve_study(out, quick, realizations=None):
    n = realizations or (2 if quick else 20)
    folder = out / ("solve-quick" if quick else "solve")
    points = [{}] + [{key: v} for _, key, values in SOLVE_KNOBS for v in values]
    sweep_rows = _sweep("solve", points, folder, n, 4000, quick)
    pts = [_point(folder, r) for r in sweep_rows]
    default = pts[0]
    rows = []
    for _, key, _values in SOLVE_KNOBS:
        for r, pt in zip(sweep_rows, pts):
            if r["overrides"] and key not in r["overrides"]:
                continue
            value = r["overrides"].get(key, SOLVE_DEFAULTS[key])
            if pt is default or not pt["escapees"] or not default["escapees"]:
                diff, lo, hi = (0.0, 0.0, 0.0) if pt is default else (None, None, None)
            else:
                diff, (lo, hi) = _paired_difference(default, pt)
            rows.append(_row(key, value, pt) + [diff, lo, hi, _solves_done(folder, r)])
    header = (["knob", "value"] + ROW_HEADER
              + ["change_from_default", "change_ci_lo", "change_ci_hi", "pressure_solves"])
    csv_path = _write(out, "solve", header, rows)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for k, (label, key, _) in enumerate(SOLVE_KNOBS):
        sel = sorted((r for r in rows if r[0] == key), key=lambda r: r[9])
        xs, ys, lo, hi = _mean_ci_columns(sel)
        ax.errorbar(xs * (1 + 0.02 * k), ys, yerr=[ys - lo, hi - ys], fmt="o-", capsize=3,
                    label=label)
        for x, y, r in zip(xs, ys, sel):
            tag = "default" if r[1] == SOLVE_DEFAULTS[key] else f"{r[1]:g}"
            ax.annotate(tag, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("wall seconds per simulated realization-second")
    ax.set_ylabel("mean escapees before a clog <s> (95 % interval)")
    ax.set_title(f"vani scene: pressure solve tolerance and skipped re-solves, "
                 f"{n} realizations per point", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "solve.png", dpi=120)
    plt.close(fig)
    return rows, csv_path, out / "solve.png"


def _escapee_chart(out, rows, n):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    paper = [r for r in rows if r[0] == "paper-like"][0]
    if paper[5] is not None:
        ax.errorbar([paper[9]], [paper[5]], yerr=[[paper[5] - paper[6]], [paper[7] - paper[5]]],
                    fmt="k*", ms=10, capsize=3, label="paper-like (dt 3.75e-7 s, 1e4 steps)")
    for k, (label, key, _) in enumerate(ESCAPEE_KNOBS):
        sel = sorted((r for r in rows if r[0] == key), key=lambda r: r[9])
        xs, ys, lo, hi = _mean_ci_columns(sel)
        xs = xs * (1 + 0.02 * (k - 1.5))  # spread the default
        ax.errorbar(xs, ys, yerr=[ys - lo, hi - ys], fmt="o-", capsize=3, label=label)
        for x, y, r in zip(xs, ys, sel):
            tag = r[1] if r[1] != _knob_value(key, ESCAPEE_DEFAULTS[key]) else "auto"
            ax.annotate(str(tag), (x, y), textcoords="offset points", xytext=(4, 4),
                        fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("wall seconds per simulated realization-second")
    ax.set_ylabel("mean escapees before a clog <s> (95 % interval)")
    ax.set_title(f"vani scene, {n} realizations per point, one knob at a time", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "escapees.png", dpi=120)
    plt.close(fig)
    return out / "escapees.png"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("study", choices=("pressure", "contact", "timestep", "escapees", "paper",
                                      "interval", "solve", "grid"))
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", default=str(ROOT / "runs" / "convergence"))
    p.add_argument("--realizations", type=int, default=None,
                   help="escapees: realizations per point (default 20, --quick 2); "
                        "paper: per setting (default 60); interval, grid: per point "
                        "(default 100); solve: per point (default 20)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="escapees, paper, interval, solve, grid: override a scene scalar at "
                        "every point (repeatable), e.g. fluid.particle_flux=false for "
                        "the fixed-obstacle model; give another --out to keep both")
    a = p.parse_args(argv)
    SETS[:] = a.set
    if a.set and a.study not in ("escapees", "paper", "interval", "solve", "grid"):
        p.error(f"--set applies to the escapees, paper, interval, solve and grid studies, "
                f"not {a.study}")
    if a.study == "escapees":
        rows, csv_path, png = escapee_study(Path(a.out), a.quick, a.realizations)
    elif a.study == "paper":
        rows, csv_path, png = paper_study(Path(a.out), a.quick, a.realizations)
    elif a.study == "interval":
        rows, csv_path, png = interval_study(Path(a.out), a.quick, a.realizations)
    elif a.study == "solve":
        rows, csv_path, png = solve_study(Path(a.out), a.quick, a.realizations)
    elif a.study == "grid":
        rows, csv_path, png = grid_study(Path(a.out), a.quick, a.realizations)
    else:
        study = {"pressure": pressure_study, "contact": contact_study,
                 "timestep": timestep_study}[a.study]
        rows, csv_path, png = study(Path(a.out), a.quick)
        if a.study == "contact":
            more, csv2, png2 = concave_contact_study(Path(a.out), a.quick)
            rows = rows + more
            csv_path, png = f"{csv_path}, {csv2}", f"{png}, {png2}"
    for r in rows:
        print(", ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r))
    print(f"wrote {csv_path} and {png}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
