"""Parameter studies: sweeps over scene overrides, and calibration of one parameter.

A *sweep* runs one base scene at several *points*, each a set of dotted overrides
(``{"particles.friction": 0.4, "run.realizations": 10}``, the keys of ``--set``),
in one process: Taichi is initialised once and its kernels compiled once for all
points. Every point writes its own folder, named after its overrides
(``particles.friction=0.4``), with ``summary.json``, ``escapees.csv`` and
``scene.resolved.toml`` as a single run does; the sweep writes ``sweep.csv`` (the
clogging statistics of every point, one row each) and ``index.json`` (folder ->
overrides). A sweep is resumable: a point whose folder holds a ``summary.json``
of the same scene (base file, common and point overrides, compared as the
validated scene text) run by the same code (a digest of the package's sources) is
skipped; a folder without one, or with another scene's or code's, is run again.

A sweep file (TOML)::

    scene = "../scenes/hourglass24.toml"   # relative to this file
    [common]                               # applied to every point
    "run.t_end" = 20.0
    "run.realizations" = 20
    [grid]                                 # cartesian product of the lists
    "particles.friction" = [0.1, 0.25, 0.4]
    "run.seed" = [1, 1001]
    [[points]]                             # and/or single points
    "particles.friction" = 0.9

Dotted keys can be quoted (as above) or written as nested tables
(``[grid.particles] friction = [...]``); a point's keys override ``[common]``.

*Calibration* (:func:`calibrate`) tunes one parameter until the mean escapees
before clogging ``<s>`` match a target: bracket, then regula falsi on
``log <s>`` (Illinois variant), each round one batch of realizations at one
value. Its interval is the parameter range over which the target lies inside
the (censoring-aware) confidence interval of ``<s>``; the value is the root of a
censoring-aware fit of ``log <s>`` linear in the parameter over that range (see
:func:`calibrate`).

Examples
--------
>>> from taichi_hsdem.sweep import run_sweep                       # doctest: +SKIP
>>> rows = run_sweep("scenes/hourglass24.toml",
...                  [{"particles.friction": mu} for mu in (0.2, 0.4)],
...                  "runs/friction", common={"run.t_end": 10.0})    # doctest: +SKIP
>>> [(r["folder"], r["mean_escapees"]) for r in rows]              # doctest: +SKIP
"""
from __future__ import annotations

import csv
import difflib
import hashlib
import io
import itertools
import json
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from .. import stats
from ..scene import Scene, SceneError, _toml_value, load_scene, read_toml, scene_to_toml

__all__ = [
    "SweepError", "Sweep", "load_sweep", "expand_grid", "point_folder", "run_sweep",
    "quick_overrides", "CalibrationError", "Evaluation", "Calibration", "calibrate",
    "simulation_evaluator",
]

SUMMARY, SERIES, RESOLVED = "summary.json", "escapees.csv", "scene.resolved.toml"
SWEEP_CSV, INDEX = "sweep.csv", "index.json"
#: Folder names longer than this are cut and given a hash of the overrides.
MAX_FOLDER_NAME = 100
#: ``quick``: this fraction of each point's ``run.t_end``, at most this many realizations.
QUICK_T_FRACTION = 0.1
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
    return _toml_value(value)


def _override_strings(overrides: Mapping[str, Any]) -> list[str]:
    # TOML spelling, so that a string stays a string and a list a list.
    return [f"{key}={_toml_value(value)}" for key, value in overrides.items()]


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


def expand_grid(grid: Mapping[str, Sequence]) -> list[dict[str, Any]]:
    """Cartesian product of ``{key: [values]}``, the last key varying fastest.

    Examples
    --------
    >>> expand_grid({"a": [1, 2], "b": [0.5]})
    [{'a': 1, 'b': 0.5}, {'a': 2, 'b': 0.5}]
    """
    keys = list(grid)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


