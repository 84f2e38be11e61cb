"""The certified pose-graph solver (microlie.optim.certify) against independent computations:
SE-Sync's objective evaluated edge by edge with translations by dense least squares, the
certificate matrix built densely and its eigenvalues by LAPACK, noise-free graphs (optimum 0),
a constructed local minimum (a ring wound once around the circle), SE-Sync's published optima."""

from __future__ import annotations

import argparse
import io
import json

import numpy as np
import pytest
from conftest import data_file

from microlie import SE2, SE3
from microlie.optim.certify import (
    SESyncProblem,
    certified_pose_graph,
    certify_poses,
    isotropic_weights,
    min_eigenvalue,
)
from microlie.optim.io.pose_graph import PoseGraph


def _graph(G, X, i, j, rng, noise=0.0, info=None, vertices=None):
    Z = X[i].between(X[j])
    if noise:
        Z = Z.compose(G.exp(noise * rng.standard_normal((len(i), G.dof))))
    if info is None:
        info = np.tile(np.eye(G.dof), (len(i), 1, 1))
    return PoseGraph(G, ids=np.arange(len(X)), poses=vertices, i=np.asarray(i),
                     j=np.asarray(j), measurements=Z, information=info)


def _random_graph(G, n, extra, rng, noise=0.0, anisotropic=False):
    X = G.exp(rng.standard_normal((n, G.dof)) * 2.0)
    i = list(range(n - 1))
    j = list(range(1, n))
    while len(i) < n - 1 + extra:
        a, b = rng.choice(n, 2, replace=False)
        i.append(int(a))
        j.append(int(b))
    info = None
    if anisotropic:
        A = rng.standard_normal((len(i), G.dof, G.dof))
        info = A @ np.swapaxes(A, 1, 2) + G.dof * np.eye(G.dof)
    return _graph(G, X, i, j, rng, noise, info), X


def _F(graph, R, t):
    """SE-Sync's objective edge by edge (R: (n, d, d) any matrices, t: (n, d))."""
    kappa, tau = isotropic_weights(graph)
    ii, jj = graph.edge_index()
    Rz = np.asarray(graph.measurements.rotation().matrix())
    tz = np.asarray(graph.measurements.translation())
    total = 0.0
    for e in range(len(ii)):
        a, b = ii[e], jj[e]
        total += kappa[e] * np.sum((R[b] - R[a] @ Rz[e]) ** 2)
        total += tau[e] * np.sum((t[b] - t[a] - R[a] @ tz[e]) ** 2)
    return total


def _best_translations(graph, R):
    """argmin_t F(R, t) with t_0 = 0 by dense weighted least squares."""
    kappa, tau = isotropic_weights(graph)
    ii, jj = graph.edge_index()
    tz = np.asarray(graph.measurements.translation())
    n, d = graph.num_vertices, graph.dim
    rows, rhs = [], []
    for e in range(len(ii)):
        for c in range(d):
            row = np.zeros(n * d)
            row[jj[e] * d + c] += 1.0
            row[ii[e] * d + c] -= 1.0
            w = np.sqrt(tau[e])
            rows.append(w * row[d:])
            rhs.append(w * (R[ii[e]] @ tz[e])[c])
    sol = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0]
    return np.vstack([np.zeros((1, d)), sol.reshape(-1, d)])


@pytest.mark.parametrize("G", [SE2, SE3])
def test_q_is_the_translation_marginalised_objective(G):
    rng = np.random.default_rng(3)
    g, _ = _random_graph(G, 7, 6, rng, noise=0.3, anisotropic=True)
    p = SESyncProblem(g)
    Q = p.dense_Q()
    assert np.allclose(Q, Q.T, atol=1e-12 * np.abs(Q).max())
    for _ in range(3):  # any d x dn matrix, rotations or not
        R = rng.standard_normal((g.num_vertices, g.dim, g.dim))
        Y = np.swapaxes(R, 1, 2).reshape(-1, g.dim)
        t = _best_translations(g, R)
        assert np.isclose(np.trace(Y.T @ Q @ Y), _F(g, R, t), rtol=1e-10)
        assert np.allclose(p.translations(R), t, atol=1e-9 * max(1.0, np.abs(t).max()))


def test_isotropic_weights_follow_se_sync():
    rng = np.random.default_rng(0)
    for G, d in ((SE2, 2), (SE3, 3)):
        g, _ = _random_graph(G, 4, 2, rng, anisotropic=True)
        kappa, tau = isotropic_weights(g)
        for e in range(g.num_edges):
            Om = g.information[e]
            assert np.isclose(tau[e], d / np.trace(np.linalg.inv(Om[:d, :d])))
            want = Om[2, 2] if d == 2 else 3.0 / (2.0 * np.trace(np.linalg.inv(Om[3:, 3:])))
            assert np.isclose(kappa[e], want)


