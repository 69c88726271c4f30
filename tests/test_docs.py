"""The documentation matches the code: the scene-key tables of docs/scene.md are the
ones generated from the keys, every relative link resolves, every file, command
flag and `path: function` pointer the documents name exists, and nothing points
outside the repository."""
import argparse
import importlib
import re
from pathlib import Path

import pytest

from taichi_hsdem.cli import COMMANDS, _parser
from taichi_hsdem.scene import docgen
from taichi_hsdem.scene.keys import SECTIONS, SpeciesConfig, key_specs
from taichi_hsdem.scene.load import Scene

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]
SCENE_DOC = ROOT / "docs" / "scene.md"


def _text(path: Path) -> str:
    return path.read_text()


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _prose(text: str) -> str:
    """The text without fenced code blocks (Python snippets name files they write)."""
    return re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)


def _anchors(text: str) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation but '-' and '_' dropped,
    spaces to '-'."""
    out = set()
    for heading in re.findall(r"^#+ (.+)$", text, re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        out.add(slug)
    return out


def test_scene_key_tables_are_the_generated_ones():
    doc = _text(SCENE_DOC)
    assert docgen.render(doc) == doc, (
        "docs/scene.md's key tables differ from taichi_hsdem/scene/keys.py: "
        "run python -m taichi_hsdem.scene.docgen --write")
    for name in docgen.tables():
        begin, end = docgen.markers(name)
        assert doc.count(begin) == 1 and doc.count(end) == 1, f"table {name} missing"


def test_every_scene_key_is_documented_in_its_section():
    doc = _text(SCENE_DOC)

    def section(heading):
        start = doc.index(heading)
        nxt = doc.find("\n## ", start + 1)
        return doc[start:nxt if nxt >= 0 else None]

    tables = {name: section(f"## `[{name}]`") for name in SECTIONS}
    tables["particles"] = section("## `[[particles]]`")
    tables["top"] = section("## Top level")
    missing = [f"{name}.{key}"
               for name, cls in [*SECTIONS.items(), ("particles", SpeciesConfig),
                                 ("top", Scene)]
               for key in key_specs(cls)
               if not re.search(rf"^\| `{key}` \|", tables[name], re.M)]
    assert not missing, missing


def test_generated_table_reads_the_key_specs():
    # One key's row, written out by hand from its Spec in keys.py.
    row = ("| `dt_safety` | float in (0, 1] | `0.15` | fraction of the critical step "
           'that dt = "auto" uses, dimensionless |')
    assert row in docgen.tables()["run"]


def test_docgen_check_flags_a_stale_table(tmp_path, capsys):
    stale = tmp_path / "scene.md"
    stale.write_text(_text(SCENE_DOC).replace("| `dt_safety` |", "| `dt_safe` |"))
    assert docgen.main(["--doc", str(stale), "--check"]) == 1
    assert "docgen --write" in capsys.readouterr().err
    assert docgen.main(["--doc", str(stale), "--write"]) == 0
    assert stale.read_text() == _text(SCENE_DOC)


@pytest.mark.parametrize("doc", DOCS, ids=_name)
def test_relative_links_resolve(doc):
    text = _text(doc)
    bad = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        dest = (doc.parent / path).resolve() if path else doc
        if not dest.exists():
            bad.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(_text(dest)):
            bad.append(target)
    assert not bad, bad


@pytest.mark.parametrize("doc", DOCS, ids=_name)
def test_named_files_exist(doc):
    text = _prose(_text(doc))
    paths = set(re.findall(
        r"(?<![\w./-])((?:tools|scenes|tests|docs|taichi_hsdem)/[\w./-]*\w)", text))
    bad = sorted(p for p in paths if not (ROOT / p).exists())
    assert not bad, bad


def _options(parser: argparse.ArgumentParser, command: list[str]) -> set[str]:
    """Option strings the parser (or the subcommand ``command`` starts with) takes."""
    opts = set(parser._option_string_actions)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command \
                and command[0] in action.choices:
            opts |= _options(action.choices[command[0]], command[1:])
    return opts


def _commands(text: str, program: str) -> list[str]:
    """What follows ``program`` in each code span and indented block (a command
    may wrap onto the next line of either)."""
    blocks = ["\n".join(b) for b in _indented_blocks(text)]
    spans = re.findall(r"`([^`]+)`", re.sub(r"^```.*?^```", "", text, flags=re.S | re.M))
    found = []
    for chunk in blocks + spans:
        flat = re.sub(r"\s+", " ", chunk)
        found += flat.split(program)[1:]
    return found


def _indented_blocks(text: str) -> list[list[str]]:
    blocks, current = [], []
    for line in text.splitlines():
        if line.startswith("    ") and not line.lstrip().startswith(("*", "|")):
            current.append(line)
        elif current:
            blocks.append(current)
            current = []
    return blocks + ([current] if current else [])


@pytest.mark.parametrize("doc", DOCS, ids=_name)
def test_command_flags_exist(doc):
    text = _text(doc)
    bad = []
    for tail in _commands(text, "python -m taichi_hsdem "):
        words = tail.split()
        if words and words[0].startswith("."):      # python -m taichi_hsdem.scene.docgen
            continue
        parser = _parser()
        if words and words[0] in COMMANDS:          # a study's own command line
            module = importlib.import_module(f"taichi_hsdem.studies.{COMMANDS[words[0]]}")
            parser, words = module._parser("x"), words[1:]
        words = [w.split("|")[0] for w in words]    # a|b|c: alternatives, one parser
        flags = {w.split("=")[0] for w in re.findall(r"(?<![\w-])--[\w-]+=?", tail)}
        bad += [f for f in flags if f not in _options(parser, words)]
    assert not bad, bad


@pytest.mark.parametrize("doc", DOCS, ids=_name)
def test_named_tools_exist(doc):
    scripts = set(re.findall(r"python (tools/[\w/]+\.py)", re.sub(r"\s+", " ", _text(doc))))
    assert not [s for s in scripts if not (ROOT / s).exists()]


@pytest.mark.parametrize("doc", DOCS, ids=_name)
def test_code_pointers_exist(doc):
    """`path.py: name, name` names a function, class or constant defined in that file."""
    bad = []
    for path, names in re.findall(r"`((?:taichi_hsdem|tests|tools)/[\w/]+\.py): ([\w., ]+)`",
                                  re.sub(r"\s*\n\s*", " ", _text(doc))):
        source = (ROOT / path).read_text() if (ROOT / path).exists() else ""
        for name in names.split(","):
            name = name.strip().split(".")[-1]
            if not re.search(rf"^\s*(def|class) {name}\b|^{name}\s*=", source, re.M):
                bad.append(f"{path}: {name}")
    assert not bad, bad


@pytest.mark.parametrize("doc", DOCS, ids=_name)
def test_nothing_points_outside_the_repository(doc):
    text = _text(doc)
    assert "../shared" not in text and "MODEL.md" not in text
    assert not re.search(r"\]\(\.\./", text)


def test_readme_is_short_and_keeps_the_set_up_and_test_commands():
    readme = _text(ROOT / "README.md")
    assert len(readme.splitlines()) <= 300
    for line in ("    bash tools/setup.sh && . tools/env.sh",
                 "    python -m taichi_hsdem scenes/vani_phi026.toml --realizations 20 "
                 "--video --set run.t_end=2",
                 "    python -m pytest -q"):
        assert line + "\n" in readme
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert "python -m pytest -q" in ci


def _readme_api_block() -> str:
    """The fenced python block right after the README's "## Python API" heading."""
    text = _text(ROOT / "README.md")
    section = text[text.index("## Python API"):]
    section = section[:section.find("\n## ", 1)]
    found = re.search(r"^```python\n(.*?)^```", section, re.S | re.M)
    assert found, "README.md: no python block under ## Python API"
    return found.group(1)


def test_the_readme_api_example_prints_a_real_mean_escapees():
    """The README's API example runs as shipped (from the repository root, in a
    fresh process: Taichi takes one backend per process) and its first line is a
    finite <s>, not None. About 30 s on two CPU cores."""
    import math
    import subprocess
    import sys
    proc = subprocess.run([sys.executable, "-c", _readme_api_block()], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    first = proc.stdout.strip().splitlines()[0]
    mean = float(first.split()[0])          # "None" raises here
    assert math.isfinite(mean) and mean > 0, first
