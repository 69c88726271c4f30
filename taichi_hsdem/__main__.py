import signal
import sys

# Ctrl-C obeyed from the start, also where the shell started this process with
# SIGINT ignored (a background job of a script); the command line's own handler
# takes over in main().
signal.signal(signal.SIGINT, signal.default_int_handler)
try:
    from .cli import main
except KeyboardInterrupt:
    print("interrupted during set-up: nothing was written", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
