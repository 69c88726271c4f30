"""Rolling friction at disk contacts (docs/model.md section 1.2) against its exact answers.

A disk pressed on a wall by a load ``F`` holds an applied moment up to
``mu_r r F`` and rolls beyond it, with the angular acceleration that the excess
gives a disk rolling without slip; two disks pressed together resist their
relative spin with ``mu_r r_eff F``, ``r_eff = r_i r_j / (r_i + r_j)``.
"""
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import arena_scene, load_tool, make_sim
from taichi_hsdem import SceneError

VANI = str(Path(__file__).resolve().parents[1] / "scenes" / "vani_phi026.toml")

R = 0.5          # disk radius
LOAD = 2.0       # normal load
MU_R = 0.1


XI = 2.0         # global damping, 1/s


def _disk_on_floor(moment, mu_r=MU_R, seconds=2.0, friction=1.0):
    """One unit disk resting on the arena's floor, pressed by LOAD, turned by
    ``moment``, damped at XI."""
    disk = {"shape": "circle", "diameter": 2 * R, "count": 1, "rolling_friction": mu_r}
    scene = arena_scene([disk], kn=1.0e4, friction=friction, restitution=0.3, dt_safety=0.05,
                        xi=XI)
    sim = make_sim(scene)
    start = np.array([[10.0, R - LOAD / 1.0e4]])
    sim.set_state([start.tolist()])
    sim.set_external_load(force=[[[0.0, -LOAD]]], moment=[[moment]])
    sim.advance(int(seconds / sim.dt))
    return sim, start, seconds


@pytest.mark.parametrize("share", [0.0, 0.5, 0.9])
def test_disk_on_a_wall_holds_a_moment_below_the_rolling_limit(share):
    moment = share * MU_R * R * LOAD
    sim, start, _ = _disk_on_floor(moment)
    st = sim.state()
    # at rest on the elastic rolling spring, k_r = k_s r^2 (k_s = k_n / 2): turned
    # by M / k_r, rolled (without slip, no force along the floor) by r times that.
    # At 0.9 of the limit the suddenly applied moment overshoots it at first
    # (up to twice the static moment), the contact rolls a little, and the disk
    # comes to rest turned further: only bounded there.
    k_r = 0.5e4 * R * R
    if share <= 0.5:
        assert st["theta"][0, 0] == pytest.approx(moment / k_r, rel=0.01, abs=1e-12)
        assert st["x"][0, 0, 0] - start[0, 0] == pytest.approx(-R * moment / k_r, rel=0.01,
                                                               abs=1e-12)
    else:
        assert moment / k_r < st["theta"][0, 0] < 1e-3
    assert abs(st["omega"][0, 0]) < 1e-6
    _, torque = sim.forces()
    assert torque[0, 0] == pytest.approx(-moment, rel=1e-3, abs=1e-9)


def test_disk_on_a_wall_rolls_beyond_the_limit_as_the_excess_moment_says():
    # rolling without slip, both motions damped at XI: (I + m r^2) (dw/dt + XI w)
    # = M - mu_r r F, I = m r^2 / 2: from w0 at t0, w = w_inf + (w0 - w_inf)
    # exp(-XI (t - t0)), w_inf = alpha / XI, and the centre rolls r times its
    # integral. From t0 = 0.2 s on, after the rolling spring has reached its
    # limit (it lets the disk turn cap / k_r first); the shear spring rings (it
    # has no dashpot), which the distance, an integral, averages out.
    excess = 0.5 * MU_R * R * LOAD
    sim, start, t0 = _disk_on_floor(MU_R * R * LOAD + excess, seconds=0.2)
    before = sim.state()
    t = 1.0
    sim.advance(int(t / sim.dt))
    t = int(t / sim.dt) * sim.dt
    st = sim.state()
    mass = math.pi * R * R
    w_inf = excess / (1.5 * mass * R * R) / XI
    w0 = before["omega"][0, 0]
    decay = 1.0 - math.exp(-XI * t)
    rolled = R * (w_inf * t + (w0 - w_inf) * decay / XI)
    # counter-clockwise on the floor: it rolls towards -x, without slip
    assert before["x"][0, 0, 0] - st["x"][0, 0, 0] == pytest.approx(rolled, rel=2e-3)
    assert st["omega"][0, 0] == pytest.approx(w_inf + (w0 - w_inf) * (1 - decay), rel=0.02)


