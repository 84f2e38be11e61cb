"""Start-up of the commands: the trajectory commands (``microlie ape``, ``rpe``, ``kitti``,
``traj``, ``res``, ``plot``) start with one BLAS thread and no cyclic garbage collection,
``microlie optimize`` with one BLAS thread.

These commands do no large BLAS work (their products are 3 x N or 3 x 3) while starting
OpenBLAS's thread pool costs some 25 ms of CPU per run, and their processes are short and
create little cyclic garbage while the collector would walk the tens of thousands of objects
of the loaded modules again and again (some 4% of a run). :func:`command_setup`, called by
``import microlie`` before NumPy loads, therefore sets ``OPENBLAS_NUM_THREADS=1`` (unless it or
``OMP_NUM_THREADS`` is set) and turns the collector off, in those command processes only. A
program that imports microlie is never affected.

``microlie optimize`` runs its solve with one BLAS thread anyway (``--blas-threads``, default
1, :mod:`microlie.optim.core.threads`); starting the thread pools that it then idles costs some
0.1 s of CPU per run (NumPy's and SciPy's OpenBLAS). So it also starts with
``OPENBLAS_NUM_THREADS=1``, unless the user set a thread count or asked for other than one
thread (``--blas-threads N``); its collector stays on (a solve makes large temporaries).
"""

from __future__ import annotations

import gc
import os
import sys

__all__ = ["command_setup", "TRAJECTORY_COMMANDS"]

TRAJECTORY_COMMANDS = ("ape", "rpe", "kitti", "traj", "res", "plot")


def _command(orig_argv: list[str], argv: list[str]) -> list[str]:
    """The command and its arguments when this process is ``microlie CMD ...`` (the console
    script) or ``python -m microlie.cli CMD ...``; else ``[]``.

    Examples
    --------
    >>> from microlie._startup import _command
    >>> _command(["python", "-m", "microlie.cli", "ape", "a", "b"], ["-m", "ape"])
    ['ape', 'a', 'b']
    >>> _command(["/usr/bin/microlie", "optimize", "g.g2o"], ["/usr/bin/microlie", "optimize",
    ...          "g.g2o"])
    ['optimize', 'g.g2o']
    >>> _command(["python", "script.py"], ["script.py", "ape"])
    []
    """
    if argv and os.path.basename(argv[0]) in ("microlie", "microlie.exe"):  # console script
        return list(argv[1:])
    for i, tok in enumerate(orig_argv[:-2]):
        if tok == "-m":
            return list(orig_argv[i + 2:]) if orig_argv[i + 1] == "microlie.cli" else []
    return []


def _one_blas_thread(args: list[str]) -> bool:
    """Whether ``microlie optimize ARGS`` solves with one BLAS thread (``--blas-threads``
    absent or 1; a value argparse would refuse counts as absent).

    Examples
    --------
    >>> from microlie._startup import _one_blas_thread
    >>> _one_blas_thread(["g.g2o"]), _one_blas_thread(["g.g2o", "--blas-threads", "1"])
    (True, True)
    >>> _one_blas_thread(["--blas-threads", "0"]), _one_blas_thread(["--blas-threads=4"])
    (False, False)
    """
    value = "1"
    for i, tok in enumerate(args):
        if tok == "--blas-threads" and i + 1 < len(args):
            value = args[i + 1]
        elif tok.startswith("--blas-threads="):
            value = tok.split("=", 1)[1]
    try:
        return int(value) == 1
    except ValueError:
        return True


def command_setup() -> bool:
    """In a trajectory command's process: one BLAS thread (unless the user set a thread count;
    only before NumPy is imported) and no cyclic garbage collection; in ``microlie optimize``'s
    with one BLAS thread to solve, one BLAS thread. Returns whether this is a trajectory
    command's process (module docstring).

    Returns
    -------
    bool
    """
    cmd = _command(list(getattr(sys, "orig_argv", [])), sys.argv)
    trajectory = bool(cmd) and cmd[0] in TRAJECTORY_COMMANDS
    optimize = bool(cmd) and cmd[0] == "optimize" and _one_blas_thread(cmd[1:])
    if not (trajectory or optimize):
        return False
    if "numpy" not in sys.modules and "OPENBLAS_NUM_THREADS" not in os.environ and \
            "OMP_NUM_THREADS" not in os.environ:
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
    if trajectory:
        gc.disable()
    return trajectory
