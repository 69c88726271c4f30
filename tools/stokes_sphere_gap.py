"""A sphere at mid-gap of a Hele-Shaw cell: 3D Stokes drag, free drift and dipoles.

A sphere of diameter ``d`` (radius ``a = d/2``) is centred at mid-gap between two
no-slip plates a distance ``H`` apart. Two 3D Stokes problems are solved with
NGSolve on one mesh (one LU factorisation serves both):

* **fixed**: the sphere is held (``u = 0`` on it) in a pressure-driven flow;
* **moving**: the sphere translates along ``x`` at speed ``V`` in fluid at rest
  (``u = V e_x`` on it, the same pressure at both ends).

From them this tool computes, for an *isolated* sphere in an *unbounded* cell
(the side walls' and the ends' influence removed, below):

``drift_ratio`` (lambda)
    Speed of the force-free (and, by symmetry, torque-free) sphere over the
    depth-averaged speed ``U`` of the ambient flow:
    ``lambda = V / U = F_fix / (-F_mov)``, with ``F_fix = f_fix eta U a`` the
    x-force on the held sphere and ``F_mov = f_mov eta V a`` (negative: drag)
    on the moving one, so that ``F = f_fix eta U a + f_mov eta V a = 0``.
``dipole_fixed`` (B / a^2)
    The depth-averaged pressure disturbance of the held sphere far from it
    (``r >> H``) is a 2D dipole ``p' = -B G x / r^2``, with ``G = -dp/dx > 0``
    the driving gradient of the ambient flow (``U = G H^2 / (12 eta)``). With
    this sign an impermeable Darcy cylinder (``a >> H``) has ``B/a^2 = 1``.
``dipole_moving`` (C / a^2)
    The moving sphere's disturbance is ``p' = +C (12 eta V / H^2) x / r^2``
    (positive ahead of the sphere); an impermeable Darcy cylinder moving at
    ``V`` has ``C/a^2 = 1``.
``dipole_free`` (B_free / a^2)
    The freely drifting sphere's: ``p' = -B_free G x / r^2`` with
    ``B_free = B - lambda C`` (superposition of the two problems).

Method
------
Units ``H = 1``, ``eta = 1``. The domain is a quarter of a straight cell,
``-L <= x <= L``, ``0 <= y <= W``, ``0 <= z <= H/2``: both problems are even in
``y`` and in ``z - H/2``, so ``y = 0`` and ``z = H/2`` are mirror planes (zero
normal velocity and shear; the sphere does not rotate). The plate ``z = 0`` and
the sphere are no-slip; the side wall ``y = W`` is free-slip (``--sidewall
slip``: the same as a periodic row of spheres ``2W`` apart) or no-slip; inlet and
outlet carry the gradient form's traction ``(grad u - p I) n = -p_b n``. ``W`` and
``L`` are given in units of ``ell = max(d, 0.7 H)`` (a small sphere's
disturbance still reaches ~H across the gap). Taylor-Hood P_k/P_(k-1)
(``k = 3`` by default), geometry curved to order ``k``, UMFPACK.

The mesh is refined over the lubrication region, ``rho <= min(0.95 a,
sqrt(8 a delta))`` with ``delta = (H - d)/2`` the film at the apex: there the
element size is capped at ``h_film`` times the local film thickness
``h(rho) = delta + a - sqrt(a^2 - rho^2)``; on the sphere at ``h_part a``;
elsewhere at ``h_far H``.

*Force*: the consistent reaction ``F_x = -R(w)``, ``R`` the residual of the
weak form and ``w`` the discrete field equal to ``e_x`` on the sphere's degrees
of freedom (times 4 for the quarter). The traction's surface integral is
reported beside it as a check (``F_surface_rel``).

*Dipole*: the pressure is averaged over the gap (6-point Gauss-Legendre over
``0 <= z <= H/2``) on a grid of spacing ``ell/4`` covering ``r >= 2 ell``,
``|x| <= L - ell``, ``y <= W - H/2``, and least-squares fitted with

    p_bar = c0 + c1 x + D Phi(x, y),  Phi = (pi / 2W) Re coth(pi (x + i y) / 2W),

``Phi`` being ``x / r^2`` plus all its images in Neumann walls ``y = +-W``. The
ambient gradient at the sphere is the far one plus the images' uniform part,
``g = c1 + D pi^2 / (12 W^2)``. For **no-slip side walls** the fit uses the
wall shifted in by the side-wall layer's displacement thickness,
``W_eff = W - 0.315 H`` (``(96/pi^5)(31/32) zeta(5) H``): with the nominal
``W`` the fitted ``B`` drifts with the sampling radius and comes out ~5 % high;
with ``W_eff`` no-slip and free-slip domains agree to 0.04 %.

*Removing the walls*: by linearity the two runs give ``F = f_fix U + f_mov V``
and ``D = -B G + 12 C V`` in terms of the ambient speed each one sees (the
moving run has a small ambient flow too: its dipole's pressure jump leaks out
through the fixed end pressures); the fixed run gives ``f_fix`` and ``B``, the
moving one then ``f_mov`` and ``C``. These are the isolated sphere's values:
going from ``W = 4 ell, L = 8 ell`` free-slip to ``6 ell, 12 ell`` no-slip
changes them by at most 6e-5 on lambda and 3e-4 (relative) on ``B`` and ``C``,
where the raw ratio ``F_fix / -F_mov``, with ``U`` from the far gradient, moves
by 0.6-2 %.

Usage
-----
::

    python tools/stokes_sphere_gap.py --dh 0.875 [--quick] [--out FILE.json]
    python tools/stokes_sphere_gap.py --table [--checks] [--csv FILE.csv] [--runs DIR]

``--table`` solves every ratio of :data:`TABLE_DH` with the ``table`` preset
and writes the CSV (default ``taichi_hsdem/data/sphere_in_gap.csv``);
``--checks`` adds at every ratio a coarser mesh (``check_mesh``) and a larger
domain with no-slip side walls on that coarser mesh (``check_domain``) and
writes the largest changes into the CSV's header. ``--runs DIR`` keeps each
solve's JSON there and reuses those whose settings match. The mesh and domain
options (``--W --L --sidewall --hfar --hpart --hfilm --order``) override the
preset of a single run. One thread by default (``--threads``). Exit 2 (one
line) when NGSolve is missing.

Cost, one thread, on a shared two-core machine: a ``table`` solve took 1-4
minutes (135,000-315,000 unknowns; d/H = 0.975, whose film is 0.0125 H, the
most), a ``check_domain`` one up to 7 minutes and 9 GB, a ``quick`` one 6-60 s;
``--table --checks`` took 1.6 hours.
"""
from __future__ import annotations

