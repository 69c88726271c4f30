"""The Hele-Shaw pressure solve (docs/model.md section 2): the finite-volume system of
:mod:`.system` solved by conjugate gradients preconditioned with classical
(Ruge-Stuben) algebraic multigrid, one hierarchy per realization, in this process
or in worker processes (:mod:`.pool`).

Everything here is numpy / scipy / pyamg: the solve runs on the host, once every
``fluid.update_interval`` DEM steps.

Examples
--------
>>> import numpy as np
>>> from taichi_hsdem.fluid import PressureSolver
>>> from taichi_hsdem.laws import free_permeability
>>> active = np.ones((20, 10), dtype=bool)
>>> solver = PressureSolver(active, dx=1.0, dy=1.0, viscosity=1.0,
...                         bc={"kind": "pressure", "p_in": 1.0, "p_out": 0.0})
>>> p, info = solver.solve(np.full(active.shape, free_permeability(1.0)))
>>> round(float(p[0, 0]), 6), round(float(info.flux_in[0]), 6)  # dp/L = 1/20
(0.975, 0.041667)
"""

from __future__ import annotations

import time
import warnings
import weakref
from dataclasses import dataclass

import numpy as np

from . import pool as solver_pool
from .system import FiniteVolumeSystem

# Most preconditioned CG iterations one realization may take in one solve.
# Ruge-Stuben-preconditioned CG needs about 10 for a relative residual of 1e-8 at
# permeability contrasts of 1e3-1e6 on a 160 x 135 grid, so reaching this limit
# means the solve failed; the flux check then reports it. The hierarchy options
# are solver_pool.AMG_OPTIONS.
MAXITER = 200

# Seconds of solving after which a solver with workers > 1 starts using them.
POOL_AFTER_SECONDS = 2.0

# A realization's multigrid hierarchy is built afresh (Ruge-Stuben coarsening) at
# every FULL_EVERY + 1-th change of its matrix; in between it keeps its coarsening
# and only recomputes the Galerkin coarse operators of the new matrix
# (solver_pool.refresh). `python tools/bench_amg.py` on 67 solves of a vani
# realization: 29.1 ms per solve rebuilding every time, 26.3 ms with 8 (8.0 against
# 10.4 CG iterations; 4: 26.7 ms, 16: 27.8 ms), pressures within 2.3e-10 of the
# pressure range of each other. A modest gain: the V-cycles, not the set-up, cost most.
FULL_EVERY = 8


class FluxImbalanceError(RuntimeError):
    """The inflow and outflow of a solved realization do not balance.

    Attributes
    ----------
    realization : int
    flux_in, flux_out : float
        Per unit depth, m^2/s.
    limit : float
        The largest imbalance that was accepted, m^2/s.
    """

    def __init__(self, realization, flux_in, flux_out, limit, tol):
        self.realization = realization
        self.flux_in = flux_in
        self.flux_out = flux_out
        self.limit = limit
        super().__init__(
            f"pressure solve of realization {realization} does not conserve mass: "
            f"inflow {flux_in:.6g}, outflow {flux_out:.6g} (per unit depth), imbalance "
            f"{abs(flux_in - flux_out):.3g} > {limit:.3g} allowed for solver tolerance "
            f"{tol:g}. The multigrid solve did not converge (see PressureSolver's maxiter); check the "
            "permeability field for zeros or extreme contrasts, or loosen "
            "fluid.solver_tol")


@dataclass
class SolveInfo:
    """What one :meth:`PressureSolver.solve` did.

    Attributes
    ----------
    flux_in, flux_out : numpy.ndarray, shape (R,)
        Total flow per unit depth (m^2/s) into and out of the domain through its
        boundary faces, per realization: the sums of the inward and of the outward
        face fluxes. With the ``pressure`` and ``flow_rate`` conditions and
        ``p_in >= p_out`` these are the inlet and outlet flow rates.
    iterations : int
        Preconditioned CG iterations of the slowest realization (0: the warm
        start already met the tolerance).
    residual : float
        Largest relative residual ``|b - A p| / |b|`` over the realizations.
    rebuilt : bool
        Whether any realization's multigrid hierarchy was rebuilt.
    blocked : numpy.ndarray of bool, shape (R,)
        Realizations in which no open path joins the inlet to the outlet (only
        possible where ``kappa == 0``); their ``flux_in`` and ``flux_out`` are 0.
        Always False for the ``dirichlet`` condition.
    """

    flux_in: np.ndarray
    flux_out: np.ndarray
    iterations: int
    residual: float
    rebuilt: bool
    blocked: np.ndarray


