"""Writing a run's results: summary.json, final_state.npz, escapees.csv, arches.csv,
scene.resolved.toml, the checkpoint, the plots, video.mp4 and the ParaView series.

A run only ever replaces or removes files that runs of this project wrote in its
folder (listed in :data:`MANIFEST`), and refuses a folder holding a file of a
result name that none wrote (:func:`foreign_files`). Its files wait in a hidden
staging folder inside the output folder (:class:`Staging`, which also holds the
folder's lock) until the run ends; then they are moved into place together,
summary.json last, and files an earlier run wrote that this one does not are
removed, so that the folder never mixes two runs. Every file is written to a
temporary name and renamed, so nothing half-written ever stands under a result's
name. The checkpoint is the run's own state: into a folder with no earlier result
it goes straight in at its wall-clock interval, so that a run killed hard can be
resumed; beside an earlier result it waits in the staging folder.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import checkpoint, report
from .scene import Scene, scene_to_toml


def atomic_write(path: Path, text: str):
    """Write ``text`` to ``path`` through a temporary file beside it, so that
    ``path`` never holds half a file."""
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text)
    os.replace(tmp, path)


def json_safe(obj):
    """Plain JSON: numpy scalars to Python, NaN and inf to None (null), tuples to
    lists, keys to strings, anything else to its text."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)) or obj is None or isinstance(obj, str):
        return bool(obj) if isinstance(obj, np.bool_) else obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return str(obj)


def write_resolved_scene(scene: Scene, out: Path, notes: dict | None = None):
    """``scene.resolved.toml``, headed by what each ``auto`` chose and why."""
    out.mkdir(parents=True, exist_ok=True)
    head = "".join(f"# auto {key}: {why}\n" for key, why in sorted((notes or {}).items()))
    atomic_write(out / "scene.resolved.toml", head + scene_to_toml(scene))


def write_summary(summary: dict, out: Path):
    atomic_write(out / "summary.json", json.dumps(json_safe(summary), indent=1) + "\n")


#: The final states' file: numpy arrays, realization first.
FINAL_STATE = "final_state.npz"
#: Its arrays (R realizations, N bodies): ``x`` (R, N, 2) m, ``theta`` (R, N) rad,
#: ``v`` (R, N, 2) m/s, ``omega`` (R, N) rad/s, ``alive`` (R, N) bool, ``species``
#: (N,) each body's species (the summary's ``species`` order), ``seed`` (R,).
FINAL_STATE_ARRAYS = ("x", "theta", "v", "omega", "alive", "species", "seed")


def write_final_state(result, out: Path):
    """``final_state.npz``: the run's end state (``Result.final``) and each
    realization's seed (:data:`FINAL_STATE_ARRAYS`); realization ``r`` is row ``r``
    of every per-realization array, as in summary.json's ``realizations``."""
    st = result.final
    arrays = {k: np.asarray(st[k]) for k in FINAL_STATE_ARRAYS if k != "seed"}
    arrays["seed"] = np.array([int(r["seed"]) for r in result.summary["realizations"]],
                              dtype=np.int64)
    path = Path(out) / FINAL_STATE
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    os.replace(tmp, path)


class NoFinalState(ValueError):
    """A folder holds no final state (no final_state.npz, and no ``final_state`` in
    a summary.json written before the file existed)."""


