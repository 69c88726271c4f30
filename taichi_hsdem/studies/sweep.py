"""Sweeps: one base scene run at several points of dotted overrides, resumable.

A *sweep* runs one base scene at several *points*, each a set of dotted overrides
(``{"particles.friction": 0.4, "run.realizations": 10}``, the keys of ``--set``),
in one process: Taichi is initialised once and its kernels compiled once for all
points. Every point is a run into its own folder, named after its overrides
(``particles.friction=0.4``), and writes what a run writes but the video and the
ParaView series (``summary.json``, ``escapees.csv``, ``arches.csv``,
``flow.csv``, ``final_state.npz``, ``scene.resolved.toml``, the plots), with a
run's lock and staging; the sweep writes ``sweep.csv`` (the clogging statistics of
every point, one row each), ``sweep.png`` (``<s>`` with its 95 % interval against
the swept value, a lower bound where nothing clogged: :mod:`.sweep_plot`) and
``index.json`` (folder -> overrides). A sweep is resumable: a point whose folder holds a ``summary.json``
of the same scene (base file, common and point overrides, compared as the
validated scene text) run by the same code (a digest of the package's sources) is
skipped; a folder without one, or with another scene's or code's, is run again.

The output folder follows :mod:`.folder`: it is locked while the sweep writes (a
second sweep, figure or run into it is refused), ``sweep.csv`` and ``index.json``
are replaced only when a sweep wrote them, a point's files only when a run or
sweep of taichi_hsdem wrote them (the run's manifest, in each point's folder), and
a finished point of another sweep file (or a plain run's result) is never run
again into its folder. A grid of more than ``MAX_POINTS`` (10,000) points is
refused, with its count, before it is built. Each refusal is one line, exit 2,
nothing run.

A sweep file (TOML)::

    scene = "../scenes/hourglass24.toml"   # relative to this file
    [common]                               # applied to every point
    "run.t_end" = 20.0
    "run.realizations" = 20
    [grid]                                 # cartesian product of the lists
    "particles.friction" = [0.1, 0.25, 0.4]
    "run.seed" = [1, 1001]
    [[points]]                             # and/or single points
    "particles.friction" = 0.9

Dotted keys can be quoted (as above) or written as nested tables
(``[grid.particles] friction = [...]``); a point's keys override ``[common]``.

Calibration lives in :mod:`taichi_hsdem.studies.calibrate`.

Examples
--------
>>> from taichi_hsdem.studies.sweep import run_sweep                       # doctest: +SKIP
>>> rows = run_sweep("scenes/hourglass24.toml",
...                  [{"particles.friction": mu} for mu in (0.2, 0.4)],
...                  "runs/friction", common={"run.t_end": 10.0})    # doctest: +SKIP
>>> [(r["folder"], r["mean_escapees"]) for r in rows]              # doctest: +SKIP

Command line::

    python -m taichi_hsdem sweep SWEEP.toml [--out DIR] [--resume | --no-resume]
                                            [--set KEY=VALUE ...] [--quick]
                                            [--cluster ADDRESS] [--quiet]

(``python tools/sweep.py`` is the same.) Each point writes ``DIR/<overrides>/``;
the sweep writes ``DIR/sweep.csv`` and ``DIR/index.json``, ``DIR`` defaulting to
``runs/<sweep file name>/``. ``--set KEY=VALUE`` overrides a key at every point
(after ``[common]``; a key the points vary is refused). ``--quick`` runs each
point with at most two realizations, each to its ``run.t_end`` (it clogs as the
full point does; the statistics are wider), into ``DIR/quick/``; the points'
``summary.json`` and ``index.json`` record what it set. Each point says how far
its run is every 5 s, and each finished point how many are left and about how
long they will take. Exit status: 0
every point has its results; 1 a point failed or a realization went unstable (the
other points are written); 2 the sweep file or a point is invalid (one line per
problem; nothing is run).
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import sys
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from ..output import atomic_write
from ..scene import Scene, load_scene, scene_to_toml
from ..digest import code_digest
from ..exits import EXIT_FAILED, EXIT_INVALID, EXIT_OK, Parser, folder_name
from .cluster import Cluster
from .folder import StudyFolder, StudyFolderError, point_folder_problem
from .progress import Eta, PointProgress
from .sweep_file import (MAX_POINTS, Sweep, SweepError, _check_points,  # noqa: F401
                         _describe_point, _override_strings, _value_text, expand_grid,
                         command_line_sets, load_sweep, point_folder, quick_overrides)

__all__ = [
    "SweepError", "Sweep", "load_sweep", "expand_grid", "point_folder", "run_sweep",
    "quick_overrides",
]

SUMMARY, SERIES, RESOLVED = "summary.json", "escapees.csv", "scene.resolved.toml"
SWEEP_CSV, INDEX, SWEEP_PNG = "sweep.csv", "index.json", "sweep.png"


# ---------------------------------------------------------------------------- runs

def _scene_key(scene: Scene) -> str:
    """What makes two points the same run: the validated scene, as TOML text, and
    the code that runs it (:func:`code_digest`)."""
    return hashlib.sha256((scene_to_toml(scene) + "\n# code " + code_digest()).encode()
                          ).hexdigest()


def _finished_summary(folder: Path, key: str) -> dict | None:
    """The folder's summary if it is complete and of the scene ``key``, else None."""
    try:
        summary = json.loads((folder / SUMMARY).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(summary, dict) or not isinstance(summary.get("realizations"), list):
        return None
    sweep = summary.get("sweep")
    if not isinstance(sweep, dict) or sweep.get("scene_sha256") != key:
        return None
    if not ((folder / SERIES).is_file() and (folder / RESOLVED).is_file()):
        return None
    return summary


def _row(folder: str, point: Mapping, status: str, summary: dict | None,
         message: str | None = None) -> dict:
    """One point's line of the sweep table, from its summary."""
    row: dict[str, Any] = {"folder": folder, "status": status, "overrides": dict(point),
                           "message": message}
    real = (summary or {}).get("realizations") or []
    st = (summary or {}).get("statistics") or {}
    ok = [r for r in real if r.get("status") == "ok"]
    row.update(
        n=len(real), n_ok=len(ok), n_unstable=len(real) - len(ok),
        n_clogged=sum(1 for r in ok if r.get("clogged")),
        mean_escapees=st.get("mean_escapees"),
        mean_escapees_ci=st.get("mean_escapees_ci") or [None, None],
        # nothing clogged: no estimate, the one-sided lower bound here
        mean_escapees_lower_bound=st.get("mean_escapees_lower_bound"),
        mean_escapees_method=st.get("mean_escapees_method"),
        decay_rate=st.get("decay_rate"),
        decay_rate_ci=st.get("decay_rate_ci") or [None, None],
        never_clogged_fraction=st.get("never_clogged_fraction"),
        never_clogged_fraction_ci=st.get("never_clogged_fraction_ci") or [None, None],
        wall_time_s=(summary or {}).get("wall_time_s"))
    return row


def point_text(row: Mapping) -> str:
    """A finished point's statistics for its line: ``<s>`` as every message says it
    (:func:`taichi_hsdem.stats.estimate_text`; a lower bound when nothing clogged)
    and the clogs."""
    from ..stats.text import mean_phrase
    mean = mean_phrase(row["mean_escapees"], row["mean_escapees_ci"],
                       row.get("mean_escapees_lower_bound"))
    return f"{mean}, {row['n_clogged']}/{row['n_ok']} clogged"


_CSV_STATS = ("n", "n_ok", "n_unstable", "n_clogged", "mean_escapees",
              "mean_escapees_ci", "mean_escapees_lower_bound", "mean_escapees_method", "decay_rate", "decay_rate_ci",
              "never_clogged_fraction", "never_clogged_fraction_ci", "wall_time_s")


def _write_table(rows: list[dict], out: Path) -> None:
    """``sweep.csv``: folder, status, one column per override key, the statistics
    (an interval as two columns ``..._lo``, ``..._hi``); empty cells for missing."""
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row["overrides"] if k not in keys]
    header = ["folder", "status"] + keys
    for name in _CSV_STATS:
        header += [f"{name}_lo", f"{name}_hi"] if name.endswith("_ci") else [name]
    header.append("message")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)

    def cell(v):
        return "" if v is None else (repr(v) if isinstance(v, float) else v)

    for row in rows:
        line = [row["folder"], row["status"]]
        line += [_value_text(row["overrides"][k]) if k in row["overrides"] else ""
                 for k in keys]
        for name in _CSV_STATS:
            v = row[name]
            line += [cell(v[0]), cell(v[1])] if name.endswith("_ci") else [cell(v)]
        line.append(row["message"] or "")
        w.writerow(line)
    atomic_write(out / SWEEP_CSV, buf.getvalue())