import argparse
import dataclasses
import pathlib
import shlex
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import stokes_fem  # noqa: E402  (require(): the only way NGSolve is imported)

DATA_CSV = HERE.parent / "taichi_hsdem" / "data" / "sphere_in_gap.csv"
TABLE_DH = (0.3, 0.4, 0.5, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.875, 0.9, 0.925, 0.95, 0.975)
WALL_LAYER = 0.315          # displacement thickness of a no-slip side wall, over H
# The table's error bar: about three times the largest change measured against the
# checks over TABLE_DH (lambda 7e-5 and B_free 2.2e-4 a^2 absolute; B, C 3e-4
# relative, from the domain; F 1.1e-4 relative), rounded up.
ERROR_ESTIMATE = ("+-0.0002 on drift_ratio, +-0.0005 on dipole_free (units of a^2), "
                  "+-0.05 % on dipole_fixed and dipole_moving, +-0.03 % on f_fix and f_mov")
CSV_COLUMNS = ("d_over_H", "drift_ratio", "dipole_free", "dipole_fixed", "dipole_moving",
               "f_fix", "f_mov", "ndof", "mesh", "domain")


@dataclasses.dataclass(frozen=True)
class Settings(stokes_fem.MeshSettings):
    """One solve. Lengths over ``H``; ``W``, ``L`` over ``ell = max(d, 0.7 H)``.

    Attributes
    ----------
    dh : float
        ``d / H``.
    W, L : float
        Half-width (side wall at ``y = W ell``) and half-length (ends at
        ``x = -+L ell``).
    sidewall : {"slip", "noslip"}
    h_far, h_part, h_film : float
        Element size caps: far field over ``H``, on the sphere over ``a``, in the
        film over its local thickness.
    order : int
        Velocity order ``k`` of Taylor-Hood P_k/P_(k-1).
    """

    dh: float
    W: float = 4.0
    L: float = 8.0
    sidewall: str = "slip"
    h_far: float = 0.25
    h_part: float = 0.1
    h_film: float = 0.35
    order: int = 3

    @property
    def ell(self):
        return max(self.dh, 0.7)

    def domain_label(self):
        return f"W={self.W:g}ell L={self.L:g}ell {self.sidewall}"

    def tag(self):
        return f"dh{self.dh:g}_W{self.W:g}_L{self.L:g}_{self.sidewall}_{self.mesh_tag()}"


