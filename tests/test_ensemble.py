"""Realizations run together are independent: realization k of a batch is the run
of seed + k alone (README, "Reproducibility"), down to the last bit of its final
positions, and different seeds start from different placements."""
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import Simulation, load_scene

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


def test_flow_rate_inlet_batch_and_alone_give_the_same_bits():
    """With a flow-rate inlet the inflow is shared among the inlet cells by their
    permeability: those shares must be summed in the same order in a batch as
    alone (a batch's columns come out Fortran-ordered). The first pressure solve
    and the positions after 0.05 s (about 1850 steps, 6 solves) of vani's
    realization 1, in a batch of two and alone."""
    vani = HOURGLASS.parent / "vani_phi026.toml"

    def run(seed, realizations):
        sim = Simulation(load_scene(vani, ["run.t_end=0.05", f"run.seed={seed}",
                                           f"run.realizations={realizations}",
                                           "fluid.workers=1"]))
        first = sim.pressure().copy()
        return first, sim.run()

    p_batch, batch = run(0, 2)
    p_alone, alone = run(1, 1)
    assert alone.summary["fluid"]["solves"] >= 5
    np.testing.assert_array_equal(p_alone[0], p_batch[1])
    for key in ("x", "theta", "v", "alive"):
        np.testing.assert_array_equal(alone.final[key][0], batch.final[key][1], err_msg=key)
