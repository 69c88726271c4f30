"""The scene-key tables of ``docs/scene.md``, generated from :mod:`.keys`.

Every key's kind, allowed range, default and documentation live in its
:class:`~.keys.Spec`; this module writes them as Markdown tables between marker
comments in ``docs/scene.md``, so the reference and the validation cannot drift
apart (``tests/test_docs.py`` checks that the committed file equals what this
module generates). The prose around the tables is written by hand.

``python -m taichi_hsdem.scene.docgen`` prints the tables; ``--write`` rewrites
the tables of ``docs/scene.md`` in place, ``--check`` exits 1 when they are stale.

Examples
--------
>>> from taichi_hsdem.scene.keys import DampingConfig
>>> print(table(DampingConfig))
| key | accepts | default | meaning |
|---|---|---|---|
| `xi` | float >= 0 or `"auto"` | `"auto"` | global damping, 1/s; "auto": the plate drag |
"""
from __future__ import annotations

import argparse
import dataclasses
import re
import sys
from pathlib import Path

from .keys import SECTIONS, Spec, SpeciesConfig, key_specs
from .load import Scene

#: The repository's scene reference (the package is installed from the checkout).
DOC = Path(__file__).resolve().parents[2] / "docs" / "scene.md"

_BEGIN = "<!-- BEGIN GENERATED KEYS: {name} (python -m taichi_hsdem.scene.docgen --write) -->"
_END = "<!-- END GENERATED KEYS: {name} -->"
_BLOCK = re.compile(r"(<!-- BEGIN GENERATED KEYS: (?P<name>[\w.]+) [^\n]*-->\n)"
                    r"(?:.*?\n)?(<!-- END GENERATED KEYS: (?P=name) -->)", re.S)

_KINDS = {"float": "float", "int": "int", "bool": "bool", "str": "string",
          "points": "list of `[x, y]`", "poses": "list of `[x, y]` or `[x, y, theta]`",
          "polygons": "list of polygons (each a list of `[x, y]`)",
          "interval": "`[x0, x1]`"}


def _number(value) -> str:
    text = repr(value)
    return re.sub(r"e([+-])0*(\d)", lambda m: "e" + m.group(1).replace("+", "") + m.group(2),
                  text)


def _value(value) -> str:
    """A default as it is written in TOML."""
    if isinstance(value, bool):
        return f"`{'true' if value else 'false'}`"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, (int, float)):
        return f"`{_number(value)}`"
    if isinstance(value, tuple):
        return "`[]`" if not value else f"`{list(value)}`"
    return f"`{value}`"


def accepts(spec: Spec) -> str:
    """What a key accepts, e.g. ``float in (0, 1]`` or ``int >= 1 or "auto"``."""
    if spec.kind == "choice":
        text = ", ".join(f'`"{c}"`' for c in spec.choices)
    else:
        text = _KINDS[spec.kind]
        lo = (f"({_number(spec.gt)}" if spec.gt is not None
              else f"[{_number(spec.ge)}" if spec.ge is not None else None)
        hi = (f"{_number(spec.lt)})" if spec.lt is not None
              else f"{_number(spec.le)}]" if spec.le is not None else None)
        if lo and hi:
            text += f" in {lo}, {hi}"
        elif lo:
            text += (" > " if lo[0] == "(" else " >= ") + lo[1:]
        elif hi:
            text += (" < " if hi[-1] == ")" else " <= ") + hi[:-1]
        if spec.min_len > 1:
            text += f" (at least {spec.min_len})"
    if spec.auto:
        text += ' or `"auto"`'
    return text


def _default(spec: Spec, default) -> str:
    if spec.required:
        return "required"
    if default is None:
        return "see meaning"
    return _value(default)


def table(cls, only: tuple[str, ...] | None = None) -> str:
    """The Markdown table of ``cls``'s keys; with ``only``, just the keys used only by
    those geometry kinds / shapes (``()``: the keys every kind uses)."""
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    rows = ["| key | accepts | default | meaning |", "|---|---|---|---|"]
    for name, spec in key_specs(cls).items():
        if only is not None and spec.only != only:
            continue
        doc = spec.doc.replace("|", "\\|")
        if only is None and spec.only:
            doc += " (only for " + ", ".join(f'`"{s}"`' for s in spec.only) + ")"
        rows.append(f"| `{name}` | {accepts(spec)} | {_default(spec, defaults[name])} "
                    f"| {doc} |")
    return "\n".join(rows)


def tables() -> dict[str, str]:
    """Every generated table of docs/scene.md, by its marker name."""
    out = {"top": table(Scene)}
    for name, cls in SECTIONS.items():
        if name == "geometry":
            out["geometry"] = table(cls, only=())
            kinds = sorted({s.only for s in key_specs(cls).values() if s.only})
            for kinds_ in kinds:
                out["geometry." + "_".join(kinds_)] = table(cls, only=kinds_)
        else:
            out[name] = table(cls)
    out["particles"] = table(SpeciesConfig)
    return out


def render(text: str) -> str:
    """``text`` (docs/scene.md) with every generated block replaced by the current
    table; a block whose name is unknown is left as it is (the test then fails on
    the missing table)."""
    current = tables()

    def fill(m):
        name = m.group("name")
        if name not in current:
            return m.group(0)
        return m.group(1) + current[name] + "\n" + m.group(3)

    return _BLOCK.sub(fill, text)


def markers(name: str) -> tuple[str, str]:
    """The begin and end comments around table ``name``."""
    return _BEGIN.format(name=name), _END.format(name=name)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m taichi_hsdem.scene.docgen",
                                description="Scene-key tables of docs/scene.md, "
                                            "generated from taichi_hsdem/scene/keys.py.")
    p.add_argument("--doc", type=Path, default=DOC, help="the scene reference to update")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="rewrite the tables in --doc")
    mode.add_argument("--check", action="store_true",
                      help="exit 1 when the tables in --doc are not the generated ones")
    args = p.parse_args(argv)
    if not (args.write or args.check):
        for name, text in tables().items():
            print("\n".join([markers(name)[0], text, markers(name)[1], ""]))
        return 0
    try:
        old = args.doc.read_text()
    except OSError as e:
        print(f"{args.doc}: {e.strerror}", file=sys.stderr)
        return 2
    new = render(old)
    if args.check:
        if new != old:
            print(f"{args.doc}: the key tables differ from taichi_hsdem/scene/keys.py; "
                  "run python -m taichi_hsdem.scene.docgen --write", file=sys.stderr)
            return 1
        return 0
    if new != old:
        args.doc.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
