"""The reference paper's clogging figures (Zhou et al. 2024, Figs. 8-13) as commands.

Usage::

    python tools/figures.py escapees-time [--quick] [--realizations N] [--out DIR]
                                           [--set section.key=value ...] [--phi ...]
    python tools/figures.py pmf-collapse  [...] [--phi 0.19 0.26 0.32]
    python tools/figures.py friction      [...] [--mu 0.1 0.3 0.5 0.7 0.9] [--phi 0.26]
    python tools/figures.py shapes        [...] [--ratios 1.7 1.2]
    python tools/figures.py polygons      [...] [--vertices 3 4 5 6] [--ratio 1.2]

Each writes ``<figure>.png``, ``points.csv``, ``realizations.csv``, ``pmf.csv`` or
``series.csv``, ``figure.json`` and ``points/`` (each finished point, read back by a
rerun into the same ``--out``: resumable) to ``--out`` (default ``runs/figures/<figure>/``),
prints one line per point and where it wrote. ``--realizations 100`` is the paper's
sample size; ``--quick`` a smoke test for CI. Details: ``taichi_hsdem/figures.py``.
"""
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from taichi_hsdem.studies.figures import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
