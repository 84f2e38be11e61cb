"""The JAX and torch evaluation paths of the kernel layer give the NumPy numbers.

Kernels are evaluated on hard inputs (``test_kernels.hard_inputs``: angles 0, 1e-12, 1e-6, near
and exactly pi; Sim3 scale exponent 0) on paths that NumPy does not take:

* ``jax.jit`` on a batch large enough that a common factor times a vector (``ops.times``) is
  assembled as one broadcast product (``_kernels._stack_blocks``);
* one torch element without autograd, evaluated on Python floats (the traced scalar code);
* one torch element that needs autograd, or inside ``torch.func`` transforms (tensor ops).

Each must equal the generic NumPy kernel (float64: 1e-12 relative; float32: float32 rounding).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GROUPS, require, tangent_with_angle
from test_kernels import hard_inputs as kernel_hard_inputs

from microlie import SO3
from microlie import _array as A
from microlie import _kernels as K

TILE = 5  # 5 copies of test_kernels' 18 hard inputs: 90 elements, above _array.BLOCK_MIN


def hard_inputs(k: K.Kernel, rng: np.random.Generator, tile: int = TILE) -> list:
    """float64 inputs of kernel ``k`` at the hard angles (and scale exponent 0 for Sim3)."""
    return [np.tile(x, (tile, 1)) for x in kernel_hard_inputs(k, np.float64, rng)]


def kernels_of(G) -> list[K.Kernel]:
    return [k for k in K.KERNELS.values() if k.group is G and k.fn is not None]


def as_tuple(r):
    return r if isinstance(r, tuple) else (r,)


def assert_same(got, want, tol, what):
    for g, w in zip(as_tuple(got), as_tuple(want), strict=True):
        g = np.asarray(g)
        assert g.shape == w.shape, what
        scale = max(1.0, float(np.abs(w).max()))
        err = float(np.abs(g - w).max()) / scale if w.size else 0.0
        assert err <= tol, f"{what}: {err:.2e}"


# jitted: the kernels that assemble common-factor blocks (values, and the SO3 / SE3 exp and log
# Jacobians; XLA takes several seconds to compile each larger Jacobian kernel)
VALUES = ("exp", "log", "plus", "minus", "lplus", "lminus", "compose", "between", "inverse",
          "act")
JITTED = [name for name, k in K.KERNELS.items()
          if k.group.__name__ in ("SO3", "SE3", "SE23", "Sim3") and k.fn is not None
          and (name.split(".")[1] in VALUES or k.group is SO3
               or name in ("SE3.exp_jac", "SE3.log_jac"))]
USES_BLOCKS = ("SO3.exp", "SO3.log", "SO3.plus", "SO3.minus", "SO3.exp_jac", "SE3.exp",
               "SE3.log", "SE3.minus", "SE3.exp_jac", "SE23.log", "Sim3.log")


@pytest.mark.parametrize("name", JITTED)
def test_jax_jit_batches_equal_numpy(name, monkeypatch):
    """``jax.jit`` of a kernel on 90 hard inputs equals the NumPy kernel."""
    jax = require("jax")
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    k = K.KERNELS[name]
    ins = hard_inputs(k, np.random.default_rng(1))
    calls = []
    stack_blocks = K._stack_blocks
    monkeypatch.setattr(K, "_stack_blocks", lambda *a: calls.append(1) or stack_blocks(*a))
    got = jax.jit(lambda *a: K.run(k, *a))(*[jnp.asarray(x) for x in ins])
    assert_same(got, as_tuple(K.run(k, *ins)), 1e-12, f"{name} jax.jit")
    if name in USES_BLOCKS:
        assert calls, "no common-factor block was assembled"  # the path under test was taken


def test_small_jitted_batches_and_single_elements_stack_columns(monkeypatch):
    """Below ``BLOCK_MIN`` elements (one fusion is cheapest there) and for one element, the
    columns are stacked as they are; the numbers are the same."""
    jax = require("jax")
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    calls = []
    stack_blocks = K._stack_blocks
    monkeypatch.setattr(K, "_stack_blocks", lambda *a: calls.append(1) or stack_blocks(*a))
    k = K.KERNELS["SO3.exp"]
    x = hard_inputs(k, np.random.default_rng(2), tile=1)[0]
    assert len(x) < A.BLOCK_MIN
    f = jax.jit(lambda t: K.run(k, t))
    assert_same(f(jnp.asarray(x)), K.run(k, x), 1e-12, "SO3.exp small batch")
    assert_same(f(jnp.asarray(x[3])), K.run(k, x[3]), 1e-12, "SO3.exp one element")
    assert not calls


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_torch_single_elements_equal_numpy(G):
    """One torch element, no autograd: evaluated on floats (exactly NumPy's single-element
    code), returned as tensors of the input dtype; float32 rounds like NumPy's float32."""
    torch = require("torch")
    rng = np.random.default_rng(3)
    for k in kernels_of(G):
        ins = hard_inputs(k, rng, tile=1)
        for i in range(len(ins[0])):
            one = [x[i] for x in ins]
            for dt, ndt in ((torch.float64, np.float64), (torch.float32, np.float32)):
                want = as_tuple(K.run(k, *[x.astype(ndt) for x in one]))
                got = as_tuple(K.run(k, *[torch.tensor(x, dtype=dt) for x in one]))
                for g, w in zip(got, want, strict=True):
                    assert type(g) is torch.Tensor and g.dtype == dt, k.name
                    np.testing.assert_array_equal(g.numpy(), w, err_msg=k.name)


