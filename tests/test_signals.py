"""SIGTERM (``kill``, ``timeout``, Slurm) and SIGHUP (the terminal closed) are obeyed
as Ctrl-C is: during the run the results and a checkpoint are kept; during set-up
nothing is written; while the results are written they all are; after the run's
end the line says the result is complete. Each exits 128 + the signal's number
with one line, and leaves no lock and no staging folder behind."""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from taichi_hsdem import checkpoint, output
from taichi_hsdem.cli import _Interrupt, main
from taichi_hsdem.scene.keys import OutputConfig

ROOT = Path(__file__).resolve().parents[1]
VANI = str(ROOT / "scenes" / "vani_phi026.toml")
HOURGLASS = str(ROOT / "scenes" / "hourglass24.toml")
# one realization that runs on (no clog ends it early) for about 15 s of wall time
LONG = ["--realizations", "1", "--set", "fluid.workers=1", "--set", "run.t_end=0.6",
        "--set", "run.stop_at_clog=false", "--set", "output.series_interval=0.004"]
CODES = {signal.SIGTERM: 143, signal.SIGHUP: 129}


def _leftovers(out: Path) -> list[str]:
    return [p.name for p in out.iterdir()
            if p.name.startswith((output.STAGING_PREFIX, output.LOCK))]


def _python(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter (a signal our handler misses would kill
    pytest itself)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)


def _build_swallowing(name: str) -> str:
    """Code that makes runner.build raise signal ``name`` in a ``try`` whose bare
    ``except`` swallows the stop, as Taichi's decorators do while they inspect
    their caller."""
    return textwrap.dedent(f"""
        import os, signal, time
        from taichi_hsdem import runner
        build = runner.build
        def build_swallowing_a_signal(*args, **kwargs):
            try:                                  # as taichi.lang.kernel_impl does
                os.kill(os.getpid(), signal.{name})
                time.sleep(5)
            except:
                pass
            return build(*args, **kwargs)
        runner.build = build_swallowing_a_signal
        """)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["TERM", "HUP"])
def test_a_signal_during_the_run_keeps_results_and_a_checkpoint(tmp_path, sig):
    out = tmp_path / "run"
    log = tmp_path / "stderr.txt"
    cmd = [sys.executable, "-m", "taichi_hsdem", VANI, *LONG, "--out", str(out)]
    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd, cwd=tmp_path, stderr=fh)
        deadline = time.time() + 120
        while time.time() < deadline and "t = " not in log.read_text():
            time.sleep(0.1)
        proc.send_signal(sig)
        proc.wait(timeout=120)
    err = log.read_text()
    name = signal.Signals(sig).name
    assert proc.returncode == CODES[sig], err
    assert "Traceback" not in err
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"stopped by {name} at t = ") and "--resume" in line, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["t_reached"] < 0.6
    header = checkpoint.read_header(out / checkpoint.FILE)
    assert header["host"]["t"] == pytest.approx(summary["t_reached"], abs=1e-9)
    assert _leftovers(out) == []
    if sig == signal.SIGTERM:      # the checkpoint goes on to the end
        assert main(["--resume", str(out), "--quiet"]) == 0
        assert json.loads((out / "summary.json").read_text())["status"] == "complete"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["TERM", "HUP"])
def test_a_signal_during_set_up_writes_nothing(tmp_path, sig):
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "taichi_hsdem", HOURGLASS, "--out", str(out),
           "--set", "run.t_end=50", "--set", "run.stop_at_clog=false", "--quiet"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not (out.is_dir() and any(
            p.name.startswith(output.STAGING_PREFIX) for p in out.iterdir())):
        time.sleep(0.01)
    proc.send_signal(sig)
    err = proc.communicate(timeout=120)[1]
    name = signal.Signals(sig).name
    assert proc.returncode == CODES[sig], err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    if "set-up" in err:
        assert err.strip() == f"stopped by {name} during set-up: nothing was written"
        assert not out.exists()
    else:   # set-up had just ended: the run's first chunk kept
        assert f"stopped by {name} at t =" in err
        assert _leftovers(out) == []


