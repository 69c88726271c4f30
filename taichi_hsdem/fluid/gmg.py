"""Batched geometric-multigrid CG for the Hele-Shaw pressure, in Taichi (issue #22).

:class:`TaichiPressureSolver` solves the finite-volume system of
:class:`taichi_hsdem.fluid.PressureSolver` (docs/model.md section 2: cell-centred
two-point fluxes with the harmonic mean, Dirichlet faces half a cell away, walls
passing no flux) for all ``R`` realizations at once, without assembling a matrix,
in float64 whatever the simulation's precision wherever the backend has float64
kernels (in float32 elsewhere: Metal, GLES; see F32_TOL_FLOOR), on the Taichi
backend in use: on a GPU the fields stay on the device, and the host reads one
report per solve.

Method
------
*Operator.* Each cell stores two numbers, ``Tx`` and ``Ty``, the
transmissibilities of its east and north faces (``2 k1 k2 / (k1 + k2) dy / (dx
eta)``; 0 on a wall). A Dirichlet face is a face to a ghost cell outside the box
whose correction is always 0, with the half-cell conductance ``2 k dy / (dx eta)``
(its value enters only the right-hand side), so ``(A x)_c = (sum_f T_f) x_c -
sum_f T_f x_f`` over the four faces of every cell, with nothing else to store. A
cell that is no unknown (a wall, a pocket no Dirichlet face reaches, a cell cut
off by zero permeability) has no open face: its diagonal is 0 and it is skipped.

*Hierarchy.* The grid is coarsened by 2 x 2 aggregation (a coarse cell is an
unknown if any of its children is) until at most ``COARSEST_CELLS`` cells remain.
With piecewise-constant prolongation ``P`` and restriction ``P^T`` the Galerkin
operator ``P^T A P`` is again a five-point operator of the same form: the
transmissibility of a coarse face, Dirichlet faces included, is the sum of those
of the fine faces across it. Building a level is one pass over the finer one.
The coarsest level is factored by dense Cholesky, per realization.

*Cycle.* A V(2, 2)-cycle with red-black Gauss-Seidel: two red-then-black sweeps
before the coarse correction, two black-then-red sweeps (their adjoint) after,
so the cycle is a symmetric operator and plain preconditioned CG applies. The
coarse correction is multiplied by ``OVERCORRECTION``: piecewise-constant
interpolation underestimates smooth errors, and unscaled it converges badly.
The cycle stays positive definite for any positive scaling (the smoothing part is
positive definite and the coarse part semi-definite), so CG remains valid.

*Conjugate gradients.* One CG per realization, each stopped when its own relative
residual ``|b - A p| / |b|`` meets ``tol``; a converged realization is frozen
(every kernel skips it) while the others go on. The recursively updated
residual decides the stop; the true residual is then recomputed, and CG restarted
from there if rounding had made them differ by more than ``tol`` (in float32 it
also stops once that residual is round-off: _gmg_cg._after_check). A realization
left out of a solve (``solve(..., only=...)``, flag ``_SKIP``) is frozen from
the start.

*Moving bodies* (``solve(..., bodies=BodyTerms(...))``, the implicit carried
volume): the operator gains ``S (H M) S^T``, one symmetric positive
semi-definite term per body (:mod:`._gmg_bodies`). CG applies it to each vector
it multiplies, in two passes (gather ``S^T x`` per body over its own box of
cells, a thread per body; spread ``S z``, a thread per cell), into row ``_PW``;
the V-cycle stays that of ``A``.

*Reproducibility.* A realization's pressure does not depend on the others in the
batch, nor on the thread count: no float atomics; every dot product sums fixed
segments of ``_SEGMENT`` cells of each grid column, each serially in one thread,
then the segment sums serially; nothing couples realizations (see Layout).

*Layout.* One flat array per quantity holds all levels. Level ``l`` of
realization ``r`` is ``nx_l + 2`` columns (x-major) of ``ny_l + 1`` entries: a
ghost column on each side and a ghost entry at the top of each column, which is
also the ghost below the next one; cell ``(i, j)`` is at ``off_l + (r (nx_l + 2) +
i + 1) (ny_l + 1) + j``. The ghosts hold the Dirichlet faces (west: ``Tx`` of the
west ghost column; east and north: ``Tx`` and ``Ty`` of the last cells; south:
``Ty`` of the ghost below) and a correction of 0, so the five-point stencil needs
no branches and no realization reads another's entries.

*Parallel work.* ``realizations`` (the CPU default for grids up to
``REALIZATION_CELLS`` cells): the whole solve of a realization by one thread, in
one kernel launch. ``rows``: every loop over a grid in parallel over segments of
its columns, the levels of at most ``SERIAL_CELLS`` cells cycled one realization
per thread. On the CPU (both ways) a level's smoother runs its half-sweeps in
one pass over the columns, each half-sweep a column behind the one before
(_gmg_cycle._sweeps_pass): a column is fetched once for all of them; ``rows``
does so in blocks of ``_BLOCK`` columns, a thread each, then the seams between
the blocks.
``cells``: in parallel over cells (the default on every GPU). Dot products are
summed the same way in all three, and the three give the same bits.

*Realizations side by side.* A CPU float64 batch solved the ``realizations`` way
runs 4 realizations per thread, each cell's four values one vector in Taichi
fields, which the compiler vectorizes (:mod:`._gmg_lanes`): 1.3-1.4 times the
solves per second with moving bodies, twice without; the same bits.

*Host reads.* One per solve: the report (_gmg_cg._report) after the CG. On a GPU
the CG runs as many iterations as the last solve took before that read, then a
quarter as many at a time (_iterate); the permeability scan is read with the
report unless some realization had cut-off cells at the last solve (solve).

Examples
--------
>>> import numpy as np
>>> from taichi_hsdem import backend
>>> _ = backend.init("cpu", "f64")
>>> solver = TaichiPressureSolver(np.ones((20, 10), bool), 1.0, 1.0, 1.0,
...     bc={"kind": "pressure", "p_in": 1.0, "p_out": 0.0})
>>> p, info = solver.solve(np.ones((20, 10)))
>>> round(float(p[0, 0]), 6), round(float(info.flux_in[0]), 6)  # dp/L = 1/20
(0.975, 0.5)
"""

# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
import time

import numpy as np
from scipy import ndimage

from .. import backend
from ..backend import ti
from .solver import FluxImbalanceError, SolveInfo
from .system import FiniteVolumeSystem
from ._gmg_bodies import BODY_COLUMNS, BodyTerms, Terms, _body_rhs
from ._gmg_cg import (REPORT_COLUMNS, _REPORT_ACTIVE, _REPORT_FLAGS, _REPORT_FLUXES,
                      _boundary_fluxes, _cg_direction, _cg_step, _check_stopped, _copy_row,
                      _mark, _pressure, _report, _residual_check, _solve_each)
from ._gmg_cycle import (CG_ROWS, COARSEST_CELLS, MAXITER, N_CONSTS, N_FLAGS, REAL,
                         REALIZATION_CELLS, SERIAL_CELLS, SWEEPS, _BAD, _BB, _CHANGED, _ITERS,
                         _K_DX, _K_DY, _K_GX, _K_GY, _K_INFLOW, _K_PREF, _K_TOL2, _KEEP,
                         _PARALLEL, _RES, _SOL, _SEGMENT, _SIDE_NAMES, _ZEROS, _restrict,
                         _serial_cycle, _smooth, _smooth_blocks, vec2)
from ._gmg_lanes import Lanes, lanes_pay
from ._gmg_setup import (_assemble, _coarsen, _copy_rhs, _factor, _load_guess, _scan,
                         _set_carried_rhs, _upload)

# The float32 solve (a backend without float64 kernels: Metal, most integrated
# GPUs): its tolerance is at least F32_TOL_FLOOR, it also stops where its residual
# is round-off (_gmg_cg.F32_OPERATOR_FLOOR), and its inflow and outflow need only
# balance to F32_FLUX_FLOOR of the larger flux. Measured (Kozeny-Carman contrast
# 1/60, a quarter of the cells covered, tol 1e-6): the pressure within 7e-6, 5e-5
# and 9e-5 of float64's (pressure inlet; 7e-5 to 1e-3 with a flow-rate inlet) and the
# fluxes balanced to 1.7e-5, 4.7e-4 and 1.6e-3 on grids of 1.1e4, 1.7e5 and 1.1e6
# cells, in 9-19 iterations (tests/test_gmg_f32.py).
F32_TOL_FLOOR = 1e-6
F32_FLUX_FLOOR = 5e-3

