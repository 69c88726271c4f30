"""The implicit carried-volume coupling (fluid.flux_coupling = "implicit"): the
Taichi solve against a dense solve of the same equations built from the pyamg
side's own pieces, and the physics it must reproduce (docs/scene.md, Carried
volume)."""

import numpy as np
import pytest
import scipy.sparse as sp

from taichi_hsdem import Simulation, load_scene
from taichi_hsdem.backend import ti
from taichi_hsdem.fluid import gmg
from taichi_hsdem.fluid.gmg import BodyTerms, TaichiPressureSolver
from taichi_hsdem.fluid.system import FiniteVolumeSystem
from taichi_hsdem.resolve import resolve

DX, DY, ETA, GAP = 0.5, 0.25, 2.0, 0.5
FLOW = {"kind": "flow_rate", "Q": 2.0, "p_out": 1.0}


def bodies_on(shape, R, seed):
    """Random disks (radius 3-5 cells) per realization: owner map, centres in
    cell units, kappa (1 outside, 1/60 inside), random mobilities and drifts."""
    rng = np.random.default_rng(seed)
    N = 4
    i, j = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    owner = np.full((R, *shape), -1, np.int32)
    centre = np.zeros((R, N, 2))
    for r in range(R):
        for o in range(N):
            c = rng.uniform((6, 6), (shape[0] - 6, shape[1] - 6))
            rad = rng.uniform(3, 5)
            owner[r][(i - c[0]) ** 2 + ((j - c[1]) * DY / DX) ** 2 < rad**2] = o
            centre[r, o] = c
    kappa = np.where(owner >= 0, 1 / 60, 1.0)
    mobility = rng.uniform(0.2, 3.0, (R, N, 3))
    mobility[:, :, 2] /= 10.0              # rotational: 1 / I, I ~ m r^2
    drift = rng.normal(size=(R, N, 3))
    return owner, centre, kappa, mobility, drift


def device(owner, centre, mobility, drift):
    def up(a, dtype):
        out = ti.ndarray(dtype, a.shape)
        out.from_numpy(np.ascontiguousarray(a))
        return out
    return BodyTerms(up(owner, ti.i32), up(centre, ti.f64), up(mobility, ti.f64),
                     up(drift, ti.f64))


def dense_reference(active, kappa, owner, centre, mobility, drift, x0):
    """(A + S M S^T) x = b + S (q + M S^T x0) by a dense solve, A and b from the
    pyamg side's assembly, each column of S from its lagged carried-flux source
    (fluid.PressureSolver.solve) of one body's unit velocity: none of the
    Taichi code."""
    f = FiniteVolumeSystem(active, DX, DY, ETA, FLOW, n_batch=1, gap=GAP)
    n = f._n
    f._assemble([0], kappa.reshape(-1)[f._cells][None])
    A = sp.csr_array((f._data[0], f._indices, f._indptr), shape=(n, n)).toarray()
    nx, ny = active.shape
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    N = centre.shape[0]
    S = np.zeros((n, 3 * N))
    occupied = owner >= 0
    for o in range(N):
        mine = owner == o
        rx, ry = (i - centre[o, 0]) * DX, (j - centre[o, 1]) * DY
        for m, (vx, vy) in enumerate(((1.0, 0.0), (0.0, 1.0), (-ry, rx))):
            field = np.zeros((nx, ny, 2))
            field[..., 0] = np.where(mine, vx, 0.0)
            field[..., 1] = np.where(mine, vy, 0.0)
            S[:, 3 * o + m] = f._carried_source(field[None], occupied[None])[0]
    M = mobility.ravel()
    x0c = x0.reshape(-1)[f._cells] - f.p_ref
    rhs = f._rhs[0] + S @ (drift.ravel() + M * (S.T @ x0c))
    x = np.linalg.solve(A + (S * M) @ S.T, rhs)
    p = np.full(nx * ny, np.nan)
    p[f._cells] = x + f.p_ref
    return p.reshape(nx, ny), S


