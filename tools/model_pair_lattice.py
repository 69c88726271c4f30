"""The depth-averaged model's steady drift of a periodic lattice of disk pairs
(or lone disks), on the model's own grid and discretisation.

What is computed (and how it maps onto the runtime code):

* Grid: the scene's cell ``h = model.fluid_dx`` (vani_phi026: d/6.003), a periodic
  cell of ``nx x ny`` cells, ``nx = round(Lx/h)``, ``ny = round(Ly/h)`` with
  ``Lx, Ly`` those of tools/stokes_pair_lattice.py (the actual phi follows from
  the rounded cell and is reported).
* Permeability: a cell whose centre lies inside a disk (``|r| <= radius``, as
  ``dem.coupling.inside_body`` for circles) takes the species' Kozeny-Carman
  ``kappa_p`` (``model.species[0].kappa``), the others ``kappa_free``
  (``model.kappa_free``) -- ``rasterize_permeability``.
* Fluxes: two-point flux with the harmonic mean (``laws.harmonic_mean``), as in
  ``fluid.system.FiniteVolumeSystem._assemble``, with the faces wrapped
  periodically; the pressure is ``-G x + p~`` with ``p~`` periodic.
* Carried flux: ``FiniteVolumeSystem._carried_source`` itself (called on a
  namespace holding the periodic face lists), cells carrying ``c v`` of their
  disk (``c = species.carried``; ``vs = c v`` in the runtime's rasterisation).
* Force on a disk: the surface-node force of ``dem.coupling.pressure_forces``
  with bilinear sampling (``fluid.pressure_sampling = "bilinear"``, the default):
  ``F = -sum_k sigma(p_k) H a_k``, ``a_k = geometry.shapes.boundary_vectors`` of
  the species' nodes. On a circle its moment is zero, so disks do not spin.
* Steady drift: ``m xi v = F`` (the damping ``advance_body`` applies; no plate
  friction in the scene), with ``xi = species.xi`` (``damping.xi = "auto"``).
  The pressure is linear in G and the disks' velocities: one fixed solve
  (G = 1, v = 0) and one per velocity component of each disk (G = 0, that
  component = 1), one LU; then ``m xi v_i = F_i^fix + sum_j M_ij v_j`` is solved
  for all velocities together. This is the fixed point the implicit coupling
  (``fluid.flux_coupling = "implicit"``) reaches at a steady state: there the
  carried velocity equals the DEM velocity and the force is the node force
  (docs/model.md 3.3).
* ``U``: the total (Darcy + carried) flux through a column of x-faces over ``Ly``
  (the same in every column), i.e. ``Q / (H W)``; ``V / U`` with ``V`` the mean
  x-velocity of the disks.
* The staircase depends on where the disks sit in their cells: the layout is
  shifted by ``--offsets`` offsets (a regular k x k grid over one cell, k =
  sqrt(offsets)) and the results averaged (mean and standard deviation reported).

    python tools/model_pair_lattice.py --arrangement side --gap 0.05 --phi 0.24 \
        [--set particles.carried_fraction=0.5685] [--offsets 64] [--out F.json]
    python tools/model_pair_lattice.py --lone --phi 0.24 ...
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time
import types

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from taichi_hsdem import load_scene  # noqa: E402
from taichi_hsdem.resolve import resolve  # noqa: E402
from taichi_hsdem.laws import harmonic_mean  # noqa: E402
from taichi_hsdem.fluid.system import FiniteVolumeSystem  # noqa: E402
from taichi_hsdem.geometry.shapes import boundary_vectors  # noqa: E402

SCENE = str(HERE.parent / "scenes" / "vani_phi026.toml")


def pair_cell(dh, phi, gap, arrangement):
    """(Lx, Ly, centres) over H, from tools/stokes_pair_lattice.Settings (pure geometry:
    it needs no NGSolve)."""
    import stokes_pair_lattice as spl
    s = spl.Settings(dh=dh, phi=phi, gap=gap, arrangement=arrangement)
    h = 0.5 * s.s
    centres = [(0.0, -h), (0.0, h)] if arrangement == "side" else [(-h, 0.0), (h, 0.0)]
    return s.Lx, s.Ly, centres


class PeriodicLattice:
    def __init__(self, model, nx, ny):
        self.m = model
        s = model.species[0]
        self.h = float(model.fluid_dx)
        self.nx, self.ny = nx, ny
        self.H = float(model.scene.fluid.gap)
        self.eta = float(model.scene.fluid.viscosity)
        self.kf, self.kp = float(model.kappa_free), float(s.kappa)
        self.c, self.xi, self.mass = float(s.carried), float(s.xi), float(s.mass)
        self.radius = float(s.shape.radius)
        self.nodes = np.asarray(s.shape.nodes, float)
        self.avec = boundary_vectors(self.nodes)
        n = nx * ny
        flat = np.arange(n).reshape(nx, ny)
        fa_x, fb_x = flat.ravel(), np.roll(flat, -1, axis=0).ravel()   # (i,j) -> (i+1,j)
        fa_y, fb_y = flat.ravel(), np.roll(flat, -1, axis=1).ravel()   # (i,j) -> (i,j+1)
        self.fa = np.concatenate([fa_x, fa_y])
        self.fb = np.concatenate([fb_x, fb_y])
        self.is_x = np.concatenate([np.ones(n, bool), np.zeros(n, bool)])
        self.n = n
        # the namespace FiniteVolumeSystem._carried_source reads
        self.ns = types.SimpleNamespace(n_batch=1, _cells=np.arange(n), _f_is_x=self.is_x,
                                        dx=self.h, dy=self.h, _fa=self.fa, _fb=self.fb, _n=n)
        xc = (np.arange(nx) + 0.5) * self.h
        yc = (np.arange(ny) + 0.5) * self.h
        self.cx, self.cy = np.meshgrid(xc, yc, indexing="ij")

    def occupancy(self, centres):
        """owner per cell (-1 none), min-image distance (periodic)."""
        Lx, Ly = self.nx * self.h, self.ny * self.h
        owner = np.full((self.nx, self.ny), -1)
        for i, (x0, y0) in enumerate(centres):
            dx = (self.cx - x0 + 0.5 * Lx) % Lx - 0.5 * Lx
            dy = (self.cy - y0 + 0.5 * Ly) % Ly - 0.5 * Ly
            owner[np.hypot(dx, dy) <= self.radius] = i      # highest index wins
        return owner

    def pieces(self, centres):
        """The steady balance's linear pieces for disks at ``centres``: the node
        forces ``F0`` of the fixed solve (G = 1, v = 0) and ``M`` (column k: those of
        unit velocity component k, G = 0), the column flux of each (``flux0``,
        ``fluxv``), and the solves' largest residual and column-flux spread."""
        owner = self.occupancy(centres)
        inside = owner >= 0
        kappa = np.where(inside, self.kp, self.kf).ravel()
        T = harmonic_mean(kappa[self.fa], kappa[self.fb]) / self.eta   # dy/dx = 1
        n = self.n
        A, lu, gx_out = periodic_operator(T, self.fa, self.fb, self.is_x, n)
        nb = len(centres)
        # right-hand sides: fixed (G = 1), then (disk j, component q) unit velocities
        cases = [("fixed", None, None)] + [("move", j, q) for j in range(nb) for q in (0, 1)]
        results = []
        for kind, j, q in cases:
            if kind == "fixed":
                G = 1.0
                carried = np.zeros((self.nx, self.ny, 2))
            else:
                G = 0.0
                carried = np.zeros((self.nx, self.ny, 2))
                carried[owner == j, q] = self.c
            src = FiniteVolumeSystem._carried_source(self.ns, carried, inside)[0]
            rhs = src - G * self.h * gx_out
            pt = np.zeros(n)
            pt[1:] = lu.solve(rhs[1:])
            resid = A @ pt - rhs
            # face fluxes a -> b: Darcy + carried
            darcy = T * (pt[self.fa] - pt[self.fb] + np.where(self.is_x, G * self.h, 0.0))
            v = carried.reshape(-1, 2)
            chi = inside.ravel().astype(float)
            comp = np.where(self.is_x, 0, 1)
            sides = np.maximum(chi[self.fa] + chi[self.fb], 1.0)
            qc = (v[self.fa, comp] + v[self.fb, comp]) / sides * self.h
            total = darcy + qc
            col = total[:n].reshape(self.nx, self.ny).sum(axis=1)   # each column of x-faces
            forces = np.array([self.node_force(pt.reshape(self.nx, self.ny), G, c)
                               for c in centres])
            results.append({"forces": forces, "flux": col.mean(), "flux_spread": np.ptp(col),
                            "resid": float(np.abs(resid[1:]).max())})
        return {"F0": results[0]["forces"].ravel(),
                "M": np.array([r["forces"].ravel() for r in results[1:]]).T,
                "flux0": results[0]["flux"], "fluxv": np.array([r["flux"] for r in results[1:]]),
                "owner": owner, "max_resid": max(r["resid"] for r in results),
                "column_flux_spread": max(r["flux_spread"] for r in results)
                / abs(results[0]["flux"])}

    def pair_resistance(self, centres, table):
        """``K`` (2 nb x 2 nb, block diagonal) of ``fluid.pair_mobility``
        (taichi_hsdem/dem/pairs.py) for disks at ``centres``: every other disk and
        every periodic image (a disk's own included) within the cutoff, the
        ``table``'s last knot."""
        nb, d, cutoff = len(centres), 2.0 * self.radius, float(table[-1, 0])
        Lx, Ly = self.nx * self.h, self.ny * self.h
        c = np.asarray(centres, float)
        K = np.zeros((2 * nb, 2 * nb))
        reach = int(math.ceil((1.0 + cutoff) * d / min(Lx, Ly))) + 1
        for i in range(nb):
            for j in range(nb):
                for a in range(-reach, reach + 1):
                    for b in range(-reach, reach + 1):
                        sep = c[j] - c[i] + np.array([a * Lx, b * Ly])
                        dist = math.hypot(*sep)
                        if dist == 0.0 or dist / d - 1.0 >= cutoff:
                            continue
                        alpha, beta = pair_coefficients(table, dist / d - 1.0)
                        e = sep / dist
                        K[2 * i:2 * i + 2, 2 * i:2 * i + 2] += (
                            alpha * np.eye(2) + beta * (2.0 * np.outer(e, e) - np.eye(2)))
        return K

    def drift(self, parts, K=None):
        """``(velocities (nb, 2), U)``: the steady drift ``m xi (I - K) v = F0 + M v``
        (K = 0: no pair resistance) and the mean volume flux per unit width."""
        nu = len(parts["F0"])
        K = np.zeros((nu, nu)) if K is None else K
        vel = np.linalg.solve(self.mass * self.xi * (np.eye(nu) - K) - parts["M"], parts["F0"])
        flux = parts["flux0"] + parts["fluxv"] @ vel
        return vel.reshape(-1, 2), flux / (self.ny * self.h)

    def solve(self, centres, pair=None):
        """Steady drift of the disks at ``centres`` (cell frame, metres); ``pair``:
        the close pairs' resistance table, or None."""
        parts = self.pieces(centres)
        K = None if pair is None else self.pair_resistance(centres, pair)
        vel, U = self.drift(parts, K)
        owner = parts["owner"]
        return {"V": vel[:, 0].tolist(), "Vy": vel[:, 1].tolist(), "U": U,
                "V_over_U": float(vel[:, 0].mean() / U),
                "cells_inside": [int((owner == j).sum()) for j in range(len(centres))],
                "max_resid": parts["max_resid"],
                "column_flux_spread": parts["column_flux_spread"]}

    def node_force(self, pt, G, centre):
        """-H sum_k sigma(p_k) a_k, sigma bilinear over the four cell centres
        around the node (all active), p = -G x + p~ (p~ periodic)."""
        pts = self.nodes + np.asarray(centre)
        gx = pts[:, 0] / self.h - 0.5
        gy = pts[:, 1] / self.h - 0.5
        i0 = np.floor(gx).astype(int)
        j0 = np.floor(gy).astype(int)
        fx, fy = gx - i0, gy - j0
        sigma = np.zeros(len(pts))
        for da in (0, 1):
            for db in (0, 1):
                w = (fx if da else 1 - fx) * (fy if db else 1 - fy)
                a, b = i0 + da, j0 + db
                val = -G * (a + 0.5) * self.h + pt[a % self.nx, b % self.ny]
                sigma += w * val
        return -self.H * (sigma[:, None] * self.avec).sum(axis=0)


