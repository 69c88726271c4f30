"""Concave particles (issue #18): contact and stability checks that hold for any
simple polygon, and surface nodes and level sets that follow the shape.

The mechanics tests put concave bodies in the contacts that broke the old
"centre inside another" check (an L's centroid lies in its own notch, so anything
resting there held it) and check each against an answer the contact law does not
give: at rest, the contact forces on every body balance the load on it.
"""
import math

import numpy as np
import pytest

from conftest import arena_scene, make_sim
from taichi_hsdem import SceneError, Simulation, load_scene
from taichi_hsdem.layout import BAD_PASSED
from taichi_hsdem.geometry import distance as dist
from taichi_hsdem.geometry import shapes as sh
from taichi_hsdem.resolve import node_gap, resolve

# The L-shape in units of 100 um: arms 0.45 wide, 1.4 long. Its centroid,
# (0.508, 0.508) from the outer corner, lies 0.058 beyond the inner corner (0.45,
# 0.45) on the diagonal: in the notch.
ARM, LENGTH = 0.45, 1.4
L_OUTLINE = [[0.0, 0.0], [LENGTH, 0.0], [LENGTH, ARM], [ARM, ARM], [ARM, LENGTH], [0.0, LENGTH]]
L_SPECIES = {"shape": "polygon", "vertices": L_OUTLINE, "count": 1}
L_SHAPE = sh.polygon(L_OUTLINE)
L_CENTROID = -L_SHAPE.vertices[0]          # from the outer corner (vertex 0)

# Settling: global damping XI (1/s) and a dashpot (e = 0.5) take the kinetic
# energy out; the imbalance left after T_SETTLE decays like exp(-XI t), from the
# whole load at the start to ~1e-9 of it (exp(-20)), far below the 1e-6 allowed
# (round-off of the node sums and the slower rocking of the stack, measured
# residuals below 1e-8).
XI, T_SETTLE = 5.0, 4.0
BALANCE = 1e-6


def star(tips=10, r_out=0.7, r_in=0.35):
    a = np.pi * np.arange(2 * tips) / tips
    r = np.where(np.arange(2 * tips) % 2 == 0, r_out, r_in)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def settle(species, poses, g, friction=0.0):
    """Bodies at ``poses`` (x, y, theta) under a gravity-like load ``m g`` each,
    settled for T_SETTLE: the simulation, its contact forces and moments, the load."""
    sim = make_sim(arena_scene(species, friction=friction, restitution=0.5, xi=XI,
                               dt_safety=0.1))
    poses = np.asarray(poses, dtype=float)
    sim.set_state([poses[:, :2]], theta=[poses[:, 2]])
    load = np.array([s.mass for s in sim.model.species])[sim.particles.species_np][:, None] \
        * np.asarray(g, dtype=float)[None]
    sim.set_external_load(force=[load])
    sim.advance(int(T_SETTLE / sim.dt))
    f, tau = sim.forces()
    return sim, f[0], tau[0], load


def assert_at_rest_in_balance(sim, f, tau, load):
    sim.batch.max_overlap.fill(0)              # the overlap at rest, not the landing's
    sim.advance(10)
    f, tau = (a[0] for a in sim.forces())
    st = sim.state()
    assert sim.batch.bad.to_numpy()[0] & BAD_PASSED == 0
    assert sim.batch.bad.to_numpy()[0] == 0
    assert st["alive"].all()
    scale = float(np.abs(load).max())
    # the contact forces balance the load on every body, and their moments vanish
    np.testing.assert_allclose(f, -load, rtol=0, atol=BALANCE * scale)
    np.testing.assert_allclose(tau, 0.0, rtol=0, atol=BALANCE * scale * LENGTH)
    # at rest: surface speeds a millionth of the speed the load gives over a size
    rb = np.array([s.shape.bounding_radius for s in sim.model.species])[sim.particles.species_np]
    speed = math.sqrt(scale / float(np.min([s.mass for s in sim.model.species])) * LENGTH)
    assert np.abs(st["v"]).max() + np.abs(st["omega"][0] * rb).max() < 1e-6 * speed
    # and the overlap stays shallow (kn = 1e4 against loads of a few units)
    assert float(sim.batch.max_overlap.to_numpy()[0]) < 0.01


