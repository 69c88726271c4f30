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
import dataclasses
import difflib
import math
import numbers
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

__all__ = [
    "SceneError", "RunConfig", "FluidConfig", "GeometryConfig", "SpeciesConfig",
    "ContactConfig", "DampingConfig", "FeedConfig", "ClogConfig", "OutputConfig",
    "Scene", "load_scene", "scene_to_toml",
]

AUTO = "auto"
#: Packing fractions of all species together must stay below this (docs/scene.md).
MAX_PACKING_FRACTION = 0.6
#: Kozeny-Carman inside a particle needs gap > this * d_eq (docs/scene.md, Conventions).
MIN_GAP_OVER_DEQ = 2.0 / 3.0


class SceneError(ValueError):
    """An invalid scene; ``problems`` lists each one as ``"FILE: key: problem"``."""

    def __init__(self, problems: str | Iterable[str]):
        problems = [problems] if isinstance(problems, str) else problems
        # One line per problem, even when a key or an override holds a newline.
        self.problems = [re.sub(r"[\x00-\x1f\x7f]",
                                lambda m: repr(m.group())[1:-1], p) for p in problems]
        super().__init__("\n".join(self.problems))

    def __str__(self) -> str:
        return "\n".join(self.problems)


# --------------------------------------------------------------------------- keys

@dataclass(frozen=True)
class _Spec:
    """What one scene key accepts."""

    kind: str  # "float", "int", "bool", "str", "choice", "points", "poses", "polygons", "interval"
    doc: str
    required: bool = False
    auto: bool = False  # the string "auto" is accepted besides the kind
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] = ()
    min_len: int = 0
    only: tuple[str, ...] = ()  # used only by these geometry kinds / particle shapes


def _key(kind: str, doc: str, default: Any = None, **spec: Any) -> Any:
    return field(default=default, metadata={"spec": _Spec(kind, doc, **spec)})


def _specs(cls) -> dict[str, _Spec]:
    return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls)
            if "spec" in f.metadata}


def _document(cls):
    """Append a numpydoc ``Attributes`` section built from the keys' docs."""
    lines = ["", "Attributes", "----------"]
    for name, spec in _specs(cls).items():
        lines += [name, "    " + spec.doc]
    cls.__doc__ = (cls.__doc__ or "").rstrip() + "\n" + "\n".join(lines) + "\n"
    return cls


class _Config:
    """Shared behaviour of the frozen config dataclasses."""

    def replace(self, **changes: Any):
        """A copy with ``changes`` applied (not re-validated; see `Scene.with_values`)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the keys that have a value (lists for tuples, no ``None``)."""
        return {name: _plain(getattr(self, name)) for name in _specs(type(self))
                if getattr(self, name) is not None}


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


@_document
@dataclass(frozen=True)
class RunConfig(_Config):
    """``[run]``: duration, time step, realizations, backend."""

    t_end: float = _key("float", "physical time to simulate, s", required=True, gt=0)
    dt: float | str = _key("float", 'DEM time step, s, or "auto" (dt_safety times the '
                           "critical step 2 sqrt(m_eff/kn))", AUTO, auto=True, gt=0)
    dt_safety: float = _key("float", 'fraction of the critical step that dt = "auto" '
                            "uses, dimensionless", 0.15, gt=0, le=1)
    realizations: int = _key("int", "independent random realizations run together",
                             1, ge=1)
    seed: int = _key("int", "seed of realization 0; realization k uses seed + k", 0,
                     ge=0)
    arch: str = _key("choice", "Taichi backend (auto: a GPU when present)", "cpu",
                     choices=("cpu", "gpu", "auto"))
    precision: str = _key("choice", "floating point type of the kernels", "f64",
                          choices=("f64", "f32"))
    stepping: str = _key("choice", '"fused": many DEM steps per kernel launch, one '
                         'realization per thread (disks only); "per_step": three launches '
                         'per step, bodies in parallel; "auto": fused for disks on the CPU',
                         AUTO, choices=("auto", "fused", "per_step"))
    stop_at_clog: bool = _key("bool", "stop a realization once it has clogged", True)
    force_dt: bool = _key("bool", "accept a dt above the critical step (stability "
                          "studies); the run is then watched and reported unstable", False)


