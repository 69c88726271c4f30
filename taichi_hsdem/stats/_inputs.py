"""Input checks shared by the statistics.

The counts come from runs, files or the command line, so every error names what
is wrong in the user's terms.
"""

from __future__ import annotations

import numpy as np


def check_confidence(confidence: float) -> float:
    confidence = float(confidence)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie strictly between 0 and 1, got {confidence}")
    return confidence


def as_clogged(clogged, n_expected: int | None = None) -> np.ndarray:
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


def as_escapees(escapees, name: str = "escapees") -> np.ndarray:
    s = np.asarray(escapees)
    if s.ndim != 1:
        raise ValueError(f"{name} must be a 1-D sequence of counts, got shape {s.shape}")
    if s.size == 0:
        raise ValueError(f"{name} is empty: need at least one realization")
    if s.dtype == bool:
        raise ValueError(
            f"{name} must be integer counts, got booleans (are escapees and clogged swapped?)"
        )
    if s.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be integer counts, got dtype {s.dtype}")
    if s.dtype.kind == "f":
        # Whole-valued floats (e.g. from JSON or a CSV) are fine; 2.5 is not.
        bad = ~np.isfinite(s) | (s != np.floor(s))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"{name} must be non-negative integers, got non-integer {s[i].item()!r} at index {i}"
            )
    if (s < 0).any():
        i = int(np.flatnonzero(s < 0)[0])
        raise ValueError(
            f"{name} must be non-negative integers, got negative {s[i].item()!r} at index {i}"
        )
    return s.astype(np.int64)


def as_samples(escapees, clogged) -> tuple[np.ndarray, np.ndarray]:
    s = as_escapees(escapees)
    return s, as_clogged(clogged, s.size)
