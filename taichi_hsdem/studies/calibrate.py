"""Calibration: tune one parameter until the mean escapees before clogging ``<s>``
match a target.

:func:`calibrate` brackets, then applies regula falsi on ``log <s>`` (Illinois
variant), each round one batch of realizations at one value. Its interval is the
parameter range over which the target lies inside the (censoring-aware)
confidence interval of ``<s>``; the value is the root of a censoring-aware fit of
``log <s>`` linear in the parameter over that range (see :func:`calibrate`).
:func:`simulation_evaluator` makes the ``evaluate(value)`` that runs a scene.

Command line (``python tools/calibrate.py`` is the same)::

    python -m taichi_hsdem calibrate SCENE.toml --target 20 [--param particles.friction]
        --lo 0.1 --hi 0.9 [--realizations 20] [--rounds 8] [--xtol X]
        [--confidence 0.95] [--seed S] [--set section.key=value ...] [--out DIR]
        [--quick] [--quiet]

Each round runs one batch of ``--realizations`` realizations at one value of
``--param`` (fresh seeds every round, so the rounds are independent samples); the
rounds bracket the target and close in on it by regula falsi on ``log <s>``
(:func:`taichi_hsdem.studies.calibrate.calibrate`; ``<s>`` usually falls with friction, but
either direction works). The result is the calibrated value and the range of the
parameter over which the target lies inside the confidence interval of ``<s>``
(censoring-aware, :mod:`taichi_hsdem.stats`).

Writes ``DIR/calibration.csv`` (one row per evaluation, appended as it finishes)
and ``DIR/calibration.json`` (the result, every evaluation's counts), ``DIR``
defaulting to ``runs/calibrate_<scene name>/``. ``--quick`` is a smoke test: 4
realizations, 3 rounds, each realization to the scene's ``run.t_end`` (a shorter
run would stop before the first clogs).

Exit status: 0 calibrated (interval bounded inside the range; narrower than
``--xtol`` when given); 1 not bracketed, interval open, or a run failed (the
evaluations so far are written); 2 invalid scene or arguments.
"""
from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
from scipy import optimize

from .. import stats
from ..scene import load_scene
from ..scene.toml import toml_value
from . import fmt
from .progress import PointProgress
from ..exits import EXIT_FAILED, EXIT_INVALID, EXIT_OK, Parser, folder_name
from ..stop import raise_if_swallowed

__all__ = ["CalibrationError", "Evaluation", "Calibration", "calibrate", "simulation_evaluator"]


class CalibrationError(RuntimeError):
    """An evaluation gave nothing to calibrate on (message says what to change)."""


@dataclass(frozen=True)
class Evaluation:
    """One batch of realizations at one parameter value, and its statistics."""

    value: float
    escapees: tuple
    clogged: tuple
    mean: float              # <s>, censoring-aware (stats.mean_escapees)
    mean_ci: tuple
    n_clogged: int
    info: dict = field(default_factory=dict)   # what the evaluator reported besides

    @property
    def n(self) -> int:
        return len(self.escapees)

    @property
    def total(self) -> int:
        return int(sum(self.escapees))


