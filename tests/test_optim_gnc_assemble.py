"""Assembling the pieces of a pose graph by cycles of pieces (core/gnc_assemble.py)."""

from __future__ import annotations

import numpy as np
import pytest

from microlie import SE2, SE3, SO2, SO3
from microlie.optim import BetweenFactor, FactorGraph, Information
from microlie.optim.core.gnc import GNC
from microlie.optim.core.gnc_assemble import (
    assemble_edges,
    join_pieces,
    parallel_links,
    pose_pieces,
    reduce_series,
    variance_factor,
)

SIGMA = 0.01
C2 = {SE2: 11.344867, SE3: 16.811894}  # chi2.ppf(0.99, 3), chi2.ppf(0.99, 6)


def _truth(G, n, rng, spread=1.0):
    """``n`` random poses as matrices."""
    d = 2 if G is SE2 else 3
    R = (SO2 if G is SE2 else SO3).random(n, rng=rng)
    return np.asarray(G.from_rotation_translation(R, rng.uniform(-5, 5, (n, d)) * spread)
                      .matrix(), dtype=np.float64)


def _measure(G, T, ii, jj, rng, wrong=()):
    """Measurements of the truth with noise SIGMA; the rows in ``wrong`` random."""
    dim = 3 if G is SE2 else 6
    d = 2 if G is SE2 else 3
    Z = G.from_matrix(np.linalg.inv(T[ii]) @ T[jj]).compose(
        G.exp(rng.normal(0, SIGMA, (ii.size, dim))))
    P = np.asarray(Z.params).copy()
    w = np.asarray(wrong, dtype=np.int64)
    if w.size:
        rand = G.from_rotation_translation((SO2 if G is SE2 else SO3).random(w.size, rng=rng),
                                           rng.uniform(-10, 10, (w.size, d)))
        P[w] = np.asarray(rand.params)
    return G.from_params(P), np.tile(np.eye(dim) / SIGMA ** 2, (ii.size, 1, 1))


def _numeric_cov(G, D1, S1, D2, S2, h=1e-6):
    """Covariance of ``Log(C^-1 D1 exp(a) D2 exp(b))`` by finite-difference Jacobians."""
    dim = S1.shape[0]
    C = G.from_matrix(D1 @ D2)
    J1 = np.zeros((dim, dim))
    J2 = np.zeros((dim, dim))
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = h
        P1 = D1 @ np.asarray(G.exp(e).matrix()) @ D2
        P2 = D1 @ D2 @ np.asarray(G.exp(e).matrix())
        J1[:, k] = np.asarray(C.inverse().compose(G.from_matrix(P1)).log()) / h
        J2[:, k] = np.asarray(C.inverse().compose(G.from_matrix(P2)).log()) / h
    return J1 @ S1 @ J1.T + J2 @ S2 @ J2.T


