"""Free drift of a square monolayer lattice of spheres at mid-gap: 3D Stokes, NGSolve.

Identical spheres of diameter ``d`` (radius ``a = d/2``) are centred at mid-gap
between two no-slip plates a distance ``H`` apart. They form a square lattice of
period ``L = a sqrt(pi / phi)`` in ``x`` and ``y``, so ``phi = pi a^2 / L^2`` is
the fraction of the plate's area that the spheres cover (their solid volume
fraction is ``eps = (2/3) (d/H) phi``). A mean pressure gradient ``-G`` along
``x`` drives the flow, and every sphere moves freely: it is force-free along
``x``, and by symmetry it feels no other force or torque. This tool computes

``drift_over_mean`` (``V / U_mean``)
    The spheres' speed ``V`` over the mean volume flux per unit area of the
    cross-section, ``U_mean = Q_total / (L H)``. ``Q_total`` is the total
    (fluid + solid) volume flux through one cell's cross-section. ``U_mean``
    is the superficial speed of the mixture, the ``U`` of ``Q = U H W``.
``drift_over_fluid`` (``V / U_fluid``)
    ``V`` over the fluid's own mean velocity, ``U_fluid = int_fluid u_x dV /
    V_fluid``. Equivalently ``U_fluid = (U_mean - eps V) / (1 - eps)``.
``mean_over_poiseuille`` (``U_mean / U_P``)
    The permeability of the suspension of free spheres: ``U_P = G H^2 / (12
    eta)`` is the plane-Poiseuille mean speed at the same mean gradient, with
    no spheres.

As ``phi -> 0``, ``V / U_mean`` tends to the isolated sphere's drift ratio
lambda (tools/stokes_sphere_gap.py). Its slope there is ``lambda B_free / a^2``,
from the far-field dipole of the free sphere (``V / U_mean = lambda / (1 - phi
B_free / a^2)`` for point dipoles on the lattice).

Method
------
Units ``H = 1``, ``eta = 1``, ``G = 12`` (so ``U_P = 1``). The sphere is centred
at ``(0, 0, H/2)``. Taylor-Hood P_k/P_(k-1), gradient form ``(grad u, grad v) -
(div v, p) - (div u, q)``, geometry curved to order ``k``, UMFPACK. The three
velocity components are separate scalar H1 spaces, each with its own Dirichlet
faces. (In NGSolve 6.2.2608, ``Periodic(VectorH1(..., dirichletx=...))`` drops
the per-component flags.)

*Computed domain* (``--xmode sym``, the default): 1/8 of the unit cell,
``0 <= x <= L/2``, ``0 <= y <= L/2``, ``0 <= z <= H/2``.

* ``y = 0``, ``y = L/2`` and ``z = H/2`` are mirror planes: zero normal
  velocity and no shear.
* ``x = 0`` and ``x = L/2`` are planes of Stokes reversibility. The geometry
  is even in ``x``, so reversing the flow and reflecting ``x`` maps the
  solution onto itself. Hence ``u_x`` is even, ``u_y`` and ``u_z`` are odd, and
  ``p`` is odd about a constant. Periodicity gives the same about ``x = L/2``.
  On these planes ``u_y = u_z = 0`` and ``du_x/dx = 0``, so the gradient
  form's natural condition is exactly a given pressure. The fixed problem
  takes ``p = 0`` at ``x = 0`` and ``p = -G L/2`` at ``x = L/2``; the moving
  problem takes ``p = 0`` on both.
* The plate ``z = 0`` and the sphere are no-slip.

*Independent check* (``--xmode periodic``): 1/4 of the cell, ``-L/2 <= x <=
L/2``, with the two ``x`` faces identified (periodic spaces). The mean
gradient is a body force ``G e_x``, and a NumberSpace multiplier fixes the
mean of the periodic pressure. The physical pressure ``p_per - G x`` adds the
force ``G (4/3) pi a^3`` on the sphere. This formulation agrees with ``sym`` to
within the mesh error. In ``V / U_mean`` the difference is 2e-7 at phi = 0.1
(0.3/0.15/0.5 P4) and 2.5e-5 at 0.26 (0.2/0.1/0.35 P3). The periodic cell's
meshes are coarser near the sphere, so they converge more slowly: at 0.26,
0.3/0.15/0.5 P3 is still 2e-4 off.

*Two solves, one LU*. A single assembly and UMFPACK factorisation serve both
problems:

* **fixed**: ``u = 0`` on the sphere, mean gradient ``-G``;
* **moving**: ``u = e_x`` on the sphere, mean gradient zero.

*Force*: the consistent reaction ``F_x = -R(w)``. ``R`` is the residual of the
weak form, and ``w`` is the discrete field equal to ``e_x`` on the sphere's
degrees of freedom. The result is multiplied by the number of copies (8, or 4
for ``periodic``). The free sphere then has ``F_fix + V F_mov = 0``, so ``V =
-F_fix / F_mov``. The traction's surface integrals (gradient and symmetric
form) are reported beside it as a check (``F_surface_rel``).

*U_mean*: by linearity, ``Q_total = Q_fix + V Q_mov``. ``Q_fix`` and
``Q_mov`` are the integrals of ``u_x`` over the face ``x = L/2`` (times 4 for
the ``y`` and ``z`` mirrors). That face holds no solid, so this is the whole
flux through a cross-section. Then ``U_mean = Q_total / (L H)``. Two other
measures of the same flux must agree, and are reported as the relative
differences ``Q_check_x0`` and ``Q_check_volume``:

* at ``x = 0``, where the section cuts the sphere, the fluid's flux plus the
  solid's own flux ``V pi a^2``;
* the cell average of the mixture velocity, ``(int_fluid u_x dV + V (4/3) pi
  a^3) / L``.

They agree with ``Q_total`` to 1e-7 or better on the table's meshes.

*Mesh*: element size ``h_far H`` in general, ``h_part a`` on the sphere, and,
over the lubrication films to the plates, ``h_film`` times the local film
thickness ``h(rho) = delta + a - sqrt(a^2 - rho^2)``, where ``delta = (H -
d)/2`` and ``rho <= min(0.95 a, sqrt(8 a delta))``. The same refinement is
used by tools/stokes_sphere_gap.py.

*Accuracy* at ``d/H = 0.875``. The ``table`` preset (0.3/0.15/0.5 P4) and the
finer ``check_mesh`` (0.2/0.1/0.35 P3) differ by at most 4e-6 in ``V / U_mean``
and 7e-6 in ``U_mean / U_P``. At phi = 0.1 and 0.26 the table's ``V / U_mean``
agrees to 1e-6 with a still finer 0.15/0.07/0.25 P3. P3 on the table's mesh
(``check_order``) is up to 3.2e-5 off in ``V / U_mean`` and 6.1e-5 in
``U_mean / U_P``. The ``quick`` preset (0.4/0.2/0.7 P3) is up to 1.5e-4 off in
``V / U_mean`` (at phi = 0.1; 5.4e-5 at 0.26). ``--checks`` measures these
differences and writes them into the CSV's header.

Usage
-----
::

    python tools/stokes_sphere_lattice.py --dh 0.875 --phi 0.26 [--quick] [--out FILE.json]
    python tools/stokes_sphere_lattice.py --table [--checks] [--dh 0.875] [--csv FILE.csv] [--runs DIR]

``--table`` solves every ``phi`` of :data:`TABLE_PHI` with the ``table`` preset
and writes the CSV (default ``taichi_hsdem/data/sphere_lattice.csv``). It adds a
``phi = 0`` row (``cell_over_H = inf``): the quadratic extrapolation, column by
column, of the three smallest ``phi``. ``--checks`` also solves every ``phi``
with the ``check_order`` and ``check_mesh`` presets, and writes the largest
differences into the header line. ``--runs DIR`` keeps each solve's JSON there
and reuses any whose settings match. The options ``--xmode --hfar --hpart
--hfilm --order`` override the preset of a single run. NGSolve runs on one
thread by default (``--threads``); also export ``OMP_NUM_THREADS=1
OPENBLAS_NUM_THREADS=1`` to keep UMFPACK's BLAS on one core. NGSolve is imported
only through ``stokes_fem.require``. Without it (the ``stokes`` extra), the
command prints one line and exits with status 2.

Cost at ``d/H = 0.875``, on one thread of a loaded machine: the ``table`` preset
takes 17-130 s and up to 4 GB per ``phi``, the most at the smallest ``phi``
(the largest cell). ``check_mesh`` needs 8 GB at phi = 0.005, and ``--table
--checks`` takes about 15 minutes in all. ``quick`` takes a few seconds at
``phi = 0.26``.
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

DATA_CSV = HERE.parent / "taichi_hsdem" / "data" / "sphere_lattice.csv"
TABLE_PHI = (0.005, 0.01, 0.02, 0.05, 0.1, 0.18, 0.26, 0.3, 0.4)
CSV_COLUMNS = ("d_over_H", "phi", "cell_over_H", "drift_over_mean", "drift_over_fluid",
               "mean_over_poiseuille")
RATIOS = ("drift_over_mean", "drift_over_fluid", "mean_over_poiseuille")
G_MEAN = 12.0               # mean gradient of the fixed problem: U_P = G H^2 / 12 = 1


@dataclasses.dataclass(frozen=True)
class Settings(stokes_fem.MeshSettings):
    """One solve. Lengths are over ``H``.

    Attributes
    ----------
    dh : float
        ``d / H``, in (0, 1).
    phi : float
        Area fraction ``pi a^2 / L^2``, in (0, pi/4): the spheres must not touch.
    xmode : {"sym", "periodic"}
        The 1/8 cell with reversibility planes, or the periodic 1/4 cell (check).
    h_far, h_part, h_film : float
        Element size caps: far field over ``H``, on the sphere over ``a``, and in
        the film over its local thickness.
    order : int
        Velocity order ``k`` of Taylor-Hood P_k/P_(k-1).
    """

    dh: float
    phi: float
    xmode: str = "sym"
    h_far: float = 0.3
    h_part: float = 0.15
    h_film: float = 0.5
    order: int = 4

    def __post_init__(self):
        if not 0.0 < self.dh < 1.0:
            raise ValueError(f"d/H must lie in (0, 1), not {self.dh}")
        if not 0.0 < self.phi < 0.25 * math.pi:
            raise ValueError(f"phi must lie in (0, pi/4) (touching spheres), not {self.phi}")
        if self.xmode not in ("sym", "periodic"):
            raise ValueError(f"xmode is 'sym' or 'periodic', not {self.xmode!r}")
        if self.order < 2:
            raise ValueError("Taylor-Hood needs order >= 2")

    @property
    def a(self):
        return 0.5 * self.dh

    @property
    def L(self):
        """Lattice period over ``H``."""
        return self.a * math.sqrt(math.pi / self.phi)

    def tag(self):
        return f"{self.xmode}_dh{self.dh:g}_phi{self.phi:g}_{self.mesh_tag()}"


# Presets (mesh; d/H and phi are given separately). "table" is the CSV's; "quick"
# is the test's (tests/test_stokes_sphere_lattice.py): a few seconds at phi = 0.26.
PRESETS = {
    "table": dict(h_far=0.3, h_part=0.15, h_film=0.5, order=4),
    "check_order": dict(h_far=0.3, h_part=0.15, h_film=0.5, order=3),
    "check_mesh": dict(h_far=0.2, h_part=0.1, h_film=0.35, order=3),
    "quick": dict(h_far=0.4, h_part=0.2, h_film=0.7, order=3),
}


def preset(name, dh, phi, **overrides):
    """:class:`Settings` of preset ``name`` at ``d/H = dh`` and ``phi``, with ``overrides``
    (``None`` values ignored)."""
    kw = dict(PRESETS[name])
    kw.update({k: v for k, v in overrides.items() if v is not None})
    return Settings(dh=float(dh), phi=float(phi), **kw)


# --------------------------------------------------------------------------- mesh

def build_mesh(s: Settings, ng, occ):
    """The computed cell's curved tetrahedral mesh (refined over the film:
    ``stokes_fem.film_points``).

    Faces: ``xlo`` (x = 0, or -L/2 when periodic), ``xhi`` (x = L/2), ``ylo`` (y = 0),
    ``yhi`` (y = L/2), ``plate`` (z = 0), ``mid`` (z = H/2), ``particle``.
    """
    L = s.L
    sym = s.xmode == "sym"
    return stokes_fem.sphere_box_mesh(s, ng, occ, (0.0 if sym else -0.5 * L, 0, 0),
                                      (0.5 * L, 0.5 * L, 0.5),
                                      ("xlo", "xhi", "ylo", "yhi", "plate", "mid"),
                                      phimax=0.5 * math.pi if sym else math.pi,
                                      periodic_x=not sym)


# -------------------------------------------------------------------------- solve

def solve_pair(mesh, s: Settings, ng):
    """Assemble once, factorise once, and solve the fixed and the moving problem.

    Returns
    -------
    dict
        ``ndof``, ``elements``, ``copies``, timings, and, for each problem, the
        whole sphere's x-force ``F`` (reaction), the traction integrals' relative
        differences from it, the full cell's fluxes ``Q_xhi`` and ``Q_fluid_xlo``
        (fluid only), ``int_fluid_ux`` and ``fluid_volume`` (full cell), and the
        velocity's divergence (L2 norm).
    """
    sym = s.xmode == "sym"
    if sym:
        dirichlet = ("plate|particle", "plate|particle|ylo|yhi|xlo|xhi",
                     "plate|particle|mid|xlo|xhi")
    else:
        dirichlet = ("plate|particle", "plate|particle|ylo|yhi", "plate|particle|mid")
    wrap = (lambda space: space) if sym else ng.Periodic
    comps = [wrap(ng.H1(mesh, order=s.order, dirichlet=d)) for d in dirichlet]
    Qs = wrap(ng.H1(mesh, order=s.order - 1))
    if sym:
        X = comps[0] * comps[1] * comps[2] * Qs
        (ux, uy, uz, p), (vx, vy, vz, q) = X.TnT()
    else:
        X = comps[0] * comps[1] * comps[2] * Qs * ng.NumberSpace(mesh)
        (ux, uy, uz, p, lam), (vx, vy, vz, q, mu) = X.TnT()
    u3, v3 = (ux, uy, uz), (vx, vy, vz)
    div_u = sum(ng.grad(c)[i] for i, c in enumerate(u3))
    div_v = sum(ng.grad(c)[i] for i, c in enumerate(v3))
    n = ng.specialcf.normal(3)
    t0 = time.perf_counter()
    form = ng.BilinearForm(X)
    form += (sum(ng.grad(c) * ng.grad(t) for c, t in zip(u3, v3))
             - div_v * p - div_u * q) * ng.dx
    if not sym:
        form += (p * mu + q * lam) * ng.dx
    form.Assemble()
    t1 = time.perf_counter()
    inv = form.mat.Inverse(X.FreeDofs(), inverse="umfpack")
    t2 = time.perf_counter()
    copies = 8.0 if sym else 4.0

    rhs = {"fixed": ng.LinearForm(X), "moving": ng.LinearForm(X)}
    if sym:   # traction -p_b n with p_b = -G L/2 at x = L/2 (p = 0 at x = 0)
        rhs["fixed"] += (G_MEAN * 0.5 * s.L) * vx * n[0] * ng.ds("xhi")
    else:
        rhs["fixed"] += G_MEAN * vx * ng.dx
    particle = mesh.Boundaries("particle")
    fields, w = stokes_fem.solve_fixed_moving(ng, X, form, inv, rhs, particle, ng.CF(1.0))
    # periodic: the solved pressure is the periodic part; the physical p_per - G x
    # pushes the held sphere with G times its volume
    body = 0.0 if sym else G_MEAN * 4.0 / 3.0 * math.pi * s.a ** 3
    info = {"ndof": X.ndof, "elements": mesh.ne, "copies": copies,
            "t_assemble": t1 - t0, "t_factor": t2 - t1}
    for key, g in fields.items():
        r = g.vec.CreateVector()
        r.data = form.mat * g.vec - rhs[key].vec
        extra = body if key == "fixed" else 0.0
        force = -copies * ng.InnerProduct(r, w.vec) + extra
        grad_u = ng.CF(tuple(ng.Grad(g.components[i]) for i in range(3)), dims=(3, 3))
        gb = ng.BoundaryFromVolumeCF(grad_u)
        pb = ng.BoundaryFromVolumeCF(g.components[3])
        surface = {}
        for name, tr in (("grad", gb * n - pb * n), ("sym", (gb + gb.trans) * n - pb * n)):
            surface[name] = -copies * ng.Integrate(tr[0], mesh, ng.BND, definedon=particle,
                                                   order=2 * s.order + 2) + extra
        ux_h = g.components[0]
        info[key] = {
            "F": force,
            "F_surface_rel": {k: v / force - 1.0 for k, v in surface.items()},
            "Q_xhi": 4.0 * ng.Integrate(ux_h, mesh, ng.BND, definedon=mesh.Boundaries("xhi")),
            "Q_fluid_xlo": 4.0 * ng.Integrate(ux_h, mesh, ng.BND,
                                              definedon=mesh.Boundaries("xlo")),
            "int_fluid_ux": copies * ng.Integrate(ux_h, mesh),
            "fluid_volume": copies * ng.Integrate(ng.CF(1.0), mesh),
            "div_L2": math.sqrt(ng.Integrate((grad_u[0, 0] + grad_u[1, 1] + grad_u[2, 2]) ** 2,
                                             mesh)),
        }
    info["t_solve"] = time.perf_counter() - t0
    return info


def analyse(info, s: Settings):
    """Free-sphere speed and the three ratios from the two solves (module docstring).

    Returns
    -------
    dict
        The CSV's quantities, ``V``, ``Q_total``, ``U_mean``, ``U_fluid``, and the
        checks ``Q_check_x0`` and ``Q_check_volume`` (relative differences from
        ``Q_total``). Also the fixed array's ``k_fixed_over_k`` (``U_mean / U_P``
        with the spheres held) and the forces ``f_fix = F_fix / (eta U_P a)`` and
        ``f_mov = F_mov / (eta V a)``.
    """
    a, L, H = s.a, s.L, 1.0
    fx, mv = info["fixed"], info["moving"]
    V = -fx["F"] / mv["F"]
    Q = fx["Q_xhi"] + V * mv["Q_xhi"]
    U_mean = Q / (L * H)
    fluid_int = fx["int_fluid_ux"] + V * mv["int_fluid_ux"]
    U_fluid = fluid_int / fx["fluid_volume"]
    vol_sphere = 4.0 / 3.0 * math.pi * a ** 3
    Q_volume = (fluid_int + V * vol_sphere) / L
    # sym: x = 0 cuts the sphere (its solid flux V pi a^2 added); periodic: x = -L/2, no solid
    solid = math.pi * a * a if s.xmode == "sym" else 0.0
    Q_x0 = fx["Q_fluid_xlo"] + V * (mv["Q_fluid_xlo"] + solid)
    U_P = G_MEAN * H ** 2 / 12.0
    return {
        "d_over_H": s.dh, "phi": s.phi, "cell_over_H": L,
        "drift_over_mean": V / U_mean,
        "drift_over_fluid": V / U_fluid,
        "mean_over_poiseuille": U_mean / U_P,
        "V": V, "Q_total": Q, "U_mean": U_mean, "U_fluid": U_fluid,
        "solid_volume_fraction": vol_sphere / (L * L * H),
        "Q_check_x0": Q_x0 / Q - 1.0,
        "Q_check_volume": Q_volume / Q - 1.0,
        "k_fixed_over_k": fx["Q_xhi"] / (L * H) / U_P,
        "f_fix": fx["F"] / (U_P * a),
        "f_mov": mv["F"] / a,
    }


def run(s: Settings, threads=1, verbose=False):
    """Mesh, solve and analyse one :class:`Settings`; returns a JSON-ready dict."""
    def solve(mesh, ng):
        info = solve_pair(mesh, s, ng)
        return analyse(info, s), info

    return stokes_fem.run_sphere(s, threads, verbose, build_mesh, solve,
                                 note=f"L = {s.L:.4f} H, ")


# --------------------------------------------------------------------------- table

def cached_run(s: Settings, runs_dir, threads):
    """:func:`run`, or the JSON of an earlier run of the same settings in ``runs_dir``."""
    return stokes_fem.cached_run(s, runs_dir, lambda s: run(s, threads, verbose=True),
                                 "V/U_mean {drift_over_mean:.6f}  V/U_fluid "
                                 "{drift_over_fluid:.6f}  U_mean/U_P {mean_over_poiseuille:.6f}")


def extrapolate_zero(rows, n=3):
    """The ``phi = 0`` row: a quadratic in ``phi`` through the ``n`` smallest ``phi``,
    one ratio at a time."""
    low = sorted(rows, key=lambda r: r["phi"])[:n]
    phis = np.array([r["phi"] for r in low])
    out = {"d_over_H": low[0]["d_over_H"], "phi": 0.0, "cell_over_H": math.inf}
    for k in RATIOS:
        out[k] = float(np.polyval(np.polyfit(phis, [r[k] for r in low], 2), 0.0))
    return out


def write_table(rows, path, header):
    """Write the CSV: one ``#`` line (``header``), the column names, then the rows."""
    cells = [[f"{r['d_over_H']:g}", f"{r['phi']:g}",
              "inf" if math.isinf(r["cell_over_H"]) else f"{r['cell_over_H']:.6f}"]
             + [f"{r[k]:.6f}" for k in RATIOS] for r in sorted(rows, key=lambda r: r["phi"])]
    stokes_fem.write_table(path, [header.replace("\n", " ")], CSV_COLUMNS, cells)


