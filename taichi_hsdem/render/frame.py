"""Off-screen frames of a simulation and their H.264 video.

A frame shows the walls (grey), the fluid region coloured by the pressure field
(a viridis-like map with a colour bar), and every particle with its true shape
and orientation. It is drawn with Taichi's GGUI on an invisible window (Vulkan;
on a machine without a GPU the Mesa software driver from the Debian packages
``mesa-vulkan-drivers libvulkan1`` does it) and read back as a numpy image, to
which a strip with the time, the escapee count and the colour bar's range is
added in numpy with a small built-in bitmap font.

What GGUI needs, and how this module deals with it:

* **Vulkan.** :func:`vulkan_status` probes it once per process in a subprocess
  (a broken driver may crash the process that tries it); :class:`Renderer`
  refuses to start, with the reason, when the probe failed.
* **One window per process.** Every :class:`Renderer` draws into the same
  hidden window, created on first use. A renderer of another size, or a new
  Taichi program (``ti.init`` called again), destroys and recreates it, so
  renderers of different sizes may be used in turn (each switch costs a window
  creation). Two live GGUI windows, or a window outliving its Taichi program,
  crash the interpreter at exit; this module never leaves either behind.
* **No file in the user's folder.** Dear ImGui, inside GGUI, writes
  ``imgui.ini`` into the current directory when a window is destroyed (also at
  exit). Windows are therefore created and destroyed with the process inside a
  private temporary folder, and an ``atexit`` hook destroys the window there
  and removes the folder. Nothing here calls ``window.get_gui()`` or
  ``window.show()`` (``show`` crashes without a display).
* **Redraw before capture.** The window's image is cleared after every
  capture, so :meth:`Renderer.draw` draws everything each time.

Examples
--------
>>> from taichi_hsdem import render, shapes                      # doctest: +SKIP
>>> r = render.Renderer((0, 4, 0, 2), outline, [], [shapes.circle(0.3)],
...                     pressure_shape=(40, 20), pressure_range=(0, 100))
>>> with render.VideoWriter("video.mp4", fps=25) as video:
...     video.write(r.draw(x, theta, template, visible, pressure=p, t=0.1))
"""

# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
import atexit
import contextlib
import functools
import math
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np
import taichi as ti
from taichi.lang import impl

from .. import backend
from ..geometry.polygon import signed_area, triangle_areas, triangulate

__all__ = ["vulkan_status", "colormap", "triangulate", "Renderer", "VideoWriter",
           "close_window"]

# ---------------------------------------------------------------------------
# Colours, as 8-bit RGB so that what the tests read back is exact.

WALL_GREY = (128, 128, 128)
#: Fluid colour when no pressure is drawn, or where the pressure is not finite.
FLUID_PLAIN = (205, 222, 240)
#: Particle outlines and the orientation tick of disks.
OUTLINE_DARK = (20, 20, 20)
#: Fill colour of species k is ``SPECIES_COLORS[k % len(SPECIES_COLORS)]``:
#: white, orange, pink, red, tan, none of them in the pressure map or grey.
SPECIES_COLORS = ((245, 245, 245), (255, 140, 26), (240, 80, 160), (215, 40, 40),
                  (200, 150, 100))
STRIP_BACKGROUND = (24, 24, 24)
TEXT_COLOR = (235, 235, 235)

# Viridis (matplotlib, CC0) sampled at 0, 1/8, ..., 1; linear in between. Its
# lightness rises monotonically, so a printed frame still orders pressures.
_VIRIDIS_ANCHORS = np.array([
    [0.267, 0.005, 0.329], [0.283, 0.141, 0.458], [0.254, 0.265, 0.530],
    [0.207, 0.372, 0.553], [0.164, 0.471, 0.558], [0.128, 0.567, 0.551],
    [0.135, 0.659, 0.518], [0.267, 0.749, 0.441], [0.478, 0.821, 0.318],
    [0.741, 0.873, 0.150], [0.993, 0.906, 0.144]])
_LUT_SIZE = 256
_LUT = np.rint(255.0 * np.column_stack([
    np.interp(np.linspace(0.0, 1.0, _LUT_SIZE),
              np.linspace(0.0, 1.0, len(_VIRIDIS_ANCHORS)), _VIRIDIS_ANCHORS[:, c])
    for c in range(3)])).astype(np.uint8)
