"""Explicit integration with global damping (docs/model.md section 1).

    v     <- [(1 - xi dt/2) v     + dt F/m] / (1 + xi dt/2)
    omega <- [(1 - xi dt/2) omega + dt M/I] / (1 + xi dt/2 + zeta dt)
    (and + plate friction's rate in v's denominator, below)
    x     <- x + dt v,   theta <- theta + dt omega

``xi`` is per species (``damping.xi = "auto"`` depends on the density); the
velocity's denominator also holds the plate friction's drag rate where the
particle rests on a plate (:func:`plate_rate`, from the velocity before the step:
the Coulomb limit over the speed, implicit). ``zeta``,
per particle, is its spin drag over its inertia (``particles.spin_drag``: the
viscous torque of the plates beyond ``xi I``), taken implicitly (backward Euler),
so that it damps without oscillating however large ``zeta dt`` is. The same
kernel adds the external loads ``f_ext``, ``tau_ext`` (zero unless set through
:meth:`Simulation.set_external_load`) and watches for what makes a step untrustworthy: non-finite values and bodies
moving more than a quarter of their size in one step (flag per realization), and
a body that has moved half the Verlet skin since the last neighbour build (asks
for a rebuild). It also counts bodies crossing the escape line and parks them.
"""

import numpy as np

from ..backend import ti  # sets the environment before Taichi loads
from ..layout import BAD_FAST, BAD_NAN, F_REBUILD
from .neighbors import NEIGHBORS
from .state import Batch, Bodies, Materials, Particles


@ti.kernel
def advance_kernel(bodies: Bodies.Pack, batch: Batch.Pack, particles: Particles.Pack,
                   materials: Materials.Pack, neighbors: NEIGHBORS, flags: ti.types.ndarray(),
                   dt: float, skin: float, x_escape: float):
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        if batch.running[r] == 0 or bodies.alive[r, i] == 0:
            continue
        if advance_body(bodies, batch, particles, materials, neighbors, dt, skin, x_escape, r, i):
            flags[F_REBUILD] = 1


@ti.func
def plate_rate(particles: ti.template(), i, v):
    """The plate friction of particle ``i`` at velocity ``v`` as a drag rate,
    1/s: the Coulomb limit over the mass (``plate``) over the speed, the speed
    taken at least ``creep``, so that a sliding particle meets the limit against
    its motion and a held one a drag that stops it but for a creep (0 without
    plate contact)."""
    rate = 0.0
    if particles.plate[i] > 0.0:
        rate = particles.plate[i] / ti.max(v.norm(), particles.creep[i])
    return rate


@ti.func
def advance_body(bodies: ti.template(), batch: ti.template(), particles: ti.template(),
                 materials: ti.template(), neighbors: ti.template(), dt, skin, x_escape, r, i):
    """One step of body ``i`` of realization ``r``; True when it has moved half the
    Verlet skin since the last neighbour build."""
    damp = materials.xi[particles.species[i]] * dt * 0.5
    vn = ((1.0 - damp) * bodies.v[r, i]
          + dt * (bodies.force[r, i] + bodies.f_ext[r, i]) / particles.mass[i]) / (
              1.0 + damp + dt * plate_rate(particles, i, bodies.v[r, i]))
    wn = ((1.0 - damp) * bodies.omega[r, i] + dt * (bodies.torque[r, i] + bodies.tau_ext[r, i])
          / particles.inertia[i]) / (1.0 + damp + dt * particles.spin[i])
    xn = bodies.x[r, i] + dt * vn
    bodies.v[r, i] = vn
    bodies.omega[r, i] = wn
    bodies.x[r, i] = xn
    bodies.theta[r, i] += dt * wn
    if not (ti.math.isinf(xn).any() or ti.math.isnan(xn).any()
            or ti.math.isnan(wn) or ti.math.isinf(wn)):
        if vn.norm() * dt > 0.25 * particles.d_eq[i]:
            ti.atomic_or(batch.bad[r], BAD_FAST)
    else:
        ti.atomic_or(batch.bad[r], BAD_NAN)
    moved = (xn - neighbors.x_ref[r, i]).norm() > 0.5 * skin
    if xn.x > x_escape:
        bodies.alive[r, i] = 0
        batch.escaped[r] += 1
    return moved


def advance(bodies, batch, particles, materials, neighbors, flags, dt: float, skin: float,
            x_escape: float):
    """One step of every live body of every running realization (module doc);
    raises ``flags[F_REBUILD]`` when a body moved half the Verlet ``skin`` since
    the last neighbour build."""
    advance_kernel(bodies.pack(), batch.pack(), particles.pack(), materials.pack(),
                   neighbors.pack(), flags, dt, skin, x_escape)


@ti.kernel
def _status_kernel(batch: Batch.Pack, reset: ti.i32):
    for r in range(batch.running.shape[0]):
        batch.status[0, r] = batch.running[r]
        batch.status[1, r] = batch.escaped[r]
        batch.status[2, r] = batch.bad[r]
        batch.status[3, r] = batch.max_overlap[r]
        if reset != 0:
            batch.max_overlap[r] = 0.0


def read_status(batch, reset_overlap: bool):
    """``(running, escaped, bad, max_overlap)`` of every realization, read in one
    transfer (each read of a device array costs a kernel launch and more,
    about 0.1 ms on the CPU); with ``reset_overlap`` the deepest overlap starts
    again from 0. The integers travel in the kernels' float type: exact below
    2^24, far above any escapee count or the ``BAD_*`` bits."""
    _status_kernel(batch.pack(), int(bool(reset_overlap)))
    a = batch.status.to_numpy()
    return (a[0].astype(np.int32), a[1].astype(np.int64), a[2].astype(np.int32),
            a[3].astype(float))


#: The bodies' arrays :func:`read_state` reads.
_STATE = Bodies.part("x", "theta", "v", "omega", "alive")
#: Columns of its buffer: x, y, theta, v_x, v_y, omega, alive.
STATE_COLUMNS = 7


@ti.kernel
def _state_kernel(bodies: _STATE, out: ti.types.ndarray()):
    for r, i in ti.ndrange(out.shape[0], out.shape[1]):
        pos, vel = bodies.x[r, i], bodies.v[r, i]
        out[r, i, 0] = pos[0]
        out[r, i, 1] = pos[1]
        out[r, i, 2] = bodies.theta[r, i]
        out[r, i, 3] = vel[0]
        out[r, i, 4] = vel[1]
        out[r, i, 5] = bodies.omega[r, i]
        out[r, i, 6] = bodies.alive[r, i]


def read_state(bodies, out) -> np.ndarray:
    """Every body's pose, velocities and whether it is alive, ``(R, N,
    STATE_COLUMNS)`` in the kernels' float type, read in one transfer into the
    device buffer ``out`` of that shape (five reads cost five kernel launches
    and more: at every host check); the values are copied exactly (``alive``
    is 0 or 1)."""
    _state_kernel(bodies.pack_of(_STATE), out)
    return out.to_numpy()