@_document
@dataclass(frozen=True)
class FluidConfig(_Config):
    """``[fluid]``: the Hele-Shaw pressure solve."""

    enabled: bool = _key("bool", "false: no pressure solve, no fluid force", True)
    viscosity: float | None = _key("float", "eta, Pa s (required while enabled)", gt=0)
    gap: float = _key("float", "H, plate spacing and particle thickness, m",
                      required=True, gt=0)
    cell_size: float | str = _key("float", 'fluid cell edge, m; "auto": smallest '
                                  "particle d_eq / 6", AUTO, auto=True, gt=0)
    bc: str = _key("choice", '"pressure": p_in and p_out; "flow_rate": flow_rate in, '
                   "p_out out", "pressure", choices=("pressure", "flow_rate"))
    p_in: float | None = _key("float", 'inlet pressure, Pa (required for bc = "pressure")')
    p_out: float = _key("float", "outlet pressure, Pa", 0.0)
    flow_rate: float | None = _key("float", "Q through the whole gap, m^3/s (required "
                                   'for bc = "flow_rate")', gt=0)
    update_interval: int | str = _key("int", 'DEM steps between pressure solves, or "auto" '
                                      "(the fastest expected particle crosses half a fluid "
                                      "cell between solves)", AUTO, auto=True, ge=1)
    resolve_fraction: float = _key("float", "re-solve only if more than this fraction "
                                   "of cells changed permeability (0: always), "
                                   "dimensionless", 0.0, ge=0, lt=1)
    solver_tol: float = _key("float", "relative residual of the multigrid solve, "
                             "dimensionless", 1e-8, gt=0, le=1e-2)
    workers: int | str = _key("int", "processes that share the realizations' pressure "
                              'solves; "auto": one per usable CPU, at most one per '
                              "realization (the answer does not depend on it)", AUTO,
                              auto=True, ge=1)
    pressure_sampling: str = _key("choice", "how a surface node reads the pressure",
                                  "bilinear", choices=("bilinear", "cell"))
    particle_flux: bool = _key("bool", "conserve the mixture: moving particles carry "
                               "their volume (div((kappa/eta) grad p) = div(chi v)); false: "
                               "fluid alone, particles as fixed obstacles (MODEL.md)", False)
    force_update: str = _key("choice", "when the pressure force on the particles is "
                             "evaluated: at each pressure solve and held in between "
                             '("solve"), or at every DEM step from the last pressure field '
                             '("step")', "solve", choices=("solve", "step"))


_HOURGLASS, _CONVERGING, _POLYGON = ("hourglass",), ("converging",), ("polygon",)


@_document
@dataclass(frozen=True)
class GeometryConfig(_Config):
    """``[geometry]``: the fluid region; keys of the other kinds are ``None``."""

    kind: str = _key("choice", "the outline generator", required=True,
                     choices=("hourglass", "converging", "polygon"))
    wall_cell_size: float | str = _key("float", 'wall level-set spacing, m; "auto": '
                                       "smallest d_eq / 10", AUTO, auto=True, gt=0)
    escape_offset: float | None = _key("float", "escape line distance downstream of "
                                       "the constriction's exit, m (None: 0.5 max "
                                       "d_eq, resolved by the run)", ge=0)
    # kind = "hourglass"
    length: float | None = _key("float", "channel length, m", required=True, gt=0,
                                only=_HOURGLASS)
    width: float | None = _key("float", "channel width, m", required=True, gt=0,
                               only=_HOURGLASS)
    neck_width: float | None = _key("float", "narrowest width, m, < width",
                                    required=True, gt=0, only=_HOURGLASS)
    neck_x: float | None = _key("float", "neck position from the inlet, m (default "
                                "length / 2)", only=_HOURGLASS)
    taper_length: float | None = _key("float", "length over which each side narrows, "
                                      "m (default width)", gt=0, only=_HOURGLASS)
    # kind = "converging"
    width_in: float | None = _key("float", "upstream channel width, m", required=True,
                                  gt=0, only=_CONVERGING)
    length_in: float | None = _key("float", "upstream straight length, m",
                                   required=True, gt=0, only=_CONVERGING)
    angle: float | None = _key("float", "convergence half-angle, degrees", 45.0, gt=0,
                               le=90, only=_CONVERGING)
    constriction_width: float | None = _key("float", "W, m, < width_in", required=True,
                                            gt=0, only=_CONVERGING)
    constriction_length: float | None = _key("float", "straight constriction length, "
                                             "m", 0.0, ge=0, only=_CONVERGING)
    width_out: float | None = _key("float", "outlet channel width, m, >= "
                                   "constriction_width (default width_in)", gt=0,
                                   only=_CONVERGING)
    length_out: float | None = _key("float", "outlet channel length, m", required=True,
                                    gt=0, only=_CONVERGING)
    # kind = "polygon"
    outline: tuple[tuple[float, float], ...] | None = _key(
        "points", "the fluid region, a simple polygon of [x, y] vertices, m",
        required=True, min_len=3, only=_POLYGON)
    obstacles: tuple[tuple[tuple[float, float], ...], ...] | None = _key(
        "polygons", "solid islands inside the outline, polygons of [x, y], m", (),
        only=_POLYGON)
    constriction_x: float | None = _key("float", "where escape is measured from, m "
                                        "(None: x of the narrowest section, resolved "
                                        "by the run)", only=_POLYGON)


_ROUND, _SQUARE, _RECT, _REGULAR = (("circle", "regular_polygon"), ("square",),
                                    ("rectangle",), ("regular_polygon",))


