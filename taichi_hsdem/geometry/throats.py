"""Throats: the constrictions between neighbouring solids of a geometry.

The solids are the obstacles (pillars) and the wall chains of the outline (its
edges that are not on the inlet or the outlet, joined end to end: the bottom and
the top wall of a straight channel). Neighbours are the edges of the Delaunay
triangulation of the obstacles' centroids and of the point of each wall chain
nearest to each centroid. The throat between two neighbours is the shortest
segment between them; it is kept when it is a constriction, i.e. when no third
solid comes within ``(1 + GABRIEL_SLACK)`` times half its width of its midpoint
(the disk on the segment is empty: Gabriel's test). The slack drops the diagonals
of a square lattice, which cross the centre of a pore that four pillars keep at
the same distance, whatever the polygon that stands for each circle.

The pores are the Delaunay triangles of the same points, joined across every
edge between two solids that is no throat (two neighbours with a third in
between: one pore around them), and the inlet and the outlet are what lies
beyond the triangulation's hull edges facing -x and +x; an edge between two
points of one wall chain is wall. Each throat joins the pores on either side of
the Delaunay edges of its pair of solids (:attr:`Throats.links`): crossing the
gap between two solids is crossing one of them. With a set of throats clogged
the inlet is cut off from the outlet (:meth:`Throats.blocked`) when every path of
pores between them crosses a clogged throat.

A geometry without obstacles has no throats here (its single constriction is
``Geometry.constriction_x0``).

>>> from taichi_hsdem.geometry.micromodel import pillar_array
>>> m = pillar_array("square", rows=3, columns=4, diameter=1.0, spacing=2.0,
...                  inlet_length=2.0, outlet_length=2.0)
>>> t = find_throats(m.outline, m.obstacles)
>>> len(t), round(float(t.widths.min()), 2)
(25, 1.0)

The first column's four gaps clogged cut the inlet off; three of them do not:

>>> first = np.flatnonzero(np.isclose(t.midpoints[:, 0], 3.0))
>>> clogged = np.isin(np.arange(len(t)), first)
>>> len(first), t.blocked(clogged), t.blocked(clogged & (np.arange(len(t)) != first[0]))
(4, True, False)
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .polygon import point_segment_distance, segments_intersect
from .walls import open_edges

#: How much nearer than half the throat's width a third solid may come to the
#: throat's midpoint before the throat is a pore centre, not a constriction.
GABRIEL_SLACK = 0.05


@dataclass(frozen=True)
class Throats:
    """``start`` (T, 2) and ``end`` (T, 2): each throat's shortest segment, from
    solid ``solids[k, 0]`` to ``solids[k, 1]`` (obstacle indices, then the wall
    chains numbered from the obstacle count), sorted by midpoint x then y, m."""
    start: np.ndarray
    end: np.ndarray
    solids: np.ndarray
    #: the pore network (module notes): ``links`` (L, 2) join two pores (0 the
    #: inlet, 1 the outlet, ``n_pores`` in all) across throat ``link_throat`` (L,)
    #: (a throat's gap may span several Delaunay edges, each a link)
    links: np.ndarray = None
    link_throat: np.ndarray = None
    n_pores: int = 2

    @property
    def midpoints(self) -> np.ndarray:
        return 0.5 * (self.start + self.end)

    @property
    def widths(self) -> np.ndarray:
        return np.hypot(*(self.end - self.start).T)

    def __len__(self) -> int:
        return len(self.start)

    @property
    def network(self) -> bool:
        """Whether these throats make a network (two or more): the whole-run clog
        is then the inlet cut off from the outlet, and the network outputs are
        written; one throat is the single-constriction scene."""
        return len(self.start) >= 2

    @cached_property
    def _tree(self):
        from scipy.spatial import cKDTree
        return cKDTree(self.midpoints)

    def blocked(self, clogged) -> bool:
        """Whether the throats ``clogged`` (T,) bool cut the inlet off from the
        outlet: every path of pores between them crosses a clogged throat."""
        from scipy.sparse import coo_array
        from scipy.sparse.csgraph import connected_components
        if self.links is None or not len(self):
            return False
        open_ = ~np.asarray(clogged, dtype=bool)[self.link_throat]
        a, b = self.links[open_, 0], self.links[open_, 1]
        graph = coo_array((np.ones(len(a)), (a, b)), shape=(self.n_pores, self.n_pores))
        _, label = connected_components(graph, directed=False)
        return bool(label[0] != label[1])

    def blocked_since(self, t_clog) -> float:
        """The earliest time at which the throats clogged by then (``t_clog`` (T,),
        NaN: open) cut the inlet off from the outlet; NaN when they do not now."""
        t_clog = np.asarray(t_clog, dtype=float)
        clogged = np.isfinite(t_clog)
        if not clogged.any() or not self.blocked(clogged):
            return float("nan")
        times = np.unique(t_clog[clogged])
        lo, hi = 0, len(times) - 1          # blocked at times[hi]; find the first
        while lo < hi:
            mid = (lo + hi) // 2
            if self.blocked(clogged & (t_clog <= times[mid])):
                hi = mid
            else:
                lo = mid + 1
        return float(times[lo])

    def near(self, points, radius) -> tuple[np.ndarray, np.ndarray]:
        """(point index, throat index) of every throat whose segment may come
        within ``radius`` (per point) of ``points``: its midpoint does."""
        if not len(points) or not len(self):
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        points = np.asarray(points, dtype=float)
        reach = np.broadcast_to(np.asarray(radius, dtype=float) + self.widths.max() / 2,
                                (len(points),))
        # only points within reach of the midpoints' box can find one (most of a
        # long inlet's particles cannot): the tree is asked about those alone; the
        # box is widened a little, so that no pair the tree would find is lost
        lo, hi = self._box
        slack = 1e-9 * (np.abs(points).max(axis=1) + reach) + reach
        ask = np.flatnonzero(np.all((points >= lo - slack[:, None])
                                    & (points <= hi + slack[:, None]), axis=1))
        if not len(ask):
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        lists = self._tree.query_ball_point(points[ask], reach[ask])
        counts = np.fromiter(map(len, lists), dtype=int, count=len(lists))
        throat = np.fromiter(itertools.chain.from_iterable(lists), dtype=int,
                             count=int(counts.sum()))
        return np.repeat(ask, counts), throat

    @cached_property
    def _box(self):
        """The lower left and upper right corners of the throats' midpoints."""
        return self.midpoints.min(axis=0), self.midpoints.max(axis=0)


