"""The output folder's promises: a run never deletes or overwrites a file that no
run of this project wrote, never mixes two runs, and a failed run leaves the
earlier result exactly as it was; Ctrl-C is obeyed from the first moment."""
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from taichi_hsdem import output
from taichi_hsdem.cli import main

ROOT = Path(__file__).resolve().parents[1]
HOURGLASS = str(ROOT / "scenes" / "hourglass24.toml")
SHORT = ["--set", "run.t_end=0.2", "--quiet"]
UNSTABLE = ["--set", "run.dt=0.5", "--set", "run.force_dt=true", "--set", "run.t_end=30",
            "--quiet"]


def snapshot(folder: Path) -> dict:
    """Every file under ``folder`` (hidden ones too) with the hash of its bytes."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def user_folder(tmp_path) -> Path:
    out = tmp_path / "mine"
    (out / "vtk").mkdir(parents=True)
    (out / "vtk" / "thesis_figure.vtp").write_text("user data")
    (out / "video.mp4").write_bytes(b"my holiday video")
    (out / "notes.txt").write_text("keep me")
    return out


def test_a_folder_holding_the_users_files_of_result_names_is_refused(tmp_path, capsys):
    out = user_folder(tmp_path)
    before = snapshot(out)
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 2
    err = capsys.readouterr().err
    assert "video.mp4" in err and "vtk" in err and "no run of taichi_hsdem" in err
    assert len(err.strip().splitlines()) == 1
    assert snapshot(out) == before                       # not a byte changed
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "video.mp4", "vtk"]


def test_other_files_of_the_user_survive_runs_and_reruns(tmp_path, capsys):
    """A folder with the user's own notes: runs write beside them; a rerun that
    writes fewer files removes only the earlier run's."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    (out / "escapees.png.bak").write_text("also mine")
    assert main([HOURGLASS, "--out", str(out), *SHORT, "--vtk"]) == 0
    assert (out / "series.pvd").is_file() and (out / "vtk").is_dir()
    manifest = json.loads((out / output.MANIFEST).read_text())["files"]
    assert {"summary.json", "series.pvd", "vtk", "checkpoint.npz"} <= set(manifest)
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 0     # no --vtk this time
    assert not (out / "series.pvd").exists() and not (out / "vtk").exists()
    assert (out / "notes.txt").read_text() == "keep me"
    assert (out / "escapees.png.bak").read_text() == "also mine"
    assert "vtk" not in json.loads((out / output.MANIFEST).read_text())["files"]
    assert not [p for p in out.iterdir() if p.name.startswith((".incomplete", output.LOCK))]


def test_a_folder_of_an_earlier_version_without_manifest_is_a_run_folder(tmp_path, capsys):
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 0
    (out / output.MANIFEST).unlink()                  # as a run before manifests left it
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 0
    assert (out / output.MANIFEST).is_file()


def test_an_unstable_run_leaves_the_earlier_result_exactly_as_it_was(tmp_path, capsys):
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 0
    before = snapshot(out)
    capsys.readouterr()
    assert main([HOURGLASS, "--out", str(out), *UNSTABLE]) == 1
    err = capsys.readouterr().err
    assert "unstable" in err and "kept as it was" in err and "Traceback" not in err
    assert snapshot(out) == before                       # checkpoint included


def test_an_unstable_run_into_a_new_folder_is_marked_failed(tmp_path, capsys):
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), *UNSTABLE]) == 1
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed"                       # never complete-looking
    assert s["realizations"][0]["status"] == "unstable"


def test_two_runs_never_write_one_folder_at_once(tmp_path, capsys):
    out = tmp_path / "o"
    with output.Staging(out):                            # another run is writing it
        assert main([HOURGLASS, "--out", str(out), *SHORT]) == 2
        err = capsys.readouterr().err
        assert "another run is writing" in err
    assert not out.exists()                              # that run made it, and kept nothing


