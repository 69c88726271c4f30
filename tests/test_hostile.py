"""Hostile input: every family of bad scenes and arguments gets exit 2 and one line
in the user's terms (the key they set, the bound), at once, before anything is
allocated or written; output folders that cannot be written are refused the same
way; a write that fails at the end (a full disk) exits 1 and leaves the previous
result as it was, with no temporary file behind."""
import errno
import json
import os
import time
from pathlib import Path

import pytest

from taichi_hsdem import output
from taichi_hsdem.cli import main

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
VANI, SQUARES, HOURGLASS = (str(SCENES / f"{n}.toml") for n in ("vani_phi026", "squares",
                                                                "hourglass24"))


def sets(*pairs):
    return sum((["--set", p] for p in pairs), [])


CASES = [  # (arguments, the key the message must name, a phrase it must hold)
    ([SQUARES, *sets("particles.0.count=1000000000")], "particles[0].count", "at most 0.6 fits"),
    ([VANI, "--realizations", "1000000"], "run.realizations", "memory available"),
    ([SQUARES, *sets("particles.0.ls_spacing=1e-9")], "particles[0].ls_spacing",
     "memory available"),
    ([VANI, *sets("geometry.wall_cell_size=1e-9")], "geometry.wall_cell_size",
     "memory available"),
    ([VANI, *sets("fluid.cell_size=1e-8")], "fluid.cell_size", "memory available"),
    ([VANI, *sets("geometry.angle=1e-7")], "geometry.angle", "use a larger angle"),
    ([VANI, *sets("geometry.angle=90")], "geometry.angle", "constriction_length > 0"),
    ([VANI, *sets("particles.0.density=1e308")], "particles[0].density", "outside the magnitudes"),
    ([VANI, *sets("particles.0.density=1e-300")], "particles[0].density",
     "outside the magnitudes"),
    ([VANI, *sets("fluid.gap=1e308")], "fluid.gap", "outside the magnitudes"),
    ([VANI, *sets("run.dt=1e-300")], "run.dt", "outside the magnitudes"),
    ([VANI, *sets("run.dt=1e-90")], "run.dt", "steps"),
    ([HOURGLASS, *sets("fluid.p_in=1e60")], "run.t_end", "steps"),
    ([HOURGLASS, *sets("fluid.p_in=1e300")], "fluid.p_in", "outside the magnitudes"),
    ([HOURGLASS, *sets("run.t_end=1e-9")], "run.t_end", "no step"),
    ([VANI, *sets("feed.region=[-1.0, -0.5]")], "feed.region", "outside the channel"),
    ([VANI, *sets("feed.inlet=[-1.0, -0.5]")], "feed.inlet", "outside the channel"),
    ([VANI, "--realizations", "x"], "--realizations", "invalid int"),
]


@pytest.mark.parametrize("args, key, phrase", CASES, ids=[c[1] + ":" + c[2][:12] for c in CASES])
def test_hostile_input_is_refused_in_the_users_terms(args, key, phrase, tmp_path, capsys):
    out = tmp_path / "out"
    t0 = time.perf_counter()
    code = main(args + ["--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert time.perf_counter() - t0 < 60                   # refused up front
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and all(key in ln or "--set" in ln or ":" in ln for ln in lines), err
    assert any(key in ln and phrase in ln for ln in lines), err
    assert "Traceback" not in err and "Warning" not in err
    assert not out.exists()                                # nothing written


@pytest.mark.parametrize("sets_, key", [
    (['run.precision="f32"', "particles.0.density=1e40"], "particles[0].density"),
    (['run.precision="f32"', "particles.0.kn=1e30"], "particles[0].kn"),
])
def test_derived_numbers_outside_the_precision_are_refused(sets_, key):
    # what the kernels hold must fit their float type: f32 stiffnesses and masses,
    # squared in the contact law, must stay below sqrt(f32 max / 1e6)
    from taichi_hsdem import SceneError, load_scene
    from taichi_hsdem.resolve import resolve
    with pytest.raises(SceneError) as caught:
        resolve(load_scene(VANI, sets_))
    assert any(key in line and "f32 kernels can" in line for line in caught.value.problems)


def test_sliver_polygon_is_refused_before_its_level_set_is_built(tmp_path, capsys):
    # 1 mm long, 1 nm thick: d_eq = 1.1 um, so the auto level-set spacing d_eq / 40
    # would grid the 1 mm outline with ~1e9 nodes
    text = (SCENES / "squares.toml").read_text().replace(
        'shape = "square"', 'shape = "polygon"\nvertices = [[0.0, 0.0], [1e-3, 0.0], '
        '[1e-3, 1e-9], [0.0, 1e-9]]').replace("side = ", "# side = ")
    scene = tmp_path / "sliver.toml"
    scene.write_text(text)
    t0 = time.perf_counter()
    assert main([str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert time.perf_counter() - t0 < 60
    assert "particles[0]" in err and "Traceback" not in err, err


def test_output_folder_that_is_a_file_or_under_one(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for out, phrase in ((blocker, "is a file, not a folder"), (blocker / "sub", "which is a file")):
        assert main([HOURGLASS, "--out", str(out), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("--out: ") and phrase in err, err
    assert blocker.read_text() == "x"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main([HOURGLASS, "--out", str(ro / "run"), "--quiet"]) == 2
        assert "permission denied" in capsys.readouterr().err
    finally:
        ro.chmod(0o700)


def test_a_full_disk_at_the_end_keeps_the_previous_result(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    args = [HOURGLASS, "--out", str(out), "--quiet", *sets("run.t_end=0.2")]
    assert main(args) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "checkpoint.npz"}

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(output, "write_summary", full)
    assert main(args + sets("particles.friction=0.1")) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and "Traceback" not in err
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "checkpoint.npz"}
    assert after.keys() == before.keys()                 # nothing added, no .part, no staging
    assert json.loads(after["summary.json"]) == json.loads(before["summary.json"])


def test_a_failed_run_leaves_the_previous_result_and_a_finished_one_replaces_all(tmp_path,
                                                                                  capsys):
    out = tmp_path / "run"
    assert main([HOURGLASS, "--out", str(out), "--quiet", "--video", *sets("run.t_end=0.2",
                                                                         "output.frames=3")]) == 0
    assert (out / "video.mp4").is_file()
    # a second run without video: the first run's video must not stay beside it
    assert main([HOURGLASS, "--out", str(out), "--quiet", *sets("run.t_end=0.3")]) == 0
    assert not (out / "video.mp4").exists()
    assert json.loads((out / "summary.json").read_text())["t_end"] == 0.3
    assert not [p for p in out.iterdir() if p.name.startswith(".") or p.suffix == ".part"]
