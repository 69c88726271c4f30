"""Studies made of many runs: sweeps (:mod:`.sweep`), calibration (:mod:`.calibrate`)
and the paper's figures (:mod:`.figures`); :mod:`.digest` keys their kept results
on the code that made them."""


def fmt(value) -> str:
    """An estimate for a message: ``-`` for none, ``inf``, else 4 significant digits."""
    return "-" if value is None else ("inf" if value == float("inf") else f"{value:.4g}")
