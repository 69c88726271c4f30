"""Conjugate-gradient pieces of the Taichi pressure solver (:mod:`.gmg`): the
per-cell CG steps, the deterministic segment sums behind every dot product, one
CG iteration per kernel launch or a whole solve per realization, and the
pressure and boundary fluxes read back. Package-internal: :mod:`.gmg` is the API."""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
from ..backend import ti
from ._gmg_cycle import (N_FLAGS, OVERCORRECTION, REAL, _ADIR, _ALPHA, _B, _BB, _BETA, _CHECK,
                         _Cells, _Chol, _FIRST, _TX, _TY, _Consts, _DIR, _Field, _Grid, _INLET,
                         _ITERS, _Ints, _K_INFLOW, _K_PREF, _K_TOL2, _NX, _NY, _Ops, _PW, _RES,
                         _RHS, _RR, _RUNNING, _RZ, _Rows, _SKIP, _SOL, _Sides, _TASK, _UNDRIVEN,
                         _X, _apply, _cycle_of, _diagonal, _index, _lanes, _segment, _segments)
from ._gmg_bodies import Terms, _product, _product_of

#: The float32 solve also stops once its true residual is below this fraction of
#: ``|A| |x|`` (_after_check): round-off (the solves of gmg.F32_FLUX_FLOOR's
#: measurements stop there at 1e-7 as at 1e-6; 3e-7 is 5 units of round-off).
F32_OPERATOR_FLOOR = 3e-7

# ---------------------------------------------------------------- CG pieces
# Per-cell steps of CG on the finest level (k: flat index, s: column stride),
# with one signature so that the
# loops below can run any of them: in parallel over the grid (_for_cells) or over
# one realization in one thread (_for_cells_of), with identical arithmetic.
@ti.func
def _clear(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
           flags: ti.template(), r, k, s):
    """No guess where there is no unknown, nor anywhere without driving (b = 0:
    the answer of an SPD system is 0)."""
    if _diagonal(op, k, s) == 0 or flags[r, _UNDRIVEN] != 0:
        cg[_SOL, k] = 0.0


@ti.func
def _residual(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
              flags: ti.template(), r, k, s):
    mg[_B, k] = cg[_RHS, k] - _apply(op, cg, _SOL, k, s)
    _operator_scale(op, mg, cg, k, s)


@ti.func
def _operator_scale(op: ti.template(), mg: ti.template(), cg: ti.template(), k, s):
    """In float32 only: ``(|A| |x|)_k`` into row _X of the fine level (free while
    the true residual is checked: the next V-cycle starts from zero), the scale
    of the round-off in ``A x`` (_after_check)."""
    if ti.static(REAL.dtype == ti.f32):
        mg[_X, k] = (_diagonal(op, k, s) * ti.abs(cg[_SOL, k])
                     + op[k - s][_TX] * ti.abs(cg[_SOL, k - s]) + op[k][_TX] * ti.abs(cg[_SOL, k + s])
                     + op[k - 1][_TY] * ti.abs(cg[_SOL, k - 1]) + op[k][_TY] * ti.abs(cg[_SOL, k + 1]))


@ti.func
def _matvec(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
            flags: ti.template(), r, k, s):
    cg[_ADIR, k] = _apply(op, cg, _DIR, k, s)


# The same two with the moving bodies' term (_gmg_bodies), applied beforehand
# to the same vector and held in row _PW.
@ti.func
def _residual_b(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
                flags: ti.template(), r, k, s):
    mg[_B, k] = cg[_RHS, k] - _apply(op, cg, _SOL, k, s) - cg[_PW, k]
    _operator_scale(op, mg, cg, k, s)


@ti.func
def _matvec_b(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
              flags: ti.template(), r, k, s):
    cg[_ADIR, k] = _apply(op, cg, _DIR, k, s) + cg[_PW, k]


@ti.func
def _bodies_apply(cg: ti.template(), src, flags: ti.template(), geo: ti.template(),
                  terms: ti.template(), consts: ti.template()):
    """``cg[_PW] = S (H M) S^T cg[src]`` of every running realization (top-level
    loops: they complete before the next one starts)."""
    _product(cg, src, _PW, flags, _RUNNING, terms, geo, consts)


