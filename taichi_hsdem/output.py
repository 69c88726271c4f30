"""Writing a run's results: summary.json, escapees.csv, scene.resolved.toml, the
checkpoint, the plots, video.mp4 and the ParaView series.

A run's files wait in a hidden staging folder inside the output folder
(:class:`Staging`) until the run ends; then they are moved into place together,
summary.json last, and result files an earlier run left there that this one
does not write are removed, so that the folder never mixes two runs. Every file
is written to a temporary name and renamed, so nothing half-written ever stands
under a result's name. The checkpoint is the exception that proves the rule: it
is the run's own state, written straight into the folder (atomically) at its
wall-clock interval so that a run killed hard can still be resumed.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import checkpoint, report
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
        if statuses[r] != "unstable":
            w.writerow([r, repr(float(t)), int(s)])
    atomic_write(out / "escapees.csv", buf.getvalue())


#: Files (and folders) a run writes into its output folder; the ones an earlier
#: run left there and this run does not write are removed when it publishes.
RESULT_FILES = ("scene.resolved.toml", "escapees.csv", "summary.json", "video.mp4",
                "escapees.png", "pmf.png", "series.pvd", "vtk", checkpoint.FILE)


def estimate_text(mean, ci) -> str:
    """``<s>`` with its interval for a message: ``12.3 [8.1, 17.9]``."""
    def num(v):
        return "-" if v is None else ("inf" if v == math.inf else f"{v:.3g}")
    lo, hi = ci if ci else (None, None)
    return f"{num(mean)} [{num(lo)}, {num(hi)}]"


class Staging:
    """The output folder of one run and the hidden folder its files wait in.

    ``with Staging(out) as staged``: creates ``out`` (if needed) and
    ``out/.incomplete-*``; :meth:`path` names a file in the staging folder;
    :meth:`publish` moves the results into ``out``; leaving the block removes the
    staging folder, and ``out`` too when this run created it and left it empty.
    """

    def __init__(self, out: Path):
        self.out = Path(out)
        self.tmp = None
        self._created = False

    def __enter__(self):
        self._created = not self.out.exists()
        self.out.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=".incomplete-", dir=self.out))
        return self

    def __exit__(self, *exc):
        shutil.rmtree(self.tmp, ignore_errors=True)
        if self._created:
            try:
                self.out.rmdir()             # only if nothing was kept
            except OSError:
                pass

    def path(self, name: str) -> Path:
        return self.tmp / name

    def publish(self, result, extra: list[str], resumed: bool = False) -> list[str]:
        """Write the scene, the series and the summary beside the files ``extra``
        already staged, then move them all into the folder (summary last); returns
        the names kept. A fresh run removes what an earlier run left and it does not
        write; a resumed run keeps the earlier part's files it does not replace."""
        statuses = [r["status"] for r in result.summary["realizations"]]
        write_resolved_scene(result.scene, self.tmp, result.notes)
        write_series(result.series, statuses, self.tmp)
        names = ["scene.resolved.toml", "escapees.csv", *extra]
        for name in names:
            _replace(self.tmp / name, self.out / name)
        if not resumed:
            for name in RESULT_FILES:
                if name not in names and name not in ("summary.json", checkpoint.FILE):
                    _remove(self.out / name)
        write_summary(result.summary, self.tmp)
        _replace(self.tmp / "summary.json", self.out / "summary.json")
        return names + ["summary.json"]


def _replace(src: Path, dst: Path):
    """Move ``src`` to ``dst`` (a file is replaced atomically; a folder replaces
    the old folder of that name)."""
    if src.is_dir():
        _remove(dst)
    os.replace(src, dst)


def _remove(path: Path):
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


class CheckpointClock:
    """``on_chunk`` hook of a run: a checkpoint every ``every`` seconds of wall
    time (0: never during the run), straight into the output folder."""

    def __init__(self, sim, staged: Staging, every: float):
        self.sim, self.staged, self.every = sim, staged, float(every)
        self.last = time.perf_counter()
        self.saved = 0

    def __call__(self, sim):
        if self.every > 0 and time.perf_counter() - self.last >= self.every:
            self.save()

    def save(self):
        checkpoint.save(self.sim, self.staged.out / checkpoint.FILE)
        self.last = time.perf_counter()
        self.saved += 1


