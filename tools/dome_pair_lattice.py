"""A prototype, not the model: tools/model_pair_lattice.py with a depth-resolved
("dome") sphere in place of the model's uniform disk, to test whether the sphere's
depth profile gives the 3D pair interactions (docs/validation.md, "The escapee
stream"; it does not: it halves the model's side-by-side excess mostly by leaving
a weaker dipole, keeps its sign, and drifts 16-23 % slow without a fitted drag).

A sphere of radius a at mid-gap leaves, at in-plane distance r < a, two films
(above/below) of total open thickness h(r) = H - 2 sqrt(a^2 - r^2), each h/2.
Lubrication in each film (sphere at velocity w, plates fixed):
  flux per unit width (both films) = -(h^3/48) grad p / eta + w h/2
  => H kappa(r) = h^3/48  (films=2; the brief's single-gap h^3/12 is films=1)
  carried per unit area  = (H - h) w + w h/2 => c(r) = 1 - h/(2H)
Force per unit area on the sphere:
  pressure (projected, by parts)  -(H - h) grad p
  film shear (Poiseuille part)    -(h/2) grad p
  film shear (Couette part)       -(4 eta / h) w
  total                           -H c(r) grad p - (4 eta/h) w
The pressure/Poiseuille part is discretised as the exact adjoint of the carried
flux (generalised force Q_k = H sum_f (p_a - p_b) q_f^(k)), so the mobility matrix
is symmetric. The Couette drag matrix D is integrated exactly (quad), no grid.
DOFs per disk: Vx, Vy, Omega_z (rigid motion w = V + Omega x (r - r_c)).
Force-free (and torque-free with spin): (D - M) v = Q_fix.

Discretisation: cell kappa = arithmetic mean of kappa(r) over ns x ns sub-samples
in the cell (ns=1: cell centre), harmonic mean across faces (as the tool);
face carried flux = h * mean over ns x ns sub-samples of the face's dual square of
c(r) w.n (ns=1: face midpoint).
"""
from __future__ import annotations

import math
import pathlib
import sys
import time

import numpy as np
from scipy.integrate import quad

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from taichi_hsdem import load_scene  # noqa: E402
from taichi_hsdem.resolve import resolve  # noqa: E402
from taichi_hsdem.laws import harmonic_mean  # noqa: E402
from model_pair_lattice import (lattice_parser, layout, periodic_operator,  # noqa: E402
                                report)

SCENE = str(HERE.parent / "scenes" / "vani_phi026.toml")


