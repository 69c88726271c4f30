"""The process's off-screen GGUI: whether Vulkan renders here (probed once, in a
subprocess), and the one hidden window every renderer draws into.

* **Vulkan.** :func:`vulkan_status` probes it once per process in a subprocess
  (a broken driver may crash the process that tries it).
* **One window per process.** Every renderer draws into the same hidden window,
  created on first use. A renderer of another size, or a new Taichi program
  (``ti.init`` called again), destroys and recreates it. Two live GGUI windows, or
  a window outliving its Taichi program, crash the interpreter at exit; this module
  never leaves either behind.
* **No file in the user's folder.** Dear ImGui, inside GGUI, writes ``imgui.ini``
  into the current directory when a window is destroyed (also at exit). Windows
  are therefore created and destroyed with the process inside a private temporary
  folder, and an ``atexit`` hook destroys the window there and removes the folder.
  Nothing here calls ``window.get_gui()`` or ``window.show()`` (``show`` crashes
  without a display).
"""
import atexit
import contextlib
import functools
import os
import shutil
import subprocess
import sys
import tempfile

import taichi as ti
from taichi.lang import impl

from .. import backend

# ---------------------------------------------------------------------------
# Vulkan probe

_PACKAGES_HINT = ("Off-screen rendering uses Taichi GGUI, which needs a Vulkan driver; "
                  "on a machine without a GPU install the Mesa software driver: "
                  "apt-get install mesa-vulkan-drivers libvulkan1 (Debian packages "
                  "mesa-vulkan-drivers, libvulkan1)")

# Draws one red triangle on black and checks a pixel inside it, so that a driver
# that opens but renders nothing is caught too.
_PROBE = """
import numpy as np, taichi as ti
ti.init(arch=ti.cpu, log_level=ti.ERROR)
w = ti.ui.Window("probe", (16, 16), vsync=False, show_window=False)
c = w.get_canvas()
v = ti.Vector.field(2, ti.f32, 3)
v.from_numpy(np.array([[0, 0], [1, 0], [0, 1]], np.float32))
c.set_background_color((0.0, 0.0, 0.0))
c.triangles(v, color=(1.0, 0.0, 0.0))
img = w.get_image_buffer_as_numpy()
ok = img.shape[:2] == (16, 16) and img[2, 2, 0] > 0.9 and img[13, 13, 0] < 0.1
w.destroy()
print("GGUI-OK" if ok else "GGUI-WRONG-PIXELS")
"""


@functools.cache
def vulkan_status() -> tuple[bool, str]:
    """Whether off-screen GGUI rendering works in this environment.

    The probe (create a hidden window, draw a triangle, read it back) runs once
    per process in a subprocess, in a temporary folder, so that a crashing
    driver cannot take the caller down and no file is left behind; the answer
    is cached.

    Returns
    -------
    ok : bool
    reason : str
        When not ok: what failed and which Debian packages provide the
        software Vulkan driver (``mesa-vulkan-drivers libvulkan1``).

    Examples
    --------
    >>> ok, reason = vulkan_status()        # doctest: +SKIP
    """
    with tempfile.TemporaryDirectory(prefix="taichi_hsdem_probe_") as tmp:
        try:
            proc = subprocess.run([sys.executable, "-c", _PROBE], cwd=tmp,
                                  capture_output=True, text=True, timeout=180)
        except subprocess.TimeoutExpired:
            return False, f"the Vulkan probe hung for 180 s. {_PACKAGES_HINT}"
    if proc.returncode == 0 and "GGUI-OK" in proc.stdout:
        return True, "off-screen GGUI rendering works"
    if proc.returncode < 0:
        detail = f"the probe process was killed by signal {-proc.returncode}"
    else:
        # The last stderr line is the exception ("RuntimeError: Vulkan must be
        # available for GGUI"); stdout holds Taichi's banner.
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        lines = lines or [ln for ln in proc.stdout.splitlines() if ln.strip()]
        detail = lines[-1].strip() if lines else f"exit status {proc.returncode}"
    return False, f"GGUI could not render ({detail}). {_PACKAGES_HINT}"


# ---------------------------------------------------------------------------
# The process's one GGUI window

_DISPLAY = {"window": None, "size": None, "prog": None, "dir": None}


@contextlib.contextmanager
def _in_private_dir():
    """Run with the cwd in this module's temporary folder (ImGui writes
    ``imgui.ini`` into the cwd when a window is destroyed)."""
    if _DISPLAY["dir"] is None:
        _DISPLAY["dir"] = tempfile.mkdtemp(prefix="taichi_hsdem_ggui_")
        atexit.register(_shutdown)
    previous = os.getcwd()
    os.chdir(_DISPLAY["dir"])
    try:
        yield
    finally:
        os.chdir(previous)


def _shutdown():
    close_window()
    if _DISPLAY["dir"] is not None:
        shutil.rmtree(_DISPLAY["dir"], ignore_errors=True)
        _DISPLAY["dir"] = None


def close_window() -> None:
    """Destroy the shared hidden window, if any (the next draw makes a new one).

    Done at exit automatically, and on the next draw after ``ti.init`` or
    ``ti.reset``; call it to free the window's memory earlier.
    """
    window = _DISPLAY["window"]
    if window is None:
        return
    _DISPLAY.update(window=None, size=None, prog=None)
    with _in_private_dir():
        window.destroy()


def acquire_window(size):
    """The shared window at ``size`` (width, height) for the current program."""
    prog = impl.get_runtime().prog
    if _DISPLAY["window"] is not None and (_DISPLAY["size"] != size
                                           or _DISPLAY["prog"] is not prog):
        close_window()
    if _DISPLAY["window"] is None:
        with _in_private_dir(), taichi_logging_at_least("warn"):
            window = ti.ui.Window("taichi_hsdem", size, vsync=False, show_window=False)
        _DISPLAY.update(window=window, size=size, prog=prog)
    return _DISPLAY["window"]


@contextlib.contextmanager
def taichi_logging_at_least(level):
    """Silence Taichi's C++ logger below ``level`` (the capture logs one info
    line per frame), restoring the caller's level afterwards."""
    levels = ("trace", "debug", "info", "warn", "error", "critical")
    current = next((lv for lv in levels if ti.is_logging_effective(lv)), "critical")
    if levels.index(current) >= levels.index(level):
        yield
        return
    ti.set_logging_level(level)
    try:
        yield
    finally:
        ti.set_logging_level(current)


def ensure_taichi():
    if impl.get_runtime().prog is None:
        backend.init("cpu")
