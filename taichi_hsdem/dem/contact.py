"""Contact forces (docs/model.md section 1): the LS-DEM node law and the disk fast path.

For particle ``i`` against ``j`` every surface node ``p`` of ``i`` is mapped into
``j``'s body frame and ``phi_j(p)`` is bilinearly interpolated on ``j``'s level-set
grid. A node with ``phi_j(p) < 0`` is in contact:

* normal force ``F_n = -phi_j(p) k_n n - gamma_n (u . n) n`` with ``n`` the
  normalised gradient of ``phi_j`` (world frame) and ``u`` the velocity of ``i``
  relative to ``j`` at ``p``;
* shear ``F_s <- F_s - k_s dt u_t``, kept per (node, partner), rotated onto the
  current tangent, reset when the node leaves contact, capped at ``mu |F_n|``;
* moment ``(p - x) x (F_n + F_s)``.

``gamma_n = c_e sqrt(k_n m_eff)`` with ``c_e = -2 ln(e) / sqrt(pi^2 + ln(e)^2)``.

Both directions of a pair are evaluated (``i``'s nodes in ``j`` *and* ``j``'s nodes in
``i``), so a corner of either body cannot pass through a face of the other. Each
thread owns one body and sums every force acting on it, the reaction of the other
direction included, instead of scattering reactions with atomics: the summation
order is then fixed, so a realization gives bit-identical results whatever else
runs beside it. The price is evaluating each node pair twice; the shear history
is double-buffered (read ``old``, the owner writes ``new``) so that both threads
see the same history.

With ``normalize`` (the paper's choice) the resultant force and moment of one
direction of one contact are divided by its number of nodes in contact. When both
directions see a contact (two disks, two faces) the pair's resultant is their
mean; a corner driven into a face is seen by one direction only and counts alone.
Against the walls each place of contact (a run of consecutive surface nodes along
the outline) is one contact: a body touching them in two places, as an arch of a
body on its two feet or a body in a corner, gets each resultant divided by its own
count. Between two bodies all the nodes of one direction still count as one
contact, wherever they touch (two interlocked concave bodies touching in two
places get one count; which places of the two directions are the same contact is
not worked out).

Disks (every particle a circle) take the analytic path: one contact point per
pair, ``delta = r_i + r_j - |x_i - x_j|``, the same law, no level-set grids.
With rolling friction ``mu_r`` (disks only) each contact also carries a rolling
moment: an elastic part ``M <- M - k_r dt (omega_i - omega_j)``, ``k_r = k_s
r_eff^2``, with a dashpot ``c_e sqrt(k_r I_eff)`` while it holds, capped at
``mu_r r_eff |F_n|`` (``r_eff = r_i r_j / (r_i + r_j)``, ``1/I_eff = 1/I_i +
1/I_j``; ``r_i``, ``I_i`` and ``omega_j = 0`` against a wall); the elastic part is
kept beside the shear in the history (node 1 of the disk).
"""

from ..backend import on_gpu, ti  # sets the environment before Taichi loads
from .kmath import cross, node_world, rot, rot_t, sin_cos, spin, template_sample, wall_sample
from ..layout import (BAD_PASSED, F_HISTORY_OVERFLOW, PAIR_CE, PAIR_KN, PAIR_KS, PAIR_MU,
                      PAIR_MUR)
from .neighbors import NEIGHBORS
from .state import (CONTACT_PARTICLES, Batch, Bodies, Materials, ShearHistory, Templates,
                    WallGrid)

vec2 = ti.math.vec2


@ti.func
def contact_law(depth, n, u, fs_old, kn, ks, mu, gamma, dt):
    """Normal and updated shear force of one contact point (see module doc)."""
    un = u.dot(n)
    fn = depth * kn * n - gamma * un * n
    # Shear carried over from the last step, rotated onto the current tangent.
    fs = fs_old - fs_old.dot(n) * n
    fs -= ks * dt * (u - un * n)
    cap = mu * fn.norm()
    fsn = fs.norm()
    if fsn > cap:
        fs *= cap / fsn
    return fn, fs


