"""tools/neck_plot.py: ln <s> against (W/d)^2 from neck-width tables, with the
2D silos' straight line fitted over the widths that clog."""
import math

import pytest
from conftest import load_tool

HEADER = "wd,mean_escapees,ci_lo,ci_hi,never_clogged,n,n_unstable,status\n"


def _synthetic(path, a=-0.5, b=0.9, widths=(1.2, 1.4, 1.6, 1.8, 2.0), spread=(0.8, 1.3)):
    """A neck.csv whose <s> lies exactly on ln<s> = a + b (W/d)^2 (intervals of
    different widths, so the fit is weighted), and one width where nothing clogged."""
    rows = []
    for k, wd in enumerate(widths):
        s = math.exp(a + b * wd * wd)
        f = spread[0] - 0.05 * k, spread[1] + 0.1 * k
        rows.append(f"{wd},{s!r},{s * f[0]!r},{s * f[1]!r},{k},40,0,ran\n")
    rows.append("2.4,,300.0,,40,40,0,ran\n")
    path.write_text(HEADER + "".join(rows))
    return a, b


def test_the_fitted_slope_is_the_synthetic_tables_and_the_png_is_written(tmp_path, capsys):
    plot = load_tool("neck_plot")
    table = tmp_path / "neck.csv"
    a, b = _synthetic(table)
    series = plot.parse_series(f"phi = 0.30={table}")
    assert series.label == "phi = 0.30"
    assert [p.censored for p in series.points] == [False] * 5 + [True]
    f = plot.fit(series.points)
    assert f.weighted and f.points == 5 and f.wd_range == (1.2, 2.0)
    assert f.slope == pytest.approx(b, abs=1e-6)
    assert f.intercept == pytest.approx(a, abs=1e-6)
    assert f.chi2_dof == pytest.approx(0, abs=1e-9)
    # the one lower bound, ln 300 = 5.70, lies above the line's 4.68 at W/d = 2.4
    assert (f.bounds_above, f.bounds) == (1, 1)
    png = tmp_path / "out" / "neck.png"
    assert plot.main([f"phi = 0.30={table}", "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = capsys.readouterr().out
    assert f"{b:.6g} (W/d)^2" in out and "1 of 1 lower bounds above the line" in out


def test_a_folder_of_parts_joins_and_unweighted_points_still_fit(tmp_path):
    plot = load_tool("neck_plot")
    one, two = tmp_path / "one", tmp_path / "two.csv"
    one.mkdir()
    (one / "neck.csv").write_text(HEADER + "1.2,5.0,,,0,10,0,ran\n1.4,7.0,,,0,10,0,ran\n")
    two.write_text(HEADER + "1.6,11.0,,,0,10,0,ran\n2.0,,50.0,,10,10,0,ran\n")
    series = plot.parse_series(f"{one}+{two}")
    assert series.label == "one" and [p.wd for p in series.points] == [1.2, 1.4, 1.6, 2.0]
    f = plot.fit(series.points)
    assert not f.weighted and f.points == 3
    import numpy as np
    slope = np.polyfit([1.44, 1.96, 2.56], np.log([5.0, 7.0, 11.0]), 1)[0]
    assert f.slope == pytest.approx(slope, abs=1e-9)


def test_a_table_without_the_columns_is_refused_in_one_line(tmp_path, capsys):
    plot = load_tool("neck_plot")
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    assert plot.main([str(bad), "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a neck table" in err
    assert not (tmp_path / "x.png").exists()


def test_realizations_of_one_width_from_several_runs_are_pooled():
    plot = load_tool("neck_plot")
    from taichi_hsdem.stats.geometric import mean_escapees
    esc, clog = [3, 40, 7, 40, 12], [True, False, True, False, True]
    points = plot.pooled({2.0: (esc, clog), 1.2: ([2, 1], [True, True]),
                          2.4: ([50, 50], [False, False])})
    assert [p.wd for p in points] == [1.2, 2.0, 2.4]
    m, (lo, hi) = mean_escapees(esc, clog)
    assert (points[1].s, points[1].lo, points[1].hi) == (m, lo, hi)
    assert (points[1].never, points[1].n) == (2, 5)
    assert points[2].censored and points[2].lo > 0 and points[2].hi is None
    assert plot.folder_counts(__import__("pathlib").Path("no such folder")) == {}
