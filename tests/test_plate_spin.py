"""The plates' resistances against exact answers: the spin drag of a particle
between the plates (docs/model.md section 1.3) and the friction of a particle
resting on a plate (section 1.4)."""
import math
from pathlib import Path

import pytest

from conftest import arena_scene, make_sim

DISK = {"shape": "circle", "diameter": 1.0, "count": 1}
ROOT = Path(__file__).resolve().parents[1]


def _lone(xi=2.0, **species):
    """One unit disk (density 1, thickness 1: m = pi/4) in the closed arena."""
    scene = arena_scene([dict(DISK, **species)], xi=xi, dt_safety=0.05)
    return scene


@pytest.mark.parametrize("zeta_dt", [0.01, 100.0])
def test_spin_drag_decays_the_spin_implicitly(zeta_dt):
    # omega_n+1 = (1 - xi dt/2) omega_n / (1 + xi dt/2 + zeta dt): the global
    # damping's Crank-Nicolson factor with the spin drag's rate zeta = c / I
    # taken backward: exact per step, and monotone however large zeta dt is
    xi = 2.0
    probe = make_sim(_lone(xi))
    inertia = probe.model.species[0].inertia
    zeta = zeta_dt / probe.dt
    sim = make_sim(_lone(xi, spin_drag=zeta * inertia))
    assert sim.dt == probe.dt
    sim.set_state([[[5.0, 5.0]]], omega=[[3.0]])
    damp = 0.5 * xi * sim.dt
    factor = (1 - damp) / (1 + damp + zeta * sim.dt)
    seen = []
    for n in range(1, 6):
        sim.advance(1)
        seen.append(sim.state()["omega"][0, 0])
        assert seen[-1] == pytest.approx(3.0 * factor ** n, rel=1e-12)
    assert all(w > 0 for w in seen)
    if zeta_dt < 1:
        # against the continuous decay exp(-(xi + zeta) t), to first order in dt
        n = int(0.5 / sim.dt)
        sim.set_state([[[5.0, 5.0]]], omega=[[3.0]])
        sim.advance(n)
        rate = xi + zeta
        assert sim.state()["omega"][0, 0] == pytest.approx(
            3.0 * math.exp(-rate * n * sim.dt), rel=n * (zeta * sim.dt) ** 2)


PLATE = dict(plate_friction=0.5)


def _plate_run(load_ratio, density=1.0, xi=2.0, seconds=20.0):
    """A unit disk on the plate (fluid density 0, gravity 1: buoyant weight
    pi/6 rho) under a load along x of ``load_ratio`` times its friction limit;
    returns the simulation and that limit."""
    scene = _lone(xi, density=density, **PLATE)
    scene["fluid"].update(density=0.0 if density else 1.0, gravity=1.0)
    sim = make_sim(scene)
    limit = 0.5 * abs(density - scene["fluid"]["density"]) * math.pi / 6
    sim.set_state([[[5.0, 5.0]]])
    sim.set_external_load(force=[[[load_ratio * limit, 0.0]]])
    sim.advance(int(seconds / sim.dt))
    return sim, limit


def test_plate_friction_holds_a_particle_below_the_coulomb_limit():
    # below the limit the friction is a drag of rate limit / (m creep): the
    # particle creeps at v = (F/m) / (xi + limit / (m creep)), below the creep
    # speed 1e-6 d xi (the steady state of the step, exact)
    sim, limit = _plate_run(0.5)
    sp = sim.model.species[0]
    assert sp.plate * sp.mass == pytest.approx(limit, rel=1e-12)
    assert sp.creep == pytest.approx(1e-6 * 1.0 * 2.0, rel=1e-12)
    v = sim.state()["v"][0, 0]
    expect = (0.5 * limit / sp.mass) / (sp.xi + sp.plate / sp.creep)
    assert v[0] == pytest.approx(expect, rel=1e-9)
    assert abs(v[1]) < 1e-15 and 0 < v[0] < sp.creep


def test_plate_friction_lets_a_particle_slide_above_the_limit_against_its_motion():
    # above the limit it slides at v = (F/m - limit/m) / xi
    sim, limit = _plate_run(2.0)
    sp = sim.model.species[0]
    v = sim.state()["v"][0, 0]
    assert v[0] == pytest.approx((2.0 * limit - limit) / sp.mass / sp.xi, rel=1e-9)


def test_a_neutrally_buoyant_particle_feels_no_plate():
    scene = _lone(2.0, density=1.0, **PLATE)
    scene["fluid"].update(density=1.0, gravity=9.81)
    sim = make_sim(scene)
    assert sim.model.species[0].plate == 0.0
    assert "no buoyant weight" in sim.model.notes["particles.0.plate_friction"]


def test_auto_spin_drag_spins_a_lone_disk_down_at_the_confined_sphere_rate():
    # a lone disk of the vani scene (d/H = 0.875) set spinning in the flow: its
    # spin decays at 8 pi eta a^3 f(d/H) / I, f from the 3D Stokes table (the
    # pressure's moment on a circle is zero; the global damping's xi I is part
    # of that rate, the spin drag the rest)
    import tomllib
    from taichi_hsdem import Simulation, laws, load_scene
    raw = tomllib.loads((ROOT / "scenes" / "vani_phi026.toml").read_text())
    del raw["particles"][0]["packing_fraction"]
    raw["particles"][0]["positions"] = [[0.0015, 0.0]]
    raw["feed"]["mode"] = "none"
    scene = load_scene(raw, ["run.realizations=1"])
    sim = Simulation(scene)
    sp = sim.model.species[0]
    f = laws.sphere_spin_torque(140e-6 / 160e-6)
    assert f == pytest.approx(1.1880945, abs=1e-6)          # the table's row at 0.875
    torque = 8 * math.pi * 1e-3 * 70e-6 ** 3 * f
    assert sp.spin_drag + sp.xi * sp.inertia == pytest.approx(torque, rel=1e-12)
    x = sim.state()["x"]
    sim.set_state(x, omega=[[50.0]])
    sim.update_fluid(force=True)
    n = int(2.0e-3 / sim.dt)
    sim.advance(n)
    omega = sim.state()["omega"][0, 0]
    # the step's own decay, to round-off (no other moment acts) ...
    damp, zdt = 0.5 * sp.xi * sim.dt, sp.spin_drag / sp.inertia * sim.dt
    assert omega == pytest.approx(50.0 * ((1 - damp) / (1 + damp + zdt)) ** n, rel=1e-12)
    # ... which is the sphere's exp(-T t / (I Omega)) to first order in the spin
    # drag's zeta dt (backward Euler: the exponent short by about n zeta dt
    # (zeta dt / 2 + xi dt / 2) per unit, 4 % here; the steady balance is exact)
    exact = 50.0 * math.exp(-torque / sp.inertia * n * sim.dt)
    assert 0 < math.log(omega / exact) < n * zdt * (zdt + 2 * damp)
