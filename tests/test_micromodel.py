"""Micromodels (issue 36): the pillar array, its throats, and what each throat saw."""
import math

import numpy as np
import pytest

from taichi_hsdem import load_scene
from taichi_hsdem.gallery import make_sim
from taichi_hsdem.geometry.micromodel import PillarError, pillar_array, polygon_gap
from taichi_hsdem.geometry.throats import find_throats, throat_rows
from taichi_hsdem.scene import SceneError
from taichi_hsdem.scene.toml import scene_to_toml


RANDOM = dict(rows=4, columns=5, diameter=1.0, spacing=2.0, inlet_length=3.0,
              outlet_length=2.0, spread=0.2, min_throat=0.4)


def test_random_array_is_reproducible_and_keeps_min_throat_from_pillars_and_walls():
    a = pillar_array("random", seed=7, **RANDOM)
    b = pillar_array("random", seed=7, **RANDOM)
    c = pillar_array("random", seed=8, **RANDOM)
    assert len(a.obstacles) == 20
    assert all(np.array_equal(p, q) for p, q in zip(a.obstacles, b.obstacles))
    assert not np.allclose(a.centres, c.centres)
    half_width = a.outline[:, 1].max()
    assert half_width == 4 * 2.0 / 2 + (2.0 - 1.0) / 2
    for k, p in enumerate(a.obstacles):
        assert half_width - np.abs(p[:, 1]).max() >= 0.4          # from both walls
        assert p[:, 0].min() >= 3.0 and p[:, 0].max() <= 3.0 + 5 * 2.0
        for q in a.obstacles[:k]:
            assert polygon_gap(p, q) >= 0.4 * (1 - 1e-12)
    # the sizes spread: their standard deviation is near 0.2 of the mean
    assert 0.1 < a.radii.std() / a.radii.mean() < 0.3


def test_square_array_of_hand_built_square_pillars_has_every_throat_exactly():
    # 2 rows x 3 columns of unit squares, centres 2.5 apart, 0.75 from the walls:
    # 3 gaps between the rows (1.5), 6 to the walls (0.75), 4 between columns (1.5);
    # the square pores' diagonals are no throats
    centres = [(3.0 + 2.5 * j, 1.25 + 2.5 * i) for j in range(3) for i in range(2)]
    squares = [np.array([[x - .5, y - .5], [x + .5, y - .5], [x + .5, y + .5], [x - .5, y + .5]])
               for x, y in centres]
    outline = [[0.0, 0.0], [11.0, 0.0], [11.0, 5.0], [0.0, 5.0]]
    t = find_throats(outline, squares)
    assert len(t) == 13
    widths = sorted(np.round(t.widths, 12).tolist())
    assert widths == [0.75] * 6 + [1.5] * 7
    # each gap's segment is the middle of the two faces
    mids = {tuple(np.round(m, 12)) for m in t.midpoints}
    assert (3.0, 2.5) in mids and (4.25, 1.25) in mids and (3.0, 0.375) in mids


def test_square_pillars_are_generated_exactly_and_every_gap_is_a_throat():
    # 4-sided "polygon" pillars are squares of side pillar_diameter facing the
    # axes; 2 x 3 of them, 2.5 apart: every gap (3 in the columns, 6 to the
    # walls, 4 between the columns) is 1.5 wide
    m = pillar_array("square", rows=2, columns=3, diameter=1.0, spacing=2.5,
                     inlet_length=2.0, outlet_length=2.0, sides=4, shape="polygon")
    for (x, y), p in zip(m.centres, m.obstacles):
        assert np.allclose(np.sort(p, axis=0), [[x - .5, y - .5], [x - .5, y - .5],
                                                [x + .5, y + .5], [x + .5, y + .5]],
                           rtol=0, atol=1e-12)
    t = find_throats(m.outline, m.obstacles)
    assert len(t) == 13
    assert np.allclose(t.widths, 1.5, rtol=0, atol=1e-12)


def test_polygon_pillars_whose_corners_touch_or_come_nearer_than_min_throat_are_refused():
    # hexagons (flat faces 1 apart) stand with a corner up: along a column the
    # corners are 2 / sqrt(3) = 1.1547 apart centre to centre
    hexagons = dict(rows=3, columns=2, diameter=1.0, inlet_length=2.0, outlet_length=2.0,
                    sides=6, shape="polygon")
    with pytest.raises(PillarError, match="pillar_spacing: 1.1 is too small") as e:
        pillar_array("square", spacing=1.1, **hexagons)
    assert e.value.key == "pillar_spacing"
    with pytest.raises(PillarError, match=r"min_throat: 0.05 is wider than the array's "
                       r"narrowest gap, 0.045299"):
        pillar_array("square", spacing=1.2, min_throat=0.05, **hexagons)
    m = pillar_array("square", spacing=1.2, min_throat=0.045, **hexagons)
    t = find_throats(m.outline, m.obstacles)
    assert t.widths.min() == pytest.approx(1.2 - 2 / math.sqrt(3), rel=1e-12)


