"""Checkpoints: everything the next step of a batch needs, in one ``.npz`` file.

A checkpoint holds the Taichi arrays (bodies, per-realization status, shear
history, neighbour lists, fluid fields), the fluid coupling's host state
(:meth:`~taichi_hsdem.dem.coupling.FluidCoupling.host_state`) and the pressure
solver's (:meth:`~taichi_hsdem.fluid.PressureSolver.state`), the run state whole
(:class:`~taichi_hsdem.runstate.RunState`: time, steps, results so far, the
observables' records, the time series, the feeders' random-number states) and,
as text, the resolved scene and the digest of the code that wrote it. Arrays are
stored as they are (no pickle); the rest is one JSON header. Floats survive
exactly (``repr`` round-trips in JSON).

:func:`save` writes it atomically (a temporary file beside it, then a rename);
:func:`restore` loads it into a :class:`~taichi_hsdem.simulation.Simulation` of
the same scene and code, which then goes on bit for bit as the run that wrote it
would have (tested): ``python -m taichi_hsdem --resume DIR``.

Examples
--------
>>> from taichi_hsdem import checkpoint                         # doctest: +SKIP
>>> checkpoint.save(sim, "runs/x/checkpoint.npz")               # doctest: +SKIP
>>> header = checkpoint.read_header("runs/x/checkpoint.npz")    # doctest: +SKIP
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

from . import backend
from .digest import code_digest
from .runstate import ARRAY_FIELDS, ArchRecord, RealizationResult, RunState
from .scene import SceneError, load_scene, scene_to_toml
from .scene.coerce import is_finite_real, is_int
from .scene.toml import parse_toml, tomllib

FILE = "checkpoint.npz"
FORMAT = 1
# runstate.RealizationResult's fields and the statuses it takes.
RESULT_KEYS = tuple(f.name for f in dataclasses.fields(RealizationResult))
RESULT_STATUSES = ("ok", "unstable")
# runstate.ArchRecord's fields and the failures a broken arch takes.
ARCH_KEYS = tuple(f.name for f in dataclasses.fields(ArchRecord))
ARCH_FAILURES = ("escaped", "rolled", "slid")
# The run state's arrays (runstate.ARRAY_FIELDS) are stored as host.<field>; its
# other fields in the header's host record, beside the neighbour lists' and the
# fluid coupling's counters.
HOST = "host."


class CheckpointError(ValueError):
    """A checkpoint that cannot be continued (message says why, in the user's terms)."""


def _device_arrays(sim) -> dict:
    """Every Taichi array whose content the next step reads, by a stable name."""
    b, q, nl = sim.bodies, sim.batch, sim.neighbors
    arrays = {f"bodies.{k}": getattr(b, k) for k in (
        "x", "theta", "v", "omega", "force", "torque", "f_fluid", "tau_fluid", "f_ext",
        "tau_ext", "alive")}
    arrays.update({f"batch.{k}": getattr(q, k) for k in (
        "running", "escaped", "bad", "max_overlap")})
    arrays["flags"] = sim.flags
    for i, (partners, shear) in enumerate(sim.history.buffers):
        arrays[f"history.{i}.partners"] = partners
        arrays[f"history.{i}.shear"] = shear
    arrays.update({f"neighbors.{k}": getattr(nl, k) for k in (
        "x_ref", "cell_n", "cell_p", "nbr", "nbr_n")})
    if sim.fused:
        arrays["fused.done"] = sim.done
        arrays["fused.builds"] = sim.builds
    if sim.fluid is not None:
        arrays.update({f"fluid.{k}": a for k, a in sim.fluid.device_arrays().items()})
    return arrays


def _host_arrays(sim) -> dict:
    """The run state's arrays, by their names in the checkpoint."""
    return {HOST + name: value for name, value in sim.run_state.to_arrays()[1].items()}


def save(sim, path) -> Path:
    """Write ``sim``'s state to ``path`` (atomically); returns the path."""
    path = Path(path)
    arrays = {name: a.to_numpy() for name, a in _device_arrays(sim).items()}
    host, state_arrays = sim.run_state.to_arrays()
    host.update({"neighbor_caps": list(sim.neighbors.capacities),
                 "neighbor_builds": sim.neighbors.builds})
    arrays.update({HOST + name: value for name, value in state_arrays.items()})
    if sim.fluid is not None:
        fl = sim.fluid
        counters, fluid_arrays = fl.host_state()
        arrays.update({f"fluid.{k}": v for k, v in fluid_arrays.items()})
        arrays.update({f"solver.{k}": v for k, v in fl.solver.state().items()})
        host["fluid"] = counters
    header = {"format": FORMAT, "code": code_digest(), "precision": sim.scene.run.precision,
              "scene": scene_to_toml(sim.scene), "source": sim.scene.source, "host": host}
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    tmp = path.with_name(path.name + ".part")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


# Every exception np.load and the zip reader raise on a damaged file: a short or
# cut zip (BadZipFile, EOFError), a member whose CRC fails (BadZipFile), a .npy
# header that does not parse or promises more than the member holds (ValueError),
# a member whose declared shape cannot be allocated (MemoryError), compressed data
# that does not inflate (zlib.error), a missing array (KeyError).
_UNREADABLE = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error,
               MemoryError, struct.error)


