"""``python -m taichi_hsdem SCENE.toml``: run a scene, write its results;
``python -m taichi_hsdem --resume DIR``: continue the checkpoint a run left in DIR.

Exit status: 0 success; 2 the scene, the arguments or the output folder are
invalid (one line per problem, no traceback, nothing written); 1 the run failed
(numerical instability, a fluid solve that did not balance, results that could
not be written), with what to change; 130 interrupted (Ctrl-C), 143 stopped by
SIGTERM (``kill``, ``timeout``, Slurm), 129 by SIGHUP (the terminal closed), at any
moment, with one line saying what was kept.

The output folder's rules (:mod:`taichi_hsdem.output`): files of the user's are
never replaced or removed, a folder never mixes two runs, and a failed run leaves
the earlier result as it was. An interrupted run writes its results marked
``"status": "interrupted"`` with the time reached, and a checkpoint.
"""
from __future__ import annotations

import argparse
import atexit
import gc
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

from . import checkpoint, output
from .exits import EXIT_FAILED, EXIT_INVALID, EXIT_OK, Parser, folder_name_problem
from .scene import SceneError, load_scene
from .scene.load import path_length_problem
from .stats.text import mean_phrase
from .stop import Stopped, describe
from .scene.toml import parse_toml

# Keys a resumed run may change: its end and what it writes.
RESUMABLE_KEYS = ("run.t_end", "output.")


def _parser() -> argparse.ArgumentParser:
    p = Parser(prog="python -m taichi_hsdem",
               description="Run a taichi_hsdem scene (LS-DEM + Hele-Shaw clogging simulation).",
               epilog="The studies: python -m taichi_hsdem sweep|calibrate|figures|arches "
                      "--help. 'python -m taichi_hsdem run SCENE.toml ...' is the same as "
                      "without 'run'.")
    p.add_argument("scene", nargs="?", help="scene TOML file (see docs/scene.md)")
    p.add_argument("--resume", metavar="DIR",
                   help="continue the checkpoint in DIR (a run's output folder)")
    p.add_argument("--out", help="output folder (default: the scene's output.dir, runs/<name>/)")
    p.add_argument("--arch", choices=("cpu", "gpu", "auto", "cuda", "vulkan", "metal",
                                      "opengl"),
                   help="Taichi backend (gpu refuses a software driver; naming the backend "
                        "runs on it anyway)")
    p.add_argument("--realizations", type=int, metavar="N", help="number of realizations")
    p.add_argument("--seed", type=int, metavar="S", help="seed of realization 0")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scalar of the scene (repeatable)")
    v = p.add_mutually_exclusive_group()
    v.add_argument("--video", dest="video", action="store_true", default=None,
                   help="write video.mp4")
    v.add_argument("--no-video", dest="video", action="store_false", help="no video")
    p.add_argument("--vtk", action="store_true", default=None,
                   help="write a ParaView series (series.pvd) at the video's frame times")
    p.add_argument("--view", action="store_true",
                   help="live window (needs a display): space pause, n step, s screenshot, Esc close")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


class _Progress:
    """A bar on a terminal, a plain line every ~10 % otherwise, nothing when quiet."""

    def __init__(self, quiet: bool, t0: float, t_end: float):
        self.quiet = quiet
        self.bar = None
        self.t_end = t_end
        self.next_frac = 0.1 * (int(10 * t0 / t_end) + 1) if t_end > 0 else 1.0
        self.wall0 = time.perf_counter()
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=t_end, initial=t0, unit="s(sim)", file=sys.stderr,
                            bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} s [{elapsed}<{remaining}]")

    def __call__(self, t, t_end):
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.update(min(t, t_end) - self.bar.n)
        elif t >= self.next_frac * t_end:
            print(f"t = {t:.4g} / {t_end:.4g} s ({100 * t / t_end:.0f} %), "
                  f"{time.perf_counter() - self.wall0:.1f} s wall", file=sys.stderr, flush=True)
            while self.next_frac * t_end <= t:
                self.next_frac += 0.1

    def close(self):
        if self.bar is not None:
            self.bar.close()


