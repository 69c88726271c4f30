"""A three-sphere arch across the vani funnel: 3D Stokes forces and torques against Darcy.

The 2D model's arch of three disks across the 45-degree funnel of
``scenes/vani_phi026.toml`` narrowed to ``W = 2.2 d`` (``geometry.constriction_width
= 308e-6``; the funnel's upper wall is the line ``x + y = c``, ``c = 3.5 mm``, the
lower one ``x - y = c``, the neck at ``x = 3.346 mm``) is statically admissible but
has one mechanism: the middle disk translates sideways and turns against the outer
two, every contact rolling without slip. The 2D pressure gives a circle no moment,
so nothing but the forces' change acts along it. This tool asks what 3D Stokes
gives on spheres (diameter ``d``, radius ``a = d/2``, at mid-gap of the cell of gap
``H``) in the same places.

Set-up
------
*Arch* (``beta = 20`` degrees, surface gap ``g`` at every contact, spheres and
funnel walls): middle sphere at ``(x_m, y_m)``, outer ones on the lines
``a + g`` from the walls, ``2a + g`` from the middle one. Symmetric arch:
``y_m = 0``, ``x_m = c - sqrt(2) (a + g) - (2a + g)(sin beta + cos beta)``, the
outer ones at ``x_m + (2a + g) sin beta, +-(2a + g) cos beta`` (``g = 0``: the 2D
probe's touching arch). *Displaced* arch (the antisymmetric mode): the middle
sphere moved sideways to ``y_m = delta`` at the same ``x_m``, each outer one slid
along its wall line until its gap to the middle one is ``g`` again.

*3D Stokes* (:mod:`stokes_fem`): the scene's outline cut to ``x_neck - L_up d <=
x <= x_neck + L_down d``, extruded over the half-gap ``0 <= z <= H/2`` (the mid
plane is a mirror plane of flow in the plane past spheres at mid-gap, and of
spins about ``z``: ``u_z = 0`` and no shear there), less the spheres (no bridges:
every gap is open). No slip on the plate, the walls and the spheres; the ends
carry the traction ``sigma n = -p_b n``. The symmetric-stress form ``2 eta
e(u) : e(v)`` is used, so that the consistent reaction is the Cauchy traction's
force and moment even on a spinning sphere (the gradient form's would be off by
``2 eta V Omega``, a third of ``8 pi eta a^3 Omega``, on the spinning sphere
itself). Taylor-Hood P_k/P_(k-1) (``k = 2`` by default), geometry curved to
order ``k``, UMFPACK; one factorisation serves four problems:

* ``flow``: the spheres held, a pressure drop across the ends;
* ``spin_<s>``: sphere ``s`` spinning at ``Omega`` about ``z`` (``u = Omega
  e_z x (x - x_s)`` on it), the others held, fluid at rest at both ends.

The mesh is capped at ``h_far H`` everywhere, ``h_part a`` on the spheres and
``h_film`` times the local thickness of every thin film: the sphere-plate film
``(H - d)/2`` and the sphere-sphere and sphere-wall gaps ``g``, each over the
whole lubrication disc ``rho <= min(0.95 a, sqrt(8 a delta))``
(:func:`stokes_fem.film_points` rotated onto each gap).

*Loads*: force ``(F_x, F_y)`` and torque ``T`` (about ``z`` through the sphere's
centre) on each sphere from the consistent reaction (the residual of the weak
form against the rigid motion ``e_x``, ``e_y`` or ``e_z x (x - x_s)`` on that
sphere's degrees of freedom, doubled for the half-gap).

*2D Darcy*: the same centres as disks in a copy of the scene (written to a
temporary folder, ``feed.mode = "none"``, ``[[particles]] positions``),
``Simulation.update_fluid(force=True)`` and ``fluid_forces()``: the pressure
force and moment on each disk at the scene's flow rate, on its grid
(``fluid.cell_size`` auto, ``d/6``, and ``--cell2d`` finer as a check).

Units and what is reported
--------------------------
Both models are brought to the same flow rate ``Q`` through the cell and
normalised by ``F* = 12 pi eta Q a^2 / (H^2 W)`` (the Hele-Shaw gradient at the
neck times a disk's volume ``pi a^2 H``): forces as ``F/F*``, torques as
``T / (a F*)``. The spin problems give the rotational resistance matrix
``T_i = -K_ij Omega_j`` in units of ``8 pi eta a^3`` (1 for a sphere in unbounded
fluid; ``K_ii`` the sphere's own, ``K_ij`` its neighbours').

From the loads, for each configuration and model:

* ``T/aF``: torque over ``a |F|``;
* the contact forces of the rigid arch in equilibrium under the fluid loads
  (four contacts, normal ``N`` and tangential ``t`` each: 8 unknowns, 9
  equations; least squares), the largest ``|t|/N`` and, per sphere,
  ``T / (mu a N_max)`` with ``mu = 0.25`` and ``N_max`` its largest contact force;
* the mechanism: the rolling velocities ``(v_s, omega_s)`` of the three spheres
  (no relative velocity at any contact point, the mid-point of each gap) per
  unit sideways speed of the middle sphere, and the fluid loads' power along it,
  ``P = sum F_s . v_s + T_s omega_s``, in units of ``F*`` (``P_T``: the torques'
  share). ``P = 0`` is the condition for the rigid arch to be in equilibrium at
  all (it is the 9th equation's residual); at the displaced arch (``delta > 0``)
  ``P < 0`` pushes it back (restoring), ``P > 0`` further (destabilising).

Usage
-----
::

    python tools/stokes_arch.py [--quick] [--out runs/stokes_arch/arch.csv]
        [--gaps 0.05,0.02] [--delta 0.05] [--mesh default|fine|quick]
        [--check-mesh] [--check-order] [--check-domain] [--cell2d 3] [--no-2d]
        [--ends 3] [--runs DIR] [--threads N]

Solves the symmetric and the displaced arch (``--delta`` over ``d``; 0: the
symmetric one only) at every gap (``--gaps`` over ``d``) and the 2D model at the
same centres (on its grid and on one ``--cell2d`` times finer). The checks solve
both arches at the first gap again: ``--check-mesh`` on the ``fine`` mesh,
``--check-order`` with P3/P2 on the same mesh, ``--check-domain`` with the ends
5 d from the neck instead of 3 d (``--ends``: of every solve; the spheres must
lie between them: ``--gaps 1 --delta 0 --ends 7 --no-2d`` puts the spheres a
diameter apart, whose spin coefficients are then near a lone sphere's). Prints
the table and the statics, writes the
CSV (default ``runs/stokes_arch/arch.csv``, one row per sphere, columns
:data:`COLUMNS`); each 3D solve's JSON is kept in ``--runs`` (default
``solves/`` beside the CSV) and reused when its settings match. ``--quick``: the
coarse mesh and the first gap (about 15 s). Exit 2 (one line) when NGSolve is
missing.

Cost, one thread on a shared two-core machine: 10 s a solve (four problems,
90,000 unknowns) on the default mesh, 50 s on the fine one (290,000), the whole
run with the three checks about six minutes.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import pathlib
import sys
import tempfile
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import stokes_fem  # noqa: E402  (require(): the only way NGSolve is imported)

SCENE = ROOT / "scenes" / "vani_phi026.toml"
OVERRIDES = ("geometry.constriction_width=308e-6",)
BETA = 20.0            # degrees
MU = 0.25              # the scene's friction
SPHERES = ("m", "up", "low")
PAIR = ("up", "low")     # --config pair: the two spheres of the held pair


def names(n):
    """The spheres' names: three (the arch) or two (the pair)."""
    return SPHERES if n == 3 else PAIR
