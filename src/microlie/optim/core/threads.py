"""BLAS threads inside the solvers: one by default.

The dense work of a solve (the supernodal factorisation's ``potrf``/``trsm``/``syrk``, the
Schur complement's products) is many small BLAS calls. A multithreaded BLAS wakes its pool
for each of them, and on a machine whose cores are busy the threads wait for each other:
on two cores, one kept busy by another process, sphere2500's solve took 2.4 s with OpenBLAS's
default threads against 0.29 s with one (medians; 2.9-21x within a round; ``BENCHMARKS.md``,
"BLAS threads"). :func:`FactorGraph.optimize
<microlie.optim.FactorGraph.optimize>`, :func:`~microlie.optim.bundle_adjust` and
``microlie optimize`` therefore run with ``blas_threads=1``: every BLAS library loaded in the
process (OpenBLAS, MKL, BLIS, ... : NumPy and SciPy may each carry their own) is limited to one
thread for the whole call, through threadpoolctl, and the previous setting is restored
afterwards. ``blas_threads=n`` asks for ``n`` threads, ``blas_threads=None`` leaves the BLAS as
the user set it (environment variables such as ``OPENBLAS_NUM_THREADS``, an enclosing
``threadpoolctl.threadpool_limits``) or as the library's default (one thread per core).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import sys
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

from ..._fast import compiled

__all__ = ["blas_threads_limit", "limit_new_libraries", "with_blas_threads"]

P = ParamSpec("P")
R = TypeVar("R")


class _Limit:
    """The context of :func:`blas_threads_limit`: SciPy's BLAS loaded first (unless the compiled
    Cholesky calls NumPy's, ``microlie._c._chol.BLAS == "numpy"``), every loaded BLAS
    held at ``n`` threads, libraries loaded later in the block held too when the code that
    loads them calls :func:`limit_new_libraries`, all restored on exit."""

    def __init__(self, n: int) -> None:
        self.n = n
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> _Limit:
        chol = compiled("_chol")
        if chol is None or getattr(chol, "BLAS", "scipy") == "scipy":
            import scipy.linalg  # noqa: F401  # SciPy's own BLAS (the factorisations) is loaded
        elif "scipy.linalg" not in sys.modules and _SCIPY_HOOK not in sys.meta_path:
            # not needed by the solve: held when (if) something imports it inside the block
            sys.meta_path.insert(0, _SCIPY_HOOK)

        self._stack.enter_context(_controller().limit(limits=self.n, user_api="blas"))
        _ACTIVE.append(self)
        return self

    def __exit__(self, *exc: object) -> None:
        _ACTIVE.remove(self)
        if not _ACTIVE and _SCIPY_HOOK in sys.meta_path:
            sys.meta_path.remove(_SCIPY_HOOK)
        self._stack.close()  # the libraries loaded inside first, then the others


class _ScipyLinalgHook:
    """A ``sys.meta_path`` finder that lets ``scipy.linalg`` load as usual and then holds its
    BLAS (:func:`limit_new_libraries`); removed once used or when no limit is active."""

    def find_spec(self, name: str, path: Any, target: Any = None) -> Any:
        if name != "scipy.linalg":
            return None
        sys.meta_path.remove(self)
        from importlib.machinery import PathFinder

        spec = PathFinder.find_spec(name, path, target)
        if spec is None or spec.loader is None or not _ACTIVE:
            return spec
        run = spec.loader.exec_module

        def exec_module(module: Any) -> None:
            run(module)
            limit_new_libraries()

        spec.loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


_SCIPY_HOOK = _ScipyLinalgHook()
_ACTIVE: list[_Limit] = []
_CONTROLLER: list[Any] = []  # [threadpoolctl.ThreadpoolController, len(sys.modules) at its scan]


def _controller(rescan: bool = False) -> Any:
    """threadpoolctl's view of the loaded libraries, scanned again only when modules were
    imported since (or ``rescan``): a scan reads ``/proc/self/maps``, 1-10 ms, more than a
    small solve."""
    if rescan or not _CONTROLLER or _CONTROLLER[1] != len(sys.modules):
        from threadpoolctl import ThreadpoolController

        _CONTROLLER[:] = [ThreadpoolController(), len(sys.modules)]
    return _CONTROLLER[0]


def blas_threads_limit(blas_threads: int | None) -> contextlib.AbstractContextManager[Any]:
    """A context manager that holds every loaded BLAS library at ``blas_threads`` threads
    (``None``: changes nothing), restoring the previous counts on exit.

    SciPy's BLAS is loaded on entry; a library loaded inside the block (MKL by pypardiso) is
    held too once its loader calls :func:`limit_new_libraries`.

    Parameters
    ----------
    blas_threads : int or None
        Threads (>= 1), or ``None`` to keep the user's or the library's setting.

    Returns
    -------
    context manager

    Raises
    ------
    ValueError
        ``blas_threads`` is neither ``None`` nor a positive integer.

    Examples
    --------
    >>> from threadpoolctl import threadpool_info
    >>> from microlie.optim.core.threads import blas_threads_limit
    >>> with blas_threads_limit(1):
    ...     {d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"}
    {1}
    """
    if blas_threads is None:
        return contextlib.nullcontext()
    if isinstance(blas_threads, bool) or not isinstance(blas_threads, int) or blas_threads < 1:
        raise ValueError(f"blas_threads must be a positive integer or None (keep the BLAS "
                         f"library's setting), not {blas_threads!r}")
    return _Limit(blas_threads)


def limit_new_libraries() -> None:
    """Inside a :func:`blas_threads_limit` block, hold the BLAS libraries loaded since its
    start at its thread count too (restored when the block ends); outside one, nothing.

    Examples
    --------
    >>> from microlie.optim.core.threads import limit_new_libraries
    >>> limit_new_libraries()  # outside a limit: nothing
    """
    if _ACTIVE:
        top = _ACTIVE[-1]
        top._stack.enter_context(_controller(rescan=True).limit(limits=top.n, user_api="blas"))


def with_blas_threads(fn: Callable[P, R]) -> Callable[P, R]:
    """Run ``fn`` under :func:`blas_threads_limit` of its keyword-only ``blas_threads``
    argument (its default when not given): one limit around the whole call, not per BLAS call
    (a scan of the loaded libraries costs milliseconds: see :func:`_controller`).

    Parameters
    ----------
    fn : callable
        A function with a keyword-only parameter ``blas_threads``.

    Returns
    -------
    callable
        ``fn`` wrapped, same signature.

    Examples
    --------
    >>> from threadpoolctl import threadpool_info
    >>> from microlie.optim.core.threads import with_blas_threads
    >>> @with_blas_threads
    ... def work(*, blas_threads=1):
    ...     return {d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"}
    >>> work()
    {1}
    """
    param = inspect.signature(fn).parameters["blas_threads"]
    if param.kind is not inspect.Parameter.KEYWORD_ONLY:
        raise TypeError(f"{fn.__qualname__}: blas_threads must be keyword-only")
    default = param.default

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        n: Any = kwargs.get("blas_threads", default)
        with blas_threads_limit(n):
            return fn(*args, **kwargs)

    return wrapper
