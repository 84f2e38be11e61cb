"""The TLS region search after GNC on pose graphs (core/gnc_search.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from microlie import SE2, SE3, SO2, SO3
from microlie.optim import BetweenFactor, FactorGraph, Isotropic
from microlie.optim.core.gnc import GNC
from microlie.optim.core.gnc_chordal import pose_graph_edges
from microlie.optim.core.gnc_search import (
    best_region_move,
    chain_moves,
    region_moves,
    search_stage,
)

SIGMA = 0.01


def _true_chain(G, rng, n):
    """``(n, k, k)`` true pose matrices of a random chain from the identity (steps: rotation
    angles ~ N(0, 0.3), translations uniform in [0.5, 1.5] per axis)."""
    d = 2 if G is SE2 else 3
    R = SO2 if G is SE2 else SO3
    step = G.from_rotation_translation(R.exp(rng.normal(0, 0.3, (n - 1, 1 if G is SE2 else 3))),
                                       rng.uniform(0.5, 1.5, (n - 1, d)))
    T = [np.eye(d + 1)]
    for k in range(n - 1):
        T.append(T[-1] @ np.asarray(step[k].matrix()))
    return np.array(T)


def _scene(G, seed, noise=True):
    """Two pieces of ten poses (chains with internal loop closures); across them the odometry
    edge 9-10 and three good closures (noise a tenth of what the information says, so that
    the truth fits), and two wrong closures that both fit when piece 1 is moved by one rigid
    motion ``D``. Returns the edges, the truth ``T`` and the poses ``X``
    with piece 1 moved by ``D`` (the local minimum: 2 wrong edges fit, 4 good ones do not)."""
    rng = np.random.default_rng(seed)
    d = 2 if G is SE2 else 3
    dim = 3 if G is SE2 else 6
    R = SO2 if G is SE2 else SO3
    n = 20
    T = _true_chain(G, rng, n)
    ii, jj, kind = [], [], []  # 0 inside a piece, 1 good across, 2 wrong across
    for p in range(2):
        for v in range(10 * p, 10 * p + 9):
            ii.append(v), jj.append(v + 1), kind.append(0)
        for a, b in ((0, 3), (2, 6), (4, 8), (1, 9), (5, 9)):
            ii.append(10 * p + a), jj.append(10 * p + b), kind.append(0)
    for a, b in ((9, 10), (7, 12), (5, 15), (3, 18)):
        ii.append(a), jj.append(b), kind.append(1)
    for a, b in ((1, 14), (6, 17)):
        ii.append(a), jj.append(b), kind.append(2)
    ii, jj, kind = np.array(ii), np.array(jj), np.array(kind)
    Zm = np.linalg.inv(T[ii]) @ T[jj]
    if noise:
        Zm = Zm @ np.asarray(G.exp(rng.normal(0, SIGMA / 10, (ii.size, dim))).matrix())
    # piece 1 displaced by a random rigid motion; the wrong edges measure it displaced
    D = np.asarray(G.from_rotation_translation(R.random(1, rng=rng),
                                               rng.uniform(-20, 20, (1, d))).matrix())[0]
    X = T.copy()
    X[10:] = D @ T[10:]
    bad = kind == 2
    Zm[bad] = np.linalg.inv(X[ii[bad]]) @ X[jj[bad]]
    info = np.tile(np.eye(dim) / SIGMA ** 2, (ii.size, 1, 1))
    return n, ii, jj, G.from_matrix(Zm), info, T, X, kind


def _tls_sum(G, X, ii, jj, Z, info, c2):
    """``sum min(s, c^2)`` by the group's own operations (the independent computation)."""
    Xg = G.from_matrix(X)
    r = np.asarray(Z.inverse().compose(Xg[ii].inverse().compose(Xg[jj])).log())
    return float(np.minimum(np.einsum("ea,eab,eb->e", r, info, r), c2).sum())