class DomeLattice:
    def __init__(self, model, nx, ny, ns=4, films=2):
        s = model.species[0]
        self.h = float(model.fluid_dx)
        self.nx, self.ny = nx, ny
        self.H = float(model.scene.fluid.gap)
        self.eta = float(model.scene.fluid.viscosity)
        self.kf = float(model.kappa_free)
        self.a = float(s.shape.radius)
        self.ns = ns
        self.films = films
        n = nx * ny
        flat = np.arange(n).reshape(nx, ny)
        self.fa = np.concatenate([flat.ravel(), flat.ravel()])
        self.fb = np.concatenate([np.roll(flat, -1, axis=0).ravel(),
                                  np.roll(flat, -1, axis=1).ravel()])
        self.is_x = np.concatenate([np.ones(n, bool), np.zeros(n, bool)])
        self.n = n
        hh = self.h
        I, J = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        sub = (np.arange(ns) + 0.5) / ns - 0.5           # offsets within a square of side 1
        su, sv = np.meshgrid(sub, sub, indexing="ij")
        su, sv = su.ravel() * hh, sv.ravel() * hh
        # cell sub-samples
        cx = ((I + 0.5) * hh).ravel()[:, None] + su[None]
        cy = ((J + 0.5) * hh).ravel()[:, None] + sv[None]
        self.cell_pts = (cx, cy)
        # face dual squares: x-face midpoint ((i+1)h, (j+.5)h); y-face ((i+.5)h, (j+1)h)
        fxx = ((I + 1.0) * hh).ravel()[:, None] + su[None]
        fxy = ((J + 0.5) * hh).ravel()[:, None] + sv[None]
        fyx = ((I + 0.5) * hh).ravel()[:, None] + su[None]
        fyy = ((J + 1.0) * hh).ravel()[:, None] + sv[None]
        self.face_pts = (np.concatenate([fxx, fyx]), np.concatenate([fxy, fyy]))
        # exact Couette drag: 4 eta / h(r) over the disk
        a, H, eta = self.a, self.H, self.eta
        hr = lambda r: H - 2.0 * math.sqrt(max(a * a - r * r, 0.0))
        self.D_tr = quad(lambda r: 4 * eta / hr(r) * 2 * math.pi * r, 0, a, limit=200)[0]
        self.D_rot = quad(lambda r: 4 * eta / hr(r) * 2 * math.pi * r ** 3, 0, a, limit=200)[0]

    def _rel(self, pts, centre):
        Lx, Ly = self.nx * self.h, self.ny * self.h
        dx = (pts[0] - centre[0] + 0.5 * Lx) % Lx - 0.5 * Lx
        dy = (pts[1] - centre[1] + 0.5 * Ly) % Ly - 0.5 * Ly
        return dx, dy

    def gap_h(self, r):
        return self.H - 2.0 * np.sqrt(np.clip(self.a ** 2 - r ** 2, 0.0, None))

    def kappa_of(self, r, inside):
        h = self.gap_h(r)
        k = h ** 3 / (12.0 * self.H) / (4.0 if self.films == 2 else 1.0)
        return np.where(inside, k, self.kf)

    def c_of(self, r):
        return 1.0 - self.gap_h(r) / (2.0 * self.H)

    def solve(self, centres, drag_scale=1.0):
        nb = len(centres)
        # permeability
        kap_s = np.full(self.cell_pts[0].shape, self.kf)
        for c in centres:
            dx, dy = self._rel(self.cell_pts, c)
            r = np.hypot(dx, dy)
            ins = r < self.a
            kap_s = np.where(ins, self.kappa_of(r, ins), kap_s)
        kappa = kap_s.mean(axis=1)
        T = harmonic_mean(kappa[self.fa], kappa[self.fb]) / self.eta
        # carried face fluxes per DOF (Vx, Vy, Om) of each disk
        qs = []
        for c in centres:
            dx, dy = self._rel(self.face_pts, c)
            r = np.hypot(dx, dy)
            ins = r < self.a
            cc = np.where(ins, self.c_of(r), 0.0)
            wx = np.where(self.is_x[:, None], 1.0, 0.0)
            wy = 1.0 - wx
            wom = np.where(self.is_x[:, None], -dy, dx)     # (Om z x rel).n
            for w in (wx, wy, wom):
                qs.append(self.h * (cc * w).mean(axis=1))
        n = self.n
        A, lu, gx_out = periodic_operator(T, self.fa, self.fb, self.is_x, n)
        nd = 3 * nb
        dp_list, flux_list, resid = [], [], 0.0
        self.pts = []
        for k in range(nd + 1):
            if k == 0:
                G, q = 1.0, np.zeros_like(T)
            else:
                G, q = 0.0, qs[k - 1]
            src = np.bincount(self.fb, q, n) - np.bincount(self.fa, q, n)
            rhs = src - G * self.h * gx_out
            pt = np.zeros(n)
            pt[1:] = lu.solve(rhs[1:])
            self.pts.append(pt.copy())
            resid = max(resid, float(np.abs((A @ pt - rhs)[1:]).max()))
            dp = pt[self.fa] - pt[self.fb] + np.where(self.is_x, G * self.h, 0.0)
            total = T * dp + q
            col = total[:n].reshape(self.nx, self.ny).sum(axis=1)
            dp_list.append(dp)
            flux_list.append((col.mean(), np.ptp(col)))
        Qmat = np.array([[self.H * np.dot(dp_list[l], qs[k]) for l in range(nd + 1)]
                         for k in range(nd)])   # Q_k from case l
        Qfix, M = Qmat[:, 0], Qmat[:, 1:]
        Dm = np.diag(np.tile([self.D_tr, self.D_tr, self.D_rot], nb)) * drag_scale
        out = {}
        for spin in (True, False):
            idx = np.arange(nd) if spin else np.array([k for k in range(nd) if k % 3 != 2])
            v = np.zeros(nd)
            v[idx] = np.linalg.solve((Dm - M)[np.ix_(idx, idx)], Qfix[idx])
            flux = flux_list[0][0] + sum(flux_list[k + 1][0] * v[k] for k in range(nd))
            U = flux / (self.ny * self.h)
            vv = v.reshape(nb, 3)
            if spin:
                self.v_free = v.copy()
            out["spin" if spin else "nospin"] = {
                "V_over_U": float(vv[:, 0].mean() / U), "U": U, "V": vv[:, 0].tolist(),
                "Vy": vv[:, 1].tolist(), "Om_a_over_V": (vv[:, 2] * self.a / vv[:, 0]).tolist()}
        out["Qfix"], out["M"], out["D"] = Qfix, M, Dm
        out["fluxes"] = [f for f, _ in flux_list]
        out["W"] = self.ny * self.h
        out["U_fix"] = flux_list[0][0] / (self.ny * self.h)
        out["M_asym"] = float(np.abs(M - M.T).max() / np.abs(M).max())
        out["max_resid"] = resid
        out["col_spread"] = max(s for _, s in flux_list[:1]) / abs(flux_list[0][0])
        return out


