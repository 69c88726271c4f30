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

from . import backend
from .geometry import shapes as shp
from . import stats
from .dem.contact import BAD_PASSED
from .dem.integrate import BAD_FAST, BAD_NAN
from .geometry.placement import PlacementError, find_free_spot, place
from .resolve import Model, pair_table, resolve, wall_table
from .scene import Scene, SceneError

CHECK_INTERVAL = 100          # steps between host-side checks, at least
CHECK_TRAVEL = 0.05           # with fluid: d_min a particle at the constriction's mean
                              # speed may move between checks (sets a longer interval)
LS_HISTORY_SLOTS = 3          # contacts one surface node can remember at once
DISK_HISTORY_SLOTS = 8        # contacts one disk can remember at once
SKIN_FRACTION = 0.25          # Verlet skin as a fraction of the smallest d_eq
UPDATE_CELL_FRACTION = 1.0    # fluid cells a particle may cross between auto-interval solves:
                              # the knee of `tools/convergence.py interval` (vani scene, 100
                              # realizations per point: 0.5 and 1 cell agree, 2 and 3 cells
                              # give fewer escapees; README, Accuracy)
MAX_TRAVEL_BETWEEN_SOLVES = 0.5  # diameters a particle may move between solves, at most


def _grid_gradient(phi: np.ndarray, h: float) -> np.ndarray:
    """Central-difference gradient of an x-first grid, flattened to (nx*ny, 2)."""
    gx, gy = np.gradient(phi, h)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


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
    final: dict = field(default_factory=dict)       # numpy arrays (R, N, ...)

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
    """

    def __init__(self, scene: Scene, place_particles: bool = True):
        self.model: Model = resolve(scene)
        self.scene = self.model.scene
        m = self.model
        run = self.scene.run
        self.arch = backend.init(run.arch, run.precision)
        import taichi as ti
        from .dem import coupling, contact, neighbors
        self._ti = ti
        real = backend.real()
        npr = backend.numpy_real()
        self._npr = npr
        R, N = run.realizations, m.n_particles
        self.R, self.N = R, N
        self.dt = m.dt
        self.t = 0.0
        self.steps = 0
        self.seeds = [run.seed + k for k in range(R)]
        self.rngs = [np.random.default_rng(s) for s in self.seeds]

        def arr(data, dtype=real):
            data = np.ascontiguousarray(data)
            a = ti.ndarray(dtype, shape=data.shape)
            a.from_numpy(data.astype(npr if dtype is real else np.int32))
            return a

        def vec(shape):
            return ti.Vector.ndarray(2, real, shape=shape)

        # Templates: level-set grids only for non-disks when any non-disk exists.
        sp_list = m.species
        spacings = [None if m.all_disks else s.ls_spacing for s in sp_list]
        stk = shp.stack([s.shape for s in sp_list], spacings)
        self._stack = stk
        ls_phi = stk["ls_phi"] if stk["ls_phi"].size else np.zeros(1)
        self.ls_phi = arr(ls_phi)
        ls_grad = np.zeros((ls_phi.size, 2))
        for off, (nx, ny), h in zip(stk["ls_offset"], stk["ls_shape"], stk["ls_spacing"]):
            if nx:
                ls_grad[off:off + nx * ny] = _grid_gradient(ls_phi[off:off + nx * ny].reshape(nx, ny), h)
        self.ls_grad = arr(ls_grad)
        self.ls_meta = arr(np.column_stack([stk["ls_offset"], stk["ls_shape"]]), ti.i32)
        self.ls_geo = arr(np.column_stack([stk["ls_origin"], stk["ls_spacing"]]))
        self.node_pos = arr(stk["node_pos"])
        areas = [coupling.boundary_vectors(s.shape.nodes) for s in sp_list]
        self.node_area = arr(np.concatenate(areas))
        self.node_meta = arr(np.column_stack([stk["node_offset"], stk["node_count"]]), ti.i32)
        self.is_circle = arr(stk["is_circle"], ti.i32)
        self.trad = arr(stk["radius"])
        # Per particle (same in every realization) and per species.
        spp = m.species_of_particle
        self.sp_np = spp
        self.sp = arr(spp, ti.i32)
        self.tm = self.sp  # one template per species
        self.mass = arr(np.array([sp_list[k].mass for k in spp]))
        self.inertia = arr(np.array([sp_list[k].inertia for k in spp]))
        self.deq = arr(np.array([sp_list[k].d_eq for k in spp]))
        self.rb = arr(np.array([sp_list[k].shape.bounding_radius for k in spp]))
        self.rad = arr(np.array([sp_list[k].shape.radius for k in spp]))
        self.pair = arr(pair_table(sp_list))
        self.wallp = arr(wall_table(sp_list))
        self.xi = arr(np.array([s.xi for s in sp_list]))
        self.kp = arr(np.array([s.kappa for s in sp_list]))
        wf = m.wall_field
        self.wall = arr(wf.phi.ravel())
        self.wall_grad = arr(_grid_gradient(wf.phi, wf.spacing))
        self.wall_meta = arr(np.array(wf.phi.shape), ti.i32)
        self.prm = arr(np.array([m.dt, 1.0 if self.scene.contact.normalize_by_nodes else 0.0,
                                 wf.origin[0], wf.origin[1], wf.spacing]))
        self.skin = SKIN_FRACTION * m.d_min
        self.iprm = arr(np.array([m.dt, self.skin, m.x_escape]))
        # State.
        self.x = vec((R, N))
        self.th = ti.ndarray(real, shape=(R, N))
        self.v = vec((R, N))
        self.w = ti.ndarray(real, shape=(R, N))
        self.f = vec((R, N))
        self.tau = ti.ndarray(real, shape=(R, N))
        self.f_ext = vec((R, N))
        self.f_fluid = vec((R, N))               # pressure force, held between evaluations
        self.tau_fluid = ti.ndarray(real, shape=(R, N))
        self.tau_ext = ti.ndarray(real, shape=(R, N))
        self.alive = ti.ndarray(ti.i32, shape=(R, N))
        self.running = arr(np.ones(R, dtype=np.int32), ti.i32)
        self.escaped = ti.ndarray(ti.i32, shape=R)
        self.bad = ti.ndarray(ti.i32, shape=R)
        self.max_overlap = ti.ndarray(real, shape=R)
        self.flags = ti.ndarray(ti.i32, shape=neighbors.N_FLAGS)
        for a in (self.th, self.w, self.tau, self.tau_ext, self.tau_fluid, self.max_overlap):
            a.fill(0)
        for a in (self.x, self.v, self.f, self.f_ext, self.f_fluid):
            a.fill(0)
        for a in (self.alive, self.escaped, self.bad, self.flags):
            a.fill(0)
        self.slots = DISK_HISTORY_SLOTS if m.all_disks else LS_HISTORY_SLOTS
        kn = 1 if m.all_disks else int(stk["node_count"].max())
        hshape = (R, N, kn, self.slots)
        self.hist = []
        for _ in range(2):
            hp = ti.ndarray(ti.i32, shape=hshape)
            hs = ti.Vector.ndarray(2, real, shape=hshape)
            hp.fill(0)
            hs.fill(0)
            self.hist.append((hp, hs))
        g = m.geometry
        margin = 2.0 * m.d_max
        self.nlist = neighbors.NeighborList(
            R, N, (g.x_min - margin, g.x_max + margin, g.y_min - margin, g.y_max + margin),
            max(s.shape.bounding_radius for s in sp_list), self.skin, real)
        # Fluid.
        self.fluid = None
        self._forces_every_step = (self.scene.fluid.enabled
                                   and self.scene.fluid.force_update == "step")
        self._fused = self._choose_stepping()
        self.check_every = CHECK_INTERVAL       # longer with fluid (_resolve_update_interval)
        if self._fused:
            self.done = ti.ndarray(ti.i32, shape=R)
            self.builds = ti.ndarray(ti.i32, shape=R)
            self.builds.fill(0)
        self.fluid_solves = 0
        self.fluid_updates = 0
        self.fluid_seconds = 0.0
        if self.scene.fluid.enabled:
            from .fluid import PressureSolver
            fl = self.scene.fluid
            nx, ny = m.fluid_shape
            self.fluid = PressureSolver(m.fluid_active, m.fluid_dx, m.fluid_dx, fl.viscosity,
                                        m.bc(), n_batch=R, tol=fl.solver_tol, gap=fl.gap,
                                        workers=m.fluid_workers)
            self.active_np = m.fluid_active
            self.active = arr(m.fluid_active.astype(np.int32), ti.i32)
            self.base = arr(np.where(m.fluid_active, m.kappa_free, 0.0))
            self.kappa = ti.ndarray(real, shape=(R, nx, ny))
            self.carried = ti.Vector.ndarray(2, real, shape=(R, nx, ny))
            # particle velocities the carried flux uses (see _source_velocities)
            self.v_src = np.zeros((R, N, 2))
            self.w_src = np.zeros((R, N))
            self.vs = vec((R, N))
            self.ws = ti.ndarray(real, shape=(R, N))
            self.pres = ti.ndarray(real, shape=(R, nx, ny))
            self.pres.fill(0)
            self.fg = arr(np.array([g.x_min, g.y_min, m.fluid_dx, fl.gap,
                                    coupling.SAMPLING[fl.pressure_sampling]]))
            self.pressure_np = np.full((R, nx, ny), np.nan)
            self._kappa_solved = None
        # Bookkeeping.
        self.results = [RealizationResult(seed=s) for s in self.seeds]
        self.last_escape_t = np.zeros(R)
        self.escaped_np = np.zeros(R, dtype=np.int64)
        self.u_ref = None
        self.e0 = None
        self.history_overflows = 0
        if place_particles:
            self._place_all()

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

    def set_state(self, x, theta=None, v=None, omega=None, alive=None):
        """Set positions (R, N, 2) [and angles, velocities, alive flags]; resets contacts."""
        R, N = self.R, self.N
        x = np.broadcast_to(np.asarray(x, dtype=float), (R, N, 2))
        self.x.from_numpy(np.ascontiguousarray(x, dtype=self._npr))
        for a, val in ((self.th, theta), (self.w, omega)):
            a.from_numpy(np.ascontiguousarray(np.broadcast_to(
                np.asarray(0.0 if val is None else val, dtype=float), (R, N)), dtype=self._npr))
        self.v.from_numpy(np.ascontiguousarray(np.broadcast_to(
            np.asarray(0.0 if v is None else v, dtype=float), (R, N, 2)), dtype=self._npr))
        self.alive.from_numpy(np.ascontiguousarray(np.broadcast_to(
            np.asarray(1 if alive is None else alive, dtype=np.int32), (R, N)), dtype=np.int32))
        for hp, hs in self.hist:
            hp.fill(0)
        self._rebuild()
        if self.fluid is not None:
            self._update_fluid(force=True)

    def set_external_load(self, force=None, moment=None):
        """Constant external force (R, N, 2) and moment (R, N) on every body, e.g. gravity."""
        R, N = self.R, self.N
        self.f_ext.from_numpy(np.ascontiguousarray(np.broadcast_to(
            np.asarray(0.0 if force is None else force, dtype=float), (R, N, 2)), dtype=self._npr))
        self.tau_ext.from_numpy(np.ascontiguousarray(np.broadcast_to(
            np.asarray(0.0 if moment is None else moment, dtype=float), (R, N)), dtype=self._npr))

    def _rebuild(self):
        self.nlist.build(self.x, self.alive, self.running, self.rb, self.flags)

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        """Current state as numpy arrays (R, N, ...)."""
        return {"x": self.x.to_numpy().astype(float), "theta": self.th.to_numpy().astype(float),
                "v": self.v.to_numpy().astype(float), "omega": self.w.to_numpy().astype(float),
                "alive": self.alive.to_numpy().astype(bool),
                "species": self.sp_np.copy()}

    def forces(self) -> tuple[np.ndarray, np.ndarray]:
        """Force and moment of the last step on every body (R, N, 2), (R, N)."""
        return self.f.to_numpy().astype(float), self.tau.to_numpy().astype(float)

    # ------------------------------------------------------------------ stepping
    def _choose_stepping(self) -> bool:
        """Resolve ``run.stepping``; True for the fused stepper (``fused.py``)."""
        m, sc = self.model, self.scene
        given = sc.run.stepping
        blockers = []
        if not m.all_disks:
            blockers.append("the particles are not all disks on the analytic path")
        if self._forces_every_step:
            blockers.append('fluid.force_update = "step" re-evaluates the fluid force '
                            "every step")
        if given == "fused" and blockers:
            raise SceneError([f"{sc.source}: run.stepping = \"fused\" is not available: "
                              + "; ".join(blockers) + ' (use "auto" or "per_step")'])
        if given == "auto":
            cpu = self.arch not in ("cuda", "vulkan", "metal", "opengl", "dx11", "dx12")
            fused = cpu and not blockers
            if fused:
                why = ("disks with held fluid forces on the CPU: many steps per kernel "
                       "launch, one realization per thread")
            elif blockers:
                why = "per_step: " + "; ".join(blockers)
            else:
                why = (f"per_step on {self.arch}: one realization per thread would leave "
                       "a GPU idle")
            self.scene = self.scene.with_values({"run.stepping": "fused" if fused
                                                 else "per_step"})
            m.scene = self.scene
            m.notes["run.stepping"] = why
            return fused
        return given == "fused"

    def step(self, n: int = 1):
        """Advance every running realization by ``n`` DEM steps (no host checks)."""
        if self._fused:
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
        running = self.running.to_numpy()
        remaining = np.where((running != 0) & (self.bad.to_numpy() == 0),
                             n - self.done.to_numpy(), 0)
        while remaining.any():
            self._rebuild()                       # grows what overflowed
            lag = remaining > 0
            k = int(remaining[lag].min())
            self.running.from_numpy(np.where(lag, running, 0).astype(np.int32))
            try:
                self._fused_launch(k)
            finally:
                self.running.from_numpy(running)
            remaining = np.where(lag & (self.bad.to_numpy() == 0),
                                 remaining - self.done.to_numpy(), 0)

    def _fused_launch(self, k: int):
        from .dem import fused
        (hp_a, hs_a), (hp_b, hs_b) = self.hist
        nl = self.nlist
        fused.disk_steps(k, self.x, self.th, self.v, self.w, self.f, self.tau, self.f_fluid,
                         self.tau_fluid, self.f_ext, self.tau_ext, self.alive, self.running,
                         self.sp, self.rad, self.mass, self.inertia, self.deq, self.xi,
                         self.pair, self.wallp, self.wall, self.wall_grad, self.wall_meta,
                         hp_a, hs_a, hp_b, hs_b, self.prm, self.iprm, self.max_overlap,
                         self.flags, self.bad, self.escaped, nl.x_ref, self.rb, nl.cell_n,
                         nl.cell_p, nl.nbr, nl.nbr_n, nl.grid, nl.ncx, nl.ncy, self.done,
                         self.builds, self.slots)
        if k % 2:
            self.hist.reverse()   # every realization's latest history is now hist[0]

    def _step_per_body(self, n: int):
        from .dem import contact, coupling, integrate
        from .dem.neighbors import F_REBUILD
        m = self.model
        for _ in range(n):
            if self._forces_every_step:
                self._fluid_forces()
            coupling.load_forces(self.f, self.tau, self.f_fluid, self.tau_fluid)
            (hp_old, hs_old), (hp_new, hs_new) = self.hist
            if m.all_disks:
                contact.disk_contacts(self.x, self.v, self.w, self.f, self.tau, self.alive,
                                      self.running, self.nlist.nbr, self.nlist.nbr_n, self.sp,
                                      self.rad, self.mass, self.pair, self.wallp, self.wall,
                                      self.wall_grad, self.wall_meta, hp_old, hs_old, hp_new, hs_new, self.prm,
                                      self.max_overlap, self.flags, self.slots)
            else:
                contact.ls_contacts(self.x, self.th, self.v, self.w, self.f, self.tau, self.alive,
                                    self.running, self.nlist.nbr, self.nlist.nbr_n, self.sp,
                                    self.tm, self.mass, self.deq, self.pair, self.wallp,
                                    self.ls_phi, self.ls_grad, self.ls_meta, self.ls_geo,
                                    self.node_pos, self.node_meta, self.wall, self.wall_grad,
                                    self.wall_meta, hp_old, hs_old,
                                    hp_new, hs_new, self.prm, self.max_overlap, self.flags,
                                    self.bad, self.slots)
            self.hist.reverse()
            integrate.advance(self.x, self.th, self.v, self.w, self.f, self.tau, self.f_ext,
                              self.tau_ext, self.alive,
                              self.running, self.sp, self.mass, self.inertia, self.deq, self.xi,
                              self.nlist.x_ref, self.iprm, self.bad, self.escaped, self.flags)
            if self.flags[F_REBUILD]:
                self._rebuild()

    # ------------------------------------------------------------------ fluid
    def _fluid_forces(self):
        from .dem import coupling
        coupling.pressure_forces(self.x, self.th, self.alive, self.running, self.tm,
                                 self.node_pos, self.node_area, self.node_meta, self.pres,
                                 self.active, self.fg, self.f_fluid, self.tau_fluid)

    def _source_velocities(self):
        """Velocities of the carried flux: each particle's current velocity averaged
        half-and-half with the one used at the previous solve. The pressure lags the
        particles by a whole update interval while they relax to their drift within
        1/xi; with the raw velocity the lagged loop v -> 2u - v alternates, the
        half-and-half average lands an isolated particle on u in one solve."""
        st = self.state()
        if self.fluid_solves == 0:
            self.v_src, self.w_src = st["v"], st["omega"]
        else:
            self.v_src = 0.5 * (self.v_src + st["v"])
            self.w_src = 0.5 * (self.w_src + st["omega"])
        self.vs.from_numpy(self.v_src.astype(self._npr))
        self.ws.from_numpy(self.w_src.astype(self._npr))

    def _update_fluid(self, force=False):
        from .dem import coupling
        m = self.model
        flux = self.scene.fluid.particle_flux
        if flux:
            self._source_velocities()
        coupling.rasterize_permeability(self.x, self.th, self.alive, self.sp, self.tm, self.rb,
                                        self.kp, self.is_circle, self.trad, self.ls_phi,
                                        self.ls_grad, self.ls_meta, self.ls_geo, self.base,
                                        self.kappa, self.fg, self.vs, self.ws, self.carried)
        kappa = self.kappa.to_numpy().astype(float)
        self.fluid_updates += 1
        if not force and self._kappa_solved is not None:
            frac = self.scene.fluid.resolve_fraction
            if frac > 0 and not flux:
                changed = (kappa != self._kappa_solved).sum(axis=(1, 2)) / m.fluid_active.sum()
                if changed.max() <= frac:
                    self._fluid_forces()          # same pressure, bodies have moved
                    return
        t0 = time.perf_counter()
        pres, info = self.fluid.solve(
            kappa, carried=self.carried.to_numpy().astype(float) if flux else None,
            # a free cell holds kappa_free in the kernels' precision (f32 rounds 0.12
            # down to 0.1199999973, below the float64 value: compare like with like)
            occupied=(kappa < float(self._npr(m.kappa_free))) & m.fluid_active
            if flux else None)
        self.fluid_seconds += time.perf_counter() - t0
        self.fluid_solves += 1
        self._kappa_solved = kappa
        self.pressure_np = pres
        self.last_fluid_info = info
        self.pres.from_numpy(np.nan_to_num(pres, nan=0.0).astype(self._npr))
        self._fluid_forces()
        if self.u_ref is None:
            # mean fluid speed through the constriction of the initial, open channel
            self.u_ref = np.abs(info.flux_out) / m.geometry.constriction_width
            self._resolve_update_interval()

    def _open_channel_speed(self) -> float:
        """Mean fluid speed through the constriction of the channel without
        particles: a property of the scene, the same for every realization, so
        that no realization's numbers depend on the others run beside it."""
        from .fluid import PressureSolver
        m, fl = self.model, self.scene.fluid
        solver = PressureSolver(m.fluid_active, m.fluid_dx, m.fluid_dx, fl.viscosity,
                                m.bc(), n_batch=1, tol=fl.solver_tol, gap=fl.gap)
        _, info = solver.solve(np.where(m.fluid_active, m.kappa_free, 0.0))
        return float(np.abs(info.flux_out).max()) / m.geometry.constriction_width

    def _resolve_update_interval(self):
        """``fluid.update_interval = "auto"``: the fastest expected particle (the mean
        fluid speed through the constriction) crosses ``UPDATE_CELL_FRACTION`` (one) fluid cell
        between solves."""
        u = self._open_channel_speed()
        if u > 0:
            # Checks (escapes, feed, clogs, stability) as often as a particle at the
            # constriction's mean speed moves CHECK_TRAVEL d; the paper's small time
            # step would otherwise check every 4e-5 s, far finer than anything changes.
            travel = CHECK_TRAVEL * self.model.d_min / (u * self.dt)
            self.check_every = max(CHECK_INTERVAL, int(travel))
            self.model.notes["run.check_every"] = (
                f"{self.check_every} steps: a particle at the mean constriction speed "
                f"{u:.4g} moves at most {CHECK_TRAVEL:g} d between checks "
                f"(and at least {CHECK_INTERVAL} steps)")
        given = self.scene.fluid.update_interval
        if given != "auto":
            travel = given * self.dt * u
            if travel > MAX_TRAVEL_BETWEEN_SOLVES * self.model.d_min:
                most = int(MAX_TRAVEL_BETWEEN_SOLVES * self.model.d_min / (u * self.dt))
                raise SceneError([
                    f"{self.scene.source}: fluid.update_interval: {given} steps let a particle "
                    f"at the constriction's mean fluid speed ({u:.3g}) move "
                    f"{travel / self.model.d_min:.2g} diameters between pressure solves, "
                    f"overrunning the pressure that pushes it; use at most {most} "
                    f"(or \"auto\")"])
            return
        n = max(1, int(UPDATE_CELL_FRACTION * self.model.fluid_dx / (u * self.dt))) if u > 0 else 1
        self.scene = self.scene.with_values({"fluid.update_interval": n})
        self.model.scene = self.scene
        self.model.notes["fluid.update_interval"] = (
            f"{UPDATE_CELL_FRACTION:g} cell / (u_c {u:.4g} * dt): a particle at the mean "
            f"constriction speed crosses {UPDATE_CELL_FRACTION:g} cell between solves")

    # ------------------------------------------------------------------ checks
    def _check(self):
        """Host-side checks every ``check_every`` steps; returns True while anything runs."""
        m = self.model
        sc = self.scene
        from .dem.neighbors import F_HISTORY_OVERFLOW
        lost = int(self.flags[F_HISTORY_OVERFLOW])
        if lost:
            self.history_overflows += lost
            self.flags[F_HISTORY_OVERFLOW] = 0
        running = self.running.to_numpy()
        escaped = self.escaped.to_numpy().astype(np.int64)
        bad = self.bad.to_numpy()
        overlap = self.max_overlap.to_numpy().astype(float)
        self.max_overlap.fill(0)
        st = None
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
                reason = ("a particle's centre ended up inside another: it passed through "
                          "between surface nodes; raise the particles' nodes or lower run.dt")
            elif overlap[r] > sc.contact.overlap_limit:
                reason = (f"overlap reached {overlap[r]:.3g} of a particle diameter "
                          f"(limit contact.overlap_limit = {sc.contact.overlap_limit:g})")
            if reason is None and not sc.fluid.enabled:
                st = st or self.state()
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
            if res.clogged:
                continue            # stop_at_clog = false: the stream goes on, the result is kept
            if escaped[r] > self.escaped_np[r]:
                self.escaped_np[r] = escaped[r]
                self.last_escape_t[r] = self.t
            res.escapees = int(escaped[r])
            if self.t - self.last_escape_t[r] >= sc.clog.window:
                st = st or self.state()
                if self._arch_static(st, r):
                    res.clogged = True
                    res.t_clog = float(self.last_escape_t[r])
                    if sc.run.stop_at_clog:
                        res.t_stop = self.t
                        running[r] = 0
                        changed = True
        if changed:
            self.running.from_numpy(running.astype(np.int32))
        if sc.feed.mode == "count":
            self._feed(running)
        return bool(running.any())

    def _kinetic_energy(self, st, r):
        m = self.model
        mass = np.array([m.species[k].mass for k in self.sp_np])
        inertia = np.array([m.species[k].inertia for k in self.sp_np])
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
        speed = np.linalg.norm(st["v"][r][near], axis=1).max()
        if self.u_ref is not None:
            ref = self.u_ref[r]
        else:
            ref = m.d_min / self.scene.clog.window
        return speed < self.scene.clog.speed_fraction * ref

    def _feed(self, running):
        """Re-insert escaped particles at the inlet (feed.mode = "count")."""
        m = self.model
        alive = self.alive.to_numpy()
        if alive.all():
            return
        xs = self.x.to_numpy().astype(float)
        ths = self.th.to_numpy().astype(float)
        vs = self.v.to_numpy().astype(float)
        shapes = [s.shape for s in m.species]
        moved = False
        for r in range(self.R):
            if not running[r]:
                continue
            for i in np.flatnonzero(alive[r] == 0):
                others = np.flatnonzero(alive[r])
                spot = find_free_spot(self.rngs[r], m.geometry, shapes[self.sp_np[i]], m.feed_inlet,
                                      xs[r, others], ths[r, others],
                                      [shapes[self.sp_np[j]] for j in others])
                if spot is None:
                    break
                xs[r, i], ths[r, i] = spot
                vs[r, i] = 0.0
                if self.fluid is not None:
                    self.v_src[r, i] = 0.0
                    self.w_src[r, i] = 0.0
                alive[r, i] = 1
                moved = True
        if moved:
            self.x.from_numpy(xs.astype(self._npr))
            self.th.from_numpy(ths.astype(self._npr))
            self.v.from_numpy(vs.astype(self._npr))
            self.alive.from_numpy(alive.astype(np.int32))
            self._rebuild()
            if self.fluid is not None:
                self._fluid_forces()              # the re-inserted bodies feel the flow at once

    # ------------------------------------------------------------------ run
    def run(self, progress=None, on_frame=None, frame_times=None) -> Result:
        """Run to ``run.t_end`` or until every realization stopped.

        ``progress(t, t_end)`` is called after every check; ``on_frame(sim)`` at each
        time of ``frame_times`` (the first at t = 0, before any step).
        """
        sc = self.scene
        t_end = sc.run.t_end
        wall0 = time.perf_counter()
        series_dt = sc.output.series_interval
        next_series = 0.0
        series = []
        frames = list(frame_times) if frame_times is not None else []
        fluid_every = sc.fluid.update_interval if self.fluid is not None else None
        running = True
        if self.fluid is not None and self.u_ref is None:
            self._update_fluid(force=True)
        while True:
            while frames and frames[0] <= self.t + 0.5 * self.dt:
                frames.pop(0)
                if on_frame is not None:
                    on_frame(self)
            if self.t >= next_series - 0.5 * self.dt:
                run_np = self.running.to_numpy()
                esc = self.escaped.to_numpy()
                for r in range(self.R):
                    if run_np[r]:
                        series.append((r, self.t, int(esc[r])))
                next_series += series_dt
            if not running or self.t >= t_end - 0.5 * self.dt:
                break
            n = min(self.check_every, int(math.ceil((t_end - self.t) / self.dt - 0.5)))
            if fluid_every is not None:
                n = min(n, fluid_every - self.steps % fluid_every)
            if frames:
                n = min(n, max(1, int(math.ceil((frames[0] - self.t) / self.dt - 0.5))))
            n = min(n, max(1, int(math.ceil((next_series - self.t) / self.dt - 0.5))))
            self.step(max(n, 1))
            if fluid_every is not None and self.steps % fluid_every == 0:
                self._update_fluid()
            running = self._check()
            if progress is not None:
                progress(self.t, t_end)
        while frames and on_frame is not None:
            frames.pop(0)
            on_frame(self)
        wall = time.perf_counter() - wall0
        # realizations still running at the end: record where they stopped
        run_np = self.running.to_numpy()
        esc = self.escaped.to_numpy()
        last_t = {r: t for r, t, _ in series}
        for r, res in enumerate(self.results):
            if res.status == "ok" and res.t_stop is None:
                res.t_stop = self.t
                if not res.clogged:
                    res.escapees = int(esc[r])
                if last_t.get(r) != self.t:
                    series.append((r, self.t, int(esc[r])))
        return self._result(wall, series)

    def _result(self, wall, series) -> Result:
        from . import __version__
        sc = self.scene
        ok = [r for r in self.results if r.status == "ok"]
        real = []
        for r in self.results:
            real.append({"seed": r.seed, "escapees": r.escapees, "clogged": r.clogged,
                         "t_clog": r.t_clog, "status": r.status, "reason": r.reason,
                         "t_stop": r.t_stop})
        st = self.state()
        summary = {
            "scene": sc.source, "version": __version__, "arch": self.arch,
            "dt": self.dt, "steps": self.steps, "t_end": sc.run.t_end,
            "wall_time_s": wall,
            "realizations": real,
            "mean_escapees": float(np.mean([r.escapees for r in ok])) if ok else None,
            # censoring-aware clogging statistics over the stable realizations
            "statistics": (stats.summarize([r.escapees for r in ok], [bool(r.clogged) for r in ok])
                           if ok else None),
            "fluid": None if self.fluid is None else {
                "updates": self.fluid_updates, "solves": self.fluid_solves,
                "solve_seconds": self.fluid_seconds,
                "grid": list(self.model.fluid_shape), "cell_size": self.model.fluid_dx},
            "neighbor_builds": self.nlist.builds + (int(self.builds.to_numpy().sum())
                                                    if self._fused else 0),
            "history_overflows": self.history_overflows,
            "contact_path": "disk" if self.model.all_disks else "level-set",
            "auto": dict(self.model.notes),
            "final_state": [
                {"x": st["x"][r].tolist(), "theta": st["theta"][r].tolist(),
                 "alive": st["alive"][r].tolist(), "species": st["species"].tolist()}
                for r in range(self.R)],
        }
        return Result(scene=sc, summary=summary, series=series, final=st)
