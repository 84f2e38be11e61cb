"""Group operations under transforms: ``torch.func.jacrev`` and ``jax.jacrev`` against the
analytic right Jacobians (``jac=True``), ``torch.compile(fullgraph=True)`` without a graph
break, the value-check rule (no host copy; skipped where values are unknown), and no
process-wide JAX flag changed by microlie."""

from __future__ import annotations

import contextlib
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import require

from microlie import SE2, SE3, SE23, SO2, SO3, Sim3
from microlie import _array as A

GROUPS = (SO2, SO3, SE2, SE3, SE23, Sim3)
ROT = {SO2: [0], SO3: [0, 1, 2], SE2: [2], SE3: [3, 4, 5], SE23: [3, 4, 5], Sim3: [3, 4, 5]}
ROOT = Path(__file__).resolve().parents[1]


def _tangents(G, case: str, rng: np.random.Generator, batch: tuple) -> tuple:
    """Three tangent arrays ``(*batch, dof)``: random, zero, tiny, or ``x`` rotated by
    ``pi - 1e-4`` (the hard inputs of Log and of ``Jr^-1``)."""
    shape = (*batch, G.dof)
    if case == "zero":
        return np.zeros(shape), np.zeros(shape), np.zeros(shape)
    if case == "tiny":
        return tuple(rng.standard_normal(shape) * 1e-9 for _ in range(3))
    x, y, t = (rng.standard_normal(shape) * 0.7 for _ in range(3))
    if case == "near_pi":
        r = ROT[G]
        v = x[..., r]
        x[..., r] = v / np.linalg.norm(v, axis=-1, keepdims=True) * (np.pi - 1e-4)
    return x, y, t


class _Torch:
    def __init__(self) -> None:
        self.torch = require("torch")
        self.jacrev = self.torch.func.jacrev

    def array(self, a):
        return self.torch.tensor(np.asarray(a), dtype=self.torch.float64)

    def context(self):
        return contextlib.nullcontext()

    def pairs(self, G, *args):
        return _pairs(G, self, *args)


class _Jax:
    def __init__(self) -> None:
        self.jax = require("jax")
        self.jacrev = self.jax.jacrev

    def array(self, a):
        import jax.numpy as jnp

        return jnp.asarray(np.asarray(a, dtype=np.float64)) if A.is_numpy_like(a) else a

    def context(self):
        return self.jax.enable_x64(True)

    def pairs(self, G, *args):
        return _pairs(G, self, *args)


def _pairs(G, be, tx, ty, tt, p) -> dict:
    """For each operation: (autodiff Jacobian, analytic right Jacobian) pairs. A right Jacobian
    is ``d/d delta [f(X Exp(delta)) (-) f(X)]`` at ``delta = 0`` (plain ``d f`` for a vector
    output); autodiff differentiates exactly that function."""
    jacrev = be.jacrev
    X, Y, t, p = G.exp(be.array(tx)), G.exp(be.array(ty)), be.array(tt), be.array(p)
    d0 = 0.0 * be.array(tx)
    out = {}
    Z, A1, A2 = X.compose(Y, jac=True)
    out["compose"] = [(jacrev(lambda d: X.plus(d).compose(Y).minus(Z))(d0), A1),
                      (jacrev(lambda d: X.compose(Y.plus(d)).minus(Z))(d0), A2)]
    Z, A1, A2 = X.between(Y, jac=True)
    out["between"] = [(jacrev(lambda d: X.plus(d).between(Y).minus(Z))(d0), A1),
                      (jacrev(lambda d: X.between(Y.plus(d)).minus(Z))(d0), A2)]
    Z, A1, A2 = X.plus(t, jac=True)
    out["plus"] = [(jacrev(lambda d: X.plus(d).plus(t).minus(Z))(d0), A1),
                   (jacrev(lambda d: X.plus(t + d).minus(Z))(d0), A2)]
    _, A1, A2 = Y.minus(X, jac=True)
    out["minus"] = [(jacrev(lambda d: Y.plus(d).minus(X))(d0), A1),
                    (jacrev(lambda d: Y.minus(X.plus(d)))(d0), A2)]
    _, A1 = X.log(jac=True)
    out["log"] = [(jacrev(lambda d: X.plus(d).log())(d0), A1)]
    E, A1 = G.exp(t, jac=True)
    out["exp"] = [(jacrev(lambda d: G.exp(t + d).minus(E))(d0), A1)]
    _, A1, A2 = X.act(p, jac=True)
    out["act"] = [(jacrev(lambda d: X.plus(d).act(p))(d0), A1),
                  (jacrev(lambda v: X.act(v))(p), A2)]
    return out


