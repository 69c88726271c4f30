"""Contact throughput: surface-node evaluations per second and DEM steps per second.

For each particle count N and each contact path

* ``disk-fast``  disks on the analytic fast path (one evaluation per pair);
* ``disk-ls``    the same disks through the level-set path
  (``contact.disk_fast_path = false``, 40 surface nodes each);
* ``square-ls``  squares of the same equivalent diameter (level sets, 40 nodes),

the benchmark builds a closed box without fluid whose free area holds the N
particles at an areal packing fraction of about 0.5, puts them on a jittered
square lattice (random small angles) with small random velocities through
``Simulation.set_state`` (placement is never timed), compiles the kernels with a
few warm-up steps, runs ``--settle-time`` simulated seconds (untimed) so that the
lattice mixes into a gas with collisions under way, chooses K from a short probe
so that K steps take at least ``--min-time`` seconds, and times
``Simulation.advance(K)`` ``--repeats`` times, each repeat starting again from the
settled state (same trajectory, same work; ``set_state`` clears the shear
history, which is rebuilt within a contact's first step).

Reported per case (medians over the repeats):

``steps_per_s``, ``s_per_step``
    wall time of ``Simulation.advance`` (one step = loading the forces, contacts,
    integration, the host's read of the rebuild flag, and the neighbour rebuilds
    that the motion triggers), ``ti.sync()`` included.
``node_evals_per_s``
    node-vs-level-set evaluations per step / time per step. Counted from the
    neighbour lists actually in use at every step (read from
    ``sim.neighbors.nbr_n`` after every rebuild): on the level-set path each listed
    entry (i, j) evaluates the nodes of i in j *and* the nodes of j in i (the
    kernel evaluates every pair from both sides, so a pair costs 2 (n_i + n_j)),
    plus n_i wall checks per particle; on the disk path one evaluation per listed
    entry plus one wall check per disk. A listed pair is evaluated whether or not
    it touches.
``cpu_per_wall``
    CPU time of this process per wall second while timed: close to the number of
    busy threads on an idle machine, lower when other jobs take the cores (the
    load averages at the end of each case are in ``load_avg``).
``contacts_per_particle``
    listed neighbour entries per particle, averaged over the timed steps: the
    candidate contacts the kernel evaluates. ``touching_per_particle`` is the
    number of pairs actually overlapping at the end of a repeat (x2 / N).

One JSON object per case on stdout (``{"case", "n", "arch", "precision", "error"}``
for a case that failed, exit status 1), a table on stderr.

``--arch gpu`` takes whatever Taichi offers: on a machine without a GPU that can
be a software Vulkan (Mesa lavapipe, reported as ``"arch": "vulkan"``), far
slower than the CPU backend and unable to compile f64 ``cos`` (every level-set
case fails in f64); those are not GPU numbers.

``--profile`` adds, for each case, the time per step of each kernel that
``Simulation.advance`` launches, each call followed by ``ti.sync()`` (the kernels are
wrapped, ``step`` itself runs unchanged; serialised, the parts add up to a little
more than a step), and ``other``: the host's rebuild-flag read and Python loop.

Usage::

    python tools/bench_contacts.py [--arch cpu|gpu|auto] [--sizes 100,1000,10000]
                                   [--cases disk-fast,disk-ls,square-ls]
                                   [--quick] [--repeats 5] [--min-time 2.0]
                                   [--precision f64|f32] [--packing 0.5]
                                   [--settle-time 0.5] [--seed 1] [--profile]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time

import numpy as np

from taichi_hsdem import backend

CASES = ("disk-fast", "disk-ls", "square-ls")
SIZES = (100, 1000, 10000)
QUICK_SIZES = (100, 1000)
PACKING = 0.5          # default areal packing fraction of the free part of the box
MAX_PACKING = 0.7      # denser lattices leave no room for the jitter and the angles
D_EQ = 1.0             # equivalent diameter of every particle
NODES = 40             # surface nodes per particle (level-set paths)
KN = 1.0e4
DENSITY = 1.0
FRICTION = 0.3
RESTITUTION = 0.9
DT_SAFETY = 0.1
V0 = 0.5               # velocity scale, d_eq per second (per component, normal)
JITTER = 0.3           # lattice jitter per coordinate, +- this fraction of the gap
MAX_ANGLE = 0.15       # squares start within +- this angle (rad) of axis-aligned
WARMUP_STEPS = 5
PROBE_TIME = 0.3       # seconds of probing to choose K
SETTLE_TIME = 0.5      # simulated seconds from the lattice before timing (~1 collision each)
BLOCK = 1.0            # width of the two blocks sealing the box ends (from 1 to 2)


# ----------------------------------------------------------------------- set-up
def _lattice(n: int) -> tuple[int, int]:
    """Columns and rows of a lattice holding n sites, about twice as wide as high."""
    target = math.sqrt(n / 2.0)
    best = None
    for ny in range(max(1, int(target / 2)), int(2 * target) + 2):
        if n % ny == 0:
            if best is None or abs(ny - target) < abs(best - target):
                best = ny
    if best is None:                       # n has no divisor near the target
        best = max(1, round(target))
        return int(math.ceil(n / best)), best
    return n // best, best


def _species(case: str, n: int) -> dict:
    common = dict(count=n, density=DENSITY, kn=KN, friction=FRICTION,
                  restitution=RESTITUTION, nodes=NODES)
    if case.startswith("disk"):
        return dict(shape="circle", diameter=D_EQ, **common)
    return dict(shape="square", side=D_EQ * math.sqrt(math.pi) / 2.0, **common)


def _extent(case: str) -> float:
    """Largest width of a particle along x or y at any starting angle."""
    if case.startswith("disk"):
        return D_EQ
    side = D_EQ * math.sqrt(math.pi) / 2.0
    return side * (math.cos(MAX_ANGLE) + math.sin(MAX_ANGLE))


def make_scene(case: str, n: int, arch: str, precision: str, packing: float = PACKING):
    """Scene dict of the box, the lattice spacing and the free-area origin."""
    area = math.pi * D_EQ ** 2 / 4.0
    a = math.sqrt(area / packing)          # lattice spacing for the target fraction
    nx, ny = _lattice(n)
    width, height = nx * a, ny * a         # free part of the box
    x0 = 1.0 + BLOCK                       # free part starts right of the inlet block
    length = width + 2.0 * x0
    scene = {
        "name": f"bench-{case}-{n}",
        "units": "dimensionless",
        # per_step: bodies in parallel, and every neighbour list built on the host,
        # where EvalCounter sees it (the fused stepper rebuilds inside its kernel)
        "run": {"t_end": 1.0, "dt": "auto", "dt_safety": DT_SAFETY, "realizations": 1,
                "arch": arch, "precision": precision, "stepping": "per_step"},
        "fluid": {"enabled": False, "gap": 1.0},
        "geometry": {
            "kind": "polygon",
            "outline": [[0.0, 0.0], [length, 0.0], [length, height], [0.0, height]],
            "obstacles": [
                [[1.0, 0.02], [x0, 0.02], [x0, height - 0.02], [1.0, height - 0.02]],
                [[length - x0, 0.02], [length - 1.0, 0.02], [length - 1.0, height - 0.02],
                 [length - x0, height - 0.02]],
            ],
            "constriction_x": length - 0.5,
            "escape_offset": 0.25,
        },
        "particles": [_species(case, n)],
        "contact": {"normalize_by_nodes": True, "disk_fast_path": case == "disk-fast"},
        "damping": {"xi": 0.0},
        "feed": {"mode": "none", "region": [x0 + 0.5, length - x0 - 0.5]},
    }
    return scene, a, (nx, ny), (x0, 0.0), width * height


def initial_state(n: int, a: float, lattice, origin, seed: int, case: str):
    """Jittered lattice positions, small angles (squares) and random velocities."""
    rng = np.random.default_rng(seed)
    nx, ny = lattice
    sites = np.array([(ix, iy) for ix in range(nx) for iy in range(ny)], dtype=float)
    if len(sites) > n:                     # more sites than particles: leave random holes
        sites = sites[np.sort(rng.choice(len(sites), n, replace=False))]
    x = np.empty((n, 2))
    x[:, 0] = origin[0] + (sites[:, 0] + 0.5) * a
    x[:, 1] = origin[1] + (sites[:, 1] + 0.5) * a
    # two neighbours jittered towards each other keep 1 - 2 JITTER of the gap
    gap = a - _extent(case)
    x += rng.uniform(-JITTER, JITTER, size=x.shape) * gap
    square = case.startswith("square")
    theta = rng.uniform(-MAX_ANGLE, MAX_ANGLE, size=n) if square else np.zeros(n)
    v = rng.normal(0.0, V0 * D_EQ, size=(n, 2))
    omega = rng.normal(0.0, V0, size=n)
    return x[None], theta[None], v[None], omega[None]


# ----------------------------------------------------------------------- counting
class EvalCounter:
    """Node evaluations of the steps taken, from the neighbour lists in use.

    Wraps ``sim.rebuild_neighbors`` (on this instance only) so that every list the
    contact kernel will use is counted for exactly the steps it is used in.
    """

    def __init__(self, sim):
        self.sim = sim
        self.level_set = not sim.model.all_disks
        counts = np.asarray(sim.templates.node_count)[np.asarray(sim.particles.species_np)]
        self.nodes = counts.astype(np.int64)          # nodes of each particle
        self.uniform = bool(np.all(self.nodes == self.nodes[0]))
        self._orig = sim.rebuild_neighbors
        sim.rebuild_neighbors = self._rebuild
        self.reset()

    def _list_stats(self):
        sim = self.sim
        nbr_n = sim.neighbors.nbr_n.to_numpy().astype(np.int64)        # (R, N)
        alive = sim.bodies.alive.to_numpy().astype(bool)
        running = sim.batch.running.to_numpy().astype(bool)
        act = alive & running[:, None]
        nbr_n = np.where(act, nbr_n, 0)
        entries = int(nbr_n.sum())
        walls = self.nodes[None, :] * act if self.level_set else act.astype(np.int64)
        if not self.level_set:
            evals = entries + int(walls.sum())
        elif self.uniform:
            evals = entries * 2 * int(self.nodes[0]) + int(walls.sum())
        else:
            nbr = sim.neighbors.nbr.to_numpy()
            cap = nbr.shape[2]
            used = np.arange(cap)[None, None, :] < nbr_n[:, :, None]
            nj = np.where(used, self.nodes[np.clip(nbr, 0, len(self.nodes) - 1)], 0)
            evals = int((nbr_n * self.nodes[None, :]).sum() + nj.sum() + walls.sum())
        return entries, evals

    def _rebuild(self):
        self._orig()
        self._close()
        self.rebuilds += 1
        self.cur = self._list_stats()

    def _close(self):
        steps = self.sim.steps - self.last
        self.entry_steps += self.cur[0] * steps
        self.evals += self.cur[1] * steps
        self.last = self.sim.steps

    def reset(self):
        """Start counting from the current state (call after set_state)."""
        self.cur = self._list_stats()
        self.last = self.sim.steps
        self.start = self.sim.steps
        self.evals = 0
        self.entry_steps = 0
        self.rebuilds = 0

    def finish(self):
        self._close()
        return self.sim.steps - self.start, self.evals, self.entry_steps, self.rebuilds


def touching_pairs(sim) -> int:
    """Pairs overlapping in the current state (disks exactly, squares by their nodes)."""
    st = sim.state()
    x, th = st["x"][0], st["theta"][0]
    nbr_n = sim.neighbors.nbr_n.to_numpy()[0]
    nbr = sim.neighbors.nbr.to_numpy()[0]
    shape = sim.model.species[0].shape
    count = 0
    if shape.kind == "circle":
        r = shape.radius
        for i in range(len(x)):
            js = nbr[i, :nbr_n[i]]
            js = js[js > i]
            count += int(np.sum(np.linalg.norm(x[js] - x[i], axis=1) < 2 * r))
        return count
    nodes = np.asarray(shape.nodes)
    half = float(np.max(np.abs(shape.vertices)))   # square half-side (vertices at +-half)
    for i in range(len(x)):
        js = nbr[i, :nbr_n[i]]
        js = js[js > i]
        ci, si = math.cos(th[i]), math.sin(th[i])
        pi = x[i] + nodes @ np.array([[ci, si], [-si, ci]])
        for j in js:
            cj, sj = math.cos(th[j]), math.sin(th[j])
            pj = x[j] + nodes @ np.array([[cj, sj], [-sj, cj]])
            # nodes of i in j's frame and of j in i's frame
            qi = (pi - x[j]) @ np.array([[cj, -sj], [sj, cj]])
            qj = (pj - x[i]) @ np.array([[ci, -si], [si, ci]])
            if (np.all(np.abs(qi) < half, axis=1).any()
                    or np.all(np.abs(qj) < half, axis=1).any()):
                count += 1
    return count


# ----------------------------------------------------------------------- timing
def _sync():
    import taichi as ti
    ti.sync()


def timed_steps(sim, k: int, cpu: list | None = None) -> float:
    """Wall time of ``sim.advance(k)``; appends this process's CPU time to ``cpu``."""
    _sync()
    c0 = time.process_time()
    t0 = time.perf_counter()
    sim.advance(k)
    _sync()
    t = time.perf_counter() - t0
    if cpu is not None:
        cpu.append(time.process_time() - c0)
    return t


