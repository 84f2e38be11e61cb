"""The hand-fused ``minus(jac=True)`` kernels of SO3, SE3 and Sim3, the branch selection that
evaluates each series only where it is used, and the component-major layout of batched
Jacobians (issue 8, first open item).

The fused kernels share the half-angle functions of Log with ``Jr^-1`` and write ``-Jl^-1``
from the blocks of ``Jr^-1``; they are checked against the independent formulas of
``G.jr_inv(tau)`` and ``G.jl_inv(tau)`` (the tangent-based closed forms, and for Sim3 the full
formula at ``-tau``) at the hard angles, and the derivative ``c'`` of the SO(3) coefficient
against a 50-digit reference.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import generic, require, tangent_with_angle

import microlie as ml
from microlie import _kernels as K
from microlie._array import NUMPY, ArrayOps
from microlie.groups import so3

GROUPS = [ml.SO3, ml.SE3, ml.Sim3]


ANGLES = [0.0, 1e-12, 1e-6, 0.3, 0.999999, 1.0, 1.000001, 2.0, np.pi - 1e-6, np.pi]


def _cases(G, rng, dtype):
    """Pairs (X, Y = X Exp(tau)) at the hard angles (and Sim3 scale exponent 0)."""
    taus = [tangent_with_angle(G, rng, th) for th in ANGLES]
    if G is ml.Sim3:
        for t in taus[::2]:
            t[6] = 0.0
        taus.append(np.zeros(G.dof))
    tau = np.array(taus)
    X = G.random(len(taus), rng=rng)
    Y = X @ G.exp(tau)
    return G(X.params.astype(dtype)), G(Y.params.astype(dtype)), tau


@pytest.mark.parametrize("G", GROUPS, ids=lambda G: G.__name__)
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("n", [1, 3, 40000])  # single elements, small and chunked batches
def test_fused_minus_jac_matches_the_jacobian_formulas(G, dtype, n):
    rng = np.random.default_rng(7)
    X, Y, _ = _cases(G, rng, dtype)
    if n == 1:
        pairs = [(X[i], Y[i]) for i in range(len(X))]
    else:
        idx = np.arange(n) % len(X)
        pairs = [(G(X.params[idx]), G(Y.params[idx]))]
    tol = 1e-12 if dtype == np.float64 else 2e-5
    for x, y in pairs:
        tau, JY, JX = y.minus(x, jac=True)
        assert tau.dtype == dtype and JY.dtype == dtype and JX.dtype == dtype
        t64 = np.asarray(tau, dtype=np.float64)
        # the value is minus()'s (the single-element and compiled paths may round differently)
        vtol = 1e-15 if dtype == np.float64 else 1e-6
        assert np.abs(tau - y.minus(x)).max() <= vtol * max(1.0, np.abs(t64).max())
        ref_r = G.jr_inv(t64)
        ref_l = -G.jl_inv(t64)
        scale = np.maximum(1.0, np.abs(ref_r).max())
        assert np.abs(JY - ref_r).max() <= tol * scale
        assert np.abs(JX - ref_l).max() <= tol * scale


def test_coef_c_slope_against_mpmath():
    mp = require("mpmath")
    mp.mp.dps = 50

    def c(t2):
        h = mp.sqrt(t2) / 2
        return (1 - h * mp.cot(h)) / t2

    for t2 in [1e-20, 1e-8, 1e-3, 0.5, 0.9999999, 1.0, 1.0000001, 3.0, 9.0, 9.8]:
        k = np.sin(np.sqrt(t2) / 2) / np.sqrt(t2)
        ch = np.cos(np.sqrt(t2) / 2)
        got_c, got_s = so3.coef_c_slope(NUMPY, np.array([t2]), np.array([k]), np.array([ch]))
        want_s = float(mp.diff(c, mp.mpf(t2)))
        assert abs(float(got_c[0]) - float(c(mp.mpf(t2)))) <= 1e-15
        # the same coefficient from a quaternion's kl = theta / |v| and |w| (not unit: the
        # norm cancels)
        th = mp.sqrt(mp.mpf(t2))
        kl, aw = float(th / mp.sin(th / 2)), 1.0001 * float(mp.cos(th / 2))
        got_q = so3.coef_c_quat(NUMPY, np.array([t2]), np.array([kl / 1.0001]), np.array([aw]))
        assert abs(float(got_q[0]) - float(c(mp.mpf(t2)))) <= 1e-15
        # c' ~ 1/720 multiplies terms of order theta^2 |rho| theta: 5e-16 absolute is below
        # their rounding (the closed form just above SMALL2 = 1 keeps 2e-13 relative)
        assert abs(float(got_s[0]) - want_s) <= 5e-16


@pytest.mark.parametrize("fraction", [0.0, 0.01, 0.4, 0.6, 0.99, 1.0])
def test_select_equals_where(fraction):
    # NumPy evaluates each branch only where it is used (the majority on the whole batch, the
    # minority gathered); the result is the element-wise where of both branches
    rng = np.random.default_rng(3)
    x = rng.random(5000) + 0.5
    y = rng.standard_normal(5000)
    cond = rng.random(5000) < fraction

    def f(a, b):
        return a * b + 1.0, np.sin(a)

    def g(a, b):
        return a / b, 2.0 * a

    got = NUMPY.select(cond, f, g, x, y)
    want = ArrayOps(np).select(cond, f, g, x, y)
    for a, b in zip(got, want, strict=True):
        assert a.shape == (5000,) and np.array_equal(a, b)
    one = NUMPY.select(cond, lambda a: a + 1.0, lambda a: a, x)  # a branch returning its input
    assert np.array_equal(one, np.where(cond, x + 1.0, x)) and np.array_equal(x, y * 0 + x)


@pytest.mark.parametrize("n", [5, 40000])
def test_batched_jacobians_are_component_major_views(n):
    # the generic kernels' layout (a compiled replacement, if any, is set aside meanwhile)
    rng = np.random.default_rng(0)
    X, Y = ml.Sim3.random(n, rng=rng), ml.Sim3.random(n, rng=rng)
    with generic("Sim3.minus_jac"):
        tau, JY, JX = Y.minus(X, jac=True)
    assert JY.shape == (n, 7, 7) and JY.strides == (8, 7 * 8 * n, 8 * n)
    assert tau.flags.c_contiguous  # vectors stay row-major
    for i in (0, n // 2, n - 1):
        one = Y[i].minus(X[i], jac=True)
        assert np.allclose(one[1], JY[i], rtol=0, atol=1e-14)
        assert np.allclose(one[2], JX[i], rtol=0, atol=1e-14)
    assert np.array_equal(np.ascontiguousarray(JY), JY)


def test_fused_kernels_are_registered():
    for G in GROUPS:
        assert K.KERNELS[f"{G.__name__}.minus_jac"].fn is G._minus_jac
