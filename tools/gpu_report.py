"""Everything a first run on a real GPU should measure, in one go, into one report.

    python tools/gpu_report.py                 # on a GPU machine: under 12 minutes on one H100/H200
    python tools/gpu_report.py --quick         # the same parts, tiny (proves the script here, on
                                               # Mesa's software Vulkan, in about 6 minutes)
    python tools/gpu_report.py --out runs/gpu_report/report.md   # the default

Parts, each a subprocess with its own time limit (seconds, full / --quick), so that
a slow or stuck part costs its limit and the report still comes out:

1. ``environment`` (30 / 120): the GPU Taichi finds (``--arch auto``'s choice and
   reason, the device's name, float64 or not), ``nvidia-smi``, versions.
2. ``tests`` (200 / 420): the GPU tests against the CPU, float64 and float32
   (``python -m pytest --arch gpu tests/test_gpu.py [--precision f32]``).
3. ``bench`` (180 / 150): ``tools/bench.py --arch gpu`` on the vani scene at 1, 10
   and 100 realizations, the squares at 10 and the paper-like case, then the
   10,000-disk channel, each case also on the CPU for the ratio (full runs only;
   ``--quick``: one realization, 1 ms simulated, GPU only).
4. ``friction`` (270 / 240): Fig. 10, ``python -m taichi_hsdem figures friction
   --realizations 100`` on the GPU, 5 s per point as the study has it
   (``--friction-t-end`` for less; ``--quick``: 2 realizations at one friction
   over 0.01 s). Points finished before the limit are kept (``--resume``: run it
   again to go on) and listed.

The report (Markdown) gives each part's command, exit status, wall time and
what it printed that matters (the benchmark table, the test summary, the
figure's numbers), so that the README's GPU row can be filled from it.
"""
import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable

# (full, quick) time limits per part, seconds: 680 s in all for a full run, under
# the 12 minutes it must fit, the rest being start-up and writing.
LIMITS = {"environment": (30, 120), "tests": (200, 420), "bench": (180, 150),
          "friction": (270, 240)}
BENCH_CASES = ["disks-0.26-R1", "disks-0.26-R10", "disks-0.26-R100", "squares-0.26-R10",
               "paper-disks-0.26-R1"]
BENCH_SIM_TIME = 0.05
CHANNEL_CASE, CHANNEL_SIM_TIME = "channel-10000", 0.005
QUICK_BENCH = ["disks-0.26-R1"]
QUICK_SIM_TIME = 0.001

_ENV_PROBE = """
import json, sys
from taichi_hsdem import backend
used = backend.init("auto", "f64")
info = {"auto": used, "auto_reason": backend.auto_reason(), "device": backend.device(),
        "float64": backend.has_f64()}
print(json.dumps(info))
"""
_GPU_PROBE = """
import json
from taichi_hsdem import backend
try:
    used = backend.init("gpu", "f32")
    print(json.dumps({"gpu": used, "device": backend.device(), "float64": backend.has_f64()}))
except backend.BackendError as e:
    print(json.dumps({"gpu": None, "error": str(e)}))
"""


