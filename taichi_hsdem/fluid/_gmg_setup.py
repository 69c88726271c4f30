"""Set-up kernels of the Taichi pressure solver (:mod:`.gmg`): the permeability
scan, the fine level's operator and right-hand side (with or without the
particles' carried flux), the initial guess, the Galerkin coarsening of the
2 x 2 aggregation levels and the coarsest level's Cholesky factor; the cycle that
uses them is in :mod:`._gmg_cycle`. Package-internal: :mod:`.gmg` is the API."""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.

import numpy as np

from ..backend import ti
from ._gmg_cycle import (REAL, _BAD, _BASE, _CHANGED, _INLET, _K_DX, _K_DY, _K_GX, _K_GY,
                         _K_INFLOW, _K_PREF, _NX, _NY, _RHS, _SOL, _TASK, _TX, _TY, _ZEROS,
                         _Cells, _Chol, _Consts, _Grid, _Ints, _Mask, _Ops, _Rows, _Sides,
                         _Vectors, _dense, _diagonal, _index)


# ---------------------------------------------------------------- helpers
@ti.func
def _built(flags: ti.template(), r, every):
    """Whether the operators of realization r are built: all (``every``), or
    those whose kappa _scan found changed. The same kappa (and the unknowns made
    from it) builds the same operator to the bit, so an unchanged realization
    keeps the one it has."""
    return every != 0 or flags[r, _CHANGED] != 0


@ti.func
def _harmonic(k1, k2):
    h = ti.cast(0.0, REAL.dtype)
    if k1 + k2 > 0:
        h = 2.0 * k1 * k2 / (k1 + k2)
    return h


def _wide(v) -> bool:
    """(at compile time) whether the Taichi expression ``v`` is float64."""
    return ti.lang.expr.Expr(v).ptr.get_rvalue_type() == ti.f64


@ti.func
def _bits(v):
    """The bit pattern of float ``v`` as an integer of its width."""
    if ti.static(_wide(v)):
        return ti.bit_cast(v, ti.i64)
    else:
        return ti.bit_cast(v, ti.i32)


@ti.func
def _is_finite(v):
    """Bit test, immune to a compiler's assumption that no value is NaN or inf."""
    finite = True
    if ti.static(_wide(v)):
        exponent = ti.i64(0x7FF)
        finite = ((ti.bit_cast(v, ti.i64) >> ti.i64(52)) & exponent) != exponent
    else:
        finite = ((ti.bit_cast(v, ti.i32) >> 23) & 0xFF) != 0xFF
    return finite


@ti.func
def _coarsen_entry(op: ti.template(), geo: ti.template(), l, r, I, J):
    """Galerkin operator entry (I, J) of level l + 1, I = -1..mx-1, J = 0..my.

    A coarse face's transmissibility is the sum of those of the fine faces
    across it: the east face of coarse column I is that of fine column 2 I + 1
    (nx - 1 if that is the last, on an odd nx), the north face of coarse row J
    that of fine row 2 J + 1 (likewise); entry (I, my) is the ghost below coarse
    column I + 1, whose bottom Dirichlet faces are those of fine columns 2 I + 2
    and 2 I + 3 (held by the fine ghosts below them).
    """
    nx, ny, my = geo[l, _NX], geo[l, _NY], geo[l + 1, _NY]
    c = ti.Vector([0.0, 0.0], dt=REAL.dtype)
    if J < my:
        fi = -1 if I < 0 else ti.min(2 * I + 1, nx - 1)
        fj = ti.min(2 * J + 1, ny - 1)
        for a in ti.static((0, 1)):
            if 2 * J + a < ny:
                c[_TX] += op[_index(geo, l, r, fi, 2 * J + a)][_TX]
            if I >= 0 and 2 * I + a < nx:
                c[_TY] += op[_index(geo, l, r, 2 * I + a, fj)][_TY]
    else:
        for a in ti.static((0, 1)):
            if 2 * I + 2 + a < nx:
                c[_TY] += op[_index(geo, l, r, 2 * I + 1 + a, ny)][_TY]
    op[_index(geo, l + 1, r, I, J)] = c


# ---------------------------------------------------------------- set-up kernels
@ti.kernel
def _scan(kappa: _Grid, seen: _Rows, connected: _Mask, flags: _Ints):
    """Count, per realization, the connected cells whose kappa changed since the
    last call, is zero, or is invalid (negative or not finite); keep a copy."""
    R, nx, ny = kappa.shape[0], kappa.shape[1], kappa.shape[2]
    for r in range(R):
        for c in ti.static((_CHANGED, _ZEROS, _BAD)):
            flags[r, c] = 0
    for t in range(R * nx):
        r, i = t // nx, t % nx
        changed, zeros, bad = 0, 0, 0
        for j in range(ny):
            if connected[i, j] != 0:
                k = ti.cast(kappa[r, i, j], REAL.dtype)
                if not (_is_finite(k) and k >= 0):
                    bad += 1
                elif k == 0:
                    zeros += 1
                if _bits(k) != _bits(seen[r, i * ny + j]):
                    changed += 1
                seen[r, i * ny + j] = k
        flags[r, _CHANGED] += changed  # integer sums: exact in any order
        flags[r, _ZEROS] += zeros
        flags[r, _BAD] += bad


