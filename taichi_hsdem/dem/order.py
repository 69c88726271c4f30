"""Bodies in cell order for the fused stepper's launches (one realization of many
bodies).

Bodies are numbered as the placement drew them, at random: consecutive bodies of
a 10,000-disk channel lie a median 80 diameters apart, so a body's neighbours
are read from anywhere in its arrays. For the length of one launch of
:func:`fused.run_steps` the bodies are copied in the order of the cells of the
broad phase (column by column, each cell's bodies as they were binned), their
neighbour lists and shear histories translated to those places, and what the
steps changed is copied back afterwards (the neighbour and cell lists only
after a rebuild in the launch). Everything outside the launch (the
fluid coupling, the checks, the outputs, checkpoints and seeds) sees the
user's numbering only.

The results are the same bits: a body's forces are summed over its neighbour
list, which is kept sorted by the user's number (``key``, :func:`neighbors.list_one`),
so each body sees its neighbours in the same order; the integration is per body;
a contact's shear is found by its partner, wherever its slot.
"""

import numpy as np

from .. import backend
from ..backend import ti  # sets the environment before Taichi loads
from .neighbors import NEIGHBORS, NeighborList
from .state import Batch, Bodies, Particles, ShearHistory, array, pack_type

#: The fewest bodies for which a launch takes them in cell order: a smaller
#: scene's arrays stay in the cache in any order, and the copies would cost
#: more than the reads they save.
MIN_BODIES = 2000

_BODIES = tuple(Bodies.Pack.members)
_PARTICLES = tuple(Particles.Pack.members)
_HISTORY = tuple(ShearHistory.Pack.members)
#: What the steps change of the bodies (copied back; the rest they only read).
_WRITTEN = ("x", "theta", "v", "omega", "force", "torque", "alive")
_LISTS = ("x_ref", "nbr", "nbr_n")


def _mine(owner: str, names) -> object:
    """The argpack type of the arrays in cell order: the same names with ``o_``
    (a kernel that copies takes both packs; pack member names are unique)."""
    return pack_type(owner, ["o_" + n for n in names])


_MINE_BODIES = _mine("CellOrderBodies", _BODIES)
_MINE_PARTICLES = _mine("CellOrderParticles", _PARTICLES)
_MINE_HISTORY = _mine("CellOrderHistory", _HISTORY)
_MINE_LISTS = _mine("CellOrderLists", _LISTS + ("cell_n", "cell_p"))
_RUNNING = Batch.part("running")


# ``stamps``: the fused stepper's rebuild count when the order was last taken
# (_ORDERED) and when the last launch began (_ENTERED).
_ORDERED, _ENTERED = 0, 1


@ti.kernel
def _cell_order(neighbors: NEIGHBORS, perm: ti.types.ndarray(), inv: ti.types.ndarray(),
                builds: ti.types.ndarray(), stamps: ti.types.ndarray(), anew: ti.i32):
    """``perm[k]``: the body in place k, the binned bodies cell by cell in the
    cells' order, then the others (not alive) by number; ``inv`` its inverse.
    Taken ``anew``, or if the stepper rebuilt the lists since it was last taken
    (else the order stays, and so do the copies of what only a rebuild changes)."""
    n_bodies = perm.shape[0]
    for _ in range(1):   # serially
        if anew != 0 or builds[0] != stamps[_ORDERED]:
            stamps[_ORDERED] = -1        # (_enter, _enter_lists: copy everything)
            for i in range(n_bodies):
                inv[i] = -1
            k = 0
            for c in range(neighbors.cell_n.shape[1]):
                for s in range(ti.min(neighbors.cell_n[0, c], neighbors.cell_p.shape[2])):
                    i = neighbors.cell_p[0, c, s]
                    if inv[i] < 0:
                        inv[i] = k
                        perm[k] = i
                        k += 1
            for i in range(n_bodies):
                if inv[i] < 0:
                    inv[i] = k
                    perm[k] = i
                    k += 1


@ti.func
def _id(ids: ti.template(), v, offset):
    """Body number ``v - offset`` carried through ``ids`` (other values, a free
    slot or the walls, as they are)."""
    out = v
    if offset <= v < ids.shape[0] + offset:
        out = ids[v - offset] + offset
    return out


