"""video.mp4 from the command line: codec, frame count, fps, and particles drawn
where (and turned the way) summary.json's final state says; frame 0 is the
initial state and the pressure range stays fixed; without a Vulkan driver the
run still succeeds, says why there is no video and leaves no stray files."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import load_scene, render
from taichi_hsdem.resolve import resolve

REPO = Path(__file__).resolve().parents[1]
HOURGLASS = REPO / "scenes" / "hourglass24.toml"

# Colour tolerance per channel after H.264 at crf 15 with 4:2:0 chroma, on a
# 3 x 3 median well inside a flat area.
TOL = 20


def _env(**extra):
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.update(extra)
    return env


def run_cli(scene, out, cwd, *args, env=None, timeout=300):
    cmd = [sys.executable, "-m", "taichi_hsdem", str(scene), "--out", str(out), *args]
    return subprocess.run(cmd, cwd=cwd, env=env or _env(), capture_output=True, text=True,
                          timeout=timeout)


def needs_vulkan():
    ok, reason = render.vulkan_status()
    if not ok:
        pytest.skip(f"no off-screen rendering here: {reason}")


def read_video(path):
    import imageio.v2 as imageio
    reader = imageio.get_reader(path)
    meta = reader.get_meta_data()
    frames = [f for f in reader]
    reader.close()
    return meta, frames


def stream_line(path):
    import imageio_ffmpeg
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                           capture_output=True, text=True)
    return next(ln for ln in probe.stderr.splitlines() if "Video:" in ln)


class PixelMap:
    """The Renderer's world-to-pixel transform, rebuilt from the resolved scene
    (bounding box of the geometry, output.width, even sizes)."""

    def __init__(self, out):
        self.scene = load_scene(str(out / "scene.resolved.toml"))
        g = resolve(self.scene).geometry
        self.bbox = (g.x_min, g.x_max, g.y_min, g.y_max)
        self.width = 2 * round(self.scene.output.width / 2)
        self.domain_height = max(2, 2 * round(self.width * (g.y_max - g.y_min)
                                              / (g.x_max - g.x_min) / 2))

    def inside(self, xy):
        x0, x1, y0, y1 = self.bbox
        return x0 < xy[0] < x1 and y0 < xy[1] < y1

    def colour(self, image, xy):
        x0, x1, y0, y1 = self.bbox
        col = int((xy[0] - x0) / (x1 - x0) * self.width)
        row = int((y1 - xy[1]) / (y1 - y0) * self.domain_height)
        patch = image[max(0, row - 1):row + 2, max(0, col - 1):col + 2].reshape(-1, 3)
        return np.median(patch, axis=0)


def close_to(rgb, ref, tol=TOL):
    return bool(np.all(np.abs(np.asarray(rgb, float) - np.asarray(ref, float)) <= tol))


def species_rgb(k):
    return render.SPECIES_COLORS[k % len(render.SPECIES_COLORS)]


def assert_no_stray_files(folder):
    assert sorted(os.listdir(folder)) == [], f"left in the working folder: {os.listdir(folder)}"


# ------------------------------------------------------------------ hourglass24

def video_run(tmp_path_factory, name, scene, *args, scene_text=None):
    """Run ``scene`` with ``--video`` from an empty working folder; return (work,
    out, completed process). With ``scene_text`` the scene file is written first."""
    needs_vulkan()
    base = tmp_path_factory.mktemp(name)
    work, out = base / "work", base / "out"
    work.mkdir()
    if scene_text is not None:
        scene = base / scene
        scene.write_text(scene_text)
    proc = run_cli(scene, out, work, "--video", *args)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return work, out, proc


@pytest.fixture(scope="module")
def hourglass_run(tmp_path_factory):
    return video_run(tmp_path_factory, "hourglass", HOURGLASS, "--set", "run.t_end=10",
                     "--set", "output.frames=25")


def test_hourglass_video_is_h264_yuv420p_with_the_scene_frames(hourglass_run):
    work, out, proc = hourglass_run
    path = out / "video.mp4"
    assert path.is_file()
    assert not list(out.glob("*.part*"))
    pm = PixelMap(out)
    meta, frames = read_video(path)
    assert meta["codec"] == "h264"
    assert meta["pix_fmt"].startswith("yuv420p")
    assert meta["fps"] == pytest.approx(pm.scene.output.fps)
    assert len(frames) == pm.scene.output.frames == 25
    assert frames[0].shape[1] == pm.width and frames[0].shape[0] > pm.domain_height
    line = stream_line(path)
    assert "h264" in line and "yuv420p" in line

    # The domain (not only the strip's clock) changed between first and last frame.
    first, last = (f[:pm.domain_height].astype(int) for f in (frames[0], frames[-1]))
    changed = np.abs(first - last).max(axis=2) > 60
    assert changed.sum() > 200

    summary = json.loads((out / "summary.json").read_text())
    video = summary["video"]
    assert video["file"] == "video.mp4" and video["frames"] == 25 and video["error"] is None
    lo, hi = video["pressure_range"]
    assert 100.0 <= lo < hi <= 200.0                  # p_out = 100, p_in = 200
    assert video["render_seconds"] > 0
    assert video["render_frames_per_second"] == pytest.approx(25 / video["render_seconds"])
    assert video["render_share_of_wall_time"] == pytest.approx(
        video["render_seconds"] / summary["wall_time_s"])
    assert 0 < video["render_share_of_wall_time"] < 1
    assert_no_stray_files(work)


def test_hourglass_last_frame_draws_the_final_state(hourglass_run):
    _, out, _ = hourglass_run
    pm = PixelMap(out)
    final = final_of(out, pm.scene.output.video_realization)
    _, frames = read_video(out / "video.mp4")
    last = frames[-1]
    wall = render.WALL_GREY
    checked = 0
    for x, alive, sp in zip(final["x"], final["alive"], final["species"]):
        if not alive or not pm.inside(x):
            continue
        rgb = pm.colour(last, x)
        assert close_to(rgb, species_rgb(sp)), (x, sp, rgb)
        assert not close_to(rgb, wall)
        checked += 1
    assert checked >= 10
    # And where there is no particle, fluid: the centre of the outlet channel
    # (x = 38, y = 0) is neither a particle colour nor a wall.
    rgb = pm.colour(last, (38.0, 0.0))
    if not any(alive and np.hypot(x[0] - 38.0, x[1]) < 1.0
               for x, alive in zip(final["x"], final["alive"])):
        assert not any(close_to(rgb, species_rgb(k)) for k in range(3))
        assert not close_to(rgb, wall)


# ------------------------------------------------------------------ squares

SQUARES = """
name = "squares10"
[run]
t_end = 8.0
seed = 3
[fluid]
viscosity = 1.0
gap = 1.6
bc = "pressure"
p_in = 200.0
p_out = 100.0
update_interval = 50
[geometry]
kind = "hourglass"
length = 40.0
width = 10.0
neck_width = 2.4
neck_x = 25.0
taper_length = 8.0
[[particles]]
name = "sq"
shape = "square"
side = 1.0
count = 10
density = 1.0
friction = 0.4
restitution = 0.5
[feed]
mode = "none"
[clog]
window = 6.0
[output]
frames = 12
width = 1920
"""


def final_of(out, r):
    """Realization ``r``'s final state in the run folder ``out`` (final_state.npz)."""
    with np.load(out / "final_state.npz") as f:
        state = {k: f[k][r] for k in ("x", "theta", "alive")}
        state["species"] = f["species"]
    return state