def run_case(case: str, n: int, args, log) -> dict:
    from taichi_hsdem import Simulation, load_scene

    t_build = time.perf_counter()
    scene_dict, a, lattice, origin, free_area = make_scene(case, n, args.arch,
                                                           args.precision, args.packing)
    sim = Simulation(load_scene(scene_dict), place_particles=False)
    init = initial_state(n, a, lattice, origin, seed=args.seed, case=case)
    x0, th0, v0, w0 = init

    def reset():
        sim.set_state(x0, th0, v=v0, omega=w0)
        sim.batch.bad.fill(0)
        sim.batch.max_overlap.fill(0)

    counter = EvalCounter(sim)
    reset()
    t_build = time.perf_counter() - t_build

    # warm-up: compiles every kernel of the step (cached for later cases)
    t_warm = timed_steps(sim, WARMUP_STEPS)
    # settle (untimed): let the lattice mix into a gas with collisions under way, and
    # start every timed repeat from that state rather than from the contact-free lattice
    settle_steps = int(round(args.settle_time / sim.dt))
    t_settle = time.perf_counter()
    if settle_steps > 0:
        sim.advance(settle_steps)
        st = sim.state()
        x0, th0, v0, w0 = st["x"], st["theta"], st["v"], st["omega"]
    t_settle = time.perf_counter() - t_settle
    # probe: double the step count until it takes PROBE_TIME
    k = 1
    while True:
        reset()
        t = timed_steps(sim, k)
        if t >= PROBE_TIME or k >= 1 << 20:
            break
        k = max(2 * k, int(k * min(8.0, 1.2 * PROBE_TIME / max(t, 1e-6))))
    per_step = t / k
    k_steps = max(10, int(math.ceil(args.min_time / per_step)))

    times, cpus, evals, entries, rebuilds = [], [], [], [], []
    touching = None
    for rep in range(args.repeats):
        reset()
        counter.reset()
        times.append(timed_steps(sim, k_steps, cpus))
        steps, ev, en, rb = counter.finish()
        assert steps == k_steps
        evals.append(ev)
        entries.append(en)
        rebuilds.append(rb)
        if rep == 0:
            touching = touching_pairs(sim)
            bad = int(sim.batch.bad.to_numpy()[0])
            overlap = float(sim.batch.max_overlap.to_numpy()[0])
    sim.rebuild_neighbors = counter._orig

    t_med = statistics.median(times)
    ev_step = statistics.median(evals) / k_steps
    sp = sim.model.species[0]
    out = {
        "case": case,
        "n": n,
        "arch": sim.arch,
        "precision": args.precision,
        "steps_per_s": k_steps / t_med,
        "steps_per_s_best": k_steps / min(times),
        "s_per_step": t_med / k_steps,
        "node_evals_per_s": ev_step / (t_med / k_steps),
        "node_evals_per_step": ev_step,
        "contacts_per_particle": statistics.median(entries) / k_steps / n,
        "touching_per_particle": 2.0 * touching / n,
        "nodes_per_particle": 1 if sim.model.all_disks else int(sim.templates.node_count[0]),
        "rebuilds_per_1000_steps": 1000.0 * statistics.median(rebuilds) / k_steps,
        "k_steps": k_steps,
        "median_of": args.repeats,
        "spread": (max(times) - min(times)) / t_med,
        # CPU seconds this process used per wall second while timed (at most the
        # number of cores; well below the threads' count when other jobs compete)
        "cpu_per_wall": statistics.median(c / t for c, t in zip(cpus, times)),
        "packing_fraction": n * sp.shape.area / free_area,
        "dt": sim.dt,
        "max_overlap": overlap,
        "stable": bad == 0,
        "build_s": t_build,
        "warmup_s": t_warm,
        "settle_steps": settle_steps,
        "settle_s": t_settle,
    }
    log(f"  {case:9s} n={n:<6d} K={k_steps:<7d} {out['steps_per_s']:10.1f} steps/s "
        f"{1e3 * out['s_per_step']:9.3f} ms/step {out['node_evals_per_s'] / 1e6:9.2f} M evals/s "
        f"(spread {100 * out['spread']:.0f} %, cpu/wall {out['cpu_per_wall']:.2f})")
    if args.profile:
        out["profile_s_per_step"] = profile_step(sim, reset, max(20, min(k_steps, 400)))
    return out