def throats_of(geometry) -> Throats:
    """The throats of a :class:`~taichi_hsdem.geometry.walls.Geometry`."""
    return find_throats(geometry.outline, geometry.obstacles)


def find_throats(outline, obstacles) -> Throats:
    """The throats between ``obstacles`` (polygons) and the walls of ``outline``
    (module notes)."""
    outline = np.asarray(outline, dtype=float)
    polys = [np.asarray(o, dtype=float) for o in obstacles]
    if not polys:
        return Throats(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), dtype=int))
    solids = [(p, np.roll(p, -1, axis=0)) for p in polys] + _wall_chains(outline)
    n_obs = len(polys)
    centroids = np.array([p.mean(axis=0) for p in polys])
    points, owner = [*centroids], list(range(n_obs))
    for w in range(n_obs, len(solids)):
        for c in centroids:
            points.append(_closest_point(c, solids[w]))
            owner.append(w)
    # an obstacle whose circumscribed circle keeps out of the test disk cannot
    # fail Gabriel's test: only the others (and the walls) are measured, so that
    # finding the throats grows with their count, not with its square
    bound = np.array([np.hypot(*(p - c).T).max() for p, c in zip(polys, centroids)])
    walls = range(n_obs, len(solids))
    rows = []
    pairs_found, tri = _neighbours(np.array(points), np.array(owner), n_obs)
    for u, v in sorted(pairs_found):
        p, q = _closest_pair(solids[u], solids[v])
        reach = (1.0 + GABRIEL_SLACK) * 0.5 * float(np.hypot(*(q - p)))
        mid = 0.5 * (p + q)
        near = np.flatnonzero(np.hypot(*(centroids - mid).T) - bound < reach)
        others = [s for s in (*near, *walls) if s not in (u, v)]
        if all(_distance(mid, solids[s]) >= reach for s in others):
            rows.append((p, q, u, v))
    if not rows:
        return Throats(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), dtype=int))
    start = np.array([r[0] for r in rows])
    end = np.array([r[1] for r in rows])
    pairs = np.array([(r[2], r[3]) for r in rows], dtype=int)
    mid = 0.5 * (start + end)
    scale = float(np.ptp(outline, axis=0).max())
    order = np.lexsort((np.round(mid[:, 1] / scale, 9), np.round(mid[:, 0] / scale, 9)))
    links, link_throat, n_pores = _pores(tri, np.array(owner), pairs[order])
    return Throats(start[order], end[order], pairs[order], links, link_throat, n_pores)


