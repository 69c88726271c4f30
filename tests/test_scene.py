"""Scene loading, validation, overrides and the TOML round trip."""

import copy
import dataclasses
import math
import re

import pytest

from taichi_hsdem.scene import (
    ClogConfig, ContactConfig, DampingConfig, FeedConfig, FluidConfig, GeometryConfig,
    OutputConfig, RunConfig, Scene, SceneError, SpeciesConfig, load_scene,
    scene_to_toml,
)

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

SCENE_TOML = """\
description = "two species through a converging constriction"

[run]
t_end = 2
realizations = 3
seed = 7

[fluid]
viscosity = 1e-3
gap = 4e-5
bc = "flow_rate"
flow_rate = 1e-12

[geometry]
kind = "converging"
width_in = 4e-4
length_in = 1e-3
constriction_width = 5e-5
length_out = 5e-4

[[particles]]
shape = "circle"
diameter = 3e-5
density = 1050
packing_fraction = 0.2

[[particles]]
name = "squares"
shape = "square"
side = 2.5e-5
density = 1050
count = 10
friction = 0.4

[output]
video = true
video_realization = 2
"""


def minimal() -> dict:
    """The smallest valid scene, as a dict."""
    return {
        "run": {"t_end": 1.0},
        "fluid": {"viscosity": 1.0, "gap": 1.0, "p_in": 200.0, "p_out": 100.0},
        "geometry": {"kind": "hourglass", "length": 10.0, "width": 4.0,
                     "neck_width": 1.5},
        "particles": [{"shape": "circle", "diameter": 1.0, "density": 1.0,
                       "count": 24}],
    }


def problems_of(source, overrides=()) -> list[str]:
    with pytest.raises(SceneError) as caught:
        load_scene(source, overrides)
    assert str(caught.value) == "\n".join(caught.value.problems)
    return caught.value.problems


