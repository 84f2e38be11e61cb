"""The generic group test suite: every check runs on every group (conftest.GROUPS) and, where it
concerns values, on every backend (NumPy, PyTorch, JAX) and dtype.

References are independent of the code under test: SciPy's matrix exponential and logarithm,
central finite differences on the group, and the group axioms.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    GROUPS,
    element,
    fd_jacobian,
    hard_elements,
    require,
    rotation_angle,
    tangent_with_angle,
    to_backend,
    to_numpy,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm, logm

from microlie import SE2, SE3, SE23, SO2, SO3, LieGroup, Sim3

HARD_ANGLES = {"random": None, "tiny": 1e-9, "near_pi": np.pi - 1e-4}


def seeds():
    return st.integers(0, 2**32 - 1)


def random_tangent(G, rng, scale=1.0, size=None):
    theta = rng.uniform(0.0, np.pi - 1e-3) * min(scale, 1.0)
    return tangent_with_angle(G, rng, theta, size)


# ------------------------------------------------------------------------ axioms


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@settings(max_examples=25, deadline=None)
@given(seed=seeds())
def test_group_axioms(G, seed):
    rng = np.random.default_rng(seed)
    X, Y, Z = (G.exp(random_tangent(G, rng)) for _ in range(3))
    E = G.identity()
    M = lambda A: A.matrix()  # noqa: E731
    np.testing.assert_allclose(M((X @ Y) @ Z), M(X @ (Y @ Z)), atol=1e-12)  # associativity
    np.testing.assert_allclose(M(X @ E), M(X), atol=1e-15)
    np.testing.assert_allclose(M(E @ X), M(X), atol=1e-15)
    np.testing.assert_allclose(M(X @ X.inverse()), np.eye(G.matrix_dim), atol=1e-13)
    np.testing.assert_allclose(M(X.inverse() @ X), np.eye(G.matrix_dim), atol=1e-13)
    # the representation is a homomorphism: matrix(X Y) = matrix(X) matrix(Y)
    np.testing.assert_allclose(M(X @ Y), M(X) @ M(Y), atol=1e-12)
    # action is compatible with composition and with the matrix
    p = rng.standard_normal(G.point_dim)
    np.testing.assert_allclose((X @ Y).act(p), X.act(Y.act(p)), atol=1e-12)
    # homogeneous point (SE23's 5x5 matrix: (p, 1, 0))
    ph = np.concatenate([p, np.eye(G.matrix_dim - G.point_dim)[0]]) \
        if G.matrix_dim > G.point_dim else p
    np.testing.assert_allclose(X.act(p), (M(X) @ ph)[: G.point_dim], atol=1e-12)


# ------------------------------------------------------------------------ Exp / Log vs SciPy


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@settings(max_examples=30, deadline=None)
@given(seed=seeds())
def test_exp_log_against_scipy_expm_logm(G, seed):
    rng = np.random.default_rng(seed)
    tau = random_tangent(G, rng)
    X = G.exp(tau)
    np.testing.assert_allclose(X.matrix(), expm(G.hat(tau)), atol=1e-12, rtol=1e-12)
    if np.all(np.pi - rotation_angle(G, tau) > 1e-2):
        L = np.real(logm(X.matrix()))
        np.testing.assert_allclose(G.hat(X.log()), L, atol=1e-9)
    np.testing.assert_allclose(G.vee(G.hat(tau)), tau, atol=1e-15)


def test_exp_log_backends_and_dtypes(group, backend):
    G = group
    rng = np.random.default_rng(1)
    tau = np.stack([random_tangent(G, rng) for _ in range(6)])
    ref = expm(G.hat(tau))
    for dtype, tol in ((np.float64, 1e-12), (np.float32, 2e-6)):
        t = to_backend(tau, backend, dtype)
        X = G.exp(t)
        assert type(X.params) is type(t)
        assert str(X.params.dtype).endswith(np.dtype(dtype).name)
        np.testing.assert_allclose(to_numpy(X.matrix()), ref, atol=tol * 10)
        np.testing.assert_allclose(to_numpy(X.log()), tau, atol=tol * 10)


# ------------------------------------------------------------------------ adjoint identities


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@settings(max_examples=25, deadline=None)
@given(seed=seeds())
def test_adjoint_identity_eq15(G, seed):
    rng = np.random.default_rng(seed)
    X = G.exp(random_tangent(G, rng))
    tau = 0.5 * random_tangent(G, rng)
    Ad = X.adjoint()
    # X Exp(tau) = Exp(Ad_X tau) X
    np.testing.assert_allclose((X @ G.exp(tau)).matrix(), (G.exp(Ad @ tau) @ X).matrix(),
                               atol=1e-12)
    # Ad_X tau = vee(X hat(tau) X^-1)
    Xm = X.matrix()
    np.testing.assert_allclose(Ad @ tau, G.vee(Xm @ G.hat(tau) @ np.linalg.inv(Xm)), atol=1e-12)
    np.testing.assert_allclose(X.inverse().adjoint(), np.linalg.inv(Ad), atol=1e-12)


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@pytest.mark.parametrize("where", list(HARD_ANGLES))
def test_left_right_jacobian_relations(G, where):
    rng = np.random.default_rng(2)
    for _ in range(5):
        theta = HARD_ANGLES[where]
        tau = random_tangent(G, rng) if theta is None else tangent_with_angle(G, rng, theta)
        Jr, Jl = G.jr(tau), G.jl(tau)
        np.testing.assert_allclose(Jl, G.exp(tau).adjoint() @ Jr, atol=1e-12)
        np.testing.assert_allclose(Jl, G.jr(-tau), atol=1e-15)
        np.testing.assert_allclose(Jr @ G.jr_inv(tau), np.eye(G.dof), atol=1e-11)
        np.testing.assert_allclose(Jl @ G.jl_inv(tau), np.eye(G.dof), atol=1e-11)


def test_jr_closed_forms_match_generic_series(group):
    """Where a group has a closed-form Jr, the generic int_0^1 Ad_Exp(-s tau) ds agrees."""
    G = group
    rng = np.random.default_rng(3)
    for theta in (0.0, 1e-9, 0.3, 2.0, np.pi - 1e-4):
        tau = tangent_with_angle(G, rng, theta, 4)
        np.testing.assert_allclose(G.jr(tau), G._jr_series(tau), atol=1e-12)


def test_small_adjoint_is_the_bracket(group):
    G = group
    rng = np.random.default_rng(4)
    a, b = rng.standard_normal((2, G.dof))
    ha, hb = G.hat(a), G.hat(b)
    np.testing.assert_allclose(G.ad(a) @ b, G.vee(ha @ hb - hb @ ha), atol=1e-14)
    np.testing.assert_allclose(G.bracket(a, b), -G.bracket(b, a), atol=1e-14)
    # d/dt Ad_Exp(t a) at t = 0 is ad_a
    h = 1e-6
    d = (G.exp(h * a).adjoint() - G.exp(-h * a).adjoint()) / (2 * h)
    np.testing.assert_allclose(G.ad(a), d, atol=1e-8)


# ------------------------------------------------------------------------ all Jacobians vs FD


def _builders(G, rng, theta):
    """Inputs for each operation, with the relevant rotation angle equal to ``theta``."""
    def tan():
        return random_tangent(G, rng) if theta is None else tangent_with_angle(G, rng, theta)

    def el():
        return G.exp(tan())

    X = el()
    return {
        "inverse": [X],
        "compose": [X, el()],
        "between": [X, X @ G.exp(tan())],
        "act": [X, rng.standard_normal(G.point_dim)],
        "exp": [tan()],
        "log": [X],
        "plus": [el(), tan()],
        "minus": [X @ G.exp(tan()), X],
        "lplus": [el(), tan()],
        "lminus": [G.exp(tan()) @ X, X],
    }


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@pytest.mark.parametrize("where", list(HARD_ANGLES))
@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("bk", ["numpy", "torch", "jax"])
@settings(max_examples=3, deadline=None)
@given(seed=seeds())
def test_every_jacobian_against_finite_differences(G, where, side, bk, seed):
    """Analytic Jacobians (computed on each backend, float64) against central finite
    differences on the group (NumPy): relative error <= 1e-6."""
    backend_fixture_check(bk)
    rng = np.random.default_rng(seed)
    for op, args in _builders(G, rng, HARD_ANGLES[where]).items():
        _check_against_fd(G, op, args, side, bk, where)


def _check_against_fd(G, op, args, side, bk, where):
    """``op(*args, jac=True)`` on backend ``bk`` against :func:`fd_jacobian` (NumPy)."""
    bargs = [element(G, x.params, bk) if isinstance(x, LieGroup) else to_backend(x, bk)
             for x in args]
    if op == "exp":
        f = lambda t: G.exp(t)  # noqa: E731
        res = G.exp(bargs[0], jac=True, side=side)
    else:
        f = lambda *a: getattr(a[0], op)(*a[1:])  # noqa: E731
        res = getattr(bargs[0], op)(*bargs[1:], jac=True, side=side)
    jacs = [to_numpy(J) for J in res[1:]]
    assert len(jacs) == len(args)
    for i, J in enumerate(jacs):
        J_fd = fd_jacobian(f, args, i, side=side)
        err = np.abs(J - J_fd).max() / max(1.0, np.abs(J_fd).max())
        assert err <= 1e-6, f"{G.__name__}.{op} d/darg{i} ({side}, {where}): {err:.2e}"


def _hard_cases(G, rng):
    """``(op, args)`` pairs with a hard element (conftest.hard_elements) as the group input.
    ``Log`` of an element within the finite-difference step of pi is not differentiable (it
    jumps to the other side), so ``log`` is taken at the near-identity element only; ``minus``
    and ``lminus`` take hard elements as inputs and small differences as outputs."""
    cases = []
    small = lambda: 0.3 * tangent_with_angle(G, rng, 0.4)  # noqa: E731
    for name, H in hard_elements(G, rng).items():
        Y = G.exp(random_tangent(G, rng))
        cases += [(name, "inverse", [H]), (name, "compose", [H, Y]), (name, "compose", [Y, H]),
                  (name, "between", [H, H @ G.exp(small())]),
                  (name, "act", [H, rng.standard_normal(G.point_dim)]),
                  (name, "plus", [H, small()]), (name, "lplus", [H, small()]),
                  (name, "minus", [H @ G.exp(small()), H]),
                  (name, "lminus", [G.exp(small()) @ H, H])]
        if name == "near_identity":
            cases.append((name, "log", [H]))
    for theta in (np.pi - 2e-11, np.pi, 1e-9):
        cases.append((f"angle {theta}", "exp", [tangent_with_angle(G, rng, theta)]))
    return cases


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("bk", ["numpy", "torch", "jax"])
def test_jacobians_at_hard_elements_against_finite_differences(G, side, bk):
    """Every Jacobian at a near-identity element and Sophus-style hard elements (angle exactly
    pi, built exactly and by composition; quaternion w ~ 1e-11), on every backend."""
    backend_fixture_check(bk)
    rng = np.random.default_rng(26)
    for name, op, args in _hard_cases(G, rng):
        _check_against_fd(G, op, args, side, bk, name)


def backend_fixture_check(bk):
    if bk == "torch":
        require("torch")
    elif bk == "jax":
        require("jax").config.update("jax_enable_x64", True)


def test_jacobians_on_backends_match_numpy(group, backend):
    """The analytic Jacobians computed on torch/JAX arrays equal the NumPy ones (float64), and
    float32 stays float32 within float32 accuracy."""
    G = group
    rng = np.random.default_rng(5)
    args = _builders(G, rng, None)
    for op, a in args.items():
        ref = _jac_call(G, op, a)
        for dtype, tol in ((np.float64, 1e-12), (np.float32, 2e-4)):
            conv = [element(G, x.params, backend, dtype) if isinstance(x, LieGroup)
                    else to_backend(x, backend, dtype) for x in a]
            out = _jac_call(G, op, conv)
            for r, o in zip(ref, out, strict=True):
                np.testing.assert_allclose(to_numpy(o), to_numpy(r), atol=tol * 10,
                                           err_msg=f"{op} {backend} {dtype}")


def _jac_call(G, op, a):
    if op == "exp":
        return G.exp(a[0], jac=True)
    return getattr(a[0], op)(*a[1:], jac=True)


# ------------------------------------------------------------------------ precision


PREC_ANGLES = [0.0, 1e-300, 1e-12, 1e-8, 1e-4, 0.1, 1.0, 3.0, np.pi - 1e-6, np.pi - 1e-9]


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@pytest.mark.parametrize("bk", ["numpy", "torch", "jax"])
def test_log_exp_roundtrip_float64(G, bk):
    backend_fixture_check(bk)
    rng = np.random.default_rng(6)
    for theta in PREC_ANGLES:
        tau = tangent_with_angle(G, rng, theta, 50)
        back = to_numpy(G.exp(to_backend(tau, bk)).log())
        assert np.abs(back - tau).max() <= 1e-12, (theta, np.abs(back - tau).max())
        # single elements take the scalar path: same precision
        for t in tau[:5]:
            assert np.abs(G.exp(t).log() - t).max() <= 1e-12


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_exp_log_roundtrip_float64(G):
    rng = np.random.default_rng(7)
    X = G.random(2000, rng=rng)
    assert _matrix_error(G.exp(X.log()), X) <= 1e-14
    for d in (1e-12, 1e-13, 0.0):  # within 1e-12 of pi, and exactly pi
        tau = tangent_with_angle(G, rng, np.pi - d, 200)
        X = G.exp(tau)
        L = X.log()
        assert np.all(np.isfinite(L))
        assert np.all(rotation_angle(G, L) <= np.pi + 1e-15)
        assert _matrix_error(G.exp(L), X) <= 1e-14


def _matrix_error(X, Y):
    """Max-norm matrix error; relative to the largest entry where translations/scales make
    entries larger than 1 (poses), absolute for rotations."""
    a, b = X.matrix(), Y.matrix()
    return np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b).max(axis=(-1, -2), keepdims=True)))


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_exactly_pi_has_valid_log(G):
    # a rotation by exactly pi built without rounding (the class's test fact)
    X = G._exact_pi_element()
    rot = X if not hasattr(G, "_rotation") else X.rotation()
    np.testing.assert_array_equal(rot.params, type(rot)._exact_pi_element().params)
    L = X.log()
    assert np.isclose(rotation_angle(G, L), np.pi, atol=1e-15)
    np.testing.assert_allclose(G.exp(L).matrix(), X.matrix(), atol=1e-14)


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@pytest.mark.parametrize("bk", ["numpy", "torch", "jax"])
def test_roundtrips_float32_on_backends(G, bk):
    backend_fixture_check(bk)
    rng = np.random.default_rng(18)
    for theta in [*PREC_ANGLES[:-2], np.pi - 1e-6]:
        tau = tangent_with_angle(G, rng, theta, 50).astype(np.float32)
        tau = tau[rotation_angle(G, tau.astype(np.float64)) <= np.pi]
        back = G.exp(to_backend(tau, bk, np.float32)).log()
        assert str(back.dtype).endswith("float32")
        assert np.abs(to_numpy(back) - tau).max() <= 1e-5


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_roundtrips_float32(G):
    rng = np.random.default_rng(8)
    pi32 = float(np.nextafter(np.float32(np.pi), np.float32(0)))  # largest float32 below pi
    for theta in [*PREC_ANGLES[:-2], np.pi - 1e-6]:
        tau = tangent_with_angle(G, rng, theta, 50).astype(np.float32)
        # the float32 rounding of the vector may change its angle: keep it at most pi
        tau = tau[rotation_angle(G, tau.astype(np.float64)) <= np.pi]
        back = G.exp(tau).log()
        assert back.dtype == np.float32
        assert np.abs(back - tau).max() <= 1e-5, (theta, np.abs(back - tau).max())
    # at pi to float32 precision the two logarithms (+-axis) are equally valid: check the
    # element instead
    X = G.exp(tangent_with_angle(G, rng, pi32, 50).astype(np.float32))
    assert _matrix_error(G.exp(X.log()), X) <= 1e-5
    X = G.random(2000, rng=rng, dtype=np.float32)
    assert X.dtype == np.float32
    assert np.abs(G.exp(X.log()).matrix() - X.matrix()).max() <= 1e-5


# ------------------------------------------------------------------------ batches


def _all_outputs(G, X, Y, tau, p):
    """Every operation and every Jacobian, flattened to a list of arrays."""
    outs = [G.exp(tau, jac=True), X.log(jac=True), X.inverse(jac=True), X.compose(Y, jac=True),
            X.between(Y, jac=True), X.act(p, jac=True), X.plus(tau, jac=True),
            Y.minus(X, jac=True), X.lplus(tau, jac=True), Y.lminus(X, jac=True),
            X.minus(Y, jac=True, side="left")]
    flat = [to_numpy(o) for res in outs for o in res]
    return flat + [to_numpy(X.adjoint()), to_numpy(X.matrix()), to_numpy(G.jr(tau)),
                   to_numpy(G.jr_inv(tau))]


def test_batch_shapes_equal_elementwise(group, backend, batch_shape):
    """Batch shapes (), (1,) and (3, 1, 2): every operation and Jacobian has the batch shape
    in front and equals the single-element (scalar path) result element by element."""
    G = group
    rng = np.random.default_rng(9)
    X, Y = G.random(batch_shape, rng=rng), G.random(batch_shape, rng=rng)
    tau = 0.7 * rng.standard_normal((*batch_shape, G.dof))
    p = rng.standard_normal((*batch_shape, G.point_dim))
    batched = _all_outputs(G, element(G, X.params, backend), element(G, Y.params, backend),
                           to_backend(tau, backend), to_backend(p, backend))
    for idx in np.ndindex(*batch_shape):
        x = G(X.params[idx]) if idx else X
        y = G(Y.params[idx]) if idx else Y
        single = _all_outputs(G, x, y, tau[idx], p[idx])
        for k, (b, v) in enumerate(zip(batched, single, strict=True)):
            assert b.shape == (*batch_shape, *v.shape), k
            np.testing.assert_allclose(b[idx], v, atol=1e-13, rtol=1e-13, err_msg=str(k))


def test_broadcasting(group, backend):
    G = group
    rng = np.random.default_rng(10)
    X = G.random((4, 1), rng=rng)
    Y = G.random((1, 5), rng=rng)
    Z = element(G, X.params, backend) @ element(G, Y.params, backend)
    assert Z.batch_shape == (4, 5)
    for i in range(4):
        for j in range(5):
            np.testing.assert_allclose(to_numpy(Z[i, j]), (X[i, 0] @ Y[0, j]).params,
                                       atol=1e-14)
    # a single element against a batch, and Jacobians broadcast too
    Z2, J1, J2 = X[0, 0].compose(Y, jac=True)
    assert Z2.batch_shape == (1, 5) and J1.shape == (1, 5, G.dof, G.dof)
    assert J2.shape == (1, 5, G.dof, G.dof)
    pts = rng.standard_normal((7, G.point_dim))
    assert X[0, 0].act(pts).shape == (7, G.point_dim)


def test_indexing_and_iteration(group):
    G = group
    X = G.random((3, 2), rng=0)
    assert X[1].batch_shape == (2,)
    assert X[:, 0].batch_shape == (3,)
    assert len(X) == 3 and len(list(X)) == 3
    with pytest.raises(IndexError):
        X[0, 0][0]
    with pytest.raises(AttributeError):
        X.params = None


# ------------------------------------------------------------------------ interpolation


def test_interpolate(group):
    G = group
    rng = np.random.default_rng(11)
    X, Y = G.random(rng=rng), G.random(rng=rng)
    np.testing.assert_allclose(X.interpolate(Y, 0.0).matrix(), X.matrix(), atol=1e-14)
    np.testing.assert_allclose(X.interpolate(Y, 1.0).matrix(), Y.matrix(), atol=1e-12)
    # the midpoint is the geodesic midpoint: equal right distances to both ends
    Mid = X.interpolate(Y, 0.5)
    np.testing.assert_allclose(Mid.minus(X), Y.minus(Mid), atol=1e-12)
    ts = np.linspace(0, 1, 5)
    assert X.interpolate(Y, ts).batch_shape == (5,)


# ------------------------------------------------------------------------ bad input


def test_bad_input_raises_value_error(group):
    G = group
    with pytest.raises(ValueError, match="shape"):
        G(np.zeros(G.param_dim + 1))
    with pytest.raises(ValueError, match="shape"):
        G.exp(np.zeros(G.dof + 1))
    bad = np.array(G._identity_params)
    bad[0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        G(bad)
    t = np.zeros(G.dof)
    t[-1] = np.inf
    with pytest.raises(ValueError, match="NaN or infinite"):
        G.exp(t)
    with pytest.raises(ValueError, match="shape"):
        G.identity().act(np.zeros(G.point_dim + 1))
    with pytest.raises(ValueError, match="side"):
        G.identity().log(jac=True, side="middle")
    with pytest.raises(TypeError):
        G.identity() @ (SO3 if G is not SO3 else SE3).identity()


def test_rotation_validation():
    R = np.diag([1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="not orthogonal"):
        SO3.from_matrix(R + 1e-3)
    with pytest.raises(ValueError, match="determinant -1"):
        SO3.from_matrix(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="norm differs from 1"):
        SO3.from_quat([0.0, 0.0, 0.0, 1.1])
    with pytest.raises(ValueError, match="zero quaternion"):
        SO3.from_quat([0.0, 0.0, 0.0, 0.0], normalize=True)
    with pytest.raises(ValueError, match="NaN"):
        SO3.from_quat([np.nan, 0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="determinant -1"):
        SO2.from_matrix(np.diag([1.0, -1.0]))
    with pytest.raises(ValueError, match="not orthogonal"):
        SE2.from_matrix(np.array([[1.0, 0.1, 0], [0, 1.0, 0], [0, 0, 1]]))
    with pytest.raises(ValueError, match="last row"):
        SE3.from_matrix(np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]]))
    with pytest.raises(ValueError, match="scale must be positive"):
        Sim3(np.array([0, 0, 0, 0, 0, 0, 1.0, -2.0]))
    # repair only on request: normalize=True projects onto the group
    rng = np.random.default_rng(12)
    Rn = SO3.random(rng=rng).matrix() + 1e-3 * rng.standard_normal((3, 3))
    X = SO3.from_matrix(Rn, normalize=True)
    U, _, Vt = np.linalg.svd(Rn)
    np.testing.assert_allclose(X.matrix(), U @ Vt, atol=1e-14)
    q = SO3.from_quat([0.0, 0.0, 0.0, 2.0], normalize=True).as_quat()
    np.testing.assert_allclose(q, [0, 0, 0, 1.0])


def test_near_orthogonal_rounding_is_accepted_and_exact():
    """A rotation matrix with a rounding-level defect (pinocchio#2768) gives a finite log."""
    rng = np.random.default_rng(13)
    R = SO3.random(100, rng=rng).matrix() * (1 + 2e-16)
    X = SO3.from_matrix(R)
    assert np.all(np.isfinite(X.log()))
    np.testing.assert_allclose(X.matrix(), R, atol=1e-15)


# ------------------------------------------------------------------------ constructors


def test_quaternion_and_rotation_constructors_against_scipy():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(14)
    X = SO3.random(50, rng=rng)
    ref = Rotation.from_quat(X.as_quat())
    np.testing.assert_allclose(X.matrix(), ref.as_matrix(), atol=1e-15)
    np.testing.assert_allclose(X.as_rotvec(), ref.as_rotvec(), atol=1e-13)
    np.testing.assert_allclose(SO3.from_rotvec(ref.as_rotvec()).matrix(), ref.as_matrix(),
                               atol=1e-14)
    wxyz = X.as_quat(scalar_first=True)
    np.testing.assert_allclose(wxyz, ref.as_quat(scalar_first=True), atol=0)
    np.testing.assert_allclose(SO3.from_quat(wxyz, scalar_first=True).params, X.params)
    np.testing.assert_allclose(SO3.from_matrix(ref.as_matrix()).matrix(), ref.as_matrix(),
                               atol=1e-15)
    for seq in ("xyz", "ZYX", "zxz", "XYX"):
        ang = rng.uniform(-1.5, 1.5, (20, 3))
        np.testing.assert_allclose(SO3.from_euler(seq, ang).matrix(),
                                   Rotation.from_euler(seq, ang).as_matrix(), atol=1e-14)
        np.testing.assert_allclose(X.as_euler(seq), ref.as_euler(seq), atol=1e-12)
    rpy = X.as_rpy()
    np.testing.assert_allclose(rpy, ref.as_euler("xyz"), atol=1e-12)
    np.testing.assert_allclose(SO3.from_rpy(*rpy.T).matrix(), X.matrix(), atol=1e-14)
    np.testing.assert_allclose(SO3.from_euler("xyz", [90, 0, 0], degrees=True).matrix(),
                               [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)
    # q and -q are the same rotation; canonical picks w >= 0
    q = -X.as_quat()
    np.testing.assert_allclose(SO3.from_quat(q).matrix(), X.matrix(), atol=1e-15)
    assert np.all(SO3.from_quat(q).as_quat(canonical=True)[:, 3] >= 0)


def test_pose_constructors_and_accessors():
    rng = np.random.default_rng(15)
    R = SO3.random(4, rng=rng)
    t = rng.standard_normal((4, 3))
    T = SE3.from_rotation_translation(R, t)
    np.testing.assert_allclose(T.translation(), t)
    np.testing.assert_allclose(T.rotation().matrix(), R.matrix())
    np.testing.assert_allclose(SE3.from_matrix(T.matrix()).matrix(), T.matrix(), atol=1e-15)
    S = Sim3.from_rotation_translation_scale(R, t, [0.5, 1.0, 2.0, 3.0])
    np.testing.assert_allclose(S.scale(), [0.5, 1.0, 2.0, 3.0])
    np.testing.assert_allclose(S.matrix()[:, :3, :3], S.scale()[:, None, None] * R.matrix())
    np.testing.assert_allclose(Sim3.from_matrix(S.matrix()).matrix(), S.matrix(), atol=1e-14)
    P = SE2.from_xy_theta([1.0, 2.0], [3.0, 4.0], [0.5, -3.0])
    np.testing.assert_allclose(P.angle(), [0.5, -3.0], atol=1e-15)
    np.testing.assert_allclose(P.translation(), [[1, 3], [2, 4.0]])
    np.testing.assert_allclose(SO2.from_angle([0.1, 3.1]).angle(), [0.1, 3.1], atol=1e-15)
    np.testing.assert_allclose(SE2.from_matrix(P.matrix()).params, P.params, atol=1e-15)


def test_sim3_at_sigma_zero_equals_se3():
    rng = np.random.default_rng(16)
    tau = tangent_with_angle(SE3, rng, 1.3, 10)
    z = np.concatenate([tau, np.zeros((10, 1))], -1)
    np.testing.assert_allclose(Sim3.exp(z).matrix(), SE3.exp(tau).matrix(), atol=1e-14)
    np.testing.assert_allclose(Sim3.jr(z)[:, :6, :6], SE3.jr(tau), atol=1e-13)
    # scale alone
    s = Sim3.exp(np.array([1.0, 2.0, 3.0, 0, 0, 0, 0.7]))
    np.testing.assert_allclose(s.translation(), np.expm1(0.7) / 0.7 * np.array([1.0, 2, 3]))


@pytest.mark.parametrize("sigma", [-8.0, -3.0, 0.0, 1e-9, 3.0, 8.0])
@pytest.mark.parametrize("theta", [0.0, 1e-9, 1.0, np.pi - 1e-6])
def test_sim3_exp_wide_scale_range(sigma, theta):
    rng = np.random.default_rng(17)
    z = tangent_with_angle(Sim3, rng, theta, 5)
    z[:, 6] = sigma
    mpmath = require("mpmath")
    mpmath.mp.dps = 40  # SciPy's expm loses ~1e-13 at these scales: use 40 digits instead
    ref = np.array([np.array(mpmath.expm(mpmath.matrix(h.tolist())).tolist(), dtype=float)
                    for h in Sim3.hat(z)])
    X = Sim3.exp(z)
    np.testing.assert_allclose(X.matrix(), ref, rtol=1e-14, atol=1e-14 * np.abs(ref).max())
    np.testing.assert_allclose(X.log(), z, atol=1e-11)


def test_large_batches_take_the_chunked_path_and_agree(group, backend):
    """Batches above the chunk size (NumPy and CPU torch evaluate them in cache-sized chunks)
    give the same numbers as single elements."""
    from microlie import _kernels as base

    G = group
    n = 2 * max(base.CHUNK, base.TORCH_CHUNK) + 17
    rng = np.random.default_rng(24)
    X, Y = G.random(n, rng=rng), G.random(n, rng=rng)
    tau = rng.standard_normal((n, G.dof))
    Xb, Yb, tb = element(G, X.params, backend), element(G, Y.params, backend), \
        to_backend(tau, backend)
    res = {"compose": to_numpy(Xb @ Yb), "log": to_numpy(Xb.log()), "exp": to_numpy(G.exp(tb)),
           "jr": to_numpy(G.jr(tb[:40000]))}
    for i in (0, base.CHUNK - 1, base.CHUNK, base.TORCH_CHUNK + 3, n - 1):
        np.testing.assert_allclose(res["compose"][i], (X[i] @ Y[i]).params, atol=1e-14)
        np.testing.assert_allclose(res["log"][i], X[i].log(), atol=1e-14)
        np.testing.assert_allclose(res["exp"][i], G.exp(tau[i]).params, atol=1e-14)
        if i < 40000:
            np.testing.assert_allclose(res["jr"][i], G.jr(tau[i]), atol=1e-13)


# ------------------------------------------------------------------------ regressions (issue 8)


@pytest.mark.parametrize(("G", "bk"), [(G, "torch") for G in GROUPS]
                         + [(G, "jax") for G in (SO3, SE3, Sim3)],
                         ids=lambda x: x if isinstance(x, str) else x.__name__)
def test_autodiff_through_log_at_exactly_pi(G, bk):
    """At a rotation by exactly pi (quaternion w = 0) autodiff of ``Log(X Exp(d))`` equals the
    analytic ``Jr^-1(Log X)``: along the rotation axis the angle moves one for one (torch's
    d|w|/dw = 0 at 0 used to give 0 there)."""
    backend_fixture_check(bk)
    X = G._exact_pi_element()  # about x, w = 0 exactly
    tau, J = X.log(jac=True)
    sl = G._rotation_slice
    axis = np.zeros(G.dof)
    axis[sl.start] = 1.0
    np.testing.assert_allclose((J @ axis)[sl], axis[sl], atol=1e-15)  # angle: one for one
    # independently: the one-sided difference that turns the angle below pi
    h = 1e-7
    fd = (X.plus(-h * axis).log() - tau) / -h
    np.testing.assert_allclose(fd, J @ axis, atol=1e-6)
    d0 = np.zeros(G.dof)
    if bk == "torch":
        torch = require("torch")
        Xt = G(torch.tensor(X.params))
        Jad = torch.autograd.functional.jacobian(lambda d: Xt.plus(d).log(),
                                                 torch.tensor(d0)).numpy()
    else:
        import jax
        import jax.numpy as jnp

        Xj = G(jnp.asarray(X.params))
        Jad = np.asarray(jax.jacfwd(lambda d: Xj.plus(d).log())(jnp.asarray(d0)))
    np.testing.assert_allclose(Jad, J, atol=1e-12)


def test_from_matrix_normalize_rejects_degenerate_matrices():
    """``normalize=True`` projects onto the nearest rotation; where that is not unique (the zero
    matrix, rank 1) it raises instead of returning the identity."""
    def homogeneous(n, block):
        T = np.eye(n)
        T[:block.shape[0], :block.shape[1]] = block
        return T

    rank1 = np.outer([1.0, 2.0, 3.0], [0.5, -1.0, 2.0])
    z3, z2 = np.zeros((3, 3)), np.zeros((2, 2))
    cases = [(SO3, z3, "rank < 2"), (SO3, rank1, "rank < 2"),
             (SO3, np.stack([np.eye(3), z3]), "rank < 2"),
             (SE3, homogeneous(4, z3), "rank < 2"), (SE23, homogeneous(5, z3), "rank < 2"),
             (Sim3, homogeneous(4, z3), "positive determinant"),
             (SO2, z2, "no nearest rotation"),
             (SO2, np.array([[1.0, 2.0], [2.0, -1.0]]), "no nearest rotation"),
             (SE2, homogeneous(3, z2), "no nearest rotation")]
    for G, m, match in cases:
        with pytest.raises(ValueError, match=match):
            G.from_matrix(m, normalize=True)
    # rank 2 still has a unique nearest rotation, and that is what is returned
    np.testing.assert_allclose(SO3.from_matrix(np.diag([1.0, 1.0, 0.0]), normalize=True)
                               .matrix(), np.eye(3), atol=1e-15)


def test_from_euler_validated_like_scipy():
    from itertools import product

    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(25)
    seqs = ["".join(p) for n in (1, 2, 3) for p in product("xyz", repeat=n)
            if all(a != b for a, b in zip(p, p[1:], strict=False))]
    for seq in seqs + [s.upper() for s in seqs]:
        n = len(seq)
        for shape in ((n,), (4, n), (2, 3, n)):
            ang = rng.uniform(-3.0, 3.0, shape)
            np.testing.assert_allclose(SO3.from_euler(seq, ang).matrix(),
                                       Rotation.from_euler(seq, ang).as_matrix(), atol=1e-14,
                                       err_msg=seq)
        deg = rng.uniform(-170, 170, (5, n))
        np.testing.assert_allclose(SO3.from_euler(seq, deg, degrees=True).matrix(),
                                   Rotation.from_euler(seq, deg, degrees=True).as_matrix(),
                                   atol=1e-14)
    # one axis: a scalar angle is one rotation, as in SciPy
    np.testing.assert_allclose(SO3.from_euler("y", 0.3).matrix(),
                               Rotation.from_euler("y", 0.3).as_matrix(), atol=1e-15)
    bad = [("xxy", [0.1, 0.2, 0.3]), ("zz", [0.1, 0.2]), ("xYz", [0.1, 0.2, 0.3]),
           ("abc", [0.1, 0.2, 0.3]), ("", [0.1]), ("xyzx", [0.1, 0.2, 0.3, 0.4]),
           ("xyz", [0.1, 0.2]), ("x", [0.1, 0.2]), ("XY", [0.1, 0.2, 0.3])]
    for seq, ang in bad:
        with pytest.raises(ValueError):
            Rotation.from_euler(seq, ang)  # SciPy rejects it too
        with pytest.raises(ValueError, match="Euler"):
            SO3.from_euler(seq, ang)


@pytest.mark.parametrize("G", [SE2, SE3])
@pytest.mark.parametrize("theta", [0.0, 1e-12, 1e-3, 1.0, np.pi - 1e-6, np.pi - 1e-12, np.pi])
def test_log_matrix_unchecked(G, theta):
    # the unchecked Log of homogeneous matrices agrees with the checked path (from the
    # group's element) and its Exp gives the matrix back; away from pi also with SciPy's logm
    rng = np.random.default_rng(5)
    dim = G.dof
    tau = rng.normal(size=(20, dim))
    rot = slice(2, 3) if G is SE2 else slice(3, 6)
    ax = tau[:, rot] / np.linalg.norm(tau[:, rot], axis=1, keepdims=True)
    tau[:, rot] = ax * theta
    if theta == np.pi:  # exactly pi: pure translations times an element rotated by pi
        tau[:, rot] = 0.0
        X = G.exp(tau) @ G._exact_pi_element()
    else:
        X = G.exp(tau)
    M = np.asarray(X.matrix())
    got = G.log_matrix(M)
    np.testing.assert_allclose(got, np.asarray(X.log()), atol=1e-12)
    np.testing.assert_allclose(np.asarray(G.exp(got).matrix()), M, atol=1e-12)
    if theta < 3.0:
        for k in range(3):
            np.testing.assert_allclose(np.asarray(G.hat(got[k])), logm(M[k]).real, atol=1e-9)