# Places of contact along a body's outline. Its surface nodes are numbered along
# the outline, so the nodes of one place of contact are a run of consecutive
# numbers (the last node's neighbour being node 0). The paper divides the
# resultant of a contact by its number of nodes in contact: a body touching the
# walls in several places (a corner of the channel; an L standing on both its
# feet) has several contacts, each divided by its own count. _place_step folds
# one node into the accumulator, _place_total closes it; a single place gives
# the plain sum over the nodes (the caller divides that, for the same bits).
# Accumulator: the open run's force and moment and count (0-3), the first run's
# when it starts at node 0 (4-7; it may join the last run), the closed runs'
# normalized sums (8-10), the count of places (11).
_OPEN, _FIRST, _SUM, _PLACES = 0, 4, 8, 11


@ti.func
def _no_places():
    return ti.Vector([0.0] * 12)


@ti.func
def _place_step(acc, k, hit, fm):
    out = acc
    if hit:
        for c in ti.static(range(3)):
            out[_OPEN + c] += fm[c]
        out[_OPEN + 3] += 1.0
    elif acc[_OPEN + 3] > 0:  # the run before node k ends
        if k - acc[_OPEN + 3] == 0:  # it started at node 0: keep it for the wrap
            for c in ti.static(range(4)):
                out[_FIRST + c] = acc[_OPEN + c]
        else:
            for c in ti.static(range(3)):
                out[_SUM + c] += acc[_OPEN + c] / acc[_OPEN + 3]
        for c in ti.static(range(4)):
            out[_OPEN + c] = 0.0
        out[_PLACES] += 1.0
    return out


@ti.func
def _place_total(acc):
    """(sum over places of their resultant over their node count, number of places).
    With every node in contact no run was closed: the open run is the one place."""
    total = ti.Vector([acc[_SUM], acc[_SUM + 1], acc[_SUM + 2]])
    places = acc[_PLACES]
    run = acc[_OPEN + 3]
    first = acc[_FIRST + 3]
    if run > 0 and first > 0:  # the last run goes on into the first one
        for c in ti.static(range(3)):
            total[c] += (acc[_FIRST + c] + acc[_OPEN + c]) / (first + run)
    else:
        if run > 0:
            places += 1.0
            for c in ti.static(range(3)):
                total[c] += acc[_OPEN + c] / run
        if first > 0:
            for c in ti.static(range(3)):
                total[c] += acc[_FIRST + c] / first
    return total, ti.cast(places, ti.i32)


@ti.func
def find_shear(hp: ti.template(), hs: ti.template(), r, i, k, slots: ti.template(), partner):
    fs = vec2(0.0, 0.0)
    for s in ti.static(range(slots)):
        if hp[r, i, k, s] == partner + 1:
            fs = hs[r, i, k, s]
    return fs


@ti.func
def store_shear(hp: ti.template(), hs: ti.template(), r, i, k, slots: ti.template(), partner, fs):
    """Keep the shear ``fs`` of node ``k`` against ``partner``; returns 1 if every
    slot was taken (the contact force is kept, its history dropped), else 0. The
    caller counts the drops into ``flags[F_HISTORY_OVERFLOW]`` after its loops:
    Taichi 1.7.4's integer atomics inside a loop break the loop on Vulkan."""
    stored = 0
    for s in ti.static(range(slots)):
        if stored == 0 and hp[r, i, k, s] == 0:
            hp[r, i, k, s] = partner + 1
            hs[r, i, k, s] = fs
            stored = 1
    return 1 - stored


@ti.func
def rolling_law(m_old, w_rel, kr, cr, cap, dt):
    """Rolling moment of one disk contact and the elastic part to keep: the
    elastic moment carried over, turned by the relative spin ``w_rel`` over the
    step, with the dashpot ``cr`` while it holds; at the limit ``cap`` the
    contact rolls and the moment is the limit (no dashpot)."""
    m_el = m_old - kr * dt * w_rel
    m = m_el
    if ti.abs(m_el) >= cap:
        if m_el != 0.0:
            m_el *= cap / ti.abs(m_el)
        m = m_el
    else:
        m = m_el - cr * w_rel
        if ti.abs(m) > cap:
            m *= cap / ti.abs(m)
    return m, m_el


@ti.func
def find_roll(hp: ti.template(), hs: ti.template(), r, i, slots: ti.template(), partner):
    """Disk ``i``'s rolling moment against ``partner`` from the last step (0 for a
    new contact): in the slot of the partner's shear, node 1."""
    m = 0.0
    for s in ti.static(range(slots)):
        if hp[r, i, 0, s] == partner + 1:
            m = hs[r, i, 1, s][0]
    return m