def profile_step(sim, reset, steps: int) -> dict:
    """Time each kernel that ``Simulation.advance`` launches, serialised.

    Every Taichi kernel of the contact, coupling and integration modules and the
    neighbour rebuild are wrapped for the duration (module attributes, which
    ``step`` looks up at every call) so that each call is followed by
    ``ti.sync()`` and timed; ``sim.advance(steps)`` then runs as usual. ``other`` is
    what remains of the step: the host's read of the rebuild flag and the Python
    loop (plus the wrappers' own small cost).
    """
    import taichi as ti
    from taichi_hsdem.dem import contact, coupling, integrate

    acc: dict = {}
    clock = time.perf_counter

    def timed(name, fn):
        def wrapper(*a, **k):
            t0 = clock()
            out = fn(*a, **k)
            ti.sync()
            acc[name] = acc.get(name, 0.0) + clock() - t0
            return out
        return wrapper

    patched = []
    for mod in (contact, coupling, integrate):
        for name, obj in list(vars(mod).items()):
            if getattr(obj, "_is_wrapped_kernel", False):
                patched.append((mod, name, obj))
                setattr(mod, name, timed(name, obj))
    reset()
    rebuilds0 = sim.neighbors.builds
    rebuild = sim.rebuild_neighbors
    sim.rebuild_neighbors = timed("rebuild", rebuild)
    try:
        ti.sync()
        t0 = clock()
        sim.advance(steps)
        ti.sync()
        total = clock() - t0
    finally:
        sim.rebuild_neighbors = rebuild
        for mod, name, obj in patched:
            setattr(mod, name, obj)
    prof = {key: val / steps for key, val in acc.items()}
    prof["other"] = (total - sum(acc.values())) / steps
    prof["serialised_total"] = total / steps
    prof["rebuilds_per_1000_steps"] = 1000.0 * (sim.neighbors.builds - rebuilds0) / steps
    prof["steps"] = steps
    return prof


