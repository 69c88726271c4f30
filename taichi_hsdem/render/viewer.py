"""Live viewer (``--view``): the video's picture in a window while the run goes on.

Keys: space pauses and resumes, ``n`` advances one frame while paused, ``s`` saves
a screenshot (``screenshot_<t>.png`` in the output folder), Esc closes the window
(the run goes on without it).

The picture is drawn by the video's renderer (off-screen GGUI, one hidden window
per process) and shown with Taichi's X11 ``ti.GUI``, so the viewer adds no second
GGUI window. Frames come at the video's times (``output.frames`` over ``t_end``).
"""
from __future__ import annotations

import os
import socket
from pathlib import Path

import numpy as np


def display_available() -> tuple[bool, str]:
    """Is there an X server to open a window on (Taichi's GUI is X11): ``DISPLAY``
    set, and its socket (``:N`` on this machine, ``host:N`` over TCP) answering."""
    display = os.environ.get("DISPLAY", "")
    if not display:
        return False, "no display (DISPLAY is not set): --view needs a desktop session or Xvfb"
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return False, f"DISPLAY={display!r} is not an X display name like :0"
    try:
        if host in ("", "unix"):
            with socket.socket(socket.AF_UNIX) as sock:
                sock.settimeout(2.0)
                sock.connect(f"/tmp/.X11-unix/X{number}")
        else:
            socket.create_connection((host, 6000 + int(number)), timeout=2.0).close()
    except OSError as exc:
        return False, (f"no X server answers on DISPLAY={display} ({exc.strerror or exc}): "
                       "--view needs a running desktop session or Xvfb")
    return True, ""


class LiveViewer:
    """Shows the frames a :class:`~taichi_hsdem.render.VideoRecorder` draws.

    Pass it as the recorder's ``viewer``; :meth:`show` is called with each frame
    (a top-down (H, W, 3) uint8 image) and returns when the run may go on.
    """

    def __init__(self, out_dir: Path, title="taichi_hsdem"):
        import taichi as ti
        self._ti = ti
        self.out_dir = Path(out_dir)
        self.title = title
        self.gui = None
        self.closed = False
        self.paused = False
        self.screenshots: list[Path] = []

    def _display(self, frame):
        ti = self._ti
        if self.gui is None:
            self.gui = ti.GUI(self.title, res=(frame.shape[1], frame.shape[0]))
        # ti.GUI takes x-first, bottom-up images with values in [0, 1]
        self.gui.set_image(frame[::-1].transpose(1, 0, 2).astype(np.float32) / 255.0)
        self.gui.show()

    def handle_key(self, key, sim, frame) -> bool:
        """Act on one key press; return True when the run may advance."""
        ti = self._ti
        if key == ti.GUI.ESCAPE:
            self.close()
            return True
        if key == ti.GUI.SPACE:
            self.paused = not self.paused
        elif key == "n":
            return True
        elif key == "s":
            self.out_dir.mkdir(parents=True, exist_ok=True)
            path = self.out_dir / f"screenshot_{sim.t:.6g}.png"
            import imageio.v3 as iio
            iio.imwrite(path, frame)
            self.screenshots.append(path)
        return not self.paused

    def show(self, sim, frame):
        if self.closed:
            return
        self._display(frame)
        while self.gui is not None and self.gui.running:
            stepped = False
            for e in self.gui.get_events(self._ti.GUI.PRESS):
                stepped = self.handle_key(e.key, sim, frame) and e.key == "n" or stepped
                if self.closed:
                    return
            if stepped or not self.paused:
                return
            self._display(frame)

    def close(self):
        if self.gui is not None:
            self.gui.close()
            self.gui = None
        self.closed = True
