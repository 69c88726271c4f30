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
