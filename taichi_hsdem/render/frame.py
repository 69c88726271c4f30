"""Off-screen frames of a simulation.

A frame shows the walls (grey), the fluid region coloured by the pressure field
(a viridis-like map with a colour bar), and every particle with its true shape
and orientation. It is drawn with Taichi's GGUI on the process's hidden window
(:mod:`.window`; on a machine without a GPU the Mesa software driver from the
Debian packages ``mesa-vulkan-drivers libvulkan1`` does it) and read back as a
numpy image, to which a strip with the time, the escapee count and the colour
bar with its unit and range is added with the built-in bitmap font (:mod:`.font`). The window's
image is cleared after every capture, so :meth:`Renderer.draw` draws everything
each time. :mod:`.video` writes the frames as H.264.

Examples
--------
>>> from taichi_hsdem import render                              # doctest: +SKIP
>>> from taichi_hsdem.geometry import shapes                      # doctest: +SKIP
>>> r = render.Renderer((0, 4, 0, 2), outline, [], [shapes.circle(0.3)],
...                     pressure_shape=(40, 20), pressure_range=(0, 100))
>>> with render.VideoWriter("video.mp4", fps=25) as video:
...     video.write(r.draw(x, theta, template, visible, pressure=p, t=0.1))
"""

# No "from __future__ import annotations": Taichi reads kernel annotations as objects.
import numpy as np
import taichi as ti
from taichi.lang import impl

from ..dem.kmath import sin_cos
from ..geometry.polygon import signed_area, triangle_areas, triangulate
from ..geometry.shapes import outline_polygon
from .font import GLYPH_H, even, format_time, stamp, text_mask
from .window import (acquire_window, close_window, ensure_taichi, taichi_logging_at_least,
                     vulkan_status)

__all__ = ["colormap", "finite_range", "Renderer"]

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

# The strip's time suffix and pressure unit for each value of the scene's units.
_UNIT_LABELS = {"SI": (" s", "Pa"), "dimensionless": ("", "dimensionless")}

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


def finite_range(p):
    """``(min, max)`` of the finite values of ``p``, or None when none is finite.

    A flat field is widened to ``(p, p + max(1, |p|))`` so that it can serve as
    a colour-map range (``max > min``).

    Examples
    --------
    >>> finite_range([3.0, float("nan"), 1.0]), finite_range([2.0, 2.0])
    ((1.0, 3.0), (2.0, 4.0))
    """
    p = np.asarray(p, dtype=np.float64)
    finite = p[np.isfinite(p)]
    if finite.size == 0:
        return None
    lo, hi = float(finite.min()), float(finite.max())
    if hi <= lo:
        hi = lo + max(1.0, abs(lo))
    return lo, hi


# ---------------------------------------------------------------------------
# Geometry helpers (host, once per renderer)

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
    outline = outline_polygon(shape, _CIRCLE_SEGMENTS)
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
            c, s = sin_cos(theta[i])   # the kernels' own (SPIR-V has no f64 sin, cos)
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

