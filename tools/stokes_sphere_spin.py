"""A sphere at mid-gap of a Hele-Shaw cell spinning about the plates' normal: Stokes torque.

A sphere of diameter ``d`` (radius ``a = d/2``) is centred at mid-gap between two
no-slip plates a distance ``H`` apart and spins at ``Omega`` about the axis
normal to the plates, in fluid otherwise at rest. This tool computes the
torque ``T`` the fluid exerts on it (against the spin) as the coefficient

``spin_torque`` (``T / (8 pi eta a^3 Omega)``)
    1 for a sphere in unbounded fluid; it grows as the plates close in and
    stays finite at contact (the films' shear is ``eta Omega rho / h(rho)``,
    whose moment ``~ int rho^3 / h d rho`` converges as the film ``delta`` at
    the apex vanishes).

Method
------
The flow is axisymmetric about the sphere's vertical axis and purely azimuthal,
``u = u_phi(r, z) e_phi`` with no pressure; with ``u_phi = r f(r, z)`` (``f``
the fluid's angular velocity) Stokes' equations reduce to

    div(r^3 grad f) = 0   in the meridian half-plane (r >= 0, 0 <= z <= H),

``f = Omega`` on the sphere, ``f = 0`` on the plates, and a natural condition
(``df/dr = 0``) on the axis, where ``f`` is regular. The viscous dissipation is
``eta r^2 |grad f|^2`` per unit volume, so

    T Omega = 2 pi eta int r^3 |grad f|^2 dr dz,

which is the consistent reaction ``T = 2 pi eta R(w)``: ``R`` the residual of
the weak form and ``w`` the discrete field equal to 1 on the sphere's degrees
of freedom (:func:`solve`). The surface integral ``2 pi eta int r^3 df/dn ds``
over the sphere is reported beside it as a check (``T_surface_rel``). The
torque, an energy, converges like the square of the field's error in the energy
norm.

Units ``H = 1``, ``eta = 1``, ``Omega = 1``. ``f`` is even about ``z = H/2``,
so only the half-gap ``0 <= z <= H/2`` is meshed (natural condition on the mid
plane; the torque is doubled). The domain ends at ``r = a + R H``, with ``f = 0``
there (``--outer noslip``) or the natural, zero-shear condition (``free``); the
disturbance dies like ``exp(-pi r / H)`` (the slit's slowest swirl mode,
``K_1(pi r / H) sin(pi z / H)``), ``exp(-3 pi)`` ~ 1e-4 at ``R = 3``. NGSolve
2D, continuous ``P_k`` on triangles curved to order ``k``, UMFPACK. The mesh is
that of the 3D tools in the meridian plane: the sphere's edge is capped at
``h_part a``, the lubrication film at ``h_film`` times its local thickness
(``stokes_fem.film_points`` at :data:`FILM_RINGS` radii), the rest at
``h_far H``.

Checks
------
``--checks`` adds at every ratio of the table a finer mesh (``check_mesh``:
sizes halved, ``P5``) and a larger domain with the free outer condition
(``check_domain``: ``R = 5``) and writes the largest changes into the CSV's
header (1.2e-9 and 2.6e-9 relative: the table's seven decimals are its error),
with two checks of the solver:

* *unbounded fluid*: a point rotlet between two walls has images of
  alternating sign at ``z = H/2 + k H`` (each wall's image of an axial rotlet
  is exactly the opposite rotlet at the mirror point: on the wall the two are
  equally far, and ``e_z x (x - x0)`` does not see ``x0``'s height). They turn
  the fluid at the centre at ``-(3/2) zeta(3) / H^3`` times the rotlet's
  strength ``a^3 (Omega - omega)``.
  Faxen's law (``T = 8 pi eta a^3 (Omega - omega)``, exact) with those
  reflections summed gives :func:`image_sum`,
  ``1 / (1 - (3/16) zeta(3) (d/H)^3)`` ~ ``1 + 0.2254 (d/H)^3``. Its remainder
  comes from the images' non-uniform swirl, reflected by the sphere as a
  higher multipole and back: ``O((d/H)^10)``. Measured: 2.8e-5 above 1 at d/H
  = 0.05 (equal to the image sum within 2e-10), and the remainder 1e-10,
  2.5e-9, 1.3e-7, 2.4e-6 at d/H = 0.1, 0.2, 0.3, 0.4 (a factor 18 from 0.3 to
  0.4: ``(4/3)^10``).
* *one wall, exact* (Jeffery 1915, bispherical coordinates): a sphere whose
  centre is ``h`` from a single plane wall has
  ``T / (8 pi eta a^3 Omega) = sum_n (sinh alpha / sinh(n alpha))^3``,
  ``cosh alpha = h / a`` (:func:`jeffery`; ``zeta(3)`` at contact,
  ``1 + (a/h)^3 / 8`` far away). ``--wall one`` solves that problem (the plate
  ``z = 0``, the sphere ``delta = (H - d)/2`` above it, ``f = 0`` on the far
  sides of a box ``R = 40`` beyond it) with the check mesh's sizes at the films
  of d/H = 0.3 to 0.975: within 7e-9 of Jeffery's sum.

The table's mesh is made for ``d/H >= 0.3``: for a smaller sphere its far size
``h_far`` is a few radii, and at d/H = 0.05 it is 4e-7 off (the check mesh
2e-10).

Usage
-----
::

    python tools/stokes_sphere_spin.py --d-over-h 0.9 [--quick | --preset one_wall]
                                       [--out FILE.json]
    python tools/stokes_sphere_spin.py --table [--checks] [--csv FILE.csv] [--runs DIR]

``--table`` solves every ratio of :data:`TABLE_DH` (those of
``taichi_hsdem/data/sphere_in_gap.csv``) with the ``table`` preset and writes
the CSV (default ``taichi_hsdem/data/sphere_spin.csv``). ``--runs DIR`` keeps
each solve's JSON there and reuses those whose settings match. The mesh and
domain options (``--R --outer --wall --hfar --hpart --hfilm --order``) override
the preset of a single run. One thread by default (``--threads``). Exit 2 (one
line) when NGSolve is missing.

Cost, one thread, on a shared two-core machine: a ``table`` solve takes 0.2-1 s
(14,000-16,000 unknowns), a ``check_mesh`` one 1-4 s (85,000), a ``quick`` one
0.05 s (2,500; within 2e-6 of the table); ``--table --checks`` took 40 s.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import shlex
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import stokes_fem  # noqa: E402  (require(): the only way NGSolve is imported)
from taichi_hsdem.laws import sphere_spin_images as image_sum  # noqa: E402

DATA_DIR = HERE.parent / "taichi_hsdem" / "data"
DATA_CSV = DATA_DIR / "sphere_spin.csv"
GAP_CSV = DATA_DIR / "sphere_in_gap.csv"
# The table's ratios: those of the translating sphere's table (its first column).
TABLE_DH = tuple(row["d_over_H"] for row in stokes_fem.read_table(GAP_CSV, text=("mesh",
                                                                                  "domain")))
FILM_RINGS = 40             # radii of stokes_fem.film_points (cheap in 2D)
# The table's error bar: its last digit (7 decimals). The largest change measured
# against the checks over TABLE_DH (--checks; the header's second line) is 3e-9.
ERROR_ESTIMATE = "+-1e-7 on spin_torque (its last digit)"
ERROR_ABS = 1e-7
CSV_COLUMNS = ("d_over_H", "spin_torque", "ndof", "mesh", "domain")


@dataclasses.dataclass(frozen=True)
class Settings(stokes_fem.MeshSettings):
    """One solve. Lengths over ``H``.

    Attributes
    ----------
    dh : float
        ``d / H``.
    R : float
        Two walls: the domain ends at ``r = a + R``. One wall: a box of side
        ``R`` beyond the sphere (``r <= a + R``, ``z <= delta + 2 a + R``).
    outer : {"noslip", "free"}
        Condition on the domain's far boundary: ``f = 0`` or zero shear.
    wall : {"two", "one"}
        The sphere at mid-gap between two plates (the table), or ``delta = (H -
        d)/2`` above one plate (Jeffery's check).
    h_far, h_part, h_film : float
        Element size caps: far field over ``H`` (one wall: over ``R``), on
        the sphere over ``a``, in the film over its local thickness.
    order : int
        Polynomial order ``k`` of the elements and of the geometry.
    """

    dh: float
    R: float = 3.0
    outer: str = "noslip"
    wall: str = "two"
    h_far: float = 0.05
    h_part: float = 0.02
    h_film: float = 0.2
    order: int = 4

    def domain_label(self):
        if self.wall == "one":
            return f"one wall box={self.R:g}H {self.outer}"
        return f"R={self.R:g}H {self.outer}"

    def tag(self):
        return f"spin_dh{self.dh:g}_{self.wall}_R{self.R:g}_{self.outer}_{self.mesh_tag()}"


# Presets (mesh and domain; d/H is given separately). "table" is the CSV's;
# "quick" is coarser (the test's comparison of another mesh with the table).
PRESETS = {
    "table": dict(R=3.0, outer="noslip", wall="two", h_far=0.05, h_part=0.02, h_film=0.2,
                  order=4),
    "check_mesh": dict(R=3.0, outer="noslip", wall="two", h_far=0.025, h_part=0.01,
                       h_film=0.1, order=5),
    "check_domain": dict(R=5.0, outer="free", wall="two", h_far=0.05, h_part=0.02,
                         h_film=0.2, order=4),
    "one_wall": dict(R=40.0, outer="noslip", wall="one", h_far=0.025, h_part=0.01,
                     h_film=0.1, order=5),
    "quick": dict(R=3.0, outer="noslip", wall="two", h_far=0.1, h_part=0.05, h_film=0.4,
                  order=3),
}


def preset(name, dh, **overrides):
    """:class:`Settings` of preset ``name`` at ``d/H = dh``, with ``overrides``."""
    kw = dict(PRESETS[name])
    kw.update({k: v for k, v in overrides.items() if v is not None})
    return Settings(dh=float(dh), **kw)


# ------------------------------------------------------------------ closed forms

def jeffery(h_over_a):
    """Jeffery's exact torque coefficient of a sphere spinning about the normal of
    one plane wall, its centre ``h`` from the wall: ``sum_n (sinh alpha / sinh(n
    alpha))^3``, ``cosh alpha = h / a``.

    Examples
    --------
    >>> round(jeffery(1e8), 6), round(jeffery(1.0 + 1e-9), 3)   # far; touching: zeta(3)
    (1.0, 1.202)
    """
    alpha = math.acosh(float(h_over_a))
    n = np.arange(1, int(math.ceil(40.0 / alpha)) + 2)          # to sinh(n alpha) ~ e^40
    return float(np.sum((math.sinh(alpha) / np.sinh(n * alpha)) ** 3))


# --------------------------------------------------------------------------- mesh

def build_mesh(s: Settings, ng, occ):
    """The meridian half-plane's curved triangular mesh (refined over the film:
    ``stokes_fem.film_points``).

    Coordinates ``(r, z)``. Edges: ``axis`` (r = 0), ``plate`` (z = 0), ``outer``
    (the far side(s)), ``mid`` (z = H/2, two walls only), ``particle``.
    """
    from netgen.meshing import MeshingParameters  # present once require() passed

    a = 0.5 * s.dh
    delta = 0.5 - a                                 # the film at the apex
    if s.wall == "two":
        zc, top, maxh = 0.5, 0.5, s.h_far
    elif s.wall == "one":
        zc = delta + a
        top, maxh = zc + a + s.R, s.h_far * s.R
    else:
        raise ValueError(f"wall must be 'two' or 'one', got {s.wall!r}")
    box = occ.WorkPlane().Rectangle(a + s.R, top).Face()
    box.edges.Min(occ.X).name = "axis"
    box.edges.Max(occ.X).name = "outer"
    box.edges.Min(occ.Y).name = "plate"
    box.edges.Max(occ.Y).name = "mid" if s.wall == "two" else "outer"
    disk = occ.WorkPlane().Circle(0.0, zc, a).Face()
    disk.edges.name = "particle"
    disk.edges.maxh = s.h_part * a
    mp = MeshingParameters(maxh=maxh, grading=0.3)
    # film_points' (x, y, z) with phimax = 0 lie on y = 0: (r, z) = (x, z)
    for x, _, z, h in stokes_fem.film_points(a, delta, s.h_film, phimax=0.0, rings=FILM_RINGS):
        mp.RestrictH(x, z, 0.0, h=h)
    mesh = ng.Mesh(occ.OCCGeometry(box - disk, dim=2).GenerateMesh(mp=mp))
    if s.order > 1:
        mesh.Curve(s.order)
    return mesh


# -------------------------------------------------------------------------- solve

def solve(mesh, s: Settings, ng):
    """Solve for ``f = u_phi / r`` (``f = 1`` on the sphere) and measure the torque.

    Returns
    -------
    results : dict
        ``spin_torque`` (the reaction's).
    info : dict
        ``ndof``, ``elements``, timings, ``T`` (the torque, ``eta = Omega = H =
        1``) and ``T_surface_rel`` (the surface integral's relative difference).
    """
    dirichlet = "plate|particle" + ("|outer" if s.outer == "noslip" else "")
    V = ng.H1(mesh, order=s.order, dirichlet=dirichlet)
    f, g = V.TnT()
    r = ng.x
    t0 = time.perf_counter()
    form = ng.BilinearForm(V)
    form += r ** 3 * ng.grad(f) * ng.grad(g) * ng.dx
    form.Assemble()
    t1 = time.perf_counter()
    particle = mesh.Boundaries("particle")
    sol = ng.GridFunction(V)
    sol.Set(1.0, definedon=particle)
    res = sol.vec.CreateVector()
    res.data = -form.mat * sol.vec
    sol.vec.data += form.mat.Inverse(V.FreeDofs(), inverse="umfpack") * res
    t2 = time.perf_counter()
    w = ng.GridFunction(V)
    w.Set(1.0, definedon=particle)
    halves = 2.0 if s.wall == "two" else 1.0
    torque = halves * 2.0 * math.pi * ng.InnerProduct(form.mat * sol.vec, w.vec)
    n = ng.specialcf.normal(2)                      # out of the fluid: into the sphere
    surface = -halves * 2.0 * math.pi * ng.Integrate(
        r ** 3 * (ng.BoundaryFromVolumeCF(ng.grad(sol)) * n), mesh, ng.BND,
        definedon=particle, order=2 * s.order + 4)
    a = 0.5 * s.dh
    info = {"ndof": V.ndof, "elements": mesh.ne, "t_assemble": t1 - t0, "t_solve": t2 - t1,
            "T": torque, "T_surface_rel": surface / torque - 1.0}
    return {"spin_torque": torque / (8.0 * math.pi * a ** 3)}, info


def run(s: Settings, threads=1, verbose=False):
    """Mesh and solve one :class:`Settings`; returns a JSON-ready dict."""
    return stokes_fem.run_sphere(s, threads, verbose, build_mesh,
                                 lambda mesh, ng: solve(mesh, s, ng),
                                 labels={"domain": s.domain_label()})


# --------------------------------------------------------------------------- table

def cached_run(s: Settings, runs_dir, threads):
    """:func:`run`, or the JSON of an earlier run of the same settings in ``runs_dir``."""
    return stokes_fem.cached_run(s, runs_dir, lambda s: run(s, threads, verbose=False),
                                 "spin_torque {spin_torque:.7f}")


def read_table(path=DATA_CSV):
    """The CSV as a dict ``{d_over_H: row}`` (numbers as floats)."""
    return {row["d_over_H"]: row
            for row in stokes_fem.read_table(path, text=("mesh", "domain"))}


def write_table(rows, path, command, lines):
    comments = [f"3D Stokes torque on a sphere (diameter d, a = d/2) spinning at Omega about "
                f"the plates' normal at mid-gap of a Hele-Shaw cell (plates H apart): "
                f"spin_torque = T/(8 pi eta a^3 Omega), 1 in unbounded fluid; axisymmetric "
                f"swirl u_phi = r f(r,z), div(r^3 grad f) = 0, NGSolve 2D P_k, torque from "
                f"the dissipation (the reaction); reproduce: {command}",
                *lines,
                "mesh h_far/h_part/h_film P_order (far over H, on the sphere over a, in the "
                "film over its local thickness); domain r <= a + R H, outer boundary "
                "noslip (f = 0) or free (zero shear)"]
    cells = [[f"{r['settings']['dh']:g}", f"{r['spin_torque']:.7f}", r["ndof"], r["mesh"],
              r["domain"]] for r in rows]
    stokes_fem.write_table(path, comments, CSV_COLUMNS, cells)


def validations(runs_dir, threads):
    """The unbounded limit, the image sum and Jeffery's one wall (module docstring).

    Returns
    -------
    dict
        ``unbounded``: ``{preset: coefficient}`` at d/H = 0.05 (``table`` and
        ``check_mesh``); ``images``: ``{d/H: coefficient - image_sum}`` on the
        check mesh; ``jeffery``: ``{d/H: (coefficient, exact)}`` at the table's
        films; ``jeffery_worst``: the largest relative difference and its d/H;
        ``lines``: what the CSV's header says of them.
    """
    def coefficient(name, dh):
        return cached_run(preset(name, dh), runs_dir, threads)["spin_torque"]

    out = {"unbounded": {name: coefficient(name, 0.05) for name in ("table", "check_mesh")},
           "images": {dh: coefficient("check_mesh", dh) - image_sum(dh)
                      for dh in (0.1, 0.2, 0.3, 0.4)},
           "jeffery": {dh: (coefficient("one_wall", dh), jeffery(1.0 / dh))  # h = H/2, a = d/2
                       for dh in (0.3, 0.65, 0.9, 0.975)}}
    worst = max(out["jeffery"].items(), key=lambda kv: abs(kv[1][0] / kv[1][1] - 1.0))
    out["jeffery_worst"] = (abs(worst[1][0] / worst[1][1] - 1.0), worst[0])
    unb = out["unbounded"]
    images = ", ".join(f"{dh:g}: {v:+.1e}" for dh, v in out["images"].items())
    jeff = ", ".join(f"{dh:g}: {c:.8f} ({j:.8f})" for dh, (c, j) in out["jeffery"].items())
    out["lines"] = [
        f"checks of the solver: (1) unbounded fluid, d/H = 0.05: {unb['table']:.8f} on the "
        f"table's mesh, {unb['check_mesh']:.10f} on the check's (1 within "
        f"{abs(unb['check_mesh'] - 1):.1e}), the point rotlet's images summed "
        f"(1/(1 - (3/16) zeta(3) (d/H)^3)) {image_sum(0.05):.10f}; (2) coefficient minus that "
        f"image sum on the check mesh at d/H {images} (the remainder grows like (d/H)^10: the "
        f"images' non-uniform swirl reflected); (3) one wall (the sphere H/2 - a from a single "
        f"plate), 0.025/0.01/0.1 P5 in a box of 40H, against Jeffery's exact sum over "
        f"(sinh alpha/sinh n alpha)^3, cosh alpha = H/d, in parentheses, at the films of d/H "
        f"{jeff} (largest relative difference {out['jeffery_worst'][0]:.1e})"]
    return out


def table(dhs, csv_path, runs_dir, threads, checks, command):
    rows, worst = [], {"mesh": (0.0, None), "domain": (0.0, None)}
    for dh in dhs:
        ref = cached_run(preset("table", dh), runs_dir, threads)
        rows.append(ref)
        if checks:
            for name in ("mesh", "domain"):
                other = cached_run(preset("check_" + name, dh), runs_dir, threads)
                change = abs(other["spin_torque"] / ref["spin_torque"] - 1.0)
                if change > worst[name][0]:
                    worst[name] = (change, dh)
    lines = ["no checks run (--checks measures the mesh and domain error)"]
    valid = None
    if checks:
        lines = [f"estimated error: {ERROR_ESTIMATE}; largest relative change measured "
                 f"against the checks: mesh {worst['mesh'][0]:.1e} (at d/H = "
                 f"{worst['mesh'][1]:g}; 0.025/0.01/0.1 P5 against the table's "
                 f"0.05/0.02/0.2 P4), domain {worst['domain'][0]:.1e} (at d/H = "
                 f"{worst['domain'][1]:g}; R=5H free against R=3H noslip)"]
        valid = validations(runs_dir, threads)
        lines += valid["lines"]
    write_table(rows, csv_path, command, lines)
    return rows, worst, valid


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--d-over-h", "--dh", dest="dh", type=float, help="d/H of a single run")
    stokes_fem.add_run_options(ap, PRESETS, DATA_CSV, table="TABLE_DH", axis="dh", label="d/H",
                               checks="mesh and domain checks, validations")
    ap.add_argument("--R", type=float, help="domain size beyond the sphere / H")
    ap.add_argument("--outer", choices=("noslip", "free"))
    ap.add_argument("--wall", choices=("two", "one"))
    stokes_fem.add_mesh_options(ap)
    args = ap.parse_args(argv)
    if stokes_fem.extra_missing("stokes_sphere_spin", args.threads):
        return 2
    if args.table:
        t0 = time.perf_counter()
        dhs = ([float(v) for v in args.table_dh.split(",")] if args.table_dh else TABLE_DH)
        command = "python tools/stokes_sphere_spin.py --table" + (" --checks" if args.checks
                                                                  else "")
        if args.table_dh:
            command += " --table-dh " + shlex.quote(args.table_dh)
        rows, worst, valid = table(dhs, args.csv, args.runs, args.threads, args.checks,
                                   command)
        for r in rows:
            print(f"{r['settings']['dh']:6g} spin_torque {r['spin_torque']:.7f}  ndof "
                  f"{r['ndof']}  T_surface_rel {r['solve']['T_surface_rel']:.1e}")
        if args.checks:
            print("largest changes:", {k: f"{v:.1e} at {dh:g}" for k, (v, dh) in worst.items()})
            print(valid["lines"][0])
        print(f"wrote {args.csv} ({time.perf_counter() - t0:.1f} s)")
        return 0
    if args.dh is None:
        ap.error("give --d-over-h or --table")
    name = "quick" if args.quick else (args.preset or "table")
    s = preset(name, args.dh, R=args.R, outer=args.outer, wall=args.wall, h_far=args.hfar,
               h_part=args.hpart, h_film=args.hfilm, order=args.order)
    rec = run(s, args.threads)
    summary = {k: rec[k] for k in ("spin_torque", "ndof", "mesh", "domain", "wall_s")}
    summary.update({k: rec["solve"][k] for k in ("elements", "T_surface_rel")})
    if s.wall == "two":
        summary["image_sum"] = image_sum(s.dh)
    else:
        summary["jeffery"] = jeffery(1.0 / s.dh)
    stokes_fem.print_run(rec, summary, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
