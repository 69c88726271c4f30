"""tools/bench_reduction.py: its two contact kernels (per-body sums, atomic pair
scatter) against an independent numpy evaluation of the same disk law, and the
conservation laws a pair force obeys."""
from pathlib import Path

import numpy as np

from conftest import load_tool

ROOT = Path(__file__).resolve().parents[1]
EPS = np.finfo(np.float64).eps


def _reference(pb, tool):
    """Per-pair forces from the half list in numpy, scattered with np.add.at: force
    and moment on every body, the pair forces, the moments and the capped count."""
    x, v, w, r, m = pb["x"], pb["v"], pb["w"], pb["rad"], pb["mass"]
    prm = pb["prm"]
    kn, ks, mu, ce, dt = (prm[k] for k in (tool.P_KN, tool.P_KS, tool.P_MU, tool.P_CE,
                                            tool.P_DT))
    i, j = pb["half"][:, 0], pb["half"][:, 1]
    d = x[i] - x[j]
    dist = np.linalg.norm(d, axis=1)
    depth = r[i] + r[j] - dist
    on = depth > 0
    i, j, d, dist, depth = i[on], j[on], d[on], dist[on], depth[on]
    n = d / dist[:, None]
    gamma = ce * np.sqrt(kn * m[i] * m[j] / (m[i] + m[j]))
    ra = -(r[i] - 0.5 * depth)[:, None] * n        # centre of i to the contact point
    rb = (r[j] - 0.5 * depth)[:, None] * n         # centre of j to the same point

    def perp(a):                                   # w x a, per unit w
        return np.stack([-a[:, 1], a[:, 0]], axis=1)

    u = v[i] + w[i, None] * perp(ra) - v[j] - w[j, None] * perp(rb)
    un = np.sum(u * n, axis=1)
    fn = (depth * kn - gamma * un)[:, None] * n
    fs = -ks * dt * (u - un[:, None] * n)
    cap = mu * np.linalg.norm(fn, axis=1)
    fsn = np.linalg.norm(fs, axis=1)
    capped = fsn > cap
    fs[capped] *= (cap[capped] / fsn[capped])[:, None]
    fp = fn + fs

    def cross(a, b):
        return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]

    f = np.zeros_like(x)
    tau = np.zeros(len(x))
    np.add.at(f, i, fp)
    np.add.at(f, j, -fp)
    np.add.at(tau, i, cross(ra, fs))
    np.add.at(tau, j, cross(rb, -fs))
    return f, tau, fp, cross(ra, fs), int(capped.sum())


def test_per_body_and_atomic_pair_kernels_give_the_reference_forces_and_conserve_momentum():
    tool = load_tool("bench_reduction")
    from taichi_hsdem.backend import ti
    pb = tool.problem(200, seed=3)
    # A time step 30 times the benchmark's makes the tangential force k_s dt u_t
    # reach the Coulomb cap in some contacts and not in others: both branches run.
    pb["prm"][tool.P_DT] *= 30.0
    x, r = pb["x"], pb["rad"]

    # the lists: every pair closer than r_i + r_j + skin, by brute force
    gap = np.linalg.norm(x[:, None] - x[None], axis=2) - (r[:, None] + r[None])
    skin = tool.SKIN * 2.0 * r.min()
    ii, jj = np.nonzero(np.triu(gap < skin, k=1))
    assert np.array_equal(pb["half"], np.stack([ii, jj], axis=1))
    for b in range(len(x)):
        row = pb["nbr"][b, :pb["nbr_n"][b]]
        assert np.array_equal(row, np.sort(np.nonzero((gap[b] < skin) & (np.arange(len(x)) != b))[0]))

    f_ref, tau_ref, fp, tp, n_capped = _reference(pb, tool)
    n_touch = len(fp)
    assert 2 * n_touch / len(x) >= 3.0        # a dense packing: several contacts per disk
    assert 0 < n_capped < n_touch             # capped and free tangential forces both

    arrays = tool.Arrays(pb, ti.f64)
    f_body, tau_body = arrays.forces("per_body")
    f_pair, tau_pair = arrays.forces("atomic_pairs")

    # The same law in the same precision: the kernels and numpy differ by the rounding
    # of a handful of terms per body (a few units of 2.2e-16 of the largest pair
    # force or moment). 1e-12 leaves a margin of over 1000 and still fails on any
    # sign, factor or missed pair (errors of order one).
    f_scale = np.max(np.abs(fp))
    t_scale = np.max(np.abs(tp))
    for f, tau in ((f_body, tau_body), (f_pair, tau_pair)):
        assert np.max(np.abs(f - f_ref)) <= 1e-12 * f_scale
        assert np.max(np.abs(tau - tau_ref)) <= 1e-12 * t_scale
    assert np.max(np.abs(f_body - f_pair)) <= 1e-12 * f_scale
    assert np.max(np.abs(tau_body - tau_pair)) <= 1e-12 * t_scale

    # Newton's third law and the balance of angular momentum about the origin (the
    # two bodies share the contact point): zero up to the rounding of the sums, at
    # most (terms in the longest sum + log2 N) eps times the sum of what is added.
    terms = int(pb["nbr_n"].max()) + int(np.ceil(np.log2(len(x)))) + 2
    abs_f = 2.0 * np.sum(np.linalg.norm(fp, axis=1))
    lever = np.linalg.norm(x, axis=1).max() + r.max()
    for f, tau in ((f_body, tau_body), (f_pair, tau_pair)):
        assert np.all(np.abs(f.sum(axis=0)) <= terms * EPS * abs_f)
        moment = np.sum(x[:, 0] * f[:, 1] - x[:, 1] * f[:, 0]) + tau.sum()
        assert abs(moment) <= 2 * terms * EPS * lever * abs_f
    # ... and the bounds are far below any single contact: a lost pair would show
    assert terms * EPS * abs_f < 1e-6 * f_scale
