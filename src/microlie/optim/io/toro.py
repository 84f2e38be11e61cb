"""TORO pose-graph files: ``VERTEX2``/``EDGE2`` (2-D) and ``VERTEX3``/``EDGE3`` (3-D).

Lines (``#`` starts a comment)::

    VERTEX2 id x y theta
    EDGE2 i j dx dy dtheta I_xx I_xy I_yy I_tt I_xt I_yt
    VERTEX3 id x y z roll pitch yaw
    EDGE3 i j dx dy dz droll dpitch dyaw I11 I12 ... I16 I22 ... I66

An edge says ``Z_ij ~ X_i^-1 X_j`` (as in GTSAM's and TORO's own readers).

**2-D information order differs from g2o's.** TORO lists ``inf_ff inf_fs inf_ss inf_rr
inf_fr inf_sr`` (f forward = x, s sideways = y, r rotation = theta): the three diagonal-ish
entries ``xx, xy, yy`` of the translation block, then ``theta theta``, then the two cross terms
``x theta, y theta``. In g2o's order that is ``[[v0, v1, v4], [v1, v2, v5], [v4, v5, v3]]``.

**3-D**: rotations are roll, pitch, yaw with ``R = Rz(yaw) Ry(pitch) Rx(roll)``; the 21
information numbers are the upper triangle, row by row, over ``(x, y, z, roll, pitch, yaw)``.
We use that matrix as the information of our tangent ``(rho, phi)`` as stored, without a
Jacobian between Euler-angle and so(3) perturbations (exact at zero rotation, and what TORO
files, usually with diagonal information, are written for). GTSAM 4.3's ``EDGE3`` reader
takes the matrix in its own rotation-first order instead, so on a TORO 3-D file with
different translation and rotation weights its cost differs from ours.

>>> import tempfile, os
>>> from microlie.optim.io.toro import read_toro
>>> path = os.path.join(tempfile.mkdtemp(), "g.graph")
>>> _ = open(path, "w").write("VERTEX2 0 0 0 0\\nVERTEX2 1 1 0 0\\n"
...                            "EDGE2 0 1 1 0 0 10 1 20 30 2 3\\n")
>>> read_toro(path).information[0].tolist()
[[10.0, 1.0, 2.0], [1.0, 20.0, 3.0], [2.0, 3.0, 30.0]]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..._files import atomic_write
from ...groups import SE2, SE3, SO3, LieGroup
from .pose_graph import (
    EdgeTag,
    PoseGraph,
    VertexTag,
    format_rows,
    parse_pose_graph,
    pose_values,
    se2_params,
    symmetric_from_upper,
)

__all__ = ["read_toro", "write_toro"]

# TORO's (ff, fs, ss, rr, fr, sr) -> upper triangle (xx, xy, xt, yy, yt, tt)
_TORO_TO_UPPER = [0, 1, 4, 2, 5, 3]
_UPPER_TO_TORO = list(np.argsort(_TORO_TO_UPPER))


def _se3_rpy_params(v: np.ndarray) -> np.ndarray:
    q = np.asarray(SO3.from_rpy(v[:, 3], v[:, 4], v[:, 5]).params)
    return np.concatenate([v[:, :3], q], axis=-1)


VERTEX_TAGS = {
    "VERTEX2": VertexTag(SE2, 3, se2_params),
    "VERTEX3": VertexTag(SE3, 6, _se3_rpy_params),
}
EDGE_TAGS = {
    "EDGE2": EdgeTag(SE2, 3, 6, se2_params,
                     lambda w: symmetric_from_upper(w[:, _TORO_TO_UPPER], 3)),
    "EDGE3": EdgeTag(SE3, 6, 21, _se3_rpy_params, lambda w: symmetric_from_upper(w, 6)),
}


def read_toro(path: str | Path, *, information: str = "strict") -> PoseGraph:
    r"""Read a TORO pose graph (2-D or 3-D); information matrices come back in our tangent
    order (see the module docstring for TORO's 2-D order).

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
    >>> from microlie.optim.io.toro import read_toro, write_toro
    >>> out = os.path.join(os.path.dirname(path), "out.graph")
    >>> write_toro(out, graph)
    >>> back = read_toro(out)
    >>> round(back.cost(), 12), bool(np.allclose(back.information, graph.information))
    (0.025, True)
    """
    return parse_pose_graph(path, VERTEX_TAGS, EDGE_TAGS, kind="TORO",
                            information=information)


def _toro_values(X: LieGroup) -> np.ndarray:
    if isinstance(X, SE2):
        return pose_values(X)
    assert isinstance(X, SE3)
    p = np.asarray(X.params, dtype=np.float64)
    R = X.rotation()
    assert isinstance(R, SO3)
    return np.concatenate([p[:, :3], np.asarray(R.as_rpy())], axis=1)


def write_toro(path: str | Path, graph: PoseGraph, poses: LieGroup | None = None) -> None:
    r"""Write ``graph`` as TORO, with ``poses`` as vertex lines. TORO has no fixed-vertex line:
    a graph with fixed ids is refused (``ValueError``).

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
    >>> from microlie.optim.io.toro import write_toro
    >>> out = os.path.join(os.path.dirname(path), "out.graph")
    >>> write_toro(out, graph)
    >>> open(out).readline().split()[0]
    'VERTEX2'
    """
    if graph.fixed.size:
        raise ValueError("TORO files cannot hold fixed vertices; write g2o instead")
    X = graph.poses if poses is None else graph._poses(poses)
    is2d = graph.group is SE2
    vtag, etag = ("VERTEX2", "EDGE2") if is2d else ("VERTEX3", "EDGE3")
    d = graph.group.dof
    r, c = np.triu_indices(d)
    w = graph.information[:, r, c]
    if is2d:
        w = w[:, _UPPER_TO_TORO]
    lines: list[str] = []
    if X is not None:
        lines += format_rows(vtag, [graph.ids], _toro_values(X))
    lines += format_rows(etag, [graph.i, graph.j],
                         np.concatenate([_toro_values(graph.measurements), w], axis=1))
    with atomic_write(path) as f:  # a temporary file renamed over ``path``
        f.write("\n".join(lines) + "\n")
