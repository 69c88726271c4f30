"""Histogram of the escapees and the PMF of ``x = s / <s>`` (Fig. 9 collapse).

The PMF's bins hold whole values of ``s``: a bin of ``m`` consecutive integers
spans ``m / <s>`` in ``x``, so no bin holds more values of ``s`` than another
(bins of equal width in ``x`` would not: with ``<s> = 3.2`` and width 0.25,
every fifth bin would hold no integer at all and stay empty).

Normalisation and censoring. The density is ``count / (n * m / <s>)`` with
``n`` *all* the realizations, clogged or not: the count of bin ``j`` over ``n``
estimates ``P(S in bin j, and the run clogged there before it ended)``. For a
bin below every censored count that is ``P(S in bin j)`` itself, so for a
geometric ``s`` with a large ``<s>`` the density follows ``exp(-x)`` there
whatever the censoring; above the censored counts it falls below ``exp(-x)``
(runs that would have clogged there were stopped first), and the area under
the whole curve is the clogged fraction, not 1. Dividing by the clogged count
instead would lift the whole curve by ``n / n_clogged`` (1.4 with 30 %
censored).
"""

from __future__ import annotations

import math

import numpy as np

from ._inputs import as_clogged, as_escapees, as_samples
from .geometric import fit_geometric

PMF_BIN_FRACTION = 0.5  # default PMF bin width in units of <s> (rounded to whole s)


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
    :func:`~taichi_hsdem.stats.fit_geometric` accounts for them.

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
    s = as_escapees(escapees)
    c = np.ones(s.size, bool) if clogged is None else as_clogged(clogged, s.size)
    kept = s[c]
    max_s = int(kept.max()) if kept.size else 0
    edges = _integer_edges(max_s, bins)
    counts, _ = np.histogram(kept, bins=edges)
    return counts.astype(np.int64), edges


def _pmf_undefined_reason(fit) -> str | None:
    if fit.n_clogged == 0:
        return "no realization clogged"
    if not (math.isfinite(fit.mean) and fit.mean > 0):
        return f"<s> = {fit.mean} (every clogged realization had s = 0)"
    return None


def pmf_bins(escapees, clogged, bin_fraction: float = PMF_BIN_FRACTION, max_x=None
             ) -> list[dict]:
    """PMF of ``x = s / <s>`` on bins of whole ``s``, normalised by all realizations.

    ``<s>`` is the censoring-aware fit mean
    (:func:`~taichi_hsdem.stats.fit_geometric`). Each bin holds
    ``m = max(1, round(bin_fraction * <s>))`` consecutive values of ``s``, from
    ``s = 0`` to past the largest clogged ``s`` (and to ``max_x * <s>`` at
    least). The module notes say what censoring does to the curve.

    Parameters
    ----------
    escapees, clogged : array_like
        As in :func:`~taichi_hsdem.stats.fit_geometric`.
    bin_fraction : float, optional
        Target bin width in units of ``<s>`` (default 0.5), rounded to whole ``s``.
    max_x : float or None, optional
        Extend the bins to ``x = max_x`` at least (default: to the largest
        clogged ``s``).

    Returns
    -------
    list of dict
        One per bin: ``s_lo``, ``s_hi`` (the bin's first and last ``s``), ``x``
        (its mean ``s`` over ``<s>``), ``count`` (clogged realizations in it),
        ``pmf`` (``count / (n_realizations * bin_width_x)``), ``stderr`` (binomial,
        ``sqrt(count (1 - count / n_realizations)) / (n_realizations *
        bin_width_x)``, 0 for an empty bin), ``mean_s``, ``bin_width_x``
        (``m / <s>``), ``n_clogged`` and ``n_realizations``. Empty when
        ``s / <s>`` is undefined (no clog, or ``<s> = 0``).

    Raises
    ------
    ValueError
        ``bin_fraction`` or ``max_x`` not positive, and the input errors of
        :func:`~taichi_hsdem.stats.fit_geometric`.

    Examples
    --------
    >>> bins = pmf_bins([1, 3, 2, 6, 9], [True, True, True, True, False], bin_fraction=0.4)
    >>> bins[0]["mean_s"], [(b["s_lo"], b["s_hi"], b["count"]) for b in bins]
    (5.25, [(0, 1, 1), (2, 3, 2), (4, 5, 0), (6, 7, 1)])
    >>> round(sum(b["pmf"] * b["bin_width_x"] for b in bins), 12)   # clogged fraction
    0.8
    """
    s, c = as_samples(escapees, clogged)
    if not (math.isfinite(bin_fraction) and bin_fraction > 0):
        raise ValueError(f"bin_fraction must be a positive number, got {bin_fraction!r}")
    if max_x is not None and not (math.isfinite(max_x) and max_x > 0):
        raise ValueError(f"max_x must be a positive number or None, got {max_x!r}")
    fit = fit_geometric(s, c)
    if _pmf_undefined_reason(fit) is not None:
        return []
    mean = fit.mean
    m = max(1, int(round(bin_fraction * mean)))
    top = int(s[c].max()) + 1
    if max_x is not None:
        top = max(top, int(math.ceil(max_x * mean)))
    edges = np.arange(0, (-(-top // m) + 1) * m, m)
    counts, _ = histogram(s, c, bins=edges)
    n, width = int(s.size), m / mean
    return [{"s_lo": int(lo), "s_hi": int(lo) + m - 1, "x": (lo + 0.5 * (m - 1)) / mean,
             "count": int(cnt), "pmf": cnt / (n * width),
             "stderr": math.sqrt(cnt * (1.0 - cnt / n)) / (n * width),
             "mean_s": mean, "bin_width_x": width, "n_clogged": fit.n_clogged,
             "n_realizations": n}
            for lo, cnt in zip(edges[:-1].tolist(), counts.tolist())]


def normalized_pmf(escapees, clogged, bin_fraction: float = PMF_BIN_FRACTION, max_x=None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bins of :func:`pmf_bins` as arrays, raising where the PMF is undefined.

    Parameters
    ----------
    escapees, clogged, bin_fraction, max_x
        As in :func:`pmf_bins`.

    Returns
    -------
    x, pmf, stderr : ndarray
        Each bin's mean ``s / <s>``, density (normalised by all realizations)
        and binomial standard error.

    Raises
    ------
    ValueError
        No clogged realization, or ``<s> = 0``, so ``x`` is undefined; and the
        errors of :func:`pmf_bins`.

    Examples
    --------
    >>> x, pmf, err = normalized_pmf([0, 1, 2, 3], [True] * 4, bin_fraction=0.5)
    >>> x.tolist(), pmf.tolist()
    ([0.0, 0.6666666666666666, 1.3333333333333333, 2.0], [0.375, 0.375, 0.375, 0.375])
    """
    s, c = as_samples(escapees, clogged)
    bins = pmf_bins(s, c, bin_fraction, max_x)
    if not bins:
        raise ValueError(f"s/<s> is undefined: {_pmf_undefined_reason(fit_geometric(s, c))}")
    return tuple(np.array([b[k] for b in bins], dtype=float) for k in ("x", "pmf", "stderr"))