def _write_index(out: Path, base: Path, common: Mapping, entries: dict[str, dict],
                 quick: Mapping | None = None) -> None:
    """``index.json``: folder -> overrides, merged with what earlier sweeps into
    the same folder recorded; ``quick``: folder -> what ``--quick`` set there."""
    index = {}
    try:
        old = json.loads((out / INDEX).read_text())
        if isinstance(old, dict) and isinstance(old.get("points"), dict):
            index = old["points"]
    except (OSError, ValueError):
        pass
    index.update(entries)
    atomic_write(out / INDEX, json.dumps({"scene": str(base), "common": dict(common),
                                          "quick": dict(quick or {}), "points": index},
                                         indent=1, default=str) + "\n")


def run_sweep(base_scene_path: str | Path, points: Sequence[Mapping[str, Any]],
              out_dir: str | Path, resume: bool = True,
              progress: Callable[[str], None] | None = None,
              common: Mapping[str, Any] | None = None, quick: bool = False,
              cluster: str | None = None, study: str | None = None) -> list[dict]:
    """Run ``base_scene_path`` at every point; write one folder per point.

    Parameters
    ----------
    base_scene_path : str or Path
        The scene file every point starts from.
    points : list of dict
        Dotted overrides per point, e.g. ``{"particles.friction": 0.4}``
        (the keys and checks of ``--set``; values are Python values).
    out_dir : str or Path
        Gets one folder per point (:func:`point_folder`), ``sweep.csv``,
        ``sweep.png`` and ``index.json``.
    resume : bool
        Skip a point whose folder already holds a complete ``summary.json`` of the
        same scene; ``False`` runs every point again.
    progress : callable, optional
        Called with a one-line message as each point ends (with the points left
        and an estimate of their time) and, run here, every 5 s of a point.
    common : dict, optional
        Overrides applied to every point before its own.
    quick : bool
        Smoke test: each point run with :func:`quick_overrides` (at most two
        realizations, each to its ``run.t_end``); folder names do not change, so
        give a separate ``out_dir``.
    cluster : str, optional
        Run the points on a Dask cluster (:mod:`.cluster`): a scheduler address or
        ``"local[:N]"``; the folders must be on a file system the workers share.
    study : str, optional
        What the sweep is (the command line gives its sweep file's path; default
        the base scene's path): a finished point of another study is never run
        again into its folder (:class:`StudyFolderError`).

    Returns
    -------
    list of dict
        One row per point, in order: ``folder``, ``status`` (``"ran"``,
        ``"skipped"``, ``"unstable"``: ran but some realization went unstable,
        ``"failed"``: no result, see ``message``, ``"invalid"``: the set-up was
        refused), ``overrides``, ``message`` and the statistics of ``sweep.csv``
        (``n``, ``n_ok``, ``n_unstable``, ``n_clogged``, ``mean_escapees`` and its
        ``_ci``, ``mean_escapees_lower_bound``: when nothing clogged, with
        ``mean_escapees`` None, ``decay_rate`` and its ``_ci``, ``never_clogged_fraction`` and its
        ``_ci``, ``wall_time_s``).

    Raises
    ------
    SweepError
        A point is not a valid scene (every problem listed; nothing is run).
    StudyFolderError
        ``out_dir`` cannot be used (a file, a dangling link, another study writing
        it, a file of the user's with a result name, a finished point of another
        study): one line, nothing is run.
    ClusterError
        ``cluster`` cannot be used (Dask missing, no scheduler answering): one
        line, before the folder is made.
    """
    base = Path(base_scene_path)
    common = dict(common or {})
    points = [dict(p) for p in points]
    scenes = _check_points(base, points, common, str(base))
    quicks = [quick_overrides(scene) if quick else {} for scene in scenes]
    if quick:
        scenes = [load_scene(base, _override_strings({**common, **point, **q}))
                  for point, q in zip(points, quicks)]
    out = Path(out_dir)
    study = study or f"scene {base.resolve()}"
    # the cluster first: one it cannot use is refused before the folder is made
    with Cluster(cluster, say=progress) as pool, \
            StudyFolder(out, "sweep", legacy=_legacy_files) as folder:
        folder.refuse_foreign([SWEEP_CSV, INDEX, SWEEP_PNG], "the sweep")
        keys = [_scene_key(scene) for scene in scenes]
        _check_point_folders(out, points, keys, study, resume)
        folder.claim([SWEEP_CSV, INDEX, SWEEP_PNG])
        return _run_points(out, base, points, scenes, keys, common, study, resume, progress,
                           pool, quicks)


