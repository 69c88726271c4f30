"""Disk contacts: each body summing its own forces against each pair scattering with atomics.

The simulator's contact kernels (``taichi_hsdem/contact.py``) give every body a
thread that walks the body's own neighbour list and sums the forces acting on it:
no atomics and a fixed summation order, at the price of evaluating every pair twice
(once from each side). The alternative evaluates each pair once, from a half list
(``i < j``), and adds the force to both bodies with atomic adds. This benchmark
times the two on the same disks, the same neighbour lists and the same force law:

``per_body``
    one thread per body over the full list (both directions, sorted by index, padded
    to a fixed capacity like the simulator's); ``f[i]`` and ``tau[i]`` updated once
    by their owner, with a plain load and store.
``atomic_pairs``
    one thread per listed pair ``i < j``; ``+F`` and the moment on ``i``, ``-F`` and
    the moment on ``j`` added with ``ti.atomic_add`` (two bodies, two components of
    force and one of moment each: six atomics per pair).

The force is the simulator's disk law (``contact.contact_law``: Hookean normal force
with restitution damping, tangential force ``-k_s dt u_t`` capped at ``mu |F_n|``)
without the shear history (``fs_old = 0`` in both variants): the history's per-body
lookup is what a half list would change anyway, and leaving it out times the
reduction itself. Both kernels *add* onto ``f`` and ``tau``, as in a step, where the
forces are loaded (fluid, drag) before the contacts; neither needs a zeroing pass.

Set-up (never timed): ``N`` disks of mean diameter 1 and radii uniform within
+-``POLY`` on a triangular lattice of spacing 1, inflated by ``GROW``, jittered by
+-``JITTER``, then pushed apart for ``RELAX_ITERS`` sweeps wherever two overlap by
more than ``KEEP_OVERLAP`` of a diameter. The result: about 5 contacts per disk,
overlaps of a few per cent of a diameter (each row reports the numbers). Bodies are
numbered row by row (neighbours close in memory, as after a spatial sort;
``--shuffle`` numbers them at random). The neighbour lists come from
``scipy.spatial.cKDTree`` once: every pair closer than ``r_i + r_j + skin``, skin
``SKIN`` times the smallest diameter (the simulator's Verlet skin), so a list also
holds near misses, which cost a distance check in either variant. Velocities and
spins are random so that the damping and the tangential force act (without history
the tangential force is small: the Coulomb cap binds in about 0.3 % of the contacts,
the shallowest; the test raises dt so that it binds in a fifth).

Before timing, the two variants' forces and moments are compared (each from zero):
``max_rel_diff_f`` is the largest difference of a body's force component over the
largest force component, ``max_rel_diff_tau`` the same for the moments. They differ
only by rounding (summation order; a pair's two evaluations in ``per_body`` are
mirror images, equal and opposite up to Taichi's fast-math contractions), a few
units of the last place of the largest pair force, so they must stay below
``1e-12`` (f64) or ``1e-5`` (f32); ``agree`` says whether they do and the exit
status is 1 when they do not.

Timing: per (size, precision), each variant launched ``K`` times between two
``ti.sync()`` calls, ``K`` chosen from a probe so that a repeat lasts at least
``--min-time`` seconds; ``--repeats`` repeats, the two variants alternating (ABBA)
so that a drift in the machine's load falls on both. Reported per (size, precision,
variant), one JSON object per line on stdout:

``ms_per_launch``, ``ms_best``, ``spread``
    median, best and (max - min) / median of the repeats' wall time per launch,
    launch overhead included.
``empty_launch_ms``
    a kernel with the same arguments and an empty body, launched the same way: the
    launch overhead included in ``ms_per_launch`` (about half of it at N = 1000).
``pair_evals_per_launch``, ``pair_evals_per_s``
    pair-force evaluations (a listed entry, touching or not, counted once per force
    computed): twice the half list for ``per_body``, once for ``atomic_pairs``. At
    equal time ``per_body`` therefore shows twice the rate.
``ratio_per_body_over_atomic``
    ``per_body``'s median time over ``atomic_pairs``'s, same process, same lists:
    above 1 means the atomics are faster. ``ratio_range`` is the lowest and highest
    of the per-repeat ratios (each repeat's two variants ran back to back);
    ``ratio_net_of_launch`` the ratio once ``empty_launch_ms`` is taken off both
    (the kernels' own work).
``cpu_per_wall``
    this process's CPU seconds per wall second while timed: near the thread count on
    an idle machine, lower when other jobs take the cores.

Read the ratio, not the absolute times, on a shared machine: both variants suffer
the same competition, and the ratio's range shows how much the load moved it.

Usage::

    python tools/bench_reduction.py [--sizes 1000,10000,100000] [--precision f64,f32]
                                    [--repeats 5] [--min-time 0.5] [--seed 1]
                                    [--shuffle] [--threads N]
"""
import argparse
import contextlib
import io
import json
import math
import os
import statistics
import sys
import time

