"""Exact TLS ties broken by the start values (core/gnc_bridges.py, core/gnc_merge.py, GNC).

A piece of a pose graph joined to the rest by one good edge and one wrong edge, no other edge
across: accepting either and rejecting the other costs the same TLS objective (the piece
moves rigidly so that the accepted edge fits). The truth is built first (poses, then exact
measurements from them); the other solution is the piece moved by the rigid motion that makes
the wrong edge fit, computed here from the truth and the wrong measurement.
"""

from __future__ import annotations

import numpy as np
import pytest

from microlie import SE2, SE3, SO2, SO3
from microlie.optim import BetweenFactor, FactorGraph, Isotropic
from microlie.optim.core.gnc import GNC
from microlie.optim.core.gnc_bridges import repair_bridges
from microlie.optim.core.gnc_merge import merge_components

SIGMA = 0.1


def _tie_graph(G, seed):
    """Vertices 0-3 (every pair joined: cycles), 4-6 (a triangle); across: 3-4 (good) and
    1-5 (a random measurement). Returns the truth (matrices), edges, measurements, the piece
    mask, the index of the good and the wrong edge, and the motion ``D`` of the piece that
    makes the wrong edge fit."""
    rng = np.random.default_rng(seed)
    d = 2 if G is SE2 else 3
    R = SO2 if G is SE2 else SO3
    T = np.asarray(G.from_rotation_translation(R.random(7, rng=rng),
                                               rng.uniform(-5, 5, (7, d))).matrix())
    T[0] = np.eye(d + 1)
    ii = np.array([0, 1, 2, 0, 1, 0, 4, 5, 4, 3, 1])
    jj = np.array([1, 2, 3, 2, 3, 3, 5, 6, 6, 4, 5])
    Zm = np.linalg.inv(T[ii]) @ T[jj]
    wrong_Z = np.asarray(G.from_rotation_translation(R.random(1, rng=rng),
                                                     rng.uniform(-10, 10, (1, d))).matrix())[0]
    Zm[10] = wrong_Z
    piece = np.zeros(7, dtype=bool)
    piece[4:] = True
    D = T[1] @ wrong_Z @ np.linalg.inv(T[5])  # X_1^-1 (D X_5) = Z_wrong
    return T, ii, jj, Zm, piece, 9, 10, D


def _graph(G, ii, jj, Zm, X0):
    g = FactorGraph()
    x = g.add_variables(G.from_matrix(X0), fixed=[0])
    dim = 3 if G is SE2 else 6
    f = g.add(BetweenFactor(x, ii, jj, G.from_matrix(Zm), Isotropic(dim, SIGMA)))
    return g, x, f


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("fits", ["good", "wrong"])
def test_gnc_cycles_tie_decided_by_the_start(G, seed, fits):
    T, ii, jj, Zm, piece, good, wrong, D = _tie_graph(G, seed)
    other = T.copy()
    other[piece] = D @ T[piece]  # the other TLS minimiser: the wrong edge fits
    # the start: the truth (the good edge fits) or the other minimiser (the wrong one fits),
    # both perturbed a little so that no edge fits exactly at the start
    rng = np.random.default_rng(100 + seed)
    dim = 3 if G is SE2 else 6
    X0 = T if fits == "good" else other
    X0 = np.asarray(G.from_matrix(X0).compose(G.exp(rng.normal(0, 1e-3, (7, dim)))).matrix())
    X0[0] = T[0]
    g, x, f = _graph(G, ii, jj, Zm, X0)
    # the start decides ties (chain=False; chain=True lets the odometry decide), under the
    # file's information (variance_factor=1)
    res = g.optimize(robust=GNC("tls", first="cycles", chain=False, variance_factor=1.0))
    expect = T if fits == "good" else other
    got = np.asarray(res.values[x].matrix())
    np.testing.assert_allclose(got, expect, atol=1e-7)
    inl = res.inliers[0]
    assert inl[good] == (fits == "good") and inl[wrong] == (fits == "wrong")
    assert inl[:9].all()
    # an exact tie: the TLS objective is the same both ways (one edge rejected)
    c2 = float(__import__("scipy.stats", fromlist=["chi2"]).chi2.ppf(0.99, dim))
    assert res.final_robust_cost == pytest.approx(0.5 * c2, rel=1e-6)


