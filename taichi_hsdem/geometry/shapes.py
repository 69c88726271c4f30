"""Particle shape templates for LS-DEM: geometry, surface nodes, level sets.

A shape template is a rigid 2D outline in its own *body frame*: the centroid is at
the origin and polygon vertices run counter-clockwise. From it this module derives
what the rest of the method needs (docs/model.md section 1):

* the mass properties (area, polar moment of area about the centroid), so that a
  particle's mass and inertia come from its shape instead of being assumed;
* surface nodes spaced evenly along the outline, each with the length of boundary
  it stands for and its outward normal (contact and fluid forces act there);
* nodes at a given spacing (`respaced`), and the frames (below).

The exact signed distance, the point surely inside a concave outline, the
thinnest part and the overlap test are in :mod:`.distance`.

Everything here is plain numpy and runs on the host, once per template. The
kernels that use the result live elsewhere.

Frames: a body point ``p`` of a particle at centre ``x`` and angle ``theta`` sits
at ``R(theta) p + x`` in the world (``transform``); ``to_body`` inverts it.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass

import numpy as np

from .polygon import cross, point_segment_distance, segments_intersect, signed_area

__all__ = [
    "Shape",
    "circle",
    "square",
    "rectangle",
    "regular_polygon",
    "polygon",
    "respaced",
    "transform",
    "to_body",
]



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
