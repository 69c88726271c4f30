"""The obstacles near each point: what makes the wall distance of a geometry with
many obstacles (a micromodel's pillars) cost what its points cost, not points x
edges.

For a point ``p``, ``V`` is the distance to the nearest obstacle vertex (a
k-d tree over them) and ``U = min(V, u)`` with ``u`` any known upper bound of the
distance to the walls (the outline's, computed in full by the caller). The
nearest obstacle edge of ``p`` lies within ``U`` when any does, and an obstacle
``k`` whose every vertex lies within ``R_k`` of its vertex mean ``c_k`` has all of
its boundary there too, so only the obstacles with ``|p - c_k| - R_k <= U`` can
hold the nearest edge or contain ``p`` (a point inside an obstacle is within its
``R_k`` of ``c_k``). Their edges are measured exactly, with the operations the
brute-force distance uses, so the result is the brute force's, bit for bit
(``tests/test_micromodel.py``). Two further exact shortcuts: a point whose ``u``
is at most ``V - L / 2`` (``L`` the longest obstacle edge: the nearest point of an
edge is within ``L / 2`` of one of its ends) and whose ``V`` exceeds twice the
largest ``R_k`` (it cannot be inside one) needs no obstacle at all.

Each obstacle's edges are padded to the longest obstacle's count with edges of no
length at one of its vertices: no crossing (they never straddle a height) and a
distance to a vertex of the boundary, so neither result changes.

>>> import numpy as np
>>> square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
>>> index = ObstacleIndex([square, square + [3.0, 0.0]])
>>> d2, inside = index.query(np.array([[2.0, 0.5], [0.5, 0.5]]), np.array([9.0, 9.0]))
>>> np.sqrt(d2).tolist(), inside.tolist()
([1.0, 0.5], [False, True])
"""
from __future__ import annotations

import numpy as np

from .polygon import CHUNK_ELEMENTS

#: Obstacle candidates asked of the k-d tree per point at first (doubled for the
#: points that have more).
FIRST_NEIGHBOURS = 8


