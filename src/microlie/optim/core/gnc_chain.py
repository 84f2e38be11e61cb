"""The chain of a pose graph: the spanning tree of the edges between the nearest vertex
indices, and the poses composed along it.

When the vertices are numbered in time order (g2o and TORO files of SLAM runs) the tree is the
odometry. ``GNC(chain=True)`` (:mod:`microlie.optim.core.gnc`) uses it where the data cannot
decide: exact ties of the TLS objective go to the tree's edges, and the answer with the tree's
edges held as inliers is tried against GNC's own.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import LieGroup
from .gnc_assemble import join_pieces

__all__ = ["chain_edges", "chain_poses"]


def chain_edges(edges: Any) -> np.ndarray:
    """The spanning tree (forest) of a pose graph by the nearest vertex indices: a minimum
    spanning tree with weights ``|i - j|`` (the odometry chain when vertices are numbered in
    time order and consecutive ones are joined); of parallel edges the first is used.

    Parameters
    ----------
    edges : PoseGraphEdges
        The pose graph (:func:`~microlie.optim.core.gnc_chordal.pose_graph_edges`).

    Returns
    -------
    numpy.ndarray
        ``(E,)`` booleans: the tree's edges.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_chain import chain_edges
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(4), fixed=[0])
    >>> # a closure 0-2, the chain 0-1-2-3 stored out of order, 2-1 twice
    >>> _ = g.add(BetweenFactor(x, [0, 2, 2, 0, 3], [2, 1, 1, 1, 2], SE2.identity(5)))
    >>> chain_edges(pose_graph_edges(g.problem())).tolist()
    [False, True, False, True, True]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import minimum_spanning_tree

    n, ii, jj = edges.n, edges.ii, edges.jj
    lo, hi = np.minimum(ii, jj), np.maximum(ii, jj)
    links = np.unique(np.stack([lo, hi], axis=1), axis=0).reshape(-1, 2)
    W = coo_matrix(((links[:, 1] - links[:, 0]).astype(np.float64), (links[:, 0], links[:, 1])),
                   shape=(n, n)).tocsr()
    T = minimum_spanning_tree(W).tocoo()
    tree = set(zip(np.minimum(T.row, T.col).tolist(), np.maximum(T.row, T.col).tolist(),
                   strict=True))
    in_tree = np.zeros(ii.size, dtype=bool)
    for e in range(ii.size):
        key = (int(lo[e]), int(hi[e]))
        if key in tree:  # the first edge of each tree link
            in_tree[e] = True
            tree.discard(key)
    return in_tree


def chain_poses(edges: Any, anchor_pose: LieGroup) -> LieGroup:
    """Poses composed from the anchor along :func:`chain_edges`.

    Parameters
    ----------
    edges : PoseGraphEdges
        The pose graph (:func:`~microlie.optim.core.gnc_chordal.pose_graph_edges`).
    anchor_pose : LieGroup
        The pose of ``edges.anchor``.

    Returns
    -------
    LieGroup
        ``(n,)`` poses; a vertex that no edge joins to the anchor keeps ``anchor_pose``
        composed along its own tree (rooted at its lowest vertex).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_chain import chain_poses
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3), fixed=[0])
    >>> # the chain 0-1-2 (1 m steps) and a closure 0-2 that disagrees: the chain wins
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 5.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    >>> _ = g.add(BetweenFactor(x, [0, 1, 0], [1, 2, 2], Z))
    >>> np.round(chain_poses(pose_graph_edges(g.problem()), SE2.identity()).translation(),
    ...          12).tolist()
    [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]
    """
    A = np.asarray(anchor_pose.matrix(), dtype=np.float64)
    P = join_pieces(np.tile(A, (edges.n, 1, 1)), np.asarray(edges.Z.matrix(), dtype=np.float64),
                    edges.ii, edges.jj, np.zeros(edges.ii.size, dtype=bool), chain_edges(edges),
                    edges.anchor)
    return edges.group.from_matrix(P)
