"""The compiled linearisation of BAL reprojection factors (``microlie._c._reproj``,
``microlie.optim.core.compiled.ReprojectionPlan``) against the NumPy path of ``Problem``
(``ReprojectionFactor.evaluate_into``, whitening, robust correction, products and scatter:
independent code) and against ``H = J^T J``, ``g = J^T e`` assembled densely from central
differences of the residuals on ``scipy.linalg.expm``: the same linear system, costs and
solution, with fixed cameras, points and intrinsics, held components, constant intrinsics,
per-observation correlated noise, a robust loss and points behind the camera (both ``behind``
options). ``MICROLIE_FAST=0`` keeps the NumPy path."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require
from scipy.linalg import expm

from microlie import SO3
from microlie.optim import FactorGraph, Information, ReprojectionFactor, TrustRegion
from microlie.optim.core import compiled
from microlie.optim.core.compiled import ReprojectionPlan
from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene


@pytest.fixture
def reproj(monkeypatch):
    monkeypatch.delenv("MICROLIE_FAST", raising=False)
    return require("microlie._c._reproj")


def _scene(rng, nc=4, npt=25, behind=0):
    """A BAL scene as a graph's pieces: rotations, translations, intrinsics, points and
    observations (every point seen by 2-4 cameras); ``behind`` points moved behind the
    first camera that sees them."""
    R = SO3.exp(rng.normal(scale=0.3, size=(nc, 3)))
    t = rng.normal(size=(nc, 3)) + [0.0, 0.0, -8.0]
    K = np.column_stack([rng.uniform(400, 600, nc), rng.normal(scale=0.05, size=nc),
                         rng.normal(scale=0.01, size=nc)])
    X = rng.normal(size=(npt, 3))
    cam, pt = [], []
    for j in range(npt):
        for c in rng.choice(nc, size=rng.integers(2, 5), replace=False):
            cam.append(c)
            pt.append(j)
    cam, pt = np.array(cam), np.array(pt)
    Rm = np.asarray(R.matrix())
    for j in range(behind):  # P_z >= 0 in the camera of its first observation
        c = cam[np.flatnonzero(pt == j)[0]]
        X[j] = Rm[c].T @ (np.array([0.1, -0.2, 3.0]) - t[c])
    obs = rng.normal(scale=20.0, size=(cam.size, 2))
    return R, t, K, X, cam, pt, obs


def _graph(rng, *, loss=None, behind="evaluate", noise=None, const_k=False, n_behind=0,
           fix=True, hold=True):
    R, t, K, X, cam, pt, obs = _scene(rng, behind=n_behind)
    g = FactorGraph()
    rv = g.add_variables(R, name="R")
    tv = g.add_variables(t, name="t")
    xv = g.add_variables(X, name="X")
    kv = None if const_k else g.add_variables(K, name="K")
    intr = K[cam] if const_k else (kv, cam)
    if noise == "per":
        S = rng.normal(size=(cam.size, 2, 2))
        noise = Information(S @ np.swapaxes(S, 1, 2) + 2 * np.eye(2))
    elif noise == "shared":
        noise = Information(np.array([[2.0, 0.3], [0.3, 0.5]]))
    g.add(ReprojectionFactor(((rv, cam), (tv, cam)), (xv, pt), obs, intrinsics=intr,
                             noise=noise, loss=loss, behind=behind))
    if fix:
        g.fix(rv, [0])
        g.fix(xv, [3])
        if kv is not None:
            g.fix(kv, [1])
    if hold:
        g.fix(tv, [2], components=[1])
        if kv is not None:
            g.fix(kv, [0], components=[2])
    return g


def _pair(g, monkeypatch):
    """The problem with the compiled plan and the one on the NumPy path."""
    p = g.problem(gauge="none")
    monkeypatch.setenv("MICROLIE_FAST", "0")
    from microlie.optim.core.problem import Problem

    q = Problem(g.variables, g.factors, "none")
    monkeypatch.delenv("MICROLIE_FAST")
    assert isinstance(p.plans[0], ReprojectionPlan) and q.plans[0] is None
    return p, q


CASES = [dict(), dict(loss="huber:2.0"), dict(noise="per"), dict(noise="shared", loss="cauchy:5"),
         dict(const_k=True), dict(n_behind=3), dict(n_behind=3, behind="drop"),
         dict(fix=False, hold=False)]


@pytest.mark.parametrize("case", CASES)
def test_same_linear_system_as_the_numpy_path(reproj, monkeypatch, case):
    rng = np.random.default_rng(7)
    g = _graph(rng, **case)
    p, q = _pair(g, monkeypatch)
    st = [v.initial for v in p.variables]
    a, b = p.linearize(st), q.linearize(st)
    assert a.data.shape == b.data.shape
    np.testing.assert_allclose(a.data, b.data, rtol=0, atol=1e-12 * np.abs(b.data).max())
    np.testing.assert_allclose(a.grad, b.grad, rtol=0, atol=1e-12 * np.abs(b.grad).max())
    assert a.cost == pytest.approx(b.cost, rel=1e-13)
    assert a.robust_cost == pytest.approx(b.robust_cost, rel=1e-13)
    ca, cb = p.costs(st), q.costs(st)
    assert ca == pytest.approx(cb, rel=1e-13)


def _residuals(R, t, X, K, cam, pt, obs):
    """Ceres' SnavelyReprojectionError written out (rotation matrices given)."""
    P = np.einsum("nij,nj->ni", R[cam], X[pt]) + t[cam]
    p = -P[:, :2] / P[:, 2:]
    r2 = (p ** 2).sum(1)
    f, k1, k2 = K[cam].T
    return (f * (1 + k1 * r2 + k2 * r2 ** 2))[:, None] * p - obs