@dataclass(frozen=True)
class Calibration:
    """The result of :func:`calibrate`.

    ``value`` is the calibrated parameter (NaN when the target was not
    bracketed) and ``ci`` the parameter range over which the target lies inside
    the ``confidence`` interval of ``<s>`` (interpolated between evaluations); an
    end flagged in ``ci_open`` lies at an evaluation whose interval still holds
    the target, so the data do not bound it on that side. ``window`` is the range
    of the evaluations whose pooled fit gave ``value``, and ``slope`` that fit's
    ``d log<s> / d param``.
    """

    target: float
    value: float
    ci: tuple
    ci_open: tuple
    confidence: float
    bracketed: bool
    converged: bool
    lo: float
    hi: float
    window: tuple
    slope: float
    evaluations: tuple
    message: str

    def to_dict(self) -> dict:
        """JSON-ready (non-finite numbers as None)."""
        def plain(v):
            if isinstance(v, (np.integer, np.floating, np.bool_)):
                v = v.item()
            if isinstance(v, float):
                return v if math.isfinite(v) else None
            if isinstance(v, (list, tuple)):
                return [plain(x) for x in v]
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            return v
        return plain({
            "target": self.target, "value": self.value, "ci": list(self.ci),
            "ci_open": list(self.ci_open), "confidence": self.confidence,
            "bracketed": self.bracketed, "converged": self.converged,
            "lo": self.lo, "hi": self.hi, "window": list(self.window),
            "slope_dlog_mean_dparam": self.slope, "message": self.message,
            "method": "ci: parameter range where the target lies inside the "
                      "interpolated confidence interval of <s>; value: root of log<s> "
                      "linear in the parameter, censoring-aware geometric likelihood "
                      "pooled over the window",
            "evaluations": [{"value": e.value, "n": e.n, "n_clogged": e.n_clogged,
                             "mean_escapees": e.mean, "mean_escapees_ci": list(e.mean_ci),
                             "escapees": list(e.escapees), "clogged": list(e.clogged),
                             **e.info} for e in self.evaluations]})


def _evaluation(value: float, escapees, clogged, confidence: float,
                info: dict | None = None) -> Evaluation:
    if len(escapees) == 0:
        raise CalibrationError(f"no stable realization at {value!r}: nothing to "
                               f"calibrate on (lower run.dt or raise the realizations)")
    s = np.asarray(escapees, dtype=np.int64)
    c = np.asarray(clogged, dtype=bool)
    mean, ci = stats.mean_escapees(s, c, confidence)
    if math.isnan(mean):
        raise CalibrationError(
            f"at {value!r} nothing escaped and nothing clogged in {s.size} "
            f"realization(s): <s> is undefined; run longer (run.t_end)")
    return Evaluation(value=float(value), escapees=tuple(int(v) for v in s),
                      clogged=tuple(bool(v) for v in c), mean=float(mean),
                      mean_ci=(float(ci[0]), float(ci[1])), n_clogged=int(c.sum()),
                      info=dict(info or {}))


def _log_gap(e: Evaluation, target: float) -> float:
    """``log <s> - log target``: the function whose root is calibrated (+inf when
    nothing clogged, -inf when every realization clogged at s = 0)."""
    if e.mean == math.inf:
        return math.inf
    if e.mean <= 0.0:
        return -math.inf
    return math.log(e.mean) - math.log(target)


def _merged(evals: Sequence[Evaluation], confidence: float) -> list[Evaluation]:
    """One evaluation per distinct value (batches at the same value pooled), sorted."""
    groups: dict[float, list[Evaluation]] = {}
    for e in evals:
        groups.setdefault(e.value, []).append(e)
    return [g[0] if len(g) == 1 else
            _evaluation(x, sum((e.escapees for e in g), ()), sum((e.clogged for e in g), ()),
                        confidence)
            for x, g in sorted(groups.items())]


def _band_interval(evals: list[Evaluation], target: float):
    """Hull of the parameter values where ``target`` lies between the lower and
    upper confidence bounds of ``<s>``, each interpolated linearly in log between
    neighbouring evaluations (``evals`` sorted, one per value). A bound of 0 or
    infinity holds over the whole segment next to it. Returns ((lo, hi),
    (open_lo, open_hi)), or None when no value qualifies."""
    big = 1e6   # stands for log(0) and log(inf): the crossing then sits at the other end
    lt = math.log(target)
    x = [e.value for e in evals]
    low = [lt - big if e.mean_ci[0] <= 0 else math.log(e.mean_ci[0]) for e in evals]
    up = [lt + big if e.mean_ci[1] == math.inf else
          (lt - big if e.mean_ci[1] <= 0 else math.log(e.mean_ci[1])) for e in evals]

    def part(a0, a1, below):
        """The t in [0, 1] with a0 + t (a1 - a0) <= lt (below) or >= lt."""
        d = a1 - a0
        if d == 0.0:
            ok = a0 <= lt if below else a0 >= lt
            return (0.0, 1.0) if ok else None
        t = (lt - a0) / d
        keep_low = (d > 0) == below   # the side of t that satisfies the inequality
        lo_t, hi_t = (0.0, min(1.0, t)) if keep_low else (max(0.0, t), 1.0)
        return (lo_t, hi_t) if lo_t <= hi_t else None

    inside = []
    for i in range(len(evals)):
        if low[i] <= lt <= up[i]:
            inside.append(x[i])
    for i in range(len(evals) - 1):
        a = part(low[i], low[i + 1], True)
        b = part(up[i], up[i + 1], False)
        if a and b and max(a[0], b[0]) <= min(a[1], b[1]):
            t0, t1 = max(a[0], b[0]), min(a[1], b[1])
            inside += [x[i] + t0 * (x[i + 1] - x[i]), x[i] + t1 * (x[i + 1] - x[i])]
    if not inside:
        return None
    open_lo = min(inside) <= x[0] and low[0] <= lt <= up[0]
    open_hi = max(inside) >= x[-1] and low[-1] <= lt <= up[-1]
    return (min(inside), max(inside)), (bool(open_lo), bool(open_hi))