def test_without_rolling_friction_any_moment_rolls_the_disk():
    moment = 0.1 * MU_R * R * LOAD
    sim, start, t = _disk_on_floor(moment, mu_r=0.0, seconds=1.0)
    alpha = moment / (1.5 * math.pi * R ** 4)
    rolled = alpha * R / XI * (t - (1.0 - math.exp(-XI * t)) / XI)
    assert start[0, 0] - sim.state()["x"][0, 0, 0] == pytest.approx(rolled, rel=2e-3)


def _pair(moment, mu_r, seconds=1.0, radii=(R, 0.25)):
    """Two disks side by side, pressed together along x by LOAD; the left one
    turned by ``moment``, the right one by its opposite; ``mu_r`` one value or
    one per disk (each its own species)."""
    mu_rs = mu_r if isinstance(mu_r, tuple) else (mu_r, mu_r)
    species = [{"shape": "circle", "diameter": 2 * r, "count": 1, "rolling_friction": m}
               for r, m in zip(radii, mu_rs)]
    scene = arena_scene(species, kn=1.0e4, friction=0.0, restitution=0.3, dt_safety=0.05,
                        length=30.0)
    sim = make_sim(scene)
    gap = LOAD / 1.0e4
    start = np.array([[10.0, 5.0], [10.0 + radii[0] + radii[1] - gap, 5.0]])
    sim.set_state([start.tolist()])
    sim.set_external_load(force=[[[LOAD, 0.0], [-LOAD, 0.0]]], moment=[[moment, -moment]])
    sim.advance(int(seconds / sim.dt))
    return sim


def test_two_disks_resist_their_relative_spin_up_to_mu_r_r_eff_f():
    reff = R * 0.25 / (R + 0.25)
    limit = MU_R * reff * LOAD
    held = _pair(0.8 * limit, MU_R).state()
    assert np.abs(held["omega"][0]).max() < 1e-3
    # beyond the limit the excess spins the two apart: I_i dw_i/dt = M - limit
    sim = _pair(1.5 * limit, MU_R, seconds=0.5)
    w = sim.state()["omega"][0]
    inertia = [0.5 * math.pi * r ** 4 for r in (R, 0.25)]
    np.testing.assert_allclose(w, [0.5 * limit * 0.5 / inertia[0],
                                   -0.5 * limit * 0.5 / inertia[1]], rtol=0.02)


def test_a_pair_of_species_takes_the_mean_of_their_rolling_friction():
    # mu_r 0.05 and 0.15: the pair's limit is that of 0.1, as above
    limit = MU_R * R * 0.25 / (R + 0.25) * LOAD
    assert np.abs(_pair(0.8 * limit, (0.05, 0.15)).state()["omega"][0]).max() < 1e-3
    w = _pair(1.5 * limit, (0.05, 0.15), seconds=0.5).state()["omega"][0]
    inertia = [0.5 * math.pi * r ** 4 for r in (R, 0.25)]
    np.testing.assert_allclose(w, [0.25 * limit / inertia[0], -0.25 * limit / inertia[1]],
                               rtol=0.02)


def test_rolling_friction_is_refused_for_shapes_other_than_disks():
    square = {"shape": "square", "side": 1.0, "count": 1, "rolling_friction": 0.1}
    with pytest.raises(SceneError, match="rolling_friction.*disks only"):
        make_sim(arena_scene([square]))


def test_placed_arch_of_three_holds_in_the_default_flow_with_rolling_friction():
    # the symmetric arch of three at W/d = 2.2 in the vani flow (each contact
    # opened by 0.01 d, nothing fed): without rolling friction it rolls away in
    # 0.18 s (docs/validation.md, arches of three); with mu_r = 0.02 it holds
    # the second (it holds 3 s from 0.005 on, and fails at 0.002)
    tool = load_tool("arch_lifetime")
    escapees, first = tool.lifetime(VANI, 2.2, 20.0, 1.0, ["particles.rolling_friction=0.02"])
    assert escapees == 0 and first is None
    escapees, first = tool.lifetime(VANI, 2.2, 20.0, 0.4, [])
    assert escapees == 3 and first < 0.3
