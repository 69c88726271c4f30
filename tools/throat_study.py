"""Do two throats of a pillar array, far apart, clog as a single constriction of
the same shape does? The per-passage clogging probability, both ways.

Usage::

    python tools/throat_study.py [--realizations N] [--seed S] [--t-end T]
                                 [--out DIR] [--quiet]

Two scenes from ``scenes/micromodel.toml`` (its disks, fluid, flow speed and
packing in the inlet):

* ``array``: one circular pillar of 1 mm (24-gon) in a 1.3 mm channel, so two
  throats of 150 um (1.5 d), one on each side, 1.15 mm apart (7.7 throat widths):
  ``geometry.rows = columns = 1``. A realization runs until both throats clog (the
  inlet is cut off) or ``--t-end``; ``throats.csv`` gives each throat's passages
  and whether it clogged.
* ``single``: the array's upper half, a 0.65 mm channel with the half pillar on
  its lower wall (the symmetry line made a wall, which in a Hele-Shaw cell passes
  no flux either way), half the flow rate and half the disks: one throat of the
  same shape, the single-constriction clog test (``run.stop_at_clog``).

Per-passage statistics: in ``single`` the escapees before the clog; in ``array``
each throat's passages before it clogged (censored at ``t_end`` when it never
did), and the escapees before the first of its throats clogged (two independent
throats of the single's per-passage probability give the same mean); each by the
censoring-aware geometric fit (``taichi_hsdem.stats``): ``<s>`` with its 95 %
interval and the difference (MOVER). Writes
``DIR/single/``, ``DIR/array/`` (run folders) and ``DIR/throat_study.md``.

Exit status: 0 done; 1 a run failed; 2 bad arguments.
"""
from __future__ import annotations

import argparse
import csv
import json
import pathlib
import sys

import numpy as np

