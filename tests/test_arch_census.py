"""The arch census every run takes at its checks (observables.census_arches, the
run folder's arches.csv, ``python -m taichi_hsdem arches`` on a run folder),
against arches known otherwise: a pair wedged where statics puts it, chains moved
by hand (rolled, slid, escaped), a channel-wide chain out of the neck's reach, and
a real run's clog (its time, and its arch as the figure analysis finds it in the
final state)."""
import csv
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import arena_scene, make_sim

from taichi_hsdem import Simulation, checkpoint, load_scene, observables, output
from taichi_hsdem.cli import main
from taichi_hsdem.resolve import resolve
from taichi_hsdem.runstate import RunState
from taichi_hsdem.studies import arches

ROOT = Path(__file__).resolve().parents[1]
VANI = ROOT / "scenes" / "vani_phi026.toml"
# A 45 degree funnel (tests/test_mechanics.py's): lower side x - y = 5.6, upper
# side x + y = 15.6, a neck 1.2 wide at x = 10; disks of diameter 1.
FUNNEL = [[0.0, 0.0], [5.6, 0.0], [10.0, 4.4], [10.0, 5.6], [5.6, 10.0], [0.0, 10.0]]
NECK_X = 9.9                # the scene's geometry.constriction_x: the model's neck
KN, LOAD = 1.0e4, 2.0


def _funnel(count=2):
    scene = arena_scene([{"shape": "circle", "diameter": 1.0, "count": count}], kn=KN,
                        friction=0.0, restitution=0.5, xi=5.0, dt_safety=0.1)
    scene["geometry"].update(outline=FUNNEL, obstacles=[], constriction_x=NECK_X,
                             escape_offset=0.05)
    scene["feed"]["region"] = [1.0, 9.0]
    scene["run"]["t_end"] = 0.5
    return scene


def _wedged():
    """The pair's centres at rest under LOAD along +x, side by side about y = 5:
    by statics each disk is pressed into the other by LOAD / KN and into its side
    by sqrt(2) LOAD / KN (tests/test_mechanics.py holds a run to it)."""
    pair, wall = LOAD / KN, math.sqrt(2) * LOAD / KN
    y = 0.5 - pair / 2
    x = 15.6 - (5.0 + y) - math.sqrt(2) * (0.5 - wall)
    return np.array([[x, 5.0 - y], [x, 5.0 + y]])


def _state(x, theta=None, alive=None):
    """One realization's check state (Simulation.state()'s arrays) of centres ``x``."""
    x = np.asarray(x, float)
    return {"x": x[None], "theta": np.zeros((1, len(x))) if theta is None else
            np.asarray(theta, float)[None],
            "alive": np.ones((1, len(x)), bool) if alive is None else np.asarray(alive)[None]}


def _census(count=2):
    model = resolve(load_scene(_funnel(count)))
    return model, observables.ArchCensus(model), RunState.start([0], count, 1, 0)


def test_a_pair_wedged_in_a_funnel_under_a_load_is_one_arch_of_two_that_holds():
    sim = make_sim(_funnel())
    x = _wedged()
    sim.set_state([x])
    sim.set_external_load(force=[[[LOAD, 0.0], [LOAD, 0.0]]])
    result = sim.run()
    assert np.abs(sim.state()["x"][0] - x).max() < 1e-9          # held where statics says
    (a,) = result.arches
    # found at the first check, the lower disk first, half a diameter short of the neck
    assert (a.realization, a.arch, a.held, a.t_broken, a.count, a.ids, a.failure) == \
        (0, 0, True, None, 2, (0, 1), "held")
    assert a.t_formed == pytest.approx(sim.check_every * sim.dt, rel=1e-12)
    assert a.x_over_d == pytest.approx(x[0, 0] - NECK_X, abs=1e-12)
    assert x[0, 0] - NECK_X == pytest.approx(-0.5066, abs=1e-4)
    s = result.summary
    assert s["realizations"][0]["arches_formed"] == s["arches_formed"] == s["arches_held"] == 1


def test_a_geometry_without_two_side_walls_takes_no_census(tmp_path):
    sim = make_sim(arena_scene([{"shape": "circle", "diameter": 1.0, "count": 1}],
                               run__t_end=0.05))      # a box: two blocks seal its ends
    sim.set_state([[[5.0, 5.0]]])
    assert sim.census is None
    result = sim.run()
    s = result.summary
    assert result.arches == [] and s["arches_formed"] is s["arches_held"] is None
    assert s["realizations"][0]["arches_formed"] is None
    output.write_arches(result.arches, ["ok"], tmp_path)
    assert (tmp_path / "arches.csv").read_text() == \
        "realization,arch,t_formed,t_broken,held,count,ids,x_over_d,failure\n"


