"""``GNC(variance_factor=...)`` and ``GNC(chain=True)``, with their helpers
(``gnc_chain.chain_edges`` / ``chain_poses``, ``gnc_assemble.known_variance``) and the
command's flags.

Checked against independent computations: the spanning tree against Kruskal's algorithm
written here, the chain's poses against the odometry initialiser of ``microlie.optim.init``,
the estimated variance factor against the ratio the noise was simulated with, a given variance
factor against the same graph with its information scaled, and every answer against plain
least squares on the graph without the planted outliers.
"""

from __future__ import annotations

import io
import json
import re

import numpy as np
import pytest

from microlie import SE2, SE3
from microlie.optim import BetweenFactor, FactorGraph, Isotropic, PriorFactor
from microlie.optim.core.gnc import GNC
from microlie.optim.core.gnc_assemble import known_variance
from microlie.optim.core.gnc_chain import chain_edges, chain_poses
from microlie.optim.core.gnc_chordal import pose_graph_edges


def _snake(G, rows, cols, sigma_true, sigma_file, seed):
    """Poses on a rows x cols grid walked as a snake (odometry 0-1-2-...) with closures
    between vertically adjacent cells; measurements with noise ``sigma_true``, information
    from ``sigma_file``. Returns (truth, i, j, measurement params, sigma_file)."""
    rng = np.random.default_rng(seed)
    n = rows * cols
    cell = np.array([(r, c if r % 2 == 0 else cols - 1 - c) for r in range(rows)
                     for c in range(cols)])
    d = 2 if G is SE2 else 3
    tau = np.zeros((n, G.dof))
    tau[:, 0], tau[:, 1] = cell[:, 1], cell[:, 0]
    tau[:, d:] = rng.normal(0, 0.1, (n, G.dof - d))
    X = G.exp(tau)
    X = X[0].between(X)  # vertex 0 at the identity
    at = {tuple(c): k for k, c in enumerate(cell)}
    loops = [(at[(r, c)], at[(r + 1, c)]) for r in range(rows - 1) for c in range(cols)
             if abs(at[(r, c)] - at[(r + 1, c)]) > 1]
    ii = np.r_[np.arange(n - 1), [a for a, _ in loops]]
    jj = np.r_[np.arange(1, n), [b for _, b in loops]]
    Z = X[ii].between(X[jj]).compose(G.exp(rng.normal(0, sigma_true, (ii.size, G.dof))))
    return X, ii, jj, np.asarray(Z.params).copy(), sigma_file


def _graph(G, X0, ii, jj, Zp, sigma):
    g = FactorGraph()
    x = g.add_variables(X0, fixed=[0])
    f = g.add(BetweenFactor(x, ii, jj, G.from_params(Zp), Isotropic(G.dof, sigma)))
    return g, x, f


def _clean(G, X0, ii, jj, Zp, sigma, out):
    """Plain least squares on the graph without the edges ``out``: the reference."""
    keep = ~out
    g, x, _ = _graph(G, X0, ii[keep], jj[keep], Zp[keep], sigma)
    return np.asarray(g.optimize().values[x].params)


def _kruskal(n, ii, jj):
    """Total weight and edge count of a minimum spanning forest by ``|i - j|`` (written here
    independently: sort, union-find)."""
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    total, count = 0, 0
    for e in sorted(range(ii.size), key=lambda e: abs(int(ii[e]) - int(jj[e]))):
        a, b = find(int(ii[e])), find(int(jj[e]))
        if a != b:
            parent[a] = b
            total += abs(int(ii[e]) - int(jj[e]))
            count += 1
    return total, count


