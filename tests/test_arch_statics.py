"""Arches of disks between two walls against their statics (docs/model.md section 6).

A chain of k disks wedged between two walls has 2 k + 2 contact-force unknowns
(a normal and a tangential force at each contact) against 3 k balances. Whether
a configuration can stand under given loads is a small linear program: normal
forces non-negative, each tangential force within Coulomb's cone, every disk in
balance of force and moment. For k = 2 (a pair in a funnel) it is determinate;
for k = 3 only the mirror-symmetric arch balances at all, and then with a
single set of forces. The simulator's arches are held against that answer.
"""
import math

import numpy as np
import pytest
from scipy.optimize import linprog

from conftest import arena_scene, make_sim

SQ2 = math.sqrt(2.0)
# A 45-degree funnel of unit disks narrowing to a neck of 2.2 d at x = 10
# (centre line y = 5): lower wall x - y = 6.1, upper wall x + y = 16.1.
FUNNEL22 = [[0.0, 0.0], [6.1, 0.0], [10.0, 3.9], [10.0, 6.1], [6.1, 10.0], [0.0, 10.0]]
UPPER = (16.1, (-1 / SQ2, -1 / SQ2))    # x + y = 16.1, normal pointing into the channel
LOWER = (6.1, (-1 / SQ2, 1 / SQ2))      # x - y = 6.1
RADIUS = 0.5


def arch_statics(centres, loads, contacts, mu, radius=RADIUS, cost=None, mu_r=0.0):
    """The linear program of a disk arch's statics.

    ``contacts``: ``(i, j)`` disk on disk, or ``(i, n)`` disk ``i`` on a wall
    whose unit normal ``n`` points into the channel. Unknowns per contact: the
    normal force ``N >= 0`` and the tangential force ``T``, ``|T| <= mu N``;
    with rolling friction ``mu_r`` a third, the rolling moment ``M`` (a couple,
    ``+M`` on ``i``, ``-M`` on ``j``), ``|M| <= mu_r r_eff N`` (``r_eff = r / 2``
    between equal disks, ``r`` on a wall); each disk's force and moment balance
    with its load ``(fx, fy)``. Returns scipy's result (``status`` 0:
    admissible, 2: no balance), ``x`` the ``(N, T)`` (or ``(N, T, M)``) of each
    contact in turn, minimising ``cost . x``."""
    centres = np.asarray(centres, float)
    nc = len(contacts)
    w = 3 if mu_r > 0 else 2                   # unknowns per contact
    A = np.zeros((3 * len(centres), w * nc))
    cone = np.zeros((2 * (w - 1) * nc, w * nc))
    for c, (i, other) in enumerate(contacts):
        if isinstance(other, int):
            n = centres[other] - centres[i]
            n /= np.linalg.norm(n)
            sides = [(i, -n), (other, n)]          # each pushed away from the other
            r_eff = radius / 2
        else:
            sides = [(i, np.asarray(other, float))]
            r_eff = radius
        for side, (k, push) in enumerate(sides):
            t = np.array([-push[1], push[0]])
            arm = -radius * push                   # centre to contact point
            A[3 * k:3 * k + 2, w * c] += push
            A[3 * k:3 * k + 2, w * c + 1] += t
            A[3 * k + 2, w * c + 1] += arm[0] * t[1] - arm[1] * t[0]
            if w == 3:
                A[3 * k + 2, w * c + 2] += 1.0 if side == 0 else -1.0
        rows = 2 * (w - 1) * c
        cone[rows, [w * c, w * c + 1]] = [-mu, 1.0]
        cone[rows + 1, [w * c, w * c + 1]] = [-mu, -1.0]
        if w == 3:
            cone[rows + 2, [w * c, w * c + 2]] = [-mu_r * r_eff, 1.0]
            cone[rows + 3, [w * c, w * c + 2]] = [-mu_r * r_eff, -1.0]
    b = -np.concatenate([[fx, fy, 0.0] for fx, fy in loads])
    bounds = [(0, None) if q % w == 0 else (None, None) for q in range(w * nc)]
    return linprog(np.zeros(w * nc) if cost is None else cost, A_ub=cone,
                   b_ub=np.zeros(len(cone)), A_eq=A, b_eq=b, bounds=bounds, method="highs")