def layout(model, args):
    """``(nx, ny, base)``: the periodic cell in grid cells and the particles'
    centres (m) about its middle, for ``args`` (``lone``, ``n``, ``phi``, ``gap``,
    ``arrangement``); the cell rounded to whole cells, so phi shifts a little."""
    s = model.species[0]
    H = float(model.scene.fluid.gap)
    dh = s.d_eq / H
    h = float(model.fluid_dx)
    if args.lone:
        if args.n:
            nx = ny = args.n
        else:
            L = 0.5 * dh * math.sqrt(math.pi / args.phi) * H
            nx = ny = int(round(L / h))
        base = [(0.0, 0.0)]
    else:
        Lx, Ly, cen = pair_cell(dh, args.phi, args.gap, args.arrangement)
        nx, ny = int(round(Lx * H / h)), int(round(Ly * H / h))
        base = [(x * H, y * H) for x, y in cen]
    return nx, ny, base


def run(args):
    model = resolve(load_scene(SCENE, args.set))
    s = model.species[0]
    h = float(model.fluid_dx)
    nx, ny, base = layout(model, args)
    lat = PeriodicLattice(model, nx, ny)
    nb = len(base)
    phi_actual = nb * math.pi * lat.radius ** 2 / (nx * ny * h * h)
    t0 = time.perf_counter()
    pair = pair_setting(model, args)
    recs = [lat.solve(centres, pair) for centres in placements(lat, base, args.offsets)]
    vu = np.array([r["V_over_U"] for r in recs])
    out = {"scene": SCENE, "set": args.set, "lone": args.lone,
           "arrangement": None if args.lone else args.arrangement,
           "gap": None if args.lone else args.gap, "phi_nominal": args.phi,
           "phi_actual": phi_actual, "nx": nx, "ny": ny, "h": h, "d_over_h": s.d_eq / h,
           "d_over_H": s.d_eq / float(model.scene.fluid.gap), "carried": lat.c, "xi": lat.xi, "kappa_p_over_free": lat.kp / lat.kf,
           "pair_mobility": pair is not None,
           "offsets": len(recs), "V_over_U": float(vu.mean()),
           "V_over_U_std": float(vu.std()), "V_over_U_sem": float(vu.std() / math.sqrt(len(vu))),
           "Vy_over_V_rms": float(np.sqrt(np.mean([np.mean(np.square(r["Vy"]))
                                                   / np.mean(np.square(r["V"]))
                                                   for r in recs]))),
           "max_resid": max(r["max_resid"] for r in recs),
           "column_flux_spread": max(r["column_flux_spread"] for r in recs),
           "cells_inside_mean": float(np.mean([np.mean(r["cells_inside"]) for r in recs])),
           "wall_s": time.perf_counter() - t0}
    return out


