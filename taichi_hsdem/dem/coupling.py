"""Fluid to particle and particle to fluid (docs/model.md sections 2 and 3).

* Permeability: a fluid cell whose centre lies inside a particle (``phi <= 0``)
  takes the particle species' Kozeny-Carman permeability; other fluid cells keep
  the free value ``H^2/12``; wall cells are not unknowns (``base = 0``).
* Pressure force: each surface node ``k`` takes the pressure ``sigma`` at its
  position and contributes ``F_k = -sigma H a_k``, ``M_k = (p_k - x) x F_k``.
  ``a_k`` is the node's outward boundary vector, ``l_k n_k``, taken as half the
  rotated chord between its two neighbours: the ``a_k`` of a closed outline then
  sum to exactly zero, so a uniform pressure pushes no body anywhere, and in a
  linear pressure field the force is exactly the pressure drop across the node
  polygon's area (divergence theorem) — the property a test checks.

* Carried volume (``fluid.particle_flux = true``): the cells a particle owns
  move at its velocity. ``"implicit"`` (``fluid.flux_coupling``) hands the solver
  each particle's mean velocity over the next interval as an affine function of
  the pressure (:func:`body_drift`, from its motion since the last solve) and
  the cells' owners; ``"lagged"`` rasterises ``chi v`` from the velocities now
  (:meth:`FluidCoupling._source_velocities`). docs/scene.md, Carried volume.

:class:`FluidCoupling` owns the fluid arrays of a batch (permeability, carried
flux, pressure) and the pressure solver (``fluid.solver``: the Taichi multigrid,
which reads the permeability where the kernels wrote it and leaves the pressure
there, or pyamg on the host); the host calls :meth:`FluidCoupling.update` every
``fluid.update_interval`` steps.
"""

import time

import numpy as np

from .. import backend
from ..backend import ti  # sets the environment before Taichi loads
from ..fluid import PressureSolver
from ..fluid.gmg import REAL, BodyTerms, TaichiPressureSolver
from . import state
from .integrate import plate_rate
from .pairs import _PAIR_BODIES, _PAIR_PARTICLES, pair_mobility
from ..laws import pair_mobility_table
from .kmath import cross, exp_neg, node_world, rot, rot_t, sin_cos, spin, template_sample
from ..layout import SAMPLING

vec2 = ti.math.vec2

# The kernels below run at every fluid update (pressure_forces twice with the
# implicit carried volume) and a launch costs about 3.5 us per array: they take
# the parts of the bundles they read (state.Bundle.part), not whole bundles.
_POSE = state.Bodies.part("x", "theta", "alive")
_HELD = state.Bodies.part("x", "theta", "alive", "f_fluid", "tau_fluid")
# what body_drift reads of the particles: inertia, spin drag and plate friction
_DRAG = state.Particles.part("species", "mass", "inertia", "spin", "plate", "creep")
_LEVEL_SETS = state.Templates.part("is_circle", "radius", "ls_phi", "ls_grad", "ls_meta",
                                   "ls_geo")
_NODES = state.Templates.part("node_pos", "node_area", "node_meta")
# FluidCoupling's arrays: the permeability (``cell_kappa``: Materials has a
# ``kappa``), carried flux and owners rasterize_permeability writes, from the
# free permeability ``base`` and the source velocities ``vs``, ``ws``, but not for
# a realization ``frozen`` (1: left out of the solve, see FluidCoupling.update);
# and the bodies' state at the last solve with their terms of the next
# (body_drift).
_CELLS = state.pack_type("FluidCoupling", ("base", "cell_kappa", "carried", "owner", "vs",
                                           "ws", "frozen"))
# (in the pressure solve's float type, REAL; ``drift_consts``: the fluid interval,
# the gap and the grid's origin and cell size, as arrays of that type carry them)
_DRIFT = state.pack_type("FluidCoupling", ("past", "centre", "mobility", "drift",
                                           "drift_consts"))


@ti.func
def inside_body(templates: ti.template(), tm, q):
    """Is body-frame point ``q`` inside template ``tm``."""
    inside = False
    if templates.is_circle[tm] != 0:
        inside = q.norm() <= templates.radius[tm]
    else:
        phi, g = template_sample(templates.ls_phi, templates.ls_grad, templates.ls_meta,
                                 templates.ls_geo, tm, q)
        inside = phi <= 0.0
    return inside


