"""Checkpoints: everything the next step of a batch needs, in one ``.npz`` file.

A checkpoint holds the Taichi arrays (bodies, per-realization status, shear
history, neighbour lists, fluid fields), the pressure solver's state
(:meth:`~taichi_hsdem.fluid.PressureSolver.state`), the host's bookkeeping (time,
steps, results so far, the time series, the feeders' random-number states) and,
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

import json
import os
from pathlib import Path

import numpy as np

from . import backend
from .digest import code_digest
from .scene import load_scene, scene_to_toml
from .scene.toml import parse_toml

FILE = "checkpoint.npz"
FORMAT = 1


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
        fl = sim.fluid
        arrays.update({f"fluid.{k}": getattr(fl, k) for k in (
            "kappa", "carried", "pres", "vs", "ws")})
    return arrays


def save(sim, path) -> Path:
    """Write ``sim``'s state to ``path`` (atomically); returns the path."""
    path = Path(path)
    arrays = {name: a.to_numpy() for name, a in _device_arrays(sim).items()}
    host = {
        "t": sim.t, "steps": sim.steps, "seeds": sim.seeds,
        "rngs": [rng.bit_generator.state for rng in sim.rngs],
        "results": [vars(r) for r in sim.results],
        "series": [[int(r), float(t), int(s)] for r, t, s in sim.series],
        "next_series": sim.next_series, "any_running": sim.any_running,
        "history_overflows": sim.history_overflows, "launches": sim.launches,
        "neighbor_caps": [sim.neighbors.cell_cap, sim.neighbors.nbr_cap],
        "neighbor_builds": sim.neighbors.builds,
        "e0": None if sim.e0 is None else [float(v) for v in sim.e0],
        "u_ref": None if sim.u_ref is None else [float(v) for v in sim.u_ref],
    }
    arrays["host.last_escape_t"] = sim.last_escape_t
    arrays["host.escaped"] = sim.escaped_np
    if sim.fluid is not None:
        fl = sim.fluid
        arrays["fluid.pressure"] = fl.pressure
        arrays["fluid.v_src"] = fl.v_src
        arrays["fluid.w_src"] = fl.w_src
        if fl.past is not None:
            arrays["fluid.past"] = fl.past.to_numpy()
        if fl._kappa_solved is not None:
            arrays["fluid.kappa_solved"] = fl._kappa_solved
        arrays.update({f"solver.{k}": v for k, v in fl.solver.state().items()})
        host["fluid"] = {"updates": fl.updates, "solves": fl.solves, "seconds": fl.seconds}
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


def read_header(path) -> dict:
    """The JSON header of a checkpoint (``scene`` text, ``code`` digest, ``host``
    state); :class:`CheckpointError` when the file is missing or not one."""
    path = Path(path)
    try:
        with np.load(path) as data:
            header = json.loads(bytes(data["header"]).decode())
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no checkpoint here (a run leaves checkpoint.npz in "
                              "its output folder)") from None
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint ({exc})") from None
    if header.get("format") != FORMAT:
        raise CheckpointError(f"{path}: checkpoint format {header.get('format')} is not "
                              f"the {FORMAT} this version reads")
    return header


def check_continuable(header: dict, scene, path) -> None:
    """Refuse a checkpoint of other code, or of another scene than ``scene`` (which
    may differ in ``run.t_end`` and the output keys only)."""
    if header["code"] != code_digest():
        raise CheckpointError(f"{path}: written by other code (package sources or library "
                              "versions changed since); it cannot continue bit for bit: run "
                              "the scene again from the start")
    mine = scene.with_values({"run.t_end": 1.0, "output.dir": "-"})
    theirs = load_scene(parse_toml(header["scene"])).with_values(
        {"run.t_end": 1.0, "output.dir": "-"})
    tables = [(section, getattr(mine, section).to_dict(), getattr(theirs, section).to_dict())
              for section in ("run", "fluid", "geometry", "contact", "damping", "feed", "clog")]
    if len(mine.particles) != len(theirs.particles):
        raise CheckpointError(f"{path}: the checkpoint has {len(theirs.particles)} particle "
                              f"species, this scene {len(mine.particles)}")
    tables += [(f"particles[{k}]", a.to_dict(), b.to_dict())
               for k, (a, b) in enumerate(zip(mine.particles, theirs.particles))]
    for where, a, b in tables:
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                raise CheckpointError(f"{path}: {where}.{key} is {b.get(key)!r} in the "
                                      f"checkpoint, {a.get(key)!r} here: only run.t_end and "
                                      "the output keys can change on --resume")


def restore(sim, path) -> dict:
    """Load the checkpoint at ``path`` into ``sim`` (built from the checkpoint's
    scene); returns its header."""
    path = Path(path)
    header = read_header(path)
    check_continuable(header, sim.scene, path)
    host = header["host"]
    npr = backend.numpy_real()
    nl = sim.neighbors
    nl.cell_cap, nl.nbr_cap = host["neighbor_caps"]
    nl._alloc_cells()
    nl._alloc_nbr()
    with np.load(path) as data:
        for name, array in _device_arrays(sim).items():
            value = data[name]
            if tuple(value.shape) != tuple(array.to_numpy().shape):
                raise CheckpointError(f"{path}: {name} has shape {value.shape}, not the "
                                      "scene's: the checkpoint is of another set-up")
            floating = np.issubdtype(value.dtype, np.floating)
            array.from_numpy(value.astype(npr if floating else value.dtype))
        sim.last_escape_t = data["host.last_escape_t"].copy()
        sim.escaped_np = data["host.escaped"].copy()
        if sim.fluid is not None:
            fl = sim.fluid
            fl.pressure = data["fluid.pressure"].copy()
            fl.v_src = data["fluid.v_src"].copy()
            fl.w_src = data["fluid.w_src"].copy()
            if fl.past is not None:
                fl.past.from_numpy(data["fluid.past"].astype(np.float64))
            fl._kappa_solved = (data["fluid.kappa_solved"].copy()
                                if "fluid.kappa_solved" in data else None)
            fl.solver.restore({k[len("solver."):]: data[k] for k in data.files
                               if k.startswith("solver.")})
            fl.updates, fl.solves, fl.seconds = (host["fluid"][k] for k in
                                                 ("updates", "solves", "seconds"))
    sim.t, sim.steps = float(host["t"]), int(host["steps"])
    for rng, state in zip(sim.rngs, host["rngs"]):
        rng.bit_generator.state = state
    for res, saved in zip(sim.results, host["results"]):
        vars(res).update(saved)
    sim.series = [(int(r), float(t), int(s)) for r, t, s in host["series"]]
    sim.next_series = float(host["next_series"])
    sim.any_running = bool(host["any_running"])
    sim.history_overflows = int(host["history_overflows"])
    sim.launches = int(host["launches"])
    nl.builds = int(host["neighbor_builds"])
    sim.e0 = None if host["e0"] is None else np.array(host["e0"])
    sim.u_ref = None if host["u_ref"] is None else np.array(host["u_ref"])
    return header
