"""3D Stokes flow in the pore space of a Hele-Shaw cell, with NGSolve (issue #19).

The fluid region is the channel outline extruded over the gap ``0 <= z <= H``, less
the particles: spheres of their diameter centred at mid-gap (``z = H/2``), or
prisms (cylinders through the whole gap). Netgen meshes it in tetrahedra, finer in the
thin films (:func:`narrow_gaps`) and curved to the order of the velocity; the Stokes
equations

    -eta lap u + grad p = 0,   div u = 0

are solved with the Taylor-Hood pair (continuous P_k velocity, P_(k-1) pressure; the
validation uses k = 3), no slip
on the plates, the side walls and the particles, and the pressure given on the
inlet (``x = x_min``) and outlet (``x = x_max``) as the traction of the gradient
form, ``(eta grad u - p I) n = -p_b n``: in a section whose flow is fully developed
(``du/dn = 0``) that is ``p = p_b``. The saddle-point system is factorised with
UMFPACK (an indefinite sparse LU): an iterative MinRes with a BDDC-preconditioned
velocity block took over 14 minutes where UMFPACK took one on a 360,000-unknown
hourglass mesh (P2/P1).

Contacts need care: DEM particles touch with overlaps of 1e-4 d, and two spheres so
nearly tangent leave a cusp (or a film 1e-4 d thick) that no mesher resolves. A
pair of spheres, or a sphere and a side wall, whose gap is below ``bridge_gap``
times the smaller radius (overlaps included) is joined by a *bridge*: a cylinder
of radius ``bridge_radius`` times the smaller radius along the line of centres
(towards the wall's nearest point for a wall), the usual remedy for meshing
sphere packings. It fills only the lens round the contact point, where a film
thinner than 0.1 r passes a negligible flux (lubrication: ~ gap^(5/2)).

Only this module imports NGSolve; :func:`require` says how to install it.

The last section holds what tools/stokes_sphere_gap.py and
tools/stokes_sphere_lattice.py share: one sphere at mid-gap in a box, its mesh
refined over the films, the fixed and the moving problem on one LU, and a table of
runs (each run's JSON cached by its settings, a CSV with ``#`` comment lines).
"""
from __future__ import annotations

import csv
import json
import math
import pathlib
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np

PIP_HINT = "pip install -e '.[stokes]'  (or: pip install ngsolve)"


class MissingExtra(ImportError):
    """NGSolve (the ``stokes`` extra) is not installed."""


def require(threads=1):
    """Import NGSolve and Netgen's OCC geometry, or raise :class:`MissingExtra`.

    Parameters
    ----------
    threads : int
        Threads NGSolve may use (its task manager is not started: 1 keeps every
        assembly and the factorisation on one core).

    Returns
    -------
    tuple
        The modules ``(ngsolve, netgen.occ)``.
    """
    try:
        import ngsolve
        from netgen import occ
    except ImportError as exc:  # only the extra is missing: say how to get it
        raise MissingExtra(f"the 3D Stokes solve needs NGSolve, which is not installed "
                           f"({exc}); install it with: {PIP_HINT}") from None
    ngsolve.SetNumThreads(int(threads))
    ngsolve.ngsglobals.msg_level = 0
    return ngsolve, occ


@dataclass
class Bridge:
    """A cylinder joining two touching bodies (or a body and a wall).

    Attributes
    ----------
    a, b : numpy.ndarray, shape (2,)
        End points of its axis in the plane, at mid-gap.
    radius : float
    gap : float
        Surface gap of the contact it closes (negative: overlap).
    between : tuple
        ``(i, j)`` particle indices, or ``(i, "wall")``.
    """

    a: np.ndarray
    b: np.ndarray
    radius: float
    gap: float
    between: tuple


def wall_segments(outline, x_min, x_max, tol=1e-9):
    """The outline's edges that are walls (not the inlet ``x_min`` or outlet ``x_max``).

    Returns
    -------
    numpy.ndarray, shape (E, 2, 2)
    """
    p = np.asarray(outline, dtype=float)
    q = np.roll(p, -1, axis=0)
    scale = tol * max(float(np.ptp(p, axis=0).max()), 1.0)
    on_inlet = (np.abs(p[:, 0] - x_min) < scale) & (np.abs(q[:, 0] - x_min) < scale)
    on_outlet = (np.abs(p[:, 0] - x_max) < scale) & (np.abs(q[:, 0] - x_max) < scale)
    keep = ~(on_inlet | on_outlet)
    return np.stack([p[keep], q[keep]], axis=1)