@pytest.mark.parametrize("G", [SE2, SE3])
def test_region_move_undoes_a_displaced_piece(G):
    n, ii, jj, Z, info, T, X, kind = _scene(G, 0, noise=False)
    c2 = float(chi2.ppf(0.99, info.shape[-1]))
    lab = (np.arange(n) >= 10).astype(np.int64)
    gain, moved, D = best_region_move(G, G.from_matrix(X), ii, jj, Z, info, lab,
                                      np.ones(ii.size, bool), c2, 0)
    assert moved.tolist() == [False] * 10 + [True] * 10
    # 4 good edges fit, 2 wrong ones no longer: the sum falls by 2 c^2
    assert gain == pytest.approx(-2.0 * c2, rel=1e-9)
    X2 = X.copy()
    X2[moved] = D @ X[moved]
    np.testing.assert_allclose(X2, T, atol=1e-9)  # back at the truth
    assert _tls_sum(G, X2, ii, jj, Z, info, c2) - _tls_sum(G, X, ii, jj, Z, info, c2) == \
        pytest.approx(gain, rel=1e-9)


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("seed", [2, 3])
def test_region_gain_is_the_exact_change(G, seed):
    # noisy measurements and finer pieces (the second piece cut in three): the gain of every
    # proposed move equals the change of sum min(s, c^2) computed from scratch
    n, ii, jj, Z, info, T, X, kind = _scene(G, seed)
    c2 = float(chi2.ppf(0.99, info.shape[-1]))
    lab = np.r_[np.zeros(10), np.repeat([1, 2, 3], [3, 3, 4])].astype(np.int64)
    moves = region_moves(G, G.from_matrix(X), ii, jj, Z, info, lab, np.ones(ii.size, bool),
                         c2, 0, tol=-10.0)  # every proposal's best region, even worse ones
    assert moves
    before = _tls_sum(G, X, ii, jj, Z, info, c2)
    for gain, region, D in moves:
        X2 = X.copy()
        m = np.isin(lab, region)
        assert not m[0]  # the anchor's piece never moves
        X2[m] = D @ X[m]
        assert _tls_sum(G, X2, ii, jj, Z, info, c2) - before == pytest.approx(gain, abs=1e-6)
    assert moves[0][0] < -0.25 * c2
    assert all(a[0] <= b[0] for a, b in zip(moves[:-1], moves[1:], strict=True))


def test_known_edges_are_never_truncated():
    # with the odometry edge 9-10 known (cost s, no truncation), breaking it is never cheap:
    # at the truth no move is proposed although the two wrong edges are rejected there
    n, ii, jj, Z, info, T, X, kind = _scene(SE2, 4)
    c2 = float(chi2.ppf(0.99, 3))
    lab = (np.arange(n) >= 10).astype(np.int64)
    judged = ~((ii == 9) & (jj == 10))
    assert region_moves(SE2, SE2.from_matrix(T), ii, jj, Z, info, lab, judged, c2, 0) == []


@pytest.mark.parametrize("G", [SE2, SE3])
def test_search_stage_on_a_graph(G):
    n, ii, jj, Z, info, T, X, kind = _scene(G, 5)
    c2 = float(chi2.ppf(0.99, info.shape[-1]))
    g = FactorGraph()
    x = g.add_variables(G.from_matrix(X), fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Isotropic(info.shape[-1], SIGMA)))
    edges = pose_graph_edges(g.problem())
    known = [kind == 0]
    w = [(kind != 1).astype(np.float64)]  # GNC's verdict in the local minimum
    states = [np.asarray(G.from_matrix(X).params)]

    def objective(st):
        return 0.5 * _tls_sum(G, np.asarray(G.from_params(st[0]).matrix()), ii, jj, Z, info,
                              c2)

    new, moves = search_stage(states, edges, known, [np.zeros(ii.size, bool)], w, [c2],
                              lambda st: st, objective)
    assert moves == 1
    P = np.asarray(G.from_params(new[0]).matrix())
    assert np.abs(P[:, :-1, -1] - T[:, :-1, -1]).max() < 10 * SIGMA * n  # at the truth
    assert w[0].tolist() == (kind != 2).astype(float).tolist()  # wrong out, good in
    assert objective(new) < objective(states)


def test_search_stage_keeps_states_when_the_solve_does_not_help():
    n, ii, jj, Z, info, T, X, kind = _scene(SE2, 6)
    c2 = float(chi2.ppf(0.99, 3))
    g = FactorGraph()
    x = g.add_variables(SE2.from_matrix(X), fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Isotropic(3, SIGMA)))
    edges = pose_graph_edges(g.problem())
    w = [(kind != 1).astype(np.float64)]
    states = [np.asarray(SE2.from_matrix(X).params)]
    new, moves = search_stage(states, edges, [kind == 0], [np.zeros(ii.size, bool)], w, [c2],
                              lambda st: states, lambda st: 0.0)  # a solve that undoes it
    assert moves == 0 and new is states
    assert w[0].tolist() == (kind != 1).astype(float).tolist()  # weights restored


