"""The reference paper's clogging figures as commands (Zhou et al. 2024, Figs. 8-13).

Each command runs a set of *points* (one scene each: a packing fraction, a friction,
a shape...), every point a batch of random realizations run together, then writes
into ``--out`` (default ``runs/figures/<command>/``):

``<command>.png``
    the figure;
``points.csv``
    one row per point: what was varied, particle count, realizations (stable,
    clogged, censored, unstable), ``<s>`` and its interval, the decay rate of
    ``P(s) ~ exp(-lambda s)`` and its interval, the never-clogged fraction, the
    wall time (and for ``escapees-time`` the fitted and theoretical escape rates);
``realizations.csv``
    one row per realization: seed, escapees, clogged, t_clog, t_stop, status;
``pmf.csv``
    (every command but ``escapees-time``) the PMF of ``x = s/<s>`` with its
    binomial standard error;
``series.csv``
    (``escapees-time``) escapees over time per realization beside the theory
    line ``4 phi Q t / (H pi d^2)``;
``figure.json``
    the command line, the overrides of every point, wall times (``wall_time_s``
    this invocation's, a point's ``wall_s`` the run that computed it, ``resumed``
    whether it was read back);
``points/<point>.json``
    each point's realizations as soon as the point has finished. A later run
    into the same ``--out`` reads a point back instead of running it when its
    scene (seeds included), realization count and the package code are the
    same (``--no-resume`` runs everything again), so an interrupted figure loses
    at most the point it was running.

The folder is locked while a figure writes it, and holds one figure's results:
files of these names that no figure wrote there (the user's) are never replaced,
and another figure's folder is refused (:mod:`.folder`; exit 2, one line).

Commands
--------
``escapees-time`` (Fig. 8)
    ``scenes/vani_phi026.toml`` with ``run.stop_at_clog = false`` at packing
    fractions 0.086, 0.17, 0.26: escapees against time, and the steady escape
    rate against ``4 phi Q / (H pi d^2)`` (``Q = fluid.flow_rate``,
    ``H = fluid.gap``, ``d`` the particle's equivalent diameter). Particles start
    in the control volume and need a transit time to reach the constriction, so
    the rate is fitted from each realization's first escape on (see
    :func:`stream_rate`).
``pmf-collapse`` (Fig. 9)
    the same scene at phi = 0.19, 0.26, 0.32, stopping at the clog: histogram of
    escapees before clogging and the PMF of ``s/<s>`` against ``exp(-x)``.
``friction`` (Fig. 10)
    phi = 0.26, friction 0.1 ... 0.9: ``<s>`` with its interval, and decay rates.
``shapes`` (Figs. 11-12)
    ``scenes/squares.toml`` (mu = 0.4) and circles of the same bounding diameter,
    at W/d_b = 1.7 and 1.2.
``polygons`` (Fig. 13)
    ``scenes/polygons.toml`` (W/d_b = 1.2, mu = 0.4): regular polygons of 3-6
    vertices and circles of the same bounding diameter, ``<s>`` against the vertex
    count.

Statistics
----------
Every estimate comes from :mod:`taichi_hsdem.stats` over the realizations that ran
stably: a realization that never clogged is right-censored (its ``s`` is a lower
bound) and enters the geometric likelihood as such, it is not dropped; ``<s>`` is
the censoring-aware fit with its profile-likelihood interval
(:func:`taichi_hsdem.stats.mean_escapees`). The PMF of ``s/<s>`` is binned on whole
``s`` and normalised by all realizations (:func:`taichi_hsdem.stats.pmf_bins`), so
with censoring it integrates to the clogged fraction. Unstable realizations are
counted in ``points.csv`` and left out.

Sizes
-----
Default: :data:`DEFAULT_REALIZATIONS` realizations per point and the scene's
``t_end`` (5 s); the paper used 100 per point (``--realizations 100``).
``--quick`` is a smoke test of the whole chain: 2-3 realizations a point, a clog
window of 0.15 s, the upstream channel shrunk to :data:`QUICK_BOX` bounding
diameters square (the count-based scenes scaled to the same areal fraction) so
that particles reach the constriction soon, each run to
:data:`~.points.QUICK_T_END` (3 s, stopping at a clog; the level-set figures on a
fluid cell of ``d_b / 5``): they clog as the full figure does, with wide
intervals (``friction --quick``: 9 of 9 clogged, 18 s on 2 cores; ``polygons
--quick``: 5 of 8 clogged, 41 s; ``shapes --quick``: the circles' 4 of 4, the
squares' lower bounds, 33 s). Its numbers are not the paper's statistics. ``--set`` overrides
(applied after the command's and ``--quick``'s own, before the point's varied
value) change anything else.

Examples
--------
::

    python -m taichi_hsdem figures escapees-time --quick
    python -m taichi_hsdem figures friction --realizations 100 --out runs/fig10
    python -m taichi_hsdem figures polygons --vertices 3 4 --set run.t_end=2
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from .. import stats
from ..laws import theory_escapees
from ..output import atomic_write, json_safe
from ..resolve import resolve
from ..digest import code_digest
from .points import (DEFAULT_POINTS, DEFAULT_REALIZATIONS, FIGURES, PAPER_REALIZATIONS,
                     QUICK_POINTS, SPEC, FigureError, PointRun, base_scene, build_points,
                     load_point, point_file, point_key, run_point, save_point, series_by_seed)
from .cluster import Cluster, ClusterError
from .progress import Eta
from .folder import StudyFolder, StudyFolderError, point_folder_problem
from .plots import pyplot, render
from ..scene import SceneError
from ..exits import Parser, folder_name



# ----------------------------------------------------------------------------- points


# ----------------------------------------------------------------------------- running


# ----------------------------------------------------------------------------- analysis


def stream_rate(series, rows) -> dict:
    """Escape rate of the steady stream, pooled over realizations.

    For each stable realization the stream runs from the first sample with an
    escape (``t1``, ``s1``) to the end of the run, or, for a realization that
    clogged, to the first sample at its final count (the last escape). The rate is
    ``sum(s_end - s1) / sum(t_end - t1)``: escapes counted from an escape on, over
    the time they took, so the transit time of the first particles from the control
    volume to the constriction does not enter. Standard error ``sqrt(n) / T``
    (Poisson). Realizations with no escape contribute nothing to the rate and are
    counted in ``n_no_escape``.
    """
    ok = {r["seed"]: r for r in rows if r["status"] == "ok"}
    per = series_by_seed([x for x in series if x[0] in ok])
    events, duration, firsts, no_escape = 0, 0.0, [], 0
    for seed, row in ok.items():
        pts = per.get(seed, [])
        idx = next((i for i, (_, s) in enumerate(pts) if s >= 1), None)
        if idx is None:
            no_escape += 1
            continue
        t1, s1 = pts[idx]
        firsts.append(t1)
        if row["clogged"]:
            s_end = max(s for _, s in pts)
            t_end = next(t for t, s in pts if s == s_end)
        else:
            t_end, s_end = pts[-1]
        events += s_end - s1
        duration += t_end - t1
    rate = events / duration if duration > 0 else math.nan
    err = math.sqrt(events) / duration if duration > 0 else math.nan
    return {"rate": rate, "rate_stderr": err, "events": int(events), "duration": duration,
            "t_first_mean": float(np.mean(firsts)) if firsts else math.nan,
            "n_no_escape": no_escape}


def pmf_lsq_rate(bins: list[dict]) -> float:
    """Slope ``k`` of ``ln(pmf) = a - k x`` over non-empty bins, weighted by count
    (``1`` for an exponential collapse); NaN with fewer than two non-empty bins."""
    pts = [(b["x"], math.log(b["pmf"]), b["count"]) for b in bins if b["count"] > 0]
    if len(pts) < 2:
        return math.nan
    x, y, w = (np.array(v, dtype=float) for v in zip(*pts))
    if np.ptp(x) == 0:
        return math.nan
    slope = np.polyfit(x, y, 1, w=np.sqrt(w))[0]
    return float(-slope)


def point_stats(run: PointRun) -> dict:
    """Censoring-aware statistics of one point (keys of ``points.csv``)."""
    n_unstable = sum(1 for r in run.rows if r["status"] != "ok")
    s, c = run.samples()
    d = {"realizations": len(run.rows), "n_ok": int(s.size), "n_unstable": n_unstable}
    if s.size == 0:
        d.update(n_clogged=0, n_censored=0, mean_s=math.nan, mean_s_lo=math.nan,
                 mean_s_hi=math.nan, mean_s_lower_bound=None, mean_method="",
                 observed_mean_s=math.nan,
                 p_clog=math.nan, decay_rate=math.nan, decay_rate_lo=math.nan,
                 decay_rate_hi=math.nan, decay_rate_stderr=math.nan,
                 decay_rate_x=math.nan, pmf_lsq_rate_x=math.nan,
                 never_clogged=math.nan, never_clogged_lo=math.nan, never_clogged_hi=math.nan)
        return d
    fit = stats.fit_geometric(s, c)
    mean, (lo, hi) = stats.mean_escapees(s, c)
    method = stats.summarize(s, c)["mean_escapees_method"]
    never, (nlo, nhi) = stats.never_clogged_fraction(c)
    bins = stats.pmf_bins(s, c)
    # nothing clogged: no estimate, its one-sided lower bound in its own column
    mean, bound = stats.censored_fields(mean, (lo, hi))
    d.update(n_clogged=fit.n_clogged, n_censored=fit.n_censored, mean_s=mean,
             mean_s_lo=lo, mean_s_hi=hi, mean_s_lower_bound=bound, mean_method=method,
             observed_mean_s=float(s.mean()),
             p_clog=fit.p, decay_rate=fit.decay_rate, decay_rate_lo=fit.decay_rate_ci[0],
             decay_rate_hi=fit.decay_rate_ci[1], decay_rate_stderr=fit.decay_rate_stderr,
             decay_rate_x=fit.decay_rate * fit.mean if math.isfinite(fit.mean) else math.nan,
             pmf_lsq_rate_x=pmf_lsq_rate(bins),
             never_clogged=never, never_clogged_lo=nlo, never_clogged_hi=nhi)
    return d


# ----------------------------------------------------------------------------- output

def _fmt(v):
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return "1" if v else "0"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v)) if math.isfinite(v) else ("nan" if math.isnan(v) else
                                                        ("inf" if v > 0 else "-inf"))
    return str(v)


def write_csv(path: Path, rows: list[dict], columns=None):
    if columns is None:
        columns = []
        for r in rows:
            for k in r:
                if k not in columns:
                    columns.append(k)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        for r in rows:
            w.writerow([_fmt(r.get(k)) for k in columns])
    tmp.replace(path)


def _interval_text(mean, lo, hi):
    def f(v):
        return "inf" if not math.isfinite(v) else f"{v:.3g}"
    return f"{f(mean)} [{f(lo)}, {f(hi)}]"


def summary_line(command: str, run: PointRun, row: dict) -> str:
    p = run.point
    if run.error:
        return f"{p.label}: FAILED ({run.error}), {run.wall:.1f} s"
    head = (f"{p.label}: {row['n_particles']} particles, {row['n_ok']}/{row['realizations']} "
            f"stable ({row['n_clogged']} clogged, {row['n_censored']} censored)")
    if command == "escapees-time":
        return (f"{head}, first escape at {row['t_first_mean']:.3g} s (mean), rate "
                f"{row['rate']:.3g} +- {row['rate_stderr']:.2g} /s vs theory "
                f"{row['theory_rate']:.3g} /s (ratio {row['rate_ratio']:.2f}), {run.wall:.1f} s"
                f"{_kept(run)}")
    mean = stats.mean_phrase(row["mean_s"], (row["mean_s_lo"], row["mean_s_hi"]),
                             row.get("mean_s_lower_bound"))
    return (f"{head}, {mean}, "
            f"lambda = {_interval_text(row['decay_rate'], row['decay_rate_lo'], row['decay_rate_hi'])}"
            f" /escapee, {run.wall:.1f} s{_kept(run)}")


def _kept(run: PointRun) -> str:
    return " (finished earlier, read back)" if run.resumed else ""


# ----------------------------------------------------------------------------- driver

def _point_row(command: str, run: PointRun) -> dict:
    row = {"label": run.point.label, **run.point.values}
    info = dict(run.info)
    row.update({k: info.get(k, math.nan) for k in ("n_particles", "phi_actual", "d_eq", "d_b",
                                                     "flow_rate", "gap", "t_end", "dt")})
    row["contact_path"] = info.get("contact_path", "")
    row.update(point_stats(run))
    if command == "escapees-time":
        sr = stream_rate(run.series, run.rows)
        row.update(sr)
        phi = run.point.values["phi"]
        if row["flow_rate"] and math.isfinite(row["d_eq"]):
            row["theory_rate"] = float(theory_escapees(phi, 1.0, row["flow_rate"], row["gap"],
                                                       row["d_eq"]))
            row["theory_rate_phi_actual"] = float(theory_escapees(
                row["phi_actual"], 1.0, row["flow_rate"], row["gap"], row["d_eq"]))
        else:
            row["theory_rate"] = row["theory_rate_phi_actual"] = math.nan
        row["rate_ratio"] = (sr["rate"] / row["theory_rate"]
                             if row["theory_rate"] and math.isfinite(row["theory_rate"])
                             else math.nan)
    row["wall_s"] = run.wall
    row["error"] = run.error or ""
    return row


def _opts_from_args(command, args) -> dict:
    opts = {}
    for key in ("phi", "mu", "ratios", "vertices", "ratio"):
        v = getattr(args, key, None)
        if v is not None:
            opts[key] = v
    if getattr(args, "no_circle", False):
        opts["circle"] = False
    return opts


def run_figure(command: str, *, quick=False, realizations=None, out=None, sets=(),
               scene=None, seed=None, batch=None, opts=None, log=None, argv=None,
               resume=True, cluster=None) -> dict:
    """Run one figure; returns ``{"out", "files", "points", "runs"}``.

    Every finished point is kept in ``<out>/points/``; with ``resume`` a point kept
    there from the same scene, realization count and code is read back instead of
    run again, so an interrupted figure restarts where it stopped.

    With ``cluster`` (a Dask scheduler address or ``"local[:N]"``) the points run
    one task each on the cluster (:mod:`.cluster`).

    Raises :class:`FigureError` for invalid scenes or arguments before anything runs.
    """
    if command not in SPEC:
        raise FigureError(f"unknown figure {command!r}; choose from {', '.join(FIGURES)}")
    try:
        pyplot()
    except ImportError:
        raise FigureError("matplotlib is needed for the figures: pip install 'taichi_hsdem[plot]'") \
            from None
    if realizations is None:
        realizations = SPEC[command]["quick_realizations"] if quick else DEFAULT_REALIZATIONS
    if int(realizations) < 1:
        raise FigureError(f"--realizations must be >= 1, got {realizations}")
    sets = list(sets)
    if seed is not None:
        sets.append(f"run.seed={int(seed)}")
    merged = dict(DEFAULT_POINTS[command])
    if quick:
        merged.update(QUICK_POINTS.get(command, {}))
    merged.update(opts or {})
    opts = merged
    try:
        base, overrides = base_scene(command, scene, quick, sets)
        if command == "escapees-time" and base.fluid.bc != "flow_rate":
            raise FigureError(f"{base.source}: fluid.bc: escapees-time needs a flow-rate inlet "
                              f"(the theory line uses Q = fluid.flow_rate)")
        points = build_points(command, base, opts)
        for p in points:       # refuse impossible set-ups before any compute
            resolve(p.scene.with_values({"run.realizations": 1}))
    except SceneError as exc:
        raise FigureError(exc.problems) from None
    out = Path(out) if out else Path("runs") / "figures" / command
    kept_files = [point_file(out, p) for p in points]
    owner = {}
    for p, path in zip(points, kept_files):
        if path.name in owner:
            raise FigureError(f"points {owner[path.name]!r} and {p.label!r} would share "
                              f"{path.name}: give distinct values")
        owner[path.name] = p.label
    names = [f.relative_to(out).as_posix() for f in kept_files] + figure_files(command)
    say = log or (lambda msg: None)
    # the cluster first: one it cannot use is refused before the folder is made
    with Cluster(cluster, say=say) as pool, \
            StudyFolder(out, f"figures {command}", legacy=_legacy_files(command)) as folder:
        problem = point_folder_problem(out / "points")
        if problem:
            raise StudyFolderError(problem.replace("a point's folder", "the points' folder"))
        folder.refuse_foreign(names, "the figure")
        folder.claim(names)
        code_digest()                  # this process's code, before any point runs
        say(f"{command}: {len(points)} point(s) x {realizations} realization(s), t_end = "
            f"{base.run.t_end:g} s{' (quick)' if quick else ''} -> {out}")
        t0 = time.perf_counter()
        runs = [None] * len(points)
        keys = [point_key(p, realizations) for p in points]
        todo = []
        for k, (p, path) in enumerate(zip(points, kept_files)):
            kept = load_point(path, keys[k], p) if resume else None
            if kept is not None:
                say(f"[{k + 1}/{len(points)}] {p.label}: finished earlier, read from {path}")
                runs[k] = kept
            else:
                todo.append(k)

        eta = Eta(len(todo))

        def finished(i, run):
            k = todo[i]
            if not run.error:
                save_point(kept_files[k], keys[k], run)
            runs[k] = run
            print(summary_line(command, run, _point_row(command, run)), flush=True)
            left = eta.done()
            if left:
                say(left)

        if todo:
            say(f"running {len(todo)} point(s)" + (f" on the cluster {cluster}" if cluster else ""))
        pool.run(run_point, [(points[k], int(realizations), batch, say if not cluster else None,
                              f"[{k + 1}/{len(points)}] {points[k].label}")
                             for k in todo], finished)
        for k, run in enumerate(runs):
            if k not in todo:
                print(summary_line(command, run, _point_row(command, run)), flush=True)
        rows = [_point_row(command, run) for run in runs]
        wall = time.perf_counter() - t0

        files = []
        real_rows = []
        for run in runs:
            for r in run.rows:
                real_rows.append({"label": run.point.label, **run.point.values, **r})
        write_csv(out / "realizations.csv", real_rows,
                  ["label", *points[0].values.keys(), "seed", "escapees", "clogged", "t_clog",
                   "t_stop", "status", "reason"])
        files.append(out / "realizations.csv")
        write_csv(out / "points.csv", rows)
        files.append(out / "points.csv")
        meta = (f"taichi_hsdem figures {command}: {realizations} realization(s)/point, t_end "
                f"{base.run.t_end:g} s{', QUICK (not the paper statistics)' if quick else ''}")
        png = out / f"{command}.png"
        pmfs = []
        if command != "escapees-time":
            pmf_rows = []
            for run in runs:
                s, c = run.samples()
                bins = stats.pmf_bins(s, c) if s.size else []
                pmfs.append(bins)
                for b in bins:
                    pmf_rows.append({"label": run.point.label, **run.point.values, **b})
            write_csv(out / "pmf.csv", pmf_rows,
                      ["label", *points[0].values.keys(), "x", "pmf", "stderr", "count", "s_lo",
                       "s_hi", "mean_s", "bin_width_x", "n_clogged"])
            files.append(out / "pmf.csv")
        if command == "escapees-time":
            srows = []
            for run, row in zip(runs, rows):
                phi = run.point.values["phi"]
                for seed_, t, s in sorted(run.series):
                    srows.append({"phi": phi, "seed": seed_, "t": t, "escapees": s,
                                  "theory_escapees": float(theory_escapees(
                                      phi, t, row["flow_rate"], row["gap"], row["d_eq"]))})
            write_csv(out / "series.csv", srows, ["phi", "seed", "t", "escapees", "theory_escapees"])
            files.append(out / "series.csv")
        render(command, runs, rows, pmfs, png, meta)
        files.append(png)
        info = {"figure": command, "argv": list(argv) if argv is not None else None,
                "quick": bool(quick), "realizations_per_point": int(realizations),
                "scene": base.source, "t_end": base.run.t_end, "base_overrides": overrides,
                "wall_time_s": wall,
                "points": [{"label": r.point.label, "values": r.point.values,
                            "overrides": {k: v for k, v in r.point.overrides.items()},
                            "wall_s": r.wall, "error": r.error, "info": r.info,
                            "resumed": r.resumed} for r in runs]}
        atomic_write(out / "figure.json", json.dumps(json_safe(info), indent=1, allow_nan=False)
                     + "\n")
        files.append(out / "figure.json")
        print(f"wrote {out}/: " + ", ".join(f.name for f in files) + f" ({wall:.1f} s)", flush=True)
        return {"out": out, "files": files, "points": rows, "runs": runs}


def figure_files(command: str) -> list[str]:
    """The files a figure writes in its folder (beside ``points/``)."""
    names = ["realizations.csv", "points.csv", f"{command}.png", "figure.json"]
    names.append("series.csv" if command == "escapees-time" else "pmf.csv")
    return names


def _legacy_files(command: str):
    """The names a figure of an earlier version (no study manifest) wrote in a
    folder, told by its ``figure.json``: its files and point files present."""
    def legacy(out: Path) -> list[str]:
        try:
            info = json.loads((out / "figure.json").read_text())
        except (OSError, ValueError):
            return []
        if not (isinstance(info, dict) and info.get("figure") == command):
            return []
        names = [n for n in figure_files(command) if (out / n).exists()]
        try:
            names += [f"points/{p.name}" for p in (out / "points").glob("*.json")]
        except OSError:
            pass
        return names
    return legacy


def _parser(prog: str) -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quick", action="store_true",
                        help="tiny run for CI: few realizations, short t_end, small upstream "
                             "box (not the paper's statistics)")
    common.add_argument("--realizations", type=int, metavar="N",
                        help=f"realizations per point (default {DEFAULT_REALIZATIONS}, "
                             f"--quick 2-3; the paper: {PAPER_REALIZATIONS})")
    common.add_argument("--out", type=folder_name, metavar="DIR", help="output folder (default runs/figures/<figure>/)")
    common.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override a scene scalar (repeatable), as in python -m taichi_hsdem")
    common.add_argument("--scene", metavar="TOML", help="base scene instead of the shipped one")
    common.add_argument("--seed", type=int, metavar="S", help="seed of realization 0 (run.seed)")
    common.add_argument("--batch", type=int, metavar="B",
                        help="realizations run together per simulation (default: all)")
    common.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    common.add_argument("--cluster", metavar="ADDRESS",
                        help="run the points on a Dask cluster: a scheduler address, or "
                             "local[:N] for N worker processes here (the cluster extra)")
    common.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                        help="read back points finished earlier in --out/points/ (same "
                             "scene, realizations and code) instead of running them again "
                             "(default: --resume)")
    p = Parser(prog=prog,
                                description="The clogging figures of Zhou et al. (2024), "
                                            "Figs. 8-13: PNG, CSV of the numbers, figure.json.")
    sub = p.add_subparsers(dest="figure", required=True, metavar="FIGURE")
    s = sub.add_parser("escapees-time", parents=[common], help="Fig. 8: escapees over time vs "
                       "4 phi Q t/(H pi d^2)")
    s.add_argument("--phi", type=float, nargs="+", help="packing fractions (default 0.086 0.17 0.26)")
    s = sub.add_parser("pmf-collapse", parents=[common], help="Fig. 9: PMF of s/<s> vs exp(-x)")
    s.add_argument("--phi", type=float, nargs="+", help="packing fractions (default 0.19 0.26 0.32)")
    s = sub.add_parser("friction", parents=[common], help="Fig. 10: <s> vs friction")
    s.add_argument("--mu", type=float, nargs="+", help="frictions (default 0.1 ... 0.9; "
                   "--quick 0.1 0.5 0.9)")
    s.add_argument("--phi", type=float, help="packing fraction (default 0.26)")
    s = sub.add_parser("shapes", parents=[common], help="Figs. 11-12: squares vs circles")
    s.add_argument("--ratios", type=float, nargs="+", help="W/d_b (default 1.7 1.2)")
    s = sub.add_parser("polygons", parents=[common], help="Fig. 13: <s> vs vertex count")
    s.add_argument("--vertices", type=int, nargs="+", help="vertex counts (default 3 4 5 6; "
                   "--quick 3 4 6)")
    s.add_argument("--ratio", type=float, help="W/d_b (default 1.2)")
    s.add_argument("--no-circle", action="store_true", help="leave out the circles")
    return p


def main(argv=None, prog: str = "python -m taichi_hsdem figures") -> int:
    """Command line; exit 0 on success, 1 when a point failed, 2 for invalid input."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = _parser(prog).parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)

    def log(msg):
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    try:
        res = run_figure(args.figure, quick=args.quick, realizations=args.realizations,
                         out=args.out, sets=args.set, scene=args.scene, seed=args.seed,
                         batch=args.batch, opts=_opts_from_args(args.figure, args), log=log,
                         argv=argv, resume=args.resume, cluster=args.cluster)
    except (FigureError, ClusterError, StudyFolderError) as exc:
        for line in getattr(exc, "problems", [str(exc)]):
            print(line, file=sys.stderr)
        return 2
    errors = [r.error for r in res["runs"] if r.error]
    if args.quiet:      # --quiet silences progress, not the points' failures
        for line in dict.fromkeys(errors):
            print(line, file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