def test_chain_edges_is_a_minimum_spanning_forest_by_index_distance():
    rng = np.random.default_rng(3)
    for trial in range(30):
        n = int(rng.integers(2, 25))
        E = int(rng.integers(1, 3 * n))
        ii = rng.integers(0, n, E)
        jj = (ii + rng.integers(1, n, E)) % n  # no self-loops (a BetweenFactor refuses them)
        g = FactorGraph()
        x = g.add_variables(SE2.identity(n), fixed=[0])
        g.add(BetweenFactor(x, ii, jj, SE2.identity(E)))
        tree = chain_edges(pose_graph_edges(g.problem(gauge="none")))
        want_total, want_count = _kruskal(n, ii, jj)
        assert int(tree.sum()) == want_count, trial
        assert int(np.abs(ii[tree] - jj[tree]).sum()) == want_total, trial
        # a forest: no cycle among the chosen edges (Kruskal on them keeps them all)
        assert _kruskal(n, ii[tree], jj[tree])[1] == want_count


def test_chain_poses_equal_the_odometry_initialiser(tmp_path):
    from microlie.optim.init import odometry
    from microlie.optim.io.g2o import read_g2o

    for G, tag in ((SE2, "EDGE_SE2"), (SE3, "EDGE_SE3:QUAT")):
        X, ii, jj, Zp, _ = _snake(G, 3, 5, 0.05, 0.05, seed=1)
        Z = G.from_params(Zp)
        lines = []
        for k in range(ii.size):  # closures first and odometry stored backwards: the tree
            e = (k + 14) % ii.size  # must still pick the consecutive edges
            a, b, z = int(ii[e]), int(jj[e]), Z[e]
            if e < 14:
                a, b, z = b, a, z.inverse()
            if G is SE2:
                t, th = np.asarray(z.translation()), float(np.asarray(z.log())[2])
                info = "1 0 0 1 0 1"
                lines.append(f"{tag} {a} {b} {float(t[0])!r} {float(t[1])!r} {th!r} {info}")
            else:
                t = np.asarray(z.translation())
                q = np.asarray(z.rotation().params)  # (x, y, z, w): g2o's order
                info = " ".join("1" if r == c else "0" for r in range(6) for c in range(r, 6))
                lines.append(f"{tag} {a} {b} " + " ".join(repr(float(v)) for v in t) + " " +
                             " ".join(repr(float(v)) for v in q) + " " + info)
        path = tmp_path / f"snake{G.__name__}.g2o"
        path.write_text("\n".join(lines) + "\n")
        pg = read_g2o(path)
        want = odometry(pg)
        fg, x = pg.to_factor_graph(want, gauge="fix")
        edges = pose_graph_edges(fg.problem())
        got = chain_poses(edges, want[edges.anchor])
        np.testing.assert_allclose(np.asarray(got.matrix()), np.asarray(want.matrix()),
                                   atol=1e-12)


def test_known_variance_matches_the_simulated_ratio():
    # noise simulated with sigma 0.01, information from sigma 0.1: v = (0.01 / 0.1)^2 = 0.01;
    # 10 x 12 snake: redundancy 3 (110 closures ...) large enough for a 20% band
    X, ii, jj, Zp, _ = _snake(SE2, 10, 12, 0.01, 0.1, seed=2)
    g, x, f = _graph(SE2, X, ii, jj, Zp, 0.1)
    v = known_variance(pose_graph_edges(g.problem()), [np.ones(ii.size, bool)], 0.99)
    assert 0.008 < v < 0.012, v
    # the same with the information right: about 1; overstated noise the other way (the
    # information claims less noise than there is) is clipped to 1
    every = [np.ones(ii.size, bool)]
    g, x, f = _graph(SE2, X, ii, jj, Zp, 0.01)
    assert 0.8 < known_variance(pose_graph_edges(g.problem()), every, 0.99) <= 1.0
    g, x, f = _graph(SE2, X, ii, jj, Zp, 0.001)
    assert known_variance(pose_graph_edges(g.problem()), every, 0.99) == 1.0
    # one closure 0.5 m off among them: the plain estimate (variance_factor at the same poses)
    # is inflated; the trimmed one stays within the band
    from microlie.optim.core.gnc_assemble import _pose_known, variance_factor

    Zp2 = Zp.copy()
    k = ii.size - 7
    Zp2[k] = np.asarray(SE2.from_params(Zp[k]).compose(SE2.exp([0.5, 0.0, 0.0])).params)
    g, x, f = _graph(SE2, X, ii, jj, Zp2, 0.1)
    e = pose_graph_edges(g.problem())
    kn = np.ones(ii.size, bool)
    plain = variance_factor(SE2, e.n, e.ii, e.jj, e.Z, e.info,
                            _pose_known(SE2, e.n, e.ii, e.jj, e.Z, e.info, kn, e.anchor), kn)
    assert plain > 0.015
    assert 0.008 < known_variance(e, every, 0.99) < 0.012