@_document
@dataclass(frozen=True)
class SpeciesConfig(_Config):
    """One ``[[particles]]`` table; keys of the other shapes are ``None``."""

    name: str = _key("str", 'label (default "species<k>")')
    shape: str = _key("choice", "particle outline", required=True,
                      choices=("circle", "square", "rectangle", "regular_polygon",
                               "polygon"))
    diameter: float | None = _key("float", "circle diameter, or circumscribed diameter "
                                  "of a regular polygon, m", required=True, gt=0,
                                  only=_ROUND)
    side: float | None = _key("float", "square side, m", required=True, gt=0,
                              only=_SQUARE)
    width: float | None = _key("float", "rectangle width, m", required=True, gt=0,
                               only=_RECT)
    height: float | None = _key("float", "rectangle height, m", required=True, gt=0,
                                only=_RECT)
    n_vertices: int | None = _key("int", "vertices of a regular polygon", required=True,
                                  ge=3, only=_REGULAR)
    vertices: tuple[tuple[float, float], ...] | None = _key(
        "points", "body-frame outline [x, y] (recentred on its centroid by the run), m",
        required=True, min_len=3, only=("polygon",))
    count: int | None = _key("int", "particles in the control volume (or "
                             "packing_fraction, or positions)", ge=0)
    positions: tuple[tuple[float, float, float], ...] | None = _key(
        "poses", "initial [x, y] or [x, y, theta] of every particle of this species "
        "(m, m, rad; theta 0 if left out), instead of a random placement; the same in "
        "every realization, checked against the walls and each other", min_len=1)
    packing_fraction: float | None = _key("float", "areal fraction in the control "
                                          "volume (or count), dimensionless", gt=0,
                                          lt=MAX_PACKING_FRACTION)
    density: float = _key("float", "kg/m^3", required=True, gt=0)
    kn: float | str = _key("float", 'normal stiffness of the prism, N/m; "auto": '
                           "largest driving force / (overlap_target d_eq)", AUTO,
                           auto=True, gt=0)
    ks: float | str = _key("float", 'tangential stiffness, N/m; "auto": kn / 2', AUTO,
                           auto=True, ge=0)
    friction: float = _key("float", "Coulomb coefficient mu, dimensionless", 0.25,
                           ge=0)
    restitution: float = _key("float", "coefficient of restitution e, dimensionless",
                              0.5, gt=0, le=1)
    nodes: int = _key("int", "surface nodes (at least the shape's vertices)", 40, ge=3)
    ls_spacing: float | str = _key("float", 'level-set grid spacing, m; "auto": d_eq '
                                   "/ 40", AUTO, auto=True, gt=0)
    xi: float | None = _key("float", "global damping of this species, 1/s; unset: "
                            "damping.xi (the resolved scene records each species' value)",
                            None, ge=0)

    def area(self) -> float:
        """Area of the shape, m^2."""
        return _shape_area(self.shape, dataclasses.asdict(self))

    def d_eq(self) -> float:
        """Equivalent diameter ``sqrt(4 A / pi)``, m."""
        return math.sqrt(4.0 * self.area() / math.pi)


@_document
@dataclass(frozen=True)
class ContactConfig(_Config):
    """``[contact]``: contact law options."""

    normalize_by_nodes: bool = _key("bool", "divide a contact's resultant by its "
                                    "number of nodes in contact (the paper)", True)
    overlap_target: float = _key("float", 'overlap kn = "auto" aims at, fraction of '
                                 "d_eq", 0.02, gt=0, le=0.2)
    overlap_limit: float = _key("float", "deepest overlap before a realization is "
                                "stopped as unstable, fraction of d_eq", 0.25, gt=0,
                                lt=1)
    disk_fast_path: bool = _key("bool", "use analytic disk contacts when every particle "
                                "is a circle (false: level sets for disks too)", True)


@_document
@dataclass(frozen=True)
class DampingConfig(_Config):
    """``[damping]``: global (plate drag) damping."""

    xi: float | str = _key("float", 'global damping, 1/s; "auto": the plate drag',
                           AUTO, auto=True, ge=0)


@_document
@dataclass(frozen=True)
class FeedConfig(_Config):
    """``[feed]``: where particles start and re-enter."""

    mode: str = _key("choice", "keep the particle count, or let the domain empty",
                     "count", choices=("count", "none"))
    region: tuple[float, float] | None = _key("interval", "control volume [x0, x1], m "
                                              "(None: upstream straight section, "
                                              "resolved by the run)")
    inlet: tuple[float, float] | None = _key("interval", "re-entry strip [x0, x1], m "
                                             "(None: first 2 max d_eq of region, "
                                             "resolved by the run)")


@_document
@dataclass(frozen=True)
class ClogConfig(_Config):
    """``[clog]``: the clog criterion."""

    window: float = _key("float", "time without escape that signals a clog, s "
                         "(default 0.1 t_end)", gt=0)
    speed_fraction: float = _key("float", "speed threshold near the constriction, "
                                 "fraction of the mean fluid speed", 0.02, gt=0, lt=1)


@_document
@dataclass(frozen=True)
class OutputConfig(_Config):
    """``[output]``: files written by a run."""

    dir: str = _key("str", 'output folder (default "runs/<name>")')
    video: bool = _key("bool", "write video.mp4", False)
    video_realization: int = _key("int", "which realization the video shows, < "
                                  "run.realizations", 0, ge=0)
    fps: int = _key("int", "video frame rate, 1/s", 30, ge=1)
    frames: int = _key("int", "frames over t_end (frame 0 is the initial state)", 150,
                       ge=2)
    width: int = _key("int", "video width, pixels, even", 960, ge=64)
    series_interval: float = _key("float", "time between rows of escapees.csv, s "
                                  "(default t_end / 200)", gt=0)


_SECTIONS = {"run": RunConfig, "fluid": FluidConfig, "geometry": GeometryConfig,
             "contact": ContactConfig, "damping": DampingConfig, "feed": FeedConfig,
             "clog": ClogConfig, "output": OutputConfig}


