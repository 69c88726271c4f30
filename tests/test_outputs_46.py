"""Issue 46, items 7 and 12: what a run's outputs say.

Ensemble curves keep each clogged (stopped) realization at its final state, with
the realizations faint behind the mean; count axes get integer ticks; every scene
with a flow rate gets ``pressure_drop.png``."""
from types import SimpleNamespace

import numpy as np
import pytest

from taichi_hsdem import report

pytest.importorskip("matplotlib")


@pytest.fixture
def figures(monkeypatch):
    """The figures saved, by file name, kept open to be read."""
    import matplotlib.figure
    saved = {}

    def keep(fig, path, *args, **kwargs):
        saved[str(path).rsplit("/", 1)[-1]] = fig
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep)
    monkeypatch.setattr(report, "draw_clog_map", lambda *a, **k: {})
    return saved


def mean_line(fig):
    (ax,) = fig.axes[:1]
    (line,) = [ln for ln in ax.lines if ln.get_linewidth() == 2]
    return line


def network_result():
    """Realization 0 clogs and stops at t = 0.5 with K/K0 0.2 and 60 % of its
    throats clogged; realization 1 stays open to t = 1 at K/K0 0.6, 20 % clogged."""
    real = [{"status": "ok", "clogged": True}, {"status": "ok", "clogged": False}]
    dp0, q = 2.0, 1.0
    flow = ([(0, t, dp0 / k, q) for t, k in ((0.0, 1.0), (0.25, 0.5), (0.5, 0.2))]
            + [(1, t, dp0 / 0.6, q) for t in (0.0, 0.25, 0.5, 0.75, 1.0)])
    network = [(0, 0.0, 10, 0), (0, 0.3, 14, 3), (0, 0.5, 16, 6),
               (1, 0.0, 10, 0), (1, 0.5, 15, 2), (1, 1.0, 24, 2)]
    return SimpleNamespace(summary={"realizations": real}, flow=flow, network=network,
                           throats=[], scene=SimpleNamespace(name="fake", units="SI")), (dp0, q)


def test_a_clogged_realization_that_stopped_stays_clogged_in_the_means(tmp_path, figures):
    result, empty = network_result()
    drawn = report.plot_network(result, tmp_path, [None] * 10, None, empty)
    assert drawn["permeability"] == "permeability.png"
    t, k = mean_line(figures["permeability.png"]).get_data()
    assert t[-1] == 1.0
    assert np.all(np.diff(k) <= 1e-12)              # never reads as unclogging
    assert k[-1] == pytest.approx(0.4)              # (0.2 + 0.6) / 2: 0 held, not dropped
    n, f = mean_line(figures["throats_clogged.png"]).get_data()
    assert n[-1] == 24
    assert np.all(np.diff(f) >= -1e-12)             # the clogged fraction never falls
    assert f[-1] == pytest.approx((0.6 + 0.2) / 2)
    # the realizations faint behind the mean, the stopped one dotted at its end
    ax = figures["permeability.png"].axes[0]
    faint = [ln for ln in ax.lines if ln.get_linewidth() < 1 and ln.get_alpha() is not None]
    assert len(faint) == 3 and all(ln.get_alpha() <= 0.4 for ln in faint)
    (dotted,) = [ln for ln in faint if ln.get_linestyle() == ":"]
    assert dotted.get_xydata().tolist() == [[0.5, 0.2], [1.0, 0.2]]


def run_result(fluid, units="SI"):
    """Two realizations of a single-constriction run: realization 0 clogs and
    stops at t = 0.4 at a drop of 9 Pa; realization 1 runs to t = 1 and ends at
    3 Pa; escapees up to 3 (matplotlib would tick them every 0.5)."""
    real = [{"status": "ok", "clogged": True, "escapees": 2},
            {"status": "ok", "clogged": False, "escapees": 3}]
    series = ([(0, t, s) for t, s in ((0.0, 0), (0.2, 1), (0.4, 2))]
              + [(1, t, s) for t, s in ((0.0, 0), (0.5, 2), (1.0, 3))])
    flow = ([(0, t, dp, 1e-10) for t, dp in ((0.0, 1.0), (0.2, 4.0), (0.4, 9.0))]
            + [(1, t, dp, 1e-10) for t, dp in ((0.0, 1.0), (0.5, 2.0), (1.0, 3.0))])
    return SimpleNamespace(summary={"realizations": real}, series=series, flow=flow,
                           scene=SimpleNamespace(name="fake", units=units, fluid=fluid))


FLOW_RATE = SimpleNamespace(enabled=True, bc="flow_rate", flow_rate=1e-10)


def test_escapee_counts_are_ticked_at_whole_numbers(tmp_path, figures):
    report.plot_run(run_result(FLOW_RATE), tmp_path)
    ticks = figures["escapees.png"].axes[0].get_yticks()
    assert len(ticks) >= 3 and np.all(ticks == np.round(ticks))


def test_a_scene_with_a_flow_rate_gets_its_pressure_drop_plot(tmp_path, figures):
    drawn = report.plot_run(run_result(FLOW_RATE), tmp_path)
    assert drawn["pressure_drop"] == "pressure_drop.png"
    ax = figures["pressure_drop.png"].axes[0]
    assert ax.get_ylabel() == "pressure drop (Pa)" and ax.get_xlabel() == "t (s)"
    t, dp = mean_line(figures["pressure_drop.png"]).get_data()
    assert t[-1] == 1.0 and dp[-1] == pytest.approx((9.0 + 3.0) / 2)   # the clogged one held
    faint = [ln for ln in ax.lines if ln.get_linewidth() < 1]
    assert len(faint) == 3 and all(ln.get_alpha() <= 0.4 for ln in faint)


