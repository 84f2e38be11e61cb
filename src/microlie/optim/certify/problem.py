"""SE-Sync's isotropic objective and its translation-marginalised data matrix ``Q``.

For a pose graph with edges ``i -> j`` (measurement ``Z_ij = (R~_ij, t~_ij)``, ``X_j ~ X_i Z_ij``)
SE-Sync (Rosen, Carlone, Bandeira, Leonard, IJRR 2019) minimises

    F(R, t) = sum_e  kappa_e ||R_j - R_i R~_ij||_F^2 + tau_e ||t_j - t_i - R_i t~_ij||^2

(no 1/2). With ``R = [R_1 ... R_n]`` (``d x dn``) and ``T = [t_1 ... t_n]`` (``d x n``) it is
``tr([T R] M [T R]^T)`` with the sparse

    M = [[L_tau,  V  ],      L_tau : n x n Laplacian of the weights tau,
         [V^T,  L_rho + Sigma]]   L_rho : dn x dn connection Laplacian (blocks kappa I on the
                                  diagonal, -kappa R~_ij at (i, j)), Sigma : block diagonal
                                  sum_{e out of i} tau t~ t~^T, V : n x dn with
                                  V[i, block i] += tau t~^T, V[j, block i] -= tau t~^T.

Minimising over ``T`` leaves ``F = tr(R Q R^T)`` with the Schur complement
``Q = L_rho + Sigma - V^T L_tau^+ V`` (dense in general); it is applied here through one
sparse Cholesky factorisation of ``L_tau`` with the anchor's row and column removed (the
optimal translations are ``T^T = -L_tau^+ V R^T``, the anchor's at the origin).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..io.pose_graph import PoseGraph
from ..linalg.base import SingularSystemError
from ..linalg.linear import make_solver

__all__ = ["isotropic_weights", "SESyncProblem", "project_so"]


def isotropic_weights(graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
    r"""SE-Sync's isotropic precisions ``(kappa, tau)`` of every edge from its information.

    3-D: ``tau = 3 / tr(Omega_t^-1)``, ``kappa = 3 / (2 tr(Omega_R^-1))``; 2-D:
    ``tau = 2 / tr(Omega_t^-1)``, ``kappa = Omega_theta_theta``, with ``Omega_t`` and
    ``Omega_R`` the translation and rotation blocks of the edge's information matrix (as
    SE-Sync reads a g2o file; the translation-rotation coupling is ignored).

    Parameters
    ----------
    graph : PoseGraph
        An SE2 or SE3 pose graph.

    Returns
    -------
    kappa, tau : numpy.ndarray
        ``(E,)`` rotation and translation weights.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> info = np.diag([4.0, 4.0, 4.0, 10.0, 10.0, 10.0])[None]
    >>> g = PoseGraph(SE3, ids=np.arange(2), poses=None, i=np.array([0]), j=np.array([1]),
    ...               measurements=SE3.identity((1,)), information=info)
    >>> [round(float(w[0]), 12) for w in isotropic_weights(g)]
    [5.0, 4.0]
    """
    d = graph.dim
    if d not in (2, 3):
        raise ValueError(f"graph must be an SE2 or SE3 pose graph, got {graph.group.__name__}")
    info = graph.information
    it = info[:, :d, :d]
    tau = d / np.trace(np.linalg.inv(it), axis1=1, axis2=2)
    if d == 2:
        kappa = info[:, 2, 2].copy()
    else:
        kappa = 1.5 / np.trace(np.linalg.inv(info[:, 3:, 3:]), axis1=1, axis2=2)
    return kappa, tau


def _block_coo(bi: np.ndarray, bj: np.ndarray, blocks: np.ndarray, rs: int, cs: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """COO triplets of dense ``(rs, cs)`` blocks placed at block rows ``bi``, columns ``bj``."""
    a, b = np.meshgrid(np.arange(rs), np.arange(cs), indexing="ij")
    rows = (bi[:, None, None] * rs + a).ravel()
    cols = (bj[:, None, None] * cs + b).ravel()
    return rows, cols, np.asarray(blocks, dtype=np.float64).ravel()


class SESyncProblem:
    r"""The sparse matrices of SE-Sync's objective for one pose graph, ``Q`` products, the
    objective, the optimal translations and the certificate matrix (module docstring).

    Parameters
    ----------
    graph : PoseGraph
        An SE2 or SE3 pose graph whose edges join all its vertices.
    anchor : int
        Position (in ``graph.ids``) of the vertex whose translation is held at the origin.

    Attributes
    ----------
    d, n : int
        Dimension and number of poses.
    kappa, tau : numpy.ndarray
        The weights (:func:`isotropic_weights`).
    L_rho, Sigma, V, L_tau : scipy.sparse.csr_matrix
        The blocks of ``M`` (module docstring).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], [np.pi / 2, np.pi / 2, np.pi])
    >>> g = PoseGraph(SE2, ids=np.arange(3), poses=None, i=np.array([0, 1, 0]),
    ...               j=np.array([1, 2, 2]), measurements=Z,
    ...               information=np.tile(np.eye(3), (3, 1, 1)))
    >>> p = SESyncProblem(g)
    >>> R = np.asarray(SE2.from_xy_theta(0.0, 0.0, [0.0, np.pi / 2, np.pi]).rotation().matrix())
    >>> Y = R.transpose(0, 2, 1).reshape(-1, 2)  # Y's block i is R_i^T
    >>> round(p.objective(Y), 12)  # the noise-free poses: F = 0
    0.0
    """

    def __init__(self, graph: PoseGraph, anchor: int = 0) -> None:
        import scipy.sparse as sp  # type: ignore[import-untyped]

        d = graph.dim
        kappa, tau = isotropic_weights(graph)
        n = graph.num_vertices
        if not 0 <= anchor < n:
            raise ValueError(f"anchor must be a vertex position in 0..{n - 1}, got {anchor}")
        ii, jj = graph.edge_index()
        if np.any(ii == jj):
            k = int(np.flatnonzero(ii == jj)[0])
            raise ValueError(f"edge {k} joins vertex {graph.i[k]} to itself: remove it")
        Z = graph.measurements
        Rz = np.asarray(Z.rotation().matrix(), dtype=np.float64)  # type: ignore[attr-defined]
        tz = np.asarray(Z.translation(), dtype=np.float64)  # type: ignore[attr-defined]
        self.graph, self.d, self.n, self.anchor = graph, d, n, anchor
        self.kappa, self.tau = kappa, tau
        eye = np.broadcast_to(np.eye(d), Rz.shape)
        k3 = kappa[:, None, None]
        parts = [_block_coo(ii, ii, k3 * eye, d, d), _block_coo(jj, jj, k3 * eye, d, d),
                 _block_coo(ii, jj, -k3 * Rz, d, d),
                 _block_coo(jj, ii, -k3 * np.swapaxes(Rz, 1, 2), d, d)]
        self.L_rho = _csr(parts, d * n, d * n)
        tt = tau[:, None, None] * tz[:, :, None] * tz[:, None, :]
        self.Sigma = _csr([_block_coo(ii, ii, tt, d, d)], d * n, d * n)
        vt = tau[:, None, None] * tz[:, None, :]  # (E, 1, d)
        self.V = _csr([_block_coo(ii, ii, vt, 1, d), _block_coo(jj, ii, -vt, 1, d)], n, d * n)
        self.L_tau = sp.coo_matrix(
            (np.concatenate([tau, tau, -tau, -tau]),
             (np.concatenate([ii, jj, ii, jj]), np.concatenate([ii, jj, jj, ii]))),
            shape=(n, n)).tocsr()
        self._keep = np.delete(np.arange(n), anchor)
        self._Lred = self.L_tau[self._keep][:, self._keep].tocsc()
        self._Lred.sort_indices()
        self._chol = make_solver("cholesky")
        self._chol.analyse(self._Lred.indptr, self._Lred.indices, n - 1)
        try:
            self._chol.factorize(self._Lred.data)
        except SingularSystemError:
            raise ValueError("graph: its edges do not join all vertices to the anchor vertex "
                             f"{graph.ids[anchor]} (the translation Laplacian is singular); "
                             "add edges or solve each connected part apart") from None
        self._LS = (self.L_rho + self.Sigma).tocsr()
        #: scale of Q (its largest diagonal entry of L_rho + Sigma), for relative tolerances
        self.scale = float(max(self._LS.diagonal().max(), np.finfo(float).tiny))
        self._preconditioners: dict[float, Callable[[np.ndarray], np.ndarray]] = {}

    # ------------------------------------------------------------------ products
    def _marginal(self, Y: np.ndarray) -> np.ndarray:
        """``L_tau^+ V Y`` with the anchor's row zero (``(n, k)``) for ``Y`` ``(dn, k)``."""
        W = np.asarray(self.V @ Y)
        out = np.zeros_like(W)
        if self.n > 1:
            out[self._keep] = self._chol.solve(W[self._keep])
        return out

    def Q(self, Y: np.ndarray) -> np.ndarray:
        """The product ``Q Y``.

        Parameters
        ----------
        Y : numpy.ndarray
            ``(dn, k)``.

        Returns
        -------
        numpy.ndarray
            ``(dn, k)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> bool(np.allclose(p.Q(Y), 0.0, atol=1e-12))  # noise-free: Q R^T = 0
        True
        """
        Y = np.asarray(Y, dtype=np.float64)
        return np.asarray(self._LS @ Y) - np.asarray(self.V.T @ self._marginal(Y))

    def preconditioner(self, shift: float) -> Callable[[np.ndarray], np.ndarray]:
        """``Z -> (Q + shift I)^-1 Z``: one sparse Cholesky factorisation of the augmented
        matrix ``M`` with ``shift`` on its rotation diagonal (``Q + shift I`` is its Schur
        complement), reused for every product and cached per ``shift``.

        Parameters
        ----------
        shift : float
            ``> 0`` (``Q`` is only semi-definite).

        Returns
        -------
        callable
            ``(dn, k)`` arrays to ``(dn, k)`` arrays.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> Z = np.random.default_rng(0).standard_normal((6, 2))
        >>> bool(np.allclose(p.preconditioner(0.5)(p.Q(Z) + 0.5 * Z), Z))
        True
        """
        if not shift > 0:
            raise ValueError(f"shift must be > 0, got {shift}")
        cached = self._preconditioners.get(shift)
        if cached is not None:  # one factorisation per shift, shared by the staircase's ranks
            return cached
        A = self.certificate_matrix(np.broadcast_to(-shift * np.eye(self.d),
                                                    (self.n, self.d, self.d)))
        A.sort_indices()
        chol = make_solver("cholesky")
        chol.analyse(A.indptr, A.indices, A.shape[0])
        chol.factorize(A.data)
        m = self.n - 1

        def apply(Z: np.ndarray) -> np.ndarray:
            rhs = np.zeros((A.shape[0],) + Z.shape[1:])
            rhs[m:] = Z
            return np.asarray(chol.solve(rhs)[m:])

        self._preconditioners[shift] = apply
        return apply

    def chordal_rotations(self) -> np.ndarray:
        """The chordal start: ``min tr(R L_rho R^T)`` over all ``d x d`` blocks with the
        anchor's held at ``I`` (one sparse Cholesky solve with ``d`` right-hand sides), each
        block projected to SO(d) (as :func:`microlie.optim.init.chordal`'s rotations, with
        SE-Sync's weights).

        Returns
        -------
        numpy.ndarray
            ``(n, d, d)`` rotations.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> Rc = p.chordal_rotations()  # noise-free: the true rotations relative to vertex 0
        >>> bool(np.allclose(Rc, R[0].T @ R))
        True
        """
        d, a = self.d, self.anchor
        keep = np.flatnonzero(np.repeat(np.arange(self.n) != a, d))
        L = self.L_rho.tocsc()
        Lkk = L[keep][:, keep].tocsc()
        Lkk.sort_indices()
        chol = make_solver("cholesky")
        chol.analyse(Lkk.indptr, Lkk.indices, Lkk.shape[0])
        chol.factorize(Lkk.data)
        Y = np.zeros((self.n * d, d))
        Y[a * d:(a + 1) * d] = np.eye(d)
        Y[keep] = chol.solve(-np.asarray(L[keep][:, a * d:(a + 1) * d].todense()))
        return project_so(np.swapaxes(Y.reshape(-1, d, d), 1, 2))

    def objective(self, Y: np.ndarray) -> float:
        """``tr(Y^T Q Y)``: SE-Sync's ``F`` with the optimal translations.

        Parameters
        ----------
        Y : numpy.ndarray
            ``(dn, r)``: blocks ``R_i^T``, or a point of the rank-``r`` relaxation.

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> abs(p.objective(Y)) < 1e-12
        True
        """
        return float(np.sum(Y * self.Q(Y)))

    def dense_Q(self) -> np.ndarray:
        """``Q`` as a dense matrix (small problems; for checks).

        Returns
        -------
        numpy.ndarray
            ``(dn, dn)``, symmetric positive semi-definite.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> p.dense_Q().shape
        (6, 6)
        """
        return self.Q(np.eye(self.d * self.n))

    def translations(self, R: np.ndarray) -> np.ndarray:
        """The translations that minimise ``F`` for given rotations, the anchor's at the
        origin.

        Parameters
        ----------
        R : numpy.ndarray
            ``(n, d, d)`` rotations.

        Returns
        -------
        numpy.ndarray
            ``(n, d)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> (np.round(p.translations(R), 9) + 0.0).tolist()  # the anchor's pose is already I
        [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]
        """
        Y = np.swapaxes(R, 1, 2).reshape(-1, self.d)
        return -self._marginal(Y)

    def lagrange_multipliers(self, Y: np.ndarray) -> np.ndarray:
        """The symmetric block-diagonal multipliers of the first-order conditions at ``Y``:
        ``Lambda_i = sym((Q Y)_i Y_i^T)``.

        Parameters
        ----------
        Y : numpy.ndarray
            ``(dn, r)``.

        Returns
        -------
        numpy.ndarray
            ``(n, d, d)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> p.lagrange_multipliers(Y).shape
        (3, 2, 2)
        """
        return _lagrange(Y, self.Q(Y), self.d)

    def certificate_matrix(self, Lam: np.ndarray) -> Any:
        """The sparse augmented matrix ``[[L_tau, V], [V^T, L_rho + Sigma - Lambda]]`` with the
        anchor's row and column removed: ``S = Q - Lambda`` is its Schur complement, so it is
        positive (semi)definite exactly when ``S`` is (Sylvester's law of inertia).

        Parameters
        ----------
        Lam : numpy.ndarray
            ``(n, d, d)`` symmetric blocks of ``Lambda``.

        Returns
        -------
        scipy.sparse.csc_matrix
            ``(n - 1 + dn)`` square.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim.io.pose_graph import PoseGraph
        >>> from microlie.optim.certify import SESyncProblem
        >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
        >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
        >>> p = SESyncProblem(PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
        ...                   measurements=X[i].between(X[j]),
        ...                   information=np.tile(np.eye(3), (3, 1, 1))))
        >>> R = np.asarray(X.rotation().matrix())
        >>> Y = np.swapaxes(R, 1, 2).reshape(-1, 2)  # blocks R_i^T
        >>> p.certificate_matrix(p.lagrange_multipliers(Y)).shape
        (8, 8)
        """
        import scipy.sparse as sp

        d, n = self.d, self.n
        idx = np.arange(n)
        lam = _csr([_block_coo(idx, idx, Lam, d, d)], d * n, d * n)
        Vk = self.V[self._keep]
        return sp.bmat([[self._Lred, Vk], [Vk.T, self._LS - lam]], format="csc")