@ti.kernel
def rasterize_permeability(bodies: _POSE, sp: ti.types.ndarray(), rb: ti.types.ndarray(),
                           kp: ti.types.ndarray(), templates: _LEVEL_SETS, cells: _CELLS,
                           ox: float, oy: float, h: float, span: ti.i32):
    """Permeability of every fluid cell, ``chi v``: the velocity of the particle
    a cell's centre lies in (``vs + ws x r``), zero outside particles, and
    ``owner``: that particle (the highest-numbered where two overlap), -1; a
    realization ``frozen`` keeps what it has.

    A thread per cell of each body's box of cells (``span`` cells a side at
    most), not a loop over the box in a thread per body: a GPU gets the threads,
    and Taichi 1.7.4's integer atomics inside a loop break that loop on Vulkan
    (Mesa's lavapipe: the loop stops early and what follows it is lost)."""
    nx = cells.base.shape[0]
    ny = cells.base.shape[1]
    for r, cx, cy in cells.cell_kappa:
        if cells.frozen[r] == 0:
            cells.cell_kappa[r, cx, cy] = cells.base[cx, cy]
            cells.carried[r, cx, cy] = vec2(0.0, 0.0)
            cells.owner[r, cx, cy] = -1
    for r, i, t in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1], span * span):
        if bodies.alive[r, i] == 0 or cells.frozen[r] != 0:
            continue
        xi = bodies.x[r, i]
        i0 = ti.max(ti.cast(ti.floor((xi.x - rb[i] - ox) / h - 0.5), ti.i32), 0)
        i1 = ti.min(ti.cast(ti.ceil((xi.x + rb[i] - ox) / h - 0.5), ti.i32), nx - 1)
        j0 = ti.max(ti.cast(ti.floor((xi.y - rb[i] - oy) / h - 0.5), ti.i32), 0)
        j1 = ti.min(ti.cast(ti.ceil((xi.y + rb[i] - oy) / h - 0.5), ti.i32), ny - 1)
        a = i0 + t // span
        b = j0 + t % span
        if a <= i1 and b <= j1:
            if cells.base[a, b] > 0.0:
                c, s = sin_cos(bodies.theta[r, i])
                centre = vec2(ox + (a + 0.5) * h, oy + (b + 0.5) * h)
                if inside_body(templates, sp[i], rot_t(c, s, centre - xi)):
                    ti.atomic_min(cells.cell_kappa[r, a, b], kp[sp[i]])
                    ti.atomic_max(cells.owner[r, a, b], i)
                    cells.carried[r, a, b] = (cells.vs[r, i]
                                              + spin(cells.ws[r, i], centre - xi))


@ti.func
def sample_pressure(pres: ti.template(), active: ti.template(), r, p, ox, oy, h, mode):
    """Pressure at ``p``: bilinear over the active cell centres around it
    (weights renormalised next to walls), or the value of the cell holding it."""
    nx = active.shape[0]
    ny = active.shape[1]
    gx = (p.x - ox) / h - 0.5
    gy = (p.y - oy) / h - 0.5
    value = 0.0
    done = False
    if mode == 1:
        a = ti.cast(ti.floor(gx + 0.5), ti.i32)
        b = ti.cast(ti.floor(gy + 0.5), ti.i32)
        if 0 <= a < nx and 0 <= b < ny:
            if active[a, b] != 0:
                value = pres[r, a, b]
                done = True
    if not done:
        i0 = ti.cast(ti.floor(gx), ti.i32)
        j0 = ti.cast(ti.floor(gy), ti.i32)
        fx = gx - i0
        fy = gy - j0
        wsum = 0.0
        acc = 0.0
        for da, db in ti.static(ti.ndrange(2, 2)):
            a = i0 + da
            b = j0 + db
            if 0 <= a < nx and 0 <= b < ny:
                if active[a, b] != 0:
                    wgt = (fx if da == 1 else 1.0 - fx) * (fy if db == 1 else 1.0 - fy)
                    wsum += wgt
                    acc += wgt * pres[r, a, b]
        if wsum > 0.0:
            value = acc / wsum
    return value


