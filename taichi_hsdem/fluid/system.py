"""The finite-volume discretisation of the Hele-Shaw pressure equation on the
fixed grid (docs/model.md section 2), independent of how it is solved.

The fluid obeys ``div u = 0`` and ``u = -(kappa / eta) grad p``, per unit depth of
the gap. Cell-centred finite volumes on a uniform grid of ``nx x ny`` cells; every
array is x-first: ``kappa[i, j]`` belongs to the cell centred at
``(x0 + (i + 0.5) dx, y0 + (j + 0.5) dy)``. The flux through a face between two
cells is the two-point flux with the harmonic mean of their permeabilities,

    F = T (p_1 - p_2),   T = 2 k_1 k_2 / (k_1 + k_2) * (dy / dx) / eta   (x-faces),

a Dirichlet face sits half a cell from its cell centre (``T = k (dy / (dx / 2)) /
eta``), and a wall (an inactive cell, or a box side without a value) passes no flux.
The matrix is symmetric positive definite.

:class:`FiniteVolumeSystem` holds everything that depends only on the grid and the
boundary condition (which cells are unknowns, the face lists, the sparsity
pattern) and fills in a realization's matrix and right-hand side from its
permeability; :class:`~taichi_hsdem.fluid.PressureSolver` solves it.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..laws import harmonic_mean

_SIDES = ("left", "right", "bottom", "top")


class FiniteVolumeSystem:
    """The discretised pressure equation of ``n_batch`` realizations on one grid.

    Parameters are those of :class:`~taichi_hsdem.fluid.PressureSolver` (``active``,
    ``dx``, ``dy``, ``viscosity``, ``bc``, ``n_batch``, ``gap``); see its
    docstring for the boundary conditions and what happens to cut-off cells.
    """

    def __init__(self, active, dx, dy, viscosity, bc, n_batch=1, gap=None):
        self._set_grid(active, dx, dy, viscosity, n_batch)
        self._parse_bc(bc, gap)
        self._build_pattern()

    # ------------------------------------------------------------------ set-up
    def _set_grid(self, active, dx, dy, viscosity, n_batch):
        """Check and keep the grid: ``active`` (copied), spacings, viscosity, batch."""
        active = np.array(active, dtype=bool)  # a copy: the caller may reuse theirs
        if active.ndim != 2:
            raise ValueError(f"active must be a 2D (nx, ny) array, got shape {active.shape}")
        for name, value in (("dx", dx), ("dy", dy), ("viscosity", viscosity)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        if not (isinstance(n_batch, (int, np.integer)) and n_batch >= 1):
            raise ValueError(f"n_batch must be an int >= 1, got {n_batch}")
        self.shape = active.shape
        self.dx, self.dy, self.viscosity = float(dx), float(dy), float(viscosity)
        self.n_batch = int(n_batch)
        self.active = active

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
            total = _row_sums(weight)[:, None]
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
        inflow = _row_sums(self._share)
        flux_in = _row_sums(np.clip(inward, 0.0, None)) + np.clip(inflow, 0.0, None)
        flux_out = _row_sums(np.clip(-inward, 0.0, None)) + np.clip(-inflow, 0.0, None)
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
        >>> from taichi_hsdem.fluid import PressureSolver
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
            total = _row_sums(weight)[:, None]
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


def _row_sums(a: np.ndarray) -> np.ndarray:
    """The sum of each row, added in the same order whatever the batch: numpy sums a
    C-ordered row pairwise but accumulates a Fortran-ordered array (which taking
    columns ``a[:, cells]`` of a batch gives) column by column, so a realization
    solved in a batch would round otherwise than solved alone."""
    return np.ascontiguousarray(a).sum(axis=1)


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