@pytest.mark.parametrize("G", [SE2, SE3])
def test_reduce_series_composes_chain_and_covariance(G):
    rng = np.random.default_rng(0)
    T = _truth(G, 4, rng)
    ii, jj = np.array([0, 2, 3]), np.array([1, 1, 2])  # 0 -> 1 <- 2 <- 3: mixed directions
    D = np.linalg.inv(T[ii]) @ T[jj]
    dim = 3 if G is SE2 else 6
    A = rng.normal(size=(3, dim, dim))
    S = A @ np.swapaxes(A, 1, 2) * 1e-3 + np.eye(dim) * 1e-4
    a, b, Dc, Sc, mem = reduce_series(G, 4, ii, jj, D, S, keep=0)
    assert a.size == 0  # a path: everything is set aside
    # a cycle 0 -> 1 -> 2 -> 0 with a tail 2 - 3: the tail goes, the cycle stays as a loop
    ii2, jj2 = np.array([0, 1, 2, 3]), np.array([1, 2, 0, 2])
    D2 = np.linalg.inv(T[ii2]) @ T[jj2]
    S2 = np.concatenate([S, S[:1]])
    a, b, Dc, Sc, mem = reduce_series(G, 4, ii2, jj2, D2, S2, keep=0)
    assert sorted(len(m) for m in mem) == [1, 2]
    k = int(np.argmax([len(m) for m in mem]))
    # the composed link runs between 0 and the other end through the removed vertex
    assert {int(a[k]), int(b[k])} == {0, 1} or {int(a[k]), int(b[k])} == {0, 2}
    Tk = np.linalg.inv(T[a[k]]) @ T[b[k]]
    assert np.allclose(Dc[k], Tk, atol=1e-9)
    # its covariance against finite differences of the composition
    e1, e2 = mem[k]
    o1 = D2[e1] if ii2[e1] == a[k] else np.linalg.inv(D2[e1])
    sgn1 = ii2[e1] == a[k]
    Ad1 = np.asarray(G.from_matrix(D2[e1]).adjoint())
    S1 = S2[e1] if sgn1 else Ad1 @ S2[e1] @ Ad1.T
    o2 = D2[e2] if jj2[e2] == b[k] else np.linalg.inv(D2[e2])
    Ad2 = np.asarray(G.from_matrix(D2[e2]).adjoint())
    S2b = S2[e2] if jj2[e2] == b[k] else Ad2 @ S2[e2] @ Ad2.T
    # walking an edge backwards: Log(D^-1 exp(x)...) ~ -Ad(D) x, the covariance above
    assert np.allclose(Sc[k], _numeric_cov(G, o1, S1, o2, S2b), rtol=1e-4, atol=1e-10)


def test_reduce_series_refuses_bad_shapes():
    with pytest.raises(ValueError, match="one entry per link"):
        reduce_series(SE2, 2, np.array([0]), np.array([2]), np.zeros((1, 3, 3)),
                      np.zeros((1, 3, 3)))


@pytest.mark.parametrize("G", [SE2, SE3])
def test_parallel_links_majority_and_deferred_ties(G):
    rng = np.random.default_rng(1)
    dim = 3 if G is SE2 else 6
    true = _truth(G, 1, rng)[0]
    good = true @ np.asarray(G.exp(rng.normal(0, SIGMA, (3, dim))).matrix())
    wrong = _truth(G, 2, rng, spread=2.0)
    S = np.tile(np.eye(dim) * SIGMA ** 2, (5, 1, 1))
    D = np.concatenate([good, wrong])
    a, b = np.zeros(5, np.int64), np.ones(5, np.int64)
    assert parallel_links(G, a, b, D, S, C2[G]).tolist() == [0, 1, 2]
    # the same links walked the other way are the same votes
    Dr = np.linalg.inv(D)
    Sr = np.array([np.asarray(G.from_matrix(Dk).adjoint()) @ Sk @
                   np.asarray(G.from_matrix(Dk).adjoint()).T for Dk, Sk in zip(D, S, strict=True)])
    assert parallel_links(G, b, a, Dr, Sr, C2[G]).tolist() == [0, 1, 2]
    # one against one, two against two: deferred
    assert parallel_links(G, a[:2], b[:2], D[[0, 3]], S[:2], C2[G]).size == 0
    D4 = np.concatenate([good[:2], wrong[:1], wrong[:1] @ np.asarray(
        G.exp(rng.normal(0, SIGMA, (1, dim))).matrix())])
    assert parallel_links(G, a[:4], b[:4], D4, S[:4], C2[G]).size == 0


