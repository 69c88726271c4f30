"""Checkpoints and restart: a run stopped, saved and continued in a new Simulation
gives the bits of the run never stopped (disks on the fused path with a flow-rate
inlet and re-feeding; squares on the level-set per-step path), also when a
finished run is extended to a later t_end; a checkpoint of other code or another
scene is refused."""
import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import Simulation, checkpoint, load_scene
from taichi_hsdem.cli import main
from taichi_hsdem.runstate import ARRAY_FIELDS, FIELDS, RunState

ROOT = Path(__file__).resolve().parents[1]
VANI = ROOT / "scenes" / "vani_phi026.toml"
SQUARES = ROOT / "scenes" / "squares.toml"
# Explicit series interval and clog window: their defaults follow t_end, and the
# extension test changes t_end.
COMMON = ["run.realizations=2", "fluid.workers=1", "output.series_interval=0.004",
          "clog.window=0.1"]
# Vani's particles started next to the constriction and re-fed far upstream, so that
# within 0.3 s some escape and are fed again.
NEAR = ["feed.region=[0.0024, 0.0031]", "feed.inlet=[0.0, 0.0005]", "run.stop_at_clog=false"]


def _same(a, b):
    for key in ("x", "theta", "v", "omega", "alive"):
        np.testing.assert_array_equal(a.final[key], b.final[key], err_msg=key)
    assert a.summary["realizations"] == b.summary["realizations"]
    assert a.series == b.series
    assert a.flow == b.flow and a.flow
    assert a.summary["steps"] == b.summary["steps"]
    assert a.summary["neighbor_builds"] == b.summary["neighbor_builds"]


def _stopped_then_resumed(path, sets, tmp_path, chunks, at_stop=None):
    """Run ``chunks`` chunks, checkpoint, continue in a fresh Simulation;
    ``at_stop(first)`` looks at the stopped run before it is saved."""
    first = Simulation(load_scene(path, sets))
    count = {"n": 0}

    def stop():
        count["n"] += 1
        return count["n"] > chunks

    part = first.run(stop=stop)
    assert part.summary["status"] == "interrupted"
    if at_stop is not None:
        at_stop(first)
    assert {r["status"] for r in part.summary["realizations"]} <= {"interrupted", "unstable",
                                                                   "ok"}
    saved = checkpoint.save(first, tmp_path / "checkpoint.npz")
    second = Simulation(load_scene(path, sets), place_particles=False)
    checkpoint.restore(second, saved)
    assert second.t == first.t and second.steps == first.steps
    return second.run()


@pytest.mark.parametrize("path, sets, chunks", [
    (VANI, COMMON + NEAR + ["run.t_end=0.3"], 40),
    # the implicit carried volume keeps each body's motion since the last solve
    (VANI, COMMON + NEAR + ["run.t_end=0.3", "fluid.particle_flux=true"], 40),
    (SQUARES, COMMON + ["run.t_end=0.02", "particles.count=20"], 3),
    # rolling friction keeps each contact's moment in the shear history (stopped
    # at t = 0.2 s: the first contacts hold moments from about 0.16 s)
    (VANI, COMMON + NEAR + ["run.t_end=0.3", "particles.rolling_friction=0.05"], 150),
])
def test_resumed_run_is_the_run_never_stopped(path, sets, chunks, tmp_path):
    straight = Simulation(load_scene(path, sets)).run()

    def rolling_moments_held(first):
        # the checkpoint carries contacts' rolling moments, not an empty node
        moments = first.history.old[1].to_numpy()[:, :, 1, :, 0]
        assert np.abs(moments).max() > 0

    rolling = any(s.startswith("particles.rolling_friction") for s in sets)
    resumed = _stopped_then_resumed(path, sets, tmp_path, chunks,
                                    rolling_moments_held if rolling else None)
    assert straight.summary["status"] == resumed.summary["status"] == "complete"
    _same(straight, resumed)
    # not vacuous: the particles moved, and for vani escaped and were fed again
    if path == VANI:
        assert sum(r["escapees"] or 0 for r in straight.summary["realizations"]) > 0
        assert straight.summary["fluid"]["solves"] > 5