@_document
@dataclass(frozen=True)
class Scene(_Config):
    """A validated scene; build it with `load_scene`.

    ``particles`` holds one `SpeciesConfig` per ``[[particles]]`` table and
    ``source`` the file it was read from (``"<dict>"`` for a dict).
    """

    name: str = _key("str", "names the default output folder (default: file stem)")
    description: str = _key("str", "free text", "")
    units: str = _key("choice", 'how numbers are read: SI, or "dimensionless" (same '
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
        for section in _SECTIONS:
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


_TOP_ORDER = ("name", "description", "units", "run", "fluid", "geometry", "particles",
              "contact", "damping", "feed", "clog", "output")


# ----------------------------------------------------------------- shape geometry

def _signed_area(points) -> float:
    """Shoelace area, positive for a counter-clockwise polygon."""
    n = len(points)
    return 0.5 * sum(points[i][0] * points[(i + 1) % n][1]
                     - points[(i + 1) % n][0] * points[i][1] for i in range(n))


def _shape_area(shape: str, keys: Mapping[str, Any]) -> float:
    if shape == "circle":
        return math.pi * keys["diameter"] ** 2 / 4.0
    if shape == "square":
        return keys["side"] ** 2
    if shape == "rectangle":
        return keys["width"] * keys["height"]
    if shape == "regular_polygon":
        n, radius = keys["n_vertices"], keys["diameter"] / 2.0
        return 0.5 * n * radius ** 2 * math.sin(2.0 * math.pi / n)
    return abs(_signed_area(keys["vertices"]))


def _shape_vertex_count(shape: str, keys: Mapping[str, Any]) -> int:
    fixed = {"circle": 0, "square": 4, "rectangle": 4}
    if shape in fixed:
        return fixed[shape]
    return keys["n_vertices"] if shape == "regular_polygon" else len(keys["vertices"])


def _orientation(a, b, c) -> float:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _on_segment(a, b, p) -> bool:
    return (min(a[0], b[0]) <= p[0] <= max(a[0], b[0])
            and min(a[1], b[1]) <= p[1] <= max(a[1], b[1]))


def _segments_touch(a, b, c, d) -> bool:
    """Whether closed segments ab and cd share a point."""
    o1, o2 = _orientation(a, b, c), _orientation(a, b, d)
    o3, o4 = _orientation(c, d, a), _orientation(c, d, b)
    if ((o1 > 0 > o2) or (o1 < 0 < o2)) and ((o3 > 0 > o4) or (o3 < 0 < o4)):
        return True
    return ((o1 == 0 and _on_segment(a, b, c)) or (o2 == 0 and _on_segment(a, b, d))
            or (o3 == 0 and _on_segment(c, d, a)) or (o4 == 0 and _on_segment(c, d, b)))


def _polygon_problem(points) -> str | None:
    """Why ``points`` is not a simple polygon of non-zero area, or None."""
    n = len(points)
    if points[0] == points[-1]:
        return ("the last vertex repeats the first; the polygon closes itself, leave "
                "the repeat out")
    for i in range(n):
        if points[i] == points[(i + 1) % n]:
            return f"vertices {i} and {(i + 1) % n} coincide"
    if _signed_area(points) == 0.0:
        return "the polygon has zero area"
    edges = [(points[i], points[(i + 1) % n]) for i in range(n)]
    for i in range(n):
        # Adjacent edges share a vertex; they only fail by folding back on each other.
        a, b = edges[i]
        c = edges[(i + 1) % n][1]
        if (_orientation(a, b, c) == 0
                and (b[0] - a[0]) * (c[0] - b[0]) + (b[1] - a[1]) * (c[1] - b[1]) < 0):
            return f"the edges at vertex {(i + 1) % n} fold back on each other"
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue
            if _segments_touch(*edges[i], *edges[j]):
                return f"edges {i} and {j} cross or touch: the polygon is not simple"
    return None


def _inside(point, polygon) -> bool:
    """Even-odd rule point-in-polygon test."""
    x, y = point
    inside = False
    n = len(polygon)
    for i in range(n):
        (x0, y0), (x1, y1) = polygon[i], polygon[(i + 1) % n]
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


# ------------------------------------------------------------------- type checks

_BAD = object()  # a value already reported as invalid
_MISSING = object()  # a key the table does not give


class _Problems:
    """Collects ``"ORIGIN: key: problem"`` lines; ORIGIN is the file or an override."""

    def __init__(self, label: str, origins: Mapping[str, str]):
        self.label, self.origins, self.lines = label, origins, []

    def add(self, key: str, message: str) -> None:
        origin, probe = self.label, key
        while probe:
            if probe in self.origins:
                origin = self.origins[probe]
                break
            probe = probe[:max(probe.rfind("."), probe.rfind("["), 0)]
        line = f"{origin}: {key}: {message}" if key else f"{origin}: {message}"
        if line not in self.lines:
            self.lines.append(line)


def _toml_string(text: str) -> str:
    escapes = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n",
               "\f": "\\f", "\r": "\\r"}
    out = []
    for ch in text:
        if ch in escapes:
            out.append(escapes[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        value = float(value)
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}"
                               for k, v in value.items()) + "}"
    return str(value)


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_string(key)


def _show(value: Any, limit: int = 60) -> str:
    try:
        text = _toml_value(value)
    except Exception:  # a value TOML cannot spell (e.g. a lone surrogate)
        text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _describe(value: Any) -> str:
    if value is None:
        return "None"
    if isinstance(value, bool):
        kind = "boolean"
    elif isinstance(value, numbers.Integral):
        kind = "integer"
    elif isinstance(value, numbers.Real):
        kind = "number"
    elif isinstance(value, str):
        kind = "string"
    elif isinstance(value, (list, tuple)):
        kind = "array"
    elif isinstance(value, Mapping):
        return "a table"
    else:
        kind = type(value).__name__.replace("datetime", "date-time")
    return f"{kind} {_show(value)}"