def _planted(G, seed=4, rows=4, cols=6, sigma_true=0.01, sigma_file=0.1, n_bad=3,
             shift=None):
    """The snake with ``n_bad`` closures replaced by wild ones (or, with ``shift``, by the
    true relative pose moved by ``shift`` in x: an outlier within the file's noise)."""
    rng = np.random.default_rng(seed)
    X, ii, jj, Zp, sf = _snake(G, rows, cols, sigma_true, sigma_file, seed)
    n = rows * cols
    out = np.zeros(ii.size, dtype=bool)
    out[rng.choice(np.arange(n - 1, ii.size), n_bad, replace=False)] = True
    d = 2 if G is SE2 else 3
    if shift is None:
        wild = np.concatenate([rng.uniform(-5, 5, (n_bad, d)),
                               rng.uniform(-2, 2, (n_bad, G.dof - d))], axis=1)
        Zp[out] = np.asarray(G.exp(wild).params)
    else:
        true = X[ii[out]].between(X[jj[out]])
        Zp[out] = np.asarray(true.compose(G.exp(np.tile(np.r_[shift, np.zeros(G.dof - 1)],
                                                        (n_bad, 1)))).params)
    return X, ii, jj, Zp, sf, out


@pytest.mark.parametrize("G", [SE2, SE3])
def test_a_given_variance_factor_is_the_information_scaled(G):
    X, ii, jj, Zp, sf, out = _planted(G)
    v = 0.04
    g, x, f = _graph(G, X, ii, jj, Zp, sf)
    res = g.optimize(robust=GNC("tls", variance_factor=v, chain=False), verbose=False)
    h, y, _ = _graph(G, X, ii, jj, Zp, sf * np.sqrt(v))  # the covariances times v
    ref = h.optimize(robust=GNC("tls", variance_factor=1.0, chain=False), verbose=False)
    np.testing.assert_array_equal(res.inliers[0], ref.inliers[0])
    np.testing.assert_allclose(np.asarray(res.values[x].params),  # LM's tolerances
                               np.asarray(ref.values[y].params), atol=1e-7)
    # costs in the graph's own units: the scaled graph's costs divided by 1 / v
    assert res.final_cost == pytest.approx(ref.final_cost * v, rel=1e-9)
    assert res.final_robust_cost == pytest.approx(ref.final_robust_cost * v, rel=1e-9)
    assert "variance factor 0.04 (given)" in res.message
    np.testing.assert_array_equal(res.inliers[0], ~out)


def test_estimated_variance_factor_rejects_an_outlier_within_the_files_noise():
    # a closure 0.2 m off: 20 true sigmas, 2 of the file's: accepted under the file's
    # information, rejected once the variance factor (0.01 simulated) is estimated (with the
    # family-wise quantile of the default, or 0.99)
    X, ii, jj, Zp, sf, out = _planted(SE2, seed=5, rows=8, cols=10, n_bad=1, shift=0.2)
    g, x, f = _graph(SE2, X, ii, jj, Zp, sf)
    plain = g.optimize(robust=GNC("tls", variance_factor=1.0, chain=False), verbose=False)
    assert plain.inliers[0][out].all()  # the problem: the file's noise lets it in
    want = _clean(SE2, X, ii, jj, Zp, sf, out)
    for opts in ({}, {"variance_factor": "estimate", "quantile": 0.99, "chain": False}):
        g, x, f = _graph(SE2, X, ii, jj, Zp, sf)
        res = g.optimize(robust=GNC("tls", **opts), verbose=False)
        np.testing.assert_array_equal(res.inliers[0], ~out)
        np.testing.assert_allclose(np.asarray(res.values[x].params), want, atol=1e-8)
        v = float(re.search(r"variance factor ([0-9.e-]+) \(estimated from (\d+)",
                            res.message).group(1))
        assert 0.004 < v < 0.025, v  # 0.01 simulated, small redundancy


