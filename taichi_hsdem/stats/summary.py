"""Every statistic of an ensemble in one JSON-serialisable dict, and the bias
that unstable realizations may carry.

Unstable realizations (a run stopped by the solver, not by a clog or the end
time) hold no usable count and are left out of every statistic. Leaving one
out is the same as keeping it as censored at ``s = 0`` (it adds nothing to the
likelihood), which is unbiased only if instability is unrelated to when the
run would have clogged. :func:`unstable_sensitivity` bounds the effect.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from ._inputs import as_escapees, as_samples, check_confidence
from .geometric import fit_geometric, never_clogged_fraction
from .gof import geometric_fit_test
from .pmf import PMF_BIN_FRACTION, _pmf_undefined_reason, histogram, pmf_bins
from .text import estimate_text

UNSTABLE_NOTE = (
    "unstable realizations are left out of every statistic, as if censored at s = 0: "
    "unbiased only if instability is unrelated to clogging. <s> would be "
    "mean_escapees_if_unstable_clogged_at_zero had they all clogged at once (the lowest "
    "possible), and mean_escapees_if_unstable_censored_at_last_count (given their counts) "
    "had they been kept as runs stopped without a clog")


def _check_unstable(n_unstable, unstable_escapees) -> tuple[int, np.ndarray | None]:
    if unstable_escapees is not None and len(unstable_escapees) == 0:
        unstable_escapees = None
    if unstable_escapees is not None:
        unstable_escapees = as_escapees(unstable_escapees, "unstable_escapees")
        if n_unstable == 0:
            n_unstable = unstable_escapees.size
    if isinstance(n_unstable, bool) or int(n_unstable) != n_unstable or n_unstable < 0:
        raise ValueError(f"n_unstable must be a non-negative integer, got {n_unstable!r}")
    n_unstable = int(n_unstable)
    if unstable_escapees is not None and unstable_escapees.size != n_unstable:
        raise ValueError(f"n_unstable is {n_unstable} but unstable_escapees holds "
                         f"{unstable_escapees.size} counts: give one count per unstable run")
    return n_unstable, unstable_escapees


def unstable_sensitivity(escapees, clogged, n_unstable: int = 0, unstable_escapees=None
                         ) -> dict:
    """How far ``<s>`` could move had the unstable realizations been kept.

    Parameters
    ----------
    escapees, clogged : array_like
        The stable realizations, as in :func:`~taichi_hsdem.stats.fit_geometric`.
    n_unstable : int, optional
        Unstable realizations left out (default 0; taken from
        ``unstable_escapees`` when that is given and this is 0).
    unstable_escapees : array_like of int, optional
        Escapees of each unstable realization when it stopped.

    Returns
    -------
    dict
        ``n_unstable``; ``mean_escapees_if_unstable_clogged_at_zero``,
        ``sum(s) / (n_clogged + n_unstable)``, the lowest ``<s>`` any outcome of
        those runs could give; ``mean_escapees_if_unstable_censored_at_last_count``,
        ``(sum(s) + sum(unstable_escapees)) / n_clogged``, the estimate had they
        been kept as stopped without a clog (NaN when their counts are not
        given); and ``note``, saying so. With no unstable run both equal the
        estimate.

    Examples
    --------
    >>> d = unstable_sensitivity([4, 6, 10], [True, True, False], 2, [3, 7])
    >>> d["mean_escapees_if_unstable_clogged_at_zero"], d["mean_escapees_if_unstable_censored_at_last_count"]
    (5.0, 15.0)
    """
    s, c = as_samples(escapees, clogged)
    n_unstable, s_unstable = _check_unstable(n_unstable, unstable_escapees)
    k, total = int(c.sum()), int(s.sum())
    estimate = fit_geometric(s, c).mean
    if n_unstable == 0:
        low = high = estimate
    else:
        low = total / (k + n_unstable)
        if s_unstable is None:
            high = math.nan
        else:
            extra = total + int(s_unstable.sum())
            high = extra / k if k else (math.inf if extra else math.nan)
    return {"n_unstable": n_unstable,
            "mean_escapees_if_unstable_clogged_at_zero": low,
            "mean_escapees_if_unstable_censored_at_last_count": high,
            "note": UNSTABLE_NOTE if n_unstable else "no unstable realization"}


def _plain(value):
    """Python floats/ints/lists with NaN and inf as None (strict JSON has neither)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list, np.ndarray)):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    value = float(value)
    return value if math.isfinite(value) else None


