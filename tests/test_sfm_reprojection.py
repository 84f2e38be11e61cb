"""ReprojectionFactor: residuals against independent projection formulas (Ceres'
SnavelyReprojectionError, OpenCV's radial-tangential pinhole) and BALProblem.residuals on
problem-49-7776; Jacobians against check_jacobians and a central difference on the 4x4 / 3x3
matrix exponential, at hard points; a small bundle-adjustment graph (SE3 or SO3 x R3 poses, LM
with GTSAM's rules on the full system) reaches bundle_adjust's optimum (trust region on the Schur
system)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import data_file
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from microlie import SE3, SO3
from microlie.optim import (
    BALProblem,
    FactorGraph,
    Isotropic,
    ReprojectionFactor,
    bundle_adjust,
    bundle_graph,
    check_jacobians,
    read_bal,
)
from microlie.optim.sfm.bundle import synthetic_scene

INTRINSICS = {
    "bal": np.array([480.0, -0.05, 0.02]),
    "pinhole": np.array([500.0, 520.0, 320.0, 240.0]),
    "pinhole-radtan": np.array([500.0, 520.0, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3]),
}
FORMS = ("SE3", "SO3xR3")


# ------------------------------------------------------------------ independent oracles

def project(model: str, P: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels of camera-frame points, written from the models' definitions (Ceres'
    SnavelyReprojectionError; OpenCV's projectPoints with k1, k2, p1, p2)."""
    if model == "bal":
        f, k1, k2 = K[..., 0], K[..., 1], K[..., 2]
        p = -P[..., :2] / P[..., 2:3]
        r2 = (p ** 2).sum(-1)
        return (f * (1.0 + k1 * r2 + k2 * r2 ** 2))[..., None] * p
    x, y = P[..., 0] / P[..., 2], P[..., 1] / P[..., 2]
    fx, fy, cx, cy = K[..., 0], K[..., 1], K[..., 2], K[..., 3]
    if model == "pinhole-radtan":
        k1, k2, p1, p2 = K[..., 4], K[..., 5], K[..., 6], K[..., 7]
        r2 = x * x + y * y
        radial = 1.0 + k1 * r2 + k2 * r2 * r2
        x, y = (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)
    return np.stack([fx * x + cx, fy * y + cy], -1)


def hat6(xi: np.ndarray) -> np.ndarray:
    """The 4x4 matrix of an se(3) tangent (rho, phi)."""
    rho, phi = xi[:3], xi[3:]
    M = np.zeros((4, 4))
    M[:3, :3] = [[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]]
    M[:3, 3] = rho
    return M


def scene(model: str, depths: np.ndarray, xy: np.ndarray, seed: int = 0):
    """World-to-camera transforms (R, t) and world points whose camera-frame coordinates
    are (xy, depth); BAL looks down -z, so its depths are negated by the caller's sign."""
    rng = np.random.default_rng(seed)
    n = len(depths)
    R = Rotation.random(n, random_state=seed).as_matrix()
    t = rng.normal(size=(n, 3))
    P = np.column_stack([xy, depths])
    X = np.einsum("nji,nj->ni", R, P - t)                # X = R^T (P - t)
    return R, t, X


def make_factor(model: str, form: str, R, t, X, K, obs, *, variable_K=True, behind="evaluate",
                c2w=False):
    """A graph of one camera per observation and the factor; returns (factor, values). ``R, t``
    are the world-to-camera transforms; with ``c2w`` the variables hold their inverses."""
    n = len(X)
    if c2w:
        R, t = np.swapaxes(R, 1, 2), -np.einsum("nji,nj->ni", R, t)
    g = FactorGraph()
    idx = np.arange(n)
    if form == "SE3":
        T = SE3.from_rotation_translation(SO3.from_matrix(R), t)
        pose = g.add_variables(T)
        pose_arg = (pose, idx)
        vals = [T]
    else:
        rot = g.add_variables(SO3.from_matrix(R))
        trans = g.add_variables(t)
        pose_arg = ((rot, idx), (trans, idx))
        vals = [SO3.from_matrix(R), t]
    pts = g.add_variables(X)
    vals.append(X)
    if variable_K:
        Kv = g.add_variables(K)
        intr = (Kv, idx)
        vals.append(K)
    else:
        intr = K
    f = ReprojectionFactor(pose_arg, (pts, idx), obs, model=model, intrinsics=intr,
                           behind=behind, camera_to_world=c2w)
    g.add(f)
    return f, vals


