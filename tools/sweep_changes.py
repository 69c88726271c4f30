"""Which point of a finished sweep moved the clogging statistics: each point's
mean escapees before a clog ``<s>`` beside its change from a reference point,
with the paired bootstrap interval (the points share their seeds).

Usage::

    python tools/sweep_changes.py SWEEP_OUT [--reference base] [--out FILE.md]

``SWEEP_OUT`` is a ``python -m taichi_hsdem sweep`` output folder (one folder
per point, each with its ``summary.json``); ``--reference`` names the folder of
the point the others are compared with (default ``base``, the point of no
override). A change "moves `<s>`" when its 95 % interval (BCa, paired by seed,
4000 resamples: :func:`taichi_hsdem.stats.mean_difference`) leaves out 0. With
k points compared, about 0.05 k of them would "move" by chance alone, so a last
column asks the same of the Bonferroni interval at 1 - 0.05/k (20,000
resamples): "yes" there holds for the whole family of points at 95 %.
Prints a markdown table (and writes it to ``--out``).

Exit status: 0 the table was written; 2 the folder, a point or the reference is
missing or unreadable (one line each).
"""
from __future__ import annotations

import json
import pathlib
import sys

from taichi_hsdem.exits import EXIT_INVALID, EXIT_OK, Parser


def _counts(folder: pathlib.Path):
    """``(seeds, escapees, clogged, <s>, n)`` of a point: the seeds, escapees and
    clogs of its stable realizations, its ``<s>`` as every message writes it
    (:func:`taichi_hsdem.stats.estimate_text`: a lower bound when nothing clogged)
    and how many realizations it ran."""
    from taichi_hsdem.stats import estimate_text
    s = json.loads((folder / "summary.json").read_text())
    ok = [r for r in s["realizations"] if r["status"] == "ok"]
    bound = (s.get("statistics") or {}).get("mean_escapees_lower_bound")
    return ([r["seed"] for r in ok], [r["escapees"] for r in ok], [bool(r["clogged"]) for r in ok],
            estimate_text(s["mean_escapees"], s["mean_escapees_ci"] or (None, None), bound),
            len(s["realizations"]))


def _no_change(ref_clog, clog) -> str | None:
    """Why the change of ``<s>`` is undefined (nothing clogged on a side: that
    ``<s>`` is a lower bound only), else None."""
    sides = [name for name, c in (("the reference", ref_clog), ("this point", clog))
             if not any(c)]
    if not sides:
        return None
    return f"none: nothing clogged in {' or '.join(sides)} (its <s> is a lower bound)"


def _moves(lo: float, hi: float) -> str:
    return "yes" if (lo > 0 or hi < 0) else "no"


def table(out: pathlib.Path, reference: str = "base") -> str:
    """The markdown table of every point of ``out`` against ``reference``."""
    from taichi_hsdem.stats import mean_difference
    ref = _counts(out / reference)
    points = {f.name: _counts(f) for f in sorted(out.iterdir())
              if (f / "summary.json").exists()}
    # the points compared: every other one with a stable realization, if the reference has
    k = max(1, sum(name != reference and bool(c[0]) for name, c in points.items())
            if ref[0] else 1)
    family = 1.0 - 0.05 / k
    rows = ["| point | `<s>` [95 %] | clogged | change from the reference [95 %, paired] "
            f"| moves `<s>` | beyond chance over all {k} (Bonferroni) |",
            "|---|---|---|---|---|---|"]
    for name, (seeds, esc, clog, mean, n) in points.items():
        line = f"| {name} | {mean} | {sum(clog)} of {n} |"
        if name == reference:
            rows.append(line + " (reference) | | |")
            continue
        if not seeds or not ref[0]:
            rows.append(line + " no stable realization to compare | - | - |")
            continue
        why = _no_change(ref[2], clog)
        if why:
            rows.append(line + f" {why} | - | - |")
            continue
        paired = seeds == ref[0]
        diff, (dlo, dhi) = mean_difference(ref[1], ref[2], esc, clog, method="bca",
                                           paired=paired)
        _, (flo, fhi) = mean_difference(ref[1], ref[2], esc, clog, confidence=family,
                                        method="bca", paired=paired, n_boot=20000)
        rows.append(line + f" {diff:+.2f} [{dlo:+.2f}, {dhi:+.2f}]"
                    + ("" if paired else " (unpaired)")
                    + f" | {_moves(dlo, dhi)} | {_moves(flo, fhi)} |")
    return "\n".join(rows) + "\n"


def main(argv=None) -> int:
    p = Parser(prog="tools/sweep_changes.py", description=__doc__.split("\n\n")[0])
    p.add_argument("folder", help="a sweep's output folder")
    p.add_argument("--reference", default="base", help="the reference point's folder name")
    p.add_argument("--out", help="also write the table to this file")
    try:
        args = p.parse_args(argv)
    except SystemExit as exc:          # --help (0) or a bad argument (2)
        return exc.code
    out = pathlib.Path(args.folder)
    if not (out / args.reference / "summary.json").exists():
        print(f"{out}: no finished reference point {args.reference!r} (its summary.json)",
              file=sys.stderr)
        return EXIT_INVALID
    try:
        text = table(out, args.reference)
    except (OSError, ValueError, KeyError) as exc:
        print(f"{out}: a point's summary.json cannot be read: {exc}", file=sys.stderr)
        return EXIT_INVALID
    print(text, end="")
    if args.out:
        pathlib.Path(args.out).write_text(text)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