def _same_state(a, b):
    """Two run states field by field (runstate.FIELDS): arrays of the same dtype and
    bits, generators in the same state, the rest equal."""
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if name == "rngs":
            assert [g.bit_generator.state for g in x] == [g.bit_generator.state for g in y]
        elif isinstance(x, np.ndarray):
            assert isinstance(y, np.ndarray) and x.dtype == y.dtype, name
            np.testing.assert_array_equal(x, y, err_msg=name)
        else:
            assert type(x) is type(y) and x == y, name


def test_run_state_round_trips_every_field():
    """to_arrays covers every field of RunState, and from_arrays of its output,
    through the JSON a checkpoint's header is, gives each back exactly."""
    rng = np.random.default_rng(7)
    rs = RunState.start([3, 4], n_particles=5, n_species=2, n_throats=3)
    for gen in rs.rngs:
        gen.random(3)                               # not the seeded state
    rs.t, rs.steps, rs.next_series = 0.1 + 1e-17 * 3, 12345, 0.30000000000000004
    rs.any_running, rs.history_overflows, rs.launches = False, 2, 17
    rs.e0, rs.u_ref = rng.random(2), rng.random(2)
    rs.results[1].escapees, rs.results[1].clogged, rs.results[1].t_clog = 9, True, 0.07
    rs.results[0].status, rs.results[0].reason = "unstable", "why"
    rs.series = [(0, 0.0, 0), (1, 0.1, 3)]
    rs.flow = [(0, 0.05, 1.25, 1e-10), (1, 0.05, float("nan"), 2e-10)]
    for name in ARRAY_FIELDS:
        old = getattr(rs, name)
        new = (rng.integers(0, 9, old.shape) if old.dtype.kind == "i" else
               rng.random(old.shape) > 0.5 if old.dtype == bool else rng.random(old.shape))
        setattr(rs, name, new.astype(old.dtype))
    rs.throat_t_clog[0, 1] = np.nan
    values, arrays = rs.to_arrays()
    assert set(values) | set(arrays) == set(FIELDS) and not set(values) & set(arrays)
    again = RunState.from_arrays(json.loads(json.dumps(values)), arrays)
    assert again.flow[1][2] != again.flow[1][2]         # NaN stays NaN
    again.flow[1] = rs.flow[1]
    _same_state(rs, again)


def test_checkpoint_restores_the_run_state_whole(tmp_path):
    """Stopped in a run with escapes, re-feeding and pressure solves: the restored
    Simulation holds the saved run state, every field, and the neighbour lists'
    and the fluid coupling's own state."""
    sets = COMMON + NEAR + ["run.t_end=0.3"]
    first = Simulation(load_scene(VANI, sets))
    first.run(stop=lambda: first.t > 0.25)
    rs = first.run_state
    assert rs.escaped.sum() > 0 and rs.series and rs.flow and rs.u_ref is not None
    saved = checkpoint.save(first, tmp_path / "checkpoint.npz")
    second = Simulation(load_scene(VANI, sets), place_particles=False)
    checkpoint.restore(second, saved)
    _same_state(first.run_state, second.run_state)
    assert second.neighbors.capacities == first.neighbors.capacities
    assert second.neighbors.builds == first.neighbors.builds
    (ca, a), (cb, b) = first.fluid.host_state(), second.fluid.host_state()
    assert ca == cb and set(a) == set(b)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_extended_run_is_the_longer_run(tmp_path):
    sets = COMMON + ["run.t_end=0.1"]
    longer = Simulation(load_scene(VANI, COMMON + ["run.t_end=0.16"])).run()
    short = Simulation(load_scene(VANI, sets))
    short.run()
    saved = checkpoint.save(short, tmp_path / "checkpoint.npz")
    again = Simulation(load_scene(VANI, COMMON + ["run.t_end=0.16"]), place_particles=False)
    checkpoint.restore(again, saved)
    _same(longer, again.run())