# Background palette indices beyond the pressure map (see _paint_background).
_PLAIN_INDEX = _LUT_SIZE
_WALL_INDEX = _LUT_SIZE + 1
_BACKGROUND_PALETTE = np.vstack([_LUT, FLUID_PLAIN, WALL_GREY]).astype(np.uint8)

# Drawing sizes.
_CIRCLE_SEGMENTS = 32
_OUTLINE_PX = 1.25          # outline width, pixels
_TICK_FROM, _TICK_TO, _TICK_HALF_WIDTH = 0.35, 0.92, 0.1   # disk tick, radii
_GLYPH_W, _GLYPH_H = 5, 7   # bitmap font cell, before scaling

# Roles of a template's local vertices, which decide their colour.
_ROLE_OUTLINE, _ROLE_FILL = 0, 1


def colormap(s) -> np.ndarray:
    """Pressure colours: map ``s`` in [0, 1] (clipped) to 8-bit RGB.

    Parameters
    ----------
    s : array_like
        Normalised values, ``(p - p_min) / (p_max - p_min)``.

    Returns
    -------
    ndarray of uint8, shape ``s.shape + (3,)``
        The 256-entry viridis-like table the frames use, nearest entry.

    Examples
    --------
    >>> colormap([0.0, 1.0]).tolist()
    [[68, 1, 84], [253, 231, 37]]
    """
    return _LUT[_lut_index(np.asarray(s, dtype=np.float64))]


def _lut_index(s):
    return np.clip(np.rint(s * (_LUT_SIZE - 1)), 0, _LUT_SIZE - 1).astype(np.int32)


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


def _acquire_window(size):
    """The shared window at ``size`` (width, height) for the current program."""
    prog = impl.get_runtime().prog
    if _DISPLAY["window"] is not None and (_DISPLAY["size"] != size
                                           or _DISPLAY["prog"] is not prog):
        close_window()
    if _DISPLAY["window"] is None:
        with _in_private_dir(), _taichi_logging_at_least("warn"):
            window = ti.ui.Window("taichi_hsdem", size, vsync=False, show_window=False)
        _DISPLAY.update(window=window, size=size, prog=prog)
    return _DISPLAY["window"]


@contextlib.contextmanager
def _taichi_logging_at_least(level):
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


def _ensure_taichi():
    if impl.get_runtime().prog is None:
        backend.init("cpu")


# ---------------------------------------------------------------------------
# Geometry helpers (host, once per renderer)

def _template_outline(shape):
    if shape.kind == "circle":
        a = 2.0 * np.pi * np.arange(_CIRCLE_SEGMENTS) / _CIRCLE_SEGMENTS
        return shape.radius * np.column_stack([np.cos(a), np.sin(a)])
    return np.asarray(shape.vertices, dtype=np.float64)


def _inset(outline, width):
    """The CCW ``outline`` moved ``width`` inwards: each vertex slides along its
    bisector to the point ``width`` from both adjacent edge lines (the miter
    length is capped at 4 ``width`` for very sharp corners)."""
    edge_in = outline - np.roll(outline, 1, axis=0)
    edge_out = np.roll(outline, -1, axis=0) - outline
    n_in = np.column_stack([-edge_in[:, 1], edge_in[:, 0]]) / np.hypot(*edge_in.T)[:, None]
    n_out = np.column_stack([-edge_out[:, 1], edge_out[:, 0]]) / np.hypot(*edge_out.T)[:, None]
    cos_turn = np.einsum("ij,ij->i", n_in, n_out)
    miter = (n_in + n_out) / np.maximum(1.0 + cos_turn, 1.0 / 8.0)[:, None]
    return outline + width * miter


