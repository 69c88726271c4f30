"""What a run observes at its host checks, and the results it reports.

:class:`~taichi_hsdem.simulation.Simulation` steps the bodies; every
``check_every`` steps it hands the checked state (``Simulation.state()``) to the
functions here, which update its :class:`~taichi_hsdem.runstate.RunState`:

* escapes and the clog at the constriction (:func:`count_escapes`, with
  :func:`arch_static` and :func:`rest_speed`: the ``[clog]`` criterion of
  docs/scene.md), or, with several throats, of the pore network (:func:`network_clog`);
* every throat's passages and clog (:func:`observe_throats`, micromodels), and the
  network's injected bodies and clogged throats over time (:func:`network_rows`);
* the arch census at the neck (:func:`census_arches`, with :class:`ArchCensus`):
  when each arch formed, when and how it broke, or that it held;
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
from typing import NamedTuple

import numpy as np

from . import stats
from .geometry.placement import find_free_spot
from .geometry.throats import observe, throat_rows
from .runstate import ArchRecord, RunState
from .scene import Scene
from .studies import arch_geometry
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
    # (realization, t, injected, throats clogged), with several throats
    network: list = field(default_factory=list)
    # ArchRow per arch of the census, by realization and arch number
    arches: list = field(default_factory=list)
    # with several species: (realization, t, (escapees per species)) beside each
    # row of ``series``, in the same order (empty otherwise)
    series_species: list = field(default_factory=list)
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


# ------------------------------------------------------------------ escapee series
def count_species(rs: RunState, dead) -> None:
    """At a check, before feeding (``dead`` (R, S) the dead bodies per species
    now): the escapes per species since the last check into
    ``rs.species_escaped``, for every realization, clogged or not. A body dies
    only by escaping and comes back only at a check, so the dead bodies beyond
    those the last check left (``rs.unfed_by_species``) escaped since."""
    rs.species_escaped += np.asarray(dead, dtype=np.int64) - rs.unfed_by_species


def species_now(rs: RunState, dead) -> np.ndarray:
    """Escapes per species (R, S) now, between checks: those counted at the checks
    (:func:`count_species`) and the bodies dead since the last one (``dead`` (R, S)
    now)."""
    return rs.species_escaped + np.asarray(dead, dtype=np.int64) - rs.unfed_by_species


def record_series(rs: RunState, running, escaped, dead=None) -> None:
    """The escapee series' rows at ``rs.t``: ``(r, t, escapees)`` into ``rs.series``
    for each realization ``running`` (``escaped`` (R,) the escapes so far) and,
    with ``dead`` (R, S) (a scene of several species; None for one),
    ``(r, t, (escapees per species))`` into ``rs.series_species`` beside it
    (:func:`species_now`)."""
    by_species = None if dead is None else species_now(rs, dead)
    for r in range(len(running)):
        if running[r]:
            rs.series.append((r, rs.t, int(escaped[r])))
            if by_species is not None:
                rs.series_species.append((r, rs.t, tuple(int(v) for v in by_species[r])))


def escapee_table(series, statuses, species=None, series_species=None) -> tuple[list, list]:
    """``escapees.csv`` as ``(header, rows)``: ``realization,t,escapees`` from
    ``series`` and, with several ``species`` (their names) and their rows
    ``series_species`` beside each of ``series`` (:attr:`Result.series_species`),
    one column ``escapees_<name>`` per species after those. A scene of one species,
    or a run that recorded no per-species rows, keeps the three columns. Unstable
    realizations (``statuses``) are left out.

    Examples
    --------
    >>> escapee_table([(0, 0.5, 3)], ["ok"])
    (['realization', 't', 'escapees'], [[0, '0.5', 3]])
    >>> escapee_table([(0, 0.5, 3)], ["ok"], ["small", "large"], [(0, 0.5, (1, 2))])
    (['realization', 't', 'escapees', 'escapees_small', 'escapees_large'], [[0, '0.5', 3, 1, 2]])
    """
    per = (species is not None and len(species) > 1 and series_species is not None
           and len(series_species) == len(series))
    header = ["realization", "t", "escapees"]
    if per:
        names = [str(n) for n in species]
        unique = len(set(names)) == len(names)
        header += [f"escapees_{n}" if unique else f"escapees_{k}_{n}"
                   for k, n in enumerate(names)]
    rows = []
    for k, (r, t, s) in enumerate(series):
        if statuses[r] == "unstable":
            continue
        row = [r, repr(float(t)), int(s)]
        if per:
            rr, tt, counts = series_species[k]
            if (rr, tt) != (r, t):
                raise ValueError(f"series_species row {k} is ({rr}, {tt}), not beside "
                                 f"the series' ({r}, {t})")
            row += [int(v) for v in counts]
        rows.append(row)
    return header, rows


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


def count_escapes(rs: RunState, model, r, escaped, dead, st, throats=None) -> bool:
    """Escapes and the clog of realization ``r`` at a check at ``rs.t``: ``escaped``
    (R,) the bodies past the escape line so far, ``dead`` (R, S) the dead bodies
    per species now, ``st`` the state. Returns True when the realization clogged
    and stops (``run.stop_at_clog``).

    With ``throats`` (two or more: a pore network, :func:`network_clog`) the
    realization clogs when its clogged throats have cut the inlet off from the
    outlet for clog.window (a throat's clog needs no passage for clog.window, not
    that long at rest: a throat that particles seldom reach would otherwise close a
    cut the moment one of them paused in it); otherwise when the arch at the
    constriction holds (:func:`arch_static`) with no escape for clog.window: from
    the last escape, or, before any escape, from when the arch formed (``t_clog``,
    the first check that found it static after the last escape)."""
    res = rs.results[r]
    went = escaped[r] > rs.escaped[r]
    if went:
        rs.escaped[r] = escaped[r]
        rs.last_escape_t[r] = rs.t
        rs.arch_static_t[r] = np.nan     # an arch that holds forms after this
    res.escapees = int(escaped[r])
    rs.escaped_by_species[r] += dead[r] - rs.unfed_by_species[r]
    sc = model.scene
    if throats is not None:
        t_clog = network_clog(rs, throats, r)
        if t_clog is None or rs.t - t_clog < sc.clog.window:
            return False            # open, or the cut not yet held for clog.window
    else:
        static = not went and arch_static(model, rs.u_ref, st, r)
        if static and np.isnan(rs.arch_static_t[r]):
            rs.arch_static_t[r] = rs.t
        # a clog: no escape for clog.window and the arch static now. It formed
        # when the checks first found it static after the last escape (the speed
        # at the neck flickers about the threshold once it holds, so the latest
        # static stretch would start late). Before any escape the window counts
        # from when the arch formed: t = 0 is no event (rs.last_escape_t starts
        # at 0), and counting from it clogged a realization at the first static
        # check past clog.window, t_clog = t_stop, an arch held for no time
        since = rs.last_escape_t[r] if rs.escaped[r] > 0 else rs.arch_static_t[r]
        if not (static and rs.t - since >= sc.clog.window):
            return False
        t_clog = float(rs.arch_static_t[r])
    res.clogged = True
    res.t_clog = t_clog
    if sc.run.stop_at_clog:
        res.t_stop = rs.t
        return True
    return False


def network_clog(rs: RunState, throats, r) -> float | None:
    """When the throats of realization ``r`` clogged now (``rs.throat_t_clog``) first
    cut the inlet off from the outlet, every path between them crossing a clogged
    throat (:meth:`~taichi_hsdem.geometry.throats.Throats.blocked_since`); None
    while a path is open. A throat's clog time is when it was first found at rest
    after its latest passage, so this is when the last throat of the cut did."""
    t = throats.blocked_since(rs.throat_t_clog[r])
    return None if np.isnan(t) else t


def observe_throats(rs: RunState, model, throats, st, r) -> None:
    """Passages and clogs of every throat of realization ``r`` at a check
    (:func:`~taichi_hsdem.geometry.throats.observe`, from ``rs.check_x`` to
    ``st``): a throat blocked at rest with nothing through it for clog.window has
    clogged, since it was first found so after its latest passage.

    The window counts from the latest passage or, before any passage, from when
    particles were first found at rest there: t = 0 is no event (counting from it
    clogged a throat first reached after clog.window at the first check that
    found it at rest, held for no time). A throat found holding no particle
    (none reached it, or they left it without passing) starts its rest afresh:
    the particles that stop there next are a new arch."""
    passed, static, reached = observe(throats, rs.check_x[r], rs.check_alive[r],
                                      st["x"][r], st["v"][r], st["alive"][r],
                                      rest_speed(model, rs.u_ref, r), model.d_max)
    t = rs.t
    went = passed > 0
    rs.throat_passages[r] += passed
    rs.throat_last_passage_t[r, went] = t
    rs.throat_static_t[r, went | ~reached] = np.nan
    rs.throat_t_clog[r, went] = np.nan
    first = static & np.isnan(rs.throat_static_t[r])
    rs.throat_static_t[r, first] = t
    since = np.where(rs.throat_passages[r] > 0, rs.throat_last_passage_t[r],
                     rs.throat_static_t[r])
    with np.errstate(invalid="ignore"):
        held = t - since >= model.scene.clog.window     # NaN (never at rest): False
    clog = static & np.isnan(rs.throat_t_clog[r]) & held
    rs.throat_t_clog[r, clog] = rs.throat_static_t[r, clog]


def network_rows(rs: RunState, checked, escaped, alive) -> None:
    """The ``network`` rows of a check (several throats): for each realization in
    ``checked``, ``(r, t, injected, throats clogged)`` when either changed since its
    last row (or it has none). Injected: the bodies alive now (after feeding) and
    the escapes so far (``escaped`` (R,)), as every escaped body died once."""
    n_clogged = np.isfinite(rs.throat_t_clog).sum(axis=1)
    injected = np.asarray(escaped, dtype=np.int64) + np.asarray(alive).sum(axis=1)
    wanted = {int(r) for r in np.flatnonzero(checked)}
    last = {}
    for row in reversed(rs.network):      # the newest row of each realization checked
        if wanted <= last.keys():
            break
        if row[0] in wanted:
            last.setdefault(row[0], row)
    for r in sorted(wanted):
        now = (int(injected[r]), int(n_clogged[r]))
        if r not in last or (last[r][2], last[r][3]) != now:
            rs.network.append((int(r), rs.t, *now))


# ------------------------------------------------------------------ arches
#: The census looks for arches among the particles whose centre lies within this
#: many bounding diameters of the neck along x: the arches that clog a
#: constriction sit within about a diameter of it, and the search stays cheap.
CENSUS_REACH = 3.0


class ArchRow(NamedTuple):
    """One arch of the census, as ``arches.csv`` writes it (:attr:`Result.arches`)."""
    realization: int
    arch: int
    t_formed: float
    t_broken: float | None       # None: held
    held: bool
    count: int
    ids: tuple
    x_over_d: float
    failure: str                 # "held", "escaped", "rolled" or "slid"


class ArchCensus:
    """What the arch census (:func:`census_arches`) needs of a model, worked out
    once. :meth:`of` gives None for a geometry the census cannot read: one with
    obstacles (a micromodel's pillars) or without an open inlet and outlet.

    Attributes
    ----------
    sides : Sides
        The two side walls (:class:`~taichi_hsdem.studies.arch_geometry.Sides`).
    shapes, species : list, (N,) array
        The species' shapes and each body's species.
    radius : (N,) array
        Each body's radius, half its ``d_eq`` (the failure's lever arm).
    d_b, d_min : float
        The largest bounding diameter (touching: a gap of at most ``DEFAULT_TOL``
        of it) and the smallest ``d_eq`` (the positions' unit).
    neck_x : float
        The neck's x, the middle of the constriction.
    x_range : (float, float)
        The particles searched: centres within :data:`CENSUS_REACH` of the neck.
    watch : float
        How long a broken arch is watched for an escape: ``clog.window``.
    """

    def __init__(self, model):
        g = model.geometry
        self.sides = arch_geometry.Sides(g)
        self.shapes = [s.shape for s in model.species]
        self.species = np.asarray(model.species_of_particle)
        self.radius = 0.5 * np.array([model.species[k].d_eq for k in self.species])
        self.d_b = 2.0 * max(s.bounding_radius for s in self.shapes)
        self.d_min = model.d_min
        self.neck_x = 0.5 * (g.constriction_x0 + g.constriction_x1)
        self.x_range = (g.constriction_x0 - CENSUS_REACH * self.d_b,
                        g.constriction_x1 + CENSUS_REACH * self.d_b)
        self.watch = model.scene.clog.window

    @classmethod
    def of(cls, model):
        """The census of ``model``, or None where its geometry has no two side walls."""
        try:
            return cls(model)
        except arch_geometry.ArchError:
            return None

    def chain(self, x, theta, alive):
        """The arch spanning the neck in one realization's state (x (N, 2), theta
        (N,), alive (N,)): its particles from the lower side wall up, or None
        (:func:`~taichi_hsdem.studies.arch_geometry.arch_chain`, touching: gap at most
        ``DEFAULT_TOL`` bounding diameters; particles within :data:`CENSUS_REACH`
        of the neck)."""
        return arch_geometry.arch_chain(self.shapes, x, theta, alive, self.species, self.sides,
                                        self.neck_x, self.d_b, x_range=self.x_range)

    def x_over_d(self, x) -> float:
        """Centres ``x`` (M, 2): their mean x less the neck's, over the smallest d_eq."""
        return float((np.mean(x[:, 0]) - self.neck_x) / self.d_min)

    def failure(self, arch: ArchRecord, x, theta) -> str:
        """How ``arch``, whose members are alive, broke between the check that last
        found it (its ``x``, ``theta``) and now (``x`` (N, 2), ``theta`` (N,)):
        ``"rolled"`` when its members turned more than they slid, else ``"slid"``.

        A heuristic, to first order in the motion. Turning: the sum over members
        of ``|dtheta| r`` (``r`` half the member's d_eq). Sliding: the sum, over
        the chain's contacts (lower wall - first member, each member - the next,
        last member - upper wall), of the slip: the tangential part of the
        relative displacement of the two bodies' material points at the contact,
        a point's being ``dx + dtheta z x (p - centre)`` and a wall's nothing.
        Two members touch at the point of their centre line ``r_i / (r_i + r_j)``
        of the way from ``i``, a member and a wall at the wall point nearest its
        centre. A member rolling on the others and the walls without slip has
        turned ``|dtheta| r`` and slipped nothing; one sliding without turning
        the reverse.
        """
        ids = list(arch.ids)
        xa, ta = np.array(arch.x, dtype=float), np.array(arch.theta, dtype=float)
        dx, dth, r = x[ids] - xa, theta[ids] - ta, self.radius[ids]
        turn = float(np.sum(np.abs(dth) * r))

        def perp(v):
            return np.stack([-v[:, 1], v[:, 0]], axis=1)

        def moved(k, p):         # the material points of members k at the points p
            return dx[k] + dth[k][:, None] * perp(p - xa[k])

        def along(u, normal):    # the sizes of u's parts across the contact normals
            t = perp(normal)
            return np.abs(np.sum(u * t, axis=1)) / np.hypot(t[:, 0], t[:, 1])

        i, j = np.arange(len(ids) - 1), np.arange(1, len(ids))
        p = xa[i] + (r[i] / (r[i] + r[j]))[:, None] * (xa[j] - xa[i])
        ends = np.array([0, len(ids) - 1])
        q = np.array([self.sides.nearest(xa[:1], 0)[0], self.sides.nearest(xa[-1:], 1)[0]])
        slip = float(along(moved(i, p) - moved(j, p), xa[j] - xa[i]).sum()
                     + along(moved(ends, q), q - xa[ends]).sum())
        return "rolled" if turn > slip else "slid"


