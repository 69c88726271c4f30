"""Realizations run together are independent: realization k of a batch is the run
of seed + k alone (README, "Reproducibility"), down to the last bit of its final
positions, and different seeds start from different placements."""
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import Simulation, load_scene, observables

HOURGLASS = Path(__file__).resolve().parents[1] / "scenes" / "hourglass24.toml"
SEED = 1
BATCH = 3
# Placed next to the neck (x = 25; the taper starts at 17) rather than in the
# upstream straight section, so that disks escape within seconds instead of minutes.
SHORT = ["run.t_end=4.0", "feed.region=[14.0, 22.0]"]


def scene(seed, realizations, extra=()):
    return load_scene(HOURGLASS, SHORT + [f"run.seed={seed}",
                                          f"run.realizations={realizations}", *extra])


def test_seeds_give_different_placements():
    batch = Simulation(scene(SEED, BATCH)).state()["x"]
    for a in range(BATCH):
        for b in range(a + 1, BATCH):
            assert not np.allclose(batch[a], batch[b]), (a, b)
    # ... and the placement of seed + k is that of realization k run alone
    alone = Simulation(scene(SEED + 2, 1)).state()["x"]
    np.testing.assert_array_equal(alone[0], batch[2])


@pytest.fixture(scope="module")
def batch_result():
    return Simulation(scene(SEED, BATCH)).run()


def test_batch_is_not_vacuous(batch_result):
    real = batch_result.summary["realizations"]
    assert [r["seed"] for r in real] == [SEED + k for k in range(BATCH)]
    assert max(r["escapees"] or 0 for r in real) > 0     # something happened to compare


@pytest.mark.parametrize("k", [0, BATCH - 1])
def test_seed_alone_reproduces_its_realization(batch_result, k):
    """Two of the three: at most one realization can be the one whose numbers
    (e.g. the fastest initial flow) would decide something batch-wide."""
    alone = Simulation(scene(SEED + k, 1)).run()
    got, want = alone.summary["realizations"][0], batch_result.summary["realizations"][k]
    for key in ("seed", "status", "escapees", "clogged", "t_clog", "t_stop"):
        assert got[key] == want[key], key
    for key in ("x", "theta", "alive"):
        np.testing.assert_array_equal(alone.final[key][0], batch_result.final[key][k],
                                      err_msg=key)


def in_one_group(make, lanes, monkeypatch):
    """``make()``'s simulation, with ``lanes`` True its batch's pressure solved in
    the lanes of one group (fluid/_gmg_lanes.py: groups as for one thread), so
    that its realizations solve side by side."""
    from taichi_hsdem import limits
    from taichi_hsdem.fluid.gmg import TaichiPressureSolver
    monkeypatch.setattr(TaichiPressureSolver, "lanes", lanes)
    if lanes is True:
        monkeypatch.setattr(limits, "thread_share", lambda: 1)
    sim = make()
    if lanes is True:
        assert sim.fluid.solver._lanes.groups == 1     # one group
    return sim


@pytest.mark.parametrize("lanes", ["auto", True])
def test_flow_rate_inlet_batch_and_alone_give_the_same_bits(lanes, monkeypatch):
    """With a flow-rate inlet the inflow is shared among the inlet cells by their
    permeability: those shares must be summed in the same order in a batch as
    alone (a batch's columns come out Fortran-ordered). The first pressure solve
    and the positions after 0.05 s (about 1850 steps, 6 solves) of vani's
    realization 1, in a batch of two and alone; and with the batch's two solved
    side by side in one group's lanes (fluid/_gmg_lanes.py), the moving bodies'
    term included."""
    vani = HOURGLASS.parent / "vani_phi026.toml"

    def run(seed, realizations):
        sim = in_one_group(lambda: Simulation(load_scene(
            vani, ["run.t_end=0.05", f"run.seed={seed}", f"run.realizations={realizations}",
                   "fluid.workers=1"])), lanes if realizations > 1 else "auto", monkeypatch)
        first = sim.pressure().copy()
        return first, sim.run()

    p_batch, batch = run(0, 2)
    p_alone, alone = run(1, 1)
    assert alone.summary["fluid"]["solves"] >= 5
    np.testing.assert_array_equal(p_alone[0], p_batch[1])
    for key in ("x", "theta", "v", "alive"):
        np.testing.assert_array_equal(alone.final[key][0], batch.final[key][1], err_msg=key)