def quick_overrides(scene: Scene) -> dict[str, Any]:
    """Overrides that make a smoke-test run of ``scene``: ``QUICK_T_FRACTION`` of
    its ``run.t_end`` and at most ``QUICK_REALIZATIONS`` realizations."""
    return {"run.t_end": QUICK_T_FRACTION * scene.run.t_end,
            "run.realizations": min(QUICK_REALIZATIONS, scene.run.realizations)}


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
    points: list[dict] = expand_grid(grid) if grid else []
    explicit = raw.get("points", [])
    if not isinstance(explicit, list) or not all(isinstance(p, Mapping) for p in explicit):
        bad("points", "expected an array of tables ([[points]])")
    else:
        points += [_flatten(p) for p in explicit]
    if not points and not problems:
        bad("grid", "nothing to sweep: add a [grid] of lists or [[points]] tables")
    if problems:
        raise SweepError(problems)
    _check_points(scene_path, points, common, label)
    return Sweep(scene=scene_path, common=common, points=tuple(points), source=label,
                 description=description)


def _check_points(scene_path, points, common, label) -> list[Scene]:
    """Load every point's scene; raise one SweepError listing every problem."""
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
    for k, point in enumerate(points):
        if not isinstance(point, Mapping) or not all(isinstance(key, str) for key in point):
            problems.append(f"{label}: point {k}: expected a dict of dotted keys to "
                            f"values, got {point!r}")
            continue
        where = f"{label}: point {k} ({_describe_point(point)})"
        folder = point_folder(point)
        if folder in folders:
            problems.append(f"{where}: repeats point {folders[folder]}")
            continue
        folders[folder] = k
        try:
            scenes.append(load_scene(scene_path, _override_strings({**common, **point})))
        except SceneError as error:
            problems += [f"{where}: {line}" for line in error.problems
                         if line not in shared]
        except TypeError as error:  # a value TOML cannot spell
            problems.append(f"{where}: {error}")
    backends = {(s.run.arch, s.run.precision) for s in scenes}
    if len(backends) > 1:
        problems.append(f"{label}: run.arch and run.precision must be the same at every "
                        f"point (one Taichi backend per process), got "
                        f"{sorted(backends)}")
    if problems:
        raise SweepError(problems)
    return scenes


# ---------------------------------------------------------------------------- runs

_CODE_DIGEST: str | None = None


def code_digest() -> str:
    """SHA-256 of the package's Python sources (file names and contents, sorted)
    and of the versions of the libraries that compute a result (Taichi, NumPy,
    SciPy, pyamg).

    Part of every resume key: a finished point computed by other code (a changed
    ``auto`` rule, a fixed bug) is run again rather than passed off as current.
    Deliberately the whole package, plotting included: a kept result also holds
    statistics computed when it ran, and telling which edit can change a number
    is not worth a stale figure. Read once per process, at the first call (the
    sweep and figure commands call it before their first point), so that an edit
    made while a long run goes on does not label the old code's results as new.
    """
    global _CODE_DIGEST
    if _CODE_DIGEST is None:
        from importlib import metadata
        h = hashlib.sha256()
        for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
            h.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
        for dist in ("taichi", "numpy", "scipy", "pyamg"):
            try:
                version = metadata.version(dist)
            except metadata.PackageNotFoundError:
                version = "absent"
            h.update(f"{dist}=={version}\0".encode())
        _CODE_DIGEST = h.hexdigest()
    return _CODE_DIGEST


def _scene_key(scene: Scene) -> str:
    """What makes two points the same run: the validated scene, as TOML text, and
    the code that runs it (:func:`code_digest`)."""
    return hashlib.sha256((scene_to_toml(scene) + "\n# code " + code_digest()).encode()
                          ).hexdigest()


