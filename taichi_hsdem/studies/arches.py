"""The arches that clog a constriction: which particles span the neck, and how they touch.

A clogged realization ends with an arch: a chain of particles, each pressed on the
next, from one side wall to the other across the constriction. The geometry here
finds it in a state:

* **the arch** is the shortest chain (fewest particles) of touching particles from
  the lower side wall to the upper one (ties: the chain nearest the neck),
  :func:`arch_chain`;
* two outlines **touch** when their gap is at most ``tol`` times the bounding
  diameter ``d_b`` (a pressed contact has a small overlap, a negative gap); the gap
  is exact for outlines apart (the nearest points of two polygons are a vertex of
  one and an edge of the other, or a wall corner); for two convex outlines that
  overlap it is minus the penetration depth (the separating-axis test), for
  others minus the deepest vertex's depth; for two disks, and a disk and a wall,
  it comes from the centres' distances, many at once;
* a contact is **face-to-face** when an edge of one outline lies along an edge of
  the other (or along the wall): normals opposed within ``angle`` degrees and,
  over a common stretch of at least ``FACE_OVERLAP`` of the shorter edge, the one
  within ``tol d_b`` outside the other's line (or pressed into it by at most
  ``FACE_OVERLAP`` of the shorter edge); otherwise it is a **vertex** contact (a
  corner on a face or on a corner). A circle's contacts are all ``curved``.

Every run takes an arch census at its checks with :func:`arch_chain`
(:func:`taichi_hsdem.observables.census_arches`: when each arch formed, when and how
it broke, or that it held) and writes it to its folder's ``arches.csv``.

``python -m taichi_hsdem arches DIR`` (or ``python tools/arches.py DIR``) reads

* a **run folder** (``summary.json`` and ``arches.csv``): one line per
  realization (the arches formed, how the broken ones failed, the one that held:
  its particles and position) and a total line;
* a finished ``python -m taichi_hsdem figures`` **figure folder** (``figure.json``; every
  realization's final state kept in its point files, ``<out>/points/``): per
  clogged realization it finds the arch of the final state and sorts its
  contacts, and writes ``DIR/arches.csv`` (one row per clogged realization),
  ``DIR/arches.png`` (sample arches per point) and one summary line per point.
"""
from __future__ import annotations

import csv
import heapq
import io
import json
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from ..exits import Parser
from ..geometry.distance import signed_distance
from ..geometry.polygon import is_convex, point_segment_distance
from ..geometry.shapes import outline_polygon, to_body, transform
from ..geometry.walls import open_edges, wall_distance, wall_segments

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


# ----------------------------------------------------------------------------
# A figure folder
# ----------------------------------------------------------------------------

def _point_models(folder: Path):
    """``[(label, model, point data)]`` of a finished figure folder."""
    from ..resolve import resolve
    from ..scene import SceneError, load_scene

    try:
        fig = json.loads((folder / "figure.json").read_text())
    except (OSError, ValueError) as exc:
        raise ArchError(f"{folder}: no readable figure.json ({exc}); run python -m "
                        f"taichi_hsdem figures into it first") from None
    from .points import Point, point_file
    problem = _figure_json_problem(fig)
    if problem:
        raise ArchError(f"{folder / 'figure.json'}: {problem}: not the figure.json of a "
                        "finished figure (python -m taichi_hsdem figures writes it)")
    try:
        base = load_scene(fig["scene"], [str(o) for o in fig.get("base_overrides") or []])
        scenes = [base.with_values(dict(p["overrides"])) for p in fig["points"]]
    except SceneError as exc:
        raise ArchError("; ".join(exc.problems)) from None
    out = []
    for p, scene in zip(fig["points"], scenes):
        path = point_file(folder, Point(str(p["label"]), p["values"], scene))
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            raise ArchError(f"{path}: missing or unreadable; rerun the figure") from None
        if not isinstance(data, dict) or not isinstance(data.get("rows"), list):
            raise ArchError(f"{path}: not a point file of a figure (no \"rows\"); rerun the "
                            "figure")
        if not data.get("finals"):
            raise ArchError(f"{path}: no final states (point files written before they were "
                            f"kept); rerun the figure with --no-resume")
        out.append((p["label"], resolve(scene.with_values({"run.realizations": 1})), data))
    return out


