"""The studies' output folders (issue 45): a lock so that two studies never mix, a
manifest so that the user's files are never replaced, a finished point never
rewritten by another study, a file or a dangling link where a folder goes refused,
a huge grid refused before it is built; each with exit 2 and one line."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from taichi_hsdem import output
from taichi_hsdem.studies import arches, calibrate, figures
from taichi_hsdem.studies import sweep as sweep_module
from taichi_hsdem.studies.folder import STUDY_MANIFEST, StudyFolder, StudyFolderError
from taichi_hsdem.studies.sweep import (MAX_POINTS, SweepError, expand_grid, load_sweep,
                                        point_folder, run_sweep)

ROOT = Path(__file__).resolve().parents[1]
HOURGLASS = ROOT / "scenes" / "hourglass24.toml"
TINY = {"run.t_end": 0.3}
POINT = point_folder({"particles.friction": 0.2})


def sweep_file(folder: Path, name="s.toml", frictions=(0.2,), t_end=0.3,
               realizations=1) -> Path:
    path = folder / name
    path.write_text(f'scene = "{HOURGLASS.as_posix()}"\n[common]\n"run.t_end" = {t_end}\n'
                    f'"run.realizations" = {realizations}\n[grid]\n"particles.friction" = '
                    f'[{", ".join(map(str, frictions))}]\n')
    return path


def sweep(argv, capsys):
    """The command's exit status and its stderr lines."""
    code = sweep_module.main([*map(str, argv), "--quiet"])
    return code, capsys.readouterr().err.strip().splitlines()


