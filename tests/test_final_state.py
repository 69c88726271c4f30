"""The final particle states go to final_state.npz (the documented arrays, equal to
``Result.final``), a result file like the others (in the manifest); summary.json
holds statistics only: no ``final_state``, under 20 KB for the main job's 20
realizations. A folder written before the npz existed still reads through its
summary's ``final_state``."""
import json
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import output
from taichi_hsdem.cli import main

ROOT = Path(__file__).resolve().parents[1]
VANI = str(ROOT / "scenes" / "vani_phi026.toml")
ARRAYS = ("x", "theta", "v", "omega", "alive", "species", "seed")


@pytest.fixture(scope="module")
def vani20(tmp_path_factory):
    """The main job (20 realizations) cut short, and the Result it published."""
    out = tmp_path_factory.mktemp("final") / "vani"
    published = []
    publish = output.Staging.publish

    def keep(self, result, extra):
        published.append(result)
        return publish(self, result, extra)

    output.Staging.publish = keep
    try:
        assert main([VANI, "--realizations", "20", "--no-video", "--quiet", "--out", str(out),
                     "--set", "run.t_end=0.2"]) == 0
    finally:
        output.Staging.publish = publish
    (result,) = published
    return out, result


def test_final_state_npz_holds_the_documented_arrays_equal_to_result_final(vani20):
    out, result = vani20
    assert output.FINAL_STATE_ARRAYS == ARRAYS
    with np.load(out / "final_state.npz") as f:
        assert sorted(f.files) == sorted(ARRAYS)
        R, N = f["alive"].shape
        assert R == 20 and N > 0
        shapes = {"x": (R, N, 2), "theta": (R, N), "v": (R, N, 2), "omega": (R, N),
                  "alive": (R, N), "species": (N,), "seed": (R,)}
        for key in ARRAYS:
            assert f[key].shape == shapes[key], key
        for key in ("x", "theta", "v", "omega", "alive", "species"):
            np.testing.assert_array_equal(f[key], result.final[key], err_msg=key)
        assert f["alive"].dtype == bool
        summary = json.loads((out / "summary.json").read_text())
        assert f["seed"].tolist() == [r["seed"] for r in summary["realizations"]]
    # a result file like the others: listed in the folder's manifest
    manifest = json.loads((out / output.MANIFEST).read_text())["files"]
    assert "final_state.npz" in manifest and "final_state.npz" in output.RESULT_FILES


def test_summary_json_is_small_and_holds_no_state(vani20):
    out, result = vani20
    summary = json.loads((out / "summary.json").read_text())
    assert "final_state" not in summary and "final_state" not in result.summary
    assert (out / "summary.json").stat().st_size < 20_000
    assert len(summary["realizations"]) == 20


def test_an_older_folder_reads_through_its_summary(vani20, tmp_path):
    """A folder from before final_state.npz: read_final_state falls back to the
    summary's final_state (positions, angles, alive flags, species); with
    neither, one clear error."""
    out, result = vani20
    summary = json.loads((out / "summary.json").read_text())
    fin = result.final
    summary["final_state"] = [
        {"x": fin["x"][r].tolist(), "theta": fin["theta"][r].tolist(),
         "alive": fin["alive"][r].tolist(), "species": fin["species"].tolist()}
        for r in range(len(summary["realizations"]))]
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    old = output.read_final_state(tmp_path)
    for key in ("x", "theta", "alive", "species"):
        np.testing.assert_array_equal(old[key], fin[key], err_msg=key)
    assert old["seed"].tolist() == [r["seed"] for r in summary["realizations"]]
    del summary["final_state"]
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(output.NoFinalState, match="no final_state.npz"):
        output.read_final_state(tmp_path)


def test_a_full_disk_writing_the_final_state_keeps_the_earlier_result(tmp_path, capsys,
                                                                      monkeypatch):
    """final_state.npz is staged like every result: a failure writing it is one
    line (exit 1) and leaves the earlier result byte for byte."""
    import errno
    import os
    out = tmp_path / "o"
    args = [str(ROOT / "scenes" / "hourglass24.toml"), "--out", str(out), "--quiet",
            "--no-video", "--set", "run.t_end=0.1"]
    assert main(args) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert "final_state.npz" in before

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "savez_compressed", full)
    capsys.readouterr()
    assert main(args + ["--set", "particles.friction=0.1"]) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and err.count("\n") == 1, err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
