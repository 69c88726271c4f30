"""``sweep.png``: a sweep's ``<s>`` against the value it sweeps.

One marker per point with its 95 % interval (an interval open above is drawn to
the top of the axes with an arrow); a point where nothing clogged is its one-sided
95 % lower bound, an open triangle pointing up, as every message says it
(:func:`taichi_hsdem.stats.estimate_text`), never the plain mean of its counts.
The x axis is the first key whose value changes from point to point and is a
number; the other changing keys make one series each. A sweep of no numeric key
has the points in order, named by their folders. A point with no statistics
(nothing escaped or clogged) is a cross at the foot of the axes. Matplotlib is
imported on first use (the ``plot`` extra); without it nothing is drawn.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..report import without_library_warnings
from .plots import pyplot

#: The most series drawn (one per combination of the other changing keys).
MAX_SERIES = 10


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def axes_of(rows: Sequence[Mapping]) -> tuple[str | None, list[str]]:
    """The x key (None: the points in order) and the other keys that change.

    Examples
    --------
    >>> rows = [{"overrides": {"a": 1, "b": "x"}}, {"overrides": {"a": 2, "b": "y"}}]
    >>> axes_of(rows)
    ('a', ['b'])
    """
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row["overrides"] if k not in keys]
    changing = [k for k in keys
                if len({repr(row["overrides"].get(k)) for row in rows}) > 1]
    numeric = [k for k in changing
               if all(_number(row["overrides"].get(k)) is not None for row in rows)]
    x = numeric[0] if numeric else None
    return x, [k for k in changing if k != x]


def estimate(row: Mapping) -> tuple[float, float, float, bool] | None:
    """``(y, lo, hi, is_bound)`` of a point, or None when it has no statistics:
    ``<s>`` and its interval, or, where nothing clogged, the lower bound (lo = y,
    hi = inf)."""
    if not row.get("n_ok"):
        return None
    mean = row.get("mean_escapees")
    if mean is not None and math.isfinite(mean):
        lo, hi = row.get("mean_escapees_ci") or (None, None)
        lo = mean if lo is None else lo
        hi = math.inf if hi is None else hi
        return float(mean), float(lo), float(hi), False
    bound = row.get("mean_escapees_lower_bound")
    if bound is None or not math.isfinite(bound) or bound <= 0:
        return None
    return float(bound), float(bound), math.inf, True


def plot_sweep(rows: Sequence[Mapping], path: Path, title: str = "") -> bool:
    """Draw ``sweep.png`` at ``path`` (replaced whole); False only when there is no
    point or no matplotlib. A point without statistics (no stable realization, or
    none that escaped or clogged) is a cross at the foot of the axes, named in the
    legend, so that a sweep too short to estimate anything still says so."""
    if not rows:
        return False
    try:
        plt = pyplot()
    except ImportError:
        return False
    _draw(plt, [(row, estimate(row)) for row in rows], Path(path), title)
    return True


def no_estimate(rows: Sequence[Mapping]) -> list[str]:
    """The folders of the points that have no statistics to draw."""
    return [str(row.get("folder", "")) for row in rows if estimate(row) is None]


@without_library_warnings
def _draw(plt, points, path: Path, title: str) -> None:
    x_key, others = axes_of([row for row, _ in points])
    series: dict[str, list] = {}
    for k, (row, e) in enumerate(points):
        name = ", ".join(f"{key}={row['overrides'].get(key)}" for key in others)
        series.setdefault(name, []).append((k, row, e))
    known = [e for _, e in points if e is not None]
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=110)
    try:
        top = max([e[0] for e in known], default=1.0)
        finite_hi = [e[2] for e in known if math.isfinite(e[2])]
        cap = max([top, *finite_hi]) * 2.0
        floor = min([e[1] for e in known], default=cap / 4.0) / 1.5
        for n, (name, members) in enumerate(series.items()):
            if n == MAX_SERIES:
                break
            xs = [_number(row["overrides"][x_key]) if x_key else k for k, row, _ in members]
            color = f"C{n % 10}"
            for x, (_, _, e) in zip(xs, members):
                if e is None:
                    ax.plot([x], [floor * 1.15], "x", color=color, ms=8, mew=1.5)
                    continue
                y, lo, hi, is_bound = e
                up = hi if math.isfinite(hi) else cap
                ax.plot([x, x], [lo, up], color=color, lw=1.2)
                if not math.isfinite(hi):
                    ax.annotate("", xy=(x, cap * 1.25), xytext=(x, cap),
                                arrowprops=dict(arrowstyle="->", color=color, lw=1.2))
                ax.plot([x], [y], "^" if is_bound else "o", color=color,
                        mfc="none" if is_bound else color, ms=7)
            if known or name:
                ax.plot([], [], "o", color=color, label=name or "<s>, 95 % interval")
        if any(e[3] for e in known):
            ax.plot([], [], "^", color="0.3", mfc="none",
                    label="nothing clogged: 95 % lower bound")
        if len(known) < len(points):
            ax.plot([], [], "x", color="0.3", mew=1.5,
                    label="no estimate: nothing escaped or clogged (run longer)")
        if not known:
            ax.text(0.5, 0.55, "no point has an estimate of <s>:\nnothing escaped or clogged "
                    "within run.t_end", transform=ax.transAxes, ha="center", va="center",
                    fontsize=9)
        ax.set_yscale("log")
        if not known:                                   # no scale to read
            ax.tick_params(axis="y", which="both", left=False, labelleft=False)
        ax.set_ylim(floor, cap * 1.6)
        ax.set_ylabel("<s> (escapees before a clog)")
        if x_key:
            ax.set_xlabel(x_key)
        else:
            ax.set_xticks(range(len(points)))
            ax.set_xticklabels([row["folder"] for row, _ in points], rotation=30,
                               ha="right", fontsize=7)
        if len(series) > MAX_SERIES:
            title += f" (first {MAX_SERIES} of {len(series)} series)"
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(tmp, format="png")
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()
