"""A backend without float64 kernels (Metal, GLES) runs the default physics in
float32, its pressure solve too (fluid.gmg.F32_TOL_FLOOR): here on the CPU, with
float32 kernels and the backend's float64 probe answered "no", against the
CPU's float64 run of the vani case (tests/gpu_cases.py: 2 realizations, 150
steps). Tolerances: those of tests/test_gpu.py for float32."""
import subprocess
import sys
from pathlib import Path

import numpy as np

from test_gpu import F32_TOLERANCE

TESTS = Path(__file__).resolve().parent


def case(tmp_path, *options):
    out = tmp_path / f"vani{len(options)}.npz"
    proc = subprocess.run([sys.executable, str(TESTS / "gpu_cases.py"), "vani", "--out",
                           str(out), *options], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return dict(np.load(out))


def test_without_float64_the_default_physics_runs_in_float32(tmp_path):
    f32 = case(tmp_path, "--precision", "f32", "--no-f64")
    f64 = case(tmp_path)
    assert not f32["vani.solve_f64"] and f64["vani.solve_f64"]
    assert f32["vani.solves"] == f64["vani.solves"]
    assert np.array_equal(f32["vani.alive"], f64["vani.alive"])
    for key, tol in F32_TOLERANCE.items():
        a, b = f32[f"vani.{key}"].astype(float), f64[f"vani.{key}"]
        m = ~np.isnan(b)
        assert np.array_equal(np.isnan(a), np.isnan(b)), key
        worst = np.abs(a[m] - b[m]).max() / np.abs(b[m]).max()
        print(key, worst)
        assert worst <= tol, (key, worst, tol)