def _pooled_root(evals: list[Evaluation], target: float) -> tuple[float, float]:
    """Root of ``log <s> = a + b x`` fitted by maximum likelihood to the pooled
    evaluations (a clogged realization contributes ``(1 - p)^s p``, a censored
    one ``(1 - p)^s``, ``p = 1/(1 + <s>)``, as in :mod:`taichi_hsdem.stats`);
    returns (root, b)."""

    x = np.array([e.value for e in evals])
    k = np.array([e.n_clogged for e in evals], dtype=float)
    total = np.array([e.total for e in evals], dtype=float)
    x0, span = float(x.mean()), float(np.ptp(x))
    u = (x - x0) / span

    def nll(params):
        eta = params[0] + params[1] * u          # log <s>
        return -float(np.sum(total * eta - (k + total) * np.logaddexp(0.0, eta)))

    def grad(params):
        eta = params[0] + params[1] * u
        g = total - (k + total) / (1.0 + np.exp(-eta))
        return -np.array([g.sum(), (g * u).sum()])

    finite = [math.log(e.mean) for e in evals if 0.0 < e.mean < math.inf]
    start = np.array([float(np.mean(finite)) if finite else math.log(target), 0.0])
    # Bounded: an end with no clog (or only s = 0) pulls log<s> to +-infinity.
    best = optimize.minimize(nll, start, jac=grad, method="L-BFGS-B",
                             bounds=[(-50.0, 50.0), (-100.0, 100.0)])
    a, b = best.x
    root = x0 + span * (math.log(target) - a) / b if b != 0.0 else math.nan
    return root, b / span


