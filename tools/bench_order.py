"""Would numbering the bodies in cell order speed up the DEM steps? (issue:
"bodies in cell order"), measured before it is built.

One :class:`Simulation` of a benchmark case (``tools/bench.py``'s names, default
``channel-10000``: 10,000 disks placed at random, so that consecutive bodies lie
far apart) is set to the same disks twice, alternately: in the placement's
numbering, and renumbered by their cell (cells of one diameter, column by column,
so that consecutive bodies are neighbours). Each time it takes ``--warm`` steps,
then ``--steps`` timed steps of ``Simulation.advance`` (the DEM launches alone,
the fluid forces held), ``--repeats`` pairs. It prints one JSON line: the median
distance between consecutive bodies in diameters, the milliseconds per step
of each numbering (medians, and the ratio of each pair), and how far apart the
same disk ends in the two numberings, in d. The disks are alike, but the two
runs are not the same discretisation: a fluid cell that two touching disks both
cover belongs to the higher-numbered (``dem/coupling.py``: ``owner``), so
renumbering moves the carried flux and the fluid forces of disks in contact (by
up to 1 % on ``channel-300``), besides the order of every sum.

    python tools/bench_order.py [--case channel-10000] [--steps 300] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def cell_order(x: np.ndarray, d: float) -> np.ndarray:
    """Indices of the bodies (x: (N, 2)) sorted by their cell of side d, column by
    column."""
    ix = np.floor((x[:, 0] - x[:, 0].min()) / d).astype(np.int64)
    iy = np.floor((x[:, 1] - x[:, 1].min()) / d).astype(np.int64)
    return np.lexsort((iy, ix))


def spacing(x: np.ndarray, d: float) -> float:
    """Median distance between consecutive bodies, in d."""
    return float(np.median(np.hypot(*np.diff(x, axis=0).T)) / d)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--case", default="channel-10000")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--warm", type=int, default=5)
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args(argv)
    if a.steps < 1 or a.repeats < 1 or a.warm < 0:
        print("--steps and --repeats must be at least 1, --warm at least 0", file=sys.stderr)
        return 2
    import bench
    from taichi_hsdem import load_scene
    from taichi_hsdem.simulation import Simulation
    path, overrides = bench.overrides(a.case, 1.0)
    sim = Simulation(load_scene(path, overrides))
    if sim.R != 1:
        print(f"{a.case}: one realization wanted (the order is per realization)",
              file=sys.stderr)
        return 2
    st = sim.state()
    d = float(sim.model.d_max)
    x, theta, alive = st["x"], st["theta"], st["alive"]
    order = cell_order(x[0], d)
    layouts = {"placed": (x, theta, alive),
               "cells": (x[:, order], theta[:, order], alive[:, order])}
    times = {name: [] for name in layouts}
    ends = {}
    for _ in range(a.repeats):
        for name, (xs, ths, als) in layouts.items():
            sim.set_state(xs, theta=ths, alive=als)
            sim.advance(a.warm)
            t0 = time.perf_counter()
            sim.advance(a.steps)
            times[name].append((time.perf_counter() - t0) / a.steps * 1e3)
            ends[name] = sim.state()["x"][0]
    back = np.empty_like(order)
    back[order] = np.arange(order.size)          # placed body i is cells body back[i]
    apart = float(np.max(np.hypot(*(ends["cells"][back] - ends["placed"]).T)) / d)
    print(json.dumps({
        "case": a.case, "bodies": int(sim.N), "steps": a.steps,
        "spacing_d": {"placed": round(spacing(x[0], d), 2),
                      "cells": round(spacing(x[0, order], d), 2)},
        "ms_per_step": {k: round(statistics.median(v), 4) for k, v in times.items()},
        "end_positions_apart_d": apart,
        "ratio_cells_over_placed": [round(c / p, 3) for c, p in
                                    zip(times["cells"], times["placed"])]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
