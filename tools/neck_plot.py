"""ln <s> against (W/d)^2 for neck-width studies, beside the 2D silos' form.

Usage::

    python tools/neck_plot.py SERIES [SERIES ...] [--out PNG] [--quiet]

Each ``SERIES`` is ``[LABEL=]PATH[+PATH...]``: ``PATH`` a folder that
``tools/neck_study.py`` wrote (its finished points, read from their summaries, so a
study stopped part way counts) or a CSV with the columns of its ``neck.csv``
(``wd,mean_escapees,ci_lo,ci_hi,never_clogged,n``; ``mean_escapees`` empty where
nothing clogged, ``ci_lo`` then the one-sided 95 % lower bound); several paths
joined by ``+`` make one series: folders' realizations at the same W/d are pooled
(the same study run in parts, or on more seeds), a table's width replaces an
earlier one's. ``LABEL`` defaults
to the packing fraction of the folder's first point (``phi = 0.40``), else the
path's name.

Draws ln ``<s>`` against ``(W/d)^2`` with the 95 % intervals, the widths where
nothing clogged as lower bounds (a triangle pointing up), and, per series, the
weighted least-squares line ``ln <s> = a + b (W/d)^2`` over the widths that clog
(weights from the intervals: sigma = (ln hi - ln lo) / 3.92). That line is the
2D silos' stated form: the clogging fraction decays exponentially in the outlet
width to the power of the dimension, so ``<s>`` grows as ``exp(b (W/d)^2)``
(Janda et al., EPL 2008; Thomas & Durian, PRL 2015). Prints one line per series:
``b``, its standard error, chi^2 per degree of freedom (about 1: the line fits
within the intervals) and how many lower bounds lie above the line.

Exit status: 0 the PNG is written; 2 bad arguments or an unreadable table (one line).
"""
from __future__ import annotations

import argparse
import csv
import math
import pathlib
import sys
from dataclasses import dataclass, field

from taichi_hsdem.exits import EXIT_INVALID, EXIT_OK, Parser

Z95 = 1.959963984540054


@dataclass
class Point:
    """One width of a study: ``s`` the mean escapees before a clog (None: nothing
    clogged), ``lo``/``hi`` its 95 % interval (``lo`` the lower bound when
    ``s`` is None; ``hi`` None where unbounded)."""
    wd: float
    s: float | None
    lo: float | None
    hi: float | None
    never: int | None = None
    n: int | None = None

    @property
    def censored(self) -> bool:
        return self.s is None


@dataclass
class Fit:
    """``ln <s> = intercept + slope (W/d)^2`` over ``points`` widths."""
    slope: float
    intercept: float
    slope_se: float
    chi2_dof: float | None        # None: two points, or unweighted
    weighted: bool
    points: int
    wd_range: tuple[float, float]
    bounds_above: int = 0          # lower bounds (nothing clogged) above the line
    bounds: int = 0


@dataclass
class Series:
    label: str
    points: list[Point] = field(default_factory=list)


def _num(text: str) -> float | None:
    text = (text or "").strip()
    if not text:
        return None
    v = float(text)
    return v if math.isfinite(v) else None


def read_table(path: pathlib.Path) -> list[Point]:
    """The points of a ``neck.csv`` (or a folder holding one)."""
    if path.is_dir():
        path = path / "neck.csv"
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows or not {"wd", "mean_escapees", "ci_lo", "ci_hi"} <= set(rows[0]):
        raise ValueError(f"{path}: not a neck table (needs wd,mean_escapees,ci_lo,ci_hi)")
    out = []
    for row in rows:
        never, n = _num(row.get("never_clogged", "")), _num(row.get("n", ""))
        p = Point(float(row["wd"]), _num(row["mean_escapees"]), _num(row["ci_lo"]),
                  _num(row["ci_hi"]), None if never is None else int(never),
                  None if n is None else int(n))
        if p.s is None and p.lo is None:
            continue                    # a point that has no result (failed)
        out.append(p)
    return out


def _packing_fraction(folder: pathlib.Path) -> float | None:
    """The packing fraction a neck_study folder ran at: its ``index.json``'s
    common override, else its base scene's; None when neither says."""
    import json

    from taichi_hsdem.scene import SceneError
    try:
        index = json.loads((folder / "index.json").read_text())
        phi = index.get("common", {}).get("particles.packing_fraction")
        if phi is None:
            from taichi_hsdem.scene import load_scene
            phi = load_scene(index["scene"]).particles[0].packing_fraction
        return None if phi is None else float(phi)
    except (OSError, ValueError, KeyError, TypeError, IndexError, SceneError):
        # a label only: the path's name will do
        return None


