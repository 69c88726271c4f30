"""The command line and its output folder, as CONTRACT.md states them."""
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import numpy as np

from taichi_hsdem import __version__, output
from taichi_hsdem.cli import main

ROOT = Path(__file__).resolve().parents[1]
HOURGLASS = str(ROOT / "scenes" / "hourglass24.toml")
SHORT = ["--set", "run.t_end=1.0", "--quiet"]


def run_cli(args, capsys):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_run_writes_contract_outputs(tmp_path, capsys):
    out = tmp_path / "o"
    code, stdout, stderr = run_cli([HOURGLASS, "--out", str(out), *SHORT], capsys)
    assert code == 0
    assert stdout == "" and stderr == ""                  # --quiet: nothing but errors
    s = json.loads((out / "summary.json").read_text())
    for key in ("scene", "version", "arch", "dt", "steps", "t_end", "wall_time_s",
                "realizations", "mean_escapees"):
        assert key in s
    assert s["version"] == __version__ and s["arch"] == "x64" and s["t_end"] == 1.0
    assert s["steps"] == pytest.approx(1.0 / s["dt"], abs=1)
    (r,) = s["realizations"]
    assert set(r) >= {"seed", "escapees", "clogged", "t_clog", "status"}
    assert r["status"] == "ok" and r["seed"] == 1
    rows = list(csv.reader((out / "escapees.csv").open()))
    # three species: a column per species after the total, which they sum to
    assert rows[0] == ["realization", "t", "escapees"] + [f"escapees_{n}" for n in s["species"]]
    assert len(s["species"]) == 3
    assert all(int(row[2]) == sum(int(v) for v in row[3:]) for row in rows[1:])
    assert float(rows[-1][1]) == pytest.approx(1.0, abs=2 * s["dt"])
    resolved = (out / "scene.resolved.toml").read_text()
    assert "dt = " in resolved and '"auto"' not in resolved     # every auto resolved