def _nearest_on_segments(point, segments):
    a, b = segments[:, 0], segments[:, 1]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    foot = a + t[:, None] * ab
    dist = np.linalg.norm(point - foot, axis=1)
    k = int(np.argmin(dist))
    return foot[k], float(dist[k])


def find_bridges(centres, radii, walls, bridge_gap=0.1, bridge_radius=0.2):
    """Contacts to close with a bridge (see the module docstring).

    Parameters
    ----------
    centres : (N, 2) array_like
    radii : (N,) array_like
    walls : (E, 2, 2) array_like
        Wall segments (:func:`wall_segments`).
    bridge_gap : float
        Pairs closer than ``bridge_gap * min(r_i, r_j)`` are bridged.
    bridge_radius : float
        The bridge's radius in units of the smaller radius. A pair that overlaps
        so much that the spheres' intersection circle is already wider gets none.

    Returns
    -------
    list of Bridge
    """
    x = np.asarray(centres, dtype=float).reshape(-1, 2)
    r = np.asarray(radii, dtype=float).ravel()
    out = []
    for i in range(len(r)):
        for j in range(i + 1, len(r)):
            d = float(np.linalg.norm(x[j] - x[i]))
            gap = d - r[i] - r[j]
            rmin = min(r[i], r[j])
            if gap >= bridge_gap * rmin:
                continue
            a = bridge_radius * rmin
            if gap < 0:  # radius of the circle where the two spheres meet
                s = (d * d + r[i] ** 2 - r[j] ** 2) / (2 * d)
                if np.sqrt(max(r[i] ** 2 - s * s, 0.0)) >= a:
                    continue
            out.append(Bridge(x[i].copy(), x[j].copy(), a, gap, (i, j)))
        if len(walls):
            foot, dist = _nearest_on_segments(x[i], np.asarray(walls, dtype=float))
            gap = dist - r[i]
            a = bridge_radius * r[i]
            if gap < bridge_gap * r[i] and not (gap < 0 and np.sqrt(max(r[i] ** 2 - dist ** 2,
                                                                        0.0)) >= a):
                # through the wall by half a radius: the solid part is cut away
                u = (foot - x[i]) / max(dist, 1e-300)
                out.append(Bridge(x[i].copy(), foot + 0.5 * r[i] * u, a, gap, (i, "wall")))
    return out


def _prism(occ, polygon, z0, z1):
    wp = occ.WorkPlane(occ.Axes((0, 0, z0), n=occ.Z, h=occ.X))
    wp.MoveTo(*polygon[0])
    for q in polygon[1:]:
        wp.LineTo(*q)
    wp.Close()
    return wp.Face().Extrude(z1 - z0)


