"""Statistics of escapees before clogging (MODEL.md section 4, Figs. 9-13).

Each realization of a clogging run yields ``s``, the number of particles that
passed the constriction, and whether a clog ended it. The reference paper finds
``s`` geometric, ``P(s) = (1 - p)^s p`` on ``s = 0, 1, 2, ...``: every particle
reaching the constriction clogs it with a probability ``p``, independently of the
others, so ``P(s) ~ exp(-lambda s)`` with ``lambda = -ln(1 - p)`` and
``<s> = (1 - p) / p``.

A realization that reached the end time without clogging is right-censored: its
true ``s`` is at least the observed count. Dropping such realizations, or
counting them as clogs, biases ``p`` upwards (``<s>`` downwards); the
likelihood below uses them correctly.

Likelihood
----------
A clogged realization contributes ``P(S = s) = (1 - p)^s p``, a censored one
``P(S >= s) = (1 - p)^s``. With ``k`` clogged realizations and ``S_tot`` the sum
of all observed counts (clogged and censored),

    log L(p) = k ln p + S_tot ln(1 - p),   p_hat = k / (k + S_tot).

Confidence intervals
--------------------
Profile likelihood (likelihood ratio): the interval holds every ``p`` with
``2 [log L(p_hat) - log L(p)] <= chi2_1(confidence)``. Unlike a Wald interval
it is not symmetric, stays inside ``(0, 1)`` and is invariant under
reparametrisation, so the intervals of ``<s>`` and ``lambda`` are the images of
the interval of ``p`` through those monotone maps. At the two boundaries the
likelihood ratio interval undercovers, and there the exact one-sided bound from
the probability of the observed outcome is used instead:

* no clog at all (``k = 0``): ``p_hat = 0``; the probability of seeing no clog
  is ``(1 - p)^S_tot``, so ``p <= 1 - alpha^(1 / S_tot)`` with
  ``alpha = 1 - confidence`` (the "rule of three": ``lambda <= 3.0 / S_tot``
  at 95 %); the interval of ``lambda`` reaches 0 and that of ``<s>`` reaches
  infinity.
* every realization clogged at ``s = 0`` (``S_tot = 0``): ``p_hat = 1``; the
  probability of that is ``p^k``, so ``p >= alpha^(1 / k)``.
* ``k = 0`` and ``S_tot = 0`` (every realization censored before anything
  escaped): the data say nothing about ``p``; estimates are NaN, interval (0, 1).

The standard error of ``lambda`` is the delta-method one from the observed
information, ``p_hat / sqrt(k (1 - p_hat))``; it is NaN when ``k = 0`` and
infinite when ``p_hat = 1``, where ``decay_rate_ci`` is the number to use.

Examples
--------
>>> fit = fit_geometric([3, 0, 7, 12, 5], [True, True, True, False, True])
>>> round(fit.p, 4), fit.n_censored
(0.129, 1)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special
from scipy import stats as sps

__all__ = [
    "GeometricFit",
    "fit_geometric",
    "mean_escapees",
    "histogram",
    "normalized_pmf",
    "never_clogged_fraction",
    "clog_probability_per_escapee",
    "exponential_rate_fit",
    "summarize",
]


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


# --------------------------------------------------------------------------
# Input checks: the counts come from runs, files or the command line, so the
# errors name what is wrong in the user's terms.
# --------------------------------------------------------------------------

def _check_confidence(confidence: float) -> float:
    confidence = float(confidence)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie strictly between 0 and 1, got {confidence}")
    return confidence


def _as_clogged(clogged, n_expected: int | None = None) -> np.ndarray:
    c = np.asarray(clogged)
    if c.ndim != 1:
        raise ValueError(f"clogged must be a 1-D sequence of booleans, got shape {c.shape}")
    if c.size == 0:
        raise ValueError("clogged is empty: need at least one realization")
    if n_expected is not None and c.size != n_expected:
        raise ValueError(
            f"escapees and clogged differ in length ({n_expected} vs {c.size}): "
            "give one entry per realization in each"
        )
    if c.dtype == bool:
        return c
    # 0/1 integers (e.g. read back from a CSV) are accepted; anything else is
    # more likely a mix-up of arguments than a flag.
    if c.dtype.kind not in "iuf":
        raise ValueError(f"clogged must hold booleans (or 0/1), got dtype {c.dtype}")
    bad = (c != 0) & (c != 1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"clogged must hold booleans (or 0/1), got {c[i].item()!r} at index {i} "
            "(are escapees and clogged swapped?)"
        )
    return c.astype(bool)


def _as_escapees(escapees) -> np.ndarray:
    s = np.asarray(escapees)
    if s.ndim != 1:
        raise ValueError(f"escapees must be a 1-D sequence of counts, got shape {s.shape}")
    if s.size == 0:
        raise ValueError("escapees is empty: need at least one realization")
    if s.dtype == bool:
        raise ValueError(
            "escapees must be integer counts, got booleans (are escapees and clogged swapped?)"
        )
    if s.dtype.kind not in "iuf":
        raise ValueError(f"escapees must be integer counts, got dtype {s.dtype}")
    if s.dtype.kind == "f":
        # Whole-valued floats (e.g. from JSON or a CSV) are fine; 2.5 is not.
        bad = ~np.isfinite(s) | (s != np.floor(s))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"escapees must be non-negative integers, got non-integer {s[i].item()!r} at index {i}"
            )
    if (s < 0).any():
        i = int(np.flatnonzero(s < 0)[0])
        raise ValueError(
            f"escapees must be non-negative integers, got negative {s[i].item()!r} at index {i}"
        )
    return s.astype(np.int64)


def _as_samples(escapees, clogged) -> tuple[np.ndarray, np.ndarray]:
    s = _as_escapees(escapees)
    return s, _as_clogged(clogged, s.size)


# --------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------

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


def _mean_of(p: float) -> float:
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
    >>> round(fit.p, 4), round(fit.mean, 4)
    (0.2857, 2.5)
    >>> fit_geometric([10, 20, 30], [False, False, False]).p_ci[0]
    0.0
    """
    confidence = _check_confidence(confidence)
    s, c = _as_samples(escapees, clogged)
    k = int(c.sum())
    total = int(s.sum())
    alpha = 1.0 - confidence

    if k == 0 and total == 0:
        p, p_ci = math.nan, (0.0, 1.0)
    elif k == 0:
        p, p_ci = 0.0, (0.0, -math.expm1(math.log(alpha) / total))
    elif total == 0:
        p, p_ci = 1.0, (alpha ** (1.0 / k), 1.0)
    else:
        p, p_ci = k / (k + total), _profile_interval(k, total, confidence)

    if math.isnan(p):
        mean = rate = rate_se = math.nan
    else:
        mean, rate = _mean_of(p), _rate_of(p)
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
        mean_ci=(_mean_of(p_ci[1]), _mean_of(p_ci[0])),
        decay_rate=rate,
        decay_rate_stderr=rate_se,
        n=int(s.size),
        n_clogged=k,
        n_censored=int(s.size - k),
        decay_rate_ci=(_rate_of(p_ci[0]), _rate_of(p_ci[1])),
        confidence=confidence,
    )