def _run_points(out, base, points, scenes, keys, common, study, resume, progress,
                pool, quicks) -> list[dict]:
    """:func:`run_sweep`'s work, in its checked and locked folder ``out``."""
    code_digest()                  # this process's code, before any point runs
    say = progress or (lambda message: None)
    total = len(points)
    rows: list = [None] * total
    tasks, where_of = [], []
    for k, (point, scene, key) in enumerate(zip(points, scenes, keys)):
        folder = point_folder(point)
        done = _finished_summary(out / folder, key) if resume else None
        if done is not None:
            say(f"[{k + 1}/{total}] {folder}: skipped (finished)")
            rows[k] = _row(folder, point, "skipped", done)
            continue
        task = [scene, point, common, str(base), str(out / folder), key, study, quicks[k]]
        if pool.kind is None and progress is not None:
            task.append(PointProgress(say, f"[{k + 1}/{total}] {folder}"))
        tasks.append(tuple(task))
        where_of.append(k)
    clock = Eta(len(tasks))
    if tasks:
        say(f"running {len(tasks)} point(s)" + ("" if pool.kind is None else
                                                f" on the cluster {pool.spec}"))

    def finished(i, answer):
        k = where_of[i]
        status, summary, message = answer
        folder = point_folder(points[k])
        head = f"[{k + 1}/{total}] {folder}"
        rows[k] = _row(folder, points[k], status, summary, message)
        left = clock.done()
        left = f"; {left}" if left else ""
        if summary is None:
            say(f"{head}: {'refused' if status == 'invalid' else 'failed'}: {message}{left}")
            return
        say(f"{head}: done in {summary['wall_time_s']:.1f} s, {point_text(rows[k])}"
            + (f"; {message}" if message else "") + left)

    pool.run(run_point, tasks, finished)
    _write_index(out, base, common, {row["folder"]: row["overrides"] for row in rows},
                 {point_folder(p): q for p, q in zip(points, quicks) if q})
    _write_table(rows, out)
    from .sweep_plot import no_estimate, plot_sweep
    if not plot_sweep(rows, out / SWEEP_PNG, title=f"{Path(base).stem}"
                      + (" (quick: <= 2 realizations a point)" if any(quicks) else "")):
        (out / SWEEP_PNG).unlink(missing_ok=True)      # no matplotlib: no stale plot
    blank = no_estimate(rows)
    if blank:
        say(f"{len(blank)} of {len(rows)} point(s) have no estimate of <s> (nothing escaped "
            f"or clogged, or no stable realization; a longer run.t_end gives one): "
            f"{', '.join(blank[:5])}{', ...' if len(blank) > 5 else ''}")
    return rows


