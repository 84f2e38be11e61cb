"""A mixed graph in one solve, against GTSAM 4.3 (fixture tests/fixtures/optim/mixed_gtsam.json).

The scene (16 SE3 cameras on a circle, 300 landmarks, one shared pinhole calibration, odometry
between consecutive cameras with a loop closure, GPS-like camera positions, a calibration prior)
and GTSAM's solution of the same graph (``GeneralSFMFactor2Cal3_S2``, ``BetweenFactorPose3``,
``GPSFactor``, ``PriorFactorCal3_S2``; LM to convergence) were made by
``benchmarks/mixed_graph_gtsam.py`` (command and versions in the fixture and in
tests/fixtures/optim/README.md). That script verified the convention mappings used here
numerically against GTSAM before solving.

Our graph, in two forms of the same objective (``FORMS``):

* ``"T_cw"``: poses world-to-camera ``T_cw = P_wc^-1`` (SE3, right perturbation, tangent
  translation first), as :class:`ReprojectionFactor` takes them by default. GTSAM's odometry
  ``Log(Z^-1 P_i^-1 P_j)`` is then ``Log(Z^-1 T_i T_j^-1)``, the same element: a CustomFactor
  with Jacobians ``Jr^-1(r) Ad(T_j)`` and ``-Jr^-1(r) Ad(T_j)``; GPS is the camera centre
  ``-R^T t - z``, Jacobian ``[-I, [c]x]``. (microlie's ``BetweenFactor`` on ``T_cw``,
  ``Log(Z^-1 T_i^-1 T_j)``, is a different objective.)
* ``"T_wc"``: poses camera-to-world ``P_wc`` as GTSAM's, ``ReprojectionFactor(...,
  camera_to_world=True)``, the stock :class:`BetweenFactor`, and GPS ``t - z`` with Jacobian
  ``[R, 0]``.

In both: landmarks ``R(3)``, the calibration ``R(4)`` ``(fx, fy, cx, cy)`` with a
:class:`PriorFactor`, noise sigmas permuted to translation first. GTSAM's Cal3_S2 has a fifth
parameter, the skew, held at 0 by a prior of sigma 1e-6 px; the fixture records that term's
final cost (about 1e-11, below the 1e-6 relative tolerance by orders of magnitude).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from microlie import SE3
from microlie.optim import (
    BetweenFactor,
    CustomFactor,
    Diagonal,
    FactorGraph,
    Isotropic,
    PriorFactor,
    ReprojectionFactor,
    check_jacobians,
)
from microlie.optim.core.landmarks import landmark_batches

FIXTURE = Path(__file__).parent / "fixtures" / "optim" / "mixed_gtsam.json"
FORMS = ("T_cw", "T_wc")


@pytest.fixture(scope="module")
def fx() -> dict:
    return json.loads(FIXTURE.read_text())


def _hat(v: np.ndarray) -> np.ndarray:
    """``(m, 3) -> (m, 3, 3)`` skew-symmetric matrices."""
    H = np.zeros(v.shape[:-1] + (3, 3))
    H[..., 0, 1], H[..., 0, 2], H[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return H - np.swapaxes(H, -1, -2)


def between_cw(Ti: SE3, Tj: SE3, Zinv_params: np.ndarray):
    """``r = Log(Z^-1 T_i T_j^-1)``: GTSAM's BetweenFactorPose3 on ``P = T^-1``."""
    E = SE3(Zinv_params).compose(Ti).compose(Tj.inverse())
    r = E.log()
    A = SE3.jr_inv(r) @ Tj.adjoint()
    return r, [A, -A]


def gps_cw(T: SE3, z: np.ndarray):
    """``r = -R^T t - z`` (the camera centre of ``T_cw``), ``J = [-I, [c]x]``."""
    M = T.matrix()
    c = -np.einsum("mji,mj->mi", M[:, :3, :3], M[:, :3, 3])
    eye = np.broadcast_to(np.eye(3), (len(z), 3, 3))
    return c - z, [np.concatenate([-eye, _hat(c)], axis=2)]


def gps_wc(P: SE3, z: np.ndarray):
    """``r = t - z`` for ``P_wc = (R, t)``, ``J = [R, 0]`` (GTSAM's GPSFactor)."""
    M = P.matrix()
    return M[:, :3, 3] - z, [np.concatenate([M[:, :3, :3], np.zeros((len(z), 3, 3))], axis=2)]


def _poses(mats) -> SE3:
    return SE3.from_matrix(np.asarray(mats, dtype=float))


