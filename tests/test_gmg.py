"""Taichi multigrid pressure solve (taichi_hsdem.fluid.gmg) against the pyamg reference
(fluid.PressureSolver), a direct solve of the same matrix and exact answers."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from taichi_hsdem.fluid import _gmg_cycle, gmg
from taichi_hsdem.backend import ti
from taichi_hsdem.fluid import (
    FluxImbalanceError,
    PressureSolver,
    circular_inclusion_error,
)
from taichi_hsdem.fluid.gmg import TaichiPressureSolver


def disk_field(shape, seed, count, radius, contrast, high=1.0):
    """Permeability ``high`` with ``count`` random disks of ``high * contrast``
    (centres and radius in cells)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(shape[0]) + 0.5, np.arange(shape[1]) + 0.5, indexing="ij")
    kappa = np.full(shape, high)
    for cx, cy in rng.uniform((0, 0), shape, size=(count, 2)):
        kappa[(x - cx) ** 2 + (y - cy) ** 2 < radius**2] = high * contrast
    return kappa


def walled(shape):
    """A channel with a wall block in it and a single fluid cell sealed inside the
    block (no Dirichlet face reaches it)."""
    active = np.ones(shape, bool)
    nx, ny = shape
    active[nx // 3:nx // 3 + 6, ny // 4:ny // 4 + 7] = False
    active[nx // 3 + 3, ny // 4 + 3] = True
    return active


def hourglass(shape, neck):
    """Walls that narrow a channel linearly to ``neck`` cells at mid-length."""
    nx, ny = shape
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    half = neck / 2 + (ny - neck) / 2 * np.abs(i - (nx - 1) / 2) / ((nx - 1) / 2)
    return np.abs(j + 0.5 - ny / 2) < half


PRESSURE = {"kind": "pressure", "p_in": 1.0, "p_out": 0.0}
FLOW = {"kind": "flow_rate", "Q": 2.0, "p_out": 1.0}


def dirichlet(shape):
    nx, ny = shape
    return {"kind": "dirichlet", "left": 3.0 + np.linspace(0, 1, ny),
            "right": None, "bottom": np.linspace(3, 0, nx), "top": None}


def both(active, bc, n_batch=1, tol=1e-10, gap=0.5, **extra):
    """The reference and the Taichi solver on the same problem."""
    args = (active, 0.5, 0.25, 2.0, bc)
    kw = {"n_batch": n_batch, "tol": tol, "gap": gap}
    return PressureSolver(*args, **kw), TaichiPressureSolver(*args, **kw, **extra)


@pytest.mark.parametrize("contrast", [1 / 60, 1e-6])
@pytest.mark.parametrize("kind", ["pressure", "flow_rate", "dirichlet"])
def test_solves_the_reference_system_to_its_tolerance(kind, contrast):
    shape, tol = (64, 40), 1e-10
    bc = {"pressure": PRESSURE, "flow_rate": FLOW, "dirichlet": dirichlet(shape)}[kind]
    kappa = disk_field(shape, seed=1, count=40, radius=3.0, contrast=contrast)
    ref, new = both(walled(shape), bc, tol=tol)
    p_ref, info_ref = ref.solve(kappa)
    p, info = new.solve(kappa)
    np.testing.assert_array_equal(new.connected, ref.connected)
    np.testing.assert_array_equal(np.isnan(p), np.isnan(p_ref))
    # The same matrix: the answer's residual in the reference's own assembled
    # matrix meets the tolerance (the two assemblies differ by rounding only).
    A = sp.csr_array((ref._data[0], ref._indices, ref._indptr), shape=(ref._n, ref._n))
    b = ref._rhs[0]
    x = p.ravel()[ref._cells] - ref.p_ref
    residual = np.linalg.norm(b - A @ x)
    assert residual <= tol * np.linalg.norm(b) * (1 + 1e-3)
    # So the error is within what that residual allows, |x - x*| <= |r| / lambda_min,
    # and well within 1e-6 of the pressure drop (the whole range of x*).
    exact = sla.spsolve(A.tocsc(), b)
    lam_min = sla.eigsh(A.tocsc(), k=1, sigma=0, which="LM", return_eigenvectors=False)[0]
    assert np.linalg.norm(x - exact) <= residual / lam_min * (1 + 1e-6)
    assert np.abs(x - exact).max() <= 1e-6 * np.ptp(exact)
    # Fluxes balance and agree with the reference's (both are solves to 1e-10).
    np.testing.assert_allclose(info.flux_in, info.flux_out, rtol=1e-8)
    np.testing.assert_allclose(info.flux_in, info_ref.flux_in, rtol=1e-7)
    assert info.residual <= tol and 0 < info.iterations < 100
    u = np.stack(new.velocity(p, kappa))
    u_ref = np.stack(ref.velocity(p_ref, kappa))
    assert np.abs(u - u_ref).max() < 1e-6 * np.abs(u_ref).max()


def inclusion_error(solver_class, cells_per_radius, k_ratio):
    return circular_inclusion_error(cells_per_radius, k_ratio, solver_class=solver_class)["l1"]


def test_circular_inclusion_against_the_exact_solution():
    # Measured for the reference (test_fluid): L1 error / (G a) 0.0111 at 8 cells
    # per radius, 0.00504 at 16. Both solvers solve the same discrete problem to
    # 1e-11, so they share the discretisation error to far below its size.
    errors = [inclusion_error(TaichiPressureSolver, m, 1e-2) for m in (8, 16)]
    reference = [inclusion_error(PressureSolver, m, 1e-2) for m in (8, 16)]
    np.testing.assert_allclose(errors, reference, rtol=1e-6)
    assert errors[1] < 0.006 and errors[1] < 0.6 * errors[0]


def test_hourglass_conserves_mass_through_every_section():
    shape, dx, dy, eta = (80, 36), 0.5, 0.25, 3.0
    active = hourglass(shape, neck=4)
    kappa = disk_field(shape, seed=6, count=10, radius=2.5, contrast=1e-2)
    solver = TaichiPressureSolver(active, dx, dy, eta, PRESSURE, tol=1e-12)
    p, info = solver.solve(kappa)
    assert np.isnan(p[~active]).all() and np.isfinite(p[active]).all()
    assert info.flux_in[0] > 0
    assert info.flux_in[0] == pytest.approx(info.flux_out[0], rel=1e-9)
    # the two-point flux summed over each column of interior x-faces is the inflow
    open_face = active[:-1] & active[1:]
    k_face = 2 * kappa[:-1] * kappa[1:] / (kappa[:-1] + kappa[1:])
    flux = np.where(open_face, k_face * (p[:-1] - p[1:]), 0.0).sum(axis=1) * dy / (dx * eta)
    np.testing.assert_allclose(flux, info.flux_in[0], rtol=1e-9)
    ux, uy = solver.velocity(p, kappa)
    assert not ux[~active].any() and not uy[~active].any()


def test_warm_start_reduces_iterations():
    shape = (60, 40)
    kappa = disk_field(shape, seed=2, count=12, radius=4.0, contrast=1e-3)
    x, y = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    nearby = kappa * (1 + 0.01 * np.sin(x / 7.0) * np.cos(y / 5.0))
    warm = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE, tol=1e-10)
    warm.solve(kappa)
    p_warm, info_warm = warm.solve(nearby)
    cold = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE, tol=1e-10)
    p_cold, info_cold = cold.solve(nearby)
    assert info_warm.rebuilt and info_warm.iterations < info_cold.iterations
    assert np.abs(p_warm - p_cold).max() < 1e-8
    _, info = cold.solve(nearby, x0=p_cold)  # the answer as the guess
    assert info.iterations == 0
    setup = cold.stats["setup_seconds"]
    _, info = cold.solve(nearby.copy())      # same kappa: nothing rebuilt
    assert not info.rebuilt and info.iterations == 0
    assert cold.stats["rebuilds"] == 1 and cold.stats["solves"] == 3
    if cold.parallel != "cells":             # on the CPU not even the operators
        assert cold.stats["setup_seconds"] == setup