def test_checkpoint_of_other_code_or_scene_is_refused(tmp_path, monkeypatch):
    sets = COMMON + ["run.t_end=0.01"]
    sim = Simulation(load_scene(VANI, sets))
    saved = checkpoint.save(sim, tmp_path / "checkpoint.npz")
    other = Simulation(load_scene(VANI, sets + ["particles.friction=0.4"]),
                       place_particles=False)
    with pytest.raises(checkpoint.CheckpointError, match="friction"):
        checkpoint.restore(other, saved)
    monkeypatch.setattr(checkpoint, "code_digest", lambda: "0" * 64)
    with pytest.raises(checkpoint.CheckpointError, match="other code"):
        checkpoint.restore(Simulation(load_scene(VANI, sets), place_particles=False), saved)


def test_cli_resume_extends_and_refuses_what_it_cannot(tmp_path, capsys):
    out = tmp_path / "run"
    base = [str(VANI), "--out", str(out), "--quiet"] + sum((["--set", s] for s in COMMON), [])
    assert main(base + ["--set", "run.t_end=0.04"]) == 0
    assert (out / "checkpoint.npz").is_file()
    assert main(["--resume", str(out), "--set", "particles.friction=0.5"]) == 2
    assert "only run.t_end and the output keys" in capsys.readouterr().err
    assert main(["--resume", str(tmp_path / "nothing")]) == 2
    assert "no checkpoint here" in capsys.readouterr().err
    assert main(["--resume", str(out), "--set", "run.t_end=0.08", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["t_end"] == 0.08 and summary["t_reached"] == pytest.approx(0.08, abs=1e-4)


def test_ctrl_c_keeps_results_and_a_checkpoint_that_resumes(tmp_path):
    """A real SIGINT to the command line: exit 130, one line saying what was kept,
    the results marked interrupted, no staging folder left; --resume finishes it
    with the bits of a run never interrupted."""
    out, ref = tmp_path / "run", tmp_path / "ref"
    sets = sum((["--set", s] for s in COMMON + ["run.t_end=0.6"]), [])
    cmd = [sys.executable, "-m", "taichi_hsdem", str(VANI), *sets]
    log = tmp_path / "stderr.txt"
    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd + ["--out", str(out)], cwd=tmp_path, stderr=fh)
        deadline = time.time() + 120
        while time.time() < deadline and "t = " not in log.read_text():
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    err = log.read_text()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted at t =" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["t_reached"] < 0.6
    assert not [p for p in out.iterdir() if p.name.startswith(".incomplete")]
    assert main(["--resume", str(out), "--quiet"]) == 0
    assert main([str(VANI), *sets, "--out", str(ref), "--quiet"]) == 0
    done, straight = (json.loads((d / "summary.json").read_text()) for d in (out, ref))
    assert done["status"] == "complete"
    with np.load(out / "final_state.npz") as fa, np.load(ref / "final_state.npz") as fb:
        assert sorted(fa.files) == sorted(fb.files)
        for key in fa.files:
            np.testing.assert_array_equal(fa[key], fb[key], err_msg=key)
    assert done["realizations"] == straight["realizations"]
    assert (out / "escapees.csv").read_text() == (ref / "escapees.csv").read_text()



# --------------------------------------------------------- damaged or edited checkpoints

HOURGLASS = ROOT / "scenes" / "hourglass24.toml"


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A run's output folder with a checkpoint at its end (t = 0.2 of 0.2 s)."""
    out = tmp_path_factory.mktemp("ck") / "run"
    assert main([str(HOURGLASS), "--out", str(out), "--quiet", "--set", "run.t_end=0.2"]) == 0
    return out


def _arrays(folder):
    with np.load(folder / checkpoint.FILE) as data:
        return {k: data[k] for k in data.files}


def _header(arrays):
    return json.loads(bytes(arrays["header"]).decode())


def _set_header(arrays, header):
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)


def _edit_host(key, value):
    def edit(a):
        h = _header(a)
        h["host"][key] = value
        _set_header(a, h)
    return edit


def _edit_header(key, value):
    def edit(a):
        h = _header(a)
        h[key] = value(h[key]) if callable(value) else value
        _set_header(a, h)
    return edit


def _set_item(name, index, value):
    return lambda a: a[name].__setitem__(index, value)