def build(fx: dict, form: str):
    """Our graph of the fixture's scene at its start: (graph, poses, points, K)."""
    sc = fx["scene"]
    st = sc["start"]
    g = FactorGraph()
    P0 = np.asarray(st["P_wc"], dtype=float)
    poses = g.add_variables(_poses(P0 if form == "T_wc" else np.linalg.inv(P0)))
    pts = g.add_variables(np.array(st["landmarks"]))
    K = g.add_variables(np.array([st["K"]]))
    ob = sc["observations"]
    cam, lm, uv = np.array(ob["camera"]), np.array(ob["landmark"]), np.array(ob["uv"])
    g.add(ReprojectionFactor((poses, cam), (pts, lm), uv, model="pinhole",
                             intrinsics=(K, np.zeros(len(cam), dtype=np.int64)),
                             noise=Isotropic(2, ob["sigma_px"]),
                             camera_to_world=form == "T_wc"))
    bt = sc["between"]["factors"]
    i, j = [b["i"] for b in bt], [b["j"] for b in bt]
    Z = _poses([np.block([[np.array(b["R"]), np.array(b["t"])[:, None]],
                          [np.zeros((1, 3)), np.ones((1, 1))]]) for b in bt])
    bn = Diagonal(sc["between"]["sigmas_microlie"])
    if form == "T_wc":
        g.add(BetweenFactor(poses, i, j, Z, bn))
    else:
        g.add(CustomFactor(between_cw, [(poses, i), (poses, j)], 6, bn,
                           data=[Z.inverse().params], jac="analytic"))
    gp = sc["gps"]["factors"]
    g.add(CustomFactor(gps_wc if form == "T_wc" else gps_cw, [(poses, [f["i"] for f in gp])],
                       3, Isotropic(3, sc["gps"]["sigma"]),
                       data=[np.array([f["position"] for f in gp])], jac="analytic"))
    cp = sc["calibration_prior"]
    g.add(PriorFactor(K, 0, np.array(cp["mean"]), Diagonal(cp["sigmas"])))
    return g, poses, pts, K


def solve(g: FactorGraph, linear_solver: str):
    """LM to a relative cost decrease of 1e-12 (5 iterations here, as GTSAM's). Not tighter:
    a further step decreases the cost by ~1e-16 relative, at its rounding floor, so whether it
    is accepted is a coin toss that differs between linear solvers, and it moves the weakly
    determined directions (the focal lengths) by up to 4e-7 px without changing the cost.
    GTSAM's damping (the identity), so that the iterates are GTSAM's: the default ("auto",
    ``diag(H)`` on a graph with reprojection factors) reaches the same cost (checked below) at
    a point up to 6e-7 px away in those directions."""
    return g.optimize(linear_solver=linear_solver, rel_tol=1e-12, abs_tol=1e-12, max_iter=100,
                      damping="identity")


def _T_cw(T: SE3, form: str) -> SE3:
    return T.inverse() if form == "T_wc" else T


def test_fixture_scene_is_what_the_doc_says(fx):
    sc = fx["scene"]
    assert sc["n_cameras"] == 16 and sc["n_points"] == 300
    assert len(sc["observations"]["camera"]) == 2907
    assert np.bincount(sc["observations"]["landmark"]).min() >= 3
    assert fx["gtsam"]["skew_prior_error"] < 1e-9 * fx["gtsam"]["final_error"]


@pytest.mark.parametrize("form", FORMS)
def test_factors_jacobians_match_finite_differences(fx, form):
    g, *_ = build(fx, form)
    for f in g.factors:
        assert check_jacobians(f).ok, f.name


@pytest.mark.parametrize("form", FORMS)
def test_initial_cost_equals_gtsam_error(fx, form):
    """Same objective at the same start: the conventions (pose inverse, tangent order, noise
    permutation, GPS on the camera centre) agree with GTSAM's."""
    g, *_ = build(fx, form)
    assert g.cost() == pytest.approx(fx["gtsam"]["initial_error"], rel=1e-10)


def _compare_to_gtsam(fx, res, poses, pts, K, form):
    ref = fx["gtsam"]
    assert res.converged, res.message
    assert res.final_cost == pytest.approx(ref["final_error"], rel=1e-6)
    assert res.initial_cost == pytest.approx(ref["initial_error"], rel=1e-10)
    T = _T_cw(res.values[poses], form)
    assert np.abs(_poses(ref["final"]["T_cw"]).inverse().compose(T).log()).max() < 1e-8
    assert np.abs(res.values[pts] - np.array(ref["final"]["landmarks"])).max() < 1e-8
    assert np.abs(res.values[K][0] - np.array(ref["final"]["K"])).max() < 1e-7


@pytest.mark.parametrize("form", FORMS)
def test_mixed_graph_one_call_schur_equals_cholesky_and_gtsam(fx, form):
    """The acceptance item: reprojection + odometry + GPS + calibration prior in one graph;
    linear_solver="cholesky" and "schur" agree to 1e-8 and reach GTSAM's optimum."""
    g, poses, pts, K = build(fx, form)
    assert landmark_batches(g.problem()) == [pts]      # what "schur" eliminates by default
    a = solve(g, "cholesky")
    b = solve(g, "schur")
    _compare_to_gtsam(fx, a, poses, pts, K, form)
    _compare_to_gtsam(fx, b, poses, pts, K, form)
    assert a.final_cost == pytest.approx(b.final_cost, rel=1e-8)
    assert np.abs(a.values[poses].inverse().compose(b.values[poses]).log()).max() < 1e-8
    assert np.abs(a.values[pts] - b.values[pts]).max() < 1e-8
    assert np.abs(a.values[K] - b.values[K]).max() < 1e-8
    default = g.optimize(linear_solver="schur", rel_tol=1e-12, abs_tol=1e-12)
    assert default.final_cost == pytest.approx(fx["gtsam"]["final_error"], rel=1e-12)