@pytest.mark.parametrize("parallel", gmg._PARALLEL)
def test_a_realization_alone_gives_the_bits_it_gets_in_a_batch(parallel):
    # 45 x 29 cells: no multiple of anything the loops are cut into.
    shape, R = (45, 29), 3
    active = walled(shape)
    batches = [np.stack([disk_field(shape, 10 * r + step, 8, 3.0, 1e-3) for r in range(R)])
               for step in range(2)]
    batch = TaichiPressureSolver(active, 0.5, 0.5, 2.0, FLOW, n_batch=R, gap=0.5,
                                 parallel=parallel)
    alone = [TaichiPressureSolver(active, 0.5, 0.5, 2.0, FLOW, gap=0.5, parallel=parallel)
             for _ in range(R)]
    for kappas in batches:  # a cold solve, then one warm-started from it
        p, info = batch.solve(kappas)
        for r in range(R):
            p_r, info_r = alone[r].solve(kappas[r])
            np.testing.assert_array_equal(p[r], p_r)
            np.testing.assert_array_equal(info.flux_out[r], info_r.flux_out[0])


def test_a_batch_runs_its_realizations_side_by_side_only_where_they_vectorize(monkeypatch):
    """The lanes (_gmg_lanes) take a CPU batch of float64 solved one realization per
    thread where it fills the lanes (on 2 threads: 8, 16, 20, 100 realizations;
    not 4, 10, 12); a realization alone, the rows and cells ways and float32 keep
    one realization per thread (so the bit tests around here compare the two)."""
    from taichi_hsdem import limits
    monkeypatch.setattr(limits, "thread_share", lambda: 2)
    active = np.ones((20, 12), bool)
    for n, used in ((8, True), (16, True), (20, True), (100, True), (4, False), (10, False),
                    (12, False)):
        solver = TaichiPressureSolver(active, 1.0, 1.0, 1.0, FLOW, n_batch=n, gap=0.5)
        assert (solver._lanes is not None) == used, n
    monkeypatch.setattr(TaichiPressureSolver, "lanes", True)
    assert TaichiPressureSolver(active, 1.0, 1.0, 1.0, FLOW, n_batch=5, gap=0.5)._lanes
    for extra in ({"n_batch": 1}, {"n_batch": 5, "parallel": "rows"},
                  {"n_batch": 5, "parallel": "cells"}, {"n_batch": 5, "real": "f32"}):
        assert TaichiPressureSolver(active, 1.0, 1.0, 1.0, FLOW, gap=0.5, **extra)._lanes is None


