"""The sphere-lattice table (tools/stokes_sphere_lattice.py, taichi_hsdem/data/sphere_lattice.csv).

The shipped CSV is read back: every phi, the columns, and the identities between
them. Then one quick 3D Stokes solve (NGSolve, the ``stokes`` extra; skipped
without it) at phi = 0.26 is compared with the CSV's row.
"""
import csv
import importlib.resources
import importlib.util
import math
import time
from pathlib import Path

import pytest

from conftest import load_tool

ROOT = Path(__file__).resolve().parents[1]


ssl = load_tool("stokes_sphere_lattice")


def _table():
    path = importlib.resources.files("taichi_hsdem") / "data" / "sphere_lattice.csv"
    return {row["phi"]: row for row in ssl.read_table(path)}


def test_shipped_table_has_every_phi_and_consistent_columns():
    """Every phi of TABLE_PHI is in the table, plus the extrapolated phi = 0 row,
    and the columns agree with one another:

    * ``cell_over_H = (d/2H) sqrt(pi/phi)``;
    * the fluid's mean velocity is ``U_fluid = (U_mean - eps V)/(1 - eps)``, with
      ``eps = (2/3)(d/H) phi`` the solid volume fraction;
    * the free spheres outrun the mixture, and the speed-up grows with phi;
    * ``U_mean/U_P`` falls with phi, and is 1 at phi = 0.
    """
    path = importlib.resources.files("taichi_hsdem") / "data" / "sphere_lattice.csv"
    first = path.read_text().splitlines()[0]
    assert first.startswith("# ") and "python tools/stokes_sphere_lattice.py --table" in first
    rows = _table()
    assert sorted(rows) == [0.0] + sorted(ssl.TABLE_PHI)
    for phi, row in rows.items():
        assert set(row) == set(ssl.CSV_COLUMNS)
        assert row["d_over_H"] == 0.875
        if phi == 0.0:
            assert math.isinf(row["cell_over_H"])
            assert row["drift_over_mean"] == pytest.approx(row["drift_over_fluid"], abs=1e-5)
            assert row["mean_over_poiseuille"] == pytest.approx(1.0, abs=1e-5)
            continue
        a = 0.5 * row["d_over_H"]
        assert row["cell_over_H"] == pytest.approx(a * math.sqrt(math.pi / phi), rel=1e-6)
        eps = 2.0 / 3.0 * row["d_over_H"] * phi
        r = row["drift_over_mean"]
        assert row["drift_over_fluid"] == pytest.approx((1 - eps) / (1 / r - eps), abs=3e-6)
    phis = sorted(rows)
    drift = [rows[p]["drift_over_mean"] for p in phis]
    mean = [rows[p]["mean_over_poiseuille"] for p in phis]
    assert all(1.0 < x < y for x, y in zip(drift, drift[1:]))
    assert all(x > y for x, y in zip(mean, mean[1:]))


def test_dilute_limit_is_the_isolated_sphere():
    """As phi -> 0 the lattice's drift ratio is the lone sphere's lambda
    (sphere_in_gap.csv, another solver and another domain): the two agree to
    about 1e-5 at d/H = 0.875; the tolerance, 5e-4, allows for that table's own
    error and is still 20 times below the O(phi) term at phi = 0.02 (0.0095)."""
    gap = importlib.resources.files("taichi_hsdem") / "data" / "sphere_in_gap.csv"
    with gap.open() as fh:
        lam = {float(r["d_over_H"]): float(r["drift_ratio"])
               for r in csv.DictReader(line for line in fh if not line.startswith("#"))}
    if 0.875 not in lam:
        pytest.skip("sphere_in_gap.csv has no row at d/H = 0.875")
    assert _table()[0.0]["drift_over_mean"] == pytest.approx(lam[0.875], abs=5e-4)


def test_quick_solve_matches_the_table():
    """One coarse solve (preset ``quick``: P3/P2, sizes 0.4 H / 0.2 a / 0.7 film,
    9,561 unknowns, a few seconds) at phi = 0.26 against the table's row (preset
    ``table``: 0.3/0.15/0.5 P4). The quick preset's measured differences from the
    table, at phi = 0.02, 0.05, 0.1, 0.18, 0.26, 0.3 and 0.4, are at most 1.5e-4
    on V/U_mean (5.4e-5 at 0.26), 1.5e-4 on V/U_fluid (7e-5) and 1.3e-4 on
    U_mean/U_P (9e-5). The tolerance, 3e-4, is twice the worst of these. It is
    below the same mesh's error at P2/P1 (9e-4 on V/U_mean, 1.4e-3 on U_mean/U_P
    at 0.26), and far below what a wrong definition would change: V over the
    fluid's mean velocity instead of the mixture's is 2.5e-2 higher, and the
    lone sphere's drift ratio (phi -> 0) is 0.115 lower."""
    pytest.importorskip("ngsolve", reason="NGSolve (the stokes extra) is not installed: "
                        "pip install -e '.[stokes]'")
    ref = _table()[0.26]
    t0 = time.perf_counter()
    rec = ssl.run(ssl.preset("quick", 0.875, 0.26), threads=1)
    wall = time.perf_counter() - t0
    for key in ssl.RATIOS:
        assert abs(rec[key] - ref[key]) < 3e-4, (key, rec[key], ref[key])
    # the flux through the cell by three measures, and the force by two
    assert abs(rec["Q_check_x0"]) < 1e-5 and abs(rec["Q_check_volume"]) < 1e-5
    for key in ("fixed", "moving"):
        assert abs(rec["solve"][key]["F_surface_rel"]["grad"]) < 1e-2
    assert wall < 60, f"the quick solve took {wall:.0f} s"
