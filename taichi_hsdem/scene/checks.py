"""The checks of a scene that span keys (:func:`.load.load_scene` runs them once
every table is read): a polygon's simplicity, the fluid's boundary keys, each
geometry kind's consistency (a micromodel's pillar array is built to see that
it can be), a species' count, packing fraction and shape, and the scene-wide
ones (its name and output folder, packing fractions, names, the gap against
each particle's size). Each adds its problems to a :class:`.coerce.Problems`
and fills the defaults that depend on other keys."""

from __future__ import annotations

import math
import unicodedata
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.micromodel import CIRCLE_MIN_SIDES, MICROMODEL_KEYS, PillarError, array_of
from ..geometry.polygon import (cross, first_crossing, points_in_polygon, segments_intersect,
                                signed_area)
from ..limits import MAX_OBSTACLE_VERTICES, MAX_OUTLINE_VERTICES
from .coerce import BAD, Problems, good, show
from .keys import (AUTO, MAX_MAGNITUDE, MAX_PACKING_FRACTION, MIN_GAP_OVER_DEQ, MIN_MAGNITUDE,
                   SpeciesConfig, key_specs, shape_area, shape_vertex_count, vtk_indices)

#: The largest seed a realization may have: seeds are written as 64-bit integers.
MAX_SEED = 2 ** 63 - 1

# What Linux file systems take: bytes per file or folder name, and per path.
MAX_NAME_BYTES = 255
MAX_PATH_BYTES = 4095


def path_length_problem(path) -> str | None:
    """Why no file system takes folder ``path`` (a name or the whole path too long
    in bytes), or None."""
    parts = [part.encode("utf-8", "surrogatepass") for part in Path(path).parts]
    if any(len(part) > MAX_NAME_BYTES for part in parts) or sum(map(len, parts)) > MAX_PATH_BYTES:
        return (f"a folder name longer than {MAX_NAME_BYTES} bytes, or a path longer than "
                f"{MAX_PATH_BYTES}: no file system takes it")
    return None


def control_character(text: str) -> str | None:
    """The first control character in ``text`` (ESC, a newline, DEL, ...) spelt
    as U+XXXX, or None."""
    for c in text:
        if unicodedata.category(c) == "Cc":
            return f"U+{ord(c):04X}"
    return None

# ---------------------------------------------------------------- polygons

def _polygon_problem(points) -> str | None:
    """Why ``points`` is not a simple polygon of non-zero area, or None."""
    n = len(points)
    size = max(abs(c) for p in points for c in p)
    span = max(max(p[k] for p in points) - min(p[k] for p in points) for k in (0, 1))
    if size > MAX_MAGNITUDE or 0 < span < MIN_MAGNITUDE:
        return (f"its coordinates (up to {size:.3g} in size, {span:.3g} across) are outside "
                f"the magnitudes the simulator computes with ({MIN_MAGNITUDE:g} to "
                f"{MAX_MAGNITUDE:g}); use SI units, or dimensionless numbers of ordinary size")
    if points[0] == points[-1]:
        return ("the last vertex repeats the first; the polygon closes itself, leave "
                "the repeat out")
    for i in range(n):
        if points[i] == points[(i + 1) % n]:
            return f"vertices {i} and {(i + 1) % n} coincide"
    zero_area = signed_area(points) == 0.0
    if zero_area and _collinear(points):
        return "the polygon has zero area (its vertices lie on one line)"
    for i in range(n):
        # Adjacent edges share a vertex; they only fail by folding back on each other.
        a, b, c = points[i], points[(i + 1) % n], points[(i + 2) % n]
        if (cross(np.subtract(b, a), np.subtract(c, a)) == 0
                and (b[0] - a[0]) * (c[0] - b[0]) + (b[1] - a[1]) * (c[1] - b[1]) < 0):
            return f"the edges at vertex {(i + 1) % n} fold back on each other"
    pair = first_crossing(points)
    if pair is not None:
        return (f"edges {pair[0]} and {pair[1]} cross or touch: the polygon is "
                f"self-intersecting (not simple)")
    return "the polygon has zero area" if zero_area else None


def _collinear(points) -> bool:
    """Whether every vertex lies on the line through the first and the farthest."""
    p = np.asarray(points, dtype=float) - np.asarray(points[0], dtype=float)
    far = p[int(np.argmax(np.hypot(p[:, 0], p[:, 1])))]
    return bool(np.all(far[0] * p[:, 1] - far[1] * p[:, 0] == 0.0))


