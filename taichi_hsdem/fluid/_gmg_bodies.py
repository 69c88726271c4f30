"""The moving bodies' terms of the implicit carried-volume coupling in the Taichi
pressure solver (:mod:`.gmg`; docs/scene.md, "Carried volume").

A body ``o`` with generalized velocity ``u_o = (v_x, v_y, omega)`` moves the
fluid-grid cells it owns (``owner``: the cells whose centre lies inside it) at
``v + omega z x r_c``, ``r_c`` from its centre. Each face carries the mean of
that velocity over its owned sides, normal to it, times its length (the lagged
carried flux's rule, fluid.PressureSolver.solve: a face on the body's edge
carries the whole velocity, so the volume it sweeps lands in the fluid cells
next to it, not in the body's low permeability). The right-hand side gains
``S u``, linear in all the bodies' velocities. The velocity over the next
fluid interval is affine in the pressure: ``u = d + M (F_0 - H S^T (p - p_0))``
with ``F_0`` the last step's force (held pressure force from ``p_0`` included)
and ``-H S^T`` the pressure force's change, read by the same weights the other
way (the pressure gradient summed over the owned cells). So the pressure solves

    (A + S (H M) S^T) x = b + S (q + (H M) S^T x_0),   q = d + M F_0,

``x_0`` the initial guess (the last solution). A body that does not move
(``q = 0`` and in balance) leaves the pressure of the fixed obstacles
exactly. The matrix is ``A`` plus one symmetric positive semi-definite term per
body: CG applies as before, preconditioned by the multigrid of ``A`` alone.

Arrays: ``owner`` (R, nx, ny) int32 (-1: no body), ``centre`` (R, N, 2) float64
in cell units (cell ``(i, j)``'s centre at ``(i, j)``), ``mobility`` (R, N, 3)
``H M`` (0 for a body out of play), ``drift`` (R, N, 3) ``q``; work arrays
``y``, ``z`` (R, N, 3), ``box`` (R, N, 4) int32 (each body's box of cells,
found by :func:`_body_rhs`). Each body's sum runs over the cells it owns in cell
order, each cell's over its four faces, in one thread each: a realization's
result depends on nothing else in the batch, nor on how the threads are laid out.
Package-internal: :mod:`.gmg` is the API."""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
from ..backend import ti
from ._gmg_cycle import _BASE, _NX, _NY, _RHS, _SOL, _Cells, _Field, _Ints, _Rows, _index

_Owner = ti.types.ndarray(dtype=ti.i32, ndim=3)   # (R, nx, ny): a body's number or -1


@ti.func
def _face_weight(owner: ti.template(), unknown: ti.template(), r, i, j, i2, j2, length):
    """Length over the owned sides' count (at least 1) of the face between (i, j)
    and (i2, j2); 0 if (i2, j2) is off the grid or no unknown."""
    nx, ny = owner.shape[1], owner.shape[2]
    w = ti.f64(0.0)
    if 0 <= i2 < nx and 0 <= j2 < ny:
        if unknown[r, i2, j2] != 0:
            # length / max(count, 1), without a division: halving is exact
            w = length
            if owner[r, i, j] >= 0 and owner[r, i2, j2] >= 0:
                w = 0.5 * length
    return w


@ti.func
def _near_body(owner: ti.template(), r, i, j):
    """Whether a body owns (i, j) or one of its four neighbours: elsewhere every
    face of the cell carries nothing (a test that spares most cells the sum)."""
    nx, ny = owner.shape[1], owner.shape[2]
    near = owner[r, i, j] >= 0
    if i > 0:
        near = near or owner[r, i - 1, j] >= 0
    if i + 1 < nx:
        near = near or owner[r, i + 1, j] >= 0
    if j > 0:
        near = near or owner[r, i, j - 1] >= 0
    if j + 1 < ny:
        near = near or owner[r, i, j + 1] >= 0
    return near


