"""The DEM steps of one realization of many bodies in three orders, timed in turn:
as placed (``order.Numbered``: consecutive bodies lie far apart), in cell order
for each launch (``order.CellOrder``, what a run of at least
``order.MIN_BODIES`` bodies does: the arrays copied in cell order and back
around each launch, the same bits), and renumbered by cell once before the
steps (``renumbered``: no copies, the bound of what the order can give; a
different discretisation, see below).

One :class:`Simulation` of a benchmark case (``tools/bench.py``'s names, default
``channel-10000``) is set to the same disks each time, takes ``--warm`` steps,
then ``--steps`` timed steps of ``Simulation.advance`` in launches of
``--launch`` steps (a run launches the steps between two checks or solves:
about 50 to 110 for ``channel-10000``), the fluid forces held; ``--repeats``
rounds. It prints one JSON line: the median distance between consecutive
bodies in diameters, the milliseconds per step of each order (medians), each
round's ratios to the placed order, whether the cell order ended in the placed
run's bits, and how far apart the renumbered run's disks end, in d. The
renumbered run is not the same discretisation: a fluid cell that two touching
disks both cover belongs to the higher-numbered (``dem/coupling.py``: ``owner``),
so renumbering the user's bodies moves the carried flux and the fluid forces of
disks in contact (by up to 1 % on ``channel-300``), besides the order of every
sum.

    python tools/bench_order.py [--case channel-10000] [--steps 300] [--launch 50] [--repeats 3]
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
    p.add_argument("--launch", type=int, default=50)
    p.add_argument("--warm", type=int, default=5)
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args(argv)
    if a.steps < 1 or a.repeats < 1 or a.warm < 0 or a.launch < 1:
        print("--steps, --launch and --repeats must be at least 1, --warm at least 0",
              file=sys.stderr)
        return 2
    import bench
    from taichi_hsdem import load_scene
    from taichi_hsdem.dem import order as body_order
    from taichi_hsdem.simulation import Simulation
    path, overrides = bench.overrides(a.case, 1.0)
    sim = Simulation(load_scene(path, overrides))
    if sim.R != 1 or not sim.fused:
        print(f"{a.case}: one realization on the fused stepper wanted (the order is per "
              "realization)", file=sys.stderr)
        return 2
    st = sim.state()
    d = float(sim.model.d_max)
    x, theta, alive = st["x"], st["theta"], st["alive"]
    order = cell_order(x[0], d)
    numbered = body_order.Numbered(sim.N)
    cells = body_order.CellOrder(sim.N, sim.particles, sim.history, sim.neighbors)
    ways = {"placed": ((x, theta, alive), numbered),
            "cell_order": ((x, theta, alive), cells),
            "renumbered": ((x[:, order], theta[:, order], alive[:, order]), numbered)}
    times = {name: [] for name in ways}
    ends = {}
    held = {}             # the fluid forces of the first set-up: every run starts from them
    for _ in range(a.repeats):
        for name, ((xs, ths, als), how) in ways.items():
            sim._order = how
            sim.set_state(xs, theta=ths, alive=als)
            b = sim.bodies
            if not held:
                held.update(f=b.f_fluid.to_numpy(), tau=b.tau_fluid.to_numpy())
            rows = order if name == "renumbered" else slice(None)
            b.f_fluid.from_numpy(np.ascontiguousarray(held["f"][:, rows]))
            b.tau_fluid.from_numpy(np.ascontiguousarray(held["tau"][:, rows]))
            sim.advance(a.warm)
            left = a.steps
            t0 = time.perf_counter()
            while left > 0:
                sim.advance(min(a.launch, left))
                left -= a.launch
            times[name].append((time.perf_counter() - t0) / a.steps * 1e3)
            ends[name] = sim.state()["x"][0]
    back = np.empty_like(order)
    back[order] = np.arange(order.size)          # placed body i is renumbered body back[i]
    apart = float(np.max(np.hypot(*(ends["renumbered"][back] - ends["placed"]).T)) / d)
    print(json.dumps({
        "case": a.case, "bodies": int(sim.N), "steps": a.steps, "launch": a.launch,
        "spacing_d": {"placed": round(spacing(x[0], d), 2),
                      "cells": round(spacing(x[0, order], d), 2)},
        "ms_per_step": {k: round(statistics.median(v), 4) for k, v in times.items()},
        "cell_order_same_bits": bool(np.array_equal(ends["cell_order"], ends["placed"])),
        "renumbered_apart_d": apart,
        "ratio_over_placed": {k: [round(c / p, 3) for c, p in zip(v, times["placed"])]
                              for k, v in times.items() if k != "placed"}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
