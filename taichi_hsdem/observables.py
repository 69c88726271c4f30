"""What a run observes at its host checks, and the results it reports.

:class:`~taichi_hsdem.simulation.Simulation` steps the bodies; every
``check_every`` steps it hands the checked state (``Simulation.state()``) to the
functions here, which update its :class:`~taichi_hsdem.runstate.RunState`:

* escapes and the clog at the constriction (:func:`count_escapes`, with
  :func:`arch_static` and :func:`rest_speed`: the ``[clog]`` criterion of
  docs/scene.md);
* every throat's passages and clog (:func:`observe_throats`, micromodels);
* feeding the inlet (:func:`feed`, ``feed.mode = "count"``);
* the ``flow.csv`` rows of a pressure solve (:func:`flow_rows`);
* and, at the end, the :class:`Result` with its summary (:func:`run_result`).

Plain numpy, no Taichi: the stepper writes back to the device what changed.

Examples
--------
>>> from taichi_hsdem import observables                        # doctest: +SKIP
>>> observables.arch_static(sim.model, sim.run_state.u_ref, sim.state(), 0)  # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import stats
from .geometry.placement import find_free_spot
from .geometry.throats import observe, throat_rows
from .runstate import RunState
from .scene import Scene
from .version import __version__


@dataclass
class Result:
    """What a run produced, as Python objects (the CLI writes them to files)."""
    scene: Scene
    summary: dict
    series: list = field(default_factory=list)      # (realization, t, escapees)
    flow: list = field(default_factory=list)        # (realization, t, pressure drop, Q)
    # (realization, throat, x, y, width, passages, clogged, t_clog), with several throats
    throats: list = field(default_factory=list)
    final: dict = field(default_factory=dict)       # numpy arrays (R, N, ...)
    notes: dict = field(default_factory=dict)       # what every "auto" chose, and why

    @property
    def ok(self) -> bool:
        return all(r["status"] == "ok" for r in self.summary["realizations"])


def dead_by_species(alive, onehot) -> np.ndarray:
    """Bodies not alive in ``alive`` (R, N), per realization and species (R, S);
    ``onehot`` (N, S) is each body's species."""
    return (np.asarray(alive) == 0).astype(np.int64) @ onehot


def kinetic_energy(model, species, st, r) -> float:
    """Kinetic energy (translation and rotation) of the live bodies of realization
    ``r`` in the state ``st`` (``Simulation.state()``), J; ``species`` (N,) each
    body's species."""
    mass = np.array([model.species[k].mass for k in species])
    inertia = np.array([model.species[k].inertia for k in species])
    a = st["alive"][r]
    return float(0.5 * np.sum(mass[a] * np.sum(st["v"][r][a] ** 2, axis=1))
                 + 0.5 * np.sum(inertia[a] * st["omega"][r][a] ** 2))


# ------------------------------------------------------------------ clogs
def rest_speed(model, u_ref, r) -> float:
    """Below this speed a particle at a constriction is at rest (docs/scene.md,
    [clog]): clog.speed_fraction of the mean fluid speed there (``u_ref``, per
    realization, from the first solve), or without fluid (``u_ref`` None) of
    d / clog.window."""
    clog = model.scene.clog
    ref = u_ref[r] if u_ref is not None else model.d_min / clog.window
    return clog.speed_fraction * ref


def arch_static(model, u_ref, st, r) -> bool:
    """Particles of realization ``r`` sit at the constriction and none of them
    moves (:func:`rest_speed`)."""
    g = model.geometry
    a = st["alive"][r]
    xs = st["x"][r]
    near = (a & (xs[:, 0] > g.constriction_x0 - model.d_max)
            & (xs[:, 0] < g.constriction_x1 + model.d_max))
    if not near.any():
        return False
    return np.linalg.norm(st["v"][r][near], axis=1).max() < rest_speed(model, u_ref, r)


