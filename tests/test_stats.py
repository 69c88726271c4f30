"""Escapee statistics against exact answers and samples of known distributions.

Samples are geometric on s = 0, 1, 2, ...: numpy's ``geometric`` counts trials
up to the first success (support 1, 2, ...), so ``s = rng.geometric(p) - 1`` has
``P(s) = (1 - p)^s p`` and ``<s> = (1 - p) / p``. Seeds are fixed, so every
test is deterministic; the tolerances say how likely a failure would be for a
fresh seed, i.e. how much the check could be tightened.
"""

import json
import math

import numpy as np
import pytest
from scipy import stats as sps

from taichi_hsdem.stats import (
    GeometricFit,
    clog_probability_per_escapee,
    exponential_rate_fit,
    fit_geometric,
    histogram,
    mean_escapees,
    never_clogged_fraction,
    normalized_pmf,
    summarize,
)


def geometric_sample(rng, p, n):
    return rng.geometric(p, n) - 1


def censor(s_true, cutoff):
    """A run that ends once `cutoff` particles escaped: those that would have
    clogged later are seen with s = cutoff and no clog (we only know S >= cutoff)."""
    clogged = s_true < cutoff
    return np.minimum(s_true, cutoff), clogged


def test_fit_matches_closed_form_and_recovers_p():
    rng = np.random.default_rng(11)
    p_true, n = 0.04, 400
    s = geometric_sample(rng, p_true, n)
    fit = fit_geometric(s, np.ones(n, bool))

    assert isinstance(fit, GeometricFit)
    assert (fit.n, fit.n_clogged, fit.n_censored) == (n, n, 0)
    # The MLE is closed-form; only rounding separates the two.
    assert fit.p == pytest.approx(n / (n + s.sum()), rel=1e-14)
    assert fit.mean == pytest.approx(s.mean(), rel=1e-12)
    assert fit.decay_rate == pytest.approx(-math.log(1 - fit.p), rel=1e-12)
    # The stated 95 % interval holds the true p (a fresh seed fails 1 time in 20).
    assert fit.p_ci[0] < p_true < fit.p_ci[1]
    assert fit.mean_ci[0] < (1 - p_true) / p_true < fit.mean_ci[1]
    assert fit.decay_rate_ci[0] < -math.log(1 - p_true) < fit.decay_rate_ci[1]
    # At n = 400 the likelihood-ratio interval is nearly the Wald one,
    # width 2 * 1.96 * sqrt(p^2 (1 - p) / n); they differ at O(n^-1/2) = 5 %,
    # so 10 % bounds the difference.
    wald_width = 2 * 1.959964 * math.sqrt(fit.p**2 * (1 - fit.p) / n)
    assert fit.p_ci[1] - fit.p_ci[0] == pytest.approx(wald_width, rel=0.10)
    # ... and the LR interval is skewed the way the likelihood is: longer above.
    assert fit.p_ci[1] - fit.p > fit.p - fit.p_ci[0]


def test_interval_points_have_the_likelihood_ratio_threshold():
    # Independent of the root finder: at both ends of the interval,
    # 2 [log L(p_hat) - log L(p)] must equal chi2_1(0.95) = 3.8415.
    s = np.array([3, 0, 7, 12, 5, 1, 30, 2])
    c = np.array([True, True, True, False, True, True, False, True])
    fit = fit_geometric(s, c)
    k, total = c.sum(), s.sum()

    def loglik(p):
        return k * math.log(p) + total * math.log1p(-p)

    for end in fit.p_ci:
        assert 2 * (loglik(fit.p) - loglik(end)) == pytest.approx(3.841459, abs=1e-6)
    wider = fit_geometric(s, c, confidence=0.99)
    assert wider.p_ci[0] < fit.p_ci[0] and wider.p_ci[1] > fit.p_ci[1]


@pytest.mark.parametrize("cutoff", [None, 30])
def test_interval_coverage_over_repeated_samples(cutoff):
    # 200 samples of n = 100 at p = 0.05 (<s> = 19); with cutoff = 30 about
    # 0.95^30 = 21 % of realizations are censored. If the 95 % interval is right,
    # the number covering p is Binomial(200, 0.95): mean 190, sd 3.1, so
    # [180, 198] (90-99 %) fails for a fresh seed with probability < 0.5 %.
    rng = np.random.default_rng(2024)
    p_true, n, reps = 0.05, 100, 200
    covered, rates, stderrs = 0, [], []
    for _ in range(reps):
        s_true = geometric_sample(rng, p_true, n)
        s, c = (s_true, np.ones(n, bool)) if cutoff is None else censor(s_true, cutoff)
        fit = fit_geometric(s, c)
        covered += fit.p_ci[0] <= p_true <= fit.p_ci[1]
        rates.append(fit.decay_rate)
        stderrs.append(fit.decay_rate_stderr)
    assert 0.90 <= covered / reps <= 0.99
    # The stated standard error of the decay rate matches the spread of the
    # rates: the sample sd of 200 values is uncertain by 1/sqrt(2*199) = 5 %,
    # and the delta method is first order (a few % low at n = 100); 20 % bounds both.
    assert np.mean(stderrs) == pytest.approx(np.std(rates, ddof=1), rel=0.20)
    # The rates centre on the true one: their mean is uncertain by sd/sqrt(200).
    true_rate = -math.log(1 - p_true)
    assert abs(np.mean(rates) - true_rate) < 4 * np.std(rates, ddof=1) / math.sqrt(reps)


