"""Realizations side by side in the Taichi pressure solver (:mod:`.gmg`): the whole
CG solve of LANES realizations in one thread, each cell's values of the group one
``vector(LANES)``, so that the compiler turns the group's arithmetic into vector
instructions (docs/performance.md, "Realizations side by side").

The vectors live in Taichi fields, not in the ndarrays of the rest of the
solver: from ndarrays the same code stays scalar (``tools/bench_lanes.py``). A
solve copies each group's operators (every level), Cholesky factors, right-hand
side, guess and last search direction from the ndarrays into the fields, solves,
and copies the solution and search direction back; the fields keep nothing
between solves, so every solver of a process shares them (:class:`LanePool`,
grown to the largest; a kernel is compiled per pool, not per solver).

Each lane runs the operations of the one-thread-per-realization solve
(:func:`._gmg_cg._solve_one`) in the same order, so its bits are that solve's, alone
or in any batch: the V-cycle's helpers are those of :mod:`._gmg_cycle`, which
take either storage; CG's scalars are vectors of the lanes' values, and where a
lane's solve does something another's does not (stop, check its true residual,
start again) the others' values are kept by a select, their arithmetic done and
dropped. The moving bodies' term runs lane by lane on the ndarrays, as
:func:`._gmg_bodies._product_of` does it: its cells differ between realizations.
Float64 only; float32 solves keep the scalar way. Package-internal."""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
import numpy as np

from .. import limits
from ..backend import ti
from ._gmg_bodies import Terms, _spread_box, gathers_of, ring
from ._gmg_cycle import (COARSEST_CELLS, LANES, OVERCORRECTION, REAL, _ADIR, _ALPHA, _B,
                         _BB, _BETA, _CHECK, _Chol, _Consts, _DIR, _FIRST, _ITERS, _Ints,
                         _K_DX, _K_DY, _K_TOL2, _NX, _NY, _Ops, _PW, _RES, _RHS, _RR,
                         _RUNNING, _RZ, _Rows, _SOL, _TASK, _TX, _TY, _UNDRIVEN, _X, LaneOps,
                         _apply, _cycle_of, _diagonal, _index, _segment, _segments)
from ._gmg_setup import _upload

#: Rows of the lanes' CG field: the ndarray's solution, direction, A times it and
#: right-hand side, then the bodies' term in row _LPW (the ndarray's _BASE, which
#: the solve does not read, is left out).
_LPW = 4
_CG_ROWS = 5
#: Column of the lanes' level table holding the solve's group count (after _OFF,
#: _NX, _NY): the groups the kernel's threads take, the first G of ``slots``.
_GROUPS = 3