def world(centroid_from_corner, corner, theta=0.0):
    """Centre of a body whose outer-corner vertex sits at ``corner`` (turned by theta)."""
    c, s = math.cos(theta), math.sin(theta)
    r = np.array([[c, -s], [s, c]])
    return np.asarray(corner, dtype=float) + r @ centroid_from_corner


def test_inside_point_of_concave_shapes():
    # The L's deepest point is the centre of the largest circle in its corner
    # square: touching both outer faces and the reflex corner, radius
    # r = ARM sqrt(2) / (1 + sqrt(2)) = 0.2636 (r = sqrt(2) (ARM - r)).
    p, depth = dist.inside_point(L_SHAPE)
    r = ARM * math.sqrt(2) / (1 + math.sqrt(2))
    assert depth == pytest.approx(r, rel=1e-3)
    np.testing.assert_allclose(p + L_CENTROID, [r, r], atol=1e-3)
    assert dist.signed_distance(L_SHAPE, np.zeros(2)) > 0        # the centroid is outside
    # symmetric shapes keep their centre exactly
    for s in (sh.square(1.0), sh.regular_polygon(5, 1.0), sh.polygon(star()), sh.circle(1.0)):
        q, d = dist.inside_point(s)
        assert q.tolist() == [0.0, 0.0] and d == pytest.approx(-dist.signed_distance(s, q))
    # a crescent (a disk with a bite taken out): the centroid is outside, the point
    # is inside and no sampled point of the outline's inside is deeper
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    outer = np.column_stack([np.cos(a), np.sin(a)])
    inner = np.column_stack([0.3 + 0.9 * np.cos(a[::-1]), 0.9 * np.sin(a[::-1])])
    keep_outer = outer[np.hypot(outer[:, 0] - 0.3, outer[:, 1]) > 0.9]
    keep_inner = inner[np.hypot(inner[:, 0], inner[:, 1]) < 1.0]
    outline = np.vstack([keep_outer, keep_inner])
    moon = sh.polygon(outline, n_nodes=len(outline))
    q, d = dist.inside_point(moon)
    assert dist.signed_distance(moon, np.zeros(2)) > 0 and dist.signed_distance(moon, q) < 0
    grid = np.stack(np.meshgrid(*[np.linspace(-1.5, 1.5, 301)] * 2), -1).reshape(-1, 2)
    assert -dist.signed_distance(moon, grid).min() <= d + 1e-4 * 2
    # its thinnest part is the band's middle, not its horns, which narrow to nothing
    assert dist.thinnest_width(moon) == pytest.approx(2 * d)


def test_thinnest_width_is_the_arm():
    assert dist.thinnest_width(L_SHAPE) == pytest.approx(ARM)
    # the star's arm, across its base: from an inner vertex to the far side of the
    # arm, 2 r_in sin(pi/10) cos(angle of the side to the chord)
    v = star()
    side = v[0] - v[-1]
    chord = v[1] - v[-1]
    expected = abs(side[0] * chord[1] - side[1] * chord[0]) / np.linalg.norm(side)
    assert dist.thinnest_width(sh.polygon(v)) == pytest.approx(expected)
    assert dist.thinnest_width(sh.rectangle(3.0, 0.2)) == pytest.approx(0.2)
    assert dist.thinnest_width(sh.circle(2.0)) == 2.0


