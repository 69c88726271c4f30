"""Particle shape templates for LS-DEM: geometry, surface nodes, level sets.

A shape template is a rigid 2D outline in its own *body frame*: the centroid is at
the origin and polygon vertices run counter-clockwise. From it this module derives
what the rest of the method needs (MODEL.md section 1):

* the mass properties (area, polar moment of area about the centroid), so that a
  particle's mass and inertia come from its shape instead of being assumed;
* surface nodes spaced evenly along the outline, each with the length of boundary
  it stands for and its outward normal (contact and fluid forces act there);
* the exact signed distance (negative inside), which :mod:`.levelset` samples on
  the grids the contact kernels read;
* what the stability checks and the ``auto`` node and grid rules need to know of
  any outline, convex or not: a point surely inside it (`inside_point`, the
  centroid of a concave body may lie outside it), its thinnest part
  (`thinnest_width`), and nodes at a given spacing (`respaced`).

Everything here is plain numpy and runs on the host: once per template, and
for `overlaps`, once per candidate pair when particles are placed. The kernels
that use the result live elsewhere.

Frames: a body point ``p`` of a particle at centre ``x`` and angle ``theta`` sits
at ``R(theta) p + x`` in the world (``transform``); ``to_body`` inverts it.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass

import numpy as np

from .polygon import (cross, crossings, point_segment_distance, segments_intersect,
                      signed_area)

__all__ = [
    "Shape",
    "circle",
    "square",
    "rectangle",
    "regular_polygon",
    "polygon",
    "signed_distance",
    "inside_point",
    "thinnest_width",
    "respaced",
    "transform",
    "to_body",
    "overlaps",
]


# Round-off allowance of `overlaps`, relative to the bounding radii: outlines
# this close count as touching, not overlapping, so that shapes placed edge to
# edge by a rotation (cos(pi/2) is 6e-17, not 0) are not refused.
_REL_TOL = 1.0e-9

# A vertex that turns the outline inwards by at least this many degrees is a
# concave corner for `thinnest_width` (not the gentle turns of a concave arc).
CONCAVE_TURN = 20.0

# Bound on the (points x edges) temporaries of the polygon distance, so that a
# fine level-set grid does not allocate gigabytes at once.
_CHUNK_ENTRIES = 1 << 20


# eq=False: generated equality would compare the arrays elementwise and fail;
# templates are compared by identity.
@dataclass(frozen=True, eq=False)
class Shape:
    """One particle shape template, in its body frame.

    Build it with `circle`, `square`, `rectangle`, `regular_polygon` or `polygon`
    rather than directly. Arrays are read-only.

    Attributes
    ----------
    name : str
        The constructor that made it: ``"circle"``, ``"square"``, ``"rectangle"``,
        ``"regular_polygon"`` or ``"polygon"``.
    kind : str
        ``"circle"`` (analytic contact, no level set needed) or ``"polygon"``.
    radius : float
        Circle radius for a circle; the bounding radius for a polygon.
    vertices : ndarray of shape (nv, 2) or None
        Polygon vertices, centroid at the origin, counter-clockwise. None for a
        circle.
    area : float
        Area of the outline.
    perimeter : float
        Length of the outline.
    inertia_per_mass : float
        Polar moment of area about the centroid divided by the area, so that a
        particle of mass ``m`` has moment of inertia ``m * inertia_per_mass``.
    bounding_radius : float
        Largest distance from the centroid to the outline.
    equivalent_diameter : float
        Diameter of the disk of the same area, ``sqrt(4 A / pi)``.
    sphericity : float
        2D sphericity ``sqrt(4 pi A) / P``: 1 for a circle, 0.886 for a square.
    nodes : ndarray of shape (n, 2)
        Surface nodes, evenly spaced by arc length; every polygon vertex is one.
    node_lengths : ndarray of shape (n,)
        Length of boundary each node stands for (half of each adjacent segment
        for a polygon, the arc ``P / n`` for a circle); sums to ``perimeter``.
    node_normals : ndarray of shape (n, 2)
        Outward unit normals at the nodes (at a vertex, the normalised sum of the
        two adjacent edge normals).
    """

    name: str
    kind: str
    radius: float
    vertices: np.ndarray | None
    area: float
    perimeter: float
    inertia_per_mass: float
    bounding_radius: float
    equivalent_diameter: float
    sphericity: float
    nodes: np.ndarray
    node_lengths: np.ndarray
    node_normals: np.ndarray


# ---------------------------------------------------------------------------
# Constructors
# ---------------------------------------------------------------------------


def circle(diameter, n_nodes=40) -> Shape:
    """A disk of the given diameter.

    Parameters
    ----------
    diameter : float
        Diameter, > 0.
    n_nodes : int, optional
        Number of surface nodes (>= 3), equally spaced starting at angle 0.

    Returns
    -------
    Shape

    Examples
    --------
    >>> s = circle(2.0, n_nodes=4)
    >>> s.nodes.round(12).tolist()
    [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [-0.0, -1.0]]
    >>> float(s.inertia_per_mass)
    0.5
    """
    r = 0.5 * check_positive("diameter", diameter)
    n = _node_count(n_nodes)
    angle = 2.0 * np.pi * np.arange(n) / n
    normals = np.column_stack([np.cos(angle), np.sin(angle)])
    perimeter = 2.0 * np.pi * r
    # Each node stands for its arc of the true circle, not half of each chord, so
    # the node lengths sum to the circle's perimeter as they do for polygons.
    return _make_shape(
        name="circle",
        kind="circle",
        vertices=None,
        area=np.pi * r * r,
        perimeter=perimeter,
        inertia_per_mass=0.5 * r * r,
        bounding_radius=r,
        nodes=r * normals,
        node_lengths=np.full(n, perimeter / n),
        node_normals=normals,
    )


def square(side, n_nodes=40) -> Shape:
    """An axis-aligned square (edges parallel to the body axes).

    Unlike ``regular_polygon(4, ...)``, which puts a vertex on the +x axis, the
    square's edges face the axes; its first node is the corner ``(-s/2, -s/2)``.

    Parameters
    ----------
    side : float
        Edge length, > 0.
    n_nodes : int, optional
        Number of surface nodes, >= 4.

    Returns
    -------
    Shape

    Examples
    --------
    >>> s = square(1.0, n_nodes=8)
    >>> float(s.area), float(s.perimeter), float(s.node_lengths[0])
    (1.0, 4.0, 0.5)
    """
    side = check_positive("side", side)
    return _polygon_shape(_box(side, side), n_nodes, "square", centred=True)


def rectangle(width, height, n_nodes=40) -> Shape:
    """An axis-aligned rectangle, ``width`` along body x and ``height`` along y.

    Parameters
    ----------
    width, height : float
        Edge lengths, > 0.
    n_nodes : int, optional
        Number of surface nodes, >= 4.

    Returns
    -------
    Shape

    Examples
    --------
    >>> s = rectangle(2.0, 1.0)
    >>> round(float(s.inertia_per_mass), 12)  # (w^2 + h^2) / 12
    0.416666666667
    """
    width = check_positive("width", width)
    height = check_positive("height", height)
    return _polygon_shape(_box(width, height), n_nodes, "rectangle", centred=True)


def regular_polygon(n_vertices, diameter, n_nodes=40) -> Shape:
    """A regular polygon inscribed in a circle of the given diameter.

    Parameters
    ----------
    n_vertices : int
        Number of vertices, >= 3.
    diameter : float
        Circumscribed (bounding) diameter, > 0. Vertex 0 lies on the +x axis.
    n_nodes : int, optional
        Number of surface nodes, >= ``n_vertices``.

    Returns
    -------
    Shape

    Examples
    --------
    >>> s = regular_polygon(3, 2.0, n_nodes=6)
    >>> s.vertices.round(12).tolist()
    [[1.0, 0.0], [-0.5, 0.866025403784], [-0.5, -0.866025403784]]
    """
    try:
        nv = operator.index(n_vertices)
    except TypeError:
        raise ValueError(f"n_vertices must be an integer, got {n_vertices!r}") from None
    if nv < 3:
        raise ValueError(f"a regular polygon needs n_vertices >= 3, got {nv}")
    r = 0.5 * check_positive("diameter", diameter)
    angle = 2.0 * np.pi * np.arange(nv) / nv
    vertices = r * np.column_stack([np.cos(angle), np.sin(angle)])
    return _polygon_shape(vertices, n_nodes, "regular_polygon", centred=True)


def polygon(vertices, n_nodes=40) -> Shape:
    """Any simple polygon, convex or concave, given in either orientation.

    The outline is recentred on its centroid and made counter-clockwise; give
    each vertex once (the outline closes itself).

    Parameters
    ----------
    vertices : array_like of shape (nv, 2)
        The outline, nv >= 3, no repeated vertices, no crossing or touching edges.
    n_nodes : int, optional
        Number of surface nodes, >= nv.

    Returns
    -------
    Shape

    Raises
    ------
    ValueError
        If the outline has fewer than 3 vertices, repeated vertices, crossing
        edges or zero area, or if ``n_nodes`` is fewer than its vertices.

    Examples
    --------
    >>> L = polygon([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]])
    >>> float(L.area), float(L.perimeter)
    (3.0, 8.0)
    """
    return _polygon_shape(vertices, n_nodes, "polygon")


# ---------------------------------------------------------------------------
# Distance, level sets, frames
# ---------------------------------------------------------------------------


def outline_polygon(shape, circle_segments: int = 32) -> np.ndarray:
    """The outline to draw a template with: its vertices, or for a circle a regular
    polygon of ``circle_segments`` vertices (body frame, counter-clockwise)."""
    if shape.kind == "circle":
        a = 2.0 * np.pi * np.arange(circle_segments) / circle_segments
        return shape.radius * np.column_stack([np.cos(a), np.sin(a)])
    return np.asarray(shape.vertices, dtype=np.float64)


def boundary_vectors(nodes: np.ndarray) -> np.ndarray:
    """Outward boundary vectors ``a_k`` (length times normal) of a closed CCW node
    loop: half the chord between a node's two neighbours, turned outwards.

    They sum to exactly zero over the loop (a uniform pressure pushes no body), and
    ``sum_k f(p_k) a_k`` integrates a linear ``f`` over the node polygon's outline
    exactly (the divergence theorem).

    Examples
    --------
    >>> a = boundary_vectors(square(2.0, 4).nodes)
    >>> a.sum(axis=0).tolist(), float((square(2.0, 4).nodes[:, 0] * a[:, 0]).sum())
    ([0.0, 0.0], 4.0)
    """
    chord = np.roll(nodes, -1, axis=0) - np.roll(nodes, 1, axis=0)
    return 0.5 * np.stack([chord[:, 1], -chord[:, 0]], axis=1)


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
    sharp tip, which narrows to nothing, is not taken for the shape's.

    Examples
    --------
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
    return best


def respaced(shape, spacing) -> Shape:
    """The same outline with surface nodes at most ``spacing`` apart: every edge of
    a polygon gets ``ceil(length / spacing)`` equal intervals (so equal edges, as
    on a regular polygon, get equal counts), a circle ``ceil(perimeter / spacing)``.

    Examples
    --------
    >>> len(respaced(regular_polygon(6, 2.0), 6.0 / 40).nodes)   # 7 per face
    42
    >>> len(respaced(circle(1.0), np.pi / 40).nodes)
    40
    """
    h = check_positive("spacing", spacing)
    if shape.kind == "circle":
        return circle(2.0 * shape.radius, max(3, int(_intervals(shape.perimeter, h))))
    edges = np.hypot(*(np.roll(shape.vertices, -1, axis=0) - shape.vertices).T)
    counts = _intervals(edges, h)
    return _polygon_shape(shape.vertices, int(counts.sum()), shape.name, centred=True,
                          counts=counts)


def _intervals(length, spacing):
    """Equal intervals at most ``spacing`` long in ``length`` (array-wise), at least 1."""
    # the allowance keeps a length that is a whole number of spacings (a perimeter
    # / 40) from gaining an interval to round-off, or to the few digits a scene
    # file gives its vertices in (a regular star's edges then differ by 1e-5)
    return np.maximum(1, np.ceil(np.asarray(length) / spacing - 1e-3).astype(int))


def transform(points_body, x, theta) -> np.ndarray:
    """Body-frame points to world frame: rotate by ``theta`` (CCW), then translate by ``x``.

    Parameters
    ----------
    points_body : array_like of shape (..., 2)
    x : array_like of shape (..., 2)
        Centre of mass in the world; broadcasts against ``points_body``.
    theta : float or array_like of shape (...)
        Angle in radians; broadcasts against the points' leading dimensions.

    Returns
    -------
    ndarray of shape (..., 2)

    Examples
    --------
    >>> transform([[1.0, 0.0]], [2.0, 3.0], np.pi / 2).round(12).tolist()
    [[2.0, 4.0]]
    """
    p = np.asarray(points_body, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    rotated = np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], axis=-1)
    return rotated + np.asarray(x, dtype=float)


def to_body(points_world, x, theta) -> np.ndarray:
    """World-frame points to the body frame of a particle at ``x``, angle ``theta``.

    The inverse of `transform`.

    Parameters
    ----------
    points_world : array_like of shape (..., 2)
    x : array_like of shape (..., 2)
        Centre of mass in the world; broadcasts against ``points_world``.
    theta : float or array_like of shape (...)
        Angle in radians.

    Returns
    -------
    ndarray of shape (..., 2)

    Examples
    --------
    >>> to_body([[2.0, 4.0]], [2.0, 3.0], np.pi / 2).round(12).tolist()
    [[1.0, 0.0]]
    """
    d = np.asarray(points_world, dtype=float) - np.asarray(x, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


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


def check_positive(name, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def _node_count(n_nodes) -> int:
    try:
        n = operator.index(n_nodes)
    except TypeError:
        raise ValueError(f"n_nodes must be an integer, got {n_nodes!r}") from None
    if n < 3:
        raise ValueError(f"n_nodes must be >= 3, got {n}")
    return n


def _box(width, height) -> np.ndarray:
    hw, hh = 0.5 * width, 0.5 * height
    return np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])


def frozen(a) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def concat_arrays(arrays, empty_shape) -> np.ndarray:
    return np.concatenate(arrays) if arrays else np.zeros(empty_shape)


def _make_shape(*, name, kind, vertices, area, perimeter, inertia_per_mass, bounding_radius,
                nodes, node_lengths, node_normals) -> Shape:
    return Shape(
        name=name,
        kind=kind,
        radius=float(bounding_radius),
        vertices=None if vertices is None else frozen(vertices),
        area=float(area),
        perimeter=float(perimeter),
        inertia_per_mass=float(inertia_per_mass),
        bounding_radius=float(bounding_radius),
        equivalent_diameter=math.sqrt(4.0 * area / math.pi),
        sphericity=math.sqrt(4.0 * math.pi * area) / perimeter,
        nodes=frozen(nodes),
        node_lengths=frozen(node_lengths),
        node_normals=frozen(node_normals),
    )


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


def _check_outline(vertices) -> np.ndarray:
    """Validate a user's polygon; messages use the user's vertex numbering.

    Points within 1e-12 of the outline's size count as coincident: only exact
    repeats and touches survive the floating-point input, and anything coarser
    would refuse legitimate thin features.
    """
    v = np.asarray(vertices, dtype=float)
    if v.ndim != 2 or v.shape[1] != 2:
        raise ValueError(f"polygon vertices must be a list of [x, y] pairs, got shape {v.shape}")
    nv = len(v)
    if nv < 3:
        raise ValueError(f"a polygon needs at least 3 vertices, got {nv}")
    if not np.all(np.isfinite(v)):
        raise ValueError("polygon vertices must be finite numbers")
    tol = 1e-12 * float(np.ptp(v, axis=0).max())
    dist = np.hypot(*(v[:, None, :] - v[None, :, :]).transpose(2, 0, 1))
    i, j = np.nonzero(np.triu(dist <= tol, k=1))
    if len(i):
        raise ValueError(
            f"polygon vertices {i[0]} and {j[0]} are the same point "
            "(give each vertex once; the outline closes itself)"
        )
    a = v
    b = np.roll(v, -1, axis=0)
    # Edges that share no vertex must not meet at all (crossing or touching).
    ea, eb = np.triu_indices(nv, k=2)
    keep = ~((ea == 0) & (eb == nv - 1))
    ea, eb = ea[keep], eb[keep]
    meet = segments_intersect(a[ea], b[ea], a[eb], b[eb], tol, touching=False)
    for p, (s, e) in ((a[ea], (a[eb], b[eb])), (b[ea], (a[eb], b[eb])),
                      (a[eb], (a[ea], b[ea])), (b[eb], (a[ea], b[ea]))):
        meet |= point_segment_distance(p, s, e) <= tol
    if meet.any():
        k = np.argmax(meet)
        raise ValueError(f"polygon edges {ea[k]} and {eb[k]} cross (the outline must be a simple polygon)")
    # Neighbouring edges need no test of their own: one folding back onto the
    # other puts a vertex on a non-neighbouring edge (caught above) or, for a
    # triangle, leaves no area.
    if abs(signed_area(v)) <= 1e-12 * float(np.ptp(v, axis=0).max()) ** 2:
        raise ValueError("polygon has zero area (its vertices are collinear)")
    return v


def _polygon_shape(vertices, n_nodes, name, centred=False, counts=None) -> Shape:
    """Shape from an outline; ``centred``: the outline's centroid is the origin
    (by symmetry, or already shifted), so skip the shift that would only add
    round-off to it; ``counts``: node intervals per edge (default: ``n_nodes``
    spread by `_edge_counts`)."""
    v = _check_outline(vertices)
    n = _node_count(n_nodes)
    if n < len(v):
        raise ValueError(f"n_nodes={n} is fewer than the polygon's {len(v)} vertices")
    if signed_area(v) < 0:
        v = v[::-1]
    w = np.roll(v, -1, axis=0)
    c = cross(v, w)
    area = 0.5 * c.sum()
    if not centred:
        centroid = ((v + w) * c[:, None]).sum(axis=0) / (6.0 * area)
        v = v - centroid
        w = w - centroid
        c = cross(v, w)
    # Polar moment of area of the triangle fan from the (now centroidal) origin.
    polar = np.sum(c * (np.sum(v * v, axis=1) + np.sum(v * w, axis=1) + np.sum(w * w, axis=1))) / 12.0
    nodes, lengths, normals = _polygon_nodes(v, n, counts)
    edge_len = np.hypot(*(w - v).T)
    return _make_shape(
        name=name,
        kind="polygon",
        vertices=v,
        area=area,
        perimeter=edge_len.sum(),
        inertia_per_mass=polar / area,
        bounding_radius=np.hypot(v[:, 0], v[:, 1]).max(),
        nodes=nodes,
        node_lengths=lengths,
        node_normals=normals,
    )


def _edge_counts(lengths, n) -> np.ndarray:
    """Split ``n`` sub-intervals over edges: each edge in equal intervals, the
    split at the largest spacing ``s`` whose ``max(1, ceil(length / s))`` per edge
    makes at most ``n`` (what `respaced` gives at that spacing, so that a resolved
    scene's count rebuilds the nodes ``"auto"`` chose), the rest, if ``n`` is not
    such a total, one each to the edges with the longest intervals.

    Every vertex is a node, the spacing is as even as whole numbers allow, and
    equal edges get equal counts whenever ``n`` allows (a regular polygon at a
    multiple of its vertex count).
    """
    lengths = np.asarray(lengths, dtype=float)
    # the spacings at which some edge's count changes, longest first
    k = np.arange(1, n + 1)
    candidates = np.unique((lengths[:, None] / k[None]).ravel())[::-1]
    counts = np.ones(len(lengths), dtype=int)
    for spacing in candidates:
        trial = _intervals(lengths, spacing)
        if trial.sum() > n:
            break
        counts = trial
    while counts.sum() < n:
        counts[np.argmax(lengths / counts)] += 1
    return counts


def _polygon_nodes(v, n, counts=None):
    edges = np.roll(v, -1, axis=0) - v
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    if counts is None:
        counts = _edge_counts(lengths, n)
    frac = np.concatenate([np.arange(m) / m for m in counts])
    edge = np.repeat(np.arange(len(v)), counts)
    nodes = v[edge] + frac[:, None] * edges[edge]
    edge_normals = np.column_stack([edges[:, 1], -edges[:, 0]]) / lengths[:, None]
    normals = edge_normals[edge]
    bisector = edge_normals + np.roll(edge_normals, 1, axis=0)
    first = np.cumsum(counts) - counts  # node index of each vertex
    normals[first] = bisector / np.hypot(bisector[:, 0], bisector[:, 1])[:, None]
    segment = np.repeat(lengths / counts, counts)  # node i to node i + 1
    node_lengths = 0.5 * (segment + np.roll(segment, 1))
    return nodes, node_lengths, normals
