"""The points of a figure: which scenes each command runs (the paper's settings,
with ``--quick`` versions), running a point's realizations, and keeping finished
points in ``<out>/points/`` so that a rerun resumes where it stopped."""
from __future__ import annotations

import hashlib
import json
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.walls import fluid_area
from ..output import atomic_write, json_safe
from ..resolve import species_shape
from ..scene import Scene, load_scene, scene_to_toml
from ..digest import code_digest
from .progress import PointProgress


FIGURES = ("escapees-time", "pmf-collapse", "friction", "shapes", "polygons")


DEFAULT_REALIZATIONS = 10


PAPER_REALIZATIONS = 100


QUICK_BOX = 6.0                 # quick mode: upstream channel QUICK_BOX x QUICK_BOX d_b


QUICK_CLOG_WINDOW = 0.15        # s


QUICK_CELLS_PER_DB = 5.0        # quick mode, level-set scenes: fluid cell d_b / 5


#: quick mode: long enough to clog (the vani scene's first escapes come at about
#: 0.5 s, its clogs after <s> = 8 of them at 11 a second; at 0.5 s, as before,
#: nothing had clogged); a run that clogs stops there. The level-set figures' too,
#: since their steps run many to a launch (about 12 s of wall time a simulated
#: second for the quick polygons' point, 170 before)
QUICK_T_END = 3.0               # s


_REPO = Path(__file__).resolve().parents[2]


# Per command: base scene, overrides of the command, quick realizations and t_end.
SPEC = {
    "escapees-time": dict(scene="vani_phi026.toml", fixed=["run.stop_at_clog=false"],
                          quick_realizations=2, quick_t_end=QUICK_T_END, level_set=False),
    "pmf-collapse": dict(scene="vani_phi026.toml", fixed=["run.stop_at_clog=true"],
                         quick_realizations=3, quick_t_end=QUICK_T_END, level_set=False),
    "friction": dict(scene="vani_phi026.toml", fixed=["run.stop_at_clog=true"],
                     quick_realizations=3, quick_t_end=QUICK_T_END, level_set=False),
    "shapes": dict(scene="squares.toml", fixed=["run.stop_at_clog=true", "particles.friction=0.4"],
                   quick_realizations=2, quick_t_end=QUICK_T_END, level_set=True),
    "polygons": dict(scene="polygons.toml",
                     fixed=["run.stop_at_clog=true", "particles.friction=0.4"],
                     quick_realizations=2, quick_t_end=QUICK_T_END, level_set=True),
}


DEFAULT_POINTS = {
    "escapees-time": dict(phi=(0.086, 0.17, 0.26)),
    "pmf-collapse": dict(phi=(0.19, 0.26, 0.32)),
    "friction": dict(mu=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9), phi=0.26),
    "shapes": dict(ratios=(1.7, 1.2)),
    "polygons": dict(vertices=(3, 4, 5, 6), ratio=1.2),
}


QUICK_POINTS = {
    "friction": dict(mu=(0.1, 0.5, 0.9)),
    "polygons": dict(vertices=(3, 4, 6)),
}


class FigureError(Exception):
    """Invalid arguments or scenes: every problem, one line each."""

    def __init__(self, problems):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("\n".join(self.problems))


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
    # seed -> the realization's state where it stopped (a clog's arch, for
    # tools/arches.py): "x" (n, 2), "theta" (n), "alive" (n), "species" (n)
    finals: dict = field(default_factory=dict)

    @property
    def ok_rows(self):
        return [r for r in self.rows if r["status"] == "ok"]

    def samples(self):
        ok = self.ok_rows
        return (np.array([r["escapees"] for r in ok], dtype=np.int64),
                np.array([bool(r["clogged"]) for r in ok], dtype=bool))


def bounding_diameter(scene: Scene, species: int = 0) -> float:
    """Bounding (circumscribed) diameter ``d_b`` of a species' shape."""
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
    spec = SPEC[command]
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


def _point_info(sim) -> dict:
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