@pytest.mark.parametrize("fits", ["good", "wrong"])
def test_repair_bridges_tie_both_ways(fits):
    """The bridge accepted, the other edge rejected: the start decides which one stays."""
    G = SE2
    T, ii, jj, Zm, piece, good, wrong, D = _tie_graph(G, 3)
    other = T.copy()
    other[piece] = D @ T[piece]
    info = np.tile(np.eye(3) / SIGMA ** 2, (ii.size, 1, 1))
    Z = G.from_matrix(Zm)
    c2 = 11.34
    # start residuals, computed here: the start is the truth or the other minimiser
    X0 = T if fits == "good" else other
    rel = np.linalg.inv(X0[ii]) @ X0[jj]
    r = np.asarray(Z.inverse().compose(G.from_matrix(rel)).log())
    s0 = np.einsum("ea,eab,eb->e", r, info, r)
    judged = np.zeros(ii.size, dtype=bool)
    judged[[good, wrong]] = True
    for now, X in ((good, T), (wrong, other)):  # GNC left either edge accepted
        w = np.ones(ii.size)
        w[wrong if now == good else good] = 0.0
        X2, w2 = repair_bridges(G, 7, ii, jj, Z, info, G.from_matrix(X), w, judged, c2,
                                start=s0, anchor=0)
        keep = good if fits == "good" else wrong
        assert w2[keep] == 1.0 and w2[good + wrong - keep] == 0.0
        np.testing.assert_allclose(np.asarray(X2.matrix()), X0, atol=1e-9)
        # without the start a tie is left alone
        X3, w3 = repair_bridges(G, 7, ii, jj, Z, info, G.from_matrix(X), w, judged, c2)
        np.testing.assert_array_equal(w3, w)
        np.testing.assert_allclose(np.asarray(X3.matrix()), X, atol=1e-12)


def test_repair_bridges_anchor_in_the_piece_stays():
    """The anchor vertex alone on one side (one good and two wrong edges, a wrong one
    accepted): the rest moves, the anchor does not."""
    G = SE2
    rng = np.random.default_rng(7)
    n = 6
    T = np.asarray(G.from_rotation_translation(SO2.random(n, rng=rng),
                                               rng.uniform(-5, 5, (n, 2))).matrix())
    # 1-5: a cycle with chords; 0-1 good; 0-3 and 0-4 wrong
    ii = np.array([1, 2, 3, 4, 1, 2, 0, 0, 0])
    jj = np.array([2, 3, 4, 5, 5, 5, 1, 3, 4])
    Zm = np.linalg.inv(T[ii]) @ T[jj]
    Zm[7:] = np.asarray(G.from_rotation_translation(SO2.random(2, rng=rng),
                                                    rng.uniform(-10, 10, (2, 2))).matrix())
    Z = G.from_matrix(Zm)
    info = np.tile(np.eye(3) / SIGMA ** 2, (ii.size, 1, 1))
    # GNC's answer: the rest placed so that 0-3 fits, 0-1 and 0-4 rejected
    D = T[0] @ Zm[7] @ np.linalg.inv(T[3])
    X = T.copy()
    X[1:] = D @ T[1:]
    w = np.ones(ii.size)
    w[[6, 8]] = 0.0
    judged = np.zeros(ii.size, dtype=bool)
    judged[6:] = True
    s0 = np.full(ii.size, 1e4)
    s0[6] = 0.0  # the start fits the good edge (e.g. odometry)
    s0[:6] = 0.0
    X2, w2 = repair_bridges(G, n, ii, jj, Z, info, G.from_matrix(X), w, judged, 11.34,
                            start=s0, anchor=0)
    assert w2[6:].tolist() == [1.0, 0.0, 0.0]
    np.testing.assert_allclose(np.asarray(X2.matrix()), T, atol=1e-9)  # the truth, anchor kept


def test_merge_components_joins_along_the_edge_that_fits_the_start():
    """A component with two cut edges that disagree (one good, one wrong; no vote): it is
    placed along the one with the smaller start residual."""
    G = SE2
    T, ii, jj, Zm, piece, good, wrong, D = _tie_graph(G, 4)
    Z = G.from_matrix(Zm)
    info = np.tile(np.eye(3) / SIGMA ** 2, (ii.size, 1, 1))
    base = np.ones(ii.size, dtype=bool)
    base[[good, wrong]] = False
    Xoff = T.copy()
    Xoff[piece] = np.asarray(G.exp([3.0, -2.0, 1.0]).matrix()) @ T[piece]  # the piece off
    for fits, expect in (("good", T), ("wrong", None)):
        s0 = np.zeros(ii.size)
        s0[wrong if fits == "good" else good] = 50.0
        X2, merged, left = merge_components(G, 7, ii, jj, Z, info, G.from_matrix(Xoff), base,
                                            11.34, 0, start=s0)
        if expect is None:
            expect = T.copy()
            expect[piece] = D @ T[piece]
        np.testing.assert_allclose(np.asarray(X2.matrix()), expect, atol=1e-9)
        assert not merged.any() and left == 0


@pytest.mark.parametrize("bad", [np.zeros(10), -np.ones(11), np.full(11, np.nan)])
def test_start_residuals_validated(bad):
    T, ii, jj, Zm, piece, good, wrong, D = _tie_graph(SE2, 0)
    Z = SE2.from_matrix(Zm)
    info = np.tile(np.eye(3), (ii.size, 1, 1))
    with pytest.raises(ValueError, match="start"):
        repair_bridges(SE2, 7, ii, jj, Z, info, SE2.from_matrix(T), np.ones(11),
                       np.ones(11, bool), 11.34, start=bad)
    with pytest.raises(ValueError, match="start"):
        merge_components(SE2, 7, ii, jj, Z, info, SE2.from_matrix(T), np.ones(11, bool),
                         11.34, 0, start=bad)
    with pytest.raises(ValueError, match="anchor"):
        repair_bridges(SE2, 7, ii, jj, Z, info, SE2.from_matrix(T), np.ones(11),
                       np.ones(11, bool), 11.34, anchor=7)
