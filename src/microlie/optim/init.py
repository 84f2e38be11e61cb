"""Initial guesses for pose graphs: the file's vertices, an odometry chain, chordal relaxation,
the certified global optimum of SE-Sync's objective.

All four return one batch of poses aligned with ``graph.ids``.

- :func:`from_file`: the vertices the file holds (an error when it has none).
- :func:`odometry`: compose the edges ``ids[k] -> ids[k+1]`` (an edge stored the other way
  round is inverted); an error names the first missing link.
- :func:`chordal`: rotations by linear least squares on the entries of the rotation matrices
  (``R_i Z_ij = R_j`` for every edge, weighted by the rotation precision, the anchor's rotation
  held), one sparse Cholesky solve shared by the ``n`` rows of ``R``; projection of each
  estimate to SO(n) by SVD; then translations by linear least squares with those rotations
  fixed, ``R_i^T (t_j - t_i) = t_ij`` weighted by the translation block of the information.
- :func:`certified`: the global minimiser of SE-Sync's isotropic objective, with a verified
  certificate (:func:`microlie.optim.certify.certified_pose_graph`, started from chordal).

The odometry chain starts at the first vertex; the chordal anchor is the first fixed vertex
(``FIX``), else the first vertex. Either keeps its file pose when the file has vertices and is
the identity otherwise.

>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.io.pose_graph import PoseGraph
>>> Z = SE2.from_xy_theta([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], [np.pi / 2, np.pi / 2, np.pi])
>>> g = PoseGraph(SE2, ids=np.arange(3), poses=None, i=np.array([0, 1, 0]),
...               j=np.array([1, 2, 2]), measurements=Z, information=np.tile(np.eye(3), (3, 1, 1)))
>>> np.round(odometry(g).translation(), 12).tolist()
[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]
>>> np.round(chordal(g).translation(), 6).tolist()
[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from ..groups import SE2, SE3, LieGroup
from .io.pose_graph import PoseGraph

__all__ = ["initialize", "from_file", "odometry", "chordal", "certified", "INIT_METHODS",
           "InitMethod"]

InitMethod = Literal["file", "odometry", "chordal", "certified"]
INIT_METHODS: tuple[str, ...] = ("file", "odometry", "chordal", "certified")


def initialize(graph: PoseGraph, method: InitMethod = "file") -> LieGroup:
    r"""Initial poses by ``method``.

    Parameters
    ----------
    graph : PoseGraph
        The graph.
    method : {"file", "odometry", "chordal", "certified"}
        See :func:`from_file`, :func:`odometry`, :func:`chordal` and :func:`certified`.

    Returns
    -------
    LieGroup
        Poses aligned with ``graph.ids``.

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
    >>> from microlie.optim.init import initialize
    >>> np.round(initialize(graph, "chordal").translation()[:, 0], 9).tolist()
    [0.0, 1.0, 2.0]
    """
    if method == "file":
        return from_file(graph)
    if method == "odometry":
        return odometry(graph)
    if method == "chordal":
        return chordal(graph)
    if method == "certified":
        return certified(graph)
    raise ValueError(f"unknown initialisation {method!r}; choose one of {INIT_METHODS}")


def from_file(graph: PoseGraph) -> LieGroup:
    r"""The file's vertices.

    Parameters
    ----------
    graph : PoseGraph
        A graph with vertex lines.

    Returns
    -------
    LieGroup

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
    >>> from microlie.optim.init import from_file
    >>> from_file(graph).translation()[:, 0].tolist()
    [0.0, 0.9, 2.1]
    """
    if graph.poses is None:
        raise ValueError("the file has no vertices: use the odometry or chordal "
                         "initialisation")
    return graph.poses


def _anchor(graph: PoseGraph) -> int:
    return int(graph.index(graph.fixed[0])) if graph.fixed.size else 0


def _anchored(graph: PoseGraph, X: LieGroup, k: int) -> LieGroup:
    """Move ``X`` (with ``X[k]`` the identity) so that ``X[k]`` is the file's pose of vertex k."""
    if graph.poses is None:
        return X
    return graph.poses[k:k + 1].compose(X)