VANI = HOURGLASS.parent / "vani_phi026.toml"
POLYGONS = HOURGLASS.parent / "polygons.toml"
# Bodies start in or next to the converging section and are fed again at the far
# inlet, so that within tenths of a second they escape and are fed again, in each
# realization at its own times (the feed once refreshed every realization's held
# pressure forces when any one was fed); with disks one realization also clogs,
# and stop_at_clog = false runs on past it.
STREAM = ["feed.inlet=[0.0, 0.0005]", "run.stop_at_clog=false", "fluid.workers=1"]
# about vani's pressure drop at its flow rate (1.18 Pa at the first solve)
PRESSURE = ["fluid.bc=pressure", "fluid.p_in=1.2", "fluid.p_out=0.0"]
DISKS = ["feed.region=[0.0024, 0.0031]", "clog.window=0.1"]
PENTAGONS = ["feed.region=[0.0026, 0.0033]", "particles.count=10", "clog.window=0.04",
             "run.t_end=0.15"]
STREAMS = {  # scene, overrides, whether a realization clogs, realizations run alone
    "disks-flow_rate": (VANI, DISKS + ["run.t_end=0.6"], True, (0, 1)),
    "disks-pressure": (VANI, DISKS + ["run.t_end=0.7"] + PRESSURE, True, (0, 1)),
    "pentagons-flow_rate": (POLYGONS, PENTAGONS, False, (0,)),
    "pentagons-pressure": (POLYGONS, PENTAGONS + PRESSURE, False, (0,)),
}


def stream(name, seed, realizations):
    path, sets, _, _ = STREAMS[name]
    return Simulation(load_scene(path, STREAM + sets + [f"run.seed={seed}",
                                                        f"run.realizations={realizations}"]))


@pytest.mark.parametrize("name, lanes", [(name, "auto") for name in STREAMS]
                         + [("disks-flow_rate", True), ("disks-pressure", True)])
def test_batch_equals_alone_through_escapes_refeeds_and_clogs(name, lanes, monkeypatch):
    """Realization k of a batch of two is seed k alone, to the bit, over a run in
    which bodies escape and are fed again (and, with disks, one realization clogs
    and runs on): results, series, final state. The pentagons (level-set contacts,
    the per-step stepper) compare one realization, to keep the test short. The
    disks again with the batch's pressure solved side by side in the lanes
    (fluid/_gmg_lanes.py), both inlets: a realization that has clogged or is
    re-fed solves beside one that has not."""
    _, _, clogs, alone_ks = STREAMS[name]
    sim = in_one_group(lambda: stream(name, 0, 2), lanes, monkeypatch)
    # the disks run with the close pairs' resistance (its neighbours summed in
    # number order, dem/pairs.py), the pentagons' d/H leaves it off
    assert sim.model.pair_mobility == name.startswith("disks")
    batch = sim.run()
    rows = batch.summary["realizations"]
    for k, row in enumerate(rows):
        dead = int(np.count_nonzero(~batch.final["alive"][k]))
        assert row["status"] == "ok" and row["escapees"] > dead, (k, row)   # fed again
    if clogs:
        assert any(row["clogged"] for row in rows)
    for k in alone_ks:
        alone = stream(name, k, 1).run()
        assert alone.summary["realizations"][0] == rows[k]
        assert [(t, s) for r, t, s in alone.series] == [(t, s) for r, t, s in batch.series
                                                         if r == k]
        for key in ("x", "theta", "v", "omega", "alive"):
            np.testing.assert_array_equal(alone.final[key][0], batch.final[key][k],
                                          err_msg=key)


@pytest.mark.parametrize("lanes, sets", [
    ("auto", []), (True, []), ("auto", PRESSURE + ["run.t_end=0.7"]),
    ("auto", ["fluid.flux_coupling=lagged"])], ids=["flow_rate", "flow_rate-lanes",
                                                    "pressure", "lagged"])
