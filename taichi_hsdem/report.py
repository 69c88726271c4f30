"""Plots where people look, in a run's output folder:

* ``escapees.png``: escapees against time for every realization, their mean, and,
  with a flow-rate inlet, the empirical law of a steady stream, whose escape rate
  is ``4 phi Q / (H pi d^2)`` (docs/model.md section 4; ``phi`` the packing
  fraction of the control volume, ``d`` the particles' mean equivalent
  diameter). The particles start at rest and the first ones need a transit
  time to reach the constriction, so the law is drawn over the steady stream
  only (:func:`law_line`): from the time the stream is established, the mean
  over realizations of their first escape, through the mean curve there;
* ``pressure_drop.png``, with a flow-rate inlet (:func:`plot_pressure_drop`): the
  pressure drop the pump reads (``flow.csv``) against time, each realization
  faint behind their mean;
* ``pmf.png`` (at least :data:`taichi_hsdem.stats.MIN_CLOGS` clogged
  realizations; fewer cannot show a shape, and the summary says why it is
  missing): the PMF of ``s / <s>`` on a log scale with ``exp(-x)``, the
  geometric law's, titled with the clog probability per escapee and the
  goodness-of-fit p-value of the geometric law (:func:`pmf_title`).

With several throats (a micromodel, :func:`plot_network`):

* ``permeability.png``: the permeability of the whole domain against time,
  ``K(t)/K0 = (Q / dp) / (Q0 / dp0)`` from ``flow.csv``'s flow rate ``Q`` and
  pressure drop ``dp`` (Darcy: ``K`` proportional to ``Q / dp`` in one geometry),
  ``K0`` the empty domain's (:func:`empty_flow`: the same grid and solve without
  particles);
* ``throats_clogged.png``: the fraction of throats clogged against the particles
  injected (``network.csv``);
* in both, each realization faint behind their mean (:func:`ensemble_mean`), in
  which a clogged realization that stopped is kept at its final state (dotted
  past its end): it stays clogged, so the mean never reads as unclogging where
  one stopped;
* ``clog_map.png``: the geometry with each throat drawn across its gap, coloured
  by the share of realizations in which it is clogged at the end.

Matplotlib comes with the ``plot`` extra; without it the plots are skipped and
the summary says so.
"""
from __future__ import annotations

import functools
import warnings
from pathlib import Path

import numpy as np

from . import stats
from .geometry.walls import fluid_area
from .laws import theory_escapees