import numpy as np
from scipy.spatial import cKDTree

from taichi_hsdem.backend import ti  # sets the environment before Taichi loads
from taichi_hsdem.dem.contact import contact_law
from taichi_hsdem.dem.kmath import cross, spin
from taichi_hsdem.laws import restitution_factor

vec2 = ti.math.vec2

SIZES = (1000, 10000, 100000)
POLY = 0.1             # radii uniform within +- this fraction of the mean
GROW = 1.02            # mean diameter over the lattice spacing (all start overlapping)
JITTER = 0.15          # lattice jitter per coordinate, +- this many spacings
RELAX_ITERS = 20       # sweeps pushing deep overlaps apart
KEEP_OVERLAP = 0.02    # overlaps up to this fraction of a diameter are left alone
SKIN = 0.25            # neighbour-list skin over the smallest diameter (simulation.py)
DENSITY = 1.0
KN = 1.0e4
KS = 0.5 * KN          # the scene's "auto" shear stiffness
FRICTION = 0.3
RESTITUTION = 0.9
DT_FRACTION = 0.05     # dt over sqrt(m_min / kn): sets the size of the tangential force
V_SCALE = 0.5          # velocity and spin scales (per component, normal)
TOLERANCE = {"f64": 1e-12, "f32": 1e-5}
# prm layout (real array)
P_KN, P_KS, P_MU, P_CE, P_DT = 0, 1, 2, 3, 4


