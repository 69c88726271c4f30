"""Scenes that give their particles' initial positions (``particles.positions``)."""
import numpy as np
import pytest

from conftest import arena_scene
from taichi_hsdem import Simulation, SceneError, load_scene, scene_to_toml
from taichi_hsdem.cli import main
from taichi_hsdem.scene import read_toml

DISK = {"shape": "circle", "diameter": 1.0}


def _scene(positions, random_count=0, **extra):
    species = [dict(DISK, name="given", positions=positions)]
    if random_count:
        species.append(dict(DISK, name="random", count=random_count))
    return arena_scene(species, realizations=2, **extra)


def test_given_positions_are_where_the_particles_start_in_every_realization():
    poses = [[5.0, 5.0, 0.3], [7.0, 3.0], [9.5, 6.5, -1.0]]
    sim = Simulation(load_scene(_scene(poses, random_count=6)))
    st = sim.state()
    for r in range(2):
        np.testing.assert_array_equal(st["x"][r, :3], [p[:2] for p in poses])
        np.testing.assert_array_equal(st["theta"][r, :3], [0.3, 0.0, -1.0])
        # the randomly placed ones keep out of the given ones (centre distance >= d)
        gaps = np.linalg.norm(st["x"][r, 3:, None] - st["x"][r, None, :3], axis=-1)
        assert gaps.min() >= 1.0
    assert not np.array_equal(st["x"][0, 3:], st["x"][1, 3:])  # seeds differ there
    assert sim.model.scene.particles[0].count == 3


@pytest.mark.parametrize("poses, message", [
    ([[5.0, 5.0], [5.5, 5.0]], "particles 0 and 1 overlap by 0.5"),
    ([[5.0, 9.8]], "particle 0 (species 'given') overlaps a wall by 0.3"),
    ([[1.5, 5.0]], "has its centre outside the fluid region, at (1.5, 5)"),  # in a block
])
def test_overlapping_positions_are_refused_with_the_overlap(poses, message):
    with pytest.raises(SceneError) as caught:
        Simulation(load_scene(_scene(poses)))
    text = str(caught.value)
    assert "particles.positions" in text and message in text


@pytest.mark.parametrize("species_extra, message", [
    ({"count": 3}, "particles[0].count: 3 differs from the 2 positions given"),
    ({"packing_fraction": 0.1}, "positions are given too"),
    ({"positions": [[5.0, 5.0], [7.0]]}, "particles[0].positions[1]: expected [x, y] or [x, y, theta]"),
    ({"positions": [[5.0, "a"]]}, "particles[0].positions[0]"),
    ({"positions": []}, "needs at least 1 entries"),
])
def test_malformed_positions_are_reported(species_extra, message):
    scene = arena_scene([{**DISK, "positions": [[5.0, 5.0], [7.0, 3.0]], **species_extra}])
    with pytest.raises(SceneError) as caught:
        Simulation(load_scene(scene))
    assert message in str(caught.value)


def test_cli_refuses_a_particle_in_a_wall_with_exit_2(tmp_path, capsys):
    path = tmp_path / "scene.toml"
    path.write_text(scene_to_toml(load_scene(_scene([[5.0, 5.0]]))).replace(
        "[5.0, 5.0, 0.0]", "[5.0, 9.9, 0.0]"))
    code = main([str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2
    assert "overlaps a wall by 0.4" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_positions_survive_the_resolved_scene_round_trip(tmp_path):
    scene = load_scene(_scene([[5.0, 5.0, 0.25], [7.0, 3.0]], random_count=2))
    path = tmp_path / "resolved.toml"
    path.write_text(scene_to_toml(scene))
    again = load_scene(path)
    assert again.particles[0].positions == ((5.0, 5.0, 0.25), (7.0, 3.0, 0.0))
    assert read_toml(path)["particles"][0]["positions"][0] == [5.0, 5.0, 0.25]


def test_given_positions_beside_a_species_placed_by_packing_fraction():
    scene = _scene([[5.0, 5.0]])
    random = {k: v for k, v in scene["particles"][0].items() if k != "positions"}
    scene["particles"].append({**random, "name": "random", "packing_fraction": 0.1})
    sim = Simulation(load_scene(scene))
    n_random = sim.model.species[1].count
    assert n_random > 0 and sim.N == 1 + n_random
    st = sim.state()
    np.testing.assert_array_equal(st["x"][:, 0], [[5.0, 5.0]] * 2)
    assert np.linalg.norm(st["x"][:, 1:] - [5.0, 5.0], axis=-1).min() >= 1.0