def rolling_needed(centres, loads, contacts, mu, lo=0.0, hi=2.0):
    """The least rolling friction at which the arch has a balance (bisection on
    the linear program's feasibility, to 1e-6)."""
    if arch_statics(centres, loads, contacts, mu).status == 0:
        return 0.0
    while hi - lo > 1e-6:
        mid = 0.5 * (lo + hi)
        if arch_statics(centres, loads, contacts, mu, mu_r=mid).status == 0:
            hi = mid
        else:
            lo = mid
    return hi


def three_disk_arch(beta_deg, shift=0.0):
    """Centres of a symmetric arch of three unit disks vaulted upstream in
    FUNNEL22: the middle one on the centre line, the outer ones touching it at
    ``beta`` from the cross-stream direction and touching the walls;
    ``shift`` moves the middle one across the stream (the rolling mode's
    direction), the outer ones staying on the walls and touching it."""
    b = math.radians(beta_deg)
    xm = UPPER[0] - 5.0 - SQ2 * RADIUS - 2 * RADIUS * (math.sin(b) + math.cos(b))
    mid = np.array([xm, 5.0 + shift])
    centres = [mid]
    for side, (const, normal) in ((1, UPPER), (-1, LOWER)):
        # the outer centre lies on the wall's line moved r inwards, x + side y =
        # const - sqrt(2) r, at 2 r from the middle one: the root near beta's
        on_line = np.array([const - SQ2 * RADIUS - side * 5.0, 5.0])
        along = np.array([normal[1], -normal[0]])
        d0 = on_line - mid
        bq, cq = 2 * d0 @ along, d0 @ d0 - 4 * RADIUS ** 2
        guess = mid + 2 * RADIUS * np.array([math.sin(b), side * math.cos(b)])
        roots = (-bq + np.array([-1.0, 1.0]) * math.sqrt(bq * bq - 4 * cq)) / 2
        centres.append(min((on_line + s * along for s in roots),
                           key=lambda p: np.linalg.norm(p - guess)))
    return np.array(centres)


def arch_contacts(x):
    """The middle disk on both outer ones, each outer one on its wall."""
    return [(0, 1), (0, 2), (1, UPPER[1]), (2, LOWER[1])]


def test_pair_in_a_45_degree_funnel_is_determinate():
    # two frictionless disks side by side under loads F along x: the pair's
    # contact carries F, each wall sqrt(2) F (the closed form of the wedge)
    x = np.array([[8.0, 5.0 + RADIUS], [8.0, 5.0 - RADIUS]])
    walls_y = [(0, 1), (0, UPPER[1]), (1, LOWER[1])]
    res = arch_statics(x, [(1.0, 0.0), (1.0, 0.0)], walls_y, mu=0.0)
    assert res.status == 0
    np.testing.assert_allclose(res.x[0::2], [1.0, SQ2, SQ2], rtol=1e-9)


def symmetric_arch_forces(beta_deg, load=1.0):
    """The symmetric three-disk arch's contact forces in closed form: middle to
    outer normal N and tangential T, wall normal Nw (wall tangential -T)."""
    s, c = math.sin(math.radians(beta_deg)), math.cos(math.radians(beta_deg))
    # middle disk: N s - T c = F/2; outer disk: torque T_w = -T, and its x and y
    # balances with the wall's normal eliminated give F + N (s - c) = T (c + s + sqrt 2)
    T = load * (1.0 + (s - c) / (2 * s)) / ((c + s + SQ2) - c * (s - c) / s)
    N = (load / 2 + T * c) / s
    Nw = SQ2 * (N * c + T * s + T / SQ2)
    return N, T, Nw