# ---------------------------------------------------------------- the solver
class TaichiPressureSolver:
    """Pressure solve for ``n_batch`` permeability fields on one grid, in Taichi.

    A drop-in for :class:`taichi_hsdem.fluid.PressureSolver`: the same arguments,
    boundary conditions, connected-component rules, ``p_ref``, tolerance,
    flux-balance check and warm start; see there. The method is in the module
    docstring.

    Parameters
    ----------
    active, dx, dy, viscosity, bc, n_batch, tol, gap
        As for :class:`~taichi_hsdem.fluid.PressureSolver`.
    workers, pool_after, full_every
        Accepted for compatibility and unused: every realization is solved in
        this process at once, and there is no hierarchy to keep between solves
        (building one costs about one pass over the grid).
    parallel : {"auto", "realizations", "rows", "cells"}
        What one thread does: a whole realization's solve, in one kernel launch
        (``realizations``: no launch or synchronisation costs, for batches and
        small grids on the CPU); a column segment in each grid-sized loop (``rows``:
        cheap index arithmetic, for large grids on the CPU); or a cell (``cells``:
        enough threads for a GPU). ``auto`` picks by backend and grid size
        (:meth:`_choose_parallel`). The three give the same bits (fast math off).
    real : {None, "f64", "f32"}
        The solve's float type: None, float64 where the backend has it, else
        float32 (:func:`taichi_hsdem.backend.solve_real`), whose tolerance is at
        least ``F32_TOL_FLOOR`` and its flux check ``F32_FLUX_FLOOR``.

    Notes
    -----
    *Zero permeability.* A realization with ``kappa == 0`` in connected cells has
    its cut-off cells (docs/model.md: no pressure, NaN) found on the host: its kappa
    is copied there and labelled with :func:`scipy.ndimage.label`, once per
    solve in which it has zeros; everything else stays on the device.

    *Device arrays.* ``kappa`` (and ``x0``, ``carried``, ``occupied``) may be
    Taichi ndarrays of shape ``(R, nx, ny)`` (``(R, nx, ny, 2)``) of any float
    type, e.g. the simulation's own; ``solve(..., host=False)`` returns the
    pressure as this solver's ndarray ``(R, nx, ny)`` instead of a copy
    on the host. Only the per-realization numbers (fluxes, residuals, iteration
    counts) then cross to the host.

    Attributes
    ----------
    connected : numpy.ndarray of bool, shape (nx, ny)
    p_ref : float
    levels : list of (int, int)
        The grid of each multigrid level, finest first.

    Examples
    --------
    The two-halves channel of the PressureSolver example:

    >>> active = np.ones((8, 4), dtype=bool)
    >>> solver = TaichiPressureSolver(active, 1.0, 1.0, 1.0, n_batch=2,
    ...     bc={"kind": "flow_rate", "Q": 2.0, "p_out": 0.0}, gap=0.5)
    >>> kappa = np.ones((2, 8, 4)); kappa[1, 4:] = 0.1
    >>> p, info = solver.solve(kappa)
    >>> np.round(info.flux_out, 8).tolist()
    [4.0, 4.0]
    >>> round(float(p[1, 0, 0] / p[0, 0, 0]), 6)
    5.8
    """

    # Parsing the boundary condition, shaping arrays and the numpy velocity read
    # only the grid attributes this class shares with PressureSolver.
    _set_grid = FiniteVolumeSystem._set_grid
    _parse_bc = FiniteVolumeSystem._parse_bc
    _as_batch = FiniteVolumeSystem._as_batch
    velocity = FiniteVolumeSystem.velocity

    def __init__(self, active, dx, dy, viscosity, bc, n_batch=1, tol=1e-8, gap=None,
                 workers=1, pool_after=None, full_every=None, *, parallel="auto", real=None):
        t_start = time.perf_counter()
        self._set_grid(active, dx, dy, viscosity, n_batch)
        if not 0 < tol < 1:
            raise ValueError(f"tol must lie in (0, 1), got {tol}")
        if parallel not in ("auto", *_PARALLEL):
            raise ValueError(f"parallel must be 'auto' or one of {_PARALLEL}, got {parallel!r}")
        if real not in (None, "f64", "f32"):
            raise ValueError(f"real must be None, 'f64' or 'f32', got {real!r}")
        self.real = ({"f64": ti.f64, "f32": ti.f32}[real] if real is not None
                     else backend.solve_real())
        self._np_real = np.float64 if self.real == ti.f64 else np.float32
        self.requested_tol = float(tol)
        # float32 cannot go below its floors (module constants)
        self.tol = float(tol) if self.real == ti.f64 else max(float(tol), F32_TOL_FLOOR)
        self.flux_floor = 1e-6 if self.real == ti.f64 else F32_FLUX_FLOOR
        self._parse_bc(bc, gap)
        self._sides = self._side_table()
        self.connected, joined = self._anchored(self.active)
        if self.kind == "flow_rate" and not self.connected[0].any():
            raise ValueError(
                "no active cell of the inlet column (x = x_min) is connected to the "
                "outlet (x = x_max): the flow rate cannot pass; check the geometry")
        if self.kind == "pressure" and not joined:
            raise ValueError(
                "no path of active cells joins the inlet (x = x_min) to the "
                "outlet (x = x_max): no flow can pass; check the geometry")
        self.parallel = self._choose_parallel() if parallel == "auto" else parallel
        self._build_levels()
        self._stats = {"solves": 0, "rebuilds": 0, "setup_seconds": 0.0,
                       "solve_seconds": 0.0, "iterations": 0,
                       "init_seconds": time.perf_counter() - t_start}

    # ------------------------------------------------------------------ set-up
    def _choose_parallel(self):
        """``cells`` on a GPU (any backend but the CPU's); on the CPU
        ``realizations`` for grids of at most REALIZATION_CELLS cells, else
        ``rows``. The choice depends on neither the batch size nor the thread
        count, so that a realization gets the same work alone and in a batch."""
        if backend.on_gpu():
            return "cells"
        return "realizations" if self.shape[0] * self.shape[1] <= REALIZATION_CELLS else "rows"

    def _side_table(self):
        """(4, max(nx, ny), 2): per box-side face, the Dirichlet conductance per
        unit permeability (0: wall) and the value minus p_ref."""
        nx, ny = self.shape
        table = np.zeros((4, max(nx, ny), 2))
        factor = {"left": 2 * self.dy / self.dx, "right": 2 * self.dy / self.dx,
                  "bottom": 2 * self.dx / self.dy, "top": 2 * self.dx / self.dy}
        edge = {"left": self.active[0, :], "right": self.active[-1, :],
                "bottom": self.active[:, 0], "top": self.active[:, -1]}
        for s, name in enumerate(_SIDE_NAMES):
            values = self.side_values[name]
            use = edge[name] & np.isfinite(values)
            table[s, :use.size, 0] = np.where(use, factor[name] / self.viscosity, 0.0)
            table[s, :use.size, 1] = np.where(use, values - self.p_ref, 0.0)
        return table

    def _anchored(self, open_cells):
        """The open cells joined to a Dirichlet face through open cells (4-connected),
        and whether a path of open cells joins the left and right sides."""
        labels, count = ndimage.label(open_cells)
        touching = {}
        for s, name in enumerate(_SIDE_NAMES):
            edge = {"left": labels[0, :], "right": labels[-1, :],
                    "bottom": labels[:, 0], "top": labels[:, -1]}[name]
            touching[name] = edge[(self._sides[s, :edge.size, 0] > 0) & (edge > 0)]
        anchored = np.zeros(count + 1, dtype=bool)
        for ids in touching.values():
            anchored[ids] = True
        anchored[0] = False
        joined = np.intersect1d(touching["left"], touching["right"]).size > 0
        return anchored[labels], joined

    def _build_levels(self):
        """Level table, work arrays and the Cholesky storage."""
        R = self.n_batch
        levels = [self.shape]
        while levels[-1][0] * levels[-1][1] > COARSEST_CELLS:
            nx, ny = levels[-1]
            levels.append(((nx + 1) // 2, (ny + 1) // 2))
        self.levels = levels
        sizes = [R * (nx + 2) * (ny + 1) for nx, ny in levels]
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        geo = np.array([[offsets[l], nx, ny] for l, (nx, ny) in enumerate(levels)],
                       dtype=np.int32)
        if offsets[-1] >= 2**31:
            raise ValueError(f"grid too large for 32-bit indices: {offsets[-1]} cells in all")
        # Levels cycled by one thread per realization (see SERIAL_CELLS); the
        # coarsest always is.
        small = SERIAL_CELLS if self.parallel == "rows" else 0
        self._serial_from = next(l for l, (nx, ny) in enumerate(levels)
                                 if nx * ny <= small or l == len(levels) - 1)
        nx, ny = self.shape
        fine = sizes[0]
        self._geo = _upload(geo, ti.i32)
        real = self.real
        self._op = ti.ndarray(vec2(real), (int(offsets[-1]),))
        # realizations side by side (module doc): their own rows replace these
        lanes = (self.parallel == "realizations" and real == ti.f64 and R > 1
                 and not backend.on_gpu() and lanes_pay(R, self.lanes))
        self._mg = ti.ndarray(real, (2, 1 if lanes else int(offsets[-1])))
        self._cg = ti.ndarray(real, (CG_ROWS, fine))
        segments = (ny + _SEGMENT - 1) // _SEGMENT
        self._part = ti.ndarray(real, (2, R * nx * segments))  # the segment sums
        self._state = ti.ndarray(real, (R, 7))
        self._flags = ti.ndarray(ti.i32, (R, N_FLAGS))
        self._report = ti.ndarray(real, (R, REPORT_COLUMNS))
        cm = levels[-1][0] * levels[-1][1]
        self._chol = ti.ndarray(real, (R, cm, cm))
        self._sides_dev = _upload(self._sides, real, vec2(real))
        self._consts = ti.ndarray(real, (N_CONSTS,))
        consts = np.zeros(N_CONSTS)
        consts[[_K_TOL2, _K_DX, _K_DY, _K_PREF, _K_INFLOW, _K_GX, _K_GY]] = (
            self.tol**2, self.dx, self.dy, self.p_ref, self.inflow,
            self.dy / (self.dx * self.viscosity), self.dx / (self.dy * self.viscosity))
        self._consts.from_numpy(consts.astype(self._np_real))
        self._last_iterations = None   # of the last solve (how far to run unread, _iterate)
        self._connected_dev = _upload(self.connected, ti.i8)
        self._unknown_host = np.broadcast_to(self.connected, (R, nx, ny)).copy()
        self._unknown = _upload(self._unknown_host, ti.i8)
        self._seen = _upload(np.full((R, nx * ny), np.nan), real)
        self._kappa_in = ti.ndarray(real, (R, nx, ny))  # a host kappa lands here
        self._inputs = {}  # device copies of the other host inputs, made on first use
        self._out = ti.ndarray(real, (R, nx, ny))
        self._fluxes = ti.ndarray(real, (R, 2))
        self._blocked = np.zeros(R, dtype=bool)
        self._had_zeros = np.zeros(R, dtype=bool)  # zero kappa at the last change
        # stand-ins for the bodies' arrays in solves without them (never read)
        self._no_bodies = Terms(owner=_upload(np.full((1, 1, 1), -1), ti.i32),
                                unknown=self._unknown,
                                body=_upload(np.zeros((1, 1, BODY_COLUMNS)), real),
                                box=_upload(np.full((1, 1, 4), -1), ti.i32))
        self._bodies = None                        # those of the solve under way
        self._terms = None   # their pack (Terms), kept while the same arrays come
        self._lanes = Lanes(levels, R, real) if lanes else None
        self._solved = None   # the realizations solved (``only``), None for all
        self._only = None     # ``only`` on the device, made on first use

    # ------------------------------------------------------------------ public
    def solve(self, kappa, x0=None, carried=None, occupied=None, *, host=True, bodies=None,
              only=None):
        """Pressure for each realization's permeability field.

        As :meth:`taichi_hsdem.fluid.PressureSolver.solve`, which see; in
        addition the inputs may be Taichi ndarrays (class Notes), and with
        ``host=False`` the pressure is returned as this solver's device ndarray
        ``(R, nx, ny)`` of its float type (overwritten by the next solve). With
        ``bodies`` (:class:`BodyTerms`, not with ``carried``) the moving bodies
        carry their volume implicitly: the pressure and their velocities over
        the next interval are solved together (:mod:`._gmg_bodies`). With
        ``only`` (bool, (R,)) the realizations outside it are not set up nor
        iterated: CG leaves their solution and pressure as the last solve left
        them (0 iterations), as a solve of a system that has not changed since
        that one converged would. Leave out only such realizations: the flux
        check is still computed from each one's solution and present kappa.

        Returns
        -------
        pressure : numpy.ndarray or taichi Ndarray
            Pa; NaN in inactive cells and cells cut off from every Dirichlet face.
        info : SolveInfo
            ``rebuilt``: whether any realization's kappa changed, so its
            hierarchy was rebuilt.

        Raises
        ------
        FluxImbalanceError, ValueError
            As for :class:`~taichi_hsdem.fluid.PressureSolver`.

        Examples
        --------
        >>> solver = TaichiPressureSolver(np.ones((4, 3), bool), 1.0, 1.0, 1.0,
        ...     bc={"kind": "pressure", "p_in": 2.0, "p_out": 0.0})
        >>> p, info = solver.solve(np.ones((4, 3)))
        >>> p[:, 0].round(6).tolist()
        [1.75, 1.25, 0.75, 0.25]
        >>> p, info = solver.solve(np.ones((4, 3)))  # converged warm start
        >>> info.rebuilt, info.iterations
        (False, 0)
        """
        t_start = time.perf_counter()
        REAL.dtype = self.real     # the type the kernels compile for (_gmg_cycle._Real)
        if bodies is not None and carried is not None:
            raise ValueError("give carried (the lagged carried flux) or bodies (the "
                             "implicit one), not both")
        k_dev, single = self._device_grid(kappa, "kappa", self._kappa_in)
        self._mark(only)
        _scan(k_dev, self._seen, self._connected_dev, self._flags)
        if self.parallel == "cells" and not self._had_zeros.any():
            # On a GPU (the cells way), with no realization cut off: solve before
            # reading the scan (one read per solve, the report at its end), the
            # operators built anew (the same kappa builds the same operator, bit
            # for bit). Should the scan have found zero or invalid permeabilities,
            # the kept guess is put back and the solve done again the careful way
            # below. On the CPU a read costs less than a rebuild: the scan is read
            # first and the operators built only where kappa changed.
            _copy_row(self._cg, _SOL, _KEEP)
            self._build(k_dev, None, None)
            report = self._solve_system(x0, carried, occupied, bodies, k_dev)
            scan = report[:, _REPORT_FLAGS:_REPORT_FLAGS + N_FLAGS]
            if not (scan[:, _BAD].any() or scan[:, _ZEROS].any()):
                return self._finish(report, scan[:, _CHANGED] > 0, single, host, t_start)
            _copy_row(self._cg, _KEEP, _SOL)
        else:
            scan = self._flags.to_numpy()
        if scan[:, _BAD].any():
            self._report_bad(k_dev)
        changed = scan[:, _CHANGED] > 0
        if changed.any():
            self._build(k_dev, changed, scan[:, _ZEROS] > 0)
        report = self._solve_system(x0, carried, occupied, bodies, k_dev)
        return self._finish(report, changed, single, host, t_start)

    def _mark(self, only):
        """Flag the realizations outside ``only`` (solve) to be skipped."""
        solved = None if only is None else np.asarray(only, dtype=bool)
        if solved is not None and solved.shape != (self.n_batch,):
            raise ValueError(f"only must have shape ({self.n_batch},), got {solved.shape}")
        if solved is not None and solved.all():
            solved = None
        if solved is None and self._solved is None:
            return                          # nothing skipped now or at the last solve
        if self._only is None:
            self._only = ti.ndarray(ti.i32, (self.n_batch,))
        self._only.from_numpy(np.ones(self.n_batch, np.int32) if solved is None
                              else solved.astype(np.int32))
        _mark(self._flags, self._only)
        self._solved = solved

    def _build(self, k_dev, changed, zeros):
        """The cut-off cells of the realizations whose zeros may have moved (given
        ``changed`` and ``zeros``), then their operators (``changed`` None: every
        realization's): the fine one from kappa, the Galerkin levels below, the
        coarse factor."""
        t_setup = time.perf_counter()
        every = int(changed is None)
        if changed is not None:
            self._cut_off(k_dev, changed, zeros)
        _assemble(k_dev, self._unknown, self._sides_dev, self._op, self._cg, self._state,
                  self._geo, self._consts, self._flags, every)
        for l in range(len(self.levels) - 1):
            _coarsen(self._op, self._geo, self._flags, l, every)
        _factor(self._op, self._chol, self._geo, self._flags, len(self.levels) - 1, every)
        self._stats["setup_seconds"] += time.perf_counter() - t_setup

    def _solve_system(self, x0, carried, occupied, bodies, k_dev):
        """Guess, right-hand side, CG and the boundary fluxes; the report (host)."""
        R = self.n_batch
        if x0 is not None:
            x0_dev, _ = self._device_grid(x0, "x0", self._staging("x0", (R, *self.shape)))
            _load_guess(x0_dev, self._unknown, self._cg, self._geo, self._consts)
        self._bodies = bodies
        self._set_rhs(carried, occupied)
        return self._iterate(k_dev)

    def _finish(self, report, changed, single, host, t_start):
        """Flux check, pressure and SolveInfo from the report of a solve."""
        flags = report[:, _REPORT_FLAGS:_REPORT_FLAGS + N_FLAGS]
        iterations = int(flags[:, _ITERS].max())
        self._last_iterations = iterations
        flux_in = report[:, _REPORT_FLUXES].astype(float)
        flux_out = report[:, _REPORT_FLUXES + 1].astype(float)
        bnorm = np.sqrt(report[:, _BB].astype(float))
        limit = max(self.flux_floor, 100.0 * self.tol) * np.maximum.reduce(
            [np.abs(flux_in), np.abs(flux_out), bnorm])
        for r in np.flatnonzero(np.abs(flux_in - flux_out) > limit):
            raise FluxImbalanceError(int(r), float(flux_in[r]), float(flux_out[r]),
                                     float(limit[r]), self.tol)
        _pressure(self._cg, self._unknown, self._out, self._geo, self._consts, self._flags)
        self._stats["solves"] += 1
        self._stats["iterations"] += iterations
        self._stats["rebuilds"] += int(np.sum(changed))
        info = SolveInfo(flux_in=flux_in, flux_out=flux_out, iterations=iterations,
                         residual=float(report[:, _RES].max()), rebuilt=bool(np.any(changed)),
                         blocked=self._blocked.copy())
        pressure = self._out
        if host:
            pressure = self._out.to_numpy().astype(float)
            pressure = pressure[0] if single else pressure
        self._stats["solve_seconds"] += time.perf_counter() - t_start
        return pressure, info

    # ------------------------------------------------------------------ solve steps
    def _device_grid(self, array, name, staging):
        """A per-cell input as an (R, nx, ny) device array; whether the caller gave
        (nx, ny). Host arrays are copied into ``staging``."""
        if isinstance(array, ti.Ndarray):
            expected = (self.n_batch, *self.shape)
            if tuple(array.shape) != expected:
                raise ValueError(f"{name} must have shape {expected}, got {tuple(array.shape)}")
            return array, False
        values, single = self._as_batch(array, name)
        staging.from_numpy(np.ascontiguousarray(values, dtype=self._np_real))
        return staging, single

    def _staging(self, name, shape):
        """A device array of the solve's type for host inputs, made on first use."""
        if name not in self._inputs:
            self._inputs[name] = ti.ndarray(self.real, shape)
        return self._inputs[name]

    def _report_bad(self, k_dev):
        k = k_dev.to_numpy().reshape(self.n_batch, -1)[:, self.connected.ravel()]
        r, c = np.argwhere(~np.isfinite(k) | (k < 0))[0]
        i, j = np.unravel_index(np.flatnonzero(self.connected)[c], self.shape)
        raise ValueError(
            f"kappa of realization {r} is {k[r, c]} in active cell ({i}, {j}); "
            "permeability must be finite and >= 0")

    def _cut_off(self, k_dev, changed, zeros):
        """Unknowns and blocked flags of the realizations whose zero cells may
        have moved (see Notes): on the host, from a copy of their kappa."""
        redo = changed & (zeros | self._had_zeros)
        if not redo.any():
            return
        k = k_dev.to_numpy()
        for r in np.flatnonzero(redo):
            if zeros[r]:
                unknown, joined = self._anchored(self.connected & (k[r] > 0))
                if self.kind == "pressure":
                    blocked = not joined
                elif self.kind == "flow_rate":
                    blocked = (k[r][0] * unknown[0]).sum() <= 0  # no inflow can enter
                else:
                    blocked = False
            else:
                unknown, blocked = self.connected, False
            self._unknown_host[r] = unknown
            self._blocked[r] = blocked
        self._had_zeros[changed] = zeros[changed]
        self._unknown.from_numpy(self._unknown_host.astype(np.int8))

    def _set_rhs(self, carried, occupied):
        if self._bodies is not None:
            self._set_body_rhs(self._bodies)
            return
        if carried is None:
            _copy_rhs(self._cg, self._geo, self.n_batch)
            return
        R, (nx, ny) = self.n_batch, self.shape
        if isinstance(carried, ti.Ndarray):
            c_dev = carried
        else:
            c_dev = self._staging("carried", (R, nx, ny, 2))
            c_dev.from_numpy(np.ascontiguousarray(
                np.asarray(carried, dtype=self._np_real).reshape(R, nx, ny, 2)))
        given = occupied is not None
        if given:
            occ_dev, _ = self._device_grid(occupied, "occupied",
                                           self._staging("occupied", (R, nx, ny)))
        else:  # unused by the kernel: any (R, nx, ny) array
            occ_dev = self._kappa_in
        _set_carried_rhs(self._cg, c_dev, occ_dev, self._connected_dev, self._unknown,
                         self._geo, self._consts, given)

    def _set_body_rhs(self, bodies):
        """The kappa part of the right-hand side plus the bodies' carried flux."""
        R, (nx, ny) = self.n_batch, self.shape
        n = bodies.centre.shape[1]
        for name, shape in (("owner", (R, nx, ny)), ("centre", (R, n, 2)),
                            ("mobility", (R, n, 3)), ("drift", (R, n, 3))):
            got = tuple(getattr(bodies, name).shape)
            if got != shape:
                raise ValueError(f"bodies.{name} must have shape {shape}, got {got}")
        t = self._terms
        if t is None or t["owner"] is not bodies.owner or tuple(t["box"].shape) != (R, n, 4):
            self._terms = t = Terms(owner=bodies.owner, unknown=self._unknown,
                                    body=ti.ndarray(self.real, (R, n, BODY_COLUMNS)),
                                    box=ti.ndarray(ti.i32, (R, n, 4)))
        _body_rhs(self._cg, t, bodies.centre, bodies.mobility, bodies.drift, self._geo,
                  self._consts, self._flags)

    def _body_args(self):
        """(whether the bodies' terms apply, their pack) for the CG kernels."""
        if self._bodies is None:
            return False, self._no_bodies
        return True, self._terms

    def _iterate(self, k_dev):
        """Preconditioned CG of every realization until each meets ``tol`` (or
        MAXITER); the boundary fluxes; the report (:func:`._gmg_cg._report`), read
        on the host.

        The host reads nothing but the report. On a GPU it runs as many CG
        iterations as the last solve took before it first reads (a stopped
        realization is skipped by every kernel, so running on costs launches,
        not bits), then a quarter of that at a time; on the CPU, where a read
        costs no more than a launch, one at a time."""
        arrays = (self._op, self._mg, self._cg, self._part, self._state, self._flags,
                  self._geo)
        maxiter = int(MAXITER)
        body = self._body_args()
        if self._lanes is not None:
            self._lanes.solve(self._op, self._cg, self._state, self._flags, self._geo,
                              self._chol, self._consts, maxiter, body, self._solved)
            return self._read_report(k_dev)
        if self.parallel == "realizations":
            _solve_each(*arrays, self._chol, self._consts, maxiter, *body)
            return self._read_report(k_dev)
        cells = self.parallel == "cells"
        _residual_check(*arrays, self._consts, maxiter, cells, *body)
        if self.parallel == "cells" and self.unread_iterations:
            last = self._last_iterations
            block, then = (8, 2) if last is None else (max(1, last), max(1, last // 4))
        else:
            block = then = 1
        while True:
            for _ in range(block):
                self._precondition()
                _cg_direction(*arrays, cells)
                _cg_step(*arrays, self._consts, maxiter, cells, *body)
                _check_stopped(*arrays, self._consts, maxiter, cells, *body)
            report = self._read_report(k_dev)
            if not report[:, _REPORT_ACTIVE].any():
                return report
            block = then

    #: Whether a GPU solve runs CG iterations unread (see _iterate); False reads
    #: after each, as on the CPU (the same bits).
    unread_iterations = True

    #: Realizations side by side (._gmg_lanes.lanes_pay): "auto" (where they fill
    #: the lanes), True (always) or False (never); the same bits.
    lanes = "auto"

    def _read_report(self, k_dev):
        _boundary_fluxes(k_dev, self._cg, self._unknown, self._sides_dev, self._state,
                         self._fluxes, self._geo, self._consts)
        _report(self._state, self._flags, self._fluxes, self._report)
        return self._report.to_numpy()

    def _precondition(self):
        """``z = M r``: one V-cycle per running realization (module docstring)."""
        cells = self.parallel == "cells"
        arrays = (self._op, self._mg, self._geo, self._flags)
        for l in range(self._serial_from):
            self._smooth(arrays, l, 0)
            _restrict(*arrays, l, cells)
        _serial_cycle(self._op, self._mg, self._chol, self._geo, self._flags,
                      self._serial_from)
        for l in reversed(range(self._serial_from)):
            self._smooth(arrays, l, 1)

    def _smooth(self, arrays, l, post):
        """The pre- (or ``post``-) smoother of level l: the half-sweeps one kernel
        each over cells on a GPU, in blocks of columns, each in one pass, on the
        CPU (the same bits)."""
        if self.parallel == "cells":
            for h in range(2 * SWEEPS):
                _smooth(*arrays, l, h, post)
        else:
            _smooth_blocks(*arrays, l, post)

    def state(self) -> dict:
        """What the next solve depends on beyond its kappa: the last solution (its
        initial guess) and which cells are cut off; :meth:`restore` continues it."""
        return {"solution": self._cg.to_numpy()[_SOL].copy(),
                "unknown": self._unknown_host.copy(), "blocked": self._blocked.copy(),
                "had_zeros": self._had_zeros.copy()}

    def restore(self, state: dict):
        """Continue from :meth:`state`: the operator is rebuilt from the next kappa
        (the same kappa gives the same operator), the guess is the kept solution."""
        cg = self._cg.to_numpy()
        solution = np.asarray(state["solution"], dtype=self._np_real)
        if solution.shape != cg[_SOL].shape:
            raise ValueError(f"solver state has {solution.shape} unknowns, expected "
                             f"{cg[_SOL].shape} (another grid or batch)")
        cg[_SOL] = solution
        self._cg.from_numpy(cg)
        self._unknown_host = np.asarray(state["unknown"]).astype(self._unknown_host.dtype)
        self._unknown.from_numpy(self._unknown_host)
        self._blocked = np.asarray(state["blocked"], dtype=bool).copy()
        self._had_zeros = np.asarray(state["had_zeros"], dtype=bool).copy()
        self._seen.fill(np.nan)            # every realization is re-assembled

    def close(self):
        """Nothing to release beyond the device arrays, which go with the solver;
        here for compatibility with :class:`~taichi_hsdem.fluid.PressureSolver`."""

    @property
    def stats(self):
        """Counters since construction: those of
        :attr:`taichi_hsdem.fluid.PressureSolver.stats` (``rebuilds``: realizations
        whose operators were rebuilt) and ``iterations`` (summed over solves, of
        the slowest realization of each)."""
        return dict(self._stats)

