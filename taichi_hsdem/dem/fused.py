"""Many DEM steps of disks in one kernel launch (``run.stepping = "fused"``).

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
path's own functions (``contact.disk_force``, ``integrate.advance_body``,
``neighbors.bin_one``/``list_one``).

Fluid forces are the held ones (``fluid.force_update = "solve"``): between two
pressure solves nothing else changes them. The shear history is double-buffered
as on the per-step path; step ``k`` reads buffer ``k % 2``.

A rebuild whose cell or neighbour capacity overflows stops that realization at
the step it reached (``done[r]``): the host grows the arrays, rebuilds, and lets
it catch up, so no contact is dropped.
"""

from ..backend import ti  # sets the environment before Taichi loads
from .contact import disk_force
from .integrate import advance_body
from .neighbors import bin_one, list_one

# Taichi's CPU backend hands a parallel loop to its threads in blocks of up to 512
# iterations, ti.loop_config(block_dim=1) or not: a loop over 10 realizations ran
# on one thread. So the loop runs _TASK iterations per realization and one of
# them works (as in fluid/_gmg_cycle.py).
_TASK = 512


@ti.func
def _forces(x: ti.template(), v: ti.template(), w: ti.template(), f: ti.template(),
            tau: ti.template(), f_fluid: ti.template(), tau_fluid: ti.template(),
            alive: ti.template(), nbr: ti.template(), nbr_n: ti.template(),
            sp: ti.template(), rad: ti.template(), mass: ti.template(), pair: ti.template(),
            wallp: ti.template(), wall: ti.template(), wall_grad: ti.template(),
            wall_shape: ti.template(), wall_ox, wall_oy, wall_h, hp_old: ti.template(),
            hs_old: ti.template(), hp_new: ti.template(), hs_new: ti.template(),
            slots: ti.template(), flags: ti.template(), dt, r):
    deepest = 0.0
    for i in range(x.shape[1]):
        if alive[r, i] != 0:
            ftot, mtot, d = disk_force(x, v, w, alive, nbr, nbr_n, sp, rad, mass, pair, wallp,
                                       wall, wall_grad, wall_shape, wall_ox, wall_oy, wall_h,
                                       hp_old, hs_old, hp_new, hs_new, slots, flags, dt, r, i)
            f[r, i] = f_fluid[r, i] + ftot
            tau[r, i] = tau_fluid[r, i] + mtot
            deepest = ti.max(deepest, d)
    return deepest