def pore_space(outline, gap, centres, radii, bridges=(), kind="spheres", h_particle=0.4):
    """The fluid region as an OCC solid with named faces.

    Parameters
    ----------
    outline : (M, 2) array_like
        Channel outline (a simple polygon); its edges on ``x = min x`` and
        ``x = max x`` become the faces ``inlet`` and ``outlet``.
    gap : float
        ``H``.
    centres, radii : array_like, shapes (N, 2), (N,)
        The particles (disks in the plane).
    bridges : list of Bridge
    kind : {"spheres", "prisms"}
        Spheres of the disk's diameter at mid-gap, or cylinders through the gap.
    h_particle : float
        Largest element edge on a particle's surface, in units of its radius.

    Returns
    -------
    occ shape
        Faces named ``inlet``, ``outlet``, ``plate``, ``wall``, ``particle``;
        only the pieces of fluid joined to the inlet or the outlet.
    """
    ng, occ = require()
    del ng
    poly = np.asarray(outline, dtype=float)
    body = _prism(occ, poly, 0.0, gap)
    body.faces.name = "wall"
    body.faces.Min(occ.Z).name = "plate"
    body.faces.Max(occ.Z).name = "plate"
    body.faces.Min(occ.X).name = "inlet"
    body.faces.Max(occ.X).name = "outlet"
    solids = []
    x = np.asarray(centres, dtype=float).reshape(-1, 2)
    r = np.asarray(radii, dtype=float).ravel()
    margin = 0.25 * gap
    for c, rad in zip(x, r):
        if kind == "spheres":
            s = occ.Sphere(occ.Pnt(c[0], c[1], 0.5 * gap), rad)
        elif kind == "prisms":
            s = occ.Cylinder(occ.Pnt(c[0], c[1], -margin), occ.Z, rad, gap + 2 * margin)
        else:
            raise ValueError(f"kind must be 'spheres' or 'prisms', got {kind!r}")
        s.faces.maxh = h_particle * rad
        solids.append(s)
    for br in bridges:
        axis = br.b - br.a
        length = float(np.linalg.norm(axis))
        if kind == "spheres":
            s = occ.Cylinder(occ.Pnt(br.a[0], br.a[1], 0.5 * gap),
                             occ.gp_Vec(axis[0] / length, axis[1] / length, 0.0),
                             br.radius, length)
        else:  # a slab through the gap
            n = np.array([-axis[1], axis[0]]) / length * br.radius
            s = _prism(occ, np.array([br.a - n, br.b - n, br.b + n, br.a + n]),
                       -margin, gap + margin)
        s.faces.maxh = h_particle * br.radius * 2
        solids.append(s)
    if not solids:
        return body
    solid = solids[0]
    for s in solids[1:]:
        solid = solid + s
    solid.faces.name = "particle"
    fluid = body - solid
    # Pockets sealed off by touching prisms and walls have no pressure level: keep
    # the pieces that reach the inlet or the outlet.
    pieces = fluid.solids
    keep = [p for p in pieces if any(f.name in ("inlet", "outlet") for f in p.faces)]
    if len(keep) < len(pieces):
        fluid = keep[0] if len(keep) == 1 else occ.Glue(keep)
    return fluid


def solid_half_thickness(xy, gap, centres, radii, bridges=(), kind="spheres"):
    """Half the thickness of solid in the column at each point (symmetric about mid-gap).

    Spheres and bridges are all centred at mid-gap, so the solid in a column is one
    segment ``|z - H/2| < c``; the fluid is ``[0, H/2 - c]`` and ``[H/2 + c, H]``.

    Parameters
    ----------
    xy : (n, 2) array_like
    gap : float
    centres, radii, bridges, kind : as :func:`pore_space`

    Returns
    -------
    numpy.ndarray, shape (n,)
        ``c`` in ``[0, H/2]`` (``H/2``: no fluid in the column).
    """
    p = np.asarray(xy, dtype=float).reshape(-1, 2)
    c = np.zeros(len(p))
    full = 0.5 * gap
    for centre, rad in zip(np.asarray(centres, dtype=float).reshape(-1, 2),
                           np.asarray(radii, dtype=float).ravel()):
        rho2 = np.sum((p - centre) ** 2, axis=1)
        inside = rho2 < rad * rad
        chord = full if kind == "prisms" else np.sqrt(np.maximum(rad * rad - rho2, 0.0))
        c = np.where(inside, np.maximum(c, chord), c)
    for br in bridges:
        axis = br.b - br.a
        length2 = float(axis @ axis)
        t = (p - br.a) @ axis / length2
        perp2 = np.sum((p - br.a - np.outer(t, axis)) ** 2, axis=1)
        inside = (t >= 0) & (t <= 1) & (perp2 < br.radius ** 2)
        chord = full if kind == "prisms" else np.sqrt(np.maximum(br.radius ** 2 - perp2, 0.0))
        c = np.where(inside, np.maximum(c, chord), c)
    return np.minimum(c, full)