class _SetupClock:
    """The set-up's word: a first line at once (before Taichi loads), then, while a
    phase of the set-up (or the first chunk of steps, where the step kernels
    compile) has run for 5 s or more, a line every 5 s saying which phase and how
    long so far. A thread prints them: Taichi's compiler holds Python's lock at
    times, so a line may come a few seconds late. Nothing when quiet."""

    EVERY = 5.0

    def __init__(self, quiet: bool, first_line: str):
        self.quiet = quiet
        self.t0 = time.perf_counter()
        self.what = "loading"
        self.since = self.t0
        self.write = None           # a progress bar's write, once there is one
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = None
        if not quiet:
            print(first_line, file=sys.stderr, flush=True)
            self._thread = threading.Thread(target=self._beat, name="set-up clock",
                                            daemon=True)
            self._thread.start()

    def phase(self, what: str):
        """The set-up has begun ``what``."""
        with self._lock:
            self.what, self.since = what, time.perf_counter()

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def _beat(self):
        while not self._stop.wait(self.EVERY):
            with self._lock:
                now = time.perf_counter()
                if now - self.since < self.EVERY - 0.05:
                    continue
                line = f"set-up: {self.what} ... ({now - self.t0:.0f} s so far)"
                if self.write is not None:
                    self.write(line)
                else:
                    print(line, file=sys.stderr, flush=True)

    def stop(self, *args):
        """The set-up is over (also usable as the run's first progress call)."""
        if not self._stop.is_set():
            self._stop.set()
            if self._thread is not None:
                self._thread.join()


class _Interrupt:
    """Ctrl-C (SIGINT), ``kill``'s and Slurm's SIGTERM and a closed terminal's SIGHUP,
    handled alike from the first line of :func:`main` to its last.

    During set-up it stops at once (nothing has been written yet); during the run
    the first asks the run to stop at the next chunk of steps (results and a
    checkpoint are kept) and a second stops at once; while the results are being
    written it waits until they all are, so that a folder never holds part of a
    run's files. The exit status is 128 + the first signal's number (130, 143,
    129). The handlers are installed explicitly, so that a run started with SIGINT
    ignored (a background job of a script) still obeys Ctrl-C; SIGHUP ignored (a
    run under ``nohup``) stays ignored. Run as the program (``keep``), the handlers
    stay after :func:`main` returns: a signal while the process winds down (Taichi's
    clean-up) says the outcome was already reached and exits at once."""

    SETUP, RUN, WRITE, DONE = "set-up", "run", "write", "done"
    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self, keep: bool = False):
        self.requested = False
        self.signum = None
        self.phase = self.SETUP
        self.previous = {}
        self.keep = keep
        self.out = None             # the output folder, once known
        self.outcome = None         # main's exit status, once reached (DONE)

    @property
    def code(self) -> int:
        """The exit status of a stop by the first signal received."""
        return 128 + int(self.signum or signal.SIGINT)

    @property
    def what(self) -> str:
        """How the stop reads in a message: "interrupted" (Ctrl-C) or "stopped by
        SIGTERM"."""
        return describe(self.signum)

    def _handler(self, signum, frame):
        if self.signum is None:
            self.signum = signum
        if self.phase == self.DONE:         # main has returned: the process winds down
            if self.outcome == EXIT_OK:
                print(f"{self.what} after the run had ended: its results in {self.out} "
                      "are complete", file=sys.stderr, flush=True)
                os._exit(self.code)
            os._exit(self.outcome if self.outcome is not None else self.code)
        if self.phase == self.SETUP or (self.phase == self.RUN and self.requested):
            raise Stopped(signum)
        self.requested = True

    def _unraisable(self, unraisable):
        """After a stop, Taichi's objects that the stop cut off half-built complain
        from their destructors ("Exception ignored in ArgPack.__del__", with a
        traceback): nothing of ours, and nothing the user can act on. Dropped;
        anything else goes to the previous hook."""
        where = getattr(unraisable.object, "__module__", None) or ""
        if self.signum is not None and where.split(".")[0] == "taichi":
            return
        self._previous_hook(unraisable)

    def __enter__(self):
        self._previous_hook = sys.unraisablehook
        sys.unraisablehook = self._unraisable
        for name in self.SIGNALS:
            sig = getattr(signal, name, None)
            if sig is None:                  # SIGHUP: not on Windows
                continue
            try:
                if sig != signal.SIGINT and signal.getsignal(sig) == signal.SIG_IGN:
                    continue                 # nohup: SIGHUP is meant to be ignored
                self.previous[sig] = signal.signal(sig, self._handler)
            except ValueError:           # not the main thread: signals stay as they are
                break
        return self

    def __exit__(self, *exc):
        if self.keep and exc[0] is None:
            self.phase = self.DONE
            return
        if self.signum is not None:
            gc.collect()            # the half-built objects go now, under our hook
        sys.unraisablehook = self._previous_hook
        for sig, previous in self.previous.items():
            signal.signal(sig, previous if previous is not None else signal.SIG_DFL)
        self.previous = {}

    def __call__(self) -> bool:
        return self.requested

    def start_run(self):
        """Set-up is over: from here a signal asks the run to stop. A signal during
        set-up whose exception a library swallowed (Taichi's decorators catch every
        exception while they inspect the caller) stops here, as set-up."""
        if self.signum is not None:
            raise Stopped(self.signum)
        self.phase = self.RUN


