"""Where a benchmark case's time goes: its run split into phases, each Taichi
kernel's share, and the pressure solve against its memory-traffic floor.

    python tools/profile_case.py channel-10000 --sim-time 0.005
    python tools/profile_case.py disks-0.26-R10 --sim-time 0.5
    python tools/profile_case.py disks-0.26-R10@fluid.solver_tol=1e-8 --top 10
    python tools/profile_case.py micromodel-1000 --sim-time 0.03 --fixed-twin

A case is one of tools/bench.py's (the same overrides). The run is timed as
bench.py times it (a few steps first, to compile), once, with Taichi's kernel
profiler on, which synchronises after every kernel: the total runs a little
slower than bench.py's, the shares are what to read. Printed:

* **phases**: the DEM launches (``Simulation.advance``), the pressure solves
  (the solver's ``solve``: operators, right-hand side, CG, the report read), the
  rest of each fluid update (rasterising the particles, the held forces, reading
  the pressure back) and the host checks (of which a micromodel's throats), with
  the wall time left over;
* **kernels**: the ``--top`` most expensive offloaded loops (Taichi names a
  kernel's loops ``<kernel>_c<n>_<k>_kernel_<loop>_<kind>``), with their share of
  the profiled time, their count and mean time;
* **solves** (the multigrid CG): per solve the iterations, the cells whose
  permeability changed since the last one, the relative residual after the first
  and the last iteration and the mean reduction per iteration: how much a solve
  starts from (a warm start where little moved) and how fast it converges; with
  ``--fixed-twin`` each solve's permeability is also solved from the same
  initial guess without the moving bodies' term (fixed obstacles), to tell what
  that term costs (the timings then include those solves);
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

import numpy as np

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
    p.add_argument("--fixed-twin", action="store_true",
                   help="also solve each pressure from the same start without the bodies' "
                        "term (fixed obstacles), for the solves table; the timings then "
                        "include those solves")
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
    from taichi_hsdem import Simulation, backend, load_scene, observables
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
    solves_seen = _watch_convergence(sim.fluid.solver,
                                     _fixed_twin(sim) if args.fixed_twin else None)
    phases, calls = defaultdict(float), defaultdict(int)
    for obj, name, phase in ((sim, "advance", "DEM steps (advance)"),
                             (sim, "update_fluid", "fluid updates"),
                             (sim.fluid.solver, "solve", "pressure solves"),
                             (sim, "_check", "host checks"),
                             (observables, "observe_throats", "throats")):
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
            ("host checks", phases["host checks"], f"{calls['host checks']} checks" + (
                f", of which the throats' {phases['throats']:.3f} s "
                f"({1e3 * phases['throats'] / calls['throats']:.2f} ms per realization and "
                "check)" if calls["throats"] else "")),
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

    _print_convergence(solves_seen)

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


# Solves listed one a row (the rest summed up in one).
SOLVE_ROWS = 10


def _fixed_twin(sim):
    """A second multigrid solver on the simulation's grid, for --fixed-twin."""
    from taichi_hsdem.fluid.gmg import TaichiPressureSolver
    m, fl = sim.model, sim.scene.fluid
    if not hasattr(sim.fluid.solver, "_read_report"):
        return None
    return TaichiPressureSolver(m.fluid_active, m.fluid_dx, m.fluid_dx, fl.viscosity, m.bc(),
                                n_batch=sim.R, tol=fl.solver_tol, gap=fl.gap)


def _watch_convergence(solver, twin=None):
    """Per pressure solve of the multigrid CG (fluid/gmg.py): the CG iterations,
    the cells whose permeability changed since the last solve (the scan's count)
    and the relative residual ``|r| / |b|`` at each report the host reads (after
    every iteration on the CPU's ``rows`` way; once, at the end, in the
    ``realizations`` way), of the realization that took the most iterations.
    Reads only the report the solver reads anyway. With ``twin`` (_fixed_twin)
    each solve's kappa is first solved by it from the same initial guess without
    the bodies' term, watched the same way. Returns the list it fills: per solve
    the reads, and the twin's (a second list)."""
    if not hasattr(solver, "_read_report"):
        return []                               # pyamg: nothing to watch
    from taichi_hsdem.fluid._gmg_cg import _REPORT_FLAGS
    from taichi_hsdem.fluid._gmg_cycle import _BB, _CHANGED, _ITERS, _RR, _SOL
    seen = []

    def watch(s, slot):
        read = s._read_report

        def read_watched(*a, **k):
            report = read(*a, **k)
            if seen:
                r = int(np.argmax(report[:, _REPORT_FLAGS + _ITERS]))
                seen[-1][slot].append((int(report[r, _REPORT_FLAGS + _ITERS]),
                                       int(report[r, _REPORT_FLAGS + _CHANGED]),
                                       float(np.sqrt(report[r, _RR]
                                                     / max(report[r, _BB], 1e-300)))))
            return report
        s._read_report = read_watched
    watch(solver, 0)
    if twin is not None:
        watch(twin, 1)
    solve = solver.solve

    def solve_watched(kappa, *a, **k):
        seen.append(([], []))
        if twin is not None:
            cg = twin._cg.to_numpy()
            cg[_SOL] = solver._cg.to_numpy()[_SOL]     # the same initial guess
            twin._cg.from_numpy(cg)
            twin.solve(kappa)
        return solve(kappa, *a, **k)
    solver.solve = solve_watched
    return seen


def _print_convergence(seen):
    """The convergence table of _watch_convergence: a row per solve."""
    rows = [s[0] for s in seen if s[0]]
    if not rows:
        return
    twins = [s[1] for s in seen if s[0]]
    print("\nsolves (the slowest realization): CG iterations, cells whose permeability "
          "changed, |r|/|b| after the first and the last iteration, the mean reduction "
          "per iteration")
    for k, reads in enumerate(rows):
        if k == SOLVE_ROWS and len(rows) > SOLVE_ROWS + 1:
            its = [r[-1][0] for r in rows[k:]]
            print(f"  ... {len(its)} more, {min(its)}-{max(its)} iterations")
            break
        print(f"  {k:3d}  {_trend(reads)}")
        if twins[k]:
            print(f"       {_trend(twins[k], changed=False)}  (fixed obstacles, same start)")


def _trend(reads, changed=True):
    """A row of the solves table from one solve's reads."""
    iters, n_changed, first = reads[0]
    last_iters, _, last = reads[-1]
    if last_iters > iters and first > 0 and last > 0:
        trend = (f"{first:9.2e} -> {last:9.2e}  "
                 f"{(last / first) ** (1.0 / (last_iters - iters)):5.2f} per iteration")
    else:   # read once, at the end (the realizations way)
        trend = f"{last:9.2e} at the end"
    cells = f"{n_changed:9d} changed" if changed else " " * 17
    return f"{last_iters:4d} iterations  {cells}  {trend}"


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
