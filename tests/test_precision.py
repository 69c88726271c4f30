"""Single precision (``run.precision = "f32"``) against the exact answers of the f64 tests.

Taichi takes one precision per process and this pytest process runs f64
(conftest.py), so every f32 number comes from one subprocess (``_F32_SCRIPT``
below; one process so that Taichi starts and compiles once, ~15 s in all). It
rebuilds the set-ups of test_mechanics.py and test_coupling.py with
``"run.precision": "f32"`` and prints its results as one JSON line; the tests
compare them with the same exact answers the f64 tests use.

f32 has unit round-off u = 2^-24 = 6e-8, but positions are absolute: a body
near x = 9 is stored to ulp(9) = 2^-20 = 9.5e-7, and every step adds
``dt v`` to it, rounded to that. Where that matters (the contact overlap), the
tolerance is derived from it; elsewhere the f64 tolerances are kept.

The script takes the precision as its argument, so the f64 reference numbers
come from the same code: ``python tests/test_precision.py f64``.
"""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

TESTS = Path(__file__).resolve().parent

_F32_SCRIPT = r'''
import json, math, sys, traceback
import numpy as np
sys.path.insert(0, sys.argv[2])
from conftest import arena_scene
from taichi_hsdem import Simulation, load_scene
from taichi_hsdem.geometry.shapes import boundary_vectors

PREC = sys.argv[1]
out = {"precision": PREC}


def make(scene):
    scene["run"]["precision"] = PREC
    return Simulation(load_scene(scene), place_particles=False)


def part(fn):
    try:
        out[fn.__name__] = fn()
    except Exception:
        out[fn.__name__] = {"error": traceback.format_exc()[-2000:]}


def head_on():
    # test_mechanics.head_on: disks d = 1 at (8, y) and (10, y), +-1 head-on,
    # dt_safety 0.02, stepped 1.2 time units. The three restitutions run side by
    # side as three species in lanes y = 2.5, 5, 7.5 (no species meets another;
    # the time step does not depend on e: same dt as three separate runs).
    es = (0.3, 0.6, 0.9)
    species = [{"shape": "circle", "diameter": 1.0, "count": 2, "nodes": 40,
                "restitution": e} for e in es]
    sim = make(arena_scene(species, dt_safety=0.02))
    lanes = (2.5, 5.0, 7.5)
    sim.set_state([[p for y in lanes for p in ([8.0, y], [10.0, y])]],
                  v=[[[1.0, 0.0], [-1.0, 0.0]] * 3])
    sim.step(int(1.2 / sim.dt))
    v = sim.state()["v"][0]
    return {"e": list(es),
            "ratio": [float((v[2 * k + 1, 0] - v[2 * k, 0]) / 2.0) for k in range(3)],
            "vy": float(np.abs(v[:, 1]).max()), "dt": sim.dt,
            "mass": sim.model.species[0].mass, "kn": sim.model.species[0].kn}


def square():
    # test_mechanics.resting_square (level-set path, arena floor y = 0): side 1,
    # 40 nodes, kn 1e4, mu 0.3, e 0.5, dt_safety 0.1, load 10 for 1 time unit,
    # then for 1 more with a tangential push. Realization 0: push 1.5 mu load
    # (slides); realization 1: no push (the face's overlap).
    mu, load = 0.3, 10.0
    sim = make(arena_scene([{"shape": "square", "side": 1.0, "count": 1, "nodes": 40}],
                           friction=mu, restitution=0.5, kn=1e4, dt_safety=0.1,
                           realizations=2))
    sim.set_state([[[10.0, 0.5]]] * 2)
    sim.set_external_load(force=[[[0.0, -load]]] * 2)
    sim.step(int(1.0 / sim.dt))
    x0 = sim.state()["x"][:, 0].copy()
    sim.set_external_load(force=[[[1.5 * mu * load, -load]], [[0.0, -load]]])
    sim.step(int(1.0 / sim.dt))
    x = sim.state()["x"][:, 0]
    return {"slide": float(x[0, 0] - x0[0, 0]), "mass": sim.model.species[0].mass,
            "overlap": float(0.5 - x[1, 1]), "mu": mu, "load": load, "kn": 1e4,
            "frac": 1.5}


GAP, ETA, WIDTH, LENGTH = 1.2, 1.0, 8.0, 16.0


def channel(species, cell=0.125, p_in=1.0, tol=1e-12, realizations=1, t_end=1.0,
            particle_flux=True):
    # test_coupling.channel with its defaults (pressure inlet, bilinear sampling,
    # update_interval 20, force_update "solve")
    return {
        "name": "channel", "units": "dimensionless",
        "run": {"t_end": t_end, "realizations": realizations, "seed": 0,
                "stop_at_clog": False},
        "fluid": {"enabled": True, "viscosity": ETA, "gap": GAP, "cell_size": cell,
                  "solver_tol": tol, "update_interval": 20, "pressure_sampling": "bilinear",
                  "force_update": "solve", "particle_flux": particle_flux,
                  "bc": "pressure", "p_in": p_in, "p_out": 0.0},
        "geometry": {"kind": "polygon",
                     "outline": [[0.0, 0.0], [LENGTH, 0.0], [LENGTH, WIDTH], [0.0, WIDTH]],
                     "constriction_x": LENGTH - 1.5, "escape_offset": 0.5},
        "particles": [dict({"density": 1.0}, **sp) for sp in species],
        "feed": {"mode": "none", "region": [1.0, LENGTH - 2.0]},
    }


def node_area(shape):
    return float(np.sum(shape.nodes[:, 0] * boundary_vectors(shape.nodes)[:, 0]))


def image_factor(dipole):
    return 1.0 + dipole * math.pi ** 2 / (3.0 * WIDTH ** 2)


def beta_of(sim):
    kf, kp = sim.model.kappa_free, sim.model.species[0].kappa
    return (kf - kp) / (kf + kp)


def lone_disk():
    # test_coupling.test_lone_disk_force_is_the_exact_inclusion_force at d/8: one
    # disk on the centreline at x = 8 + offset, one step; the three offsets as
    # three realizations (each has its own pressure solve and far-field flux).
    offs = (0.0, 0.03, 0.0625)
    sim = make(channel([{"shape": "circle", "diameter": 1.0, "count": 1}],
                       realizations=len(offs)))
    sim.set_state([[[8.0 + o, WIDTH / 2]] for o in offs])
    sim.step(1)
    f, m = sim.forces()
    sp = sim.model.species[0]
    beta = beta_of(sim)
    res = {"offsets": list(offs), "fx": [], "fy": [], "m": [], "exact": [],
           "perimeter": sp.shape.perimeter, "nodes": len(sp.shape.nodes)}
    for r in range(len(offs)):
        grad = sim.fluid.last_info.flux_out[r] * ETA / (sim.model.kappa_free * WIDTH)
        res["exact"].append((1 + beta) * node_area(sp.shape) * grad * GAP
                            * image_factor(beta * 0.25))
        res["fx"].append(float(f[r, 0, 0]))
        res["fy"].append(float(f[r, 0, 1]))
        res["m"].append(float(m[r, 0]))
    return res


def drift(carried):
    # test_coupling.test_auto_damping_disk_drifts_at_the_mean_fluid_velocity,
    # density 1: xi = "auto", p_in = 100, 8 relaxation times, then a 1.5 window.
    density, p_in, t_window = 1.0, 100.0, 1.5
    rho_xi = (2.0 * 0.12 / (0.12 + 0.0019)) * ETA / 0.12
    t_steady = 8.0 * density / rho_xi
    sim = make(channel([{"shape": "circle", "diameter": 1.0, "count": 1, "density": density}],
                       p_in=p_in, tol=1e-10, t_end=t_steady + t_window,
                       particle_flux=carried))
    sim.set_state([[[4.0, WIDTH / 2]]])
    xi = sim.model.species[0].xi
    rec = []

    def frame(s):
        st = s.state()
        rec.append((s.t, st["x"][0, 0].copy(), st["v"][0, 0].copy()))

    sim.run(on_frame=frame, frame_times=[1.0 / xi, t_steady, t_steady + t_window])
    (t0, x0, v0), (t1, x1, v1), (t2, x2, _) = rec[:3]
    u = sim.fluid.last_info.flux_out[0] / WIDTH
    v_mean = (x2[0] - x1[0]) / (t2 - t1)
    sp = sim.model.species[0]
    corrected = u * node_area(sp.shape) / sp.shape.area * image_factor(beta_of(sim) * 0.25)
    return {"u": float(u), "v_mean": float(v_mean), "corrected": float(corrected),
            "y_off": float(x2[1] - WIDTH / 2), "v0_ratio": float(v0[0] / v_mean),
            "transient": float(1.0 - math.exp(-xi * t0)), "v1_ratio": float(v1[0] / v_mean)}


def drift_held():
    return drift(False)


def drift_carried():
    return drift(True)


for fn in (head_on, square, lone_disk, drift_held, drift_carried):
    part(fn)
print("RESULT " + json.dumps(out))
'''