def _mean_escapees(s: np.ndarray, c: np.ndarray, confidence: float):
    """Mean, interval and the name of the method used (shared with summarize)."""
    n = s.size
    if c.all() and n >= 2 and np.ptp(s) > 0:
        mean = float(s.mean())
        half = sps.t.ppf(0.5 + 0.5 * confidence, n - 1) * s.std(ddof=1) / math.sqrt(n)
        # s >= 0, so a lower end below 0 carries no information.
        return mean, (max(0.0, float(mean - half)), float(mean + half)), "sample_t"
    fit = fit_geometric(s, c, confidence)
    return fit.mean, fit.mean_ci, "geometric_mle"


def mean_escapees(escapees, clogged, confidence: float = 0.95
                  ) -> tuple[float, tuple[float, float]]:
    """Mean escapees before clogging, ``<s>``, with a confidence interval.

    When every realization clogged, the sample mean with a Student-t interval
    (lower end clipped at 0). When some are censored the sample mean is biased
    low, so the censoring-aware geometric fit's ``mean`` and ``mean_ci`` are
    returned instead. The two point estimates coincide when nothing is censored
    (``(1 - p_hat) / p_hat = sum(s) / n``). The fit's interval is also used when
    the t-interval degenerates (one realization, or all counts equal, which
    would give a zero-width interval).

    Parameters
    ----------
    escapees, clogged : array_like
        As in :func:`fit_geometric`.
    confidence : float, optional
        Confidence level (default 0.95).

    Returns
    -------
    mean : float
    ci : tuple of float

    Examples
    --------
    >>> m, (lo, hi) = mean_escapees([1, 2, 3, 4, 5], [True] * 5)
    >>> m, round(lo, 3), round(hi, 3)
    (3.0, 1.037, 4.963)
    """
    confidence = _check_confidence(confidence)
    s, c = _as_samples(escapees, clogged)
    mean, ci, _ = _mean_escapees(s, c, confidence)
    return mean, ci