def _stiefel(rng, n, d, r):
    A = rng.standard_normal((n, r, d))
    Qf, _ = np.linalg.qr(A)
    return np.swapaxes(Qf, 1, 2).reshape(-1, r)


@pytest.mark.parametrize("G,r", [(SE2, 2), (SE2, 4), (SE3, 3), (SE3, 5)])
def test_min_eigenvalue_against_the_dense_certificate_matrix(G, r):
    rng = np.random.default_rng(5)
    g, _ = _random_graph(G, 6, 5, rng, noise=0.5)
    p = SESyncProblem(g)
    d, n = g.dim, g.num_vertices
    Y = _stiefel(rng, n, d, r)
    Q = p.dense_Q()
    QY = Q @ Y
    S = Q.copy()
    for k in range(n):
        B = QY[k * d:(k + 1) * d] @ Y[k * d:(k + 1) * d].T
        S[k * d:(k + 1) * d, k * d:(k + 1) * d] -= 0.5 * (B + B.T)
    w, V = np.linalg.eigh(S)
    lam, v, ok = min_eigenvalue(p, Y, 1e-8)
    assert np.isclose(lam, w[0], rtol=1e-8, atol=1e-9 * np.abs(w).max())
    assert np.isclose(abs(v @ V[:, 0]), 1.0, atol=1e-6)
    assert ok == (w[0] >= -1e-8)


@pytest.mark.parametrize("G", [SE2, SE3])
def test_noise_free_graph_is_solved_to_zero_and_certified(G):
    rng = np.random.default_rng(11)
    g, X = _random_graph(G, 12, 10, rng)
    bad = G.exp(rng.standard_normal((12, G.dof)) * 3.0)  # a far start
    for start in (None, bad):
        res = certified_pose_graph(g, start)
        assert res.certified and abs(res.min_eigenvalue) <= res.tolerance
        assert abs(res.objective) < 1e-9 and abs(res.cost) < 1e-9
        # the anchor is the identity (no vertices): poses relative to vertex 0
        want = X[0:1].inverse().compose(X)
        assert np.allclose(res.poses.matrix(), want.matrix(), atol=1e-7)


def _wound_ring(G, n):
    """n poses at one place, identity measurements around a ring, and the start with vertex
    k turned by 2 pi k / n: a critical point of F (by symmetry) with F > 0 = the optimum."""
    ang = 2 * np.pi * np.arange(n) / n
    if G is SE2:
        X = SE2.from_xy_theta(0.0, 0.0, ang)
        wound = SE2.from_xy_theta(0.0, 0.0, ang)
        X = SE2.identity((n,))
    else:
        tau = np.zeros((n, 6))
        tau[:, 5] = ang
        wound = SE3.exp(tau)
        X = SE3.identity((n,))
    i = np.arange(n)
    j = (i + 1) % n
    return _graph(G, X, i, j, None, vertices=wound), wound


@pytest.mark.parametrize("G", [SE2, SE3])
def test_wound_ring_is_not_certified_and_the_staircase_leaves_it(G):
    n = 8
    g, wound = _wound_ring(G, n)
    c = certify_poses(g, wound)
    kappa = isotropic_weights(g)[0][0]
    # at the wound ring: F = n kappa ||R(2 pi / n) - I||_F^2 = n kappa 4 (1 - cos(2 pi / n))
    assert np.isclose(c.objective, n * kappa * 4 * (1 - np.cos(2 * np.pi / n)), rtol=1e-9)
    assert c.moved < 1e-9 and not c.certified
    # dense check of the eigenvalue that refutes it
    p = SESyncProblem(g)
    Y = np.swapaxes(np.asarray(wound.rotation().matrix()), 1, 2).reshape(-1, g.dim)
    Q = p.dense_Q()
    S = Q - _blockdiag_lambda(Q, Y, g.dim)
    assert np.isclose(c.min_eigenvalue, np.linalg.eigvalsh(S)[0], rtol=1e-8)
    assert c.min_eigenvalue < -c.tolerance
    res = certified_pose_graph(g, wound)
    assert res.certified and res.rank > g.dim and abs(res.objective) < 1e-9
    assert abs(res.cost) < 1e-9