def _tail_scene():
    """A rigid snake body (vertices 0-17) and a tail 18-23 hanging on it by the odometry
    edge 17-18 alone, plus one wrong closure 20 -> 2 across that cut. Rejecting 17-18 and
    accepting the closure (the tail moved rigidly) ties exactly with the truth."""
    X, ii, jj, Zp, sf = _snake(SE2, 3, 6, 0.001, 0.01, seed=6)
    n0 = 18
    rng = np.random.default_rng(7)
    steps = SE2.exp(np.c_[np.ones(6), rng.normal(0, 0.3, (6, 2))])
    tail = [X[n0 - 1]]
    for k in range(6):
        tail.append(tail[-1].compose(steps[k]))
    Xt = SE2.from_params(np.r_[np.asarray(X.params), np.asarray([np.asarray(t.params)
                                                                   for t in tail[1:]])])
    ti = np.arange(n0 - 1, n0 + 5)
    tj = ti + 1
    Zt = Xt[ti].between(Xt[tj])
    wrong = SE2.from_xy_theta([3.0], [-2.0], [0.7])
    ii2 = np.r_[ii, ti, [20]]
    jj2 = np.r_[jj, tj, [2]]
    Zp2 = np.r_[Zp, np.asarray(Zt.params), np.asarray(wrong.params)]
    out = np.zeros(ii2.size, dtype=bool)
    out[-1] = True
    bridge = ii.size  # the edge 17-18
    return Xt, ii2, jj2, Zp2, sf, out, bridge


def test_chain_breaks_the_tie_for_the_odometry_from_any_start():
    from microlie.optim.core.gnc_ties import swap_witness

    Xt, ii, jj, Zp, sf, out, bridge = _tail_scene()
    Z = SE2.from_params(Zp)
    swapped = swap_witness(Xt, ii, jj, Z, np.arange(18, 24), ii.size - 1, fixed=0)
    want = _clean(SE2, Xt, ii, jj, Zp, sf, out)
    for start in (Xt, swapped):  # the truth, and the start that fits the wrong closure
        g, x, f = _graph(SE2, start, ii, jj, Zp, sf)
        res = g.optimize(robust=GNC("tls", chain=True), verbose=False)
        np.testing.assert_array_equal(res.inliers[0], ~out)
        np.testing.assert_allclose(np.asarray(res.values[x].params), want, atol=1e-8)
        assert "chain hypothesis: " in res.message
        assert res.ties  # still reported: the data alone cannot decide
    # without the chain the start decides: from the swapped start the wrong closure holds
    g, x, f = _graph(SE2, swapped, ii, jj, Zp, sf)
    res = g.optimize(robust=GNC("tls", chain=False), verbose=False)
    assert res.inliers[0][-1] and not res.inliers[0][bridge]


@pytest.mark.parametrize("G", [SE2, SE3])
def test_chain_hypothesis_loses_against_a_wrong_odometry_edge(G):
    X, ii, jj, Zp, sf, out = _planted(G, seed=8, rows=4, cols=6, n_bad=1)
    d = 2 if G is SE2 else 3
    k = 9  # an odometry edge 9-10, made wild: the tree must not be trusted
    Zp[k] = np.asarray(G.exp(np.r_[[2.5, -1.5], np.zeros(d - 2), [0.8],
                                   np.zeros(G.dof - d - 1)]).params)
    out[k] = True
    g, x, f = _graph(G, X, ii, jj, Zp, sf)
    res = g.optimize(robust=GNC("tls", chain=True), verbose=False)
    np.testing.assert_array_equal(res.inliers[0], ~out)
    np.testing.assert_allclose(np.asarray(res.values[x].params),
                               _clean(G, X, ii, jj, Zp, sf, out), atol=1e-8)
    assert "kept the answer that broke ties by the chain" in res.message


