"""Initial guesses: odometry chains against matrix products, chordal initialisation against
exact graphs and against a dense least-squares solve written from the definition."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file
from scipy.spatial.transform import Rotation

from microlie import SE2, SE3
from microlie.optim.init import chordal, from_file, initialize, odometry
from microlie.optim.io.g2o import read_g2o
from microlie.optim.io.pose_graph import PoseGraph


def _matrices_from_g2o(path) -> tuple[dict, list]:
    """Edges of a g2o file as (i, j, 4x4 or 3x3 matrix), parsed without microlie."""
    edges = []
    for line in open(path):
        t = line.split()
        if t and t[0] == "EDGE_SE2":
            x, y, th = map(float, t[3:6])
            M = np.array([[np.cos(th), -np.sin(th), x], [np.sin(th), np.cos(th), y], [0, 0, 1]])
            edges.append((int(t[1]), int(t[2]), M))
        elif t and t[0] == "EDGE_SE3:QUAT":
            v = list(map(float, t[3:10]))
            M = np.eye(4)
            M[:3, :3] = Rotation.from_quat(v[3:7]).as_matrix()
            M[:3, 3] = v[:3]
            edges.append((int(t[1]), int(t[2]), M))
    return edges


@pytest.mark.parametrize("rel", ["pose_graph/kitti_00.g2o", "pose_graph/sphere2500.g2o"])
def test_odometry_chain_equals_matrix_products(rel):
    path = data_file(rel)
    g = read_g2o(path)
    X = np.asarray((g.poses[0:1] if g.poses is not None else g.group.identity((1,)))
                   .matrix())[0]
    step = {i: M for i, j, M in _matrices_from_g2o(path) if j == i + 1}
    expect = [X]
    for k in range(g.num_vertices - 1):
        X = X @ step[k]
        expect.append(X)
    got = np.asarray(odometry(g).matrix())
    np.testing.assert_allclose(got, np.array(expect), atol=1e-7 * np.abs(expect).max())


def _graph(G, X, edges, noise=0.0, rng=None, info=None) -> PoseGraph:
    i = np.array([e[0] for e in edges])
    j = np.array([e[1] for e in edges])
    Z = X[i].between(X[j])
    if noise:
        Z = Z.plus(noise * rng.standard_normal((len(edges), G.dof)))
    if info is None:
        info = np.tile(np.eye(G.dof), (len(edges), 1, 1))
    return PoseGraph(G, ids=np.arange(len(X)), poses=None, i=i, j=j, measurements=Z,
                     information=info)


EDGES = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (0, 3), (2, 6), (6, 1), (4, 0)]


def test_odometry_inverts_reversed_edges_and_names_a_missing_link():
    rng = np.random.default_rng(1)
    X = SE3.random(4, rng=rng)
    X = X[0:1].inverse().compose(X)  # X[0] = identity
    g = _graph(SE3, X, [(0, 1), (2, 1), (2, 3)])
    np.testing.assert_allclose(np.asarray(odometry(g).matrix()), np.asarray(X.matrix()),
                               atol=1e-12)
    g = _graph(SE3, X, [(0, 1), (2, 3), (0, 2)])
    with pytest.raises(ValueError, match="no edge between vertices 1 and 2"):
        odometry(g)


@pytest.mark.parametrize("G", [SE2, SE3])
def test_chordal_recovers_an_exact_graph(G):
    rng = np.random.default_rng(2)
    X = G.random(7, rng=rng)
    X = X[0:1].inverse().compose(X)
    info = np.array([np.diag(rng.uniform(1, 50, G.dof)) for _ in EDGES])
    g = _graph(G, X, EDGES, info=info)
    Y = chordal(g)
    np.testing.assert_allclose(np.asarray(Y.matrix()), np.asarray(X.matrix()), atol=1e-9)
    assert g.cost(Y) == pytest.approx(0.0, abs=1e-16)


def _dense_chordal(g: PoseGraph) -> np.ndarray:
    """Chordal initialisation from its definition with dense matrices: vec(R) unknowns,
    Kronecker products, numpy.linalg.lstsq, SVD projection; anchor vertex 0."""
    d, n = g.dim, g.num_vertices
    Zm = np.asarray(g.measurements.matrix())
    rows, rhs = [], []
    for e in range(g.num_edges):
        i, j, Rz = g.i[e], g.j[e], Zm[e, :d, :d]
        Om = g.information[e, d:, d:]
        s = np.sqrt(Om.shape[0] / np.trace(np.linalg.inv(Om)))
        # vec(R_i Rz - R_j) = (Rz^T kron I) vec(R_i) - vec(R_j)  (column-major vec)
        A = np.zeros((d * d, d * d * n))
        A[:, i * d * d:(i + 1) * d * d] = np.kron(Rz.T, np.eye(d))
        A[:, j * d * d:(j + 1) * d * d] -= np.eye(d * d)
        rows.append(s * A)
        rhs.append(np.zeros(d * d))
    A, b = np.vstack(rows), np.concatenate(rhs)
    b = b - A[:, :d * d] @ np.eye(d).ravel(order="F")
    x = np.linalg.lstsq(A[:, d * d:], b, rcond=None)[0]
    Rs = [np.eye(d)] + [x[k * d * d:(k + 1) * d * d].reshape(d, d, order="F")
                        for k in range(n - 1)]
    R = []
    for M in Rs:
        U, _, Vt = np.linalg.svd(M)
        R.append(U @ np.diag([1.0] * (d - 1) + [np.linalg.det(U @ Vt)]) @ Vt)
    rows, rhs = [], []
    for e in range(g.num_edges):
        i, j, tz = g.i[e], g.j[e], Zm[e, :d, d]
        L = np.linalg.cholesky(g.information[e, :d, :d]).T  # L^T L = Omega_t
        A = np.zeros((d, d * n))
        A[:, i * d:(i + 1) * d] -= R[i].T
        A[:, j * d:(j + 1) * d] += R[i].T
        rows.append(L @ A)
        rhs.append(L @ tz)
    t = np.linalg.lstsq(np.vstack(rows)[:, d:], np.concatenate(rhs), rcond=None)[0]
    T = np.tile(np.eye(d + 1), (n, 1, 1))
    for k in range(n):
        T[k, :d, :d] = R[k]
        T[k, :d, d] = 0.0 if k == 0 else t[(k - 1) * d:k * d]
    return T


@pytest.mark.parametrize("G", [SE2, SE3])
def test_chordal_equals_dense_least_squares_from_the_definition(G):
    rng = np.random.default_rng(3)
    X = G.random(7, rng=rng)
    info = []
    for _ in EDGES:
        L = rng.standard_normal((G.dof, G.dof)) + 3 * np.eye(G.dof)
        info.append(L @ L.T)
    g = _graph(G, X, EDGES, noise=0.2, rng=rng, info=np.array(info))
    np.testing.assert_allclose(np.asarray(chordal(g).matrix()), _dense_chordal(g), atol=1e-9)


def test_chordal_anchor_keeps_the_file_pose_of_the_fixed_vertex():
    rng = np.random.default_rng(4)
    X = SE3.random(7, rng=rng)
    g = _graph(SE3, X, EDGES, noise=0.05, rng=rng).replace(poses=X, fixed=np.array([3]))
    Y = chordal(g)
    np.testing.assert_allclose(Y[3].params, X[3].params, atol=1e-12)
    h = g.replace(fixed=np.zeros(0, dtype=np.int64))
    np.testing.assert_allclose(chordal(h)[0].params, X[0].params, atol=1e-12)


def test_chordal_is_far_better_than_a_poor_file_start():
    g = read_g2o(data_file("pose_graph/MIT.g2o"))  # README: LM from the file stalls at 385.1
    assert g.cost(chordal(g)) < 1e-7 * g.cost()


def test_initialize_dispatch_and_errors():
    rng = np.random.default_rng(5)
    X = SE2.random(7, rng=rng)
    g = _graph(SE2, X, EDGES)
    with pytest.raises(ValueError, match="no vertices"):
        from_file(g)
    with pytest.raises(ValueError, match="unknown initialisation 'best'"):
        initialize(g, "best")  # type: ignore[arg-type]
    assert initialize(g.replace(poses=X), "file") is X
    np.testing.assert_allclose(np.asarray(initialize(g, "odometry").params),
                               np.asarray(odometry(g).params))
