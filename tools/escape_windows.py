"""Escape rate of an ``escapees-time`` figure run in windows of time.

    python tools/escape_windows.py runs/fig8 [--windows 0:5,0:1,1:2,2:5]

Reads ``series.csv`` and ``realizations.csv`` of a ``tools/figures.py
escapees-time`` run and prints, per packing fraction and window ``[t0, t1]``, the
escapes of every realization in the window pooled over the time each spent
unclogged in it (a clogged realization counts up to its clog), against the theory
rate ``4 phi Q / (H pi d^2)``. The figure's own rate counts from each
realization's first escape on; these windows show how the stream starts (no
particle is near the constriction at t = 0) and how fast it then runs.
"""
import argparse
import bisect
import csv
import sys
from collections import defaultdict
from pathlib import Path


def windows_table(folder, windows):
    """Rows ``(phi, t0, t1, escapes, unclogged_s, rate, theory_rate)``."""
    folder = Path(folder)
    series = defaultdict(list)
    theory = {}
    for r in csv.DictReader(open(folder / "series.csv")):
        t = float(r["t"])
        series[(r["phi"], int(r["seed"]))].append((t, int(r["escapees"])))
        if t > 0:
            theory[r["phi"]] = float(r["theory_escapees"]) / t
    ends = {}
    for r in csv.DictReader(open(folder / "realizations.csv")):
        if r["status"] != "ok":
            continue
        clogged = r["clogged"] in ("1", "True", "true")
        ends[(r["phi"], int(r["seed"]))] = float(r["t_clog"]) if clogged else float(r["t_stop"])
    # per stable realization: sample times, counts, and when it stopped counting
    runs = {}
    for key, pts in series.items():
        if key in ends:
            pts.sort()
            runs[key] = ([p[0] for p in pts], [p[1] for p in pts], ends[key])

    def count_at(times, counts, t):
        k = bisect.bisect_right(times, t) - 1
        return counts[k] if k >= 0 else 0

    rows = []
    for phi in sorted(theory, key=float):
        for t0, t1 in windows:
            events, duration = 0, 0.0
            for key, (times, counts, stop) in runs.items():
                end = min(t1, stop)
                if key[0] != phi or end <= t0:
                    continue
                events += count_at(times, counts, end) - count_at(times, counts, t0)
                duration += end - t0
            rate = events / duration if duration > 0 else float("nan")
            rows.append((float(phi), t0, t1, events, duration, rate, theory[phi]))
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", help="output folder of tools/figures.py escapees-time")
    p.add_argument("--windows", default="0:5,0:1,1:2,2:3,3:4,4:5,1:5",
                   help="comma-separated t0:t1 windows in seconds")
    a = p.parse_args(argv)
    try:
        windows = [tuple(float(v) for v in w.split(":")) for w in a.windows.split(",")]
        if any(len(w) != 2 or not w[1] > w[0] >= 0 for w in windows):
            raise ValueError
    except ValueError:
        print(f"--windows: expected t0:t1 pairs with 0 <= t0 < t1, got {a.windows!r}",
              file=sys.stderr)
        return 2
    missing = [n for n in ("series.csv", "realizations.csv") if not (Path(a.folder) / n).is_file()]
    if missing:
        print(f"{a.folder}: no {' or '.join(missing)} (run tools/figures.py escapees-time "
              f"first)", file=sys.stderr)
        return 2
    print("phi,t0,t1,escapes,unclogged_realization_s,rate_per_s,theory_per_s,ratio")
    for phi, t0, t1, ev, dur, rate, th in windows_table(a.folder, windows):
        print(f"{phi:g},{t0:g},{t1:g},{ev},{dur:.1f},{rate:.3f},{th:.3f},{rate / th:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
