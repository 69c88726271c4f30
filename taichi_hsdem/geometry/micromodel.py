"""Micromodels: a straight channel holding an array of pillars.

The pillars are regular polygons of ``sides`` vertices. A circular pillar's
polygon straddles the circle of the pillar's radius ``r``: the vertices lie at
``R_v = 2 r / (1 + cos(pi / sides))`` and the edges' midpoints at
``R_v cos(pi / sides)``, so the outline departs from the circle by at most
``r tan^2(pi / (2 sides))`` (0.43 % of r at 24 sides) and a gap between two
pillars, or a pillar and a wall, is within ``2 r tan^2(pi / (2 sides))`` of the
circles' gap. A polygonal pillar (``shape = "polygon"``) is the polygon whose
inscribed circle is the pillar's: its flat faces are ``diameter`` apart (a
square of side ``diameter`` at 4 sides), its vertices at ``r / cos(pi / sides)``.
Random arrays keep the circles through the polygons' vertices at least
``min_throat`` apart, so the polygons themselves too; regular arrays are
measured, polygon to polygon, against it.

The channel spans x in [0, inlet_length + columns * spacing + outlet_length] and
y in [-W/2, W/2] with ``W = rows * spacing + (spacing - diameter)``: the gap
between the outer pillars of a square column and the walls equals the gap
between two pillars of the column. Column ``j`` is centred at
``x = inlet_length + (j + 1/2) spacing``. In a staggered array every other column
is shifted by ``spacing / 2`` and holds ``rows - 1`` pillars.

>>> m = pillar_array("square", rows=2, columns=3, diameter=1.0, spacing=2.0,
...                  inlet_length=4.0, outlet_length=3.0)
>>> len(m.obstacles), float(m.outline[:, 0].max()), float(m.outline[:, 1].max())
(6, 13.0, 2.5)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .polygon import point_segment_distance, points_in_polygon

ARRAYS = ("square", "staggered", "random")
SHAPES = ("circle", "polygon")
#: Fewest sides of a circular pillar's polygon: its outline within 4 % of r of
#: the circle (module notes)
CIRCLE_MIN_SIDES = 8
#: The ``[geometry]`` keys of ``kind = "micromodel"`` (:func:`array_of` reads them).
MICROMODEL_KEYS = ("pillar_array", "pillar_shape", "rows", "columns", "pillar_diameter",
                   "pillar_spacing", "pillar_sides", "diameter_spread", "min_throat",
                   "inlet_length", "outlet_length", "pillar_seed")


class PillarError(ValueError):
    """An array that cannot be built: ``key`` is the ``[geometry]`` key to change."""

    def __init__(self, key: str, problem: str):
        self.key, self.problem = key, problem
        super().__init__(f"{key}: {problem}")
#: Smallest pillar diameter, relative to the channel's larger side: a pillar's
#: outline is built from coordinates of the channel's size, and below about 3e-8
#: of it float64 rounding makes its polygon collinear (1e-6 leaves a margin).
MIN_RELATIVE_DIAMETER = 1e-6
#: Tries for each pillar of a random array before the array is refused as too dense.
RANDOM_TRIES = 2000


@dataclass(frozen=True)
class Micromodel:
    """A generated pillar array: the channel ``outline`` (counter-clockwise), the
    pillars' ``centres`` (n, 2) and circle ``radii`` (n,), their polygons
    ``obstacles`` and ``x_exit``, the downstream end of the array, m."""
    outline: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    obstacles: tuple
    x_exit: float


def vertex_radius(radius: float, sides: int, shape: str = "circle") -> float:
    """Radius of the vertices of a pillar polygon of ``radius`` (module notes)."""
    if shape == "polygon":
        return radius / math.cos(math.pi / sides)
    return 2.0 * radius / (1.0 + math.cos(math.pi / sides))


def pillar_polygon(centre, radius: float, sides: int, shape: str = "circle") -> np.ndarray:
    """(sides, 2) counter-clockwise vertices; an edge (not a vertex) faces +x, +y,
    -x and -y when ``sides`` is a multiple of 4, so that a lattice's gaps along the
    axes are gaps between flat faces."""
    angles = (np.arange(sides) + 0.5) * (2.0 * math.pi / sides)
    rv = vertex_radius(radius, sides, shape)
    return np.asarray(centre, dtype=float) + rv * np.stack([np.cos(angles), np.sin(angles)], 1)


def channel_size(rows: int, columns: int, diameter: float, spacing: float,
                 inlet_length: float, outlet_length: float) -> tuple[float, float]:
    """(length, width) of the channel of an array (module notes)."""
    return (inlet_length + columns * spacing + outlet_length,
            rows * spacing + (spacing - diameter))


def pillar_array(array: str, rows: int, columns: int, diameter: float, spacing: float,
                 inlet_length: float, outlet_length: float, sides: int = 24,
                 spread: float = 0.0, min_throat: float | None = None,
                 seed: int = 0, shape: str = "circle") -> Micromodel:
    """The pillar array of a micromodel (module notes).

    ``array``: "square", "staggered" or "random"; ``shape``: "circle" or
    "polygon" (module notes). A random array places
    ``rows * columns`` pillars of diameters ``diameter * (1 + spread * z)`` (z
    standard normal, cut at +-2) one after the other at uniform random spots of
    the array's box, x in [inlet_length, inlet_length + columns * spacing], keeping
    every polygon at least ``min_throat`` from the others and from the walls
    (default ``(spacing - diameter) / 2``); the same ``seed`` gives the same array.

    Raises PillarError (naming the key to change) when the pillars touch each
    other or the walls, or a random array cannot be placed.
    """
    if array not in ARRAYS:
        raise PillarError("pillar_array", f"expected one of {ARRAYS}, got {array!r}")
    if shape not in SHAPES:
        raise PillarError("pillar_shape", f"expected one of {SHAPES}, got {shape!r}")
    length, width = channel_size(rows, columns, diameter, spacing, inlet_length,
                                 outlet_length)
    gap = spacing - diameter
    if gap <= 0:
        raise PillarError("pillar_spacing", f"{spacing:g} must exceed pillar_diameter "
                          f"({diameter:g}): the pillars would touch")
    smallest = MIN_RELATIVE_DIAMETER * max(length, width)
    if not diameter >= smallest:
        raise PillarError("pillar_diameter", f"{diameter:g} is too small for a channel "
                          f"{max(length, width):g} long: a pillar must be at least "
                          f"{MIN_RELATIVE_DIAMETER:g} of it ({smallest:.3g}) for its "
                          "outline to be resolved")
    r = diameter / 2.0
    y0 = -width / 2.0 + gap + r          # centre of the lowest pillar of a column
    if array == "random":
        centres, radii = _random(rows * columns, r, spread, inlet_length,
                                 inlet_length + columns * spacing, width,
                                 gap / 2.0 if min_throat is None else min_throat,
                                 sides, shape, np.random.default_rng(seed), smallest)
    else:
        if array == "staggered" and rows < 2:
            raise PillarError("rows", "a staggered array needs at least 2 rows (every "
                              "other column holds rows - 1 pillars)")
        points = []
        for j in range(columns):
            shifted = array == "staggered" and j % 2 == 1
            x = inlet_length + (j + 0.5) * spacing
            for i in range(rows - 1 if shifted else rows):
                points.append((x, y0 + i * spacing + (spacing / 2.0 if shifted else 0.0)))
        centres = np.array(points, dtype=float)
        radii = np.full(len(centres), r)
    outline = np.array([[0.0, -width / 2], [length, -width / 2], [length, width / 2],
                        [0.0, width / 2]])
    obstacles = tuple(pillar_polygon(c, rr, sides, shape) for c, rr in zip(centres, radii))
    if array != "random":
        narrowest = _narrowest_gap(obstacles, width, vertex_radius(r, sides, shape))
        if narrowest <= 0:
            raise PillarError("pillar_spacing", f"{spacing:g} is too small for "
                              f"{sides}-sided pillars of diameter {diameter:g}: their "
                              "corners touch")
        if min_throat is not None and narrowest < min_throat:
            raise PillarError("min_throat", f"{min_throat:g} is wider than the array's "
                              f"narrowest gap, {narrowest:g}")
    x_exit = float(max(o[:, 0].max() for o in obstacles))
    return Micromodel(outline, centres, radii, obstacles, x_exit)


def array_of(g) -> Micromodel:
    """The array a micromodel ``[geometry]`` asks for: ``g`` a dict of its keys or
    the scene's ``GeometryConfig``."""
    get = g.__getitem__ if isinstance(g, dict) else lambda name: getattr(g, name)
    return pillar_array(get("pillar_array"), get("rows"), get("columns"),
                        get("pillar_diameter"), get("pillar_spacing"), get("inlet_length"),
                        get("outlet_length"), sides=get("pillar_sides"),
                        spread=get("diameter_spread"), min_throat=get("min_throat"),
                        seed=get("pillar_seed"), shape=get("pillar_shape"))


