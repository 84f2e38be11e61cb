"""Graduated non-convexity (microlie.optim.core.gnc).

Small synthetic pose graphs with known outliers: GNC finds them (precision and recall 1) and
ends at the least-squares optimum of the inliers alone (solved independently, on a graph built
without the outliers); the weights are the minimisers of the paper's Black-Rangarajan outlier
processes (checked by scalar minimisation); thresholds are chi-square quantiles (scipy, and the
closed form for two degrees of freedom); known inliers keep weight 1; bad options raise.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from scipy.stats import chi2

from microlie import SE2, SE3
from microlie.optim import BetweenFactor, FactorGraph, GemanMcClure, Isotropic, PriorFactor
from microlie.optim.core.gnc import (
    GNC,
    gm_weights,
    initial_mu,
    inlier_thresholds,
    make_gnc,
    tls_weights,
)


def _loop_graph(G, n=40, n_loops=30, n_bad=6, seed=0, sigma=0.01):
    """A noisy trajectory with odometry and loop closures; ``n_bad`` loop closures replaced
    by wild measurements. Returns (edges i, j, Z, outlier mask, odometry mask, truth)."""
    rng = np.random.default_rng(seed)
    tau = np.zeros((n, G.dof))
    d = 2 if G is SE2 else 3
    tau[:, :d] = rng.uniform(-1.0, 1.0, (n, d))
    tau[:, d:] = rng.uniform(-0.5, 0.5, (n, G.dof - d))
    X = G.exp(tau)
    ii = list(range(n - 1))
    jj = list(range(1, n))
    while len(ii) < n - 1 + n_loops:
        a, b = sorted(rng.choice(n, 2, replace=False))
        if b - a > 1:
            ii.append(int(a))
            jj.append(int(b))
    ii, jj = np.array(ii), np.array(jj)
    Z = X[ii].between(X[jj]).compose(G.exp(rng.normal(0, sigma, (ii.size, G.dof))))
    out = np.zeros(ii.size, bool)
    bad = rng.choice(np.arange(n - 1, ii.size), n_bad, replace=False)
    out[bad] = True
    wild = np.zeros((n_bad, G.dof))
    wild[:, :d] = rng.uniform(-5, 5, (n_bad, d))
    wild[:, d:] = rng.uniform(-2.5, 2.5, (n_bad, G.dof - d))
    Zp = np.asarray(Z.params).copy()
    Zp[bad] = np.asarray(G.exp(wild).params)
    odo = np.arange(ii.size) < n - 1
    return ii, jj, G.from_params(Zp), out, odo, X


def _graph(G, ii, jj, Z, X0, sigma=0.01, rows=None):
    g = FactorGraph()
    x = g.add_variables(X0, fixed=[0])
    sel = np.arange(ii.size) if rows is None else rows
    f = g.add(BetweenFactor(x, ii[sel], jj[sel], Z[sel], Isotropic(G.dof, sigma)))
    return g, x, f


def _odometry(G, ii, jj, Z, X0, n):
    params = [np.asarray(X0[0].params)]
    cur = X0[0]
    for k in range(n - 1):
        cur = cur.compose(Z[k])
        params.append(np.asarray(cur.params))
    return G.from_params(np.stack(params))


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("surrogate", ["tls", "gm"])
@pytest.mark.parametrize("seed", [0, 1])
def test_gnc_finds_the_outliers_and_the_inlier_optimum(G, surrogate, seed):
    ii, jj, Z, out, odo, truth = _loop_graph(G, seed=seed)
    X0 = _odometry(G, ii, jj, Z, truth, 40)
    g, x, f = _graph(G, ii, jj, Z, X0)
    q = 0.9999  # an inlier beyond the 0.99 quantile is a 1-in-100 event among 70 edges
    res = g.optimize(robust=GNC(surrogate, quantile=q))
    assert res.converged, res.message
    pred_in = res.inliers[0]
    assert np.array_equal(pred_in, ~out)  # precision and recall 1
    # the least-squares optimum of the inliers alone, solved on its own graph
    g2, x2, _ = _graph(G, ii, jj, Z, X0, rows=np.flatnonzero(~out))
    ref = g2.optimize(rel_tol=1e-12, abs_tol=1e-14).values[x2]
    err = np.abs(np.asarray(res.values[x].translation()) - np.asarray(ref.translation())).max()
    if surrogate == "tls":  # TLS ends with binary weights: least squares on the inliers
        assert np.array_equal(res.weights[0], (~out).astype(float))
        assert err < 1e-6
    else:  # GM: the minimum of the Geman-McClure cost near the inlier optimum, found by
        # the engine's IRLS with the GemanMcClure loss (scale c) from the inlier optimum
        c = float(np.sqrt(chi2.ppf(q, G.dof)))
        g3, x3, _ = _graph(G, ii, jj, Z, ref)
        g3.factors[0].loss = GemanMcClure(c)
        gm = g3.optimize(rel_tol=1e-12, abs_tol=1e-14).values[x3]
        err = np.abs(np.asarray(res.values[x].translation()) -
                     np.asarray(gm.translation())).max()
        assert err < 1e-3  # GNC stops on a 1e-5 relative change of the weighted cost
        assert res.weights[0][out].max() < 1e-3


def test_gnc_with_least_squares_first_and_known_inliers():
    ii, jj, Z, out, odo, truth = _loop_graph(SE2, seed=3)
    X0 = _odometry(SE2, ii, jj, Z, truth, 40)
    g, x, f = _graph(SE2, ii, jj, Z, X0)
    res = g.optimize(robust=GNC("tls", known_inliers=[(f, odo)], first="least-squares"))
    assert np.array_equal(res.inliers[0], ~out)
    assert np.all(res.weights[0][odo] == 1.0)


def test_known_inliers_keep_weight_one_even_when_wrong():
    # six priors on one pose, the last one wild; marked known, it keeps weight 1
    g = FactorGraph()
    x = g.add_variables(SE2.identity(1))
    z = SE2.exp(np.array([[0.0, 0, 0]] * 5 + [[9.0, 0, 0]]))
    f = g.add(PriorFactor(x, [0] * 6, z, Isotropic(3, 0.1)))
    res = g.optimize(robust=GNC("tls", known_inliers=[(f, [5])]))
    assert res.weights[0][5] == 1.0 and res.inliers[0][5]
    res2 = g.optimize(robust=GNC("gm", known_inliers=[(f, np.arange(6) == 5)]))
    assert res2.weights[0][5] == 1.0
    # the whole batch known: plain least squares (the mean of the six, 1.5 in x)
    res3 = g.optimize(robust=GNC("tls", known_inliers=[f]))
    assert np.allclose(res3.values[x].log(), [[1.5, 0.0, 0.0]], atol=1e-9)
    assert res3.weights[0].tolist() == [1.0] * 6 and res3.outer_iterations == 0


def _tls_dual(w, r2, c2, mu):  # the paper's TLS outlier process, Black-Rangarajan duality
    return w * r2 + mu * (1.0 - w) * c2 / (mu + w)


def _gm_dual(w, r2, c2, mu):  # the GM outlier process
    return w * r2 + mu * c2 * (np.sqrt(w) - 1.0) ** 2


@pytest.mark.parametrize("mu", [1e-3, 0.3, 1.0, 7.0, 1e4])
def test_weights_minimise_the_outlier_processes(mu):
    c2 = 11.34
    r2 = np.concatenate([np.geomspace(1e-4, 1e5, 60), [c2 * mu / (mu + 1), c2 * (mu + 1) / mu]])
    for fn, dual, m in ((tls_weights, _tls_dual, mu), (gm_weights, _gm_dual, 1.0 + mu)):
        w = fn(r2, c2, m)
        for rk, wk in zip(r2, w, strict=True):
            def obj(v, rk=rk, dual=dual, m=m):
                return dual(v, rk, c2, m)

            opt = minimize_scalar(obj, bounds=(0.0, 1.0), method="bounded",
                                  options={"xatol": 1e-12})
            best = min((opt.x, 0.0, 1.0), key=obj)
            assert dual(wk, rk, c2, m) <= dual(best, rk, c2, m) + 1e-9 * max(1.0, rk)
            assert abs(wk - best) < 1e-4 or abs(dual(wk, rk, c2, m) - dual(best, rk, c2, m)) \
                < 1e-12 * max(1.0, rk)


def test_first_weights_follow_the_closed_form():
    # one outer iteration from the start values: weights = formula at the start residuals
    ii, jj, Z, out, odo, truth = _loop_graph(SE2, seed=5)
    X0 = _odometry(SE2, ii, jj, Z, truth, 40)
    g, x, f = _graph(SE2, ii, jj, Z, X0)
    for surrogate, fn in (("tls", tls_weights), ("gm", gm_weights)):
        res = g.optimize(robust=GNC(surrogate, max_iter=1, first="values"))
        # residuals at the start computed directly: log(Z^-1 X_i^-1 X_j) / sigma
        r = Z.inverse().compose(X0[ii].between(X0[jj])).log() / 0.01
        s = (r ** 2).sum(1)
        c2 = chi2.ppf(0.99, 3)
        mu = c2 / (2 * s.max() - c2) if surrogate == "tls" else max(1.0, 2 * s.max() / c2)
        assert np.allclose(res.weights[0], fn(s, c2, mu), rtol=1e-9, atol=1e-12)
        assert res.outer_iterations == 1


def test_thresholds_are_chi_square_quantiles():
    g = FactorGraph()
    a = g.add_variables(np.zeros((2, 2)))
    b = g.add_variables(SE3.identity(2))
    f2 = g.add(PriorFactor(a, [0, 1], np.zeros((2, 2))))
    f6 = g.add(PriorFactor(b, [0, 1], SE3.identity(2)))
    for q in (0.5, 0.9, 0.99, 0.999):
        c2 = inlier_thresholds([f2, f6], q)
        assert c2[0] == pytest.approx(-2.0 * np.log1p(-q), rel=1e-12)  # chi2(2): closed form
        assert c2[1] == pytest.approx(chi2.ppf(q, 6), rel=1e-12)
    assert initial_mu("tls", np.array([1.0, 2.0]), np.array([11.0, 11.0])) is None


def test_bad_options_raise():
    for kw in ({"surrogate": "huber"}, {"quantile": 0.0}, {"quantile": 1.0},
               {"quantile": 1.5}, {"mu_step": 1.0}, {"max_iter": 0}, {"max_iter": 2.5},
               {"cost_tol": -1.0}, {"weights_tol": 0.5}, {"first": "lm"},
               {"known_inliers": "odometry"}):
        with pytest.raises(ValueError):
            GNC(**kw)
    with pytest.raises(ValueError, match="robust must be"):
        make_gnc("huber")
    g = FactorGraph()
    x = g.add_variables(SE2.identity(2))
    f = g.add(PriorFactor(x, [0, 1], SE2.identity(2)))
    other = PriorFactor(FactorGraph().add_variables(SE2.identity(1)), 0, SE2.identity())
    for ki in ([other], [(f, [2])], [(f, np.ones(3, bool))], [(f, [0.5])], [3]):
        with pytest.raises(ValueError, match="known_inliers"):
            g.optimize(robust=GNC(known_inliers=ki))
    g2 = FactorGraph()
    y = g2.add_variables(SE2.identity(1))
    g2.add(PriorFactor(y, 0, SE2.identity(), loss="huber:1"))
    with pytest.raises(ValueError, match="replaces robust losses"):
        g2.optimize(robust="gnc-tls")
    assert g2.factors[0].loss is not None  # left as it was


def _g2o_with_outliers(path):
    ii, jj, Z, out, odo, truth = _loop_graph(SE2, seed=2)
    X0 = _odometry(SE2, ii, jj, Z, truth, 40)
    p, z = np.asarray(X0.params).tolist(), np.asarray(Z.params).tolist()
    th = np.arctan2(np.asarray(X0.params)[:, 3], np.asarray(X0.params)[:, 2]).tolist()
    tz = np.arctan2(np.asarray(Z.params)[:, 3], np.asarray(Z.params)[:, 2]).tolist()
    lines = [f"VERTEX_SE2 {k} {p[k][0]!r} {p[k][1]!r} {th[k]!r}" for k in range(40)]
    lines += [f"EDGE_SE2 {a} {b} {z[e][0]!r} {z[e][1]!r} {tz[e]!r} 10000 0 0 10000 0 10000"
              for e, (a, b) in enumerate(zip(ii, jj, strict=True))]
    path.write_text("\n".join(lines) + "\n")
    return np.flatnonzero(out).tolist()


def test_command_reports_the_outlier_edges(tmp_path):
    import argparse
    import io
    import json

    from microlie.optim.command import register, run

    path = tmp_path / "out.g2o"
    planted = _g2o_with_outliers(path)
    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    for extra in ([], ["--known-inliers", "odometry"], ["--gnc-quantile", "0.9999"]):
        out = io.StringIO()
        args = parser.parse_args(["optimize", str(path), "--robust", "gnc-tls", "--json",
                                  *extra])
        assert run(args, out, io.StringIO()) == 0
        rep = json.loads(out.getvalue())
        assert rep["gnc"]["outlier_edges"] == planted
        # the default: 1 - 1e-6 with the cycle marking's estimated variance factor, 0.99
        # with the odometry known (the file's information)
        assert rep["gnc"]["quantile"] == (0.9999 if "--gnc-quantile" in extra else
                                          0.99 if "--known-inliers" in extra else 1 - 1e-6)
    for bad in (["--known-inliers", "odometry"], ["--gnc-quantile", "0.9"],
                ["--gnc-first", "chordal"],
                ["--robust", "gnc-huber"], ["--robust", "gnc-tls", "--gnc-quantile", "1.5"]):
        with pytest.raises(ValueError):
            run(parser.parse_args(["optimize", str(path), *bad]), io.StringIO(),
                io.StringIO())


def test_docs_section_prints_what_the_page_shows(capsys):
    """The section "Outliers: graduated non-convexity" of docs/optim.md runs on its own."""
    import re
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "optim.md").read_text()
    sec = page[page.index("## Outliers: graduated non-convexity"):]
    sec = sec[:sec.index("\n## ")]
    (kind, code), (kind2, text) = re.findall(r"```(python|text)\n(.*?)```", sec, flags=re.S)
    assert (kind, kind2) == ("python", "text")
    exec(compile(code, "docs/optim.md", "exec"), {})
    assert capsys.readouterr().out == text


@pytest.mark.parametrize("backend", ["cholesky", "dense"])
def test_symbolic_analysis_once_for_all_outer_iterations(backend, monkeypatch):
    from microlie.optim import make_solver

    ii, jj, Z, out, odo, truth = _loop_graph(SE2, seed=4)
    X0 = _odometry(SE2, ii, jj, Z, truth, 40)
    g, x, f = _graph(SE2, ii, jj, Z, X0)
    cls = type(make_solver(backend, 3, 3))
    calls = []
    orig = cls.analyse
    monkeypatch.setattr(cls, "analyse", lambda self, *a, **k: (calls.append(1),
                                                               orig(self, *a, **k))[1])
    res = g.optimize(robust=GNC("tls", first="values"), linear_solver=backend)
    assert res.outer_iterations > 5 and len(calls) == 1


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("seed", [1, 2])  # seed 0 with SE3 and 15 bad: one inlier rejected
@pytest.mark.parametrize("n_bad", [15, 21])  # 50% and 70% of the 30 loop closures
def test_chordal_first_stage_with_most_loop_closures_wrong(G, seed, n_bad):
    # odometry as known inliers, first="chordal" (GNC-TLS on the chordal relaxation first):
    # every wrong loop closure found, the answer the least-squares optimum of the inliers
    # solved on a graph built without the outliers
    ii, jj, Z, out, odo, truth = _loop_graph(G, seed=seed, n_bad=n_bad)
    X0 = _odometry(G, ii, jj, Z, truth, 40)
    g, x, f = _graph(G, ii, jj, Z, X0)
    res = g.optimize(robust=GNC("tls", known_inliers=[(f, odo)], quantile=0.9999,
                                first="chordal"))
    assert res.converged, res.message
    assert np.array_equal(res.inliers[0], ~out)
    assert np.array_equal(res.weights[0], (~out).astype(float))
    g2, x2, _ = _graph(G, ii, jj, Z, X0, rows=np.flatnonzero(~out))
    ref = g2.optimize(rel_tol=1e-12, abs_tol=1e-14).values[x2]
    err = np.abs(np.asarray(res.values[x].matrix()) - np.asarray(ref.matrix())).max()
    assert err < 1e-6


@pytest.mark.parametrize("G", [SE2, SE3])
def test_chordal_stage_without_outliers_is_the_chordal_initialisation(G):
    # all weights stay 1: the relaxation equals microlie.optim.init.chordal (written apart)
    from microlie.optim.core.gnc_chordal import chordal_gnc
    from microlie.optim.init import chordal
    from microlie.optim.io.pose_graph import PoseGraph

    ii, jj, Z, out, odo, truth = _loop_graph(G, n_bad=0, seed=4)
    rng = np.random.default_rng(4)
    info = np.zeros((ii.size, G.dof, G.dof))
    d = 2 if G is SE2 else 3
    info[:, :d, :d] = np.diag(rng.uniform(50, 200, d))  # block-diagonal, anisotropic
    info[:, d:, d:] = np.eye(G.dof - d) * rng.uniform(100, 400, (ii.size, 1, 1))
    pg = PoseGraph(G, ids=np.arange(40), poses=None, i=ii, j=jj, measurements=Z,
                   information=info)
    X, w, _ = chordal_gnc(G, 40, ii, jj, Z, info, 0, G.identity(), np.zeros(ii.size, bool))
    assert np.all(w == 1.0)
    assert np.abs(np.asarray(X.matrix()) - np.asarray(chordal(pg).matrix())).max() < 1e-8


def test_chordal_first_needs_a_pose_graph():
    g = FactorGraph()
    x = g.add_variables(SE2.identity(2), fixed=[0])
    y = g.add_variables(SE2.identity(1))
    g.add(BetweenFactor(x, [0], [1], SE2.identity(1)))
    g.add(PriorFactor(y, 0, SE2.identity()))
    with pytest.raises(ValueError, match="first='chordal' needs a pose graph"):
        g.optimize(robust=GNC("tls", first="chordal"))
    with pytest.raises(ValueError, match="GNC first must be one of"):
        GNC("tls", first="odometry")
    g2 = FactorGraph()
    z = g2.add_variables(SE2.identity(2), fixed=[0])
    g2.add(BetweenFactor(z, [0], [1], SE2.identity(1)))
    with pytest.raises(ValueError, match="is a TLS stage"):
        g2.optimize(robust=GNC("gm", first="chordal"))
    assert g2.optimize(robust=GNC("tls", first="chordal")).converged


def test_command_cycle_length_and_moves(tmp_path):
    """``--gnc-cycle-length`` and ``--gnc-moves`` reach ``GNC(cycle_length=, moves=)``: the
    planted outliers are found, and the flags are refused where no cycle marking runs
    (``--gnc-first`` other than cycles or auto, or auto with gnc-gm)."""
    import argparse
    import io
    import json

    from microlie.optim.command import register, run

    path = tmp_path / "out.g2o"
    planted = _g2o_with_outliers(path)
    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    out = io.StringIO()
    args = parser.parse_args(["optimize", str(path), "--robust", "gnc-tls", "--json",
                              "--gnc-first", "cycles", "--gnc-cycle-length", "7",
                              "--gnc-moves"])
    assert run(args, out, io.StringIO()) == 0
    assert json.loads(out.getvalue())["gnc"]["outlier_edges"] == planted
    out = io.StringIO()  # the search and the assembly on the same file find the same edges
    args = parser.parse_args(["optimize", str(path), "--robust", "gnc-tls", "--json",
                              "--gnc-search", "--gnc-assemble"])
    assert (args.gnc_search, args.gnc_assemble) == (True, True)
    assert run(args, out, io.StringIO()) == 0
    assert json.loads(out.getvalue())["gnc"]["outlier_edges"] == planted
    for bad, match in ((["--robust", "gnc-gm", "--gnc-moves"], "cycle marking only"),
                       (["--robust", "gnc-gm", "--gnc-search"], "cycle marking only"),
                       (["--robust", "gnc-tls", "--gnc-first", "values",
                         "--gnc-assemble"], "cycle marking only"),
                       (["--gnc-search"], "applies to --robust"),
                       (["--robust", "gnc-tls", "--gnc-first", "chordal",
                         "--gnc-cycle-length", "7"], "cycle marking only"),
                       (["--robust", "gnc-tls", "--gnc-first", "values",
                         "--no-gnc-moves"], "cycle marking only"),
                       (["--robust", "gnc-tls", "--gnc-first", "cycles",
                         "--gnc-cycle-length", "12"], "cycle_length"),
                       (["--gnc-moves"], "applies to --robust")):
        with pytest.raises(ValueError, match=match):
            run(parser.parse_args(["optimize", str(path), *bad]), io.StringIO(),
                io.StringIO())