@ti.func
def _interval_shares(y):
    """For the damped motion ``v' = F/m - xi v`` at constant F over an interval T,
    ``y = xi T``: ``(alpha, g)`` with the interval's mean velocity
    ``alpha v0 + g T F / m``: ``alpha = (1 - exp(-y)) / y``, ``g = (1 - alpha) / y``
    (1 and 1/2 at y = 0, by the series below y = 0.01)."""
    g = ti.cast(0.5, REAL.dtype)
    if y < 0.01:
        g = 0.5 + y * (-1.0 / 6.0 + y * (1.0 / 24.0 - y / 120.0))
    else:
        g = (y - 1.0 + exp_neg(y)) / (y * y)
    return 1.0 - y * g, g


@ti.kernel
def body_drift(bodies: state.Bodies.Pack, running: ti.types.ndarray(), particles: _DRAG,
               xi: ti.types.ndarray(), carried: ti.types.ndarray(), terms: _DRIFT):
    """fluid.gmg.BodyTerms of every body but ``owner``: its mean velocity over the
    next fluid interval if the force it felt over the last one were held,
    ``drift = alpha v0 + g T F / m``, and how that changes with the pressure
    force, ``mobility = H g T / m`` (``I`` for the rotation); its centre in
    cell units. ``F``, the mean force of the last interval (held pressure force
    and contacts), follows from the motion since the last solve (``past``: pose,
    velocity and whether it was in play then), ``F T = m (dv + xi dx)``; for a
    body without that history (just placed or re-inserted), the pressure force
    ``f`` of the last pressure at its present pose and the external load. Then
    ``past`` is set to now. The spin relaxes at ``xi + spin`` (the spin drag
    over the inertia), the translation at ``xi`` plus the plate friction's rate
    at the present speed. Both terms are scaled by the species' carried
    fraction: the solve's source is the flux the body's cells carry, ``c`` times
    its velocity (docs/model.md section 3.4)."""
    for r, i in ti.ndrange(bodies.v.shape[0], bodies.v.shape[1]):
        interval, gap = terms.drift_consts[0], terms.drift_consts[1]
        ox, oy, h = terms.drift_consts[2], terms.drift_consts[3], terms.drift_consts[4]
        for q in ti.static(range(3)):
            terms.mobility[r, i, q] = 0.0
            terms.drift[r, i, q] = 0.0
        terms.centre[r, i, 0] = (ti.cast(bodies.x[r, i].x, REAL.dtype) - ox) / h - 0.5
        terms.centre[r, i, 1] = (ti.cast(bodies.x[r, i].y, REAL.dtype) - oy) / h - 0.5
        now = ti.Vector([ti.cast(bodies.x[r, i].x, REAL.dtype),
                         ti.cast(bodies.x[r, i].y, REAL.dtype),
                         ti.cast(bodies.theta[r, i], REAL.dtype)], dt=REAL.dtype)
        vel = ti.Vector([ti.cast(bodies.v[r, i].x, REAL.dtype),
                         ti.cast(bodies.v[r, i].y, REAL.dtype),
                         ti.cast(bodies.omega[r, i], REAL.dtype)], dt=REAL.dtype)
        play = running[r] != 0 and bodies.alive[r, i] != 0
        if play:
            k_spin = xi[particles.species[i]] + particles.spin[i]
            kv = ti.cast(xi[particles.species[i]], REAL.dtype) + ti.cast(
                plate_rate(particles, i, bodies.v[r, i]), REAL.dtype)
            k = ti.Vector([kv, kv, ti.cast(k_spin, REAL.dtype)], dt=REAL.dtype)
            inert = ti.Vector([ti.cast(particles.mass[i], REAL.dtype),
                               ti.cast(particles.mass[i], REAL.dtype),
                               ti.cast(particles.inertia[i], REAL.dtype)], dt=REAL.dtype)
            impulse = ti.Vector([0.0, 0.0, 0.0], dt=REAL.dtype)   # (mean force) T / inertia
            if terms.past[r, i, 6] != 0:
                for q in ti.static(range(3)):
                    impulse[q] = ((vel[q] - terms.past[r, i, 3 + q])
                                  + k[q] * (now[q] - terms.past[r, i, q]))
            else:
                held, ext = bodies.f_fluid[r, i], bodies.f_ext[r, i]
                load = ti.Vector([ti.cast(held.x + ext.x, REAL.dtype), ti.cast(held.y + ext.y, REAL.dtype),
                                  ti.cast(bodies.tau_fluid[r, i] + bodies.tau_ext[r, i],
                                          REAL.dtype)], dt=REAL.dtype)
                impulse = load * interval / inert
            c = ti.cast(carried[particles.species[i]], REAL.dtype)
            for q in ti.static(range(3)):
                alpha, g = _interval_shares(k[q] * interval)
                terms.mobility[r, i, q] = c * (gap * g * interval / inert[q])
                terms.drift[r, i, q] = c * (alpha * vel[q] + g * impulse[q])
        for q in ti.static(range(3)):
            terms.past[r, i, q] = now[q]
            terms.past[r, i, 3 + q] = vel[q]
        terms.past[r, i, 6] = 1.0 if play else 0.0


