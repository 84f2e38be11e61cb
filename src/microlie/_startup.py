"""What happens while microlie loads: no cyclic garbage collection, and one BLAS thread for the
trajectory commands.

* Importing NumPy and microlie allocates tens of thousands of long-lived objects; the collector
  runs over them again and again while they load and finds nothing to free (some 7% of the
  import time). ``with no_collection(): ...`` suspends it for the block and restores its state.
* The trajectory commands (``microlie ape``, ``rpe``, ``kitti``, ``traj``, ``res``, ``plot``) do
  no large BLAS work (their products are 3 x N or 3 x 3), while starting OpenBLAS's thread pool
  costs some 25 ms of CPU per run. :func:`command_blas_threads`, called before NumPy is imported,
  sets ``OPENBLAS_NUM_THREADS=1`` for those commands only, and only when neither it nor
  ``OMP_NUM_THREADS`` is set. A program that imports microlie is never affected.
"""

from __future__ import annotations

import gc
import os
import sys
from types import TracebackType

__all__ = ["no_collection", "command_blas_threads", "TRAJECTORY_COMMANDS"]

TRAJECTORY_COMMANDS = ("ape", "rpe", "kitti", "traj", "res", "plot")


class no_collection:  # noqa: N801 - used like a function: ``with no_collection(): ...``
    """Suspend the cyclic garbage collector for a ``with`` block (its state is restored).

    Examples
    --------
    >>> import gc
    >>> from microlie._startup import no_collection
    >>> with no_collection():
    ...     gc.isenabled()
    False
    >>> gc.isenabled()
    True
    """

    def __enter__(self) -> None:
        self._enabled = gc.isenabled()
        gc.disable()

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._enabled:
            gc.enable()


def _trajectory_command(orig_argv: list[str], argv: list[str]) -> bool:
    """Whether this process is ``microlie CMD ...`` or ``python -m microlie.cli CMD ...`` with a
    trajectory command ``CMD``."""
    if argv and os.path.basename(argv[0]) in ("microlie", "microlie.exe"):  # console script
        return len(argv) > 1 and argv[1] in TRAJECTORY_COMMANDS
    for i, tok in enumerate(orig_argv[:-2]):
        if tok == "-m":
            return orig_argv[i + 1] == "microlie.cli" and orig_argv[i + 2] in TRAJECTORY_COMMANDS
    return False


def command_blas_threads() -> bool:
    """Set ``OPENBLAS_NUM_THREADS=1`` if this process is a trajectory command that NumPy has not
    been imported in yet and the user set no thread count (module docstring); whether it did.

    Examples
    --------
    >>> from microlie._startup import _trajectory_command
    >>> _trajectory_command(["python", "-m", "microlie.cli", "ape", "a", "b"], ["-m", "ape"])
    True
    >>> _trajectory_command(["python", "-m", "microlie.cli", "optimize", "g.g2o"], ["-m"])
    False
    >>> _trajectory_command(["python", "script.py"], ["script.py", "ape"])
    False
    """
    if "numpy" in sys.modules or "OPENBLAS_NUM_THREADS" in os.environ or \
            "OMP_NUM_THREADS" in os.environ:
        return False
    if not _trajectory_command(list(getattr(sys, "orig_argv", [])), sys.argv):
        return False
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    return True
