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
    for out, phrase in ((blocker, "is a file, not a folder"),
                        (blocker / "sub", "which is not a folder")):
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
    assert not [p for p in out.iterdir() if p.name != output.MANIFEST
                and (p.name.startswith(".") or p.suffix == ".part")]


# ------------------------------------------------- hangs and tracebacks of hostile scenes

def _circle(n, r):
    import math
    return [[r * math.cos(2 * math.pi * k / n), r * math.sin(2 * math.pi * k / n)]
            for k in range(n)]


def _scene_file(tmp_path, text, name="s.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _polygon_outline_scene(tmp_path, outline, obstacles=None):
    """vani_phi026 with its converging channel replaced by ``outline``."""
    text = (SCENES / "vani_phi026.toml").read_text()
    start = text.index("[geometry]")
    end = text.index("\n[", start + 1)
    geometry = f"[geometry]\nkind = \"polygon\"\noutline = {outline}\n"
    if obstacles is not None:
        geometry += f"obstacles = {obstacles}\n"
    return _scene_file(tmp_path, text[:start] + geometry + text[end:])


def _refused(args, capsys, tmp_path, seconds=60):
    """Run the command line; return its one-line-per-problem stderr after checking
    exit 2, no traceback, nothing written, and an answer within ``seconds``."""
    t0 = time.perf_counter()
    code = main(args + ["--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert time.perf_counter() - t0 < seconds, "refused, but not up front"
    assert "Traceback" not in err and err.strip(), err
    assert not (tmp_path / "out").exists()
    return err


def test_a_3000_vertex_particle_is_refused_up_front(tmp_path, capsys):
    # the pair-by-pair simplicity check alone took over 5 minutes
    err = _refused([SQUARES, *sets('particles.0.shape="polygon"', "particles.0.side=nan",
                                   f"particles.0.vertices={_circle(3000, 1e-5)}")],
                   capsys, tmp_path, seconds=20)
    assert "particles[0].vertices: has 3000 vertices, more than the 1000" in err, err


def test_a_6000_vertex_outline_is_refused_up_front(tmp_path, capsys):
    outline = [[0.0, 0.0], [3e-3, 0.0]] + [[3e-3 * k / 6000, 4e-4] for k in range(6000, -1, -1)]
    err = _refused([_polygon_outline_scene(tmp_path, outline)], capsys, tmp_path, seconds=20)
    assert "geometry.outline: has 6003 vertices, more than the 2000" in err, err


def test_simplicity_check_of_a_large_polygon_is_fast_and_exact():
    # 2000 vertices (the bound): the vectorised check against the pair-by-pair answer
    import numpy as np

    from taichi_hsdem.geometry.polygon import first_crossing, segments_intersect
    circle = np.array(_circle(2000, 1.0))
    t0 = time.perf_counter()
    assert first_crossing(circle) is None
    assert time.perf_counter() - t0 < 10
    crossed = np.array(_circle(300, 1.0))
    crossed[[100, 200]] = crossed[[200, 100]]         # two far vertices swapped
    n = len(crossed)
    brute = next((a, b) for a in range(n) for b in range(a + 2, n)
                 if not (a == 0 and b == n - 1) and segments_intersect(
                     crossed[a], crossed[(a + 1) % n], crossed[b], crossed[(b + 1) % n]))
    assert first_crossing(crossed) == brute
    assert brute[0] == 99                             # the first edge into a moved vertex


@pytest.mark.parametrize("outline, obstacles, key, phrase", [
    ("[[0.0, 0.0], [3e-3, 4e-4], [3e-3, 0.0], [0.0, 3e-4]]", None, "geometry.outline",
     "cross or touch"),
    ("[[0.0, 0.0], [1e-3, 0.0], [3e-3, 0.0]]", None, "geometry.outline", "zero area"),
    ("[[0.0, 0.0], [3e-3, 0.0], [3e-3, 4e-4], [0.0, 4e-4]]",
     "[[[1e-3, 1e-4], [2e-3, 1e-4], [1.5e-3, 1e-4]]]", "geometry.obstacles[0]", "zero area"),
    ("[[0.0, 0.0], [3e-3, 0.0], [3e-3, 4e-4], [0.0, 4e-4]]",
     "[[[1e-3, 1e-4], [2e-3, 2e-4], [2e-3, 1e-4], [1e-3, 2e-4]]]", "geometry.obstacles[0]",
     "self-intersecting"),
    ("[[0.0, 0.0], [3e-3, 0.0], [3e-3, 4e-4], [0.0, 4e-4]]",
     "[[[1e-3, 1e-4], [4e-3, 1e-4], [1e-3, 2e-4]]]", "geometry.obstacles[0]",
     "strictly inside"),
], ids=["bow-tie outline", "collinear outline", "collinear obstacle", "bow-tie obstacle",
        "obstacle through the wall"])
def test_bad_channel_polygons_are_refused(outline, obstacles, key, phrase, tmp_path, capsys):
    err = _refused([_polygon_outline_scene(tmp_path, outline, obstacles)], capsys, tmp_path)
    assert any(key in ln and phrase in ln for ln in err.splitlines()), err


def test_more_frames_than_steps_are_clamped_to_one_a_step():
    # a million frames over 5 steps drew the same states for hours
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import resolve
    model = resolve(load_scene(HOURGLASS, ["output.frames=1000000", "run.t_end=0.01"]))
    steps = round(0.01 / model.dt)
    assert model.scene.output.frames == steps + 1
    assert "one frame per step" in model.notes["output.frames"]


@pytest.mark.parametrize("text, phrase", [
    ("x = " + "[" * 50000 + "]" * 50000, "nested too deep"),
    ("name = 'a'\nname = 'b'\n", "invalid TOML"),
    ("description = \"\x01\"\n", "invalid TOML"),
], ids=["deeply nested arrays", "duplicate key", "control character"])
def test_hostile_toml_is_refused_in_one_line(text, phrase, tmp_path, capsys):
    err = _refused([_scene_file(tmp_path, text)], capsys, tmp_path)
    assert err.count("\n") == 1 and phrase in err, err


def test_a_huge_array_of_bad_entries_is_one_line(tmp_path, capsys):
    # 200000 bad positions gave 200000 lines
    text = (SCENES / "hourglass24.toml").read_text().replace(
        "count = 8", "positions = [" + ", ".join(["[1]"] * 200000) + "]", 1)
    err = _refused([_scene_file(tmp_path, text)], capsys, tmp_path)
    assert err.count("positions") == 1 and err.count("\n") <= 2, err[:500]
    assert "particles[0].positions[0]: expected [x, y]" in err, err


def test_a_scene_name_too_long_for_a_folder_is_refused(tmp_path, capsys):
    text = (SCENES / "hourglass24.toml").read_text().replace('name = "hourglass24"',
                                                             f'name = "{"a" * 5000}"')
    err = _refused([_scene_file(tmp_path, text)], capsys, tmp_path)
    assert "name: is 5000 bytes long" in err and "at most 255" in err, err
    err = _refused([HOURGLASS, *sets(f'output.dir="{tmp_path}/{"b" * 300}"')], capsys, tmp_path)
    assert "output.dir: a folder name longer than 255 bytes" in err, err


@pytest.mark.parametrize("kind", ["device", "fifo", "oversize"])
def test_a_scene_that_is_not_a_regular_file_or_huge_is_not_read(kind, tmp_path, capsys):
    if kind == "device":
        path, phrase = "/dev/zero", "not a regular file"
    elif kind == "fifo":
        path, phrase = str(tmp_path / "pipe.toml"), "not a regular file"
        os.mkfifo(path)                         # reading it would block forever
    else:
        path, phrase = str(tmp_path / "big.toml"), "larger than 16 MB"
        with open(path, "wb") as fh:
            fh.write(b"#" * (17 * 2 ** 20))
    err = _refused([path], capsys, tmp_path, seconds=10)
    assert err.startswith(f"{path}: ") and phrase in err, err


@pytest.mark.parametrize("args, key", [
    (["--set", "particles.nodes=100000000"], "particles[0].nodes"),
    (["--realizations", "3000"], "run.realizations"),
], ids=["nodes", "realizations"])
def test_memory_refusal_respects_an_address_space_limit(args, key, tmp_path):
    # ulimit -v 8000000: numpy's _ArrayMemoryError traceback, since the estimate
    # compared against the machine's memory only
    import resource
    import subprocess
    import sys

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (8_000_000 * 1024, 8_000_000 * 1024))

    proc = subprocess.run([sys.executable, "-m", "taichi_hsdem", VANI, *args, "--out",
                           str(tmp_path / "o"), "--quiet"], capture_output=True, text=True,
                          preexec_fn=limit, timeout=300, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert key in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