def test_bad_input():
    n, ii, jj, Z, info, T, X, kind = _scene(SE2, 7)
    lab = np.zeros(n, np.int64)
    with pytest.raises(ValueError, match="SE2 or SE3"):
        region_moves(SO2, SE2.from_matrix(X), ii, jj, Z, info, lab, np.ones(ii.size, bool),
                     11.3, 0)
    with pytest.raises(ValueError, match="max_steps"):
        region_moves(SE2, SE2.from_matrix(X), ii, jj, Z, info, lab, np.ones(ii.size, bool),
                     11.3, 0, max_steps=0)
    with pytest.raises(ValueError, match="one entry per edge"):
        region_moves(SE2, SE2.from_matrix(X), ii, jj, Z, info, lab, np.ones(3, bool), 11.3, 0)
    with pytest.raises(ValueError, match="search must be True or False"):
        GNC("tls", first="cycles", search="yes")  # type: ignore[arg-type]


def test_gnc_with_search_on_a_pose_graph():
    # the whole pipeline (first="cycles", search=True) from the displaced poses: the wrong
    # closures rejected, the good ones kept, the poses at the truth
    n, ii, jj, Z, info, T, X, kind = _scene(SE2, 8)
    g = FactorGraph()
    x = g.add_variables(SE2.from_matrix(X), fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Isotropic(3, SIGMA)))
    res = g.optimize(robust=GNC("tls", first="cycles", search=True), verbose=False)
    assert res.inliers[0].tolist() == (kind != 2).tolist()
    P = np.asarray(res.values[x].translation())
    assert np.abs(P - T[:, :2, 2]).max() < 0.01


def _chain_scene(G, seed, noise=False):
    """Three pieces of four poses (chains): A = 0-3 (the anchor's), B = 4-7, C = 8-11. The
    good edges across them, 3-4 and 7-8 (odometry) and the closure 1-9, are rejected: B sits
    displaced by one rigid motion, held there by the wrong edge 0-5 that fits it, and C by
    another, held by the wrong edge 2-10. Moving B alone to the truth brings 3-4 in and 0-5
    out (7-8 stays out: C is displaced), moving C alone brings 1-9 in and 2-10 out: ties.
    Moving C and then B brings 3-4, 7-8 and 1-9 in and both wrong edges out: one edge less.
    Returns the edges, the truth ``T``, the displaced poses ``X`` and the piece labels."""
    rng = np.random.default_rng(seed)
    d = 2 if G is SE2 else 3
    dim = 3 if G is SE2 else 6
    R = SO2 if G is SE2 else SO3
    n = 12
    T = _true_chain(G, rng, n)
    ii = np.array([0, 1, 2, 4, 5, 6, 8, 9, 10, 3, 7, 1, 0, 2])
    jj = np.array([1, 2, 3, 5, 6, 7, 9, 10, 11, 4, 8, 9, 5, 10])
    kind = np.array([0] * 9 + [1] * 3 + [2] * 2)  # inside a piece, good across, wrong
    Zm = np.linalg.inv(T[ii]) @ T[jj]
    if noise:
        Zm = Zm @ np.asarray(G.exp(rng.normal(0, SIGMA / 10, (ii.size, dim))).matrix())
    X = T.copy()
    for lo, hi in ((4, 8), (8, 12)):  # B and C displaced by different rigid motions
        D = np.asarray(G.from_rotation_translation(R.random(1, rng=rng),
                                                   rng.uniform(-20, 20, (1, d))).matrix())[0]
        X[lo:hi] = D @ T[lo:hi]
    bad = kind == 2
    Zm[bad] = np.linalg.inv(X[ii[bad]]) @ X[jj[bad]]
    info = np.tile(np.eye(dim) / SIGMA ** 2, (ii.size, 1, 1))
    lab = np.repeat([0, 1, 2], 4)
    return n, ii, jj, G.from_matrix(Zm), info, T, X, kind, lab


