"""Outputs larger than the block cache (issue 19, item 17).

Both output caches (the generic kernels' pool in ``microlie._kernels`` and the compiled
kernels' cache in ``microlie._c._lie``) keep one freed block above their limit, the latest,
for the next output of that size: a Jacobian of 1e6 SE3 elements (288 MB, above the default
256 MB) no longer comes in fresh pages on every call. Checked here with small limits: the
results above the limit equal the same kernel's results computed in small batches (which never
touch the cache), a live result never shares memory with a new one, the freed block is reused,
and the cache holds at most one block above its limit. Timings: ``benchmarks/output_cache.py``.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import require

from microlie import SE3

N = 60_000  # Jacobians of 17.3 MB (float64) and 8.6 MB (float32): above the limits below


def _elements(seed: int, n: int, dtype) -> SE3:
    return SE3(SE3.random(n, rng=np.random.default_rng(seed)).params.astype(dtype))


def _small_batches(X: SE3, size: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    """log(jac=True) in batches below every cache threshold, concatenated."""
    parts = [X[i:i + size].log(jac=True) for i in range(0, len(X), size)]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _address(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


def _check(got: tuple, want: tuple, dtype) -> None:
    tol = 1e-12 if dtype == np.float64 else 1e-5
    for g, w in zip(got, want, strict=True):
        assert g.dtype == dtype and g.shape == w.shape
        np.testing.assert_allclose(g, w, rtol=tol, atol=tol)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_issue19_item17_compiled_outputs_above_the_cache_limit(dtype):
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0")
    lie = require("microlie._c._lie")
    from microlie._fast import installed

    assert "SE3.log_jac" in installed()
    X, Y, Z = (_elements(s, N, dtype) for s in (1, 2, 3))
    want = {k: _small_batches(V) for k, V in (("X", X), ("Y", Y), ("Z", Z))}
    old = lie.set_cache_limit(4)  # 4 MB
    try:
        a = X.log(jac=True)
        assert a[1].nbytes > 4 << 20
        b = Y.log(jac=True)
        assert not np.shares_memory(a[1], b[1])
        _check(a, want["X"], dtype)
        _check(b, want["Y"], dtype)
        addr = _address(b[1])
        del a, b
        info = lie.cache_info()
        assert info.get("large", 0) >= N * 36 * np.dtype(dtype).itemsize  # kept: one block
        assert info["bytes"] <= info["limit"]
        c = Z.log(jac=True)
        assert _address(c[1]) == addr  # reused
        assert lie.cache_info()["large"] == 0  # handed out, not shared
        _check(c, want["Z"], dtype)
        del c
        bigger = (N + 20000) * 36 * np.dtype(dtype).itemsize
        d = _elements(4, N + 20000, dtype).log(jac=True)  # too large for the kept block
        del d
        assert lie.cache_info()["large"] >= bigger  # the latest replaced it: one block
        assert lie.cache_info()["large"] < bigger + bigger // 4 + (4 << 20)
    finally:
        lie.set_cache_limit(old)
    assert lie.cache_info()["large"] == 0  # set_cache_limit releases it
