"""``linear_solver="schur"`` (microlie.optim.linalg.schur_solver): the Schur solve against a
dense solve of ``H`` on random block patterns, a mixed graph (SE3 poses, R(3) landmarks,
between factors, a position prior) against the sparse Cholesky and
scipy.optimize.least_squares, the ``eliminate=`` checks, and one symbolic analysis per
problem."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import least_squares

from microlie import SE3
from microlie.optim import (
    BetweenFactor,
    CustomFactor,
    Diagonal,
    FactorGraph,
    Isotropic,
    PriorFactor,
    SingularSystemError,
    check_jacobians,
)
from microlie.optim.core.landmarks import landmark_batches
from microlie.optim.linalg.cholesky import SupernodalSolver
from microlie.optim.linalg.schur_solver import SchurSolver


def _random_system(rng, nr, ne, dofs_e=(3, 6)):
    """A random SPD ``H`` (``J^T J`` of random block rows) on a random block pattern: ``nr``
    kept nodes and ``ne`` eliminated ones (dofs 3 and 6 mixed, interleaved), no two eliminated
    nodes in one block. Returns the dense H, its CSC (full dense blocks), node offsets and the
    eliminated nodes."""
    dofs = np.concatenate([rng.choice([3, 6], nr), rng.choice(dofs_e, ne)])
    perm = rng.permutation(dofs.size)
    dofs = dofs[perm]
    is_e = np.zeros(dofs.size, bool)
    is_e[np.argsort(perm)[nr:]] = True
    off = np.concatenate([[0], np.cumsum(dofs)])
    n, nn = int(off[-1]), dofs.size
    M = rng.random((nn, nn)) < 0.4
    M = M | M.T
    np.fill_diagonal(M, True)
    M[np.ix_(is_e, is_e)] = np.eye(int(is_e.sum()), dtype=bool)
    rows = []
    for u, v in zip(*np.nonzero(np.triu(M)), strict=True):
        r = np.zeros((4, n))
        r[:, off[u]:off[u + 1]] = rng.standard_normal((4, dofs[u]))
        r[:, off[v]:off[v + 1]] = rng.standard_normal((4, dofs[v]))
        rows.append(r)
    J = np.vstack(rows)
    H = J.T @ J + 1e-6 * np.eye(n)  # J may be rank deficient: a tiny ridge
    full = np.zeros((n, n), bool)
    for u, v in zip(*np.nonzero(M), strict=True):
        full[off[u]:off[u + 1], off[v]:off[v + 1]] = True
    c, r = np.nonzero(full.T)  # column by column, rows sorted
    A = sp.csc_matrix((H[r, c], (r, c)), shape=(n, n))
    A.sort_indices()
    assert A.nnz == full.sum()
    return H, A, off, np.flatnonzero(is_e)


@pytest.mark.parametrize("fast", ["1", "0"])
@pytest.mark.parametrize("reduced", ["dense", "cholesky"])
@pytest.mark.parametrize("seed", range(12))
def test_schur_solve_equals_dense_solve(seed, reduced, fast, monkeypatch):
    """x = S^-1 ... back-substituted equals numpy.linalg.solve(H, b), for one and several
    right-hand sides, undamped and with LM damping added to the diagonal in place; by the
    compiled formation of S (microlie._c._normal, when installed) and by the NumPy one."""
    monkeypatch.setenv("MICROLIE_FAST", fast)
    rng = np.random.default_rng(seed)
    H, A, off, elim = _random_system(rng, int(rng.integers(1, 7)), int(rng.integers(1, 25)))
    n = H.shape[0]
    s = SchurSolver(off, elim, reduced)
    s.analyse(A.indptr, A.indices, n)
    assert s.reduced_solver.name == reduced
    diag = np.flatnonzero(A.indices == np.repeat(np.arange(n), np.diff(A.indptr)))
    for lam in (0.0, 1e-3, 10.0):
        data = A.data.copy()
        data[diag] += lam
        Hd = H + lam * np.eye(n)
        s.factorize(data)
        b = rng.standard_normal((n, 3))
        ref = np.linalg.solve(Hd, b)
        tol = 1e-10 * np.linalg.cond(Hd)
        x = s.solve(b)
        assert np.abs(x - ref).max() <= tol * np.abs(ref).max()
        x0 = s.solve(b[:, 0])
        assert x0.shape == (n,)
        assert np.abs(x0 - ref[:, 0]).max() <= tol * np.abs(ref).max()


def test_schur_solver_rejects_bad_input():
    rng = np.random.default_rng(3)
    H, A, off, elim = _random_system(rng, 2, 4)
    n = H.shape[0]
    with pytest.raises(ValueError, match="eliminate names every node"):
        SchurSolver(off, np.arange(off.size - 1))
    with pytest.raises(ValueError, match="reduced must be one of"):
        SchurSolver(off, elim, "lu")
    with pytest.raises(ValueError, match="node_off"):
        SchurSolver([0, 3, 3], [0])
    kept = np.setdiff1d(np.arange(off.size - 1), elim)
    s = SchurSolver(off, np.r_[elim, kept[:1]])  # a kept node shares blocks with the others
    if (np.abs(H[off[kept[0]]:off[kept[0] + 1]][:, np.r_[[i for e in elim for i in
                                                          range(off[e], off[e + 1])]]])
            > 0).any():
        with pytest.raises(ValueError, match="share a block"):
            s.analyse(A.indptr, A.indices, n)
    s = SchurSolver(off, elim)
    s.analyse(A.indptr, A.indices, n)
    bad = A.data.copy()
    e0 = off[elim[0]]
    bad[(A.indices == e0) & (np.repeat(np.arange(n), np.diff(A.indptr)) == e0)] = -1.0
    with pytest.raises(SingularSystemError) as err:
        s.factorize(bad)
    assert off[elim[0]] <= err.value.unknown < off[elim[0] + 1]


# ------------------------------------------------------------------ the mixed graph
def _observe(T, p, z):
    """r = T^-1 p - z (the landmark in the camera frame), with the right Jacobians:
    d r / d xi = [-I, [q]x] (xi = (rho, phi), T Exp(xi)) and d r / d p = R^T."""
    R, t = T.rotation().matrix(), T.translation()
    q = np.einsum("mji,mj->mi", R, p - t)
    m = q.shape[0]
    hat = np.zeros((m, 3, 3))
    hat[:, 0, 1], hat[:, 0, 2], hat[:, 1, 2] = -q[:, 2], q[:, 1], -q[:, 0]
    hat -= np.swapaxes(hat, 1, 2)
    JT = np.concatenate([np.broadcast_to(-np.eye(3), (m, 3, 3)), hat], axis=2)
    return q - z, [JT, np.swapaxes(R, 1, 2)]


def _scene(seed=0, n_poses=6, n_points=40):
    rng = np.random.default_rng(seed)
    truth_T = SE3.exp(np.concatenate([np.stack([np.arange(n_poses) * 1.0,
                                                np.zeros(n_poses), np.zeros(n_poses)], 1),
                                      0.1 * rng.standard_normal((n_poses, 3))], 1))
    truth_p = rng.uniform([-2, -3, 4], [n_poses + 2, 3, 9], (n_points, 3))
    g = FactorGraph()
    T = g.add_variables(truth_T @ SE3.exp(0.05 * rng.standard_normal((n_poses, 6))),
                        name="poses")
    P = g.add_variables(truth_p + 0.3 * rng.standard_normal((n_points, 3)), name="points")
    cam, pt = [], []
    for j in range(n_points):
        for i in rng.choice(n_poses, 3, replace=False):
            cam.append(i)
            pt.append(j)
    cam, pt = np.array(cam), np.array(pt)
    zt = np.einsum("mji,mj->mi", truth_T[cam].rotation().matrix(),
                   truth_p[pt] - truth_T[cam].translation())
    z = zt + 0.002 * rng.standard_normal(zt.shape)
    obs = CustomFactor(_observe, [(T, cam), (P, pt)], 3, Isotropic(3, 0.01), data=[z],
                       jac="analytic")
    g.add(obs)
    i = np.arange(n_poses - 1)
    rel = (truth_T[i].inverse() @ truth_T[i + 1]) @ SE3.exp(0.002 * rng.standard_normal(
        (n_poses - 1, 6)))
    g.add(BetweenFactor(T, i, i + 1, rel, Diagonal([0.02] * 3 + [0.01] * 3)))
    gps = truth_T.translation() + 0.01 * rng.standard_normal((n_poses, 3))
    g.add(CustomFactor(lambda X, zz: X.translation() - zz, [(T, np.arange(n_poses))], 3,
                       Isotropic(3, 0.05), data=[gps]))
    g.add(PriorFactor(T, 0, truth_T[0], Isotropic(6, 0.01)))
    return g, T, P, obs


def test_observation_jacobians():
    g, T, P, obs = _scene()
    assert check_jacobians(obs).ok


@pytest.mark.parametrize("solver", ["lm", "gn", "dogleg"])
def test_mixed_graph_schur_equals_cholesky_and_scipy(solver):
    """The same graph solved with "schur" and "cholesky" (and, for the values, scipy's
    least_squares on the whole residual vector) agree to 1e-8."""
    g, T, P, _ = _scene()
    assert landmark_batches(g.problem()) == [P]
    kw = dict(solver=solver, rel_tol=1e-14, abs_tol=1e-14, max_iter=50)
    rs = g.optimize(linear_solver="schur", **kw)
    rc = g.optimize(linear_solver="cholesky", **kw)
    assert rs.linear_solver == "schur" and rs.iterations > 2
    assert abs(rs.final_cost - rc.final_cost) <= 1e-8 * rc.final_cost
    assert np.abs(rs.values[P] - rc.values[P]).max() <= 1e-8
    assert np.abs(rs.values[T].params - rc.values[T].params).max() <= 1e-8

    # scipy: the whitened residuals as a function of (pose tangents, points)
    p = g.problem()
    x0 = [v.initial for v in p.variables]

    def fun(dx):
        states = p.retract(x0, dx)
        out = []
        for f in p.factors:
            r = np.asarray(f.evaluate(p.gather(f, states), False))
            out.append(p.whiten(f, r).ravel())
        return np.concatenate(out)

    ref = least_squares(fun, np.zeros(p.size), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert abs(rs.final_cost - ref.cost) <= 1e-8 * ref.cost
    sx = p.retract(x0, ref.x)
    assert np.abs(rs.values[P] - sx[p.key(P)]).max() <= 1e-7
    assert np.abs(rs.values[T].params - sx[p.key(T)]).max() <= 1e-7


def test_marginals_through_schur():
    g, T, P, _ = _scene(1)
    res = g.optimize(linear_solver="cholesky")
    a = g.marginal_covariance(res.values, [(T, 2), (P, 5)], linear_solver="schur")
    b = g.marginal_covariance(res.values, [(T, 2), (P, 5)], linear_solver="dense")
    assert np.abs(a - b).max() <= 1e-10 * np.abs(b).max()


def test_eliminate_argument():
    g, T, P, _ = _scene(2, n_poses=4, n_points=10)
    rd = g.optimize(linear_solver="schur", eliminate=[P])
    rs = g.optimize(linear_solver="schur")
    assert abs(rd.final_cost - rs.final_cost) <= 1e-12 * rs.final_cost
    with pytest.raises(ValueError, match="'poses' share a factor with each other"):
        g.optimize(linear_solver="schur", eliminate=[T])
    with pytest.raises(ValueError, match="names every free variable"):
        h = FactorGraph()
        q = h.add_variables(np.zeros((3, 2)), name="q")
        h.add(PriorFactor(q, [0, 1, 2], np.ones((3, 2))))
        h.optimize(linear_solver="schur", eliminate=q)
    with pytest.raises(ValueError, match="eliminate\\[0\\] is not a variable handle"):
        g.optimize(linear_solver="schur", eliminate=[q])
    with pytest.raises(ValueError, match="applies to linear_solver='schur' only"):
        g.optimize(linear_solver="cholesky", eliminate=[P])
    with pytest.raises(ValueError, match="found no variables to eliminate"):
        h.optimize(linear_solver="schur")  # one batch only: nothing would remain
    # two batches that share a factor cannot both be eliminated
    k = FactorGraph()
    a = k.add_variables(np.zeros((2, 2)), name="a")
    b = k.add_variables(np.zeros((2, 2)), name="b")
    c = k.add_variables(np.zeros((1, 2)), name="c")
    k.add(CustomFactor(lambda u, v, w: u + v + w - 1.0, [(a, [0, 1]), (b, [0, 1]),
                                                         (c, [0, 0])], 2))
    k.add(PriorFactor(a, [0, 1], np.zeros((2, 2))))
    k.add(PriorFactor(b, [0, 1], np.zeros((2, 2))))
    k.add(PriorFactor(c, 0, np.zeros(2)))
    with pytest.raises(ValueError, match="'a' and 'b' share a factor"):
        k.optimize(linear_solver="schur", eliminate=[a, b])
    assert [v.name for v in landmark_batches(k.problem())] in (["a"], ["b"])
    fixed = FactorGraph()
    f1 = fixed.add_variables(np.zeros((2, 2)), name="f1", fixed=True)
    f2 = fixed.add_variables(np.zeros((2, 2)), name="f2")
    fixed.add(CustomFactor(lambda u, v: u - v, [(f1, [0, 1]), (f2, [0, 1])], 2))
    with pytest.raises(ValueError, match="every variable of 'f1' is fixed"):
        fixed.optimize(linear_solver="schur", eliminate=[f1])


def test_symbolic_analysis_runs_once(monkeypatch):
    """Across the iterations of a solve and a second solve of the same graph, the Schur
    solver and its reduced system's supernodal Cholesky are analysed once; every iteration
    refactorises."""
    calls = {"schur": 0, "reduced": 0, "factorize": 0}
    real_s, real_r, real_f = SchurSolver.analyse, SupernodalSolver.analyse, \
        SchurSolver.factorize

    def count(name, real):
        def wrapped(self, *a, **k):
            calls[name] += 1
            return real(self, *a, **k)
        return wrapped

    monkeypatch.setattr(SchurSolver, "analyse", count("schur", real_s))
    monkeypatch.setattr(SupernodalSolver, "analyse", count("reduced", real_r))
    monkeypatch.setattr(SchurSolver, "factorize", count("factorize", real_f))
    monkeypatch.setattr("microlie.optim.linalg.schur_solver.DENSE_ALWAYS", 0)
    monkeypatch.setattr("microlie.optim.linalg.schur_solver.DENSE_MAX", 0)
    g, T, P, _ = _scene(3)
    r1 = g.optimize(linear_solver="schur", rel_tol=1e-12, abs_tol=1e-12)
    r2 = g.optimize(linear_solver="schur", max_iter=3)
    assert r1.iterations > 2
    assert calls["schur"] == 1 and calls["reduced"] == 1
    assert calls["factorize"] >= r1.iterations + r2.iterations
    assert g.problem().analysed("schur").reduced_solver.name == "cholesky"


def test_fixed_variables():
    """Held landmarks and a held pose stay put and the optimum is the sparse Cholesky's."""
    g, T, P, _ = _scene(4)
    g.fix(P, [0, 3, 7])
    g.fix(T, [2])
    kw = dict(rel_tol=1e-14, abs_tol=1e-14, max_iter=50)
    rs = g.optimize(linear_solver="schur", **kw)
    rc = g.optimize(linear_solver="cholesky", **kw)
    assert abs(rs.final_cost - rc.final_cost) <= 1e-8 * rc.final_cost
    assert np.abs(rs.values[P] - rc.values[P]).max() <= 1e-8
    init = g.initial_values()
    assert np.array_equal(rs.values[P][[0, 3, 7]], init[P][[0, 3, 7]])
    assert np.array_equal(rs.values[T].params[2], init[T].params[2])