def narrow_gaps(gap, centres, radii, walls, bridges=(), kind="spheres", below=1.0):
    """Thin films of fluid to mesh finer: ``(point, thickness)`` at the middle of each.

    Above and below every sphere (thickness ``(H - d) / 2``), and between two
    particles, or a particle and a side wall, closer than ``below`` times the
    smaller radius but not bridged.

    Returns
    -------
    list of (numpy.ndarray (3,), float)
    """
    x = np.asarray(centres, dtype=float).reshape(-1, 2)
    r = np.asarray(radii, dtype=float).ravel()
    mid = 0.5 * gap
    bridged = {tuple(b.between) for b in bridges}
    out = []
    for i in range(len(r)):
        if kind == "spheres":
            film = mid - r[i]
            for z in (0.5 * film, gap - 0.5 * film):
                out.append((np.array([x[i, 0], x[i, 1], z]), film))
        for j in range(i + 1, len(r)):
            d = float(np.linalg.norm(x[j] - x[i]))
            g = d - r[i] - r[j]
            if 0 < g < below * min(r[i], r[j]) and (i, j) not in bridged:
                p = x[i] + (r[i] + 0.5 * g) * (x[j] - x[i]) / d
                out.append((np.array([p[0], p[1], mid]), g))
        if len(walls) and (i, "wall") not in bridged:
            foot, dist = _nearest_on_segments(x[i], np.asarray(walls, dtype=float))
            g = dist - r[i]
            if 0 < g < below * r[i]:
                p = x[i] + (r[i] + 0.5 * g) * (foot - x[i]) / dist
                out.append((np.array([p[0], p[1], mid]), g))
    return out


def mesh_pore_space(shape, h_far, grading=0.3, curve_order=1, films=(), h_film=1.0):
    """Netgen tetrahedral mesh of :func:`pore_space`'s solid.

    Parameters
    ----------
    shape : occ shape
    h_far : float
        Largest element edge anywhere.
    films : list of (point, thickness)
        :func:`narrow_gaps`: the element size at each point is held to
        ``h_film`` times the film's thickness (and grows away from it at the
        ``grading`` rate).
    h_film : float
    grading : float
        Netgen's growth limit of the element size away from small features
        (0.3 is its default).
    curve_order : int
        Order of the geometry (1: straight tetrahedra, a sphere an inscribed
        polyhedron). Curving needs the films refined: on the hourglass's coarse
        mesh without them, order 2 left inflow and outflow at 0.67 and 0.45 (badly
        curved elements in the films between spheres and plates), with them the
        two balance; :class:`StokesSolution` reports both.

    Returns
    -------
    ngsolve.Mesh
    """
    ng, occ = require()
    from netgen.meshing import MeshingParameters
    mp = MeshingParameters(maxh=h_far, grading=grading)
    for point, thickness in films:
        mp.RestrictH(*(float(v) for v in point), h=min(h_film * thickness, h_far))
    mesh = ng.Mesh(occ.OCCGeometry(shape).GenerateMesh(mp=mp))
    if curve_order > 1:
        mesh.Curve(curve_order)
    return mesh


@dataclass
class StokesSolution:
    """A solved Stokes problem.

    Attributes
    ----------
    mesh : ngsolve.Mesh
    velocity, pressure : ngsolve.GridFunction
    flux_in, flux_out : float
        Volume flow through the inlet (inwards) and the outlet (outwards).
    ndof : int
        Unknowns of the mixed system (velocity and pressure).
    elements : int
        Tetrahedra.
    seconds : float
        Assembly and factorisation.
    idle_pressure : int
        Pressure unknowns no free velocity reaches (see :func:`solve_stokes`).
    """

    mesh: object
    velocity: object
    pressure: object
    flux_in: float
    flux_out: float
    ndof: int
    elements: int
    seconds: float
    idle_pressure: int = 0


