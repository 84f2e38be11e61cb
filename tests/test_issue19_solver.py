"""Regression tests of issue 19, items 5, 6, 11 and 12 (solver outcomes, bundle-adjustment
covariances, marginals with every linear backend, rank-deficient systems and the gauge)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from conftest import data_file

from microlie import SE2
from microlie.cli import main
from microlie.optim import (
    BetweenFactor,
    FactorGraph,
    Isotropic,
    PriorFactor,
    SingularSystemError,
    available_solvers,
)
from microlie.optim.g2o import read_g2o
from microlie.optim.init import chordal

BACKENDS = ["auto", *available_solvers()]


def _se2_loop_graph(n: int = 120, seed: int = 0) -> tuple[FactorGraph, object, list]:
    """An SE2 chain of ``n`` poses with loop closures and a prior on pose 0 (3n unknowns);
    also the edges ``(i, j, Z, sigma)`` for an independent residual."""
    rng = np.random.default_rng(seed)
    g = FactorGraph()
    x = g.add_variables(SE2.exp(0.3 * rng.standard_normal((n, 3))), name="x")
    g.add(PriorFactor(x, 0, SE2.identity(), Isotropic(3, 0.1)))
    i = np.r_[np.arange(n - 1), rng.integers(0, n - 10, n // 4)]
    j = np.r_[np.arange(1, n), i[n - 1:] + rng.integers(5, 10, n // 4)]
    Z = SE2.exp(0.2 * rng.standard_normal((i.size, 3)))
    g.add(BetweenFactor(x, i, j, Z, Isotropic(3, 0.5)))
    return g, x, [(i, j, Z, 0.5)]


def _whitened_residuals(X: SE2, edges: list) -> np.ndarray:
    """All whitened residuals, written out from the definitions (prior ``Log(X_0)`` with sigma
    0.1, edges ``Log(Z^-1 X_i^-1 X_j)``)."""
    out = [np.asarray(X[0:1].log()).ravel() / 0.1]
    for i, j, Z, s in edges:
        out.append(np.asarray(Z.inverse().compose(X[i].inverse()).compose(X[j]).log()).ravel()
                   / s)
    return np.concatenate(out)


def _fd_information(X: SE2, edges: list, h: float = 1e-6) -> np.ndarray:
    """``J^T J`` with ``J`` by central differences in the right tangent ``X Exp(delta)``."""
    n = len(X)
    P = np.asarray(X.params)
    cols = []
    for k in range(n):
        for a in range(3):
            d = np.zeros(3)
            d[a] = h
            Pp, Pm = P.copy(), P.copy()
            Pp[k] = np.asarray(SE2(P[k]).compose(SE2.exp(d)).params)
            Pm[k] = np.asarray(SE2(P[k]).compose(SE2.exp(-d)).params)
            cols.append((_whitened_residuals(SE2(Pp), edges)
                         - _whitened_residuals(SE2(Pm), edges)) / (2 * h))
    J = np.stack(cols, axis=1)
    return J.T @ J


# ----------------------------------------------------------------------------- item 11
@pytest.mark.parametrize("backend", BACKENDS)
def test_issue19_item11_marginals_match_the_dense_inverse(backend):
    # 360 unknowns in 2-D: "auto" picks qdldl when it is installed (its solve took no matrix
    # right-hand side: "Length of b does not match size of A")
    g, x, edges = _se2_loop_graph()
    X = g.initial_values()[x]
    cov = np.linalg.inv(_fd_information(X, edges))
    m = g.marginals(None, x, linear_solver=backend)
    ref = np.stack([cov[3 * k:3 * k + 3, 3 * k:3 * k + 3] for k in range(len(X))])
    np.testing.assert_allclose(m.cov, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())
    J = g.marginal_covariance(None, [(x, 5), (x, 77)], linear_solver=backend)
    sel = np.r_[15:18, 231:234]
    np.testing.assert_allclose(J, cov[np.ix_(sel, sel)], rtol=1e-6,
                               atol=1e-9 * np.abs(cov).max())


# ----------------------------------------------------------------------------- item 12
@pytest.mark.parametrize("backend", BACKENDS)
def test_issue19_item12_rank_deficient_gauss_newton_raises_on_every_backend(backend):
    # no prior, no gauge check: H is singular (3 zero eigenvalues) whatever the backend; qdldl
    # took its rounding-noise pivots (-2e-15 of their diagonal) and returned a step
    g, x, _ = _se2_loop_graph()
    g.factors.pop(0)
    g._changed()
    H = g.problem("none").matrix(g.problem("none").linearize(
        [v.initial for v in g.variables]).data).toarray()
    w = np.linalg.eigvalsh(H)
    assert np.sum(w < 1e-10 * w[-1]) == 3  # the gauge, independently of every backend
    with pytest.raises(SingularSystemError, match=r"rank deficient .*first at x\[\d+\]"):
        g.optimize(solver="gn", gauge="none", linear_solver=backend)


@pytest.mark.parametrize("backend", [b for b in available_solvers() if b != "dense"])
def test_issue19_item12_gauge_free_m3500_is_singular_on_every_backend(backend):
    # M3500 without its gauge: every backend factorised it (pivots 4e-14 .. 1e-11 of their
    # diagonal, positive), so GN took a step along the gauge
    pg = read_g2o(data_file("pose_graph/input_M3500_g2o.g2o"))
    fg, _ = pg.to_factor_graph(gauge="none")
    with pytest.raises(SingularSystemError, match="rank deficient"):
        fg.optimize(solver="gn", gauge="none", linear_solver=backend, max_iter=1)


DISCONNECTED = ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1.1 0 0\nVERTEX_SE2 7 5 0 0\n"
                "VERTEX_SE2 9 6.2 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
                "EDGE_SE2 7 9 1 0 0 1 0 0 1 0 1\n")


def test_issue19_item12_chordal_names_the_vertices_not_connected_to_the_anchor(tmp_path):
    path = tmp_path / "two_parts.g2o"
    path.write_text(DISCONNECTED)
    with pytest.raises(ValueError, match=r"2 vertices are not connected .* vertex 0: 7, 9;"):
        chordal(read_g2o(path))


def _optimize(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main(["optimize", *argv], out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def test_issue19_item12_optimize_takes_the_gauge_its_error_suggests(tmp_path):
    path = tmp_path / "two_parts.g2o"
    path.write_text(DISCONNECTED)
    code, _, err = _optimize(str(path))
    assert code == 1
    assert "vertex 7" in err and "--gauge fix_first" in err and "gauge='fix_first'" not in err
    code, out, err = _optimize(str(path), "--gauge", "fix_first", "--json",
                               "-o", str(tmp_path / "out.g2o"))
    assert code == 0, err
    r = json.loads(out)
    assert r["converged"] is True and r["gauge"] == "fix_first" and r["gauge_fixed"] == [7]
    X = read_g2o(tmp_path / "out.g2o").poses
    # vertex 7 held at its start (5, 0, 0); vertex 9 one unit edge ahead of it, vertex 1 of 0
    np.testing.assert_allclose(np.asarray(X.translation()), [[0, 0], [1, 0], [5, 0], [6, 0]],
                               atol=1e-9)