@ti.kernel
def pressure_forces(bodies: _HELD, running: ti.types.ndarray(), which: ti.types.ndarray(),
                    sp: ti.types.ndarray(), templates: _NODES, pres: ti.types.ndarray(),
                    active: ti.types.ndarray(), ox: float, oy: float, h: float, gap: float,
                    mode: ti.i32):
    """Set ``f_fluid``, ``tau_fluid`` of every body of the realizations with
    ``which[r] != 0`` to its pressure force and moment (0 where not running or
    not alive); the other realizations' are left as they are."""
    for r, i in ti.ndrange(bodies.x.shape[0], bodies.x.shape[1]):
        if which[r] != 0:
            fsum = vec2(0.0, 0.0)
            msum = 0.0
            if running[r] != 0 and bodies.alive[r, i] != 0:
                xi = bodies.x[r, i]
                c, s = sin_cos(bodies.theta[r, i])
                off = templates.node_meta[sp[i], 0]
                for k in range(templates.node_meta[sp[i], 1]):
                    p = node_world(templates.node_pos, off + k, xi, c, s)
                    sigma = sample_pressure(pres, active, r, p, ox, oy, h, mode)
                    df = -sigma * gap * rot(c, s, vec2(templates.node_area[off + k, 0],
                                                       templates.node_area[off + k, 1]))
                    fsum += df
                    msum += cross(p - xi, df)
            bodies.f_fluid[r, i] = fsum
            bodies.tau_fluid[r, i] = msum


@ti.kernel
def finite_or_zero(src: ti.types.ndarray(), dst: ti.types.ndarray(),
                   frozen: ti.types.ndarray()):
    """``dst = src`` in the kernels' precision, 0 where ``src`` is not finite (the
    walls and cut-off cells, which hold NaN), but for realizations ``frozen``
    (their pressure as it was)."""
    for I in ti.grouped(src):
        if frozen[I[0]] == 0:
            value = src[I]
            dst[I] = 0.0 if ti.math.isnan(value) or ti.math.isinf(value) else value


@ti.kernel
def load_forces(f: ti.types.ndarray(), tau: ti.types.ndarray(), f0: ti.types.ndarray(),
                tau0: ti.types.ndarray()):
    """Start a step's force sums from the held fluid forces ``f0``, ``tau0``."""
    for r, i in f:
        f[r, i] = f0[r, i]
        tau[r, i] = tau0[r, i]