def read_header(path) -> dict:
    """The JSON header of a checkpoint (``scene`` text, ``code`` digest, ``host``
    state), every field checked (types, ranges, the scene inside valid);
    :class:`CheckpointError` when the file is missing, damaged or not one."""
    path = Path(path)
    with _opened(path) as data:
        return _header_of(data, path)


@contextlib.contextmanager
def _opened(path: Path):
    """The checkpoint at ``path`` as an open ``NpzFile``, read from one open file:
    a run that replaces the file meanwhile (its next checkpoint) cannot mix the
    header of one with the arrays of the other."""
    if not path.exists():
        raise CheckpointError(f"{path}: no checkpoint here (a run leaves checkpoint.npz in "
                              "its output folder)")
    if not path.is_file():
        raise CheckpointError(f"{path}: not a regular file")
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint ({_reason(exc)})") from None
    with fh:
        try:
            if not zipfile.is_zipfile(fh):    # np.load would read it as .npy or pickle
                raise CheckpointError(f"{path}: not a readable checkpoint (not a complete "
                                      ".npz archive: cut short, or another kind of file)")
            fh.seek(0)
            data = np.load(fh, allow_pickle=False)
        except CheckpointError:
            raise
        except (*_UNREADABLE, RecursionError) as exc:
            raise CheckpointError(f"{path}: not a readable checkpoint ({_reason(exc)})") \
                from None
        with data:
            yield data


def _header_of(data, path: Path) -> dict:
    """The checked header of the open checkpoint ``data`` (see :func:`read_header`)."""
    try:
        header = json.loads(bytes(data["header"]).decode())
    except (*_UNREADABLE, RecursionError) as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint ({_reason(exc)})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        found = header.get("format") if isinstance(header, dict) else None
        raise CheckpointError(f"{path}: checkpoint format {found!r} is not the {FORMAT} this "
                              "version reads")
    for key in ("code", "precision", "scene", "source"):
        if not isinstance(header.get(key), str):
            raise CheckpointError(f"{path}: header.{key}: missing or not text")
    _check_host(header.get("host"), path)
    try:
        scene = load_scene(parse_toml(header["scene"]))
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise CheckpointError(f"{path}: the scene inside is not TOML ({_reason(exc)})") from None
    except SceneError as exc:
        raise CheckpointError(f"{path}: the scene inside is not valid: "
                              f"{exc.problems[0].partition(': ')[2]}") from None
    if len(header["host"]["seeds"]) != scene.run.realizations:
        raise CheckpointError(f"{path}: host.seeds: {len(header['host']['seeds'])} seeds for "
                              f"the scene's {scene.run.realizations} realizations")
    return header


def _reason(exc: BaseException) -> str:
    """An exception in a few words (its message, or its type when it has none)."""
    text = " ".join(str(exc).split())[:200]
    return text or type(exc).__name__


