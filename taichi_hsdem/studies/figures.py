"""The reference paper's clogging figures as commands (Zhou et al. 2024, Figs. 8-13).

Each command runs a set of *points* (one scene each: a packing fraction, a friction,
a shape...), every point a batch of random realizations run together, then writes
into ``--out`` (default ``runs/figures/<command>/``):

``<command>.png``
    the figure;
``points.csv``
    one row per point: what was varied, particle count, realizations (stable,
    clogged, censored, unstable), ``<s>`` and its interval, the decay rate of
    ``P(s) ~ exp(-lambda s)`` and its interval, the never-clogged fraction, the
    wall time (and for ``escapees-time`` the fitted and theoretical escape rates);
``realizations.csv``
    one row per realization: seed, escapees, clogged, t_clog, t_stop, status;
``pmf.csv``
    (every command but ``escapees-time``) the PMF of ``x = s/<s>`` with its
    binomial standard error;
``series.csv``
    (``escapees-time``) escapees over time per realization beside the theory
    line ``4 phi Q t / (H pi d^2)``;
``figure.json``
    the command line, the overrides of every point, wall times (``wall_time_s``
    this invocation's, a point's ``wall_s`` the run that computed it, ``resumed``
    whether it was read back);
``points/<point>.json``
    each point's realizations as soon as the point has finished. A later run
    into the same ``--out`` reads a point back instead of running it when its
    scene (seeds included), realization count and the package code are the
    same (``--no-resume`` runs everything again), so an interrupted figure loses
    at most the point it was running.

Commands
--------
``escapees-time`` (Fig. 8)
    ``scenes/vani_phi026.toml`` with ``run.stop_at_clog = false`` at packing
    fractions 0.086, 0.17, 0.26: escapees against time, and the steady escape
    rate against ``4 phi Q / (H pi d^2)`` (``Q = fluid.flow_rate``,
    ``H = fluid.gap``, ``d`` the particle's equivalent diameter). Particles start
    in the control volume and need a transit time to reach the constriction, so
    the rate is fitted from each realization's first escape on (see
    :func:`stream_rate`).
``pmf-collapse`` (Fig. 9)
    the same scene at phi = 0.19, 0.26, 0.32, stopping at the clog: histogram of
    escapees before clogging and the PMF of ``s/<s>`` against ``exp(-x)``.
``friction`` (Fig. 10)
    phi = 0.26, friction 0.1 ... 0.9: ``<s>`` with its interval, and decay rates.
``shapes`` (Figs. 11-12)
    ``scenes/squares.toml`` (mu = 0.4) and circles of the same bounding diameter,
    at W/d_b = 1.7 and 1.2.
``polygons`` (Fig. 13)
    ``scenes/polygons.toml`` (W/d_b = 1.2, mu = 0.4): regular polygons of 3-6
    vertices and circles of the same bounding diameter, ``<s>`` against the vertex
    count.

Statistics
----------
Every estimate comes from :mod:`taichi_hsdem.stats` over the realizations that ran
stably: a realization that never clogged is right-censored (its ``s`` is a lower
bound) and enters the geometric likelihood as such, it is not dropped; ``<s>`` is
the sample mean with a t interval when every realization clogged and the
censoring-aware fit otherwise (:func:`taichi_hsdem.stats.mean_escapees`).
Unstable realizations are counted in ``points.csv`` and left out.

Sizes
-----
Default: :data:`DEFAULT_REALIZATIONS` realizations per point and the scene's
``t_end`` (5 s); the paper used 100 per point (``--realizations 100``).
``--quick`` is a smoke test of the whole chain for CI (a couple of minutes on two
CPU cores): few realizations, a short ``t_end``, a clog window of 0.15 s, the
upstream channel shrunk to :data:`QUICK_BOX` bounding diameters square (the
count-based scenes scaled to the same areal fraction) so that particles reach the
constriction within that time, and for the level-set scenes a fluid cell of
``d_b / 5``. Its numbers are not the paper's statistics. ``--set`` overrides
(applied after the command's and ``--quick``'s own, before the point's varied
value) change anything else.

Examples
--------
::

    python tools/figures.py escapees-time --quick
    python tools/figures.py friction --realizations 100 --out runs/fig10
    python tools/figures.py polygons --vertices 3 4 --set run.t_end=2
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import stats
from ..scene import Scene, SceneError, load_scene

FIGURES = ("escapees-time", "pmf-collapse", "friction", "shapes", "polygons")
DEFAULT_REALIZATIONS = 10
PAPER_REALIZATIONS = 100
QUICK_BOX = 6.0                 # quick mode: upstream channel QUICK_BOX x QUICK_BOX d_b
QUICK_CLOG_WINDOW = 0.15        # s
QUICK_CELLS_PER_DB = 5.0        # quick mode, level-set scenes: fluid cell d_b / 5
PMF_BIN_FRACTION = 0.5          # target PMF bin width in units of <s> (rounded to whole s)

_REPO = Path(__file__).resolve().parents[1]

# Per command: base scene, overrides of the command, quick realizations and t_end.
_SPEC = {
    "escapees-time": dict(scene="vani_phi026.toml", fixed=["run.stop_at_clog=false"],
                          quick_realizations=2, quick_t_end=0.5, level_set=False),
    "pmf-collapse": dict(scene="vani_phi026.toml", fixed=["run.stop_at_clog=true"],
                         quick_realizations=3, quick_t_end=0.5, level_set=False),
    "friction": dict(scene="vani_phi026.toml", fixed=["run.stop_at_clog=true"],
                     quick_realizations=3, quick_t_end=0.5, level_set=False),
    "shapes": dict(scene="squares.toml", fixed=["run.stop_at_clog=true", "particles.friction=0.4"],
                   quick_realizations=2, quick_t_end=0.3, level_set=True),
    "polygons": dict(scene="polygons.toml",
                     fixed=["run.stop_at_clog=true", "particles.friction=0.4"],
                     quick_realizations=2, quick_t_end=0.3, level_set=True),
}
_DEFAULT_POINTS = {
    "escapees-time": dict(phi=(0.086, 0.17, 0.26)),
    "pmf-collapse": dict(phi=(0.19, 0.26, 0.32)),
    "friction": dict(mu=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9), phi=0.26),
    "shapes": dict(ratios=(1.7, 1.2)),
    "polygons": dict(vertices=(3, 4, 5, 6), ratio=1.2),
}
_QUICK_POINTS = {
    "friction": dict(mu=(0.1, 0.5, 0.9)),
    "polygons": dict(vertices=(3, 4, 6)),
}


class FigureError(Exception):
    """Invalid arguments or scenes: every problem, one line each."""

    def __init__(self, problems):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("\n".join(self.problems))


# ----------------------------------------------------------------------------- points

@dataclass
class Point:
    """One scene of a figure: ``values`` name it (CSV columns), ``label`` prints it."""
    label: str
    values: dict
    scene: Scene
    overrides: dict = field(default_factory=dict)   # what the point sets on the base scene


@dataclass
class PointRun:
    point: Point
    rows: list = field(default_factory=list)        # one dict per realization
    series: list = field(default_factory=list)      # (seed, t, escapees), stable ones only
    wall: float = 0.0
    info: dict = field(default_factory=dict)
    error: str | None = None
    resumed: bool = False                           # read back from <out>/points/

    @property
    def ok_rows(self):
        return [r for r in self.rows if r["status"] == "ok"]

    def samples(self):
        ok = self.ok_rows
        return (np.array([r["escapees"] for r in ok], dtype=np.int64),
                np.array([bool(r["clogged"]) for r in ok], dtype=bool))


def bounding_diameter(scene: Scene, species: int = 0) -> float:
    """Bounding (circumscribed) diameter ``d_b`` of a species' shape."""
    from ..resolve import species_shape
    return 2.0 * species_shape(scene.particles[species]).bounding_radius


