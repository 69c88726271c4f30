"""The run state: the host's bookkeeping of a batch, one object, saved whole.

:class:`RunState` holds what :class:`~taichi_hsdem.simulation.Simulation` keeps
on the host between steps beside the Taichi arrays: time and step count, the
feeders' random-number generators, each realization's result so far, the
observables' per-realization records (the last escape, the static arch, the
escapes by species, every throat's passages and clog), the arch census and the
time series.
The stepper advances ``t`` and ``steps``; the observables
(:mod:`taichi_hsdem.observables`) update the rest at the checks;
:mod:`taichi_hsdem.checkpoint` saves it with :meth:`RunState.to_arrays` and
restores it with :meth:`RunState.from_arrays`, every field, so that a resumed run
goes on bit for bit. Plain numpy: the command line reads checkpoints before it
loads Taichi.

Examples
--------
>>> from taichi_hsdem.runstate import RunState
>>> rs = RunState.start(seeds=[0, 1], n_particles=3, n_species=1, n_throats=0)
>>> values, arrays = rs.to_arrays()
>>> RunState.from_arrays(values, arrays).seeds
[0, 1]
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass
class RealizationResult:
    """One realization's result so far (``summary.json``'s ``realizations`` rows
    are made from it)."""
    seed: int
    escapees: int | None = 0
    clogged: bool | None = False
    t_clog: float | None = None
    status: str = "ok"
    reason: str | None = None
    t_stop: float | None = None


@dataclass
class ArchRecord:
    """One arch of a realization's census
    (:func:`~taichi_hsdem.observables.census_arches`): ``arches.csv``'s rows are
    made from it.

    Attributes
    ----------
    realization, arch : int
        The realization, and the arch's number in it (from 0, in order of formation).
    t_formed : float
        The first check that found it.
    ids : list of int
        Its particles at the latest check that found it, from the lower side wall up.
    x, theta : list
        Their centres (``[x, y]`` each) and angles then: the failure's start.
    x_over_d : float
        Their centres' mean x then, less the neck's, over the smallest ``d_eq``.
    t_broken : float or None
        The first check that did not find it; None while it holds.
    failure : str or None
        ``"escaped"``, ``"rolled"`` or ``"slid"`` once broken.
    watching : bool
        Broken, and still watched: a member's escape would make it ``"escaped"``.
    """
    realization: int
    arch: int
    t_formed: float
    ids: list
    x: list
    theta: list
    x_over_d: float
    t_broken: float | None = None
    failure: str | None = None
    watching: bool = False


#: The fields of :class:`RunState` kept as numpy arrays (the others are plain
#: values and lists, JSON in a checkpoint's header).
ARRAY_FIELDS = ("last_escape_t", "escaped", "arch_static_t", "escaped_by_species",
                "unfed_by_species", "throat_passages", "throat_last_passage_t",
                "throat_static_t", "throat_t_clog", "check_x", "check_alive")


@dataclass
class RunState:
    """The host's state of a batch of ``R`` realizations of ``N`` bodies, ``S``
    species and ``T`` throats (:func:`~taichi_hsdem.geometry.throats.throats_of`).

    Attributes
    ----------
    t, steps : float, int
        Simulated time (``dt`` summed ``steps`` times) and DEM steps so far.
    seeds, rngs : list
        Each realization's seed and the generator its feeder draws from.
    results : list of RealizationResult
    series : list
        ``(realization, t, escapees)`` rows so far; ``next_series`` the time of the next.
    flow : list
        ``(realization, t, pressure drop, flow rate)`` rows, one per pressure solve.
    network : list
        With several throats: ``(realization, t, injected, throats clogged)`` rows,
        at the first check and at every check that changed either (injected: the
        bodies placed or fed so far).
    arches : list of ArchRecord
        The arch census so far, every realization's arches in order of formation.
    any_running : bool
        Whether the last check left any realization running.
    history_overflows, launches : int
        Shear-history contacts lost, fused-stepper kernel launches.
    e0, u_ref : (R,) array or None
        Kinetic energy at the first check without fluid (the stability check);
        mean fluid speed through the constriction at the first solve.
    last_escape_t, escaped : (R,)
        The check that counted the latest escape, and the escapees it counted.
    arch_static_t : (R,)
        The first check since the latest escape that found the arch static, NaN
        before one did: a clog's ``t_clog``.
    escaped_by_species, unfed_by_species : (R, S) int
        Escapees per species counted at the checks, and the bodies the latest
        check left dead (escaped, not re-fed): a body dies only by escaping and
        comes back only at a check, so the dead bodies beyond those are the
        escapes since.
    throat_passages, throat_last_passage_t, throat_static_t, throat_t_clog : (R, T)
        Per throat: centres that crossed its segment between two checks, the time
        of the latest, the first check since that found it blocked at rest (NaN:
        none, or the throat was found empty since), and its clog time (NaN: open;
        a passage reopens it).
    check_x, check_alive : (R, N, 2), (R, N)
        Positions and alive flags at the latest check (or ``set_state``).
    species_escaped : (R, S) int
        Escapes per species over the whole run, counted at every check whether
        the realization clogged or not (``escaped_by_species`` stops at the clog):
        the per-species escapee series (:func:`~taichi_hsdem.observables.count_species`).
    series_species : list
        With several species: ``(realization, t, (escapees per species))`` beside
        each ``series`` row, in the same order.
    """
    t: float
    steps: int
    seeds: list
    rngs: list
    results: list
    series: list
    flow: list
    network: list
    arches: list
    next_series: float
    any_running: bool
    history_overflows: int
    launches: int
    e0: np.ndarray | None
    u_ref: np.ndarray | None
    last_escape_t: np.ndarray
    escaped: np.ndarray
    arch_static_t: np.ndarray
    escaped_by_species: np.ndarray
    unfed_by_species: np.ndarray
    throat_passages: np.ndarray
    throat_last_passage_t: np.ndarray
    throat_static_t: np.ndarray
    throat_t_clog: np.ndarray
    check_x: np.ndarray
    check_alive: np.ndarray
    species_escaped: np.ndarray
    series_species: list

    @classmethod
    def start(cls, seeds, n_particles: int, n_species: int, n_throats: int) -> RunState:
        """The state at t = 0, before any body is placed."""
        R, N, S, T = len(seeds), int(n_particles), int(n_species), int(n_throats)
        return cls(
            t=0.0, steps=0, seeds=[int(s) for s in seeds],
            rngs=[np.random.default_rng(s) for s in seeds],
            results=[RealizationResult(seed=int(s)) for s in seeds],
            series=[], flow=[], network=[], arches=[], next_series=0.0, any_running=True,
            history_overflows=0, launches=0, e0=None, u_ref=None,
            last_escape_t=np.zeros(R), escaped=np.zeros(R, dtype=np.int64),
            arch_static_t=np.full(R, np.nan),
            escaped_by_species=np.zeros((R, S), dtype=np.int64),
            unfed_by_species=np.zeros((R, S), dtype=np.int64),
            throat_passages=np.zeros((R, T), dtype=np.int64),
            throat_last_passage_t=np.zeros((R, T)),
            throat_static_t=np.full((R, T), np.nan), throat_t_clog=np.full((R, T), np.nan),
            check_x=np.zeros((R, N, 2)), check_alive=np.zeros((R, N), dtype=bool),
            species_escaped=np.zeros((R, S), dtype=np.int64), series_species=[])

    def to_arrays(self) -> tuple[dict, dict]:
        """``(values, arrays)``: every field, the plain ones as JSON-ready values
        (floats exact through ``repr``), those of :data:`ARRAY_FIELDS` as numpy
        arrays; :meth:`from_arrays` makes the same state of them."""
        values = {
            "t": self.t, "steps": self.steps, "seeds": list(self.seeds),
            "rngs": [rng.bit_generator.state for rng in self.rngs],
            "results": [dict(vars(r)) for r in self.results],
            "series": [[int(r), float(t), int(s)] for r, t, s in self.series],
            "flow": [[int(r), float(t), float(dp), float(q)] for r, t, dp, q in self.flow],
            "network": [[int(r), float(t), int(n), int(c)] for r, t, n, c in self.network],
            "arches": [dict(vars(a)) for a in self.arches],
            "next_series": self.next_series, "any_running": self.any_running,
            "history_overflows": self.history_overflows, "launches": self.launches,
            "e0": None if self.e0 is None else [float(v) for v in self.e0],
            "u_ref": None if self.u_ref is None else [float(v) for v in self.u_ref],
            "species_escaped": self.species_escaped.tolist(),
            "series_species": [[int(r), float(t), [int(v) for v in c]]
                               for r, t, c in self.series_species],
        }
        arrays = {name: getattr(self, name) for name in ARRAY_FIELDS}
        return values, arrays

    @classmethod
    def from_arrays(cls, values: dict, arrays: dict) -> RunState:
        """The state :meth:`to_arrays` gave ``values`` and ``arrays`` of (checked by
        the caller: :func:`taichi_hsdem.checkpoint.restore` validates them first)."""
        rngs = []
        for seed, saved in zip(values["seeds"], values["rngs"]):
            rng = np.random.default_rng(seed)
            rng.bit_generator.state = saved
            rngs.append(rng)
        return cls(
            t=float(values["t"]), steps=int(values["steps"]),
            seeds=[int(s) for s in values["seeds"]], rngs=rngs,
            results=[RealizationResult(**saved) for saved in values["results"]],
            series=[(int(r), float(t), int(s)) for r, t, s in values["series"]],
            flow=[(int(r), float(t), float(dp), float(q)) for r, t, dp, q in values["flow"]],
            network=[(int(r), float(t), int(n), int(c)) for r, t, n, c in values["network"]],
            arches=[ArchRecord(**saved) for saved in values["arches"]],
            next_series=float(values["next_series"]),
            any_running=bool(values["any_running"]),
            history_overflows=int(values["history_overflows"]),
            launches=int(values["launches"]),
            e0=None if values["e0"] is None else np.array(values["e0"]),
            u_ref=None if values["u_ref"] is None else np.array(values["u_ref"]),
            # a checkpoint written before these: the counts up to the clog, no rows
            species_escaped=np.array(values.get("species_escaped",
                                                arrays["escaped_by_species"]),
                                     dtype=np.int64).reshape(arrays["escaped_by_species"].shape),
            series_species=[(int(r), float(t), tuple(int(v) for v in c))
                            for r, t, c in values.get("series_species", [])],
            **{name: arrays[name] for name in ARRAY_FIELDS})


#: Every field of :class:`RunState`, in order (a test keeps :meth:`to_arrays`
#: covering them all).
FIELDS = tuple(f.name for f in fields(RunState))
