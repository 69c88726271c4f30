"""Study points on a Dask LocalCluster of two workers give the results of the same
points run in this process (the same seeds, the same bits), and nothing is written
outside the output folder."""
import json
import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="the cluster extra brings dask.distributed")

from taichi_hsdem.studies.cluster import ClusterError, parse  # noqa: E402
from taichi_hsdem.studies.sweep import run_sweep  # noqa: E402

HOURGLASS = Path(__file__).resolve().parents[1] / "scenes" / "hourglass24.toml"
POINTS = [{"particles.friction": 0.2}, {"particles.friction": 0.6}]
COMMON = {"run.t_end": 1.5, "run.realizations": 2, "feed.region": [14.0, 22.0]}


def _results(out):
    keep = ("realizations", "steps", "statistics")
    out_ = {}
    for p in sorted(out.iterdir()):
        if (p / "summary.json").is_file():
            out_[p.name] = {k: json.loads((p / "summary.json").read_text())[k] for k in keep}
            with np.load(p / "final_state.npz") as f:     # the point's final state
                out_[p.name]["final_state"] = {k: f[k].tolist() for k in f.files}
    return out_


def test_sweep_on_a_local_cluster_gives_the_in_process_results(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    here = run_sweep(HOURGLASS, POINTS, tmp_path / "here", common=COMMON)
    there = run_sweep(HOURGLASS, POINTS, tmp_path / "there", common=COMMON,
                      cluster="local:2")
    assert [r["status"] for r in here] == [r["status"] for r in there] == ["ran", "ran"]
    a, b = _results(tmp_path / "here"), _results(tmp_path / "there")
    assert len(a) == 2 and a == b
    # nothing but the two output folders in the working directory
    assert sorted(os.listdir(tmp_path)) == ["here", "there"]


def test_cluster_argument_is_checked():
    assert parse(None) is None and parse("local:3") == ("local", 3)
    assert parse("tcp://10.0.0.1:8786") == ("address", "tcp://10.0.0.1:8786")
    with pytest.raises(ClusterError, match="local:N needs a whole number"):
        parse("local:two")


@pytest.mark.parametrize("spec, why", [
    ("tcp://[:::1", "not a scheduler address"),          # Dask took about 10 s on it
    ("tcp://host:99999", "not a scheduler address"),
    ("tcp://:8786", "names no host"),
])
def test_a_malformed_address_is_refused_before_any_wait(spec, why):
    with pytest.raises(ClusterError, match=why):
        parse(spec)
    assert parse("tcp://[::1]:8786") == ("address", "tcp://[::1]:8786")
    assert parse("10.0.0.1:8786") == ("address", "10.0.0.1:8786")