def mean_difference(escapees_a, clogged_a, escapees_b, clogged_b,
                    confidence: float = 0.95, n_boot: int = 4000, seed: int = 0
                    ) -> tuple[float, tuple[float, float]]:
    """Change of the mean escapees ``<s>_b - <s>_a`` between two ensembles, with a
    percentile-bootstrap confidence interval.

    Each ensemble's mean is the estimate of :func:`mean_escapees` (the sample mean
    when all clogged, else the censoring-aware ``sum(s) / clogs``); the interval
    resamples the realizations of each ensemble independently (the two are
    independent runs, or runs of the same seeds that chaos has decorrelated).
    A resample with no clog has an unbounded mean: the interval's ends are then
    ``-inf`` or ``inf`` as such resamples make them.

    Examples
    --------
    >>> d, (lo, hi) = mean_difference([3, 5, 4, 6], [True] * 4, [8, 9, 7, 10], [True] * 4)
    >>> d, lo < d < hi
    (4.0, True)
    """
    confidence = _check_confidence(confidence)
    sa, ca = _as_samples(escapees_a, clogged_a)
    sb, cb = _as_samples(escapees_b, clogged_b)
    diff = _mean_escapees(sb, cb, confidence)[0] - _mean_escapees(sa, ca, confidence)[0]
    rng = np.random.default_rng(seed)

    def boot_means(s, c):
        idx = rng.integers(0, s.size, size=(n_boot, s.size))
        total, clogs = s[idx].sum(axis=1).astype(float), c[idx].sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            censored = np.where(clogs > 0, total / clogs, np.inf)
        # all clogged: the sample mean, which equals sum(s) / n
        return np.where(c[idx].all(axis=1), total / s.size, censored)

    d = boot_means(sb, cb) - boot_means(sa, ca)
    d = d[~np.isnan(d)]            # inf - inf: both resamples unbounded
    alpha = 0.5 * (1.0 - confidence)
    lo, hi = np.quantile(d, [alpha, 1.0 - alpha]) if d.size else (-np.inf, np.inf)
    return float(diff), (float(lo), float(hi))


