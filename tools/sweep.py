"""Run a parameter sweep: ``python tools/sweep.py SWEEP.toml ...`` is
``python -m taichi_hsdem sweep SWEEP.toml ...`` (usage: :mod:`taichi_hsdem.studies.sweep`)."""
import sys

from taichi_hsdem.studies.sweep import main

if __name__ == "__main__":
    sys.exit(main(prog="tools/sweep.py"))
