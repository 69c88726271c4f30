"""Broad phase: a cell list per realization feeding a Verlet neighbour list.

Bodies whose bounding circles come within ``skin`` of each other are listed; the
list is rebuilt only after some body moved more than ``skin / 2`` since the last
build (the integrator raises a flag). Capacities are fixed arrays with overflow
flags: the host reads the flag, grows the array and rebuilds, so a contact is
never dropped silently.

Binning runs serially inside each realization (realizations in parallel) on the
CPU, a thread per body on a GPU; each body's neighbour list is kept sorted by
index, so the neighbour order, and with it the order in which forces are summed,
is reproducible either way. On a GPU the per-step path rebuilds on the device
when the integrator's flag says so (:func:`rebuild_if_flagged`), without a host
read per step.
"""

import numpy as np

from .. import backend
from ..backend import on_gpu, ti  # sets the environment before Taichi loads
from ..layout import F_CELL_OVERFLOW, F_NBR_OVERFLOW, F_REBUILD, GEO_H, GEO_OX, GEO_OY, GEO_SKIN
from .state import Batch, Bodies, Bundle, Particles, array, pack_type

vec2 = ti.math.vec2

# The pack of a NeighborList: its arrays, and its grid's cell counts (ncx, ncy)
# and geometry (layout.GEO_*, with the Verlet skin).
NEIGHBORS = pack_type("NeighborList", ("x_ref", "cell_n", "cell_p", "nbr", "nbr_n",
                                       "cell_shape", "cell_geo"))


@ti.kernel
def bin_particles(bodies: Bodies.Pack, batch: Batch.Pack, neighbors: NEIGHBORS,
                  flags: ti.types.ndarray()):
    for r in range(bodies.x.shape[0]):
        # (the overflow it returns is for the fused stepper; here flags carries it)
        bin_one(bodies, batch, neighbors, flags, r)


# The bodies', batch's and particles' arrays a rebuild reads (bin_one, list_one).
_BIN_BODIES = Bodies.part("x", "alive")
_BIN_BATCH = Batch.part("running")
_LIST_PARTICLES = Particles.part("bounding_radius")


@ti.func
def _bin_body(bodies: ti.template(), batch: ti.template(), neighbors: ti.template(),
              flags: ti.template(), r, i):
    """Put body i of realization r (if alive and running) into its cell, at the
    slot an atomic count gives it; returns 1 if the cell was full. Serially
    (bin_one) the slots follow the bodies' order; in parallel (_rebuild) the
    order inside a cell depends on the threads, the neighbour lists do not
    (list_one sorts them by index)."""
    overflow = 0
    if batch.running[r] != 0 and bodies.alive[r, i] != 0:
        cx, cy = cell_of(neighbors, bodies.x[r, i])
        c = cx * neighbors.cell_shape[1] + cy
        slot = ti.atomic_add(neighbors.cell_n[r, c], 1)
        if slot < neighbors.cell_p.shape[2]:
            neighbors.cell_p[r, c, slot] = i
        else:
            flags[F_CELL_OVERFLOW] = 1
            overflow = 1
    return overflow


#: Entries of the per-step path's device rebuild record (rebuild_if_flagged):
#: the step (counted from 1) whose rebuild overflowed and stalled the batch (0:
#: none), the rebuilds done since the host last read it, then each realization's
#: ``running`` as it was when the batch stalled.
STALL_STEP, STALL_BUILDS, STALL_RUNNING = 0, 1, 2


@ti.func
def _go(flags: ti.template(), stall: ti.template(), gated: ti.template()):
    """Whether a rebuild runs: always, or (``gated``) when the rebuild flag is
    up and the batch has not stalled."""
    go = True
    if ti.static(gated):
        go = flags[F_REBUILD] != 0 and stall[STALL_STEP] == 0
    return go


