"""The default physics on a GPU against the CPU (issue 34): ``python -m pytest
--arch gpu`` runs these on the GPU backend Taichi finds (here Mesa's software
Vulkan; CUDA, Metal elsewhere), ``--precision f32`` the ones marked
``both_precisions`` in single precision. The default run has
tests/test_gpu_suite.py run both in subprocesses.

Each case (tests/gpu_cases.py) runs here, on the GPU, and in one CPU subprocess
per session (float64), and the two are compared.

Tolerances:

* float64: ``F64_TOLERANCE`` = 1e-9 of each quantity's largest magnitude. The two
  backends compute the same IEEE operations but not always in the same order
  (Mesa's Vulkan compiler reassociates sums and folds constants), so they part
  by round-off, 1e-16, which the pressure solve (condition number about 1e4) and
  150 steps of contacts grow: measured on the vani case 6e-13 in the pressure,
  7e-12 in the velocities, 1e-15 in the positions (tests/gpu_cases.py; Vulkan
  against x64). 1e-9 leaves a thousandfold margin and is still a million times
  below any difference a wrong kernel makes (a body left out of the
  permeability moved the first pressure by 30 %).
* float32 against the CPU's float64: ``F32_TOLERANCE``, per quantity, of its
  largest magnitude: the kernels' round-off, 6e-8, grown the same way. Measured
  on the vani case (Vulkan, f32, 150 steps): positions 4.5e-7, velocities 4.6e-4,
  fluid forces 4e-6, pressure 2e-8 (its solve is float64 where the backend has
  it); over a whole 0.02 s run (739 steps) 9.5e-6, 1.4e-3, 1.7e-3 and 1.6e-4,
  as far as the CPU's own float32 run lies from its float64 one. The float32
  solve (Metal's) is held within ``F32_SOLVE_TOLERANCE`` = 3e-4 of the float64
  pressure (fluid/gmg.py, F32_TOL_FLOOR: measured 7e-6 with a pressure inlet,
  7e-5 with a flow-rate one).
"""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gpu_cases
from conftest import both_precisions, precision
from kmath_kernel import kmath_values
from taichi_hsdem import backend

pytestmark = pytest.mark.gpu
TESTS = Path(__file__).resolve().parent
F64_TOLERANCE = 1e-9
F32_TOLERANCE = {"x": 2e-5, "v": 5e-3, "f_fluid": 5e-3, "pressure": 1e-3}
F32_SOLVE_TOLERANCE = 3e-4


@pytest.fixture(scope="session")
def cpu(tmp_path_factory):
    """The CPU's float64 answer to every case this run compares (one subprocess)."""
    out = tmp_path_factory.mktemp("cpu") / "ref.npz"
    cases = list(gpu_cases.CASES) if precision() == "f64" else ["vani", "solve"]
    proc = subprocess.run([sys.executable, str(TESTS / "gpu_cases.py"), "--arch", "cpu",
                           "--precision", "f64", "--out", str(out), *cases],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return dict(np.load(out))


def tolerance():
    return F64_TOLERANCE if precision() == "f64" else F32_TOLERANCE


def agree(case, gpu, cpu, keys, tol):
    """Each of ``keys`` of the GPU run within ``tol`` (a number, or one per key)
    of the CPU's, relative to the largest magnitude of the CPU's (NaN where both
    are NaN: walls)."""
    tol = tol if isinstance(tol, dict) else dict.fromkeys(keys, tol)
    worst = {}
    for key in keys:
        a, b = np.asarray(gpu[key], dtype=float), cpu[f"{case}.{key}"].astype(float)
        assert a.shape == b.shape, key
        assert np.array_equal(np.isnan(a), np.isnan(b)), key
        m = ~np.isnan(b)
        scale = np.abs(b[m]).max()
        worst[key] = float(np.abs(a[m] - b[m]).max() / scale) if scale > 0 else 0.0
    assert all(worst[k] <= tol[k] for k in keys), (case, worst, tol)
    return worst


def test_the_gpu_backend_is_a_gpu():
    assert backend.current_arch() not in ("x64", "arm64")


@both_precisions
def test_kernel_trigonometry_against_numpy():
    # kmath.sin_cos and exp_neg on this backend (no backend sin/cos/exp in kernels):
    # f64 within 1.1 ulp (measured 1.02 on Mesa's Vulkan, 0.84 on the CPU), f32
    # within 2^-23 absolute (measured 8.4e-8)
    real = backend.numpy_real()
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-4, 4, 200_000), rng.uniform(-1e3, 1e3, 50_000),
                        np.arange(-2000, 2000) * (np.pi / 2)]).astype(real)
    for got, ref in kmath_values(x):   # cos, sin, exp
        keep = ref != 0
        err = np.abs(got[keep].astype(np.longdouble) - ref[keep])
        if real is np.float64:
            ulps = err / np.spacing(np.abs(ref[keep]).astype(np.float64)).astype(np.longdouble)
            assert float(ulps.max()) <= 1.1
        else:
            assert float(err.max()) <= 2.0 ** -23


