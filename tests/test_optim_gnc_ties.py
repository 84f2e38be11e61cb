"""Exact ties of the TLS objective (microlie.optim.core.gnc_ties).

A loop-rich SE2 block with a chain hanging on it by one edge (a bridge of the true inlier
graph) and one wrong edge from the chain to the block: the least-squares optimum of the good
edges (the reference) and the swap witness (the chain moved rigidly so that the wrong edge
fits) have the same truncated-least-squares objective, written here from the SE2 formulas
(not through our factors), yet are metres apart. The bridge finder is checked against brute
force (remove each edge, count components with SciPy) on random multigraphs.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.stats import chi2

from microlie import SE2
from microlie.optim import BetweenFactor, FactorGraph, Isotropic, LevenbergMarquardt
from microlie.optim.core.gnc_ties import bridges, swap_witness, tie_bridges

SIGMA = 0.05


def _se2_log_residual(xi, xj, z):
    """``Log(Z^-1 X_i^-1 X_j)`` for poses given as rows ``(x, y, theta)``, by hand:
    ``theta`` the relative angle, ``rho = V(theta)^-1 t`` with
    ``V = [[sin, -(1 - cos)], [1 - cos, sin]] / theta``."""

    def mat(p):
        c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
        M = np.zeros(p.shape[:-1] + (3, 3))
        M[..., 0, 0], M[..., 0, 1], M[..., 0, 2] = c, -s, p[..., 0]
        M[..., 1, 0], M[..., 1, 1], M[..., 1, 2] = s, c, p[..., 1]
        M[..., 2, 2] = 1.0
        return M

    T = np.linalg.inv(mat(z)) @ np.linalg.inv(mat(xi)) @ mat(xj)
    th = np.arctan2(T[:, 1, 0], T[:, 0, 0])
    t = T[:, :2, 2]
    a = np.where(np.abs(th) < 1e-12, 1.0, np.sin(th) / np.where(th == 0, 1.0, th))
    b = np.where(np.abs(th) < 1e-12, th / 2, (1 - np.cos(th)) / np.where(th == 0, 1.0, th))
    det = a * a + b * b  # V = [[a, -b], [b, a]], V^-1 = [[a, b], [-b, a]] / det
    rho = np.stack([(a * t[:, 0] + b * t[:, 1]) / det, (-b * t[:, 0] + a * t[:, 1]) / det], 1)
    return np.column_stack([rho, th])


def _tls(P, ii, jj, Zp, c2):
    """``0.5 * sum min(s, c^2)``, ``s = |r|^2 / sigma^2``, poses and measurements as
    ``(x, y, theta)`` rows."""
    r = _se2_log_residual(P[ii], P[jj], Zp)
    s = np.sum(r * r, axis=1) / SIGMA**2
    return 0.5 * float(np.minimum(s, c2).sum()), s


def _xyt(X):
    return np.column_stack([np.asarray(X.translation()), np.asarray(X.angle())])


def _block_and_chain(seed=0):
    """A 3x3 grid (every horizontal, vertical and diagonal neighbour) and a 4-pose chain
    hanging on its corner 8 by the edge 8-9; edge -1 is wrong: chain end 12 to vertex 0."""
    rng = np.random.default_rng(seed)
    grid = [(r, c) for r in range(3) for c in range(3)]
    xy = np.array([(c * 2.0, r * 2.0) for r, c in grid] +
                  [(4.0 + 2.0 * k, 4.0 + 0.5 * k) for k in range(1, 5)])
    n = xy.shape[0]
    X = SE2.from_xy_theta(xy[:, 0], xy[:, 1], rng.uniform(-0.5, 0.5, n))
    ii, jj = [], []
    for a in range(9):
        for b in range(a + 1, 9):
            (ra, ca), (rb, cb) = grid[a], grid[b]
            if max(abs(ra - rb), abs(ca - cb)) == 1:
                ii.append(a)
                jj.append(b)
    ii += [8, 9, 10, 11, 12]
    jj += [9, 10, 11, 12, 0]
    ii, jj = np.array(ii), np.array(jj)
    E = ii.size
    Z = X[ii].between(X[jj]).compose(SE2.exp(rng.normal(0, SIGMA, (E, 3))))
    wrong = SE2.from_xy_theta(3.0, -2.0, 1.0)  # 12 -> 0: a random, wrong measurement
    Zp = np.array(Z.params)
    Zp[-1] = np.asarray(wrong.params)
    return X, ii, jj, SE2.from_params(Zp), n


def _optimum(X0, ii, jj, Z):
    g = FactorGraph()
    x = g.add_variables(X0, fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Isotropic(3, SIGMA)))
    res = g.optimize(solver=LevenbergMarquardt(abs_tol=0.0, rel_tol=1e-15), max_iter=200)
    return res.values[x]


def test_swap_witness_is_an_exact_tie():
    X, ii, jj, Z, n = _block_and_chain()
    E = ii.size
    good = np.arange(E) < E - 1
    ref = _optimum(X, ii[good], jj[good], Z[np.flatnonzero(good)])
    ties = tie_bridges(n, ii, jj, good)
    # the chain's four edges are the bridges; the one with the largest smaller side is 8-9
    assert [t.edge for t in ties] == [E - 5, E - 4, E - 3, E - 2]
    assert ties[0].side.tolist() == [9, 10, 11, 12]
    assert ties[0].wrong.tolist() == [E - 1]
    W = swap_witness(ref, ii, jj, Z, ties[0].side, E - 1, fixed=0)
    c2 = float(chi2.ppf(0.99, 3))
    Zx = _xyt(Z)
    t_ref, s_ref = _tls(_xyt(ref), ii, jj, Zx, c2)
    t_w, s_w = _tls(_xyt(W), ii, jj, Zx, c2)
    # the hand-written residual is the factor's (a check of the formula, not of the tie)
    r = np.asarray(ref[ii].between(ref[jj]).minus(Z))
    np.testing.assert_allclose(s_ref, np.sum(r * r, axis=1) / SIGMA**2, rtol=1e-9, atol=1e-12)
    # the reference rejects the wrong edge, fits the bridge exactly (it is a bridge);
    # the witness fits the wrong edge exactly and rejects the bridge; nothing else changes
    assert s_ref[E - 1] > c2 and s_w[E - 5] > c2
    assert s_ref[E - 5] < 1e-12 and s_w[E - 1] < 1e-12
    np.testing.assert_allclose(np.delete(s_w, [E - 5, E - 1]), np.delete(s_ref, [E - 5, E - 1]),
                               rtol=1e-9, atol=1e-12)
    assert t_w == pytest.approx(t_ref, rel=1e-9)
    assert t_ref > c2 / 2  # not trivially zero: the rejected edge and the noise
    ape = np.sqrt(np.mean(np.sum((_xyt(W)[:, :2] - _xyt(ref)[:, :2]) ** 2, axis=1)))
    assert ape > 1.0
    assert np.array_equal(_xyt(W)[:9], _xyt(ref)[:9])  # the block (and the gauge) stays


def test_swap_witness_keeps_the_fixed_vertex():
    X, ii, jj, Z, n = _block_and_chain(seed=1)
    block = np.arange(9)  # move the block instead: vertex 0 is in it, so the chain moves
    W1 = swap_witness(X, ii, jj, Z, block, ii.size - 1, fixed=0)
    W2 = swap_witness(X, ii, jj, Z, np.arange(9, n), ii.size - 1)
    np.testing.assert_allclose(np.asarray(W1.params), np.asarray(W2.params), atol=1e-12)
    with pytest.raises(ValueError, match="does not cross"):
        swap_witness(X, ii, jj, Z, [9, 10, 11, 12], 0)


def _brute_bridges(n, ii, jj):
    def ncomp(keep):
        A = coo_matrix((np.ones(keep.sum()), (ii[keep], jj[keep])), shape=(n, n))
        return connected_components(A, directed=False)[0]

    base = ncomp(np.ones(ii.size, bool))
    out = []
    for e in range(ii.size):
        keep = np.ones(ii.size, bool)
        keep[e] = False
        if ncomp(keep) > base:
            out.append(e)
    return np.array(out, dtype=np.int64)


@pytest.mark.parametrize("seed", range(40))
def test_bridges_against_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 14))
    E = int(rng.integers(0, 2 * n + 2))
    ii = rng.integers(0, n, E)
    jj = rng.integers(0, n, E)
    if E and seed % 3 == 0:  # parallel edges and self-loops on purpose
        ii = np.concatenate([ii, ii[:2], [ii[0]]])
        jj = np.concatenate([jj, jj[:2], [ii[0]]])
    if seed % 4 == 1:  # a tree plus a few extra edges: many bridges
        par = [int(rng.integers(0, v)) for v in range(1, n)]
        ii = np.concatenate([np.arange(1, n), ii[:2]]).astype(np.int64)
        jj = np.concatenate([par, jj[:2]]).astype(np.int64)
    np.testing.assert_array_equal(bridges(n, ii, jj), _brute_bridges(n, ii, jj))


@pytest.mark.parametrize("seed", range(20))
def test_tie_bridges_against_brute_force(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(2, 14))
    par = [int(rng.integers(0, v)) for v in range(1, n)]
    k = int(rng.integers(0, n))
    ii = np.concatenate([np.arange(1, n), rng.integers(0, n, k)]).astype(np.int64)
    jj = np.concatenate([par, rng.integers(0, n, k)]).astype(np.int64)
    E = ii.size
    good = rng.random(E) < 0.7
    judged = rng.random(E) < 0.8
    got = {t.edge: (t.side.tolist(), t.wrong.tolist())
           for t in tie_bridges(n, ii, jj, good, judged)}
    gi = np.flatnonzero(good)
    want = {}
    for e in gi[_brute_bridges(n, ii[gi], jj[gi])]:
        keep = gi[gi != e]
        A = coo_matrix((np.ones(keep.size), (ii[keep], jj[keep])), shape=(n, n))
        lab = connected_components(A, directed=False)[1]
        la, lb = lab[ii[e]], lab[jj[e]]
        na, nb = np.sum(lab == la), np.sum(lab == lb)
        wrong = np.flatnonzero(~good & (((lab[ii] == la) & (lab[jj] == lb)) |
                                        ((lab[ii] == lb) & (lab[jj] == la))))
        if not judged[e] or wrong.size == 0:
            continue
        sides = [np.flatnonzero(lab == la).tolist(), np.flatnonzero(lab == lb).tolist()]
        want[int(e)] = (sides, wrong.tolist(), min(na, nb))
    assert set(got) == set(want)
    for e, (side, wrong) in got.items():
        sides, w, m = want[e]
        assert side in sides and len(side) == m
        assert wrong == w


def test_bad_input():
    with pytest.raises(ValueError, match="same length|one length"):
        bridges(3, [0, 1], [1])
    with pytest.raises(ValueError, match="lie in"):
        bridges(2, [0], [2])
    with pytest.raises(ValueError, match="integer"):
        bridges(2, [0.0], [1.0])
    with pytest.raises(ValueError, match="good"):
        tie_bridges(3, [0, 1], [1, 2], [True])
    with pytest.raises(ValueError, match="out of range"):
        swap_witness(SE2.identity(2), [0], [1], SE2.identity(1), [1], 3)


@pytest.mark.parametrize("first", ["values", "cycles"])
def test_gnc_reports_the_ties_of_its_answer(first):
    """GNC-TLS without known inliers on the block-and-chain scene: ``result.ties`` names the
    accepted edge that holds the chain and the rejected one that could hold it instead, and
    swapping them (the chain moved rigidly) gives the same TLS objective, by hand."""
    from microlie.optim.core.gnc import GNC

    X, ii, jj, Z, n = _block_and_chain()
    E = ii.size
    g = FactorGraph()
    x = g.add_variables(X, fixed=[0])
    g.add(BetweenFactor(x, ii, jj, Z, Isotropic(3, SIGMA)))
    res = g.optimize(robust=GNC("tls", first=first), verbose=False)
    assert res.ties, res.message
    assert "not unique" in res.message
    t = res.ties[0]
    assert t.held_by[0] == 0 and t.alternatives and all(b == 0 for b, _ in t.alternatives)
    held, alt = t.held_by[1], t.alternatives[0][1]
    assert {held, alt} <= set(range(E - 5, E)) and E - 1 in {held, alt}  # chain or wrong edge
    assert res.inliers[0][held] and not res.inliers[0][alt]
    assert set(t.poses.tolist()) <= set(range(9, n))  # a part of the chain
    ans = res.values[x]
    c2 = float(chi2.ppf(0.99, 3))
    W = swap_witness(ans, ii, jj, Z, t.poses, alt, fixed=0)
    t_ans, s_ans = _tls(_xyt(ans), ii, jj, _xyt(Z), c2)
    t_w, s_w = _tls(_xyt(W), ii, jj, _xyt(Z), c2)
    assert s_ans[held] < 1e-10 and s_w[alt] < 1e-10 and s_w[held] > c2
    assert t_w == pytest.approx(t_ans, rel=1e-9)


def test_gnc_ties_empty_with_known_inliers_and_none_for_gm():
    from microlie.optim.core.gnc import GNC

    X, ii, jj, Z, n = _block_and_chain()
    E = ii.size
    g = FactorGraph()
    x = g.add_variables(X, fixed=[0])
    f = g.add(BetweenFactor(x, ii, jj, Z, Isotropic(3, SIGMA)))
    res = g.optimize(robust=GNC("tls", known_inliers=[(f, np.arange(E - 1))]), verbose=False)
    assert res.ties == [] and "not unique" not in res.message
    assert not res.inliers[0][E - 1]
    assert g.optimize(robust=GNC("gm"), verbose=False).ties is None


def test_command_reports_the_ties(tmp_path):
    import argparse
    import io
    import json

    from microlie.optim.command import register, run

    X, ii, jj, Z, n = _block_and_chain()
    E = ii.size
    P, Q = _xyt(X).tolist(), _xyt(Z).tolist()
    info = f"{1 / SIGMA**2!r} 0 0 {1 / SIGMA**2!r} 0 {1 / SIGMA**2!r}"
    lines = [f"VERTEX_SE2 {k} {P[k][0]!r} {P[k][1]!r} {P[k][2]!r}" for k in range(n)]
    lines += [f"EDGE_SE2 {a} {b} {Q[e][0]!r} {Q[e][1]!r} {Q[e][2]!r} {info}"
              for e, (a, b) in enumerate(zip(ii, jj, strict=True))]
    path = tmp_path / "tie.g2o"
    path.write_text("\n".join(lines) + "\n")
    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    reps = []
    for extra in ([], ["--known-inliers", "odometry"]):  # odometry: the chain's edges known
        out = io.StringIO()
        args = parser.parse_args(["optimize", str(path), "--robust", "gnc-tls", "--json",
                                  *extra])
        assert run(args, out, io.StringIO()) == 0
        reps.append(json.loads(out.getvalue())["gnc"])
    ties = reps[0]["ties"]
    assert ties and ties[0]["poses"] >= 1
    assert {ties[0]["held_by"], *ties[0]["alternatives"]} <= set(range(E - 5, E))
    assert reps[1]["ties"] == [] and reps[1]["outlier_edges"] == [E - 1]
