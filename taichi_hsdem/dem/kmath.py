"""Small Taichi functions the contact, coupling and integration kernels share:
rotations, the 2D cross product, the velocity of a point of a spinning body, and
the bilinear sampling of a level-set grid (a template's or the walls')."""

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