def test_censoring_aware_fit_is_unbiased_and_naive_ones_are_not():
    rng = np.random.default_rng(7)
    p_true, n, cutoff = 0.02, 2000, 60
    s, c = censor(geometric_sample(rng, p_true, n), cutoff)
    # 0.98^60 = 30 % of the realizations are censored.
    assert (~c).mean() == pytest.approx(0.98**60, abs=0.03)  # 3 sd of a binomial fraction

    aware = fit_geometric(s, c)
    dropped = fit_geometric(s[c], c[c])  # forget the censored realizations
    as_clogged = fit_geometric(s, np.ones(n, bool))  # pretend they clogged at the end
    assert aware.n_censored == (~c).sum()
    assert aware.p_ci[0] < p_true < aware.p_ci[1]

    # What the naive estimators converge to, exactly: with q = 1 - p,
    # E[min(S, c)] = q (1 - q^c) / p and E[S | S < c] = (E[min] - c q^c) / (1 - q^c);
    # both estimators are 1 / (1 + that mean).
    q = 1 - p_true
    e_min = q * (1 - q**cutoff) / p_true
    e_trunc = (e_min - cutoff * q**cutoff) / (1 - q**cutoff)
    p_as_clogged, p_dropped = 1 / (1 + e_min), 1 / (1 + e_trunc)  # 0.0282, 0.0407
    assert p_dropped == pytest.approx(0.0407, abs=1e-4)
    assert p_as_clogged == pytest.approx(0.0282, abs=1e-4)

    # Both naive fits land on their (wrong) limits within their own intervals
    # and miss the true p by more than three widths of the aware interval
    # (about 12 standard errors: far beyond chance). Dropping the censored
    # realizations doubles p (halves <s>); counting them as clogs inflates p by 40 %.
    for naive, limit in ((dropped, p_dropped), (as_clogged, p_as_clogged)):
        assert naive.p_ci[0] < limit < naive.p_ci[1]
        assert naive.p_ci[0] > p_true
        assert naive.p - p_true > 3 * (aware.p_ci[1] - aware.p_ci[0])
    assert dropped.mean < 0.6 * (1 - p_true) / p_true
    # mean_escapees switches to the fit as soon as anything is censored.
    m, ci = mean_escapees(s, c)
    assert (m, ci) == (aware.mean, aware.mean_ci)
    assert ci[0] < (1 - p_true) / p_true < ci[1]


def test_mean_escapees_t_interval_when_uncensored():
    # Hand value: mean 3, sd sqrt(2.5), t_{0.975, 4} = 2.776445.
    m, ci = mean_escapees([1, 2, 3, 4, 5], [True] * 5)
    half = 2.776445 * math.sqrt(2.5) / math.sqrt(5)
    assert m == 3.0
    assert ci == pytest.approx((3 - half, 3 + half), abs=1e-6)
    # Uncensored, the fit's point estimate is the sample mean too.
    assert fit_geometric([1, 2, 3, 4, 5], [True] * 5).mean == pytest.approx(3.0, rel=1e-12)
    # The lower end is clipped at 0: s >= 0.
    assert mean_escapees([0, 0, 0, 9], [True] * 4)[1][0] == 0.0


