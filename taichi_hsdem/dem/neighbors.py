"""Broad phase: a cell list per realization feeding a Verlet neighbour list.

Bodies whose bounding circles come within ``skin`` of each other are listed; the
list is rebuilt only after some body moved more than ``skin / 2`` since the last
build (the integrator raises a flag). Capacities are fixed arrays with overflow
flags: the host reads the flag, grows the array and rebuilds, so a contact is
never dropped silently.

Binning runs serially inside each realization (realizations in parallel), so the
neighbour order, and with it the order in which forces are summed, is
reproducible.
"""

import numpy as np

from .. import backend
from ..backend import ti  # sets the environment before Taichi loads
from .layout import F_CELL_OVERFLOW, F_NBR_OVERFLOW, F_REBUILD

vec2 = ti.math.vec2


@ti.kernel
def bin_particles(x: ti.types.ndarray(), alive: ti.types.ndarray(), running: ti.types.ndarray(),
                  cell_n: ti.types.ndarray(), cell_p: ti.types.ndarray(), ox: float, oy: float,
                  cs: float, ncx: ti.i32, ncy: ti.i32, flags: ti.types.ndarray()):
    for r in range(x.shape[0]):
        bin_one(x, alive, running, cell_n, cell_p, ox, oy, cs, ncx, ncy, flags, r)  # (the
        # overflow it returns is for the fused stepper; here flags carries it)


@ti.func
def cell_of(ox, oy, cs, ncx, ncy, p):
    """Cell (clamped to the grid) holding world point ``p``; the grid's lower-left
    corner is (ox, oy), its cells ``cs`` wide."""
    cx = ti.min(ti.max(ti.cast(ti.floor((p.x - ox) / cs), ti.i32), 0), ncx - 1)
    cy = ti.min(ti.max(ti.cast(ti.floor((p.y - oy) / cs), ti.i32), 0), ncy - 1)
    return cx, cy


@ti.func
def bin_one(x: ti.template(), alive: ti.template(), running: ti.template(),
            cell_n: ti.template(), cell_p: ti.template(), ox, oy, cs, ncx, ncy,
            flags: ti.template(), r):
    """Bin the live bodies of realization ``r``, serially (a reproducible order);
    returns 1 if a cell overflowed its capacity."""
    cap = cell_p.shape[2]
    overflow = 0
    for c in range(ncx * ncy):
        cell_n[r, c] = 0
    if running[r] != 0:
        for i in range(x.shape[1]):
            if alive[r, i] != 0:
                cx, cy = cell_of(ox, oy, cs, ncx, ncy, x[r, i])
                c = cx * ncy + cy
                slot = cell_n[r, c]
                if slot < cap:
                    cell_p[r, c, slot] = i
                else:
                    flags[F_CELL_OVERFLOW] = 1
                    overflow = 1
                cell_n[r, c] = slot + 1
    return overflow


@ti.kernel
def build_neighbors(x: ti.types.ndarray(), x_ref: ti.types.ndarray(), alive: ti.types.ndarray(),
                    running: ti.types.ndarray(), rb: ti.types.ndarray(),
                    cell_n: ti.types.ndarray(), cell_p: ti.types.ndarray(),
                    nbr: ti.types.ndarray(), nbr_n: ti.types.ndarray(), ox: float, oy: float,
                    cs: float, skin: float, ncx: ti.i32, ncy: ti.i32,
                    flags: ti.types.ndarray()):
    for r, i in ti.ndrange(x.shape[0], x.shape[1]):
        list_one(x, x_ref, alive, running, rb, cell_n, cell_p, nbr, nbr_n, ox, oy, cs, skin,
                 ncx, ncy, flags, r, i)  # (the count is for the fused stepper)