@pytest.mark.parametrize("parallel", gmg._PARALLEL)
def test_solves_the_dense_reference(parallel):
    shape, R = (40, 28), 2
    active = np.ones(shape, bool)
    owner, centre, kappa, mobility, drift = bodies_on(shape, R, seed=3)
    solver = TaichiPressureSolver(active, DX, DY, ETA, FLOW, n_batch=R, tol=1e-12, gap=GAP,
                                  parallel=parallel)
    p0, _ = solver.solve(kappa)                      # fixed obstacles: the guess
    p, info = solver.solve(kappa, bodies=device(owner, centre, mobility, drift))
    for r in range(R):
        ref, S = dense_reference(active, kappa[r], owner[r], centre[r], mobility[r],
                                 drift[r], p0[r])
        # the bodies move the pressure by 5 % of the channel's whole drop (48): far
        # more than the tolerance below
        assert np.nanmax(np.abs(ref - p0[r])) > 0.02 * np.nanmax(np.abs(p0[r] - 1.0))
        # CG to 1e-12 on a system of condition ~1e4: 1e-8 of the range
        assert np.nanmax(np.abs(p[r] - ref)) < 1e-8 * np.ptp(ref[np.isfinite(ref)])
    # the carried flux sums to zero over each body: inflow still equals outflow
    np.testing.assert_allclose(info.flux_in, info.flux_out, rtol=1e-9)


def test_bodies_at_rest_in_balance_keep_the_fixed_obstacle_pressure():
    # A static arch: every body at rest, its last step's forces in balance
    # (drift 0). Then u = -M H S^T (p - p0) and p = p0 solves the coupled
    # system exactly, whatever the mobilities: the arch gives the pressure of
    # fixed obstacles.
    shape = (48, 30)
    active = np.ones(shape, bool)
    owner, centre, kappa, mobility, _ = bodies_on(shape, 1, seed=5)
    solver = TaichiPressureSolver(active, DX, DY, ETA, FLOW, tol=1e-12, gap=GAP)
    p0, _ = solver.solve(kappa)
    p, info = solver.solve(kappa, bodies=device(owner, centre, 1e3 * mobility,
                                                np.zeros_like(mobility)))
    assert info.iterations <= 1
    assert np.nanmax(np.abs(p - p0)) < 1e-9 * np.nanmax(np.abs(p0 - 1.0))


@pytest.mark.parametrize("parallel", gmg._PARALLEL)
def test_a_realization_alone_gives_the_bits_it_gets_in_a_batch(parallel):
    shape, R = (45, 29), 3
    active = np.ones(shape, bool)
    owner, centre, kappa, mobility, drift = bodies_on(shape, R, seed=7)
    batch = TaichiPressureSolver(active, DX, DY, ETA, FLOW, n_batch=R, gap=GAP,
                                 parallel=parallel)
    p, _ = batch.solve(kappa, bodies=device(owner, centre, mobility, drift))
    for r in range(R):
        alone = TaichiPressureSolver(active, DX, DY, ETA, FLOW, gap=GAP, parallel=parallel)
        p_r, _ = alone.solve(kappa[r], bodies=device(owner[r:r + 1], centre[r:r + 1],
                                                     mobility[r:r + 1], drift[r:r + 1]))
        np.testing.assert_array_equal(p[r], p_r)


def test_moving_bodies_side_by_side_give_the_bits_of_one_realization_per_thread(monkeypatch):
    """The moving bodies' term in the lanes (_gmg_lanes: lane by lane on the
    ndarrays): five realizations, each its own bodies, give the pressure of the
    one-realization-per-thread solve bit for bit, cold and warm."""
    shape, R = (45, 29), 5
    active = np.ones(shape, bool)
    owner, centre, kappa, mobility, drift = bodies_on(shape, R, seed=11)
    answers = {}
    for lanes in (False, True):
        monkeypatch.setattr(TaichiPressureSolver, "lanes", lanes)
        solver = TaichiPressureSolver(active, DX, DY, ETA, FLOW, n_batch=R, gap=GAP)
        assert (solver._lanes is not None) == lanes
        terms = device(owner, centre, mobility, drift)
        answers[lanes] = [solver.solve(kappa, bodies=terms)[0] for _ in range(2)]
    for p0, p1 in zip(answers[False], answers[True]):
        np.testing.assert_array_equal(p0, p1)
    assert not np.array_equal(answers[True][0][0], answers[True][0][1])


