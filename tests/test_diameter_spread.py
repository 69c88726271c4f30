"""particles.diameter_spread: a species split, when the scene is loaded, into five
equally populated size classes whose sizes are 1 + s z_k times the species' own
(z_k the conditional means of a standard normal in its five equal-probability
bins, rescaled to unit standard deviation)."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate, stats

from taichi_hsdem.cli import main
from taichi_hsdem.resolve import resolve
from taichi_hsdem.scene import SceneError, load_scene, scene_to_toml
from taichi_hsdem.scene.load import size_class_factors, split_count

ROOT = Path(__file__).resolve().parents[1]
VANI = str(ROOT / "scenes" / "vani_phi026.toml")


def bin_means():
    """z_k by quadrature of x phi(x) over each fifth of the normal's probability,
    independent of the loader's closed form; and the same rescaled to unit
    standard deviation over the five classes."""
    edges = [-np.inf, *stats.norm.ppf([0.2, 0.4, 0.6, 0.8]), np.inf]
    z = np.array([integrate.quad(lambda x: x * stats.norm.pdf(x), a, b,
                                 epsabs=1e-14, epsrel=1e-14)[0] / 0.2
                  for a, b in zip(edges[:-1], edges[1:])])
    return z, (z - z.mean()) / z.std()


def scene(species, **fluid):
    return {"run": {"t_end": 1.0},
            "fluid": {"viscosity": 1e-3, "gap": 2e-5, "p_in": 100.0, **fluid},
            "geometry": {"kind": "hourglass", "length": 1e-3, "width": 2e-4,
                         "neck_width": 5e-5},
            "particles": species}


CIRCLE = {"name": "beads", "shape": "circle", "diameter": 2e-5, "density": 1050.0,
          "count": 23, "friction": 0.4, "kn": 3.0}


def test_bin_means_are_the_known_ones():
    z, _ = bin_means()
    # E[X | X > Phi^-1(0.8)] = phi(0.8416) / 0.2 = 1.39981 (tables of the normal)
    np.testing.assert_allclose(z, [-1.39981, -0.53190, 0.0, 0.53190, 1.39981], atol=1e-5)


@pytest.mark.parametrize("s", [1e-3, 0.05, 0.1, 0.25])
def test_factors_have_mean_one_and_standard_deviation_s(s):
    f = np.array(size_class_factors(s))
    assert abs(f.mean() - 1.0) < 1e-12
    assert abs(f.std() - s) < 1e-12                  # over the five equal classes
    assert np.all(np.diff(f) > 0)                    # smallest first
    np.testing.assert_allclose(f, 1.0 + s * bin_means()[1], rtol=0, atol=1e-12)


def test_counts_split_evenly_middle_first():
    for n in range(5, 60):
        counts = split_count(n)
        assert sum(counts) == n and max(counts) - min(counts) <= 1
        # the middle class takes the first extra particle, the outer ones the last
        assert counts[2] == max(counts) and min(counts[0], counts[4]) == min(counts)
    sc = load_scene(scene([dict(CIRCLE, diameter_spread=0.1)]))
    assert [p.count for p in sc.particles] == [4, 5, 5, 5, 4]           # 23 = 5 * 4 + 3


def test_classes_are_named_scaled_and_copied():
    s = 0.1
    sc = load_scene(scene([dict(CIRCLE, diameter_spread=s)]))
    names = [p.name for p in sc.particles]
    assert names == [f"beads/{k}" for k in range(1, 6)]
    _, zhat = bin_means()
    for p, z in zip(sc.particles, zhat):
        assert p.diameter == pytest.approx(2e-5 * (1 + s * z), rel=1e-12)
        assert p.diameter_spread == 0.0
        assert (p.density, p.friction, p.kn, p.shape) == (1050.0, 0.4, 3.0, "circle")


@pytest.mark.parametrize("species", [
    {"shape": "square", "side": 1.5e-5},
    {"shape": "rectangle", "width": 2e-5, "height": 1e-5},
    {"shape": "regular_polygon", "diameter": 2e-5, "n_vertices": 6},
    {"shape": "polygon", "vertices": [[0, 0], [2e-5, 0], [2e-5, 1e-5], [1e-5, 1.5e-5]]},
])
def test_every_shape_scales_its_size(species):
    s = 0.2
    base = dict(species, density=1000.0, count=10)
    d = load_scene(scene([base])).particles[0].d_eq()
    classes = load_scene(scene([dict(base, diameter_spread=s)])).particles
    np.testing.assert_allclose([p.d_eq() for p in classes], d * (1 + s * bin_means()[1]),
                               rtol=1e-12)


def test_packing_fractions_split_into_five_equal_parts():
    species = dict(CIRCLE, count=None, packing_fraction=0.3, diameter_spread=0.05)
    del species["count"]
    sc = load_scene(scene([species]))
    fractions = [p.packing_fraction for p in sc.particles]
    assert sum(fractions) == pytest.approx(0.3, rel=1e-14)
    assert fractions == [pytest.approx(0.06, rel=1e-14)] * 5
    assert all(p.count is None for p in sc.particles)


def test_resolved_species_have_the_class_diameters():
    s = 0.05
    m = resolve(load_scene(VANI, [f"particles.diameter_spread={s}", "run.realizations=1"]))
    np.testing.assert_allclose([sp.d_eq for sp in m.species],
                               140e-6 * (1 + s * bin_means()[1]), rtol=1e-12)
    # the five packing fractions resolve to counts of nearly the same area each
    areas = [sp.count * math.pi * sp.d_eq ** 2 / 4 for sp in m.species]
    assert max(areas) / min(areas) < 1.25


def test_zero_spread_leaves_the_scene_unchanged():
    plain = load_scene(scene([CIRCLE])).to_dict()
    assert load_scene(scene([dict(CIRCLE, diameter_spread=0.0)])).to_dict() == plain
    assert load_scene(scene([dict(CIRCLE, diameter_spread=0)])).to_dict() == plain


def test_the_written_scene_loads_as_the_same_classes(tmp_path):
    sc = load_scene(scene([dict(CIRCLE, diameter_spread=0.1),
                           {"shape": "square", "side": 1e-5, "density": 1.0, "count": 3}]))
    path = tmp_path / "again.toml"
    path.write_text(scene_to_toml(sc))
    again = load_scene(path)
    assert again.to_dict() == sc.to_dict()
    assert [p.name for p in again.particles] == [*(f"beads/{k}" for k in range(1, 6)),
                                                  "species1"]


@pytest.mark.parametrize("change, text", [
    ({"positions": [[1e-4, 1e-4], [2e-4, 1e-4], [3e-4, 1e-4], [4e-4, 1e-4],
                    [5e-4, 1e-4]], "count": None}, "positions"),
    ({"diameter_spread": 0.3}, "must be in [0, 0.25]"),
    ({"diameter_spread": -0.01}, "must be in [0, 0.25]"),
    ({"count": 4}, "count must be at least 5, got 4"),
    ({"count": 0}, "count must be at least 5, got 0"),
])
def test_refusals_name_the_spread(change, text):
    species = {**CIRCLE, "diameter_spread": 0.1, **change}
    species = {k: v for k, v in species.items() if v is not None}
    with pytest.raises(SceneError) as error:
        load_scene(scene([species]))
    (line,) = [p for p in error.value.problems if "diameter_spread" in p]
    assert line.startswith("<dict>: particles[0].diameter_spread: ") and text in line


def test_a_class_too_thick_for_the_gap_is_refused_on_the_spread():
    # gap 2e-5 takes d_eq < 3e-5: d = 2.7e-5 does, its largest class at s = 0.1 not
    ok = dict(CIRCLE, diameter=2.7e-5)
    load_scene(scene([ok]))
    with pytest.raises(SceneError, match=r"particles\[0\]\.diameter_spread: 0.1 makes size "
                                         r"class beads/5 d_eq = 3.09\d*e-05, and fluid.gap"):
        load_scene(scene([dict(ok, diameter_spread=0.1)]))


def test_class_names_must_not_clash():
    other = dict(CIRCLE, name="beads/2")
    with pytest.raises(SceneError, match=r"particles\[0\]\.name: its size class "
                                         r'"beads/2" \(diameter_spread\) is the name of '
                                         r"particles\[1\]"):
        load_scene(scene([dict(CIRCLE, diameter_spread=0.1), other]))


def test_an_override_names_its_origin_and_the_cli_exits_2(tmp_path, capsys):
    path = tmp_path / "three.toml"
    path.write_text(Path(VANI).read_text().replace("packing_fraction = 0.26", "count = 3"))
    args = [str(path), "--out", str(tmp_path / "x"), "--quiet",
            "--set", "particles.diameter_spread=0.05"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert ("(--set particles.diameter_spread=0.05): particles[0].diameter_spread: 0.05 "
            "splits the species into 5 size classes: count must be at least 5, got 3") in err


def test_a_short_run_counts_escapees_per_class_and_reruns(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert main([VANI, "--out", str(a), "--realizations", "1", "--quiet",
                 "--set", "particles.diameter_spread=0.05", "--set", "run.t_end=0.05"]) == 0
    sa = json.loads((a / "summary.json").read_text())
    assert sa["species"] == [f"disks/{k}" for k in range(1, 6)]
    (r,) = sa["realizations"]
    assert r["status"] == "ok" and len(r["escapees_by_species"]) == 5
    # the resolved scene lists the classes with spread 0: it reruns the same particles
    assert main([str(a / "scene.resolved.toml"), "--out", str(b), "--quiet"]) == 0
    sb = json.loads((b / "summary.json").read_text())
    assert sb["species"] == sa["species"]
    with np.load(a / "final_state.npz") as fa, np.load(b / "final_state.npz") as fb:
        for key in ("x", "theta", "v", "omega", "alive", "species", "seed"):
            np.testing.assert_array_equal(fa[key], fb[key], err_msg=key)
