"""The README gallery: one frame of every shipped scene, drawn by the video's renderer.

    python tools/gallery.py [--out docs/gallery] [--scenes hourglass24 vani_phi026 ...]

Each scene is run (one realization, its own seed) to the time given below and its
state drawn as the video would show it: walls, the pressure field, the particles
with their true shapes, the time and the escapee count. Writes ``<scene>.png`` per
scene into ``--out`` (default ``docs/gallery``). Needs off-screen rendering (the
software Vulkan driver ``tools/setup.sh`` installs).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
# Simulated time at which each scene is drawn: far enough for the stream to form.
TIMES = {"hourglass24": 25.0, "vani_phi026": 1.0, "squares": 0.6, "polygons": 0.6,
         "concave": 0.6}


class _LastFrame:
    """A stand-in for the live viewer: keeps the recorder's last frame."""

    def __init__(self):
        self.frame = None

    def show(self, sim, frame):
        self.frame = frame

    def close(self):
        pass


def draw(name: str, out: pathlib.Path) -> pathlib.Path:
    import imageio.v3 as iio

    from taichi_hsdem import Simulation, load_scene
    from taichi_hsdem.render import VideoRecorder
    t = TIMES.get(name, 0.5)
    sim = Simulation(load_scene(ROOT / "scenes" / f"{name}.toml",
                                [f"run.t_end={t}", "run.realizations=1", "output.frames=2",
                                 "run.stop_at_clog=false", "fluid.workers=1"]))
    keep = _LastFrame()
    recorder = VideoRecorder(sim, None, viewer=keep)
    sim.run(on_frame=recorder, frame_times=recorder.frame_times)
    recorder.close()
    if keep.frame is None:
        raise RuntimeError(f"{name}: no frame was drawn ({recorder.error})")
    path = out / f"{name}.png"
    iio.imwrite(path, keep.frame)
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python tools/gallery.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=str(ROOT / "docs" / "gallery"), help="folder for the PNGs")
    p.add_argument("--scenes", nargs="+", help="scene names (default: every scenes/*.toml)")
    args = p.parse_args(argv)
    from taichi_hsdem.render import vulkan_status
    ok, why = vulkan_status()
    if not ok:
        print(f"tools/gallery.py: {why}", file=sys.stderr)
        return 1
    names = args.scenes or sorted(f.stem for f in (ROOT / "scenes").glob("*.toml"))
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        print(draw(name, out), file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
