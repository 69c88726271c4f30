"""Mean escapees before a clog against the neck width W/d, for one model.

Usage::

    python tools/neck_study.py [SCENE] [--wd 1.2,1.5,1.7,2.0,2.5] [--realizations N]
                               [--seed S] [--t-end T] [--set SECTION.KEY=VALUE ...]
                               [--out DIR] [--quiet]

Runs ``SCENE`` (default ``scenes/vani_phi026.toml``) with only
``geometry.constriction_width`` changed, to ``W/d`` times the equivalent diameter of
its largest species, at every ``--wd``, with the same seeds at every point
(``--set`` applies to every point: the model under test, e.g.
``--set fluid.particle_flux=false``). The points run as one sweep
(:func:`taichi_hsdem.studies.sweep.run_sweep`: resumable, one folder per point).
Writes ``DIR/neck.csv`` and ``DIR/neck.md``: per W/d the mean escapees before a
clog ``<s>`` with its 95 % interval (the summary's ``mean_escapees_ci``) and how
many realizations never clogged. ``<s>`` should rise with W/d (every experiment).

Exit status: 0 every point has its results; 1 a point failed or went unstable;
2 bad arguments or an invalid scene (one line each).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

from taichi_hsdem.exits import EXIT_FAILED, EXIT_INVALID, EXIT_OK, Parser

ROOT = pathlib.Path(__file__).resolve().parents[1]
WIDTH = "geometry.constriction_width"


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="tools/neck_study.py", description=__doc__.split("\n\n")[0])
    p.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "vani_phi026.toml"),
                   help="scene file (default scenes/vani_phi026.toml)")
    p.add_argument("--wd", default="1.2,1.5,1.7,2.0,2.5",
                   help="neck widths over the particle diameter, comma-separated")
    p.add_argument("--realizations", type=int, default=20, help="realizations per point")
    p.add_argument("--seed", type=int, default=100, help="seed of realization 0")
    p.add_argument("--t-end", type=float, default=3.0, help="physical time per realization, s")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override for every point (repeatable)")
    p.add_argument("--out", default="runs/neck_study", help="output folder")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def _ratios(text: str) -> list[float]:
    """``--wd``: positive numbers, comma-separated."""
    values = [float(v) for v in text.split(",") if v.strip()]
    if not values or min(values) <= 0:
        raise ValueError("need positive numbers")
    return values


def table(rows: list[dict], ratios: list[float]) -> tuple[str, str]:
    """(CSV, markdown) of the points: W/d, <s>, its interval, never clogged / n."""
    from taichi_hsdem.studies import fmt
    csv = ["wd,mean_escapees,ci_lo,ci_hi,never_clogged,n,n_unstable,status"]
    md = ["| W/d | `<s>` [95 %] | never clogged |", "|---|---|---|"]
    for wd, row in zip(ratios, rows):
        lo, hi = row["mean_escapees_ci"]
        never = row["n_ok"] - row["n_clogged"] if row["n"] else None
        csv.append(",".join("" if v is None else str(v) for v in (
            wd, row["mean_escapees"], lo, hi, never, row["n"], row["n_unstable"],
            row["status"])))
        # no clog at all: the mean is unbounded, its lower limit is what was seen
        mean = (f"> {fmt(lo)}" if row["mean_escapees"] is None and lo is not None
                else fmt(row["mean_escapees"]))
        md.append(f"| {wd:g} | {mean} [{fmt(lo)}, {fmt(hi)}] | {never} of {row['n']} |")
    return "\n".join(csv) + "\n", "\n".join(md) + "\n"


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # --help (0) or a bad argument (2)
        return exc.code
    try:
        ratios = _ratios(args.wd)
    except ValueError:
        print(f"--wd: {args.wd!r}: give positive numbers separated by commas", file=sys.stderr)
        return EXIT_INVALID
    from taichi_hsdem.output import atomic_write
    from taichi_hsdem.scene import SceneError, load_scene
    from taichi_hsdem.scene.toml import parse_override_value
    from taichi_hsdem.studies.sweep import SweepError, run_sweep
    try:
        scene = load_scene(args.scene, args.set)
    except SceneError as exc:
        for line in getattr(exc, "problems", [str(exc)]):
            print(line, file=sys.stderr)
        return EXIT_INVALID
    d = max(sp.d_eq() for sp in scene.particles)
    common = {"run.realizations": args.realizations, "run.seed": args.seed,
              "run.t_end": args.t_end}
    for item in args.set:           # load_scene has checked each one
        key, _, value = item.partition("=")
        common[key.strip()] = parse_override_value(value.strip())
    points = [{WIDTH: round(wd * d, 12)} for wd in ratios]   # no float noise in folder names
    out = pathlib.Path(args.out)

    def say(message):
        if not args.quiet:
            print(message, file=sys.stderr, flush=True)

    try:
        rows = run_sweep(args.scene, points, out, progress=say, common=common)
    except SweepError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    csv, md = table(rows, ratios)
    atomic_write(out / "neck.csv", csv)
    atomic_write(out / "neck.md", md)
    say(md)
    return EXIT_OK if all(r["status"] in ("ran", "skipped") for r in rows) else EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