def hand_jacobians(model, form, R, t, X, K, h=1e-6, c2w=False):
    """Central differences of the oracle residual on the matrix exponential: right
    perturbation T expm(hat(xi)) for SE3, R expm(hat(phi)) for SO3, + h for vectors, of the
    pose variable T (T_cw = (R, t), or its inverse T_wc with ``c2w``)."""
    n = len(X)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, t
    if c2w:
        T = np.linalg.inv(T)

    def res(T_, X_, K_):
        Tcw = np.linalg.inv(T_) if c2w else T_
        P = np.einsum("nij,nj->ni", Tcw[:, :3, :3], X_) + Tcw[:, :3, 3]
        return project(model, P, K_)

    def dT(xi_cols):   # one perturbation matrix per observation
        return np.stack([expm(hat6(x)) for x in xi_cols])

    out = []
    dofs = (6,) if form == "SE3" else (3, 3)
    for part, d in enumerate(dofs):
        J = np.zeros((n, 2, d))
        for a in range(d):
            cols = []
            for s in (1.0, -1.0):
                xi = np.zeros((n, 6))
                if form == "SE3":
                    xi[:, a] = s * h
                    Tp = T @ dT(xi)
                elif part == 0:                    # rotation: R expm(hat(phi))
                    xi[:, 3 + a] = s * h
                    Tp = T.copy()
                    Tp[:, :3, :3] = T[:, :3, :3] @ dT(xi)[:, :3, :3]
                else:                              # translation: t + h e_a
                    Tp = T.copy()
                    Tp[:, a, 3] += s * h
                cols.append(res(Tp, X, K))
            J[:, :, a] = (cols[0] - cols[1]) / (2 * h)
        out.append(J)
    for which, base in (("X", X), ("K", K)):
        d = base.shape[1]
        J = np.zeros((n, 2, d))
        for a in range(d):
            step = h * max(1.0, float(np.abs(base[:, a]).max()))
            cols = []
            for s in (1.0, -1.0):
                v = base.copy()
                v[:, a] += s * step
                cols.append(res(T, v, K) if which == "X" else res(T, X, v))
            J[:, :, a] = (cols[0] - cols[1]) / (2 * step)
        out.append(J)
    return out


def hard_points(model: str):
    """Camera-frame (xy, depth) of ordinary points, points near the camera plane, on the
    optical axis and behind the camera (sign: the model's viewing direction)."""
    sign = -1.0 if model == "bal" else 1.0
    xy = np.array([[0.3, -0.2], [0.0, 0.0], [0.5, 0.4], [1e-3, -2e-3], [0.01, 0.02],
                   [-0.3, 0.2], [0.2, 0.1]])
    depth = sign * np.array([4.0, 3.0, 2.0, 1e-2, 2e-2, -3.0, -0.5])
    return xy, depth


# ------------------------------------------------------------------ Jacobians

@pytest.mark.parametrize("c2w", [False, True], ids=["T_cw", "T_wc"])
@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("model", list(INTRINSICS))
def test_jacobians_match_matrix_exponential_differences(model, form, c2w):
    xy, depth = hard_points(model)
    R, t, X = scene(model, depth, xy, seed=1)
    K = np.tile(INTRINSICS[model], (len(X), 1))
    obs = np.random.default_rng(2).normal(size=(len(X), 2))
    f, vals = make_factor(model, form, R, t, X, K, obs, c2w=c2w)
    r, Js = f.evaluate(vals, True)
    P = np.einsum("nij,nj->ni", R, X) + t
    np.testing.assert_allclose(r, project(model, P, K) - obs, rtol=1e-9, atol=1e-7)
    # near the plane the Jacobians reach 1e5 px per unit: compare relative to each row
    ref = hand_jacobians(model, form, R, t, X, K, c2w=c2w)
    for k, (Ja, Jn) in enumerate(zip(Js, ref, strict=True)):
        scale = np.maximum(1.0, np.abs(Jn).max(axis=2, keepdims=True))
        err = np.abs(Ja - Jn) / scale
        assert err.max() < 1e-6, (k, err.max())
    assert check_jacobians(f).ok
    assert check_jacobians(f, vals).ok


