"""Calibrate one scene parameter until the mean escapees before clogging match a target.

Usage::

    python tools/calibrate.py SCENE.toml --target 20 [--param particles.friction]
        --lo 0.1 --hi 0.9 [--realizations 20] [--rounds 8] [--xtol X]
        [--confidence 0.95] [--seed S] [--set section.key=value ...] [--out DIR]
        [--quick] [--quiet]

Each round runs one batch of ``--realizations`` realizations at one value of
``--param`` (fresh seeds every round, so the rounds are independent samples); the
rounds bracket the target and close in on it by regula falsi on ``log <s>``
(:func:`taichi_hsdem.studies.calibrate.calibrate`; ``<s>`` usually falls with friction, but
either direction works). The result is the calibrated value and the range of the
parameter over which the target lies inside the confidence interval of ``<s>``
(censoring-aware, :mod:`taichi_hsdem.stats`).

Writes ``DIR/calibration.csv`` (one row per evaluation, appended as it finishes)
and ``DIR/calibration.json`` (the result, every evaluation's counts), ``DIR``
defaulting to ``runs/calibrate_<scene name>/``. ``--quick`` is a smoke test: 4
realizations, 3 rounds, a tenth of ``run.t_end``.

Exit status: 0 calibrated (interval bounded inside the range; narrower than
``--xtol`` when given); 1 not bracketed, interval open, or a run failed (the
evaluations so far are written); 2 invalid scene or arguments.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from taichi_hsdem.cli import EXIT_FAILED, EXIT_INVALID, EXIT_OK, Parser  # noqa: E402

QUICK_REALIZATIONS, QUICK_ROUNDS, QUICK_T_FRACTION = 4, 3, 0.1
CSV_COLUMNS = ("round", "value", "seed", "n", "n_unstable", "n_clogged", "escapees_total",
               "mean_escapees", "mean_escapees_ci_lo", "mean_escapees_ci_hi",
               "wall_time_s")


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="tools/calibrate.py", description=__doc__.split("\n\n")[0])
    p.add_argument("scene", help="scene TOML file")
    p.add_argument("--target", type=float, required=True, help="<s> to match (> 0)")
    p.add_argument("--param", default="particles.friction",
                   help="dotted scene key to tune (default particles.friction)")
    p.add_argument("--lo", type=float, required=True, help="low end of the range")
    p.add_argument("--hi", type=float, required=True, help="high end of the range")
    p.add_argument("--realizations", type=int, default=20, metavar="N",
                   help="realizations per round (default 20)")
    p.add_argument("--rounds", type=int, default=8,
                   help="evaluations in all, the two ends included (default 8)")
    p.add_argument("--xtol", type=float, default=0.0,
                   help="stop once the interval is narrower than this (default: run "
                        "every round)")
    p.add_argument("--confidence", type=float, default=0.95, help="default 0.95")
    p.add_argument("--seed", type=int, help="seed of the first round's first "
                   "realization (default the scene's run.seed)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scalar of the scene (repeatable)")
    p.add_argument("--out", help="output folder (default runs/calibrate_<scene name>/)")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help="run each round as a task on a Dask cluster: a scheduler address, or "
                        "local[:N] (the cluster extra)")
    p.add_argument("--quick", action="store_true", help="smoke test: "
                   f"{QUICK_REALIZATIONS} realizations, {QUICK_ROUNDS} rounds, "
                   f"{QUICK_T_FRACTION:g} of run.t_end")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def _check_args(args) -> list[str]:
    bad = []
    if not (args.target > 0 and math.isfinite(args.target)):
        bad.append(f"--target: must be a positive number, got {args.target:g}")
    if not args.lo < args.hi:
        bad.append(f"--lo {args.lo:g} must be below --hi {args.hi:g}")
    if args.realizations < 1:
        bad.append(f"--realizations: must be >= 1, got {args.realizations}")
    if args.rounds < 2:
        bad.append(f"--rounds: must be >= 2 (the two ends), got {args.rounds}")
    if not 0 < args.confidence < 1:
        bad.append(f"--confidence: must lie strictly between 0 and 1, got "
                   f"{args.confidence:g}")
    if args.xtol < 0:
        bad.append(f"--xtol: must be >= 0, got {args.xtol:g}")
    if args.seed is not None and args.seed < 0:
        bad.append(f"--seed: must be >= 0, got {args.seed}")
    return bad


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return exc.code
    problems = _check_args(args)
    if problems:
        for line in problems:
            print(f"tools/calibrate.py: {line}", file=sys.stderr)
        return EXIT_INVALID
    from taichi_hsdem import stats
    from taichi_hsdem.runner import RunFailed
    from taichi_hsdem.scene import SceneError, load_scene
    from taichi_hsdem.studies.calibrate import CalibrationError, calibrate, simulation_evaluator
    from taichi_hsdem.studies.cluster import Cluster, ClusterError

    sets = list(args.set)
    realizations, rounds = args.realizations, args.rounds
    try:
        scene = load_scene(args.scene, sets)
        if args.quick:
            sets.append(f"run.t_end={QUICK_T_FRACTION * scene.run.t_end!r}")
            realizations, rounds = min(realizations, QUICK_REALIZATIONS), QUICK_ROUNDS
        for value in (args.lo, args.hi):   # the parameter and both ends, checked now
            load_scene(args.scene, sets + [f"{args.param}={value!r}"])
        pool = Cluster(args.cluster)
        evaluate = simulation_evaluator(args.scene, args.param, realizations, sets,
                                        seed=args.seed, pool=pool)
    except (SceneError, ClusterError) as exc:
        for line in getattr(exc, "problems", [str(exc)]):
            print(line, file=sys.stderr)
        return EXIT_INVALID
    out = pathlib.Path(args.out) if args.out else pathlib.Path("runs") / f"calibrate_{scene.name}"
    out.mkdir(parents=True, exist_ok=True)
    table = out / "calibration.csv"

    def say(message):
        if not args.quiet:
            print(message, file=sys.stderr, flush=True)

    with table.open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerow(CSV_COLUMNS)
    rounds_done = []

    def evaluate_and_record(value):
        escapees, clogged, info = evaluate(value)
        rounds_done.append(value)
        row = [len(rounds_done), repr(float(value)), info["seed"],
               len(escapees) + info["n_unstable"], info["n_unstable"], sum(clogged),
               sum(escapees)]
        if escapees:
            mean, (lo, hi) = stats.mean_escapees(escapees, clogged, args.confidence)
            row += [repr(mean), repr(lo), repr(hi)]
        else:
            row += ["", "", ""]
        row.append(repr(info["wall_time_s"]))
        with table.open("a", newline="") as fh:
            csv.writer(fh, lineterminator="\n").writerow(row)
        return escapees, clogged, info

    say(f"{args.scene}: calibrating {args.param} in [{args.lo:g}, {args.hi:g}] to "
        f"<s> = {args.target:g}, {rounds} round(s) of {realizations} realization(s) "
        f"-> {out}")
    try:
        with pool:
            cal = calibrate(evaluate_and_record, args.target, args.lo, args.hi,
                            rounds=rounds, xtol=args.xtol, confidence=args.confidence, log=say)
    except ClusterError as exc:
        print(exc, file=sys.stderr)
        return EXIT_INVALID
    except CalibrationError as exc:
        print(f"calibration stopped: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except RunFailed as exc:
        for line in exc.lines:
            print(f"calibration stopped: {line}", file=sys.stderr)
        return EXIT_INVALID if exc.kind == "invalid" else EXIT_FAILED
    report = {"scene": args.scene, "param": args.param, "set": sets,
              "realizations_per_round": realizations, **cal.to_dict()}
    (out / "calibration.json").write_text(json.dumps(report, indent=1) + "\n")
    if cal.converged:
        say(f"{args.param}: {cal.message} -> {out / 'calibration.json'}")
        return EXIT_OK
    print(f"{args.param}: {cal.message}", file=sys.stderr)
    return EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