@pytest.fixture(scope="module")
def squares_run(tmp_path_factory):
    return video_run(tmp_path_factory, "squares", "squares10.toml", scene_text=SQUARES)


def test_squares_are_drawn_turned_by_their_theta(squares_run):
    work, out, _ = squares_run
    pm = PixelMap(out)
    final = final_of(out, 0)
    meta, frames = read_video(out / "video.mp4")
    assert len(frames) == 12
    last = frames[-1]
    colour = species_rgb(0)
    side = 1.0                                  # 48 pixels at width 1920
    xs = np.array(final["x"])
    alive = np.array(final["alive"], dtype=bool)

    def corner_point(x, theta):
        # The body corner (s/2, s/2) pulled 15 % towards the centre, turned by theta.
        c, s = np.cos(theta), np.sin(theta)
        q = 0.85 * side / 2
        return np.array([x[0] + c * q - s * q, x[1] + s * q + c * q])

    discriminating = 0
    for i in np.flatnonzero(alive):
        x, theta = xs[i], final["theta"][i]
        if not pm.inside(x):
            continue
        assert close_to(pm.colour(last, x), colour)
        on = corner_point(x, theta)
        assert close_to(pm.colour(last, on), colour), (i, theta)
        # theta + pi/4 puts the point off an edge's midpoint, 0.1 side outside
        # the square; where the particle is drawn unturned (theta ignored) that
        # point and the one above swap roles unless theta is far from k pi/2.
        off = corner_point(x, theta + np.pi / 4)
        phase = theta % (np.pi / 2)
        others = np.flatnonzero(alive & (np.arange(len(xs)) != i))
        clear = np.all(np.hypot(*(xs[others] - off).T) > side / np.sqrt(2) + 0.05)
        if 0.3 < phase < np.pi / 2 - 0.3 and clear:
            assert not close_to(pm.colour(last, off), colour), (i, theta)
            discriminating += 1
    assert discriminating >= 1
    assert_no_stray_files(work)


