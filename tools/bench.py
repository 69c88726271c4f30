"""Benchmark the shipped cases: one JSON line per case on stdout.

    python tools/bench.py                 # CPU, every case (minutes)
    python tools/bench.py --quick         # R = 1, 10 only, shorter runs
    python tools/bench.py --arch gpu      # on a GPU machine
    python tools/bench.py --cases disks-0.26-R10,paper-disks-0.26-R1
    python tools/bench.py --cases disks-0.26-R10@fluid.workers=1,disks-0.26-R10
    python tools/bench.py --cases disks-0.26-R1 --sim-time 1 --video-frames 600
    python tools/bench.py --cases disks-0.26-R16 --lanes off   # one realization per thread

Cases: disks and squares at packing fractions 0.17 and 0.26 in the vani channel
(scenes/vani_phi026.toml; squares from scenes/squares.toml with the same count),
realizations 1, 10, 100; a paper-like case (the paper's time step 3.75e-7 s and
a pressure solve every 1e4 steps) to compare with the auto settings in one run;
and ``channel-N``, N disks of 100 um in a 12 mm wide converging channel whose
straight section grows with N (``channel-10000``: 20 mm, 1590 x 720 fluid cells),
one realization (``channel_overrides``; not in the default list: run them with
``--cases channel-1000,channel-3000,channel-10000 --sim-time 0.005``); and
``micromodel-N``, N disks in scenes/micromodel.toml with the 34 x 6 pillar array
of docs/performance.md behind an inlet that grows with N (``micromodel-10000``:
20 mm, the 1350 x 723 grid of that page's command), one realization
(``micromodel_overrides``).
A case name may end in ``@key=value`` overrides (as ``--set``), one ``@`` each, to
time one knob against the default in the same run.

Each case runs in its own process (so peak memory is the case's own), first a few
steps to compile, then ``--sim-time`` seconds of simulated time timed as a whole.
Reported per case: DEM steps per second, surface-node (or disk-pair) contact
evaluations per second over whole steps, simulated realization-seconds per wall
second, realization pressure solves per second, the solve's share of wall time
and time per solve, wall time per step with and without the solves and of the
DEM launches alone (``advance_ms_per_step``), the solver used and whether the
particles carried their volume (``fluid.particle_flux``), peak resident memory
of the simulation process and of the pressure-solver worker processes
(``fluid.workers``, pyamg only).
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER_DT = 3.75e-7
PAPER_FLUID_EVERY = 10000
SERIES_INTERVAL = 0.025   # s: the vani scene's own, t_end / 200


def cases(quick):
    reals = (1, 10) if quick else (1, 10, 100)
    out = []
    for shape in ("disks", "squares"):
        for phi in (0.17, 0.26):
            for r in reals:
                out.append(f"{shape}-{phi}-R{r}")
    out += ["paper-disks-0.26-R1", "paper-squares-0.26-R1"]
    return out


# The channel of issue #22: 12 mm wide, a 20 mm straight section holding 10,000
# disks of 100 um (packing fraction 0.327), 45-degree convergence to 1.7 d, a short
# outlet; 1590 x 720 fluid cells at d/6. ``channel-N`` scales the straight section
# with N at the same packing fraction, so the fluid grid grows with N as well.
CHANNEL_WIDTH = 12e-3
CHANNEL_LENGTH_10K = 20e-3
CHANNEL_D = 100e-6


def channel_overrides(n):
    length = CHANNEL_LENGTH_10K * n / 10_000
    phi = n * 3.141592653589793 * CHANNEL_D ** 2 / 4 / (CHANNEL_WIDTH * length)
    # the vani scene's upstream speed (flow rate scaled with the width) and H/d 1.15
    return [f"geometry.width_in={CHANNEL_WIDTH}", f"geometry.length_in={length}",
            f"geometry.constriction_width={1.7 * CHANNEL_D}",
            f"geometry.width_out={CHANNEL_WIDTH}", "geometry.length_out=0.6e-3",
            f"particles.diameter={CHANNEL_D}", f"particles.packing_fraction={phi!r}",
            "fluid.gap=115e-6", f"fluid.flow_rate={1e-10 * CHANNEL_WIDTH / 1.4e-3 * 115 / 160}"]


# The 10,000-disk micromodel of docs/performance.md: 34 x 6 pillars (12.05 mm
# wide) behind a 20 mm inlet at 10,000 disks, the shipped mean flow speed.
# ``micromodel-N`` scales the inlet with N (the array stays), so a smaller N
# keeps the pillars' share of the solve and the throats' checks.
def micromodel_overrides(n):
    return ["geometry.rows=34", "geometry.columns=6",
            f"geometry.inlet_length={20e-3 * n / 10_000!r}", f"particles.count={n}",
            "fluid.flow_rate=2.008e-9"]


def overrides(case, sim_time):
    case, *extra = case.split("@")
    parts = case.split("-")
    if parts[0] == "micromodel":
        ov = [f"run.t_end={sim_time}", "run.stop_at_clog=false",
              f"output.series_interval={SERIES_INTERVAL}"]
        return ROOT / "scenes" / "micromodel.toml", ov + micromodel_overrides(int(parts[1])) + extra
    if parts[0] == "channel":
        ov = [f"run.t_end={sim_time}", "run.stop_at_clog=false",
              f"output.series_interval={SERIES_INTERVAL}"]
        return ROOT / "scenes" / "vani_phi026.toml", ov + channel_overrides(int(parts[1])) + extra
    paper = parts[0] == "paper"
    if paper:
        parts = parts[1:]
    shape, phi, reals = parts[0], float(parts[1]), int(parts[2][1:])
    scene = ROOT / "scenes" / ("vani_phi026.toml" if shape == "disks" else "squares.toml")
    # The time series is sampled as in the full 5 s scene (t_end / 200), not every few
    # steps as a short --sim-time would make it.
    ov = [f"run.realizations={reals}", f"run.t_end={sim_time}", "run.stop_at_clog=false",
          f"output.series_interval={SERIES_INTERVAL}"]
    if shape == "disks":
        ov.append(f"particles.packing_fraction={phi}")
    else:
        # squares of bounding diameter d_b: the count that gives phi in the control volume
        side = 98.99e-6
        area = 1.4e-3 * 2.8e-3
        ov.append(f"particles.count={int(round(phi * area / side ** 2))}")
    if paper:
        ov += [f"run.dt={PAPER_DT}", f"fluid.update_interval={PAPER_FLUID_EVERY}"]
    return scene, ov + extra


def time_calls(obj, name, seconds, key, calls=None):
    """Wrap method ``name`` of ``obj`` so that each call adds its wall time to
    ``seconds[key]`` (and 1 to ``calls[key]``)."""
    f = getattr(obj, name)

    def timed(*args, **kwargs):
        t = time.perf_counter()
        try:
            return f(*args, **kwargs)
        finally:
            seconds[key] += time.perf_counter() - t
            if calls is not None:
                calls[key] += 1
    setattr(obj, name, timed)


def _rss_mb(pid, field="VmHWM"):
    """Peak (VmHWM) or current (VmRSS) resident memory of a process, MB; None if
    unknown."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        return None
    return None


