"""Shared builders for small scenes the tests run on the CPU backend.

``python -m pytest --precision f32`` runs the kernels in single precision (Taichi
takes one precision per process) and then only the tests marked
``both_precisions``: their tolerances follow from :func:`unit_roundoff` where
f32's round-off matters. ``tests/test_precision.py`` runs that in a subprocess of
the default (f64) run.

``python -m pytest --arch gpu`` runs the same tests on the GPU backend (CUDA):
every simulation a test builds runs there whatever its scene's ``run.arch``, and
the run stops at once, with a message, where Taichi finds no GPU with float64
kernels. Tests that check the CPU's own paths (the fused disk stepper, ``x64`` in
a summary) are expected to fail there; the rest hold the same tolerances.
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
                     help="Taichi backend of this run (gpu: every simulation of the tests on "
                          "the GPU, whatever its scene's run.arch)")


def pytest_configure(config):
    _PRECISION["value"] = config.getoption("--precision")
    _PRECISION["arch"] = config.getoption("--arch")


def pytest_collection_modifyitems(config, items):
    if precision() == "f64":
        return
    skip = pytest.mark.skip(reason="f64 only (not marked both_precisions)")
    for item in items:
        if "both_precisions" not in item.keywords:
            item.add_marker(skip)


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


make_sim = gallery.make_sim
HeadOn = gallery.HeadOn


def head_on(e, **kwargs):
    """:func:`taichi_hsdem.gallery.head_on` in this test run's precision."""
    kwargs.setdefault("precision", precision())
    return gallery.head_on(e, **kwargs)


def speed(v):
    return float(np.linalg.norm(v))
