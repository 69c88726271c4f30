"""Plane-polygon primitives shared by the scene checks, shapes, walls, placement and
the renderer, each written once: the 2D cross product, the signed (shoelace) area,
segment intersection, the even-odd point-in-polygon test, distance to segments,
clipping to a vertical strip and ear-clipping triangulation.

Polygons are ``(n, 2)`` arrays of vertices without a repeated closing vertex.
"""
from __future__ import annotations

import numpy as np

# Points x edges per chunk of the vectorised tests (bounds their memory).
CHUNK_ELEMENTS = 2 ** 21


def cross(a, b):
    """``a_x b_y - a_y b_x`` over the last axis (broadcast)."""
    a, b = np.asarray(a), np.asarray(b)
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def is_convex(poly) -> bool:
    """Whether a counter-clockwise polygon turns left (or goes straight, to
    round-off) at every vertex.

    Examples
    --------
    >>> is_convex([[0, 0], [2, 0], [2, 2], [0, 2]]), is_convex([[0, 0], [2, 0], [1, 0.5], [1, 2]])
    (True, False)
    """
    v = np.asarray(poly, dtype=float)
    e = np.roll(v, -1, axis=0) - v
    size = float(np.ptp(v, axis=0).max())
    return bool(np.all(cross(e, np.roll(e, -1, axis=0)) >= -1e-12 * size * size))


def signed_area(poly) -> float:
    """Shoelace area, positive for a counter-clockwise polygon.

    Examples
    --------
    >>> signed_area([[0, 0], [2, 0], [2, 1], [0, 1]])
    2.0
    """
    poly = np.asarray(poly, dtype=float)
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def segments_intersect(p1, p2, q1, q2, tol: float = 0.0, touching: bool = True) -> np.ndarray:
    """Whether closed segments ``[p1, p2]`` and ``[q1, q2]`` cross or touch (broadcast).

    Parameters
    ----------
    p1, p2, q1, q2 : (..., 2) array_like
        Segment end points; broadcast against each other.
    tol : float
        Distance within which an end point counts as lying on the other segment.
    touching : bool
        Count segments that only touch (an end point on the other segment, or
        collinear overlap) as intersecting; False: only proper crossings, each end
        point farther than ``tol`` from the other segment's line, on opposite sides.

    Returns
    -------
    ndarray of bool

    Examples
    --------
    >>> segments_intersect([0, 0], [2, 2], [[0, 2], [3, 0]], [[2, 0], [3, 2]]).tolist()
    [True, False]
    """
    p1, p2, q1, q2 = (np.asarray(v, dtype=float) for v in (p1, p2, q1, q2))
    ep, eq = p2 - p1, q2 - q1
    # Orientation of each end point against the other segment's line, turned into
    # a signed distance so that `tol` is a length.
    lp = np.maximum(np.hypot(ep[..., 0], ep[..., 1]), 1e-300)
    lq = np.maximum(np.hypot(eq[..., 0], eq[..., 1]), 1e-300)
    d1, d2 = cross(eq, p1 - q1) / lq, cross(eq, p2 - q1) / lq
    d3, d4 = cross(ep, q1 - p1) / lp, cross(ep, q2 - p1) / lp
    proper = (((d1 > tol) & (d2 < -tol)) | ((d1 < -tol) & (d2 > tol))) & \
             (((d3 > tol) & (d4 < -tol)) | ((d3 < -tol) & (d4 > tol)))
    if not touching:
        return proper
    touch = (_on_segment(p1, q1, q2, d1, tol) | _on_segment(p2, q1, q2, d2, tol)
             | _on_segment(q1, p1, p2, d3, tol) | _on_segment(q2, p1, p2, d4, tol))
    return proper | touch