def observe(throats: Throats, x_before, alive_before, x, v, alive, rest_speed: float,
            reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a check of one realization sees at each throat: (passages (T,) int,
    blocked at rest (T,) bool, reached (T,) bool: it holds a particle now).

    A passage is a centre whose straight path from its position at the previous
    check (``x_before``, alive then) to ``x`` crosses the throat's segment, either
    way; a particle that escaped since stays where it crossed the escape line, so
    the throats it passed on its way out count. Each live particle belongs to the
    throat whose segment is nearest, when nearer than ``reach`` (the largest
    diameter); a throat is blocked at rest, as the single constriction's arch
    test, when it holds particles, none moves at ``rest_speed`` or faster and none
    passed it. A throat that holds no particle has not been reached (or was left):
    the caller starts its rest afresh when one comes.
    """
    T = len(throats)
    # a path (a point) that reaches a throat's segment comes within its half
    # width of the segment's midpoint: only those pairs are measured, so a check
    # grows with the particles, not with particles x throats
    a, b = x_before[alive_before], x[alive_before]
    i, k = throats.near((a + b) / 2, np.hypot(*(b - a).T) / 2)
    crossed = segments_intersect(a[i], b[i], throats.start[k], throats.end[k], touching=False)
    passed = np.bincount(k[crossed], minlength=T)
    xs = x[alive]
    i, k = throats.near(xs, np.full(len(xs), reach))
    d = point_segment_distance(xs[i], throats.start[k], throats.end[k])
    i, k, d = i[d < reach], k[d < reach], d[d < reach]
    order = np.lexsort((k, d, i))          # nearest segment first (the lower index on ties)
    first = order[np.r_[True, i[order][1:] != i[order][:-1]]] if len(order) else order
    moving = np.linalg.norm(v[alive], axis=1) >= rest_speed
    held = np.bincount(k[first], minlength=T) > 0
    stirring = np.bincount(k[first][moving[i[first]]], minlength=T) > 0
    return passed, held & ~stirring & (passed == 0), held


def throat_rows(throats: Throats, passages, t_clog) -> list:
    """``throats.csv`` rows (realization, throat, x, y, width, passages, clogged,
    t_clog or None) from per-realization arrays (R, T) (NaN t_clog: open), when
    there are several throats, else none."""
    if len(throats) < 2:
        return []
    mid, width = throats.midpoints, throats.widths
    return [(r, k, float(mid[k, 0]), float(mid[k, 1]), float(width[k]),
             int(passages[r, k]), bool(np.isfinite(t_clog[r, k])),
             None if np.isnan(t_clog[r, k]) else float(t_clog[r, k]))
            for r in range(len(passages)) for k in range(len(throats))]


def _wall_chains(outline: np.ndarray) -> list:
    """The outline's wall edges, joined into chains between the open edges, each
    as (starts, ends) arrays."""
    inlet, outlet = open_edges(outline, outline[:, 0].min(), outline[:, 0].max())
    wall = ~(inlet | outlet)
    a, b = outline, np.roll(outline, -1, axis=0)
    n = len(outline)
    if wall.all():
        return [(a, b)]
    first = int(np.flatnonzero(~wall)[0])
    chains, current = [], []
    for k in range(first + 1, first + 1 + n):
        e = k % n
        if wall[e]:
            current.append(e)
        elif current:
            chains.append(current)
            current = []
    if current:
        chains.append(current)
    return [(a[c], b[c]) for c in chains]


def _neighbours(points, owner, n_obs) -> tuple[set, object]:
    """Pairs of solids (u < v, not both walls) joined by a Delaunay edge of
    ``points`` (every pair when there are too few points to triangulate), and the
    triangulation (None then)."""
    from scipy.spatial import Delaunay, QhullError
    try:
        tri = Delaunay(points)
        edges = set()
        for simplex in tri.simplices:
            edges.update(itertools.combinations(sorted(simplex), 2))
    except (QhullError, ValueError):   # fewer than 3 points, or all on one line
        tri = None
        edges = set(itertools.combinations(range(len(points)), 2))
    pairs = set()
    for i, j in edges:
        u, v = sorted((int(owner[i]), int(owner[j])))
        if u != v and u < n_obs:
            pairs.add((u, v))
    return pairs, tri


def _pores(tri, owner, pairs) -> tuple[np.ndarray, np.ndarray, int]:
    """The pore network of the throats (``pairs`` (T, 2), their solids; module
    notes): its links (L, 2) between pores (0 the inlet, 1 the outlet), the throat
    each link crosses (L,), and the pore count. Without a triangulation every
    throat joins the inlet to the outlet."""
    T = len(pairs)
    if tri is None:
        return np.tile([0, 1], (T, 1)), np.arange(T), 2
    throat_of = {(int(u), int(v)): k for k, (u, v) in enumerate(pairs)}
    n_tri = len(tri.simplices)
    parent = list(range(n_tri + 2))          # triangle t is node t + 2

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    joins = []                               # (node, node, throat)
    pts = tri.points
    for t, simplex in enumerate(tri.simplices):
        for corner in range(3):
            i, j = (int(simplex[(corner + 1) % 3]), int(simplex[(corner + 2) % 3]))
            other = int(tri.neighbors[t, corner])
            if other >= 0 and other < t:
                continue                     # each inner edge once
            u, v = sorted((int(owner[i]), int(owner[j])))
            if u == v:
                continue                     # along one wall: no way through
            if other >= 0:
                beyond = other + 2
            else:
                # a hull edge: the inlet or the outlet lies beyond it, on the side
                # its outward normal points to (none for a wall's own edge)
                edge = pts[j] - pts[i]
                normal = np.array([edge[1], -edge[0]])
                if np.dot(normal, pts[i] - pts[int(simplex[corner])]) < 0:
                    normal = -normal
                if abs(normal[0]) <= 1e-9 * np.hypot(*normal):
                    continue
                beyond = 0 if normal[0] < 0 else 1
            k = throat_of.get((u, v))
            if k is None:
                parent[find(t + 2)] = find(beyond)       # a free way: one pore
            else:
                joins.append((t + 2, beyond, k))
    roots = {}
    for a in (0, 1):
        roots.setdefault(find(a), len(roots))
    links = np.array([(roots.setdefault(find(a), len(roots)),
                       roots.setdefault(find(b), len(roots))) for a, b, _ in joins],
                     dtype=int).reshape(-1, 2)
    link_throat = np.array([k for _, _, k in joins], dtype=int)
    # a link inside one pore joins nothing
    keep = links[:, 0] != links[:, 1]
    return links[keep], link_throat[keep], len(roots)


def _distance(point, solid) -> float:
    return float(point_segment_distance(point[None], solid[0], solid[1]).min())


def _closest_point(point, solid) -> np.ndarray:
    """The point of ``solid`` (segments) nearest to ``point``."""
    a, b = solid
    ab = b - a
    t = np.clip(np.sum((point - a) * ab, axis=1) / np.sum(ab * ab, axis=1), 0.0, 1.0)
    foot = a + t[:, None] * ab
    return foot[np.argmin(np.hypot(*(foot - point).T))]


def _closest_pair(sa, sb) -> tuple[np.ndarray, np.ndarray]:
    """(point on A, point on B): the shortest segment between two solids of
    straight segments that do not cross. It ends at a vertex of one of them; where
    two faces are parallel every segment across their overlap is as short, and
    the one in its middle (the mean of the overlap's ends) is taken."""
    starts, ends, dists = [], [], []
    for verts_of, other, flip in ((sa, sb, False), (sb, sa, True)):
        verts = np.concatenate([verts_of[0], verts_of[1]])
        a, b = other[0][None], other[1][None]
        ab = b - a
        p = verts[:, None]
        t = np.clip(np.sum((p - a) * ab, axis=2) / np.sum(ab * ab, axis=2), 0.0, 1.0)
        foot = a + t[..., None] * ab
        d = np.hypot(*(foot - p).transpose(2, 0, 1))
        near = np.broadcast_to(p, foot.shape)
        starts.append((foot if flip else near).reshape(-1, 2))
        ends.append((near if flip else foot).reshape(-1, 2))
        dists.append(d.ravel())
    d = np.concatenate(dists)
    best = d <= d.min() * (1.0 + 1e-9)
    return np.concatenate(starts)[best].mean(axis=0), np.concatenate(ends)[best].mean(axis=0)
