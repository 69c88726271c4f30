"""Scene: the typed, validated, immutable description of one run, read from TOML.

Every key of ``docs/scene.md`` is one field of one frozen dataclass below; its unit
and allowed range live in the field's ``metadata["spec"]`` and drive the
validation, so the documentation of a key and its check cannot drift apart.

``load_scene`` reads a TOML file (or a dict of the same structure), applies
``section.key=value`` overrides, checks everything and either returns a `Scene` or
raises one `SceneError` listing every problem, each as ``"FILE: key: problem"``.

Defaults that depend only on other keys of the scene are filled in here
(``clog.window = 0.1 * t_end``, ``geometry.width_out = width_in``, ...). Defaults
that need the built geometry or the particle shapes (``geometry.escape_offset``,
``feed.region``, every ``"auto"``) stay ``None`` / ``"auto"``; the simulator
resolves them and records the values with `Scene.with_values`.

A species with ``diameter_spread`` > 0 is replaced here, once every table is
checked, by its five size classes (`size_class_factors`, `split_count`): the
`Scene` and everything after it (resolve, the outputs, ``scene.resolved.toml``)
see ordinary species of spread 0.

Examples
--------
>>> scene = load_scene({
...     "run": {"t_end": 1.0},
...     "fluid": {"viscosity": 1e-3, "gap": 2e-5, "p_in": 100.0},
...     "geometry": {"kind": "hourglass", "length": 1e-3, "width": 2e-4,
...                  "neck_width": 5e-5},
...     "particles": [{"shape": "circle", "diameter": 2e-5, "density": 1050.0,
...                    "count": 40}],
... }, overrides=["particles.friction=0.4"])
>>> scene.particles[0].friction, scene.clog.window
(0.4, 0.1)
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from statistics import NormalDist
from typing import Any, Iterable, Mapping

import numpy as np

from ..geometry.micromodel import CIRCLE_MIN_SIDES, MICROMODEL_KEYS, PillarError, array_of
from ..geometry.polygon import (cross, first_crossing, points_in_polygon, segments_intersect,
                                signed_area)
from .coerce import (
    BAD,
    MISSING,
    Problems,
    describe,
    good,
    read_table,
    show,
    suggest,
    unknown_key_message,
)
from .keys import (
    AUTO,
    MAX_PACKING_FRACTION,
    MIN_GAP_OVER_DEQ,
    SECTIONS,
    ClogConfig,
    Config,
    ContactConfig,
    DampingConfig,
    FeedConfig,
    FluidConfig,
    GeometryConfig,
    OutputConfig,
    RunConfig,
    SceneError,
    SpeciesConfig,
    document,
    key_specs,
    keyfield,
    shape_area,
    shape_vertex_count,
    vtk_indices,
)
from ..limits import MAX_OBSTACLE_VERTICES, MAX_OUTLINE_VERTICES
from .toml import parse_override_value, read_toml

__all__ = ["Scene", "load_scene"]


@document
@dataclass(frozen=True)
class Scene(Config):
    """A validated scene; build it with `load_scene`.

    ``particles`` holds one `SpeciesConfig` per ``[[particles]]`` table and
    ``source`` the file it was read from (``"<dict>"`` for a dict).
    """

    name: str = keyfield("str", "names the default output folder (default: file stem)")
    description: str = keyfield("str", "free text", "")
    units: str = keyfield("choice", 'how numbers are read: SI, or "dimensionless" (same '
                         "formulas, numbers as given)", "SI",
                         choices=("SI", "dimensionless"))
    run: RunConfig = field(default_factory=RunConfig)
    fluid: FluidConfig = field(default_factory=FluidConfig)
    geometry: GeometryConfig = field(default_factory=GeometryConfig)
    particles: tuple[SpeciesConfig, ...] = ()
    contact: ContactConfig = field(default_factory=ContactConfig)
    damping: DampingConfig = field(default_factory=DampingConfig)
    feed: FeedConfig = field(default_factory=FeedConfig)
    clog: ClogConfig = field(default_factory=ClogConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    source: str = "<dict>"

    def to_dict(self) -> dict[str, Any]:
        """The scene as plain nested dicts and lists (no ``source``, no ``None``)."""
        out = super().to_dict()
        for section in SECTIONS:
            out[section] = getattr(self, section).to_dict()
        out["particles"] = [species.to_dict() for species in self.particles]
        return {key: out[key] for key in _TOP_ORDER}

    def with_values(self, values: Mapping[str, Any]) -> "Scene":
        """A re-validated copy with dotted keys set, e.g. ``{"fluid.cell_size": 1e-6,
        "particles.0.kn": 3.0}`` (``"particles.kn"`` sets every species). A value of
        ``None`` removes the key, so that it takes its default again or, e.g.,
        ``{"particles.0.count": 120, "particles.0.packing_fraction": None}`` records
        what a packing fraction resolved to.

        Raises `SceneError` if a key is unknown or a value is out of range. Defaults
        filled from other keys (``output.dir``, ``clog.window``, ...) keep their
        values; remove them too to have them recomputed.
        """
        raw = self.to_dict()
        origins: dict[str, str] = {}
        problems: list[str] = []
        label = f"{self.source} (with_values)"
        for path, value in values.items():
            _set_path(raw, str(path), value, label, origins, problems)
        if problems:
            raise SceneError(problems)
        return _build_scene(raw, self.source, self.name, origins)


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

_TOP_ORDER = ("name", "description", "units", "run", "fluid", "geometry", "particles",
              "contact", "damping", "feed", "clog", "output")


# ---------------------------------------------------------------- polygons

def _polygon_problem(points) -> str | None:
    """Why ``points`` is not a simple polygon of non-zero area, or None."""
    n = len(points)
    if points[0] == points[-1]:
        return ("the last vertex repeats the first; the polygon closes itself, leave "
                "the repeat out")
    for i in range(n):
        if points[i] == points[(i + 1) % n]:
            return f"vertices {i} and {(i + 1) % n} coincide"
    if signed_area(points) == 0.0:
        return "the polygon has zero area"
    for i in range(n):
        # Adjacent edges share a vertex; they only fail by folding back on each other.
        a, b, c = points[i], points[(i + 1) % n], points[(i + 2) % n]
        if (cross(np.subtract(b, a), np.subtract(c, a)) == 0
                and (b[0] - a[0]) * (c[0] - b[0]) + (b[1] - a[1]) * (c[1] - b[1]) < 0):
            return f"the edges at vertex {(i + 1) % n} fold back on each other"
    pair = first_crossing(points)
    if pair is not None:
        return f"edges {pair[0]} and {pair[1]} cross or touch: the polygon is not simple"
    return None


# ------------------------------------------------------------------- type checks


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


def _build_scene(raw: Any, label: str, stem: str, origins: Mapping[str, str]) -> Scene:
    out = Problems(label, origins)
    if not isinstance(raw, Mapping):
        raise SceneError(f"{label}: expected a table of sections, got {describe(raw)}")
    known = set(key_specs(Scene)) | set(SECTIONS) | {"particles"}
    for key in raw:
        if str(key) not in known:
            out.add(str(key), unknown_key_message(str(key), known, ""))
    scene = read_table(Scene, {k: v for k, v in raw.items() if k in key_specs(Scene)},
                        "", out)
    for section, cls in SECTIONS.items():
        discriminator = "kind" if cls is GeometryConfig else None
        scene[section] = read_table(cls, raw.get(section, MISSING), section, out,
                                     discriminator)
    _check_fluid(scene["fluid"], out)
    _check_geometry(scene["geometry"], out)

    raw_species = raw.get("particles", MISSING)
    species: dict[int, dict] = {}
    shapes: dict[int, Any] = {}
    if raw_species is MISSING or (isinstance(raw_species, (list, tuple))
                                   and not raw_species):
        out.add("particles", "missing: add at least one [[particles]] table")
    elif not isinstance(raw_species, (list, tuple)):
        out.add("particles", f"expected an array of tables [[particles]], got "
                             f"{describe(raw_species)}")
    else:
        for k, table in enumerate(raw_species):
            values = read_table(SpeciesConfig, table, f"particles[{k}]", out, "shape")
            if isinstance(table, Mapping):
                species[k] = values
                shapes[k] = _check_species(values, k, out)
    _check_scene(scene, species, shapes, stem, out)
    classes = _expand_size_classes(species, shapes, scene["fluid"]["gap"], out)
    if out.lines:
        raise SceneError(out.lines)
    sections = {name: cls(**scene[name]) for name, cls in SECTIONS.items()}
    return Scene(**{name: scene[name] for name in key_specs(Scene)}, **sections,
                 particles=tuple(SpeciesConfig(**s) for s in classes), source=label)


# ------------------------------------------------------------ size classes

#: A species with ``diameter_spread`` > 0 becomes this many size classes.
SIZE_CLASSES = 5
#: The keys a size class scales: a shape's lengths (``vertices`` point by point).
_SIZE_KEYS = ("diameter", "side", "width", "height", "vertices")
#: The order in which the classes take the remainder of a count (middle first).
_REMAINDER_ORDER = (2, 1, 3, 0, 4)


def size_class_factors(spread: float) -> tuple[float, ...]:
    """The ``SIZE_CLASSES`` size factors ``1 + spread z_k`` of a species with
    ``diameter_spread = spread``, smallest first.

    ``z_k`` is the mean of a standard normal variable within the k-th of the
    ``SIZE_CLASSES`` intervals of equal probability, ``K (phi(a_k-1) - phi(a_k))``
    with ``a_k = Phi^-1(k / K)``, rescaled to unit standard deviation over the
    classes, so that the factors have mean 1 and standard deviation ``spread``.

    >>> [round(f, 6) for f in size_class_factors(0.1)]
    [0.852197, 0.943837, 1.0, 1.056163, 1.147803]
    """
    normal, k = NormalDist(), SIZE_CLASSES
    edges = [normal.inv_cdf(i / k) for i in range(1, k)]
    density = [0.0, *(normal.pdf(a) for a in edges), 0.0]
    z = [k * (density[i] - density[i + 1]) for i in range(k)]
    z = [(z[i] - z[k - 1 - i]) / 2.0 for i in range(k)]   # exactly antisymmetric: mean 0
    scale = math.sqrt(sum(t * t for t in z) / k)
    return tuple(1.0 + spread * t / scale for t in z)


def split_count(count: int) -> list[int]:
    """``count`` particles over the ``SIZE_CLASSES`` classes, as evenly as possible,
    the remainder to the middle classes first.

    >>> split_count(12), split_count(9)
    ([2, 3, 3, 2, 2], [2, 2, 2, 2, 1])
    """
    counts = [count // SIZE_CLASSES] * SIZE_CLASSES
    for i in _REMAINDER_ORDER[:count % SIZE_CLASSES]:
        counts[i] += 1
    return counts


def _expand_size_classes(species: dict[int, dict], shapes: dict[int, Any], gap: Any,
                         out: Problems) -> list[dict]:
    """The species of the run: each one with ``diameter_spread`` > 0 replaced by
    its ``SIZE_CLASSES`` size classes (``size_class_factors``), each checked as the
    species' own keys were; a class the checks refuse is reported on the spread."""
    classes: list[dict] = []
    for k, v in species.items():
        spread = v["diameter_spread"]
        if not good(spread) or spread == 0:
            classes.append(v)
            continue
        where = f"particles[{k}].diameter_spread"
        if good(v["positions"]):
            out.add(where, f"{show(spread)} splits the species into {SIZE_CLASSES} size "
                           "classes, which positions cannot say; give count or "
                           "packing_fraction instead")
            continue
        if good(v["count"]) and v["count"] < SIZE_CLASSES:
            out.add(where, f"{show(spread)} splits the species into {SIZE_CLASSES} size "
                           f"classes: count must be at least {SIZE_CLASSES}, got "
                           f"{v['count']}")
            continue
        if shapes.get(k) is None or any(value is BAD for value in v.values()) or not (
                good(v["count"]) or good(v["packing_fraction"])):
            continue        # reported already
        factors = size_class_factors(spread)
        if factors[0] <= 0.0:
            out.add(where, f"{show(spread)} gives the smallest class a size factor of "
                           f"{factors[0]:.6g}, no size at all; use a smaller spread")
            continue
        counts = split_count(v["count"]) if good(v["count"]) else None
        for j, factor in enumerate(factors):
            table = {key: value for key, value in v.items() if value is not None}
            for key in _SIZE_KEYS:
                if key in table:
                    table[key] = (tuple((factor * x, factor * y) for x, y in table[key])
                                  if key == "vertices" else factor * table[key])
            table.update(name=f"{v['name']}/{j + 1}", diameter_spread=0.0)
            if counts is not None:
                table["count"] = counts[j]
            else:
                table["packing_fraction"] = v["packing_fraction"] / SIZE_CLASSES
            # the species' own checks, on the class (an empty label: the lines are
            # reported on the spread that made them)
            scratch = Problems("", {})
            values = read_table(SpeciesConfig, table, "", scratch, "shape")
            shape = _check_species(values, k, scratch) if not scratch.lines else None
            if scratch.lines or shape is None:
                why = scratch.lines[0].removeprefix(": ") if scratch.lines else "its shape"
                out.add(where, f"{show(spread)} makes size class {table['name']} "
                               f"(size factor {factor:.6g}) invalid: {why}")
                break
            d_eq = math.sqrt(4.0 * shape[0] / math.pi)
            if good(gap) and gap <= MIN_GAP_OVER_DEQ * d_eq:
                out.add(where, f"{show(spread)} makes size class {table['name']} d_eq = "
                               f"{d_eq:.6g}, and fluid.gap ({show(gap)}) must exceed (2/3) "
                               f"d_eq = {MIN_GAP_OVER_DEQ * d_eq:.6g} for the Kozeny-Carman "
                               "porosity inside it; use a smaller spread or a wider gap")
                break
            classes.append(values)
    names: dict[str, int] = {}
    for k, v in species.items():
        if good(v["name"]):
            names.setdefault(v["name"], k)
    for k, v in species.items():
        if good(v["diameter_spread"]) and v["diameter_spread"] > 0 and good(v["name"]):
            for j in range(SIZE_CLASSES):
                name = f"{v['name']}/{j + 1}"
                if name in names:
                    out.add(f"particles[{k}].name", f"its size class {show(name)} "
                            f"(diameter_spread) is the name of particles[{names[name]}]")
                    break
    return classes


