"""Frames and video: pixels read back at known world points against the colours
the scene puts there, geometry against exact areas, the MP4 against its codec
and size, and the process's working folder against stray files."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import backend
from taichi_hsdem import render
from taichi_hsdem.geometry.polygon import triangulate
from taichi_hsdem.render.font import text_mask
from taichi_hsdem.geometry import shapes

REPO = Path(__file__).resolve().parents[1]

# Domain [0, 4] x [0, 2]: a channel y in [0.2, 1.8] with an hourglass neck
# (walls reach y = 0.7 and 1.3 at x = 2) and a rectangular obstacle.
BBOX = (0.0, 4.0, 0.0, 2.0)
OUTLINE = np.array([(0, 0.2), (1.5, 0.2), (2, 0.7), (2.5, 0.2), (4, 0.2),
                    (4, 1.8), (2.5, 1.8), (2, 1.3), (1.5, 1.8), (0, 1.8)], dtype=float)
OBSTACLE = np.array([(3.5, 0.9), (3.8, 0.9), (3.8, 1.1), (3.5, 1.1)], dtype=float)
WIDTH = 400                      # 0.01 world units per pixel
P_SHAPE = (40, 20)               # cells of 0.1 x 0.1
P_RANGE = (0.0, 100.0)

# Templates: 0 disk d = 0.3, 1 square side 0.4, 2 concave L (arms 0.1 wide).
L_RAW = np.array([(0, 0), (0.3, 0), (0.3, 0.1), (0.1, 0.1), (0.1, 0.3), (0, 0.3)], dtype=float)
# Centroid of the L, from its two rectangles [0,0.3]x[0,0.1] (area 0.03) and
# [0,0.1]x[0.1,0.3] (area 0.02); shapes.polygon recentres the outline on it.
L_CENTROID = (0.03 * np.array([0.15, 0.05]) + 0.02 * np.array([0.05, 0.2])) / 0.05

X = np.array([[0.6, 1.0], [1.0, 0.6], [3.0, 1.0], [1.0, 1.3], [0.3, 0.5]])
THETA = np.array([0.0, np.pi / 2, np.pi / 6, 0.0, 0.0])
TEMPLATE = np.array([0, 0, 1, 2, 0])
VISIBLE = np.array([True, True, True, True, False])   # the last one is parked


def cell_pressure(x):
    """p = 100 - 25 x, sampled at cell centres of the 0.1-wide columns."""
    return 100.0 - 25.0 * x


def pressure_field():
    xc = (np.arange(P_SHAPE[0]) + 0.5) * (BBOX[1] - BBOX[0]) / P_SHAPE[0]
    return np.repeat(cell_pressure(xc)[:, None], P_SHAPE[1], axis=1)


def luminance(rgb):
    return np.asarray(rgb, dtype=float) @ np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module", autouse=True)
def taichi_cpu():
    import taichi.lang.impl as impl
    if impl.get_runtime().prog is None:
        backend.init("cpu")


@pytest.fixture(scope="module")
def renderer(taichi_cpu):
    templates = [shapes.circle(0.3), shapes.square(0.4), shapes.polygon(L_RAW)]
    r = render.Renderer(BBOX, OUTLINE, [OBSTACLE], templates, width=WIDTH,
                        pressure_shape=P_SHAPE, pressure_range=P_RANGE, title="test")
    yield r
    r.close()


@pytest.fixture(scope="module")
def frame(renderer):
    return renderer.draw(X, THETA, TEMPLATE, VISIBLE, pressure=pressure_field(), t=1.25,
                         escapees=12)


def pixel(renderer, image, xy):
    col, row = renderer.world_to_pixel(np.asarray(xy, dtype=float))[0]
    return image[int(row), int(col)]


def species(k):
    return np.array(render.SPECIES_COLORS[k], dtype=np.uint8)


def expected_fluid(renderer, xy):
    """Colour of free fluid in the pixel holding xy: the pressure of the cell
    holding that pixel's centre, on the fixed range."""
    col = int(renderer.world_to_pixel(np.asarray(xy, dtype=float))[0, 0])
    x_centre = (col + 0.5) * (BBOX[1] - BBOX[0]) / WIDTH
    xc = (np.floor(x_centre / 0.1) + 0.5) * 0.1
    return render.colormap((cell_pressure(xc) - P_RANGE[0]) / (P_RANGE[1] - P_RANGE[0]))


