"""Where a benchmark case's time goes: its run split into phases, each Taichi
kernel's share, and the pressure solve against its memory-traffic floor.

    python tools/profile_case.py channel-10000 --sim-time 0.005
    python tools/profile_case.py disks-0.26-R10 --sim-time 0.5
    python tools/profile_case.py disks-0.26-R10@fluid.solver_tol=1e-8 --top 10

A case is one of tools/bench.py's (the same overrides). The run is timed as
bench.py times it (a few steps first, to compile), once, with Taichi's kernel
profiler on, which synchronises after every kernel: the total runs a little
slower than bench.py's, the shares are what to read. Printed:

* **phases**: the DEM launches (``Simulation.advance``), the pressure solves
  (the solver's ``solve``: operators, right-hand side, CG, the report read), the
  rest of each fluid update (rasterising the particles, the held forces, reading
  the pressure back) and the host checks, with the wall time left over;
* **kernels**: the ``--top`` most expensive offloaded loops (Taichi names a
  kernel's loops ``<kernel>_c<n>_<k>_kernel_<loop>_<kind>``), with their share of
  the profiled time, their count and mean time;
* **the solve's floor**: cells x CG iterations (per solve, the most any
  realization of the batch took: the floor is then an upper bound) x the bytes a
  CG iteration moves per fine cell (``BYTES_PER_CELL_ITERATION``, counted from
  the kernels below) over the memory bandwidth ``--bandwidth`` (a triad ``y = a x
  + y`` moved 19-21 GB/s on the 2-core machine of docs/performance.md), and how
  far the measured solve is from it. Where a realization's grid stays in the cache (the vani grid, 10^4
  cells, about 1 MB) the floor is not bandwidth but arithmetic, and the ratio
  says how far the solve is from streaming its data once per pass.
"""
import argparse
import re
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