@pytest.mark.parametrize("c2w", [False, True], ids=["T_cw", "T_wc"])
@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("model", list(INTRINSICS))
def test_behind_drop_zero_rows_and_exact_jacobians(model, form, c2w):
    xy, depth = hard_points(model)
    depth = np.append(depth, 0.0)                   # one point exactly on the camera plane
    xy = np.vstack([xy, [0.1, 0.1]])
    R, t, X = scene(model, depth, xy, seed=4)
    R[-1], t[-1], X[-1] = np.eye(3), 0.0, [0.1, 0.1, 0.0]    # P_z = 0 exactly
    K = np.tile(INTRINSICS[model], (len(X), 1))
    obs = np.random.default_rng(5).normal(size=(len(X), 2))
    f, vals = make_factor(model, form, R, t, X, K, obs, behind="drop", c2w=c2w)
    with np.errstate(all="raise"):                  # no warning from the dropped rows
        r, Js = f.evaluate(vals, True)
    P = np.einsum("nij,nj->ni", R, X) + t
    front = P[:, 2] < 0 if model == "bal" else P[:, 2] > 0
    assert front.tolist() == [True] * 5 + [False] * 3
    with np.errstate(divide="ignore", invalid="ignore"):
        want = np.where(front[:, None], project(model, P, K) - obs, 0.0)
    np.testing.assert_allclose(r, want, rtol=1e-12, atol=1e-9)
    for J in Js:
        assert np.all(J[~front] == 0.0)
    # the dropped rows stay dropped under a small perturbation: finite differences agree
    keep = np.arange(7)                              # not the point exactly on the plane
    f2, vals2 = make_factor(model, form, R[keep], t[keep], X[keep], K[keep], obs[keep],
                            behind="drop", c2w=c2w)
    assert check_jacobians(f2, vals2).ok
    ref = hand_jacobians(model, form, R[keep], t[keep], X[keep], K[keep], c2w=c2w)
    for Ja, Jn in zip(f2.evaluate(vals2, True)[1], ref, strict=True):
        Jn = np.where(front[keep][:, None, None], Jn, 0.0)
        scale = np.maximum(1.0, np.abs(Jn).max(axis=2, keepdims=True))
        assert (np.abs(Ja - Jn) / scale).max() < 1e-6


def test_point_on_the_camera_plane_evaluated_is_infinite():
    R, t, X = np.eye(3)[None], np.zeros((1, 3)), np.array([[0.1, 0.2, 0.0]])
    f, vals = make_factor("pinhole", "SE3", R, t, X, INTRINSICS["pinhole"][None],
                          np.zeros((1, 2)))
    assert not np.all(np.isfinite(f.evaluate(vals, False)))


@pytest.mark.parametrize("model", list(INTRINSICS))
def test_constant_intrinsics(model):
    xy, depth = hard_points(model)
    R, t, X = scene(model, depth[:3], xy[:3], seed=6)
    K = INTRINSICS[model]
    obs = np.random.default_rng(7).normal(size=(3, 2))
    f, vals = make_factor(model, "SE3", R, t, X, K, obs, variable_K=False)
    assert len(f.args) == 2 and f.intrinsics.shape == (3, len(K))
    r, Js = f.evaluate(vals, True)
    P = np.einsum("nij,nj->ni", R, X) + t
    np.testing.assert_allclose(r, project(model, P, np.tile(K, (3, 1))) - obs, rtol=1e-12)
    assert [J.shape for J in Js] == [(3, 2, 6), (3, 2, 3)]
    assert check_jacobians(f).ok


@pytest.mark.parametrize("c2w", [False, True], ids=["T_cw", "T_wc"])
@pytest.mark.parametrize("form", FORMS)
def test_evaluate_into_matches_evaluate(form, c2w):
    xy, depth = hard_points("pinhole-radtan")
    R, t, X = scene("pinhole-radtan", depth, xy, seed=8)
    K = np.tile(INTRINSICS["pinhole-radtan"], (len(X), 1))
    f, vals = make_factor("pinhole-radtan", form, R, t, X, K, np.ones((len(X), 2)), c2w=c2w)
    r, Js = f.evaluate(vals, True)
    out = np.full((len(X), 2, 6 + 3 + 8), np.nan)
    r2 = f.evaluate_into(vals, out)
    np.testing.assert_array_equal(r2, r)
    np.testing.assert_array_equal(out, np.concatenate(Js, axis=2))