@ti.func
def _cell_velocity(owner: ti.template(), centre: ti.template(), z: ti.template(), r, i, j,
                   dx, dy):
    """``v + omega z x r_c`` of the body owning (i, j) in the generalized
    velocities ``z``; 0 in a cell no body owns."""
    v = ti.Vector([0.0, 0.0], dt=ti.f64)
    o = owner[r, i, j]
    if o >= 0:
        rx = (i - centre[r, o, 0]) * dx
        ry = (j - centre[r, o, 1]) * dy
        v = ti.Vector([z[r, o, 0] - z[r, o, 2] * ry, z[r, o, 1] + z[r, o, 2] * rx], dt=ti.f64)
    return v


@ti.func
def _gather_body(cg: ti.template(), src, owner: ti.template(), unknown: ti.template(),
                 centre: ti.template(), y: ti.template(), box: ti.template(), geo: ti.template(),
                 dx, dy, r, o):
    """``y[r, o] = (S^T cg[src])`` of body o: its owned cells, in cell order, found
    in its box of cells (``box``, made by :func:`_body_rhs`)."""
    ny = geo[0, _NY]
    gx_sum = ti.f64(0.0)
    gy_sum = ti.f64(0.0)
    tau = ti.f64(0.0)
    for i in range(box[r, o, 0], box[r, o, 1] + 1):
        for j in range(box[r, o, 2], box[r, o, 3] + 1):
            if owner[r, i, j] == o and unknown[r, i, j] != 0:
                k = _index(geo, 0, r, i, j)
                s = ny + 1
                d = cg[src, k]
                gx = ti.f64(0.0)
                gy = ti.f64(0.0)
                w = _face_weight(owner, unknown, r, i, j, i + 1, j, dy)
                if w > 0:
                    gx += (cg[src, k + s] - d) * w
                w = _face_weight(owner, unknown, r, i, j, i - 1, j, dy)
                if w > 0:
                    gx += (d - cg[src, k - s]) * w
                w = _face_weight(owner, unknown, r, i, j, i, j + 1, dx)
                if w > 0:
                    gy += (cg[src, k + 1] - d) * w
                w = _face_weight(owner, unknown, r, i, j, i, j - 1, dx)
                if w > 0:
                    gy += (d - cg[src, k - 1]) * w
                rx = (i - centre[r, o, 0]) * dx
                ry = (j - centre[r, o, 1]) * dy
                gx_sum += gx
                gy_sum += gy
                tau += rx * gy - ry * gx
    y[r, o, 0] = gx_sum
    y[r, o, 1] = gy_sum
    y[r, o, 2] = tau


@ti.func
def _spread_cell(cg: ti.template(), base, owner: ti.template(), unknown: ti.template(),
                 centre: ti.template(), z: ti.template(), geo: ti.template(), dx, dy, r, i, j):
    """``cg[base] + (S z)`` at cell (i, j) of realization r (``base < 0``:
    ``S z``): the carried flux into the cell, net."""
    k = _index(geo, 0, r, i, j)
    val = ti.f64(0.0)
    if unknown[r, i, j] != 0 and _near_body(owner, r, i, j):
        here = _cell_velocity(owner, centre, z, r, i, j, dx, dy)
        for di, dj, comp, sign in ti.static(((-1, 0, 0, 1.0), (1, 0, 0, -1.0),
                                             (0, -1, 1, 1.0), (0, 1, 1, -1.0))):
            i2, j2 = i + di, j + dj
            length = dy if ti.static(comp == 0) else dx
            w = _face_weight(owner, unknown, r, i, j, i2, j2, length)
            if w > 0 and (owner[r, i, j] >= 0 or owner[r, i2, j2] >= 0):
                there = _cell_velocity(owner, centre, z, r, i2, j2, dx, dy)
                val += sign * (here[comp] + there[comp]) * w
    if base >= 0:
        val += cg[base, k]
    return val


