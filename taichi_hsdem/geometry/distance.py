"""Distances and insides of a shape template, convex or not.

The exact signed distance to an outline (negative inside), which
:mod:`.levelset` samples on the grids the contact kernels read; what the
stability checks and the ``auto`` node and grid rules need to know of any
outline: a point surely inside it (`inside_point`: the centroid of a concave
body may lie outside it) and its thinnest part (`thinnest_width`); and whether
two placed templates overlap (`overlaps`, once per candidate pair when particles
are placed). Plain numpy, on the host.
"""

from __future__ import annotations

import math

import numpy as np

from .polygon import cross, crossings, is_convex, point_segment_distance, segments_intersect
from .shapes import to_body, transform

__all__ = ["signed_distance", "inside_point", "thinnest_width", "overlaps"]


# Round-off allowance of `overlaps`, relative to the bounding radii: outlines
# this close count as touching, not overlapping, so that shapes placed edge to
# edge by a rotation (cos(pi/2) is 6e-17, not 0) are not refused.
_REL_TOL = 1.0e-9

# A vertex that turns the outline inwards by at least this many degrees is a
# concave corner for `thinnest_width` (not the gentle turns of a concave arc).
CONCAVE_TURN = 20.0

# `thinnest_width`'s search for necks between two wide parts: the inside sampled
# on a grid of the outline's size over NECK_CELLS, and a neck counted only when
# both parts it joins are deeper than it by NECK_MARGIN cells (less is the grid's
# own ripple along a ridge of constant depth, an arm's midline).
NECK_CELLS = 128
NECK_MARGIN = 2.0

# Bound on the (points x edges) temporaries of the polygon distance, so that a
# fine level-set grid does not allocate gigabytes at once.
_CHUNK_ENTRIES = 1 << 20


def signed_distance(shape, points) -> np.ndarray:
    """Exact signed distance from points to a shape's outline, negative inside.

    Parameters
    ----------
    shape : Shape
    points : array_like of shape (..., 2)
        Body-frame points.

    Returns
    -------
    ndarray of shape (...)

    Examples
    --------
    >>> from taichi_hsdem.geometry.shapes import square
    >>> signed_distance(square(2.0), [[0.0, 0.0], [2.0, 0.0], [4.0, 5.0]]).tolist()
    [-1.0, 1.0, 5.0]
    """
    p = np.asarray(points, dtype=float)
    if p.shape[-1:] != (2,):
        raise ValueError(f"points must have shape (..., 2), got {p.shape}")
    if shape.kind == "circle":
        return np.hypot(p[..., 0], p[..., 1]) - shape.radius
    flat = p.reshape(-1, 2)
    out = np.empty(len(flat))
    chunk = max(1, _CHUNK_ENTRIES // len(shape.vertices))
    for start in range(0, len(flat), chunk):
        out[start : start + chunk] = _polygon_sdf(shape.vertices, flat[start : start + chunk])
    return out.reshape(p.shape[:-1])


def inside_point(shape, rel_tol: float = 1e-4) -> tuple[np.ndarray, float]:
    """The point deepest inside a shape (its pole of inaccessibility, the centre of
    its largest inscribed circle) and its depth, body frame.

    A concave body's centroid can lie outside it (an L's lies in its notch), so the
    "passed through" check tests this point instead: another body can hold it only
    once it has sunk into this one by the whole inscribed radius. The centroid is
    kept when no point is deeper by more than ``rel_tol`` of the size, so symmetric
    shapes answer their centre exactly.

    Parameters
    ----------
    shape : Shape
    rel_tol : float, optional
        Depth resolution of the search, relative to the outline's size.

    Returns
    -------
    point : ndarray of shape (2,)
    depth : float
        ``-signed_distance(shape, point)``, > 0.

    Examples
    --------
    >>> from taichi_hsdem.geometry.shapes import polygon
    >>> L = polygon([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]])
    >>> float(signed_distance(L, [0.0, 0.0])) > 0    # its centroid is in the notch
    True
    >>> p, depth = inside_point(L)
    >>> round(depth, 3), bool(signed_distance(L, p) < 0)    # 2 - sqrt(2)
    (0.586, True)
    """
    if shape.kind == "circle":
        return np.zeros(2), float(shape.radius)
    v = shape.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    size = float((hi - lo).max())
    tol = rel_tol * size
    best, depth = np.zeros(2), float(-signed_distance(shape, np.zeros(2)))
    # Best-first over a quadtree (polylabel): a cell of half-size r can hold no
    # point deeper than its centre's depth plus r sqrt(2); keep only the cells
    # that could beat the best by more than tol.
    half = size / 32.0
    nx, ny = (np.ceil((hi - lo) / (2 * half)).astype(int) + 1)
    gx = lo[0] + half * (2 * np.arange(nx) + 1)
    gy = lo[1] + half * (2 * np.arange(ny) + 1)
    cells = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
    while len(cells):
        d = -signed_distance(shape, cells)
        k = int(np.argmax(d))
        if d[k] > depth + tol:
            best, depth = cells[k].copy(), float(d[k])
        cells = cells[d + half * math.sqrt(2.0) > depth + tol]
        half *= 0.5
        cells = (cells[:, None, :] + half * np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]])
                 ).reshape(-1, 2)
    return best, depth