def test_bad_options_are_refused():
    for bad in (0, -1.0, float("nan"), float("inf"), "yes", True):
        with pytest.raises(ValueError, match="variance_factor"):
            GNC(variance_factor=bad)
    for bad in (1, "yes"):
        with pytest.raises(ValueError, match="chain must be True, False or None"):
            GNC(chain=bad)
    with pytest.raises(ValueError, match="chain=True needs first='cycles'"):
        _graph(SE2, *_planted(SE2)[:5])[0].optimize(robust=GNC("tls", first="values",
                                                                chain=True))
    X, ii, jj, Zp, sf, out = _planted(SE2)
    g, x, f = _graph(SE2, X, ii, jj, Zp, sf)
    with pytest.raises(ValueError, match="variance_factor='estimate' comes from"):
        g.optimize(robust=GNC("tls", first="values", variance_factor="estimate"))
    h = FactorGraph()  # not a pose graph: priors only
    y = h.add_variables(SE2.identity(1))
    h.add(PriorFactor(y, [0, 0], SE2.identity(2)))
    with pytest.raises(ValueError, match="chain=True needs a pose graph"):
        h.optimize(robust=GNC("tls", first="cycles", chain=True))


def test_command_flags_reach_the_options(tmp_path):
    import argparse

    from microlie.optim.command import register, run

    X, ii, jj, Zp, sf, out = _planted(SE2, seed=9)
    Z = SE2.from_params(Zp)
    info = 1.0 / sf ** 2
    lines = [f"VERTEX_SE2 {k} 0 0 0" for k in range(X.batch_shape[0])]
    for e in range(ii.size):
        t, th = np.asarray(Z[e].translation()), float(np.asarray(Z[e].log())[2])
        lines.append(f"EDGE_SE2 {ii[e]} {jj[e]} {float(t[0])!r} {float(t[1])!r} {th!r} {info} "
                     f"0 0 {info} 0 {info}")
    path = tmp_path / "planted.g2o"
    path.write_text("\n".join(lines) + "\n")
    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    outs = io.StringIO()
    args = parser.parse_args(["optimize", str(path), "--robust", "gnc-tls", "--json",
                              "--init", "chordal", "--gnc-chain",
                              "--gnc-variance-factor", "estimate"])
    assert run(args, outs, io.StringIO()) == 0
    rep = json.loads(outs.getvalue())["gnc"]
    assert rep["options"]["chain"] is True and rep["options"]["variance_factor"] == "estimate"
    assert rep["outlier_edges"] == np.flatnonzero(out).tolist()
    args = parser.parse_args(["optimize", str(path), "--robust", "gnc-tls", "--json",
                              "--gnc-variance-factor", "0.5"])
    outs = io.StringIO()
    assert run(args, outs, io.StringIO()) == 0
    assert json.loads(outs.getvalue())["gnc"]["options"]["variance_factor"] == 0.5
    for bad, match in ((["--gnc-chain"], "applies to --robust"),
                       (["--robust", "gnc-gm", "--gnc-chain"], "cycle marking only"),
                       (["--robust", "gnc-tls", "--gnc-first", "values",
                         "--gnc-variance-factor", "estimate"], "cycle marking only")):
        with pytest.raises(ValueError, match=match):
            run(parser.parse_args(["optimize", str(path), *bad]), io.StringIO(),
                io.StringIO())
    with pytest.raises(SystemExit):
        parser.parse_args(["optimize", str(path), "--gnc-variance-factor", "-2"])
