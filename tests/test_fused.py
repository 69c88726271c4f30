"""The fused stepper (``run.stepping = "fused"``, many steps per kernel launch) is the
per-step path's arithmetic in another order of launches: the same scene gives the
same bits on both, also when a neighbour rebuild overflows inside a launch and the
realization has to stop and catch up."""
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import Simulation, load_scene
from taichi_hsdem.scene import SceneError

SCENES = Path(__file__).resolve().parents[1] / "scenes"
HOURGLASS = SCENES / "hourglass24.toml"
# Placed next to the neck, as in test_ensemble, so that disks touch, jam and escape
# within the run: contacts, shear history, walls, escapes and re-feeding all happen.
# Particles as fixed obstacles: the packing at the neck that overflows the
# capacities below was found with that trajectory (the kernels under test do not
# depend on it).
SHORT = ["run.t_end=4.0", "feed.region=[14.0, 22.0]", "run.realizations=2",
         "run.seed=3", "run.stop_at_clog=false", "fluid.particle_flux=false"]


def run(stepping, extra=(), shrink=False, device_rebuilds=False):
    """The hourglass run; ``shrink``: neighbour capacities of one, so that the
    loose initial placement just fits and the denser packing at the neck overflows
    them in the kernel's own rebuilds; ``device_rebuilds``: the per-step path
    rebuilds its lists on the device, as on a GPU."""
    caps = (1, 1) if shrink else (8, 16)
    sim = Simulation(load_scene(HOURGLASS, SHORT + [f"run.stepping={stepping}", *extra]),
                     neighbor_capacities=caps)
    sim.initial_caps = (sim.neighbors.cell_cap, sim.neighbors.nbr_cap)
    sim.device_rebuilds = device_rebuilds
    advance, chunk = sim.advance, sim._steps_per_body
    sim.calls = {"advance": 0, "chunks": 0}

    def counted_advance(n=1):
        sim.calls["advance"] += 1
        advance(n)

    def counted_chunk(n):
        sim.calls["chunks"] += 1
        return chunk(n)
    sim.advance, sim._steps_per_body = counted_advance, counted_chunk
    res = sim.run()
    return sim, res


@pytest.fixture(scope="module")
def per_step():
    return run("per_step")


def _same(a, b):
    (sa, ra), (sb, rb) = a, b
    xa, xb = sa.state(), sb.state()
    for key in ("x", "v", "theta", "omega", "alive"):
        np.testing.assert_array_equal(xa[key], xb[key], err_msg=key)
    assert ([r["escapees"] for r in ra.summary["realizations"]]
            == [r["escapees"] for r in rb.summary["realizations"]])
    assert sa.steps == sb.steps


def test_per_step_run_is_not_vacuous(per_step):
    sim, res = per_step
    escapees = [r["escapees"] for r in res.summary["realizations"]]
    assert sum(escapees) > 0, escapees            # bodies reached the escape line
    assert res.summary["neighbor_builds"] > 5     # and moved enough to need new lists
    f, _ = sim.forces()
    assert np.abs(f).max() > 0                    # contacts (no fluid here) pushed


def test_fused_gives_the_per_step_bits(per_step):
    fused = run("fused")
    assert fused[0].fused and not per_step[0].fused
    _same(fused, per_step)


def test_overflowing_rebuilds_catch_up(per_step):
    """Capacities of one: the kernel stops each realization at its overflowing
    rebuild, the host grows the arrays and the realization catches up; nothing is
    dropped, so the result is still the per-step one."""
    sim, res = run("fused", shrink=True)
    assert (sim.neighbors.cell_cap, sim.neighbors.nbr_cap) != sim.initial_caps   # grown in the run
    assert sim.run_state.launches > sim.calls["advance"]                # and caught up
    _same((sim, res), per_step)


@pytest.mark.parametrize("shrink", [False, True])
def test_device_rebuilds_give_the_host_rebuilds_bits(per_step, shrink):
    """The per-step path with its lists rebuilt on the device (a GPU's way: a
    thread per body, no host read per step) gives the bits of the host's
    rebuilds; with capacities of one a rebuild overflows on the device, the
    batch stalls there and the host grows the lists and resumes from that step,
    the shear history's buffers in the right order."""
    sim, res = run("per_step", shrink=shrink, device_rebuilds=True)
    assert res.summary["neighbor_builds"] == per_step[1].summary["neighbor_builds"]
    if shrink:
        assert (sim.neighbors.cell_cap, sim.neighbors.nbr_cap) != sim.initial_caps
        assert sim.stalled_rebuilds > 0                      # stalled and resumed
    else:
        assert sim.stalled_rebuilds == 0
        assert sim.calls["chunks"] == sim.calls["advance"]   # one read per chunk
    _same((sim, res), per_step)