@ti.func
def store_roll(hp: ti.template(), hs: ti.template(), r, i, slots: ti.template(), partner, m):
    """Keep the rolling moment beside the partner's shear (:func:`store_shear`
    first; dropped with it when every slot was taken)."""
    for s in ti.static(range(slots)):
        if hp[r, i, 0, s] == partner + 1:
            hs[r, i, 1, s] = vec2(m, 0.0)


@ti.func
def roll_contact(hp_old: ti.template(), hs_old: ti.template(), hp_new: ti.template(),
                 hs_new: ti.template(), r, i, slots: ti.template(), partner, w_rel, ks, ce,
                 reff, ieff, limit, dt):
    """Disk ``i``'s rolling moment against ``partner`` this step
    (:func:`rolling_law` with ``k_r = k_s r_eff^2`` and the dashpot
    ``c_e sqrt(k_r I_eff)``), its elastic part kept in the new history."""
    kr = ks * reff * reff
    m, m_el = rolling_law(find_roll(hp_old, hs_old, r, i, slots, partner), w_rel, kr,
                          ce * ti.sqrt(kr * ieff), limit, dt)
    store_roll(hp_new, hs_new, r, i, slots, partner, m_el)
    return m


@ti.kernel
def ls_contacts(bodies: Bodies.Pack, batch: Batch.Pack, particles: CONTACT_PARTICLES,
                materials: Materials.Pack, templates: Templates.Pack, walls: WallGrid.Pack,
                history: ShearHistory.Pack, neighbors: NEIGHBORS, flags: ti.types.ndarray(),
                slots: ti.template(), dt: float, normalize: ti.i32):
    """Add every contact force and moment acting on each body (level-set path,
    :func:`ls_force`)."""
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        if batch.running[r] == 0 or bodies.alive[r, i] == 0:
            continue
        f, m, deepest = ls_force(bodies, batch, particles, materials, templates, walls, history,
                                 neighbors, flags, slots, dt, normalize, r, i)
        bodies.force[r, i] += f
        bodies.torque[r, i] += m
        ti.atomic_max(batch.max_overlap[r], deepest)


@ti.kernel
def ls_pair_contacts(bodies: Bodies.Pack, batch: Batch.Pack, particles: CONTACT_PARTICLES,
                     materials: Materials.Pack, templates: Templates.Pack,
                     history: ShearHistory.Pack, neighbors: NEIGHBORS, flags: ti.types.ndarray(),
                     part_f: ti.types.ndarray(), part_m: ti.types.ndarray(),
                     slots: ti.template(), dt: float, normalize: ti.i32):
    """The first half of :func:`ls_contacts` for a GPU, whose shaders read at most
    31 arrays (ls_contacts reads 34): each body's contacts with its neighbours,
    into ``part_f`` ((R, N, 2)) and ``part_m`` ((R, N, 2): moment, deepest
    overlap); :func:`ls_wall_contacts` adds the walls' and both to the body, the
    same operations in the same order as ls_contacts."""
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        if batch.running[r] == 0 or bodies.alive[r, i] == 0:
            continue
        f, m, deepest = ls_pairs(bodies, batch, particles, materials, templates, history,
                                 neighbors, flags, slots, dt, normalize, r, i)
        for c in ti.static(range(2)):
            part_f[r, i, c] = f[c]
        part_m[r, i, 0] = m
        part_m[r, i, 1] = deepest


@ti.kernel
def ls_wall_contacts(bodies: Bodies.Pack, batch: Batch.Pack, particles: CONTACT_PARTICLES,
                     materials: Materials.Pack, templates: Templates.Pack, walls: WallGrid.Pack,
                     history: ShearHistory.Pack, flags: ti.types.ndarray(),
                     part_f: ti.types.ndarray(), part_m: ti.types.ndarray(),
                     slots: ti.template(), dt: float, normalize: ti.i32):
    """The second half (see :func:`ls_pair_contacts`)."""
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        if batch.running[r] == 0 or bodies.alive[r, i] == 0:
            continue
        fw, mw, deepest = ls_walls(bodies, particles, materials, templates, walls, history,
                                   flags, slots, dt, normalize, part_m[r, i, 1], r, i)
        bodies.force[r, i] += vec2(part_f[r, i, 0], part_f[r, i, 1]) + fw
        bodies.torque[r, i] += part_m[r, i, 0] + mw
        ti.atomic_max(batch.max_overlap[r], deepest)