# ----------------------------------------------------------------------- set-up
def packing(n: int, seed: int = 1, shuffle: bool = False):
    """Positions (n, 2) and radii (n,) of a dense random disk packing (module doc)."""
    rng = np.random.default_rng(seed)
    ny = max(1, int(round(math.sqrt(n * math.sqrt(3.0) / 2.0))))   # about square
    nx = -(-n // ny)
    k = np.arange(n)
    ix, iy = k % nx, k // nx
    x = np.stack([ix + 0.5 * (iy % 2), iy * math.sqrt(3.0) / 2.0], axis=1)
    x += rng.uniform(-JITTER, JITTER, (n, 2))
    r = 0.5 * GROW * rng.uniform(1.0 - POLY, 1.0 + POLY, n)
    for _ in range(RELAX_ITERS):
        p, d, dist = _close_pairs(x, r, 0.0)
        over = r[p[:, 0]] + r[p[:, 1]] - dist - KEEP_OVERLAP * GROW
        push = 0.25 * np.maximum(over, 0.0)[:, None] * d / dist[:, None]
        dx = np.zeros_like(x)
        np.add.at(dx, p[:, 0], push)
        np.add.at(dx, p[:, 1], -push)
        x += dx
    if shuffle:
        perm = rng.permutation(n)
        x, r = x[perm], r[perm]
    return x, r


def _close_pairs(x, r, skin):
    """Pairs ``i < j`` (sorted) closer than ``r_i + r_j + skin``, their ``x_i - x_j``
    and distances."""
    p = cKDTree(x).query_pairs(2.0 * r.max() + skin, output_type="ndarray")
    p = p[np.lexsort((p[:, 1], p[:, 0]))]
    d = x[p[:, 0]] - x[p[:, 1]]
    dist = np.linalg.norm(d, axis=1)
    keep = dist < r[p[:, 0]] + r[p[:, 1]] + skin
    return p[keep], d[keep], dist[keep]


def neighbor_lists(x, r):
    """Half list ``(P, 2)`` with ``i < j``, and the full list: ``nbr (N, cap)``
    (each row sorted by index, padded with -1) and ``nbr_n (N,)``."""
    n = len(x)
    half, _, _ = _close_pairs(x, r, SKIN * 2.0 * r.min())
    both = np.concatenate([half, half[:, ::-1]])
    both = both[np.lexsort((both[:, 1], both[:, 0]))]
    nbr_n = np.bincount(both[:, 0], minlength=n)
    start = np.concatenate([[0], np.cumsum(nbr_n)[:-1]])
    slot = np.arange(len(both)) - start[both[:, 0]]
    nbr = np.full((n, max(1, int(nbr_n.max()))), -1, dtype=np.int32)
    nbr[both[:, 0], slot] = both[:, 1]
    return half.astype(np.int32), nbr, nbr_n.astype(np.int32)


def problem(n: int, seed: int = 1, shuffle: bool = False) -> dict:
    """Everything the kernels take, as float64 numpy arrays, plus the lists."""
    x, r = packing(n, seed, shuffle)
    rng = np.random.default_rng(seed + 1)
    mass = DENSITY * math.pi * r * r
    half, nbr, nbr_n = neighbor_lists(x, r)
    dt = DT_FRACTION * math.sqrt(mass.min() / KN)
    prm = np.zeros(5)
    prm[[P_KN, P_KS, P_MU, P_CE, P_DT]] = KN, KS, FRICTION, restitution_factor(RESTITUTION), dt
    return dict(x=x, v=rng.normal(0.0, V_SCALE, (n, 2)), w=rng.normal(0.0, V_SCALE / r.mean(), n),
                rad=r, mass=mass, prm=prm, half=half, nbr=nbr, nbr_n=nbr_n)


def packing_stats(pb: dict) -> dict:
    """Listed and touching neighbours per body, overlaps over the mean diameter."""
    x, r, half = pb["x"], pb["rad"], pb["half"]
    dist = np.linalg.norm(x[half[:, 0]] - x[half[:, 1]], axis=1)
    over = (r[half[:, 0]] + r[half[:, 1]] - dist) / (2.0 * r.mean())
    touching = over > 0.0
    n = len(x)
    return {"pairs": int(len(half)),
            "listed_per_body": 2.0 * len(half) / n,
            "touching_per_body": 2.0 * int(touching.sum()) / n,
            "median_overlap": float(np.median(over[touching])),
            "max_overlap": float(over.max()),
            "nbr_cap": int(pb["nbr"].shape[1])}


# ----------------------------------------------------------------------- kernels
@ti.func
def pair_force(x: ti.template(), v: ti.template(), w: ti.template(), rad: ti.template(),
               mass: ti.template(), prm: ti.template(), i, j):
    """Force on disk ``i`` from disk ``j``, its shear part, and the arms from each
    centre to the contact point (all zero when apart); the simulator's disk law
    without history. Only the shear part turns a disk (the normal force points
    through both centres), so moments are taken of it alone, as the simulator does."""
    f = vec2(0.0, 0.0)
    fs = vec2(0.0, 0.0)
    ra = vec2(0.0, 0.0)
    rb = vec2(0.0, 0.0)
    d = x[i] - x[j]
    dist = d.norm()
    depth = rad[i] + rad[j] - dist
    if depth > 0.0 and dist > 0.0:
        nrm = d / dist
        kn = prm[P_KN]
        meff = mass[i] * mass[j] / (mass[i] + mass[j])
        gamma = prm[P_CE] * ti.sqrt(kn * meff)
        ra = -(rad[i] - 0.5 * depth) * nrm
        rb = (rad[j] - 0.5 * depth) * nrm
        u = (v[i] + spin(w[i], ra)) - (v[j] + spin(w[j], rb))
        fn, fs = contact_law(depth, nrm, u, vec2(0.0, 0.0), kn, prm[P_KS], prm[P_MU],
                             gamma, prm[P_DT])
        f = fn + fs
    return f, fs, ra, rb


@ti.kernel
def forces_per_body(x: ti.types.ndarray(), v: ti.types.ndarray(), w: ti.types.ndarray(),
                    rad: ti.types.ndarray(), mass: ti.types.ndarray(), prm: ti.types.ndarray(),
                    nbr: ti.types.ndarray(), nbr_n: ti.types.ndarray(),
                    f: ti.types.ndarray(), tau: ti.types.ndarray()):
    """Add to each body the contact forces and moments on it, summed by its owner."""
    for i in range(x.shape[0]):
        ftot = vec2(0.0, 0.0)
        mtot = 0.0
        for q in range(nbr_n[i]):
            fij, fs, ra, _ = pair_force(x, v, w, rad, mass, prm, i, nbr[i, q])
            ftot += fij
            mtot += cross(ra, fs)
        # The thread owns body i: a plain load and store, not an atomic.
        f[i] = f[i] + ftot
        tau[i] = tau[i] + mtot


@ti.kernel
def forces_atomic_pairs(x: ti.types.ndarray(), v: ti.types.ndarray(), w: ti.types.ndarray(),
                        rad: ti.types.ndarray(), mass: ti.types.ndarray(),
                        prm: ti.types.ndarray(), half: ti.types.ndarray(),
                        f: ti.types.ndarray(), tau: ti.types.ndarray()):
    """Add each listed pair's force and moments to both of its bodies, atomically."""
    for p in range(half.shape[0]):
        i = half[p, 0]
        j = half[p, 1]
        fij, fs, ra, rb = pair_force(x, v, w, rad, mass, prm, i, j)
        ti.atomic_add(f[i], fij)
        ti.atomic_add(f[j], -fij)
        ti.atomic_add(tau[i], cross(ra, fs))
        ti.atomic_add(tau[j], cross(rb, -fs))


@ti.kernel
def empty_launch(x: ti.types.ndarray(), v: ti.types.ndarray(), w: ti.types.ndarray(),
                 rad: ti.types.ndarray(), mass: ti.types.ndarray(), prm: ti.types.ndarray(),
                 nbr: ti.types.ndarray(), nbr_n: ti.types.ndarray(),
                 f: ti.types.ndarray(), tau: ti.types.ndarray()):
    """The per-body kernel's arguments and no work: the cost of a launch."""
    pass


class Arrays:
    """Taichi ndarrays of one problem in the current precision."""

    def __init__(self, pb: dict, real):
        npr = np.float64 if real == ti.f64 else np.float32
        n = len(pb["x"])

        def vec(a):
            out = ti.Vector.ndarray(2, real, shape=len(a))
            out.from_numpy(a.astype(npr))
            return out

        def arr(a, dtype):
            out = ti.ndarray(dtype, shape=a.shape)
            out.from_numpy(a)
            return out

        self.x, self.v = vec(pb["x"]), vec(pb["v"])
        self.w = arr(pb["w"].astype(npr), real)
        self.rad = arr(pb["rad"].astype(npr), real)
        self.mass = arr(pb["mass"].astype(npr), real)
        self.prm = arr(pb["prm"].astype(npr), real)
        self.nbr = arr(pb["nbr"], ti.i32)
        self.nbr_n = arr(pb["nbr_n"], ti.i32)
        self.half = arr(pb["half"], ti.i32)
        self.f = ti.Vector.ndarray(2, real, shape=n)
        self.tau = ti.ndarray(real, shape=n)

    def _common(self):
        return self.x, self.v, self.w, self.rad, self.mass, self.prm

    def launch(self, variant: str):
        if variant == "per_body":
            forces_per_body(*self._common(), self.nbr, self.nbr_n, self.f, self.tau)
        elif variant == "atomic_pairs":
            forces_atomic_pairs(*self._common(), self.half, self.f, self.tau)
        else:
            empty_launch(*self._common(), self.nbr, self.nbr_n, self.f, self.tau)

    def forces(self, variant: str):
        """Force (N, 2) and moment (N,) on every body from one launch from zero."""
        self.f.fill(0)
        self.tau.fill(0)
        self.launch(variant)
        return self.f.to_numpy().astype(np.float64), self.tau.to_numpy().astype(np.float64)


VARIANTS = ("per_body", "atomic_pairs")


def compare(arrays: Arrays) -> dict:
    """Largest difference between the variants' forces and moments, relative to the
    largest component of each."""
    fa, ta = arrays.forces("per_body")
    fb, tb = arrays.forces("atomic_pairs")
    return {"max_rel_diff_f": float(np.max(np.abs(fa - fb)) / np.max(np.abs(fa))),
            "max_rel_diff_tau": float(np.max(np.abs(ta - tb)) / np.max(np.abs(ta)))}


# ----------------------------------------------------------------------- timing
def _time(arrays: Arrays, variant: str, k: int, cpu: list | None = None) -> float:
    """Wall seconds per launch over ``k`` launches, synchronised at both ends."""
    ti.sync()
    c0 = time.process_time()
    t0 = time.perf_counter()
    for _ in range(k):
        arrays.launch(variant)
    ti.sync()
    t = time.perf_counter() - t0
    if cpu is not None:
        cpu.append((time.process_time() - c0) / t)
    return t / k


def launches_for(arrays: Arrays, variant: str, min_time: float) -> int:
    """Launches that take at least ``min_time`` seconds, from doubling probes."""
    k = 1
    while True:
        t = _time(arrays, variant, k) * k
        if t >= 0.2 * min_time or k >= 1 << 22:
            return max(1, int(math.ceil(k * min_time / max(t, 1e-9))))
        k *= 2 if t > 0.02 * min_time else 16


def run_point(pb: dict, precision: str, args) -> list[dict]:
    real = ti.f64 if precision == "f64" else ti.f32
    arrays = Arrays(pb, real)
    for variant in VARIANTS + ("empty",):
        arrays.launch(variant)   # compile
    check = compare(arrays)
    tol = TOLERANCE[precision]
    agree = check["max_rel_diff_f"] < tol and check["max_rel_diff_tau"] < tol

    ks = {v: launches_for(arrays, v, args.min_time) for v in VARIANTS + ("empty",)}
    times = {v: [] for v in VARIANTS + ("empty",)}
    cpus = {v: [] for v in VARIANTS}
    for rep in range(args.repeats):
        order = VARIANTS if rep % 2 == 0 else VARIANTS[::-1]   # ABBA
        for v in order:
            times[v].append(_time(arrays, v, ks[v], cpus[v]))
    # the launch overhead is short and steady: three repeats are enough
    for _ in range(3):
        times["empty"].append(_time(arrays, "empty", ks["empty"]))

    med = {v: statistics.median(t) for v, t in times.items()}
    per_rep = [a / b for a, b in zip(times["per_body"], times["atomic_pairs"])]
    stats = packing_stats(pb)
    evals = {"per_body": 2 * stats["pairs"], "atomic_pairs": stats["pairs"]}
    rows = []
    for v in VARIANTS:
        rows.append({
            "n": len(pb["x"]),
            "precision": precision,
            "variant": v,
            "ms_per_launch": 1e3 * med[v],
            "ms_best": 1e3 * min(times[v]),
            "spread": (max(times[v]) - min(times[v])) / med[v],
            "empty_launch_ms": 1e3 * med["empty"],
            "pair_evals_per_launch": evals[v],
            "pair_evals_per_s": evals[v] / med[v],
            "ratio_per_body_over_atomic": med["per_body"] / med["atomic_pairs"],
            "ratio_range": [min(per_rep), max(per_rep)],
            "ratio_net_of_launch": (med["per_body"] - med["empty"])
            / (med["atomic_pairs"] - med["empty"]),
            **check,
            "tolerance": tol,
            "agree": agree,
            "launches_per_repeat": ks[v],
            "median_of": args.repeats,
            "cpu_per_wall": statistics.median(cpus[v]),
            **stats,
            "shuffled": args.shuffle,
            "threads": args.threads,
        })
    return rows


def _load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)),
                        help="comma-separated disk counts (default: %(default)s)")
    parser.add_argument("--precision", default="f64,f32",
                        help="comma-separated subset of f64,f32 (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats (default 5)")
    parser.add_argument("--min-time", type=float, default=0.5,
                        help="seconds each timed repeat lasts at least (default 0.5)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--shuffle", action="store_true",
                        help="number the disks at random instead of row by row")
    parser.add_argument("--threads", type=int, default=os.cpu_count(),
                        help="Taichi CPU threads (default: every core, %(default)s)")
    args = parser.parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        parser.error("--sizes takes comma-separated integers")
    precisions = [p.strip() for p in args.precision.split(",") if p.strip()]
    if any(p not in TOLERANCE for p in precisions) or not precisions:
        parser.error("--precision takes f64 and/or f32")
    if not sizes or min(sizes) < 2 or args.repeats < 1 or args.min_time <= 0 or args.threads < 1:
        parser.error("sizes must be >= 2, --repeats and --threads >= 1, --min-time > 0")

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    log(f"bench_reduction: cpus={os.cpu_count()} threads={args.threads} "
        f"load average at start {_load()}")
    t0 = time.perf_counter()
    problems = {n: problem(n, args.seed, args.shuffle) for n in sizes}
    log(f"  packings built in {time.perf_counter() - t0:.1f} s")
    rows = []
    for precision in precisions:
        # One Taichi default precision per initialisation: re-initialise for each
        # (the kernels recompile; the packings are shared).
        with contextlib.redirect_stdout(io.StringIO()):   # stdout carries the JSON
            ti.init(arch=ti.cpu, default_fp=ti.f64 if precision == "f64" else ti.f32,
                    cpu_max_num_threads=args.threads, log_level=ti.ERROR,
                    offline_cache=True)
        for n in sizes:
            point = run_point(problems[n], precision, args)
            for row in point:
                row["load_avg"] = _load()
                print(json.dumps(row), flush=True)
            rows += point
            a, b = point
            log(f"  {precision} n={n:<7d} per_body {a['ms_per_launch']:9.4f} ms  "
                f"atomic {b['ms_per_launch']:9.4f} ms  ratio {a['ratio_per_body_over_atomic']:.2f} "
                f"({a['ratio_range'][0]:.2f}-{a['ratio_range'][1]:.2f}, net of launch "
                f"{a['ratio_net_of_launch']:.2f})  "
                f"empty {a['empty_launch_ms']:.4f} ms  diff f {a['max_rel_diff_f']:.1e} "
                f"tau {a['max_rel_diff_tau']:.1e}  cpu/wall {a['cpu_per_wall']:.2f}")
        ti.reset()
    log(f"total {time.perf_counter() - t0:.0f} s; load average at end {_load()}")
    return 0 if all(r["agree"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
