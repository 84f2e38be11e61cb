"""Issue 22's policies: LM damping that does not depend on the units (``damping=``,
``microlie optimize --damping``) and what the pose-graph readers do with information matrices
that are not positive definite (``information=``, ``--information``).

Independent references: GTSAM 4.3 LM's M3500 optimum 68.95743912 and SE-Sync's published
optima (``../shared/data/README.md``), the ground truth of noise-free synthetic graphs, and
eigen-decompositions / matrix inverses computed here.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from conftest import data_file

from microlie import SE2, SE3
from microlie.cli import main
from microlie.optim import BetweenFactor, CustomFactor, FactorGraph, Information, PriorFactor
from microlie.optim.core.strategies import LevenbergMarquardt
from microlie.optim.io.g2o import read_g2o, write_g2o
from microlie.optim.io.information import (
    PSD_FLOOR,
    apply_information_policy,
    isotropic_information,
    nearest_psd,
)
from microlie.optim.io.pose_graph import PoseGraph
from microlie.optim.io.toro import read_toro, write_toro

M3500 = "pose_graph/input_M3500_g2o.g2o"
M3500_OPT = 68.95743912  # README: GTSAM 4.3 LM


def _run(*argv: str) -> tuple[int, dict | None, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main(["optimize", *argv, "--json", "-q"], out=out, err=err)
    text = out.getvalue()
    return code, (json.loads(text) if text.strip() else None), err.getvalue()


def _scaled(g: PoseGraph, s: float) -> PoseGraph:
    """Translations in units of 1/s metres: positions and measured translations times s,
    the information's translation rows and columns divided by s (the cost is unchanged)."""
    d = g.dim
    P, Z = np.array(g.poses.params), np.array(g.measurements.params)
    P[:, :d] *= s
    Z[:, :d] *= s
    w = np.ones(g.group.dof)
    w[:d] = 1.0 / s
    return g.replace(poses=g.group(P), measurements=g.group(Z),
                     information=g.information * w[:, None] * w[None, :])


# ---------------------------------------------------------------------- damping
@pytest.fixture(scope="module")
def m3500_solution(tmp_path_factory):
    """The default command's M3500 optimum in metres (its poses)."""
    out = tmp_path_factory.mktemp("m3500") / "one.g2o"
    code, r, _ = _run(str(data_file(M3500)), "-o", str(out))
    assert code == 0 and r["final_cost"] == pytest.approx(M3500_OPT, rel=1e-7)
    return read_g2o(out).poses


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e3, 1e6])
def test_m3500_in_any_unit_reaches_the_same_optimum_with_the_default_command(
        tmp_path, scale, m3500_solution):
    g = read_g2o(data_file(M3500))
    path = tmp_path / f"m3500-{scale:g}.g2o"
    write_g2o(path, _scaled(g, scale))
    out = tmp_path / "out.g2o"
    code, r, _ = _run(str(path), "-o", str(out))
    assert code == 0 and r is not None and r["converged"]
    assert r["final_cost"] == pytest.approx(M3500_OPT, rel=1e-7)  # the cost is unit-free
    assert r["iterations"] <= 10
    # the optimum itself, back in metres (both runs stop at rel_tol 1e-5: 1e-5 m apart)
    X = read_g2o(out).poses
    np.testing.assert_allclose(np.asarray(X.translation()) / scale,
                               np.asarray(m3500_solution.translation()), atol=1e-4)
    np.testing.assert_allclose(np.asarray(X.params)[:, 2:],
                               np.asarray(m3500_solution.params)[:, 2:], atol=1e-5)


def test_identity_damping_stalls_in_micrometres_and_diagonal_does_not(tmp_path):
    # the measurement: GTSAM's damping stops far from the optimum, saying converged
    g = _scaled(read_g2o(data_file(M3500)), 1e6)
    path = tmp_path / "um.g2o"
    write_g2o(path, g)
    code, r, _ = _run(str(path), "--damping", "identity")
    assert code == 0 and r["converged"] and r["final_cost"] > 1e6
    code, r, _ = _run(str(path), "--damping", "diagonal")
    assert r["final_cost"] == pytest.approx(M3500_OPT, rel=1e-7)