# (name, how the arrays are edited, a phrase the one line must hold)
EDITS = [
    ("missing array", lambda a: a.pop("bodies.x"), "bodies.x: missing"),
    ("wrong dtype", lambda a: a.update({"bodies.x": a["bodies.x"].astype(np.float32)}),
     "bodies.x: float32"),
    ("wrong shape", lambda a: a.update({"bodies.v": a["bodies.v"][:, :3]}),
     "bodies.v: float64 (1, 3, 2)"),
    ("foreign array", lambda a: a.update({"extra": np.zeros(3)}), "not of this scene"),
    ("NaN position", _set_item("bodies.x", (0, 0, 0), np.nan), "bodies.x: NaN or infinite"),
    ("index out of range", _set_item("neighbors.nbr", (0, 0, 0), 10 ** 9),
     "neighbors.nbr: values outside"),
    ("absurd capacities", _edit_host("neighbor_caps", [10 ** 9, 10 ** 9]),
     "neighbor_caps"),
    ("NaN time", _edit_host("t", float("nan")), "host.t: must be a finite time"),
    ("infinite time", _edit_host("t", float("inf")), "host.t: must be a finite time"),
    ("negative time", _edit_host("t", -1.0), "host.t: must be a finite time"),
    ("time 1e300", _edit_host("t", 1e300), "is not host.steps"),
    ("negative steps", _edit_host("steps", -7), "host.steps: must be an integer >= 0"),
    ("steps beyond the time", _edit_host("steps", 10 ** 6), "is not host.steps"),
    ("results", _edit_host("results", [{}]), "host.results[0]"),
    ("random state", _edit_host("rngs", [{"state": 5}]), "host.rngs[0]"),
    ("series", _edit_host("series", [[7, 0.0, 0]]), "host.series"),
    ("no host", _edit_header("host", None), "header.host"),
    ("format", _edit_header("format", 99), "format 99"),
    ("scene not TOML", _edit_header("scene", "[[[ x"), "the scene inside is not TOML"),
    ("scene nested", _edit_header("scene", "x = " + "[" * 100000),
     "the scene inside is not TOML"),
    ("scene invalid", _edit_header("scene", lambda s: s.replace("friction = 0.4",
                                                                "friction = -3.0", 1)),
     "particles[0].friction: must be >= 0"),
    ("other code", _edit_header("code", "0" * 64), "written by other code"),
]