def odometry(graph: PoseGraph) -> LieGroup:
    r"""Compose the odometry chain ``ids[0] -> ids[1] -> ...``; the first pose is the file's
    (identity without vertices).

    Parameters
    ----------
    graph : PoseGraph
        The graph.

    Returns
    -------
    LieGroup

    Raises
    ------
    ValueError
        Naming the first missing link.

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
    >>> np.round(odometry(graph).translation()[:, 0], 12).tolist()
    [0.0, 1.0, 2.0]
    """
    G = graph.group
    ii, jj = graph.edge_index()
    n = graph.num_vertices
    step = np.full(n - 1, -1, dtype=np.int64)  # edge index for link k -> k+1
    forward = np.zeros(n - 1, dtype=bool)
    fwd = np.flatnonzero(jj == ii + 1)
    bwd = np.flatnonzero(ii == jj + 1)
    step[jj[bwd]] = bwd  # a reversed edge only where no forward one exists (set first)
    step[ii[fwd]] = fwd
    forward[ii[fwd]] = True
    missing = np.flatnonzero(step < 0)
    if missing.size:
        k = missing[0]
        raise ValueError(f"the odometry chain is incomplete: no edge between vertices "
                         f"{graph.ids[k]} and {graph.ids[k + 1]}")
    Z = graph.measurements[step]
    Zinv = Z.inverse()
    p = np.where(forward[:, None], np.asarray(Z.params), np.asarray(Zinv.params))
    steps = G(np.concatenate([np.asarray(G.identity((1,)).params), p], axis=0))
    X = _prefix_compose(steps)
    if graph.poses is not None:
        X = graph.poses[0:1].compose(X)
    return X


def _prefix_compose(steps: LieGroup) -> LieGroup:
    """``X_k = S_0 S_1 ... S_k`` for a batch of steps, by log2(n) batched compositions."""
    X = steps
    n = len(X)
    s = 1
    while s < n:
        head = X[:s]
        tail = X[:n - s].compose(X[s:])
        X = type(X)(np.concatenate([np.asarray(head.params), np.asarray(tail.params)], axis=0))
        s *= 2
    return X


def _solve_spd(H: Any, b: np.ndarray, block: int) -> np.ndarray:
    """Solve ``H x = b`` (symmetric positive definite, unknowns in blocks of ``block``) with the
    solver's own sparse Cholesky interface (:func:`microlie.optim.linalg.linear.make_solver`)."""
    import scipy.sparse as sp  # type: ignore[import-untyped]

    from .linalg.linear import make_solver

    H = sp.csc_matrix(H)
    H.sort_indices()
    # one factorisation: SuperLU measured fastest here, dense Cholesky on small systems
    ls = make_solver("dense" if H.shape[0] < 300 else "scipy", H.shape[0])
    ls.analyse(H.indptr, H.indices, H.shape[0], block_size=block)
    ls.factorize(H.data)
    return ls.solve(b)


def _block_normal_equations(ii: np.ndarray, jj: np.ndarray, Wi: np.ndarray, Wj: np.ndarray,
                            Wij: np.ndarray, n: int, keep: np.ndarray) -> Any:
    """Assemble ``H`` with blocks ``H_ii += Wi``, ``H_jj += Wj``, ``H_ij += Wij``,
    ``H_ji += Wij^T`` (blocks of size m), restricted to the blocks in ``keep``."""
    import scipy.sparse as sp  # type: ignore[import-untyped]

    m = Wi.shape[-1]
    pos = np.full(n, -1, dtype=np.int64)
    pos[keep] = np.arange(keep.size)
    a, b = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    rows, cols, vals = [], [], []
    for bi, bj, W in ((ii, ii, Wi), (jj, jj, Wj), (ii, jj, Wij),
                      (jj, ii, np.swapaxes(Wij, 1, 2))):
        pi, pj = pos[bi], pos[bj]
        sel = (pi >= 0) & (pj >= 0)
        rows.append((pi[sel, None, None] * m + a).ravel())
        cols.append((pj[sel, None, None] * m + b).ravel())
        vals.append(W[sel].ravel())
    size = keep.size * m
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(size, size))