DEFAULT_OUT = ROOT / "runs" / "stokes_arch" / "arch.csv"

# Mesh presets: h_far over H, h_part over a, h_film over the film's thickness.
# Netgen's surface mesher of the OCC spheres follows their own cap (h_part) more
# than the films' local sizes, so h_part sets the films' resolution on the spheres.
MESHES = {
    "default": dict(h_far=0.5, h_part=0.1, h_film=0.7, order=2),
    "fine": dict(h_far=0.4, h_part=0.07, h_film=0.5, order=2),
    "quick": dict(h_far=0.7, h_part=0.2, h_film=1.0, order=2),
}


# ----------------------------------------------------------------------- geometry

@dataclasses.dataclass(frozen=True)
class Cell:
    """The scene's numbers (SI) and the funnel's outline."""

    d: float
    H: float
    eta: float
    Q: float
    W: float
    c: float
    x_neck: float
    outline: tuple

    @property
    def a(self):
        return 0.5 * self.d

    @property
    def force_scale(self):
        """``F* = 12 pi eta Q a^2 / (H^2 W)``, N."""
        return 12.0 * math.pi * self.eta * self.Q * self.a ** 2 / (self.H ** 2 * self.W)


def load_cell(scene_path=SCENE, overrides=OVERRIDES):
    """The scene's constants and resolved outline (``taichi_hsdem.resolve``)."""
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import resolve
    m = resolve(load_scene(scene_path, list(overrides)))
    sc = m.scene
    outline = np.asarray(m.geometry.outline, dtype=float)
    # upper funnel wall: the edge that descends at 45 degrees to the neck
    p, q = outline, np.roll(outline, -1, axis=0)
    slope = [(i, (q[i, 1] - p[i, 1]) / (q[i, 0] - p[i, 0]))
             for i in range(len(p)) if abs(q[i, 0] - p[i, 0]) > 1e-12]
    i = next(k for k, s in slope if abs(s + 1.0) < 1e-6 and p[k, 1] > 0)
    c = float(p[i, 0] + p[i, 1])
    x_neck = float(max(p[i, 0], q[i, 0]))
    d = float(sc.particles[0].diameter)
    return Cell(d=d, H=float(sc.fluid.gap), eta=float(sc.fluid.viscosity),
                Q=float(sc.fluid.flow_rate), W=float(m.geometry.constriction_width), c=c,
                x_neck=x_neck, outline=tuple(map(tuple, outline)))