def _finished_summary(folder: Path, key: str) -> dict | None:
    """The folder's summary if it is complete and of the scene ``key``, else None."""
    try:
        summary = json.loads((folder / SUMMARY).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(summary, dict) or not isinstance(summary.get("realizations"), list):
        return None
    sweep = summary.get("sweep")
    if not isinstance(sweep, dict) or sweep.get("scene_sha256") != key:
        return None
    if not ((folder / SERIES).is_file() and (folder / RESOLVED).is_file()):
        return None
    return summary


def _row(folder: str, point: Mapping, status: str, summary: dict | None,
         message: str | None = None) -> dict:
    """One point's line of the sweep table, from its summary."""
    row: dict[str, Any] = {"folder": folder, "status": status, "overrides": dict(point),
                           "message": message}
    real = (summary or {}).get("realizations") or []
    st = (summary or {}).get("statistics") or {}
    ok = [r for r in real if r.get("status") == "ok"]
    row.update(
        n=len(real), n_ok=len(ok), n_unstable=len(real) - len(ok),
        n_clogged=sum(1 for r in ok if r.get("clogged")),
        mean_escapees=st.get("mean_escapees"),
        mean_escapees_ci=st.get("mean_escapees_ci") or [None, None],
        mean_escapees_method=st.get("mean_escapees_method"),
        decay_rate=st.get("decay_rate"),
        decay_rate_ci=st.get("decay_rate_ci") or [None, None],
        never_clogged_fraction=st.get("never_clogged_fraction"),
        never_clogged_fraction_ci=st.get("never_clogged_fraction_ci") or [None, None],
        wall_time_s=(summary or {}).get("wall_time_s"))
    return row


_CSV_STATS = ("n", "n_ok", "n_unstable", "n_clogged", "mean_escapees",
              "mean_escapees_ci", "mean_escapees_method", "decay_rate", "decay_rate_ci",
              "never_clogged_fraction", "never_clogged_fraction_ci", "wall_time_s")


def _write_table(rows: list[dict], out: Path) -> None:
    """``sweep.csv``: folder, status, one column per override key, the statistics
    (an interval as two columns ``..._lo``, ``..._hi``); empty cells for missing."""
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row["overrides"] if k not in keys]
    header = ["folder", "status"] + keys
    for name in _CSV_STATS:
        header += [f"{name}_lo", f"{name}_hi"] if name.endswith("_ci") else [name]
    header.append("message")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)

    def cell(v):
        return "" if v is None else (repr(v) if isinstance(v, float) else v)

    for row in rows:
        line = [row["folder"], row["status"]]
        line += [_value_text(row["overrides"][k]) if k in row["overrides"] else ""
                 for k in keys]
        for name in _CSV_STATS:
            v = row[name]
            line += [cell(v[0]), cell(v[1])] if name.endswith("_ci") else [cell(v)]
        line.append(row["message"] or "")
        w.writerow(line)
    _atomic_text(out / SWEEP_CSV, buf.getvalue())


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text)
    tmp.replace(path)


def _write_index(out: Path, base: Path, common: Mapping, entries: dict[str, dict]) -> None:
    """``index.json``: folder -> overrides, merged with what earlier sweeps into
    the same folder recorded."""
    index = {}
    try:
        old = json.loads((out / INDEX).read_text())
        if isinstance(old, dict) and isinstance(old.get("points"), dict):
            index = old["points"]
    except (OSError, ValueError):
        pass
    index.update(entries)
    _atomic_text(out / INDEX, json.dumps({"scene": str(base), "common": dict(common),
                                          "points": index}, indent=1, default=str) + "\n")