def _legacy_files(out: Path) -> list[str]:
    """``sweep.csv`` and ``index.json`` of a sweep from before the study manifest,
    told by what they hold."""
    names = []
    try:
        index = json.loads((out / INDEX).read_text())
        if isinstance(index, dict) and isinstance(index.get("points"), dict) \
                and "scene" in index:
            names.append(INDEX)
    except (OSError, ValueError):
        pass
    try:
        with open(out / SWEEP_CSV, encoding="utf-8", errors="replace") as fh:
            if fh.readline().startswith("folder,status,"):
                names.append(SWEEP_CSV)
    except OSError:
        pass
    return names


def _point_study(summary: dict) -> str | None:
    sweep = summary.get("sweep")
    return sweep.get("study") if isinstance(sweep, dict) else None


def _check_point_folders(out: Path, points, keys, study: str, resume: bool):
    """Refuse (:class:`StudyFolderError`, one line) a point whose folder is a file
    or a dangling link, holds a file of a point's result name that no run of
    taichi_hsdem wrote, or holds the finished result of another study (a plain
    run's, or another sweep file's) that this sweep would run again."""
    from ..output import foreign_files
    for point, key in zip(points, keys):
        where = out / point_folder(point)
        problem = point_folder_problem(where)
        if problem:
            raise StudyFolderError(problem)
        if not where.is_dir():
            continue
        foreign = foreign_files(where)
        if foreign:
            raise StudyFolderError(
                f"{where / foreign[0]}: not written by a run of taichi_hsdem, and the "
                "sweep would replace it: move it, or choose another folder")
        try:
            summary = json.loads((where / SUMMARY).read_text())
        except (OSError, ValueError):
            continue                      # no finished result here
        if not isinstance(summary, dict) or (resume and _finished_summary(where, key)):
            continue                      # skipped, not rewritten
        if not isinstance(summary.get("sweep"), dict):
            raise StudyFolderError(
                f"{where}: holds the finished result of a run (not of a sweep), which this "
                "sweep would replace: move it, or choose another folder")
        other = _point_study(summary)
        if other is not None and other != study:
            raise StudyFolderError(
                f"{where}: holds a finished point of another sweep ({other}), which this "
                "one would replace: choose another folder, or remove that point's folder")


