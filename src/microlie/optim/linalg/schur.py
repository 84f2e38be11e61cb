"""Schur-complement solution of the damped bundle-adjustment normal equations.

The linearised problem ``min |J_c dc + J_p dp + r|^2 + |D_c dc|^2 + |D_p dp|^2`` (camera blocks
``c``, point blocks ``p``, every observation touching one camera and one point) is solved by
eliminating the points: with ``V_j = sum_a J_pa^T J_pa + D_pj^2`` (3x3 per point, block diagonal)
and ``W_a = J_ca^T J_pa``, the reduced camera system is

    S dc = -(g_c - sum_a W_a V^-1 g_p),   S = U + D_c^2 - sum_{a,b same point} W_a V^-1 W_b^T

and then ``dp = -V^-1 (g_p + sum_a W_a^T dc)``. The formation uses the rank-2 structure of every
observation: ``W_a V^-1 W_b^T = J_ca^T q_ab J_cb`` with the 2x2 ``q_ab = G_a G_b^T``,
``G_a = J_pa C_j^-T`` (``C_j`` the Cholesky factor of ``V_j``). The pairs of observations that
share a point are sorted by camera pair once (:class:`SchurStructure`), so each camera-pair block
is one matrix product over contiguous memory instead of a scatter (``np.add.at``).

With the compiled extra (``microlie._c._schur``, unless ``MICROLIE_FAST=0``) the dense reduced
system is formed in one compiled pass over the points (the same products, summed per point); the
NumPy formation below stays the reference, the fallback and the sparse path.

``S`` is factorised densely (LAPACK Cholesky) or, for many cameras, sparsely; ``"full"`` solves
the whole damped system with a sparse factorisation instead (the points then are eliminated by the
backend's ordering), which exists to compare against and to test the elimination with.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.linalg as sla  # type: ignore[import-untyped]
import scipy.sparse as sp  # type: ignore[import-untyped]

from ..._fast import compiled as compiled_module

__all__ = ["SchurStructure", "NormalEquations", "LinearSolverKind", "LINEAR_SOLVERS"]

LinearSolverKind = Literal["auto", "dense", "sparse", "full"]
LINEAR_SOLVERS: tuple[str, ...] = ("auto", "dense", "sparse", "full")
DENSE_LIMIT = 3000  # camera unknowns up to which the reduced system is factorised densely
SPARSE_DENSITY = 0.05  # above it (fraction of nonzero camera blocks) dense up to DENSE_MAX
DENSE_MAX = 12000
_PAIR_CHUNK = 1 << 17  # observation pairs gathered at once when forming the reduced system


_fast_module: Any = None


def _fast() -> Any:
    """``microlie._c._schur``, or ``None`` (not installed, an older build, or
    ``MICROLIE_FAST=0``); ``_fast_module`` set to a module or ``False`` forces a path."""
    if _fast_module is not None:
        return _fast_module or None
    return compiled_module("_schur")


class SchurStructure:
    """The sparsity of a bundle-adjustment problem, analysed once.

    The observations must be sorted by camera, then point (``np.lexsort((pt, cam))`` order),
    which the solver does once: each camera's observations are then one contiguous block.

    Parameters
    ----------
    cam, pt : numpy.ndarray
        ``(n_obs,)`` the camera and point of each observation.
    n_cameras, n_points : int
        The sizes.
    cam_dim : int
        Unknowns per camera (``6 + k``).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
    >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
    >>> s = SchurStructure(cam, pt, 2, 3, 9)
    >>> s.sparse_reduced()  # 18 camera unknowns: dense
    False
    """

    def __init__(self, cam: np.ndarray, pt: np.ndarray, n_cameras: int, n_points: int,
                 cam_dim: int) -> None:
        cam = np.asarray(cam, dtype=np.intp)
        pt = np.asarray(pt, dtype=np.intp)
        if np.any(np.diff(cam) < 0):
            raise ValueError("observations must be sorted by camera")
        self.cam, self.pt = cam, pt
        self.n_cameras, self.n_points, self.cam_dim = n_cameras, n_points, cam_dim
        self.n_obs = len(cam)
        counts = np.bincount(pt, minlength=n_points)
        self.point_count = counts
        ccount = np.bincount(cam, minlength=n_cameras)
        self.cam_bounds = np.concatenate([[0], np.cumsum(ccount)]).astype(np.intp)
        # pairs a < b of observations of the same point, with cam[a] <= cam[b]: enumerate them
        # in point order (a stable sort keeps the camera order within each point)
        by_pt = np.argsort(pt, kind="stable")
        point_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
        # the observations of each point, in camera order (CSR), for the compiled formation
        self.point_obs = by_pt.astype(np.intp)
        self.point_ptr = np.concatenate([point_start, [self.n_obs]]).astype(np.intp)
        a_list, b_list = [], []
        for m in np.unique(counts):
            if m < 2:
                continue
            base = point_start[counts == m]
            ia, ib = np.triu_indices(m, 1)
            a_list.append(by_pt[(base[:, None] + ia[None]).ravel()])
            b_list.append(by_pt[(base[:, None] + ib[None]).ravel()])
        a = np.concatenate(a_list) if a_list else np.zeros(0, np.intp)
        b = np.concatenate(b_list) if b_list else np.zeros(0, np.intp)
        swap = cam[a] > cam[b]
        a, b = np.where(swap, b, a), np.where(swap, a, b)
        key = cam[a] * n_cameras + cam[b]
        order = np.argsort(key, kind="stable")
        self.pair_a, self.pair_b, key = a[order], b[order], key[order]
        ukey, start = np.unique(key, return_index=True)
        self.pair_blocks = (ukey // n_cameras, ukey % n_cameras)
        self.pair_bounds = np.concatenate([start, [len(key)]]).astype(np.intp)
        # chunks of whole camera-pair blocks with at most _PAIR_CHUNK pairs (or one block)
        chunks, i0 = [], 0
        nb = len(ukey)
        while i0 < nb:
            i1 = int(np.searchsorted(self.pair_bounds, self.pair_bounds[i0] + _PAIR_CHUNK,
                                     side="right")) - 1
            i1 = min(max(i1, i0 + 1), nb)
            chunks.append((i0, i1))
            i0 = i1
        self.pair_chunks = chunks
        self.block_density = (2 * len(ukey) + n_cameras) / max(n_cameras, 1) ** 2

    def sparse_reduced(self, kind: str = "auto") -> bool:
        """Whether ``kind`` factorises the reduced camera system sparsely: ``"auto"`` does when it
        has more than ``DENSE_LIMIT`` unknowns and is sparse (fewer than ``SPARSE_DENSITY`` of its
        blocks nonzero), or more than ``DENSE_MAX`` unknowns.

        Parameters
        ----------
        kind : {"auto", "dense", "sparse", "full"}
            The linear solver kind.

        Returns
        -------
        bool

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> s.sparse_reduced("auto"), s.sparse_reduced("sparse")
        (False, True)
        """
        if kind != "auto":
            return kind == "sparse"
        n = self.n_cameras * self.cam_dim
        return n > DENSE_MAX or (n > DENSE_LIMIT and self.block_density < SPARSE_DENSITY)

    def buffer(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        """A scratch array kept between iterations (fresh large arrays cost page faults that
        measured as much as the arithmetic on them).

        Parameters
        ----------
        name : str
            The buffer's key.
        shape : tuple of int
            Its shape (a new array when it changes).

        Returns
        -------
        numpy.ndarray
            Uninitialised contents.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> b = s.buffer("tmp", (2, 3))
        >>> s.buffer("tmp", (2, 3)) is b
        True
        """
        ws = self.__dict__.setdefault("_workspace", {})
        a = ws.get(name)
        if a is None or a.shape != shape:
            a = ws[name] = np.empty(shape)
        return a

    def point_sum(self, v: np.ndarray) -> np.ndarray:
        """Per-point sums of per-observation rows.

        Parameters
        ----------
        v : numpy.ndarray
            ``(n_obs, k)``.

        Returns
        -------
        numpy.ndarray
            ``(n_points, k)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> s.point_sum(np.ones((6, 2))).tolist()  # every point is seen twice
        [[2.0, 2.0], [2.0, 2.0], [2.0, 2.0]]
        """
        out = np.empty((self.n_points, v.shape[1]))
        for k in range(v.shape[1]):
            out[:, k] = np.bincount(self.pt, weights=v[:, k], minlength=self.n_points)
        return out

    def camera_jacobian_csr(self, Jc: np.ndarray) -> sp.csr_matrix:
        """The camera Jacobian as a sparse matrix (two rows per observation).

        Parameters
        ----------
        Jc : numpy.ndarray
            ``(n_obs, 2, d)``.

        Returns
        -------
        scipy.sparse.csr_matrix
            ``(2 n_obs, n_cameras d)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> s.camera_jacobian_csr(np.ones((6, 2, 9))).shape
        (12, 18)
        """
        n, d = self.n_obs, self.cam_dim
        cols = self.cam[:, None] * d + np.arange(d)[None, :]
        indices = np.repeat(cols, 2, axis=0).ravel()
        indptr = np.arange(0, 2 * n * d + 1, d)
        return sp.csr_matrix((Jc.reshape(-1), indices, indptr), shape=(2 * n, self.n_cameras * d))


def _chol3_inv(v: np.ndarray) -> tuple[np.ndarray, ...]:
    """Inverse ``Ci`` of the lower Cholesky factor of symmetric 3x3 matrices given as the six
    components ``(v00, v01, v02, v11, v12, v22)`` (each ``(n,)``); NaN where not positive."""
    v00, v01, v02, v11, v12, v22 = v
    with np.errstate(invalid="ignore", divide="ignore"):
        c00 = np.sqrt(v00)
        c10 = v01 / c00
        c20 = v02 / c00
        c11 = np.sqrt(v11 - c10 * c10)
        c21 = (v12 - c20 * c10) / c11
        c22 = np.sqrt(v22 - c20 * c20 - c21 * c21)
        i00, i11, i22 = 1.0 / c00, 1.0 / c11, 1.0 / c22
        i10 = -c10 * i00 * i11
        i21 = -c21 * i11 * i22
        i20 = -(c20 * i00 + c21 * i10) * i22
    return i00, i10, i11, i20, i21, i22


@dataclass
class NormalEquations:
    """One linearisation of a bundle-adjustment problem: residuals and Jacobians of the
    observations (sorted by camera, already weighted and scaled).

    Parameters
    ----------
    structure : SchurStructure
        The analysed sparsity.
    r : numpy.ndarray
        ``(n, 2)`` residuals.
    Jc : numpy.ndarray
        ``(n, 2, d)`` camera Jacobians.
    Jp : numpy.ndarray
        ``(n, 2, 3)`` point Jacobians.
    fixed_cameras : numpy.ndarray, optional
        ``(n_cameras, d)`` mask of held camera unknowns (a camera's pose, its intrinsics or
        both); held unknowns get a zero step.
    fixed_points : numpy.ndarray, optional
        ``(n_points,)`` mask of held points.
    timings : dict
        Accumulates the time of the parts.
    full_backend : str
        The sparse solver of the ``"full"`` kind.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
    >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
    >>> s = SchurStructure(cam, pt, 2, 3, 9)
    >>> rng = np.random.default_rng(0)
    >>> r, Jc = rng.normal(size=(6, 2)), rng.normal(size=(6, 2, 9))
    >>> Jp = rng.normal(size=(6, 2, 3))
    >>> ne = NormalEquations(s, r, Jc, Jp)
    >>> Dc2, Dp2 = np.ones((2, 9)), np.ones((3, 3))  # unit damping
    >>> J = np.zeros((12, 27))  # the dense Jacobian, to check against
    >>> for k in range(6):
    ...     J[2 * k:2 * k + 2, 9 * cam[k]:9 * cam[k] + 9] = Jc[k]
    ...     J[2 * k:2 * k + 2, 18 + 3 * pt[k]:21 + 3 * pt[k]] = Jp[k]
    >>> H = ne.full_matrix(Dc2, Dp2).toarray()
    >>> bool(np.allclose(H, J.T @ J + np.eye(27)))
    True
    """

    structure: SchurStructure
    r: np.ndarray
    Jc: np.ndarray
    Jp: np.ndarray
    fixed_cameras: np.ndarray | None = None
    fixed_points: np.ndarray | None = None
    timings: dict[str, float] = field(default_factory=dict)
    full_backend: str = "auto"      # sparse Cholesky of the full system (``kind="full"``)

    def __post_init__(self) -> None:
        st, Jc, Jp, r = self.structure, self.Jc, self.Jp, self.r
        d = st.cam_dim
        # held variables: their columns are removed (zeroed here, unit diagonal in the solve)
        if self.fixed_cameras is not None and self.fixed_cameras.any():
            Jc = self.Jc = np.where(self.fixed_cameras[st.cam][:, None, :], 0.0, Jc)
        if self.fixed_points is not None and self.fixed_points.any():
            Jp = self.Jp = np.where(self.fixed_points[st.pt][:, None, None], 0.0, Jp)
        # point blocks V (6 components), gradients, diagonals
        JpT = np.ascontiguousarray(Jp.transpose(1, 2, 0))        # (2, 3, n)
        self._jp = JpT
        fast = _fast()
        if fast is not None:
            self.V, self.gp, self.U, self.gc = fast.blocks(
                np.ascontiguousarray(Jc), np.ascontiguousarray(Jp), np.ascontiguousarray(r),
                st.cam, st.pt, st.n_cameras, st.n_points)
            self._diagonals()
            return
        prods = np.stack([(JpT[:, 0] * JpT[:, 0]).sum(0), (JpT[:, 0] * JpT[:, 1]).sum(0),
                          (JpT[:, 0] * JpT[:, 2]).sum(0), (JpT[:, 1] * JpT[:, 1]).sum(0),
                          (JpT[:, 1] * JpT[:, 2]).sum(0), (JpT[:, 2] * JpT[:, 2]).sum(0)], 1)
        gp_obs = np.einsum("rin,nr->ni", JpT, r)
        V = st.point_sum(prods)
        gp = st.point_sum(gp_obs)
        self.V, self.gp = V, gp
        # camera side (observations are sorted by camera): U_c = Jc^T Jc, g_c = Jc^T r
        Jcc = Jc.reshape(-1, d)                                      # (2n, d)
        rc = r.reshape(-1)
        b = st.cam_bounds
        nc = st.n_cameras
        self.U = np.zeros((nc, d, d))
        self.gc = np.zeros((nc, d))
        for c in range(nc):
            s, e = 2 * b[c], 2 * b[c + 1]
            blk = Jcc[s:e]
            self.U[c] = blk.T @ blk
            self.gc[c] = blk.T @ rc[s:e]
        self._diagonals()

    def _diagonals(self) -> None:
        self.diag_c = np.diagonal(self.U, axis1=1, axis2=2).copy()
        self.diag_p = self.V[:, [0, 3, 5]].copy()
        self.gradient = np.concatenate([self.gc.ravel(), self.gp.ravel()])

    # ------------------------------------------------------------------ products with J
    def jvp(self, dc: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """``J_c dc + J_p dp``.

        Parameters
        ----------
        dc : numpy.ndarray
            ``(n_cameras, d)`` camera step.
        dp : numpy.ndarray
            ``(n_points, 3)`` point step.

        Returns
        -------
        numpy.ndarray
            ``(n, 2)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> rng = np.random.default_rng(0)
        >>> r, Jc = rng.normal(size=(6, 2)), rng.normal(size=(6, 2, 9))
        >>> Jp = rng.normal(size=(6, 2, 3))
        >>> ne = NormalEquations(s, r, Jc, Jp)
        >>> Dc2, Dp2 = np.ones((2, 9)), np.ones((3, 3))  # unit damping
        >>> J = np.zeros((12, 27))  # the dense Jacobian, to check against
        >>> for k in range(6):
        ...     J[2 * k:2 * k + 2, 9 * cam[k]:9 * cam[k] + 9] = Jc[k]
        ...     J[2 * k:2 * k + 2, 18 + 3 * pt[k]:21 + 3 * pt[k]] = Jp[k]
        >>> dc, dp = np.ones((2, 9)), np.ones((3, 3))
        >>> bool(np.allclose(ne.jvp(dc, dp).ravel(), J @ np.ones(27)))
        True
        """
        st = self.structure
        cached = getattr(self, "_jc_dc", None)
        if cached is not None and cached[0] is dc:
            out = cached[1].copy()                     # J_c dc from the back substitution
        else:
            out = np.matmul(self.Jc, np.take(dc, st.cam, axis=0)[:, :, None])[:, :, 0]
        out += np.einsum("rin,ni->nr", self._jp, np.take(dp, st.pt, axis=0))
        return out

    # ------------------------------------------------------------------ the damped solve
    def solve(self, Dc2: np.ndarray, Dp2: np.ndarray, kind: LinearSolverKind = "auto"
              ) -> tuple[np.ndarray, np.ndarray] | None:
        """Solve ``(J^T J + diag(D^2)) delta = -J^T r`` by the Schur complement of the points.

        Parameters
        ----------
        Dc2 : numpy.ndarray
            ``(n_cameras, d)`` squared damping diagonal of the cameras.
        Dp2 : numpy.ndarray
            ``(n_points, 3)`` squared damping diagonal of the points.
        kind : {"auto", "dense", "sparse", "full"}
            How: the reduced camera system dense or sparse, or the full system.

        Returns
        -------
        tuple of numpy.ndarray or None
            ``(dc, dp)``, or ``None`` when the system is not positive definite.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> rng = np.random.default_rng(0)
        >>> r, Jc = rng.normal(size=(6, 2)), rng.normal(size=(6, 2, 9))
        >>> Jp = rng.normal(size=(6, 2, 3))
        >>> ne = NormalEquations(s, r, Jc, Jp)
        >>> Dc2, Dp2 = np.ones((2, 9)), np.ones((3, 3))  # unit damping
        >>> J = np.zeros((12, 27))  # the dense Jacobian, to check against
        >>> for k in range(6):
        ...     J[2 * k:2 * k + 2, 9 * cam[k]:9 * cam[k] + 9] = Jc[k]
        ...     J[2 * k:2 * k + 2, 18 + 3 * pt[k]:21 + 3 * pt[k]] = Jp[k]
        >>> dc, dp = ne.solve(Dc2, Dp2)
        >>> x = np.linalg.solve(J.T @ J + np.eye(27), -J.T @ r.ravel())
        >>> bool(np.allclose(np.r_[dc.ravel(), dp.ravel()], x))
        True
        """
        if kind not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, got {kind!r}")
        if kind == "full":
            return self._solve_full(Dc2, Dp2)
        t0 = time.perf_counter()
        red = self.reduced_system(Dc2, Dp2, self.structure.sparse_reduced(kind))
        if red is None:
            return None
        S, rhs_v, (i00, i10, i11, i20, i21, i22), gp = red
        st, d, nc = self.structure, self.structure.cam_dim, self.structure.n_cameras
        fp = self.fixed_points
        jp = self._jp
        t1 = time.perf_counter()
        dc = self._solve_reduced(S, rhs_v)
        if dc is None:
            return None
        t2 = time.perf_counter()
        # back substitution: dp = -V^-1 (gp + Jp^T Jc dc)
        dc = dc.reshape(nc, d)
        fast = _fast()
        if fast is not None:
            held = np.zeros(st.n_points, bool) if fp is None else np.ascontiguousarray(fp, bool)
            dp, y = fast.back(np.ascontiguousarray(self.Jc), np.ascontiguousarray(self.Jp),
                              np.ascontiguousarray(dc), st.cam, st.pt, np.ascontiguousarray(gp),
                              np.ascontiguousarray(np.stack([i00, i10, i11, i20, i21, i22])),
                              held)
            self._jc_dc = (dc, y)
            return self._timed(t0, t1, t2, dc, dp)
        y = np.matmul(self.Jc, np.take(dc, st.cam, axis=0)[:, :, None])[:, :, 0]
        self._jc_dc = (dc, y)
        z = np.einsum("rin,nr->ni", jp, y)
        w = gp + st.point_sum(z)
        if fp is not None and fp.any():
            w[fp] = 0.0
        w0, w1, w2 = w[:, 0], w[:, 1], w[:, 2]
        u0 = i00 * w0
        u1 = i10 * w0 + i11 * w1
        u2 = i20 * w0 + i21 * w1 + i22 * w2
        dp = -np.stack([i00 * u0 + i10 * u1 + i20 * u2, i11 * u1 + i21 * u2, i22 * u2], 1)
        return self._timed(t0, t1, t2, dc, dp)

    def _timed(self, t0: float, t1: float, t2: float, dc: np.ndarray, dp: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        t3 = time.perf_counter()
        tm = self.timings
        tm["schur_form"] = tm.get("schur_form", 0.0) + t1 - t0
        tm["reduced_solve"] = tm.get("reduced_solve", 0.0) + t2 - t1
        tm["back_substitution"] = tm.get("back_substitution", 0.0) + t3 - t2
        return dc, dp

    def reduced_system(self, Dc2: np.ndarray, Dp2: np.ndarray, sparse: bool = False
                       ) -> tuple | None:
        """The reduced camera system ``S dc = rhs`` (held unknowns replaced by unit rows), with the
        points' inverse Cholesky factors and gradient.

        Parameters
        ----------
        Dc2 : numpy.ndarray
            ``(n_cameras, d)`` squared damping diagonal of the cameras.
        Dp2 : numpy.ndarray
            ``(n_points, 3)`` squared damping diagonal of the points.
        sparse : bool
            Return ``S`` as sparse CSC instead of dense.

        Returns
        -------
        tuple or None
            ``(S, rhs, ...)``; ``None`` when a point block is not positive definite.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> rng = np.random.default_rng(0)
        >>> r, Jc = rng.normal(size=(6, 2)), rng.normal(size=(6, 2, 9))
        >>> Jp = rng.normal(size=(6, 2, 3))
        >>> ne = NormalEquations(s, r, Jc, Jp)
        >>> Dc2, Dp2 = np.ones((2, 9)), np.ones((3, 3))  # unit damping
        >>> J = np.zeros((12, 27))  # the dense Jacobian, to check against
        >>> for k in range(6):
        ...     J[2 * k:2 * k + 2, 9 * cam[k]:9 * cam[k] + 9] = Jc[k]
        ...     J[2 * k:2 * k + 2, 18 + 3 * pt[k]:21 + 3 * pt[k]] = Jp[k]
        >>> S, rhs = ne.reduced_system(Dc2, Dp2)[:2]
        >>> dc = ne.solve(Dc2, Dp2)[0]
        >>> bool(np.allclose(np.linalg.solve(S, rhs), dc.ravel()))
        True
        """
        st, d = self.structure, self.structure.cam_dim
        V = self.V.copy()
        V[:, 0] += Dp2[:, 0]
        V[:, 3] += Dp2[:, 1]
        V[:, 5] += Dp2[:, 2]
        fp = self.fixed_points
        gp = self.gp
        if fp is not None and fp.any():
            V[fp] = (1.0, 0.0, 0.0, 1.0, 0.0, 1.0)
            gp = gp.copy()
            gp[fp] = 0.0
        fc = self.fixed_cameras
        held = np.nonzero(fc.reshape(-1))[0] if fc is not None and fc.any() else None
        fast = None if sparse else _fast()
        if fast is not None:
            out = fast.reduce(np.ascontiguousarray(self.Jc), np.ascontiguousarray(self.Jp),
                              np.ascontiguousarray(V), np.ascontiguousarray(gp), self.U,
                              self.gc, st.cam, st.point_ptr, st.point_obs)
            if out is None:
                return None
            S, rhs_v, ci = out
            S[np.diag_indices_from(S)] += Dc2.reshape(-1)
            if held is not None:
                rhs_v[held] = 0.0
                S[held, :] = 0.0
                S[:, held] = 0.0
                S[held, held] = 1.0
            return S, rhs_v, tuple(ci), gp
        i00, i10, i11, i20, i21, i22 = _chol3_inv(V.T)
        if not np.all(np.isfinite(i22)):
            return None
        pt = st.pt
        # G_a = Jp_a Ci^T (2 x 3), Ci the inverse Cholesky factor of the point's damped V
        CiT = np.zeros((st.n_points, 3, 3))
        CiT[:, 0, 0], CiT[:, 0, 1], CiT[:, 0, 2] = i00, i10, i20
        CiT[:, 1, 1], CiT[:, 1, 2], CiT[:, 2, 2] = i11, i21, i22
        Gt = np.matmul(self.Jp, np.take(CiT, pt, axis=0))                       # (n, 2, 3)
        # Z_a^T = G_a^T Jc_a (3 x d per observation): W_a V^-1 W_b^T = Z_a Z_b^T
        Zt = np.matmul(Gt.transpose(0, 2, 1), self.Jc,
                       out=st.buffer("Zt", (st.n_obs, 3, d)))                   # (n, 3, d)
        # h = Ci gp per point: W_a V^-1 gp = Z_a h_a
        g0, g1, g2 = gp[:, 0], gp[:, 1], gp[:, 2]
        h = np.stack([i00 * g0, i10 * g0 + i11 * g1, i20 * g0 + i21 * g1 + i22 * g2], 1)
        nc = st.n_cameras
        rhs = -self.gc.copy()
        Zc = Zt.reshape(-1, d)                                       # (3n, d) by camera
        hc = np.take(h, st.pt, axis=0).reshape(-1)
        b = st.cam_bounds
        diag = np.empty((nc, d, d))
        for c in range(nc):
            s, e = 3 * b[c], 3 * b[c + 1]
            blk = Zc[s:e]
            diag[c] = self.U[c] - blk.T @ blk
            rhs[c] += blk.T @ hc[s:e]
        # pairs a < b of observations of one point, grouped by camera pair; gathered in chunks
        # of camera pairs so that memory stays bounded on large problems
        c1s, c2s = st.pair_blocks
        blocks = np.empty((len(c1s), d, d))
        pb = st.pair_bounds
        for i0, i1 in st.pair_chunks:
            p0, p1 = pb[i0], pb[i1]
            shape = (int(p1 - p0), 3, d)
            # np.take into kept buffers (mode="clip": indices are valid by construction, and
            # "raise" with out= would copy)
            Za = np.take(Zt, st.pair_a[p0:p1], axis=0, out=st.buffer(f"Za{i0}", shape),
                         mode="clip").reshape(-1, d)
            Zb = np.take(Zt, st.pair_b[p0:p1], axis=0, out=st.buffer(f"Zb{i0}", shape),
                         mode="clip").reshape(-1, d)
            for i in range(i0, i1):
                s, e = 3 * (pb[i] - p0), 3 * (pb[i + 1] - p0)
                np.matmul(Za[s:e].T, Zb[s:e], out=blocks[i])
        rhs_v = rhs.reshape(-1)
        if held is not None:
            rhs_v[held] = 0.0
        n = nc * d
        if not sparse:
            Sb = np.zeros((nc, nc, d, d))
            Sb[np.arange(nc), np.arange(nc)] = diag
            # (c1, c2) keys are unique with c1 <= c2, so neither statement repeats an index;
            # for c1 == c2 (a point seen twice by one camera) both add to the diagonal block
            Sb[c1s, c2s] -= blocks
            Sb[c2s, c1s] -= blocks.transpose(0, 2, 1)
            S = Sb.transpose(0, 2, 1, 3).reshape(n, n)
            S[np.diag_indices_from(S)] += Dc2.reshape(-1)
            if held is not None:
                S[held, :] = 0.0
                S[:, held] = 0.0
                S[held, held] = 1.0
            return S, rhs_v, (i00, i10, i11, i20, i21, i22), gp
        # sparse assembly: diagonal blocks, pair blocks and their transposes (COO, summed)
        ii, jj = np.meshgrid(np.arange(d), np.arange(d), indexing="ij")
        cams = np.arange(nc)
        rows = [(cams[:, None, None] * d + ii).ravel(), (c1s[:, None, None] * d + ii).ravel(),
                (c2s[:, None, None] * d + ii).ravel()]
        cols = [(cams[:, None, None] * d + jj).ravel(), (c2s[:, None, None] * d + jj).ravel(),
                (c1s[:, None, None] * d + jj).ravel()]
        vals = [diag.ravel(), -blocks.ravel(), -blocks.transpose(0, 2, 1).ravel()]
        r_ = np.concatenate(rows)
        c_ = np.concatenate(cols)
        v_ = np.concatenate(vals)
        if held is not None:
            mask = np.zeros(n, bool)
            mask[held] = True
            v_ = np.where(mask[r_] | mask[c_], 0.0, v_)
        dvals = Dc2.reshape(-1).copy()
        if held is not None:
            dvals[held] = 1.0
        r_ = np.concatenate([r_, np.arange(n)])
        c_ = np.concatenate([c_, np.arange(n)])
        v_ = np.concatenate([v_, dvals])
        Ssp = sp.csc_matrix((v_, (r_, c_)), shape=(n, n))
        Ssp.sum_duplicates()
        Ssp.sort_indices()
        return Ssp, rhs_v, (i00, i10, i11, i20, i21, i22), gp

    @staticmethod
    def _solve_reduced(S: Any, rhs: np.ndarray) -> np.ndarray | None:
        if sp.issparse(S):
            from .linear import SingularSystemError, make_solver

            solver = make_solver("auto", S.shape[0])
            try:
                solver.analyse(S.indptr, S.indices, S.shape[0])
                solver.factorize(S.data)
                x = solver.solve(rhs)
            except SingularSystemError:
                return None
            return x if np.all(np.isfinite(x)) else None
        try:
            cf = sla.cho_factor(S, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            return None
        x = sla.cho_solve(cf, rhs, check_finite=False)
        return x if np.all(np.isfinite(x)) else None

    # ------------------------------------------------------------------ reference: full system
    def full_matrix(self, Dc2: np.ndarray, Dp2: np.ndarray) -> sp.csc_matrix:
        """The damped normal matrix ``J^T J + diag(D^2)`` over (cameras, points).

        Parameters
        ----------
        Dc2 : numpy.ndarray
            ``(n_cameras, d)`` squared damping diagonal of the cameras.
        Dp2 : numpy.ndarray
            ``(n_points, 3)`` squared damping diagonal of the points.

        Returns
        -------
        scipy.sparse.csc_matrix
            ``(n_cameras d + 3 n_points)`` square.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.linalg.schur import NormalEquations, SchurStructure
        >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)  # 2 cameras see 3 points
        >>> s = SchurStructure(cam, pt, 2, 3, 9)
        >>> rng = np.random.default_rng(0)
        >>> r, Jc = rng.normal(size=(6, 2)), rng.normal(size=(6, 2, 9))
        >>> Jp = rng.normal(size=(6, 2, 3))
        >>> ne = NormalEquations(s, r, Jc, Jp)
        >>> Dc2, Dp2 = np.ones((2, 9)), np.ones((3, 3))  # unit damping
        >>> J = np.zeros((12, 27))  # the dense Jacobian, to check against
        >>> for k in range(6):
        ...     J[2 * k:2 * k + 2, 9 * cam[k]:9 * cam[k] + 9] = Jc[k]
        ...     J[2 * k:2 * k + 2, 18 + 3 * pt[k]:21 + 3 * pt[k]] = Jp[k]
        >>> ne.full_matrix(Dc2, Dp2).shape
        (27, 27)
        """
        st = self.structure
        n, d = st.n_obs, st.cam_dim
        cols_p = st.n_cameras * d + st.pt[:, None] * 3 + np.arange(3)[None, :]
        ip = np.arange(0, 2 * n * 3 + 1, 3)
        Jp_csr = sp.csr_matrix((self.Jp.reshape(-1), np.repeat(cols_p, 2, axis=0).ravel(), ip),
                               shape=(2 * n, st.n_cameras * d + st.n_points * 3))
        jc = st.camera_jacobian_csr(self.Jc)
        Jc_csr = sp.csr_matrix((jc.data, jc.indices, jc.indptr), shape=Jp_csr.shape)
        J = (Jc_csr + Jp_csr).tocsc()
        H = (J.T @ J).tocsc()
        H = H + sp.diags(np.concatenate([Dc2.reshape(-1), Dp2.reshape(-1)]))
        return self._fix(H.tocsc())

    def _fix(self, H: sp.csc_matrix) -> sp.csc_matrix:
        st, d = self.structure, self.structure.cam_dim
        idx = []
        if self.fixed_cameras is not None and self.fixed_cameras.any():
            idx.append(np.nonzero(self.fixed_cameras.reshape(-1))[0])
        if self.fixed_points is not None and self.fixed_points.any():
            idx.append((st.n_cameras * d + np.nonzero(self.fixed_points)[0][:, None] * 3
                        + np.arange(3)).ravel())
        if not idx:
            return H
        fix = np.zeros(H.shape[0], bool)
        fix[np.concatenate(idx)] = True
        keep = sp.diags((~fix).astype(float))
        return (keep @ H @ keep + sp.diags(fix.astype(float))).tocsc()

    def _solve_full(self, Dc2, Dp2):
        from .linear import SingularSystemError, make_solver

        st, d = self.structure, self.structure.cam_dim
        H = self.full_matrix(Dc2, Dp2)
        H.sort_indices()
        g = self.gradient.copy()
        if self.fixed_cameras is not None:
            g[: st.n_cameras * d][self.fixed_cameras.reshape(-1)] = 0.0
        if self.fixed_points is not None:
            g[st.n_cameras * d:].reshape(-1, 3)[self.fixed_points] = 0.0
        # the pattern is the same at every iteration: analyse once per structure
        cache = getattr(st, "_full_solver", None)
        if (cache is None or cache[1].shape != H.indices.shape
                or not np.array_equal(cache[1], H.indices)
                or not np.array_equal(cache[2], H.indptr)):
            solver = make_solver(self.full_backend, H.shape[0])
            solver.analyse(H.indptr, H.indices, H.shape[0])
            cache = (solver, H.indices.copy(), H.indptr.copy())
            st._full_solver = cache
        try:
            cache[0].factorize(H.data)
            x = -cache[0].solve(g)
        except SingularSystemError:
            return None
        if not np.all(np.isfinite(x)):
            return None
        k = st.n_cameras * d
        return x[:k].reshape(st.n_cameras, d), x[k:].reshape(st.n_points, 3)
