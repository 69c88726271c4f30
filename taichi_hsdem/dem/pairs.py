"""The near-field correction of close pairs' mobility (``fluid.pair_mobility``,
docs/model.md section 3.5).

Two depth-averaged Darcy disks close together act as one elongated obstacle:
side by side across the flow they speed each other up by 12-14 % at a surface
gap of 0.05 d, in line they slow each other by 7-8 %, where confined spheres in
3D Stokes move within 5 % of a lone one either way. The correction is a
resistance per close pair: body ``i`` drifts as if its plate drag were
``m xi (I - K_i)``, ``K_i = sum_j alpha(g) I + beta(g) (2 e e^T - I)`` over its
neighbours ``j`` closer than the table's last knot (``g`` the surface gap over
the mean ``d_eq`` of the two, ``e`` the unit vector between their centres), with
``alpha``, ``beta`` piecewise linear in ``g`` on the knots of
:func:`taichi_hsdem.laws.pair_mobility_table` (fitted so that the model's pair
lattices drift as the 3D Stokes ones, ``tools/pair_mobility_fit.py``). It is
held between fluid updates as the pressure force is: the force
``m xi K_i v_i`` from the velocity at the update joins the held fluid force,
and at steady drift ``m xi v = F + m xi K v`` is that resistance. A body at
rest feels none of it: the pressure force on held bodies is unchanged.

Neighbours come from the broad phase's cells (:mod:`.neighbors`), the 5 x 5
cells round the body (1.25 d each at least: a body binned at the last build
lies within half the Verlet skin, d/8, of where it is now), taken in the
order of their numbers, so that the sum does not depend on how the cells were
filled (a GPU fills them in any order) nor on the other realizations.
"""

from ..backend import ti  # sets the environment before Taichi loads
from . import state
from .neighbors import NEIGHBORS, cell_of

vec2 = ti.math.vec2

_PAIR_BODIES = state.Bodies.part("x", "v", "alive", "f_fluid")
_PAIR_PARTICLES = state.Particles.part("species", "mass", "d_eq")


@ti.func
def _coefficients(table: ti.template(), g):
    """``(alpha, beta)`` at gap ``g``: piecewise linear between the knots of
    ``table`` (rows ``g, alpha, beta``), the first knot's below it, zero from
    the last knot on."""
    n = table.shape[0]
    a = table[0, 1]
    b = table[0, 2]
    if g >= table[n - 1, 0]:
        a = 0.0
        b = 0.0
    elif g > table[0, 0]:
        for k in range(n - 1):
            if table[k, 0] <= g < table[k + 1, 0]:
                w = (g - table[k, 0]) / (table[k + 1, 0] - table[k, 0])
                a = table[k, 1] + w * (table[k + 1, 1] - table[k, 1])
                b = table[k, 2] + w * (table[k + 1, 2] - table[k, 2])
    return a, b


#: Neighbours within the cutoff one pass gathers (a disk has at most 12 of its
#: own size there); past this many, further passes take the next ones.
_GATHER = 24


@ti.func
def _within(bodies: ti.template(), particles: ti.template(), r, i, j, cutoff):
    d = 0.5 * (particles.d_eq[i] + particles.d_eq[j])
    return (j != i and bodies.alive[r, j] != 0
            and (bodies.x[r, j] - bodies.x[r, i]).norm() < (1.0 + cutoff) * d)


@ti.func
def _gather(bodies: ti.template(), particles: ti.template(), neighbors: ti.template(),
            r, i, last, cutoff):
    """``(near, n)``: the live bodies numbered above ``last`` within the cutoff of
    body ``i``, from the 5 x 5 cells round it: ``n`` of them, the smallest
    ``_GATHER`` numbers in ``near`` in increasing order (an insertion sort)."""
    near = ti.Vector([0] * _GATHER, dt=ti.i32)
    n = 0
    ncx, ncy = neighbors.cell_shape[0], neighbors.cell_shape[1]
    ccap = neighbors.cell_p.shape[2]
    cx, cy = cell_of(neighbors, bodies.x[r, i])
    for dx, dy in ti.ndrange((-2, 3), (-2, 3)):
        ax, ay = cx + dx, cy + dy
        if 0 <= ax < ncx and 0 <= ay < ncy:
            c = ax * ncy + ay
            for s in range(ti.min(neighbors.cell_n[r, c], ccap)):
                j = neighbors.cell_p[r, c, s]
                if j > last and _within(bodies, particles, r, i, j, cutoff):
                    if n < _GATHER or j < near[_GATHER - 1]:
                        slot = ti.min(n, _GATHER - 1)
                        while slot > 0 and near[slot - 1] > j:
                            near[slot] = near[slot - 1]
                            slot -= 1
                        near[slot] = j
                    n += 1
    return near, n


@ti.func
def _add_pair(bodies: ti.template(), particles: ti.template(), table: ti.template(),
              r, i, j, k):
    """``k`` (Kxx, Kxy, Kyy) with the term of neighbour ``j`` added."""
    sep = bodies.x[r, j] - bodies.x[r, i]
    dist = ti.max(sep.norm(), 1e-30)
    d = 0.5 * (particles.d_eq[i] + particles.d_eq[j])
    a, b = _coefficients(table, dist / d - 1.0)
    e = sep / dist
    return k + ti.Vector([a + b * (2.0 * e.x * e.x - 1.0), b * 2.0 * e.x * e.y,
                          a + b * (2.0 * e.y * e.y - 1.0)])


@ti.kernel
def pair_mobility(bodies: _PAIR_BODIES, running: ti.types.ndarray(),
                  which: ti.types.ndarray(), particles: _PAIR_PARTICLES,
                  xi: ti.types.ndarray(), neighbors: NEIGHBORS, table: ti.types.ndarray()):
    """Add ``m xi K_i v_i`` to the held fluid force of every live body of the
    realizations with ``which[r] != 0`` (module docstring); ``xi`` per species
    (``Materials.xi``)."""
    cutoff = table[table.shape[0] - 1, 0]
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        if which[r] != 0 and running[r] != 0 and bodies.alive[r, i] != 0:
            k = ti.Vector([0.0, 0.0, 0.0])
            # the neighbours in number order (the sum's order), _GATHER at a time
            last = -1
            found = 0
            while True:
                near, n = _gather(bodies, particles, neighbors, r, i, last, cutoff)
                for q in range(ti.min(n, _GATHER)):
                    k = _add_pair(bodies, particles, table, r, i, near[q], k)
                found += n
                if n <= _GATHER:
                    break
                last = near[_GATHER - 1]
            if found > 0:
                vel = bodies.v[r, i]
                scale = particles.mass[i] * xi[particles.species[i]]
                bodies.f_fluid[r, i] += scale * vec2(k[0] * vel.x + k[1] * vel.y,
                                                     k[1] * vel.x + k[2] * vel.y)
