"""Multigrid pressure solves spread over worker processes.

pyamg holds Python's global interpreter lock, so threads do not run two solves at
once (two threads: 1.18x on this 2-core machine). The realizations of a batch are
independent systems, so they are split over plain worker processes instead: worker
``w`` owns every realization ``r`` with ``r % workers == w``, keeps its multigrid
hierarchies between solves and receives only the new matrix values, right-hand
sides and initial guesses.

The workers are started with :mod:`subprocess` (``python -m
taichi_hsdem.fluid.worker``), not :mod:`multiprocessing`: a spawned multiprocessing
child re-imports the user's main script, which runs a script without a
``__main__`` guard a second time, and forking a process that runs Taichi's thread
pool is unsafe. Messages are pickles over the worker's stdin and stdout; the
worker imports numpy, scipy and pyamg only. A worker that fails or dies is
reported as :class:`PoolError`; :class:`taichi_hsdem.fluid.PressureSolver` then
carries on in its own process.

Every solve, in a worker or in-process, goes through :func:`solve_block`, so a
realization's pressure does not depend on where it was solved (bit for bit).
"""

from __future__ import annotations

import atexit
import itertools
import os
import pickle
import subprocess
import sys
import time
import traceback

import numpy as np


# Hierarchy options. Seven Ruge-Stuben levels down to a handful of unknowns cost
# more in per-level overhead than they save on a grid of 1e4 unknowns; stopping at
# 2000 unknowns with a sparse LU there took 30 ms per solve against 45 ms (vani
# scene, 120 consecutive solves, 8 CG iterations against 13 for 1e-8).
AMG_OPTIONS = {"max_coarse": 2000, "coarse_solver": "splu"}

_CACHE: dict = {}     # (token, realization) -> pyamg hierarchy, in the process that solves
_PATTERNS: dict = {}  # token -> (n, indptr, indices): the shared sparsity pattern


class PoolError(RuntimeError):
    """A worker process failed or could not be started."""


def solve_block(token, pattern, rows, new_data, rhs, guess, tol, maxiter):
    """Solve realizations ``rows`` of the solver ``token``.

    Parameters
    ----------
    token : int
        Identifies the :class:`~taichi_hsdem.fluid.PressureSolver`.
    pattern : tuple or None
        ``(n, indptr, indices)`` of the CSR pattern, sent with a solver's first block.
    rows : sequence of int
        Realization numbers, in the order of ``rhs`` and ``guess``.
    new_data : dict
        ``{realization: [(mode, CSR values), ...]}`` for the realizations whose
        matrix changed, applied in order: ``"full"`` builds a Ruge-Stuben
        hierarchy of that matrix, ``"refresh"`` keeps the realization's hierarchy
        (its coarsening and interpolation) and recomputes the Galerkin operators
        of the new matrix (:func:`refresh`).
    rhs, guess : numpy.ndarray, shape (len(rows), n)
    tol : float
        Relative residual of the CG solve.
    maxiter : int

    Returns
    -------
    x : numpy.ndarray, shape (len(rows), n)
    iterations : numpy.ndarray of int
    residual : numpy.ndarray
        ``|b - A x| / |b|`` (0 where ``b == 0``: the answer is 0).
    setup_seconds : float
    """

    import pyamg
    import scipy.sparse as sp

    if pattern is not None:
        _PATTERNS[token] = pattern
    n, indptr, indices = _PATTERNS[token]
    t0 = time.perf_counter()
    for r, ops in new_data.items():
        for mode, data in ops:
            # Own arrays: eliminate_zeros prunes them in place and the hierarchy
            # keeps a reference to its matrix.
            A = sp.csr_array((np.ascontiguousarray(data, dtype=float), indices.copy(),
                              indptr.copy()), shape=(n, n))
            A.eliminate_zeros()
            if mode == "full":
                _CACHE[token, r] = pyamg.ruge_stuben_solver(A, **AMG_OPTIONS)
            else:
                refresh(_CACHE[token, r], A)
    setup = time.perf_counter() - t0
    x = np.zeros((len(rows), n))
    iterations = np.zeros(len(rows), dtype=int)
    residual = np.zeros(len(rows))
    for i, r in enumerate(rows):
        b = rhs[i]
        bnorm = np.linalg.norm(b)
        if bnorm == 0.0:  # no driving at all: the SPD system's answer is 0
            continue
        hierarchy = _CACHE[token, r]
        history = []
        x[i] = hierarchy.solve(b, x0=guess[i], tol=tol, maxiter=maxiter, accel="cg",
                               residuals=history)
        iterations[i] = len(history) - 1
        residual[i] = np.linalg.norm(b - hierarchy.levels[0].A @ x[i]) / bnorm
    return x, iterations, residual, setup


