"""Many DEM steps in one kernel launch (``run.stepping = "fused"``): disks on the
analytic path and level-set shapes alike.

The per-step path launches three kernels per step (load the held fluid force,
contacts, integration) and reads a flag on the host to know whether the
neighbour list needs a rebuild. For the small bodies counts of a clogging scene
(tens to hundreds of disks per realization) the work of a step is a few
microseconds and the launches cost far more: the paper-like scene ran 1260
steps/s, about 0.8 ms per step, nearly all of it host overhead.

Here one launch advances every running realization by ``n`` steps. Each
realization is one task (realizations run in parallel, one per thread; see
``_TASK``); inside it the steps, bodies and contacts run serially: forces of
every body, then the integration of every body, then, when some body has moved
half the Verlet skin, that realization's own neighbour-list rebuild. Serial order inside a realization
makes the summation order fixed, so a realization's result does not depend on
what runs beside it, as on the per-step path. The arithmetic is the per-step
path's own functions (``contact.disk_force`` or ``contact.ls_force``,
``integrate.advance_body``, ``neighbors.bin_one``/``list_one``). For level-set
shapes the launches weighed even more: a 9-particle quick polygon scene spent
1.7 ms a step, more than half of it in Taichi's Python code passing some thirty
arrays to each of three kernels.

Fluid forces are the held ones (``fluid.force_update = "solve"``): between two
pressure solves nothing else changes them. The shear history is double-buffered
as on the per-step path; step ``k`` reads buffer ``k % 2``.

A rebuild whose cell or neighbour capacity overflows stops that realization at
the step it reached (``done[r]``): the host grows the arrays, rebuilds, and lets
it catch up, so no contact is dropped.
"""

from typing import NamedTuple

from ..backend import ti  # sets the environment before Taichi loads
from .contact import disk_force, ls_force
from .integrate import advance_body
from ..layout import GEO_SKIN
from .neighbors import NEIGHBORS, bin_one, list_one
from .state import Batch, Bodies, Materials, Particles, ShearHistory, Templates, WallGrid

# The arrays the steps read: a launch takes at most 64 arguments on the CPU (each
# array and each pack one), which all of every bundle would pass.
_TEMPLATES = Templates.part("ls_phi", "ls_grad", "ls_meta", "ls_geo", "node_pos", "node_meta",
                            "inside")
_MATERIALS = Materials.part("pair", "wall", "xi")
_BATCH = Batch.part("running", "escaped", "bad", "max_overlap")

# Taichi's CPU backend hands a parallel loop to its threads in blocks of up to 512
# iterations, ti.loop_config(block_dim=1) or not: a loop over 10 realizations ran
# on one thread. So the loop runs _TASK iterations per realization and one of
# them works (as in fluid/_gmg_cycle.py).
_TASK = 512


class _History(NamedTuple):
    """The shear history's two buffers in the roles of one step (old: read, new:
    written), as :func:`contact.ls_force` reads them from the history's pack."""
    partners_old: object
    shear_old: object
    partners_new: object
    shear_new: object


#: The contact law of a launch (a compile-time choice): the analytic disks', the
#: level-set node law, or the node law with its sums normalized by node counts
#: (``contact.normalize_by_nodes``).
DISKS, NODES, NODES_NORMALIZED = 0, 1, 2


@ti.func
def _forces(bodies: ti.template(), batch: ti.template(), particles: ti.template(),
            materials: ti.template(), templates: ti.template(), walls: ti.template(),
            neighbors: ti.template(), hist: ti.template(), slots: ti.template(),
            flags: ti.template(), law: ti.template(), dt, r):
    deepest = 0.0
    for i in range(bodies.x.shape[1]):
        if bodies.alive[r, i] != 0:
            # declared out here: each branch of a static if is a scope of its own
            ftot, mtot, d = ti.Vector([0.0, 0.0]), 0.0, 0.0
            if ti.static(law == DISKS):
                ftot, mtot, d = disk_force(bodies, particles, materials, walls, neighbors,
                                           hist.partners_old, hist.shear_old,
                                           hist.partners_new, hist.shear_new, slots, flags,
                                           dt, r, i)
            else:
                ftot, mtot, d = ls_force(bodies, batch, particles, materials, templates, walls,
                                         hist, neighbors, flags, slots, dt,
                                         ti.static(int(law == NODES_NORMALIZED)), r, i)
            bodies.force[r, i] = bodies.f_fluid[r, i] + ftot
            bodies.torque[r, i] = bodies.tau_fluid[r, i] + mtot
            deepest = ti.max(deepest, d)
    return deepest


