"""tools/stokes_arch.py --config pair: the held pair's geometry and statics (no NGSolve)."""
import math
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "tools"))
import stokes_arch as sa  # noqa: E402


def test_pair_touches_both_walls_and_each_other_at_the_gap():
    cell = sa.load_cell(overrides=())
    assert abs(cell.W / cell.d - 1.7) < 1e-9
    for g in (0.0, 0.02, 0.05):
        x = sa.pair(cell, g * cell.d)
        assert abs(np.linalg.norm(x[0] - x[1]) - (cell.d + g * cell.d)) < 1e-12
        for k, name in enumerate(sa.PAIR):
            dist = abs(sa.WALL_N[name] @ x[k] - cell.c / math.sqrt(2.0))
            assert abs(dist - cell.a - g * cell.d) < 1e-12
            assert x[k][0] < cell.x_neck           # upstream of the neck
        cs = sa.contacts(cell, x)
        assert len(cs) == 3
        for i, j, n, p in cs:                      # contact points upstream of the neck
            assert p[0] < cell.x_neck


def test_pair_statics_is_determinate_and_symmetric():
    cell = sa.load_cell(overrides=())
    x = sa.pair(cell, 0.05 * cell.d)
    F = np.array([[45.0, -14.5], [45.0, 14.5]])
    T = np.array([1.4, -1.4])
    st = sa.statics(cell, x, F, T)
    assert st["residual"] < 1e-12
    N = np.array(st["N"])
    assert np.all(N > 0)
    # wall: N_w / sqrt(2) balances F_x (the tangential forces are small)
    assert abs(N[1] - 45.0 * math.sqrt(2.0)) < 0.05 * N[1]
    assert abs(N[1] - N[2]) < 1e-9
    assert st["slip_max"] < sa.MU
    assert st["P"] == 0.0
