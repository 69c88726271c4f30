"""Would a colour-split layout speed up the ``gmg`` smoother? One run, three kernels.

    python tools/bench_layout.py [--nx 1590] [--ny 720] [--repeats 7]

On the 10,000-disk channel's fine grid (1590 x 720 cells by default), with random
transmissibilities, it times one red Gauss-Seidel half-sweep

* ``strided``: the package's layout (``fluid/_gmg_cycle.py``): a column of ny cells
  and a ghost, both colours interleaved, the east and north transmissibilities of
  a cell side by side; a thread takes 64 cells of a column, every second one;
* ``separate``: the same layout with the east and north transmissibilities, the
  correction and its right-hand side each in a one-dimensional array of its own
  (the package keeps ``(tx, ty)`` pairs and a two-row work array);
* ``split``: each colour of a column stored contiguously, with its own west, east,
  south and north transmissibilities and inverse diagonal, so that the loop over a
  column's red cells reads the black ones at unit stride (what a vectorizing
  compiler wants);

and, for the machine's limit, a ``triad`` ``y = a x + y`` over 2^24 float64s. It
prints the median time of each and the bytes each moves per second. The two
half-sweeps do the same arithmetic; the layouts differ only in where the values
lie. Taichi's CPU backend, float64, ``fast_math`` off as in the package.
"""
import argparse
import time

import numpy as np
import taichi as ti

