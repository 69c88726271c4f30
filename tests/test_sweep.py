"""Sweeps (folders, table, resume, errors) and the calibration of one parameter."""
import csv
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

import taichi_hsdem.studies.sweep as sweep_module
from taichi_hsdem.studies.calibrate import calibrate
from taichi_hsdem.studies.sweep import (SweepError, expand_grid, load_sweep, point_folder,
                                        run_sweep)

ROOT = Path(__file__).resolve().parents[1]
HOURGLASS = ROOT / "scenes" / "hourglass24.toml"
TINY = {"run.t_end": 0.3}


def tool(name):
    """``tools/<name>.py`` as a module (tools/ is not a package)."""
    spec = importlib.util.spec_from_file_location(f"tool_{name}", ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------ points, files

def test_point_folder_is_stable_and_unique():
    assert point_folder({"run.seed": 7, "particles.friction": 0.4}) == \
        point_folder({"particles.friction": 0.4, "run.seed": 7}) == \
        "particles.friction=0.4,run.seed=7"
    assert point_folder({}) == "base"
    # characters a folder name should not hold are replaced, and a hash keeps the
    # two points apart
    a, b = point_folder({"feed.region": [1.0, 2.0]}), point_folder({"feed.region": [1.0, 2.5]})
    assert a != b and "/" not in a + b and " " not in a + b
    long = {f"particles.{k}.name": "n" * 40 for k in range(5)}
    other = dict(long, **{"particles.4.name": "m" * 40})
    assert len(point_folder(long)) <= 100 and point_folder(long) != point_folder(other)


def test_expand_grid_is_the_cartesian_product_last_key_fastest():
    assert expand_grid({"a": [1, 2], "b": [3, 4]}) == [
        {"a": 1, "b": 3}, {"a": 1, "b": 4}, {"a": 2, "b": 3}, {"a": 2, "b": 4}]


def test_load_sweep_reads_grid_points_and_common(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(f"""
scene = "{HOURGLASS.as_posix()}"
[common]
run.t_end = 0.5
[grid]
"particles.friction" = [0.2, 0.4]
run.seed = [1, 2]
[[points]]
"particles.friction" = 0.9
""")
    sweep = load_sweep(path)
    assert sweep.scene == HOURGLASS and sweep.common == {"run.t_end": 0.5}
    assert sweep.points == ({"particles.friction": 0.2, "run.seed": 1},
                            {"particles.friction": 0.2, "run.seed": 2},
                            {"particles.friction": 0.4, "run.seed": 1},
                            {"particles.friction": 0.4, "run.seed": 2},
                            {"particles.friction": 0.9})


def test_bad_sweep_file_lists_every_problem_and_exits_2(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(f"""
scene = "{HOURGLASS.as_posix()}"
[common]
"run.t_end" = -1.0
[grid]
"particles.frction" = [0.2]
[[points]]
"fluid.bc" = "sideways"
""")
    with pytest.raises(SweepError) as err:
        load_sweep(path)
    text = str(err.value)
    assert "common" in text and "run.t_end: must be > 0" in text
    assert "particles.frction: unknown key" in text and "friction" in text
    assert "fluid.bc: must be one of" in text
    assert text.count("run.t_end: must be > 0") == 1      # reported once, not per point
    out = tmp_path / "out"
    assert tool("sweep").main([str(path), "--out", str(out), "--quiet"]) == 2
    assert "unknown key" in capsys.readouterr().err and not out.exists()

    for text, expect in ((f'scene = "{HOURGLASS.as_posix()}"\n[grid]\n"run.seed" = 3\n',
                          "expected a non-empty list"),
                         (f'scene = "{HOURGLASS.as_posix()}"\nsceen = 1\n'
                          '[[points]]\n"run.seed" = 3\n', "did you mean 'scene'"),
                         ('scene = "missing.toml"\n[[points]]\n"run.seed" = 3\n', "not a file"),
                         (f'scene = "{HOURGLASS.as_posix()}"\n', "nothing to sweep"),
                         (f'scene = "{HOURGLASS.as_posix()}"\n[[points]]\n"run.seed" = 3\n'
                          '[[points]]\n"run.seed" = 3\n', "repeats point 0"),
                         (f'scene = "{HOURGLASS.as_posix()}"\n[[points]]\n"run.seed" = 3\n'
                          '[[points]]\n"run.precision" = "f32"\n', "one Taichi backend")):
        path.write_text(text)
        with pytest.raises(SweepError, match=expect):
            load_sweep(path)


# ------------------------------------------------------------------ running, resume

def test_sweep_writes_folders_and_table_then_resumes(tmp_path, capsys, monkeypatch):
    out = tmp_path / "sweep"
    points = [{"particles.friction": 0.2}, {"particles.friction": 0.4}]
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text(f'scene = "{HOURGLASS.as_posix()}"\n[common]\n"run.t_end" = 0.3\n'
                          '[grid]\n"particles.friction" = [0.2, 0.4]\n')
    # First run through the command line.
    assert tool("sweep").main([str(sweep_file), "--out", str(out), "--quiet"]) == 0
    folders = [out / point_folder(p) for p in points]
    assert [f.name for f in folders] == ["particles.friction=0.2", "particles.friction=0.4"]
    for folder, point in zip(folders, points):
        for name in ("summary.json", "escapees.csv", "scene.resolved.toml"):
            assert (folder / name).is_file(), (folder, name)
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["sweep"]["overrides"] == point and summary["t_end"] == 0.3
        assert f"friction = {point['particles.friction']}" in (
            folder / "scene.resolved.toml").read_text()
    with (out / "sweep.csv").open() as fh:
        table = list(csv.DictReader(fh))
    assert [r["folder"] for r in table] == [f.name for f in folders]
    assert [float(r["particles.friction"]) for r in table] == [0.2, 0.4]
    for row, folder in zip(table, folders):
        summary = json.loads((folder / "summary.json").read_text())
        st = summary["statistics"]
        assert int(row["n"]) == len(summary["realizations"]) == 1
        assert int(row["n_clogged"]) == st["n_clogged"]
        assert row["never_clogged_fraction"] == repr(st["never_clogged_fraction"])
        for name in ("mean_escapees_ci_lo", "mean_escapees_ci_hi", "decay_rate",
                     "decay_rate_ci_lo", "decay_rate_ci_hi"):
            assert name in row
    index = json.loads((out / "index.json").read_text())
    assert index["points"] == {f.name: p for f, p in zip(folders, points)}
    stamps = [(f / "summary.json").stat().st_mtime_ns for f in folders]

    # Second run: both finished, nothing runs.
    messages = []
    rows = run_sweep(HOURGLASS, points, out, common=TINY, progress=messages.append)
    assert [r["status"] for r in rows] == ["skipped", "skipped"]
    # each point says it was skipped; a point of this 0.3 s sweep without an
    # estimate of <s> is named once at the end
    assert all("skipped" in m or "have no estimate of <s>" in m for m in messages)
    assert sum("skipped" in m for m in messages) == 2
    assert [(f / "summary.json").stat().st_mtime_ns for f in folders] == stamps
    assert rows[0]["n"] == 1 and rows[0]["never_clogged_fraction"] is not None

    # A point whose summary is gone (interrupted) is run again, the other is not.
    (folders[1] / "summary.json").unlink()
    rows = run_sweep(HOURGLASS, points, out, common=TINY)
    assert [r["status"] for r in rows] == ["skipped", "ran"]
    assert (folders[0] / "summary.json").stat().st_mtime_ns == stamps[0]
    assert (folders[1] / "summary.json").is_file()

    # The same folder with other overrides (here the common t_end: the sweep file
    # edited, the same study) is not finished.
    study = str(sweep_file.resolve())
    rows = run_sweep(HOURGLASS, points[:1], out, common={"run.t_end": 0.2}, study=study)
    assert rows[0]["status"] == "ran"
    assert json.loads((folders[0] / "summary.json").read_text())["t_end"] == 0.2
    # ... and resume=False runs a finished point again
    assert run_sweep(HOURGLASS, points[:1], out, common={"run.t_end": 0.2},
                     resume=False, study=study)[0]["status"] == "ran"
    assert run_sweep(HOURGLASS, points[:1], out,
                     common={"run.t_end": 0.2})[0]["status"] == "skipped"
    # ... and so does other package code (a changed default must not pass stale
    # results off as current)
    monkeypatch.setattr(sweep_module, "code_digest", lambda: "0" * 64)
    assert run_sweep(HOURGLASS, points[:1], out,
                     common={"run.t_end": 0.2}, study=study)[0]["status"] == "ran"


def test_run_sweep_refuses_bad_points_before_running(tmp_path):
    with pytest.raises(SweepError, match="particles.frction: unknown key"):
        run_sweep(HOURGLASS, [{"run.t_end": 0.1}, {"particles.frction": 0.4}], tmp_path / "o")
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------- calibration

def geometric_evaluator(mean_of, realizations, seed, cap=None):
    """A stand-in for the simulation: ``s`` geometric with ``<s> = mean_of(x)``,
    right-censored at ``cap`` (a run that ended before its clog)."""
    rng = np.random.default_rng(seed)

    def evaluate(x):
        s = rng.geometric(1.0 / (1.0 + mean_of(x)), realizations) - 1
        clogged = np.ones(realizations, bool)
        if cap is not None:
            clogged = s <= cap
            s = np.minimum(s, cap)
        return s.tolist(), clogged.tolist()
    return evaluate


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_calibrate_recovers_a_known_parameter(seed):
    # <s> falls with mu ("hyperbolic", Fig. 10): 20 at mu* = sqrt(0.8 / 18)
    def mean_of(mu):
        return 2.0 + 0.8 / mu ** 2
    mu_star = math.sqrt(0.8 / 18.0)
    cal = calibrate(geometric_evaluator(mean_of, 100, seed, cap=80), target=20.0,
                    lo=0.1, hi=0.9, rounds=8)
    assert cal.bracketed and cal.converged and not any(cal.ci_open)
    assert cal.ci[0] <= mu_star <= cal.ci[1]
    assert cal.ci[0] <= cal.value <= cal.ci[1]
    assert cal.ci[1] - cal.ci[0] < 0.08                 # an interval that says something
    assert abs(cal.value - mu_star) < 0.03
    assert len(cal.evaluations) == 8 and cal.evaluations[0].value == 0.1
    assert any(not c for e in cal.evaluations for c in e.clogged)   # censoring was used


def test_calibrate_interval_covers_the_truth_in_most_runs():
    """The stated interval is a 95 % one: over 40 independent calibrations of an
    increasing <s> it must hold the true value in most of them."""
    def mean_of(x):
        return 2.0 * math.exp(3.0 * x)
    x_star = math.log(5.0) / 3.0
    hits = 0
    for seed in range(40):
        cal = calibrate(geometric_evaluator(mean_of, 30, 100 + seed), target=10.0,
                        lo=0.0, hi=1.0, rounds=6)
        hits += cal.ci[0] <= x_star <= cal.ci[1]
    assert hits >= 34            # P(<= 33 of 40) < 1e-2 at 95 % coverage


def test_calibrate_reports_a_target_out_of_range():
    cal = calibrate(geometric_evaluator(lambda mu: 5.0, 50, 0), target=20.0, lo=0.1, hi=0.9)
    assert not cal.bracketed and not cal.converged and math.isnan(cal.value)
    assert "not bracketed" in cal.message and len(cal.evaluations) == 2
    json.dumps(cal.to_dict(), allow_nan=False)


def test_calibrate_xtol_stops_early():
    cal = calibrate(geometric_evaluator(lambda mu: 40.0 * math.exp(-4.0 * mu), 400, 3),
                    target=10.0, lo=0.0, hi=1.0, rounds=12, xtol=0.1)
    assert cal.converged and cal.ci[1] - cal.ci[0] < 0.1 and len(cal.evaluations) < 12


def test_calibrate_tool_checks_its_arguments(tmp_path, capsys):
    main = tool("calibrate").main
    out = tmp_path / "c"
    assert main([str(HOURGLASS), "--target", "20", "--lo", "0.9", "--hi", "0.1",
                 "--out", str(out)]) == 2
    assert "--lo 0.9 must be below --hi 0.1" in capsys.readouterr().err
    assert main([str(HOURGLASS), "--target", "20", "--lo", "0.1", "--hi", "0.9",
                 "--param", "particles.frction", "--out", str(out)]) == 2
    assert "unknown key" in capsys.readouterr().err
    assert main([str(HOURGLASS), "--target", "20", "--lo", "-0.1", "--hi", "0.9",
                 "--out", str(out)]) == 2
    assert "friction" in capsys.readouterr().err
    assert not out.exists()