@pytest.mark.parametrize("edit, phrase", [e[1:] for e in EDITS], ids=[e[0] for e in EDITS])
def test_edited_checkpoint_is_refused_in_one_line(finished, edit, phrase, tmp_path, capsys):
    folder = tmp_path / "run"
    shutil.copytree(finished, folder)
    arrays = _arrays(finished)
    edit(arrays)
    with open(folder / checkpoint.FILE, "wb") as fh:
        np.savez(fh, **arrays)
    before = (folder / "summary.json").read_bytes()
    assert main(["--resume", str(folder), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"--resume: {folder / checkpoint.FILE}: "), err
    assert phrase in err, err
    assert (folder / "summary.json").read_bytes() == before      # nothing written


@pytest.mark.parametrize("damage, phrase", [
    (lambda b: b[:len(b) // 2], "not a complete .npz archive"),
    (lambda b: b"", "not a complete .npz archive"),
    (lambda b: b"\x93NUMPY" + b[6:], "not a readable checkpoint"),
    (lambda b: b[:len(b) // 3] + bytes([b[len(b) // 3] ^ 0xFF]) + b[len(b) // 3 + 1:],
     "Bad CRC-32"),
], ids=["truncated", "empty", "npy magic", "CRC error"])
def test_damaged_checkpoint_file_is_refused_in_one_line(finished, damage, phrase, tmp_path,
                                                        capsys):
    folder = tmp_path / "run"
    shutil.copytree(finished, folder)
    path = folder / checkpoint.FILE
    path.write_bytes(damage(path.read_bytes()))
    assert main(["--resume", str(folder), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and phrase in err and "Traceback" not in err, err


def test_resume_to_an_earlier_t_end_is_refused(finished, tmp_path, capsys):
    folder = tmp_path / "run"
    shutil.copytree(finished, folder)
    assert main(["--resume", str(folder), "--quiet", "--set", "run.t_end=0.1"]) == 2
    err = capsys.readouterr().err
    assert "past run.t_end = 0.1 s" in err and err.count("\n") == 1, err


def test_result_fields_are_the_simulations(finished):
    # the checkpoint checks each result record's keys without importing the simulator
    import dataclasses

    from taichi_hsdem.runstate import RealizationResult
    assert checkpoint.RESULT_KEYS == tuple(f.name for f in dataclasses.fields(RealizationResult))
    results = _header(_arrays(finished))["host"]["results"]
    assert [tuple(r) for r in results] == [checkpoint.RESULT_KEYS]


def test_resumed_between_an_escape_and_the_clog_keeps_its_clog_time(tmp_path):
    """Stopped after the last escape, with the arch already found static but the
    clog not yet declared: the resumed run reports the clog time, the last escape
    and the escapees per species of the run never stopped (host bookkeeping the
    checkpoint carries). Vani, seed 3, started at the neck: the last escape at
    0.357 s, arch static from 0.376 s, clog declared 0.1 s after the last escape."""
    sets = ["run.realizations=1", "run.seed=3", "fluid.workers=1", "clog.window=0.1",
            "feed.region=[0.0024, 0.0031]", "feed.inlet=[0.0, 0.0005]",
            "run.stop_at_clog=false", "run.t_end=0.5"]
    straight = Simulation(load_scene(VANI, sets)).run()
    row = straight.summary["realizations"][0]
    first = Simulation(load_scene(VANI, sets))
    part = first.run(stop=lambda: first.t > row["t_clog"])
    assert part.summary["realizations"][0]["clogged"] is False    # not declared yet
    saved = checkpoint.save(first, tmp_path / "checkpoint.npz")
    second = Simulation(load_scene(VANI, sets), place_particles=False)
    checkpoint.restore(second, saved)
    resumed = second.run()
    assert row["clogged"] and row["t_last_escape"] < row["t_clog"]
    _same(straight, resumed)


# --------------------------------------------------------------- resuming in place

def _files(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


def test_in_place_resume_removes_what_the_resumed_run_does_not_write(tmp_path, capsys):
    """A run continued in its own folder publishes the whole run, as into another
    folder: files of the earlier part it does not write (a video, a ParaView series
    it was not asked for this time) go."""
    from taichi_hsdem import output, render
    out = tmp_path / "run"
    video = ["--video"] if render.vulkan_status()[0] else []
    assert main([str(HOURGLASS), "--out", str(out), "--quiet", "--set", "run.t_end=0.2",
                 "--vtk", *video]) == 0
    assert (out / "series.pvd").is_file() and (out / "vtk").is_dir()
    assert main(["--resume", str(out), "--quiet", "--set", "run.t_end=0.3", "--no-video",
                 "--set", "output.vtk=false"]) == 0
    left = {p.name for p in out.iterdir()}
    assert not left & {"video.mp4", "series.pvd", "vtk"}, left
    manifest = set(json.loads((out / output.MANIFEST).read_text())["files"])
    assert manifest == {n for n in left if not n.startswith(".")}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "complete" and summary["t_reached"] == pytest.approx(0.3,
                                                                                      abs=1e-2)


def test_in_place_resume_refuses_a_checkpoint_of_another_scene(tmp_path, capsys):
    """Another scene's checkpoint.npz copied into a run's folder: --resume there is
    refused in one line naming a key that differs, and the folder stays as it was;
    into another folder it goes on."""
    x, y, z = tmp_path / "x", tmp_path / "y", tmp_path / "z"
    assert main([str(HOURGLASS), "--out", str(x), "--quiet", "--set", "run.t_end=0.2"]) == 0
    assert main([str(VANI), "--out", str(y), "--quiet", "--realizations", "1",
                 "--set", "run.t_end=0.01"]) == 0
    shutil.copy2(y / checkpoint.FILE, x / checkpoint.FILE)
    before = _files(x)
    capsys.readouterr()
    assert main(["--resume", str(x), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "another scene" in err, err
    assert "in the checkpoint" in err and "--out" in err
    assert _files(x) == before
    assert main(["--resume", str(x), "--out", str(z), "--quiet"]) == 0
    assert 'name = "vani_phi026"' in (z / "scene.resolved.toml").read_text()
