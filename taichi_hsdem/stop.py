"""The exception a signal raises to stop the program (Ctrl-C, SIGTERM, SIGHUP).

It is a subclass of :class:`KeyboardInterrupt`, so that every ``except
KeyboardInterrupt`` catches it, and not that class itself: CPython remembers a plain
KeyboardInterrupt raised inside code that a C extension evaluates (Taichi's set-up
does) and, under ``python -m``, ends the process by SIGINT at exit whatever status
the program chose. This module imports nothing heavy: the entry point installs its
handler before the package loads Taichi.

A signal that arrives while Python runs a destructor (Taichi's ``ArgPack.__del__``
after a kernel launch, say) raises its stop there, where Python only reports the
exception ("Exception ignored in ...", with a traceback) and goes on: the stop
would be lost. :func:`keep_swallowed_stops` installs a hook that keeps such a stop
quietly instead, and :func:`raise_if_swallowed` (asked between chunks of a run and
between a study's points) raises it again where it can stop the program."""
import signal
import sys


class Stopped(KeyboardInterrupt):
    """Raised by :func:`raise_stop` in the main thread on a stopping signal."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signum)
        self.signum = signum


def raise_stop(signum, frame):
    """A signal handler: stop where the program is, by :class:`Stopped`."""
    raise Stopped(signum)


#: Signals whose stop a destructor swallowed, not yet raised again.
swallowed: list = []


def keep_swallowed_stops() -> None:
    """Install the hook that keeps a stop raised where Python can only report it
    (a destructor), instead of printing it; other reports go to the hook before."""
    previous = sys.unraisablehook

    def hook(unraisable):
        if isinstance(unraisable.exc_value, Stopped):
            swallowed.append(unraisable.exc_value.signum)
            return
        previous(unraisable)
    sys.unraisablehook = hook


def raise_if_swallowed() -> None:
    """Raise again the first stop that a destructor swallowed, if any."""
    if swallowed:
        signum = swallowed[0]
        swallowed.clear()
        raise Stopped(signum)


def describe(signum) -> str:
    """How a stop by ``signum`` reads: "interrupted" (Ctrl-C) or "stopped by
    SIGTERM"."""
    if signum in (None, signal.SIGINT):
        return "interrupted"
    return f"stopped by {signal.Signals(signum).name}"