def test_thinnest_width_finds_a_gentle_neck():
    # A Cassini oval (a = 1, b = 1.1): a peanut whose waist no sharp corner marks
    # (400 vertices, turns under 2 degrees). Its waist is the shortest chord
    # through the origin, 2 sqrt(b^2 - a^2) = 0.9165 (at x = 0: y^2 = b^2 - a^2),
    # thinner than its lobes' inscribed circles. The search finds it to a cell of
    # its grid (1/128 of the oval's length, 2.5 % of the waist), turned any way.
    a, b = 1.0, 1.1
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    r = np.sqrt(a * a * np.cos(2 * t) + np.sqrt(b ** 4 - a ** 4 * np.sin(2 * t) ** 2))
    waist = 2 * np.sqrt(b * b - a * a)
    for turn in (0.0, 10.0, 45.0):
        c, s = np.cos(np.radians(turn)), np.sin(np.radians(turn))
        pts = np.column_stack([r * np.cos(t), r * np.sin(t)]) @ np.array([[c, s], [-s, c]])
        oval = sh.polygon(pts, n_nodes=400)
        _, depth = dist.inside_point(oval)
        assert 2 * depth > 1.2
        cell = dist._neck_width(oval)[1]
        assert abs(dist.thinnest_width(oval) - waist) <= cell, turn
    # a tip or a plateau is no neck: the L's arm, the star's and crescent's answers
    # above stand, and a convex shape is not searched at all
    assert dist._neck_width(L_SHAPE)[0] == np.inf
    assert dist._neck_width(sh.polygon(star()))[0] == np.inf
    # a U (base and arms 1 wide) keeps its exact chord: the search's saddle between
    # the two corners (a cell or two low) does not replace it
    u = sh.polygon([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]])
    assert dist._neck_width(u)[0] < 1.0
    assert dist.thinnest_width(u) == pytest.approx(1.0)


def test_respaced_regular_polygons_have_equal_faces():
    # 40 nodes on a hexagon today: faces of 6 and 7 intervals (spacings 0.167 and
    # 0.143 of the edge); "auto" spaces at most perimeter / 40 apart, so 7 each.
    hexagon = sh.regular_polygon(6, 2.0, n_nodes=40)
    gaps = np.hypot(*(np.roll(hexagon.nodes, -1, 0) - hexagon.nodes).T)
    assert gaps.max() / gaps.min() > 1.1
    auto = sh.respaced(hexagon, hexagon.perimeter / 40)
    gaps = np.hypot(*(np.roll(auto.nodes, -1, 0) - auto.nodes).T)
    assert len(auto.nodes) == 42 and gaps.max() - gaps.min() < 1e-12
    for v in auto.vertices:
        assert np.any(np.all(auto.nodes == v, axis=1))
    assert auto.area == hexagon.area and auto.inertia_per_mass == hexagon.inertia_per_mass


def test_auto_nodes_and_grid_follow_the_thinnest_part():
    # Ls with the stars (arms 0.207 wide): the paper's spacing, perimeter /
    # 40, is finer than the arm, so both keep it (the L 42 nodes: its edges of 1.4,
    # 0.45 and 0.95 in 10, 4 and 7 equal intervals), grids at d_eq / 40 (the arm
    # spans 8.45 cells).
    star_sp = {"shape": "polygon", "vertices": star().tolist(), "count": 1}
    m = resolve(load_scene(arena_scene([dict(L_SPECIES), star_sp])))
    assert [len(s.shape.nodes) for s in m.species] == [42, 40]
    assert all("paper" in m.notes[f"particles.{k}.nodes"] for k in (0, 1))
    # written into the resolved scene, whose count rebuilds the very same nodes
    assert m.scene.particles[0].nodes == 42
    again = resolve(m.scene)
    for s, t in zip(m.species, again.species):
        np.testing.assert_array_equal(s.shape.nodes, t.shape.nodes)
    for s in m.species:
        assert s.ls_spacing == pytest.approx(s.d_eq / 40)
    # stars with arms of 0.092 (r_in 0.15): every outline of the scene gets nodes at
    # most an arm apart, and the star a grid of 8 cells across its arm
    thin = dict(star_sp, vertices=star(r_in=0.15).tolist())
    m = resolve(load_scene(arena_scene([dict(L_SPECIES), thin])))
    w = dist.thinnest_width(sh.polygon(star(r_in=0.15)))
    for s in m.species:
        assert node_gap(s.shape) <= w * (1 + 1e-3)
    assert [len(s.shape.nodes) for s in m.species] == [64, 140]
    note = m.notes["particles.0.nodes"]
    assert "thinnest part" in note and "particles[1]" in note
    s = m.species[1]
    assert s.ls_spacing == pytest.approx(w / 8) and s.ls_spacing < s.d_eq / 40
    # a disk keeps the paper's 40 nodes
    disk = resolve(load_scene(arena_scene([{"shape": "circle", "diameter": 1.0,
                                            "count": 1}], fast_path=False)))
    assert len(disk.species[0].shape.nodes) == 40 and "paper" in disk.notes["particles.0.nodes"]


