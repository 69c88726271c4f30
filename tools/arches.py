"""The clogging arches of a finished ``tools/figures.py`` run.

    python tools/arches.py runs/figures/polygons [--tol 0.01] [--angle 10] [--examples 6]

For every clogged realization of every point: the arch (the shortest chain of
touching particles from one side wall to the other), its size and how its
contacts touch (face-to-face, vertex or curved). Writes ``arches.csv`` and
``arches.png`` (sample arches per point) into the folder and prints one line per
point. Details: ``taichi_hsdem/studies/arches.py``.
"""
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from taichi_hsdem.studies.arches import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
