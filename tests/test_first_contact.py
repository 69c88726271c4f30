"""What a researcher meets first (issue 46): ``--arch gpu`` refused on a software
driver with the driver's name and the CPU alternative (``--arch vulkan`` runs there
anyway), and a realization that clogs before any escape has its ``t_clog`` when the
arch formed, held for clog.window from then."""
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from taichi_hsdem import Simulation, load_scene

ROOT = Path(__file__).resolve().parents[1]
VANI = ROOT / "scenes" / "vani_phi026.toml"


def _backend(code: str) -> dict:
    """Run ``code`` (which sets ``out``, a dict) in a fresh process: Taichi takes one
    backend per process, and this one runs on the CPU."""
    proc = subprocess.run(
        [sys.executable, "-c",
         "import json\nfrom taichi_hsdem import backend\nout = {}\n" + code
         + "\nprint('RESULT ' + json.dumps(out))"],
        capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def test_arch_gpu_on_a_software_driver_is_refused_naming_the_driver_and_the_cpu():
    out = _backend(
        "try:\n"
        "    backend.refuse_software_gpu('gpu', 'f64')\n"
        "    out['ok'] = backend.current_arch()\n"
        "except backend.BackendError as exc:\n"
        "    out['error'] = str(exc)\n"
        "out['device'] = backend.device()\n"
        "out['arch'] = backend.current_arch()\n")
    if "ok" in out:
        if out["device"] is None or not backend_software(out["device"]):
            return                          # a real GPU: --arch gpu runs there
        pytest.fail(f"a software driver was taken: {out}")
    error = out["error"]
    if "no usable GPU" in error or "no float64" in error:
        pytest.skip(f"no GPU backend here: {error}")
    assert out["device"] and backend_software(out["device"]), out
    assert "\n" not in error
    assert out["device"] in error and "software driver" in error
    assert "--arch cpu" in error and f"--arch {out['arch']}" in error


def test_the_command_line_refuses_arch_gpu_on_a_software_driver(tmp_path):
    # the whole command: exit 2, one line naming the driver and --arch cpu,
    # nothing written; where the GPU is real or absent, not this test's case
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "taichi_hsdem", str(ROOT / "scenes" /
                           "vani_phi026.toml"), "--arch", "gpu", "--realizations", "1",
                           "--no-video", "--set", "run.t_end=0.01", "--out", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    if "software driver" not in proc.stderr:
        pytest.skip(f"no software GPU driver here (exit {proc.returncode})")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert lines[0].startswith("vani_phi026: setting up (")       # the progress line
    assert len(lines) == 2 and "--arch cpu" in lines[1]            # one problem, one line
    assert not out.exists()


def backend_software(device: str) -> bool:
    from taichi_hsdem import backend
    return backend._is_software(device)


def test_naming_the_backend_runs_on_a_software_driver():
    out = _backend(
        "try:\n"
        "    backend.refuse_software_gpu('vulkan', 'f64')\n"
        "    out['arch'] = backend.init('vulkan', 'f64')\n"
        "    out['device'] = backend.device()\n"
        "except backend.BackendError as exc:\n"
        "    out['error'] = str(exc)\n")
    if "error" in out and "cannot start vulkan" in out["error"]:
        pytest.skip(out["error"])
    assert out.get("arch") == "vulkan", out


def test_cpu_and_auto_pass_the_software_driver_check():
    out = _backend("backend.refuse_software_gpu('auto', 'f64')\n"
                   "backend.refuse_software_gpu('cpu', 'f64')\n"
                   "out['arch'] = backend.current_arch()\n")
    assert out["arch"] is None          # nothing initialised: the check was not needed


def test_a_clog_before_any_escape_counts_its_window_from_when_the_arch_formed():
    """Vani seeds 6 and 7 (clog.window 0.1 s): no disk escapes before an arch forms
    at the neck (the census: 0.796 s and 0.747 s). Seed 7's arch holds: t_clog is
    when the checks first found it static (0.753 s, after the census saw it form),
    and the clog is declared clog.window later (t_stop 0.855 s); counted from t = 0
    the window would have passed already, and t_clog would be t_stop. Seed 6's
    arch broke 0.070 s after it formed (a member escaped): no clog then."""
    window = 0.1
    result = Simulation(load_scene(VANI, ["run.seed=6", "run.realizations=2",
                                          f"clog.window={window}", "run.t_end=0.9"])).run()
    broke, held = result.summary["realizations"]
    formed = {a.realization: a for a in result.arches if a.held}
    assert held["escapees"] == 0 and held["clogged"], held
    assert held["t_stop"] - held["t_clog"] >= window - 1e-9, held
    arch = formed[1]
    assert arch.t_formed <= held["t_clog"] < arch.t_formed + window, (arch, held)
    first = [a for a in result.arches if a.realization == 0][0]
    assert first.failure == "escaped" and first.t_broken - first.t_formed < window, first
    assert not (broke["clogged"] and broke["t_clog"] < first.t_broken), broke


def test_a_sweep_point_where_nothing_clogged_says_a_lower_bound(tmp_path):
    """The sweep's point line and sweep.csv say nothing clogged as the run does
    (stats.estimate_text; issue 46: "- [4.191, -]"): the lower bound, and in the
    table an empty estimate with the bound in its own column."""
    import csv
    from taichi_hsdem.stats import estimate_text, summarize
    from taichi_hsdem.studies import sweep
    esc = [3, 7, 1, 12]
    st = summarize(esc, [False] * 4)
    summary = {"realizations": [{"seed": k, "escapees": s, "clogged": False, "status": "ok"}
                                for k, s in enumerate(esc)],
               "statistics": st, "wall_time_s": 1.0}
    row = sweep._row("base", {}, "ran", summary)
    said = estimate_text(None, None, st["mean_escapees_lower_bound"])
    assert said.startswith("> ") and said.endswith("(nothing clogged; 95 % lower bound)")
    assert sweep.point_text(row) == f"<s> {said}, 0/4 clogged"      # not "<s> = > ..."
    assert st["mean_escapees_note"].endswith(said)          # what the run prints
    sweep._write_table([row], tmp_path)
    with open(tmp_path / "sweep.csv", newline="") as fh:
        (line,) = list(csv.DictReader(fh))
    assert line["mean_escapees"] == ""
    assert float(line["mean_escapees_lower_bound"]) == st["mean_escapees_lower_bound"]


HOURGLASS = ROOT / "scenes" / "hourglass24.toml"


def test_the_set_up_phases_reach_the_api_in_order():
    phases = []
    sim = Simulation(load_scene(HOURGLASS, ["run.realizations=1"]), on_phase=phases.append)
    assert sim.R == 1
    assert [p.split(" ")[0] for p in phases] == ["starting", "resolving", "finding",
                                                 "placing", "compiling"], phases
    assert phases[0] == "starting Taichi (cpu)" or phases[0].startswith("starting Taichi (")


def test_a_run_says_it_is_setting_up_at_once_and_how_a_slow_set_up_goes(
        tmp_path, capsys, monkeypatch):
    """The first line comes before Taichi is loaded (within 2 s of the command);
    a phase of the set-up that takes longer than the clock's interval (5 s; 0.2 s
    here) gets a line saying which phase and how long so far."""
    from taichi_hsdem import cli, runner
    monkeypatch.setattr(cli._SetupClock, "EVERY", 0.2)
    seen = {}
    build = runner.build

    def slow_build(scene, **options):
        seen["before_build"] = capsys.readouterr().err
        options["on_phase"]("placing the particles")
        time.sleep(1.0)
        return build(scene, **options)
    monkeypatch.setattr(runner, "build", slow_build)
    out = tmp_path / "o"
    assert cli.main([str(HOURGLASS), "--out", str(out), "--realizations", "1",
                     "--set", "run.t_end=0.2", "--no-video"]) == 0
    first = seen["before_build"].strip().splitlines()
    assert len(first) == 1 and first[0].startswith("hourglass24: setting up ("), first
    err = capsys.readouterr().err.splitlines()
    beats = [ln for ln in err if ln.startswith("set-up: placing the particles ... (")]
    assert beats and beats[0].endswith("s so far)"), err
    info = next(k for k, ln in enumerate(err) if ln.startswith("hourglass24: 1 realization"))
    assert err.index(beats[0]) < info and ", set up in " in err[info]
    # the clock stops with the set-up: nothing of it after the run's end
    assert not any(ln.startswith("set-up:") for ln in err[info + 1:]
                   if not ln.startswith("set-up: compiling the step kernels"))
