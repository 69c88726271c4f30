"""Sweep files: reading, checking and expanding the points of a sweep.

A sweep file names a base scene, ``[common]`` overrides for every point, a
``[grid]`` of lists (their cartesian product) and single ``[[points]]``; the
format is in :mod:`.sweep`. :func:`load_sweep` reads one and validates every
point as a scene before anything runs; :func:`point_folder` names a point's
folder after its overrides alone.
"""
from __future__ import annotations

import difflib
import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..scene import Scene, SceneError, load_scene, read_toml
from ..scene.toml import parse_override_value, toml_value

#: The most points a sweep takes (grid and ``[[points]]`` together): a grid
#: larger than this is refused, with its point count, before it is built.
MAX_POINTS = 10_000
#: Folder names longer than this are cut and given a hash of the overrides.
MAX_FOLDER_NAME = 100
#: ``quick``: at most this many realizations a point (each to its ``run.t_end``).
QUICK_REALIZATIONS = 2
_SWEEP_KEYS = ("scene", "description", "common", "grid", "points")


class SweepError(SceneError):
    """An invalid sweep (file, point or override); ``problems`` lists each one."""


# --------------------------------------------------------------------------- points

def _flatten(table: Mapping, prefix: str = "") -> dict[str, Any]:
    """Nested tables to dotted keys; lists and scalars are values."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flatten(value, path + "."))
        else:
            out[path] = value
    return out


def _value_text(value: Any) -> str:
    """A value as the user would type it after ``--set key=``."""
    if isinstance(value, str):
        return value
    return toml_value(value)


def _override_strings(overrides: Mapping[str, Any]) -> list[str]:
    # TOML spelling, so that a string stays a string and a list a list.
    return [f"{key}={toml_value(value)}" for key, value in overrides.items()]


def _describe_point(point: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={_value_text(v)}" for k, v in point.items()) or "(base scene)"


def _digest(obj: Any, n: int = 8) -> str:
    text = json.dumps(obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:n]


def point_folder(point: Mapping[str, Any]) -> str:
    """The folder name of a point: its overrides, keys sorted, e.g.
    ``"particles.friction=0.4,run.seed=7"``; ``"base"`` for no override.

    The name depends on the point alone, so it is the same in every sweep that
    holds the point. Characters other than letters, digits and ``._=,+-`` become
    ``_``; a name that needed such a change, or is longer than
    ``MAX_FOLDER_NAME``, ends in a hash of the overrides so that two points never
    share a folder.

    Examples
    --------
    >>> point_folder({"run.seed": 7, "particles.friction": 0.4})
    'particles.friction=0.4,run.seed=7'
    """
    if not point:
        return "base"
    items = sorted(point.items())
    raw = ",".join(f"{k}={_value_text(v)}" for k, v in items)
    name = re.sub(r"[^A-Za-z0-9._=,+-]", "_", raw)
    if name != raw or len(name) > MAX_FOLDER_NAME:
        tag = _digest([[k, v] for k, v in items])
        name = name[:MAX_FOLDER_NAME - len(tag) - 1] + "-" + tag
    return name


def grid_size(grid: Mapping[str, Sequence]) -> int:
    """The number of points of ``{key: [values]}`` (the product of the list
    lengths), without building them."""
    return math.prod(len(values) for values in grid.values())


def _too_many(n: int, what: str) -> str:
    return (f"{what} makes {n:,} points, more than the {MAX_POINTS:,} a sweep takes: "
            "use fewer values per key, or split the sweep into several files")


def expand_grid(grid: Mapping[str, Sequence]) -> list[dict[str, Any]]:
    """Cartesian product of ``{key: [values]}``, the last key varying fastest.

    Raises :class:`SweepError` (nothing built) when the product holds more than
    ``MAX_POINTS`` points.

    Examples
    --------
    >>> expand_grid({"a": [1, 2], "b": [0.5]})
    [{'a': 1, 'b': 0.5}, {'a': 2, 'b': 0.5}]
    """
    n = grid_size(grid)
    if n > MAX_POINTS:
        raise SweepError(_too_many(n, "the grid"))
    keys = list(grid)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


def command_line_sets(sets: Sequence[str], points: Sequence[Mapping]) -> dict[str, Any]:
    """``--set KEY=VALUE`` strings as the overrides of every point (typed as in a
    scene's ``--set``); a key that a point varies is refused (:class:`SweepError`,
    one line each), since the point's own value would silently win.

    Examples
    --------
    >>> command_line_sets(["run.t_end=0.5"], [{"particles.friction": 0.1}])
    {'run.t_end': 0.5}
    """
    out: dict[str, Any] = {}
    problems = []
    varied = {key for point in points for key in point}
    for text in sets:
        key, sep, value = str(text).partition("=")
        key = key.strip()
        if not sep or not key:
            problems.append(f"--set {text}: expected SECTION.KEY=VALUE")
        elif key in varied:
            problems.append(f"--set {key}: the sweep varies this key at its points; "
                            "change it in the sweep file instead")
        else:
            out[key] = parse_override_value(value.strip())
    if problems:
        raise SweepError(problems)
    return out


def quick_overrides(scene: Scene) -> dict[str, Any]:
    """Overrides that make a smoke-test run of ``scene``: at most
    ``QUICK_REALIZATIONS`` realizations, each to the scene's own ``run.t_end`` (a
    shorter run would stop before the first clogs, and a run that clogs stops
    there), so a quick point gives the point's statistics, only wider."""
    return {"run.realizations": min(QUICK_REALIZATIONS, scene.run.realizations)}