def test_sigterm_while_the_results_are_written_lets_them_all_be_written(tmp_path):
    out = tmp_path / "o"
    proc = _python(f"""
        import os, signal, sys
        from taichi_hsdem import output
        from taichi_hsdem.cli import main
        publish = output.Staging.publish
        def term_then_publish(self, *args, **kwargs):
            os.kill(os.getpid(), signal.SIGTERM)
            return publish(self, *args, **kwargs)
        output.Staging.publish = term_then_publish
        sys.exit(main([{HOURGLASS!r}, "--out", {str(out)!r}, "--set", "run.t_end=0.2",
                       "--quiet"]))
        """, tmp_path)
    assert proc.returncode == 143, proc.stderr
    assert proc.stderr.strip() == (f"stopped by SIGTERM while the results were written: "
                                   f"all of them were written to {out}")
    assert json.loads((out / "summary.json").read_text())["status"] == "complete"
    manifest = set(json.loads((out / output.MANIFEST).read_text())["files"])
    assert manifest == {p.name for p in out.iterdir() if not p.name.startswith(".")}
    assert _leftovers(out) == []


@pytest.mark.parametrize("when", ["done", "teardown"])
def test_ctrl_c_just_after_done_says_the_result_is_complete(tmp_path, when):
    """Ctrl-C right after "done in" (still in main), or while the process winds
    down after it (Taichi's clean-up): exit 130 and one line saying the result is
    complete."""
    out = tmp_path / "o"
    proc = _python(f"""
        import atexit, os, signal, sys, time
        from taichi_hsdem import cli
        say = cli._say
        def say_then_ctrl_c(quiet, msg):
            say(quiet, msg)
            if msg.startswith("done in") and {when!r} == "done":
                os.kill(os.getpid(), signal.SIGINT)
        cli._say = say_then_ctrl_c
        if {when!r} == "teardown":
            atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(5)))
        sys.argv = ["taichi_hsdem", {HOURGLASS!r}, "--out", {str(out)!r},
                    "--set", "run.t_end=0.2"]
        sys.exit(cli.main())
        """, tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 130, proc.stderr
    assert lines[-2].startswith("done in"), proc.stderr
    assert lines[-1] == f"interrupted after the run had ended: its results in {out} are complete"
    assert json.loads((out / "summary.json").read_text())["status"] == "complete"
    assert _leftovers(out) == []


def test_stale_staging_folders_without_a_checkpoint_are_removed_when_a_run_starts(
        tmp_path, capsys):
    """Staging folders a run killed hard left (empty, or only files cut short) go;
    one holding a checkpoint stays for --resume."""
    out = tmp_path / "o"
    out.mkdir()
    (out / ".incomplete-empty").mkdir()
    (out / ".incomplete-cut").mkdir()
    (out / ".incomplete-cut" / "summary.json.part").write_text("{")
    (out / ".incomplete-kept").mkdir()
    (out / ".incomplete-kept" / checkpoint.FILE).write_bytes(b"not read here")
    assert main([HOURGLASS, "--out", str(out), "--set", "run.t_end=0.2", "--quiet"]) == 0
    assert _leftovers(out) == [".incomplete-kept"]


def test_a_killed_cluster_job_loses_at_most_a_minute():
    assert 0 < OutputConfig().checkpoint_every <= 60


def test_sighup_ignored_by_nohup_stays_ignored_and_the_handlers_are_restored():
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with _Interrupt() as interrupt:
            assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) == interrupt._handler
            assert signal.getsignal(signal.SIGINT) == interrupt._handler
        assert signal.getsignal(signal.SIGTERM) == previous[signal.SIGTERM]
        assert signal.getsignal(signal.SIGINT) == previous[signal.SIGINT]
    finally:
        signal.signal(signal.SIGHUP, previous[signal.SIGHUP])


@pytest.mark.parametrize("stop", ["Stopped", "KeyboardInterrupt"])
def test_a_stop_inside_code_an_extension_evaluates_keeps_the_exit_status(tmp_path, stop):
    """CPython, under ``python -m``, ends with SIGINT (status -2) whatever the program
    returned once a plain KeyboardInterrupt was raised inside code that C evaluates
    (``PyRun_String``: Taichi's set-up does this), even if caught: the cause of runs
    stopped during set-up exiting -2. The signal handlers raise :class:`Stopped`,
    which CPython does not remember; the plain class shows the trap is real."""
    package = tmp_path / "stopper"
    package.mkdir()
    (package / "__main__.py").write_text(textwrap.dedent(f"""
        import ctypes, signal, sys
        from taichi_hsdem.stop import Stopped
        def handler(signum, frame):
            raise {stop}() if {stop!r} == "KeyboardInterrupt" else Stopped(signum)
        signal.signal(signal.SIGTERM, handler)
        run = ctypes.pythonapi.PyRun_String
        run.restype = ctypes.py_object
        run.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.py_object, ctypes.py_object]
        try:
            run(b"import os, signal, time\\nos.kill(os.getpid(), signal.SIGTERM)\\n"
                b"time.sleep(5)", 257, {{}}, {{}})
        except KeyboardInterrupt:
            sys.exit(143)
        sys.exit(1)
        """))
    proc = subprocess.run([sys.executable, "-m", "stopper"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(
                              [str(ROOT), os.environ.get("PYTHONPATH", "")])})
    assert proc.returncode == (143 if stop == "Stopped" else -signal.SIGINT), proc.stderr