# -------------------------------------------------------------------- overrides

def _set_path(raw: dict, path: str, value: Any, origin: str,
              origins: dict[str, str], problems: list[str]) -> None:
    """Set dotted ``path`` in ``raw`` (``None``: remove the key), remembering
    ``origin`` for error messages."""
    path = re.sub(r"^particles\[(\d+)\]\.", r"particles.\1.", path.strip())
    parts = path.split(".")

    def fail(message: str) -> None:
        problems.append(f"{origin}: {path}: {message}")

    if not all(parts):
        return fail("malformed key; expected section.key")
    head = parts[0]
    if head == "particles":
        species = raw.get("particles")
        if len(parts) == 3 and parts[1].isdigit():
            indices, key = [int(parts[1])], parts[2]
        elif len(parts) == 2:
            indices, key = list(range(len(species))) if isinstance(
                species, list) else [], parts[1]
        else:
            return fail("expected particles.key or particles.K.key with K a species "
                        "index")
        specs = key_specs(SpeciesConfig)
        if key not in specs:
            return fail("unknown key" + suggest(key, specs))
        if not isinstance(species, list) or not species:
            return fail("the scene has no [[particles]] table to set it on")
        for k in indices:
            if k >= len(species):
                return fail(f"no species {k}; the scene has {len(species)} "
                            f"(indices 0 to {len(species) - 1})")
            if isinstance(species[k], dict):
                _assign(species[k], key, value)
                origins[f"particles[{k}].{key}"] = origin
        return None
    if head in SECTIONS:
        if len(parts) != 2:
            return fail(f"expected {head}.key" if len(parts) == 1 else "unknown key")
        specs = key_specs(SECTIONS[head])
        if parts[1] not in specs:
            return fail("unknown key" + suggest(parts[1], specs))
        section = raw.setdefault(head, {})
        if isinstance(section, dict):  # otherwise the table itself is reported
            _assign(section, parts[1], value)
            origins[path] = origin
        return None
    top = key_specs(Scene)
    if len(parts) == 1 and head in top:
        _assign(raw, head, value)
        origins[head] = origin
        return None
    return fail("unknown section or key"
                + suggest(head, list(top) + list(SECTIONS) + ["particles"]))