def test_pressure_drop_png_is_written_and_only_with_a_flow_rate(tmp_path):
    drawn = report.plot_run(run_result(FLOW_RATE), tmp_path)
    assert (tmp_path / "pressure_drop.png").is_file() and drawn["pressure_drop"]
    for fluid in (SimpleNamespace(enabled=True, bc="pressure", flow_rate=None),
                  SimpleNamespace(enabled=False, bc="flow_rate", flow_rate=1e-10)):
        folder = tmp_path / fluid.bc / str(fluid.enabled)
        folder.mkdir(parents=True)
        assert "pressure_drop" not in report.plot_run(run_result(fluid), folder)
        assert not (folder / "pressure_drop.png").exists()
    dimensionless = report.plot_run(run_result(FLOW_RATE, units="dimensionless"),
                                    tmp_path / "pressure" / "True")
    assert dimensionless["pressure_drop"] == "pressure_drop.png"


def test_the_cli_docs_example_reads_a_run_without_pandas(tmp_path, monkeypatch):
    """docs/cli.md's reading example runs as shipped with what the project
    installs (pandas is in no extra): on a run folder's escapees.csv and
    summary.json it draws escapees_by_hand.png."""
    import re
    import sys
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / "docs" / "cli.md").read_text()
    (block,) = re.findall(r"^Reading the results.*?^```python\n(.*?)^```", text, re.S | re.M)
    run = tmp_path / "runs" / "vani_phi026"
    run.mkdir(parents=True)
    (run / "escapees.csv").write_text("realization,t,escapees\n0,0.0,0\n1,0.0,0\n"
                                      "0,0.5,3\n1,0.5,1\n0,1.0,4\n1,1.0,6\n")
    (run / "summary.json").write_text('{"mean_escapees": 5.0, "mean_escapees_ci": [2, 9], '
                                      '"never_clogged": 1}')
    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, "pandas", None)      # as where it is not installed
    import matplotlib
    matplotlib.use("Agg")
    exec(compile(block, "docs/cli.md", "exec"), {})
    assert (tmp_path / "escapees_by_hand.png").stat().st_size > 0


def test_the_escapee_series_has_a_column_per_species_and_one_species_keeps_three():
    """escapees.csv per species (observables.escapee_table, record_series): the
    escapes counted at every check (count_species, clogged or not) and the bodies
    dead since, beside each total; one species keeps realization,t,escapees."""
    import json

    from taichi_hsdem import observables
    from taichi_hsdem.runstate import RunState
    rs = RunState.start([0, 1], n_particles=4, n_species=2, n_throats=0)
    # a check at t = 0.1: realization 0 lost a body of species 0 (escaped), re-fed after
    rs.t = 0.1
    observables.count_species(rs, np.array([[1, 0], [0, 0]]))
    rs.unfed_by_species = np.zeros((2, 2), dtype=np.int64)
    # a series row at t = 0.15, between checks: one of species 1 has escaped since
    rs.t = 0.15
    observables.record_series(rs, [1, 1], np.array([2, 0]), np.array([[0, 1], [0, 0]]))
    assert rs.series == [(0, 0.15, 2), (1, 0.15, 0)]
    assert rs.series_species == [(0, 0.15, (1, 1)), (1, 0.15, (0, 0))]
    header, rows = observables.escapee_table(rs.series, ["ok", "ok"], ["small", "large"],
                                             rs.series_species)
    assert header == ["realization", "t", "escapees", "escapees_small", "escapees_large"]
    assert rows == [[0, "0.15", 2, 1, 1], [1, "0.15", 0, 0, 0]]
    assert all(sum(row[3:]) == row[2] for row in rows)
    # an unstable realization is left out, as before
    assert observables.escapee_table(rs.series, ["ok", "unstable"], ["small", "large"],
                                     rs.series_species)[1] == rows[:1]
    # one species (or a run that recorded no per-species rows): the three columns
    assert observables.escapee_table(rs.series, ["ok", "ok"], ["disks"], []) == (
        ["realization", "t", "escapees"], [[0, "0.15", 2], [1, "0.15", 0]])
    assert observables.escapee_table(rs.series, ["ok", "ok"], ["a", "b"], [])[0] == [
        "realization", "t", "escapees"]
    # a checkpoint keeps them; one written before them reads as none recorded
    values, arrays = rs.to_arrays()
    again = RunState.from_arrays(json.loads(json.dumps(values)), arrays)
    assert again.series_species == rs.series_species
    assert again.species_escaped.tolist() == [[1, 0], [0, 0]]
    for key in ("series_species", "species_escaped"):
        del values[key]
    old = RunState.from_arrays(json.loads(json.dumps(values)), arrays)
    assert old.series_species == [] and old.species_escaped.dtype == np.int64


def test_when_every_realization_went_unstable_each_missing_plot_says_why(tmp_path, figures):
    """Before: throats_clogged.png and pressure_drop.png were simply missing, and
    permeability.png was drawn with no curve, with no note in the summary."""
    result, empty = network_result()
    for row in result.summary["realizations"]:
        row["status"] = "unstable"
    drawn = report.plot_network(result, tmp_path, [None] * 10, None, empty)
    assert drawn["permeability_skipped"] == drawn["throats_clogged_skipped"] == report.NO_STABLE
    assert "permeability" not in drawn and "throats_clogged" not in drawn
    assert "permeability.png" not in figures and "throats_clogged.png" not in figures
    run = run_result(FLOW_RATE)
    for row in run.summary["realizations"]:
        row["status"] = "unstable"
    drawn = report.plot_run(run, tmp_path)
    assert drawn["pressure_drop_skipped"] == report.NO_STABLE
    assert "pressure_drop.png" not in figures
