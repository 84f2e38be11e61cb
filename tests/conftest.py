"""Shared test fixtures: the groups, the array backends and finite differences.

In CI (``CI=true``) a missing optional dependency or data file is an error, never a skip.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
from pathlib import Path

import numpy as np
import pytest

import microlie as ml
from microlie import LieGroup
from microlie import _kernels as _K

IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")
# The generic suite (test_groups, test_autodiff, ...) runs on every group of this list: adding a
# group to it is one entry here (SE_2(3) is the entry ``ml.SE23``). Group-specific test facts
# live on the class: ``_rotation_slice`` (the rotation's entries of the tangent) and
# ``_exact_pi_element()`` (a rotation by exactly pi); a Pose derives both from its rotation group.
GROUPS = [ml.SO2, ml.SE2, ml.SO3, ml.SE3, ml.Sim3, ml.SE23]
BACKENDS = ["numpy", "torch", "jax"]
BATCH_SHAPES = [(), (1,), (3, 1, 2)]
DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
# fixture-generation scripts import peers (gtsam, cv2) that CI does not install: not test modules
collect_ignore = ["fixtures"]


def require(module: str):
    """Import an optional module; skip locally, fail in CI, when it is missing."""
    try:
        return importlib.import_module(module)
    except ImportError:
        why = f"{module} not installed"
        if module.startswith("microlie._c"):  # a compiled module: say why it is missing
            from microlie import _fast

            why = f"{module} was not built: {_fast.describe()}"
        if IN_CI:
            pytest.fail(f"{why}; CI requires it")
        pytest.skip(why)


def data_file(rel: str) -> Path:
    """A file of ../shared/data; skip locally, fail in CI, when it is missing."""
    p = DATA / rel
    if not p.exists():
        if IN_CI:
            pytest.fail(f"shared data file {p} is missing")
        pytest.skip(f"shared data file {p} is missing")
    return p


def _jax(x64: bool = True):
    """The ``jax`` module, with float64 (``jax_enable_x64``) on, or off with ``x64=False``,
    for the running test only (:func:`_jax_precision` turns it off after every test)."""
    jax = require("jax")
    jax.config.update("jax_enable_x64", x64)
    return jax


def _x64_off() -> None:
    jax = sys.modules.get("jax")
    if jax is not None:  # never imports JAX for a test that does not use it
        jax.config.update("jax_enable_x64", False)


@pytest.fixture(autouse=True)
def _jax_precision():
    """Every test starts and ends with JAX in its default precision, as users run it:
    ``jax_enable_x64`` off (float32 arrays, float64 requests silently float32). A test that
    needs float64 JAX turns x64 on for itself (:func:`_jax`, or :func:`to_backend` with
    float64); float32 JAX tests run with it off (``to_backend(..., "jax", np.float32)``,
    ``_jax(x64=False)``), so the float32 paths are tested as they run outside the tests."""
    _x64_off()
    yield
    _x64_off()


def to_backend(x: np.ndarray, backend: str, dtype=np.float64):
    """``x`` as an array of ``backend`` and ``dtype``; on JAX x64 is turned on for float64 and
    off for float32 (the mode a user of that dtype runs in), for the rest of the test."""
    x = np.asarray(x, dtype=dtype)
    if backend == "numpy":
        return x
    if backend == "torch":
        torch = require("torch")
        return torch.tensor(x)
    if backend == "jax":
        _jax(x64=x.dtype == np.float64)
        import jax.numpy as jnp

        return jnp.asarray(x)
    raise ValueError(backend)


def to_numpy(x) -> np.ndarray:
    if isinstance(x, LieGroup):
        x = x.params
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def element(G, params: np.ndarray, backend: str, dtype=np.float64) -> LieGroup:
    return G(to_backend(params, backend, dtype))


@pytest.fixture(params=GROUPS, ids=lambda g: g.__name__)
def group(request):
    return request.param


@pytest.fixture(params=BATCH_SHAPES, ids=lambda s: "batch" + "x".join(map(str, s)))
def batch_shape(request):
    return request.param


@pytest.fixture(params=BACKENDS)
def backend(request):
    if request.param == "torch":
        require("torch")
    if request.param == "jax":
        _jax()
    return request.param


# ------------------------------------------------------------------------ tangent vectors

def tangent_with_angle(G, rng: np.random.Generator, theta: float, size=None) -> np.ndarray:
    """A random tangent vector of ``G`` whose rotation angle is exactly ``theta``."""
    shape = () if size is None else (size,) if isinstance(size, int) else tuple(size)
    tau = rng.standard_normal((*shape, G.dof))
    sl = G._rotation_slice
    rot = tau[..., sl]
    n = rot.shape[-1]
    if n == 1:
        tau[..., sl] = theta * np.sign(rot + 1e-300)
    else:
        axis = rot / np.linalg.norm(rot, axis=-1, keepdims=True)
        tau[..., sl] = theta * axis
    return tau


def rotation_angle(G, tau: np.ndarray) -> np.ndarray:
    return np.linalg.norm(tau[..., G._rotation_slice], axis=-1)


def hard_elements(G, rng: np.random.Generator) -> dict:
    """Sophus-style hard elements of ``G``: near the identity, a rotation by exactly pi (built
    without rounding, and reached by composing two quarter turns), and a rotation whose
    quaternion has ``w`` about 1e-11 (angle ``pi - 2e-11``)."""
    half = G.exp(tangent_with_angle(G, rng, np.pi / 2))
    return {
        "near_identity": G.exp(1e-8 * rng.standard_normal(G.dof)),
        "exact_pi": G._exact_pi_element(),
        "pi_by_composition": half @ half,
        "w_1e-11": G.exp(tangent_with_angle(G, rng, np.pi - 2e-11)),
    }


# ------------------------------------------------------------------------ finite differences

def fd_jacobian(f, args: list, i: int, side: str = "right", h: float = 1e-6) -> np.ndarray:
    """Central finite-difference Jacobian of ``f(*args)`` with respect to ``args[i]``.

    Group arguments are perturbed with ``plus`` (right) or ``lplus`` (left), vector arguments
    additively; group outputs are differenced with ``minus`` / ``lminus``. Independent of the
    analytic Jacobians: only ``Exp``/``Log`` and composition are used.
    """
    x = args[i]
    y0 = f(*args)
    dim = x.dof if isinstance(x, LieGroup) else np.asarray(x).shape[-1]
    cols = []
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = h
        outs = []
        for sgn in (1.0, -1.0):
            a = list(args)
            if isinstance(x, LieGroup):
                d = x.exp(sgn * e)
                a[i] = x @ d if side == "right" else d @ x
            else:
                a[i] = x + sgn * e
            outs.append(f(*a))
        if isinstance(y0, LieGroup):
            if side == "right":
                dp, dm = y0.inverse() @ outs[0], y0.inverse() @ outs[1]
            else:
                dp, dm = outs[0] @ y0.inverse(), outs[1] @ y0.inverse()
            cols.append((dp.log() - dm.log()) / (2 * h))
        else:
            cols.append((np.asarray(outs[0]) - np.asarray(outs[1])) / (2 * h))
    return np.stack(cols, axis=-1)


# Hypothesis: CI replays a fixed set of examples (reproducible); local runs explore.
@contextlib.contextmanager
def generic(name: str):
    """The generic kernel ``name`` (a compiled replacement, if any, set aside meanwhile)."""
    saved = _K.KERNELS[name].impl
    _K.register(name, None)
    try:
        yield
    finally:
        _K.register(name, saved)


from hypothesis import settings as _hsettings  # noqa: E402

_hsettings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if IN_CI:
    _hsettings.load_profile("ci")