# Presets (mesh and domain; d/H is given separately). "table" is the CSV's;
# "quick" is the test's (tests/test_stokes_sphere_gap.py): ~10 s at d/H = 0.7.
PRESETS = {
    "table": dict(W=4.0, L=8.0, sidewall="slip", h_far=0.25, h_part=0.1, h_film=0.35, order=3),
    "check_mesh": dict(W=4.0, L=8.0, sidewall="slip", h_far=0.3, h_part=0.15, h_film=0.5, order=3),
    "check_domain": dict(W=6.0, L=12.0, sidewall="noslip", h_far=0.3, h_part=0.15, h_film=0.5,
                         order=3),
    "quick": dict(W=3.0, L=6.0, sidewall="slip", h_far=0.5, h_part=0.3, h_film=1.0, order=3),
}


def preset(name, dh, **overrides):
    """:class:`Settings` of preset ``name`` at ``d/H = dh``, with ``overrides``."""
    kw = dict(PRESETS[name])
    kw.update({k: v for k, v in overrides.items() if v is not None})
    return Settings(dh=float(dh), **kw)


# --------------------------------------------------------------------------- mesh

def build_mesh(s: Settings, ng, occ):
    """The quarter domain's curved tetrahedral mesh (refined over the film:
    ``stokes_fem.film_points``).

    Faces: ``inlet`` (x = -L), ``outlet`` (x = L), ``sym`` (y = 0), ``wall``
    (y = W), ``plate`` (z = 0), ``mid`` (z = H/2), ``particle``.
    """
    W, L = s.W * s.ell, s.L * s.ell
    return stokes_fem.sphere_box_mesh(s, ng, occ, (-L, 0, 0), (L, W, 0.5),
                                      ("inlet", "outlet", "sym", "wall", "plate", "mid"))


# -------------------------------------------------------------------------- solve

def solve_pair(mesh, s: Settings, ng, p_drop):
    """Assemble once, factorise once, solve the fixed and the moving problem.

    Returns
    -------
    fields : dict
        ``{"fixed": GridFunction, "moving": GridFunction}`` (velocity, pressure).
    info : dict
        ``ndof``, ``elements``, timings, and per problem the reaction force
        ``F`` (whole sphere, x), the traction integral's relative difference
        ``F_surface_rel``, and the inlet and outlet fluxes of the quarter.
    """
    walls = "plate|particle" + ("|wall" if s.sidewall == "noslip" else "")
    V = ng.VectorH1(mesh, order=s.order, dirichletx=walls,
                    dirichlety="plate|particle|wall|sym", dirichletz=walls + "|mid")
    Q = ng.H1(mesh, order=s.order - 1)
    X = V * Q
    (u, p), (v, q) = X.TnT()
    n = ng.specialcf.normal(3)
    t0 = time.perf_counter()
    form = ng.BilinearForm(X)
    form += (ng.InnerProduct(ng.grad(u), ng.grad(v)) - ng.div(v) * p - ng.div(u) * q) * ng.dx
    form.Assemble()
    t1 = time.perf_counter()
    inv = form.mat.Inverse(X.FreeDofs(), inverse="umfpack")
    t2 = time.perf_counter()

    rhs = {"fixed": ng.LinearForm(X), "moving": ng.LinearForm(X)}
    rhs["fixed"] += -p_drop * (v * n) * ng.ds("inlet")
    fields, w = stokes_fem.solve_fixed_moving(ng, X, form, inv, rhs, mesh.Boundaries("particle"),
                                              ng.CF((1, 0, 0)))
    info = {"ndof": X.ndof, "elements": mesh.ne, "t_assemble": t1 - t0, "t_factor": t2 - t1}
    for key, g in fields.items():
        r = g.vec.CreateVector()
        r.data = form.mat * g.vec - rhs[key].vec
        force = -4.0 * ng.InnerProduct(r, w.vec)
        vel, pres = g.components
        traction = (ng.BoundaryFromVolumeCF(ng.Grad(vel)) * n
                    - ng.BoundaryFromVolumeCF(pres) * n)
        surface = -4.0 * ng.Integrate(traction[0], mesh, ng.BND,
                                      definedon=mesh.Boundaries("particle"),
                                      order=2 * s.order + 2)
        flux = [float(ng.Integrate(vel * n, mesh, ng.BND, definedon=mesh.Boundaries(b)))
                for b in ("inlet", "outlet")]
        info[key] = {"F": force, "F_surface_rel": surface / force - 1.0,
                     "flux_in": -flux[0], "flux_out": flux[1]}
    return fields, info


