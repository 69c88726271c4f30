"""Send a signal to ``python -m taichi_hsdem`` at many moments of its set-up and
tally the exit statuses: every one should be 128 + the signal's number (a status of
0 is a signal lost, -2 CPython's exit by SIGINT).

    python tools/signal_scan.py [--signal HUP] [--from 0.3] [--step 0.05] [--n 60]
"""
import argparse
import collections
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--signal", default="HUP", choices=["INT", "TERM", "HUP"])
    ap.add_argument("--from", dest="start", type=float, default=0.3,
                    help="first delay after the start, in seconds")
    ap.add_argument("--step", type=float, default=0.05)
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "hourglass24.toml"))
    args = ap.parse_args(argv)
    sig = getattr(signal, f"SIG{args.signal}")
    codes, odd = collections.Counter(), []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.n):
            delay = args.start + args.step * i
            out = Path(tmp) / "o"
            shutil.rmtree(out, ignore_errors=True)
            proc = subprocess.Popen([sys.executable, "-m", "taichi_hsdem", args.scene,
                                     "--out", str(out), "--set", "run.t_end=50", "--quiet"],
                                    cwd=tmp, stderr=subprocess.PIPE, text=True)
            time.sleep(delay)
            proc.send_signal(sig)
            err = proc.communicate()[1]
            codes[proc.returncode] += 1
            if proc.returncode != 128 + sig:
                odd.append(f"{delay:.3f} s: exit {proc.returncode} {err.strip()[-120:]!r}")
    print(f"SIG{args.signal} at {args.n} moments: exit statuses {dict(codes)}")
    for line in odd:
        print("  " + line)
    return 0 if not odd else 1


if __name__ == "__main__":
    sys.exit(main())