WALL_N = {"up": np.array([1.0, 1.0]) / math.sqrt(2.0),     # from the sphere to its wall
          "low": np.array([1.0, -1.0]) / math.sqrt(2.0)}


def arch(cell: Cell, gap, delta=0.0, beta=BETA):
    """Centres ``(3, 2)`` (m, up, low) of the arch with surface gaps ``gap`` (m)
    and the middle sphere ``delta`` (m) sideways (module docstring)."""
    a, b, c = cell.a, math.radians(beta), cell.c
    s = 2 * a + gap
    xm = c - math.sqrt(2.0) * (a + gap) - s * (math.sin(b) + math.cos(b))
    m = np.array([xm, delta])
    out = [m]
    for name, sign in (("up", 1.0), ("low", -1.0)):
        n = WALL_N[name]
        t = np.array([-n[1], n[0]])                  # along the wall line
        base = np.array([xm + s * math.sin(b), sign * s * math.cos(b)])  # symmetric place
        # |base + u t - m| = s: the root nearest u = 0
        r = base - m
        B, C = 2 * r @ t, r @ r - s * s
        roots = np.array([(-B + sg * math.sqrt(B * B - 4 * C)) / 2 for sg in (1, -1)])
        u = roots[np.argmin(np.abs(roots))]
        out.append(base + u * t)
    return np.array(out)


def pair(cell: Cell, gap):
    """Centres ``(2, 2)`` (up, low) of the symmetric held pair at the neck: the two
    spheres ``gap`` (m) apart across the axis and ``gap`` from their funnel walls."""
    a, c = cell.a, cell.c
    y = a + 0.5 * gap
    xp = c - y - math.sqrt(2.0) * (a + gap)
    return np.array([[xp, y], [xp, -y]])


def contacts(cell: Cell, x):
    """The contacts (four of the arch, three of the pair): ``(i, j, n, p)``: bodies
    (``j = None``: a wall), unit normal from ``i`` to ``j``, contact point (the gap's
    mid-point), all in the plane."""
    out = []
    nm = names(len(x))
    for i, j in (((0, 1), (0, 2)) if len(x) == 3 else ((0, 1),)):
        n = (x[j] - x[i]) / np.linalg.norm(x[j] - x[i])
        out.append((i, j, n, 0.5 * (x[i] + cell.a * n + x[j] - cell.a * n)))
    for j, name in ((nm.index("up"), "up"), (nm.index("low"), "low")):
        n = WALL_N[name]
        dist = abs(n @ x[j] - cell.c / math.sqrt(2.0))
        out.append((j, None, n, x[j] + (cell.a + 0.5 * (dist - cell.a)) * n))
    return out


def _cross(r, f):
    return r[0] * f[1] - r[1] * f[0]