def _template_block(shape, outline_width):
    """Body-frame triangle vertices and their roles for one template.

    A particle is its outline's triangles in the dark colour, then the same
    triangulation of the outline moved ``outline_width`` inwards in the fill
    colour, leaving a dark rim; a disk adds a dark tick from its centre towards
    ``theta = 0`` so that its rotation shows. On a particle too small for the
    rim the width is halved until the inset triangles keep their orientation.
    """
    outline = _template_outline(shape)
    if signed_area(outline) < 0:
        outline = outline[::-1]
    triangles = triangulate(outline)
    width = outline_width
    inner = _inset(outline, width)
    while np.any(triangle_areas(inner, triangles) <= 0.0) and width > 1e-3 * outline_width:
        width *= 0.5
        inner = _inset(outline, width)
    parts = [outline[triangles].reshape(-1, 2), inner[triangles].reshape(-1, 2)]
    roles = [np.full(3 * len(triangles), _ROLE_OUTLINE), np.full(3 * len(triangles), _ROLE_FILL)]
    if shape.kind == "circle":
        r = shape.radius
        x0, x1, h = _TICK_FROM * r, _TICK_TO * r, _TICK_HALF_WIDTH * r
        tick = np.array([[x0, -h], [x1, -h], [x1, h], [x0, -h], [x1, h], [x0, h]])
        parts.append(tick)
        roles.append(np.full(len(tick), _ROLE_OUTLINE))
    return np.vstack(parts), np.concatenate(roles)


# ---------------------------------------------------------------------------
# Kernels

@ti.kernel
def _fluid_mask(vertices: ti.types.ndarray(dtype=ti.f64, ndim=2),
                starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
                x0: ti.f64, y0: ti.f64, dx: ti.f64, dy: ti.f64,
                mask: ti.types.ndarray(dtype=ti.u8, ndim=2)):
    """mask[i, j] = 1 where pixel (i, j)'s centre (j from the bottom) is inside
    polygon 0 (the outline) and outside every later polygon (obstacles);
    even-odd crossing test per polygon."""
    for i, j in ti.ndrange(mask.shape[0], mask.shape[1]):
        px = x0 + (i + 0.5) * dx
        py = y0 + (j + 0.5) * dy
        fluid = 0
        for k in range(starts.shape[0] - 1):
            first = starts[k]
            end = starts[k + 1]
            inside = 0
            for e in range(first, end):
                f = e + 1
                if f == end:
                    f = first
                ya = vertices[e, 1]
                yb = vertices[f, 1]
                if (ya > py) != (yb > py):
                    xa = vertices[e, 0]
                    xc = xa + (py - ya) * (vertices[f, 0] - xa) / (yb - ya)
                    if px < xc:
                        inside = 1 - inside
            if k == 0:
                fluid = inside
            elif inside == 1:
                fluid = 0
        mask[i, j] = ti.cast(fluid, ti.u8)


@ti.kernel
def _paint_background(mask: ti.types.ndarray(dtype=ti.u8, ndim=2),
                      cell_colour: ti.types.ndarray(dtype=ti.i32, ndim=2),
                      pixel_to_cell: ti.types.vector(4, ti.f64),
                      palette: ti.types.ndarray(dtype=ti.u8, ndim=2),
                      image: ti.template()):
    """image[i, j] = palette[wall] outside the fluid, else the palette entry of
    the pressure cell holding the pixel's centre: cell index
    ``floor(a (i + 1/2) + b)`` with ``pixel_to_cell = (a_x, b_x, a_y, b_y)``,
    clamped to the grid."""
    w = image.shape[0]
    h = image.shape[1]
    nx = cell_colour.shape[0]
    ny = cell_colour.shape[1]
    for i, j in ti.ndrange(w, h):
        k = _WALL_INDEX
        if mask[i, j] != 0:
            fi = ti.floor(pixel_to_cell[0] * (i + 0.5) + pixel_to_cell[1], ti.i32)
            fj = ti.floor(pixel_to_cell[2] * (j + 0.5) + pixel_to_cell[3], ti.i32)
            k = cell_colour[ti.max(0, ti.min(fi, nx - 1)), ti.max(0, ti.min(fj, ny - 1))]
        image[i, j] = ti.Vector([palette[k, 0], palette[k, 1], palette[k, 2]], ti.u8)


