"""How many realizations Taichi's CPU backend smooths at once: the realization-
innermost layout of the pressure solve (issue: "ensembles at the CPU's vector
width"), measured before it is built.

The kernel is the solve's dearest loop in its simplest form: red-black
Gauss-Seidel sweeps of the 5-point operator on the vani scene's grid (175 x 61
cells by default), each realization with its own coefficients (its own
particles), one thread per group of realizations, serial over the cells as the
one-thread-per-realization solve (``fluid/_gmg_cg.py: _solve_each``) is. The
layouts timed side by side, in one process:

* ``scalar``: the current one, each realization's grid on its own, a thread per
  realization (``W = 1``);
* ``lanes-W``: the ``W`` realizations of a group side by side in each cell's
  ``ti.types.vector(W)``, one thread per group, every operation on the vector.

Each prints nanoseconds per cell, realization and half-sweep (median of
``--repeats`` timed launches after a compiling one), and the lanes' speed-up
over ``scalar``. The answers of every layout are compared with the scalar one's
bits (the arithmetic per lane is the scalar's); the exit status is 1 if any
differs. ``--no-scalarize`` runs with ``real_matrix_scalarize=False`` (Taichi keeps
the vectors whole for LLVM): with Taichi 1.7.4 it aborts in LLVM's code
generation (an assertion in ``LoadInst``) on these fields of vectors.

Measured (docs/performance.md, "Realizations side by side"): on one thread of
an AVX-512 Xeon, 4 lanes smooth 1.7-1.8 times cheaper per cell and realization
than the scalar layout, 2 lanes 1.6, 8 and 16 lanes slower (0.75-0.8): Taichi
scalarizes the vectors, so the gain is from one thread's loads of neighbouring
realizations, not from SIMD.

    python tools/bench_lanes.py [--realizations 16] [--widths 2,4,8,16] [--nx 175 --ny 61]
                                [--sweeps 20] [--repeats 7] [--no-scalarize] [--threads 2]
"""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.

import argparse
import json
import statistics
import sys
import time

import numpy as np


def build(ti, R, W, nx, ny):
    """Fields and the sweep kernel of one layout: W = 1 the scalar one."""
    G = R // W
    vec = ti.types.vector(W, ti.f64) if W > 1 else ti.f64
    x, b, inv, ae, an = (ti.field(vec, shape=(G, nx, ny)) for _ in range(5))

    @ti.kernel
    def sweeps(n: ti.i32):
        for g in range(G):                              # one thread per group
            for k in range(n):                          # half-sweeps, serial
                colour = k % 2
                for i in range(1, nx - 1):
                    first = 1 + (i + 1 + colour) % 2           # (i + j) % 2 == colour
                    for jj in range((ny - 1 - first) // 2 + (ny - 1 - first) % 2):
                        j = first + 2 * jj
                        s = (b[g, i, j] + ae[g, i, j] * x[g, i + 1, j]
                             + ae[g, i - 1, j] * x[g, i - 1, j]
                             + an[g, i, j] * x[g, i, j + 1]
                             + an[g, i, j - 1] * x[g, i, j - 1])
                        x[g, i, j] = s * inv[g, i, j]
    return (x, b, inv, ae, an), sweeps


def fill(fields, R, W, nx, ny, seed=0):
    """The same coefficients for every layout: realization r's grids."""
    rng = np.random.default_rng(seed)
    ae = rng.uniform(0.5, 1.5, (R, nx, ny))
    an = rng.uniform(0.5, 1.5, (R, nx, ny))
    diag = ae + np.roll(ae, 1, 1) + an + np.roll(an, 1, 2) + 1e-3
    data = {"x": np.zeros((R, nx, ny)), "b": rng.uniform(-1, 1, (R, nx, ny)),
            "inv": 1.0 / diag, "ae": ae, "an": an}
    for f, name in zip(fields, ("x", "b", "inv", "ae", "an")):
        a = data[name]
        if W > 1:                          # (G, W, nx, ny) -> (G, nx, ny, W)
            a = a.reshape(R // W, W, nx, ny).transpose(0, 2, 3, 1)
        f.from_numpy(np.ascontiguousarray(a))


def answer(x, R, W, nx, ny):
    a = x.to_numpy()
    return a.transpose(0, 3, 1, 2).reshape(R, nx, ny) if W > 1 else a


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--realizations", type=int, default=16)
    p.add_argument("--widths", default="2,4,8,16")
    p.add_argument("--nx", type=int, default=175)
    p.add_argument("--ny", type=int, default=61)
    p.add_argument("--sweeps", type=int, default=20, help="half-sweeps per launch")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--no-scalarize", action="store_true")
    a = p.parse_args(argv)
    widths = [1] + [int(w) for w in a.widths.split(",") if w.strip()]
    R = a.realizations
    bad = [w for w in widths if R % w]
    if bad:
        print(f"--realizations {R} is not a multiple of the widths {bad}", file=sys.stderr)
        return 2
    import taichi as ti
    ti.init(arch=ti.cpu, default_fp=ti.f64, cpu_max_num_threads=a.threads, fast_math=False,
            real_matrix_scalarize=not a.no_scalarize, offline_cache=False, log_level=ti.WARN)
    results, ref = [], None
    for W in widths:
        fields, sweeps = build(ti, R, W, a.nx, a.ny)
        fill(fields, R, W, a.nx, a.ny)
        sweeps(a.sweeps)                               # compiles, and the reference bits
        ti.sync()
        got = answer(fields[0], R, W, a.nx, a.ny)
        if ref is None:
            ref = got
        same = bool(np.array_equal(got, ref))
        times = []
        for _ in range(a.repeats):
            fill(fields, R, W, a.nx, a.ny)
            ti.sync()
            t0 = time.perf_counter()
            sweeps(a.sweeps)
            ti.sync()
            times.append(time.perf_counter() - t0)
        cells = (a.nx - 2) * (a.ny - 2) / 2.0          # one colour a half-sweep
        ns = statistics.median(times) / (cells * R * a.sweeps) * 1e9
        results.append({"layout": "scalar" if W == 1 else f"lanes-{W}", "width": W,
                        "ns_per_cell_realization": round(ns, 3), "same_bits": same,
                        "times_s": [round(t, 5) for t in times]})
    base = results[0]["ns_per_cell_realization"]
    for r in results:
        r["speedup_over_scalar"] = round(base / r["ns_per_cell_realization"], 3)
        print(json.dumps({**r, "realizations": R, "grid": [a.nx, a.ny],
                          "scalarize": not a.no_scalarize, "threads": a.threads}))
    return 0 if all(r["same_bits"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