@dataclass(frozen=True)
class Sweep:
    """A sweep file, read and checked: the base scene, the common overrides and
    one dict of overrides per point (grid points first, then ``[[points]]``)."""

    scene: Path
    common: dict
    points: tuple
    source: str = "<dict>"
    description: str = ""


def load_sweep(path: str | Path) -> Sweep:
    """Read a sweep file (module notes give the format) and check every point.

    Every point is validated as a scene (``load_scene`` with the common and point
    overrides) before anything runs.

    Raises
    ------
    SweepError
        With every problem, one ``"FILE: where: problem"`` line each.
    """
    path = Path(path)
    raw = read_toml(path, "sweep", SweepError)
    label = str(path)
    problems: list[str] = []

    def bad(where: str, message: str) -> None:
        problems.append(f"{label}: {where}: {message}")

    for key in raw:
        if key not in _SWEEP_KEYS:
            close = difflib.get_close_matches(key, _SWEEP_KEYS, n=1)
            bad(key, "unknown key" + (f"; did you mean {close[0]!r}?" if close else
                                      f"; expected one of {', '.join(_SWEEP_KEYS)}"))
    scene_path = None
    scene = raw.get("scene")
    if scene is None:
        bad("scene", 'missing: give the base scene file, e.g. scene = "scenes/x.toml"')
    elif not isinstance(scene, str) or not scene.strip():
        bad("scene", f"expected a path string, got {scene!r}")
    else:
        scene_path = Path(scene) if Path(scene).is_absolute() else path.parent / scene
        if not scene_path.is_file():
            bad("scene", f"{scene_path} (relative to the sweep file's folder) is not a file")
    description = raw.get("description", "")
    if not isinstance(description, str):
        bad("description", f"expected a string, got {description!r}")

    common: dict = {}
    if "common" in raw:
        if isinstance(raw["common"], Mapping):
            common = _flatten(raw["common"])
        else:
            bad("common", "expected a table of overrides ([common])")
    grid: dict = {}
    if "grid" in raw:
        if isinstance(raw["grid"], Mapping):
            for key, values in _flatten(raw["grid"]).items():
                if not isinstance(values, list) or not values:
                    bad(f"grid.{key}", f"expected a non-empty list of values, got "
                                       f"{values!r}")
                else:
                    grid[key] = values
        else:
            bad("grid", "expected a table of lists ([grid])")
    explicit = raw.get("points", [])
    if not isinstance(explicit, list) or not all(isinstance(p, Mapping) for p in explicit):
        bad("points", "expected an array of tables ([[points]])")
        explicit = []
    n_grid = grid_size(grid) if grid else 0
    points: list[dict] = []
    if n_grid + len(explicit) > MAX_POINTS:
        bad("grid" if n_grid > MAX_POINTS else "points",
            _too_many(n_grid + len(explicit), "the [grid]" + (
                f" ({' x '.join(str(len(v)) for v in grid.values())} values)" if grid else "")
                + (" with the [[points]]" if explicit else "")))
    else:
        points = expand_grid(grid) if grid else []
        points += [_flatten(p) for p in explicit]
    if not points and not problems:
        bad("grid", "nothing to sweep: add a [grid] of lists or [[points]] tables")
    if problems:
        raise SweepError(problems)
    _check_points(scene_path, points, common, label)
    return Sweep(scene=scene_path, common=common, points=tuple(points), source=label,
                 description=description)


