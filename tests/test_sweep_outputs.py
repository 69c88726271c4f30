"""What a sweep gives: quick points that run long enough to clog and record what
ran, ``--set`` for the whole sweep, a run's files in every point's folder (its own
lock), ``sweep.png``, and progress with the time left."""
import json
import math
import subprocess
import sys

import pytest

from taichi_hsdem import output
from taichi_hsdem.scene import load_scene
from taichi_hsdem.studies import progress, sweep_plot
from taichi_hsdem.studies.sweep import SweepError, command_line_sets, point_folder, \
    quick_overrides, run_sweep

from test_study_folders import HOURGLASS, sweep, sweep_file


# ----------------------------------------------------------------------- quick

def test_quick_keeps_each_point_s_t_end_and_records_what_ran(tmp_path, capsys):
    # before: a tenth of t_end (0.3 s of the vani scene's 3, before the first
    # escape) and summary/index.json saying the sweep file's realizations
    scene = load_scene(HOURGLASS, ["run.t_end=0.3", "run.realizations=3"])
    assert quick_overrides(scene) == {"run.realizations": 2}
    assert quick_overrides(load_scene(HOURGLASS, ["run.realizations=1"])) == \
        {"run.realizations": 1}
    code, err = sweep([sweep_file(tmp_path, frictions=(0.3,), realizations=3), "--quick",
                       "--out", tmp_path / "o"], capsys)
    assert code == 0, err
    folder = tmp_path / "o" / "quick" / point_folder({"particles.friction": 0.3})
    summary = json.loads((folder / "summary.json").read_text())
    assert len(summary["realizations"]) == 2
    assert summary["t_end"] == pytest.approx(0.3)
    assert summary["sweep"]["quick"] == {"run.realizations": 2}
    assert summary["sweep"]["common"] == {"run.t_end": 0.3, "run.realizations": 3}
    resolved = load_scene(folder / "scene.resolved.toml")
    assert (resolved.run.t_end, resolved.run.realizations) == (pytest.approx(0.3), 2)
    index = json.loads((tmp_path / "o" / "quick" / "index.json").read_text())
    assert index["quick"] == {folder.name: {"run.realizations": 2}}


# ----------------------------------------------------------------------- --set

def test_set_applies_to_every_point_and_a_swept_key_is_refused(tmp_path, capsys):
    path = sweep_file(tmp_path, frictions=(0.2, 0.4))
    out = tmp_path / "o"
    code, err = sweep([path, "--out", out, "--set", "run.t_end=0.1",
                       "--set", "particles.restitution=0.5"], capsys)
    assert code == 0, err          # before: "unrecognized arguments: --set", exit 2
    for mu in (0.2, 0.4):
        resolved = load_scene(out / point_folder({"particles.friction": mu})
                              / "scene.resolved.toml")
        assert resolved.run.t_end == pytest.approx(0.1)
        assert resolved.particles[0].restitution == pytest.approx(0.5)
        assert resolved.particles[0].friction == pytest.approx(mu)

    code, err = sweep([path, "--out", tmp_path / "p", "--set", "particles.friction=0.9"],
                      capsys)
    assert code == 2 and len(err) == 1, err
    assert "--set particles.friction" in err[0] and "varies" in err[0]
    code, err = sweep([path, "--out", tmp_path / "p", "--set", "run.t_end"], capsys)
    assert code == 2 and err == ["--set run.t_end: expected SECTION.KEY=VALUE"]
    code, err = sweep([path, "--out", tmp_path / "p", "--set", "run.t_end=-1"], capsys)
    assert code == 2 and any("run.t_end" in line for line in err), err
    assert not (tmp_path / "p").exists()


def test_command_line_sets_are_typed_as_a_scene_s_set():
    assert command_line_sets(["run.t_end=0.5", "run.arch=cpu", "a.b=[1, 2]"], []) == \
        {"run.t_end": 0.5, "run.arch": "cpu", "a.b": [1, 2]}
    with pytest.raises(SweepError) as info:
        command_line_sets(["=1", "x.y=2"], [{"x.y": 1}])
    assert len(info.value.problems) == 2