# ------------------------------------------------------------------ in process

def test_frame_zero_is_the_initial_state_and_the_range_holds_every_frame(tmp_path):
    """The recorder on a Simulation in this process: frame 0 shows the placed
    particles before any step, the colour range is the initial solve's and every
    frame's pressure (nothing clipped), one range for every frame (issue 46), the
    strip is in the scene's units (hourglass24 is dimensionless), and frames land
    at output.frames times from 0 to t_end."""
    needs_vulkan()
    from taichi_hsdem import Simulation
    from taichi_hsdem.render import VideoRecorder

    sim = Simulation(load_scene(str(HOURGLASS), ["run.t_end=0.5", "output.frames=4",
                                                 "output.width=480"]))
    initial = sim.state()
    p0 = sim.pressure()[0]
    rec = VideoRecorder(sim, tmp_path / "video.mp4")
    finite = p0[np.isfinite(p0)]
    assert rec.pressure_range == (finite.min(), finite.max())
    assert (rec.renderer.time_unit, rec.renderer.pressure_unit) == ("", "dimensionless")
    assert rec.frame_times == pytest.approx([0.0, 0.5 / 3, 1.0 / 3, 0.5])
    seen = []
    extremes = []
    ranges = []
    draw = rec.renderer.draw

    def drawing(*args, **kwargs):
        ranges.append(rec.renderer.pressure_range)
        return draw(*args, **kwargs)
    rec.renderer.draw = drawing

    def on_frame(s):
        seen.append(s.t)
        rec(s)
        p = s.pressure()[0]
        extremes.append((p[np.isfinite(p)].min(), p[np.isfinite(p)].max()))

    result = sim.run(on_frame=on_frame, frame_times=rec.frame_times)
    rec.close(keep=True)
    assert rec.error is None and rec.frames == 4
    assert seen[0] == 0.0 and seen[-1] == pytest.approx(0.5, abs=sim.dt)
    # one range, the initial solve's and every frame's extremes, for every frame
    whole = (min([finite.min()] + [lo for lo, _ in extremes]),
             max([finite.max()] + [hi for _, hi in extremes]))
    assert rec.pressure_range == whole and ranges == [whole] * 4
    assert (tmp_path / "video.mp4").is_file()
    assert not (tmp_path / "video.mp4.part.mp4").exists()

    _, frames = read_video(tmp_path / "video.mp4")
    assert len(frames) == 4
    r = rec.renderer
    for frame, state in ((frames[0], initial), (frames[-1], result.final)):
        for x, alive, sp in zip(state["x"][0], state["alive"][0], state["species"]):
            if alive:
                col, row = r.world_to_pixel(x)[0]
                rgb = np.median(frame[int(row) - 1:int(row) + 2,
                                      int(col) - 1:int(col) + 2].reshape(-1, 3), axis=0)
                assert close_to(rgb, species_rgb(sp)), (x, sp, rgb)
    summary = rec.summary(result.summary["wall_time_s"])
    assert summary["frames"] == 4 and summary["pressure_range"] == list(rec.pressure_range)