def _run_script(precision):
    proc = subprocess.run([sys.executable, "-c", _F32_SCRIPT, precision, str(TESTS)],
                          capture_output=True, text=True, timeout=300)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, (
        f"f32 subprocess failed (rc {proc.returncode}):\n{proc.stdout[-3000:]}\n"
        f"{proc.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT "):])


@pytest.fixture(scope="module")
def f32():
    out = _run_script("f32")
    assert out["precision"] == "f32"
    return out


def _part(out, name):
    res = out[name]
    if "error" in res:
        pytest.fail(f"f32 run of {name} raised:\n{res['error']}")
    return res


# ------------------------------------------------------------------ mechanics
E_ROUNDOFF_REASON = (
    "f32 position round-off: measured rebound ratio 0.29404 (-2.0 %) against 0.30109 "
    "in f64 (the same set-up, exact e = 0.3). x += dt v is rounded to ulp(9) = 9.5e-7 "
    "every step, about 1/200 of the step's displacement dt v = 2e-4, and the ~100 "
    "contact steps carry that into the overlap (up to ~1e-4 of a peak 7.9e-3): the spring "
    "force errs by ~1 %, and the weakly rebounding e = 0.3 feels it most. The same "
    "collision near x = 6 (ulp 4.8e-7) gives 0.30113 in f32. "
    "test_f32_restitution_error_within_position_roundoff_bound bounds it.")