def run_sweep(base_scene_path: str | Path, points: Sequence[Mapping[str, Any]],
              out_dir: str | Path, resume: bool = True,
              progress: Callable[[str], None] | None = None,
              common: Mapping[str, Any] | None = None, quick: bool = False) -> list[dict]:
    """Run ``base_scene_path`` at every point; write one folder per point.

    Parameters
    ----------
    base_scene_path : str or Path
        The scene file every point starts from.
    points : list of dict
        Dotted overrides per point, e.g. ``{"particles.friction": 0.4}``
        (the keys and checks of ``--set``; values are Python values).
    out_dir : str or Path
        Gets one folder per point (:func:`point_folder`), ``sweep.csv`` and
        ``index.json``.
    resume : bool
        Skip a point whose folder already holds a complete ``summary.json`` of the
        same scene; ``False`` runs every point again.
    progress : callable, optional
        Called with a one-line message as each point starts and ends.
    common : dict, optional
        Overrides applied to every point before its own.
    quick : bool
        Smoke test: each point run with :func:`quick_overrides` (a tenth of its
        ``run.t_end``, at most two realizations); folder names do not change, so
        give a separate ``out_dir``.

    Returns
    -------
    list of dict
        One row per point, in order: ``folder``, ``status`` (``"ran"``,
        ``"skipped"``, ``"unstable"``: ran but some realization went unstable,
        ``"failed"``: no result, see ``message``, ``"invalid"``: the set-up was
        refused), ``overrides``, ``message`` and the statistics of ``sweep.csv``
        (``n``, ``n_ok``, ``n_unstable``, ``n_clogged``, ``mean_escapees`` and its
        ``_ci``, ``decay_rate`` and its ``_ci``, ``never_clogged_fraction`` and its
        ``_ci``, ``wall_time_s``).

    Raises
    ------
    SweepError
        A point is not a valid scene (every problem listed; nothing is run).
    """
    from .. import backend
    from ..fluid import FluxImbalanceError
    from ..output import write_resolved_scene, write_series, write_summary
    from ..simulation import RunError, Simulation

    base = Path(base_scene_path)
    common = dict(common or {})
    points = [dict(p) for p in points]
    scenes = _check_points(base, points, common, str(base))
    if quick:
        scenes = [load_scene(base, _override_strings({**common, **point,
                                                      **quick_overrides(scene)}))
                  for point, scene in zip(points, scenes)]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    code_digest()                  # this process's code, before any point runs
    say = progress or (lambda message: None)
    rows = []
    total = len(points)
    for k, (point, scene) in enumerate(zip(points, scenes)):
        folder = point_folder(point)
        where = out / folder
        key = _scene_key(scene)
        head = f"[{k + 1}/{total}] {folder}"
        done = _finished_summary(where, key) if resume else None
        if done is not None:
            say(f"{head}: skipped (finished)")
            rows.append(_row(folder, point, "skipped", done))
            continue
        where.mkdir(parents=True, exist_ok=True)
        # A result of other overrides left here must not pass for this point's.
        (where / SUMMARY).unlink(missing_ok=True)
        try:
            sim = Simulation(scene)
        except (SceneError, backend.BackendError) as error:
            message = "; ".join(getattr(error, "problems", [str(error)]))
            say(f"{head}: refused: {message}")
            rows.append(_row(folder, point, "invalid", None, message))
            continue
        say(f"{head}: running {sim.R} realization(s) to t = {scene.run.t_end:g}")
        write_resolved_scene(sim.scene, where, sim.model.notes)
        try:
            result = sim.run()
        except FluxImbalanceError as error:
            message = (f"the pressure solve did not conserve mass ({error}); tighten "
                       f"fluid.solver_tol or refine fluid.cell_size")
            say(f"{head}: failed: {message}")
            rows.append(_row(folder, point, "failed", None, message))
            continue
        except RunError as error:
            say(f"{head}: failed: {error}")
            rows.append(_row(folder, point, "failed", None, str(error)))
            continue
        summary = result.summary
        summary["sweep"] = {"overrides": point, "common": common,
                            "base_scene": str(base), "scene_sha256": key}
        statuses = [r["status"] for r in summary["realizations"]]
        write_series(result.series, statuses, where)
        write_summary(summary, where)  # last: its presence marks the point finished
        summary = json.loads((where / SUMMARY).read_text())  # as later sweeps read it
        unstable = [r for r in summary["realizations"] if r["status"] != "ok"]
        status, message = "ran", None
        if unstable:
            status = "unstable"
            message = (f"{len(unstable)} realization(s) went unstable (seeds "
                       f"{', '.join(str(r['seed']) for r in unstable)}): lower run.dt "
                       f"(or run.dt_safety), raise kn, or lower the driving")
        row = _row(folder, point, status, summary, message)
        rows.append(row)
        mean, (lo, hi) = row["mean_escapees"], row["mean_escapees_ci"]
        say(f"{head}: done in {summary['wall_time_s']:.1f} s, mean escapees "
            f"{_fmt(mean)} [{_fmt(lo)}, {_fmt(hi)}], {row['n_clogged']}/{row['n_ok']} "
            f"clogged" + (f"; {message}" if message else ""))
        del sim, result
    _write_index(out, base, common, {row["folder"]: row["overrides"] for row in rows})
    _write_table(rows, out)
    return rows


def _fmt(value) -> str:
    return "-" if value is None else ("inf" if value == math.inf else f"{value:.4g}")


# --------------------------------------------------------------------- calibration

class CalibrationError(RuntimeError):
    """An evaluation gave nothing to calibrate on (message says what to change)."""


