"""A batch of realizations of one scene: set-up, the step loop, and its results.

The host orchestrates; kernels do the per-body work. Per DEM step: fluid pressure
forces (or a clear), contact forces, integration; on the per-step path the host
reads one small flag array to know whether the neighbour list needs a rebuild,
while the fused stepper (``fused.py``, disks) runs all the steps up to the next
check in one launch and rebuilds inside it. Every
``check_every`` steps it reads escapes, stability flags and speeds, feeds the
inlet, looks for clogs and samples the time series; every
``fluid.update_interval`` steps it re-rasterises the permeability and re-solves
the pressure.

Examples
--------
>>> import taichi_hsdem as th
>>> sim = th.Simulation(th.load_scene("scenes/hourglass24.toml",
...                                   ["run.t_end=0.5"]))      # doctest: +SKIP
>>> result = sim.run()                                          # doctest: +SKIP
>>> result.summary["realizations"][0]["escapees"]               # doctest: +SKIP
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from . import backend, stats
from .dem import contact, coupling, fused, integrate, state
from .layout import BAD_FAST, BAD_NAN, BAD_PASSED, F_HISTORY_OVERFLOW, F_REBUILD
from .dem.neighbors import NeighborList
from .geometry.placement import PlacementError, find_free_spot, place
from .geometry.throats import observe, throat_rows, throats_of
from .resolve import Model, resolve
from .scene import Scene, SceneError
from .version import __version__


class RunError(RuntimeError):
    """The run failed for a reason the user must act on (message says what)."""


@dataclass
class RealizationResult:
    seed: int
    escapees: int | None = 0
    clogged: bool | None = False
    t_clog: float | None = None
    status: str = "ok"
    reason: str | None = None
    t_stop: float | None = None


@dataclass
class Result:
    """What a run produced, as Python objects (the CLI writes them to files)."""
    scene: Scene
    summary: dict
    series: list = field(default_factory=list)      # (realization, t, escapees)
    flow: list = field(default_factory=list)        # (realization, t, pressure drop, Q)
    # (realization, throat, x, y, width, passages, clogged, t_clog), with several throats
    throats: list = field(default_factory=list)
    final: dict = field(default_factory=dict)       # numpy arrays (R, N, ...)
    notes: dict = field(default_factory=dict)       # what every "auto" chose, and why

    @property
    def ok(self) -> bool:
        return all(r["status"] == "ok" for r in self.summary["realizations"])


class Simulation:
    """All realizations of one scene, run together in batched Taichi arrays.

    Parameters
    ----------
    scene : Scene
        A validated scene (:func:`taichi_hsdem.load_scene`).
    place_particles : bool
        Place particles at random (default). ``False`` leaves them parked for the
        caller to set with :meth:`set_state` (tests, scripted set-ups).
    neighbor_capacities : (int, int)
        Initial bodies per cell and neighbours per body of the neighbour lists
        (each doubles whenever a rebuild overflows it).

    Attributes
    ----------
    model : Model
        The resolved set-up (every ``auto`` decided); ``scene`` is ``model.scene``.
    bodies, batch, particles, materials, templates, walls, history
        The Taichi arrays (:mod:`taichi_hsdem.dem.state`).
    neighbors : NeighborList
    fluid : FluidCoupling or None
        The pressure solve and its arrays, None without fluid.
    t, steps : float, int
        Simulated time and DEM steps so far.
    """

    def __init__(self, scene: Scene, place_particles: bool = True,
                 neighbor_capacities: tuple[int, int] = (8, 16)):
        self.arch = backend.init(scene.run.arch, scene.run.precision)
        self.model: Model = resolve(scene, self.arch)
        m = self.model
        self.scene = m.scene
        R, N = self.scene.run.realizations, m.n_particles
        self.R, self.N = R, N
        self.dt = m.dt
        self.t = 0.0
        self.steps = 0
        self.seeds = [self.scene.run.seed + k for k in range(R)]
        self.rngs = [np.random.default_rng(s) for s in self.seeds]
        self.templates = state.Templates.of(m)
        self.particles = state.Particles.of(m)
        self.materials = state.Materials.of(m)
        self.walls = state.WallGrid.of(m)
        self.bodies = state.Bodies.zeros(R, N)
        self.batch = state.Batch.start(R)
        self.flags = state.flags()
        self.history = state.ShearHistory.of(m, self.templates, R, N)
        g = m.geometry
        margin = 2.0 * m.d_max
        self.neighbors = NeighborList(
            R, N, (g.x_min - margin, g.x_max + margin, g.y_min - margin, g.y_max + margin),
            max(s.shape.bounding_radius for s in m.species), m.skin, *neighbor_capacities)
        self.fused = m.stepping == "fused"
        self.launches = 0   # kernel launches of the fused stepper
        if self.fused:
            self.done = state.array(np.zeros(R, dtype=np.int32), state.ti.i32)
            self.builds = state.array(np.zeros(R, dtype=np.int32), state.ti.i32)
        self.fluid = coupling.FluidCoupling(m, R, N) if self.scene.fluid.enabled else None
        self._forces_every_step = (self.fluid is not None
                                   and self.scene.fluid.force_update == "step")
        self.results = [RealizationResult(seed=s) for s in self.seeds]
        self.last_escape_t = np.zeros(R)
        self.escaped_np = np.zeros(R, dtype=np.int64)
        # per realization: the first check since its latest escape that found the
        # arch static (_arch_static), NaN before one did: a clog's t_clog
        self.arch_static_t = np.full(R, np.nan)
        # escapees per realization and species counted at the checks, and the bodies
        # the latest check left dead (escaped, not re-inserted): a body dies only by
        # escaping and comes back only at a check, so the dead bodies beyond those
        # are the escapes since
        S = len(m.species)
        self._species_onehot = np.eye(S, dtype=np.int64)[self.particles.species_np]
        self.escaped_by_species = np.zeros((R, S), dtype=np.int64)
        self.unfed_by_species = np.zeros((R, S), dtype=np.int64)
        self.u_ref = None   # per realization: mean speed through the constriction, first solve
        self.e0 = None
        self.history_overflows = 0
        self.series: list = []          # (realization, t, escapees) rows so far
        self.flow: list = []            # (realization, t, pressure drop, flow rate) per solve
        self.next_series = 0.0          # time of the next row
        # Per throat (geometry/throats.py) and realization, from the checks:
        # passages (centres that crossed its segment between two checks), the time
        # of the latest one, the first check since then that found it blocked at
        # rest (NaN: none), and t_clog (NaN: open; a passage reopens a clog)
        self.throats = throats_of(m.geometry)
        T = len(self.throats)
        self.throat_passages = np.zeros((R, T), dtype=np.int64)
        self.throat_last_passage_t = np.zeros((R, T))
        self.throat_static_t = np.full((R, T), np.nan)
        self.throat_t_clog = np.full((R, T), np.nan)
        # the positions and alive flags the latest check (or set_state) left
        self.check_x = np.zeros((R, N, 2))
        self.check_alive = np.zeros((R, N), dtype=bool)
        self.any_running = True
        self.interrupted = False
        if place_particles:
            self._place_all()

    @property
    def check_every(self) -> int:
        """DEM steps between host-side checks (``Model.check_every``)."""
        return self.model.check_every

    # ------------------------------------------------------------------ set-up
    def _place_all(self):
        m = self.model
        shapes = [s.shape for s in m.species]
        xs = np.zeros((self.R, self.N, 2))
        ths = np.zeros((self.R, self.N))
        given = (np.zeros(self.N, dtype=bool) if m.initial_poses is None
                 else np.isfinite(m.initial_poses[:, 0]))
        existing = None
        if given.any():  # the same in every realization; the others avoid them
            xs[:, given] = m.initial_poses[given, :2]
            ths[:, given] = m.initial_poses[given, 2]
            existing = (m.initial_poses[given, :2], m.initial_poses[given, 2],
                        [shapes[k] for k in m.species_of_particle[given]])
        random = np.flatnonzero(~given)
        for r in range(self.R if random.size else 0):
            try:
                xs[r, random], ths[r, random] = place(
                    self.rngs[r], m.geometry, shapes, m.species_of_particle[random],
                    m.feed_region, gap=0.0, existing=existing)
            except PlacementError as exc:
                raise SceneError([f"{self.scene.source}: particles: {exc}"]) from None
        self.set_state(xs, ths)

    def _to_device(self, array, value, shape, dtype=None):
        """Fill Taichi ``array`` with ``value`` broadcast to ``shape``."""
        dtype = backend.numpy_real() if dtype is None else dtype
        array.from_numpy(np.ascontiguousarray(np.broadcast_to(
            np.asarray(value, dtype=float if dtype is not np.int32 else np.int32), shape),
            dtype=dtype))

    def set_state(self, x, theta=None, v=None, omega=None, alive=None):
        """Set positions (R, N, 2) [and angles, velocities, alive flags]; resets contacts."""
        R, N = self.R, self.N
        b = self.bodies
        self._to_device(b.x, x, (R, N, 2))
        self._to_device(b.theta, 0.0 if theta is None else theta, (R, N))
        self._to_device(b.omega, 0.0 if omega is None else omega, (R, N))
        self._to_device(b.v, 0.0 if v is None else v, (R, N, 2))
        self._to_device(b.alive, 1 if alive is None else alive, (R, N), np.int32)
        # bodies set dead here did not escape
        self.unfed_by_species = self._dead_by_species(b.alive.to_numpy())
        self.check_x = np.array(np.broadcast_to(x, (R, N, 2)), dtype=float)
        self.check_alive = b.alive.to_numpy().astype(bool)
        self.history.clear()
        self.rebuild_neighbors()
        if self.fluid is not None:
            self.fluid.forget_motion()
            self.update_fluid(force=True)

    def set_external_load(self, force=None, moment=None):
        """Constant external force (R, N, 2) and moment (R, N) on every body, e.g. gravity."""
        R, N = self.R, self.N
        self._to_device(self.bodies.f_ext, 0.0 if force is None else force, (R, N, 2))
        self._to_device(self.bodies.tau_ext, 0.0 if moment is None else moment, (R, N))

    def rebuild_neighbors(self):
        """Rebuild the neighbour lists now (growing their capacities as needed)."""
        self.neighbors.build(self.bodies, self.batch, self.particles, self.flags)

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        """Current state as numpy arrays (R, N, ...)."""
        b = self.bodies
        return {"x": b.x.to_numpy().astype(float), "theta": b.theta.to_numpy().astype(float),
                "v": b.v.to_numpy().astype(float), "omega": b.omega.to_numpy().astype(float),
                "alive": b.alive.to_numpy().astype(bool),
                "species": self.particles.species_np.copy()}

    def forces(self) -> tuple[np.ndarray, np.ndarray]:
        """Force and moment of the last step on every body (R, N, 2), (R, N)."""
        return (self.bodies.force.to_numpy().astype(float),
                self.bodies.torque.to_numpy().astype(float))

    def fluid_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """The held pressure force and moment on every body (R, N, 2), (R, N)."""
        return (self.bodies.f_fluid.to_numpy().astype(float),
                self.bodies.tau_fluid.to_numpy().astype(float))

    def pressure(self) -> np.ndarray | None:
        """The last pressure solve, (R, nx, ny), Pa, NaN in walls; None without fluid."""
        return None if self.fluid is None else self.fluid.pressure

    def running(self) -> np.ndarray:
        """Which realizations are still running, (R,) bool."""
        return self.batch.running.to_numpy().astype(bool)

    def escaped(self) -> np.ndarray:
        """Bodies past the escape line so far, per realization (R,)."""
        return self.batch.escaped.to_numpy().astype(np.int64)

    def _dead_by_species(self, alive) -> np.ndarray:
        """Bodies not alive in ``alive`` (R, N), per realization and species (R, S)."""
        return (np.asarray(alive) == 0).astype(np.int64) @ self._species_onehot

    # ------------------------------------------------------------------ stepping
    def step(self, n: int = 1):
        """Advance every running realization by ``n`` DEM steps (no host checks)."""
        if self.fused:
            self._step_fused(n)
        else:
            self._step_per_body(n)
        for _ in range(n):
            self.t += self.dt
        self.steps += n

    def _step_fused(self, n: int):
        """``n`` steps in one launch; realizations whose neighbour rebuild overflowed
        stop early and catch up once the host has grown the capacities."""
        self._fused_launch(n)
        batch = self.batch
        done = self.done.to_numpy()      # -1: went bad or not running (fused.disk_steps)
        remaining = np.where(done >= 0, n - done, 0)
        if remaining.any():
            running = batch.running.to_numpy()
        while remaining.any():
            self.rebuild_neighbors()                  # grows what overflowed
            lag = remaining > 0
            k = int(remaining[lag].min())
            batch.running.from_numpy(np.where(lag, running, 0).astype(np.int32))
            try:
                self._fused_launch(k)
            finally:
                batch.running.from_numpy(running)
            done = self.done.to_numpy()
            remaining = np.where(lag & (done >= 0), remaining - done, 0)

    def _fused_launch(self, k: int):
        m = self.model
        self.launches += 1
        fused.run_steps(k, self.bodies, self.batch, self.particles, self.materials,
                        self.walls, self.history, self.neighbors, self.flags, self.done,
                        self.builds, self.dt, m.x_escape)

    def _step_per_body(self, n: int):
        m = self.model
        b = self.bodies
        normalize = self.scene.contact.normalize_by_nodes
        for _ in range(n):
            if self._forces_every_step:
                self.fluid.apply_forces(b, self.batch, self.particles, self.templates)
            coupling.load_forces(b.force, b.torque, b.f_fluid, b.tau_fluid)
            contact.add_forces(b, self.batch, self.particles, self.materials, self.templates,
                               self.walls, self.history, self.neighbors, self.flags, self.dt,
                               normalize, m.all_disks)
            self.history.swap()
            integrate.advance(b, self.batch, self.particles, self.materials, self.neighbors,
                              self.flags, self.dt, m.skin, m.x_escape)
            if self.flags[F_REBUILD]:
                self.rebuild_neighbors()

    # ------------------------------------------------------------------ fluid
    def update_fluid(self, force: bool = False):
        """Re-rasterise the permeability and re-solve the pressure (unless
        ``fluid.resolve_fraction`` says it changed too little and ``force`` is not
        set); refresh the held fluid forces."""
        info = self.fluid.update(self.bodies, self.batch, self.particles, self.templates,
                                 self.materials, force=force)
        if info is None:
            return
        if self.u_ref is None:
            # mean fluid speed through the constriction of the initial channel
            self.u_ref = np.abs(info.flux_out) / self.model.geometry.constriction_width
        self._record_flow(info)

    def _record_flow(self, info):
        """A ``flow`` row per running realization at each pressure solve: the
        pressure drop across the domain and the flow rate leaving it (m^3/s: the
        outflow per unit depth times the gap). Under a pressure inlet the drop is
        the imposed ``p_in - p_out``; under a flow-rate inlet it is what a syringe
        pump's sensor reads: the mean pressure on the inlet, extrapolated from the
        first two cell columns to the boundary (exact for a linear pressure), less
        ``p_out``."""
        fl = self.scene.fluid
        q = np.asarray(info.flux_out, dtype=float) * fl.gap
        if fl.bc == "pressure":
            drop = np.full(self.R, fl.p_in - fl.p_out)
        else:
            p = self.fluid.pressure
            edge = 1.5 * p[:, 0, :] - 0.5 * p[:, 1, :]      # NaN where either is wall
            drop = np.array([np.mean(e[np.isfinite(e)]) if np.isfinite(e).any() else np.nan
                             for e in edge]) - fl.p_out
        running = self.batch.running.to_numpy()
        self.flow += [(r, self.t, float(drop[r]), float(q[r]))
                      for r in range(self.R) if running[r]]

    # ------------------------------------------------------------------ checks
    def _check(self, final: bool = False):
        """Host-side checks every ``check_every`` steps; returns True while anything runs.

        ``final``: the last steps of a run that ends between two checks: only the
        stability checks, reading without resetting, so that a later :meth:`run`
        (an extension, or a resumed checkpoint) sees what a run never stopped sees.
        """
        m = self.model
        sc = self.scene
        lost = int(self.flags[F_HISTORY_OVERFLOW])
        if lost:
            self.history_overflows += lost
            self.flags[F_HISTORY_OVERFLOW] = 0
        batch = self.batch
        running, escaped, bad, overlap = integrate.read_status(batch, not final)
        # every check reads the state: the arch test runs at each one (t_clog)
        st = self.state() if running.any() and not final else None
        dead = None if st is None else self._dead_by_species(st["alive"])
        changed = False
        for r in range(self.R):
            if not running[r]:
                continue
            res = self.results[r]
            reason = None
            if bad[r] & BAD_NAN:
                reason = "non-finite position or velocity"
            elif bad[r] & BAD_FAST:
                reason = "a particle moved more than a quarter of its size in one step"
            elif bad[r] & BAD_PASSED:
                reason = ("a particle's deepest point ended up inside another: it passed "
                          "through between surface nodes; raise the particles' nodes (or "
                          "use \"auto\") or lower run.dt")
            elif overlap[r] > sc.contact.overlap_limit:
                reason = (f"overlap reached {overlap[r]:.3g} of a particle diameter "
                          f"(limit contact.overlap_limit = {sc.contact.overlap_limit:g})")
            if reason is None and not sc.fluid.enabled and not final:
                ke = self._kinetic_energy(st, r)
                if self.e0 is None:
                    self.e0 = np.array([self._kinetic_energy(st, k) for k in range(self.R)])
                tiny = 1e-12 * float(np.sum([s.mass * s.count for s in m.species])) * (m.d_min / self.dt) ** 2
                if ke > 1.1 * self.e0[r] + tiny:
                    reason = (f"kinetic energy grew from {self.e0[r]:.4g} to {ke:.4g} J "
                              f"without any driving force")
            if reason is not None:
                res.status = "unstable"
                res.reason = reason
                res.escapees = None
                res.clogged = None
                res.t_stop = self.t
                running[r] = 0
                changed = True
                continue
            if len(self.throats) and not final:
                self._check_throats(st, r)
            if res.clogged or final:
                continue            # stop_at_clog = false: the stream goes on, the result is kept
            went = escaped[r] > self.escaped_np[r]
            if went:
                self.escaped_np[r] = escaped[r]
                self.last_escape_t[r] = self.t
                self.arch_static_t[r] = np.nan     # an arch that holds forms after this
            static = not went and self._arch_static(st, r)
            if static and np.isnan(self.arch_static_t[r]):
                self.arch_static_t[r] = self.t
            res.escapees = int(escaped[r])
            self.escaped_by_species[r] += dead[r] - self.unfed_by_species[r]
            # a clog: no escape for clog.window and the arch static now. It formed
            # when the checks first found it static after the last escape (the speed
            # at the neck flickers about the threshold once it holds, so the latest
            # static stretch would start late)
            if static and self.t - self.last_escape_t[r] >= sc.clog.window:
                res.clogged = True
                res.t_clog = float(self.arch_static_t[r])
                if sc.run.stop_at_clog:
                    res.t_stop = self.t
                    running[r] = 0
                    changed = True
        if changed:
            batch.running.from_numpy(running.astype(np.int32))
        if st is not None:
            if sc.feed.mode == "count":
                self._feed(running, st)
            self.unfed_by_species = self._dead_by_species(st["alive"])
            self.check_x, self.check_alive = st["x"], st["alive"]
        return bool(running.any())

    def kinetic_energy(self) -> np.ndarray:
        """Kinetic energy (translation and rotation) of the live bodies of each
        realization, (R,), J."""
        st = self.state()
        return np.array([self._kinetic_energy(st, r) for r in range(self.R)])

    def _kinetic_energy(self, st, r):
        m = self.model
        spp = self.particles.species_np
        mass = np.array([m.species[k].mass for k in spp])
        inertia = np.array([m.species[k].inertia for k in spp])
        a = st["alive"][r]
        return float(0.5 * np.sum(mass[a] * np.sum(st["v"][r][a] ** 2, axis=1))
                     + 0.5 * np.sum(inertia[a] * st["omega"][r][a] ** 2))

    def _arch_static(self, st, r) -> bool:
        """Particles sit at the constriction and none of them moves."""
        m = self.model
        g = m.geometry
        a = st["alive"][r]
        xs = st["x"][r]
        near = a & (xs[:, 0] > g.constriction_x0 - m.d_max) & (xs[:, 0] < g.constriction_x1 + m.d_max)
        if not near.any():
            return False
        return np.linalg.norm(st["v"][r][near], axis=1).max() < self._rest_speed(r)

    def _rest_speed(self, r) -> float:
        """Below this speed a particle at a constriction is at rest (docs/scene.md,
        [clog]): clog.speed_fraction of the mean fluid speed there, or without
        fluid of d / clog.window."""
        ref = (self.u_ref[r] if self.u_ref is not None
               else self.model.d_min / self.scene.clog.window)
        return self.scene.clog.speed_fraction * ref

    def _check_throats(self, st, r):
        """Passages and clogs of every throat of realization ``r`` at a check
        (:func:`~taichi_hsdem.geometry.throats.observe`): a throat blocked at rest
        with nothing through it for clog.window has clogged, since it was first
        found so after its latest passage."""
        passed, static = observe(self.throats, self.check_x[r], self.check_alive[r],
                                 st["x"][r], st["v"][r], st["alive"][r],
                                 self._rest_speed(r), self.model.d_max)
        went = passed > 0
        self.throat_passages[r] += passed
        self.throat_last_passage_t[r, went] = self.t
        self.throat_static_t[r, went] = np.nan
        self.throat_t_clog[r, went] = np.nan
        first = static & np.isnan(self.throat_static_t[r])
        self.throat_static_t[r, first] = self.t
        clog = (static & np.isnan(self.throat_t_clog[r])
                & (self.t - self.throat_last_passage_t[r] >= self.scene.clog.window))
        self.throat_t_clog[r, clog] = self.throat_static_t[r, clog]

    def _feed(self, running, st):
        """Re-insert escaped particles at the inlet (feed.mode = "count") of the
        realizations ``running``, given the check's state ``st`` (:meth:`state`),
        which is updated to what was fed."""
        m = self.model
        b = self.bodies
        spp = self.particles.species_np
        alive = st["alive"]
        if alive.all():
            return
        xs, ths, vs = st["x"], st["theta"], st["v"]
        shapes = [s.shape for s in m.species]
        fed = np.zeros(self.R, dtype=bool)
        for r in range(self.R):
            if not running[r]:
                continue
            for i in np.flatnonzero(alive[r] == 0):
                others = np.flatnonzero(alive[r])
                spot = find_free_spot(self.rngs[r], m.geometry, shapes[spp[i]], m.feed_inlet,
                                      xs[r, others], ths[r, others],
                                      [shapes[spp[j]] for j in others])
                if spot is None:
                    break
                xs[r, i], ths[r, i] = spot
                vs[r, i] = 0.0
                if self.fluid is not None:
                    self.fluid.forget_velocity(r, i)
                alive[r, i] = True
                fed[r] = True
        if fed.any():
            npr = backend.numpy_real()
            b.x.from_numpy(xs.astype(npr))
            b.theta.from_numpy(ths.astype(npr))
            b.v.from_numpy(vs.astype(npr))
            b.alive.from_numpy(alive.astype(np.int32))
            self.rebuild_neighbors()
            if self.fluid is not None:
                # the re-inserted bodies feel the flow at once; the realizations not
                # fed keep their held forces, as they would run alone
                self.fluid.apply_forces(b, self.batch, self.particles, self.templates,
                                        only=fed)

    # ------------------------------------------------------------------ run
    def run(self, progress=None, on_frame=None, frame_times=None, stop=None,
            on_chunk=None) -> Result:
        """Run to ``run.t_end`` or until every realization stopped.

        ``progress(t, t_end)`` is called after every check; ``on_frame(sim)`` at each
        time of ``frame_times`` (the first at t = 0, before any step) not yet
        passed; ``stop()``, when given, is asked between chunks of steps and ends
        the run early when it returns True (the realizations still running are
        then ``"interrupted"``); ``on_chunk(sim)`` is called after every chunk (a
        checkpoint hook). Calling ``run`` again after a later ``run.t_end`` was set
        (:meth:`extend`) goes on from where the last call stopped.

        Host checks (escapes, clogs, feeding, stability) run every
        ``check_every`` steps counted from step 0 and the pressure every
        ``fluid.update_interval`` steps: neither depends on the frames, the series
        rows, ``t_end`` or where a run was stopped and resumed, so a run resumed
        from a checkpoint, or extended to a later ``t_end``, gives the bits of one
        never stopped.
        """
        sc = self.scene
        t_end = sc.run.t_end
        wall0 = time.perf_counter()
        series_dt = sc.output.series_interval
        frames = [t for t in (frame_times or ()) if t > self.t - 0.5 * self.dt] \
            if self.steps else list(frame_times or ())
        fluid_every = sc.fluid.update_interval if self.fluid is not None else None
        n_end = int(math.ceil(t_end / self.dt - 0.5))
        every = self.check_every
        self.interrupted = False
        if self.fluid is not None and self.u_ref is None:
            self.update_fluid(force=True)
        while True:
            while frames and frames[0] <= self.t + 0.5 * self.dt:
                frames.pop(0)
                if on_frame is not None:
                    on_frame(self)
            if self.t >= self.next_series - 0.5 * self.dt:
                run_np, esc, _, _ = integrate.read_status(self.batch, False)
                for r in range(self.R):
                    if run_np[r]:
                        self.series.append((r, self.t, int(esc[r])))
                self.next_series += series_dt
            if not self.any_running or self.steps >= n_end:
                break
            if stop is not None and stop():
                self.interrupted = True
                break
            n = min((self.steps // every + 1) * every, n_end) - self.steps
            if fluid_every is not None:
                n = min(n, fluid_every - self.steps % fluid_every)
            if frames:
                n = min(n, max(1, int(math.ceil((frames[0] - self.t) / self.dt - 0.5))))
            n = min(n, max(1, int(math.ceil((self.next_series - self.t) / self.dt - 0.5))))
            self.step(max(n, 1))
            if fluid_every is not None and self.steps % fluid_every == 0:
                self.update_fluid()
            if self.steps % every == 0:
                self.any_running = self._check()
                if progress is not None:
                    progress(self.t, t_end)
            if on_chunk is not None:
                on_chunk(self)
        if self.steps % every:
            self.any_running = self._check(final=True)
        if not self.interrupted:
            while frames and on_frame is not None:
                frames.pop(0)
                on_frame(self)
        return self._result(time.perf_counter() - wall0)

    def extend(self, t_end: float):
        """Set a later ``run.t_end`` (checked like the scene's), so that the next
        :meth:`run` goes on to it."""
        self.scene = self.scene.with_values({"run.t_end": float(t_end)})
        self.model.scene = self.scene

    def _result(self, wall) -> Result:
        """The run's results so far. Realizations still running are reported as
        stopped now (``t_stop``; ``"interrupted"`` when :meth:`run` was stopped
        early), without changing them, so that a later :meth:`run` goes on."""
        sc = self.scene
        esc = self.batch.escaped.to_numpy()
        st = self.state()
        dead = self._dead_by_species(st["alive"])
        series = list(self.series)
        last_t = {r: t for r, t, _ in series}
        real = []
        for r, res in enumerate(self.results):
            by_species = self.escaped_by_species[r]
            t_last = float(self.last_escape_t[r])
            if res.status == "ok" and not res.clogged:   # counted up to now
                by_species = by_species + dead[r] - self.unfed_by_species[r]
                if esc[r] > self.escaped_np[r]:
                    t_last = self.t
            row = {"seed": res.seed, "escapees": res.escapees, "clogged": res.clogged,
                   "t_clog": res.t_clog, "status": res.status, "reason": res.reason,
                   "t_stop": res.t_stop,
                   "escapees_by_species": (None if res.status == "unstable"
                                           else [int(v) for v in by_species]),
                   # the check that saw the last escape counted (None: none)
                   "t_last_escape": (None if res.status == "unstable"
                                     or not by_species.any() else t_last)}
            if res.status == "ok" and res.t_stop is None:
                row["t_stop"] = self.t
                if not res.clogged:
                    row["escapees"] = int(esc[r])
                if self.interrupted:
                    row["status"] = "interrupted"
                if last_t.get(r) != self.t:
                    series.append((r, self.t, int(esc[r])))
            real.append(row)
        counted = [r for r in real if r["status"] in ("ok", "interrupted")]
        n_unstable = sum(1 for r in real if r["status"] == "unstable")
        statistics = (stats.summarize([r["escapees"] for r in counted],
                                      [bool(r["clogged"]) for r in counted],
                                      n_unstable=n_unstable) if counted else None)
        summary = {
            "scene": sc.source, "version": __version__, "arch": self.arch,
            "status": "interrupted" if self.interrupted else "complete",
            "dt": self.dt, "steps": self.steps, "t_end": sc.run.t_end, "t_reached": self.t,
            "wall_time_s": wall,
            "species": [s.name for s in self.model.species],  # escapees_by_species' order
            "realizations": real,
            # the censoring-aware estimate of <s> (stats.summarize), not the plain mean
            "mean_escapees": None if statistics is None else statistics["mean_escapees"],
            "mean_escapees_ci": None if statistics is None else statistics["mean_escapees_ci"],
            "never_clogged": None if statistics is None else statistics["n_never_clogged"],
            "statistics": statistics,
            "fluid": None if self.fluid is None else self.fluid.summary(),
            "neighbor_builds": self.neighbors.builds + (int(self.builds.to_numpy().sum())
                                                        if self.fused else 0),
            "history_overflows": self.history_overflows,
            "contact_path": "disk" if self.model.all_disks else "level-set",
            "auto": dict(self.model.notes),
            "final_state": [
                {"x": st["x"][r].tolist(), "theta": st["theta"][r].tolist(),
                 "alive": st["alive"][r].tolist(), "species": st["species"].tolist()}
                for r in range(self.R)],
        }
        return Result(scene=sc, summary=summary, series=series, flow=list(self.flow),
                      throats=throat_rows(self.throats, self.throat_passages,
                                          self.throat_t_clog), final=st, notes=dict(self.model.notes))