# --------------------------------------------------------------------- far field

def gap_average(mesh, pressure, xy, n_gauss=6):
    """Gap-averaged pressure at the points ``xy`` (NaN outside the fluid)."""
    g, wts = np.polynomial.legendre.leggauss(n_gauss)
    z = 0.25 * (g + 1.0)                                    # 0 <= z <= H/2
    pts = mesh(np.repeat(xy[:, 0], n_gauss), np.repeat(xy[:, 1], n_gauss),
               np.tile(z, len(xy)))
    ok = pts["nr"] >= 0
    vals = np.full(len(ok), np.nan)
    vals[ok] = np.asarray(pressure(pts[ok])).ravel()
    return (vals.reshape(len(xy), n_gauss) * wts).sum(axis=1) / wts.sum()


def image_dipole(x, y, W):
    """``x / r^2`` plus its images in Neumann walls ``y = +-W``."""
    zeta = np.pi * (x + 1j * y) / (2.0 * W)
    return np.real(np.pi / (2.0 * W) / np.tanh(zeta))


def fit_far_field(xy, p, W):
    """Least-squares ``p = c0 + c1 x + D Phi``; returns ``(c0, c1, D)``, rms."""
    A = np.stack([np.ones(len(xy)), xy[:, 0], image_dipole(xy[:, 0], xy[:, 1], W)], axis=1)
    ok = np.isfinite(p)
    c, *_ = np.linalg.lstsq(A[ok], p[ok], rcond=None)
    return c, float(np.sqrt(np.mean((p[ok] - A[ok] @ c) ** 2)))


def sample_points(s: Settings, r_min=2.0, margin=1.0):
    """The fit's grid: spacing ``ell/4``, ``r >= r_min ell``, ``|x| <= L - margin ell``,
    ``y <= W - H/2``."""
    ell = s.ell
    W, L, step = s.W * ell, s.L * ell, 0.25 * ell
    xs = np.arange(-L + margin * ell, L - margin * ell + 1e-9, step)
    ys = np.arange(0.5 * step, W - 0.5 + 1e-9, step)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    return pts[np.hypot(pts[:, 0], pts[:, 1]) >= r_min * ell]


def ring_dipole(mesh, pressure, s: Settings, c, W_fit, radius):
    """``D`` from one ring ``r = radius`` alone (``c0``, ``c1`` from the full fit)."""
    th = np.linspace(0.0, np.pi, 181)[1:-1]
    pts = np.stack([radius * np.cos(th), radius * np.sin(th)], axis=1)
    pts = pts[(pts[:, 1] < s.W * s.ell) & (np.abs(pts[:, 0]) < s.L * s.ell - 0.5)]
    rest = gap_average(mesh, pressure, pts) - c[0] - c[1] * pts[:, 0]
    phi = image_dipole(pts[:, 0], pts[:, 1], W_fit)
    ok = np.isfinite(rest)
    return float(np.dot(rest[ok], phi[ok]) / np.dot(phi[ok], phi[ok]))