def quick_overrides(scene: Scene, level_set: bool) -> list[str]:
    """What ``--quick`` sets on a base scene (see the module notes)."""
    d_b = bounding_diameter(scene)
    g = scene.geometry
    out = [f"clog.window={QUICK_CLOG_WINDOW}"]
    if g.kind == "converging" and scene.feed.region is None:
        box = QUICK_BOX * d_b
        if box < g.width_in:
            ratio = box * min(box, g.length_in) / (g.width_in * g.length_in)
            out += [f"geometry.width_in={box!r}", f"geometry.length_in={min(box, g.length_in)!r}"]
            for k, sp in enumerate(scene.particles):
                if sp.count is not None:
                    out.append(f"particles.{k}.count={max(2, int(round(sp.count * ratio)))}")
    if level_set:
        out.append(f"fluid.cell_size={d_b / QUICK_CELLS_PER_DB!r}")
    return out


def _default_scene_path(name: str) -> Path:
    for root in (_REPO, Path.cwd()):
        p = root / "scenes" / name
        if p.exists():
            return p
    return _REPO / "scenes" / name


def base_scene(command: str, scene_path=None, quick=False, user_sets=(), t_end=None) -> tuple[Scene, list[str]]:
    """The command's base scene and the overrides that made it (in order)."""
    spec = _SPEC[command]
    path = Path(scene_path) if scene_path else _default_scene_path(spec["scene"])
    raw = load_scene(path)
    overrides = list(spec["fixed"])
    if quick:
        overrides += quick_overrides(raw, spec["level_set"])
        overrides.append(f"run.t_end={spec['quick_t_end']}")
    overrides += list(user_sets)
    return load_scene(path, overrides), overrides


def _with(base: Scene, values: dict) -> Scene:
    return base.with_values(values)


def build_points(command: str, base: Scene, opts: dict) -> list[Point]:
    """The scenes of one figure, every one validated (``SceneError`` otherwise)."""
    pts = []
    if command in ("escapees-time", "pmf-collapse"):
        for phi in opts["phi"]:
            ov = {"particles.packing_fraction": float(phi), "particles.count": None}
            pts.append(Point(f"phi={phi:g}", {"phi": float(phi)}, _with(base, ov), ov))
    elif command == "friction":
        phi = float(opts["phi"])
        for mu in opts["mu"]:
            ov = {"particles.packing_fraction": phi, "particles.count": None,
                  "particles.friction": float(mu)}
            pts.append(Point(f"mu={mu:g}", {"mu": float(mu), "phi": phi}, _with(base, ov), ov))
    elif command == "shapes":
        d_b = bounding_diameter(base)
        base_name = base.particles[0].shape
        circle = {"particles.shape": "circle", "particles.diameter": d_b}
        for key in ("side", "width", "height", "n_vertices", "vertices"):
            circle[f"particles.{key}"] = None
        for ratio in opts["ratios"]:
            w = {"geometry.constriction_width": float(ratio) * d_b}
            for shape, extra in ((base_name, {}), ("circle", circle)):
                ov = {**extra, **w}
                pts.append(Point(f"{shape} W/d_b={ratio:g}",
                                 {"shape": shape, "W_over_db": float(ratio), "d_b": d_b},
                                 _with(base, ov), ov))
    elif command == "polygons":
        d_b = bounding_diameter(base)
        w = {"geometry.constriction_width": float(opts["ratio"]) * d_b}
        clear = {f"particles.{k}": None for k in ("side", "width", "height", "vertices")}
        for nv in opts["vertices"]:
            ov = {**clear, "particles.shape": "regular_polygon", "particles.n_vertices": int(nv),
                  "particles.diameter": d_b, **w}
            pts.append(Point(f"{nv} vertices", {"shape": "regular_polygon", "n_vertices": int(nv),
                                                "W_over_db": float(opts["ratio"]), "d_b": d_b},
                             _with(base, ov), ov))
        if opts.get("circle", True):
            ov = {**clear, "particles.shape": "circle", "particles.n_vertices": None,
                  "particles.diameter": d_b, **w}
            pts.append(Point("circle", {"shape": "circle", "n_vertices": 0,
                                        "W_over_db": float(opts["ratio"]), "d_b": d_b},
                             _with(base, ov), ov))
    else:  # pragma: no cover - argparse limits the choice
        raise ValueError(command)
    return pts