def statics(cell: Cell, x, F, T, mu=MU):
    """Contact forces of the rigid arch under the fluid loads, the mechanism and its power.

    Parameters
    ----------
    x : (3, 2) centres, m; F : (3, 2) forces; T : (3,) torques over ``a`` (in the
    force's unit: ``T/(a F*)`` with ``F/F*``).

    Returns
    -------
    dict
        ``N``, ``t`` (4 each: m-up, m-low, up-wall, low-wall; ``N > 0``
        compressive), ``slip_max`` (largest ``|t|/N``), ``N_max`` per sphere,
        ``residual`` (the equilibrium's, over ``max |F|``), the mechanism
        ``v`` (3, 2) and ``omega`` (3,) (over ``1/a``) per unit sideways speed
        of the middle sphere, ``P`` and ``P_T`` (the loads' power along it; the torques' part).
    """
    cs = contacts(cell, x)
    nb = len(x)
    A = np.zeros((3 * nb, 2 * len(cs)))       # rows: (Fx, Fy, M) of each sphere
    for k, (i, j, n, p) in enumerate(cs):
        tau = np.array([-n[1], n[0]])
        for body, sg in ((i, -1.0), (j, 1.0)):   # on i: -N n + t tau; on j: opposite
            if body is None:
                continue
            r = (p - x[body]) / cell.a            # lever arms in units of a
            A[3 * body:3 * body + 2, 2 * k] += sg * n
            A[3 * body + 2, 2 * k] += sg * _cross(r, n)
            A[3 * body:3 * body + 2, 2 * k + 1] -= sg * tau
            A[3 * body + 2, 2 * k + 1] -= sg * _cross(r, tau)
    load = np.concatenate([np.r_[F[s], T[s]] for s in range(nb)])
    sol, *_ = np.linalg.lstsq(A, -load, rcond=None)
    N, t = sol[0::2], sol[1::2]
    resid = float(np.linalg.norm(A @ sol + load) / np.abs(F).max())
    if nb == 3:
        # mechanism: the velocities (v, omega) doing no work on any contact force
        _, _, vt = np.linalg.svd(A.T)
        mode = vt[-1]
        mode = mode / mode[1]                      # v_y of the middle sphere = 1
        v = np.stack([mode[3 * s:3 * s + 2] for s in range(3)])
        om = np.array([mode[3 * s + 2] for s in range(3)])
    else:                   # the pair: 6 equations, 6 unknowns, no mechanism
        v, om = np.zeros((nb, 2)), np.zeros(nb)
    PF = float(np.sum(F * v))
    PT = float(np.sum(T * om))
    Nmax = [max(N[k] for k, c in enumerate(cs) if s in (c[0], c[1])) for s in range(nb)]
    return {"N": N.tolist(), "t": t.tolist(), "slip_max": float(np.max(np.abs(t) / N)),
            "N_max": Nmax, "residual": resid, "v": v.tolist(), "omega": om.tolist(),
            "P": PF + PT, "P_T": PT, "mu": mu}


# -------------------------------------------------------------------------- 3D mesh

@dataclasses.dataclass(frozen=True)
class Settings:
    """One 3D solve. ``gap``, ``delta``, ``L_up``, ``L_down`` over ``d``."""

    gap: float
    delta: float = 0.0
    L_up: float = 3.0
    L_down: float = 3.0
    h_far: float = 0.5
    h_part: float = 0.25
    h_film: float = 0.7
    order: int = 2
    config: str = "arch"     # or "pair" (the scene's own width, no override)

    def asdict(self):
        """The settings as stored with a solve (the arch's without ``config``, as before)."""
        out = dataclasses.asdict(self)
        if self.config == "arch":
            out.pop("config")
        return out

    def mesh_label(self):
        return stokes_fem.mesh_label(self.h_far, self.h_part, self.h_film, self.order)

    def tag(self):
        return (f"g{self.gap:g}_dl{self.delta:g}_L{self.L_up:g}-{self.L_down:g}_"
                f"h{self.h_far:g}_{self.h_part:g}_{self.h_film:g}_p{self.order}"
                + ("" if self.config == "arch" else f"_{self.config}"))


def clip_x(poly, x0, x1):
    """The polygon ``poly`` cut to ``x0 <= x <= x1`` (Sutherland-Hodgman)."""
    def clip(pts, keep, cut):
        out = []
        for k in range(len(pts)):
            p, q = pts[k], pts[(k + 1) % len(pts)]
            if keep(p):
                out.append(p)
            if keep(p) != keep(q):
                s = (cut - p[0]) / (q[0] - p[0])
                out.append(p + s * (q - p))
        return out
    pts = [np.asarray(p, float) for p in poly]
    pts = clip(pts, lambda p: p[0] >= x0, x0)
    pts = clip(pts, lambda p: p[0] <= x1, x1)
    out = [pts[0]]
    for p in pts[1:]:
        if np.linalg.norm(p - out[-1]) > 1e-12:
            out.append(p)
    return np.array(out)


