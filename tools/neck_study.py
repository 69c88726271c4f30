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
clog ``<s>`` with its 95 % interval (the summary's ``mean_escapees_ci``), how
many realizations never clogged, and where the clogs held: how far upstream of
the neck's entrance the most downstream particle near it sat when the run
stopped, in particle diameters (median and quartiles over the clogged
realizations; against a sudden contraction about 0.5; in a converging section an
arch can hold further up, where the channel is wider than ``W``: at half-angle
``a`` it is ``W + 2 x tan(a)`` wide there). ``<s>`` should rise with W/d (every
experiment).

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


def arch_positions(folder: pathlib.Path) -> list[float]:
    """How far upstream of the neck's entrance, in diameters of the largest
    species, the most downstream particle within 4 diameters of it (or in the
    neck) sat, in every clogged realization of a finished point (its
    ``summary.json``, ``final_state.npz`` and resolved scene; a point written
    before the npz existed: its summary's ``final_state``; none: no positions)."""
    import json

    from taichi_hsdem.output import NoFinalState, read_final_state
    from taichi_hsdem.resolve.domain import _geometry
    from taichi_hsdem.scene import load_scene
    summary = json.loads((folder / "summary.json").read_text())
    try:
        fin = read_final_state(folder, summary)
    except NoFinalState:
        return []
    scene = load_scene(folder / "scene.resolved.toml")
    g = _geometry(scene.geometry)
    d = max(sp.d_eq() for sp in scene.particles)
    out = []
    for r, res in enumerate(summary["realizations"]):
        if not res.get("clogged") or r >= len(fin["x"]):
            continue
        x = fin["x"][r][fin["alive"][r]]
        near = x[(x[:, 0] > g.constriction_x0 - 4 * d) & (x[:, 0] < g.constriction_x1 + d)]
        if len(near):
            out.append(float(g.constriction_x0 - near[:, 0].max()) / d)
    return out


def table(rows: list[dict], ratios: list[float],
          where: list[list[float]] | None = None) -> tuple[str, str]:
    """(CSV, markdown) of the points: W/d, <s>, its interval, never clogged / n,
    and where the clogs held (``where``: :func:`arch_positions` of each point)."""
    import numpy as np

    from taichi_hsdem.stats import estimate_text
    where = where or [[] for _ in ratios]
    csv = ["wd,mean_escapees,ci_lo,ci_hi,never_clogged,n,n_unstable,status,"
           "arch_upstream_median,arch_upstream_q1,arch_upstream_q3"]
    md = ["| W/d | `<s>` [95 %] | never clogged | clogs held upstream of the neck (d) |",
          "|---|---|---|---|"]
    for wd, row, w in zip(ratios, rows, where):
        lo, hi = row["mean_escapees_ci"]
        never = row["n_ok"] - row["n_clogged"] if row["n"] else None
        q = np.percentile(w, [50, 25, 75]) if w else [None] * 3
        csv.append(",".join("" if v is None else str(v) for v in (
            wd, row["mean_escapees"], lo, hi, never, row["n"], row["n_unstable"],
            row["status"], *q)))
        # no clog at all: the one-sided lower bound, as every message says it
        mean = estimate_text(row["mean_escapees"], (lo, hi))
        held = f"{q[0]:.2f} ({q[1]:.2f}-{q[2]:.2f})" if w else "-"
        md.append(f"| {wd:g} | {mean} | {never} of {row['n']} | {held} |")
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
    from taichi_hsdem.studies.sweep import point_folder
    where = [arch_positions(out / point_folder(p)) if (out / point_folder(p) / "summary.json")
             .exists() else [] for p in points]
    csv, md = table(rows, ratios, where)
    atomic_write(out / "neck.csv", csv)
    atomic_write(out / "neck.md", md)
    say(md)
    return EXIT_OK if all(r["status"] in ("ran", "skipped") for r in rows) else EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
