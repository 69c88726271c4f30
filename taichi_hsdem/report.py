"""Plots where people look, in a run's output folder:

* ``escapees.png``: escapees against time for every realization, their mean, and,
  with a flow-rate inlet, the empirical law of a steady stream
  ``s(t) = 4 phi Q t / (H pi d^2)`` (MODEL.md section 4; ``phi`` the packing
  fraction of the control volume, ``d`` the particles' mean equivalent diameter);
* ``pmf.png`` (two or more clogged realizations): the PMF of ``s / <s>`` on a log
  scale with ``exp(-x)``, the geometric law's, and the p-value of the test of a
  constant clogging probability (:func:`taichi_hsdem.stats.geometric_fit_test`).

Matplotlib comes with the ``plot`` extra; without it the plots are skipped and
the summary says so.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import stats
from .geometry.walls import fluid_area
from .laws import theory_escapees


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_run(result, folder: Path, law=None) -> dict:
    """Draw ``escapees.png`` (and ``pmf.png`` when it has data) into ``folder``;
    ``law`` is the ``(phi, Q, H, d)`` of the steady-stream line, None for none.
    Returns what was drawn, for the summary."""
    try:
        plt = _pyplot()
    except ImportError:
        return {"skipped": 'matplotlib is not installed (pip install "taichi_hsdem[plot]")'}
    folder = Path(folder)
    drawn = {"escapees": "escapees.png"}
    real = result.summary["realizations"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    per = {}
    for r, t, s in result.series:
        if real[r]["status"] != "unstable":
            per.setdefault(r, []).append((t, s))
    t_max = 0.0
    for r, rows in sorted(per.items()):
        t, s = np.array(rows).T
        ax.step(t, s, where="post", lw=0.8, alpha=0.5, color="0.5")
        t_max = max(t_max, float(t.max()))
    if per:
        grid = np.linspace(0.0, t_max, 200)
        curves = [np.interp(grid, *np.array(rows).T) for rows in per.values()]
        ax.plot(grid, np.mean(curves, axis=0), color="C0", lw=2,
                label=f"mean of {len(curves)} realization(s)")
    if law is not None:
        phi, q, h, d = law
        ax.plot(grid, theory_escapees(phi, grid, q, h, d), "k--", lw=1,
                label=r"$4 \phi Q t / (H \pi d^2)$" + f", phi = {phi:.3g}")
    ax.set_xlabel("t (s)" if result.scene.units == "SI" else "t")
    ax.set_ylabel("escapees s")
    ax.set_title(f"{result.scene.name}: escapees over time")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(folder / "escapees.png", dpi=110)
    plt.close(fig)

    counted = [r for r in real if r["status"] in ("ok", "interrupted")]
    s = np.array([r["escapees"] for r in counted], dtype=np.int64)
    c = np.array([bool(r["clogged"]) for r in counted])
    if c.sum() >= 2:
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
            p = test.p_value
            ax.set_title(f"PMF of s/<s>; constant clogging probability: "
                         f"p = {p:.3g}" if math.isfinite(p) else "PMF of s/<s>")
            ax.legend(fontsize=8)
            fig.tight_layout()
            fig.savefig(folder / "pmf.png", dpi=110)
            plt.close(fig)
            drawn["pmf"] = "pmf.png"
    return drawn


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