@ti.func
def _update(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
            flags: ti.template(), r, k, s):
    alpha = state[r, _ALPHA]
    cg[_SOL, k] = cg[_SOL, k] + alpha * cg[_DIR, k]
    mg[_B, k] = mg[_B, k] - alpha * cg[_ADIR, k]


@ti.func
def _direction(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
               flags: ti.template(), r, k, s):
    cg[_DIR, k] = mg[_X, k] + state[r, _BETA] * cg[_DIR, k]


@ti.func
def _for_cells(body: ti.template(), op: ti.template(), mg: ti.template(), cg: ti.template(),
               state: ti.template(), flags: ti.template(), geo: ti.template(),
               cells: ti.template(), gate: ti.template()):
    """``body`` at every fine cell of every realization whose flag ``gate`` is set
    (``_RUNNING``: every running one), in parallel."""
    R, nx, ny = flags.shape[0], geo[0, _NX], geo[0, _NY]
    if ti.static(cells):
        span = _lanes(nx * ny)
        for t in range(R * span):
            r, c = t // span, t % span
            if c < nx * ny and flags[r, gate]:
                body(op, mg, cg, state, flags, r, _index(geo, 0, r, c // ny, c % ny), ny + 1)
    else:
        segments = _segments(ny)
        for t in range(R * nx * segments):
            r, i, j0, j1 = _segment(t, nx, ny, segments)
            if flags[r, gate]:
                first = _index(geo, 0, r, i, 0)
                for j in range(j0, j1):
                    body(op, mg, cg, state, flags, r, first + j, ny + 1)


@ti.func
def _for_cells_and_sum(body: ti.template(), op: ti.template(), mg: ti.template(),
                       cg: ti.template(), state: ti.template(), flags: ti.template(),
                       geo: ti.template(), cells: ti.template(), a: ti.template(), ra,
                       b: ti.template(), rb, part: ti.template(), gate: ti.template()):
    """_for_cells, then _segment_sums of ``a[ra] b[rb]`` into ``part[0]``: by
    segments in one pass, each summed by the thread that has just updated it
    (from its cache) in the order of _segment_sum."""
    if ti.static(cells):
        _for_cells(body, op, mg, cg, state, flags, geo, cells, gate)
        _segment_sums(a, ra, b, rb, part, 0, geo, flags, gate)
    else:
        R, nx, ny = flags.shape[0], geo[0, _NX], geo[0, _NY]
        segments = _segments(ny)
        for t in range(R * nx * segments):
            r, i, j0, j1 = _segment(t, nx, ny, segments)
            if flags[r, gate]:
                first = _index(geo, 0, r, i, 0)
                for j in range(j0, j1):
                    body(op, mg, cg, state, flags, r, first + j, ny + 1)
                part[0, t] = _segment_sum(a, ra, b, rb, geo, r, i, j0, j1)


@ti.func
def _for_cells_of(body: ti.template(), op: ti.template(), mg: ti.template(),
                  cg: ti.template(), state: ti.template(), flags: ti.template(),
                  geo: ti.template(), r):
    """``body`` at every fine cell of realization r, serially."""
    nx, ny = geo[0, _NX], geo[0, _NY]
    for i in range(nx):
        first = _index(geo, 0, r, i, 0)
        for j in range(ny):
            body(op, mg, cg, state, flags, r, first + j, ny + 1)


@ti.func
def _for_cells_and_sum_of(body: ti.template(), op: ti.template(), mg: ti.template(),
                          cg: ti.template(), state: ti.template(), flags: ti.template(),
                          geo: ti.template(), r, a: ti.template(), ra, b: ti.template(), rb,
                          part: ti.template()):
    """_for_cells_of, then _segment_sums_of of ``a[ra] b[rb]`` into ``part[0]``, in
    one pass: each segment summed right after its cells are done, in the order of
    _segment_sum (the same bits as the two passes; ``body`` changes only its own
    cell's entries)."""
    nx, ny = geo[0, _NX], geo[0, _NY]
    segments = _segments(ny)
    for q in range(nx * segments):
        t = r * nx * segments + q
        _, i, j0, j1 = _segment(t, nx, ny, segments)
        first = _index(geo, 0, r, i, 0)
        for j in range(j0, j1):
            body(op, mg, cg, state, flags, r, first + j, ny + 1)
        part[0, t] = _segment_sum(a, ra, b, rb, geo, r, i, j0, j1)


@ti.func
def _segment_sum(a: ti.template(), ra, b: ti.template(), rb, geo: ti.template(), r, i,
                 j0, j1):
    """``sum a[ra] b[rb]`` over cells j0..j1-1 of grid column i of realization r,
    serially: the first stage of every dot product (the second is _total), on
    fixed segments, so that the result depends on neither the thread count nor
    the other realizations."""
    s = ti.cast(0.0, REAL.dtype)
    first = _index(geo, 0, r, i, 0)
    for j in range(j0, j1):
        s += a[ra, first + j] * b[rb, first + j]
    return s


@ti.func
def _segment_sums(a: ti.template(), ra, b: ti.template(), rb, part: ti.template(), slot,
                  geo: ti.template(), flags: ti.template(), gate: ti.template()):
    """``part[slot, t]``: the segment sums of every realization with flag ``gate``,
    t numbering the segments realization, column and segment first."""
    R, nx, ny = flags.shape[0], geo[0, _NX], geo[0, _NY]
    segments = _segments(ny)
    for t in range(R * nx * segments):
        r, i, j0, j1 = _segment(t, nx, ny, segments)
        if flags[r, gate]:
            part[slot, t] = _segment_sum(a, ra, b, rb, geo, r, i, j0, j1)


@ti.func
def _segment_sums_of(a: ti.template(), ra, b: ti.template(), rb, part: ti.template(),
                     slot, geo: ti.template(), r):
    """The same for realization r, serially."""
    nx, ny = geo[0, _NX], geo[0, _NY]
    segments = _segments(ny)
    for q in range(nx * segments):
        t = r * nx * segments + q
        _, i, j0, j1 = _segment(t, nx, ny, segments)
        part[slot, t] = _segment_sum(a, ra, b, rb, geo, r, i, j0, j1)


@ti.func
def _total(part: ti.template(), slot, r, n):
    """The second stage: the n segment sums of realization r, serially."""
    s = ti.cast(0.0, REAL.dtype)
    for q in range(n):
        s += part[slot, r * n + q]
    return s


# Per-realization scalar steps.
@ti.func
def _set_norm_b(part: ti.template(), state: ti.template(), flags: ti.template(), r, n):
    state[r, _BB] = _total(part, 1, r, n)
    flags[r, _UNDRIVEN] = 1 if state[r, _BB] == 0 else 0


@ti.func
def _after_check(part: ti.template(), state: ti.template(), flags: ti.template(), r, n,
                 tol2, maxiter):
    """Relative true residual; iterate on while it exceeds tol (and MAXITER allows).
    In float32 also stop once the residual is round-off, below F32_OPERATOR_FLOOR
    of ``|A| |x|`` (part[1], _operator_scale): a flow-rate inlet's |b| is about
    nx times smaller than the terms of ``A x`` (measured floor 6e-4 relative to
    |b| on a 175 x 61 grid, 5e-3 on 700 x 244, against 1e-6 with a pressure inlet)."""
    state[r, _RR] = _total(part, 0, r, n)
    res2 = ti.cast(0.0, REAL.dtype)
    if state[r, _BB] > 0:
        res2 = state[r, _RR] / state[r, _BB]
    state[r, _RES] = ti.sqrt(res2)
    go = res2 > tol2
    if ti.static(REAL.dtype == ti.f32):
        go = go and state[r, _RR] > F32_OPERATOR_FLOOR**2 * _total(part, 1, r, n)
    flags[r, _RUNNING] = 1 if go and flags[r, _ITERS] < maxiter else 0
    flags[r, _CHECK] = 0
    flags[r, _FIRST] = 1


@ti.func
def _set_beta(part: ti.template(), state: ti.template(), r, n, first):
    rz = _total(part, 0, r, n)
    state[r, _BETA] = 0.0
    if not first:
        state[r, _BETA] = rz / state[r, _RZ]
    state[r, _RZ] = rz


@ti.func
def _set_alpha(part: ti.template(), state: ti.template(), r, n):
    curvature = _total(part, 0, r, n)
    state[r, _ALPHA] = 0.0
    if curvature > 0:  # else a breakdown: stop (_after_step), the check reports
        state[r, _ALPHA] = state[r, _RZ] / curvature


@ti.func
def _after_step(part: ti.template(), state: ti.template(), flags: ti.template(), r, n,
                tol2, maxiter):
    state[r, _RR] = _total(part, 0, r, n)
    flags[r, _ITERS] += 1
    go = (state[r, _RR] > tol2 * state[r, _BB] and flags[r, _ITERS] < maxiter
          and state[r, _ALPHA] != 0)
    flags[r, _RUNNING] = 1 if go else 0
    if not go:  # the true residual decides (_check_stopped)
        flags[r, _CHECK] = 1


# ---------------------------------------------------------------- CG kernels
# One CG iteration of every running realization is _cg_direction (after the
# V-cycle), _cg_step and _check_stopped; the host reads nothing between them, so
# on a GPU it may launch several iterations before it reads how many realizations
# are still at work (gmg._iterate): a realization that has stopped is skipped by
# every kernel, and each one's own sequence of operations is the same however
# many launches come between its steps, so the bits are too.
@ti.kernel
def _residual_check(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows,
                    flags: _Ints, geo: _Ints, consts: _Consts, maxiter: ti.i32,
                    cells: ti.template(), bodies: ti.template(), terms: Terms):
    """At the start of a solve: counters reset, |b| computed, the guess cleared
    where _clear says, and the true residual ``r = b - A x`` of every realization
    with whether it must iterate. ``bodies``: whether the moving bodies' ``terms``
    (:mod:`._gmg_bodies`) apply."""
    R, n = flags.shape[0], geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    for r in range(R):
        flags[r, _RUNNING] = 1 - flags[r, _SKIP]
        flags[r, _ITERS] = 0
    _segment_sums(cg, _RHS, cg, _RHS, part, 1, geo, flags, _RUNNING)
    for r in range(R):
        if flags[r, _RUNNING]:
            _set_norm_b(part, state, flags, r, n)
    _for_cells(_clear, op, mg, cg, state, flags, geo, cells, _RUNNING)
    _true_residual(op, mg, cg, part, state, flags, geo, consts, maxiter, cells, bodies, terms,
                   _RUNNING)


@ti.kernel
def _check_stopped(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows,
                   flags: _Ints, geo: _Ints, consts: _Consts, maxiter: ti.i32,
                   cells: ti.template(), bodies: ti.template(), terms: Terms):
    """The realizations that stopped at the last step (flag _CHECK): their true
    residual decides; one that misses the tolerance (rounding made it drift from
    the recursively updated one) starts CG again from there."""
    _true_residual(op, mg, cg, part, state, flags, geo, consts, maxiter, cells, bodies, terms,
                   _CHECK)


@ti.func
def _true_residual(op: ti.template(), mg: ti.template(), cg: ti.template(),
                   part: ti.template(), state: ti.template(), flags: ti.template(),
                   geo: ti.template(), consts: ti.template(), maxiter, cells: ti.template(),
                   bodies: ti.template(), terms: ti.template(), gate: ti.template()):
    """``r = b - A x`` and _after_check of the realizations with flag ``gate``."""
    R, n = flags.shape[0], geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    if ti.static(bodies):
        _product(cg, _SOL, _PW, flags, gate, terms, geo, consts)
        _for_cells_and_sum(_residual_b, op, mg, cg, state, flags, geo, cells, mg, _B, mg, _B,
                           part, gate)
    else:
        _for_cells_and_sum(_residual, op, mg, cg, state, flags, geo, cells, mg, _B, mg, _B,
                           part, gate)
    if ti.static(REAL.dtype == ti.f32):
        _segment_sums(mg, _X, mg, _X, part, 1, geo, flags, gate)
    for r in range(R):
        if flags[r, gate]:
            _after_check(part, state, flags, r, n, consts[_K_TOL2], maxiter)


@ti.kernel
def _cg_direction(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows,
                  flags: _Ints, geo: _Ints, cells: ti.template()):
    """``d = z + beta d`` with ``beta = r.z / (r.z)_previous`` (0 on a (re)start:
    flag _FIRST)."""
    R, n = flags.shape[0], geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    _segment_sums(mg, _B, mg, _X, part, 0, geo, flags, _RUNNING)
    for r in range(R):
        if flags[r, _RUNNING]:
            _set_beta(part, state, r, n, flags[r, _FIRST])
            flags[r, _FIRST] = 0
    _for_cells(_direction, op, mg, cg, state, flags, geo, cells, _RUNNING)


@ti.kernel
def _cg_step(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows, flags: _Ints,
             geo: _Ints, consts: _Consts, maxiter: ti.i32, cells: ti.template(),
             bodies: ti.template(), terms: Terms):
    """``x += alpha d``, ``r -= alpha A d`` with ``alpha = r.z / d.Ad``; a realization
    whose residual meets the tolerance stops, its true residual to be checked."""
    R, n = flags.shape[0], geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    if ti.static(bodies):
        _bodies_apply(cg, _DIR, flags, geo, terms, consts)
        _for_cells_and_sum(_matvec_b, op, mg, cg, state, flags, geo, cells, cg, _DIR, cg,
                           _ADIR, part, _RUNNING)
    else:
        _for_cells_and_sum(_matvec, op, mg, cg, state, flags, geo, cells, cg, _DIR, cg,
                           _ADIR, part, _RUNNING)
    for r in range(R):
        if flags[r, _RUNNING]:
            _set_alpha(part, state, r, n)
    _for_cells_and_sum(_update, op, mg, cg, state, flags, geo, cells, mg, _B, mg, _B, part,
                       _RUNNING)
    for r in range(R):
        if flags[r, _RUNNING]:
            _after_step(part, state, flags, r, n, consts[_K_TOL2], maxiter)


@ti.kernel
def _solve_each(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows, flags: _Ints,
                geo: _Ints, chol: _Chol, consts: _Consts, maxiter: ti.i32,
                bodies: ti.template(), terms: Terms):
    """The whole CG solve, one thread per realization: the steps of
    _residual_check, _cg_direction and _cg_step with _cycle_of, in one launch
    (a realization with flag _SKIP left as it is: _mark)."""
    for t in range(flags.shape[0] * _TASK):  # one realization per thread (see _TASK)
        if t % _TASK == 0 and flags[t // _TASK, _SKIP] == 0:
            _solve_one(op, mg, cg, part, state, flags, geo, chol, t // _TASK, consts, maxiter,
                       bodies, terms)


@ti.func
def _solve_one(op: ti.template(), mg: ti.template(), cg: ti.template(), part: ti.template(),
               state: ti.template(), flags: ti.template(), geo: ti.template(),
               chol: ti.template(), r, consts: ti.template(), maxiter, bodies: ti.template(),
               terms: ti.template()):
    """The CG solve of realization r, serially (see _solve_each)."""
    tol2 = consts[_K_TOL2]
    n = geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    flags[r, _ITERS] = 0
    flags[r, _RUNNING] = 1
    _segment_sums_of(cg, _RHS, cg, _RHS, part, 1, geo, r)
    _set_norm_b(part, state, flags, r, n)
    _for_cells_of(_clear, op, mg, cg, state, flags, geo, r)
    checked = 0
    while not checked:
        if ti.static(bodies):
            _product_of(cg, _SOL, _PW, terms, geo, consts, r)
            _for_cells_and_sum_of(_residual_b, op, mg, cg, state, flags, geo, r, mg, _B, mg,
                                  _B, part)
        else:
            _for_cells_and_sum_of(_residual, op, mg, cg, state, flags, geo, r, mg, _B, mg, _B,
                                  part)
        if ti.static(REAL.dtype == ti.f32):
            _segment_sums_of(mg, _X, mg, _X, part, 1, geo, r)
        _after_check(part, state, flags, r, n, tol2, maxiter)
        checked = 1 - flags[r, _RUNNING]
        first = 1
        while flags[r, _RUNNING]:
            _cycle_of(op, mg, chol, geo, r, 0, OVERCORRECTION)
            _segment_sums_of(mg, _B, mg, _X, part, 0, geo, r)
            _set_beta(part, state, r, n, first)
            _for_cells_of(_direction, op, mg, cg, state, flags, geo, r)
            first = 0
            flags[r, _FIRST] = 0
            if ti.static(bodies):
                _product_of(cg, _DIR, _PW, terms, geo, consts, r)
                _for_cells_and_sum_of(_matvec_b, op, mg, cg, state, flags, geo, r, cg, _DIR,
                                      cg, _ADIR, part)
            else:
                _for_cells_and_sum_of(_matvec, op, mg, cg, state, flags, geo, r, cg, _DIR, cg,
                                      _ADIR, part)
            _set_alpha(part, state, r, n)
            _for_cells_and_sum_of(_update, op, mg, cg, state, flags, geo, r, mg, _B, mg, _B,
                                  part)
            _after_step(part, state, flags, r, n, tol2, maxiter)


# ---------------------------------------------------------------- output kernels
@ti.kernel
def _pressure(cg: _Rows, unknown: _Cells, out: _Field, geo: _Ints, consts: _Consts,
              flags: _Ints):
    """The pressure, NaN in cells without one; a realization left out of the
    solve (flag _SKIP) keeps the one it has, from the same solution."""
    R, nx, ny = unknown.shape[0], geo[0, _NX], geo[0, _NY]
    nan = ti.cast(ti.math.nan, REAL.dtype)
    for t in range(R * nx):
        r, i = t // nx, t % nx
        if flags[r, _SKIP] == 0:
            for j in range(ny):
                p = nan
                if unknown[r, i, j] != 0:
                    p = cg[_SOL, _index(geo, 0, r, i, j)] + consts[_K_PREF]
                out[r, i, j] = p


@ti.kernel
def _boundary_fluxes(kappa: _Grid, cg: _Rows, unknown: _Cells, sides: _Sides,
                     state: _Rows, fluxes: _Rows, geo: _Ints, consts: _Consts):
    """Sums of the inward and of the outward boundary-face fluxes, per realization,
    serially (``fluxes[r] = (in, out)``)."""
    R, nx, ny = unknown.shape[0], geo[0, _NX], geo[0, _NY]
    for r in range(R):
        into, out = ti.cast(0.0, REAL.dtype), ti.cast(0.0, REAL.dtype)
        for s in ti.static(range(4)):
            for m in range((ny, ny, nx, nx)[s]):
                i = (0, nx - 1, m, m)[s]
                j = (m, m, 0, ny - 1)[s]
                g = sides[s, m][0]
                if g > 0 and unknown[r, i, j] != 0:
                    x = cg[_SOL, _index(geo, 0, r, i, j)]
                    q = g * ti.cast(kappa[r, i, j], REAL.dtype) * (sides[s, m][1] - x)
                    into += ti.max(q, 0.0)
                    out += ti.max(-q, 0.0)
        delivered = ti.cast(0.0, REAL.dtype)  # nothing enters where every inlet cell is cut off
        if state[r, _INLET] > 0:
            delivered = consts[_K_INFLOW]
        fluxes[r, 0] = into + ti.max(delivered, 0.0)
        fluxes[r, 1] = out + ti.max(-delivered, 0.0)


@ti.kernel
def _report(state: _Rows, flags: _Ints, fluxes: _Rows, report: _Rows):
    """What the host reads after a solve (or a block of CG iterations), in one
    transfer: per realization the floats of ``state``, the integers of ``flags``
    (exact in either float type below 2^24; the scan's counts matter only as
    nonzero), the boundary fluxes, and whether it is still at work (running or to
    be checked)."""
    for r in range(flags.shape[0]):
        for c in ti.static(range(7)):
            report[r, c] = state[r, c]
        for c in ti.static(range(N_FLAGS)):
            report[r, 7 + c] = ti.cast(flags[r, c], REAL.dtype)
        report[r, 7 + N_FLAGS] = fluxes[r, 0]
        report[r, 8 + N_FLAGS] = fluxes[r, 1]
        report[r, 9 + N_FLAGS] = ti.cast(flags[r, _RUNNING] + flags[r, _CHECK], REAL.dtype)


REPORT_COLUMNS = 10 + N_FLAGS
_REPORT_FLAGS, _REPORT_FLUXES, _REPORT_ACTIVE = 7, 7 + N_FLAGS, 9 + N_FLAGS


@ti.kernel
def _copy_row(cg: _Rows, src: ti.i32, dst: ti.i32):
    """``cg[dst] = cg[src]`` (the initial guess kept and put back, gmg.solve)."""
    for k in range(cg.shape[1]):
        cg[dst, k] = cg[src, k]


@ti.kernel
def _mark(flags: _Ints, only: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """Flag _SKIP of every realization with ``only[r] == 0``, which no kernel of
    the next solve touches (not running, no iterations, nothing to check)."""
    for r in range(flags.shape[0]):
        skip = 1 if only[r] == 0 else 0
        flags[r, _SKIP] = skip
        if skip:
            flags[r, _RUNNING] = 0
            flags[r, _ITERS] = 0
            flags[r, _CHECK] = 0
