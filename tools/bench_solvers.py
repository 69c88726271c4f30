"""Pressure solvers side by side (issue #22): one JSON line per case and candidate.

    python tools/bench_solvers.py                   # every case (about 7 minutes on 2 cores)
    python tools/bench_solvers.py --quick           # the vani cases, 2 repeats, in-process
    python tools/bench_solvers.py --cases vani-R10 --candidates taichi,pyamg-block
    python tools/bench_solvers.py --study contrast  # iterations against contrast and grid
    python tools/bench_solvers.py --arch gpu --candidates taichi   # on a GPU machine

Cases. ``vani-R1``, ``vani-R10``: the fluid grid of scenes/vani_phi026.toml
(175 x 61 cells, its walls, flow-rate condition, tolerance and Kozeny-Carman
permeability), with the scene's 66 disks (6 cells across) placed at random without
overlap in each realization. ``big-R1``: 1590 x 720 cells, pressure drop across,
10,000 disks 6 cells across (area fraction 0.25) of 1/60 the free permeability.

Candidates. ``pyamg``: today's :class:`taichi_hsdem.fluid.PressureSolver`
(workers=1: a Ruge-Stuben hierarchy and CG per realization). ``pyamg-block``: one
hierarchy of the block-diagonal matrix of all realizations and one CG call (its
tolerance then holds for the batch, not for each realization). ``taichi``:
:class:`taichi_hsdem.fluid.gmg.TaichiPressureSolver` (``--parallel`` to force a way).

Measured per line: ``init_ms`` (constructor), ``cold_ms`` (a first solve from zero,
median of the repeats, each on a new solver), ``setup_ms`` (its assembly and
hierarchy part), ``warm_ms`` (median over ``repeats`` consecutive solves on one
solver, the disks shifted by 0.3 cells each time, each warm-started from the last
pressure, as in a run), iterations of both, ``error_cold`` / ``error_warm`` (the
largest pressure difference from a sparse direct solve of the same matrix, over
the pressure range; the first and last configuration), ``*_cpu_ms`` (CPU time of
this process, all its threads: the work, less sensitive than wall time to
other load on the machine), ``solver_mb`` (resident memory a solver added by the
end of its first solve: its arrays and hierarchy), ``peak_rss_mb`` of the
process that ran the candidate (each in its own process except with --quick) and
``rss_before_mb`` (its resident memory before the candidate started: imports and
the problem). Taichi's kernel compilation is done before timing, reported as
``compile_s``; ``bits_alone`` says whether realization 0 solved alone gave the
same bits as inside the batch.
"""
import argparse
import gc
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = ("vani-R1", "vani-R10", "big-R1")
CANDIDATES = ("pyamg", "pyamg-block", "taichi")
SHIFT = 0.3  # cells the disks move between two warm solves


