"""One BLAS thread inside the solvers unless asked otherwise (issue 19, item 13).

The thread counts are read with threadpoolctl inside the solve (through a wrapped inner
function) and after it. Every test first sets the process to 2 BLAS threads (the user's setting)
so that a limit of 1 is visible on any machine, also on one core. Timings are in
``benchmarks/blas_threads.py``, not here.
"""

from __future__ import annotations

import argparse
import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import microlie
from microlie import SE2
from microlie.optim import BetweenFactor, Diagonal, FactorGraph, PriorFactor, bundle_adjust
from microlie.optim.core import graph as graph_module
from microlie.optim.linalg.schur_solver import SchurSolver
from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene


def _blas_threads() -> dict[str, int]:
    return {d["filepath"]: d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"}


def _chain() -> tuple[FactorGraph, object]:
    g = FactorGraph()
    x = g.add_variables(SE2.identity(4), name="x")
    g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
    step = SE2.exp(np.tile([1.0, 0.0, 0.1], (3, 1)))
    g.add(BetweenFactor(x, [0, 1, 2], [1, 2, 3], step, Diagonal([0.1, 0.1, 0.1])))
    return g, x


@pytest.fixture
def spy_solve(monkeypatch):
    """Records the BLAS thread counts seen inside FactorGraph.optimize's solve."""
    seen: list[dict[str, int]] = []
    inner = graph_module.solve

    def solve(*args, **kwargs):
        seen.append(_blas_threads())
        return inner(*args, **kwargs)

    monkeypatch.setattr(graph_module, "solve", solve)
    return seen


def test_issue19_item13_optimize_runs_with_one_blas_thread(spy_solve):
    g, _ = _chain()
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert set(before.values()) == {2}
        res = g.optimize()
        after = _blas_threads()
    assert res.converged
    assert len(spy_solve) == 1
    inside = spy_solve[0]
    assert inside and set(inside.values()) == {1}, inside
    # NumPy's and SciPy's BLAS (two libraries in the usual wheels) are all held
    assert set(before) <= set(inside)
    # the user's setting is back (a BLAS that the solve loaded first, e.g. SciPy's when
    # scipy.linalg is imported on first use, keeps its own default)
    assert {k: after[k] for k in before} == before


def test_issue19_item13_opt_out_and_explicit_count(spy_solve):
    g, _ = _chain()
    with threadpool_limits(limits=2, user_api="blas"):
        g.optimize(blas_threads=None)
        g.optimize(blas_threads=3)
        after = _blas_threads()
    assert set(spy_solve[0].values()) == {2}  # None: the user's setting is kept
    assert set(spy_solve[1].values()) == {3}
    assert set(after.values()) == {2}


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "1"])
def test_issue19_item13_bad_blas_threads_is_refused(bad):
    g, _ = _chain()
    with pytest.raises(ValueError, match="blas_threads must be a positive integer or None"):
        g.optimize(blas_threads=bad)


def test_issue19_item13_bundle_adjust_runs_with_one_blas_thread(monkeypatch):
    seen: list[dict[str, int]] = []
    inner = SchurSolver.factorize

    def factorize(self, *args, **kwargs):
        seen.append(_blas_threads())
        return inner(self, *args, **kwargs)

    monkeypatch.setattr(SchurSolver, "factorize", factorize)
    _, start = synthetic_scene(n_cameras=3, n_points=30, seed=4)
    with threadpool_limits(limits=2, user_api="blas"):
        bundle_adjust(start, fix_cameras=[0], max_iter=3)
        n_default = len(seen)
        bundle_adjust(start, fix_cameras=[0], max_iter=3, blas_threads=None)
        after = _blas_threads()
    assert n_default > 0 and len(seen) > n_default
    assert all(set(s.values()) == {1} for s in seen[:n_default])
    assert all(set(s.values()) == {2} for s in seen[n_default:])
    assert set(after.values()) == {2}