def test_make_solver_schur_names_the_way():
    from microlie.optim import make_solver

    with pytest.raises(ValueError, match="needs the problem's variables"):
        make_solver("schur")


def test_schur_analysis_by_sort_and_search_equals_dense_solve(monkeypatch):
    """Without the dense key and position tables of SchurSolver.analyse (large reduced
    systems: numpy.unique and binary search), the solution still equals numpy.linalg.solve."""
    import microlie.optim.linalg.schur_solver as ss
    monkeypatch.setattr(ss, "DENSE_KEYS", 0)
    monkeypatch.setattr(ss, "DENSE_TABLE", 0)
    rng = np.random.default_rng(5)
    H, A, off, elim = _random_system(rng, 5, 20)
    s = SchurSolver(off, elim)
    s.analyse(A.indptr, A.indices, H.shape[0])
    s.factorize(A.data)
    b = rng.standard_normal(H.shape[0])
    ref = np.linalg.solve(H, b)
    np.testing.assert_allclose(s.solve(b), ref, rtol=0, atol=1e-10 * np.linalg.cond(H)
                               * np.abs(ref).max())


def _camera_system(rng, nc, npt, sizes=(3, 3, 3)):
    """A bundle-like SPD ``H``: ``nc`` cameras of ``len(sizes)`` nodes each (numbered batch
    by batch, as a graph numbers rotations, translations and intrinsics), ``npt`` 3-unknown
    points each seen by 2-5 cameras (a block row touching every node of the camera and the
    point), one point seen by no camera. Returns the dense H, its CSC, node offsets, the
    point nodes and each camera's nodes."""
    nb = len(sizes)
    dofs = np.array(list(np.repeat(sizes, nc)) + [3] * npt)
    off = np.concatenate([[0], np.cumsum(dofs)])
    n = int(off[-1])
    cam_nodes = [[b * nc + c for b in range(nb)] for c in range(nc)]
    rows = []
    for j in range(npt - 1):
        pn = nb * nc + j
        for c in rng.choice(nc, size=rng.integers(2, min(nc, 5) + 1), replace=False):
            r = np.zeros((2, n))
            for u in [*cam_nodes[c], pn]:
                r[:, off[u]:off[u + 1]] = rng.standard_normal((2, dofs[u]))
            rows.append(r)
    J = np.vstack(rows)
    H = J.T @ J + 1e-3 * np.eye(n)
    A = sp.csc_matrix(np.where(np.abs(H) > 0, H, 0.0))
    # the pattern: full dense blocks of every pair of nodes that share a row (and diagonals)
    nn = dofs.size
    node = np.repeat(np.arange(nn), dofs)
    M = np.eye(nn, dtype=bool)
    for r in rows:
        us = np.unique(node[np.flatnonzero(r.any(0))])
        M[np.ix_(us, us)] = True
    full = M[node][:, node]
    c, r = np.nonzero(full.T)
    A = sp.csc_matrix((H[r, c], (r, c)), shape=(n, n))
    A.sort_indices()
    return H, A, off, np.arange(nb * nc, nn), cam_nodes


