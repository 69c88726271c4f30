"""Messages that say the true reason in the user's keys (issue 45, item 7): a flag
and a ``--set`` of the same key are refused rather than one silently winning; a
run.dt too small for t_end is told to raise run.dt, not to soften contacts."""
from pathlib import Path

import pytest

from taichi_hsdem.cli import main

ROOT = Path(__file__).resolve().parents[1]
HOURGLASS = str(ROOT / "scenes" / "hourglass24.toml")


@pytest.mark.parametrize("flag, setting", [
    (["--realizations", "2"], "run.realizations=1e3"),
    (["--realizations", "2"], "run.realizations=true"),
    (["--seed", "4"], "run.seed=5"),
    (["--no-video"], "output.video=true"),
    (["--arch", "cpu"], 'run.arch="auto"'),
])
def test_a_flag_and_a_set_of_the_same_key_are_refused(tmp_path, capsys, flag, setting):
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), *flag, "--set", setting, "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    key = setting.partition("=")[0]
    assert err == [f"--set {setting} and {flag[0] if flag[0] != '--no-video' else '--video/--no-video'} "
                   f"both set {key}: give one"]
    assert not out.exists()


def test_a_flag_alone_and_a_set_of_another_key_are_fine(tmp_path):
    assert main([HOURGLASS, "--out", str(tmp_path / "o"), "--realizations", "1",
                 "--set", "run.t_end=0.05", "--no-video", "--quiet"]) == 0