def solve_stokes(mesh, viscosity, p_in, p_out, noslip="wall|plate|particle",
                 symmetry_y=None, order=2):
    """Taylor-Hood Stokes solve with the pressure given at the inlet and outlet.

    Parameters
    ----------
    mesh : ngsolve.Mesh
        Faces named ``inlet`` and ``outlet`` (see :func:`pore_space`).
    viscosity : float
        ``eta``.
    p_in, p_out : float
        Pressures (normal tractions ``-p n``) on ``inlet`` and ``outlet``.
    noslip : str
        Faces with ``u = 0``, as an NGSolve regular expression.
    symmetry_y : str, optional
        Faces normal to y on which only ``u_y = 0`` (free slip, no shear): a
        mirror plane, for the plane-Poiseuille check.
    order : int
        Velocity order ``k`` of the Taylor-Hood pair (P_k / P_(k-1)), ``k >= 2``.

    Returns
    -------
    StokesSolution

    Notes
    -----
    A pressure unknown all of whose elements have every velocity unknown on a
    no-slip face (a tetrahedron wedged into the corner where a plate meets a wall
    or a prism) appears in no equation: the matrix is singular (UMFPACK refuses
    it). Such unknowns are left out of the solve; afterwards a vertex value
    becomes the mean of its element neighbours' and a higher-order coefficient
    zero. The hourglass's prisms had 15 of 11,000 on the quick mesh.
    """
    ng, _ = require()
    t0 = time.perf_counter()
    side = noslip if symmetry_y is None else f"{noslip}|{symmetry_y}"
    V = ng.VectorH1(mesh, order=order, dirichletx=noslip, dirichlety=side,
                    dirichletz=noslip)
    Q = ng.H1(mesh, order=order - 1)
    X = V * Q
    (u, p), (v, q) = X.TnT()
    n = ng.specialcf.normal(3)
    a = ng.BilinearForm(X)
    a += (viscosity * ng.InnerProduct(ng.grad(u), ng.grad(v)) - ng.div(v) * p
          - ng.div(u) * q) * ng.dx
    a.Assemble()
    f = ng.LinearForm(X)
    f += -p_in * (v * n) * ng.ds("inlet") - p_out * (v * n) * ng.ds("outlet")
    f.Assemble()
    idle, neighbours = _idle_pressure(mesh, V, Q)
    free = ng.BitArray(X.FreeDofs())
    for k in idle:
        free.Clear(V.ndof + int(k))
    sol = ng.GridFunction(X)
    sol.vec.data = a.mat.Inverse(free, inverse="umfpack") * f.vec
    vel, pres = sol.components
    if len(idle):
        values = pres.vec.FV().NumPy()
        nv = mesh.nv
        for k in idle:
            near = [j for j in neighbours[k] if j < nv and j not in idle]
            values[k] = np.mean(values[near]) if (k < nv and near) else 0.0
    flux_in = -ng.Integrate(vel * n, mesh, definedon=mesh.Boundaries("inlet"))
    flux_out = ng.Integrate(vel * n, mesh, definedon=mesh.Boundaries("outlet"))
    return StokesSolution(mesh, vel, pres, float(flux_in), float(flux_out), X.ndof, mesh.ne,
                          time.perf_counter() - t0, len(idle))


def _idle_pressure(mesh, V, Q):
    """The pressure unknowns whose elements hold no free velocity unknown, and for
    each the pressure unknowns of the elements round it."""
    import ngsolve as ng
    free_v = np.array(list(V.FreeDofs()), dtype=bool)
    reached = np.zeros(Q.ndof, dtype=bool)
    for el in mesh.Elements(ng.VOL):
        if free_v[np.array(V.GetDofNrs(el))].any():
            reached[np.array(Q.GetDofNrs(el))] = True
    idle = set(np.flatnonzero(~reached).tolist())
    neighbours = {k: set() for k in idle}
    if idle:
        for el in mesh.Elements(ng.VOL):
            q = Q.GetDofNrs(el)
            for k in idle.intersection(q):
                neighbours[k].update(q)
    return idle, neighbours