@ti.func
def _history_row(src: ti.template(), src_prefix: ti.template(), dst: ti.template(),
                 dst_prefix: ti.template(), nodes: ti.template(), slots: ti.template(),
                 ids: ti.template(), a, b):
    """Body ``a``'s latest shear history (the ``old`` buffer) of the pack ``src``
    into body ``b``'s of ``dst`` (their members named with these prefixes), the
    partners carried through ``ids``. The other buffer is not copied: a step
    clears a body's partners there before it writes them."""
    p_src = ti.static(getattr(src, src_prefix + "partners_old"))
    p_dst = ti.static(getattr(dst, dst_prefix + "partners_old"))
    h_src = ti.static(getattr(src, src_prefix + "shear_old"))
    h_dst = ti.static(getattr(dst, dst_prefix + "shear_old"))
    for q in ti.static(range(nodes)):
        for s in ti.static(range(slots)):
            p_dst[0, b, q, s] = _id(ids, p_src[0, a, q, s], 1)
            h_dst[0, b, q, s] = h_src[0, a, q, s]


@ti.kernel
def _enter(bodies: Bodies.Pack, mine: _MINE_BODIES, particles: Particles.Pack,
           mine_p: _MINE_PARTICLES, perm: ti.types.ndarray(), stamps: ti.types.ndarray()):
    """The bodies' arrays in the order ``perm``, and the particles' if the order
    is new (_cell_order)."""
    for k in range(perm.shape[0]):
        i = perm[k]
        for name in ti.static(_BODIES):
            ti.static(getattr(mine, "o_" + name))[0, k] = ti.static(getattr(bodies, name))[0, i]
        if stamps[_ORDERED] < 0:
            for name in ti.static(_PARTICLES):
                ti.static(getattr(mine_p, "o_" + name))[k] = ti.static(getattr(particles, name))[i]


@ti.kernel
def _enter_lists(history: ShearHistory.Pack, mine_h: _MINE_HISTORY, neighbors: NEIGHBORS,
                 mine_l: _MINE_LISTS, perm: ti.types.ndarray(), inv: ti.types.ndarray(),
                 builds: ti.types.ndarray(), stamps: ti.types.ndarray(), nodes: ti.template(),
                 slots: ti.template()):
    """The shear histories in the order ``perm``, and the neighbour lists if the
    order is new (else they hold what the last launch left, the same lists),
    every body number carried to its place; the stamps of the rebuild count."""
    anew = stamps[_ORDERED] < 0
    for k in range(perm.shape[0]):
        i = perm[k]
        _history_row(history, "", mine_h, "o_", nodes, slots, inv, i, k)
        if anew:
            mine_l.o_x_ref[0, k] = neighbors.x_ref[0, i]
            mine_l.o_nbr_n[0, k] = neighbors.nbr_n[0, i]
            for q in range(neighbors.nbr.shape[2]):
                mine_l.o_nbr[0, k, q] = _id(inv, neighbors.nbr[0, i, q], 0)
    for _ in range(1):
        stamps[_ORDERED] = builds[0]
        stamps[_ENTERED] = builds[0]


@ti.kernel
def _leave(bodies: Bodies.Pack, mine: _MINE_BODIES, history: ShearHistory.Pack,
           mine_h: _MINE_HISTORY, neighbors: NEIGHBORS, mine_l: _MINE_LISTS,
           perm: ti.types.ndarray(), builds: ti.types.ndarray(), stamps: ti.types.ndarray(),
           nodes: ti.template(), slots: ti.template()):
    """What the steps changed back in the numbering: the bodies, the shear
    histories, and, if the steps rebuilt them, the neighbour and cell lists."""
    rebuilt = builds[0] != stamps[_ENTERED]
    for k in range(perm.shape[0]):
        i = perm[k]
        for name in ti.static(_WRITTEN):
            ti.static(getattr(bodies, name))[0, i] = ti.static(getattr(mine, "o_" + name))[0, k]
        _history_row(mine_h, "o_", history, "", nodes, slots, perm, k, i)
        if rebuilt:
            neighbors.x_ref[0, i] = mine_l.o_x_ref[0, k]
            neighbors.nbr_n[0, i] = mine_l.o_nbr_n[0, k]
            for q in range(neighbors.nbr.shape[2]):
                neighbors.nbr[0, i, q] = _id(perm, mine_l.o_nbr[0, k, q], 0)
    for c in range(neighbors.cell_n.shape[1]):
        if rebuilt:
            neighbors.cell_n[0, c] = mine_l.o_cell_n[0, c]
            for s in range(neighbors.cell_p.shape[2]):
                neighbors.cell_p[0, c, s] = _id(perm, mine_l.o_cell_p[0, c, s], 0)