def test_a_stopped_realization_is_left_out_of_the_solves_and_nothing_changes(lanes, sets,
                                                                            monkeypatch):
    """Once a realization has stopped (here it clogs, run.stop_at_clog) and been
    solved once since, the pressure solves leave it out (dem/coupling.py:
    FluidCoupling.skip_stopped; nothing of it moves, so its solve would take no
    iteration). The run's results, series, flow rows, final state and final
    pressure are those of the same batch solved whole at every solve, with one
    realization per thread and in one group's lanes (which then hold the
    running realization alone); with the pressure inlet too. With the lagged
    carried flux a stopped realization's system still changes: it is solved."""
    from taichi_hsdem.dem.coupling import FluidCoupling

    def run(skip):
        monkeypatch.setattr(FluidCoupling, "skip_stopped", skip)
        sim = in_one_group(lambda: Simulation(load_scene(
            VANI, ["feed.inlet=[0.0, 0.0005]", "fluid.workers=1", *DISKS, "run.t_end=0.6",
                   "run.seed=0", "run.realizations=2", *sets])), lanes, monkeypatch)
        solver, asked = sim.fluid.solver, []
        solve = solver.solve

        def spy(*args, only=None, **kwargs):
            asked.append(None if only is None else np.array(only))
            return solve(*args, only=only, **kwargs)
        monkeypatch.setattr(solver, "solve", spy)
        return sim, sim.run(), asked

    sim, res, asked = run(True)
    whole_sim, whole, asked_whole = run(False)
    rows = res.summary["realizations"]
    assert [row["clogged"] for row in rows].count(True) == 1, rows   # one stops early
    left_out = sum(only is not None and not only.all() for only in asked)
    frozen = sim.fluid.frozen.to_numpy().tolist()     # its permeability not redrawn
    if "fluid.flux_coupling=lagged" in sets:
        # the lagged flux's source velocities still change after the stop (left
        # out, the stopped realization's final pressure was 1.7 % off)
        assert left_out == 0 and frozen == [0, 0]
    else:
        assert left_out >= 3
        assert frozen == [int(row["clogged"]) for row in rows]
    assert all(only is None for only in asked_whole)
    assert rows == whole.summary["realizations"]
    assert res.series == whole.series
    assert sim.run_state.flow == whole_sim.run_state.flow
    for key in ("x", "theta", "v", "omega", "alive"):
        np.testing.assert_array_equal(res.final[key], whole.final[key], err_msg=key)
    np.testing.assert_array_equal(sim.fluid.pressure, whole_sim.fluid.pressure)


def test_t_clog_is_the_first_static_arch_after_the_last_escape():
    """t_clog is the first check after the last escape at which the arch test held
    (not the last escape's time), read here from every check's state; the clog was
    declared clog.window after the last escape, with the arch static then."""
    sim = stream("disks-flow_rate", 1, 1)
    checks = []

    def record(s):
        if s.steps % s.check_every == 0:
            checks.append((s.t, int(s.escaped()[0]), s.state()))

    row = sim.run(on_chunk=record).summary["realizations"][0]
    assert row["clogged"] and row["escapees"] > 0
    counts = [0] + [n for _, n, _ in checks]
    last = max(i for i in range(len(checks)) if counts[i + 1] > counts[i])
    def static_at(st):
        return observables.arch_static(sim.model, sim.run_state.u_ref, st, 0)

    static = [i for i in range(last + 1, len(checks)) if static_at(checks[i][2])]
    assert row["t_clog"] == checks[static[0]][0] > checks[last][0]
    assert row["t_last_escape"] == checks[last][0]
    declared = next(t for t, _, st in checks[static[0]:] if t - checks[last][0] >= 0.1
                    and static_at(st))
    assert row["t_clog"] <= declared


def test_escapees_by_species_are_the_bodies_of_each_size_that_left(batch_result):
    """Without feeding, the bodies that escaped are the dead ones: per species, they
    are the counts, which sum to the escapees."""
    assert batch_result.summary["species"] == ["small", "medium", "large"]
    species = batch_result.final["species"]
    sizes_seen = set()
    for k, row in enumerate(batch_result.summary["realizations"]):
        dead = ~batch_result.final["alive"][k]
        want = [int(np.count_nonzero(dead & (species == s))) for s in range(3)]
        assert row["escapees_by_species"] == want and sum(want) == row["escapees"]
        sizes_seen |= {s for s in range(3) if want[s]}
    assert len(sizes_seen) >= 2          # not all of one size
