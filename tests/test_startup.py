"""microlie._startup: the trajectory commands start NumPy with one BLAS thread (unless the user
set a thread count) and without the cyclic garbage collector, ``microlie optimize`` with one
BLAS thread unless ``--blas-threads`` asks for more; importing microlie in a program changes
neither the environment nor the collector."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
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


#: Not needed to read, solve and write a pose graph: plotting, the array backends, the
#: trajectory readers and metrics, bundle adjustment, IMU, the other linear solvers, and SciPy's
#: modules that the solve does not use (scipy vendors its own array-api-compat; the
#: stand-alone package is a torch/jax probe).
OPTIMIZE_NEVER = ("matplotlib", "torch", "jax", "array_api_compat", "pandas", "qdldl",
                  "pypardiso", "pymetis", "rosbags", "scipy.optimize", "scipy.stats",
                  "scipy.spatial", "scipy.interpolate", "scipy.integrate", "scipy.special",
                  "microlie.optim.plot", "microlie.optim.sfm", "microlie.optim.command_bal",
                  "microlie.optim.io.bal", "microlie.optim.io.toro",
                  "microlie.optim.linalg.schur_solver",
                  "microlie.optim.core.elimination", "microlie.imu", "microlie.uncertainty",
                  "microlie.calibration", "microlie.data", "microlie.traj.io",
                  "microlie.traj.evaluate", "microlie.traj.metrics", "microlie.traj.plot",
                  "microlie.traj.sync", "microlie.traj.rosbag")


@pytest.mark.parametrize("fast", ["1", "0"])
def test_optimize_imports_only_what_it_uses(tmp_path, fast):
    # an SE3 chain with a loop closure; the compiled extra (if installed) or the NumPy loops
    lines = [f"VERTEX_SE3:QUAT {i} {i + 0.1 * (i % 2)} 0 0 0 0 0 1" for i in range(4)]
    info = " ".join("1" if r == c else "0" for r in range(6) for c in range(r, 6))
    lines += [f"EDGE_SE3:QUAT {i} {i + 1} 1 0 0 0 0 0 1 {info}" for i in range(3)]
    lines.append(f"EDGE_SE3:QUAT 0 3 3 0 0 0 0 0 1 {info}")
    path, out = tmp_path / "g.g2o", tmp_path / "out.g2o"
    path.write_text("\n".join(lines) + "\n")
    argv = ["optimize", str(path), "--json", "-o", str(out)]
    code = ("import io, sys; from microlie.cli import main; "
            f"code = main({argv!r}, out=io.StringIO(), err=io.StringIO()); "
            f"never = {OPTIMIZE_NEVER!r}; "
            "print(code, sorted(m for m in sys.modules if m in never "
            "or m.startswith(tuple(n + '.' for n in never))))")
    assert _run(["-c", code], MICROLIE_FAST=fast) == ["0", "[]"]
    assert out.read_text().count("VERTEX_SE3:QUAT") == 4


#: With the compiled code, SciPy's dense linear algebra (its own OpenBLAS: ~0.18 s of CPU and
#: 30 MB at import; the compiled Cholesky calls NumPy's OpenBLAS) and its sparse graph and
#: sparse solver modules are not imported either (the order is ours, the components NumPy's).
COMPILED_NEVER = ("scipy.linalg", "scipy.sparse.linalg", "scipy.sparse.csgraph")


def test_optimize_with_the_compiled_code_imports_no_scipy_linalg(tmp_path):
    import importlib.util

    if importlib.util.find_spec("microlie._c._order") is None:
        pytest.skip("microlie._c._order is not built")
    import microlie._c._chol as chol

    if chol.BLAS != "numpy":  # not a Linux NumPy wheel's OpenBLAS: SciPy's BLAS is used
        pytest.skip(f"the compiled Cholesky calls {chol.BLAS}'s BLAS here")
    path, out = tmp_path / "g.g2o", tmp_path / "out.g2o"
    lines = [f"VERTEX_SE2 {i} {i + 0.1 * (i % 2)} 0 0" for i in range(5)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0 1 0 0 1 0 1" for i in range(4)]
    path.write_text("\n".join(lines + ["EDGE_SE2 0 4 4 0 0 1 0 0 1 0 1"]) + "\n")
    # the supernodal Cholesky (what "auto" takes for 3-D graphs above 8,000 unknowns without
    # PARDISO; below 300 unknowns "auto" is the dense LAPACK Cholesky, SciPy's)
    argv = ["optimize", str(path), "--json", "-o", str(out), "--linear-solver", "cholesky"]
    code = ("import io, sys; from microlie.cli import main; "
            f"code = main({argv!r}, out=io.StringIO(), err=io.StringIO()); "
            f"never = {COMPILED_NEVER!r}; "
            "print(code, sorted(m for m in sys.modules if m in never "
            "or m.startswith(tuple(n + '.' for n in never))))")
    root = str(Path(chol.__file__).resolve().parents[2])  # the microlie (and build) imported here
    assert _run(["-c", code], MICROLIE_FAST="1", PYTHONPATH=root) == ["0", "[]"]
    assert out.read_text().count("VERTEX_SE2") == 5


@pytest.mark.parametrize("fast", ["1", "0"])
def test_optimize_3d_with_the_compiled_code_imports_no_scipy(tmp_path, fast):
    # the path a 3-D pose graph takes with the compiled code (the supernodal Cholesky: what
    # "auto" takes from 8,000 unknowns): not one SciPy module (scipy.sparse alone costs ~0.15 s
    # of CPU and ~23 MB at import); without the compiled code the same command still works
    import importlib.util

    if fast == "1" and importlib.util.find_spec("microlie._c._chol") is None:
        pytest.skip("microlie._c is not built")
    lines = [f"VERTEX_SE3:QUAT {i} {i + 0.1 * (i % 2)} {0.05 * i} 0 0 0 0 1" for i in range(6)]
    info = " ".join("1" if r == c else "0" for r in range(6) for c in range(r, 6))
    lines += [f"EDGE_SE3:QUAT {i} {i + 1} 1 0 0 0 0 0 1 {info}" for i in range(5)]
    lines += [f"EDGE_SE3:QUAT 0 5 5 0 0 0 0 0 1 {info}", f"EDGE_SE3:QUAT 1 4 3 0 0 0 0 0 1 {info}"]
    path, out = tmp_path / "g.g2o", tmp_path / "out.g2o"
    path.write_text("\n".join(lines) + "\n")
    argv = ["optimize", str(path), "--json", "-o", str(out), "--linear-solver", "cholesky"]
    code = ("import io, json, sys; from microlie.cli import main; s = io.StringIO(); "
            f"code = main({argv!r}, out=s, err=io.StringIO()); "
            "print(code, json.loads(s.getvalue())['final_cost'] < 1e-12, "
            "sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))")
    res = _run(["-c", code], MICROLIE_FAST=fast)
    assert res[:2] == ["0", "True"]
    if fast == "1":
        assert res[2:] == ["[]"]
    x = np.array([[float(t) for t in ln.split()[2:5]] for ln in out.read_text().splitlines()
                  if ln.startswith("VERTEX_SE3:QUAT")])
    # consistent measurements: unit steps along x from the first pose, y and z its own
    np.testing.assert_allclose(x - x[0], np.c_[np.arange(6.0), np.zeros((6, 2))], atol=1e-6)