def test_a_device_rebuild_that_overflows_mid_chunk_catches_up():
    """1501 steps in one call, capacities of one: on the device the lists
    overflow at step 696 (of 1501), the batch stalls for the remaining 805
    steps of the call (an odd number: the shear history's buffers must be put
    back in order), the host grows the lists and runs them; the bits are those
    of the host's rebuilds after every step."""
    states = {}
    for device in (False, True):
        sim = Simulation(load_scene(HOURGLASS, SHORT + ["run.stepping=per_step"]),
                         neighbor_capacities=(1, 1))
        sim.device_rebuilds = device
        taken, chunk = [], sim._steps_per_body

        def counted(n, chunk=chunk, taken=taken):
            taken.append(chunk(n))
            return taken[-1]
        sim._steps_per_body = counted
        sim.advance(1501)
        states[device] = sim.state()
        if device:
            assert sim.stalled_rebuilds == 1 and taken[0] < 1501 and (1501 - taken[0]) % 2
        else:
            assert taken == [1501]
    for key in ("x", "v", "theta", "omega", "alive"):
        np.testing.assert_array_equal(states[True][key], states[False][key], err_msg=key)


def test_auto_records_its_choice():
    sim = Simulation(load_scene(HOURGLASS, SHORT))
    assert sim.fused and sim.scene.run.stepping == "fused"
    assert "run.stepping" in sim.model.notes


def test_fused_refused_where_it_does_not_apply():
    with pytest.raises(SceneError, match="re-evaluates the fluid force every step"):
        Simulation(load_scene(SCENES / "squares.toml", ["run.stepping=fused", "run.t_end=0.01",
                                                        "fluid.force_update=step"]))
    # auto falls back to per_step there, and says why
    sim = Simulation(load_scene(SCENES / "squares.toml", ["run.t_end=0.01",
                                                          "fluid.force_update=step"]))
    assert not sim.fused and sim.scene.run.stepping == "per_step"
    assert "every step" in sim.model.notes["run.stepping"]


# Level-set triangles in the small upstream box of the figures' quick mode, with
# the fluid: they touch, rotate, are re-listed and the first leaves at 0.22 s.
LEVEL_SET = ["run.t_end=0.25", "run.realizations=2", "run.seed=1", "run.stop_at_clog=false",
             "geometry.width_in=0.00084", "geometry.length_in=0.00084", "particles.count=9"]


def test_fused_level_sets_give_the_per_step_bits():
    """The level-set node law in the fused launch: the per-step path's bits, a
    run of ten thousand steps with contacts, rebuilds, an escape and pressure
    solves (so that equal bits are not equal because nothing happened)."""
    runs = {}
    for stepping in ("per_step", "fused"):
        sim = Simulation(load_scene(SCENES / "polygons.toml",
                                    LEVEL_SET + [f"run.stepping={stepping}"]))
        assert sim.fused == (stepping == "fused") and not sim.model.all_disks
        runs[stepping] = (sim, sim.run())
    sim, res = runs["per_step"]
    assert res.summary["neighbor_builds"] > 2 and res.summary["fluid"]["solves"] > 10
    assert np.abs(sim.forces()[1]).max() > 0            # contact moments turned bodies
    assert sum(r["escapees"] for r in res.summary["realizations"]) > 0
    _same(runs["fused"], runs["per_step"])
    assert runs["fused"][1].summary["contact_path"] == "level-set"


def test_step_is_a_deprecated_name_of_advance():
    """``sim.step(n)`` (its old name) warns and takes the DEM steps ``advance(n)``
    takes: no checks, no series rows."""
    old, new = (Simulation(load_scene(HOURGLASS, SHORT)) for _ in range(2))
    with pytest.warns(DeprecationWarning, match="advance"):
        old.step(30)
    new.advance(30)
    assert old.steps == new.steps == 30 and old.t == new.t
    np.testing.assert_array_equal(old.state()["x"], new.state()["x"])
    assert old.run_state.series == new.run_state.series == []


def test_fused_gives_the_per_step_bits_with_rolling_friction():
    # the rolling moments ride in the shear history's second node: both paths
    # read and write them alike
    extra = ["particles.0.rolling_friction=0.05", "run.t_end=1.5"]
    per = run("per_step", extra)
    moments = per[0].history.old[1].to_numpy()[:, :, 1, :, 0]
    assert np.abs(moments).max() > 0
    _same(run("fused", extra), per)