@pytest.mark.parametrize("make, expected", [
    (lambda d: "", "folder name is empty"),
    (lambda d: str(d / "a\x1bx"), "control character U+001B"),      # was echoed raw
    (lambda d: (os.symlink(d / "gone", d / "dangling"), str(d / "dangling"))[1],
     "does not exist"),
    (lambda d: (os.symlink(d / "loop", d / "loop"), str(d / "loop" / "x"))[1],
     "loop"),
    (lambda d: str(d / ("n" * 300)), "longer than 255 bytes"),
])
def test_odd_output_paths_are_refused_in_one_line(tmp_path, capsys, make, expected):
    target = make(tmp_path)
    assert main([HOURGLASS, "--out", target, *SHORT]) == 2
    err = capsys.readouterr().err
    assert expected in err.lower() or expected in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_resume_into_another_folder_does_not_mix_it_with_that_folders_run(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert main([HOURGLASS, "--out", str(b), *SHORT, "--vtk"]) == 0   # b: an unrelated run
    assert main([HOURGLASS, "--out", str(a), *SHORT]) == 0
    a_before = snapshot(a)
    assert main(["--resume", str(a), "--out", str(b), "--set", "run.t_end=0.3",
                 "--quiet"]) == 0
    assert snapshot(a) == a_before
    assert not (b / "vtk").exists() and not (b / "series.pvd").exists()
    s = json.loads((b / "summary.json").read_text())
    assert s["t_reached"] == pytest.approx(0.3, abs=1e-3)


def _sigint_during_setup(tmp_path, ignore_sigint: bool):
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "taichi_hsdem", HOURGLASS, "--out", str(out),
           "--set", "run.t_end=50", "--quiet"]
    pre = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignore_sigint else None
    proc = subprocess.Popen(cmd, cwd=tmp_path, stderr=subprocess.PIPE, text=True,
                            preexec_fn=pre)
    deadline = time.time() + 120
    # the staging folder appears once the scene is valid, before the simulation
    # is built (Taichi's kernels, placement, the first pressure solve)
    while time.time() < deadline and not (out.is_dir() and any(
            p.name.startswith(".incomplete") for p in out.iterdir())):
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=120)[1]
    return proc.returncode, err, out


@pytest.mark.parametrize("ignore_sigint", [False, True])
def test_ctrl_c_during_set_up_exits_130_and_writes_nothing(tmp_path, ignore_sigint):
    code, err, out = _sigint_during_setup(tmp_path, ignore_sigint)
    assert code == 130, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    if "set-up" in err:
        assert not out.exists()                          # it made the folder: gone again
    else:   # set-up had just ended: the run's first chunk kept, as the README says
        assert "interrupted at t =" in err
        assert json.loads((out / "summary.json").read_text())["status"] == "interrupted"


