"""Random placement against independent checks: counts, packing fraction,
pairwise distances, exact wall clearance, failure messages, re-insertion spots."""

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from taichi_hsdem.geometry import placement as pl
from taichi_hsdem.geometry import distance as dist
from taichi_hsdem.geometry import shapes as sh
from taichi_hsdem.geometry import walls as wl

# The Sec. 3.2 channel in units of the disk diameter: W/d = 1.7, a 10 d wide,
# 20 d long upstream section (the control volume, area 200), 45 degree
# convergence from y = +-5 to +-0.85 over 4.15, then a 5 d outlet.
D = 1.0
X_NECK = 20.0 + 4.15
# Its walls, written out by hand so that the checks do not go through walls.py.
WALLS = np.array([
    [[0.0, -5.0], [20.0, -5.0]], [[20.0, -5.0], [X_NECK, -0.85]],
    [[0.0, 5.0], [20.0, 5.0]], [[20.0, 5.0], [X_NECK, 0.85]],
    [[X_NECK, -0.85], [X_NECK, -5.0]], [[X_NECK, 0.85], [X_NECK, 5.0]],
    [[X_NECK, -5.0], [X_NECK + 5.0, -5.0]], [[X_NECK, 5.0], [X_NECK + 5.0, 5.0]],
])


@pytest.fixture(scope="module")
def channel():
    return wl.converging(width_in=10.0, length_in=20.0, constriction_width=1.7, length_out=5.0)


def segment_distance(p, walls=WALLS):
    """Distance from points (M, 2) to the nearest of the hand-written walls."""
    a, b = walls[:, 0], walls[:, 1]
    ab = b - a
    t = np.clip(np.einsum("mwk,wk->mw", p[:, None] - a, ab) / np.sum(ab * ab, axis=1), 0, 1)
    return np.linalg.norm(p[:, None] - (a + t[..., None] * ab), axis=2).min(axis=1)


def test_count_for_fraction(channel):
    # 0.26 * 200 / (pi / 4) = 66.2 disks; squares of side 0.8: 0.26 * 200 / 0.64 = 81.25.
    assert pl.count_for_fraction(0.26, channel, channel.upstream_region, sh.circle(D)) == 66
    assert pl.count_for_fraction(0.26, channel, (0.0, 20.0), sh.square(0.8)) == 81
    # The region is clipped to the channel: [-5, 20] holds the same fluid.
    assert pl.count_for_fraction(0.26, channel, (-5.0, 20.0), sh.circle(D)) == 66


def test_disks_at_026_reach_the_count_with_no_overlap(channel):
    disk = sh.circle(D)
    region = channel.upstream_region
    n = pl.count_for_fraction(0.26, channel, region, disk)
    x, theta = pl.place(np.random.default_rng(0), channel, [disk], np.zeros(n, int), region)
    assert x.shape == (n, 2) and theta.shape == (n,)
    # Areal fraction: n disks in the 200 area; rounding the count moves it by at
    # most half a disk, (pi/4) / 2 / 200.
    assert abs(n * disk.area / 200.0 - 0.26) <= disk.area / 400.0
    assert np.all((x[:, 0] >= 0.0) & (x[:, 0] <= 20.0))
    assert pdist(x).min() > D                       # disks of diameter D do not overlap
    assert segment_distance(x).min() > D / 2        # nor touch a wall
    assert x[:, 0].min() >= D / 2                   # nor stick out through the inlet
    assert np.all((theta >= 0) & (theta < 2 * np.pi))
    assert pl.check_initial(channel, [disk], x, theta, np.zeros(n, int)) == []


def test_squares_no_overlap_no_wall_contact(channel):
    square = sh.square(0.8)
    gap = 0.01
    n = pl.count_for_fraction(0.26, channel, (0.0, 20.0), square)
    x, theta = pl.place(np.random.default_rng(1), channel, [square], np.zeros(n, int),
                        (0.0, 20.0), gap=gap)
    assert len(x) == n == 81
    # Pairs: the exact test of shapes.py, with the clearance asked for.
    for i in range(n):
        for j in range(i + 1, n):
            assert not dist.overlaps(square, x[i], theta[i], square, x[j], theta[j], gap)
    # Walls: every node (vertices among them) clears the hand-written walls by
    # more than the gap, and no wall corner lies within gap of a square.
    nodes = sh.transform(square.nodes[None], x[:, None], theta[:, None]).reshape(-1, 2)
    assert np.all(np.abs(nodes[:, 1]) < 5.0)        # inside the channel's span
    assert nodes[:, 0].min() >= 0.0
    assert segment_distance(nodes).min() > gap
    for corner in ([20.0, 5.0], [20.0, -5.0]):
        sd = [dist.signed_distance(square, sh.to_body(np.array([corner]), x[k], theta[k]))[0]
              for k in range(n)]
        assert min(sd) > gap


