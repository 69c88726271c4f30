"""Calibrate one scene parameter against a target ``<s>``: ``python tools/calibrate.py
SCENE.toml ...`` is ``python -m taichi_hsdem calibrate SCENE.toml ...`` (usage:
:mod:`taichi_hsdem.studies.calibrate`)."""
import sys

from taichi_hsdem.studies.calibrate import main

if __name__ == "__main__":
    sys.exit(main(prog="tools/calibrate.py"))