@pytest.mark.parametrize("fast", ["1", "0"])
@pytest.mark.parametrize("sizes", [(3, 3, 3), (3, 3, 2), (6, 3)])
def test_supernodes_of_camera_nodes(fast, sizes, monkeypatch):
    """The nodes of one camera (always together in every block row) become one supernode of
    the reduced system (9 x 9 blocks for three 3-unknown nodes: the compiled formation's
    block path), and the solve still equals numpy.linalg.solve, damped or not."""
    monkeypatch.setenv("MICROLIE_FAST", fast)
    rng = np.random.default_rng(11)
    nc = 7
    H, A, off, elim, cams = _camera_system(rng, nc, 40, sizes)
    n = H.shape[0]
    s = SchurSolver(off, elim, "cholesky")
    s.analyse(A.indptr, A.indices, n)
    assert s.supernodes == nc and s.n_reduced == nc * sum(sizes)
    # each camera's unknowns are consecutive in the reduced numbering
    nodes_of = np.repeat(np.arange(off.size - 1), np.diff(off))[s._r_unk]
    for k, c in enumerate(cams):
        assert set(nodes_of[k * sum(sizes):(k + 1) * sum(sizes)]) == set(c)
    diag = np.flatnonzero(A.indices == np.repeat(np.arange(n), np.diff(A.indptr)))
    for lam in (0.0, 1e-2, 10.0):
        data = A.data.copy()
        data[diag] += lam
        Hd = H + lam * np.eye(n)
        s.factorize(data)
        b = rng.standard_normal(n)
        ref = np.linalg.solve(Hd, b)
        x = s.solve(b)
        assert np.abs(x - ref).max() <= 1e-10 * np.linalg.cond(Hd) * np.abs(ref).max()


