"""Channel walls: the fluid region and its signed distance (the gridded wall level
set is :mod:`.wallfield`).

The fluid region is a simple polygon, the *outline*, minus solid islands, the
*obstacles* (docs/model.md section 1: "Walls (channel outline, constriction) are a
static level set on a fixed grid"). The outline's edges on ``x = x_min`` are the
inlet and those on ``x = x_max`` the outlet: they are open, every other edge is a
wall.

Open ends
---------
Particles reach the outlet (and, rarely, back past the inlet), so the wall level
set must not change sign across an open edge: if it did, a node crossing the
outlet would jump from ``phi = +w/2`` to ``phi = -w/2`` and be hit by a wall force
as deep as half the channel. The fluid region is therefore continued straight
beyond each open edge: a point with ``x <= x_min`` is fluid when its height lies
inside an inlet edge, and the walls ending at the edge are continued as rays
parallel to the x axis. Inside ``x_min <= x <= x_max`` the rays are never nearer
than the wall they continue (a ray's nearest point to such a point is its corner,
which the wall contains), so ``wall_distance`` there is the exact distance to the
walls; beyond the open ends it is the distance of the straight continuation.

Examples
--------
>>> g = converging(width_in=4.0, length_in=6.0, constriction_width=1.0, length_out=3.0)
>>> round(width_at(g, 3.0), 12), round(width_at(g, g.constriction_x0), 12)
(4.0, 1.0)
>>> [round(float(v), 12) for v in wall_distance(g, [[1.0, 0.0], [1.0, 2.5]])]
[2.0, -0.5]
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .nearest import ObstacleIndex
from .polygon import (CHUNK_ELEMENTS, clipped_area, cross, crossings, first_crossing,
                      points_in_polygon, segments_intersect, signed_area)

# Relative tolerance of "same width" / "same x" against the geometry's size:
# outlines are built from sums and products of the user's numbers, exact to a
# few ulps, never to 1e-9.
_REL_TOL = 1e-9


class _WallData(NamedTuple):
    """Arrays derived once from a geometry, for the vectorised queries."""
    wall_a: np.ndarray      # (S, 2) wall segment starts
    wall_b: np.ndarray      # (S, 2) wall segment ends
    piece_a: np.ndarray     # (P, 2) walls and open-end rays: start
    piece_u: np.ndarray     # (P, 2) unit direction
    piece_len: np.ndarray   # (P,) length, inf for a ray
    edge_a: np.ndarray      # (E, 2) every polygon edge (outline incl. open ones, obstacles)
    edge_b: np.ndarray      # (E, 2)
    inlet: np.ndarray       # (k, 2) y intervals of the inlet edges
    outlet: np.ndarray      # (k, 2) y intervals of the outlet edges
    corners: np.ndarray     # (C, 2) every outline and obstacle vertex
    outline_pieces: tuple   # (start, unit, length) of the outline's walls and rays
    index: object           # ObstacleIndex of the obstacles (nearest.py), None without


@dataclass(frozen=True, eq=False)
class Geometry:
    """The fluid region of a channel: outline, obstacles, constriction, control volume.

    Build it with `hourglass`, `converging` or `from_polygon` rather than directly:
    they validate the polygons and find the constriction. Arrays are read-only.
    ``eq=False``: two geometries compare by identity (comparing arrays
    element-wise has no single truth value).

    Attributes
    ----------
    outline : (nv, 2) ndarray
        The fluid region, a simple counter-clockwise polygon, m.
    obstacles : tuple of (k, 2) ndarray
        Solid islands strictly inside the outline, counter-clockwise, m.
    x_min, x_max, y_min, y_max : float
        Bounding box of the outline. Edges on ``x = x_min`` are the inlet, edges on
        ``x = x_max`` the outlet; both are open (not walls).
    constriction_x0, constriction_x1 : float
        x range of the narrowest section (equal for a point-like neck).
    constriction_width : float
        Open width there, m.
    upstream_region : tuple of float
        ``(x0, x1)``: the default control volume (``feed.region``), the upstream
        straight section.

    Examples
    --------
    >>> g = hourglass(length=10.0, width=2.0, neck_width=0.5)
    >>> g.constriction_x0, g.constriction_width, g.upstream_region
    (5.0, 0.5, (0.0, 3.0))
    """
    outline: np.ndarray
    obstacles: tuple
    x_min: float
    x_max: float
    y_min: float
    y_max: float
    constriction_x0: float
    constriction_x1: float
    constriction_width: float
    upstream_region: tuple
    _walls: _WallData = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        # Frozen dataclass: derived arrays are set once, through object.__setattr__.
        object.__setattr__(self, "_walls", _wall_data(self.outline, self.obstacles,
                                                      self.x_min, self.x_max))


# ----------------------------------------------------------------------------
# Generators
# ----------------------------------------------------------------------------

def hourglass(length, width, neck_width, neck_x=None, taper_length=None) -> Geometry:
    """Straight channel whose walls narrow linearly to a neck and widen again (Sec. 3.1).

    The channel runs from ``x = 0`` to ``x = length`` with ``y`` in
    ``[-width/2, width/2]``; both walls move inward linearly over ``taper_length``
    to ``neck_width`` at ``neck_x`` and back out over the next ``taper_length``,
    symmetric about ``y = 0``.

    Parameters
    ----------
    length, width : float
        Channel length and width, m.
    neck_width : float
        Narrowest width, in ``(0, width)``, m.
    neck_x : float, optional
        Position of the neck, m from the inlet; default ``length / 2``.
    taper_length : float, optional
        Length over which each side narrows, m; default ``width``. The taper
        ``[neck_x - taper_length, neck_x + taper_length]`` must lie in ``[0, length]``.

    Returns
    -------
    Geometry
        Constriction at ``neck_x`` (a point), control volume
        ``(0, neck_x - taper_length)``, or ``(0, neck_x)`` when the taper starts at
        the inlet.

    Examples
    --------
    >>> g = hourglass(10.0, 2.0, 0.5, neck_x=4.0, taper_length=1.5)
    >>> round(width_at(g, 4.0), 12), round(width_at(g, 3.25), 12)
    (0.5, 1.25)
    """
    length, width, neck_width = float(length), float(width), float(neck_width)
    neck_x = length / 2 if neck_x is None else float(neck_x)
    taper = width if taper_length is None else float(taper_length)
    _require(length > 0, f"hourglass: length must be > 0, got {length}")
    _require(width > 0, f"hourglass: width must be > 0, got {width}")
    _require(0 < neck_width < width,
             f"hourglass: neck_width must be in (0, width = {width}), got {neck_width}")
    _require(taper > 0, f"hourglass: taper_length must be > 0, got {taper}")
    _require(neck_x - taper >= 0 and neck_x + taper <= length,
             f"hourglass: the taper [neck_x - taper_length, neck_x + taper_length] = "
             f"[{neck_x - taper:g}, {neck_x + taper:g}] must lie within the channel "
             f"[0, length = {length:g}]")
    h, n = width / 2, neck_width / 2
    bottom = [(0.0, -h), (neck_x - taper, -h), (neck_x, -n), (neck_x + taper, -h), (length, -h)]
    top = [(x, -y) for x, y in reversed(bottom)]
    upstream_end = neck_x - taper if neck_x - taper > 0 else neck_x
    return _build(np.array(bottom + top), (), constriction=(neck_x, neck_x),
                  upstream=(0.0, upstream_end))


def converging(width_in, length_in, constriction_width, length_out, angle=45.0,
               constriction_length=0.0, width_out=None) -> Geometry:
    """Wide channel, converging section, straight constriction, sudden expansion (Sec. 3.2).

    From the inlet at ``x = 0``: a straight channel of width ``width_in`` and
    length ``length_in``; both walls converge at the half-angle ``angle`` (to the
    x axis) until the width is ``constriction_width``, which takes
    ``(width_in - constriction_width) / (2 tan(angle))``; a straight
    constriction of length ``constriction_length``; then a sudden expansion to
    ``width_out`` for ``length_out``. Symmetric about ``y = 0``.

    Parameters
    ----------
    width_in, length_in : float
        Upstream channel width and straight length, m.
    constriction_width : float
        ``W``, in ``(0, width_in)``, m.
    length_out : float
        Outlet channel length, m.
    angle : float
        Convergence half-angle in ``(0, 90]``, degrees (90: a sudden contraction).
    constriction_length : float
        Straight constriction length, >= 0, m.
    width_out : float, optional
        Outlet channel width, >= ``constriction_width``; default ``width_in``.

    Returns
    -------
    Geometry
        Constriction ``[x0, x0 + constriction_length]`` with ``x0`` the end of the
        converging section; control volume ``(0, length_in)``.

    Examples
    --------
    >>> g = converging(4.0, 6.0, 1.0, 3.0, angle=45.0, constriction_length=0.5)
    >>> [round(v, 12) for v in (g.constriction_x0, g.constriction_x1, g.x_max)]
    [7.5, 8.0, 11.0]
    """
    width_in, length_in = float(width_in), float(length_in)
    w, length_out, angle = float(constriction_width), float(length_out), float(angle)
    lc = float(constriction_length)
    width_out = width_in if width_out is None else float(width_out)
    _require(width_in > 0, f"converging: width_in must be > 0, got {width_in}")
    _require(length_in > 0, f"converging: length_in must be > 0, got {length_in}")
    _require(0 < w < width_in, f"converging: constriction_width must be in "
                               f"(0, width_in = {width_in:g}), got {w:g}")
    _require(length_out > 0, f"converging: length_out must be > 0, got {length_out}")
    _require(0 < angle <= 90, f"converging: angle must be in (0, 90] degrees, got {angle}")
    _require(lc >= 0, f"converging: constriction_length must be >= 0, got {lc}")
    _require(width_out >= w, f"converging: width_out must be >= constriction_width "
                             f"= {w:g}, got {width_out:g}")
    # At 90 degrees tan() is ~1e16, not infinite: a sudden contraction must have
    # exactly zero length, not a sliver edge of 1e-17 m.
    taper = 0.0 if angle == 90 else (width_in - w) / 2 / np.tan(np.radians(angle))
    x0 = length_in + taper
    x1 = x0 + lc
    x_end = x1 + length_out
    hi, hw, ho = width_in / 2, w / 2, width_out / 2
    bottom = [(0.0, -hi), (length_in, -hi), (x0, -hw), (x1, -hw), (x1, -ho), (x_end, -ho)]
    top = [(x, -y) for x, y in reversed(bottom)]
    return _build(np.array(bottom + top), (), constriction=(x0, x1),
                  upstream=(0.0, length_in))


def from_polygon(outline, obstacles=(), constriction_x=None) -> Geometry:
    """A geometry from a user's outline and solid islands.

    Parameters
    ----------
    outline : (nv, 2) array_like
        The fluid region, a simple polygon (either orientation; stored
        counter-clockwise), m. It must have at least one vertical edge on its
        leftmost x (the inlet) and one on its rightmost x (the outlet).
        Repeated and collinear vertices are dropped.
    obstacles : sequence of (k, 2) array_like
        Solid islands: simple polygons strictly inside the outline, not touching
        each other or the outline.
    constriction_x : float, optional
        Where the constriction is (a point). By default the narrowest vertical
        section is found: the open width ``width_at(x)`` is piecewise linear in x
        between the vertices' x coordinates, so its minimum lies at one of them;
        each is scored by the smaller of its one-sided widths (so the section at
        a sudden expansion counts as narrow). The most upstream minimum is taken,
        and extended downstream while the width stays at that minimum (a
        straight constriction).

    Returns
    -------
    Geometry
        Control volume: from the inlet to where the width first differs from the
        inlet width (the upstream straight section); when the width changes at
        once, from the inlet to the constriction.

    Raises
    ------
    ValueError
        A polygon is not simple, has fewer than 3 distinct vertices or no area, an
        obstacle is not strictly inside the outline or touches another, there is no
        inlet or outlet edge, or ``constriction_x`` is outside ``(x_min, x_max)``.

    Examples
    --------
    >>> g = from_polygon([[0, -1], [4, -1], [5, -0.25], [6, -1], [9, -1],
    ...                   [9, 1], [6, 1], [5, 0.25], [4, 1], [0, 1]])
    >>> g.constriction_x0, g.constriction_width, g.upstream_region
    (5.0, 0.5, (0.0, 4.0))
    """
    out = _clean_polygon(outline, "outline")
    obs = tuple(_clean_polygon(o, f"obstacle {k}") for k, o in enumerate(obstacles))
    constriction = None
    if constriction_x is not None:
        cx = float(constriction_x)
        lo, hi = out[:, 0].min(), out[:, 0].max()
        _require(lo < cx < hi, f"constriction_x = {cx:g} must lie inside the channel "
                               f"({lo:g}, {hi:g})")
        constriction = (cx, cx)
    return _build(out, obs, constriction=constriction, upstream=None)


# ----------------------------------------------------------------------------
# Queries
# ----------------------------------------------------------------------------

def wall_segments(geometry: Geometry, extend: float = 0.0) -> np.ndarray:
    """Every wall segment: outline edges not on the inlet or outlet, and obstacle edges.

    Parameters
    ----------
    geometry : Geometry
    extend : float
        If > 0, also return the straight continuations of the walls beyond the
        open ends (see the module notes), this long, m: what `wall_distance`
        uses, for analytic disk-wall contacts that must agree with it.

    Returns
    -------
    (S, 2, 2) ndarray
        ``segments[s] = [start, end]``.

    Examples
    --------
    >>> wall_segments(converging(4.0, 6.0, 1.0, 3.0)).shape
    (8, 2, 2)
    """
    w = geometry._walls
    segs = np.stack([w.wall_a, w.wall_b], axis=1)
    if extend > 0:
        rays = np.isinf(w.piece_len)
        ends = w.piece_a[rays] + float(extend) * w.piece_u[rays]
        segs = np.concatenate([segs, np.stack([w.piece_a[rays], ends], axis=1)])
    return segs


def wall_distance(geometry: Geometry, points) -> np.ndarray:
    """Signed distance from points to the walls, positive in the fluid.

    ``|phi|`` is the distance to the nearest wall segment (the inlet and outlet
    edges are not walls and do not count); ``phi > 0`` inside the outline and
    outside every obstacle, ``phi < 0`` elsewhere. Beyond the open ends the
    channel is continued straight (module notes), so ``phi`` is continuous across
    the inlet and outlet.

    Parameters
    ----------
    geometry : Geometry
    points : (M, 2) array_like

    Returns
    -------
    (M,) ndarray

    Examples
    --------
    >>> g = hourglass(10.0, 2.0, 0.5)
    >>> [round(float(v), 12) for v in wall_distance(g, [[0.0, 0.5], [10.5, 0.0], [1.0, 1.5]])]
    [0.5, 1.0, -0.5]
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    w = geometry._walls
    if w.index is None:
        dist = _distance_to_pieces(pts, w.piece_a, w.piece_u, w.piece_len)
        return np.where(_in_fluid(geometry, pts), dist, -dist)
    # the outline in full, the obstacles near each point only (nearest.py: the
    # same values as measuring every obstacle edge)
    dist = _distance_to_pieces(pts, *w.outline_pieces)
    d2, inside = w.index.query(pts, dist)
    dist = np.minimum(dist, np.sqrt(d2))
    return np.where(_in_fluid(geometry, pts, inside), dist, -dist)


