"""The arches that clog a constriction: which particles span the neck, and how they touch.

A clogged realization ends with an arch: a chain of particles, each pressed on the
next, from one side wall to the other across the constriction. The geometry here
finds it in a state (:mod:`.arch_geometry` holds it):

* **the arch** is the shortest chain (fewest particles) of touching particles from
  the lower side wall to the upper one (ties: the chain nearest the neck),
  :func:`arch_chain`;
* two outlines **touch** when their gap is at most ``tol`` times the bounding
  diameter ``d_b`` (a pressed contact has a small overlap, a negative gap); the gap
  is exact for outlines apart (the nearest points of two polygons are a vertex of
  one and an edge of the other, or a wall corner); for two convex outlines that
  overlap it is minus the penetration depth (the separating-axis test), for
  others minus the deepest vertex's depth; for two disks, and a disk and a wall,
  it comes from the centres' distances, many at once;
* a contact is **face-to-face** when an edge of one outline lies along an edge of
  the other (or along the wall): normals opposed within ``angle`` degrees and,
  over a common stretch of at least ``FACE_OVERLAP`` of the shorter edge, the one
  within ``tol d_b`` outside the other's line (or pressed into it by at most
  ``FACE_OVERLAP`` of the shorter edge); otherwise it is a **vertex** contact (a
  corner on a face or on a corner). A circle's contacts are all ``curved``.

Every run takes an arch census at its checks with :func:`arch_chain`
(:func:`taichi_hsdem.observables.census_arches`: when each arch formed, when and how
it broke, or that it held) and writes it to its folder's ``arches.csv``.

``python -m taichi_hsdem arches DIR`` (or ``python tools/arches.py DIR``) reads

* a **run folder** (``summary.json`` and ``arches.csv``): one line per
  realization (the arches formed, how the broken ones failed, the one that held:
  its particles and position) and a total line;
* a finished ``python -m taichi_hsdem figures`` **figure folder** (``figure.json``; every
  realization's final state kept in its point files, ``<out>/points/``): per
  clogged realization it finds the arch of the final state and sorts its
  contacts, and writes ``DIR/arches.csv`` (one row per clogged realization),
  ``DIR/arches.png`` (sample arches per point) and one summary line per point.
"""
from __future__ import annotations

import csv
import io
import json
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from ..exits import Parser
from ..geometry.shapes import outline_polygon, transform
from ..geometry.walls import wall_segments
from ..scene.coerce import is_finite_real, is_int
from .arch_geometry import (ArchError, DEFAULT_ANGLE, DEFAULT_TOL, FACE_OVERLAP, Sides,  # noqa: F401
                            arch_chain, find_arch, pair_gap, pair_kind, wall_kind,
                            world_outline)


# ----------------------------------------------------------------------------
# A figure folder
# ----------------------------------------------------------------------------

def _point_models(folder: Path):
    """``[(label, model, point data)]`` of a finished figure folder."""
    from ..resolve import resolve
    from ..scene import SceneError, load_scene

    try:
        fig = json.loads((folder / "figure.json").read_text())
    except (OSError, ValueError) as exc:
        raise ArchError(f"{folder}: no readable figure.json ({exc}); run python -m "
                        f"taichi_hsdem figures into it first") from None
    from .points import Point, point_file
    problem = _figure_json_problem(fig)
    if problem:
        raise ArchError(f"{folder / 'figure.json'}: {problem}: not the figure.json of a "
                        "finished figure (python -m taichi_hsdem figures writes it)")
    try:
        base = load_scene(fig["scene"], [str(o) for o in fig.get("base_overrides") or []])
        scenes = [base.with_values(dict(p["overrides"])) for p in fig["points"]]
    except SceneError as exc:
        raise ArchError("; ".join(exc.problems)) from None
    out = []
    for p, scene in zip(fig["points"], scenes):
        path = point_file(folder, Point(str(p["label"]), p["values"], scene))
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            raise ArchError(f"{path}: missing or unreadable; rerun the figure") from None
        if not isinstance(data, dict) or not isinstance(data.get("rows"), list):
            raise ArchError(f"{path}: not a point file of a figure (no \"rows\"); rerun the "
                            "figure")
        if not data.get("finals"):
            raise ArchError(f"{path}: no final states (point files written before they were "
                            f"kept); rerun the figure with --no-resume")
        model = resolve(scene.with_values({"run.realizations": 1}))
        problem = _point_problem(data, len(model.species))
        if problem:
            raise ArchError(f"{path}: damaged point file: {problem}; rerun the figure with "
                            "--no-resume")
        out.append((p["label"], model, data))
    return out