@ti.kernel
def _assemble(kappa: _Grid, unknown: _Cells, sides: _Sides, op: _Ops, cg: _Rows,
              state: _Rows, geo: _Ints, consts: _Consts, flags: _Ints, every: ti.i32):
    """Fine-level operator and the kappa-dependent right-hand side, of every
    realization (``every``) or of those whose kappa changed (_built).

    ``consts``: ``gx = dy / (dx eta)``, ``gy = dx / (dy eta)``, the inflow;
    ``sides[s, m] = (g, v)``: the
    Dirichlet conductance per unit permeability of box side ``s`` at position
    ``m`` (0: wall) and its value minus ``p_ref``. The ``flow_rate`` inflow goes to
    the inlet cells in proportion to kappa. Cells that are no unknown get 0.
    """
    R, nx, ny = kappa.shape[0], kappa.shape[1], kappa.shape[2]
    for r in range(R):
        if _built(flags, r, every):
            total = ti.cast(0.0, REAL.dtype)
            for j in range(ny):
                if unknown[r, 0, j] != 0:
                    total += ti.cast(kappa[r, 0, j], REAL.dtype)
            state[r, _INLET] = total
    for t in range(R * (nx + 1)):
        r, i = t // (nx + 1), t % (nx + 1) - 1  # i = -1: the west ghost column
        gx, gy, inflow = consts[_K_GX], consts[_K_GY], consts[_K_INFLOW]
        if _built(flags, r, every):
            for j in range(ny + 1):
                c = ti.Vector([0.0, 0.0], dt=REAL.dtype)
                base = ti.cast(0.0, REAL.dtype)
                if j == ny:  # the ghost below column i + 1: its bottom Dirichlet face
                    if i + 1 < nx:  # noqa: SIM102 - Taichi's `and` does not short-circuit
                        if unknown[r, i + 1, 0] != 0:
                            c[_TY] = sides[2, i + 1][0] * ti.cast(kappa[r, i + 1, 0], REAL.dtype)
                elif i < 0:  # the west ghost: the left Dirichlet face of cell (0, j)
                    if unknown[r, 0, j] != 0:
                        c[_TX] = sides[0, j][0] * ti.cast(kappa[r, 0, j], REAL.dtype)
                elif unknown[r, i, j] != 0:
                    k = ti.cast(kappa[r, i, j], REAL.dtype)
                    c[_TX] = sides[1, j][0] * k  # on the last column, its right face
                    if i + 1 < nx:
                        c[_TX] = 0.0
                        if unknown[r, i + 1, j] != 0:
                            c[_TX] = gx * _harmonic(k, ti.cast(kappa[r, i + 1, j], REAL.dtype))
                    c[_TY] = sides[3, i][0] * k  # on the top row, its top face
                    if j + 1 < ny:
                        c[_TY] = 0.0
                        if unknown[r, i, j + 1] != 0:
                            c[_TY] = gy * _harmonic(k, ti.cast(kappa[r, i, j + 1], REAL.dtype))
                    gv = ti.cast(0.0, REAL.dtype)
                    for side in ti.static(range(4)):
                        on_side = (i == 0, i == nx - 1, j == 0, j == ny - 1)[side]
                        m = (j, j, i, i)[side]
                        if on_side:
                            gv += sides[side, m][0] * sides[side, m][1]
                    base = k * gv
                    if i == 0 and state[r, _INLET] > 0:
                        base += inflow * k / state[r, _INLET]
                op[_index(geo, 0, r, i, j)] = c
                if i >= 0 and j < ny:
                    cg[_BASE, _index(geo, 0, r, i, j)] = base


@ti.kernel
def _coarsen(op: _Ops, geo: _Ints, flags: _Ints, l: ti.i32, every: ti.i32):
    R, mx, my = flags.shape[0], geo[l + 1, _NX], geo[l + 1, _NY]
    for t in range(R * (mx + 1)):
        r, I = t // (mx + 1), t % (mx + 1) - 1
        if _built(flags, r, every):
            for J in range(my + 1):
                _coarsen_entry(op, geo, l, r, I, J)