@dataclass(frozen=True)
class Evaluation:
    """One batch of realizations at one parameter value, and its statistics."""

    value: float
    escapees: tuple
    clogged: tuple
    mean: float              # <s>, censoring-aware (stats.mean_escapees)
    mean_ci: tuple
    n_clogged: int
    info: dict = field(default_factory=dict)   # what the evaluator reported besides

    @property
    def n(self) -> int:
        return len(self.escapees)

    @property
    def total(self) -> int:
        return int(sum(self.escapees))


@dataclass(frozen=True)
class Calibration:
    """The result of :func:`calibrate`.

    ``value`` is the calibrated parameter (NaN when the target was not
    bracketed) and ``ci`` the parameter range over which the target lies inside
    the ``confidence`` interval of ``<s>`` (interpolated between evaluations); an
    end flagged in ``ci_open`` lies at an evaluation whose interval still holds
    the target, so the data do not bound it on that side. ``window`` is the range
    of the evaluations whose pooled fit gave ``value``, and ``slope`` that fit's
    ``d log<s> / d param``.
    """

    target: float
    value: float
    ci: tuple
    ci_open: tuple
    confidence: float
    bracketed: bool
    converged: bool
    lo: float
    hi: float
    window: tuple
    slope: float
    evaluations: tuple
    message: str

    def to_dict(self) -> dict:
        """JSON-ready (non-finite numbers as None)."""
        def plain(v):
            if isinstance(v, (np.integer, np.floating, np.bool_)):
                v = v.item()
            if isinstance(v, float):
                return v if math.isfinite(v) else None
            if isinstance(v, (list, tuple)):
                return [plain(x) for x in v]
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            return v
        return plain({
            "target": self.target, "value": self.value, "ci": list(self.ci),
            "ci_open": list(self.ci_open), "confidence": self.confidence,
            "bracketed": self.bracketed, "converged": self.converged,
            "lo": self.lo, "hi": self.hi, "window": list(self.window),
            "slope_dlog_mean_dparam": self.slope, "message": self.message,
            "method": "ci: parameter range where the target lies inside the "
                      "interpolated confidence interval of <s>; value: root of log<s> "
                      "linear in the parameter, censoring-aware geometric likelihood "
                      "pooled over the window",
            "evaluations": [{"value": e.value, "n": e.n, "n_clogged": e.n_clogged,
                             "mean_escapees": e.mean, "mean_escapees_ci": list(e.mean_ci),
                             "escapees": list(e.escapees), "clogged": list(e.clogged),
                             **e.info} for e in self.evaluations]})


def _evaluation(value: float, escapees, clogged, confidence: float,
                info: dict | None = None) -> Evaluation:
    if len(escapees) == 0:
        raise CalibrationError(f"no stable realization at {value!r}: nothing to "
                               f"calibrate on (lower run.dt or raise the realizations)")
    s = np.asarray(escapees, dtype=np.int64)
    c = np.asarray(clogged, dtype=bool)
    mean, ci = stats.mean_escapees(s, c, confidence)
    if math.isnan(mean):
        raise CalibrationError(
            f"at {value!r} nothing escaped and nothing clogged in {s.size} "
            f"realization(s): <s> is undefined; run longer (run.t_end)")
    return Evaluation(value=float(value), escapees=tuple(int(v) for v in s),
                      clogged=tuple(bool(v) for v in c), mean=float(mean),
                      mean_ci=(float(ci[0]), float(ci[1])), n_clogged=int(c.sum()),
                      info=dict(info or {}))


def _log_gap(e: Evaluation, target: float) -> float:
    """``log <s> - log target``: the function whose root is calibrated (+inf when
    nothing clogged, -inf when every realization clogged at s = 0)."""
    if e.mean == math.inf:
        return math.inf
    if e.mean <= 0.0:
        return -math.inf
    return math.log(e.mean) - math.log(target)


def _merged(evals: Sequence[Evaluation], confidence: float) -> list[Evaluation]:
    """One evaluation per distinct value (batches at the same value pooled), sorted."""
    groups: dict[float, list[Evaluation]] = {}
    for e in evals:
        groups.setdefault(e.value, []).append(e)
    return [g[0] if len(g) == 1 else
            _evaluation(x, sum((e.escapees for e in g), ()), sum((e.clogged for e in g), ()),
                        confidence)
            for x, g in sorted(groups.items())]