def analyse(mesh, fields, info, s: Settings):
    """Isolated-sphere coefficients from the two solves (module docstring)."""
    a = 0.5 * s.dh
    W_fit = s.W * s.ell - (WALL_LAYER if s.sidewall == "noslip" else 0.0)
    pts = sample_points(s)
    fits = {}
    for key, g in fields.items():
        pbar = gap_average(mesh, g.components[1], pts)
        c, rms = fit_far_field(pts, pbar, W_fit)
        fits[key] = {"c": c, "rms_rel": rms / float(np.nanmax(pbar) - np.nanmin(pbar)),
                     "n_points": int(np.isfinite(pbar).sum())}

    def ambient_speed(c):     # U = G H^2 / 12, G = -(c1 + D pi^2 / 12 W^2)
        return -(c[1] + c[2] * np.pi ** 2 / (12.0 * W_fit ** 2)) / 12.0

    cF, cM = fits["fixed"]["c"], fits["moving"]["c"]
    UF, UM = ambient_speed(cF), ambient_speed(cM)
    B = -cF[2] / (12.0 * UF)
    f_fix = info["fixed"]["F"] / UF
    f_mov = info["moving"]["F"] - f_fix * UM                 # V = 1
    C = (cM[2] + B * 12.0 * UM) / 12.0
    lam = f_fix / -f_mov
    rings = {}
    for r in (1.5, 2.0, 2.5, 3.0):
        D = ring_dipole(mesh, fields["fixed"].components[1], s, cF, W_fit, r * s.ell)
        rings[f"{r:g}"] = -D / (12.0 * UF) / a ** 2
    U_far = -cF[1] / 12.0
    return {
        "drift_ratio": lam,
        "dipole_free": (B - lam * C) / a ** 2,
        "dipole_fixed": B / a ** 2,
        "dipole_moving": C / a ** 2,
        "f_fix": f_fix / a,
        "f_mov": f_mov / a,
        "diagnostics": {
            "U_ambient_fixed": UF, "U_ambient_moving": UM,
            "fit_rms_rel": {k: v["rms_rel"] for k, v in fits.items()},
            "fit_points": fits["fixed"]["n_points"],
            "ring_dipole_fixed": rings,
            "ring_spread_rel": (max(rings.values()) - min(rings.values())) / (B / a ** 2),
            "raw_drift_ratio": info["fixed"]["F"] / U_far / -info["moving"]["F"],
            "raw_f_fix": info["fixed"]["F"] / U_far / a,
        },
    }


def run(s: Settings, threads=1, verbose=False):
    """Mesh, solve and analyse one :class:`Settings`; returns a JSON-ready dict."""
    def solve(mesh, ng):
        p_drop = 12.0 * 2.0 * s.L * s.ell        # U ~ 1
        fields, info = solve_pair(mesh, s, ng, p_drop)
        return analyse(mesh, fields, info, s), info

    return stokes_fem.run_sphere(s, threads, verbose, build_mesh, solve,
                                 labels={"domain": s.domain_label()})


# --------------------------------------------------------------------------- table

def cached_run(s: Settings, runs_dir, threads):
    """:func:`run`, or the JSON of an earlier run of the same settings in ``runs_dir``."""
    return stokes_fem.cached_run(s, runs_dir, lambda s: run(s, threads, verbose=True),
                                 "lambda {drift_ratio:.5f}  B_free/a^2 {dipole_free:.4f}")


QUANTITIES = ("drift_ratio", "dipole_free", "dipole_fixed", "dipole_moving", "f_fix", "f_mov")


def changes(ref, other):
    """Differences of ``other`` from ``ref``: absolute for lambda and for
    ``dipole_free`` (which is small at small d/H), relative otherwise."""
    out = {"drift_ratio": abs(other["drift_ratio"] - ref["drift_ratio"]),
           "dipole_free": abs(other["dipole_free"] - ref["dipole_free"])}
    for k in ("dipole_fixed", "dipole_moving", "f_fix", "f_mov"):
        out[k] = abs(other[k] / ref[k] - 1.0)
    return out


def write_table(rows, path, command, error_line):
    comments = [f"3D Stokes (NGSolve), sphere at mid-gap, isolated (side-wall images removed); "
                f"reproduce: {command}",
                error_line,
                "dipoles over a^2 (p' = -B G x/r^2 fixed, +C 12 eta V/H^2 x/r^2 moving, "
                "B_free = B - lambda C); f_fix = F_fix/(eta U a), f_mov = F_mov/(eta V a); "
                "mesh h_far/h_part/h_film P_order; domain in ell = max(d, 0.7H)"]
    cells = [[f"{r['settings']['dh']:g}", f"{r['drift_ratio']:.5f}", f"{r['dipole_free']:.5f}",
              f"{r['dipole_fixed']:.5f}", f"{r['dipole_moving']:.5f}", f"{r['f_fix']:.4f}",
              f"{r['f_mov']:.4f}", r["ndof"], r["mesh"], r["domain"]] for r in rows]
    stokes_fem.write_table(path, comments, CSV_COLUMNS, cells)


