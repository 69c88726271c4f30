"""Study points on a Dask cluster: ``--cluster ADDRESS`` (a running scheduler, such as
one dask-jobqueue starts on Slurm) or ``--cluster local[:N]`` (a
``LocalCluster`` of N worker processes on this machine; N defaults to the usable
CPUs).

One task is one point, its realizations still batched in one process. Workers
are processes of their own, started fresh (Dask's spawn), so Taichi is never
forked after it started; each worker limits its threads (Taichi's, BLAS's and
the pressure solver's processes) to its share of the cores through
``TAICHI_HSDEM_THREADS``. A point's result does not depend on where it ran: the
same seeds, the same code, and kernels and solves that give the same bits
whatever runs beside them (tested on a LocalCluster of two workers).

Dask is the ``cluster`` extra: ``pip install "taichi_hsdem[cluster]"``.
"""
from __future__ import annotations

import tempfile
from typing import Callable, Sequence
from urllib.parse import urlsplit

from ..limits import usable_cpus
from ..stop import raise_if_swallowed
from ..limits import THREADS_ENV

INSTALL_HINT = 'pip install "taichi_hsdem[cluster]"'
#: Seconds to wait for a scheduler's answer before --cluster ADDRESS is refused.
CONNECT_TIMEOUT = 8


class ClusterError(ValueError):
    """The --cluster argument cannot be used (message says why)."""


def parse(spec: str | None):
    """``None`` (run in this process), ``("local", n)`` or ``("address", text)``."""
    if spec is None:
        return None
    spec = spec.strip()
    if spec == "local" or spec.startswith("local:"):
        n = spec.partition(":")[2]
        if n and not (n.isdigit() and int(n) >= 1):
            raise ClusterError(f"--cluster {spec}: local:N needs a whole number N >= 1")
        return ("local", int(n) if n else usable_cpus())
    if not spec:
        raise ClusterError("--cluster: give a scheduler address (tcp://host:8786) or local[:N]")
    try:                        # a malformed address is refused at once, not after a wait
        parts = urlsplit(spec if "://" in spec else f"tcp://{spec}")
        parts.port
    except ValueError as exc:
        raise ClusterError(f"--cluster {spec}: not a scheduler address ({exc}); give "
                           f"tcp://host:port or local[:N]") from None
    if not parts.hostname:
        raise ClusterError(f"--cluster {spec}: names no host; give tcp://host:port or "
                           f"local[:N]")
    return ("address", spec)


class Cluster:
    """A Dask client for ``parse(spec)``; ``with Cluster(spec) as c: c.run(...)``.
    With ``spec`` None everything runs here, in order.

    A study enters it before it makes its output folder, so that a --cluster it
    cannot use (Dask missing, no scheduler answering within
    :data:`CONNECT_TIMEOUT` seconds) is refused with nothing written; ``say``
    (optional) is told before the wait."""

    def __init__(self, spec: str | None, say: Callable[[str], None] | None = None):
        self.kind = parse(spec)
        self.spec = spec
        self.say = say or (lambda message: None)
        self.client = None
        self._local = None
        self._scratch = None

    def __enter__(self):
        if self.kind is None:
            return self
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise ClusterError(f"--cluster {self.spec}: needs Dask (distributed), which is "
                               f"not installed: {INSTALL_HINT}") from None
        if self.kind[0] == "local":
            n = self.kind[1]
            threads = max(1, usable_cpus() // n)
            env = {THREADS_ENV: str(threads), "OMP_NUM_THREADS": "1",
                   "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
            self.say(f"starting a local cluster of {n} worker(s)")
            # workers keep their scratch files out of the user's folder
            self._scratch = tempfile.TemporaryDirectory(prefix="taichi_hsdem_dask_")
            self._local = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                       dashboard_address=None, env=env,
                                       local_directory=self._scratch.name,
                                       silence_logs=40)
            self.client = Client(self._local)
        else:
            address = self.kind[1]
            self.say(f"connecting to the cluster at {address} (waiting up to "
                     f"{CONNECT_TIMEOUT} s)")
            try:
                self.client = Client(address, timeout=CONNECT_TIMEOUT)
            except (OSError, ValueError, TypeError, AssertionError) as exc:
                # Dask's own errors for an address it cannot use or reach
                why = " ".join(str(exc).split()) or type(exc).__name__
                raise ClusterError(f"--cluster {address}: no Dask scheduler answers "
                                   f"({why})") from None
        return self

    def __exit__(self, *exc):
        if self.client is not None:
            self.client.close()
        if self._local is not None:
            self._local.close()
        if self._scratch is not None:
            self._scratch.cleanup()

    def run(self, fn: Callable, tasks: Sequence[tuple],
            done: Callable[[int, object], None] | None = None) -> list:
        """``[fn(*t) for t in tasks]``, here or one task per point on the cluster;
        ``done(i, result)`` as each finishes (in finishing order); results in
        ``tasks``' order. After each ``done`` a stop that a destructor swallowed
        (:func:`taichi_hsdem.stop.raise_if_swallowed`) is raised again: the
        finished point is kept, the study stops."""
        if self.client is None:
            results = []
            for i, t in enumerate(tasks):
                results.append(fn(*t))
                if done is not None:
                    done(i, results[-1])
                raise_if_swallowed()
            return results
        from distributed import as_completed
        futures = [self.client.submit(fn, *t, pure=False) for t in tasks]
        index = {f.key: i for i, f in enumerate(futures)}
        results = [None] * len(futures)
        for future in as_completed(futures):
            i = index[future.key]
            results[i] = future.result()
            if done is not None:
                done(i, results[i])
            raise_if_swallowed()
        return results