def chordal(graph: PoseGraph) -> LieGroup:
    r"""Chordal initialisation: rotations by linear least squares and projection to SO(n),
    then translations by linear least squares with the rotations fixed (see the module
    docstring). The anchor vertex keeps its file pose (identity without vertices).

    Parameters
    ----------
    graph : PoseGraph
        The graph.

    Returns
    -------
    LieGroup

    Raises
    ------
    ValueError
        Naming the vertices not connected to the anchor by edges.

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
    >>> from microlie.optim.init import chordal
    >>> bool(np.allclose(chordal(graph).translation()[:, 0], [0.0, 1.0, 2.0]))
    True
    """
    from .certify.problem import project_so

    d = graph.dim
    n = graph.num_vertices
    ii, jj = graph.edge_index()
    k0 = _anchor(graph)
    _require_connected(graph, ii, jj, k0)
    keep = np.delete(np.arange(n), k0)
    Z = graph.measurements
    assert isinstance(Z, (SE2, SE3))
    Rz = np.asarray(Z.rotation().matrix())  # (E, d, d)
    tz = np.asarray(Z.translation())
    info = graph.information
    nt = d  # translation block size
    Irot = info[:, nt:, nt:]
    Itr = info[:, :nt, :nt]
    # rotation weights: the mean precision of the rotation block (its trace's inverse form)
    w = Irot.shape[-1] / np.trace(np.linalg.inv(Irot), axis1=1, axis2=2)
    # unknowns x_i = R_i^T (d x d); residual Z^T x_i - x_j; the rows of R_i decouple
    eye = np.broadcast_to(np.eye(d), Rz.shape)
    ZT = np.swapaxes(Rz, 1, 2)
    Wi = w[:, None, None] * (Rz @ ZT)  # A_i^T A_i with A_i = Z^T
    Wj = w[:, None, None] * eye
    Wij = -w[:, None, None] * Rz  # A_i^T A_j = Z (-I)
    H = _block_normal_equations(ii, jj, Wi, Wj, Wij, n, keep)
    # the anchor's x_0 = I moves to the right-hand side: b = -H[:, anchor] I
    b = np.zeros((n, d, d))
    on_i, on_j = ii == k0, jj == k0
    # terms with the anchor as j: A_i^T (-A_j x_0) = -Z(-I) I = w Z, at block i
    np.add.at(b, ii[on_j], w[on_j, None, None] * Rz[on_j])
    # terms with the anchor as i: A_j^T (-A_i x_0) = -(-I) Z^T = w Z^T, at block j
    np.add.at(b, jj[on_i], w[on_i, None, None] * ZT[on_i])
    x = _solve_spd(H, b[keep].reshape(-1, d), d)
    xs = np.empty((n, d, d))
    xs[k0] = np.eye(d)
    xs[keep] = x.reshape(-1, d, d)
    R = project_so(np.swapaxes(xs, 1, 2))
    # translations: r = R_i^T (t_j - t_i) - t_ij, weight Omega_t; A_i = -R_i^T, A_j = R_i^T
    Ri = R[ii]
    W = Ri @ Itr @ np.swapaxes(Ri, 1, 2)
    Ht = _block_normal_equations(ii, jj, W, W, -W, n, keep)
    g = np.einsum("eab,ebc,ec->ea", Ri, Itr, tz)  # R_i Omega t_ij
    bt = np.zeros((n, d))
    np.add.at(bt, ii, -g)
    np.add.at(bt, jj, g)
    t = np.zeros((n, d))
    t[keep] = _solve_spd(Ht, bt[keep].reshape(-1), d).reshape(-1, d)
    T = np.zeros((n, d + 1, d + 1))
    T[:, :d, :d] = R
    T[:, :d, d] = t
    T[:, d, d] = 1.0
    X = (SE2 if d == 2 else SE3).from_matrix(T)  # R is a rotation to rounding
    return _anchored(graph, X, k0)


def certified(graph: PoseGraph) -> LieGroup:
    r"""The certified global minimiser of SE-Sync's isotropic objective
    (:func:`microlie.optim.certify.certified_pose_graph` from the chordal start); raises when
    its certificate does not verify. The anchor vertex keeps its file pose.

    Parameters
    ----------
    graph : PoseGraph
        An SE2 or SE3 graph whose edges join all its vertices.

    Returns
    -------
    LieGroup

    Raises
    ------
    ValueError
        The certificate did not verify (the message gives the smallest eigenvalue and the
        tolerance); call ``certified_pose_graph`` for the uncertified answer.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from microlie.optim.io.g2o import read_g2o
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nVERTEX_SE2 2 2.1 0 0\n"
    ...     "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n")
    >>> from microlie.optim.init import certified
    >>> np.round(certified(read_g2o(path)).translation()[:, 0], 9).tolist()
    [0.0, 1.0, 2.0]
    """
    from .certify import certified_pose_graph

    res = certified_pose_graph(graph)
    if not res.certified:
        raise ValueError(
            f"certified initialisation: the certificate did not verify (smallest eigenvalue "
            f"{res.min_eigenvalue:.6g} below -{res.tolerance:.3g} at rank {res.rank}); use "
            f"microlie.optim.certify.certified_pose_graph for the uncertified poses, or another "
            f"initialisation")
    return res.poses


def _require_connected(graph: PoseGraph, ii: np.ndarray, jj: np.ndarray, k0: int) -> None:
    """Raise naming the vertices that no chain of edges joins to the anchor ``k0`` (their
    poses relative to it are undetermined; the normal equations would be singular)."""
    import scipy.sparse as sp  # type: ignore[import-untyped]
    from scipy.sparse.csgraph import connected_components  # type: ignore[import-untyped]

    n = graph.num_vertices
    adj = sp.coo_matrix((np.ones(ii.size), (ii, jj)), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    away = np.flatnonzero(label != label[k0])
    if away.size:
        ids = [str(v) for v in np.asarray(graph.ids)[away[:20]]]
        more = f" and {away.size - 20} more" if away.size > 20 else ""
        raise ValueError(
            f"chordal initialisation: {away.size} vertices are not connected by edges to the "
            f"anchor vertex {graph.ids[k0]}: {', '.join(ids)}{more}; add edges joining them to "
            f"the rest of the graph, or remove them")

