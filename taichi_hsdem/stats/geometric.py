"""Censoring-aware geometric fit of the escapees before clogging, ``<s>`` and ``p``.

Likelihood
----------
A clogged realization contributes ``P(S = s) = (1 - p)^s p``, a censored one
``P(S >= s) = (1 - p)^s``. With ``k`` clogged realizations and ``S_tot`` the sum
of all observed counts (clogged and censored),

    log L(p) = k ln p + S_tot ln(1 - p),   p_hat = k / (k + S_tot),

so ``<s>_hat = (1 - p_hat) / p_hat = S_tot / k``: the sum of all counts over the
number of clogs. The plain mean of the counts, ``S_tot / n``, equals it only when
nothing is censored; otherwise it is biased low (a never-clogged run counted as if
it had clogged).

Confidence intervals
--------------------
Profile likelihood (likelihood ratio): the interval holds every ``p`` with
``2 [log L(p_hat) - log L(p)] <= chi2_1(confidence)``. It is not symmetric,
stays inside ``(0, 1)`` and is invariant under reparametrisation, so the
intervals of ``<s>`` and ``lambda`` are the images of the interval of ``p``
through those monotone maps. It is used whether or not anything is censored:
its exact coverage with nothing censored is 0.946-0.953 for n = 5 to 100
(tests/test_stats.py computes it from the negative binomial law of ``S_tot``),
where a Student-t interval on the plain mean covers only 0.88 at n = 5, 0.90
at n = 10 and 0.92 at n = 20 (20000 simulated samples each: the counts are
skewed, and a sample with a low mean also has a low spread). At the two boundaries the likelihood ratio
interval undercovers, and there the exact one-sided bound from the probability
of the observed outcome is used instead (``ci_method = "exact_one_sided"``):

* no clog at all (``k = 0``): ``p_hat = 0``; the probability of seeing no clog
  is ``(1 - p)^S_tot``, so ``p <= 1 - alpha^(1 / S_tot)`` with
  ``alpha = 1 - confidence`` (the "rule of three": ``lambda <= 3.0 / S_tot``
  at 95 %); the interval of ``lambda`` reaches 0 and that of ``<s>`` reaches
  infinity.
* every realization clogged at ``s = 0`` (``S_tot = 0``): ``p_hat = 1``; the
  probability of that is ``p^k``, so ``p >= alpha^(1 / k)``.
* ``k = 0`` and ``S_tot = 0`` (every realization censored before anything
  escaped): the data say nothing about ``p``; estimates are NaN, interval (0, 1)
  (``ci_method = "uninformative"``).

The standard error of ``lambda`` is the delta-method one from the observed
information, ``p_hat / sqrt(k (1 - p_hat))``; it is NaN when ``k = 0`` and
infinite when ``p_hat = 1``, where ``decay_rate_ci`` is the number to use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special
from scipy import stats as sps

from ._inputs import as_clogged, as_samples, check_confidence


@dataclass(frozen=True)
class GeometricFit:
    """Censoring-aware maximum-likelihood fit of a geometric distribution.

    Attributes
    ----------
    p : float
        Probability that an arriving particle clogs (per escapee), MLE.
        NaN when nothing escaped and nothing clogged.
    p_ci : tuple of float
        Confidence interval of ``p`` (profile likelihood; see module notes).
    mean : float
        ``<s> = (1 - p) / p`` implied by the fit (``inf`` when ``p = 0``).
    mean_ci : tuple of float
        Image of ``p_ci``; its upper end is ``inf`` when ``p_ci[0] = 0``.
    decay_rate : float
        ``lambda = -ln(1 - p)`` in ``P(s) ~ exp(-lambda s)``.
    decay_rate_stderr : float
        Delta-method standard error of ``decay_rate`` (NaN with no clog,
        ``inf`` when ``p = 1``).
    n, n_clogged, n_censored : int
        Realizations in all, ending in a clog, and censored.
    decay_rate_ci : tuple of float
        Image of ``p_ci``; starts at 0 when ``p_ci[0] = 0``.
    confidence : float
        Confidence level of the intervals.
    ci_method : str
        How the intervals were found: ``"profile_likelihood"``,
        ``"exact_one_sided"`` (no clog, or every clog at ``s = 0``) or
        ``"uninformative"`` (nothing escaped, nothing clogged).
    """

    p: float
    p_ci: tuple[float, float]
    mean: float
    mean_ci: tuple[float, float]
    decay_rate: float
    decay_rate_stderr: float
    n: int
    n_clogged: int
    n_censored: int
    decay_rate_ci: tuple[float, float]
    confidence: float
    ci_method: str = "profile_likelihood"


def _loglik_logodds(theta: float, k: int, total: int) -> float:
    # log L in theta = logit(p): k ln p + S ln(1-p) = k theta - (k+S) ln(1+e^theta).
    # The log-odds scale keeps the root search away from p = 0 and p = 1.
    return k * theta - (k + total) * np.logaddexp(0.0, theta)


def _profile_interval(k: int, total: int, confidence: float) -> tuple[float, float]:
    """Likelihood-ratio interval of p for k >= 1 clogs and total >= 1 escapees."""
    theta_hat = math.log(k / total)
    target = _loglik_logodds(theta_hat, k, total) - 0.5 * sps.chi2.ppf(confidence, 1)
    ends = []
    for direction in (-1.0, 1.0):
        # log L is concave and falls to -inf on both sides (k, total >= 1), so
        # doubling the step brackets the root.
        step = 1.0
        while _loglik_logodds(theta_hat + direction * step, k, total) > target:
            step *= 2.0
        lo, hi = sorted((theta_hat, theta_hat + direction * step))
        root = optimize.brentq(lambda t: _loglik_logodds(t, k, total) - target, lo, hi,
                               xtol=1e-12)
        ends.append(float(special.expit(root)))
    return ends[0], ends[1]


def mean_of_p(p: float) -> float:
    """``<s> = (1 - p) / p``, ``inf`` at ``p = 0``."""
    return math.inf if p == 0.0 else (1.0 - p) / p


def _rate_of(p: float) -> float:
    return math.inf if p == 1.0 else -math.log1p(-p)


def fit_geometric(escapees, clogged, confidence: float = 0.95) -> GeometricFit:
    """Fit ``P(s) = (1 - p)^s p`` to escapee counts, censored ones included.

    Parameters
    ----------
    escapees : array_like of int
        Escapees ``s >= 0`` of each realization (up to the clog, or up to the
        end time for a realization that did not clog).
    clogged : array_like of bool
        Whether each realization ended in a clog; ``False`` marks it censored.
    confidence : float, optional
        Confidence level of the intervals (default 0.95).

    Returns
    -------
    GeometricFit
        ``p = n_clogged / (n_clogged + sum(s))`` with its profile-likelihood
        interval, and ``<s>``, ``lambda`` derived from it (module notes give the
        boundary cases).

    Raises
    ------
    ValueError
        Empty input, lengths that differ, counts that are negative or not
        whole numbers, flags that are not booleans.

    Examples
    --------
    >>> fit = fit_geometric([4, 1, 0, 5], [True, True, True, True])
    >>> round(fit.p, 4), round(fit.mean, 4), fit.ci_method
    (0.2857, 2.5, 'profile_likelihood')
    >>> fit = fit_geometric([3, 0, 7, 12, 5], [True, True, True, False, True])
    >>> round(fit.p, 4), fit.n_censored
    (0.129, 1)
    >>> fit_geometric([10, 20, 30], [False, False, False]).p_ci[0]
    0.0
    """
    confidence = check_confidence(confidence)
    s, c = as_samples(escapees, clogged)
    k = int(c.sum())
    total = int(s.sum())
    alpha = 1.0 - confidence

    if k == 0 and total == 0:
        p, p_ci, how = math.nan, (0.0, 1.0), "uninformative"
    elif k == 0:
        p, p_ci, how = 0.0, (0.0, -math.expm1(math.log(alpha) / total)), "exact_one_sided"
    elif total == 0:
        p, p_ci, how = 1.0, (alpha ** (1.0 / k), 1.0), "exact_one_sided"
    else:
        p, p_ci = k / (k + total), _profile_interval(k, total, confidence)
        how = "profile_likelihood"

    if math.isnan(p):
        mean = rate = rate_se = math.nan
    else:
        # total / k rather than (1 - p) / p: exact for integer counts.
        mean, rate = (total / k if k else math.inf), _rate_of(p)
        # Observed information at p_hat is k/p^2 + S/(1-p)^2 = k / (p^2 (1-p)),
        # and d lambda / dp = 1/(1-p).
        if k == 0:
            rate_se = math.nan
        elif p == 1.0:
            rate_se = math.inf
        else:
            rate_se = p / math.sqrt(k * (1.0 - p))

    return GeometricFit(
        p=p,
        p_ci=p_ci,
        # <s> and lambda are monotone in p (decreasing and increasing).
        mean=mean,
        mean_ci=(mean_of_p(p_ci[1]), mean_of_p(p_ci[0])),
        decay_rate=rate,
        decay_rate_stderr=rate_se,
        n=int(s.size),
        n_clogged=k,
        n_censored=int(s.size - k),
        decay_rate_ci=(_rate_of(p_ci[0]), _rate_of(p_ci[1])),
        confidence=confidence,
        ci_method=how,
    )


def mean_escapees(escapees, clogged, confidence: float = 0.95
                  ) -> tuple[float, tuple[float, float]]:
    """Mean escapees before clogging, ``<s>``, with its profile-likelihood interval.

    The censoring-aware estimate ``sum(s) / n_clogged`` and the interval of
    :func:`fit_geometric` (``fit.mean``, ``fit.mean_ci``), whether or not
    anything is censored, so the method never changes with the data. With
    nothing censored the estimate is the plain mean of the counts.

    Parameters
    ----------
    escapees, clogged : array_like
        As in :func:`fit_geometric`.
    confidence : float, optional
        Confidence level (default 0.95).

    Returns
    -------
    mean : float
        ``inf`` when nothing clogged (the interval's lower end is then the
        information the data hold).
    ci : tuple of float

    Examples
    --------
    >>> m, (lo, hi) = mean_escapees([1, 2, 3, 4, 5], [True] * 5)
    >>> m, round(lo, 3), round(hi, 3)
    (3.0, 1.162, 9.223)
    >>> m, _ = mean_escapees([460] + [500] * 9, [True] + [False] * 9)
    >>> m    # (460 + 9 * 500) / 1 clog; the plain mean of the counts is 496
    4960.0
    """
    fit = fit_geometric(escapees, clogged, confidence)
    return fit.mean, fit.mean_ci


def clog_probability_per_escapee(escapees, clogged, confidence: float = 0.95
                                 ) -> tuple[float, tuple[float, float]]:
    """``p`` and its interval from :func:`fit_geometric`.

    Examples
    --------
    >>> round(clog_probability_per_escapee([4, 1, 0, 5], [True] * 4)[0], 4)
    0.2857
    """
    fit = fit_geometric(escapees, clogged, confidence)
    return fit.p, fit.p_ci


def exponential_rate_fit(escapees, clogged) -> tuple[float, float]:
    """Decay rate ``lambda`` of ``P(s) ~ exp(-lambda s)`` and its standard error.

    From :func:`fit_geometric`; see there for the cases with no clog
    (NaN error) or ``p = 1`` (infinite rate).

    Examples
    --------
    >>> rate, err = exponential_rate_fit([4, 1, 0, 5], [True] * 4)
    >>> round(rate, 4), round(err, 4)
    (0.3365, 0.169)
    """
    fit = fit_geometric(escapees, clogged)
    return fit.decay_rate, fit.decay_rate_stderr


def never_clogged_fraction(clogged, confidence: float = 0.95
                           ) -> tuple[float, tuple[float, float]]:
    """Fraction of realizations that never clogged, with a Wilson interval.

    The Wilson score interval keeps good coverage for fractions near 0 or 1
    and small samples, where the Wald interval collapses to zero width.

    Parameters
    ----------
    clogged : array_like of bool
    confidence : float, optional
        Confidence level (default 0.95).

    Returns
    -------
    fraction : float
    ci : tuple of float

    Examples
    --------
    >>> f, (lo, hi) = never_clogged_fraction([False] * 3 + [True] * 7)
    >>> f, round(lo, 4), round(hi, 4)
    (0.3, 0.1078, 0.6032)
    """
    confidence = check_confidence(confidence)
    c = as_clogged(clogged)
    n = c.size
    f = float((~c).sum()) / n
    z2 = sps.norm.ppf(0.5 + 0.5 * confidence) ** 2
    centre = (f + z2 / (2 * n)) / (1 + z2 / n)
    half = math.sqrt(z2) / (1 + z2 / n) * math.sqrt(f * (1 - f) / n + z2 / (4 * n * n))
    # Clip rounding only: the exact Wilson ends lie in [0, 1].
    return f, (max(0.0, float(centre - half)), min(1.0, float(centre + half)))