def test_ctrl_c_in_the_middle_of_set_up_is_obeyed_even_when_sigint_was_ignored(
        tmp_path, capsys, monkeypatch):
    """Ctrl-C while the simulation is being built (Taichi's kernels, placement, the
    first solve), in a process that started with SIGINT ignored as a script's
    background job does: exit 130, one line, nothing written."""
    from taichi_hsdem import runner
    build = runner.build

    def build_then_ctrl_c(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        return build(*args, **kwargs)

    monkeypatch.setattr(runner, "build", build_then_ctrl_c)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        code = main([HOURGLASS, "--out", str(tmp_path / "o"), *SHORT])
    finally:
        signal.signal(signal.SIGINT, previous)
    err = capsys.readouterr().err
    assert code == 130 and err.strip() == "interrupted during set-up: nothing was written"
    assert not (tmp_path / "o").exists()


def test_ctrl_c_while_the_results_are_written_lets_them_all_be_written(
        tmp_path, capsys, monkeypatch):
    publish = output.Staging.publish

    def ctrl_c_then_publish(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        return publish(self, *args, **kwargs)

    monkeypatch.setattr(output.Staging, "publish", ctrl_c_then_publish)
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 130
    err = capsys.readouterr().err
    assert err.startswith("interrupted while the results were written: all of them")
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "complete"
    manifest = set(json.loads((out / output.MANIFEST).read_text())["files"])
    assert manifest == {p.name for p in out.iterdir() if not p.name.startswith(".")}
    assert {"summary.json", "escapees.csv", "scene.resolved.toml", "checkpoint.npz"} <= manifest


CHANNEL = """
name = "channel"
units = "dimensionless"
[run]
t_end = 0.01
[fluid]
viscosity = 1.0
gap = 1.2
particle_flux = false
update_interval = 2
{bc}
[geometry]
kind = "polygon"
outline = [[0.0, -1.5], [12.0, -1.5], [12.0, 1.5], [0.0, 1.5]]
constriction_x = 11.0
[[particles]]
shape = "circle"
diameter = 1.0
positions = [[6.0, 0.0]]
density = 1.0
[feed]
mode = "none"
"""


def test_flow_csv_reads_the_drop_a_pump_would_at_the_flow_the_pressure_inlet_gave(tmp_path,
                                                                                  capsys):
    """A disk held as an obstacle in a straight channel at t = 0, once under
    p_in - p_out = 100 and once under the flow rate that gave: the finite-volume
    system is then the same linear one, so the flow-rate run's pressure drop (the
    inlet column extrapolated to the boundary; the pressure is linear there, 6 d
    upstream of the disk, so the two-column extrapolation is exact) is the 100
    imposed, to the solve's accuracy (solver_tol 1e-6 against a permeability
    contrast of 1e3: 1e-4 allowed, 4e-6 measured), and its flow rate column is the
    one prescribed, in m^3/s (per unit depth times the gap)."""
    import csv as csvmod
    runs = {}
    for name, bc in (("p", 'bc = "pressure"\np_in = 200.0\np_out = 100.0'), ("q", None)):
        if bc is None:
            bc = f'bc = "flow_rate"\nflow_rate = {runs["p"][0][3]!r}\np_out = 100.0'
        scene = tmp_path / f"{name}.toml"
        scene.write_text(CHANNEL.format(bc=bc))
        assert main([str(scene), "--out", str(tmp_path / name), "--quiet"]) == 0
        with open(tmp_path / name / "flow.csv") as fh:
            rows = list(csvmod.reader(fh))
        assert rows[0] == ["realization", "t", "pressure_drop", "flow_rate"]
        runs[name] = [[float(v) for v in row] for row in rows[1:]]
        solves = json.loads((tmp_path / name / "summary.json").read_text())["fluid"]["solves"]
        assert len(runs[name]) == solves >= 2                 # a row at every solve
    p0, q0 = runs["p"][0], runs["q"][0]
    assert p0[1] == q0[1] == 0.0 and p0[2] == 100.0
    assert q0[2] == pytest.approx(100.0, rel=1e-4)
    assert q0[3] == pytest.approx(p0[3], rel=1e-6)


@pytest.mark.parametrize("where", ["checkpoint", "plots"])
def test_a_full_disk_is_one_line_and_leaves_the_earlier_result(tmp_path, capsys,
                                                               monkeypatch, where):
    """No space left while the run writes its checkpoint (during the run) or its
    plots (at the end): exit 1, one line, the earlier result byte for byte."""
    import errno
    from taichi_hsdem import checkpoint, report
    out = tmp_path / "o"
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 0
    before = snapshot(out)

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    if where == "checkpoint":
        monkeypatch.setattr(checkpoint, "save", full)
        sets = ["--set", "output.checkpoint_every=1e-9"]     # at every chunk
    else:
        monkeypatch.setattr(report, "plot_run", full)
        sets = []
    capsys.readouterr()
    assert main([HOURGLASS, "--out", str(out), *SHORT, *sets]) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and err.count("\n") == 1, err
    assert snapshot(out) == before


def test_resume_while_another_run_writes_the_folder_says_so(tmp_path, capsys):
    """A live run's folder holds its checkpoint before any manifest names it: the
    reason given is the run writing there, not a file of no run's, and also
    before that run's first checkpoint."""
    from taichi_hsdem import checkpoint
    done, out = tmp_path / "done", tmp_path / "live"
    assert main([HOURGLASS, "--out", str(done), *SHORT]) == 0
    capsys.readouterr()
    with output.Staging(out):                            # the live run
        assert main(["--resume", str(out), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"--resume: another run is writing to {out}"), err
        (out / checkpoint.FILE).write_bytes((done / checkpoint.FILE).read_bytes())
        for args in (["--resume", str(out)], ["--resume", str(done), "--out", str(out)]):
            assert main([*args, "--quiet"]) == 2
            err = capsys.readouterr().err
            assert "another run is writing" in err and "no run of taichi_hsdem" not in err
            assert len(err.strip().splitlines()) == 1


def test_a_lock_path_that_is_a_folder_is_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / "o"
    (out / output.LOCK).mkdir(parents=True)
    assert main([HOURGLASS, "--out", str(out), *SHORT]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"--out: {out / output.LOCK} is a folder, where runs of "
                           "taichi_hsdem keep the folder's lock: remove it, or choose "
                           "another folder")
    assert sorted(p.name for p in out.iterdir()) == [output.LOCK]


def test_resume_of_a_folder_named_with_a_control_character_is_refused(tmp_path, capsys):
    """An ESC in --resume's folder would be echoed raw in every line after."""
    odd = tmp_path / "a\x1bx"
    odd.mkdir()
    assert main(["--resume", str(odd)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == "--resume: the folder name holds the control character U+001B", line
    assert list(odd.iterdir()) == []