def _band_interval(evals: list[Evaluation], target: float):
    """Hull of the parameter values where ``target`` lies between the lower and
    upper confidence bounds of ``<s>``, each interpolated linearly in log between
    neighbouring evaluations (``evals`` sorted, one per value). A bound of 0 or
    infinity holds over the whole segment next to it. Returns ((lo, hi),
    (open_lo, open_hi)), or None when no value qualifies."""
    big = 1e6   # stands for log(0) and log(inf): the crossing then sits at the other end
    lt = math.log(target)
    x = [e.value for e in evals]
    low = [lt - big if e.mean_ci[0] <= 0 else math.log(e.mean_ci[0]) for e in evals]
    up = [lt + big if e.mean_ci[1] == math.inf else
          (lt - big if e.mean_ci[1] <= 0 else math.log(e.mean_ci[1])) for e in evals]

    def part(a0, a1, below):
        """The t in [0, 1] with a0 + t (a1 - a0) <= lt (below) or >= lt."""
        d = a1 - a0
        if d == 0.0:
            ok = a0 <= lt if below else a0 >= lt
            return (0.0, 1.0) if ok else None
        t = (lt - a0) / d
        keep_low = (d > 0) == below   # the side of t that satisfies the inequality
        lo_t, hi_t = (0.0, min(1.0, t)) if keep_low else (max(0.0, t), 1.0)
        return (lo_t, hi_t) if lo_t <= hi_t else None

    inside = []
    for i in range(len(evals)):
        if low[i] <= lt <= up[i]:
            inside.append(x[i])
    for i in range(len(evals) - 1):
        a = part(low[i], low[i + 1], True)
        b = part(up[i], up[i + 1], False)
        if a and b and max(a[0], b[0]) <= min(a[1], b[1]):
            t0, t1 = max(a[0], b[0]), min(a[1], b[1])
            inside += [x[i] + t0 * (x[i + 1] - x[i]), x[i] + t1 * (x[i + 1] - x[i])]
    if not inside:
        return None
    first, last = evals[0], evals[-1]
    open_lo = min(inside) <= x[0] and low[0] <= lt <= up[0]
    open_hi = max(inside) >= x[-1] and low[-1] <= lt <= up[-1]
    return (min(inside), max(inside)), (bool(open_lo), bool(open_hi))


def _pooled_root(evals: list[Evaluation], target: float) -> tuple[float, float]:
    """Root of ``log <s> = a + b x`` fitted by maximum likelihood to the pooled
    evaluations (a clogged realization contributes ``(1 - p)^s p``, a censored
    one ``(1 - p)^s``, ``p = 1/(1 + <s>)``, as in :mod:`taichi_hsdem.stats`);
    returns (root, b)."""
    from scipy import optimize

    x = np.array([e.value for e in evals])
    k = np.array([e.n_clogged for e in evals], dtype=float)
    total = np.array([e.total for e in evals], dtype=float)
    x0, span = float(x.mean()), float(np.ptp(x))
    u = (x - x0) / span

    def nll(params):
        eta = params[0] + params[1] * u          # log <s>
        return -float(np.sum(total * eta - (k + total) * np.logaddexp(0.0, eta)))

    def grad(params):
        eta = params[0] + params[1] * u
        g = total - (k + total) / (1.0 + np.exp(-eta))
        return -np.array([g.sum(), (g * u).sum()])

    finite = [math.log(e.mean) for e in evals if 0.0 < e.mean < math.inf]
    start = np.array([float(np.mean(finite)) if finite else math.log(target), 0.0])
    # Bounded: an end with no clog (or only s = 0) pulls log<s> to +-infinity.
    best = optimize.minimize(nll, start, jac=grad, method="L-BFGS-B",
                             bounds=[(-50.0, 50.0), (-100.0, 100.0)])
    a, b = best.x
    root = x0 + span * (math.log(target) - a) / b if b != 0.0 else math.nan
    return root, b / span


