"""What the pressure solves cost as the realizations of a batch stop, with the
stopped ones left out of the solves (``FluidCoupling.skip_stopped``, the
default: neither solved nor set up, their permeability not redrawn) and with
every realization solved at every solve, in one process.

A batch of the vani scene runs until every realization has clogged (or
``--t-end``), once each way and ``--repeats`` times in turn (left out, whole,
left out, ...); the two ways give the same bits, so their solves pair one to
one. Per band of running realizations it prints the solves' median wall time
each way and the median of their ratios, pair by pair, the same for the whole
fluid updates (the permeability drawn, the solve, the forces), then the whole
runs' times. Timing only (no test asserts a speed)::

    python tools/bench_stopped.py --realizations 32 --repeats 2
"""
import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BANDS = ((0.75, 1.0), (0.5, 0.75), (0.25, 0.5), (0.125, 0.25), (0.0, 0.125))


def run(realizations, t_end, skip):
    """(per solve: running count, seconds of the solve, of its fluid update), the
    run's wall seconds, the final positions."""
    from taichi_hsdem import Simulation, load_scene
    from taichi_hsdem.dem.coupling import FluidCoupling
    FluidCoupling.skip_stopped = skip
    sim = Simulation(load_scene(ROOT / "scenes" / "vani_phi026.toml",
                                [f"run.realizations={realizations}", f"run.t_end={t_end}"]))
    solver, log = sim.fluid.solver, []
    solve, update = solver.solve, sim.fluid.update

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        out = solve(*args, **kwargs)
        log[-1][1] = time.perf_counter() - t0
        return out

    def timed_update(*args, **kwargs):
        log.append([int(sim.batch.running.to_numpy().sum()), np.nan, np.nan])
        t0 = time.perf_counter()
        out = update(*args, **kwargs)
        log[-1][2] = time.perf_counter() - t0
        return out
    solver.solve, sim.fluid.update = timed, timed_update
    t0 = time.perf_counter()
    result = sim.run()
    wall = time.perf_counter() - t0
    log = np.array(log)
    return log[~np.isnan(log[:, 1])], wall, result.final["x"]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--realizations", type=int, default=32)
    p.add_argument("--t-end", type=float, default=5.0, help="simulated seconds at most")
    p.add_argument("--repeats", type=int, default=2, help="runs each way, in turn")
    a = p.parse_args(argv)
    from taichi_hsdem import backend
    backend.init("cpu", "f64")
    runs = {True: [], False: []}
    for _ in range(a.repeats):
        for skip in (True, False):
            runs[skip].append(run(a.realizations, a.t_end, skip))
    ref = runs[True][0][2]
    if not all(np.array_equal(r[2], ref) for way in runs.values() for r in way):
        raise SystemExit("the two ways ended in different positions: they must give the "
                         "same bits")
    left, whole = (np.stack([r[0] for r in runs[k]]) for k in (True, False))
    counts = left[0, :, 0]
    print(f"{a.realizations} realizations, {len(counts)} solves a run, {a.repeats} runs each way "
          "(the same bits)")
    for column, what in ((1, "solves"), (2, "fluid updates")):
        print(f"{what}: running   count   left out (ms)   whole (ms)   ratio, median of pairs")
        for lo, hi in BANDS:
            m = (counts > lo * a.realizations) & (counts <= hi * a.realizations)
            if not m.any():
                continue
            t_left, t_whole = left[:, m, column], whole[:, m, column]
            print(f"{int(lo * a.realizations) + 1:3d}-{int(hi * a.realizations):3d}   "
                  f"{m.sum():10d}   {1e3 * np.median(t_left):13.1f}   "
                  f"{1e3 * np.median(t_whole):10.1f}   {np.median(t_left / t_whole):.2f}")
    walls = [(r[1], w[1]) for r, w in zip(runs[True], runs[False])]
    print("whole runs (s), left out / whole: " + ", ".join(f"{x:.1f} / {y:.1f}" for x, y in walls)
          + f"; solves {left[:, :, 1].sum(axis=1).round(1).tolist()} / "
          f"{whole[:, :, 1].sum(axis=1).round(1).tolist()}; their fluid updates "
          f"{left[:, :, 2].sum(axis=1).round(1).tolist()} / "
          f"{whole[:, :, 2].sum(axis=1).round(1).tolist()}")


if __name__ == "__main__":
    main()
