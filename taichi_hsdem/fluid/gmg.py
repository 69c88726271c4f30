"""Batched geometric-multigrid CG for the Hele-Shaw pressure, in Taichi (issue #22).

:class:`TaichiPressureSolver` solves the finite-volume system of
:class:`taichi_hsdem.fluid.PressureSolver` (docs/model.md section 2: cell-centred
two-point fluxes with the harmonic mean, Dirichlet faces half a cell away, walls
passing no flux) for all ``R`` realizations at once, without assembling a matrix,
in float64 whatever the simulation's precision, on the Taichi backend in use: on
a GPU the fields stay on the device.

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
from there if rounding had made them differ by more than ``tol``.

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
per thread.
``cells``: in parallel over cells (the GPU default). Dot products are summed the
same way in all three.

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
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from ..backend import BackendError, ti
from .solver import FluxImbalanceError, SolveInfo
from .system import FiniteVolumeSystem
from ._gmg_bodies import BODY_COLUMNS, Terms, _body_rhs
from ._gmg_cg import (_boundary_fluxes, _cg_direction, _cg_step, _pressure, _residual_check,
                      _solve_each)
from ._gmg_cycle import (COARSEST_CELLS, MAXITER, OVERCORRECTION, REALIZATION_CELLS,
                         SERIAL_CELLS, SWEEPS, _BAD, _BB, _CHANGED, _ITERS, _PARALLEL, _RES, _SOL,
                         _SEGMENT, _SIDE_NAMES, _ZEROS, _assemble, _coarsen, _copy_rhs,
                         _factor, _load_guess, _restrict, _scan, _serial_cycle,
                         _set_carried_rhs, _smooth, _vec2)

# ---------------------------------------------------------------- the solver
class BodyTerms(NamedTuple):
    """The moving bodies of the implicit carried-volume coupling, for
    :meth:`TaichiPressureSolver.solve` (the equations: :mod:`._gmg_bodies`;
    docs/scene.md, "Carried volume"): Taichi ndarrays, ``R`` realizations of
    ``N`` bodies.

    Attributes
    ----------
    owner : int32 (R, nx, ny)
        The body whose outline holds each cell's centre, -1 for none.
    centre : float64 (R, N, 2)
        Each body's centre in cell units: cell ``(i, j)``'s centre is at ``(i, j)``.
    mobility : float64 (R, N, 3)
        ``H M``: over the next fluid interval the body moves at ``drift -
        mobility S^T (p - p_0)`` (``v_x, v_y, omega``; 0 for a body out of play),
        ``p_0`` the initial guess.
    drift : float64 (R, N, 3)
        That velocity at ``p = p_0``.
    """

    owner: object
    centre: object
    mobility: object
    drift: object


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
        (:meth:`_choose_parallel`). Each is bit-reproducible, but they differ
        from one another in the last bits.

    Notes
    -----
    *Zero permeability.* A realization with ``kappa == 0`` in connected cells has
    its cut-off cells (docs/model.md: no pressure, NaN) found on the host: its kappa
    is copied there and labelled with :func:`scipy.ndimage.label`, once per
    solve in which it has zeros; everything else stays on the device.

    *Device arrays.* ``kappa`` (and ``x0``, ``carried``, ``occupied``) may be
    Taichi ndarrays of shape ``(R, nx, ny)`` (``(R, nx, ny, 2)``) of any float
    type, e.g. the simulation's own; ``solve(..., host=False)`` returns the
    pressure as this solver's float64 ndarray ``(R, nx, ny)`` instead of a copy
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
                 workers=1, pool_after=None, full_every=None, *, parallel="auto"):
        t_start = time.perf_counter()
        self._set_grid(active, dx, dy, viscosity, n_batch)
        if not 0 < tol < 1:
            raise ValueError(f"tol must lie in (0, 1), got {tol}")
        if parallel not in ("auto", *_PARALLEL):
            raise ValueError(f"parallel must be 'auto' or one of {_PARALLEL}, got {parallel!r}")
        arch = ti.lang.impl.current_cfg().arch
        if arch not in (ti.x64, ti.arm64, ti.cuda):
            raise BackendError(f"TaichiPressureSolver solves in float64, which Taichi's {arch.name} "
                               "backend lacks; use fluid.PressureSolver there")
        self.tol = float(tol)
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
        """``cells`` on a CUDA GPU; on the CPU ``realizations`` for grids of at most
        REALIZATION_CELLS cells, else ``rows``. The choice depends on neither the
        batch size nor the thread count: the three ways differ in rounding
        (Taichi compiles with fast math, which may reorder a sum differently in
        different kernels), and a realization must get the same bits alone and
        in a batch."""
        if ti.lang.impl.current_cfg().arch == ti.cuda:
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
        self._op = ti.ndarray(_vec2, (int(offsets[-1]),))
        self._mg = ti.ndarray(ti.f64, (2, int(offsets[-1])))
        self._cg = ti.ndarray(ti.f64, (6, fine))
        segments = (ny + _SEGMENT - 1) // _SEGMENT
        self._part = ti.ndarray(ti.f64, (2, R * nx * segments))  # the segment sums
        self._state = ti.ndarray(ti.f64, (R, 7))
        self._flags = ti.ndarray(ti.i32, (R, 6))
        cm = levels[-1][0] * levels[-1][1]
        self._chol = ti.ndarray(ti.f64, (R, cm, cm))
        self._sides_dev = _upload(self._sides, ti.f64, _vec2)
        self._connected_dev = _upload(self.connected, ti.i8)
        self._unknown_host = np.broadcast_to(self.connected, (R, nx, ny)).copy()
        self._unknown = _upload(self._unknown_host, ti.i8)
        self._seen = _upload(np.full((R, nx * ny), np.nan), ti.f64)
        self._kappa_in = ti.ndarray(ti.f64, (R, nx, ny))  # a host kappa lands here
        self._inputs = {}  # device copies of the other host inputs, made on first use
        self._out = ti.ndarray(ti.f64, (R, nx, ny))
        self._fluxes = ti.ndarray(ti.f64, (R, 2))
        self._blocked = np.zeros(R, dtype=bool)
        self._had_zeros = np.zeros(R, dtype=bool)  # zero kappa at the last change
        # stand-ins for the bodies' arrays in solves without them (never read)
        self._no_bodies = Terms(owner=_upload(np.full((1, 1, 1), -1), ti.i32),
                                unknown=self._unknown,
                                body=_upload(np.zeros((1, 1, BODY_COLUMNS)), ti.f64),
                                box=_upload(np.full((1, 1, 4), -1), ti.i32))
        self._bodies = None                        # those of the solve under way
        self._terms = None   # their pack (Terms), kept while the same arrays come

    # ------------------------------------------------------------------ public
    def solve(self, kappa, x0=None, carried=None, occupied=None, *, host=True, bodies=None):
        """Pressure for each realization's permeability field.

        As :meth:`taichi_hsdem.fluid.PressureSolver.solve`, which see; in
        addition the inputs may be Taichi ndarrays (class Notes), and with
        ``host=False`` the pressure is returned as this solver's device ndarray
        ``(R, nx, ny)`` of float64 (overwritten by the next solve). With
        ``bodies`` (:class:`BodyTerms`, not with ``carried``) the moving bodies
        carry their volume implicitly: the pressure and their velocities over
        the next interval are solved together (:mod:`._gmg_bodies`).

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
        R = self.n_batch
        k_dev, single = self._device_grid(kappa, "kappa", self._kappa_in)
        _scan(k_dev, self._seen, self._connected_dev, self._flags)
        scan = self._flags.to_numpy()
        if scan[:, _BAD].any():
            self._report_bad(k_dev)
        changed = scan[:, _CHANGED] > 0
        zeros = scan[:, _ZEROS] > 0
        if changed.any():
            t_setup = time.perf_counter()
            self._cut_off(k_dev, changed, zeros)
            self._build_operators(k_dev)
            self._stats["rebuilds"] += int(changed.sum())
            self._stats["setup_seconds"] += time.perf_counter() - t_setup
        if x0 is not None:
            x0_dev, _ = self._device_grid(x0, "x0", self._staging("x0", (R, *self.shape)))
            _load_guess(x0_dev, self._unknown, self._cg, self._geo, self.p_ref)
        if bodies is not None and carried is not None:
            raise ValueError("give carried (the lagged carried flux) or bodies (the "
                             "implicit one), not both")
        self._bodies = bodies
        self._set_rhs(carried, occupied)
        self._iterate()
        state = self._state.to_numpy()
        flags = self._flags.to_numpy()
        iterations = int(flags[:, _ITERS].max())
        _boundary_fluxes(k_dev, self._cg, self._unknown, self._sides_dev, self._state,
                         self._fluxes, self._geo, self.inflow)
        fluxes = self._fluxes.to_numpy()
        flux_in, flux_out = fluxes[:, 0].copy(), fluxes[:, 1].copy()
        bnorm = np.sqrt(state[:, _BB])
        limit = max(1e-6, 100.0 * self.tol) * np.maximum.reduce(
            [np.abs(flux_in), np.abs(flux_out), bnorm])
        for r in np.flatnonzero(np.abs(flux_in - flux_out) > limit):
            raise FluxImbalanceError(int(r), float(flux_in[r]), float(flux_out[r]),
                                     float(limit[r]), self.tol)
        _pressure(self._cg, self._unknown, self._out, self._geo, self.p_ref)
        self._stats["solves"] += 1
        self._stats["iterations"] += iterations
        info = SolveInfo(flux_in=flux_in, flux_out=flux_out, iterations=iterations,
                         residual=float(state[:, _RES].max()), rebuilt=bool(changed.any()),
                         blocked=self._blocked.copy())
        pressure = self._out
        if host:
            pressure = self._out.to_numpy()
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
        staging.from_numpy(np.ascontiguousarray(values, dtype=np.float64))
        return staging, single

    def _staging(self, name, shape):
        """A float64 device array for host inputs, made on first use."""
        if name not in self._inputs:
            self._inputs[name] = ti.ndarray(ti.f64, shape)
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

    def _build_operators(self, k_dev):
        """Fine operator from kappa, the Galerkin levels below, the coarse factor."""
        _assemble(k_dev, self._unknown, self._sides_dev, self._op, self._cg, self._state,
                  self._geo, self.dy / (self.dx * self.viscosity),
                  self.dx / (self.dy * self.viscosity), self.inflow)
        for l in range(len(self.levels) - 1):
            _coarsen(self._op, self._geo, l, self.n_batch)
        _factor(self._op, self._chol, self._geo, len(self.levels) - 1)

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
                np.asarray(carried, dtype=np.float64).reshape(R, nx, ny, 2)))
        given = occupied is not None
        if given:
            occ_dev, _ = self._device_grid(occupied, "occupied",
                                           self._staging("occupied", (R, nx, ny)))
        else:  # unused by the kernel: any (R, nx, ny) array
            occ_dev = self._kappa_in
        _set_carried_rhs(self._cg, c_dev, occ_dev, self._connected_dev, self._unknown,
                         self._geo, self.dx, self.dy, given)

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
                                    body=ti.ndarray(ti.f64, (R, n, BODY_COLUMNS)),
                                    box=ti.ndarray(ti.i32, (R, n, 4)))
        _body_rhs(self._cg, t, bodies.centre, bodies.mobility, bodies.drift, self._geo,
                  self.dx, self.dy)

    def _body_args(self):
        """(whether the bodies' terms apply, their pack, dx, dy) for the CG kernels."""
        if self._bodies is None:
            return False, self._no_bodies, self.dx, self.dy
        return True, self._terms, self.dx, self.dy

    def _iterate(self):
        """Preconditioned CG of every realization until each meets ``tol`` (or
        MAXITER)."""
        arrays = (self._op, self._mg, self._cg, self._part, self._state, self._flags,
                  self._geo)
        tol2, maxiter = self.tol**2, int(MAXITER)
        body = self._body_args()
        if self.parallel == "realizations":
            _solve_each(*arrays, self._chol, tol2, maxiter, OVERCORRECTION, *body)
        else:
            cells = self.parallel == "cells"
            running = _residual_check(*arrays, tol2, maxiter, True, cells, *body)
            first = 1
            while running:
                self._precondition()
                _cg_direction(*arrays, first, cells)
                first = 0
                running = _cg_step(*arrays, tol2, maxiter, cells, *body)
                if not running:  # the true residual decides; restart where it drifted
                    running = _residual_check(*arrays, tol2, maxiter, False, cells, *body)
                    first = 1

    def _precondition(self):
        """``z = M r``: one V-cycle per running realization (module docstring)."""
        cells = self.parallel == "cells"
        arrays = (self._op, self._mg, self._geo, self._flags)
        for l in range(self._serial_from):
            for h in range(2 * SWEEPS):
                _smooth(*arrays, l, h, 0, 0.0, cells)
            _restrict(*arrays, l, cells)
        _serial_cycle(self._op, self._mg, self._chol, self._geo, self._flags,
                      self._serial_from, OVERCORRECTION)
        for l in reversed(range(self._serial_from)):
            for h in range(2 * SWEEPS):
                _smooth(*arrays, l, h, 1, OVERCORRECTION, cells)

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
        solution = np.asarray(state["solution"], dtype=np.float64)
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


def _upload(array, dtype, element=None):
    """A device copy of a numpy array (``element``: a vector type for the last axis)."""
    array = np.ascontiguousarray(array)
    shape = array.shape[:-1] if element is not None else array.shape
    out = ti.ndarray(element if element is not None else dtype, shape)
    out.from_numpy(array.astype({ti.f64: np.float64, ti.i32: np.int32, ti.i8: np.int8}[dtype]))
    return out
