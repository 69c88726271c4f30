"""Closed-form material laws of the model (docs/model.md sections 1-2), plain numpy.

* :func:`restitution_factor`: the dashpot factor ``c_e`` of a restitution ``e``,
  ``gamma_n = c_e sqrt(k_n m_eff)``.
* :func:`free_permeability`: the empty Hele-Shaw cell, ``H^2 / 12``.
* :func:`kozeny_carman`: a fluid cell covered by a particle.
* :func:`harmonic_mean`: how two cells' permeabilities (or two species'
  stiffnesses) combine at a face (in series).
"""
from __future__ import annotations

import math

import numpy as np


def restitution_factor(e: float) -> float:
    """``c_e`` such that ``gamma_n = c_e sqrt(k_n m_eff)`` gives restitution ``e``.

    ``c_e = -2 ln(e) / sqrt(pi^2 + ln(e)^2)`` (0 for a perfectly elastic contact).

    Examples
    --------
    >>> round(restitution_factor(0.5), 6)
    0.430908
    """
    if e >= 1.0:
        return 0.0
    le = math.log(e)
    return -2.0 * le / math.sqrt(math.pi ** 2 + le ** 2)


def harmonic_mean(a, b):
    """``2 a b / (a + b)``, elementwise, and 0 where both are 0 (e.g. a face
    between two solids).

    Examples
    --------
    >>> float(harmonic_mean(1.0, 3.0)), float(harmonic_mean(0.0, 0.0))
    (1.5, 0.0)
    """
    total = np.add(a, b)
    out = np.zeros(np.broadcast(a, b).shape)
    np.divide(2.0 * np.multiply(a, b), total, out=out, where=total > 0)
    return out[()]


def free_permeability(gap):
    """Permeability of the empty Hele-Shaw cell, ``kappa = H^2 / 12``.

    Parameters
    ----------
    gap : float
        Plate spacing ``H``, m.

    Returns
    -------
    float
        Depth-averaged permeability, m^2.

    Examples
    --------
    >>> free_permeability(1.2e-3)
    1.2e-07
    """
    if not gap > 0:
        raise ValueError(f"gap must be > 0, got {gap}")
    return float(gap) ** 2 / 12.0


def kozeny_carman(sphericity, diameter, area, gap):
    """Permeability of a fluid cell covered by a particle (Kozeny-Carman).

    ``kappa = Phi_s^2 eps^3 d^2 / (150 (1 - eps)^2)`` with the porosity of the
    cell column that holds the particle, ``eps = 1 - V_p / (A H)`` and
    ``V_p = (2/3) A d`` (a sphere of diameter ``d`` for a disk of that diameter; the
    same ratio for other shapes). See docs/scene.md, Conventions.

    Parameters
    ----------
    sphericity : float
        ``Phi_s`` in (0, 1], the 2D sphericity ``sqrt(4 pi A) / P``.
    diameter : float
        ``d``, the particle's equivalent diameter ``sqrt(4 A / pi)``, m.
    area : float
        ``A``, the particle's cross-section, m^2.
    gap : float
        ``H``, plate spacing, m.

    Returns
    -------
    float
        Permeability, m^2.

    Raises
    ------
    ValueError
        If ``eps <= 0``: the particle's volume does not fit in the gap
        (``H <= (2/3) d``).

    Examples
    --------
    >>> d = 1e-3
    >>> k = kozeny_carman(1.0, d, np.pi * d**2 / 4, 1.2 * d)
    >>> round(k / free_permeability(1.2 * d), 4)  # about 60 times less permeable
    0.0158
    """
    if not (sphericity > 0 and diameter > 0 and area > 0 and gap > 0):
        raise ValueError(
            "kozeny_carman needs sphericity, diameter, area and gap > 0, got "
            f"{sphericity}, {diameter}, {area}, {gap}")
    volume = (2.0 / 3.0) * area * diameter
    eps = 1.0 - volume / (area * gap)
    if eps <= 0:
        raise ValueError(
            f"Kozeny-Carman porosity {eps:.3g} <= 0: a particle of diameter {diameter} "
            f"does not fit in a gap of {gap}; the gap must exceed (2/3) d = "
            f"{2.0 * diameter / 3.0:.6g}")
    return float(sphericity**2 * eps**3 * diameter**2 / (150.0 * (1.0 - eps) ** 2))


def theory_escapees(phi, t, flow_rate, gap, diameter):
    """Escapees of a steady stream, ``4 phi Q t / (H pi d^2)`` (docs/model.md sec. 4)."""
    return 4.0 * np.asarray(phi, dtype=float) * flow_rate * np.asarray(t, dtype=float) / (
        gap * math.pi * diameter ** 2)