# ---------------------------------------------------------------- problems
def place_disks(active, count, radius, rng, attempts=200):
    """Disk centres (cells) placed one after another at random where the active
    mask holds, without overlap; fewer if the space runs out."""
    nx, ny = active.shape
    size = 2.0 * radius  # bucket side: overlaps are looked for in the 3 x 3 buckets
    buckets = {}
    centres = []
    for _ in range(count):
        for _ in range(attempts):
            c = rng.uniform((0, 0), (nx, ny))
            if not active[int(c[0]), int(c[1])]:
                continue
            bx, by = int(c[0] // size), int(c[1] // size)
            near = [q for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                    for q in buckets.get((bx + dx, by + dy), ())]
            if all((c[0] - q[0]) ** 2 + (c[1] - q[1]) ** 2 >= size**2 for q in near):
                buckets.setdefault((bx, by), []).append(c)
                centres.append(c)
                break
    return np.array(centres)


def rasterise(shape, centres, radius, k_in, k_out):
    """kappa: ``k_in`` in the cells whose centre lies in a disk, ``k_out`` elsewhere."""
    kappa = np.full(shape, k_out)
    r = int(np.ceil(radius)) + 1
    for cx, cy in centres:
        i0, i1 = max(int(cx) - r, 0), min(int(cx) + r + 1, shape[0])
        j0, j1 = max(int(cy) - r, 0), min(int(cy) + r + 1, shape[1])
        if i0 >= i1 or j0 >= j1:
            continue
        x, y = np.meshgrid(np.arange(i0, i1) + 0.5, np.arange(j0, j1) + 0.5, indexing="ij")
        kappa[i0:i1, j0:j1][(x - cx) ** 2 + (y - cy) ** 2 < radius**2] = k_in
    return kappa


def problem(case, steps):
    """The grid, condition and ``steps + 1`` permeability batches of a case, the
    disks moved by SHIFT cells in x from one to the next."""
    name, reals = case.split("-R")
    R = int(reals)
    rng = np.random.default_rng(2026)
    if name == "vani":
        from taichi_hsdem import load_scene
        from taichi_hsdem.resolve import resolve
        scene = load_scene(ROOT / "scenes" / "vani_phi026.toml")
        model = resolve(scene)
        f = scene.fluid
        setup = {"active": model.fluid_active, "dx": model.fluid_dx, "dy": model.fluid_dx,
                 "viscosity": f.viscosity, "bc": model.bc(), "tol": f.solver_tol,
                 "gap": f.gap}
        count, radius = model.n_particles, model.species[0].d_eq / model.fluid_dx / 2
        k_in, k_out = model.species[0].kappa, model.kappa_free
    elif name == "big":
        setup = {"active": np.ones((1590, 720), bool), "dx": 1.0, "dy": 1.0, "viscosity": 1.0,
                 "bc": {"kind": "pressure", "p_in": 1.0, "p_out": 0.0}, "tol": 1e-8,
                 "gap": None}
        count, radius, k_in, k_out = 10000, 3.0, 1.0 / 60.0, 1.0
    else:
        raise SystemExit(f"unknown case {case!r}; cases: {', '.join(CASES)}")
    centres = [place_disks(setup["active"], count, radius, rng) for _ in range(R)]
    shape = setup["active"].shape
    kappas = [np.stack([rasterise(shape, c + [SHIFT * step, 0.0], radius, k_in, k_out)
                        for c in centres]) for step in range(steps + 1)]
    return setup, kappas


# ---------------------------------------------------------------- candidates
class BlockAMG:
    """One Ruge-Stuben hierarchy of the block-diagonal matrix of all realizations
    (the options of solver_pool.AMG_OPTIONS), solved by one CG call; the matrices
    are assembled by PressureSolver's own code."""

    def __init__(self, active, dx, dy, viscosity, bc, n_batch, tol, gap):
        from taichi_hsdem.fluid import PressureSolver
        self.host = PressureSolver(active, dx, dy, viscosity, bc, n_batch=n_batch, tol=tol,
                                   gap=gap)
        self.tol, self.x = tol, None
        self.stats = {"setup_seconds": 0.0}

    def solve(self, kappa):
        import pyamg
        import scipy.sparse as sp

        from taichi_hsdem.fluid import pool as solver_pool
        h = self.host
        R, n = h.n_batch, h._n
        t0 = time.perf_counter()
        h._assemble(np.arange(R), kappa.reshape(R, -1)[:, h._cells])
        blocks = [sp.csr_array((h._data[r], h._indices, h._indptr), shape=(n, n))
                  for r in range(R)]
        ml = pyamg.ruge_stuben_solver(sp.block_diag(blocks, format="csr"),
                                      **solver_pool.AMG_OPTIONS)
        self.stats["setup_seconds"] = time.perf_counter() - t0
        b = h._rhs.ravel()
        residuals = []
        self.x = ml.solve(b, x0=self.x, tol=self.tol, accel="cg", residuals=residuals)
        pressure = np.full((R, h.shape[0] * h.shape[1]), np.nan)
        pressure[:, h._cells] = self.x.reshape(R, n) + h.p_ref
        return pressure.reshape(R, *h.shape), len(residuals) - 1


def make(candidate, setup, R, parallel):
    args = (setup["active"], setup["dx"], setup["dy"], setup["viscosity"], setup["bc"])
    kw = {"n_batch": R, "tol": setup["tol"], "gap": setup["gap"]}
    if candidate == "pyamg":
        from taichi_hsdem.fluid import PressureSolver
        return PressureSolver(*args, **kw, workers=1)
    if candidate == "pyamg-block":
        return BlockAMG(*args, **kw)
    if candidate == "taichi":
        from taichi_hsdem.fluid.gmg import TaichiPressureSolver
        return TaichiPressureSolver(*args, **kw, parallel=parallel)
    raise SystemExit(f"unknown candidate {candidate!r}; candidates: {', '.join(CANDIDATES)}")


def solve(solver, kappa):
    """Pressure and iterations of one solve."""
    out = solver.solve(kappa)
    p, extra = out
    return p, extra if isinstance(extra, int) else extra.iterations


def measure(case, candidate, repeats, parallel="auto"):
    """Times, iterations and the pressures of the first and last configuration."""
    setup, kappas = problem(case, repeats)
    R = kappas[0].shape[0]
    out = {"case": case, "candidate": candidate, "cells": int(setup["active"].size),
           "realizations": R, "repeats": repeats,
           "rss_before_mb": _rss_mb()}
    if candidate == "taichi":
        t0 = time.perf_counter()
        warmup = make(candidate, setup, R, parallel)
        p_batch = solve(warmup, kappas[0])[0]
        out["compile_s"] = round(time.perf_counter() - t0, 2)
        out["parallel"] = warmup.parallel
        alone = make(candidate, setup, 1, parallel)
        out["bits_alone"] = bool(np.array_equal(solve(alone, kappas[0][:1])[0], p_batch[:1],
                                                equal_nan=True))
        del warmup, alone
    init, cold, cold_cpu, setup_s, its = [], [], [], [], []
    solver = None
    for repeat in range(repeats):
        del solver  # one solver alive at a time
        gc.collect()
        before = _rss_mb()
        t0 = time.perf_counter()
        solver = make(candidate, setup, R, parallel)
        t1, c1 = time.perf_counter(), time.process_time()
        p_cold, n = solve(solver, kappas[0])
        cold.append(time.perf_counter() - t1)
        cold_cpu.append(time.process_time() - c1)
        if repeat == 0:
            out["solver_mb"] = round(_rss_mb() - before, 1)
        init.append(t1 - t0)
        setup_s.append(solver.stats["setup_seconds"])
        its.append(n)
    warm, warm_cpu, warm_its = [], [], []
    for kappa in kappas[1:]:
        t0, c0 = time.perf_counter(), time.process_time()
        p_warm, n = solve(solver, kappa)
        warm.append(time.perf_counter() - t0)
        warm_cpu.append(time.process_time() - c0)
        warm_its.append(n)
    out.update(
        init_ms=_ms(statistics.median(init)), cold_ms=_ms(statistics.median(cold)),
        cold_ms_min=_ms(min(cold)), cold_cpu_ms=_ms(statistics.median(cold_cpu)),
        setup_ms=_ms(statistics.median(setup_s)), cold_iterations=int(statistics.median(its)),
        warm_ms=_ms(statistics.median(warm)), warm_ms_min=_ms(min(warm)),
        warm_cpu_ms=_ms(statistics.median(warm_cpu)),
        warm_iterations=int(statistics.median(warm_its)), peak_rss_mb=_rss_mb("VmHWM"))
    return out, p_cold, p_warm


def direct(setup, kappa):
    """Sparse direct solve of PressureSolver's own matrix for each realization."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla

    from taichi_hsdem.fluid import PressureSolver
    R = kappa.shape[0]
    h = PressureSolver(setup["active"], setup["dx"], setup["dy"], setup["viscosity"],
                       setup["bc"], n_batch=R, tol=setup["tol"], gap=setup["gap"])
    h._assemble(np.arange(R), kappa.reshape(R, -1)[:, h._cells])
    out = np.full((R, kappa[0].size), np.nan)
    for r in range(R):
        A = sp.csc_array((h._data[r], h._indices, h._indptr), shape=(h._n, h._n))
        out[r, h._cells] = sla.spsolve(A, h._rhs[r], permc_spec="MMD_AT_PLUS_A") + h.p_ref
    return out.reshape(kappa.shape)


def error(p, exact):
    """Largest |p - exact| over the pressure range, over the realizations."""
    return float(max(np.nanmax(np.abs(p[r] - exact[r])) / np.nanmax(np.ptp(
        exact[r][np.isfinite(exact[r])])) for r in range(exact.shape[0])))


# ---------------------------------------------------------------- convergence study
def contrast_study(quick, parallel):
    """Iterations from zero to 1e-8 against contrast, disk cover and grid size
    (disks 6 cells across, overlapping; ``taichi_ms``: that cold solve)."""
    from taichi_hsdem.fluid import PressureSolver
    from taichi_hsdem.fluid.gmg import TaichiPressureSolver
    grids = [(175, 61), (350, 122)] if quick else [(175, 61), (350, 122), (700, 244),
                                                    (1400, 488)]
    bc = {"kind": "pressure", "p_in": 1.0, "p_out": 0.0}
    rng = np.random.default_rng(7)
    for small in (True, False):  # compile both CPU ways first, out of the timings
        shape = (60, 40) if small else (300, 300)
        TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, bc,
                             parallel=parallel).solve(np.ones(shape))
    for shape in grids:
        active = np.ones(shape, bool)
        for phi in (0.25, 0.5):
            # random overlapping disks: at 0.5 they form clusters and enclose fluid
            count = int(phi * shape[0] * shape[1] / (np.pi * 9.0))
            centres = rng.uniform((0, 0), shape, size=(count, 2))
            for contrast in (1 / 60, 1e-3, 1e-6):
                kappa = rasterise(shape, centres, 3.0, contrast, 1.0)
                row = {"study": "contrast", "grid": list(shape), "disk_cover": phi,
                       "contrast": contrast}
                solver = TaichiPressureSolver(active, 1.0, 1.0, 1.0, bc, tol=1e-8,
                                              parallel=parallel)
                t0 = time.perf_counter()
                _, info = solver.solve(kappa)
                row.update(taichi_iterations=info.iterations,
                           taichi_ms=_ms(time.perf_counter() - t0), levels=len(solver.levels))
                if shape[0] * shape[1] <= 200_000:
                    _, info = PressureSolver(active, 1.0, 1.0, 1.0, bc, tol=1e-8).solve(kappa)
                    row["pyamg_iterations"] = info.iterations
                print(json.dumps(row), flush=True)


# ---------------------------------------------------------------- driver
def _ms(seconds):
    return round(1e3 * seconds, 2)


def _rss_mb(field="VmRSS"):
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        pass
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true",
                   help="vani cases only, 2 repeats, all in this process (no memory figures)")
    p.add_argument("--cases", help=f"comma-separated, from {', '.join(CASES)}")
    p.add_argument("--candidates", help=f"comma-separated, from {', '.join(CANDIDATES)}")
    p.add_argument("--repeats", type=int, default=None, help="default 5 (--quick: 2)")
    p.add_argument("--parallel", default="auto", help="TaichiPressureSolver's parallel")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--study", choices=("contrast",), help="run a study instead")
    p.add_argument("--one", nargs=3, help=argparse.SUPPRESS)  # case candidate outdir
    a = p.parse_args(argv)
    from taichi_hsdem import backend
    backend.init(a.arch, "f64")
    if a.study:
        contrast_study(a.quick, a.parallel)
        return 0
    repeats = a.repeats or (2 if a.quick else 5)
    if a.one:
        case, candidate, outdir = a.one
        row, p_cold, p_warm = measure(case, candidate, repeats, a.parallel)
        np.save(Path(outdir) / "cold.npy", p_cold)
        np.save(Path(outdir) / "warm.npy", p_warm)
        print(json.dumps(row), flush=True)
        return 0
    cases = a.cases.split(",") if a.cases else (CASES[:2] if a.quick else CASES)
    candidates = a.candidates.split(",") if a.candidates else CANDIDATES
    for case in cases:
        setup, kappas = problem(case, repeats)
        exact = [direct(setup, kappas[0]), direct(setup, kappas[-1])]
        for candidate in candidates:
            if a.quick:  # in this process
                row, p_cold, p_warm = measure(case, candidate, repeats, a.parallel)
                row["peak_rss_mb"] = row["rss_before_mb"] = None
            else:
                with tempfile.TemporaryDirectory(prefix="bench-solvers-") as tmp:
                    proc = subprocess.run(
                        [sys.executable, __file__, "--one", case, candidate, tmp,
                         "--repeats", str(repeats), "--parallel", a.parallel, "--arch", a.arch],
                        check=False, capture_output=True, text=True)
                    if proc.returncode != 0:
                        print(json.dumps({"case": case, "candidate": candidate,
                                          "error": proc.stderr.strip().splitlines()[-3:]}),
                              flush=True)
                        continue
                    row = json.loads(proc.stdout.strip().splitlines()[-1])
                    p_cold, p_warm = np.load(Path(tmp) / "cold.npy"), np.load(Path(tmp) / "warm.npy")
            row["error_cold"] = error(p_cold, exact[0])
            row["error_warm"] = error(p_warm, exact[1])
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