def placements(lat, base, offsets):
    """The disks' centres (metres) for each of ``offsets`` positions of the layout
    ``base`` in its grid cell, a stratified k x k grid (k = sqrt(offsets)) about
    the periodic cell's middle: the lattice is cell-periodic, so only the offset
    within a grid cell matters."""
    k = int(round(math.sqrt(offsets)))
    grid = (np.arange(k) + 0.5) / k
    return [[((0.5 * lat.nx + u) * lat.h + x, (0.5 * lat.ny + v) * lat.h + y) for x, y in base]
            for u in grid for v in grid]


def pair_coefficients(table, g):
    """``(alpha, beta)`` of the pair resistance at gap ``g``: dem/pairs.py's
    piecewise-linear rule on ``table`` (rows ``g, alpha, beta``)."""
    if g >= table[-1, 0]:
        return 0.0, 0.0
    if g <= table[0, 0]:
        return float(table[0, 1]), float(table[0, 2])
    return float(np.interp(g, table[:, 0], table[:, 1])), float(np.interp(g, table[:, 0],
                                                                          table[:, 2]))


def pair_setting(model, args):
    """The pair resistance's table the lattice applies (``--pair-mobility``:
    ``auto`` as the scene resolves ``fluid.pair_mobility``), or None."""
    choice = getattr(args, "pair_mobility", "auto")
    on = model.pair_mobility if choice == "auto" else choice == "on"
    if not on:
        return None
    from taichi_hsdem.laws import pair_mobility_table
    return pair_mobility_table()