def _check_host(host, path) -> None:
    """Every field of the header's ``host`` record: its type and range (``t`` finite
    and >= 0, counters non-negative integers, one entry per realization)."""
    def bad(key, what):
        raise CheckpointError(f"{path}: host.{key}: {what}")

    if not isinstance(host, dict):
        raise CheckpointError(f"{path}: header.host: missing or not a table")
    t = host.get("t")
    if not is_finite_real(t) or t < 0:
        bad("t", f"must be a finite time >= 0, got {t!r}")
    for key in ("steps", "history_overflows", "launches", "neighbor_builds"):
        if not is_int(host.get(key)) or host[key] < 0:
            bad(key, f"must be an integer >= 0, got {host.get(key)!r}")
    if not is_finite_real(host.get("next_series")) or host["next_series"] < 0:
        bad("next_series", f"must be a finite time >= 0, got {host.get('next_series')!r}")
    if not isinstance(host.get("any_running"), bool):
        bad("any_running", f"must be true or false, got {host.get('any_running')!r}")
    seeds = host.get("seeds")
    if not isinstance(seeds, list) or not seeds or not all(is_int(s) for s in seeds):
        bad("seeds", "must be a non-empty list of integers")
    R = len(seeds)
    for key in ("rngs", "results"):
        if not isinstance(host.get(key), list) or len(host[key]) != R or not all(
                isinstance(v, dict) for v in host[key]):
            bad(key, f"must hold one record per realization ({R})")
    for k, state in enumerate(host["rngs"]):
        try:
            np.random.default_rng().bit_generator.state = state
        except (TypeError, ValueError, KeyError, AttributeError, OverflowError) as exc:
            bad(f"rngs[{k}]", f"not a random-number generator state ({_reason(exc)})")
    for k, res in enumerate(host["results"]):
        if set(res) != set(RESULT_KEYS):
            bad(f"results[{k}]", f"must have exactly the keys {sorted(RESULT_KEYS)}")
        kinds = {"seed": is_int, "escapees": is_int, "clogged": lambda v: isinstance(v, bool),
                 "t_clog": is_finite_real, "t_stop": is_finite_real,
                 "status": lambda v: v in RESULT_STATUSES,
                 "reason": lambda v: isinstance(v, str)}
        for key, check in kinds.items():
            value = res[key]
            if not (value is None and key != "status" and key != "seed") and not check(value):
                bad(f"results[{k}].{key}", f"invalid value {value!r}")
        if res["seed"] != seeds[k]:
            bad(f"results[{k}].seed", f"{res['seed']} is not the realization's seed {seeds[k]}")
        if (res["escapees"] or 0) < 0 or any(res[key] is not None and not 0 <= res[key] <= t
                                              for key in ("t_clog", "t_stop")):
            bad(f"results[{k}]", "a count below 0 or a time outside [0, host.t]")
    series = host.get("series")
    if not isinstance(series, list) or not all(
            isinstance(row, list) and len(row) == 3 and is_int(row[0]) and 0 <= row[0] < R
            and is_finite_real(row[1]) and 0 <= row[1] <= t and is_int(row[2]) and row[2] >= 0
            for row in series):
        bad("series", "must be rows [realization, t, escapees] with t in [0, host.t]")
    flow = host.get("flow")
    if not isinstance(flow, list) or not all(
            isinstance(row, list) and len(row) == 4 and is_int(row[0]) and 0 <= row[0] < R
            and is_finite_real(row[1]) and 0 <= row[1] <= t
            and all(isinstance(v, float) for v in row[2:]) for row in flow):
        bad("flow", "must be rows [realization, t, pressure drop, flow rate] with t in "
                    "[0, host.t]")
    network = host.get("network")
    if not isinstance(network, list) or not all(
            isinstance(row, list) and len(row) == 4 and is_int(row[0]) and 0 <= row[0] < R
            and is_finite_real(row[1]) and 0 <= row[1] <= t
            and all(is_int(v) and v >= 0 for v in row[2:]) for row in network):
        bad("network", "must be rows [realization, t, injected, throats clogged] with t "
                       "in [0, host.t]")
    arches = host.get("arches")
    if not isinstance(arches, list):
        bad("arches", "missing or not a list (a checkpoint of an earlier version: run the "
                      "scene again from the start)")
    for k, arch in enumerate(arches):
        if not _is_arch(arch, R, t):
            bad(f"arches[{k}]", f"not an arch record (keys {sorted(ARCH_KEYS)}: members with "
                                "their positions and angles, times in [0, host.t])")
    caps = host.get("neighbor_caps")
    if not isinstance(caps, list) or len(caps) != 2 or not all(
            is_int(c) and c >= 1 for c in caps):
        bad("neighbor_caps", f"must be two integers >= 1, got {caps!r}")
    for key in ("e0", "u_ref"):
        value = host.get(key, ())
        if value is not None and not (isinstance(value, list) and len(value) == R and all(
                is_finite_real(v) and v >= 0 for v in value)):
            bad(key, f"must be null or {R} finite numbers >= 0")
    if "fluid" in host:
        fl = host["fluid"]
        if not isinstance(fl, dict) or not all(
                is_int(fl.get(k)) and fl[k] >= 0 for k in ("updates", "solves")) or not (
                is_finite_real(fl.get("seconds")) and fl["seconds"] >= 0):
            bad("fluid", "must hold counters updates, solves >= 0 and seconds >= 0")