def calibrate(evaluate: Callable[[float], tuple], target: float, lo: float, hi: float,
              rounds: int = 8, xtol: float = 0.0, confidence: float = 0.95,
              log: Callable[[str], None] | None = None) -> Calibration:
    """Find the parameter value at which the mean escapees ``<s>`` equal ``target``.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(value) -> (escapees, clogged)`` (optionally a third item, a dict
        recorded with the evaluation): one batch of independent realizations at
        ``value``, escapee counts and clog flags (``False``: censored at the end
        time).
    target : float
        The ``<s>`` to match, > 0.
    lo, hi : float
        The parameter range; ``<s>`` must cross the target inside it (in either
        direction: it usually falls with friction).
    rounds : int
        Evaluations in all, the two ends included (>= 2).
    xtol : float
        Stop early once the interval of the calibrated value is closed and
        narrower than this (0: run every round).
    confidence : float
        Level of every interval.
    log : callable, optional
        Called with one line per evaluation.

    Returns
    -------
    Calibration

    Notes
    -----
    The ends are evaluated first; if ``log <s> - log target`` has the same sign
    at both, the target is not bracketed and the result says so. Otherwise each
    round evaluates the regula falsi point of ``log <s>`` between the bracket's
    ends (Illinois variant, kept within the middle 80 % of the bracket; bisection
    while an end has no clog at all) and keeps the sub-bracket that still
    crosses.

    The interval is the range of the parameter over which the target lies inside
    the confidence interval of ``<s>`` (:func:`taichi_hsdem.stats.mean_escapees`,
    censoring-aware), the bounds interpolated linearly in ``log`` between
    neighbouring evaluations: it needs no model of ``<s>(param)`` beyond that
    interpolation, and it does not shrink below what one batch resolves (more
    realizations per round narrow it, more rounds near the root do not). The
    calibrated value is the root of ``log <s> = a + b x`` fitted by maximum
    likelihood to the evaluations inside the interval and the nearest one on
    each side of it, clipped to the interval.

    Examples
    --------
    A synthetic stand-in: ``<s> = 40 exp(-4 mu)``, 200 geometric realizations.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> def evaluate(mu):
    ...     s = rng.geometric(1.0 / (1.0 + 40.0 * np.exp(-4.0 * mu)), 200) - 1
    ...     return s, np.ones(s.size, bool)
    >>> cal = calibrate(evaluate, target=10.0, lo=0.0, hi=1.0)
    >>> bool(cal.ci[0] < np.log(4.0) / 4.0 < cal.ci[1])
    True
    """
    if not (target > 0 and math.isfinite(target)):
        raise ValueError(f"target must be a positive number, got {target!r}")
    if not lo < hi:
        raise ValueError(f"lo must be below hi, got lo = {lo!r}, hi = {hi!r}")
    if int(rounds) != rounds or rounds < 2:
        raise ValueError(f"rounds must be an integer >= 2, got {rounds!r}")
    stats.mean_escapees([1], [True], confidence)   # checks confidence
    say = log or (lambda message: None)
    evals: list[Evaluation] = []

    def run(value: float) -> float:
        out = evaluate(value)
        e = _evaluation(value, out[0], out[1], confidence, out[2] if len(out) > 2 else None)
        evals.append(e)
        say(f"round {len(evals)}: value {value:.6g}: <s> = {fmt(e.mean)} "
            f"[{fmt(e.mean_ci[0])}, {fmt(e.mean_ci[1])}], {e.n_clogged}/{e.n} clogged")
        return _log_gap(e, target)

    def result(value, ci, ci_open, bracketed, converged, window, slope, message):
        return Calibration(target=float(target), value=value, ci=tuple(ci),
                           ci_open=tuple(ci_open), confidence=confidence,
                           bracketed=bracketed, converged=converged, lo=float(lo),
                           hi=float(hi), window=tuple(window), slope=slope,
                           evaluations=tuple(evals), message=message)

    a, b = float(lo), float(hi)
    g_a, g_b = run(a), run(b)
    if (g_a > 0) == (g_b > 0) and g_a != 0.0 and g_b != 0.0:
        side = "above" if g_a > 0 else "below"
        advice = ("no realization clogged at either end: run longer (run.t_end)"
                  if g_a == g_b == math.inf else "widen the range (lo, hi)")
        return result(math.nan, (math.nan, math.nan), (True, True), False, False,
                      (lo, hi), math.nan,
                      f"target {target:g} not bracketed: <s> = {fmt(evals[0].mean)} at "
                      f"{lo:g} and {fmt(evals[1].mean)} at {hi:g} are both {side} it; "
                      f"{advice}")
    kept = 0   # > 0: a replaced that many rounds in a row (b kept); < 0: the reverse
    for _ in range(int(rounds) - 2):
        if g_a == 0.0 or g_b == 0.0:
            break
        width = b - a
        if math.isfinite(g_a) and math.isfinite(g_b):
            x = b - g_b * width / (g_b - g_a)
            x = min(max(x, a + 0.1 * width), b - 0.1 * width)
        else:
            x = 0.5 * (a + b)
        g = run(x)
        if g == 0.0 or (g > 0) == (g_a > 0):
            a, g_a = x, g
            kept = max(kept, 0) + 1
            if kept >= 2:      # Illinois: the kept end's value halved
                g_b *= 0.5
        else:
            b, g_b = x, g
            kept = min(kept, 0) - 1
            if kept <= -2:
                g_a *= 0.5
        band = _band_interval(_merged(evals, confidence), target)
        if xtol > 0 and band and not any(band[1]) and band[0][1] - band[0][0] < xtol:
            break
    merged = _merged(evals, confidence)
    (ci_lo, ci_hi), ci_open = _band_interval(merged, target)
    below = [e for e in merged if e.value < ci_lo]
    above = [e for e in merged if e.value > ci_hi]
    near = ([below[-1]] if below else []) + [e for e in merged if ci_lo <= e.value <= ci_hi] \
        + ([above[0]] if above else [])
    if len(near) < 2:
        near = sorted(merged, key=lambda e: abs(e.value - 0.5 * (ci_lo + ci_hi)))[:2]
    root, slope = _pooled_root(near, target)
    value = min(max(root, ci_lo), ci_hi) if math.isfinite(root) else 0.5 * (ci_lo + ci_hi)
    converged = not any(ci_open) and (xtol <= 0 or ci_hi - ci_lo < xtol)
    message = (f"calibrated {value:.6g}, interval [{ci_lo:.6g}, {ci_hi:.6g}] (the "
               f"target inside the {100 * confidence:g} % interval of <s>)")
    if any(ci_open):
        message += ("; open at the " + " and ".join(
            side for side, o in zip(("low", "high"), ci_open) if o)
            + " end: the data do not bound it inside the range")
    elif not converged:
        message += f"; wider than xtol = {xtol:g}: raise the realizations per round"
    return result(value, (ci_lo, ci_hi), ci_open, True, converged,
                  (min(e.value for e in near), max(e.value for e in near)), slope,
                  message)