def same_arch(before, now) -> bool:
    """Whether the chain ``now`` is the arch whose members were ``before``: they
    share more than half the particles of the larger of the two (the same set, or
    one holding the other and most of its particles, or most kept and a few
    swapped)."""
    shared = len(set(before) & set(now))
    return 2 * shared > max(len(before), len(now))


def census_arches(rs: RunState, census: ArchCensus, st, r) -> None:
    """The arch census of realization ``r`` at a check at ``rs.t``, into ``rs.arches``.

    An arch is a chain of touching particles from one side wall to the other
    across the neck (:meth:`ArchCensus.chain`). The chain found now continues
    the realization's holding arch when :func:`same_arch` says so and no member
    of it escaped; the arch's members and position are then updated to now.
    Otherwise the holding arch broke now (``t_broken``): ``"escaped"`` when a
    member passed the escape line since the check that last found it, else
    ``"rolled"`` or ``"slid"`` by :meth:`ArchCensus.failure`, and a chain found
    now is a new arch. A broken arch stays watched, and becomes ``"escaped"``
    when one of its members passes the escape line, until the next arch forms or
    for ``clog.window`` after it broke: a failed arch lets its particles through
    over the checks that follow. ``st`` is the state before feeding, so a body
    not alive passed the escape line since the last check.
    """
    x, theta, alive = st["x"][r], st["theta"][r], st["alive"][r]
    chain = census.chain(x, theta, alive)
    last = next((a for a in reversed(rs.arches) if a.realization == r), None)
    if last is not None and last.t_broken is None:
        escaped = not alive[last.ids].all()
        if chain is not None and not escaped and same_arch(last.ids, chain):
            last.ids, last.x, last.theta = chain, x[chain].tolist(), theta[chain].tolist()
            last.x_over_d = census.x_over_d(x[chain])
            return
        last.t_broken = rs.t
        last.failure = "escaped" if escaped else census.failure(last, x, theta)
        last.watching = not escaped
    elif last is not None and last.watching:
        if rs.t - last.t_broken >= census.watch:
            last.watching = False
        elif not alive[last.ids].all():
            last.failure, last.watching = "escaped", False
    if chain is None:
        return
    if last is not None:
        last.watching = False
    rs.arches.append(ArchRecord(
        realization=int(r), arch=0 if last is None else last.arch + 1, t_formed=rs.t,
        ids=chain, x=x[chain].tolist(), theta=theta[chain].tolist(),
        x_over_d=census.x_over_d(x[chain])))


