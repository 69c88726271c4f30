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


def _atomic_write(path: Path, text: str):
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text)
    os.replace(tmp, path)


def _clean(obj):
    """JSON-safe copy: numpy scalars to Python, non-finite floats to null."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_resolved_scene(scene: Scene, out: Path):
    out.mkdir(parents=True, exist_ok=True)
    _atomic_write(out / "scene.resolved.toml", scene_to_toml(scene))


def write_summary(summary: dict, out: Path):
    _atomic_write(out / "summary.json", json.dumps(_clean(summary), indent=1) + "\n")


def write_series(series, statuses, out: Path):
    """``escapees.csv``: realization,t,escapees; unstable realizations are left out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["realization", "t", "escapees"])
    for r, t, s in series:
        if statuses[r] == "ok":
            w.writerow([r, repr(float(t)), int(s)])
    _atomic_write(out / "escapees.csv", buf.getvalue())


class VideoRecorder:
    """Draws one realization of a running :class:`Simulation` into an MP4."""

    def __init__(self, sim, path: Path):
        from .render import Renderer, VideoWriter
        sc = sim.scene
        m = sim.model
        g = m.geometry
        self.sim = sim
        self.r = sc.output.video_realization
        prange = None
        pshape = None
        if sim.fluid is not None:
            pshape = m.fluid_shape
            p = sim.pressure_np[self.r]
            lo, hi = float(np.nanmin(p)), float(np.nanmax(p))
            prange = (lo, hi if hi > lo else lo + 1.0)
        self.renderer = Renderer((g.x_min, g.x_max, g.y_min, g.y_max), g.outline, list(g.obstacles),
                                 [s.shape for s in m.species], width=sc.output.width,
                                 pressure_shape=pshape, pressure_range=prange, title=sc.name)
        self.tmp = path.with_name(path.name + ".part.mp4")
        self.path = path
        self.writer = VideoWriter(self.tmp, sc.output.fps)
        self.frames = 0
        self.seconds = 0.0

    def __call__(self, sim):
        import time
        t0 = time.perf_counter()
        st = sim.state()
        r = self.r
        pres = sim.pressure_np[r] if sim.fluid is not None else None
        esc = sim.results[r].escapees or 0
        frame = self.renderer.draw(st["x"][r], st["theta"][r], st["species"], st["alive"][r],
                                   pressure=pres, t=sim.t, escapees=esc)
        self.writer.write(frame)
        self.frames += 1
        self.seconds += time.perf_counter() - t0

    def close(self, keep=True):
        self.writer.close()
        if keep:
            os.replace(self.tmp, self.path)
        elif self.tmp.exists():
            self.tmp.unlink()