def test_against_dense_central_differences(reproj):
    """H and g of the compiled path equal J^T J and J^T e with J from central differences
    of the residuals written independently (rotations perturbed by scipy's expm)."""
    rng = np.random.default_rng(3)
    R, t, K, X, cam, pt, obs = _scene(rng, nc=4, npt=8)
    g = FactorGraph()
    rv, tv = g.add_variables(R), g.add_variables(t)
    xv, kv = g.add_variables(X), g.add_variables(K)
    g.add(ReprojectionFactor(((rv, cam), (tv, cam)), (xv, pt), obs, intrinsics=(kv, cam)))
    p = g.problem(gauge="none")
    assert isinstance(p.plans[0], ReprojectionPlan)
    lin = p.linearize([v.initial for v in p.variables])
    H, grad = p.matrix(lin.data).toarray(), lin.grad
    Rm = np.asarray(R.matrix())
    nc, npt = len(t), len(X)

    def hat(w):
        return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])

    def res(dx):
        d = iter(np.split(dx, np.cumsum([3 * nc, 3 * nc, 3 * npt])))
        dR, dt, dX, dK = (next(d).reshape(-1, 3) for _ in range(4))
        Rp = np.stack([Rm[c] @ expm(hat(dR[c])) for c in range(nc)])
        return _residuals(Rp, t + dt, X + dX, K + dK, cam, pt, obs).ravel()

    n = p.size
    # the differences below are in the order R, t, X, K (3 unknowns per variable); where
    # each of them is in the problem's numbering
    where = np.concatenate([p.node_off[p.node_of[p.key(v)]][:, None] + np.arange(3)
                            for v in (rv, tv, xv, kv)]).ravel()
    e0 = res(np.zeros(n))
    J = np.empty((e0.size, n))
    for k in range(n):
        h = 1e-6 * max(1.0, abs(np.concatenate([np.zeros(6 * nc), X.ravel(), K.ravel()])[k]))
        dx = np.zeros(n)
        dx[k] = h
        J[:, k] = (res(dx) - res(-dx)) / (2 * h)
    Hr, gr = np.empty((n, n)), np.empty(n)
    Hr[np.ix_(where, where)], gr[where] = J.T @ J, J.T @ e0
    assert np.abs(H - Hr).max() <= 1e-6 * np.abs(Hr).max()
    assert np.abs(grad - gr).max() <= 1e-6 * np.abs(gr).max()
    assert lin.cost == pytest.approx(0.5 * e0 @ e0, rel=1e-12)


def test_same_solution_and_off_switch(reproj, monkeypatch):
    """A whole trust-region solve ends at the same cost with and without the compiled plan;
    MICROLIE_FAST=0 builds no plan."""
    _, start = synthetic_scene(6, 60, seed=4)
    res = {}
    for fast in ("1", "0"):
        monkeypatch.setenv("MICROLIE_FAST", fast)
        bg = bundle_graph(start, fix_cameras=[0], fix_points=[0], robust="huber:2.0")
        p = bg.graph.problem()
        assert isinstance(p.plans[0], ReprojectionPlan) == (fast == "1")
        res[fast] = bg.graph.optimize(solver=TrustRegion(), linear_solver="schur")
    assert res["1"].final_cost == pytest.approx(res["0"].final_cost, rel=1e-10)
    assert res["1"].iterations == res["0"].iterations


def test_other_forms_take_the_numpy_path(reproj):
    """SE3 poses, camera_to_world and the pinhole model have no compiled plan."""
    rng = np.random.default_rng(1)
    R, t, K, X, cam, pt, obs = _scene(rng)
    g = FactorGraph()
    rv, tv, xv = g.add_variables(R), g.add_variables(t), g.add_variables(X)
    kv = g.add_variables(K)
    f1 = g.add(ReprojectionFactor(((rv, cam), (tv, cam)), (xv, pt), obs, intrinsics=(kv, cam),
                                  camera_to_world=True))
    f2 = g.add(ReprojectionFactor(((rv, cam), (tv, cam)), (xv, pt), obs, model="pinhole",
                                  intrinsics=[500.0, 500.0, 0.0, 0.0]))
    p = g.problem(gauge="none")
    assert compiled.plan(p, f1) is None and compiled.plan(p, f2) is None


def test_bad_arguments(reproj):
    z = np.zeros
    R, t, X, K = np.tile(np.eye(3), (2, 1, 1)), z((2, 3)), z((2, 3)), np.ones((2, 3))
    idx = np.array([[0, 0, 0, 5]], dtype=np.intp)  # K row 5 of 2
    with pytest.raises(ValueError, match="idx"):
        reproj.cost(R, t, X, K, idx, z((1, 2)), np.eye(2)[None], False, z(1))
    idx[0, 3] = 0
    with pytest.raises(ValueError, match="L must"):
        reproj.cost(R, t, X, K, idx, z((1, 2)), np.tile(np.eye(2), (3, 1, 1)), False, z(1))
    st = np.full((1, 16), -1, np.intp)
    st[0, 0] = 10  # a block past the end of data
    lens, goff = np.full((1, 4), 3, np.intp), np.full((1, 4), -1, np.intp)
    with pytest.raises(ValueError, match="starts"):
        reproj.normal(R, t, X, K, idx, z((1, 2)), np.eye(2)[None], False, None, st, lens,
                      goff, z(1), z(12), z(12))
    with pytest.raises(ValueError, match="C-contiguous"):
        reproj.cost(R, t, X, K, idx.astype(np.int32), z((1, 2)), np.eye(2)[None], False, z(1))
