"""Shared builders for small scenes the tests run on the CPU backend.

``python -m pytest --precision f32`` runs the kernels in single precision (Taichi
takes one precision per process) and then only the tests marked
``both_precisions``: their tolerances follow from :func:`unit_roundoff` where
f32's round-off matters. ``tests/test_precision.py`` runs that in a subprocess of
the default (f64) run.

``python -m pytest --arch gpu`` runs the tests marked ``gpu`` (tests/test_gpu.py)
on the GPU backend Taichi finds (CUDA, Vulkan, Metal; here Mesa's software Vulkan),
each comparing its GPU run with the CPU run of the same thing; every simulation
a test builds runs there, whatever its scene's ``run.arch``. The run stops at
once with exit status 2 and a message where Taichi finds no GPU (or, for f64, none
with float64 kernels). The default (CPU) run leaves the ``gpu`` tests out and runs
them in a subprocess instead (tests/test_gpu_suite.py), skipped with the reason
where there is no GPU.
"""
import numpy as np
import pytest

from taichi_hsdem import backend, gallery

both_precisions = pytest.mark.both_precisions
_PRECISION = {"value": "f64", "arch": "cpu"}


def pytest_addoption(parser):
    parser.addoption("--precision", choices=("f64", "f32"), default="f64",
                     help="floating-point type of the kernels for this run; f32 runs only "
                          "the tests marked both_precisions")
    parser.addoption("--arch", choices=("cpu", "gpu"), default="cpu",
                     help="Taichi backend of this run (gpu: the tests marked gpu, every "
                          "simulation on the GPU, whatever its scene's run.arch)")


def pytest_configure(config):
    _PRECISION["value"] = config.getoption("--precision")
    _PRECISION["arch"] = config.getoption("--arch")
    config.addinivalue_line("markers", "gpu: compares a GPU run with the CPU's; runs with "
                                       "--arch gpu only (tests/test_gpu_suite.py)")


def pytest_collection_modifyitems(config, items):
    gpu = _PRECISION["arch"] == "gpu"
    skip_cpu = pytest.mark.skip(reason="a CPU test (--arch gpu runs the tests marked gpu)")
    skip_gpu = pytest.mark.skip(reason="a GPU test: python -m pytest --arch gpu (the default "
                                       "run has tests/test_gpu_suite.py run them)")
    skip_f64 = pytest.mark.skip(reason="f64 only (not marked both_precisions)")
    for item in items:
        if (item.get_closest_marker("gpu") is not None) != gpu:
            item.add_marker(skip_gpu if not gpu else skip_cpu)
        elif precision() != "f64" and "both_precisions" not in item.keywords:
            item.add_marker(skip_f64)


def precision() -> str:
    """The kernels' floating-point type in this test process, "f64" or "f32"."""
    return _PRECISION["value"]


def unit_roundoff() -> float:
    """Unit round-off of the kernels' floating-point type (2^-53 or 2^-24)."""
    return 2.0 ** -24 if precision() == "f32" else 2.0 ** -53


def ulp(x: float) -> float:
    """Spacing of the kernels' floating-point numbers at ``x``."""
    return float(np.spacing(backend.numpy_real()(x)))


@pytest.fixture(scope="session", autouse=True)
def _taichi_backend():
    # One backend per process: every test runs on the CPU (or, with --arch gpu, on
    # the GPU), in the precision asked.
    if _PRECISION["arch"] == "cpu":
        backend.init("cpu", precision())
        yield
        return
    try:
        backend.init("gpu", precision())
    except backend.BackendError as exc:
        pytest.exit(f"--arch gpu: {exc}", returncode=2)
    init = backend.init
    # a scene's run.arch ("cpu" by default) would otherwise refuse the GPU backend
    backend.init = lambda arch="cpu", precision="f64": init("gpu", precision)
    yield
    backend.init = init


def arena_scene(particles, **kwargs):
    """:func:`taichi_hsdem.gallery.arena_scene` in this test run's precision."""
    kwargs.setdefault("precision", precision())
    return gallery.arena_scene(particles, **kwargs)


def load_tool(name):
    """The module of ``tools/<name>.py`` (the tools are scripts, not a package),
    registered in ``sys.modules`` so that its dataclasses find their module."""
    import importlib.util
    import sys
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


make_sim = gallery.make_sim
HeadOn = gallery.HeadOn


def head_on(e, **kwargs):
    """:func:`taichi_hsdem.gallery.head_on` in this test run's precision."""
    kwargs.setdefault("precision", precision())
    return gallery.head_on(e, **kwargs)


def speed(v):
    return float(np.linalg.norm(v))
