"""Shape templates against exact geometry: distances, nodes, mass properties,
level-set sampling, overlap tests and the flat layout uploaded to Taichi."""

import math

import numpy as np
import pytest

from taichi_hsdem.geometry import levelset as ls
from taichi_hsdem.geometry import distance as dist
from taichi_hsdem.geometry import shapes as sh
from taichi_hsdem.geometry.polygon import signed_area

# L shape: [0,2]x[0,1] union [0,1]x[0,2], notch [1,2]x[1,2]. Given clockwise to
# check that polygon() reorients it.
L_OUTLINE = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], dtype=float)[::-1]
L_CENTROID = np.array([5.0, 5.0]) / 6.0  # (2 * (1, 0.5) + 1 * (0.5, 1.5)) / 3


def box_sdf(p, half):
    """Exact signed distance to an axis-aligned box centred at the origin."""
    q = np.abs(p) - half
    outside = np.hypot(*np.maximum(q, 0.0).T)
    return outside + np.minimum(q.max(axis=1), 0.0)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


# --------------------------------------------------------------------------- SDF


def test_circle_sdf_is_distance_to_centre_minus_radius(rng):
    s = sh.circle(3.0)
    p = rng.uniform(-4, 4, size=(500, 2))
    # Closed form |p| - r; only round-off separates them.
    np.testing.assert_allclose(dist.signed_distance(s, p), np.hypot(*p.T) - 1.5, atol=1e-12)


def test_square_sdf_inside_outside_and_at_corners(rng):
    s = sh.square(2.0)
    p = np.vstack([
        rng.uniform(-3, 3, size=(1000, 2)),
        # just outside and just inside each corner, along the diagonal and off it
        np.array([[1.0, 1.0]]) + rng.normal(scale=1e-3, size=(200, 2)),
        np.array([[-1.0, 1.0]]) + rng.normal(scale=1e-3, size=(200, 2)),
    ])
    # Exact box distance; only round-off separates them.
    np.testing.assert_allclose(dist.signed_distance(s, p), box_sdf(p, 1.0), atol=1e-12)
    # Hand values: centre, mid-face outside, diagonal from a corner.
    np.testing.assert_allclose(
        dist.signed_distance(s, [[0, 0], [0, 1.5], [2, 2], [0.9, 0.9]]),
        [-1.0, 0.5, math.sqrt(2.0), -0.1], atol=1e-12)


def test_concave_sdf_in_notch_and_arms(rng):
    s = sh.polygon(L_OUTLINE)
    body = lambda pts: np.asarray(pts, float) - L_CENTROID  # noqa: E731  (user frame -> body frame)
    # Outside the L, the distance to a union of boxes is the smaller of the two
    # box distances; sample the notch [1,2]x[1,2] where both boxes matter.
    notch = rng.uniform(1.0, 2.0, size=(500, 2))
    exact = np.minimum(box_sdf(notch - [1.0, 0.5], [1.0, 0.5]), box_sdf(notch - [0.5, 1.5], [0.5, 0.5]))
    np.testing.assert_allclose(dist.signed_distance(s, body(notch)), exact, atol=1e-12)
    # Hand values: mid-arm depth 0.5; the reflex corner (1,1) is the nearest
    # boundary point of (0.9,0.9), at sqrt(0.02); (3,3) is nearest to the corners
    # (2,1) and (1,2) that bound the notch, at sqrt(5).
    np.testing.assert_allclose(
        dist.signed_distance(s, body([[1.5, 0.5], [0.5, 1.5], [0.9, 0.9], [1.5, 1.5], [3, 3]])),
        [-0.5, -0.5, -math.sqrt(0.02), 0.5, math.sqrt(5.0)], atol=1e-12)


# --------------------------------------------------------------------- level set


def test_level_set_grid_covers_bounding_box_with_margin():
    s = sh.rectangle(1.0, 0.55)
    h = 0.1
    g = ls.make_level_set(s, h, margin_cells=3)
    nx, ny = g.phi.shape
    far = g.origin + h * (np.array([nx, ny]) - 1)
    # Margin of at least 3 cells past each side of the box (to round-off).
    assert np.all(g.origin <= [-0.5 - 3 * h + 1e-12, -0.275 - 3 * h + 1e-12])
    assert np.all(far >= [0.5 + 3 * h - 1e-12, 0.275 + 3 * h - 1e-12])
    # Centred: the slack of the partial cell is split evenly.
    np.testing.assert_allclose(g.origin + far, 0.0, atol=1e-12)
    # Node values are the exact distance.
    i, j = 4, 2
    exact = dist.signed_distance(s, g.origin + h * np.array([i, j]))
    np.testing.assert_allclose(g.phi[i, j], exact, atol=1e-15)