def _point_problem(data: dict, n_species: int) -> str | None:
    """What a point file's ``rows`` and ``finals`` lack that :func:`analyse_folder`
    and :func:`draw` read, or None: every row an object with its seed, escapees,
    clogged and status; the final state of each clogged realization an object of
    equally long lists ``x`` (pairs of finite numbers), ``theta`` (finite
    numbers), ``alive`` and ``species`` (indices of the scene's species)."""
    finals = data["finals"]
    if not isinstance(finals, dict):
        return '"finals" is not an object'
    for k, r in enumerate(data["rows"]):
        if not (isinstance(r, dict) and all(key in r for key in
                                            ("seed", "escapees", "clogged", "status"))):
            return f'row {k} lacks its "seed", "escapees", "clogged" or "status"'
        if not (is_int(r["seed"]) and isinstance(r["status"], str)
                and (r["escapees"] is None or is_finite_real(r["escapees"]))):
            return f'row {k}: its "seed", "escapees" or "status" is of the wrong type'
        if r["status"] != "ok" or not r["clogged"] or str(r["seed"]) not in finals:
            continue
        fs = finals[str(r["seed"])]
        where = f'the final state of seed {r["seed"]}'
        if not (isinstance(fs, dict) and all(isinstance(fs.get(key), list) for key in
                                             ("x", "theta", "alive", "species"))):
            return f'{where} lacks its "x", "theta", "alive" or "species" list'
        n = len(fs["x"])
        if any(len(fs[key]) != n for key in ("theta", "alive", "species")):
            return f'{where}: "x", "theta", "alive" and "species" differ in length'
        if not all(isinstance(xi, list) and len(xi) == 2 and all(map(is_finite_real, xi))
                   for xi in fs["x"]):
            return f'{where}: "x" is not a list of pairs of finite numbers'
        if not all(map(is_finite_real, fs["theta"])):
            return f'{where}: "theta" is not a list of finite numbers'
        if not all(isinstance(a, (bool, int)) for a in fs["alive"]):
            return f'{where}: "alive" is not a list of booleans'
        if not all(is_int(sp) and 0 <= sp < n_species for sp in fs["species"]):
            return (f'{where}: "species" holds other than the scene\'s species indices '
                    f'(0 to {n_species - 1})')
    return None


def _figure_json_problem(fig) -> str | None:
    """What a figure.json lacks that :func:`_point_models` reads, or None."""
    if not isinstance(fig, dict):
        return "not a JSON object"
    if not isinstance(fig.get("scene"), str) or not fig["scene"]:
        return 'no "scene" (the base scene file)'
    if not isinstance(fig.get("base_overrides") or [], list):
        return '"base_overrides" is not a list'
    points = fig.get("points")
    if not isinstance(points, list):
        return 'no "points" list'
    if not points:
        return 'an empty "points" list (a figure has at least one point)'
    for k, p in enumerate(points):
        if not (isinstance(p, dict) and isinstance(p.get("label"), str)
                and isinstance(p.get("values"), dict) and isinstance(p.get("overrides"), dict)):
            return f'point {k} lacks its "label", "values" or "overrides"'
    return None