def _blocks(J: np.ndarray, n: int) -> np.ndarray:
    """The diagonal blocks ``(n, k, m)`` of a batched Jacobian ``(n, k, n, m)``; the
    off-diagonal ones must be zero (element ``i`` depends on input ``i`` only)."""
    diag = np.stack([J[i, :, i] for i in range(n)])
    off = J.copy()
    for i in range(n):
        off[i, :, i] = 0.0
    assert np.abs(off).max() == 0.0
    return diag


def _check_jacrev(G, be, cases, batch: bool) -> None:
    rng = np.random.default_rng(5)
    with be.context():
        for case in cases:
            tx, ty, tt = _tangents(G, case, rng, ())
            p = rng.standard_normal(G.point_dim)
            for op, pairs in be.pairs(G, tx, ty, tt, p).items():
                for auto, exact in pairs:
                    auto, exact = np.asarray(auto), np.asarray(exact)
                    assert auto.dtype == np.float64 and auto.shape == exact.shape
                    tol = 1e-12 * max(1.0, np.abs(exact).max())
                    assert np.abs(auto - exact).max() <= tol, (G.__name__, op, case)
        if not batch:
            return
        n = 3
        tx, ty, tt = _tangents(G, "random", rng, (n,))
        p = rng.standard_normal((n, G.point_dim))
        for op, pairs in be.pairs(G, tx, ty, tt, p).items():
            for auto, exact in pairs:
                diag, exact = _blocks(np.asarray(auto), n), np.asarray(exact)
                tol = 1e-12 * max(1.0, np.abs(exact).max())
                assert np.abs(diag - exact).max() <= tol, (G.__name__, op, "batch")


@pytest.mark.parametrize("G", GROUPS, ids=lambda G: G.__name__)
def test_torch_jacrev_equals_the_analytic_jacobians(G):
    """``torch.func.jacrev`` through exp, log, compose, between, plus, minus and act equals the
    closed-form right Jacobians to 1e-12 (relative to max(1, |J|)) in float64: single elements
    at random, zero, tiny (1e-9) and near-pi (pi - 1e-4) tangents, and a batch of 3."""
    _check_jacrev(G, _Torch(), ("random", "zero", "tiny", "near_pi"), batch=True)


@pytest.mark.parametrize("G", GROUPS, ids=lambda G: G.__name__)
def test_jax_jacrev_equals_the_analytic_jacobians(G):
    """The same for ``jax.jacrev`` (float64 inside ``jax.enable_x64``), at the hardest input
    (near pi) for every group and on a batch for SE(3). Op-by-op JAX differentiation is slow
    (about 1 s per Jacobian at load 15): the whole sweep is the torch test's."""
    _check_jacrev(G, _Jax(), ("near_pi",), batch=G is SE3)


def test_jacrev_through_from_params():
    """The issue's case: ``jacrev`` of ``SE3.from_params(q).act(p)`` with respect to the raw
    parameters (checked, by the constructor) equals central differences of the same map."""
    torch = require("torch")
    X = SE3.exp(np.array([0.3, -0.2, 0.5, 0.4, -0.7, 0.2]))
    q = torch.tensor(X.params)
    p = torch.tensor([[1.0, 2.0, 3.0], [-0.5, 0.1, 0.8]])
    J = torch.func.jacrev(lambda q: SE3.from_params(q).act(p))(q).numpy()  # (2, 3, 7)

    def f(qv):  # the unnormalised map: R(q / |q|) p + t
        Q = np.array(qv)
        Q[3:] /= np.linalg.norm(Q[3:])
        return SE3.from_params(Q).act(p.numpy())

    h = 1e-6
    fd = np.stack([(f(X.params + h * e) - f(X.params - h * e)) / (2 * h)
                   for e in np.eye(7)], axis=-1)
    np.testing.assert_allclose(J, fd, atol=1e-8)
    # and a gradient through a whole expression of checked elements
    g = torch.func.grad(lambda q: SE3.from_params(q).compose(SE3.from_params(q)).log().sum())(q)
    assert g.shape == (7,) and torch.isfinite(g).all()