def test_all_censored():
    s, c = [10, 20, 30], [False, False, False]
    fit = fit_geometric(s, c)
    assert (fit.p, fit.mean, fit.decay_rate) == (0.0, math.inf, 0.0)
    assert math.isnan(fit.decay_rate_stderr)
    # Exact one-sided bound: P(no clog in 60 arrivals) = (1 - p)^60 = 0.05,
    # so the rate interval is [0, -ln(0.05) / 60] = [0, 0.04993] (rule of three).
    assert fit.p_ci == (0.0, pytest.approx(1 - 0.05 ** (1 / 60), rel=1e-12))
    assert fit.decay_rate_ci == (0.0, pytest.approx(-math.log(0.05) / 60, rel=1e-12))
    assert fit.mean_ci == (pytest.approx(0.05 ** (1 / 60) / (1 - 0.05 ** (1 / 60))), math.inf)
    assert mean_escapees(s, c) == (math.inf, fit.mean_ci)
    assert never_clogged_fraction(c)[0] == 1.0
    with pytest.raises(ValueError, match="no realization clogged"):
        normalized_pmf(s, c)
    d = summarize(s, c)
    json.dumps(d, allow_nan=False)  # strict JSON: inf became None
    assert d["fit_mean"] is None and d["fit_mean_ci"][1] is None
    assert d["decay_rate_ci"][1] == pytest.approx(0.04993, abs=1e-5)
    assert d["histogram"]["counts"] == [0] and d["normalized_pmf"]["pmf"] == []


def test_all_zero_escapees():
    # Every realization clogged at once: p_hat = 1, and P(5 immediate clogs) = p^5,
    # so p >= 0.05^(1/5) = 0.5493.
    fit = fit_geometric([0] * 5, [True] * 5)
    assert (fit.p, fit.mean, fit.decay_rate, fit.decay_rate_stderr) == (1.0, 0.0, math.inf, math.inf)
    assert fit.p_ci == (pytest.approx(0.05**0.2, rel=1e-12), 1.0)
    assert fit.mean_ci == (0.0, pytest.approx((1 - 0.05**0.2) / 0.05**0.2, rel=1e-12))
    # The t-interval would have zero width here; the fit's is used.
    assert mean_escapees([0] * 5, [True] * 5) == (0.0, fit.mean_ci)
    with pytest.raises(ValueError, match="undefined"):
        normalized_pmf([0] * 5, [True] * 5)
    d = summarize([0] * 5, [True] * 5)
    json.dumps(d, allow_nan=False)
    assert d["mean_escapees_method"] == "geometric_mle" and d["decay_rate"] is None

    # Censored before anything escaped: no information on p at all.
    empty = fit_geometric([0, 0, 0], [False] * 3)
    assert math.isnan(empty.p) and empty.p_ci == (0.0, 1.0)
    assert empty.decay_rate_ci == (0.0, math.inf)
    json.dumps(summarize([0, 0, 0], [False] * 3), allow_nan=False)


def test_never_clogged_fraction_wilson():
    # Textbook Wilson 95 % interval for 3 of 10: (0.1078, 0.6032).
    f, ci = never_clogged_fraction([False] * 3 + [True] * 7)
    assert f == 0.3
    assert ci == pytest.approx((0.10779, 0.60322), abs=1e-5)
    # None of 10: the interval is [0, z^2 / (n + z^2)] = [0, 0.2775], not a
    # zero-width Wald interval.
    f, ci = never_clogged_fraction([True] * 10)
    assert f == 0.0
    assert ci == (0.0, pytest.approx(3.841459 / 13.841459, rel=1e-6))
    # 0/1 integers are read as flags.
    assert never_clogged_fraction([1, 0, 1, 1])[0] == 0.25


def test_histogram_counts_clogged_only():
    s = [0, 2, 2, 5, 7, 3]
    c = [True, True, True, False, True, True]
    counts, edges = histogram(s, c)
    assert edges.tolist() == list(range(9))  # one bin per integer 0..7
    assert counts.tolist() == [1, 0, 2, 1, 0, 0, 0, 1]  # the censored 5 left out
    counts, edges = histogram(s, c, bins=3)  # width ceil(8/3) = 3
    assert edges.tolist() == [0, 3, 6, 9] and counts.tolist() == [3, 1, 1]
    counts, _ = histogram(s, bins=[0, 1, 10])  # clogged=None: all realizations
    assert counts.tolist() == [1, 5]


def test_normalized_pmf_is_exp_minus_x_for_a_geometric_sample():
    rng = np.random.default_rng(5)
    p_true, n = 1 / 201, 20000  # <s> = 200, so s/<s> is nearly continuous
    s = geometric_sample(rng, p_true, n)
    c = np.ones(n, bool)

    x, pmf, err = normalized_pmf(s, c, bins=20, range_max=5.0)
    width = x[1] - x[0]
    assert width == pytest.approx(0.25)
    # Normalised by all clogged samples: the integral is the fraction below 5 <s>.
    below = np.mean(s / s.mean() <= 5.0)
    assert pmf.sum() * width == pytest.approx(below, rel=1e-12)
    x_all, pmf_all, _ = normalized_pmf(s, c, bins=20, range_max=None)
    assert pmf_all.sum() * (x_all[1] - x_all[0]) == pytest.approx(1.0, rel=1e-12)

    # Chi-square against the bin averages of exp(-x). Every bin holds > 30
    # samples, so the binomial errors are non-zero and near-Gaussian; 20 bins,
    # the 99.9 % point of chi2(20) is 45.3. Discreteness (50 integers per bin)
    # and the estimated <s> add O(1/50) to each bin, well below its error.
    expected = (np.exp(-(x - width / 2)) - np.exp(-(x + width / 2))) / width
    assert err.min() > 0
    chi2 = np.sum(((pmf - expected) / err) ** 2)
    assert chi2 < sps.chi2.ppf(0.999, df=x.size)
    # Binomial standard error of the first bin, by hand.
    c0 = pmf[0] * n * width
    assert err[0] == pytest.approx(math.sqrt(c0 * (1 - c0 / n)) / (n * width), rel=1e-12)


