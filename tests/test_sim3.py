"""Sim(3) in closed form against 50-digit references computed here with mpmath.

``Jr(zeta) = phi(-ad_zeta)`` with ``phi(x) = (e^x - 1)/x`` is the top-right block of
``expm([[-ad, I], [0, 0]])`` (14x14) and ``W = phi(sigma I + hat(phi))`` the top-right block of
``expm([[sigma I + hat(phi), I], [0, 0]])`` (6x6), both evaluated by ``mpmath.expm`` at 50
digits; ``Jr^-1`` is the 50-digit inverse. Each block of a Jacobian (``rho rho``, ``rho phi``,
``rho sigma``, ``phi phi``) must agree to 1e-12 relative (max-norm of the block).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require, to_backend, to_numpy
from test_fused_minus import generic

from microlie import SE3, Sim3
from microlie import _kernels as K
from microlie.groups import sim3

SIGMAS = [0.0, 1e-12, -1e-12, 1e-6, -1e-3, 0.7, -1.99, 2.01, -8.0, 20.0, 50.0, -50.0]
THETAS = [0.0, 1e-12, 1e-6, 1e-3, 1.0, np.pi - 1e-6, np.pi]
BLOCKS = [(slice(0, 3), slice(0, 3)), (slice(0, 3), slice(3, 6)), (slice(0, 3), slice(6, 7)),
          (slice(3, 6), slice(3, 6))]


def _mp():
    mp = require("mpmath")
    mp.mp.dps = 50
    return mp


def _hat(mp, v):
    return mp.matrix([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _ad(mp, z):
    """The 7x7 ``ad_zeta``: ``[[sigma I + hat(phi), hat(rho), -rho], [0, hat(phi), 0], [0]]``
    (from the bracket of ``hat(zeta) = [[sigma I + hat(phi), rho], [0, 0]]``)."""
    F, P = _hat(mp, z[3:6]), _hat(mp, z[:3])
    a = mp.zeros(7, 7)
    for i in range(3):
        for j in range(3):
            a[i, j] = F[i, j] + (z[6] if i == j else 0)
            a[i, 3 + j] = P[i, j]
            a[3 + i, 3 + j] = F[i, j]
        a[i, 6] = -z[i]
    return a


def _phi_of(mp, A):
    """``phi(A) = sum_k A^k / (k+1)!``: Taylor series on ``A / 2^j``, then ``j`` doublings
    ``phi(2A) = phi(A) (e^A + I) / 2``, ``e^(2A) = (e^A)^2`` (all at the working precision)."""
    n = A.rows
    j = max(0, int(mp.ceil(mp.log(max(mp.mnorm(A, 1), 1), 2))) + 1)
    N = A / 2**j
    I = mp.eye(n)
    E, F, term, k = I.copy(), I.copy(), I.copy(), 1
    while True:
        term = term * N / k  # N^k / k!
        E += term
        F += term / (k + 1)
        k += 1
        if mp.mnorm(term, 1) < mp.mpf(10) ** (-mp.mp.dps - 5):
            break
    for _ in range(j):
        F = F * (E + I) / 2
        E = E * E
    return F


def reference(z):
    """50-digit ``Jr``, ``Jr^-1`` and ``W`` of a float64 tangent vector (as float64 arrays)."""
    mp = _mp()
    zz = [mp.mpf(float(x)) for x in z]
    Jr = _phi_of(mp, -_ad(mp, zz))
    A = _hat(mp, zz[3:6]) + zz[6] * mp.eye(3)
    W = _phi_of(mp, A)
    f = lambda m: np.array(m.tolist(), dtype=float)  # noqa: E731
    return f(Jr), f(mp.inverse(Jr)), f(W)


def _tangent(rng, sigma, theta, rho_scale=1.0):
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    return np.concatenate([rho_scale * rng.standard_normal(3), theta * axis, [sigma]])


def _block_errors(J, R):
    return [np.abs(J[r, c] - R[r, c]).max() / np.abs(R[r, c]).max() for r, c in BLOCKS]


@pytest.mark.parametrize("sigma", SIGMAS)
def test_jr_jr_inv_and_w_against_50_digit_reference(sigma):
    rng = np.random.default_rng(abs(hash(sigma)) % 2**32)
    for theta in THETAS:
        z = _tangent(rng, sigma, theta)
        Jr, Jri, W = reference(z)
        where = f"sigma={sigma}, theta={theta}"
        for name, J, R in (("Jr", Sim3.jr(z), Jr), ("Jr^-1", Sim3.jr_inv(z), Jri)):
            errs = _block_errors(J, R)
            assert max(errs) <= 1e-12, (name, where, errs)
            # the structurally zero blocks are exactly zero
            assert np.all(J[3:6, :3] == 0) and np.all(J[3:6, 6] == 0) and np.all(J[6, :6] == 0)
            assert J[6, 6] == 1.0
        # W through Exp's translation (W rho) and through the coefficients
        a, b, c = sim3.w_coefficients(sim3.A.SCALAR, float(sigma), float(theta**2))
        F = SE3.hat(np.concatenate([[0, 0, 0], z[3:6]]))[:3, :3]
        Wn = a * np.eye(3) + b * F + c * F @ F
        assert np.abs(Wn - W).max() <= 1e-12 * np.abs(W).max(), (where, Wn, W)
        t = Sim3.exp(z).translation()
        assert np.abs(t - W @ z[:3]).max() <= 1e-12 * np.abs(W).max() * np.abs(z[:3]).max()
        # Log inverts it (translation part back to rho within the same relative accuracy)
        back = Sim3.exp(z).log()
        if theta < np.pi:
            np.testing.assert_allclose(back, z, rtol=0, atol=1e-12 * max(1.0, abs(sigma)))


def test_random_points_and_batches_against_reference():
    """Random tangents over the whole range (batched), including large translations."""
    rng = np.random.default_rng(5)
    zs = []
    for _ in range(12):
        sigma = rng.choice([rng.uniform(-50, 50), rng.uniform(-3, 3),
                            rng.choice([-1, 1]) * 10 ** rng.uniform(-14, 0)])
        theta = rng.choice([rng.uniform(0, np.pi), 10 ** rng.uniform(-14, 0),
                            np.pi - 10 ** rng.uniform(-14, -1)])
        zs.append(_tangent(rng, sigma, theta, rho_scale=rng.choice([1.0, 100.0])))
    zs = np.array(zs)
    Jb, Jib = Sim3.jr(zs), Sim3.jr_inv(zs)
    for z, J, Ji in zip(zs, Jb, Jib, strict=True):
        Jr, Jri, _ = reference(z)
        assert max(_block_errors(J, Jr)) <= 1e-12, z
        assert max(_block_errors(Ji, Jri)) <= 1e-12, z
        # the single-element path agrees (to rounding: batches may run the compiled kernel)
        np.testing.assert_allclose(Sim3.jr(z), J, rtol=0, atol=1e-14 * max(1.0, abs(J).max()))


@pytest.mark.parametrize("sigma", SIGMAS)
def test_minus_jacobians_against_50_digit_reference(sigma):
    """``Y.minus(X, jac=True)`` (the fused kernel: ``Jr^-1`` in closed form, ``-Jl^-1`` as
    ``ad - Jr^-1``) against ``Jr^-1(tau)`` and ``-Jr^-1(-tau)`` at 50 digits, at the tau it
    returns, on the generic NumPy path (single elements and a batch)."""
    rng = np.random.default_rng(abs(hash(sigma)) % 2**32 + 1)
    zs = np.array([_tangent(rng, sigma, theta) for theta in THETAS])
    X = Sim3.random(len(zs), rng=rng)
    Y = X @ Sim3.exp(zs)
    with generic("Sim3.minus_jac"):  # the generic kernel (a compiled one is tested apart)
        batch = Y.minus(X, jac=True)
        singles = [Y[i].minus(X[i], jac=True) for i in range(len(zs))]
    for i, theta in enumerate(THETAS):
        for got in ((batch[0][i], batch[1][i], batch[2][i]), singles[i]):
            _check_minus_jacobians(*got, f"sigma={sigma}, theta={theta}")


def test_minus_jacobians_of_a_batch_mixing_scales():
    """One batch over every scale and angle of the grid (the kernel picks its formula for A
    element by element, on both sides of sigma = -2) against the 50-digit reference."""
    rng = np.random.default_rng(11)
    cases = [(sg, th) for sg in SIGMAS for th in THETAS]
    zs = np.array([_tangent(rng, sg, th) for sg, th in cases])
    X = Sim3.random(len(zs), rng=rng)
    Y = X @ Sim3.exp(zs)
    # tiled past 2 * CHUNK elements: the chunked evaluation, whose output components are
    # computed straight into the output (A's minority formula patched in)
    reps = 2 * K.CHUNK // len(zs) + 1
    XX, YY = Sim3(np.tile(X.params, (reps, 1))), Sim3(np.tile(Y.params, (reps, 1)))
    with generic("Sim3.minus_jac"):
        tau, Jr_inv, Jl_inv_neg = Y.minus(X, jac=True)
        big = YY.minus(XX, jac=True)
    for i, (sg, th) in enumerate(cases):
        _check_minus_jacobians(tau[i], Jr_inv[i], Jl_inv_neg[i], f"sigma={sg}, theta={th}")
        j = i + (reps - 1) * len(zs)  # in the last chunk
        _check_minus_jacobians(big[0][j], big[1][j], big[2][j], f"sigma={sg}, theta={th}")
        if th == np.pi:  # Log at exactly pi may take either sign of the axis
            continue
        for b, s in zip(big, (tau, Jr_inv, Jl_inv_neg), strict=True):
            np.testing.assert_allclose(b[j], s[i], rtol=0, atol=1e-14 * max(1.0, abs(s[i]).max()))


def _check_minus_jacobians(tau, Jr_inv, Jl_inv_neg, where):
    """``Jr^-1(tau)`` and ``-Jr^-1(-tau)`` against 50 digits, and the structural entries."""
    _, Jri, _ = reference(tau)
    _, Jli, _ = reference(-tau)
    assert max(_block_errors(Jr_inv, Jri)) <= 1e-12, (where, _block_errors(Jr_inv, Jri))
    assert max(_block_errors(-Jl_inv_neg, Jli)) <= 1e-12, (where, _block_errors(-Jl_inv_neg, Jli))
    assert np.all(Jr_inv[3:6, :3] == 0) and np.all(Jl_inv_neg[6, :6] == 0)
    assert Jr_inv[6, 6] == 1.0 and Jl_inv_neg[6, 6] == -1.0


def test_the_old_generic_series_was_wrong_at_large_sigma():
    """Regression: the generic Jr series (kept for groups without closed forms) is off by
    several hundred percent at sigma = 50; the closed form is not."""
    z = np.array([0.3, -0.2, 0.5, 0.4, -0.7, 1.1, 50.0])
    Jr, _, _ = reference(z)
    assert max(_block_errors(Sim3._jr_series(z), Jr)) > 1.0
    assert max(_block_errors(Sim3.jr(z), Jr)) <= 1e-12


def test_sigma_beyond_range_raises():
    ok = np.array([0.1, 0.2, 0.3, 0.1, 0.2, 0.3, sim3.SIGMA_MAX])
    Sim3.exp(ok), Sim3.jr(ok), Sim3.jr_inv(ok), Sim3.jl(-ok)
    for s in (sim3.SIGMA_MAX + 0.5, -sim3.SIGMA_MAX - 0.5):
        bad = np.array([[0.0] * 7, [0.1, 0.2, 0.3, 0.1, 0.2, 0.3, s]])
        for f in (Sim3.exp, Sim3.jr, Sim3.jr_inv, Sim3.jl, Sim3.jl_inv):
            with pytest.raises(ValueError, match="SIGMA_MAX"):
                f(bad)
        X = Sim3.from_rotation_translation_scale(np.eye(3), [1.0, 2.0, 3.0], np.exp(s))
        I = Sim3.identity()
        calls = [(X.log, ()), (X.log, (True,)), (X.minus, (I,)), (X.lminus, (I,)),
                 (I.minus, (X, True)), (I.plus, (bad[1],)), (I.lplus, (bad,))]
        for f, args in calls:
            with pytest.raises(ValueError, match="SIGMA_MAX"):
                f(*args)
    # the edge itself is accepted both ways
    E = Sim3.exp(ok)
    assert abs(E.log()[6] - sim3.SIGMA_MAX) < 1e-12


@pytest.mark.parametrize("sigma", [0.0, 1e-12, 0.5, -3.0, 40.0])
def test_float32_is_sane(sigma):
    rng = np.random.default_rng(7)
    for theta in (0.0, 1e-6, 1.0, np.pi - 1e-3):
        z = _tangent(rng, sigma, theta)
        J64, Ji64 = Sim3.jr(z), Sim3.jr_inv(z)
        J32, Ji32 = Sim3.jr(z.astype(np.float32)), Sim3.jr_inv(z.astype(np.float32))
        assert J32.dtype == np.float32 and Ji32.dtype == np.float32
        # float32 input rounding alone moves sigma by ~6e-8 |sigma|, the scale by that times
        # e^sigma: compare against float64 at the rounded input
        z32 = z.astype(np.float32).astype(np.float64)
        for a, b in ((J32, Sim3.jr(z32)), (Ji32, Sim3.jr_inv(z32))):
            assert max(_block_errors(a.astype(np.float64), b)) <= 2e-5, (sigma, theta)
        assert np.isfinite(J64).all() and np.isfinite(Ji64).all()


@pytest.mark.parametrize("bk", ["torch", "jax"])
def test_backends_and_gradients_at_sigma_and_theta_zero(bk):
    """Same numbers on torch/JAX; gradients of Exp, Log and Jr finite at sigma = theta = 0 and
    equal to central differences of the closed forms elsewhere."""
    rng = np.random.default_rng(8)
    zs = np.array([_tangent(rng, s, t) for s, t in
                   [(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1e-12, 1e-12), (-20.0, 3.0)]])
    zb = to_backend(zs, bk)
    with generic("Sim3.jr"), generic("Sim3.jr_inv"):  # the same formulas (a compiled kernel
        jr, jr_inv = Sim3.jr(zs), Sim3.jr_inv(zs)     # agrees to 1e-13, test_kernels.py)
    np.testing.assert_allclose(to_numpy(Sim3.jr(zb)), jr, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(to_numpy(Sim3.jr_inv(zb)), jr_inv, rtol=1e-13, atol=1e-13)

    def loss(z):  # a sum over the batch: its gradient holds each element's gradient
        X = Sim3.exp(z)
        return (X.params.sum() + Sim3.jr(z).sum() + Sim3.jr_inv(z).sum()
                + (X @ X).log().sum())

    if bk == "torch":
        torch = require("torch")
        t = torch.tensor(zs, requires_grad=True)
        loss(t).backward()
        g = t.grad.numpy()
    else:
        jax = require("jax")
        g = np.asarray(jax.grad(loss)(zb))
    assert np.all(np.isfinite(g)), g
    h = 1e-6
    for z, gz in zip(zs, g, strict=True):
        if np.linalg.norm(z[3:]) > 0.5:  # away from the patched origin: the true gradient
            fd = np.array([(loss(z + h * e) - loss(z - h * e)) / (2 * h) for e in np.eye(7)])
            np.testing.assert_allclose(gz, fd, rtol=1e-6, atol=1e-6)


def test_jax_jit_and_vmap():
    jax = require("jax")
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    z = np.random.default_rng(9).standard_normal((6, 7))
    np.testing.assert_allclose(np.asarray(jax.jit(Sim3.jr)(jnp.asarray(z))), Sim3.jr(z),
                               atol=1e-14)
    np.testing.assert_allclose(np.asarray(jax.vmap(Sim3.jr_inv)(jnp.asarray(z))),
                               Sim3.jr_inv(z), atol=1e-13)
