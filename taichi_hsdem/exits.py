"""Exit statuses and the argument parser every command line of the package shares.

0 success; 1 the run failed (what to change is said); 2 the scene, the arguments
or the output folder are invalid (one line per problem, no traceback, nothing
written); 130 interrupted (Ctrl-C); a run or a study stopped by SIGTERM exits 143
and by SIGHUP 129 (128 + the signal's number), as after Ctrl-C.
"""
from __future__ import annotations

import argparse
import sys

EXIT_OK, EXIT_FAILED, EXIT_INVALID, EXIT_INTERRUPTED = 0, 1, 2, 130


class Parser(argparse.ArgumentParser):
    """argparse with the project's exit status for bad arguments (2, one line)."""

    def error(self, message):
        print(f"{self.prog}: {message}", file=sys.stderr)
        sys.exit(EXIT_INVALID)


def folder_name_problem(text: str) -> str | None:
    """Why ``text`` cannot name an output folder (empty, or holding a control
    character such as ESC that a terminal would act on when the path is printed),
    or None."""
    from .scene.checks import control_character
    if not text.strip():
        return "the folder name is empty"
    character = control_character(text)
    return f"the folder name holds the control character {character}" if character else None


def folder_name(text: str) -> str:
    """argparse ``type`` of ``--out``: refuses what :func:`folder_name_problem`
    names, as the plain run does, instead of quietly writing into the default
    folder (an empty name) or echoing escape codes."""
    problem = folder_name_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text
