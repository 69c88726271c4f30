"""The output folder of a study (``sweep``, ``figures``, ``calibrate``): the rules
of a run's folder (:mod:`taichi_hsdem.output`) for the studies.

* Two writers never mix: a study holds the folder's lock (the same
  ``.taichi_hsdem.lock`` a run takes, so a run and a study exclude each other too)
  while it writes; a second one is refused (:class:`StudyFolderError`, exit 2).
* The user's files are never replaced: the study's manifest
  (:data:`STUDY_MANIFEST`, beside the run's own) names every file a study wrote in
  the folder, listed before the file is written; a file of a study's result name
  that it does not list is the user's, and the study refuses to replace it.
* A folder holds one kind of study: the manifest names it (``"sweep"``,
  ``"figures friction"``, ``"calibrate"``); another kind is refused.
* A file, or a link to nothing, where a folder is expected is refused.

A folder written by a version of the studies from before the manifest is read by
what its files hold (``legacy``: a sweep's ``index.json``, a figure's
``figure.json``, ...).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable, Iterable

from .. import output
from ..output import atomic_write
from ..scene import SceneError

try:                       # where it lives (scene.checks), or lived (scene.load)
    from ..scene.checks import path_length_problem
except ImportError:        # pragma: no cover
    from ..scene.load import path_length_problem

#: The list of the files the studies of taichi_hsdem wrote in a study's folder.
STUDY_MANIFEST = ".taichi_hsdem-study.json"


class StudyFolderError(SceneError):
    """The study's output folder cannot be used; one line (``problems``)."""


def folder_problem(path: Path, key: str = "--out") -> str | None:
    """Why ``path`` cannot be a folder a study writes into (a file, a link to
    nothing, under a file, not writable, too long), or None. Creates nothing."""
    path = Path(path)
    too_long = path_length_problem(path)
    if too_long:
        return f"{key}: {path}: {too_long}"
    try:
        if os.path.islink(path) and not path.exists():
            return (f"{key}: {path} is a link to {os.readlink(path)}, which does not "
                    "exist (or is a loop of links)")
        if path.exists() and not path.is_dir():
            return f"{key}: {path} is a file, not a folder"
        probe = path
        while not os.path.lexists(probe) and probe.parent != probe:
            probe = probe.parent
        if not probe.is_dir():
            return f"{key}: {path} lies under {probe}, which is not a folder"
        if not os.access(probe, os.W_OK | os.X_OK):
            return f"{key}: cannot write in {probe} (permission denied)"
    except OSError as exc:
        return f"{key}: cannot use {path} ({exc.strerror or exc})"
    return None


class StudyFolder:
    """``with StudyFolder(out, "sweep") as folder``: checks ``out``
    (:func:`folder_problem`), creates it, takes its lock and reads its manifest;
    :meth:`refuse_foreign` refuses names the studies did not write there,
    :meth:`claim` lists names in the manifest before they are written. Leaving
    the block releases the lock, and removes ``out`` when it was created here and
    is left empty. Every refusal is a :class:`StudyFolderError` of one line.

    ``legacy(out)``: the names a study of an earlier version (no manifest) wrote
    there, read from what the folder holds.
    """

    def __init__(self, out, study: str, key: str = "--out",
                 legacy: Callable[[Path], Iterable[str]] | None = None):
        self.out = Path(out)
        self.study = study
        self.key = key
        self._legacy = legacy
        self._lock = None
        self._created = False
        self.files: set[str] = set()

    # ------------------------------------------------------------------ lock
    def __enter__(self):
        problem = folder_problem(self.out, self.key)
        if problem:
            raise StudyFolderError(problem)
        self._created = not os.path.lexists(self.out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StudyFolderError(f"{self.key}: cannot create {self.out} "
                                   f"({exc.strerror or exc})") from None
        try:
            self._take_lock()
            self._read_manifest()
        except BaseException:
            self.__exit__()
            raise
        return self

    def _take_lock(self):
        import fcntl
        problem = output.lock_problem(self.out)
        if problem:
            raise StudyFolderError(f"{self.key}: {problem}")
        try:
            fh = open(self.out / output.LOCK, "a+")
        except OSError as exc:
            raise StudyFolderError(f"{self.key}: cannot open the folder's lock "
                                   f"{self.out / output.LOCK} ({exc.strerror or exc})") \
                from None
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise StudyFolderError(f"{self.key}: another study (or run) is writing to "
                                   f"{self.out}: wait for it to end, or choose another "
                                   "folder") from None
        self._lock = fh

    def __exit__(self, *exc):
        if self._lock is not None:
            try:
                os.unlink(self.out / output.LOCK)
            except OSError:
                pass
            self._lock.close()
            self._lock = None
        if self._created:
            try:
                self.out.rmdir()             # only if nothing was kept
            except OSError:
                pass

    # -------------------------------------------------------------- manifest
    def _read_manifest(self):
        path = self.out / STUDY_MANIFEST
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            self.files = set(self._legacy(self.out)) if self._legacy else set()
            return
        except (OSError, ValueError) as exc:
            raise StudyFolderError(
                f"{self.key}: {path}, the record of the files studies of taichi_hsdem "
                f"wrote in {self.out}, is unreadable or damaged ({exc}): choose another "
                "folder, or remove the record if the files there are a study's") from None
        if not (isinstance(data, dict) and isinstance(data.get("files"), list)):
            raise StudyFolderError(
                f"{self.key}: {path}, the record of the files studies of taichi_hsdem "
                f"wrote in {self.out}, does not list files: choose another folder, or "
                "remove the record if the files there are a study's")
        other = data.get("study")
        if isinstance(other, str) and other != self.study:
            raise StudyFolderError(
                f"{self.key}: {self.out} holds the results of another study "
                f"({other}), not of {self.study}: choose another folder")
        self.files = {n for n in data["files"] if isinstance(n, str)}

    def owns(self, name: str) -> bool:
        return name in self.files

    def foreign(self, names: Iterable[str]) -> list[str]:
        """Those of ``names`` (relative to the folder) that stand there and that no
        study of taichi_hsdem wrote."""
        return [n for n in names
                if os.path.lexists(self.out / n) and n not in self.files]

    def refuse_foreign(self, names: Iterable[str], what: str = "the study"):
        """A :class:`StudyFolderError` naming the first of ``names`` that is the
        user's (:meth:`foreign`), if any."""
        foreign = self.foreign(names)
        if foreign:
            more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
            raise StudyFolderError(
                f"{self.out / foreign[0]}{more}: not written by a study of taichi_hsdem, "
                f"and {what} would replace it: move it, or choose another folder")

    def claim(self, names: Iterable[str]):
        """List ``names`` in the manifest (before they are written)."""
        new = set(names) - self.files
        if new:
            self.files |= new
            atomic_write(self.out / STUDY_MANIFEST,
                         json.dumps({"study": self.study, "files": sorted(self.files)},
                                    indent=0) + "\n")


def point_folder_problem(folder: Path) -> str | None:
    """Why ``folder`` (a study's sub-folder) cannot hold a point: a file, or a
    link to nothing, stands there."""
    if os.path.islink(folder) and not folder.exists():
        return (f"{folder}: a link to {os.readlink(folder)}, which does not exist, "
                "stands where a point's folder goes: remove it, or choose another folder")
    if os.path.lexists(folder) and not folder.is_dir():
        return (f"{folder}: a file stands where a point's folder goes: move it, or "
                "choose another folder")
    return None
