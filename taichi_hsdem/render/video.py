"""Video of a run: H.264 MP4 frames (:class:`VideoWriter`) and the recorder that
draws one realization of a running simulation into them (:class:`VideoRecorder`)."""
import math
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from .frame import Renderer, finite_range
from .overlay import CLOG_RED, network_label, paint_label, paint_segments


class VideoWriter:
    """H.264 (libx264, yuv420p) MP4 writer for frames from :meth:`Renderer.draw`.

    Frames are written at their own size: imageio-ffmpeg's default
    ``macro_block_size=16`` would rescale any size that is not a multiple of
    16, so it is set to 1, and frames must have even width and height
    (yuv420p halves the chroma resolution), which the renderer guarantees.

    Parameters
    ----------
    path : str or path-like
        Output file (``.mp4``); its folder must exist.
    fps : float
        Frames per second, > 0.
    quality : float, optional
        imageio-ffmpeg quality in [1, 10]; 7 gives libx264 ``-crf 15``.

    Examples
    --------
    >>> with VideoWriter("out.mp4", fps=25) as video:        # doctest: +SKIP
    ...     video.write(frame)
    """

    def __init__(self, path, fps, quality=7):
        fps = float(fps)
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number, got {fps}")
        self.path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(folder):
            raise FileNotFoundError(f"folder for the video does not exist: {folder}")
        self.fps = fps
        self.quality = quality
        self.frames = 0
        self._size = None
        self._writer = None

    def write(self, frame):
        """Append one (H, W, 3) uint8 frame; all frames must share one size."""
        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"a frame must be an (H, W, 3) uint8 array, got "
                             f"{frame.shape} {frame.dtype}")
        if frame.shape[0] % 2 or frame.shape[1] % 2:
            raise ValueError(f"H.264 yuv420p needs even frame sizes, got {frame.shape[:2]}")
        if self._writer is None:
            import imageio.v2 as imageio
            self._size = frame.shape[:2]
            self._writer = imageio.get_writer(
                self.path, format="FFMPEG", mode="I", fps=self.fps, codec="libx264",
                pixelformat="yuv420p", quality=self.quality, macro_block_size=1,
                ffmpeg_log_level="error")
        elif frame.shape[:2] != self._size:
            raise ValueError(f"frame size {frame.shape[:2]} differs from the first "
                             f"frame's {self._size}")
        self._writer.append_data(frame)
        self.frames += 1

    def close(self):
        """Finish the file (no file is written if no frame was)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class VideoRecorder:
    """Draws one realization of a running :class:`Simulation` into ``video.mp4``.

    Pass it as ``on_frame`` to :meth:`Simulation.run` with ``frame_times`` from
    :attr:`frame_times`: ``output.frames`` frames evenly spaced over
    ``[0, run.t_end]``, frame 0 being the initial state (drawn before the first
    step), played at ``output.fps``. The realization shown is
    ``output.video_realization``. The video ends with the first frame drawn after
    that realization stopped (a clog, or an instability): it shows the final state
    once instead of repeating it up to ``t_end``.

    The pressure colour scale is fixed for the whole video: one range, the
    smallest and largest pressure of the initial solve and of every frame, so
    that a colour means one pressure in every frame, nothing is clipped, and a
    pressure that builds up (the inlet pressure rising behind a clog under a
    flow-rate inlet) shows as colours that change, not as a bar that widens. The
    frames' inputs (the particles, the pressure field, the overlay) are spooled
    to disk beside the video as the run draws them, and drawn and encoded at
    ``close(keep=True)``, when the range is known. The strip under each frame
    prints the unit (Pa, or "dimensionless" for a dimensionless scene) and the
    range next to the colour bar, the same in every frame; :meth:`summary`
    reports it. A live window (``viewer``) cannot wait for the range: it is drawn
    at once, on a scale that widens to what it has shown.

    With several throats (a micromodel) every clogged throat is drawn as a red bar
    across its gap, and the corner of the domain prints the pressure drop of the
    latest solve and how many throats are clogged (:mod:`.overlay`).

    The file is written as ``<name>.part.mp4`` and renamed by
    ``close(keep=True)``. A frame that fails to render stops the video (the run
    goes on); :attr:`error` then says why and ``close`` keeps nothing. The spool
    (``<name>.frames``) is removed by ``close`` either way.
    """

    def __init__(self, sim, path: Path | None, viewer=None):
        """``path=None``: draw for ``viewer`` only (``--view`` without ``--video``)."""
        t0 = time.perf_counter()
        sc = sim.scene
        m = sim.model
        g = m.geometry
        self.sim = sim
        self.r = sc.output.video_realization
        self.fps = sc.output.fps
        self.n_frames = sc.output.frames
        prange = pshape = extent = None
        if sim.fluid is not None:
            nx, ny = m.fluid_shape
            dx = m.fluid_dx
            pshape = (nx, ny)
            # Square cells of side dx from the domain's lower-left corner; the
            # top row may overhang y_max.
            extent = (g.x_min, g.x_min + nx * dx, g.y_min, g.y_min + ny * dx)
            prange = finite_range(sim.pressure()[self.r])
        self.renderer = Renderer((g.x_min, g.x_max, g.y_min, g.y_max), g.outline,
                                 list(g.obstacles), [s.shape for s in m.species],
                                 width=sc.output.width, pressure_shape=pshape,
                                 pressure_range=prange, title=sc.name,
                                 pressure_extent=extent, grow_range=True, units=sc.units)
        self.viewer = viewer
        self.path = None if path is None else Path(path)
        self.tmp = None if path is None else self.path.with_name(self.path.name + ".part.mp4")
        self.writer = None if path is None else VideoWriter(self.tmp, self.fps)
        # the frames' inputs, drawn at close on the whole run's range
        self.spool = None if path is None else self.path.with_name(self.path.name + ".frames")
        if self.spool is not None:
            shutil.rmtree(self.spool, ignore_errors=True)
            self.spool.mkdir()
        self._range = prange        # the initial solve's and every frame's, so far
        self._species = None
        self.frames = 0
        self.ended = False          # the shown realization stopped and its last frame is drawn
        self.seconds = 0.0          # drawing and encoding frames, inside the run
        self.finish_seconds = 0.0   # flushing the encoder at close
        self.setup_seconds = time.perf_counter() - t0
        self.error = None
        self._fill_for = self._fill_index = None
        self._children_cpu0 = self._children_cpu()
        self.encoder_cpu_seconds = None

    @staticmethod
    def _children_cpu():
        """CPU seconds of this process's finished child processes (the ffmpeg
        encoder is one; its time is not in ``seconds``, as it encodes in
        parallel, competing with the simulation for the cores)."""
        try:
            import resource
        except ImportError:                     # not on Windows
            return None
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        return ru.ru_utime + ru.ru_stime

    def _display_pressure(self, p):
        """The field with every non-finite cell (solid wall) given its nearest
        finite cell's value. The renderer colours a fluid pixel by the cell
        holding its centre; along a slanted wall that cell's centre can lie in
        the wall (an inactive, NaN cell), which would show as a pale fleck."""
        p = np.asarray(p, dtype=float)
        bad = ~np.isfinite(p)
        if not bad.any() or bad.all():
            return p
        if self._fill_for is None or not np.array_equal(bad, self._fill_for):
            self._fill_for = bad
            self._fill_index = ndimage.distance_transform_edt(
                bad, return_distances=False, return_indices=True)
        return p[tuple(self._fill_index)]

    @property
    def pressure_range(self):
        """The video's colour-map range, (p_min, p_max): the initial solve's and
        every frame's pressures so far, the whole run's once closed; None without
        fluid."""
        return self._range

    @property
    def frame_times(self) -> list[float]:
        """Times of the frames: ``output.frames`` from 0 to ``run.t_end``."""
        return [float(t) for t in np.linspace(0.0, self.sim.scene.run.t_end, self.n_frames)]

    def __call__(self, sim):
        if self.error is not None or self.ended:
            return
        t0 = time.perf_counter()
        r = self.r
        # stopped (checked before drawing): this frame shows the final state, the last
        self.ended = not bool(sim.running()[r])
        try:
            pres = None
            if sim.fluid is not None:
                pres = self._display_pressure(sim.pressure()[r])
                seen = finite_range(pres)
                if seen is not None:
                    self._range = seen if self._range is None else (
                        min(self._range[0], seen[0]), max(self._range[1], seen[1]))
            st = sim.state()
            self._species = st["species"]
            frame = {"x": st["x"][r], "theta": st["theta"][r], "alive": st["alive"][r],
                     # the live counter: the results' count is only refreshed every check
                     "t": sim.t, "escapees": int(sim.escaped()[r])}
            if pres is not None:
                frame["pressure"] = pres.astype(np.float32)    # display only: half the spool
            if sim.throats.network:
                frame["clogged"] = np.isfinite(sim.run_state.throat_t_clog[r])
                frame["drop"] = next((row[2] for row in reversed(sim.run_state.flow)
                                      if row[0] == r), np.nan)
            if self.spool is not None:
                np.savez(self.spool / f"{self.frames:06d}.npz", **frame)
            live = None
            if self.viewer is not None or self.spool is None:
                # a window (or no file: drawn for a viewer only) cannot wait for the range
                self.renderer.grow_range = True
                live = self._draw(sim.throats, frame)
        except Exception as exc:        # a broken video must not lose the run
            self.error = f"{type(exc).__name__}: {exc}"
            return
        finally:
            self.seconds += time.perf_counter() - t0
        self.frames += 1
        if live is not None and self.viewer is not None:
            try:
                self.viewer.show(sim, live)    # outside the timing: it waits for keys
            except Exception as exc:           # a window that cannot open must not stop the run
                print(f"--view stopped: the window failed ({type(exc).__name__}: {exc}); "
                      "the run goes on", file=sys.stderr)
                self.viewer = None

    def _draw(self, throats, frame):
        """One frame's image from its inputs (what :meth:`__call__` spools)."""
        out = self.renderer.draw(frame["x"], frame["theta"], self._species, frame["alive"],
                                 pressure=frame.get("pressure"), t=float(frame["t"]),
                                 escapees=int(frame["escapees"]))
        if throats.network:
            self._draw_network(throats, frame, out)
        return out

    def _draw_network(self, throats, frame, out):
        """The clogged throats (red bars) and the label of :mod:`.overlay`."""
        rend = self.renderer
        clogged = np.asarray(frame["clogged"], dtype=bool)
        domain = out[:rend.domain_height]
        if clogged.any():
            ends = np.stack([rend.world_to_pixel(throats.start[clogged]),
                             rend.world_to_pixel(throats.end[clogged])], axis=1)
            paint_segments(domain, ends, max(1.5, rend.width / 320), CLOG_RED)
        drop = float(frame["drop"])
        unit = "" if rend.pressure_unit == "dimensionless" else rend.pressure_unit
        paint_label(domain, network_label(int(clogged.sum()), len(throats),
                                          None if np.isnan(drop) else drop, unit),
                    max(1, rend._scale - 1))

    def _encode(self):
        """Draw the spooled frames on the whole run's range and encode them."""
        t0 = time.perf_counter()
        rend = self.renderer
        rend.grow_range = False
        if self._range is not None:
            lo, hi = self._range
            if not hi > lo:                      # a uniform field: any positive span
                hi = lo + max(abs(lo), 1.0) * 1e-6
            rend.pressure_range = self._range = (lo, hi)
        try:
            for k in range(self.frames):
                with np.load(self.spool / f"{k:06d}.npz") as saved:
                    frame = {name: saved[name] for name in saved.files}
                self.writer.write(self._draw(self.sim.throats, frame))
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self.seconds += time.perf_counter() - t0

    def summary(self, wall_time_s: float) -> dict:
        """``summary.json``'s ``"video"`` entry; ``wall_time_s`` is the run's
        (which includes the frames' drawing and encoding)."""
        share = self.seconds / wall_time_s if wall_time_s > 0 else None
        return {"file": None if self.error or self.path is None else self.path.name,
                "frames": self.frames, "ended_at_stop": self.ended,
                "fps": self.fps, "realization": self.r,
                "width": self.renderer.width, "height": self.renderer.height,
                "pressure_range": (None if self.pressure_range is None
                                   else list(self.pressure_range)),
                "render_seconds": self.seconds,
                "render_frames_per_second": (self.frames / self.seconds
                                             if self.seconds > 0 else None),
                "render_share_of_wall_time": share,
                "setup_seconds": self.setup_seconds,
                "finish_seconds": self.finish_seconds,
                "encoder_cpu_seconds": self.encoder_cpu_seconds,
                "error": self.error}

    def close(self, keep=True):
        """Finish the file and rename it to ``path`` (``keep``), or delete it."""
        if keep and self.error is None and self.writer is not None and self.frames:
            self._encode()
        if self.spool is not None:
            shutil.rmtree(self.spool, ignore_errors=True)
        t0 = time.perf_counter()
        try:
            if self.writer is not None:
                self.writer.close()
        except Exception as exc:
            if self.error is None:
                self.error = f"{type(exc).__name__}: {exc}"
        self.finish_seconds += time.perf_counter() - t0
        cpu = self._children_cpu()
        if cpu is not None and self._children_cpu0 is not None:
            self.encoder_cpu_seconds = cpu - self._children_cpu0
        self.renderer.close()
        if self.viewer is not None:
            self.viewer.close()
        if self.tmp is None:
            return
        if keep and self.error is None and self.tmp.exists():
            os.replace(self.tmp, self.path)
        elif self.tmp.exists():
            self.tmp.unlink()