def gap_films(centre, normal, a, delta, zmid, rings=8):
    """:func:`stokes_fem.film_points` of a sphere (centre, radius ``a``) over a flat
    film ``delta`` thick, whose plane has the unit ``normal`` (3,) pointing to the
    sphere; points above ``z = zmid`` dropped. Returns ``(point, thickness)``."""
    n = np.asarray(normal, float)
    e1 = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    foot = np.asarray(centre, float) - (a + delta) * n
    out = []
    for px, py, pz, h in stokes_fem.film_points(a, delta, 1.0, phimax=2 * math.pi,
                                                 rings=rings):
        q = foot + px * e1 + py * e2 + pz * n
        if -1e-9 <= q[2] <= zmid + 1e-9:
            out.append((q, h))
    return out


def build_mesh(s: Settings, cell: Cell, x, ng, occ):
    """Curved mesh of the half-gap pore space (units ``H = 1``); faces ``inlet``,
    ``outlet``, ``plate``, ``wall``, ``mid``, ``p0`` ``p1`` ``p2`` (the spheres)."""
    H = cell.H
    a = cell.a / H
    xs = np.asarray(x) / H
    poly = clip_x(np.asarray(cell.outline) / H, (cell.x_neck - s.L_up * cell.d) / H,
                  (cell.x_neck + s.L_down * cell.d) / H)
    full = stokes_fem.pore_space(poly, 1.0, xs, [a] * len(xs), h_particle=s.h_part)
    lo, hi = poly.min(axis=0) - 1.0, poly.max(axis=0) + 1.0
    half = occ.Box(occ.Pnt(lo[0], lo[1], -1.0), occ.Pnt(hi[0], hi[1], 0.5))
    half.faces.Max(occ.Z).name = "mid"
    fluid = full * half
    for f in fluid.faces:
        if f.name == "particle":
            cx, cy, _ = f.center
            f.name = f"p{int(np.argmin(np.hypot(xs[:, 0] - cx, xs[:, 1] - cy)))}"
    films = []
    for k in range(len(xs)):                             # sphere-plate film
        films += gap_films((xs[k, 0], xs[k, 1], 0.5), (0, 0, 1), a, 0.5 - a, 0.5)
    for i, j, n, p in contacts(cell, np.asarray(x)):
        if j is None:                                    # sphere-wall gap
            g = (abs(n @ np.asarray(x[i]) - cell.c / math.sqrt(2.0)) - cell.a) / H
            films += gap_films((xs[i, 0], xs[i, 1], 0.5), (-n[0], -n[1], 0), a, g, 0.5)
        else:                                            # sphere-sphere: both halves
            g = (np.linalg.norm(np.asarray(x[j]) - x[i]) - 2 * cell.a) / H
            for k, sg in ((i, -1.0), (j, 1.0)):
                films += [(q, 2 * h) for q, h in
                          gap_films((xs[k, 0], xs[k, 1], 0.5), (sg * n[0], sg * n[1], 0), a,
                                    0.5 * g, 0.5)]
    mesh = stokes_fem.mesh_pore_space(fluid, s.h_far, curve_order=s.order, films=films,
                                      h_film=s.h_film)
    return mesh, xs


# ------------------------------------------------------------------------- 3D solve

