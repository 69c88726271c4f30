"""Explicit integration with global damping (docs/model.md section 1).

    v     <- [(1 - xi dt/2) v     + dt F/m] / (1 + xi dt/2)
    omega <- [(1 - xi dt/2) omega + dt M/I] / (1 + xi dt/2)
    x     <- x + dt v,   theta <- theta + dt omega

``xi`` is per species (``damping.xi = "auto"`` depends on the density). The same
kernel adds the external loads ``f_ext``, ``tau_ext`` (zero unless set through
:meth:`Simulation.set_external_load`) and watches for what makes a step untrustworthy: non-finite values and bodies
moving more than a quarter of their size in one step (flag per realization), and
a body that has moved half the Verlet skin since the last neighbour build (asks
for a rebuild). It also counts bodies crossing the escape line and parks them.
"""

import numpy as np

from ..backend import ti  # sets the environment before Taichi loads
from .layout import BAD_FAST, BAD_NAN, F_REBUILD


@ti.kernel
def advance_kernel(x: ti.types.ndarray(), th: ti.types.ndarray(), v: ti.types.ndarray(),
                   w: ti.types.ndarray(), f: ti.types.ndarray(), tau: ti.types.ndarray(),
                   f_ext: ti.types.ndarray(), tau_ext: ti.types.ndarray(),
                   alive: ti.types.ndarray(), running: ti.types.ndarray(),
                   bad: ti.types.ndarray(), escaped: ti.types.ndarray(),
                   sp: ti.types.ndarray(), mass: ti.types.ndarray(), inertia: ti.types.ndarray(),
                   deq: ti.types.ndarray(), xi: ti.types.ndarray(), x_ref: ti.types.ndarray(),
                   flags: ti.types.ndarray(), dt: float, skin: float, x_escape: float):
    for r, i in ti.ndrange(x.shape[0], x.shape[1]):
        if running[r] == 0 or alive[r, i] == 0:
            continue
        if advance_body(x, th, v, w, f, tau, f_ext, tau_ext, alive, bad, escaped, sp, mass,
                        inertia, deq, xi, x_ref, dt, skin, x_escape, r, i):
            flags[F_REBUILD] = 1


@ti.func
def advance_body(x: ti.template(), th: ti.template(), v: ti.template(), w: ti.template(),
                 f: ti.template(), tau: ti.template(), f_ext: ti.template(),
                 tau_ext: ti.template(), alive: ti.template(), bad: ti.template(),
                 escaped: ti.template(), sp: ti.template(), mass: ti.template(),
                 inertia: ti.template(), deq: ti.template(), xi: ti.template(),
                 x_ref: ti.template(), dt, skin, x_escape, r, i):
    """One step of body ``i`` of realization ``r``; True when it has moved half the
    Verlet skin since the last neighbour build."""
    damp = xi[sp[i]] * dt * 0.5
    vn = ((1.0 - damp) * v[r, i] + dt * (f[r, i] + f_ext[r, i]) / mass[i]) / (1.0 + damp)
    wn = ((1.0 - damp) * w[r, i] + dt * (tau[r, i] + tau_ext[r, i]) / inertia[i]) / (1.0 + damp)
    xn = x[r, i] + dt * vn
    v[r, i] = vn
    w[r, i] = wn
    x[r, i] = xn
    th[r, i] += dt * wn
    if not (ti.math.isinf(xn).any() or ti.math.isnan(xn).any()
            or ti.math.isnan(wn) or ti.math.isinf(wn)):
        if vn.norm() * dt > 0.25 * deq[i]:
            ti.atomic_or(bad[r], BAD_FAST)
    else:
        ti.atomic_or(bad[r], BAD_NAN)
    moved = (xn - x_ref[r, i]).norm() > 0.5 * skin
    if xn.x > x_escape:
        alive[r, i] = 0
        escaped[r] += 1
    return moved


def advance(bodies, batch, particles, materials, neighbors, flags, dt: float, skin: float,
            x_escape: float):
    """One step of every live body of every running realization (module doc);
    raises ``flags[F_REBUILD]`` when a body moved half the Verlet ``skin`` since
    the last neighbour build."""
    b, p = bodies, particles
    advance_kernel(b.x, b.theta, b.v, b.omega, b.force, b.torque, b.f_ext, b.tau_ext,
                   b.alive, batch.running, batch.bad, batch.escaped, p.species, p.mass,
                   p.inertia, p.d_eq, materials.xi, neighbors.x_ref, flags, dt, skin,
                   x_escape)


@ti.kernel
def _status_kernel(running: ti.types.ndarray(), escaped: ti.types.ndarray(),
                   bad: ti.types.ndarray(), max_overlap: ti.types.ndarray(),
                   out: ti.types.ndarray(), reset: ti.i32):
    for r in range(running.shape[0]):
        out[0, r] = running[r]
        out[1, r] = escaped[r]
        out[2, r] = bad[r]
        out[3, r] = max_overlap[r]
        if reset != 0:
            max_overlap[r] = 0.0


def read_status(batch, reset_overlap: bool):
    """``(running, escaped, bad, max_overlap)`` of every realization, read in one
    transfer (each read of a device array costs a kernel launch and more,
    about 0.1 ms on the CPU); with ``reset_overlap`` the deepest overlap starts
    again from 0. The integers travel in the kernels' float type: exact below
    2^24, far above any escapee count or the ``BAD_*`` bits."""
    _status_kernel(batch.running, batch.escaped, batch.bad, batch.max_overlap, batch.status,
                   int(bool(reset_overlap)))
    a = batch.status.to_numpy()
    return (a[0].astype(np.int32), a[1].astype(np.int64), a[2].astype(np.int32),
            a[3].astype(float))
