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
    # the injected bodies and clogged throats over time too (network.csv)
    assert second.run_state.network == straight.run_state.network
    assert [row[3] for row in straight.run_state.network][-1] == 1


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
    with open(out / "network.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["realization", "t", "injected", "throats_clogged", "fraction_clogged"]
    assert rows[1][2:] == ["40", "0", "0.0"]           # the 40 disks placed, none clogged
    import json
    summary = json.loads((out / "summary.json").read_text())
    net = summary["network"]
    assert (net["throats"], net["pores"]) == (25, 20)
    assert net["realizations"][0]["throats_clogged"] == 0
    # K0: the empty array's pressure drop at the pump's flow rate, a little below
    # the first solve's (the disks in the inlet add resistance)
    assert 4.0 < net["empty"]["pressure_drop"] < 4.5
    assert net["empty"]["flow_rate"] == pytest.approx(2e-10, rel=1e-9)
    assert 0.5 < net["realizations"][0]["permeability_ratio"] <= 1.0
    for name in ("permeability.png", "throats_clogged.png", "clog_map.png"):
        assert (out / name).stat().st_size > 1000
        assert summary["plots"][name.split(".")[0]] == name


def test_wall_distance_near_many_obstacles_is_the_brute_forces_bit_for_bit():
    """The wall distance measures only the obstacles near each point
    (geometry/nearest.py): the same bits as every edge measured, inside and out,
    for circular, square and hexagonal pillars in regular and random arrays."""
    from taichi_hsdem.geometry import walls as wl
    from taichi_hsdem.geometry.walls import _distance_to_pieces, _in_fluid
    rng = np.random.default_rng(5)
    for kind, extra in [("square", {}), ("random", dict(spread=0.2, min_throat=0.3, seed=2)),
                        ("staggered", dict(sides=6, shape="polygon")),
                        ("square", dict(sides=4, shape="polygon"))]:
        m = pillar_array(kind, rows=3, columns=4, diameter=1.0, spacing=1.75, inlet_length=2.0,
                         outlet_length=1.0, **extra)
        g = wl.from_polygon(m.outline, m.obstacles, constriction_x=m.x_exit)
        pts = np.concatenate([
            np.column_stack([rng.uniform(g.x_min - 1, g.x_max + 1, 20000),
                             rng.uniform(g.y_min - 1, g.y_max + 1, 20000)]),
            np.concatenate(m.obstacles),                            # on the vertices
            np.concatenate([(o + np.roll(o, -1, axis=0)) / 2 for o in m.obstacles])])
        w = g._walls
        brute = _distance_to_pieces(pts, w.piece_a, w.piece_u, w.piece_len)
        brute = np.where(_in_fluid(g, pts), brute, -brute)
        assert np.array_equal(wl.wall_distance(g, pts), brute), kind


@pytest.mark.parametrize("array", ["square", "staggered"])
def test_the_inlet_is_cut_off_by_a_whole_column_of_clogged_throats_and_nothing_less(array):
    m = pillar_array(array, rows=3, columns=4, diameter=1.0, spacing=2.0, inlet_length=2.0,
                     outlet_length=2.0)
    t = find_throats(m.outline, m.obstacles)
    x = np.round(t.midpoints[:, 0], 9)
    across = np.abs(t.end[:, 1] - t.start[:, 1]) > np.abs(t.end[:, 0] - t.start[:, 0])
    columns = sorted(set(x[across]))
    assert len(columns) == 4
    for c in columns:
        cut = across & (x == c)
        assert t.blocked(cut)
        for k in np.flatnonzero(cut):                  # one gap open: a way through
            assert not t.blocked(cut & (np.arange(len(t)) != k))
    # every throat along the flow clogged (the gaps between the columns' pillars):
    # the columns' gaps still lead through
    assert not t.blocked(~across)
    # every throat but one clogged: one gap alone is no way from inlet to outlet
    assert all(t.blocked(np.arange(len(t)) != k) for k in range(len(t)))
    # the time the inlet was cut off: when the last throat of the cut clogged
    t_clog = np.where(across & (x == columns[1]), 1.0 + np.arange(len(t)) * 0.01, np.nan)
    assert t.blocked_since(t_clog) == np.nanmax(t_clog)
    assert np.isnan(t.blocked_since(np.where(t_clog == np.nanmax(t_clog), np.nan, t_clog)))


def _column_jam(sim, column_x):
    """A disk at rest in the mouth of every gap of the column at ``column_x``
    (within a diameter of its throat, nearer to it than to any other): each of
    those throats is found blocked at rest."""
    gaps = [k for k in range(len(sim.throats))
            if abs(sim.throats.midpoints[k, 0] - column_x) < 1e-9
            and abs(sim.throats.end[k, 1] - sim.throats.start[k, 1]) > 0.5]
    xs = [[column_x - 0.95, sim.throats.midpoints[k, 1]] for k in gaps]
    return gaps, xs


def test_a_column_clogged_by_hand_clogs_the_realization_and_one_gap_less_does_not():
    column = 6.0 + 1.5 * 3.5
    many = dict(MICRO, particles=[dict(MICRO["particles"][0], count=4)])
    sim = make_sim(many)
    gaps, xs = _column_jam(sim, column)
    assert len(gaps) == 4
    sim.set_state([xs])
    result = sim.run()
    row = result.summary["realizations"][0]
    assert row["clogged"] and row["escapees"] == 0
    # formed when its throats did: at the first check (nothing ever passed them);
    # declared once it held for clog.window, where the run stops (run.stop_at_clog)
    dt_check = sim.check_every * sim.dt
    assert row["t_clog"] == pytest.approx(dt_check, rel=1e-9)
    window = MICRO["clog"]["window"]
    assert row["t_clog"] + window <= row["t_stop"] < row["t_clog"] + window + dt_check
    net = result.summary["network"]["realizations"][0]
    assert net["throats_clogged"] == 4 and net["t_cut"] == row["t_clog"]
    assert result.network[0][2:] == (4, 0) and result.network[-1][2:] == (4, 4)
    # three of the four gaps jammed (the disk of the fourth far upstream): open
    sim = make_sim(many)
    xs[-1] = [2.0, 0.0]
    sim.set_state([xs])
    result = sim.run()
    assert not result.summary["realizations"][0]["clogged"]
    assert result.summary["network"]["realizations"][0]["throats_clogged"] == 3


def test_the_video_draws_each_clogged_throat_red_and_nothing_else():
    from taichi_hsdem import render
    from taichi_hsdem.render.overlay import CLOG_RED
    from taichi_hsdem.render.video import VideoRecorder
    ok, reason = render.vulkan_status()
    if not ok:
        pytest.skip(f"no off-screen rendering here: {reason}")
    sim = make_sim(dict(MICRO, output={"width": 480}))
    x, y = 6.0 + 1.5 * 3.5, sim.throats.midpoints[_throat(sim, 11.25, -1.75), 1]
    k = _throat(sim, x, y)
    sim.set_state([[[x - 0.9, y - 0.52], [x - 0.9, y + 0.52], [2.0, 0.0]]])
    recorder = VideoRecorder(sim, None)
    drawn = []
    original = recorder.renderer.draw

    def draw(*args, **kw):
        drawn.append(original(*args, **kw))
        return drawn[-1]
    recorder.renderer.draw = draw
    sim.run(on_frame=recorder, frame_times=[0.0, MICRO["run"]["t_end"]])
    recorder.close(keep=False)
    red = np.all(drawn[-1][:recorder.renderer.domain_height] == CLOG_RED, axis=-1)
    assert not np.all(drawn[0] == CLOG_RED, axis=-1).any()      # nothing clogged at t = 0
    col, row = recorder.renderer.world_to_pixel(sim.throats.midpoints[k:k + 1])[0]
    assert red[int(row), int(col)]
    # the bar spans the gap, nothing else is red
    rows, cols = np.nonzero(red)
    ends = recorder.renderer.world_to_pixel(np.stack([sim.throats.start[k], sim.throats.end[k]]))
    assert cols.min() >= ends[:, 0].min() - 3 and cols.max() <= ends[:, 0].max() + 3
    assert rows.min() >= ends[:, 1].min() - 3 and rows.max() <= ends[:, 1].max() + 3


def test_obstacle_vertices_have_their_own_budget():
    from taichi_hsdem.limits import MAX_OBSTACLE_VERTICES
    geometry = dict(MICRO["geometry"], rows=40, columns=30, pillar_spacing=3.5)
    # 1200 pillars of 24 sides (28,800 vertices): within the budget (was 2000 in all)
    load_scene(dict(MICRO, geometry=geometry))
    with pytest.raises(SceneError, match=r"geometry.pillar_sides: 1200 pillars of 48 sides "
                                         r"have 57600 vertices, more than the 50000"):
        load_scene(dict(MICRO, geometry=dict(geometry, pillar_sides=48)))
    with pytest.raises(SceneError, match=r"geometry.rows: 50 x 41 = 2050 pillars, more than "
                                         r"the 2000 obstacles"):
        load_scene(dict(MICRO, geometry=dict(geometry, rows=50, columns=41, pillar_sides=8)))
    assert MAX_OBSTACLE_VERTICES == 50_000
    # a polygon scene: the obstacles' vertices together (each polygon within 2000)
    outline = [[0.0, -1.0], [40.0, -1.0], [40.0, 1.0], [0.0, 1.0]]
    rings = [[[1.0 + 1.2 * k + 0.4 * math.cos(a), 0.4 * math.sin(a)]
              for a in np.linspace(0, 2 * math.pi, 1800, endpoint=False)] for k in range(30)]
    poly = dict(MICRO, geometry={"kind": "polygon", "outline": outline, "obstacles": rings})
    with pytest.raises(SceneError, match=r"geometry.obstacles: the obstacles have 54000 "
                                         r"vertices, more than the 50000"):
        load_scene(poly)


def test_a_throat_first_reached_late_clogs_only_after_its_window_at_rest():
    """Issue 46, item 7: before any passage the throat's window counts from when
    particles came to rest there, not from t = 0: two disks put at rest across a
    gap at t = 0.3 (> clog.window) clog it a window later, with t_clog the first
    check that found them, not at once."""
    sim = make_sim(MICRO)
    x, y = 6.0 + 1.5 * 3.5, sim.throats.midpoints[_throat(sim, 11.25, -1.75), 1]
    k = _throat(sim, x, y)
    far = [[2.0, -1.0], [2.0, 1.0], [2.0, 0.0]]           # at rest, at no throat
    sim.set_state([far])
    window = MICRO["clog"]["window"]
    sim.run(stop=lambda: sim.t > 1.5 * window)
    assert not np.isfinite(sim.run_state.throat_static_t).any()
    t_put = sim.t
    sim.set_state([[[x - 0.9, y - 0.52], [x - 0.9, y + 0.52], [2.0, 0.0]]])
    sim.run(stop=lambda: sim.t > t_put + 0.5 * window)
    assert not np.isfinite(sim.run_state.throat_t_clog).any()     # held for half a window
    t_found = sim.run_state.throat_static_t[0, k]
    assert t_put < t_found <= t_put + sim.check_every * sim.dt * 1.000001
    sim.run()
    assert np.flatnonzero(np.isfinite(sim.run_state.throat_t_clog[0])).tolist() == [k]
    assert sim.run_state.throat_t_clog[0, k] == t_found
    assert sim.run_state.throat_passages.sum() == 0


def test_a_throat_left_without_a_passage_starts_its_rest_afresh():
    """Particles at rest at a throat that are moved away (no passage) leave no
    rest time behind: the next ones to stop there start the window again."""
    sim = make_sim(MICRO)
    x, y = 6.0 + 1.5 * 3.5, sim.throats.midpoints[_throat(sim, 11.25, -1.75), 1]
    k = _throat(sim, x, y)
    arch = [[x - 0.9, y - 0.52], [x - 0.9, y + 0.52], [2.0, 0.0]]
    sim.set_state([arch])
    window = MICRO["clog"]["window"]
    sim.run(stop=lambda: sim.t > 0.5 * window)
    assert np.isfinite(sim.run_state.throat_static_t[0, k])
    sim.set_state([[[2.0, -1.0], [2.0, 1.0], [2.0, 0.0]]])        # taken away
    sim.run(stop=lambda: sim.t > 0.75 * window)
    assert not np.isfinite(sim.run_state.throat_static_t[0, k])
    t_back = sim.t
    sim.set_state([arch])
    sim.run(stop=lambda: sim.t > 1.2 * window)    # a window after the first stop, not after the second
    assert not np.isfinite(sim.run_state.throat_t_clog).any()
    sim.run()
    assert sim.run_state.throat_t_clog[0, k] > t_back
