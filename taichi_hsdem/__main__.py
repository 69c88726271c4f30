import signal
import sys

from .stop import describe, keep_swallowed_stops, raise_stop

# Ctrl-C, SIGTERM and SIGHUP obeyed from the start with one line and 128 + the
# signal's number, also where the shell started this process with SIGINT ignored (a
# background job of a script); SIGHUP ignored (nohup) stays ignored. While the
# command line's modules load (numpy, Taichi: about a second) a signal is noted, not
# raised: raised inside a C extension's initialisation it would come out as that
# library's ImportError. After that a signal stops the program where it is (the
# studies rely on it) until the command line's own handler takes over in main().
_received = []
_signals = [sig for sig in (getattr(signal, name, None) for name in ("SIGINT", "SIGTERM", "SIGHUP"))
            if sig is not None and (sig == signal.SIGINT
                                    or signal.getsignal(sig) != signal.SIG_IGN)]
for _sig in _signals:
    signal.signal(_sig, lambda signum, frame: _received.append(signum))
try:
    from .cli import main
finally:
    if _received:
        print(f"{describe(_received[0])} during set-up: nothing was written", file=sys.stderr)
        sys.exit(128 + int(_received[0]))
keep_swallowed_stops()
for _sig in _signals:
    signal.signal(_sig, raise_stop)

sys.exit(main())