@ti.kernel
def _factor(op: _Ops, chol: _Chol, geo: _Ints, flags: _Ints, l: ti.i32, every: ti.i32):
    """Dense Cholesky factor (lower) of each realization's coarsest operator (see
    _built); a cell that is no unknown gets an identity row."""
    R, nx, ny = chol.shape[0], geo[l, _NX], geo[l, _NY]
    for t in range(R * _TASK):
        if t % _TASK == 0 and _built(flags, t // _TASK, every):
            _factor_of(op, chol, geo, l, t // _TASK, nx, ny)


@ti.func
def _factor_of(op: ti.template(), chol: ti.template(), geo: ti.template(), l, r, nx, ny):
    m = nx * ny
    for c in range(m):
        for q in range(m):
            chol[r, c, q] = 0.0
    for c in range(m):
        k = _dense(geo, l, r, c)
        d = _diagonal(op, k, ny + 1)
        chol[r, c, c] = d if d > 0 else 1.0
        if c + ny < m:
            chol[r, c + ny, c] = -op[k][_TX]
        if (c + 1) % ny != 0:
            chol[r, c + 1, c] = -op[k][_TY]
    for c in range(m):
        v = chol[r, c, c]
        for q in range(c):
            v -= chol[r, c, q] * chol[r, c, q]
        chol[r, c, c] = ti.sqrt(v)
        for e in range(c + 1, m):
            w = chol[r, e, c]
            for q in range(c):
                w -= chol[r, e, q] * chol[r, c, q]
            chol[r, e, c] = w / chol[r, c, c]


@ti.kernel
def _copy_rhs(cg: _Rows, geo: _Ints, R: ti.i32):
    """Right-hand side without carried flux: the kappa-dependent part."""
    nx, ny = geo[0, _NX], geo[0, _NY]
    for t in range(R * nx):
        r, i = t // nx, t % nx
        for j in range(ny):
            k = _index(geo, 0, r, i, j)
            cg[_RHS, k] = cg[_BASE, k]


@ti.func
def _occupied(carried: ti.template(), occupied: ti.template(), r, i, j, given: ti.template()):
    """1 in a cell inside a particle (``occupied``, or else ``carried != 0``), else 0."""
    chi = ti.cast(0.0, REAL.dtype)
    if ti.static(given):
        chi = ti.cast(1.0, REAL.dtype) if occupied[r, i, j] != 0 else ti.cast(0.0, REAL.dtype)
    else:
        if carried[r, i, j, 0] != 0 or carried[r, i, j, 1] != 0:
            chi = 1.0
    return chi


@ti.kernel
def _set_carried_rhs(cg: _Rows, carried: _Vectors, occupied: _Grid, connected: _Mask,
                     unknown: _Cells, geo: _Ints, consts: _Consts, given: ti.template()):
    """Right-hand side with the particles' carried flux (fluid.PressureSolver.solve):
    each face between two connected cells carries the mean of ``chi v`` over its
    occupied sides (``given``: ``occupied``; else cells where ``carried != 0``),
    normal to it, times its length; zero in cells that are no unknown."""
    R, nx, ny = carried.shape[0], carried.shape[1], carried.shape[2]
    for t in range(R * nx):
        r, i = t // nx, t % nx
        dx, dy = consts[_K_DX], consts[_K_DY]
        for j in range(ny):
            k = _index(geo, 0, r, i, j)
            rhs = ti.cast(0.0, REAL.dtype)
            if unknown[r, i, j] != 0:
                inward, outward = ti.cast(0.0, REAL.dtype), ti.cast(0.0, REAL.dtype)
                # west, south (into the cell), east, north (out of it)
                for di, dj, comp, length, sign in ti.static(
                        ((-1, 0, 0, 0, 1), (0, -1, 1, 1, 1), (1, 0, 0, 0, -1), (0, 1, 1, 1, -1))):
                    i2, j2 = i + di, j + dj
                    if i2 >= 0 and i2 < nx and j2 >= 0 and j2 < ny:  # noqa: SIM102
                        if connected[i2, j2] != 0:
                            chi = (_occupied(carried, occupied, r, i, j, given)
                                   + _occupied(carried, occupied, r, i2, j2, given))
                            v = (ti.cast(carried[r, i, j, comp], REAL.dtype)
                                 + ti.cast(carried[r, i2, j2, comp], REAL.dtype))
                            q = v / ti.max(chi, 1.0) * (dy, dx)[length]
                            if ti.static(sign == 1):
                                inward += q
                            else:
                                outward += q
                rhs = cg[_BASE, k] + (inward - outward)
            cg[_RHS, k] = rhs


@ti.kernel
def _load_guess(x0: _Grid, unknown: _Cells, cg: _Rows, geo: _Ints, consts: _Consts):
    """The initial guess ``x0 - p_ref``, 0 where that is not finite or no unknown."""
    R, nx, ny = x0.shape[0], x0.shape[1], x0.shape[2]
    for t in range(R * nx):
        r, i = t // nx, t % nx
        for j in range(ny):
            v = ti.cast(x0[r, i, j], REAL.dtype) - consts[_K_PREF]
            if not (unknown[r, i, j] != 0 and _is_finite(v)):
                v = 0.0
            cg[_SOL, _index(geo, 0, r, i, j)] = v


def _upload(array, dtype, element=None):
    """A device copy of a numpy array (``element``: a vector type for the last axis)."""
    array = np.ascontiguousarray(array)
    shape = array.shape[:-1] if element is not None else array.shape
    out = ti.ndarray(element if element is not None else dtype, shape)
    out.from_numpy(array.astype({ti.f64: np.float64, ti.f32: np.float32, ti.i32: np.int32,
                                 ti.i8: np.int8}[dtype]))
    return out
