"""Autodiff through the groups: torch autograd and JAX (jit, grad, vmap, jacfwd).

The Jacobian that autodiff finds through ``plus`` (perturbing each input on the right) and
``minus`` (differencing the output on the right) must equal the analytic one, at random points
and at the hard angles; gradients must be finite at the identity and near pi.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GROUPS, require, tangent_with_angle, to_numpy

from microlie import LieGroup

ANGLES = {"random": None, "zero": 0.0, "tiny": 1e-9, "near_pi": np.pi - 1e-6}
OPS = ["inverse", "compose", "between", "act", "exp", "log", "plus", "minus", "lplus", "lminus"]


def _inputs(G, rng, theta):
    def tan():
        if theta is None:
            return tangent_with_angle(G, rng, rng.uniform(0.1, 3.0))
        return tangent_with_angle(G, rng, theta)

    X = G.exp(tan())
    return {
        "inverse": [X], "compose": [X, G.exp(tan())], "between": [X, X @ G.exp(tan())],
        "act": [X, rng.standard_normal(G.point_dim)], "exp": [tan()], "log": [X],
        "plus": [G.exp(tan()), tan()], "minus": [X @ G.exp(tan()), X],
        "lplus": [G.exp(tan()), tan()], "lminus": [G.exp(tan()) @ X, X],
    }


def _apply(G, op, args, **kw):
    if op == "exp":
        return G.exp(args[0], **kw)
    return getattr(args[0], op)(*args[1:], **kw)


def _perturbed(G, op, args, i, delta):
    """``f(args with args[i] (+) delta) (-) f(args)`` (right perturbation, right minus)."""
    a = list(args)
    a[i] = a[i].plus(delta) if isinstance(a[i], LieGroup) else a[i] + delta
    y, y0 = _apply(G, op, a), _apply(G, op, args)
    return y.minus(y0) if isinstance(y, LieGroup) else y - y0


def _to(args, conv):
    return [type(x)(conv(x.params)) if isinstance(x, LieGroup) else conv(x) for x in args]


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@pytest.mark.parametrize("where", list(ANGLES))
def test_torch_autograd_equals_analytic(G, where):
    torch = require("torch")
    rng = np.random.default_rng(20)
    for op, args in _inputs(G, rng, ANGLES[where]).items():
        analytic = _apply(G, op, args, jac=True)[1:]
        targs = _to(args, lambda a: torch.tensor(a, dtype=torch.float64))
        for i, J in enumerate(analytic):
            dim = args[i].dof if isinstance(args[i], LieGroup) else len(args[i])
            d0 = torch.zeros(dim, dtype=torch.float64)
            Jad = torch.autograd.functional.jacobian(
                lambda d, i=i, op=op, targs=targs: _perturbed(G, op, targs, i, d), d0)
            np.testing.assert_allclose(Jad.numpy(), J, atol=1e-9,
                                       err_msg=f"{G.__name__}.{op} arg {i} at {where}")


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
@pytest.mark.parametrize("where", list(ANGLES))
def test_jax_jacfwd_equals_analytic(G, where):
    require("jax")
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(21)
    for op, args in _inputs(G, rng, ANGLES[where]).items():
        analytic = _apply(G, op, args, jac=True)[1:]
        jargs = _to(args, jnp.asarray)
        for i, J in enumerate(analytic):
            dim = args[i].dof if isinstance(args[i], LieGroup) else len(args[i])
            Jad = jax.jacfwd(lambda d, i=i, op=op, jargs=jargs: _perturbed(G, op, jargs, i, d))(
                jnp.zeros(dim))
            np.testing.assert_allclose(np.asarray(Jad), J, atol=1e-9,
                                       err_msg=f"{G.__name__}.{op} arg {i} at {where}")


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_torch_gradients_finite_at_identity_and_near_pi(G):
    torch = require("torch")
    rng = np.random.default_rng(22)
    for theta in (0.0, 1e-9, np.pi - 1e-6, np.pi):
        tau = torch.tensor(tangent_with_angle(G, rng, theta), requires_grad=True)
        X = G.exp(tau)
        p = torch.tensor(rng.standard_normal(G.point_dim), requires_grad=True)
        loss = (X.params.sum() + X.log().sum() + (X @ X).params.sum() + X.act(p).sum()
                + X.inverse().log().sum() + G.exp(tau, jac=True)[1].sum()
                + X.log(jac=True)[1].sum())
        loss.backward()
        assert torch.isfinite(tau.grad).all(), (theta, tau.grad)
        assert torch.isfinite(p.grad).all()
        # gradient with respect to the raw parameters of Log at the identity
        P = torch.tensor(G.identity().params, requires_grad=True)
        G._wrap(P).log().sum().backward()
        assert torch.isfinite(P.grad).all()


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_jax_gradients_finite_at_identity_and_near_pi(G):
    require("jax")
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(23)
    p = jnp.asarray(rng.standard_normal(G.point_dim))

    def loss(t):
        X = G.exp(t)
        return (X.params.sum() + X.log().sum() + (X @ X).params.sum() + X.act(p).sum()
                + X.inverse().log().sum() + G.exp(t, jac=True)[1].sum()
                + X.log(jac=True)[1].sum())

    for theta in (0.0, 1e-9, np.pi - 1e-6, np.pi):
        g = jax.grad(loss)(jnp.asarray(tangent_with_angle(G, rng, theta)))
        assert np.all(np.isfinite(np.asarray(g))), (theta, g)
    gP = jax.grad(lambda P: G._wrap(P).log().sum())(jnp.asarray(G.identity().params))
    assert np.all(np.isfinite(np.asarray(gP)))


def test_torch_autograd_through_jacobian_outputs():
    """A loss on an analytic Jacobian differentiates (second derivatives exist and agree with
    finite differences of the Jacobian)."""
    torch = require("torch")
    from microlie import SE3

    tau = torch.tensor([0.3, -0.1, 0.2, 0.5, -0.4, 0.7], dtype=torch.float64, requires_grad=True)
    (SE3.exp(tau, jac=True)[1] ** 2).sum().backward()
    h = 1e-6
    fd = []
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        t0 = tau.detach().numpy()
        fd.append(((SE3.jr(t0 + e) ** 2).sum() - (SE3.jr(t0 - e) ** 2).sum()) / (2 * h))
    np.testing.assert_allclose(tau.grad.numpy(), fd, atol=1e-7)


def test_jax_jit_vmap_pytrees():
    require("jax")
    import jax
    import jax.numpy as jnp

    from microlie import SE3, SO3

    jax.config.update("jax_enable_x64", True)
    X = SE3(jnp.asarray(SE3.random(8, rng=1).params))
    Y = SE3(jnp.asarray(SE3.random(8, rng=2).params))
    leaves, treedef = jax.tree_util.tree_flatten(X)
    assert len(leaves) == 1 and leaves[0].shape == (8, 7)
    f = jax.jit(lambda A, B: A.between(B).log())
    ref = SE3(np.asarray(X.params)).between(SE3(np.asarray(Y.params))).log()
    np.testing.assert_allclose(np.asarray(f(X, Y)), ref, atol=1e-13)
    Z = jax.jit(lambda A, B: A @ B)(X, Y)
    assert isinstance(Z, SE3)
    v = jax.vmap(lambda A: A.act(jnp.ones(3)))(X)
    np.testing.assert_allclose(np.asarray(v), SE3(np.asarray(X.params)).act(np.ones(3)),
                               atol=1e-13)
    R = jax.vmap(SO3.exp)(jnp.asarray(np.random.default_rng(3).standard_normal((5, 3))))
    assert isinstance(R, SO3) and R.batch_shape == (5,)


def test_torch_keeps_type_dtype_and_device():
    torch = require("torch")
    from microlie import SE3

    for dtype in (torch.float32, torch.float64):
        t = torch.zeros(3, 6, dtype=dtype)
        X, J = SE3.exp(t, jac=True)
        assert X.params.dtype == dtype and J.dtype == dtype
        assert X.params.device == t.device
        assert isinstance(X.log(), torch.Tensor)
    assert to_numpy(SE3.identity().act(torch.ones(3))).shape == (3,)
