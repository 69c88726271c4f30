"""The studies' refusals found by tools/fuzz_cli.py: bad input gets one clear line
on stderr in the user's terms and exit 2, writes nothing when refused before any
work, and never a traceback."""
import json
import os
from pathlib import Path

import pytest

from taichi_hsdem.studies import arches

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