def test_circular_pillar_throats_within_the_stated_polygon_error():
    # 24-gon pillars: each gap within 2 r tan^2(pi / 48) of the circles' (docs)
    m = pillar_array("staggered", rows=3, columns=4, diameter=1.0, spacing=2.0,
                     inlet_length=2.0, outlet_length=2.0)
    t = find_throats(m.outline, m.obstacles)
    circles = {1.0: 12, 2.0 * math.hypot(1.0, 0.5) - 1.0: 12, 1.5 + 0.5: 2}
    bound = 2 * 0.5 * math.tan(math.pi / 48) ** 2
    assert len(t) == 26
    for w in t.widths:
        assert min(abs(w - c) for c in circles) <= bound + 1e-12


MICRO = {
    "units": "dimensionless",
    "run": {"t_end": 1.0, "dt_safety": 0.05},
    "fluid": {"enabled": False, "gap": 1.0},
    "geometry": {"kind": "micromodel", "rows": 3, "columns": 4, "pillar_diameter": 2.0,
                 "pillar_spacing": 3.5, "inlet_length": 6.0, "outlet_length": 3.0},
    "particles": [{"shape": "circle", "diameter": 1.0, "count": 3, "density": 1.0,
                   "kn": 1e4, "friction": 0.4, "restitution": 0.5}],
    "feed": {"mode": "none"},
    "clog": {"window": 0.2},
}


def test_micromodel_scene_resolves_to_its_polygons_and_reloads_the_same(tmp_path):
    sim = make_sim(MICRO)
    g = sim.scene.geometry
    assert g.kind == "polygon" and len(g.obstacles) == 12 and g.pillar_array is None
    path = tmp_path / "resolved.toml"
    path.write_text(scene_to_toml(sim.scene))
    again = load_scene(path).geometry
    assert again.obstacles == g.obstacles and again.constriction_x == g.constriction_x
    # escape is measured past the array, so every throat sees the particles
    assert sim.model.x_escape > max(max(x for x, _ in o) for o in g.obstacles)
    assert len(sim.throats) == 25


def test_micromodel_keys_are_checked():
    bad = dict(MICRO, geometry=dict(MICRO["geometry"], pillar_spacing=1.5))
    with pytest.raises(SceneError, match="geometry.pillar_spacing: 1.5 must exceed"):
        load_scene(bad)
    bad = dict(MICRO, geometry=dict(MICRO["geometry"], diameter_spread=0.1))
    with pytest.raises(SceneError, match="geometry.diameter_spread: applies to"):
        load_scene(bad)
    bad = dict(MICRO, geometry=dict(MICRO["geometry"], pillar_sides=6))
    with pytest.raises(SceneError, match="geometry.pillar_sides: 6 sides are too few"):
        load_scene(bad)
    load_scene(dict(MICRO, geometry=dict(MICRO["geometry"], pillar_sides=6,
                                         pillar_shape="polygon")))


def _throat(sim, x, y):
    return int(np.argmin(np.hypot(*(sim.throats.midpoints - (x, y)).T)))


def test_clog_placed_by_hand_is_found_at_that_throat_only():
    sim = make_sim(MICRO)
    # the gap between the lowest two pillars of column 1 (x = 6 + 1.5 * 3.5):
    # two disks side by side across it, at rest, just upstream; a third far
    # upstream, at rest but at no throat
    x, y = 6.0 + 1.5 * 3.5, sim.throats.midpoints[_throat(sim, 11.25, -1.75), 1]
    k = _throat(sim, x, y)
    xs = [[x - 0.9, y - 0.52], [x - 0.9, y + 0.52], [2.0, 0.0]]
    sim.set_state([xs])
    sim.run()
    clogged = np.flatnonzero(np.isfinite(sim.run_state.throat_t_clog[0]))
    assert clogged.tolist() == [k]
    assert sim.run_state.throat_passages.sum() == 0
    # formed at the first check (nothing ever passed it), found after clog.window
    assert sim.run_state.throat_t_clog[0, k] == pytest.approx(sim.check_every * sim.dt, rel=1e-9)
    rows = [r for r in throat_rows(sim.throats, sim.run_state.throat_passages, sim.run_state.throat_t_clog)
            if r[6]]
    assert [(r[0], r[1]) for r in rows] == [(0, k)]