@ti.func
def _product_of(cg: ti.template(), src, dst, owner: ti.template(), unknown: ti.template(),
                centre: ti.template(), mobility: ti.template(), y: ti.template(),
                z: ti.template(), box: ti.template(), geo: ti.template(), dx, dy, r):
    """``cg[dst] = S (H M) S^T cg[src]`` of realization r, at every cell, serially
    (in the thread that runs the realization's whole solve)."""
    for o in range(y.shape[1]):
        _gather_body(cg, src, owner, unknown, centre, y, box, geo, dx, dy, r, o)
        for m in ti.static(range(3)):
            z[r, o, m] = mobility[r, o, m] * y[r, o, m]
    for i in range(geo[0, _NX]):
        for j in range(geo[0, _NY]):
            cg[dst, _index(geo, 0, r, i, j)] = _spread_cell(cg, -1, owner, unknown, centre,
                                                            z, geo, dx, dy, r, i, j)


@ti.func
def _product(cg: ti.template(), src, dst, flags: ti.template(), running, owner: ti.template(),
             unknown: ti.template(), centre: ti.template(), mobility: ti.template(),
             y: ti.template(), z: ti.template(), box: ti.template(), geo: ti.template(), dx, dy):
    """``cg[dst] = S (H M) S^T cg[src]`` of every running realization (flag
    ``running`` of ``flags``), in two top-level loops: a thread per body, then a
    thread per grid column. Each body's sum runs over its own cells in cell order and
    each cell's over its four faces, so the bits are those of :func:`_product_of`."""
    R, N = y.shape[0], y.shape[1]
    for r, o in ti.ndrange(R, N):
        if flags[r, running]:
            _gather_body(cg, src, owner, unknown, centre, y, box, geo, dx, dy, r, o)
            for m in ti.static(range(3)):
                z[r, o, m] = mobility[r, o, m] * y[r, o, m]
    nx, ny = geo[0, _NX], geo[0, _NY]
    for t in range(R * nx):  # a thread per grid column: a third faster than per cell
        r, i = t // nx, t % nx
        if flags[r, running]:
            for j in range(ny):
                cg[dst, _index(geo, 0, r, i, j)] = _spread_cell(cg, -1, owner, unknown,
                                                                centre, z, geo, dx, dy, r, i, j)


@ti.kernel
def _body_rhs(cg: _Rows, owner: _Owner, unknown: _Cells, centre: _Field, mobility: _Field,
              drift: _Field, y: _Field, z: _Field, box: _Owner, geo: _Ints, dx: ti.f64,
              dy: ti.f64):
    """Each body's box of cells (the smallest holding the cells it owns; empty
    if none), then ``RHS = BASE + S (q + (H M) S^T SOL)``, SOL being the
    initial guess."""
    R, N = y.shape[0], y.shape[1]
    nx, ny = geo[0, _NX], geo[0, _NY]
    for r, o in ti.ndrange(R, N):
        box[r, o, 0], box[r, o, 1], box[r, o, 2], box[r, o, 3] = nx, -1, ny, -1
    for r, i, j in ti.ndrange(R, nx, ny):
        o = owner[r, i, j]
        if o >= 0:
            ti.atomic_min(box[r, o, 0], i)
            ti.atomic_max(box[r, o, 1], i)
            ti.atomic_min(box[r, o, 2], j)
            ti.atomic_max(box[r, o, 3], j)
    for r, o in ti.ndrange(R, N):
        _gather_body(cg, _SOL, owner, unknown, centre, y, box, geo, dx, dy, r, o)
        for m in ti.static(range(3)):
            z[r, o, m] = drift[r, o, m] + mobility[r, o, m] * y[r, o, m]
    for r, i, j in ti.ndrange(R, nx, ny):
        cg[_RHS, _index(geo, 0, r, i, j)] = _spread_cell(cg, _BASE, owner, unknown, centre,
                                                         z, geo, dx, dy, r, i, j)