def _is_arch(a, R, t) -> bool:
    """An arch record of the census (runstate.ArchRecord): its keys, its members
    (ids >= 0, each with a finite position and angle), its realization and times
    (formed, then broken, in [0, t]) and its failure (none while it holds)."""
    if not isinstance(a, dict) or set(a) != set(ARCH_KEYS):
        return False
    ids, xs, ths, broken = a["ids"], a["x"], a["theta"], a["t_broken"]
    members = (isinstance(ids, list) and ids and all(is_int(i) and i >= 0 for i in ids)
               and isinstance(xs, list) and len(xs) == len(ids)
               and all(isinstance(p, list) and len(p) == 2 and all(map(is_finite_real, p)) for p in xs)
               and isinstance(ths, list) and len(ths) == len(ids) and all(map(is_finite_real, ths)))
    held = broken is None and a["failure"] is None and a["watching"] is False
    failed = (is_finite_real(broken) and is_finite_real(a["t_formed"]) and a["t_formed"] <= broken <= t
              and a["failure"] in ARCH_FAILURES and isinstance(a["watching"], bool))
    return bool(members and is_int(a["realization"]) and 0 <= a["realization"] < R
                and is_int(a["arch"]) and a["arch"] >= 0 and is_finite_real(a["t_formed"])
                and 0 <= a["t_formed"] <= t and is_finite_real(a["x_over_d"]) and (held or failed))


def check_continuable(header: dict, scene, path) -> None:
    """Refuse a checkpoint of other code, or of another scene than ``scene`` (which
    may differ in ``run.t_end`` and the output keys only)."""
    if header["code"] != code_digest():
        raise CheckpointError(f"{path}: written by other code (package sources or library "
                              "versions changed since); it cannot continue bit for bit: run "
                              "the scene again from the start")
    difference = scene_difference(load_scene(parse_toml(header["scene"])), scene,
                                  "in the checkpoint", "here")
    if difference:
        raise CheckpointError(f"{path}: {difference}: only run.t_end and the output keys "
                              "can change on --resume")


def scene_difference(theirs, mine, where_theirs: str, where_mine: str) -> str | None:
    """The first key (other than ``run.t_end`` and the output keys) whose value
    differs between two scenes, as ``particles[0].friction is 0.4 in
    <where_theirs>, 0.5 <where_mine>``; None when they are the same run."""
    mine = mine.with_values({"run.t_end": 1.0, "output.dir": "-"})
    theirs = theirs.with_values({"run.t_end": 1.0, "output.dir": "-"})
    tables = [(section, getattr(mine, section).to_dict(), getattr(theirs, section).to_dict())
              for section in ("run", "fluid", "geometry", "contact", "damping", "feed", "clog")]
    if len(mine.particles) != len(theirs.particles):
        return (f"{len(theirs.particles)} particle species {where_theirs}, "
                f"{len(mine.particles)} {where_mine}")
    tables += [(f"particles[{k}]", a.to_dict(), b.to_dict())
               for k, (a, b) in enumerate(zip(mine.particles, theirs.particles))]
    for where, a, b in tables:
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                return (f"{where}.{key} is {b.get(key)!r} {where_theirs}, {a.get(key)!r} "
                        f"{where_mine}")
    return None