def simulation_evaluator(scene_path: str | Path, param: str, realizations: int,
                         overrides: Iterable[str] = (), seed: int | None = None,
                         progress: Callable[[str], None] | None = None, pool=None):
    """An ``evaluate(value)`` for :func:`calibrate` that runs the scene.

    Each call sets ``param = value``, runs ``realizations`` realizations with
    seeds not used by an earlier call (call ``i`` starts at
    ``seed + i * realizations``; ``seed`` defaults to the scene's ``run.seed``),
    and returns the escapees and clog flags of the stable realizations, plus a
    dict with ``seed``, ``n_unstable`` and ``wall_time_s``; a run that cannot be
    made or fails raises :class:`taichi_hsdem.runner.RunFailed`. With ``pool`` (an
    open :class:`~taichi_hsdem.studies.cluster.Cluster`) each call runs as one task
    on it. The scene is checked when the evaluator is made (``SceneError``); check
    ``param`` at the values you will pass (``load_scene(scene_path,
    [f"{param}={value}"])``).
    """
    overrides = list(overrides)
    scene = load_scene(scene_path, overrides)
    first = scene.run.seed if seed is None else int(seed)
    calls = itertools.count()
    say = progress or (lambda message: None)

    def evaluate(value: float):
        i = next(calls)
        s0 = first + i * realizations
        sc = load_scene(scene_path, overrides + [f"{param}={toml_value(value)}",
                                                 f"run.realizations={realizations}",
                                                 f"run.seed={s0}"])
        say(f"{param} = {value:.6g}: {realizations} realization(s), seeds {s0}..."
            f"{s0 + realizations - 1}")
        if pool is None or getattr(pool, "client", None) is None:     # here
            real, wall = run_realizations(
                sc, PointProgress(say, f"{param} = {value:.6g}") if progress else None)
        else:
            (real, wall), = pool.run(run_realizations, [(sc,)])
        ok = [r for r in real if r["status"] == "ok"]
        return ([r["escapees"] for r in ok], [bool(r["clogged"]) for r in ok],
                {"seed": s0, "n_unstable": len(real) - len(ok), "wall_time_s": wall})

    return evaluate


def run_realizations(scene, progress=None) -> tuple[list[dict], float]:
    """The realizations of ``scene`` run to the end (here or on a cluster worker),
    and the wall time; ``progress``: a :class:`~.progress.PointProgress` (its set-up
    phases and the run's time)."""
    # the simulator loads Taichi (about a second): only once there is something to run
    from ..runner import build, execute
    t0 = time.perf_counter()
    result = execute(build(scene, on_phase=getattr(progress, "phase", None)),
                     progress=progress)
    return result.summary["realizations"], time.perf_counter() - t0