def solve3d(s: Settings, cell: Cell, threads=1, verbose=True):
    """Mesh, factorise once, solve ``flow`` and the three ``spin`` problems; the
    loads on each sphere (units ``H = eta = 1``, pressure drop 1, ``Omega = 1``)."""
    ng, occ = stokes_fem.require(threads)
    x = (arch(cell, s.gap * cell.d, s.delta * cell.d) if s.config == "arch"
         else pair(cell, s.gap * cell.d))
    nb = len(x)
    t0 = time.perf_counter()
    mesh, xs = build_mesh(s, cell, x, ng, occ)
    t_mesh = time.perf_counter() - t0
    if verbose:
        print(f"  mesh {mesh.ne} tets, {t_mesh:.0f} s", flush=True)
    walls = "plate|wall|" + "|".join(f"p{k}" for k in range(nb))
    V = ng.VectorH1(mesh, order=s.order, dirichletx=walls, dirichlety=walls,
                    dirichletz=walls + "|mid")
    Q = ng.H1(mesh, order=s.order - 1)
    X = V * Q
    (u, p), (v, q) = X.TnT()
    n = ng.specialcf.normal(3)
    form = ng.BilinearForm(X)
    form += (2.0 * ng.InnerProduct(ng.Sym(ng.grad(u)), ng.Sym(ng.grad(v)))
             - ng.div(v) * p - ng.div(u) * q) * ng.dx
    form.Assemble()
    t1 = time.perf_counter()
    # pressure unknowns no free velocity reaches (tetrahedra wedged where the plate
    # meets a wall) appear in no equation: left out, as stokes_fem.solve_stokes does
    idle, _ = stokes_fem._idle_pressure(mesh, V, Q)
    free = ng.BitArray(X.FreeDofs())
    for k in idle:
        free.Clear(V.ndof + int(k))
    inv = form.mat.Inverse(free, inverse="umfpack")
    t2 = time.perf_counter()
    if verbose:
        print(f"  ndof {X.ndof} ({len(idle)} idle pressure), assembled "
              f"{t1 - t0 - t_mesh:.0f} s, factorised {t2 - t1:.0f} s", flush=True)

    def rigid(k, what):
        cx, cy = xs[k]
        return {"Fx": ng.CF((1, 0, 0)), "Fy": ng.CF((0, 1, 0)),
                "T": ng.CF((-(ng.y - cy), ng.x - cx, 0))}[what]

    tests = {}
    for k in range(nb):
        for what in ("Fx", "Fy", "T"):
            w = ng.GridFunction(X)
            w.components[0].Set(rigid(k, what), definedon=mesh.Boundaries(f"p{k}"))
            tests[k, what] = w
    out = {}
    for prob in ("flow",) + tuple(f"spin_{nm}" for nm in names(nb)):
        f = ng.LinearForm(X)
        if prob == "flow":
            f += -1.0 * (v * n) * ng.ds("inlet")
        f.Assemble()
        g = ng.GridFunction(X)
        if prob != "flow":
            k = names(nb).index(prob[5:])
            g.components[0].Set(rigid(k, "T"), definedon=mesh.Boundaries(f"p{k}"))
        res = f.vec.CreateVector()
        res.data = f.vec - form.mat * g.vec
        g.vec.data += inv * res
        r = g.vec.CreateVector()
        r.data = form.mat * g.vec - f.vec
        loads = np.array([[-2.0 * ng.InnerProduct(r, tests[k, w].vec) for w in ("Fx", "Fy", "T")]
                          for k in range(nb)])
        vel = g.components[0]
        flux = [2.0 * float(ng.Integrate(vel * n, mesh, ng.BND,
                                         definedon=mesh.Boundaries(b))) for b in ("inlet",
                                                                                  "outlet")]
        out[prob] = {"loads": loads.tolist(), "flux_in": -flux[0], "flux_out": flux[1]}
    return {"settings": s.asdict(), "mesh": s.mesh_label(), "ndof": X.ndof,
            "elements": mesh.ne, "idle_pressure": len(idle), "centres": x.tolist(),
            "t_mesh": t_mesh,
            "t_factor": t2 - t1, "wall_s": time.perf_counter() - t0, "problems": out}


def cached3d(s: Settings, cell: Cell, runs_dir, threads):
    """:func:`solve3d`, or the JSON of an earlier solve of the same settings."""
    path = pathlib.Path(runs_dir) / f"{s.tag()}.json"
    if path.exists():
        rec = json.loads(path.read_text())
        if rec.get("settings") == s.asdict():
            return rec
    print(f"solving {s.tag()}", flush=True)
    rec = solve3d(s, cell, threads)
    print(f"  ndof {rec['ndof']}  {rec['wall_s']:.0f} s", flush=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(rec, indent=1))
    return rec