def test_no_chain_from_wall_to_wall_is_no_arch():
    model, census, rs = _census(count=12)
    x = np.zeros((12, 2))
    x[:2] = _wedged()
    # ten disks touching in a column across the 10 wide inlet channel at x = 3: a
    # chain from wall to wall, 6.9 diameters upstream of the neck
    x[2:] = np.column_stack([np.full(10, 3.0), 0.5 + np.arange(10)])
    apart = x.copy()
    apart[1, 1] += 0.02                      # a gap of 0.02 d across the centre line
    cases = {"pulled apart": (apart, [True, True] + [False] * 10),
             "the lower one alone": (x, [True] + [False] * 11),
             "the column beyond the census's reach": (x, [False, False] + [True] * 10)}
    for name, (pos, alive) in cases.items():
        st = _state(pos, alive=np.array(alive))
        assert census.chain(st["x"][0], st["theta"][0], st["alive"][0]) is None, name
        observables.census_arches(rs, census, st, 0)
        assert rs.arches == [], name
    # the whole channel searched (the figure analysis) finds the column, and the
    # pair within 0.03 d
    shapes = [s.shape for s in model.species]
    assert arches.arch_chain(shapes, x, np.zeros(12), [False, False] + [True] * 10,
                             model.species_of_particle, census.sides, NECK_X, 1.0) == \
        list(range(2, 12))
    assert arches.arch_chain(shapes, apart, np.zeros(12), [True, True] + [False] * 10,
                             model.species_of_particle, census.sides, NECK_X, 1.0,
                             tol=0.03) == [0, 1]


def _broken(s, turn):
    """The wedged pair moved back by ``s`` along its sides, apart, each turned by
    ``turn`` (counter-clockwise for the lower one, the upper one mirrored)."""
    x = _wedged()
    x[0] += -s * np.array([1.0, 1.0]) / math.sqrt(2)        # down the lower side
    x[1] += s * np.array([-1.0, 1.0]) / math.sqrt(2)        # up the upper side
    return x, [turn, -turn]


# The lower disk touches its side (x - y = 5.6) at r (1, -1)/sqrt(2) from its
# centre; moved by -s (1, 1)/sqrt(2), that point stays put (no slip) when the disk
# turns by s / r counter-clockwise: it rolled. Not turned, it slid by s on each side.
@pytest.mark.parametrize("turn, failure", [(0.05 / 0.5, "rolled"), (0.0, "slid")],
                         ids=["rolled", "slid"])
def test_a_pair_that_left_its_wedge_rolled_or_slid_as_its_motion_says(turn, failure):
    _, census, rs = _census()
    observables.census_arches(rs, census, _state(_wedged()), 0)
    rs.t = 0.1
    x, theta = _broken(0.05, turn)
    st = _state(x, theta)
    assert census.chain(st["x"][0], st["theta"][0], st["alive"][0]) is None
    observables.census_arches(rs, census, st, 0)
    (a,) = observables.arch_rows(rs)
    assert (a.t_formed, a.t_broken, a.held, a.ids, a.failure) == (0.0, 0.1, False, (0, 1),
                                                                  failure)


def test_an_arch_whose_member_escapes_failed_by_escaping():
    model, census, rs = _census()
    window = model.scene.clog.window

    def check(t, x, theta=(0.0, 0.0), alive=(True, True)):
        rs.t = t
        observables.census_arches(rs, census, _state(x, theta, np.array(alive)), 0)

    slid, _ = _broken(0.05, 0.0)
    # gone through the escape line between two checks: escaped at once
    check(0.0, _wedged())
    check(0.1, _wedged(), alive=(True, False))
    # slid, then one of the pair escapes within clog.window: escaped after all
    check(0.2, _wedged())
    check(0.3, slid)
    check(0.3 + 0.5 * window, slid, alive=(False, True))
    # slid, and the escape came clog.window after: it stays slid
    check(1.0, _wedged())
    check(1.1, slid)
    check(1.1 + window, slid)
    check(1.1 + 1.5 * window, slid, alive=(False, True))
    # slid, a new arch formed within clog.window, then one of the first escapes:
    # the new one escaped, the first stays slid
    check(2.0, _wedged())
    check(2.1, slid)
    check(2.1 + 0.25 * window, _wedged())
    check(2.1 + 0.5 * window, _wedged(), alive=(False, True))
    rows = [(a.arch, a.t_formed, a.t_broken, a.failure) for a in observables.arch_rows(rs)]
    assert rows == [(0, 0.0, 0.1, "escaped"), (1, 0.2, 0.3, "escaped"), (2, 1.0, 1.1, "slid"),
                    (3, 2.0, 2.1, "slid"),
                    (4, 2.1 + 0.25 * window, 2.1 + 0.5 * window, "escaped")]