def read_final_state(folder: Path, summary: dict | None = None) -> dict:
    """The final state of the run (or sweep point) in ``folder`` as numpy arrays
    (:data:`FINAL_STATE_ARRAYS`). A folder written before ``final_state.npz``
    existed falls back to its summary.json's ``final_state`` (``summary``, read
    when not given): there only ``x``, ``theta``, ``alive``, ``species`` and
    ``seed`` (no velocities). Raises :class:`NoFinalState` when neither is there."""
    folder = Path(folder)
    path = folder / FINAL_STATE
    if path.is_file():
        try:
            with np.load(path) as data:
                return {k: data[k] for k in data.files}
        except (OSError, ValueError, KeyError) as exc:
            raise NoFinalState(f"{path}: unreadable ({exc})") from None
    if summary is None:
        try:
            summary = json.loads((folder / "summary.json").read_text())
        except (OSError, ValueError):
            summary = {}
    old = summary.get("final_state") if isinstance(summary, dict) else None
    if not old:
        raise NoFinalState(f"{folder}: no {FINAL_STATE} (nor a final_state in its "
                           "summary.json)")
    try:
        out = {"x": np.array([f["x"] for f in old], dtype=float).reshape(len(old), -1, 2),
               "alive": np.array([f["alive"] for f in old], dtype=bool)}
        if all("theta" in f for f in old):
            out["theta"] = np.array([f["theta"] for f in old], dtype=float)
        if "species" in old[0]:
            out["species"] = np.asarray(old[0]["species"], dtype=np.int64)
        out["seed"] = np.array([int(r["seed"]) for r in summary.get("realizations", [])],
                               dtype=np.int64)
    except (KeyError, TypeError, ValueError) as exc:
        raise NoFinalState(f"{folder}/summary.json: an unreadable final_state ({exc})") \
            from None
    return out


def write_flow(flow, statuses, out: Path):
    """``flow.csv``: realization,t,pressure_drop,flow_rate (Pa, m^3/s) at every
    pressure solve; unstable realizations are left out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["realization", "t", "pressure_drop", "flow_rate"])
    for r, t, drop, q in flow:
        if statuses[r] != "unstable":
            w.writerow([r, repr(float(t)), repr(float(drop)), repr(float(q))])
    atomic_write(out / "flow.csv", buf.getvalue())


def write_throats(rows, statuses, out: Path):
    """``throats.csv``: realization,throat,x,y,width,passages,clogged,t_clog (m, s;
    t_clog empty for an open throat), one row per throat of each realization at
    the end of the run; unstable realizations are left out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["realization", "throat", "x", "y", "width", "passages", "clogged", "t_clog"])
    for r, k, x, y, width, passages, clogged, t_clog in rows:
        if statuses[r] != "unstable":
            w.writerow([r, k, repr(float(x)), repr(float(y)), repr(float(width)), int(passages),
                        "true" if clogged else "false",
                        "" if t_clog is None else repr(float(t_clog))])
    atomic_write(out / "throats.csv", buf.getvalue())


def write_network(rows, statuses, n_throats: int, out: Path):
    """``network.csv``: realization,t,injected,throats_clogged,fraction_clogged, at
    the first check and every check that changed the bodies injected or the
    throats clogged (several throats); unstable realizations are left out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["realization", "t", "injected", "throats_clogged", "fraction_clogged"])
    for r, t, injected, clogged in rows:
        if statuses[r] != "unstable":
            w.writerow([r, repr(float(t)), int(injected), int(clogged),
                        repr(clogged / n_throats)])
    atomic_write(out / "network.csv", buf.getvalue())


def write_series(series, statuses, out: Path, species=None, series_species=None):
    """``escapees.csv``: realization,t,escapees, and with several ``species`` a
    column escapees_<name> per species from ``series_species``
    (:func:`~taichi_hsdem.observables.escapee_table`); unstable realizations are
    left out."""
    from .observables import escapee_table
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    header, rows = escapee_table(series, statuses, species, series_species)
    w.writerow(header)
    w.writerows(rows)
    atomic_write(out / "escapees.csv", buf.getvalue())


def write_arches(rows, statuses, out: Path):
    """``arches.csv``: realization,arch,t_formed,t_broken,held,count,ids,x_over_d,failure,
    one row per arch of the census (:class:`~taichi_hsdem.observables.ArchRow`;
    t_broken empty for an arch that held, ids separated by spaces); unstable
    realizations are left out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["realization", "arch", "t_formed", "t_broken", "held", "count", "ids",
                "x_over_d", "failure"])
    for a in rows:
        if statuses[a.realization] != "unstable":
            w.writerow([a.realization, a.arch, repr(float(a.t_formed)),
                        "" if a.t_broken is None else repr(float(a.t_broken)),
                        "true" if a.held else "false", a.count, " ".join(map(str, a.ids)),
                        repr(float(a.x_over_d)), a.failure])
    atomic_write(out / "arches.csv", buf.getvalue())