def fluid_area(geometry: Geometry, x0: float, x1: float) -> float:
    """Exact area of the fluid region with ``x0 <= x <= x1``.

    The outline and each obstacle are clipped against the two half-planes
    (Sutherland-Hodgman; a concave polygon may come out with zero-width bridges,
    which add no area) and the obstacles' areas subtracted.

    Examples
    --------
    >>> g = converging(4.0, 6.0, 1.0, 3.0, angle=45.0)
    >>> round(fluid_area(g, 0.0, 6.0), 12), round(fluid_area(g, 6.0, 7.5), 12)
    (24.0, 3.75)
    """
    x0, x1 = float(x0), float(x1)
    _require(x0 <= x1, f"fluid_area: x0 = {x0:g} must be <= x1 = {x1:g}")
    area = clipped_area(geometry.outline, x0, x1)
    return area - sum(clipped_area(o, x0, x1) for o in geometry.obstacles)


def width_at(geometry: Geometry, x):
    """Total open width of the fluid region on the vertical line at x.

    Where the width jumps (a vertical wall, e.g. a sudden expansion) the smaller
    side is returned: the passage a particle has to get through there. 0 outside
    ``[x_min, x_max]``.

    Parameters
    ----------
    geometry : Geometry
    x : float or array_like

    Returns
    -------
    float, or ndarray shaped like x

    Examples
    --------
    >>> g = converging(4.0, 6.0, 1.0, 3.0, angle=45.0, width_out=3.0)
    >>> [round(float(v), 12) for v in width_at(g, [0.0, 7.0, 7.5, 9.0])]
    [4.0, 2.0, 1.0, 3.0]
    """
    xs = np.asarray(x, dtype=float)
    out = np.array([_width(geometry, float(v)) for v in xs.ravel()]).reshape(xs.shape)
    return float(out) if out.ndim == 0 else out


