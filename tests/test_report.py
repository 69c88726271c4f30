"""The run's plots (report.py): the steady-stream law drawn from the time the
stream is established, through the mean curve there; no PMF figure from a
sample too small to show a shape."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from taichi_hsdem import report, stats

pytest.importorskip("matplotlib")

# slope 4 phi Q / (H pi d^2) = 1 / pi escapees per unit time
LAW = (0.25, 1.0, 1.0, 1.0)


def fake_result(series, statuses, clogged=None, units="SI"):
    """What plot_run reads of a run: the escapee series, each realization's
    status, count and clog flag, the scene's name and units."""
    last = {}
    for r, _, s in series:
        last[r] = s
    clogged = clogged or [False] * len(statuses)
    real = [{"status": st, "escapees": last.get(r, 0), "clogged": cl}
            for r, (st, cl) in enumerate(zip(statuses, clogged))]
    return SimpleNamespace(summary={"realizations": real}, series=series,
                           scene=SimpleNamespace(name="fake", units=units))


# Realization 0 first escapes at t = 2, realization 1 at t = 3: the stream is
# established at their mean, t = 2.5, where the mean curve (linear between the
# samples) is (2 + 0.5) / 2 = 1.25. Realization 2 went unstable after an escape
# at t = 0.5 and is left out.
SERIES = ([(0, t, s) for t, s in ((0, 0), (1, 0), (2, 1), (3, 3), (4, 5))]
          + [(1, t, s) for t, s in ((0, 0), (1, 0), (2, 0), (3, 1), (4, 2))]
          + [(2, t, s) for t, s in ((0, 0), (0.5, 1))])
STATUSES = ["ok", "ok", "unstable"]


def test_law_is_drawn_from_the_mean_first_escape_through_the_mean_curve():
    plt = report._pyplot()
    fig, ax = plt.subplots()
    anchor = report.draw_escapees(ax, fake_result(SERIES, STATUSES), LAW)
    assert anchor == {"law_from_t": 2.5, "law_from_s": pytest.approx(1.25, abs=1e-12)}
    (line,) = [ln for ln in ax.lines if ln.get_label().startswith("slope")]
    assert "from the mean first escape (t = 2.5 s)" in line.get_label()
    t, s = line.get_data()
    assert t[0] == 2.5 and s[0] == pytest.approx(1.25, abs=1e-12)   # not (0, 0)
    assert t[-1] == 4.0 and s[-1] == pytest.approx(1.25 + 1.5 / math.pi, rel=1e-12)
    np.testing.assert_allclose(np.diff(s) / np.diff(t), 1 / math.pi, rtol=1e-9)
    plt.close(fig)


def test_plot_run_records_the_anchor_and_without_escapes_no_law(tmp_path):
    drawn = report.plot_run(fake_result(SERIES, STATUSES), tmp_path, law=LAW)
    assert drawn["law_from_t"] == 2.5 and (tmp_path / "escapees.png").is_file()
    still = [(0, t, 0) for t in (0.0, 1.0, 2.0)]
    drawn = report.plot_run(fake_result(still, ["ok"]), tmp_path, law=LAW)
    assert drawn["law_skipped"] == "no particle escaped: no stream to compare with the law"
    assert "law_from_t" not in report.plot_run(fake_result(SERIES, STATUSES), tmp_path)


@pytest.mark.parametrize("clogs", [2, stats.MIN_CLOGS - 1, stats.MIN_CLOGS])
def test_pmf_figure_needs_min_clogs(tmp_path, clogs):
    """The PMF figure and its test go together: drawn from MIN_CLOGS clogged
    realizations on, otherwise the summary says why it is missing."""
    rng = np.random.default_rng(5)
    counts = rng.geometric(0.1, clogs + 3) - 1
    series = [(r, 1.0, int(s)) for r, s in enumerate(counts)]
    result = fake_result(series, ["ok"] * len(counts), clogged=[True] * clogs + [False] * 3)
    drawn = report.plot_run(result, tmp_path)
    if clogs < stats.MIN_CLOGS:
        assert drawn["pmf_skipped"] == (
            f"{clogs} clogged realization(s): the PMF of s/<s> needs at least "
            f"{stats.MIN_CLOGS} to show a shape")
        assert "pmf" not in drawn and not (tmp_path / "pmf.png").exists()
    else:
        assert drawn["pmf"] == "pmf.png" and (tmp_path / "pmf.png").is_file()
        assert "pmf_skipped" not in drawn


def test_pmf_title_says_the_gof_p_value_and_the_clog_probability_per_escapee():
    """pmf.png's title names the test's p-value as a GOF p-value, beside the
    estimated clog probability per escapee (issue 46: "constant clogging
    probability: p = 0.522" read as a probability, where p was 0.123)."""
    s, c = [4, 1, 0, 5, 2, 7, 1, 0, 3, 9], [True] * 10
    title = report.pmf_title(s, c)
    p, (lo, hi) = stats.clog_probability_per_escapee(s, c)
    gof = stats.geometric_fit_test(s, c).p_value
    assert f"clog probability per escapee {p:.2g} [{lo:.2g}, {hi:.2g}]" in title
    assert f"GOF p-value {gof:.3g}" in title
    assert "constant clogging probability" not in title
    few = report.pmf_title([3, 5], [True, True])
    assert "GOF p-value not tested" in few
