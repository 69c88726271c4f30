"""The paper's figures as commands (taichi_hsdem.studies.figures, tools/figures.py).

The default run holds the analysis helpers (no simulation) and one command's quick
version, the cheapest (escapees-time at one packing fraction); the other commands'
quick versions are marked slow (``pytest -m slow``).
"""
import csv
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import stats
from taichi_hsdem.studies import figures, points

pytest.importorskip("matplotlib")

ROOT = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def check_png(path):
    data = Path(path).read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 5000


# ------------------------------------------------------------------ helpers, no run

def test_theory_line_formula():
    # 4 phi Q t / (H pi d^2), by hand for phi = 0.26, Q = 1e-10, H = 160 um, d = 140 um
    by_hand = 4 * 0.26 * 1e-10 * 2.0 / (160e-6 * math.pi * 140e-6 ** 2)
    assert figures.theory_escapees(0.26, 2.0, 1e-10, 160e-6, 140e-6) == pytest.approx(by_hand)
    assert by_hand / 2.0 == pytest.approx(10.556, rel=1e-3)


def test_stream_rate_counts_from_first_escape():
    # realization 0: steady stream from t = 1 at 2/s; realization 1 clogs after its
    # 3rd escape at t = 2.5, then nothing more; realization 2 never lets one out.
    series = [(0, t, max(0, int(2 * (t - 1.0)) + 1) if t >= 1.0 else 0)
              for t in np.arange(0.0, 5.01, 0.25)]
    series += [(1, t, 0 if t < 1.5 else (1 if t < 2.0 else (2 if t < 2.5 else 3)))
               for t in np.arange(0.0, 5.01, 0.25)]
    series += [(2, t, 0) for t in np.arange(0.0, 5.01, 0.25)]
    rows = [{"seed": 0, "status": "ok", "clogged": False},
            {"seed": 1, "status": "ok", "clogged": True},
            {"seed": 2, "status": "ok", "clogged": False}]
    r = figures.stream_rate(series, rows)
    # realization 0: s from 1 (t = 1) to 9 (t = 5): 8 escapes in 4 s;
    # realization 1: from 1 (t = 1.5) to 3 (t = 2.5): 2 in 1 s -> 10 in 5 s
    assert r["events"] == 10 and r["duration"] == pytest.approx(5.0)
    assert r["rate"] == pytest.approx(2.0)
    assert r["rate_stderr"] == pytest.approx(math.sqrt(10) / 5.0)
    assert r["t_first_mean"] == pytest.approx(1.25) and r["n_no_escape"] == 1


def test_pmf_bins_whole_escapees_and_normalisation():
    rng = np.random.default_rng(3)
    s = rng.geometric(0.1, size=400) - 1          # s = 0, 1, 2, ... with <s> = 9
    c = np.ones(s.size, bool)
    bins = stats.pmf_bins(s, c)
    mean = stats.fit_geometric(s, c).mean
    assert mean == pytest.approx(s.mean())
    m = bins[0]["s_hi"] - bins[0]["s_lo"] + 1
    assert m == round(stats.pmf.PMF_BIN_FRACTION * mean)
    assert all(b["s_hi"] - b["s_lo"] + 1 == m for b in bins)   # whole s, equal bins
    assert sum(b["count"] for b in bins) == s.size
    total = sum(b["pmf"] * b["bin_width_x"] for b in bins)
    assert total == pytest.approx(1.0)
    # the collapse: near exp(-x), so the fitted decay in x is near 1
    assert figures.pmf_lsq_rate(bins) == pytest.approx(1.0, abs=0.25)