# --------------------------------------------------------------- cross-key checks

def _check_fluid(v: dict, out: Problems) -> None:
    if v["enabled"] is not True:
        return
    if v["viscosity"] is None:
        out.add("fluid.viscosity", "missing: required while fluid.enabled = true")
    if v["bc"] == "pressure":
        if v["p_in"] is None:
            out.add("fluid.p_in", 'missing: required for fluid.bc = "pressure"')
        elif good(v["p_in"], v["p_out"]) and v["p_in"] <= v["p_out"]:
            out.add("fluid.p_in", f"must exceed fluid.p_out ({show(v['p_out'])}) so "
                                  f"the fluid flows from inlet to outlet, got "
                                  f"{show(v['p_in'])}")
    if v["bc"] == "flow_rate" and v["flow_rate"] is None:
        out.add("fluid.flow_rate", 'missing: required for fluid.bc = "flow_rate"')


def _check_geometry(v: dict, out: Problems) -> None:
    kind = v["kind"]
    if kind == "hourglass":
        if v["neck_x"] is None and good(v["length"]):
            v["neck_x"] = v["length"] / 2.0
        if v["taper_length"] is None and good(v["width"]):
            v["taper_length"] = v["width"]
        if good(v["neck_width"], v["width"]) and v["neck_width"] >= v["width"]:
            out.add("geometry.neck_width", f"must be < geometry.width "
                    f"({show(v['width'])}), got {show(v['neck_width'])}")
        if good(v["neck_x"], v["length"]):
            if not 0.0 < v["neck_x"] < v["length"]:
                out.add("geometry.neck_x", f"must lie inside the channel, in (0, "
                        f"{show(v['length'])}), got {show(v['neck_x'])}")
            elif good(v["taper_length"]) and not (
                    v["taper_length"] <= v["neck_x"] <= v["length"] - v["taper_length"]):
                out.add("geometry.taper_length",
                        f"the tapers span [{show(v['neck_x'] - v['taper_length'])}, "
                        f"{show(v['neck_x'] + v['taper_length'])}] around neck_x, past "
                        f"the channel [0, {show(v['length'])}]; shorten taper_length "
                        "or move neck_x")
    elif kind == "converging":
        if v["width_out"] is None and good(v["width_in"]):
            v["width_out"] = v["width_in"]
        width, inlet, outlet = v["constriction_width"], v["width_in"], v["width_out"]
        if good(width, inlet) and width >= inlet:
            out.add("geometry.constriction_width", f"must be < geometry.width_in "
                    f"({show(inlet)}), got {show(width)}")
        if good(width, outlet) and outlet < width:
            out.add("geometry.width_out", f"must be >= geometry.constriction_width "
                    f"({show(width)}), got {show(outlet)}")
        if v["angle"] == 90 and v["constriction_length"] == 0:
            out.add("geometry.angle", "90 degrees (a sudden contraction) needs "
                    "geometry.constriction_length > 0: with no length the constriction is "
                    "a slit in a wall of no thickness")
    elif kind == "polygon":
        _check_polygon_outline(v, out)
    elif kind == "micromodel":
        _check_micromodel(v, out)


def _check_micromodel(v: dict, out: Problems) -> None:
    """The pillar array must fit its vertex budget and be buildable (the generator
    is cheap, so it is run here and its refusal reported on the key it names)."""
    given = [v[k] for k in MICROMODEL_KEYS if k != "min_throat"]   # min_throat may be None
    if not good(*given) or v["min_throat"] is BAD:
        return
    if v["pillar_shape"] == "circle" and v["pillar_sides"] < CIRCLE_MIN_SIDES:
        out.add("geometry.pillar_sides", f"{v['pillar_sides']} sides are too few to stand "
                f"for a circle (at least {CIRCLE_MIN_SIDES}); or set pillar_shape = "
                '"polygon"')
        return
    if v["diameter_spread"] > 0 and v["pillar_array"] != "random":
        out.add("geometry.diameter_spread", f"applies to pillar_array = \"random\" only "
                f"(the {v['pillar_array']} array's pillars are all pillar_diameter)")
        return
    # the resolved scene holds the pillars as geometry.obstacles: within its bounds
    pillars = v["rows"] * v["columns"]
    if pillars > MAX_OUTLINE_VERTICES:
        out.add("geometry.rows", f"{v['rows']} x {v['columns']} = {pillars} pillars, more "
                f"than the {MAX_OUTLINE_VERTICES} obstacles a scene may hold; use fewer "
                "rows or columns")
        return
    total = pillars * v["pillar_sides"]
    if v["pillar_sides"] > MAX_OUTLINE_VERTICES or total > MAX_OBSTACLE_VERTICES:
        out.add("geometry.pillar_sides", f"{pillars} pillars of {v['pillar_sides']} sides "
                f"have {total} vertices, more than the {MAX_OBSTACLE_VERTICES} a run can "
                f"afford (at most {MAX_OUTLINE_VERTICES} each); use fewer sides or pillars")
        return
    try:
        array_of(v)
    except PillarError as exc:
        out.add("geometry." + exc.key, exc.problem)


