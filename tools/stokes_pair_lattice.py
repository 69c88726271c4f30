"""Free drift of a rectangular monolayer lattice of sphere *pairs* at mid-gap: 3D Stokes.

The lone-sphere lattice of tools/stokes_sphere_lattice.py, with two spheres per
periodic cell ``Lx x Ly``: diameter ``d`` (radius ``a``), centred at mid-gap
between no-slip plates ``H`` apart, a centre distance ``s = d (1 + g)`` apart
(``g``: the surface gap over ``d``), either

* ``side``: side by side across the flow, centres ``(0, +-s/2)``, or
* ``inline``: in line along the flow, centres ``(+-s/2, 0)``.

The area fraction is ``phi = 2 pi a^2 / (Lx Ly)``. The cell's aspect is chosen so
that a sphere's nearest neighbours other than its partner are equally far in
``x`` and ``y``: ``Lx = Ly - s`` (side) or ``Ly = Lx - s`` (inline), so the in-line
cell is the side-by-side one turned by 90 degrees. A mean pressure gradient
``-G`` along ``x`` drives the flow; the spheres are force-free along ``x`` and, side
by side, torque-free about ``z`` (there each sphere spins: its torque about ``z`` is
not zero by symmetry). Output, as the lattice tool defines them:
``drift_over_mean`` (``V / U_mean``, ``U_mean = Q_total / (Ly H)``, fluid + solid
flux), ``drift_over_fluid``, ``mean_over_poiseuille``, the spin ``Omega a / V``,
and ``ratio_to_lone``: ``V / U_mean`` over the lone-sphere square lattice's at the
same ``phi`` and on the same mesh preset (a run of
``stokes_sphere_lattice.run``, cached with ``--runs``).

Computed domain: 1/8 of the cell, ``0 <= x <= Lx/2``, ``0 <= y <= Ly/2``,
``0 <= z <= H/2``, holding a quarter of one sphere.

* ``z = H/2``, ``y = 0`` and ``y = Ly/2`` are mirror planes. Side by side,
  ``y = 0`` lies between the spheres (it maps one onto the other); in line it
  passes through both centres.
* ``x = 0`` and ``x = Lx/2`` are planes of Stokes reversibility (reverse the
  flow and reflect ``x``: the geometry is even in ``x`` about both, and the
  mean gradient is kept), with the same conditions as in the lattice tool
  (``u_y = u_z = 0``, a given pressure). Side by side, ``x = 0`` passes through
  the centres, and a spin about ``z`` is even under the reversal: it is
  allowed, and its surface velocity ``Omega (-(y - y_c), x, 0)`` meets
  ``u_y = 0`` on ``x = 0``. In line, ``x = 0`` lies between the spheres and
  maps one onto the other, the reversal keeping ``V_x`` (both spheres move
  alike, by the uniqueness of the Stokes solution); the mirror ``y = 0``
  through the centres forbids a spin about ``z``, ``z = H/2`` the others.

So no quarter cell is needed: 1/8 holds in both arrangements.

Problems on one factorisation: **fixed** (spheres held, mean gradient ``-G``),
**translating** (``u = e_x`` on the sphere, no mean gradient) and, side by side,
**rotating** (``u = e_z x (r - r_c)``). Force ``F_x`` and torque ``T_z`` on the
whole sphere are consistent reactions (``-4 R(w)``, ``w`` the unit translation
or rotation on the sphere's degrees of freedom; the domain holds a quarter of
it). Free: ``F_fix + V F_tr + Omega F_rot = 0`` and ``T_fix + V T_tr + Omega
T_rot = 0``. ``F_rot - T_tr`` (reciprocity) is reported as a check. The flux
``Q_total`` is 4 times the integral of ``u_x`` on ``x = Lx/2`` (no solid there),
checked against the cell average of the mixture velocity.

Mesh: the lattice tool's sizes (``h_far`` over ``H``, ``h_part`` over ``a``,
``h_film`` over the local film thickness) with its film refinement
(``stokes_fem.film_points``) over the plate film and also over the film between
the sphere and the symmetry plane between the two spheres (half the pair's gap).

Units ``H = 1``, ``eta = 1``, ``G = 12`` (``U_P = 1``). Usage::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 nice -n 15 \
        python tools/stokes_pair_lattice.py --arrangement side --gap 0.05 --phi 0.24 \
        [--preset quick|table|check_mesh|check_order] [--runs DIR] [--out FILE.json]
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import stokes_fem
import stokes_sphere_lattice as lattice

G_MEAN = lattice.G_MEAN
COPIES_SPHERE = 4.0     # the domain holds a quarter of one sphere
COPIES_CELL = 8.0       # and is 1/8 of the cell


@dataclasses.dataclass(frozen=True)
class Settings(stokes_fem.MeshSettings):
    """One solve (lengths over ``H``); see the module docstring."""

    dh: float
    phi: float
    gap: float
    arrangement: str = "side"
    h_far: float = 0.4
    h_part: float = 0.2
    h_film: float = 0.7
    order: int = 3

    def __post_init__(self):
        if self.arrangement not in ("side", "inline"):
            raise ValueError(f"arrangement is 'side' or 'inline', not {self.arrangement!r}")
        if not 0.0 < self.dh < 1.0:
            raise ValueError(f"d/H must lie in (0, 1), not {self.dh}")
        if self.gap <= 0.0:
            raise ValueError("the pair's gap must be positive")
        if self.order < 2:
            raise ValueError("Taylor-Hood needs order >= 2")
        if self.D <= self.dh:
            raise ValueError("the pairs' neighbours overlap at this phi")

    @property
    def a(self):
        return 0.5 * self.dh

    @property
    def s(self):
        """Centre distance of the pair."""
        return self.dh * (1.0 + self.gap)

    @property
    def area(self):
        return 2.0 * math.pi * self.a ** 2 / self.phi

    @property
    def D(self):
        """Distance to the nearest neighbours other than the partner (both directions)."""
        s = self.s
        return 0.5 * (-s + math.sqrt(s * s + 4.0 * self.area))

    @property
    def Lx(self):
        return self.D if self.arrangement == "side" else self.D + self.s

    @property
    def Ly(self):
        return self.D + self.s if self.arrangement == "side" else self.D

    @property
    def centre(self):
        """The computed sphere's centre (x, y) in the 1/8 domain."""
        return (0.0, 0.5 * self.s) if self.arrangement == "side" else (0.5 * self.s, 0.0)

    def tag(self):
        return (f"pair_{self.arrangement}_g{self.gap:g}_dh{self.dh:g}_phi{self.phi:g}_"
                f"{self.mesh_tag()}")


