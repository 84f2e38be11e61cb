"""The device engine's dense normal equations (``optim/device/dense.py``): ``H`` and ``g``
against ``J^T J`` and ``J^T e`` of a Jacobian taken by central differences of the residuals
through the retraction (a fixed variable, factors of one and two arguments, a batch), on torch
and JAX."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import _jax, require, to_backend

from microlie import SE3
from microlie.optim import BetweenFactor, Diagonal, FactorGraph, PriorFactor


def _np(a):
    return a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)


@pytest.mark.parametrize("backend", ["torch", "jax"])
def test_normal_equations_equal_central_difference_jacobian(backend):
    if backend == "jax":
        _jax()
    else:
        require("torch")
    from microlie.optim.device import DeviceProblem
    from microlie.optim.device.dense import normal_equations

    rng = np.random.default_rng(3)
    X0 = SE3.exp(rng.normal(size=(5, 6)) * 0.4)
    g = FactorGraph()
    x = g.add_variables(SE3.from_params(to_backend(X0.params, backend)), fixed=[2])
    g.add(PriorFactor(x, 0, SE3.exp(0.1 * rng.normal(size=6)), Diagonal([0.1] * 6)))
    g.add(BetweenFactor(x, [0, 1, 2, 3, 0], [1, 2, 3, 4, 3],
                        SE3.exp(0.5 * rng.normal(size=(5, 6))),
                        Diagonal(np.linspace(0.05, 0.3, 6))))
    p = DeviceProblem.from_graph(g)
    assert p.size == 4 * 6                       # pose 2 is fixed: no column
    B, n = 3, p.size
    xp = p.backend.xp
    theta = tuple({k: xp.stack([v] * B) for k, v in d.items()} for d in p.theta())
    x0 = p.retract([xp.stack([a] * B) for a in p.initial()],     # a start per problem
                   to_backend(0.2 * rng.normal(size=(B, n)), backend))
    H, grad = normal_equations(p, p.linearize(theta, x0))

    def e(dx):
        xs = p.retract(x0, to_backend(dx, backend))
        return np.concatenate([_np(r).reshape(B, -1) for r in p.linearize(theta, xs).e], 1)

    h = 1e-6
    J = np.stack([(e(np.broadcast_to(h * np.eye(n)[k], (B, n)))
                   - e(np.broadcast_to(-h * np.eye(n)[k], (B, n)))) / (2 * h)
                  for k in range(n)], -1)
    r = e(np.zeros((B, n)))
    Hn, gn = J.transpose(0, 2, 1) @ J, (J.transpose(0, 2, 1) @ r[..., None])[..., 0]
    np.testing.assert_allclose(_np(H), Hn, rtol=1e-6, atol=1e-6 * np.abs(Hn).max())
    np.testing.assert_allclose(_np(grad), gn, rtol=1e-6, atol=1e-6 * np.abs(gn).max())
    assert np.array_equal(_np(H), _np(H).transpose(0, 2, 1))
