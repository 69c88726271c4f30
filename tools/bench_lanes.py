"""How many realizations Taichi's CPU backend smooths at once, and in what storage:
the realization-innermost layout of the pressure solve (issue: "ensembles at the
CPU's vector width"), measured before it is built.

The kernel is the solve's dearest loop in its simplest form: red-black
Gauss-Seidel half-sweeps of the 5-point operator on the vani scene's grid (175 x 61
cells by default), each realization with its own coefficients (its own
particles), one thread per group of realizations, serial over the cells as the
one-thread-per-realization solve (``fluid/_gmg_cg.py: _solve_each``) is, every
array one-dimensional with the flat cell index ``k = i ny + j`` computed by hand,
as the package's are. Timed side by side, in one process, for each storage:

* ``ndarray``: ``ti.ndarray`` arrays passed to the kernel, the package's storage
  (one compiled kernel serves every grid size);
* ``field``: ``ti.field`` arrays the kernel closes over (their sizes compiled in);

and for each the layouts:

* ``scalar``: each realization's grid on its own, a thread per realization
  (``W = 1``); ``ndarray-scalar`` is today's solve;
* ``lanes-W``: the ``W`` realizations of a group side by side, each cell's values
  one ``ti.types.vector(W)`` element, one thread per group, every operation on
  the vector.

Each prints nanoseconds per cell, realization and half-sweep (median of
``--repeats`` timed launches after a compiling one), and the speed-up over
``ndarray-scalar``. The answers of every layout are compared with
``ndarray-scalar``'s bits (the arithmetic per lane is the scalar's); the exit
status is 1 if any differs. ``--no-scalarize`` runs with
``real_matrix_scalarize=False`` (Taichi hands the vectors to LLVM whole).

Measured (docs/performance.md, "Realizations side by side"): the vectors pay
only in fields, 2.5-2.8 times per cell and realization at 4 lanes (LLVM
vectorizes the division), where ndarrays of vectors run 1.1 times; 8 lanes
spill.

    python tools/bench_lanes.py [--realizations 16] [--widths 2,4,8] [--storage ndarray,field]
                                [--nx 175 --ny 61] [--sweeps 20] [--repeats 7]
                                [--no-scalarize] [--threads 2]
"""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.

import argparse
import json
import statistics
import sys
import time

import numpy as np

_NAMES = ("x", "b", "ae", "an")
# Taichi's CPU backend hands a parallel loop to its threads in blocks of up to 512
# iterations: a loop over groups takes 512 per group, one of them working, as the
# package's loops over realizations do (fluid/_gmg_cycle.py: _TASK).
_TASK = 512