# ------------------------------------------------- a point is a run into its folder

def test_each_point_writes_a_run_s_files_and_a_held_point_folder_fails_alone(tmp_path):
    out = tmp_path / "o"
    held = out / point_folder({"particles.friction": 0.4})
    held.mkdir(parents=True)
    code = ("import fcntl, sys, time; fh = open(sys.argv[1], 'a+'); "
            "fcntl.flock(fh, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(held / output.LOCK)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        rows = run_sweep(HOURGLASS, [{"particles.friction": 0.2}, {"particles.friction": 0.4}],
                         out, common={"run.t_end": 0.3, "run.realizations": 1})
    finally:
        proc.kill()
        proc.wait()
    assert [r["status"] for r in rows] == ["ran", "failed"]
    assert "another run is writing" in rows[1]["message"]
    assert not (held / "summary.json").exists()
    ran = out / point_folder({"particles.friction": 0.2})
    names = {p.name for p in ran.iterdir()}
    # before: summary.json, escapees.csv, final_state.npz and the scene only
    assert {"arches.csv", "escapees.png", "summary.json", "escapees.csv",
            "final_state.npz", "scene.resolved.toml"} <= names
    assert not any(n.startswith(".incomplete-") or n == output.LOCK for n in names)
    assert "plots" in json.loads((ran / "summary.json").read_text())


# ---------------------------------------------------------------------- sweep.png

def row(value, mean=None, ci=(None, None), bound=None, n_ok=4, folder=None):
    return {"folder": folder or f"mu={value}", "overrides": {"particles.friction": value},
            "n_ok": n_ok, "mean_escapees": mean, "mean_escapees_ci": list(ci),
            "mean_escapees_lower_bound": bound}


def test_sweep_png_draws_intervals_and_lower_bounds(tmp_path):
    assert sweep_plot.estimate(row(0.1, 8.0, (5.0, 13.0))) == (8.0, 5.0, 13.0, False)
    assert sweep_plot.estimate(row(0.1, 8.0, (5.0, None))) == (8.0, 5.0, math.inf, False)
    # nothing clogged: the lower bound, open above; never a plain mean
    assert sweep_plot.estimate(row(0.9, None, bound=40.0)) == (40.0, 40.0, math.inf, True)
    assert sweep_plot.estimate(row(0.9, None, bound=None)) is None
    assert sweep_plot.estimate(row(0.9, 3.0, n_ok=0)) is None
    rows = [row(0.1, 8.0, (5.0, 13.0)), row(0.5, 20.0, (10.0, None)), row(0.9, bound=40.0)]
    assert sweep_plot.axes_of(rows) == ("particles.friction", [])
    for r, seed in zip(rows, (1, 2, 1)):
        r["overrides"]["run.seed"] = seed
    assert sweep_plot.axes_of(rows) == ("particles.friction", ["run.seed"])
    words = [{"overrides": {"run.arch": a}} for a in ("cpu", "vulkan")]
    assert sweep_plot.axes_of(words) == (None, ["run.arch"])
    path = tmp_path / "sweep.png"
    assert sweep_plot.plot_sweep(rows, path, title="t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sweep.png"]   # no temp left
    assert not sweep_plot.plot_sweep([], tmp_path / "empty.png")
    assert not (tmp_path / "empty.png").exists()