#: Files (and folders) a run writes into its output folder.
RESULT_FILES = ("scene.resolved.toml", FINAL_STATE, "escapees.csv", "arches.csv", "flow.csv",
                "throats.csv", "network.csv", "summary.json", "video.mp4", "escapees.png",
                "pressure_drop.png", "pmf.png", "permeability.png", "throats_clogged.png",
                "clog_map.png", "series.pvd", "vtk", checkpoint.FILE)
#: The plots a run may draw (report.py).
PLOTS = ("escapees.png", "pressure_drop.png", "pmf.png", "permeability.png",
         "throats_clogged.png", "clog_map.png")
#: The list of the files the runs of this project wrote in a folder: only these
#: are ever replaced or removed there.
MANIFEST = ".taichi_hsdem-files.json"
#: Held (``flock``) while a run writes a folder, so that two runs never mix.
LOCK = ".taichi_hsdem.lock"
#: Prefix of the hidden folder a run's files wait in (:class:`Staging`).
STAGING_PREFIX = ".incomplete-"


class FolderInUse(OSError):
    """Another run is writing the output folder."""


class FolderUnusable(OSError):
    """The output folder's lock cannot be taken (its path is not a file)."""


def lock_problem(out: Path) -> str | None:
    """Why ``out``'s lock cannot be taken (its path is a folder or some other
    thing than a file), or None."""
    path = Path(out) / LOCK
    if os.path.lexists(path) and not path.is_file():
        kind = "a folder" if path.is_dir() else "not a regular file"
        return (f"{path} is {kind}, where runs of taichi_hsdem keep the folder's lock: "
                "remove it, or choose another folder")
    return None


def in_use(out: Path) -> bool:
    """Whether a run alive holds ``out``'s lock (is writing ``out``). Creates
    nothing."""
    import fcntl
    try:
        fh = open(Path(out) / LOCK, "rb")
    except OSError:
        return False
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
    return False


def _is_run_summary(path: Path) -> bool:
    """``summary.json`` of a run of this project (a folder from before manifests)."""
    try:
        with open(path, "rb") as fh:
            data = json.loads(fh.read(1 << 24))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and {"version", "realizations", "scene"} <= set(data)


def owned_files(out: Path) -> set[str]:
    """The names in ``out`` that runs of this project wrote there: the manifest's,
    or, in a folder a run of an earlier version wrote (no manifest, a run's
    ``summary.json``), the result names present."""
    out = Path(out)
    try:
        data = json.loads((out / MANIFEST).read_text())
        return {n for n in data["files"] if isinstance(n, str) and n in RESULT_FILES}
    except FileNotFoundError:
        pass
    except (OSError, ValueError, KeyError, TypeError):
        return set()
    if _is_run_summary(out / "summary.json"):
        return {n for n in RESULT_FILES if os.path.lexists(out / n)}
    return set()


def manifest_problem(out: Path) -> str | None:
    """Why the manifest in ``out`` cannot be read (damaged, unreadable), or None
    (read, or absent)."""
    path = Path(out) / MANIFEST
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict) or not isinstance(data.get("files"), list):
            return "it does not list files"
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"
    except ValueError as exc:
        return f"damaged: {exc}"
    return None


def foreign_files(out: Path) -> list[str]:
    """Names in ``out`` that a run may write (or remove) but that no run of this
    project wrote: a run refuses such a folder rather than lose the user's files."""
    out = Path(out)
    if not out.is_dir():
        return []
    mine = owned_files(out)
    return [n for n in RESULT_FILES if os.path.lexists(out / n) and n not in mine]


def holds_result(out: Path) -> bool:
    """``out`` holds the result (or checkpoint) of an earlier run."""
    return bool(owned_files(out) & {"summary.json", checkpoint.FILE})