def count_escapes(rs: RunState, model, r, escaped, dead, st) -> bool:
    """Escapes and the clog of realization ``r`` at a check at ``rs.t``: ``escaped``
    (R,) the bodies past the escape line so far, ``dead`` (R, S) the dead bodies
    per species now, ``st`` the state. Returns True when the realization clogged
    and stops (``run.stop_at_clog``)."""
    res = rs.results[r]
    went = escaped[r] > rs.escaped[r]
    if went:
        rs.escaped[r] = escaped[r]
        rs.last_escape_t[r] = rs.t
        rs.arch_static_t[r] = np.nan     # an arch that holds forms after this
    static = not went and arch_static(model, rs.u_ref, st, r)
    if static and np.isnan(rs.arch_static_t[r]):
        rs.arch_static_t[r] = rs.t
    res.escapees = int(escaped[r])
    rs.escaped_by_species[r] += dead[r] - rs.unfed_by_species[r]
    # a clog: no escape for clog.window and the arch static now. It formed when
    # the checks first found it static after the last escape (the speed at the
    # neck flickers about the threshold once it holds, so the latest static
    # stretch would start late)
    sc = model.scene
    if static and rs.t - rs.last_escape_t[r] >= sc.clog.window:
        res.clogged = True
        res.t_clog = float(rs.arch_static_t[r])
        if sc.run.stop_at_clog:
            res.t_stop = rs.t
            return True
    return False


def observe_throats(rs: RunState, model, throats, st, r) -> None:
    """Passages and clogs of every throat of realization ``r`` at a check
    (:func:`~taichi_hsdem.geometry.throats.observe`, from ``rs.check_x`` to
    ``st``): a throat blocked at rest with nothing through it for clog.window has
    clogged, since it was first found so after its latest passage."""
    passed, static = observe(throats, rs.check_x[r], rs.check_alive[r],
                             st["x"][r], st["v"][r], st["alive"][r],
                             rest_speed(model, rs.u_ref, r), model.d_max)
    t = rs.t
    went = passed > 0
    rs.throat_passages[r] += passed
    rs.throat_last_passage_t[r, went] = t
    rs.throat_static_t[r, went] = np.nan
    rs.throat_t_clog[r, went] = np.nan
    first = static & np.isnan(rs.throat_static_t[r])
    rs.throat_static_t[r, first] = t
    clog = (static & np.isnan(rs.throat_t_clog[r])
            & (t - rs.throat_last_passage_t[r] >= model.scene.clog.window))
    rs.throat_t_clog[r, clog] = rs.throat_static_t[r, clog]


# ------------------------------------------------------------------ feeding
def feed(model, rngs, species, running, st) -> list:
    """Re-insert escaped particles at the inlet (``feed.mode = "count"``) of the
    realizations ``running``, each drawn from its generator in ``rngs``, into the
    check's state ``st`` (``Simulation.state()``, updated in place: pose, zero
    velocity, alive). Returns the ``(realization, body)`` pairs fed; the caller
    writes ``st`` back to the device when there are any."""
    alive = st["alive"]
    if alive.all():
        return []
    xs, ths, vs = st["x"], st["theta"], st["v"]
    shapes = [s.shape for s in model.species]
    fed = []
    for r in range(len(rngs)):
        if not running[r]:
            continue
        for i in np.flatnonzero(alive[r] == 0):
            others = np.flatnonzero(alive[r])
            spot = find_free_spot(rngs[r], model.geometry, shapes[species[i]],
                                  model.feed_inlet, xs[r, others], ths[r, others],
                                  [shapes[species[j]] for j in others])
            if spot is None:
                break
            xs[r, i], ths[r, i] = spot
            vs[r, i] = 0.0
            alive[r, i] = True
            fed.append((r, int(i)))
    return fed


# ------------------------------------------------------------------ flow
def flow_rows(fluid, flux_out, pressure, running, t) -> list:
    """The ``flow`` rows of a pressure solve at ``t``, one per realization in
    ``running``: the pressure drop across the domain and the flow rate leaving it
    (m^3/s: the outflow per unit depth ``flux_out`` times the gap). Under a
    pressure inlet the drop is the imposed ``p_in - p_out``; under a flow-rate
    inlet it is what a syringe pump's sensor reads: the mean of ``pressure`` (R,
    nx, ny) on the inlet, extrapolated from the first two cell columns to the
    boundary (exact for a linear pressure), less ``p_out``. ``fluid`` is the
    scene's ``[fluid]`` table."""
    q = np.asarray(flux_out, dtype=float) * fluid.gap
    R = len(running)
    if fluid.bc == "pressure":
        drop = np.full(R, fluid.p_in - fluid.p_out)
    else:
        p = pressure
        edge = 1.5 * p[:, 0, :] - 0.5 * p[:, 1, :]      # NaN where either is wall
        drop = np.array([np.mean(e[np.isfinite(e)]) if np.isfinite(e).any() else np.nan
                         for e in edge]) - fluid.p_out
    return [(r, t, float(drop[r]), float(q[r])) for r in range(R) if running[r]]


