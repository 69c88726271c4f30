"""Multigrid pieces of the Taichi pressure solver (:mod:`.gmg`): its constants and
array layout, the matrix-free five-point operator, the 2 x 2 aggregation levels,
red-black Gauss-Seidel smoothing, the restriction, the coarsest level's Cholesky
solve and the V-cycle. The kernels that build the operators, the right-hand side
and the Cholesky factor are in :mod:`._gmg_setup`. Package-internal: :mod:`.gmg`
is the API."""
# No "from __future__ import annotations": Taichi reads kernel annotations as objects.

from typing import NamedTuple

from ..backend import ti

# Most CG iterations one realization may take in one solve. From zero to 1e-8
# (tools/bench_solvers.py --study contrast, 175 x 61 to 1400 x 488 cells): 12-15
# at the Kozeny-Carman contrast (1/60), up to 39 at 1e-3 and 87 at 1e-6 with half
# the area in overlapping disks that enclose fluid; reaching this means the solve
# failed, and the flux check reports it.
MAXITER = 500

# Red-black Gauss-Seidel sweeps before and after each coarse correction. Two
# sweeps took 13-17 iterations against 19-22 for one at contrast 60 (175 x 61 to
# 1400 x 488 cells): more work per iteration, less per solve.
SWEEPS = 2

# Scaling of the coarse correction. At contrast 60-1e3 and two sweeps, 1.0 took
# 35-72 iterations, 1.5 took 19-35, 1.8 took 14-27, 2.0 took 13-25, 2.3 took 13-31.
OVERCORRECTION = 2.0

# Half-sweeps of the pre- (and of the post-) smoother.
_HALVES = 2 * SWEEPS

# Grid columns per block of the ``rows`` way's smoother (_smooth_blocks): a block
# is smoothed by one thread in one pass, holding about _HALVES + 2 columns in its
# cache (on the 721-cell columns of a 1590 x 720 grid about 140 kB); the seams
# between blocks cost about _HALVES^2 / (_HALVES _BLOCK) of that again.
_BLOCK = 64

# Cells per realization at or below which a level is not coarsened further but
# factored (dense Cholesky: COARSEST_CELLS^3 / 3 flops per realization per set-up).
COARSEST_CELLS = 64

# On the CPU, levels with at most this many cells per realization are cycled by
# one thread per realization in a single kernel launch: on a 10^3-10^4-cell level
# the cost of launching a parallel loop (tens of microseconds on 2 cores) exceeds
# the work in it.
SERIAL_CELLS = 4096

# On the CPU, grids of at most this many cells are solved one realization per
# thread in a single kernel launch (parallel="realizations"); larger ones with
# every thread on each grid-sized loop (parallel="rows"), which a single large
# realization needs. The vani grid (10^4 cells), R = 1: 8 ms per cold solve one
# way against 21 ms the other (preliminary, a loaded 2-core machine).
REALIZATION_CELLS = 2**16