def _ladder(G, rng, wrong_rows=True):
    """Two rails of 12 poses joined by rungs at 0, 4, 8 and 11: every cycle has 8 to 10 edges
    (none marked by the 3-5 edge cycles), plus three random edges between rung ends; the
    truth."""
    n = 24
    T = _truth(G, 1, rng)
    d = 2 if G is SE2 else 3
    steps = G.from_rotation_translation((SO2 if G is SE2 else SO3).exp(
        rng.normal(0, 0.05, (n, 1 if G is SE2 else 3))), np.tile(
            np.r_[1.0, np.zeros(d - 1)], (n, 1)))
    P = [np.eye(d + 1)]
    for k in range(11):
        P.append(P[-1] @ np.asarray(steps[k].matrix()))
    up = np.eye(d + 1)
    up[1, d] = 4.0
    P = np.array(P + [up @ p for p in P])
    P = T[0] @ P
    ii = list(range(11)) + list(range(12, 23)) + [0, 4, 8, 11]
    jj = list(range(1, 12)) + list(range(13, 24)) + [12, 16, 20, 23]
    bad = [(4, 20), (8, 12), (0, 23)]
    ii += [a for a, _ in bad]
    jj += [b for _, b in bad]
    ii, jj = np.array(ii), np.array(jj)
    wrong = np.arange(ii.size - len(bad), ii.size)
    Z, info = _measure(G, P, ii, jj, rng, wrong if wrong_rows else ())
    truth = np.ones(ii.size, bool)
    truth[wrong] = False
    return n, ii, jj, Z, info, P, truth


@pytest.mark.parametrize("G", [SE2, SE3])
def test_assemble_edges_marks_long_cycles_not_wrong_edges(G):
    rng = np.random.default_rng(2)
    n, ii, jj, Z, info, P, truth = _ladder(G, rng)
    from microlie.optim.core.gnc_cycles import consistent_edges

    assert not consistent_edges(G, n, ii, jj, Z, info)[truth].any()  # no short cycle
    kn = assemble_edges(G, n, ii, jj, Z, info, np.zeros(ii.size, bool), 0, variance=1.0)
    assert kn.tolist() == truth.tolist()
    # the default variance factor: no known edge, no redundancy, 1
    assert assemble_edges(G, n, ii, jj, Z, info, np.zeros(ii.size, bool), 0).tolist() == \
        truth.tolist()


def _deferred(G, rng):
    """Pieces A = {0..3}, C = {4..7} (squares with a diagonal, known) and B = {8, 9, 10} (a
    chain, known). A-C: two good edges; A-B: one good edge g and one random edge w (one
    against one); C-B: one good edge h, which agrees with g only once A and C are joined."""
    T = _truth(G, 11, rng)
    ii = [0, 1, 2, 3, 0, 4, 5, 6, 7, 4, 8, 9, 4, 6, 1, 3, 5]
    jj = [1, 2, 3, 0, 2, 5, 6, 7, 4, 6, 9, 10, 0, 2, 8, 10, 9]
    ii, jj = np.array(ii), np.array(jj)
    Z, info = _measure(G, T, ii, jj, rng, wrong=[15])
    known = np.zeros(ii.size, bool)
    known[:12] = True
    return T, ii, jj, Z, info, known


@pytest.mark.parametrize("G", [SE2, SE3])
def test_deferred_tie_resolved_by_the_larger_piece(G):
    rng = np.random.default_rng(3)
    T, ii, jj, Z, info, known = _deferred(G, rng)
    g, w = 14, 15  # and h = 16
    # between the first pieces A and B: g against w, one link each: no choice
    X = pose_pieces(G, 11, ii, jj, Z, info, known, G.from_matrix(T))
    lab = np.array([0] * 4 + [1] * 4 + [2] * 3)
    Q = np.linalg.inv(X[[0] * 4 + [4] * 4 + [8] * 3]) @ X
    e = np.array([g, w])
    D = Q[ii[e]] @ np.asarray(Z[e].matrix()) @ np.linalg.inv(Q[jj[e]])  # type: ignore[call-overload]
    S = np.array([np.asarray(G.from_matrix(Q[jj[k]]).adjoint()) @ np.linalg.inv(info[k]) @
                  np.asarray(G.from_matrix(Q[jj[k]]).adjoint()).T for k in e])
    assert parallel_links(G, lab[ii[e]], lab[jj[e]], D, S, C2[G]).size == 0
    # assembled: A and C join by their two edges, then g and h agree across A+C | B
    kn = assemble_edges(G, 11, ii, jj, Z, info, known, 0, variance=1.0)
    expect = np.ones(ii.size, bool)
    expect[w] = False
    assert kn.tolist() == expect.tolist()


