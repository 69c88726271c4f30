"""Single precision (``run.precision = "f32"``): the tests marked ``both_precisions``
(in test_mechanics.py and test_coupling.py) run again with f32 kernels.

Taichi takes one precision per process and this pytest process runs f64, so the
f32 run is one pytest subprocess with ``--precision f32`` (conftest.py); the tests
themselves carry the f32 tolerances, derived from its round-off where it matters.
"""
import re
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_the_precision_tests_pass_in_f32():
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "--precision", "f32", "-m", "both_precisions",
         "-p", "no:cacheprovider", "test_mechanics.py", "test_coupling.py"],
        cwd=TESTS, capture_output=True, text=True, timeout=900)
    tail = proc.stdout[-3000:] + proc.stderr[-2000:]
    assert proc.returncode == 0, tail
    passed = re.search(r"(\d+) passed", proc.stdout)
    # rebound ratio (3), square slide, node-count normalisation, lone disk, drift (2)
    assert passed and int(passed.group(1)) == 8, tail


def test_arch_gpu_runs_the_tests_there_or_says_there_is_no_gpu():
    # ``--arch gpu`` (conftest.py) puts every simulation of the tests on the GPU; on
    # a machine without a GPU with float64 kernels (CI, this project's CPUs: none,
    # or Mesa's software Vulkan) the run stops at once with the backend's message
    # and exit status 2, before any test runs.
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "--arch", "gpu", "-m", "both_precisions",
         "-p", "no:cacheprovider", "test_mechanics.py"],
        cwd=TESTS, capture_output=True, text=True, timeout=900)
    tail = proc.stdout[-3000:] + proc.stderr[-2000:]
    stopped = re.search(r"--arch gpu: (arch=gpu was requested but Taichi found no usable "
                        r"GPU|the GPU backend found is \w+, which has no f64 kernels)", tail)
    if stopped:
        assert proc.returncode == 2, tail
        assert not re.search(r"\d+ passed", proc.stdout), tail
    else:  # a GPU machine: the same tests pass there
        assert proc.returncode == 0, tail
        passed = re.search(r"(\d+) passed", proc.stdout)
        assert passed and int(passed.group(1)) == 5, tail
