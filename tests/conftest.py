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
import copy
from collections import namedtuple

import numpy as np
import pytest

from taichi_hsdem import backend

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


def arena_scene(particles, *, kn=1.0e4, friction=0.0, restitution=1.0, xi=0.0, length=20.0,
                height=10.0, dt="auto", dt_safety=0.05, normalize=True, fast_path=True,
                realizations=1, **extra):
    """A closed box without fluid: an outline whose open inlet/outlet ends are
    sealed by two solid blocks leaving slits far narrower than any particle.

    ``particles``: list of species tables (shape keys, count, density...); the
    contact keys given here are filled in where a species does not set them.
    """
    species = []
    for sp in particles:
        sp = dict(sp)
        sp.setdefault("density", 1.0)
        sp.setdefault("kn", kn)
        sp.setdefault("friction", friction)
        sp.setdefault("restitution", restitution)
        species.append(sp)
    scene = {
        "name": "arena",
        "units": "dimensionless",
        "run": {"t_end": 1.0, "dt": dt, "dt_safety": dt_safety, "realizations": realizations,
                "precision": precision()},
        "fluid": {"enabled": False, "gap": 1.0},
        "geometry": {
            "kind": "polygon",
            "outline": [[0.0, 0.0], [length, 0.0], [length, height], [0.0, height]],
            "obstacles": [
                [[1.0, 0.02], [2.0, 0.02], [2.0, height - 0.02], [1.0, height - 0.02]],
                [[length - 2.0, 0.02], [length - 1.0, 0.02], [length - 1.0, height - 0.02],
                 [length - 2.0, height - 0.02]],
            ],
            "constriction_x": length - 0.5,
            "escape_offset": 0.25,
        },
        "particles": species,
        "contact": {"normalize_by_nodes": normalize, "disk_fast_path": fast_path},
        "damping": {"xi": xi},
        "feed": {"mode": "none", "region": [2.5, length - 2.5]},
    }
    for key, value in extra.items():
        section, name = key.split("__")
        scene.setdefault(section, {})[name] = value
    return copy.deepcopy(scene)


def make_sim(scene_dict):
    from taichi_hsdem import Simulation, load_scene
    return Simulation(load_scene(scene_dict), place_particles=False)


HeadOn = namedtuple("HeadOn", "ratio v dt")


def head_on(e, fast_path=True, dt_safety=0.02, nodes=40):
    """Two unit disks (kn 1e4, no fluid) meet head on at relative speed 2: the
    rebound ratio, which the continuous spring-dashpot makes exactly ``e``, the
    final velocities and the time step."""
    sim = make_sim(arena_scene([{"shape": "circle", "diameter": 1.0, "count": 2,
                                 "nodes": nodes}], restitution=e, fast_path=fast_path,
                               dt_safety=dt_safety))
    sim.set_state([[[8.0, 5.0], [10.0, 5.0]]], v=[[[1.0, 0.0], [-1.0, 0.0]]])
    sim.step(int(1.2 / sim.dt))          # approach (0.5), contact, separation
    v = sim.state()["v"][0]
    return HeadOn((v[1, 0] - v[0, 0]) / 2.0, v, sim.dt)


def speed(v):
    return float(np.linalg.norm(v))
