"""The dipole a lone drifting disk leaves on the pressure grid, and the carried
fraction that makes it the 3D Stokes sphere's (docs/model.md section 3.4).

A disk on the grid is a staircase of cells (a cell belongs to it when its centre
lies inside), more polarisable than the circle it stands for: on the default
d/6 grid it leaves a dipole about 13 % above the exact inclusion's, an error of
first order in the cell size. The dipole is linear in what the disk's cells
carry, so the share that leaves a given dipole on the grid follows from two
solves per position: the disk held (``s = 0``) and carrying the mean fluid
speed (``s = 1``).

How: a channel ``LENGTH`` diameters long and ``WIDTH`` wide, pressure at both
ends, walls at the sides, the package's own finite-volume system
(:class:`~taichi_hsdem.fluid.system.FiniteVolumeSystem`, its harmonic face means
and carried source), solved directly (scipy's LU); the disk at the channel's
centre, shifted by each of ``OFFSETS`` within a cell; the pressure fitted on the
ring ``RING`` (diameters) with ``p = a0 + a1 x + a2 f(x, y)``, ``f`` the dipole
with its images in the side walls, ``B / a^2 = a2 / a1 / a^2``, averaged over the
offsets (the dipole varies by about 4 % with the position on the grid; the 3 x 3
offsets give the carried fraction within 0.1 % of 6 x 6).
``tools/dipole_grid.py`` runs the same fit over random positions and grids.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .system import FiniteVolumeSystem

#: The channel around the disk, in diameters.
LENGTH, WIDTH = 24.0, 12.0
#: The ring the dipole is fitted on, in diameters from the disk's centre.
RING = (1.5, 3.0)
#: Above this many cells across the disk the grid's error is extrapolated from
#: this grid at first order instead of solved (the solve's cost grows as the
#: square of it: 0.8 s here): measured at 24 cells, 0.1 % from the solve.
MAX_CELLS = 12.0
#: The disk's positions within a cell, a 3 x 3 stratified grid (-1/3, 0, 1/3 of a
#: cell each way), and their weights: a disk shifted by -u is the mirror image of
#: one shifted by +u (its cells mirror, and the dipole is even in x and y), so
#: the quarter with u, v >= 0 stands for all nine (to the channel's asymmetry of
#: a third of a cell, six diameters from the disk).
OFFSETS = ((0.0, 0.0), (1 / 3, 0.0), (0.0, 1 / 3), (1 / 3, 1 / 3))
WEIGHTS = (1.0, 2.0, 2.0, 4.0)


@functools.lru_cache(maxsize=64)
def _fits(d_cells: float, kappa_ratio: float) -> np.ndarray:
    """Per offset, the ring fit's ``(a1, a2)`` of the held disk and of the
    carried part (per unit carried speed): ``(len(OFFSETS), 2, 2)``. Units: the
    cell 1, the free permeability and the viscosity 1, a unit mean gradient."""
    d = float(d_cells)
    nx, ny = int(round(LENGTH * d)), int(round(WIDTH * d))
    L, W = float(nx), float(ny)
    fv = FiniteVolumeSystem(np.ones((nx, ny), bool), 1.0, 1.0, 1.0,
                            {"kind": "pressure", "p_in": L, "p_out": 0.0})
    cx, cy = np.meshgrid(np.arange(nx) + 0.5, np.arange(ny) + 0.5, indexing="ij")
    out = np.zeros((len(OFFSETS), 2, 2))
    for n, (ox, oy) in enumerate(OFFSETS):
        dx, dy = cx - (0.5 * L + ox), cy - (0.5 * W + oy)
        r = np.hypot(dx, dy)
        inside = r <= 0.5 * d
        kappa = np.where(inside, kappa_ratio, 1.0).ravel()[fv._cells]
        fv._assemble([0], kappa[None])
        A = sp.csr_array((fv._data[0], fv._indices, fv._indptr), shape=(fv._n, fv._n))
        carried = np.zeros((1, nx, ny, 2))
        carried[0, inside, 0] = 1.0
        rhs = np.column_stack([fv._rhs[0], fv._carried_source(carried, inside[None])[0]])
        x = spla.splu(A.tocsc()).solve(rhs)
        p = np.full((nx * ny, 2), np.nan)
        p[fv._cells] = x
        out[n] = ring_fit(p, dx.ravel(), dy.ravel(), d, W)[1:].T
    return out


def ring_fit(p, dx, dy, d, width):
    """``(a0, a1, a2)``, the least-squares fit ``p = a0 + a1 x + a2 f(x, y)`` on
    the ring ``RING`` (diameters ``d``) round a disk, ``dx``, ``dy`` the cells'
    offsets from its centre, ``f`` the dipole ``x / r^2`` with its images in side
    walls ``width`` apart; ``B / a^2 = a2 / a1 / a^2``. ``p`` may hold several
    fields as columns (then one row of coefficients per field)."""
    r = np.hypot(dx, dy)
    ring = (r > RING[0] * d) & (r < RING[1] * d)
    images = np.real(math.pi / width / np.tanh(math.pi * (dx + 1j * dy) / width))
    basis = np.column_stack([np.ones(ring.sum()), dx[ring], images[ring]])
    return np.linalg.lstsq(basis, p[ring], rcond=None)[0]


def grid_dipole(d_cells: float, kappa_ratio: float, carried_speed: float) -> float:
    """``B / a^2`` of a disk ``d_cells`` cells across, of permeability
    ``kappa_ratio`` times the fluid's, whose cells carry ``carried_speed`` times
    the mean fluid speed (``c lambda``), on the grid: the mean over the 3 x 3
    offsets (``OFFSETS`` with their ``WEIGHTS``)."""
    f = _fits(float(d_cells), float(kappa_ratio))
    a1 = f[:, 0, 0] + carried_speed * f[:, 1, 0]
    a2 = f[:, 0, 1] + carried_speed * f[:, 1, 1]
    return float(np.average(a2 / a1, weights=WEIGHTS) / (0.25 * d_cells ** 2))


def grid_carried_speed(d_cells: float, kappa_ratio: float, dipole: float) -> float:
    """The carried speed ``c lambda`` at which the disk of :func:`grid_dipole`
    leaves ``dipole`` (``B / a^2``) on the grid (secant steps on a function that
    is linear to 2e-3)."""
    s0, s1 = 0.0, 1.0
    b0, b1 = grid_dipole(d_cells, kappa_ratio, s0), grid_dipole(d_cells, kappa_ratio, s1)
    for _ in range(20):
        if b1 == b0:
            break
        s0, s1 = s1, s1 + (dipole - b1) * (s1 - s0) / (b1 - b0)
        b0, b1 = b1, grid_dipole(d_cells, kappa_ratio, s1)
        if abs(b1 - dipole) < 1e-10:
            break
    return float(s1)


def carried_speed(d_cells: float, kappa_ratio: float, dipole: float, exact: float) -> float:
    """:func:`grid_carried_speed` up to :data:`MAX_CELLS` cells across; beyond, its
    value there moved towards ``exact`` (the circle's, the limit of a fine grid)
    at first order in the cell size."""
    if d_cells <= MAX_CELLS:
        return grid_carried_speed(d_cells, kappa_ratio, dipole)
    coarse = grid_carried_speed(MAX_CELLS, kappa_ratio, dipole)
    return float(exact + (coarse - exact) * MAX_CELLS / d_cells)