def folder_counts(folder: pathlib.Path) -> dict[float, tuple[list[int], list[bool]]]:
    """W/d -> (escapees, clogged) of every stable realization in a neck_study
    folder's finished points (each point's ``summary.json`` and resolved scene);
    empty when it has none (a table, or a study that has not finished a point)."""
    import json

    from taichi_hsdem.scene import load_scene
    out: dict[float, tuple[list[int], list[bool]]] = {}
    if not folder.is_dir():
        return out
    for sub in sorted(folder.iterdir()):
        if not ((sub / "summary.json").is_file() and (sub / "scene.resolved.toml").is_file()):
            continue
        scene = load_scene(sub / "scene.resolved.toml")
        d = max(sp.d_eq() for sp in scene.particles)
        wd = round(scene.geometry.constriction_width / d, 9)
        real = [r for r in json.loads((sub / "summary.json").read_text())["realizations"]
                if r.get("status") == "ok"]
        esc, clog = out.setdefault(wd, ([], []))
        esc += [int(r["escapees"]) for r in real]
        clog += [bool(r["clogged"]) for r in real]
    return out


def pooled(counts: dict[float, tuple[list[int], list[bool]]]) -> list[Point]:
    """One point per W/d from its realizations: the censoring-aware ``<s>`` and
    its 95 % interval (:func:`taichi_hsdem.stats.geometric.mean_escapees`)."""
    from taichi_hsdem.stats.geometric import mean_escapees
    out = []
    for wd in sorted(counts):
        esc, clog = counts[wd]
        if not esc:
            continue
        m, (lo, hi) = mean_escapees(esc, clog)
        fin = [v if v is not None and math.isfinite(v) else None for v in (m, lo, hi)]
        out.append(Point(wd, *fin, never=len(esc) - sum(clog), n=len(esc)))
    return out


def parse_series(text: str) -> Series:
    if all(pathlib.Path(t).exists() for t in text.split("+") if t):
        label, paths = "", text         # a path may hold "=" (a point's folder)
    else:
        label, _, paths = text.rpartition("=")
    parts = [pathlib.Path(p) for p in paths.split("+") if p]
    if not parts:
        raise ValueError(f"{text!r}: no path")
    points: dict[float, Point] = {}
    counts: dict[float, tuple[list[int], list[bool]]] = {}
    for part in parts:
        found = folder_counts(part)
        if not found:
            for p in read_table(part):
                points[p.wd] = p        # a table: a later part replaces a width
        for wd, (esc, clog) in found.items():
            counts.setdefault(wd, ([], []))
            counts[wd][0].extend(esc)
            counts[wd][1].extend(clog)
    for p in pooled(counts):            # folders: a width's realizations pooled
        points[p.wd] = p
    if not label:
        phi = _packing_fraction(parts[0]) if parts[0].is_dir() else None
        label = f"phi = {phi:.2f}" if phi is not None else parts[0].stem
    return Series(label, [points[k] for k in sorted(points)])


def fit(points: list[Point]) -> Fit | None:
    """Weighted least squares of ln <s> on (W/d)^2 over the widths that clog
    (unweighted when any of them lacks a two-sided interval); None below two."""
    import numpy as np
    use = [p for p in points if not p.censored and p.s > 0]
    if len(use) < 2:
        return None
    x = np.array([p.wd ** 2 for p in use])
    y = np.log([p.s for p in use])
    sig = [(math.log(p.hi) - math.log(p.lo)) / (2 * Z95)
           if p.lo and p.hi and p.hi > p.lo > 0 else None for p in use]
    weighted = all(s is not None for s in sig)
    w = np.array([1 / s ** 2 for s in sig]) if weighted else np.ones(len(use))
    sw, sx, sy = w.sum(), (w * x).sum(), (w * y).sum()
    sxx, sxy = (w * x * x).sum(), (w * x * y).sum()
    det = sw * sxx - sx * sx
    if det <= 0:
        return None
    slope = (sw * sxy - sx * sy) / det
    intercept = (sxx * sy - sx * sxy) / det
    r = y - intercept - slope * x
    dof = len(use) - 2
    chi2 = float((w * r * r).sum())
    if weighted:
        se = math.sqrt(sw / det)
        chi2_dof = chi2 / dof if dof else None
    else:
        se = math.sqrt(chi2 / dof * sw / det) if dof else float("nan")
        chi2_dof = None
    bounds = [p for p in points if p.censored and p.lo]
    above = sum(math.log(p.lo) > intercept + slope * p.wd ** 2 for p in bounds)
    return Fit(float(slope), float(intercept), float(se), chi2_dof, weighted, len(use),
               (use[0].wd, use[-1].wd), above, len(bounds))