def loads3d(rec, cell: Cell):
    """Forces ``F/F*`` (3, 2), torques ``T/(a F*)`` (3,) at the scene's flow rate, and
    the spin matrix ``K`` (3, 3) over ``8 pi eta a^3`` (``K[i, j]``: torque on ``i``
    against a unit spin of ``j``)."""
    H = cell.H
    a, W = cell.a / H, cell.W / H
    fl = rec["problems"]["flow"]
    q = 0.5 * (fl["flux_in"] + fl["flux_out"])               # per unit pressure drop
    fstar = 12.0 * math.pi * q * a ** 2 / W                  # F* at that flux (eta = H = 1)
    L = np.asarray(fl["loads"])
    nm = names(len(L))
    K = np.array([[-rec["problems"][f"spin_{sj}"]["loads"][i][2] for sj in nm]
                  for i in range(len(L))]) / (8.0 * math.pi * a ** 3)
    return L[:, :2] / fstar, L[:, 2] / (a * fstar), K, q


# ------------------------------------------------------------------------- 2D model

def loads2d(cell: Cell, x, cell_size=None, scene_path=SCENE, overrides=OVERRIDES):
    """Darcy pressure force ``F/F*`` (3, 2) and moment ``T/(a F*)`` (3,) on disks at ``x``."""
    import taichi_hsdem as th
    text = pathlib.Path(scene_path).read_text()
    pos = "[" + ", ".join(f"[{float(p[0])!r}, {float(p[1])!r}]" for p in np.asarray(x)) + "]"
    for old, new in (("packing_fraction = 0.26", f"positions = {pos}"),
                     ('mode = "count"', 'mode = "none"')):
        if old not in text:
            raise RuntimeError(f"{scene_path}: no line {old!r} to replace")
        text = text.replace(old, new)
    over = list(overrides) + ["run.realizations=1"]
    if cell_size:
        over.append(f"fluid.cell_size={cell_size!r}")
    with tempfile.TemporaryDirectory() as tmp:
        path = pathlib.Path(tmp) / "arch.toml"
        path.write_text(text)
        sim = th.Simulation(th.load_scene(path, over))
    sim.update_fluid(force=True)
    f, tau = sim.fluid_forces()
    fs = cell.force_scale
    return f[0] / fs, tau[0] / (cell.a * fs)


# ------------------------------------------------------------------------ reporting

COLUMNS = ("config", "gap_over_d", "delta_over_d", "model", "mesh", "ndof", "sphere",
           "x_over_d", "y_over_d", "Fx", "Fy", "T", "T_over_aF", "T_over_mu_aNmax",
           "slip_max", "P", "P_T", "omega_mode", "K_m", "K_up", "K_low")


def rows_for(config, s_gap, s_delta, model, mesh, ndof, cell, x, F, T, K=None):
    st = statics(cell, x, F, T)
    rows = []
    nm = names(len(x))
    for k, name in enumerate(nm):
        Fm = float(np.hypot(*F[k]))
        rows.append({
            "config": config, "gap_over_d": s_gap, "delta_over_d": s_delta, "model": model,
            "mesh": mesh, "ndof": ndof, "sphere": name,
            "x_over_d": (x[k][0] - cell.x_neck) / cell.d, "y_over_d": x[k][1] / cell.d,
            "Fx": F[k][0], "Fy": F[k][1], "T": T[k], "T_over_aF": T[k] / Fm,
            "T_over_mu_aNmax": T[k] / (MU * st["N_max"][k]), "slip_max": st["slip_max"],
            "P": st["P"], "P_T": st["P_T"], "omega_mode": st["omega"][k],
            **{f"K_{sj}": ("" if K is None or sj not in nm else K[k, nm.index(sj)])
               for sj in SPHERES}})
    return rows, st


