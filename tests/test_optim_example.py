"""``microlie optimize --example`` and the graph it solves (``example_pose_graph``).

Independent checks: the residuals and costs are recomputed here with 3x3 matrices and the
closed-form SE(2) logarithm (no microlie code); the noise is drawn with known covariance, so at
the ground truth ``2 * cost`` is chi-square with ``3 E`` degrees of freedom and at the optimum
with ``3 E - 3 (V - 1)`` (the first pose held); GTSAM 4.3's costs on the same graph are in
``tests/fixtures/optim/gtsam_example.json`` with the command that made them.
"""

from __future__ import annotations

import io
import json
import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import require

from microlie.cli import main
from microlie.data import EXAMPLE_SIGMAS, example_pose_graph
from microlie.optim.io.g2o import read_g2o

ROOT = Path(__file__).resolve().parents[1]
GTSAM = json.loads((ROOT / "tests" / "fixtures" / "optim" / "gtsam_example.json").read_text())


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = main(["optimize", *argv], out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def _mats(params: np.ndarray) -> np.ndarray:
    """(N, 3, 3) homogeneous matrices of SE(2) parameters (x, y, cos, sin)."""
    x, y, c, s = np.asarray(params, dtype=np.float64).T
    M = np.zeros((x.size, 3, 3))
    M[:, 0, 0], M[:, 0, 1], M[:, 0, 2] = c, -s, x
    M[:, 1, 0], M[:, 1, 1], M[:, 1, 2] = s, c, y
    M[:, 2, 2] = 1.0
    return M


def _residuals(graph, poses_params: np.ndarray) -> np.ndarray:
    """Log(Z^-1 X_i^-1 X_j) per edge, (x, y, theta), with the closed-form SE(2) log."""
    X = _mats(poses_params)
    E = np.linalg.inv(_mats(graph.measurements.params)) @ np.linalg.inv(X[graph.i]) @ X[graph.j]
    th = np.arctan2(E[:, 1, 0], E[:, 0, 0])
    a = np.where(np.abs(th) < 1e-9, 1.0, np.sin(th) / np.where(th == 0, 1.0, th))
    b = np.where(np.abs(th) < 1e-9, th / 2, (1 - np.cos(th)) / np.where(th == 0, 1.0, th))
    V = np.stack([np.stack([a, -b], -1), np.stack([b, a], -1)], -2)
    rho = np.linalg.solve(V, E[:, :2, 2][..., None])[..., 0]
    return np.column_stack([rho, th])


def _cost(graph, poses_params: np.ndarray) -> float:
    r = _residuals(graph, poses_params)
    return 0.5 * float(np.einsum("ei,eij,ej->", r, graph.information, r))


def _within(value: float, mean: float, var: float, k: float = 4.0) -> bool:
    return abs(value - mean) <= k * math.sqrt(var)


def test_example_graph_is_a_city_walk_with_the_stated_noise():
    graph, truth = example_pose_graph()
    V, E = graph.num_vertices, graph.num_edges
    assert (V, E) == (GTSAM["num_vertices"], GTSAM["num_edges"])
    assert np.array_equal(graph.ids, np.arange(V))
    assert np.array_equal(graph.i[:V - 1], np.arange(V - 1))  # odometry first
    assert np.array_equal(graph.j[:V - 1], np.arange(1, V))
    assert np.all(graph.j[V - 1:] > graph.i[V - 1:] + 1)     # then loop closures
    T = np.asarray(truth.params)
    assert np.allclose(T[:, :2], np.round(T[:, :2]), atol=1e-12)  # on the 1 m grid of [0, 10]^2
    assert T[:, :2].min() > -1e-12 and T[:, :2].max() < 10 + 1e-12
    heading = np.arctan2(T[:, 3], T[:, 2]) / (np.pi / 2)
    assert np.allclose(heading, np.round(heading), atol=1e-12)   # multiples of 90 degrees
    loop_i, loop_j = graph.i[V - 1:], graph.j[V - 1:]
    assert np.allclose(T[loop_i, :2], T[loop_j, :2], atol=1e-12)  # closures at revisits
    # the noise: residuals at the truth are -n, n ~ N(0, diag(sigmas)^2)
    r = _residuals(graph, T)
    assert np.allclose(r.std(axis=0) / np.array(EXAMPLE_SIGMAS), 1.0, atol=4 / math.sqrt(2 * E))
    assert np.allclose(graph.information, np.diag(np.array(EXAMPLE_SIGMAS) ** -2.0))
    cost_truth = _cost(graph, T)
    assert _within(2 * cost_truth, 3 * E, 6 * E)                   # chi-square(3E)
    assert cost_truth == pytest.approx(GTSAM["error_at_ground_truth"], rel=1e-9)
    # the start is the odometry chain from the true first pose, composed here with matrices
    Z = _mats(graph.measurements.params)
    chain = [np.eye(3)]
    for k in range(V - 1):
        chain.append(chain[-1] @ Z[k])
    assert np.allclose(_mats(graph.poses.params), np.array(chain), atol=1e-9)
    assert _cost(graph, np.asarray(graph.poses.params)) == pytest.approx(
        GTSAM["error_at_start"], rel=1e-9)


def test_example_graph_is_deterministic_and_checks_its_arguments():
    g1, t1 = example_pose_graph()
    g2, t2 = example_pose_graph()
    assert np.array_equal(g1.measurements.params, g2.measurements.params)
    assert np.array_equal(t1.params, t2.params) and np.array_equal(g1.j, g2.j)
    g3, _ = example_pose_graph(seed=21)
    assert g3.num_edges != g1.num_edges or not np.array_equal(g3.measurements.params,
                                                              g1.measurements.params)
    small, truth = example_pose_graph(20, side=2)
    assert small.num_vertices == 20 and np.asarray(truth.params)[:, :2].max() <= 2 + 1e-12
    for kwargs, name in (({"n_poses": 1}, "n_poses"), ({"side": 0}, "side"),
                         ({"sigmas": (0.1, 0.1, 0.0)}, "sigmas"),
                         ({"sigmas": (0.1, 0.1)}, "sigmas"), ({"p_turn": 1.5}, "p_turn"),
                         ({"p_loop": -0.1}, "p_loop")):
        with pytest.raises(ValueError, match=name):
            example_pose_graph(**kwargs)


def test_example_command_reaches_the_chi_square_optimum_and_gtsam(tmp_path):
    out_file = tmp_path / "opt.g2o"
    code, out, err = _run("--example", "--json", "-o", str(out_file))
    assert code == 0, err
    r = json.loads(out)
    graph, truth = example_pose_graph()
    V, E = graph.num_vertices, graph.num_edges
    assert r["file"] is None and r["init"] == "odometry" and r["converged"] is True
    assert (r["num_vertices"], r["num_edges"]) == (V, E)
    assert 1 <= r["iterations"] <= 20 and 0 < r["time_s"] < 60
    X = np.asarray(read_g2o(out_file).poses.params)
    final = _cost(graph, X)
    assert r["final_cost"] == pytest.approx(final, rel=1e-7)  # the file holds %.9g-ish numbers
    assert r["initial_cost"] == pytest.approx(GTSAM["error_at_start"], rel=1e-9)
    assert r["final_cost"] == pytest.approx(GTSAM["error_at_lm_optimum"], rel=1e-6)
    # chi-square: 2 cost at the optimum ~ chi2(3E - 3(V-1)); the drop from the truth ~ chi2(3(V-1))
    dof = 3 * E - 3 * (V - 1)
    assert _within(2 * r["final_cost"], dof, 2 * dof)
    cost_truth = _cost(graph, np.asarray(truth.params))
    assert r["final_cost"] < cost_truth
    assert _within(2 * (cost_truth - r["final_cost"]), 3 * (V - 1), 6 * (V - 1))
    assert r["ground_truth"]["cost"] == pytest.approx(cost_truth, rel=1e-9)
    # closer to the truth than the start (same gauge: pose 0 is held at the true first pose)
    T = np.asarray(truth.params)[:, :2]
    rmse0 = math.sqrt(np.mean(np.sum((np.asarray(graph.poses.params)[:, :2] - T) ** 2, -1)))
    rmse = math.sqrt(np.mean(np.sum((X[:, :2] - T) ** 2, -1)))
    assert r["ground_truth"]["initial_rmse"] == pytest.approx(rmse0, rel=1e-9)
    assert r["ground_truth"]["final_rmse"] == pytest.approx(rmse, rel=1e-6)
    assert rmse < rmse0 / 5 and rmse < 0.5


def test_example_summary_and_plot(tmp_path):
    require("matplotlib")
    png = tmp_path / "example.png"
    code, out, err = _run("--example", "--plot", str(png))
    assert code == 0, err
    _, js, _ = _run("--example", "--json", "-q")
    r = json.loads(js)
    assert out.startswith("example (microlie.data.example_pose_graph): SE2 pose graph, 500 poses, "
                          "693 edges\n")
    m = re.search(r"start odometry: cost (\S+) -> (\S+) in (\d+) iterations, (\S+) s, converged",
                  out)
    assert m is not None, out
    assert float(m[1]) == pytest.approx(r["initial_cost"], rel=1e-9)
    assert float(m[2]) == pytest.approx(r["final_cost"], rel=1e-9)
    assert int(m[3]) == r["iterations"]
    m = re.search(r"ground truth \(RMS\): (\S+) m -> (\S+) m", out)
    assert m is not None and float(m[2]) < float(m[1]) / 5
    assert "microlie optimize: example" in err  # the header names the example
    head = png.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", head[16:24]) == (1200, 600)


@pytest.mark.parametrize("argv, message", [
    (["--example", "IN.g2o"], "not allowed with argument"),
    (["IN.g2o", "--example"], "not allowed with argument"),
    ([], "one of the arguments IN --example is required"),
    (["--json"], "one of the arguments IN --example is required"),
])
def test_example_and_an_input_file_is_a_usage_error(tmp_path, argv, message):
    code, out, err = _run(*argv)
    assert code == 2 and out == ""
    assert message in err and "usage: microlie optimize" in err


def test_example_refuses_a_bal_format(tmp_path):
    code, out, err = _run("--example", "--format", "bal")
    assert code == 1 and out == ""
    assert "--example is a pose graph: --format bal does not apply" in err


def test_readme_first_command_is_the_example_and_the_second_is_ci(tmp_path, monkeypatch):
    """README: the first command runs ``microlie optimize --example --plot``, its printed
    output and GTSAM's cost match a run; the second command is ``.ci/run``'s."""
    require("matplotlib")
    readme = (ROOT / "README.md").read_text()
    commands = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
    first = commands[0].split(" && ")
    assert first[:2] == ['python3 -m venv .venv', '.venv/bin/pip install -q -e ".[plot]"']
    argv = first[2].split()
    assert argv[:3] == [".venv/bin/microlie", "optimize", "--example"] and "--plot" in argv
    ci = [ln for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln.startswith("python3")]
    assert commands[1] == ci[0]
    monkeypatch.chdir(tmp_path)
    out, err = io.StringIO(), io.StringIO()
    assert main(argv[1:], out=out, err=err) == 0, err.getvalue()
    assert (tmp_path / argv[argv.index("--plot") + 1]).is_file()
    shown = re.search(r"```text\n(.*?)\n```", readme, flags=re.S)
    assert shown is not None
    strip = re.compile(r"\((?:qdldl|cholesky|scipy)\)|[\d.]+ s,")  # install- and time-bound
    assert strip.sub("", shown[1]) == strip.sub("", out.getvalue().rstrip("\n"))
    assert f"reaches the same cost, {GTSAM['error_at_lm_optimum']:.12g}," in readme
