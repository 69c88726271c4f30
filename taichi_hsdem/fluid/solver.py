"""Hele-Shaw (depth-averaged Darcy) pressure solve on a fixed grid (MODEL.md section 2).

The fluid obeys ``div u = 0`` and ``u = -(kappa / eta) grad p``, per unit depth of
the gap. Cell-centred finite volumes on a uniform grid of ``nx x ny`` cells; every
array is x-first: ``kappa[i, j]`` belongs to the cell centred at
``(x0 + (i + 0.5) dx, y0 + (j + 0.5) dy)``. The flux through a face between two
cells is the two-point flux with the harmonic mean of their permeabilities,

    F = T (p_1 - p_2),   T = 2 k_1 k_2 / (k_1 + k_2) * (dy / dx) / eta   (x-faces),

a Dirichlet face sits half a cell from its cell centre (``T = k (dy / (dx / 2)) /
eta``), and a wall (an inactive cell, or a box side without a value) passes no flux.
The matrix is symmetric positive definite and is solved with classical
(Ruge-Stuben) algebraic multigrid as a preconditioner for conjugate gradients.

Everything here is numpy / scipy / pyamg: the solve runs on the host, once every
``fluid.update_interval`` DEM steps.

Examples
--------
>>> import numpy as np
>>> from taichi_hsdem.fluid import PressureSolver, free_permeability
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
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from . import pool as solver_pool
from ..laws import free_permeability, harmonic_mean, kozeny_carman  # noqa: F401 (re-exported)

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

_SIDES = ("left", "right", "bottom", "top")


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


class PressureSolver:
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
        active = np.array(active, dtype=bool)  # a copy: the caller may reuse theirs
        if active.ndim != 2:
            raise ValueError(f"active must be a 2D (nx, ny) array, got shape {active.shape}")
        for name, value in (("dx", dx), ("dy", dy), ("viscosity", viscosity)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        if not (isinstance(n_batch, (int, np.integer)) and n_batch >= 1):
            raise ValueError(f"n_batch must be an int >= 1, got {n_batch}")
        if not 0 < tol < 1:
            raise ValueError(f"tol must lie in (0, 1), got {tol}")
        if not (isinstance(workers, (int, np.integer)) and workers >= 1):
            raise ValueError(f"workers must be an int >= 1, got {workers}")
        self.shape = active.shape
        self.dx, self.dy, self.viscosity = float(dx), float(dy), float(viscosity)
        self.n_batch, self.tol = int(n_batch), float(tol)
        self.active = active
        self._parse_bc(bc, gap)
        self._build_pattern()
        self.workers = int(min(workers, self.n_batch))
        self.pool_after = float(pool_after)
        if not (isinstance(full_every, (int, np.integer)) and full_every >= 0):
            raise ValueError(f"full_every must be an int >= 0, got {full_every}")
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

    # ------------------------------------------------------------------ set-up
    def _parse_bc(self, bc, gap):
        """Turn ``bc`` into one Dirichlet value per box-side face (NaN: wall)."""
        nx, ny = self.shape
        kind = bc.get("kind") if isinstance(bc, dict) else None
        length = {"left": ny, "right": ny, "bottom": nx, "top": nx}
        side = {s: np.full(length[s], np.nan) for s in _SIDES}
        self.inflow = 0.0  # flow per unit depth through column 0, flow_rate only
        if kind == "pressure":
            _require(bc, ("p_in", "p_out"), kind)
            side["left"][:] = bc["p_in"]
            side["right"][:] = bc["p_out"]
        elif kind == "flow_rate":
            _require(bc, ("Q", "p_out"), kind)
            if gap is None or not (np.isfinite(gap) and gap > 0):
                raise ValueError(f"the flow_rate condition needs gap > 0, got {gap}")
            self.inflow = float(bc["Q"]) / float(gap)
            side["right"][:] = bc["p_out"]
        elif kind == "dirichlet":
            unknown = set(bc) - {"kind", *_SIDES}
            if unknown:
                raise ValueError(f"unknown keys in the dirichlet condition: {sorted(unknown)}")
            for s in _SIDES:
                if bc.get(s) is not None:
                    values = np.asarray(bc[s], dtype=float)
                    if values.shape != (length[s],):
                        raise ValueError(
                            f"dirichlet '{s}' needs {length[s]} values, got shape {values.shape}")
                    if not np.all(np.isfinite(values)):
                        raise ValueError(f"dirichlet '{s}' values must be finite")
                    side[s][:] = values
        else:
            raise ValueError(
                f"bc kind must be 'pressure', 'flow_rate' or 'dirichlet', got {kind!r}")
        given = np.concatenate(list(side.values()))
        if not np.any(np.isfinite(given)):
            raise ValueError(
                "the dirichlet condition needs at least one side with pressure values "
                "(without one the pressure is undetermined)")
        self.kind = kind
        self.side_values = side
        # Solving for p - p_ref keeps the right-hand side a pressure *difference*:
        # the relative tolerance then bounds the flux error even where the
        # pressures carry a large offset (an ambient 1e5 Pa under a 10 Pa drop).
        finite = given[np.isfinite(given)]
        self.p_ref = 0.5 * (finite.min() + finite.max())

    def _build_pattern(self):
        nx, ny = self.shape
        dx, dy = self.dx, self.dy
        flat = np.arange(nx * ny).reshape(nx, ny)

        # Dirichlet faces on the box sides: (grid cell, dx/2-distance factor, value, side).
        face_cells, face_factor, face_value, face_side = [], [], [], []
        border = {"left": (flat[0, :], 2 * dy / dx), "right": (flat[-1, :], 2 * dy / dx),
                  "bottom": (flat[:, 0], 2 * dx / dy), "top": (flat[:, -1], 2 * dx / dy)}
        for code, s in enumerate(_SIDES):
            cells, factor = border[s]
            use = self.active.ravel()[cells] & np.isfinite(self.side_values[s])
            face_cells.append(cells[use])
            face_factor.append(np.full(use.sum(), factor))
            face_value.append(self.side_values[s][use])
            face_side.append(np.full(use.sum(), code))
        d_cells = np.concatenate(face_cells)

        # Interior faces between two active cells: x-faces then y-faces.
        act = self.active
        fx = act[:-1, :] & act[1:, :]
        fy = act[:, :-1] & act[:, 1:]
        fa = np.concatenate([flat[:-1, :][fx], flat[:, :-1][fy]])
        fb = np.concatenate([flat[1:, :][fx], flat[:, 1:][fy]])
        fg = np.concatenate([np.full(fx.sum(), dy / dx), np.full(fy.sum(), dx / dy)])
        f_is_x = np.concatenate([np.ones(fx.sum(), bool), np.zeros(fy.sum(), bool)])

        # Drop the active cells no Dirichlet face can reach: their pressure is
        # undetermined (a singular block) and no flow passes through them.
        graph = sp.coo_array((np.ones(fa.size), (fa, fb)), shape=(nx * ny, nx * ny))
        _, labels = connected_components(graph, directed=False)
        anchored = np.zeros(labels.max() + 1, dtype=bool)
        anchored[labels[d_cells]] = True
        connected = act.ravel() & anchored[labels]
        inlet = connected[flat[0, :]] if self.kind == "flow_rate" else np.zeros(ny, bool)
        if self.kind == "flow_rate" and not inlet.any():
            raise ValueError(
                "no active cell of the inlet column (x = x_min) is connected to the "
                "outlet (x = x_max): the flow rate cannot pass; check the geometry")
        if self.kind == "pressure":
            codes = np.concatenate(face_side)
            reach_in = np.zeros_like(anchored)
            reach_in[labels[d_cells[codes == 0]]] = True
            if not reach_in[labels[d_cells[codes == 1]]].any():
                raise ValueError(
                    "no path of active cells joins the inlet (x = x_min) to the "
                    "outlet (x = x_max): no flow can pass; check the geometry")
        self.connected = connected.reshape(nx, ny)

        # Number the unknowns; keep only faces between connected cells.
        self._cells = np.flatnonzero(connected)
        n = self._cells.size
        number = np.full(nx * ny, -1)
        number[self._cells] = np.arange(n)
        keep = connected[fa]  # both ends share a component
        self._fa, self._fb, self._fg = number[fa[keep]], number[fb[keep]], fg[keep]
        self._f_is_x = f_is_x[keep]
        self._dc = number[d_cells]
        self._dg = np.concatenate(face_factor)
        self._dv = np.concatenate(face_value) - self.p_ref
        self._dside = np.concatenate(face_side)
        self._ic = number[flat[0, :][inlet]]
        self._n = n

        # Sparsity pattern of one block: diagonal, then each face twice. Building
        # the CSR once from entry ids gives the permutation that refills it.
        rows = np.concatenate([np.arange(n), self._fa, self._fb])
        cols = np.concatenate([np.arange(n), self._fb, self._fa])
        ids = np.arange(1, rows.size + 1, dtype=float)
        pattern = sp.csr_array((ids, (rows, cols)), shape=(n, n))
        pattern.sort_indices()
        self._perm = pattern.data.astype(np.int64) - 1
        self._indptr, self._indices = pattern.indptr, pattern.indices

        R = self.n_batch
        self._kappa_seen = np.full((R, n), np.nan)  # NaN: every realization is new
        self._data = np.zeros((R, self._perm.size))  # CSR values of each realization
        self._rhs = np.zeros((R, n))
        self._pinned = np.zeros((R, n), dtype=bool)
        self._blocked = np.zeros(R, dtype=bool)
        self._share = np.zeros((R, self._ic.size))  # flow_rate inflow per inlet cell
        self._last = np.zeros((R, n))  # last solution, p - p_ref
        # the matrix each hierarchy was coarsened from, and refreshes since (-1: none)
        self._base = np.zeros_like(self._data)
        self._since = np.full(R, -1)

    # ------------------------------------------------------------------ helpers
    def _as_batch(self, array, name):
        """(R, nx, ny) view of a per-cell array; whether the caller gave (nx, ny)."""
        array = np.asarray(array, dtype=float)
        if array.shape == self.shape and self.n_batch == 1:
            return array[None], True
        if array.shape == (self.n_batch, *self.shape):
            return array, False
        raise ValueError(
            f"{name} must have shape {(self.n_batch, *self.shape)}"
            + (f" or {self.shape}" if self.n_batch == 1 else "") + f", got {array.shape}")

    def _assemble(self, which, kappa):
        """Matrices, right-hand sides and hierarchies of realizations ``which``.

        ``kappa`` is (len(which), n): the permeability of the unknowns.
        """
        n, eta = self._n, self.viscosity
        m = len(which)
        T = self._fg * harmonic_mean(kappa[:, self._fa], kappa[:, self._fb]) / eta
        Td = self._dg * kappa[:, self._dc] / eta
        weight = kappa[:, self._ic]  # inflow shares; the uniform dy cancels
        pinned = np.zeros((m, n), dtype=bool)
        blocked = np.zeros(m, dtype=bool)
        for row in np.flatnonzero((kappa == 0).any(axis=1)):
            pinned[row], blocked[row] = self._cut_off(T[row], Td[row])
        if pinned.any():
            # A pinned group is decoupled: identity rows, zero right-hand side.
            T[pinned[:, self._fa] | pinned[:, self._fb]] = 0.0
            Td[pinned[:, self._dc]] = 0.0
            weight = np.where(pinned[:, self._ic], 0.0, weight)

        offset = (np.arange(m) * n)[:, None]
        diagonal = (np.bincount((offset + self._fa).ravel(), T.ravel(), m * n)
                    + np.bincount((offset + self._fb).ravel(), T.ravel(), m * n)
                    + np.bincount((offset + self._dc).ravel(), Td.ravel(), m * n)).reshape(m, n)
        diagonal[pinned] = 1.0
        rhs = np.bincount((offset + self._dc).ravel(), (Td * self._dv).ravel(),
                          m * n).reshape(m, n)
        if self.inflow != 0.0:
            total = weight.sum(axis=1, keepdims=True)
            share = np.divide(self.inflow * weight, total, out=np.zeros_like(weight),
                              where=total > 0)
            rhs[:, self._ic] += share
            self._share[which] = share
            blocked |= total[:, 0] == 0
        # Row-major rows: pyamg's C++ core reads a strided row (fancy indexing can
        # lay `data` out column-major) as garbage.
        self._data[which] = np.concatenate([diagonal, -T, -T], axis=1)[:, self._perm]
        self._rhs[which] = rhs
        self._pinned[which] = pinned
        self._blocked[which] = blocked

    def _cut_off(self, T, Td):
        """Cells with no open path to a Dirichlet face, and whether inlet and
        outlet are disconnected, for one realization with zero permeabilities."""
        n = self._n
        open_face = T > 0
        graph = sp.coo_array((np.ones(open_face.sum()),
                              (self._fa[open_face], self._fb[open_face])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
        open_d = Td > 0
        anchored = np.zeros(labels.max() + 1, dtype=bool)
        anchored[labels[self._dc[open_d]]] = True
        if self.kind == "pressure":
            reach_in = np.zeros_like(anchored)
            reach_in[labels[self._dc[open_d & (self._dside == 0)]]] = True
            blocked = not reach_in[labels[self._dc[open_d & (self._dside == 1)]]].any()
        else:  # flow_rate: decided from the inflow shares; dirichlet: never
            blocked = False
        return ~anchored[labels], blocked

    # ------------------------------------------------------------------ public
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
        x, its, res = self._solve_all(self._hierarchy_ops(changed), rhs, guess)
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

    def _pattern(self):
        return (self._n, self._indptr, self._indices)

    def close(self):
        """Free this solver's hierarchies here and in the worker processes (also
        done when the solver is garbage-collected)."""
        self._finalizer()

    def _carried_source(self, carried, occupied):
        """Right-hand side of the particles' carried flux: each interior face takes
        the mean of ``chi v`` over its occupied sides, normal to it, times its length."""
        R = self.n_batch
        v = np.asarray(carried, dtype=float).reshape(R, -1, 2)[:, self._cells]
        if occupied is None:
            occupied = np.any(np.asarray(carried).reshape(R, -1, 2) != 0.0, axis=-1)
        chi = np.asarray(occupied, dtype=float).reshape(R, -1)[:, self._cells]
        comp = np.where(self._f_is_x, 0, 1)
        length = np.where(self._f_is_x, self.dy, self.dx)
        sides = np.maximum(chi[:, self._fa] + chi[:, self._fb], 1.0)
        q = (v[:, self._fa, comp] + v[:, self._fb, comp]) / sides * length   # a -> b
        n = self._n
        offset = (np.arange(R) * n)[:, None]
        src = (np.bincount((offset + self._fb).ravel(), q.ravel(), R * n)
               - np.bincount((offset + self._fa).ravel(), q.ravel(), R * n))
        return src.reshape(R, n)

    def _boundary_fluxes(self, x, kappa):
        """Sums of the inward and outward boundary-face fluxes per realization."""
        inward = self._dg * kappa[:, self._dc] / self.viscosity * (self._dv - x[:, self._dc])
        inward[self._pinned[:, self._dc]] = 0.0
        inflow = self._share.sum(axis=1)
        flux_in = np.clip(inward, 0.0, None).sum(axis=1) + np.clip(inflow, 0.0, None)
        flux_out = np.clip(-inward, 0.0, None).sum(axis=1) + np.clip(-inflow, 0.0, None)
        return flux_in, flux_out

    def velocity(self, pressure, kappa):
        """Depth-averaged velocity at the cell centres.

        The velocity on each face is the two-point flux over the face length
        (``-k_h (p_2 - p_1) / (eta dx)`` on an x-face, with the harmonic mean
        ``k_h``; the prescribed inflow share on a ``flow_rate`` inlet face); a cell's
        velocity is the mean of its two x-faces and of its two y-faces. Walls and
        cells without a pressure get 0.

        Parameters
        ----------
        pressure : array_like
            As returned by :meth:`solve`.
        kappa : array_like
            The permeability that pressure was solved with.

        Returns
        -------
        ux, uy : numpy.ndarray
            m/s, the same shape as ``pressure``.

        Examples
        --------
        >>> solver = PressureSolver(np.ones((5, 2), bool), 0.1, 0.1, 2.0,
        ...     bc={"kind": "pressure", "p_in": 1.0, "p_out": 0.0})
        >>> kappa = np.full((5, 2), 0.5)
        >>> ux, uy = solver.velocity(solver.solve(kappa)[0], kappa)
        >>> np.allclose(ux, 0.5 / 2.0 * 1.0 / 0.5), np.allclose(uy, 0.0)  # k/eta dp/L
        (True, True)
        """
        p, single = self._as_batch(pressure, "pressure")
        k, _ = self._as_batch(kappa, "kappa")
        eta, dx, dy = self.viscosity, self.dx, self.dy
        has_p = np.isfinite(p) & self.connected
        p = np.where(has_p, p, 0.0)
        k = np.where(has_p, k, 0.0)
        R, nx, ny = p.shape
        side = self.side_values

        ux_face = np.zeros((R, nx + 1, ny))
        both = has_p[:, :-1] & has_p[:, 1:]
        ux_face[:, 1:-1] = np.where(
            both, -harmonic_mean(k[:, :-1], k[:, 1:]) * (p[:, 1:] - p[:, :-1]) / (eta * dx), 0.0)
        left = has_p[:, 0] & np.isfinite(side["left"])
        ux_face[:, 0] = np.where(left, k[:, 0] * (side["left"] - p[:, 0]) / (eta * dx / 2), 0.0)
        right = has_p[:, -1] & np.isfinite(side["right"])
        ux_face[:, -1] = np.where(right, k[:, -1] * (p[:, -1] - side["right"]) / (eta * dx / 2),
                                  0.0)
        if self.inflow != 0.0:
            weight = k[:, 0]  # zero where the inlet cell has no pressure
            total = weight.sum(axis=1, keepdims=True)
            ux_face[:, 0] = np.divide(self.inflow * weight, total * dy,
                                      out=np.zeros_like(weight), where=total > 0)

        uy_face = np.zeros((R, nx, ny + 1))
        both = has_p[:, :, :-1] & has_p[:, :, 1:]
        uy_face[:, :, 1:-1] = np.where(
            both, -harmonic_mean(k[:, :, :-1], k[:, :, 1:]) * (p[:, :, 1:] - p[:, :, :-1])
            / (eta * dy), 0.0)
        bottom = has_p[:, :, 0] & np.isfinite(side["bottom"])
        uy_face[:, :, 0] = np.where(
            bottom, k[:, :, 0] * (side["bottom"] - p[:, :, 0]) / (eta * dy / 2), 0.0)
        top = has_p[:, :, -1] & np.isfinite(side["top"])
        uy_face[:, :, -1] = np.where(
            top, k[:, :, -1] * (p[:, :, -1] - side["top"]) / (eta * dy / 2), 0.0)

        ux = np.where(has_p, 0.5 * (ux_face[:, :-1] + ux_face[:, 1:]), 0.0)
        uy = np.where(has_p, 0.5 * (uy_face[:, :, :-1] + uy_face[:, :, 1:]), 0.0)
        return (ux[0], uy[0]) if single else (ux, uy)

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


def _require(bc, keys, kind):
    missing = [key for key in keys if key not in bc]
    extra = set(bc) - {"kind", *keys}
    if missing or extra:
        raise ValueError(
            f"the {kind} condition needs exactly the keys {list(keys)}; missing "
            f"{missing}, unknown {sorted(extra)}")
    for key in keys:
        if not np.isfinite(bc[key]):
            raise ValueError(f"{kind} condition: {key} must be finite, got {bc[key]}")


# ---------------------------------------------------------------- verification
def circular_inclusion_pressure(x, y, radius, k_out, k_in, gradient=1.0):
    """Exact pressure round a circular inclusion in a uniform far-field gradient.

    MODEL.md section 6: with ``beta = (k_out - k_in) / (k_out + k_in)``,
    ``p = -G x (1 + beta a^2 / r^2)`` outside and ``p = -G x 2 k_out / (k_out +
    k_in)`` inside (``r < a``), the inclusion centred at the origin.

    Examples
    --------
    >>> float(circular_inclusion_pressure(2.0, 0.0, 1.0, 1.0, 0.0))  # -2 (1 + 1/4)
    -2.5
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    beta = (k_out - k_in) / (k_out + k_in)
    r2 = x * x + y * y
    outside = -gradient * x * (1.0 + beta * radius**2 / np.where(r2 > 0, r2, 1.0))
    inside = -gradient * x * 2.0 * k_out / (k_out + k_in)
    return np.where(r2 < radius**2, inside, outside)[()]