def test_float32_values_and_observations():
    xy, depth = hard_points("bal")
    R, t, X = scene("bal", depth[:3], xy[:3], seed=9)
    K = np.tile(INTRINSICS["bal"], (3, 1))
    obs32 = np.random.default_rng(10).normal(size=(3, 2)).astype(np.float32)
    f, vals = make_factor("bal", "SE3", R, t, X, K, obs32)
    assert f.observations.dtype == np.float64
    np.testing.assert_array_equal(f.observations, obs32.astype(np.float64))
    v32 = [SE3(np.asarray(vals[0].params, dtype=np.float32)), X.astype(np.float32),
           K.astype(np.float32)]
    c = check_jacobians(f, v32)                      # checked in float32: tol 1e-2
    assert c.ok and c.tol == 1e-2
    r = f.evaluate(v32, False)
    P = np.einsum("nij,nj->ni", R, X) + t
    np.testing.assert_allclose(r, project("bal", P, K) - obs32, rtol=1e-4, atol=1e-2)


def test_bad_input_names_the_argument():
    g = FactorGraph()
    T = g.add_variables(SE3.identity(2))
    rot = g.add_variables(SO3.identity(2))
    tr = g.add_variables(np.zeros((2, 3)))
    X = g.add_variables(np.ones((2, 3)))
    X2 = g.add_variables(np.ones((2, 2)))
    K = g.add_variables(np.tile([500.0, 0, 0], (2, 1)))
    K4 = g.add_variables(np.tile([500.0, 500, 0, 0], (2, 1)))
    obs = np.zeros((2, 2))
    ok = dict(intrinsics=(K, [0, 1]))
    cases = [
        (dict(pose=(rot, [0, 1])), "pose"),
        (dict(pose=((tr, [0, 1]), (rot, [0, 1]))), "pose"),
        (dict(pose=(T, [0, 1]), point=(X2, [0, 1])), "point"),
        (dict(pose=(T, [0, 1]), intrinsics=None), "intrinsics"),
        (dict(pose=(T, [0, 1]), intrinsics=(K4, [0, 1])), "intrinsics"),
        (dict(pose=(T, [0, 1]), intrinsics=[500.0, 0.0]), "intrinsics"),
        (dict(pose=(T, [0, 1]), observations=np.zeros((3, 2))), "observations"),
        (dict(pose=(T, [0, 1]), observations=np.array([[0.0, np.nan], [0, 0]])), "observations"),
        (dict(pose=(T, [0, 1]), behind="skip"), "behind"),
        (dict(pose=(T, [0, 1]), model="fisheye"), "model"),
        (dict(pose=(T, [0, 1]), camera_to_world="yes"), "camera_to_world"),
    ]
    for kw, word in cases:
        args = {"point": (X, [0, 1]), "observations": obs, **ok, **kw}
        with pytest.raises(ValueError, match=word):
            ReprojectionFactor(args.pop("pose"), args.pop("point"), args.pop("observations"),
                               **args)


# ------------------------------------------------------------------ residuals on BAL files

def snavely(bal: BALProblem) -> np.ndarray:
    """Ceres' SnavelyReprojectionError with scipy's angle-axis rotation."""
    c = bal.cameras[bal.camera_index]
    P = Rotation.from_rotvec(c[:, :3]).apply(bal.points[bal.point_index]) + c[:, 3:6]
    return project("bal", P, c[:, 6:9]) - bal.observations


def bal_graph(bal: BALProblem, form: str, behind: str = "evaluate"):
    g = FactorGraph()
    rot = SO3.exp(bal.cameras[:, :3])
    if form == "SE3":
        T = g.add_variables(SE3.from_rotation_translation(rot, bal.cameras[:, 3:6]))
        pose = (T, bal.camera_index)
    else:
        R = g.add_variables(rot)
        t = g.add_variables(bal.cameras[:, 3:6])
        pose = ((R, bal.camera_index), (t, bal.camera_index))
    K = g.add_variables(bal.cameras[:, 6:9])
    X = g.add_variables(bal.points)
    f = g.add(ReprojectionFactor(pose, (X, bal.point_index), bal.observations,
                                 intrinsics=(K, bal.camera_index), behind=behind))
    return g, f