@ti.func
def ls_force(bodies: ti.template(), batch: ti.template(), particles: ti.template(),
             materials: ti.template(), templates: ti.template(), walls: ti.template(),
             history: ti.template(), neighbors: ti.template(), flags: ti.template(),
             slots: ti.template(), dt, normalize, r, i):
    """Contact force, moment and deepest overlap (fraction of d_eq) on body ``i``
    of realization ``r``: :func:`ls_pairs`, then :func:`ls_walls`."""
    f, m, deepest = ls_pairs(bodies, batch, particles, materials, templates, history, neighbors,
                             flags, slots, dt, normalize, r, i)
    fw, mw, deepest = ls_walls(bodies, particles, materials, templates, walls, history, flags,
                               slots, dt, normalize, deepest, r, i)
    return f + fw, m + mw, deepest


@ti.func
def _body_pose(bodies: ti.template(), particles: ti.template(), templates: ti.template(), r, i):
    """Body ``i`` of realization ``r`` as the node loops read it: its template,
    position, (cos, sin) of its angle, velocity, spin, and its nodes' offset and
    count in the stacked node table."""
    t = particles.species[i]
    c, s = sin_cos(bodies.theta[r, i])
    return (t, bodies.x[r, i], c, s, bodies.v[r, i], bodies.omega[r, i],
            templates.node_meta[t, 0], templates.node_meta[t, 1])


