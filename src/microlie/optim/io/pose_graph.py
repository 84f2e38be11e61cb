"""Pose graphs read from files: one typed object, a shared line parser, GTSAM's cost.

A :class:`PoseGraph` holds what a g2o or TORO file says: the group (SE2 or SE3), the vertex
ids, the initial poses as one batch (``None`` when the file has no vertices), the edges
``i -> j`` with their measurements ``Z`` as one batch, the information matrices ``(E, d, d)`` in
**our tangent order** (translation first: SE2 ``(x, y, theta)``, SE3 ``(rho, phi)``), and the
fixed ids. Its :meth:`~PoseGraph.cost` is GTSAM's ``0.5 sum r^T Omega r`` with the edge
residual ``r = (X_i^-1 X_j) (-) Z = Log(Z^-1 X_i^-1 X_j)``, over the file's edges only.

The readers live in :mod:`microlie.optim.io.g2o` and :mod:`microlie.optim.io.toro`; both use the
parser here, which reports a malformed line as ``ValueError("FILE:LINE: ...")``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..._fast import text_parser
from ..._textfile import digits_only, numbers_by_line, plain_error, read_text
from ...groups import SE2, SE3, LieGroup
from .information import INFORMATION_POLICIES, apply_information_policy

__all__ = ["PoseGraph", "VertexTag", "EdgeTag", "parse_pose_graph", "symmetric_from_upper",
           "se2_params", "pose_values", "format_rows"]


@dataclass(frozen=True, eq=False)
class PoseGraph:
    """A pose graph: vertices (ids, optional initial poses), edges with measurements and
    information matrices in our tangent order, and fixed ids.

    ``i``, ``j`` and ``fixed`` hold vertex *ids* as in the file; ``ids`` is sorted and
    ``poses[k]`` (when present) is the pose of ``ids[k]``. An edge says ``Z ~ X_i^-1 X_j``.

    Parameters
    ----------
    group : type
        The pose group (SE2 or SE3).
    ids : numpy.ndarray
        ``(V,)`` sorted vertex ids.
    poses : LieGroup or None
        ``(V,)`` initial poses, or ``None`` without vertex lines.
    i, j : numpy.ndarray
        ``(E,)`` edge endpoint ids.
    measurements : LieGroup
        ``(E,)`` relative poses ``Z``.
    information : numpy.ndarray
        ``(E, d, d)`` information matrices, tangent translation first.
    fixed : numpy.ndarray
        Ids of fixed vertices.
    repaired : numpy.ndarray
        Indices of the edges whose information matrix in the file was not positive definite
        and was replaced by the reader's ``information=`` policy
        (:mod:`microlie.optim.io.information`); empty by default.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> g = PoseGraph(SE2, ids=np.array([0, 1]), poses=SE2.from_xy_theta([0., 1.], [0., 0.], 0.),
    ...               i=np.array([0]), j=np.array([1]),
    ...               measurements=SE2.from_xy_theta([1.1], [0.], [0.]),
    ...               information=np.eye(3)[None] * 100.0)
    >>> round(g.cost(), 12)  # 0.5 * 100 * 0.1^2
    0.5
    """

    group: type[LieGroup]
    ids: np.ndarray
    poses: LieGroup | None
    i: np.ndarray
    j: np.ndarray
    measurements: LieGroup
    information: np.ndarray
    fixed: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    repaired: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        if self.group not in (SE2, SE3):
            raise ValueError(f"a pose graph is on SE2 or SE3, got {self.group!r}")
        d = self.group.dof
        ids = np.asarray(self.ids, dtype=np.int64)
        object.__setattr__(self, "ids", ids)
        for name in ("i", "j", "fixed", "repaired"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.int64))
        if ids.ndim != 1 or np.any(np.diff(ids) <= 0):
            raise ValueError("ids must be a strictly increasing 1-D array of vertex ids")
        n_e = self.i.shape[0]
        if self.i.shape != (n_e,) or self.j.shape != (n_e,):
            raise ValueError("i and j must be 1-D arrays of the same length")
        rep = self.repaired
        if rep.ndim != 1 or np.any((rep < 0) | (rep >= n_e)):
            raise ValueError(f"repaired must be a 1-D array of edge indices in 0 .. {n_e - 1}")
        if self.measurements.batch_shape != (n_e,) or type(self.measurements) is not self.group:
            raise ValueError(f"measurements must be a {self.group.__name__} batch of {n_e}")
        info = np.asarray(self.information, dtype=np.float64)
        if info.shape != (n_e, d, d):
            raise ValueError(f"information must have shape ({n_e}, {d}, {d}), got {info.shape}")
        object.__setattr__(self, "information", info)
        if self.poses is not None and (type(self.poses) is not self.group
                                       or self.poses.batch_shape != ids.shape):
            raise ValueError(f"poses must be a {self.group.__name__} batch of {ids.size}")
        for name in ("i", "j", "fixed"):
            missing = np.setdiff1d(getattr(self, name), ids)
            if missing.size:
                raise ValueError(f"{name} refers to vertex id {int(missing[0])}, not in ids")

    # ------------------------------------------------------------------ sizes and indices
    @property
    def dim(self) -> int:
        """The dimension of the poses: 2 (SE2) or 3 (SE3)."""
        return self.group.point_dim

    @property
    def num_vertices(self) -> int:
        return int(self.ids.size)

    @property
    def num_edges(self) -> int:
        return int(self.i.size)

    def index(self, ids: Any) -> np.ndarray:
        r"""Positions in ``ids`` (and in ``poses``) of the given vertex ids.

        Parameters
        ----------
        ids : array_like
            Vertex ids of the graph.

        Returns
        -------
        numpy.ndarray
            Integer positions.

        Raises
        ------
        ValueError
            An id that is not a vertex.

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
        >>> graph.index([2, 0]).tolist()
        [2, 0]
        """
        ids = np.asarray(ids, dtype=np.int64)
        k = np.searchsorted(self.ids, ids)
        bad = (k >= self.ids.size) | (self.ids[np.minimum(k, self.ids.size - 1)] != ids)
        if np.any(bad):
            raise ValueError(f"vertex id {int(ids[bad].reshape(-1)[0])} is not in this graph")
        return k

    def edge_index(self) -> tuple[np.ndarray, np.ndarray]:
        r"""Positions ``(ii, jj)`` in ``poses`` of the edges' endpoints.

        Returns
        -------
        ii, jj : numpy.ndarray

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
        >>> [a.tolist() for a in graph.edge_index()]
        [[0, 1], [1, 2]]
        """
        return self.index(self.i), self.index(self.j)

    def replace(self, **changes: Any) -> PoseGraph:
        r"""A copy with some fields replaced (for example ``poses=...``).

        Parameters
        ----------
        **changes
            Field values.

        Returns
        -------
        PoseGraph

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
        >>> from microlie import SE2
        >>> graph.replace(poses=SE2.from_xy_theta([0.0, 1.0, 2.0], 0.0, 0.0)).cost()
        0.0
        """
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ cost
    def residuals(self, poses: LieGroup | None = None) -> np.ndarray:
        r"""Edge residuals ``Log(Z^-1 X_i^-1 X_j)`` in our tangent order.

        Parameters
        ----------
        poses : LieGroup, optional
            Poses aligned with ``ids`` (default: the graph's own).

        Returns
        -------
        numpy.ndarray
            ``(E, d)``.

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
        >>> np.round(graph.residuals(), 12).tolist()
        [[-0.1, 0.0, 0.0], [0.2, 0.0, 0.0]]
        """
        X = self._poses(poses)
        ii, jj = self.edge_index()
        return np.asarray(X[ii].between(X[jj]).minus(self.measurements))

    def cost(self, poses: LieGroup | None = None) -> float:
        r"""GTSAM's error ``0.5 sum_e r_e^T Omega_e r_e`` over the edges (no prior terms).

        Parameters
        ----------
        poses : LieGroup, optional
            Poses aligned with ``ids`` (default: the graph's own).

        Returns
        -------
        float

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
        >>> round(graph.cost(), 12)  # 0.5 * (0.1^2 + 0.2^2)
        0.025
        """
        r = self.residuals(poses)
        return 0.5 * float(np.einsum("ei,eij,ej->", r, self.information, r))

    # ------------------------------------------------------------------ to the solver
    def to_factor_graph(self, poses: LieGroup | None = None, *, loss: Any = None,
                        gauge: str = "prior", prior_sigma: float = 1e-6) -> tuple[Any, Any]:
        r"""Build a :class:`~microlie.optim.FactorGraph` of this graph's edges.

        One ``BetweenFactor`` batch holds every edge with its information matrix and ``loss``.
        The gauge: the file's fixed vertices when it has ``FIX`` lines; otherwise
        ``gauge="prior"`` (default, as GTSAM) adds a prior on the first pose at its start value
        with standard deviation ``prior_sigma`` (a term :meth:`cost` leaves out), ``gauge="fix"``
        holds the first pose constant, ``gauge="none"`` adds nothing (the solver then asks for a
        gauge).

        Parameters
        ----------
        poses : LieGroup, optional
            The start (default: the file's).
        loss : str or RobustLoss, optional
            A robust loss or a spec such as ``"huber:1.0"``.
        gauge : {"prior", "fix", "none"}
            See above.
        prior_sigma : float
            The gauge prior's standard deviation.

        Returns
        -------
        factor_graph : FactorGraph
        handle : Variables
            ``result.values[handle]`` is the optimised batch aligned with ``ids``.

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
        >>> fg, x = graph.to_factor_graph(gauge="fix")
        >>> res = fg.optimize()
        >>> np.round(res.values[x].translation()[:, 0], 9).tolist()
        [0.0, 1.0, 2.0]
        """
        from ..core.factors import BetweenFactor, PriorFactor
        from ..core.graph import FactorGraph
        from ..core.noise import Information, Isotropic

        X = self._poses(poses)
        fg = FactorGraph()
        fixed = self.index(self.fixed) if self.fixed.size else None
        if fixed is None and gauge == "fix":
            fixed = np.array([0])
        elif gauge not in ("prior", "fix", "none"):
            raise ValueError(f"gauge must be 'prior', 'fix' or 'none', got {gauge!r}")
        handle = fg.add_variables(X, fixed=fixed, name="poses")
        ii, jj = self.edge_index()
        info = np.asarray(self.information)
        if len(info) and bool(np.all(info == info[0])):  # one matrix for every edge: one
            info = info[0]  # square root shared (as GTSAM shares one noise model)
        fg.add(BetweenFactor(handle, ii, jj, self.measurements, Information(info), loss=loss))
        if fixed is None and gauge == "prior":
            fg.add(PriorFactor(handle, [0], X[0:1], Isotropic(self.group.dof, prior_sigma)))
        return fg, handle

    def _poses(self, poses: LieGroup | None) -> LieGroup:
        X = self.poses if poses is None else poses
        if X is None:
            raise ValueError("this pose graph has no poses: give poses or initialise "
                             "(microlie.optim.init)")
        if type(X) is not self.group or X.batch_shape != self.ids.shape:
            raise ValueError(f"poses must be a {self.group.__name__} batch of {self.ids.size}")
        return X


def symmetric_from_upper(values: np.ndarray, d: int) -> np.ndarray:
    """Upper-triangle entries, row by row, to symmetric matrices.

    Parameters
    ----------
    values : numpy.ndarray
        ``(E, d(d+1)/2)``.
    d : int
        The matrix size.

    Returns
    -------
    numpy.ndarray
        ``(E, d, d)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.io.pose_graph import symmetric_from_upper
    >>> symmetric_from_upper(np.array([[1.0, 2.0, 3.0]]), 2)[0].tolist()
    [[1.0, 2.0], [2.0, 3.0]]
    """
    r, c = np.triu_indices(d)
    M = np.zeros((values.shape[0], d, d))
    M[:, r, c] = values
    M[:, c, r] = values
    return M


def se2_params(values: np.ndarray) -> np.ndarray:
    """SE(2) parameters ``(x, y, cos theta, sin theta)`` of the ``(x, y, theta)`` columns of
    a file's rows (g2o's and TORO's 2-D vertices and edges).

    Parameters
    ----------
    values : numpy.ndarray
        ``(N, 3)``: ``x, y, theta`` (radians).

    Returns
    -------
    numpy.ndarray
        ``(N, 4)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.io.pose_graph import se2_params
    >>> np.round(se2_params(np.array([[1.0, 2.0, np.pi / 2]])), 12).tolist()
    [[1.0, 2.0, 0.0, 1.0]]
    """
    v = values
    return np.stack([v[:, 0], v[:, 1], np.cos(v[:, 2]), np.sin(v[:, 2])], axis=-1)


def pose_values(X: LieGroup) -> np.ndarray:
    """The numbers a g2o or TORO line prints for a batch of poses: ``(x, y, theta)`` for SE(2)
    (``theta = atan2(sin, cos)``), the parameters ``(t, q_xyzw)`` for SE(3).

    Parameters
    ----------
    X : LieGroup
        A batch of SE(2) or SE(3) poses.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` or ``(N, 7)``, float64.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import pose_values
    >>> np.round(pose_values(SE2.exp(np.array([[0.0, 0.0, 0.5]]))), 12).tolist()
    [[0.0, 0.0, 0.5]]
    """
    p = np.asarray(X.params, dtype=np.float64)
    if isinstance(X, SE2):
        return np.stack([p[:, 0], p[:, 1], np.arctan2(p[:, 3], p[:, 2])], axis=-1)
    return p


def format_rows(tag: str, ids: list[np.ndarray], values: np.ndarray) -> list[str]:
    """One text line per row: the tag, the integer ids, then the numbers in Python's shortest
    ``repr`` that reads back to the same double.

    Parameters
    ----------
    tag : str
        The line's first word (``"VERTEX_SE2"``, ``"EDGE2"``, ...).
    ids : list of numpy.ndarray
        One ``(N,)`` integer array per id column.
    values : numpy.ndarray
        ``(N, k)``: the numbers of each line.

    Returns
    -------
    list of str

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.io.pose_graph import format_rows
    >>> format_rows("VERTEX_SE2", [np.array([7])], np.array([[0.1, 2.0, -3.0]]))
    ['VERTEX_SE2 7 0.1 2.0 -3.0']
    """
    fmt = f"{tag} " + " ".join(["%d"] * len(ids) + ["%r"] * values.shape[1])
    id_rows = np.stack(ids, axis=1).tolist()
    return [fmt % (*i, *v) for i, v in zip(id_rows, values.tolist(), strict=True)]


# ---------------------------------------------------------------------- the line parser
@dataclass(frozen=True)
class VertexTag:
    """A vertex line ``TAG id v_1 ... v_n`` of a pose-graph format.

    Parameters
    ----------
    group : type
        The pose group.
    n : int
        Number of values after the id.
    to_params : callable
        Maps ``(V, n)`` values to group parameters ``(V, param_dim)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import VertexTag
    >>> tag = VertexTag(SE2, 3, lambda v: SE2.from_xy_theta(v[:, 0], v[:, 1], v[:, 2]).params)
    >>> tag.to_params(np.array([[1.0, 2.0, 0.0]])).tolist()
    [[1.0, 2.0, 1.0, 0.0]]
    """

    group: type[LieGroup]
    n: int
    to_params: Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class EdgeTag:
    """An edge line ``TAG i j z_1 ... z_n w_1 ... w_m`` of a pose-graph format.

    Parameters
    ----------
    group : type
        The pose group.
    n : int
        Number of measurement values.
    m : int
        Number of information values.
    to_params : callable
        Maps the ``(E, n)`` measurement values to group parameters.
    to_information : callable
        Maps ``(E, m)`` values to ``(E, d, d)`` information matrices in our tangent order.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import EdgeTag, symmetric_from_upper
    >>> tag = EdgeTag(SE2, 3, 6, lambda z: SE2.from_xy_theta(z[:, 0], z[:, 1], z[:, 2]).params,
    ...               lambda w: symmetric_from_upper(w, 3))
    >>> tag.to_information(np.array([[1.0, 0, 0, 2.0, 0, 3.0]]))[0].diagonal().tolist()
    [1.0, 2.0, 3.0]
    """

    group: type[LieGroup]
    n: int
    m: int
    to_params: Callable[[np.ndarray], np.ndarray]
    to_information: Callable[[np.ndarray], np.ndarray]


class _Lines:
    """The numbers of one kind of line (vertex, edge or FIX), with line numbers for messages."""

    def __init__(self) -> None:
        self.ids: Any = np.zeros((0, 0), dtype=np.int64)
        self.values: Any = np.zeros((0, 0))
        self.lines: Any = np.zeros(0, dtype=np.int64)


def parse_pose_graph(path: str | Path, vertex_tags: dict[str, VertexTag],
                     edge_tags: dict[str, EdgeTag], fix_tag: str | None = None,
                     kind: str = "pose-graph", *, information: str = "strict") -> PoseGraph:
    r"""Parse a line-based pose-graph file with the given tags (see :mod:`.g2o`, :mod:`.toro`).

    The file is UTF-8 (a byte order mark is dropped). Blank lines and lines starting with
    ``#`` are skipped. Every other line must start with a known tag and have exactly its
    number of fields (each line is checked); ids are integers in ``0 .. 2**63 - 1``, read
    exactly, and the numbers finite, in plain ASCII (Python's ``int`` and ``float`` rules
    without ``_`` separators or other scripts' digits). Anything else is
    a ``ValueError`` naming ``FILE:LINE``. Lines are grouped by tag and each group is
    converted in one call; a group that fails is re-read line by line to name the first bad
    line.

    Parameters
    ----------
    path : str or pathlib.Path
        The file.
    vertex_tags, edge_tags : dict
        Tag name to :class:`VertexTag` / :class:`EdgeTag`.
    fix_tag : str, optional
        The fixed-vertex tag (``"FIX"`` for g2o).
    kind : str
        The format's name, for messages.
    information : {"strict", "nearest-psd", "isotropic"}
        What to do with information matrices that are not positive definite: refuse the file
        (default), repair them, or make every matrix isotropic
        (:mod:`microlie.optim.io.information`).

    Returns
    -------
    PoseGraph

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
    >>> from microlie.optim.io.g2o import EDGE_TAGS, VERTEX_TAGS
    >>> from microlie.optim.io.pose_graph import parse_pose_graph
    >>> len(parse_pose_graph(path, VERTEX_TAGS, EDGE_TAGS, "FIX").ids)
    3
    """
    if information not in INFORMATION_POLICIES:
        raise ValueError(f"information must be one of "
                         f"{', '.join(map(repr, INFORMATION_POLICIES))}, got {information!r}")
    path = Path(path)
    name = str(path)
    known = sorted([*vertex_tags, *edge_tags, *([fix_tag] if fix_tag else [])])
    text = read_text(path)
    buckets: dict[str, tuple[list[str], list[int]]] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        parts = line.split(None, 1)
        if not parts or parts[0].startswith("#"):
            continue
        b = buckets.get(parts[0])
        if b is None:
            b = buckets[parts[0]] = ([], [])
        if line.isascii():
            b[0].append(parts[1] if len(parts) > 1 else "")
        else:  # with the separator: a no-break space after the tag is refused too
            b[0].append(line.lstrip()[len(parts[0]):])
        b[1].append(lineno)
    group: type[LieGroup] | None = None
    group_tag, group_line = "", 0
    vertices, edges, fixed = _Lines(), _Lines(), _Lines()
    errors: list[tuple[int, str]] = []  # (line, message): the first bad line is reported
    for tag, (rests, lines) in sorted(buckets.items(), key=lambda kv: kv[1][1][0]):
        try:
            if tag == fix_tag:
                for r, ln in zip(rests, lines, strict=True):
                    why = plain_error(r)
                    if why is not None:
                        raise _LineError(ln, f"{name}:{ln}: {tag}: {why}")
                ids = [_ints(r.split(), f"{name}:{ln}", tag, at_least_one=True, line=ln)
                       for r, ln in zip(rests, lines, strict=True)]
                fixed.ids = [i for row in ids for i in row]
                fixed.lines = [ln for row, ln in zip(ids, lines, strict=True) for _ in row]
                continue
            spec: VertexTag | EdgeTag
            if tag in vertex_tags:
                spec, n_ids, store = vertex_tags[tag], 1, vertices
                n_num = spec.n
            elif tag in edge_tags:
                spec, n_ids, store = edge_tags[tag], 2, edges
                n_num = spec.n + spec.m
            else:
                raise _LineError(lines[0], f"{name}:{lines[0]}: unknown tag {tag!r} in a "
                                 f"{kind} file (known: {', '.join(known)})")
            if group is None:
                group, group_tag, group_line = spec.group, tag, lines[0]
            elif spec.group is not group:
                raise _LineError(lines[0], f"{name}:{lines[0]}: {tag} is a "
                                 f"{spec.group.__name__} line but line {group_line} "
                                 f"({group_tag}) made this a {group.__name__} graph")
            store.ids, store.values = _block(name, tag, rests, lines, n_ids, n_num)
            store.lines = np.asarray(lines, dtype=np.int64)
        except _LineError as e:
            errors.append((e.line, str(e)))
    if errors:
        raise ValueError(min(errors)[1])
    if group is None:
        raise ValueError(f"{name}: no vertex or edge lines (tags: {', '.join(known)})")
    return _assemble(name, group, vertices, edges, fixed, vertex_tags, edge_tags, information)


class _LineError(ValueError):
    """A malformed line; ``line`` lets the parser report the first one in the file."""

    def __init__(self, line: int, message: str) -> None:
        super().__init__(message)
        self.line = int(line)


def _block(name: str, tag: str, rests: list[str], lines: list[int], n_ids: int,
           n_num: int) -> tuple[np.ndarray, np.ndarray]:
    """Ids ``(n, n_ids)`` (int64, exact) and numbers ``(n, n_num)`` of the lines of one tag.

    Every line's field count is checked (a line with a field too many next to one with a
    field too few must not shift numbers from one to the other). Plain ASCII lines with ids
    below ``2**53`` are converted in bulk (:func:`~microlie._textfile.numbers_by_line`); the
    others with Python's ``int`` and ``float`` rules on plain ASCII lines, line by line where a
    line fails, which names the first bad line.
    """
    k = n_ids + n_num
    joined = "\n".join(rests)
    if joined.isascii():  # plain numbers, ids below 2**53: converted in bulk
        data = joined.encode("ascii")
        parse = text_parser()  # the compiled reader (float()'s values), 2-4x numpy.fromstring
        a = parse(data, k, False, False) if parse is not None else None
        if a is not None and a.shape[0] == len(rests) and (a[:, :n_ids] < 2**53).all() and all(
                t.isdigit() for r in rests for t in r.split(None, n_ids)[:n_ids]):
            return a[:, :n_ids].astype(np.int64), a[:, n_ids:]
        bulk = numbers_by_line(data)
        if bulk is not None and bulk[2].size == len(rests) and (bulk[2] == k).all():
            a, starts = bulk[0].reshape(-1, k), bulk[1].reshape(-1, k)
            if np.isfinite(a).all() and digits_only(data, starts[:, :n_ids].reshape(-1),
                                                    a[:, :n_ids].reshape(-1)):
                return a[:, :n_ids].astype(np.int64), a[:, n_ids:]
    for rest, ln in zip(rests, lines, strict=True):
        why = plain_error(rest)
        if why is not None:
            raise _LineError(ln, f"{name}:{ln}: {tag}: {why}")
    fields = [r.split() for r in rests]
    counts = np.fromiter(map(len, fields), dtype=np.intp, count=len(fields))
    bad = np.flatnonzero(counts != k)
    if bad.size:
        r = int(bad[0])
        _check_line(name, tag, fields[r], lines[r], n_ids, n_num)  # raises
    try:
        ids = np.array([f[:n_ids] for f in fields], dtype=np.int64).reshape(-1, n_ids)
        vals = np.array([f[n_ids:] for f in fields], dtype=np.float64).reshape(-1, n_num)
    except (ValueError, OverflowError):
        rows = [_check_line(name, tag, f, ln, n_ids, n_num)
                for f, ln in zip(fields, lines, strict=True)]
        ids = np.array([r[0] for r in rows], dtype=np.int64).reshape(-1, n_ids)
        vals = np.array([r[1] for r in rows], dtype=np.float64).reshape(-1, n_num)
    bad = np.flatnonzero(~np.isfinite(vals).all(axis=1) | (ids < 0).any(axis=1))
    if bad.size:
        r = int(bad[0])
        _check_line(name, tag, fields[r], lines[r], n_ids, n_num)  # raises
    return ids, vals


_ID_MAX = 2**63 - 1


def _check_line(name: str, tag: str, fields: list[str], lineno: int, n_ids: int,
                n_num: int) -> tuple[list[int], list[float]]:
    """The ids and numbers of one line, or the error that names what is wrong with it."""
    where = f"{name}:{lineno}"
    if len(fields) != n_ids + n_num:
        raise _LineError(lineno, f"{where}: {tag} needs {n_ids + n_num} fields "
                         f"({n_ids} id{'s' * (n_ids > 1)} and {n_num} numbers), "
                         f"got {len(fields)}")
    return (_ints(fields[:n_ids], where, tag, line=lineno),
            _floats(fields[n_ids:], where, tag, line=lineno))


def _ints(fields: Sequence[str], where: str, tag: str, at_least_one: bool = False,
          line: int = 0) -> list[int]:
    """Vertex ids: integers in ``0 .. 2**63 - 1`` (GTSAM ``Symbol`` keys fit), exact."""
    if at_least_one and not fields:
        raise _LineError(line, f"{where}: {tag} needs at least one vertex id")
    out = []
    for f in fields:
        try:
            v = int(f)
        except ValueError:
            raise _LineError(line, f"{where}: {tag}: vertex id {f!r} is not an "
                             "integer") from None
        if v < 0:
            raise _LineError(line, f"{where}: {tag}: negative vertex id {v}")
        if v > _ID_MAX:
            raise _LineError(line, f"{where}: {tag}: vertex id {v} is larger than "
                             f"2**63 - 1 = {_ID_MAX}")
        out.append(v)
    return out


def _floats(fields: Sequence[str], where: str, tag: str, line: int = 0) -> list[float]:
    try:
        out = [float(f) for f in fields]
    except ValueError:
        bad = next(f for f in fields if not _is_float(f))
        raise _LineError(line, f"{where}: {tag}: field {bad!r} is not a number") from None
    if not all(math.isfinite(v) for v in out):
        bad = next(f for f, v in zip(fields, out, strict=True) if not math.isfinite(v))
        raise _LineError(line, f"{where}: {tag}: non-finite value {bad!r}")
    return out


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _assemble(name: str, group: type[LieGroup], vertices: _Lines, edges: _Lines,
              fixed: _Lines, vertex_tags: dict[str, VertexTag],
              edge_tags: dict[str, EdgeTag], information: str) -> PoseGraph:
    vspec = next((s for s in vertex_tags.values() if s.group is group), None)
    espec = next((s for s in edge_tags.values() if s.group is group), None)
    if espec is None:
        raise ValueError(f"{name}: no edge tag for {group.__name__}")
    # vertices: unique ids, sorted
    poses = None
    if vertices.lines.size:
        vid = vertices.ids[:, 0]
        order = np.argsort(vid, kind="stable")
        dup = np.flatnonzero(np.diff(vid[order]) == 0)
        if dup.size:
            k = order[dup[0] + 1]
            first = vertices.lines[order[dup[0]]]
            raise ValueError(f"{name}:{vertices.lines[k]}: vertex {vid[k]} is defined twice "
                             f"(first on line {first})")
        assert vspec is not None
        vals = vertices.values[order]
        vlines = vertices.lines[order]
        params = _checked_params(vspec.to_params, vals, name, vlines, "vertex")
        poses = group(params)
        ids = vid[order]
    if not edges.lines.size:
        raise ValueError(f"{name}: no edges")
    ij = edges.ids
    elines = edges.lines
    self_loop = np.flatnonzero(ij[:, 0] == ij[:, 1])
    if self_loop.size:
        k = self_loop[0]
        raise ValueError(f"{name}:{elines[k]}: edge from vertex {ij[k, 0]} to itself")
    if poses is None:
        ids = np.unique(ij)
    else:
        for col in (0, 1):
            bad = np.flatnonzero(~np.isin(ij[:, col], ids))
            if bad.size:
                k = bad[0]
                raise ValueError(f"{name}:{elines[k]}: edge {ij[k, 0]} -> {ij[k, 1]} refers to "
                                 f"vertex {ij[k, col]}, which has no vertex line")
    vals = edges.values
    Z = group(_checked_params(espec.to_params, vals[:, :espec.n], name, elines, "measurement"))
    info, repaired = apply_information_policy(espec.to_information(vals[:, espec.n:]),
                                              information, group.point_dim, name=name,
                                              lines=elines)
    fix = np.asarray(fixed.ids, dtype=np.int64).reshape(-1)
    flines = fixed.lines
    unknown = np.flatnonzero(~np.isin(fix, ids))
    if unknown.size:
        k = unknown[0]
        raise ValueError(f"{name}:{flines[k]}: FIX names vertex {fix[k]}, which is not in "
                         "the graph")
    return PoseGraph(group, ids=ids, poses=poses, i=ij[:, 0], j=ij[:, 1], measurements=Z,
                     information=info, fixed=np.unique(fix), repaired=repaired)


def _checked_params(to_params: Callable[[np.ndarray], np.ndarray], vals: np.ndarray,
                    name: str, lines: np.ndarray, what: str) -> np.ndarray:
    try:
        return to_params(vals)
    except _BadRow as e:
        raise ValueError(f"{name}:{lines[e.row]}: {what}: {e.message}") from None


class _BadRow(Exception):
    """Raised by a ``to_params`` converter for a row it refuses (for example a zero
    quaternion); the parser turns it into a ``ValueError`` with FILE:LINE."""

    def __init__(self, row: int, message: str) -> None:
        super().__init__(message)
        self.row = int(row)
        self.message = message


def unit_quaternions(q: np.ndarray) -> np.ndarray:
    """Normalise ``(N, 4)`` quaternions printed with rounding; a norm off by more than 1 %
    is refused (``_BadRow``) rather than silently repaired."""
    n = np.linalg.norm(q, axis=-1)
    bad = np.flatnonzero(np.abs(n - 1.0) > 1e-2)
    if bad.size:
        k = bad[0]
        raise _BadRow(k, f"quaternion {q[k].tolist()} has norm {n[k]:.6g}, not 1")
    return q / n[:, None]