@ti.func
def _rebuild(bodies: ti.template(), batch: ti.template(), particles: ti.template(),
             neighbors: ti.template(), flags: ti.template(), stall: ti.template(),
             gated: ti.template()):
    """Bin and list every realization in three top-level loops, a thread per
    cell, body, body (a GPU's shape); ``gated``: only if _go says so."""
    R, N = bodies.x.shape[0], bodies.x.shape[1]
    for r, c in ti.ndrange(R, neighbors.cell_shape[0] * neighbors.cell_shape[1]):
        if _go(flags, stall, gated):
            neighbors.cell_n[r, c] = 0
    for r, i in ti.ndrange(R, N):
        if _go(flags, stall, gated):
            _bin_body(bodies, batch, neighbors, flags, r, i)
    for r, i in ti.ndrange(R, N):
        if _go(flags, stall, gated):
            list_one(bodies, batch, particles, neighbors, flags, r, i)


@ti.kernel
def rebuild_each(bodies: _BIN_BODIES, batch: _BIN_BATCH, particles: _LIST_PARTICLES,
                 neighbors: NEIGHBORS, flags: ti.types.ndarray(),
                 stall: ti.types.ndarray()):
    """bin_particles and build_neighbors with a thread per body (a GPU's shape):
    the same cells, counts and lists, each cell's bodies in another order."""
    _rebuild(bodies, batch, particles, neighbors, flags, stall, False)


@ti.kernel
def rebuild_if_flagged(bodies: _BIN_BODIES, batch: _BIN_BATCH, particles: _LIST_PARTICLES,
                       neighbors: NEIGHBORS, flags: ti.types.ndarray(),
                       stall: ti.types.ndarray(), step: ti.i32):
    """The per-step path's rebuild without a host read (a GPU's way): if the
    integrator raised ``flags[F_REBUILD]``, bin and list every realization on
    the device, a thread per cell, body, body. A rebuild that overflows a
    capacity stalls the batch: ``stall`` records the step and each
    realization's ``running``, and every realization stops running, so the
    following steps' kernels do nothing until the host, reading ``stall``
    once per chunk of steps, has grown the lists and resumes from that step."""
    _rebuild(bodies, batch, particles, neighbors, flags, stall, True)
    for _ in range(1):
        if _go(flags, stall, True):
            if flags[F_CELL_OVERFLOW] != 0 or flags[F_NBR_OVERFLOW] != 0:
                stall[STALL_STEP] = step + 1
                for r in range(bodies.x.shape[0]):
                    stall[STALL_RUNNING + r] = batch.running[r]
                    batch.running[r] = 0
            else:
                flags[F_REBUILD] = 0
                stall[STALL_BUILDS] = stall[STALL_BUILDS] + 1


@ti.func
def cell_of(neighbors: ti.template(), p):
    """Cell (clamped to the grid) holding world point ``p``."""
    geo = ti.static(neighbors.cell_geo)
    cs = geo[GEO_H]
    cx = ti.cast(ti.floor((p.x - geo[GEO_OX]) / cs), ti.i32)
    cy = ti.cast(ti.floor((p.y - geo[GEO_OY]) / cs), ti.i32)
    return (ti.min(ti.max(cx, 0), neighbors.cell_shape[0] - 1),
            ti.min(ti.max(cy, 0), neighbors.cell_shape[1] - 1))


@ti.func
def bin_one(bodies: ti.template(), batch: ti.template(), neighbors: ti.template(),
            flags: ti.template(), r):
    """Bin the live bodies of realization ``r``, serially (a reproducible order);
    returns 1 if a cell overflowed its capacity."""
    overflow = 0
    for c in range(neighbors.cell_shape[0] * neighbors.cell_shape[1]):
        neighbors.cell_n[r, c] = 0
    for i in range(bodies.x.shape[1]):
        overflow = overflow | _bin_body(bodies, batch, neighbors, flags, r, i)
    return overflow


@ti.kernel
def build_neighbors(bodies: Bodies.Pack, batch: Batch.Pack, particles: Particles.Pack,
                    neighbors: NEIGHBORS, flags: ti.types.ndarray()):
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        # (the count it returns is for the fused stepper)
        list_one(bodies, batch, particles, neighbors, flags, r, i)