def test_pmf_bins_keep_censored_in_the_mean():
    # censored realizations are not in the histogram but raise <s> (stats.fit_geometric)
    s = np.array([2, 4, 6, 30, 30])
    c = np.array([True, True, True, False, False])
    bins = stats.pmf_bins(s, c)
    fit = stats.fit_geometric(s, c)
    assert bins[0]["mean_s"] == pytest.approx(fit.mean)
    assert fit.mean > s[c].mean()
    assert sum(b["count"] for b in bins) == 3
    assert stats.pmf_bins(s, np.zeros(5, bool)) == []      # no clog: undefined


def test_point_stats_handles_censored_and_unstable():
    p = points.Point("x", {"mu": 0.1}, scene=None)
    run = points.PointRun(p, rows=[
        {"seed": 0, "escapees": 3, "clogged": True, "status": "ok"},
        {"seed": 1, "escapees": 8, "clogged": False, "status": "ok"},
        {"seed": 2, "escapees": 1, "clogged": True, "status": "ok"},
        {"seed": 3, "escapees": None, "clogged": None, "status": "unstable"}])
    d = figures.point_stats(run)
    assert (d["n_ok"], d["n_clogged"], d["n_censored"], d["n_unstable"]) == (3, 2, 1, 1)
    mean, ci = stats.mean_escapees([3, 8, 1], [True, False, True])
    assert d["mean_s"] == pytest.approx(mean) and d["mean_method"] == "geometric_mle"
    assert (d["mean_s_lo"], d["mean_s_hi"]) == pytest.approx(ci)
    assert d["decay_rate"] == pytest.approx(-math.log(1 - 2 / 14))


def test_invalid_override_is_refused_before_running(tmp_path, capsys):
    rc = figures.main(["friction", "--quick", "--out", str(tmp_path / "f"),
                       "--set", "particles.frction=0.3"])
    assert rc == 2
    assert "frction" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()


def test_points_of_each_figure():
    base, _ = points.base_scene("shapes", quick=True)
    pts = points.build_points("shapes", base, points.DEFAULT_POINTS["shapes"])
    d_b = points.bounding_diameter(base)
    assert d_b == pytest.approx(98.99e-6 * math.sqrt(2))
    circles = [p for p in pts if p.values["shape"] == "circle"]
    assert len(pts) == 4 and len(circles) == 2
    for p in circles:
        sp = p.scene.particles[0]
        assert sp.shape == "circle" and sp.diameter == pytest.approx(d_b) and sp.side is None
        assert sp.count == base.particles[0].count and sp.friction == 0.4
    for p in pts:
        assert p.scene.geometry.constriction_width == pytest.approx(p.values["W_over_db"] * d_b)
    base, _ = points.base_scene("polygons")
    pts = points.build_points("polygons", base, points.DEFAULT_POINTS["polygons"])
    assert [p.values["n_vertices"] for p in pts] == [3, 4, 5, 6, 0]
    assert all(p.scene.particles[0].count == 50 for p in pts)


def _fake_run(values, label, rng, n=12, censor_at=None, info=None):
    """A PointRun of geometric counts (no simulation), some censored."""
    s = rng.geometric(0.15, size=n) - 1
    rows, series = [], []
    for k, sk in enumerate(s):
        if censor_at == 0:                      # never clogged, something escaped
            clogged, sk = False, int(sk) + 1
        else:
            clogged = censor_at is None or sk < censor_at
            sk = int(sk if clogged else censor_at)
        rows.append({"seed": k, "escapees": sk, "clogged": clogged, "t_clog": 1.0,
                     "t_stop": 2.0, "status": "ok", "reason": None})
        for j, t in enumerate(np.linspace(0, 2, 21)):
            series.append((k, float(t), min(sk, max(0, j - 4))))
    rows.append({"seed": n, "escapees": None, "clogged": None, "t_clog": None, "t_stop": 0.5,
                 "status": "unstable", "reason": "test"})
    info = info or {"n_particles": 12, "phi_actual": values.get("phi", 0.26), "d_eq": 140e-6,
                    "d_b": 140e-6, "flow_rate": 1e-10, "gap": 160e-6, "t_end": 2.0,
                    "dt": 1e-5, "contact_path": "disk"}
    return points.PointRun(points.Point(label, values, scene=None), rows=rows,
                            series=series, wall=1.0, info=info)