class ObstacleIndex:
    """The obstacles of a geometry, for :meth:`query`."""

    def __init__(self, obstacles):
        from scipy.spatial import cKDTree
        polys = [np.asarray(o, dtype=float) for o in obstacles]
        self.count = len(polys)
        # obstacles in classes of edge counts padded to the next power of two, so
        # that a point near a small obstacle never pays for the largest one's edges
        sizes = np.array([len(p) for p in polys])
        width = 1 << np.ceil(np.log2(sizes)).astype(np.int64)
        self.cls = np.searchsorted(np.unique(width), width)
        self.row = np.zeros(self.count, dtype=np.int64)
        self.classes = []
        longest = 0.0
        for c, E in enumerate(np.unique(width)):
            members = np.flatnonzero(width == E)
            self.row[members] = np.arange(len(members))
            K = len(members)
            a, b, u = np.zeros((K, E, 2)), np.zeros((K, E, 2)), np.zeros((K, E, 2))
            length = np.zeros((K, E))
            for j, k in enumerate(members):
                p = polys[k]
                n = len(p)
                q = np.roll(p, -1, axis=0)
                seg = q - p
                seg_len = np.linalg.norm(seg, axis=1)
                a[j, :n], b[j, :n] = p, q
                u[j, :n] = seg / seg_len[:, None]
                length[j, :n] = seg_len
                a[j, n:] = b[j, n:] = p[0]          # no length, no crossing
            longest = max(longest, float(length.max()))
            self.classes.append((a, b, u, length))
        self.longest = longest
        self.centres = np.array([p.mean(axis=0) for p in polys])
        self.radii = np.array([np.hypot(*(p - c).T).max() for p, c in zip(polys, self.centres)])
        self._centre_tree = cKDTree(self.centres)
        self._vertex_tree = cKDTree(np.concatenate(polys))

    def query(self, points, bound) -> tuple[np.ndarray, np.ndarray]:
        """``(d2, inside)`` for ``points`` (M, 2): ``d2`` the squared distance to
        the nearest obstacle edge where it may be below ``bound`` (M,) (an upper
        bound of the distance to the walls), else inf; ``inside`` whether the point
        lies inside an obstacle (even-odd, the half-open test of
        :func:`~taichi_hsdem.geometry.polygon.crossings`)."""
        M = len(points)
        d2 = np.full(M, np.inf)
        inside = np.zeros(M, dtype=bool)
        if not M:
            return d2, inside
        v, _ = self._vertex_tree.query(points)
        r_max = float(self.radii.max())
        slack = 1e-9 * (v + self.longest)
        need = ~((bound <= v - 0.5 * self.longest - slack) & (v > 2.0 * r_max + slack))
        idx = np.flatnonzero(need)
        if not idx.size:
            return d2, inside
        reach = np.minimum(v[idx], bound[idx])
        pt, ob = self._candidates(points[idx], reach)
        if not pt.size:
            return d2, inside
        near = np.empty(len(pt))
        odd = np.empty(len(pt), dtype=np.int64)
        p_all = points[idx]
        for c, arrays in enumerate(self.classes):
            pairs = np.flatnonzero(self.cls[ob] == c)
            step = max(1, CHUNK_ELEMENTS // 32 // arrays[0].shape[1])     # in cache
            for s in range(0, len(pairs), step):
                at = pairs[s:s + step]
                near[at], odd[at] = _measure(p_all[pt[at]], self.row[ob[at]], *arrays)
        # the pairs come sorted by point: one reduction per point
        first = np.flatnonzero(np.r_[True, pt[1:] != pt[:-1]])
        best = np.full(idx.size, np.inf)
        best[pt[first]] = np.minimum.reduceat(near, first)
        parity = np.zeros(idx.size, dtype=np.int64)
        parity[pt[first]] = np.add.reduceat(odd, first)
        d2[idx] = best
        inside[idx] = parity % 2 == 1
        return d2, inside

    def _candidates(self, points, reach) -> tuple[np.ndarray, np.ndarray]:
        """(point, obstacle) pairs with ``|p - c_k| - R_k <= reach`` (per point)."""
        r_max = float(self.radii.max())
        # the tree takes one bound per query: the points go in bins of reach within
        # a factor 2 of each other, each asked with its bin's largest, then filtered
        scale = max(float(reach.max()), r_max) * 2.0 ** -60
        bins = np.ceil(np.log2(np.maximum(reach, scale) / scale)).astype(np.int64)
        pts, obs = [], []
        for b in np.unique(bins):
            todo = np.flatnonzero(bins == b)
            bound = float(reach[todo].max()) + r_max
            k = min(FIRST_NEIGHBOURS, self.count)
            while todo.size:
                dist, nb = self._centre_tree.query(points[todo], k=k,
                                                   distance_upper_bound=bound * (1 + 1e-12))
                dist, nb = dist.reshape(len(todo), k), nb.reshape(len(todo), k)
                full = np.isfinite(dist[:, -1]) & (k < self.count)
                rows, cols = np.nonzero(np.isfinite(dist) & ~full[:, None])
                cand = nb[rows, cols]
                # a little slack: an extra candidate changes nothing, a missed one would
                keep = (dist[rows, cols] - self.radii[cand]
                        <= reach[todo][rows] * (1 + 1e-9) + 1e-12 * r_max)
                pts.append(todo[rows[keep]])
                obs.append(cand[keep])
                todo = todo[full]
                k = min(2 * k, self.count)
        pt, ob = np.concatenate(pts), np.concatenate(obs)
        order = np.argsort(pt, kind="stable")
        return pt[order], ob[order]


def _measure(points, rows, a, b, u, length):
    """Squared distance from each point to the nearest edge of its obstacle
    (``rows`` in the class arrays), and the parity of the edges its +x ray
    crosses: the brute force's operations (walls._distance_to_pieces,
    polygon.crossings), so its bits."""
    p = points[:, None, :]
    d = p - a[rows]
    unit = u[rows]
    t = np.clip(np.einsum("mpk,mpk->mp", d, unit), 0.0, length[rows])
    r = d - t[..., None] * unit
    near = np.min(np.einsum("mpk,mpk->mp", r, r), axis=1)
    a, b = a[rows], b[rows]
    py, px = p[..., 1], p[..., 0]
    dy = b[..., 1] - a[..., 1]
    safe_dy = np.where(dy == 0, 1.0, dy)
    straddle = (a[..., 1] > py) != (b[..., 1] > py)
    x_cross = a[..., 0] + (py - a[..., 1]) * (b[..., 0] - a[..., 0]) / safe_dy
    return near, np.count_nonzero(straddle & (px < x_cross), axis=1) % 2
