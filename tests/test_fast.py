"""The compiled kernels (``microlie._c``, built by ``pip install .``): every one agrees with
the generic kernel it replaces on the hard inputs (float64 and float32, batched and single), the
generated header matches microlie.groups._math, ``MICROLIE_FAST=0`` disables them, bad arguments
are errors. The reference is the generic component kernel (independent code: NumPy formulas of
microlie.groups, not the C element functions)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import require, tangent_with_angle

import microlie as ml
from microlie.groups import _single

ROOT = Path(__file__).resolve().parents[1]
HARD = (0.0, 1e-12, 1e-7, 1e-4, 0.7, 3.0, np.pi - 1e-6, np.pi)


def _compiled():
    """The registry and the names of the installed compiled kernels (re-registered: another
    test may have swapped a replacement)."""
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0: the generic kernels only")
    require("microlie._c._lie")
    K = importlib.import_module("microlie._kernels")
    from microlie import _fast

    names = _fast.install()
    assert {"SO3.exp", "SO3.log", "SE3.exp", "SE3.log", "SE3.compose", "SE3.act",
            "SE3.exp_jac", "SE3.act_jac", "SE3.minus_jac", "SE3.between_jac", "SE3.jr",
            "SE3.jr_inv", "Sim3.exp", "Sim3.log", "Sim3.compose", "Sim3.act", "Sim3.jr",
            "Sim3.jr_inv", "Sim3.minus_jac", "Sim3.between_jac"} <= set(names)
    return K, names


def _exact_pi_params(G, rng, n):
    """Parameters of rotations by exactly pi (w = 0 exactly), and some with w < 0."""
    q = rng.standard_normal((n, 4))
    q[: n // 2, 3] = 0.0
    q[: 2] = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[n // 2:, 3] = -np.abs(q[n // 2:, 3])
    if G.param_dim == 4:
        return q
    t = rng.standard_normal((n, 3))
    if G.param_dim == 8:  # Sim3: a scale, exactly 1 for half of them
        s = np.exp(rng.uniform(-5.0, 5.0, (n, 1)))
        s[::2] = 1.0
        return np.concatenate([t, q, s], axis=1)
    return np.concatenate([t, q], axis=1)


# Sim3 log-scales: 0 exactly, tiny, around the series/recurrence switch at |sigma| = 2, large,
# and the extremes +-SIGMA_MAX = 50 (tangent inputs; elements are built within +-20 so that
# products of two stay finite in float32)
SIGMAS = (0.0, 0.0, 1e-12, -1e-7, 1.9999, -2.0001, 7.5, -30.0, 50.0, -50.0)


def _inputs(k, dtype, rng):
    G = k.group
    taus = np.concatenate([tangent_with_angle(G, rng, th, 4) for th in HARD])
    if G.dof == 7:  # Sim3: every hard angle paired with several hard scales
        taus = np.concatenate([taus] * 3)
        taus[:, 6] = np.resize(SIGMAS, len(taus))
        taus = taus[rng.permutation(len(taus))]
    out = []
    for kind in k.ins:
        if kind == "t":
            x = taus
        elif kind == "p":
            t = taus.copy()
            if G.dof == 7:
                t[:, 6] = np.clip(t[:, 6], -20.0, 20.0)
            x = np.concatenate([G.exp(t).params, _exact_pi_params(G, rng, 8)])[: len(taus)]
            x = rng.permutation(x)
        elif kind == "v":
            x = rng.standard_normal((len(taus), G.point_dim)) * 10.0
        else:
            raise AssertionError(f"unknown input kind {kind!r} of {k.name}")
        out.append(np.ascontiguousarray(x, dtype=dtype))
    return out


def _row_error(g, w, single: bool) -> float:
    """Largest difference relative to the largest entry of its element (at least 1): one scale
    per element, so that a huge entry of one element (a scale e^50) hides nothing elsewhere."""
    g = g.astype(float).reshape(1 if single else len(g), -1)
    w = w.astype(float).reshape(g.shape)
    scale = np.maximum(1.0, np.abs(w).max(axis=1, keepdims=True))
    return float((np.abs(g - w) / scale).max())


def test_compiled_kernels_agree_with_the_generic_kernels():
    """float64 against the generic kernel (1e-13); float32 (computed in float64, rounded once)
    against the compiled kernel's own float64 result on the same inputs (a few float32 ulps)
    and against the generic float64 kernel on them (1e-5: float32 inputs are not exactly unit
    quaternions, on which equivalent formulas differ, e.g. Sim3 minus_jac by 2.4e-6). The
    generic float32 kernel is no reference: its float32 intermediates cancel (Y X^-1 of two equal
    Sim3 elements with translations of 3e7 and scale e^20 comes out 0.5 off, one float32 ulp of
    the translation)."""
    K, names = _compiled()
    rng = np.random.default_rng(11)
    for name in names:
        k = K.KERNELS[name]
        assert k.impl is not None, name
        for dtype in (np.float64, np.float32):
            ins = _inputs(k, dtype, rng)
            n = len(ins[0])
            for case in [ins, *([x[i] for x in ins] for i in (0, 5, n - 1))]:
                single = case[0].ndim == 1
                got = K.run(k, *case)
                impl, k.impl = k.impl, None
                try:
                    want = K.run(k, *case)
                    ref = K.run(k, *[x.astype(np.float64) for x in case])
                finally:
                    k.impl = impl
                same = K.run(k, *[x.astype(np.float64) for x in case])  # compiled, float64
                got = got if isinstance(got, tuple) else (got,)
                want = want if isinstance(want, tuple) else (want,)
                ref = ref if isinstance(ref, tuple) else (ref,)
                same = same if isinstance(same, tuple) else (same,)
                for g, w, r, c in zip(got, want, ref, same, strict=True):
                    assert g.dtype == w.dtype == dtype and g.shape == w.shape, name
                    what = f"{name} {np.dtype(dtype).name} {g.shape}"
                    if dtype == np.float64:
                        assert (e := _row_error(g, w, single)) <= 1e-13, f"{what}: {e:.2e}"
                    else:
                        e = _row_error(g, c, single)
                        assert e <= 3e-7, f"{what} vs its float64 result: {e:.2e}"
                        e = _row_error(g, r, single)
                        assert e <= 1e-5, f"{what} vs the generic float64 one: {e:.2e}"


def test_compiled_kernels_are_used_by_the_classes():
    K, _ = _compiled()
    from microlie import SE3

    k = K.KERNELS["SE3.exp"]
    calls = []
    impl = k.impl

    def counting(t):
        calls.append(t.shape)
        return impl(t)
    K.register("SE3.exp", counting)
    try:
        SE3.exp(np.zeros((5, 6)))
    finally:
        K.register("SE3.exp", impl)
    assert calls == [(5, 6)]


def _gen():
    spec = importlib.util.spec_from_file_location("gen_coeffs", ROOT / "tools" / "gen_coeffs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_coefficient_header_is_generated_from_the_generic_series():
    gen = _gen()
    assert gen.HEADER.read_text() == gen.render(), "run: PYTHONPATH=src python tools/gen_coeffs.py"
    from microlie.groups import _math as M

    text = gen.render()
    assert repr(M.C_COT[-1]) in text and f"#define SMALL2 {M.SMALL2!r}" in text


def test_environment_variable_disables_the_compiled_kernels():
    if os.environ.get("MICROLIE_FAST") != "0":
        require("microlie._c._lie")
    code = "from microlie import _fast; print(len(_fast.installed()), _fast.install())"
    env = dict(os.environ, MICROLIE_FAST="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["0", "[]"]


def test_compiled_kernel_rejects_bad_arguments():
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0")
    lie = require("microlie._c._lie")
    with pytest.raises(ValueError, match=r"SE3.exp: argument 0 .*\(N, 6\)"):
        lie.se3_exp(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="same N and dtype"):
        lie.se3_compose(np.zeros((2, 7)), np.zeros((2, 7), dtype=np.float32))
    with pytest.raises(ValueError, match="C-contiguous"):
        lie.so3_exp(np.zeros((3, 6))[:, ::2])
    with pytest.raises(TypeError, match="expected 2 arguments"):
        lie.so3_act(np.zeros((1, 4)))
    (q,) = lie.so3_exp(np.zeros((0, 3)))
    assert q.shape == (0, 4)


def test_output_cache_reuses_freed_blocks_and_never_a_live_one():
    """Large outputs come from a cache of freed blocks (warm pages): a freed block is reused,
    an array still alive never shares memory with a new result, and the limit 0 disables it."""
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0")
    lie = require("microlie._c._lie")
    from microlie import SE3

    rng = np.random.default_rng(3)
    tau = rng.standard_normal((60_000, 6))  # outputs of 3.4 MB: above the 1 MB threshold
    want = SE3.exp(tau).params.copy()
    old = lie.set_cache_limit(64)
    try:
        (a,) = lie.se3_exp(tau)
        addr = a.ctypes.data
        (b,) = lie.se3_exp(tau)  # a is alive: b must be another block
        assert b.ctypes.data != addr and not np.shares_memory(a, b)
        np.testing.assert_array_equal(a, want)
        np.testing.assert_array_equal(b, want)
        del a
        assert lie.cache_info()["blocks"] >= 1
        (c,) = lie.se3_exp(tau[::-1].copy())  # the freed block, overwritten completely
        assert c.ctypes.data == addr and c.flags.writeable and c.flags.c_contiguous
        np.testing.assert_array_equal(c, want[::-1])
        del b, c
        assert lie.set_cache_limit(0) == 64  # 0: empties the cache and allocates fresh
        assert lie.cache_info()["blocks"] == 0
        (d,) = lie.se3_exp(tau)
        assert d.base is None
        np.testing.assert_array_equal(d, want)
    finally:
        lie.set_cache_limit(old)
    with pytest.raises(ValueError, match=">= 0"):
        lie.set_cache_limit(-1)


def test_output_cache_limit_from_the_environment_is_validated():
    require("microlie._c._lie")
    code = "import microlie._c._lie as L; print(L.cache_info()['limit'])"
    env = dict(os.environ, MICROLIE_FAST_CACHE_MB="3")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == [str(3 << 20)]
    env["MICROLIE_FAST_CACHE_MB"] = "lots"
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert r.returncode != 0 and "MICROLIE_FAST_CACHE_MB must be a whole number" in r.stderr


def test_compiled_one_element_functions_are_in_use():
    """With the extra, SO3/SE3 single elements run the C functions of ``microlie._c._one``
    (moved here from test_single.py, whose every test runs on two implementations)."""
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0: the Python functions only")
    one = require("microlie._c._one")
    from microlie import _fast

    names = {f"{g}.{op}" for g in ("SO3", "SE3") for op in _single.OPS}
    assert set(_fast.installed_single()) == names
    for name in names:
        g, op = name.split(".")
        assert getattr(getattr(ml, g), f"_one_{op}") is getattr(one, f"{g.lower()}_{op}")
    X = ml.SE3.random(rng=0)
    with pytest.raises(TypeError, match="expected 2 arguments"):
        one.se3_compose(X)
    assert type(X @ X) is ml.SE3 and (X @ X)._floats is None  # built in C
    assert sorted(one.OPS) == ["SE3", "SO3"] and sorted(one.OPS["SE3"]) == sorted(_single.OPS)