def _say(quiet, msg):
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def _overrides(args) -> list[str]:
    overrides = list(args.set)
    if args.arch is not None:
        overrides.append(f'run.arch="{args.arch}"')
    if args.realizations is not None:
        overrides.append(f"run.realizations={args.realizations}")
    if args.seed is not None:
        overrides.append(f"run.seed={args.seed}")
    if args.video is not None:
        overrides.append(f"output.video={'true' if args.video else 'false'}")
    if args.vtk:
        overrides.append("output.vtk=true")
    given = {text.partition("=")[0].strip(): text for text in args.set}
    for flag, key in (("--arch", "run.arch"), ("--realizations", "run.realizations"),
                      ("--seed", "run.seed"), ("--video/--no-video", "output.video"),
                      ("--vtk", "output.vtk")):
        if key in given and any(o.startswith(f"{key}=") for o in overrides[len(args.set):]):
            raise SceneError(f"--set {given[key]} and {flag} both set {key}: give one")
    return overrides


def output_folder_problem(out: Path, key: str) -> str | None:
    """Why results cannot be written to folder ``out`` (``key`` names where it came
    from: ``--out`` or ``FILE: output.dir``), or None. Creates nothing."""
    too_long = path_length_problem(out)
    if too_long:
        return f"{key}: {too_long}"
    try:
        if os.path.islink(out) and not out.exists():
            return (f"{key}: {out} is a link to {os.readlink(out)}, which does not exist "
                    "(or is a loop of links)")
        if out.exists() and not out.is_dir():
            return f"{key}: {out} is a file, not a folder"
        probe = out
        while not os.path.lexists(probe):
            if probe.parent == probe:
                break
            probe = probe.parent
        if not probe.is_dir():
            return f"{key}: {out} lies under {probe}, which is not a folder"
        if not os.access(probe, os.W_OK | os.X_OK):
            return f"{key}: cannot write in {probe} (permission denied)"
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        return f"{key}: cannot write in {out} ({exc.strerror or exc})"
    locked = output.lock_problem(out)
    if locked:
        return f"{key}: {locked}"
    if output.in_use(out):
        # its checkpoint, not yet in the manifest, is not the user's
        return f"{key}: another run is writing to {out}: wait for it to end, or choose " \
               "another folder"
    foreign = output.foreign_files(out)
    damaged = output.manifest_problem(out) if foreign else None
    if damaged:
        return (f"{key}: {out / output.MANIFEST}, the record of the files runs of "
                f"taichi_hsdem wrote there, is {damaged}; so {', '.join(foreign)} may be "
                "your own files: choose a new or empty folder, or move them (or remove "
                "the record if they are a run's)")
    if foreign:
        return (f"{key}: {out} holds {', '.join(foreign)}, which no run of taichi_hsdem "
                "wrote there and which a run would replace or remove: choose a new or "
                "empty folder, or move them")
    return None