def test_too_sparse_nodes_and_grid_for_a_thin_arm_refused():
    # 6 nodes (the vertices) leave 1.4 between two, more than the star's arm (0.207)
    species = [dict(L_SPECIES, nodes=6), {"shape": "polygon", "vertices": star().tolist(),
                                         "count": 1}]
    with pytest.raises(SceneError) as err:
        Simulation(load_scene(arena_scene(species)))
    msg = str(err.value)
    assert "particles[0].nodes" in msg and "thinnest part" in msg and "particles[1]" in msg
    # 0.23 passes d_eq / 5 (0.232) but not half the arm (0.225)
    species = [dict(L_SPECIES, ls_spacing=0.23)]
    with pytest.raises(SceneError) as err:
        Simulation(load_scene(arena_scene(species)))
    assert "particles[0].ls_spacing" in str(err.value) and "thinnest part" in str(err.value)


def test_disk_nested_in_an_l_rests_in_balance():
    # The L stands in the arena's corner (floor y = 0, the left block's face x = 2)
    # and a disk of diameter 0.3 sits in its inner corner, both loaded towards the
    # corner. The disk holds the L's centroid (the old check called that a pass-
    # through); at rest the contact forces on each must balance its load.
    r = 0.15
    corner = np.array([2.0, 0.0])
    x_l = world(L_CENTROID, corner)
    x_d = corner + ARM + r
    assert np.hypot(*(x_l - x_d)) < r                       # the premise
    g = 50.0 * np.array([-1.0, -1.0]) / math.sqrt(2)
    sim, f, tau, load = settle([dict(L_SPECIES), {"shape": "circle", "diameter": 2 * r,
                                                  "count": 1}],
                               [(*x_l, 0.0), (*x_d, 0.0)], g)
    assert_at_rest_in_balance(sim, f, tau, load)
    # still nested: touching both inner faces
    st = sim.state()
    np.testing.assert_allclose(st["x"][0, 1], x_d, atol=0.01)


def test_nested_ls_rest_in_balance():
    # A second L with its outer corner in the first one's inner corner: it holds
    # the first one's centroid. Loaded towards the arena's corner.
    corner = np.array([2.0, 0.0])
    x1 = world(L_CENTROID, corner)
    x2 = world(L_CENTROID, corner + ARM)
    assert dist.signed_distance(L_SHAPE, sh.to_body(x1, x2, 0.0)) < 0   # the premise
    g = 20.0 * np.array([-1.0, -1.0]) / math.sqrt(2)
    sim, f, tau, load = settle([dict(L_SPECIES, count=2)], [(*x1, 0.0), (*x2, 0.0)], g)
    assert_at_rest_in_balance(sim, f, tau, load)


def test_interlocked_ls_rest_in_balance():
    # Two Ls hooked into each other: the second turned by 180 degrees, its right arm
    # standing in the first one's notch on the bottom arm and its top arm lying on
    # the first one's left arm, which stands in the second one's notch. Gravity
    # down: it rests on two supports (statically indeterminate, but the sum of the
    # contact forces must still be the load), the first L on the floor. Friction
    # holds it: frictionless, the upper L tilts elastically onto its nearer
    # support and the tilted faces push it sideways off the supports, as they
    # would a real frictionless body.
    corner = np.array([8.0, 0.0])
    x1 = world(L_CENTROID, corner)
    shift = 0.1                        # keeps the corners of the two off each other
    x2 = world(L_CENTROID, corner + [shift + LENGTH, ARM + LENGTH], math.pi)
    sim, f, tau, load = settle([dict(L_SPECIES, count=2)], [(*x1, 0.0), (*x2, math.pi)],
                               [0.0, -20.0], friction=0.5)
    assert_at_rest_in_balance(sim, f, tau, load)
    # both supports carry load: the upper L only leans elastically towards the nearer
    # one (statics: 0.75 and 0.25 of its weight, a tilt of (0.75 - 0.25) W / (kn
    # 0.95) ~ 1e-3; measured 2.6e-3 with the lower L's own rocking), far from tipping
    st = sim.state()
    assert abs(st["theta"][0, 1] - math.pi) < 0.01