from taichi_hsdem.exits import EXIT_FAILED, EXIT_INVALID, EXIT_OK, Parser

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "micromodel.toml"
PILLAR, GAP = 1.0e-3, 150e-6
INLET, OUTLET = 1.0e-3, 0.4e-3
SIDES = 24


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="tools/throat_study.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--realizations", type=int, default=20, help="realizations per scene")
    p.add_argument("--seed", type=int, default=0, help="seed of realization 0")
    p.add_argument("--t-end", type=float, default=4.0, help="physical time per realization, s")
    p.add_argument("--out", default="runs/throat_study", help="output folder")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def scenes(t_end: float, realizations: int, seed: int) -> tuple[list, dict]:
    """The array's ``--set`` overrides of scenes/micromodel.toml, and the single
    throat's scene as a dict (module notes)."""
    from taichi_hsdem import load_scene
    from taichi_hsdem.geometry.micromodel import channel_size, pillar_polygon
    from taichi_hsdem.scene.toml import parse_toml
    base = load_scene(SCENE)
    spacing = PILLAR + GAP
    length, width = channel_size(1, 1, PILLAR, spacing, INLET, OUTLET)
    _, shipped_width = channel_size(
        base.geometry.rows, base.geometry.columns, base.geometry.pillar_diameter,
        base.geometry.pillar_spacing, base.geometry.inlet_length, base.geometry.outlet_length)
    speed = base.fluid.flow_rate / (base.fluid.gap * shipped_width)       # mean, m/s
    # the shipped inlet's packing: its count over its inlet's area
    count = base.particles[0].count * (width * INLET) / (shipped_width * base.geometry.inlet_length)
    count = 2 * int(round(count / 2))
    common = [f"run.t_end={t_end!r}", f"run.realizations={realizations}", f"run.seed={seed}"]
    array = common + ["geometry.rows=1", "geometry.columns=1",
                      f"geometry.pillar_diameter={PILLAR!r}",
                      f"geometry.pillar_spacing={spacing!r}",
                      f"geometry.inlet_length={INLET!r}", f"geometry.outlet_length={OUTLET!r}",
                      f"fluid.flow_rate={speed * base.fluid.gap * width!r}",
                      f"particles.count={count}"]
    # the upper half: the pillar's polygon above y = 0 on the lower wall
    xc = INLET + spacing / 2
    poly = pillar_polygon((xc, 0.0), PILLAR / 2, SIDES)
    upper = poly[poly[:, 1] > 0]
    upper = upper[np.argsort(-np.arctan2(upper[:, 1], upper[:, 0] - xc))]   # left to right
    half = width / 2
    # where the polygon's edge across y = 0 on the right meets it (the left: mirrored)
    right = float(np.interp(0.0, [poly[-1, 1], poly[0, 1]], [poly[-1, 0], poly[0, 0]]))
    left = 2 * xc - right
    outline = ([[0.0, 0.0], [left, 0.0]] + upper.tolist() + [[right, 0.0], [length, 0.0],
               [length, half], [0.0, half]])
    single = parse_toml(SCENE.read_text())
    single["name"] = "micromodel_single_throat"
    single["description"] = "the upper half of a one-pillar array: one throat of 1.5 d"
    single["run"] = dict(single["run"], t_end=t_end, realizations=realizations, seed=seed)
    single["geometry"] = {"kind": "polygon", "outline": outline}
    single["fluid"] = dict(single["fluid"], flow_rate=speed * base.fluid.gap * half)
    single["particles"] = [dict(single["particles"][0], count=count // 2)]
    return array, single


def first_clog_escapees(folder: pathlib.Path, throat_rows) -> tuple[list, list]:
    """Per realization of the array run in ``folder``: the escapees counted at its
    first throat clog (``escapees.csv``'s sample at or before it) and True, or its
    last count and False when no throat clogged."""
    series = {}
    with open(folder / "escapees.csv") as fh:
        for row in csv.DictReader(fh):
            series.setdefault(int(row["realization"]), []).append(
                (float(row["t"]), int(row["escapees"])))
    s, c = [], []
    for r, samples in sorted(series.items()):
        t_clog = [float(x["t_clog"]) for x in throat_rows
                  if int(x["realization"]) == r and x["clogged"] == "true"]
        times = [t for t, _ in samples]
        if t_clog:
            at = max(0, int(np.searchsorted(times, min(t_clog), side="right")) - 1)
            s.append(samples[at][1])
            c.append(True)
        else:
            s.append(samples[-1][1])
            c.append(False)
    return s, c


def _summary(folder: pathlib.Path) -> dict:
    return json.loads((folder / "summary.json").read_text())


def _estimate(x) -> str:
    """``<s> [lo, hi]`` of a :func:`taichi_hsdem.stats.summarize` result; ``-``
    where it has none (nothing clogged)."""
    from taichi_hsdem.studies import fmt
    lo, hi = x["mean_escapees_ci"] or (None, None)
    return f"{fmt(x['mean_escapees'])} [{fmt(lo)}, {fmt(hi)}]"


def _rate(x) -> str:
    """The per-passage clogging probability ``1 / <s>``; ``-`` without an estimate."""
    from taichi_hsdem.studies import fmt
    m = x["mean_escapees"]
    return "-" if m is None else fmt(1 / m)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if args.realizations < 1 or args.t_end <= 0:
        print("tools/throat_study.py: --realizations and --t-end must be positive",
              file=sys.stderr)
        return EXIT_INVALID
    from taichi_hsdem import stats
    from taichi_hsdem.cli import main as run
    from taichi_hsdem.scene import load_scene, scene_to_toml
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    array, single = scenes(args.t_end, args.realizations, args.seed)
    single_toml = out / "single_throat.toml"
    single_toml.write_text(scene_to_toml(load_scene(single)))
    quiet = ["--quiet"] if args.quiet else []
    for name, cmd in (("array", [str(SCENE), *sum((["--set", v] for v in array), [])]),
                      ("single", [str(single_toml)])):
        code = run([*cmd, "--out", str(out / name), "--no-video", *quiet])
        if code != EXIT_OK:
            print(f"tools/throat_study.py: the {name} run failed (exit {code})",
                  file=sys.stderr)
            return EXIT_FAILED
    one = _summary(out / "single")
    stable = [r for r in one["realizations"] if r["status"] == "ok"]
    s1 = [r["escapees"] for r in stable]
    c1 = [bool(r["clogged"]) for r in stable]
    with open(out / "array" / "throats.csv") as fh:
        rows = list(csv.DictReader(fh))
    s2 = [int(r["passages"]) for r in rows]
    c2 = [r["clogged"] == "true" for r in rows]
    a, b = stats.summarize(s1, c1), stats.summarize(s2, c2)
    diff, ci = stats.mean_difference(s1, c1, s2, c2)
    # the array's escapees before its first clog (both throats open): with two
    # independent throats of the single's per-passage probability p, the passages
    # of both before the first clog are geometric with the same p
    s3, c3 = first_clog_escapees(out / "array", rows)
    f = stats.summarize(s3, c3)
    diff3, ci3 = stats.mean_difference(s1, c1, s3, c3)

    lines = [
        "# Two far-apart throats against a single one of the same shape",
        "",
        f"`python tools/throat_study.py --realizations {args.realizations} --seed "
        f"{args.seed} --t-end {args.t_end:g}`",
        "",
        "| | ensemble | clogged | mean passages before a clog `<s>` [95 %] |",
        "|---|---|---|---|",
        f"| single throat | {len(s1)} realizations | {sum(c1)} | {_estimate(a)} |",
        f"| array, per throat, whole run | {len(s2)} throats of {len(s2) // 2} realizations | "
        f"{sum(c2)} | {_estimate(b)} |",
        f"| array, escapees before the first clog | {len(s3)} realizations | {sum(c3)} | "
        f"{_estimate(f)} |",
        "",
        f"Differences from the single throat (MOVER, 95 %): per throat {diff:+.3g} "
        f"[{ci[0]:+.3g}, {ci[1]:+.3g}], before the first clog {diff3:+.3g} "
        f"[{ci3[0]:+.3g}, {ci3[1]:+.3g}]; per-passage clogging probability 1/<s>: "
        f"{_rate(a)} single, {_rate(b)} per array throat, {_rate(f)} before the array's "
        f"first clog.",
        f"Array realizations cut off (both throats clogged): "
        f"{sum(1 for r in _summary(out / 'array')['realizations'] if r['clogged'])} of "
        f"{len(s2) // 2}.",
    ]
    (out / "throat_study.md").write_text("\n".join(lines) + "\n")
    if not args.quiet:
        print("\n".join(lines))
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
