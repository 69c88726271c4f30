import signal
import sys

from .stop import Stopped, describe, raise_stop

# Ctrl-C, SIGTERM and SIGHUP obeyed from the start with one line and 128 + the
# signal's number, also where the shell started this process with SIGINT ignored (a
# background job of a script); SIGHUP ignored (nohup) stays ignored. The command
# line's own handler takes over in main().
for _name in ("SIGINT", "SIGTERM", "SIGHUP"):
    _sig = getattr(signal, _name, None)
    if _sig is not None and (_sig == signal.SIGINT
                             or signal.getsignal(_sig) != signal.SIG_IGN):
        signal.signal(_sig, raise_stop)
try:
    from .cli import main
except Stopped as exc:
    print(f"{describe(exc.signum)} during set-up: nothing was written", file=sys.stderr)
    sys.exit(128 + int(exc.signum))

sys.exit(main())