#: A sweep's refusal lists at most this many problems of single points (the
#: rest counted in one more line); a value refused wherever it stands is said once.
MAX_POINT_PROBLEMS = 10


def _value_problems(scene_path, points, common, shared) -> dict:
    """``{(key, value text): [problem lines]}`` of each distinct value of the
    points checked once, alone over the base scene and ``common`` (a value
    refused there is refused at a point holding it only if the point's own check
    says so too: another key of the point may be what makes it valid)."""
    seen, out = set(), {}
    for point in points:
        if not isinstance(point, Mapping):
            continue
        for key, value in point.items():
            try:
                pair = (key, _value_text(value))
            except TypeError:
                continue
            if pair in seen or not isinstance(key, str):
                continue
            seen.add(pair)
            try:
                load_scene(scene_path, _override_strings({**common, key: value}))
            except SceneError as error:
                out[pair] = [line for line in error.problems if line not in shared]
            except TypeError:
                pass
    return out


def _value_lines(label, bad: dict) -> list[str]:
    """One line per refused value (``bad``: ``{(key, value text): [(point, line)]}``),
    or, for a key with more than three refused values, one line naming them all."""
    by_key: dict[str, list] = {}
    for (key, text), hits in bad.items():
        by_key.setdefault(key, []).append((text, hits))
    out = []
    for key, values in by_key.items():
        lines = []
        for text, hits in values:
            points = sorted({k for k, _ in hits})
            problems = list(dict.fromkeys(line for _, line in hits))
            more = f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""
            at = f"at point {points[0]}" if len(points) == 1 else f"at {len(points)} points"
            lines.append(f"{label}: {key} = {text} ({at}): {problems[0]}{more}")
        if len(values) > 3:
            names = ", ".join(text for text, _ in values[:8]) + (
                ", ..." if len(values) > 8 else "")
            lines = [f"{label}: {key}: {len(values)} of its values are refused ({names}); "
                     f"the first: {lines[0].split(': ', 1)[1]}"]
        out += lines
    return out


def _check_points(scene_path, points, common, label) -> list[Scene]:
    """Load every point's scene; raise one SweepError listing every problem: a
    value refused at every point holding it once, naming its key and value (not
    once per point: a bad value of a grid's list stands in many points)."""
    problems: list[str] = []
    scenes = []
    folders: dict[str, int] = {}
    shared: set[str] = set()   # problems of [common], reported once
    if common:
        try:
            load_scene(scene_path, _override_strings(common))
        except SceneError as error:
            shared = set(error.problems)
            problems += [f"{label}: common: {line}" for line in error.problems]
    alone = _value_problems(scene_path, points, common, shared)
    bad: dict = {}             # (key, value text) -> [(point, line)]
    single: list[str] = []     # the problems of single points
    for k, point in enumerate(points):
        if not isinstance(point, Mapping) or not all(isinstance(key, str) for key in point):
            single.append(f"{label}: point {k}: expected a dict of dotted keys to "
                          f"values, got {point!r}")
            continue
        where = f"{label}: point {k} ({_describe_point(point)})"
        folder = point_folder(point)
        if folder in folders:
            single.append(f"{where}: repeats point {folders[folder]}")
            continue
        folders[folder] = k
        try:
            scenes.append(load_scene(scene_path, _override_strings({**common, **point})))
        except SceneError as error:
            for line in error.problems:
                if line in shared:
                    continue
                pair = next((pair for pair in ((key, _value_text(v))
                                               for key, v in point.items())
                             if line in alone.get(pair, ())), None)
                if pair is None:
                    single.append(f"{where}: {line}")
                else:
                    bad.setdefault(pair, []).append((k, line))
        except TypeError as error:  # a value TOML cannot spell
            single.append(f"{where}: {error}")
    problems += _value_lines(label, bad)
    if len(single) > MAX_POINT_PROBLEMS:
        single = single[:MAX_POINT_PROBLEMS] + [
            f"{label}: and {len(single) - MAX_POINT_PROBLEMS} more problems of single points"]
    problems += single
    backends = {(s.run.arch, s.run.precision) for s in scenes}
    if len(backends) > 1:
        problems.append(f"{label}: run.arch and run.precision must be the same at every "
                        f"point (one Taichi backend per process), got "
                        f"{sorted(backends)}")
    if problems:
        raise SweepError(problems)
    return scenes
