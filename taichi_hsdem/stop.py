"""The exception a signal raises to stop the program (Ctrl-C, SIGTERM, SIGHUP).

It is a subclass of :class:`KeyboardInterrupt`, so that every ``except
KeyboardInterrupt`` catches it, and not that class itself: CPython remembers a plain
KeyboardInterrupt raised inside code that a C extension evaluates (Taichi's set-up
does) and, under ``python -m``, ends the process by SIGINT at exit whatever status
the program chose. This module imports nothing heavy: the entry point installs its
handler before the package loads Taichi.

A stop can be lost on its way: raised while Python runs a destructor (Taichi's
``ArgPack.__del__`` after a kernel launch, say), Python only reports it ("Exception
ignored in ...", with a traceback) and goes on; raised while Taichi's decorators
inspect their caller, their bare ``except:`` swallows it (a sweep signalled during a
point's set-up ran that point to its end). So :func:`raise_stop` notes each stop in
:data:`pending` before raising it, :func:`keep_swallowed_stops` installs a hook that
keeps a destructor's stop quietly instead of printing it, and
:func:`raise_if_swallowed` (asked between chunks of a run and between a study's
points) raises a noted stop again where it can stop the program."""
import signal
import sys


class Stopped(KeyboardInterrupt):
    """Raised by :func:`raise_stop` in the main thread on a stopping signal."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signum)
        self.signum = signum


#: Signals whose stop was raised and may not have reached the program (a library or
#: a destructor swallowed it), not yet raised again by :func:`raise_if_swallowed`.
pending: list = []


def raise_stop(signum, frame):
    """A signal handler: stop where the program is, by :class:`Stopped`, noted in
    :data:`pending` first in case what runs there swallows it."""
    if not pending:
        pending.append(signum)
    raise Stopped(signum)


def keep_swallowed_stops() -> None:
    """Install the hook that keeps a stop raised where Python can only report it
    (a destructor), instead of printing it; other reports go to the hook before."""
    previous = sys.unraisablehook

    def hook(unraisable):
        if isinstance(unraisable.exc_value, Stopped):
            if not pending:
                pending.append(unraisable.exc_value.signum)
            return
        previous(unraisable)
    sys.unraisablehook = hook


def raise_if_swallowed() -> None:
    """Raise again the first noted stop, if any (it may have reached the program
    already: then the program is stopping, and raising it again changes nothing)."""
    if pending:
        signum = pending[0]
        pending.clear()
        raise Stopped(signum)


def describe(signum) -> str:
    """How a stop by ``signum`` reads: "interrupted" (Ctrl-C) or "stopped by
    SIGTERM"."""
    if signum in (None, signal.SIGINT):
        return "interrupted"
    return f"stopped by {signal.Signals(signum).name}"
