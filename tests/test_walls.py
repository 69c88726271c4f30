"""Channel geometry against hand-computed answers: widths, angles, signed wall
distances, the gridded level set, areas of the fluid region."""

import math

import numpy as np
import pytest

from taichi_hsdem.geometry import walls as wl
from taichi_hsdem.geometry import wallfield as wf
from taichi_hsdem.geometry.polygon import signed_area

# Outlines are built from a handful of sums, products and one tan(); 1e-12 on
# numbers of order 10 leaves room for those few ulps and nothing else.
EXACT = 1e-12


def converging_ref():
    """4 wide, 6 long upstream; 45 degrees down to W = 1 over 1.5; no straight
    constriction; outlet 3 wide and 3 long. Corners: (6, +-2), (7.5, +-0.5)."""
    return wl.converging(width_in=4.0, length_in=6.0, constriction_width=1.0, length_out=3.0,
                         angle=45.0, width_out=3.0)


# --------------------------------------------------------------------- outlines

def test_hourglass_widths_and_taper_angle():
    g = wl.hourglass(length=10.0, width=2.0, neck_width=0.5, neck_x=4.0, taper_length=1.5)
    assert (g.x_min, g.x_max, g.y_min, g.y_max) == (0.0, 10.0, -1.0, 1.0)
    assert g.constriction_x0 == g.constriction_x1 == 4.0
    assert g.constriction_width == pytest.approx(0.5, abs=EXACT)
    assert g.upstream_region == (0.0, 2.5)
    # Inlet, straight part, half-way down the taper (linear: 2 - 1.5 * 0.5), neck,
    # half-way up, downstream straight part.
    xs = [0.0, 1.0, 3.25, 4.0, 4.75, 9.0]
    assert np.allclose(wl.width_at(g, xs), [2.0, 2.0, 1.25, 0.5, 1.25, 2.0], atol=EXACT)
    # Symmetric about y = 0: the outline is its own mirror image.
    mirrored = g.outline * [1, -1]
    assert {tuple(p) for p in np.round(mirrored, 12)} == {tuple(p) for p in np.round(g.outline, 12)}
    # Each wall narrows by (2 - 0.5) / 2 over 1.5: half-angle atan(0.5).
    lower = g.outline[(g.outline[:, 0] >= 2.5) & (g.outline[:, 0] <= 4.0) & (g.outline[:, 1] < 0)]
    (xa, ya), (xb, yb) = lower[np.argsort(lower[:, 0])]
    assert math.atan2(yb - ya, xb - xa) == pytest.approx(math.atan(0.5), abs=EXACT)


def test_hourglass_defaults_and_errors():
    g = wl.hourglass(12.0, 2.0, 0.5)  # neck_x = length / 2, taper = width
    assert g.constriction_x0 == 6.0 and g.upstream_region == (0.0, 4.0)
    with pytest.raises(ValueError, match="neck_width"):
        wl.hourglass(10.0, 2.0, 2.0)
    with pytest.raises(ValueError, match="taper"):
        wl.hourglass(10.0, 2.0, 0.5, neck_x=1.0, taper_length=2.0)


@pytest.mark.parametrize("angle", [30.0, 45.0, 60.0, 90.0])
def test_converging_widths_and_angle(angle):
    t = math.tan(math.radians(angle))
    g = wl.converging(width_in=4.0, length_in=6.0, constriction_width=1.0, length_out=3.0,
                      angle=angle, constriction_length=0.5, width_out=3.0)
    taper = 0.0 if angle == 90 else 1.5 / t  # each wall moves in by (4 - 1) / 2
    x0 = 6.0 + taper
    assert g.constriction_x0 == pytest.approx(x0, abs=EXACT)
    assert g.constriction_x1 == pytest.approx(x0 + 0.5, abs=EXACT)
    assert g.constriction_width == pytest.approx(1.0, abs=EXACT)
    assert g.x_max == pytest.approx(x0 + 3.5, abs=EXACT)
    assert g.upstream_region == (0.0, 6.0)
    # Inlet, upstream, constriction (middle and at the sudden expansion, where the
    # narrower side counts), downstream.
    xs = [0.0, 3.0, x0 + 0.25, x0 + 0.5, x0 + 2.0]
    assert np.allclose(wl.width_at(g, xs), [4.0, 4.0, 1.0, 1.0, 3.0], atol=EXACT)
    if angle < 90:
        # Half-way down the converging section: 4 - 2 * (taper / 2) * tan(angle) = 2.5.
        assert wl.width_at(g, 6.0 + taper / 2) == pytest.approx(2.5, abs=EXACT)
        # The upper converging wall runs at -angle to the x axis.
        top = g.outline[np.isclose(g.outline[:, 0], 6.0) & (g.outline[:, 1] > 0)][0]
        tip = g.outline[np.isclose(g.outline[:, 0], x0) & np.isclose(g.outline[:, 1], 0.5)][0]
        slope = math.degrees(math.atan2(tip[1] - top[1], tip[0] - top[0]))
        assert slope == pytest.approx(-angle, abs=1e-9)
    assert wl.width_at(g, -1.0) == 0.0 and wl.width_at(g, g.x_max + 1.0) == 0.0


