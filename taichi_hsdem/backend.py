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
import re
import sys
import tempfile

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


class AddressSpaceLimit(BackendError):
    """Taichi could not reserve the address space it starts with (``ulimit -v``)."""


def init(arch: str = "cpu", precision: str = "f64") -> str:
    """Initialise Taichi once; return the name of the backend actually used.

    Parameters
    ----------
    arch : {"cpu", "gpu", "auto", "cuda", "vulkan", "metal", "opengl"}
        ``gpu``: the GPU Taichi finds (CUDA, else Vulkan, Metal, OpenGL), refused
        where there is none, or where ``precision = "f64"`` and it has no float64
        kernels (a software driver is refused by :func:`refuse_software_gpu`, which
        the command line calls). ``cuda``, ``vulkan``, ``metal``, ``opengl``: that
        backend, whatever its driver (Mesa's software Vulkan included), refused
        where Taichi cannot start it. ``auto``: that GPU unless it is a software driver (Mesa's
        llvmpipe, SwiftShader: about 100 times slower than the CPU backend) or
        has no float64 kernels for an f64 run; else the CPU. Why is kept
        (:func:`auto_reason`) and recorded in the resolved scene.
    precision : {"f64", "f32"}

    Examples
    --------
    >>> from taichi_hsdem import backend
    >>> backend.init("cpu", "f64")
    'x64'
    """
    if "request" in _STATE:     # Taichi runs (a failed start leaves only the BLAS limit)
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
    # Once Taichi's worker threads run, a multi-threaded BLAS call on the pressure
    # solve's small vectors waits on them (measured: a 14,400-value dot product
    # 8 ms instead of 3 us): one BLAS thread, limited at run time because numpy
    # may have loaded before the environment variables could act.
    _STATE["blas_limit"] = threadpool_limits(limits=1, user_api="blas")
    if arch == "cpu":
        used, device = _ti_init(ti.cpu, fp), None
    elif arch in EXPLICIT_GPUS:
        used, device = _ti_init(getattr(ti, arch), fp, name_device=True)
        if used != arch:        # Taichi falls back to the CPU where it cannot start it
            ti.reset()
            raise BackendError(f"arch={arch} was requested but Taichi cannot start {arch} "
                               "here; use --arch cpu or --arch auto")
    else:
        used, device = _ti_init(ti.gpu, fp, name_device=True)
    f64 = _probe_f64(used)
    why = None
    if arch == "auto" and used not in _CPUS:
        if _is_software(device):
            why = (f"{used} here is a software driver ({device}), about 100 times slower "
                   "than the CPU backend: the CPU")
        elif precision == "f64" and not f64:
            why = (f"{used} has no float64 kernels: the CPU (run.precision = \"f32\" runs "
                   f"on {used})")
        else:
            why = f"the GPU found: {used}" + (f" ({device})" if device else "")
        if not why.startswith("the GPU"):
            ti.reset()
            used, device, f64 = _ti_init(ti.cpu, fp), None, True
    elif arch == "auto":
        why = "no GPU found (CUDA, Vulkan, Metal or OpenGL): the CPU"
    if arch == "gpu" and used in _CPUS:
        raise BackendError("arch=gpu was requested but Taichi found no usable GPU "
                           "(CUDA, Vulkan or Metal); use --arch cpu or --arch auto")
    if precision == "f64" and not f64:
        raise BackendError(f"the GPU backend found is {used}, which has no float64 kernels; "
                           f"use --arch cpu, or --set run.precision=\"f32\"")
    _STATE.update(request=(arch, precision), arch_request=arch, arch=used, device=device,
                  precision=precision, real=fp, why=why, f64=f64)
    return used


#: Taichi's CPU backends.
_CPUS = ("x64", "arm64")
#: GPU backends a user can name (``arch = "vulkan"``): run there whatever the driver.
EXPLICIT_GPUS = ("cuda", "vulkan", "metal", "opengl")
#: Backends whose kernels never have float64 (Taichi's Metal, OpenGL ES).
NO_F64_ARCHS = _NO_F64 = ("metal", "gles")
#: Device names of software drivers (Mesa's llvmpipe/lavapipe, Google's SwiftShader).
_SOFTWARE = ("llvmpipe", "lavapipe", "swiftshader", "softpipe")


def _is_software(device) -> bool:
    return device is not None and any(w in device.lower() for w in _SOFTWARE)


def refuse_software_gpu(arch: str, precision: str = "f64") -> None:
    """Initialise Taichi for ``arch`` (:func:`init`) and raise :class:`BackendError`
    (one line: the driver and the CPU alternative) when ``arch = "gpu"`` found only a
    software driver (Mesa's llvmpipe/lavapipe, SwiftShader: about 100 times slower than
    the CPU backend; 87 s against 2.9 s measured on vani_phi026). Naming the backend
    (``arch = "vulkan"``) runs there anyway; ``cpu`` and ``auto`` pass (``auto``
    already takes the CPU over a software driver).

    The command line calls this before it builds a simulation, so that ``--arch
    gpu`` on a machine without a real GPU stops at once (exit status 2)."""
    if arch != "gpu":
        return
    used = init(arch, precision)
    device = _STATE.get("device")
    if _is_software(device):
        raise BackendError(
            f"the GPU found is a software driver ({used} on {device}), about 100 times slower "
            f"than the CPU: use --arch cpu (or --arch auto, which takes the CPU here), or "
            f"--arch {used} to run on the software driver anyway")


