"""Start-up of the trajectory commands (``microlie ape``, ``rpe``, ``kitti``, ``traj``, ``res``,
``plot``): one BLAS thread and no cyclic garbage collection.

These commands do no large BLAS work (their products are 3 x N or 3 x 3) while starting
OpenBLAS's thread pool costs some 25 ms of CPU per run, and their processes are short and
create little cyclic garbage while the collector would walk the tens of thousands of objects
of the loaded modules again and again (some 4% of a run). :func:`command_setup`, called by
``import microlie`` before NumPy loads, therefore sets ``OPENBLAS_NUM_THREADS=1`` (unless it or
``OMP_NUM_THREADS`` is set) and turns the collector off, in those command processes only. A
program that imports microlie is never affected.
"""

from __future__ import annotations

import gc
import os
import sys

__all__ = ["command_setup", "TRAJECTORY_COMMANDS"]

TRAJECTORY_COMMANDS = ("ape", "rpe", "kitti", "traj", "res", "plot")


def _trajectory_command(orig_argv: list[str], argv: list[str]) -> bool:
    """Whether this process is ``microlie CMD ...`` (the console script) or
    ``python -m microlie.cli CMD ...`` with a trajectory command ``CMD``.

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
    if argv and os.path.basename(argv[0]) in ("microlie", "microlie.exe"):  # console script
        return len(argv) > 1 and argv[1] in TRAJECTORY_COMMANDS
    for i, tok in enumerate(orig_argv[:-2]):
        if tok == "-m":
            return orig_argv[i + 1] == "microlie.cli" and orig_argv[i + 2] in TRAJECTORY_COMMANDS
    return False


def command_setup() -> bool:
    """In a trajectory command's process: one BLAS thread (unless the user set a thread count;
    only before NumPy is imported) and no cyclic garbage collection. Returns whether this is
    such a process (module docstring).

    Returns
    -------
    bool
    """
    if not _trajectory_command(list(getattr(sys, "orig_argv", [])), sys.argv):
        return False
    if "numpy" not in sys.modules and "OPENBLAS_NUM_THREADS" not in os.environ and \
            "OMP_NUM_THREADS" not in os.environ:
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
    gc.disable()
    return True