def test_converging_default_outlet_width_and_errors():
    g = wl.converging(4.0, 6.0, 1.0, 3.0)
    assert wl.width_at(g, g.x_max - 1.0) == pytest.approx(4.0, abs=EXACT)
    with pytest.raises(ValueError, match="constriction_width"):
        wl.converging(4.0, 6.0, 5.0, 3.0)
    with pytest.raises(ValueError, match="angle"):
        wl.converging(4.0, 6.0, 1.0, 3.0, angle=0.0)
    with pytest.raises(ValueError, match="width_out"):
        wl.converging(4.0, 6.0, 1.0, 3.0, width_out=0.5)


def test_from_polygon_finds_the_constriction_like_the_generators():
    g = wl.converging(4.0, 6.0, 1.0, 3.0, angle=30.0, constriction_length=0.5, width_out=3.0)
    # Given clockwise, with a repeated closing vertex: both are accepted.
    p = wl.from_polygon(np.vstack([g.outline[::-1], g.outline[-1:]]))
    assert signed_area(p.outline) > 0
    assert (p.constriction_x0, p.constriction_x1) == pytest.approx(
        (g.constriction_x0, g.constriction_x1), abs=EXACT)
    assert p.constriction_width == pytest.approx(1.0, abs=EXACT)
    assert p.upstream_region == (0.0, 6.0)
    h = wl.from_polygon(wl.hourglass(10.0, 2.0, 0.5, neck_x=4.0, taper_length=1.5).outline)
    assert (h.constriction_x0, h.constriction_x1, h.upstream_region) == (4.0, 4.0, (0.0, 2.5))
    assert wl.from_polygon(g.outline, constriction_x=7.0).constriction_x0 == 7.0


def test_from_polygon_rejects_bad_polygons():
    box = [[0, -1], [4, -1], [4, 1], [0, 1]]
    with pytest.raises(ValueError, match="simple"):
        wl.from_polygon([[0, 0], [4, 0], [4, 2], [2, -1], [0, 2]])
    with pytest.raises(ValueError, match="strictly inside"):
        wl.from_polygon(box, obstacles=[[[3, 0], [5, 0], [5, 0.5]]])
    with pytest.raises(ValueError, match="overlap"):
        wl.from_polygon(box, obstacles=[[[1, 0], [2, 0], [2, 0.5]],
                                        [[1.5, 0.1], [3, 0.1], [3, 0.5]]])
    with pytest.raises(ValueError, match="inlet"):
        wl.from_polygon([[0, 0], [2, -1], [4, 0], [2, 1]])
    with pytest.raises(ValueError, match="at least 3"):
        wl.from_polygon([[0, 0], [1, 0], [0, 0]])
    with pytest.raises(ValueError, match="doubles back"):
        wl.from_polygon([[0, 0], [1, 0], [2, 0]])
    with pytest.raises(ValueError, match="constriction_x"):
        wl.from_polygon(box, constriction_x=5.0)


# ------------------------------------------------------------- wall distance

def test_wall_segments_leave_out_inlet_and_outlet():
    g = converging_ref()
    segs = wl.wall_segments(g)
    # 10 outline vertices (no straight constriction), so 10 edges: the inlet and
    # outlet edges are left out.
    assert len(g.outline) == 10 and segs.shape == (8, 2, 2)
    on_open = np.all(np.isclose(segs[:, :, 0], 0.0), axis=1) | \
        np.all(np.isclose(segs[:, :, 0], g.x_max), axis=1)
    assert not on_open.any()
    ext = wl.wall_segments(g, extend=2.0)
    assert ext.shape == (12, 2, 2)  # 2 rays per open edge
    assert np.allclose(np.abs(ext[8:, 1, 0] - ext[8:, 0, 0]), 2.0)


