"""Plots of pose graphs (matplotlib, an optional dependency: ``pip install microlie[plot]``).

:func:`plot_pose_graph` draws the initial and the optimised graph side by side: a top view
(x, y) for SE2, a 3-D view for SE3. Odometry edges (``j = i + 1``) are drawn darker than loop
closures. It builds a ``matplotlib.figure.Figure`` directly and renders it with the Agg
canvas, so it never touches pyplot or the caller's backend.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .._files import save_figure
from ..groups import LieGroup
from .io.pose_graph import PoseGraph

__all__ = ["plot_pose_graph"]


def _segments(graph: PoseGraph, X: LieGroup) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(X.params)[:, :graph.dim]
    ii, jj = graph.edge_index()
    seg = np.stack([t[ii], t[jj]], axis=1)
    odo = jj == ii + 1
    return seg[odo], seg[~odo]


def plot_pose_graph(graph: PoseGraph, initial: LieGroup, optimised: LieGroup,
                    path: str | Path | None = None, title: str | None = None) -> Any:
    r"""Figure with the initial (left) and optimised (right) graph, built with the Agg canvas
    (the caller's matplotlib state is left alone).

    Parameters
    ----------
    graph : PoseGraph
        The graph (its edges are drawn).
    initial, optimised : LieGroup
        Poses aligned with ``graph.ids``.
    path : str or pathlib.Path, optional
        Save the figure there (PNG, 1200 x 600 px).
    title : str, optional
        The figure title.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from microlie.optim.io.g2o import read_g2o
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nVERTEX_SE2 2 2.1 0 0\n"
    ...     "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n")
    >>> graph = read_g2o(path)
    >>> from microlie.optim.init import odometry
    >>> from microlie.optim.plot import plot_pose_graph
    >>> fig = plot_pose_graph(graph, graph.poses, odometry(graph))
    >>> len(fig.axes)
    2
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import LineCollection
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - exercised only without matplotlib
        raise ImportError("plotting needs matplotlib: pip install 'microlie[plot]'") from exc
    fig = Figure(figsize=(12.0, 6.0), dpi=100)
    FigureCanvasAgg(fig)
    three_d = graph.dim == 3
    for k, (X, name) in enumerate(((initial, "initial"), (optimised, "optimised"))):
        odo, loops = _segments(graph, X)
        if three_d:
            from mpl_toolkits.mplot3d.art3d import (  # type: ignore[import-untyped]
                Line3DCollection,
            )

            ax = fig.add_subplot(1, 2, k + 1, projection="3d")
            ax.add_collection3d(Line3DCollection(loops, colors="tab:orange", linewidths=0.3,
                                                 alpha=0.5, label="loop closures"))
            ax.add_collection3d(Line3DCollection(odo, colors="tab:blue", linewidths=0.8,
                                                 label="odometry"))
            pts = np.asarray(X.params)[:, :3]
            lo, hi = pts.min(0), pts.max(0)
            mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-9)
            ax.set_xlim(mid[0] - half, mid[0] + half)
            ax.set_ylim(mid[1] - half, mid[1] + half)
            ax.set_zlim(mid[2] - half, mid[2] + half)
            ax.set_zlabel("z")
        else:
            ax = fig.add_subplot(1, 2, k + 1)
            ax.add_collection(LineCollection(list(loops), colors="tab:orange", linewidths=0.3,
                                             alpha=0.5, label="loop closures"))
            ax.add_collection(LineCollection(list(odo), colors="tab:blue", linewidths=0.8,
                                             label="odometry"))
            ax.autoscale()
            ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_title(f"{name}: cost {graph.cost(X):.10g}")
        if k == 0:
            ax.legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(title)
    if path is not None:
        save_figure(fig, path)
    return fig