@pytest.mark.parametrize("e", [
    pytest.param(0.3, marks=pytest.mark.xfail(strict=True, reason=E_ROUNDOFF_REASON)),
    0.6, 0.9])
def test_f32_head_on_rebound_ratio_is_restitution(f32, e):
    # test_mechanics.test_head_on_rebound_ratio_is_restitution in f32: the same
    # exact answer e and the same 1 % (the integrator's own error at 2 % of the
    # critical step is 0.4 % for e = 0.3, less for larger e).
    # Measured f32 (f64): 0.29404 (0.30109), 0.60059 (0.60050), 0.89979 (0.90040).
    res = _part(f32, "head_on")
    ratio = res["ratio"][res["e"].index(e)]
    assert ratio == pytest.approx(e, rel=0.01)


def test_f32_head_on_has_no_sideways_velocity(f32):
    # Both disks of a lane share y exactly (y is stored exactly in f32 too), so the
    # contact normal is exactly along x: nothing sideways, as in f64 (< 1e-12).
    assert _part(f32, "head_on")["vy"] < 1e-12


def test_f32_restitution_error_within_position_roundoff_bound(f32):
    # Bound on what f32 adds to the rebound ratio. Each step rounds x += dt v to
    # ulp(x) (half an ulp each body), so over the n_c = t_c / dt steps of a contact
    # the overlap d - |x2 - x1| drifts by up to n_c ulp. The spring force kn times
    # that, over the contact time t_c, changes the relative velocity by up to
    # kn n_c ulp t_c / m_eff; divided by the approach speed 2 v0:
    #   de <= kn t_c^2 ulp / (2 m_eff v0 dt) = (pi^2 / 2) ulp / (v0 dt) / (1 - zeta^2)
    # (t_c = pi / omega_d, omega^2 = kn / m_eff, zeta the damping ratio of e).
    # At x ~ 9, ulp = 9.5e-7, v0 dt = 2.05e-4: de <= 0.026 for e = 0.3, 0.023 for
    # e = 0.9. On top: the f64 test's 1 % integrator allowance. A loosening of the
    # f64 test's 1 %, but one that follows from f32; measured errors 0.0060 (e = 0.3),
    # 0.0006, 0.0002 (f64: 0.0011, 0.0005, 0.0004): within the bound by a factor
    # ~4 (it assumes every rounding goes the same way).
    res = _part(f32, "head_on")
    ulp = float(np.spacing(np.float32(9.5)))         # the contact is at x = 8.5 .. 9.5
    assert ulp == 2.0 ** -20
    v0, dt = 1.0, res["dt"]
    for e, ratio in zip(res["e"], res["ratio"]):
        zeta = -math.log(e) / math.sqrt(math.pi ** 2 + math.log(e) ** 2)
        de = (math.pi ** 2 / 2) * ulp / (v0 * dt) / (1 - zeta ** 2)
        assert abs(ratio - e) <= 0.01 * e + de, (e, ratio, de)


