"""Studies made of many runs: sweeps (:mod:`.sweep`), calibration (:mod:`.calibrate`)
and the paper's figures (:mod:`.points`, :mod:`.figures`, :mod:`.plots`); kept
results are keyed on the code that made them (:mod:`taichi_hsdem.digest`)."""


def fmt(value) -> str:
    """An estimate for a message: ``-`` for none, ``inf``, else 4 significant digits."""
    return "-" if value is None else ("inf" if value == float("inf") else f"{value:.4g}")