def write(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def with_changes(changes: dict, base=None) -> dict:
    """``minimal()`` (or ``base``) with dotted keys set; a None value deletes the key."""
    data = copy.deepcopy(base or minimal())
    for path, value in changes.items():
        *parents, key = path.split(".")
        table = data
        for part in parents:
            table = table[int(part)] if part.isdigit() else table.setdefault(part, {})
        if key.isdigit():
            table[int(key)] = value
        elif value is None:
            table.pop(key, None)
        else:
            table[key] = value
    return data


# ------------------------------------------------------------ valid scenes

def test_file_scene_values_and_defaults(tmp_path):
    path = write(tmp_path, SCENE_TOML, "two_species.toml")
    scene = load_scene(path)
    assert scene.source == str(path)
    assert scene.name == "two_species"
    assert scene.units == "SI"
    assert scene.run.t_end == 2.0 and isinstance(scene.run.t_end, float)
    assert scene.run.dt == "auto" and scene.run.dt_safety == 0.15
    assert scene.run.arch == "cpu" and scene.run.precision == "f64"
    assert scene.fluid.cell_size == "auto" and scene.fluid.p_out == 0.0
    assert scene.fluid.p_in is None
    assert scene.fluid.update_interval == "auto" and scene.fluid.solver_tol == 1e-6
    geometry = scene.geometry
    assert geometry.angle == 45.0 and geometry.constriction_length == 0.0
    assert geometry.width_out == 4e-4  # default: width_in
    assert geometry.escape_offset is None and geometry.wall_cell_size == "auto"
    assert geometry.length is None and geometry.outline is None
    first, squares = scene.particles
    assert first.name == "species0" and squares.name == "squares"
    assert first.friction == 0.25 and squares.friction == 0.4
    assert first.kn == "auto" and first.ks == "auto" and first.nodes == "auto"
    assert first.restitution == 0.5 and first.side is None
    assert squares.count == 10 and squares.packing_fraction is None
    assert first.d_eq() == pytest.approx(3e-5)
    assert squares.d_eq() == pytest.approx(math.sqrt(4 * 2.5e-5 ** 2 / math.pi))
    assert scene.contact.normalize_by_nodes is True
    assert scene.damping.xi == "auto" and scene.feed.mode == "count"
    assert scene.feed.region is None and scene.feed.inlet is None
    assert scene.clog.window == pytest.approx(0.2)  # 0.1 t_end
    assert scene.output.series_interval == pytest.approx(0.01)  # t_end / 200
    assert scene.output.dir == "runs/two_species"
    assert scene.output.width == 960 and scene.output.frames == 150


def test_dict_source_and_hourglass_defaults():
    scene = load_scene(minimal())
    assert scene.source == "<dict>" and scene.name == "scene"
    assert scene.output.dir == "runs/scene"
    assert scene.geometry.neck_x == 5.0 and scene.geometry.taper_length == 4.0
    assert scene.geometry.width_in is None
    hash(scene)  # immutable all the way down


def test_dict_source_is_not_modified():
    data = minimal()
    before = copy.deepcopy(data)
    load_scene(data, ["run.t_end=5", "particles.friction=0.1", "clog.window=1"])
    assert data == before


def test_scene_is_frozen():
    scene = load_scene(minimal())
    with pytest.raises(dataclasses.FrozenInstanceError):
        scene.run.t_end = 3.0


def test_round_trip_through_toml(tmp_path):
    scene = load_scene(write(tmp_path, SCENE_TOML))
    text = scene_to_toml(scene)
    again = load_scene(tomllib.loads(text))
    assert again == dataclasses.replace(scene, source="<dict>")
    # and through a file, with a key whose value TOML must escape
    odd = scene.with_values({"description": 'quote " backslash \\ tab\t ü \x7f',
                             "particles.1.kn": 0.1 + 0.2})
    path = write(tmp_path, scene_to_toml(odd), "resolved.toml")
    assert dataclasses.replace(load_scene(path), source=odd.source) == odd
    assert load_scene(path).particles[1].kn == 0.1 + 0.2  # repr: exact


def test_round_trip_polygon_geometry_and_shapes():
    data = with_changes({
        "geometry": {"kind": "polygon",
                     "outline": [[0, 0], [10, 0], [10, 4], [0, 4]],
                     "obstacles": [[[4, 1], [6, 1], [5, 3]]],
                     "constriction_x": 5.5},
        "feed.region": [0.5, 3],
        "particles.0": {"shape": "polygon", "density": 2.0, "count": 3,
                        "vertices": [[0, 0], [0.8, 0], [0.8, 0.8], [0.4, 0.3],
                                     [0, 0.8]]},
    })
    data["particles"].append({"shape": "rectangle", "width": 0.9, "height": 0.6,
                              "density": 1, "count": 1})
    data["particles"].append({"shape": "regular_polygon", "diameter": 1.0,
                              "n_vertices": 5, "density": 1, "count": 1})
    scene = load_scene(data)
    assert scene.geometry.outline == ((0.0, 0.0), (10.0, 0.0), (10.0, 4.0), (0.0, 4.0))
    assert scene.geometry.obstacles == (((4.0, 1.0), (6.0, 1.0), (5.0, 3.0)),)
    assert scene.feed.region == (0.5, 3.0)
    assert scene.geometry.neck_x is None  # an hourglass key
    assert scene.particles[0].area() == pytest.approx(0.64 - 0.5 * 0.8 * 0.5)
    assert scene.particles[1].area() == pytest.approx(0.54)
    assert scene.particles[2].area() == pytest.approx(
        2.5 * 0.25 * math.sin(2 * math.pi / 5))
    again = load_scene(tomllib.loads(scene_to_toml(scene)))
    assert again == scene


def test_to_dict_is_plain():
    scene = load_scene(with_changes({"feed.region": [1, 2]}))
    data = scene.to_dict()
    assert data["feed"]["region"] == [1.0, 2.0]
    assert data["particles"][0]["diameter"] == 1.0
    assert "source" not in data and "width_in" not in data["geometry"]
    assert load_scene(data) == scene


def test_replace_and_with_values():
    scene = load_scene(with_changes({"particles": [
        {"shape": "circle", "diameter": 1.0, "density": 1.0, "count": 2},
        {"shape": "circle", "diameter": 0.8, "density": 1.0, "count": 2}]}))
    resolved = scene.with_values({"fluid.cell_size": 0.125, "particles.0.kn": 3,
                                  "particles.ks": 1.5, "run.dt": 1e-4,
                                  "feed.region": (0.5, 2.0)})
    assert resolved.fluid.cell_size == 0.125
    assert [s.kn for s in resolved.particles] == [3.0, "auto"]
    assert [s.ks for s in resolved.particles] == [1.5, 1.5]
    assert resolved.feed.region == (0.5, 2.0) and resolved.run.dt == 1e-4
    assert resolved.name == scene.name and resolved.source == scene.source
    assert scene.fluid.cell_size == "auto"  # the original is untouched
    assert scene.replace(name="other").name == "other"
    assert scene.run.replace(t_end=9.0).t_end == 9.0
    # None removes a key: a packing fraction recorded as the count it gave
    fraction = load_scene(with_changes({"particles.0.count": None,
                                        "particles.0.packing_fraction": 0.3}))
    counted = fraction.with_values({"particles.0.count": 17,
                                    "particles.0.packing_fraction": None,
                                    "clog.window": None, "run.t_end": 4.0})
    assert counted.particles[0].count == 17
    assert counted.particles[0].packing_fraction is None
    assert counted.clog.window == pytest.approx(0.4)  # recomputed from the new t_end
    with pytest.raises(SceneError, match=r"count is given too"):
        fraction.with_values({"particles.0.count": 17})
    with pytest.raises(SceneError, match=r"fluid\.cell_size: must be > 0, got -1\.0"):
        scene.with_values({"fluid.cell_size": -1.0})
    with pytest.raises(SceneError, match=r"fluid\.cel_size: unknown key \(did you mean "
                                         r"'cell_size'\?\)"):
        scene.with_values({"fluid.cel_size": 1.0})


def test_int_accepted_for_float_and_auto_kept():
    scene = load_scene(with_changes({"run.dt": 0.001, "fluid.cell_size": "auto",
                                     "particles.0.kn": 5}))
    assert scene.particles[0].kn == 5.0 and isinstance(scene.particles[0].kn, float)
    assert scene.run.dt == 0.001 and scene.fluid.cell_size == "auto"


def test_fluid_disabled_needs_no_viscosity_or_pressure():
    scene = load_scene(with_changes({"fluid": {"enabled": False, "gap": 1.0}}))
    assert scene.fluid.enabled is False and scene.fluid.viscosity is None


def test_unicode_values_are_kept():
    scene = load_scene(with_changes({"name": "Ünïcødé ✓", "description": "粒子 ∅",
                                     "particles.0.name": "kreis ○"}))
    assert scene.output.dir == "runs/Ünïcødé ✓"
    assert scene.particles[0].name == "kreis ○"
    assert load_scene(tomllib.loads(scene_to_toml(scene))) == scene


# --------------------------------------------------------------- overrides

def test_overrides_are_typed(tmp_path):
    path = write(tmp_path, SCENE_TOML)
    scene = load_scene(path, ["run.t_end=0.5", "fluid.bc=pressure", "fluid.p_in=3",
                              'run.dt="auto"', "run.stop_at_clog=false",
                              "feed.region=[1e-4, 5e-4]", "description=hello world",
                              "fluid.cell_size=auto", "run.arch = gpu"])
    assert scene.run.t_end == 0.5 and scene.clog.window == pytest.approx(0.05)
    assert scene.fluid.bc == "pressure" and scene.fluid.p_in == 3.0
    assert scene.run.dt == "auto" and scene.run.stop_at_clog is False
    assert scene.feed.region == (1e-4, 5e-4)
    assert scene.description == "hello world" and scene.run.arch == "gpu"


def test_override_per_species_and_all_species(tmp_path):
    path = write(tmp_path, SCENE_TOML)
    one = load_scene(path, ["particles.1.friction=0.9"])
    assert [s.friction for s in one.particles] == [0.25, 0.9]
    bracket = load_scene(path, ["particles[0].restitution=0.8"])
    assert [s.restitution for s in bracket.particles] == [0.8, 0.5]
    every = load_scene(path, ["particles.friction=0.4", "particles.nodes=12"])
    assert [s.friction for s in every.particles] == [0.4, 0.4]
    assert [s.nodes for s in every.particles] == [12, 12]


def test_override_problems_name_the_override(tmp_path):
    path = write(tmp_path, SCENE_TOML)
    problems = problems_of(path, ["fluid.flowrate=1", "run.t_end=abc",
                                  "particles.friction=-1", "particles.7.nodes=9",
                                  "noequals", "particles.colour=red", "sun.x=1",
                                  "run.seed=1.5", "fluid=3"])
    # keys that do not exist first, then the values, in the scene's order
    assert problems == [
        f"{path} (--set fluid.flowrate=1): fluid.flowrate: unknown key (did you mean "
        "'flow_rate'?)",
        f"{path} (--set particles.7.nodes=9): particles.7.nodes: no species 7; the "
        "scene has 2 (indices 0 to 1)",
        f"{path} (--set noequals): expected section.key=value",
        f"{path} (--set particles.colour=red): particles.colour: unknown key",
        f"{path} (--set sun.x=1): sun.x: unknown section or key (did you mean 'run'?)",
        f"{path} (--set fluid=3): fluid: expected fluid.key",
        f'{path} (--set run.t_end=abc): run.t_end: expected a number > 0, got '
        'string "abc"',
        f"{path} (--set run.seed=1.5): run.seed: expected an integer >= 0, got "
        "number 1.5",
        f"{path} (--set particles.friction=-1): particles[0].friction: must be >= 0, "
        "got -1.0",
        f"{path} (--set particles.friction=-1): particles[1].friction: must be >= 0, "
        "got -1.0",
    ]


def test_bad_override_does_not_hide_file_problems(tmp_path):
    path = write(tmp_path, SCENE_TOML.replace("seed = 7", "seed = -7"))
    problems = problems_of(path, ["run.t_ed=1"])
    assert any("(--set run.t_ed=1): run.t_ed: unknown key (did you mean 't_end'?)"
               in p for p in problems)
    assert f"{path}: run.seed: must be >= 0, got -7" in problems


# ---------------------------------------------------------- bad input: files

def test_missing_file(tmp_path):
    path = tmp_path / "nope.toml"
    assert problems_of(path) == [f"{path}: file not found"]


def test_malformed_toml_names_file_and_line(tmp_path):
    path = write(tmp_path, "[run]\nt_end = 1\n[fluid\ngap = 1\n")
    (problem,) = problems_of(path)
    assert problem.startswith(f"{path}: invalid TOML: ")
    assert "line 3" in problem and "Traceback" not in problem


def test_duplicate_key_is_malformed(tmp_path):
    path = write(tmp_path, "[run]\nt_end = 1\nt_end = 2\n")
    (problem,) = problems_of(path)
    assert problem.startswith(f"{path}: invalid TOML: ") and "line 3" in problem


def test_not_utf8(tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes('description = "caf\xe9"\n'.encode("latin-1"))
    assert problems_of(path) == [f"{path}: not UTF-8 text (byte 18)"]


def test_empty_file_reports_every_required_key(tmp_path):
    path = write(tmp_path, "")
    assert problems_of(path) == [
        f"{path}: run.t_end: missing: required",
        f"{path}: fluid.gap: missing: required",
        f"{path}: geometry.kind: missing: required",
        f"{path}: fluid.viscosity: missing: required while fluid.enabled = true",
        f'{path}: fluid.p_in: missing: required for fluid.bc = "pressure"',
        f"{path}: particles: missing: add at least one [[particles]] table",
    ]


def test_empty_particle_list_and_wrong_table_types():
    assert problems_of(with_changes({"particles": []})) == [
        "<dict>: particles: missing: add at least one [[particles]] table"]
    problems = problems_of(with_changes({"particles": {"shape": "circle"},
                                         "run": [1, 2], "clog": "fast"}))
    assert problems == [
        "<dict>: run: expected a table [run], got array [1, 2]",
        '<dict>: clog: expected a table [clog], got string "fast"',
        "<dict>: particles: expected an array of tables [[particles]], got a table",
    ]


# --------------------------------------------------------- bad input: keys

def test_unknown_keys_suggest_the_closest(tmp_path):
    text = SCENE_TOML.replace("[run]", "t_end = 4\nvidoe = 1\n[run]\nt_edn = 1") \
        .replace("friction = 0.4", "frition = 0.4\nviscosity = 1")
    path = write(tmp_path, text)
    problems = problems_of(path)
    assert f"{path}: t_end: unknown section or key; it belongs in [run]" in problems
    assert (f"{path}: vidoe: unknown section or key (did you mean 'video'?)"
            not in problems)  # 'video' is an [output] key, not a top-level one
    assert any(p.startswith(f"{path}: vidoe: unknown section or key") for p in problems)
    assert f"{path}: run.t_edn: unknown key (did you mean 't_end'?)" in problems
    assert (f"{path}: particles[1].frition: unknown key (did you mean 'friction'?)"
            in problems)
    assert (f"{path}: particles[1].viscosity: unknown key here; it belongs in [fluid]"
            in problems)
    assert len(problems) == 5


@pytest.mark.parametrize("key, value, message", [
    ("run.t_end", 0, "run.t_end: must be > 0, got 0.0"),
    ("run.t_end", True, "run.t_end: expected a number > 0, got boolean true"),
    ("run.t_end", "1", 'run.t_end: expected a number > 0, got string "1"'),
    ("run.t_end", float("nan"), "run.t_end: expected a finite number, got nan"),
    ("run.t_end", float("inf"), "run.t_end: expected a finite number, got inf"),
    ("run.t_end", 10 ** 400, "run.t_end: expected a finite number, got inf"),
    ("run.dt", "fast", 'run.dt: expected a number > 0 or "auto", got string "fast"'),
    ("run.dt_safety", 1.5, "run.dt_safety: must be in (0, 1], got 1.5"),
    ("run.realizations", 0, "run.realizations: must be >= 1, got 0"),
    ("run.realizations", 2.0, "run.realizations: expected an integer >= 1, got "
                              "number 2.0"),
    ("run.arch", "tpu", "run.arch: must be one of 'cpu', 'gpu', 'auto', 'cuda', 'vulkan', "
                        "'metal', 'opengl', got \"tpu\" (did you mean 'gpu'?)"),
    ("run.precision", "f16", "run.precision: must be one of 'f64', 'f32', got "
                                 "\"f16\" (did you mean 'f64'?)"),
    ("run.stop_at_clog", 1, "run.stop_at_clog: expected true or false, got integer 1"),
    ("fluid.resolve_fraction", 1.0, "fluid.resolve_fraction: must be in [0, 1), got "
                                    "1.0"),
    ("fluid.solver_tol", 0.1, "fluid.solver_tol: must be in (0, 0.01], got 0.1"),
    ("fluid.pressure_sampling", "nearest", "fluid.pressure_sampling: must be one of "
                                           "'bilinear', 'cell', got \"nearest\""),
    ("fluid.update_interval", 0, "fluid.update_interval: must be >= 1, got 0"),
    ("fluid.bc", "flowrate", "fluid.bc: must be one of 'pressure', 'flow_rate', got "
                             "\"flowrate\" (did you mean 'flow_rate'?)"),
    ("geometry", {"kind": "converging", "width_in": 4.0, "length_in": 5.0,
                  "angle": 95, "constriction_width": 1.6, "length_out": 3.0},
     "geometry.angle: must be in (0, 90], got 95.0"),
    ("geometry.angle", 30, "geometry.angle: not used by kind 'hourglass'"),
    ("geometry.kind", "funnel", "geometry.kind: must be one of 'hourglass', "
                                "'converging', 'polygon', 'micromodel', got \"funnel\""),
    ("geometry.escape_offset", -1, "geometry.escape_offset: must be >= 0, got -1.0"),
    ("particles.0", {"shape": "circle", "diameter": 1.0, "density": 1.0,
                     "packing_fraction": 0.6}, "particles[0].packing_fraction: must be in "
                                          "(0, 0.6), got 0.6"),
    ("particles.0.restitution", 0, "particles[0].restitution: must be in (0, 1], got "
                                   "0.0"),
    ("particles.0.nodes", 2, "particles[0].nodes: must be in [3, 20000], got 2"),
    ("particles.0.ks", -1, "particles[0].ks: must be >= 0, got -1.0"),
    ("particles.0.shape", "blob", "particles[0].shape: must be one of 'circle', "
                                  "'square', 'rectangle', 'regular_polygon', "
                                  "'polygon', got \"blob\""),
    ("particles.0.friction", "≈0.3", 'particles[0].friction: expected a number >= 0, '
                                     'got string "≈0.3"'),
    ("particles.0.name", "\ud800", "particles[0].name: not valid Unicode text: "
                                   "'\\ud800'"),
    ("particles.0.count", -1, "particles[0].count: must be >= 0, got -1"),
    ("contact.overlap_target", 0.3, "contact.overlap_target: must be in (0, 0.2], got "
                                    "0.3"),
    ("contact.normalize_by_nodes", "yes", 'contact.normalize_by_nodes: expected true '
                                          'or false, got string "yes"'),
    ("damping.xi", -0.5, 'damping.xi: must be >= 0, got -0.5'),
    ("feed.mode", "refill", "feed.mode: must be one of 'count', 'none', got "
                            "\"refill\""),
    ("feed.region", [3, 1], "feed.region: expected [x0, x1] with x0 < x1, got [3, 1]"),
    ("feed.inlet", [0, "a"], 'feed.inlet: expected [x0, x1] with two finite numbers, '
                             'got array [0, "a"]'),
    ("clog.speed_fraction", 1, "clog.speed_fraction: must be in (0, 1), got 1.0"),
    ("clog.window", 0, "clog.window: must be > 0, got 0.0"),
    ("output.width", 962.0, "output.width: expected an integer in [64, 7680], got "
                            "number 962.0"),
    ("output.width", 32, "output.width: must be in [64, 7680], got 32"),
    ("output.width", 961, "output.width: must be even (H.264 with yuv420p), got 961"),
    ("output.frames", 1, "output.frames: must be in [2, 1000000], got 1"),
    ("output.fps", 0, "output.fps: must be >= 1, got 0"),
    ("output.dir", 5, "output.dir: expected a string, got integer 5"),
    ("units", "imperial", "units: must be one of 'SI', 'dimensionless', got "
                          "\"imperial\""),
    ("name", "a/b", 'name: must be a non-empty folder name without / or \\, got "a/b"'),
    ("description", {"a": 1}, "description: expected a string, got a table"),
])
def test_bad_value(key, value, message):
    problems = problems_of(with_changes({key: value}))
    assert problems == [f"<dict>: {message}"]


def test_bad_value_messages_are_exact():
    assert problems_of(with_changes({"run.t_end": -2})) == [
        "<dict>: run.t_end: must be > 0, got -2.0"]


def test_many_problems_reported_together(tmp_path):
    text = SCENE_TOML.replace("t_end = 2", "t_end = -2") \
        .replace("viscosity = 1e-3", 'viscosity = "water"') \
        .replace("density = 1050\ncount = 10", "density = 0\ncount = 10") \
        .replace("video_realization = 2", "video_realization = 3")
    problems = problems_of(write(tmp_path, text, "many.toml"))
    path = tmp_path / "many.toml"
    assert problems == [
        f"{path}: run.t_end: must be > 0, got -2.0",
        f'{path}: fluid.viscosity: expected a number > 0, got string "water"',
        f"{path}: particles[1].density: must be > 0, got 0.0",
        f"{path}: output.video_realization: must be < run.realizations (3), got 3",
    ]


# --------------------------------------------------- inconsistent combinations

def test_pressure_bc_without_p_in():
    assert problems_of(with_changes({"fluid.p_in": None})) == [
        '<dict>: fluid.p_in: missing: required for fluid.bc = "pressure"']


def test_pressure_bc_with_p_in_not_above_p_out():
    assert problems_of(with_changes({"fluid.p_in": 100})) == [
        "<dict>: fluid.p_in: must exceed fluid.p_out (100.0) so the fluid flows from "
        "inlet to outlet, got 100.0"]


def test_flow_rate_bc_without_flow_rate_and_with_p_in():
    assert problems_of(with_changes({"fluid.bc": "flow_rate"})) == [
        '<dict>: fluid.flow_rate: missing: required for fluid.bc = "flow_rate"']
    # p_in left over from a pressure scene is allowed (so --set fluid.bc works)
    scene = load_scene(with_changes({"fluid.bc": "flow_rate", "fluid.flow_rate": 2.0}))
    assert scene.fluid.flow_rate == 2.0


def test_viscosity_required_when_enabled():
    assert problems_of(with_changes({"fluid.viscosity": None})) == [
        "<dict>: fluid.viscosity: missing: required while fluid.enabled = true"]


def test_species_count_and_packing_fraction():
    assert problems_of(with_changes({"particles.0.packing_fraction": 0.2})) == [
        "<dict>: particles[0].packing_fraction: count is given too: give exactly one "
        "of count and packing_fraction"]
    assert problems_of(with_changes({"particles.0.count": None})) == [
        "<dict>: particles[0].count: missing: give exactly one of count and "
        "packing_fraction"]


def test_packing_fractions_sum():
    species = {"shape": "circle", "diameter": 1.0, "density": 1.0,
               "packing_fraction": 0.3}
    assert problems_of(with_changes({"particles": [species, species]})) == [
        "<dict>: particles: the packing fractions sum to 0.6; it must be < 0.6"]
    below = dict(species, packing_fraction=0.29, name="b")
    assert len(load_scene(with_changes({"particles": [species, below]})).particles) == 2


@pytest.mark.parametrize("species, message", [
    ({"shape": "circle", "side": 1.0},
     ["particles[0].diameter: missing: required for shape 'circle'",
      "particles[0].side: not used by shape 'circle'"]),
    ({"shape": "square", "diameter": 1.0, "side": 1.0},
     ["particles[0].diameter: not used by shape 'square'"]),
    ({"shape": "rectangle", "width": 1.0},
     ["particles[0].height: missing: required for shape 'rectangle'"]),
    ({"shape": "regular_polygon", "diameter": 1.0},
     ["particles[0].n_vertices: missing: required for shape 'regular_polygon'"]),
    ({"shape": "regular_polygon", "diameter": 1.0, "n_vertices": 2},
     ["particles[0].n_vertices: must be in [3, 1000], got 2"]),
    ({"shape": "polygon", "vertices": [[0, 0], [1, 0]]},
     ["particles[0].vertices: needs at least 3 vertices, got 2"]),
    ({"shape": "polygon", "vertices": [[0, 0], [1, 0], [1, "x"]]},
     ['particles[0].vertices[2]: expected [x, y] with two finite numbers, got array '
      '[1, "x"]']),
    ({"shape": "polygon", "vertices": [[0, 0], [1, 1], [1, 0], [0, 1]]},
     ["particles[0].vertices: edges 0 and 2 cross or touch: the polygon is "
      "self-intersecting (not simple)"]),
    ({"shape": "polygon", "vertices": [[0, 0], [2, 0], [2, 1], [0, 2], [2, 3]]},
     ["particles[0].vertices: edges 2 and 4 cross or touch: the polygon is "
      "self-intersecting (not simple)"]),
    ({"shape": "polygon", "vertices": [[0, 0], [1, 0], [1, 1], [0, 0]]},
     ["particles[0].vertices: the last vertex repeats the first; the polygon closes "
      "itself, leave the repeat out"]),
    ({"shape": "square", "side": 1.0, "nodes": 3},
     ["particles[0].nodes: must be at least the 4 vertices of the square, got 3"]),
    ({"shape": "regular_polygon", "diameter": 1.0, "n_vertices": 8, "nodes": 6},
     ["particles[0].nodes: must be at least the 8 vertices of the regular polygon, "
      "got 6"]),
    ({"shape": "circle"},
     ["particles[0].diameter: missing: required for shape 'circle'"]),
    ({"side": 1.0},
     ["particles[0].shape: missing: required"]),
])
def test_shape_keys(species, message):
    table = dict({"density": 1.0, "count": 1}, **species)
    assert problems_of(with_changes({"particles": [table]})) == [
        f"<dict>: {m}" for m in message]


def test_gap_against_equivalent_diameter():
    # square of side s: d_eq = s sqrt(4/pi); gap = 1 must exceed (2/3) d_eq
    side = 1.4
    d_eq = side * math.sqrt(4 / math.pi)
    assert 1.0 <= (2 / 3) * d_eq
    problems = problems_of(with_changes({"particles.0": {
        "shape": "square", "side": side, "density": 1.0, "count": 1}}))
    assert problems == [
        f"<dict>: fluid.gap: must be > (2/3) d_eq = {(2 / 3) * d_eq:.6g} of "
        f"particles[0] (species0, d_eq = {d_eq:.6g}) for the Kozeny-Carman porosity "
        "inside it, got 1.0"]
    # a circle of diameter 1.5 sits exactly on the limit and is refused; 1.49 passes
    assert problems_of(with_changes({"particles.0.diameter": 1.5}))[0].startswith(
        "<dict>: fluid.gap: must be > (2/3) d_eq = 1 of particles[0]")
    assert load_scene(with_changes({"particles.0.diameter": 1.49}))


def test_gap_uses_regular_polygon_area():
    # hexagon, R = 1: A = 3 sin(60 deg) * 2 / 2 ... d_eq = sqrt(4A/pi) = 1.8187
    area = 3 * math.sin(math.pi / 3)
    d_eq = math.sqrt(4 * area / math.pi)
    hexagon = {"shape": "regular_polygon", "diameter": 2.0, "n_vertices": 6,
               "density": 1.0, "count": 1}
    ok = with_changes({"particles.0": hexagon, "fluid.gap": (2 / 3) * d_eq * 1.001})
    assert load_scene(ok).particles[0].d_eq() == pytest.approx(d_eq)
    bad = with_changes({"particles.0": hexagon, "fluid.gap": (2 / 3) * d_eq * 0.999})
    assert problems_of(bad)[0].startswith("<dict>: fluid.gap: must be > (2/3) d_eq")


def test_converging_widths():
    converging = {"kind": "converging", "width_in": 4.0, "length_in": 5.0,
                  "constriction_width": 4.0, "length_out": 3.0, "width_out": 2.0}
    problems = problems_of(with_changes({"geometry": converging}))
    assert problems == [
        "<dict>: geometry.constriction_width: must be < geometry.width_in (4.0), got "
        "4.0",
        "<dict>: geometry.width_out: must be >= geometry.constriction_width (4.0), got "
        "2.0",
    ]


def test_hourglass_neck_and_tapers():
    assert problems_of(with_changes({"geometry.neck_width": 4.0})) == [
        "<dict>: geometry.neck_width: must be < geometry.width (4.0), got 4.0"]
    assert problems_of(with_changes({"geometry.neck_x": 12.0})) == [
        "<dict>: geometry.neck_x: must lie inside the channel, in (0, 10.0), got 12.0"]
    assert problems_of(with_changes({"geometry.taper_length": 6.0})) == [
        "<dict>: geometry.taper_length: the tapers span [-1.0, 11.0] around neck_x, "
        "past the channel [0, 10.0]; shorten taper_length or move neck_x"]


def test_geometry_keys_of_another_kind():
    problems = problems_of(with_changes({"geometry.width_in": 3.0,
                                         "geometry.outline": [[0, 0], [1, 0], [1, 1]]}))
    assert problems == [
        "<dict>: geometry.width_in: not used by kind 'hourglass'",
        "<dict>: geometry.outline: not used by kind 'hourglass'",
    ]


def test_polygon_outline_checks():
    base = {"kind": "polygon", "outline": [[0, 0], [10, 0], [10, 4], [0, 4]]}
    assert load_scene(with_changes({"geometry": base})).geometry.obstacles == ()
    slanted = dict(base, outline=[[0, 0], [10, 0], [9, 4], [0, 4]])
    assert problems_of(with_changes({"geometry": slanted})) == [
        "<dict>: geometry.outline: has no edge on x = 10.0: the outlet is the "
        "outline's vertical edge at its greatest x"]
    outside = dict(base, obstacles=[[[4, 1], [6, 1], [5, 5]]], constriction_x=10)
    assert problems_of(with_changes({"geometry": outside})) == [
        "<dict>: geometry.constriction_x: must lie inside the outline, in (0.0, 10.0), "
        "got 10.0",
        "<dict>: geometry.obstacles[0]: must lie strictly inside geometry.outline",
    ]
    assert problems_of(with_changes({"geometry": {"kind": "polygon"}})) == [
        "<dict>: geometry.outline: missing: required for kind 'polygon'"]


def test_video_realization_and_overlap_limits():
    problems = problems_of(with_changes({"output.video_realization": 1,
                                         "contact.overlap_limit": 0.01}))
    assert problems == [
        "<dict>: output.video_realization: must be < run.realizations (1), got 1",
        "<dict>: contact.overlap_limit: must exceed contact.overlap_target (0.02), "
        "got 0.01",
    ]


def test_duplicate_species_names():
    species = {"shape": "circle", "diameter": 1.0, "density": 1.0, "count": 1,
               "name": "disk"}
    assert problems_of(with_changes({"particles": [species, species]})) == [
        '<dict>: particles[1].name: "disk" already names particles[0]']


def test_config_fields_and_their_units():
    assert {f.name for f in dataclasses.fields(ClogConfig)} == {"window",
                                                                "speed_fraction"}
    assert "escape_offset" in {f.name for f in dataclasses.fields(GeometryConfig)}
    assert "ls_spacing" in {f.name for f in dataclasses.fields(SpeciesConfig)}
    assert [f.name for f in dataclasses.fields(Scene)] == [
        "name", "description", "units", "run", "fluid", "geometry", "particles",
        "contact", "damping", "feed", "clog", "output", "source"]
    # every real-valued key states its unit (or that it is dimensionless)
    unit = re.compile(r"\bm\b|m\^|\bs\b|Pa|kg|N/m|1/s|degrees|dimensionless|fraction of")
    for cls in (RunConfig, FluidConfig, GeometryConfig, SpeciesConfig, ContactConfig,
                DampingConfig, FeedConfig, ClogConfig, OutputConfig):
        for f in dataclasses.fields(cls):
            spec = f.metadata["spec"]
            assert f.name in cls.__doc__
            if spec.kind in ("float", "points", "polygons", "interval"):
                assert unit.search(spec.doc), (cls.__name__, f.name, spec.doc)


def test_folder_instead_of_file(tmp_path):
    assert problems_of(tmp_path) == [f"{tmp_path}: is a folder, not a scene file"]


def test_single_override_string_and_one_line_per_problem(tmp_path):
    path = write(tmp_path, SCENE_TOML)
    assert load_scene(path, "run.seed=3").run.seed == 3
    (problem,) = problems_of(path, ["run.t_end=1\nx = 2"])
    assert "\n" not in problem
    assert problem == (f"{path} (--set run.t_end=1\\nx = 2): run.t_end: expected a "
                       'number > 0, got string "1\\nx = 2"')


def test_nonsense_values():
    data = with_changes({
        "run.t_end": [], "run.seed": 2 ** 70 * -1, "fluid.gap": {"x": 1},
        "particles.0.diameter": "∞", "particles.0.nodes": 40.5, "output.video": "🎬"})
    data["geometry"]["length"] = None  # a dict can hold what TOML cannot
    problems = problems_of(data)
    assert problems == [
        "<dict>: run.t_end: expected a number > 0, got array []",
        "<dict>: run.seed: must be >= 0, got -1180591620717411303424",
        "<dict>: fluid.gap: expected a number > 0, got a table",
        "<dict>: geometry.length: expected a number > 0, got None",
        '<dict>: output.video: expected true or false, got string "🎬"',
        '<dict>: particles[0].diameter: expected a number > 0, got string "∞"',
        "<dict>: particles[0].nodes: expected an integer in [3, 20000] or \"auto\", got number 40.5",
    ]
