"""The documentation matches the code: every scene key is in docs/scene.md, in its
section's table, and the README's commands name files that exist."""
import re
from pathlib import Path

from taichi_hsdem.scene.keys import SECTIONS, SpeciesConfig, key_specs
from taichi_hsdem.scene.load import Scene

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "scene.md").read_text()


def _table(heading: str) -> str:
    start = DOC.index(heading)
    nxt = DOC.find("\n## ", start + 1)
    return DOC[start:nxt if nxt >= 0 else None]


def test_every_scene_key_is_documented_in_its_section():
    tables = {name: _table(f"## `[{name}]`") for name in SECTIONS}
    tables["particles"] = _table("## `[[particles]]`")
    tables["top"] = _table("## Top level")
    missing = []
    for name, cls in [*SECTIONS.items(), ("particles", SpeciesConfig), ("top", Scene)]:
        for key in key_specs(cls):
            if not re.search(rf"^\| (`\w+`, )*`{key}`(, `\w+`)* \|", tables[name], re.M):
                missing.append(f"{name}.{key}")
    assert not missing, missing


def test_readme_commands_name_files_that_exist():
    readme = (ROOT / "README.md").read_text()
    paths = set(re.findall(r"\b((?:tools|scenes|tests|docs)/[\w./-]+\.(?:py|toml|sh|md))\b",
                           readme))
    assert paths, "no paths found"
    assert not [p for p in paths if not (ROOT / p).exists()]