def thinnest_width(shape) -> float:
    """Width of the thinnest part of a shape: the diameter of its largest inscribed
    circle, or the shortest chord through its inside from a concave corner across
    to the far side, when shorter (an arm's width, the neck between two notches);
    a circle's diameter.

    Concave corners are vertices that turn the outline inwards by at least
    `CONCAVE_TURN` degrees: the gentle turns of a concave arc drawn as a polygon
    (a crescent's inner edge) do not count, so the width of a tapering horn or a
    sharp tip, which narrows to nothing, is not taken for the shape's. A gentle
    neck between two wider parts (a peanut's waist), which no sharp corner marks,
    is found as a saddle of the depth inside (`_neck_width`).

    Examples
    --------
    >>> from taichi_hsdem.geometry.shapes import polygon, rectangle
    >>> thinnest_width(polygon([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]]))
    1.0
    >>> thinnest_width(rectangle(2.0, 0.5))
    0.5
    """
    point, depth = inside_point(shape)
    best = 2.0 * depth
    if shape.kind == "circle":
        return best
    v = shape.vertices
    nv = len(v)
    a, ab = v, np.roll(v, -1, axis=0) - v
    before = np.roll(ab, 1, axis=0)      # the edge into vertex i; ab[i] leaves it
    angle = np.degrees(np.arctan2(cross(before, ab), np.sum(before * ab, axis=1)))
    size = float(np.ptp(v, axis=0).max())
    for i in np.flatnonzero(angle <= -CONCAVE_TURN):
        # closest point of every edge that does not end at vertex i
        t = np.clip(np.sum((v[i] - a) * ab, axis=1) / np.sum(ab * ab, axis=1), 0.0, 1.0)
        c = a + t[:, None] * ab
        dist = np.hypot(*(c - v[i]).T)
        dist[[i, (i - 1) % nv]] = np.inf
        for e in np.argsort(dist):
            if dist[e] >= best:
                break
            # a chord, not a path along the outline or across a notch
            pts = v[i] + np.linspace(0.0, 1.0, 9)[1:-1, None] * (c[e] - v[i])
            if np.all(signed_distance(shape, pts) < -1e-9 * size):
                best = float(dist[e])
                break
    neck, cell = _neck_width(shape)
    # a neck only where no chord or inscribed circle already gave that width (the
    # search's grid answers a chord's exact width a cell or two low)
    return neck if neck < best - NECK_MARGIN * cell else best


def _neck_width(shape) -> tuple[float, float]:
    """Twice the depth of the shallowest neck joining two deeper parts of a
    polygon (inf without one), and the search's grid cell: the width is found to
    about one cell (the ridge of the depth is crossed between grid points).

    The depth inside (minus the signed distance) peaks in each wide part and
    dips between two of them at a saddle, the middle of the neck: there the
    inscribed circle is the neck's width. Cells of a grid over the outline are
    joined deepest first to their eight neighbours (union-find); where a cell
    joins two parts, each deeper than it by more than `NECK_MARGIN` cells, it is
    a neck. A horn or a tip only narrows away from the body, so it joins nothing
    and is no neck.
    """
    v = shape.vertices
    if is_convex(v):
        return math.inf, 0.0          # the depth has one peak
    lo, hi = v.min(axis=0), v.max(axis=0)
    h = float((hi - lo).max()) / NECK_CELLS
    nx, ny = (np.ceil((hi - lo) / h).astype(int) + 1)
    gx = lo[0] + h * np.arange(nx)
    gy = lo[1] + h * np.arange(ny)
    depth = -signed_distance(shape, np.stack(np.meshgrid(gx, gy, indexing="ij"), -1))
    inside = depth > 0
    parent = np.full(nx * ny, -1)
    peak = np.zeros(nx * ny)          # the deepest cell of each part (at its root)

    def root(k):
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    flat = depth.ravel()
    neck = math.inf
    for k in np.argsort(-flat, kind="stable"):
        if not inside.flat[k]:
            break
        parent[k], peak[k] = k, flat[k]
        i, j = divmod(int(k), ny)
        for ii, jj in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1),
                       (i - 1, j - 1), (i - 1, j + 1), (i + 1, j - 1), (i + 1, j + 1)):
            if not (0 <= ii < nx and 0 <= jj < ny) or parent[ii * ny + jj] < 0:
                continue
            a, b = root(k), root(ii * ny + jj)
            if a == b:
                continue
            if min(peak[a], peak[b]) > flat[k] + NECK_MARGIN * h:
                neck = min(neck, 2.0 * float(flat[k]))
            if peak[a] < peak[b]:
                a, b = b, a
            parent[b] = a
    return neck, h