def calibrate(evaluate: Callable[[float], tuple], target: float, lo: float, hi: float,
              rounds: int = 8, xtol: float = 0.0, confidence: float = 0.95,
              log: Callable[[str], None] | None = None) -> Calibration:
    """Find the parameter value at which the mean escapees ``<s>`` equal ``target``.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(value) -> (escapees, clogged)`` (optionally a third item, a dict
        recorded with the evaluation): one batch of independent realizations at
        ``value``, escapee counts and clog flags (``False``: censored at the end
        time).
    target : float
        The ``<s>`` to match, > 0.
    lo, hi : float
        The parameter range; ``<s>`` must cross the target inside it (in either
        direction: it usually falls with friction).
    rounds : int
        Evaluations in all, the two ends included (>= 2).
    xtol : float
        Stop early once the interval of the calibrated value is closed and
        narrower than this (0: run every round).
    confidence : float
        Level of every interval.
    log : callable, optional
        Called with one line per evaluation.

    Returns
    -------
    Calibration

    Notes
    -----
    The ends are evaluated first; if ``log <s> - log target`` has the same sign
    at both, the target is not bracketed and the result says so. Otherwise each
    round evaluates the regula falsi point of ``log <s>`` between the bracket's
    ends (Illinois variant, kept within the middle 80 % of the bracket; bisection
    while an end has no clog at all) and keeps the sub-bracket that still
    crosses.

    The interval is the range of the parameter over which the target lies inside
    the confidence interval of ``<s>`` (:func:`taichi_hsdem.stats.mean_escapees`,
    censoring-aware), the bounds interpolated linearly in ``log`` between
    neighbouring evaluations: it needs no model of ``<s>(param)`` beyond that
    interpolation, and it does not shrink below what one batch resolves (more
    realizations per round narrow it, more rounds near the root do not). The
    calibrated value is the root of ``log <s> = a + b x`` fitted by maximum
    likelihood to the evaluations inside the interval and the nearest one on
    each side of it, clipped to the interval.

    Examples
    --------
    A synthetic stand-in: ``<s> = 40 exp(-4 mu)``, 200 geometric realizations.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> def evaluate(mu):
    ...     s = rng.geometric(1.0 / (1.0 + 40.0 * np.exp(-4.0 * mu)), 200) - 1
    ...     return s, np.ones(s.size, bool)
    >>> cal = calibrate(evaluate, target=10.0, lo=0.0, hi=1.0)
    >>> bool(cal.ci[0] < np.log(4.0) / 4.0 < cal.ci[1])
    True
    """
    if not (target > 0 and math.isfinite(target)):
        raise ValueError(f"target must be a positive number, got {target!r}")
    if not lo < hi:
        raise ValueError(f"lo must be below hi, got lo = {lo!r}, hi = {hi!r}")
    if int(rounds) != rounds or rounds < 2:
        raise ValueError(f"rounds must be an integer >= 2, got {rounds!r}")
    stats.mean_escapees([1], [True], confidence)   # checks confidence
    say = log or (lambda message: None)
    evals: list[Evaluation] = []

    def run(value: float) -> float:
        out = evaluate(value)
        e = _evaluation(value, out[0], out[1], confidence, out[2] if len(out) > 2 else None)
        evals.append(e)
        say(f"round {len(evals)}: value {value:.6g}: <s> = {_fmt(e.mean)} "
            f"[{_fmt(e.mean_ci[0])}, {_fmt(e.mean_ci[1])}], {e.n_clogged}/{e.n} clogged")
        return _log_gap(e, target)

    def result(value, ci, ci_open, bracketed, converged, window, slope, message):
        return Calibration(target=float(target), value=value, ci=tuple(ci),
                           ci_open=tuple(ci_open), confidence=confidence,
                           bracketed=bracketed, converged=converged, lo=float(lo),
                           hi=float(hi), window=tuple(window), slope=slope,
                           evaluations=tuple(evals), message=message)

    a, b = float(lo), float(hi)
    g_a, g_b = run(a), run(b)
    if (g_a > 0) == (g_b > 0) and g_a != 0.0 and g_b != 0.0:
        side = "above" if g_a > 0 else "below"
        advice = ("no realization clogged at either end: run longer (run.t_end)"
                  if g_a == g_b == math.inf else "widen the range (lo, hi)")
        return result(math.nan, (math.nan, math.nan), (True, True), False, False,
                      (lo, hi), math.nan,
                      f"target {target:g} not bracketed: <s> = {_fmt(evals[0].mean)} at "
                      f"{lo:g} and {_fmt(evals[1].mean)} at {hi:g} are both {side} it; "
                      f"{advice}")
    kept = 0   # > 0: a replaced that many rounds in a row (b kept); < 0: the reverse
    for _ in range(int(rounds) - 2):
        if g_a == 0.0 or g_b == 0.0:
            break
        width = b - a
        if math.isfinite(g_a) and math.isfinite(g_b):
            x = b - g_b * width / (g_b - g_a)
            x = min(max(x, a + 0.1 * width), b - 0.1 * width)
        else:
            x = 0.5 * (a + b)
        g = run(x)
        if g == 0.0 or (g > 0) == (g_a > 0):
            a, g_a = x, g
            kept = max(kept, 0) + 1
            if kept >= 2:      # Illinois: the kept end's value halved
                g_b *= 0.5
        else:
            b, g_b = x, g
            kept = min(kept, 0) - 1
            if kept <= -2:
                g_a *= 0.5
        band = _band_interval(_merged(evals, confidence), target)
        if xtol > 0 and band and not any(band[1]) and band[0][1] - band[0][0] < xtol:
            break
    merged = _merged(evals, confidence)
    (ci_lo, ci_hi), ci_open = _band_interval(merged, target)
    xs = [e.value for e in merged]
    below = [e for e in merged if e.value < ci_lo]
    above = [e for e in merged if e.value > ci_hi]
    near = ([below[-1]] if below else []) + [e for e in merged if ci_lo <= e.value <= ci_hi] \
        + ([above[0]] if above else [])
    if len(near) < 2:
        near = sorted(merged, key=lambda e: abs(e.value - 0.5 * (ci_lo + ci_hi)))[:2]
    root, slope = _pooled_root(near, target)
    value = min(max(root, ci_lo), ci_hi) if math.isfinite(root) else 0.5 * (ci_lo + ci_hi)
    converged = not any(ci_open) and (xtol <= 0 or ci_hi - ci_lo < xtol)
    message = (f"calibrated {value:.6g}, interval [{ci_lo:.6g}, {ci_hi:.6g}] (the "
               f"target inside the {100 * confidence:g} % interval of <s>)")
    if any(ci_open):
        message += ("; open at the " + " and ".join(
            side for side, o in zip(("low", "high"), ci_open) if o)
            + " end: the data do not bound it inside the range")
    elif not converged:
        message += f"; wider than xtol = {xtol:g}: raise the realizations per round"
    return result(value, (ci_lo, ci_hi), ci_open, True, converged,
                  (min(e.value for e in near), max(e.value for e in near)), slope,
                  message)


