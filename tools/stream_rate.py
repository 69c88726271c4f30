"""Escapee rate of a steady stream through a constriction too wide to clog,
against the experiments' law ``4 phi Q / (H pi d^2)`` (particles at the mean
fluid velocity), for each way the particles' volume enters the pressure.

    python tools/stream_rate.py [--width-d 5] [--phi 0.1] [--realizations 4]
        [--t-end 5] [--t-skip 1] [--models obstacle,implicit,lagged] [--set K=V ...]

The vani scene (``scenes/vani_phi026.toml``) with its constriction widened to
``--width-d`` diameters, ``run.stop_at_clog = false``, every other default. The
rate pools the escapes after ``--t-skip`` over all realizations. ``phi`` of the
law is measured, as the experiments would: the areal fraction of particles whose
centres lie in the downstream half of the straight upstream channel (clear of
the feeder's re-entry strip; ``--strip``), averaged over the frames after
``--t-skip``; the scene's nominal ``phi`` is printed beside
it, with the particles' mean x-velocity there over the mean fluid speed
``Q / (H W_in)`` (the law assumes 1). ``obstacle`` is ``fluid.particle_flux = false`` (particles as fixed
obstacles); ``implicit`` and ``lagged`` carry the particles' volume
(``fluid.flux_coupling``) with the default share of it (``carried_fraction``:
the 3D Stokes sphere's dipole); ``tracer`` carries all of it with
``drift_ratio = 1`` (the earlier default: tracers of the depth-averaged flow).
"""
import argparse
import math
import time
from pathlib import Path

import numpy as np

from taichi_hsdem import Simulation, load_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "vani_phi026.toml"
MODELS = {"obstacle": ["fluid.particle_flux=false"],
          "implicit": ["fluid.particle_flux=true", "fluid.flux_coupling=implicit"],
          "lagged": ["fluid.particle_flux=true", "fluid.flux_coupling=lagged"],
          "tracer": ["fluid.particle_flux=true", "fluid.flux_coupling=implicit",
                     "particles.drift_ratio=1", "particles.carried_fraction=1"]}


def measure(model: str, args) -> dict:
    """Rate, measured phi and the law's rate for one coupling."""
    base = load_scene(SCENE)
    d = base.particles[0].diameter
    overrides = [f"geometry.constriction_width={args.width_d * d!r}",
                 f"particles.0.packing_fraction={args.phi!r}",
                 f"run.realizations={args.realizations}", f"run.t_end={args.t_end!r}",
                 "run.stop_at_clog=false", f"run.seed={args.seed}", *MODELS[model], *args.set]
    sim = Simulation(load_scene(SCENE, overrides))
    g, sc = sim.model.geometry, sim.scene
    a, b = args.strip
    x0, length = g.x_min + a * sc.geometry.length_in, (b - a) * sc.geometry.length_in
    strip = sc.geometry.width_in * length
    area = math.pi * d**2 / 4
    fractions, speeds = [], []

    def frame(s):
        if s.t >= args.t_skip - 1e-12:
            st = s.state()
            x = st["x"][..., 0]
            inside = st["alive"] & (x >= x0) & (x <= x0 + length)
            fractions.append(inside.sum(axis=1) * area / strip)
            speeds.append(st["v"][..., 0][inside])

    every = 0.05
    t0 = time.perf_counter()
    res = sim.run(on_frame=frame, frame_times=list(np.arange(0.0, args.t_end + 1e-9, every)))
    wall = time.perf_counter() - t0
    series = np.array(res.series)
    escapes = span = 0.0
    stable = 0
    for r in range(sim.R):
        if res.summary["realizations"][r]["status"] != "ok":
            continue
        stable += 1
        s = series[(series[:, 0] == r) & (series[:, 1] >= args.t_skip - 1e-9)]
        escapes += s[-1, 2] - s[0, 2]
        span += s[-1, 1] - s[0, 1]
    phi = float(np.mean(fractions)) if fractions else float("nan")
    q, gap = sc.fluid.flow_rate, sc.fluid.gap
    law = 4 * phi * q / (gap * math.pi * d**2)
    rate = escapes / span if span > 0 else float("nan")
    u = q / (gap * sc.geometry.width_in)           # mean fluid speed upstream
    v = float(np.concatenate(speeds).mean()) / u if speeds else float("nan")
    return {"model": model, "rate": rate, "phi": phi, "law": law, "ratio": rate / law, "v": v,
            "escapes": int(escapes), "stable": stable, "R": sim.R, "wall": wall}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--width-d", type=float, default=5.0, help="constriction width / d")
    p.add_argument("--phi", type=float, default=0.1, help="scene packing fraction")
    p.add_argument("--realizations", type=int, default=4)
    p.add_argument("--t-end", type=float, default=5.0)
    p.add_argument("--t-skip", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--strip", type=lambda t: tuple(float(v) for v in t.split(":")),
                   default=(0.5, 1.0), metavar="A:B", help="where phi and the speed are "
                   "measured: from A to B of the upstream channel's length (default 0.5:1, "
                   "clear of the feeder's re-entry strip)")
    p.add_argument("--models", default="obstacle,implicit", help="comma-separated, of "
                   + ", ".join(MODELS))
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    args = p.parse_args(argv)
    models = args.models.split(",")
    bad = [m for m in models if m not in MODELS]
    if bad:
        p.error(f"unknown model(s) {bad}; choose from {list(MODELS)}")
    print(f"W = {args.width_d:g} d, scene phi {args.phi:g}, {args.realizations} realizations, "
          f"t = {args.t_skip:g}..{args.t_end:g} s")
    print(f"{'model':10s} {'escapes':>8s} {'rate/s':>8s} {'phi_meas':>9s} {'law/s':>8s} "
          f"{'rate/law':>9s} {'v_up/U':>7s} {'stable':>7s} {'wall s':>7s}")
    for m in models:
        r = measure(m, args)
        print(f"{r['model']:10s} {r['escapes']:8d} {r['rate']:8.3f} {r['phi']:9.4f} "
              f"{r['law']:8.3f} {r['ratio']:9.3f} {r['v']:7.3f} {r['stable']:>3d}/{r['R']:<3d} "
              f"{r['wall']:7.1f}", flush=True)


if __name__ == "__main__":
    main()
