"""Reading one table of a scene against its keys' specs (:mod:`.keys`): each value
converted to its kind or reported, once, as ``"ORIGIN: key: problem"`` in the
user's terms (the file or the ``--set`` that gave it), with a suggestion for a
misspelt key or choice."""
from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
from typing import Any, Iterable, Mapping

from .keys import AUTO, MAX_MAGNITUDE, MIN_MAGNITUDE, SECTIONS, Spec, SpeciesConfig, key_specs
from .toml import toml_value

BAD = object()  # a value already reported as invalid


MISSING = object()  # a key the table does not give


class Problems:
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


def show(value: Any, limit: int = 60) -> str:
    try:
        text = toml_value(value)
    except Exception:  # a value TOML cannot spell (e.g. a lone surrogate)
        text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def describe(value: Any) -> str:
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
    return f"{kind} {show(value)}"


def _num(x: float) -> str:
    return repr(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(x)


def _range_text(spec: Spec) -> str:
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


def _in_range(x: float, spec: Spec) -> bool:
    return ((spec.gt is None or x > spec.gt) and (spec.ge is None or x >= spec.ge)
            and (spec.lt is None or x < spec.lt) and (spec.le is None or x <= spec.le))


def suggest(word: str, candidates: Iterable[str]) -> str:
    match = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {match[0]!r}?)" if match else ""


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_int(value: Any) -> bool:
    """An integer, not a bool (which Python counts as one)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_finite_real(value: Any) -> bool:
    """A finite real number, not a bool: what a file's numeric field must hold."""
    return _is_real(value) and math.isfinite(value)


def _expected(spec: Spec) -> str:
    what = {"float": "a number", "int": "an integer", "bool": "true or false",
            "str": "a string", "choice": "one of " + ", ".join(map(repr, spec.choices)),
            "points": "an array of [x, y] pairs", "polygons": "an array of polygons",
            "poses": "an array of [x, y] or [x, y, theta]",
            "interval": "[x0, x1]"}[spec.kind]
    limits = _range_text(spec)
    if limits:
        what += " " + limits
    return what + (' or "auto"' if spec.auto else "")


def _coerce_point(value: Any, key: str, out: Problems):
    if (isinstance(value, (list, tuple)) and len(value) == 2
            and all(is_finite_real(c) for c in value)):
        return (float(value[0]), float(value[1]))
    out.add(key, f"expected [x, y] with two finite numbers, got {describe(value)}")
    return BAD


def _coerce_pose(value: Any, key: str, out: Problems):
    if (isinstance(value, (list, tuple)) and len(value) in (2, 3)
            and all(is_finite_real(c) for c in value)):
        return (float(value[0]), float(value[1]),
                float(value[2]) if len(value) == 3 else 0.0)
    out.add(key, f"expected [x, y] or [x, y, theta] with finite numbers, got {describe(value)}")
    return BAD


def _coerce_array(value: Any, key: str, out: Problems, item, what: str,
                  min_len: int = 0, unit: str = "entries", max_len: int | None = None):
    """A tuple of ``item(entry, "key[i]", out)`` for an array ``value`` of
    ``min_len`` to ``max_len`` entries, or BAD after reporting why not (the first
    bad entry only: a huge array of bad entries is one line, not a line each)."""
    if not isinstance(value, (list, tuple)):
        out.add(key, f"expected an array of {what}, got {describe(value)}")
        return BAD
    if max_len is not None and len(value) > max_len:
        out.add(key, f"has {len(value)} {unit}, more than the {max_len} a run can afford "
                     "(its set-up and every contact grow with them); simplify it")
        return BAD
    items = []
    for i, p in enumerate(value):
        items.append(item(p, f"{key}[{i}]", out))
        if items[-1] is BAD:
            return BAD
    if len(items) < min_len:
        out.add(key, f"needs at least {min_len} {unit}, got {len(items)}")
        return BAD
    return tuple(items)


def _coerce_points(value: Any, key: str, min_len: int, out: Problems,
                   max_len: int | None = None):
    return _coerce_array(value, key, out, _coerce_point, "[x, y] pairs", min_len, "vertices",
                         max_len)