def run_point(scene: Scene, point: Mapping, common: Mapping, base: str, where: str,
              key: str, study: str | None = None, quick: Mapping | None = None,
              progress: Callable[[float, float], None] | None = None
              ) -> tuple[str, dict | None, str | None]:
    """Run one point of a sweep into folder ``where`` (here or on a cluster worker):
    ``(status, summary as written or None, message)``.

    The point is a run into its own folder, with a run's protections (the folder's
    lock, its files staged and published together, the manifest) and a run's files
    but the video and ParaView series: the scene, ``escapees.csv``,
    ``arches.csv``, ``flow.csv`` (and a network's files), the final state, the
    plots and ``summary.json`` (last: its presence marks the point finished), whose
    ``sweep`` entry records the point's overrides, the common ones and ``quick``'s.
    ``progress(t, t_end)`` is called after every check of the run.
    """
    # the simulator loads Taichi (about a second): only once there is something to run
    from ..output import FolderInUse, FolderUnusable, Pictures, Staging
    from ..runner import RunFailed, build, execute, unstable_message
    where = Path(where)
    try:
        sim = build(scene, on_phase=getattr(progress, "phase", None))
    except RunFailed as error:
        return "invalid", None, "; ".join(error.lines)
    try:
        with Staging(where) as staged:
            pictures = Pictures(sim, staged, moving=False)
            try:
                result = execute(sim, progress=progress)
            except RunFailed as error:
                return "failed", None, "; ".join(error.lines)
            result.summary["sweep"] = {
                "overrides": dict(point), "common": dict(common), "quick": dict(quick or {}),
                "base_scene": base, "scene_sha256": key, "study": study}
            pictures.finish(result)
            staged.publish(result, pictures.files())
    except (FolderInUse, FolderUnusable) as error:
        return "failed", None, str(error)
    summary = json.loads((where / SUMMARY).read_text())  # as later sweeps read it
    message = unstable_message(result)
    return ("unstable" if message else "ran"), summary, message