def test_two_species_keep_their_order_and_sizes(channel):
    big, small = sh.circle(1.0), sh.circle(0.5)
    species = np.array([1, 0] * 20)
    x, _ = pl.place(7, channel, [big, small], species, (0.0, 20.0))
    r = np.where(species == 0, 0.5, 0.25)
    i, j = np.triu_indices(len(x), 1)
    assert np.all(np.linalg.norm(x[i] - x[j], axis=1) > r[i] + r[j])
    assert np.all(segment_distance(x) > r)


def test_existing_particles_are_avoided(channel):
    disk = sh.circle(D)
    x1, t1 = pl.place(2, channel, [disk], np.zeros(40, int), (0.0, 20.0))
    x2, _ = pl.place(3, channel, [disk], np.zeros(20, int), (0.0, 20.0),
                     existing=(x1, t1, [disk] * 40))
    assert pdist(np.vstack([x1, x2])).min() > D


def test_impossible_packing_raises_a_helpful_error(channel):
    disk = sh.circle(D)
    n = pl.count_for_fraction(0.7, channel, channel.upstream_region, disk)
    with pytest.raises(pl.PlacementError) as err:
        pl.place(np.random.default_rng(0), channel, [disk], np.zeros(n, int),
                 channel.upstream_region, max_attempts=2000)
    e = err.value
    assert isinstance(e, ValueError)
    assert e.requested == n == 178 and 0 < e.placed < n
    # Random sequential addition of disks jams at 0.547 (and walls lower it).
    assert 0.3 < e.fraction_reached < 0.547
    assert e.fraction_requested == pytest.approx(n * disk.area / 200.0)
    msg = str(e)
    assert f"placed {e.placed} of {n}" in msg
    assert f"{e.fraction_reached:.3f}" in msg
    assert "Lower the packing_fraction or count" in msg and "enlarge the region" in msg


def test_same_seed_same_placement(channel):
    shapes = [sh.circle(D), sh.square(0.8)]
    species = np.array([0, 1] * 15)
    a = pl.place(np.random.default_rng(11), channel, shapes, species, (0.0, 20.0))
    b = pl.place(np.random.default_rng(11), channel, shapes, species, (0.0, 20.0))
    c = pl.place(np.random.default_rng(12), channel, shapes, species, (0.0, 20.0))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


def lattice():
    """Touching unit disks on a unit square lattice over x in [0.5, 2.5], y in [-4.5, 4.5]."""
    gx, gy = np.meshgrid([0.5, 1.5, 2.5], np.arange(-4.5, 5.0, 1.0), indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel()])


def test_find_free_spot_none_when_the_strip_is_full(channel):
    # Every point of the strip [0, 2] where a unit disk's centre may go (x >= 0.5,
    # |y| <= 4.5) is within sqrt(2)/2 < 1 of a lattice site: no spot exists.
    disk = sh.circle(D)
    full = lattice()
    spot = pl.find_free_spot(np.random.default_rng(0), channel, disk, (0.0, 2.0), full,
                             np.zeros(len(full)), [disk] * len(full), attempts=2000)
    assert spot is None


def test_find_free_spot_finds_the_only_hole(channel):
    # Remove the site (1.5, 0.5): a disk of diameter 0.5 fits where it is at least
    # 0.75 from the four side neighbours (1 away), i.e. within 0.25 of the site.
    disk, small = sh.circle(D), sh.circle(0.5)
    sites = lattice()
    hole = np.array([1.5, 0.5])
    others = sites[np.linalg.norm(sites - hole, axis=1) > 1e-9]
    spot = pl.find_free_spot(np.random.default_rng(4), channel, small, (0.0, 2.0), others,
                             np.zeros(len(others)), [disk] * len(others), attempts=5000)
    assert spot is not None
    x, theta = spot
    assert np.linalg.norm(x - hole) <= 0.25
    assert np.linalg.norm(others - x, axis=1).min() > 0.75
    assert 0 <= theta < 2 * np.pi


