"""Exact solutions of the pressure equation, for tests and convergence studies
(like pyamg's ``gallery``): docs/model.md section 6."""
from __future__ import annotations

import time

import numpy as np

from .solver import PressureSolver


def circular_inclusion_pressure(x, y, radius, k_out, k_in, gradient=1.0):
    """Exact pressure round a circular inclusion in a uniform far-field gradient.

    docs/model.md section 6: with ``beta = (k_out - k_in) / (k_out + k_in)``,
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


def circular_inclusion_error(cells_per_radius, k_ratio, half_width=4.0, tol=1e-11,
                             solver_class=None):
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
    solver_class : class, optional
        The solver to use, constructed as :class:`PressureSolver` is (default:
        :class:`PressureSolver`, pyamg's CG).

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
    solver = (solver_class or PressureSolver)(np.ones((m, m), bool), h, h, 1.0, bc, tol=tol)
    t_start = time.perf_counter()
    p, _ = solver.solve(kappa)
    seconds = time.perf_counter() - t_start
    error = np.abs(p - exact(x, y))
    return {"cells": m * m, "l1": float(error.mean()), "linf": float(error.max()),
            "seconds": seconds}