def _num(x: float) -> str:
    return repr(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(x)


def _range_text(spec: _Spec) -> str:
    low = (("(", spec.gt) if spec.gt is not None
           else ("[", spec.ge) if spec.ge is not None else None)
    high = ((")", spec.lt) if spec.lt is not None
            else ("]", spec.le) if spec.le is not None else None)
    if low and high:
        return f"in {low[0]}{_num(low[1])}, {_num(high[1])}{high[0]}"
    if low:
        return f"{'>' if low[0] == '(' else '>='} {_num(low[1])}"
    if high:
        return f"{'<' if high[0] == ')' else '<='} {_num(high[1])}"
    return ""


def _in_range(x: float, spec: _Spec) -> bool:
    return ((spec.gt is None or x > spec.gt) and (spec.ge is None or x >= spec.ge)
            and (spec.lt is None or x < spec.lt) and (spec.le is None or x <= spec.le))


def _suggest(word: str, candidates: Iterable[str]) -> str:
    match = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {match[0]!r}?)" if match else ""


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _expected(spec: _Spec) -> str:
    what = {"float": "a number", "int": "an integer", "bool": "true or false",
            "str": "a string", "choice": "one of " + ", ".join(map(repr, spec.choices)),
            "points": "an array of [x, y] pairs", "polygons": "an array of polygons",
            "poses": "an array of [x, y] or [x, y, theta]",
            "interval": "[x0, x1]"}[spec.kind]
    limits = _range_text(spec)
    if limits:
        what += " " + limits
    return what + (' or "auto"' if spec.auto else "")


def _coerce_point(value: Any, key: str, out: _Problems):
    if (isinstance(value, (list, tuple)) and len(value) == 2
            and all(_is_real(c) and math.isfinite(c) for c in value)):
        return (float(value[0]), float(value[1]))
    out.add(key, f"expected [x, y] with two finite numbers, got {_describe(value)}")
    return _BAD


def _coerce_pose(value: Any, key: str, out: _Problems):
    if (isinstance(value, (list, tuple)) and len(value) in (2, 3)
            and all(_is_real(c) and math.isfinite(c) for c in value)):
        return (float(value[0]), float(value[1]),
                float(value[2]) if len(value) == 3 else 0.0)
    out.add(key, f"expected [x, y] or [x, y, theta] with finite numbers, got {_describe(value)}")
    return _BAD


def _coerce_array(value: Any, key: str, out: _Problems, item, what: str,
                  min_len: int = 0, unit: str = "entries"):
    """A tuple of ``item(entry, "key[i]", out)`` for an array ``value`` of at least
    ``min_len`` entries, or _BAD after reporting why not."""
    if not isinstance(value, (list, tuple)):
        out.add(key, f"expected an array of {what}, got {_describe(value)}")
        return _BAD
    items = tuple(item(p, f"{key}[{i}]", out) for i, p in enumerate(value))
    if _BAD in items:
        return _BAD
    if len(items) < min_len:
        out.add(key, f"needs at least {min_len} {unit}, got {len(items)}")
        return _BAD
    return items


def _coerce_points(value: Any, key: str, min_len: int, out: _Problems):
    return _coerce_array(value, key, out, _coerce_point, "[x, y] pairs", min_len, "vertices")


def _coerce(value: Any, spec: _Spec, key: str, out: _Problems) -> Any:
    """``value`` converted to the key's type, or _BAD after reporting why not."""
    if spec.auto and value == AUTO:
        return AUTO
    kind = spec.kind
    if kind in ("float", "int"):
        if not (_is_int(value) if kind == "int" else _is_real(value)):
            hint = ""
            if isinstance(value, str):
                hint = _suggest(value, [AUTO]) if spec.auto else ""
            out.add(key, f"expected {_expected(spec)}, got {_describe(value)}{hint}")
            return _BAD
        try:
            number = int(value) if kind == "int" else float(value)
        except OverflowError:
            number = math.inf
        if not math.isfinite(number):
            out.add(key, f"expected a finite number, got {_show(number)}")
            return _BAD
        if not _in_range(number, spec):
            out.add(key, f"must be {_range_text(spec)}, got {_show(number)}")
            return _BAD
        return number
    if kind == "bool":
        if isinstance(value, bool):
            return value
        out.add(key, f"expected true or false, got {_describe(value)}")
        return _BAD
    if kind in ("str", "choice"):
        if not isinstance(value, str):
            out.add(key, f"expected {_expected(spec)}, got {_describe(value)}")
            return _BAD
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            out.add(key, f"not valid Unicode text: {value!r}")
            return _BAD
        if kind == "choice" and value not in spec.choices:
            out.add(key, f"must be one of {', '.join(map(repr, spec.choices))}, got "
                         f"{_show(value)}{_suggest(value, spec.choices)}")
            return _BAD
        return value
    if kind == "points":
        return _coerce_points(value, key, spec.min_len, out)
    if kind == "poses":
        return _coerce_array(value, key, out, _coerce_pose, "[x, y] or [x, y, theta]",
                             spec.min_len)
    if kind == "polygons":
        return _coerce_array(value, key, out,
                             lambda p, where, o: _coerce_points(p, where, 3, o), "polygons")
    # interval
    if (isinstance(value, (list, tuple)) and len(value) == 2
            and all(_is_real(c) and math.isfinite(c) for c in value)):
        if value[0] < value[1]:
            return (float(value[0]), float(value[1]))
        out.add(key, f"expected [x0, x1] with x0 < x1, got {_show(value)}")
        return _BAD
    out.add(key, f"expected [x0, x1] with two finite numbers, got {_describe(value)}")
    return _BAD


