"""The paper's figures drawn from the point runs of :mod:`.figures`: escapees
against time (Fig. 8), the PMF collapse (Fig. 9), friction (Fig. 10), squares
against circles (Figs. 11-12) and polygons (Fig. 13). Matplotlib is imported on
first use (the ``plot`` extra)."""
from __future__ import annotations

from pathlib import Path

import math

import numpy as np

from .. import stats
from ..report import without_library_warnings
from ..laws import theory_escapees
from .points import series_by_seed


def pyplot():
    """matplotlib.pyplot on the off-screen Agg backend (ImportError without the
    ``plot`` extra)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _err_mean(rows):
    """Means and asymmetric error bars with infinite ends drawn as arrows; where
    nothing clogged, the one-sided lower bound (``mean_s_lower_bound``, as every
    message says it: :func:`taichi_hsdem.stats.estimate_text`), never the plain
    mean of the counts. Also returns which points are such bounds."""
    y = np.array([np.nan if r["mean_s"] is None else r["mean_s"] for r in rows], dtype=float)
    lo = np.array([r["mean_s_lo"] for r in rows], dtype=float)
    hi = np.array([r["mean_s_hi"] for r in rows], dtype=float)
    bound = np.array([np.nan if r.get("mean_s_lower_bound") is None else r["mean_s_lower_bound"]
                      for r in rows], dtype=float)
    is_bound = ~np.isfinite(y) & np.isfinite(bound)
    y = np.where(is_bound, bound, y)
    finite_hi = hi[np.isfinite(hi)]
    cap = (np.nanmax(np.concatenate([finite_hi, y[np.isfinite(y)]])) * 1.5
           if np.isfinite(y).any() else 1.0)
    hi_open = ~np.isfinite(hi)
    hi = np.where(hi_open, np.maximum(cap, y), hi)
    lo = np.where(np.isfinite(lo), lo, y)
    return (y, np.vstack([np.clip(y - lo, 0, None), np.clip(hi - y, 0, None)]), hi_open,
            is_bound)


def _pmf_panel(ax, groups, title="PMF of s/<s>"):
    """``groups``: [(label, bins)]; semilog, exp(-x) for reference."""
    xmax = 1.0
    for label, bins in groups:
        b = [x for x in bins if x["count"] > 0]
        if not b:
            continue
        x = np.array([v["x"] for v in b])
        xmax = max(xmax, float(x.max()))
        ax.errorbar(x, [v["pmf"] for v in b], yerr=[v["stderr"] for v in b], fmt="o",
                    ms=4, capsize=2, label=label)
    xs = np.linspace(0, max(xmax, 3.0), 100)
    ax.plot(xs, np.exp(-xs), "k--", lw=1, label="exp(-x)")
    ax.set_yscale("log")
    ax.set_xlabel("x = s / <s>")
    ax.set_ylabel("PMF (density in x)")
    ax.set_title(title)
    ax.legend(fontsize=7)


def _finish(plt, fig, path, meta):
    """Footer line ``meta``, layout, write ``path``, free the figure."""
    fig.text(0.01, 0.005, meta, fontsize=6, color="0.4", ha="left", va="bottom")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


@without_library_warnings
def plot_escapees_time(runs, rows, path: Path, meta: str):
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    t_max = 0.0
    for k, (run, row) in enumerate(zip(runs, rows)):
        if run.error or not run.series:
            continue
        col = colors[k % len(colors)]
        per = series_by_seed(run.series)
        for seed, pts in per.items():
            t, s = zip(*pts)
            a1.step(t, s, where="post", color=col, alpha=0.25, lw=0.8)
            t_max = max(t_max, max(t))
        # mean over realizations on the common sample times (a realization that
        # stopped keeps its last count)
        times = np.array(sorted({t for pts in per.values() for t, _ in pts}))
        means = np.zeros(times.size)
        for pts in per.values():
            t, s = (np.array(v, dtype=float) for v in zip(*pts))
            i = np.searchsorted(t, times + 1e-12, side="right") - 1
            means += np.where(i >= 0, s[np.clip(i, 0, None)], 0.0)
        means /= len(per)
        a1.plot(times, means, color=col, lw=2, label=f"phi = {run.point.values['phi']:g} (mean)")
        tt = np.linspace(0, max(times), 50)
        th = theory_escapees(run.point.values["phi"], tt, row["flow_rate"], row["gap"], row["d_eq"])
        a1.plot(tt, th, "--", color=col, lw=1)
        t1 = row["t_first_mean"]
        if math.isfinite(t1):
            ts = np.linspace(t1, max(times), 20)
            a1.plot(ts, theory_escapees(run.point.values["phi"], ts - t1, row["flow_rate"],
                                        row["gap"], row["d_eq"]), ":", color=col, lw=1)
    a1.set_xlabel("t (s)")
    a1.set_ylabel("escapees s")
    a1.set_title("escapees over time; -- 4 phi Q t/(H pi d^2), : same from first escape")
    a1.title.set_fontsize(8)
    a1.legend(fontsize=7)
    phis = np.array([r["phi"] for r in rows])
    ok = [i for i, r in enumerate(rows) if math.isfinite(r["rate"])]
    if ok:
        a2.errorbar(phis[ok], [rows[i]["rate"] for i in ok],
                    yerr=[rows[i]["rate_stderr"] for i in ok], fmt="o", capsize=3,
                    label="fitted (from first escape)")
    pp = np.linspace(0, max(phis.max(), 0.01) * 1.1, 50)
    r0 = rows[0]
    a2.plot(pp, theory_escapees(pp, 1.0, r0["flow_rate"], r0["gap"], r0["d_eq"]), "k--",
            label="4 phi Q / (H pi d^2)")
    a2.set_xlabel("packing fraction phi")
    a2.set_ylabel("escape rate (1/s)")
    a2.set_title("steady escape rate")
    a2.legend(fontsize=7)
    _finish(plt, fig, path, meta)


@without_library_warnings
def plot_pmf_collapse(runs, rows, pmfs, path: Path, meta: str):
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    for run, row in zip(runs, rows):
        s, c = run.samples()
        if s.size == 0:
            continue
        counts, edges = stats.histogram(s, c)
        lab = (f"phi = {run.point.values['phi']:g} ({row['n_clogged']} clogged, "
               f"{row['n_censored']} censored)")
        if counts.size and counts.sum():
            a1.stairs(counts, edges, label=lab, lw=1.5)
        else:
            a1.plot([], [], label=lab)
    a1.set_xlabel("escapees before clogging s")
    a1.set_ylabel("realizations")
    a1.set_title("histogram of s (clogged realizations)")
    a1.legend(fontsize=7)
    _pmf_panel(a2, [(f"phi = {r.point.values['phi']:g}", pmfs[i]) for i, r in enumerate(runs)])
    _finish(plt, fig, path, meta)


def _mean_decay_panels(a1, a2, x, rows, xlabel, labels=None, xticks=None, series_label=None):
    y, yerr, open_hi, is_bound = _err_mean(rows)
    a1.errorbar(x, np.where(is_bound, np.nan, y), yerr=yerr, fmt="o-", capsize=3,
                label=series_label)
    if is_bound.any():     # nothing clogged: the lower bound, open above
        xb = np.asarray(x)[is_bound]
        a1.errorbar(xb, y[is_bound], yerr=yerr[:, is_bound], fmt="none", capsize=0,
                    ecolor="0.5")
        a1.plot(xb, y[is_bound], "_", color="0.3", ms=12, mew=2,
                label="nothing clogged: 95 % lower bound" if not
                a1.get_legend_handles_labels()[1].count("nothing clogged: 95 % lower bound")
                else None)
    if open_hi.any():
        a1.plot(np.asarray(x)[open_hi], yerr[1][open_hi] + y[open_hi], "^", color="0.3", ms=5,
                label="interval open above" if not a1.get_legend_handles_labels()[1].count(
                    "interval open above") else None)
    if np.all(y[np.isfinite(y)] > 0) and np.isfinite(y).any():
        a1.set_yscale("log")
    a1.set_xlabel(xlabel)
    a1.set_ylabel("<s> (escapees before clogging)")
    lam = np.array([r["decay_rate"] for r in rows], dtype=float)
    lo = np.array([r["decay_rate_lo"] for r in rows], dtype=float)
    hi = np.array([r["decay_rate_hi"] for r in rows], dtype=float)
    fin = np.isfinite(lam) & np.isfinite(hi)
    if fin.any():
        xa = np.asarray(x, dtype=float)[fin]
        a2.errorbar(xa, lam[fin], yerr=[np.clip(lam[fin] - lo[fin], 0, None),
                                        np.clip(hi[fin] - lam[fin], 0, None)],
                    fmt="s-", capsize=3, label=series_label)
    a2.set_xlabel(xlabel)
    a2.set_ylabel("decay rate lambda of P(s) ~ exp(-lambda s)")
    for a in (a1, a2):
        if xticks is not None:
            a.set_xticks(xticks)
            a.set_xticklabels(labels)


@without_library_warnings
def plot_friction(runs, rows, path: Path, meta: str):
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    _mean_decay_panels(a1, a2, [r["mu"] for r in rows], rows, "friction mu")
    a1.set_title(f"<s> vs friction at phi = {rows[0]['phi']:g} (95 % CI)")
    a2.set_title("decay rates (95 % CI)")
    _finish(plt, fig, path, meta)


@without_library_warnings
def plot_shapes(runs, rows, pmfs, path: Path, meta: str):
    plt = pyplot()
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(14, 4.4))
    shapes_ = list(dict.fromkeys(r["shape"] for r in rows))
    for j, shape in enumerate(shapes_):
        sel = [i for i, r in enumerate(rows) if r["shape"] == shape]
        dodge = 0.01 * (j - 0.5 * (len(shapes_) - 1))      # keep equal points apart
        _mean_decay_panels(a1, a2, [rows[i]["W_over_db"] + dodge for i in sel],
                           [rows[i] for i in sel], "W / d_b", series_label=shape)
    ratios = sorted({r["W_over_db"] for r in rows})
    for a in (a1, a2):
        a.set_xticks(ratios)
        a.set_xlim(min(ratios) - 0.15, max(ratios) + 0.15)
    a1.set_title("<s> (95 % CI)")
    a2.set_title("decay rates (95 % CI)")
    a1.legend(fontsize=7)
    a2.legend(fontsize=7)
    _pmf_panel(a3, [(r.point.label, pmfs[i]) for i, r in enumerate(runs)])
    _finish(plt, fig, path, meta)


@without_library_warnings
def plot_polygons(runs, rows, pmfs, path: Path, meta: str):
    plt = pyplot()
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(14, 4.4))
    nv = [r["n_vertices"] for r in rows]
    poly = [v for v in nv if v > 0]
    circ_x = (max(poly) + 1.5) if poly else 1.0
    x = [v if v > 0 else circ_x for v in nv]
    labels = [str(v) if v > 0 else "circle" for v in nv]
    _mean_decay_panels(a1, a2, x, rows, "vertices", labels=labels, xticks=x)
    a1.set_title(f"<s> vs vertex count, W/d_b = {rows[0]['W_over_db']:g} (95 % CI)")
    a2.set_title("decay rates (95 % CI)")
    _pmf_panel(a3, [(r.point.label, pmfs[i]) for i, r in enumerate(runs)])
    _finish(plt, fig, path, meta)


def render(command: str, runs, rows, pmfs, path: Path, meta: str = ""):
    """Draw one figure from its point runs, ``points.csv`` rows and PMF bins."""
    if command == "escapees-time":
        plot_escapees_time(runs, rows, path, meta)
    elif command == "pmf-collapse":
        plot_pmf_collapse(runs, rows, pmfs, path, meta)
    elif command == "friction":
        plot_friction(runs, rows, path, meta)
    elif command == "shapes":
        plot_shapes(runs, rows, pmfs, path, meta)
    elif command == "polygons":
        plot_polygons(runs, rows, pmfs, path, meta)
    else:
        raise ValueError(f"unknown figure {command!r}")