@ti.func
def ls_pairs(bodies: ti.template(), batch: ti.template(), particles: ti.template(),
             materials: ti.template(), templates: ti.template(), history: ti.template(),
             neighbors: ti.template(), flags: ti.template(), slots: ti.template(), dt,
             normalize, r, i):
    """Contact force, moment and deepest overlap (fraction of d_eq) on body ``i``
    of realization ``r`` from its listed neighbours; starts its new shear history
    (:func:`ls_walls` adds the walls' entries).

    A body whose inside point (the deepest point of its template, ``inside``:
    not its centre of mass, which an L-shape's notch holds) lies inside a
    neighbour has passed through it between surface nodes (too few nodes for the
    speed or the shapes): the realization is flagged ``BAD_PASSED`` rather than
    allowed to go on with bodies inside bodies. A body resting in another's notch
    does not trip it: the neighbour would have to sink in by the whole inscribed
    radius.

    Pairs whose bounding circles do not meet are skipped (no node of one can be
    inside the other), and so is a node outside the other body's bounding circle.
    """
    ti_, xi, ci, si, vi, wi, noff_i, nn_i = _body_pose(bodies, particles, templates, r, i)
    pole_i = node_world(templates.inside, ti_, xi, ci, si)
    rb_i = particles.bounding_radius[i]
    for k in range(nn_i):
        for s in ti.static(range(slots)):
            history.partners_new[r, i, k, s] = 0
    ftot = vec2(0.0, 0.0)
    mtot = 0.0
    deepest = 0.0
    dropped = 0
    passed = 0
    for q in range(neighbors.nbr_n[r, i]):
        j = neighbors.nbr[r, i, q]
        if bodies.alive[r, j] == 0:
            continue
        tj = particles.species[j]
        xj = bodies.x[r, j]
        rb_j = particles.bounding_radius[j]
        if (xi - xj).norm() >= rb_i + rb_j:
            continue
        cj, sj = sin_cos(bodies.theta[r, j])
        vj = bodies.v[r, j]
        wj = bodies.omega[r, j]
        a, b = particles.species[i], particles.species[j]
        kn = materials.pair[a, b, PAIR_KN]
        ks = materials.pair[a, b, PAIR_KS]
        mu = materials.pair[a, b, PAIR_MU]
        mi = particles.mass[i]
        mj = particles.mass[j]
        meff = mi * mj / (mi + mj)
        gamma = materials.pair[a, b, PAIR_CE] * ti.sqrt(kn * meff)
        held, _ = template_sample(templates.ls_phi, templates.ls_grad, templates.ls_meta,
                                  templates.ls_geo, tj, rot_t(cj, sj, pole_i - xj))
        if held < 0.0:
            passed = 1
        # (a) nodes of i inside j: force on i, history owned by i.
        fa = vec2(0.0, 0.0)
        ma = 0.0
        na = 0
        for k in range(nn_i):
            p = node_world(templates.node_pos, noff_i + k, xi, ci, si)
            if (p - xj).norm() >= rb_j:
                continue
            qb = rot_t(cj, sj, p - xj)
            phi, g = template_sample(templates.ls_phi, templates.ls_grad,
                                     templates.ls_meta, templates.ls_geo, tj, qb)
            if phi < 0.0 and g.norm() > 0.0:
                nrm = rot(cj, sj, g.normalized())
                u = (vi + spin(wi, p - xi)) - (vj + spin(wj, p - xj))
                fs_old = find_shear(history.partners_old, history.shear_old, r, i, k,
                                    slots, j)
                fn, fs = contact_law(-phi, nrm, u, fs_old, kn, ks, mu, gamma, dt)
                dropped += store_shear(history.partners_new, history.shear_new, r, i, k,
                                       slots, j, fs)
                fa += fn + fs
                ma += cross(p - xi, fn + fs)
                na += 1
                deepest = ti.max(deepest, -phi / particles.d_eq[i])
        # (b) nodes of j inside i: the reaction on i, with j's (old) history.
        fb = vec2(0.0, 0.0)
        mb = 0.0
        nb = 0
        noff_j = templates.node_meta[tj, 0]
        for k in range(templates.node_meta[tj, 1]):
            p = node_world(templates.node_pos, noff_j + k, xj, cj, sj)
            if (p - xi).norm() >= rb_i:
                continue
            qb = rot_t(ci, si, p - xi)
            phi, g = template_sample(templates.ls_phi, templates.ls_grad,
                                     templates.ls_meta, templates.ls_geo, ti_, qb)
            if phi < 0.0 and g.norm() > 0.0:
                nrm = rot(ci, si, g.normalized())
                u = (vj + spin(wj, p - xj)) - (vi + spin(wi, p - xi))
                fs_old = find_shear(history.partners_old, history.shear_old, r, j, k,
                                    slots, i)
                fn, fs = contact_law(-phi, nrm, u, fs_old, kn, ks, mu, gamma, dt)
                fb -= fn + fs
                mb -= cross(p - xi, fn + fs)
                nb += 1
        if normalize != 0:
            if na > 0:
                fa /= na
                ma /= na
            if nb > 0:
                fb /= nb
                mb /= nb
        # Both directions estimate the same contact: average them when both see
        # it, so a pair is not twice as stiff as a body against a wall.
        both = 0.5 if na > 0 and nb > 0 else 1.0
        ftot += both * (fa + fb)
        mtot += both * (ma + mb)
    if passed != 0:    # after the loops (store_shear)
        ti.atomic_or(batch.bad[r], BAD_PASSED)
    if dropped != 0:
        flags[F_HISTORY_OVERFLOW] += dropped
    return ftot, mtot, deepest


@ti.func
def ls_walls(bodies: ti.template(), particles: ti.template(), materials: ti.template(),
             templates: ti.template(), walls: ti.template(), history: ti.template(),
             flags: ti.template(), slots: ti.template(), dt, normalize, deepest_pairs, r, i):
    """The walls' part of :func:`ls_force`: the nodes of body ``i`` against the
    static wall level set; the deepest overlap so far comes in (``deepest_pairs``)
    and goes out updated."""
    n_part = bodies.x.shape[1]
    ti_, xi, ci, si, vi, wi, noff_i, nn_i = _body_pose(bodies, particles, templates, r, i)
    deepest = deepest_pairs
    dropped = 0
    a = particles.species[i]
    kn = materials.wall[a, PAIR_KN]
    ks = materials.wall[a, PAIR_KS]
    mu = materials.wall[a, PAIR_MU]
    gamma = materials.wall[a, PAIR_CE] * ti.sqrt(kn * particles.mass[i])
    fw = vec2(0.0, 0.0)
    mw = 0.0
    nw = 0
    places = _no_places()
    for k in range(nn_i):
        p = node_world(templates.node_pos, noff_i + k, xi, ci, si)
        phi, g = wall_sample(walls, p)
        hit = False
        fm = ti.Vector([0.0, 0.0, 0.0])
        if phi < 0.0 and g.norm() > 0.0:
            nrm = g.normalized()
            u = vi + spin(wi, p - xi)
            fs_old = find_shear(history.partners_old, history.shear_old, r, i, k, slots,
                                n_part)
            fn, fs = contact_law(-phi, nrm, u, fs_old, kn, ks, mu, gamma, dt)
            dropped += store_shear(history.partners_new, history.shear_new, r, i, k, slots,
                                   n_part, fs)
            fc = fn + fs
            mc = cross(p - xi, fc)
            fw += fc
            mw += mc
            nw += 1
            deepest = ti.max(deepest, -phi / particles.d_eq[i])
            hit = True
            fm = ti.Vector([fc[0], fc[1], mc])
        places = _place_step(places, k, hit, fm)
    if normalize != 0 and nw > 0:
        total, count = _place_total(places)
        if count > 1:   # touching the walls in several places: each its own contact
            fw = vec2(total[0], total[1])
            mw = total[2]
        else:
            fw /= nw
            mw /= nw
    if dropped != 0:   # after the loops (store_shear)
        flags[F_HISTORY_OVERFLOW] += dropped
    return fw, mw, deepest


