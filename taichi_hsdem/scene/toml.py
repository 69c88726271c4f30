"""TOML in and out: reading a file with one clear error per way it can fail, the
values of ``--set key=value``, and writing a scene back as TOML that reads back to
an equal scene."""
from __future__ import annotations

import math
import numbers
import re
import stat
from pathlib import Path
from typing import Any, Mapping

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from .keys import SceneError


def toml_string(text: str) -> str:
    """A TOML basic string, control characters escaped."""
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


def toml_value(value: Any) -> str:
    """``value`` spelled as TOML (numbers exactly, by ``repr``)."""
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
        return toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}"
                               for k, v in value.items()) + "}"
    return str(value)


def toml_key(key: str) -> str:
    """A bare key when TOML allows one, else a quoted one."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else toml_string(key)


#: The largest scene file read: real scenes are a few kB (a 1000-vertex polygon
#: is about 40 kB); past this a file is not a scene (``/dev/zero``, a log).
MAX_SCENE_BYTES = 16 * 2 ** 20


def parse_toml(text: str) -> dict:
    """TOML text as a dict (``tomllib.TOMLDecodeError`` when it is not TOML, also
    for arrays nested too deep for the parser's recursion)."""
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError("arrays or tables nested too deep") from None


def parse_override_value(text: str) -> Any:
    """A TOML value, or the text itself when it is not one (``flow_rate``)."""
    try:
        parsed = parse_toml(f"v = {text}")
    except tomllib.TOMLDecodeError:
        return text
    return parsed["v"] if list(parsed) == ["v"] else text


def read_toml(path: Path, what: str = "scene", error: type = None) -> dict:
    """A TOML file as a dict; every way it can fail becomes ``error`` (default
    :class:`SceneError`) with one line naming the file (``what`` it should be)."""
    error = error or SceneError
    try:
        try:
            info = path.stat()
        except ValueError:              # os.stat refuses a NUL in the path
            raise error(f"{str(path)!r}: not a file name (it holds a NUL character)") from None
        if stat.S_ISDIR(info.st_mode):
            raise IsADirectoryError
        # A device or FIFO would be read forever (/dev/zero) or block (a pipe).
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{path}: not a regular file (a device, pipe or socket); give a "
                        f"{what} file")
        with open(path, "rb") as fh:
            data = fh.read(MAX_SCENE_BYTES + 1)
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, not a {what} file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(data) > MAX_SCENE_BYTES:
        raise error(f"{path}: larger than {MAX_SCENE_BYTES // 2 ** 20} MB: not a {what} "
                    "file (a scene is a few kB)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start})") from None
    try:
        return parse_toml(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: invalid TOML: {exc}") from None


def scene_to_toml(scene) -> str:
    """The scene as TOML text that `load_scene` reads back to an equal scene."""
    lines = ["# Scene written by taichi_hsdem: every key, defaults filled in."]
    data = scene.to_dict()
    tables = []
    for key, value in data.items():
        if isinstance(value, Mapping):
            tables.append((f"[{toml_key(key)}]", value))
        elif isinstance(value, list) and value and all(isinstance(v, Mapping)
                                                       for v in value):
            tables += [(f"[[{toml_key(key)}]]", v) for v in value]
        else:
            lines.append(f"{toml_key(key)} = {toml_value(value)}")
    for header, table in tables:
        lines += ["", header]
        lines += [f"{toml_key(k)} = {toml_value(v)}" for k, v in table.items()
                  if v is not None]
    return "\n".join(lines) + "\n"