@pytest.mark.parametrize("bc", [FLOW, PRESSURE])
def test_realizations_side_by_side_give_the_bits_of_one_per_thread(bc, monkeypatch):
    """Five realizations (a group of four and one with three idle lanes) of
    different permeabilities, so that they stop after different iteration counts:
    the lanes give each the pressure, fluxes, residual and iteration count of the
    one-realization-per-thread solve, cold and warm-started; and again after a
    solver of another grid has used the shared lanes (whose values then lie where
    this grid has its ghosts)."""
    shape, R = (45, 29), 5
    active = walled(shape)
    kappas = [np.stack([disk_field(shape, 10 * r + step, 4 + 3 * r, 3.0, 10.0 ** -(r % 3 + 1))
                        for r in range(R)]) for step in range(2)]
    answers = {}
    for lanes in (False, True):
        monkeypatch.setattr(TaichiPressureSolver, "lanes", lanes)
        if lanes:   # another grid and batch through the lanes first
            other = TaichiPressureSolver(np.ones((70, 38), bool), 1.0, 1.0, 1.0, bc,
                                         n_batch=6, gap=0.5)
            other.solve(disk_field((70, 38), 99, 20, 3.0, 1e-2)[None].repeat(6, 0))
        solver = TaichiPressureSolver(active, 0.5, 0.5, 2.0, bc, n_batch=R, gap=0.5)
        assert (solver._lanes is not None) == lanes
        answers[lanes] = [solver.solve(k) for k in kappas]
    counts = set()
    for (p0, i0), (p1, i1) in zip(answers[False], answers[True]):
        np.testing.assert_array_equal(p0, p1)
        np.testing.assert_array_equal(i0.flux_out, i1.flux_out)
        assert (i0.iterations, i0.residual) == (i1.iterations, i1.residual)
        counts.add(i0.iterations)
    assert counts != {0}


@pytest.mark.parametrize("bc", [PRESSURE, FLOW], ids=["pressure", "flow_rate"])
def test_only_the_realizations_whose_kappa_changed_are_rebuilt(bc):
    """A solve rebuilds the operators (fine, coarse levels, coarse factor, the
    kappa part of the right-hand side) of the realizations whose kappa changed,
    not the others'; what it leaves is what a build of all of them gives, to the
    bit. Realization 2's coarse factor, overwritten by hand, shows it was left."""
    shape, R = (40, 26), 3
    solver = TaichiPressureSolver(walled(shape), 1.0, 1.0, 1.0, bc, n_batch=R, gap=0.5)
    kappa = np.stack([disk_field(shape, seed, 6, 3.0, 0.05) for seed in range(R)])
    solver.solve(kappa)
    changed = kappa.copy()
    changed[1] = disk_field(shape, 9, 6, 3.0, 0.0)       # new disks, cells cut off
    marker = solver._chol.to_numpy()
    marker[2] = np.eye(marker.shape[1])
    solver._chol.from_numpy(marker)
    p, info = solver.solve(changed)
    assert solver._flags.to_numpy()[:, gmg._CHANGED].tolist()[::2] == [0, 0]
    assert info.rebuilt and np.isfinite(p[1][walled(shape)]).any()

    def arrays():
        cg = solver._cg.to_numpy()
        return (solver._op.to_numpy(), solver._chol.to_numpy(), cg[_gmg_cycle._BASE],
                solver._state.to_numpy()[:, _gmg_cycle._INLET])
    left = arrays()
    np.testing.assert_array_equal(left[1][2], np.eye(marker.shape[1]))   # not rebuilt
    solver._build(solver._kappa_in, None, None)                           # every one
    whole = arrays()
    left[1][2] = whole[1][2]
    for a, b in zip(left, whole):
        np.testing.assert_array_equal(a, b)