def _load(args) -> tuple:
    """The scene and the checkpoint the arguments ask for (None when not
    resuming); SceneError otherwise."""
    if args.resume is None:
        if args.scene is None:
            raise SceneError("python -m taichi_hsdem: give a scene file, or --resume DIR")
        return load_scene(args.scene, _overrides(args)), None
    if args.scene is not None:
        raise SceneError(f"--resume: give either a scene file ({args.scene}) or --resume "
                         f"{args.resume}, not both")
    problem = folder_name_problem(args.resume)
    if problem:                         # its name is printed in every line after
        raise SceneError(f"--resume: {problem}")
    path = Path(args.resume) / checkpoint.FILE
    home = _home_of(Path(args.resume))
    if output.in_use(home):
        raise SceneError(f"--resume: another run is writing to {home}, and its checkpoint "
                         "changes as it goes: wait for it to end, then --resume")
    try:
        header = checkpoint.read_header(path)
    except checkpoint.CheckpointError as exc:
        raise SceneError(f"--resume: {exc}") from None
    sets = _overrides(args)
    for text in sets:
        key = text.partition("=")[0].strip()
        if not any(key == k or (k.endswith(".") and key.startswith(k))
                   for k in RESUMABLE_KEYS):
            raise SceneError(f"--resume: --set {key}: only run.t_end and the output keys "
                             f"can change when a run is continued")
    try:
        raw = parse_toml(header["scene"])
    except SceneError as exc:
        raise SceneError(f"--resume: {path}: the scene inside is damaged "
                         f"({exc.problems[0]})") from None
    raw.setdefault("output", {})["dir"] = str(_home_of(Path(args.resume)))
    scene = load_scene(raw, sets, label=str(path))
    return scene, path


def _other_scene_problem(folder: Path, scene, path: Path) -> str | None:
    """Why the checkpoint ``path`` (of ``scene``) cannot continue in place in
    ``folder``: it is of another scene than the result a run left there (its
    ``scene.resolved.toml``), or None. A continued run replaces that result, so
    the two must be one run."""
    resolved = folder / "scene.resolved.toml"
    if "scene.resolved.toml" not in output.owned_files(folder) or not resolved.is_file():
        return None
    try:
        theirs = load_scene(parse_toml(resolved.read_text()))
    except (OSError, UnicodeDecodeError, SceneError):
        return None             # nothing to compare with: the run replaces it whole
    difference = checkpoint.scene_difference(scene, theirs, "in the checkpoint",
                                             f"in {resolved}")
    if difference is None:
        return None
    return (f"--resume: {path} is of another scene than the result in {folder} "
            f"({difference}): continue it into another folder with --resume {folder} "
            "--out OTHER, or run the scene again")


def _home_of(folder: Path) -> Path:
    """Where a run continued from ``folder`` publishes: the folder itself, or for
    the staging folder of a run killed hard, the output folder it lies in."""
    if folder.resolve().name.startswith(output.STAGING_PREFIX):
        return folder.resolve().parent
    return folder


def _same_folder(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


#: ``python -m taichi_hsdem COMMAND ...``: the studies' command lines, by module.
COMMANDS = {"sweep": "sweep", "calibrate": "calibrate", "figures": "figures",
            "arches": "arches"}


def _command(argv) -> int | None:
    """Run ``argv`` as a study's command line when it names one; None otherwise."""
    if not argv or argv[0] not in COMMANDS or os.path.exists(argv[0]):
        return None
    import importlib
    try:
        module = importlib.import_module(f".studies.{COMMANDS[argv[0]]}", __package__)
        return module.main(list(argv[1:]), prog=f"python -m taichi_hsdem {argv[0]}")
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"{argv[0]} {describe(signum)}: what finished before is kept (a rerun "
              "into the same folder goes on from there)", file=sys.stderr)
        return 128 + int(signum)
    except Exception as exc:         # MemoryError included: one line, not a traceback
        return _failure(exc, "the study needs more memory than this machine gave; "
                             "use fewer points, realizations or particles")


