"""Small Taichi functions the contact, coupling and integration kernels share:
rotations, the 2D cross product, the velocity of a point of a spinning body, and
the bilinear sampling of a level-set grid (a template's or the walls'), and the
sine, cosine and exponential every kernel uses instead of the backend's own."""

import math

from ..backend import ti  # sets the environment before Taichi loads
from ..layout import GEO_H, GEO_OX, GEO_OY, OUTSIDE

vec2 = ti.math.vec2


@ti.func
def rot(c, s, v):
    """``v`` turned by the angle whose cosine and sine are ``c``, ``s``."""
    return vec2(c * v.x - s * v.y, s * v.x + c * v.y)


@ti.func
def rot_t(c, s, v):
    """``v`` turned back by that angle (world to body frame)."""
    return vec2(c * v.x + s * v.y, -s * v.x + c * v.y)


@ti.func
def cross(a, b):
    return a.x * b.y - a.y * b.x


@ti.func
def spin(w, r):
    """Velocity ``w x r`` of a point at ``r`` from the centre of a body spinning at ``w``."""
    return vec2(-w * r.y, w * r.x)


@ti.func
def grid_sample(data: ti.template(), gdata: ti.template(), off, nx, ny, ox, oy, h, q):
    """Bilinear value and gradient of a grid stored x-first from ``data[off]``.

    The gradient is the bilinear interpolation of the grid's central-difference
    gradient ``gdata`` (continuous and second-order), not the gradient of the
    bilinear value, which jumps between cells and tilts contact normals by O(h/r)
    next to grid lines. Outside the grid the value is ``OUTSIDE`` (no contact) and
    the gradient zero.
    """
    phi = OUTSIDE
    grad = vec2(0.0, 0.0)
    gx = (q.x - ox) / h
    gy = (q.y - oy) / h
    if gx >= 0.0 and gy >= 0.0 and gx < nx - 1 and gy < ny - 1:
        i0 = ti.cast(ti.floor(gx), ti.i32)
        j0 = ti.cast(ti.floor(gy), ti.i32)
        fx = gx - i0
        fy = gy - j0
        k00 = off + i0 * ny + j0
        k10 = k00 + ny
        w00 = (1 - fx) * (1 - fy)
        w10 = fx * (1 - fy)
        w01 = (1 - fx) * fy
        w11 = fx * fy
        phi = data[k00] * w00 + data[k10] * w10 + data[k00 + 1] * w01 + data[k10 + 1] * w11
        for c in ti.static(range(2)):
            grad[c] = (gdata[k00, c] * w00 + gdata[k10, c] * w10 + gdata[k00 + 1, c] * w01
                       + gdata[k10 + 1, c] * w11)
    return phi, grad


@ti.func
def template_sample(ls_phi: ti.template(), ls_grad: ti.template(), ls_meta: ti.template(),
                    ls_geo: ti.template(), t, q):
    """Level set of template ``t`` and its gradient at body-frame point ``q``
    (``ls_meta[t]``: offset, nx, ny; ``ls_geo[t]``: origin x, origin y, spacing)."""
    phi, g = grid_sample(ls_phi, ls_grad, ls_meta[t, 0], ls_meta[t, 1], ls_meta[t, 2],
                         ls_geo[t, GEO_OX], ls_geo[t, GEO_OY], ls_geo[t, GEO_H], q)
    return phi, g


@ti.func
def wall_sample(walls: ti.template(), p):
    """Wall level set (positive in the fluid) and its gradient at world point ``p``
    (``walls``: a :class:`~taichi_hsdem.dem.state.WallGrid` pack)."""
    phi, g = grid_sample(walls.phi, walls.grad, 0, walls.shape[0], walls.shape[1],
                         walls.geo[GEO_OX], walls.geo[GEO_OY], walls.geo[GEO_H], p)
    return phi, g