@ti.func
def list_one(x: ti.template(), x_ref: ti.template(), alive: ti.template(),
             running: ti.template(), rb: ti.template(), cell_n: ti.template(),
             cell_p: ti.template(), nbr: ti.template(), nbr_n: ti.template(),
             ox, oy, cs, skin, ncx, ncy, flags: ti.template(), r, i):
    """Neighbour list of body ``i`` of realization ``r`` from the binned cells;
    returns how many neighbours it found (more than the capacity: overflow)."""
    cap = nbr.shape[2]
    ccap = cell_p.shape[2]
    nbr_n[r, i] = 0
    x_ref[r, i] = x[r, i]
    count = 0
    if running[r] != 0 and alive[r, i] != 0:
        xi = x[r, i]
        cx, cy = cell_of(ox, oy, cs, ncx, ncy, xi)
        for dx, dy in ti.ndrange((-1, 2), (-1, 2)):
            ax = cx + dx
            ay = cy + dy
            if 0 <= ax < ncx and 0 <= ay < ncy:
                c = ax * ncy + ay
                for s in range(ti.min(cell_n[r, c], ccap)):
                    j = cell_p[r, c, s]
                    if j != i and (x[r, j] - xi).norm() < rb[i] + rb[j] + skin:
                        if count < cap:
                            # Keep the list sorted by index: the order in which forces
                            # are summed must not depend on when (or, batched, why)
                            # the list was built.
                            slot = count
                            while slot > 0 and nbr[r, i, slot - 1] > j:
                                nbr[r, i, slot] = nbr[r, i, slot - 1]
                                slot -= 1
                            nbr[r, i, slot] = j
                        else:
                            flags[F_NBR_OVERFLOW] = 1
                        count += 1
        nbr_n[r, i] = ti.min(count, cap)
    return count


class NeighborList:
    """Owns the cell list and the neighbour list of a batch of realizations.

    Parameters
    ----------
    n_real, n_part : int
        Realizations and particles per realization.
    bbox : (x_min, x_max, y_min, y_max)
        Region the bodies live in (bodies outside are binned into edge cells).
    max_radius, skin : float
        Largest bounding radius and the Verlet skin.
    cell_cap, nbr_cap : int
        Initial capacities: bodies per cell, neighbours per body. Each doubles
        whenever a build overflows it.
    """

    def __init__(self, n_real, n_part, bbox, max_radius, skin, cell_cap=8, nbr_cap=16):
        self.skin = float(skin)
        self.cell_size = 2.0 * max_radius + skin
        self.origin = (float(bbox[0]), float(bbox[2]))
        self.ncx = max(1, int(np.ceil((bbox[1] - bbox[0]) / self.cell_size)))
        self.ncy = max(1, int(np.ceil((bbox[3] - bbox[2]) / self.cell_size)))
        self.shape = (n_real, n_part)
        self.cell_cap = int(cell_cap)
        self.nbr_cap = int(nbr_cap)
        self.cell_n = ti.ndarray(ti.i32, shape=(n_real, self.ncx * self.ncy))
        self._alloc_cells()
        self._alloc_nbr()
        self.x_ref = ti.Vector.ndarray(2, backend.real(), shape=self.shape)
        self.builds = 0

    def _alloc_cells(self):
        self.cell_p = ti.ndarray(ti.i32, shape=(self.shape[0], self.ncx * self.ncy, self.cell_cap))

    def _alloc_nbr(self):
        self.nbr = ti.ndarray(ti.i32, shape=self.shape + (self.nbr_cap,))
        self.nbr_n = ti.ndarray(ti.i32, shape=self.shape)

    @property
    def grid(self) -> tuple:
        """The scalars the kernels take: origin x, origin y, cell size, skin, and
        the cell counts ncx, ncy."""
        return (self.origin[0], self.origin[1], self.cell_size, self.skin, self.ncx, self.ncy)

    def build(self, bodies, batch, particles, flags):
        """Rebuild, growing the capacities until nothing overflows."""
        ox, oy, cs, skin, ncx, ncy = self.grid
        x, alive, running = bodies.x, bodies.alive, batch.running
        while True:
            flags_np = flags.to_numpy()
            flags_np[[F_CELL_OVERFLOW, F_NBR_OVERFLOW, F_REBUILD]] = 0
            flags.from_numpy(flags_np)
            bin_particles(x, alive, running, self.cell_n, self.cell_p, ox, oy, cs, ncx, ncy,
                          flags)
            build_neighbors(x, self.x_ref, alive, running, particles.bounding_radius,
                            self.cell_n, self.cell_p, self.nbr, self.nbr_n, ox, oy, cs, skin,
                            ncx, ncy, flags)
            got = flags.to_numpy()
            if got[F_CELL_OVERFLOW]:
                self.cell_cap *= 2
                self._alloc_cells()
                continue
            if got[F_NBR_OVERFLOW]:
                self.nbr_cap *= 2
                self._alloc_nbr()
                continue
            self.builds += 1
            return
