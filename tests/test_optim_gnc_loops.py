"""Longer cycles and rigid moves after GNC (microlie.optim.core.gnc_loops).

The cycle marking is checked against an independent criterion on noise-free graphs (an edge
is on a consistent cycle of at most ``L`` edges exactly when the other good edges join its
ends by a path of at most ``L - 1`` steps: breadth-first distances from scipy) and against
``gnc_cycles.consistent_edges`` (a separate implementation) on noisy ones for ``L <= 5``;
the moves against constructed truth (a piece put where a wrong edge holds it goes back, and
the TLS objective, computed here from the residuals, falls); GNC with
``cycle_length=8, moves=True`` on a grid pose graph with wrong loop closures against the
least-squares optimum of the graph without them.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from microlie import SE2, SE3
from microlie.optim import BetweenFactor, FactorGraph, Isotropic
from microlie.optim.core.gnc import GNC
from microlie.optim.core.gnc_chordal import chordal_gnc, pose_graph_edges
from microlie.optim.core.gnc_cycles import consistent_edges
from microlie.optim.core.gnc_loops import (
    cycle_consistent_edges,
    mark_loops,
    move_pieces,
    move_regions,
)


def _ladder(G, length=12, gap=2, n_bad=6, seed=0, sigma=0.0):
    """Two rails of ``length`` poses (unit steps) joined by rungs every ``gap`` poses (so
    the shortest cycles have ``2 gap + 2`` edges), and ``n_bad`` wild edges between random
    vertices. Returns (ii, jj, Z, bad mask, n, true poses)."""
    rng = np.random.default_rng(seed)
    n = 2 * length
    d = 2 if G is SE2 else 3
    tau = np.zeros((n, G.dof))
    tau[:, 0] = np.r_[np.arange(length), np.arange(length)]
    tau[:, 1] = np.r_[np.zeros(length), np.full(length, 2.0)]
    tau[:, d:] = rng.uniform(-0.3, 0.3, (n, G.dof - d))
    X = G.exp(tau)
    ii = list(range(length - 1)) + list(range(length, n - 1))
    jj = list(range(1, length)) + list(range(length + 1, n))
    for k in range(0, length, gap):
        ii.append(k)
        jj.append(length + k)
    good = len(ii)
    a = rng.integers(0, n, n_bad)
    b = (a + rng.integers(1, n - 1, n_bad)) % n
    ii, jj = np.array(ii + a.tolist()), np.array(jj + b.tolist())
    Z = X[ii].between(X[jj])
    P = np.asarray(Z.params).copy()
    wild = G.exp(np.concatenate([rng.uniform(-5, 5, (n_bad, d)),
                                 rng.uniform(-np.pi, np.pi, (n_bad, G.dof - d))], 1))
    P[good:] = np.asarray(wild.params)
    Z = G.from_params(P)
    if sigma:
        Z = Z.compose(G.exp(rng.normal(0, sigma, (ii.size, G.dof))))
    bad = np.arange(ii.size) >= good
    return ii, jj, Z, bad, n, X


def _path_truth(ii, jj, bad, n, L):
    """Good edges whose ends the other good edges join within L - 1 steps."""
    out = np.zeros(ii.size, bool)
    for e in np.flatnonzero(~bad):
        keep = ~bad & (np.arange(ii.size) != e)
        A = coo_matrix((np.ones(int(keep.sum())), (ii[keep], jj[keep])), shape=(n, n))
        dist = shortest_path(A, directed=False, unweighted=True, indices=[ii[e]])[0]
        out[e] = dist[jj[e]] <= L - 1
    return out


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("gap,L", [(1, 4), (2, 5), (2, 6), (3, 7), (3, 8), (4, 9)])
def test_cycles_match_path_lengths(G, gap, L):
    ii, jj, Z, bad, n, _ = _ladder(G, gap=gap, seed=gap + L)
    info = np.tile(np.eye(G.dof) * 1e4, (ii.size, 1, 1))
    ok = cycle_consistent_edges(G, n, ii, jj, Z, info, max_length=L)
    assert ok.tolist() == _path_truth(ii, jj, bad, n, L).tolist()
    assert not ok[bad].any()


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("L", [3, 4, 5])
def test_short_cycles_match_consistent_edges(G, L):
    for seed in range(3):
        ii, jj, Z, bad, n, _ = _ladder(G, gap=1 + seed % 2, seed=seed, sigma=0.02)
        info = np.tile(np.eye(G.dof) * 1e3, (ii.size, 1, 1))
        ours = cycle_consistent_edges(G, n, ii, jj, Z, info, max_length=L)
        ref = consistent_edges(G, n, ii, jj, Z, info, max_length=L)
        assert ours.tolist() == ref.tolist()


def test_support_two_needs_two_cycles():
    # gap 2: an inner rung lies on two 6-cycles, a rail edge or an end rung on one
    ii, jj, Z, bad, n, _ = _ladder(SE2, length=5, gap=2, n_bad=0)
    info = np.tile(np.eye(3) * 1e4, (ii.size, 1, 1))
    one = cycle_consistent_edges(SE2, n, ii, jj, Z, info, max_length=6)
    two = cycle_consistent_edges(SE2, n, ii, jj, Z, info, max_length=6, support=2)
    assert one.all()
    rung = (ii == 2) & (jj == 7)
    assert two.tolist() == rung.tolist()


def test_cycle_options_rejected():
    ii, jj, Z, _, n, _ = _ladder(SE2, n_bad=0)
    info = np.tile(np.eye(3), (ii.size, 1, 1))
    for kw, msg in (({"max_length": 10}, "max_length"), ({"max_length": 1}, "max_length"),
                    ({"quantile": 0.0}, "quantile"), ({"chunk": 0}, "chunk")):
        with pytest.raises(ValueError, match=msg):
            cycle_consistent_edges(SE2, n, ii, jj, Z, info, **kw)
    with pytest.raises(ValueError, match="one entry per edge"):
        cycle_consistent_edges(SE2, n, ii, jj[:-1], Z, info)


def test_relaxation_of_known_edges_only():
    # every edge known or rejected: one relaxation of the known edges, the rejected ones
    # (wild) without influence; noise-free known edges: the truth up to the anchor
    ii, jj, Z, bad, n, X = _ladder(SE3, gap=2, n_bad=5, seed=3)
    info = np.tile(np.eye(6) * 100.0, (ii.size, 1, 1))
    P, w, _ = chordal_gnc(SE3, n, ii, jj, Z, info, 0, X[0], ~bad, rejected=bad)
    assert w.tolist() == (~bad).astype(float).tolist()
    np.testing.assert_allclose(np.asarray(P.matrix()), np.asarray(X.matrix()), atol=1e-6)


def _graph(G, ii, jj, Z, n, sigma):
    g = FactorGraph()
    x = g.add_variables(G.identity(n), fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Isotropic(G.dof, sigma)))
    return g, x


def test_mark_loops_marks_no_wrong_edge():
    ii, jj, Z, bad, n, _ = _ladder(SE3, length=16, gap=2, n_bad=8, seed=5, sigma=0.01)
    g, _ = _graph(SE3, ii, jj, Z, n, 0.01)
    kn = mark_loops(pose_graph_edges(g.problem()), [np.zeros(ii.size, bool)], 0.99)[0]
    assert not kn[bad].any()
    assert kn[~bad].mean() > 0.9


def _tls(G, P, ii, jj, Z, info, c2, known):
    r = np.asarray(Z.inverse().compose(P[ii].between(P[jj])).log())
    s = np.einsum("ea,eab,eb->e", r, info, r)
    return 0.5 * float(np.where(known, s, np.minimum(s, c2)).sum())


def test_move_pieces_puts_a_piece_back():
    ii, jj, Z, bad, n, X = _ladder(SE2, length=10, gap=1, n_bad=0)
    # a wrong edge from vertex 0 to the far end of the top rail holds the last rung's pair
    # {9, 19} 4 m away: its known rung is the piece, its rail edges do not fit
    Zw = SE2.from_xy_theta([3.0], [6.0], [0.5])
    ii, jj = np.r_[ii, 0], np.r_[jj, 19]
    Z = SE2.from_params(np.concatenate([np.asarray(Z.params), np.asarray(Zw.params)]))
    D = X[0].compose(Zw).compose(X[19].inverse())
    P = np.asarray(X.matrix()).copy()
    P[[9, 19]] = np.asarray(D.matrix()) @ P[[9, 19]]
    known = np.zeros(ii.size, bool)
    known[:-1] = True
    known[[8, 17]] = False  # the rail edges 8-9 and 18-19 are judged
    info = np.tile(np.eye(3) * 100.0, (ii.size, 1, 1))
    c2 = 11.34
    before = _tls(SE2, SE2.from_matrix(P), ii, jj, Z, info, c2, known)
    X2, moved = move_pieces(SE2, n, ii, jj, Z, info, SE2.from_matrix(P), known, c2, 0)
    assert moved
    np.testing.assert_allclose(np.asarray(X2.matrix()), np.asarray(X.matrix()), atol=1e-9)
    after = _tls(SE2, X2, ii, jj, Z, info, c2, known)
    assert after < before - c2 / 4


@pytest.mark.parametrize("max_size", [50, 2])  # 2: the region is too large, grown instead
def test_move_regions_moves_a_chain(max_size):
    # core: the squares of columns 0-5 of a ladder known; beyond it every edge judged, and
    # the vertices 6, 7 (bottom) and 16, 17 (top) each moved where a wrong edge from vertex
    # 0 holds it
    ii, jj, Z, bad, n, X = _ladder(SE3, length=10, gap=1, n_bad=0, seed=2)
    info = np.tile(np.eye(6) * 100.0, (ii.size, 1, 1))
    left = np.array([v for v in range(n) if v % 10 <= 5])
    core = np.isin(ii, left) & np.isin(jj, left)
    moved_v = [6, 7, 16, 17]
    P = np.asarray(X.matrix()).copy()
    rng = np.random.default_rng(0)
    wrong_Z = []
    for v in moved_v:  # each put somewhere else, with a wrong edge 0 -> v that fits there
        P[v] = np.asarray(SE3.exp(rng.uniform(-3, 3, 6)).matrix()) @ P[v]
        wrong_Z.append(np.linalg.inv(P[0]) @ P[v])
    ii = np.r_[ii, [0] * 4]
    jj = np.r_[jj, moved_v]
    Z = SE3.from_params(np.concatenate([np.asarray(Z.params),
                                        np.asarray(SE3.from_matrix(np.array(wrong_Z)).params)]))
    info = np.tile(np.eye(6) * 100.0, (ii.size, 1, 1))
    known = np.r_[core, np.zeros(4, bool)]
    # the far end (8, 9, 18, 19) stays in place, judged: with 6, 7, 16, 17 one region
    # outside the core; the judged edges that fit now are the accepted ones
    c2 = 16.81
    Xs = SE3.from_matrix(P)
    r = np.asarray(Z.inverse().compose(Xs[ii].between(Xs[jj])).log())
    acc = ~known & (np.einsum("ea,eab,eb->e", r, info, r) <= c2)
    before = _tls(SE3, Xs, ii, jj, Z, info, c2, known)
    X2, moved = move_regions(SE3, n, ii, jj, Z, info, Xs, known, acc, c2, 0,
                             max_size=max_size)
    assert moved
    after = _tls(SE3, X2, ii, jj, Z, info, c2, known)
    assert after < before - c2 / 4
    np.testing.assert_allclose(np.asarray(X2.matrix())[moved_v], np.asarray(X.matrix())[moved_v],
                               atol=1e-9)
    if max_size == 2:  # without growing, a region too large is left alone
        assert not move_regions(SE3, n, ii, jj, Z, info, Xs, known, acc, c2, 0, max_size=2,
                                grow=0)[1]


def test_gnc_cycle_length_and_moves_on_a_ladder():
    for seed in range(3):
        ii, jj, Z, bad, n, _ = _ladder(SE3, length=20, gap=2, n_bad=10, seed=seed,
                                       sigma=0.01)
        g, x = _graph(SE3, ii, jj, Z, n, 0.01)
        res = g.optimize(robust=GNC("tls", first="cycles", cycle_length=8, moves=True))
        assert res.inliers[0].tolist() == (~bad).tolist()
        gc, xc = _graph(SE3, ii[~bad], jj[~bad], Z[~bad], n, 0.01)
        ref = gc.optimize()
        np.testing.assert_allclose(np.asarray(res.values[x].params),
                                   np.asarray(ref.values[xc].params), atol=1e-5)  # solver tolerance


def test_gnc_options_rejected():
    for kw, msg in (({"cycle_length": 10}, "cycle_length"), ({"cycle_length": True},
                                                              "cycle_length"),
                    ({"moves": 1}, "moves")):
        with pytest.raises(ValueError, match=msg):
            GNC("tls", first="cycles", **kw)
