"""What a run would cost, estimated before anything is allocated: memory against what
the machine has, and DEM steps against what can finish.

:func:`resolve <taichi_hsdem.resolve.resolve>` adds up the :class:`Part` of every
grid and array a scene asks for and refuses the scene, naming the key that made
the largest part, when the total would not fit; a step count that could never
finish (or no step at all) is refused the same way.

The per-element byte counts are upper estimates of the host and device arrays
each element owns, temporaries included (measured on the vani and hourglass
scenes, rounded up); they only need to be right to a factor of two to tell a
scene that fits from one that needs a thousand times the memory.

Examples
--------
>>> human_bytes(3.2e9)
'3.2 GB'
"""
from __future__ import annotations

import os
from dataclasses import dataclass

# Bytes per element, host and device together (see the module doc).
WALL_NODE_BYTES = 64             # wall level set: points, distance, gradient, device copy
LEVEL_SET_NODE_BYTES = 80        # a template's grid: points, distance, gradient, stacked copy
FLUID_CELL_BYTES = 100           # the fluid grid itself: active mask, faces, sparsity pattern
FLUID_CELL_REALIZATION_BYTES = 400   # per realization: matrix, multigrid hierarchy, fields
#                                      (the lanes' copies, fluid/_gmg_lanes.py, included)
BODY_BYTES = 400                 # per body and realization: state, neighbours, host copies
HISTORY_SLOT_BYTES = 2 * (4 + 16)    # shear history: two buffers of (partner, 2-vector)

#: The largest share of the available memory a run may plan to use.
MEMORY_FRACTION = 0.8
#: More DEM steps than this can not finish (the paper's runs take 2e7).
MAX_STEPS = 1.0e10
#: Most vertices of one particle polygon: each is at least one surface node, and
#: the level set, the overlap checks and every contact grow with them (a
#: 3000-vertex polygon took minutes before the first step).
MAX_PARTICLE_VERTICES = 1000
#: Most vertices of a channel outline and its obstacles together: the scene check
#: and the wall level set grow with their square and product (6000 took minutes).
MAX_OUTLINE_VERTICES = 2000
#: Most vertices of all obstacles together (a micromodel's pillars), each obstacle a
#: polygon of at most MAX_OUTLINE_VERTICES: the wall level set measures only the
#: obstacles near each point (geometry/nearest.py) and the obstacle checks only
#: neighbouring pairs, so they grow with the vertex count, not with its square
#: (docs/performance.md, "Micromodels").
MAX_OBSTACLE_VERTICES = 50_000
#: Most surface nodes of one particle template: every contact of the particle
#: tests each node (the automatic count is 40 to a few hundred).
MAX_NODES = 20000
#: Most video frames (9 hours at 30 frames per second) and the widest video (8K):
#: each frame is drawn and encoded, at width x height pixels.
MAX_FRAMES = 1_000_000
MAX_VIDEO_WIDTH = 7680
#: A process's share of the cores, when something (a Dask worker) gave it one:
#: Taichi's CPU threads and the pressure solver's processes stay within it.
THREADS_ENV = "TAICHI_HSDEM_THREADS"


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity, within :func:`thread_share`)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    share = thread_share()
    return min(cpus, share) if share else cpus


def thread_share() -> int | None:
    """The threads this process may use (``THREADS_ENV``), or None for all."""
    value = os.environ.get(THREADS_ENV, "")
    return int(value) if value.isdigit() and int(value) >= 1 else None


@dataclass(frozen=True)
class Part:
    """One array or grid of a run: which key sets its size, what it is, its bytes,
    and what to change (a phrase) to make it smaller."""
    key: str
    what: str
    nbytes: float
    advice: str


def available_memory() -> int | None:
    """Memory this process could still allocate, bytes: the machine's (Linux
    ``MemAvailable``, else the free physical pages), or less where an address-space
    limit (``ulimit -v``) leaves less; None where neither can be read."""
    machine = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    machine = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if machine is None:
        try:
            machine = int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (AttributeError, OSError, ValueError):
            pass
    limit = _address_space_left()
    if limit is None:
        return machine
    return limit if machine is None else min(machine, limit)


def _address_space_left() -> int | None:
    """Address space this process may still map under ``RLIMIT_AS`` (its limit less
    its current size, ``VmSize``), bytes; None without a limit or where unknown."""
    try:
        import resource
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (ImportError, OSError, ValueError):
        return None
    if soft == resource.RLIM_INFINITY:
        return None
    size = 0
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    size = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    return max(0, soft - size)


def human_bytes(n: float) -> str:
    """``n`` bytes in kB, MB, GB, ... (decimal), 3 significant digits."""
    units = ("B", "kB", "MB", "GB", "TB", "PB", "EB")
    k = 0
    while n >= 1000 and k < len(units) - 1:
        n /= 1000.0
        k += 1
    return f"{n:.3g} {units[k]}"


def memory_problems(parts: list[Part], source: str, available: int | None = None) -> list[str]:
    """One line naming the largest part when all of ``parts`` would not fit in
    ``MEMORY_FRACTION`` of the ``available`` memory (default: this machine's), else
    none.

    Examples
    --------
    >>> memory_problems([Part("fluid.cell_size", "a grid", 5e12, "raise it")], "s.toml",
    ...                 available=16e9)                            # doctest: +ELLIPSIS
    ['s.toml: fluid.cell_size: a grid would need about 5 TB, more than the 16 GB ...']
    """
    available = available_memory() if available is None else available
    total = sum(p.nbytes for p in parts)
    if available is None or total <= MEMORY_FRACTION * available:
        return []
    big = max(parts, key=lambda p: p.nbytes)
    share = "" if big.nbytes >= 0.99 * total else f" (of {human_bytes(total)} for the whole run)"
    return [f"{source}: {big.key}: {big.what} would need about {human_bytes(big.nbytes)}"
            f"{share}, more than the {human_bytes(available)} of memory available here; "
            f"{big.advice}"]