def restore(sim, path) -> dict:
    """Load the checkpoint at ``path`` into ``sim`` (built from the checkpoint's
    scene); returns its header. Everything is read and checked before ``sim`` is
    touched: :class:`CheckpointError` leaves it as it was."""
    path = Path(path)
    with _opened(path) as data:
        header = _header_of(data, path)
        check_continuable(header, sim.scene, path)
        host = header["host"]
        _check_progress(host, sim, path)
        arrays = _read_arrays(sim, data, path, host)
    if sim.fluid is not None and not isinstance(host.get("fluid"), dict):
        raise CheckpointError(f"{path}: host.fluid: missing, though the scene has a fluid")
    run_state = RunState.from_arrays(host, {name: arrays[HOST + name]
                                            for name in ARRAY_FIELDS})
    nl = sim.neighbors
    nl.resize(*host["neighbor_caps"])
    npr = backend.numpy_real()
    for name, array in _device_arrays(sim).items():
        value = arrays[name]
        floating = np.issubdtype(value.dtype, np.floating)
        array.from_numpy(value.astype(npr if floating else value.dtype))
    nl.builds = int(host["neighbor_builds"])
    if sim.fluid is not None:
        fl = sim.fluid
        fl.restore_host_state(host["fluid"], {k[len("fluid."):]: v for k, v in arrays.items()
                                              if k in _FLUID_HOST})
        fl.solver.restore({k[len("solver."):]: v for k, v in arrays.items()
                           if k.startswith("solver.")})
    sim.run_state = run_state
    return header


def _check_progress(host, sim, path) -> None:
    """The time and step count agree with each other and with the scene: ``t`` is
    ``steps`` time steps and no later than ``run.t_end``; the seeds are the scene's."""
    t, steps, dt, t_end = host["t"], host["steps"], sim.dt, sim.scene.run.t_end
    seeds = list(sim.run_state.seeds)
    if host["seeds"] != seeds:
        raise CheckpointError(f"{path}: host.seeds: {host['seeds']} are not the scene's "
                              f"{seeds}")
    # t is dt summed steps times: its round-off stays far below a part in 1e6.
    if abs(t - steps * dt) > 1e-6 * steps * dt + 0.5 * dt:
        raise CheckpointError(f"{path}: host.t = {t!r} s is not host.steps = {steps} steps "
                              f"of dt = {dt:g} s")
    if t > t_end + 0.5 * dt:
        raise CheckpointError(f"{path}: the checkpoint is at t = {t:.6g} s, past run.t_end "
                              f"= {t_end:.6g} s: --set run.t_end to {t:.6g} or later")
    # The neighbour capacities only grow by doubling from the first ones while a
    # rebuild overflows, and never past what N bodies can fill.
    if any(i >= sim.N for arch in host["arches"] for i in arch["ids"]):
        raise CheckpointError(f"{path}: host.arches: particle ids beyond the scene's {sim.N} "
                              "bodies")
    caps = host["neighbor_caps"]
    if any(c > max(2 * sim.N, 16, *sim.neighbors.capacities) for c in caps):
        raise CheckpointError(f"{path}: host.neighbor_caps: {caps} exceed what "
                              f"{sim.N} bodies can fill")


#: The fluid coupling's host arrays (FluidCoupling.host_state), by checkpoint name.
_FLUID_HOST = {"fluid.pressure", "fluid.v_src", "fluid.w_src", "fluid.past",
               "fluid.kappa_solved"}
