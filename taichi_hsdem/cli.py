"""``python -m taichi_hsdem SCENE.toml``: run a scene, write its results.

Exit status: 0 success; 2 the scene or the arguments are invalid (one line per
problem, no traceback); 1 the run failed (numerical instability, a fluid solve
that did not balance), with what to change.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

EXIT_OK, EXIT_FAILED, EXIT_INVALID = 0, 1, 2


class Parser(argparse.ArgumentParser):
    """argparse with the project's exit status for bad arguments (2, one line)."""

    def error(self, message):
        self.print_usage(sys.stderr)
        print(f"{self.prog}: {message}", file=sys.stderr)
        sys.exit(EXIT_INVALID)


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="python -m taichi_hsdem",
                description="Run a taichi_hsdem scene (LS-DEM + Hele-Shaw clogging simulation).")
    p.add_argument("scene", help="scene TOML file (see docs/scene.md)")
    p.add_argument("--out", help="output folder (default: the scene's output.dir, runs/<name>/)")
    p.add_argument("--arch", choices=("cpu", "gpu", "auto"), help="Taichi backend")
    p.add_argument("--realizations", type=int, metavar="N", help="number of realizations")
    p.add_argument("--seed", type=int, metavar="S", help="seed of realization 0")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scalar of the scene (repeatable)")
    v = p.add_mutually_exclusive_group()
    v.add_argument("--video", dest="video", action="store_true", default=None,
                   help="write video.mp4")
    v.add_argument("--no-video", dest="video", action="store_false", help="no video")
    p.add_argument("--view", action="store_true",
                   help="live window (needs a display): space pause, n step, s screenshot, Esc close")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


class _Progress:
    """A bar on a terminal, a plain line every ~10 % otherwise, nothing when quiet."""

    def __init__(self, quiet: bool, t_end: float):
        self.quiet = quiet
        self.bar = None
        self.next_frac = 0.1
        self.t_end = t_end
        self.t0 = time.perf_counter()
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=t_end, unit="s(sim)", file=sys.stderr,
                            bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} s [{elapsed}<{remaining}]")

    def __call__(self, t, t_end):
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.update(min(t, t_end) - self.bar.n)
        elif t >= self.next_frac * t_end:
            print(f"t = {t:.4g} / {t_end:.4g} s ({100 * t / t_end:.0f} %), "
                  f"{time.perf_counter() - self.t0:.1f} s wall", file=sys.stderr, flush=True)
            while self.next_frac * t_end <= t:
                self.next_frac += 0.1

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _say(quiet, msg):
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # --help (0) or a bad argument (2)
        return exc.code
    from .scene import SceneError, load_scene
    overrides = list(args.set)
    if args.arch is not None:
        overrides.append(f'run.arch="{args.arch}"')
    if args.realizations is not None:
        overrides.append(f"run.realizations={args.realizations}")
    if args.seed is not None:
        overrides.append(f"run.seed={args.seed}")
    if args.video is not None:
        overrides.append(f"output.video={'true' if args.video else 'false'}")
    try:
        scene = load_scene(args.scene, overrides)
    except SceneError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    from .output import write_resolved_scene, write_series, write_summary
    from .runner import UNSTABLE_HINT, RunFailed, build, execute
    out = Path(args.out) if args.out else Path(scene.output.dir)
    try:
        sim = build(scene)
    except RunFailed as exc:
        for line in exc.lines:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    out.mkdir(parents=True, exist_ok=True)
    write_resolved_scene(sim.scene, out, sim.model.notes)
    _say(args.quiet, f"{scene.name}: {sim.R} realization(s) x {sim.N} particles, "
         f"dt = {sim.dt:.3g} s, {sim.model.species[0].shape.name if len(sim.model.species) == 1 else 'mixed'} "
         f"({'disk' if sim.model.all_disks else 'level-set'} contacts), arch {sim.arch} -> {out}")
    recorder = None
    frame_times = None
    video_skipped = None
    viewer = None
    if args.view:
        from .render.viewer import LiveViewer, display_available
        ok, why = display_available()
        if ok:
            viewer = LiveViewer(out, title=f"taichi_hsdem: {sim.scene.name}")
        else:
            print(f"--view skipped: {why}", file=sys.stderr)
    if sim.scene.output.video or viewer is not None:
        from .render import VideoRecorder, vulkan_status
        ok, why = vulkan_status()
        if ok:
            recorder = VideoRecorder(sim, out / "video.mp4" if sim.scene.output.video else None,
                                     viewer=viewer)
            frame_times = recorder.frame_times
        else:
            video_skipped = why
            # the user asked for a picture: say so even with --quiet
            print(f"rendering skipped: {why}", file=sys.stderr)
    progress = _Progress(args.quiet, sim.scene.run.t_end)
    try:
        result = execute(sim, progress=progress, on_frame=recorder, frame_times=frame_times)
    except BaseException as exc:        # also Ctrl-C or a bug: leave no half-written video
        progress.close()
        if recorder is not None:
            recorder.close(keep=False)
        if isinstance(exc, RunFailed):
            for line in exc.lines:
                print(f"run failed: {line}", file=sys.stderr)
            return EXIT_FAILED
        raise
    progress.close()
    if recorder is not None:
        recorder.close(keep=True)
        result.summary["video"] = recorder.summary(result.summary["wall_time_s"])
        if recorder.error is not None:
            print(f"video not written: rendering failed ({recorder.error})", file=sys.stderr)
    elif video_skipped is not None:
        result.summary["video"] = {"file": None, "skipped": video_skipped}
    statuses = [r["status"] for r in result.summary["realizations"]]
    write_summary(result.summary, out)
    write_series(result.series, statuses, out)
    bad = [(k, r) for k, r in enumerate(result.summary["realizations"]) if r["status"] != "ok"]
    if bad:
        for k, r in bad:
            print(f"realization {k} (seed {r['seed']}) went unstable at t = {r['t_stop']:.4g} s: "
                  f"{r['reason']}", file=sys.stderr)
        print(f"its results were not written; {UNSTABLE_HINT}", file=sys.stderr)
        return EXIT_FAILED
    s = result.summary
    clogged = sum(1 for r in s["realizations"] if r["clogged"])
    _say(args.quiet, f"done in {s['wall_time_s']:.1f} s: {s['steps']} steps, mean escapees "
         f"{s['mean_escapees']:.3g}, {clogged}/{len(s['realizations'])} clogged -> {out}")
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