def _chain(scale: float) -> tuple[FactorGraph, object, float]:
    """A 2-D loop of 30 poses with noisy measurements, translations times ``scale``."""
    rng = np.random.default_rng(5)
    n = 30
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    truth = SE2.from_xy_theta(10 * np.cos(th), 10 * np.sin(th), th + np.pi / 2)
    i = np.arange(n)
    j = (i + 1) % n
    Z = (truth[i].inverse() @ truth[j]).params.copy()
    Z[:, :2] += rng.normal(0, 0.05, (n, 2))
    x0 = truth.params.copy()
    x0[:, :2] += rng.normal(0, 0.5, (n, 2))
    x0[0] = truth.params[0]
    Z[:, :2] *= scale
    x0[:, :2] *= scale
    W = np.diag([1.0 / scale**2, 1.0 / scale**2, 100.0])
    fg = FactorGraph()
    x = fg.add_variables(SE2(x0))
    fg.add(PriorFactor(x, 0, SE2(x0[:1])))
    fg.add(BetweenFactor(x, i, j, SE2(Z), Information(np.broadcast_to(W, (n, 3, 3)).copy())))
    return fg, x, scale


def test_diagonal_damping_iterates_do_not_depend_on_the_units():
    # to the default tolerances (tighter, rounding decides the last rejections)
    runs = [_chain(s)[0].optimize(solver="lm", damping="diagonal") for s in (1.0, 1e5)]
    a, b = ([h.cost for h in r.history] for r in runs)
    assert len(a) == len(b) >= 3
    np.testing.assert_allclose(a, b, rtol=1e-8)
    assert [h.damping for h in runs[0].history] == [h.damping for h in runs[1].history]
    ident = [_chain(s)[0].optimize(solver="lm", damping="identity") for s in (1.0, 1e5)]
    assert ident[1].iterations > 2 * ident[0].iterations  # GTSAM's damping: the units matter


def test_auto_is_gtsams_identity_in_metres_and_diagonal_in_micrometres():
    fg, _, _ = _chain(1.0)
    auto, ident = (fg.optimize(solver="lm", damping=d) for d in ("auto", "identity"))
    assert [h.cost for h in auto.history] == [h.cost for h in ident.history]
    assert "diag(H)" not in auto.message
    fg, _, _ = _chain(1e6)
    auto, diag = (fg.optimize(solver="lm", damping=d) for d in ("auto", "diagonal"))
    assert [h.cost for h in auto.history] == [h.cost for h in diag.history]
    assert "damping auto: diag(H)" in auto.message


def test_auto_switches_where_the_identity_stops_too_damped():
    # a soft coordinate (curvature 1e-8) beside an arctan residual from b = 3, where
    # Gauss-Newton overshoots: LM raises lambda to ~1 for b, which freezes a; the identity
    # then stops at a ~ 0 reporting convergence. The minimum is a = 5, b = 0.
    g = FactorGraph()
    x = g.add_variables(np.array([[0.0, 3.0]]))

    def res(p):
        return np.stack([1e-4 * (p[..., 0] - 5.0), 10.0 * np.arctan(p[..., 1])], axis=-1)

    g.add(CustomFactor(res, [(x, [0])], 2))
    # lambda_initial 1e-12 < 1e-3 x 1e-8: auto starts with the identity
    ident = g.optimize(solver="lm", damping="identity", lambda_initial=1e-12)
    assert ident.converged and abs(ident.values[x][0, 0]) < 1e-3
    auto = g.optimize(solver="lm", damping="auto", lambda_initial=1e-12)
    assert auto.converged and "switched from I to diag(H)" in auto.message
    np.testing.assert_allclose(auto.values[x][0], [5.0, 0.0], atol=1e-6)
    n = len(ident.history)
    assert [h.cost for h in auto.history[:n]] == [h.cost for h in ident.history]


