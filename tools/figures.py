"""``python tools/figures.py ...`` is ``python -m taichi_hsdem figures ...`` (usage:
:mod:`taichi_hsdem.studies.figures`)."""
import sys

from taichi_hsdem.studies.figures import main

if __name__ == "__main__":
    sys.exit(main(prog="tools/figures.py"))
