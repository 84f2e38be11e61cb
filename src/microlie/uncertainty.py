"""Uncertainty on Lie groups: Gaussians, covariance propagation, left and right frames.

A :class:`Gaussian` on a group is a mean element ``Xbar``, a tangent covariance ``P`` of shape
``(*batch, dof, dof)`` and an explicit **frame** that says on which side the error multiplies
(the documentation's "Uncertainty" page):

* ``frame="right"`` (local, body): ``X = Xbar (+) eps = Xbar Exp(eps)``,  ``eps ~ N(0, P)``;
* ``frame="left"`` (global, world): ``X = eps (+) Xbar = Exp(eps) Xbar``, ``eps ~ N(0, P)``.

The two describe the same distribution when ``P_left = Ad_Xbar P_right Ad_Xbar^T``
(:meth:`Gaussian.to_frame`; exact, no linearisation). Every propagation is first order
(eq. 16): ``P_y = J P J^T`` with ``J`` the Jacobian of the *same* side as the frame; results keep
the frame of the Gaussian the method is called on, and the other operand of a binary operation
is converted to that frame first. Tangent vectors are translation first.

Vector-valued results (a point moved by an uncertain pose, the logarithm of an uncertain
element) are :class:`VectorGaussian` objects: a mean ``(*batch, n)`` and a covariance
``(*batch, n, n)`` in ``R^n``, where there is no frame to choose.

>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.uncertainty import Gaussian
>>> step = SE2.from_xy_theta(1.0, 0.0, 0.1)
>>> X = Gaussian(SE2.identity(), np.diag([0.01, 0.01, 0.001]), frame="right")
>>> Q = Gaussian(step, np.diag([0.02, 0.01, 0.002]), frame="right")
>>> Z = X.compose(Q)                      # eq. (17): Ad_Q^-1 P_X Ad_Q^-T + P_Q
>>> Z.frame, Z.cov.shape
('right', (3, 3))
>>> bool(np.allclose(Z.to_frame("left").to_frame("right").cov, Z.cov))
True
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Literal, cast, overload

import numpy as np

from . import _array as A
from . import _linalg as L
from ._array import Array
from .groups.base import LieGroup

__all__ = ["Gaussian", "VectorGaussian", "propagate", "FRAMES", "RANK_RTOL"]

Frame = Literal["right", "left"]
FRAMES: tuple[str, str] = ("right", "left")
_LOG_2PI = math.log(2.0 * math.pi)


# ---------------------------------------------------------------------------- checks


def _check_frame(frame: Any, what: str = "frame") -> str:
    if frame not in FRAMES:
        raise ValueError(f"{what} must be 'right' or 'left', got {frame!r}")
    return frame


def _as_array(x: Any, like: Array, what: str) -> Array:
    """``x`` as a float array of the backend of ``like`` (clear error on a backend mix)."""
    arr = A.as_float_array(x, like=like)
    if not L.same_backend(arr, like):
        raise ValueError(f"{what} is a {type(arr).__module__} array but the mean is a "
                         f"{type(like).__module__} array: use one array backend")
    return arr


def _check_finite(x: Array, what: str) -> np.ndarray | None:
    """Raise ``ValueError`` if ``x`` holds NaN or inf; returns its values as NumPy (``None``
    when they are unknown under a trace: no check, and no traced value is ever forced)."""
    M = L.concrete(x)
    if M is not None and M.size and not np.isfinite(M).all():
        raise ValueError(f"{what} contains NaN or infinite values")
    return M


def check_covariance(P: Array, n: int, what: str = "covariance",
                     blocks: _Blocks | None = None) -> bool:
    """Raise ``ValueError`` unless ``P`` is ``(..., n, n)``, finite, symmetric and PSD.

    Symmetry and positive semi-definiteness are checked to ``sqrt(eps)`` of the dtype relative to
    the largest entry or eigenvalue of each matrix. The values are read without forcing a
    traced one: under ``jax.jit`` a concrete (closed-over) covariance is checked, a traced one
    is not. Returns True when every matrix is also known to have full rank by the rank rule
    (unit ``blocks``, see :class:`_Null`; default: every coordinate its own unit).
    """
    A.check_last_dim(P, (n, n), what)
    M = _check_finite(P, what)
    if M is None or M.size == 0:
        return False
    tol = math.sqrt(float(np.finfo(M.dtype).eps))
    M = M.astype(np.float64, copy=False)
    scale = np.abs(M).max(axis=(-1, -2))
    asym = np.abs(M - np.swapaxes(M, -1, -2)).max(axis=(-1, -2))
    if np.any(asym > tol * scale):
        raise ValueError(f"{what} is not symmetric (max |P - P^T| = {asym.max():.3g})")
    M = 0.5 * (M + np.swapaxes(M, -1, -2))
    blocks = _singletons(n) if blocks is None else blocks
    if _full_rank(M, _threshold(M, blocks, None, P)):
        return True
    w = np.linalg.eigvalsh(M)
    if np.any(w[..., 0] < -tol * np.maximum(np.abs(w).max(axis=-1), 1e-300)):
        raise ValueError(f"{what} is not positive semi-definite (smallest eigenvalue "
                         f"{w[..., 0].min():.3g})")
    return False


# ---------------------------------------------------------------------------- rank rule

#: Tolerance of the rank rule, by dtype: a coordinate is degenerate when the part of its
#: variance not explained by the preceding coordinates is at most this fraction of the total
#: variance of its unit block (SciPy's rank tolerances, ``1e6 eps`` in float64 = 2.2e-10 and
#: ``1e3 eps`` in float32 = 1.2e-4; blocks of different units never compare, so the rule does
#: not depend on units).
RANK_RTOL: dict[str, float] = {"float64": 1e6 * float(np.finfo(np.float64).eps),
                               "float32": 1e3 * float(np.finfo(np.float32).eps)}


def _rtol(P: Array) -> float:
    return RANK_RTOL["float32" if "float32" in str(P.dtype) else "float64"]


def _eps(P: Array) -> float:
    return float(np.finfo(np.float32 if "float32" in str(P.dtype) else np.float64).eps)


class _Blocks:
    """Unit blocks of a tangent space: ``idx``, index arrays (upstream blocks first), and
    ``member``, the ``(n, n)`` 0/1 matrix of "same block"."""

    __slots__ = ("idx", "member", "rotated")

    def __init__(self, idx: Sequence[np.ndarray]) -> None:
        self.idx = tuple(idx)
        n = sum(len(b) for b in self.idx)
        self.member = np.zeros((n, n))
        for b in self.idx:
            self.member[np.ix_(b, b)] = 1.0
        self.rotated = any(len(b) > 1 for b in self.idx)


_BLOCKS: dict[Any, _Blocks] = {}


def _unit_blocks(group: type[LieGroup]) -> _Blocks:
    """The unit blocks of ``group``'s tangent.

    The blocks are the strongly connected components of the sparsity pattern of ``Ad_X`` at a
    generic ``X``: coordinates that a change of frame mixes into each other must share a unit
    (SE(3): translation, rotation; Sim(3): translation, rotation, log-scale; ``R(n)``: every
    coordinate alone, since its adjoint is the identity; products: the blocks of the factors).
    A block is upstream of those whose rows of ``Ad`` read it (rotation before translation).
    """
    blocks = _BLOCKS.get(group)
    if blocks is None:
        n = group.dof
        tau = np.linspace(0.3, 1.1, n) * (-1.0) ** np.arange(n)
        Ad = np.asarray(group.exp(tau).adjoint(), dtype=np.float64)
        reach = (np.abs(Ad) > 1e-9 * np.abs(Ad).max()) | np.eye(n, dtype=bool)
        for _ in range(n.bit_length() + 1):  # transitive closure by squaring
            reach = (reach.astype(np.int64) @ reach.astype(np.int64)) > 0
        same = reach & reach.T
        firsts = sorted({int(np.argmax(row)) for row in same})
        groups = [np.flatnonzero(same[i]) for i in firsts]
        blocks = _Blocks(sorted(groups, key=lambda b: (int(reach[b[0]].sum()), int(b[0]))))
        _BLOCKS[group] = blocks
    return blocks


def _singletons(n: int) -> _Blocks:
    blocks = _BLOCKS.get(n)
    if blocks is None:
        blocks = _BLOCKS[n] = _Blocks([np.array([k]) for k in range(n)])
    return blocks


def _threshold(M: np.ndarray, blocks: _Blocks, mag: np.ndarray | None, P: Array) -> np.ndarray:
    """The variance ``(..., n)`` at or below which a direction of each coordinate's unit block
    counts as zero: ``rtol`` times the block's total variance (its trace: invariant to the
    orientation of its axes), and at least the rounding floor ``4 n eps`` times the block's
    trace of ``mag`` (``|T| |P0| |T|^T`` when ``M`` was computed as ``T P0 T^T``; default
    ``|M|``)."""
    n = M.shape[-1]
    d0 = np.diagonal(M, axis1=-2, axis2=-1)
    dm = np.abs(np.diagonal(M if mag is None else mag, axis1=-2, axis2=-1))
    return np.maximum(_rtol(P) * (d0 @ blocks.member), 4 * n * _eps(P) * (dm @ blocks.member))


def _full_rank(M: np.ndarray, thr: np.ndarray) -> bool:
    """``M - diag(thr)`` is positive definite (one Cholesky factorisation). Sufficient for the
    rank rule: then every Schur complement of a block exceeds ``thr`` (Schur complements are
    monotone); the elimination of :meth:`_Null.of` decides the other cases exactly."""
    try:
        np.linalg.cholesky(M - thr[..., :, None] * np.eye(M.shape[-1]))
    except np.linalg.LinAlgError:
        return False
    return True


class _Null:
    """The degenerate directions of a batch of covariances (NumPy constants for autograd).

    The tangent splits into unit blocks (:func:`_unit_blocks`; a vector: every coordinate
    alone). Block by block, upstream first, the conditional covariance of the block given the
    directions kept so far (its Schur complement) is diagonalised, ``V^T C V = diag(w)``; a
    direction is **degenerate** when ``w <= thr`` (:func:`_threshold`: :data:`RANK_RTOL`
    times the block's total variance, so the rule depends neither on units nor on the
    orientation of the axes; a variance that is 0 or negative is always degenerate). In the
    rotated coordinates ``P' = Q^T P Q`` (``Q`` block-diagonal, the ``V``; identity for
    single coordinates) the kept ones, ``m``, index a principal block ``P'_mm`` of full rank,
    so ``G = Q pad(P'_mm^-1) Q^T`` is a symmetric generalised inverse of ``P``: ``e^T G e`` and
    ``P H^T G r`` are those of the pseudo-inverse for every ``e`` and ``r`` in the range. A
    deviation ``e`` lies in that range (the support) when at every degenerate direction
    ``|e' - P' G' e'|_k <= 3 sqrt(w_k) + sqrt(eps) max(|e|, 1)`` (within three of the
    standard deviations counted as zero, plus rounding).
    """

    __slots__ = ("keep", "rank_loss", "var", "eps", "Q")

    def __init__(self, keep: np.ndarray, var: np.ndarray, eps: float,
                 Q: np.ndarray | None) -> None:
        self.keep = keep  # (*batch, n) float: 1 for the kept directions (columns of Q)
        self.rank_loss = (keep == 0).sum(axis=-1)
        self.var, self.eps, self.Q = var, eps, Q  # var: the variances counted as zero

    @staticmethod
    def of(P: Array, blocks: _Blocks | None = None,
           mag: np.ndarray | None = None) -> _Null | None:
        """``None`` when every matrix has full rank, or when the values are unknown (traced).
        ``blocks``: the unit blocks (default: every coordinate alone); ``mag``: the magnitudes
        that rounded into ``P`` (see :func:`_threshold`)."""
        M = L.concrete(P)
        if M is None or M.size == 0:
            return None
        M = M.astype(np.float64, copy=False)
        n = M.shape[-1]
        blocks = _singletons(n) if blocks is None else blocks
        A_ = 0.5 * (M + np.swapaxes(M, -1, -2))
        thr = np.broadcast_to(_threshold(A_, blocks, mag, P), A_.shape[:-1])
        if _full_rank(A_, thr):  # the common case
            return None
        bad = np.zeros(M.shape[:-1], dtype=bool)
        var = np.zeros(M.shape[:-1])
        Q = np.broadcast_to(np.eye(n), A_.shape).copy()
        for b in blocks.idx:
            if len(b) > 1:  # rotate the block to the eigenvectors of its Schur complement
                _, V = np.linalg.eigh(A_[..., b[:, None], b[None, :]])
                A_[..., b, :] = np.swapaxes(V, -1, -2) @ A_[..., b, :]
                A_[..., :, b] = A_[..., :, b] @ V
                Q[..., b[:, None], b[None, :]] = V
            for k in b:  # eliminate each direction (the block's are now uncorrelated)
                d = A_[..., k, k]
                z = d <= thr[..., k]
                bad[..., k] = z
                var[..., k] = np.where(z, np.maximum(d, 0.0), 0.0)
                col = np.where(z[..., None], 0.0,
                               A_[..., :, k] / np.where(z, 1.0, d)[..., None])
                A_ = A_ - col[..., :, None] * A_[..., k, None, :]
                A_[..., k, :] = np.where(z[..., None], 0.0, A_[..., k, :])
                A_[..., :, k] = np.where(z[..., None], 0.0, A_[..., :, k])
        if not bad.any():
            return None
        return _Null((~bad).astype(np.float64), var, _eps(P), Q if blocks.rotated else None)

    def _rot(self, P: Array) -> tuple[Array | None, Array]:
        """``(Q, Q^T P Q)`` in the backend of ``P`` (``Q`` is ``None`` for the identity)."""
        if self.Q is None:
            return None, P
        q = L.asarray(self.Q, P)
        return q, L.mT(q) @ P @ q

    def pinv_solve(self, P: Array, b: Array) -> Array:
        """``G b`` for matrices ``b`` ``(..., n, k)`` (differentiable in ``P`` and ``b``)."""
        q, Pr = self._rot(P)
        if q is None:
            return self._solve(Pr, b)
        return q @ self._solve(Pr, L.mT(q) @ b)

    def _solve(self, Pr: Array, b: Array) -> Array:
        m, Pm = self._block(Pr)
        return L.solve(Pm, m[..., :, None] * b) * m[..., :, None]

    def _block(self, Pr: Array) -> tuple[Array, Array]:
        """The mask ``m`` in the backend of ``Pr`` and ``Pr_mm`` padded with the identity."""
        m = L.asarray(self.keep, Pr)
        return m, Pr * (m[..., :, None] * m[..., None, :]) + L.diag_embed(1.0 - m)

    def off_support(self, P: Array, e: Array) -> Array:
        """Boolean ``(...)``: the deviation ``e`` ``(..., n)`` leaves the support of ``P``."""
        q, Pr = self._rot(P)
        er = e if q is None else (L.mT(q) @ e[..., None])[..., 0]
        r = er - (Pr @ self._solve(Pr, er[..., None]))[..., 0]
        bad = L.asarray(1.0 - self.keep, e)
        size = L.where((e * e).sum(-1) > 1.0, (e * e).sum(-1), 1.0) ** 0.5
        tol = L.asarray(3.0 * self.var**0.5, e) + self.eps**0.5 * size[..., None]
        return (bad * (r * r - tol * tol) > 0).any(-1)

    def log_pdet(self, P: Array, A: Array | None = None) -> Array:
        """Log of the pseudo-determinant of ``P`` (the product of its nonzero eigenvalues), or
        of ``A P A^T`` for an invertible ``A``. With ``P' = B P'_mm B^T``, ``B = P' G'``
        (identity on the kept rows): ``pdet(A Q P' Q^T A^T) = det P'_mm det(C^T C)``,
        ``C = A Q B`` (without ``A``: ``C^T C = I + W^T W``, ``W`` the degenerate rows of
        ``B``)."""
        n = int(P.shape[-1])
        q, Pr = self._rot(P)
        m, Pm = self._block(Pr)
        B = (Pr @ self._solve(Pr, L.eye(n, Pr))) * m[..., None, :]
        C = B if A is None else (A if q is None else A @ q) @ B
        return L.slogdet(Pm)[1] + L.slogdet(L.mT(C) @ C + L.diag_embed(1.0 - m))[1]


# ---------------------------------------------------------------------------- vector Gaussian


class VectorGaussian:
    """A Gaussian in ``R^n``.

    The result of pushing a group Gaussian into a vector space (:meth:`Gaussian.act`,
    :meth:`Gaussian.log`, :func:`propagate` with an array value); also the input type of
    :meth:`Gaussian.from_tangent` and :meth:`Gaussian.plus`. There is no frame in ``R^n``.

    Parameters
    ----------
    mean : array_like
        ``(*batch, n)``.
    cov : array_like
        ``(*batch, n, n)``.
    validate : bool
        Check the covariance (finite, symmetric, positive semi-definite).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import VectorGaussian
    >>> v = VectorGaussian(np.zeros(2), np.diag([4.0, 1.0]))
    >>> float(v.mahalanobis(np.array([2.0, 0.0])))
    1.0
    """

    __slots__ = ("mean", "cov", "_null")
    mean: Array
    cov: Array
    _null: Any

    def __init__(self, mean: Any, cov: Any, *, validate: bool = True) -> None:
        m = A.as_float_array(mean)
        if m.ndim < 1:
            raise ValueError("the mean of a VectorGaussian must have shape (..., n)")
        _check_finite(m, "VectorGaussian mean")
        P = _as_array(cov, m, "VectorGaussian covariance")
        full = False
        if validate:
            full = check_covariance(P, m.shape[-1], "VectorGaussian covariance")
        else:
            A.check_last_dim(P, (m.shape[-1], m.shape[-1]), "VectorGaussian covariance")
        self._init(*_broadcast_pair(L.copy(m), L.copy(P)))
        if full:
            object.__setattr__(self, "_null", None)

    @classmethod
    def _make(cls, mean: Array, cov: Array) -> VectorGaussian:
        obj = object.__new__(cls)
        obj._init(mean, cov)
        return obj

    def _init(self, mean: Array, cov: Array) -> None:
        object.__setattr__(self, "mean", L.readonly(mean))
        object.__setattr__(self, "cov", cov if cov is None else L.readonly(cov))
        object.__setattr__(self, "_null", _UNSET)
        L.activate_pytrees(mean)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("VectorGaussian objects are immutable")

    def __reduce__(self):
        return (VectorGaussian._make, (self.mean, self.cov))

    @property
    def dim(self) -> int:
        return int(self.mean.shape[-1])

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.mean.shape[:-1])

    def __getitem__(self, index: Any) -> VectorGaussian:
        index = index if isinstance(index, tuple) else (index,)
        return VectorGaussian._make(self.mean[index + (slice(None),)],
                                    self.cov[index + (slice(None), slice(None))])

    def __repr__(self) -> str:
        return f"VectorGaussian(dim={self.dim}, batch_shape={self.batch_shape})"

    def std(self) -> Array:
        """Marginal standard deviations, ``sqrt(diag(cov))``.

        Returns
        -------
        array
            ``(*batch, n)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import VectorGaussian
        >>> v = VectorGaussian(np.array([1.0, 2.0, 3.0]), np.diag([4.0, 1.0, 0.25]))
        >>> v.std().tolist()
        [2.0, 1.0, 0.5]
        """
        return L.diag(self.cov) ** 0.5

    def marginal(self, indices: Sequence[int]) -> VectorGaussian:
        """The marginal over the coordinates ``indices`` (e.g. ``(0, 1)`` for x and y).

        Parameters
        ----------
        indices : sequence of int
            The kept coordinates, in order.

        Returns
        -------
        VectorGaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import VectorGaussian
        >>> v = VectorGaussian(np.array([1.0, 2.0, 3.0]), np.diag([4.0, 1.0, 0.25]))
        >>> m = v.marginal([2, 0])
        >>> m.mean.tolist(), np.diag(m.cov).tolist()
        ([3.0, 1.0], [0.25, 4.0])
        """
        idx = [int(i) for i in indices]
        return VectorGaussian._make(self.mean[..., idx], self.cov[..., idx, :][..., :, idx])

    def sample(self, n: int | tuple[int, ...], rng: Any = None) -> Array:
        """``n`` samples drawn with a NumPy generator.

        Parameters
        ----------
        n : int or tuple of int
            The sample shape.
        rng : int or numpy.random.Generator, optional
            The random source.

        Returns
        -------
        array
            ``(*n, *batch, dim)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import VectorGaussian
        >>> v = VectorGaussian(np.zeros(3), np.eye(3))
        >>> v.sample(5, rng=0).shape
        (5, 3)
        """
        z = _standard_normal(n, (*self.batch_shape, self.dim), rng, self.mean)
        return self.mean + (_cov_factor(self) @ z[..., None])[..., 0]

    def mahalanobis(self, x: Any, squared: bool = False) -> Array:
        """Mahalanobis distance ``sqrt((x - m)^T P^-1 (x - m))``.

        Parameters
        ----------
        x : array_like
            ``(*batch, n)`` points.
        squared : bool
            Without the square root (chi-square with ``dim`` degrees of freedom under the model).

        Returns
        -------
        array
            Shape ``batch``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import VectorGaussian
        >>> v = VectorGaussian(np.array([1.0, 2.0, 3.0]), np.diag([4.0, 1.0, 0.25]))
        >>> float(v.mahalanobis(np.array([3.0, 2.0, 3.5]), squared=True))
        2.0
        """
        d = _as_array(x, self.mean, "x") - self.mean
        return _mahalanobis(d, self.cov, squared, _rank(self))

    def log_density(self, x: Any) -> Array:
        """``log N(x; mean, cov)`` (the covariance must be positive definite).

        Parameters
        ----------
        x : array_like
            ``(*batch, n)`` points.

        Returns
        -------
        array
            Shape ``batch``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import VectorGaussian
        >>> v = VectorGaussian(np.array([1.0, 2.0, 3.0]), np.diag([4.0, 1.0, 0.25]))
        >>> expected = -0.5 * np.log(np.linalg.det(2 * np.pi * v.cov))
        >>> bool(np.isclose(v.log_density(v.mean), expected))
        True
        """
        d = _as_array(x, self.mean, "x") - self.mean
        return _log_normal(d, self.cov, _rank(self))

    def ellipse(self, nsigma: float = 2.0, num: int = 64, dims: tuple[int, int] = (0, 1)
                ) -> Array:
        """Points on the ``nsigma`` contour of the 2-D marginal over ``dims`` (for plotting; no
        matplotlib needed).

        Parameters
        ----------
        nsigma : float
            The contour's Mahalanobis radius.
        num : int
            Number of points.
        dims : tuple of int
            The two coordinates.

        Returns
        -------
        array
            ``(*batch, num, 2)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import VectorGaussian
        >>> VectorGaussian(np.zeros(2), np.eye(2)).ellipse(1.0, num=4).round(12).tolist()
        [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [-0.0, -1.0]]
        """
        g = self.marginal(dims)
        t = np.linspace(0.0, 2.0 * np.pi, num, endpoint=False)
        circle = A.as_float_array(np.stack([np.cos(t), np.sin(t)], -1), like=g.mean)
        S = L.sqrt_psd(g.cov)
        return g.mean[..., None, :] + nsigma * (circle @ L.mT(S))


# ---------------------------------------------------------------------------- group Gaussian


class Gaussian:
    """A Gaussian on a Lie group with an explicit error frame.

    ``frame="right"``: ``X = mean Exp(eps)`` (local error); ``frame="left"``:
    ``X = Exp(eps) mean`` (global error); ``eps ~ N(0, cov)``, tangent translation first.
    ``mean`` and ``cov`` broadcast over the leading batch axes; any array backend of the core
    works (NumPy, PyTorch, JAX).

    Parameters
    ----------
    mean : LieGroup
        The mean element (any batch shape).
    cov : array_like
        ``(*batch, dof, dof)`` covariance of ``eps``.
    frame : {"right", "left"}
        The error frame; no default on purpose.
    validate : bool
        Check the covariance: shape, finite, symmetric and positive semi-definite to
        ``sqrt(eps)`` of its dtype (``ValueError``); ``False`` keeps only the shape check.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3, Gaussian
    >>> X = Gaussian(SE3.identity(), 0.01 * np.eye(6), frame="right")
    >>> X.to_frame("left").frame
    'left'
    """

    __slots__ = ("mean", "cov", "frame", "_null")
    mean: LieGroup
    cov: Array
    frame: Frame
    _null: Any

    def __init__(self, mean: LieGroup, cov: Any, *, frame: Frame,
                 validate: bool = True) -> None:
        if not isinstance(mean, LieGroup):
            raise TypeError(f"the mean must be a group element, got {type(mean).__name__}")
        _check_frame(frame)
        P = _as_array(cov, mean.params, f"{type(mean).__name__} Gaussian covariance")
        what = f"{type(mean).__name__} Gaussian covariance"
        full = False
        if validate:
            full = check_covariance(P, mean.dof, what, _unit_blocks(type(mean)))
            full = full and frame == "right"  # the rank is decided in the right frame
        else:
            A.check_last_dim(P, (mean.dof, mean.dof), what)
        params, P = _broadcast_pair(mean.params, L.copy(P))
        self._init(_element(mean, params), P, frame)
        if full:  # the rank is known from the validation
            object.__setattr__(self, "_null", None)

    @classmethod
    def _make(cls, mean: LieGroup, cov: Array, frame: Frame) -> Gaussian:
        obj = object.__new__(cls)
        obj._init(mean, cov, frame)
        return obj

    def _init(self, mean: LieGroup, cov: Array, frame: Frame) -> None:
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", cov if cov is None else L.readonly(cov))
        object.__setattr__(self, "frame", frame)
        object.__setattr__(self, "_null", _UNSET)
        L.activate_pytrees(cov)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Gaussian objects are immutable")

    def __reduce__(self):
        return (Gaussian._make, (self.mean, self.cov, self.frame))

    @classmethod
    def from_std(cls, mean: LieGroup, std: Any, *, frame: Frame) -> Gaussian:
        """A Gaussian with diagonal covariance ``diag(std**2)``.

        Parameters
        ----------
        mean : LieGroup
            The mean.
        std : array_like
            ``(..., dof)`` standard deviations, tangent order (translation first).
        frame : {"right", "left"}
            The error frame.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> from microlie import SE2, Gaussian
        >>> Gaussian.from_std(SE2.identity(), [0.1, 0.1, 0.01], frame="left").cov.diagonal()
        array([0.01  , 0.01  , 0.0001])
        """
        s = _as_array(std, mean.params, "std")
        A.check_last_dim(s, mean.dof, "std")
        return cls(mean, L.diag_embed(s**2), frame=frame)

    # ------------------------------------------------------------------ container protocol
    @property
    def group(self) -> type[LieGroup]:
        return type(self.mean)

    @property
    def dof(self) -> int:
        return self.mean.dof

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.mean.batch_shape

    def __len__(self) -> int:
        return len(self.mean)

    def __getitem__(self, index: Any) -> Gaussian:
        index = index if isinstance(index, tuple) else (index,)
        return Gaussian._make(self.mean[index], self.cov[index + (slice(None), slice(None))],
                              self.frame)

    def __repr__(self) -> str:
        return (f"Gaussian({self.group.__name__}, frame={self.frame!r}, "
                f"batch_shape={self.batch_shape})")

    # ------------------------------------------------------------------ frames
    def frame_map(self, frame: Frame) -> Array:
        """The matrix ``T`` taking this Gaussian's error to the error in ``frame``
        (``eps_frame = T eps_self``): ``Ad_mean`` right to left, ``Ad_mean^-1`` left to right,
        identity for the same frame.

        Parameters
        ----------
        frame : {"right", "left"}
            The target frame.

        Returns
        -------
        array
            ``(*batch, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> bool(np.allclose(g.frame_map("left"), g.mean.adjoint()))
        True
        """
        _check_frame(frame)
        if frame == self.frame:
            return L.eye(self.dof, self.cov, self.cov.shape[:-2])
        if frame == "left":
            return self.mean.adjoint()
        return self.mean.inverse().adjoint()

    def to_frame(self, frame: Frame) -> Gaussian:
        """The same distribution with its error in ``frame``: ``P_left = Ad P_right Ad^T`` and
        ``P_right = Ad^-1 P_left Ad^-T`` (``Ad = Ad_mean``). Exact: ``mean Exp(e) =
        Exp(Ad e) mean`` holds for every ``e``.

        Parameters
        ----------
        frame : {"right", "left"}
            The target frame.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3, Gaussian
        >>> X = Gaussian(SO3.exp([0.0, 0.0, np.pi / 2]), np.diag([1.0, 0.0, 0.0]), frame="right")
        >>> X.to_frame("left").cov.round(12) + 0.0   # body x-axis error = world y-axis error
        array([[0., 0., 0.],
               [0., 1., 0.],
               [0., 0., 0.]])
        """
        if _check_frame(frame) == self.frame:
            return self
        T = self.frame_map(frame)
        return Gaussian._make(self.mean, L.symmetrize(T @ self.cov @ L.mT(T)), frame)

    # ------------------------------------------------------------------ errors and samples
    def error(self, X: LieGroup) -> Array:
        """The tangent error of ``X`` in this frame: ``Log(mean^-1 X)`` (right) or
        ``Log(X mean^-1)`` (left); the inverse of :meth:`retract`.

        Parameters
        ----------
        X : LieGroup
            An element of the mean's group (broadcast over the batch).

        Returns
        -------
        array
            ``(*batch, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> np.round(g.error(g.retract([0.1, 0.0, 0.2])), 12).tolist()
        [0.1, 0.0, 0.2]
        """
        self._same_group(X)
        return X.minus(self.mean) if self.frame == "right" else X.lminus(self.mean)

    def retract(self, eps: Any) -> LieGroup:
        """The element with error ``eps`` in this frame: ``mean Exp(eps)`` (right) or
        ``Exp(eps) mean`` (left).

        Parameters
        ----------
        eps : array_like
            ``(*batch, dof)`` tangent error.

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> bool(np.allclose(g.retract([0.0, 0.0, 0.0]).params, g.mean.params))
        True
        """
        return self.mean.plus(eps) if self.frame == "right" else self.mean.lplus(eps)

    def sample(self, n: int | tuple[int, ...], rng: Any = None) -> LieGroup:
        """``n`` samples ``retract(eps_i)``, ``eps_i ~ N(0, cov)``.

        Parameters
        ----------
        n : int or tuple of int
            The sample shape.
        rng : int or numpy.random.Generator, optional
            The random source.

        Returns
        -------
        LieGroup
            Batch shape ``(*n, *batch)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3, Gaussian
        >>> Gaussian(SO3.identity(), 0.01 * np.eye(3), frame="left").sample(4, rng=0).batch_shape
        (4,)
        """
        z = _standard_normal(n, (*self.batch_shape, self.dof), rng, self.cov)
        return self.retract((_cov_factor(self) @ z[..., None])[..., 0])

    def mahalanobis(self, X: LieGroup, squared: bool = False) -> Array:
        """Mahalanobis distance of ``X`` from the mean, ``sqrt(e^T P^-1 e)`` with ``e =``
        :meth:`error` ``(X)`` in this frame (frame-independent, since the frames differ by the
        exact linear map ``Ad``: computed in the right frame, where the rank of a singular
        ``P`` is decided, so both frames give the same value).

        Parameters
        ----------
        X : LieGroup
            An element of the mean's group (broadcast over the batch).
        squared : bool
            Return ``e^T P^-1 e`` (chi-square with ``dof`` degrees of freedom under the model).

        Returns
        -------
        array
            Shape ``batch``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> round(float(g.mahalanobis(g.retract([0.2, 0.0, 0.0]))), 12)  # 0.2 / 0.2
        1.0
        """
        P, T = _canonical(self)
        return _mahalanobis(_apply(T, self.error(X)), P, squared, _rank(self, (P, T)))

    def log_density(self, X: LieGroup, haar: bool = False) -> Array:
        """Log-density of ``X``: ``log N(e; 0, P)`` with ``e =`` :meth:`error` ``(X)``.

        This is the density of the tangent error (a "concentrated Gaussian"). With ``haar=True``
        it becomes a density on the group with respect to the Haar measure (left-invariant for a
        right error, right-invariant for a left error, normalised to the Lebesgue measure of the
        tangent space at the identity): ``- log |det Jr(e)|`` (right) or ``- log |det Jl(e)|``
        (left) is added. Frame-independent up to that measure.

        Parameters
        ----------
        X : LieGroup
            An element of the mean's group (broadcast over the batch).
        haar : bool
            The density with respect to the Haar measure instead of the tangent error's.

        Returns
        -------
        array
            Shape ``batch``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> P = np.diag([0.04, 0.01, 0.0025])
        >>> expected = -0.5 * np.log(np.linalg.det(2 * np.pi * P))
        >>> bool(np.isclose(g.log_density(g.mean), expected))
        True
        """
        e = self.error(X)
        P, T = _canonical(self)
        out = _log_normal(_apply(T, e), P, _rank(self, (P, T)), self.cov,
                          None if T is None else self.mean.adjoint())  # T^-1
        if haar:
            J = self.group.jr(e) if self.frame == "right" else self.group.jl(e)
            out = out - L.slogdet(J)[1]
        return out

    # ------------------------------------------------------------------ propagation
    def propagate(self, value: LieGroup | Array, jacobian: Any, *, side: Frame
                  ) -> Gaussian | VectorGaussian:
        """Linearised distribution of ``value = f(X)`` (eq. 16): ``P_y = J P J^T``.

        This Gaussian is converted to ``side`` first, and a group result is returned in frame
        ``side``. See :func:`propagate` for several inputs.

        Parameters
        ----------
        value : LieGroup or array
            ``f(mean)``.
        jacobian : array_like
            ``d f / d X`` with perturbations on ``side`` for the input and, for a group-valued
            ``f``, the output (``side="right"``: ``f(X Exp(e)) = f(X) Exp(J e)``; ``side="left"``:
            ``f(Exp(e) X) = Exp(J e) f(X)``).
        side : {"right", "left"}
            The perturbation side of ``jacobian``.

        Returns
        -------
        Gaussian or VectorGaussian
            A :class:`Gaussian` for a group ``value``, else a :class:`VectorGaussian`.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3, Gaussian
        >>> X = Gaussian(SO3.exp([0.1, 0.2, 0.3]), 1e-3 * np.eye(3), frame="right")
        >>> Y, J = X.mean.inverse(jac=True)         # right Jacobian of the inverse: -Ad_X
        >>> X.propagate(Y, J, side="right").frame
        'right'
        """
        return propagate(value, [self], [jacobian], side=side)

    def inverse(self) -> Gaussian:
        """Distribution of ``X^-1`` in this frame. Right: ``P = Ad_X P Ad_X^T``; left:
        ``P = Ad_X^-1 P Ad_X^-T`` (both exact: the error maps linearly).

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> A = g.mean.adjoint()
        >>> bool(np.allclose(g.inverse().cov, A @ g.cov @ A.T))
        True
        """
        Y, J = self.mean.inverse(jac=True, side=self.frame)
        return propagate(Y, [self], [J], side=self.frame)

    def compose(self, other: Gaussian | LieGroup, cross_cov: Any = None) -> Gaussian:
        """Distribution of ``X Y`` (``other`` is ``Y``), in this Gaussian's frame (eq. 17).

        Right frame: ``P_Z = Ad_Y^-1 P_X Ad_Y^-T + P_Y``; left frame:
        ``P_Z = P_X + Ad_X P_Y Ad_X^T``.

        Parameters
        ----------
        other : Gaussian or LieGroup
            ``Y``; a Gaussian in the other frame is converted first; a plain element is exact
            (zero covariance).
        cross_cov : array_like, optional
            ``E[eps_X eps_Y^T]`` with each error in its own Gaussian's frame; adds
            ``J_X C J_Y^T + J_Y C^T J_X^T``. ``ValueError`` unless
            ``[[P_X, C], [C^T, P_Y]]`` is positive semi-definite (see :func:`propagate`).

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> Z = g.compose(g)
        >>> Ai = g.mean.inverse().adjoint()
        >>> bool(np.allclose(Z.cov, Ai @ g.cov @ Ai.T + g.cov))
        True
        """
        Y = self._operand(other)
        Z, JX, JY = self.mean.compose(Y.mean, jac=True, side=self.frame)
        return self._binary(Z, JX, JY, Y, cross_cov)

    def between(self, other: Gaussian | LieGroup, cross_cov: Any = None) -> Gaussian:
        """Distribution of ``X^-1 Y`` (``other`` is ``Y``), in this Gaussian's frame. Right:
        ``J_X = -Ad_(Y^-1 X)``, ``J_Y = I``.

        Parameters
        ----------
        other : Gaussian or LieGroup
            ``Y``.
        cross_cov : array_like, optional
            As in :meth:`compose` (for two poses with a joint covariance, this is their
            relative-pose uncertainty); validated the same way.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> D = g.between(g.mean)  # the mean itself is exact: only X's error remains
        >>> bool(np.allclose(D.cov, g.cov))
        True
        """
        Y = self._operand(other)
        Z, JX, JY = self.mean.between(Y.mean, jac=True, side=self.frame)
        return self._binary(Z, JX, JY, Y, cross_cov)

    def act(self, points: Any, points_cov: Any = None, cross_cov: Any = None
            ) -> VectorGaussian:
        """Distribution of the moved points ``X . p`` in ``R^n`` (world coordinates).

        Without point noise ``P_p' = J_X P J_X^T`` with ``J_X`` the point Jacobian of this
        frame's side (SE(3) right: ``[R, -R hat(p)]``; left: ``[I, -hat(X p)]``).

        Parameters
        ----------
        points : array_like or VectorGaussian
            ``(..., point_dim)`` points, or a :class:`VectorGaussian` of them.
        points_cov : array_like, optional
            Their covariance (instead of a VectorGaussian).
        cross_cov : array_like, optional
            ``E[eps_X dp^T]`` (``eps_X`` in this frame).

        Returns
        -------
        VectorGaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> p = g.act(np.array([0.0, 0.0]))  # the position: x and y variances, rotated
        >>> np.round(p.mean, 12).tolist(), round(float(np.trace(p.cov)), 12)
        ([1.0, 2.0], 0.05)
        """
        pts = self._vector(points, points_cov, self.group.point_dim, "points")
        out, JX, Jp = self.mean.act(pts.mean, jac=True, side=self.frame)
        inputs: list[Gaussian | VectorGaussian] = [self]
        jacs = [JX]
        if not _is_zero(pts):
            inputs.append(pts)
            jacs.append(Jp)
        return cast(VectorGaussian, propagate(
            out, inputs, jacs, side=self.frame,
            cross_cov=None if cross_cov is None else {(0, 1): cross_cov}))

    def log(self) -> VectorGaussian:
        """Distribution of ``Log(X)`` in ``R^dof``: ``J = Jr^-1(Log mean)`` (right frame) or
        ``Jl^-1(Log mean)`` (left frame).

        Returns
        -------
        VectorGaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> L = g.log()
        >>> J = SE2.jr_inv(g.mean.log())
        >>> bool(np.allclose(L.cov, J @ g.cov @ J.T))
        True
        """
        tau, J = self.mean.log(jac=True, side=self.frame)
        return cast(VectorGaussian, propagate(tau, [self], [J], side=self.frame))

    @classmethod
    def from_tangent(cls, group: type[LieGroup], mean: Any, cov: Any = None, *,
                     frame: Frame) -> Gaussian:
        """Distribution of ``Exp(tau)`` for ``tau ~ N(mean, cov)``: mean ``Exp(mean)``, covariance
        ``Jr P Jr^T`` (right frame) or ``Jl P Jl^T`` (left frame), at ``mean``.

        Parameters
        ----------
        group : type
            The :class:`~microlie.LieGroup` subclass.
        mean : array_like or VectorGaussian
            The tangent mean (a VectorGaussian carries its covariance; then ``cov`` is omitted).
        cov : array_like, optional
            ``(*batch, dof, dof)``.
        frame : {"right", "left"}
            The error frame of the result.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3, Gaussian
        >>> g = Gaussian.from_tangent(SO3, [0.0, 0.0, 0.0], 1e-2 * np.eye(3), frame="right")
        >>> bool(np.allclose(g.cov, 1e-2 * np.eye(3)))     # Jr(0) = I
        True
        """
        _check_frame(frame)
        t = _vector_input(mean, cov, group.dof, "tangent", None)
        X, J = group.exp(t.mean, jac=True, side=frame)
        return propagate(X, [t], [J], side=frame)

    def plus(self, tau: Any, tau_cov: Any = None, cross_cov: Any = None) -> Gaussian:
        """Distribution of ``X (+) tau = X Exp(tau)`` with tangent noise ``tau ~ N(tau, tau_cov)``
        (a motion model step), in this frame. Right: ``P = Ad_Exp(tau)^-1 P Ad^-T
        + Jr(tau) Q Jr(tau)^T``.

        Parameters
        ----------
        tau : array_like or VectorGaussian
            The step (a VectorGaussian carries its covariance).
        tau_cov : array_like, optional
            ``Q``, the step's covariance.
        cross_cov : array_like, optional
            ``E[eps_X dtau^T]``.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> step = np.array([1.0, 0.0, 0.0])
        >>> out = g.plus(step, 0.01 * np.eye(3))
        >>> bool(np.allclose(out.mean.params, g.mean.plus(step).params))
        True
        """
        t = self._vector(tau, tau_cov, self.dof, "tau")
        Z, JX, Jt = self.mean.plus(t.mean, jac=True, side=self.frame)
        return self._binary(Z, JX, Jt, t, cross_cov)

    def lplus(self, tau: Any, tau_cov: Any = None, cross_cov: Any = None) -> Gaussian:
        """Distribution of ``tau (+) X = Exp(tau) X`` with tangent noise ``tau ~ N(tau,
        tau_cov)`` (a step applied in the world frame), in this frame. Left:
        ``P = Ad_Exp(tau) P Ad_Exp(tau)^T + Jl(tau) Q Jl(tau)^T``.

        Parameters
        ----------
        tau : array_like or VectorGaussian
            The step.
        tau_cov : array_like, optional
            Its covariance.
        cross_cov : array_like, optional
            ``E[eps_X dtau^T]``.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.from_xy_theta(1.0, 2.0, 0.5), np.diag([0.04, 0.01, 0.0025]),
        ...              frame="right")
        >>> out = g.lplus(np.array([0.0, 0.0, 0.1]), 1e-4 * np.eye(3))
        >>> bool(np.allclose(out.mean.params, g.mean.lplus([0.0, 0.0, 0.1]).params))
        True
        """
        t = self._vector(tau, tau_cov, self.dof, "tau")
        Z, JX, Jt = self.mean.lplus(t.mean, jac=True, side=self.frame)
        return self._binary(Z, JX, Jt, t, cross_cov)

    # ------------------------------------------------------------------ estimation
    def update(self, residual: Any, H: Any, R: Any, *, reset: bool = True) -> Gaussian:
        """Error-state Kalman update with a linear(ised) measurement of the error.

        Model: ``residual = z - h(mean) ~= H eps + v``, ``v ~ N(0, R)``, ``eps`` this Gaussian's
        error in its frame (so ``H`` is the Jacobian of ``h`` on this frame's side). Computes
        ``K = P H^T S^-1`` with ``S = H P H^T + R``, ``d = K residual``, the Joseph-form
        covariance ``(I - K H) P (I - K H)^T + K R K^T``, and the new mean ``retract(d)``.

        Rank-deficient ``P`` and ``R`` are handled exactly: when ``S`` is singular (the rank
        rule of docs/uncertainty.md, tolerance :data:`RANK_RTOL`, independent of units) a
        generalised inverse is used, so ``d`` stays in the range of ``P H^T`` (the mean never
        moves along a zero-variance direction), and a residual that has a component where
        ``S`` has zero variance (the measurement contradicts what both sides hold certain)
        raises ``ValueError``. Under ``jax.jit`` with a traced covariance the rank cannot be
        read: ``S`` must then be invertible.

        Parameters
        ----------
        residual : array_like
            ``(*batch, m)``, ``z - h(mean)``.
        H : array_like
            ``(*batch, m, dof)`` measurement Jacobian on this frame's side.
        R : array_like
            ``(*batch, m, m)`` measurement covariance (checked like every covariance).
        reset : bool
            Move the covariance to the new mean's error: ``Jr(d) P Jr(d)^T`` (right) or
            ``Jl(d) P Jl(d)^T`` (left), since ``mean Exp(d + x) ~= mean Exp(d) Exp(Jr(d) x)``.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> g = Gaussian(SE2.identity(), np.diag([1.0, 1.0, 0.0]), frame="right")  # exact heading
        >>> out = g.update([0.5, 0.0], np.eye(2, 3), np.eye(2), reset=False)
        >>> out.mean.log().round(12).tolist(), np.diag(out.cov).round(12).tolist()
        ([0.25, 0.0, 0.0], [0.5, 0.5, 0.0])
        """
        P = self.cov
        r = _as_array(residual, P, "residual")
        m = int(r.shape[-1])
        Hm = _as_array(H, P, "H")
        A.check_last_dim(Hm, (m, self.dof), "H")
        _check_finite(r, "residual")
        _check_finite(Hm, "H")
        Rm = _as_array(R, P, "R")
        check_covariance(Rm, m, "R")
        return self._kalman(r, Hm, Rm, reset, None, None, "update: the residual and the model")

    def fuse(self, other: Gaussian, *, reset: bool = True) -> Gaussian:
        """Fuse two independent Gaussians on the same element (the update of an error-state
        filter with ``H = I``), in this Gaussian's frame.

        ``other`` is relinearised onto this mean in the right (body) frame, whatever the
        frames: with ``d = other.mean (-) mean`` (right minus), ``X = other.mean Exp(e2)``
        gives ``e_r ~= d + Jr^-1(d) e2``, a measurement ``d`` of this Gaussian's right error
        ``e_r = T e`` (``T`` = :meth:`frame_map` ``("right")``) with covariance
        ``Jr^-1(d) P2 Jr^-T(d)``; then :meth:`update` with ``H = T``. The left-frame model
        is this one mapped exactly by ``Ad``, so the result does not depend on the frames, and
        the rank of ``S`` is decided in the right frame (see :class:`_Null`). First order in
        ``e2`` and ``d``: accurate when the two means agree to within a few standard
        deviations and the covariances are small.

        Rank-deficient covariances follow the rule of :meth:`update`: a Gaussian with
        zero-variance directions fused with itself returns its mean and half its covariance.
        Two estimates that differ along a direction in which both have zero variance (beyond
        rounding) have no common support: ``ValueError``, never a projection that would
        silently keep one side's value. The other's support, relinearised onto this mean, is
        tilted by ``O(|d|)``; the tiny variance this gives ``S`` counts as zero.

        Parameters
        ----------
        other : Gaussian
            Another estimate of the same element.
        reset : bool
            As in :meth:`update`.

        Returns
        -------
        Gaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2, Gaussian
        >>> a = Gaussian(SE2.identity(), np.eye(3), frame="right")
        >>> bool(np.allclose(a.fuse(a).cov, 0.5 * np.eye(3)))
        True
        """
        if not isinstance(other, Gaussian):
            raise TypeError(f"fuse needs a Gaussian, got {type(other).__name__}")
        self._same_group(other.mean)
        _same_backend(self.cov, other.cov)
        # the measurement is written in the right frame of this mean whatever the frames, so
        # the rank decision on S (and the result) does not depend on the frames
        o, T = other.to_frame("right"), self.frame_map("right")
        d = o.mean.minus(self.mean)
        Ji = self.group.jr_inv(d)
        R = L.symmetrize(Ji @ o.cov @ L.mT(Ji))
        mag = None
        M1, M2, Jn = _magnitude(self, T), _magnitude(other), L.concrete(Ji)
        if M1 is not None and M2 is not None and Jn is not None:
            Jn = np.abs(Jn)
            mag = M1 + Jn @ M2 @ np.swapaxes(Jn, -1, -2)
        return self._kalman(d, T, R, reset, _unit_blocks(self.group), mag,
                            "fuse: `other` and this Gaussian")

    def _kalman(self, r: Array, H: Array, R: Array, reset: bool,
                blocks: _Blocks | None, mag: np.ndarray | None,
                who: str) -> Gaussian:
        P = self.cov
        PHt = P @ L.mT(H)
        S = L.symmetrize(H @ PHt + R)
        null = _Null.of(S, blocks, mag)
        if null is None:
            K = L.mT(L.solve(S, L.mT(PHt)))
        else:
            off = L.concrete(null.off_support(S, r))
            if off is not None and off.any():
                raise ValueError(
                    f"{who} are incompatible: they differ along a direction in which both "
                    f"have zero variance (the residual is not in the range of "
                    f"S = H P H^T + R, so the product of the densities is empty). If the "
                    f"difference is noise, give that direction a variance in one of them")
            K = L.mT(null.pinv_solve(S, L.mT(PHt)))
        d = (K @ r[..., None])[..., 0]
        IKH = L.eye(self.dof, P) - K @ H
        Pn = IKH @ P @ L.mT(IKH) + K @ R @ L.mT(K)
        if reset:
            J = self.group.jr(d) if self.frame == "right" else self.group.jl(d)
            Pn = J @ Pn @ L.mT(J)
        return Gaussian._make(self.retract(d), L.symmetrize(Pn), self.frame)

    # ------------------------------------------------------------------ helpers
    def _same_group(self, X: Any) -> None:
        if type(X) is not self.group:
            raise TypeError(f"expected a {self.group.__name__}, got {type(X).__name__}")

    def _operand(self, other: Any) -> Gaussian:
        if isinstance(other, LieGroup):
            self._same_group(other)
            _same_backend(self.cov, other.params)
            return Gaussian._make(other, None, self.frame)  # exact element: no covariance
        if not isinstance(other, Gaussian):
            raise TypeError(f"expected a Gaussian or a {self.group.__name__}, "
                            f"got {type(other).__name__}")
        self._same_group(other.mean)
        _same_backend(self.cov, other.cov)
        return other

    def _vector(self, x: Any, cov: Any, n: int, what: str) -> VectorGaussian:
        v = _vector_input(x, cov, n, what, self.cov)
        _same_backend(self.cov, v.mean)
        return v

    def _binary(self, Z: Any, J1: Array, J2: Array, other: Any, cross_cov: Any):
        if _is_zero(other):
            if cross_cov is not None:
                raise ValueError("cross_cov given but the other operand has no covariance")
            return propagate(Z, [self], [J1], side=self.frame)
        return propagate(Z, [self, other], [J1, J2], side=self.frame,
                         cross_cov=None if cross_cov is None else {(0, 1): cross_cov})


# ---------------------------------------------------------------------------- propagation


@overload
def propagate(value: LieGroup, inputs: Sequence[Gaussian | VectorGaussian],
              jacobians: Sequence[Any], *, side: Frame,
              cross_cov: Mapping[tuple[int, int], Any] | None = None) -> Gaussian: ...
@overload
def propagate(value: Any, inputs: Sequence[Gaussian | VectorGaussian],
              jacobians: Sequence[Any], *, side: Frame,
              cross_cov: Mapping[tuple[int, int], Any] | None = None) -> VectorGaussian: ...
def propagate(value: LieGroup | Any, inputs: Sequence[Gaussian | VectorGaussian],
              jacobians: Sequence[Any], *, side: Frame,
              cross_cov: Mapping[tuple[int, int], Any] | None = None
              ) -> Gaussian | VectorGaussian:
    """Linearised distribution of ``value = f(x_0, x_1, ...)`` (eq. 16, several inputs).

    ``P = sum_i J_i P_i J_i^T + sum_(i,j) (J_i C_ij J_j^T + J_j C_ij^T J_i^T)``.

    Parameters
    ----------
    value : LieGroup or array
        ``f`` at the means. A group ``value`` gives a :class:`Gaussian` in frame ``side``; an
        array gives a :class:`VectorGaussian`.
    inputs : sequence of Gaussian or VectorGaussian
        The independent (unless ``cross_cov``) inputs. Group inputs in the other frame are
        converted exactly (``J_i Ad`` is used).
    jacobians : sequence of array_like
        ``jacobians[i]`` is ``d f / d x_i``, shape ``(*batch, m, dim_i)``; for group inputs and
        a group output the perturbations are on ``side`` (right: ``X Exp(e)``; left:
        ``Exp(e) X``).
    side : {"right", "left"}
        The perturbation side.
    cross_cov : mapping, optional
        ``cross_cov[(i, j)] = E[e_i e_j^T]`` (``i != j``), each error in its own input's frame.
        The joint covariance of the inputs they make must be positive semi-definite (smallest
        eigenvalue of its correlation matrix ``>= -sqrt(eps)``), else ``ValueError`` naming
        ``cross_cov``: an indefinite joint gives negative variances.

    Returns
    -------
    Gaussian or VectorGaussian

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2, Gaussian
    >>> from microlie.uncertainty import propagate
    >>> X = Gaussian(SE2.identity(), 0.01 * np.eye(3), frame="right")
    >>> Y = Gaussian(SE2.from_xy_theta(1.0, 0.0, 0.5), 0.02 * np.eye(3), frame="right")
    >>> Z, JX, JY = X.mean.compose(Y.mean, jac=True)
    >>> bool(np.allclose(propagate(Z, [X, Y], [JX, JY], side="right").cov, X.compose(Y).cov))
    True
    """
    _check_frame(side, "side")
    inputs, jacobians = list(inputs), list(jacobians)
    if len(inputs) != len(jacobians) or not inputs:
        raise ValueError(f"need one Jacobian per input, got {len(jacobians)} Jacobians for "
                         f"{len(inputs)} inputs")
    like = next((g.cov for g in inputs if getattr(g, "cov", None) is not None), None)
    if like is None:
        raise ValueError("no input has a covariance")
    if isinstance(value, LieGroup):
        m = value.dof
        ref = value.params
    else:
        value = L.copy(_as_array(value, like, "value"))
        m = int(value.shape[-1])
        ref = value
    eff = []
    for i, (g, J) in enumerate(zip(inputs, jacobians, strict=True)):
        if not isinstance(g, (Gaussian, VectorGaussian)):
            raise TypeError(f"input {i} must be a Gaussian or VectorGaussian, "
                            f"got {type(g).__name__}")
        n = g.dof if isinstance(g, Gaussian) else g.dim
        J = _as_array(J, ref, f"Jacobian {i}")
        A.check_last_dim(J, (m, n), f"Jacobian {i}")
        if isinstance(g, Gaussian) and g.frame != side:
            J = J @ g.frame_map(side)
        eff.append(J)
    P = None
    for g, J in zip(inputs, eff, strict=True):
        if g.cov is None:
            continue
        term = J @ g.cov @ L.mT(J)
        P = term if P is None else P + term
    cross = {}
    for (i, j), C in (cross_cov or {}).items():
        if i == j or not (0 <= i < len(inputs) and 0 <= j < len(inputs)):
            raise ValueError(f"cross_cov key {(i, j)} must name two different inputs")
        ni, nj = eff[i].shape[-1], eff[j].shape[-1]
        Cm = _as_array(C, ref, f"cross_cov[{(i, j)}]")
        A.check_last_dim(Cm, (ni, nj), f"cross_cov[{(i, j)}]")
        cross[(i, j)] = (Cm, _check_finite(Cm, f"cross_cov[{(i, j)}]"))
    if cross:
        _check_joint([g.cov for g in inputs], {k: c[1] for k, c in cross.items()})
    for (i, j), (Cm, _) in cross.items():
        term = eff[i] @ Cm @ L.mT(eff[j])
        P = P + term + L.mT(term)
    if P is None:
        raise ValueError("no input has a covariance")
    P = L.symmetrize(P)
    if isinstance(value, LieGroup):
        params, P = _broadcast_pair(value.params, P)
        return Gaussian._make(_element(value, params), P, side)
    mean, P = _broadcast_pair(value, P)
    return VectorGaussian._make(mean, P)


# ---------------------------------------------------------------------------- internals


def _check_joint(covs: Sequence[Array | None], cross: Mapping[tuple[int, int], Any]) -> None:
    """Raise ``ValueError`` unless the joint covariance of the inputs (``covs[i]`` on the
    diagonal, ``None`` = exact, ``cross[(i, j)]`` off it) is positive semi-definite: smallest
    eigenvalue of its correlation matrix (``D^-1 P D^-1``, ``D = sqrt(diag P)``; 1 where 0, so
    units do not matter) ``>= -sqrt(eps)``, as :func:`check_covariance`. Skipped under a
    trace (values unknown)."""
    vals = [None if c is None else L.concrete(c) for c in covs]
    if any(c is not None and v is None for c, v in zip(covs, vals, strict=True)) or \
            any(v is None for v in cross.values()):
        return
    ref = next(c for c in covs if c is not None)
    dims = [int(c.shape[-1]) if c is not None else 0 for c in covs]
    for (i, j), C in cross.items():  # exact inputs: their size from the cross-covariance
        dims[i], dims[j] = C.shape[-2], C.shape[-1]
    off = np.concatenate([[0], np.cumsum(dims)])
    mats = [v for v in vals if v is not None] + list(cross.values())
    batch = np.broadcast_shapes(*(m.shape[:-2] for m in mats))
    Jt = np.zeros((*batch, off[-1], off[-1]))
    for i, v in enumerate(vals):
        if v is not None:
            Jt[..., off[i]:off[i + 1], off[i]:off[i + 1]] = v
    for (i, j), C in cross.items():
        Jt[..., off[i]:off[i + 1], off[j]:off[j + 1]] += C
        Jt[..., off[j]:off[j + 1], off[i]:off[i + 1]] += np.swapaxes(C, -1, -2)
    d = np.diagonal(Jt, axis1=-2, axis2=-1)
    s = np.where(d > 0, np.sqrt(np.where(d > 0, d, 1.0)), 1.0)
    w = np.linalg.eigvalsh(Jt / (s[..., :, None] * s[..., None, :]))[..., 0]
    tol = math.sqrt(_eps(ref))
    if np.any(w < -tol):
        keys = ", ".join(f"cross_cov[{k}]" for k in cross)
        raise ValueError(
            f"{keys} makes the joint covariance [[P1, C], [C^T, P2]] of the inputs "
            f"indefinite (smallest eigenvalue of its correlation matrix {w.min():.3g} < "
            f"-{tol:.2g}): C = E[e1 e2^T] must come from a valid joint covariance (at least "
            f"|C_ij| <= sqrt(P1_ii P2_jj)); take it from the joint covariance of the inputs, "
            f"each error in its own Gaussian's frame")


def _broadcast_pair(v: Array, P: Array) -> tuple[Array, Array]:
    """Broadcast the batch axes of a vector ``(..., k)`` and a matrix ``(..., n, n)``."""
    batch = tuple(np.broadcast_shapes(tuple(v.shape[:-1]), tuple(P.shape[:-2])))
    return (L.broadcast_to(v, (*batch, v.shape[-1])), L.broadcast_to(P, (*batch, *P.shape[-2:])))


def _element(X: LieGroup, params: Array) -> LieGroup:
    """``X`` itself, or the element of its group with ``params`` (``X``'s broadcast)."""
    return X if params is X.params else type(X).from_params(params, check=False)


def _same_backend(a: Array, b: Array) -> None:
    if a is not None and b is not None and not L.same_backend(a, b):
        raise ValueError(f"cannot mix array backends: {type(a).__module__} and "
                         f"{type(b).__module__} (convert one Gaussian first)")


def _is_zero(g: Any) -> bool:
    return g.cov is None


def _vector_input(x: Any, cov: Any, n: int, what: str, like: Array | None) -> VectorGaussian:
    """A :class:`VectorGaussian` from a VectorGaussian, or from a mean and an optional cov (no
    cov: an exact value, marked by ``cov=None``)."""
    if isinstance(x, VectorGaussian):
        if cov is not None:
            raise ValueError(f"{what}: give a VectorGaussian or a mean and a covariance, not both")
        A.check_last_dim(x.mean, n, what)
        return x
    m = A.as_float_array(x) if like is None else _as_array(x, like, what)
    A.check_last_dim(m, n, what)
    _check_finite(m, what)
    if cov is None:
        return VectorGaussian._make(m, None)
    return VectorGaussian(m, cov)


def _standard_normal(n: int | tuple[int, ...], shape: tuple, rng: Any, like: Array) -> Array:
    size = (n,) if isinstance(n, (int, np.integer)) else tuple(n)
    return L.asarray(np.random.default_rng(rng).standard_normal((*size, *shape)), like)


_UNSET: Any = object()  # "rank not computed yet" (distinct from None: "full rank or unknown")


def _canonical(g: Gaussian) -> tuple[Array, Array | None]:
    """``(P_right, T)``: the covariance in the right (body) frame and the map ``T`` from this
    frame's error to it (``None`` for a right frame). Ranks and distances are decided there:
    the right error does not depend on where the world frame is, the left one does."""
    if g.frame == "right":
        return g.cov, None
    T = g.frame_map("right")
    return L.symmetrize(T @ g.cov @ L.mT(T)), T


def _apply(T: Array | None, e: Array) -> Array:
    return e if T is None else (T @ e[..., None])[..., 0]


def _magnitude(g: Gaussian, T: Array | None = None) -> np.ndarray | None:
    """``|T| |P| |T|^T`` (NumPy) for :func:`_canonical`'s ``T P T^T``: the scale of what rounded
    into each entry (``|P|`` for a right frame); ``None`` under a trace."""
    M = L.concrete(g.cov)
    if M is None:
        return None
    M = np.abs(M.astype(np.float64, copy=False))
    if g.frame == "right":
        return M
    Tn = L.concrete(g.frame_map("right") if T is None else T)
    if Tn is None:
        return None
    Tn = np.abs(Tn.astype(np.float64, copy=False))
    return Tn @ M @ np.swapaxes(Tn, -1, -2)


def _rank(g: Gaussian | VectorGaussian,
          canon: tuple[Array, Array | None] | None = None) -> _Null | None:
    """The zero-variance directions of ``g.cov`` (of a Gaussian: of its right-frame covariance,
    in unit blocks; ``canon``: :func:`_canonical` ``(g)`` if known), computed once per
    object."""
    null = g._null
    if null is _UNSET:
        if isinstance(g, Gaussian):
            P, T = _canonical(g) if canon is None else canon
            null = _Null.of(P, _unit_blocks(g.group), _magnitude(g, T))
        else:
            null = _Null.of(g.cov)
        object.__setattr__(g, "_null", null)
    return null


def _cov_factor(g: Gaussian | VectorGaussian) -> Array:
    """``S`` with ``S S^T = g.cov`` for sampling: the Cholesky factor when the covariance is
    known to have full rank (its gradient is finite where ``eigh``'s is not: repeated
    eigenvalues), else the symmetric square root from ``eigh`` (rank-deficient or traced)."""
    if L.concrete(g.cov) is None:
        return L.sqrt_psd(g.cov)
    if isinstance(g, Gaussian) and g.frame == "left":  # its own matrix, not the canonical one
        full = _Null.of(g.cov, _unit_blocks(g.group)) is None
    else:
        full = _rank(g) is None
    return L.cholesky(g.cov) if full else L.sqrt_psd(g.cov)


def _mahalanobis(e: Array, P: Array, squared: bool, null: _Null | None) -> Array:
    """``e^T P^-1 e`` (or its root); on a rank-deficient ``P`` (``null``, see :class:`_Null`)
    the pseudo-inverse on the support and ``inf`` off it."""
    if null is None:
        d2 = (e * L.solve(P, e[..., None])[..., 0]).sum(-1)
    else:
        d2 = (e * null.pinv_solve(P, e[..., None])[..., 0]).sum(-1)
        d2 = L.where(null.off_support(P, e), math.inf, d2)
    return d2 if squared else d2**0.5


def _log_normal(e: Array, P: Array, null: _Null | None, P0: Array | None = None,
                A: Array | None = None) -> Array:
    """``log N(e; 0, P)``; on a rank-deficient ``P`` the density on its support (w.r.t. the
    Lebesgue measure of the support, as SciPy's ``allow_singular=True``), ``-inf`` off it.
    With ``P = T P0 T^T`` and ``A = T^-1``: the density of ``A e`` under ``P0`` instead (the
    distance and the rank are read from ``P``, the volume from ``P0``)."""
    n = e.shape[-1]
    d2 = _mahalanobis(e, P, True, null)
    if null is None:
        return -0.5 * (d2 + n * _LOG_2PI + L.slogdet(P if P0 is None else P0)[1])
    rank = L.asarray(n - null.rank_loss, d2)
    return -0.5 * (d2 + rank * _LOG_2PI + null.log_pdet(P, A))


L.register_pytree(Gaussian, lambda g: ((g.mean, g.cov), g.frame),
                  lambda frame, ch: Gaussian._make(ch[0], ch[1], frame))
L.register_pytree(VectorGaussian, lambda g: ((g.mean, g.cov), None),
                  lambda _, ch: VectorGaussian._make(ch[0], ch[1]))