def _read_table(cls, raw: Any, where: str, out: _Problems,
                discriminator: str | None = None) -> dict[str, Any]:
    """Type-check one table against ``cls``'s keys.

    Returns every key's value: converted, the static default, ``None`` (optional and
    absent, or not used by the discriminator's value) or _BAD (already reported).
    """
    specs = _specs(cls)
    prefix = f"{where}." if where else ""
    if raw is _MISSING:
        raw = {}
    if not isinstance(raw, Mapping):
        header = "[[particles]]" if where.startswith("particles") else f"[{where}]"
        out.add(where, f"expected a table {header}, got {_describe(raw)}")
        return dict.fromkeys(specs, _BAD)
    for key in raw:
        if str(key) not in specs:
            out.add(prefix + str(key), _unknown_key_message(str(key), specs, where))
    chosen = None
    if discriminator:
        chosen = (_coerce(raw[discriminator], specs[discriminator],
                          prefix + discriminator, out) if discriminator in raw
                  else _MISSING)
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    for name, spec in specs.items():
        key = prefix + name
        if name == discriminator:
            values[name] = chosen
        elif spec.only and not (isinstance(chosen, str) and chosen in spec.only):
            # A key of another kind / shape, or the discriminator is missing or bad
            # (reported already): nothing to check.
            if isinstance(chosen, str) and name in raw:
                out.add(key, f"not used by {discriminator} {chosen!r}")
            values[name] = _BAD if name in raw else None
            continue
        else:
            values[name] = (_coerce(raw[name], spec, key, out) if name in raw
                            else _MISSING)
        if values[name] is _MISSING:
            if spec.required:
                needed = f" for {discriminator} {chosen!r}" if spec.only else ""
                out.add(key, f"missing: required{needed}")
                values[name] = _BAD
            else:
                values[name] = defaults[name]
    return values


def _unknown_key_message(key: str, known: Iterable[str], where: str) -> str:
    """Says ``key`` is unknown in table ``where`` ("" for the top level), suggesting
    the closest known key, or else the tables where such a key belongs."""
    suggestion = _suggest(key, known)
    if suggestion:
        return ("unknown key" if where else "unknown section or key") + suggestion
    homes = [f"[{name}]" for name, cls in _SECTIONS.items()
             if name != where and key in _specs(cls)]
    if key in _specs(SpeciesConfig) and not where.startswith("particles"):
        homes.append("[[particles]]")
    if not where:
        message = "unknown section or key"
        return message + (f"; it belongs in {' or '.join(homes)}" if homes else "")
    return "unknown key" + (f" here; it belongs in {' or '.join(homes)}" if homes else "")


def _good(*values: Any) -> bool:
    return all(v is not None and v is not _BAD and v != AUTO for v in values)


# --------------------------------------------------------------- cross-key checks

def _check_fluid(v: dict, out: _Problems) -> None:
    if v["enabled"] is not True:
        return
    if v["viscosity"] is None:
        out.add("fluid.viscosity", "missing: required while fluid.enabled = true")
    if v["bc"] == "pressure":
        if v["p_in"] is None:
            out.add("fluid.p_in", 'missing: required for fluid.bc = "pressure"')
        elif _good(v["p_in"], v["p_out"]) and v["p_in"] <= v["p_out"]:
            out.add("fluid.p_in", f"must exceed fluid.p_out ({_show(v['p_out'])}) so "
                                  f"the fluid flows from inlet to outlet, got "
                                  f"{_show(v['p_in'])}")
    if v["bc"] == "flow_rate" and v["flow_rate"] is None:
        out.add("fluid.flow_rate", 'missing: required for fluid.bc = "flow_rate"')


def _check_geometry(v: dict, out: _Problems) -> None:
    kind = v["kind"]
    if kind == "hourglass":
        if v["neck_x"] is None and _good(v["length"]):
            v["neck_x"] = v["length"] / 2.0
        if v["taper_length"] is None and _good(v["width"]):
            v["taper_length"] = v["width"]
        if _good(v["neck_width"], v["width"]) and v["neck_width"] >= v["width"]:
            out.add("geometry.neck_width", f"must be < geometry.width "
                    f"({_show(v['width'])}), got {_show(v['neck_width'])}")
        if _good(v["neck_x"], v["length"]):
            if not 0.0 < v["neck_x"] < v["length"]:
                out.add("geometry.neck_x", f"must lie inside the channel, in (0, "
                        f"{_show(v['length'])}), got {_show(v['neck_x'])}")
            elif _good(v["taper_length"]) and not (
                    v["taper_length"] <= v["neck_x"] <= v["length"] - v["taper_length"]):
                out.add("geometry.taper_length",
                        f"the tapers span [{_show(v['neck_x'] - v['taper_length'])}, "
                        f"{_show(v['neck_x'] + v['taper_length'])}] around neck_x, past "
                        f"the channel [0, {_show(v['length'])}]; shorten taper_length "
                        "or move neck_x")
    elif kind == "converging":
        if v["width_out"] is None and _good(v["width_in"]):
            v["width_out"] = v["width_in"]
        width, inlet, outlet = v["constriction_width"], v["width_in"], v["width_out"]
        if _good(width, inlet) and width >= inlet:
            out.add("geometry.constriction_width", f"must be < geometry.width_in "
                    f"({_show(inlet)}), got {_show(width)}")
        if _good(width, outlet) and outlet < width:
            out.add("geometry.width_out", f"must be >= geometry.constriction_width "
                    f"({_show(width)}), got {_show(outlet)}")
    elif kind == "polygon":
        _check_polygon_outline(v, out)


