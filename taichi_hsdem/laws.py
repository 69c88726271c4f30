"""Closed-form material laws of the model (docs/model.md sections 1-2), plain numpy.

* :func:`restitution_factor`: the dashpot factor ``c_e`` of a restitution ``e``,
  ``gamma_n = c_e sqrt(k_n m_eff)``.
* :func:`free_permeability`: the empty Hele-Shaw cell, ``H^2 / 12``.
* :func:`kozeny_carman`: a fluid cell covered by a particle.
* :func:`harmonic_mean`: how two cells' permeabilities (or two species'
  stiffnesses) combine at a face (in series).
* :func:`sphere_in_gap`: how a sphere at mid-gap drifts with, and disturbs, the
  depth-averaged flow (3D Stokes, ``taichi_hsdem/data/sphere_in_gap.csv``);
  :func:`carried_fraction`, :func:`inclusion_dipole` and :func:`drift_damping`:
  the Darcy disk that reproduces both (docs/model.md section 3.4).
* :func:`sphere_spin_torque`: the viscous torque on such a sphere spinning about
  the plates' normal (Stokes, ``taichi_hsdem/data/sphere_spin.csv``).
"""
from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

SPHERE_IN_GAP = Path(__file__).with_name("data") / "sphere_in_gap.csv"
SPHERE_SPIN = Path(__file__).with_name("data") / "sphere_spin.csv"
PAIR_MOBILITY_TABLE = Path(__file__).with_name("data") / "pair_mobility.csv"
#: Beyond this surface gap (over the pair's mean d_eq) the pair resistance is zero:
#: the last knot of the table tools/pair_mobility_fit.py writes, where it holds 0.
PAIR_CUTOFF = 1.0


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


@lru_cache(maxsize=None)
def _table(path: Path, columns: tuple[str, ...]) -> np.ndarray:
    """The ``columns`` of the CSV ``path`` (``#`` lines are comments) as rows of
    floats, sorted by the first column."""
    import csv
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    table = np.array([[float(r[k]) for k in columns] for r in rows])
    return table[np.argsort(table[:, 0])]


def _sphere_table() -> np.ndarray:
    """``(d/H, drift ratio, free dipole)`` rows of :data:`SPHERE_IN_GAP`, by d/H."""
    return _table(SPHERE_IN_GAP, ("d_over_H", "drift_ratio", "dipole_free"))


def pair_mobility_table() -> np.ndarray:
    """``(g, alpha, beta)`` rows of :data:`PAIR_MOBILITY_TABLE`, by the surface gap
    ``g`` over d: the close pairs' resistance of ``fluid.pair_mobility``
    (:mod:`taichi_hsdem.dem.pairs`; written by ``tools/pair_mobility_fit.py``). The
    last knot is the cutoff, :data:`PAIR_CUTOFF`, with zeros."""
    return _table(PAIR_MOBILITY_TABLE, ("g", "alpha", "beta"))


def _spin_table() -> np.ndarray:
    """``(d/H, spin torque)`` rows of :data:`SPHERE_SPIN`, by d/H."""
    return _table(SPHERE_SPIN, ("d_over_H", "spin_torque"))


def sphere_in_gap_range() -> tuple[float, float]:
    """The d/H range :func:`sphere_in_gap` covers."""
    t = _sphere_table()
    return float(t[0, 0]), float(t[-1, 0])


def sphere_in_gap(d_over_h: float) -> tuple[float, float]:
    """How a rigid sphere of diameter ``d`` centred between plates ``H`` apart
    moves with a pressure-driven flow: ``(drift_ratio, dipole)``.

    ``drift_ratio`` is the force- and torque-free sphere's speed over the mean
    (depth-averaged) fluid speed ``u``; ``dipole`` is ``B / a^2`` of the
    depth-averaged pressure it then leaves, ``p' = -B G x / r^2`` (``a = d/2``,
    ``G`` the driving gradient, ``x`` along the flow). Interpolated (piecewise
    cubic, monotone) in the 3D Stokes table :data:`SPHERE_IN_GAP`, computed by
    ``python tools/stokes_sphere_gap.py --table`` (docs/validation.md).

    Raises
    ------
    ValueError
        Outside the table's range of d/H.

    Examples
    --------
    >>> lam, b = sphere_in_gap(0.875)
    >>> round(lam, 3), round(b, 3)
    (1.009, 0.464)
    """
    from scipy.interpolate import PchipInterpolator
    t = _sphere_table()
    lo, hi = t[0, 0], t[-1, 0]
    if not lo <= d_over_h <= hi:
        raise ValueError(f"d/H = {d_over_h:.4g} is outside the 3D Stokes table of a "
                         f"sphere at mid-gap ({lo:g} to {hi:g})")
    drift = PchipInterpolator(t[:, 0], t[:, 1])(d_over_h)
    dipole = PchipInterpolator(t[:, 0], t[:, 2])(d_over_h)
    return float(drift), float(dipole)


def sphere_spin_range() -> tuple[float, float]:
    """The d/H range :func:`sphere_spin_torque` covers."""
    t = _spin_table()
    return float(t[0, 0]), float(t[-1, 0])


#: Apery's constant, zeta(3): the images of a rotlet between two plates sum to it.
ZETA3 = 1.2020569031595942