def _total_rss_mb():
    """Current resident memory of this process and its solver workers, MB."""
    from taichi_hsdem.fluid import pool as solver_pool
    pids = [os.getpid()] + [w.proc.pid for w in solver_pool.pool().workers]
    return sum(_rss_mb(pid, "VmRSS") or 0.0 for pid in pids)


def run_case(case, arch, precision, sim_time, video_frames=0):
    import tempfile
    import numpy as np
    from taichi_hsdem import Simulation, backend, load_scene
    backend.init(arch, precision)
    scene_path, ov = overrides(case, sim_time)
    ov += [f'run.arch="{arch}"', f'run.precision="{precision}"']
    if video_frames:
        ov.append(f"output.frames={video_frames}")
    sim = Simulation(load_scene(scene_path, ov))
    if sim.fluid is not None:
        sim.update_fluid(force=True)  # run()'s first solve (it sets the update interval)
    sim.advance(5)                      # compile every kernel before timing
    solves0, fluid_s0 = (sim.fluid.solves, sim.fluid.seconds) if sim.fluid else (0, 0.0)
    steps0 = sim.steps
    samples = []                     # (simulated time, resident MB): flat over the run?

    def progress(t, t_end):
        if not samples or t >= samples[-1][0] + t_end / 8:
            samples.append((t, _total_rss_mb()))

    spent = defaultdict(float)       # the DEM launches alone (Simulation.advance)
    time_calls(sim, "advance", spent, "advance")
    rec = tmp = None
    if video_frames:                 # draw and encode frames too (into a scratch folder)
        from taichi_hsdem.render import VideoRecorder
        tmp = tempfile.TemporaryDirectory(prefix="hsdem-bench-")
        rec = VideoRecorder(sim, Path(tmp.name) / "video.mp4")
    t0 = time.perf_counter()
    sim.run(progress=progress, on_frame=rec,
            frame_times=rec.frame_times if rec is not None else None)
    wall = time.perf_counter() - t0
    video = None
    if rec is not None:
        rec.close(keep=False)
        tmp.cleanup()
        video = {"frames": rec.frames, "error": rec.error,
                 "render_share": round(rec.seconds / wall, 3)}
    steps = sim.steps - steps0
    # contact evaluations per step, from the final neighbour lists
    nbr = sim.neighbors.nbr_n.to_numpy().astype(np.int64)
    alive = sim.bodies.alive.to_numpy().astype(bool)
    nodes = np.array([s.shape.nodes.shape[0] for s in sim.model.species])[sim.particles.species_np]
    if sim.model.all_disks:
        evals = int(nbr[alive].sum() + alive.sum())
    else:
        nb = sim.neighbors.nbr.to_numpy()
        evals = 0
        for r in range(sim.R):
            for i in np.flatnonzero(alive[r]):
                js = nb[r, i, :nbr[r, i]]
                evals += int(nbr[r, i] * nodes[i] + nodes[js].sum() + nodes[i])
    solves1, fluid_s1 = (sim.fluid.solves, sim.fluid.seconds) if sim.fluid else (0, 0.0)
    solves = (solves1 - solves0) * sim.R
    workers = getattr(sim.fluid.solver, "workers", 0) if sim.fluid is not None else 0
    worker_rss = []
    if workers > 1:
        from taichi_hsdem.fluid import pool as solver_pool
        worker_rss = [_rss_mb(w.proc.pid) for w in solver_pool.pool().workers]
    half = len(samples) // 2
    return {
        "case": case, "arch": sim.arch, "precision": precision,
        "realizations": sim.R, "particles": sim.N, "dt": sim.dt,
        "fluid_update_interval": sim.scene.fluid.update_interval,
        "steps": steps, "wall_s": round(wall, 3),
        "steps_per_s": round(steps / wall, 1),
        "contact_evals_per_s": round(evals * steps / wall, 0),
        "realization_sim_s_per_wall_s": round(sim.R * (sim.t - 0.0) / wall, 6),
        "pressure_solves_per_s": round(solves / wall, 2),
        "pressure_share": round((fluid_s1 - fluid_s0) / wall, 3),
        "ms_per_solve": round(1000 * (fluid_s1 - fluid_s0) / solves, 2) if solves else None,
        "ms_per_step": round(1000 * wall / steps, 4) if steps else None,
        # the step without the pressure solves: the DEM and everything else
        "dem_ms_per_step": round(1000 * (wall - (fluid_s1 - fluid_s0)) / steps, 4)
        if steps else None,
        # the DEM launches alone (contacts, motion, neighbour rebuilds): the rest of
        # dem_ms_per_step is the fluid updates' other work (rasterising, held
        # forces, reading the pressure) and the host checks
        "advance_ms_per_step": round(1000 * spent["advance"] / steps, 4) if steps else None,
        "fluid_solver": sim.model.fluid_solver if sim.fluid is not None else None,
        # carried volume (implicit coupling) or fixed obstacles: the solve differs
        "particle_flux": sim.scene.fluid.particle_flux if sim.fluid is not None else None,
        "fluid_workers": workers,
        # whether the solve ran its realizations side by side (fluid/_gmg_lanes.py)
        "lanes": getattr(getattr(sim.fluid, "solver", None), "_lanes", None) is not None,
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "worker_peak_rss_mb": worker_rss,
        # resident memory (process + workers) over the run's first and second half
        "rss_mb_first_half_max": max((m for _, m in samples[:half]), default=None),
        "rss_mb_second_half_max": max((m for _, m in samples[half:]), default=None),
        # (simulated s, MB) every t_end / 8: the solver workers join once the solves
        # have taken 2 s (fluid.POOL_AFTER_SECONDS); after that the total should be flat
        "rss_mb_samples": [[round(t, 4), m] for t, m in samples],
        "video": video,
    }


