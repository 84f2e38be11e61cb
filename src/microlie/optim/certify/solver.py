"""The certified solver: Riemannian staircase, certificate, rounding (SE-Sync, Rosen et al.,
IJRR 2019; Shonan averaging, Dellaert et al., ECCV 2020). See :mod:`microlie.optim.certify`."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...groups import SE2, SE3, LieGroup
from ..core.threads import with_blas_threads
from ..io.pose_graph import PoseGraph
from ..linalg.base import SingularSystemError
from ..linalg.linear import make_solver
from .problem import SESyncProblem, project_so
from .stiefel import retract, trust_region

__all__ = ["CertifiedResult", "certified_pose_graph", "certify_poses", "min_eigenvalue"]

#: default relative tolerances: the certificate's (times the scale of Q) and the gradient's
EIG_RTOL = 1e-6
GRAD_RTOL = 1e-9


@dataclass(frozen=True)
class CertifiedResult:
    """What :func:`certified_pose_graph` and :func:`certify_poses` return.

    Attributes
    ----------
    poses : LieGroup
        ``(V,)`` poses aligned with ``graph.ids`` (the anchor keeps its file pose, or the
        identity without vertices).
    objective : float
        SE-Sync's ``F`` at ``poses`` (isotropic weights, no 1/2; :mod:`microlie.optim.certify`).
    lower_bound : float
        A lower bound on the optimum of ``F``: the relaxation's value when its certificate
        verified, else ``-inf``.
    cost : float
        GTSAM's error ``0.5 sum r^T Omega r`` at ``poses`` with the file's full information
        (:meth:`PoseGraph.cost`).
    certified : bool
        ``min_eigenvalue >= -tolerance`` at ``poses``: they are a global minimiser of ``F``.
    min_eigenvalue : float
        The smallest eigenvalue of the certificate matrix ``S = Q - Lambda`` at ``poses``.
    tolerance : float
        The certificate's tolerance.
    rank : int
        The largest rank of the staircase (``d`` when the first local optimum certified).
    iterations : int
        Trust-region iterations over all ranks.
    gradient_norm : float
        The Riemannian gradient's norm of ``F`` at ``poses`` (first-order optimality).
    moved : float
        :func:`certify_poses` with ``refine``: the largest rotation angle (rad) between the
        given poses and the refined ones; 0 otherwise.
    time_s : float
        Wall time.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> from microlie.optim.certify import certified_pose_graph
    >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.5, 3.0])
    >>> i, j = np.array([0, 1, 0]), np.array([1, 2, 2])
    >>> g = PoseGraph(SE2, ids=np.arange(3), poses=X, i=i, j=j,
    ...               measurements=X[i].between(X[j]), information=np.tile(np.eye(3), (3, 1, 1)))
    >>> res = certified_pose_graph(g)
    >>> res.certified, res.rank, res.min_eigenvalue >= -res.tolerance
    (True, 2, True)
    """

    poses: LieGroup
    objective: float
    lower_bound: float
    cost: float
    certified: bool
    min_eigenvalue: float
    tolerance: float
    rank: int
    iterations: int
    gradient_norm: float
    moved: float
    time_s: float


def _graph(graph: PoseGraph | str | Path) -> PoseGraph:
    if isinstance(graph, PoseGraph):
        if graph.group not in (SE2, SE3):
            raise ValueError(f"graph must be an SE2 or SE3 pose graph, got "
                             f"{graph.group.__name__}")
        return graph
    if isinstance(graph, (str, Path)):
        from ..io.formats import FORMATS, detect_format

        fmt = detect_format(graph)
        if fmt not in ("g2o", "toro"):
            raise ValueError(f"graph: {graph} is a {fmt} file, not a pose graph (g2o or TORO)")
        return _graph(FORMATS[fmt].load("reader")(graph))
    raise ValueError(f"graph must be a PoseGraph or the path of a g2o/TORO file, got "
                     f"{type(graph).__name__}")


def _anchor(graph: PoseGraph) -> int:
    return int(graph.index(graph.fixed[0])) if graph.fixed.size else 0


def _stack(R: np.ndarray) -> np.ndarray:
    """``(n, d, d)`` rotations -> ``Y`` ``(n d, d)`` with blocks ``R_i^T``."""
    return np.ascontiguousarray(np.swapaxes(R, 1, 2).reshape(-1, R.shape[-1]))


def _poses(problem: SESyncProblem, R: np.ndarray) -> LieGroup:
    graph, d, k = problem.graph, problem.d, problem.anchor
    t = problem.translations(R)
    T = np.zeros((problem.n, d + 1, d + 1))
    T[:, :d, :d] = R
    T[:, :d, d] = t
    T[:, d, d] = 1.0
    if graph.poses is not None:  # the anchor at its file pose: X <- X_file[k] X[k]^-1 X
        A = np.asarray(graph.poses[k:k + 1].matrix())[0] @ np.linalg.inv(T[k])
        T = A @ T
    else:
        T = np.linalg.inv(T[k]) @ T
    return (SE2 if d == 2 else SE3).from_matrix(T)


def _rotations(X: LieGroup) -> np.ndarray:
    return np.asarray(X.rotation().matrix(), dtype=np.float64)  # type: ignore[attr-defined]


def _round(Y: np.ndarray, d: int) -> np.ndarray:
    """Rotations ``(n, d, d)`` from a relaxation point ``Y`` ``(n d, r)``: its best rank-``d``
    factor, the reflection that gives most blocks a positive determinant, each block projected
    to SO(d)."""
    U, s, _ = np.linalg.svd(Y, full_matrices=False)
    B = (U[:, :d] * s[:d]).reshape(-1, d, d)  # blocks ~ R_i^T up to a common O(d) factor
    if np.sum(np.linalg.det(B) > 0) < B.shape[0] / 2:
        B = B * np.r_[np.ones(d - 1), -1.0]
    return project_so(np.swapaxes(B, 1, 2))


def min_eigenvalue(problem: SESyncProblem, Y: np.ndarray, tolerance: float
                   ) -> tuple[float, np.ndarray, bool]:
    r"""The smallest eigenvalue of the certificate matrix ``S = Q - Lambda(Y)`` and its
    eigenvector, and whether ``S + tolerance I`` is positive definite.

    ``S`` is the Schur complement of the sparse augmented matrix
    (:meth:`SESyncProblem.certificate_matrix`), so ``S - sigma I`` is positive definite exactly
    when the augmented matrix with ``-sigma`` added to its last ``dn`` diagonal entries has a
    Cholesky factor. The test is that factorisation at ``sigma = -tolerance``; the eigenpair
    comes from Lanczos on ``(S - sigma I)^-1`` (scipy's ``eigsh``), with ``sigma`` lowered by
    factors of 10 until the factorisation succeeds when ``S`` is not certified.

    Parameters
    ----------
    problem : SESyncProblem
        The data.
    Y : numpy.ndarray
        ``(n d, r)`` a first-order critical point (``Lambda`` is read from it).
    tolerance : float
        The certificate's tolerance (> 0).

    Returns
    -------
    value : float
    vector : numpy.ndarray
        ``(n d,)``, unit norm.
    certified : bool
        ``value >= -tolerance`` (decided by the factorisation, not by the eigensolver).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> from microlie.optim.certify import SESyncProblem, min_eigenvalue
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 1.0], [0.0, 0.0, 1.0], [np.pi / 2, np.pi / 2, np.pi])
    >>> g = PoseGraph(SE2, ids=np.arange(3), poses=None, i=np.array([0, 1, 0]),
    ...               j=np.array([1, 2, 2]), measurements=Z,
    ...               information=np.tile(np.eye(3), (3, 1, 1)))
    >>> p = SESyncProblem(g)
    >>> R = np.asarray(SE2.from_xy_theta(0.0, 0.0, [0.0, np.pi / 2, np.pi]).rotation().matrix())
    >>> lam, v, ok = min_eigenvalue(p, R.transpose(0, 2, 1).reshape(-1, 2), 1e-9)
    >>> ok, abs(lam) < 1e-9
    (True, True)
    """
    import scipy.sparse as sp  # type: ignore[import-untyped]
    from scipy.sparse.linalg import (  # type: ignore[import-untyped]
        ArpackNoConvergence,
        LinearOperator,
        eigsh,
    )

    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    A = problem.certificate_matrix(problem.lagrange_multipliers(Y))
    m = problem.n - 1
    N = A.shape[0]
    shift = sp.diags(np.r_[np.zeros(m), np.ones(N - m)], format="csc")
    chol = make_solver("cholesky")
    A.sort_indices()
    B = (A + shift).tocsc()  # the pattern of A with its whole diagonal
    B.sort_indices()
    chol.analyse(B.indptr, B.indices, N)
    sigma = -tolerance
    certified = None
    for _ in range(40):
        Bs = (A - sigma * shift).tocsc()
        Bs.sort_indices()
        try:
            chol.factorize(Bs.data)
        except SingularSystemError:
            certified = False if certified is None else certified
            sigma *= 10.0
            continue
        certified = True if certified is None else certified
        break
    else:
        raise ValueError("the certificate matrix could not be shifted to positive definite "
                         "(non-finite data?)")

    def inv(b: np.ndarray) -> np.ndarray:
        rhs = np.zeros((N,) + b.shape[1:])
        rhs[m:] = b.reshape(N - m, *b.shape[1:])
        return chol.solve(rhs)[m:]

    dn = N - m
    op = LinearOperator((dn, dn), matvec=inv, dtype=np.float64)
    if dn <= 3:
        M = inv(np.eye(dn))
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        mu, v = w[-1], V[:, -1]
    else:
        v0 = np.random.default_rng(0).standard_normal(dn)
        try:
            w, V = eigsh(op, k=1, which="LA", v0=v0, tol=1e-10, ncv=min(dn, 40),
                         maxiter=20 * dn)
        except ArpackNoConvergence as e:  # keep Lanczos' best estimate when it has one
            if not len(e.eigenvalues):
                raise ValueError("the certificate's eigenvalue did not converge (Lanczos); "
                                 "the factorisation says certified="
                                 f"{bool(certified)}") from None
            w, V = e.eigenvalues, e.eigenvectors
        mu, v = float(w[0]), V[:, 0]
    return sigma + 1.0 / mu, v / np.linalg.norm(v), bool(certified)


def _escape(problem: SESyncProblem, Y: np.ndarray, v: np.ndarray, f: float
            ) -> np.ndarray:
    """From a rank-``r`` critical point with negative curvature ``v``, a point of rank
    ``r + 1`` with a lower objective: ``[Y, 0] + alpha [0, v]``, retracted, with ``alpha``
    halved until the objective decreases."""
    d = problem.d
    Yp = np.hstack([Y, np.zeros((Y.shape[0], 1))])
    Vp = np.zeros_like(Yp)
    Vp[:, -1] = v
    alpha = np.sqrt(problem.n)
    for _ in range(60):
        Yn = retract(Yp, alpha * Vp, d)
        if problem.objective(Yn) < f:
            return Yn
        alpha *= 0.5
    return retract(Yp, alpha * Vp, d)


#: the preconditioner's shift, relative to the scale of Q
PRECON_RSHIFT = 1e-6


def _refine(problem: SESyncProblem, Y: np.ndarray, grad_tol: float, max_iter: int) -> Any:
    precon = problem.preconditioner(PRECON_RSHIFT * problem.scale)
    return trust_region(problem.Q, Y, problem.d, grad_tol=grad_tol, max_iter=max_iter,
                        precon=precon)


@with_blas_threads
def certified_pose_graph(graph: PoseGraph | str | Path, initial: LieGroup | None = None, *,
                         tolerance: float | None = None, max_rank: int = 10,
                         max_iter: int = 500, blas_threads: int | None = 1
                         ) -> CertifiedResult:
    r"""The global minimiser of SE-Sync's objective ``F``, with its certificate.

    The Riemannian staircase: minimise ``tr(Y^T Q Y)`` over ``n`` Stiefel blocks of rank ``r``
    (trust region, :mod:`microlie.optim.certify.stiefel`) from ``r = d``; when the certificate
    matrix ``S = Q - Lambda`` has an eigenvalue below ``-tolerance``, escape along its
    eigenvector to rank ``r + 1``. Once a rank's optimum certifies (the relaxation is solved),
    round to SO(d), refine at rank ``d`` and certify the rounded rotations; the translations are
    then the linear least-squares ones.

    Parameters
    ----------
    graph : PoseGraph or path
        An SE2/SE3 pose graph (or a g2o/TORO file) whose edges join all vertices.
    initial : LieGroup, optional
        Start poses (only the rotations are used); default the chordal rotations
        (:meth:`SESyncProblem.chordal_rotations`).
    tolerance : float, optional
        The certificate accepts ``lambda_min(S) >= -tolerance``; default ``1e-6`` times the
        largest diagonal entry of ``L_rho + Sigma``.
    max_rank : int
        The staircase stops (not certified) above this rank.
    max_iter : int
        Trust-region iterations per rank.
    blas_threads : int or None
        BLAS threads during the call (default 1, measured fastest on a busy machine; ``None``
        keeps the library's setting).

    Returns
    -------
    CertifiedResult

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> from microlie.optim.certify import certified_pose_graph
    >>> rng = np.random.default_rng(1)
    >>> X = SE3.exp(rng.normal(size=(6, 6)))  # noise-free ring with two chords
    >>> i, j = np.array([0, 1, 2, 3, 4, 5, 0, 1]), np.array([1, 2, 3, 4, 5, 0, 3, 4])
    >>> g = PoseGraph(SE3, ids=np.arange(6), poses=None, i=i, j=j,
    ...               measurements=X[i].between(X[j]), information=np.tile(np.eye(6), (8, 1, 1)))
    >>> res = certified_pose_graph(g)
    >>> res.certified, abs(res.objective) < 1e-9, abs(res.cost) < 1e-9
    (True, True, True)
    """
    t0 = time.perf_counter()
    graph = _graph(graph)
    if max_rank < graph.dim:
        raise ValueError(f"max_rank must be at least the dimension {graph.dim}, got {max_rank}")
    if initial is not None and len(initial) != graph.num_vertices:
        raise ValueError(f"initial must hold {graph.num_vertices} poses (one per vertex), got "
                         f"{len(initial)}")
    problem = SESyncProblem(graph, _anchor(graph))
    d = problem.d
    tol = EIG_RTOL * problem.scale if tolerance is None else float(tolerance)
    gtol = GRAD_RTOL * problem.scale * np.sqrt(d * problem.n)
    Y = _stack(problem.chordal_rotations() if initial is None else _rotations(initial))
    iters = 0
    lower = -np.inf
    r = d
    while True:
        out = _refine(problem, Y, gtol, max_iter)
        iters += out.iterations
        lam, v, ok = min_eigenvalue(problem, out.Y, tol)
        if ok:
            lower = out.f
            break
        if r >= max_rank:
            break
        Y = _escape(problem, out.Y, v, out.f)
        r += 1
    if r == d:
        R, f, gn = _rotations_of(out.Y, d), out.f, out.grad_norm
        certified = ok
    else:
        rounded = _stack(_round(out.Y, d))
        ref = _refine(problem, rounded, gtol, max_iter)
        iters += ref.iterations
        lam, _, certified = min_eigenvalue(problem, ref.Y, tol)
        R, f, gn = _rotations_of(ref.Y, d), ref.f, ref.grad_norm
    X = _poses(problem, R)
    return CertifiedResult(poses=X, objective=f, lower_bound=float(lower), cost=graph.cost(X),
                           certified=certified, min_eigenvalue=float(lam), tolerance=tol,
                           rank=r, iterations=iters, gradient_norm=gn, moved=0.0,
                           time_s=time.perf_counter() - t0)


def _rotations_of(Y: np.ndarray, d: int) -> np.ndarray:
    """Rotations from a rank-``d`` point (blocks ``R_i^T``), projected to SO(d) (rounding)."""
    return project_so(np.swapaxes(Y.reshape(-1, d, d), 1, 2))


@with_blas_threads
def certify_poses(graph: PoseGraph | str | Path, poses: LieGroup, *, refine: bool = True,
                  tolerance: float | None = None, max_iter: int = 500,
                  blas_threads: int | None = 1) -> CertifiedResult:
    r"""Whether ``poses`` (for example a Levenberg-Marquardt answer) are the global minimum of
    SE-Sync's objective ``F``.

    The certificate needs a critical point of ``F``; a solver of the full-information cost
    stops near one, not at it. With ``refine`` the rotations are first taken to the nearest
    critical point of ``F`` (trust region at rank ``d`` from ``poses``; ``moved`` says how far),
    and that point is certified. A local minimum gives ``certified=False`` and a negative
    ``min_eigenvalue``.

    Parameters
    ----------
    graph : PoseGraph or path
        An SE2/SE3 pose graph (or a g2o/TORO file).
    poses : LieGroup
        ``(V,)`` poses aligned with ``graph.ids``.
    refine : bool
        Refine on ``F`` first (default); without, ``poses``' rotations are certified as given.
    tolerance : float, optional
        As in :func:`certified_pose_graph`.
    max_iter : int
        Trust-region iterations of the refinement.
    blas_threads : int or None
        As in :func:`certified_pose_graph`.

    Returns
    -------
    CertifiedResult
        ``poses`` are the refined ones (translations the optimal ones for the rotations).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.io.pose_graph import PoseGraph
    >>> from microlie.optim.certify import certify_poses
    >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0],
    ...                       [0.0, 1.5, 3.1, -1.6])
    >>> i, j = np.array([0, 1, 2, 3]), np.array([1, 2, 3, 0])
    >>> g = PoseGraph(SE2, ids=np.arange(4), poses=X, i=i, j=j,
    ...               measurements=X[i].between(X[j]), information=np.tile(np.eye(3), (4, 1, 1)))
    >>> c = certify_poses(g, X)
    >>> c.certified, c.moved < 1e-9
    (True, True)
    """
    t0 = time.perf_counter()
    graph = _graph(graph)
    if len(poses) != graph.num_vertices:
        raise ValueError(f"poses must hold {graph.num_vertices} poses (one per vertex), got "
                         f"{len(poses)}")
    problem = SESyncProblem(graph, _anchor(graph))
    d = problem.d
    tol = EIG_RTOL * problem.scale if tolerance is None else float(tolerance)
    R0 = _rotations(poses)
    Y = _stack(R0)
    iters = 0
    if refine:
        out = _refine(problem, Y, GRAD_RTOL * problem.scale * np.sqrt(d * problem.n), max_iter)
        Y, iters = out.Y, out.iterations
    lam, _, ok = min_eigenvalue(problem, Y, tol)
    R = _rotations_of(Y, d)
    QY = problem.Q(Y)
    from .stiefel import project

    gn = float(np.linalg.norm(2.0 * project(Y, QY, d)))
    f = float(np.sum(Y * QY))
    # the largest angle between the given and the refined rotations (all relative to the
    # anchor, which fixes the common rotation)
    k = problem.anchor
    rel0 = np.swapaxes(R0[k], 0, 1) @ R0
    rel = np.swapaxes(R[k], 0, 1) @ R
    # the angle from the chord: ||A - B||_F = 2 sqrt(2) sin(angle / 2) in SO(2) and SO(3)
    chord = np.linalg.norm(rel - rel0, axis=(1, 2)) / (2.0 * np.sqrt(2.0))
    moved = float(2.0 * np.arcsin(min(float(chord.max()), 1.0))) if refine else 0.0
    X = _poses(problem, R)
    return CertifiedResult(poses=X, objective=f, lower_bound=f if ok else -np.inf,
                           cost=graph.cost(X), certified=ok, min_eigenvalue=float(lam),
                           tolerance=tol, rank=d, iterations=iters, gradient_norm=gn,
                           moved=moved, time_s=time.perf_counter() - t0)
