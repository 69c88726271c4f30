"""Statistics of escapees before clogging (docs/model.md section 4, Figs. 9-13).

Each realization of a clogging run yields ``s``, the number of particles that
passed the constriction, and whether a clog ended it. The reference paper finds
``s`` geometric, ``P(s) = (1 - p)^s p`` on ``s = 0, 1, 2, ...``: every particle
reaching the constriction clogs it with a probability ``p``, independently of the
others, so ``P(s) ~ exp(-lambda s)`` with ``lambda = -ln(1 - p)`` and
``<s> = (1 - p) / p``.

A realization that reached the end time without clogging is right-censored: its
true ``s`` is at least the observed count. Dropping such realizations, or
counting them as clogs (the plain mean of the counts), biases ``p`` upwards
(``<s>`` downwards); the likelihood uses them correctly.

One module per concern, re-exported here as a flat API:

* :mod:`.geometric`: the censoring-aware fit (:func:`fit_geometric`), ``<s>``
  with its profile-likelihood interval (:func:`mean_escapees`), ``p``,
  ``lambda`` and the never-clogged fraction.
* :mod:`.difference`: the change of ``<s>`` between two ensembles
  (:func:`mean_difference`).
* :mod:`.pmf`: the histogram and the PMF of ``s / <s>`` on bins of whole ``s``
  (:func:`pmf_bins`).
* :mod:`.gof`: the test of the geometric law's constant clogging probability
  (:func:`geometric_fit_test`), reported from :data:`MIN_CLOGS` clogs on.
* :mod:`.summary`: everything in one JSON-ready dict (:func:`summarize`), and
  the bias unstable realizations may carry (:func:`unstable_sensitivity`).
* :mod:`.text`: the one way every message, table and figure writes ``<s>``
  (:func:`estimate_text`: ``> 2.86 (nothing clogged; 95 % lower bound)`` when
  nothing clogged; :func:`censored_fields` for CSV and JSON).

Examples
--------
>>> from taichi_hsdem import stats
>>> fit = stats.fit_geometric([3, 0, 7, 12, 5], [True, True, True, False, True])
>>> round(fit.p, 4), fit.n_censored, fit.mean
(0.129, 1, 6.75)
"""

from .difference import mean_difference
from .geometric import (
    GeometricFit,
    clog_probability_per_escapee,
    exponential_rate_fit,
    fit_geometric,
    mean_escapees,
    never_clogged_fraction,
)
from .gof import MIN_CLOGS, GeometricFitTest, geometric_fit_test, hazard_table
from .pmf import PMF_BIN_FRACTION, histogram, normalized_pmf, pmf_bins
from .summary import summarize, unstable_sensitivity
from .text import censored_fields, estimate_text, mean_phrase

__all__ = [
    "GeometricFit",
    "fit_geometric",
    "mean_escapees",
    "mean_difference",
    "histogram",
    "pmf_bins",
    "normalized_pmf",
    "PMF_BIN_FRACTION",
    "never_clogged_fraction",
    "clog_probability_per_escapee",
    "exponential_rate_fit",
    "GeometricFitTest",
    "MIN_CLOGS",
    "geometric_fit_test",
    "hazard_table",
    "summarize",
    "unstable_sensitivity",
    "estimate_text",
    "mean_phrase",
    "censored_fields",
]
