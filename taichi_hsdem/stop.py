"""The exception a signal raises to stop the program (Ctrl-C, SIGTERM, SIGHUP).

It is a subclass of :class:`KeyboardInterrupt`, so that every ``except
KeyboardInterrupt`` catches it, and not that class itself: CPython remembers a plain
KeyboardInterrupt raised inside code that a C extension evaluates (Taichi's set-up
does) and, under ``python -m``, ends the process by SIGINT at exit whatever status
the program chose. This module imports nothing heavy: the entry point installs its
handler before the package loads Taichi."""
import signal


class Stopped(KeyboardInterrupt):
    """Raised by :func:`raise_stop` in the main thread on a stopping signal."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signum)
        self.signum = signum


def raise_stop(signum, frame):
    """A signal handler: stop where the program is, by :class:`Stopped`."""
    raise Stopped(signum)


def describe(signum) -> str:
    """How a stop by ``signum`` reads: "interrupted" (Ctrl-C) or "stopped by
    SIGTERM"."""
    if signum in (None, signal.SIGINT):
        return "interrupted"
    return f"stopped by {signal.Signals(signum).name}"