def test_the_three_ways_of_parallel_work_agree():
    shape = (96, 70)  # large enough for rows to use both the level kernels and the serial tail
    kappa = disk_field(shape, seed=3, count=30, radius=3.0, contrast=1e-3)
    answers = {}
    for parallel in gmg._PARALLEL:
        solver = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE,
                                      tol=1e-10, parallel=parallel)
        answers[parallel], info = solver.solve(kappa)
        assert info.residual <= 1e-10
    for p in answers.values():  # the same operations in the same order: the same bits
        np.testing.assert_array_equal(p, answers["realizations"])


@pytest.mark.parametrize("shape", [(301, 57), (70, 33), (130, 9)])
def test_one_pass_smoother_gives_the_bits_of_the_half_sweeps_in_turn(shape):
    """The CPU's smoother (_smooth_blocks: every half-sweep in one pass, in blocks
    of columns, then the seams between them) against its half-sweeps one kernel
    each over all cells, from the same random field: the pre-smoother and the
    post-smoother with its coarse correction, on grids of 4 blocks with a
    remainder, 1 block, and a column height below the blocks' width."""
    from taichi_hsdem.fluid import _gmg_cycle as cycle
    kappa = disk_field(shape, seed=5, count=shape[0] * shape[1] // 150, radius=3.0,
                       contrast=1e-2)
    solver = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE, n_batch=2,
                                  parallel="rows")
    solver.solve(np.stack([kappa, kappa[::-1]]))  # builds every level's operator
    start = np.random.default_rng(1).standard_normal(solver._mg.shape)
    solver._flags.from_numpy(np.ones(solver._flags.shape, np.int32))
    arrays = (solver._op, solver._mg, solver._geo, solver._flags)
    for post in (0, 1):
        solver._mg.from_numpy(start)
        cycle._smooth_blocks(*arrays, 0, post)
        one_pass = solver._mg.to_numpy()
        solver._mg.from_numpy(start)
        for h in range(2 * cycle.SWEEPS):
            cycle._smooth(*arrays, 0, h, post)
        np.testing.assert_array_equal(one_pass, solver._mg.to_numpy())
        assert np.abs(one_pass - start).max() > 1.0  # the smoother did change it


_SUBPROCESS = textwrap.dedent("""
    import json, sys
    import numpy as np
    from taichi_hsdem import backend
    backend.init("cpu", "f32")
    from taichi_hsdem.fluid.gmg import TaichiPressureSolver
    args = json.loads(sys.argv[1])
    kappa = np.load(args["kappa"])
    out = {}
    for parallel in ("realizations", "rows"):
        solver = TaichiPressureSolver(np.ones(kappa.shape, bool), 1.0, 1.0, 1.0,
            {"kind": "pressure", "p_in": 1.0, "p_out": 0.0}, tol=1e-10, parallel=parallel)
        np.save(args[parallel], solver.solve(kappa)[0])
    print(backend.ti.lang.impl.current_cfg().cpu_max_num_threads)
""")


def test_bits_do_not_depend_on_threads_or_the_simulation_precision(tmp_path):
    """The solve is float64 whatever the default float, and each dot product is
    summed in a fixed order: one thread and f32 give the bits of this process."""
    shape = (96, 70)
    kappa = disk_field(shape, seed=4, count=30, radius=3.0, contrast=1e-3)
    np.save(tmp_path / "kappa.npy", kappa)
    files = {"kappa": str(tmp_path / "kappa.npy"),
             "realizations": str(tmp_path / "a.npy"), "rows": str(tmp_path / "b.npy")}
    env = dict(os.environ, TI_CPU_MAX_NUM_THREADS="1")
    run = subprocess.run([sys.executable, "-c", _SUBPROCESS, json.dumps(files)], env=env,
                         check=False, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[-1] == "1"
    for parallel in ("realizations", "rows"):
        p, _ = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE,
                                    tol=1e-10, parallel=parallel).solve(kappa)
        np.testing.assert_array_equal(np.load(files[parallel]), p)