def circular_inclusion_error(cells_per_radius, k_ratio, half_width=4.0, tol=1e-11):
    """Discretisation error of the inclusion problem on one grid.

    A disk of radius ``a = 1`` and permeability ``k_ratio`` in a unit background,
    in the box ``[-half_width, half_width]^2`` with the exact pressure (``G = 1``,
    ``eta = 1``) on all four sides; a cell belongs to the inclusion if its centre
    does (a staircase interface, so about first order).

    Parameters
    ----------
    cells_per_radius : int
        ``a / dx``.
    k_ratio : float
        ``k2 / k1``.

    Returns
    -------
    dict
        ``cells`` (grid cells), ``l1`` (mean absolute error), ``linf`` (largest),
        both in units of ``G a``, and ``seconds`` (the solve, hierarchy included).

    Examples
    --------
    >>> e = circular_inclusion_error(4, 1e-2)
    >>> e["cells"], round(e["l1"], 3)
    (1024, 0.018)
    """
    m = int(round(2 * half_width * cells_per_radius))
    h = 1.0 / cells_per_radius
    centres = -half_width + (np.arange(m) + 0.5) * h
    x, y = np.meshgrid(centres, centres, indexing="ij")
    kappa = np.where(x * x + y * y < 1.0, k_ratio, 1.0)

    def exact(px, py):
        return circular_inclusion_pressure(px, py, 1.0, 1.0, k_ratio)

    edge = np.full(m, half_width)
    bc = {"kind": "dirichlet",
          "left": exact(-edge, centres), "right": exact(edge, centres),
          "bottom": exact(centres, -edge), "top": exact(centres, edge)}
    solver = PressureSolver(np.ones((m, m), bool), h, h, 1.0, bc, tol=tol)
    t_start = time.perf_counter()
    p, _ = solver.solve(kappa)
    seconds = time.perf_counter() - t_start
    error = np.abs(p - exact(x, y))
    return {"cells": m * m, "l1": float(error.mean()), "linf": float(error.max()),
            "seconds": seconds}
