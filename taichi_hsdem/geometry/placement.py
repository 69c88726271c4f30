"""Initial placement of particles in the channel, re-insertion spots, and checks.

Random sequential addition (RSA): particles are added one at a time, largest
first (small ones fill the gaps the large ones leave; the other order strands the
large ones), each at a position drawn uniformly in the fluid part of the control
volume ``region = (x0, x1)`` (the centre lies in the strip) with an angle uniform
in ``[0, 2 pi)``; a draw is kept if the particle clears every wall by more than
``gap`` and overlaps no particle placed before it, otherwise a new one is drawn.
RSA of equal disks jams at an areal fraction of about 0.547, and well before that
a free spot becomes rare, so dense requests fail with `PlacementError` rather
than loop.

Wall test (exact). A disk clears the walls by ``wall_distance(centre) - r``. For
a polygon: every vertex must have ``wall_distance > gap``, every wall corner
within reach must have the shape's signed distance ``> gap``, and no edge may
cross a wall segment. The distance between two polygonal chains that do not
cross is reached at a vertex of one of them, so these three are exactly
"clearance > gap"; they imply the surface nodes' test (every node at
``wall_distance > gap``), which alone would miss a wall corner poking into a face
between two nodes. The centre must be in the fluid, and the particle may not
stick out through the inlet or outlet (the fluid grid ends there).

Particle test. Candidates are found on a uniform grid of cell ``2 R_max + gap``
(``R`` the bounding radius), so a test costs the same at any particle count.
Bounding circles farther apart than ``gap`` cannot overlap; inscribed circles
closer than ``gap`` must; pairs of disks are decided by the first test exactly;
the rest go to `distance.overlaps`.

Examples
--------
>>> from taichi_hsdem.geometry import shapes, walls
>>> g = walls.converging(width_in=10.0, length_in=20.0, constriction_width=1.7, length_out=5.0)
>>> disk = shapes.circle(1.0)
>>> n = count_for_fraction(0.26, g, g.upstream_region, disk)
>>> x, theta = place(np.random.default_rng(0), g, [disk], np.zeros(n, int), g.upstream_region)
>>> n, x.shape, bool(check_initial(g, [disk], x, theta, np.zeros(n, int)) == [])
(66, (66, 2), True)
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from . import distance as _distance
from . import shapes as _shapes
from .polygon import segments_intersect
from .walls import Geometry, fluid_area, wall_distance, wall_segments

# Candidate positions are drawn and wall-tested in vectorised batches; the batch
# grows while draws keep failing (dense packing) and shrinks after quick successes,
# so that neither sparse nor dense placements waste much work.
_BATCH_MIN = 8
_BATCH_MAX = 1024


class PlacementError(ValueError):
    """Particles could not all be placed without overlap.

    Attributes
    ----------
    placed, requested : int
        Particles placed before giving up, and asked for.
    fraction_reached, fraction_requested : float
        Their areal fraction in the fluid part of the region.
    """

    def __init__(self, message, placed, requested, fraction_reached, fraction_requested):
        super().__init__(message)
        self.placed = placed
        self.requested = requested
        self.fraction_reached = fraction_reached
        self.fraction_requested = fraction_requested


def count_for_fraction(packing_fraction, geometry: Geometry, region, shape) -> int:
    """Number of particles of ``shape`` that fill ``region`` to an areal fraction.

    ``round(packing_fraction * fluid_area(region) / shape.area)``, the fluid area
    being that of the strip ``x0 <= x <= x1`` clipped to the channel.

    Examples
    --------
    >>> from taichi_hsdem.geometry import shapes, walls
    >>> g = walls.converging(10.0, 20.0, 1.7, 5.0)
    >>> count_for_fraction(0.26, g, (0.0, 20.0), shapes.circle(1.0))
    66
    """
    phi = float(packing_fraction)
    if not phi > 0:
        raise ValueError(f"packing_fraction must be > 0, got {phi}")
    x0, x1 = _strip(geometry, region)
    return int(round(phi * fluid_area(geometry, x0, x1) / shape.area))


def place(rng, geometry: Geometry, shapes, species_of_particle, region, gap=0.0,
          max_attempts=20000, existing=None, names=None):
    """Random positions and angles, without overlap, for every particle.

    Parameters
    ----------
    rng : numpy.random.Generator or int
        Source of randomness (an int seeds a new generator); the same generator
        state gives the same placement.
    geometry : Geometry
    shapes : sequence of Shape
        One per species.
    species_of_particle : (N,) array_like of int
        Species index of each particle.
    region : (x0, x1)
        The strip the centres are drawn in, m (clipped to the channel).
    gap : float
        Clearance required from the walls and between particles, >= 0, m.
    max_attempts : int
        Random draws allowed per particle before giving up.
    existing : (positions (E, 2), angles (E,), shapes sequence of E Shape), optional
        Particles already present, which the new ones must not overlap.
    names : sequence of str, optional
        Species names, for the error message.

    Returns
    -------
    x : (N, 2) ndarray
        Centres, in the order of ``species_of_particle``.
    theta : (N,) ndarray
        Angles, radians.

    Raises
    ------
    PlacementError
        A particle found no free spot in ``max_attempts`` draws. The message says
        how many were placed, the packing fraction reached, and what to change.

    Examples
    --------
    >>> from taichi_hsdem.geometry import shapes, walls
    >>> g = walls.converging(10.0, 20.0, 1.7, 5.0)
    >>> x, theta = place(1, g, [shapes.square(1.0)], np.zeros(40, int), (0.0, 20.0), gap=0.01)
    >>> x.shape, theta.shape
    ((40, 2), (40,))
    """
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    shapes = list(shapes)
    species = _species(species_of_particle, len(shapes))
    gap = _gap(gap)
    max_attempts = int(max_attempts)
    if max_attempts < 1:
        raise ValueError(f"max_attempts must be >= 1, got {max_attempts}")
    strip = _strip(geometry, region)
    ex_x, ex_theta, ex_shapes = _existing(existing)
    packer = _Packer(geometry, strip, gap, shapes + ex_shapes)
    for k in range(len(ex_shapes)):
        packer.add(ex_x[k], ex_theta[k], packer.index(ex_shapes[k]))
    which = [packer.index(s) for s in shapes]
    areas = np.array([s.area for s in shapes])[species]
    order = np.argsort(-areas, kind="stable")
    x = np.empty((len(species), 2))
    theta = np.empty(len(species))
    for n, p in enumerate(order):
        spot = packer.try_place(rng, which[species[p]], max_attempts)
        if spot is None:
            raise _placement_error(geometry, strip, _label(shapes, names, species[p]), n,
                                   areas, areas[order[:n]].sum(), max_attempts, gap)
        x[p], theta[p] = spot
        packer.add(spot[0], spot[1], which[species[p]])
    return x, theta


def find_free_spot(rng, geometry: Geometry, shape, region, others_x, others_theta, others_shapes,
                   gap=0.0, attempts=200):
    """A random spot in ``region`` where ``shape`` fits among other particles.

    Used by the feeder to re-insert an escaped particle at the inlet.

    Parameters
    ----------
    rng : numpy.random.Generator or int
    geometry : Geometry
    shape : Shape
    region : (x0, x1)
        Strip the centre is drawn in, m.
    others_x : (M, 2) array_like
    others_theta : (M,) array_like
    others_shapes : sequence of M Shape
        The particles in the domain (only those near the strip matter).
    gap : float
        Required clearance, m.
    attempts : int
        Random draws before giving up.

    Returns
    -------
    (x (2,) ndarray, theta float), or None if no free spot was found.

    Examples
    --------
    >>> from taichi_hsdem.geometry import shapes, walls
    >>> g = walls.converging(10.0, 20.0, 1.7, 5.0)
    >>> disk = shapes.circle(1.0)
    >>> spot = find_free_spot(0, g, disk, (0.0, 2.0), np.empty((0, 2)), np.empty(0), [])
    >>> bool(0.0 <= spot[0][0] <= 2.0)
    True
    """
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    strip = _strip(geometry, region)
    ox, otheta, oshapes = _existing((others_x, others_theta, others_shapes))
    packer = _Packer(geometry, strip, _gap(gap), [shape] + oshapes)
    for k in range(len(oshapes)):
        packer.add(ox[k], otheta[k], packer.index(oshapes[k]))
    spot = packer.try_place(rng, packer.index(shape), int(attempts))
    return None if spot is None else (spot[0].copy(), float(spot[1]))


def check_initial(geometry: Geometry, shapes, x, theta, species_of_particle, gap=0.0,
                  names=None) -> list[str]:
    """Problems with user-supplied positions: wall overlaps and particle overlaps.

    Parameters
    ----------
    geometry : Geometry
    shapes : sequence of Shape
        One per species.
    x : (N, 2) array_like
    theta : (N,) array_like
    species_of_particle : (N,) array_like of int
    gap : float
        Clearance asked for; particles closer than this (but not overlapping) are
        reported too when ``gap > 0``.
    names : sequence of str, optional
        Species names for the messages (default: the index and the shape kind).

    Returns
    -------
    list of str
        One line per problem, e.g. ``"particle 3 (species 'disks') overlaps a wall
        by 1.2e-06 m"``, ``"particles 2 and 7 overlap"``; empty when fine.

    Examples
    --------
    >>> from taichi_hsdem.geometry import shapes, walls
    >>> g = walls.converging(10.0, 20.0, 1.7, 5.0)
    >>> check_initial(g, [shapes.circle(1.0)], [[5.0, 0.0], [5.5, 0.0], [5.0, 4.75]],
    ...               np.zeros(3), [0, 0, 0], names=["disks"])
    ["particle 2 (species 'disks') overlaps a wall by 0.25 m", 'particles 0 and 1 overlap by 0.5 m']
    """
    shapes = list(shapes)
    species = _species(species_of_particle, len(shapes))
    n = len(species)
    x = np.asarray(x, dtype=float)
    theta = np.asarray(theta, dtype=float).reshape(-1)
    if x.shape != (n, 2) or theta.shape != (n,):
        raise ValueError(f"x must have shape ({n}, 2) and theta ({n},) for {n} particles, "
                         f"got {x.shape} and {theta.shape}")
    gap = _gap(gap)
    labels = [_label(shapes, names, k) for k in range(len(shapes))]
    segs = wall_segments(geometry)
    corners = _wall_corners(geometry)
    # Wall tests vectorised per species; messages then in particle order.
    phi_c = wall_distance(geometry, x)
    clear, crosses = np.zeros(n), np.zeros(n, dtype=bool)
    lo, hi = np.zeros(n), np.zeros(n)
    for k, s in enumerate(shapes):
        m = np.flatnonzero(species == k)
        clear[m], crosses[m] = _wall_clearance(geometry, s, x[m], theta[m], gap, segs, corners,
                                               phi_c[m])
        lo[m], hi[m] = _x_extent(s, x[m], theta[m])
    problems = []
    for p in range(n):
        who = f"particle {p} ({labels[species[p]]})"
        if phi_c[p] <= 0:
            problems.append(f"{who} has its centre outside the fluid region, at "
                            f"({x[p, 0]:.6g}, {x[p, 1]:.6g})")
            continue
        if clear[p] < 0:
            problems.append(f"{who} overlaps a wall by {-clear[p]:.2g} m")
        elif crosses[p]:
            # A thin wall across the particle, no vertex of either inside the other.
            problems.append(f"{who} crosses a wall")
        elif clear[p] <= gap and gap > 0:
            problems.append(f"{who} is {clear[p]:.2g} m from a wall, closer than the gap "
                            f"{gap:.2g} m")
        if lo[p] < geometry.x_min:
            problems.append(f"{who} sticks out through the inlet (x < {geometry.x_min:g})")
        if hi[p] > geometry.x_max:
            problems.append(f"{who} sticks out through the outlet (x > {geometry.x_max:g})")
    if n < 2:
        return problems
    radius = np.array([s.bounding_radius for s in shapes])[species]
    pairs = cKDTree(x).query_pairs(2 * radius.max() + gap, output_type="ndarray")
    for i, j in sorted(map(tuple, pairs)):
        si, sj = shapes[species[i]], shapes[species[j]]
        d = float(np.hypot(*(x[j] - x[i])))
        if si.kind == "circle" and sj.kind == "circle":
            depth = si.radius + sj.radius - d
            if depth > 0:
                problems.append(f"particles {i} and {j} overlap by {depth:.2g} m")
            elif gap > 0 and -depth < gap:
                problems.append(f"particles {i} and {j} are {-depth:.2g} m apart, closer than "
                                f"the gap {gap:.2g} m")
        elif _distance.overlaps(si, x[i], theta[i], sj, x[j], theta[j], 0.0):
            problems.append(f"particles {i} and {j} overlap")
        elif gap > 0 and _distance.overlaps(si, x[i], theta[i], sj, x[j], theta[j], gap):
            problems.append(f"particles {i} and {j} are closer than the gap {gap:.2g} m")
    return problems


# ----------------------------------------------------------------------------
# Internals
# ----------------------------------------------------------------------------

class _Packer:
    """Placed particles on a uniform grid, and the RSA draw-and-test loop."""

    def __init__(self, geometry: Geometry, strip, gap: float, shapes):
        self.geometry = geometry
        self.strip = strip
        self.gap = gap
        self.shapes = []
        self._ids = {}
        self.radius = np.empty(0)      # bounding radius per shape index
        self.inner = np.empty(0)       # inscribed radius about the centroid
        for s in shapes:
            self.index(s)
        self.segments = wall_segments(geometry)
        self.corners = _wall_corners(geometry)
        # Any two particles that can touch are less than one cell apart, so the
        # 3 x 3 cells around a candidate hold every particle it could overlap.
        self.cell = 2 * float(self.radius.max()) + gap
        self.lo = np.array([strip[0] - self.cell, geometry.y_min - self.cell])
        self.hi = np.array([strip[1] + self.cell, geometry.y_max + self.cell])
        ncell = np.floor((self.hi - self.lo) / self.cell).astype(int) + 1
        self.slots = np.full((ncell[0], ncell[1], 4), -1, dtype=np.int64)
        self.fill = np.zeros(ncell, dtype=np.int64)
        # Zero-filled, not empty: padded neighbour slots read entry 0 (then masked).
        self.pos = np.zeros((64, 2))
        self.ang = np.zeros(64)
        self.sid = np.zeros(64, dtype=np.int64)
        self.count = 0
        self.batch = _BATCH_MIN

    def index(self, shape) -> int:
        """Index of a shape in this packer's table (added on first sight)."""
        key = id(shape)
        if key not in self._ids:
            self._ids[key] = len(self.shapes)
            self.shapes.append(shape)
            # A concave shape's centroid can lie outside it: no inscribed disk then.
            inner = max(0.0, -float(_distance.signed_distance(shape, np.zeros(2))))
            self.radius = np.append(self.radius, shape.bounding_radius)
            self.inner = np.append(self.inner, inner)
        return self._ids[key]

    def add(self, x, theta, shape_index) -> None:
        x = np.asarray(x, dtype=float)
        # Particles farther than a cell from the strip cannot touch a candidate.
        if np.any(x < self.lo) or np.any(x > self.hi):
            return
        if self.count == len(self.pos):
            self.pos = np.concatenate([self.pos, np.zeros_like(self.pos)])
            self.ang = np.concatenate([self.ang, np.zeros_like(self.ang)])
            self.sid = np.concatenate([self.sid, np.zeros_like(self.sid)])
        k = self.count
        self.pos[k], self.ang[k], self.sid[k] = x, theta, shape_index
        self.count += 1
        i, j = self._cells(x[None])[0]
        if self.fill[i, j] == self.slots.shape[2]:
            # A full cell (many small particles in cells sized for the largest):
            # double every cell's capacity rather than drop a neighbour.
            grown = np.full(self.slots.shape[:2] + (2 * self.slots.shape[2],), -1, np.int64)
            grown[:, :, :self.slots.shape[2]] = self.slots
            self.slots = grown
        self.slots[i, j, self.fill[i, j]] = k
        self.fill[i, j] += 1

    def _cells(self, xs):
        c = np.floor((xs - self.lo) / self.cell).astype(np.int64)
        return np.minimum(np.maximum(c, 0), np.array(self.fill.shape) - 1)

    def neighbours(self, xs) -> np.ndarray:
        """(K, 9 * capacity) indices of placed particles in the 3 x 3 cells; -1 pads."""
        c = self._cells(xs)
        off = np.arange(-1, 2)
        ix = np.clip(c[:, 0, None, None] + off[:, None], 0, self.fill.shape[0] - 1)
        iy = np.clip(c[:, 1, None, None] + off[None, :], 0, self.fill.shape[1] - 1)
        return self.slots[ix, iy].reshape(len(xs), -1)

    def try_place(self, rng, s: int, attempts: int):
        """(x, theta) of the first draw that fits, or None after ``attempts`` draws."""
        shape = self.shapes[s]
        x0, x1 = self.strip
        g = self.geometry
        used = 0
        while used < attempts:
            k = min(self.batch, attempts - used)
            first_batch = used == 0
            used += k
            xs = np.column_stack([rng.uniform(x0, x1, k), rng.uniform(g.y_min, g.y_max, k)])
            th = rng.uniform(0.0, 2 * np.pi, k)
            fits = np.flatnonzero(self._clear_of_walls(shape, xs, th))
            hit = self._first_free(s, xs[fits], th[fits]) if fits.size else None
            if hit is not None:
                if first_batch:
                    self.batch = max(_BATCH_MIN, self.batch // 2)
                return xs[fits[hit]], th[fits[hit]]
            self.batch = min(_BATCH_MAX, 2 * self.batch)
        return None

    def _clear_of_walls(self, shape, xs, th) -> np.ndarray:
        g = self.geometry
        phi_c = wall_distance(g, xs)
        lo, hi = _x_extent(shape, xs, th)
        ok = (phi_c > 0) & (lo >= g.x_min) & (hi <= g.x_max)
        idx = np.flatnonzero(ok)
        clear, crosses = _wall_clearance(g, shape, xs[idx], th[idx], self.gap,
                                         self.segments, self.corners, phi_c[idx])
        ok[idx] = (clear > self.gap) & ~crosses
        return ok

    def _first_free(self, s: int, xs, th):
        """Index of the first candidate overlapping no placed particle, or None."""
        nb = self.neighbours(xs)
        valid = nb >= 0
        j = np.where(valid, nb, 0)
        d = np.linalg.norm(xs[:, None, :] - self.pos[j], axis=2)
        other = self.sid[j]
        near = valid & (d - self.radius[s] - self.radius[other] < self.gap)
        # Inscribed disks closer than gap: the shapes are too. For two disks
        # (inscribed = bounding) this decides every near pair exactly.
        sure = near & (d - self.inner[s] - self.inner[other] < self.gap)
        unsure = near & ~sure
        shape = self.shapes[s]
        for c in np.flatnonzero(~sure.any(axis=1)):
            if not any(_distance.overlaps(shape, xs[c], th[c], self.shapes[self.sid[q]],
                                        self.pos[q], self.ang[q], self.gap)
                       for q in nb[c, unsure[c]]):
                return int(c)
        return None


def _wall_clearance(geometry, shape, xs, th, gap, segments, corners, phi_c=None):
    """Clearance of each placed copy of ``shape`` from the walls, and edge crossings.

    Returns ``(clear, crosses)``. ``clear > gap`` exactly when the shape clears
    the walls by more than ``gap`` (given no crossing); a value <= gap is the exact
    clearance when >= 0 and, when negative, the deepest penetration of a vertex
    into a wall or of a wall corner into the shape. Copies whose centre is farther
    than ``R + gap`` from every wall get the lower bound ``phi(centre) - R``.
    ``phi_c``: the centres' wall distance, when the caller has it already.
    """
    phi_c = wall_distance(geometry, xs) if phi_c is None else phi_c
    crosses = np.zeros(len(xs), dtype=bool)
    if shape.kind == "circle":
        return phi_c - shape.radius, crosses
    r = shape.bounding_radius
    clear = phi_c - r
    idx = np.flatnonzero(clear <= gap)
    if idx.size == 0:
        return clear, crosses
    v = _shapes.transform(shape.vertices[None], xs[idx, None], th[idx, None])
    nv = v.shape[1]
    vertex_clear = wall_distance(geometry, v.reshape(-1, 2)).reshape(len(idx), nv).min(axis=1)
    # Wall corners farther than R + gap from the centre are farther than gap from the shape.
    kk, cc = np.nonzero(np.linalg.norm(corners[None] - xs[idx, None], axis=2) <= r + gap)
    corner_clear = np.full(len(idx), np.inf)
    if kk.size:
        sd = _distance.signed_distance(shape, _shapes.to_body(corners[cc], xs[idx][kk], th[idx][kk]))
        np.minimum.at(corner_clear, kk, sd)
    clear[idx] = np.minimum(vertex_clear, corner_clear)
    # Catches a thin wall laid across the shape with no vertex of either inside
    # the other.
    crosses[idx] = segments_intersect(v[:, :, None], np.roll(v, -1, axis=1)[:, :, None],
                                      segments[None, None, :, 0], segments[None, None, :, 1]
                                      ).any(axis=(1, 2))
    return clear, crosses


def _wall_corners(geometry: Geometry) -> np.ndarray:
    """Every wall end point: the outline's and the obstacles' vertices."""
    return np.concatenate([geometry.outline, *geometry.obstacles])


def _x_extent(shape, xs, th):
    if shape.kind == "circle":
        return xs[:, 0] - shape.radius, xs[:, 0] + shape.radius
    vx = _shapes.transform(shape.vertices[None], xs[:, None], th[:, None])[..., 0]
    return vx.min(axis=1), vx.max(axis=1)


def _strip(geometry: Geometry, region):
    try:
        x0, x1 = (float(v) for v in region)
    except (TypeError, ValueError):
        raise ValueError(f"region must be a pair [x0, x1], got {region!r}") from None
    if not x0 < x1:
        raise ValueError(f"region [{x0:g}, {x1:g}]: x0 must be < x1")
    lo, hi = max(x0, geometry.x_min), min(x1, geometry.x_max)
    if not lo < hi or fluid_area(geometry, lo, hi) <= 0:
        raise ValueError(f"region [{x0:g}, {x1:g}] holds no fluid: the channel spans "
                         f"x = [{geometry.x_min:g}, {geometry.x_max:g}]")
    return lo, hi


def _species(species_of_particle, n_species: int) -> np.ndarray:
    species = np.asarray(species_of_particle).reshape(-1)
    if species.size and (not np.issubdtype(species.dtype, np.integer)
                         or species.min() < 0 or species.max() >= n_species):
        raise ValueError(f"species_of_particle must hold integers in [0, {n_species}), "
                         f"one per particle")
    return species.astype(np.int64)


def _gap(gap) -> float:
    gap = float(gap)
    if not gap >= 0:
        raise ValueError(f"gap must be >= 0, got {gap}")
    return gap


def _existing(existing):
    if existing is None:
        return np.empty((0, 2)), np.empty(0), []
    x, theta, shapes = existing
    shapes = list(shapes)
    x = np.asarray(x, dtype=float).reshape(-1, 2)
    theta = np.asarray(theta, dtype=float).reshape(-1)
    if not len(x) == len(theta) == len(shapes):
        raise ValueError(f"existing particles: got {len(x)} positions, {len(theta)} angles "
                         f"and {len(shapes)} shapes; they must match")
    return x, theta, shapes


def _label(shapes, names, k: int) -> str:
    return f"species '{names[k]}'" if names is not None else f"species {k} ({shapes[k].name})"


def _placement_error(geometry, strip, label, placed, areas, placed_area,
                     max_attempts, gap) -> PlacementError:
    area = fluid_area(geometry, *strip)
    reached, requested = placed_area / area, areas.sum() / area
    gap_hint = f", or reduce the gap ({gap:g})" if gap > 0 else ""
    return PlacementError(
        f"placed {placed} of {len(areas)} particles in the region x = [{strip[0]:g}, "
        f"{strip[1]:g}]: a particle of {label} found no free spot "
        f"in {max_attempts} random tries. Packing fraction reached {reached:.3f} of the "
        f"{requested:.3f} requested (random placement of disks jams near 0.55 and slows "
        f"down well before). Lower the packing_fraction or count, or enlarge the region "
        f"(feed.region){gap_hint}.",
        placed, len(areas), reached, requested)