SEGMENT = 64   # cells (of one colour, in split) per work item, as fluid/_gmg_cycle.py


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nx", type=int, default=1590)
    ap.add_argument("--ny", type=int, default=720)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args()
    ti.init(arch=ti.cpu, default_fp=ti.f64, fast_math=False, offline_cache=False,
            log_level=ti.ERROR)
    nx, ny = a.nx, a.ny
    s = ny + 1                     # column stride: ny cells and one ghost
    n = (nx + 2) * s               # ghost columns on both sides
    half = (ny + 1) // 2           # cells of one colour per column, at most
    hs = half + 2                  # a colour's column stride: one pad at each end
    m = (nx + 2) * hs
    rng = np.random.default_rng(0)
    tx, ty = rng.uniform(0.5, 1.5, n), rng.uniform(0.5, 1.5, n)
    x, b = rng.standard_normal(n), rng.standard_normal(n)
    ghost = np.zeros((nx + 2, s), bool)   # the ghosts hold no correction
    ghost[[0, -1], :] = True
    ghost[:, ny] = True
    x[ghost.ravel()] = 0.0

    vec2 = ti.types.vector(2, ti.f64)
    op = ti.ndarray(vec2, n)
    op.from_numpy(np.stack([tx, ty], 1))
    mg = ti.ndarray(ti.f64, (2, n))
    mg.from_numpy(np.stack([x, b]))

    segs = (ny + SEGMENT - 1) // SEGMENT   # work items per column

    @ti.func
    def red_run(t, colour):
        """First index and count of the cells of one colour in work item t: a
        segment of SEGMENT cells of one column, every second one."""
        i, seg = t // segs, t % segs
        j0, j1 = seg * SEGMENT, ti.min((seg + 1) * SEGMENT, ny)
        first = j0 + (i + colour + j0) % 2
        return (i + 1) * s + first, (j1 - first + 1) // 2

    @ti.kernel
    def strided(op: ti.types.ndarray(dtype=vec2, ndim=1), mg: ti.types.ndarray(ndim=2),
                colour: ti.i32):
        for t in range(nx * segs):
            k0, count = red_run(t, colour)
            for h in range(count):
                k = k0 + 2 * h
                d = op[k][0] + op[k][1] + op[k - s][0] + op[k - 1][1]
                v = mg[1, k] + (op[k - s][0] * mg[0, k - s] + op[k][0] * mg[0, k + s]
                                + op[k - 1][1] * mg[0, k - 1] + op[k][1] * mg[0, k + 1])
                mg[0, k] = v / d

    A1 = ti.types.ndarray(dtype=ti.f64, ndim=1)
    flat = []
    for v in (tx, ty, x, b):
        arr = ti.ndarray(ti.f64, n)
        arr.from_numpy(v)
        flat.append(arr)

    @ti.kernel
    def separate(tx: A1, ty: A1, x: A1, b: A1, colour: ti.i32):
        for t in range(nx * segs):
            k0, count = red_run(t, colour)
            for h in range(count):
                k = k0 + 2 * h
                d = tx[k] + ty[k] + tx[k - s] + ty[k - 1]
                v = b[k] + (tx[k - s] * x[k - s] + tx[k] * x[k + s]
                            + ty[k - 1] * x[k - 1] + ty[k] * x[k + 1])
                x[k] = v / d

    def split(values, c):
        """Cells of colour c ((i + j) % 2 == c) of a strided array, colour-split."""
        out = np.zeros(m)
        for i in range(nx):
            j = np.arange((i + c) % 2, ny, 2)
            out[(i + 1) * hs + 1 + j // 2] = values[(i + 1) * s + j]
        return out

    west, south = np.roll(tx, s), np.roll(ty, 1)
    coef = np.zeros((2, 5, m))
    for c in (0, 1):
        for q, v in enumerate((west, tx, south, ty, 1.0 / (tx + ty + west + south))):
            coef[c, q] = split(v, c)
    cw = ti.ndarray(ti.f64, (2, 5, m))
    cw.from_numpy(coef)
    cx = ti.ndarray(ti.f64, (2, m))
    cx.from_numpy(np.stack([split(x, 0), split(x, 1)]))
    cb = ti.ndarray(ti.f64, (2, m))
    cb.from_numpy(np.stack([split(b, 0), split(b, 1)]))

    @ti.kernel
    def colour_split(cw: ti.types.ndarray(ndim=3), cx: ti.types.ndarray(ndim=2),
                     cb: ti.types.ndarray(ndim=2), colour: ti.i32):
        segs = (half + SEGMENT - 1) // SEGMENT
        o = 1 - colour
        for t in range(nx * segs):
            i, seg = t // segs, t % segs
            base = (i + 1) * hs + 1
            p = (i + colour) % 2   # where this column's other colour sits: below or above
            for h in range(seg * SEGMENT, ti.min((seg + 1) * SEGMENT, half)):
                k = base + h
                v = cb[colour, k] + (cw[colour, 0, k] * cx[o, k - hs]
                                     + cw[colour, 1, k] * cx[o, k + hs]
                                     + cw[colour, 2, k] * cx[o, k - 1 + p]
                                     + cw[colour, 3, k] * cx[o, k + p])
                cx[colour, k] = v * cw[colour, 4, k]

    nt = 1 << 24
    tx_, ty_ = ti.ndarray(ti.f64, nt), ti.ndarray(ti.f64, nt)
    tx_.fill(1.0)
    ty_.fill(2.0)

    @ti.kernel
    def triad(x: ti.types.ndarray(ndim=1), y: ti.types.ndarray(ndim=1)):
        for k in range(nt):
            y[k] = 0.5 * x[k] + y[k]

    def median_ms(f, *args):
        f(*args)
        ti.sync()
        times = []
        for _ in range(a.repeats):
            t = time.perf_counter()
            for _ in range(10):
                f(*args)
            ti.sync()
            times.append((time.perf_counter() - t) / 10)
        return float(np.median(times)) * 1e3

    red = nx * ny / 2
    # bytes read or written once each: strided touches every cache line of op, x, b
    cases = [("strided", strided, (op, mg, 0), n * 8 * 4 + red * 8),
             ("separate", separate, (*flat, 0), n * 8 * 4 + red * 8),
             ("split", colour_split, (cw, cx, cb, 0), red * 8 * 8),
             ("triad", triad, (tx_, ty_), nt * 8 * 3)]
    for name, f, args, nbytes in cases:
        ms = median_ms(f, *args)
        print(f"{name:8s} {ms:8.2f} ms  {nbytes / ms / 1e6:6.1f} GB/s")
    # A red half-sweep reads only black cells, so repeating it gives the same red
    # values: the three layouts must hold the same answer (split up to the
    # rounding of its stored inverse diagonal).
    red_cells = split(np.ones(n), 0) > 0
    ref = split(mg.to_numpy()[0], 0)[red_cells]
    for name, got in (("separate", split(flat[2].to_numpy(), 0)[red_cells]),
                      ("split", cx.to_numpy()[0][red_cells])):
        diff = np.abs(got - ref).max() / np.abs(ref).max()
        print(f"{name:8s} against strided: largest difference {diff:.1e} of the largest value")
        if diff > 1e-12:
            raise SystemExit(f"{name} does not compute the strided half-sweep")


if __name__ == "__main__":
    main()