def _sweep_body(ti, G, nx, ny):
    """The half-sweeps of every group on arrays ``x, b, ae, an`` (any storage
    and element: the arithmetic is written once)."""
    @ti.func
    def body(n, x: ti.template(), b: ti.template(), ae: ti.template(), an: ti.template()):
        for t in range(G * _TASK):                      # one thread per group
            g = t // _TASK
            if t % _TASK != 0:
                continue
            base = g * nx * ny
            for h in range(n):                          # half-sweeps, serial
                colour = h % 2
                for i in range(1, nx - 1):
                    first = 1 + (i + 1 + colour) % 2       # (i + j) % 2 == colour
                    for jj in range((ny - 1 - first) // 2 + (ny - 1 - first) % 2):
                        k = base + i * ny + first + 2 * jj
                        # the package's Gauss-Seidel update (fluid/_gmg_cycle.py:
                        # _relax): the diagonal from the four faces, 0 where it is 0
                        d = ae[k] + an[k] + ae[k - ny] + an[k - 1]
                        s = (b[k] + (ae[k - ny] * x[k - ny] + ae[k] * x[k + ny]
                                     + an[k - 1] * x[k - 1] + an[k] * x[k + 1]))
                        x[k] = ti.select(d > 0, s / d, 0.0)
    return body


def build(ti, storage, R, W, nx, ny):
    """The arrays of one layout and a ``sweeps(n)`` that runs it."""
    G = R // W
    element = ti.types.vector(W, ti.f64) if W > 1 else ti.f64
    body = _sweep_body(ti, G, nx, ny)
    if storage == "field":
        arrays = [ti.field(element, shape=(G * nx * ny,)) for _ in _NAMES]

        @ti.kernel
        def run(n: ti.i32):
            body(n, *ti.static(arrays))

        return arrays, lambda n: run(n)
    arrays = [ti.ndarray(element, shape=(G * nx * ny,)) for _ in _NAMES]
    A = ti.types.ndarray(dtype=element, ndim=1)

    @ti.kernel
    def run_nd(n: ti.i32, x: A, b: A, ae: A, an: A):
        body(n, x, b, ae, an)

    return arrays, lambda n: run_nd(n, *arrays)


def coefficients(R, nx, ny, seed=0):
    """Realization r's grids, the same for every layout."""
    rng = np.random.default_rng(seed)
    ae = rng.uniform(0.5, 1.5, (R, nx, ny))
    an = rng.uniform(0.5, 1.5, (R, nx, ny))
    return {"x": np.zeros((R, nx, ny)), "b": rng.uniform(-1, 1, (R, nx, ny)), "ae": ae,
            "an": an}


def fill(arrays, data, R, W, nx, ny):
    for f, name in zip(arrays, _NAMES):
        a = data[name]                     # (G, W, nx, ny) -> (G, nx, ny, W), flat cells
        a = a.reshape(R // W, W, nx, ny).transpose(0, 2, 3, 1).reshape(-1, W)
        f.from_numpy(np.ascontiguousarray(a if W > 1 else a[:, 0]))


def answer(x, R, W, nx, ny):
    return x.to_numpy().reshape(R // W, nx, ny, W).transpose(0, 3, 1, 2).reshape(R, nx, ny)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--realizations", type=int, default=16)
    p.add_argument("--widths", default="2,4,8")
    p.add_argument("--storage", default="ndarray,field",
                   help="comma-separated: ndarray (the package's), field")
    p.add_argument("--nx", type=int, default=175)
    p.add_argument("--ny", type=int, default=61)
    p.add_argument("--sweeps", type=int, default=20, help="half-sweeps per launch")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--no-scalarize", action="store_true")
    a = p.parse_args(argv)
    widths = [1] + [int(w) for w in a.widths.split(",") if w.strip()]
    storages = [s.strip() for s in a.storage.split(",") if s.strip()]
    R = a.realizations
    if any(s not in ("ndarray", "field") for s in storages) or not storages:
        print(f"--storage {a.storage}: each must be ndarray or field", file=sys.stderr)
        return 2
    bad = [w for w in widths if R % w]
    if bad:
        print(f"--realizations {R} is not a multiple of the widths {bad}", file=sys.stderr)
        return 2
    if a.nx < 3 or a.ny < 3:
        print("--nx and --ny must be at least 3", file=sys.stderr)
        return 2
    import taichi as ti
    ti.init(arch=ti.cpu, default_fp=ti.f64, cpu_max_num_threads=a.threads, fast_math=False,
            real_matrix_scalarize=not a.no_scalarize, offline_cache=False, log_level=ti.WARN)
    data = coefficients(R, a.nx, a.ny)
    layouts = [("ndarray", 1)] + [(s, w) for s in storages for w in widths
                                  if (s, w) != ("ndarray", 1)]
    results, ref = [], None
    for storage, W in layouts:
        arrays, sweeps = build(ti, storage, R, W, a.nx, a.ny)
        fill(arrays, data, R, W, a.nx, a.ny)
        sweeps(a.sweeps)                               # compiles, and the bits compared
        ti.sync()
        got = answer(arrays[0], R, W, a.nx, a.ny)
        if ref is None:
            ref = got
        times = []
        for _ in range(a.repeats):
            fill(arrays, data, R, W, a.nx, a.ny)
            ti.sync()
            t0 = time.perf_counter()
            sweeps(a.sweeps)
            ti.sync()
            times.append(time.perf_counter() - t0)
        cells = (a.nx - 2) * (a.ny - 2) / 2.0          # one colour a half-sweep
        ns = statistics.median(times) / (cells * R * a.sweeps) * 1e9
        results.append({"layout": f"{storage}-" + ("scalar" if W == 1 else f"lanes-{W}"),
                        "storage": storage, "width": W,
                        "ns_per_cell_realization": round(ns, 3),
                        "same_bits": bool(np.array_equal(got, ref)),
                        "times_s": [round(t, 5) for t in times]})
    base = results[0]["ns_per_cell_realization"]
    for r in results:
        r["speedup_over_ndarray_scalar"] = round(base / r["ns_per_cell_realization"], 3)
        print(json.dumps({**r, "realizations": R, "grid": [a.nx, a.ny],
                          "scalarize": not a.no_scalarize, "threads": a.threads}))
    return 0 if all(r["same_bits"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
