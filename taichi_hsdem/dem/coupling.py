"""Fluid to particle and particle to fluid (MODEL.md sections 2 and 3).

* Permeability: a fluid cell whose centre lies inside a particle (``phi <= 0``)
  takes the particle species' Kozeny-Carman permeability; other fluid cells keep
  the free value ``H^2/12``; wall cells are not unknowns (``base = 0``).
* Pressure force: each surface node ``k`` takes the pressure ``sigma`` at its
  position and contributes ``F_k = -sigma H a_k``, ``M_k = (p_k - x) x F_k``.
  ``a_k`` is the node's outward boundary vector, ``l_k n_k``, taken as half the
  rotated chord between its two neighbours: the ``a_k`` of a closed outline then
  sum to exactly zero, so a uniform pressure pushes no body anywhere, and in a
  linear pressure field the force is exactly the pressure drop across the node
  polygon's area (divergence theorem) — the property a test checks.
"""

import numpy as np
from ..backend import ti  # sets the environment before Taichi loads

from .contact import cross, node_world, rot, rot_t, spin, template_sample

vec2 = ti.math.vec2

# fluid grid parameters (real array)
FG_OX, FG_OY, FG_DX, FG_GAP, FG_SAMPLING = 0, 1, 2, 3, 4
N_FGPARAMS = 5
SAMPLING = {"bilinear": 0, "cell": 1}


def boundary_vectors(nodes: np.ndarray) -> np.ndarray:
    """Outward boundary vectors ``a_k`` (length times normal) of a closed CCW node loop."""
    chord = np.roll(nodes, -1, axis=0) - np.roll(nodes, 1, axis=0)
    return 0.5 * np.stack([chord[:, 1], -chord[:, 0]], axis=1)


@ti.func
def inside_body(tm, is_circle: ti.template(), trad: ti.template(), ls_phi: ti.template(),
                ls_grad: ti.template(), ls_meta: ti.template(), ls_geo: ti.template(), q):
    """Is body-frame point ``q`` inside template ``tm``."""
    inside = False
    if is_circle[tm] != 0:
        inside = q.norm() <= trad[tm]
    else:
        phi, g = template_sample(ls_phi, ls_grad, ls_meta, ls_geo, tm, q)
        inside = phi <= 0.0
    return inside


@ti.kernel
def rasterize_permeability(x: ti.types.ndarray(), th: ti.types.ndarray(),
                           alive: ti.types.ndarray(), sp: ti.types.ndarray(),
                           tm: ti.types.ndarray(), rb: ti.types.ndarray(),
                           kp: ti.types.ndarray(), is_circle: ti.types.ndarray(),
                           trad: ti.types.ndarray(), ls_phi: ti.types.ndarray(), ls_grad: ti.types.ndarray(),
                           ls_meta: ti.types.ndarray(), ls_geo: ti.types.ndarray(),
                           base: ti.types.ndarray(), kappa: ti.types.ndarray(),
                           fg: ti.types.ndarray(), vs: ti.types.ndarray(),
                           ws: ti.types.ndarray(), carried: ti.types.ndarray()):
    """Permeability of every fluid cell, and ``chi v``: the velocity of the particle
    a cell's centre lies in (``vs + ws x r``), zero outside particles."""
    nx = base.shape[0]
    ny = base.shape[1]
    ox = fg[FG_OX]
    oy = fg[FG_OY]
    h = fg[FG_DX]
    for r, cx, cy in kappa:
        kappa[r, cx, cy] = base[cx, cy]
        carried[r, cx, cy] = vec2(0.0, 0.0)
    for r, i in ti.ndrange(x.shape[0], x.shape[1]):
        if alive[r, i] == 0:
            continue
        xi = x[r, i]
        c = ti.cos(th[r, i])
        s = ti.sin(th[r, i])
        i0 = ti.max(ti.cast(ti.floor((xi.x - rb[i] - ox) / h - 0.5), ti.i32), 0)
        i1 = ti.min(ti.cast(ti.ceil((xi.x + rb[i] - ox) / h - 0.5), ti.i32), nx - 1)
        j0 = ti.max(ti.cast(ti.floor((xi.y - rb[i] - oy) / h - 0.5), ti.i32), 0)
        j1 = ti.min(ti.cast(ti.ceil((xi.y + rb[i] - oy) / h - 0.5), ti.i32), ny - 1)
        for a in range(i0, i1 + 1):
            for b in range(j0, j1 + 1):
                if base[a, b] > 0.0:
                    centre = vec2(ox + (a + 0.5) * h, oy + (b + 0.5) * h)
                    if inside_body(tm[i], is_circle, trad, ls_phi, ls_grad, ls_meta, ls_geo,
                                   rot_t(c, s, centre - xi)):
                        ti.atomic_min(kappa[r, a, b], kp[sp[i]])
                        carried[r, a, b] = vs[r, i] + spin(ws[r, i], centre - xi)