@ti.kernel
def disk_contacts(bodies: Bodies.Pack, batch: Batch.Pack, particles: CONTACT_PARTICLES,
                  materials: Materials.Pack, walls: WallGrid.Pack, history: ShearHistory.Pack,
                  neighbors: NEIGHBORS, flags: ti.types.ndarray(), slots: ti.template(),
                  dt: float):
    """Add every contact force and moment on each disk (analytic fast path).

    The pair is evaluated by both disks, each keeping its own copy of the shear
    history; the two copies stay exact mirrors because every operation is
    antisymmetric in (i, j).
    """
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        if batch.running[r] == 0 or bodies.alive[r, i] == 0:
            continue
        ftot, mtot, deepest = disk_force(
            bodies, particles, materials, walls, neighbors, history.partners_old,
            history.shear_old, history.partners_new, history.shear_new, slots, flags, dt, r, i)
        bodies.force[r, i] += ftot
        bodies.torque[r, i] += mtot
        ti.atomic_max(batch.max_overlap[r], deepest)


@ti.func
def disk_force(bodies: ti.template(), particles: ti.template(), materials: ti.template(),
               walls: ti.template(), neighbors: ti.template(), hp_old: ti.template(),
               hs_old: ti.template(), hp_new: ti.template(), hs_new: ti.template(),
               slots: ti.template(), flags: ti.template(), dt, r, i):
    """Contact force, moment and deepest overlap (fraction of d) on disk ``i`` of
    realization ``r`` from its listed neighbours and the walls; writes its new
    shear history."""
    n_part = bodies.x.shape[1]
    for s in ti.static(range(slots)):
        hp_new[r, i, 0, s] = 0
    xi = bodies.x[r, i]
    vi = bodies.v[r, i]
    wi = bodies.omega[r, i]
    ri = particles.disk_radius[i]
    ftot = vec2(0.0, 0.0)
    mtot = 0.0
    deepest = 0.0
    dropped = 0
    for q in range(neighbors.nbr_n[r, i]):
        j = neighbors.nbr[r, i, q]
        if bodies.alive[r, j] == 0:
            continue
        d = xi - bodies.x[r, j]
        dist = d.norm()
        depth = ri + particles.disk_radius[j] - dist
        if depth > 0.0 and dist > 0.0:
            nrm = d / dist
            a, b = particles.species[i], particles.species[j]
            kn = materials.pair[a, b, PAIR_KN]
            mi = particles.mass[i]
            mj = particles.mass[j]
            meff = mi * mj / (mi + mj)
            gamma = materials.pair[a, b, PAIR_CE] * ti.sqrt(kn * meff)
            # contact point half-way through the overlap
            ra = -(ri - 0.5 * depth) * nrm
            rb = (particles.disk_radius[j] - 0.5 * depth) * nrm
            u = (vi + spin(wi, ra)) - (bodies.v[r, j] + spin(bodies.omega[r, j], rb))
            fs_old = find_shear(hp_old, hs_old, r, i, 0, slots, j)
            fn, fs = contact_law(depth, nrm, u, fs_old, kn, materials.pair[a, b, PAIR_KS],
                                 materials.pair[a, b, PAIR_MU], gamma, dt)
            dropped += store_shear(hp_new, hs_new, r, i, 0, slots, j, fs)
            ftot += fn + fs
            mtot += cross(ra, fs)
            mur = materials.pair[a, b, PAIR_MUR]
            if mur > 0.0:
                rj = particles.disk_radius[j]
                reff = ri * rj / (ri + rj)
                # 1 / I_eff summed in an order symmetric in (i, j), and kept in
                # range in single precision (I ~ 1e-17 kg m^2 for the vani disks)
                ieff = 1.0 / (2.0 / (mi * ri * ri) + 2.0 / (mj * rj * rj))
                mtot += roll_contact(hp_old, hs_old, hp_new, hs_new, r, i, slots, j,
                                     wi - bodies.omega[r, j], materials.pair[a, b, PAIR_KS],
                                     materials.pair[a, b, PAIR_CE], reff, ieff,
                                     mur * reff * fn.norm(), dt)
            deepest = ti.max(deepest, depth / (2.0 * ri))
    phi, g = wall_sample(walls, xi)
    depth = ri - phi
    if depth > 0.0 and g.norm() > 0.0:
        nrm = g.normalized()
        a = particles.species[i]
        kn = materials.wall[a, PAIR_KN]
        gamma = materials.wall[a, PAIR_CE] * ti.sqrt(kn * particles.mass[i])
        ra = -(ri - 0.5 * depth) * nrm
        u = vi + spin(wi, ra)
        fs_old = find_shear(hp_old, hs_old, r, i, 0, slots, n_part)
        fn, fs = contact_law(depth, nrm, u, fs_old, kn, materials.wall[a, PAIR_KS],
                             materials.wall[a, PAIR_MU], gamma, dt)
        dropped += store_shear(hp_new, hs_new, r, i, 0, slots, n_part, fs)
        ftot += fn + fs
        mtot += cross(ra, fs)
        mur = materials.wall[a, PAIR_MUR]
        if mur > 0.0:
            mtot += roll_contact(hp_old, hs_old, hp_new, hs_new, r, i, slots, n_part, wi,
                                 materials.wall[a, PAIR_KS], materials.wall[a, PAIR_CE], ri,
                                 0.5 * particles.mass[i] * ri * ri, mur * ri * fn.norm(), dt)
        deepest = ti.max(deepest, depth / (2.0 * ri))
    if dropped != 0:   # after the loops (store_shear)
        flags[F_HISTORY_OVERFLOW] += dropped
    return ftot, mtot, deepest