# ------------------------------------------------------------------ torch.compile


def _explain(f, *args):
    require("torch")
    import torch._dynamo as dynamo

    dynamo.reset()
    ex = dynamo.explain(f)(*args)
    return ex.graph_count, ex.graph_break_count, [r.reason for r in ex.break_reasons]


def test_compile_fullgraph_without_graph_breaks():
    """``torch.compile`` traces exp, act, compose, between, log, plus, minus (and a checked
    ``from_params``) of a batch as one graph; the compiled function (``fullgraph=True``, the
    eager backend: no C compiler in a unit test) gives the eager numbers."""
    torch = require("torch")
    rng = np.random.default_rng(1)
    x = torch.tensor(rng.standard_normal((5, 6)) * 0.5)
    y = torch.tensor(rng.standard_normal((5, 6)) * 0.5)
    p = torch.tensor(rng.standard_normal((5, 3)))

    def f(x, y, p):
        X, Y = SE3.exp(x), SE3.exp(y)
        Z = SE3.from_params(X.compose(Y).params)
        return (X.act(p), X.between(Y).params, Z.log(), X.plus(y).params, Y.minus(X),
                X.act(p, jac=True)[1])

    assert _explain(f, x, y, p) == (1, 0, [])
    assert _explain(lambda x, p: SE3.exp(x).act(p), x, p) == (1, 0, [])
    g = torch.compile(f, fullgraph=True, backend="eager")
    for a, b in zip(g(x, y, p), f(x, y, p), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-15)


def test_compile_registers_with_dynamo_imported_after_microlie():
    """The stand-ins of the compiled single-element functions are registered when
    ``torch._dynamo`` is imported after microlie (the usual import order), and nothing is
    imported or changed before: a fresh process."""
    require("torch")
    code = (
        "import sys, microlie, torch\n"
        "from microlie import SE3, _fast, _torch_compile\n"
        "assert 'torch._dynamo' not in sys.modules\n"
        "x = torch.zeros(4, 6, dtype=torch.float64)\n"
        "p = torch.ones(4, 3, dtype=torch.float64)\n"
        "g = torch.compile(lambda x, p: SE3.exp(x).act(p), fullgraph=True, backend='eager')\n"
        "assert torch.equal(g(x, p), p)\n"
        "print(_torch_compile.registered(), len(_fast.installed_single()))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=300, check=True)
    registered, single = map(int, out.stdout.split())
    assert (registered > 0) == (single > 0)


# ------------------------------------------------------------------ value checks


def test_checks_under_torch_func_read_no_memory():
    """Inside a ``torch.func`` transform the wrapped tensors are not checked (no values to
    read); a tensor the transform does not wrap is still checked, by a reduction (never
    ``Tensor.numpy``): bad input raises the same ``ValueError``."""
    torch = require("torch")
    X = SE3.exp(torch.tensor([0.1, 0.2, 0.3, 0.4, 0.5, 0.6], dtype=torch.float64))
    d0 = torch.zeros(6, dtype=torch.float64)
    bad = torch.tensor([1.0, float("nan"), 0.0], dtype=torch.float64)
    with pytest.raises(ValueError, match="points contains NaN"):
        torch.func.jacrev(lambda d: X.plus(d).act(bad))(d0)
    inf = torch.full((6,), float("inf"), dtype=torch.float64)
    with pytest.raises(ValueError, match="tangent vector contains NaN"):
        torch.func.jacrev(lambda d: X.plus(d).plus(inf).params)(d0)
    # what the transform wraps (its input, and tensors made inside it) is not checked
    J = torch.func.jacrev(lambda d: X.plus(d + inf).params)(d0)
    assert not torch.isfinite(J).all()


def test_meta_tensors_pass_unchecked_and_shapes_still_raise():
    """A ``meta`` tensor has no values: value checks skip it (documented), the operation
    returns a meta tensor of the right shape; shape errors still raise."""
    torch = require("torch")
    x = torch.empty((4, 6), dtype=torch.float64, device="meta")
    q = SE3.exp(x).act(torch.empty((4, 3), dtype=torch.float64, device="meta"))
    assert q.device.type == "meta" and tuple(q.shape) == (4, 3)
    assert SE3.from_params(torch.empty((2, 7), device="meta")).batch_shape == (2,)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 6\)"):
        SE3.exp(torch.empty((4, 5), dtype=torch.float64, device="meta"))


