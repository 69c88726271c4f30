"""Pressure-solve cost against how often the multigrid hierarchy is rebuilt.

    python tools/bench_amg.py [--sim-time 0.3] [--full-every 0,2,4,8,16,64] [--repeats 3]

Records the permeability fields a real run hands to the pressure solver (the vani
scene, one realization, its own update interval, ``--sim-time`` simulated
seconds), then replays that sequence through :class:`taichi_hsdem.fluid.PressureSolver`
once per ``full_every`` value: 0 builds a Ruge-Stuben hierarchy at every change
of the matrix (the behaviour before refreshes existed); ``K`` builds one at every
``K + 1``-th change and in between only recomputes the Galerkin coarse operators
(``solver_pool.refresh``). Prints one JSON line per value: milliseconds per
solve (median of the repeats), preconditioned-CG iterations (mean and most), and
the largest pressure difference from the ``full_every = 0`` solutions relative
to the pressure range (both meet the solver's relative residual; the difference
is what that tolerance leaves).
"""
import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def record(sim_time, seed):
    """The permeability fields of one vani realization at each pressure update."""
    import taichi_hsdem as th
    scene = th.load_scene(ROOT / "scenes" / "vani_phi026.toml", [
        "run.realizations=1", f"run.t_end={sim_time}", "run.stop_at_clog=false",
        "fluid.workers=1", f"run.seed={seed}"])
    sim = th.Simulation(scene)
    fields = []
    solve = sim.fluid.solver.solve

    def spy(kappa, *args, **kwargs):
        fields.append(np.array(kappa, copy=True))
        return solve(kappa, *args, **kwargs)
    sim.fluid.solver.solve = spy
    sim.run()
    m = sim.model
    return fields, (m.fluid_active, m.fluid_dx, scene.fluid.viscosity, m.bc(),
                    scene.fluid.solver_tol, scene.fluid.gap)


def replay(fields, setup, full_every):
    from taichi_hsdem.fluid import PressureSolver
    active, dx, eta, bc, tol, gap = setup
    solver = PressureSolver(active, dx, dx, eta, bc, n_batch=1, tol=tol, gap=gap,
                            full_every=full_every)
    out, its = [], []
    t0 = time.perf_counter()
    for kappa in fields:
        p, info = solver.solve(kappa)
        out.append(p)
        its.append(info.iterations)
    wall = time.perf_counter() - t0
    solver.close()
    return wall, out, its


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim-time", type=float, default=0.3)
    ap.add_argument("--full-every", default="0,2,4,8,16,64")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1003)
    a = ap.parse_args(argv)
    fields, setup = record(a.sim_time, a.seed)
    changes = sum(1 for k0, k1 in zip(fields, fields[1:]) if not np.array_equal(k0, k1))
    print(f"recorded {len(fields)} solves, {changes} with a changed matrix", file=sys.stderr)
    reference = None
    values = [int(v) for v in a.full_every.split(",")]
    for k in [0] + [v for v in values if v != 0]:   # 0 first: the reference
        times = []
        for _ in range(a.repeats):
            wall, out, its = replay(fields, setup, k)
            times.append(wall)
        if reference is None:
            reference = out
        dev = max(float(np.nanmax(np.abs(p - q)) / (np.nanmax(q) - np.nanmin(q)))
                  for p, q in zip(out, reference))
        print(json.dumps({
            "full_every": k, "solves": len(fields),
            "ms_per_solve": round(1e3 * statistics.median(times) / len(fields), 3),
            "iterations_mean": round(float(np.mean(its)), 2), "iterations_max": int(max(its)),
            "max_pressure_dev_over_range": dev, "times_s": [round(t, 3) for t in times]}),
            flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