class PressureSolver(FiniteVolumeSystem):
    """Pressure solve for ``n_batch`` permeability fields on one grid.

    Everything that depends only on the grid and the boundary condition (which
    cells are unknowns, the face lists, the sparsity pattern) is built here once;
    :meth:`solve` only fills in values.

    Parameters
    ----------
    active : array_like of bool, shape (nx, ny)
        Fluid cells. Inactive cells (walls) are not unknowns and pass no flux.
        Active cells that no Dirichlet face can reach (pockets sealed off by walls)
        have no determined pressure: they are treated as walls too (see
        :attr:`connected`).
    dx, dy : float
        Cell size, m.
    viscosity : float
        ``eta``, Pa s.
    bc : dict
        One of

        * ``{"kind": "pressure", "p_in": float, "p_out": float}``: ``p_in`` on the
          ``x = x_min`` faces of the active cells of column 0, ``p_out`` on the
          ``x = x_max`` faces of the last column; every other box side is a wall.
        * ``{"kind": "flow_rate", "Q": float, "p_out": float}``: a total inflow
          per unit depth ``q = Q / gap`` through the ``x = x_min`` faces of
          column 0, shared among the inlet cells in proportion to ``kappa dy``
          (as a uniform gradient would share it), ``p_out`` at the outlet.
        * ``{"kind": "dirichlet", "left": (ny,) | None, "right": (ny,) | None,
          "bottom": (nx,) | None, "top": (nx,) | None}``: a pressure per face on
          each box side given, ``None`` for a wall (for exact-solution tests).
    n_batch : int
        Number of realizations ``R`` solved together.
    tol : float
        Relative residual ``|b - A p| / |b|`` of the CG solve, in (0, 1).
    gap : float, optional
        Plate spacing ``H``, m; needed for ``flow_rate``.
    workers : int
        Processes that share the realizations' solves (1: all in this process).
        Each realization is solved the same way wherever it runs, so the answer
        does not depend on ``workers``; if a worker fails, the solver warns and
        goes on in this process. See :mod:`taichi_hsdem.fluid.pool`.
    pool_after : float
        Solve in this process until the solves have taken this many seconds, then
        move to the workers: starting a worker costs about a second of CPU (its
        imports), which a short run never earns back.
    full_every : int
        Refreshes of a hierarchy's coarse operators between two full Ruge-Stuben
        builds (see ``FULL_EVERY``).
    maxiter : int
        Most CG iterations one realization may take in one solve (see ``MAXITER``);
        a solve that stops there fails the flux check.

    Notes
    -----
    *One hierarchy per realization.* The realizations share one sparsity pattern
    (the block-diagonal matrix's blocks are alike), but each realization gets its
    own Ruge-Stuben hierarchy and CG solve, in this process or in the worker
    process that owns it (realization ``r`` goes to worker ``r % workers``). On a 160 x 135 grid at a contrast of
    1e3 this costs about what one hierarchy of the block-diagonal matrix does
    (R = 10, best of 7: set-up 0.26 s against 0.25 s, cold solve 0.35 s against
    0.31 s), and it lets a realization whose permeability did not change keep its
    hierarchy, and makes the tolerance hold for each realization rather than for
    the batch. A hierarchy is rebuilt whenever the permeability changes: the old
    one as a preconditioner for the new matrix did not converge in 200 iterations
    after disks of contrast 1e3 moved by up to half a cell.

    *Flux check.* Summing the cell equations, the interior fluxes cancel, so
    ``flux_in - flux_out`` is the sum of the residual ``b - A p``: a solve that
    met its relative tolerance leaves an imbalance of about ``tol |b|`` (measured:
    0.03-1 times). :meth:`solve` raises :class:`FluxImbalanceError` when
    ``|in - out| > max(1e-6, 100 tol) * max(|in|, |out|, |b|)``. The floor ``|b|``
    (the right-hand side's norm, a flux) keeps a converged solve of a nearly
    clogged channel, whose through-flow is tiny against ``|b|``, from being
    reported (without it a band of contrast 1e-3 across the channel fails at
    ``tol = 1e-8``).

    *Blocked realizations.* Where ``kappa == 0`` in active cells, every group of
    cells cut off from all Dirichlet faces (and every zero-permeability cell) gets
    NaN pressure and zero velocity; a part reachable only from the inlet takes
    ``p_in``. A realization with no open path from inlet to outlet is flagged in
    :attr:`SolveInfo.blocked`, with zero fluxes; with ``flow_rate`` its inflow
    cannot be delivered and is dropped (``flux_in = 0``), nothing is raised.

    Attributes
    ----------
    connected : numpy.ndarray of bool, shape (nx, ny)
        The active cells that carry a pressure unknown (active and joined to a
        Dirichlet face through active cells).
    p_ref : float
        The pressure the solve is referred to (mid-range of the Dirichlet values).

    Examples
    --------
    A channel of two halves, the right one ten times less permeable, two
    realizations at once:

    >>> active = np.ones((8, 4), dtype=bool)
    >>> solver = PressureSolver(active, 1.0, 1.0, 1.0, n_batch=2,
    ...     bc={"kind": "flow_rate", "Q": 2.0, "p_out": 0.0}, gap=0.5)
    >>> kappa = np.ones((2, 8, 4)); kappa[1, 4:] = 0.1
    >>> p, info = solver.solve(kappa)
    >>> np.round(info.flux_out, 8).tolist()  # Q / gap
    [4.0, 4.0]
    >>> round(float(p[1, 0, 0] / p[0, 0, 0]), 6)  # (3 + 5.5 + 30 + 5) / 7.5
    5.8
    """

    def __init__(self, active, dx, dy, viscosity, bc, n_batch=1, tol=1e-8, gap=None,
                 workers=1, pool_after=POOL_AFTER_SECONDS, full_every=FULL_EVERY,
                 maxiter=MAXITER):
        t_start = time.perf_counter()
        if not 0 < tol < 1:
            raise ValueError(f"tol must lie in (0, 1), got {tol}")
        if not (isinstance(workers, (int, np.integer)) and workers >= 1):
            raise ValueError(f"workers must be an int >= 1, got {workers}")
        if not (isinstance(full_every, (int, np.integer)) and full_every >= 0):
            raise ValueError(f"full_every must be an int >= 0, got {full_every}")
        super().__init__(active, dx, dy, viscosity, bc, n_batch, gap)
        self.tol = float(tol)
        self.workers = int(min(workers, self.n_batch))
        self.pool_after = float(pool_after)
        self.full_every = int(full_every)
        self.maxiter = int(maxiter)
        self._pool = solver_pool.pool()
        self._token = self._pool.token()
        self._pattern_at = set()  # where the pattern was sent: "local" or (generation, w)
        self._finalizer = weakref.finalize(self, _release, self._token)
        self._finalizer.atexit = False
        self._stats = {"solves": 0, "rebuilds": 0, "setup_seconds": 0.0,
                       "solve_seconds": 0.0,
                       "init_seconds": time.perf_counter() - t_start}
        self._restored = {}   # realization -> ops that rebuild its hierarchy (see restore)

    # ------------------------------------------------------------------ set-up





    def solve(self, kappa, x0=None, carried=None, occupied=None):
        """Pressure for each realization's permeability field.

        With ``carried`` (the volume flux that moving particles carry, ``chi v``,
        m/s, shape ``kappa.shape + (2,)``), the mixture is conserved rather than
        the fluid alone: ``div((kappa/eta) grad p) = div(chi v)``, so a particle
        moving with the flow displaces no fluid around itself. ``occupied`` (bool,
        ``kappa``'s shape) marks the cells inside particles: a face with a particle
        cell on either side moves with it, carrying the mean of ``chi v`` over its
        occupied sides (half the particle's velocity on a particle's edge would
        push the other half through the particle's low permeability); faces on the
        boundary carry nothing, so the carried fluxes sum to zero over the domain
        and inflow still equals outflow.

        Parameters
        ----------
        kappa : array_like, shape (R, nx, ny), or (nx, ny) when ``n_batch == 1``
            Permeability, m^2, >= 0 and finite in active cells (0: impermeable);
            values in inactive cells are ignored. A realization whose ``kappa`` on
            the active cells differs from the previous call gets a new multigrid
            hierarchy; an identical one keeps its own.
        x0 : array_like, same shape as ``kappa``, optional
            Initial guess (NaN allowed where there is no pressure). Default: the
            last solution (zero pressure difference on the first call).

        Returns
        -------
        pressure : numpy.ndarray, same shape as ``kappa``
            Pa; NaN in inactive cells and cells cut off from every Dirichlet face.
        info : SolveInfo

        Raises
        ------
        FluxImbalanceError
            If a realization's inflow and outflow do not balance (see Notes of
            :class:`PressureSolver`).
        ValueError
            If ``kappa`` has the wrong shape or a negative or non-finite value in
            an active cell.

        Examples
        --------
        >>> solver = PressureSolver(np.ones((4, 3), bool), 1.0, 1.0, 1.0,
        ...     bc={"kind": "pressure", "p_in": 2.0, "p_out": 0.0})
        >>> p, info = solver.solve(np.ones((4, 3)))
        >>> p[:, 0].round(6).tolist()
        [1.75, 1.25, 0.75, 0.25]
        >>> p, info = solver.solve(np.ones((4, 3)))  # same kappa: same hierarchy
        >>> info.rebuilt, info.iterations
        (False, 0)
        """
        t_start = time.perf_counter()
        k3, single = self._as_batch(kappa, "kappa")
        R = self.n_batch
        k = k3.reshape(R, -1)[:, self._cells]
        bad = ~np.isfinite(k) | (k < 0)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            i, j = np.unravel_index(self._cells[c], self.shape)
            raise ValueError(
                f"kappa of realization {r} is {k[r, c]} in active cell ({i}, {j}); "
                "permeability must be finite and >= 0")

        changed = np.flatnonzero(~np.all(k == self._kappa_seen, axis=1))
        if changed.size:
            t_setup = time.perf_counter()
            self._assemble(changed, k[changed])
            self._kappa_seen[changed] = k[changed]
            self._stats["rebuilds"] += changed.size
            self._stats["setup_seconds"] += time.perf_counter() - t_setup

        if x0 is None:
            guess = self._last.copy()
        else:
            guess = self._as_batch(x0, "x0")[0].reshape(R, -1)[:, self._cells] - self.p_ref
            guess = np.nan_to_num(guess, nan=0.0)
        guess[self._pinned] = 0.0

        rhs = self._rhs
        if carried is not None:
            rhs = rhs + self._carried_source(carried, occupied)
            rhs[self._pinned] = 0.0
        ops = self._hierarchy_ops(changed)
        for r, before in self._restored.items():     # hierarchies as at the checkpoint
            ops[r] = before + ops.get(r, [])
        x, its, res = self._solve_all(ops, rhs, guess)
        self._restored = {}
        iterations, residual = int(its.max(initial=0)), float(res.max(initial=0.0))
        bnorm = np.linalg.norm(rhs, axis=1)
        self._last = x

        flux_in, flux_out = self._boundary_fluxes(x, k)
        limit = max(1e-6, 100.0 * self.tol) * np.maximum.reduce(
            [np.abs(flux_in), np.abs(flux_out), bnorm])
        for r in np.flatnonzero(np.abs(flux_in - flux_out) > limit):
            raise FluxImbalanceError(int(r), float(flux_in[r]), float(flux_out[r]),
                                     float(limit[r]), self.tol)

        pressure = np.full((R, self.shape[0] * self.shape[1]), np.nan)
        pressure[:, self._cells] = np.where(self._pinned, np.nan, x + self.p_ref)
        pressure = pressure.reshape(R, *self.shape)
        self._stats["solves"] += 1
        self._stats["solve_seconds"] += time.perf_counter() - t_start
        info = SolveInfo(flux_in=flux_in, flux_out=flux_out, iterations=int(iterations),
                         residual=float(residual), rebuilt=bool(changed.size),
                         blocked=self._blocked.copy())
        return (pressure[0] if single else pressure), info

    def _hierarchy_ops(self, changed):
        """What to do to the hierarchies of the realizations whose matrix changed:
        ``{r: [("full" | "refresh", values)]}`` (see solver_pool.solve_block)."""
        ops = {}
        for r in (int(r) for r in changed):
            if self._since[r] < 0 or self._since[r] >= self.full_every:
                self._base[r] = self._data[r]
                self._since[r] = 0
                ops[r] = [("full", self._data[r])]
            else:
                self._since[r] += 1
                ops[r] = [("refresh", self._data[r])]
        return ops

    def _recreate_ops(self, r):
        """Ops that give a process with nothing of realization ``r`` the very
        hierarchy it has: built from the same matrix, refreshed to the current one."""
        ops = [("full", self._base[r])]
        if self._since[r] > 0:
            ops.append(("refresh", self._data[r]))
        return ops

    def _solve_all(self, ops, rhs, guess):
        """Solve every realization, in worker processes when ``workers > 1``,
        after applying ``ops`` to the hierarchies. Returns x (R, n), iterations
        (R,), relative residuals (R,)."""
        R = self.n_batch
        if self.workers > 1 and self._stats["solve_seconds"] >= self.pool_after:
            try:
                return self._solve_pooled(ops, rhs, guess)
            except solver_pool.PoolError as exc:
                warnings.warn(f"{exc}\nthe pressure solves go on in this process "
                              "(fluid.workers = 1)", RuntimeWarning, stacklevel=3)
                self.workers = 1
                # the workers' hierarchies are gone
                ops = {r: self._recreate_ops(r) for r in range(R)}
        pattern = None if "local" in self._pattern_at else self._pattern()
        self._pattern_at.add("local")
        x, its, res, setup = solver_pool.solve_block(
            self._token, pattern, range(R), ops, rhs, guess, self.tol, self.maxiter)
        self._stats["setup_seconds"] += setup
        return x, its, res

    def _solve_pooled(self, ops, rhs, guess):
        R, W = self.n_batch, self.workers
        generation = self._pool.generation
        calls, owned = [], []
        for w in range(W):
            rows = list(range(w, R, W))
            first = (generation, w) not in self._pattern_at
            if first:  # a new worker knows nothing: the pattern and every hierarchy
                send = {r: self._recreate_ops(r) for r in rows}
            else:
                send = {r: ops[r] for r in rows if r in ops}
            calls.append(("solve_block", (
                self._token, self._pattern() if first else None, rows,
                send, rhs[rows], guess[rows], self.tol, self.maxiter)))
            owned.append(rows)
        replies = self._pool.map(calls)  # raises PoolError if any worker failed
        self._pattern_at.update((generation, w) for w in range(W))
        if "local" in self._pattern_at:  # the solves have moved: free the copies here
            solver_pool.forget(self._token)
            self._pattern_at.discard("local")
        x = np.zeros((R, self._n))
        its, res = np.zeros(R, dtype=int), np.zeros(R)
        for rows, (xw, itw, rw, setup) in zip(owned, replies):
            x[rows], its[rows], res[rows] = xw, itw, rw
        self._stats["setup_seconds"] += max(reply[3] for reply in replies)
        return x, its, res

    # What a later solve depends on: the matrices and right-hand sides filled in so
    # far, the matrix each hierarchy was coarsened from and its refreshes since, and
    # the last solution (the next solve's initial guess).
    _STATE = ("_kappa_seen", "_data", "_rhs", "_pinned", "_blocked", "_share", "_last",
              "_base", "_since")

    def state(self) -> dict:
        """Arrays that make a solver of the same grid continue exactly as this one
        (:meth:`restore`): the next solve gives the same bits."""
        return {name: getattr(self, name).copy() for name in self._STATE}

    def restore(self, state: dict):
        """Continue from :meth:`state`. The hierarchies are rebuilt from the kept
        matrices at the next solve (the same coarsening and operators, so the same
        solve), here or in the workers, which are told nothing is known."""
        for name in self._STATE:
            value = np.asarray(state[name])
            if value.shape != getattr(self, name).shape:
                raise ValueError(f"solver state {name} has shape {value.shape}, expected "
                                 f"{getattr(self, name).shape} (another grid or batch)")
            setattr(self, name, value.astype(getattr(self, name).dtype, copy=True))
        self.close()                        # forget what this process and the workers hold
        self._finalizer = weakref.finalize(self, _release, self._token)
        self._finalizer.atexit = False
        self._pattern_at = set()
        self._restored = {r: self._recreate_ops(r) for r in range(self.n_batch)
                          if self._since[r] >= 0}

    def _pattern(self):
        return (self._n, self._indptr, self._indices)

    def close(self):
        """Free this solver's hierarchies here and in the worker processes (also
        done when the solver is garbage-collected)."""
        self._finalizer()



    @property
    def stats(self):
        """Counters since construction.

        ``solves`` (calls to :meth:`solve`), ``rebuilds`` (multigrid hierarchies
        built, one per realization whose permeability changed), ``setup_seconds``
        (assembly and hierarchy set-up, part of ``solve_seconds``),
        ``solve_seconds`` (wall time inside :meth:`solve`), ``init_seconds``
        (building the sparsity pattern).
        """
        return dict(self._stats)


def _release(token):
    solver_pool.forget(token)
    solver_pool.pool().forget(token)



# ---------------------------------------------------------------- verification