#: The signals to ignore once the program's last Python code ran (see
#: :func:`_ignore_late_signals`); filled when main runs as the program.
_LATE_SIGNALS: set = set()


def _ignore_late_signals() -> None:
    """The last exit handler (registered when this module loads, before any of
    Taichi's, so run after them): ignore the stopping signals. The interpreter's
    finalization then sets a Python handler's signal back to its default action, and
    one arriving there killed the process silently (exit -2 for a study or run that
    had ended with 0); ignored, it leaves the exit status main chose."""
    for sig in _LATE_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


atexit.register(_ignore_late_signals)


def _after_the_end(command: str, code: int) -> None:
    """Handlers for the process's wind-down once a study's main returned ``code``
    (Taichi's clean-up): a signal then says that the study had ended and exits at
    once, 128 + its number after a success, ``code`` otherwise, instead of dying of
    it silently or with a traceback; past the exit handlers it is ignored
    (:func:`_ignore_late_signals`). SIGHUP ignored (nohup) stays ignored."""
    def handler(signum, frame):
        if code == EXIT_OK:
            print(f"{command} {describe(signum)} after it had ended: what it wrote is "
                  "complete", file=sys.stderr, flush=True)
            os._exit(128 + int(signum))
        os._exit(code)
    for name in _Interrupt.SIGNALS:
        sig = getattr(signal, name, None)
        if sig is not None and (sig == signal.SIGINT
                                or signal.getsignal(sig) != signal.SIG_IGN):
            signal.signal(sig, handler)
            _LATE_SIGNALS.add(sig)


def _failure(exc: Exception, memory_advice: str) -> int:
    """One line and exit 1 for an exception no check caught: out of memory (with
    ``memory_advice``), or a defect of ours (re-raised, for its traceback, when
    TAICHI_HSDEM_DEBUG is set)."""
    if isinstance(exc, MemoryError):
        print(f"out of memory: {memory_advice}", file=sys.stderr)
        return EXIT_FAILED
    if os.environ.get("TAICHI_HSDEM_DEBUG"):
        raise exc
    print(f"internal error ({type(exc).__name__}: {exc}); this is a bug of "
          "taichi_hsdem: please report it with the command (set "
          "TAICHI_HSDEM_DEBUG=1 for the traceback)", file=sys.stderr)
    return EXIT_FAILED


def main(argv=None) -> int:
    """``python -m taichi_hsdem [run] SCENE.toml ...`` or ``python -m taichi_hsdem
    sweep|calibrate|figures|arches ...``; the exit status."""
    explicit = argv is not None
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["run"] and not os.path.exists("run"):
        argv = argv[1:]
    code = _command(argv)
    if code is not None:
        if not explicit:
            _after_the_end(argv[0], code)
        return code
    # Called with no arguments, main is the program (python -m taichi_hsdem): the
    # signal handlers stay while the process winds down, and past the exit handlers
    # the signals are ignored.
    if not explicit:
        _LATE_SIGNALS.update(getattr(signal, name) for name in _Interrupt.SIGNALS
                             if hasattr(signal, name))
    with _Interrupt(keep=not explicit) as interrupt:
        code = _guarded(argv, interrupt)
        if code == EXIT_OK and interrupt.requested:
            # a signal after the last check of the run, when all was written
            print(f"{interrupt.what} after the run had ended: its results in "
                  f"{interrupt.out} are complete", file=sys.stderr)
            code = interrupt.code
        interrupt.outcome = code
        return code


