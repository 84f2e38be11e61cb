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
from conftest import GROUPS, IN_CI, require, tangent_with_angle

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
    """Parameters of elements whose rotation is by exactly pi (``_exact_pi_element``, no
    rounding), alone and composed with random elements of rotation 0 (translations, velocities,
    scale exponent 0 for Sim3), and some whose quaternion has w < 0 (rotation groups of 3D)."""
    X = G._exact_pi_element()
    tau = rng.standard_normal((n, G.dof))
    tau[:, G._rotation_slice] = 0.0
    if G.dof == 7:
        tau[::2, 6] = 0.0
    p = np.array((G.exp(tau) @ X).params)
    p[0] = X.params
    rot = G if not hasattr(G, "_dims") else G._rotation
    if rot is ml.SO3:  # quaternions: the other sign of the double cover, w <= 0
        lo, hi = (0, 4) if G is ml.SO3 else G._dims()
        p[n // 2:, lo:hi] = -p[n // 2:, lo:hi]
    return p


# Sim3 log-scales: 0 exactly, tiny, around the series/recurrence switch at |sigma| = 2, large,
# and the extremes +-SIGMA_MAX = 50 (tangent inputs; elements are built within +-20 so that
# products of two stay finite in float32)
SIGMAS = (0.0, 0.0, 1e-12, -1e-7, 1.9999, -2.0001, 7.5, -30.0, 50.0, -50.0)


def _inputs(k, dtype, rng):
    G = k.group
    taus = np.concatenate([tangent_with_angle(G, rng, th, 4) for th in HARD])
    if G is ml.Sim3:  # every hard angle paired with several hard scales
        taus = np.concatenate([taus] * 3)
        taus[:, 6] = np.resize(SIGMAS, len(taus))
        taus = taus[rng.permutation(len(taus))]
    out = []
    for kind in k.ins:
        if kind == "t":
            x = taus
        elif kind == "p":
            t = taus.copy()
            if G is ml.Sim3:
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
    """Every compiled kernel of every group (the generated batched kernels of ``_lie`` and the
    one-element ones of ``_one``): float64 against the generic kernel (1e-13); float32 (computed in
    float64, rounded once) against the compiled kernel's own float64 result on the same inputs
    (a few float32 ulps) and against the generic float64 kernel on them (1e-5: float32 inputs
    are not exactly unit quaternions, on which equivalent formulas differ, e.g. Sim3 minus_jac
    by 2.4e-6). The generic float32 kernel is no reference: its float32 intermediates cancel (Y
    X^-1 of two equal Sim3 elements with translations of 3e7 and scale e^20 comes out 0.5 off,
    one float32 ulp of the translation)."""
    K, names = _compiled()
    generated = {n for n, k in K.KERNELS.items()
                 if k.group in GROUPS and k.fn is not None and n != "SO3.from_matrix"}
    assert set(names) == generated  # every element-wise kernel of every group is compiled
    rng = np.random.default_rng(11)
    for name in names:
        k = K.KERNELS[name]
        assert k.impl is not None and k.one is not None, name
        for dtype in (np.float64, np.float32):
            ins = _inputs(k, dtype, rng)
            n = len(ins[0])
            for case in [ins, *([x[i] for x in ins] for i in (0, 5, n - 1))]:
                single = case[0].ndim == 1
                got = K.run(k, *case)
                impl, one = k.impl, k.one
                k.impl = k.one = None
                try:
                    want = K.run(k, *case)
                    ref = K.run(k, *[x.astype(np.float64) for x in case])
                finally:
                    k.impl, k.one = impl, one
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


def test_batched_kernels_agree_with_the_generic_kernels_across_block_boundaries():
    """The batched kernels run as a row loop or on blocks of 32 elements (row copies by width,
    the block evaluation, threads released above 4 blocks): batches of 1, 31, 33, 64 and 161
    hard inputs (a partial block at either end, whole blocks, more than 4 blocks), float64
    against the generic kernel (1e-13) and float32 against the compiled float64 result."""
    K, names = _compiled()
    rng = np.random.default_rng(5)
    for name in names:
        k = K.KERNELS[name]
        base = _inputs(k, np.float64, rng)
        for n in (1, 31, 33, 64, 161):
            idx = rng.integers(0, len(base[0]), n)
            ins = [np.ascontiguousarray(x[idx]) for x in base]
            got = K.run(k, *ins)
            impl, one = k.impl, k.one
            k.impl = k.one = None
            try:
                want = K.run(k, *ins)
            finally:
                k.impl, k.one = impl, one
            f32 = K.run(k, *[x.astype(np.float32) for x in ins])
            same = K.run(k, *[x.astype(np.float32).astype(np.float64) for x in ins])
            got, want, f32, same = ((r if isinstance(r, tuple) else (r,))
                                    for r in (got, want, f32, same))
            for g, w, h, c in zip(got, want, f32, same, strict=True):
                assert g.shape == w.shape == h.shape and h.dtype == np.float32, name
                assert (e := _row_error(g, w, False)) <= 1e-13, f"{name} n={n}: {e:.2e}"
                assert (e := _row_error(h, c, False)) <= 3e-7, f"{name} n={n} float32: {e:.2e}"


def test_compiled_so3_log_matches_scipy_rotation_vectors():
    """SO3.log of 10,000 quaternions (both signs of w, angles from 0 and 1e-12 to pi - 1e-6, a
    batch of many blocks) against SciPy's ``Rotation.as_rotvec`` (independent code): within
    1.5e-15 of the angle (measured 4.0e-16), exact at angle 0, in float64."""
    _compiled()
    Rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    rng = np.random.default_rng(8)
    n = 10_000
    axis = rng.standard_normal((n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    theta = np.concatenate([[0.0, 1e-12, 1e-8, np.pi - 1e-6], rng.uniform(0.0, np.pi, n - 4)])
    q = np.concatenate([axis * np.sin(theta / 2)[:, None], np.cos(theta / 2)[:, None]], axis=1)
    q[1::2] = -q[1::2]
    got = ml.SO3(q).log()
    want = Rotation.from_quat(q).as_rotvec()
    err = np.abs(got - want).max(axis=1) / np.maximum(theta, 1e-300)
    assert err.max() <= 1.5e-15, err.max()
    assert not got[0].any()


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


def test_the_build_holds_the_kernels_generated_from_todays_formulas():
    """The compiled kernels are generated from the component formulas (microlie._codegen): the
    header of the build is what the generator writes from the formulas of this checkout (a
    formula changed without a rebuild fails here), and it has one C function per element-wise
    kernel of every group."""
    from microlie import _codegen
    from microlie import _kernels as K

    header = ROOT / "src" / "microlie" / "_c" / "generated" / "lie_kernels.h"
    if not header.exists():
        why = f"{header} not generated (no build in this checkout)"
        (pytest.fail if IN_CI else pytest.skip)(why)
    text = _codegen.source()
    assert header.read_text() == text, "rebuild: python setup.py build_ext --inplace"
    for name, k in K.KERNELS.items():
        if k.group in GROUPS and k.fn is not None and name != "SO3.from_matrix":
            assert f"LK_FN void {_codegen.c_name(name)}(" in text, name
    assert "SO3.from_matrix" not in text  # a Python branch on a value: not traceable


def test_vecmath_coefficient_header_is_what_its_generator_writes():
    spec = importlib.util.spec_from_file_location("gen_coeffs", ROOT / "tools" / "gen_coeffs.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    assert gen.VM_HEADER.read_text() == gen.render_vecmath(), "run: python tools/gen_coeffs.py"


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
    old = lie.set_cache_limit(0)  # empty: blocks freed by earlier tests are not in play
    lie.set_cache_limit(64)
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
    """With the extra, single elements of every group run the C functions of
    ``microlie._c._one`` (moved here from test_single.py, whose every test runs on two
    implementations)."""
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0: the Python functions only")
    one = require("microlie._c._one")
    from microlie import _fast

    groups = ("SO2", "SE2", "SO3", "SE3", "Sim3", "SE23")
    names = {f"{g}.{op}{j}" for g in groups for op in _single.OPS for j in ("", "_jac")}
    assert set(_fast.installed_single()) == names
    for name in names:
        g, op = name.split(".")
        c_name = f"j_{g.lower()}_{op}" if op.endswith("_jac") else f"{g.lower()}_{op}"
        assert getattr(getattr(ml, g), f"_one_{op}") is getattr(one, c_name)
    X = ml.SE3.random(rng=0)
    with pytest.raises(TypeError, match="expected 2 arguments"):
        one.se3_compose(X)
    assert type(X @ X) is ml.SE3 and (X @ X)._floats is None  # built in C
    assert sorted(one.OPS) == sorted(groups) and sorted(one.OPS["SE3"]) == sorted(_single.OPS)


def _hard_single_inputs(G, rng):
    """Tangent vectors at the hard angles 0, 1e-12, near pi and pi (Sim3: each with a hard
    log-scale, down to 0 and out to +-SIGMA_MAX) and the elements they make, with the exact pi
    element."""
    taus = [tangent_with_angle(G, rng, th) for th in (0.0, 1e-12, 0.7, np.pi - 1e-6, np.pi)]
    if G is ml.Sim3:
        taus = [t.copy() for t in taus for _ in range(2)]
        for t, sg in zip(taus, SIGMAS, strict=True):
            t[6] = sg
    elements = [G.exp(t) for t in taus] + [G._exact_pi_element()]
    return taus, elements


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_compiled_one_element_operations_equal_the_generic_ones(G):
    """Every one-element operation, values and ``jac=True`` (the generated C of ``_one``:
    ``G.exp(tau)``, ``X.between(Y, jac=True)``, ...), returns what the generic path returns (the
    same types, the same values to rounding: 1e-13 relative to the element's largest entry) at
    the hard angles 0, 1e-12, near pi and pi, and for Sim3 at the hard scales (sigma = 0,
    1e-12, +-2, +-50 = SIGMA_MAX)."""
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0: the Python functions only")
    one = require("microlie._c._one")
    rng = np.random.default_rng(5)
    taus, elements = _hard_single_inputs(G, rng)
    v = rng.standard_normal(G.point_dim)
    fast = {a: G.__dict__[a] for a in G.__dict__ if a.startswith("_one_")}
    assert len(fast) == 2 * len(_single.OPS)
    assert all(getattr(G, a).__self__ is one for a in fast)  # the C functions, not Python's
    # second operands: for Sim3 those of log-scale at most 2.5 (minus stays within the range)
    ys = [e for e in elements if G is not ml.Sim3 or abs(np.log(e.params[7])) <= 2.5]
    for i, X in enumerate(elements):
        tau, Y = taus[i % len(taus)], ys[(i + 3) % len(ys)]
        calls = [(G.exp, (tau,)), (X.log, ()), (X.inverse, ()), (X.compose, (Y,)),
                 (X.between, (Y,)), (X.act, (v,)), (X.plus, (tau,)), (X.minus, (Y,))]
        for method, args in calls:
            for jac in (False, True):
                got = method(*args, jac=True) if jac else method(*args)
                for a in fast:
                    setattr(G, a, staticmethod(lambda *args: None))
                try:
                    want = method(*args, jac=True) if jac else method(*args)
                finally:
                    for a, f in fast.items():
                        setattr(G, a, f)
                got, want = (got, want) if jac else ((got,), (want,))
                assert len(got) == len(want)
                for g, w in zip(got, want, strict=True):
                    assert type(g) is type(w)
                    g, w = np.asarray(getattr(g, "params", g)), np.asarray(getattr(w, "params", w))
                    assert g.shape == w.shape and g.dtype == w.dtype == np.float64
                    np.testing.assert_allclose(g, w, rtol=0,
                                               atol=1e-13 * max(1.0, np.abs(w).max()))


def test_compiled_sim3_single_elements_apply_the_scale_range():
    """Sim3's range check |sigma| <= SIGMA_MAX in the compiled single elements: a tangent input
    (exp, plus) or output (log, minus) beyond it makes the C function return None, and the
    public call then raises the generic path's ValueError; at the bound itself the C result
    equals the exponential of the 4x4 algebra matrix (scipy)."""
    if os.environ.get("MICROLIE_FAST") == "0":
        pytest.skip("MICROLIE_FAST=0: the Python functions only")
    from scipy.linalg import expm

    from microlie.groups.sim3 import SIGMA_MAX

    one = require("microlie._c._one")
    G = ml.Sim3
    at = np.array([0.3, -0.2, 0.1, 0.4, -0.5, 0.6, -SIGMA_MAX])
    X = one.sim3_exp(at)
    assert type(X) is G
    got, want = X.matrix(), expm(G.hat(at))
    for block in (np.s_[:3, :3], np.s_[:3, 3]):  # s R (about e^-50) and t, each to its scale
        np.testing.assert_allclose(got[block], want[block], rtol=0,
                                   atol=1e-11 * np.abs(want[block]).max())
    beyond = at.copy()
    beyond[6] = -SIGMA_MAX * (1.0 + 1e-9)
    E = G.identity()
    big = G.exp(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 30.0]))  # big @ big: sigma = 60
    for fn, args in [(one.sim3_exp, (beyond,)), (one.j_sim3_exp_jac, (beyond,)),
                     (one.sim3_plus, (E, beyond)), (one.j_sim3_plus_jac, (E, beyond)),
                     (one.sim3_log, (big @ big,)), (one.j_sim3_log_jac, (big @ big,)),
                     (one.sim3_minus, (big @ big, E)), (one.j_sim3_minus_jac, (big @ big, E))]:
        assert fn(*args) is None, fn.__name__
    for call in (lambda: G.exp(beyond), lambda: G.exp(beyond, jac=True),
                 lambda: E.plus(beyond), lambda: (big @ big).log(),
                 lambda: (big @ big).log(jac=True), lambda: (big @ big).minus(E)):
        with pytest.raises(ValueError, match="exceeds SIGMA_MAX"):
            call()
    assert one.sim3_log(big) is not None and one.sim3_minus(big, E) is not None


@pytest.mark.parametrize("G", [ml.SO3, ml.SE3, ml.Sim3])
def test_angles_beyond_the_compiled_reduction_take_the_generic_kernel(G, monkeypatch):
    """vecmath.h reduces angles up to 2**26 rad exactly and returns NaN beyond; such rows are
    computed by the generic kernel (the result equals it, no error); a NaN input still raises."""
    require("microlie._c._lie")
    from microlie import _kernels as K

    k = K.KERNELS[f"{G.__name__}.exp"]
    if k.impl is None:
        pytest.skip("the compiled kernels are not registered (MICROLIE_FAST=0)")
    rng = np.random.default_rng(3)
    v = rng.standard_normal((5, G.dof))
    v[1, 0] = 3e8  # an angle far beyond 2**26 (the rest is ordinary)
    with_c = G.exp(v).params
    monkeypatch.setattr(k, "impl", None)  # the generic kernel alone
    generic = G.exp(v).params
    monkeypatch.undo()
    np.testing.assert_allclose(with_c, generic, rtol=1e-12, atol=1e-12)
    v[2, 1] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        G.exp(v)
