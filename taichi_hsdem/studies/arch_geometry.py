"""The geometry of an arch: gaps between outlines and walls, how two touch, the chain
that spans the neck.

The definitions (touching, face-to-face, vertex and curved contacts, the arch as
the shortest touching chain from wall to wall) are in :mod:`.arches`, which
reads folders and writes the census; this module works on one configuration.
"""
from __future__ import annotations

import heapq
import math

import numpy as np

from ..geometry.distance import signed_distance
from ..geometry.polygon import is_convex, point_segment_distance
from ..geometry.shapes import to_body, transform
from ..geometry.walls import open_edges, wall_distance

DEFAULT_TOL = 0.01       # touching: gap <= tol * d_b
DEFAULT_ANGLE = 10.0     # face-to-face: normals opposed within this many degrees
FACE_OVERLAP = 0.25      # ... over at least this fraction of the shorter edge


class ArchError(Exception):
    """A folder or scene the arch analysis cannot read, in the user's terms."""


# ----------------------------------------------------------------------------
# Geometry of one configuration
# ----------------------------------------------------------------------------

def world_outline(shape, x, theta):
    """A polygon's vertices in the world (counter-clockwise); None for a circle."""
    if shape.kind == "circle":
        return None
    return transform(shape.vertices, x, theta)


def _separation(va, vb) -> float:
    """Largest separation of two convex CCW polygons along their edge normals:
    minus the penetration depth when they overlap (the separating-axis test)."""
    best = -math.inf
    for v, w in ((va, vb), (vb, va)):
        _, _, n, _ = _edges(v)
        # along each edge's outward normal: how far the other's nearest vertex lies past it
        past = np.einsum("ijk,ik->ij", w[None, :, :] - v[:, None, :], n).min(axis=1)
        best = max(best, float(past.max()))
    return best


def pair_gap(shape_a, xa, ta, shape_b, xb, tb) -> float:
    """Gap between two outlines: their distance when apart; when they overlap,
    minus the penetration depth for two convex polygons (the separating-axis
    test), else minus the deepest vertex's depth (for circles, the overlap)."""
    xa, xb = np.asarray(xa, float), np.asarray(xb, float)
    if shape_a.kind == "circle" and shape_b.kind == "circle":
        return float(np.hypot(*(xa - xb)) - shape_a.radius - shape_b.radius)
    if shape_a.kind == "circle":
        shape_a, xa, ta, shape_b, xb, tb = shape_b, xb, tb, shape_a, xa, ta
    if shape_b.kind == "circle":
        return float(signed_distance(shape_a, to_body(xb[None], xa, ta))[0] - shape_b.radius)
    va = world_outline(shape_a, xa, ta)
    vb = world_outline(shape_b, xb, tb)
    if is_convex(shape_a.vertices) and is_convex(shape_b.vertices):
        # overlapping convex outlines may hold no vertex of each other (a cross)
        sep = _separation(va, vb)
        if sep <= 0:
            return sep
    return float(min(signed_distance(shape_b, to_body(va, xb, tb)).min(),
                     signed_distance(shape_a, to_body(vb, xa, ta)).min()))


