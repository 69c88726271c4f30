"""Where each method fails, found on purpose: refused up front, or detected and
reported as unstable (never written out as a result)."""
import math
from pathlib import Path

import pytest

from conftest import arena_scene, make_sim
from taichi_hsdem import SceneError, Simulation, load_scene
from taichi_hsdem.resolve import node_sagitta
from taichi_hsdem.geometry import shapes

HOURGLASS = Path(__file__).resolve().parents[1] / "scenes" / "hourglass24.toml"


def test_too_few_surface_nodes_refused_with_advice():
    # 4 nodes on a disk hide 0.146 d of surface between nodes (r (1 - cos 45));
    # the default overlap target is 0.02 d, so the scene is refused, with a count
    # that would do (12 nodes hide 0.017 d).
    assert node_sagitta(shapes.circle(1.0, 4)) == pytest.approx(0.5 * (1 - math.cos(math.pi / 4)))
    scene = arena_scene([{"shape": "circle", "diameter": 1.0, "count": 2, "nodes": 4}],
                        fast_path=False)
    with pytest.raises(SceneError) as err:
        Simulation(load_scene(scene))
    msg = str(err.value)
    assert "particles[0].nodes" in msg and "0.146 d" in msg and "use about 16 nodes" in msg
    # polygons with a node at every corner hide nothing on their straight edges
    assert node_sagitta(shapes.square(1.0, 4)) == 0.0


def test_level_set_grid_too_coarse_refused():
    scene = arena_scene([{"shape": "square", "side": 1.0, "count": 2, "ls_spacing": 0.3}])
    with pytest.raises(SceneError) as err:
        Simulation(load_scene(scene))
    assert "ls_spacing" in str(err.value) and "too coarse" in str(err.value)


def test_fluid_interval_that_overruns_the_pressure_is_refused():
    scene = load_scene(HOURGLASS, ["fluid.update_interval=100000"])
    with pytest.raises(SceneError) as err:
        Simulation(scene)
    msg = str(err.value)
    assert "fluid.update_interval" in msg and "diameters between pressure solves" in msg


def test_soft_contacts_detected_when_overlap_exceeds_limit():
    # kn so low that a load of 10 squeezes two unit disks by F/kn = 0.5 d, past the
    # default limit of 0.25 d: the realization stops as unstable, with the reason.
    scene = arena_scene([{"shape": "circle", "diameter": 1.0, "count": 2}], kn=20.0,
                        restitution=0.5, xi=5.0)
    scene["run"]["t_end"] = 20.0
    sim = make_sim(scene)
    sim.set_state([[[9.5, 5.0], [10.5, 5.0]]])
    sim.set_external_load(force=[[[10.0, 0.0], [-10.0, 0.0]]])
    res = sim.run()
    r = res.summary["realizations"][0]
    assert r["status"] == "unstable" and "overlap" in r["reason"]
    assert res.summary["mean_escapees"] is None
    # the same load on stiff contacts (kn = 1e4: 1e-3 d) runs through
    scene["particles"][0]["kn"] = 1e4
    sim = make_sim(scene)
    sim.set_state([[[9.5, 5.0], [10.5, 5.0]]])
    sim.set_external_load(force=[[[10.0, 0.0], [-10.0, 0.0]]])
    assert sim.run().summary["realizations"][0]["status"] == "ok"


def test_body_passing_through_another_is_detected():
    # Bodies already interpenetrating (centre of one inside the other) — what a
    # pass-through between sparse nodes ends in — stop the realization.
    scene = arena_scene([{"shape": "square", "side": 1.0, "count": 2}])
    sim = make_sim(scene)
    sim.set_state([[[10.0, 5.0], [10.2, 5.0]]])
    res = sim.run()
    r = res.summary["realizations"][0]
    assert r["status"] == "unstable" and "inside another" in r["reason"]