def _check_polygon_outline(v: dict, out: Problems) -> None:
    outline = v["outline"]
    if not good(outline):
        return
    problem = _polygon_problem(outline)
    if problem:
        out.add("geometry.outline", problem)
        return
    xs = [p[0] for p in outline]
    x_min, x_max = min(xs), max(xs)
    n = len(outline)
    for side, x, end in (("inlet", x_min, "least"), ("outlet", x_max, "greatest")):
        if not any(outline[i][0] == x == outline[(i + 1) % n][0] for i in range(n)):
            out.add("geometry.outline", f"has no edge on x = {show(x)}: the {side} is "
                    f"the outline's vertical edge at its {end} x")
    if good(v["constriction_x"]) and not x_min < v["constriction_x"] < x_max:
        out.add("geometry.constriction_x", f"must lie inside the outline, in "
                f"({show(x_min)}, {show(x_max)}), got {show(v['constriction_x'])}")
    if not good(v["obstacles"]):
        return
    # the outline is measured in full from every wall node, the obstacles only near
    # each one (geometry/nearest.py): a budget of their own (each polygon within
    # MAX_OUTLINE_VERTICES, its key's bound)
    total = sum(len(obstacle) for obstacle in v["obstacles"])
    if total > MAX_OBSTACLE_VERTICES:
        out.add("geometry.obstacles", f"the obstacles have {total} vertices, more than the "
                f"{MAX_OBSTACLE_VERTICES} a run can afford; simplify them or use fewer")
        return
    a, b = np.asarray(outline), np.roll(outline, -1, axis=0)
    for k, obstacle in enumerate(v["obstacles"]):
        key = f"geometry.obstacles[{k}]"
        problem = _polygon_problem(obstacle)
        if problem:
            out.add(key, problem)
            continue
        c, d = np.asarray(obstacle), np.roll(obstacle, -1, axis=0)
        if not points_in_polygon(obstacle, outline).all() or segments_intersect(
                a[:, None], b[:, None], c[None], d[None]).any():
            out.add(key, "must lie strictly inside geometry.outline")


def _check_species(v: dict, index: int, out: Problems) -> tuple[float, int] | None:
    """Fill the name, check count / packing_fraction and the shape; return
    (area, vertex count) when the shape is valid."""
    where = f"particles[{index}]"
    if v["name"] is None:
        v["name"] = f"species{index}"
    if good(v["positions"]):
        n = len(v["positions"])
        if v["packing_fraction"] is not None:
            out.add(f"{where}.packing_fraction", "positions are given too: give one of "
                                                 "count, packing_fraction and positions")
        elif v["count"] is not None and v["count"] != n:
            out.add(f"{where}.count", f"{v['count']} differs from the {n} positions given")
        else:
            v["count"] = n
    elif v["count"] is None and v["packing_fraction"] is None:
        out.add(f"{where}.count", "missing: give exactly one of count and "
                                  "packing_fraction")
    elif v["count"] is not None and v["packing_fraction"] is not None:
        out.add(f"{where}.packing_fraction", "count is given too: give exactly one of "
                                             "count and packing_fraction")
    shape = v["shape"]
    if not good(shape) or not all(good(v[name]) for name, spec in
                                   key_specs(SpeciesConfig).items() if shape in spec.only):
        return None
    if shape == "polygon":
        problem = _polygon_problem(v["vertices"])
        if problem:
            out.add(f"{where}.vertices", problem)
            return None
    vertices = shape_vertex_count(shape, v)
    if good(v["nodes"]) and v["nodes"] != AUTO and v["nodes"] < vertices:
        out.add(f"{where}.nodes", f"must be at least the {vertices} vertices of the "
                                  f"{shape.replace('_', ' ')}, got {v['nodes']}")
    return shape_area(shape, v), vertices