@ti.kernel
def _place_particles(x: ti.types.ndarray(dtype=ti.f64, ndim=2),
                     theta: ti.types.ndarray(dtype=ti.f64, ndim=1),
                     template: ti.types.ndarray(dtype=ti.i32, ndim=1),
                     first: ti.types.ndarray(dtype=ti.i32, ndim=1),
                     fill: ti.types.ndarray(dtype=ti.f32, ndim=2),
                     block_start: ti.types.ndarray(dtype=ti.i32, ndim=1),
                     local: ti.types.ndarray(dtype=ti.f64, ndim=2),
                     role: ti.types.ndarray(dtype=ti.i32, ndim=1),
                     outline_rgb: ti.types.vector(3, ti.f32),
                     origin: ti.types.vector(2, ti.f64),
                     to_canvas: ti.types.vector(2, ti.f64),
                     used: ti.i32,
                     verts: ti.template(), colours: ti.template()):
    """Rotate and translate each visible particle's template block into canvas
    coordinates at its slot ``first[i]``; collapse the unused tail to a point."""
    for i in range(x.shape[0]):
        o = first[i]
        if o >= 0:
            t = template[i]
            c = ti.cos(theta[i])
            s = ti.sin(theta[i])
            for k in range(block_start[t], block_start[t + 1]):
                qx = local[k, 0]
                qy = local[k, 1]
                wx = x[i, 0] + c * qx - s * qy
                wy = x[i, 1] + s * qx + c * qy
                slot = o + k - block_start[t]
                verts[slot] = ti.cast(ti.Vector([(wx - origin[0]) * to_canvas[0],
                                                 (wy - origin[1]) * to_canvas[1]]), ti.f32)
                rgb = outline_rgb
                if role[k] == _ROLE_FILL:
                    rgb = ti.Vector([fill[i, 0], fill[i, 1], fill[i, 2]])
                colours[slot] = rgb
    for k in range(used, verts.shape[0]):
        verts[k] = ti.Vector([0.0, 0.0], ti.f32)


@ti.kernel
def _capture_to_frame(buffer: ti.types.ndarray(dtype=ti.f32, ndim=3),
                      frame: ti.types.ndarray(dtype=ti.u8, ndim=3)):
    """GGUI's (width, height, 4) float capture, row 0 at the bottom, into the
    top rows of a top-down (rows, width, 3) uint8 frame."""
    w = buffer.shape[0]
    h = buffer.shape[1]
    for i, j in ti.ndrange(w, h):
        for c in ti.static(range(3)):
            level = ti.min(ti.max(buffer[i, j, c], 0.0), 1.0)
            frame[h - 1 - j, i, c] = ti.cast(level * 255.0 + 0.5, ti.u8)


# ---------------------------------------------------------------------------
# Bitmap font: 5x7 cells, one hex byte per row, bit 4 = leftmost column.

_FONT_HEX = {
    " ": "00000000000000", "0": "0E11131519110E", "1": "040C040404040E",
    "2": "0E11010204081F", "3": "1F02040201110E", "4": "02060A121F0202",
    "5": "1F101E0101110E", "6": "0608101E11110E", "7": "1F010204080808",
    "8": "0E11110E11110E", "9": "0E11110F01020C",
    "A": "0E11111F111111", "B": "1E11111E11111E", "C": "0E11101010110E",
    "D": "1C12111111121C", "E": "1F10101E10101F", "F": "1F10101E101010",
    "G": "0E11101711110F", "H": "1111111F111111",
    "I": "0E04040404040E", "J": "0702020202120C", "K": "11121418141211",
    "L": "1010101010101F", "M": "111B1515111111", "N": "11111915131111",
    "O": "0E11111111110E", "P": "1E11111E101010", "Q": "0E11111115120D",
    "R": "1E11111E141211", "S": "0F10100E01011E", "T": "1F040404040404",
    "U": "1111111111110E", "V": "11111111110A04", "W": "1111111515150A",
    "X": "11110A040A1111", "Y": "1111110A040404", "Z": "1F01020408101F",
    "a": "00000E010F110F", "b": "1010161911111E",
    "c": "00000E1010110E", "d": "01010D1311110F", "e": "00000E111F100E",
    "f": "0609081C080808", "g": "000F11110F010E", "h": "10101619111111",
    "i": "04000C0404040E", "j": "0200060202120C", "k": "10101214181412",
    "l": "0C04040404040E", "m": "00001A15151111", "n": "00001619111111",
    "o": "00000E1111110E", "p": "00001E111E1010", "q": "00000D130F0101",
    "r": "00001619101010", "s": "00000E100E011E", "t": "08081C08080906",
    "u": "0000111111130D", "v": "00001111110A04", "w": "0000111115150A",
    "x": "0000110A040A11", "y": "000011110F010E",
    "z": "00001F0204081F",
    ".": "00000000000C0C", ",": "000000000C0408",
    ":": "000C0C000C0C00", ";": "000C0C000C0408", "-": "0000001F000000",
    "+": "0004041F040400", "=": "00001F001F0000", "_": "0000000000001F",
    "/": "01010204081010", "(": "02040808080402", ")": "08040202020408",
    "[": "0E08080808080E", "]": "0E02020202020E", "%": "18190204081303",
    "!": "04040404040004", "?": "0E110102040004", "#": "0A0A1F0A1F0A0A",
    "*": "0004150E150400", "<": "02040810080402", ">": "08040201020408",
    "'": "04040800000000", '"': "0A0A0000000000", "^": "040A1100000000",
    "|": "04040404040404", "~": "00000815020000",
}