@ti.func
def node_world(node_pos: ti.template(), n, x, c, s):
    """World position of surface node ``n`` of a body at ``x`` turned by (c, s)."""
    return x + rot(c, s, vec2(node_pos[n, 0], node_pos[n, 1]))


# ---------------------------------------------------------------- trigonometry
# Kernel-side sine, cosine and exponential, so that no kernel calls the backend's
# own: SPIR-V (Vulkan, Metal) has sin, cos and exp for 16- and 32-bit floats only,
# its f32 versions need only be accurate to 2^-11 there, and a CPU's libm picks
# its code by CPU features. These are the same IEEE operations on every backend,
# so that the CPU's and a GPU's results differ only where a compiler reorders
# them (Mesa's Vulkan simplifies (1 - (1 - a)) - a to 0: hence no compensated
# sums below). Accuracy (tests/test_kmath.py, against numpy's long double):
# sin_cos in f64 within 0.84 ulp of the exact value on the CPU and 0.99 ulp on
# Mesa's Vulkan for |x| < 1.6e6; in f32 within 8.4e-8 absolute (0.7 2^-23) for
# |x| < 1e5; exp_neg within 1 ulp.
#
# f64: fdlibm's (FreeBSD msun) reduction by pi/2 in two 33-bit parts and a tail,
# and its polynomials on [-pi/4, pi/4] (__kernel_sin, __kernel_cos).
_INVPIO2 = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e+00      # the first 33 bits of pi/2
_PIO2_2 = 6.07710050630396597660e-11      # the next 33
_PIO2_2T = 2.02226624879595063154e-21     # pi/2 - _PIO2_1 - _PIO2_2
_S1, _S2, _S3, _S4, _S5, _S6 = (
    -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
    2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_C1, _C2, _C3, _C4, _C5, _C6 = (
    4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
    -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)
# f32: pi/2 in three parts of 8, 8 and 24 bits (n P1 and n P2 exact for |n| < 2^16)
# and Cephes' sinf/cosf polynomials.
_F_PIO2 = (1.5703125, 4.825592041015625e-4, 1.2675908465098473e-06)
_F_SIN = (-1.9515295891e-4, 8.3321608736e-3, -1.6666654611e-1)
_F_COS = (2.443315711809948e-5, -1.388731625493765e-3, 4.166664568298827e-2)
# exp: ln 2 in a high part with trailing zero bits (k ln2_hi exact) and the rest
_LN2_HI, _LN2_LO = 6.93147180369123816490e-01, 1.90821492927058770002e-10
_F_LN2_HI, _F_LN2_LO = 6.9314575195e-01, 1.4286067653e-06
_INV_LN2 = 1.44269504088896338700e+00
_INV_FACT = tuple(1.0 / math.factorial(q) for q in range(14))   # the series of exp


def _is_f64(x) -> bool:
    """(at compile time) whether the Taichi expression ``x`` is float64."""
    return ti.lang.expr.Expr(x).ptr.get_rvalue_type() == ti.f64


@ti.func
def _quadrant(n, kc, ks):
    """(cos, sin) of r + n pi/2 from those of r."""
    c, s = kc, ks
    if n == 1:
        c, s = -ks, kc
    elif n == 2:
        c, s = -kc, -ks
    elif n == 3:
        c, s = ks, -kc
    return c, s


@ti.func
def _sin_cos64(x):
    fn = ti.floor(x * _INVPIO2 + 0.5)
    # x - fn pi/2 as y0 + y1 (fdlibm __rem_pio2, its second step always taken)
    r = x - fn * _PIO2_1
    w = fn * _PIO2_2
    t = r
    r = t - w
    w = fn * _PIO2_2T - ((t - r) - w)
    y0 = r - w
    y1 = (r - y0) - w
    z = y0 * y0
    zz = z * z
    rs = _S2 + z * (_S3 + z * _S4) + z * zz * (_S5 + z * _S6)
    v = z * y0
    ks = y0 - ((z * (0.5 * y1 - v * rs) - y1) - v * _S1)
    rc = z * (_C1 + z * (_C2 + z * _C3)) + zz * zz * (_C4 + z * (_C5 + z * _C6))
    kc = 1.0 - (0.5 * z - (z * rc - y0 * y1))
    if z > 0.09:
        # fdlibm's older split: qx near |y0|/4 with few bits, so that 1 - qx and
        # 0.5 z - qx are exact (0.99 -> 0.84 ulp; Mesa folds it back to the above)
        qx = ti.floor(ti.abs(y0) * 262144.0) * 9.5367431640625e-07
        kc = (1.0 - qx) - ((0.5 * z - qx) - (z * rc - y0 * y1))
    return _quadrant(ti.cast(fn, ti.i32) & 3, kc, ks)


@ti.func
def _sin_cos32(x):
    f = ti.f32
    fn = ti.floor(x * ti.cast(_INVPIO2, f) + ti.cast(0.5, f))
    r = (((x - fn * ti.cast(_F_PIO2[0], f)) - fn * ti.cast(_F_PIO2[1], f))
         - fn * ti.cast(_F_PIO2[2], f))
    z = r * r
    ks = (((ti.cast(_F_SIN[0], f) * z + ti.cast(_F_SIN[1], f)) * z + ti.cast(_F_SIN[2], f))
          * z * r + r)
    kc = (((ti.cast(_F_COS[0], f) * z + ti.cast(_F_COS[1], f)) * z + ti.cast(_F_COS[2], f))
          * z * z - ti.cast(0.5, f) * z + ti.cast(1.0, f))
    return _quadrant(ti.cast(fn, ti.i32) & 3, kc, ks)


@ti.func
def sin_cos(x):
    """``(cos x, sin x)`` in the type of ``x`` (f64 or f32), from the same IEEE
    operations on every backend (see above)."""
    c, s = x, x
    if ti.static(_is_f64(x)):
        c, s = _sin_cos64(x)
    else:
        c, s = _sin_cos32(x)
    return c, s


@ti.func
def _pow2_neg(k, one):
    """2^-k for an integer 0 <= k, exactly (0 below the type's range), by
    squaring: no bit patterns, so no 64-bit integers on the device."""
    scale = one
    b = one * 0.5
    kk = k
    while kk > 0:
        if kk & 1:
            scale *= b
        b *= b
        kk >>= 1
    return scale


@ti.func
def exp_neg(y):
    """``exp(-y)`` for ``y >= 0`` in the type of ``y``: ``2^-k exp(-r)``, ``y = k ln 2
    + r``, ``|r| <= ln 2 / 2``, by its Taylor series (degree 13 in f64, 7 in
    f32: the first term left out is below half an ulp)."""
    e = y * 0.0
    if ti.static(_is_f64(y)):
        if y < 708.0:
            k = ti.floor(y * _INV_LN2 + 0.5)
            # k ln 2 - y as fdlibm forms it (Mesa folds (k hi - y) + k lo into
            # k (hi + lo) - y, 1e5 ulp off)
            r = k * _LN2_LO - (y - k * _LN2_HI)
            p = ti.f64(_INV_FACT[13])
            for q in ti.static(range(12, -1, -1)):
                p = p * r + _INV_FACT[q]
            e = p * _pow2_neg(ti.cast(k, ti.i32), ti.f64(1.0))
    else:
        f = ti.f32
        if y < ti.cast(87.0, f):
            k = ti.floor(y * ti.cast(_INV_LN2, f) + ti.cast(0.5, f))
            r = k * ti.cast(_F_LN2_LO, f) - (y - k * ti.cast(_F_LN2_HI, f))
            p = ti.cast(_INV_FACT[7], f)
            for q in ti.static(range(6, -1, -1)):
                p = p * r + ti.cast(_INV_FACT[q], f)
            e = p * _pow2_neg(ti.cast(k, ti.i32), ti.cast(1.0, f))
    return e