def _allow_fast_math():
    """Make backend.init's ti.init compile with fast_math on (benchmark only)."""
    import taichi as ti
    init = ti.init

    def with_fast_math(*args, **kwargs):
        kwargs["fast_math"] = True
        return init(*args, **kwargs)
    ti.init = with_fast_math


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--precision", default="f64", choices=("f64", "f32"))
    p.add_argument("--quick", action="store_true")
    p.add_argument("--cases", help="comma-separated case names (default: all)")
    p.add_argument("--sim-time", type=float, default=None,
                   help="simulated seconds per case (default 0.05, --quick 0.02)")
    p.add_argument("--video-frames", type=int, default=0,
                   help="also draw and encode this many video frames over the run "
                        "(realization 0; a scratch file), to time them and to see "
                        "whether memory grows per frame")
    p.add_argument("--fast-math", action="store_true",
                   help="compile the kernels with Taichi's fast_math (the package turns it "
                        "off for bit-identical results): to time what that costs")
    p.add_argument("--lanes", default="auto", choices=("auto", "on", "off"),
                   help="the pressure solve's realizations side by side (fluid/_gmg_lanes.py): "
                        "where they fill the lanes (auto), always, or never; the same bits")
    p.add_argument("--one", help=argparse.SUPPRESS)   # internal: run one case here
    a = p.parse_args(argv)
    sim_time = a.sim_time or (0.02 if a.quick else 0.05)
    if a.one:
        if a.fast_math:
            _allow_fast_math()
        from taichi_hsdem.fluid.gmg import TaichiPressureSolver
        TaichiPressureSolver.lanes = {"auto": "auto", "on": True, "off": False}[a.lanes]
        print(json.dumps(run_case(a.one, a.arch, a.precision, sim_time, a.video_frames)),
              flush=True)
        return 0
    chosen = a.cases.split(",") if a.cases else cases(a.quick)
    for case in chosen:
        proc = subprocess.run([sys.executable, __file__, "--one", case, "--arch", a.arch,
                               "--precision", a.precision, "--sim-time", str(sim_time),
                               "--video-frames", str(a.video_frames), "--lanes", a.lanes]
                              + (["--fast-math"] if a.fast_math else []),
                              capture_output=True, text=True)
        if proc.returncode != 0:
            print(json.dumps({"case": case, "error": proc.stderr.strip().splitlines()[-1:]}),
                  flush=True)
            continue
        line = proc.stdout.strip().splitlines()[-1]
        print(line, flush=True)
        d = json.loads(line)
        print(f"{case:24s} {d['steps_per_s']:>9.0f} steps/s {d['contact_evals_per_s']:>12.3g} "
              f"evals/s {d['realization_sim_s_per_wall_s']:>9.4f} real-s/s "
              f"pressure {100 * d['pressure_share']:.0f} % {d['peak_rss_mb']:.0f} MB",
              file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