# ----------------------------------------------------------------------------- running

def _point_info(sim) -> dict:
    from ..geometry.walls import fluid_area
    m = sim.model
    sc = sim.scene
    region = m.feed_region
    area = fluid_area(m.geometry, region[0], region[1])
    solid = sum(s.count * s.shape.area for s in m.species)
    return {"n_particles": int(m.n_particles), "d_eq": float(m.species[0].d_eq),
            "d_b": 2.0 * float(m.species[0].shape.bounding_radius),
            "phi_actual": float(solid / area) if area > 0 else math.nan,
            "flow_rate": sc.fluid.flow_rate if sc.fluid.bc == "flow_rate" else None,
            "gap": float(sc.fluid.gap), "dt": float(sim.dt), "t_end": float(sc.run.t_end),
            "contact_path": "disk" if m.all_disks else "level-set"}


def run_point(point: Point, realizations: int, batch: int | None = None, log=None) -> PointRun:
    """Run ``realizations`` of a point in batches of ``batch`` (default: all at once).

    Realization ``k`` has seed ``run.seed + k`` whatever the batching.
    """
    from ..fluid import FluxImbalanceError
    from ..simulation import RunError, Simulation
    out = PointRun(point)
    batch = realizations if not batch else max(1, min(int(batch), realizations))
    seed0 = point.scene.run.seed
    t0 = time.perf_counter()
    done = 0
    while done < realizations:
        n = min(batch, realizations - done)
        scene = point.scene.with_values({"run.realizations": n, "run.seed": seed0 + done})
        try:
            sim = Simulation(scene)
            if not out.info:
                out.info = _point_info(sim)
            res = sim.run()
        except (RunError, FluxImbalanceError) as exc:
            out.error = f"{type(exc).__name__}: {exc}"
            break
        seen = set()
        for r, t, s in res.series:
            key = (r, float(t))
            if key in seen:
                continue
            seen.add(key)
            if res.summary["realizations"][r]["status"] == "ok":
                out.series.append((res.summary["realizations"][r]["seed"], float(t), int(s)))
        for rr in res.summary["realizations"]:
            out.rows.append({k: rr.get(k) for k in ("seed", "escapees", "clogged", "t_clog",
                                                    "t_stop", "status", "reason")})
        del sim, res
        done += n
        if log is not None and done < realizations:
            log(f"  {point.label}: {done}/{realizations} realizations, "
                f"{time.perf_counter() - t0:.0f} s")
    out.wall = time.perf_counter() - t0
    return out


# ----------------------------------------------------------------------------- analysis

def theory_escapees(phi, t, flow_rate, gap, diameter):
    """Escapees of a steady stream, ``4 phi Q t / (H pi d^2)`` (MODEL.md sec. 4)."""
    return 4.0 * np.asarray(phi, dtype=float) * flow_rate * np.asarray(t, dtype=float) / (
        gap * math.pi * diameter ** 2)


def _by_seed(series):
    out = {}
    for seed, t, s in series:
        out.setdefault(seed, []).append((t, s))
    return {k: sorted(v) for k, v in out.items()}


def stream_rate(series, rows) -> dict:
    """Escape rate of the steady stream, pooled over realizations.

    For each stable realization the stream runs from the first sample with an
    escape (``t1``, ``s1``) to the end of the run, or, for a realization that
    clogged, to the first sample at its final count (the last escape). The rate is
    ``sum(s_end - s1) / sum(t_end - t1)``: escapes counted from an escape on, over
    the time they took, so the transit time of the first particles from the control
    volume to the constriction does not enter. Standard error ``sqrt(n) / T``
    (Poisson). Realizations with no escape contribute nothing to the rate and are
    counted in ``n_no_escape``.
    """
    ok = {r["seed"]: r for r in rows if r["status"] == "ok"}
    per = _by_seed([x for x in series if x[0] in ok])
    events, duration, firsts, no_escape = 0, 0.0, [], 0
    for seed, row in ok.items():
        pts = per.get(seed, [])
        idx = next((i for i, (_, s) in enumerate(pts) if s >= 1), None)
        if idx is None:
            no_escape += 1
            continue
        t1, s1 = pts[idx]
        firsts.append(t1)
        if row["clogged"]:
            s_end = max(s for _, s in pts)
            t_end = next(t for t, s in pts if s == s_end)
        else:
            t_end, s_end = pts[-1]
        events += s_end - s1
        duration += t_end - t1
    rate = events / duration if duration > 0 else math.nan
    err = math.sqrt(events) / duration if duration > 0 else math.nan
    return {"rate": rate, "rate_stderr": err, "events": int(events), "duration": duration,
            "t_first_mean": float(np.mean(firsts)) if firsts else math.nan,
            "n_no_escape": no_escape}


