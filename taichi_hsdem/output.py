"""Writing a run's results: summary.json, escapees.csv, scene.resolved.toml, video.mp4.

Files are written to a temporary name and renamed, so an interrupted run never
leaves a half-written result that looks complete.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path

import numpy as np

from .scene import Scene, scene_to_toml


def atomic_write(path: Path, text: str):
    """Write ``text`` to ``path`` through a temporary file beside it, so that
    ``path`` never holds half a file."""
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text)
    os.replace(tmp, path)


def json_safe(obj):
    """Plain JSON: numpy scalars to Python, NaN and inf to None (null), tuples to
    lists, keys to strings, anything else to its text."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)) or obj is None or isinstance(obj, str):
        return bool(obj) if isinstance(obj, np.bool_) else obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return str(obj)


def write_resolved_scene(scene: Scene, out: Path, notes: dict | None = None):
    """``scene.resolved.toml``, headed by what each ``auto`` chose and why."""
    out.mkdir(parents=True, exist_ok=True)
    head = "".join(f"# auto {key}: {why}\n" for key, why in sorted((notes or {}).items()))
    atomic_write(out / "scene.resolved.toml", head + scene_to_toml(scene))


def write_summary(summary: dict, out: Path):
    atomic_write(out / "summary.json", json.dumps(json_safe(summary), indent=1) + "\n")


def write_series(series, statuses, out: Path):
    """``escapees.csv``: realization,t,escapees; unstable realizations are left out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["realization", "t", "escapees"])
    for r, t, s in series:
        if statuses[r] == "ok":
            w.writerow([r, repr(float(t)), int(s)])
    atomic_write(out / "escapees.csv", buf.getvalue())