def refresh(hierarchy, A):
    """Put the fine matrix ``A`` into ``hierarchy`` in place: the coarse operators
    become the Galerkin products ``R A P`` of the hierarchy's own interpolation and
    the coarse LU is redone. The result depends only on the matrix the hierarchy
    was built from and on ``A``, not on what was refreshed in between."""
    import pyamg

    levels = hierarchy.levels
    levels[0].A = A
    for fine, coarse in zip(levels[:-1], levels[1:]):
        coarse.A = (fine.R @ fine.A @ fine.P).tocsr()
    hierarchy.coarse_solver = pyamg.multilevel.coarse_grid_solver(AMG_OPTIONS["coarse_solver"])


def forget(token):
    """Drop the hierarchies and pattern of solver ``token`` from this process."""
    _PATTERNS.pop(token, None)
    for key in [key for key in _CACHE if key[0] == token]:
        del _CACHE[key]


_CALLS = {"solve_block": solve_block, "forget": forget}


# The folder holding the taichi_hsdem package, where ``python -m`` finds it.
_PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class _Worker:
    def __init__(self):
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                   MKL_NUM_THREADS="1")
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "taichi_hsdem.fluid.worker"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, env=env, cwd=_PACKAGE_PARENT)
        except OSError as exc:
            raise PoolError(f"could not start a pressure-solver process: {exc}") from exc

    def send(self, name, args):
        try:
            pickle.dump((name, args), self.proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self.proc.stdin.flush()
        except (OSError, ValueError) as exc:
            raise PoolError(f"pressure-solver process {self.proc.pid} is gone: {exc}") from exc

    def receive(self):
        try:
            ok, value = pickle.load(self.proc.stdout)
        except (EOFError, OSError, pickle.UnpicklingError, ValueError) as exc:
            raise PoolError(f"pressure-solver process {self.proc.pid} stopped "
                            f"(exit code {self.proc.poll()}): {exc!r}") from exc
        if not ok:
            raise PoolError(f"pressure-solver process {self.proc.pid} failed:\n{value}")
        return value

    def close(self):
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=5)
        except Exception:  # noqa: BLE001 - best effort at exit
            self.proc.kill()


class Pool:
    """Worker processes shared by every solver of this process (see :func:`pool`)."""

    def __init__(self):
        self.workers: list[_Worker] = []
        self.generation = 0  # bumped whenever the workers (and what they held) go
        self._tokens = itertools.count(1)

    def token(self) -> int:
        return next(self._tokens)

    def ensure(self, count):
        while len(self.workers) < count:
            self.workers.append(_Worker())
        return self.workers[:count]

    def map(self, calls):
        """Run ``calls`` (one ``(name, args)`` per worker, ``None`` to skip) at once;
        return their results in order. On any failure every worker is stopped (their
        state is no longer known) and :class:`PoolError` is raised."""
        try:
            workers = self.ensure(len(calls))
            for worker, call in zip(workers, calls):
                if call is not None:
                    worker.send(*call)
            return [worker.receive() if call is not None else None
                    for worker, call in zip(workers, calls)]
        except PoolError:
            self.close()
            raise

    def forget(self, token):
        """Tell every running worker to drop ``token``'s hierarchies; a failure only
        stops the workers (what they held is gone either way)."""
        try:
            self.map([("forget", (token,))] * len(self.workers))
        except PoolError:
            pass

    def close(self):
        for worker in self.workers:
            worker.close()
        self.workers = []
        self.generation += 1


_POOL: Pool | None = None


def pool() -> Pool:
    """The process-wide worker pool (workers start on first use, stop at exit)."""
    global _POOL
    if _POOL is None:
        _POOL = Pool()
        atexit.register(_POOL.close)
    return _POOL


def serve():
    """Worker loop: answer ``(name, args)`` pickles on stdin until it closes."""
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing but replies may reach the parent's pipe
    while True:
        try:
            name, args = pickle.load(stdin)
        except EOFError:
            return
        try:
            reply = (True, _CALLS[name](*args))
        except Exception:  # noqa: BLE001 - the parent reports it
            reply = (False, traceback.format_exc())
        pickle.dump(reply, stdout, protocol=pickle.HIGHEST_PROTOCOL)
        stdout.flush()