class Sides:
    """The two side walls of a channel along x, as segments with their normals
    into the fluid: the lower wall is the outline's run (counter-clockwise) from
    the inlet to the outlet, the upper one the run back."""

    def __init__(self, geometry):
        if geometry.obstacles:
            raise ArchError("the arch analysis needs a channel with two side walls and "
                            "no obstacles")
        v = np.asarray(geometry.outline, float)
        w = np.roll(v, -1, axis=0)
        inlet, outlet = open_edges(v, geometry.x_min, geometry.x_max)
        if not inlet.any() or not outlet.any():
            raise ArchError("the arch analysis needs a channel with an open inlet and outlet")
        # walk counter-clockwise from the last inlet edge: lower wall until the
        # outlet, upper wall after it
        start = int(np.flatnonzero(inlet)[-1])
        runs, side = ([], []), 0
        for k in ((start + 1 + np.arange(len(v))) % len(v)):
            if inlet[k]:
                continue
            if outlet[k]:
                side = 1
                continue
            runs[side].append([v[k], w[k]])
        if not runs[0] or not runs[1]:
            raise ArchError("the arch analysis needs a channel with two side walls")
        self.geometry = geometry
        self.segments = [np.array(r, float).reshape(-1, 2, 2) for r in runs]
        self.normals = []
        for s in self.segments:
            t = s[:, 1] - s[:, 0]
            # fluid on the left of a counter-clockwise outline
            self.normals.append(np.stack([-t[:, 1], t[:, 0]], axis=1)
                                / np.hypot(t[:, 0], t[:, 1])[:, None])

    def _point_gaps(self, pts) -> np.ndarray:
        """Signed distances of points to the lower and the upper side, (2, M)
        (negative inside that wall)."""
        pts = np.asarray(pts, float).reshape(-1, 2)
        d = np.array([point_segment_distance(pts[:, None, :], s[None, :, 0],
                                             s[None, :, 1]).min(axis=1)
                      for s in self.segments])
        inside = wall_distance(self.geometry, pts) < 0
        return np.where(inside & np.array([d[0] <= d[1], d[1] <= d[0]]), -d, d)

    def gap(self, shape, x, theta, k) -> float:
        """Gap between a particle and side wall ``k`` (0 lower, 1 upper)."""
        return float(self.gaps([shape], [x], [theta])[k, 0])

    def gaps(self, shapes, x, theta) -> np.ndarray:
        """Gaps between particles (``shapes[i]`` at ``x[i]``, ``theta[i]``) and the
        lower and the upper side wall, (2, M): the disks' at once, from their
        centres' distances."""
        x = np.asarray(x, float).reshape(-1, 2)
        out = np.empty((2, len(x)))
        disk = np.array([s.kind == "circle" for s in shapes], dtype=bool)
        if disk.any():
            radius = np.array([s.radius for s, d in zip(shapes, disk) if d])
            out[:, disk] = self._point_gaps(x[disk]) - radius
        for i in np.flatnonzero(~disk):
            v = world_outline(shapes[i], x[i], theta[i])
            out[:, i] = self._point_gaps(v).min(axis=1)
            for k in (0, 1):
                corners = self.segments[k].reshape(-1, 2)
                out[k, i] = min(out[k, i], signed_distance(shapes[i], to_body(
                    corners, x[i], theta[i])).min())
        return out

    def nearest(self, points, k) -> np.ndarray:
        """The points of side wall ``k`` nearest to ``points`` (M, 2)."""
        p = np.asarray(points, float).reshape(-1, 1, 2)
        a, b = self.segments[k][None, :, 0], self.segments[k][None, :, 1]
        ab = b - a
        t = np.clip(np.sum((p - a) * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0.0, 1.0)
        foot = a + t[..., None] * ab
        best = np.argmin(np.hypot(*np.moveaxis(foot - p, -1, 0)), axis=1)
        return foot[np.arange(len(p)), best]


def _edges(v):
    """(start, end, outward unit normal, length) of a CCW polygon's edges."""
    a, b = v, np.roll(v, -1, axis=0)
    t = b - a
    length = np.hypot(t[:, 0], t[:, 1])
    return a, b, np.stack([t[:, 1], -t[:, 0]], axis=1) / length[:, None], length


def _lies_along(p0, p1, length, n, q0, q1, other_length, tol) -> bool:
    """Does edge q0-q1 lie along edge p0-p1 (outward normal n)? Over their common
    stretch along p's line, at least FACE_OVERLAP of the shorter edge, q stays
    within ``tol`` outside p's line, or inside it (pressed in) by at most
    FACE_OVERLAP of the shorter edge."""
    t = (p1 - p0) / length
    s0, s1 = float((q0 - p0) @ t), float((q1 - p0) @ t)
    lo, hi = max(min(s0, s1), 0.0), min(max(s0, s1), length)
    shorter = min(length, other_length)
    if s0 == s1 or hi - lo < FACE_OVERLAP * shorter:
        return False
    for s in (lo, hi):      # q at the ends of the common stretch, off p's line
        off = float((q0 + (s - s0) / (s1 - s0) * (q1 - q0) - p0) @ n)
        if not (-FACE_OVERLAP * shorter <= off <= tol):
            return False
    return True


def _faces_touch(a, b, n_a, n_b, tol, angle) -> bool:
    """Do edge sets ``a`` (starts, ends, lengths; outward normals ``n_a``) and
    ``b`` hold an opposed pair lying along each other (normals opposed within
    ``angle`` degrees; `_lies_along` seen from either edge)?"""
    (a0, a1, len_a), (b0, b1, len_b) = a, b
    cos = math.cos(math.radians(angle))
    for i in range(len(a0)):
        for j in range(len(b0)):
            if float(n_a[i] @ n_b[j]) > -cos:
                continue
            if (_lies_along(a0[i], a1[i], len_a[i], n_a[i], b0[j], b1[j], len_b[j], tol)
                    or _lies_along(b0[j], b1[j], len_b[j], n_b[j], a0[i], a1[i], len_a[i], tol)):
                return True
    return False


def pair_kind(shape_a, xa, ta, shape_b, xb, tb, tol, angle=DEFAULT_ANGLE) -> str:
    """``"face"``, ``"vertex"`` or (a circle in it) ``"curved"`` for a touching pair."""
    if shape_a.kind == "circle" or shape_b.kind == "circle":
        return "curved"
    a0, a1, na, la = _edges(world_outline(shape_a, xa, ta))
    b0, b1, nb, lb = _edges(world_outline(shape_b, xb, tb))
    return "face" if _faces_touch((a0, a1, la), (b0, b1, lb), na, nb, tol, angle) else "vertex"


def wall_kind(sides, k, shape, x, theta, tol, angle=DEFAULT_ANGLE) -> str:
    """The same for a particle on side wall ``k``: a face flat on the wall or not."""
    if shape.kind == "circle":
        return "curved"
    a0, a1, na, la = _edges(world_outline(shape, x, theta))
    s = sides.segments[k]
    ls = np.hypot(*(s[:, 1] - s[:, 0]).T)
    # the wall, seen as a body, faces the fluid: its normal opposes the particle's face
    return ("face" if _faces_touch((a0, a1, la), (s[:, 0], s[:, 1], ls), na,
                                   sides.normals[k], tol, angle) else "vertex")


# ----------------------------------------------------------------------------
# The arch of one final state
# ----------------------------------------------------------------------------

def arch_chain(shapes, x, theta, alive, species, sides, neck_x, d_b, tol=DEFAULT_TOL,
               x_range=None):
    """The particles of the arch of one configuration, from the lower side wall up,
    or None when no chain of touching particles joins the two side walls.

    The arch is the shortest chain (fewest particles; ties: the chain nearest
    ``neck_x``) of particles each touching the next (gap at most ``tol d_b``,
    :func:`pair_gap`), the first touching the lower side wall and the last the
    upper one (:meth:`Sides.gaps`). Two disks' gap is their centres' distance
    less their radii, all at once. ``x_range``: only the alive particles whose
    centre x lies in ``(lo, hi)`` take part (None: every alive one).
    """
    x = np.asarray(x, float)
    theta = np.asarray(theta, float)
    take = np.asarray(alive, bool).copy()
    if x_range is not None:
        take &= (x[:, 0] > x_range[0]) & (x[:, 0] < x_range[1])
    live = np.flatnonzero(take)
    if not live.size:
        return None
    gap_d = tol * d_b
    reach = 2.0 * d_b          # two centres further apart than two bounding diameters cannot touch
    xl, tl = x[live], theta[live]
    sh = [shapes[int(species[i])] for i in live]
    on_wall = [np.flatnonzero(g <= gap_d) for g in sides.gaps(sh, xl, tl)]
    if not on_wall[0].size or not on_wall[1].size:
        return None
    disk = np.array([s.kind == "circle" for s in sh], dtype=bool)
    radius = np.array([s.radius if d else np.nan for s, d in zip(sh, disk)])
    # Dijkstra over the particles (indices into live): one per particle, a little
    # for distance from the neck
    weight = 1.0 + 1e-3 * np.abs(xl[:, 0] - neck_x) / d_b
    neigh = {}

    def neighbours(a):
        if a not in neigh:
            sep = np.hypot(*(xl - xl[a]).T)
            near = np.flatnonzero(sep < reach)
            near = near[near != a]
            both = disk[near] & disk[a]
            gap = np.where(both, sep[near] - radius[near] - radius[a], np.nan)
            for k in np.flatnonzero(~both):
                b = near[k]
                gap[k] = pair_gap(sh[a], xl[a], tl[a], sh[b], xl[b], tl[b])
            neigh[a] = near[gap <= gap_d].tolist()
        return neigh[a]

    dist = {int(a): weight[a] for a in on_wall[0]}
    prev = {a: None for a in dist}
    heap = [(d, a) for a, d in dist.items()]
    heapq.heapify(heap)
    top = set(on_wall[1].tolist())
    end = None
    while heap:
        d, a = heapq.heappop(heap)
        if d > dist[a]:
            continue
        if a in top:
            end = a
            break
        for b in neighbours(a):
            nd = d + weight[b]
            if nd < dist.get(b, math.inf):
                dist[b], prev[b] = nd, a
                heapq.heappush(heap, (nd, b))
    if end is None:
        return None
    chain = [end]
    while prev[chain[-1]] is not None:
        chain.append(prev[chain[-1]])
    return [int(live[a]) for a in reversed(chain)]


def find_arch(shapes, x, theta, alive, species, sides, neck_x, d_b, tol=DEFAULT_TOL,
              angle=DEFAULT_ANGLE):
    """The arch of one configuration (:func:`arch_chain`, every alive particle), or
    None when no chain of touching particles joins the two side walls.

    Returns ``{"particles": [i, ...] from the lower wall up, "pairs": [kind of
    each neighbouring pair], "walls": [kind on the lower wall, on the upper]}``.
    """
    chain = arch_chain(shapes, x, theta, alive, species, sides, neck_x, d_b, tol)
    if chain is None:
        return None
    x = np.asarray(x, float)
    theta = np.asarray(theta, float)
    gap_d = tol * d_b
    sh = {i: shapes[int(species[i])] for i in chain}
    pairs = [pair_kind(sh[i], x[i], theta[i], sh[j], x[j], theta[j], gap_d, angle)
             for i, j in zip(chain, chain[1:])]
    walls = [wall_kind(sides, 0, sh[chain[0]], x[chain[0]], theta[chain[0]], gap_d, angle),
             wall_kind(sides, 1, sh[chain[-1]], x[chain[-1]], theta[chain[-1]], gap_d, angle)]
    return {"particles": chain, "pairs": pairs, "walls": walls}