def add_forces(bodies, batch, particles, materials, templates, walls, history, neighbors,
               flags, dt: float, normalize: bool, disks: bool):
    """Add every contact force and moment to ``bodies.force``/``torque``: the
    analytic disk law when ``disks`` (every particle a circle), else the level-set
    node law; writes the new shear history (``history.new``) and the deepest
    overlap of each realization (``batch.max_overlap``)."""
    packs = (bodies.pack(), batch.pack(), particles.pack_of(CONTACT_PARTICLES), materials.pack())
    if disks:
        disk_contacts(*packs, walls.pack(), history.pack(), neighbors.pack(), flags,
                      history.slots, dt)
    elif not (SPLIT_LS_CONTACTS or on_gpu()):
        ls_contacts(*packs, templates.pack(), walls.pack(), history.pack(), neighbors.pack(),
                    flags, history.slots, dt, int(normalize))
    else:   # a GPU: two kernels of at most 31 arrays each, the same bits
        part_f, part_m = _parts(bodies.x.shape)
        ls_pair_contacts(*packs, templates.pack(), history.pack(), neighbors.pack(), flags,
                         part_f, part_m, history.slots, dt, int(normalize))
        ls_wall_contacts(*packs, templates.pack(), walls.pack(), history.pack(), flags,
                         part_f, part_m, history.slots, dt, int(normalize))


#: Whether the level-set contacts take the two kernels of a GPU on the CPU too
#: (tests/kernel_arrays.py counts their arrays on the CPU).
SPLIT_LS_CONTACTS = False
_PARTS = {}


def _parts(shape):
    """The pair contacts' sums that ls_pair_contacts hands to ls_wall_contacts."""
    shape = tuple(shape)
    if shape not in _PARTS:
        from .. import backend
        _PARTS[shape] = tuple(ti.ndarray(backend.real(), shape + (2,)) for _ in range(2))
    return _PARTS[shape]