class FluidCoupling:
    """The fluid side of a batch: permeability, carried flux and pressure arrays
    (``(R, nx, ny)``, x-first) and the pressure solver.

    Parameters
    ----------
    model : Model
        The resolved set-up (its fluid grid, boundary condition, solver settings).
    n_real, n_part : int
        Realizations and particles per realization.
    neighbors, materials : NeighborList, Materials
        The batch's broad phase and per-species damping, which the close pairs'
        resistance (``fluid.pair_mobility``) reads.
    """

    def __init__(self, model, n_real: int, n_part: int, neighbors, materials):
        fl = model.scene.fluid
        g = model.geometry
        nx, ny = model.fluid_shape
        shape = (n_real, nx, ny)
        self.model = model
        solver = TaichiPressureSolver if model.fluid_solver == "gmg" else PressureSolver
        self.solver = solver(model.fluid_active, model.fluid_dx, model.fluid_dx, fl.viscosity,
                             model.bc(), n_batch=n_real, tol=fl.solver_tol, gap=fl.gap,
                             workers=model.fluid_workers)
        self.on_device = model.fluid_solver == "gmg"
        self.active = state.array(model.fluid_active.astype(np.int32), ti.i32)
        self.base = state.array(np.where(model.fluid_active, model.kappa_free, 0.0))
        self.kappa = state._zeros(shape)
        self.carried = state._zeros(shape, vector=True)
        self.owner = state._zeros(shape, ti.i32)
        self.pres = state._zeros(shape)
        # particle velocities the carried flux uses (see _source_velocities)
        self.v_src = np.zeros((n_real, n_part, 2))
        self.w_src = np.zeros((n_real, n_part))
        self.vs = state._zeros((n_real, n_part), vector=True)
        self.ws = state._zeros((n_real, n_part))
        self.frozen = state._zeros(n_real, ti.i32)
        self._cells = _CELLS(base=self.base, cell_kappa=self.kappa, carried=self.carried,
                             owner=self.owner, vs=self.vs, ws=self.ws, frozen=self.frozen)
        # the realizations apply_forces sets: all of them, or those it is given
        self._every = state.array(np.ones(n_real, dtype=np.int32), ti.i32)
        self._chosen = state._zeros(n_real, ti.i32)
        # the close pairs' resistance (fluid.pair_mobility, dem/pairs.py): the
        # broad phase's cells find the pairs, the species' damping scales it
        self.neighbors = neighbors
        self._xi = materials.xi
        self._pair_table = state.array(pair_mobility_table()) if model.pair_mobility else None
        # the implicit carried volume (fluid.flux_coupling = "implicit"): the
        # bodies' terms of the pressure solve, made on the first update
        self.implicit = bool(fl.particle_flux) and fl.flux_coupling == "implicit"
        self.terms = None
        self._drift = None      # their pack with past (_DRIFT)
        # per body at the last solve: x, y, theta, v_x, v_y, omega, in play (1/0)
        real = self.solver.real if self.on_device else ti.f64   # the solve's float type
        self.past = state._zeros((n_real, n_part, 7), real) if self.implicit else None
        self.interval = float(fl.update_interval) * float(model.dt)
        self.grid = (float(g.x_min), float(g.y_min), float(model.fluid_dx))
        # cells a side of the largest body's box of cells (rasterize_permeability)
        self._span = int(np.ceil(2.0 * max(s.shape.bounding_radius for s in model.species)
                                 / float(model.fluid_dx))) + 3
        self.gap = float(fl.gap)
        self.sampling = SAMPLING[fl.pressure_sampling]
        self._pressure = np.full(shape, np.nan)    # the last solve's, Pa (NaN: walls)
        self._pressure_device = None               # the same, on the device (gmg)
        self.last_info = None                      # its SolveInfo
        self._kappa_solved = None
        self._settled = np.zeros(n_real, dtype=bool)  # stopped, and solved since
        self._frozen_host = np.zeros(n_real, dtype=bool)  # frozen's values
        self.updates = 0
        self.solves = 0
        self.seconds = 0.0

    def apply_forces(self, bodies, batch, particles, templates, only=None, pairs=True):
        """Set every body's held fluid force and moment from the last pressure (and,
        with ``fluid.pair_mobility``, the close pairs' resistance); with
        ``only`` ((R,) bool), those of the realizations it flags alone, so that
        re-inserting a body in one realization leaves the others' forces as a run
        of theirs alone has them (batch equals alone); ``pairs=False`` leaves the
        pairs' resistance out."""
        b, t = bodies, templates
        which = self._every
        if only is not None:
            which = self._chosen
            which.from_numpy(np.asarray(only, dtype=np.int32))
        pressure_forces(b.pack_of(_HELD), batch.running, which, particles.species,
                        t.pack_of(_NODES), self.pres, self.active, *self.grid, self.gap,
                        self.sampling)
        if self._pair_table is not None and pairs:
            pair_mobility(b.pack_of(_PAIR_BODIES), batch.running, which,
                          particles.pack_of(_PAIR_PARTICLES), self._xi, self.neighbors.pack(),
                          self._pair_table)

    def forget_velocity(self, r: int, i: int):
        """Body ``i`` of realization ``r`` was re-inserted: it carries no flux yet."""
        self.v_src[r, i] = 0.0
        self.w_src[r, i] = 0.0
        if self.past is not None:       # no motion since the last solve to read
            self.past[r, i, 6] = 0.0

    def forget_motion(self):
        """The bodies were moved by hand (Simulation.set_state): no motion since
        the last solve to read."""
        if self.past is not None:
            self.past.fill(0)

    def device_arrays(self) -> dict:
        """The Taichi arrays whose content the next update or step reads, by name
        (what a checkpoint keeps of them)."""
        return {"kappa": self.kappa, "carried": self.carried, "pres": self.pres,
                "vs": self.vs, "ws": self.ws}

    def host_state(self) -> tuple[dict, dict]:
        """``(counters, arrays)``: what a checkpoint keeps of the coupling beside
        :meth:`device_arrays` and the solver's own state: the update, solve and
        solve-time counters, and the last pressure, the carried flux's source
        velocities, the implicit coupling's motion since the last solve (``past``)
        and the permeability of the last solve (``kappa_solved``, once solved)."""
        counters = {"updates": self.updates, "solves": self.solves, "seconds": self.seconds}
        arrays = {"pressure": self.pressure, "v_src": self.v_src, "w_src": self.w_src}
        if self.past is not None:
            arrays["past"] = self.past.to_numpy()
        if self._kappa_solved is not None:
            arrays["kappa_solved"] = self._kappa_solved
        return counters, arrays

    def restore_host_state(self, counters: dict, arrays: dict):
        """Continue from :meth:`host_state` (checked by the caller); ``kappa_solved``
        may be absent (no solve yet)."""
        self.pressure = arrays["pressure"]
        self.v_src = arrays["v_src"]
        self.w_src = arrays["w_src"]
        if self.past is not None:
            self.past.from_numpy(arrays["past"].astype(np.float64))
        self._kappa_solved = arrays.get("kappa_solved")
        self.updates, self.solves, self.seconds = (counters[k] for k in
                                                   ("updates", "solves", "seconds"))

    def _body_terms(self, bodies, batch, particles, templates, materials):
        """The bodies' terms of the implicit solve (fluid.gmg.BodyTerms) at the
        present poses and velocities, from their motion since the last solve."""
        b = bodies
        # the last pressure's force at the present poses, for bodies without a history
        # (the pairs' resistance, a correction of their drift, is left to the solve's)
        self.apply_forces(bodies, batch, particles, templates, pairs=False)
        R, N = self.v_src.shape[:2]
        if self.terms is None:
            real = self.solver.real
            self.terms = BodyTerms(self.owner, *(ti.ndarray(real, (R, N, c)) for c in (2, 3, 3)))
            consts = ti.ndarray(real, 5)
            consts.from_numpy(np.array([self.interval, self.gap, *self.grid],
                                       dtype=np.float64 if real == ti.f64 else np.float32))
            self._drift = _DRIFT(past=self.past, centre=self.terms.centre,
                                 mobility=self.terms.mobility, drift=self.terms.drift,
                                 drift_consts=consts)
        REAL.dtype = self.solver.real   # body_drift computes in the solve's float type
        body_drift(b.pack(), batch.running, particles.pack_of(_DRAG), materials.xi,
                   materials.carry, self._drift)
        return self.terms

    def _source_velocities(self, bodies):
        """Velocities of the carried flux: each particle's current velocity averaged
        half-and-half with the one used at the previous solve. The pressure lags the
        particles by a whole update interval while they relax to their drift within
        1/xi; with the raw velocity the lagged loop v -> 2u - v alternates, the
        half-and-half average lands an isolated particle on u in one solve. The
        cells carry the species' share of it."""
        v = bodies.v.to_numpy().astype(float)
        w = bodies.omega.to_numpy().astype(float)
        if self.solves == 0:
            self.v_src, self.w_src = v, w
        else:
            self.v_src = 0.5 * (self.v_src + v)
            self.w_src = 0.5 * (self.w_src + w)
        # the cells carry the species' share of it (docs/model.md section 3.4)
        m = self.model
        c = np.array([s.carried for s in m.species])[m.species_of_particle]
        self.vs.from_numpy((self.v_src * c[None, :, None]).astype(backend.numpy_real()))
        self.ws.from_numpy((self.w_src * c[None, :]).astype(backend.numpy_real()))

    def update(self, bodies, batch, particles, templates, materials, force: bool = False):
        """Re-rasterise the permeability and, unless it changed too little
        (``fluid.resolve_fraction``) and ``force`` is not set, re-solve the
        pressure; then refresh every body's held fluid force. Returns the
        :class:`~taichi_hsdem.fluid.SolveInfo` of a solve, or None."""
        m = self.model
        implicit = self.implicit
        flux = m.scene.fluid.particle_flux and not implicit   # the lagged carried flux
        if flux:
            self._source_velocities(bodies)
        only = None
        if self.on_device and self.skip_stopped and not flux:
            running = batch.running.to_numpy() != 0
            only = running | ~self._settled
            if (self._frozen_host != ~only).any():
                self._frozen_host = ~only
                self.frozen.from_numpy(self._frozen_host.astype(np.int32))
        b, t = bodies, templates
        rasterize_permeability(b.pack_of(_POSE), particles.species, particles.bounding_radius,
                               materials.kappa, t.pack_of(_LEVEL_SETS), self._cells,
                               *self.grid, self._span)
        self.updates += 1
        frac = m.scene.fluid.resolve_fraction
        # re-solve only when kappa changed enough: never with a carried flux, which
        # changes at every update
        skipping = frac > 0 and not m.scene.fluid.particle_flux
        kappa = None
        if flux or not self.on_device or skipping:
            kappa = self.kappa.to_numpy().astype(float)
        if not force and self._kappa_solved is not None and skipping:
            changed = (kappa != self._kappa_solved).sum(axis=(1, 2)) / m.fluid_active.sum()
            if changed.max() <= frac:
                self.apply_forces(bodies, batch, particles, templates)  # same pressure,
                return None                                            # moved bodies
        t0 = time.perf_counter()
        carried = occupied = None
        if flux:
            carried = self.carried.to_numpy().astype(float)
            # a free cell holds kappa_free in the kernels' precision (f32 rounds 0.12
            # down to 0.1199999973, below the float64 value: compare like with like)
            occupied = (kappa < float(backend.numpy_real()(m.kappa_free))) & m.fluid_active
        if self.on_device:
            terms = (self._body_terms(bodies, batch, particles, templates, materials)
                     if implicit else None)
            if only is not None:
                self._settled = ~running
            pres, info = self.solver.solve(self.kappa if kappa is None else kappa,
                                           carried=carried, occupied=occupied, host=False,
                                           bodies=terms, only=only)
            self._pressure_device, self._pressure = pres, None
            finite_or_zero(pres, self.pres, self.frozen)
        else:
            pres, info = self.solver.solve(kappa, carried=carried, occupied=occupied)
            self._pressure = pres
            self.pres.from_numpy(np.nan_to_num(pres, nan=0.0).astype(backend.numpy_real()))
        self.seconds += time.perf_counter() - t0
        self.solves += 1
        self._kappa_solved = kappa
        self.last_info = info
        self.apply_forces(bodies, batch, particles, templates)
        return info

    #: Leave a stopped realization out of the pressure solves once it has been
    #: solved since it stopped: nothing of it moves any more (the DEM skips it,
    #: its bodies are out of play), so its solve would take no iteration and
    #: leave its pressure as it is. False solves every realization every time
    #: (the same bits). Not with the lagged carried flux (fluid.flux_coupling =
    #: "lagged"): its source velocities, averaged with each update's, still change
    #: after the stop, and with them the system.
    skip_stopped = True

    @property
    def pressure(self) -> np.ndarray:
        """The last solve's pressure, (R, nx, ny), Pa, NaN in walls (a host copy)."""
        if self._pressure is None:
            self._pressure = self._pressure_device.to_numpy()
        return self._pressure

    @pressure.setter
    def pressure(self, value):
        self._pressure = np.asarray(value, dtype=float)
        self._pressure_device = None

    def summary(self) -> dict:
        """``summary.json``'s ``"fluid"`` entry."""
        return {"updates": self.updates, "solves": self.solves,
                "solve_seconds": self.seconds, "grid": list(self.model.fluid_shape),
                "cell_size": self.model.fluid_dx}