def analyse_folder(folder, tol=DEFAULT_TOL, angle=DEFAULT_ANGLE):
    """Per point ``(label, rows, model, data)``; a row per clogged stable realization."""
    folder = Path(folder)
    result = []
    for label, model, data in _point_models(folder):
        shapes = [s.shape for s in model.species]
        d_b = 2.0 * max(s.bounding_radius for s in shapes)
        g = model.geometry
        sides = Sides(g)
        neck_x = 0.5 * (g.constriction_x0 + g.constriction_x1)
        rows = []
        for r in data["rows"]:
            if r["status"] != "ok" or not r["clogged"]:
                continue
            fs = data["finals"].get(str(r["seed"]))
            if fs is None:
                continue
            arch = find_arch(shapes, fs["x"], fs["theta"], fs["alive"], fs["species"], sides,
                             neck_x, d_b, tol, angle)
            row = {"label": label, "seed": r["seed"], "escapees": r["escapees"],
                   "arch_found": arch is not None}
            if arch is not None:
                kinds = Counter(arch["pairs"])
                walls = Counter(arch["walls"])
                row.update({"arch_size": len(arch["particles"]),
                            "pair_face": kinds["face"], "pair_vertex": kinds["vertex"],
                            "pair_curved": kinds["curved"],
                            "wall_face": walls["face"], "wall_vertex": walls["vertex"],
                            "wall_curved": walls["curved"],
                            "particles": " ".join(map(str, arch["particles"]))})
            rows.append(row)
        result.append((label, rows, model, data))
    return result


COLUMNS = ["label", "seed", "escapees", "arch_found", "arch_size", "pair_face", "pair_vertex",
           "pair_curved", "wall_face", "wall_vertex", "wall_curved", "particles"]


def summary_line(label, rows) -> str:
    found = [r for r in rows if r["arch_found"]]
    sizes = Counter(r["arch_size"] for r in found)
    pf = sum(r["pair_face"] for r in found)
    pv = sum(r["pair_vertex"] for r in found)
    wf = sum(r["wall_face"] for r in found)
    wv = sum(r["wall_vertex"] for r in found)
    mean = np.mean([r["arch_size"] for r in found]) if found else math.nan
    parts = [f"{label}: {len(rows)} clogged, arch found in {len(found)}",
             "sizes " + ", ".join(f"{k}: {sizes[k]}" for k in sorted(sizes))
             + f" (mean {mean:.2f})" if found else "no sizes"]
    pc = sum(r["pair_curved"] for r in found)
    wc = sum(r["wall_curved"] for r in found)
    if pf + pv:
        parts.append(f"particle-particle contacts face {pf}, vertex {pv} "
                     f"({pf / (pf + pv):.0%} face)")
    if wf + wv:
        parts.append(f"on the walls face {wf}, vertex {wv}")
    if pc + wc:
        parts.append(f"curved contacts {pc} between particles, {wc} on the walls")
    return "; ".join(parts)


