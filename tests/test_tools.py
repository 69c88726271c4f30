"""The benchmark and study commands' argument handling (their runs are measured,
not tested: see docs/performance.md)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import load_tool

ROOT = Path(__file__).resolve().parents[1]


def test_bench_case_names_carry_overrides():
    bench = load_tool("bench")
    scene, ov = bench.overrides("disks-0.26-R10@fluid.workers=1@run.dt_safety=0.1", 0.02)
    assert scene.name == "vani_phi026.toml"
    assert ov[:3] == ["run.realizations=10", "run.t_end=0.02", "run.stop_at_clog=false"]
    assert "particles.packing_fraction=0.26" in ov
    assert ov[-2:] == ["fluid.workers=1", "run.dt_safety=0.1"]
    scene, ov = bench.overrides("paper-squares-0.17-R1", 0.05)
    assert scene.name == "squares.toml"
    assert f"run.dt={bench.PAPER_DT}" in ov
    assert f"fluid.update_interval={bench.PAPER_FLUID_EVERY}" in ov


@pytest.mark.parametrize("lanes, used", [("on", True), ("off", False)])
def test_bench_turns_the_solve_s_lanes_on_and_off(lanes, used):
    """``tools/bench.py --lanes``: the pressure solve's realizations side by side
    or one per thread, whatever the batch (its row says which ran)."""
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "bench.py"), "--cases",
                           "disks-0.26-R10", "--sim-time", "0.002", "--lanes", lanes],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    row = json.loads([line for line in proc.stdout.splitlines() if line.startswith("{")][-1])
    assert "error" not in row, row
    assert row["lanes"] is used and row["realizations"] == 10


def test_escapee_study_moves_one_knob_at_a_time_off_the_scene_defaults():
    conv = load_tool("convergence")
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import resolve
    model = resolve(load_scene(ROOT / "scenes" / "vani_phi026.toml"))
    scene = model.scene
    # The chart labels a point "auto" by these values: they must be the scene's.
    assert conv.ESCAPEE_DEFAULTS["run.dt_safety"] == scene.run.dt_safety
    assert conv.ESCAPEE_DEFAULTS["contact.overlap_target"] == scene.contact.overlap_target
    assert conv.ESCAPEE_DEFAULTS["fluid.cell_size"] == \
        __import__("pytest").approx(model.d_min / 6, rel=1e-12)
    for _, key, values in conv.ESCAPEE_KNOBS:
        assert conv.ESCAPEE_DEFAULTS[key] not in values


def test_paper_settings_are_the_same_in_the_study_and_the_benchmark():
    conv, bench = load_tool("convergence"), load_tool("bench")
    assert conv.PAPER_POINT == {"run.dt": bench.PAPER_DT,
                                "fluid.update_interval": bench.PAPER_FLUID_EVERY}
    assert bench.PAPER_DT == 3.75e-7 and bench.PAPER_FLUID_EVERY == 10000  # Zhou et al.


def test_interval_study_points_are_the_cells_they_are_labelled_with(monkeypatch):
    """The interval study gives its points as steps (so that a folder stays the same
    run whatever the default): each must be, to a step per half cell, what "auto"
    resolves to at that many cells per solve, and the longest must be accepted."""
    conv = load_tool("convergence")
    from taichi_hsdem import load_scene
    from taichi_hsdem import resolve as resolve_module
    from taichi_hsdem.resolve import domain
    vani = ROOT / "scenes" / "vani_phi026.toml"

    def interval(*sets):
        scene = load_scene(vani, ["run.realizations=1", "fluid.workers=1", *sets])
        return resolve_module.resolve(scene).scene.fluid.update_interval

    steps = [int(round(c / 0.5 * conv.HALF_CELL_STEPS)) for c in conv.INTERVAL_CELLS]
    for cells, k in zip(conv.INTERVAL_CELLS, steps):
        monkeypatch.setattr(domain, "UPDATE_CELL_FRACTION", cells)
        assert abs(interval() - k) <= cells / 0.5, (cells, k)
    monkeypatch.undo()
    # the current default is one of the points, and the escapee study's "auto"
    assert interval() == conv.ESCAPEE_DEFAULTS["fluid.update_interval"]
    assert interval() in steps
    # would refuse an interval over half a diameter
    assert interval(f"fluid.update_interval={steps[-1]}") == steps[-1]


def test_grid_study_points_are_the_cells_they_are_labelled_with():
    """The grid study's points hold the default and solve as often as it does:
    the interval it gives is what "auto" resolves to on the default grid."""
    conv = load_tool("convergence")
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import FLUID_CELLS_PER_D, resolve
    vani = ROOT / "scenes" / "vani_phi026.toml"
    model = resolve(load_scene(vani, ["run.realizations=1"]))
    assert model.scene.fluid.update_interval == conv.GRID_INTERVAL_STEPS
    assert conv.GRID_CELLS[0] == FLUID_CELLS_PER_D        # the reference is the default
    assert model.d_min == conv.D_VANI
    for c in conv.GRID_CELLS:
        m = resolve(load_scene(vani, ["run.realizations=1", f"fluid.cell_size={conv.D_VANI / c!r}",
                                      f"fluid.update_interval={conv.GRID_INTERVAL_STEPS}"]))
        # the grid is fitted to the channel: within a cell in 60 of what was asked
        assert abs(model.d_min / m.fluid_dx - c) < c / 60, (c, model.d_min / m.fluid_dx)


def test_solve_study_labels_its_base_point_with_the_scene_defaults():
    """The solve study's first point is the vani scene as shipped: the values it
    is labelled with (and measured against) are what the scene resolves to, and no
    other point repeats them."""
    conv = load_tool("convergence")
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import resolve
    model = resolve(load_scene(ROOT / "scenes" / "vani_phi026.toml", ["run.realizations=1"]))
    fluid = model.scene.fluid
    assert conv.SOLVE_DEFAULTS == {"fluid.solver_tol": fluid.solver_tol,
                                   "fluid.resolve_fraction": fluid.resolve_fraction}
    for _label, key, values in conv.SOLVE_KNOBS:
        assert conv.SOLVE_DEFAULTS[key] not in values


def test_sweep_studies_take_set_overrides_at_every_point(tmp_path, capsys):
    # --set reaches every point's resolved scene (e.g. the fixed-obstacle model of
    # the README's earlier studies); a bad key stops before anything is written
    conv = load_tool("convergence")
    out = tmp_path / "conv"
    assert conv.main(["interval", "--quick", "--realizations", "1", "--out", str(out),
                      "--set", "fluid.particle_flux=false"]) == 0
    resolved = sorted(out.glob("interval-quick/*/scene.resolved.toml"))
    assert len(resolved) == 4
    for path in resolved:
        assert "\nparticle_flux = false\n" in path.read_text()
    bad = tmp_path / "bad"
    try:
        conv.main(["interval", "--quick", "--out", str(bad), "--set", "fluid.bogus=1"])
    except SystemExit as exc:
        assert exc.code == 2
    else:
        raise AssertionError("a bad --set key was accepted")
    assert "fluid.bogus: unknown key" in capsys.readouterr().err
    assert not bad.exists()


def test_timestep_study_quick_writes_its_chart(tmp_path):
    conv = load_tool("convergence")
    rows, csv_path, png = conv.timestep_study(tmp_path, quick=True)
    assert csv_path.is_file() and png.is_file()
    assert [r[0] for r in rows] == [0.02, 0.15, 0.3]
    # at 0.02 of the critical step the spring-dashpot rebounds at e within 1 %
    # (first order in omega dt: 0.4 % measured), and the max column is the max
    assert rows[0][-1] < 0.01
    for r in rows:
        assert r[-1] == max(abs(v) for v in r[2:-1])


def test_escape_windows_pool_escapes_over_unclogged_time(tmp_path):
    # Two realizations at phi 0.1: seed 0 escapes at t = 0.5, 1.5, 2.5 and never
    # clogs (runs to 3 s); seed 1 escapes at 0.2 and clogs at 1.0. Window [0, 2]:
    # escapes 2 (seed 0) + 1 (seed 1) over 2 + 1 unclogged seconds = 1 per s.
    (tmp_path / "series.csv").write_text(
        "phi,seed,t,escapees,theory_escapees\n"
        "0.1,0,0.0,0,0.0\n0.1,0,0.5,1,0.25\n0.1,0,1.5,2,0.75\n0.1,0,2.5,3,1.25\n"
        "0.1,0,3.0,3,1.5\n0.1,1,0.0,0,0.0\n0.1,1,0.2,1,0.1\n0.1,1,1.0,1,0.5\n")
    (tmp_path / "realizations.csv").write_text(
        "label,phi,seed,escapees,clogged,t_clog,t_stop,status,reason\n"
        "a,0.1,0,3,0,,3.0,ok,\na,0.1,1,1,1,1.0,1.0,ok,\n")
    tool = load_tool("escape_windows")
    (row,) = tool.windows_table(tmp_path, [(0.0, 2.0)])
    assert row[:5] == (0.1, 0.0, 2.0, 3, 3.0)
    assert row[5] == 1.0 and row[6] == 0.5          # theory: 0.25 escapees at 0.5 s
    (late,) = tool.windows_table(tmp_path, [(1.0, 3.0)])
    assert late[3:5] == (2, 2.0)                    # seed 1 has clogged by then
    assert tool.main([str(tmp_path), "--windows", "2:1"]) == 2
    (tmp_path / "realizations.csv").unlink()
    assert tool.main([str(tmp_path)]) == 2               # a folder without its table


def test_neck_study_sets_the_width_from_the_diameter_and_tabulates(tmp_path):
    """tools/neck_study.py: each point's resolved neck is W/d times the largest
    equivalent diameter (vani: d = 140 um), and the table has a row per point."""
    from taichi_hsdem.scene import read_toml
    neck = load_tool("neck_study")
    out = tmp_path / "neck"
    assert neck.main(["--wd", "1.3", "--realizations", "1", "--t-end", "0.01",
                      "--out", str(out), "--quiet"]) == 0
    (point,) = [p for p in out.iterdir() if p.is_dir()]
    resolved = read_toml(point / "scene.resolved.toml")
    assert resolved["geometry"]["constriction_width"] == pytest.approx(1.3 * 140e-6, rel=1e-9)
    md = (out / "neck.md").read_text().splitlines()
    assert md[0].startswith("| W/d |") and md[2].startswith("| 1.3 |")
    assert (out / "neck.csv").read_text().splitlines()[1].startswith("1.3,")
    # where a clog held: the most downstream particle near the neck, in diameters
    # upstream of its entrance; placed by hand 0.4 d up, one further back, one
    # beyond the window (5 d up) and one dead
    import json
    from taichi_hsdem.resolve.domain import _geometry
    from taichi_hsdem.scene import load_scene
    g = _geometry(load_scene(point / "scene.resolved.toml").geometry)
    d, x0 = 140e-6, g.constriction_x0
    import numpy as np
    summary = json.loads((point / "summary.json").read_text())
    assert "final_state" not in summary
    summary["realizations"][0]["clogged"] = True
    (point / "summary.json").write_text(json.dumps(summary))
    x = [[x0 - 0.4 * d, 0.0], [x0 - 1.5 * d, 0.0], [x0 - 5 * d, 0.0], [x0 + 0.2 * d, 0.0]]
    alive = [1, 1, 1, 0]
    with np.load(point / "final_state.npz") as f:
        arrays = {k: f[k] for k in f.files}
    arrays["x"], arrays["alive"] = np.array([x]), np.array([alive], dtype=bool)
    np.savez(point / "final_state.npz", **arrays)
    assert neck.arch_positions(point) == [pytest.approx(0.4, rel=1e-9)]
    # a point written before final_state.npz: its summary's final_state
    (point / "final_state.npz").unlink()
    summary["final_state"] = [{"x": x, "alive": alive}]
    (point / "summary.json").write_text(json.dumps(summary))
    assert neck.arch_positions(point) == [pytest.approx(0.4, rel=1e-9)]
    summary["realizations"][0]["clogged"] = False     # only clogged realizations count
    (point / "summary.json").write_text(json.dumps(summary))
    assert neck.arch_positions(point) == []


def test_sweep_changes_compares_points_paired_by_seed(tmp_path):
    """tools/sweep_changes.py: each point's <s> against the reference, paired by
    seed. A point whose every realization clogs after 10 more escapes than the
    reference's moves <s> by +10 exactly (every resample of the pairs too); a copy
    of the reference does not move it; a noisy shift of +2.9 leaves out 0 at 95 %
    but not at the Bonferroni level of three comparisons (1 - 0.05/3), whose
    interval is the wider; a point with no stable realization says so; a missing
    reference exits 2."""
    import json
    tool = load_tool("sweep_changes")

    def point(name, escapees, status="ok"):
        (tmp_path / name).mkdir()
        rows = [{"seed": 100 + k, "escapees": s, "clogged": True, "status": status}
                for k, s in enumerate(escapees)]
        mean = sum(escapees) / len(escapees) if status == "ok" else None
        (tmp_path / name / "summary.json").write_text(json.dumps(
            {"realizations": rows, "mean_escapees": mean,
             "mean_escapees_ci": None if mean is None else [0.8 * mean, 1.2 * mean]}))

    base = [3, 7, 1, 12, 5, 9, 2, 6, 4, 8]
    point("base", base)
    point("more", [s + 10 for s in base])
    point("same", base)
    point("noisy", [8, 3, 2, 15, 5, 15, 8, 11, 5, 13])
    point("unstable", [None] * 10, status="unstable")     # every realization went bad
    text = tool.table(tmp_path)
    rows = {line.split("|")[1].strip(): line for line in text.splitlines()[2:]}
    assert "+10.00 [+10.00, +10.00]" in rows["more"] and rows["more"].endswith("| yes | yes |")
    assert "+0.00 [+0.00, +0.00]" in rows["same"] and rows["same"].endswith("| no | no |")
    assert rows["noisy"].endswith("| yes | no |")
    assert "| - | 0 of 10 | no stable realization to compare | - | - |" in rows["unstable"]
    assert "beyond chance over all 3 (Bonferroni)" in text.splitlines()[0]
    assert "(reference)" in rows["base"]
    assert tool.main([str(tmp_path), "--reference", "nothing"]) == 2


def test_sweep_changes_says_nothing_clogged_as_a_lower_bound(tmp_path):
    """A point where nothing clogged: its <s> as every message writes it (a lower
    bound, from summary.json's statistics), and no change (issue 46: it printed
    "+nan [-inf, +inf]")."""
    import json
    from taichi_hsdem.stats import summarize
    tool = load_tool("sweep_changes")
    for name, clogged in (("base", True), ("never", False)):
        esc = [3, 7, 1, 12, 5]
        st = summarize(esc, [clogged] * 5)
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(
            {"realizations": [{"seed": k, "escapees": s, "clogged": clogged, "status": "ok"}
                              for k, s in enumerate(esc)],
             "mean_escapees": st["mean_escapees"], "mean_escapees_ci": st["mean_escapees_ci"],
             "statistics": st}))
    rows = {line.split("|")[1].strip(): line for line in tool.table(tmp_path).splitlines()[2:]}
    bound = summarize([3, 7, 1, 12, 5], [False] * 5)["mean_escapees_lower_bound"]
    assert (f"| never | > {bound:.3g} (nothing clogged; 95 % lower bound) | 0 of 5 | none: "
            "nothing clogged in this point (its <s> is a lower bound) | - | - |") == rows["never"]
    assert "nan" not in rows["never"] and "inf" not in rows["never"]


def test_throat_study_reports_an_ensemble_that_never_clogged():
    """tools/throat_study.py's table cells: an ensemble with no clog has no <s>
    (stats.summarize gives None): "-", not a traceback; one with clogs gives its
    estimate and 1/<s>."""
    from taichi_hsdem import stats
    tool = load_tool("throat_study")
    none = stats.summarize([5, 7, 9], [False, False, False])
    assert none["mean_escapees"] is None
    assert tool._estimate(none).startswith("- [") and tool._rate(none) == "-"
    some = stats.summarize([4, 4, 4, 4], [True] * 4)      # sum(s) / n_clogged = 4
    assert tool._estimate(some).startswith("4 [") and tool._rate(some) == "0.25"


def test_profile_case_splits_a_run_and_sets_its_solve_against_the_floor():
    """tools/profile_case.py on a short vani run: the phases add up to the wall
    time, the kernels are listed dearest first, the floor is cells x iterations x
    bytes / bandwidth; a bad argument is refused in words."""
    import re
    import subprocess
    import sys
    tool = ROOT / "tools" / "profile_case.py"
    proc = subprocess.run([sys.executable, str(tool), "disks-0.17-R1", "--sim-time", "0.01",
                           "--top", "3", "--bandwidth", "10"],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout
    wall = float(re.search(r"([\d.]+) s wall", out).group(1))
    phases = [float(v) for v in re.findall(r"^  [a-zA-Z ()]+?\s+(-?[\d.]+) s\s+-?[\d.]+ %", out,
                                         re.M)]
    assert len(phases) == 5 and sum(phases) == pytest.approx(wall, abs=0.01)
    kernels = [float(v) for v in re.findall(r"^ +[\d.]+ % +([\d.]+) s +\d+ x", out, re.M)]
    assert len(kernels) == 3 and kernels == sorted(kernels, reverse=True)
    m = re.search(r"(\d+) cells x ([\d.]+) iterations x (\d+) B at 10 GB/s = ([\d.]+) ms", out)
    cells, iters, per_cell, floor_ms = int(m[1]), float(m[2]), int(m[3]), float(m[4])
    assert cells == 175 * 61 and per_cell == load_tool("profile_case").BYTES_PER_CELL_ITERATION
    assert floor_ms == pytest.approx(1e3 * cells * iters * per_cell / 10e9, rel=0.01, abs=0.06)
    bad = subprocess.run([sys.executable, str(tool), "disks-0.17-R1", "--top", "0"],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and "--top must be at least 1" in bad.stderr


def test_arch_lifetime_places_the_symmetric_arch_on_the_walls():
    # each outer disk a radius (less the 0.01 d opening) inside its 45-degree
    # wall and two radii (plus the opening) from the middle one, at beta from
    # the cross-stream direction
    import math
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import resolve
    tool = load_tool("arch_lifetime")
    d = 140e-6
    g = resolve(load_scene(ROOT / "scenes" / "vani_phi026.toml",
                           [f"geometry.constriction_width={2.2 * d}"])).geometry
    mid, up, low = tool.arch_positions(g, 45.0, d, 20.0)
    a, e = d / 2, tool.OPENING * d / 2
    c = g.constriction_x0 + g.constriction_width / 2      # upper wall: x + y = c
    assert (c - up[0] - up[1]) / math.sqrt(2) == pytest.approx(a + e / math.sqrt(2), rel=1e-9)
    assert up[1] == -low[1] and up[0] == low[0] and mid[1] == 0.0
    gap = math.hypot(up[0] - mid[0], up[1] - mid[1])
    assert 2 * a < gap < 2 * a + 3 * e
    assert math.degrees(math.atan2(up[0] - mid[0], up[1])) == pytest.approx(20.0, abs=0.5)


def test_arch_lifetime_refuses_a_bad_angle():
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "arch_lifetime.py"),
                           "--beta", "75"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--beta" in proc.stderr


def test_dipole_grid_converges_at_first_order_and_finds_the_carried_fraction():
    """tools/dipole_grid.py: the staircase disk's dipole on the vani scene's grid
    against the exact inclusion (laws.inclusion_dipole) with the scene's carried
    fraction (each grid's "auto"): +13.2 % at d/6 (the default cell), +7.9 % at d/12,
    +3.9 % at d/24 measured (8 positions): first order, the error about halving with the cell.
    Asserted on 4 positions: d/6 between +8 and +20 %, the d/12 error 0.4-0.75 of
    it; and the fraction it finds for the 3D sphere's dipole leaves that dipole on
    the grid (a solve of its own, to 1 %: B is linear in c to 2e-3)."""
    from taichi_hsdem import load_scene
    from taichi_hsdem.resolve import resolve
    tool = load_tool("dipole_grid")
    vani = Path(__file__).resolve().parents[1] / "scenes" / "vani_phi026.toml"
    errors = []
    for cell in ("2.3333e-5", "1.16667e-5"):
        scene = load_scene(vani, [f"fluid.cell_size={cell}"])
        res = tool.study(scene, positions=4)
        row = res["rows"][1]
        errors.append(row["grid"] / row["exact"] - 1)
    assert 0.08 < errors[0] < 0.20 and 0.4 < errors[1] / errors[0] < 0.75, errors
    scene = load_scene(vani)
    res = tool.study(scene, positions=4)
    m = resolve(scene)
    s = m.species[0]
    offsets = [tuple(v) for v in np.random.default_rng(0).uniform(-0.5, 0.5, (4, 2))]
    b, _ = tool.grid_dipole(m.fluid_dx, s.d_eq, m.kappa_free, s.kappa,
                            res["c_grid"] * res["lambda"], offsets)
    assert b == pytest.approx(res["target"], rel=0.01)
    # the scene's "auto" share is already the grid's (fluid.grid_dipole, 3 x 3
    # stratified positions against these 4 random ones, which scatter by 1 %)
    assert res["c_grid"] == pytest.approx(s.carried, rel=0.02)


def test_bench_lanes_layouts_give_the_scalar_bits():
    """tools/bench_lanes.py: the realizations side by side in a cell's vector
    (2 and 4 lanes), in ndarrays (the package's storage) and in fields, sweep to
    the same bits as each realization alone in an ndarray (its exit status says
    so), the premise of a realization-innermost solve."""
    import subprocess
    import sys
    from pathlib import Path
    tool = Path(__file__).resolve().parents[1] / "tools" / "bench_lanes.py"
    proc = subprocess.run([sys.executable, str(tool), "--realizations", "4", "--widths", "2,4",
                           "--nx", "12", "--ny", "9", "--sweeps", "6", "--repeats", "1",
                           "--threads", "1"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert [r["layout"] for r in rows] == ["ndarray-scalar", "ndarray-lanes-2", "ndarray-lanes-4",
                                           "field-scalar", "field-lanes-2", "field-lanes-4"]
    assert all(r["same_bits"] for r in rows)
    assert rows[0]["speedup_over_ndarray_scalar"] == 1.0


def test_bench_order_times_both_numberings_of_the_same_disks():
    """tools/bench_order.py: the placed and the cell-ordered numbering of the same
    disks, timed in turn; cell order puts consecutive bodies about a cell apart
    (the placement scatters them), and the two runs end with every disk within a
    small fraction of a diameter of its twin (the owner rule of shared cells
    and the order of sums are all that differ)."""
    import subprocess
    import sys
    from pathlib import Path
    tool = Path(__file__).resolve().parents[1] / "tools" / "bench_order.py"
    proc = subprocess.run([sys.executable, str(tool), "--case", "channel-300", "--steps", "10",
                           "--repeats", "1", "--warm", "2"], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    row = json.loads([line for line in proc.stdout.splitlines() if line.startswith("{")][-1])
    assert row["bodies"] == 300
    assert row["spacing_d"]["cells"] < 3.0 < 10.0 < row["spacing_d"]["placed"]
    assert 0.0 <= row["end_positions_apart_d"] < 1e-3
    assert all(v > 0 for v in row["ms_per_step"].values())
    assert len(row["ratio_cells_over_placed"]) == 1


def test_bench_stopped_pairs_the_two_ways_solve_by_solve():
    """tools/bench_stopped.py: the batch run with the stopped realizations left out
    of the solves and solved whole, in turn in one process; the two end in the
    same positions (the tool checks it) and every solve, and its whole fluid
    update, is timed both ways."""
    tool = ROOT / "tools" / "bench_stopped.py"
    proc = subprocess.run([sys.executable, str(tool), "--realizations", "2", "--t-end",
                           "0.03", "--repeats", "1"], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("2 realizations,") and "(the same bits)" in lines[0]
    bands = [line for line in lines if line.lstrip().startswith("2-  2")]
    assert len(bands) == 2             # the solves, then their fluid updates
    (solves, left, whole, ratio), (updates, *times) = (
        [float(v) for v in band.split()[2:]] for band in bands)
    assert solves >= 2 and left > 0 and whole > 0 and ratio > 0
    assert updates == solves and times[0] >= left and times[1] >= whole
    assert lines[-1].startswith("whole runs (s), left out / whole:")
