"""The pressure drop of an EMPTY micromodel (no particles), against references
that do not come from the solver at the run's resolution (issue 36).

* An exact Darcy result: the square array of circular pillars is the classical
  problem of the conductivity of a square array of insulating cylinders (the
  depth-averaged Hele-Shaw pressure is harmonic with no flux into the pillars):
  Rayleigh's series with Perrins, McKenzie and McPhedran's coefficients, exact to
  far below these tolerances at this area fraction. A channel whose walls lie on
  the array's symmetry lines is an exact strip of the infinite array. The grid
  error is that of the staircase: a cell is fluid when its centre is, so the
  pillars' boundary is off by up to half a cell, a first-order error in the cell
  size. Measured: K/K_exact - 1 = -1.38 % at 21 cells per spacing (the run's
  d/6 for the shipped scene), -1.84 % at 42, -1.05 % at 84, -0.56 % at 168; the
  first-order extrapolation of the last two, -0.07 % (docs/micromodels.md). The
  tolerances hold these with room for the staircase's irregular convergence: 2 %
  at the run's resolution, 1.5 % at four times finer.
* A finer grid of the same solver: the shipped scene's empty pressure drop at its
  own resolution against the same scene at half and a quarter of the cell size,
  extrapolated (measured 4.2315, 4.1852, 4.1684 Pa: 1.5 to 1.9 % above the
  extrapolated value, depending on the order assumed).
"""
from pathlib import Path

import pytest

from taichi_hsdem import load_scene
from taichi_hsdem.gallery import pillar_lattice_gradient, rayleigh_square_array
from taichi_hsdem.report import empty_flow
from taichi_hsdem.resolve import resolve

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "micromodel.toml"


def test_rayleigh_series_is_keller_reciprocal_and_maxwell_at_low_fraction():
    # at low area fraction the series is Maxwell's (1 - f) / (1 + f)
    assert rayleigh_square_array(0.01) == pytest.approx(0.99 / 1.01, rel=1e-8)
    assert rayleigh_square_array(0.0) == 1.0


@pytest.mark.parametrize("cells, tol", [(21, 0.02), (84, 0.015)])
def test_empty_square_array_permeability_against_the_exact_darcy_result(cells, tol):
    computed, exact = pillar_lattice_gradient(cells)
    assert exact == pytest.approx(0.5914, abs=2e-4)      # f = 0.2558 (96-gon pillars)
    assert abs(computed / exact - 1) < tol


def test_shipped_micromodel_empty_pressure_drop_against_finer_grids():
    base = 100e-6 / 6          # the scene's auto cell size, d_eq / 6
    drops = []
    for fine in (1, 2, 4):
        model = resolve(load_scene(SCENE, [f"fluid.cell_size={base / fine!r}"]), "x64")
        drop, q = empty_flow(model)
        assert q == pytest.approx(2e-10, rel=1e-9)
        drops.append(drop)
    coarse, mid, finest = drops
    assert coarse > mid > finest                          # converging from above
    assert (coarse - mid) / (mid - finest) > 2.0          # at least first order
    limit = finest - (mid - finest)                       # first-order extrapolation
    assert 0.0 < coarse / limit - 1 < 0.025