def test_the_video_ends_at_the_first_frame_after_the_realization_stopped(tmp_path):
    """A neck narrower than every particle clogs the hourglass (about t = 14 of
    20, particles as fixed obstacles): the frames after the stop would repeat the
    final state, so the video ends with the first frame drawn once the realization
    stopped, and that frame shows the final state."""
    needs_vulkan()
    from taichi_hsdem import Simulation
    from taichi_hsdem.render import VideoRecorder

    sim = Simulation(load_scene(str(HOURGLASS), [
        "run.t_end=20", "clog.window=0.5", "geometry.neck_width=0.8",
        "output.frames=11", "output.width=480", "fluid.particle_flux=false"]))
    rec = VideoRecorder(sim, tmp_path / "video.mp4")
    result = sim.run(on_frame=rec, frame_times=rec.frame_times)
    rec.close(keep=True)
    res = sim.results[0]
    assert res.clogged and res.t_stop < 18.0        # stopped two frames or more early
    # frames every 2: those before the check that stopped it, then the first at or
    # after it (which sees the realization stopped)
    expected = sum(1 for t in rec.frame_times if t < res.t_stop - 0.5 * sim.dt) + 1
    assert rec.error is None and rec.ended and rec.frames == expected < 11
    _, frames = read_video(tmp_path / "video.mp4")
    assert len(frames) == expected
    r = rec.renderer
    state = result.final
    for x, alive, sp in zip(state["x"][0], state["alive"][0], state["species"]):
        if alive:
            col, row = r.world_to_pixel(x)[0]
            rgb = np.median(frames[-1][int(row) - 1:int(row) + 2,
                                       int(col) - 1:int(col) + 2].reshape(-1, 3), axis=0)
            assert close_to(rgb, species_rgb(sp)), (x, sp, rgb)
    assert rec.summary(result.summary["wall_time_s"])["ended_at_stop"] is True