@pytest.mark.parametrize("fast", ["1", "0"])
def test_blocks_not_stored_in_full(fast, monkeypatch):
    """A pattern whose blocks are not dense (entries of B_e and C_e not stored: read as
    zeros) solves as numpy.linalg.solve does."""
    monkeypatch.setenv("MICROLIE_FAST", fast)
    H = np.array([[5.0, 1.0, 0.5, 0.0, 0.0],
                  [1.0, 4.0, 0.3, 0.2, 0.4],
                  [0.5, 0.3, 3.0, 0.0, 0.0],
                  [0.0, 0.2, 0.0, 2.0, 0.0],
                  [0.0, 0.4, 0.0, 0.0, 6.0]])
    A = sp.csc_matrix(H)  # stores the nonzeros only
    s = SchurSolver([0, 2, 4, 5], eliminate=[1, 2], reduced="dense")
    s.analyse(A.indptr, A.indices, 5)
    assert s._pad  # entries read as the zero after H's data
    s.factorize(A.data)
    b = np.arange(1.0, 6.0)
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(H, b), rtol=1e-13)


@pytest.mark.parametrize("fast", ["1", "0"])
@pytest.mark.parametrize("seed", range(6))
def test_analysis_from_the_block_pattern(seed, fast, monkeypatch):
    """Analysed from the pattern of 3 x 3 blocks alone (``indices=None``, as a Problem hands
    it over: H's node blocks read off it, never off the scalar pattern), the solve equals
    numpy.linalg.solve, on random block patterns (nodes of 3 and 6 unknowns) and bundle-like
    ones (cameras of three nodes)."""
    monkeypatch.setenv("MICROLIE_FAST", fast)
    rng = np.random.default_rng(100 + seed)
    if seed % 2:
        H, A, off, elim, _ = _camera_system(rng, 5, 30)
    else:
        H, A, off, elim = _random_system(rng, int(rng.integers(1, 7)), int(rng.integers(1, 25)))
    n = H.shape[0]
    Bk = A.tobsr(blocksize=(3, 3))  # symmetric pattern: its block CSR is its block CSC
    Bk.sort_indices()
    s = SchurSolver(off, elim, "cholesky")
    s.analyse(A.indptr, None, n, 3, block_pattern=(Bk.indptr, Bk.indices))
    assert not s._pad  # the blocks are stored in full: H's data is read in place
    assert s._indices is None  # the scalar pattern was never expanded
    for lam in (0.0, 1e-2):
        data = A.data.copy()
        diag = np.flatnonzero(A.indices == np.repeat(np.arange(n), np.diff(A.indptr)))
        data[diag] += lam
        Hd = H + lam * np.eye(n)
        s.factorize(data)
        b = rng.standard_normal(n)
        ref = np.linalg.solve(Hd, b)
        x = s.solve(b)
        assert np.abs(x - ref).max() <= 1e-10 * np.linalg.cond(Hd) * np.abs(ref).max()