def test_a_disk_flying_along_a_row_of_gaps_passes_each_of_its_throats_once():
    sim = make_sim(dict(MICRO, particles=[dict(MICRO["particles"][0], count=1)]))
    y = sim.throats.midpoints[_throat(sim, 11.25, -1.75), 1]
    sim.set_state([[[2.0, y]]], v=[[[40.0, 0.0]]])
    sim.run()
    on_line = np.abs(sim.throats.midpoints[:, 1] - y) < 1e-9
    # the four columns' gaps at that height; the horizontal gaps between columns
    # are parallel to the path and not crossed
    crossed = on_line & (np.abs(sim.throats.end[:, 1] - sim.throats.start[:, 1]) > 0.1)
    assert crossed.sum() == 4
    assert sim.run_state.throat_passages[0, crossed].tolist() == [1, 1, 1, 1]
    assert sim.run_state.throat_passages[0, ~crossed].sum() == 0
    assert not np.isfinite(sim.run_state.throat_t_clog).any()


def test_a_disk_that_passes_the_last_throat_and_escapes_between_two_checks_is_counted():
    sim = make_sim(dict(MICRO, particles=[dict(MICRO["particles"][0], count=1)]))
    k = _throat(sim, 6.0 + 3.5 * 3.5, -1.75)        # last column, x = 18.25
    x0, speed = 17.9, 40.0
    reach = x0 + speed * sim.check_every * sim.dt    # where the first check finds it
    assert x0 < sim.throats.midpoints[k, 0] < sim.model.x_escape < reach
    sim.set_state([[[x0, sim.throats.midpoints[k, 1]]]], v=[[[speed, 0.0]]])
    sim.run()
    assert sim.results[0].escapees == 1
    assert sim.run_state.throat_passages[0].tolist() == [int(j == k) for j in range(len(sim.throats))]


def test_resumed_run_keeps_every_throats_passages_and_clog(tmp_path):
    """Stopped after the flyer passed the first column and after the jammed
    throat was first found at rest, but before its clog was declared: the resumed
    run's throats are those of the run never stopped."""
    from taichi_hsdem import checkpoint
    from taichi_hsdem.simulation import Simulation

    def started():
        sim = make_sim(MICRO)
        x, y = 6.0 + 1.5 * 3.5, sim.throats.midpoints[_throat(sim, 11.25, -1.75), 1]
        sim.set_state([[[x - 0.9, y - 0.52], [x - 0.9, y + 0.52], [2.0, 1.75]]],
                      v=[[[0.0, 0.0], [0.0, 0.0], [40.0, 0.0]]])
        return sim

    straight = started()
    straight.run()
    first = started()
    first.run(stop=lambda: first.t > 0.16)
    assert first.t < MICRO["clog"]["window"] and first.run_state.throat_passages.sum() == 1
    assert not np.isfinite(first.run_state.throat_t_clog).any() and np.isfinite(first.run_state.throat_static_t).any()
    saved = checkpoint.save(first, tmp_path / "checkpoint.npz")
    second = Simulation(first.scene, place_particles=False)
    checkpoint.restore(second, saved)
    second.run()
    assert straight.run_state.throat_passages.sum() == 4 and np.isfinite(straight.run_state.throat_t_clog).sum() == 1
    for name in ("throat_passages", "throat_last_passage_t", "throat_t_clog"):
        assert np.array_equal(getattr(second.run_state, name),
                              getattr(straight.run_state, name), equal_nan=True)


def test_shipped_micromodel_writes_its_throats(tmp_path, capsys):
    """scenes/micromodel.toml from the command line: throats.csv has the contract's
    columns and a row for each of the 25 throats of its 3 x 4 array (150 um gaps
    between 24-gon pillars: within 2 r tan^2(pi / 48) of the circles', which the
    gaps between flat faces reach), beside flow.csv."""
    import csv
    from pathlib import Path

    from taichi_hsdem.cli import main
    scene = Path(__file__).resolve().parents[1] / "scenes" / "micromodel.toml"
    out = tmp_path / "run"
    assert main([str(scene), "--out", str(out), "--quiet", "--no-video",
                 "--set", "run.t_end=0.02"]) == 0
    with open(out / "throats.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["realization", "throat", "x", "y", "width", "passages", "clogged",
                       "t_clog"]
    assert [(int(r[0]), int(r[1])) for r in rows[1:]] == [(0, k) for k in range(25)]
    bound = 2 * 100e-6 * math.tan(math.pi / 48) ** 2
    assert all(abs(float(r[4]) - 150e-6) <= bound * (1 + 1e-9) for r in rows[1:])
    assert (out / "flow.csv").exists()