def _check_polygon_outline(v: dict, out: _Problems) -> None:
    outline = v["outline"]
    if not _good(outline):
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
            out.add("geometry.outline", f"has no edge on x = {_show(x)}: the {side} is "
                    f"the outline's vertical edge at its {end} x")
    if _good(v["constriction_x"]) and not x_min < v["constriction_x"] < x_max:
        out.add("geometry.constriction_x", f"must lie inside the outline, in "
                f"({_show(x_min)}, {_show(x_max)}), got {_show(v['constriction_x'])}")
    if not _good(v["obstacles"]):
        return
    edges = [(outline[i], outline[(i + 1) % n]) for i in range(n)]
    for k, obstacle in enumerate(v["obstacles"]):
        key = f"geometry.obstacles[{k}]"
        problem = _polygon_problem(obstacle)
        if problem:
            out.add(key, problem)
        elif not all(_inside(p, outline) for p in obstacle) or any(
                _segments_touch(a, b, obstacle[i], obstacle[(i + 1) % len(obstacle)])
                for a, b in edges for i in range(len(obstacle))):
            out.add(key, "must lie strictly inside geometry.outline")


def _check_species(v: dict, index: int, out: _Problems) -> tuple[float, int] | None:
    """Fill the name, check count / packing_fraction and the shape; return
    (area, vertex count) when the shape is valid."""
    where = f"particles[{index}]"
    if v["name"] is None:
        v["name"] = f"species{index}"
    if _good(v["positions"]):
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
    if not _good(shape) or not all(_good(v[name]) for name, spec in
                                   _specs(SpeciesConfig).items() if shape in spec.only):
        return None
    if shape == "polygon":
        problem = _polygon_problem(v["vertices"])
        if problem:
            out.add(f"{where}.vertices", problem)
            return None
    vertices = _shape_vertex_count(shape, v)
    if _good(v["nodes"]) and v["nodes"] < vertices:
        out.add(f"{where}.nodes", f"must be at least the {vertices} vertices of the "
                                  f"{shape.replace('_', ' ')}, got {v['nodes']}")
    return _shape_area(shape, v), vertices


def _check_scene(scene: dict, species: dict[int, dict], shapes: dict[int, Any],
                 stem: str, out: _Problems) -> None:
    """Checks and defaults that span sections; ``species`` and ``shapes`` are keyed
    by the species' index."""
    run, fluid, output, clog = (scene[k] for k in ("run", "fluid", "output", "clog"))
    if scene["name"] is None:
        scene["name"] = stem
    name = scene["name"]
    if _good(name) and (name.strip() in ("", ".", "..")
                        or any(c in name for c in "/\\\0")):
        out.add("name", f"must be a non-empty folder name without / or \\, got "
                        f"{_show(name)}")
    if output["dir"] is None and _good(name):
        output["dir"] = f"runs/{name}"
    if _good(output["dir"]) and (not output["dir"].strip() or "\0" in output["dir"]):
        out.add("output.dir", f"must be a folder path, got {_show(output['dir'])}")
    if _good(run["t_end"]):
        if clog["window"] is None:
            clog["window"] = 0.1 * run["t_end"]
        if output["series_interval"] is None:
            output["series_interval"] = run["t_end"] / 200.0
    if _good(output["width"]) and output["width"] % 2:
        out.add("output.width", f"must be even (H.264 with yuv420p), got "
                                f"{output['width']}")
    if (_good(output["video_realization"], run["realizations"])
            and output["video_realization"] >= run["realizations"]):
        out.add("output.video_realization",
                f"must be < run.realizations ({run['realizations']}), got "
                f"{output['video_realization']}")
    contact = scene["contact"]
    if (_good(contact["overlap_target"], contact["overlap_limit"])
            and contact["overlap_limit"] <= contact["overlap_target"]):
        out.add("contact.overlap_limit", f"must exceed contact.overlap_target "
                f"({_show(contact['overlap_target'])}), got "
                f"{_show(contact['overlap_limit'])}")

    fractions = [s["packing_fraction"] for s in species.values()
                 if _good(s["packing_fraction"])]
    if len(fractions) > 1 and sum(fractions) >= MAX_PACKING_FRACTION:
        out.add("particles", f"the packing fractions sum to {sum(fractions):.6g}; "
                             f"it must be < {MAX_PACKING_FRACTION}")
    seen: dict[str, int] = {}
    for k, s in species.items():
        if _good(s["name"]):
            if s["name"] in seen:
                out.add(f"particles[{k}].name", f"{_show(s['name'])} already names "
                                                f"particles[{seen[s['name']]}]")
            seen.setdefault(s["name"], k)
    gap = fluid["gap"]
    for k, shape in shapes.items():
        if shape is None or not _good(gap):
            continue
        d_eq = math.sqrt(4.0 * shape[0] / math.pi)
        if gap <= MIN_GAP_OVER_DEQ * d_eq:
            out.add("fluid.gap", f"must be > (2/3) d_eq = {MIN_GAP_OVER_DEQ * d_eq:.6g} "
                    f"of particles[{k}] ({species[k]['name']!s}, d_eq = {d_eq:.6g}) "
                    f"for the Kozeny-Carman porosity inside it, got {_show(gap)}")