QUICK_REALIZATIONS, QUICK_ROUNDS = 4, 3
#: The files a calibration writes in its folder.
CALIBRATION_FILES = ("calibration.csv", "calibration.json")


def _legacy_files(out: Path) -> list[str]:
    """The files a calibration of an earlier version (no study manifest) wrote in
    ``out``, told by what they hold."""
    names = []
    try:
        with open(out / "calibration.csv", encoding="utf-8", errors="replace") as fh:
            if fh.readline().startswith("round,value,seed,"):
                names.append("calibration.csv")
    except OSError:
        pass
    try:
        data = json.loads((out / "calibration.json").read_text())
        if isinstance(data, dict) and {"scene", "param"} <= set(data):
            names.append("calibration.json")
    except (OSError, ValueError):
        pass
    return names


CSV_COLUMNS = ("round", "value", "seed", "n", "n_unstable", "n_clogged", "escapees_total",
               "mean_escapees", "mean_escapees_ci_lo", "mean_escapees_ci_hi",
               "wall_time_s")


def _parser(prog: str) -> argparse.ArgumentParser:
    p = Parser(prog=prog, description="Calibrate one scene parameter until the mean escapees before clogging match a target.")
    p.add_argument("scene", help="scene TOML file")
    p.add_argument("--target", type=float, required=True, help="<s> to match (> 0)")
    p.add_argument("--param", default="particles.friction",
                   help="dotted scene key to tune (default particles.friction)")
    p.add_argument("--lo", type=float, required=True, help="low end of the range")
    p.add_argument("--hi", type=float, required=True, help="high end of the range")
    p.add_argument("--realizations", type=int, default=20, metavar="N",
                   help="realizations per round (default 20)")
    p.add_argument("--rounds", type=int, default=8,
                   help="evaluations in all, the two ends included (default 8)")
    p.add_argument("--xtol", type=float, default=0.0,
                   help="stop once the interval is narrower than this (default: run "
                        "every round)")
    p.add_argument("--confidence", type=float, default=0.95, help="default 0.95")
    p.add_argument("--seed", type=int, help="seed of the first round's first "
                   "realization (default the scene's run.seed)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scalar of the scene (repeatable)")
    p.add_argument("--out", type=folder_name, help="output folder (default runs/calibrate_<scene name>/)")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help="run each round as a task on a Dask cluster: a scheduler address, or "
                        "local[:N] (the cluster extra)")
    p.add_argument("--quick", action="store_true", help="smoke test: "
                   f"{QUICK_REALIZATIONS} realizations, {QUICK_ROUNDS} rounds, each to run.t_end")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def _check_args(args) -> list[str]:
    bad = []
    if not (args.target > 0 and math.isfinite(args.target)):
        bad.append(f"--target: must be a positive number, got {args.target:g}")
    if not args.lo < args.hi:
        bad.append(f"--lo {args.lo:g} must be below --hi {args.hi:g}")
    if args.realizations < 1:
        bad.append(f"--realizations: must be >= 1, got {args.realizations}")
    if args.rounds < 2:
        bad.append(f"--rounds: must be >= 2 (the two ends), got {args.rounds}")
    if not 0 < args.confidence < 1:
        bad.append(f"--confidence: must lie strictly between 0 and 1, got "
                   f"{args.confidence:g}")
    if args.xtol < 0:
        bad.append(f"--xtol: must be >= 0, got {args.xtol:g}")
    if args.seed is not None and args.seed < 0:
        bad.append(f"--seed: must be >= 0, got {args.seed}")
    return bad