@pytest.mark.parametrize("command", figures.FIGURES)
def test_every_figure_renders(command, tmp_path):
    # every plot from synthetic points, with the awkward cases: a censored point,
    # a point with no clog at all (open interval), an unstable realization
    rng = np.random.default_rng(1)
    if command in ("escapees-time", "pmf-collapse"):
        vals = [{"phi": p} for p in (0.19, 0.26, 0.32)]
    elif command == "friction":
        vals = [{"mu": m, "phi": 0.26} for m in (0.1, 0.5, 0.9)]
    elif command == "shapes":
        vals = [{"shape": sh, "W_over_db": r, "d_b": 140e-6}
                for r in (1.7, 1.2) for sh in ("square", "circle")]
    else:
        vals = [{"shape": "regular_polygon", "n_vertices": v, "W_over_db": 1.2, "d_b": 140e-6}
                for v in (3, 4, 6)] + [{"shape": "circle", "n_vertices": 0, "W_over_db": 1.2,
                                         "d_b": 140e-6}]
    runs = [_fake_run(v, str(v), rng, censor_at=(0 if i == 0 else (15 if i == 1 else None)))
            for i, v in enumerate(vals)]
    rows = [figures._point_row(command, r) for r in runs]
    # nothing clogged: no estimate, the one-sided lower bound (issue 46)
    assert rows[0]["n_clogged"] == 0 and rows[0]["mean_s"] is None
    assert rows[0]["mean_s_lower_bound"] == rows[0]["mean_s_lo"] > 0
    if command != "escapees-time":      # its line gives the escape rate, no <s>
        said = stats.estimate_text(None, None, rows[0]["mean_s_lower_bound"])
        assert f"<s> {said}," in figures.summary_line(command, runs[0], rows[0])
        assert said.endswith("(nothing clogged; 95 % lower bound)")
    pmfs = [stats.pmf_bins(*r.samples()) for r in runs]
    png = tmp_path / f"{command}.png"
    figures.render(command, runs, rows, pmfs, png, "test")
    check_png(png)


# ------------------------------------------------------------------ one quick command

def test_a_figure_point_says_where_it_is_while_it_runs(tmp_path, capsys, monkeypatch):
    """Before: a figure's point printed nothing until it ended (13-21 s a quick
    point, minutes at 100 realizations); now its set-up and its time, as a
    sweep's point does (every PointProgress.EVERY s: 0 here, so at each check)."""
    from taichi_hsdem.studies import progress
    monkeypatch.setattr(progress.PointProgress, "EVERY", 0.0)
    out = tmp_path / "fig8"
    rc = figures.main(["escapees-time", "--quick", "--phi", "0.26", "--set", "run.t_end=0.05",
                       "--realizations", "2", "--out", str(out)])
    assert rc == 0
    err = capsys.readouterr().err.splitlines()
    assert any(line.startswith("[1/1] phi=0.26: setting up: ") for line in err), err
    times = [line for line in err if line.startswith("[1/1] phi=0.26: t = ")]
    assert len(times) >= 2 and times[-1].split("t = ")[1].startswith(("0.04", "0.05")), times


