"""benchmarks/devices.py's shared pieces: the NumPy formulas every contender's cost is checked
with, the problem generators, and the command line. The timings themselves are the
benchmark's, not a test's."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dev():
    spec = importlib.util.spec_from_file_location("bench_devices",
                                                  ROOT / "benchmarks" / "devices.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_devices"] = mod    # dataclasses resolve their module by name
    spec.loader.exec_module(mod)
    yield mod
    sys.modules.pop("bench_devices", None)


def twist(xi):
    """The 4x4 matrix of a tangent [rho, phi]."""
    M = np.zeros((4, 4))
    w = xi[3:]
    M[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    M[:3, 3] = xi[:3]
    return M


def hard_tangents(rng):
    """Angles from 0 and 1e-9 to pi - 1e-3, translations of a few metres."""
    out = []
    for theta in (0.0, 1e-9, 1e-7, 1e-4, 0.3, 2.0, np.pi - 1e-3):
        axis = rng.normal(size=3)
        out.append(np.concatenate([rng.normal(size=3) * 3, theta * axis / np.linalg.norm(axis)]))
    return np.array(out)


def test_se3_exp_log_against_matrix_exponential(dev):
    xi = hard_tangents(np.random.default_rng(0))
    T = dev.se3_exp(xi)
    for k in range(len(xi)):
        np.testing.assert_allclose(T[k], expm(twist(xi[k])), rtol=0, atol=1e-13)
    np.testing.assert_allclose(dev.se3_log(T), xi, rtol=0, atol=1e-9)
    # log against the matrix logarithm away from pi (logm is accurate there)
    for k in range(len(xi) - 1):
        np.testing.assert_allclose(twist(dev.se3_log(T)[k]), np.real(logm(T[k])), atol=1e-9)


def test_quaternion_conversions_against_scipy(dev):
    R = Rotation.random(50, random_state=1)
    q = dev.quat_xyzw_from_matrix(R.as_matrix())
    ref = R.as_quat()                                   # scipy's (x, y, z, w)
    ref *= np.where(ref[:, 3:] < 0, -1.0, 1.0)
    np.testing.assert_allclose(q, ref, atol=1e-14)
    np.testing.assert_allclose(dev.matrix_from_quat_xyzw(q), R.as_matrix(), atol=1e-14)
    T = dev.se3_exp(hard_tangents(np.random.default_rng(2)))
    np.testing.assert_allclose(dev.matrix_from_params(dev.params_from_matrix(T)), T, atol=1e-14)


def test_pose_graph_cost_equals_microlie_graph_cost(dev):
    """The benchmark's NumPy cost (independent formulas) against microlie's FactorGraph at the
    same start, and the batch's structure as documented."""
    from microlie import SE3
    from microlie.optim import BetweenFactor, Diagonal, FactorGraph, PriorFactor

    p = dev.make_pose_graphs(3, seed=5)
    assert p.edges.shape == (12, 2) and p.X0.shape == (3, 10, 4, 4)
    assert np.all(p.edges[9:, 1] - p.edges[9:, 0] >= 3)
    costs = dev.pose_graph_costs(p, p.X0)
    for b in range(3):
        g = FactorGraph()
        X = g.add_variables(SE3(dev.params_from_matrix(p.X0[b])))
        g.add(BetweenFactor(X, p.edges[:, 0], p.edges[:, 1],
                            SE3(dev.params_from_matrix(p.Z[b])), Diagonal(1 / p.w_edge)))
        g.add(PriorFactor(X, 0, SE3(dev.params_from_matrix(p.Z0[b])), Diagonal(1 / p.w_prior)))
        r = g.optimize(max_iter=0)
        assert costs[b] == pytest.approx(r.initial_cost, rel=1e-12)
    # the benchmark's own graph of the batch (the NumPy engine's contender) has the same cost
    g3, _ = dev.build_graph("posegraph", p, 3)
    assert g3.optimize(max_iter=0).initial_cost == pytest.approx(costs.sum(), rel=1e-12)
    # the truth is near the optimum: its cost is about half the number of residuals
    assert np.all(dev.pose_graph_costs(p, p.truth) < 0.5 * (12 * 6 + 6) * 3)


def test_pnp_cost_equals_a_direct_projection(dev):
    p = dev.make_pnp(4, seed=3, m=25)
    assert p.points.shape == (4, 25, 3) and p.uv.shape == (4, 25, 2)
    b = 2
    R, t = p.truth[b, :3, :3], p.truth[b, :3, 3]
    P = p.points[b] @ R.T + t
    assert np.all(P[:, 2] >= 4.0 - 1e-9)                 # in front of the camera
    uv = np.column_stack([500 * P[:, 0] / P[:, 2] + 320, 500 * P[:, 1] / P[:, 2] + 240])
    assert dev.pnp_costs(p, p.truth)[b] == pytest.approx(0.5 * np.sum((uv - p.uv[b]) ** 2),
                                                          rel=1e-12)
    g, _ = dev.build_graph("pnp", p, 4)
    assert g.optimize(max_iter=0).initial_cost == pytest.approx(dev.pnp_costs(p, p.T0).sum(),
                                                                rel=1e-12)


def test_bal_cost_is_the_published_initial_cost(dev):
    b = dev.read_bal_arrays(data_file("bal/problem-49-7776-pre.txt"))
    assert (len(b.cameras), len(b.points), len(b.uv)) == (49, 7776, 31843)
    # SciPy Cookbook: initial cost 8.5091e+05 (../shared/data/README.md); 850912.46 with the
    # points behind a camera evaluated (the BAL convention)
    assert dev.bal_cost(b, b.cameras, b.points) == pytest.approx(850912.46068, rel=1e-9)


@pytest.mark.parametrize("argv, word", [(["--batch", "0"], "--batch"),
                                        (["--pnp-points", "3"], "--pnp-points"),
                                        (["--bal", "/nonexistent.txt"], "--bal"),
                                        (["--device", "tpu"], "--device"),
                                        (["--max-iter", "0"], "--max-iter"),
                                        (["--rel-tol", "-1"], "--rel-tol")])
def test_bad_arguments_name_the_option(dev, argv, word, capsys):
    with pytest.raises(SystemExit):
        dev.main(argv)
    assert word in capsys.readouterr().err