@pytest.mark.parametrize("way", ["rows", "realizations", "lanes"])
def test_only_solves_the_realizations_named_and_leaves_the_others(way, monkeypatch):
    """``solve(..., only=)``: the realizations outside ``only`` take no iteration
    and keep their last pressure and fluxes, though a solve would now change
    them; those inside get the bits a whole solve gives them (in the lanes
    packed into other groups and lanes: three realizations in two groups where
    five filled them). A later whole solve solves every one again."""
    shape, R = (45, 29), 5
    active = np.ones(shape, bool)
    owner, centre, kappa, mobility, drift = bodies_on(shape, R, seed=3)
    monkeypatch.setattr(TaichiPressureSolver, "lanes", way == "lanes")
    parallel = "rows" if way == "rows" else "realizations"
    a, b = (TaichiPressureSolver(active, DX, DY, ETA, FLOW, n_batch=R, gap=GAP,
                                 parallel=parallel) for _ in range(2))
    assert (a._lanes is not None) == (way == "lanes")
    first = device(owner, centre, mobility, drift)
    p_a1, info_a1 = a.solve(kappa, bodies=first)
    b.solve(kappa, bodies=first)
    then = device(owner, centre, mobility, -drift)     # a new answer everywhere
    only = np.array([True, False, True, False, True])
    p_a2, info_a2 = a.solve(kappa, bodies=then, only=only)
    p_b2, info_b2 = b.solve(kappa, bodies=then)
    np.testing.assert_array_equal(p_a2[only], p_b2[only])
    np.testing.assert_array_equal(p_a2[~only], p_a1[~only])
    assert not np.allclose(p_b2[~only], p_a1[~only])
    np.testing.assert_array_equal(info_a2.flux_in[~only], info_a1.flux_in[~only])
    np.testing.assert_array_equal(info_a2.flux_in[only], info_b2.flux_in[only])
    assert info_a2.iterations == info_b2.iterations > 0
    p_a3, _ = a.solve(kappa, bodies=then)             # every one again
    scale = np.nanmax(np.abs(p_b2))
    np.testing.assert_allclose(p_a3[~only], p_b2[~only], rtol=0, atol=1e-5 * scale)
    with pytest.raises(ValueError, match="only must have shape"):
        a.solve(kappa, bodies=then, only=[True, False])


def test_bad_body_arrays_are_refused():
    shape = (20, 12)
    active = np.ones(shape, bool)
    owner, centre, kappa, mobility, drift = bodies_on((20, 12), 1, seed=1)
    solver = TaichiPressureSolver(active, DX, DY, ETA, FLOW, gap=GAP)
    with pytest.raises(ValueError, match="bodies.mobility must have shape"):
        solver.solve(kappa, bodies=device(owner, centre, mobility[:, :2], drift))
    with pytest.raises(ValueError, match="not both"):
        solver.solve(kappa, carried=np.zeros((*shape, 2)),
                     bodies=device(owner, centre, mobility, drift))


def jam_scene(coupling, t_end):
    """Four unit disks pushed by a flow-rate inlet into a 45-degree contraction
    whose neck (0.8) is narrower than a disk: the first sticks in the neck, the
    others pile up behind it, and all come to rest (a jammed cluster)."""
    fluid = {"enabled": True, "viscosity": 1.0, "gap": 1.2, "cell_size": 0.125,
             "bc": "flow_rate", "flow_rate": 1.2, "p_out": 0.0, "solver_tol": 1e-10}
    if coupling == "obstacle":
        fluid["particle_flux"] = False
    else:
        fluid.update(particle_flux=True, flux_coupling=coupling)
    return {
        "name": "jam", "units": "dimensionless",
        "run": {"t_end": t_end, "realizations": 1, "stop_at_clog": False},
        "fluid": fluid,
        "geometry": {"kind": "converging", "width_in": 4.0, "length_in": 6.0, "angle": 45.0,
                     "constriction_width": 0.8, "constriction_length": 0.0,
                     "width_out": 4.0, "length_out": 2.0},
        "particles": [{"shape": "circle", "diameter": 1.0, "density": 1.0, "friction": 0.3,
                       "positions": [[3.0, 0.0, 0.0], [4.2, -0.6, 0.0], [4.2, 0.6, 0.0],
                                     [5.4, 0.0, 0.0]]}],
        "feed": {"mode": "none"},
    }