@ti.func
def list_one(bodies: ti.template(), batch: ti.template(), particles: ti.template(),
             neighbors: ti.template(), flags: ti.template(), r, i):
    """Neighbour list of body ``i`` of realization ``r`` from the binned cells;
    returns how many neighbours it found (more than the capacity: overflow)."""
    cap = neighbors.nbr.shape[2]
    ccap = neighbors.cell_p.shape[2]
    ncx = neighbors.cell_shape[0]
    ncy = neighbors.cell_shape[1]
    neighbors.nbr_n[r, i] = 0
    neighbors.x_ref[r, i] = bodies.x[r, i]
    count = 0
    if batch.running[r] != 0 and bodies.alive[r, i] != 0:
        xi = bodies.x[r, i]
        cx, cy = cell_of(neighbors, xi)
        for dx, dy in ti.ndrange((-1, 2), (-1, 2)):
            ax = cx + dx
            ay = cy + dy
            if 0 <= ax < ncx and 0 <= ay < ncy:
                c = ax * ncy + ay
                for s in range(ti.min(neighbors.cell_n[r, c], ccap)):
                    j = neighbors.cell_p[r, c, s]
                    if j != i and ((bodies.x[r, j] - xi).norm()
                                   < particles.bounding_radius[i] + particles.bounding_radius[j]
                                   + neighbors.cell_geo[GEO_SKIN]):
                        if count < cap:
                            # Keep the list sorted by index: the order in which forces
                            # are summed must not depend on when (or, batched, why)
                            # the list was built.
                            slot = count
                            while slot > 0 and neighbors.nbr[r, i, slot - 1] > j:
                                neighbors.nbr[r, i, slot] = neighbors.nbr[r, i, slot - 1]
                                slot -= 1
                            neighbors.nbr[r, i, slot] = j
                        else:
                            flags[F_NBR_OVERFLOW] = 1
                        count += 1
        neighbors.nbr_n[r, i] = ti.min(count, cap)
    return count


class NeighborList(Bundle):
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
    Pack = NEIGHBORS

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
        self.cell_shape = array(np.array([self.ncx, self.ncy]), ti.i32)
        self.cell_geo = array(np.array([*self.origin, self.cell_size, self.skin]))
        self._alloc_cells()
        self._alloc_nbr()
        self.x_ref = ti.Vector.ndarray(2, backend.real(), shape=self.shape)
        self.builds = 0
        self._no_stall = array(np.zeros(1), ti.i32)  # rebuild_each's (unread) record

    @property
    def capacities(self) -> tuple[int, int]:
        """Bodies per cell and neighbours per body the lists hold now."""
        return self.cell_cap, self.nbr_cap

    def resize(self, cell_cap: int, nbr_cap: int):
        """Allocate the cell and neighbour lists anew at these capacities (a
        checkpoint's), empty: their contents are to be set or rebuilt."""
        self.cell_cap, self.nbr_cap = int(cell_cap), int(nbr_cap)
        self._alloc_cells()
        self._alloc_nbr()

    def _alloc_cells(self):
        self.cell_p = ti.ndarray(ti.i32, shape=(self.shape[0], self.ncx * self.ncy, self.cell_cap))

    def _alloc_nbr(self):
        self.nbr = ti.ndarray(ti.i32, shape=self.shape + (self.nbr_cap,))
        self.nbr_n = ti.ndarray(ti.i32, shape=self.shape)

    def rebuild_if_flagged(self, bodies, batch, particles, flags, stall, step: int):
        """Rebuild on the device if the last step raised ``flags[F_REBUILD]``
        (:func:`rebuild_if_flagged`); no host read."""
        rebuild_if_flagged(bodies.pack_of(_BIN_BODIES), batch.pack_of(_BIN_BATCH),
                           particles.pack_of(_LIST_PARTICLES), self.pack(), flags, stall,
                           int(step))

    def build(self, bodies, batch, particles, flags):
        """Rebuild, growing the capacities until nothing overflows."""
        while True:
            flags_np = flags.to_numpy()
            flags_np[[F_CELL_OVERFLOW, F_NBR_OVERFLOW, F_REBUILD]] = 0
            flags.from_numpy(flags_np)
            b, q, nl = bodies.pack(), batch.pack(), self.pack()
            if on_gpu():    # a thread per body; on the CPU binning per realization
                rebuild_each(bodies.pack_of(_BIN_BODIES), batch.pack_of(_BIN_BATCH),
                             particles.pack_of(_LIST_PARTICLES), nl, flags, self._no_stall)
            else:
                bin_particles(b, q, nl, flags)
                build_neighbors(b, q, particles.pack(), nl, flags)
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