@both_precisions
def test_the_multigrid_solve_agrees_with_the_cpu(cpu):
    gpu = gpu_cases.solve("gpu", precision())
    # the solve is float64 wherever the backend has it, whatever the run's precision
    tol = F64_TOLERANCE if backend.has_f64() else F32_SOLVE_TOLERANCE
    agree("solve", gpu, cpu, ["flow_p", "pressure_p", "flow_flux", "pressure_flux"], tol)
    if backend.has_f64():
        for bc in ("flow", "pressure"):
            assert gpu[f"{bc}_iterations"] == cpu[f"solve.{bc}_iterations"]


@both_precisions
def test_the_float32_solve_within_its_floor(cpu):
    # the solve a backend without float64 gets (Metal), here forced
    from taichi_hsdem.fluid.gmg import F32_FLUX_FLOOR
    gpu = gpu_cases.solve("gpu", precision(), real="f32")
    agree("solve", gpu, cpu, ["flow_p", "pressure_p"], F32_SOLVE_TOLERANCE)
    for bc in ("flow", "pressure"):
        f_in, f_out = gpu[f"{bc}_flux"]
        assert np.all(np.abs(f_in - f_out) <= F32_FLUX_FLOOR * np.abs(f_in))
        assert gpu[f"{bc}_iterations"] < 40      # stops at its floor, not at MAXITER


@both_precisions
def test_the_vani_scene_ends_where_the_cpu_run_ends(cpu):
    # the default physics: disks, the multigrid CG with the implicit carried volume,
    # per-step kernels on the GPU against the fused stepper on the CPU
    gpu = gpu_cases.vani("gpu", precision())
    assert gpu["t"] == pytest.approx(float(cpu["vani.t"]), rel=1e-12)
    assert gpu["solves"] == cpu["vani.solves"]
    assert np.array_equal(gpu["alive"], cpu["vani.alive"])
    worst = agree("vani", gpu, cpu, ["x", "v", "pressure", "f_fluid"], tolerance())
    print("vani, largest relative differences:", worst)


def test_device_rebuilds_give_the_cpu_lists_and_stall_on_overflow(cpu):
    # the neighbour lists binned a thread per body on the GPU, by the host's build
    # and by the per-step path's device rebuild, against the CPU's serial binning:
    # the same lists, integers equal; too small lists stall the batch at the step
    gpu = gpu_cases.rebuild("gpu", precision())
    for key in ("host", "device"):
        np.testing.assert_array_equal(gpu[key], cpu[f"rebuild.{key}"], err_msg=key)
    np.testing.assert_array_equal(gpu["device"], gpu["host"])
    assert (gpu["host"] >= 0).sum() > 0                          # bodies have neighbours
    assert list(gpu["device_stall"][:2]) == [0, 1]               # rebuilt once, no stall
    assert list(gpu["device_running"]) == [1, 1]
    assert list(gpu["overflow_stall"]) == [8, 1, 1, 1]           # stalled at step 7 + 1
    assert list(gpu["overflow_running"]) == [0, 0]


def test_level_set_squares_end_where_the_cpu_run_ends(cpu):
    # the node contacts in two kernels of at most 31 arrays each, with fluid (f64:
    # the float32 run is the vani case's)
    gpu = gpu_cases.squares("gpu", precision())
    worst = agree("squares", gpu, cpu, ["x", "theta", "v", "omega", "pressure", "f_fluid"],
                  tolerance())
    print("squares, largest relative differences:", worst)
