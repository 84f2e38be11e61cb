"""``torch.compile`` through the compiled single-element functions.

Single float64 NumPy elements run through the C functions of ``microlie._c._one`` (the
``_one_<op>`` attributes of the group classes and the ``one`` functions of the kernels, see
:mod:`microlie.groups._single` and :func:`microlie._kernels.register_single`). Every group
operation calls one first; it returns ``None`` for anything else (a tensor, a batch, float32),
and the operation falls through to the generic path. ``torch.compile`` (Dynamo) cannot trace a
C function: without help it would break the graph at the first call of every operation
(``fullgraph=True`` fails). For each of them this module registers with Dynamo a stand-in in
Python that returns ``None`` (:func:`torch.compiler.substitute_in_graph`), so that Dynamo
traces the generic path, which is what the C function would have chosen for a tensor; eager
calls still run the C functions.

Registering needs ``torch._dynamo``, which ``import torch`` does not import (it takes 1-2 s):
it is done when ``torch._dynamo`` is imported (by ``torch.compile``, ``torch._dynamo.explain``,
...), through an import hook that :func:`install` puts on ``sys.meta_path`` and that removes
itself once it has fired; at once when ``torch._dynamo`` is already imported. The hook changes
nothing else: it looks at the name of each module imported and does nothing for every other
one.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
import types
from collections.abc import Sequence
from typing import Any

__all__ = ["install", "register", "registered"]

_TARGET = "torch._dynamo"
_done: set[int] = set()
_keep: list[Any] = []  # the registered functions (their ids must stay theirs)


def _compiled_functions() -> list[Any]:
    """The C functions that group operations call before their generic path."""
    from . import _kernels as K
    from .groups.base import LieGroup

    fns: list[Any] = []
    todo: list[type] = [LieGroup]
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        for name, value in vars(cls).items():
            if name.startswith("_one_") and isinstance(value, staticmethod):
                fns.append(value.__func__)
    fns.extend(k.one for k in K.KERNELS.values() if k.one is not None)
    return [f for f in fns if isinstance(f, types.BuiltinFunctionType)]


def _stand_in() -> Any:
    def not_handled(*args: Any, **kwargs: Any) -> None:
        """What the C function returns for anything but a float64 NumPy element."""
        return None
    return not_handled


def register() -> int:
    """Register the stand-ins with Dynamo (imports ``torch._dynamo``); return how many were
    new. Idempotent."""
    import torch

    new = 0
    for fn in _compiled_functions():
        if id(fn) in _done:
            continue
        torch.compiler.substitute_in_graph(fn, skip_signature_check=True)(_stand_in())
        _done.add(id(fn))
        _keep.append(fn)
        new += 1
    # The group operations look up their array operations in a cache keyed by namespace; a
    # first entry made while Dynamo traces is a guard the next call fails (a recompile of the
    # whole function on its second call): the torch entry is made here, before any trace.
    from ._array import ops_for

    ops_for(torch.zeros(()))
    return new


def registered() -> int:
    """How many C functions have a stand-in registered with Dynamo in this process."""
    return len(_done)


class _Loader(importlib.abc.Loader):
    """The loader of ``torch._dynamo``, followed by :func:`register`."""

    def __init__(self, loader: Any) -> None:
        self.loader = loader

    def create_module(self, spec: Any) -> Any:
        return self.loader.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self.loader.exec_module(module)
        try:
            register()
        except Exception as exc:  # never break the import of torch._dynamo
            import warnings

            warnings.warn(f"microlie: torch.compile will break the graph at each group "
                          f"operation (registering the compiled single-element functions "
                          f"with torch._dynamo failed: {exc!r})", RuntimeWarning, stacklevel=2)


class _Hook(importlib.abc.MetaPathFinder):
    """Waits for ``torch._dynamo`` to be imported, then registers (once)."""

    def find_spec(self, name: str, path: Sequence[str] | None = None,
                  target: Any = None) -> Any:
        if name != _TARGET:
            return None
        _remove_hook()
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return spec
        spec.loader = _Loader(spec.loader)
        return spec


def _remove_hook() -> None:
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _Hook)]


def install() -> None:
    """Make ``torch.compile`` trace through the compiled single-element functions: register now
    if ``torch._dynamo`` is imported, else when it is (see the module docstring)."""
    if _TARGET in sys.modules:
        register()
    elif not any(isinstance(f, _Hook) for f in sys.meta_path):
        sys.meta_path.insert(0, _Hook())