def test_damping_bad_input():
    with pytest.raises(ValueError, match="damping must be one of 'auto', 'identity'"):
        LevenbergMarquardt(damping="marquardt")
    with pytest.raises(ValueError, match=r"stall_ratio must be in \(0, 1\)"):
        LevenbergMarquardt(stall_ratio=1.0)
    code, _, err = _run(str(data_file("pose_graph/gtsam/pose2example.txt")), "--solver",
                        "dogleg", "--damping", "diagonal")
    assert code == 1 and "--damping applies to --solver lm, not dogleg" in err


# ---------------------------------------------------------------------- information policy
def _cubicle_like(tmp_path, rng, n=40):
    """A noise-free 3-D graph (odometry and loop closures from a ground truth), with SPD
    translation and rotation blocks but cross terms that make about a third of the 6x6
    matrices indefinite (as in cubicle.g2o). Returns the file, truth, information and the
    indices of the indefinite edges."""
    t = np.c_[np.cos(np.arange(n) / 3), np.sin(np.arange(n) / 3), 0.1 * np.arange(n)]
    truth = SE3.exp(np.c_[t, rng.normal(0, 0.3, (n, 3))])
    i = np.r_[np.arange(n - 1), rng.integers(0, n, 25)]
    j = np.r_[np.arange(1, n), rng.integers(0, n, 25)]
    keep = i != j
    i, j = i[keep], j[keep]
    E = i.size
    W = np.zeros((E, 6, 6))
    for k in range(E):
        A = rng.normal(size=(3, 3))
        B = rng.normal(size=(3, 3))
        W[k, :3, :3] = A @ A.T + 3 * np.eye(3)
        W[k, 3:, 3:] = 10 * (B @ B.T + np.eye(3))
        if k % 3 == 1:  # cross terms larger than the blocks allow
            C = rng.normal(size=(3, 3)) * 20
            W[k, :3, 3:], W[k, 3:, :3] = C, C.T
    lam = np.linalg.eigvalsh(W)
    bad = np.flatnonzero(lam[:, 0] <= 0)
    assert 5 < bad.size < E
    X0 = SE3(truth.params.copy())
    g = PoseGraph(SE3, ids=np.arange(n), poses=X0 @ SE3.exp(rng.normal(0, 0.02, (n, 6))),
                  i=i, j=j, measurements=truth[i].inverse() @ truth[j], information=W)
    g = g.replace(poses=SE3(np.concatenate([truth.params[:1], g.poses.params[1:]])))
    path = tmp_path / "cubicle-like.g2o"
    write_g2o(path, g)
    return path, truth, read_g2o_raw(path, n, E), bad


def read_g2o_raw(path, n, E) -> np.ndarray:
    """The file's 6x6 matrices parsed here (upper triangle row by row), independent of the
    reader."""
    rows = [line.split() for line in open(path) if line.startswith("EDGE_SE3:QUAT")]
    assert len(rows) == E
    r, c = np.triu_indices(6)
    W = np.zeros((E, 6, 6))
    for k, row in enumerate(rows):
        v = np.array(row[10:], dtype=float)
        W[k, r, c] = v
        W[k, c, r] = v
    return W


def test_indefinite_information_is_refused_by_default_with_file_line_and_count(tmp_path):
    rng = np.random.default_rng(1)
    path, _, W, bad = _cubicle_like(tmp_path, rng)
    n = 40
    first_line = n + bad[0] + 1  # n vertex lines, then the edges in order
    msg = (rf"{path}:{first_line}: information matrix is not positive definite .*; "
           rf"{bad.size} of {W.shape[0]} edges have such a matrix")
    with pytest.raises(ValueError, match=msg):
        read_g2o(path)
    code, r, err = _run(str(path))
    assert code == 1 and r is None and f"{path}:{first_line}:" in err
    assert f"{bad.size} of {W.shape[0]} edges" in err and "--information" in err