def draw(result, path, examples=6, tol=DEFAULT_TOL):
    """Sample arches per point, zoomed on the neck: one row of panels per point."""
    from .plots import pyplot
    plt = pyplot()
    n_rows = len(result)
    fig, axes = plt.subplots(n_rows, examples, figsize=(2.0 * examples, 2.1 * n_rows),
                             squeeze=False)
    for row_axes, (label, rows, model, data) in zip(axes, result):
        shapes = [s.shape for s in model.species]
        d_b = 2.0 * max(s.bounding_radius for s in shapes)
        g = model.geometry
        neck_x = 0.5 * (g.constriction_x0 + g.constriction_x1)
        yc = 0.5 * (g.y_min + g.y_max)
        segs = wall_segments(g)
        shown = [r for r in rows if r["arch_found"]][:examples]
        for ax, r in zip(row_axes, shown + [None] * (examples - len(shown))):
            ax.set_axis_off()
            if r is None:
                continue
            fs = data["finals"][str(r["seed"])]
            arch = set(int(i) for i in r["particles"].split())
            for i, (xi, ti, al, sp) in enumerate(zip(fs["x"], fs["theta"], fs["alive"],
                                                     fs["species"])):
                if not al or abs(xi[0] - neck_x) > 3 * d_b:
                    continue
                w = transform(outline_polygon(shapes[int(sp)]), xi, ti)
                ax.fill(w[:, 0], w[:, 1], color="tab:red" if i in arch else "0.8",
                        ec="k", lw=0.4)
            for s in segs:
                ax.plot(s[:, 0], s[:, 1], "k-", lw=1.2)
            ax.set_xlim(neck_x - 2.5 * d_b, neck_x + 0.7 * d_b)
            ax.set_ylim(yc - 1.6 * d_b, yc + 1.6 * d_b)
            ax.set_aspect("equal")
            faces = r["pair_face"] + r["wall_face"]
            corners = r["pair_vertex"] + r["wall_vertex"]
            ax.set_title(f"seed {r['seed']}: {r['arch_size']} (f{faces}/v{corners})", fontsize=7)
        row_axes[0].text(-0.05, 0.5, label, transform=row_axes[0].transAxes, rotation=90,
                         ha="right", va="center", fontsize=8)
    fig.suptitle(f"clogging arches (red; flow left to right; touching: gap <= {tol:g} d_b; "
                 f"f/v: face/vertex contacts)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------
# A run folder
# ----------------------------------------------------------------------------

#: arches.csv's columns in a run folder (output.write_arches).
RUN_COLUMNS = ["realization", "arch", "t_formed", "t_broken", "held", "count", "ids",
               "x_over_d", "failure"]


def read_run(folder: Path):
    """``(summary, arches)`` of a run folder: its summary.json, and its arches.csv
    as one list of row dicts (text values) per realization."""
    try:
        summary = json.loads((folder / "summary.json").read_text())
        n = len(summary["realizations"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ArchError(f"{folder}/summary.json: not a run's summary ({exc})") from None
    path = folder / "arches.csv"
    if not path.is_file():
        raise ArchError(f"{path}: missing: the run was made before runs took an arch census; "
                        "run the scene again")
    arches = [[] for _ in range(n)]
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            if reader.fieldnames != RUN_COLUMNS:
                raise ValueError(f"columns {reader.fieldnames}, not {RUN_COLUMNS}")
            for row in reader:
                arches[int(row["realization"])].append(row)
    except (OSError, ValueError, IndexError) as exc:
        raise ArchError(f"{path}: not a run's arches.csv ({exc})") from None
    return summary, arches


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}es"


def _failures(rows) -> str:
    """How the broken arches of ``rows`` failed: ``2 escaped, 1 slid``."""
    counts = Counter(r["failure"] for r in rows if r["held"] != "true")
    return ", ".join(f"{counts[k]} {k}" for k in ("escaped", "rolled", "slid") if counts[k])


def run_lines(summary, arches) -> list[str]:
    """One line per realization of a run folder (:func:`read_run`): the arches
    formed, how the broken ones failed, the one that held (its particles from the
    lower wall up and its position: x of their mean less the neck's, over the
    smallest d_eq); and a total line."""
    lines = []
    for k, (real, rows) in enumerate(zip(summary["realizations"], arches)):
        head = f"realization {k} (seed {real['seed']}): "
        if real["status"] == "unstable":
            lines.append(head + "went unstable, no arches counted")
            continue
        parts = [_plural(len(rows), "arch") + " formed"]
        if _failures(rows):
            parts.append(f"broken: {_failures(rows)}")
        held = [r for r in rows if r["held"] == "true"]
        parts += [f"held: particles {r['ids']} at x = {float(r['x_over_d']):+.2f} d from "
                  f"the neck, formed at t = {float(r['t_formed']):.4g}" for r in held] or [
            "none held"]
        lines.append(head + "; ".join(parts))
    counted = [rows for real, rows in zip(summary["realizations"], arches)
               if real["status"] != "unstable"]
    every = [r for rows in counted for r in rows]
    held = sum(r["held"] == "true" for r in every)
    total = (f"total: {_plural(len(every), 'arch')} formed in {len(counted)} "
             f"realization{'' if len(counted) == 1 else 's'}, {held} held")
    if _failures(every):
        total += f"; broken: {_failures(every)}"
    return lines + [total]


def _parser(prog: str) -> Parser:
    p = Parser(prog=prog, description="The arches of a run folder (its arch census), or the "
                                      "clogging arches of a finished figures folder.")
    p.add_argument("folder", help="a run's output folder, or a figure's --out folder")
    p.add_argument("--tol", type=float, default=None,
                   help=f"figure folders: touching: gap at most this times d_b (default "
                        f"{DEFAULT_TOL})")
    p.add_argument("--angle", type=float, default=None,
                   help=f"figure folders: face-to-face: normals opposed within this many "
                        f"degrees (default {DEFAULT_ANGLE:g})")
    p.add_argument("--examples", type=int, default=None,
                   help="figure folders: arches drawn per point (default 6)")
    return p


def main(argv=None, prog: str = "python -m taichi_hsdem arches") -> int:
    """Command line; exit 0 on success, 2 for invalid input."""
    try:
        args = _parser(prog).parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    folder = Path(args.folder)
    options = [f"--{k}" for k in ("tol", "angle", "examples") if getattr(args, k) is not None]
    if not (folder / "figure.json").exists():
        if not (folder / "summary.json").exists():
            print(f"{folder}: neither a run folder (no summary.json) nor a figure folder "
                  f"(no readable figure.json)", file=sys.stderr)
            return 2
        if options:
            print(f"{', '.join(options)}: for figure folders; a run's arch census was taken "
                  f"during the run (touching: gap <= {DEFAULT_TOL:g} d_b)", file=sys.stderr)
            return 2
        try:
            summary, arches = read_run(folder)
        except ArchError as exc:
            print(str(exc), file=sys.stderr)
            return 2
        if summary.get("arches_formed") is None:
            print(f"{folder}: the run took no arch census: its geometry is not a channel with "
                  "two side walls and no obstacles")
            return 0
        print("\n".join(run_lines(summary, arches)))
        return 0
    tol = DEFAULT_TOL if args.tol is None else args.tol
    angle = DEFAULT_ANGLE if args.angle is None else args.angle
    examples = 6 if args.examples is None else args.examples
    problems = []
    if not (0 < tol < 1):
        problems.append(f"--tol must be in (0, 1), got {tol:g}")
    if not (0 < angle < 90):
        problems.append(f"--angle must be in (0, 90) degrees, got {angle:g}")
    if examples < 1:
        problems.append(f"--examples must be >= 1, got {examples}")
    if problems:
        print("\n".join(problems), file=sys.stderr)
        return 2
    try:
        result = analyse_folder(folder, tol, angle)
    except ArchError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    from .folder import StudyFolder, StudyFolderError
    try:
        name = _figure_name(folder)
        with StudyFolder(folder, f"figures {name}" if name else "figures", key=str(folder),
                         legacy=_legacy_files) as study:
            study.refuse_foreign(FILES, "the arch census")
            study.claim(FILES)
            _write(folder, result, examples, tol)
    except StudyFolderError as exc:
        print("\n".join(exc.problems), file=sys.stderr)
        return 2
    return 0


#: The files the census of a figure folder writes there.
FILES = ("arches.csv", "arches.png")


def _figure_name(folder: Path):
    try:
        return json.loads((folder / "figure.json").read_text()).get("figure")
    except (OSError, ValueError, AttributeError):
        return None


def _legacy_files(folder: Path) -> list[str]:
    """The figure's files and the census's in a figure folder of an earlier
    version (no study manifest), told by what they hold."""
    from .figures import _legacy_files as figure_files
    name = _figure_name(folder)
    names = list(figure_files(name)(folder)) if name else []
    try:
        with open(folder / "arches.csv", encoding="utf-8", errors="replace") as fh:
            if names and fh.readline().rstrip("\n") == ",".join(COLUMNS):
                names += [n for n in FILES if (folder / n).exists()]
    except OSError:
        pass
    return names


def _write(folder: Path, result, examples: int, tol: float):
    from ..output import atomic_write
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for _, rows, _, _ in result:
        for r in rows:
            w.writerow([r.get(k, "") for k in COLUMNS])
    atomic_write(folder / "arches.csv", buf.getvalue())
    for label, rows, _, _ in result:
        print(summary_line(label, rows))
    draw(result, folder / "arches.png", examples, tol)
    print(f"wrote {folder}/arches.csv, arches.png")