def read_table(path=DATA_CSV):
    """The CSV as a dict ``{d_over_H: row}`` (numbers as floats)."""
    return {row["d_over_H"]: row
            for row in stokes_fem.read_table(path, text=("mesh", "domain"))}


def table(dhs, csv_path, runs_dir, threads, checks, command):
    rows, worst = [], {k: (0.0, None) for k in QUANTITIES}
    for dh in dhs:
        ref = cached_run(preset("table", dh), runs_dir, threads)
        rows.append(ref)
        if checks:
            m = cached_run(preset("check_mesh", dh), runs_dir, threads)
            dom = cached_run(preset("check_domain", dh), runs_dir, threads)
            for k, v in changes(ref, m).items():          # mesh error
                if v > worst[k][0]:
                    worst[k] = (v, f"mesh at {dh:g}")
            for k, v in changes(m, dom).items():          # domain error, same mesh
                if v > worst[k][0]:
                    worst[k] = (v, f"domain at {dh:g}")
    if checks:
        parts = [f"{k} {v:.1e} ({where})" for k, (v, where) in worst.items()]
        error_line = (f"estimated error: {ERROR_ESTIMATE}; largest change measured against "
                      "the checks (mesh: 0.3/0.15/0.5 P3 against the table's; domain: "
                      "W=6ell L=12ell no-slip against W=4ell L=8ell slip, both on "
                      "0.3/0.15/0.5 P3; lambda and dipole_free absolute, the "
                      "others relative): " + "; ".join(parts))
    else:
        error_line = "no checks run (--checks measures the mesh and domain error)"
    write_table(rows, csv_path, command, error_line)
    return rows, worst


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dh", type=float, help="d/H of a single run")
    stokes_fem.add_run_options(ap, PRESETS, DATA_CSV, table="TABLE_DH", axis="dh", label="d/H",
                               checks="mesh and domain checks")
    ap.add_argument("--W", type=float, help="half-width / ell")
    ap.add_argument("--L", type=float, help="half-length / ell")
    ap.add_argument("--sidewall", choices=("slip", "noslip"))
    stokes_fem.add_mesh_options(ap)
    args = ap.parse_args(argv)
    if stokes_fem.extra_missing("stokes_sphere_gap", args.threads):
        return 2
    if args.table:
        dhs = ([float(v) for v in args.table_dh.split(",")] if args.table_dh else TABLE_DH)
        # the command that recomputes this table (--runs is only a cache, --csv the place)
        command = "python tools/stokes_sphere_gap.py --table" + (" --checks" if args.checks
                                                                 else "")
        if args.table_dh:
            command += " --table-dh " + shlex.quote(args.table_dh)
        rows, worst = table(dhs, args.csv, args.runs, args.threads, args.checks, command)
        for r in rows:
            print(f"{r['settings']['dh']:6g} lambda {r['drift_ratio']:.5f}  B_free "
                  f"{r['dipole_free']:.5f}  B {r['dipole_fixed']:.5f}  C {r['dipole_moving']:.5f}")
        print(f"wrote {args.csv}")
        return 0
    if args.dh is None:
        ap.error("give --dh or --table")
    name = "quick" if args.quick else (args.preset or "table")
    s = preset(name, args.dh, W=args.W, L=args.L, sidewall=args.sidewall, h_far=args.hfar,
               h_part=args.hpart, h_film=args.hfilm, order=args.order)
    rec = run(s, args.threads, verbose=True)
    summary = {k: rec[k] for k in QUANTITIES + ("ndof", "mesh", "domain", "wall_s")}
    summary["ring_spread_rel"] = rec["diagnostics"]["ring_spread_rel"]
    summary["F_surface_rel"] = {k: rec["solve"][k]["F_surface_rel"] for k in ("fixed", "moving")}
    stokes_fem.print_run(rec, summary, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