def pmf_bins(escapees, clogged, bin_fraction: float = PMF_BIN_FRACTION, max_x=None) -> list[dict]:
    """PMF of ``x = s/<s>`` over the clogged realizations, on bins of whole ``s``.

    ``<s>`` is the censoring-aware fit mean (:func:`taichi_hsdem.stats.fit_geometric`);
    each bin holds ``m = max(1, round(bin_fraction * <s>))`` consecutive values of
    ``s`` (:func:`taichi_hsdem.stats.histogram`), so no bin holds more integers than
    another. Density in ``x``: ``count / (n_clogged * m / <s>)``, at ``x`` = the
    bin's mean ``s`` over ``<s>``; standard error binomial. Empty list when
    ``s/<s>`` is undefined (no clog, or ``<s> = 0``).
    """
    s = np.asarray(escapees, dtype=np.int64)
    c = np.asarray(clogged, dtype=bool)
    if s.size == 0 or not c.any():
        return []
    fit = stats.fit_geometric(s, c)
    mean = fit.mean
    if not (math.isfinite(mean) and mean > 0):
        return []
    m = max(1, int(round(bin_fraction * mean)))
    top = int(s[c].max()) + 1
    if max_x is not None:
        top = max(top, int(math.ceil(max_x * mean)))
    nb = -(-top // m)
    edges = np.arange(0, (nb + 1) * m, m)
    counts, edges = stats.histogram(s, c, bins=edges)
    n = int(c.sum())
    width = m / mean
    out = []
    for j, cnt in enumerate(counts):
        lo, hi = int(edges[j]), int(edges[j + 1])
        out.append({"s_lo": lo, "s_hi": hi - 1, "x": 0.5 * (lo + hi - 1) / mean, "count": int(cnt),
                    "pmf": cnt / (n * width),
                    "stderr": math.sqrt(cnt * (1.0 - cnt / n)) / (n * width),
                    "mean_s": mean, "bin_width_x": width, "n_clogged": n})
    return out


def pmf_lsq_rate(bins: list[dict]) -> float:
    """Slope ``k`` of ``ln(pmf) = a - k x`` over non-empty bins, weighted by count
    (``1`` for an exponential collapse); NaN with fewer than two non-empty bins."""
    pts = [(b["x"], math.log(b["pmf"]), b["count"]) for b in bins if b["count"] > 0]
    if len(pts) < 2:
        return math.nan
    x, y, w = (np.array(v, dtype=float) for v in zip(*pts))
    if np.ptp(x) == 0:
        return math.nan
    slope = np.polyfit(x, y, 1, w=np.sqrt(w))[0]
    return float(-slope)


def point_stats(run: PointRun) -> dict:
    """Censoring-aware statistics of one point (keys of ``points.csv``)."""
    n_unstable = sum(1 for r in run.rows if r["status"] != "ok")
    s, c = run.samples()
    d = {"realizations": len(run.rows), "n_ok": int(s.size), "n_unstable": n_unstable}
    nan2 = (math.nan, math.nan)
    if s.size == 0:
        d.update(n_clogged=0, n_censored=0, mean_s=math.nan, mean_s_lo=math.nan,
                 mean_s_hi=math.nan, mean_method="", observed_mean_s=math.nan,
                 p_clog=math.nan, decay_rate=math.nan, decay_rate_lo=math.nan,
                 decay_rate_hi=math.nan, decay_rate_stderr=math.nan,
                 decay_rate_x=math.nan, pmf_lsq_rate_x=math.nan,
                 never_clogged=math.nan, never_clogged_lo=math.nan, never_clogged_hi=math.nan)
        return d
    fit = stats.fit_geometric(s, c)
    mean, (lo, hi) = stats.mean_escapees(s, c)
    method = stats.summarize(s, c)["mean_escapees_method"]
    never, (nlo, nhi) = stats.never_clogged_fraction(c)
    bins = pmf_bins(s, c)
    d.update(n_clogged=fit.n_clogged, n_censored=fit.n_censored, mean_s=mean,
             mean_s_lo=lo, mean_s_hi=hi, mean_method=method,
             observed_mean_s=float(s.mean()),
             p_clog=fit.p, decay_rate=fit.decay_rate, decay_rate_lo=fit.decay_rate_ci[0],
             decay_rate_hi=fit.decay_rate_ci[1], decay_rate_stderr=fit.decay_rate_stderr,
             decay_rate_x=fit.decay_rate * fit.mean if math.isfinite(fit.mean) else math.nan,
             pmf_lsq_rate_x=pmf_lsq_rate(bins),
             never_clogged=never, never_clogged_lo=nlo, never_clogged_hi=nhi)
    return d


# ----------------------------------------------------------------------------- output

def _fmt(v):
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return "1" if v else "0"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v)) if math.isfinite(v) else ("nan" if math.isnan(v) else
                                                        ("inf" if v > 0 else "-inf"))
    return str(v)