def test_sweep_png_is_drawn_when_no_point_has_an_estimate(tmp_path):
    """Before: a sweep whose points saw no escape and no clog (`--set
    run.t_end=0.3`) wrote no sweep.png and said nothing; now the points are
    crosses at the foot of the axes, named, and the sweep names them."""
    rows = [row(0.1, None), row(0.5, None), row(0.9, 3.0, n_ok=0)]
    assert sweep_plot.no_estimate(rows) == ["mu=0.1", "mu=0.5", "mu=0.9"]
    assert sweep_plot.plot_sweep(rows, tmp_path / "none.png")
    assert (tmp_path / "none.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    mixed = [row(0.1, 8.0, (5.0, 13.0)), row(0.5, None)]
    assert sweep_plot.no_estimate(mixed) == ["mu=0.5"]
    assert sweep_plot.plot_sweep(mixed, tmp_path / "mixed.png")


# ---------------------------------------------------------------------- progress

def test_progress_says_each_long_point_s_time_and_the_points_left(monkeypatch):
    clock = iter([0.0, 10.0, 20.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    eta = progress.Eta(3)                                   # t0 = 0
    assert eta.done() == "2 of 3 point(s) left, about 20 s"     # 10 s a point
    assert eta.done() == "1 of 3 point(s) left, about 10 s"
    assert eta.done() == ""                                     # the last
    assert progress.duration(600) == "10 min" and progress.duration(7200) == "2.0 h"

    lines = []
    times = iter([0.0, 2.0, 6.0, 7.0, 12.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(times))
    tell = progress.PointProgress(lines.append, "[1/2] mu=0.2")
    for t in (0.0, 0.1, 0.2, 0.3, 0.4):
        tell(t, 3.0)
    assert lines == ["[1/2] mu=0.2: t = 0.2 / 3 s, 6 s", "[1/2] mu=0.2: t = 0.4 / 3 s, 12 s"]


def test_calibrate_quick_runs_to_the_scene_s_t_end_and_keeps_the_user_s(tmp_path, monkeypatch,
                                                                      capsys):
    """Before: ``--quick`` added run.t_end = a tenth of the scene's after the user's
    ``--set``s, so no round clogged and a user's t_end was overridden."""
    from taichi_hsdem.studies import calibrate
    seen = {}

    def fake(scene, param, realizations, sets, seed=None, pool=None, progress=None):
        seen.update(realizations=realizations, sets=list(sets))

        def evaluate(value):           # <s> falls with the value: 2 / value
            s = max(1, round(2 / value))
            return [s] * realizations, [True] * realizations, \
                {"seed": 1, "n_unstable": 0, "wall_time_s": 0.0}
        return evaluate

    monkeypatch.setattr(calibrate, "simulation_evaluator", fake)
    args = [str(HOURGLASS), "--target", "5", "--lo", "0.1", "--hi", "0.9", "--quick",
            "--quiet", "--out"]
    calibrate.main(args + [str(tmp_path / "a")])
    assert seen == {"realizations": 4, "sets": []}
    report = json.loads((tmp_path / "a" / "calibration.json").read_text())
    assert report["set"] == [] and report["realizations_per_round"] == 4
    calibrate.main(args + [str(tmp_path / "b"), "--set", "run.t_end=0.7"])
    assert seen["sets"] == ["run.t_end=0.7"]
    capsys.readouterr()


def test_a_point_says_at_once_that_it_sets_up_then_its_slow_phases(monkeypatch):
    lines = []
    times = iter([0.0, 1.0, 7.0, 8.0, 14.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(times))
    tell = progress.PointProgress(lines.append, "[1/2] p")
    tell.phase("loading Taichi")             # 0 s: at once
    tell.phase("building the grid")          # 1 s: too soon after the last line
    tell.phase("compiling the kernels")      # 7 s: said
    tell(0.0, 3.0)                           # 8 s: the run starts
    tell(0.5, 3.0)                           # 14 s: 7 s since the last line
    assert lines == ["[1/2] p: setting up: loading Taichi",
                     "[1/2] p: set-up: compiling the kernels",
                     "[1/2] p: t = 0.5 / 3 s, 6 s"]


def test_a_calibration_round_run_here_says_its_set_up_and_progress(monkeypatch):
    """Before: a round ran silent (its runs got no progress; only its result line)."""
    from taichi_hsdem.studies import calibrate

    def fake(scene, progress=None):
        assert isinstance(progress, progress_module.PointProgress)
        progress.phase("starting Taichi (cpu)")
        return [{"status": "ok", "escapees": 3, "clogged": True}], 0.1

    progress_module = progress
    monkeypatch.setattr(calibrate, "run_realizations", fake)
    lines = []
    evaluate = calibrate.simulation_evaluator(HOURGLASS, "particles.friction", 1,
                                              progress=lines.append)
    assert evaluate(0.3)[:2] == ([3], [True])
    assert lines[-1] == "particles.friction = 0.3: setting up: starting Taichi (cpu)"
