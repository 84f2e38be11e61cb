"""Tests of :mod:`microlie._linalg` against NumPy/SciPy, on NumPy, PyTorch and JAX.

Every function is run on each backend in float64 and float32, single and batched, and its
result compared with NumPy's or SciPy's on the same numbers (float64 reference); the result
must keep the input's backend and dtype. Gradients through torch and ``jax.jit`` are checked
against closed forms (``d tr(A^-1 B) / dB = A^-T``, ``d log det A / dA = A^-T``).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from conftest import BACKENDS, _jax, require, to_backend, to_numpy

from microlie import _linalg as L

DTYPES = [np.float64, np.float32]
BATCHES = [(), (3,), (2, 1, 4)]


def spd(rng, batch, n):
    B = rng.standard_normal((*batch, n, n))
    return B @ np.swapaxes(B, -1, -2) + n * np.eye(n)


def tol(dtype):
    return 1e-11 if dtype == np.float64 else 2e-4


def check(out, ref, like, dtype):
    """Same backend and dtype as ``like``, values equal to ``ref`` to the dtype's tolerance."""
    assert type(out).__module__.split(".")[0] == type(like).__module__.split(".")[0]
    assert str(out.dtype).endswith(np.dtype(dtype).name)
    got = to_numpy(out).astype(np.float64)
    assert got.shape == np.shape(ref)
    atol = tol(dtype) * max(1.0, np.abs(ref).max())
    np.testing.assert_allclose(got, ref, rtol=tol(dtype), atol=atol)


@pytest.fixture(params=BACKENDS)
def backend(request):
    if request.param == "jax":
        _jax()
    elif request.param == "torch":
        require("torch")
    return request.param


@pytest.mark.parametrize("dtype", DTYPES, ids=["f64", "f32"])
@pytest.mark.parametrize("batch", BATCHES, ids=str)
def test_against_numpy_scipy(backend, dtype, batch):
    rng = np.random.default_rng(7)
    n, k = 4, 2
    a = spd(rng, batch, n)
    g = rng.standard_normal((*batch, n, n)) + 3 * np.eye(n)  # general, well conditioned
    b = rng.standard_normal((*batch, n, k))
    low = np.linalg.cholesky(a)
    a = np.linalg.cholesky(a) @ np.swapaxes(low, -1, -2)  # exactly symmetric in float64
    # the references are computed on the values the backend actually sees (rounded to dtype)
    a, g, b = (x.astype(dtype).astype(np.float64) for x in (a, g, b))
    low = np.linalg.cholesky(a)
    A_, G_, B_ = (to_backend(x, backend, dtype) for x in (a, g, b))

    check(L.mT(G_), np.swapaxes(g, -1, -2), G_, dtype)
    check(L.symmetrize(G_), 0.5 * (g + np.swapaxes(g, -1, -2)), G_, dtype)
    check(L.solve(G_, B_), np.linalg.solve(g, b), G_, dtype)
    check(L.inv(G_), np.linalg.inv(g), G_, dtype)
    check(L.cholesky(A_), low, A_, dtype)
    check(L.cho_solve(L.cholesky(A_), B_), np.linalg.solve(a, b), A_, dtype)
    ref_tri = np.stack([sla.solve_triangular(m, r, lower=True)
                        for m, r in zip(low.reshape(-1, n, n), b.reshape(-1, n, k), strict=True)]
                       ).reshape(b.shape)
    check(L.solve_triangular(to_backend(low, backend, dtype), B_), ref_tri, A_, dtype)
    ref_up = np.linalg.solve(np.swapaxes(low, -1, -2), b)
    check(L.solve_triangular(L.mT(to_backend(low, backend, dtype)), B_, lower=False), ref_up,
          A_, dtype)
    w, V = L.eigh(A_)
    w_ref = np.linalg.eigvalsh(a)
    check(w, w_ref, A_, dtype)
    check(L.eigvalsh(A_), w_ref, A_, dtype)
    # eigenvectors are unique up to sign: compare the reconstruction and orthonormality
    Vn = to_numpy(V).astype(np.float64)
    np.testing.assert_allclose(Vn @ (w_ref[..., :, None] * np.swapaxes(Vn, -1, -2)), a,
                               rtol=tol(dtype), atol=tol(dtype) * np.abs(a).max())
    S = L.sqrt_psd(A_)
    Sn = to_numpy(S).astype(np.float64)
    np.testing.assert_allclose(Sn @ np.swapaxes(Sn, -1, -2), a, rtol=tol(dtype),
                               atol=tol(dtype) * np.abs(a).max())
    check(L.det(G_), np.linalg.det(g), G_, dtype)
    sign, logdet = L.slogdet(G_)
    s_ref, ld_ref = np.linalg.slogdet(g)
    check(sign, s_ref, G_, dtype)
    check(logdet, ld_ref, G_, dtype)
    check(L.diag(G_), np.diagonal(g, axis1=-2, axis2=-1), G_, dtype)
    v = B_[..., 0]
    check(L.diag_embed(v), b[..., 0][..., :, None] * np.eye(n), G_, dtype)
    check(L.eye(n, G_), np.eye(n), G_, dtype)
    check(L.eye(n, G_, batch_shape=(2, 3)), np.broadcast_to(np.eye(n), (2, 3, n, n)), G_, dtype)
    check(L.zeros((2, n), G_), np.zeros((2, n)), G_, dtype)
    check(L.broadcast_to(G_, (5, *g.shape)), np.broadcast_to(g, (5, *g.shape)), G_, dtype)
    check(L.concat([G_, B_], axis=-1), np.concatenate([g, b], axis=-1), G_, dtype)
    check(L.stack([G_, G_], axis=0), np.stack([g, g]), G_, dtype)
    assert L.numel(G_) == g.size
    c = L.copy(G_)
    check(c, g, G_, dtype)
    np.testing.assert_array_equal(L.concrete(G_), g.astype(dtype))


