"""The studies' refusals found by tools/fuzz_cli.py: bad input gets one clear line
on stderr in the user's terms and exit 2, writes nothing when refused before any
work, and never a traceback."""
import json
import os
import sys
from pathlib import Path

import pytest

from taichi_hsdem.studies import arches, calibrate, figures
from taichi_hsdem.studies import cluster as cluster_module
from taichi_hsdem.studies import sweep as sweep_module

from test_arches import _figure_folder

ROOT = Path(__file__).resolve().parents[1]
HOURGLASS = ROOT / "scenes" / "hourglass24.toml"


# ----------------------------------------------- 1. arches on damaged point files

def _state(**change):
    state = {"x": [[1.0, 2.0]], "theta": [0.0], "alive": [1], "species": [0]}
    return {**state, **change}


DAMAGED = {
    "empty": ("", "missing or unreadable"),
    "cut": ("{", "missing or unreadable"),
    "list": ("[]", "no \"rows\""),
    "row_not_object": ({"rows": [3], "finals": {"7": _state()}}, "row 0 lacks"),
    "row_empty": ({"rows": [{}], "finals": {"7": _state()}}, "row 0 lacks"),
    "row_no_seed": ({"rows": [{"status": "ok", "clogged": True}], "finals": {"7": _state()}},
                    "row 0 lacks"),
    "row_types": ({"rows": [{"seed": "7", "escapees": 3, "clogged": True, "status": "ok"}],
                   "finals": {"7": _state()}}, "wrong type"),
    "finals_list": ({"finals": [1]}, '"finals" is not an object'),
    "final_number": ({"finals": {"7": 3}}, "lacks its \"x\""),
    "final_empty": ({"finals": {"7": {}}}, "lacks its \"x\""),
    "final_lengths": ({"finals": {"7": _state(theta=[])}}, "differ in length"),
    "final_x": ({"finals": {"7": _state(x=[[1e300, "x"]])}}, "pairs of finite numbers"),
    "final_species": ({"finals": {"7": _state(species=[9])}}, "species indices"),
}