def read_table(path=DATA_CSV):
    """The CSV as a list of rows (dicts of floats), in file order."""
    return stokes_fem.read_table(path)


def table(dh, phis, csv_path, runs_dir, threads, checks, command):
    """Solve every ``phi`` (and with ``checks`` the check presets), write the CSV.

    Returns
    -------
    rows : list of dict
        The CSV's rows, the extrapolated ``phi = 0`` one first.
    header : str
        The CSV's comment line.
    """
    recs = [cached_run(preset("table", dh, phi), runs_dir, threads) for phi in phis]
    rows = [{k: r[k] for k in CSV_COLUMNS} for r in recs]
    flux = max(max(abs(r["Q_check_x0"]), abs(r["Q_check_volume"])) for r in recs)
    parts = [f"3D Stokes (NGSolve, tools/stokes_sphere_lattice.py): free spheres at mid-gap "
             f"in a square lattice (period cell_over_H); drift V over U_mean = Q_total/(L H) "
             f"(fluid + solid flux), over the fluid's mean velocity, and U_mean over plane "
             f"Poiseuille at the same mean gradient; mesh {preset_label('table')}; "
             f"reproduce: {command}",
             f"flux balance within {flux:.0e}"]
    if len(rows) >= 3:
        rows.insert(0, extrapolate_zero(rows))
        low = ", ".join(f"{p:g}" for p in sorted(phis)[:3])
        parts.append(f"phi = 0 row: quadratic extrapolation of phi = {low}")
    if checks:
        largest = {}
        for name in ("check_order", "check_mesh"):
            worst = {k: (0.0, None) for k in RATIOS}
            for ref in recs:
                other = cached_run(preset(name, dh, ref["phi"]), runs_dir, threads)
                for k in RATIOS:
                    d = abs(other[k] - ref[k])
                    if d > worst[k][0]:
                        worst[k] = (d, ref["phi"])
                    largest[name] = max(largest.get(name, 0.0), d)
            parts.append(f"largest difference from {preset_label(name)}: " + ", ".join(
                f"{k} {v:.1e} (phi {p:g})" for k, (v, p) in worst.items()))
        parts.append(f"error estimate +-{round_up(largest['check_mesh']):.0e} on the ratios "
                     f"(the largest difference from the finer mesh; each check is the less "
                     f"accurate of its pair, so at most "
                     f"+-{round_up(max(largest.values())):.0e} with the P3 check as well)")
    else:
        parts.append("no mesh checks run (--checks measures them)")
    header = "; ".join(parts)
    write_table(rows, csv_path, header)
    return rows, header