# Components of an entry of the operator: the transmissibility of the east and of
# the north face of the cell (of a ghost: of its one Dirichlet face, see Layout).
_TX, _TY = 0, 1
# Rows of the multigrid work array: the correction and its right-hand side (on
# the finest level, the preconditioned residual z and the CG residual r).
_X, _B = 0, 1
# Rows of the fine-level CG array: solution (p - p_ref), search direction,
# A times it, right-hand side, the part of it that depends on kappa only, and
# the moving bodies' term of the operator applied to a vector (_gmg_bodies), and
# the initial guess kept while a solve may have to start again (gmg.solve).
_SOL, _DIR, _ADIR, _RHS, _BASE, _PW, _KEEP = range(7)
CG_ROWS = 7
# Columns of the level table.
_OFF, _NX, _NY = 0, 1, 2
# Per-realization integers: still iterating, iterations done, no driving at all
# (b = 0), the permeability scan's counts of changed, zero and invalid cells, and
# the CG's own: stopped at the last step, its true residual to be checked; and the
# next search direction starts afresh (beta = 0); and left out of this solve
# (gmg.TaichiPressureSolver.solve's ``only``: every CG kernel skips it).
_RUNNING, _ITERS, _UNDRIVEN, _CHANGED, _ZEROS, _BAD, _CHECK, _FIRST, _SKIP = range(9)
N_FLAGS = 9
# Per-realization floats: r.z, |b|^2, |r|^2, CG step and direction coefficients,
# the inlet's total permeability (flow_rate), the final relative residual.
_RZ, _BB, _RR, _ALPHA, _BETA, _INLET, _RES = range(7)
# How a Gauss-Seidel half-sweep reads its neighbours: as stored; as zero (the
# first half-sweep of a cycle, which starts from x = 0); or with the coarse
# correction added (the first half-sweep after it, see _relax).
_STORED, _ZERO, _CORRECTED = range(3)
# Ways to share the work among threads (TaichiPressureSolver, parameter parallel).
_PARALLEL = ("realizations", "rows", "cells")
# With parallel="cells" each realization gets a multiple of this many iterations
# of a parallel loop, so that its cells fall at the same places in the blocks
# Taichi cuts the loop into (32 iterations on the CPU) and in a CPU's vector
# lanes: otherwise a vectorized block and its scalar remainder round differently
# and a realization's result would depend on its place in the batch.
_LANES = 64
# Taichi's CPU backend hands a parallel loop to its threads in blocks of up to 512
# iterations (measured with ti.global_thread_idx: a loop of 100 or 512 runs on one
# thread, ti.loop_config(block_dim=1) or not). So a loop over realizations runs
# _TASK iterations per realization, one of them working; and in the ``rows`` way
# a thread takes a segment of a grid column, _SEGMENT cells, not the whole column
# (a grid of 1590 columns would give 2 threads 1024 and 566 of them).
_TASK = 512
_SEGMENT = 64
# Left, right, bottom, top: the box sides in the order of fluid._SIDES.
_SIDE_NAMES = ("left", "right", "bottom", "top")

# Constants of a solver, in one array of its float type (``consts``): the float
# scalars travel there, not as kernel arguments, whose types are fixed when a
# kernel is defined. The squared tolerance, the cell sizes, p_ref, the flow-rate
# inflow and the face conductance factors dy / (dx eta), dx / (dy eta).
_K_TOL2, _K_DX, _K_DY, _K_PREF, _K_INFLOW, _K_GX, _K_GY = range(7)
N_CONSTS = 7


class _Real:
    """The solve's float type (float64, or float32 where the backend has no
    float64: backend.solve_real), read by the kernels below when they compile.
    Every kernel takes an array of that type, so Taichi compiles it anew for
    each type and the two never meet."""
    dtype = ti.f64


REAL = _Real()


def vec2(real):
    """The operator's element type: (Tx, Ty) in ``real``."""
    return ti.types.vector(2, real)


# Float arrays take the solver's type (any float type: compiled per type).
_Ops = ti.types.ndarray(ndim=1)
_Sides = ti.types.ndarray(ndim=2)
_Rows = ti.types.ndarray(ndim=2)
_Ints = ti.types.ndarray(dtype=ti.i32, ndim=2)
_Cells = ti.types.ndarray(dtype=ti.i8, ndim=3)
_Mask = ti.types.ndarray(dtype=ti.i8, ndim=2)
_Chol = ti.types.ndarray(ndim=3)
_Field = ti.types.ndarray(ndim=3)
_Consts = ti.types.ndarray(ndim=1)
_Grid = ti.types.ndarray(ndim=3)     # any float type: the simulation's kappa
_Vectors = ti.types.ndarray(ndim=4)  # (R, nx, ny, 2), any float type


# ---------------------------------------------------------------- lanes
# The cell helpers below serve two storages. The package's: ``op`` an ndarray of
# (Tx, Ty) per cell, ``mg``/``cg`` ndarrays of rows, one realization's values per
# cell. And realizations side by side (:mod:`._gmg_lanes`): ``op`` a LaneOps of
# two fields, ``mg``/``cg`` fields of rows, each cell's value a vector of LANES
# realizations' values, the arithmetic of every lane that of the scalar code.

#: Realizations side by side in a lane solve (:mod:`._gmg_lanes`): a 256-bit
#: register of float64 (tools/bench_lanes.py: 4 vectorize, 8 spill).
LANES = 4