def test_bilinear_sample_error_is_second_order_for_circle(rng):
    r = 1.0
    s = sh.circle(2 * r)
    errors = []
    for h in (0.05, 0.025):
        g = ls.make_level_set(s, h)
        rho = rng.uniform(r / 2, r + 2 * h, size=2000)
        ang = rng.uniform(0, 2 * np.pi, size=2000)
        p = np.column_stack([rho * np.cos(ang), rho * np.sin(ang)])
        phi, grad = ls.sample(g, p)
        # Bilinear error <= h^2/8 (max|f_xx| + max|f_yy|) over the cell; for
        # |p| - r both second derivatives are <= 1/rho, rho >= r/2 - sqrt(2) h.
        rho_min = r / 2 - math.sqrt(2) * h
        err = np.abs(phi - (rho - r))
        assert err.max() <= h * h / (4 * rho_min)
        # Gradient of the interpolant: a difference quotient of f_x taken at most
        # h away in x and y, so |error| <= h (max|f_xx| + max|f_xy|) <= 1.5 h / rho.
        assert np.abs(grad - p / rho[:, None]).max() <= 1.5 * h / rho_min
        errors.append(err.max())
    # Halving h divides the error by about 4 (second order); 3 allows for the
    # random points not hitting each grid's worst spot.
    assert errors[0] / errors[1] > 3.0


def test_bilinear_sample_is_exact_where_sdf_is_linear(rng):
    # Away from corners and from the diagonals (the medial axis, where the
    # inside distance has a kink), a square's distance is linear in every cell,
    # and bilinear interpolation reproduces linear functions exactly.
    s = sh.square(1.0)
    h = 0.02
    g = ls.make_level_set(s, h)
    p = rng.uniform(-0.55, 0.55, size=(4000, 2))
    a = np.abs(p)
    away = (np.abs(a[:, 0] - a[:, 1]) > 3 * h) & (np.minimum(a[:, 0], a[:, 1]) < 0.5 - 3 * h)
    p = p[away]
    phi, grad = ls.sample(g, p)
    np.testing.assert_allclose(phi, box_sdf(p, 0.5), atol=1e-12)
    axis = np.where((a[away, 0] > a[away, 1])[:, None], [1.0, 0.0], [0.0, 1.0]) * np.sign(p)
    np.testing.assert_allclose(grad, axis, atol=1e-9)


def test_sample_gradient_is_derivative_of_interpolant_and_outside_is_far(rng):
    g = ls.make_level_set(sh.polygon(L_OUTLINE), 0.1)
    p = rng.uniform(-1.0, 1.0, size=(50, 2))
    eps = 1e-7
    phi, grad = ls.sample(g, p)
    # Central differences of the interpolant (linear in each direction within a
    # cell, so only round-off and cell-boundary crossings, which are rare at eps)
    fd = np.column_stack([
        (ls.sample(g, p + [eps, 0])[0] - ls.sample(g, p - [eps, 0])[0]) / (2 * eps),
        (ls.sample(g, p + [0, eps])[0] - ls.sample(g, p - [0, eps])[0]) / (2 * eps),
    ])
    np.testing.assert_allclose(grad, fd, atol=1e-6)
    out = np.array([[10.0, 0.0], [0.0, -10.0], [np.nan, 0.0]])
    phi, grad = ls.sample(g, out)
    assert np.all(phi == ls.OUTSIDE_PHI) and np.all(grad == 0.0)


# ------------------------------------------------------------------------- nodes