def test_join_and_pose_pieces_against_truth():
    rng = np.random.default_rng(4)
    T, ii, jj, Z, info, known = _deferred(SE2, rng)
    M = np.asarray(Z.matrix())
    # pieces displaced; joined along A-C edge 12 and g: every vertex back near the truth
    D1 = np.asarray(SE2.exp([[3.0, -2.0, 1.0]]).matrix())[0]
    D2 = np.asarray(SE2.exp([[-4.0, 1.0, -2.0]]).matrix())[0]
    X = T.copy()
    X[4:8] = D1 @ X[4:8]
    X[8:] = D2 @ X[8:]
    joins = np.zeros(ii.size, bool)
    joins[[12, 14]] = True
    Y = join_pieces(X, M, ii, jj, known, joins, 0)
    assert np.allclose(Y[:4], T[:4])  # the root's piece stays
    assert np.abs(Y[:, :2, 2] - T[:, :2, 2]).max() < 0.2  # noise 0.01 along short paths
    kn = known.copy()
    kn[[12, 13, 14, 16]] = True
    P = pose_pieces(SE2, 11, ii, jj, Z, info, kn, SE2.from_matrix(Y))
    assert np.abs(P[:, :2, 2] - T[:, :2, 2]).max() < 0.2  # 0.01 rad at 5-10 m lever arms
    # the least-squares optimum: the gradient of the known edges' cost vanishes, so the
    # variance factor there is no larger than at the truth
    assert variance_factor(SE2, 11, ii, jj, Z, info, P, kn) <= \
        variance_factor(SE2, 11, ii, jj, Z, info, T, kn)


def test_assemble_edges_refuses_bad_input():
    rng = np.random.default_rng(5)
    n, ii, jj, Z, info, P, truth = _ladder(SE2, rng)
    kn = np.zeros(ii.size, bool)
    with pytest.raises(ValueError, match="group must be SE2 or SE3"):
        assemble_edges(SO2, n, ii, jj, Z, info, kn, 0)
    with pytest.raises(ValueError, match="one entry per edge"):
        assemble_edges(SE2, n, ii, jj, Z, info, kn[:-1], 0)
    with pytest.raises(ValueError, match="anchor"):
        assemble_edges(SE2, n, ii, jj, Z, info, kn, n)
    with pytest.raises(ValueError, match="quantile"):
        assemble_edges(SE2, n, ii, jj, Z, info, kn, 0, quantile=1.0)
    with pytest.raises(ValueError, match="max_length"):
        assemble_edges(SE2, n, ii, jj, Z, info, kn, 0, max_length=2)
    with pytest.raises(ValueError, match="variance"):
        assemble_edges(SE2, n, ii, jj, Z, info, kn, 0, variance=0.0)
    with pytest.raises(ValueError, match="assemble must be True or False"):
        GNC(first="cycles", assemble=1)  # type: ignore[arg-type]


@pytest.mark.parametrize("G", [SE2, SE3])
def test_gnc_assemble_pipeline_finds_the_wrong_edges(G):
    rng = np.random.default_rng(6)
    n, ii, jj, Z, info, P, truth = _ladder(G, rng)
    g = FactorGraph()
    start = G.from_matrix(P).compose(G.exp(rng.normal(0, 0.05, (n, 3 if G is SE2 else 6))))
    x = g.add_variables(start, fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Information(info)))
    res = g.optimize(robust=GNC(first="cycles", assemble=True), verbose=False)
    assert res.inliers[0].tolist() == truth.tolist()
    # against the truth: the least-squares optimum of the good edges is within the noise
    X = np.asarray(res.values[x].matrix())
    Pa = np.linalg.inv(P[0]) @ P  # the same gauge: vertex 0 held at the start's pose
    Xa = np.linalg.inv(X[0]) @ X
    assert np.abs(Xa[:, :-1, -1] - Pa[:, :-1, -1]).max() < 0.1