def _blockdiag_lambda(Q, Y, d):
    out = np.zeros_like(Q)
    QY = Q @ Y
    for k in range(Y.shape[0] // d):
        s = slice(k * d, (k + 1) * d)
        B = QY[s] @ Y[s].T
        out[s, s] = 0.5 * (B + B.T)
    return out


def test_certified_optimum_is_no_worse_than_local_solutions():
    """Noisy SE3 graph: the certified F is at most F at many local solutions from random
    starts, and its lower bound equals it."""
    rng = np.random.default_rng(2)
    g, _ = _random_graph(SE3, 10, 12, rng, noise=0.6)
    res = certified_pose_graph(g)
    assert res.certified and np.isclose(res.lower_bound, res.objective, rtol=1e-9)
    for _ in range(5):
        start = SE3.exp(rng.standard_normal((10, 6)) * 3.0)
        c = certify_poses(g, start)  # a critical point near the random start
        assert c.objective >= res.objective * (1 - 1e-9)


def test_bad_input_is_refused():
    rng = np.random.default_rng(0)
    g, X = _random_graph(SE2, 5, 2, rng)
    with pytest.raises(ValueError, match="initial must hold 5 poses"):
        certified_pose_graph(g, X[:3])
    with pytest.raises(ValueError, match="max_rank"):
        certified_pose_graph(g, max_rank=1)
    with pytest.raises(ValueError, match="tolerance must be > 0"):
        min_eigenvalue(SESyncProblem(g), np.tile(np.eye(2), (5, 1)), 0.0)
    with pytest.raises(ValueError, match="PoseGraph or the path"):
        certified_pose_graph(42)  # type: ignore[arg-type]
    split = PoseGraph(SE2, ids=np.arange(4), poses=None, i=np.array([0, 2]),
                      j=np.array([1, 3]), measurements=SE2.identity((2,)),
                      information=np.tile(np.eye(3), (2, 1, 1)))
    with pytest.raises(ValueError, match="do not join all vertices"):
        certified_pose_graph(split, SE2.identity((4,)))


@pytest.mark.parametrize("name,published,digits", [
    ("sphere2500.g2o", 1.687e3, 0.5e0), ("parking-garage.g2o", 1.263e0, 0.5e-3),
    ("CSAIL.g2o", 3.170e1, 0.5e-2), ("tinyGrid3D.g2o", None, None)])
def test_se_sync_published_optima(name, published, digits):
    from microlie.optim.io.g2o import read_g2o

    g = read_g2o(data_file(f"pose_graph/{name}"))
    res = certified_pose_graph(g)
    assert res.certified
    if published is not None:  # Rosen et al. IJRR 2019, Table 2 ("SE-Sync optimal F")
        assert abs(res.objective - published) <= digits
    # the F of the returned poses, edge by edge
    R = np.asarray(res.poses.rotation().matrix())
    t = np.asarray(res.poses.translation())
    assert np.isclose(_F(g, R, t), res.objective, rtol=1e-9)


def test_command_says_a_local_minimum_is_not_certified(tmp_path):
    from microlie.optim.command import register
    from microlie.optim.io.g2o import write_g2o

    g, wound = _wound_ring(SE2, 8)
    path = tmp_path / "ring.g2o"
    write_g2o(path, g, wound)
    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())

    def run(*extra):
        out = io.StringIO()
        args = parser.parse_args(["optimize", str(path), "--json", "-q", *extra])
        assert args.func(args, out, io.StringIO()) == 0
        return json.loads(out.getvalue())

    local = run("--init", "file", "--certify")
    assert local["final_cost"] > 1.0 and not local["certificate"]["certified"]
    best = run("--init", "certified", "--certify")
    assert best["certified_init"]["certified"] and best["certificate"]["certified"]
    assert best["final_cost"] < 1e-12
    text = io.StringIO()
    args = parser.parse_args(["optimize", str(path), "-q", "--init", "file", "--certify"])
    args.func(args, text, io.StringIO())
    assert "NOT certified" in text.getvalue()


def test_command_refuses_certify_for_bundle_adjustment(tmp_path):
    from microlie.optim.command import register

    path = tmp_path / "one.txt"  # BAL: 1 camera, 1 point, 1 observation
    path.write_text("1 1 1\n0 0 1.0 2.0\n" + "\n".join(["0.0"] * 6 + ["500.0", "0.0", "0.0"])
                    + "\n0.0\n0.0\n-5.0\n")
    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    for extra in (["--certify"], ["--init", "certified"]):
        args = parser.parse_args(["optimize", str(path), "-q", "--format", "bal", *extra])
        with pytest.raises(ValueError, match="apply to pose graphs"):
            args.func(args, io.StringIO(), io.StringIO())


def test_bignoise_from_the_file_vertices_is_a_local_minimum_and_the_staircase_leaves_it():
    """sphere_bignoise_vertex3: the critical point of F next to the file's vertices is not
    certified; the staircase from there (rank 4) reaches a certified optimum whose value equals
    the relaxation's lower bound."""
    from microlie.optim.io.g2o import read_g2o

    g = read_g2o(data_file("pose_graph/sphere_bignoise_vertex3.g2o"))
    local = certify_poses(g, g.poses)
    assert not local.certified and local.min_eigenvalue < -local.tolerance
    again = certified_pose_graph(g, g.poses)
    assert again.certified and again.rank > 3 and again.objective < local.objective
    assert np.isclose(again.lower_bound, again.objective, rtol=1e-9)
    R = np.asarray(again.poses.rotation().matrix())
    assert np.isclose(_F(g, R, np.asarray(again.poses.translation())), again.objective,
                      rtol=1e-9)
