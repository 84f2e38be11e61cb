"""``microlie optimize problem.txt --format bal``: bundle adjustment of a BAL file.

:func:`run_bal` is the BAL entry of :data:`microlie.optim.io.formats.FORMATS`: it reads the file
and solves it with :func:`microlie.optim.sfm.bundle.bundle_adjust`, the one engine
(:meth:`FactorGraph.optimize <microlie.optim.FactorGraph.optimize>` on
:func:`~microlie.optim.sfm.bundle.bundle_graph`'s graph; BAL camera model, points behind a camera
evaluated as in the standard BAL model). ``--solver`` defaults to ``trust-region``
(Levenberg-Marquardt with Ceres' rules) and ``--linear-solver`` takes the engine's words:
``auto`` (the default: ``schur``, the points eliminated), ``schur``, ``cholesky``, ``dense``,
... for the full system. The JSON report has the pose-graph keys (``initial_cost``,
``final_cost``, ``iterations``, ``time_s``, ``converged``, ...). Costs are
``0.5 * sum |r|^2`` in pixels (without the robust loss even when ``--robust`` is given; the
robust objective is reported as ``final_robust_cost``). ``-o OUT`` writes the optimised problem
as BAL, ``--plot FILE`` draws the cameras and points before and after.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, TextIO

__all__ = ["run_bal"]

# the words of bundle_adjust's own loop before issue 20, and what to ask for now
_OLD_WORDS = {"sparse": "schur (it chooses a dense or sparse reduced system)",
              "full": "cholesky (the full system)"}


def run_bal(args: argparse.Namespace, err: TextIO) -> dict[str, Any]:
    """Read, solve, write and plot one BAL problem.

    Parameters
    ----------
    args : argparse.Namespace
        From the parser of :func:`microlie.optim.command.register` (with ``format="bal"``).
    err : text stream
        Where messages go.

    Returns
    -------
    dict
        The JSON report.

    Examples
    --------
    >>> import argparse, io, os, tempfile
    >>> from microlie.optim.io.bal import write_bal
    >>> from microlie.optim.sfm.bundle import synthetic_scene
    >>> from microlie.optim.command import register
    >>> path = os.path.join(tempfile.mkdtemp(), "scene.txt")
    >>> write_bal(path, synthetic_scene(3, 20, seed=2)[1].to_bal())
    >>> parser = argparse.ArgumentParser(prog="microlie")
    >>> _ = register(parser.add_subparsers())
    >>> from microlie.optim.command_bal import run_bal
    >>> report = run_bal(parser.parse_args(["optimize", path, "--format", "bal"]), io.StringIO())
    >>> report["final_cost"] < report["initial_cost"], report["linear_solver"]
    (True, 'schur')
    """
    from .command import (
        policy_options,
        print_header,
        show_iterations,
        solver_output_to,
        tolerance_options,
    )
    from .io.bal import read_bal, write_bal
    from .sfm.bundle import BundleProblem, bundle_adjust, plot_bundle

    solver = getattr(args, "solver", None) or "trust-region"
    if getattr(args, "gauge", None) is not None:
        raise ValueError("--gauge applies to pose graphs: bundle adjustment leaves its gauge "
                         "free (the damping keeps the system solvable, as in Ceres)")
    options, _ = policy_options(args, solver)
    options.update(tolerance_options(args, solver))
    if getattr(args, "information", None) is not None:
        raise ValueError("--information applies to pose graphs: a BAL file has no information "
                         "matrices (drop --information)")
    if getattr(args, "certify", False) or getattr(args, "init", None) == "certified":
        raise ValueError("--certify and --init certified apply to pose graphs (SE2/SE3), not "
                         "to bundle adjustment")
    linear = getattr(args, "linear_solver", "auto")
    if linear in _OLD_WORDS:
        raise ValueError(f"--linear-solver {linear} is gone: bundle adjustment runs on the one "
                         f"engine and takes its words (auto = schur, schur, cholesky, dense, "
                         f"scipy, qdldl, pardiso); use {_OLD_WORDS[linear]}")
    if linear == "auto":
        linear = "schur"
    t0 = time.perf_counter()
    bal = read_bal(args.input)
    start = BundleProblem.from_bal(bal)
    t1 = time.perf_counter()
    max_iter = getattr(args, "max_iter", 100)
    problem = (f"bundle adjustment, {bal.n_cameras} cameras, {bal.n_points} points, "
               f"{bal.n_observations} observations")
    print_header(args, err, f"{problem}; {solver} (linear solver {linear}), at most {max_iter} "
                       f"iterations; read {t1 - t0:.3f} s")
    with solver_output_to(err):
        res = bundle_adjust(start, robust=getattr(args, "robust", None), solver=solver,
                            linear_solver=linear, max_iter=max_iter,
                            verbose=show_iterations(err, args), **options,
                            blas_threads=None)  # run() holds the command's --blas-threads
    solved = start.with_values(res.values)
    report: dict[str, Any] = {
        "file": str(args.input),
        "format": "bal",
        "problem": problem,
        "num_cameras": bal.n_cameras,
        "num_points": bal.n_points,
        "num_observations": bal.n_observations,
        "robust": getattr(args, "robust", None),
        "solver": res.solver,
        "linear_solver": res.linear_solver,
        "initial_cost": res.initial_cost,
        "final_cost": res.final_cost,
        "initial_robust_cost": res.initial_robust_cost,
        "final_robust_cost": res.final_robust_cost,
        "iterations": res.iterations,
        "time_s": res.time_s,
        "converged": bool(res.converged),
        "termination": res.termination,
        "message": res.message,
        "read_s": t1 - t0,
        "timings": {k: float(v) for k, v in res.timings.items()},
    }
    if getattr(args, "output", None) and res.termination != "failure":
        write_bal(args.output, solved.to_bal())
        report["output"] = str(args.output)
    if getattr(args, "plot", None):
        plot_bundle(start, solved, args.plot, title=Path(args.input).name)
        report["plot"] = str(args.plot)
    return report


if __name__ == "__main__":  # pragma: no cover
    ns = argparse.Namespace(input=sys.argv[1], robust=None, max_iter=100, output=None,
                            plot=None)
    print(run_bal(ns, sys.stderr))