def first_crossing(poly, tol: float = 0.0) -> tuple[int, int] | None:
    """The first pair ``(i, j)``, ``i < j`` in row order, of non-adjacent edges of the
    closed polygon ``poly`` that cross or touch (within ``tol``), or None when it is
    simple. Edge ``i`` runs from vertex ``i`` to ``i + 1``.

    Vectorised over blocks of ``CHUNK_ELEMENTS`` pairs: a 6000-vertex outline takes
    seconds, where a pair-by-pair loop took minutes.

    Examples
    --------
    >>> first_crossing([[0, 0], [2, 0], [0, 2], [2, 2]])     # a bow tie
    (1, 3)
    >>> first_crossing([[0, 0], [1, 0], [0, 1]]) is None
    True
    """
    a = np.asarray(poly, dtype=float)
    b = np.roll(a, -1, axis=0)
    n = len(a)
    rows = max(1, CHUNK_ELEMENTS // max(n, 1))
    for start in range(0, n - 2, rows):
        i = np.arange(start, min(start + rows, n - 2))[:, None]
        j = np.arange(start + 2, n)[None, :]
        # non-adjacent: j >= i + 2, and not the closing pair (0, n - 1)
        wanted = (j >= i + 2) & ~((i == 0) & (j == n - 1))
        hit = segments_intersect(a[i], b[i], a[j], b[j], tol) & wanted
        if hit.any():
            r, c = np.unravel_index(int(np.argmax(hit)), hit.shape)
            return int(i[r, 0]), int(j[0, c])
    return None


def _on_segment(p, a, b, d, tol):
    """p within tol of the line through a, b (d: its signed distance) and inside the box."""
    lo, hi = np.minimum(a, b) - tol, np.maximum(a, b) + tol
    inside = np.all((p >= lo) & (p <= hi), axis=-1)
    return (np.abs(d) <= tol) & inside


def point_segment_distance(p, a, b) -> np.ndarray:
    """Distance from points ``p`` to segments ``a``-``b`` (all broadcast)."""
    ab = b - a
    ap = p - a
    t = np.clip(np.sum(ap * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0.0, 1.0)
    d = ap - t[..., None] * ab
    return np.hypot(d[..., 0], d[..., 1])


def points_in_polygon(points, poly) -> np.ndarray:
    """Even-odd crossing test (points exactly on an edge: either answer).

    Examples
    --------
    >>> points_in_polygon([[0.5, 0.5], [1.5, 0.5]], [[0, 0], [1, 0], [1, 1], [0, 1]]).tolist()
    [True, False]
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    poly = np.asarray(poly, dtype=float)
    return crossings(points, poly, np.roll(poly, -1, axis=0)) % 2 == 1


def crossings(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Number of edges a->b crossed by the ray from each point towards +x (the
    half-open test on y counts a ray through a vertex once)."""
    count = np.zeros(len(points), dtype=np.int64)
    step = max(1, CHUNK_ELEMENTS // max(len(a), 1))
    dy = b[:, 1] - a[:, 1]
    safe_dy = np.where(dy == 0, 1.0, dy)  # horizontal edges never straddle a height
    for s in range(0, len(points), step):
        px = points[s:s + step, 0:1]
        py = points[s:s + step, 1:2]
        straddle = (a[:, 1] > py) != (b[:, 1] > py)
        x_cross = a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / safe_dy
        count[s:s + step] = np.count_nonzero(straddle & (px < x_cross), axis=1)
    return count


def clip_half_plane(poly: np.ndarray, xc: float, keep_right: bool) -> np.ndarray:
    """The part of ``poly`` right (``keep_right``) or left of the line x = xc."""
    s = poly[:, 0] - xc if keep_right else xc - poly[:, 0]
    out = []
    n = len(poly)
    for k in range(n):
        q = (k + 1) % n
        if s[k] >= 0:
            out.append(poly[k])
        if (s[k] >= 0) != (s[q] >= 0):
            out.append(poly[k] + s[k] / (s[k] - s[q]) * (poly[q] - poly[k]))
    return np.array(out).reshape(-1, 2)


def clipped_area(poly: np.ndarray, x0: float, x1: float) -> float:
    """Signed area of the part of ``poly`` between x = x0 and x = x1."""
    clipped = clip_half_plane(clip_half_plane(poly, x0, True), x1, False)
    return signed_area(clipped) if len(clipped) >= 3 else 0.0


def triangulate(vertices) -> np.ndarray:
    """Ear-clipping triangulation of a simple polygon (convex or concave).

    Parameters
    ----------
    vertices : array_like, shape (n, 2)
        Outline, either orientation, no repeated closing vertex.

    Returns
    -------
    ndarray of int, shape (n - 2 - (collinear vertices), 3)
        Counter-clockwise triangles as indices into ``vertices``.

    Raises
    ------
    ValueError
        If the outline crosses itself (no ear left, or the triangles overlap).

    Examples
    --------
    >>> triangulate([[0, 0], [2, 0], [2, 2], [1, 1], [0, 2]]).shape
    (3, 3)
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
        raise ValueError(f"a polygon needs (n >= 3, 2) vertices, got shape {v.shape}")
    ring = list(range(len(v))) if signed_area(v) > 0 else list(range(len(v)))[::-1]
    eps = 1e-12 * float(np.ptp(v, axis=0).max()) ** 2

    def orient(a, b, c):
        return (v[b, 0] - v[a, 0]) * (v[c, 1] - v[a, 1]) - (v[b, 1] - v[a, 1]) * (v[c, 0] - v[a, 0])

    triangles = []
    while len(ring) > 3:
        m = len(ring)
        for k in range(m):
            a, b, c = ring[k - 1], ring[k], ring[(k + 1) % m]
            turn = orient(a, b, c)
            if abs(turn) <= eps:          # collinear: drop b, no triangle lost
                del ring[k]
                break
            if turn < 0:                  # reflex vertex
                continue
            corners = {tuple(v[a]), tuple(v[b]), tuple(v[c])}
            blocked = any(
                tuple(v[p]) not in corners
                and orient(a, b, p) >= -eps and orient(b, c, p) >= -eps and orient(c, a, p) >= -eps
                for p in ring)
            if not blocked:
                triangles.append((a, b, c))
                del ring[k]
                break
        else:
            raise ValueError("polygon is not simple: ear clipping found no ear")
    if abs(orient(*ring)) > eps:
        triangles.append(tuple(ring))
    triangles = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    # Crossing edges can still yield ears; the pieces then overlap or turn
    # clockwise, and their areas no longer add up to the outline's.
    areas = triangle_areas(v, triangles)
    if np.any(areas <= 0.0) or abs(areas.sum() - abs(signed_area(v))) > 1e-9 * areas.sum():
        raise ValueError("polygon is not simple: its triangles overlap (edges cross)")
    return triangles


def triangle_areas(points, triangles):
    """Signed areas of triangles given as index triples into ``points``."""
    a, b, c = (points[triangles[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    return 0.5 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
