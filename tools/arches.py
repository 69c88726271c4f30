"""``python tools/arches.py ...`` is ``python -m taichi_hsdem arches ...`` (usage:
:mod:`taichi_hsdem.studies.arches`)."""
import sys

from taichi_hsdem.studies.arches import main

if __name__ == "__main__":
    sys.exit(main(prog="tools/arches.py"))