@ti.kernel
def disk_steps(n_steps: ti.i32, x: ti.types.ndarray(), th: ti.types.ndarray(),
               v: ti.types.ndarray(), w: ti.types.ndarray(), f: ti.types.ndarray(),
               tau: ti.types.ndarray(), f_fluid: ti.types.ndarray(),
               tau_fluid: ti.types.ndarray(), f_ext: ti.types.ndarray(),
               tau_ext: ti.types.ndarray(), alive: ti.types.ndarray(),
               running: ti.types.ndarray(), bad: ti.types.ndarray(),
               escaped: ti.types.ndarray(), max_overlap: ti.types.ndarray(),
               sp: ti.types.ndarray(), rad: ti.types.ndarray(), mass: ti.types.ndarray(),
               inertia: ti.types.ndarray(), deq: ti.types.ndarray(), rb: ti.types.ndarray(),
               xi: ti.types.ndarray(), pair: ti.types.ndarray(), wallp: ti.types.ndarray(),
               wall: ti.types.ndarray(), wall_grad: ti.types.ndarray(),
               wall_shape: ti.types.ndarray(), wall_ox: float, wall_oy: float,
               wall_h: float, hp_a: ti.types.ndarray(), hs_a: ti.types.ndarray(),
               hp_b: ti.types.ndarray(), hs_b: ti.types.ndarray(), slots: ti.template(),
               x_ref: ti.types.ndarray(), cell_n: ti.types.ndarray(),
               cell_p: ti.types.ndarray(), nbr: ti.types.ndarray(), nbr_n: ti.types.ndarray(),
               g_ox: float, g_oy: float, cs: float, skin: float, ncx: ti.i32, ncy: ti.i32,
               flags: ti.types.ndarray(), done: ti.types.ndarray(),
               builds: ti.types.ndarray(), dt: float, x_escape: float):
    """Advance every running realization by up to ``n_steps`` steps.

    ``done[r]``: the steps realization ``r`` took (``n_steps`` unless a neighbour
    rebuild overflowed), or -1 if it went bad or was not running: all the host
    reads after a launch. ``builds[r]`` counts its rebuilds. The
    latest shear history ends in buffer ``a`` when ``n_steps`` is even, else ``b``,
    for every realization (one that stopped early, or did not run, is copied
    there), so that the host swaps the two buffers of the whole batch.
    """
    n_part = x.shape[1]
    for t in range(x.shape[0] * _TASK):  # one realization per task (_TASK)
        if t % _TASK == 0:
            r = t // _TASK
            deepest = max_overlap[r]
            s = 0
            stop = 1 - running[r]        # a stopped realization takes no step
            while s < n_steps and stop == 0:
                if s % 2 == 0:
                    deepest = ti.max(deepest, _forces(
                        x, v, w, f, tau, f_fluid, tau_fluid, alive, nbr, nbr_n, sp, rad, mass,
                        pair, wallp, wall, wall_grad, wall_shape, wall_ox, wall_oy, wall_h,
                        hp_a, hs_a, hp_b, hs_b, slots, flags, dt, r))
                else:
                    deepest = ti.max(deepest, _forces(
                        x, v, w, f, tau, f_fluid, tau_fluid, alive, nbr, nbr_n, sp, rad, mass,
                        pair, wallp, wall, wall_grad, wall_shape, wall_ox, wall_oy, wall_h,
                        hp_b, hs_b, hp_a, hs_a, slots, flags, dt, r))
                moved = 0
                for i in range(n_part):
                    if alive[r, i] != 0:
                        if advance_body(x, th, v, w, f, tau, f_ext, tau_ext, alive, bad, escaped,
                                        sp, mass, inertia, deq, xi, x_ref, dt, skin, x_escape,
                                        r, i):
                            moved = 1
                s += 1
                if bad[r] != 0:
                    stop = 1
                elif moved != 0:
                    builds[r] += 1
                    if bin_one(x, alive, running, cell_n, cell_p, g_ox, g_oy, cs, ncx, ncy, flags,
                               r):
                        stop = 1
                    for i in range(n_part):
                        if list_one(x, x_ref, alive, running, rb, cell_n, cell_p, nbr, nbr_n,
                                    g_ox, g_oy, cs, skin, ncx, ncy, flags, r, i) > nbr.shape[2]:
                            stop = 1
            done[r] = -1 if bad[r] != 0 or running[r] == 0 else s
            max_overlap[r] = deepest
            if s % 2 != n_steps % 2:
                # the latest history is in the other buffer: copy it where the host looks
                for i, k, q in ti.ndrange(n_part, hp_a.shape[2], slots):
                    if s % 2 == 0:
                        hp_b[r, i, k, q] = hp_a[r, i, k, q]
                        hs_b[r, i, k, q] = hs_a[r, i, k, q]
                    else:
                        hp_a[r, i, k, q] = hp_b[r, i, k, q]
                        hs_a[r, i, k, q] = hs_b[r, i, k, q]


def run_steps(n: int, bodies, batch, particles, materials, walls, history, neighbors, flags,
              done, builds, dt: float, x_escape: float):
    """``n`` steps of every running realization in one launch (module doc); leaves
    the latest shear history in ``history.old``."""
    b, p, m, wg, nl = bodies, particles, materials, walls, neighbors
    (hp_a, hs_a), (hp_b, hs_b) = history.old, history.new
    disk_steps(n, b.x, b.theta, b.v, b.omega, b.force, b.torque, b.f_fluid, b.tau_fluid,
               b.f_ext, b.tau_ext, b.alive, batch.running, batch.bad, batch.escaped,
               batch.max_overlap, p.species, p.radius, p.mass, p.inertia, p.d_eq,
               p.bounding_radius, m.xi, m.pair, m.wall, wg.phi, wg.grad, wg.shape,
               wg.origin[0], wg.origin[1], wg.spacing, hp_a, hs_a, hp_b, hs_b, history.slots,
               nl.x_ref, nl.cell_n, nl.cell_p, nl.nbr, nl.nbr_n, *nl.grid, flags, done, builds,
               dt, x_escape)
    if n % 2:
        history.swap()   # every realization's latest history is now history.old
