"""The single-element fast path (``microlie.groups._single``, and the compiled one of
``microlie._c._one`` when installed): taken for one float64 NumPy element, declined for
everything else, and indistinguishable from the generic path in values and in errors."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GROUPS, hard_elements
from scipy.linalg import expm

import microlie as ml
from microlie.groups import _single
from microlie.groups._single import OPS


@pytest.fixture(autouse=True, params=["installed", "python"])
def implementation(request, monkeypatch):
    """Every test runs on the functions in use (the compiled SO3/SE3 ones when microlie._c
    is installed) and on the Python ones of every group."""
    if request.param == "python":
        for G in GROUPS:
            for op, fn in _single.build(G).items():
                monkeypatch.setattr(G, f"_one_{op}", staticmethod(fn))
    return request.param


def _inputs(G, rng):
    """(X, Y, tau, point) cases: random elements, and the hard elements against random ones."""
    cases = []
    for _ in range(3):
        cases.append((G.random(rng=rng), G.random(rng=rng), 0.7 * rng.standard_normal(G.dof),
                      rng.standard_normal(G.point_dim)))
    for H in hard_elements(G, rng).values():
        tau = H.log()
        cases.append((H, G.random(rng=rng), tau, rng.standard_normal(G.point_dim)))
        cases.append((G.random(rng=rng), H, 1e-12 * tau, 1e3 * rng.standard_normal(G.point_dim)))
    cases.append((G.identity(), G.identity(), np.zeros(G.dof), np.zeros(G.point_dim)))
    return cases


def _call(op, X, Y, tau, v):
    G = type(X)
    return {"exp": lambda: G.exp(tau), "log": X.log, "inverse": X.inverse,
            "compose": lambda: X.compose(Y), "between": lambda: X.between(Y),
            "act": lambda: X.act(v), "plus": lambda: X.plus(tau),
            "minus": lambda: Y.minus(X)}[op]()


def _fast(op, X, Y, tau, v):
    """The fast-path function itself (None when it declines)."""
    G = type(X)
    f = getattr(G, f"_one_{op}")
    return {"exp": lambda: f(tau), "log": lambda: f(X), "inverse": lambda: f(X),
            "compose": lambda: f(X, Y), "between": lambda: f(X, Y), "act": lambda: f(X, v),
            "plus": lambda: f(X, tau), "minus": lambda: f(Y, X)}[op]()


def _generic(monkeypatch, G, op):
    """Switch the fast path of ``G.op`` off (the generic path answers)."""
    monkeypatch.setattr(G, f"_one_{op}", staticmethod(lambda *args: None))


def _mat(x):
    return x.matrix() if isinstance(x, ml.LieGroup) else None


def _affine(G, M, v):
    n = G.point_dim
    return M @ v if G.matrix_dim == n else M[:n, :n] @ v + M[:n, n]


@pytest.mark.parametrize("op", list(OPS))
@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_fast_path_is_taken_and_agrees_with_matrices(G, op):
    rng = np.random.default_rng(3)
    hat = G.hat
    for X, Y, tau, v in _inputs(G, rng):
        assert _fast(op, X, Y, tau, v) is not None  # the fast path answered
        out = _call(op, X, Y, tau, v)
        MX, MY = _mat(X), _mat(Y)
        if op == "exp":
            want, got = expm(hat(tau)), out.matrix()
        elif op == "log":
            want, got = MX, expm(hat(out))
        elif op == "inverse":
            want, got = np.linalg.inv(MX), out.matrix()
        elif op == "compose":
            want, got = MX @ MY, out.matrix()
        elif op == "between":
            want, got = np.linalg.inv(MX) @ MY, out.matrix()
        elif op == "act":
            want, got = _affine(G, MX, v), out
        elif op == "plus":
            want, got = MX @ expm(hat(tau)), out.matrix()
        else:  # Y (-) X = Log(X^-1 Y)
            want, got = np.linalg.inv(MX) @ MY, expm(hat(out))
        scale = 1.0 + np.abs(want).max()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * scale, err_msg=op)


@pytest.mark.parametrize("op", list(OPS))
@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_fast_path_gives_what_the_generic_path_gives(G, op, monkeypatch):
    rng = np.random.default_rng(4)
    cases = _inputs(G, rng)
    fast = [_call(op, *c) for c in cases]
    _generic(monkeypatch, G, op)
    for c, f in zip(cases, fast, strict=True):
        g = _call(op, *c)
        assert type(f) is type(g)
        fa, ga = (f.params, g.params) if isinstance(g, ml.LieGroup) else (f, g)
        assert type(fa) is np.ndarray and fa.dtype == ga.dtype == np.float64
        assert fa.shape == ga.shape and fa.flags.writeable == ga.flags.writeable
        np.testing.assert_allclose(fa, ga, rtol=0, atol=4e-16 * (1 + np.abs(ga).max()))
        if isinstance(f, ml.LieGroup):  # the cached floats are the parameters
            assert f._floats is None or list(f._floats) == f.params.tolist()


def test_fast_path_declines_what_it_does_not_handle():
    X = ml.SE3.random(rng=0)
    tau, v = np.full(6, 0.1), np.ones(3)
    X32 = ml.SE3(X.params.astype(np.float32))
    B = ml.SE3(X.params[None])
    assert ml.SE3._one_compose(X, ml.SO3.identity()) is None
    assert ml.SE3._one_compose(X32, X32) is None
    assert ml.SE3._one_compose(X, X32) is None
    assert ml.SE3._one_compose(B, B) is None
    assert ml.SE3._one_log(B) is None
    assert ml.SE3._one_exp(tau.tolist()) is None
    assert ml.SE3._one_exp(tau.astype(np.float32)) is None
    assert ml.SE3._one_exp(tau[None]) is None
    assert ml.SE3._one_exp(tau[:5]) is None
    assert ml.SE3._one_act(X, v.astype(np.float32)) is None
    assert ml.SE3._one_act(X, v[None]) is None
    assert ml.SE3._one_act(X, [1.0, 2.0, 3.0]) is None
    assert ml.SE3._one_act(X, np.array([1.0, np.nan, 0.0])) is None
    assert ml.SE3._one_plus(X, np.array([0, 0, 0, np.inf, 0, 0.0])) is None
    # ... and the generic path answers those with the promoted dtype and batch shape
    assert (X32 @ X32).dtype == np.float32 and X.act(v.astype(np.float32)).dtype == np.float64
    assert (B @ X).batch_shape == (1,) and ml.SE3.exp(tau.tolist()).allclose(ml.SE3.exp(tau))
    with pytest.raises(TypeError, match="expected a SE3"):
        X.compose(ml.SO3.identity())


def _bad_inputs():
    """(group, op, callable) with a bad input each."""
    X, S = ml.SE3.random(rng=0), ml.Sim3.random(rng=0)
    nan6 = np.array([0.0, np.nan, 0, 0, 0, 0])
    return [
        ("SE3.exp nan", lambda: ml.SE3.exp(nan6)),
        ("SE3.exp inf", lambda: ml.SE3.exp(np.array([0, 0, 0, np.inf, 0, 0.0]))),
        ("SE3.exp shape", lambda: ml.SE3.exp(np.zeros(5))),
        ("SE3.exp huge angle", lambda: ml.SE3.exp(np.array([0, 0, 0, 1e200, 0, 0.0]))),
        ("SO3.exp huge angle", lambda: ml.SO3.exp(np.array([1e200, 0, 0.0]))),
        ("SE3.plus nan", lambda: X.plus(nan6)),
        ("SE3.plus huge angle", lambda: X.plus(np.array([0, 0, 0, 0, 1e300, 0.0]))),
        ("SE3.act nan", lambda: X.act(np.array([1.0, np.nan, 0.0]))),
        ("SE3.act inf", lambda: X.act(np.array([1.0, np.inf, 0.0]))),
        ("SE3.act shape", lambda: X.act(np.zeros(2))),
        ("Sim3.exp sigma", lambda: ml.Sim3.exp(np.array([0, 0, 0, 0, 0, 0, 60.0]))),
        ("Sim3.plus sigma", lambda: S.plus(np.array([0, 0, 0, 0, 0, 0, -60.0]))),
        ("Sim3.log sigma", lambda: ml.Sim3.exp(np.array([0, 0, 0, 0, 0, 0, 45.0])).compose(
            ml.Sim3.exp(np.array([0, 0, 0, 0, 0, 0, 45.0]))).log()),
    ]


@pytest.mark.parametrize("case", range(len(_bad_inputs())))
def test_bad_input_raises_the_generic_error(case, monkeypatch):
    name, fn = _bad_inputs()[case]
    with pytest.raises(ValueError) as fast:
        fn()
    for G in GROUPS:
        for op in OPS:
            _generic(monkeypatch, G, op)
    with pytest.raises(ValueError) as generic:
        fn()
    assert str(fast.value) == str(generic.value), name


def test_elements_never_see_later_writes_to_the_callers_array():
    p = ml.SE3.random(rng=5).params.copy()
    for make in (ml.SE3, lambda a: ml.SE3.from_params(a, check=False)):
        want = make(p.copy())
        a = p.copy()
        X = make(a)
        a[:3] += 10.0  # the caller's array changes; the element must not
        assert X.params.tolist() == want.params.tolist() == list(X._floats)
        Y = ml.SE3.random(rng=6)
        np.testing.assert_array_equal((X @ Y).params, (want @ Y).params)
        np.testing.assert_array_equal(X.log(), want.log())
    B = ml.SE3.random(3, rng=7)
    for i in range(3):  # elements sliced from a batch take the fast path too
        assert ml.SE3._one_log(B[i]) is not None
        np.testing.assert_allclose(B[i].log(), B.log()[i], rtol=0, atol=1e-15)


def test_outputs_of_the_fast_path_are_immutable_and_tangents_writable():
    X, Y = ml.SE3.random(rng=8), ml.SE3.random(rng=9)
    Z = X @ Y
    with pytest.raises(ValueError):
        Z.params[0] = 1.0
    with pytest.raises(AttributeError):
        Z.params = np.zeros(7)
    t = Z.log()
    t[0] = 5.0  # a fresh, writable array, as from the generic path
    q = X.act(np.ones(3))
    q[0] = 5.0
    assert Z.log()[0] != 5.0


def test_a_long_chain_matches_the_generic_path(monkeypatch):
    rng = np.random.default_rng(10)
    steps = ml.SE3.exp(0.3 * rng.standard_normal((200, 6)))
    step_list = list(steps)
    X = ml.SE3.identity()
    for s in step_list:
        X = X @ s
    _generic(monkeypatch, ml.SE3, "compose")
    Y = ml.SE3.identity()
    for s in step_list:
        Y = Y @ s
    np.testing.assert_allclose(X.params, Y.params, rtol=0, atol=1e-13)


def test_unusual_layouts_fall_back_or_are_read_correctly():
    """A strided or byte-swapped parameter array, an element of a subclass: declined by the
    compiled functions (the Python ones read any layout), right values either way."""
    X, Y = ml.SE3.random(rng=11), ml.SE3.random(rng=12)
    want = X.matrix() @ Y.matrix()
    wide = np.zeros((7, 2))
    wide[:, 0] = X.params
    strided = ml.SE3._wrap(wide[:, 0])
    swapped = ml.SE3._wrap(X.params.astype(">f8"))
    for Z in (strided, swapped):
        np.testing.assert_allclose((Z @ Y).matrix(), want, atol=1e-14)
        np.testing.assert_allclose(Z.act(np.ones(3)), X.act(np.ones(3)), atol=1e-14)

    class Sub(ml.SE3):
        pass

    A, B = Sub(X.params), Sub(Y.params)
    assert ml.SE3._one_compose(A, B) is None  # not an SE3 exactly
    assert type(A @ B) is Sub
    np.testing.assert_allclose((A @ B).matrix(), want, atol=1e-14)