def test_the_same_arch_keeps_most_of_its_particles():
    assert observables.same_arch([3, 5], [3, 5])
    assert observables.same_arch([3, 5, 8], [3, 8])             # one left, two of three kept
    assert observables.same_arch([3, 8], [3, 5, 8])             # one joined
    assert observables.same_arch([1, 2, 3, 4, 5], [1, 2, 3, 4, 6])     # one of five swapped
    assert not observables.same_arch([3, 5], [3, 7])            # half is not most
    assert not observables.same_arch([3, 5], [3, 5, 7, 9])
    assert not observables.same_arch([3, 5], [7, 9])


# ------------------------------------------------------------------ a real run

# clog.window shorter than the scene's 0.5 s, so that a clog is declared by 1.5 s
SETS = ["run.t_end=1.5", "run.realizations=2", "fluid.workers=1", "clog.window=0.25"]


@pytest.fixture(scope="module")
def vani_run(tmp_path_factory):
    """The vani scene's folder, 2 realizations to t = 1.5 s (about 7 s here)."""
    out = tmp_path_factory.mktemp("census") / "run"
    assert main([str(VANI), "--out", str(out), "--quiet",
                 *sum((["--set", s] for s in SETS), [])]) == 0
    return out


def _rows(folder):
    with open(folder / "arches.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_a_real_runs_clogging_arch_formed_as_the_clog_did_and_is_the_final_states_arch(
        vani_run):
    summary = json.loads((vani_run / "summary.json").read_text())
    final = output.read_final_state(vani_run)
    rows = _rows(vani_run)
    model = resolve(load_scene(VANI, SETS))
    census = observables.ArchCensus(model)
    shapes = [s.shape for s in model.species]
    # measured: realization 1 clogs at 0.79 s on a pair, realization 0 forms no
    # arch in 1.5 s
    assert any(real["clogged"] for real in summary["realizations"]) and rows
    for k, real in enumerate(summary["realizations"]):
        mine = [a for a in rows if a["realization"] == str(k)]
        assert real["arches_formed"] == len(mine)
        assert [a["arch"] for a in mine] == [str(n) for n in range(len(mine))]
        for a in mine[:-1]:                          # only the latest can hold
            assert a["held"] == "false" and a["failure"] in ("escaped", "rolled", "slid")
            assert float(a["t_formed"]) < float(a["t_broken"])
        if not real["clogged"]:
            continue
        held = mine[-1]
        assert (held["held"], held["t_broken"], held["failure"]) == ("true", "", "held")
        # the arch touches, then its particles settle until the clog criterion
        # finds them at rest (t_clog), which also waits for the disks already
        # past the arch to escape (measured: the arch at 0.736 s, the last escape
        # 0.758 s, t_clog 0.793 s; with the earlier defaults one check after the
        # arch formed, four before the plates' spin drag)
        t_formed = float(held["t_formed"])
        assert t_formed <= real["t_clog"] <= max(t_formed, real["t_last_escape"]) + 0.05
        # the arch of the final state that the figure analysis finds (every
        # particle searched), at the position the census gave
        fs = {key: final[key][k] for key in ("x", "theta", "alive")}
        fs["species"] = final["species"]
        found = arches.find_arch(shapes, fs["x"], fs["theta"], fs["alive"], fs["species"],
                                 census.sides, census.neck_x, census.d_b)["particles"]
        assert [int(i) for i in held["ids"].split()] == found and int(held["count"]) == \
            len(found)
        x_mean = np.mean(np.array(fs["x"])[found, 0])
        assert float(held["x_over_d"]) == pytest.approx(
            (x_mean - census.neck_x) / model.d_min, abs=1e-12)
    assert summary["arches_formed"] == len(rows)
    assert summary["arches_held"] == sum(a["held"] == "true" for a in rows)