def _glyph_cell(hex_rows):
    """A (7, 6) boolean character cell: the 5-pixel glyph and a blank column."""
    rows = [int(hex_rows[2 * r:2 * r + 2], 16) for r in range(_GLYPH_H)]
    return np.array([[(row >> (_GLYPH_W - 1 - c)) & 1 for c in range(_GLYPH_W)] + [0]
                     for row in rows], dtype=bool)


_GLYPH_CELLS = {ch: _glyph_cell(code) for ch, code in _FONT_HEX.items()}


def _text_mask(text, scale):
    """Boolean (7 scale, 6 scale len(text)) image of ``text``, each font pixel a
    ``scale`` x ``scale`` block; unknown characters print as '?'."""
    if not text:
        return np.zeros((_GLYPH_H * scale, 0), dtype=bool)
    line = np.hstack([_GLYPH_CELLS.get(ch, _GLYPH_CELLS["?"]) for ch in text])
    return line.repeat(scale, axis=0).repeat(scale, axis=1)


def _stamp(image, mask, row, col, colour):
    """Paint ``colour`` where ``mask`` is set, top-left at (row, col), clipped."""
    h = max(0, min(mask.shape[0], image.shape[0] - row))
    w = max(0, min(mask.shape[1], image.shape[1] - col))
    if h and w:
        image[row:row + h, col:col + w][mask[:h, :w]] = colour


def _format_time(t):
    t = float(t)
    return f"{t:.3f}" if t == 0.0 or 1e-2 <= abs(t) < 1e5 else f"{t:.3e}"


def _even(n):
    return max(2, 2 * int(round(n / 2.0)))


# ---------------------------------------------------------------------------