def group_count(n_batch):
    """How many groups ``n_batch`` realizations are solved in: as many as it takes,
    rounded up to a multiple of the threads (at most one realization a group),
    so that each thread has as many lanes' bodies' terms to apply (lane by lane):
    16 realizations on 2 threads are 4 groups of 4, 20 are 6 of 4 or 3 (lane q of
    group g holds the (q G + g)-th realization solved, :meth:`Lanes.solve`)."""
    threads = limits.thread_share() or limits.usable_cpus()
    return int(min(n_batch, -(-(-(-n_batch // LANES)) // threads) * threads))


def lanes_pay(n_batch, lanes="auto"):
    """Whether ``n_batch`` realizations are solved side by side: always (``lanes``
    True), never (False), or ("auto") where they fill at least 0.8 of their
    groups' lanes. On 2 threads (the vani scene, moving bodies; ``python
    tools/bench.py --cases disks-0.26-RN --lanes on|off``, docs/performance.md):
    in full groups (8, 16, 100) a solve takes 0.7-0.9 of the time of one
    realization per thread; 4 (two groups of 2) and 10 (groups of 3, 3, 2, 2)
    1.1-1.2 times as long: the bodies' term, lane by lane, does not shrink."""
    if lanes != "auto":
        return bool(lanes)
    return n_batch >= 0.8 * LANES * group_count(n_batch)


class Lanes:
    """The lanes of one solver: its groups of at most LANES realizations, their
    level table (where the ndarrays' table has one realization) and the
    process's fields."""

    def __init__(self, levels, n_batch, real):
        groups = group_count(n_batch)
        sizes = [groups * (nx + 2) * (ny + 1) for nx, ny in levels]
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        # (offset, nx, ny) of each level as the ndarrays' table, and the groups
        # of the solve (column _GROUPS, set by solve)
        self._table = np.array([[offsets[l], nx, ny, groups] for l, (nx, ny) in
                                enumerate(levels)], dtype=np.int32)
        self.geo = _upload(self._table, ti.i32)
        self.pool = pool(real).fit(int(offsets[-1]), int(sizes[0]), groups)
        self.n_batch, self.groups = n_batch, groups   # groups: of the whole batch
        self._slots = ti.ndarray(ti.i32, (groups, LANES))
        self._solved = None      # the realizations that the slots hold

    def solve(self, op, cg, state, flags, geo, chol, consts, maxiter, body, solved=None):
        """The whole solve of the realizations ``solved`` (every one if None;
        :func:`_solve_lanes`): as many groups as they take (:func:`group_count`),
        lane q of group g holding the (q G + g)-th of them. A realization's
        bits do not depend on its lane or on the others in its group."""
        solved = (np.arange(self.n_batch) if solved is None
                  else np.flatnonzero(np.asarray(solved, dtype=bool)))
        if self._solved is None or not np.array_equal(solved, self._solved):
            G = group_count(len(solved))
            slots = np.full(tuple(self._slots.shape), -1, dtype=np.int32)
            k = np.arange(len(solved))
            slots[k % max(G, 1), k // max(G, 1)] = solved
            self._slots.from_numpy(slots)
            self._table[:, _GROUPS] = G
            self.geo.from_numpy(self._table)
            self._solved = solved
        p = self.pool
        _solve_lanes(op, cg, state, flags, geo, chol, self.geo, consts, maxiter, self._slots,
                     *body, p.ops, p.mg, p.cg, p.chol)


class LanePool:
    """The lanes' fields, shared by every solver of one float type in a process
    and grown to the largest asked for, on a ladder of sizes (a solve copies in
    what it needs and keeps nothing there after; the fields stay until the
    process ends)."""

    def __init__(self, real):
        self.real = real
        self.capacity = (0, 0, 0)   # (all levels' entries, the finest level's, groups)
        self.tree = None
        self.ops = self.mg = self.cg = self.chol = None

    def fit(self, entries, fine, groups):
        """Fields holding ``entries`` flat indices on all levels, ``fine`` on the
        finest and the Cholesky factors of ``groups`` groups."""
        if all(n <= c for n, c in zip((entries, fine, groups), self.capacity)):
            return self
        # on a ladder of 2^(k/4), so that few sizes occur (a kernel is compiled
        # for each; Taichi's offline cache keeps it across runs, keyed by the
        # sizes) and at most a fifth is never used
        entries, fine, groups = (_ladder(max(n, c)) for n, c in
                                 zip((entries, fine, groups), self.capacity))
        if self.tree is not None:
            self.tree.destroy()
        vec = ti.types.vector(LANES, self.real)
        fb = ti.FieldsBuilder()
        tx, ty, mg, cg, chol = (ti.field(vec) for _ in range(5))
        fb.dense(ti.i, entries).place(tx, ty)
        fb.dense(ti.ij, (2, entries)).place(mg)
        fb.dense(ti.ij, (_CG_ROWS, fine)).place(cg)
        fb.dense(ti.ijk, (groups, COARSEST_CELLS, COARSEST_CELLS)).place(chol)
        self.tree = fb.finalize()
        self.ops, self.mg, self.cg, self.chol = LaneOps(tx, ty), mg, cg, chol
        self.capacity = (entries, fine, groups)
        return self


def _ladder(n):
    """The least 2^(k/4), rounded up to an integer, that is at least n."""
    k = max(0, int(np.ceil(4 * np.log2(max(n, 1)) - 1e-9)))
    while int(np.ceil(2.0 ** (k / 4))) < n:
        k += 1
    return int(np.ceil(2.0 ** (k / 4)))


_POOLS = {}


def pool(real):
    """The process's LanePool of float type ``real``."""
    if real not in _POOLS:
        _POOLS[real] = LanePool(real)
    return _POOLS[real]


# ---------------------------------------------------------------- copies
@ti.func
def _copy_in(op: ti.template(), cg: ti.template(), chol: ti.template(), geo: ti.template(),
             lops: ti.template(), lmg: ti.template(), lcg: ti.template(),
             lchol: ti.template(), lgeo: ti.template(), slots: ti.template(), g):
    """Group g's operators of every level, Cholesky factors, right-hand side,
    guess and search direction into the lanes, and its multigrid rows cleared
    (the fields are shared: another solver's values may lie where this one has
    the ghosts, which every sweep reads as 0); a lane past the batch gets
    nothing to solve (zero operator, unit factor)."""
    m = geo[geo.shape[0] - 1, _NX] * geo[geo.shape[0] - 1, _NY]
    zero = ti.Vector([0.0] * LANES, dt=REAL.dtype)
    for l in range(geo.shape[0]):
        per = (geo[l, _NX] + 2) * (geo[l, _NY] + 1)
        for c in range(lgeo[l, 0] + g * per, lgeo[l, 0] + (g + 1) * per):
            lmg[_X, c] = zero
            lmg[_B, c] = zero
    for q in range(LANES):
        r = slots[g, q]
        for l in range(geo.shape[0]):
            per = (geo[l, _NX] + 2) * (geo[l, _NY] + 1)
            src, dst = geo[l, 0] + r * per, lgeo[l, 0] + g * per
            for c in range(per):
                tx, ty = ti.cast(0.0, REAL.dtype), ti.cast(0.0, REAL.dtype)
                if r >= 0:
                    tx, ty = op[src + c][_TX], op[src + c][_TY]
                _put(lops.tx, ti.Vector([dst + c]), q, tx)
                _put(lops.ty, ti.Vector([dst + c]), q, ty)
        per = (geo[0, _NX] + 2) * (geo[0, _NY] + 1)
        src, dst = r * per, g * per
        for c in range(per):
            for row in ti.static((_SOL, _DIR, _RHS)):
                v = ti.cast(0.0, REAL.dtype)
                if r >= 0:
                    v = cg[row, src + c]
                _put(lcg, ti.Vector([row, dst + c]), q, v)
        for a, b in ti.ndrange(m, m):
            v = ti.select(a == b, ti.cast(1.0, REAL.dtype), ti.cast(0.0, REAL.dtype))
            if r >= 0:
                v = chol[r, a, b]
            _put(lchol, ti.Vector([g, a, b]), q, v)


@ti.func
def _copy_out(cg: ti.template(), geo: ti.template(), lcg: ti.template(), slots: ti.template(),
              g):
    """Group g's solutions and search directions back to the ndarray."""
    per = (geo[0, _NX] + 2) * (geo[0, _NY] + 1)
    for q in range(LANES):
        r = slots[g, q]
        if r >= 0:
            for c in range(per):
                for row in ti.static((_SOL, _DIR)):
                    cg[row, r * per + c] = _lane(lcg[row, g * per + c], q)


# ---------------------------------------------------------------- the lanes' CG
@ti.func
def _part(a: ti.template(), ra, b: ti.template(), rb, first, j0, j1):
    """One segment's ``sum a[ra] b[rb]``, cells first + j0 .. first + j1 - 1."""
    part = ti.Vector([0.0] * LANES, dt=REAL.dtype)
    for j in range(j0, j1):
        part += a[ra, first + j] * b[rb, first + j]
    return part


@ti.func
def _lane_product(cg: ti.template(), lcg: ti.template(), src, terms: ti.template(),
                  geo: ti.template(), lgeo: ti.template(), consts: ti.template(), mask,
                  slots: ti.template(), g):
    """``lcg[_LPW] = S (H M) S^T lcg[src]`` of the lanes in ``mask``, lane by lane
    (the bodies' cells differ between realizations) on the ndarray's rows of its
    realization, as :func:`._gmg_bodies._product_of` with the same bits: lcg[src]
    out to cg[src] and ``S z`` back in the bodies' rings only (every value the
    product reads or makes lies there; elsewhere it is 0). The lane is a loop
    variable, not unrolled, so that the product is compiled once (unrolled four
    times it tripled the kernel's compile time)."""
    zero = ti.Vector([0.0] * LANES, dt=REAL.dtype)
    per = (geo[0, _NX] + 2) * (geo[0, _NY] + 1)
    for c in range(g * per, (g + 1) * per):
        lcg[_LPW, c] = zero
    for q in range(LANES):
        r = slots[g, q]
        if _lane(mask, q) != 0 and r >= 0:
            for o in range(terms.body.shape[1]):
                b = ring(terms, geo, r, o)
                for i, j in ti.ndrange((b[0], b[1]), (b[2], b[3])):
                    cg[src, _index(geo, 0, r, i, j)] = _lane(lcg[src, _index(lgeo, 0, g, i, j)],
                                                             q)
            gathers_of(cg, src, terms, geo, consts, r)
            for o in range(terms.body.shape[1]):
                _spread_box(cg, _PW, -1, terms, geo, consts[_K_DX], consts[_K_DY], r, o)
            for o in range(terms.body.shape[1]):
                b = ring(terms, geo, r, o)
                for i, j in ti.ndrange((b[0], b[1]), (b[2], b[3])):
                    _put(lcg, ti.Vector([_LPW, _index(lgeo, 0, g, i, j)]), q,
                         cg[_PW, _index(geo, 0, r, i, j)])


@ti.func
def _lane(v, q):
    """Component q (a run-time index) of the lanes' vector v."""
    out = v[0]
    for p in ti.static(range(1, LANES)):
        if q == p:
            out = v[p]
    return out


@ti.func
def _put(a: ti.template(), index, q, value):
    """``a[index][q] = value``: lane q (a run-time index) of the vector at the
    grouped ``index`` (a ti.Vector of indices) of field a."""
    for p in ti.static(range(LANES)):
        if q == p:
            a[index][p] = value


@ti.func
def _any(mask):
    n = 0
    for q in ti.static(range(LANES)):
        n += mask[q]
    return n > 0


@ti.func
def _keep(mask, new, old):
    """``new`` in the lanes of ``mask``, ``old`` in the others."""
    return ti.select(mask != 0, new, old)


# Per-cell steps of the lanes' CG, in the order of the scalar solve's
# (_gmg_cg._residual_b, _matvec_b, _update); ``mask``: the lanes they change,
# ``coef``: the step's coefficient (alpha), ``bodies``: whether row _LPW applies.
@ti.func
def _residual(lops: ti.template(), lmg: ti.template(), lcg: ti.template(), k, s, mask,
              coef, bodies: ti.template()):
    b = lcg[_RHS, k] - _apply(lops, lcg, _SOL, k, s)
    if ti.static(bodies):
        b = b - lcg[_LPW, k]
    lmg[_B, k] = _keep(mask, b, lmg[_B, k])


@ti.func
def _matvec(lops: ti.template(), lmg: ti.template(), lcg: ti.template(), k, s, mask, coef,
            bodies: ti.template()):
    ad = _apply(lops, lcg, _DIR, k, s)
    if ti.static(bodies):
        ad = ad + lcg[_LPW, k]
    lcg[_ADIR, k] = ad


@ti.func
def _update(lops: ti.template(), lmg: ti.template(), lcg: ti.template(), k, s, mask, coef,
            bodies: ti.template()):
    lcg[_SOL, k] = _keep(mask, lcg[_SOL, k] + coef * lcg[_DIR, k], lcg[_SOL, k])
    lmg[_B, k] = _keep(mask, lmg[_B, k] - coef * lcg[_ADIR, k], lmg[_B, k])


@ti.func
def _no_step(lops: ti.template(), lmg: ti.template(), lcg: ti.template(), k, s, mask, coef,
             bodies: ti.template()):
    """No change: _cells_and_sum with it is a dot product alone."""
    pass


@ti.func
def _cells_and_sum(step: ti.template(), lops: ti.template(), lmg: ti.template(),
                   lcg: ti.template(), lgeo: ti.template(), g, mask, coef,
                   bodies: ti.template(), a: ti.template(), ra, b: ti.template(), rb):
    """``step`` at every fine cell of group g, then ``sum a[ra] b[rb]`` of every lane,
    segment by segment as the scalar solve's _for_cells_and_sum_of and its total
    (:func:`._gmg_cg._segment_sum`, ``_total``)."""
    nx, ny = lgeo[0, _NX], lgeo[0, _NY]
    segments = _segments(ny)
    total = ti.Vector([0.0] * LANES, dt=REAL.dtype)
    for t in range(nx * segments):
        _, i, j0, j1 = _segment(t, nx, ny, segments)
        first = _index(lgeo, 0, g, i, 0)
        for j in range(j0, j1):
            step(lops, lmg, lcg, first + j, ny + 1, mask, coef, bodies)
        total += _part(a, ra, b, rb, first, j0, j1)
    return total


@ti.func
def _lane_solve(lops: ti.template(), lmg: ti.template(), lcg: ti.template(),
                lchol: ti.template(), lgeo: ti.template(), cg: ti.template(),
                geo: ti.template(), state: ti.template(), flags: ti.template(),
                consts: ti.template(), maxiter, bodies: ti.template(), terms: ti.template(),
                slots: ti.template(), g):
    """The CG solve of group g's lanes (module docstring): the steps of
    :func:`._gmg_cg._solve_one`, each lane's in its order."""
    tol2 = consts[_K_TOL2]
    nx, ny = lgeo[0, _NX], lgeo[0, _NY]
    s = ny + 1
    zero = ti.Vector([0.0] * LANES, dt=REAL.dtype)
    active = ti.Vector([0] * LANES)
    for q in ti.static(range(LANES)):
        active[q] = ti.select(slots[g, q] >= 0, 1, 0)
    iters = ti.Vector([0] * LANES)
    bb = _cells_and_sum(_no_step, lops, lmg, lcg, lgeo, g, active, zero, bodies, lcg, _RHS,
                        lcg, _RHS)
    undriven = ti.select(bb == 0, 1, 0)
    for i in range(nx):
        first = _index(lgeo, 0, g, i, 0)
        for j in range(ny):
            k = first + j
            cleared = ti.select(_diagonal(lops, k, s) == 0, 1, undriven)
            lcg[_SOL, k] = ti.select(cleared != 0, zero, lcg[_SOL, k])
    rz, rr, alpha, beta, res = zero, zero, zero, zero, zero
    running = ti.Vector([0] * LANES)
    first_step = ti.Vector([0] * LANES)
    pending = active        # lanes whose true residual decides what they do next
    while _any(pending):
        # r = b - A x of the pending lanes, and _after_check
        if ti.static(bodies):
            _lane_product(cg, lcg, _SOL, terms, geo, lgeo, consts, pending, slots, g)
        total = _cells_and_sum(_residual, lops, lmg, lcg, lgeo, g, pending, zero, bodies,
                               lmg, _B, lmg, _B)
        rr = _keep(pending, total, rr)
        res2 = ti.select(bb > 0, rr / bb, zero)
        res = _keep(pending, ti.sqrt(res2), res)
        go = ti.select(res2 > tol2, 1, 0) * ti.select(iters < maxiter, 1, 0)
        running = _keep(pending, go, running)
        first_step = _keep(pending, 1, first_step)
        pending = ti.Vector([0] * LANES)
        while _any(running):
            _cycle_of(lops, lmg, lchol, lgeo, g, 0, OVERCORRECTION)
            rz_new = _cells_and_sum(_no_step, lops, lmg, lcg, lgeo, g, running, zero, bodies,
                                    lmg, _B, lmg, _X)
            beta = _keep(running, ti.select(first_step != 0, zero, rz_new / rz), beta)
            rz = _keep(running, rz_new, rz)
            first_step = _keep(running, 0, first_step)
            for i in range(nx):
                first = _index(lgeo, 0, g, i, 0)
                for j in range(ny):
                    k = first + j
                    lcg[_DIR, k] = _keep(running, lmg[_X, k] + beta * lcg[_DIR, k],
                                         lcg[_DIR, k])
            if ti.static(bodies):
                _lane_product(cg, lcg, _DIR, terms, geo, lgeo, consts, running, slots, g)
            curvature = _cells_and_sum(_matvec, lops, lmg, lcg, lgeo, g, running, zero, bodies,
                                       lcg, _DIR, lcg, _ADIR)
            alpha = _keep(running, ti.select(curvature > 0, rz / curvature, zero), alpha)
            total = _cells_and_sum(_update, lops, lmg, lcg, lgeo, g, running, alpha, bodies,
                                   lmg, _B, lmg, _B)
            rr = _keep(running, total, rr)
            iters += running
            go = (ti.select(rr > tol2 * bb, 1, 0) * ti.select(iters < maxiter, 1, 0)
                  * ti.select(alpha != 0, 1, 0))
            pending = _keep(running, 1 - go, pending)
            running = _keep(running, go, running)
    for q in ti.static(range(LANES)):
        r = slots[g, q]
        if r >= 0:
            state[r, _RZ] = rz[q]
            state[r, _BB] = bb[q]
            state[r, _RR] = rr[q]
            state[r, _ALPHA] = alpha[q]
            state[r, _BETA] = beta[q]
            state[r, _RES] = res[q]
            flags[r, _ITERS] = iters[q]
            flags[r, _UNDRIVEN] = undriven[q]
            flags[r, _RUNNING] = 0
            flags[r, _CHECK] = 0
            flags[r, _FIRST] = 1


@ti.kernel
def _solve_lanes(op: _Ops, cg: _Rows, state: _Rows, flags: _Ints, geo: _Ints, chol: _Chol,
                 lgeo: _Ints, consts: _Consts, maxiter: ti.i32, slots: _Ints,
                 bodies: ti.template(), terms: Terms, lops: ti.template(), lmg: ti.template(),
                 lcg: ti.template(), lchol: ti.template()):
    """The whole solve of the realizations in the first ``lgeo[0, _GROUPS]``
    groups of ``slots`` (``slots[g, q]``: lane q of group g, -1 for none), a group
    of LANES per thread: copied into the lanes, solved, copied back (module
    docstring). ``lops``: the pool's LaneOps."""
    for t in range(lgeo[0, _GROUPS] * _TASK):  # one group per thread (_TASK)
        if t % _TASK == 0:
            g = t // _TASK
            _copy_in(op, cg, chol, geo, lops, lmg, lcg, lchol, lgeo, slots, g)
            _lane_solve(lops, lmg, lcg, lchol, lgeo, cg, geo, state, flags, consts, maxiter,
                        bodies, terms, slots, g)
            _copy_out(cg, geo, lcg, slots, g)
