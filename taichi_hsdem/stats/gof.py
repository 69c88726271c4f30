"""Goodness of fit of the geometric law: is the clogging probability constant?

The geometric law ``P(s) = (1 - p)^s p`` (the exponential PMF of the paper's
Fig. 9) says exactly that the discrete hazard, the probability that the run
clogs at ``s`` given that it reached ``s``, is the same ``p`` at every ``s``.
:func:`geometric_fit_test` tests that.

The test
--------
The likelihood of clogged and censored counts factorises into independent
Bernoulli trials, one per value of ``s`` at which a run was at risk: a run
clogged at ``s_i`` survived the trials at ``0 .. s_i - 1`` and clogged at
``s_i``; a censored one survived ``0 .. s_i - 1``. This holds whatever the
(non-informative) censoring, so a test on the table of trials needs no model
of when runs were stopped. The test is the score test of ``beta = 0`` in

    logit h(s) = alpha + beta * log(1 + s),

a trend in the hazard table (Cochran-Armitage): ``beta > 0`` is a hazard that
rises with ``s`` (a discrete Weibull law of shape > 1), ``beta < 0`` one that
falls (early clogs from the initial packing; every mixture of geometric laws has
a falling hazard). With ``R_t`` runs at risk and ``O_t`` clogs at ``s = t``,
``N = sum R_t`` trials, ``p_hat = sum O_t / N`` and ``z_t = log(1 + t)``,

    U = sum z_t (O_t - p_hat R_t),
    V = p_hat (1 - p_hat) [sum R_t z_t^2 - (sum R_t z_t)^2 / N],
    Z = U / sqrt(V),

and ``Z`` is asymptotically standard normal under the geometric law (a score
statistic; for censored data the martingale central limit theorem), so the
two-sided p-value is ``2 Phi(-|Z|)`` and needs no simulation. The test is
locally most powerful against these alternatives and needs only the fit
under the null. It is not omnibus: a hazard that rises and then falls back
can pass it.

Why this test and not another (measured on ``floor`` of Weibull counts, whose
shape 1 is the geometric law; ``<s>`` = 19.5 unless said otherwise, censored
runs stopped at ``s`` = 24 (30 %); 10000 repetitions for a size, known to
+-0.0022, and 2000 for a power):

* A parametric bootstrap of a Kaplan-Meier distance would need the censoring
  count every clogged run would have had, which is never observed.
* With ``z = s`` instead of ``log(1 + s)`` the statistic is dominated by the
  few longest runs: size 0.064 at n = 20 (one tail 0.062), 0.083 at n = 10,
  and power 0.13 against a falling hazard (shape 0.7, n = 20) where
  ``log(1 + s)`` has 0.44 (4000 repetitions).
* With ``z = log(1 + s)`` the two-sided size at alpha = 0.05 is 0.048-0.055 for
  n = 10, 20, 50 and 100, uncensored or 30 % censored, and 0.048 at
  ``<s>`` = 300; 0.058 at ``<s>`` = 2.5 (n = 20). It runs low where few
  distinct ``s`` occur: 0.036 at ``<s>`` = 0.6, 0.029 at n = 10 with runs
  stopped at ``s`` = 5. The two tails are unequal without censoring at small n
  (0.013 below, 0.039 above at n = 20), so use the two-sided p-value.
* Below 10 clogs the size is erratic, so the test is not reported there
  (:data:`MIN_CLOGS`; measured at alpha = 0.05 with seeded samples of exactly
  ``k`` clogs, 10000 repetitions uncensored, ~1000-9000 censored): one clog is
  never rejected uncensored but 0.077 of the time with 30-60 % of the runs
  censored over n = 2-30, and 0.125 at n = 3 with 60 % censored (a p = 0.039
  from one clog is such a case; tests/test_stats.py); 2-4 clogs
  give 0.002-0.084 depending on ``<s>`` (2.5, 19.5, 300) and censoring; 5-9
  clogs 0.038-0.068. At 10 clogs it is 0.046-0.054 uncensored and 0.037-0.064
  censored, and 0.046-0.056 from 12 on.
* Power at n = 20: 0.63 against shape 1.5 (0.27 with runs stopped at 20, 37 %
  censored), 0.97 against shape 2, 0.44 against shape 0.7, 0.93 against shape
  0.5; at n = 50, 1.00 against shapes 2 and 0.5; at n = 100 with 30 %
  censored, 0.96 against shape 1.5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

from ._inputs import as_samples

METHOD = "score test: logit hazard linear in log(1+s)"

#: Fewest clogs for which the test (and the PMF of ``s/<s>`` it goes with) is
#: reported: below it the size at the 5 % level ranges 0.00-0.08 with ``<s>``
#: and the censoring, from it on 0.037-0.064 (module notes).
MIN_CLOGS = 10


@dataclass(frozen=True)
class GeometricFitTest:
    """Result of :func:`geometric_fit_test`.

    Attributes
    ----------
    method : str
        What was tested (module notes).
    statistic : float or None
        ``Z``, standard normal under the geometric law; positive when the
        hazard rises with ``s``. None when not reported (``reason``).
    p_value : float or None
        Two-sided, ``2 Phi(-|Z|)``; None with ``statistic``.
    n_clogged : int
        Clogs in the data (each is one event of the hazard table).
    reason : str or None
        Why there is no statistic: too few clogs for the test to hold its size,
        or data that hold no information on the hazard's shape; None when
        reported.
    """

    method: str
    statistic: float | None
    p_value: float | None
    n_clogged: int
    reason: str | None = None


def hazard_table(escapees, clogged) -> tuple[np.ndarray, np.ndarray]:
    """Runs at risk ``R_t`` and clogs ``O_t`` at each ``s = t = 0 .. max(s)``.

    A run is at risk at ``t`` when ``s_i > t``, or ``s_i = t`` and it clogged
    there; a censored run's last trial is at ``s_i - 1``.

    Examples
    --------
    >>> at_risk, clogs = hazard_table([0, 2, 3], [True, True, False])
    >>> at_risk.tolist(), clogs.tolist()
    ([3, 2, 2, 0], [1, 0, 1, 0])
    """
    s, c = as_samples(escapees, clogged)
    size = int(s.max()) + 1
    at_s = np.bincount(s, minlength=size)
    reached = np.cumsum(at_s[::-1])[::-1]          # runs with s_i >= t
    clogs = np.bincount(s[c], minlength=size)
    return reached - at_s + clogs, clogs


def geometric_fit_test(escapees, clogged, min_clogs: int = MIN_CLOGS) -> GeometricFitTest:
    """Test the constant clogging probability of the geometric law (module notes).

    Parameters
    ----------
    escapees, clogged : array_like
        As in :func:`~taichi_hsdem.stats.fit_geometric`; censored runs count.
    min_clogs : int, optional
        Fewest clogs to report the test for (default :data:`MIN_CLOGS`, below
        which its size is not the nominal one), >= 1.

    Returns
    -------
    GeometricFitTest
        ``statistic`` and ``p_value`` are None, and ``reason`` says why, with
        fewer than ``min_clogs`` clogs, or when the data hold no information on
        the shape of the hazard: every run at risk only at ``s = 0``, or every
        trial a clog.

    Examples
    --------
    A hazard that rises with ``s`` (every run clogs between 8 and 12) is
    rejected; counts spread like a geometric sample are not; one clog is not
    tested:

    >>> late = geometric_fit_test([8, 9, 10, 11, 12, 10, 9, 11, 12, 10], [True] * 10)
    >>> late.statistic > 0, late.p_value < 0.01
    (True, True)
    >>> round(geometric_fit_test([0, 1, 3, 0, 7, 2, 1, 12, 4, 0], [True] * 10).p_value, 3)
    0.673
    >>> geometric_fit_test([3, 20, 20], [True, False, False]).reason
    '1 clog: the test needs 10 or more to hold its size (below, the chance of rejecting a true geometric law at the 5 % level ranges 0.00-0.08)'
    """
    if isinstance(min_clogs, bool) or int(min_clogs) != min_clogs or min_clogs < 1:
        raise ValueError(f"min_clogs must be a positive integer, got {min_clogs!r}")
    s, c = as_samples(escapees, clogged)
    k = int(c.sum())

    def untested(reason):
        return GeometricFitTest(method=METHOD, statistic=None, p_value=None, n_clogged=k,
                                reason=reason)

    if k < min_clogs:
        return untested(f"{k} clog{'' if k == 1 else 's'}: the test needs {min_clogs} or more "
                        "to hold its size (below, the chance of rejecting a true geometric "
                        "law at the 5 % level ranges 0.00-0.08)")
    at_risk, clogs = hazard_table(s, c)
    z = np.log1p(np.arange(at_risk.size, dtype=float))
    trials, events = float(at_risk.sum()), float(clogs.sum())
    if events == trials:
        return untested("every realization clogged at s = 0: the hazard is seen at s = 0 only")
    p = events / trials
    score = float(np.sum(z * (clogs - p * at_risk)))
    spread = float(np.sum(at_risk * z**2) - np.sum(at_risk * z) ** 2 / trials)
    # spread is 0 (up to rounding) when every trial is at s = 0.
    if spread <= 1e-12 * max(1.0, float(np.sum(at_risk * z**2))):
        return untested("every trial is at s = 0: no change of the hazard with s to test")
    stat = score / math.sqrt(p * (1.0 - p) * spread)
    return GeometricFitTest(method=METHOD, statistic=stat,
                            p_value=2.0 * float(sps.norm.sf(abs(stat))), n_clogged=k)