def _integer_edges(max_s: int, bins) -> np.ndarray:
    if bins is None:
        return np.arange(max_s + 2)
    if np.ndim(bins) == 0:
        if int(bins) != bins or bins < 1:
            raise ValueError(f"bins must be a positive integer or a sequence of edges, got {bins!r}")
        # Equal integer widths, so every bin holds the same number of values of s.
        width = -(-(max_s + 1) // int(bins))
        return np.arange(0, max_s + 1 + width, width)
    edges = np.asarray(bins)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError("bins given as edges must be a strictly increasing 1-D sequence of >= 2 values")
    return edges


def histogram(escapees, clogged=None, bins=None) -> tuple[np.ndarray, np.ndarray]:
    """Counts of escapees over integer bins, clogged realizations only.

    Censored realizations are left out (their ``s`` is only a lower bound);
    :func:`fit_geometric` accounts for them.

    Parameters
    ----------
    escapees : array_like of int
    clogged : array_like of bool, optional
        ``None`` treats every realization as clogged.
    bins : None, int or sequence, optional
        ``None``: one bin per integer ``0 .. max(s)``. An int: at most that
        many bins of equal integer width covering ``0 .. max(s)``. A sequence:
        bin edges, with ``numpy.histogram``'s convention (``[a, b)``, the last
        bin closed).

    Returns
    -------
    counts : ndarray of int
    edges : ndarray
        ``len(counts) + 1`` edges; bin ``i`` holds ``edges[i] <= s < edges[i+1]``.

    Examples
    --------
    >>> counts, edges = histogram([0, 2, 2, 5], [True, True, True, False])
    >>> counts.tolist(), edges.tolist()
    ([1, 0, 2], [0, 1, 2, 3])
    """
    s = _as_escapees(escapees)
    c = np.ones(s.size, bool) if clogged is None else _as_clogged(clogged, s.size)
    kept = s[c]
    max_s = int(kept.max()) if kept.size else 0
    edges = _integer_edges(max_s, bins)
    counts, _ = np.histogram(kept, bins=edges)
    return counts.astype(np.int64), edges


def _pmf_undefined_reason(fit: GeometricFit) -> str | None:
    if fit.n_clogged == 0:
        return "no realization clogged"
    if not (math.isfinite(fit.mean) and fit.mean > 0):
        return f"<s> = {fit.mean} (every clogged realization had s = 0)"
    return None


def normalized_pmf(escapees, clogged, bins: int = 20, range_max: float | None = 5.0
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Density of ``x = s / <s>`` over the clogged realizations (Fig. 9 collapse).

    ``<s>`` is the censoring-aware fit mean (the sample mean when nothing is
    censored). The density is normalised by the number of clogged
    realizations, so ``sum(pmf) * bin_width`` is the fraction of them with
    ``x <= range_max``: 1 when the range covers them all (``range_max=None``
    makes it). For a geometric ``s`` with a large ``<s>`` the result
    approximates ``exp(-x)``. With censoring the clogged sample is truncated,
    so its shape departs from ``exp(-x)`` near the censoring counts.

    Parameters
    ----------
    escapees, clogged : array_like
        As in :func:`fit_geometric`.
    bins : int, optional
        Number of equal bins on ``[0, range_max]`` (default 20).
    range_max : float or None, optional
        Upper end of the bins in units of ``<s>`` (default 5); ``None`` uses
        the largest ``x``.

    Returns
    -------
    centres, pmf, stderr : ndarray
        Bin centres, density, and its binomial standard error
        ``sqrt(c (1 - c/n)) / (n w)`` (``c`` the bin count, ``n`` the clogged
        count, ``w`` the width): 0 for an empty bin, so a goodness-of-fit test
        should take its variance from the model instead.

    Raises
    ------
    ValueError
        No clogged realization, or ``<s> = 0``, so ``x`` is undefined; and the
        input errors of :func:`fit_geometric`.

    Examples
    --------
    >>> x, pmf, err = normalized_pmf([1, 3, 2, 6], [True] * 4, bins=4, range_max=2.0)
    >>> x.tolist(), pmf.tolist()
    ([0.25, 0.75, 1.25, 1.75], [0.5, 0.5, 0.5, 0.5])
    """
    s, c = _as_samples(escapees, clogged)
    if int(bins) != bins or bins < 1:
        raise ValueError(f"bins must be a positive integer, got {bins!r}")
    fit = fit_geometric(s, c)
    reason = _pmf_undefined_reason(fit)
    if reason is not None:
        raise ValueError(f"s/<s> is undefined: {reason}")
    x = s[c] / fit.mean
    top = float(x.max()) if range_max is None else float(range_max)
    if not top > 0:
        raise ValueError(f"range_max must be positive, got {range_max!r}")
    counts, edges = np.histogram(x, bins=int(bins), range=(0.0, top))
    n, width = x.size, edges[1] - edges[0]
    pmf = counts / (n * width)
    stderr = np.sqrt(counts * (1.0 - counts / n)) / (n * width)
    return 0.5 * (edges[:-1] + edges[1:]), pmf, stderr


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
    confidence = _check_confidence(confidence)
    c = _as_clogged(clogged)
    n = c.size
    f = float((~c).sum()) / n
    z2 = sps.norm.ppf(0.5 + 0.5 * confidence) ** 2
    centre = (f + z2 / (2 * n)) / (1 + z2 / n)
    half = math.sqrt(z2) / (1 + z2 / n) * math.sqrt(f * (1 - f) / n + z2 / (4 * n * n))
    # Clip rounding only: the exact Wilson ends lie in [0, 1].
    return f, (max(0.0, float(centre - half)), min(1.0, float(centre + half)))


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


def _plain(value):
    """Python floats/ints/lists with NaN and inf as None (strict JSON has neither)."""
    if isinstance(value, (tuple, list, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    value = float(value)
    return value if math.isfinite(value) else None


def summarize(escapees, clogged, confidence: float = 0.95, pmf_bins: int = 20,
              pmf_range_max: float = 5.0) -> dict:
    """Every statistic of this module as a JSON-serialisable dict.

    Values are plain ints, floats and lists; an infinite or undefined value
    (e.g. ``<s>`` with no clog, its interval's upper end) is ``None``, so that
    ``json.dumps(..., allow_nan=False)`` succeeds. ``normalized_pmf`` holds
    empty lists when ``s/<s>`` is undefined.

    Parameters
    ----------
    escapees, clogged : array_like
        As in :func:`fit_geometric`.
    confidence : float, optional
        Confidence level of every interval (default 0.95).
    pmf_bins, pmf_range_max : optional
        Passed to :func:`normalized_pmf`.

    Returns
    -------
    dict
        Keys: ``n``, ``n_clogged``, ``n_censored``, ``confidence``,
        ``mean_escapees``, ``mean_escapees_ci``, ``mean_escapees_method``
        (``"sample_t"`` or ``"geometric_mle"``), ``clog_probability_per_escapee``,
        ``clog_probability_per_escapee_ci``, ``fit_mean``, ``fit_mean_ci``,
        ``decay_rate``, ``decay_rate_stderr``, ``decay_rate_ci``,
        ``never_clogged_fraction``, ``never_clogged_fraction_ci``,
        ``histogram`` (``counts``, ``edges``) and ``normalized_pmf``
        (``centres``, ``pmf``, ``stderr``).

    Examples
    --------
    >>> import json
    >>> d = summarize([10, 20, 30], [False, False, False])
    >>> d["clog_probability_per_escapee"], d["fit_mean"]
    (0.0, None)
    >>> _ = json.dumps(d, allow_nan=False)
    """
    confidence = _check_confidence(confidence)
    s, c = _as_samples(escapees, clogged)
    fit = fit_geometric(s, c, confidence)
    mean, mean_ci, method = _mean_escapees(s, c, confidence)
    never, never_ci = never_clogged_fraction(c, confidence)
    counts, edges = histogram(s, c)
    if _pmf_undefined_reason(fit) is None:
        centres, pmf, stderr = normalized_pmf(s, c, pmf_bins, pmf_range_max)
    else:
        centres = pmf = stderr = []
    return {
        "n": fit.n,
        "n_clogged": fit.n_clogged,
        "n_censored": fit.n_censored,
        "confidence": confidence,
        "mean_escapees": _plain(mean),
        "mean_escapees_ci": _plain(mean_ci),
        "mean_escapees_method": method,
        "clog_probability_per_escapee": _plain(fit.p),
        "clog_probability_per_escapee_ci": _plain(fit.p_ci),
        "fit_mean": _plain(fit.mean),
        "fit_mean_ci": _plain(fit.mean_ci),
        "decay_rate": _plain(fit.decay_rate),
        "decay_rate_stderr": _plain(fit.decay_rate_stderr),
        "decay_rate_ci": _plain(fit.decay_rate_ci),
        "never_clogged_fraction": _plain(never),
        "never_clogged_fraction_ci": _plain(never_ci),
        "histogram": {"counts": _plain(counts), "edges": _plain(edges)},
        "normalized_pmf": {"centres": _plain(centres), "pmf": _plain(pmf),
                           "stderr": _plain(stderr)},
    }