def _parser(prog: str) -> argparse.ArgumentParser:
    p = Parser(prog=prog, description="Run a parameter sweep: one base scene at many points of overrides, resumable.")
    p.add_argument("sweep", help="sweep file (TOML)")
    p.add_argument("--out", type=folder_name, help="output folder (default runs/<sweep file name>/)")
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="skip points whose folder holds a finished run of the same "
                        "scene by the same package code (default: --resume)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scene key at every point (after [common]; "
                        "repeatable); a key the points vary is refused")
    p.add_argument("--quick", action="store_true",
                   help="smoke test: <= 2 realizations a point, each to its run.t_end, "
                        "into OUT/quick/")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help="run the points on a Dask cluster: a scheduler address, or local[:N] "
                        "for N worker processes here (the cluster extra)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv=None, prog: str = "python -m taichi_hsdem sweep") -> int:
    """The sweep's command line (usage: the module doc); its exit status."""
    try:
        args = _parser(prog).parse_args(argv)
    except SystemExit as exc:          # --help (0) or a bad argument (2)
        return exc.code
    from .cluster import ClusterError
    try:
        sweep = load_sweep(args.sweep)
    except SweepError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    try:
        sets = command_line_sets(args.set, sweep.points)
    except SweepError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    from ..scene import SceneError
    refused = []
    for text in args.set:              # each --set alone, said in the user's words
        try:
            load_scene(sweep.scene, [text])
        except SceneError as exc:       # without load_scene's "FILE (--set TEXT): "
            origin = f"{Path(sweep.scene)} (--set {text}): "
            refused += [f"--set {text}: {line.removeprefix(origin)}" for line in exc.problems]
    if refused:
        for line in refused:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    common = {**sweep.common, **sets}
    out = Path(args.out) if args.out else Path("runs") / Path(
        args.sweep).stem
    if args.quick:
        out = out / "quick"

    # said with the first progress line, once the folder is checked: a refused
    # folder is one line
    header = [f"{args.sweep}: {len(sweep.points)} point(s) of {sweep.scene} -> {out}"]

    def say(message):
        if not args.quiet:
            while header:
                print(header.pop(), file=sys.stderr, flush=True)
            print(message, file=sys.stderr, flush=True)

    try:
        rows = run_sweep(sweep.scene, list(sweep.points), out, resume=args.resume,
                         progress=say, common=common, quick=args.quick,
                         cluster=args.cluster, study=str(Path(args.sweep).resolve()))
    except (StudyFolderError, SweepError) as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    except ClusterError as exc:
        print(exc, file=sys.stderr)
        return EXIT_INVALID
    invalid = [r for r in rows if r["status"] == "invalid"]
    failed = [r for r in rows if r["status"] in ("failed", "unstable")]
    for r in invalid + failed:
        print(f"{r['folder']}: {r['status']}: {r['message']}", file=sys.stderr)
    counts = {s: sum(1 for r in rows if r["status"] == s)
              for s in ("ran", "skipped", "unstable", "failed", "invalid")}
    say("done: " + ", ".join(f"{n} {s}" for s, n in counts.items() if n)
        + f" -> {out / 'sweep.csv'}")
    if invalid:
        return EXIT_INVALID
    return EXIT_FAILED if failed else EXIT_OK