def run(args):
    model = resolve(load_scene(SCENE, args.set))
    s = model.species[0]
    h = float(model.fluid_dx)
    nx, ny, base = layout(model, args)
    lat = DomeLattice(model, nx, ny, ns=args.ns, films=args.films)
    nb = len(base)
    phi_actual = nb * math.pi * lat.a ** 2 / (nx * ny * h * h)
    k = int(round(math.sqrt(args.offsets)))
    grid = (np.arange(k) + 0.5) / k
    offs = np.array([(u, v) for u in grid for v in grid])
    t0 = time.perf_counter()
    recs = [lat.solve([((0.5 * nx + o[0]) * h + x, (0.5 * ny + o[1]) * h + y) for x, y in base],
                      drag_scale=args.drag_scale) for o in offs]
    out = {"lone": args.lone, "arrangement": None if args.lone else args.arrangement,
           "gap": None if args.lone else args.gap, "phi_nominal": args.phi,
           "phi_actual": phi_actual, "nx": nx, "ny": ny, "d_over_h": s.d_eq / h,
           "ns": args.ns, "films": args.films, "drag_scale": args.drag_scale,
           "offsets": len(offs), "D_tr_over_eta_a": lat.D_tr / (lat.eta * lat.a),
           "M_asym": max(r["M_asym"] for r in recs),
           "max_resid": max(r["max_resid"] for r in recs), "wall_s": time.perf_counter() - t0}
    for key in ("spin", "nospin"):
        vu = np.array([r[key]["V_over_U"] for r in recs])
        out[key] = {"V_over_U": float(vu.mean()), "std": float(vu.std()),
                    "Om_a_over_V": float(np.mean([r[key]["Om_a_over_V"][0] for r in recs]))}
    return out


def main(argv=None):
    ap = lattice_parser(__doc__, phi=0.1)
    ap.add_argument("--ns", type=int, default=4)
    ap.add_argument("--films", type=int, default=2)
    ap.add_argument("--drag-scale", type=float, default=1.0)
    args = ap.parse_args(argv)
    report(run(args), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