def _figure_json_problem(fig) -> str | None:
    """What a figure.json lacks that :func:`_point_models` reads, or None."""
    if not isinstance(fig, dict):
        return "not a JSON object"
    if not isinstance(fig.get("scene"), str) or not fig["scene"]:
        return 'no "scene" (the base scene file)'
    if not isinstance(fig.get("base_overrides") or [], list):
        return '"base_overrides" is not a list'
    points = fig.get("points")
    if not isinstance(points, list):
        return 'no "points" list'
    for k, p in enumerate(points):
        if not (isinstance(p, dict) and isinstance(p.get("label"), str)
                and isinstance(p.get("values"), dict) and isinstance(p.get("overrides"), dict)):
            return f'point {k} lacks its "label", "values" or "overrides"'
    return None


def analyse_folder(folder, tol=DEFAULT_TOL, angle=DEFAULT_ANGLE):
    """Per point ``(label, rows, model, data)``; a row per clogged stable realization."""
    folder = Path(folder)
    result = []
    for label, model, data in _point_models(folder):
        shapes = [s.shape for s in model.species]
        d_b = 2.0 * max(s.bounding_radius for s in shapes)
        g = model.geometry
        sides = Sides(g)
        neck_x = 0.5 * (g.constriction_x0 + g.constriction_x1)
        rows = []
        for r in data["rows"]:
            if r["status"] != "ok" or not r["clogged"]:
                continue
            fs = data["finals"].get(str(r["seed"]))
            if fs is None:
                continue
            arch = find_arch(shapes, fs["x"], fs["theta"], fs["alive"], fs["species"], sides,
                             neck_x, d_b, tol, angle)
            row = {"label": label, "seed": r["seed"], "escapees": r["escapees"],
                   "arch_found": arch is not None}
            if arch is not None:
                kinds = Counter(arch["pairs"])
                walls = Counter(arch["walls"])
                row.update({"arch_size": len(arch["particles"]),
                            "pair_face": kinds["face"], "pair_vertex": kinds["vertex"],
                            "pair_curved": kinds["curved"],
                            "wall_face": walls["face"], "wall_vertex": walls["vertex"],
                            "wall_curved": walls["curved"],
                            "particles": " ".join(map(str, arch["particles"]))})
            rows.append(row)
        result.append((label, rows, model, data))
    return result


COLUMNS = ["label", "seed", "escapees", "arch_found", "arch_size", "pair_face", "pair_vertex",
           "pair_curved", "wall_face", "wall_vertex", "wall_curved", "particles"]


def summary_line(label, rows) -> str:
    found = [r for r in rows if r["arch_found"]]
    sizes = Counter(r["arch_size"] for r in found)
    pf = sum(r["pair_face"] for r in found)
    pv = sum(r["pair_vertex"] for r in found)
    wf = sum(r["wall_face"] for r in found)
    wv = sum(r["wall_vertex"] for r in found)
    mean = np.mean([r["arch_size"] for r in found]) if found else math.nan
    parts = [f"{label}: {len(rows)} clogged, arch found in {len(found)}",
             "sizes " + ", ".join(f"{k}: {sizes[k]}" for k in sorted(sizes))
             + f" (mean {mean:.2f})"]
    pc = sum(r["pair_curved"] for r in found)
    wc = sum(r["wall_curved"] for r in found)
    if pf + pv:
        parts.append(f"particle-particle contacts face {pf}, vertex {pv} "
                     f"({pf / (pf + pv):.0%} face)")
    if wf + wv:
        parts.append(f"on the walls face {wf}, vertex {wv}")
    if pc + wc:
        parts.append(f"curved contacts {pc} between particles, {wc} on the walls")
    return "; ".join(parts)