PRESETS = lattice.PRESETS


def preset(name, dh, phi, gap, arrangement, **overrides):
    kw = dict(PRESETS[name])
    kw.update({k: v for k, v in overrides.items() if v is not None})
    return Settings(dh=float(dh), phi=float(phi), gap=float(gap), arrangement=arrangement, **kw)


# --------------------------------------------------------------------------- mesh

def film_refinement(s: Settings):
    """``(x, y, z, h)`` caps: the plate film and the film to the plane between the pair."""
    a = s.a
    cx, cy = s.centre
    out = []
    # plate film (z = 0, apex delta above it): a half disc in the domain
    for u, v, w, h in stokes_fem.film_points(a, 0.5 - a, s.h_film, phimax=math.pi):
        # film_points spreads over y >= 0; side by side the domain's half is x >= 0
        x, y = (v, u) if s.arrangement == "side" else (u, v)
        out.append((cx + x, cy + y, w, h))
    # film to the symmetry plane between the spheres (distance s/2 - a): a quarter disc
    for u, v, w, h in stokes_fem.film_points(a, 0.5 * s.s - a, s.h_film, phimax=0.5 * math.pi):
        if s.arrangement == "side":      # plane y = 0, in-plane coordinates (x, z)
            out.append((cx + u, w, 0.5 - v, h))
        else:                            # plane x = 0, in-plane coordinates (y, z)
            out.append((w, cy + u, 0.5 - v, h))
    return out