@ti.kernel
def steps(n_steps: ti.i32, bodies: Bodies.Pack, batch: _BATCH,
          particles: Particles.Pack, materials: _MATERIALS, templates: _TEMPLATES,
          walls: WallGrid.Pack, history: ShearHistory.Pack, neighbors: NEIGHBORS,
          flags: ti.types.ndarray(), done: ti.types.ndarray(), builds: ti.types.ndarray(),
          slots: ti.template(), law: ti.template(), dt: float,
          x_escape: float):
    """Advance every running realization by up to ``n_steps`` steps.

    ``done[r]``: the steps realization ``r`` took (``n_steps`` unless a neighbour
    rebuild overflowed), or -1 if it went bad or was not running: all the host
    reads after a launch. ``builds[r]`` counts its rebuilds. The
    latest shear history ends in buffer ``a`` (the pack's ``old`` pair) when
    ``n_steps`` is even, else ``b`` (``new``), for every realization (one that
    stopped early, or did not run, is copied there), so that the host swaps the
    two buffers of the whole batch.
    """
    hp_a, hs_a = ti.static(history.partners_old, history.shear_old)
    hp_b, hs_b = ti.static(history.partners_new, history.shear_new)
    n_part = bodies.x.shape[1]
    skin = neighbors.cell_geo[GEO_SKIN]
    for t in range(bodies.x.shape[0] * _TASK):  # one realization per task (_TASK)
        if t % _TASK == 0:
            r = t // _TASK
            deepest = batch.max_overlap[r]
            s = 0
            stop = 1 - batch.running[r]        # a stopped realization takes no step
            while s < n_steps and stop == 0:
                if s % 2 == 0:
                    deepest = ti.max(deepest, _forces(
                        bodies, batch, particles, materials, templates, walls, neighbors,
                        ti.static(_History(hp_a, hs_a, hp_b, hs_b)), slots, flags, law, dt, r))
                else:
                    deepest = ti.max(deepest, _forces(
                        bodies, batch, particles, materials, templates, walls, neighbors,
                        ti.static(_History(hp_b, hs_b, hp_a, hs_a)), slots, flags, law, dt, r))
                moved = 0
                for i in range(n_part):
                    if bodies.alive[r, i] != 0:
                        if advance_body(bodies, batch, particles, materials, neighbors, dt, skin,
                                        x_escape, r, i):
                            moved = 1
                s += 1
                if batch.bad[r] != 0:
                    stop = 1
                elif moved != 0:
                    builds[r] += 1
                    if bin_one(bodies, batch, neighbors, flags, r):
                        stop = 1
                    for i in range(n_part):
                        if list_one(bodies, batch, particles, neighbors, flags, r,
                                    i) > neighbors.nbr.shape[2]:
                            stop = 1
            done[r] = -1 if batch.bad[r] != 0 or batch.running[r] == 0 else s
            batch.max_overlap[r] = deepest
            if s % 2 != n_steps % 2:
                # the latest history is in the other buffer: copy it where the host looks
                for i, k, q in ti.ndrange(n_part, hp_a.shape[2], slots):
                    if s % 2 == 0:
                        hp_b[r, i, k, q] = hp_a[r, i, k, q]
                        hs_b[r, i, k, q] = hs_a[r, i, k, q]
                    else:
                        hp_a[r, i, k, q] = hp_b[r, i, k, q]
                        hs_a[r, i, k, q] = hs_b[r, i, k, q]


def run_steps(n: int, bodies, batch, particles, materials, templates, walls, history,
              neighbors, flags, done, builds, dt: float, x_escape: float, level_set: bool,
              normalize: bool):
    """``n`` steps of every running realization in one launch (module doc); leaves
    the latest shear history in ``history.old``. ``level_set``: the node law of
    level-set shapes (``normalize``: ``contact.normalize_by_nodes``), else the
    analytic disks'."""
    steps(n, bodies.pack(), batch.pack_of(_BATCH), particles.pack(), materials.pack_of(_MATERIALS),
          templates.pack_of(_TEMPLATES),
          walls.pack(), history.pack(), neighbors.pack(), flags, done, builds, history.slots,
          (NODES_NORMALIZED if normalize else NODES) if level_set else DISKS, dt, x_escape)
    if n % 2:
        history.swap()   # every realization's latest history is now history.old
