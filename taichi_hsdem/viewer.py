"""Live viewer (``--view``): the video's picture in a window while the run goes on.

Keys: space pauses and resumes, ``n`` advances one frame while paused, ``s`` saves
a screenshot (``screenshot_<t>.png`` in the output folder), Esc closes the window
(the run goes on without it).

The picture is drawn by :class:`taichi_hsdem.render.Renderer` (off-screen GGUI,
one hidden window per process) and shown with Taichi's X11 ``ti.GUI``, so the
viewer adds no second GGUI window.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def display_available() -> tuple[bool, str]:
    """Is there a display to open a window on."""
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return True, ""
    return False, "no display (DISPLAY is not set): --view needs a desktop session or Xvfb"


class LiveViewer:
    """An ``on_frame`` callback for :meth:`Simulation.run` that shows each frame.

    ``draw`` is a callable ``sim -> (H, W, 3) uint8 image`` (top-down), e.g. a
    :class:`~taichi_hsdem.output.VideoRecorder`'s frame maker.
    """

    def __init__(self, draw, out_dir: Path, title="taichi_hsdem"):
        import taichi as ti
        self._ti = ti
        self.draw = draw
        self.out_dir = Path(out_dir)
        self.title = title
        self.gui = None
        self.paused = False
        self.screenshots: list[Path] = []

    def _show(self, frame):
        ti = self._ti
        if self.gui is None:
            self.gui = ti.GUI(self.title, res=(frame.shape[1], frame.shape[0]))
        # ti.GUI takes x-first, bottom-up images with values in [0, 1]
        self.gui.set_image(frame[::-1].transpose(1, 0, 2).astype(np.float32) / 255.0)
        self.gui.show()

    def _handle(self, sim, frame) -> bool:
        """Process pending keys; return True to advance."""
        ti = self._ti
        step = False
        for e in self.gui.get_events(ti.GUI.PRESS):
            if e.key == ti.GUI.ESCAPE:
                self.close()
                return True
            if e.key == ti.GUI.SPACE:
                self.paused = not self.paused
            elif e.key == "n":
                step = True
            elif e.key == "s":
                self.out_dir.mkdir(parents=True, exist_ok=True)
                path = self.out_dir / f"screenshot_{sim.t:.6g}.png"
                import imageio.v3 as iio
                iio.imwrite(path, frame)
                self.screenshots.append(path)
        return step or not self.paused

    def __call__(self, sim):
        if self.draw is None:
            return
        frame = self.draw(sim)
        self._show(frame)
        while self.gui is not None and self.gui.running:
            if self._handle(sim, frame):
                return
            self._show(frame)

    def close(self):
        if self.gui is not None:
            self.gui.close()
            self.gui = None
        self.draw = None
