"""The clogging-arch analysis (tools/arches.py) against configurations built by hand,
whose gaps, contacts and arches are known exactly."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem.geometry.shapes import circle, rectangle, regular_polygon, square
from taichi_hsdem.geometry.walls import converging, wall_distance
from taichi_hsdem.studies import arches

ROOT = Path(__file__).resolve().parents[1]
EPS = 1e-4


def test_gap_between_outlines_is_their_distance_or_minus_the_deepest_vertex():
    sq = square(1.0)
    assert arches.pair_gap(sq, [0, 0], 0.0, sq, [1.2, 0], 0.0) == pytest.approx(0.2, abs=1e-12)
    assert arches.pair_gap(sq, [0, 0], 0.0, sq, [0.95, 0], 0.0) == pytest.approx(-0.05, abs=1e-12)
    # a corner towards a face: the half-diagonal reaches sqrt(2)/2 from the centre
    x = 0.5 + math.sqrt(0.5) + 0.1
    assert arches.pair_gap(sq, [0, 0], 0.0, sq, [x, 0], math.pi / 4) == pytest.approx(0.1, abs=1e-12)
    # a disk against a face, in either order, and two disks
    d = circle(1.0)
    assert arches.pair_gap(d, [1.3, 0.2], 0.0, sq, [0, 0], 0.0) == pytest.approx(0.3, abs=1e-12)
    assert arches.pair_gap(sq, [0, 0], 0.0, d, [1.3, 0.2], 0.0) == pytest.approx(0.3, abs=1e-12)
    assert arches.pair_gap(d, [0, 0], 0.0, d, [0.9, 0], 0.0) == pytest.approx(-0.1, abs=1e-12)
    # two rods crossed at their centres: no vertex of either inside the other, and
    # yet they overlap by the rod's width (the shorter way out of the cross)
    rod = rectangle(1.0, 0.1)
    assert arches.pair_gap(rod, [0, 0], 0.0, rod, [0, 0], math.pi / 2) == \
        pytest.approx(-0.55, abs=1e-12)


def test_face_to_face_and_vertex_contacts_are_told_apart():
    sq = square(1.0)
    tol = 0.01
    assert arches.pair_kind(sq, [0, 0], 0.0, sq, [1 - EPS, 0.3], 0.0, tol) == "face"
    # one turned 0.3 degrees: its face's ends within 0.0026 of the other's, a face;
    # turned 3 degrees, they stand 0.026 off it (more than tol): only a corner touches
    c = 0.5 + 0.5 * math.cos(math.radians(0.3)) + 0.5 * math.sin(math.radians(0.3)) - EPS
    assert arches.pair_kind(sq, [0, 0], 0.0, sq, [c, 0.0], math.radians(0.3), tol) == "face"
    c = 0.5 + 0.5 * math.cos(math.radians(3)) + 0.5 * math.sin(math.radians(3)) - EPS
    assert arches.pair_gap(sq, [0, 0], 0.0, sq, [c, 0.0], math.radians(3)) < 0
    assert arches.pair_kind(sq, [0, 0], 0.0, sq, [c, 0.0], math.radians(3), tol) == "vertex"
    x = 0.5 + math.sqrt(0.5) - EPS
    assert arches.pair_kind(sq, [0, 0], 0.0, sq, [x, 0], math.pi / 4, tol) == "vertex"
    # faces that meet only at a corner (shifted by almost a side) are not face-to-face
    assert arches.pair_kind(sq, [0, 0], 0.0, sq, [1 - EPS, 0.9], 0.0, tol) == "vertex"
    # pressed deeper than tol, still face to face; and either way round
    assert arches.pair_kind(sq, [0, 0], 0.0, sq, [0.994, 0.3], 0.0, 0.005) == "face"
    slab = rectangle(4.0, 0.5)
    c = [0.3, 0.25 + 0.5 - EPS + 0.5 * math.sin(math.radians(0.5))]
    for args in ((slab, [0, 0], 0.0, sq, c, math.radians(0.5)),
                 (sq, c, math.radians(0.5), slab, [0, 0], 0.0)):
        assert arches.pair_gap(*args) < 0
        assert arches.pair_kind(*args, tol) == "face"
    hexa = regular_polygon(6, 1.0)            # vertex 0 on +x: flat faces up and down
    h = math.sqrt(3) / 2                        # width across the flats
    assert arches.pair_kind(hexa, [0, 0], 0.0, hexa, [0.2, h - EPS], 0.0, tol) == "face"
    assert arches.pair_kind(circle(1.0), [0, 0], 0.0, sq, [1.0 - EPS, 0], 0.0, tol) == "curved"


def _channel():
    # the shipped polygons scene's channel, scaled to d_b = 1: W = 1.2, 45 degrees
    return converging(10.0, 20.0, 1.2, 5.0, angle=45.0)


def test_a_square_flat_on_the_wall_is_a_face_contact_and_on_its_corner_a_vertex():
    g = _channel()
    sides = arches.Sides(g)
    sq = square(0.5)
    y0 = g.y_min
    flat = [3.0, y0 + 0.25 - EPS]
    corner = [3.0, y0 + math.sqrt(2) * 0.25 - EPS]
    assert arches.Sides(g).gap(sq, flat, 0.0, 0) == pytest.approx(-EPS, abs=1e-12)
    assert sides.gap(sq, flat, 0.0, 1) > 9
    assert arches.wall_kind(sides, 0, sq, flat, 0.0, 0.01) == "face"
    assert arches.wall_kind(sides, 0, sq, corner, math.pi / 4, 0.01) == "vertex"
    # a face on a long wall, tilted 0.5 degrees, still lies along it (its ends
    # 0.0022 off the wall); tilted 3 degrees, only its corner touches
    for tilt, kind in ((0.5, "face"), (3.0, "vertex")):
        a = math.radians(tilt)
        low = [3.0, y0 + 0.25 * (math.cos(a) + math.sin(a)) - EPS]
        assert sides.gap(sq, low, a, 0) == pytest.approx(-EPS, abs=1e-12)
        assert arches.wall_kind(sides, 0, sq, low, a, 0.01) == kind, tilt
    # on the upper wall, and on the 45 degree taper (a diamond's face lies along it)
    assert arches.wall_kind(sides, 1, sq, [3.0, g.y_max - 0.25 + EPS], 0.0, 0.01) == "face"
    neck = g.constriction_x0
    # lower taper: y - x = -0.6 - neck; a diamond's centre half a side off that line
    c = np.array([neck - 1.0, -0.6 - 1.0]) + (0.25 - EPS) * np.array([-1.0, 1.0]) / math.sqrt(2)
    assert sides.gap(sq, c, math.pi / 4, 0) == pytest.approx(-EPS, abs=1e-9)
    assert arches.wall_kind(sides, 0, sq, c, math.pi / 4, 0.01) == "face"


def test_the_side_walls_are_the_outline_runs_between_inlet_and_outlet():
    # an upper wall with a notch dipping below the centre line is still the upper wall
    from taichi_hsdem.geometry.walls import from_polygon
    g = from_polygon([[0, 0], [10, 0], [10, 3], [6, 3], [6, 0.5], [4, 0.5], [4, 3], [0, 3]])
    sides = arches.Sides(g)
    assert len(sides.segments[0]) == 1 and len(sides.segments[1]) == 5
    assert [[6.0, 0.5], [4.0, 0.5]] in sides.segments[1].tolist()
    assert sides.segments[0].tolist() == [[[0.0, 0.0], [10.0, 0.0]]]
    for s, n in zip(sides.segments, sides.normals):     # into the fluid
        probe = s.mean(axis=1) + 1e-3 * n
        assert (wall_distance(g, probe) > 0).all()


def _disk_arch():
    """Two disks of diameter 1 on the two 45 degree tapers of a W = 1.2 neck,
    touching each other on the centre line: each centre is r from its taper
    line ``|y| - x = -0.6 - x_neck`` and r from the centre line, so
    ``x_neck - x_c = r sqrt(2) + r - 0.6``; pressed by EPS into both (r - EPS
    for r), and a third disk far upstream."""
    g = _channel()
    r = 0.5 - EPS
    xc = g.constriction_x0 - (r * math.sqrt(2) + r - 0.6)
    x = np.array([[xc, -r], [xc, r], [xc - 3.0, 0.0]])
    return g, x


def test_two_disks_wedged_across_the_neck_are_its_arch():
    g, x = _disk_arch()
    sides = arches.Sides(g)
    shapes = [circle(1.0)]
    species = [0, 0, 0]
    theta = [0.0, 0.0, 0.0]
    arch = arches.find_arch(shapes, x, theta, [True] * 3, species, sides, g.constriction_x0, 1.0)
    assert arch["particles"] == [0, 1]
    assert arch["pairs"] == ["curved"] and arch["walls"] == ["curved", "curved"]
    assert sides.gap(shapes[0], x[0], 0.0, 0) == pytest.approx(-EPS, abs=1e-12)
    assert sides.gap(shapes[0], x[1], 0.0, 1) == pytest.approx(-EPS, abs=1e-12)
    # one of them gone (escaped), or the two pulled apart by more than the tolerance
    assert arches.find_arch(shapes, x, theta, [True, False, True], species, sides,
                            g.constriction_x0, 1.0) is None
    apart = x.copy()
    apart[1, 1] += 0.02
    assert arches.find_arch(shapes, apart, theta, [True] * 3, species, sides,
                            g.constriction_x0, 1.0) is None
    assert arches.find_arch(shapes, apart, theta, [True] * 3, species, sides,
                            g.constriction_x0, 1.0, tol=0.03)["particles"] == [0, 1]


def _figure_folder(tmp_path, finals=True):
    """A figure folder by hand: one circle point of the shipped polygons scene with
    one clogged realization, the disk arch scaled to d_b = 140 um."""
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import resolve
    scene = ROOT / "scenes" / "polygons.toml"
    ov = {"particles.shape": "circle", "particles.n_vertices": None,
          "particles.diameter": 140e-6}
    g = resolve(load_scene(scene).with_values({**ov, "run.realizations": 1})).geometry
    ref, x = _disk_arch()
    d = 140e-6
    x = (x - [ref.constriction_x0, 0.0]) * d + [g.constriction_x0, 0.0]
    (tmp_path / "points").mkdir()
    (tmp_path / "figure.json").write_text(json.dumps({
        "scene": str(scene), "base_overrides": [],
        "points": [{"label": "circle", "values": {"shape": "circle"}, "overrides": ov}]}))
    data = {"rows": [{"seed": 7, "escapees": 3, "clogged": True, "t_clog": 1.0, "t_stop": 1.5,
                      "status": "ok", "reason": None},
                     {"seed": 8, "escapees": 9, "clogged": False, "t_clog": None,
                      "t_stop": 5.0, "status": "ok", "reason": None}]}
    if finals:
        state = {"x": x.tolist(), "theta": [0.0] * 3, "alive": [True] * 3, "species": [0] * 3}
        data["finals"] = {"7": state, "8": state}
    (tmp_path / "points" / "circle.json").write_text(json.dumps(data))
    return tmp_path


def test_the_command_reads_a_figure_folder_and_writes_the_arches(tmp_path, capsys):
    folder = _figure_folder(tmp_path)
    assert arches.main([str(folder), "--examples", "2"]) == 0
    out = capsys.readouterr().out
    assert "circle: 1 clogged, arch found in 1; sizes 2: 1" in out
    rows = (folder / "arches.csv").read_text().splitlines()
    assert rows[0].startswith("label,seed,escapees,arch_found,arch_size")
    assert rows[1].split(",")[:5] == ["circle", "7", "3", "True", "2"]
    assert len(rows) == 2                       # the unclogged realization has no arch
    assert (folder / "arches.png").stat().st_size > 0


def test_the_command_refuses_what_it_cannot_read(tmp_path, capsys):
    assert arches.main([str(tmp_path)]) == 2
    assert "no readable figure.json" in capsys.readouterr().err
    folder = _figure_folder(tmp_path, finals=False)
    assert arches.main([str(folder)]) == 2
    assert "no final states" in capsys.readouterr().err
    assert arches.main([str(folder), "--tol", "0"]) == 2
    assert "--tol must be in (0, 1)" in capsys.readouterr().err
