"""Run a parameter sweep: one base scene at many points of overrides, resumable.

Usage::

    python tools/sweep.py SWEEP.toml [--out DIR] [--resume | --no-resume] [--quick]
                                     [--quiet]

``SWEEP.toml`` names the base scene (relative to the sweep file), ``[common]``
overrides for every point, a ``[grid]`` of lists (cartesian product) and/or
``[[points]]`` tables (see :mod:`taichi_hsdem.studies.sweep`)::

    scene = "../scenes/hourglass24.toml"
    [common]
    "run.t_end" = 20.0
    "run.realizations" = 20
    [grid]
    "particles.friction" = [0.1, 0.25, 0.4, 0.9]

Each point writes ``DIR/<overrides>/`` (summary.json, escapees.csv,
scene.resolved.toml); the sweep writes ``DIR/sweep.csv`` (one row of clogging
statistics per point) and ``DIR/index.json`` (folder -> overrides). With
``--resume`` (the default) a point whose folder already holds the summary of the
same scene, run by the same package code, is skipped. ``--quick`` runs each point
for a tenth of its ``run.t_end`` with at most two realizations, into
``DIR/quick/``.

Exit status: 0 every point has its results; 1 a point failed or a realization went
unstable (the other points are written); 2 the sweep file or a point is invalid
(one line per problem; nothing is run).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from taichi_hsdem.cli import EXIT_FAILED, EXIT_INVALID, EXIT_OK, Parser  # noqa: E402


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="tools/sweep.py", description=__doc__.split("\n\n")[0])
    p.add_argument("sweep", help="sweep file (TOML)")
    p.add_argument("--out", help="output folder (default runs/<sweep file name>/)")
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="skip points whose folder holds a finished run of the same "
                        "scene by the same package code (default: --resume)")
    p.add_argument("--quick", action="store_true",
                   help="smoke test: 1/10 of run.t_end, <= 2 realizations, into OUT/quick/")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help="run the points on a Dask cluster: a scheduler address, or local[:N] "
                        "for N worker processes here (the cluster extra)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # --help (0) or a bad argument (2)
        return exc.code
    from taichi_hsdem.studies.cluster import ClusterError
    from taichi_hsdem.studies.sweep import SweepError, load_sweep, run_sweep
    try:
        sweep = load_sweep(args.sweep)
    except SweepError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    out = pathlib.Path(args.out) if args.out else pathlib.Path("runs") / pathlib.Path(
        args.sweep).stem
    if args.quick:
        out = out / "quick"

    def say(message):
        if not args.quiet:
            print(message, file=sys.stderr, flush=True)

    say(f"{args.sweep}: {len(sweep.points)} point(s) of {sweep.scene} -> {out}")
    try:
        rows = run_sweep(sweep.scene, list(sweep.points), out, resume=args.resume,
                         progress=say, common=sweep.common, quick=args.quick,
                         cluster=args.cluster)
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


if __name__ == "__main__":
    sys.exit(main())