def fmt(v):
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="coarse mesh, one gap")
    ap.add_argument("--config", choices=("arch", "pair"), default="arch",
                    help="the arch of three at W = 2.2 d (default) or the held pair at "
                         "the scene's own W = 1.7 d (no displaced case)")
    ap.add_argument("--gaps", default="0.05,0.02", help="surface gaps over d (%(default)s)")
    ap.add_argument("--delta", type=float, default=0.05,
                    help="sideways displacement of the middle sphere over d (%(default)s)")
    ap.add_argument("--mesh", choices=sorted(MESHES), help="mesh preset (default: default)")
    ap.add_argument("--check-mesh", action="store_true",
                    help="both arches at the first gap on the 'fine' mesh too")
    ap.add_argument("--check-order", action="store_true",
                    help="both arches at the first gap with P3/P2 on the same mesh")
    ap.add_argument("--check-domain", action="store_true",
                    help="both arches at the first gap with ends 5 d from the neck")
    ap.add_argument("--ends", type=float, default=3.0,
                    help="inlet and outlet this far from the neck, over d (%(default)s)")
    ap.add_argument("--cell2d", type=float, default=3.0,
                    help="2D check: fluid cell size finer by this factor (0: none)")
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="CSV (%(default)s)")
    ap.add_argument("--runs", help="folder of the 3D solves' JSON (default: the CSV's)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-2d", action="store_true", help="skip the 2D model")
    args = ap.parse_args(argv)
    if stokes_fem.extra_missing("stokes_arch", args.threads):
        return 2
    out = pathlib.Path(args.out)
    runs = pathlib.Path(args.runs) if args.runs else out.parent / "solves"
    pair_ = args.config == "pair"
    over = () if pair_ else OVERRIDES
    cell = load_cell(overrides=over)
    mesh_name = "quick" if args.quick else (args.mesh or "default")
    gaps = [float(g) for g in args.gaps.split(",")]
    if args.quick:
        gaps = gaps[:1]
    deltas = (0.0, args.delta) if args.delta and not pair_ else (0.0,)
    ends = {} if args.ends == 3.0 else dict(L_up=args.ends, L_down=args.ends)
    cases = [(g, dl, MESHES[mesh_name], ends) for g in gaps for dl in deltas]
    n_main = len(cases)
    checks = []
    if args.check_mesh:
        checks.append((MESHES["fine"], {}))
    if args.check_order:
        checks.append((dict(MESHES[mesh_name], order=3), {}))
    if args.check_domain:
        checks.append((MESHES[mesh_name], dict(L_up=5.0, L_down=5.0)))
    cases += [(gaps[0], dl, mesh_kw, dom) for mesh_kw, dom in checks for dl in deltas]
    rows, summary = [], []
    for idx, (g, dl, mesh_kw, dom) in enumerate(cases):
        s = Settings(gap=g, delta=dl, **mesh_kw, **dom, config=args.config)
        rec = cached3d(s, cell, runs, args.threads)
        F, T, K, _ = loads3d(rec, cell)
        x = np.asarray(rec["centres"])
        label = rec["mesh"] + ("" if not dom else f" ends {s.L_up:g}d")
        cfg = "pair" if pair_ else ("symmetric" if dl == 0 else "displaced")
        r, st = rows_for(cfg, g, dl, "3D Stokes", label, rec["ndof"], cell, x, F, T, K)
        rows += r
        summary.append((cfg, g, "3D " + label, st))
        if not args.no_2d and idx < n_main:
            for factor in ((1.0,) + ((args.cell2d,) if args.cell2d and not args.quick else ())):
                size = None if factor == 1.0 else cell.d / 6.0 / factor
                F2, T2 = loads2d(cell, x, size, overrides=over)
                lab = "d/6" if size is None else f"d/{6 * factor:g}"
                r, st = rows_for(cfg, g, dl, "2D Darcy", f"cell {lab}", "", cell, x, F2, T2)
                rows += r
                summary.append((cfg, g, f"2D cell {lab}", st))
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as fh:
        fh.write(f"# stokes_arch: F/F*, T/(a F*), F* = 12 pi eta Q a^2/(H^2 W) = "
                 f"{cell.force_scale:.4g} N at Q = {cell.Q:g} m^3/s; K over 8 pi eta a^3; "
                 f"x from the neck; P, P_T over F* (per unit sideways speed of the middle)\n")
        wr = csv.DictWriter(fh, COLUMNS, lineterminator="\n")
        wr.writeheader()
        wr.writerows(rows)
    print(" ".join(f"{c:>10s}" for c in ("config", "gap", "model", "sphere", "Fx", "Fy", "T",
                                         "T/aF", "T/muaN", "omega", "K_ii")))
    for r in rows:
        kii = r[f"K_{r['sphere']}"]
        print(" ".join(f"{fmt(v):>10s}" for v in (r["config"], r["gap_over_d"], r["model"][:2],
                                                  r["sphere"], r["Fx"], r["Fy"], r["T"],
                                                  r["T_over_aF"], r["T_over_mu_aNmax"],
                                                  r["omega_mode"], kii)))
    for cfg, g, lab, st in summary:
        print(f"{cfg:10s} gap {g:g} {lab:28s} P {st['P']:+.4g}  P_T {st['P_T']:+.4g}  "
              f"slip_max {st['slip_max']:.3f}  N {np.round(st['N'], 3).tolist()}  "
              f"resid {st['residual']:.1e}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
