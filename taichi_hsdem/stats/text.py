"""One way to write ``<s>``, the mean escapees before a clog, in every message, table
and figure of the package: an estimate with its interval, ``12.3 [8.1, 17.9]``, or,
when nothing clogged (every realization censored), the one-sided lower confidence
bound, ``> 2.86 (nothing clogged; 95 % lower bound)``, never an infinite or missing
estimate beside an interval. In CSV and JSON the same case is a null estimate with
the bound in its own field (:func:`censored_fields`; ``summary.json``'s
``statistics.mean_escapees_lower_bound``, ``sweep.csv``'s
``mean_escapees_lower_bound``, ``points.csv``'s ``mean_s_lower_bound``)."""
from __future__ import annotations

import math

#: What follows the bound when nothing clogged.
NOTHING_CLOGGED = "nothing clogged"


def _real(v) -> bool:
    return v is not None and not isinstance(v, str) and math.isfinite(float(v))


def lower_bound_of(mean, ci, lower_bound=None) -> float | None:
    """The one-sided lower bound of a censored-only ``<s>`` (``mean`` None, NaN or
    infinite; the bound ``lower_bound`` or else ``ci``'s lower end, when positive and
    finite), else None (an estimate, or nothing known at all)."""
    if _real(mean):
        return None
    for v in (lower_bound, (ci or (None, None))[0]):
        if _real(v) and float(v) > 0:
            return float(v)
    return None


def estimate_text(mean, ci=None, lower_bound=None, confidence: float = 0.95,
                  digits: int = 3) -> str:
    """``<s>`` (or any mean escapees) for a message.

    Parameters
    ----------
    mean : float or None
        The estimate; None, NaN or infinite when nothing clogged.
    ci : (lo, hi) or None
        Its interval (``hi`` None or infinite when unbounded).
    lower_bound : float, optional
        The one-sided bound when nothing clogged (default: ``ci``'s lower end).
    confidence : float
        The bound's confidence level (default 0.95).

    Examples
    --------
    >>> estimate_text(12.34, (8.1, 17.9))
    '12.3 [8.1, 17.9]'
    >>> estimate_text(12.34, (8.1, None))
    '12.3 [8.1, inf]'
    >>> estimate_text(None, (2.857, None))
    '> 2.86 (nothing clogged; 95 % lower bound)'
    >>> estimate_text(math.inf, (2.857, math.inf))
    '> 2.86 (nothing clogged; 95 % lower bound)'
    >>> estimate_text(None, (0.0, None))            # nothing escaped or clogged
    '-'
    """
    bound = lower_bound_of(mean, ci, lower_bound)
    if bound is not None:
        return (f"> {bound:.{digits}g} ({NOTHING_CLOGGED}; {100 * confidence:g} % "
                "lower bound)")
    if not _real(mean):
        return "-"          # nothing known: no stable realization, or none escaped

    if ci is None:
        return f"{float(mean):.{digits}g}"

    def num(v, missing):
        if v is None:
            return missing
        v = float(v)
        if math.isnan(v):
            return "-"
        return ("inf" if v > 0 else "-inf") if math.isinf(v) else f"{v:.{digits}g}"
    lo, hi = ci
    return f"{float(mean):.{digits}g} [{num(lo, '-')}, {num(hi, 'inf')}]"


def mean_phrase(mean, ci=None, lower_bound=None, confidence: float = 0.95,
                name: str = "<s>") -> str:
    """``<s>`` with its value for a line of text, reading one way whatever is known.

    >>> mean_phrase(12.34, (8.1, 17.9))
    '<s> = 12.3 [8.1, 17.9]'
    >>> mean_phrase(None, (2.857, None))
    '<s> > 2.86 (nothing clogged; 95 % lower bound)'
    >>> mean_phrase(None, (0.0, None))
    '<s>: no estimate (nothing escaped or clogged)'
    """
    text = estimate_text(mean, ci, lower_bound, confidence)
    if text == "-":
        return f"{name}: no estimate (nothing escaped or clogged)"
    return f"{name} {text}" if text.startswith(">") else f"{name} = {text}"


def censored_fields(mean, ci) -> tuple[float | None, float | None]:
    """``(estimate, lower_bound)`` for a table or JSON: the estimate (None when
    nothing clogged or nothing is known) and the one-sided lower bound when nothing
    clogged (else None).

    >>> censored_fields(12.3, (8.1, 17.9))
    (12.3, None)
    >>> censored_fields(math.inf, (2.86, math.inf))
    (None, 2.86)
    """
    bound = lower_bound_of(mean, ci)
    return (float(mean) if _real(mean) else None), bound