class Staging:
    """The output folder of one run and the hidden folder its files wait in.

    ``with Staging(out) as staged``: creates ``out`` (if needed), takes its lock
    (:class:`FolderInUse` when another run holds it) and makes
    ``out/.incomplete-*``; :meth:`path` names a file in the staging folder;
    :meth:`publish` moves the results into ``out``; leaving the block removes the
    staging folder and the lock, and ``out`` too when this run created it and
    left it empty.

    The run's checkpoints (:attr:`checkpoint_path`) go straight into ``out`` when
    it holds no earlier result, so that a run killed hard can be resumed with
    ``--resume out``; otherwise they wait in the staging folder (``--resume
    out/.incomplete-*`` continues them), and the earlier result stays exactly as
    it was until this run publishes.
    """

    def __init__(self, out: Path, continuing: bool = False):
        self.out = Path(out)
        self.tmp = None
        self._created = False
        self._lock = None
        self.continuing = continuing

    def __enter__(self):
        self._created = not os.path.lexists(self.out)
        self.out.mkdir(parents=True, exist_ok=True)
        try:
            self._take_lock()
            _remove_stale_staging(self.out)
            self.tmp = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=self.out))
        except BaseException:
            self.__exit__()
            raise
        straight = self.continuing or not holds_result(self.out)
        self.checkpoint_path = (self.out if straight else self.tmp) / checkpoint.FILE
        return self

    def _take_lock(self):
        import fcntl
        problem = lock_problem(self.out)
        if problem:
            raise FolderUnusable(problem)
        try:
            fh = open(self.out / LOCK, "a+")
        except OSError as exc:
            raise FolderUnusable(f"cannot open the folder's lock {self.out / LOCK} "
                                 f"({exc.strerror or exc})") from None
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise FolderInUse(f"another run is writing to {self.out}") from None
        self._lock = fh

    def __exit__(self, *exc):
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
        if self._lock is not None:
            try:
                os.unlink(self.out / LOCK)
            except OSError:
                pass
            self._lock.close()
            self._lock = None
        if self._created:
            try:
                self.out.rmdir()             # only if nothing was kept
            except OSError:
                pass

    def path(self, name: str) -> Path:
        return self.tmp / name

    def publish(self, result, extra: list[str]) -> list[str]:
        """Write the scene, the series, the arches, the final state and the summary
        beside the files ``extra`` already staged (the checkpoint among them when it
        waited here), then move them all into the folder (summary last) and record
        them in the manifest; returns the names written. The files an earlier run
        wrote and this one does not are removed (a run continued in place too: its
        result is the whole run's). Nothing the runs of this project did not write
        is touched."""
        statuses = [r["status"] for r in result.summary["realizations"]]
        write_resolved_scene(result.scene, self.tmp, result.notes)
        write_series(result.series, statuses, self.tmp, result.summary["species"],
                     result.series_species)
        write_arches(result.arches, statuses, self.tmp)
        write_final_state(result, self.tmp)
        names = ["scene.resolved.toml", "escapees.csv", "arches.csv", FINAL_STATE, *extra]
        if result.flow:
            write_flow(result.flow, statuses, self.tmp)
            names.insert(2, "flow.csv")
        if result.throats:
            write_throats(result.throats, statuses, self.tmp)
            names.insert(names.index("escapees.csv") + 1, "throats.csv")
        if result.network:
            write_network(result.network, statuses, result.summary["network"]["throats"],
                          self.tmp)
            names.insert(names.index("throats.csv") + 1, "network.csv")
        write_summary(result.summary, self.tmp)
        earlier = owned_files(self.out)
        kept = set(names) | {"summary.json", checkpoint.FILE}
        # the manifest first names every file this and the earlier run wrote, so
        # that a crash part-way leaves no file of ours unlisted
        _write_manifest(self.out, kept | earlier)
        for name in names:
            _replace(self.tmp / name, self.out / name)
        for name in earlier - kept:
            _remove(self.out / name)
        _replace(self.tmp / "summary.json", self.out / "summary.json")
        _write_manifest(self.out, {n for n in kept if os.path.lexists(self.out / n)})
        return names + ["summary.json"]


def _remove_stale_staging(out: Path):
    """Remove the staging folders in ``out`` that runs killed hard left holding no
    checkpoint (empty, or only files cut short). Called with ``out``'s lock held, so
    that no run alive writes them; a staging folder with a checkpoint is kept for
    ``--resume``."""
    try:
        folders = [p for p in out.iterdir() if p.name.startswith(STAGING_PREFIX)]
    except OSError:
        return
    for folder in folders:
        try:
            if folder.is_symlink() or not folder.is_dir():
                continue
            names = [p.name for p in folder.iterdir()]
        except OSError:
            continue
        if all(n.endswith((".part", ".part.mp4")) for n in names):
            shutil.rmtree(folder, ignore_errors=True)