class Renderer:
    """Draws frames of one scene at a fixed size.

    The returned image is ``height = domain_height + strip_height`` rows by
    ``width`` columns: the domain (its bounding box, aspect kept, rounded to even
    sizes for H.264 yuv420p) on top, and below it a dark strip holding the text
    ``"t = 1.234 s   escapees 12"`` (after the title, if any) on the left and,
    when a pressure map is drawn, the colour bar with its range on the right.

    Parameters
    ----------
    bbox : (x_min, x_max, y_min, y_max)
        The world rectangle shown, m.
    outline : array_like, shape (nv, 2)
        The fluid region, a simple polygon (concave allowed). Everything in the
        frame outside it is drawn as wall grey.
    obstacles : list of array_like (k, 2)
        Solid islands inside the outline, drawn grey.
    shapes : list of shapes.Shape
        Particle templates; particle ``i`` is drawn as ``shapes[template[i]]``
        (a 32-gon for a circle, with a dark tick towards ``theta``), rotated by
        ``theta[i]`` and translated to ``x[i]``, with a dark outline.
    width : int, optional
        Image width in pixels (rounded to even), >= 64.
    pressure_shape : (nx, ny), optional
        The pressure grid: ``nx * ny`` cells tiling ``pressure_extent``, cell
        ``(i, j)`` covering ``[x0 + i dx, x0 + (i+1) dx] x [y0 + j dy, ...]``.
        Each fluid pixel shows the value of the cell holding its centre.
        Without it the fluid is drawn in a plain pale colour.
    pressure_range : (p_min, p_max), optional
        Fixed colour-map range, so that colours compare across frames; values
        outside are clipped. Without it each frame uses its own finite min/max.
    title : str, optional
        Printed before the time in the strip.
    pressure_extent : (x0, x1, y0, y1), optional
        The rectangle the pressure cells tile, m; default ``bbox``. (A grid of
        square cells may overhang the domain's top edge.)

    Notes
    -----
    Taichi must be initialised (``backend.init`` or ``ti.init``) before, or
    this initialises it on the CPU. All renderers share the process's one
    hidden GGUI window (see the module notes).
    """

    def __init__(self, bbox, outline, obstacles, shapes, width=960, pressure_shape=None,
                 pressure_range=None, title="", pressure_extent=None):
        ok, reason = vulkan_status()
        if not ok:
            raise RuntimeError(reason)
        x_min, x_max, y_min, y_max = (float(b) for b in bbox)
        if not (x_max > x_min and y_max > y_min):
            raise ValueError(f"bbox must be (x_min, x_max, y_min, y_max) with x_min < x_max "
                             f"and y_min < y_max, got {tuple(bbox)}")
        if int(width) < 64:
            raise ValueError(f"width must be at least 64 pixels, got {width}")
        if not shapes:
            raise ValueError("shapes must hold at least one particle template")
        self.bbox = (x_min, x_max, y_min, y_max)
        self.width = _even(int(width))
        self.domain_height = _even(self.width * (y_max - y_min) / (x_max - x_min))
        self._scale = max(1, int(round(self.width / 480)))  # font and strip scale
        self.strip_height = _even((_GLYPH_H + 8) * self._scale)
        self.height = self.domain_height + self.strip_height
        self.title = str(title)

        if pressure_shape is not None:
            nx, ny = (int(n) for n in pressure_shape)
            if nx < 1 or ny < 1:
                raise ValueError(f"pressure_shape must be two positive ints, got {pressure_shape}")
            pressure_shape = (nx, ny)
        else:
            nx = ny = 1
        self.pressure_shape = pressure_shape
        ex0, ex1, ey0, ey1 = (float(e) for e in (bbox if pressure_extent is None
                                                 else pressure_extent))
        if not (ex1 > ex0 and ey1 > ey0):
            raise ValueError(f"pressure_extent must be (x0, x1, y0, y1) with x0 < x1 and "
                             f"y0 < y1, got {tuple(pressure_extent)}")
        cell_x, cell_y = (ex1 - ex0) / nx, (ey1 - ey0) / ny
        self._pixel_to_cell = ((x_max - x_min) / self.width / cell_x, (x_min - ex0) / cell_x,
                               (y_max - y_min) / self.domain_height / cell_y,
                               (y_min - ey0) / cell_y)
        if pressure_range is not None:
            p_min, p_max = (float(p) for p in pressure_range)
            if not (np.isfinite(p_min) and np.isfinite(p_max) and p_max > p_min):
                raise ValueError(f"pressure_range must be finite with p_min < p_max, "
                                 f"got {tuple(pressure_range)}")
            pressure_range = (p_min, p_max)
        self.pressure_range = pressure_range

        polygons = [np.asarray(outline, dtype=np.float64)]
        polygons += [np.asarray(o, dtype=np.float64) for o in obstacles]
        for k, poly in enumerate(polygons):
            if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
                what = "outline" if k == 0 else f"obstacle {k - 1}"
                raise ValueError(f"{what} must be an (n >= 3, 2) array, got shape {poly.shape}")

        pixel = max((x_max - x_min) / self.width, (y_max - y_min) / self.domain_height)
        blocks = [_template_block(s, _OUTLINE_PX * pixel) for s in shapes]
        self._local = np.ascontiguousarray(np.vstack([b[0] for b in blocks]))
        self._role = np.concatenate([b[1] for b in blocks]).astype(np.int32)
        self._block_len = np.array([len(b[0]) for b in blocks], dtype=np.int64)
        self._block_start = np.concatenate([[0], np.cumsum(self._block_len)]).astype(np.int32)
        self.n_templates = len(shapes)

        self._plain_cells = np.full((1, 1), _PLAIN_INDEX, dtype=np.int32)

        _ensure_taichi()
        starts = np.cumsum([0] + [len(p) for p in polygons]).astype(np.int32)
        self._mask = np.zeros((self.width, self.domain_height), dtype=np.uint8)
        _fluid_mask(np.ascontiguousarray(np.vstack(polygons)), starts, x_min, y_min,
                    (x_max - x_min) / self.width, (y_max - y_min) / self.domain_height,
                    self._mask)
        # Taichi fields, made on the first draw and again after ti.init or close().
        self._prog = None
        self._trees = []
        self._capacity = 0

    # -- Taichi fields -------------------------------------------------------
    def _fields_for(self, capacity):
        """(background, vertices, vertex colours) fields of the current Taichi
        program, the vertex ones holding at least ``capacity`` entries."""
        _ensure_taichi()
        prog = impl.get_runtime().prog
        if prog is not self._prog:
            # A new program (or none yet): the old fields died with the old one.
            self._prog, self._trees, self._capacity = prog, [], 0
            # A u8 field, not a numpy image: GGUI's staging copy of a numpy
            # image costs ~40 ms a frame at 960 x 510, that of a field a few.
            self._background = ti.Vector.field(3, ti.u8)
            self._trees.append(self._place((self.width, self.domain_height), self._background))
        if capacity > self._capacity:
            if len(self._trees) > 1:
                self._trees.pop().destroy()
            self._verts = ti.Vector.field(2, ti.f32)
            self._colours = ti.Vector.field(3, ti.f32)
            self._trees.append(self._place(capacity, self._verts, self._colours))
            self._capacity = capacity
        return self._background, self._verts, self._colours

    @staticmethod
    def _place(shape, *fields):
        """Allocate ``fields`` in their own SNode tree, so they can be freed."""
        builder = ti.FieldsBuilder()
        axes = ti.ij if isinstance(shape, tuple) else ti.i
        builder.dense(axes, shape).place(*fields)
        return builder.finalize()

    # -- coordinates ---------------------------------------------------------
    def world_to_pixel(self, xy) -> np.ndarray:
        """Image coordinates (col, row) of world points, as floats.

        Pixel ``(c, r)`` covers ``[c, c+1) x [r, r+1)``, so the point falls in
        ``image[int(row), int(col)]`` of a frame from :meth:`draw` (row 0 at
        the top; world y points up).

        Examples
        --------
        >>> r.world_to_pixel([[x_min, y_max]])           # doctest: +SKIP
        array([[0., 0.]])
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        x_min, x_max, y_min, y_max = self.bbox
        col = (xy[:, 0] - x_min) / (x_max - x_min) * self.width
        row = (y_max - xy[:, 1]) / (y_max - y_min) * self.domain_height
        return np.column_stack([col, row])

    # -- drawing -------------------------------------------------------------
    def draw(self, x, theta, template, visible, pressure=None, t=0.0, escapees=0,
             colors=None) -> np.ndarray:
        """Render one frame.

        Parameters
        ----------
        x : array_like (N, 2)
            Particle centres, m.
        theta : array_like (N,)
            Angles, rad, counter-clockwise.
        template : array_like (N,) of int
            Index into ``shapes``.
        visible : array_like (N,) of bool
            Particles to draw (parked or removed ones are left out).
        pressure : array_like (nx, ny) or (nx * ny,), optional
            Cell pressures on ``pressure_shape`` (x index first); non-finite
            cells are drawn in the plain fluid colour. Needs ``pressure_shape``.
        t : float
            Time printed in the strip, s.
        escapees : int
            Count printed in the strip.
        colors : array_like (N, 3), optional
            Fill colours in [0, 1] replacing the per-species palette.

        Returns
        -------
        ndarray of uint8, shape (height, width, 3)
            Top-down RGB image.
        """
        x = np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(-1, 2))
        n = len(x)
        theta = np.ascontiguousarray(np.asarray(theta, dtype=np.float64).reshape(-1))
        template = np.ascontiguousarray(np.asarray(template).reshape(-1), dtype=np.int32)
        visible = np.asarray(visible, dtype=bool).reshape(-1)
        if not (len(theta) == len(template) == len(visible) == n):
            raise ValueError(f"x, theta, template, visible must have N entries each, got "
                             f"{n}, {len(theta)}, {len(template)}, {len(visible)}")
        if n and (template.min() < 0 or template.max() >= self.n_templates):
            raise ValueError(f"template ids must lie in [0, {self.n_templates}), got "
                             f"{template.min()}..{template.max()}")
        if colors is None:
            palette = np.array(SPECIES_COLORS, dtype=np.float32) / 255.0
            fill = palette[template % len(SPECIES_COLORS)]
        else:
            fill = np.asarray(colors, dtype=np.float32)
            if fill.shape != (n, 3):
                raise ValueError(f"colors must have shape ({n}, 3), got {fill.shape}")
        fill = np.ascontiguousarray(fill, dtype=np.float32)

        counts = np.where(visible, self._block_len[template], 0)
        ends = np.cumsum(counts)
        first = np.where(visible, ends - counts, -1).astype(np.int32)
        used = int(ends[-1]) if n else 0
        background, verts, colours = self._fields_for(max(3, int(self._block_len[template].sum())))

        cells, p_range = self._pressure_cells(pressure)
        _paint_background(self._mask, cells, self._pixel_to_cell, _BACKGROUND_PALETTE, background)

        x_min, x_max, y_min, y_max = self.bbox
        _place_particles(x, theta, template, first, fill, self._block_start, self._local,
                         self._role, [c / 255.0 for c in OUTLINE_DARK],
                         (x_min, y_min), (1.0 / (x_max - x_min), 1.0 / (y_max - y_min)),
                         used, verts, colours)

        window = _acquire_window((self.width, self.domain_height))
        canvas = window.get_canvas()
        canvas.set_image(background)
        canvas.triangles(verts, per_vertex_color=colours)
        with _taichi_logging_at_least("warn"):
            buffer = window.get_image_buffer_as_numpy()

        frame = np.empty((self.height, self.width, 3), dtype=np.uint8)
        _capture_to_frame(np.ascontiguousarray(buffer, dtype=np.float32), frame)
        self._draw_strip(frame[self.domain_height:], t, escapees, p_range)
        return frame

    def _pressure_cells(self, pressure):
        """Background palette index per pressure cell, and the range used."""
        if pressure is None:
            return self._plain_cells, None
        if self.pressure_shape is None:
            raise ValueError("this Renderer was built without pressure_shape; "
                             "pass pressure_shape=(nx, ny) to draw a pressure field")
        nx, ny = self.pressure_shape
        p = np.asarray(pressure, dtype=np.float64)
        if p.size != nx * ny:
            raise ValueError(f"pressure must hold nx * ny = {nx * ny} values "
                             f"(pressure_shape {self.pressure_shape}), got shape {p.shape}")
        p = p.reshape(nx, ny)
        finite = np.isfinite(p)
        if self.pressure_range is not None:
            p_min, p_max = self.pressure_range
        elif finite.any():
            p_min, p_max = float(p[finite].min()), float(p[finite].max())
            if p_max <= p_min:
                p_max = p_min + max(1.0, abs(p_min))
        else:
            return np.full((nx, ny), _PLAIN_INDEX, dtype=np.int32), None
        s = (np.where(finite, p, p_min) - p_min) / (p_max - p_min)
        cells = np.where(finite, _lut_index(s), _PLAIN_INDEX).astype(np.int32)
        return np.ascontiguousarray(cells), (p_min, p_max)

    def _draw_strip(self, strip, t, escapees, p_range):
        k = self._scale
        strip[:] = STRIP_BACKGROUND
        top = (strip.shape[0] - _GLYPH_H * k) // 2
        text_end = strip.shape[1]
        if p_range is not None:
            # From the right: p_max label, colour bar, p_min label, "p".
            bar_width = max(64, self.width // 5)
            hi = _text_mask(f"{p_range[1]:.3g}", k)
            lo = _text_mask(f"p {p_range[0]:.3g}", k)
            col = strip.shape[1] - 4 * k - hi.shape[1]
            _stamp(strip, hi, top, col, TEXT_COLOR)
            col -= 2 * k + bar_width
            strip[top:top + _GLYPH_H * k, col:col + bar_width] = colormap(
                np.linspace(0.0, 1.0, bar_width))[None, :, :]
            col -= 2 * k + lo.shape[1]
            _stamp(strip, lo, top, col, TEXT_COLOR)
            text_end = col - 6 * k
        text = f"t = {_format_time(t)} s   escapees {int(escapees)}"
        if self.title:
            text = f"{self.title}   {text}"
        mask = _text_mask(text, k)[:, :max(0, text_end - 4 * k)]
        _stamp(strip, mask, top, 4 * k, TEXT_COLOR)

    def close(self):
        """Free this renderer's Taichi fields and the shared window (a later
        draw makes them again)."""
        if impl.get_runtime().prog is self._prog:
            for tree in self._trees:
                tree.destroy()
        self._prog, self._trees, self._capacity = None, [], 0
        close_window()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ---------------------------------------------------------------------------

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