def test_sigterm_stops_a_study_with_its_status_and_one_line(tmp_path):
    # Runs that cannot end in the test's time (no stop at the clog, a long t_end): with
    # t_end = 50 and the stop at the clog, a fast machine finished both before the signal.
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text(f'scene = "{Path(HOURGLASS).as_posix()}"\n[common]\n'
                          '"run.t_end" = 5000\n"run.stop_at_clog" = false\n'
                          '[grid]\n"particles.friction" = [0.2, 0.4]\n')
    out = tmp_path / "sweep"
    proc = subprocess.Popen([sys.executable, "-m", "taichi_hsdem", "sweep", str(sweep_file),
                             "--out", str(out), "--quiet"],
                            cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not out.is_dir():
        time.sleep(0.05)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 143, err
    assert err.strip().splitlines() == [
        "sweep stopped by SIGTERM: what finished before is kept (a rerun into the same "
        "folder goes on from there)"], err


def test_a_set_up_signal_a_library_swallows_still_stops_the_run(tmp_path):
    """Taichi's decorators catch every exception (KeyboardInterrupt too) while they
    inspect their caller, so a signal landing there raised nothing: the run must
    still stop before it starts, as during set-up (a run of 50 s went on to its end
    with exit 0 before)."""
    out = tmp_path / "o"
    proc = _python(_build_swallowing("SIGHUP") + textwrap.dedent(f"""
        import sys
        from taichi_hsdem import cli
        sys.argv = ["taichi_hsdem", {HOURGLASS!r}, "--out", {str(out)!r},
                    "--set", "run.t_end=50", "--quiet"]
        sys.exit(cli.main())
        """), tmp_path)
    assert proc.returncode == 129, proc.stderr
    assert proc.stderr.strip() == "stopped by SIGHUP during set-up: nothing was written"
    assert not out.exists()


def test_a_signal_a_library_swallows_in_a_studys_point_still_stops_the_study(tmp_path):
    """The study's signal handler raises where the program is; inside Taichi's
    decorators that raise was swallowed and the point (here one of 5000 time units,
    no stop at the clog) ran on to its end: CI's sweep, signalled during its first
    point's set-up, exited 0. The stop is noted before it is raised, and the run
    raises it again at its next chunk."""
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text(f'scene = "{Path(HOURGLASS).as_posix()}"\n[common]\n'
                          '"run.t_end" = 5000\n"run.stop_at_clog" = false\n'
                          '[grid]\n"particles.friction" = [0.2, 0.4]\n')
    out = tmp_path / "sweep"
    proc = _python(_build_swallowing("SIGTERM") + textwrap.dedent(f"""
        import signal, sys
        from taichi_hsdem import cli, stop
        stop.keep_swallowed_stops()
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, stop.raise_stop)      # as python -m taichi_hsdem does
        sys.exit(cli.main(["sweep", {str(sweep_file)!r}, "--out", {str(out)!r},
                           "--quiet"]))
        """), tmp_path)
    assert proc.returncode == 143, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "sweep stopped by SIGTERM: what finished before is kept (a rerun into the same "
        "folder goes on from there)"], proc.stderr
    assert not list(out.glob("*/summary.json"))      # no point finished


def test_after_a_stop_taichis_half_built_objects_do_not_print_tracebacks(monkeypatch):
    """A stop during set-up can cut a Taichi object off half-built; its destructor
    then prints "Exception ignored in ... __del__" with a traceback (seen in the
    fuzzer: ArgPack). After a stop these are dropped; before one, and for any
    other object, they go to the hook as ever."""
    import gc

    class Half:
        def __del__(self):
            raise AttributeError("'ArgPack' object has no attribute '_ArgPack__argpack'")
    Half.__del__.__module__ = "taichi.lang.argpack"

    class Ours:
        def __del__(self):
            raise AttributeError("ours")

    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(str(u.exc_value)))
    with _Interrupt():
        Half()
        gc.collect()
    assert seen == ["'ArgPack' object has no attribute '_ArgPack__argpack'"]  # no stop
    seen.clear()
    with _Interrupt() as interrupt:
        interrupt.signum = signal.SIGTERM
        Half()
        Ours()
        gc.collect()
    assert seen == ["ours"]
    assert sys.unraisablehook != interrupt._unraisable            # restored