class Pictures:
    """What a run draws while it goes: the video (and the live viewer), the ParaView
    series, and at the end the plots; each into the staging folder."""

    def __init__(self, sim, staged: Staging, view: bool = False, quiet: bool = False,
                 resumed: bool = False):
        self.sim, self.staged = sim, staged
        self.recorder = None
        self.vtk = None
        self.notes: dict = {}
        sc = sim.scene
        viewer = None
        if view:
            from .render.viewer import LiveViewer, display_available
            ok, why = display_available()
            if ok:
                viewer = LiveViewer(staged.out, title=f"taichi_hsdem: {sc.name}")
            elif not quiet:
                print(f"--view skipped: {why}", file=sys.stderr)
        if sc.output.video or viewer is not None:
            from .render import VideoRecorder, vulkan_status
            ok, why = vulkan_status()
            if ok:
                self.recorder = VideoRecorder(
                    sim, staged.path("video.mp4") if sc.output.video else None, viewer=viewer)
            else:
                self.notes["video"] = {"file": None, "skipped": why}
                # the user asked for a picture: say so even with --quiet
                print(f"rendering skipped: {why}", file=sys.stderr)
        if sc.output.vtk:
            from .paraview import ParaViewUnavailable
            try:
                self.vtk = _series_writer(sim, staged, resumed)
            except ParaViewUnavailable as exc:
                self.notes["vtk"] = {"skipped": str(exc)}
                print(f"ParaView output skipped: {exc}", file=sys.stderr)

    @property
    def frame_times(self):
        if self.recorder is not None:
            return self.recorder.frame_times
        if self.vtk is not None:
            return [float(t) for t in np.linspace(0.0, self.sim.scene.run.t_end,
                                                  self.sim.scene.output.frames)]
        return None

    def on_frame(self, sim):
        if self.recorder is not None:
            self.recorder(sim)
        if self.vtk is not None:
            _vtk_frame(self.vtk, sim)

    def discard(self):
        """The run failed: close without keeping anything."""
        if self.recorder is not None:
            self.recorder.close(keep=False)
        if self.vtk is not None:
            self.vtk.close()

    def finish(self, result):
        """Close the writers, draw the plots; record each in the summary."""
        summary = result.summary
        if self.recorder is not None:
            self.recorder.close(keep=True)
            summary["video"] = self.recorder.summary(summary["wall_time_s"])
            if self.recorder.error is not None:
                print(f"video not written: rendering failed ({self.recorder.error})",
                      file=sys.stderr)
        if self.vtk is not None:
            self.vtk.close()
            summary["vtk"] = {"index": "series.pvd", "frames": self.vtk_frames}
        summary.update(self.notes)
        summary["plots"] = report.plot_run(result, self.staged.tmp,
                                           law=report.steady_stream_law(self.sim))

    @property
    def vtk_frames(self) -> int:
        return getattr(self.vtk, "frames_written", 0)

    def files(self) -> list[str]:
        """The staged files to publish."""
        names = ["video.mp4", "escapees.png", "pmf.png", "series.pvd", "vtk"]
        return [n for n in names if (self.staged.tmp / n).exists()]


def _series_writer(sim, staged: Staging, resumed: bool):
    from .geometry.shapes import outline_polygon
    from .paraview import FluidGrid, SeriesWriter
    m = sim.model
    g = m.geometry
    grid = None
    if sim.fluid is not None:
        grid = FluidGrid(origin=(g.x_min, g.y_min), spacing=m.fluid_dx, active=m.fluid_active)
    r = sim.scene.output.video_realization
    old = staged.out / "vtk"
    if resumed and old.is_dir():     # go on with the earlier part's series
        shutil.copytree(old, staged.path("vtk"))
        shutil.copy2(staged.out / "series.pvd", staged.path("series.pvd"))
    return SeriesWriter(staged.tmp, [r], g.outline, list(g.obstacles),
                        [outline_polygon(s.shape) for s in m.species], grid,
                        resume=sim.t if resumed else None)


def _vtk_frame(writer, sim):
    r = sim.scene.output.video_realization
    last = writer.last_time(r)
    if last is not None and sim.t <= last:
        return                     # a resumed run's first frame: the series has it
    st = sim.state()
    pressure = kappa = None
    if sim.fluid is not None:
        pressure = sim.pressure()[r]
        kappa = sim.fluid.kappa.to_numpy()[r].astype(float)
    writer.write_frame(sim.t, st["x"][r], st["theta"][r], st["v"][r], st["omega"][r],
                       st["alive"][r], st["species"], pressure=pressure, permeability=kappa,
                       realization=r)
