"""The computations the GPU tests (tests/test_gpu.py) compare between a GPU and the
CPU: each case runs on whatever backend this process has, and returns arrays.

The GPU tests run them in their own process (``--arch gpu``) and, for the CPU's
answer, in a subprocess of this script:

    python tests/gpu_cases.py --precision f64 --out ref.npz vani squares solve

Short runs, because Mesa's software Vulkan (CI's GPU) is about 100 times slower
than the CPU backend.
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _sim(scene, **values):
    from taichi_hsdem.scene import load_scene
    from taichi_hsdem.simulation import Simulation
    sc = load_scene(ROOT / "scenes" / scene,
                    overrides=[f"{k}={json.dumps(v)}" for k, v in values.items()])
    return Simulation(sc)


def _state(sim) -> dict:
    st = sim.state()
    f, tau = sim.fluid_forces()
    return {"x": st["x"], "theta": st["theta"], "v": st["v"], "omega": st["omega"],
            "alive": st["alive"].astype(float), "f_fluid": f, "pressure": sim.pressure(),
            "t": np.array(sim.t)}


def vani(arch: str, precision: str) -> dict:
    from taichi_hsdem import backend
    """The default physics (disks, the multigrid solve with the implicit carried
    volume) on the shipped vani scene, 2 realizations: the set-up solve and 150
    steps with their solves and host checks (``run`` to t = 150 dt)."""
    sim = _sim("vani_phi026.toml", **{"run.realizations": 2, "run.arch": arch,
                                      "run.precision": precision})
    sim.extend(150.5 * sim.dt)
    sim.run()
    out = _state(sim)
    out["solves"] = np.array(sim.fluid.solves)
    out["solve_f64"] = np.array(sim.fluid.solver.real == backend.ti.f64)
    return out


def squares(arch: str, precision: str) -> dict:
    """Level-set squares (the node contacts, two kernels on a GPU) with fluid: 20
    steps with a solve every 10."""
    sim = _sim("squares.toml", **{"run.realizations": 1, "run.arch": arch,
                                  "run.precision": precision})
    sim.update_fluid(force=True)
    advance = getattr(sim, "advance", None) or sim.step
    for _ in range(2):
        advance(10)
        sim.update_fluid(force=True)
    return _state(sim)


def solve(arch: str, precision: str, real: str = None) -> dict:
    """The multigrid solve alone on the vani grid's size: particles of 1/60 the
    free permeability over a quarter of the cells, a flow-rate and a pressure
    inlet, 2 realizations, tol 1e-6 (``real``: the solve's float type)."""
    from taichi_hsdem import backend
    backend.init(arch, precision)
    from taichi_hsdem.fluid.gmg import TaichiPressureSolver
    rng = np.random.default_rng(7)
    nx, ny = 175, 61
    X, Y = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    kappa = np.full((2, nx, ny), 0.12)
    for r in range(2):
        for _ in range(90):
            cx, cy = rng.uniform(0, nx), rng.uniform(0, ny)
            kappa[r][(X - cx) ** 2 + (Y - cy) ** 2 < 9] = 0.12 / 60
    out = {}
    for name, bc in (("flow", {"kind": "flow_rate", "Q": 1e-9, "p_out": 0.0}),
                     ("pressure", {"kind": "pressure", "p_in": 10.0, "p_out": 0.0})):
        s = TaichiPressureSolver(np.ones((nx, ny), bool), 1e-5, 1e-5, 1e-3, bc=bc, gap=1e-4,
                                 n_batch=2, tol=1e-6, real=real)
        p, info = s.solve(kappa)
        out[f"{name}_p"] = p
        out[f"{name}_flux"] = np.stack([info.flux_in, info.flux_out])
        out[f"{name}_iterations"] = np.array(info.iterations)
    return out


def rebuild(arch: str, precision: str) -> dict:
    """The neighbour lists of the hourglass scene's 2 realizations as placed:
    built by the host's build (a thread per body on a GPU), by the per-step
    path's device rebuild (``NeighborList.rebuild_if_flagged``, gated by the
    rebuild flag), and the device rebuild into lists of capacity one, which
    overflows and must stall the batch (its record and ``running`` after it).
    A list is its ``nbr_n`` entries, -1 after them."""
    from taichi_hsdem.layout import F_REBUILD
    sim = _sim("hourglass24.toml", **{"run.realizations": 2, "run.arch": arch,
                                      "run.precision": precision, "run.seed": 3,
                                      "run.stepping": "per_step"})
    nl = sim.neighbors

    def lists():
        nbr, n = nl.nbr.to_numpy(), nl.nbr_n.to_numpy()
        return np.where(np.arange(nbr.shape[2]) < n[..., None], nbr, -1)
    out = {}
    sim.rebuild_neighbors()
    out["host"] = lists()
    for name, caps in (("device", nl.capacities), ("overflow", (1, 1))):
        nl.resize(*caps)
        sim.flags[F_REBUILD] = 1
        nl.rebuild_if_flagged(sim.bodies, sim.batch, sim.particles, sim.flags, sim._stall, 7)
        out[f"{name}_stall"] = sim._stall.to_numpy()
        out[f"{name}_running"] = sim.batch.running.to_numpy()
        if name == "device":
            out["device"] = lists()
    return out


CASES = {"vani": vani, "squares": squares, "solve": solve, "rebuild": rebuild}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+", choices=sorted(CASES))
    ap.add_argument("--arch", default="cpu")
    ap.add_argument("--precision", default="f64")
    ap.add_argument("--out", required=True)
    ap.add_argument("--no-f64", action="store_true",
                    help="as on a backend without float64 kernels (Metal): the solve in "
                         "float32 (with --precision f32)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    from taichi_hsdem import backend
    backend.init(args.arch, args.precision)
    if args.no_f64:
        backend._STATE["f64"] = False
    found = {}
    for case in args.cases:
        for key, value in CASES[case](args.arch, args.precision).items():
            found[f"{case}.{key}"] = np.asarray(value)
    np.savez(args.out, **found)


if __name__ == "__main__":
    main()
