"""The kernel layer: the registry seam, one evaluation per fused operation, and the defects of
the evaluator (dtype promotion, traced values, bad values on every path).

References are independent of the generic kernels: the replacements below are written directly
in vectorised NumPy from the textbook formulas (Rodrigues through the quaternion, Hamilton
product, ``R p + t``), and the dtype checks compare against float64 NumPy arithmetic.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import GROUPS, require, tangent_with_angle

from microlie import SE3, SO3, LieGroup, Sim3
from microlie import _kernels as K
from microlie.groups import base

HARD = (0.0, 1e-12, 1e-6, 0.7, np.pi - 1e-6, np.pi)


# ------------------------------------------------------------------------ replacements


def so3_exp_rows(phi: np.ndarray) -> tuple[np.ndarray]:
    """Unit quaternion ``(sin(t/2) u, cos(t/2))`` of rotation vectors ``(N, 3)``."""
    t = np.linalg.norm(phi, axis=1)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    k = np.where(small, 0.5 - t * t / 48.0, np.sin(0.5 * ts) / ts)
    out = np.empty((phi.shape[0], 4), dtype=phi.dtype)
    out[:, :3] = phi * k[:, None]
    out[:, 3] = np.cos(0.5 * t)
    return (out,)


def so3_compose_rows(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray]:
    """Hamilton product of ``(x, y, z, w)`` quaternions, ``(N, 4)`` each."""
    u, a = p[:, :3], p[:, 3:]
    v, b = q[:, :3], q[:, 3:]
    out = np.empty_like(p)
    out[:, :3] = a * v + b * u + np.cross(u, v)
    out[:, 3] = (a * b)[:, 0] - np.einsum("ni,ni->n", u, v)
    return (out,)


def _rot(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q.T
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=1).reshape(-1, 3, 3)


def se3_act_rows(p: np.ndarray, v: np.ndarray) -> tuple[np.ndarray]:
    """``R p + t`` with ``R`` from the quaternion."""
    return (np.einsum("nij,nj->ni", _rot(p[:, 3:]), v) + p[:, :3],)


REPLACEMENTS = {"SO3.exp": so3_exp_rows, "SO3.compose": so3_compose_rows,
                "SE3.act": se3_act_rows}


@pytest.fixture
def replaced():
    before = {name: K.KERNELS[name].impl for name in REPLACEMENTS}  # compiled ones, if any
    for name, impl in REPLACEMENTS.items():
        K.register(name, impl)
    try:
        yield
    finally:
        for name, impl in before.items():
            K.register(name, impl)


def hard_inputs(k: K.Kernel, dtype, rng) -> list[np.ndarray]:
    """Inputs for kernel ``k`` at the hard angles (and scale exponent 0 for Sim3)."""
    G = k.group
    taus = np.concatenate([tangent_with_angle(G, rng, th, 3) for th in HARD])
    if G is Sim3:
        taus[::2, 6] = 0.0
    out = []
    for kind in k.ins:
        if kind == "t":
            x = taus
        elif kind == "p":
            x = G.exp(taus).params
        elif kind == "v":
            x = rng.standard_normal((len(taus), G.point_dim)) * 10.0
        elif kind == "m":
            x = G.exp(taus).matrix().reshape(len(taus), -1)
        else:
            raise AssertionError(f"unknown input kind {kind!r} of {k.name}")
        taus = rng.permutation(taus)  # pair different hard inputs in binary kernels
        out.append(np.ascontiguousarray(x, dtype=dtype))
    return out


def test_every_replacement_matches_the_generic_kernel(replaced):
    names = K.replacements()
    assert set(REPLACEMENTS) <= set(names)
    rng = np.random.default_rng(0)
    for name in names:
        k = K.KERNELS[name]
        for dtype, tol in ((np.float64, 1e-13), (np.float32, 2e-6)):
            ins = hard_inputs(k, dtype, rng)
            got = K.run(k, *ins)
            impl, k.impl = k.impl, None
            try:
                want = K.run(k, *ins)
            finally:
                k.impl = impl
            got = got if isinstance(got, tuple) else (got,)
            want = want if isinstance(want, tuple) else (want,)
            for g, w in zip(got, want, strict=True):
                assert g.dtype == w.dtype == dtype
                scale = max(1.0, float(np.abs(w).max()))
                err = float(np.abs(g.astype(float) - w.astype(float)).max()) / scale
                assert err <= tol, f"{name} {np.dtype(dtype).name}: {err:.2e}"


def test_replacement_is_used_for_batches(replaced):
    calls = []

    def counting(phi):
        calls.append(phi.shape)
        return so3_exp_rows(phi)

    K.register("SO3.exp", counting)
    phi = np.array([0.1, -0.2, 0.3])
    Rs = SO3.exp(np.tile(phi, (2, 5, 1)))
    assert calls == [(10, 3)] and Rs.batch_shape == (2, 5)
    SO3.exp(phi[None])
    assert calls[-1] == (1, 3)
    R = SO3.exp(phi)  # a single element keeps the traced float code (the contract)
    assert len(calls) == 2
    np.testing.assert_allclose(R.params, Rs.params[0, 0], atol=1e-16)
    # the group's other operations are untouched: Log still inverts the replaced Exp
    np.testing.assert_allclose(R.log(), phi, atol=1e-15)


def test_replacement_contract_is_enforced():
    before = K.KERNELS["SO3.exp"].impl  # the compiled one, if any
    K.register("SO3.exp", lambda phi: (np.zeros((phi.shape[0], 3)),))
    try:
        with pytest.raises(RuntimeError, match="SO3.exp"):
            SO3.exp(np.zeros((2, 3)))
    finally:
        K.register("SO3.exp", before)
    with pytest.raises(KeyError):
        K.register("SO3.nonexistent", so3_exp_rows)
    with pytest.raises(ValueError, match="backend"):
        K.register("SO3.exp", so3_exp_rows, backend="torch")


OPS = ("exp", "log", "compose", "inverse", "act", "adjoint", "matrix", "between", "minus",
       "lminus", "plus", "lplus", "jr", "jr_inv", "exp_jac", "log_jac", "act_jac", "inverse_jac",
       "compose_jac", "between_jac", "minus_jac", "lminus_jac", "plus_jac", "lplus_jac")


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_every_group_has_every_kernel_in_the_table(G):
    for op in OPS:
        k = K.KERNELS[f"{G.__name__}.{op}"]
        assert k.group is G and k is G._K[op]


@pytest.mark.parametrize("G", [G for G in GROUPS if G._has_closed_jr], ids=lambda g: g.__name__)
def test_each_operation_with_its_jacobians_is_one_evaluation(G, monkeypatch):
    """The value and all right Jacobians of an operation come from one kernel evaluation."""
    calls = []
    real = base.run
    monkeypatch.setattr(base, "run", lambda k, *a: calls.append(k.name) or real(k, *a))
    rng = np.random.default_rng(1)
    X, Y = G.random(4, rng=rng), G.random(4, rng=rng)
    t = rng.standard_normal((4, G.dof)) * 0.3
    v = rng.standard_normal((4, G.point_dim))
    cases = {"exp_jac": lambda: G.exp(t, jac=True), "log_jac": lambda: X.log(jac=True),
             "act_jac": lambda: X.act(v, jac=True), "minus_jac": lambda: X.minus(Y, jac=True),
             "between_jac": lambda: X.between(Y, jac=True),
             "compose_jac": lambda: X.compose(Y, jac=True),
             "plus_jac": lambda: X.plus(t, jac=True), "lplus_jac": lambda: X.lplus(t, jac=True),
             "lminus_jac": lambda: X.lminus(Y, jac=True),
             "inverse_jac": lambda: X.inverse(jac=True)}
    for op, f in cases.items():
        calls.clear()
        f()
        assert calls == [f"{G.__name__}.{op}"], (op, calls)


def test_vee_pseudo_inverse_is_computed_once_per_class(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("pinv called at run time")

    monkeypatch.setattr(np.linalg, "pinv", fail)
    for G in GROUPS:
        tau = np.arange(1.0, G.dof + 1.0) / 10
        np.testing.assert_allclose(G.vee(G.hat(tau)), tau, atol=1e-15)


def test_a_group_missing_a_primitive_is_rejected_when_defined():
    with pytest.raises(TypeError, match="_log.*_compose"):
        class Broken(LieGroup):  # noqa: F841
            dof = 1
            param_dim = 1
            matrix_dim = 1
            point_dim = 1
            _identity_params = (0.0,)
            _generators = np.zeros((1, 1, 1))

            @staticmethod
            def _exp(o, t):
                return t


# ------------------------------------------------------------------------ defects


@pytest.mark.parametrize("n", [None, 1, 100, 3 * K.CHUNK + 5])
def test_mixed_dtypes_follow_numpy_promotion_on_every_path(n):
    """A float64 pose acting on float32 points gives float64 (NumPy's promotion), whatever the
    batch size: single element, small batch, chunked batch; likewise for compose."""
    rng = np.random.default_rng(2)
    shape = () if n is None else (n,)
    X = SE3.exp(np.array([1e4, -2e4, 3e3, 0.1, 0.2, 0.3]))  # map-scale translation
    pts = (rng.standard_normal((*shape, 3)) * 100).astype(np.float32)
    out = X.act(pts)
    assert out.dtype == np.float64
    R = X.matrix()
    want = pts.astype(np.float64) @ R[:3, :3].T + R[:3, 3]
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-9)
    Y32 = SE3.random(shape, rng=rng, dtype=np.float32)
    assert X.compose(Y32).dtype == np.float64
    assert Y32.compose(X).dtype == np.float64
    assert Y32.compose(Y32).dtype == np.float32
    assert Y32.act(pts).dtype == np.float32
    assert X.act(pts, jac=True)[1].dtype == np.float64


def test_jit_closing_over_concrete_jax_arrays():
    """Value checks read concrete arrays on the host: they never force a traced value."""
    jax = require("jax")
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    pts = jnp.asarray(np.random.default_rng(3).standard_normal((5, 3)))
    R = jnp.asarray(SO3.exp(np.array([0.1, 0.2, 0.3])).matrix())
    T = jnp.asarray(SE3.exp(np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])).matrix())
    q = jnp.asarray([0.0, 0.0, 0.0, 1.0])

    @jax.jit
    def f(x):
        a = SE3.exp(x).act(pts)
        b = SO3.from_matrix(R).compose(SO3.exp(x[3:])).params
        c = SE3.from_matrix(T).compose(SE3.exp(x)).params
        d = SO3.from_quat(q).params
        return a, b, c, d

    x = np.array([0.5, -0.1, 0.2, 0.3, 0.0, -0.2])
    a, b, c, d = f(jnp.asarray(x))
    np.testing.assert_allclose(np.asarray(a), SE3.exp(x).act(np.asarray(pts)), atol=1e-12)
    np.testing.assert_allclose(
        np.asarray(c), (SE3.from_matrix(np.asarray(T)) @ SE3.exp(x)).params, atol=1e-12)


@pytest.mark.parametrize("G,tau,msg", [
    (SO3, [1e200, 0.0, 0.0], "not finite"), (SE3, [0.0, 0.0, 0.0, 0.0, 1e170, 0.0], "not finite"),
    (Sim3, [0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 800.0], "SIGMA_MAX|not finite"),
])
def test_overflowing_inputs_raise_the_same_error_single_and_batched(G, tau, msg):
    tau = np.asarray(tau)
    for t in (tau, np.stack([tau * 0, tau, tau * 0]), np.tile(tau, (2 * K.CHUNK + 1, 1))):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a ValueError, not NumPy warnings
            with pytest.raises(ValueError, match=msg):
                G.exp(t)
            with pytest.raises(ValueError, match=msg):
                G.identity().plus(t)


def test_np_asarray_of_an_element_is_a_type_error():
    X = SE3.random(1000, rng=0)
    with pytest.raises(TypeError, match=r"\.params.*\.matrix\(\)"):
        np.asarray(X)
    with pytest.raises(TypeError, match=r"\.params"):
        np.array([SO3.identity()])


def test_no_torch_warning_for_parameters_that_require_grad():
    torch = require("torch")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for G in GROUPS:
            p = torch.tensor(G.random(3, rng=1).params, requires_grad=True)
            X = G(p)
            X.log().sum().backward()
            assert p.grad is not None
        R = torch.tensor(SO3.random(2, rng=2).matrix(), requires_grad=True)
        SO3.from_matrix(R)
        T = torch.tensor(SE3.random(2, rng=2).matrix(), requires_grad=True)
        SE3.from_matrix(T)


def test_params_are_read_only_and_never_alias_the_callers_array():
    p = SE3.random(rng=4).params.copy()
    for X in (SE3(p), SE3.from_params(p), SE3.from_params(p, check=False)):
        with pytest.raises(ValueError, match="read-only"):
            X.params[0] = 5.0
        p_before = X.params.copy()
        p[0] += 1.0
        np.testing.assert_array_equal(X.params, p_before)
    Y = SE3.random(3, rng=5)
    for out in (Y.compose(Y), Y.inverse(), SE3.exp(Y.log()), Y[1:], Y.rotation()):
        with pytest.raises(ValueError, match="read-only"):
            out.params[..., 0] = 1.0


@pytest.mark.parametrize("bk", ["torch", "jax"])
def test_mixed_dtypes_on_other_backends(bk):
    mod = require(bk)
    if bk == "jax":
        mod.config.update("jax_enable_x64", True)
        import jax.numpy as xp
    else:
        xp = mod
    X = SE3.exp(xp.asarray(np.array([1e4, -2e4, 3e3, 0.1, 0.2, 0.3])))
    pts = xp.asarray(np.random.default_rng(6).standard_normal((4, 3)).astype(np.float32))
    out = X.act(pts)
    assert str(out.dtype).endswith("float64")
    R = np.asarray(X.matrix())
    want = np.asarray(pts).astype(np.float64) @ R[:3, :3].T + R[:3, 3]
    np.testing.assert_allclose(np.asarray(out), want, rtol=0, atol=1e-9)


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_single_and_batched_elements_acting_on_one_point(G):
    """The one-point fast path: a batch of elements acting on one point, one element on one
    point, and the traced single-element kernels agree with the batched evaluation."""
    rng = np.random.default_rng(7)
    X = G.random(5, rng=rng)
    v = rng.standard_normal(G.point_dim)
    want = X.act(np.tile(v, (5, 1)))
    np.testing.assert_allclose(X.act(v), want, rtol=0, atol=1e-14)
    for i in range(5):  # a compiled batch built with FMA may fuse a product (one ulp)
        np.testing.assert_allclose(X[i].act(v), want[i], rtol=0, atol=4.5e-16 * np.abs(
            want[i]).max())


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_nan_tangents_are_rejected_on_every_path(G):
    """A NaN anywhere in a tangent batch (checked once, by the kernel's result check on NumPy
    batches) raises like a NaN single element; so do plus, lplus and jr."""
    for shape in ((), (3,), (2 * K.CHUNK + 1,)):
        for i in range(G.dof):
            t = np.zeros((*shape, G.dof))
            t[..., i] = np.nan
            for f in (G.exp, G.identity().plus, G.identity().lplus, G.jr, G.jr_inv):
                with pytest.raises(ValueError, match="(?i)nan"):
                    f(t)


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_chunked_jacobian_kernels_agree_with_single_elements(G):
    """Wide outputs of chunked batches (filled through a transposed buffer) equal the
    single-element results, across chunk boundaries and in the last partial chunk."""
    rng = np.random.default_rng(8)
    n = 2 * K.CHUNK + 17
    X, Y = G.random(n, rng=rng), G.random(n, rng=rng)
    t = rng.standard_normal((n, G.dof)) * 0.4
    v = rng.standard_normal((n, G.point_dim))
    batched = {"minus": X.minus(Y, jac=True), "plus": X.plus(t, jac=True),
               "act": X.act(v, jac=True), "exp": G.exp(t, jac=True)}
    for i in (0, K.CHUNK - 1, K.CHUNK, n - 1):
        single = {"minus": X[i].minus(Y[i], jac=True), "plus": X[i].plus(t[i], jac=True),
                  "act": X[i].act(v[i], jac=True), "exp": G.exp(t[i], jac=True)}
        for op, outs in batched.items():
            for b, s in zip(outs, single[op], strict=True):
                b = b.params if isinstance(b, LieGroup) else b
                s = s.params if isinstance(s, LieGroup) else s
                np.testing.assert_allclose(b[i], s, rtol=1e-12, atol=1e-12, err_msg=op)


@pytest.mark.parametrize("n", [3 * K.CHUNK + 5, 7])  # chunked, and one evaluation
def test_constant_and_deferred_output_components(n):
    """Constant (Python-float) components of a chunked component-major output, also ones
    that change from chunk to chunk, become arrays or flip the sign of zero (each is written
    once after the last chunk where it stays constant); ``ops.negated(x)``,
    ``ops.add_out(a, b)``, ``ops.sub_out(a, b)``, ``ops.mul_out(a, b)`` components come out as
    ``-x``, ``a + b``, ``a - b``, ``a * b`` in matrix and vector outputs alike, also with a
    Python-float operand."""

    def fn(o, x):
        start = float(x[0][0])  # the first row of this chunk
        a = x[0] * 1.0
        c = 2.0 if start == 0 else a if start == K.CHUNK else 3.0
        z = 0.0 if start < 2 * K.CHUNK else -0.0
        return (((1.0, c, a), (a, z, o.negated(a)), (c, o.add_out(a, 0.5), -1.0)),
                (o.negated(a), o.sub_out(2.0, a), o.mul_out(a, a), o.sub_out(a, a)),
                # runs of equal constant rows (one fill each), ended by -0.0, 1.0 and an array
                ((0.0, 0.0, 0.0), (-0.0, 0.0, 1.0), (1.0, a, 1.0)))

    k = K.Kernel("test.constants", None, fn, ["v"], [(3, 3), (4,), (3, 3)])
    x = np.arange(n, dtype=np.float64)[:, None]
    out, vec, runs = K._run(k, (x,))
    a = x[:, 0]
    want_c = np.where(a < K.CHUNK, 2.0, np.where(a < 2 * K.CHUNK, a, 3.0))
    want_z = np.where(a < 2 * K.CHUNK, 0.0, -0.0) if n > 2 * K.CHUNK else np.zeros(n)
    want = np.stack([np.ones(n), want_c, a, a, want_z, -a, want_c, a + 0.5,
                     -np.ones(n)], -1).reshape(n, 3, 3)
    np.testing.assert_array_equal(out, want)
    assert np.array_equal(np.signbit(out[:, 1, 1]), np.signbit(want_z))
    np.testing.assert_array_equal(vec, np.stack([-a, 2.0 - a, a * a, 0 * a], -1))
    zero, one = np.zeros(n), np.ones(n)
    want = np.stack([zero, zero, zero, -zero, zero, one, one, a, one], -1).reshape(n, 3, 3)
    np.testing.assert_array_equal(runs, want)
    assert np.array_equal(np.signbit(runs).reshape(n, 9)[0], [0, 0, 0, 1, 0, 0, 0, 0, 0])


def test_select_patches_a_deferred_majority():
    """A chunked evaluation whose ``select`` returns output components of the majority branch
    (``add_out``: computed into the output) with the minority's values patched in, and a
    deferred minority evaluated into the majority's array."""

    def fn(o, x):
        a = x[0]

        def major(v):  # one output component in two places
            s = o.add_out(v, 1.0)
            return s, s

        r = o.select(a < 10.0, lambda v: (v * 3.0, v * 4.0), major, a)
        m = o.select(a < 10.0, major, lambda v: (v * 3.0, v * 4.0), a)  # deferred minority
        return (r[0], o.negated(a), r[1], m[0], m[1], a, a, a, a),

    k = K.Kernel("test.patch", None, fn, ["v"], [(3, 3)])
    n = 2 * K.CHUNK + 11
    x = np.arange(n, dtype=np.float64)[:, None]
    out = K._run(k, (x,))
    a = x[:, 0]
    np.testing.assert_array_equal(out[:, 0, 0], np.where(a < 10.0, 3.0 * a, a + 1.0))
    np.testing.assert_array_equal(out[:, 0, 1], -a)
    np.testing.assert_array_equal(out[:, 0, 2], np.where(a < 10.0, 4.0 * a, a + 1.0))
    np.testing.assert_array_equal(out[:, 1, 0], np.where(a < 10.0, a + 1.0, 3.0 * a))
    np.testing.assert_array_equal(out[:, 1, 1], np.where(a < 10.0, a + 1.0, 4.0 * a))