# ----------------------------------------------------------------------- main
def _load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--arch", choices=("cpu", "gpu", "auto"), default="cpu",
                        help="Taichi backend (default: %(default)s; gpu fails without one)")
    parser.add_argument("--precision", choices=("f64", "f32"), default="f64")
    parser.add_argument("--sizes", default=None,
                        help="comma-separated particle counts (default: 100,1000,10000)")
    parser.add_argument("--cases", default=",".join(CASES),
                        help="comma-separated subset of %(default)s")
    parser.add_argument("--quick", action="store_true",
                        help="sizes 100,1000, 3 repeats of >= 0.5 s")
    parser.add_argument("--repeats", type=int, default=None, help="timed repeats (default 5)")
    parser.add_argument("--min-time", type=float, default=None,
                        help="seconds each timed repeat lasts at least (default 2.0)")
    parser.add_argument("--packing", type=float, default=PACKING,
                        help=f"areal packing fraction, at most {MAX_PACKING} (default: %(default)s)")
    parser.add_argument("--settle-time", type=float, default=SETTLE_TIME,
                        help="simulated seconds run (untimed) from the lattice before the "
                             "timed repeats start (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--profile", action="store_true",
                        help="also time each kernel of a step separately")
    args = parser.parse_args(argv)
    if args.sizes:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    else:
        sizes = list(QUICK_SIZES if args.quick else SIZES)
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {unknown}; choose from {CASES}")
    if args.repeats is None:
        args.repeats = 3 if args.quick else 5
    if args.min_time is None:
        args.min_time = 0.5 if args.quick else 2.0
    if not 0.0 < args.packing <= MAX_PACKING:
        parser.error(f"--packing must lie in (0, {MAX_PACKING}]")
    if args.repeats < 1 or args.min_time <= 0 or args.settle_time < 0:
        parser.error("--repeats must be >= 1, --min-time > 0 and --settle-time >= 0")

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    try:
        arch = backend.init(args.arch, args.precision)
    except backend.BackendError as exc:
        log(f"bench_contacts: {exc}")
        return 2
    log(f"bench_contacts: arch={arch} precision={args.precision} cpus={os.cpu_count()} "
        f"load average at start {_load()}")
    t0 = time.perf_counter()
    rows = []
    failed = 0
    for n in sizes:
        for case in cases:
            try:
                row = run_case(case, n, args, log)
            except Exception as exc:   # e.g. a backend that cannot compile a kernel
                failed += 1
                msg = f"{type(exc).__name__}: {exc}".strip()
                log(f"  {case:9s} n={n:<6d} FAILED: {msg}")
                print(json.dumps({"case": case, "n": n, "arch": arch,
                                  "precision": args.precision, "error": msg}), flush=True)
                continue
            row["load_avg"] = _load()
            rows.append(row)
            print(json.dumps(row), flush=True)
    log(f"\n{'case':10s} {'n':>6s} {'steps/s':>10s} {'ms/step':>9s} {'Mevals/s':>9s} "
        f"{'evals/step':>11s} {'nbrs/p':>6s} {'touch/p':>7s} {'rb/1k':>6s} {'phi':>5s} {'cpu/wall':>8s}")
    for r in rows:
        log(f"{r['case']:10s} {r['n']:6d} {r['steps_per_s']:10.1f} {1e3 * r['s_per_step']:9.3f} "
            f"{r['node_evals_per_s'] / 1e6:9.2f} {r['node_evals_per_step']:11.0f} "
            f"{r['contacts_per_particle']:6.2f} {r['touching_per_particle']:7.2f} "
            f"{r['rebuilds_per_1000_steps']:6.1f} {r['packing_fraction']:5.2f} "
            f"{r['cpu_per_wall']:8.2f}")
        if "profile_s_per_step" in r:
            p = r["profile_s_per_step"]
            skip = ("serialised_total", "rebuilds_per_1000_steps", "steps")
            parts = ", ".join(f"{k} {1e6 * v:.0f} us" for k, v in p.items() if k not in skip)
            log(f"{'':10s} profile per step: {parts}; serialised total "
                f"{1e6 * p['serialised_total']:.0f} us")
    log(f"total {time.perf_counter() - t0:.0f} s; load average at end {_load()}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