def round_up(x):
    """``x`` rounded up to one significant digit."""
    if x <= 0.0:
        return 0.0
    e = 10.0 ** math.floor(math.log10(x))
    return math.ceil(x / e - 1e-9) * e


def preset_label(name):
    """Preset ``name``'s mesh as ``h_far/h_part/h_film P_order``."""
    return stokes_fem.mesh_label(**PRESETS[name])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dh", type=float, default=0.875, help="d/H (%(default)s)")
    ap.add_argument("--phi", type=float, help="area fraction pi a^2/L^2 of a single run")
    stokes_fem.add_run_options(ap, PRESETS, DATA_CSV, table="TABLE_PHI", axis="phi",
                               label="phi", checks="the mesh checks")
    ap.add_argument("--xmode", choices=("sym", "periodic"), help="1/8 cell (sym) or periodic")
    stokes_fem.add_mesh_options(ap)
    args = ap.parse_args(argv)
    if stokes_fem.extra_missing("stokes_sphere_lattice", args.threads):
        return 2
    if args.table:
        if not 0.0 < args.dh < 1.0:
            ap.error(f"d/H must lie in (0, 1), not {args.dh}")
        phis = ([float(v) for v in args.table_phi.split(",")] if args.table_phi else TABLE_PHI)
        # the options that decide the numbers (--runs is a cache, --csv the output)
        command = f"python tools/stokes_sphere_lattice.py --table --dh {args.dh:g}"
        if args.table_phi:
            command += f" --table-phi {shlex.quote(args.table_phi)}"
        if args.checks:
            command += " --checks"
        rows, header = table(args.dh, phis, args.csv, args.runs, args.threads, args.checks,
                             command)
        for r in rows:
            print(f"phi {r['phi']:6g}  L/H {r['cell_over_H']:8.4f}  V/U_mean "
                  f"{r['drift_over_mean']:.6f}  V/U_fluid {r['drift_over_fluid']:.6f}  "
                  f"U_mean/U_P {r['mean_over_poiseuille']:.6f}")
        print(f"# {header}\nwrote {args.csv}")
        return 0
    if args.phi is None:
        ap.error("give --phi or --table")
    name = "quick" if args.quick else (args.preset or "table")
    try:
        s = preset(name, args.dh, args.phi, xmode=args.xmode, h_far=args.hfar,
                   h_part=args.hpart, h_film=args.hfilm, order=args.order)
    except ValueError as exc:
        ap.error(str(exc))
    rec = run(s, args.threads, verbose=True)
    keys = CSV_COLUMNS + ("V", "U_mean", "U_fluid", "Q_check_x0", "Q_check_volume",
                          "k_fixed_over_k", "f_fix", "f_mov", "mesh", "ndof", "wall_s")
    summary = {k: rec[k] for k in keys}
    summary["F_surface_rel"] = {k: rec["solve"][k]["F_surface_rel"] for k in ("fixed", "moving")}
    summary["xmode"] = s.xmode
    stokes_fem.print_run(rec, summary, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