class LaneOps(NamedTuple):
    """The operator of a lane solve: the east (``tx``) and north (``ty``)
    transmissibilities, each a field of ``vector(LANES)`` per flat index."""
    tx: object
    ty: object


def _is_lanes(op):
    """Whether the helpers work on lanes (compile time: ``ti.static``)."""
    return isinstance(op, LaneOps)


@ti.func
def _tx(op: ti.template(), k):
    """Tx of flat index k (a vector of lanes, or one value)."""
    if ti.static(_is_lanes(op)):
        return op.tx[k]
    else:
        return op[k][_TX]


@ti.func
def _ty(op: ti.template(), k):
    if ti.static(_is_lanes(op)):
        return op.ty[k]
    else:
        return op[k][_TY]


@ti.func
def _zero(op: ti.template()):
    """0 in the storage of ``op``: a vector of lanes, or one value."""
    if ti.static(_is_lanes(op)):
        return ti.Vector([0.0] * LANES, dt=REAL.dtype)
    else:
        return ti.cast(0.0, REAL.dtype)


# ---------------------------------------------------------------- cell helpers
# ``k`` is a flat index and ``s = ny + 1`` the column stride of its level.
@ti.func
def _index(geo: ti.template(), l, r, i, j):
    """Flat index of (i, j) of realization r on level l; see Layout for the ghosts
    (i = -1, i = nx, j = ny)."""
    return geo[l, _OFF] + (r * (geo[l, _NX] + 2) + i + 1) * (geo[l, _NY] + 1) + j


@ti.func
def _diagonal(op: ti.template(), k, s):
    return _tx(op, k) + _ty(op, k) + _tx(op, k - s) + _ty(op, k - 1)


@ti.func
def _neighbours(op: ti.template(), a: ti.template(), row, k, s):
    """``sum_f T_f a_f`` over the four faces of cell k (a ghost's a is 0)."""
    return (_tx(op, k - s) * a[row, k - s] + _tx(op, k) * a[row, k + s]
            + _ty(op, k - 1) * a[row, k - 1] + _ty(op, k) * a[row, k + 1])


@ti.func
def _apply(op: ti.template(), a: ti.template(), row, k, s):
    """``(A a)_k``."""
    return _diagonal(op, k, s) * a[row, k] - _neighbours(op, a, row, k, s)


@ti.func
def _relax(op: ti.template(), mg: ti.template(), k, s, reads, alpha, parents):
    """Gauss-Seidel update of one cell: ``x = (b + sum_f T_f x_f) / diag``.

    A cell that is no unknown gets 0. With ``reads == _CORRECTED`` each neighbour
    is read with the coarse correction added, ``x_f + alpha x_c[parent]``
    (``parents``: the coarse indices of the west, east, south and north
    neighbours' parents): in the black half-sweep that follows the correction
    only the red neighbours' corrected values are needed (an update overwrites
    the cell's own value, and the red sweep after it reads only black cells), so
    the corrected field is never stored.
    """
    d = _diagonal(op, k, s)
    if ti.static(_is_lanes(op)):
        # every lane computes; a lane without an unknown keeps 0 (its quotient,
        # by a zero diagonal, is dropped)
        mg[_X, k] = ti.select(d > 0, _relaxed(op, mg, k, s, reads, alpha, parents) / d,
                              _zero(op))
    else:
        x = ti.cast(0.0, REAL.dtype)
        if d > 0:
            x = _relaxed(op, mg, k, s, reads, alpha, parents) / d
        mg[_X, k] = x


@ti.func
def _relaxed(op: ti.template(), mg: ti.template(), k, s, reads, alpha, parents):
    """``b + sum_f T_f x_f`` of _relax, the neighbours read as ``reads`` says."""
    v = mg[_B, k]
    if reads == _STORED:
        v += _neighbours(op, mg, _X, k, s)
    elif reads == _CORRECTED:
        v += (_tx(op, k - s) * (mg[_X, k - s] + alpha * mg[_X, parents[0]])
              + _tx(op, k) * (mg[_X, k + s] + alpha * mg[_X, parents[1]])
              + _ty(op, k - 1) * (mg[_X, k - 1] + alpha * mg[_X, parents[2]])
              + _ty(op, k) * (mg[_X, k + 1] + alpha * mg[_X, parents[3]]))
    return v