class Renderer:
    """Draws frames of one scene at a fixed size.

    The returned image is ``height = domain_height + strip_height`` rows by
    ``width`` columns: the domain (its bounding box, aspect kept, rounded to even
    sizes for H.264 yuv420p) on top, and below it a dark strip holding the text
    ``"t = 1.234 s   escapees 12"`` (after the title, if any) on the left and,
    when a pressure map is drawn, the colour bar on the right, labelled with the
    pressure's unit and the range it spans: ``p (Pa) 0 [bar] 1.2e+03``. Where
    the strip is too short for all of it the bar narrows, then the title goes,
    then ``p (Pa)``, then the bar and its labels; the text is cut at the right
    edge last.

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
        Colour-map range, so that colours compare across frames; values outside
        are clipped unless ``grow_range``. Without it (and without
        ``grow_range``) each frame uses its own finite min/max.
    grow_range : bool, optional
        Widen :attr:`pressure_range` (starting from the given one, or the first
        frame's) to every drawn frame's finite min and max before colouring it:
        the scale follows the largest pressure seen so far and never clips, so
        a pressure that builds up (behind a clog under a flow-rate inlet) keeps
        its gradient visible; colours compare across frames while it holds.
    units : {"SI", "dimensionless"}, optional
        The scene's units: the strip prints ``t = 1.250 s`` and ``p (Pa)``, or
        ``t = 1.250`` and ``p (dimensionless)``.
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
                 pressure_range=None, title="", pressure_extent=None, grow_range=False,
                 units="SI"):
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
        self.width = even(int(width))
        self.domain_height = even(self.width * (y_max - y_min) / (x_max - x_min))
        self._scale = max(1, int(round(self.width / 480)))  # font and strip scale
        self.strip_height = even((GLYPH_H + 8) * self._scale)
        self.height = self.domain_height + self.strip_height
        self.title = str(title)
        if units not in _UNIT_LABELS:
            raise ValueError(f"units must be one of {sorted(_UNIT_LABELS)}, got {units!r}")
        self.time_unit, self.pressure_unit = _UNIT_LABELS[units]
        self.grow_range = bool(grow_range)

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

        ensure_taichi()
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
        ensure_taichi()
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

        window = acquire_window((self.width, self.domain_height))
        canvas = window.get_canvas()
        canvas.set_image(background)
        canvas.triangles(verts, per_vertex_color=colours)
        with taichi_logging_at_least("warn"):
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
        seen = finite_range(p)
        if self.grow_range and seen is not None:
            if self.pressure_range is not None:
                seen = (min(seen[0], self.pressure_range[0]), max(seen[1], self.pressure_range[1]))
            self.pressure_range = seen
        if self.pressure_range is not None:
            p_min, p_max = self.pressure_range
        elif seen is not None:
            p_min, p_max = seen
        else:
            return np.full((nx, ny), _PLAIN_INDEX, dtype=np.int32), None
        s = (np.where(finite, p, p_min) - p_min) / (p_max - p_min)
        cells = np.where(finite, _lut_index(s), _PLAIN_INDEX).astype(np.int32)
        return np.ascontiguousarray(cells), (p_min, p_max)

    def _draw_strip(self, strip, t, escapees, p_range):
        k = self._scale
        strip[:] = STRIP_BACKGROUND
        top = (strip.shape[0] - GLYPH_H * k) // 2
        status = f"t = {format_time(t)}{self.time_unit}   escapees {int(escapees)}"
        text = text_mask(f"{self.title}   {status}" if self.title else status, k)
        text_end = strip.shape[1]
        if p_range is not None:
            # From the right: p_max label, colour bar, "p (unit) p_min" label. A
            # narrow frame drops the "p (unit)" first, then the whole legend (the
            # time and count matter more).
            hi = text_mask(f"{p_range[1]:.3g}", k)
            min_bar = 32 * k
            need = min_bar + text_mask(status, k).shape[1]
            for label in (f"p ({self.pressure_unit}) {p_range[0]:.3g}", f"{p_range[0]:.3g}"):
                lo = text_mask(label, k)
                # what the bar may take: the strip less margins, gaps and labels
                room = strip.shape[1] - 18 * k - hi.shape[1] - lo.shape[1]
                if room >= need:
                    break
            if room >= need:
                if self.title and room - text.shape[1] < min_bar:
                    text = text_mask(status, k)       # the time and count matter more
                bar_width = max(min_bar, min(self.width // 5, room - text.shape[1]))
                col = strip.shape[1] - 4 * k - hi.shape[1]
                stamp(strip, hi, top, col, TEXT_COLOR)
                col -= 2 * k + bar_width
                strip[top:top + GLYPH_H * k, col:col + bar_width] = colormap(
                    np.linspace(0.0, 1.0, bar_width))[None, :, :]
                col -= 2 * k + lo.shape[1]
                stamp(strip, lo, top, col, TEXT_COLOR)
                text_end = col - 6 * k
            elif self.title:
                text = text_mask(status, k)
        stamp(strip, text[:, :max(0, text_end - 4 * k)], top, 4 * k, TEXT_COLOR)

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
