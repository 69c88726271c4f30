"""Plots where people look, in a run's output folder:

* ``escapees.png``: escapees against time for every realization, their mean, and,
  with a flow-rate inlet, the empirical law of a steady stream, whose escape rate
  is ``4 phi Q / (H pi d^2)`` (docs/model.md section 4; ``phi`` the packing
  fraction of the control volume, ``d`` the particles' mean equivalent
  diameter). The particles start at rest and the first ones need a transit
  time to reach the constriction, so the law is drawn over the steady stream
  only (:func:`law_line`): from the time the stream is established, the mean
  over realizations of their first escape, through the mean curve there;
* ``pmf.png`` (at least :data:`taichi_hsdem.stats.MIN_CLOGS` clogged
  realizations; fewer cannot show a shape, and the summary says why it is
  missing): the PMF of ``s / <s>`` on a log scale with ``exp(-x)``, the
  geometric law's, and the p-value of the test of a constant clogging
  probability (:func:`taichi_hsdem.stats.geometric_fit_test`).

Matplotlib comes with the ``plot`` extra; without it the plots are skipped and
the summary says so.
"""
from __future__ import annotations

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
    ax.set_title(f"{result.scene.name}: escapees over time")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(folder / "escapees.png", dpi=110)
    plt.close(fig)

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
            p = test.p_value
            ax.set_title("PMF of s/<s>; constant clogging probability: "
                         + (f"p = {p:.3g}" if p is not None else "not tested"))
            ax.legend(fontsize=8)
            fig.tight_layout()
            fig.savefig(folder / "pmf.png", dpi=110)
            plt.close(fig)
            drawn["pmf"] = "pmf.png"
        else:
            drawn["pmf_skipped"] = "every clogged realization had s = 0: s/<s> is undefined"
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