def overlaps(shape_a, xa, ta, shape_b, xb, tb, gap=0.0) -> bool:
    """Whether two placed shapes come closer than ``gap``.

    Used to place particles without overlap. Far pairs are rejected on their
    bounding circles. A pair with a disk is decided exactly from the disk's
    centre (distance to the other outline minus the radius). Two polygons
    overlap when an edge of one crosses an edge of the other (two bars laid
    across each other, no corner inside either), or when the exact signed
    distance of one, evaluated at probe points of the other, falls below
    ``gap``. The probes of a polygon are its vertices (the distance between
    disjoint polygons is reached at a vertex of one of them, so this is exact
    for ``gap > 0``, and testing both ways catches a corner driven into a face),
    the midpoints of its edges' pieces between the other's vertices lying on
    them (outlines that share part of an edge, at ``gap = 0``) and its
    `inside_point` (identical placement). The answer does not depend
    on the number of surface nodes.

    Outlines that touch to within round-off (1e-9 of the bounding radii) do not
    overlap at ``gap = 0``.

    Parameters
    ----------
    shape_a, shape_b : Shape
    xa, xb : array_like of shape (2,)
        Centres in the world frame.
    ta, tb : float
        Angles in radians.
    gap : float, optional
        Required clearance, >= 0.

    Returns
    -------
    bool

    Examples
    --------
    >>> from taichi_hsdem.geometry.shapes import square
    >>> s = square(1.0)
    >>> overlaps(s, [0, 0], 0.0, s, [1.0, 0.0], 0.0)      # touching faces
    False
    >>> overlaps(s, [0, 0], 0.0, s, [1.0, 0.0], 0.0, gap=0.01)
    True
    """
    gap = float(gap)
    if not gap >= 0:
        raise ValueError(f"gap must be >= 0, got {gap}")
    xa = np.asarray(xa, dtype=float)
    xb = np.asarray(xb, dtype=float)
    tol = _REL_TOL * (shape_a.bounding_radius + shape_b.bounding_radius)
    limit = gap - tol
    centre_distance = float(np.hypot(*(xb - xa)))
    if centre_distance - shape_a.bounding_radius - shape_b.bounding_radius >= limit:
        return False
    if shape_a.kind == "circle":
        return bool(signed_distance(shape_b, to_body(xa, xb, tb)) - shape_a.radius < limit)
    if shape_b.kind == "circle":
        return bool(signed_distance(shape_a, to_body(xb, xa, ta)) - shape_b.radius < limit)
    va = transform(shape_a.vertices, xa, ta)
    vb = transform(shape_b.vertices, xb, tb)
    ends_a, ends_b = np.roll(va, -1, axis=0), np.roll(vb, -1, axis=0)
    if segments_intersect(va[:, None], ends_a[:, None], vb[None], ends_b[None], tol,
                          touching=False).any():
        return True
    for s, v, x, t, other, vo, xo, to in (
        (shape_a, va, xa, ta, shape_b, vb, xb, tb),
        (shape_b, vb, xb, tb, shape_a, va, xa, ta),
    ):
        probes = [v, _piece_midpoints(v, vo, tol), transform(inside_point(s)[0], x, t)[None]]
        if signed_distance(other, to_body(np.vstack(probes), xo, to)).min() < limit:
            return True
    return False


# ---------------------------------------------------------------------------
# Internals
# ---------------------------------------------------------------------------


def _polygon_sdf(vertices, points) -> np.ndarray:
    a = vertices
    b = np.roll(vertices, -1, axis=0)
    dist = point_segment_distance(points[:, None, :], a, b).min(axis=1)
    inside = crossings(points, a, b) % 2 == 1
    return np.where(inside, -dist, dist)


def _piece_midpoints(v, others, tol) -> np.ndarray:
    """Midpoints of the pieces into which the points ``others`` lying on the
    closed polygon ``v``'s edges cut those edges.

    Without proper crossings, the other outline meets an edge only at its own
    vertices or along a shared stretch that ends at one, so each piece lies
    wholly inside, outside or on the other shape, and its midpoint tells which.
    """
    a = v[:, None]
    ab = np.roll(v, -1, axis=0)[:, None] - a
    t = np.sum((others[None] - a) * ab, axis=-1) / np.sum(ab * ab, axis=-1)
    on_edge = point_segment_distance(others[None], a, a + ab) <= tol
    # Points off an edge are moved to its end, where they only add empty pieces.
    t = np.where(on_edge, np.clip(t, 0.0, 1.0), 1.0)
    ends = np.ones((len(v), 1))
    t = np.sort(np.hstack([np.zeros_like(ends), t, ends]), axis=1)
    mid = 0.5 * (t[:, 1:] + t[:, :-1])
    return (a + mid[..., None] * ab).reshape(-1, 2)
