"""Shared builders for small scenes the tests run on the CPU backend."""
import copy

import numpy as np
import pytest

from taichi_hsdem import backend


@pytest.fixture(scope="session", autouse=True)
def _taichi_cpu():
    # One backend per process: every test runs on the CPU in double precision.
    backend.init("cpu", "f64")


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
        "run": {"t_end": 1.0, "dt": dt, "dt_safety": dt_safety, "realizations": realizations},
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


def head_on(e, fast_path=True, dt_safety=0.02, nodes=40):
    """Two unit disks (kn 1e4, no fluid) meet head on at relative speed 2: the
    rebound ratio, which the continuous spring-dashpot makes exactly ``e``, and
    the final velocities."""
    sim = make_sim(arena_scene([{"shape": "circle", "diameter": 1.0, "count": 2,
                                 "nodes": nodes}], restitution=e, fast_path=fast_path,
                               dt_safety=dt_safety))
    sim.set_state([[[8.0, 5.0], [10.0, 5.0]]], v=[[[1.0, 0.0], [-1.0, 0.0]]])
    sim.step(int(1.2 / sim.dt))          # approach (0.5), contact, separation
    v = sim.state()["v"][0]
    return (v[1, 0] - v[0, 0]) / 2.0, v


def speed(v):
    return float(np.linalg.norm(v))