def test_the_package_loads_nothing_heavy_before_the_handlers(tmp_path):
    """``python -m taichi_hsdem`` imports the package before its ``__main__`` installs
    the signal handlers: that import must not load numpy or Taichi (it did, through
    the scene, a few tenths of a second in which a signal gave a traceback)."""
    res = _python("""
        import sys, time
        t0 = time.perf_counter()
        import taichi_hsdem
        dt = time.perf_counter() - t0
        heavy = sorted(m for m in ("numpy", "taichi", "scipy") if m in sys.modules)
        print(heavy, dt)
        assert taichi_hsdem.Scene.__name__ == "Scene"     # still there, on first use
        assert "numpy" in sys.modules
    """, tmp_path)
    assert res.returncode == 0, res.stderr
    heavy, dt = res.stdout.rsplit("]", 1)
    assert heavy == "[", res.stdout


def test_a_signal_while_the_modules_load_says_one_line(tmp_path):
    """SIGTERM sent as Taichi starts to load (from an import hook, so at a known
    moment): noted, and answered once the import has finished, with one line and
    143; raised inside a C extension's initialisation it would have come out as
    that library's ImportError."""
    res = _python(f"""
        import os, runpy, signal, sys
        class Hook:
            def find_spec(self, name, path=None, target=None):
                if name == "taichi":
                    sys.meta_path.remove(self)
                    os.kill(os.getpid(), signal.SIGTERM)
                return None
        sys.meta_path.insert(0, Hook())
        sys.argv = ["taichi_hsdem", {HOURGLASS!r}, "--out", "o", "--quiet"]
        runpy.run_module("taichi_hsdem", run_name="__main__")
    """, tmp_path)
    assert res.returncode == 143, res.stderr
    assert res.stderr.strip() == "stopped by SIGTERM during set-up: nothing was written"
    assert not (tmp_path / "o").exists()


def test_a_stop_that_a_library_turned_into_its_own_error_is_a_stop(monkeypatch, capsys):
    """A signal during set-up raised inside a library's C code comes back as that
    library's error (Taichi's "ImportError: initialization failed"): it is still
    the user's stop (128 + the number, one line), not an internal error."""
    from taichi_hsdem import cli

    def _main(args, interrupt):
        interrupt.signum = signal.SIGTERM
        raise ImportError("initialization failed")

    monkeypatch.setattr(cli, "_main", _main)
    interrupt = _Interrupt()
    assert cli._guarded([HOURGLASS], interrupt) == 143
    assert capsys.readouterr().err.strip() == \
        "stopped by SIGTERM during set-up: nothing was written"


def test_a_stop_a_destructor_swallows_is_kept_quietly_and_raised_again(tmp_path):
    """The fuzzer's SIGTERM to a sweep landed in Taichi's ArgPack.__del__: Python
    printed "Exception ignored in ..." with a traceback and went on, the stop lost.
    Now the hook keeps it, prints nothing, and it is raised again where it can stop
    the program."""
    code = textwrap.dedent("""
        import os, signal, time
        from taichi_hsdem import stop
        stop.keep_swallowed_stops()
        signal.signal(signal.SIGTERM, stop.raise_stop)
        class HalfBuilt:
            def __del__(self):
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(2000):
                    time.sleep(0.001)          # the handler runs in here
        obj = HalfBuilt()
        del obj
        print("swallowed", stop.pending)
        try:
            stop.raise_if_swallowed()
        except stop.Stopped as exc:
            print("raised", exc.signum, stop.pending)
        """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert proc.stdout.splitlines() == [f"swallowed [{int(signal.SIGTERM)}]",
                                        f"raised {int(signal.SIGTERM)} []"], proc.stdout


def test_a_run_raises_a_swallowed_stop_between_its_chunks(monkeypatch):
    from taichi_hsdem import Simulation, load_scene, stop
    sim = Simulation(load_scene(HOURGLASS, ["run.t_end=0.05"]))
    monkeypatch.setattr(stop, "pending", [int(signal.SIGTERM)])
    with pytest.raises(stop.Stopped) as info:
        sim.run()
    assert info.value.signum == signal.SIGTERM and stop.pending == []