class Numbered:
    """The bodies in their numbering: :class:`CellOrder`'s interface, copying
    nothing."""

    def __init__(self, n_bodies: int):
        self.key = array(np.arange(int(n_bodies), dtype=np.int32), ti.i32)

    def enter(self, bodies: Bodies, particles: Particles, history: ShearHistory,
              neighbors: NeighborList, builds):
        return bodies, particles, history, neighbors, self.key

    def leave(self, bodies: Bodies, history: ShearHistory, neighbors: NeighborList, builds):
        pass


class CellOrder:
    """The arrays of one realization's bodies in cell order (module doc), for
    :func:`fused.run_steps`: :meth:`enter` copies the numbered arrays in,
    :meth:`leave` copies back what the steps changed."""

    def __init__(self, n_bodies: int, particles: Particles, history: ShearHistory,
                 neighbors: NeighborList):
        n = int(n_bodies)
        self.perm = array(np.arange(n, dtype=np.int32), ti.i32)   # place -> number
        self.key = self.perm      # the number of the body in each place
        self.inv = array(np.arange(n, dtype=np.int32), ti.i32)    # number -> place
        self.stamps = array(np.zeros(2, dtype=np.int32), ti.i32)  # _ORDERED, _ENTERED
        self._lists_of = None     # the numbered lists' generation the copies hold
        self.bodies = Bodies.zeros(1, n)
        self.particles = Particles(**{name: ti.ndarray(a.dtype, shape=a.shape)
                                      for name, a in particles.arrays().items()},
                                   species_np=particles.species_np)
        self.history = ShearHistory(1, n, history.old[0].shape[2], history.slots)
        self._dims = (history.old[0].shape[2], history.slots)     # nodes, slots
        mine = NeighborList.__new__(NeighborList)
        mine.__dict__.update({k: v for k, v in neighbors.__dict__.items()
                              if k not in ("_packs", "_parts")})
        mine.x_ref = ti.Vector.ndarray(2, backend.real(), shape=(1, n))
        mine.cell_n = ti.ndarray(ti.i32, shape=neighbors.cell_n.shape)
        mine.resize(*neighbors.capacities)
        self.neighbors = mine

    def _packs(self):
        """The copies' packs under their ``o_`` names (made again when a list grew)."""
        mine, history = self.neighbors, self.history
        key = (id(mine.nbr), id(mine.cell_p))
        if self.__dict__.get("_packed", (None,))[0] != key:
            self._packed = (key, self._make_packs())
        return self._packed[1]

    def _make_packs(self):
        mine, history = self.neighbors, self.history
        return (_MINE_BODIES(**{"o_" + k: v for k, v in self.bodies.arrays().items()}),
                _MINE_PARTICLES(**{"o_" + k: v for k, v in self.particles.arrays().items()}),
                _MINE_HISTORY(**{"o_" + k: v for k, v in history.arrays().items()}),
                _MINE_LISTS(**{"o_" + k: getattr(mine, k)
                               for k in _LISTS + ("cell_n", "cell_p")}))

    def enter(self, bodies: Bodies, particles: Particles, history: ShearHistory,
              neighbors: NeighborList, builds):
        """Copy the numbered arrays in cell order (the order of ``neighbors``'
        cells now); returns the bodies, particles, history and neighbour list to
        step, and the key that keeps each neighbour list in the numbering's
        order. ``builds``: the fused stepper's rebuild counts."""
        mine = self.neighbors
        if mine.capacities != neighbors.capacities:
            mine.resize(*neighbors.capacities)
        nl = neighbors.pack()
        # the numbered lists rebuilt or restored on the host since: a new order
        anew = int(self._lists_of != neighbors.generation)
        self._lists_of = neighbors.generation
        _cell_order(nl, self.perm, self.inv, builds, self.stamps, anew)
        o_bodies, o_particles, o_history, o_lists = self._packs()
        _enter(bodies.pack(), o_bodies, particles.pack(), o_particles, self.perm, self.stamps)
        _enter_lists(history.pack(), o_history, nl, o_lists, self.perm, self.inv, builds,
                     self.stamps, *self._dims)
        return self.bodies, self.particles, self.history, mine, self.key

    def leave(self, bodies: Bodies, history: ShearHistory, neighbors: NeighborList, builds):
        """Copy back in the numbering what the steps changed (module doc)."""
        o_bodies, _, o_history, o_lists = self._packs()
        _leave(bodies.pack(), o_bodies, history.pack(), o_history, neighbors.pack(), o_lists,
               self.perm, builds, self.stamps, *self._dims)
