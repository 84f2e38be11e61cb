"""Replaying a pose-graph file pose by pose through :class:`IncrementalSmoother` (what
``microlie optimize FILE --incremental`` runs)."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any, TextIO

import numpy as np

from ..core.factors import BetweenFactor, PriorFactor
from ..core.noise import Information, Isotropic
from ..core.variables import element
from ..io.pose_graph import PoseGraph
from .incremental import IncrementalSmoother

__all__ = ["replay_pose_graph", "replay_schedule", "run_incremental"]


def replay_schedule(graph: PoseGraph) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """The order of a replay: vertices in id order, each edge added when its later vertex
    arrives, and the odometry edge that predicts each new vertex.

    Parameters
    ----------
    graph : PoseGraph
        The pose graph.

    Returns
    -------
    later : numpy.ndarray
        ``(E,)`` the vertex index (in ``graph.ids`` order) at which each edge is added.
    edges : list of numpy.ndarray
        ``edges[k]``: the edge indices added with vertex ``k``.
    odometry : numpy.ndarray
        ``(V,)`` for vertex ``k > 0`` the index of an edge between vertices ``k - 1`` and
        ``k`` (the first in the file), or -1 where there is none (the vertex is then taken
        from the file).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> g = PoseGraph(SE2, ids=np.array([0, 1, 2]), poses=SE2.identity(3),
    ...               i=np.array([0, 1, 2]), j=np.array([1, 2, 0]),
    ...               measurements=SE2.identity(3), information=np.tile(np.eye(3), (3, 1, 1)))
    >>> later, edges, odo = replay_schedule(g)
    >>> later.tolist(), [e.tolist() for e in edges], odo.tolist()
    ([1, 2, 2], [[], [0], [1, 2]], [-1, 0, 1])
    """
    ii, jj = graph.edge_index()
    later = np.maximum(ii, jj)
    V = graph.num_vertices
    order = np.argsort(later, kind="stable")
    bounds = np.searchsorted(later[order], np.arange(V + 1))
    edges = [order[bounds[k]:bounds[k + 1]] for k in range(V)]
    odometry = np.full(V, -1, dtype=np.int64)
    for k in range(1, V):
        e = edges[k]
        hit = e[np.minimum(ii[e], jj[e]) == k - 1]
        if hit.size:
            odometry[k] = hit[0]
    return later, edges, odometry


def replay_pose_graph(graph: PoseGraph, smoother: IncrementalSmoother | None = None, *,
                      prior_sigma: float = 1e-6, until: int | None = None,
                      callback: Callable[[int, IncrementalSmoother], None] | None = None
                      ) -> dict[str, Any]:
    """Replay ``graph`` pose by pose (:func:`replay_schedule`) through an incremental smoother.

    The first pose enters with a prior at its file value (standard deviation ``prior_sigma``,
    as GTSAM's examples); each new pose is predicted from the current estimate of the previous
    one through its odometry edge (``X_k = X_(k-1) Z`` or ``X_(k-1) Z^-1`` by the edge's
    direction), or taken from the file where no such edge exists.

    Parameters
    ----------
    graph : PoseGraph
        With initial poses (vertex lines) for the vertices that have no odometry edge
        (without vertex lines: the first pose at the identity, every other by odometry).
    smoother : IncrementalSmoother, optional
        Default: ``IncrementalSmoother()`` (GTSAM's ISAM2 defaults).
    prior_sigma : float
        The prior on the first pose.
    until : int, optional
        Stop after this many poses (default: all).
    callback : callable, optional
        ``callback(k, smoother)`` after the update of vertex ``k``.

    Returns
    -------
    dict
        ``final_cost`` (the file's edges at the final estimate, without the prior: GTSAM's
        error; the estimate with the complete step of the final factorisation,
        :meth:`~IncrementalSmoother.calculate_best_estimate`, as the wildfire leaves steps
        stale), ``updates``, ``update_ms_median``, ``update_ms_p99`` (per pose: prediction,
        factor construction and update), ``total_s`` (all of them, the Python loop and the
        final back-substitution included),
        ``converged`` (no variable's step exceeds the relinearisation threshold at the end,
        so the estimate is at its linearisation points up to that threshold),
        ``relinearized``, ``reeliminated`` (totals), ``smoother``, ``poses`` (the handle) and
        ``update_ms`` (every update's time).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> Z = SE2.exp(np.array([[1.0, 0.0, np.pi / 2]] * 4))  # a closed square
    >>> g = PoseGraph(SE2, ids=np.arange(4), poses=SE2.identity(4), i=np.array([0, 1, 2, 3]),
    ...               j=np.array([1, 2, 3, 0]), measurements=Z,
    ...               information=np.tile(np.eye(3), (4, 1, 1)))
    >>> rep = replay_pose_graph(g)
    >>> rep["updates"], rep["converged"], rep["final_cost"] < 1e-20
    (4, True, True)
    """
    if not (np.isfinite(prior_sigma) and prior_sigma > 0):
        raise ValueError(f"prior_sigma must be a positive number, got {prior_sigma!r}")
    s = smoother if smoother is not None else IncrementalSmoother()
    V = graph.num_vertices
    n = V if until is None else int(min(max(until, 1), V))
    ii, jj = graph.edge_index()
    _, edges, odometry = replay_schedule(graph)
    Zs = graph.measurements
    group = graph.group
    info = graph.information
    file_poses = graph.poses
    if file_poses is None:  # no vertex lines: identity first pose, the rest by odometry
        missing = np.flatnonzero(odometry[1:n] < 0)
        if missing.size:
            raise ValueError(f"graph: vertex {int(graph.ids[missing[0] + 1])} has no odometry "
                             f"edge from the previous vertex and the file has no vertex poses "
                             f"to start it from")
        file_poses = graph.group.identity(V)
    x = s.add_variables(file_poses, name="poses")
    t_start = time.perf_counter()
    # every edge of the file in one batch, its rows given to the smoother as they arrive
    batch = BetweenFactor(x, ii, jj, Zs, Information(info))
    # the relative pose that predicts vertex k from k - 1 (its odometry edge, or its inverse)
    has = odometry[:n] >= 0
    o = odometry[:n][has]
    Zo = Zs[o]
    flip = ii[o] != np.flatnonzero(has) - 1
    rel = np.array(np.asarray(Zo.params), copy=True)
    if flip.any():
        rel[flip] = np.asarray(Zo[flip].inverse().params)
    step: list[Any] = [None] * n  # single elements: the one-element group operations
    for q, k in enumerate(np.flatnonzero(has).tolist()):
        step[k] = element(group, rel[q])
    times = np.empty(n)
    t_prev = time.perf_counter()
    for k in range(n):
        if k == 0:
            s.update([PriorFactor(x, 0, file_poses[0:1], Isotropic(group.dof, prior_sigma))],
                     {(x, 0): file_poses[0:1]})
        else:
            Zk = step[k]
            guess = element(group, s.calculate_estimate(x, k - 1).params[0]) @ Zk \
                if Zk is not None else file_poses[k:k + 1]
            e = edges[k]
            if e.size:
                s.update_rows(batch, e, {(x, k): guess})
            else:
                s.update((), {(x, k): guess})
        t = time.perf_counter()
        times[k] = t - t_prev
        if callback is not None:
            callback(k, s)
            t = time.perf_counter()
        t_prev = t
    X = s.calculate_best_estimate()[x][:n]  # the complete step (GTSAM's calculateBestEstimate)
    total = time.perf_counter() - t_start
    sub = graph if n == V else _prefix(graph, n)
    ms = times * 1e3
    return {"final_cost": float(sub.cost(X)), "updates": int(n),
            "update_ms_median": float(np.median(ms)),
            "update_ms_p99": float(np.percentile(ms, 99)), "total_s": float(total),
            "converged": bool(s.max_step() <= s.relinearize_threshold),
            "relinearized": int(sum(r.relinearized for r in s.records)),
            "reeliminated": int(sum(r.reeliminated for r in s.records)),
            "smoother": s, "poses": x, "update_ms": ms.tolist()}


def _prefix(graph: PoseGraph, n: int) -> PoseGraph:
    """The first ``n`` vertices of ``graph`` and the edges among them."""
    ii, jj = graph.edge_index()
    keep = np.maximum(ii, jj) < n
    poses = None if graph.poses is None else graph.poses[:n]
    return graph.replace(ids=graph.ids[:n], poses=poses, i=graph.i[keep],
                         j=graph.j[keep], measurements=graph.measurements[keep],
                         information=graph.information[keep],
                         fixed=graph.fixed[np.isin(graph.fixed, graph.ids[:n])])


def run_incremental(args: argparse.Namespace, err: TextIO) -> dict[str, Any]:
    r"""``microlie optimize FILE --incremental``: read the pose graph and replay it
    (:func:`replay_pose_graph`, GTSAM's ISAM2 defaults).

    Parameters
    ----------
    args : argparse.Namespace
        From ``microlie optimize``'s parser (``input``, ``format``, ``information``); options
        of the batch solver do not apply (a ``ValueError`` names them).
    err : text stream
        Unused (the replay prints nothing while it runs).

    Returns
    -------
    dict
        The JSON report: ``final_cost``, ``updates``, ``update_ms_median``, ``update_ms_p99``,
        ``total_s``, ``converged`` (see :func:`replay_pose_graph`), ``relinearized``,
        ``reeliminated``, ``file``, ``problem``, ``incremental``.

    Examples
    --------
    >>> import argparse, io, json, os, tempfile
    >>> from microlie.optim.command import register, run
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    >>> parser = argparse.ArgumentParser(prog="microlie")
    >>> _ = register(parser.add_subparsers())
    >>> out = io.StringIO()
    >>> run(parser.parse_args(["optimize", path, "--incremental", "--json"]), out, io.StringIO())
    0
    >>> r = json.loads(out.getvalue())
    >>> r["updates"], round(r["final_cost"], 12), r["converged"]
    (2, 0.0, True)
    """
    from ..io.formats import FORMATS

    del err
    bad = [opt for opt, given in (("-o", args.output), ("--plot", args.plot),
                                  ("--solver", args.solver), ("--robust", args.robust),
                                  ("--certify", getattr(args, "certify", False)),
                                  ("--example", getattr(args, "example", False)),
                                  ("--init", args.init != "auto"),
                                  ("--damping", getattr(args, "damping", None)))
           if given]
    if bad:
        raise ValueError(f"--incremental replays the file with the incremental smoother: "
                         f"{', '.join(bad)} do not apply (drop them)")
    if args.format not in ("g2o", "toro"):
        raise ValueError(f"--incremental replays pose graphs (g2o, toro), not {args.format}")
    information = getattr(args, "information", None) or "strict"
    graph = FORMATS[args.format].load("reader")(args.input, information=information)
    rep = replay_pose_graph(graph)
    for k in ("smoother", "poses", "update_ms"):
        rep.pop(k)
    rep.update(file=args.input, incremental=True,
               problem=f"{graph.num_vertices} {graph.group.__name__} poses, "
                       f"{graph.num_edges} edges")
    return rep