def test_fast_body_driven_through_a_thin_one_is_caught():
    # A square fired at the middle of a thin bar (0.1 thick) fast enough to push its
    # face past the bar's middle, where the bar's level set turns the push round:
    # it goes through. The bar's deepest point (its middle) ends up inside the
    # square, which the inside-point check flags.
    bar = {"shape": "rectangle", "width": 3.0, "height": 0.1, "count": 1}
    sq = {"shape": "square", "side": 0.5, "count": 1}
    sim = make_sim(arena_scene([bar, sq], dt_safety=0.1))
    sim.set_state([[[10.0, 5.0], [10.0, 3.0]]], v=[[[0.0, 0.0], [0.0, 60.0]]])
    sim.advance(int(0.06 / sim.dt))
    assert sim.batch.bad.to_numpy()[0] & BAD_PASSED
    # the same bar met slowly holds the square off
    sim.set_state([[[10.0, 5.0], [10.0, 4.6]]], v=[[[0.0, 0.0], [0.0, 1.0]]])
    sim.batch.bad.fill(0)
    sim.advance(int(0.3 / sim.dt))
    assert sim.batch.bad.to_numpy()[0] == 0
    assert sim.state()["x"][0, 1, 1] < 5.0 - 0.05 - 0.25 + 0.01


# An arch of a body: a bar 1.4 wide and 1 high with a slot 0.6 wide and 0.55 deep
# cut up from the middle of its base, standing on two feet 0.4 wide.
ARCH_OUTLINE = [[0.0, 0.0], [0.4, 0.0], [0.4, 0.55], [1.0, 0.55], [1.0, 0.0], [1.4, 0.0],
                [1.4, 1.0], [0.0, 1.0]]


@pytest.mark.parametrize("outline, places", [
    ([[0.0, 0.0], [1.4, 0.0], [1.4, 0.45], [0.0, 0.45]], 1),   # a bar: one place
    (ARCH_OUTLINE, 2),                                          # its two feet
    # the same, its outline (and so its node numbers) starting in the middle of
    # its left foot: that foot's nodes are the first and the last ones, one place
    ([[0.2, 0.0]] + ARCH_OUTLINE[1:] + [[0.0, 0.0]], 2),
])
def test_each_place_of_wall_contact_is_one_contact(outline, places):
    # Resting on the floor under its weight W, a body sinks in by delta, the same
    # at every node on the floor (the floor's level set is linear in y). The paper
    # divides each contact's resultant by its nodes in contact, so each place
    # of contact pushes with kn delta: one place balances W at delta = W / kn,
    # two at W / (2 kn). (Divided once over all its wall nodes, the arch would sink
    # to W / kn on its feet as the bar does.)
    species = {"shape": "polygon", "vertices": outline, "count": 1}
    shape = sh.polygon(outline)
    corner = np.array([9.0, 0.002])            # vertex 0 just above the floor
    x0 = corner - shape.vertices[0]
    sim, f, tau, load = settle([species], [(*x0, 0.0)], [0.0, -1.0])
    assert_at_rest_in_balance(sim, f, tau, load)
    st = sim.state()
    assert abs(st["theta"][0, 0]) < 1e-6       # symmetric: it sinks in level
    delta = -(st["x"][0, 0, 1] + shape.vertices[0][1])
    weight = -load[0, 1]
    kn = 1.0e4
    assert delta == pytest.approx(weight / (places * kn), rel=1e-3)
