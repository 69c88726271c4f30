"""Fit the close pairs' resistance of ``fluid.pair_mobility`` to the 3D Stokes pairs.

The depth-averaged model's pairs of disks drift side by side up to 14 % faster
than a lone disk and in line up to 8 % slower (with the default carried
fraction), where confined spheres (3D Stokes,
``taichi_hsdem/data/sphere_pair_lattice.csv``) move within 5 % of a lone one.
``fluid.pair_mobility`` gives each body the resistance
``m xi (I - K_i)``, ``K_i = sum_j alpha(g) I + beta(g) (2 e e^T - I)`` over its
neighbours within ``g < PAIR_CUTOFF`` (taichi_hsdem/laws.py, the table's last knot;
taichi_hsdem/dem/pairs.py), ``alpha`` and ``beta`` piecewise linear in the surface gap ``g`` between knots. This tool finds
the knots' values: the model's own pair lattices (tools/model_pair_lattice.py:
the scene's grid, permeability, carried flux and node forces, the steady drift,
``--offsets`` positions in a cell), each pair's drift over its lone lattice's at
the same phi, both with the resistance applied to every disk and periodic image
within the cutoff, least squares against the 3D ratios of every row of the
table. It writes the knots to ``--out`` (the package's table:
taichi_hsdem/data/pair_mobility.csv) and prints every row before and after.

    python tools/pair_mobility_fit.py [--offsets 64] [--check-offsets 576]
        [--out taichi_hsdem/data/pair_mobility.csv] [--set K=V ...]
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
import time
import types
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import model_pair_lattice as mpl  # noqa: E402
from taichi_hsdem import load_scene  # noqa: E402
from taichi_hsdem.laws import PAIR_CUTOFF  # noqa: E402
from taichi_hsdem.resolve import resolve  # noqa: E402

TABLE_3D = HERE.parent / "taichi_hsdem" / "data" / "sphere_pair_lattice.csv"
OUT = HERE.parent / "taichi_hsdem" / "data" / "pair_mobility.csv"
#: The knots (surface gap over d); the last one, the cutoff, holds zero.
KNOTS = (0.05, 0.1, 0.2, 0.5)


def rows_3d(path=TABLE_3D):
    with open(path, newline="") as fh:
        return [{"arrangement": r["arrangement"], "gap": float(r["gap"]),
                 "phi": float(r["phi"]), "ratio": float(r["ratio"])}
                for r in csv.DictReader(line for line in fh if not line.startswith("#"))]


class Lattice:
    """One periodic lattice's linear pieces at every offset, and its mean V/U
    with a given resistance table."""

    def __init__(self, model, args):
        nx, ny, base = mpl.layout(model, args)
        self.lat = mpl.PeriodicLattice(model, nx, ny)
        h = self.lat.h
        self.phi = len(base) * math.pi * self.lat.radius ** 2 / (nx * ny * h * h)
        self.centres = mpl.placements(self.lat, base, args.offsets)
        self.parts = [self.lat.pieces(c) for c in self.centres]

    def v_over_u(self, table):
        # K depends on the centres' differences alone: the same at every offset
        K = None if table is None else self.lat.pair_resistance(self.centres[0], table)
        out = []
        for p in self.parts:
            vel, U = self.lat.drift(p, K)
            out.append(vel[:, 0].mean() / U)
        return float(np.mean(out))


def build(model, rows, offsets):
    """(pair lattice, its lone lattice) per row."""
    pairs = []
    for r in rows:
        pa = Lattice(model, types.SimpleNamespace(lone=False, n=None, phi=r["phi"], gap=r["gap"],
                                                  arrangement=r["arrangement"],
                                                  offsets=offsets))
        lo = Lattice(model, types.SimpleNamespace(lone=True, n=None, phi=pa.phi, gap=None,
                                                  arrangement=None, offsets=offsets))
        pairs.append((pa, lo))
    return pairs


def table_of(x):
    """The resistance table of the knots' values ``x`` (alpha, beta per knot)."""
    t = [(g, x[2 * k], x[2 * k + 1]) for k, g in enumerate(KNOTS)]
    return np.array(t + [(PAIR_CUTOFF, 0.0, 0.0)])


def ratios(pairs, table):
    return np.array([pa.v_over_u(table) / lo.v_over_u(table) for pa, lo in pairs])


def fit(pairs, rows):
    from scipy.optimize import least_squares
    target = np.array([r["ratio"] for r in rows])
    sol = least_squares(lambda x: ratios(pairs, table_of(x)) - target,
                        np.zeros(2 * len(KNOTS)), x_scale=0.1, xtol=1e-10, ftol=1e-12)
    return table_of(sol.x)


def write(table, path, note):
    with open(path, "w") as fh:
        fh.write(f"# {note}\n")
        fh.write("g,alpha,beta\n")
        for g, a, b in table:
            fh.write(f"{g:g},{a:.6f},{b:.6f}\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--offsets", type=int, default=64)
    ap.add_argument("--check-offsets", type=int, default=0,
                    help="re-evaluate every row at this many offsets after the fit")
    ap.add_argument("--out", default=str(OUT), help="the table to write ('-': none)")
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    model = resolve(load_scene(mpl.SCENE, args.set))
    rows = rows_3d()
    pairs = build(model, rows, args.offsets)
    before = ratios(pairs, None)
    table = fit(pairs, rows)
    after = ratios(pairs, table)
    check = None
    if args.check_offsets:
        check = ratios(build(model, rows, args.check_offsets), table)
    target = np.array([r["ratio"] for r in rows])
    print(f"{'pair':>7} {'g':>5} {'phi':>5} {'3D':>7} {'model':>7} {'fitted':>7}"
          + (f" {'check':>7}" if check is not None else ""))
    for k, r in enumerate(rows):
        print(f"{r['arrangement']:>7} {r['gap']:5.2f} {r['phi']:5.2f} {r['ratio']:7.3f} "
              f"{before[k]:7.3f} {after[k]:7.3f}" + (f" {check[k]:7.3f}" if check is not None
                                                      else ""))
    final = after if check is None else check
    err = final - target
    summary = (f"max |error| {np.abs(err).max():.4f}, rms {np.sqrt(np.mean(err ** 2)):.4f} "
               f"(without: max {np.abs(before - target).max():.4f}, rms "
               f"{np.sqrt(np.mean((before - target) ** 2)):.4f})")
    print("knots: " + ", ".join(f"g {g:g}: alpha {a:+.4f} beta {b:+.4f}" for g, a, b in table))
    print(summary, f"[{time.perf_counter() - t0:.0f} s]")
    if args.out != "-":
        write(table, args.out,
              "fluid.pair_mobility: the close pairs' resistance K = alpha(g) I + beta(g) "
              "(2 e e^T - I) per neighbour, linear between the knots, the first knot's below "
              "it, 0 from the last (the cutoff); fitted to taichi_hsdem/data/"
              "sphere_pair_lattice.csv on the vani scene's grid, d/H = 0.875: python "
              f"tools/pair_mobility_fit.py --offsets {args.offsets}"
              + (f" --check-offsets {args.check_offsets}" if args.check_offsets else "")
              + "; " + summary)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