@pytest.mark.parametrize("form", FORMS)
def test_residuals_equal_bal_problem_on_problem_49(form):
    bal = read_bal(data_file("bal/problem-49-7776-pre.txt"))
    g, f = bal_graph(bal, form)
    vals = [v.wrap(np.asarray(g.initial_values().params(v))[i]) for v, i in f.args]
    r = f.evaluate(vals, False)
    np.testing.assert_allclose(r, bal.residuals(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(r, snavely(bal), rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(g.cost(), bal.cost(), rtol=1e-12)
    gd, fd = bal_graph(bal, form, behind="drop")
    np.testing.assert_allclose(gd.cost(), bal.cost(behind="drop"), rtol=1e-12)
    assert gd.cost() < g.cost()
    # check_jacobians on the first 500 observations (a sub-batch of the same graph)
    sub = ReprojectionFactor(*_sub_args(f, 500), bal.observations[:500],
                             intrinsics=f.args[-1][0:1] + (f.args[-1][1][:500],))
    assert check_jacobians(sub).ok


def _sub_args(f: ReprojectionFactor, n: int):
    pose = (f.args[0][0], f.args[0][1][:n]) if f.pose_form == "SE3" else tuple(
        (v, i[:n]) for v, i in f.args[:2])
    point = f.args[-2][0], f.args[-2][1][:n]
    return pose, point


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("model", list(INTRINSICS))
def test_residuals_equal_bundle_problem_on_synthetic_scenes(model, form):
    _, start = synthetic_scene(5, 40, seed=11, model=model)
    g = FactorGraph()
    rot = SO3.from_matrix(start.rotations)
    cam, pt = start.camera_index, start.point_index
    if form == "SE3":
        pose = (g.add_variables(SE3.from_rotation_translation(rot, start.translations)), cam)
    else:
        pose = ((g.add_variables(rot), cam), (g.add_variables(start.translations), cam))
    K = g.add_variables(start.intrinsics)
    X = g.add_variables(start.points)
    f = g.add(ReprojectionFactor(pose, (X, pt), start.observations, model=model,
                                 intrinsics=(K, cam), noise=Isotropic(2, 2.0)))
    vals = [v.wrap(np.asarray(g.initial_values().params(v))[i]) for v, i in f.args]
    r = f.evaluate(vals, False)
    np.testing.assert_allclose(r, start.residuals(), rtol=1e-10, atol=1e-9)
    P = np.einsum("nij,nj->ni", start.rotations[cam], start.points[pt]) + start.translations[cam]
    np.testing.assert_allclose(r, project(model, P, start.intrinsics[cam]) - start.observations,
                               rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(g.cost(), start.cost() / 4.0, rtol=1e-12)   # sigma = 2 px
    assert check_jacobians(f).ok


# ------------------------------------------------------------------ solving

@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("model", ["bal", "pinhole-radtan"])
@pytest.mark.parametrize("robust", [None, "huber:1.0"])
def test_graph_reaches_bundle_adjust_optimum(model, form, robust):
    _, start = synthetic_scene(4, 30, noise=1.0, perturb=0.03, seed=12, model=model)
    # BAL: camera 1's intrinsics held; radial-tangential: all held (8 free intrinsics per
    # camera on 30 points converge in ~170 iterations)
    held = [1] if model == "bal" else [0, 1, 2, 3]
    ref = bundle_adjust(start, fix_cameras=[0], fix_points=[0], robust=robust, max_iter=200,
                        fix_intrinsics=held, function_tolerance=1e-13, parameter_tolerance=1e-13,
                        gradient_tolerance=1e-12)
    g = FactorGraph()
    cam, pt = start.camera_index, start.point_index
    rot = SO3.from_matrix(start.rotations)
    if form == "SE3":
        T = g.add_variables(SE3.from_rotation_translation(rot, start.translations), fixed=[0])
        pose = (T, cam)
    else:
        pose = ((g.add_variables(rot, fixed=[0]), cam),
                (g.add_variables(start.translations, fixed=[0]), cam))
    K = g.add_variables(start.intrinsics)
    g.fix(K, held)
    X = g.add_variables(start.points, fixed=[0])
    g.add(ReprojectionFactor(pose, (X, pt), start.observations, model=model,
                             intrinsics=(K, cam), loss=robust))
    res = g.optimize(max_iter=200, rel_tol=1e-14, abs_tol=0.0)
    assert ref.converged and res.converged
    np.testing.assert_allclose(res.final_robust_cost, ref.final_robust_cost, rtol=1e-9)
    np.testing.assert_allclose(res.final_cost, ref.final_cost, rtol=1e-6)  # not stationary
    solved = start.with_values(ref.values)
    np.testing.assert_allclose(res.values[X], solved.points, rtol=0, atol=1e-6)
    np.testing.assert_allclose(res.values[K], solved.intrinsics, rtol=1e-5, atol=1e-5)


# ------------------------------------------------------------ the engine path of bundle_adjust

def test_engine_reaches_ceres_on_problem_49():
    """bundle_graph + TrustRegion + Schur: problem-49-7776's Ceres optimum (13344.3184, the
    data README's reference) in Ceres' 31 iterations."""
    from microlie.optim import TrustRegion, bundle_graph

    bg = bundle_graph(read_bal(data_file("bal/problem-49-7776-pre.txt")))
    res = bg.graph.optimize(solver=TrustRegion(), linear_solver="schur", gauge="none")
    assert res.final_cost == pytest.approx(13344.3184, rel=1e-6)
    assert res.iterations == 31 and res.converged
    assert bg.problem(res.values).cost() == pytest.approx(res.final_cost, rel=1e-12)


def test_intrinsics_held_per_component():
    """g.fix(K, components=[1, 2]) holds k1, k2 of every camera exactly; the focal lengths
    reach a stationary point of the cost (central differences of g.cost)."""
    from microlie.optim import TrustRegion, bundle_graph

    _, start = synthetic_scene(4, 30, noise=1.0, perturb=0.03, seed=14)
    start = replace(start, intrinsics=start.intrinsics * [1.02, 1.0, 1.0])
    bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
    bg.graph.fix(bg.intrinsics, components=[1, 2])
    res = bg.graph.optimize(solver=TrustRegion(function_tolerance=1e-14), linear_solver="schur")
    K = np.asarray(res.values[bg.intrinsics])
    np.testing.assert_array_equal(K[:, 1:], start.intrinsics[:, 1:])
    assert np.all(np.abs(K[:, 0] - start.intrinsics[:, 0]) > 1.0)

    def cost_at(f: np.ndarray) -> float:
        p = bg.problem(res.values)
        return replace(p, intrinsics=np.column_stack([f, p.intrinsics[:, 1:]])).cost()

    h = 1e-3
    grad = [(cost_at(K[:, 0] + h * e) - cost_at(K[:, 0] - h * e)) / (2 * h) for e in np.eye(4)]
    grad0 = [(cost_at(start.intrinsics[:, 0] + h * e) - cost_at(start.intrinsics[:, 0] - h * e))
             / (2 * h) for e in np.eye(4)]
    assert np.max(np.abs(grad)) < 1e-5 * max(1.0, np.max(np.abs(grad0)))


@pytest.mark.parametrize("robust", [None, "huber:1.0"])
def test_assembly_equals_numpy_and_the_cost_gradient(robust, monkeypatch):
    """Problem.linearize on a bundle graph: the compiled products of microlie._c._normal
    (when installed) and NumPy's matmul and bincount assemble the same H and g (to rounding),
    and g equals the central differences of the (robust) cost."""
    _, start = synthetic_scene(3, 12, noise=1.0, perturb=0.05, seed=4)
    p = bundle_graph(start, robust=robust).graph.problem(gauge="none")
    states = [v.initial for v in p.variables]
    lin = p.linearize(states)
    monkeypatch.setenv("MICROLIE_FAST", "0")
    ref = p.linearize(states)
    # bit for bit where NumPy's matmul runs BLAS kernels with fused multiply-adds (x86-64
    # OpenBLAS); to rounding elsewhere
    np.testing.assert_allclose(lin.data, ref.data, rtol=1e-14, atol=1e-14 * np.abs(ref.data).max())
    np.testing.assert_allclose(lin.grad, ref.grad, rtol=1e-14, atol=1e-14 * np.abs(ref.grad).max())
    n, h = lin.grad.size, 1e-6
    fd = [(p.costs(p.retract(states, h * e))[1] - p.costs(p.retract(states, -h * e))[1])
          / (2 * h) for e in np.eye(n)]
    np.testing.assert_allclose(lin.grad, fd, rtol=1e-5, atol=1e-6 * np.abs(lin.grad).max())