@ti.func
def _parent_columns(geo: ti.template(), l, r, i):
    """Coarse indices of (I, 0) for the parents of the west, own and east
    neighbours of column i, and the coarse ny; a ghost's parent is a coarse
    ghost, so that it gets no correction."""
    nx, mx = geo[l, _NX], geo[l + 1, _NX]
    east = (i + 1) // 2 if i + 1 < nx else mx
    return ti.Vector([_index(geo, l + 1, r, (i + 1) // 2 - 1, 0),
                      _index(geo, l + 1, r, i // 2, 0),
                      _index(geo, l + 1, r, east, 0), geo[l + 1, _NY]])


@ti.func
def _parents(columns, j, ny):
    """Coarse indices of the parents of the west, east, south and north
    neighbours of cell (i, j), from _parent_columns of column i."""
    north = (j + 1) // 2 if j + 1 < ny else columns[3]
    return ti.Vector([columns[0] + j // 2, columns[2] + j // 2,
                      columns[1] + (j + 1) // 2 - 1, columns[1] + north])


@ti.func
def _relax_cell(op: ti.template(), mg: ti.template(), geo: ti.template(), l, r, i, j,
                reads, alpha):
    ny = geo[l, _NY]
    parents = ti.Vector([0, 0, 0, 0])
    if reads == _CORRECTED:
        parents = _parents(_parent_columns(geo, l, r, i), j, ny)
    _relax(op, mg, _index(geo, l, r, i, j), ny + 1, reads, alpha, parents)


@ti.func
def _relax_row(op: ti.template(), mg: ti.template(), geo: ti.template(), l, r, i, j0, j1,
               colour, reads, alpha):
    """One colour of cells j0..j1-1 of grid column i, with the column's indices
    computed once."""
    ny = geo[l, _NY]
    k0 = _index(geo, l, r, i, 0)
    columns = ti.Vector([0, 0, 0, 0])
    if reads == _CORRECTED:
        columns = _parent_columns(geo, l, r, i)
    first = j0 + (i + colour + j0) % 2
    for h in range((j1 - first + 1) // 2):
        j = first + 2 * h
        parents = ti.Vector([0, 0, 0, 0])
        if reads == _CORRECTED:
            parents = _parents(columns, j, ny)
        _relax(op, mg, k0 + j, ny + 1, reads, alpha, parents)


@ti.func
def _segments(n):
    """How many segments of _SEGMENT cells a column of n cells has."""
    return (n + _SEGMENT - 1) // _SEGMENT


@ti.func
def _segment(t, nx, ny, segments):
    """(r, i, j0, j1) of work item t of a loop over the segments of every column:
    realization r, column i, cells j0..j1-1."""
    per_r = nx * segments
    r, rest = t // per_r, t % per_r
    seg = rest % segments
    return r, rest // segments, seg * _SEGMENT, ti.min((seg + 1) * _SEGMENT, ny)


@ti.func
def _restrict_row(op: ti.template(), mg: ti.template(), geo: ti.template(), l, r, I,
                  J0, J1):
    """Right-hand sides of coarse cells (I, J0..J1-1): the sums of their
    children's residuals.

    Only the red children's (i + j even: (2 I, 2 J) and (2 I + 1, 2 J + 1)) are
    summed. The pre-smoother ends with a black half-sweep (see _sweep), which
    leaves each black cell's residual zero up to rounding: its update solved its
    own row, and no neighbour of it changed after. Skipping them halves the work.
    """
    nx, ny = geo[l, _NX], geo[l, _NY]
    s = ny + 1
    west = _index(geo, l, r, 2 * I, 0)
    coarse = _index(geo, l + 1, r, I, 0)
    for J in range(J0, J1):
        v = _zero(op)
        for a in ti.static((0, 1)):
            if 2 * I + a < nx and 2 * J + a < ny:
                k = west + a * (s + 1) + 2 * J
                v += mg[_B, k] - _apply(op, mg, _X, k, s)
        mg[_B, coarse + J] = v


@ti.func
def _dense(geo: ti.template(), l, r, c):
    """Flat index of cell c = i ny + j of the coarsest level (the numbering of
    its dense matrix)."""
    ny = geo[l, _NY]
    return _index(geo, l, r, c // ny, c % ny)


@ti.func
def _coarse_solve(mg: ti.template(), chol: ti.template(), geo: ti.template(), l, r):
    """x = A^-1 b on the coarsest level by the Cholesky factor."""
    m = geo[l, _NX] * geo[l, _NY]
    for c in range(m):
        v = mg[_B, _dense(geo, l, r, c)]
        for q in range(c):
            v -= chol[r, c, q] * mg[_X, _dense(geo, l, r, q)]
        mg[_X, _dense(geo, l, r, c)] = v / chol[r, c, c]
    for t in range(m):
        c = m - 1 - t
        v = mg[_X, _dense(geo, l, r, c)]
        for q in range(c + 1, m):
            v -= chol[r, q, c] * mg[_X, _dense(geo, l, r, q)]
        mg[_X, _dense(geo, l, r, c)] = v / chol[r, c, c]


@ti.func
def _lanes(n):
    """n rounded up to a multiple of _LANES."""
    return (n + _LANES - 1) // _LANES * _LANES


# ---------------------------------------------------------------- multigrid kernels
@ti.func
def _sweep(h, post):
    """(colour, reads) of half-sweep h of the pre-smoother, or (``post``) of its
    adjoint, the post-smoother: red (colour 0, i + j even) first before the
    coarse correction, black first after it."""
    colour = h % 2
    reads = _ZERO if h == 0 else _STORED
    if post:
        colour = 1 - colour
        reads = _CORRECTED if h == 0 else _STORED
    return ti.Vector([colour, reads])


@ti.func
def _sweeps_pass(op: ti.template(), mg: ti.template(), geo: ti.template(), l, r, a0, a1,
                 west, east, post, alpha):
    """The smoother's 2 SWEEPS half-sweeps (_sweep) of columns a0..a1-1 of level l
    in one pass over them: half-sweep h runs h columns behind the first, so a
    column is read from memory once, not once per half-sweep.

    Every cell gets the operands it gets from whole half-sweeps one after the
    other (the same bits): half-sweep h at column i needs h - 1 done at columns
    i - 1..i + 1, which the lag of one column per half-sweep gives, and h + 1
    overwrites what h read only after h has passed it. A block of columns beside
    another (``west`` or ``east`` false) leaves half-sweep h undone on its h
    columns next to that edge, which read or are read across it;
    _sweeps_seam does them once both blocks are done.
    """
    ny = geo[l, _NY]
    for c in range(a0, a1 + _HALVES - 1):
        for h in ti.static(range(_HALVES)):
            i = c - h
            lo = a0 if west else a0 + h
            hi = a1 if east else a1 - h
            if i >= lo and i < hi:
                colour, reads = _sweep(h, post)
                _relax_row(op, mg, geo, l, r, i, 0, ny, colour, reads, alpha)


@ti.func
def _sweeps_seam(op: ti.template(), mg: ti.template(), geo: ti.template(), l, r, b, post,
                 alpha):
    """What _sweeps_pass left undone at the edge between two blocks of columns at
    column b: half-sweep h at columns b - h..b + h - 1, in the order of h (blocks
    of at least 2 _HALVES columns, so that seams do not meet)."""
    ny = geo[l, _NY]
    for h in ti.static(range(1, _HALVES)):
        colour, reads = _sweep(h, post)
        for i in range(b - h, b + h):
            _relax_row(op, mg, geo, l, r, i, 0, ny, colour, reads, alpha)


@ti.func
def _blocks(nx):
    """How many blocks of columns a level of nx columns is smoothed in (the last
    takes the remainder: every block has at least _BLOCK columns)."""
    return ti.max(1, nx // _BLOCK)


@ti.kernel
def _smooth_blocks(op: _Ops, mg: _Rows, geo: _Ints, flags: _Ints, l: ti.i32, post: ti.i32):
    """The pre-smoother (or ``post``: the post-smoother) of level l, in parallel
    over blocks of _BLOCK grid columns, each in one pass (_sweeps_pass), then
    over the seams between them; a thread per block (_TASK iterations each, so
    that the blocks spread over the threads)."""
    alpha = OVERCORRECTION
    R, nx = flags.shape[0], geo[l, _NX]
    blocks = _blocks(nx)
    for t in range(R * blocks * _TASK):
        r, b = t // (blocks * _TASK), t // _TASK % blocks
        if t % _TASK == 0 and flags[r, _RUNNING]:
            a1 = nx if b == blocks - 1 else (b + 1) * _BLOCK
            _sweeps_pass(op, mg, geo, l, r, b * _BLOCK, a1, b == 0, b == blocks - 1,
                         post, alpha)
    for t in range(R * (blocks - 1) * _TASK):
        r, b = t // ((blocks - 1) * _TASK), t // _TASK % (blocks - 1)
        if t % _TASK == 0 and flags[r, _RUNNING]:
            _sweeps_seam(op, mg, geo, l, r, (b + 1) * _BLOCK, post, alpha)


@ti.kernel
def _smooth(op: _Ops, mg: _Rows, geo: _Ints, flags: _Ints, l: ti.i32, h: ti.i32,
            post: ti.i32):
    """Half-sweep h (see _sweep) of level l, in parallel over its cells (the
    ``cells`` way: on the CPU, _smooth_blocks does all the half-sweeps in one
    kernel); the coarse correction (post-smoothing) scaled by OVERCORRECTION."""
    alpha = OVERCORRECTION
    R, nx, ny = flags.shape[0], geo[l, _NX], geo[l, _NY]
    colour, reads = _sweep(h, post)
    half = (ny + 1) // 2  # cells of one colour per column, at most
    span = _lanes(nx * half)
    for t in range(R * span):
        r, c = t // span, t % span
        if c < nx * half and flags[r, _RUNNING]:
            i = c // half
            j = (i + colour) % 2 + 2 * (c % half)
            if j < ny:
                _relax_cell(op, mg, geo, l, r, i, j, reads, alpha)


@ti.kernel
def _restrict(op: _Ops, mg: _Rows, geo: _Ints, flags: _Ints, l: ti.i32,
              cells: ti.template()):
    """The right-hand side of level l + 1 from the residual of level l."""
    R, mx, my = flags.shape[0], geo[l + 1, _NX], geo[l + 1, _NY]
    if ti.static(cells):
        span = _lanes(mx * my)
        for t in range(R * span):
            r, c = t // span, t % span
            if c < mx * my and flags[r, _RUNNING]:
                _restrict_row(op, mg, geo, l, r, c // my, c % my, c % my + 1)
    else:
        segments = _segments(my)
        for t in range(R * mx * segments):
            r, I, J0, J1 = _segment(t, mx, my, segments)
            if flags[r, _RUNNING]:
                _restrict_row(op, mg, geo, l, r, I, J0, J1)


@ti.func
def _cycle_of(op: ti.template(), mg: ti.template(), chol: ti.template(), geo: ti.template(),
              r, l0, alpha):
    """The V-cycle of realization r from level l0 down, serially: smoothing and
    restriction down to the coarsest level, its solve, correction and smoothing
    back up (one loop over both ways, so the smoother is compiled once)."""
    L = geo.shape[0]
    down = L - 1 - l0
    for stage in range(2 * down + 1):
        if stage == down:
            _coarse_solve(mg, chol, geo, L - 1, r)
        else:
            post = 1 if stage > down else 0
            l = l0 + stage if not post else L - 1 - (stage - down)
            _sweeps_pass(op, mg, geo, l, r, 0, geo[l, _NX], True, True, post, alpha)
            if not post:
                for I in range(geo[l + 1, _NX]):
                    _restrict_row(op, mg, geo, l, r, I, 0, geo[l + 1, _NY])


@ti.kernel
def _serial_cycle(op: _Ops, mg: _Rows, chol: _Chol, geo: _Ints, flags: _Ints,
                  l0: ti.i32):
    """The V-cycle from level l0 down, one thread per running realization."""
    for t in range(flags.shape[0] * _TASK):
        r = t // _TASK
        if t % _TASK == 0 and flags[r, _RUNNING]:
            _cycle_of(op, mg, chol, geo, r, l0, OVERCORRECTION)
