"""The code in docs/bundle_adjustment.md runs, and prints what its comments say."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file

from microlie.optim.io.bal import read_bal

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "bundle_adjustment.md").read_text(),
                    re.S)


def _run(code: str) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        exec(compile(code, "docs/bundle_adjustment.md", "exec"), {})
    return buf.getvalue()


def test_bal_example(monkeypatch, tmp_path):
    monkeypatch.chdir(data_file("bal/problem-49-7776-pre.txt").parent)  # the page names it bare
    out = _run(BLOCKS[0].replace('"problem-49-solved.txt"', repr(str(tmp_path / "s.txt"))))
    lines = out.split("\n")
    assert lines[0] == "49 7776 31843"
    a, b = map(float, lines[1].split())
    assert a == pytest.approx(850912.46, abs=0.01) and b == pytest.approx(13344.3184, rel=1e-6)
    assert lines[2] == "31 True"                  # Ceres' count (the old loop's was 32)
    back = read_bal(tmp_path / "s.txt")
    assert back.cost() == pytest.approx(13344.3184, rel=1e-6)   # the written optimum


def test_two_view_example():
    out = _run(BLOCKS[1]).split("\n")
    ok, rms = out[0].split()
    assert ok == "True" and 0.1 < float(rms) < 0.3 * 2 ** 0.5
    nums = [float(v) for v in out[1].replace("[", " ").replace("]", " ").split()]
    err, std = np.abs(nums[:3]), np.array(nums[3:])
    assert np.all(err < 3 * std) and np.all(std < 0.5)     # degrees


def test_mixed_graph_example():
    """The reprojection + odometry + GPS graph of the page: its printed lines, and its optimum
    against scipy.optimize.least_squares on the same objective written independently
    (rotation vectors for the camera-to-world rotations, logm for the between residual)."""
    from scipy.linalg import expm, logm
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    block = BLOCKS[2]
    ns: dict = {}
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        exec(compile(block, "docs/bundle_adjustment.md", "exec"), ns)
    lines = buf.getvalue().split("\n")
    comments = re.findall(r"# (True \d+ \d+|\d\.\d+)", block)
    assert lines[0] == comments[0] and lines[1] == comments[1]
    n_cam = ns["n_cam"]
    cam, pt, K = ns["cam"], ns["pt"], ns["K"]
    pixels, odometry, gps = ns["pixels"], ns["odometry"].matrix(), ns["gps"]
    start_T = ns["g"].initial_values()[ns["poses"]].matrix()
    start_X = ns["g"].initial_values()[ns["points"]]

    def mat(w, c):
        M = np.tile(np.eye(4), (len(w), 1, 1))
        M[:, :3, :3], M[:, :3, 3] = Rotation.from_rotvec(w).as_matrix(), c
        return M

    def residuals(x):
        w, c = x[:3 * n_cam].reshape(-1, 3), x[3 * n_cam:6 * n_cam].reshape(-1, 3)
        X = x[6 * n_cam:].reshape(-1, 3)
        T = mat(w, c)
        P = np.einsum("nji,nj->ni", T[cam, :3, :3], X[pt] - T[cam, :3, 3])   # R^T (X - c)
        r_proj = (K[:2] * P[:, :2] / P[:, 2:] + K[2:] - pixels) / 0.5
        r_odo = []
        for i in range(n_cam - 1):
            L = np.real(logm(np.linalg.inv(odometry[i]) @ np.linalg.inv(T[i]) @ T[i + 1]))
            r_odo.append(np.r_[L[:3, 3], L[2, 1], L[0, 2], L[1, 0]] / 0.005)
        return np.concatenate([r_proj.ravel(), np.ravel(r_odo), ((c - gps) / 0.1).ravel()])

    x0 = np.concatenate([Rotation.from_matrix(start_T[:, :3, :3]).as_rotvec().ravel(),
                         start_T[:, :3, 3].ravel(), start_X.ravel()])
    assert 0.5 * np.sum(residuals(x0) ** 2) == pytest.approx(ns["result"].initial_cost,
                                                             rel=1e-9)
    # which unknowns each residual row depends on (finite differences grouped by columns)
    S = np.zeros((len(residuals(x0)), len(x0)), bool)
    for k, (c, p) in enumerate(zip(cam, pt, strict=True)):
        for j in (3 * c, 3 * n_cam + 3 * c, 6 * n_cam + 3 * p):
            S[2 * k:2 * k + 2, j:j + 3] = True
    o = 2 * len(cam)
    for i in range(n_cam - 1):
        for j in (3 * i, 3 * i + 3, 3 * n_cam + 3 * i, 3 * n_cam + 3 * i + 3):
            S[o + 6 * i:o + 6 * i + 6, j:j + 3] = True
    for i in range(n_cam):
        S[o + 6 * (n_cam - 1) + 3 * i:o + 6 * (n_cam - 1) + 3 * i + 3,
          3 * n_cam + 3 * i:3 * n_cam + 3 * i + 3] = True
    # microlie's optimum: the independent objective agrees there, and scipy started from it
    # finds nothing lower (a full scipy solve from x0 takes minutes with logm)
    Tf, Xf = ns["result"].values[ns["poses"]].matrix(), ns["result"].values[ns["points"]]
    xf = np.concatenate([Rotation.from_matrix(Tf[:, :3, :3]).as_rotvec().ravel(),
                         Tf[:, :3, 3].ravel(), Xf.ravel()])
    assert 0.5 * np.sum(residuals(xf) ** 2) == pytest.approx(ns["result"].final_cost, rel=1e-9)
    ref = least_squares(residuals, xf, method="trf", x_scale="jac", ftol=1e-15, xtol=1e-15,
                        gtol=1e-15, max_nfev=6, jac_sparsity=S)
    assert ref.cost >= ns["result"].final_cost * (1 - 1e-5)    # optimize's default rel_tol
    # logm(expm(se3 twist)) is the SE(3) log: the between residual matches microlie's
    xi = np.array([0.1, -0.2, 0.3, 0.2, 0.1, -0.3])
    M = np.zeros((4, 4))
    M[:3, :3] = [[0, -xi[5], xi[4]], [xi[5], 0, -xi[3]], [-xi[4], xi[3], 0]]
    M[:3, 3] = xi[:3]
    assert np.allclose(np.real(logm(expm(M))), M)
