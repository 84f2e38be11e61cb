"""The compiled kernels, built with the package (``pip install microlie``; from a checkout
``pip install .``): the extension modules ``microlie._c.<name>`` compiled from
``src/microlie/_c/*.c`` by ``setup.py``.

The build is optional: without a working C compiler the install succeeds without them and the
generic NumPy kernels run; :func:`describe` (printed by ``microlie --version``) says which
kernels are active and why. :func:`module` is the one accessor of a compiled module.

When the compiled modules are present, :func:`install` (called once by ``import microlie``)
registers the functions of ``microlie._c._lie`` as the NumPy replacements of the kernels they
implement (see :func:`microlie._kernels.register`): every element-wise kernel of every group,
values and fused Jacobians, generated at build time from the component formulas
(:mod:`microlie._codegen`), float64 and float32 (computed in float64, rounded once). Set the
environment variable ``MICROLIE_FAST=0`` to keep the generic NumPy kernels. The classes and
their results do not change: each compiled kernel agrees with the generic one to rounding
(``tests/test_kernels.py``). Single float64 elements go through the one-element C functions of
``microlie._c._one``: the element operations of every group (:func:`installed_single`; Sim(3)'s
range check of tangent vectors is in the generated table) and every kernel, Jacobians included
(:func:`microlie._kernels.register_single`). Large outputs reuse freed blocks (bounded by
``MICROLIE_FAST_CACHE_MB``, default 256, plus the latest freed block above it; see
``microlie._c``).
"""

from __future__ import annotations

import importlib
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["module", "compiled", "install", "installed", "installed_single", "text_parser",
           "build_record", "describe"]

_installed: list[str] = []
_single: list[str] = []
_modules: dict[str, Any] = {}
_errors: dict[str, str] = {}


def _disabled() -> bool:
    return os.environ.get("MICROLIE_FAST", "1").strip() == "0"


def module(name: str) -> Any:
    """The compiled module ``microlie._c.<name>`` (one of :data:`NAMES`, or ``"_info"``), or
    ``None``: ``MICROLIE_FAST=0`` (read on every call), or the module was not built (see
    :func:`describe`).

    Examples
    --------
    >>> from microlie import _fast
    >>> m = _fast.module("_text")
    >>> m is None or callable(m.parse_table)
    True
    """
    if _disabled():
        return None
    if name not in _modules:
        try:
            _modules[name] = importlib.import_module(f"microlie._c.{name}")
        except ImportError as exc:
            _modules[name] = None
            _errors[name] = str(exc)
    return _modules[name]


compiled = module  # the name before session 8: remove once no caller uses it


def install() -> list[str]:
    """Register the compiled kernels (if they were built and ``MICROLIE_FAST`` is not ``0``);
    return the names of the kernels registered."""
    _lie = module("_lie")
    if _lie is None:
        return []
    K = importlib.import_module("microlie._kernels")  # the kernel registry
    _installed.clear()
    for name, fn in getattr(_lie, "KERNELS", {}).items():
        if name in K.KERNELS:
            K.register(name, getattr(_lie, fn))
            _installed.append(name)
    one = module("_one")
    if one is not None and hasattr(one, "GROUPS"):  # absent from a build before generation
        _single[:] = importlib.import_module("microlie.groups._single").use_compiled(one)
        for name, fn in one.KERNELS.items():
            if name in K.KERNELS:
                K.register_single(name, getattr(one, fn))
        # torch.compile cannot trace C functions: stand-ins for it (microlie._torch_compile)
        importlib.import_module("microlie._torch_compile").install()
    return list(_installed)


def installed() -> list[str]:
    """Names of the kernels that :func:`install` registered in this process."""
    return list(_installed)


def installed_single() -> list[str]:
    """Operations whose single-element fast path :func:`install` switched to the compiled
    one-element functions (``"SE3.compose"``, ...; see :mod:`microlie.groups._single`)."""
    return list(_single)


def text_parser() -> Callable[..., Any] | None:
    """The compiled reader of numeric text tables, ``microlie._c._text.parse_table`` (used by
    :mod:`microlie.traj.io`), or ``None`` (not built, or ``MICROLIE_FAST=0``)."""
    return getattr(module("_text"), "parse_table", None)


def build_record() -> dict[str, Any]:
    """What ``setup.py`` recorded when it built the extensions (``microlie/_c/_build.json``):
    ``built`` (module names), ``failed`` (name -> the compiler's error), ``skipped`` (why no
    extension was attempted), ``flags``, ``defines``; ``{}`` when there is no record (a source
    tree that was never built).

    Examples
    --------
    >>> from microlie import _fast
    >>> isinstance(_fast.build_record(), dict)
    True
    """
    path = Path(__file__).parent / "_c" / "_build.json"
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


#: the compiled modules setup.py builds (its EXTENSIONS, but _info, which only describes)
NAMES = ("_lie", "_one", "_factors", "_graph", "_reproj", "_normal", "_order", "_pattern",
         "_symbolic", "_chol", "_text", "_incremental", "_online")


def describe() -> str:
    """One line saying which kernels are active: compiled (with the ISA they were built for and
    the version of the hot loops that runs on this CPU) or generic NumPy, and why.

    Examples
    --------
    >>> from microlie import _fast
    >>> _fast.describe().startswith(("kernels: compiled", "kernels: generic"))
    True
    """
    if _disabled():
        return "kernels: generic NumPy (MICROLIE_FAST=0)"
    record = build_record()
    active = [n for n in NAMES if module(n) is not None]
    if not active:
        if record.get("skipped"):
            why = f"compiled extensions not built: {record['skipped']}"
        elif record.get("failed"):
            first = next(iter(record["failed"].values())).strip().splitlines()
            why = "compiled extensions failed to build: " + (first[-1] if first else "?")
        elif [e for e in _errors.values() if not e.startswith("No module named")]:
            why = "compiled extensions do not import: " + next(
                e for e in _errors.values() if not e.startswith("No module named"))
        else:
            why = "compiled extensions not built: pip install . builds them"
        return f"kernels: generic NumPy ({why})"
    info_mod = module("_info")
    info = info_mod.info() if info_mod is not None else {}
    isa = f"baseline {info.get('baseline', '?')}"
    if info.get("clones"):
        isa += f", hot loops dispatched at run time, this CPU: {info.get('active', '?')}"
    missing = [n for n in NAMES if n not in active]
    tail = f"; not built: {', '.join(missing)}" if missing else ""
    return f"kernels: compiled ({len(active)} modules, {isa}){tail}"
