"""A batch of realizations of one scene: set-up, the step loop, and its results.

The host orchestrates; kernels do the per-body work. Per DEM step
(:meth:`Simulation.advance`): the held fluid pressure forces, contact forces,
integration; on the per-step path the host reads one small flag array to know
whether the neighbour list needs a rebuild, while the fused stepper
(``fused.py``, disks) runs all the steps up to the next check in one launch and
rebuilds inside it. :meth:`Simulation.run` adds the rest: every ``check_every``
steps it reads the stability flags and hands the state to the observables
(:mod:`taichi_hsdem.observables`: escapes, clogs, throats, feeding), and samples
the time series; every ``fluid.update_interval`` steps it re-rasterises the
permeability and re-solves the pressure. The host's bookkeeping lives in one
:class:`~taichi_hsdem.runstate.RunState` (``Simulation.run_state``), which
:mod:`taichi_hsdem.checkpoint` saves and restores whole.

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
import warnings

import numpy as np

from . import backend, observables
from .dem import contact, coupling, fused, integrate, state
from .layout import BAD_FAST, BAD_NAN, BAD_PASSED, F_HISTORY_OVERFLOW, F_REBUILD
from .dem.neighbors import STALL_BUILDS, STALL_RUNNING, STALL_STEP, NeighborList
from .geometry.placement import PlacementError, place
from .geometry.throats import throats_of
from .observables import Result
from .resolve import Model, resolve
from .runstate import RealizationResult, RunState
from .scene import Scene, SceneError
from .stop import raise_if_swallowed

__all__ = ["Simulation", "Result", "RealizationResult", "RunError"]


class RunError(RuntimeError):
    """The run failed for a reason the user must act on (message says what)."""


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
    on_phase : callable or None
        ``on_phase(what)`` is called as each phase of the set-up begins, with what
        it does in a few words ("starting Taichi (cpu)", "placing the particles",
        ...): the set-up takes 10-30 s on a first run (Taichi compiles its kernels;
        later runs read them from Taichi's cache).

    Attributes
    ----------
    model : Model
        The resolved set-up (every ``auto`` decided); ``scene`` is ``model.scene``.
    bodies, batch, particles, materials, templates, walls, history
        The Taichi arrays (:mod:`taichi_hsdem.dem.state`).
    neighbors : NeighborList
    fluid : FluidCoupling or None
        The pressure solve and its arrays, None without fluid.
    run_state : RunState
        The host's bookkeeping (time, results so far, the observables' records,
        the series): what a checkpoint saves beside the arrays.
    throats : Throats
        The geometry's throats (:func:`~taichi_hsdem.geometry.throats.throats_of`).
    census : ArchCensus or None
        The arch census the checks take (:class:`~taichi_hsdem.observables.ArchCensus`;
        None for a geometry without two side walls).
    t, steps : float, int
        Simulated time and DEM steps so far (``run_state``'s).
    """

    def __init__(self, scene: Scene, place_particles: bool = True,
                 neighbor_capacities: tuple[int, int] = (8, 16), on_phase=None):
        phase = on_phase if on_phase is not None else (lambda what: None)
        phase(f"starting Taichi ({scene.run.arch})")
        self.arch = backend.init(scene.run.arch, scene.run.precision)
        phase("resolving the scene (shapes' level sets, walls, time step)")
        self.model: Model = resolve(scene, self.arch)
        m = self.model
        self.scene = m.scene
        R, N = self.scene.run.realizations, m.n_particles
        self.R, self.N = R, N
        self.dt = m.dt
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
        if self.fused:
            self.done = state.array(np.zeros(R, dtype=np.int32), state.ti.i32)
            self.builds = state.array(np.zeros(R, dtype=np.int32), state.ti.i32)
        #: Whether the per-step path rebuilds the neighbour lists on the device
        #: (NeighborList.rebuild_if_flagged, a GPU's way: no host read per step)
        #: or when the host has read the rebuild flag after a step (the CPU's).
        #: The same lists either way.
        self.device_rebuilds = backend.on_gpu()
        #: How often a device rebuild overflowed and the batch caught up (a count
        #: for the curious; it changes nothing).
        self.stalled_rebuilds = 0
        self._stall = state.array(np.zeros(STALL_RUNNING + R, dtype=np.int32), state.ti.i32)
        self._state_buffer = state.array(np.zeros((R, N, integrate.STATE_COLUMNS)))
        self.fluid = (coupling.FluidCoupling(m, R, N, self.neighbors, self.materials)
                      if self.scene.fluid.enabled else None)
        self._forces_every_step = (self.fluid is not None
                                   and self.scene.fluid.force_update == "step")
        S = len(m.species)
        self._species_onehot = np.eye(S, dtype=np.int64)[self.particles.species_np]
        phase("finding the throats")
        self.throats = throats_of(m.geometry)
        self.census = observables.ArchCensus.of(m)
        self.run_state = RunState.start([self.scene.run.seed + k for k in range(R)], N, S,
                                        len(self.throats))
        self.interrupted = False    # whether the last run() was stopped early
        if place_particles:
            phase("placing the particles")
            self._place_all(phase)

    @property
    def check_every(self) -> int:
        """DEM steps between host-side checks (``Model.check_every``)."""
        return self.model.check_every

    @property
    def t(self) -> float:
        """Simulated time so far, s (``run_state.t``)."""
        return self.run_state.t

    @property
    def steps(self) -> int:
        """DEM steps so far (``run_state.steps``)."""
        return self.run_state.steps

    @property
    def seeds(self) -> list:
        """Each realization's seed."""
        return self.run_state.seeds

    @property
    def results(self) -> list:
        """Each realization's :class:`RealizationResult` so far."""
        return self.run_state.results

    # ------------------------------------------------------------------ set-up
    def _place_all(self, phase=None):
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
                    self.run_state.rngs[r], m.geometry, shapes, m.species_of_particle[random],
                    m.feed_region, gap=0.0, existing=existing)
            except PlacementError as exc:
                raise SceneError([f"{self.scene.source}: particles: {exc}"]) from None
        if phase is not None:
            phase("compiling the contact and fluid kernels, first pressure solve"
                  if self.fluid is not None else "compiling the contact kernels")
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
        rs = self.run_state
        # bodies set dead here did not escape
        rs.unfed_by_species = self._dead_by_species(b.alive.to_numpy())
        rs.check_x = np.array(np.broadcast_to(x, (R, N, 2)), dtype=float)
        rs.check_alive = b.alive.to_numpy().astype(bool)
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
        a = integrate.read_state(self.bodies, self._state_buffer)
        return {"x": a[..., 0:2].astype(float), "theta": a[..., 2].astype(float),
                "v": a[..., 3:5].astype(float), "omega": a[..., 5].astype(float),
                "alive": a[..., 6] != 0, "species": self.particles.species_np.copy()}

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
        return observables.dead_by_species(alive, self._species_onehot)

    # ------------------------------------------------------------------ stepping
    def advance(self, n: int = 1):
        """Advance every running realization by ``n`` DEM steps with the fluid
        forces held from the last pressure solve (refreshed at each step only with
        ``fluid.force_update = "step"``): contacts and integration alone. No
        pressure solve, no escape counting, clog detection or feeding, no series
        rows: :meth:`run` takes those steps and adds them (:meth:`update_fluid`
        solves the pressure by hand)."""
        if self.fused:
            self._step_fused(n)
        else:
            self._step_per_body(n)
        rs = self.run_state
        for _ in range(n):
            rs.t += self.dt
        rs.steps += n

    def step(self, n: int = 1):
        """Deprecated: :meth:`advance` (DEM steps only; :meth:`run` takes the
        whole step: pressure, escapes, clogs, feeding)."""
        warnings.warn("Simulation.step(n) is renamed Simulation.advance(n): DEM steps with "
                      "the held fluid forces, no pressure solve, escape counting or "
                      "feeding (run() takes those steps)", DeprecationWarning, stacklevel=2)
        self.advance(n)

    def _step_fused(self, n: int):
        """``n`` steps in one launch; realizations whose neighbour rebuild overflowed
        stop early and catch up once the host has grown the capacities."""
        self._fused_launch(n)
        batch = self.batch
        done = self.done.to_numpy()      # -1: went bad or not running (fused.steps)
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
        self.run_state.launches += 1
        fused.run_steps(k, self.bodies, self.batch, self.particles, self.materials,
                        self.templates, self.walls, self.history, self.neighbors, self.flags,
                        self.done, self.builds, self.dt, m.x_escape, not m.all_disks,
                        self.scene.contact.normalize_by_nodes)

    def _step_per_body(self, n: int):
        """``n`` steps, three kernels each (four on a GPU). On the CPU the host
        reads the rebuild flag after each step (a read costs less than a launch
        there); on a GPU the lists are rebuilt on the device
        (``device_rebuilds``) and the host reads once per call, to catch up
        after a rebuild that overflowed."""
        while n > 0:
            n -= self._steps_per_body(n)

    def _steps_per_body(self, n: int) -> int:
        """Up to ``n`` steps of the per-step path; how many every realization
        took (fewer than ``n`` only where a device rebuild overflowed)."""
        m = self.model
        b = self.bodies
        normalize = self.scene.contact.normalize_by_nodes
        device = self.device_rebuilds
        for s in range(n):
            if self._forces_every_step:
                self.fluid.apply_forces(b, self.batch, self.particles, self.templates)
            coupling.load_forces(b.force, b.torque, b.f_fluid, b.tau_fluid)
            contact.add_forces(b, self.batch, self.particles, self.materials, self.templates,
                               self.walls, self.history, self.neighbors, self.flags, self.dt,
                               normalize, m.all_disks)
            self.history.swap()
            integrate.advance(b, self.batch, self.particles, self.materials, self.neighbors,
                              self.flags, self.dt, m.skin, m.x_escape)
            if device:
                self.neighbors.rebuild_if_flagged(b, self.batch, self.particles, self.flags,
                                                  self._stall, s)
            elif self.flags[F_REBUILD]:
                self.rebuild_neighbors()
        if not device:
            return n
        record = self._stall.to_numpy()          # the one read of these n steps
        self.neighbors.builds += int(record[STALL_BUILDS])
        if record[STALL_STEP] == 0:
            if record[STALL_BUILDS]:
                self._stall.from_numpy(np.zeros_like(record))
            return n
        # Step ``taken`` rebuilt lists that overflowed and every realization
        # stopped there: the steps after it did nothing but swap the shear
        # history's two buffers, so the latest is in the newer one when they
        # were odd in number; then the host grows the lists and rebuilds.
        taken = int(record[STALL_STEP])
        self.stalled_rebuilds += 1
        if (n - taken) % 2:
            self.history.swap()
        self.batch.running.from_numpy(record[STALL_RUNNING:].astype(np.int32))
        self._stall.from_numpy(np.zeros_like(record))
        self.rebuild_neighbors()
        return taken

    # ------------------------------------------------------------------ fluid
    def update_fluid(self, force: bool = False):
        """Re-rasterise the permeability and re-solve the pressure (unless
        ``fluid.resolve_fraction`` says it changed too little and ``force`` is not
        set); refresh the held fluid forces."""
        info = self.fluid.update(self.bodies, self.batch, self.particles, self.templates,
                                 self.materials, force=force)
        if info is None:
            return
        rs = self.run_state
        if rs.u_ref is None:
            # mean fluid speed through the constriction of the initial channel
            rs.u_ref = np.abs(info.flux_out) / self.model.geometry.constriction_width
        fl = self.scene.fluid
        pressure = self.fluid.pressure if fl.bc != "pressure" else None
        rs.flow += observables.flow_rows(fl, info.flux_out, pressure,
                                         self.batch.running.to_numpy(), rs.t)

    # ------------------------------------------------------------------ checks
    def _check(self, final: bool = False):
        """Host-side checks every ``check_every`` steps; returns True while anything runs.

        Stability here; escapes, clogs, throats, the arch census and feeding by
        the observables (:mod:`taichi_hsdem.observables`), into :attr:`run_state`.
        ``final``: the last steps of a run that ends between two checks: only the
        stability checks, reading without resetting, so that a later :meth:`run`
        (an extension, or a resumed checkpoint) sees what a run never stopped sees.
        """
        m = self.model
        sc = self.scene
        rs = self.run_state
        lost = int(self.flags[F_HISTORY_OVERFLOW])
        if lost:
            rs.history_overflows += lost
            self.flags[F_HISTORY_OVERFLOW] = 0
        batch = self.batch
        running, escaped, bad, overlap = integrate.read_status(batch, not final)
        # every check reads the state: the arch test runs at each one (t_clog)
        st = self.state() if running.any() and not final else None
        dead = None if st is None else self._dead_by_species(st["alive"])
        if dead is not None:
            observables.count_species(rs, dead)   # every realization, clogged or not
        checked = running.astype(bool)        # a copy: running changes below
        changed = False
        for r in range(self.R):
            if not running[r]:
                continue
            res = rs.results[r]
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
                if rs.e0 is None:
                    rs.e0 = np.array([self._kinetic_energy(st, k) for k in range(self.R)])
                tiny = 1e-12 * float(np.sum([s.mass * s.count for s in m.species])) * (m.d_min / self.dt) ** 2
                if ke > 1.1 * rs.e0[r] + tiny:
                    reason = (f"kinetic energy grew from {rs.e0[r]:.4g} to {ke:.4g} J "
                              f"without any driving force")
            if reason is not None:
                res.status = "unstable"
                res.reason = reason
                res.escapees = None
                res.clogged = None
                res.t_stop = rs.t
                running[r] = 0
                changed = True
                continue
            if len(self.throats) and not final:
                observables.observe_throats(rs, m, self.throats, st, r)
            if self.census is not None and not final:
                observables.census_arches(rs, self.census, st, r)
            if res.clogged or final:
                continue            # stop_at_clog = false: the stream goes on, the result is kept
            if observables.count_escapes(rs, m, r, escaped, dead, st,
                                         self.throats if self.throats.network else None):
                running[r] = 0      # clogged, and run.stop_at_clog
                changed = True
        if changed:
            batch.running.from_numpy(running.astype(np.int32))
        if st is not None:
            if sc.feed.mode == "count":
                self._feed(running, st)
            rs.unfed_by_species = self._dead_by_species(st["alive"])
            rs.check_x, rs.check_alive = st["x"], st["alive"]
            if self.throats.network:
                stable = np.array([res.status == "ok" for res in rs.results])
                observables.network_rows(rs, checked & stable, escaped, st["alive"])
        return bool(running.any())

    def kinetic_energy(self) -> np.ndarray:
        """Kinetic energy (translation and rotation) of the live bodies of each
        realization, (R,), J."""
        st = self.state()
        return np.array([self._kinetic_energy(st, r) for r in range(self.R)])

    def _kinetic_energy(self, st, r):
        return observables.kinetic_energy(self.model, self.particles.species_np, st, r)

    def _feed(self, running, st):
        """Re-insert escaped particles at the inlet (:func:`observables.feed`) and
        write what was fed to the device: poses, neighbour lists and, for the
        realizations fed alone, the fluid forces."""
        fed = observables.feed(self.model, self.run_state.rngs, self.particles.species_np,
                               running, st)
        if not fed:
            return
        b = self.bodies
        if self.fluid is not None:
            for r, i in fed:
                self.fluid.forget_velocity(r, i)
        npr = backend.numpy_real()
        b.x.from_numpy(st["x"].astype(npr))
        b.theta.from_numpy(st["theta"].astype(npr))
        b.v.from_numpy(st["v"].astype(npr))
        b.alive.from_numpy(st["alive"].astype(np.int32))
        self.rebuild_neighbors()
        if self.fluid is not None:
            # the re-inserted bodies feel the flow at once; the realizations not
            # fed keep their held forces, as they would run alone
            only = np.zeros(self.R, dtype=bool)
            only[[r for r, _ in fed]] = True
            self.fluid.apply_forces(b, self.batch, self.particles, self.templates, only=only)

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
        rs = self.run_state
        t_end = sc.run.t_end
        wall0 = time.perf_counter()
        series_dt = sc.output.series_interval
        frames = [t for t in (frame_times or ()) if t > rs.t - 0.5 * self.dt] \
            if rs.steps else list(frame_times or ())
        fluid_every = sc.fluid.update_interval if self.fluid is not None else None
        n_end = int(math.ceil(t_end / self.dt - 0.5))
        every = self.check_every
        self.interrupted = False
        if self.fluid is not None and rs.u_ref is None:
            self.update_fluid(force=True)
        while True:
            while frames and frames[0] <= rs.t + 0.5 * self.dt:
                frames.pop(0)
                if on_frame is not None:
                    on_frame(self)
            if rs.t >= rs.next_series - 0.5 * self.dt:
                run_np, esc, _, _ = integrate.read_status(self.batch, False)
                dead = (self._dead_by_species(self.bodies.alive.to_numpy())
                        if len(self.model.species) > 1 else None)
                observables.record_series(rs, run_np, esc, dead)
                rs.next_series += series_dt
            if not rs.any_running or rs.steps >= n_end:
                break
            if stop is not None and stop():
                self.interrupted = True
                break
            raise_if_swallowed()      # a signal's stop that a destructor swallowed
            n = min((rs.steps // every + 1) * every, n_end) - rs.steps
            if fluid_every is not None:
                n = min(n, fluid_every - rs.steps % fluid_every)
            if frames:
                n = min(n, max(1, int(math.ceil((frames[0] - rs.t) / self.dt - 0.5))))
            n = min(n, max(1, int(math.ceil((rs.next_series - rs.t) / self.dt - 0.5))))
            self.advance(max(n, 1))
            if fluid_every is not None and rs.steps % fluid_every == 0:
                self.update_fluid()
            if rs.steps % every == 0:
                rs.any_running = self._check()
                if progress is not None:
                    progress(rs.t, t_end)
            if on_chunk is not None:
                on_chunk(self)
        if rs.steps % every:
            rs.any_running = self._check(final=True)
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
        """The run's results so far (:func:`observables.run_result`): realizations
        still running are reported as stopped now, without changing them, so that a
        later :meth:`run` goes on."""
        st = self.state()
        builds = self.neighbors.builds + (int(self.builds.to_numpy().sum())
                                          if self.fused else 0)
        return observables.run_result(
            self.model, self.run_state, self.throats, self.batch.escaped.to_numpy(), st,
            self._dead_by_species(st["alive"]), arch=self.arch, wall=wall,
            interrupted=self.interrupted,
            fluid=None if self.fluid is None else self.fluid.summary(),
            neighbor_builds=builds, census=self.census)