def fit_line(label: str, f: Fit | None) -> str:
    if f is None:
        return f"{label}: fewer than two widths clog, no line"
    fits = (f"chi^2/dof = {f.chi2_dof:.3g}" if f.chi2_dof is not None
            else "unweighted" if not f.weighted else "two points, exact")
    return (f"{label}: ln<s> = {f.intercept:.4g} + {f.slope:.6g} (W/d)^2 "
            f"(slope +- {f.slope_se:.2g}), {f.points} widths W/d {f.wd_range[0]:g}-"
            f"{f.wd_range[1]:g}, {fits}; {f.bounds_above} of {f.bounds} lower bounds "
            f"above the line")


def draw(series: list[Series], fits: list[Fit | None], out: pathlib.Path) -> None:
    from taichi_hsdem.report import _pyplot, without_library_warnings

    @without_library_warnings
    def _draw():
        plt = _pyplot()
        import numpy as np
        fig, ax = plt.subplots(figsize=(8.6, 4.4), dpi=100)
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for k, (sr, f) in enumerate(zip(series, fits)):
            c = colors[k % len(colors)]
            dx = (k - (len(series) - 1) / 2) * 0.05     # side by side at one width
            ok = [p for p in sr.points if not p.censored]
            if ok:
                x = np.array([p.wd ** 2 + dx for p in ok])
                y = np.log([p.s for p in ok])
                lo = np.array([y_ - math.log(p.lo) if p.lo else 0 for y_, p in zip(y, ok)])
                hi = np.array([math.log(p.hi) - y_ if p.hi else 0 for y_, p in zip(y, ok)])
                ax.errorbar(x, y, yerr=[lo, hi], fmt="o", color=c, ms=5, capsize=3,
                            label=sr.label)
            cens = [p for p in sr.points if p.censored]
            if cens:
                ax.plot([p.wd ** 2 + dx for p in cens], [math.log(p.lo) for p in cens], "^",
                        color=c, mfc="none", ms=7,
                        label=f"{sr.label}: nothing clogged (lower bound)")
            if f is not None:
                xs = np.linspace(f.wd_range[0] ** 2, f.wd_range[1] ** 2, 50)
                ax.plot(xs, f.intercept + f.slope * xs, "--", color=c, lw=1,
                        label=f"{sr.label}: fit, slope {f.slope:.2f}")
        ax.set_xlabel("(W/d)$^2$")
        ax.set_ylabel(r"ln $\langle s\rangle$")
        ax.set_title(r"ln $\langle s\rangle$ against (W/d)$^2$; 2D silos: a straight line")
        top = ax.secondary_xaxis("top", functions=(lambda v: np.sqrt(np.maximum(v, 0)),
                                                   lambda v: v ** 2))
        top.set_xlabel("W/d")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
        fig.tight_layout()
        fig.savefig(out)
        plt.close(fig)
    _draw()


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="tools/neck_plot.py", description=__doc__.split("\n\n")[0])
    p.add_argument("series", nargs="+", metavar="[LABEL=]PATH[+PATH...]",
                   help="a neck_study folder or neck.csv-like table; + joins parts")
    p.add_argument("--out", default="runs/neck_plot.png", help="PNG to write")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return exc.code
    try:
        series = [parse_series(s) for s in args.series]
    except (OSError, ValueError, KeyError) as exc:
        print(f"tools/neck_plot.py: {exc}", file=sys.stderr)
        return EXIT_INVALID
    fits = [fit(s.points) for s in series]
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    draw(series, fits, out)
    if not args.quiet:
        for s, f in zip(series, fits):
            print(fit_line(s.label, f))
        print(f"wrote {out}")
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