@pytest.mark.parametrize("G", [SE2, SE3])
def test_single_moves_are_ties_and_the_chain_lowers(G):
    n, ii, jj, Z, info, T, X, kind, lab = _chain_scene(G, 0)
    c2 = float(chi2.ppf(0.99, info.shape[-1]))
    judged = np.ones(ii.size, bool)
    before = _tls_sum(G, X, ii, jj, Z, info, c2)
    assert before == pytest.approx(3 * c2, rel=1e-9)  # the three good edges across rejected
    # every rigid move of B, C or both that makes one edge across fit, from scratch: none lowers
    Xg = G.from_matrix(X)
    for e in np.flatnonzero(kind > 0):
        for region in ([1], [2], [1, 2]):
            m = np.isin(lab, region)
            if m[ii[e]] == m[jj[e]]:
                continue
            Zm = np.asarray(Z.matrix())[e]
            D = X[ii[e]] @ Zm @ np.linalg.inv(X[jj[e]]) if m[jj[e]] else \
                X[jj[e]] @ np.linalg.inv(Zm) @ np.linalg.inv(X[ii[e]])
            X2 = X.copy()
            X2[m] = D @ X[m]
            assert _tls_sum(G, X2, ii, jj, Z, info, c2) >= before - 1e-6 * c2
    assert region_moves(G, Xg, ii, jj, Z, info, lab, judged, c2, 0) == []
    gain, X2, moved, chains = chain_moves(G, Xg, ii, jj, Z, info, lab, judged, c2, 0, length=1)
    assert (gain, chains, moved.any()) == (0.0, 0, False)  # single moves: nothing
    gain, X2, moved, chains = chain_moves(G, Xg, ii, jj, Z, info, lab, judged, c2, 0)
    assert chains == 1
    assert gain == pytest.approx(-c2, rel=1e-9)  # one edge less
    P2 = np.asarray(X2.matrix())
    assert _tls_sum(G, P2, ii, jj, Z, info, c2) - before == pytest.approx(gain, rel=1e-9)
    np.testing.assert_allclose(P2, T, atol=1e-9)  # both pieces back at the truth
    assert moved.tolist() == [False] * 4 + [True] * 8


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("seed", [1, 2])
def test_chain_gain_is_the_exact_change(G, seed):
    # noisy measurements, finer pieces (C cut in two): the gain equals the change of
    # sum min(s, c^2) recomputed from scratch by the group's operations
    n, ii, jj, Z, info, T, X, kind, lab = _chain_scene(G, seed, noise=True)
    c2 = float(chi2.ppf(0.99, info.shape[-1]))
    lab = np.repeat([0, 1, 2, 3], [4, 4, 2, 2])
    gain, X2, moved, chains = chain_moves(G, G.from_matrix(X), ii, jj, Z, info, lab,
                                          np.ones(ii.size, bool), c2, 0)
    assert chains >= 1 and gain < -0.25 * c2
    after = _tls_sum(G, np.asarray(X2.matrix()), ii, jj, Z, info, c2)
    assert after - _tls_sum(G, X, ii, jj, Z, info, c2) == pytest.approx(gain, abs=1e-6 * c2)
    assert not moved[:4].any()  # the anchor's piece never moves


def test_search_stage_with_chains():
    n, ii, jj, Z, info, T, X, kind, lab = _chain_scene(SE2, 3, noise=True)
    c2 = float(chi2.ppf(0.99, 3))
    g = FactorGraph()
    x = g.add_variables(SE2.from_matrix(X), fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Isotropic(3, SIGMA)))
    edges = pose_graph_edges(g.problem())
    states = [np.asarray(SE2.from_matrix(X).params)]

    def objective(st):
        return 0.5 * _tls_sum(SE2, np.asarray(SE2.from_params(st[0]).matrix()), ii, jj, Z,
                              info, c2)

    for chain in (False, True):
        w = [(kind != 1).astype(np.float64)]  # GNC's verdict in the local minimum
        new, moves = search_stage(states, edges, [kind == 0], [np.zeros(ii.size, bool)], w,
                                  [c2], lambda st: st, objective, chain=chain)
        assert moves == int(chain)  # the region moves alone find nothing
    P = np.asarray(SE2.from_params(new[0]).matrix())
    assert np.abs(P[:, :2, 2] - T[:, :2, 2]).max() < 10 * SIGMA * n  # at the truth
    assert w[0].tolist() == (kind != 2).astype(float).tolist()  # wrong out, good in
    assert objective(new) < objective(states)


def test_chain_bad_input():
    n, ii, jj, Z, info, T, X, kind, lab = _chain_scene(SE2, 4)
    Xg = SE2.from_matrix(X)
    judged = np.ones(ii.size, bool)
    with pytest.raises(ValueError, match="SE2 or SE3"):
        chain_moves(SO2, Xg, ii, jj, Z, info, lab, judged, 11.3, 0)
    for kw in ({"length": 0}, {"hood": 0}, {"width": 1.5}, {"max_scans": True}):
        with pytest.raises(ValueError, match="integer >= 1"):
            chain_moves(SE2, Xg, ii, jj, Z, info, lab, judged, 11.3, 0, **kw)
    for kw in ({"first": -0.1}, {"uphill": float("nan")}, {"tol": "1"}):
        with pytest.raises(ValueError, match="finite number >= 0"):
            chain_moves(SE2, Xg, ii, jj, Z, info, lab, judged, 11.3, 0, **kw)
    with pytest.raises(ValueError, match="one entry per edge"):
        chain_moves(SE2, Xg, ii, jj, Z, info, lab, judged[:3], 11.3, 0)
    with pytest.raises(ValueError, match="chain must be True or False"):
        search_stage([np.asarray(Xg.params)], None, [], [], [], [11.3], lambda st: st,
                     lambda st: 0.0, chain="yes")  # type: ignore[arg-type]