def _guarded(argv, interrupt) -> int:
    """:func:`_main` with every way out turned into an exit status and one line."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # --help (0) or a bad argument (2)
        return exc.code
    try:
        return _main(args, interrupt)
    except KeyboardInterrupt:
        print(f"{interrupt.what} during set-up: nothing was written", file=sys.stderr)
        return interrupt.code
    except Exception as exc:         # a defect of ours: one line, not a traceback
        if interrupt.signum is not None and interrupt.phase == interrupt.SETUP:
            # the stop, raised inside a library's C code, came out as its error
            print(f"{interrupt.what} during set-up: nothing was written", file=sys.stderr)
            return interrupt.code
        return _failure(exc, "the scene needs more memory than this machine gave; use "
                             "fewer realizations, particles, nodes or a coarser "
                             "fluid.cell_size")


def _main(args, interrupt) -> int:
    try:
        scene, resume_from = _load(args)
    except SceneError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    problem = None if args.out is None else folder_name_problem(args.out)
    if problem:
        print(f"--out: {problem}", file=sys.stderr)
        return EXIT_INVALID
    out = Path(args.out) if args.out else Path(scene.output.dir)
    where = "--out" if args.out else ("--resume" if resume_from else
                                      f"{scene.source}: output.dir")
    resume_dir = None if resume_from is None else resume_from.parent
    continuing = resume_dir is not None and _same_folder(out, resume_dir)
    interrupt.out = out
    problem = output_folder_problem(out, where)
    if problem is None and continuing:
        problem = _other_scene_problem(out, scene, resume_from)
    if problem:
        print(problem, file=sys.stderr)
        return EXIT_INVALID
    try:
        with output.Staging(out, continuing=continuing) as staged:
            code = _run(args, scene, resume_from, staged, interrupt)
    except output.FolderInUse as exc:
        print(f"{where}: {exc}: wait for it to end, or choose another folder",
              file=sys.stderr)
        return EXIT_INVALID
    except output.FolderUnusable as exc:
        print(f"{where}: {exc}", file=sys.stderr)
        return EXIT_INVALID
    if (code in (EXIT_OK, interrupt.code) and resume_dir is not None and not continuing
            and resume_dir.resolve().name.startswith(output.STAGING_PREFIX)):
        # the staging folder of a run killed hard, now published: it is done
        shutil.rmtree(resume_dir, ignore_errors=True)
    return code


def _run(args, scene, resume_from, staged, interrupt) -> int:
    """Build, run and publish into ``staged``; the exit status."""
    clock = _SetupClock(args.quiet, f"{scene.name}: setting up"
                        + (f" to continue {resume_from.parent}" if resume_from else "")
                        + " (Taichi compiles its kernels on a first run: 10-30 s; "
                          "later runs read them from its cache) ...")
    try:
        return _run_timed(args, scene, resume_from, staged, interrupt, clock)
    finally:
        clock.stop()


def _run_timed(args, scene, resume_from, staged, interrupt, clock) -> int:
    out = staged.out
    # The simulator loads Taichi (about a second): only once the scene is valid.
    clock.phase("loading Taichi")
    from . import backend
    from .runner import RunFailed, build, execute, unstable_hint
    try:
        sim = build(scene, place_particles=resume_from is None, on_phase=clock.phase)
        if resume_from is not None:
            clock.phase("reading the checkpoint, first pressure solve")
            checkpoint.restore(sim, resume_from)
    except RunFailed as exc:
        for line in exc.lines:
            print(line, file=sys.stderr)
        return EXIT_INVALID
    except checkpoint.CheckpointError as exc:
        print(f"--resume: {exc}", file=sys.stderr)
        return EXIT_INVALID
    sc = sim.scene
    why = backend.auto_reason()
    _say(args.quiet, f"{sc.name}: {sim.R} realization(s) x {sim.N} particles, "
         f"dt = {sim.dt:.3g} s, "
         f"{sim.model.species[0].shape.name if len(sim.model.species) == 1 else 'mixed'} "
         f"({'disk' if sim.model.all_disks else 'level-set'} contacts), arch {sim.arch}"
         + (f" ({why})" if why else "")
         + (f", resumed at t = {sim.t:.4g} s" if resume_from else "")
         + f", set up in {clock.elapsed():.1f} s -> {out}")
    if staged.checkpoint_path.parent != out:
        _say(args.quiet, f"{out} holds an earlier result, kept until this run ends; "
             f"this run's checkpoints wait in {staged.tmp} (--resume it if the run is "
             "killed)")
    pictures = output.Pictures(sim, staged, view=args.view, quiet=args.quiet,
                               resume_dir=None if resume_from is None else resume_from.parent)
    progress = _Progress(args.quiet, sim.t, sc.run.t_end)
    saver = output.CheckpointClock(sim, staged, sc.output.checkpoint_every)
    if progress.bar is not None:
        clock.write = lambda line: progress.bar.write(line, file=sys.stderr)
    clock.phase("compiling the step kernels (the first chunk of steps)")

    def first_progress(t, t_end):
        clock.stop()
        progress(t, t_end)
    interrupt.start_run()
    try:
        result = execute(sim, progress=first_progress, on_frame=pictures.on_frame,
                         frame_times=pictures.frame_times, stop=interrupt,
                         on_chunk=saver)
    except RunFailed as exc:
        interrupt.phase = interrupt.WRITE
        progress.close()
        pictures.discard()
        for line in exc.lines:
            print(f"run failed: {line}", file=sys.stderr)
        return EXIT_FAILED
    except OSError as exc:      # a checkpoint or a ParaView frame could not be written
        interrupt.phase = interrupt.WRITE
        progress.close()
        pictures.discard()
        print(f"run failed: could not write to {out} ({exc.strerror or exc}); this run's "
              "results were not written, the folder's earlier ones are as they were",
              file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:   # a second signal: stop now, keep nothing new
        interrupt.phase = interrupt.WRITE
        progress.close()
        pictures.discard()
        print(f"{interrupt.what} twice: stopped at once; the output folder's results are "
              "as they were", file=sys.stderr)
        return interrupt.code
    interrupt.phase = interrupt.WRITE
    progress.close()
    s = result.summary
    if why:
        s.setdefault("auto", {})["run.arch"] = why
    bad = [(k, r) for k, r in enumerate(s["realizations"]) if r["status"] == "unstable"]
    for k, r in bad:
        print(f"realization {k} (seed {r['seed']}) went unstable at t = {r['t_stop']:.4g} s: "
              f"{r['reason']}", file=sys.stderr)
    if bad:
        s["status"] = "failed"
        if output.holds_result(out):
            pictures.discard()
            print(f"{unstable_hint(sc)}; this run's results were not written: the earlier "
                  f"result in {out} is kept as it was", file=sys.stderr)
            return EXIT_FAILED
    try:
        pictures.finish(result)
        saver.save(staged.path(checkpoint.FILE))     # the end state: --resume extends it
        written = staged.publish(result, pictures.files() + [checkpoint.FILE])
    except OSError as exc:
        print(f"could not write the results to {out}: {exc.strerror or exc}; none of "
              "them was kept", file=sys.stderr)
        return EXIT_FAILED
    if pictures.failed:         # the user asked for it: not a silent success
        print(f"{pictures.failed}; the other results were written to {out}",
              file=sys.stderr)
    if bad:
        print(f"the unstable realizations' results were not written (status \"failed\" "
              f"in {out / 'summary.json'}); {unstable_hint(sc)}", file=sys.stderr)
        return EXIT_FAILED
    if sim.interrupted:
        print(f"{interrupt.what} at t = {sim.t:.4g} of {sc.run.t_end:.4g} s: kept "
              f"{', '.join(written)} in {out} (status \"interrupted\"); continue with "
              f"python -m taichi_hsdem --resume {out}", file=sys.stderr)
        return interrupt.code
    if interrupt.requested:
        print(f"{interrupt.what} while the results were written: all of them were "
              f"written to {out}", file=sys.stderr)
        return interrupt.code
    clogged = sum(1 for r in s["realizations"] if r["clogged"])
    stats = s["statistics"] or {}
    mean = stats.get("mean_escapees_note") or (
        f"{mean_phrase(s['mean_escapees'], s['mean_escapees_ci'])} (censoring-aware)")
    _say(args.quiet, f"done in {s['wall_time_s']:.1f} s: {s['steps']} steps, {mean}, "
         f"{clogged}/{len(s['realizations'])} clogged, "
         f"{stats.get('n_never_clogged', 0)} never clogged -> {out}")
    return EXIT_FAILED if pictures.failed else EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