def test_circle_nodes_evenly_spaced_from_angle_zero():
    s = sh.circle(2.0, n_nodes=37)
    d = np.hypot(*np.diff(np.vstack([s.nodes, s.nodes[:1]]), axis=0).T)
    assert d.std() / d.mean() < 1e-12  # equal chords up to round-off
    np.testing.assert_allclose(s.nodes[0], [1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.hypot(*s.nodes.T), 1.0, atol=1e-15)
    np.testing.assert_allclose(s.node_normals, s.nodes, atol=1e-15)  # radial, unit
    np.testing.assert_allclose(s.node_lengths.sum(), 2 * np.pi, rtol=1e-14)


def test_square_nodes_exactly_uniform_with_corners():
    s = sh.square(0.3, n_nodes=40)
    d = np.hypot(*np.diff(np.vstack([s.nodes, s.nodes[:1]]), axis=0).T)
    np.testing.assert_allclose(d, 0.03, rtol=1e-12)  # 10 intervals per side
    np.testing.assert_allclose(s.node_lengths, 0.03, rtol=1e-12)
    for v in s.vertices:  # corners are nodes, bit for bit
        assert np.any(np.all(s.nodes == v, axis=1))
    corner = np.all(np.isin(s.nodes, s.vertices), axis=1)
    np.testing.assert_allclose(np.abs(s.node_normals[corner]), math.sqrt(0.5), rtol=1e-14)
    faces = s.node_normals[~corner]
    np.testing.assert_allclose(np.sort(np.abs(faces), axis=1), [[0.0, 1.0]] * len(faces), atol=1e-15)


def test_rectangle_edges_get_largest_remainder_shares():
    # Ideal shares 40 * (2, 1, 2, 1) / 6 = 13.33, 6.67, ...: floors 13, 6, 13, 6
    # leave 2 to place, which go to the short edges (remainder 0.67).
    s = sh.rectangle(2.0, 1.0, n_nodes=40)
    vertex_at = [np.flatnonzero(np.all(s.nodes == v, axis=1))[0] for v in s.vertices]
    assert np.diff(vertex_at + [40]).tolist() == [13, 7, 13, 7]
    np.testing.assert_allclose(s.node_lengths.sum(), s.perimeter, rtol=1e-14)


def test_polygon_nodes_cover_every_vertex_and_normals_point_out():
    s = sh.polygon(L_OUTLINE, n_nodes=23)
    assert len(s.nodes) == 23
    for v in s.vertices:
        assert np.any(np.all(s.nodes == v, axis=1))
    np.testing.assert_allclose(s.node_lengths.sum(), 8.0, rtol=1e-14)  # perimeter of the L
    np.testing.assert_allclose(np.hypot(*s.node_normals.T), 1.0, rtol=1e-14)
    # A step along the normal leaves the shape by that distance, except at the
    # reflex corner (1,1): its bisector normal runs into the notch at 45 degrees
    # to both faces, so the step clears them by step / sqrt(2).
    step = 1e-3
    reflex = np.all(np.abs(s.nodes - ([1.0, 1.0] - L_CENTROID)) < 1e-12, axis=1)
    assert reflex.sum() == 1
    expected = np.where(reflex, step / math.sqrt(2), step)
    np.testing.assert_allclose(dist.signed_distance(s, s.nodes + step * s.node_normals), expected, rtol=1e-9)
    # Exactly as many nodes as vertices: the nodes are the vertices.
    only = sh.polygon(L_OUTLINE, n_nodes=6)
    np.testing.assert_array_equal(only.nodes, only.vertices)


# ------------------------------------------------------------- mass properties


def test_circle_and_rectangle_mass_properties():
    c = sh.circle(3.0)
    assert c.area == pytest.approx(np.pi * 2.25, rel=1e-14)
    assert c.perimeter == pytest.approx(3 * np.pi, rel=1e-14)
    assert c.inertia_per_mass == pytest.approx(2.25 / 2, rel=1e-14)  # r^2 / 2
    assert c.equivalent_diameter == pytest.approx(3.0, rel=1e-14)
    w, h = 3.0, 0.7
    r = sh.rectangle(w, h)
    assert r.area == pytest.approx(w * h, rel=1e-14)
    assert r.perimeter == pytest.approx(2 * (w + h), rel=1e-14)
    assert r.inertia_per_mass == pytest.approx((w * w + h * h) / 12, rel=1e-14)
    assert r.bounding_radius == pytest.approx(math.hypot(w, h) / 2, rel=1e-14)
    assert r.radius == r.bounding_radius


@pytest.mark.parametrize("n", [3, 4, 5, 6, 8])
def test_regular_polygon_mass_properties(n):
    d = 2.0
    s = sh.regular_polygon(n, d)
    R = d / 2
    # Closed forms: A = n/2 R^2 sin(2 pi/n), P = 2 n R sin(pi/n),
    # J/A = R^2 (1 + 2 cos^2(pi/n)) / 6 (-> R^2/2 as n -> inf, s^2/6 for n = 4).
    assert s.area == pytest.approx(0.5 * n * R * R * math.sin(2 * math.pi / n), rel=1e-13)
    assert s.perimeter == pytest.approx(2 * n * R * math.sin(math.pi / n), rel=1e-13)
    assert s.inertia_per_mass == pytest.approx(R * R * (1 + 2 * math.cos(math.pi / n) ** 2) / 6, rel=1e-13)
    assert s.bounding_radius == pytest.approx(R, rel=1e-14)
    np.testing.assert_array_equal(s.vertices[0], [R, 0.0])  # one vertex on +x
    assert signed_area(s.vertices) > 0  # counter-clockwise


def test_concave_polygon_mass_properties_by_decomposition():
    s = sh.polygon(L_OUTLINE)
    # Two rectangles: 2x1 centred (1, 0.5) and 1x1 centred (0.5, 1.5); parallel
    # axis theorem about the L's centroid.
    parts = [(2.0, 1.0, np.array([1.0, 0.5])), (1.0, 1.0, np.array([0.5, 1.5]))]
    area = sum(w * h for w, h, _ in parts)
    polar = sum(w * h * ((w * w + h * h) / 12 + np.sum((c - L_CENTROID) ** 2)) for w, h, c in parts)
    assert s.area == pytest.approx(area, rel=1e-14)
    assert s.inertia_per_mass == pytest.approx(polar / area, rel=1e-13)
    assert s.perimeter == pytest.approx(8.0, rel=1e-14)
    # Recentred on the centroid, made CCW: the user's vertices in reverse order.
    np.testing.assert_allclose(s.vertices + L_CENTROID, L_OUTLINE[::-1], atol=1e-14)


def test_sphericity_values():
    assert sh.circle(0.7).sphericity == pytest.approx(1.0, rel=1e-14)
    assert sh.square(0.7).sphericity == pytest.approx(math.sqrt(math.pi) / 2, rel=1e-14)  # 0.8862
    w, h = 2.0, 0.5
    exact = math.sqrt(4 * math.pi * w * h) / (2 * (w + h))
    assert sh.rectangle(w, h).sphericity == pytest.approx(exact, rel=1e-14)
    # Equilateral triangle: sqrt(4 pi sqrt(3)/4 a^2) / (3 a) = sqrt(pi sqrt(3)) / 3
    exact = math.sqrt(math.pi * math.sqrt(3)) / 3
    assert sh.regular_polygon(3, 1.0).sphericity == pytest.approx(exact, rel=1e-13)


# ---------------------------------------------------------------------- frames


def test_transform_and_to_body_are_inverse_rotations(rng):
    p = rng.normal(size=(20, 2))
    x, t = np.array([0.3, -2.0]), 0.7
    np.testing.assert_allclose(sh.to_body(sh.transform(p, x, t), x, t), p, atol=1e-14)
    # A quarter turn maps +x to +y.
    np.testing.assert_allclose(sh.transform([1.0, 0.0], [0, 0], np.pi / 2), [0.0, 1.0], atol=1e-15)


# --------------------------------------------------------------------- overlaps


SQ = sh.square(1.0, n_nodes=4)  # nodes only at the corners


@pytest.mark.parametrize("n_nodes", [4, 40])  # the answer must not depend on the nodes
@pytest.mark.parametrize("dx, dy, gap, expected", [
    (1.5, 0.3, 0.0, False),    # 0.5 apart
    (1.5, 0.3, 0.4, False),
    (1.5, 0.3, 0.6, True),     # closer than the gap asked for
    (1.0, 0.3, 0.0, False),    # faces touching, corners of each on the other's face
    (1.0, 0.0, 0.0, False),    # a whole edge shared
    (1.0, 0.3, 1e-6, True),
    (0.99, 0.3, 0.0, True),    # shallow overlap
    (0.5, 0.0, 0.0, True),     # half overlap: every corner and centre on the other's outline
    (0.01, 0.0, 0.0, True),    # deep: centres almost coincide
    (0.0, 0.0, 0.0, True),     # identical placement
    (10.0, 0.0, 0.0, False),   # rejected on bounding circles
])
def test_overlaps_axis_aligned_squares(n_nodes, dx, dy, gap, expected):
    s = sh.square(1.0, n_nodes=n_nodes)
    assert dist.overlaps(s, [0, 0], 0.0, s, [dx, dy], 0.0, gap=gap) is expected
    # Turning both by a quarter turn about the origin changes nothing (round-off
    # in the rotation stays inside the touching tolerance).
    q = np.pi / 2
    assert dist.overlaps(s, [0, 0], q, s, [-dy, dx], q, gap=gap) is expected


@pytest.mark.parametrize("order", ["ab", "ba"])
def test_overlaps_corner_into_face(order):
    # B turned 45 degrees points a corner at A's right face (x = 0.5); A's only
    # nodes are its corners, none of which is inside B.
    corner = math.sqrt(0.5)
    placed = lambda d: [(SQ, [0.0, 0.0], 0.0), (SQ, [0.5 + corner + d, 0.1], np.pi / 4)]  # noqa: E731
    for d, gap, expected in [(-0.05, 0.0, True), (0.05, 0.0, False), (0.05, 0.04, False), (0.05, 0.06, True)]:
        a, b = placed(d) if order == "ab" else placed(d)[::-1]
        assert dist.overlaps(*a, *b, gap=gap) is expected, (d, gap)


def test_overlaps_crossing_bars_with_no_vertex_inside():
    # A 10x1 bar and a 1x10 bar laid across each other off-centre: no corner and
    # no centre of either lies in the other; only the edge crossing shows it.
    a = sh.rectangle(10.0, 1.0, n_nodes=4)
    b = sh.rectangle(1.0, 10.0, n_nodes=4)
    assert dist.overlaps(a, [0, 0], 0.0, b, [3.0, 4.0], 0.0)
    assert not dist.overlaps(a, [0, 0], 0.0, b, [3.0, 5.6], 0.0)


def test_overlaps_with_circles_is_exact():
    c = sh.circle(1.0)
    # Disks: overlap iff centre distance < r_a + r_b + gap.
    assert not dist.overlaps(c, [0, 0], 0.0, c, [1.0 + 1e-6, 0], 0.0)
    assert dist.overlaps(c, [0, 0], 0.0, c, [1.0 - 1e-6, 0], 0.0)
    # Disk off a square's corner along the diagonal: distance |x - corner| - r.
    e = 0.5 + (0.5 + 1e-6) / math.sqrt(2)
    assert not dist.overlaps(SQ, [0, 0], 0.0, c, [e, e], 1.0)
    assert dist.overlaps(c, [e, e], 1.0, SQ, [0, 0], 0.0, gap=2e-6)
    e = 0.5 + (0.5 - 1e-6) / math.sqrt(2)
    assert dist.overlaps(SQ, [0, 0], 0.0, c, [e, e], 1.0)


def test_overlaps_respects_concave_notch():
    L = sh.polygon(L_OUTLINE, n_nodes=6)
    small = sh.square(0.8, n_nodes=4)
    # The notch is [1,2]x[1,2] in the user frame; a 0.8 square at its middle
    # clears both notch faces by 0.1, though it is inside the L's hull.
    at = np.array([1.5, 1.5]) - L_CENTROID
    assert not dist.overlaps(L, [0, 0], 0.0, small, at, 0.0)
    assert not dist.overlaps(L, [0, 0], 0.0, small, at, 0.0, gap=0.09)
    assert dist.overlaps(L, [0, 0], 0.0, small, at, 0.0, gap=0.11)
    assert dist.overlaps(L, [0, 0], 0.0, small, at - [0.15, 0.0], 0.0)


# ------------------------------------------------------------------------- stack


def test_stack_layout_matches_per_template_sampling(rng):
    shapes = [sh.square(1.0, n_nodes=8), sh.circle(1.0, n_nodes=12), sh.polygon(L_OUTLINE, n_nodes=10)]
    spacings = [0.1, None, 0.2]
    d = ls.stack(shapes, spacings)
    grids = [ls.make_level_set(shapes[0], 0.1), ls.make_level_set(shapes[2], 0.2)]
    sizes = [g.phi.size for g in grids]
    assert d["ls_offset"].tolist() == [0, sizes[0], sizes[0]]
    assert d["ls_shape"].tolist() == [list(grids[0].phi.shape), [0, 0], list(grids[1].phi.shape)]
    assert d["ls_phi"].shape == (sum(sizes),)
    assert d["node_offset"].tolist() == [0, 8, 20] and d["node_count"].tolist() == [8, 12, 10]
    assert d["node_pos"].shape == (30, 2) and d["node_len"].shape == (30,)
    np.testing.assert_array_equal(d["node_pos"][20:], shapes[2].nodes)
    assert d["is_circle"].tolist() == [0, 1, 0]
    for key in ("ls_offset", "ls_shape", "node_offset", "node_count", "is_circle"):
        assert d[key].dtype == np.int32
    # Bilinear read through the flat array (index offset + i*ny + j), written
    # independently of sample(), agrees with sample() on the template's grid.
    for k, g in ((0, grids[0]), (2, grids[1])):
        nx, ny = d["ls_shape"][k]
        p = rng.uniform(-0.75, 0.75, size=(100, 2))  # inside both grids (the square's reaches 0.8)
        u = (p - d["ls_origin"][k]) / d["ls_spacing"][k]
        i, j = np.floor(u).astype(int).T
        tx, ty = (u - np.floor(u)).T
        f = lambda a, b: d["ls_phi"][d["ls_offset"][k] + a * ny + b]  # noqa: E731
        flat = (f(i, j) * (1 - tx) * (1 - ty) + f(i + 1, j) * tx * (1 - ty)
                + f(i, j + 1) * (1 - tx) * ty + f(i + 1, j + 1) * tx * ty)
        np.testing.assert_allclose(flat, ls.sample(g, p)[0], atol=1e-14)


def test_stack_needs_spacing_for_polygons():
    with pytest.raises(ValueError, match="template 1 .square. is a polygon and needs a level-set spacing"):
        ls.stack([sh.circle(1.0), sh.square(1.0)], [None, None])
    with pytest.raises(ValueError, match="2 shapes but 1 spacings"):
        ls.stack([sh.circle(1.0), sh.square(1.0)], [None])


# ------------------------------------------------------------------------ errors


@pytest.mark.parametrize("make, message", [
    (lambda: sh.circle(0.0), "diameter must be a finite number > 0"),
    (lambda: sh.circle(-1.0), "diameter must be a finite number > 0"),
    (lambda: sh.square(float("nan")), "side must be a finite number > 0"),
    (lambda: sh.rectangle(1.0, 0.0), "height must be a finite number > 0"),
    (lambda: sh.regular_polygon(2, 1.0), "n_vertices >= 3"),
    (lambda: sh.circle(1.0, n_nodes=2), "n_nodes must be >= 3"),
    (lambda: sh.polygon([[0, 0], [1, 0]]), "at least 3 vertices, got 2"),
    (lambda: sh.polygon([[0, 0], [1, 0], [1, 1], [0, 0]]), "vertices 0 and 3 are the same point"),
    (lambda: sh.polygon([[0, 0], [1, 1], [1, 0], [0, 1]]), "polygon edges 0 and 2 cross"),
    (lambda: sh.polygon([[0, 0], [2, 0], [2, 2], [1, 0], [0, 2]]), "polygon edges 0 and 2 cross"),  # touches
    (lambda: sh.polygon([[0, 0], [1, 0], [2, 0]]), "polygon has zero area"),
    # folds back: vertex 2 lands on edge 0, so edge 2 touches it
    (lambda: sh.polygon([[0, 0], [2, 0], [1, 0], [1, 1]]), "polygon edges 0 and 2 cross"),
    (lambda: sh.regular_polygon(6, 1.0, n_nodes=5), "n_nodes=5 is fewer than the polygon's 6 vertices"),
    (lambda: ls.make_level_set(sh.square(1.0), 0.0), "spacing must be a finite number > 0"),
    (lambda: dist.overlaps(SQ, [0, 0], 0, SQ, [2, 0], 0, gap=-1), "gap must be >= 0"),
])
def test_errors_are_clear(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_shapes_are_immutable():
    s = sh.square(1.0)
    with pytest.raises(AttributeError):
        s.area = 2.0
    with pytest.raises(ValueError):
        s.nodes[0, 0] = 1.0