@ti.func
def sample_pressure(pres: ti.template(), active: ti.template(), r, p, ox, oy, h, mode):
    """Pressure at ``p``: bilinear over the active cell centres around it
    (weights renormalised next to walls), or the value of the cell holding it."""
    nx = active.shape[0]
    ny = active.shape[1]
    gx = (p.x - ox) / h - 0.5
    gy = (p.y - oy) / h - 0.5
    value = 0.0
    done = False
    if mode == 1:
        a = ti.cast(ti.floor(gx + 0.5), ti.i32)
        b = ti.cast(ti.floor(gy + 0.5), ti.i32)
        if 0 <= a < nx and 0 <= b < ny:
            if active[a, b] != 0:
                value = pres[r, a, b]
                done = True
    if not done:
        i0 = ti.cast(ti.floor(gx), ti.i32)
        j0 = ti.cast(ti.floor(gy), ti.i32)
        fx = gx - i0
        fy = gy - j0
        wsum = 0.0
        acc = 0.0
        for da, db in ti.static(ti.ndrange(2, 2)):
            a = i0 + da
            b = j0 + db
            if 0 <= a < nx and 0 <= b < ny:
                if active[a, b] != 0:
                    wgt = (fx if da == 1 else 1.0 - fx) * (fy if db == 1 else 1.0 - fy)
                    wsum += wgt
                    acc += wgt * pres[r, a, b]
        if wsum > 0.0:
            value = acc / wsum
    return value


@ti.kernel
def pressure_forces(x: ti.types.ndarray(), th: ti.types.ndarray(),
                    alive: ti.types.ndarray(), running: ti.types.ndarray(),
                    tm: ti.types.ndarray(), node_pos: ti.types.ndarray(),
                    node_area: ti.types.ndarray(), node_meta: ti.types.ndarray(),
                    pres: ti.types.ndarray(), active: ti.types.ndarray(),
                    fg: ti.types.ndarray(), f: ti.types.ndarray(), tau: ti.types.ndarray()):
    """Set ``f``, ``tau`` of every body to its pressure force and moment."""
    ox = fg[FG_OX]
    oy = fg[FG_OY]
    h = fg[FG_DX]
    gap = fg[FG_GAP]
    mode = ti.cast(fg[FG_SAMPLING], ti.i32)
    for r, i in ti.ndrange(x.shape[0], x.shape[1]):
        fsum = vec2(0.0, 0.0)
        msum = 0.0
        if running[r] != 0 and alive[r, i] != 0:
            xi = x[r, i]
            c = ti.cos(th[r, i])
            s = ti.sin(th[r, i])
            off = node_meta[tm[i], 0]
            for k in range(node_meta[tm[i], 1]):
                p = node_world(node_pos, off + k, xi, c, s)
                sigma = sample_pressure(pres, active, r, p, ox, oy, h, mode)
                df = -sigma * gap * rot(c, s, vec2(node_area[off + k, 0], node_area[off + k, 1]))
                fsum += df
                msum += cross(p - xi, df)
        f[r, i] = fsum
        tau[r, i] = msum


@ti.kernel
def load_forces(f: ti.types.ndarray(), tau: ti.types.ndarray(), f0: ti.types.ndarray(),
                tau0: ti.types.ndarray()):
    """Start a step's force sums from the held fluid forces ``f0``, ``tau0``."""
    for r, i in f:
        f[r, i] = f0[r, i]
        tau[r, i] = tau0[r, i]
