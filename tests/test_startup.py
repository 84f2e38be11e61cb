"""microlie._startup: the trajectory commands start NumPy with one BLAS thread (unless the user
set a thread count) and without the cyclic garbage collector, ``microlie optimize`` with one
BLAS thread unless ``--blas-threads`` asks for more; importing microlie in a program changes
neither the environment nor the collector."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = str(Path(__file__).resolve().parents[1] / "src")
PROBE = ("import gc, os, sys, microlie, microlie.traj; "
         "print(os.environ.get('OPENBLAS_NUM_THREADS'), gc.isenabled(), "
         "len(os.listdir('/proc/self/task')) if os.path.isdir('/proc/self/task') else -1)")


def _run(args: list[str], **env: str) -> list[str]:
    base = {k: v for k, v in os.environ.items()
            if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    r = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=120,
                       env={**base, "PYTHONPATH": SRC, **env})
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


def test_a_program_importing_microlie_is_not_affected():
    assert _run(["-c", PROBE])[:2] == ["None", "True"]


@pytest.mark.parametrize("args, blas, collector", [
    (["ape"], "1", False), (["rpe"], "1", False), (["plot"], "1", False),
    # optimize solves with one BLAS thread (issue 19, item 13): no pool to start, GC kept
    (["optimize", "g.g2o"], "1", True), (["optimize", "g.g2o", "--blas-threads", "1"], "1", True),
    (["optimize", "g.g2o", "--blas-threads", "0"], "None", True),
    (["optimize", "g.g2o", "--blas-threads=2"], "None", True),
    (["help"], "None", True)])
def test_console_script_of_a_command(tmp_path, args, blas, collector):
    script = tmp_path / "microlie"  # what the console script's argv[0] looks like
    script.write_text(PROBE + "\n")
    out = _run([str(script), *args])
    assert out[:2] == [blas, str(collector)]
    if blas == "1" and out[2] != "-1":
        assert out[2] == "1"  # no OpenBLAS worker threads were started


def test_the_users_thread_count_wins(tmp_path):
    script = tmp_path / "microlie"
    script.write_text(PROBE + "\n")
    assert _run([str(script), "ape"], OPENBLAS_NUM_THREADS="2")[:2] == ["2", "False"]
    assert _run([str(script), "ape"], OMP_NUM_THREADS="3")[:2] == ["None", "False"]



@pytest.mark.parametrize("command", ["ape", "rpe"])
def test_commands_import_only_what_they_use(command):
    argv = [command, "--example"] + (["-a"] if command == "ape" else [])
    code = ("import io, sys; from microlie.cli import main; "
            f"code = main({argv!r}, out=io.StringIO(), err=io.StringIO()); print(code, "
            "sorted(m for m in ('scipy', 'matplotlib', 'microlie.uncertainty', "
            "'microlie.optim.command', 'microlie.traj.plot', 'rosbags') if m in sys.modules))")
    assert _run(["-c", code]) == ["0", "[]"]