def draw(result, path, examples=6, tol=DEFAULT_TOL):
    """Sample arches per point, zoomed on the neck: one row of panels per point."""
    from .plots import pyplot
    plt = pyplot()
    n_rows = len(result)
    fig, axes = plt.subplots(n_rows, examples, figsize=(2.0 * examples, 2.1 * n_rows),
                             squeeze=False)
    for row_axes, (label, rows, model, data) in zip(axes, result):
        shapes = [s.shape for s in model.species]
        d_b = 2.0 * max(s.bounding_radius for s in shapes)
        g = model.geometry
        neck_x = 0.5 * (g.constriction_x0 + g.constriction_x1)
        yc = 0.5 * (g.y_min + g.y_max)
        segs = wall_segments(g)
        shown = [r for r in rows if r["arch_found"]][:examples]
        for ax, r in zip(row_axes, shown + [None] * (examples - len(shown))):
            ax.set_axis_off()
            if r is None:
                continue
            fs = data["finals"][str(r["seed"])]
            arch = set(int(i) for i in r["particles"].split())
            for i, (xi, ti, al, sp) in enumerate(zip(fs["x"], fs["theta"], fs["alive"],
                                                     fs["species"])):
                if not al or abs(xi[0] - neck_x) > 3 * d_b:
                    continue
                w = transform(outline_polygon(shapes[int(sp)]), xi, ti)
                ax.fill(w[:, 0], w[:, 1], color="tab:red" if i in arch else "0.8",
                        ec="k", lw=0.4)
            for s in segs:
                ax.plot(s[:, 0], s[:, 1], "k-", lw=1.2)
            ax.set_xlim(neck_x - 2.5 * d_b, neck_x + 0.7 * d_b)
            ax.set_ylim(yc - 1.6 * d_b, yc + 1.6 * d_b)
            ax.set_aspect("equal")
            faces = r["pair_face"] + r["wall_face"]
            corners = r["pair_vertex"] + r["wall_vertex"]
            ax.set_title(f"seed {r['seed']}: {r['arch_size']} (f{faces}/v{corners})", fontsize=7)
        row_axes[0].text(-0.05, 0.5, label, transform=row_axes[0].transAxes, rotation=90,
                         ha="right", va="center", fontsize=8)
    fig.suptitle(f"clogging arches (red; flow left to right; touching: gap <= {tol:g} d_b; "
                 f"f/v: face/vertex contacts)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------
# A run folder
# ----------------------------------------------------------------------------

#: arches.csv's columns in a run folder (output.write_arches).
RUN_COLUMNS = ["realization", "arch", "t_formed", "t_broken", "held", "count", "ids",
               "x_over_d", "failure"]


def read_run(folder: Path):
    """``(summary, arches)`` of a run folder: its summary.json, and its arches.csv
    as one list of row dicts (text values) per realization."""
    try:
        summary = json.loads((folder / "summary.json").read_text())
        n = len(summary["realizations"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ArchError(f"{folder}/summary.json: not a run's summary ({exc})") from None
    path = folder / "arches.csv"
    if not path.is_file():
        raise ArchError(f"{path}: missing: the run was made before runs took an arch census; "
                        "run the scene again")
    arches = [[] for _ in range(n)]
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            if reader.fieldnames != RUN_COLUMNS:
                raise ValueError(f"columns {reader.fieldnames}, not {RUN_COLUMNS}")
            for row in reader:
                arches[int(row["realization"])].append(row)
    except (OSError, ValueError, IndexError) as exc:
        raise ArchError(f"{path}: not a run's arches.csv ({exc})") from None
    return summary, arches


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}es"


def _failures(rows) -> str:
    """How the broken arches of ``rows`` failed: ``2 escaped, 1 slid``."""
    counts = Counter(r["failure"] for r in rows if r["held"] != "true")
    return ", ".join(f"{counts[k]} {k}" for k in ("escaped", "rolled", "slid") if counts[k])


def run_lines(summary, arches) -> list[str]:
    """One line per realization of a run folder (:func:`read_run`): the arches
    formed, how the broken ones failed, the one that held (its particles from the
    lower wall up and its position: x of their mean less the neck's, over the
    smallest d_eq); and a total line."""
    lines = []
    for k, (real, rows) in enumerate(zip(summary["realizations"], arches)):
        head = f"realization {k} (seed {real['seed']}): "
        if real["status"] == "unstable":
            lines.append(head + "went unstable, no arches counted")
            continue
        parts = [_plural(len(rows), "arch") + " formed"]
        if _failures(rows):
            parts.append(f"broken: {_failures(rows)}")
        held = [r for r in rows if r["held"] == "true"]
        parts += [f"held: particles {r['ids']} at x = {float(r['x_over_d']):+.2f} d from "
                  f"the neck, formed at t = {float(r['t_formed']):.4g}" for r in held] or [
            "none held"]
        lines.append(head + "; ".join(parts))
    counted = [rows for real, rows in zip(summary["realizations"], arches)
               if real["status"] != "unstable"]
    every = [r for rows in counted for r in rows]
    held = sum(r["held"] == "true" for r in every)
    total = (f"total: {_plural(len(every), 'arch')} formed in {len(counted)} realizations, "
             f"{held} held")
    if _failures(every):
        total += f"; broken: {_failures(every)}"
    return lines + [total]


def _parser(prog: str) -> Parser:
    p = Parser(prog=prog, description="The arches of a run folder (its arch census), or the "
                                      "clogging arches of a finished figures folder.")
    p.add_argument("folder", help="a run's output folder, or a figure's --out folder")
    p.add_argument("--tol", type=float, default=None,
                   help=f"figure folders: touching: gap at most this times d_b (default "
                        f"{DEFAULT_TOL})")
    p.add_argument("--angle", type=float, default=None,
                   help=f"figure folders: face-to-face: normals opposed within this many "
                        f"degrees (default {DEFAULT_ANGLE:g})")
    p.add_argument("--examples", type=int, default=None,
                   help="figure folders: arches drawn per point (default 6)")
    return p


def main(argv=None, prog: str = "python -m taichi_hsdem arches") -> int:
    """Command line; exit 0 on success, 2 for invalid input."""
    try:
        args = _parser(prog).parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    folder = Path(args.folder)
    options = [f"--{k}" for k in ("tol", "angle", "examples") if getattr(args, k) is not None]
    if not (folder / "figure.json").exists():
        if not (folder / "summary.json").exists():
            print(f"{folder}: neither a run folder (no summary.json) nor a figure folder "
                  f"(no readable figure.json)", file=sys.stderr)
            return 2
        if options:
            print(f"{', '.join(options)}: for figure folders; a run's arch census was taken "
                  f"during the run (touching: gap <= {DEFAULT_TOL:g} d_b)", file=sys.stderr)
            return 2
        try:
            summary, arches = read_run(folder)
        except ArchError as exc:
            print(str(exc), file=sys.stderr)
            return 2
        if summary.get("arches_formed") is None:
            print(f"{folder}: the run took no arch census: its geometry is not a channel with "
                  "two side walls and no obstacles")
            return 0
        print("\n".join(run_lines(summary, arches)))
        return 0
    tol = DEFAULT_TOL if args.tol is None else args.tol
    angle = DEFAULT_ANGLE if args.angle is None else args.angle
    examples = 6 if args.examples is None else args.examples
    problems = []
    if not (0 < tol < 1):
        problems.append(f"--tol must be in (0, 1), got {tol:g}")
    if not (0 < angle < 90):
        problems.append(f"--angle must be in (0, 90) degrees, got {angle:g}")
    if examples < 1:
        problems.append(f"--examples must be >= 1, got {examples}")
    if problems:
        print("\n".join(problems), file=sys.stderr)
        return 2
    try:
        result = analyse_folder(folder, tol, angle)
    except ArchError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    from .folder import StudyFolder, StudyFolderError
    try:
        name = _figure_name(folder)
        with StudyFolder(folder, f"figures {name}" if name else "figures", key=str(folder),
                         legacy=_legacy_files) as study:
            study.refuse_foreign(FILES, "the arch census")
            study.claim(FILES)
            _write(folder, result, examples, tol)
    except StudyFolderError as exc:
        print("\n".join(exc.problems), file=sys.stderr)
        return 2
    return 0


#: The files the census of a figure folder writes there.
FILES = ("arches.csv", "arches.png")


def _figure_name(folder: Path):
    try:
        return json.loads((folder / "figure.json").read_text()).get("figure")
    except (OSError, ValueError, AttributeError):
        return None


def _legacy_files(folder: Path) -> list[str]:
    """The figure's files and the census's in a figure folder of an earlier
    version (no study manifest), told by what they hold."""
    from .figures import _legacy_files as figure_files
    name = _figure_name(folder)
    names = list(figure_files(name)(folder)) if name else []
    try:
        with open(folder / "arches.csv", encoding="utf-8", errors="replace") as fh:
            if names and fh.readline().rstrip("\n") == ",".join(COLUMNS):
                names += [n for n in FILES if (folder / n).exists()]
    except OSError:
        pass
    return names


def _write(folder: Path, result, examples: int, tol: float):
    from ..output import atomic_write
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for _, rows, _, _ in result:
        for r in rows:
            w.writerow([r.get(k, "") for k in COLUMNS])
    atomic_write(folder / "arches.csv", buf.getvalue())
    for label, rows, _, _ in result:
        print(summary_line(label, rows))
    draw(result, folder / "arches.png", examples, tol)
    print(f"wrote {folder}/arches.csv, arches.png")