def _build_scene(raw: Any, label: str, stem: str, origins: Mapping[str, str]) -> Scene:
    out = _Problems(label, origins)
    if not isinstance(raw, Mapping):
        raise SceneError(f"{label}: expected a table of sections, got {_describe(raw)}")
    known = set(_specs(Scene)) | set(_SECTIONS) | {"particles"}
    for key in raw:
        if str(key) not in known:
            out.add(str(key), _unknown_key_message(str(key), known, ""))
    scene = _read_table(Scene, {k: v for k, v in raw.items() if k in _specs(Scene)},
                        "", out)
    for section, cls in _SECTIONS.items():
        discriminator = "kind" if cls is GeometryConfig else None
        scene[section] = _read_table(cls, raw.get(section, _MISSING), section, out,
                                     discriminator)
    _check_fluid(scene["fluid"], out)
    _check_geometry(scene["geometry"], out)

    raw_species = raw.get("particles", _MISSING)
    species: dict[int, dict] = {}
    shapes: dict[int, Any] = {}
    if raw_species is _MISSING or (isinstance(raw_species, (list, tuple))
                                   and not raw_species):
        out.add("particles", "missing: add at least one [[particles]] table")
    elif not isinstance(raw_species, (list, tuple)):
        out.add("particles", f"expected an array of tables [[particles]], got "
                             f"{_describe(raw_species)}")
    else:
        for k, table in enumerate(raw_species):
            values = _read_table(SpeciesConfig, table, f"particles[{k}]", out, "shape")
            if isinstance(table, Mapping):
                species[k] = values
                shapes[k] = _check_species(values, k, out)
    _check_scene(scene, species, shapes, stem, out)
    if out.lines:
        raise SceneError(out.lines)
    sections = {name: cls(**scene[name]) for name, cls in _SECTIONS.items()}
    return Scene(**{name: scene[name] for name in _specs(Scene)}, **sections,
                 particles=tuple(SpeciesConfig(**s) for s in species.values()), source=label)


# -------------------------------------------------------------------- overrides

def _parse_override_value(text: str) -> Any:
    """A TOML value, or the text itself when it is not one (``flow_rate``)."""
    try:
        parsed = tomllib.loads(f"v = {text}")
    except tomllib.TOMLDecodeError:
        return text
    return parsed["v"] if list(parsed) == ["v"] else text


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
        specs = _specs(SpeciesConfig)
        if key not in specs:
            return fail("unknown key" + _suggest(key, specs))
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
    if head in _SECTIONS:
        if len(parts) != 2:
            return fail(f"expected {head}.key" if len(parts) == 1 else "unknown key")
        specs = _specs(_SECTIONS[head])
        if parts[1] not in specs:
            return fail("unknown key" + _suggest(parts[1], specs))
        section = raw.setdefault(head, {})
        if isinstance(section, dict):  # otherwise the table itself is reported
            _assign(section, parts[1], value)
            origins[path] = origin
        return None
    top = _specs(Scene)
    if len(parts) == 1 and head in top:
        _assign(raw, head, value)
        origins[head] = origin
        return None
    return fail("unknown section or key"
                + _suggest(head, list(top) + list(_SECTIONS) + ["particles"]))


def _assign(table: dict, key: str, value: Any) -> None:
    if value is None:  # TOML has no null: None can only mean "leave the key out"
        table.pop(key, None)
    else:
        table[key] = value


def read_toml(path: Path, what: str = "scene", error: type = None) -> dict:
    """A TOML file as a dict; every way it can fail becomes ``error`` (default
    :class:`SceneError`) with one line naming the file (``what`` it should be)."""
    error = error or SceneError
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, not a {what} file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: invalid TOML: {exc}") from None


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
        _set_path(raw, key, _parse_override_value(value.strip()), origin, origins,
                  problems)
    try:
        scene = _build_scene(raw, label, stem, origins)
    except SceneError as error:
        raise SceneError(problems + error.problems) from None
    if problems:
        raise SceneError(problems)
    return scene


# ---------------------------------------------------------------------- writing

def scene_to_toml(scene: Scene) -> str:
    """The scene as TOML text that `load_scene` reads back to an equal scene."""
    lines = ["# Scene written by taichi_hsdem: every key, defaults filled in."]
    data = scene.to_dict()
    tables = []
    for key, value in data.items():
        if isinstance(value, Mapping):
            tables.append((f"[{_toml_key(key)}]", value))
        elif isinstance(value, list) and value and all(isinstance(v, Mapping)
                                                       for v in value):
            tables += [(f"[[{_toml_key(key)}]]", v) for v in value]
        else:
            lines.append(f"{_toml_key(key)} = {_toml_value(value)}")
    for header, table in tables:
        lines += ["", header]
        lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in table.items()
                  if v is not None]
    return "\n".join(lines) + "\n"