# ----------------------------------------------------------------------------
# Internals
# ----------------------------------------------------------------------------

def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _clean_polygon(points, what: str) -> np.ndarray:
    """Validate a user polygon; drop repeated and collinear vertices; orient CCW."""
    try:
        poly = np.array(points, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected a list of [x, y] pairs") from None
    _require(poly.ndim == 2 and poly.shape[1] == 2,
             f"{what}: expected a list of [x, y] pairs, got an array of shape {poly.shape}")
    _require(bool(np.all(np.isfinite(poly))), f"{what}: coordinates must be finite numbers")
    scale = max(float(np.ptp(poly, axis=0).max()) if len(poly) else 0.0, 1e-300)
    # Repeated vertices (including a closing copy of the first one) carry no edge.
    keep = np.linalg.norm(poly - np.roll(poly, 1, axis=0), axis=1) > _REL_TOL * scale
    poly = poly[keep]
    # Collinear vertices split one wall into pieces; a reversal is a zero-width spike.
    while len(poly) >= 3:
        e_in = poly - np.roll(poly, 1, axis=0)
        e_out = np.roll(poly, -1, axis=0) - poly
        lin = np.abs(cross(e_in, e_out)) <= _REL_TOL * np.linalg.norm(e_in, axis=1) \
            * np.linalg.norm(e_out, axis=1)
        back = lin & (np.sum(e_in * e_out, axis=1) < 0)
        if back.any():
            k = int(np.flatnonzero(back)[0])
            raise ValueError(f"{what}: the polygon doubles back on itself at vertex "
                             f"({poly[k, 0]:g}, {poly[k, 1]:g}) (a zero-width spike)")
        if not lin.any():
            break
        poly = np.delete(poly, int(np.flatnonzero(lin)[0]), axis=0)
    _require(len(poly) >= 3, f"{what}: needs at least 3 distinct, non-collinear vertices")
    area = signed_area(poly)
    _require(abs(area) > _REL_TOL * scale ** 2, f"{what}: the polygon has no area")
    if area < 0:
        poly = poly[::-1].copy()
    _check_simple(poly, what, tol=_REL_TOL * scale)
    return poly


def _edges(poly: np.ndarray):
    return poly, np.roll(poly, -1, axis=0)


def _check_simple(poly: np.ndarray, what: str, tol: float) -> None:
    pair = first_crossing(poly, tol)
    if pair is not None:
        p = poly[pair[0]]
        raise ValueError(f"{what}: edges {pair[0]} and {pair[1]} (from vertex ({p[0]:g}, "
                         f"{p[1]:g})) cross or touch; the polygon must be simple (no "
                         "self-intersections)")


def _distance_to_pieces(points, start, unit, length) -> np.ndarray:
    """Distance from each point to the nearest of the segments/rays start + [0, length] * unit."""
    out = np.empty(len(points))
    step = max(1, CHUNK_ELEMENTS // max(len(start), 1))
    for s in range(0, len(points), step):
        d = points[s:s + step, None, :] - start[None, :, :]
        t = np.clip(np.einsum("mpk,pk->mp", d, unit), 0.0, length)
        r = d - t[..., None] * unit
        out[s:s + step] = np.sqrt(np.min(np.einsum("mpk,mpk->mp", r, r), axis=1))
    return out


def _open_intervals(poly: np.ndarray, x_edge: float, tol: float) -> np.ndarray:
    """y intervals (lo, hi) of the polygon's edges lying on the vertical line x_edge."""
    a, b = _edges(poly)
    on = (np.abs(a[:, 0] - x_edge) <= tol) & (np.abs(b[:, 0] - x_edge) <= tol)
    ys = np.sort(np.stack([a[on, 1], b[on, 1]], axis=1), axis=1)
    return ys.reshape(-1, 2)


def _outline_tol(outline) -> float:
    """Length below which two coordinates of an outline count as equal."""
    return _REL_TOL * max(float(np.ptp(outline, axis=0).max()), 1e-300)


def open_edges(outline, x_min, x_max) -> tuple[np.ndarray, np.ndarray]:
    """Which edges of an outline (edge k from vertex k to k + 1) are the inlet
    (on ``x = x_min``) and which the outlet (on ``x = x_max``): two boolean masks."""
    outline = np.asarray(outline, dtype=float)
    tol = _outline_tol(outline)
    a, b = _edges(outline)

    def on(x):
        return (np.abs(a[:, 0] - x) <= tol) & (np.abs(b[:, 0] - x) <= tol)
    return on(x_min), on(x_max)


def _wall_data(outline, obstacles, x_min, x_max) -> _WallData:
    tol = _outline_tol(outline)
    a, b = _edges(outline)
    inlet_edge, outlet_edge = open_edges(outline, x_min, x_max)
    open_edge = inlet_edge | outlet_edge
    wall_a = [a[~open_edge]]
    wall_b = [b[~open_edge]]
    edge_a, edge_b = [a], [b]
    for o in obstacles:
        oa, ob = _edges(o)
        wall_a.append(oa)
        wall_b.append(ob)
        edge_a.append(oa)
        edge_b.append(ob)
    wall_a, wall_b = np.concatenate(wall_a), np.concatenate(wall_b)
    inlet = _open_intervals(outline, x_min, tol)
    outlet = _open_intervals(outline, x_max, tol)
    # Straight continuations of the walls beyond the open ends (module notes).
    ray_a = [np.array([[x_min, y] for y in inlet.ravel()]).reshape(-1, 2),
             np.array([[x_max, y] for y in outlet.ravel()]).reshape(-1, 2)]
    ray_u = [np.tile([-1.0, 0.0], (2 * len(inlet), 1)), np.tile([1.0, 0.0], (2 * len(outlet), 1))]
    seg = wall_b - wall_a
    seg_len = np.linalg.norm(seg, axis=1)
    piece_a = np.concatenate([wall_a] + ray_a)
    piece_u = np.concatenate([seg / seg_len[:, None]] + ray_u)
    piece_len = np.concatenate([seg_len, np.full(2 * (len(inlet) + len(outlet)), np.inf)])
    corners = np.concatenate([outline, *obstacles])
    n_wall = int((~open_edge).sum())
    rays = slice(len(wall_a), None)
    outline_pieces = tuple(np.ascontiguousarray(np.concatenate([x[:n_wall], x[rays]]))
                           for x in (piece_a, piece_u, piece_len))
    data = _WallData(wall_a, wall_b, piece_a, piece_u, piece_len, np.concatenate(edge_a),
                     np.concatenate(edge_b), inlet, outlet, corners, outline_pieces,
                     ObstacleIndex(obstacles) if len(obstacles) else None)
    for arr in (*data[:10], *outline_pieces):
        arr.setflags(write=False)
    return data


def _in_fluid(geometry: Geometry, pts: np.ndarray, in_obstacle=None) -> np.ndarray:
    """Inside the fluid region; ``in_obstacle`` (per point), when given, says which
    points lie inside an obstacle, so that only the outline's edges are crossed."""
    w = geometry._walls
    x, y = pts[:, 0], pts[:, 1]
    res = np.zeros(len(pts), dtype=bool)
    for mask, spans in ((x <= geometry.x_min, w.inlet), (x >= geometry.x_max, w.outlet)):
        ym = y[mask, None]
        res[mask] = np.any((ym > spans[:, 0]) & (ym < spans[:, 1]), axis=1)
    mid = (x > geometry.x_min) & (x < geometry.x_max)
    # Even-odd over outline and obstacle edges together: inside the outline and
    # outside every (disjoint, strictly interior) obstacle.
    if in_obstacle is None:
        res[mid] = crossings(pts[mid], w.edge_a, w.edge_b) % 2 == 1
    else:
        # obstacles lie disjoint and strictly inside: an outside one adds an even count
        n = len(geometry.outline)
        odd = crossings(pts[mid], w.edge_a[:n], w.edge_b[:n]) % 2 == 1
        res[mid] = odd ^ in_obstacle[mid]
    return res


def _section(geometry: Geometry, x: float, side: int) -> float:
    """Open length on the line at x, taken just right (side=+1) or left (-1) of it.

    Between two vertex abscissae the edges met by the line do not change and do
    not cross, so sorting their heights and pairing them (even-odd) gives the
    open intervals; at x itself the one-sided set of edges is used.
    """
    w = geometry._walls
    a, b = w.edge_a, w.edge_b
    lo, hi = np.minimum(a[:, 0], b[:, 0]), np.maximum(a[:, 0], b[:, 0])
    span = (lo <= x) & (x < hi) if side > 0 else (lo < x) & (x <= hi)
    a, b = a[span], b[span]
    y = np.sort(a[:, 1] + (x - a[:, 0]) / (b[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1]))
    return float(np.sum(y[1::2] - y[0::2]))


def _width(geometry: Geometry, x: float) -> float:
    if x < geometry.x_min or x > geometry.x_max:
        return 0.0
    if x == geometry.x_min:
        return _section(geometry, x, +1)
    if x == geometry.x_max:
        return _section(geometry, x, -1)
    return min(_section(geometry, x, -1), _section(geometry, x, +1))


def _check_obstacles(outline: np.ndarray, obstacles: tuple, tol: float) -> None:
    oa, ob = _edges(outline)
    # two obstacles whose boxes (widened by tol) are apart can neither meet nor
    # nest: only the others are tested, so the check grows with the obstacles,
    # not with their square
    lo = np.array([o.min(axis=0) for o in obstacles]).reshape(-1, 2) - tol
    hi = np.array([o.max(axis=0) for o in obstacles]).reshape(-1, 2) + tol
    for k, obs in enumerate(obstacles):
        ka, kb = _edges(obs)
        inside = points_in_polygon(obs, outline)
        touch = segments_intersect(ka[:, None], kb[:, None], oa[None], ob[None], tol).any()
        _require(bool(inside.all()) and not touch,
                 f"obstacle {k}: must lie strictly inside the outline (not crossing or "
                 f"touching it)")
        near = np.flatnonzero(np.all((lo[:k] <= hi[k]) & (hi[:k] >= lo[k]), axis=1))
        for m in near:
            other = obstacles[m]
            ma, mb = _edges(other)
            meet = segments_intersect(ka[:, None], kb[:, None], ma[None], mb[None], tol).any()
            nested = points_in_polygon(obs[:1], other)[0] or points_in_polygon(other[:1], obs)[0]
            _require(not (meet or nested), f"obstacles {m} and {k} overlap or touch")


def _narrowest(geometry: Geometry, xs: np.ndarray, tol: float):
    """(x0, x1, width) of the most upstream narrowest section (see from_polygon)."""
    widths = np.array([_width(geometry, x) for x in xs])
    w_min = widths.min()
    first = k = int(np.flatnonzero(widths <= w_min + tol)[0])
    while k + 1 < len(xs) and abs(_section(geometry, xs[k], +1) - w_min) <= tol \
            and abs(_section(geometry, xs[k + 1], -1) - w_min) <= tol:
        k += 1
    return float(xs[first]), float(xs[k]), float(w_min)


def _upstream(geometry: Geometry, xs: np.ndarray, tol: float, constriction_x0: float):
    """The inlet-width straight section, or inlet-to-constriction (see from_polygon)."""
    w_in = _section(geometry, geometry.x_min, +1)
    end = geometry.x_min
    for k in range(len(xs) - 1):
        if abs(_section(geometry, xs[k], +1) - w_in) > tol or \
                abs(_section(geometry, xs[k + 1], -1) - w_in) > tol:
            break
        end = xs[k + 1]
    if end <= geometry.x_min:
        end = constriction_x0 if constriction_x0 > geometry.x_min else geometry.x_max
    return (float(geometry.x_min), float(end))


def _build(outline, obstacles, constriction, upstream) -> Geometry:
    outline = _clean_polygon(outline, "outline")
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    scale = float((hi - lo).max())
    tol = _REL_TOL * scale
    _check_obstacles(outline, obstacles, tol)
    for name, x_edge in (("inlet", lo[0]), ("outlet", hi[0])):
        _require(len(_open_intervals(outline, x_edge, tol)) > 0,
                 f"outline: no edge lies on x = {x_edge:g}; the {name} must be a vertical "
                 f"edge at the {'leftmost' if name == 'inlet' else 'rightmost'} x of the outline")
    for arr in (outline, *obstacles):
        arr.setflags(write=False)
    # A provisional geometry gives the width queries their edge arrays; the
    # constriction and control volume then follow from it.
    geo = Geometry(outline, tuple(obstacles), float(lo[0]), float(hi[0]), float(lo[1]),
                   float(hi[1]), 0.0, 0.0, 0.0, (0.0, 0.0))
    xs = np.unique(np.concatenate([p[:, 0] for p in (outline, *obstacles)]))
    w_tol = _REL_TOL * scale
    if constriction is None:
        cx0, cx1, cw = _narrowest(geo, xs, w_tol)
    else:
        cx0, cx1 = float(constriction[0]), float(constriction[1])
        cw = _width(geo, cx0)
    if upstream is None:
        upstream = _upstream(geo, xs, w_tol, cx0)
    return Geometry(outline, tuple(obstacles), geo.x_min, geo.x_max, geo.y_min, geo.y_max,
                    cx0, cx1, float(cw), (float(upstream[0]), float(upstream[1])))