def test_resolved_scene_reruns_identically(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert run_cli([HOURGLASS, "--out", str(a), *SHORT], capsys)[0] == 0
    assert run_cli([str(a / "scene.resolved.toml"), "--out", str(b), "--quiet"], capsys)[0] == 0
    fa, fb = (output.read_final_state(d) for d in (a, b))
    assert sorted(fa) == sorted(fb) and all(np.array_equal(fa[k], fb[k]) for k in fa)


def bad_scene(tmp_path, text):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return str(p)


BASE = Path(HOURGLASS).read_text()


@pytest.mark.parametrize("text, expected", [
    ("this is = = not toml", ["bad.toml", "invalid TOML"]),
    (BASE.replace("[run]", "[run]\ncolour = 3"), ["run.colour", "unknown key"]),
    (BASE.replace("t_end = 60.0", 't_end = "long"'), ["run.t_end"]),
    (BASE.replace("t_end = 60.0", "t_end = -1.0"), ["run.t_end", "> 0"]),
    (BASE.replace("p_in = 200.0\n", ""), ["fluid.p_in"]),
    (BASE.replace("neck_width = 2.4", "neck_width = 12.0"), ["neck_width"]),
    (BASE.replace("count = 8\n", "count = 8\npacking_fraction = 0.1\n", 1), ["count", "packing_fraction"]),
    (BASE.replace('viscosity = 1.0', 'viscosity = 1.0\ncell_size = 0.9'), ["fluid.cell_size", "too coarse"]),
    (BASE.replace('shape = "circle"\ndiameter = 1.0', 'shape = "circle"\ndiameter = 1.0\nside = 1.0', 1),
     ["side", "not used by shape"]),
])
def test_bad_scene_exit_2_one_line_per_problem(tmp_path, capsys, text, expected):
    code, stdout, stderr = run_cli([bad_scene(tmp_path, text), "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    assert "Traceback" not in stderr
    assert all(e in stderr for e in expected), stderr
    assert not (tmp_path / "o").exists()                 # nothing written for a bad scene


def test_several_problems_reported_together(tmp_path, capsys):
    text = BASE.replace("t_end = 60.0", "t_end = -1.0").replace("gap = 1.7", "gap = -1.0")
    code, _, stderr = run_cli([bad_scene(tmp_path, text)], capsys)
    assert code == 2
    lines = [l for l in stderr.splitlines() if l.strip()]
    assert len(lines) >= 2 and any("run.t_end" in l for l in lines) and any("fluid.gap" in l for l in lines)


def test_bad_override_and_missing_file(tmp_path, capsys):
    code, _, err = run_cli([HOURGLASS, "--set", "particles.friction=-1"], capsys)
    assert code == 2 and "friction" in err
    code, _, err = run_cli([str(tmp_path / "nope.toml")], capsys)
    assert code == 2 and "not found" in err
    code, _, err = run_cli([HOURGLASS, "--realizations", "many"], capsys)
    assert code == 2


def test_too_dense_placement_is_a_scene_error(tmp_path, capsys):
    text = BASE.replace("count = 8", "count = 400")
    code, _, err = run_cli([bad_scene(tmp_path, text), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "particles" in err and "Traceback" not in err


def test_unstable_run_exits_1_and_writes_no_result(tmp_path, capsys):
    out = tmp_path / "o"
    code, _, err = run_cli([HOURGLASS, "--out", str(out), "--set", "run.dt=0.5",
                            "--set", "run.force_dt=true", "--set", "run.t_end=30", "--quiet"], capsys)
    assert code == 1
    assert "unstable" in err and "run.dt" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["realizations"][0]["status"] == "unstable"
    assert s["realizations"][0]["escapees"] is None and s["mean_escapees"] is None
    assert len(list(csv.reader((out / "escapees.csv").open()))) == 1   # header only


def test_module_entry_point_and_clean_cwd(tmp_path):
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, "-m", "taichi_hsdem", HOURGLASS, "--set", "run.t_end=0.2"],
                          cwd=tmp_path, capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""                               # progress and messages go to stderr
    assert "done in" in proc.stderr
    # the only thing written to the working directory is the default output folder
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]
    assert (tmp_path / "runs" / "hourglass24" / "summary.json").exists()


def test_the_studies_are_subcommands_of_the_one_command_line(tmp_path, capsys):
    """``python -m taichi_hsdem sweep|calibrate|figures|arches`` reach the studies'
    own command lines (named so in their messages), and ``run`` is the plain one."""
    assert main(["calibrate", HOURGLASS, "--target", "-1", "--lo", "0.1", "--hi", "0.9"]) == 2
    assert capsys.readouterr().err.startswith(
        "python -m taichi_hsdem calibrate: --target: must be a positive number")
    assert main(["arches", str(tmp_path)]) == 2
    assert "figure.json" in capsys.readouterr().err
    assert main(["figures", "nonsense"]) == 2
    assert "python -m taichi_hsdem figures" in capsys.readouterr().err
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["run", HOURGLASS, "--out", str(a), "--set", "run.t_end=0.2", "--quiet"]) == 0
    assert main([HOURGLASS, "--out", str(b), "--set", "run.t_end=0.2", "--quiet"]) == 0
    fa, fb = (output.read_final_state(d) for d in (a, b))
    assert sorted(fa) == sorted(fb) and all(np.array_equal(fa[k], fb[k]) for k in fa)


def test_the_shipped_example_sweep_is_valid(tmp_path, capsys):
    from taichi_hsdem.studies.sweep import load_sweep
    sweep = load_sweep(ROOT / "scenes" / "sweep_friction.toml")
    assert [p["particles.friction"] for p in sweep.points] == [0.1, 0.25, 0.5, 0.9]
    assert Path(sweep.scene).resolve() == ROOT / "scenes" / "vani_phi026.toml"
