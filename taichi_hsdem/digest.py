"""A digest of the code that computes a result, for the resume keys of sweeps and
figures: a kept result counts only for the code that made it."""
from __future__ import annotations

import hashlib
from importlib import metadata
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent

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
        h = hashlib.sha256()
        for path in sorted(_PACKAGE.rglob("*.py")):
            name = path.relative_to(_PACKAGE).as_posix()
            h.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
        for dist in ("taichi", "numpy", "scipy", "pyamg"):
            try:
                version = metadata.version(dist)
            except metadata.PackageNotFoundError:
                version = "absent"
            h.update(f"{dist}=={version}\0".encode())
        _CODE_DIGEST = h.hexdigest()
    return _CODE_DIGEST