def hold_lock(folder: Path):
    """Another process holding ``folder``'s lock (as a study or run writing it)."""
    folder.mkdir(parents=True, exist_ok=True)
    code = ("import fcntl, sys, time; fh = open(sys.argv[1], 'a+'); "
            "fcntl.flock(fh, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(folder / output.LOCK)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


# ------------------------------------------------------------------------ 1. the lock

def test_a_second_study_into_a_folder_being_written_is_refused(tmp_path, capsys):
    out = tmp_path / "p"
    holder = hold_lock(out)
    try:
        code, err = sweep([sweep_file(tmp_path), "--out", out], capsys)
        assert code == 2 and len(err) == 1, err
        assert "another study (or run) is writing to" in err[0] and str(out) in err[0]
        assert sorted(os.listdir(out)) == [output.LOCK]       # nothing written
        # the figures and the calibration take the same lock
        assert figures.main(["friction", "--quick", "--out", str(out), "--quiet"]) == 2
        assert "another study (or run) is writing" in capsys.readouterr().err
        assert calibrate.main([str(HOURGLASS), "--param", "particles.friction", "--lo",
                               "0.1", "--hi", "0.9", "--target", "5", "--quick", "--out",
                               str(out), "--quiet"]) == 2
        assert "another study (or run) is writing" in capsys.readouterr().err
    finally:
        holder.kill()
        holder.wait()


def test_the_lock_is_released_and_a_created_empty_folder_removed(tmp_path):
    out = tmp_path / "new"
    with pytest.raises(StudyFolderError, match="yours"):
        with StudyFolder(out, "sweep"):
            assert output.in_use(out)
            raise StudyFolderError("yours")
    assert not out.exists()
    with StudyFolder(out, "sweep") as folder:
        folder.claim(["sweep.csv"])
    assert not output.in_use(out) and not (out / output.LOCK).exists()
    assert json.loads((out / STUDY_MANIFEST).read_text()) == {"study": "sweep",
                                                              "files": ["sweep.csv"]}


# -------------------------------------------------------------- 2. the user's files

@pytest.mark.parametrize("name", ["sweep.csv", "index.json", f"{POINT}/summary.json",
                                  f"{POINT}/escapees.csv"])
def test_a_sweep_never_replaces_the_users_files(tmp_path, capsys, name):
    out = tmp_path / "p"
    (out / name).parent.mkdir(parents=True)
    (out / name).write_text("mine\n")
    code, err = sweep([sweep_file(tmp_path), "--out", out], capsys)
    assert code == 2 and len(err) == 1, err
    assert str(out / name) in err[0] and "move it" in err[0]
    assert (out / name).read_text() == "mine\n"
    assert not (out / "sweep.csv").exists() or name == "sweep.csv"


def test_a_figure_and_a_calibration_never_replace_the_users_files(tmp_path, capsys):
    out = tmp_path / "f"
    out.mkdir()
    (out / "points.csv").write_text("mine\n")
    assert figures.main(["friction", "--quick", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out / "points.csv") in err[0], err
    (out / "calibration.json").write_text("{}\n")
    assert calibrate.main([str(HOURGLASS), "--param", "particles.friction", "--lo", "0.1",
                           "--hi", "0.9", "--target", "5", "--quick", "--out", str(out),
                           "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out / "calibration.json") in err[0], err
    assert (out / "points.csv").read_text() == "mine\n"
    assert (out / "calibration.json").read_text() == "{}\n"


def test_a_folder_of_another_kind_of_study_is_refused(tmp_path, capsys):
    out = tmp_path / "p"
    out.mkdir()
    (out / STUDY_MANIFEST).write_text(json.dumps({"study": "figures friction",
                                                  "files": ["points.csv"]}))
    code, err = sweep([sweep_file(tmp_path), "--out", out], capsys)
    assert code == 2 and len(err) == 1 and "another study (figures friction)" in err[0], err


def test_points_resume_and_a_finished_point_is_never_rewritten_by_another_sweep(tmp_path,
                                                                                 capsys):
    out = tmp_path / "p"
    a = sweep_file(tmp_path, "a.toml", frictions=(0.2, 0.4))
    code, err = sweep([a, "--out", out], capsys)
    assert code == 0, err
    manifest = json.loads((out / STUDY_MANIFEST).read_text())
    assert manifest == {"study": "sweep", "files": ["index.json", "sweep.csv", "sweep.png"]}
    folder = out / POINT
    # a point is a run into its folder: a run's files (no video), each in its manifest
    listed = set(json.loads((folder / output.MANIFEST).read_text())["files"])
    assert listed == {p.name for p in folder.iterdir() if not p.name.startswith(".")}
    assert {"summary.json", "escapees.csv", "final_state.npz", "scene.resolved.toml",
            "arches.csv", "escapees.png"} <= listed
    stamp = (folder / "summary.json").stat().st_mtime_ns
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["sweep"]["study"] == str(a.resolve())

    # 4. resume point by point: the same sweep again runs nothing; a point whose
    # summary is gone runs again, alone
    rows = run_sweep(HOURGLASS, [{"particles.friction": 0.2}, {"particles.friction": 0.4}],
                     out, common={**TINY, "run.realizations": 1}, study=str(a.resolve()))
    assert [r["status"] for r in rows] == ["skipped", "skipped"]
    (out / point_folder({"particles.friction": 0.4}) / "summary.json").unlink()
    code, err = sweep([a, "--out", out], capsys)
    assert code == 0 and (folder / "summary.json").stat().st_mtime_ns == stamp

    # another sweep file (another scene: t_end 0.2) over the same point: refused
    b = sweep_file(tmp_path, "b.toml", frictions=(0.2,), t_end=0.2)
    code, err = sweep([b, "--out", out], capsys)
    assert code == 2 and len(err) == 1, err
    assert str(folder) in err[0] and "another sweep" in err[0] and str(a.resolve()) in err[0]
    assert (folder / "summary.json").stat().st_mtime_ns == stamp
    # ... with --no-resume too
    code, err = sweep([b, "--out", out, "--no-resume"], capsys)
    assert code == 2 and (folder / "summary.json").stat().st_mtime_ns == stamp
    # a plain run's result in a point's folder is not rewritten either
    del summary["sweep"]
    (folder / "summary.json").write_text(json.dumps(summary))
    code, err = sweep([a, "--out", out], capsys)
    assert code == 2 and len(err) == 1 and "finished result of a run" in err[0], err


# --------------------------------------------------- 3. what gave tracebacks before

def test_a_huge_grid_is_refused_with_its_point_count_before_it_is_built(tmp_path, capsys):
    path = tmp_path / "huge.toml"
    grid = "\n".join(f'"run.seed{k}" = [{", ".join(str(v) for v in range(20))}]'
                     for k in range(10))
    path.write_text(f'scene = "{HOURGLASS.as_posix()}"\n[grid]\n{grid}\n')
    with pytest.raises(SweepError, match=r"20\^10|10,240,000,000,000 points"):
        load_sweep(path)
    code, err = sweep([path], capsys)
    assert code == 2 and len(err) == 1, err
    assert "10,240,000,000,000 points" in err[0] and f"{MAX_POINTS:,}" in err[0]
    with pytest.raises(SweepError, match="10,240,000,000,000 points"):
        expand_grid({f"k{k}": list(range(20)) for k in range(10)})
    assert len(expand_grid({"a": list(range(100)), "b": list(range(100))})) == MAX_POINTS


@pytest.mark.parametrize("kind", ["file", "dangling link", "under a file"])
def test_sweep_out_that_cannot_be_a_folder_is_one_line(tmp_path, capsys, kind):
    target = tmp_path / "out"
    if kind == "file":
        target.write_text("x")
    elif kind == "dangling link":
        target.symlink_to(tmp_path / "nowhere")
    else:
        (tmp_path / "f").write_text("x")
        target = tmp_path / "f" / "out"
    code, err = sweep([sweep_file(tmp_path), "--out", target], capsys)
    assert code == 2 and len(err) == 1 and err[0].startswith(f"--out: {target}"), err
    assert not (tmp_path / "nowhere").exists()


@pytest.mark.parametrize("kind", ["file", "dangling link"])
def test_a_file_where_a_point_folder_goes_is_one_line(tmp_path, capsys, kind):
    out = tmp_path / "p"
    out.mkdir()
    if kind == "file":
        (out / POINT).write_text("mine")
    else:
        (out / POINT).symlink_to(tmp_path / "nowhere")
    code, err = sweep([sweep_file(tmp_path), "--out", out], capsys)
    assert code == 2 and len(err) == 1 and err[0].startswith(str(out / POINT)), err
    assert not (out / "sweep.csv").exists()


def test_figures_points_folder_taken_by_a_file_is_one_line(tmp_path, capsys):
    out = tmp_path / "f"
    out.mkdir()
    (out / "points").write_text("mine")
    assert figures.main(["friction", "--quick", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out / "points") in err[0], err


@pytest.mark.parametrize("figure", [{"figure": "friction", "points": []}, [1, 2],
                                    {"scene": str(HOURGLASS), "points": [{"label": 1}]},
                                    # was "internal error (ValueError: Number of rows ...)"
                                    {"scene": str(HOURGLASS), "points": []}])
def test_arches_on_a_figure_json_it_cannot_read_is_one_line(tmp_path, capsys, figure):
    (tmp_path / "figure.json").write_text(json.dumps(figure))
    assert arches.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "figure.json" in err[0] and "not the figure.json" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure.json"]    # nothing written


def test_the_arch_census_never_replaces_the_users_arches_csv(tmp_path, capsys):
    from test_arches import _figure_folder
    folder = _figure_folder(tmp_path)
    (folder / "arches.csv").write_text("mine\n")
    assert arches.main([str(folder), "--examples", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(folder / "arches.csv") in err[0], err
    assert (folder / "arches.csv").read_text() == "mine\n"
    (folder / "arches.csv").unlink()
    assert arches.main([str(folder), "--examples", "2"]) == 0      # then its own, twice
    assert arches.main([str(folder), "--examples", "2"]) == 0
    assert set(json.loads((folder / STUDY_MANIFEST).read_text())["files"]) == {
        "arches.csv", "arches.png"}