def periodic_operator(T, fa, fb, is_x, n):
    """The periodic grid's operator (faces ``fa``-``fb`` of transmissibility
    ``T``), its LU factor with cell 0's pressure fixed and, per cell, the net
    x-face transmissibility out of it: the source a unit mean gradient along x
    puts there (``G h sum T``)."""
    A = sp.coo_array((np.concatenate([T, T, -T, -T]),
                      (np.concatenate([fa, fb, fa, fb]), np.concatenate([fa, fb, fb, fa]))),
                     shape=(n, n)).tocsc()
    Tx = np.where(is_x, T, 0.0)
    return A, spla.splu(A[1:, 1:].tocsc()), np.bincount(fa, Tx, n) - np.bincount(fb, Tx, n)


def lattice_parser(doc, phi=None):
    """The lattice's options (:func:`layout` reads them), for this tool and the
    prototypes built on it: ``phi`` a default, or None to require ``--phi``."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--arrangement", choices=("side", "inline"), default="side")
    ap.add_argument("--gap", type=float, default=0.05)
    ap.add_argument("--phi", type=float, **({"required": True} if phi is None else
                                            {"default": phi}))
    ap.add_argument("--lone", action="store_true", help="one disk per square cell")
    ap.add_argument("--n", type=int, help="with --lone: cells a side (else from phi)")
    ap.add_argument("--offsets", type=int, default=64)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--pair-mobility", choices=("auto", "on", "off"), default="auto",
                    help="the close pairs' resistance (fluid.pair_mobility): as the scene "
                         "resolves it, or on/off")
    ap.add_argument("--out")
    return ap


def report(out, path, indent=None):
    """``out`` as JSON on stdout (``indent``) and, with ``path``, into that file."""
    print(json.dumps(out, indent=indent))
    if path:
        with open(path, "w") as fh:
            json.dump(out, fh, indent=1)


def main(argv=None):
    args = lattice_parser(__doc__).parse_args(argv)
    report(run(args), args.out, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
