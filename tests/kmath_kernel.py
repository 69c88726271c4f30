"""The kernels' own sine, cosine and exponential (dem/kmath.py) at given angles,
beside numpy's long-double values: what tests/test_kmath.py (on the CPU) and
tests/test_gpu.py (on a GPU) measure their errors from."""
import numpy as np

from taichi_hsdem import backend


def kmath_values(x):
    """``kmath.sin_cos`` and ``kmath.exp_neg(|x| / 100)`` of the angles ``x`` (an array
    of the backend's real type) on this process's kernels.

    Returns
    -------
    list of tuple
        ``(got, reference)`` for the cosine, the sine and the exponential, in that
        order; ``reference`` in ``numpy.longdouble``.
    """
    ti = backend.ti
    from taichi_hsdem.dem import kmath

    @ti.kernel
    def k(x: ti.types.ndarray(), c: ti.types.ndarray(), s: ti.types.ndarray(),
          e: ti.types.ndarray()):
        for i in x:
            c[i], s[i] = kmath.sin_cos(x[i])
            e[i] = kmath.exp_neg(ti.abs(x[i]) * 0.01)

    real = backend.numpy_real()
    arrays = [ti.ndarray(backend.real(), x.size) for _ in range(4)]
    arrays[0].from_numpy(x)
    k(*arrays)
    c, s, e = (a.to_numpy() for a in arrays[1:])
    xl = x.astype(np.longdouble)
    return [(c, np.cos(xl)), (s, np.sin(xl)),
            (e, np.exp(-(np.abs(x) * real(0.01)).astype(np.longdouble)))]
