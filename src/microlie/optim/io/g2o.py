"""g2o pose-graph files: ``VERTEX_SE2``, ``EDGE_SE2``, ``VERTEX_SE3:QUAT``, ``EDGE_SE3:QUAT``,
``FIX``.

Lines (``#`` starts a comment)::

    VERTEX_SE2 id x y theta
    EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33
    VERTEX_SE3:QUAT id x y z qx qy qz qw
    EDGE_SE3:QUAT i j dx dy dz qx qy qz qw I11 I12 ... I16 I22 ... I66
    FIX id [id ...]

An edge says ``Z_ij ~ X_i^-1 X_j``; the information numbers are the upper triangle of a
symmetric matrix, row by row.

**Information order.** g2o stores the information in ``[t, R]`` order: SE2 ``(x, y, theta)``,
SE3 ``(x, y, z, rotation x, y, z)``. Our tangent is translation first too (SE2
``(rho_x, rho_y, theta)``, SE3 ``(rho, phi)``), so the matrix is used **as stored, with no
reordering**, and with **no Jacobian** between g2o's rotation parametrisation and ours: g2o's
own ``EdgeSE3`` error takes the quaternion vector part (about ``phi / 2``) as its rotation
residual, which would call for scaling the rotation rows and columns by 1/2, but GTSAM 4.3's
``readG2o`` uses the matrix as the information of ``Log(Z^-1 X_i^-1 X_j)`` with a plain block
reorder to its rotation-first tangent (cross terms included, since gtsam PR #1310). We do the
same, so our cost ``0.5 sum r^T Omega r`` with ``r = Log(Z^-1 X_i^-1 X_j)`` in ``(rho, phi)``
equals GTSAM's error. It equals g2o's chi^2 / 2 on SE2 graphs only.

Quaternions are ``(x, y, z, w)`` and are normalised on reading (files print them rounded;
a norm off by more than 1 % is an error, as is every malformed line, reported as
``ValueError("FILE:LINE: ...")``).

>>> import numpy as np, tempfile, os
>>> from microlie.optim.io.g2o import read_g2o, write_g2o
>>> text = "VERTEX_SE2 0 0 0 0\\nVERTEX_SE2 1 1 0 0\\nEDGE_SE2 0 1 1.1 0 0 100 0 0 100 0 100\\n"
>>> path = os.path.join(tempfile.mkdtemp(), "g.g2o")
>>> _ = open(path, "w").write(text)
>>> g = read_g2o(path)
>>> g.group.__name__, g.num_vertices, g.num_edges, round(g.cost(), 12)
('SE2', 2, 1, 0.5)
>>> write_g2o(path, g); read_g2o(path).information[0].diagonal().tolist()
[100.0, 100.0, 100.0]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..._files import atomic_write
from ...groups import SE2, SE3, LieGroup
from .pose_graph import (
    EdgeTag,
    PoseGraph,
    VertexTag,
    format_rows,
    parse_pose_graph,
    pose_values,
    se2_params,
    symmetric_from_upper,
    unit_quaternions,
)

__all__ = ["read_g2o", "write_g2o"]


def _se3_params(v: np.ndarray) -> np.ndarray:
    return np.concatenate([v[:, :3], unit_quaternions(v[:, 3:7])], axis=-1)


VERTEX_TAGS = {
    "VERTEX_SE2": VertexTag(SE2, 3, se2_params),
    "VERTEX_SE3:QUAT": VertexTag(SE3, 7, _se3_params),
}
EDGE_TAGS = {
    "EDGE_SE2": EdgeTag(SE2, 3, 6, se2_params, lambda w: symmetric_from_upper(w, 3)),
    "EDGE_SE3:QUAT": EdgeTag(SE3, 7, 21, _se3_params, lambda w: symmetric_from_upper(w, 6)),
}


def read_g2o(path: str | Path, *, information: str = "strict") -> PoseGraph:
    r"""Read a g2o pose graph (2-D or 3-D).

    The information matrices come back in our tangent order, which is g2o's (see the module
    docstring). ``poses`` is ``None`` when the file has no vertex lines.

    Parameters
    ----------
    path : str or pathlib.Path
        The file.
    information : {"strict", "nearest-psd", "isotropic"}
        Information matrices that are not positive definite: refused with ``FILE:LINE`` and
        their count (default), replaced by the nearest positive definite ones, or every
        matrix replaced by SE-Sync's isotropic precisions
        (:mod:`microlie.optim.io.information`; the replaced edges are in ``repaired``).

    Returns
    -------
    PoseGraph

    Raises
    ------
    ValueError
        A malformed line, naming ``FILE:LINE``.

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
    >>> graph.group.__name__, graph.ids.tolist(), graph.i.tolist(), graph.j.tolist()
    ('SE2', [0, 1, 2], [0, 1], [1, 2])
    """
    return parse_pose_graph(path, VERTEX_TAGS, EDGE_TAGS, fix_tag="FIX", kind="g2o",
                            information=information)


def write_g2o(path: str | Path, graph: PoseGraph, poses: LieGroup | None = None) -> None:
    r"""Write ``graph`` as g2o, with ``poses`` as vertex lines.

    Numbers are written in the shortest form that reads back to the same double, so reading
    the file back gives the same graph (angles go through ``atan2`` for SE2).

    Parameters
    ----------
    path : str or pathlib.Path
        The file to write.
    graph : PoseGraph
        The graph.
    poses : LieGroup, optional
        Poses aligned with ``ids`` (default: the graph's own).

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
    >>> from microlie.optim.io.g2o import write_g2o
    >>> out = os.path.join(os.path.dirname(path), "out.g2o")
    >>> write_g2o(out, graph)
    >>> bool(np.allclose(read_g2o(out).information, graph.information))
    True
    """
    X = graph.poses if poses is None else graph._poses(poses)
    is2d = graph.group is SE2
    vtag, etag = ("VERTEX_SE2", "EDGE_SE2") if is2d else ("VERTEX_SE3:QUAT", "EDGE_SE3:QUAT")
    d = graph.group.dof
    r, c = np.triu_indices(d)
    lines: list[str] = []
    if X is not None:
        lines += format_rows(vtag, [graph.ids], pose_values(X))
    lines += format_rows(etag, [graph.i, graph.j],
                         np.concatenate([pose_values(graph.measurements),
                                         graph.information[:, r, c]], axis=1))
    if graph.fixed.size:
        lines.append("FIX " + " ".join(str(int(k)) for k in graph.fixed))
    with atomic_write(path) as f:  # a temporary file renamed over ``path``
        f.write("\n".join(lines) + "\n")
