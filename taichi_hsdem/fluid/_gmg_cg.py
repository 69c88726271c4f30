"""Conjugate-gradient pieces of the Taichi pressure solver (:mod:`.gmg`): the
per-cell CG steps, the deterministic segment sums behind every dot product, one
CG iteration per kernel launch or a whole solve per realization, and the
pressure and boundary fluxes read back. Package-internal: :mod:`.gmg` is the API."""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
from ..backend import ti
from ._gmg_cycle import (_ADIR, _ALPHA, _B, _BB, _BETA, _Cells, _Chol, _DIR, _Field, _Grid,
                         _INLET, _ITERS, _Ints, _NX, _NY, _Ops, _PW, _RES, _RHS, _RR,
                         _RUNNING, _RZ, _Rows, _SOL, _Sides, _TASK, _UNDRIVEN, _X, _apply,
                         _cycle_of, _diagonal, _index, _lanes, _segment, _segments)
from ._gmg_bodies import Terms, _product, _product_of

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


@ti.func
def _matvec_b(op: ti.template(), mg: ti.template(), cg: ti.template(), state: ti.template(),
              flags: ti.template(), r, k, s):
    cg[_ADIR, k] = _apply(op, cg, _DIR, k, s) + cg[_PW, k]


@ti.func
def _bodies_apply(cg: ti.template(), src, flags: ti.template(), geo: ti.template(),
                  terms: ti.template(), dx, dy):
    """``cg[_PW] = S (H M) S^T cg[src]`` of every running realization (top-level
    loops: they complete before the next one starts)."""
    _product(cg, src, _PW, flags, _RUNNING, terms, geo, dx, dy)


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
               cells: ti.template()):
    """``body`` at every fine cell of every running realization, in parallel."""
    R, nx, ny = flags.shape[0], geo[0, _NX], geo[0, _NY]
    if ti.static(cells):
        span = _lanes(nx * ny)
        for t in range(R * span):
            r, c = t // span, t % span
            if c < nx * ny and flags[r, _RUNNING]:
                body(op, mg, cg, state, flags, r, _index(geo, 0, r, c // ny, c % ny), ny + 1)
    else:
        segments = _segments(ny)
        for t in range(R * nx * segments):
            r, i, j0, j1 = _segment(t, nx, ny, segments)
            if flags[r, _RUNNING]:
                first = _index(geo, 0, r, i, 0)
                for j in range(j0, j1):
                    body(op, mg, cg, state, flags, r, first + j, ny + 1)


@ti.func
def _for_cells_and_sum(body: ti.template(), op: ti.template(), mg: ti.template(),
                       cg: ti.template(), state: ti.template(), flags: ti.template(),
                       geo: ti.template(), cells: ti.template(), a: ti.template(), ra,
                       b: ti.template(), rb, part: ti.template()):
    """_for_cells, then _segment_sums of ``a[ra] b[rb]`` into ``part[0]``: by
    segments in one pass, each summed by the thread that has just updated it
    (from its cache) in the order of _segment_sum."""
    if ti.static(cells):
        _for_cells(body, op, mg, cg, state, flags, geo, cells)
        _segment_sums(a, ra, b, rb, part, 0, geo, flags)
    else:
        R, nx, ny = flags.shape[0], geo[0, _NX], geo[0, _NY]
        segments = _segments(ny)
        for t in range(R * nx * segments):
            r, i, j0, j1 = _segment(t, nx, ny, segments)
            if flags[r, _RUNNING]:
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
def _segment_sum(a: ti.template(), ra, b: ti.template(), rb, geo: ti.template(), r, i,
                 j0, j1):
    """``sum a[ra] b[rb]`` over cells j0..j1-1 of grid column i of realization r,
    serially: the first stage of every dot product (the second is _total), on
    fixed segments, so that the result depends on neither the thread count nor
    the other realizations."""
    s = ti.f64(0.0)
    first = _index(geo, 0, r, i, 0)
    for j in range(j0, j1):
        s += a[ra, first + j] * b[rb, first + j]
    return s


@ti.func
def _segment_sums(a: ti.template(), ra, b: ti.template(), rb, part: ti.template(), slot,
                  geo: ti.template(), flags: ti.template()):
    """``part[slot, t]``: the segment sums of every running realization, t
    numbering the segments realization, column and segment first."""
    R, nx, ny = flags.shape[0], geo[0, _NX], geo[0, _NY]
    segments = _segments(ny)
    for t in range(R * nx * segments):
        r, i, j0, j1 = _segment(t, nx, ny, segments)
        if flags[r, _RUNNING]:
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
    s = ti.f64(0.0)
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
    """Relative true residual; iterate on while it exceeds tol (and MAXITER allows)."""
    state[r, _RR] = _total(part, 0, r, n)
    res2 = ti.f64(0.0)
    if state[r, _BB] > 0:
        res2 = state[r, _RR] / state[r, _BB]
    state[r, _RES] = ti.sqrt(res2)
    flags[r, _RUNNING] = 1 if res2 > tol2 and flags[r, _ITERS] < maxiter else 0


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


# ---------------------------------------------------------------- CG kernels
@ti.kernel
def _residual_check(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows,
                    flags: _Ints, geo: _Ints, tol2: ti.f64, maxiter: ti.i32,
                    initial: ti.template(), cells: ti.template(), bodies: ti.template(),
                    terms: Terms, dx: ti.f64, dy: ti.f64) -> ti.i32:
    """True residual ``r = b - A x`` of every realization and whether it must
    (go on) iterate; returns how many must. ``initial``: at the start of a solve
    (counters reset, |b| computed, the guess cleared where _clear says).
    ``bodies``: whether the moving bodies' ``terms`` (:mod:`._gmg_bodies`) apply."""
    R, n = flags.shape[0], geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    for r in range(R):
        flags[r, _RUNNING] = 1
        if ti.static(initial):
            flags[r, _ITERS] = 0
    if ti.static(initial):
        _segment_sums(cg, _RHS, cg, _RHS, part, 1, geo, flags)
        for r in range(R):
            _set_norm_b(part, state, flags, r, n)
        _for_cells(_clear, op, mg, cg, state, flags, geo, cells)
    if ti.static(bodies):
        _bodies_apply(cg, _SOL, flags, geo, terms, dx, dy)
        _for_cells_and_sum(_residual_b, op, mg, cg, state, flags, geo, cells, mg, _B, mg, _B,
                           part)
    else:
        _for_cells_and_sum(_residual, op, mg, cg, state, flags, geo, cells, mg, _B, mg, _B,
                           part)
    count = 0
    for r in range(R):
        _after_check(part, state, flags, r, n, tol2, maxiter)
        count += flags[r, _RUNNING]
    return count


@ti.kernel
def _cg_direction(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows,
                  flags: _Ints, geo: _Ints, first: ti.i32, cells: ti.template()):
    """``d = z + beta d`` with ``beta = r.z / (r.z)_previous`` (0 on a (re)start)."""
    R, n = flags.shape[0], geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    _segment_sums(mg, _B, mg, _X, part, 0, geo, flags)
    for r in range(R):
        if flags[r, _RUNNING]:
            _set_beta(part, state, r, n, first)
    _for_cells(_direction, op, mg, cg, state, flags, geo, cells)


@ti.kernel
def _cg_step(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows, flags: _Ints,
             geo: _Ints, tol2: ti.f64, maxiter: ti.i32, cells: ti.template(),
             bodies: ti.template(), terms: Terms, dx: ti.f64, dy: ti.f64) -> ti.i32:
    """``x += alpha d``, ``r -= alpha A d`` with ``alpha = r.z / d.Ad``; stop the
    realizations whose residual meets the tolerance; returns how many go on."""
    R, n = flags.shape[0], geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    if ti.static(bodies):
        _bodies_apply(cg, _DIR, flags, geo, terms, dx, dy)
        _for_cells_and_sum(_matvec_b, op, mg, cg, state, flags, geo, cells, cg, _DIR, cg,
                           _ADIR, part)
    else:
        _for_cells_and_sum(_matvec, op, mg, cg, state, flags, geo, cells, cg, _DIR, cg,
                           _ADIR, part)
    for r in range(R):
        if flags[r, _RUNNING]:
            _set_alpha(part, state, r, n)
    _for_cells_and_sum(_update, op, mg, cg, state, flags, geo, cells, mg, _B, mg, _B, part)
    count = 0
    for r in range(R):
        if flags[r, _RUNNING]:
            _after_step(part, state, flags, r, n, tol2, maxiter)
            count += flags[r, _RUNNING]
    return count


@ti.kernel
def _solve_each(op: _Ops, mg: _Rows, cg: _Rows, part: _Rows, state: _Rows, flags: _Ints,
                geo: _Ints, chol: _Chol, tol2: ti.f64, maxiter: ti.i32, alpha: ti.f64,
                bodies: ti.template(), terms: Terms, dx: ti.f64, dy: ti.f64):
    """The whole CG solve, one thread per realization: the steps of
    _residual_check, _cg_direction and _cg_step with _cycle_of, in one launch."""
    for t in range(flags.shape[0] * _TASK):  # one realization per thread (see _TASK)
        if t % _TASK == 0:
            _solve_one(op, mg, cg, part, state, flags, geo, chol, t // _TASK, tol2, maxiter,
                       alpha, bodies, terms, dx, dy)


@ti.func
def _solve_one(op: ti.template(), mg: ti.template(), cg: ti.template(), part: ti.template(),
               state: ti.template(), flags: ti.template(), geo: ti.template(),
               chol: ti.template(), r, tol2, maxiter, alpha, bodies: ti.template(),
               terms: ti.template(), dx, dy):
    """The CG solve of realization r, serially (see _solve_each)."""
    n = geo[0, _NX] * _segments(geo[0, _NY])  # segment sums each
    flags[r, _ITERS] = 0
    _segment_sums_of(cg, _RHS, cg, _RHS, part, 1, geo, r)
    _set_norm_b(part, state, flags, r, n)
    _for_cells_of(_clear, op, mg, cg, state, flags, geo, r)
    checked = 0
    while not checked:
        if ti.static(bodies):
            _product_of(cg, _SOL, _PW, terms, geo, dx, dy, r)
            _for_cells_of(_residual_b, op, mg, cg, state, flags, geo, r)
        else:
            _for_cells_of(_residual, op, mg, cg, state, flags, geo, r)
        _segment_sums_of(mg, _B, mg, _B, part, 0, geo, r)
        _after_check(part, state, flags, r, n, tol2, maxiter)
        checked = 1 - flags[r, _RUNNING]
        first = 1
        while flags[r, _RUNNING]:
            _cycle_of(op, mg, chol, geo, r, 0, alpha)
            _segment_sums_of(mg, _B, mg, _X, part, 0, geo, r)
            _set_beta(part, state, r, n, first)
            _for_cells_of(_direction, op, mg, cg, state, flags, geo, r)
            first = 0
            if ti.static(bodies):
                _product_of(cg, _DIR, _PW, terms, geo, dx, dy, r)
                _for_cells_of(_matvec_b, op, mg, cg, state, flags, geo, r)
            else:
                _for_cells_of(_matvec, op, mg, cg, state, flags, geo, r)
            _segment_sums_of(cg, _DIR, cg, _ADIR, part, 0, geo, r)
            _set_alpha(part, state, r, n)
            _for_cells_of(_update, op, mg, cg, state, flags, geo, r)
            _segment_sums_of(mg, _B, mg, _B, part, 0, geo, r)
            _after_step(part, state, flags, r, n, tol2, maxiter)


# ---------------------------------------------------------------- output kernels
@ti.kernel
def _pressure(cg: _Rows, unknown: _Cells, out: _Field, geo: _Ints, p_ref: ti.f64):
    """The pressure, NaN in cells without one."""
    R, nx, ny = unknown.shape[0], geo[0, _NX], geo[0, _NY]
    nan = ti.cast(ti.math.nan, ti.f64)
    for t in range(R * nx):
        r, i = t // nx, t % nx
        for j in range(ny):
            p = nan
            if unknown[r, i, j] != 0:
                p = cg[_SOL, _index(geo, 0, r, i, j)] + p_ref
            out[r, i, j] = p


@ti.kernel
def _boundary_fluxes(kappa: _Grid, cg: _Rows, unknown: _Cells, sides: _Sides,
                     state: _Rows, fluxes: _Rows, geo: _Ints, inflow: ti.f64):
    """Sums of the inward and of the outward boundary-face fluxes, per realization,
    serially (``fluxes[r] = (in, out)``)."""
    R, nx, ny = unknown.shape[0], geo[0, _NX], geo[0, _NY]
    for r in range(R):
        into, out = ti.f64(0.0), ti.f64(0.0)
        for s in ti.static(range(4)):
            for m in range((ny, ny, nx, nx)[s]):
                i = (0, nx - 1, m, m)[s]
                j = (m, m, 0, ny - 1)[s]
                g = sides[s, m][0]
                if g > 0 and unknown[r, i, j] != 0:
                    x = cg[_SOL, _index(geo, 0, r, i, j)]
                    q = g * ti.cast(kappa[r, i, j], ti.f64) * (sides[s, m][1] - x)
                    into += ti.max(q, 0.0)
                    out += ti.max(-q, 0.0)
        delivered = ti.f64(0.0)  # nothing enters where every inlet cell is cut off
        if state[r, _INLET] > 0:
            delivered = inflow
        fluxes[r, 0] = into + ti.max(delivered, 0.0)
        fluxes[r, 1] = out + ti.max(-delivered, 0.0)