def arch_rows(rs: RunState) -> list:
    """The census as :class:`ArchRow` s, by realization and arch number; an arch
    holding now is ``held``."""
    rows = [ArchRow(a.realization, a.arch, a.t_formed, a.t_broken, a.t_broken is None,
                    len(a.ids), tuple(a.ids), a.x_over_d,
                    "held" if a.t_broken is None else a.failure) for a in rs.arches]
    return sorted(rows, key=lambda a: (a.realization, a.arch))


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
               interrupted, fluid, neighbor_builds, census) -> Result:
    """The run's results so far, from its state ``rs``, the escapees ``escaped``
    (R,), the state ``st`` and dead bodies per species ``dead`` now. Realizations
    still running are reported as stopped now (``t_stop``; ``"interrupted"`` when
    the run was stopped early), and their holding arches as held, without
    changing ``rs``, so that a later run goes on. ``fluid``: the coupling's
    summary entry (None without fluid); ``census``: the run's :class:`ArchCensus`
    (None: it took none, and the arch counts are null)."""
    sc = model.scene
    esc = escaped
    series = list(rs.series)
    # per-species rows only when every series row has one (a Simulation that
    # records them: record_series)
    per_species = (len(rs.series_species) == len(series)
                   and rs.species_escaped.shape[1] > 1)
    series_species = list(rs.series_species) if per_species else []
    last_t = {r: t for r, t, _ in series}
    arches = arch_rows(rs)
    formed = np.bincount([a.realization for a in arches], minlength=len(rs.results))
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
               "arches_formed": (None if census is None or res.status == "unstable"
                                 else int(formed[r])),
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
                if per_species:
                    now = species_now(rs, dead)[r]
                    series_species.append((r, rs.t, tuple(int(v) for v in now)))
        real.append(row)
    counted = [r for r in real if r["status"] in ("ok", "interrupted")]
    n_unstable = sum(1 for r in real if r["status"] == "unstable")
    held = sum(1 for a in arches if a.held and real[a.realization]["status"] != "unstable")
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
        # the arch census (arches.csv), over the realizations that did not go unstable
        "arches_formed": (None if census is None else
                          sum(r["arches_formed"] for r in real if r["arches_formed"] is not None)),
        "arches_held": None if census is None else held,
        "fluid": fluid,
        "neighbor_builds": neighbor_builds,
        "history_overflows": rs.history_overflows,
        "contact_path": "disk" if model.all_disks else "level-set",
        "auto": dict(model.notes),
        # the final state is Result.final, written to final_state.npz, not here
    }
    if throats.network:
        summary["network"] = network_summary(rs, throats, real, escaped, st)
    return Result(scene=sc, summary=summary, series=series, flow=list(rs.flow),
                  throats=throat_rows(throats, rs.throat_passages, rs.throat_t_clog),
                  network=list(rs.network), arches=arches, final=st, notes=dict(model.notes),
                  series_species=series_species)