def _coerce(value: Any, spec: Spec, key: str, out: Problems) -> Any:
    """``value`` converted to the key's type, or BAD after reporting why not."""
    if spec.auto and value == AUTO:
        return AUTO
    kind = spec.kind
    if kind in ("float", "int"):
        if not (is_int(value) if kind == "int" else _is_real(value)):
            hint = ""
            if isinstance(value, str):
                hint = suggest(value, [AUTO]) if spec.auto else ""
            out.add(key, f"expected {_expected(spec)}, got {describe(value)}{hint}")
            return BAD
        try:
            number = int(value) if kind == "int" else float(value)
        except OverflowError:
            number = math.inf
        if not math.isfinite(number):
            out.add(key, f"expected a finite number, got {show(number)}")
            return BAD
        if not _in_range(number, spec):
            out.add(key, f"must be {_range_text(spec)}, got {show(number)}")
            return BAD
        if kind == "float" and number != 0 and not (
                MIN_MAGNITUDE <= abs(number) <= MAX_MAGNITUDE):
            out.add(key, f"{show(number)} is outside the magnitudes the simulator computes "
                         f"with ({MIN_MAGNITUDE:g} to {MAX_MAGNITUDE:g}, or 0); use SI units, "
                         "or dimensionless numbers of ordinary size")
            return BAD
        return number
    if kind == "bool":
        if isinstance(value, bool):
            return value
        out.add(key, f"expected true or false, got {describe(value)}")
        return BAD
    if kind in ("str", "choice"):
        if not isinstance(value, str):
            out.add(key, f"expected {_expected(spec)}, got {describe(value)}")
            return BAD
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            out.add(key, f"not valid Unicode text: {value!r}")
            return BAD
        if kind == "choice" and value not in spec.choices:
            out.add(key, f"must be one of {', '.join(map(repr, spec.choices))}, got "
                         f"{show(value)}{suggest(value, spec.choices)}")
            return BAD
        return value
    if kind == "points":
        return _coerce_points(value, key, spec.min_len, out, spec.max_len)
    if kind == "poses":
        return _coerce_array(value, key, out, _coerce_pose, "[x, y] or [x, y, theta]",
                             spec.min_len)
    if kind == "polygons":
        return _coerce_array(value, key, out,
                             lambda p, where, o: _coerce_points(p, where, 3, o, spec.max_len),
                             "polygons", max_len=spec.max_len)
    # interval
    if (isinstance(value, (list, tuple)) and len(value) == 2
            and all(is_finite_real(c) for c in value)):
        if value[0] < value[1]:
            return (float(value[0]), float(value[1]))
        out.add(key, f"expected [x0, x1] with x0 < x1, got {show(value)}")
        return BAD
    out.add(key, f"expected [x0, x1] with two finite numbers, got {describe(value)}")
    return BAD


def read_table(cls, raw: Any, where: str, out: Problems,
                discriminator: str | None = None) -> dict[str, Any]:
    """Type-check one table against ``cls``'s keys.

    Returns every key's value: converted, the static default, ``None`` (optional and
    absent, or not used by the discriminator's value) or BAD (already reported).
    """
    specs = key_specs(cls)
    prefix = f"{where}." if where else ""
    if raw is MISSING:
        raw = {}
    if not isinstance(raw, Mapping):
        header = "[[particles]]" if where.startswith("particles") else f"[{where}]"
        out.add(where, f"expected a table {header}, got {describe(raw)}")
        return dict.fromkeys(specs, BAD)
    for key in raw:
        if str(key) not in specs:
            out.add(prefix + str(key), unknown_key_message(str(key), specs, where))
    chosen = None
    if discriminator:
        chosen = (_coerce(raw[discriminator], specs[discriminator],
                          prefix + discriminator, out) if discriminator in raw
                  else MISSING)
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
            values[name] = BAD if name in raw else None
            continue
        else:
            values[name] = (_coerce(raw[name], spec, key, out) if name in raw
                            else MISSING)
        if values[name] is MISSING:
            if spec.required:
                needed = f" for {discriminator} {chosen!r}" if spec.only else ""
                out.add(key, f"missing: required{needed}")
                values[name] = BAD
            else:
                values[name] = defaults[name]
    return values


def unknown_key_message(key: str, known: Iterable[str], where: str) -> str:
    """Says ``key`` is unknown in table ``where`` ("" for the top level), suggesting
    the closest known key, or else the tables where such a key belongs."""
    suggestion = suggest(key, known)
    if suggestion:
        return ("unknown key" if where else "unknown section or key") + suggestion
    homes = [f"[{name}]" for name, cls in SECTIONS.items()
             if name != where and key in key_specs(cls)]
    if key in key_specs(SpeciesConfig) and not where.startswith("particles"):
        homes.append("[[particles]]")
    if not where:
        message = "unknown section or key"
        return message + (f"; it belongs in {' or '.join(homes)}" if homes else "")
    return "unknown key" + (f" here; it belongs in {' or '.join(homes)}" if homes else "")


def good(*values: Any) -> bool:
    return all(v is not None and v is not BAD and v != AUTO for v in values)