def test_jammed_cluster_comes_to_rest_under_the_fixed_obstacle_pressure():
    # The cluster blocks the neck, so the whole flow seeps through the stuck disk
    # (15 times the open channel's pressure): the case where the lagged
    # coupling's loop gain is ~kappa_free / kappa_p. Implicitly coupled it comes
    # to rest, and then its pressure is exactly that of fixed obstacles in the
    # same places (the independent answer: a solve without the bodies' terms).
    # Measured at t = 40: speeds 7e-13 of the open-channel speed, pressure equal
    # to 1.3e-9 of its maximum (the solves' tolerance is 1e-10; at t = 20 the
    # cluster was still settling, 4e-5 and 6e-4).
    sim = Simulation(load_scene(jam_scene("implicit", 40.0)))
    res = sim.run()
    assert res.ok
    st = sim.state()
    x = st["x"][0]
    neck = sim.model.geometry.constriction_x0
    assert x[:, 0].max() < neck and x[:, 0].max() > neck - 0.6   # one disk in the neck
    assert np.abs(st["v"][0]).max() < 1e-9 * sim.run_state.u_ref[0]
    m, fl = sim.model, sim.scene.fluid
    fixed = TaichiPressureSolver(m.fluid_active, m.fluid_dx, m.fluid_dx, fl.viscosity, m.bc(),
                                 tol=1e-12, gap=fl.gap)
    p_fixed, _ = fixed.solve(sim.fluid.kappa.to_numpy()[0].astype(float))
    p = sim.pressure()[0]
    p_open, _ = fixed.solve(np.where(m.fluid_active, m.kappa_free, 0.0))
    assert np.nanmax(p) > 10 * np.nanmax(p_open)    # clogged: 15 times the open channel
    assert np.nanmax(np.abs(p - p_fixed)) < 1e-7 * np.nanmax(p_fixed)


def test_implicit_needs_the_taichi_solver_and_says_so():
    from taichi_hsdem.scene.keys import SceneError
    scene = jam_scene("implicit", 1.0)
    scene["fluid"]["solver"] = "amg"
    with pytest.raises(SceneError, match='flux_coupling: "implicit" solves the particles'):
        Simulation(load_scene(scene))
    scene["fluid"]["flux_coupling"] = "lagged"           # the lagged one runs on pyamg
    assert Simulation(load_scene(scene)).model.fluid_solver == "amg"
    # the resolved scene says which coupling ran and why
    sim = Simulation(load_scene(jam_scene("implicit", 1.0)))
    assert "solved together" in sim.model.notes["fluid.flux_coupling"]


@pytest.mark.parametrize("arch, solver, carried", [("x64", "auto", True), ("cuda", "auto", True),
                                                   ("vulkan", "auto", True),
                                                   ("metal", "auto", True),   # in float32
                                                   ("x64", "amg", False), ("x64", "gmg", True)])
def test_particle_flux_auto_carries_the_volume_wherever_gmg_solves(arch, solver, carried):
    # The default: the carried volume wherever its implicit coupling can run (the
    # Taichi CG, on every backend), fixed obstacles where pyamg solves the pressure
    # (only the lagged coupling there, unstable once particles jam). The choice and
    # its reason go into the resolved scene, and the damping's auto rule follows it.
    scene = jam_scene("implicit", 1.0)
    del scene["fluid"]["particle_flux"]
    scene["fluid"]["solver"] = solver
    model = resolve(load_scene(scene), arch)
    fl = model.scene.fluid
    assert fl.particle_flux is carried
    note = model.notes["fluid.particle_flux"]
    assert note.startswith(f"{str(carried).lower()}:") and "auto:" in note
    assert ("keeps a clog stable" in note) == carried
    # damping.xi = "auto" follows the choice: the drift of a particle whose cells
    # carry carried_fraction of its velocity, or of one held in the solve
    # (taichi_hsdem.laws.drift_damping; docs/model.md section 5.2)
    from taichi_hsdem.laws import drift_damping
    sp = model.species[0]
    drift = model.scene.particles[0].drift_ratio
    expected = drift_damping(fl.viscosity, 1.0, fl.gap ** 2 / 12.0, sp.kappa, drift,
                             sp.carried if carried else None)
    assert sp.xi == pytest.approx(expected, rel=1e-12)
    assert (sp.carried != 1.0) == carried      # the share is used only when carried
