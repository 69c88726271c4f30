"""Every module of the package stays at most MAX_LINES long (issue 47 item 5): a
module past it is split along a seam of its own (as fluid/_gmg_setup.py from
_gmg_cycle.py and scene/checks.py from load.py)."""
from pathlib import Path

MAX_LINES = 700
PACKAGE = Path(__file__).resolve().parent.parent / "taichi_hsdem"


def test_no_module_is_over_700_lines():
    modules = sorted(PACKAGE.rglob("*.py"))
    assert len(modules) > 20   # the package is where it should be
    lengths = {path.relative_to(PACKAGE).as_posix(): len(path.read_text("utf-8").splitlines())
               for path in modules}
    too_long = {name: n for name, n in lengths.items() if n > MAX_LINES}
    assert not too_long, f"modules over {MAX_LINES} lines: {too_long}"