def main(argv=None, prog: str = "python -m taichi_hsdem calibrate") -> int:
    """The calibration's command line (usage: the module doc); its exit status."""
    try:
        args = _parser(prog).parse_args(argv)
    except SystemExit as exc:
        return exc.code
    problems = _check_args(args)
    if problems:
        for line in problems:
            print(f"{prog}: {line}", file=sys.stderr)
        return EXIT_INVALID
    from ..scene import SceneError
    from .cluster import Cluster, ClusterError

    sets = list(args.set)
    realizations, rounds = args.realizations, args.rounds
    tell = None if args.quiet else lambda m: print(m, file=sys.stderr, flush=True)
    try:
        scene = load_scene(args.scene, sets)
        if args.quick:
            realizations, rounds = min(realizations, QUICK_REALIZATIONS), QUICK_ROUNDS
        for value in (args.lo, args.hi):   # the parameter and both ends, checked now
            load_scene(args.scene, sets + [f"{args.param}={value!r}"])
        pool = Cluster(args.cluster, say=tell)
        evaluate = simulation_evaluator(
            args.scene, args.param, realizations, sets, seed=args.seed, pool=pool,
            progress=tell)
    except (SceneError, ClusterError) as exc:
        for line in getattr(exc, "problems", [str(exc)]):
            print(line, file=sys.stderr)
        return EXIT_INVALID
    out = Path(args.out) if args.out else Path("runs") / f"calibrate_{scene.name}"
    from .folder import StudyFolder, StudyFolderError
    try:
        # the cluster first: one it cannot use is refused before the folder is made
        with pool, StudyFolder(out, "calibrate", legacy=_legacy_files) as folder:
            folder.refuse_foreign(CALIBRATION_FILES, "the calibration")
            return _calibrate_into(out, args, sets, realizations, rounds, evaluate, folder,
                                   tell or (lambda message: None))
    except ClusterError as exc:
        print(exc, file=sys.stderr)
        return EXIT_INVALID
    except StudyFolderError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_INVALID


def _calibrate_into(out: Path, args, sets, realizations, rounds, evaluate, folder,
                    say) -> int:
    """:func:`main`'s calibration, in its checked and locked folder ``out``
    (``folder``: its :class:`~.folder.StudyFolder`; ``say``: its progress printer). Its files are claimed and
    ``calibration.csv`` begun when the first round has finished: a calibration
    stopped before (its scene refused at the first round's set-up) leaves the
    folder as it found it."""
    from ..runner import RunFailed
    table = out / "calibration.csv"
    rounds_done = []

    def evaluate_and_record(value):
        escapees, clogged, info = evaluate(value)
        if not rounds_done:
            folder.claim(CALIBRATION_FILES)
            with table.open("w", newline="") as fh:
                csv.writer(fh, lineterminator="\n").writerow(CSV_COLUMNS)
        rounds_done.append(value)
        row = [len(rounds_done), repr(float(value)), info["seed"],
               len(escapees) + info["n_unstable"], info["n_unstable"], sum(clogged),
               sum(escapees)]
        if escapees:
            mean, (lo, hi) = stats.mean_escapees(escapees, clogged, args.confidence)
            row += [repr(mean), repr(lo), repr(hi)]
        else:
            row += ["", "", ""]
        row.append(repr(info["wall_time_s"]))
        with table.open("a", newline="") as fh:
            csv.writer(fh, lineterminator="\n").writerow(row)
        raise_if_swallowed()          # a stop a destructor swallowed: the round is kept
        return escapees, clogged, info

    say(f"{args.scene}: calibrating {args.param} in [{args.lo:g}, {args.hi:g}] to "
        f"<s> = {args.target:g}, {rounds} round(s) of {realizations} realization(s) "
        f"-> {out}")
    try:
        cal = calibrate(evaluate_and_record, args.target, args.lo, args.hi,
                        rounds=rounds, xtol=args.xtol, confidence=args.confidence, log=say)
    except CalibrationError as exc:
        print(f"calibration stopped: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except RunFailed as exc:
        for line in exc.lines:
            print(f"calibration stopped: {line}", file=sys.stderr)
        return EXIT_INVALID if exc.kind == "invalid" else EXIT_FAILED
    report = {"scene": args.scene, "param": args.param, "set": sets,
              "realizations_per_round": realizations, **cal.to_dict()}
    from ..output import atomic_write
    atomic_write(out / "calibration.json", json.dumps(report, indent=1) + "\n")
    if cal.converged:
        say(f"{args.param}: {cal.message} -> {out / 'calibration.json'}")
        return EXIT_OK
    print(f"{args.param}: {cal.message}", file=sys.stderr)
    return EXIT_FAILED