def gap_average(solution, xy, gap, half_thickness, n_gauss=6):
    """Average of the Stokes pressure over the fluid part of the gap at each point.

    ``p_bar(x, y) = (1 / (H - 2c)) [int_0^(H/2-c) p dz + int_(H/2+c)^H p dz]`` with
    ``c`` the solid half-thickness; each of the two intervals by Gauss-Legendre
    with ``n_gauss`` points (exact for the P1 pressure within an element, and the
    pressure varies little across the gap). Quadrature points that the mesh does
    not contain (a hair outside its curved faces) are left out and the rest
    reweighted.

    Parameters
    ----------
    solution : StokesSolution
    xy : (n, 2) array_like
    gap : float
    half_thickness : (n,) array_like
        :func:`solid_half_thickness` at ``xy``.
    n_gauss : int

    Returns
    -------
    p_bar : numpy.ndarray, shape (n,)
        NaN where the column holds no fluid or no quadrature point was found.
    missed : float
        Fraction of the quadrature points not found in the mesh.
    """
    p = np.asarray(xy, dtype=float).reshape(-1, 2)
    c = np.asarray(half_thickness, dtype=float).ravel()
    g, w = np.polynomial.legendre.leggauss(n_gauss)
    film = 0.5 * gap - c                              # thickness of each interval
    lower = 0.5 * film[:, None] * (g[None, :] + 1.0)  # [0, film]
    z = np.concatenate([lower, gap - lower], axis=1)
    weight = np.concatenate([w, w])[None, :] * np.ones_like(z)
    use = np.broadcast_to((film > 1e-12 * gap)[:, None], z.shape)
    xs = np.broadcast_to(p[:, :1], z.shape)
    ys = np.broadcast_to(p[:, 1:], z.shape)
    values = np.full(z.shape, np.nan)
    idx = np.flatnonzero(use.ravel())
    found = np.zeros(z.size, dtype=bool)
    if idx.size:
        mips = solution.mesh(xs.ravel()[idx], ys.ravel()[idx], z.ravel()[idx])
        ok = mips["nr"] >= 0
        vals = np.asarray(solution.pressure(mips[ok])).ravel()
        flat = values.ravel()
        flat[idx[ok]] = vals
        values = flat.reshape(z.shape)
        found[idx[ok]] = True
    found = found.reshape(z.shape)
    wsum = np.where(found, weight, 0.0).sum(axis=1)
    pbar = np.where(wsum > 0, np.nansum(np.where(found, values * weight, 0.0), axis=1)
                    / np.where(wsum > 0, wsum, 1.0), np.nan)
    missed = 1.0 - found.sum() / max(int(use.sum()), 1)
    return pbar, float(missed)


# ------------------------------------------------- one sphere at mid-gap (two tools)

def mesh_label(h_far, h_part, h_film, order):
    """Element sizes and order as ``h_far/h_part/h_film P_order``."""
    return f"{h_far:g}/{h_part:g}/{h_film:g} P{order}"


class MeshSettings:
    """What the two tools' ``Settings`` share: element sizes ``h_far``, ``h_part``,
    ``h_film`` and the velocity ``order`` (attributes of the dataclass)."""

    def mesh_label(self):
        return mesh_label(self.h_far, self.h_part, self.h_film, self.order)

    def mesh_tag(self):
        """The sizes and order in a file name (the end of ``tag()``)."""
        return f"h{self.h_far:g}_{self.h_part:g}_{self.h_film:g}_p{self.order}"


def film_points(a, delta, h_film, phimax=math.pi, rings=8):
    """Points and sizes that cap the mesh over the lubrication film to the plate.

    For a sphere of radius ``a`` centred on the z axis whose apex is ``delta``
    from the plate ``z = 0``.

    Returns
    -------
    list of tuple
        ``(x, y, z, h)``. There are ``rings`` radii ``rho`` up to ``min(0.95 a,
        sqrt(8 a delta))``, each spread over the arc ``0 <= angle <= phimax`` (the
        half circle ``y >= 0`` by default) at mid-film height ``z = h(rho)/2``,
        with size ``h_film h(rho)``, ``h(rho) = delta + a - sqrt(a^2 - rho^2)``.
    """
    rho_max = min(0.95 * a, math.sqrt(8.0 * a * max(delta, 0.0)))
    out = []
    for rho in np.linspace(0.0, rho_max, rings):
        film = delta + a - math.sqrt(max(a * a - rho * rho, 0.0))
        size = h_film * film
        n_phi = int(math.ceil(phimax * rho / size)) + 1 if rho > 0 else 1
        for ang in np.linspace(0.0, phimax, n_phi):
            out.append((rho * math.cos(ang), max(rho * math.sin(ang), 0.0), 0.5 * film, size))
    return out


