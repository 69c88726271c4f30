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

Arrays: ``owner`` (R, nx, ny) int32 (-1: no body), ``centre`` (R, N, 2) in cell units (cell ``(i, j)``'s centre at ``(i, j)``), ``mobility`` (R, N, 3)
``H M`` (0 for a body out of play), ``drift`` (R, N, 3) ``q``. The kernels take
them as one argument pack of type :data:`Terms`: ``owner``, the grid's
``unknown`` cells, ``body`` (R, N, 11) of the solve's float type with named columns (the centre
and ``H M``, copied in by :func:`_body_rhs`, and the work vectors ``y = S^T x``,
``z = H M y``) and ``box`` (R, N, 4) int32 (each body's box of cells, found by
:func:`_body_rhs`): four arrays, not seven, as each array costs a launch of the
CG kernels about 3.5 us. Each body's sum runs over the cells it owns in cell
order, each cell's over its four faces, in one thread each: a realization's
result depends on nothing else in the batch, nor on how the threads are laid out.
Package-internal: :mod:`.gmg` is the API."""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
from typing import NamedTuple

from ..backend import ti
from ._gmg_cycle import (REAL, _BASE, _K_DX, _K_DY, _NX, _NY, _RHS, _SKIP, _SOL, _Cells,
                         _Consts, _Field, _Ints, _Rows, _index)


class BodyTerms(NamedTuple):
    """The moving bodies of the implicit carried-volume coupling, for
    :meth:`.gmg.TaichiPressureSolver.solve` (the equations: the module docstring;
    docs/scene.md, "Carried volume"): Taichi ndarrays, ``R`` realizations of
    ``N`` bodies.

    Attributes
    ----------
    owner : int32 (R, nx, ny)
        The body whose outline holds each cell's centre, -1 for none.
    centre : (R, N, 2), the solve's float type (float64 where the backend has it)
        Each body's centre in cell units: cell ``(i, j)``'s centre is at ``(i, j)``.
    mobility : (R, N, 3)
        ``H M``: over the next fluid interval the body moves at ``drift -
        mobility S^T (p - p_0)`` (``v_x, v_y, omega``; 0 for a body out of play),
        ``p_0`` the initial guess.
    drift : (R, N, 3)
        That velocity at ``p = p_0``.
    """

    owner: object
    centre: object
    mobility: object
    drift: object


_Owner = ti.types.ndarray(dtype=ti.i32, ndim=3)   # (R, nx, ny): a body's number or -1

# Columns of ``body``: the centre (x, y), then the first of three (x, y, rotation)
# each for ``H M``, ``y`` and ``z``.
_CX, _CY, _MOB, _Y, _Z = 0, 1, 2, 5, 8
BODY_COLUMNS = 11

#: The bodies' arrays of the CG kernels (module docstring).
Terms = ti.types.argpack(owner=_Owner, unknown=_Cells, body=_Field, box=_Owner)


@ti.func
def _face_weight(owner: ti.template(), unknown: ti.template(), r, i, j, i2, j2, length):
    """Length over the owned sides' count (at least 1) of the face between (i, j)
    and (i2, j2); 0 if (i2, j2) is off the grid or no unknown."""
    nx, ny = owner.shape[1], owner.shape[2]
    w = ti.cast(0.0, REAL.dtype)
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
def _cell_velocity(terms: ti.template(), r, i, j, dx, dy):
    """``v + omega z x r_c`` of the body owning (i, j) in the generalized
    velocities ``z``; 0 in a cell no body owns."""
    v = ti.Vector([0.0, 0.0], dt=REAL.dtype)
    o = terms.owner[r, i, j]
    if o >= 0:
        rx = (i - terms.body[r, o, _CX]) * dx
        ry = (j - terms.body[r, o, _CY]) * dy
        z = ti.Vector([terms.body[r, o, _Z + m] for m in ti.static(range(3))], dt=REAL.dtype)
        v = ti.Vector([z[0] - z[2] * ry, z[1] + z[2] * rx], dt=REAL.dtype)
    return v


@ti.func
def _gather_body(cg: ti.template(), src, terms: ti.template(), geo: ti.template(), dx, dy, r,
                 o):
    """``y[r, o] = (S^T cg[src])`` of body o: its owned cells, in cell order, found
    in its box of cells (``box``, made by :func:`_body_rhs`)."""
    _gather(cg, src, terms.owner, terms.unknown, terms.body, terms.box, geo, dx, dy, r, o)


@ti.func
def _gather(cg: ti.template(), src, owner: ti.template(), unknown: ti.template(),
            body: ti.template(), box: ti.template(), geo: ti.template(), dx, dy, r, o):
    """:func:`_gather_body` on the members of its pack (Taichi cannot alias them)."""
    ny = geo[0, _NY]
    gx_sum = ti.cast(0.0, REAL.dtype)
    gy_sum = ti.cast(0.0, REAL.dtype)
    tau = ti.cast(0.0, REAL.dtype)
    for i in range(box[r, o, 0], box[r, o, 1] + 1):
        for j in range(box[r, o, 2], box[r, o, 3] + 1):
            if owner[r, i, j] == o and unknown[r, i, j] != 0:
                k = _index(geo, 0, r, i, j)
                s = ny + 1
                d = cg[src, k]
                gx = ti.cast(0.0, REAL.dtype)
                gy = ti.cast(0.0, REAL.dtype)
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
                rx = (i - body[r, o, _CX]) * dx
                ry = (j - body[r, o, _CY]) * dy
                gx_sum += gx
                gy_sum += gy
                tau += rx * gy - ry * gx
    body[r, o, _Y] = gx_sum
    body[r, o, _Y + 1] = gy_sum
    body[r, o, _Y + 2] = tau


@ti.func
def _spread_cell(cg: ti.template(), base, terms: ti.template(), geo: ti.template(), dx, dy, r,
                 i, j):
    """``cg[base] + (S z)`` at cell (i, j) of realization r (``base < 0``:
    ``S z``): the carried flux into the cell, net."""
    k = _index(geo, 0, r, i, j)
    val = ti.cast(0.0, REAL.dtype)
    if terms.unknown[r, i, j] != 0 and _near_body(terms.owner, r, i, j):
        here = _cell_velocity(terms, r, i, j, dx, dy)
        for di, dj, comp, sign in ti.static(((-1, 0, 0, 1.0), (1, 0, 0, -1.0),
                                             (0, -1, 1, 1.0), (0, 1, 1, -1.0))):
            i2, j2 = i + di, j + dj
            length = dy if ti.static(comp == 0) else dx
            w = _face_weight(terms.owner, terms.unknown, r, i, j, i2, j2, length)
            if w > 0 and (terms.owner[r, i, j] >= 0 or terms.owner[r, i2, j2] >= 0):
                there = _cell_velocity(terms, r, i2, j2, dx, dy)
                val += sign * (here[comp] + there[comp]) * w
    if base >= 0:
        val += cg[base, k]
    return val


@ti.func
def _set_z(body: ti.template(), r, o):
    """``z = H M y`` of body o."""
    for m in ti.static(range(3)):
        body[r, o, _Z + m] = body[r, o, _MOB + m] * body[r, o, _Y + m]


@ti.func
def _product_of(cg: ti.template(), src, dst, terms: ti.template(), geo: ti.template(),
                consts: ti.template(), r):
    """``cg[dst] = S (H M) S^T cg[src]`` of realization r, at every cell, serially
    (in the thread that runs the realization's whole solve)."""
    gathers_of(cg, src, terms, geo, consts, r)
    for i in range(geo[0, _NX]):
        first = _index(geo, 0, r, i, 0)
        for j in range(geo[0, _NY]):
            cg[dst, first + j] = 0.0
    for o in range(terms.body.shape[1]):
        _spread_box(cg, dst, -1, terms, geo, consts[_K_DX], consts[_K_DY], r, o)


@ti.func
def gathers_of(cg: ti.template(), src, terms: ti.template(), geo: ti.template(),
               consts: ti.template(), r):
    """``z = H M S^T cg[src]`` of every body of realization r, serially: the
    first half of :func:`_product_of`, whose reads lie in the bodies' rings
    (:func:`ring`)."""
    for o in range(terms.body.shape[1]):
        _gather_body(cg, src, terms, geo, consts[_K_DX], consts[_K_DY], r, o)
        _set_z(terms.body, r, o)


@ti.func
def ring(terms: ti.template(), geo: ti.template(), r, o):
    """(i0, i1, j0, j1): body o's box of cells with the ring of cells around it,
    cells i0 <= i < i1, j0 <= j < j1 (empty for a body that owns no cell). Every
    cell where ``S z`` is not 0 lies in some body's (a face carries only between
    cells of which one is owned), and so does every value the gather reads."""
    nx, ny = geo[0, _NX], geo[0, _NY]
    return ti.Vector([ti.max(terms.box[r, o, 0] - 1, 0), ti.min(terms.box[r, o, 1] + 2, nx),
                      ti.max(terms.box[r, o, 2] - 1, 0), ti.min(terms.box[r, o, 3] + 2, ny)])


@ti.func
def _spread_box(cg: ti.template(), dst, base, terms: ti.template(), geo: ti.template(), dx,
                dy, r, o):
    """``cg[dst] = cg[base] + S z`` (``base < 0``: ``S z``) at the cells of body
    o's :func:`ring`; a cell in two rings gets the same value twice
    (:func:`_spread_cell` sums all of its faces). The rest of ``cg[dst]`` is set
    beforehand (0, or ``0 + cg[base]``)."""
    b = ring(terms, geo, r, o)
    for i in range(b[0], b[1]):
        for j in range(b[2], b[3]):
            cg[dst, _index(geo, 0, r, i, j)] = _spread_cell(cg, base, terms, geo, dx, dy, r,
                                                            i, j)


@ti.func
def _product(cg: ti.template(), src, dst, flags: ti.template(), running, terms: ti.template(),
             geo: ti.template(), consts: ti.template()):
    """``cg[dst] = S (H M) S^T cg[src]`` of every running realization (flag
    ``running`` of ``flags``), in three top-level loops: a thread per body (the
    gather), per grid column (``cg[dst] = 0``), per body (:func:`_spread_box`).
    Each body's sum runs over its own cells in cell order and each cell's over its
    four faces, so the bits are those of :func:`_product_of`."""
    R, N = terms.body.shape[0], terms.body.shape[1]
    for r, o in ti.ndrange(R, N):
        if flags[r, running]:
            _gather_body(cg, src, terms, geo, consts[_K_DX], consts[_K_DY], r, o)
            _set_z(terms.body, r, o)
    nx, ny = geo[0, _NX], geo[0, _NY]
    for t in range(R * nx):  # a thread per grid column
        r, i = t // nx, t % nx
        if flags[r, running]:
            first = _index(geo, 0, r, i, 0)
            for j in range(ny):
                cg[dst, first + j] = 0.0
    for r, o in ti.ndrange(R, N):  # a cell in two bodies' boxes gets one value twice
        if flags[r, running]:
            _spread_box(cg, dst, -1, terms, geo, consts[_K_DX], consts[_K_DY], r, o)


@ti.kernel
def _body_rhs(cg: _Rows, terms: Terms, centre: _Field, mobility: _Field, drift: _Field,
              geo: _Ints, consts: _Consts, flags: _Ints):
    """``terms.body``'s centre and ``H M`` columns from ``centre`` and ``mobility``;
    each body's box of cells (the smallest holding the cells it owns; empty if
    none); then ``RHS = BASE + S (q + (H M) S^T SOL)``, SOL being the initial
    guess. Not for a realization left out of the solve (flag _SKIP): no kernel of
    the solve reads its terms or right-hand side."""
    _load_terms(terms.owner, terms.body, terms.box, centre, mobility, geo, flags)
    R, N = terms.body.shape[0], terms.body.shape[1]
    for r, o in ti.ndrange(R, N):
        if flags[r, _SKIP] == 0:
            _gather_body(cg, _SOL, terms, geo, consts[_K_DX], consts[_K_DY], r, o)
            for m in ti.static(range(3)):
                terms.body[r, o, _Z + m] = (drift[r, o, m] + terms.body[r, o, _MOB + m]
                                            * terms.body[r, o, _Y + m])
    nx, ny = geo[0, _NX], geo[0, _NY]
    for t in range(R * nx):  # a thread per grid column: RHS = BASE (0 + it, as below)
        r, i = t // nx, t % nx
        if flags[r, _SKIP] == 0:
            first = _index(geo, 0, r, i, 0)
            for j in range(ny):
                cg[_RHS, first + j] = ti.cast(0.0, REAL.dtype) + cg[_BASE, first + j]
    for r, o in ti.ndrange(R, N):  # + S z where it is not 0: the bodies' rings
        if flags[r, _SKIP] == 0:
            _spread_box(cg, _RHS, _BASE, terms, geo, consts[_K_DX], consts[_K_DY], r, o)


@ti.func
def _load_terms(owner: ti.template(), body: ti.template(), box: ti.template(),
                centre: ti.template(), mobility: ti.template(), geo: ti.template(),
                flags: ti.template()):
    """The first passes of :func:`_body_rhs`: the centre and ``H M`` columns of
    ``body``, then each body's box of cells."""
    R, N = body.shape[0], body.shape[1]
    nx, ny = geo[0, _NX], geo[0, _NY]
    for r, o in ti.ndrange(R, N):
        if flags[r, _SKIP] == 0:
            body[r, o, _CX] = centre[r, o, 0]
            body[r, o, _CY] = centre[r, o, 1]
            for m in ti.static(range(3)):
                body[r, o, _MOB + m] = mobility[r, o, m]
            box[r, o, 0], box[r, o, 1], box[r, o, 2], box[r, o, 3] = nx, -1, ny, -1
    for r, i, j in ti.ndrange(R, nx, ny):
        o = -1
        if flags[r, _SKIP] == 0:
            o = owner[r, i, j]
        if o >= 0:
            ti.atomic_min(box[r, o, 0], i)
            ti.atomic_max(box[r, o, 1], i)
            ti.atomic_min(box[r, o, 2], j)
            ti.atomic_max(box[r, o, 3], j)