def _check_scene(scene: dict, species: dict[int, dict], shapes: dict[int, Any],
                 stem: str, out: Problems) -> None:
    """Checks and defaults that span sections; ``species`` and ``shapes`` are keyed
    by the species' index."""
    run, fluid, output, clog = (scene[k] for k in ("run", "fluid", "output", "clog"))
    if scene["name"] is None:
        scene["name"] = stem
    name = scene["name"]
    if good(name) and (name.strip() in ("", ".", "..")
                        or any(c in name for c in "/\\\0")):
        out.add("name", f"must be a non-empty folder name without / or \\, got "
                        f"{show(name)}")
    elif good(name) and control_character(name) is not None:
        out.add("name", f"holds the control character {control_character(name)}; it "
                        f"names the output folder and is printed, give printable text, "
                        f"got {show(name)}")
    elif good(name) and len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        out.add("name", f"is {len(name.encode('utf-8', 'surrogatepass'))} bytes long; it "
                        f"names the default output folder runs/<name>, and a file system "
                        f"takes at most {MAX_NAME_BYTES} bytes per folder name")
    elif output["dir"] is None and good(name):
        output["dir"] = f"runs/{name}"
    if good(output["dir"]) and (not output["dir"].strip() or "\0" in output["dir"]):
        out.add("output.dir", f"must be a folder path, got {show(output['dir'])}")
    elif good(output["dir"]) and path_length_problem(output["dir"]):
        out.add("output.dir", path_length_problem(output["dir"]))
    if (good(run["seed"], run["realizations"])
            and run["seed"] + run["realizations"] - 1 > MAX_SEED):
        out.add("run.seed", f"must be at most {MAX_SEED - run['realizations'] + 1} (2^63 - "
                f"run.realizations): realization k's seed, run.seed + k, is kept as a "
                f"64-bit integer, got {run['seed']}")
    if good(run["t_end"]):
        if clog["window"] is None:
            clog["window"] = 0.1 * run["t_end"]
        if output["series_interval"] is None:
            output["series_interval"] = run["t_end"] / 200.0
    if good(output["width"]) and output["width"] % 2:
        out.add("output.width", f"must be even (H.264 with yuv420p), got "
                                f"{output['width']}")
    if (good(output["video_realization"], run["realizations"])
            and output["video_realization"] >= run["realizations"]):
        out.add("output.video_realization",
                f"must be < run.realizations ({run['realizations']}), got "
                f"{output['video_realization']}")
    if good(output["vtk_realizations"], run["realizations"], output["video_realization"]):
        try:
            vtk_indices(output["vtk_realizations"], run["realizations"],
                        output["video_realization"])
        except ValueError as exc:
            out.add("output.vtk_realizations", str(exc))
    contact = scene["contact"]
    if (good(contact["overlap_target"], contact["overlap_limit"])
            and contact["overlap_limit"] <= contact["overlap_target"]):
        out.add("contact.overlap_limit", f"must exceed contact.overlap_target "
                f"({show(contact['overlap_target'])}), got "
                f"{show(contact['overlap_limit'])}")

    fractions = [s["packing_fraction"] for s in species.values()
                 if good(s["packing_fraction"])]
    if len(fractions) > 1 and sum(fractions) >= MAX_PACKING_FRACTION:
        out.add("particles", f"the packing fractions sum to {sum(fractions):.6g}; "
                             f"it must be < {MAX_PACKING_FRACTION}")
    seen: dict[str, int] = {}
    for k, s in species.items():
        if good(s["name"]) and control_character(s["name"]) is not None:
            out.add(f"particles[{k}].name", f"holds the control character "
                    f"{control_character(s['name'])}; give printable text, got "
                    f"{show(s['name'])}")
        if good(s["name"]):
            if s["name"] in seen:
                out.add(f"particles[{k}].name", f"{show(s['name'])} already names "
                                                f"particles[{seen[s['name']]}]")
            seen.setdefault(s["name"], k)
    gap = fluid["gap"]
    for k, shape in shapes.items():
        if shape is None or not good(gap):
            continue
        d_eq = math.sqrt(4.0 * shape[0] / math.pi)
        if gap <= MIN_GAP_OVER_DEQ * d_eq:
            out.add("fluid.gap", f"must be > (2/3) d_eq = {MIN_GAP_OVER_DEQ * d_eq:.6g} "
                    f"of particles[{k}] ({species[k]['name']!s}, d_eq = {d_eq:.6g}) "
                    f"for the Kozeny-Carman porosity inside it, got {show(gap)}")