def run(cmd, limit, cwd=ROOT, env=None):
    """(exit status or 'timed out', wall seconds, stdout, stderr) of ``cmd``, killed
    (its whole process group) after ``limit`` seconds."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=limit)
        status = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        out, err = proc.communicate()
        status = f"timed out after {limit} s"
    return status, time.perf_counter() - t0, out or "", err or ""


def fence(text, lines=40):
    tail = "\n".join(text.strip().splitlines()[-lines:])
    return f"```\n{tail}\n```\n" if tail else "(nothing)\n"


class Report:
    def __init__(self, path, quick):
        self.path, self.quick, self.parts = Path(path), quick, []
        self.t0 = time.perf_counter()

    def part(self, name, cmds_and_results, body):
        self.parts.append((name, cmds_and_results, body))
        self.write()   # after every part: a later part that hangs leaves the report

    def write(self):
        head = [f"# GPU report ({'quick' if self.quick else 'full'})", "",
                f"Written by `python tools/gpu_report.py{' --quick' if self.quick else ''}` "
                f"on {platform.node()} ({platform.platform()}), "
                f"{time.strftime('%Y-%m-%d %H:%M:%S')}, "
                f"{time.perf_counter() - self.t0:.0f} s so far.", ""]
        for name, runs, body in self.parts:
            head.append(f"## {name}")
            head.append("")
            for cmd, status, wall in runs:
                head.append(f"* `{' '.join(cmd)}`: exit {status}, {wall:.0f} s")
            head.append("")
            head.append(body)
        self.path.write_text("\n".join(head))


def environment(report, limit):
    runs, lines = [], []
    for name, probe in (("auto", _ENV_PROBE), ("gpu", _GPU_PROBE)):
        cmd = [PY, "-c", probe]
        status, wall, out, err = run(cmd, limit / 2)
        runs.append((["python", "-c", f"<{name} probe>"], status, wall))
        lines.append(f"* {name}: " + (out.strip().splitlines()[-1] if out.strip()
                                      else f"no answer: {err.strip()[-300:]}"))
    if shutil.which("nvidia-smi"):
        status, wall, out, err = run(["nvidia-smi", "--query-gpu=name,memory.total,driver_version",
                                      "--format=csv,noheader"], 20)
        lines.append(f"* nvidia-smi: {out.strip() or err.strip()}")
    import numpy
    lines.append(f"* python {platform.python_version()}, numpy {numpy.__version__}, "
                 f"{os.cpu_count()} CPUs")
    report.part("Environment", runs, "\n".join(lines) + "\n")


def tests(report, limit):
    runs, body = [], []
    for extra in ([], ["--precision", "f32"]):
        cmd = [PY, "-m", "pytest", "-q", "-s", "--arch", "gpu", "-p", "no:cacheprovider",
               *extra, "tests/test_gpu.py"]
        status, wall, out, err = run(cmd, limit / 2)
        runs.append((["python", "-m", "pytest", "--arch", "gpu", *extra, "tests/test_gpu.py"],
                     status, wall))
        found = [ln for ln in out.splitlines() if "largest relative differences" in ln
                 or " passed" in ln or " failed" in ln or "skipped" in ln]
        body.append(f"{' '.join(extra) or 'f64'}:\n" + fence("\n".join(found) or out + err, 20))
    report.part("GPU tests against the CPU", runs, "\n".join(body))


def _bench_rows(out):
    rows = []
    for line in out.splitlines():
        if line.startswith("{"):
            try:
                rows.append(json.loads(line))
            except ValueError:
                pass
    return rows


def bench(report, limit, quick):
    plan = ([("gpu", QUICK_BENCH, QUICK_SIM_TIME)] if quick else
            [("gpu", BENCH_CASES, BENCH_SIM_TIME), ("gpu", [CHANNEL_CASE], CHANNEL_SIM_TIME),
             ("cpu", BENCH_CASES[:2] + ["paper-disks-0.26-R1"], BENCH_SIM_TIME)])
    runs, rows = [], []
    deadline = time.perf_counter() + limit
    for arch, cases, sim_time in plan:
        left = deadline - time.perf_counter()
        if left < 10:
            rows.append({"case": ",".join(cases), "arch": arch, "error": "no time left"})
            continue
        cmd = [PY, "tools/bench.py", "--arch", arch, "--cases", ",".join(cases),
               "--sim-time", str(sim_time)]
        status, wall, out, err = run(cmd, left)
        runs.append((["python", *cmd[1:]], status, wall))
        rows += [dict(r, arch_asked=arch) for r in _bench_rows(out)]
    table = ["| case | arch | steps/s | realization-s per wall s | ms per solve | solve share "
             "| ms per step (DEM alone) | peak MB |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            table.append(f"| {r['case']} | {r.get('arch_asked', r.get('arch'))} | "
                         f"{r['error']} | | | | | |")
            continue
        table.append(f"| {r['case']} | {r['arch']} | {r['steps_per_s']:.0f} | "
                     f"{r['realization_sim_s_per_wall_s']:.4g} | {r['ms_per_solve']} | "
                     f"{100 * r['pressure_share']:.0f} % | {r['dem_ms_per_step']} | "
                     f"{r['peak_rss_mb']:.0f} |")
    report.part("Benchmarks (tools/bench.py)", runs,
                "\n".join(table) + "\n\n<details><summary>JSON</summary>\n\n```\n"
                + "\n".join(json.dumps(r) for r in rows) + "\n```\n</details>\n")


def friction(report, limit, quick, out_dir, t_end=None):
    cmd = [PY, "-m", "taichi_hsdem", "figures", "friction", "--out", str(out_dir),
           "--set", 'run.arch="gpu"', "--resume"]
    cmd += (["--quick", "--realizations", "2", "--mu", "0.5", "--set", "run.t_end=0.01"]
            if quick else ["--realizations", "100"])
    if t_end is not None:
        cmd += ["--set", f"run.t_end={t_end}"]
    status, wall, out, err = run(cmd, limit)
    found = []
    fig = out_dir / "figure.json"
    if fig.exists():
        found.append(fence(fig.read_text(), 60))
    points = sorted(p.name for p in (out_dir / "points").glob("*")) \
        if (out_dir / "points").exists() else []
    found.append(f"points finished: {len(points)} ({', '.join(points[:12])})\n")
    found.append("output:\n" + fence(out + err, 25))
    report.part("Fig. 10, friction, on the GPU", [(["python", *cmd[1:]], status, wall)],
                "\n".join(found))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="every part tiny, to prove the script on any GPU backend")
    ap.add_argument("--out", default="runs/gpu_report/report.md", help="the report (Markdown)")
    ap.add_argument("--work", default="runs/gpu_report", help="the friction study's folder")
    ap.add_argument("--friction-t-end", type=float, default=None,
                    help="simulated seconds per friction point (default: the study's 5 s; "
                         "a shorter one if the points do not fit their 270 s)")
    ap.add_argument("--parts", default="environment,tests,bench,friction",
                    help="comma-separated parts to run (default: all)")
    a = ap.parse_args(argv)
    q = 1 if a.quick else 0
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    report = Report(a.out, a.quick)
    parts = a.parts.split(",")
    if "environment" in parts:
        environment(report, LIMITS["environment"][q])
    if "tests" in parts:
        tests(report, LIMITS["tests"][q])
    if "bench" in parts:
        bench(report, LIMITS["bench"][q], a.quick)
    if "friction" in parts:
        work = Path(a.work) / ("quick" if a.quick else "full")
        friction(report, LIMITS["friction"][q], a.quick, ROOT / work if not work.is_absolute()
                 else work, a.friction_t_end)
    report.write()
    print(f"{a.out}: {len(report.parts)} parts in {time.perf_counter() - report.t0:.0f} s",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