def test_wall_distance_at_hand_computed_points():
    g = converging_ref()
    r2 = math.sqrt(2.0)
    cases = {
        (3.0, 0.5): 1.5,               # straight section: 2 - 0.5 to the upper wall
        (0.1, 0.0): 2.0,               # 0.1 from the inlet edge, which is not a wall
        (0.0, 1.0): 1.0,               # on the inlet edge itself
        (-0.5, 1.0): 1.0,              # beyond the inlet: walls continued straight
        (6.5, 0.3): 1.2 / r2,          # converging wall x + y = 8, foot (7.1, 0.9) on it
        (7.8, 0.2): 0.3 * r2,          # nearest the expansion corner (7.5, 0.5)
        (9.0, 1.0): 0.5,               # outlet channel, wall y = 1.5
        (10.5, 0.0): 1.5,              # on the outlet edge
        (11.0, -1.0): 0.5,             # beyond the outlet
        (3.0, 2.5): -0.5,              # inside the upper wall
        (7.0, 1.5): -0.5 / r2,         # inside, above the converging wall, foot (6.75, 1.25)
        (-0.5, 3.0): -1.0,             # beside the inlet, outside the channel's span
    }
    pts = np.array(list(cases))
    assert np.allclose(wl.wall_distance(g, pts), list(cases.values()), atol=EXACT)


def test_wall_distance_is_continuous_across_the_open_ends():
    g = converging_ref()
    y = np.linspace(-1.9, 1.9, 9)
    for x_edge, yy, inward in ((0.0, y, 1.0), (g.x_max, 0.75 * y, -1.0)):
        inside = wl.wall_distance(g, np.column_stack([np.full(9, x_edge + 1e-9 * inward), yy]))
        outside = wl.wall_distance(g, np.column_stack([np.full(9, x_edge - 1e-9 * inward), yy]))
        # phi is 1-Lipschitz: 2e-9 apart, the values may differ by 2e-9 at most.
        assert np.all(np.abs(inside - outside) <= 2e-9 + EXACT)
        assert np.all(inside > 0)


def test_wall_distance_with_an_obstacle():
    g = wl.from_polygon([[0, 0], [4, 0], [4, 2], [0, 2]],
                        obstacles=[[[1.5, 0.5], [2.5, 0.5], [2.5, 1.5], [1.5, 1.5]]])
    pts = [[2.0, 1.0], [2.0, 0.25], [1.0, 1.0], [2.4, 1.0]]
    # Island centre (0.5 deep), between island and floor (0.25 to both), left of
    # the island (0.5 to it), just inside the island's right face.
    assert np.allclose(wl.wall_distance(g, pts), [-0.5, 0.25, 0.5, -0.1], atol=EXACT)
    assert (g.constriction_x0, g.constriction_x1, g.constriction_width) == (1.5, 2.5, 1.0)
    assert wl.width_at(g, 2.0) == pytest.approx(1.0, abs=EXACT)


# ---------------------------------------------------------- gridded level set

def test_wall_field_covers_the_box_and_matches_the_nodes():
    g = converging_ref()
    h = 0.05
    f = wf.make_wall_field(g, h)
    assert np.allclose(f.origin, [g.x_min - 4 * h, g.y_min - 4 * h], atol=EXACT)
    far = f.origin + (np.array(f.phi.shape) - 1) * h
    assert np.all(far >= [g.x_max + 4 * h - EXACT, g.y_max + 4 * h - EXACT])
    assert np.all(far < [g.x_max + 5 * h, g.y_max + 5 * h])
    idx = [(0, 0), (37, 20), (f.phi.shape[0] - 1, f.phi.shape[1] - 1)]
    nodes = np.array([f.origin + np.array(ij) * h for ij in idx])
    assert np.allclose([f.phi[ij] for ij in idx], wl.wall_distance(g, nodes), atol=0)


def test_sample_wall_exact_where_the_distance_is_linear():
    # Near a straight wall, away from corners and from the medial axis, phi is a
    # linear function of position, which bilinear interpolation reproduces up to
    # round-off; its gradient is the wall's inward normal.
    g = converging_ref()
    f = wf.make_wall_field(g, 0.05)
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(1.0, 5.0, 200), rng.uniform(0.5, 1.9, 200)])
    pts[::2, 1] *= -1
    phi, grad = wf.sample_wall(f, pts)
    assert np.allclose(phi, wl.wall_distance(g, pts), atol=1e-12)
    assert np.allclose(grad, np.column_stack([np.zeros(200), -np.sign(pts[:, 1])]), atol=1e-9)
    # Near the inlet the field feels only the side walls: no push along x.
    phi0, grad0 = wf.sample_wall(f, [[0.01, 1.0], [-0.1, -1.0]])
    assert np.allclose(phi0, [1.0, 1.0], atol=1e-12)
    assert np.allclose(grad0[:, 0], 0.0, atol=1e-9)