def run_point(point: Point, realizations: int, batch: int | None = None, log=None,
              head: str | None = None) -> PointRun:
    """Run ``realizations`` of a point in batches of ``batch`` (default: all at once).

    Realization ``k`` has seed ``run.seed + k`` whatever the batching. With ``log``
    (a line printer), a long batch says where it is every few seconds, headed by
    ``head`` (default: the point's label), and a batch that ends says so.
    """
    # the simulator loads Taichi (about a second): only once there is something to run
    from ..runner import RunFailed, build, execute
    out = PointRun(point)
    batch = realizations if not batch else max(1, min(int(batch), realizations))
    seed0 = point.scene.run.seed
    t0 = time.perf_counter()
    done = 0
    while done < realizations:
        n = min(batch, realizations - done)
        scene = point.scene.with_values({"run.realizations": n, "run.seed": seed0 + done})
        progress = None
        if log is not None:
            where = head or point.label
            if n < realizations:
                where += f" (realizations {done + 1}-{done + n} of {realizations})"
            progress = PointProgress(log, where)
        try:
            sim = build(scene, on_phase=getattr(progress, "phase", None))
            if not out.info:
                out.info = _point_info(sim)
            res = execute(sim, progress=progress)
        except RunFailed as exc:
            out.error = "; ".join(exc.lines)
            break
        seen = set()
        for r, t, s in res.series:
            key = (r, float(t))
            if key in seen:
                continue
            seen.add(key)
            if res.summary["realizations"][r]["status"] == "ok":
                out.series.append((res.summary["realizations"][r]["seed"], float(t), int(s)))
        fin = res.final
        for r, rr in enumerate(res.summary["realizations"]):
            out.rows.append({k: rr.get(k) for k in ("seed", "escapees", "clogged", "t_clog",
                                                    "t_stop", "status", "reason")})
            out.finals[int(rr["seed"])] = {
                "x": fin["x"][r].tolist(), "theta": fin["theta"][r].tolist(),
                "alive": fin["alive"][r].tolist(), "species": fin["species"].tolist()}
        del sim, res
        done += n
        if log is not None and done < realizations:
            log(f"  {point.label}: {done}/{realizations} realizations, "
                f"{time.perf_counter() - t0:.0f} s")
    out.wall = time.perf_counter() - t0
    return out


def series_by_seed(series):
    """``(seed, t, escapees)`` rows as ``{seed: [(t, escapees), ...]}``, each in time order."""
    out = {}
    for seed, t, s in series:
        out.setdefault(seed, []).append((t, s))
    return {k: sorted(v) for k, v in out.items()}


def point_key(point: Point, realizations: int) -> str:
    """What makes a finished point reusable: its scene (TOML text, seeds included),
    the realization count and the package code (:func:`taichi_hsdem.sweep.code_digest`).
    The batch size is left out: a realization does not depend on those beside it."""
    text = (scene_to_toml(point.scene) + f"\n# realizations {int(realizations)}"
            f"\n# code {code_digest()}")
    return hashlib.sha256(text.encode()).hexdigest()


def point_file(out: Path, point: Point) -> Path:
    """Where a finished point is kept: ``<out>/points/<label>.json``."""
    return Path(out) / "points" / (re.sub(r"[^A-Za-z0-9._=+-]+", "_", point.label) + ".json")


def save_point(path: Path, key: str, run: PointRun) -> None:
    data = {"key": key, "label": run.point.label, "wall_s": run.wall, "info": run.info,
            "rows": run.rows, "series": [list(x) for x in run.series],
            "finals": {str(k): v for k, v in run.finals.items()}}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, json.dumps(json_safe(data)) + "\n")


_ROW_KEYS = ("seed", "escapees", "clogged", "t_clog", "t_stop", "status", "reason")


def load_point(path: Path, key: str, point: Point) -> PointRun | None:
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
                        wall=float(data["wall_s"]), info=dict(data["info"]), resumed=True,
                        finals={int(k): v for k, v in data.get("finals", {}).items()})
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
