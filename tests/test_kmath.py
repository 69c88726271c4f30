"""The kernels' own sine, cosine and exponential (dem/kmath.py: no kernel calls
the backend's, which SPIR-V has in float32 only) against numpy's long double.

Measured on the CPU over 3.5 million angles up to 1.6e6 rad: float64 sin/cos
within 0.84 ulp, exp within 1.08 ulp; float32 sin/cos within 8.4e-8 absolute,
exp within 1.16 ulp (Mesa's Vulkan: 1.02 ulp for float64 sin/cos,
tests/test_gpu.py; both run the kernel of tests/kmath_kernel.py). Asserted: 0.9
ulp, 1.1 ulp, 2^-23 absolute, 1.2 ulp.
"""
import subprocess
import sys

import numpy as np
import pytest

from conftest import precision
from kmath_kernel import kmath_values
from taichi_hsdem import backend

pytestmark = pytest.mark.skipif(np.finfo(np.longdouble).nmant < 60,
                                reason="needs an 80-bit long double (x86) as the reference")


def errors(n=400_000, seed=11):
    """(sin/cos error, exp error) of kmath on this process's kernels: in ulps for
    float64, absolute (sin/cos) and ulps (exp) for float32."""
    real = backend.numpy_real()
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.uniform(-4, 4, n), rng.uniform(-1e3, 1e3, n // 4),
                        rng.uniform(-1e5, 1e5, n // 8), [0.0, -0.0, 1e-300, 5e-9],
                        np.arange(-4000, 4000) * (np.pi / 2)]).astype(real)
    if real is np.float64:
        x = np.concatenate([x, rng.uniform(-1.6e6, 1.6e6, n // 8)])
    out = []
    for name, (got, ref) in zip(("cos", "sin", "exp"), kmath_values(x)):
        keep = (ref != 0) & (np.abs(x) < 4000 if name == "exp" else True)
        err = np.abs(got[keep].astype(np.longdouble) - ref[keep])
        if real is np.float64 or name == "exp":
            err = err / np.spacing(np.abs(ref[keep]).astype(real)).astype(np.longdouble)
        out.append(float(err.max()))
    return max(out[:2]), out[2]


def test_float64_sin_cos_and_exp_within_an_ulp():
    if precision() != "f64":
        pytest.skip("the float32 case runs in its own process (below)")
    trig, exp = errors()
    assert trig <= 0.9 and exp <= 1.1, (trig, exp)


def test_float32_sin_cos_and_exp():
    # Taichi takes one precision per process: the float32 kernels in a subprocess
    code = ("import sys; sys.path.insert(0, %r); from taichi_hsdem import backend; "
            "backend.init('cpu', 'f32'); import test_kmath; print(*test_kmath.errors())"
            % str(__import__("pathlib").Path(__file__).parent))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    trig, exp = map(float, proc.stdout.split()[-2:])
    assert trig <= 2.0 ** -23 and exp <= 1.2, (trig, exp)