@pytest.mark.parametrize("kind", sorted(DAMAGED))
def test_arches_on_a_damaged_point_file_is_one_line_naming_it(tmp_path, capsys, kind):
    folder = _figure_folder(tmp_path)
    path = folder / "points" / "circle.json"
    damage, words = DAMAGED[kind]
    if isinstance(damage, str):
        path.write_text(damage)
    else:
        data = json.loads(path.read_text())
        data.update(damage)
        path.write_text(json.dumps(data))
    assert arches.main([str(folder)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and words in err[0], err
    assert sorted(os.listdir(folder)) == ["figure.json", "points"]


# --------------------------------- 2. --cluster refused before the folder is made

NOBODY = "tcp://127.0.0.1:1"          # nothing listens there


def _studies(tmp_path, out, cluster):
    """The three studies' argument lists into ``out`` with ``--cluster cluster``."""
    from test_study_folders import sweep_file
    tail = ["--out", str(out), "--cluster", cluster, "--quiet"]
    return {
        "sweep": (sweep_module.main, [str(sweep_file(tmp_path, t_end=0.05)), *tail]),
        "figures": (figures.main, ["friction", "--quick", "--set", "run.t_end=0.05",
                                   "--realizations", "1", *tail]),
        "calibrate": (calibrate.main, [str(HOURGLASS), "--target", "3", "--lo", "0.2",
                                       "--hi", "0.6", "--realizations", "1", "--rounds",
                                       "2", "--set", "run.t_end=0.05", *tail]),
    }


@pytest.mark.parametrize("cluster", [NOBODY, "local:x", "dask-missing"])
@pytest.mark.parametrize("study", ["sweep", "figures", "calibrate"])
def test_a_cluster_that_cannot_be_used_is_refused_before_the_folder_is_made(
        tmp_path, capsys, monkeypatch, study, cluster):
    monkeypatch.setattr(cluster_module, "CONNECT_TIMEOUT", 1)
    if cluster == "dask-missing":       # as if the cluster extra were not installed
        monkeypatch.setitem(sys.modules, "distributed", None)
        cluster = "local:1"
    out = tmp_path / "out"
    main, argv = _studies(tmp_path, out, cluster)[study]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"--cluster {cluster}"), err
    assert "Traceback" not in err[0]
    assert not out.exists()


def test_connecting_to_a_cluster_is_said_before_the_wait(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")     # the cluster extra (tools/setup.sh leaves it out)
    from test_study_folders import sweep_file
    monkeypatch.setattr(cluster_module, "CONNECT_TIMEOUT", 1)
    out = tmp_path / "out"
    assert sweep_module.main([str(sweep_file(tmp_path)), "--out", str(out), "--cluster",
                              NOBODY]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    connecting = [k for k, line in enumerate(err)
                  if line.startswith(f"connecting to the cluster at {NOBODY}")]
    assert connecting and connecting[0] < len(err) - 1, err
    assert err[-1].startswith(f"--cluster {NOBODY}: no Dask scheduler answers"), err
    assert not out.exists()


def test_the_connection_timeout_is_short():
    assert 3 <= cluster_module.CONNECT_TIMEOUT <= 10


# ------------------ 3. calibrate refused at its first round's set-up leaves nothing

CALIBRATE_REFUSED = [str(HOURGLASS), "--target", "3", "--lo", "0.2", "--hi", "0.6",
                     "--realizations", "99999999999", "--quiet"]


def test_calibrate_refused_at_the_first_round_leaves_nothing(tmp_path, capsys):
    out = tmp_path / "c"
    assert calibrate.main(CALIBRATE_REFUSED + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "calibration stopped" in err and "run.realizations" in err, err
    assert not out.exists()


def test_calibrate_refused_at_the_first_round_keeps_what_the_folder_held(tmp_path, capsys):
    out = tmp_path / "c"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    assert calibrate.main(CALIBRATE_REFUSED + ["--out", str(out)]) == 2
    assert "calibration stopped" in capsys.readouterr().err
    assert sorted(os.listdir(out)) == ["notes.txt"]
    assert (out / "notes.txt").read_text() == "mine\n"


# ------------------------------------------ 4. a bad grid value is said once, not per point

def test_a_bad_grid_value_is_said_once_naming_its_key_and_value(tmp_path, capsys):
    path = tmp_path / "g.toml"
    path.write_text(f'scene = "{HOURGLASS.as_posix()}"\n[common]\n"run.t_end" = 0.05\n'
                    '[grid]\n"particles.friction" = [0.2, -1, 0.3, 0.4]\n'
                    '"run.seed" = [1, 2, 3, 4, 5]\n"damping.xi" = [0.1, 0.2, 0.3]\n')
    out = tmp_path / "out"
    assert sweep_module.main([str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "particles.friction = -1" in err[0] and "at 15 points" in err[0], err
    assert not out.exists()


# ------------------------------------- 5. figures --quiet still says why points failed

def test_figures_quiet_says_why_every_point_was_refused(tmp_path, capsys):
    out = tmp_path / "f"
    code = figures.main(["friction", "--quick", "--realizations", "99999999999", "--out",
                         str(out), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and err and len(err) <= 3, err
    assert "run.realizations" in err[0], err


@pytest.mark.parametrize("command, args", [
    (sweep_module, [str(ROOT / "scenes" / "sweep_friction.toml")]),
    (figures, ["friction", "--quick"]),
    (calibrate, [str(HOURGLASS), "--param", "particles.friction", "--target", "5",
                 "--lo", "0.1", "--hi", "0.9"]),
])
def test_an_empty_out_is_refused_as_a_run_refuses_it(command, args, tmp_path, monkeypatch,
                                                      capsys):
    """Before: `--out ""` quietly wrote into the default runs/ folder (a plain run
    refuses it)."""
    monkeypatch.chdir(tmp_path)
    for empty in ("", "  "):
        assert command.main(args + ["--out", empty]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line.endswith("--out: the folder name is empty"), line
    # an ESC in the name was echoed raw to the terminal in the "done ... ->" line
    assert command.main(args + ["--out", "a\x1bx"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith("--out: the folder name holds the control character U+001B"), line
    assert list(tmp_path.iterdir()) == []


def test_a_bad_set_of_a_sweep_is_said_once_in_the_users_words(tmp_path, capsys):
    """Before: "vani.toml: common: vani.toml (--set run.realizations=1000.0): ..."
    (the scene twice, "common" for a --set, the value rewritten)."""
    sweep_file = ROOT / "scenes" / "sweep_friction.toml"
    out = tmp_path / "s"
    assert sweep_module.main([str(sweep_file), "--set", "run.realizations=1e3", "--set",
                              "run.t_end=-1", "--out", str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2, lines
    assert lines[0].startswith("--set run.realizations=1e3: run.realizations: ")
    assert lines[1].startswith("--set run.t_end=-1: run.t_end: ")
    assert not out.exists()
