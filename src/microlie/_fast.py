"""The optional compiled kernels (``pip install "microlie[fast]"``; from a checkout ``pip install
./fast``).

When the package ``microlie_fast`` is importable, :func:`install` (called once by ``import
microlie``) registers its functions as the NumPy replacements of the kernels they implement (see
:func:`microlie._kernels.register`): every element-wise kernel of every group, values and fused
Jacobians, generated at build time from the component formulas (:mod:`microlie._codegen`), float64
and float32 (computed in float64, rounded once). Set the environment variable ``MICROLIE_FAST=0``
to keep the generic NumPy kernels. The classes and their results do not change: each compiled
kernel agrees with the generic one to rounding (``tests/test_kernels.py``). Single float64 elements
go through the one-element C functions of ``microlie_fast._one``: the element operations of every
group but Sim(3) (:func:`installed_single`) and every kernel, Jacobians included
(:func:`microlie._kernels.register_single`). Large outputs reuse freed blocks (bounded by
``MICROLIE_FAST_CACHE_MB``, default 256, plus the latest freed block above it; see
``microlie_fast``).
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from typing import Any

__all__ = ["compiled", "install", "installed", "installed_single", "text_parser"]

_installed: list[str] = []
_single: list[str] = []
_modules: dict[str, Any] = {}


def compiled(name: str) -> Any:
    """The compiled module ``microlie_fast.<name>`` (``"_graph"``, ``"_chol"``,
    ``"_normal"``, ``"_text"``), or ``None``: ``MICROLIE_FAST=0`` (read on every call),
    microlie-fast not installed, or a build older than that module."""
    if os.environ.get("MICROLIE_FAST", "1").strip() == "0":
        return None
    if name not in _modules:
        try:
            _modules[name] = importlib.import_module(f"microlie_fast.{name}")
        except ImportError:
            _modules[name] = None
    return _modules[name]


def install() -> list[str]:
    """Register the compiled kernels (if ``microlie_fast`` is importable and
    ``MICROLIE_FAST`` is not ``0``); return the names of the kernels registered."""
    if os.environ.get("MICROLIE_FAST", "1").strip() == "0":
        return []
    try:
        _lie = importlib.import_module("microlie_fast._lie")
        K = importlib.import_module("microlie._kernels")  # the kernel registry
    except ImportError:
        return []
    _installed.clear()
    for name, fn in getattr(_lie, "KERNELS", {}).items():  # {} from an older build
        if name in K.KERNELS:
            K.register(name, getattr(_lie, fn))
            _installed.append(name)
    try:  # the one-element entry points (absent from an older build)
        one = importlib.import_module("microlie_fast._one")
    except ImportError:
        one = None
    if one is not None and hasattr(one, "GROUPS"):  # absent from a build before generation
        _single[:] = importlib.import_module("microlie.groups._single").use_compiled(one)
        for name, fn in one.KERNELS.items():
            if name in K.KERNELS:
                K.register_single(name, getattr(one, fn))
    return list(_installed)


def installed() -> list[str]:
    """Names of the kernels that :func:`install` registered in this process."""
    return list(_installed)


def installed_single() -> list[str]:
    """Operations whose single-element fast path :func:`install` switched to the compiled
    one-element functions (``"SE3.compose"``, ...; see :mod:`microlie.groups._single`)."""
    return list(_single)


def text_parser() -> Callable[..., Any] | None:
    """The compiled reader of numeric text tables, ``microlie_fast._text.parse_table``
    (used by :mod:`microlie.traj.io`), or ``None`` (not installed, or ``MICROLIE_FAST=0``)."""
    return getattr(compiled("_text"), "parse_table", None)
    try:
        return importlib.import_module("microlie_fast._text").parse_table
    except (ImportError, AttributeError):  # not installed, or an older build without it
        return None
