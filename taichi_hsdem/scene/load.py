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

from .checks import (_check_fluid, _check_geometry, _check_scene, _check_species,
                     path_length_problem)
from .coerce import (BAD, MISSING, Problems, describe, good, read_table, show, suggest,
                     unknown_key_message)
from .keys import (MIN_GAP_OVER_DEQ, SECTIONS, ClogConfig, Config, ContactConfig,
                   DampingConfig, FeedConfig, FluidConfig, GeometryConfig, OutputConfig,
                   RunConfig, SceneError, SpeciesConfig, document, key_specs, keyfield)
from .toml import parse_override_value, read_toml

__all__ = ["Scene", "load_scene", "path_length_problem"]  # the last: cli, studies


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


_TOP_ORDER = ("name", "description", "units", "run", "fluid", "geometry", "particles",
              "contact", "damping", "feed", "clog", "output")


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
               overrides: Iterable[str] = (), label: str | None = None) -> Scene:
    """Read, override and validate a scene.

    Parameters
    ----------
    source : str, Path or dict
        A TOML scene file, or a dict of the same structure.
    overrides : iterable of str
        ``"section.key=value"`` strings; ``value`` is read as a TOML value, or as a
        plain string when it is not one. ``particles.K.key=v`` sets species ``K``,
        ``particles.key=v`` every species.
    label : str, optional
        Where a dict came from (a checkpoint's path, say), the prefix of its
        problems and the scene's ``source``; ``"<dict>"`` when not given.

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
        raw, label, stem = copy.deepcopy(dict(source)), label or "<dict>", "scene"
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