def test_f32_square_on_wall_slides_and_sinks_as_exact(f32):
    # Level-set path against a wall (test_mechanics.test_square_on_wall_slides_above_
    # coulomb_limit and the normalised face overlap of test_normalisation_...):
    # sliding from rest over t = 1, a = (F_t - mu F_n) / m, so
    # 0.5 (frac - 1) mu load / m (5 %, as in f64); the face pressed by the load
    # sinks load / kn (2 %, as in f64). The overlap 1e-3 sits at y ~ 0.5, stored to
    # ulp 6e-8 (6e-5 of it), and the slide's steps dt v ~ 1e-3 are ~1000 ulp(10):
    # f32 changes neither at these tolerances.
    # Measured f32 (f64): slide 0.78734 (0.78733) against the exact 0.75, +4.98 %
    # in both: the f64 test sits as close to its 5 % (the start of the slide from
    # the stuck tangential spring), and f32 moves it by 1e-5 of that;
    # overlap 1.00005e-3 (1.00000e-3).
    res = _part(f32, "square")
    expected = 0.5 * (res["frac"] - 1.0) * res["mu"] * res["load"] / res["mass"]
    assert res["slide"] == pytest.approx(expected, rel=0.05)
    assert res["overlap"] == pytest.approx(res["load"] / res["kn"], rel=0.02)


# ------------------------------------------------------------------ fluid coupling
def test_f32_lone_disk_force_is_the_exact_inclusion_force(f32):
    # test_coupling.test_lone_disk_force_is_the_exact_inclusion_force at d/8, in
    # f32: the force against (1 + beta) A_nodes G H times the wall-image factor,
    # same 2.5 % (first-order grid error). The pressure solve itself runs on the
    # host in f64; f32 enters through the stored pressure and permeability and
    # the node sum. Measured f32 +0.4560, +1.6219, +1.7300 %; f64 the same to 1e-6.
    res = _part(f32, "lone_disk")
    for fx, fy, m, exact in zip(res["fx"], res["fy"], res["m"], res["exact"]):
        assert fx > 0
        assert fx / exact - 1.0 == pytest.approx(0.0, abs=0.025)
        # Mirror symmetry: no lift, no moment. In f64 these are the solver's
        # residual (< 1e-8 Fx); in f32 the node sum of n = 40 terms -p H a_k, each
        # at most p_in H |a_k|, carries round-off up to n u p_in H (perimeter)
        # (Higham's summation bound) = 9e-6, 8e-5 of Fx. Measured |Fy| <= 1.5e-7 Fx,
        # |M| <= 3e-8 Fx; a grid-level asymmetry would be ~1e-3.
        tol = res["nodes"] * 2.0 ** -24 * 1.0 * 1.2 * res["perimeter"]
        assert abs(fy) < tol
        assert abs(m) < tol * 0.5
    # the comparison is not empty: the d/8 grid error is there (f64 +1.7 % at most)
    assert max(abs(fx / ex - 1.0) for fx, ex in zip(res["fx"], res["exact"])) > 0.001


@pytest.mark.parametrize("carried", [False, True])
def test_f32_auto_damping_disk_drifts_at_the_mean_fluid_velocity(f32, carried):
    # test_coupling.test_auto_damping_disk_drifts_at_the_mean_fluid_velocity,
    # density 1, in f32, the same answers and tolerances: drift q / W after the
    # two exact corrections within 2 %, and plainly within 3 %; straight down the
    # axis. dt v = 1.6e-3 is ~3000 ulp(5), so the position round-off is 1e-4 of the
    # drift at most. Measured f32 (f64) v / (q/W): held 1.01932 (1.01931);
    # carried 0.636 (1.0160), a bug, not round-off: Simulation._update_fluid marks
    # the particles' cells as kappa < m.kappa_free with kappa read back from the
    # f32 array, and kappa_free rounded to f32 (0.11999999732) is below the f64
    # 0.12, so every fluid cell counts as occupied and the carried flux at a
    # particle's edge is halved. Comparing against the f32-rounded kappa_free
    # gives 1.01603 in f32.
    res = _part(f32, "drift_carried" if carried else "drift_held")
    assert res["v_mean"] == pytest.approx(res["corrected"], rel=0.02)
    assert res["v_mean"] == pytest.approx(res["u"], rel=0.03)
    assert abs(res["y_off"]) < 1e-6
    if not carried:
        assert res["v0_ratio"] == pytest.approx(res["transient"], abs=0.015)
    else:
        assert res["v1_ratio"] == pytest.approx(1.0, abs=0.02)


if __name__ == "__main__":
    # the reference numbers: python tests/test_precision.py f64 (or f32)
    print(json.dumps(_run_script(sys.argv[1] if len(sys.argv) > 1 else "f64"), indent=1))