def test_solve_broadcasts_batch(backend):
    rng = np.random.default_rng(1)
    a = spd(rng, (), 3)
    b = rng.standard_normal((4, 2, 3, 2))
    out = L.solve(to_backend(a, backend), to_backend(b, backend))
    np.testing.assert_allclose(to_numpy(out), np.linalg.solve(a, b), rtol=1e-12)
    out = L.cho_solve(L.cholesky(to_backend(a, backend)), to_backend(b, backend))
    np.testing.assert_allclose(to_numpy(out), np.linalg.solve(a, b), rtol=1e-12)


def test_copy_is_independent_and_numpy_read_only():
    a = np.eye(3)
    c = L.copy(a)
    a[0, 0] = 5.0
    assert c[0, 0] == 1.0
    with pytest.raises(ValueError, match="read-only"):
        c[0, 0] = 2.0
    torch = require("torch")
    t = torch.eye(3)
    ct = L.copy(t)
    t[0, 0] = 5.0
    assert float(ct[0, 0]) == 1.0


def test_torch_autograd():
    torch = require("torch")
    rng = np.random.default_rng(3)
    a = spd(rng, (), 3)
    b = rng.standard_normal((3, 3))
    At = torch.tensor(a, requires_grad=True)
    Bt = torch.tensor(b, requires_grad=True)
    # d tr(A^-1 B) / dB = A^-T ; d log det A / dA = A^-T (through Cholesky and slogdet)
    torch.trace(L.cho_solve(L.cholesky(At), Bt)).backward()
    np.testing.assert_allclose(Bt.grad.numpy(), np.linalg.inv(a).T, rtol=1e-12)
    At.grad = None
    L.slogdet(At)[1].backward()
    np.testing.assert_allclose(At.grad.numpy(), np.linalg.inv(a).T, rtol=1e-12)
    Bt.grad = None
    torch.trace(L.solve(L.symmetrize(At), L.copy(Bt))).backward()
    np.testing.assert_allclose(Bt.grad.numpy(), np.linalg.inv(a).T, rtol=1e-12)


def test_jax_jit_and_grad():
    jax = _jax()
    import jax.numpy as jnp

    rng = np.random.default_rng(4)
    a = spd(rng, (2,), 3)
    b = rng.standard_normal((2, 3, 1))

    @jax.jit
    def f(a, b):
        return L.cho_solve(L.cholesky(a), b) + L.solve(L.symmetrize(a), b) \
            + L.diag(L.inv(a))[..., None] * 0

    np.testing.assert_allclose(np.asarray(f(jnp.asarray(a), jnp.asarray(b))),
                               2 * np.linalg.solve(a, b), rtol=1e-12)
    g = jax.grad(lambda a: L.slogdet(a)[1].sum())(jnp.asarray(a))
    np.testing.assert_allclose(np.asarray(g), np.swapaxes(np.linalg.inv(a), -1, -2), rtol=1e-10)

    # concrete() never forces a tracer
    seen = []
    jax.jit(lambda x: seen.append(L.concrete(x)) or x)(jnp.ones(2))
    assert seen == [None]


def test_uncertainty_knows_no_array_library():
    """``uncertainty`` goes through ``_linalg``/``_array`` for everything backend-specific: no
    backend test, no torch/JAX import, no NumPy-array type check in its source."""
    import re
    from pathlib import Path

    import microlie.uncertainty as U

    src = Path(U.__file__).read_text()
    bad = re.findall(r"is_numpy|is_torch|is_jax|is_traced|isinstance\([^)]*np\.ndarray|"
                     r"import torch|import jax|\.detach\(", src)
    assert not bad, bad