def test_issue19_item13_marginals_run_with_one_blas_thread(monkeypatch):
    """Marginals factorise and solve the whole system too: the same limit as the solve."""
    seen: list[dict[str, int]] = []
    inner = graph_module.FactorGraph._factorized

    def factorized(self, *args, **kwargs):
        seen.append(_blas_threads())
        return inner(self, *args, **kwargs)

    monkeypatch.setattr(graph_module.FactorGraph, "_factorized", factorized)
    g, x = _chain()
    with threadpool_limits(limits=2, user_api="blas"):
        res = g.optimize()
        g.marginals(res.values, x)
        g.marginal_covariance(res.values, [(x, 1)])
        g.marginals(res.values, x, blas_threads=None)
        after = _blas_threads()
    assert [set(s.values()) for s in seen] == [{1}, {1}, {2}]
    assert set(after.values()) == {2}


def test_issue19_item13_camera_covariance_runs_with_one_blas_thread(monkeypatch):
    """BundleGraph.camera_covariance goes through FactorGraph.marginal_covariance: its limit."""
    seen: list[dict[str, int]] = []
    inner = graph_module.FactorGraph._factorized

    def factorized(self, *args, **kwargs):
        seen.append(_blas_threads())
        return inner(self, *args, **kwargs)

    _, start = synthetic_scene(n_cameras=3, n_points=30, seed=4)
    bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
    res = bg.graph.optimize(solver="trust-region", linear_solver="schur", max_iter=3)
    monkeypatch.setattr(graph_module.FactorGraph, "_factorized", factorized)
    with threadpool_limits(limits=2, user_api="blas"):
        bg.camera_covariance(res.values, [1])
        bg.camera_covariance(res.values, [1], blas_threads=None)
    assert [set(s.values()) for s in seen] == [{1}, {2}]


def _command_args(path: Path, *extra: str) -> argparse.Namespace:
    from microlie.optim.command import register

    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    return parser.parse_args(["optimize", str(path), "--json", *extra])


@pytest.mark.parametrize("flag,expected", [((), 1), (("--blas-threads", "0"), 2),
                                           (("--blas-threads", "2"), 2)])
def test_issue19_item13_command_blas_threads(tmp_path, spy_solve, flag, expected):
    from microlie.optim.command import run

    path = tmp_path / "tiny.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\n"
                    "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    with threadpool_limits(limits=2, user_api="blas"):
        assert run(_command_args(path, *flag), io.StringIO(), io.StringIO()) == 0
        assert set(_blas_threads().values()) == {2}
    assert set(spy_solve[0].values()) == {expected}


def test_issue19_item13_command_refuses_negative_threads(tmp_path):
    from microlie.optim.command import run

    path = tmp_path / "tiny.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\n")
    with pytest.raises(ValueError, match="--blas-threads must be >= 0"):
        run(_command_args(path, "--blas-threads", "-1"), io.StringIO(), io.StringIO())


def test_issue19_item13_limit_covers_libraries_loaded_inside():
    """SciPy's BLAS loaded after the limit starts (as in ``microlie optimize``, which imports
    the solver inside it) is held too; a fresh process with a user setting of 2 threads."""
    code = (
        "import sys\n"
        "from threadpoolctl import threadpool_info\n"
        "from microlie.optim.core.threads import blas_threads_limit, limit_new_libraries\n"
        "assert 'scipy.linalg' not in sys.modules\n"
        "def blas(): return sorted({d['num_threads'] for d in threadpool_info()"
        " if d['user_api'] == 'blas'})\n"
        "with blas_threads_limit(1):\n"
        "    import scipy.linalg\n"
        "    inside = blas()\n"
        "print(inside, blas())\n"
    )
    src = str(Path(microlie.__file__).resolve().parents[1])  # the microlie under test
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2", PYTHONPATH=os.pathsep.join(
        [src, *[p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]]))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split("\n")[0]
    assert out == "[1] [2]"


def test_issue19_item13_limit_new_libraries_restores_their_count():
    """A library that appears inside a limit with its own count (here: simulated by setting
    it) is held by limit_new_libraries and everything is restored at the end."""
    from microlie.optim.core.threads import blas_threads_limit, limit_new_libraries

    with threadpool_limits(limits=2, user_api="blas"):
        with blas_threads_limit(1):
            threadpool_limits(limits=3, user_api="blas")  # a "new" library at its default
            limit_new_libraries()
            inside = _blas_threads()
        after = _blas_threads()
    assert set(inside.values()) == {1}
    assert set(after.values()) == {2}
