"""Single precision (``run.precision = "f32"``): the tests marked ``both_precisions``
(in test_mechanics.py and test_coupling.py) run again with f32 kernels.

Taichi takes one precision per process and this pytest process runs f64, so the
f32 run is one pytest subprocess with ``--precision f32`` (conftest.py); the tests
themselves carry the f32 tolerances, derived from its round-off where it matters.
The GPU's runs of both precisions: tests/test_gpu_suite.py.
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