def network_summary(rs: RunState, throats, real, escaped, st) -> dict:
    """``summary.json``'s ``network`` entry (several throats): the throat and pore
    counts, what ``clogged`` means, and per realization (unstable ones null) the
    throats clogged now, their fraction, the bodies injected so far and when the
    inlet was cut off from the outlet (``t_clog``, null while open)."""
    clogged = np.isfinite(rs.throat_t_clog)
    injected = np.asarray(escaped, dtype=np.int64) + np.asarray(st["alive"]).sum(axis=1)
    rows = []
    for r, row in enumerate(real):
        if row["status"] == "unstable":
            rows.append(None)
            continue
        t_cut = throats.blocked_since(rs.throat_t_clog[r])
        rows.append({"throats_clogged": int(clogged[r].sum()),
                     "fraction_clogged": float(clogged[r].mean()),
                     "injected": int(injected[r]),
                     "t_cut": None if np.isnan(t_cut) else float(t_cut)})
    fractions = [row["fraction_clogged"] for row in rows if row is not None]
    return {"throats": len(throats), "pores": int(throats.n_pores),
            "clogged_means": "the clogged throats have cut the inlet off from the outlet "
                             "for clog.window: every path of pores between them crosses "
                             "one",
            "mean_fraction_clogged": float(np.mean(fractions)) if fractions else None,
            "realizations": rows}