def build_mesh(s: Settings, ng, occ):
    """Curved mesh of the 1/8 cell less the sphere. Faces as the lattice tool's:
    ``xlo xhi ylo yhi plate mid particle``."""
    from netgen.meshing import MeshingParameters
    box = occ.Box(occ.Pnt(0, 0, 0), occ.Pnt(0.5 * s.Lx, 0.5 * s.Ly, 0.5))
    for i, name in enumerate(("xlo", "xhi", "ylo", "yhi", "plate", "mid")):
        side = box.faces.Max if i % 2 else box.faces.Min
        side((occ.X, occ.Y, occ.Z)[i // 2]).name = name
    cx, cy = s.centre
    sphere = occ.Sphere(occ.Pnt(cx, cy, 0.5), s.a)
    sphere.faces.name = "particle"
    sphere.faces.maxh = s.h_part * s.a
    fluid = box - sphere
    mp = MeshingParameters(maxh=s.h_far, grading=0.3)
    for x, y, z, h in film_refinement(s):
        mp.RestrictH(x, y, z, h=min(h, s.h_far))
    mesh = ng.Mesh(occ.OCCGeometry(fluid).GenerateMesh(mp=mp))
    if s.order > 1:
        mesh.Curve(s.order)
    return mesh


# -------------------------------------------------------------------------- solve

def solve_all(mesh, s: Settings, ng):
    """Assemble and factorise once; solve the fixed, translating and (side) rotating
    problems; their forces, torques and fluxes."""
    dirichlet = ("plate|particle", "plate|particle|ylo|yhi|xlo|xhi",
                 "plate|particle|mid|xlo|xhi")
    comps = [ng.H1(mesh, order=s.order, dirichlet=d) for d in dirichlet]
    Qs = ng.H1(mesh, order=s.order - 1)
    X = comps[0] * comps[1] * comps[2] * Qs
    (ux, uy, uz, p), (vx, vy, vz, q) = X.TnT()
    u3, v3 = (ux, uy, uz), (vx, vy, vz)
    div_u = sum(ng.grad(c)[i] for i, c in enumerate(u3))
    div_v = sum(ng.grad(c)[i] for i, c in enumerate(v3))
    n = ng.specialcf.normal(3)
    t0 = time.perf_counter()
    form = ng.BilinearForm(X)
    form += (sum(ng.grad(c) * ng.grad(t) for c, t in zip(u3, v3))
             - div_v * p - div_u * q) * ng.dx
    form.Assemble()
    t1 = time.perf_counter()
    inv = form.mat.Inverse(X.FreeDofs(), inverse="umfpack")
    t2 = time.perf_counter()
    particle = mesh.Boundaries("particle")
    cx, cy = s.centre
    motions = {"translating": (ng.CF(1.0), ng.CF(0.0))}
    if s.arrangement == "side":
        motions["rotating"] = (-(ng.y - cy), ng.x - cx)

    def unit_field(vel):
        w = ng.GridFunction(X)
        w.components[0].Set(vel[0], definedon=particle)
        w.components[1].Set(vel[1], definedon=particle)
        return w

    tests = {k: unit_field(v) for k, v in motions.items()}
    rhs = {k: ng.LinearForm(X) for k in ("fixed",) + tuple(motions)}
    rhs["fixed"] += (G_MEAN * 0.5 * s.Lx) * vx * n[0] * ng.ds("xhi")
    for f in rhs.values():
        f.Assemble()
    info = {"ndof": X.ndof, "elements": mesh.ne, "t_assemble": t1 - t0, "t_factor": t2 - t1}
    for key, f in rhs.items():
        g = unit_field(motions[key]) if key in motions else ng.GridFunction(X)
        res = f.vec.CreateVector()
        res.data = f.vec - form.mat * g.vec
        g.vec.data += inv * res
        r = g.vec.CreateVector()
        r.data = form.mat * g.vec - f.vec
        ux_h = g.components[0]
        grad_u = ng.CF(tuple(ng.Grad(g.components[i]) for i in range(3)), dims=(3, 3))
        rec = {
            "F": -COPIES_SPHERE * ng.InnerProduct(r, tests["translating"].vec),
            "Q_xhi": 4.0 * ng.Integrate(ux_h, mesh, ng.BND, definedon=mesh.Boundaries("xhi")),
            "Q_fluid_xlo": 4.0 * ng.Integrate(ux_h, mesh, ng.BND,
                                              definedon=mesh.Boundaries("xlo")),
            "int_fluid_ux": COPIES_CELL * ng.Integrate(ux_h, mesh),
            "fluid_volume": COPIES_CELL * ng.Integrate(ng.CF(1.0), mesh),
            "div_L2": math.sqrt(ng.Integrate((grad_u[0, 0] + grad_u[1, 1] + grad_u[2, 2]) ** 2,
                                             mesh)),
        }
        # traction integral of F_x (gradient form) as a check of the reaction
        gb = ng.BoundaryFromVolumeCF(grad_u)
        pb = ng.BoundaryFromVolumeCF(g.components[3])
        tr = gb * n - pb * n
        rec["F_surface"] = -COPIES_SPHERE * ng.Integrate(tr[0], mesh, ng.BND,
                                                         definedon=particle,
                                                         order=2 * s.order + 2)
        if "rotating" in tests:
            rec["T"] = -COPIES_SPHERE * ng.InnerProduct(r, tests["rotating"].vec)
        info[key] = rec
    info["t_solve"] = time.perf_counter() - t0
    return info


def analyse(info, s: Settings):
    """Free speed and spin, and the lattice tool's ratios."""
    a, H = s.a, 1.0
    fx, tr = info["fixed"], info["translating"]
    if "rotating" in info:
        ro = info["rotating"]
        det = tr["F"] * ro["T"] - ro["F"] * tr["T"]
        V = (-fx["F"] * ro["T"] + ro["F"] * fx["T"]) / det
        W = (-tr["F"] * fx["T"] + fx["F"] * tr["T"]) / det
        V_nospin = -fx["F"] / tr["F"]
        recip = ro["F"] / tr["T"] - 1.0
    else:
        ro = None
        V = -fx["F"] / tr["F"]
        W, V_nospin, recip = 0.0, V, None

    def comb(key):
        out = fx[key] + V * tr[key]
        if ro is not None:
            out += W * ro[key]
        return out

    Q = comb("Q_xhi")
    U_mean = Q / (s.Ly * H)
    fluid_int = comb("int_fluid_ux")
    U_fluid = fluid_int / fx["fluid_volume"]
    vol_spheres = 2.0 * 4.0 / 3.0 * math.pi * a ** 3
    Q_volume = (fluid_int + V * vol_spheres) / s.Lx
    solid_x0 = 2.0 * math.pi * a * a if s.arrangement == "side" else 0.0
    Q_x0 = comb("Q_fluid_xlo") + V * solid_x0
    return {
        "arrangement": s.arrangement, "gap": s.gap, "d_over_H": s.dh, "phi": s.phi,
        "Lx": s.Lx, "Ly": s.Ly, "s": s.s, "neighbour_distance": s.D,
        "drift_over_mean": V / U_mean,
        "drift_over_fluid": V / U_fluid,
        "mean_over_poiseuille": U_mean,
        "V": V, "Omega": W, "spin_Omega_a_over_V": W * a / V,
        "drift_over_mean_without_spin": V_nospin / ((fx["Q_xhi"] + V_nospin * tr["Q_xhi"])
                                                   / (s.Ly * H)),
        "U_mean": U_mean, "U_fluid": U_fluid,
        "Q_check_x0": Q_x0 / Q - 1.0, "Q_check_volume": Q_volume / Q - 1.0,
        "reciprocity_F_rot_over_T_tr_minus_1": recip,
        "F_surface_rel": {k: info[k]["F_surface"] / info[k]["F"] - 1.0
                          for k in ("fixed", "translating")},
    }


def run(s: Settings, threads=1, verbose=False):
    def solve(mesh, ng):
        info = solve_all(mesh, s, ng)
        return analyse(info, s), info
    return stokes_fem.run_sphere(s, threads, verbose, build_mesh, solve,
                                 note=f"Lx = {s.Lx:.4f} H, Ly = {s.Ly:.4f} H, ")


def lone_reference(s: Settings, runs_dir, threads):
    """The lone-sphere square lattice at the same ``phi`` and mesh (lattice tool)."""
    ls = lattice.Settings(dh=s.dh, phi=s.phi, h_far=s.h_far, h_part=s.h_part,
                          h_film=s.h_film, order=s.order)
    return stokes_fem.cached_run(ls, runs_dir, lambda x: lattice.run(x, threads, verbose=True),
                                 "lone lattice V/U_mean {drift_over_mean:.6f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--arrangement", choices=("side", "inline"), required=True)
    ap.add_argument("--gap", type=float, required=True, help="surface gap over d")
    ap.add_argument("--phi", type=float, required=True, help="2 pi a^2 / (Lx Ly)")
    ap.add_argument("--dh", type=float, default=0.875, help="d/H (%(default)s)")
    ap.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    ap.add_argument("--runs", help="folder caching each solve's JSON")
    ap.add_argument("--out", help="JSON of this run (with the lone reference)")
    stokes_fem.add_mesh_options(ap)
    args = ap.parse_args(argv)
    if stokes_fem.extra_missing("stokes_pair_lattice", args.threads):
        return 2
    s = preset(args.preset, args.dh, args.phi, args.gap, args.arrangement, h_far=args.hfar,
               h_part=args.hpart, h_film=args.hfilm, order=args.order)
    rec = stokes_fem.cached_run(s, args.runs, lambda x: run(x, args.threads, verbose=True),
                                "V/U_mean {drift_over_mean:.6f}  Omega a/V "
                                "{spin_Omega_a_over_V:.4f}")
    lone = lone_reference(s, args.runs, args.threads)
    rec["lone_drift_over_mean"] = lone["drift_over_mean"]
    rec["ratio_to_lone"] = rec["drift_over_mean"] / lone["drift_over_mean"]
    rec["lone_wall_s"] = lone["wall_s"]
    keys = ("arrangement", "gap", "phi", "Lx", "Ly", "drift_over_mean", "lone_drift_over_mean",
            "ratio_to_lone", "drift_over_mean_without_spin", "spin_Omega_a_over_V",
            "drift_over_fluid", "mean_over_poiseuille", "Q_check_x0", "Q_check_volume",
            "reciprocity_F_rot_over_T_tr_minus_1", "F_surface_rel", "mesh", "ndof", "wall_s")
    summary = {k: rec[k] for k in keys}
    stokes_fem.print_run(rec, summary, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