def test_aliases_agree_with_the_fit():
    s, c = [4, 1, 0, 5, 9], [True, True, True, True, False]
    fit = fit_geometric(s, c)
    assert clog_probability_per_escapee(s, c) == (fit.p, fit.p_ci)
    assert exponential_rate_fit(s, c) == (fit.decay_rate, fit.decay_rate_stderr)
    # Hand value: k = 4, S = 19, p = 4/23, rate se = p / sqrt(k (1 - p)).
    assert fit.p == pytest.approx(4 / 23)
    assert fit.decay_rate_stderr == pytest.approx((4 / 23) / math.sqrt(4 * 19 / 23))
    d = summarize(s, c)
    json.dumps(d, allow_nan=False)
    assert d["clog_probability_per_escapee"] == fit.p
    assert d["mean_escapees"] == fit.mean and d["mean_escapees_method"] == "geometric_mle"
    assert d["n_censored"] == 1 and d["never_clogged_fraction"] == 0.2
    assert sum(d["histogram"]["counts"]) == 4


@pytest.mark.parametrize(
    "escapees, clogged, message",
    [
        ([1, -2, 3], [True] * 3, "negative -2 at index 1"),
        ([1, 2.5, 3], [True] * 3, "non-integer 2.5 at index 1"),
        ([1, float("nan")], [True] * 2, "non-integer nan at index 1"),
        (["a", "b"], [True] * 2, "integer counts"),
        ([True, False], [3, 4], "booleans .are escapees and clogged swapped"),
        ([1, 2, 3], [True, False], r"differ in length \(3 vs 2\)"),
        ([], [], "escapees is empty"),
        ([[1, 2]], [[True, True]], "1-D"),
        ([1, 2], [True, 2], "clogged must hold booleans"),
    ],
)
def test_invalid_input_is_reported(escapees, clogged, message):
    with pytest.raises(ValueError, match=message):
        fit_geometric(escapees, clogged)
    with pytest.raises(ValueError, match=message):
        summarize(escapees, clogged)


def test_other_invalid_arguments():
    with pytest.raises(ValueError, match="clogged is empty"):
        never_clogged_fraction([])
    with pytest.raises(ValueError, match="confidence must lie strictly between 0 and 1"):
        fit_geometric([1, 2], [True, True], confidence=95)
    with pytest.raises(ValueError, match="bins must be a positive integer"):
        normalized_pmf([1, 2], [True, True], bins=0)
    with pytest.raises(ValueError, match="strictly increasing"):
        histogram([1, 2], bins=[0, 0, 3])
    # Whole-valued floats (as read back from JSON) are accepted.
    assert fit_geometric([1.0, 3.0], [True, True]).p == pytest.approx(2 / 6)  # k / (k + S)


def test_mean_difference_interval_covers_the_true_change():
    # 200 pairs of ensembles of n = 40 with <s> = 19 (p = 0.05) and <s> = 9 (p = 0.1),
    # the second censored at 25 escapees (6 % of it). The 95 % bootstrap interval of
    # the difference should cover the true -10 in Binomial(200, 0.95) cases: 90-99 %
    # allows for the percentile bootstrap running a little narrow at n = 40.
    from taichi_hsdem.stats import mean_difference
    rng = np.random.default_rng(11)
    covered = 0
    for k in range(200):
        a = geometric_sample(rng, 0.05, 40)
        b, cb = censor(geometric_sample(rng, 0.1, 40), 25)
        d, (lo, hi) = mean_difference(a, np.ones(40, bool), b, cb, n_boot=1000, seed=k)
        assert lo <= d <= hi
        covered += lo <= -10.0 <= hi
    assert 0.90 <= covered / 200 <= 0.99
    # the censoring-aware point estimate is the fit's own mean
    fa = fit_geometric(a, np.ones(40, bool))
    fb = fit_geometric(b, cb)
    assert d == pytest.approx(fb.mean - fa.mean, rel=1e-9)