def test_device_checks_reduce_in_the_namespace(monkeypatch):
    """Arrays outside CPU memory (a GPU; simulated) are checked by reductions in their own
    namespace, never copied to the host: ``Tensor.numpy``/``Tensor.cpu`` and NumPy
    conversion of JAX arrays are not called, and bad input raises as on the host."""
    torch = require("torch")
    jax = require("jax")
    import jax.numpy as jnp

    where = A._where  # CPU memory taken for a device's: every check must reduce there
    monkeypatch.setattr(A, "_where", lambda x: A._DEVICE if where(x) == A._HOST else where(x))

    def no_copy(*args, **kwargs):
        raise AssertionError("copied to the host")

    monkeypatch.setattr(torch.Tensor, "numpy", no_copy)
    monkeypatch.setattr(torch.Tensor, "cpu", no_copy)
    monkeypatch.setattr(A, "host_values", no_copy)
    t = torch.tensor([[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]] * 3, dtype=torch.float64)
    assert SE3.exp(t).act(torch.ones(3, 3, dtype=torch.float64)).shape == (3, 3)
    with pytest.raises(ValueError, match="points contains NaN"):
        SE3.exp(t).act(torch.full((3, 3), float("nan"), dtype=torch.float64))
    with pytest.raises(ValueError, match="norm differs from 1"):
        SO3(torch.tensor([0.0, 0.0, 0.0, 1.1], dtype=torch.float64))
    with pytest.raises(ValueError, match="SIGMA_MAX"):
        Sim3.exp(torch.tensor([0, 0, 0, 0, 0, 0, 800.0], dtype=torch.float64)[None])
    assert A.max_abs(torch.tensor([-3.0, 2.0])) == 3.0
    assert A.all_finite(torch.tensor([1.0, math.inf])) is False
    with jax.enable_x64(True):
        pts = jnp.full((2, 3), jnp.nan)
        X = SE3.exp(jnp.zeros((2, 6)))

        @jax.jit
        def f(x):  # a concrete closed-over array is checked, eagerly, inside jit
            return SE3.exp(x).act(pts)

        monkeypatch.setattr(A, "host_values", no_copy)
        with pytest.raises(ValueError, match="points contains NaN"):
            f(jnp.zeros((2, 6)))
        assert A.max_abs(X.params) == 1.0


# ------------------------------------------------------------------ JAX precision


def test_jax_custom_factor_needs_x64_and_never_sets_it():
    """``CustomFactor(jac="jax")`` with float64 off raises a ``ValueError`` saying how to
    enable it, and leaves the flag as it was."""
    jax = require("jax")
    from microlie.optim import CustomFactor, FactorGraph

    g = FactorGraph()
    x = g.add_variables(SE3.identity(1))
    tau = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    with jax.enable_x64(False):
        with pytest.raises(ValueError, match="jax_enable_x64 is off"):
            CustomFactor(lambda X: X.log(), [(x, 0)], 6, jac="jax")
        assert not jax.config.read("jax_enable_x64")
    with jax.enable_x64(True):
        f = CustomFactor(lambda X: X.log(), [(x, 0)], 6, jac="jax")
        r, (J,) = f.residual(SE3.exp(tau[None]), jac=True)
    np.testing.assert_allclose(J[0], SE3.jr_inv(tau), atol=1e-12)  # d Log(X Exp(d)) / d d