def test_nearest_psd_repairs_exactly_the_indefinite_edges_to_the_nearest_matrix(tmp_path):
    rng = np.random.default_rng(1)
    path, truth, W, bad = _cubicle_like(tmp_path, rng)
    g = read_g2o(path, information="nearest-psd")
    assert g.repaired.tolist() == bad.tolist()
    good = np.setdiff1d(np.arange(W.shape[0]), bad)
    assert np.array_equal(g.information[good], W[good])  # bit for bit
    for k in bad:
        lam, V = np.linalg.eigh(W[k])
        delta = PSD_FLOOR * lam[-1]
        expect = V @ np.diag(np.maximum(lam, delta)) @ V.T
        R = g.information[k]
        np.testing.assert_allclose(R, expect, rtol=1e-12, atol=1e-12 * lam[-1])
        mu = np.linalg.eigvalsh(R)
        assert mu[0] >= delta * (1 - 1e-6) and np.allclose(R, R.T)
        np.linalg.cholesky(R)
        # nearest: the Frobenius distance is the clipped eigenvalues' (Higham), and moving
        # towards any other matrix of the feasible set (eigenvalues >= delta) is farther
        dist = np.linalg.norm(W[k] - R)
        assert dist == pytest.approx(np.linalg.norm(np.minimum(lam - delta, 0.0)), rel=1e-9)
        psd = V @ np.diag(np.maximum(lam, 0.0)) @ V.T  # the semi-definite projection
        assert dist <= np.linalg.norm(W[k] - psd) + np.sqrt(6) * delta
        for _ in range(20):
            P = rng.normal(size=(6, 6))
            other = R + 1e-3 * lam[-1] * (P @ P.T) / np.linalg.norm(P @ P.T)
            assert np.linalg.norm(W[k] - other) >= dist
    code, r, _ = _run(str(path), "--information", "nearest-psd", "-o", str(tmp_path / "o.g2o"))
    assert code == 0 and r["converged"] and r["repaired_edges"] == bad.size
    assert r["information"] == "nearest-psd" and r["final_cost"] < 1e-12
    X = read_g2o(tmp_path / "o.g2o").poses  # the noise-free graph's optimum is the truth
    np.testing.assert_allclose(np.asarray(X.matrix()), np.asarray(truth.matrix()), atol=1e-6)


def test_isotropic_precisions_follow_se_sync_and_solve(tmp_path):
    rng = np.random.default_rng(1)
    path, truth, W, bad = _cubicle_like(tmp_path, rng)
    g = read_g2o(path, information="isotropic")
    assert g.repaired.tolist() == bad.tolist()
    tau = 3.0 / np.trace(np.linalg.inv(W[:, :3, :3]), axis1=1, axis2=2)
    kappa = 3.0 / (2.0 * np.trace(np.linalg.inv(W[:, 3:, 3:]), axis1=1, axis2=2))
    expect = np.zeros_like(W)
    expect[:, range(3), range(3)] = tau[:, None]
    expect[:, range(3, 6), range(3, 6)] = 2 * kappa[:, None]
    np.testing.assert_allclose(g.information, expect, rtol=1e-12)
    code, r, _ = _run(str(path), "--information", "isotropic", "-o", str(tmp_path / "o.g2o"))
    assert code == 0 and r["converged"] and r["repaired_edges"] == bad.size
    X = read_g2o(tmp_path / "o.g2o").poses
    np.testing.assert_allclose(np.asarray(X.matrix()), np.asarray(truth.matrix()), atol=1e-6)


