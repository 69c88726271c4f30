"""Grid convergence of the pressure solve on the circular-inclusion problem.

A disk of radius ``a`` and permeability ``k2`` in a background ``k1`` under a
far-field gradient (docs/model.md section 6), in the box ``[-4a, 4a]^2`` with the exact
pressure on its sides; cells belong to the disk if their centre does. For each
contrast ``k2/k1`` and each resolution ``a/dx`` the table gives the mean (L1) and
largest (L_inf) error of the cell pressures in units of ``G a``, the observed order
between successive resolutions, and the time of the solve (multigrid set-up
included).

Usage::

    python tools/inclusion_convergence.py [--quick] [--out runs/inclusion_convergence.csv]
"""

import argparse
import csv
import math
import pathlib

from taichi_hsdem.fluid import circular_inclusion_error

CONTRASTS = (1e-2, 1e2)
RESOLUTIONS = (4, 8, 16, 32, 64)
QUICK_RESOLUTIONS = (4, 8, 16)


def study(resolutions, contrasts=CONTRASTS):
    """Rows of the convergence table, one per (contrast, a/dx)."""
    rows = []
    for k_ratio in contrasts:
        previous = None
        for m in resolutions:
            e = circular_inclusion_error(m, k_ratio)
            order_l1 = order_linf = math.nan
            if previous is not None:
                refine = math.log(m / previous[0])
                order_l1 = math.log(previous[1]["l1"] / e["l1"]) / refine
                order_linf = math.log(previous[1]["linf"] / e["linf"]) / refine
            rows.append({"k2_over_k1": k_ratio, "a_over_dx": m, "cells": e["cells"],
                         "l1_error": e["l1"], "linf_error": e["linf"],
                         "order_l1": order_l1, "order_linf": order_linf,
                         "solve_seconds": e["seconds"]})
            previous = (m, e)
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help=f"resolutions a/dx = {QUICK_RESOLUTIONS} only")
    parser.add_argument("--out", default="runs/inclusion_convergence.csv",
                        help="CSV file to write (default: %(default)s)")
    args = parser.parse_args(argv)
    rows = study(QUICK_RESOLUTIONS if args.quick else RESOLUTIONS)

    print(f"{'k2/k1':>7} {'a/dx':>5} {'cells':>8} {'L1 error':>10} {'Linf error':>10} "
          f"{'order L1':>8} {'order Linf':>10} {'solve s':>8}")
    for row in rows:
        print(f"{row['k2_over_k1']:>7g} {row['a_over_dx']:>5d} {row['cells']:>8d} "
              f"{row['l1_error']:>10.3e} {row['linf_error']:>10.3e} "
              f"{row['order_l1']:>8.2f} {row['order_linf']:>10.2f} "
              f"{row['solve_seconds']:>8.3f}")

    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
