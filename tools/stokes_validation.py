"""The Hele-Shaw pressure against a 3D Stokes solve of the pore space (issue #19).

As the reference paper's first validation (Zhou et al. 2024, Sec. 3.1, Figs. 4-6):
run a scene (by default ``scenes/hourglass24.toml``), keep the state at an
unclogged and at the clogged instant, build the 3D pore space (the outline
extruded over the gap ``H``, each disk a sphere of its diameter at mid-gap, or a
prism with ``--particles prisms``), solve 3D Stokes in it with the same inlet and
outlet pressures and no slip on the plates, walls and particles (NGSolve,
Taylor-Hood P3/P2, P2/P1 with ``--quick``: ``tools/stokes_fem.py``), average its
pressure over the fluid part of the gap at every Hele-Shaw cell centre, and
compare. Without ``--quick`` it does so on every mesh of a study
(:data:`MESH_LEVELS`) and reports the finest, with how much the figures moved
from the one before.

Error (the paper's Eq. 16): at every active Hele-Shaw cell,
``e = |p_HS - p_S| / |p_S|`` with ``p_S`` the gap-averaged Stokes pressure; the
same difference over the pressure drop, ``|p_HS - p_S| / (p_in - p_out)``, is
reported beside it (``rel_to_drop``). The Hele-Shaw field is recomputed from the
kept positions with :class:`taichi_hsdem.fluid.PressureSolver` for each
permeability model:

* ``kozeny_carman`` (shipped, docs/model.md): cells whose centre lies in a disk take
  Kozeny-Carman, the others ``H^2 / 12``;
* ``gap_h3``: the gap ``h = H - 2 sqrt(r^2 - rho^2)`` left in the column at the
  cell centre, as one film: ``kappa = h^3 / (12 H)`` (depth-integrated conductance
  ``h^3 / 12`` over the nominal gap);
* ``lubrication``: the same gap as the two films it is, above and below the
  sphere, ``2 (h/2)^3 / 12``: ``kappa = h^3 / (48 H)`` in the disks;
* ``impermeable``: ``1e-6 H^2/12`` in the disks (the 2D obstacle limit; with
  ``--particles prisms`` the matching model);

each as it is and with ``+wall``, the no-slip side walls' boundary layer (which
Darcy's law has not): every permeability times ``1 - exp(-d / delta)``, ``d`` the
cell centre's distance to the nearest side wall. With ``delta = 0.315 H`` a straight
channel of width ``W >> H`` passes the exact rectangular-duct flux,
``W H^3 dp / (12 eta L) (1 - 0.630 H / W)`` (the series' leading terms: the
displacement thickness of each wall is ``(96 / pi^5) (31/32) zeta(5) H``); the
depth-averaged Brinkman equation's ``H / sqrt(12)`` gives 8 % less. Each choice on
the simulator's grid and on one three times finer (``_x3``), timed.

Usage::

    python tools/stokes_validation.py [SCENE] [--quick] [--out DIR] [--set KEY=VALUE ...]
        [--times T_UNCLOGGED[,T_CLOGGED]] [--states NPZ] [--particles spheres|prisms]
        [--mesh H_FAR:H_PARTICLE:H_FILM ...] [--order 2|3] [--threads N]

Writes to ``--out`` (default ``runs/stokes/``): ``states.npz`` (the kept states:
``--states`` re-runs the comparison from it without the simulation),
``errors.json``, ``fields.npz``, and per instant ``<instant>_p_stokes.png``,
``<instant>_p_hele_shaw.png``, ``<instant>_rel_error.png``,
``<instant>_rel_error_models.png``, then ``cost_vs_error.png`` and
``mesh_study.png``. Exit 2 (one line, no traceback) when NGSolve or matplotlib is
missing or the scene cannot be used.
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import stokes_fem  # noqa: E402

DEFAULT_SCENE = HERE.parent / "scenes" / "hourglass24.toml"
# Mesh levels: largest edge anywhere over the gap H, on a particle over its radius,
# in a thin film over the film's thickness (stokes_fem.narrow_gaps). The study
# runs Taylor-Hood P3/P2 (geometry curved to third order) on each; --quick runs
# P2/P1 on QUICK_LEVEL. Two spheres in a channel (H = 1.7, d = 1.6, gaps
# 0.05-0.1): P3 came within 0.2 % of the converged flux with 38,000 unknowns;
# P2 was 8 % off on the same mesh (12,000 unknowns) and 1.4 % off on one 2.4
# times finer (56,000). The films set most of the element count, so the levels
# differ less in unknowns (hourglass24: 340,000-470,000) than in their sizes; the
# finest needs 11.6 GB of memory (UMFPACK's factors) and 2.5-4 minutes a solve on
# one core.
MESH_LEVELS = ((0.7, 0.7, 1.4), (0.6, 0.6, 1.2), (0.5, 0.5, 1.0), (0.45, 0.45, 0.85))
ORDER = 3
QUICK_LEVEL, QUICK_ORDER = (0.5, 0.5, 1.0), 2      # about 1 GB, 10 s a solve
# A gap not above the largest diameter is raised to this multiple of it
# (hourglass24: 1.6 -> 1.7): spheres must not touch the plates.
GAP_FACTOR = 1.0625
FRAME_DT = 0.5           # s between kept frames when the instants are chosen here
UNCLOGGED_LEAD = 1.0     # s: the unclogged instant is this long before the first escape
MODELS = ("kozeny_carman", "gap_h3", "lubrication", "impermeable")
VARIANTS = MODELS + tuple(f"{m}+wall" for m in MODELS)
# Displacement thickness of a side wall's layer over the gap (module docstring).
WALL_LAYER = 96.0 / math.pi ** 5 * (31.0 / 32.0) * 1.0369277551433699
REFINE = (1, 3)          # Hele-Shaw grids: the simulator's, and three times finer
IMPERMEABLE = 1e-6       # of the free permeability
PAPER = {"max_rel_error": 0.13, "typical_rel_error": 0.05,
         "source": "Zhou et al. 2024, Sec. 3.1, Figs. 5-6"}


class UsageError(Exception):
    """A problem the user can fix; reported as one line, exit 2."""


# --------------------------------------------------------------------- simulator
def simulate(scene_path, overrides, times=None):
    """Run the scene and keep its states: the only place that touches the simulator.

    Parameters
    ----------
    scene_path : path
    overrides : list of str
        ``section.key=value``; ``fluid.gap`` is added when the scene's gap is not
        above its largest particle (see :data:`GAP_FACTOR`).
    times : list of float, optional
        The instants to keep (unclogged, clogged). Default: a frame every
        :data:`FRAME_DT` s, chosen from after the run (:func:`choose_instants`).

    Returns
    -------
    dict
        ``meta`` (grid, outline, fluid constants, gap decision, run summary) and
        ``frames``: list of ``(t, centres, radii, p_hs_simulator)``.
    """
    import taichi_hsdem as th
    # The comparison takes one realization. Its trajectory is the paper's model's
    # (particles as fixed obstacles, what Sec. 3.1 compared) unless the overrides
    # say otherwise: the instants it picks, and so the figures, stay those of the
    # README whatever the simulator's default.
    overrides = ["run.realizations=1", "fluid.particle_flux=false"] + list(overrides)
    try:
        scene = th.load_scene(scene_path, overrides)
    except th.SceneError as exc:
        raise UsageError(str(exc)) from None
    shapes = {sp.shape for sp in scene.particles}
    if shapes != {"circle"}:
        raise UsageError(f"{scene_path}: only disks have a sphere to compare with, "
                         f"the scene has {sorted(shapes)}")
    fl = scene.fluid
    if not fl.enabled or fl.bc != "pressure":
        raise UsageError(f"{scene_path}: needs fluid.bc = \"pressure\" (inlet and outlet "
                         f"pressures), got {fl.bc!r}")
    d_max = max(sp.diameter for sp in scene.particles)
    gap = {"file": fl.gap, "largest_diameter": d_max, "overridden": False, "used": fl.gap}
    if fl.gap <= d_max:
        used = round(GAP_FACTOR * d_max, 12)
        overrides.append(f"fluid.gap={used}")
        scene = th.load_scene(scene_path, overrides)
        gap.update(overridden=True, used=used, why=(
            f"the scene's gap {fl.gap} does not exceed its largest diameter {d_max}: "
            f"spheres would touch the plates; run with fluid.gap={used}"))
    sim = th.Simulation(scene)
    m = sim.model
    radius = np.array([s.shape.radius for s in m.species])
    frames = []
    # Stokes holds the spheres still, so its Hele-Shaw counterpart is the pressure
    # of fixed obstacles in the frame's places; where the particles carry their
    # volume (fluid.particle_flux) the simulator's own pressure also holds their
    # motion, and the frame is solved again with them held.
    held = None
    if sim.scene.fluid.particle_flux:
        from taichi_hsdem.fluid import PressureSolver
        held = PressureSolver(m.fluid_active, m.fluid_dx, m.fluid_dx, fl.viscosity, m.bc(),
                              tol=fl.solver_tol, gap=sim.scene.fluid.gap)

    def keep(s):
        st = s.state()
        alive = st["alive"][0]
        if held is None:
            p = np.array(s.pressure()[0], dtype=float)
        else:
            p = held.solve(s.fluid.kappa.to_numpy()[0].astype(float))[0]
        frames.append((float(s.t), st["x"][0][alive].copy(), radius[st["species"][alive]], p))

    t_end = scene.run.t_end
    frame_times = (sorted(times) if times else
                   list(np.arange(0.0, t_end + 0.5 * FRAME_DT, FRAME_DT)))
    t0 = time.perf_counter()
    result = sim.run(on_frame=keep, frame_times=frame_times)
    real = result.summary["realizations"][0]
    escapes = [t for r, t, s in result.series if r == 0 and s > 0]
    g = m.geometry
    meta = {
        "scene": str(scene_path), "overrides": overrides, "gap": gap,
        "viscosity": fl.viscosity, "p_in": fl.p_in, "p_out": fl.p_out,
        "dx": float(m.fluid_dx), "origin": [float(g.x_min), float(g.y_min)],
        "x_range": [float(g.x_min), float(g.x_max)],
        "active": np.asarray(m.fluid_active, dtype=bool),
        "outline": np.asarray(g.outline, dtype=float),
        "kappa_species": [float(s.kappa) for s in m.species],
        "run": {"clogged": bool(real["clogged"]), "t_clog": real["t_clog"],
                "t_stop": real["t_stop"], "escapees": real["escapees"],
                "first_escape": min(escapes) if escapes else None,
                "seed": real["seed"], "wall_time_s": time.perf_counter() - t0},
    }
    return {"meta": meta, "frames": frames}


def choose_instants(run, times):
    """Pick the unclogged and clogged frames from a :func:`simulate` run.

    Unclogged: the frame :data:`UNCLOGGED_LEAD` s before the first escape (the
    front of the stream in the taper, the neck open), or ``times[0]``. Clogged:
    the state where the run stopped after the clog (its arch settled for
    ``clog.window``), or ``times[1]``; none when the run did not clog.

    Returns
    -------
    dict
        ``{"unclogged": frame, "clogged": frame or absent}``.
    """
    frames, meta = run["frames"], run["meta"]["run"]

    def nearest(t):
        return min(frames, key=lambda f: abs(f[0] - t))

    out = {}
    if times:
        out["unclogged"] = nearest(times[0])
        if len(times) > 1:
            out["clogged"] = nearest(times[1])
        return out
    first = meta["first_escape"]
    t_u = (first - UNCLOGGED_LEAD) if first is not None else 0.5 * frames[-1][0]
    out["unclogged"] = nearest(max(t_u, 0.0))
    if meta["clogged"]:
        out["clogged"] = frames[-1]
    return out


def save_states(path, meta, instants):
    """``states.npz``: what the comparison needs, without the simulator."""
    arrays = {"active": meta["active"], "outline": meta["outline"]}
    for name, (t, x, r, p) in instants.items():
        arrays.update({f"{name}_t": t, f"{name}_x": x, f"{name}_r": r, f"{name}_p_sim": p})
    info = {k: v for k, v in meta.items() if k not in ("active", "outline")}
    info["instants"] = list(instants)
    np.savez_compressed(path, meta=json.dumps(info), **arrays)


def load_states(path):
    """Inverse of :func:`save_states`: ``(meta, instants)``."""
    with np.load(path) as z:
        meta = json.loads(str(z["meta"]))
        meta["active"], meta["outline"] = z["active"], z["outline"]
        instants = {n: (float(z[f"{n}_t"]), z[f"{n}_x"], z[f"{n}_r"], z[f"{n}_p_sim"])
                    for n in meta.pop("instants")}
    return meta, instants


# --------------------------------------------------------------------- Hele-Shaw
def cell_centres(meta, refine=1):
    """Centres ``(nx*refine, ny*refine, 2)`` of the (refined) Hele-Shaw grid."""
    nx, ny = meta["active"].shape
    h = meta["dx"] / refine
    xs = meta["origin"][0] + (np.arange(nx * refine) + 0.5) * h
    ys = meta["origin"][1] + (np.arange(ny * refine) + 0.5) * h
    return np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1)


def active_mask(meta, refine):
    """Fluid cells of a refined grid: centre inside the outline (refine 1: the
    simulator's own mask)."""
    if refine == 1:
        return np.asarray(meta["active"], dtype=bool)
    from matplotlib.path import Path
    c = cell_centres(meta, refine)
    return Path(meta["outline"]).contains_points(c.reshape(-1, 2)).reshape(c.shape[:2])


def permeability(model, centres_xy, x, r, gap, kappa_kc, walls=None):
    """Permeability at points (cell centres) for one model (see the module docstring).

    Parameters
    ----------
    model : str
        One of :data:`MODELS`, optionally followed by ``+wall``.
    centres_xy : (..., 2) ndarray
    x, r : (N, 2), (N,) ndarray
        Disk centres and radii.
    gap : float
    kappa_kc : (N,) ndarray
        Each disk's Kozeny-Carman permeability (the simulator's, per species).
    walls : (E, 2, 2) ndarray, optional
        Side-wall segments, needed for ``+wall``.

    Returns
    -------
    ndarray, shape centres_xy.shape[:-1]
    """
    model, _, wall = model.partition("+")
    free = gap * gap / 12.0
    pts = centres_xy.reshape(-1, 2)
    kappa = np.full(len(pts), free)
    chord = np.zeros(len(pts))          # largest solid half-thickness over the disks
    for centre, rad, kc in zip(x, r, kappa_kc):
        rho2 = np.sum((pts - centre) ** 2, axis=1)
        inside = rho2 <= rad * rad      # the simulator's test: centre in the disk
        if model == "kozeny_carman":
            kappa = np.where(inside, np.minimum(kappa, kc), kappa)
        elif model == "impermeable":
            kappa = np.where(inside, IMPERMEABLE * free, kappa)
        chord = np.where(inside, np.maximum(chord, np.sqrt(np.maximum(rad * rad - rho2, 0))),
                         chord)
    h = np.maximum(gap - 2.0 * chord, 0.0)
    if model == "gap_h3":
        kappa = h ** 3 / (12.0 * gap)
    elif model == "lubrication":
        kappa = np.where(chord > 0, h ** 3 / (48.0 * gap), kappa)
    elif model not in ("kozeny_carman", "impermeable"):
        raise ValueError(f"unknown permeability model {model!r}")
    if wall == "wall":
        kappa = kappa * (1.0 - np.exp(-wall_distance(pts, walls) / (WALL_LAYER * gap)))
    elif wall:
        raise ValueError(f"unknown permeability modifier {wall!r}")
    return kappa.reshape(centres_xy.shape[:-1])


def wall_distance(pts, walls):
    """Distance from each point to the nearest wall segment."""
    a, b = walls[:, 0], walls[:, 1]
    ab = b - a
    t = np.clip(((pts[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    foot = a + t[..., None] * ab
    return np.linalg.norm(pts[:, None, :] - foot, axis=-1).min(axis=1)


def hele_shaw(meta, x, r, model, refine=1, repeats=5):
    """Hele-Shaw pressure on the simulator's cell centres for one model and grid.

    Returns
    -------
    p : ndarray (nx, ny)
        Sampled at the simulator's cell centres (the centre cell of each 3 x 3
        block of a refined grid); NaN in walls.
    seconds : float
        Best of ``repeats`` (the machine is shared: the best is the cost): raster,
        solver set-up and solve.
    """
    from taichi_hsdem.fluid import PressureSolver
    from taichi_hsdem.laws import kozeny_carman
    gap = meta["gap"]["used"]
    active = active_mask(meta, refine)
    kc = np.array([kozeny_carman(1.0, 2 * rad, math.pi * rad * rad, gap) for rad in r])
    bc = {"kind": "pressure", "p_in": meta["p_in"], "p_out": meta["p_out"]}
    walls = stokes_fem.wall_segments(meta["outline"], *meta["x_range"])
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        kappa = np.where(active, permeability(model, cell_centres(meta, refine), x, r, gap,
                                              kc, walls), 0.0)
        solver = PressureSolver(active, meta["dx"] / refine, meta["dx"] / refine,
                                meta["viscosity"], bc, gap=gap)
        p, _ = solver.solve(kappa[None])
        best = min(best, time.perf_counter() - t0)
    off = refine // 2
    return p[0][off::refine, off::refine], best


def error_stats(p_hs, p_s, drop):
    """Median, 95th percentile and maximum of the relative error over the cells
    where both fields exist; the same for the error over the pressure drop."""
    ok = np.isfinite(p_hs) & np.isfinite(p_s)
    diff = np.abs(p_hs[ok] - p_s[ok])
    rel, rel_drop = diff / np.abs(p_s[ok]), diff / drop

    def stats(e):
        return {"median_rel_error": float(np.median(e)),
                "p95_rel_error": float(np.percentile(e, 95)),
                "max_rel_error": float(e.max()),
                "fraction_below_5pct": float(np.mean(e < 0.05))}  # the paper's "mostly"
    return {**stats(rel), "rel_to_drop": stats(rel_drop), "cells": int(ok.sum())}


# --------------------------------------------------------------------- Stokes
def stokes_gap_averaged(meta, x, r, level, kind, order=ORDER):
    """Solve 3D Stokes for one state on one mesh level; return the gap-averaged
    pressure at the simulator's active cell centres and what the solve cost."""
    h_far, h_part, h_film = level
    gap = meta["gap"]["used"]
    t0 = time.perf_counter()
    walls = stokes_fem.wall_segments(meta["outline"], *meta["x_range"])
    bridges = stokes_fem.find_bridges(x, r, walls)
    films = stokes_fem.narrow_gaps(gap, x, r, walls, bridges, kind)
    shape = stokes_fem.pore_space(meta["outline"], gap, x, r, bridges, kind, h_part)
    mesh = stokes_fem.mesh_pore_space(shape, h_far * gap, films=films, h_film=h_film,
                                      curve_order=order)
    t_mesh = time.perf_counter() - t0
    sol = stokes_fem.solve_stokes(mesh, meta["viscosity"], meta["p_in"], meta["p_out"],
                                  order=order)
    active = np.asarray(meta["active"], dtype=bool)
    xy = cell_centres(meta)[active]
    c = stokes_fem.solid_half_thickness(xy, gap, x, r, bridges, kind)
    t1 = time.perf_counter()
    pbar, missed = stokes_fem.gap_average(sol, xy, gap, c)
    p_s = np.full(active.shape, np.nan)
    p_s[active] = pbar
    info = {"h_far_over_gap": h_far, "h_particle_over_radius": h_part,
            "h_film_over_thickness": h_film, "order": order, "elements": sol.elements,
            "ndof": sol.ndof, "mesh_seconds": t_mesh, "solve_seconds": sol.seconds,
            "average_seconds": time.perf_counter() - t1,
            "flux_in": sol.flux_in, "flux_out": sol.flux_out, "films": len(films),
            # zero for straight elements; curved ones in thin films may leak
            "flux_imbalance": abs(sol.flux_in - sol.flux_out) / max(abs(sol.flux_in), 1e-300),
            "quadrature_points_missed": missed, "bridges": len(bridges),
            "bridged_contacts": [[b.between[0], b.between[1], round(b.gap, 6)]
                                 for b in bridges]}
    return p_s, info


# --------------------------------------------------------------------- figures
def _field(ax, meta, field, x, r, title, cmap, vmin=None, vmax=None, label=""):
    import matplotlib.patches as mp
    x0, y0 = meta["origin"]
    nx, ny = field.shape
    ext = (x0, x0 + nx * meta["dx"], y0, y0 + ny * meta["dx"])
    im = ax.imshow(np.ma.masked_invalid(field).T, origin="lower", extent=ext, cmap=cmap,
                   vmin=vmin, vmax=vmax, interpolation="nearest")
    ol = np.vstack([meta["outline"], meta["outline"][:1]])
    ax.plot(ol[:, 0], ol[:, 1], "k-", lw=0.8)
    for c, rad in zip(x, r):
        ax.add_patch(mp.Circle(c, rad, fill=False, lw=0.6, color="k"))
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.figure.colorbar(im, ax=ax, shrink=0.8, label=label)


def figures(out, name, meta, x, r, p_s, p_hs, models_p, level, order):
    """The two pressure fields and the error maps of one instant."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    lo, hi = sorted((meta["p_out"], meta["p_in"]))
    mesh = f"P{order}/P{order - 1}, h {level[0]} H, {level[1]} r, {level[2]} film"
    for fname, fld, title, cmap, vr, lab in (
            ("p_stokes", p_s, f"{name}: gap-averaged 3D Stokes pressure ({mesh})",
             "viridis", (lo, hi), "p"),
            ("p_hele_shaw", p_hs, f"{name}: Hele-Shaw pressure (Kozeny-Carman, shipped)",
             "viridis", (lo, hi), "p"),
            ("rel_error", np.abs(p_hs - p_s) / np.abs(p_s),
             f"{name}: |p_HS - p_S| / |p_S| (Kozeny-Carman)", "magma", (0, None), "e")):
        fig, ax = plt.subplots(figsize=(10, 3.2))
        _field(ax, meta, fld, x, r, title, cmap, *vr, label=lab)
        fig.tight_layout()
        fig.savefig(out / f"{name}_{fname}.png", dpi=130)
        plt.close(fig)
    vmax = max(np.nanpercentile(np.abs(p - p_s) / np.abs(p_s), 99.5) for p in models_p.values())
    fig, axes = plt.subplots(len(models_p), 1, figsize=(10, 2.6 * len(models_p)))
    for ax, (model, p) in zip(np.atleast_1d(axes), models_p.items()):
        _field(ax, meta, np.abs(p - p_s) / np.abs(p_s), x, r, f"{name}: {model}", "magma",
               0, vmax, "e")
    fig.tight_layout()
    fig.savefig(out / f"{name}_rel_error_models.png", dpi=110)
    plt.close(fig)


def summary_charts(out, report):
    """Error against cost of every Hele-Shaw choice; error against mesh size."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    inst = [n for n in ("unclogged", "clogged") if report.get(n)]
    fig, axes = plt.subplots(1, len(inst), figsize=(6 * len(inst), 4.5), squeeze=False)
    for ax, name in zip(axes[0], inst):
        for model, e in report[name]["models"].items():
            base = model.split("_x")[0].split("+")[0]
            colour = {"kozeny_carman": "C0", "gap_h3": "C1", "lubrication": "C2",
                      "impermeable": "C3"}[base]
            sec = e["hele_shaw_seconds"]
            ax.plot([sec, sec], [e["median_rel_error"], e["max_rel_error"]], "-", c=colour,
                    lw=0.8)
            ax.plot(sec, e["p95_rel_error"], "o", ms=6, c=colour,
                    mfc="white" if "+wall" in model else colour)
            ax.annotate(model.replace("kozeny_carman", "KC").replace("lubrication", "lub")
                        .replace("impermeable", "imp"), (sec, e["p95_rel_error"]),
                        fontsize=6, xytext=(3, 0), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.axhline(PAPER["max_rel_error"], ls="--", c="grey", lw=0.8)
        ax.axhline(PAPER["typical_rel_error"], ls=":", c="grey", lw=0.8)
        ax.set_xlabel("Hele-Shaw cost: raster + set-up + solve, s (best of 5)")
        ax.set_ylabel("|p_HS - p_S| / |p_S|: dot p95, line median to max")
        ax.set_title(f"{name}; hollow: +wall; dashed: paper's max 13 %, dotted: 5 %",
                     fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "cost_vs_error.png", dpi=130)
    plt.close(fig)
    study = report["mesh_study"]
    if len(study) < 2:
        return
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name in inst:
        nd = [lv[name]["stokes"]["ndof"] for lv in study]
        for key, mk in (("median_rel_error", "o-"), ("p95_rel_error", "s-"),
                        ("max_rel_error", "^-")):
            ax.semilogx(nd, [lv[name]["kozeny_carman"][key] for lv in study], mk,
                        label=f"{name} {key.split('_')[0]}")
    ax.set_xlabel("Stokes unknowns")
    ax.set_ylabel("relative error, Kozeny-Carman vs Stokes")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "mesh_study.png", dpi=130)
    plt.close(fig)


# --------------------------------------------------------------------- main
def _changes(study, instants):
    """Relative change of every error figure between the last two mesh levels."""
    if len(study) < 2:
        return None
    a, b = study[-2], study[-1]
    out = {}
    for name in instants:
        for model in b[name]:
            if model == "stokes":
                continue
            for key in ("median_rel_error", "p95_rel_error", "max_rel_error"):
                out[f"{name}/{model}/{key}"] = abs(b[name][model][key] / a[name][model][key] - 1)
    return out


def compare(out, meta, instants, levels, kind, order=ORDER):
    """Stokes on every mesh level, the Hele-Shaw models, the report."""
    drop = abs(meta["p_in"] - meta["p_out"])
    report, study, fields = {}, [], {}
    for level in levels:
        entry = {"h_far_over_gap": level[0], "h_particle_over_radius": level[1],
                 "h_film_over_thickness": level[2]}
        for name, (t, x, r, p_sim) in instants.items():
            p_s, info = stokes_gap_averaged(meta, x, r, level, kind, order)
            entry[name] = {"stokes": info}
            for model in VARIANTS:
                p_hs, _ = hele_shaw(meta, x, r, model, repeats=1)
                entry[name][model] = error_stats(p_hs, p_s, drop)
            fields[name] = p_s
            print(f"stokes_validation: {name} mesh {level}: {info['ndof']} unknowns, "
                  f"{info['solve_seconds']:.0f} s, flux in/out {info['flux_in']:.6g}/"
                  f"{info['flux_out']:.6g}; Kozeny-Carman "
                  f"median {entry[name]['kozeny_carman']['median_rel_error']:.4f} max "
                  f"{entry[name]['kozeny_carman']['max_rel_error']:.4f}", file=sys.stderr)
        study.append(entry)
    arrays = {}
    for name, (t, x, r, p_sim) in instants.items():
        p_s = fields[name]
        models, models_p = {}, {}
        for refine in REFINE:
            for model in VARIANTS:
                label = model if refine == 1 else f"{model}_x{refine}"
                p_hs, sec = hele_shaw(meta, x, r, model, refine)
                models[label] = {**error_stats(p_hs, p_s, drop), "hele_shaw_seconds": sec,
                                 "grid_refinement": refine}
                models_p[label] = p_hs
                arrays[f"{name}_p_hs_{label}"] = p_hs
        arrays[f"{name}_p_stokes"] = p_s
        p_kc = models_p["kozeny_carman"]
        report[name] = {
            "t": t, "particles": int(len(r)),
            **{k: models["kozeny_carman"][k] for k in
               ("median_rel_error", "p95_rel_error", "max_rel_error", "rel_to_drop", "cells")},
            "models": models, "stokes": study[-1][name]["stokes"],
            "shipped_model_matches_simulator": float(np.nanmax(np.abs(p_kc - p_sim)) / drop),
        }
        figures(out, name, meta, x, r, p_s, p_kc,
                {k: v for k, v in models_p.items() if k in VARIANTS}, levels[-1], order)
    np.savez_compressed(out / "fields.npz", **arrays)
    report["mesh_study"] = study
    report["mesh_change_last_two"] = _changes(study, list(instants))
    return report


def _parse_levels(specs):
    levels = []
    for s in specs:
        try:
            level = tuple(float(v) for v in s.split(":"))
        except ValueError:
            level = ()
        if len(level) != 3 or not all(v > 0 for v in level):
            raise UsageError(f"--mesh {s!r}: expected three sizes > 0, "
                             "H_FAR:H_PARTICLE:H_FILM, e.g. 0.3:0.3:0.5")
        levels.append(level)
    return levels


def main(argv=None):
    """Command line; returns the exit status."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE))
    ap.add_argument("--quick", action="store_true",
                    help=f"P{QUICK_ORDER} on one mesh {QUICK_LEVEL} instead of P{ORDER} on "
                         f"the study's {MESH_LEVELS}")
    ap.add_argument("--out", default="runs/stokes", help="output folder (%(default)s)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scene override, as for python -m taichi_hsdem")
    ap.add_argument("--times", help="T_UNCLOGGED[,T_CLOGGED] instead of the automatic choice")
    ap.add_argument("--states", help="a states.npz of an earlier run: skip the simulation")
    ap.add_argument("--particles", choices=("spheres", "prisms"), default="spheres")
    ap.add_argument("--mesh", action="append", default=[], metavar="H_FAR:H_PARTICLE:H_FILM",
                    help="a mesh level instead of the built-in ones (repeatable): largest "
                         "edge over the gap, on a particle over its radius, in a film "
                         "over its thickness")
    ap.add_argument("--order", type=int, choices=(2, 3),
                    help=f"velocity order k of Taylor-Hood P_k/P_(k-1) (default {ORDER}; "
                         f"{QUICK_ORDER} with --quick)")
    ap.add_argument("--threads", type=int, default=1, help="NGSolve threads (%(default)s)")
    args = ap.parse_args(argv)
    try:
        stokes_fem.require(args.threads)
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise UsageError("the figures need matplotlib: pip install -e '.[plot]'") from None
        levels = _parse_levels(args.mesh) or ([QUICK_LEVEL] if args.quick else list(MESH_LEVELS))
        order = args.order or (QUICK_ORDER if args.quick else ORDER)
        times = None
        if args.times:
            try:
                times = [float(v) for v in args.times.split(",")]
            except ValueError:
                raise UsageError(f"--times {args.times!r}: expected numbers") from None
        out = pathlib.Path(args.out)
        wall0 = time.perf_counter()
        if args.states:
            if not pathlib.Path(args.states).is_file():
                raise UsageError(f"--states {args.states}: no such file")
            meta, instants = load_states(args.states)
        else:
            if not pathlib.Path(args.scene).is_file():
                raise UsageError(f"{args.scene}: no such scene file")
            run = simulate(args.scene, args.set, times)
            meta, instants = run["meta"], choose_instants(run, times)
    except (stokes_fem.MissingExtra, UsageError) as exc:
        print(f"stokes_validation: {exc}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    if not args.states:
        save_states(out / "states.npz", meta, instants)
    if "clogged" not in instants:
        print("stokes_validation: the run did not clog: only the unclogged instant",
              file=sys.stderr)
    report = compare(out, meta, instants, levels, args.particles, order)
    import ngsolve
    report.update({
        "definition": "rel_error = |p_HS - p_S| / |p_S| at every active Hele-Shaw cell "
                      "centre, p_S the 3D Stokes pressure averaged over the fluid part "
                      "of the gap there (paper Eq. 16); rel_to_drop: the same difference "
                      "over |p_in - p_out|. Top-level figures: the shipped Kozeny-Carman "
                      "model on the simulator's grid against the finest mesh.",
        "particles_as": args.particles, "gap": meta["gap"], "run": meta.get("run"),
        "scene": meta["scene"], "paper": PAPER, "solver": {
            "package": f"ngsolve {ngsolve.__version__}", "elements": f"Taylor-Hood "
            f"P{order}/P{order - 1} on tetrahedra from Netgen, geometry curved to "
            f"order {order}", "linear_solver": "UMFPACK",
            "threads": args.threads},
        "wall_time_s": time.perf_counter() - wall0, "quick": bool(args.quick)})
    if "clogged" not in instants:
        report["clogged"] = None
    summary_charts(out, report)
    (out / "errors.json").write_text(json.dumps(report, indent=1))
    for name in ("unclogged", "clogged"):
        if report.get(name):
            e = report[name]
            print(f"{name}: median {e['median_rel_error']:.4f}, p95 {e['p95_rel_error']:.4f}, "
                  f"max {e['max_rel_error']:.4f} (Kozeny-Carman vs Stokes)")
    print(f"wrote {out / 'errors.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
