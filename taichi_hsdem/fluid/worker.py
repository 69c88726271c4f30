"""A pressure-solver worker process: ``python -m taichi_hsdem.fluid.worker`` answers
the solves :class:`taichi_hsdem.fluid.pool.Pool` sends it on stdin (see :mod:`.pool`)."""
from .pool import serve

if __name__ == "__main__":
    serve()