def test_escapees_time_quick(tmp_path, capsys, monkeypatch):
    out = tmp_path / "fig8"
    args = ["escapees-time", "--quick", "--phi", "0.26", "--set", "run.t_end=0.3",
            "--out", str(out), "--quiet"]
    rc = figures.main(args + ["--realizations", "2"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "phi=0.26:" in printed and f"wrote {out}" in printed
    for name in ("escapees-time.png", "points.csv", "realizations.csv", "series.csv",
                 "figure.json"):
        assert (out / name).exists(), name
    check_png(out / "escapees-time.png")

    # Q, H, d straight from the scene file
    raw = tomllib.loads((ROOT / "scenes" / "vani_phi026.toml").read_text())
    q, h, d = raw["fluid"]["flow_rate"], raw["fluid"]["gap"], raw["particles"][0]["diameter"]
    series = read_csv(out / "series.csv")
    assert series
    for r in series:
        phi, t = float(r["phi"]), float(r["t"])
        assert float(r["theory_escapees"]) == pytest.approx(4 * phi * q * t / (h * math.pi * d * d),
                                                            rel=1e-12, abs=1e-15)
    (pt,) = read_csv(out / "points.csv")
    assert float(pt["theory_rate"]) == pytest.approx(4 * 0.26 * q / (h * math.pi * d * d))
    assert int(pt["n_ok"]) + int(pt["n_unstable"]) == int(pt["realizations"]) == 2

    # each realization's final count is its last sample; the fitted rate is the
    # pooled count from each first escape on, recomputed here from the CSVs
    reals = {int(r["seed"]): r for r in read_csv(out / "realizations.csv")}
    assert len(reals) == 2
    per = {}
    for r in series:
        per.setdefault(int(r["seed"]), []).append((float(r["t"]), int(r["escapees"])))
    events, duration = 0, 0.0
    for seed, pts in per.items():
        pts.sort()
        assert reals[seed]["status"] == "ok"
        assert pts[-1][1] == int(reals[seed]["escapees"])
        assert all(b[1] >= a[1] for a, b in zip(pts, pts[1:]))     # counts never fall
        first = next((p for p in pts if p[1] >= 1), None)
        if first is None:
            continue
        if reals[seed]["clogged"] == "1":
            last = next(p for p in pts if p[1] == pts[-1][1])
        else:
            last = pts[-1]
        events += last[1] - first[1]
        duration += last[0] - first[0]
    if duration > 0:
        assert float(pt["rate"]) == pytest.approx(events / duration)
        assert float(pt["rate_ratio"]) == pytest.approx(float(pt["rate"]) / float(pt["theory_rate"]))
    else:
        assert math.isnan(float(pt["rate"]))

    # Resumable: the finished point was kept, and the same command reads it back
    # instead of running it (the outputs come out the same) ...
    assert (out / "points" / "phi=0.26.json").is_file()
    # with every realization's final state, for tools/arches.py: one per seed, a
    # pose per particle slot, read back as kept
    kept = json.loads((out / "points" / "phi=0.26.json").read_text())
    assert sorted(kept["finals"]) == sorted(str(r["seed"]) for r in kept["rows"])
    for state in kept["finals"].values():
        n = len(state["species"])
        assert n >= 1 and len(state["x"]) == len(state["theta"]) == len(state["alive"]) == n
        assert all(len(xy) == 2 for xy in state["x"])
    path = out / "points" / "phi=0.26.json"
    back = points.load_point(path, kept["key"], points.Point("phi=0.26", {}, None))
    assert back.finals == {int(k): v for k, v in kept["finals"].items()}
    written = {n: (out / n).read_text() for n in ("points.csv", "realizations.csv",
                                                   "series.csv")}

    class Ran(Exception):
        pass

    def ran(*args, **kwargs):
        raise Ran

    monkeypatch.setattr(figures, "run_point", ran)
    assert figures.main(args + ["--realizations", "2"]) == 0
    for name, text in written.items():       # the point's wall time is the run's
        assert (out / name).read_text() == text, name
    assert json.loads((out / "figure.json").read_text())["points"][0]["resumed"] is True
    assert "read back" in capsys.readouterr().out
    # ... but runs it again for another realization count, on request, or when the
    # package code changed (a new default, a fixed bug)
    with pytest.raises(Ran):
        figures.main(args + ["--realizations", "3"])
    with pytest.raises(Ran):
        figures.main(args + ["--realizations", "2", "--no-resume"])
    monkeypatch.setattr(points, "code_digest", lambda: "0" * 64)
    with pytest.raises(Ran):
        figures.main(args + ["--realizations", "2"])


# ------------------------------------------------------------------ the others (slow)

def _check_stat_outputs(out, name, n_points):
    check_png(out / f"{name}.png")
    points = read_csv(out / "points.csv")
    assert len(points) == n_points
    reals = read_csv(out / "realizations.csv")
    for p in points:
        mine = [r for r in reals if r["label"] == p["label"] and r["status"] == "ok"]
        assert int(p["n_ok"]) == len(mine)
        assert int(p["n_clogged"]) == sum(r["clogged"] == "1" for r in mine)
        assert int(p["n_censored"]) == len(mine) - int(p["n_clogged"])
        if mine:
            s = [int(r["escapees"]) for r in mine]
            c = [r["clogged"] == "1" for r in mine]
            mean, (lo, _) = stats.mean_escapees(s, c)
            if math.isfinite(mean):
                assert float(p["mean_s"]) == pytest.approx(mean)
            else:       # nothing clogged: no estimate, the lower bound in its column
                assert p["mean_s"] == "" and float(p["mean_s_lower_bound"]) == pytest.approx(lo)
    pmf = read_csv(out / "pmf.csv")
    for p in points:
        rows = [r for r in pmf if r["label"] == p["label"]]
        if rows:
            # normalised by every stable realization: with censoring the PMF
            # integrates to the clogged fraction (README, statistics)
            assert sum(float(r["pmf"]) * float(r["bin_width_x"]) for r in rows) == \
                pytest.approx(int(p["n_clogged"]) / int(p["n_ok"]))
            assert sum(int(r["count"]) for r in rows) == int(p["n_clogged"])
    return points


@pytest.mark.slow
def test_pmf_collapse_quick(tmp_path):
    out = tmp_path / "fig9"
    assert figures.main(["pmf-collapse", "--quick", "--out", str(out), "--quiet"]) == 0
    _check_stat_outputs(out, "pmf-collapse", 3)


def test_friction_quick_clogs(tmp_path):
    """The quick disk figures run long enough to clog (before: 0.5 s, every point
    "0 clogged" and its <s> a lower bound)."""
    out = tmp_path / "fig10"
    assert figures.main(["friction", "--quick", "--out", str(out), "--quiet"]) == 0
    points = _check_stat_outputs(out, "friction", 3)
    assert [float(p["mu"]) for p in points] == [0.1, 0.5, 0.9]
    assert all(int(p["n_clogged"]) >= 1 for p in points), points
    assert sum(int(p["n_clogged"]) for p in points) >= 6     # of 9: 9 here, seeds fixed
    assert all(p["mean_s"] not in ("", None) for p in points)


@pytest.mark.slow
def test_shapes_quick(tmp_path):
    out = tmp_path / "fig11"
    assert figures.main(["shapes", "--quick", "--out", str(out), "--quiet"]) == 0
    points = _check_stat_outputs(out, "shapes", 4)
    assert {p["contact_path"] for p in points} == {"disk", "level-set"}


@pytest.mark.slow
def test_polygons_quick(tmp_path):
    out = tmp_path / "fig13"
    assert figures.main(["polygons", "--quick", "--out", str(out), "--quiet"]) == 0
    points = _check_stat_outputs(out, "polygons", 4)
    assert [int(p["n_vertices"]) for p in points] == [3, 4, 6, 0]


def test_points_that_would_share_a_kept_file_are_refused(tmp_path, capsys):
    # Two points with one label would overwrite each other's kept results and
    # be indistinguishable in points.csv: refused before anything runs.
    rc = figures.main(["pmf-collapse", "--phi", "0.26", "0.26", "--out", str(tmp_path / "f"),
                       "--quiet"])
    assert rc == 2
    assert "would share" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()