def without_library_warnings(draw):
    """``draw`` with the warnings raised while it plots (matplotlib's "glyph
    missing from font", "no artists with labels", numpy's on empty data) kept off
    the user's terminal: each is about a figure's looks, never its numbers, and
    comes with a source line of ours the user cannot act on."""
    @functools.wraps(draw)
    def quiet(*args, **kwargs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return draw(*args, **kwargs)
    return quiet


#: Why an ensemble plot is left out (its ``*_skipped`` entry in the summary).
NO_STABLE = "no stable realization with rows to draw (every one went unstable, or none ran)"


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def stream_start(per) -> float | None:
    """When the steady stream is established: the mean over realizations of the
    time of each one's first escape (its first sample with ``s >= 1``); None when
    none escaped. ``per`` maps a realization to its ``[(t, s), ...]`` samples."""
    firsts = [next(t for t, s in rows if s >= 1) for rows in per.values()
              if any(s >= 1 for _, s in rows)]
    return float(np.mean(firsts)) if firsts else None


def law_line(grid, mean, t_start, law):
    """The steady-stream law as a line ``(t, s)`` over ``grid`` from ``t_start``:
    through the mean curve there, ``s = mean(t_start) + 4 phi Q (t - t_start) /
    (H pi d^2)``. ``mean`` is the mean escapee curve on ``grid``, ``law`` the
    ``(phi, Q, H, d)`` of :func:`steady_stream_law`.

    Examples
    --------
    >>> t, s = law_line(np.array([0.0, 1.0, 2.0]), np.array([0.0, 0.0, 2.0]), 1.5,
    ...                 (0.25, 1.0, 1.0, 1.0))
    >>> t.tolist(), [round(float(v), 4) for v in s]     # slope 4 phi Q/(H pi d^2) = 1/pi
    ([1.5, 2.0], [1.0, 1.1592])
    """
    phi, q, h, d = law
    t = np.concatenate([[t_start], grid[grid > t_start]])
    return t, float(np.interp(t_start, grid, mean)) + theory_escapees(phi, t - t_start, q, h, d)


def draw_escapees(ax, result, law=None) -> dict:
    """Escapees against time on ``ax``: each stable realization, their mean and,
    with ``law`` (see :func:`plot_run`), the steady-stream law from the time the
    stream is established (:func:`stream_start`, :func:`law_line`). Returns the
    law's anchor for the summary: ``{"law_from_t": t, "law_from_s": s}``, or
    ``{"law_skipped": why}`` when it is not drawn; ``{}`` without ``law``."""
    real = result.summary["realizations"]
    per = {}
    for r, t, s in result.series:
        if real[r]["status"] != "unstable":
            per.setdefault(r, []).append((t, s))
    t_max = 0.0
    for r, rows in sorted(per.items()):
        t, s = np.array(rows).T
        ax.step(t, s, where="post", lw=0.8, alpha=0.5, color="0.5")
        t_max = max(t_max, float(t.max()))
    grid = mean = None
    if per:
        grid = np.linspace(0.0, t_max, 200)
        curves = [np.interp(grid, *np.array(rows).T) for rows in per.values()]
        mean = np.mean(curves, axis=0)
        ax.plot(grid, mean, color="C0", lw=2, label=f"mean of {len(curves)} realization(s)")
    if law is None:
        return {}
    t_start = stream_start(per)
    if t_start is None:
        return {"law_skipped": "no particle escaped: no stream to compare with the law"}
    t, s = law_line(grid, mean, t_start, law)
    unit = " s" if result.scene.units == "SI" else ""
    ax.plot(t, s, "k--", lw=1, label=r"slope $4 \phi Q / (H \pi d^2)$" + f", phi = "
            f"{law[0]:.3g}, from the mean first escape (t = {t_start:.3g}{unit})")
    return {"law_from_t": t_start, "law_from_s": float(s[0])}


@without_library_warnings
def plot_run(result, folder: Path, law=None) -> dict:
    """Draw ``escapees.png`` (and ``pmf.png`` when the sample supports it) into
    ``folder``; ``law`` is the ``(phi, Q, H, d)`` of the steady-stream line, None
    for none. Returns what was drawn, for the summary: the files, the law's
    anchor (:func:`draw_escapees`) and ``pmf_skipped``, why there is no PMF."""
    try:
        plt = _pyplot()
    except ImportError:
        return {"skipped": 'matplotlib is not installed (pip install "taichi_hsdem[plot]")'}
    folder = Path(folder)
    drawn = {"escapees": "escapees.png"}
    real = result.summary["realizations"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    drawn.update(draw_escapees(ax, result, law))
    ax.set_xlabel("t (s)" if result.scene.units == "SI" else "t")
    ax.set_ylabel("escapees s")
    integer_ticks(ax.yaxis)
    ax.set_title(f"{result.scene.name}: escapees over time")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(folder / "escapees.png", dpi=110)
    plt.close(fig)

    drawn.update(plot_pressure_drop(plt, result, folder))

    counted = [r for r in real if r["status"] in ("ok", "interrupted")]
    s = np.array([r["escapees"] for r in counted], dtype=np.int64)
    c = np.array([bool(r["clogged"]) for r in counted])
    if c.sum() < stats.MIN_CLOGS:
        drawn["pmf_skipped"] = (f"{int(c.sum())} clogged realization(s): the PMF of s/<s> "
                                f"needs at least {stats.MIN_CLOGS} to show a shape")
    else:
        bins = stats.pmf_bins(s, c)
        test = stats.geometric_fit_test(s, c)
        if bins:
            fig, ax = plt.subplots(figsize=(6.4, 4.2))
            b = [x for x in bins if x["count"] > 0]
            ax.errorbar([x["x"] for x in b], [x["pmf"] for x in b],
                        yerr=[x["stderr"] for x in b], fmt="o", capsize=2,
                        label=f"{int(c.sum())} clogged of {len(s)}")
            xs = np.linspace(0, max(3.0, max(x["x"] for x in bins)), 100)
            ax.plot(xs, np.exp(-xs), "k--", lw=1, label="exp(-x) (geometric)")
            ax.set_yscale("log")
            ax.set_xlabel("x = s / <s>")
            ax.set_ylabel("PMF (density in x, over all realizations)")
            ax.set_title(pmf_title(s, c, test), fontsize=10)
            ax.legend(fontsize=8)
            fig.tight_layout()
            fig.savefig(folder / "pmf.png", dpi=110)
            plt.close(fig)
            drawn["pmf"] = "pmf.png"
        else:
            drawn["pmf_skipped"] = "every clogged realization had s = 0: s/<s> is undefined"
    return drawn


def integer_ticks(axis) -> None:
    """Ticks at whole numbers only on ``axis`` (a count: escapees, particles)."""
    from matplotlib.ticker import MaxNLocator
    axis.set_major_locator(MaxNLocator(integer=True))


def plot_pressure_drop(plt, result, folder: Path) -> dict:
    """``pressure_drop.png`` of a scene with a flow-rate inlet: the pressure drop
    the pump reads (``flow.csv``) against time, each stable realization faint,
    their mean bold, a clogged realization that stopped kept at its final drop
    (:func:`ensemble_mean`). Returns ``{"pressure_drop": name}``, or ``{}`` for a
    scene without a flow rate (under a pressure inlet the drop is imposed) or
    without rows."""
    fluid = getattr(result.scene, "fluid", None)
    if fluid is None or not fluid.enabled or fluid.bc != "flow_rate" or not result.flow:
        return {}
    real = result.summary["realizations"]
    stable = {r for r, row in enumerate(real) if row["status"] != "unstable"}
    per = {}
    for r, t, dp, _ in result.flow:
        if r in stable and np.isfinite(dp):
            per.setdefault(r, []).append((t, dp))
    if not per:
        return {"pressure_drop_skipped": NO_STABLE}
    per = {r: tuple(np.array(rows, dtype=float).T) for r, rows in per.items()}
    held = {r for r in per if real[r]["clogged"]}
    si = result.scene.units == "SI"
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    grid, mean, top = ensemble_mean(per, held)
    draw_faint(ax, per, held, top)
    ax.plot(grid, mean, color="C1", lw=2, label=ensemble_label(len(per), held))
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("t (s)" if si else "t")
    ax.set_ylabel("pressure drop (Pa)" if si else "pressure drop (dimensionless)")
    q = f"{fluid.flow_rate:.3g} m^3/s" if si else f"{fluid.flow_rate:.3g}"
    ax.set_title(f"{result.scene.name}: pressure drop at the flow rate {q}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(Path(folder) / "pressure_drop.png", dpi=110)
    plt.close(fig)
    return {"pressure_drop": "pressure_drop.png"}


def pmf_title(escapees, clogged, test=None) -> str:
    """The title of ``pmf.png``: the clog probability per escapee ``p`` (the
    censoring-aware estimate, :func:`taichi_hsdem.stats.clog_probability_per_escapee`,
    with its 95 % interval) and, beside it, the p-value of the goodness-of-fit test
    of the geometric law (:func:`taichi_hsdem.stats.geometric_fit_test`), named as a
    p-value: it is no probability of clogging.

    Examples
    --------
    >>> pmf_title([4, 1, 0, 5, 2, 7, 1, 0, 3, 9], [True] * 10)
    'PMF of s/<s>\\nclog probability per escapee 0.24 [0.13, 0.38]; geometric law: GOF p-value 0.512'
    """
    p, (lo, hi) = stats.clog_probability_per_escapee(escapees, clogged)
    test = stats.geometric_fit_test(escapees, clogged) if test is None else test
    gof = ("not tested" if test.p_value is None else f"{test.p_value:.3g}")
    return (f"PMF of s/<s>\nclog probability per escapee {p:.2g} [{lo:.2g}, {hi:.2g}]; "
            f"geometric law: GOF p-value {gof}")


def steady_stream_law(sim) -> tuple[float, float, float, float] | None:
    """``(phi, Q, H, d)`` of the escapee law of ``sim``'s scene: with a flow-rate
    inlet, the packing fraction of the control volume, the flow rate, the gap and
    the count-weighted mean equivalent diameter; None otherwise."""
    sc, m = sim.scene, sim.model
    if not sc.fluid.enabled or sc.fluid.bc != "flow_rate":
        return None
    x0, x1 = m.feed_region
    area = fluid_area(m.geometry, max(x0, m.geometry.x_min), min(x1, m.geometry.x_max))
    solid = sum(s.count * s.shape.area for s in m.species)
    n = sum(s.count for s in m.species)
    d = sum(s.count * s.d_eq for s in m.species) / n
    return solid / area, sc.fluid.flow_rate, sc.fluid.gap, d


def empty_flow(model) -> tuple[float, float] | None:
    """``(pressure drop, flow rate)`` of the empty domain: the run's fluid grid and
    boundary condition with no particle (every fluid cell at the free
    permeability ``H^2/12``), solved to 1e-10 with pyamg's CG on the finite-volume
    system the run solves, and read as ``flow.csv`` reads the run
    (:func:`~taichi_hsdem.observables.flow_rows`); None without fluid."""
    from .fluid import PressureSolver
    from .observables import flow_rows
    fl = model.scene.fluid
    if not fl.enabled:
        return None
    solver = PressureSolver(model.fluid_active, model.fluid_dx, model.fluid_dx,
                            fl.viscosity, model.bc(), n_batch=1, tol=1e-10, gap=fl.gap)
    try:
        pressure, info = solver.solve(np.where(model.fluid_active, model.kappa_free, 0.0))
    finally:
        solver.close()
    (_, _, drop, q), = flow_rows(fl, info.flux_out, np.asarray(pressure)[None], [True], 0.0)
    return drop, q


def permeability_ratio(flow, empty) -> dict:
    """``{realization: (t, K/K0)}`` arrays from ``flow`` rows (realization, t,
    pressure drop, flow rate) and ``empty`` = (dp0, Q0) (:func:`empty_flow`)."""
    dp0, q0 = empty
    per = {}
    for r, t, dp, q in flow:
        per.setdefault(r, []).append((t, (q / dp) / (q0 / dp0) if dp else np.nan))
    return {r: tuple(np.array(v).T) for r, v in per.items()}


@without_library_warnings
def plot_network(result, folder: Path, throats, geometry, empty) -> dict:
    """Draw ``permeability.png`` (with ``empty`` = (dp0, Q0), :func:`empty_flow`),
    ``throats_clogged.png`` and ``clog_map.png`` into ``folder`` (module notes);
    returns what was drawn, for the summary's ``plots``."""
    try:
        plt = _pyplot()
    except ImportError:
        return {"network_skipped": 'matplotlib is not installed (pip install '
                                   '"taichi_hsdem[plot]")'}
    folder = Path(folder)
    real = result.summary["realizations"]
    stable = {r for r, row in enumerate(real) if row["status"] != "unstable"}
    si = result.scene.units == "SI"
    drawn = {}
    # K(t) / K0
    held = {r for r in stable if real[r]["clogged"]}
    ratio = {}
    if empty is not None and result.flow:
        ratio = {r: v for r, v in permeability_ratio(result.flow, empty).items() if r in stable}
        if not ratio:
            drawn["permeability_skipped"] = NO_STABLE
    if ratio:
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        grid, mean, top = ensemble_mean(ratio, held)
        draw_faint(ax, ratio, held, top)
        ax.plot(grid, mean, color="C0", lw=2, label=ensemble_label(len(ratio), held & set(ratio)))
        ax.legend(fontsize=8)
        ax.axhline(1.0, color="k", lw=0.6, ls=":")
        ax.set_ylim(bottom=0.0)
        ax.set_xlabel("t (s)" if si else "t")
        ax.set_ylabel("K / K0")
        unit = " Pa" if si else ""
        ax.set_title(f"{result.scene.name}: permeability (K0: the empty domain, "
                     f"dp0 = {empty[0]:.3g}{unit})", fontsize=9)
        fig.tight_layout()
        fig.savefig(folder / "permeability.png", dpi=110)
        plt.close(fig)
        drawn["permeability"] = "permeability.png"
    # fraction of throats clogged against particles injected
    T = len(throats)
    per = {}
    for r, t, n, c in result.network:
        if r in stable:
            per.setdefault(r, []).append((n, c / T))
    if per:
        per = {r: tuple(np.array(rows, dtype=float).T) for r, rows in per.items()}
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        grid, mean, top = ensemble_mean(per, held, step=True)
        draw_faint(ax, per, held, top, step=True)
        ax.step(grid, mean, where="post", color="C3", lw=2,
                label=ensemble_label(len(per), held & set(per)))
        ax.set_xlabel("particles injected")
        integer_ticks(ax.xaxis)
        ax.set_ylabel(f"fraction of the {T} throats clogged")
        ax.set_ylim(0.0, 1.0)
        ax.set_title(f"{result.scene.name}: throats clogged", fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(folder / "throats_clogged.png", dpi=110)
        plt.close(fig)
        drawn["throats_clogged"] = "throats_clogged.png"
    else:
        drawn["throats_clogged_skipped"] = NO_STABLE
    # where the clogs formed
    share = np.zeros(T)
    for r, k, x, y, width, passages, clogged, t_clog in result.throats:
        if r in stable and clogged:
            share[k] += 1.0
    share /= max(1, len(stable))
    drawn.update(draw_clog_map(plt, folder / "clog_map.png", geometry, throats, share,
                               len(stable), result.scene.name, si))
    return drawn


def ensemble_mean(per, held, step=False):
    """The mean curve over realizations ``per`` (``{r: (x, y)}`` arrays, x
    increasing), each realization of ``held`` (the clogged ones, stopped) kept at
    its final value past its end: a clogged realization stays clogged, so the mean
    never reads as unclogging where one stopped. It runs to the end of the
    shortest realization not held (all of them reach it; none is extrapolated),
    or of the longest when all are held. ``step``: the curves are steps (a value
    holds until the next sample), else piecewise linear. Returns ``(grid, mean,
    top)``, ``top`` the grid's end.

    Examples
    --------
    >>> per = {0: (np.array([0.0, 0.5]), np.array([1.0, 0.2])),
    ...        1: (np.array([0.0, 1.0]), np.array([1.0, 0.6]))}
    >>> grid, mean, top = ensemble_mean(per, held={0})
    >>> top, round(float(mean[-1]), 3)       # realization 0 held at 0.2, not dropped
    (1.0, 0.4)
    """
    ends = {r: float(x[-1]) for r, (x, _) in per.items()}
    open_ends = [e for r, e in ends.items() if r not in held]
    top = min(open_ends) if open_ends else max(ends.values())
    start = min(float(x[0]) for x, _ in per.values())
    grid = np.linspace(start, top, 200) if top > start else np.array([start])
    curves = []
    for x, y in per.values():
        if step:
            at = np.searchsorted(x, grid, side="right") - 1
            curves.append(np.where(at >= 0, y[np.maximum(at, 0)], np.nan))
        else:                # np.interp holds the last value past the end
            curves.append(np.where(grid >= x[0], np.interp(grid, x, y), np.nan))
    with warnings.catch_warnings():          # before every realization's first sample: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(np.array(curves), axis=0)
    return grid, mean, top


def draw_faint(ax, per, held, top, step=False):
    """Each realization's curve of ``per`` (``{r: (x, y)}``) faint, behind the mean;
    a held one (:func:`ensemble_mean`) goes on dotted at its final value to ``top``."""
    for r, (x, y) in sorted(per.items()):
        if step:
            ax.step(x, y, where="post", lw=0.7, alpha=0.35, color="0.4")
        else:
            ax.plot(x, y, lw=0.7, alpha=0.35, color="0.4")
        if r in held and x[-1] < top:
            ax.plot([x[-1], top], [y[-1], y[-1]], lw=0.7, alpha=0.35, color="0.4", ls=":")


def ensemble_label(n, held) -> str:
    """The mean curve's legend: over how many realizations, and how many of them
    are held at their final state (:func:`ensemble_mean`)."""
    label = f"mean of {n} realization(s)"
    if held:
        label += f"; {len(held)} clogged, held at the final state (dotted)"
    return label


def draw_clog_map(plt, path, geometry, throats, share, n_real, name, si) -> dict:
    """The geometry (walls grey) with every throat's segment: open throats thin
    grey, clogged ones coloured by ``share`` (T,), the fraction of the ``n_real``
    realizations in which each is clogged at the end."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon
    g = geometry
    scale = 1e3 if si else 1.0
    fig, ax = plt.subplots(figsize=(7.5, 7.5 * (g.y_max - g.y_min) / (g.x_max - g.x_min)
                                    + 1.4))
    ax.add_patch(Polygon(g.outline * scale, closed=True, facecolor="0.97", edgecolor="0.4",
                         lw=0.8))
    for o in g.obstacles:
        ax.add_patch(Polygon(np.asarray(o) * scale, closed=True, facecolor="0.6",
                             edgecolor="0.4", lw=0.4))
    segs = np.stack([throats.start, throats.end], axis=1) * scale
    ax.add_collection(LineCollection(segs[share == 0], colors="0.75", linewidths=0.6))
    hot = share > 0
    cmap = plt.get_cmap("Reds")
    lines = LineCollection(segs[hot], cmap=cmap, linewidths=2.5)
    lines.set_array(share[hot])
    lines.set_clim(0.0, 1.0)
    ax.add_collection(lines)
    fig.colorbar(lines, ax=ax, fraction=0.04, pad=0.02,
                 label=f"share of the {n_real} realization(s) clogged there at the end")
    ax.set_xlim(g.x_min * scale, g.x_max * scale)
    ax.set_ylim(g.y_min * scale, g.y_max * scale)
    ax.set_aspect("equal")
    unit = " (mm)" if si else ""
    ax.set_xlabel("x" + unit)
    ax.set_ylabel("y" + unit)
    ax.set_title(f"{name}: where the {len(share)} throats clogged "
                 f"({int(hot.sum())} clogged in some realization)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"clog_map": Path(path).name}