def _write_manifest(out: Path, names):
    atomic_write(out / MANIFEST, json.dumps({"files": sorted(names)}) + "\n")


def _replace(src: Path, dst: Path):
    """Move ``src`` to ``dst`` (a file is replaced atomically; a folder replaces
    the old folder of that name)."""
    if src.is_dir():
        _remove(dst)
    os.replace(src, dst)


def _remove(path: Path):
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif os.path.lexists(path):
        path.unlink()


class CheckpointClock:
    """``on_chunk`` hook of a run: a checkpoint every ``every`` seconds of wall
    time (0: never during the run), at the staging's checkpoint path."""

    def __init__(self, sim, staged: Staging, every: float):
        self.sim, self.staged, self.every = sim, staged, float(every)
        self.last = time.perf_counter()
        self.saved = 0

    def __call__(self, sim):
        if self.every > 0 and time.perf_counter() - self.last >= self.every:
            self.save()

    def save(self, path: Path | None = None):
        checkpoint.save(self.sim, path or self.staged.checkpoint_path)
        self.last = time.perf_counter()
        self.saved += 1


class Pictures:
    """What a run draws while it goes: the video (and the live viewer), the ParaView
    series, and at the end the plots; each into the staging folder. With
    ``moving=False`` only the plots (a sweep's points)."""

    def __init__(self, sim, staged: Staging, view: bool = False, quiet: bool = False,
                 resume_dir: Path | None = None, moving: bool = True):
        self.sim, self.staged = sim, staged
        self.recorder = None
        self.vtk = None
        self.notes: dict = {}
        #: what was asked for and could not be drawn (one line), once finished
        self.failed: str | None = None
        sc = sim.scene
        if not moving:      # the plots only (a sweep's point): no video, viewer, series
            return
        viewer = None
        if view:
            from .render.viewer import LiveViewer, display_available
            ok, why = display_available()
            if ok:
                viewer = LiveViewer(staged.out, title=f"taichi_hsdem: {sc.name}")
            elif not quiet:
                print(f"--view skipped: {why}", file=sys.stderr)
        if sc.output.video or viewer is not None:
            from .render import VideoRecorder, vulkan_status
            ok, why = vulkan_status()
            if ok:
                self.recorder = VideoRecorder(
                    sim, staged.path("video.mp4") if sc.output.video else None, viewer=viewer)
            else:
                self.notes["video"] = {"file": None, "skipped": why}
                # the user asked for a picture: say so even with --quiet
                print(f"rendering skipped: {why}", file=sys.stderr)
        if sc.output.vtk:
            from .paraview import ParaViewUnavailable
            try:
                self.vtk = _series_writer(sim, staged, resume_dir)
            except ParaViewUnavailable as exc:
                self.notes["vtk"] = {"skipped": str(exc)}
                print(f"ParaView output skipped: {exc}", file=sys.stderr)

    @property
    def frame_times(self):
        if self.recorder is not None:
            return self.recorder.frame_times
        if self.vtk is not None:
            return [float(t) for t in np.linspace(0.0, self.sim.scene.run.t_end,
                                                  self.sim.scene.output.frames)]
        return None

    def on_frame(self, sim):
        if self.recorder is not None:
            self.recorder(sim)
        if self.vtk is not None:
            _vtk_frame(self.vtk, sim)

    def discard(self):
        """The run failed: close without keeping anything."""
        if self.recorder is not None:
            self.recorder.close(keep=False)
        if self.vtk is not None:
            self.vtk.close()

    def finish(self, result):
        """Close the writers, draw the plots; record each in the summary."""
        summary = result.summary
        if self.recorder is not None:
            self.recorder.close(keep=True)
            summary["video"] = self.recorder.summary(summary["wall_time_s"])
            if self.recorder.error is not None and self.recorder.path is not None:
                self.failed = f"video not written: rendering failed ({self.recorder.error})"
            if not self.staged.path("video.mp4").exists():
                # e.g. a continued run with no frame time left: name no file
                summary["video"]["file"] = None
                if self.recorder.error is None:
                    summary["video"]["skipped"] = "no frame fell in this run"
        if self.vtk is not None:
            self.vtk.close()
            summary["vtk"] = {"index": "series.pvd", "frames": self.vtk_frames}
        summary.update(self.notes)
        try:
            summary["plots"] = report.plot_run(result, self.staged.tmp,
                                               law=report.steady_stream_law(self.sim))
            if self.sim.throats.network:
                summary["plots"].update(self._network(result))
        except (ImportError, MemoryError) as exc:
            # e.g. under a tight `ulimit -v` matplotlib's compiled part cannot be
            # mapped: the results stand, the plots do not
            why = f"{type(exc).__name__}: {' '.join(str(exc).split())[:160]}"
            for png in self.staged.tmp.glob("*.png"):
                png.unlink()
            summary["plots"] = {"skipped": f"the plots could not be drawn ({why}); the "
                                           "results are complete"}
            print(f"plots skipped: they could not be drawn ({why}); the results are "
                  "complete", file=sys.stderr)

    def _network(self, result) -> dict:
        """The empty domain's flow (K0) and each realization's last K/K0 into the
        summary's ``network`` entry, and the network plots; returns what was drawn."""
        sim, net = self.sim, result.summary.setdefault("network", {})
        empty = None
        if sim.fluid is not None:
            from .fluid import FluxImbalanceError
            try:
                empty = report.empty_flow(sim.model)
            except FluxImbalanceError as exc:
                net["empty_skipped"] = f"the empty domain's solve failed: {exc}"
        if empty is not None:
            net["empty"] = {"pressure_drop": empty[0], "flow_rate": empty[1]}
            last = {r: float(k[-1]) for r, (_, k) in
                    report.permeability_ratio(result.flow, empty).items()}
            for r, row in enumerate(net.get("realizations", [])):
                if row is not None:
                    row["permeability_ratio"] = last.get(r)
        return report.plot_network(result, self.staged.tmp, sim.throats, sim.model.geometry,
                                   empty)

    @property
    def vtk_frames(self) -> int:
        return getattr(self.vtk, "frames_written", 0)

    def files(self) -> list[str]:
        """The staged files to publish."""
        names = ["video.mp4", *PLOTS, "series.pvd", "vtk"]
        return [n for n in names if (self.staged.tmp / n).exists()]


