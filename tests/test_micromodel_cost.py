"""What makes a micromodel's steps cheap keeps their answers: the throats' search
for particles near them (Throats.near) asks the tree only about the points in
reach of the throats' box, and finds the pairs every point would have found."""
import itertools

import numpy as np

from taichi_hsdem.geometry.micromodel import pillar_array
from taichi_hsdem.geometry.throats import find_throats


def _every_point(throats, points, radius):
    """Throats.near asking the tree about every point (as it did before)."""
    lists = throats._tree.query_ball_point(points, radius + throats.widths.max() / 2)
    counts = np.fromiter(map(len, lists), dtype=int, count=len(lists))
    throat = np.fromiter(itertools.chain.from_iterable(lists), dtype=int,
                         count=int(counts.sum()))
    return np.repeat(np.arange(len(points)), counts), throat


def test_near_finds_the_pairs_of_every_point_asked_in_the_same_order():
    m = pillar_array("square", rows=6, columns=4, diameter=200e-6, spacing=350e-6,
                     inlet_length=5e-3, outlet_length=0.4e-3)
    t = find_throats(m.outline, m.obstacles)
    lo, hi = m.outline.min(axis=0), m.outline.max(axis=0)
    rng = np.random.default_rng(3)
    points = lo + rng.random((4000, 2)) * (hi - lo)
    # points exactly at the box's edge widened by the reach, and just beyond it
    box_lo, box_hi = t.midpoints.min(axis=0), t.midpoints.max(axis=0)
    r = 100e-6
    reach = r + t.widths.max() / 2
    edge = np.array([[box_lo[0] - reach, box_lo[1]], [box_hi[0] + reach, box_hi[1]],
                     [box_lo[0], box_lo[1] - reach], [box_hi[0], box_hi[1] + reach],
                     [np.nextafter(box_lo[0] - reach, -1), box_lo[1]],
                     [t.midpoints[0, 0] - reach, t.midpoints[0, 1]]])
    points = np.r_[points, edge]
    for radius in (np.full(len(points), r), rng.random(len(points)) * 400e-6,
                   np.zeros(len(points))):
        i0, k0 = _every_point(t, points, radius)
        i1, k1 = t.near(points, radius)
        assert np.array_equal(i0, i1) and np.array_equal(k0, k1)
    i1, _ = t.near(points, np.full(len(points), r))
    assert 0 < len(np.unique(i1)) < len(points) / 2     # most points were left out


def test_near_with_every_point_out_of_reach_or_none():
    m = pillar_array("square", rows=3, columns=4, diameter=1.0, spacing=2.0,
                     inlet_length=20.0, outlet_length=2.0)
    t = find_throats(m.outline, m.obstacles)
    far = np.array([[-50.0, 0.0], [0.5, 0.0]])     # in the long inlet, far upstream
    i, k = t.near(far, np.full(2, 1.0))
    assert i.shape == k.shape == (0,)
    i, k = t.near(np.zeros((0, 2)), np.zeros(0))
    assert i.shape == k.shape == (0,)