def body_to_world(p, centre, theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([c * p[0] - s * p[1], s * p[0] + c * p[1]]) + centre


# ------------------------------------------------------------------ environment

def test_vulkan_status_reports_working_ggui_here():
    ok, reason = render.vulkan_status()
    assert ok, reason


def test_vulkan_status_without_a_driver_names_the_packages(tmp_path):
    script = (
        "import json\n"
        "from taichi_hsdem import render\n"
        "ok, reason = render.vulkan_status()\n"
        "try:\n"
        "    render.Renderer((0, 1, 0, 1), [(0, 0), (1, 0), (1, 1)], [], [None])\n"
        "    refused = ''\n"
        "except RuntimeError as e:\n"
        "    refused = str(e)\n"
        "print(json.dumps([ok, reason, refused]))\n")
    missing = str(tmp_path / "no_such_icd.json")
    env = dict(os.environ, VK_ICD_FILENAMES=missing, VK_DRIVER_FILES=missing,
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    ok, reason, refused = json.loads(proc.stdout.strip().splitlines()[-1])
    assert ok is False
    assert "mesa-vulkan-drivers" in reason and "libvulkan1" in reason
    assert "Vulkan must be available" in reason          # Taichi's own error, passed on
    assert refused == reason


# ------------------------------------------------------------------ frame layout

def test_frame_size_is_even_and_keeps_the_aspect(renderer, frame):
    assert renderer.width == WIDTH
    assert renderer.domain_height == 200                 # 400 * 2 / 4
    assert renderer.height == renderer.domain_height + renderer.strip_height
    assert frame.shape == (renderer.height, WIDTH, 3) and frame.dtype == np.uint8
    assert renderer.height % 2 == 0 and renderer.width % 2 == 0


def test_world_to_pixel_maps_corners_top_down(renderer):
    px = renderer.world_to_pixel([[0.0, 2.0], [4.0, 0.0], [1.0, 1.5]])
    np.testing.assert_allclose(px, [[0, 0], [400, 200], [100, 50]], atol=1e-9)


# ------------------------------------------------------------------ background

def test_walls_and_obstacles_are_grey(renderer, frame):
    grey = np.array(render.WALL_GREY, dtype=np.uint8)
    for xy in [(0.5, 0.05), (3.0, 1.95), (2.0, 0.5), (2.0, 1.5), (3.65, 1.0)]:
        np.testing.assert_array_equal(pixel(renderer, frame, xy), grey, err_msg=str(xy))


def test_free_fluid_shows_the_pressure_colour_and_darkens_downstream(renderer, frame):
    xs = np.array([0.25, 0.75, 1.25, 2.75, 3.25, 3.85])
    got = np.array([pixel(renderer, frame, (x, 1.65)) for x in xs])
    want = np.array([expected_fluid(renderer, (x, 1.65)) for x in xs])
    np.testing.assert_array_equal(got, want)
    # p falls with x; the colour map's lightness rises with p.
    assert np.all(np.diff(luminance(got)) < 0)
    # 8-bit rounding makes a few neighbouring entries equal, never darker.
    lut = luminance(render.colormap(np.linspace(0.0, 1.0, 256)))
    assert np.all(np.diff(lut) >= 0) and np.all(np.diff(lut[::4]) > 0)


def test_pressure_outside_the_range_is_clipped_and_nan_is_plain(renderer):
    p = pressure_field()
    p[:10] = 1e6                   # x < 1: far above p_max
    p[10:20] = np.nan              # 1 < x < 2: no value
    img = renderer.draw(X[:0], THETA[:0], TEMPLATE[:0], VISIBLE[:0], pressure=p)
    np.testing.assert_array_equal(pixel(renderer, img, (0.55, 1.65)), render.colormap(1.0))
    np.testing.assert_array_equal(pixel(renderer, img, (1.25, 1.65)),
                                  np.array(render.FLUID_PLAIN, dtype=np.uint8))


def test_pressure_grid_overhanging_the_domain(renderer):
    """Square cells of 0.1 whose 25 rows reach y = 2.5 above the 2.0-high frame."""
    r = render.Renderer(BBOX, OUTLINE, [], [shapes.circle(0.3)], width=WIDTH,
                        pressure_shape=(40, 25), pressure_range=(0.0, 2.5),
                        pressure_extent=(0.0, 4.0, 0.0, 2.5))
    yc = (np.arange(25) + 0.5) * 0.1
    p = np.repeat(yc[None, :], 40, axis=0)               # p = y at cell centres
    img = r.draw(X[:0], THETA[:0], TEMPLATE[:0], VISIBLE[:0], pressure=p)
    for y in (0.25, 0.95, 1.75):
        row = int(r.world_to_pixel([(0.5, y)])[0, 1])
        y_centre = 2.0 - (row + 0.5) * 0.01
        want = render.colormap(((np.floor(y_centre / 0.1) + 0.5) * 0.1) / 2.5)
        np.testing.assert_array_equal(pixel(r, img, (0.5, y)), want, err_msg=str(y))
    r.close()                       # frees its fields and the window; drawing remakes them
    np.testing.assert_array_equal(
        r.draw(X[:0], THETA[:0], TEMPLATE[:0], VISIBLE[:0], pressure=p), img)
    r.close()


def test_without_pressure_the_fluid_is_plain(renderer):
    img = renderer.draw(X[:0], THETA[:0], TEMPLATE[:0], VISIBLE[:0])
    np.testing.assert_array_equal(pixel(renderer, img, (3.0, 1.0)),
                                  np.array(render.FLUID_PLAIN, dtype=np.uint8))


# ------------------------------------------------------------------ particles

def test_particle_centres_have_their_species_colour(renderer, frame):
    for i in range(3):                  # the L's centroid lies in its notch
        np.testing.assert_array_equal(pixel(renderer, frame, X[i]), species(TEMPLATE[i]),
                                      err_msg=f"particle {i}")


def test_parked_particle_is_not_drawn(renderer, frame):
    np.testing.assert_array_equal(pixel(renderer, frame, X[4]), expected_fluid(renderer, X[4]))


def test_rotated_square_fills_its_rotated_corner_only(renderer, frame):
    corner = 0.85 * np.array([0.2, 0.2])          # just inside the body-frame corner
    rotated = body_to_world(corner, X[2], THETA[2])
    unrotated = X[2] + corner
    np.testing.assert_array_equal(pixel(renderer, frame, rotated), species(1))
    np.testing.assert_array_equal(pixel(renderer, frame, unrotated),
                                  expected_fluid(renderer, unrotated))
    # Outside the square just beyond an edge midpoint: fluid.
    beyond = body_to_world(np.array([0.23, 0.0]), X[2], THETA[2])
    np.testing.assert_array_equal(pixel(renderer, frame, beyond), expected_fluid(renderer, beyond))


def test_concave_particle_leaves_its_notch_empty(renderer, frame):
    arms = [np.array([0.25, 0.05]), np.array([0.05, 0.25])]
    notch = np.array([0.2, 0.2])
    for a in arms:
        np.testing.assert_array_equal(pixel(renderer, frame, X[3] + a - L_CENTROID), species(2))
    w = X[3] + notch - L_CENTROID
    np.testing.assert_array_equal(pixel(renderer, frame, w), expected_fluid(renderer, w))


def test_particles_have_a_dark_rim(renderer, frame):
    dark = np.array(render.OUTLINE_DARK, dtype=np.uint8)
    # The square's edge at body x = +0.2 lies on a pixel boundary only by
    # chance; scan across it and expect a dark pixel between fill and fluid.
    samples = [pixel(renderer, frame, body_to_world(np.array([u, 0.0]), X[2], THETA[2]))
               for u in np.linspace(0.17, 0.23, 13)]
    assert any(np.array_equal(s, dark) for s in samples)


def test_disk_tick_points_along_theta(renderer, frame):
    dark = np.array(render.OUTLINE_DARK, dtype=np.uint8)
    r = 0.15
    for i in (0, 1):                          # theta = 0 and pi / 2
        along = X[i] + 0.65 * r * np.array([np.cos(THETA[i]), np.sin(THETA[i])])
        across = X[i] + 0.65 * r * np.array([-np.sin(THETA[i]), np.cos(THETA[i])])
        np.testing.assert_array_equal(pixel(renderer, frame, along), dark)
        np.testing.assert_array_equal(pixel(renderer, frame, across), species(0))


def test_colors_override_the_species_palette(renderer):
    colors = np.tile([[0.0, 1.0, 0.0]], (len(X), 1))
    img = renderer.draw(X, THETA, TEMPLATE, VISIBLE, pressure=pressure_field(), colors=colors)
    np.testing.assert_array_equal(pixel(renderer, img, X[2]), [0, 255, 0])


def test_every_frame_is_redrawn_from_scratch(renderer, frame):
    moved = X.copy()
    moved[0] = (0.6, 1.5)
    img = renderer.draw(moved, THETA, TEMPLATE, VISIBLE, pressure=pressure_field(), t=1.25,
                        escapees=12)
    np.testing.assert_array_equal(pixel(renderer, img, X[0]), expected_fluid(renderer, X[0]))
    np.testing.assert_array_equal(pixel(renderer, img, moved[0]), species(0))
    again = renderer.draw(X, THETA, TEMPLATE, VISIBLE, pressure=pressure_field(), t=1.25,
                          escapees=12)
    np.testing.assert_array_equal(again, frame)


def test_bad_inputs_are_refused(renderer):
    with pytest.raises(ValueError, match="template"):
        renderer.draw(X, THETA, np.full(len(X), 7), VISIBLE)
    with pytest.raises(ValueError, match="pressure"):
        renderer.draw(X, THETA, TEMPLATE, VISIBLE, pressure=np.zeros(5))


# ------------------------------------------------------------------ strip

def test_strip_prints_time_escapees_and_colour_bar(renderer, frame):
    other = renderer.draw(X, THETA, TEMPLATE, VISIBLE, pressure=pressure_field(), t=1.25,
                          escapees=13)
    changed_rows = np.nonzero(np.any(other != frame, axis=(1, 2)))[0]
    assert changed_rows.size and changed_rows.min() >= renderer.domain_height

    strip = frame[renderer.domain_height:]
    scale = 1                                          # width 400 -> font scale 1
    text = text_mask("test   t = 1.250 s   escapees 12", scale)
    top = (strip.shape[0] - 7 * scale) // 2
    region = strip[top:top + text.shape[0], 4 * scale:4 * scale + text.shape[1]]
    lit = np.all(region == np.array(render.TEXT_COLOR, dtype=np.uint8), axis=2)
    np.testing.assert_array_equal(lit, text)

    bar_row = strip[top + 3]
    colours = {tuple(c) for c in bar_row}
    assert tuple(render.colormap(0.0)) in colours and tuple(render.colormap(1.0)) in colours


def strip_text_at(renderer, image, text, col):
    """Whether ``text`` is printed in the strip at column ``col`` (lit pixels
    exactly the font's, over the text's box)."""
    k = renderer._scale
    strip = image[renderer.domain_height:]
    mask = text_mask(text, k)
    top = (strip.shape[0] - 7 * k) // 2
    region = strip[top:top + mask.shape[0], col:col + mask.shape[1]]
    lit = np.all(region == np.array(render.TEXT_COLOR, dtype=np.uint8), axis=2)
    return lit.shape == mask.shape and bool(np.array_equal(lit, mask))


def bar_labels(renderer, image, unit, p_min, p_max):
    """The columns of the colour bar's labels ``p (<unit>) p_min`` and ``p_max``
    (None where absent): the bar's first and last columns are the colour map's
    ends, on the strip's middle row."""
    strip = image[renderer.domain_height:]
    k = renderer._scale
    row = strip[(strip.shape[0] - 7 * k) // 2 + 3]
    first = np.nonzero(np.all(row == render.colormap(0.0), axis=1))[0]
    last = np.nonzero(np.all(row == render.colormap(1.0), axis=1))[0]
    if not (first.size and last.size):
        return None, None
    lo = f"p ({unit}) {p_min:.3g}"
    lo_col = first[0] - 2 * k - text_mask(lo, k).shape[1]
    return (lo_col if strip_text_at(renderer, image, lo, lo_col) else None,
            last[-1] + 1 + 2 * k if strip_text_at(renderer, image, f"{p_max:.3g}",
                                                  last[-1] + 1 + 2 * k) else None)


def test_colour_bar_is_labelled_with_its_unit_and_range(renderer, frame):
    """SI: 'p (Pa) 0' left of the bar and '100' right of it, 't = 1.250 s'."""
    lo, hi = bar_labels(renderer, frame, "Pa", *P_RANGE)
    assert lo is not None and hi is not None and lo < hi


def test_dimensionless_scene_prints_no_seconds_and_no_pascals(renderer):
    """A dimensionless scene's strip reads 't = 1.250' and 'p (dimensionless)';
    a title too long to fit beside the bar gives way to the time and count."""
    r = render.Renderer(BBOX, OUTLINE, [], [shapes.circle(0.3)], width=WIDTH,
                        pressure_shape=P_SHAPE, pressure_range=P_RANGE, title="x" * 40,
                        units="dimensionless")
    img = r.draw(X[:0], THETA[:0], TEMPLATE[:0], VISIBLE[:0], pressure=pressure_field(),
                 t=1.25, escapees=12)
    assert strip_text_at(r, img, "t = 1.250   escapees 12", 4)
    lo, hi = bar_labels(r, img, "dimensionless", *P_RANGE)
    assert lo is not None and hi is not None
    with pytest.raises(ValueError, match="units"):
        render.Renderer(BBOX, OUTLINE, [], [shapes.circle(0.3)], units="cgs")
    r.close()


def test_growing_range_keeps_a_tenfold_pressure_rise_unsaturated(renderer):
    """grow_range (the video's scale): the range starts at P_RANGE and widens to
    each frame's extremes. A field that rises 10x (the inlet pressure behind a
    clog under a flow-rate inlet) is coloured on the new range, not clipped at
    the old p_max where all of x < 3.6 would be one colour; a later lower field
    is drawn on the widened range (it never shrinks)."""
    r = render.Renderer(BBOX, OUTLINE, [], [shapes.circle(0.3)], width=WIDTH,
                        pressure_shape=P_SHAPE, pressure_range=P_RANGE, grow_range=True)
    none = (X[:0], THETA[:0], TEMPLATE[:0], VISIBLE[:0])
    xs = np.array([0.25, 0.75, 1.25, 2.75, 3.25, 3.85])
    r.draw(*none, pressure=pressure_field())
    assert r.pressure_range == P_RANGE                # within the initial range
    rise = 10.0 * pressure_field()
    img = r.draw(*none, pressure=rise)
    p_max = float(rise.max())                         # 987.5, the cell at x = 0.05
    assert r.pressure_range == (0.0, p_max)
    got = np.array([pixel(r, img, (x, 1.65)) for x in xs])
    cells = 10.0 * cell_pressure((np.floor(xs / 0.1) + 0.5) * 0.1)
    np.testing.assert_array_equal(got, render.colormap(cells / p_max))
    assert np.all(np.diff(luminance(got)) < 0)       # the gradient shows upstream too
    assert bar_labels(r, img, "Pa", 0.0, p_max)[1] is not None
    img = r.draw(*none, pressure=pressure_field())
    assert r.pressure_range == (0.0, p_max)
    got = np.array([pixel(r, img, (x, 1.65)) for x in xs])
    np.testing.assert_array_equal(got, render.colormap(cells / 10.0 / p_max))
    r.close()


# ------------------------------------------------------------------ triangulation

def polygon_area(v):
    x, y = np.asarray(v, dtype=float).T
    return 0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


@pytest.mark.parametrize("outline", [
    L_RAW,
    L_RAW[::-1],                                            # clockwise
    [(np.cos(a) * (1 + 0.5 * (k % 2)), np.sin(a) * (1 + 0.5 * (k % 2)))   # star
     for k, a in enumerate(np.linspace(0, 2 * np.pi, 12, endpoint=False))],
    [(0, 0), (1, 0), (2, 0), (2, 1), (0, 1)],               # a collinear vertex
])
def test_ear_clipping_covers_the_polygon_exactly(outline):
    v = np.asarray(outline, dtype=float)
    tri = triangulate(v)
    a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
    areas = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    assert np.all(areas > 0)
    assert areas.sum() == pytest.approx(abs(polygon_area(v)), rel=1e-12)


def test_ear_clipping_refuses_a_self_intersecting_outline():
    with pytest.raises(ValueError, match="not simple"):
        triangulate([(0, 0), (1, 1), (1, 0), (0, 1), (0.5, 2), (-1, 0.5)])


# ------------------------------------------------------------------ video

def test_video_is_h264_yuv420p_at_the_frame_size(renderer, tmp_path):
    import imageio.v2 as imageio
    import imageio_ffmpeg

    path = tmp_path / "video.mp4"
    n = 6
    written = []
    with render.VideoWriter(path, fps=10) as video:
        for k in range(n):
            x = X.copy()
            x[0, 0] = 0.4 + 0.1 * k
            img = renderer.draw(x, THETA, TEMPLATE, VISIBLE, pressure=pressure_field(),
                                t=0.1 * k, escapees=k)
            video.write(img)
            written.append(img)
    assert video.frames == n

    reader = imageio.get_reader(path)
    meta = reader.get_meta_data()
    frames = [f for f in reader]
    reader.close()
    assert meta["codec"] == "h264"
    assert tuple(meta["size"]) == (renderer.width, renderer.height)
    assert meta["fps"] == pytest.approx(10)
    assert len(frames) == n
    assert frames[0].shape == (renderer.height, renderer.width, 3)
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).max() > 100
    # Lossy, but the same picture (no resizing or shift).
    assert np.mean(np.abs(frames[2].astype(int) - written[2].astype(int))) < 4.0

    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                           capture_output=True, text=True)
    stream = next(ln for ln in probe.stderr.splitlines() if "Video:" in ln)
    assert "h264" in stream and "yuv420p" in stream
    assert f"{renderer.width}x{renderer.height}" in stream


def test_video_writer_refuses_odd_or_changing_sizes(tmp_path):
    with render.VideoWriter(tmp_path / "v.mp4", fps=5) as video:
        with pytest.raises(ValueError, match="even"):
            video.write(np.zeros((11, 16, 3), np.uint8))
        video.write(np.zeros((12, 16, 3), np.uint8))
        with pytest.raises(ValueError, match="differs"):
            video.write(np.zeros((14, 16, 3), np.uint8))


# ------------------------------------------------------------------ one window, no files

def test_renderers_of_different_sizes_share_the_window_in_turn(renderer, frame, tmp_path,
                                                               monkeypatch):
    monkeypatch.chdir(tmp_path)
    small = render.Renderer(BBOX, OUTLINE, [], [shapes.circle(0.3)], width=200)
    img = small.draw(X[:1], THETA[:1], [0], [True])
    assert img.shape == (small.height, 200, 3)
    np.testing.assert_array_equal(pixel(small, img, X[0]), species(0))
    again = renderer.draw(X, THETA, TEMPLATE, VISIBLE, pressure=pressure_field(), t=1.25,
                          escapees=12)
    np.testing.assert_array_equal(again, frame)
    small.close()
    assert os.listdir(tmp_path) == []


def test_no_file_is_left_in_the_working_folder_and_reinit_is_survived(tmp_path):
    """A fresh process in an empty folder: draw, re-initialise Taichi, draw
    again, exit without closing anything. It must exit cleanly (no crash at
    teardown) and leave the folder and its temp folder empty."""
    work = tmp_path / "work"
    tmp = tmp_path / "tmp"
    work.mkdir()
    tmp.mkdir()
    script = (
        "import numpy as np, taichi as ti\n"
        "from taichi_hsdem import render\nfrom taichi_hsdem.geometry import shapes\n"
        "ti.init(arch=ti.cpu, log_level=ti.ERROR)\n"
        "args = ((0, 2, 0, 1), [(0, 0), (2, 0), (2, 1), (0, 1)], [], [shapes.square(0.4)])\n"
        "r = render.Renderer(*args, width=128)\n"
        "a = r.draw([[1.0, 0.5]], [0.3], [0], [True])\n"
        "ti.init(arch=ti.cpu, log_level=ti.ERROR)\n"
        "b = r.draw([[1.0, 0.5]], [0.3], [0], [True])\n"
        "assert np.array_equal(a, b)\n"
        "print('drawn')\n")
    env = dict(os.environ, TMPDIR=str(tmp),
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-c", script], cwd=work, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "drawn" in proc.stdout
    assert os.listdir(work) == []
    assert os.listdir(tmp) == []