def polygon_gap(a, b) -> float:
    """Shortest distance between two polygons, from a vertex of one to an edge of
    the other, both ways; 0 where a vertex of one lies inside the other (they
    overlap: translates of one convex pillar cannot cross without)."""
    if points_in_polygon(a, b).any() or points_in_polygon(b, a).any():
        return 0.0
    return float(min(point_segment_distance(p[:, None], q[None],
                                            np.roll(q, -1, axis=0)[None]).min()
                     for p, q in ((a, b), (b, a))))


def _narrowest_gap(obstacles, width: float, outer: float) -> float:
    """The narrowest gap of a regular array of pillars whose vertices lie within
    ``outer`` of their centres: pillar to pillar (the pairs near enough to
    matter) and pillar to wall."""
    walls = min(width / 2 - float(np.abs(o[:, 1]).max()) for o in obstacles)
    centres = np.array([o.mean(axis=0) for o in obstacles])
    apart = np.hypot(*(centres[:, None] - centres[None]).transpose(2, 0, 1))
    near = zip(*np.nonzero(np.triu(apart < 2 * outer + walls, 1)))
    return min([walls] + [polygon_gap(obstacles[i], obstacles[j]) for i, j in near])


def _random(n, r, spread, x0, x1, width, min_throat, sides, shape, rng, smallest):
    z = np.clip(rng.standard_normal(n), -2.0, 2.0)
    radii = r * (1.0 + spread * z)
    if radii.min() <= 0:
        raise PillarError("diameter_spread", f"{spread:g} gives pillars of no size; use "
                          "less than 0.5")
    if 2.0 * radii.min() < smallest:
        raise PillarError("diameter_spread", f"{spread:g} gives a pillar of diameter "
                          f"{2.0 * radii.min():g}, below the {smallest:.3g} "
                          f"({MIN_RELATIVE_DIAMETER:g} of the channel) its outline needs; "
                          "use a smaller spread")
    # largest first: the big ones are the hard ones to fit
    radii = np.sort(radii)[::-1]
    outer = np.array([vertex_radius(rr, sides, shape) for rr in radii])
    centres = np.zeros((n, 2))
    for k in range(n):
        lo = np.array([x0 + outer[k], -width / 2 + outer[k] + min_throat])
        hi = np.array([x1 - outer[k], width / 2 - outer[k] - min_throat])
        if np.any(hi <= lo):
            raise PillarError("min_throat", f"{min_throat:g}: a pillar of diameter "
                              f"{2 * radii[k]:g} cannot keep it from both walls")
        for _ in range(RANDOM_TRIES):
            c = lo + rng.random(2) * (hi - lo)
            gaps = np.hypot(*(centres[:k] - c).T) - outer[:k] - outer[k]
            if k == 0 or gaps.min() >= min_throat:
                centres[k] = c
                break
        else:
            raise PillarError("min_throat", f"{min_throat:g}: only {k} of the {n} pillars "
                              f"fit in {RANDOM_TRIES} random tries each; lower min_throat, "
                              "the pillar count (rows x columns) or their size")
    return centres, radii