@pytest.mark.parametrize("beta", [10.0, 20.0, 35.0])
def test_symmetric_three_disk_arch_balances_with_one_set_of_forces(beta):
    x = three_disk_arch(beta)
    loads = [(1.0, 0.0)] * 3
    N, T, Nw = symmetric_arch_forces(beta)
    # admissible with friction above |T|/N at every contact; the smallest and
    # largest middle-contact force over the admissible set coincide (determinate)
    lo = arch_statics(x, loads, arch_contacts(x), mu=0.25, cost=np.eye(8)[0])
    hi = arch_statics(x, loads, arch_contacts(x), mu=0.25, cost=-np.eye(8)[0])
    assert lo.status == 0 and hi.status == 0
    assert lo.x[0] == pytest.approx(hi.x[0], rel=1e-7)
    np.testing.assert_allclose(np.abs(lo.x), [N, abs(T), N, abs(T), Nw, abs(T), Nw, abs(T)],
                               rtol=1e-6, atol=1e-9)
    need = max(abs(T) / N, abs(T) / Nw)
    assert arch_statics(x, loads, arch_contacts(x), mu=1.02 * need).status == 0
    assert arch_statics(x, loads, arch_contacts(x), mu=0.98 * need).status == 2


def test_asymmetric_three_disk_arch_has_no_balance_at_any_friction():
    # the middle disk moved 0.02 d across the stream: 9 balances, 8 unknowns
    x = three_disk_arch(20.0, shift=0.02)
    assert np.linalg.norm(x[1] - x[0]) == pytest.approx(1.0, rel=1e-12)
    assert arch_statics(x, [(1.0, 0.0)] * 3, arch_contacts(x), mu=10.0).status == 2


def _arch_run(friction, spin_drag, seconds=4.0, kn=1.0e4, load=2.0, tilt=0.0, shift=0.0,
              rolling=0.0):
    """FUNNEL22 with three unit disks placed 0.01 upstream of the beta = 20
    arch (displaced by ``shift``; then the middle one ``tilt`` off), loads
    along x, no fluid."""
    disk = {"shape": "circle", "diameter": 1.0, "count": 3, "spin_drag": spin_drag,
            "rolling_friction": rolling}
    scene = arena_scene([disk], kn=kn, friction=friction, restitution=0.5, xi=5.0,
                        dt_safety=0.1)
    scene["geometry"].update(outline=FUNNEL22, obstacles=[], constriction_x=9.9,
                             escape_offset=0.05)
    scene["feed"]["region"] = [1.0, 9.0]
    sim = make_sim(scene)
    start = three_disk_arch(20.0, shift) - [0.01, 0.0]
    start[0, 1] += tilt
    sim.set_state([start.tolist()])
    sim.set_external_load(force=[[[load, 0.0]] * 3])
    sim.advance(int(seconds / sim.dt))
    return sim, start


def test_admissible_arch_with_its_spin_held_stands_with_the_statics_forces():
    # a stiff spin drag (rate 1e4 / s against xi = 5 / s) leaves the rolling
    # mechanism nothing to run on: the arch comes to rest where it was placed and
    # its contacts carry the forces of the linear program at the final poses
    kn, load = 1.0e4, 2.0
    sim, start = _arch_run(0.25, spin_drag=1.0e3, kn=kn, load=load)
    st = sim.state()
    x = st["x"][0]
    assert st["alive"][0].all() and sim.batch.bad.to_numpy()[0] == 0
    assert np.abs(x - start).max() < 0.02
    # at rest but for a creep of the mechanism against the spin drag: 1e-5 of the
    # speed the load gives a free disk, F / (m xi) = 0.51
    assert np.abs(st["v"][0]).max() < 1e-5 * load / (math.pi / 4 * 5.0)
    overlap = [1 - np.linalg.norm(x[1] - x[0]), 1 - np.linalg.norm(x[2] - x[0]),
               RADIUS - (UPPER[0] - x[1, 0] - x[1, 1]) / SQ2,
               RADIUS - (LOWER[0] - x[2, 0] + x[2, 1]) / SQ2]
    res = arch_statics(x, [(load, 0.0)] * 3, arch_contacts(x), mu=0.25)
    assert res.status == 0
    # kn x overlap against the statics' normal forces; the linear program is
    # solved at the final centres, which stayed mirror-symmetric to round-off
    # (contact points off by the overlap, 3e-4 d, hence 0.5 %)
    np.testing.assert_allclose(kn * np.array(overlap), res.x[0::2], rtol=5e-3)