# Bytes a preconditioned CG iteration reads and writes per fine cell, float64,
# the carried volume's bodies included (the kernels of fluid/_gmg_cycle.py,
# _gmg_cg.py and _gmg_bodies.py): the pre- and the post-smoother's pass over the
# columns (op 16, x and b 16 read, x 8 written: 40 each), the restriction
# (op 16, x 8, b 8), the coarser levels (a third of the fine level's smoothing
# and restriction: 37), the direction (z, d read, d written: 24), the operator
# times it (op 16, d 8, the bodies' term 8, A d written 8: 40, its dot product
# in the same pass), the update (x, d, r, A d read, x and r written: 48), and the
# bodies' two passes (owner 4, unknown 1, a vector 8 read; the term 8 written:
# about 13 each, as most cells are read once).
BYTES_PER_CELL_ITERATION = 40 + 40 + 32 + 37 + 24 + 40 + 48 + 13 + 13


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("case", help="a tools/bench.py case, e.g. channel-10000 or disks-0.26-R10")
    p.add_argument("--sim-time", type=float, default=None,
                   help="simulated seconds (default: bench.py's, 0.005 for channel cases)")
    p.add_argument("--top", type=int, default=15, help="kernels to list")
    p.add_argument("--bandwidth", type=float, default=20.0,
                   help="memory bandwidth for the solve's floor, GB/s (default 20)")
    args = p.parse_args(argv)
    if args.top < 1 or args.bandwidth <= 0:
        p.error("--top must be at least 1 and --bandwidth positive")
    sim_time = args.sim_time
    if sim_time is None:
        sim_time = 0.005 if args.case.startswith(("channel", "micromodel")) else 0.5
    if sim_time <= 0:
        p.error("--sim-time must be positive")

    import bench
    import taichi as ti
    init = ti.init

    def with_profiler(*a, **k):
        k["kernel_profiler"] = True
        return init(*a, **k)
    ti.init = with_profiler
    from taichi_hsdem import Simulation, backend, load_scene
    from taichi_hsdem.scene import SceneError
    backend.init("cpu", "f64")
    try:
        scene_path, ov = bench.overrides(args.case, sim_time)
        sim = Simulation(load_scene(scene_path, ov))
    except (SceneError, ValueError, IndexError) as e:
        p.error(f"case {args.case!r}: {e}")
    if sim.fluid is None:
        p.error(f"case {args.case!r} has no fluid to profile")
    sim.update_fluid(force=True)
    sim.advance(5)                       # compile every kernel before timing
    phases, calls = defaultdict(float), defaultdict(int)
    for obj, name, phase in ((sim, "advance", "DEM steps (advance)"),
                             (sim, "update_fluid", "fluid updates"),
                             (sim.fluid.solver, "solve", "pressure solves"),
                             (sim, "_check", "host checks")):
        bench.time_calls(obj, name, phases, phase, calls)
    stats0 = dict(sim.fluid.solver.stats)
    steps0 = sim.steps
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    t0 = time.perf_counter()
    sim.run()
    ti.sync()
    wall = time.perf_counter() - t0
    stats = sim.fluid.solver.stats
    solves = stats["solves"] - stats0["solves"]
    iters = stats["iterations"] - stats0["iterations"]
    steps = sim.steps - steps0

    print(f"{args.case}: {steps} DEM steps, {solves} pressure solves of {sim.R} "
          f"realization(s), {wall:.2f} s wall (kernel profiler on)")
    print("\nphases")
    solve_s = phases["pressure solves"]
    rest_of_updates = phases["fluid updates"] - solve_s
    rows = [("DEM steps (advance)", phases["DEM steps (advance)"],
             f"{1e3 * phases['DEM steps (advance)'] / max(steps, 1):.3f} ms per step"),
            ("pressure solves", solve_s,
             f"{1e3 * solve_s / max(solves, 1):.1f} ms per solve, "
             f"{iters / max(solves, 1):.1f} CG iterations each"),
            ("rest of the fluid updates", rest_of_updates,
             f"{1e3 * rest_of_updates / max(calls['fluid updates'], 1):.1f} ms per update"),
            ("host checks", phases["host checks"], f"{calls['host checks']} checks"),
            ("other", wall - phases["DEM steps (advance)"] - phases["fluid updates"]
             - phases["host checks"], "")]
    for name, seconds, note in rows:
        print(f"  {name:28s} {seconds:8.3f} s {100 * seconds / wall:5.1f} %  {note}")

    records = _kernel_rows(ti)
    total = sum(r[1] for r in records) or 1.0
    print(f"\nkernels (top {args.top} of {len(records)}, {total:.2f} s profiled)")
    for name, seconds, count in records[:args.top]:
        print(f"  {100 * seconds / total:5.1f} %  {seconds:7.3f} s  {count:6d} x "
              f"{1e3 * seconds / count:8.3f} ms  {name}")

    nx, ny = sim.fluid.solver.shape
    cells = nx * ny * sim.R
    if solves and iters:
        floor = cells * (iters / solves) * BYTES_PER_CELL_ITERATION / (args.bandwidth * 1e9)
        measured = solve_s / solves
        print(f"\nthe solve's floor: {cells} cells x {iters / solves:.1f} iterations x "
              f"{BYTES_PER_CELL_ITERATION} B at {args.bandwidth:g} GB/s = "
              f"{1e3 * floor:.1f} ms per solve; measured {1e3 * measured:.1f} ms, "
              f"{measured / floor:.1f} times the floor; "
              f"{1e9 * measured / (cells * iters / solves):.1f} ns per cell and iteration")


def _kernel_rows(ti):
    """(name, total seconds, count) of every profiled offloaded loop, dearest
    first; a loop is named ``kernel, loop k`` from Taichi's
    ``<kernel>_c<n>_<m>_kernel_<k>_<kind>``."""
    from taichi.lang import impl
    prog = impl.get_runtime().prog
    prog.sync_kernel_profiler()
    prog.update_kernel_profiler()
    totals, counts = defaultdict(float), defaultdict(int)
    for rec in prog.get_kernel_profiler_records():
        m = re.match(r"^(.*)_c\d+_\d+_kernel_(\d+)_(\w+)$", rec.name)
        name = f"{m.group(1)}, loop {m.group(2)}" if m else rec.name
        totals[name] += rec.kernel_time / 1e3
        counts[name] += 1
    return sorted(((n, totals[n], counts[n]) for n in totals), key=lambda r: -r[1])


if __name__ == "__main__":
    main()