def _probe_f64(used: str) -> bool:
    """Whether kernels compute float64 here: always on the CPU and CUDA, never on
    Metal and GLES; elsewhere (Vulkan, OpenGL: a device feature) a float64
    kernel is compiled and its result compared with numpy's (to 1e-14: Mesa's
    Vulkan divides by a constant as a product with its inverse, 1 ulp off; float32
    would be 1e-8 off)."""
    if used in _CPUS or used == "cuda":
        return True
    if used in _NO_F64:
        return False
    try:
        a = ti.ndarray(ti.f64, 4)
        a.from_numpy(np.arange(4.0) + 2.0)
        _f64_probe(a)
        got = a.to_numpy()
    except Exception:   # noqa: BLE001 - any failure to compile or run: no float64
        return False
    x = np.arange(4.0) + 2.0
    return bool(np.allclose(got, np.sqrt(x) / 3.0 + 1e-12 * np.arange(4.0), rtol=1e-14, atol=0))


def _f64_probe(a):
    for i in a:
        a[i] = ti.sqrt(a[i]) / 3.0 + 1e-12 * ti.cast(i, ti.f64)


# (annotations are strings in this module: Taichi needs the object)
_f64_probe.__annotations__ = {"a": ti.types.ndarray(dtype=ti.f64, ndim=1)}
_f64_probe = ti.kernel(_f64_probe)


def _ti_init(target, fp, name_device: bool = False):
    """``ti.init`` with the project's settings; the arch's name (and, with
    ``name_device``, the GPU's name as Taichi's log gives it, or None)."""
    # Taichi prints "Starting on arch=..." on stdout; stdout belongs to the user.
    # fast_math=False: LLVM may not reorder floating-point arithmetic, so the
    # kernels compute exactly what their source says on every CPU. With Taichi's
    # default (fast_math=True) the fused and the per-step paths, or two CPUs with
    # and without AVX-512, round differently (seen: 1e-13 apart).
    threads = {} if thread_share() is None else {"cpu_max_num_threads": thread_share()}
    settings = dict(arch=target, default_fp=fp, default_ip=ti.i32, offline_cache=True,
                    fast_math=False, **threads)
    # Taichi's C++ log goes to the process's own stdout and stderr: read it from
    # there while ti.init runs (the device's name is in its trace log only; a
    # failure is said in our words; errors of a start that worked are passed on).
    with tempfile.TemporaryFile(mode="w+b") as log, contextlib.redirect_stdout(io.StringIO()):
        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(1), os.dup(2)]
        failed = None
        try:
            os.dup2(log.fileno(), 1)
            os.dup2(log.fileno(), 2)
            ti.init(log_level=ti.TRACE if name_device else ti.ERROR, **settings)
        except RuntimeError as exc:
            failed = exc
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            ti.set_logging_level(ti.ERROR)
        log.seek(0)
        text = log.read().decode("utf-8", "replace")
    reserve = re.search(r"Virtual memory allocation \((\d+) B\) failed", str(failed or ""))
    if reserve:
        raise AddressSpaceLimit(
            f"Taichi could not reserve the {int(reserve.group(1)) / 2**30:.3g} GiB of address "
            "space it starts with: this process's virtual memory is limited (ulimit -v, "
            "or a job's memory limit on virtual memory); raise the limit to a few GiB more "
            "than the run needs (a limit on resident memory, such as Slurm's --mem, does "
            "not stop it)") from None
    if failed is not None:
        raise failed
    if not name_device:
        if text.strip():
            print(text.rstrip(), file=sys.stderr)
        return ti.lang.impl.current_cfg().arch.name
    found = re.search(r"Found Vulkan Device \d+ \((.*)\)\s*$", text, re.MULTILINE)
    return ti.lang.impl.current_cfg().arch.name, (found.group(1) if found else None)


def auto_reason() -> str | None:
    """What ``arch = "auto"`` chose and why (None for an explicit arch)."""
    return _STATE.get("why")


def on_gpu() -> bool:
    """Whether Taichi runs on a GPU backend now (any but its CPU backends), however
    it was initialised."""
    return ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64)


def current_arch() -> str | None:
    """The backend :func:`init` chose, or None before it."""
    return _STATE.get("arch")


def device() -> str | None:
    """The GPU's name where Taichi's log gives it (Vulkan), else None."""
    return _STATE.get("device")


def has_f64() -> bool:
    """Whether this backend's kernels compute float64 (:func:`_probe_f64`)."""
    return bool(_STATE.get("f64", True))


def solve_real():
    """The float type of the Taichi pressure solve: float64 wherever the backend
    has it (whatever the run's precision), else float32."""
    return ti.f64 if has_f64() else ti.f32


def real():
    """The Taichi float type chosen at :func:`init`."""
    return _STATE["real"]


def numpy_real():
    return np.float64 if _STATE["precision"] == "f64" else np.float32