def test_check_initial_reports_walls_and_pairs(channel):
    disk = sh.circle(D)
    x = np.array([[5.0, 0.0], [5.5, 0.0], [5.0, 4.75], [10.0, 0.0]])
    problems = pl.check_initial(channel, [disk], x, np.zeros(4), np.zeros(4, int),
                                names=["disks"])
    # The disk at y = 4.75 reaches 5.25, 0.25 into the wall y = 5; disks 0 and 1
    # are 0.5 apart, overlapping by 0.5.
    assert problems == ["particle 2 (species 'disks') overlaps a wall by 0.25 m",
                        "particles 0 and 1 overlap by 0.5 m"]
    near = pl.check_initial(channel, [disk], [[5.0, 4.45], [7.0, 0.0]], np.zeros(2), [0, 0],
                            gap=0.1, names=["disks"])
    assert near == ["particle 0 (species 'disks') is 0.05 m from a wall, closer than the gap 0.1 m"]
    squares = pl.check_initial(channel, [sh.square(1.0)], [[5.0, 0.0], [5.9, 0.3], [0.3, 2.0]],
                               [0.0, 0.2, 0.0], [0, 0, 0])
    assert squares == ["particle 2 (species 0 (square)) sticks out through the inlet (x < 0)",
                       "particles 0 and 1 overlap"]


def test_check_initial_sees_a_wall_corner_inside_a_face(channel):
    # A 0.6 square whose top face (y = 0.88) passes over the expansion corner
    # (24.15, 0.85): the corner is 0.03 inside the square, yet none of the
    # square's 40 nodes (0.06 apart, at x = ..., 24.11, 24.17, ...) is in the wall.
    square = sh.square(0.6)
    x = np.array([[24.23, 0.58]])
    nodes = sh.transform(square.nodes, x[0], 0.0)
    assert wl.wall_distance(channel, nodes).min() > 0
    problems = pl.check_initial(channel, [square], x, [0.0], [0], names=["sq"])
    assert problems == ["particle 0 (species 'sq') overlaps a wall by 0.03 m"]
    # ... and placement never accepts such a spot: all its draws go through the same test.


def test_check_initial_sees_a_thin_wall_across_a_particle():
    # A bar 0.05 thick across a unit square: no vertex of either lies inside the
    # other, only the edge crossing test can tell.
    g = wl.from_polygon([[0, 0], [4, 0], [4, 2], [0, 2]],
                        obstacles=[[[1.0, 0.9], [3.0, 0.9], [3.0, 0.95], [1.0, 0.95]]])
    problems = pl.check_initial(g, [sh.square(1.0)], [[2.0, 1.0]], [0.0], [0], names=["sq"])
    assert problems == ["particle 0 (species 'sq') crosses a wall"]


def test_bad_arguments(channel):
    disk = sh.circle(D)
    with pytest.raises(ValueError, match="holds no fluid"):
        pl.place(0, channel, [disk], [0], (40.0, 50.0))
    with pytest.raises(ValueError, match="species_of_particle"):
        pl.place(0, channel, [disk], [1], (0.0, 20.0))
    with pytest.raises(ValueError, match="x0 must be < x1"):
        pl.count_for_fraction(0.2, channel, (5.0, 1.0), disk)


@pytest.mark.parametrize("key", ["feed.region", "feed.inlet"])
def test_a_feed_strip_past_the_constriction_is_refused(key, tmp_path, capsys):
    """Bodies placed (or fed) downstream of the constriction would count as escapees
    without crossing it, those past the escape line at the first step: the scene is
    refused in one line naming the key, the constriction's exit and the escape line
    (vani: exit at x = 0.003381, escape line half a diameter on, 0.003451); a strip
    ending at the exit is accepted."""
    from pathlib import Path

    from taichi_hsdem import load_scene
    from taichi_hsdem.cli import main
    from taichi_hsdem.resolve import resolve

    vani = str(Path(__file__).resolve().parents[1] / "scenes" / "vani_phi026.toml")
    out = tmp_path / "out"
    code = main([vani, "--set", f"{key}=[0.0025, 0.0036]", "--set", "run.t_end=1e-4",
                 "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and not out.exists()
    assert err[0].startswith(f"{vani}: {key}: [0.0025, 0.0036] reaches past the "
                             "constriction's exit at x = 0.003381 (the escape line is at "
                             "x = 0.003451)")
    model = resolve(load_scene(vani, [f"{key}=[0.0025, 0.003381]"]), "x64")
    assert (model.feed_region if key == "feed.region" else model.feed_inlet) == \
        (0.0025, 0.003381)