def _se_sync_objective(g: PoseGraph, W: np.ndarray, X) -> float:
    """SE-Sync's F = sum kappa |R_j - R_i R_ij|_F^2 + tau |t_j - t_i - R_i t_ij|^2 with its
    weights from the file's matrices W (README "SE-Sync objective")."""
    d = g.dim
    tau = d / np.trace(np.linalg.inv(W[:, :d, :d]), axis1=1, axis2=2)
    kappa = W[:, 2, 2] if d == 2 else \
        3.0 / (2.0 * np.trace(np.linalg.inv(W[:, 3:, 3:]), axis1=1, axis2=2))
    M, Z = np.asarray(X.matrix()), np.asarray(g.measurements.matrix())
    a, b = M[g.index(g.i)], M[g.index(g.j)]
    rot = np.sum((b[:, :d, :d] - a[:, :d, :d] @ Z[:, :d, :d]) ** 2, axis=(1, 2))
    tr = b[:, :d, d] - a[:, :d, d] - np.einsum("eab,eb->ea", a[:, :d, :d], Z[:, :d, d])
    return float(np.sum(kappa * rot + tau * np.sum(tr**2, axis=1)))


@pytest.mark.parametrize("name, start, published", [
    ("manhattan.g2o", "odometry", 6431.39),  # README: 6.432e3 published, 6431.39 reproduced
    ("CSAIL.g2o", "odometry", 31.7037),
    ("sphere2500.g2o", "file", 1687.006),
])
def test_isotropic_optimum_is_se_syncs_published_one(name, start, published):
    from microlie.optim.init import initialize

    path = data_file(f"pose_graph/{name}")
    W = read_g2o(path).information
    g = read_g2o(path, information="isotropic")
    fg, poses = g.to_factor_graph(initialize(g, start))
    res = fg.optimize(rel_tol=1e-10, abs_tol=0.0, max_iter=100)
    F = _se_sync_objective(g, W, res.values[poses])
    assert F == pytest.approx(published, rel=2e-5)


def test_information_policy_on_toro_and_2d(tmp_path):
    W = np.array([[[4.0, 0, 0], [0, 1.0, 0], [0, 0, 10.0]],
                  [[1.0, 2.0, 0], [2.0, 1.0, 0], [0, 0, 5.0]]])  # the second: -1, 3, 5
    g = PoseGraph(SE2, ids=np.arange(3), poses=SE2.from_xy_theta([0., 1., 2.], 0., 0.),
                  i=np.array([0, 1]), j=np.array([1, 2]),
                  measurements=SE2.from_xy_theta([1.0, 1.0], 0., 0.), information=W)
    path = tmp_path / "g.graph"
    write_toro(path, g)
    with pytest.raises(ValueError, match=rf"{path}:5: .*1 of 2 edges"):
        read_toro(path)
    iso = read_toro(path, information="nearest-psd")
    np.testing.assert_allclose(np.linalg.eigvalsh(iso.information[1]), [5e-9, 3.0, 5.0],
                               rtol=1e-9, atol=1e-14)
    with pytest.raises(ValueError, match=rf"{path}:5: .*translation block is not positive"):
        read_toro(path, information="isotropic")  # its translation block is the indefinite part
    tau = 2.0 / (1 / 4.0 + 1.0)
    np.testing.assert_allclose(isotropic_information(W[0], 2), np.diag([tau, tau, 20.0]))


def test_information_policy_bad_input(tmp_path):
    with pytest.raises(ValueError, match="information must be one of 'strict'"):
        apply_information_policy(np.eye(3)[None], "clip", 2)
    with pytest.raises(ValueError, match="information must be one of 'strict'"):
        read_g2o(data_file("pose_graph/gtsam/pose2example.txt"), information="psd")
    with pytest.raises(ValueError, match="no positive eigenvalue"):
        nearest_psd(-np.eye(3))
    with pytest.raises(ValueError, match=r"floor must be in \[0, 1\)"):
        nearest_psd(np.eye(3), floor=1.0)
    with pytest.raises(ValueError, match=r"g.g2o:9: .*no positive eigenvalue.*nearest-psd"):
        apply_information_policy(-np.eye(3)[None], "nearest-psd", 2, name="g.g2o", lines=[9])
    code, _, err = _run(str(data_file("bal/dubrovnik-3-7-pre.txt")), "--information",
                        "isotropic")
    assert code == 1 and "--information applies to pose graphs" in err