def test_arch_whose_friction_statics_rejects_leaves_its_place():
    # beta = 20 needs |T|/N = 0.019: at mu = 0.01 it cannot stand where it is
    x = three_disk_arch(20.0)
    assert arch_statics(x, [(1.0, 0.0)] * 3, arch_contacts(x), mu=0.01).status == 2
    sim, start = _arch_run(0.01, spin_drag=1.0e3, seconds=2.0, tilt=1e-3)
    st = sim.state()
    moved = np.where(st["alive"][0], np.linalg.norm(st["x"][0] - start, axis=1), np.inf)
    assert moved.max() > 0.1


def test_displaced_arch_balances_with_rolling_friction_in_proportion_to_its_displacement():
    # rolling moments at the four contacts (|M| <= mu_r r_eff N) give the
    # displaced arch the balance that forces alone cannot: the least mu_r grows
    # in proportion to the displacement, 0.46 per diameter at beta = 20
    need = {}
    for shift in (0.01, 0.02, 0.05):
        x = three_disk_arch(20.0, shift)
        loads, contacts = [(1.0, 0.0)] * 3, arch_contacts(x)
        need[shift] = rolling_needed(x, loads, contacts, mu=0.25)
        assert arch_statics(x, loads, contacts, 0.25, mu_r=1.02 * need[shift]).status == 0
        assert arch_statics(x, loads, contacts, 0.25, mu_r=0.98 * need[shift]).status == 2
    assert need[0.02] == pytest.approx(0.00924, rel=1e-3)
    assert need[0.01] / 0.01 == pytest.approx(need[0.02] / 0.02, rel=0.01)
    assert need[0.05] / 0.05 == pytest.approx(need[0.02] / 0.02, rel=0.03)
    # the symmetric arch needs none
    x = three_disk_arch(20.0)
    assert rolling_needed(x, [(1.0, 0.0)] * 3, arch_contacts(x), mu=0.25) == 0.0


@pytest.mark.parametrize("share, holds", [(2.0, True), (0.5, False)])
def test_displaced_arch_stands_with_the_rolling_friction_statics_asks_and_not_below(
        share, holds):
    # the arch displaced by 0.02 d along its mechanism, no spin drag: with twice
    # the rolling friction the linear program needs it comes to rest where it
    # was placed; with half it goes on rolling along the mechanism, as without
    # rolling friction (slowly: the loads drive the mechanism weakly so near the
    # symmetric arch, and xi = 5 / s damps it; its spin grows from 0.02 to 0.03
    # 1 / s over the next half second, without rolling friction 0.03 to 0.04)
    x = three_disk_arch(20.0, 0.02)
    need = rolling_needed(x, [(1.0, 0.0)] * 3, arch_contacts(x), mu=0.25)
    sim, start = _arch_run(0.25, spin_drag=0.0, seconds=3.0, shift=0.02,
                           rolling=share * need)
    st = sim.state()
    moved = np.where(st["alive"][0], np.linalg.norm(st["x"][0] - start, axis=1), np.inf)
    assert sim.batch.bad.to_numpy()[0] == 0
    if holds:
        assert moved.max() < 0.02
        assert np.abs(st["omega"][0]).max() < 1e-4
    else:
        assert moved.max() > 0.02
        assert np.abs(st["omega"][0]).max() > 0.01
