"""How long a placed arch of three disks holds in the flow.

Usage::

    python tools/arch_lifetime.py [SCENE] [--wd 2.2] [--beta 20] [--t-end 0.5]
                                  [--set SECTION.KEY=VALUE ...] [--variant SETS ...]

Places three disks of the scene's (first) species as a mirror-symmetric arch
vaulted upstream across a converging channel (``geometry.kind = "converging"``,
default ``scenes/vani_phi026.toml``) whose neck is ``W/d`` diameters wide: the
middle disk on the centre line, the outer two touching it at ``beta`` degrees
from the cross-stream direction and touching the converging walls, each contact
opened by 0.01 d (so that nothing starts overlapping). Nothing else is fed
(``feed.mode = "none"``). The flow then loads the arch; the run records when the
first disk passes the escape line (the arch's life) or that none did by
``--t-end``. Such an arch is statically admissible with little friction
(``tests/test_arch_statics.py``: |T|/N = 0.019 at beta = 20); what it does in the
flow is the question (docs/validation.md, "Arches of three").

Each ``--variant`` is one run with its own comma-separated ``--set`` values on
top of the common ones (``-`` for none), e.g. ``--variant -
particles.spin_drag=0``; one line per variant: the sets, escapees by the end,
the time of the first escape.

Exit status: 0 done; 2 bad arguments or an invalid scene (one line each).
"""
from __future__ import annotations

import json
import math
import pathlib
import sys
import tomllib

from taichi_hsdem.exits import EXIT_INVALID, EXIT_OK, Parser

ROOT = pathlib.Path(__file__).resolve().parents[1]
OPENING = 0.01      # each contact opened by this fraction of d


def arch_positions(geometry, angle_deg: float, d: float, beta_deg: float) -> list[list[float]]:
    """Centres of the three disks (middle, upper, lower) for a converging channel
    (resolved ``geometry``) whose neck starts at ``constriction_x0`` and whose
    walls meet the axis at ``angle_deg``: the outer centres lie a radius inside
    the walls."""
    a = 0.5 * d
    x0 = geometry.constriction_x0
    yc = 0.5 * (geometry.y_min + geometry.y_max)
    half = 0.5 * geometry.constriction_width
    ang = math.radians(angle_deg)
    # upper wall: through (x0, yc + half), rising upstream at ang: its inward
    # normal n = -(sin ang, cos ang); the outer centre lies on the line moved a
    # inwards, at 2a from the middle one, at beta from the cross-stream direction
    b = math.radians(beta_deg)
    n = (-math.sin(ang), -math.cos(ang))
    # middle at (xm, yc); outer at (xm + 2a sin b, yc + 2a cos b); distance of the
    # outer centre to the wall line equals a:
    #   (p - w0) . n = a, w0 = (x0, yc + half)
    ox, oy = 2 * a * math.sin(b), 2 * a * math.cos(b)
    # ((xm + ox - x0) n_x + (oy - half) n_y) = a  ->  xm
    xm = x0 - ox + (a - (oy - half) * n[1]) / n[0]
    e = OPENING * a
    return [[xm - 2 * e, yc], [xm + ox - e, yc + oy], [xm + ox - e, yc - oy]]


def lifetime(scene_path: str, wd: float, beta: float, t_end: float, sets: list[str]):
    """(escapees by ``t_end``, time of the first escape or None) of one run."""
    import numpy as np
    import taichi_hsdem as th
    from taichi_hsdem.resolve import resolve

    base = th.load_scene(scene_path, sets)
    d = base.particles[0].d_eq()
    geometry = resolve(th.load_scene(scene_path, sets + [f"geometry.constriction_width={wd * d}"])
                       ).geometry
    raw = tomllib.loads(pathlib.Path(scene_path).read_text())
    sp = raw["particles"][0]
    for key in ("count", "packing_fraction"):
        sp.pop(key, None)
    sp["positions"] = arch_positions(geometry, base.geometry.angle, d, beta)
    raw["particles"] = [sp]
    raw.setdefault("feed", {})["mode"] = "none"
    scene = th.load_scene(raw, sets + [f"geometry.constriction_width={wd * d}",
                                       f"run.t_end={t_end}", "run.realizations=1",
                                       "run.stop_at_clog=false"])
    result = th.Simulation(scene).run()
    series = np.asarray(result.series, dtype=float)
    went = series[series[:, 2] > 0]
    first = float(went[:, 1].min()) if len(went) else None
    return result.summary["realizations"][0]["escapees"], first


def main(argv=None) -> int:
    p = Parser(prog="tools/arch_lifetime.py", description=__doc__.split("\n\n")[0])
    p.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "vani_phi026.toml"))
    p.add_argument("--wd", type=float, default=2.2, help="neck width over d")
    p.add_argument("--beta", type=float, default=20.0,
                   help="angle of the middle-outer line from the cross-stream direction, deg")
    p.add_argument("--t-end", type=float, default=0.5, help="physical time, s")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    p.add_argument("--variant", action="append", default=None, metavar="SETS",
                   help="comma-separated --set values of one run, '-' for none (repeatable)")
    args = p.parse_args(argv)
    if not 0 < args.beta < 60 or args.wd <= 1 or args.t_end <= 0:
        print("tools/arch_lifetime.py: --beta must lie in (0, 60), --wd above 1, "
              "--t-end above 0", file=sys.stderr)
        return EXIT_INVALID
    from taichi_hsdem import SceneError
    for variant in args.variant or ["-"]:
        sets = args.set + ([] if variant == "-" else variant.split(","))
        try:
            s, first = lifetime(args.scene, args.wd, args.beta, args.t_end, sets)
        except SceneError as error:
            print("\n".join(error.problems), file=sys.stderr)
            return EXIT_INVALID
        held = "held" if first is None else f"first escape at {first:.3f} s"
        print(json.dumps(variant), f"escapees {s}", held, flush=True)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
