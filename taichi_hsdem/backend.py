"""Taichi initialisation: one backend and one floating-point type per process.

Taichi can be initialised once per process in practice (re-initialising throws
away every compiled kernel and allocated array), so the first simulation decides
the backend and precision and later ones must agree.

Kernels take ``ti.types.ndarray`` arguments rather than reading ``ti.field``
members: an ndarray kernel is compiled once per dtype and reused by every
simulation in the process (sweeps, calibration, tests), where a field-bound
kernel is recompiled for every new set of fields (~0.1-0.2 s per kernel on the
CPU).
"""
from __future__ import annotations

import contextlib
import io
import os

import numpy as np
from threadpoolctl import threadpool_limits

from .limits import thread_share

# stdout belongs to the user: no import banner; and skip Taichi's probes for
# torch/paddle, which this package never hands arrays to.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
os.environ.setdefault("TI_ENABLE_TORCH", "0")
os.environ.setdefault("TI_ENABLE_PADDLE", "0")
import taichi as ti  # noqa: E402

_STATE: dict = {}


class BackendError(RuntimeError):
    """The requested backend cannot be used in this process."""


def init(arch: str = "cpu", precision: str = "f64") -> str:
    """Initialise Taichi once; return the name of the backend actually used.

    Parameters
    ----------
    arch : {"cpu", "gpu", "auto"}
    precision : {"f64", "f32"}

    Examples
    --------
    >>> from taichi_hsdem import backend
    >>> backend.init("cpu", "f64")
    'x64'
    """
    if _STATE:
        if _STATE["request"] != (arch, precision):
            if _STATE["precision"] != precision:
                raise BackendError(
                    f"Taichi is already running with precision {_STATE['precision']} "
                    f"in this process; start a new process for precision {precision}")
            if arch != "auto" and _STATE["arch_request"] not in (arch, "auto"):
                raise BackendError(
                    f"Taichi is already running on {_STATE['arch']} in this process; "
                    f"start a new process for arch={arch}")
        return _STATE["arch"]
    fp = ti.f64 if precision == "f64" else ti.f32
    target = {"cpu": ti.cpu, "gpu": ti.gpu, "auto": ti.gpu}[arch]
    # Once Taichi's worker threads run, a multi-threaded BLAS call on the pressure
    # solve's small vectors waits on them (measured: a 14,400-value dot product
    # 8 ms instead of 3 us): one BLAS thread, limited at run time because numpy
    # may have loaded before the environment variables could act.
    _STATE["blas_limit"] = threadpool_limits(limits=1, user_api="blas")
    used = _ti_init(target, fp)
    why = None
    if arch == "auto" and used in _NO_F64 and precision == "f64":
        # e.g. Mesa's software Vulkan when no CUDA device exists: auto means "the
        # fastest backend that runs this scene", so the CPU
        why = f"{used} has no f64 kernels here: the CPU"
        ti.reset()
        used = _ti_init(ti.cpu, fp)
    if arch == "gpu" and used in ("x64", "arm64"):
        raise BackendError("arch=gpu was requested but Taichi found no usable GPU "
                           "(CUDA, Vulkan or Metal); use --arch cpu or --arch auto")
    if used in _NO_F64 and precision == "f64":
        # e.g. Mesa's software Vulkan when no CUDA device exists: the level-set
        # kernels' f64 trigonometry does not compile there.
        raise BackendError(f"the GPU backend found is {used}, which has no f64 kernels here; "
                           f"use --arch cpu, or --set run.precision=\"f32\"")
    _STATE.update(request=(arch, precision), arch_request=arch, arch=used,
                  precision=precision, real=fp, why=why)
    return used


#: Backends whose kernels have no float64 trigonometry here.
_NO_F64 = ("vulkan", "metal", "opengl", "gles")


def _ti_init(target, fp) -> str:
    """``ti.init`` with the project's settings; the arch's name."""
    # Taichi prints "Starting on arch=..." on stdout; stdout belongs to the user.
    with contextlib.redirect_stdout(io.StringIO()):
        # fast_math=False: LLVM may not reorder floating-point arithmetic, so the
        # kernels compute exactly what their source says on every CPU. With Taichi's
        # default (fast_math=True) the fused and the per-step paths, or two CPUs with
        # and without AVX-512, round differently (seen: 1e-13 apart).
        threads = {} if thread_share() is None else {"cpu_max_num_threads": thread_share()}
        ti.init(arch=target, default_fp=fp, default_ip=ti.i32, log_level=ti.ERROR,
                offline_cache=True, fast_math=False, **threads)
    return ti.lang.impl.current_cfg().arch.name


def auto_reason() -> str | None:
    """Why ``arch = "auto"`` did not take the GPU it found, or None."""
    return _STATE.get("why")


def real():
    """The Taichi float type chosen at :func:`init`."""
    return _STATE["real"]


def numpy_real():
    return np.float64 if _STATE["precision"] == "f64" else np.float32