def _jsonable(obj):
    """Plain JSON: numpy to Python, NaN and inf to None, anything else to str."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)) or obj is None or isinstance(obj, str):
        return bool(obj) if isinstance(obj, np.bool_) else obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return str(obj)


def write_csv(path: Path, rows: list[dict], columns=None):
    if columns is None:
        columns = []
        for r in rows:
            for k in r:
                if k not in columns:
                    columns.append(k)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        for r in rows:
            w.writerow([_fmt(r.get(k)) for k in columns])
    tmp.replace(path)


def _interval_text(mean, lo, hi):
    def f(v):
        return "inf" if not math.isfinite(v) else f"{v:.3g}"
    return f"{f(mean)} [{f(lo)}, {f(hi)}]"


def summary_line(command: str, run: PointRun, row: dict) -> str:
    p = run.point
    if run.error:
        return f"{p.label}: FAILED ({run.error}), {run.wall:.1f} s"
    head = (f"{p.label}: {row['n_particles']} particles, {row['n_ok']}/{row['realizations']} "
            f"stable ({row['n_clogged']} clogged, {row['n_censored']} censored)")
    if command == "escapees-time":
        return (f"{head}, first escape at {row['t_first_mean']:.3g} s (mean), rate "
                f"{row['rate']:.3g} +- {row['rate_stderr']:.2g} /s vs theory "
                f"{row['theory_rate']:.3g} /s (ratio {row['rate_ratio']:.2f}), {run.wall:.1f} s"
                f"{_kept(run)}")
    return (f"{head}, <s> = {_interval_text(row['mean_s'], row['mean_s_lo'], row['mean_s_hi'])}, "
            f"lambda = {_interval_text(row['decay_rate'], row['decay_rate_lo'], row['decay_rate_hi'])}"
            f" /escapee, {run.wall:.1f} s{_kept(run)}")


def _kept(run: PointRun) -> str:
    return " (finished earlier, read back)" if run.resumed else ""


# ----------------------------------------------------------------------------- plots

def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _err_mean(rows):
    """Means and asymmetric error bars with infinite ends drawn as arrows."""
    y = np.array([r["mean_s"] for r in rows], dtype=float)
    lo = np.array([r["mean_s_lo"] for r in rows], dtype=float)
    hi = np.array([r["mean_s_hi"] for r in rows], dtype=float)
    obs = np.array([r["observed_mean_s"] for r in rows], dtype=float)
    unbounded = ~np.isfinite(y)
    # no clog at all: plot the observed mean, a lower bound
    y = np.where(unbounded, obs, y)
    finite_hi = hi[np.isfinite(hi)]
    cap = (np.nanmax(np.concatenate([finite_hi, y[np.isfinite(y)]])) * 1.5
           if np.isfinite(y).any() else 1.0)
    hi_open = ~np.isfinite(hi)
    hi = np.where(hi_open, np.maximum(cap, y), hi)
    lo = np.where(np.isfinite(lo), lo, y)
    return y, np.vstack([np.clip(y - lo, 0, None), np.clip(hi - y, 0, None)]), hi_open


def _pmf_panel(ax, groups, title="PMF of s/<s>"):
    """``groups``: [(label, bins)]; semilog, exp(-x) for reference."""
    xmax = 1.0
    for label, bins in groups:
        b = [x for x in bins if x["count"] > 0]
        if not b:
            continue
        x = np.array([v["x"] for v in b])
        xmax = max(xmax, float(x.max()))
        ax.errorbar(x, [v["pmf"] for v in b], yerr=[v["stderr"] for v in b], fmt="o",
                    ms=4, capsize=2, label=label)
    xs = np.linspace(0, max(xmax, 3.0), 100)
    ax.plot(xs, np.exp(-xs), "k--", lw=1, label="exp(-x)")
    ax.set_yscale("log")
    ax.set_xlabel("x = s / <s>")
    ax.set_ylabel("PMF (density in x)")
    ax.set_title(title)
    ax.legend(fontsize=7)


def _finish(plt, fig, path, meta):
    """Footer line ``meta``, layout, write ``path``, free the figure."""
    fig.text(0.01, 0.005, meta, fontsize=6, color="0.4", ha="left", va="bottom")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_escapees_time(runs, rows, path: Path, meta: str):
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    t_max = 0.0
    for k, (run, row) in enumerate(zip(runs, rows)):
        if run.error or not run.series:
            continue
        col = colors[k % len(colors)]
        per = _by_seed(run.series)
        for seed, pts in per.items():
            t, s = zip(*pts)
            a1.step(t, s, where="post", color=col, alpha=0.25, lw=0.8)
            t_max = max(t_max, max(t))
        # mean over realizations on the common sample times (a realization that
        # stopped keeps its last count)
        times = np.array(sorted({t for pts in per.values() for t, _ in pts}))
        means = np.zeros(times.size)
        for pts in per.values():
            t, s = (np.array(v, dtype=float) for v in zip(*pts))
            i = np.searchsorted(t, times + 1e-12, side="right") - 1
            means += np.where(i >= 0, s[np.clip(i, 0, None)], 0.0)
        means /= len(per)
        a1.plot(times, means, color=col, lw=2, label=f"phi = {run.point.values['phi']:g} (mean)")
        tt = np.linspace(0, max(times), 50)
        th = theory_escapees(run.point.values["phi"], tt, row["flow_rate"], row["gap"], row["d_eq"])
        a1.plot(tt, th, "--", color=col, lw=1)
        t1 = row["t_first_mean"]
        if math.isfinite(t1):
            ts = np.linspace(t1, max(times), 20)
            a1.plot(ts, theory_escapees(run.point.values["phi"], ts - t1, row["flow_rate"],
                                        row["gap"], row["d_eq"]), ":", color=col, lw=1)
    a1.set_xlabel("t (s)")
    a1.set_ylabel("escapees s")
    a1.set_title("escapees over time; -- 4 phi Q t/(H pi d^2), : same from first escape")
    a1.title.set_fontsize(8)
    a1.legend(fontsize=7)
    phis = np.array([r["phi"] for r in rows])
    ok = [i for i, r in enumerate(rows) if math.isfinite(r["rate"])]
    if ok:
        a2.errorbar(phis[ok], [rows[i]["rate"] for i in ok],
                    yerr=[rows[i]["rate_stderr"] for i in ok], fmt="o", capsize=3,
                    label="fitted (from first escape)")
    pp = np.linspace(0, max(phis.max(), 0.01) * 1.1, 50)
    r0 = rows[0]
    a2.plot(pp, theory_escapees(pp, 1.0, r0["flow_rate"], r0["gap"], r0["d_eq"]), "k--",
            label="4 phi Q / (H pi d^2)")
    a2.set_xlabel("packing fraction phi")
    a2.set_ylabel("escape rate (1/s)")
    a2.set_title("steady escape rate")
    a2.legend(fontsize=7)
    _finish(plt, fig, path, meta)


def plot_pmf_collapse(runs, rows, pmfs, path: Path, meta: str):
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    for run, row in zip(runs, rows):
        s, c = run.samples()
        if s.size == 0:
            continue
        counts, edges = stats.histogram(s, c)
        lab = (f"phi = {run.point.values['phi']:g} ({row['n_clogged']} clogged, "
               f"{row['n_censored']} censored)")
        if counts.size and counts.sum():
            a1.stairs(counts, edges, label=lab, lw=1.5)
        else:
            a1.plot([], [], label=lab)
    a1.set_xlabel("escapees before clogging s")
    a1.set_ylabel("realizations")
    a1.set_title("histogram of s (clogged realizations)")
    a1.legend(fontsize=7)
    _pmf_panel(a2, [(f"phi = {r.point.values['phi']:g}", pmfs[i]) for i, r in enumerate(runs)])
    _finish(plt, fig, path, meta)


def _mean_decay_panels(a1, a2, x, rows, xlabel, labels=None, xticks=None, series_label=None):
    y, yerr, open_hi = _err_mean(rows)
    a1.errorbar(x, y, yerr=yerr, fmt="o-", capsize=3, label=series_label)
    if open_hi.any():
        a1.plot(np.asarray(x)[open_hi], yerr[1][open_hi] + y[open_hi], "^", color="0.3", ms=5,
                label="interval open above" if not a1.get_legend_handles_labels()[1].count(
                    "interval open above") else None)
    if np.all(y[np.isfinite(y)] > 0) and np.isfinite(y).any():
        a1.set_yscale("log")
    a1.set_xlabel(xlabel)
    a1.set_ylabel("<s> (escapees before clogging)")
    lam = np.array([r["decay_rate"] for r in rows], dtype=float)
    lo = np.array([r["decay_rate_lo"] for r in rows], dtype=float)
    hi = np.array([r["decay_rate_hi"] for r in rows], dtype=float)
    fin = np.isfinite(lam) & np.isfinite(hi)
    if fin.any():
        xa = np.asarray(x, dtype=float)[fin]
        a2.errorbar(xa, lam[fin], yerr=[np.clip(lam[fin] - lo[fin], 0, None),
                                        np.clip(hi[fin] - lam[fin], 0, None)],
                    fmt="s-", capsize=3, label=series_label)
    a2.set_xlabel(xlabel)
    a2.set_ylabel("decay rate lambda of P(s) ~ exp(-lambda s)")
    for a in (a1, a2):
        if xticks is not None:
            a.set_xticks(xticks)
            a.set_xticklabels(labels)


def plot_friction(runs, rows, path: Path, meta: str):
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    _mean_decay_panels(a1, a2, [r["mu"] for r in rows], rows, "friction mu")
    a1.set_title(f"<s> vs friction at phi = {rows[0]['phi']:g} (95 % CI)")
    a2.set_title("decay rates (95 % CI)")
    _finish(plt, fig, path, meta)


def plot_shapes(runs, rows, pmfs, path: Path, meta: str):
    plt = _plt()
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(14, 4.4))
    shapes_ = list(dict.fromkeys(r["shape"] for r in rows))
    for j, shape in enumerate(shapes_):
        sel = [i for i, r in enumerate(rows) if r["shape"] == shape]
        dodge = 0.01 * (j - 0.5 * (len(shapes_) - 1))      # keep equal points apart
        _mean_decay_panels(a1, a2, [rows[i]["W_over_db"] + dodge for i in sel],
                           [rows[i] for i in sel], "W / d_b", series_label=shape)
    ratios = sorted({r["W_over_db"] for r in rows})
    for a in (a1, a2):
        a.set_xticks(ratios)
        a.set_xlim(min(ratios) - 0.15, max(ratios) + 0.15)
    a1.set_title("<s> (95 % CI)")
    a2.set_title("decay rates (95 % CI)")
    a1.legend(fontsize=7)
    a2.legend(fontsize=7)
    _pmf_panel(a3, [(r.point.label, pmfs[i]) for i, r in enumerate(runs)])
    _finish(plt, fig, path, meta)


def plot_polygons(runs, rows, pmfs, path: Path, meta: str):
    plt = _plt()
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(14, 4.4))
    nv = [r["n_vertices"] for r in rows]
    poly = [v for v in nv if v > 0]
    circ_x = (max(poly) + 1.5) if poly else 1.0
    x = [v if v > 0 else circ_x for v in nv]
    labels = [str(v) if v > 0 else "circle" for v in nv]
    _mean_decay_panels(a1, a2, x, rows, "vertices", labels=labels, xticks=x)
    a1.set_title(f"<s> vs vertex count, W/d_b = {rows[0]['W_over_db']:g} (95 % CI)")
    a2.set_title("decay rates (95 % CI)")
    _pmf_panel(a3, [(r.point.label, pmfs[i]) for i, r in enumerate(runs)])
    _finish(plt, fig, path, meta)


def render(command: str, runs, rows, pmfs, path: Path, meta: str = ""):
    """Draw one figure from its point runs, ``points.csv`` rows and PMF bins."""
    if command == "escapees-time":
        plot_escapees_time(runs, rows, path, meta)
    elif command == "pmf-collapse":
        plot_pmf_collapse(runs, rows, pmfs, path, meta)
    elif command == "friction":
        plot_friction(runs, rows, path, meta)
    elif command == "shapes":
        plot_shapes(runs, rows, pmfs, path, meta)
    elif command == "polygons":
        plot_polygons(runs, rows, pmfs, path, meta)
    else:
        raise ValueError(f"unknown figure {command!r}")


# ----------------------------------------------------------------------------- driver

def _point_row(command: str, run: PointRun) -> dict:
    row = {"label": run.point.label, **run.point.values}
    info = dict(run.info)
    row.update({k: info.get(k, math.nan) for k in ("n_particles", "phi_actual", "d_eq", "d_b",
                                                     "flow_rate", "gap", "t_end", "dt")})
    row["contact_path"] = info.get("contact_path", "")
    row.update(point_stats(run))
    if command == "escapees-time":
        sr = stream_rate(run.series, run.rows)
        row.update(sr)
        phi = run.point.values["phi"]
        if row["flow_rate"] and math.isfinite(row["d_eq"]):
            row["theory_rate"] = float(theory_escapees(phi, 1.0, row["flow_rate"], row["gap"],
                                                       row["d_eq"]))
            row["theory_rate_phi_actual"] = float(theory_escapees(
                row["phi_actual"], 1.0, row["flow_rate"], row["gap"], row["d_eq"]))
        else:
            row["theory_rate"] = row["theory_rate_phi_actual"] = math.nan
        row["rate_ratio"] = (sr["rate"] / row["theory_rate"]
                             if row["theory_rate"] and math.isfinite(row["theory_rate"])
                             else math.nan)
    row["wall_s"] = run.wall
    row["error"] = run.error or ""
    return row


def _point_key(point: Point, realizations: int) -> str:
    """What makes a finished point reusable: its scene (TOML text, seeds included),
    the realization count and the package code (:func:`taichi_hsdem.sweep.code_digest`).
    The batch size is left out: a realization does not depend on those beside it."""
    from ..scene import scene_to_toml
    from .sweep import code_digest
    text = (scene_to_toml(point.scene) + f"\n# realizations {int(realizations)}"
            f"\n# code {code_digest()}")
    return hashlib.sha256(text.encode()).hexdigest()


def point_file(out: Path, point: Point) -> Path:
    """Where a finished point is kept: ``<out>/points/<label>.json``."""
    return Path(out) / "points" / (re.sub(r"[^A-Za-z0-9._=+-]+", "_", point.label) + ".json")


def _save_point(path: Path, key: str, run: PointRun) -> None:
    data = {"key": key, "label": run.point.label, "wall_s": run.wall, "info": run.info,
            "rows": run.rows, "series": [list(x) for x in run.series]}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps(_jsonable(data)) + "\n")
    tmp.replace(path)


_ROW_KEYS = ("seed", "escapees", "clogged", "t_clog", "t_stop", "status", "reason")


def _load_point(path: Path, key: str, point: Point) -> PointRun | None:
    """The finished run of ``point`` kept at ``path``, or None (absent, unreadable,
    malformed, or of another scene, realization count or code)."""
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict) or data.get("key") != key:
            return None
        rows = data["rows"]
        if not all(isinstance(r, dict) and all(k in r for k in _ROW_KEYS) for r in rows):
            return None
        return PointRun(point, rows=list(rows),
                        series=[(int(a), float(b), int(c)) for a, b, c in data["series"]],
                        wall=float(data["wall_s"]), info=dict(data["info"]), resumed=True)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def _opts_from_args(command, args) -> dict:
    opts = {}
    for key in ("phi", "mu", "ratios", "vertices", "ratio"):
        v = getattr(args, key, None)
        if v is not None:
            opts[key] = v
    if getattr(args, "no_circle", False):
        opts["circle"] = False
    return opts


def run_figure(command: str, *, quick=False, realizations=None, out=None, sets=(),
               scene=None, seed=None, batch=None, opts=None, log=None, argv=None,
               resume=True) -> dict:
    """Run one figure; returns ``{"out", "files", "points", "runs"}``.

    Every finished point is kept in ``<out>/points/``; with ``resume`` a point kept
    there from the same scene, realization count and code is read back instead of
    run again, so an interrupted figure restarts where it stopped.

    Raises :class:`FigureError` for invalid scenes or arguments before anything runs.
    """
    if command not in _SPEC:
        raise FigureError(f"unknown figure {command!r}; choose from {', '.join(FIGURES)}")
    try:
        _plt()
    except ImportError:
        raise FigureError("matplotlib is needed for the figures: pip install 'taichi_hsdem[plot]'") \
            from None
    if realizations is None:
        realizations = _SPEC[command]["quick_realizations"] if quick else DEFAULT_REALIZATIONS
    if int(realizations) < 1:
        raise FigureError(f"--realizations must be >= 1, got {realizations}")
    sets = list(sets)
    if seed is not None:
        sets.append(f"run.seed={int(seed)}")
    merged = dict(_DEFAULT_POINTS[command])
    if quick:
        merged.update(_QUICK_POINTS.get(command, {}))
    merged.update(opts or {})
    opts = merged
    try:
        base, overrides = base_scene(command, scene, quick, sets)
        if command == "escapees-time" and base.fluid.bc != "flow_rate":
            raise FigureError(f"{base.source}: fluid.bc: escapees-time needs a flow-rate inlet "
                              f"(the theory line uses Q = fluid.flow_rate)")
        points = build_points(command, base, opts)
        from ..resolve import resolve
        for p in points:       # refuse impossible set-ups before any compute
            resolve(p.scene.with_values({"run.realizations": 1}))
    except SceneError as exc:
        raise FigureError(exc.problems) from None
    out = Path(out) if out else Path("runs") / "figures" / command
    kept_files = [point_file(out, p) for p in points]
    owner = {}
    for p, path in zip(points, kept_files):
        if path.name in owner:
            raise FigureError(f"points {owner[path.name]!r} and {p.label!r} would share "
                              f"{path.name}: give distinct values")
        owner[path.name] = p.label
    out.mkdir(parents=True, exist_ok=True)
    from .sweep import code_digest
    code_digest()                  # this process's code, before any point runs
    say = log or (lambda msg: None)
    say(f"{command}: {len(points)} point(s) x {realizations} realization(s), t_end = "
        f"{base.run.t_end:g} s{' (quick)' if quick else ''} -> {out}")
    t0 = time.perf_counter()
    runs, rows = [], []
    for k, (p, path) in enumerate(zip(points, kept_files)):
        key = _point_key(p, realizations)
        kept = _load_point(path, key, p) if resume else None
        if kept is not None:
            say(f"[{k + 1}/{len(points)}] {p.label}: finished earlier, read from {path}")
            run = kept
        else:
            say(f"[{k + 1}/{len(points)}] {p.label} ...")
            run = run_point(p, int(realizations), batch, log=say)
            if not run.error:
                _save_point(path, key, run)
        row = _point_row(command, run)
        runs.append(run)
        rows.append(row)
        print(summary_line(command, run, row), flush=True)
    wall = time.perf_counter() - t0

    files = []
    real_rows = []
    for run in runs:
        for r in run.rows:
            real_rows.append({"label": run.point.label, **run.point.values, **r})
    write_csv(out / "realizations.csv", real_rows,
              ["label", *points[0].values.keys(), "seed", "escapees", "clogged", "t_clog",
               "t_stop", "status", "reason"])
    files.append(out / "realizations.csv")
    write_csv(out / "points.csv", rows)
    files.append(out / "points.csv")
    meta = (f"taichi_hsdem figures {command}: {realizations} realization(s)/point, t_end "
            f"{base.run.t_end:g} s{', QUICK (not the paper statistics)' if quick else ''}")
    png = out / f"{command}.png"
    pmfs = []
    if command != "escapees-time":
        pmf_rows = []
        for run in runs:
            s, c = run.samples()
            bins = pmf_bins(s, c) if s.size else []
            pmfs.append(bins)
            for b in bins:
                pmf_rows.append({"label": run.point.label, **run.point.values, **b})
        write_csv(out / "pmf.csv", pmf_rows,
                  ["label", *points[0].values.keys(), "x", "pmf", "stderr", "count", "s_lo",
                   "s_hi", "mean_s", "bin_width_x", "n_clogged"])
        files.append(out / "pmf.csv")
    if command == "escapees-time":
        srows = []
        for run, row in zip(runs, rows):
            phi = run.point.values["phi"]
            for seed_, t, s in sorted(run.series):
                srows.append({"phi": phi, "seed": seed_, "t": t, "escapees": s,
                              "theory_escapees": float(theory_escapees(
                                  phi, t, row["flow_rate"], row["gap"], row["d_eq"]))})
        write_csv(out / "series.csv", srows, ["phi", "seed", "t", "escapees", "theory_escapees"])
        files.append(out / "series.csv")
    render(command, runs, rows, pmfs, png, meta)
    files.append(png)
    info = {"figure": command, "argv": list(argv) if argv is not None else None,
            "quick": bool(quick), "realizations_per_point": int(realizations),
            "scene": base.source, "t_end": base.run.t_end, "base_overrides": overrides,
            "wall_time_s": wall,
            "points": [{"label": r.point.label, "values": r.point.values,
                        "overrides": {k: v for k, v in r.point.overrides.items()},
                        "wall_s": r.wall, "error": r.error, "info": r.info,
                        "resumed": r.resumed} for r in runs]}
    tmp = out / "figure.json.part"
    tmp.write_text(json.dumps(_jsonable(info), indent=1, allow_nan=False) + "\n")
    tmp.replace(out / "figure.json")
    files.append(out / "figure.json")
    print(f"wrote {out}/: " + ", ".join(f.name for f in files) + f" ({wall:.1f} s)", flush=True)
    return {"out": out, "files": files, "points": rows, "runs": runs}


def _parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quick", action="store_true",
                        help="tiny run for CI: few realizations, short t_end, small upstream "
                             "box (not the paper's statistics)")
    common.add_argument("--realizations", type=int, metavar="N",
                        help=f"realizations per point (default {DEFAULT_REALIZATIONS}, "
                             f"--quick 2-3; the paper: {PAPER_REALIZATIONS})")
    common.add_argument("--out", metavar="DIR", help="output folder (default runs/figures/<figure>/)")
    common.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override a scene scalar (repeatable), as in python -m taichi_hsdem")
    common.add_argument("--scene", metavar="TOML", help="base scene instead of the shipped one")
    common.add_argument("--seed", type=int, metavar="S", help="seed of realization 0 (run.seed)")
    common.add_argument("--batch", type=int, metavar="B",
                        help="realizations run together per simulation (default: all)")
    common.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    common.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                        help="read back points finished earlier in --out/points/ (same "
                             "scene, realizations and code) instead of running them again "
                             "(default: --resume)")
    p = argparse.ArgumentParser(prog="python tools/figures.py",
                                description="The clogging figures of Zhou et al. (2024), "
                                            "Figs. 8-13: PNG, CSV of the numbers, figure.json.")
    sub = p.add_subparsers(dest="figure", required=True, metavar="FIGURE")
    s = sub.add_parser("escapees-time", parents=[common], help="Fig. 8: escapees over time vs "
                       "4 phi Q t/(H pi d^2)")
    s.add_argument("--phi", type=float, nargs="+", help="packing fractions (default 0.086 0.17 0.26)")
    s = sub.add_parser("pmf-collapse", parents=[common], help="Fig. 9: PMF of s/<s> vs exp(-x)")
    s.add_argument("--phi", type=float, nargs="+", help="packing fractions (default 0.19 0.26 0.32)")
    s = sub.add_parser("friction", parents=[common], help="Fig. 10: <s> vs friction")
    s.add_argument("--mu", type=float, nargs="+", help="frictions (default 0.1 ... 0.9; "
                   "--quick 0.1 0.5 0.9)")
    s.add_argument("--phi", type=float, help="packing fraction (default 0.26)")
    s = sub.add_parser("shapes", parents=[common], help="Figs. 11-12: squares vs circles")
    s.add_argument("--ratios", type=float, nargs="+", help="W/d_b (default 1.7 1.2)")
    s = sub.add_parser("polygons", parents=[common], help="Fig. 13: <s> vs vertex count")
    s.add_argument("--vertices", type=int, nargs="+", help="vertex counts (default 3 4 5 6; "
                   "--quick 3 4 6)")
    s.add_argument("--ratio", type=float, help="W/d_b (default 1.2)")
    s.add_argument("--no-circle", action="store_true", help="leave out the circles")
    return p


def main(argv=None) -> int:
    """Command line; exit 0 on success, 1 when a point failed, 2 for invalid input."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)

    def log(msg):
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    try:
        res = run_figure(args.figure, quick=args.quick, realizations=args.realizations,
                         out=args.out, sets=args.set, scene=args.scene, seed=args.seed,
                         batch=args.batch, opts=_opts_from_args(args.figure, args), log=log,
                         argv=argv, resume=args.resume)
    except FigureError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return 2
    return 1 if any(r.error for r in res["runs"]) else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