def test_the_colour_scale_is_the_whole_runs_and_never_widens(tmp_path):
    """Issue 46, item 12: under a flow-rate inlet the pressure climbs as the disks
    fill the micromodel (the pump's drop 4.5 Pa at t = 0, higher by t = 0.3 s);
    every frame is drawn on one range that holds the last frame's pressure, with
    the unit (Pa) and the same labels in every frame's strip, and the spool of
    frames is gone after close."""
    needs_vulkan()
    from taichi_hsdem import Simulation
    from taichi_hsdem.render import VideoRecorder

    sim = Simulation(load_scene(str(REPO / "scenes" / "micromodel.toml"), [
        "run.t_end=0.3", "run.realizations=1", "output.frames=4", "output.width=480"]))
    rec = VideoRecorder(sim, tmp_path / "video.mp4")
    ranges, highs = [], []
    draw = rec.renderer.draw

    def drawing(*args, **kwargs):
        ranges.append(rec.renderer.pressure_range)
        return draw(*args, **kwargs)
    rec.renderer.draw = drawing

    def on_frame(s):
        rec(s)
        p = s.pressure()[0]
        highs.append(p[np.isfinite(p)].max())

    sim.run(on_frame=on_frame, frame_times=rec.frame_times)
    assert highs[-1] > 1.05 * highs[0]                # the pressure climbed
    rec.close(keep=True)
    assert rec.error is None and len(ranges) == 4 and len(set(ranges)) == 1
    lo, hi = ranges[0]
    assert hi == pytest.approx(max(highs)) and rec.pressure_range == (lo, hi)
    assert rec.renderer.pressure_unit == "Pa"
    _, frames = read_video(tmp_path / "video.mp4")
    assert len(frames) == 4
    # the colour bar and its labels (the strip's right third) alike in every frame
    # but for the codec's noise on a few glyph pixels (measured: 4 of 2560, at the
    # low label's top row; a changed label or a moved bar changes dozens)
    strip = [f[rec.renderer.domain_height:, 2 * f.shape[1] // 3:].astype(int) for f in frames]
    assert all((np.abs(s - strip[0]).max(axis=-1) > TOL).sum() <= 8 for s in strip[1:])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["video.mp4"]


# ------------------------------------------------------------------ no Vulkan

def test_without_vulkan_the_run_succeeds_without_a_video(tmp_path):
    work, out, tmp = tmp_path / "work", tmp_path / "out", tmp_path / "tmp"
    work.mkdir()
    tmp.mkdir()
    missing = str(tmp_path / "no_such_icd.json")
    env = _env(VK_ICD_FILENAMES=missing, VK_DRIVER_FILES=missing, TMPDIR=str(tmp))
    proc = run_cli(HOURGLASS, out, work, "--video", "--set", "run.t_end=0.2", env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (out / "summary.json").is_file() and (out / "escapees.csv").is_file()
    assert not (out / "video.mp4").exists()
    assert not list(out.glob("*.mp4"))
    assert "rendering skipped" in proc.stderr
    assert "mesa-vulkan-drivers libvulkan1" in proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["video"]["file"] is None and "libvulkan1" in summary["video"]["skipped"]
    assert_no_stray_files(work)
    assert_no_stray_files(tmp)


# ------------------------------------------------------------------ every width

VANI = REPO / "scenes" / "vani_phi026.toml"


@pytest.mark.parametrize("title, units", [("", "SI"), ("vani_phi026", "SI"),
                                          ("a rather long scene name", "dimensionless")])
def test_the_strip_is_drawn_at_every_accepted_width(title, units):
    """The strip under the frame (time, count, pressure legend) at every even width
    the scene accepts (output.width, 64 to MAX_VIDEO_WIDTH): narrow frames drop the
    legend's unit, then the legend, never the time; no width raises (at 128 the
    legend once overran the left edge: IndexError, and no video)."""
    from taichi_hsdem.limits import MAX_VIDEO_WIDTH
    from taichi_hsdem.render.font import GLYPH_H, even
    from taichi_hsdem.render.frame import _UNIT_LABELS, TEXT_COLOR, Renderer
    widths = sorted({*range(64, 1026, 2), *range(1024, MAX_VIDEO_WIDTH + 1, 256),
                     MAX_VIDEO_WIDTH})
    for width in widths:
        rend = object.__new__(Renderer)          # the strip needs no Taichi fields
        rend.width = even(width)
        rend._scale = max(1, int(round(rend.width / 480)))
        rend.title = title
        rend.time_unit, rend.pressure_unit = _UNIT_LABELS[units]
        strip = np.zeros((even((GLYPH_H + 8) * rend._scale), rend.width, 3), np.uint8)
        for p_range in (None, (-1.234e-5, 98765.4), (100.0, 200.0)):
            rend._draw_strip(strip, 0.01234, 17, p_range)
            text = (strip == TEXT_COLOR).all(axis=2)
            k = rend._scale
            # the time's first glyphs start at the left margin
            assert text[:, 4 * k:10 * k].any(), (width, p_range)


@pytest.mark.parametrize("width", [64, 128])
def test_a_video_is_written_at_the_narrowest_widths(tmp_path, width):
    needs_vulkan()
    out = tmp_path / "out"
    proc = run_cli(VANI, out, tmp_path, "--realizations", "1", "--video", "--set",
                   f"output.width={width}", "--set", "run.t_end=0.05", "--quiet")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr[-3000:]
    meta, frames = read_video(out / "video.mp4")
    assert frames[0].shape[1] == width
    assert json.loads((out / "summary.json").read_text())["video"]["error"] is None


def test_a_video_that_fails_to_render_exits_1_with_one_line(tmp_path):
    """The user asked for the video: its failure is not a silent success; the other
    results are written."""
    needs_vulkan()
    out = tmp_path / "out"
    code = f"""
import sys
from taichi_hsdem.render import frame
def broken(self, *args, **kwargs):
    raise IndexError("drawn off the frame")
frame.Renderer.draw = broken
from taichi_hsdem.cli import main
sys.exit(main([{str(HOURGLASS)!r}, "--out", {str(out)!r}, "--video", "--quiet",
               "--set", "run.t_end=0.2"]))
"""
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert proc.stderr.strip() == ("video not written: rendering failed (IndexError: drawn "
                                   f"off the frame); the other results were written to {out}")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "complete" and summary["video"]["file"] is None
    assert not (out / "video.mp4").exists() and not list(out.glob("*.part*"))