def sphere_spin_images(d_over_h: float) -> float:
    """The point rotlet's images between the two plates summed,
    ``1 / (1 - (3/16) zeta(3) (d/H)^3)``: :func:`sphere_spin_torque` as
    ``d/H -> 0`` (within 1.3e-7 at d/H = 0.3, the remainder growing like
    ``(d/H)^10``).

    Examples
    --------
    >>> round(sphere_spin_images(0.3), 6)
    1.006123
    """
    return 1.0 / (1.0 - 3.0 / 16.0 * ZETA3 * float(d_over_h) ** 3)


def sphere_spin_torque(d_over_h: float) -> float:
    """Viscous torque on a sphere spinning at mid-gap about the plates' normal,
    over its value in unbounded fluid.

    A rigid sphere of diameter ``d`` (``a = d/2``) centred between no-slip plates
    ``H`` apart, spinning at ``Omega`` about the axis normal to the plates in
    fluid at rest, feels the torque

        ``T = 8 pi eta a^3 Omega * sphere_spin_torque(d/H)``

    against its spin (``eta`` the viscosity). The coefficient is 1 far from the
    plates, ``1 / (1 - (3/16) zeta(3) (d/H)^3)`` to within 1.3e-7 for
    ``d/H <= 0.3`` (the point rotlet's images), and grows to 1.31 at d/H =
    0.975, finite at contact. Interpolated (piecewise cubic, monotone) in the
    Stokes table :data:`SPHERE_SPIN` (error 1e-7), computed by
    ``python tools/stokes_sphere_spin.py --table``; between its points the
    interpolation is within 3e-4 of the solver (measured at the quarter points,
    the most near contact, where the slope grows like ``-ln(1 - d/H)``).

    Below the table (``0 < d/H < 0.3``) the image sum itself is returned.

    Raises
    ------
    ValueError
        Above the table's range of d/H (:func:`sphere_spin_range`), or d/H <= 0.

    Examples
    --------
    >>> round(sphere_spin_torque(0.3), 5), round(sphere_spin_torque(0.9), 5)
    (1.00612, 1.21143)
    >>> round(sphere_spin_torque(0.1), 7)       # the images: 1 + 2.3e-4
    1.0002254
    """
    from scipy.interpolate import PchipInterpolator
    t = _spin_table()
    lo, hi = t[0, 0], t[-1, 0]
    if 0.0 < d_over_h < lo:
        return sphere_spin_images(d_over_h)
    if not lo <= d_over_h <= hi:
        raise ValueError(f"d/H = {d_over_h:.4g} is outside the Stokes table of a spinning "
                         f"sphere at mid-gap ({lo:g} to {hi:g})")
    return float(PchipInterpolator(t[:, 0], t[:, 1])(d_over_h))


def carried_fraction(kappa_free, kappa_p, drift_ratio, dipole):
    """The share ``c`` of its velocity that a disk's cells must carry for a lone
    disk drifting at ``drift_ratio`` times the mean fluid speed to leave the
    dipole ``B / a^2 = dipole`` (docs/model.md section 3.4).

    A disk of permeability ``kappa_p`` in a background ``kappa_free`` whose cells
    carry the flux ``c v`` leaves ``B / a^2 = ((k1 - k2) - c lambda k1) / (k1 + k2)``
    (:func:`inclusion_dipole`); this inverts it.

    Examples
    --------
    >>> round(carried_fraction(1.0, 0.0, 1.0, 0.0), 12)   # a tracer: no dipole
    1.0
    >>> round(carried_fraction(1.0, 0.0, 1.0, 1.0), 12)   # an impermeable obstacle
    0.0
    """
    return ((kappa_free - kappa_p) - dipole * (kappa_free + kappa_p)) / (drift_ratio * kappa_free)


def inclusion_dipole(kappa_free, kappa_p, drift_ratio, carried):
    """``B / a^2`` of a lone disk drifting at ``drift_ratio`` times the mean
    fluid speed whose cells carry ``carried`` times its velocity: the circular
    inclusion (docs/model.md section 6) with a source, ``p = -G x (1 + B/r^2)``
    outside, continuous pressure and normal flux at the rim.

    Examples
    --------
    >>> inclusion_dipole(1.0, 0.0, 1.0, 0.0), inclusion_dipole(1.0, 0.0, 1.0, 1.0)
    (1.0, 0.0)
    """
    return ((kappa_free - kappa_p) - carried * drift_ratio * kappa_free) / (kappa_free + kappa_p)


def drift_damping(viscosity, density, kappa_free, kappa_p, drift_ratio, carried=None):
    """Global damping ``xi`` at which a lone particle (a prism of thickness ``H``,
    density ``rho``) drifts at ``drift_ratio`` times the mean fluid speed
    ``u = kappa_free G / eta`` (docs/model.md section 5.2).

    The pressure force on the disk is ``A H G (1 + B/a^2)``
    (:func:`inclusion_dipole`): with its cells carrying ``c v``
    (``carried = c``), ``xi = (2 - c lambda) eta / (rho lambda (k1 + k2))``; held
    fixed in the pressure solve (``carried = None``), ``xi = (1 + beta) eta /
    (rho lambda k1)``, ``beta = (k1 - k2) / (k1 + k2)``.

    Examples
    --------
    >>> drift_damping(1.0, 1.0, 1.0, 0.0, 1.0, carried=1.0)   # tracer: eta / (rho k1)
    1.0
    """
    if carried is None:
        beta = (kappa_free - kappa_p) / (kappa_free + kappa_p)
        return (1.0 + beta) * viscosity / (density * drift_ratio * kappa_free)
    return (2.0 - carried * drift_ratio) * viscosity / (density * drift_ratio
                                                       * (kappa_free + kappa_p))
