"""The GPU tests (tests/test_gpu.py, marked ``gpu``) from the default run: each
precision in a pytest subprocess with ``--arch gpu`` (Taichi takes one backend
and precision per process), on whatever GPU backend Taichi finds (CI: Mesa's
software Vulkan, which .ci/run installs). Where there is none the subprocess
stops at once with exit status 2 and says so (conftest.py), and these tests are
skipped with that reason.
"""
import re
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
NO_GPU = re.compile(r"--arch gpu: (arch=gpu was requested but Taichi found no usable GPU"
                    r"[^\n]*|the GPU backend found is \w+, which has no float64 kernels[^\n]*)")


def run_gpu_tests(*options):
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "--arch", "gpu",
                           "-p", "no:cacheprovider", *options, "test_gpu.py"],
                          cwd=TESTS, capture_output=True, text=True, timeout=1200)
    tail = proc.stdout[-4000:] + proc.stderr[-2000:]
    stopped = NO_GPU.search(tail)
    if stopped and proc.returncode == 2:
        pytest.skip(f"no GPU backend here: {stopped.group(1)}")
    assert proc.returncode == 0, tail
    return proc.stdout, tail


def test_the_gpu_tests_pass_on_this_machines_gpu():
    out, tail = run_gpu_tests()
    assert re.search(r"\b7 passed", out), tail


def test_the_gpu_tests_pass_there_in_float32():
    out, tail = run_gpu_tests("--precision", "f32")
    assert re.search(r"\b4 passed", out), tail


def test_arch_auto_records_its_choice_in_the_resolved_scene():
    # here (Mesa's software Vulkan, or no GPU at all) auto takes the CPU, and the
    # resolved scene says why; on a machine with a hardware GPU, that GPU
    code = ("import json; from taichi_hsdem import backend, load_scene; "
            "from taichi_hsdem.resolve import resolve; "
            "arch = backend.init('auto', 'f64'); "
            "m = resolve(load_scene(%r, ['run.arch=\"auto\"']), arch); "
            "print(json.dumps([arch, backend.device(), m.notes.get('run.arch')]))"
            % str(TESTS.parent / "scenes" / "vani_phi026.toml"))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    import json
    arch, device, note = json.loads(proc.stdout.strip().splitlines()[-1])
    assert note and note.startswith(f"{arch}: "), note
    if arch in ("x64", "arm64"):
        assert "the CPU" in note and ("software driver" in note or "no GPU" in note
                                      or "no float64" in note)
    else:
        assert "the GPU found" in note