def summarize(escapees, clogged, confidence: float = 0.95, *,
              pmf_bin_fraction: float = PMF_BIN_FRACTION, pmf_max_x=None,
              n_unstable: int = 0, unstable_escapees=None) -> dict:
    """Every statistic of this package as a JSON-serialisable dict.

    Values are plain ints, floats, strings and lists; an infinite or undefined
    value (e.g. ``<s>`` with no clog, its interval's upper end) is ``None``, so
    that ``json.dumps(..., allow_nan=False)`` succeeds.

    Parameters
    ----------
    escapees, clogged : array_like
        The stable realizations, as in :func:`~taichi_hsdem.stats.fit_geometric`.
    confidence : float, optional
        Confidence level of every interval (default 0.95).
    pmf_bin_fraction, pmf_max_x : optional
        ``bin_fraction`` and ``max_x`` of :func:`~taichi_hsdem.stats.pmf_bins`.
    n_unstable, unstable_escapees : optional
        The unstable realizations left out
        (:func:`~taichi_hsdem.stats.unstable_sensitivity`).

    Returns
    -------
    dict
        * ``n``, ``n_clogged``, ``n_censored`` (also as ``n_never_clogged``),
          ``n_unstable``, ``confidence``.
        * ``mean_escapees``: ``<s>``, the censoring-aware MLE ``sum(s) / n_clogged``;
          ``mean_escapees_ci``, its profile-likelihood interval;
          ``mean_escapees_method`` (``"geometric_mle"``, always) and
          ``mean_escapees_ci_method`` (``"profile_likelihood"``, or
          ``"exact_one_sided"`` / ``"uninformative"`` at the boundaries of
          :func:`~taichi_hsdem.stats.fit_geometric`).
        * ``mean_escapees_lower_bound``: when nothing clogged, the one-sided
          lower confidence bound of ``<s>`` (the interval's lower end; what the
          runs show), else None; ``mean_escapees_note``: why ``mean_escapees``
          is None (a sentence to print), else None.
        * ``plain_mean_escapees``: the plain mean of the counts, biased low when
          anything is censored (a never-clogged run counted as a clog).
        * ``clog_probability_per_escapee`` (``_ci``), ``fit_mean`` (``_ci``,
          the same as ``mean_escapees``), ``decay_rate``,
          ``decay_rate_stderr``, ``decay_rate_ci``, ``never_clogged_fraction``
          (``_ci``, Wilson).
        * ``geometric_fit_test``: ``method``, ``statistic``, ``p_value``,
          ``n_clogged``, ``reason`` of
          :func:`~taichi_hsdem.stats.geometric_fit_test` (None and a reason
          below :data:`~taichi_hsdem.stats.MIN_CLOGS` clogs).
        * ``unstable_sensitivity``: :func:`~taichi_hsdem.stats.unstable_sensitivity`.
        * ``histogram``: ``counts``, ``edges`` (clogged realizations, one bin per s).
        * ``normalized_pmf``: the bins of :func:`~taichi_hsdem.stats.pmf_bins`
          as columns ``centres`` (``x``), ``pmf``, ``stderr``, ``count``,
          ``s_lo``, ``s_hi``, with ``bin_width_x``, ``mean_s`` and
          ``n_realizations`` (the normaliser: all stable realizations);
          empty lists and ``None`` when ``s/<s>`` is undefined, ``reason``
          then saying why (else None).

    Examples
    --------
    >>> import json
    >>> d = summarize([460, 500, 500], [True, False, False])
    >>> d["mean_escapees"], d["plain_mean_escapees"], d["mean_escapees_ci_method"]
    (1460.0, 486.6666666666667, 'profile_likelihood')
    >>> d = summarize([10, 20, 30], [False, False, False], n_unstable=1)
    >>> d["clog_probability_per_escapee"], d["mean_escapees"], d["n_unstable"]
    (0.0, None, 1)
    >>> round(d["mean_escapees_lower_bound"], 2), d["mean_escapees_note"]
    (19.53, 'no realization clogged (3 ran): <s> > 19.5 (nothing clogged; 95 % lower bound)')
    >>> _ = json.dumps(d, allow_nan=False)
    """
    confidence = check_confidence(confidence)
    s, c = as_samples(escapees, clogged)
    fit = fit_geometric(s, c, confidence)
    never, never_ci = never_clogged_fraction(c, confidence)
    counts, edges = histogram(s, c)
    bins = pmf_bins(s, c, pmf_bin_fraction, pmf_max_x)
    columns = {name: [b[key] for b in bins] for name, key in
               (("centres", "x"), ("pmf", "pmf"), ("stderr", "stderr"), ("count", "count"),
                ("s_lo", "s_lo"), ("s_hi", "s_hi"))}
    for key in ("bin_width_x", "mean_s", "n_realizations"):
        columns[key] = bins[0][key] if bins else None
    columns["reason"] = _pmf_undefined_reason(fit)
    lower_bound, note = None, None
    if fit.n_clogged == 0:
        if fit.ci_method == "uninformative":
            note = (f"nothing escaped and nothing clogged ({fit.n} ran): the runs say "
                    "nothing about <s>")
        else:
            lower_bound = fit.mean_ci[0]
            note = (f"no realization clogged ({fit.n} ran): <s> "
                    f"{estimate_text(None, None, lower_bound, confidence)}")
    unstable = unstable_sensitivity(s, c, n_unstable, unstable_escapees)
    return _plain({
        "n": fit.n,
        "n_clogged": fit.n_clogged,
        "n_censored": fit.n_censored,
        "n_never_clogged": fit.n_censored,
        "n_unstable": unstable["n_unstable"],
        "confidence": confidence,
        "mean_escapees": fit.mean,
        "mean_escapees_ci": fit.mean_ci,
        "mean_escapees_method": "geometric_mle",
        "mean_escapees_ci_method": fit.ci_method,
        "mean_escapees_lower_bound": lower_bound,
        "mean_escapees_note": note,
        "plain_mean_escapees": float(s.mean()),
        "clog_probability_per_escapee": fit.p,
        "clog_probability_per_escapee_ci": fit.p_ci,
        "fit_mean": fit.mean,
        "fit_mean_ci": fit.mean_ci,
        "decay_rate": fit.decay_rate,
        "decay_rate_stderr": fit.decay_rate_stderr,
        "decay_rate_ci": fit.decay_rate_ci,
        "never_clogged_fraction": never,
        "never_clogged_fraction_ci": never_ci,
        "geometric_fit_test": asdict(geometric_fit_test(s, c)),
        "unstable_sensitivity": unstable,
        "histogram": {"counts": counts, "edges": edges},
        "normalized_pmf": columns,
    })