def simulation_evaluator(scene_path: str | Path, param: str, realizations: int,
                         overrides: Iterable[str] = (), seed: int | None = None,
                         progress: Callable[[str], None] | None = None):
    """An ``evaluate(value)`` for :func:`calibrate` that runs the scene.

    Each call sets ``param = value``, runs ``realizations`` realizations with
    seeds not used by an earlier call (call ``i`` starts at
    ``seed + i * realizations``; ``seed`` defaults to the scene's ``run.seed``),
    and returns the escapees and clog flags of the stable realizations, plus a
    dict with ``seed``, ``n_unstable`` and ``wall_time_s``. The scene is checked
    when the evaluator is made (``SceneError``); check ``param`` at the values
    you will pass (``load_scene(scene_path, [f"{param}={value}"])``).
    """
    from ..simulation import Simulation

    overrides = list(overrides)
    scene = load_scene(scene_path, overrides)
    first = scene.run.seed if seed is None else int(seed)
    calls = itertools.count()
    say = progress or (lambda message: None)

    def evaluate(value: float):
        i = next(calls)
        s0 = first + i * realizations
        sc = load_scene(scene_path, overrides + [f"{param}={_toml_value(value)}",
                                                 f"run.realizations={realizations}",
                                                 f"run.seed={s0}"])
        say(f"{param} = {value:.6g}: {realizations} realization(s), seeds {s0}..."
            f"{s0 + realizations - 1}")
        t0 = time.perf_counter()
        result = Simulation(sc).run()
        real = result.summary["realizations"]
        ok = [r for r in real if r["status"] == "ok"]
        return ([r["escapees"] for r in ok], [bool(r["clogged"]) for r in ok],
                {"seed": s0, "n_unstable": len(real) - len(ok),
                 "wall_time_s": time.perf_counter() - t0})

    return evaluate