def _lagrange(Y: np.ndarray, QY: np.ndarray, d: int) -> np.ndarray:
    r = Y.shape[1]
    B = QY.reshape(-1, d, r) @ np.swapaxes(Y.reshape(-1, d, r), 1, 2)
    return 0.5 * (B + np.swapaxes(B, 1, 2))


def _csr(parts: list, nr: int, nc: int) -> Any:
    import scipy.sparse as sp

    rows = np.concatenate([p[0] for p in parts])
    cols = np.concatenate([p[1] for p in parts])
    vals = np.concatenate([p[2] for p in parts])
    return sp.coo_matrix((vals, (rows, cols)), shape=(nr, nc)).tocsr()


def project_so(M: np.ndarray) -> np.ndarray:
    """The nearest rotation (Frobenius norm) to each ``(d, d)`` block of ``M``.

    Parameters
    ----------
    M : numpy.ndarray
        ``(n, d, d)``.

    Returns
    -------
    numpy.ndarray
        ``(n, d, d)`` rotations: ``U diag(1, .., det(U V^T)) V^T`` from ``M = U S V^T``.

    Examples
    --------
    >>> import numpy as np
    >>> np.round(project_so(np.array([[[2.0, 0.1], [-0.1, 2.0]]])), 4).tolist()
    [[[0.9988, 0.0499], [-0.0499, 0.9988]]]
    """
    U, _, Vt = np.linalg.svd(M)
    D = np.ones(M.shape[:-1])
    D[:, -1] = np.linalg.det(U @ Vt)
    return (U * D[:, None, :]) @ Vt