#: Host arrays where NaN means "none yet" (no static arch, no clog).
_NAN_IS_NONE = {"host.arch_static_t", "host.throat_static_t", "host.throat_t_clog"}
# Arrays whose values must be finite in every realization that has not gone
# unstable (an unstable one keeps the state it failed in, for the record).
_FINITE = {f"bodies.{k}" for k in ("x", "theta", "v", "omega", "force", "torque", "f_fluid",
                                    "tau_fluid", "f_ext", "tau_ext")} | {
    "neighbors.x_ref", "fluid.vs", "fluid.ws", "fluid.v_src", "fluid.w_src",
    "host.last_escape_t", "batch.max_overlap"}


def _read_arrays(sim, data, path, host) -> dict:
    """Every array of the checkpoint, each checked against what ``sim`` holds: present,
    of its dtype and shape (the neighbour lists at the saved capacities), finite where
    a value must be, and indices inside the batch."""
    R, N = sim.R, sim.N
    cell_cap, nbr_cap = host["neighbor_caps"]
    expected = {name: a.to_numpy() for name, a in _device_arrays(sim).items()}
    for name, cap in (("neighbors.cell_p", cell_cap), ("neighbors.nbr", nbr_cap)):
        expected[name] = np.zeros(expected[name].shape[:-1] + (cap,), expected[name].dtype)
    expected.update(_host_arrays(sim))
    if sim.fluid is not None:
        fl = sim.fluid
        _, fluid_arrays = fl.host_state()
        fluid_arrays.pop("kappa_solved", None)        # optional, below
        expected.update({f"fluid.{k}": v for k, v in fluid_arrays.items()})
        expected["fluid.pressure"] = np.zeros((R, *sim.model.fluid_shape))
        expected.update({f"solver.{k}": v for k, v in fl.solver.state().items()})
    optional = {"fluid.kappa_solved": expected.get("fluid.kappa")}
    arrays = {}
    try:
        extra = set(data.files) - set(expected) - set(optional) - {"header"}
        if extra:
            raise CheckpointError(f"{path}: arrays {sorted(extra)} are not of this scene's "
                                  "set-up")
        for name in [*expected, *(k for k in optional if k in data.files)]:
            ref = expected.get(name, optional.get(name))
            if ref is None:
                raise CheckpointError(f"{path}: {name} is not of this scene's set-up")
            if name not in data.files:
                raise CheckpointError(f"{path}: {name}: missing")
            value = data[name]
            if value.dtype != ref.dtype or value.shape != ref.shape:
                raise CheckpointError(f"{path}: {name}: {value.dtype} {value.shape}, not "
                                      f"the scene's {ref.dtype} {ref.shape}")
            arrays[name] = value
    except CheckpointError:
        raise
    except (*_UNREADABLE, RecursionError) as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint ({_reason(exc)})") from None
    fine = np.array([res["status"] != "unstable" for res in host["results"]]) & (
        arrays["batch.bad"] == 0)
    for name in _FINITE & set(arrays):
        if not np.isfinite(arrays[name][fine]).all():
            raise CheckpointError(f"{path}: {name}: NaN or infinite values in a realization "
                                  "that was running fine")
    t = host["t"]
    bounds = {"bodies.alive": (0, 1), "batch.running": (0, 1), "batch.escaped": (0, None),
              "host.escaped": (0, None), "neighbors.cell_p": (0, N - 1),
              "neighbors.nbr": (0, N - 1), "neighbors.cell_n": (0, N),
              "neighbors.nbr_n": (0, N), "history.0.partners": (0, N + 1),
              "history.1.partners": (0, N + 1), "host.last_escape_t": (0, t),
              "host.escaped_by_species": (0, None), "host.unfed_by_species": (0, N),
              "host.arch_static_t": (0, t),     # (NaN: no static arch yet)
              "host.throat_passages": (0, None), "host.throat_last_passage_t": (0, t),
              "host.throat_static_t": (0, t), "host.throat_t_clog": (0, t)}
    for name, (low, high) in bounds.items():
        value = arrays[name]
        value = value[~np.isnan(value)] if name in _NAN_IS_NONE else value
        if value.size and (value.min() < low or (high is not None and value.max() > high)):
            raise CheckpointError(f"{path}: {name}: values outside [{low}, "
                                  f"{'inf' if high is None else high}]")
    return arrays