def test_the_census_changes_no_other_result(vani_run, tmp_path):
    sim = Simulation(load_scene(VANI, SETS))
    sim.census = None
    result = sim.run()
    summary = json.loads((vani_run / "summary.json").read_text())
    without = json.loads(json.dumps(output.json_safe(result.summary)))
    final = output.read_final_state(vani_run)
    for key, value in result.final.items():
        np.testing.assert_array_equal(value, final[key], err_msg=key)
    for row in summary["realizations"] + without["realizations"]:
        row.pop("arches_formed")
    assert without["realizations"] == summary["realizations"]
    output.write_series(result.series, ["ok", "ok"], tmp_path)
    assert (tmp_path / "escapees.csv").read_text() == (vani_run / "escapees.csv").read_text()


def test_a_run_stopped_while_an_arch_holds_and_resumed_writes_the_same_arches_csv(
        vani_run, tmp_path):
    held = [float(a["t_formed"]) for a in _rows(vani_run) if a["held"] == "true"]
    first = Simulation(load_scene(VANI, SETS))
    first.run(stop=lambda: first.t > min(held))
    assert any(a.t_broken is None for a in first.run_state.arches)
    saved = checkpoint.save(first, tmp_path / "checkpoint.npz")
    second = Simulation(load_scene(VANI, SETS), place_particles=False)
    checkpoint.restore(second, saved)
    result = second.run()
    output.write_arches(result.arches, [r["status"] for r in result.summary["realizations"]],
                        tmp_path)
    assert (tmp_path / "arches.csv").read_text() == (vani_run / "arches.csv").read_text()


def test_the_arches_command_prints_a_run_folder_and_refuses_what_is_no_run(
        vani_run, tmp_path, capsys):
    rows = _rows(vani_run)
    assert main(["arches", str(vani_run)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3
    for k in (0, 1):
        mine = [a for a in rows if a["realization"] == str(k)]
        word = "arch" if len(mine) == 1 else "arches"
        assert lines[k].startswith(f"realization {k} (seed {k}): {len(mine)} {word} formed")
        for a in mine:
            if a["held"] == "true":
                assert (f"held: particles {a['ids']} at x = {float(a['x_over_d']):+.2f} d "
                        f"from the neck") in lines[k]
    held = sum(a["held"] == "true" for a in rows)
    word = "arch" if len(rows) == 1 else "arches"
    assert lines[2].startswith(f"total: {len(rows)} {word} formed in 2 realizations, "
                               f"{held} held")
    assert main(["arches", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "neither a run folder" in err, err
    older = tmp_path / "older"
    shutil.copytree(vani_run, older)
    (older / "arches.csv").unlink()
    assert main(["arches", str(older)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "made before runs took an arch census" in err, err
    assert main(["arches", str(vani_run), "--tol", "0.02"]) == 2
    assert "for figure folders" in capsys.readouterr().err


@pytest.mark.parametrize("edit, phrase", [
    (lambda a: a.update(ids=[10 ** 6], x=[[0.0, 0.0]], theta=[0.0]), "particle ids beyond"),
    (lambda a: a.update(t_formed=-1.0), "host.arches[0]: not an arch record"),
    (lambda a: a.update(failure="melted"), "host.arches[0]: not an arch record"),
], ids=["id out of range", "negative time", "unknown failure"])
def test_a_checkpoint_with_a_damaged_census_is_refused_in_one_line(vani_run, tmp_path, capsys,
                                                                   edit, phrase):
    folder = tmp_path / "run"
    shutil.copytree(vani_run, folder)
    with np.load(folder / checkpoint.FILE) as data:
        arrays = {k: data[k] for k in data.files}
    header = json.loads(bytes(arrays["header"]).decode())
    edit(header["host"]["arches"][0])
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    with open(folder / checkpoint.FILE, "wb") as fh:
        np.savez(fh, **arrays)
    assert main(["--resume", str(folder), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and phrase in err, err


def test_the_arches_lines_read_right_for_one_realization_and_no_arch():
    """Before: "formed in 1 realizations" and "sizes  (mean nan)"."""
    from taichi_hsdem.studies import arches
    summary = {"realizations": [{"seed": 4, "status": "ok"}]}
    lines = arches.run_lines(summary, [[]])
    assert lines == ["realization 0 (seed 4): 0 arches formed; none held",
                     "total: 0 arches formed in 1 realization, 0 held"]
    assert arches.summary_line("mu=0.9", []) == "mu=0.9: 0 clogged, arch found in 0; no sizes"