def sphere_box_mesh(s, ng, occ, lo, hi, faces, phimax=math.pi, periodic_x=False):
    """Curved tetrahedral mesh of the box ``lo``-``hi`` less the sphere of diameter
    ``s.dh`` centred at ``(0, 0, 1/2)`` (mid-gap of a cell ``H = 1``).

    Parameters
    ----------
    s : settings
        ``dh``; element sizes ``h_far`` (over ``H``), ``h_part`` (on the sphere,
        over its radius ``a``), ``h_film`` (over the film's local thickness, at
        :func:`film_points` with ``phimax``); ``order``, that of the geometry.
    ng, occ : modules
        :func:`require`'s.
    lo, hi : tuple of 3 float
        The box's corners.
    faces : tuple of 6 str
        Names of the box's faces x min, x max, y min, y max, z min, z max; the
        sphere's is ``particle``.
    periodic_x : bool
        Identify the fluid's x min and x max faces (periodic spaces).
    """
    from netgen.meshing import MeshingParameters  # present once require() passed

    a = 0.5 * s.dh
    box = occ.Box(occ.Pnt(*lo), occ.Pnt(*hi))
    for i, name in enumerate(faces):
        side = box.faces.Max if i % 2 else box.faces.Min
        side((occ.X, occ.Y, occ.Z)[i // 2]).name = name
    sphere = occ.Sphere(occ.Pnt(0, 0, 0.5), a)
    sphere.faces.name = "particle"
    sphere.faces.maxh = s.h_part * a
    fluid = box - sphere
    if periodic_x:
        fluid.faces.Min(occ.X).Identify(fluid.faces.Max(occ.X), "px",
                                        occ.IdentificationType.PERIODIC)
    mp = MeshingParameters(maxh=s.h_far, grading=0.3)
    for x, y, z, h in film_points(a, 0.5 - a, s.h_film, phimax):
        mp.RestrictH(x, y, z, h=h)
    mesh = ng.Mesh(occ.OCCGeometry(fluid).GenerateMesh(mp=mp))
    if s.order > 1:
        mesh.Curve(s.order)
    return mesh


def solve_fixed_moving(ng, X, form, inv, rhs, particle, unit):
    """The held and the moving sphere's problems on one factorisation.

    Parameters
    ----------
    X : ngsolve space
        Velocity first (``components[0]``).
    form : ngsolve.BilinearForm
        Assembled; ``inv`` its inverse on ``X.FreeDofs()``.
    rhs : dict
        ``{"fixed": LinearForm, "moving": LinearForm}``, assembled here.
    particle : ngsolve region
        The sphere's faces.
    unit : ngsolve.CoefficientFunction
        The moving sphere's velocity, ``e_x`` (on ``components[0]``).

    Returns
    -------
    fields : dict
        ``{"fixed": GridFunction, "moving": GridFunction}``.
    w : ngsolve.GridFunction
        ``unit`` on the sphere's degrees of freedom, zero elsewhere (the reaction
        force's test field).
    """
    for f in rhs.values():
        f.Assemble()
    fields = {}
    for key in ("fixed", "moving"):
        g = ng.GridFunction(X)
        if key == "moving":
            g.components[0].Set(unit, definedon=particle)
        res = rhs[key].vec.CreateVector()
        res.data = rhs[key].vec - form.mat * g.vec
        g.vec.data += inv * res
        fields[key] = g
    w = ng.GridFunction(X)
    w.components[0].Set(unit, definedon=particle)
    return fields, w


def run_sphere(s, threads, verbose, build_mesh, solve, note="", labels=None):
    """Mesh and solve one run of either tool; returns the JSON-ready record.

    ``build_mesh(s, ng, occ)`` meshes (``verbose``: a line with the tets and the
    seconds, headed ``note``); ``solve(mesh, ng)`` returns the run's results (a
    dict) and the solve's ``info`` (with ``ndof``). To the results are added
    ``settings`` (``asdict(s)``), ``mesh`` (``s.mesh_label()``), ``labels``,
    ``ndof``, ``solve`` (``info``), ``t_mesh`` and ``wall_s``.
    """
    ng, occ = require(threads)
    t0 = time.perf_counter()
    mesh = build_mesh(s, ng, occ)
    t_mesh = time.perf_counter() - t0
    if verbose:
        print(f"  {note}mesh {mesh.ne} tets, {t_mesh:.1f} s", flush=True)
    out, info = solve(mesh, ng)
    out.update(settings=asdict(s), mesh=s.mesh_label(), **(labels or {}), ndof=info["ndof"],
               solve=info, t_mesh=t_mesh, wall_s=time.perf_counter() - t0)
    return out


def cached_run(s, runs_dir, run, summary):
    """``run(s)``, or the JSON of an earlier run of the same settings in ``runs_dir``.

    Parameters
    ----------
    s : dataclass
        The settings; ``s.tag()`` names the JSON, which is reused only when its
        ``settings`` are ``asdict(s)``.
    runs_dir : path or None
        The cache (``None``: none, always solve).
    run : callable
        ``run(s)`` solves, returning a JSON-ready dict with ``ndof`` and ``wall_s``.
    summary : str
        A format of the run's keys, printed with ``ndof`` and the seconds after a
        new solve.
    """
    path = None
    if runs_dir is not None:
        path = pathlib.Path(runs_dir) / f"{s.tag()}.json"
        if path.exists():
            rec = json.loads(path.read_text())
            if rec.get("settings") == asdict(s):
                return rec
    print(f"solving {s.tag()}", flush=True)
    rec = run(s)
    print(f"  {summary.format_map(rec)}  ndof {rec['ndof']}  {rec['wall_s']:.0f} s", flush=True)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(rec, indent=1))
    return rec


def print_run(rec, summary, out=None):
    """Print a single run's ``summary`` (a dict) as JSON; write its whole record
    ``rec`` to the file ``out`` (JSON) when given."""
    print(json.dumps(summary, indent=1))
    if out:
        pathlib.Path(out).write_text(json.dumps(rec, indent=1))


def write_table(path, comments, columns, rows):
    """Write a CSV: each of ``comments`` on a line ``# ...``, the ``columns``, the ``rows``
    (lists of cells, written as given)."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        for line in comments:
            fh.write(f"# {line}\n")
        wr = csv.writer(fh, lineterminator="\n")
        wr.writerow(columns)
        wr.writerows(rows)


def read_table(path, text=()):
    """A CSV of :func:`write_table`'s as a list of rows in file order: dicts of floats,
    but the strings of the columns ``text``."""
    with open(path) as fh:
        return [{k: (v if k in text else float(v)) for k, v in row.items()}
                for row in csv.DictReader(line for line in fh if not line.startswith("#"))]


def add_run_options(ap, presets, data_csv, table, axis, label, checks):
    """The single run's and the table's options of both tools' command lines.

    ``--quick --preset --out``, then ``--table --checks --table-<axis> --csv
    --runs``: ``table`` names the tool's list of the table's values of ``label``
    (``--table-<axis>`` replaces it), ``checks`` what ``--checks`` adds, and
    ``data_csv`` is ``--csv``'s default.
    """
    ap.add_argument("--quick", action="store_true", help="the coarse 'quick' preset")
    ap.add_argument("--preset", choices=sorted(presets), help="a named preset (default table)")
    ap.add_argument("--out", help="JSON of a single run")
    ap.add_argument("--table", action="store_true", help=f"solve {table} and write the CSV")
    ap.add_argument("--checks", action="store_true", help=f"with --table: {checks}")
    ap.add_argument(f"--table-{axis}",
                    help=f"with --table: comma-separated {label} instead of {table}")
    ap.add_argument("--csv", default=str(data_csv), help="with --table (%(default)s)")
    ap.add_argument("--runs", help="folder for each solve's JSON (reused when settings match)")


def add_mesh_options(ap):
    """The element-size, order and thread options of both tools' command lines."""
    ap.add_argument("--hfar", type=float, help="element size far away / H")
    ap.add_argument("--hpart", type=float, help="on the sphere / a")
    ap.add_argument("--hfilm", type=float, help="in the film / local film thickness")
    ap.add_argument("--order", type=int, help="velocity order k (P_k/P_(k-1))")
    ap.add_argument("--threads", type=int, default=1, help="NGSolve threads (%(default)s)")


def extra_missing(tool, threads):
    """:func:`require` with ``threads``; ``True`` (after one line on stderr, headed
    ``tool``) when NGSolve is missing."""
    try:
        require(threads)
    except MissingExtra as exc:
        print(f"{tool}: {exc}", file=sys.stderr)
        return True
    return False