def vtk_realizations(scene) -> list[int]:
    """The realizations the ParaView series holds (``output.vtk_realizations``)."""
    from .scene.keys import vtk_indices
    o = scene.output
    return vtk_indices(o.vtk_realizations, scene.run.realizations, o.video_realization)


def _series_writer(sim, staged: Staging, resume_dir: Path | None):
    from .geometry.shapes import outline_polygon
    from .paraview import FluidGrid, SeriesWriter
    m = sim.model
    g = m.geometry
    grid = None
    if sim.fluid is not None:
        grid = FluidGrid(origin=(g.x_min, g.y_min), spacing=m.fluid_dx, active=m.fluid_active)
    old = None if resume_dir is None else Path(resume_dir)
    if old is not None and (old / "vtk").is_dir() and (old / "series.pvd").is_file():
        # go on with the earlier part's series
        shutil.copytree(old / "vtk", staged.path("vtk"))
        shutil.copy2(old / "series.pvd", staged.path("series.pvd"))
    return SeriesWriter(staged.tmp, vtk_realizations(sim.scene), g.outline, list(g.obstacles),
                        [outline_polygon(s.shape) for s in m.species], grid,
                        resume=sim.t if resume_dir is not None else None)


def _vtk_frame(writer, sim):
    st = pressure = kappa = None
    for r in vtk_realizations(sim.scene):
        last = writer.last_time(r)
        if last is not None and sim.t <= last:
            continue               # a resumed run's first frame: the series has it
        if st is None:
            st = sim.state()
            if sim.fluid is not None:
                pressure = sim.pressure()
                kappa = sim.fluid.kappa.to_numpy().astype(float)
        writer.write_frame(sim.t, st["x"][r], st["theta"][r], st["v"][r], st["omega"][r],
                           st["alive"][r], st["species"],
                           pressure=None if pressure is None else pressure[r],
                           permeability=None if kappa is None else kappa[r], realization=r)