# ------------------------------------------------------------------ results
def run_result(model, rs: RunState, throats, escaped, st, dead, *, arch, wall,
               interrupted, fluid, neighbor_builds) -> Result:
    """The run's results so far, from its state ``rs``, the escapees ``escaped``
    (R,), the state ``st`` and dead bodies per species ``dead`` now. Realizations
    still running are reported as stopped now (``t_stop``; ``"interrupted"`` when
    the run was stopped early), without changing ``rs``, so that a later run goes
    on. ``fluid``: the coupling's summary entry (None without fluid)."""
    sc = model.scene
    esc = escaped
    series = list(rs.series)
    last_t = {r: t for r, t, _ in series}
    real = []
    for r, res in enumerate(rs.results):
        by_species = rs.escaped_by_species[r]
        t_last = float(rs.last_escape_t[r])
        if res.status == "ok" and not res.clogged:   # counted up to now
            by_species = by_species + dead[r] - rs.unfed_by_species[r]
            if esc[r] > rs.escaped[r]:
                t_last = rs.t
        row = {"seed": res.seed, "escapees": res.escapees, "clogged": res.clogged,
               "t_clog": res.t_clog, "status": res.status, "reason": res.reason,
               "t_stop": res.t_stop,
               "escapees_by_species": (None if res.status == "unstable"
                                       else [int(v) for v in by_species]),
               # the check that saw the last escape counted (None: none)
               "t_last_escape": (None if res.status == "unstable"
                                 or not by_species.any() else t_last)}
        if res.status == "ok" and res.t_stop is None:
            row["t_stop"] = rs.t
            if not res.clogged:
                row["escapees"] = int(esc[r])
            if interrupted:
                row["status"] = "interrupted"
            if last_t.get(r) != rs.t:
                series.append((r, rs.t, int(esc[r])))
        real.append(row)
    counted = [r for r in real if r["status"] in ("ok", "interrupted")]
    n_unstable = sum(1 for r in real if r["status"] == "unstable")
    statistics = (stats.summarize([r["escapees"] for r in counted],
                                  [bool(r["clogged"]) for r in counted],
                                  n_unstable=n_unstable) if counted else None)
    summary = {
        "scene": sc.source, "version": __version__, "arch": arch,
        "status": "interrupted" if interrupted else "complete",
        "dt": model.dt, "steps": rs.steps, "t_end": sc.run.t_end, "t_reached": rs.t,
        "wall_time_s": wall,
        "species": [s.name for s in model.species],  # escapees_by_species' order
        "realizations": real,
        # the censoring-aware estimate of <s> (stats.summarize), not the plain mean
        "mean_escapees": None if statistics is None else statistics["mean_escapees"],
        "mean_escapees_ci": None if statistics is None else statistics["mean_escapees_ci"],
        "never_clogged": None if statistics is None else statistics["n_never_clogged"],
        "statistics": statistics,
        "fluid": fluid,
        "neighbor_builds": neighbor_builds,
        "history_overflows": rs.history_overflows,
        "contact_path": "disk" if model.all_disks else "level-set",
        "auto": dict(model.notes),
        "final_state": [
            {"x": st["x"][r].tolist(), "theta": st["theta"][r].tolist(),
             "alive": st["alive"][r].tolist(), "species": st["species"].tolist()}
            for r in range(len(rs.results))],
    }
    return Result(scene=sc, summary=summary, series=series, flow=list(rs.flow),
                  throats=throat_rows(throats, rs.throat_passages, rs.throat_t_clog),
                  final=st, notes=dict(model.notes))