def test_sample_wall_second_order_near_a_corner():
    # Around the expansion corner c = (7.5, 0.5), on the side where the corner is
    # the nearest wall point, phi = |p - c|: f_xx + f_yy = 1/r. The bilinear
    # interpolation error on a cell of side h is at most h^2/8 (|f_xx| + |f_yy|),
    # so h^2 / (8 r_min), r_min = r - sqrt(2) h the cell's nearest point to c; the
    # gradient's (difference quotients) at most h (|f_xx| + |f_xy|) <= 2 h / r_min.
    g = converging_ref()
    c = np.array([7.5, 0.5])
    rng = np.random.default_rng(5)
    r = rng.uniform(0.2, 0.35, 300)
    a = np.radians(rng.uniform(-80.0, -10.0, 300))  # cell nodes keep x > 7.5, y > 0
    pts = c + np.column_stack([r * np.cos(a), r * np.sin(a)])
    exact = wl.wall_distance(g, pts)
    assert np.allclose(exact, r, atol=EXACT)
    errors = []
    for h in (0.02, 0.01):
        phi, grad = wf.sample_wall(wf.make_wall_field(g, h), pts)
        r_min = r - math.sqrt(2) * h
        assert np.all(np.abs(phi - exact) <= h ** 2 / (8 * r_min) + EXACT)
        unit = (pts - c) / r[:, None]
        assert np.all(np.abs(grad - unit) <= (2 * h / r_min)[:, None])
        errors.append(np.abs(phi - exact).max())
    # Halving h divides the error by about 4 (second order).
    assert 3.0 < errors[0] / errors[1] < 5.0


# ------------------------------------------------------------------- areas

def test_fluid_area_against_trapezoids_and_rectangles():
    g = wl.converging(4.0, 6.0, 1.0, 3.0, angle=45.0, constriction_length=0.5, width_out=3.0)
    # Pieces: upstream 4 x 6; converging trapezoid (4 + 1)/2 x 1.5; constriction
    # 1 x 0.5; outlet 3 x 3.
    assert wl.fluid_area(g, 0.0, 6.0) == pytest.approx(24.0, abs=EXACT)
    assert wl.fluid_area(g, 6.0, 7.5) == pytest.approx(3.75, abs=EXACT)
    assert wl.fluid_area(g, 7.5, 8.0) == pytest.approx(0.5, abs=EXACT)
    assert wl.fluid_area(g, 8.0, 11.0) == pytest.approx(9.0, abs=EXACT)
    assert wl.fluid_area(g, -5.0, 50.0) == pytest.approx(37.25, abs=EXACT)
    # Straddling pieces: 1 x 4 plus the trapezoid 4 -> 2.5 over 0.75; and across
    # the concave expansion corner: (2 + 1)/2 x 0.5 + 0.5 + 3 x 1.
    assert wl.fluid_area(g, 5.0, 6.75) == pytest.approx(4.0 + 3.25 * 0.75, abs=EXACT)
    assert wl.fluid_area(g, 7.0, 9.0) == pytest.approx(0.75 + 0.5 + 3.0, abs=EXACT)
    assert wl.fluid_area(g, 3.0, 3.0) == 0.0
    # Hourglass: rectangle minus two triangles per wall, taper * (w - w_neck) in all.
    hg = wl.hourglass(10.0, 2.0, 0.5, neck_x=4.0, taper_length=1.5)
    assert wl.fluid_area(hg, 0.0, 10.0) == pytest.approx(20.0 - 1.5 * 1.5, abs=EXACT)
    assert wl.fluid_area(hg, 2.5, 4.0) == pytest.approx((2.0 + 0.5) / 2 * 1.5, abs=EXACT)
    # An island is taken out.
    ob = wl.from_polygon([[0, 0], [4, 0], [4, 2], [0, 2]],
                         obstacles=[[[1.5, 0.5], [2.5, 0.5], [2.5, 1.5], [1.5, 1.5]]])
    assert wl.fluid_area(ob, 0.0, 2.0) == pytest.approx(4.0 - 0.5, abs=EXACT)
    with pytest.raises(ValueError):
        wl.fluid_area(g, 2.0, 1.0)