def test_torch_single_elements_keep_autograd_and_transforms():
    """A torch element that needs gradients, or sits inside ``torch.func`` transforms, is
    evaluated with tensor operations: gradients equal the analytic Jacobians, ``vmap`` of a
    single-element function equals the batch."""
    torch = require("torch")
    rng = np.random.default_rng(4)
    tau = tangent_with_angle(SO3, rng, 0.9, 5)
    # autograd on one element: d Exp(t) / dt through the quaternion, against the analytic Jr
    t = torch.tensor(tau[0], requires_grad=True)
    X = SO3.exp(t)
    assert X.params.requires_grad
    J = torch.autograd.functional.jacobian(lambda d: (SO3.exp(t.detach()).inverse()
                                                      @ SO3.exp(t.detach() + d)).log(),
                                           torch.zeros(3, dtype=torch.float64))
    _, Jr = SO3.exp(tau[0], jac=True)
    np.testing.assert_allclose(J.numpy(), Jr, atol=1e-12)
    # float16 (no float path): tensor operations, float16 out, within float16 rounding
    h = SO3.exp(torch.tensor(tau[2], dtype=torch.float16)).params
    assert h.dtype == torch.float16
    np.testing.assert_allclose(h.double().numpy(), SO3.exp(tau[2]).params, atol=2e-3)
    # torch.func: vmap and jacrev over single-element code
    with torch.no_grad():
        batch = torch.func.vmap(lambda x: SO3.exp(x).params)(torch.tensor(tau))
    np.testing.assert_allclose(batch.numpy(), SO3.exp(tau).params, rtol=0, atol=1e-15)
    Jf = torch.func.jacrev(lambda d: (SO3.exp(torch.tensor(tau[1])).inverse()
                                      @ SO3.exp(torch.tensor(tau[1]) + d)).log())(
        torch.zeros(3, dtype=torch.float64))
    np.testing.assert_allclose(Jf.numpy(), SO3.exp(tau[1], jac=True)[1], atol=1e-12)


def test_jax_pytrees_round_trip():
    """Elements are JAX pytrees: jitted identity keeps class and values; ``device_get`` gives
    read-only NumPy parameters; a map over the leaves keeps the class."""
    jax = require("jax")
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    for G in GROUPS:
        X = G.random(3, rng=5)
        Xj = G.from_params(jnp.asarray(X.params), check=False)
        Y = jax.jit(lambda a: a)(Xj)
        assert type(Y) is G
        np.testing.assert_array_equal(np.asarray(Y.params), X.params)
        H = jax.device_get(Xj)
        assert type(H) is G and type(H.params) is np.ndarray and not H.params.flags.writeable
        Z = jax.tree_util.tree_map(lambda p: 2.0 * p, Xj)
        assert type(Z) is G
        np.testing.assert_allclose(np.asarray(Z.params), 2.0 * X.params)


def test_torch_large_batches_with_and_without_autograd():
    """Above ``2 * TORCH_CHUNK`` elements CPU tensors are evaluated in chunks: stacked straight
    into the output without autograd, joined with ``cat`` when a gradient is needed; both equal
    NumPy, including an element broadcast against a batch of points."""
    torch = require("torch")
    from microlie import SE3

    n = 2 * K.TORCH_CHUNK + 5
    rng = np.random.default_rng(6)
    tau = rng.standard_normal((n, 6))
    pts = rng.standard_normal((n, 3))
    want_X, want_J = SE3.exp(tau, jac=True)
    one = SE3.exp(tau[7])
    want_act = one.act(pts)
    for grad in (False, True):
        t = torch.tensor(tau, requires_grad=grad)
        X, J = SE3.exp(t, jac=True)
        assert X.params.requires_grad == grad and J.requires_grad == grad
        assert_same((X.params.detach(), J.detach()), (want_X.params, want_J), 1e-12, "SE3.exp")
        act = SE3(torch.tensor(one.params, requires_grad=grad)).act(torch.tensor(pts))
        assert_same(act.detach(), want_act, 1e-12, "SE3.act, one element on a batch")
        if grad:  # gradients through the chunks equal those of the elements taken alone
            (X.params.sum() + J.sum()).backward()
            for i in (0, K.TORCH_CHUNK, n - 1):
                ti = torch.tensor(tau[i], requires_grad=True)
                Xi, Ji = SE3.exp(ti, jac=True)
                (Xi.params.sum() + Ji.sum()).backward()
                np.testing.assert_allclose(t.grad[i].numpy(), ti.grad.numpy(), rtol=1e-12,
                                           atol=1e-12)
