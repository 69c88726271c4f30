"""The sphere-in-gap table (tools/stokes_sphere_gap.py, taichi_hsdem/data/sphere_in_gap.csv).

The shipped CSV is read back (all ratios, the columns, the physics' signs), and one
quick 3D Stokes solve (NGSolve, the ``stokes`` extra; skipped without it) is
compared with the CSV's row at d/H = 0.7.
"""
import importlib.resources
import importlib.util
import math
import time
from pathlib import Path

import pytest

from conftest import load_tool

ROOT = Path(__file__).resolve().parents[1]


ssg = load_tool("stokes_sphere_gap")


def _table():
    path = importlib.resources.files("taichi_hsdem") / "data" / "sphere_in_gap.csv"
    return ssg.read_table(path)


def test_shipped_table_has_every_ratio_and_column():
    """Every ratio of TABLE_DH, every column, and the signs and trends of the
    physics: a held sphere is pushed downstream (f_fix > 0), a moving one is
    dragged (f_mov < 0), and the free drift ratio falls as the sphere fills the
    gap (the film's lubrication drag grows like ln(a / delta))."""
    rows = _table()
    assert sorted(rows) == sorted(ssg.TABLE_DH)
    dhs = sorted(rows)
    for dh in dhs:
        row = rows[dh]
        assert set(row) == set(ssg.CSV_COLUMNS)
        assert row["f_fix"] > 0 > row["f_mov"]
        assert row["dipole_fixed"] > 0 and row["dipole_moving"] > 0
        assert math.isclose(row["drift_ratio"], row["f_fix"] / -row["f_mov"], rel_tol=2e-4)
        assert math.isclose(row["dipole_free"],
                            row["dipole_fixed"] - row["drift_ratio"] * row["dipole_moving"],
                            abs_tol=2e-4)
    lam = [rows[dh]["drift_ratio"] for dh in dhs]
    assert all(x > y for x, y in zip(lam, lam[1:]))


def test_quick_solve_matches_the_table():
    """One coarse solve (preset ``quick``: P3/P2, sizes 0.5 H / 0.3 a / 1.0 film,
    half-width 3 ell, half-length 6 ell; 6 s here) at d/H = 0.7 against the
    table's row (sizes 0.25 / 0.1 / 0.35, 4 ell x 8 ell).

    The quick preset's measured differences from the table: at d/H = 0.7,
    2.0e-4 on lambda, 4.7e-4 on B_free / a^2 and 4.6e-4 relative on B; over
    d/H = 0.3 to 0.975 at most 5.1e-4 and 1.7e-3 (at 0.975, the thinnest film).
    The tolerances, 1e-3, 1.5e-3 and 1.5e-3, are 3 to 5 times the error at 0.7,
    below that of the same mesh at P2/P1 (1.5e-3, 4.1e-3, 7.8e-3), and far
    below a lost side-wall correction (the raw ratio is 1.309 in this domain)."""
    pytest.importorskip("ngsolve", reason="NGSolve (the stokes extra) is not installed: "
                        "pip install -e '.[stokes]'")
    ref = _table()[0.7]
    t0 = time.perf_counter()
    rec = ssg.run(ssg.preset("quick", 0.7), threads=1)
    wall = time.perf_counter() - t0
    assert abs(rec["drift_ratio"] - ref["drift_ratio"]) < 1e-3
    assert abs(rec["dipole_free"] - ref["dipole_free"]) < 1.5e-3
    assert abs(rec["dipole_fixed"] / ref["dipole_fixed"] - 1) < 1.5e-3
    # the force's two measures agree (1.9e-3 measured) and the far field is a
    # clean dipole (the fixed sphere's B ring by ring over 1.5-3 ell: 3.9e-4)
    assert abs(rec["solve"]["fixed"]["F_surface_rel"]) < 1e-2
    assert rec["diagnostics"]["ring_spread_rel"] < 3e-3
    assert wall < 120, f"the quick solve took {wall:.0f} s"