def test_a_tiny_run_dt_is_told_to_raise_run_dt(tmp_path, capsys):
    assert main([HOURGLASS, "--out", str(tmp_path / "o"), "--set", "run.dt=1e-30",
                 "--set", "run.t_end=0.1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "run.dt: run.dt 1e-30 s would take 1e+29 steps" in err
    assert err.strip().endswith("lower run.t_end, or raise run.dt") and "soften" not in err


@pytest.mark.parametrize("damage, reason", [("{", "is damaged: "),
                                            ('{"files": 3}', "does not list files")])
def test_a_damaged_record_of_a_runs_files_is_named_as_the_reason(tmp_path, capsys,
                                                                 damage, reason):
    from taichi_hsdem import output
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), "--set", "run.t_end=0.05", "--no-video",
                 "--quiet"]) == 0
    (out / output.MANIFEST).write_text(damage)
    before = sorted(p.name for p in out.iterdir())
    assert main([HOURGLASS, "--out", str(out), "--set", "run.t_end=0.05", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and output.MANIFEST in err[0] and reason in err[0], err
    assert "no run of taichi_hsdem wrote" not in err[0] and "summary.json" in err[0]
    assert sorted(p.name for p in out.iterdir()) == before


def test_a_checkpoint_is_read_from_one_open_file(tmp_path, monkeypatch):
    """The header and the arrays come from one open file: a run replacing its
    checkpoint while --resume reads it (its next one) cannot mix the two."""
    import os
    import shutil

    import numpy as np

    from taichi_hsdem import checkpoint
    from taichi_hsdem.scene import load_scene
    from taichi_hsdem.scene.toml import parse_toml
    from taichi_hsdem.simulation import Simulation

    first, later = tmp_path / "first", tmp_path / "later"
    assert main([HOURGLASS, "--out", str(first), "--realizations", "1", "--set",
                 "run.t_end=0.05", "--no-video", "--quiet"]) == 0
    assert main(["--resume", str(first), "--out", str(later), "--set", "run.t_end=0.1",
                 "--quiet"]) == 0
    path = tmp_path / checkpoint.FILE
    shutil.copy(first / checkpoint.FILE, path)
    header = checkpoint.read_header(path)
    with np.load(path) as data:
        x_first = data["bodies.x"]
    with np.load(later / checkpoint.FILE) as data:
        assert not np.array_equal(data["bodies.x"], x_first)     # the test can fail
    sim = Simulation(load_scene(parse_toml(header["scene"])), place_particles=False)
    check = checkpoint._check_progress

    def replace_then_check(*args):
        os.replace(shutil.copy(later / checkpoint.FILE, tmp_path / "next.npz"), path)
        return check(*args)
    monkeypatch.setattr(checkpoint, "_check_progress", replace_then_check)
    restored = checkpoint.restore(sim, path)
    assert restored["host"]["t"] == header["host"]["t"] == sim.t
    assert np.array_equal(sim.bodies.x.to_numpy(), x_first)


def test_a_second_start_after_a_refused_one_is_refused_alike(tmp_path):
    """A sweep under ``ulimit -v``: its first point was refused in one line, the
    second gave "internal error (KeyError: 'request')" (the failed start had left
    the backend half recorded). Each start now fails the same way."""
    import subprocess
    import sys
    import textwrap
    code = textwrap.dedent("""
        import taichi as ti
        def failing_init(**kwargs):
            raise RuntimeError("[host_memory_pool.cpp:allocate_raw_memory@62] Virtual "
                               "memory allocation (1073741824 B) failed.")
        ti.init = failing_init
        from taichi_hsdem import backend
        for _ in range(2):
            try:
                backend.init("cpu", "f64")
            except backend.AddressSpaceLimit as exc:
                print("refused:", str(exc)[:40])
        """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("refused: Taichi could not reserve") == 2, proc.stdout


def test_a_limited_address_space_is_said_in_one_line(tmp_path):
    """Under ``ulimit -v`` Taichi's first reservation fails (a RuntimeError from
    its C++ memory pool, seen at 1.5 GB): one line naming the limit, exit 2, not
    "internal error"; here Taichi's failure is made to happen."""
    import subprocess
    import sys
    import textwrap
    out = tmp_path / "o"
    code = textwrap.dedent(f"""
        import sys
        import taichi as ti
        def failing_init(**kwargs):
            print("[E host_memory_pool.cpp] Virtual memory allocation (1073741824 B) "
                  "failed.", file=sys.stderr)
            raise RuntimeError("[host_memory_pool.cpp:allocate_raw_memory@62] Virtual "
                               "memory allocation (1073741824 B) failed.")
        ti.init = failing_init
        from taichi_hsdem.cli import main
        sys.exit(main([{HOURGLASS!r}, "--out", {str(out)!r}, "--quiet"]))
        """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and lines[0].startswith(
        "Taichi could not reserve the 1 GiB of address space it starts with"), lines
    assert "ulimit -v" in lines[0] and not out.exists()


@pytest.mark.parametrize("command", ["sweep", "figures", "calibrate", "arches"])
@pytest.mark.parametrize("error, start", [
    (ValueError("boom"), "internal error (ValueError: boom); this is a bug of taichi_hsdem"),
    (MemoryError(), "out of memory: the study needs more memory"),
])
def test_a_study_that_fails_inside_says_one_line_not_a_traceback(monkeypatch, capsys,
                                                                 command, error, start):
    """An exception no check of a study caught (a defect, or memory running out) is
    one line and exit 1, as for a run; TAICHI_HSDEM_DEBUG=1 gives the traceback."""
    import importlib

    from taichi_hsdem.cli import COMMANDS
    module = importlib.import_module(f"taichi_hsdem.studies.{COMMANDS[command]}")

    def failing(argv, prog):
        raise error
    monkeypatch.setattr(module, "main", failing)
    monkeypatch.delenv("TAICHI_HSDEM_DEBUG", raising=False)
    assert main([command, "x.toml"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(start), err
    assert "Traceback" not in err[0]
    monkeypatch.setenv("TAICHI_HSDEM_DEBUG", "1")
    if not isinstance(error, MemoryError):
        with pytest.raises(type(error)):
            main([command, "x.toml"])


def _hourglass_with(**changes):
    """The hourglass scene as a dict, with top-level ``changes``."""
    from taichi_hsdem.scene.toml import parse_toml
    raw = parse_toml(Path(HOURGLASS).read_text())
    raw.update(changes)
    return raw


@pytest.mark.parametrize("where, key", [("name", "name"),
                                        ("species", "particles[0].name")])
def test_a_control_character_in_a_name_is_refused(tmp_path, capsys, where, key):
    """A scene's name becomes folder names and terminal text: an ESC in it (a
    terminal's colour escape) is refused naming the key, nothing written."""
    text = Path(HOURGLASS).read_text()
    if where == "name":
        text = text.replace('name = "hourglass24"', 'name = "hg\\u001b[31mred"')
    else:
        text = text.replace('name = "small"', 'name = "sm\\u001ball"')
    scene = tmp_path / "esc.toml"
    scene.write_text(text)
    out = tmp_path / "o"
    assert main([str(scene), "--out", str(out), "--set", "run.t_end=0.05", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{scene}: {key}: holds the control "
                                               "character U+001B"), err
    assert "\x1b" not in err[0] and not out.exists()


@pytest.mark.parametrize("vertices, problem", [
    ([[0, 0], [1, 1], [1, 0], [0, 1]],
     "edges 0 and 2 cross or touch: the polygon is self-intersecting (not simple)"),
    ([[0, 0], [1, 0], [2, 0], [3, 0]],
     "the polygon has zero area (its vertices lie on one line)"),
])
def test_a_bow_tie_polygon_is_self_intersecting_not_of_zero_area(vertices, problem):
    """A bow tie's signed area is zero (its lobes cancel), but what is wrong is
    that two edges cross; "zero area" stays for vertices on one line."""
    from taichi_hsdem.scene import SceneError, load_scene
    raw = _hourglass_with()
    raw["particles"][0] = {**raw["particles"][0], "shape": "polygon",
                           "vertices": vertices}
    raw["particles"][0].pop("diameter")
    with pytest.raises(SceneError) as info:
        load_scene(raw)
    assert info.value.problems == [f"<dict>: particles[0].vertices: {problem}"]


def test_a_resumes_bad_set_is_prefixed_with_the_checkpoint_not_dict(tmp_path, capsys):
    """A continued run's scene comes from its checkpoint: a refused --set names
    that file, not "<dict>"."""
    from taichi_hsdem import checkpoint
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), "--realizations", "1", "--set",
                 "run.t_end=0.05", "--no-video", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["--resume", str(out), "--set", "run.t_end=-1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"{out / checkpoint.FILE} (--set run.t_end=-1): run.t_end: must be > 0, "
                   "got -1.0"], err


def test_a_micromodel_pillar_too_small_to_resolve_is_said_in_its_key(tmp_path, capsys):
    """A pillar diameter far below the channel's size made the pillars' polygons
    collinear in float64, reported as "geometry: obstacle 0: the polygon has no
    area"; it is said on geometry.pillar_diameter, with the limit."""
    scene = str(ROOT / "scenes" / "micromodel.toml")
    out = tmp_path / "o"
    assert main([scene, "--out", str(out), "--set", "geometry.pillar_diameter=1e-12",
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "geometry.pillar_diameter: 1e-12 is too small" in err[0], err
    assert "at least 1e-06 of it" in err[0] and "obstacle" not in err[0]
    assert not out.exists()


def test_plotting_keeps_library_warnings_off_the_terminal(tmp_path):
    """matplotlib's warnings (a legend with no labelled line when every point
    failed, a glyph missing from the font for a name in CJK) came with a source
    line of ours on stderr; the figures are drawn without them."""
    import warnings

    from taichi_hsdem.studies import plots
    row = {"phi": 0.1, "rate": float("nan"), "rate_stderr": float("nan"),
           "flow_rate": 1.0, "gap": 1.0, "d_eq": 1.0, "t_first_mean": float("nan")}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plots.plot_escapees_time([], [row], tmp_path / "f.png", "meta")
        assert main([HOURGLASS, "--out", str(tmp_path / "o"), "--realizations", "1",
                     "--set", 'name="砂時計"', "--set", "run.t_end=0.05", "--no-video",
                     "--quiet"]) == 0
    assert (tmp_path / "f.png").is_file() and (tmp_path / "o" / "escapees.png").is_file()
    assert [str(w.message) for w in caught if issubclass(w.category, UserWarning)] == []


@pytest.mark.parametrize("size", [1e300, 1e-300])
def test_a_polygon_of_coordinates_past_the_magnitudes_is_said_so(size):
    """Vertices of 1e300 overflowed numpy (RuntimeWarnings with source lines on the
    terminal) and came out as "fluid.gap: must be > (2/3) d_eq = inf"; 1e-300 as
    "zero area": both are said as the coordinates' size, as for a number."""
    import warnings

    from taichi_hsdem.scene import SceneError, load_scene
    raw = _hourglass_with()
    raw["particles"][0] = {**raw["particles"][0], "shape": "polygon",
                           "vertices": [[0.0, 0.0], [size, 0.0], [0.0, size]]}
    raw["particles"][0].pop("diameter")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(SceneError) as info:
            load_scene(raw)
    assert len(info.value.problems) == 1, info.value.problems
    assert info.value.problems[0].startswith(
        f"<dict>: particles[0].vertices: its coordinates (up to {size:.3g} in size")
    assert "outside the magnitudes the simulator computes with" in info.value.problems[0]


@pytest.mark.parametrize("when", ["exit handlers", "finalization"])
def test_a_signal_as_a_study_process_winds_down_keeps_its_outcome(tmp_path, when):
    """A signal after a study's main returned (Taichi's exit handlers, then the
    interpreter's finalization, which gives a Python handler's signal back its
    default action) killed the process silently (-2, found by the fuzzer) or
    printed a traceback from an exit handler: during the exit handlers it says the
    study had ended and exits 128 + its number, later it is ignored."""
    import subprocess
    import sys
    import textwrap
    kill = ("atexit.register(lambda: (os.kill(os.getpid(), signal.SIGTERM), "
            "time.sleep(0.5)))")
    code = textwrap.dedent(f"""
        import atexit, os, signal, sys, time
        {kill if when == "finalization" else ""}
        from taichi_hsdem.stop import raise_stop
        for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(s, raise_stop)
        from taichi_hsdem.cli import main
        {kill if when == "exit handlers" else ""}
        sys.argv = ["taichi_hsdem", "sweep", "--help"]
        sys.exit(main())
        """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    if when == "exit handlers":
        assert proc.returncode == 143, proc.stderr
        assert lines == ["sweep stopped by SIGTERM after it had ended: what it wrote is "
                         "complete"], lines
    else:
        assert proc.returncode == 0 and lines == [], (proc.returncode, proc.stderr)


@pytest.mark.parametrize("seed, realizations", [(2 ** 63, 1), (2 ** 63 - 2, 3)])
def test_a_seed_past_64_bits_is_refused_before_the_run(tmp_path, capsys, seed, realizations):
    """run.seed = 2^63 ran to its end and then failed writing final_state.npz
    (OverflowError, "internal error", found by the fuzzer): refused on run.seed."""
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), "--realizations", str(realizations),
                 "--set", f"run.seed={seed}", "--set", "run.t_end=0.05", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"run.seed: must be at most {2 ** 63 - realizations}" in err[0]
    assert not out.exists()


def test_the_largest_seed_runs(tmp_path):
    assert main([HOURGLASS, "--out", str(tmp_path / "o"), "--realizations", "1", "--set",
                 f"run.seed={2 ** 63 - 1}", "--set", "run.t_end=0.05", "--no-video",
                 "--quiet"]) == 0


def test_plots_that_cannot_be_drawn_leave_the_results_and_say_so(tmp_path, monkeypatch,
                                                                 capsys):
    """Under ``ulimit -v 2000000`` matplotlib's compiled part could not be mapped
    ("ImportError: ... failed to map segment from shared object") and the whole
    run was lost as "internal error". Now the results are written, without plots,
    and one line and the summary say why."""
    import json

    from taichi_hsdem import report

    def cannot_map(*args, **kwargs):
        raise ImportError("_backend_agg.so: failed to map segment from shared object")
    monkeypatch.setattr(report, "plot_run", cannot_map)
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), "--set", "run.t_end=0.05", "--no-video"]) == 0
    err = capsys.readouterr().err
    assert "plots skipped: they could not be drawn (ImportError: " in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["plots"]["skipped"].endswith("the results are complete")
    assert (out / "escapees.csv").exists() and not list(out.glob("*.png"))


def test_a_forced_time_step_is_not_told_to_stiffen_the_contacts():
    """With run.dt set by the scene, a stiffer kn lowers the critical step further
    below it: the advice after an instability was "raise the particles' kn"."""
    from types import SimpleNamespace

    from taichi_hsdem import load_scene
    from taichi_hsdem.runner import unstable_hint, unstable_message
    auto = load_scene(HOURGLASS, [])
    fixed = load_scene(HOURGLASS, ["run.dt=1e-5"])
    assert "raise the particles' kn" in unstable_hint(auto)
    assert "kn" not in unstable_hint(fixed) and unstable_hint(fixed).startswith("lower run.dt")
    result = SimpleNamespace(scene=fixed, summary={"realizations": [
        {"status": "unstable", "seed": 3}, {"status": "ok", "seed": 4}]})
    assert unstable_message(result) == (
        f"1 realization(s) went unstable (seeds 3): {unstable_hint(fixed)}")


def test_pillars_that_close_every_gap_on_the_grid_are_a_refusal(tmp_path, capsys):
    """pillar_diameter 345e-6 at a spacing of 350e-6 leaves 5 um gaps, closed on
    the 16.7 um fluid grid: "internal error (ValueError: no active cell of the
    inlet column ...)" before; one line naming the keys now, exit 2."""
    scene = str(ROOT / "scenes" / "micromodel.toml")
    out = tmp_path / "o"
    assert main([scene, "--out", str(out), "--set", "geometry.pillar_diameter=345e-6",
                 "--set", "run.t_end=0.01", "--no-video", "--quiet"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "geometry: on the fluid grid" in line and "no open path joins the inlet" in line
    assert "fluid.cell_size" in line and "pillar_spacing" in line
    assert not out.exists()
