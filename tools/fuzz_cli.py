"""Fuzz the command line: seeded cases over the whole argument and scene space,
each run in-process through ``taichi_hsdem.cli.main(argv)``.

Families: ``--set`` overrides (values inside, at and past every documented range,
wrong types, extreme-but-valid combinations); TOML edge cases (duplicate keys,
control characters, deep nesting, huge arrays, cut or flipped bytes); bad
polygons (self-intersecting, zero-area, collinear, too many vertices) for
particles, outlines and obstacles; ``--resume`` on corrupted or foreign
checkpoints (copies of one real checkpoint, made once); paths with odd
characters (spaces, unicode, newlines, very long, dangling links, link loops);
and argument garbage; and the study commands (``StudyCases``: sweep files
broken in random ways, ``figures``, ``calibrate`` and ``arches`` with bad
arguments, folders and figure files, and signals sent to short studies run as
processes).

A case passes when ``main`` returns 0, 1, 2, 130, 143 or 129, writes a message on stderr
when not 0, shows no traceback or "internal error", lets no exception escape,
and leaves no complete-looking result (``summary.json`` with status
"complete") from a failed run. Valid scenes run for real, at most
``--valid-runs`` of them and each cut to a few dozen steps; past that, a valid
case is resolved (every check before the run) but not run. Interrupt cases
(SIGINT, SIGTERM or SIGHUP after a random delay) always run, up to a few thousand
steps; each must exit 128 + the signal's number with one line and leave no lock
or staging folder. Each case runs in a fresh working folder of its own, which it
must leave empty (but for ``runs/`` of a run or study that succeeded or was stopped
there); a refused case (exit 2) writes nothing anywhere, and a study's case
says at most ``MAX_LINES`` lines.

    nice -n 10 python tools/fuzz_cli.py --cases 2000 --seed 0

prints a table (cases, exit codes, failures, wall time) and each failure with its
arguments and stderr; exit status 1 when any case failed.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from taichi_hsdem import checkpoint, output, runner  # noqa: E402
from taichi_hsdem.cli import main  # noqa: E402
from taichi_hsdem.scene.keys import SECTIONS, SpeciesConfig, key_specs  # noqa: E402


SCENES = ROOT / "scenes"
BASES = ["hourglass24", "vani_phi026", "squares", "polygons", "concave"]
STEPS = 30            # DEM steps a valid run is cut to
STOPS = (130, 143, 129)     # 128 + SIGINT's, SIGTERM's, SIGHUP's number
EXITS = (0, 1, 2, *STOPS)
STUDIES = ("sweep", "figures", "calibrate", "arches", "study_signal")
QUIET_WARNINGS = (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                  ResourceWarning)
MAX_LINES = 12        # a study's refusal: a line per problem, a few problems
# Keys whose large valid values only make a run long, not wrong: kept small.
SIZE = {"run.realizations": 3, "particles.count": 30, "particles.nodes": 60,
        "output.frames": 4, "output.fps": 30, "output.width": 128, "particles.n_vertices": 8}
# Never fuzzed through --set: they start other machinery (video encoding, a window,
# another backend); their own tests cover them.
SKIP = {"output.video", "output.vtk", "run.arch", "run.precision"}
EXTREMES = ["0", "-1", "1e-300", "1e300", "-1e300", "inf", "-inf", "nan", "5e-324", "1e-30",
            "1e30", "2e308", "9223372036854775808", "-0.0", "1_000", "0x10", "1e-9", "1e9"]
WRONG = ['"auto"', '"text"', "true", "[1.0, 2.0]", "[[0.0, 0.0]]", '"nan"', "{a = 1}", '""',
         '"\\u0000"', "[[[[1]]]]", "1979-05-27", '"' + "x" * 5000 + '"', "[]", "'''a\nb'''"]


# ------------------------------------------------------------ the study commands
# Their cases: sweep files malformed in random ways (bad TOML, unknown keys, bad
# grids, bad point values, grids past the point limit, --out a file or a dangling
# link), figures, calibrate and arches with bad arguments, folders and figure
# files, short valid studies, and SIGINT, SIGTERM or SIGHUP sent at a random moment
# to a short study run as its own process (python -m taichi_hsdem, whose entry
# point installs the handlers a study relies on).
HOURGLASS = (SCENES / "hourglass24.toml").as_posix()
# A valid sweep of two short points (each a fraction of a second of DEM).
SWEEP = (f'scene = "{HOURGLASS}"\n[common]\n"run.t_end" = 0.05\n"run.realizations" = 1\n'
         '[grid]\n"particles.friction" = [0.2, 0.4]\n')
FIGURES = ["escapees-time", "pmf-collapse", "friction", "shapes", "polygons"]
BAD_NUMBERS = ["0", "-1", "nan", "inf", "-inf", "1e300", "x", "", "1e-300", "99999999999"]


class StudyCases:
    """Case builders for the study commands (needs ``rng``, ``path``, ``out``,
    ``self.ck``: the folders of two finished runs)."""

    def sweep_text(self) -> str:
        """A sweep file, valid or broken in one of many ways."""
        r = self.rng
        text = SWEEP
        kind = r.choice(["valid", "cut", "flip", "dup_key", "control", "binary", "empty",
                         "unknown_top", "unknown_key", "grid_scalar", "grid_empty",
                         "grid_mixed", "grid_nested", "point_value", "point_key", "huge_grid",
                         "big_grid", "no_scene", "scene_missing", "scene_dir", "scene_self",
                         "scene_relative", "points_empty", "points_table", "grid_and_point",
                         "folder_name", "common_bad", "deep"])
        if kind == "cut":
            text = text[:r.randrange(len(text))]
        elif kind == "flip":
            data = bytearray(text.encode())
            for _ in range(r.randint(1, 4)):
                data[r.randrange(len(data))] = r.randrange(256)
            text = data.decode("utf-8", "replace")
        elif kind == "dup_key":
            text += '"particles.friction" = [0.3]\n'
        elif kind == "control":
            i = r.randrange(len(text))
            text = text[:i] + chr(r.choice([0, 1, 8, 27, 127])) + text[i:]
        elif kind == "binary":
            text = "".join(chr(r.randrange(1, 256)) for _ in range(500))
        elif kind == "empty":
            text = r.choice(["", "\n", "[grid]\n", "scene = 1\n"])
        elif kind == "unknown_top":
            text = "sceen = 'x'\n" + text
        elif kind == "unknown_key":
            text += f'"{r.choice(["particles.frction", "nosuch.key", "run", "particles.9.count", "x"])}" = [1, 2]\n'
        elif kind == "grid_scalar":
            text = text.replace("[0.2, 0.4]", r.choice(["0.2", '"0.2"', "{a = 1}", "true"]))
        elif kind == "grid_empty":
            text = text.replace("[0.2, 0.4]", "[]")
        elif kind == "grid_mixed":
            text = text.replace("[0.2, 0.4]", r.choice(['[0.2, "x"]', "[0.2, [0.4]]",
                                                        "[0.2, nan]", "[0.2, 0.2]"]))
        elif kind == "grid_nested":
            text = text.replace('[grid]\n"particles.friction" = [0.2, 0.4]',
                                "[grid.particles]\nfriction = [0.2, 0.4]\n[grid.run]\n"
                                "seed = [1, 2]")
        elif kind == "point_value":
            value = r.choice(["-1", "1e300", "nan", "inf", '"x"', "true", "[1]", "1e-300",
                              "0", "100"])
            key = r.choice(["particles.friction", "run.t_end", "particles.count",
                            "run.realizations", "fluid.gap", "run.dt"])
            text += f'[[points]]\n"{key}" = {value}\n'
        elif kind == "point_key":
            text += f'[[points]]\n"{r.choice(["run.arch", "name", "output.dir", "x.y"])}" = "a/b"\n'
        elif kind == "huge_grid":
            n = r.choice([11, 20, 30, 1000])
            keys = ["particles.friction", "particles.restitution", "run.seed", "damping.xi",
                    "particles.density", "fluid.p_in", "contact.overlap_target",
                    "particles.diameter", "clog.window", "output.series_interval"]
            text = text.replace('[grid]\n"particles.friction" = [0.2, 0.4]', "[grid]\n" + "".join(
                f'"{k}" = [{", ".join(str(0.1 + i / (10 * n)) for i in range(n))}]\n'
                for k in keys[:r.choice([3, 4, 10])]))
        elif kind == "big_grid":          # under the point limit, validated point by point
            text = text.replace("[0.2, 0.4]", "[" + ", ".join(
                str(0.1 + i / 1000) for i in range(r.choice([40, 200]))) + "]")
        elif kind == "no_scene":
            text = text.replace(f'scene = "{HOURGLASS}"\n', "")
        elif kind == "scene_missing":
            text = text.replace(HOURGLASS, "nowhere/none.toml")
        elif kind == "scene_dir":
            text = text.replace(HOURGLASS, SCENES.as_posix())
        elif kind == "scene_self":
            text = text.replace(HOURGLASS, "sweep.toml")
        elif kind == "scene_relative":
            text = text.replace(HOURGLASS, "../" * 40 + HOURGLASS.lstrip("/"))
        elif kind == "points_empty":
            text = text.replace('[grid]\n"particles.friction" = [0.2, 0.4]\n', "[[points]]\n")
        elif kind == "points_table":
            text += '[points]\n"particles.friction" = 0.3\n'
        elif kind == "grid_and_point":
            text += '[[points]]\n"particles.friction" = 0.9\n"run.seed" = 3\n'
        elif kind == "folder_name":
            text = text.replace("[0.2, 0.4]", r.choice(['["a/b", "c"]', '["..", "."]',
                                                        '["' + "n" * 300 + '"]']))
            text = text.replace('"particles.friction"', '"name"')
        elif kind == "common_bad":
            text = text.replace('"run.t_end" = 0.05', r.choice(['"run.t_end" = -1',
                                                                '"run.t_end" = "x"',
                                                                '"run.t_end" = [1]',
                                                                '"run.dt" = 1e300']))
        elif kind == "deep":
            text += "[grid.a.b.c.d.e.f.g.h.i.j.k.l.m.n.o.p.q.r.s.t.u.v.w.x.y.z]\nq = [1]\n"
        return text

    def case_sweep(self):
        r = self.rng
        path = self.path("sweep.toml")
        path.write_text(self.sweep_text())
        args = ["sweep", str(path)]
        out = self.path("out")
        how = r.choice(["plain", "plain", "plain", "file", "dangling", "under_file", "empty",
                        "default", "point_file"])
        if how == "file":
            out.write_text("mine")
        elif how == "dangling":
            out.symlink_to(out.parent / "nowhere")
        elif how == "under_file":
            out.write_text("mine")
            out = out / "sub"
        elif how == "point_file":                 # a file where a point's folder goes
            out.mkdir()
            (out / "particles.friction=0.2").write_text("mine")
        if how == "empty":
            args += ["--out", ""]
        elif how != "default":
            args += ["--out", str(out)]
        args += ["--quiet"] if r.random() < 0.9 else []
        for _ in range(r.choice([0, 0, 1, 2])):
            args += r.choice([["--set", "particles.friction=0.3"], ["--set", "run.t_end=-1"],
                              ["--set", "run.seed=2"], ["--set", "nosuch=1"], ["--set", "="],
                              ["--quick"], ["--no-resume"], ["--cluster", "nowhere:1"],
                              ["--cluster", "local:0"], ["--bogus"], ["--set"]])
        return args

    def case_figures(self):
        r = self.rng
        figure = r.choice(FIGURES + ["nosuch", "", "--help"] if r.random() < 0.2 else FIGURES)
        args = ["figures", figure, "--out", str(self.path("out"))]
        args += ["--quiet"] if r.random() < 0.9 else []
        for _ in range(r.randint(1, 3)):
            option = r.choice(["--realizations", "--seed", "--batch", "--phi", "--mu",
                               "--scene", "--set", "--cluster", "--out", "--bogus"])
            if option == "--scene":
                args += [option, r.choice([str(self.path("none.toml")), str(SCENES),
                                           self.broken_scene(), "",
                                           str(SCENES / "micromodel.toml")])]
            elif option == "--set":
                args += [option, r.choice(["run.t_end=-1", "particles.friction=x", "a=1",
                                           "fluid.gap=1e-300", "run.t_end=0.01"])]
            elif option == "--cluster":
                args += [option, r.choice(["local:0", "local:x", "", "tcp://"])]
            elif option == "--mu":
                args += [option, *r.sample(BAD_NUMBERS + ["0.2", "0.5"], r.randint(1, 3))]
            elif option == "--out":
                link = self.path("link")
                link.symlink_to(link.parent / "nowhere")
                args += [option, r.choice([str(link), "/dev/null", "/proc/1/x", ""])]
            elif option == "--bogus":
                args += [option]
            else:
                args += [option, r.choice(BAD_NUMBERS)]
        return args

    def broken_scene(self) -> str:
        p = self.path("broken.toml")
        p.write_text(self.rng.choice(["", "[run]\nt_end = -1\n", "x = ", "[[geometry]]\n"]))
        return str(p)

    def case_calibrate(self):
        r = self.rng
        good = {"--target": "5", "--lo": "0.1", "--hi": "0.9"}
        values = {"--target": BAD_NUMBERS, "--lo": BAD_NUMBERS + ["0.9"],
                  "--hi": BAD_NUMBERS + ["0.1"], "--rounds": BAD_NUMBERS + ["1", "2"],
                  "--realizations": BAD_NUMBERS, "--xtol": BAD_NUMBERS,
                  "--confidence": BAD_NUMBERS + ["1", "0.5"], "--seed": BAD_NUMBERS,
                  "--param": ["nosuch.key", "particles.name", "run.t_end", "output.video",
                              "particles.9.friction", "", "run.arch", "fluid.gap"]}
        for option in r.sample(sorted(values), r.randint(1, 2)):
            good[option] = r.choice(values[option])
        scene = r.choice([HOURGLASS] * 4 + [str(self.path("none.toml")), self.broken_scene(),
                                            str(SCENES)])
        args = ["calibrate", scene, "--out", str(self.path("out")),
                *sum(([k, v] for k, v in good.items() if r.random() < 0.95), [])]
        args += ["--quiet"] if r.random() < 0.9 else []
        if r.random() < 0.3:
            args += r.choice([["--quick"], ["--set", "run.t_end=-1"], ["--cluster", "local:0"],
                              ["--out", "/dev/null"], ["--bogus"]])
        return args

    def case_arches(self):
        r = self.rng
        folder = self.path("fig")
        kind = r.choice(["missing", "file", "empty", "run", "run_options", "run_damaged",
                         "json_bad", "json_list", "json_no_scene", "json_scene_missing",
                         "json_points", "point_file", "point_rows", "point_finals",
                         "bad_options", "link"])
        args = ["arches", str(folder)]
        if kind == "file":
            folder.write_text("mine")
        elif kind == "link":
            folder.symlink_to(folder.parent / "nowhere")
        elif kind == "empty":
            folder.mkdir()
        elif kind.startswith("run"):
            shutil.copytree(self.ck["one"], folder)
            if kind == "run_options":
                args += [r.choice(["--tol", "--angle", "--examples"]), "1"]
            elif kind == "run_damaged":
                name = r.choice(["summary.json", "arches.csv"])
                how = r.choice(["empty", "garbage", "dir", "list"])
                (folder / name).unlink()
                if how == "dir":
                    (folder / name).mkdir()
                else:
                    (folder / name).write_text({"empty": "", "garbage": "\x00{[,",
                                                "list": "[1, 2]"}[how])
        elif kind != "missing":
            folder.mkdir()
            fig = {"figure": "friction", "scene": HOURGLASS, "base_overrides": [],
                   "points": [{"label": "mu=0.2", "values": {"mu": 0.2},
                               "overrides": {"particles.friction": 0.2}}]}
            point = {"key": "k", "label": "mu=0.2", "rows": [
                {"seed": 1, "escapees": 3, "clogged": True, "status": "ok"}],
                "finals": {"1": {"x": [[1.0, 2.0]], "theta": [0.0], "alive": [1],
                                 "species": [0]}}}
            if kind == "json_bad":
                text = r.choice(["", "{", "\x00", "null", '"x"'])
            elif kind == "json_list":
                text = json.dumps([fig])
            else:
                if kind == "json_no_scene":
                    del fig["scene"]
                elif kind == "json_scene_missing":
                    fig["scene"] = str(folder / "none.toml")
                elif kind == "json_points":
                    fig["points"] = r.choice([None, 3, [3], [{}], [{"label": "a"}], "x"])
                elif kind == "point_rows":
                    point["rows"] = r.choice([None, [3], [{}], [{"status": "ok"}],
                                              [{"status": "ok", "clogged": True}]])
                elif kind == "point_finals":
                    point["finals"] = r.choice([{"1": {}}, {"1": 3}, [1],
                                                {"1": {"x": [], "theta": [], "alive": [],
                                                       "species": []}},
                                                {"1": {"x": [[1e300, "x"]], "theta": [0.0],
                                                       "alive": [1], "species": [9]}}])
                text = json.dumps(fig)
                if kind != "json_scene_missing" and kind != "point_file":
                    (folder / "points").mkdir()
                    (folder / "points" / "mu=0.2.json").write_text(json.dumps(point))
                elif kind == "point_file":
                    (folder / "points").mkdir()
                    (folder / "points" / "mu=0.2.json").write_text(r.choice(["", "{", "[]"]))
            (folder / "figure.json").write_text(text)
            if kind == "bad_options":
                args += [r.choice(["--tol", "--angle", "--examples"]),
                         r.choice(BAD_NUMBERS + ["90", "1", "0.5"])]
        return args

    def case_study_signal(self):
        """A short study run as its own process, given SIGINT, SIGTERM or SIGHUP
        after a random delay: during the import, the sweep file's checks, a point's
        run, the writing of the results, or after the study ended."""
        r = self.rng
        self.subprocess = True
        self.signal = r.choice([signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
        self.sigint_after = r.uniform(0.0, 6.0)
        kind = r.choice(["sweep", "sweep", "sweep", "arches", "calibrate"])
        if kind == "sweep":
            path = self.path("sweep.toml")
            path.write_text(SWEEP)
            return ["sweep", str(path), "--out", str(self.path("out")), "--quiet"]
        if kind == "arches":
            folder = self.path("run")
            shutil.copytree(self.ck["one"], folder)
            return ["arches", str(folder)]
        return ["calibrate", HOURGLASS, "--target", "3", "--lo", "0.2", "--hi", "0.6",
                "--realizations", "1", "--rounds", "2", "--set", "run.t_end=0.2",
                "--out", str(self.path("out")), "--quiet"]


# Failures found by this fuzzer whose fix lies in code being changed elsewhere:
# counted and shown apart ("known"), not as failures. Remove an entry once fixed.
KNOWN = {
}


def known(failure: dict) -> str | None:
    """The KNOWN entry ``failure`` is an instance of, or None."""
    return next((name for name, match in KNOWN.items() if match(failure)), None)


class _Skip(BaseException):
    """A valid case past the cap of real runs: resolved, not run (not an exception
    the command line catches, so it comes back to the fuzzer)."""


class Fuzzer(StudyCases):
    def __init__(self, work: Path, seed: int, valid_runs: int):
        self.work, self.rng, self.valid_runs = work, random.Random(seed), valid_runs
        self.runs = 0
        self.keys = [(f"{s}.{k}", spec) for s, cls in SECTIONS.items()
                     for k, spec in key_specs(cls).items()]
        self.keys += [(f"particles.{k}", spec) for k, spec in key_specs(SpeciesConfig).items()]
        self.keys = [(k, spec) for k, spec in self.keys if k not in SKIP]
        self.texts = {b: (SCENES / f"{b}.toml").read_text() for b in BASES}
        self.n = 0
        self.sigint_after = None     # seconds to Ctrl-C in the current case, or None
        self.signal = signal.SIGINT  # and which signal
        self.subprocess = False      # the case runs as its own process
        self.folder = self.work      # the current case's folder
        self.names = Counter()

    # ------------------------------------------------------------------ plumbing
    def begin(self) -> Path:
        """A fresh folder for the next case, and in it the empty working folder
        ``cwd`` the case runs in; returns that."""
        self.n += 1
        self.folder = self.work / f"c{self.n}"
        self.folder.mkdir()
        self.names.clear()
        (self.folder / "cwd").mkdir()
        return self.folder / "cwd"

    def path(self, name: str) -> Path:
        """A path of the current case's folder, not taken yet (``name``, ``2-name``, ...)."""
        self.names[name] += 1
        return self.folder / (name if self.names[name] == 1 else f"{self.names[name]}-{name}")

    def out(self) -> str:
        return str(self.path("out"))

    def scene_file(self, text: str | bytes, name: str = "scene.toml") -> str:
        p = self.path(name)
        (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
        return str(p)

    def base(self) -> str:
        return self.rng.choice(BASES)

    def short(self) -> list[str]:
        return ["--quiet"] if self.rng.random() < 0.9 else []

    # --------------------------------------------------------------- families
    def value(self, key, spec) -> str:
        r = self.rng
        if spec.kind in ("float", "int"):
            bounds = [b for b in (spec.gt, spec.ge, spec.lt, spec.le) if b is not None]
            near = [repr(float(b + d)) if spec.kind == "float" else str(int(b + d))
                    for b in bounds for d in (-1, 0, 1)]
            if key in SIZE:
                near += [str(SIZE[key]), "1", "2", "10000000000"]
            pool = near + EXTREMES + ([f"{r.uniform(-5, 5):.3g}", str(r.randint(-3, 50))])
            if spec.auto:
                pool.append('"auto"')
            return r.choice(pool) if r.random() < 0.85 else r.choice(WRONG)
        if spec.kind == "bool":
            return r.choice(["true", "false"] if r.random() < 0.7 else WRONG)
        if spec.kind == "choice":
            return r.choice([f'"{c}"' for c in spec.choices] if r.random() < 0.7 else WRONG)
        if spec.kind == "interval":
            return r.choice(["[-1.0, 0.0]", "[0.0, 1e300]", "[0.001, 0.0005]", "[0.0, 0.0028]",
                             "[1e-9, 2e-9]", "[nan, 1.0]", "[0.0, 1.0, 2.0]"] + WRONG)
        if spec.kind in ("points", "poses", "polygons"):
            return self.polygon_text(spec.kind)
        return r.choice(['"x"', '""', '"a/b"', '"runs/ü n"', '"."', '"\\n"', '"' + "n" * 300 + '"']
                        + WRONG)

    def polygon_text(self, kind: str) -> str:
        poly = self.bad_polygon()
        if kind == "polygons":
            return f"[{poly}]"
        if kind == "poses":
            return self.rng.choice(["[[0.001, 0.0002]]", "[[0.001, 0.0002, 7.0]]", "[[nan, 0.0]]",
                                    "[[0.0, 0.0, 0.0, 0.0]]", "[]", poly])
        return poly

    def bad_polygon(self) -> str:
        """A polygon as TOML: simple, self-intersecting, zero-area, collinear,
        repeated vertices, closed, huge, non-finite, of tiny or huge size."""
        r = self.rng
        s = 10.0 ** r.choice([-6, -5, -4, -3, 0, 300, -300])
        n = r.choice([3, 4, 5, 12, 200, 1001, 2001, 3000])
        shape = r.choice(["circle", "bowtie", "line", "repeat", "closed", "spike", "nan", "star"])
        ang = [2 * math.pi * k / n for k in range(n)]
        pts = [[s * math.cos(a), s * math.sin(a)] for a in ang]
        if shape == "bowtie":
            pts = [[0, 0], [s, s], [s, 0], [0, 0.7 * s]]
        elif shape == "line":
            pts = [[s * k, 0.0] for k in range(max(3, n // 100))]
        elif shape == "repeat":
            pts.insert(1, list(pts[0]))
        elif shape == "closed":
            pts.append(list(pts[0]))
        elif shape == "spike":
            pts = [[0, 0], [s, 0], [2 * s, 0], [s, 0], [s, s]]
        elif shape == "nan":
            pts[0][0] = float("nan")
        elif shape == "star":
            pts = [[s * (1 + (k % 2)) * math.cos(a), s * (1 + (k % 2)) * math.sin(a)]
                   for k, a in enumerate(ang)]
        return "[" + ", ".join(f"[{x!r}, {y!r}]" for x, y in pts) + "]"

    def case_overrides(self):
        r = self.rng
        base = self.base()
        args = [str(SCENES / f"{base}.toml"), "--out", self.out(), *self.short()]
        for _ in range(r.randint(1, 4)):
            key, spec = r.choice(self.keys)
            args += ["--set", f"{key}={self.value(key, spec)}"]
        if r.random() < 0.2:
            args += ["--set", f"run.t_end={r.choice(['0', '-1', 'nan', '1e-300', '1e300', 'x'])}"]
        if r.random() < 0.2:
            args += r.choice([["--realizations", r.choice(["0", "-1", "2", "99999999", "x"])],
                              ["--seed", r.choice(["-1", "0", str(2 ** 70), "1.5"])],
                              ["--arch", r.choice(["cpu", "tpu", ""])], ["--no-video"]])
        return args

    def case_combination(self):
        """Several extreme-but-valid values together (a valid scene, mostly)."""
        r = self.rng
        base = r.choice(["hourglass24", "vani_phi026", "squares"])
        pool = ["particles.friction=0", "particles.friction=10", "particles.restitution=1",
                "particles.restitution=1e-6", "damping.xi=0", "run.realizations=3",
                "run.seed=4294967295", "particles.count=1", "particles.count=0",
                "run.dt_safety=1", "output.frames=2", "output.series_interval=1e-9",
                "clog.window=1e-9", "run.stop_at_clog=false", 'fluid.bc="flow_rate"',
                "fluid.flow_rate=1e-30", "fluid.enabled=false", 'feed.mode="none"',
                "contact.overlap_limit=0.99", "output.checkpoint_every=1e-9",
                'name="ü n\\u00e9 name"', "particles.density=1e-3", "particles.density=1e6"]
        sets = r.sample(pool, r.randint(2, 6))
        return [str(SCENES / f"{base}.toml"), "--out", self.out(), "--quiet",
                *sum((["--set", s] for s in sets), [])]

    def case_toml(self):
        r = self.rng
        text = self.texts[self.base()]
        kind = r.choice(["dup_key", "dup_table", "control", "deep", "huge_array", "cut",
                         "flip", "bom", "crlf", "empty", "binary", "nul", "unicode_key",
                         "huge_number", "long_string", "inline_particles", "top_array"])
        if kind == "dup_key":
            text = text.replace("[run]", "[run]\nseed = 1\nseed = 2", 1)
        elif kind == "dup_table":
            text += "\n[run]\nt_end = 1.0\n"
        elif kind == "control":
            c = chr(r.choice([0, 1, 7, 8, 11, 12, 27, 127]))
            i = r.randrange(len(text))
            text = text[:i] + c + text[i:]
        elif kind == "deep":
            d = r.choice([10, 100, 1000, 100000])
            text += f"\n[output]\nx = {'[' * d}{']' * d}\n"
        elif kind == "huge_array":
            n = r.choice([1000, 100000, 500000])
            item = r.choice(["1.0", "[1.0, 2.0]", '"s"'])
            key = r.choice(["outline", "obstacles", "vertices", "x"])
            text = text.replace("[geometry]", f"[geometry]\n{key} = [{', '.join([item] * n)}]", 1)
        elif kind == "cut":
            text = text[:r.randrange(len(text))]
        elif kind == "flip":
            data = bytearray(text.encode())
            for _ in range(r.randint(1, 5)):
                data[r.randrange(len(data))] = r.randrange(256)
            return [self.scene_file(bytes(data)), "--out", self.out(), "--quiet"]
        elif kind == "bom":
            return [self.scene_file(b"\xef\xbb\xbf" + text.encode()), "--out", self.out(),
                    "--quiet"]
        elif kind == "crlf":
            text = text.replace("\n", "\r\n")
        elif kind == "empty":
            text = r.choice(["", "\n", "# nothing\n", "[run]\n"])
        elif kind == "binary":
            return [self.scene_file(bytes(r.randrange(256) for _ in range(2000))),
                    "--out", self.out(), "--quiet"]
        elif kind == "nul":
            text = text.replace("[run]", "[run]\x00", 1)
        elif kind == "unicode_key":
            text = text.replace("[run]", "[run]\n\"ünï\" = 1\n\"\" = 2", 1)
        elif kind == "huge_number":
            text = text.replace("[run]", "[run]\nseed = 99999999999999999999", 1)
        elif kind == "long_string":
            text = text.replace("[run]", f'description = "{"d" * 100000}"\n[run]', 1)
        elif kind == "inline_particles":
            text += '\nparticles = "none"\n'
        elif kind == "top_array":
            text = "[[run]]\nt_end = 1\n" + text
        return [self.scene_file(text), "--out", self.out(), *self.short(),
                "--set", "run.t_end=0.001"]

    def case_polygon(self):
        r = self.rng
        poly = self.bad_polygon()
        where = r.choice(["particle", "outline", "obstacle"])
        if where == "particle":
            text = self.texts["concave"]
            start = text.index("vertices = [")
            end = text.index("]]", start) + 2
            text = text[:start] + f"vertices = {poly}" + text[end:]
        else:
            text = self.texts["vani_phi026"]
            start = text.index("[geometry]")
            end = text.index("\n[", start + 1)
            box = "[[0.0, 0.0], [3e-3, 0.0], [3e-3, 4e-4], [0.0, 4e-4]]"
            geometry = '[geometry]\nkind = "polygon"\n' + (
                f"outline = {poly}\n" if where == "outline"
                else f"outline = {box}\nobstacles = [{poly}]\n")
            text = text[:start] + geometry + text[end:]
        return [self.scene_file(text), "--out", self.out(), "--quiet"]

    def case_paths(self):
        r = self.rng
        base = str(SCENES / f"{self.base()}.toml")
        folder = self.path("d").parent
        kind = r.choice(["space", "unicode", "newline", "long_scene", "long_out", "dangling",
                         "loop", "out_file", "under_file", "dir_scene", "empty_out", "dev_null",
                         "proc", "default_out", "scene_missing", "dash"])
        text = Path(base).read_text()
        if kind in ("space", "unicode", "newline"):
            name = {"space": "a b c", "unicode": "ünï ☃ 名", "newline": "a\nb"}[kind]
            scene = folder / f"{name}.toml"
            scene.write_text(text)
            return [str(scene), "--out", str(folder / name / name), "--quiet"]
        if kind == "long_scene":
            return [str(folder / ("s" * 300 + ".toml")), "--quiet"]
        if kind == "long_out":
            return [base, "--out", str(folder / ("o" * r.choice([255, 256, 5000]))), "--quiet"]
        if kind == "dangling":
            (folder / "link").symlink_to(folder / "nowhere")
            return ([str(folder / "link"), "--quiet"] if r.random() < 0.5
                    else [base, "--out", str(folder / "link"), "--quiet"])
        if kind == "loop":
            (folder / "l1").symlink_to(folder / "l2")
            (folder / "l2").symlink_to(folder / "l1")
            return ([str(folder / "l1"), "--quiet"] if r.random() < 0.5
                    else [base, "--out", str(folder / "l1" / "x"), "--quiet"])
        if kind == "out_file":
            (folder / "f").write_text("mine")
            return [base, "--out", str(folder / "f"), "--quiet"]
        if kind == "under_file":
            (folder / "f").write_text("mine")
            return [base, "--out", str(folder / "f" / "sub"), "--quiet"]
        if kind == "dir_scene":
            return [str(folder), "--quiet"]
        if kind == "empty_out":
            return [base, "--out", "", "--quiet"]
        if kind == "dev_null":
            return [base, "--out", "/dev/null", "--quiet"]
        if kind == "proc":
            return [base, "--out", "/proc/1/x", "--quiet"]
        if kind == "default_out":     # runs/<name> under the working folder (self.work)
            return [base, "--quiet", "--set", f'name="{r.choice(["x y", "ü", "n" * 300])}"']
        if kind == "scene_missing":
            return [str(folder / "none.toml"), "--quiet"]
        return ["--", base, "--quiet"]

    def case_argv(self):
        r = self.rng
        base = str(SCENES / f"{self.base()}.toml")
        return r.choice([
            [], ["--help"], ["--bogus"], [base, "--set"], [base, "--set", "=1"],
            [base, "--set", "run.t_end"], [base, "--set", "nosuch.key=1"],
            [base, "--set", "particles.9.count=1"], [base, "--set", "particles.x.count=1"],
            [base, base], [base, "--resume", str(self.work)], ["--resume"],
            ["--resume", ""], [base, "--video", "--no-video"], [base, "--realizations"],
            [base, "--out"], ["\x00"], ["-"], [base, "--set", "run..t_end=1"],
            [base, "--set", "particles[0].count=1", "--set", "run.t_end=0"],
            ["sweep", "--bogus"], ["run", base, "--set", "run.t_end=-1"],
        ]) + ["--out", self.out()]

    # ---------------------------------------------------------------- resume
    def make_checkpoints(self):
        """One real checkpoint (hourglass24, 0.2 s) and one of two realizations."""
        self.ck = {}
        for name, extra in (("one", []), ("two", ["--realizations", "2"])):
            out = self.work / f"ck_{name}"
            code = main([str(SCENES / "hourglass24.toml"), "--out", str(out), "--quiet",
                         "--set", "run.t_end=0.2", *extra])
            assert code == 0, f"could not make the checkpoint to corrupt (exit {code})"
            self.ck[name] = out

    def case_resume(self):
        r = self.rng
        src = self.ck[r.choice(["one", "one", "one", "two"])]
        folder = self.path("run")
        shutil.copytree(src, folder)
        path = folder / checkpoint.FILE
        kind = r.choice(["bytes", "header", "array", "foreign", "t_end", "file", "keys"])
        sets = []
        if kind == "bytes":
            data = bytearray(path.read_bytes())
            how = r.choice(["cut", "flip", "append", "zero"])
            if how == "cut":
                data = data[:r.randrange(len(data))]
            elif how == "flip":
                for _ in range(r.randint(1, 8)):
                    data[r.randrange(len(data))] ^= 1 << r.randrange(8)
            elif how == "append":
                data += bytes(r.randrange(256) for _ in range(100))
            else:
                data = bytearray(len(data))
            path.write_bytes(bytes(data))
        elif kind in ("header", "array", "foreign"):
            with np.load(path) as d:
                arrays = {k: d[k] for k in d.files}
            header = json.loads(bytes(arrays["header"]).decode())
            if kind == "header":
                table = header["host"] if r.random() < 0.7 else header
                key = r.choice(sorted(table))
                table[key] = r.choice([float("nan"), float("inf"), -1, 1e300, -7, "x", None, [],
                                       {}, True, 2 ** 70, [1e300, -1], [[0, 1e300, -1]], 0])
                arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
            elif kind == "array":
                name = r.choice(sorted(k for k in arrays if k != "header"))
                a = arrays[name]
                how = r.choice(["drop", "dtype", "shape", "nan", "huge", "str"])
                if how == "drop":
                    del arrays[name]
                elif how == "dtype":
                    arrays[name] = a.astype(r.choice([np.float32, np.int64, np.bool_, np.int8]))
                elif how == "shape":
                    arrays[name] = a.reshape(-1)[:max(0, a.size - 1)]
                elif how == "nan" and a.size and a.dtype.kind == "f":
                    a.reshape(-1)[r.randrange(a.size)] = r.choice([np.nan, np.inf, 1e300])
                elif how == "huge" and a.size and a.dtype.kind == "i":
                    a.reshape(-1)[r.randrange(a.size)] = r.choice([-2 ** 31, 2 ** 31 - 1, -1])
                else:
                    arrays[name] = np.array(["x"] * max(a.size, 1))
            else:       # another run's header on these arrays
                other = self.ck["two" if src == self.ck["one"] else "one"] / checkpoint.FILE
                with np.load(other) as d:
                    arrays["header"] = d["header"]
            with open(path, "wb") as fh:
                np.savez(fh, **arrays)
        elif kind == "t_end":
            t_end = r.choice(["0.1", "0", "nan", "-1", "1e300", "0.2", "0.21"])
            sets = ["--set", f"run.t_end={t_end}"]
        elif kind == "file":
            path.unlink()
            how = r.choice(["missing", "dir", "fifo", "dev_zero", "dangling"])
            if how == "dir":
                path.mkdir()
            elif how == "fifo":
                os.mkfifo(path)
            elif how == "dev_zero":
                path.symlink_to("/dev/zero")
            elif how == "dangling":
                path.symlink_to(folder / "nowhere")
        else:
            key, spec = r.choice(self.keys)
            sets = ["--set", f"{key}={self.value(key, spec)}"]
        return ["--resume", str(folder), "--quiet", *sets]

    # ------------------------------------------------------------------ runs
    def case_interrupt(self):
        """A valid run that gets Ctrl-C (SIGINT), SIGTERM or SIGHUP after a random
        delay: during set-up, the run, the writing of the results, or after it
        ended; ``self.sigint_after`` and ``self.signal`` tell the loop when and which."""
        self.sigint_after = self.rng.uniform(0.0, 3.0)
        self.signal = self.rng.choice([signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
        base = self.rng.choice(["hourglass24", "vani_phi026"])
        return [str(SCENES / f"{base}.toml"), "--out", self.out(), "--quiet"]

    def case(self):
        self.sigint_after = None
        self.signal = signal.SIGINT
        self.subprocess = False
        family = self.rng.choices(
            ["overrides", "combination", "toml", "polygon", "resume", "paths", "argv",
             "interrupt", *STUDIES], weights=[35, 8, 15, 12, 15, 10, 5, 4, 12, 5, 5, 6, 2])[0]
        return family, getattr(self, f"case_{family}")()

    def guarded_build(self, build):
        """runner.build for a fuzz run: valid runs cut to ``STEPS`` steps, and past the
        cap only resolved (every check of the set-up), not run."""
        def guarded(scene, **options):
            interrupt = self.sigint_after is not None
            if self.runs >= self.valid_runs and not interrupt:
                from taichi_hsdem.resolve import resolve
                try:
                    resolve(scene)
                except Exception as exc:     # what main would say: let build say it
                    if type(exc).__name__ != "SceneError":
                        raise
                    return build(scene, **options)
                raise _Skip
            sim = build(scene, **options)
            self.runs += 1
            if options.get("place_particles", True):      # an interrupt case: long enough
                sim.extend(min(sim.scene.run.t_end, (100 if interrupt else 1) * STEPS * sim.dt))
            return sim
        return guarded


@contextlib.contextmanager
def _signal_after(seconds: float | None, sig=signal.SIGINT):
    """Send this process ``sig`` after ``seconds`` (None: never); one that arrives
    after ``main`` returned is ignored here, not raised in the fuzzer."""
    if seconds is None:
        yield
        return
    previous = signal.signal(sig, lambda *a: None)
    timer = threading.Timer(seconds, os.kill, (os.getpid(), sig))
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        timer.join()
        signal.signal(sig, previous)


def _leftovers(folder: Path | None) -> list[str]:
    """A lock or staging folder a stopped run left in ``folder``."""
    if folder is None or not folder.is_dir():
        return []
    return [p.name for p in folder.iterdir()
            if p.name.startswith((output.STAGING_PREFIX, output.LOCK))]


def _complete(folder: Path) -> bytes | None:
    summary = folder / "summary.json"
    try:
        return summary.read_bytes() if summary.is_file() else None
    except OSError:
        return None


def _out_of(args: list[str], work: Path) -> Path | None:
    if "--resume" in args:
        i = args.index("--resume")
        return Path(args[i + 1]) if i + 1 < len(args) and args[i + 1] else None
    if "--out" in args:
        i = args.index("--out")
        return Path(args[i + 1]) if i + 1 < len(args) and args[i + 1] else None
    return None


def _tree(folder: Path) -> set[str]:
    """Every path under ``folder`` (links not followed), relative to it."""
    found = set()
    for top, dirs, files in os.walk(folder):
        found.update(os.path.relpath(os.path.join(top, n), folder) for n in dirs + files)
    return found


def _study_leftovers(out: Path | None) -> list[str]:
    """Locks and staging folders a stopped study left in ``out`` or its points'
    folders."""
    if out is None or not out.is_dir():
        return []
    return sorted(p for p in _tree(out)
                  if Path(p).name.startswith((output.STAGING_PREFIX, output.LOCK)))


def _in_process(fuzz: Fuzzer, args: list[str]) -> tuple:
    """``main(args)`` here, stderr captured: (exit status, stderr, traceback or None)."""
    err, std = io.StringIO(), io.StringIO()
    problem = None
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std), \
            _signal_after(fuzz.sigint_after, fuzz.signal), \
            warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for category in QUIET_WARNINGS:    # what Python shows no user by default
            warnings.simplefilter("ignore", category)
        try:
            code = main(list(args))
        except _Skip:
            code = "valid, not run"
        except BaseException:    # noqa: BLE001 - any escape is the finding
            code = "exception"
            problem = traceback.format_exc()
    text = err.getvalue() + "".join(
        warnings.formatwarning(w.message, w.category, w.filename, w.lineno) for w in caught)
    return code, text, problem


def _as_process(fuzz: Fuzzer, args: list[str], cwd: Path) -> tuple:
    """``python -m taichi_hsdem ARGS`` as a process in ``cwd``, sent ``fuzz.signal``
    after ``fuzz.sigint_after`` seconds unless it ended first."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "taichi_hsdem", *args], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        proc.wait(timeout=fuzz.sigint_after)
        fuzz.sigint_after = None                 # it ended first: no signal sent
    except subprocess.TimeoutExpired:
        proc.send_signal(fuzz.signal)
    try:
        text = proc.communicate(timeout=600)[1]
    except subprocess.TimeoutExpired:
        proc.kill()
        return "hung", proc.communicate()[1], "no exit within 600 s"
    code = proc.returncode
    if _before_the_program(fuzz.sigint_after, code, text):
        return "before the program", text, None
    if code < 0:
        return code, text, f"killed by {signal.Signals(-code).name} (no handler)"
    return code, text, None


#: The longest the interpreter takes to start before it runs the package's first
#: line (about 0.05 s on a quiet machine; a loaded one is slower).
STARTUP = 0.3


def _before_the_program(after, code, text) -> bool:
    """A signal that reached the interpreter while it was still starting, before
    ``python -m taichi_hsdem`` ran the package's first line (Python's own set-up and
    site packages: no program can handle it; the system's default action applies:
    killed, or Python's fatal error in its site module). Counted apart, not as a
    failure; any later signal must be answered by the package."""
    if after is None or after > STARTUP:
        return False
    killed = isinstance(code, int) and code < 0 and not text.strip()
    return killed or text.startswith("Fatal Python error: init_import_site")


def _check(fuzz, family, args, code, text, out, before, tree, cwd, case) -> str | None:
    """Why the case failed, or None."""
    if code == "before the program":
        return None
    if code not in EXITS and code != "valid, not run":
        return f"exit {code!r}"
    if code not in (0, "valid, not run") and not text.strip():
        return f"exit {code} without a message"
    if "Traceback" in text or "internal error" in text:
        return "traceback or internal error on stderr"
    warned = re.search(r"^\S+:\d+: (\w+Warning): .*", text, re.M)
    if warned:
        return f"a {warned[1]} with its source line on stderr: {warned[0][:200]}"
    lines = text.strip().splitlines()
    if family in STUDIES and code != 0 and len(lines) > MAX_LINES:
        return f"{len(lines)} lines on stderr"
    left = sorted(os.listdir(cwd))
    if left and not (left == ["runs"] and code in (0, "valid, not run", *STOPS)):
        return f"left {left} in the working folder"
    if code == 2 and _tree(case) - tree:
        return f"refused (exit 2) but wrote {sorted(_tree(case) - tree)[:5]}"
    # A stopped run exits 128 + its signal's number with one line and leaves no lock
    # or staging folder; a result it kept says how it ended.
    if code in STOPS:
        summary = _complete(out) if out is not None else None
        if code != 128 + int(fuzz.signal) or fuzz.sigint_after is None:
            return f"exit {code} for {signal.Signals(fuzz.signal).name}"
        if len(lines) != 1:
            return f"{len(lines)} lines after a stop, not one"
        if _leftovers(out) or (family in STUDIES and _study_leftovers(out)):
            return f"left {_leftovers(out) or _study_leftovers(out)} behind"
        if summary is not None and summary != before and not (
                b'"interrupted"' in summary or b'"complete"' in summary):
            return "a stopped run left a summary neither interrupted nor complete"
    # A failed or refused run (1, 2) must leave the folder's summary as it was;
    # an interrupted one (130) may have finished writing first, and says so.
    if code in (1, 2) and out is not None:
        after = _complete(out)
        if after is not None and after != before and b'"complete"' in after:
            return "a failed run left a complete-looking summary.json"
    return None


def run_cases(n_cases: int, seed: int, valid_runs: int, work: Path, verbose=False) -> dict:
    """Run ``n_cases`` seeded cases in ``work``; returns the counts and failures."""
    debug = os.environ.get("TAICHI_HSDEM_DEBUG")
    os.environ["TAICHI_HSDEM_DEBUG"] = "1"   # a defect shows its traceback here
    fuzz = Fuzzer(work, seed, valid_runs)
    home = os.getcwd()
    build = runner.build
    runner.build = fuzz.guarded_build(build)
    codes, families, failures, known_failures, slow = Counter(), Counter(), [], [], []
    signalled = Counter()
    t0 = time.perf_counter()
    try:
        os.chdir(work)
        fuzz.make_checkpoints()
        for k in range(n_cases):
            cwd = fuzz.begin()
            os.chdir(cwd)                    # default output folders land here
            family, args = fuzz.case()
            families[family] += 1
            out = _out_of(args, work)
            before = _complete(out) if out is not None else None
            tree = _tree(fuzz.folder)
            given = signal.Signals(fuzz.signal).name if fuzz.sigint_after is not None else None
            after = fuzz.sigint_after
            t1 = time.perf_counter()
            if fuzz.subprocess:
                code, text, problem = _as_process(fuzz, args, cwd)
            else:
                code, text, problem = _in_process(fuzz, args)
            seconds = time.perf_counter() - t1
            if problem is None:
                problem = _check(fuzz, family, args, code, text, out, before, tree, cwd,
                                 fuzz.folder)
            codes[code] += 1
            if given is not None:
                signalled[given, code in STOPS] += 1
            if seconds > 60:
                slow.append((k, family, args, seconds))
            if problem:
                failure = {"case": k, "family": family, "args": args, "code": code,
                           "problem": problem, "stderr": text[-3000:], "after": after}
                if known(failure):
                    known_failures.append(failure)
                else:
                    failures.append(failure)
            if verbose:
                print(f"{k:5d} {family:12s} {str(code):15s} {seconds:6.2f}s "
                      f"{'FAIL ' + problem.splitlines()[-1] if problem else ''}", flush=True)
    finally:
        runner.build = build
        os.chdir(home)
        if debug is None:
            os.environ.pop("TAICHI_HSDEM_DEBUG")
        else:
            os.environ["TAICHI_HSDEM_DEBUG"] = debug
    return {"cases": n_cases, "codes": codes, "families": families, "failures": failures,
            "known": known_failures,
            "slow": slow, "runs": fuzz.runs, "signalled": signalled,
            "seconds": time.perf_counter() - t0}


def report(res: dict) -> str:
    lines = [f"cases: {res['cases']}   wall time: {res['seconds']:.0f} s   "
             f"real runs: {res['runs']}   failures: {len(res['failures'])}   "
             f"known failures: {len(res['known'])}",
             "exit    count"]
    lines += [f"{str(code):15s} {n}" for code, n in sorted(res["codes"].items(), key=str)]
    lines += ["family  count"] + [f"{f:15s} {n}" for f, n in sorted(res["families"].items())]
    lines += ["signal  sent  stopped by it (the others ended first)"]
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sent = res["signalled"][name, True] + res["signalled"][name, False]
        lines.append(f"{name:7s} {sent:5d} {res['signalled'][name, True]:5d}")
    kinds = Counter(known(f) for f in res["known"])
    for name, n in kinds.items():
        example = next(f for f in res["known"] if known(f) == name)
        lines.append(f"known ({n} case(s), e.g. {example['case']}): {name}")
    for k, fam, args, s in res["slow"]:
        lines.append(f"slow: case {k} ({fam}) {s:.0f} s: {args!r}"[:400])
    for f in res["failures"]:
        lines += [f"FAIL case {f['case']} ({f['family']}): {f['problem'].splitlines()[-1]}",
                  f"  argv: {f['args']!r}"[:2000], "  " + (f["problem"] if "Traceback" in
                                                          f["problem"] else f["stderr"])[-1500:]]
    return "\n".join(lines)


def _main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--valid-runs", type=int, default=50,
                   help="most valid scenes run for real (each cut to a few dozen steps)")
    p.add_argument("--work", help="folder for the cases' files (default: a temporary one)")
    p.add_argument("--verbose", action="store_true", help="one line per case")
    a = p.parse_args(argv)
    with contextlib.ExitStack() as stack:
        work = Path(a.work) if a.work else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        work.mkdir(parents=True, exist_ok=True)
        if any(work.iterdir()):
            print(f"--work {work}: holds files (of an earlier fuzzing?); give an empty or "
                  "new folder", file=sys.stderr)
            return 2
        res = run_cases(a.cases, a.seed, a.valid_runs, work.resolve(), a.verbose)
    print(report(res))
    return 1 if res["failures"] else 0


if __name__ == "__main__":
    sys.exit(_main())