@pytest.mark.parametrize("bc, gap", [(PRESSURE, None), (FLOW, 1.0)])
def test_zero_permeability_cuts_cells_off_as_the_reference_does(bc, gap):
    shape = (30, 12)
    open_kappa = np.ones(shape)
    closed = open_kappa.copy()
    closed[10, :] = 0.0        # an impermeable column across the channel
    island = open_kappa.copy()
    island[19:24, 3:9] = 0.0   # a ring of zeros round a permeable pocket
    island[20:23, 4:8] = 1.0
    island[[0, -1], 5] = 0.0   # an inlet and an outlet cell: no Dirichlet face there
    kappas = np.stack([open_kappa, closed, island])
    ref = PressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, bc, n_batch=3, gap=gap)
    new = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, bc, n_batch=3, gap=gap)
    new.solve(np.stack([open_kappa] * 3))  # every cell an unknown, then cut off
    p_ref, info_ref = ref.solve(kappas)
    p, info = new.solve(kappas)
    assert info.blocked.tolist() == info_ref.blocked.tolist() == [False, True, False]
    np.testing.assert_array_equal(np.isnan(p), np.isnan(p_ref))
    assert np.isnan(p[2, 20:23, 4:8]).all()
    np.testing.assert_allclose(p, p_ref, atol=1e-6)
    assert info.flux_in[1] < 1e-6 and info.flux_out[1] < 1e-6
    # unblocking gives every cell its pressure back
    p, info = new.solve(np.stack([open_kappa] * 3))
    assert not info.blocked.any() and np.isfinite(p).all()
    np.testing.assert_allclose(p[1], p[0], atol=1e-8)


def test_device_kappa_and_device_pressure():
    shape, R = (40, 24), 2
    # values exact in float32, so the f32 device copy holds the same numbers
    kappa = np.stack([disk_field(shape, s, 6, 3.0, 2.0**-10) for s in range(R)])
    on_device = ti.ndarray(ti.f32, (R, *shape))
    on_device.from_numpy(kappa.astype(np.float32))
    host = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE, n_batch=R)
    device = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE, n_batch=R)
    p, info_host = host.solve(kappa)
    p_device, info = device.solve(on_device, host=False)
    assert isinstance(p_device, ti.Ndarray) and p_device.shape == (R, *shape)
    np.testing.assert_array_equal(p_device.to_numpy(), p)
    np.testing.assert_array_equal(info.flux_in, info_host.flux_in)


def test_carried_flux_matches_the_reference():
    shape = (50, 30)
    kappa = disk_field(shape, seed=8, count=10, radius=3.0, contrast=1 / 60)
    rng = np.random.default_rng(9)
    occupied = kappa < 1.0
    carried = np.where(occupied[..., None], rng.normal(size=(*shape, 2)), 0.0)
    ref, new = both(np.ones(shape, bool), FLOW)
    for occ in (None, occupied):
        p_ref, info_ref = ref.solve(kappa, carried=carried, occupied=occ)
        p, info = new.solve(kappa, carried=carried, occupied=occ)
        assert np.abs(p - p_ref).max() < 1e-7 * np.ptp(p_ref)
        np.testing.assert_allclose(info.flux_out, info_ref.flux_out, rtol=1e-7)


def test_flux_imbalance_and_user_errors(monkeypatch):
    shape = (60, 40)
    kappa = disk_field(shape, seed=1, count=12, radius=4.0, contrast=1e-3)
    monkeypatch.setattr(gmg, "MAXITER", 1)
    solver = TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, PRESSURE, n_batch=2)
    with pytest.raises(FluxImbalanceError, match="realization 0") as caught:
        solver.solve(np.stack([kappa, kappa]))
    assert abs(caught.value.flux_in - caught.value.flux_out) > caught.value.limit > 0
    monkeypatch.undo()
    bad = np.stack([kappa, kappa])
    bad[1, 3, 2] = -1.0
    with pytest.raises(ValueError, match=r"realization 1 .* cell \(3, 2\)"):
        solver.solve(bad)
    with pytest.raises(ValueError, match="shape"):
        solver.solve(kappa)
    with pytest.raises(ValueError, match="gap"):
        TaichiPressureSolver(np.ones(shape, bool), 1.0, 1.0, 1.0, FLOW)
    blocked = np.ones(shape, bool)
    blocked[30, :] = False
    with pytest.raises(ValueError, match="no path"):
        TaichiPressureSolver(blocked, 1.0, 1.0, 1.0, PRESSURE)