def _assign(table: dict, key: str, value: Any) -> None:
    if value is None:  # TOML has no null: None can only mean "leave the key out"
        table.pop(key, None)
    else:
        table[key] = value


def load_scene(source: str | Path | Mapping[str, Any],
               overrides: Iterable[str] = ()) -> Scene:
    """Read, override and validate a scene.

    Parameters
    ----------
    source : str, Path or dict
        A TOML scene file, or a dict of the same structure.
    overrides : iterable of str
        ``"section.key=value"`` strings; ``value`` is read as a TOML value, or as a
        plain string when it is not one. ``particles.K.key=v`` sets species ``K``,
        ``particles.key=v`` every species.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        With every problem found, one ``"FILE: key: problem"`` line each.

    Examples
    --------
    >>> load_scene("scenes/hourglass.toml", ["run.t_end=0.5"])  # doctest: +SKIP
    """
    if isinstance(source, Mapping):
        raw, label, stem = copy.deepcopy(dict(source)), "<dict>", "scene"
    elif isinstance(source, (str, Path)):
        path = Path(source)
        raw, label, stem = read_toml(path), str(path), path.stem
    else:
        raise TypeError(f"source must be a path or a dict, got {type(source).__name__}")
    if isinstance(overrides, str):
        overrides = [overrides]
    origins: dict[str, str] = {}
    problems: list[str] = []
    for text in overrides:
        origin = f"{label} (--set {text})"
        key, sep, value = str(text).partition("=")
        if not sep or not key.strip():
            problems.append(f"{origin}: expected section.key=value")
            continue
        _set_path(raw, key, parse_override_value(value.strip()), origin, origins,
                  problems)
    try:
        scene = _build_scene(raw, label, stem, origins)
    except SceneError as error:
        raise SceneError(problems + error.problems) from None
    except ArithmeticError as exc:      # a combination the checks did not foresee
        raise SceneError(problems + [f"{label}: the scene's numbers overflow or vanish in "
                                     f"its checks ({exc}); use values of ordinary size"]) from None
    if problems:
        raise SceneError(problems)
    return scene
