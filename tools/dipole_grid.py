"""The dipole a lone particle leaves in the depth-averaged pressure on the scene's own
grid, against the exact inclusion's, and the carried fraction that would leave the
3D Stokes sphere's dipole on that grid.

The particle is the staircase the coupling rasterises (a cell belongs to it when its
centre lies inside the disk of diameter ``d_eq``), with the species' permeability,
drifting at ``lambda u`` and carrying the fraction ``c`` of its velocity in its cells
(``fluid.particle_flux``): one pyamg solve per position on the scene's cell size,
in a channel 24 d long and 12 d wide, the dipole ``B / a^2`` fitted on the ring
1.5 d < r < 3 d with the side walls' images, averaged over random positions of the
disk in a cell. ``B`` is linear in ``c`` (``B0 - c S``), so two solves per position
give it for every ``c``.

    python tools/dipole_grid.py scenes/vani_phi026.toml [--positions 8] [--set K=V]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from taichi_hsdem import SceneError, load_scene  # noqa: E402
from taichi_hsdem.fluid.grid_dipole import ring_fit  # noqa: E402
from taichi_hsdem.laws import inclusion_dipole, sphere_in_gap  # noqa: E402


def grid_dipole(h: float, d: float, k_free: float, k_p: float, carried_speed: float,
                offsets, length: float = 24.0, width: float = 12.0):
    """``B / a^2`` (mean and spread over ``offsets``, in cells) of a disk of diameter
    ``d`` on a grid of cell ``h``, its cells of permeability ``k_p`` carrying
    ``carried_speed`` times the mean fluid speed."""
    from taichi_hsdem.fluid.solver import PressureSolver
    nx, ny = int(round(length * d / h)), int(round(width * d / h))
    L, W = nx * h, ny * h
    cx, cy = np.meshgrid((np.arange(nx) + 0.5) * h, (np.arange(ny) + 0.5) * h, indexing="ij")
    solver = PressureSolver(np.ones((nx, ny), bool), h, h, 1.0,
                            {"kind": "pressure", "p_in": L, "p_out": 0.0}, tol=1e-12)
    values = []
    for ox, oy in offsets:
        x0, y0 = L / 2 + ox * h, W / 2 + oy * h
        dx, dy = cx - x0, cy - y0
        inside = np.hypot(dx, dy) <= d / 2
        kappa = np.where(inside, k_p, k_free)
        if carried_speed:
            carried = np.zeros((nx, ny, 2))
            carried[inside, 0] = carried_speed * k_free      # mean speed k_free |G| / eta
            p, _ = solver.solve(kappa, carried=carried, occupied=inside)
        else:
            p, _ = solver.solve(kappa)
        coef = ring_fit(p, dx, dy, d, W)
        values.append(coef[2] / coef[1] / (0.25 * d * d))
    return float(np.mean(values)), float(np.std(values))


def study(scene, positions: int = 8, seed: int = 0) -> dict:
    """The grid's dipole at c = 0, the scene's c and 1, and the c that gives the
    3D sphere's dipole on this grid, for the scene's first species."""
    from taichi_hsdem.resolve import resolve
    m = resolve(scene)
    s, lam = m.species[0], m.scene.particles[0].drift_ratio
    d, h = s.d_eq, m.fluid_dx
    offsets = [tuple(v) for v in np.random.default_rng(seed).uniform(-0.5, 0.5, (positions, 2))]
    rows = []
    for c in (0.0, s.carried, 1.0):
        b, spread = grid_dipole(h, d, m.kappa_free, s.kappa, c * lam, offsets)
        rows.append({"c": c, "grid": b, "spread": spread,
                     "exact": inclusion_dipole(m.kappa_free, s.kappa, lam, c)})
    b0, s_slope = rows[0]["grid"], rows[0]["grid"] - rows[2]["grid"]
    target = sphere_in_gap(d / m.scene.fluid.gap)[1]
    return {"d_over_h": d / h, "lambda": lam, "c": s.carried, "rows": rows, "target": target,
            "c_grid": (b0 - target) / s_slope, "linear_error": rows[1]["grid"] - (
                b0 - s.carried * s_slope)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--positions", type=int, default=8)
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    args = ap.parse_args(argv)
    try:
        scene = load_scene(args.scene, args.set)
        res = study(scene, args.positions)
    except SceneError as exc:
        print("\n".join(exc.problems), file=sys.stderr)
        return 2
    print(f"d/h = {res['d_over_h']:.2f}, lambda = {res['lambda']:.4f}, "
          f"{args.positions} positions in a cell")
    print("c        grid B/a^2       exact    grid/exact")
    for r in res["rows"]:
        print(f"{r['c']:.4f}   {r['grid']:.4f} +- {r['spread']:.4f}   {r['exact']:.4f}   "
              f"{r['grid'] / r['exact']:.4f}")
    print(f"the 3D sphere's B/a^2 {res['target']:.4f}: on this grid c = {res['c_grid']:.4f} "
          f"leaves it (the scene's c = {res['c']:.4f}); linearity in c to "
          f"{abs(res['linear_error']):.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
