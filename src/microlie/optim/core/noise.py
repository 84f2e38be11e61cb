"""Noise models: the weight of a residual, stored as a square-root information matrix.

Every model reduces to ``L`` with ``L^T L = Omega`` (the information, inverse covariance); the
solver whitens ``e = L r``, ``A = L J`` and minimises ``0.5 * sum |e|^2 = 0.5 * sum r^T Omega r``
(GTSAM's cost). ``L`` is one ``(d, d)`` matrix shared by all factors of a batch, or a stack
``(m, d, d)`` with one per factor. A matrix that is not symmetric positive definite is a
``ValueError`` naming the model (and the first offending factor).

>>> import numpy as np
>>> n = Covariance(np.diag([4.0, 1.0]))
>>> np.allclose(n.information, np.diag([0.25, 1.0]))
True
"""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np

__all__ = ["NoiseModel", "Information", "SqrtInformation", "Covariance", "Diagonal",
           "Isotropic", "Unit", "as_noise"]


def _stack(x: Any, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim < 2 or a.shape[-1] != a.shape[-2]:
        raise ValueError(f"{what} must be a square matrix (d, d) or a stack (m, d, d), "
                         f"got shape {a.shape}")
    if a.ndim > 3:
        raise ValueError(f"{what} must have shape (d, d) or (m, d, d), got {a.shape}")
    if not _finite(a):
        raise ValueError(f"{what} has non-finite entries")
    return a


def _finite(a: np.ndarray) -> bool:
    """Whether every entry is finite (Python floats for small arrays: a NumPy reduction costs
    more there)."""
    if a.size <= 100:
        return all(map(math.isfinite, a.ravel().tolist()))
    return bool(np.isfinite(a).all())


def _cholesky_checked(M: np.ndarray, what: str, upper: bool = False) -> np.ndarray:
    """Lower (``upper``: upper) Cholesky factor of each symmetric positive definite matrix, or
    a ValueError."""
    if M.shape[-1] <= 12 and (M.ndim == 2 or M.shape[0] <= 4):
        # one or a few small matrices (a factor that arrives alone): Python floats for the
        # symmetry check and LAPACK's potrf, far cheaper there than NumPy's batched calls
        if M.ndim == 2:
            return _cholesky_small(M, what, "", upper)
        return np.stack([_cholesky_small(Mk, what, f" (factor {k})", upper)
                         for k, Mk in enumerate(M)])
    C = _cholesky_stack(M, what)
    return np.swapaxes(C, -1, -2).copy() if upper else C


def _cholesky_small(M: np.ndarray, what: str, where: str, upper: bool) -> np.ndarray:
    """:func:`_cholesky_checked` of one ``(d, d)`` matrix (``where`` names it in errors)."""
    v = M.tolist()
    d = len(v)
    if not all(abs(v[i][j] - v[j][i]) <= 1e-9 * (1.0 + abs(v[i][j]))
               for i in range(d) for j in range(d) if i != j):
        raise ValueError(f"{what} is not symmetric{where}")
    c = _potrf(M, upper)
    if c is not None:
        return c
    ev = np.linalg.eigvalsh(M).min()
    raise ValueError(f"{what} is not positive definite{where}: smallest eigenvalue {ev:.3g}")


def _potrf(M: np.ndarray, upper: bool) -> np.ndarray | None:
    """The Cholesky factor of one small matrix, or ``None`` when it is not positive definite:
    LAPACK's ``dpotrf`` through SciPy when ``scipy.linalg`` is already imported (cheapest), else
    NumPy's (``microlie optimize`` with the compiled code never imports ``scipy.linalg``: it
    costs more than all the factors of a file)."""
    lapack = sys.modules.get("scipy.linalg.lapack")
    if lapack is not None:
        c, info = lapack.dpotrf(M, lower=0 if upper else 1, clean=1)
        return np.ascontiguousarray(c) if info == 0 else None
    try:
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return None
    return np.ascontiguousarray(L.T) if upper else L


def _cholesky_stack(M: np.ndarray, what: str) -> np.ndarray:
    """:func:`_cholesky_checked` of any stack: NumPy's batched factorisation."""
    sym = np.abs(M - np.swapaxes(M, -1, -2)) <= 1e-9 * (1.0 + np.abs(M))
    if not np.all(sym):
        bad = np.argwhere(~sym.reshape(-1, M.shape[-1] ** 2).all(-1)).ravel()
        where = f" (factor {int(bad[0])})" if M.ndim == 3 else ""
        raise ValueError(f"{what} is not symmetric{where}")
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        pass
    M3 = M.reshape(-1, *M.shape[-2:])
    for k in range(M3.shape[0]):
        try:
            np.linalg.cholesky(M3[k])
        except np.linalg.LinAlgError:
            where = f" (factor {k})" if M.ndim == 3 else ""
            ev = np.linalg.eigvalsh(M3[k]).min()
            raise ValueError(f"{what} is not positive definite{where}: smallest eigenvalue "
                             f"{ev:.3g}") from None
    raise AssertionError("unreachable")


class NoiseModel:
    """A Gaussian noise model, held as its square-root information ``sqrt_info`` (upper
    triangular ``L`` with ``L^T L = information``), shape ``(d, d)`` or ``(m, d, d)``.

    The properties ``information`` and ``covariance`` give ``L^T L`` and its inverse.

    Parameters
    ----------
    sqrt_info : array_like
        ``L``, one ``(d, d)`` matrix or a stack ``(m, d, d)`` (one per factor).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import NoiseModel
    >>> n = NoiseModel(np.diag([10.0, 2.0]))
    >>> n.dim, n.covariance.diagonal().tolist()
    (2, [0.01, 0.25])
    """

    sqrt_info: np.ndarray

    def __init__(self, sqrt_info: Any) -> None:
        self.sqrt_info = _stack(sqrt_info, type(self).__name__)

    @property
    def dim(self) -> int:
        return int(self.sqrt_info.shape[-1])

    @property
    def scales(self) -> np.ndarray | None:
        """The diagonal of ``sqrt_info``, ``(d,)`` or ``(m, d)``, when it is diagonal
        (isotropic or diagonal noise: whitening is then a scale), else ``None``.

        Examples
        --------
        >>> from microlie.optim import Diagonal, Information
        >>> Diagonal([0.5, 0.25]).scales.tolist(), Information([[2.0, 1.0], [1.0, 2.0]]).scales
        ([2.0, 4.0], None)
        """
        L = self.sqrt_info
        if "_scales" not in self.__dict__ or self.__dict__["_scales"][0] is not L:
            d = np.diagonal(L, axis1=-2, axis2=-1)
            diagonal = np.count_nonzero(L) == np.count_nonzero(d)
            self.__dict__["_scales"] = (L, d.copy() if diagonal else None)
        return self.__dict__["_scales"][1]

    @property
    def information(self) -> np.ndarray:
        L = self.sqrt_info
        return np.swapaxes(L, -1, -2) @ L

    @property
    def covariance(self) -> np.ndarray:
        return np.linalg.inv(self.information)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim}, shape={self.sqrt_info.shape})"


def _upper_sqrt(info: np.ndarray, what: str) -> np.ndarray:
    return _cholesky_checked(info, what, upper=True)  # L upper with L^T L = info


class Information(NoiseModel):
    """Full information matrix ``Omega`` (inverse covariance).

    Parameters
    ----------
    information : array_like
        ``(d, d)`` or ``(m, d, d)``, symmetric positive definite.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import Information
    >>> n = Information([[4.0, 1.0], [1.0, 2.0]])
    >>> bool(np.allclose(n.sqrt_info.T @ n.sqrt_info, [[4, 1], [1, 2]]))
    True
    """

    def __init__(self, information: Any) -> None:
        O = _stack(information, "Information")
        self.sqrt_info = _upper_sqrt(O, "the information matrix")  # finite, square: no _stack


class SqrtInformation(NoiseModel):
    """Square-root information ``L`` with ``L^T L = Omega`` (any square root, e.g. upper
    Cholesky); must be invertible.

    Parameters
    ----------
    sqrt_info : array_like
        ``(d, d)`` or ``(m, d, d)``.

    Examples
    --------
    >>> from microlie.optim import SqrtInformation
    >>> SqrtInformation([[2.0, 0.0], [0.0, 4.0]]).information.tolist()
    [[4.0, 0.0], [0.0, 16.0]]
    """

    def __init__(self, sqrt_info: Any) -> None:
        L = _stack(sqrt_info, "SqrtInformation")
        _cholesky_checked(np.swapaxes(L, -1, -2) @ L, "the square-root information matrix")
        super().__init__(L)


class Covariance(NoiseModel):
    """Covariance ``Sigma``; the information is ``Sigma^-1``.

    Parameters
    ----------
    covariance : array_like
        ``(d, d)`` or ``(m, d, d)``, symmetric positive definite.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import Covariance
    >>> S = [[0.04, 0.01], [0.01, 0.09]]
    >>> bool(np.allclose(Covariance(S).covariance, S))
    True
    """

    def __init__(self, covariance: Any) -> None:
        S = _stack(covariance, "Covariance")
        C = _cholesky_checked(S, "the covariance matrix")  # S = C C^T -> Omega = C^-T C^-1
        eye = np.broadcast_to(np.eye(S.shape[-1]), S.shape)
        super().__init__(np.linalg.solve(C, eye))  # L = C^-1, L^T L = S^-1


class Diagonal(NoiseModel):
    """Independent components with standard deviations ``sigmas``.

    Parameters
    ----------
    sigmas : array_like
        ``(d,)`` or ``(m, d)`` positive standard deviations.

    Examples
    --------
    >>> from microlie.optim import Diagonal
    >>> Diagonal([0.1, 0.5]).sqrt_info.diagonal().tolist()
    [10.0, 2.0]
    """

    def __init__(self, sigmas: Any) -> None:
        s = np.asarray(sigmas, dtype=np.float64)
        if s.ndim not in (1, 2) or not _finite(s):
            raise ValueError(f"Diagonal sigmas must be finite with shape (d,) or (m, d), "
                             f"got {s.shape}")
        if s.size and not float(s.min()) > 0:
            raise ValueError("Diagonal sigmas must be positive (the information would not be "
                             "positive definite)")
        if s.ndim == 1:
            self.sqrt_info = np.diag(1.0 / s)
            return
        L = np.zeros((*s.shape, s.shape[-1]))
        idx = np.arange(s.shape[-1])
        L[..., idx, idx] = 1.0 / s
        self.sqrt_info = L

    @classmethod
    def from_variances(cls, variances: Any) -> Diagonal:
        """The diagonal model of standard deviations ``sqrt(variances)``.

        Parameters
        ----------
        variances : array_like
            ``(d,)`` or ``(m, d)`` positive variances.

        Returns
        -------
        Diagonal

        Examples
        --------
        >>> from microlie.optim import Diagonal
        >>> Diagonal.from_variances([0.01, 0.25]).sqrt_info.diagonal().tolist()
        [10.0, 2.0]
        """
        v = np.asarray(variances, dtype=np.float64)
        if np.any(v <= 0):
            raise ValueError("Diagonal variances must be positive")
        return cls(np.sqrt(v))


class Isotropic(NoiseModel):
    """The same standard deviation ``sigma`` on all ``dim`` components.

    Parameters
    ----------
    dim : int
        The residual dimension.
    sigma : float
        The standard deviation.

    Examples
    --------
    >>> from microlie.optim import Isotropic
    >>> Isotropic(3, 0.5).information.diagonal().tolist()
    [4.0, 4.0, 4.0]
    """

    def __init__(self, dim: int, sigma: float) -> None:
        if not (np.isfinite(sigma) and sigma > 0):
            raise ValueError(f"Isotropic sigma must be positive and finite, got {sigma}")
        if int(dim) != dim or dim < 1:
            raise ValueError(f"Isotropic dim must be a positive integer, got {dim!r}")
        self.sqrt_info = np.eye(int(dim)) / float(sigma)


class Unit(Isotropic):
    """Unit noise (identity information).

    Parameters
    ----------
    dim : int
        The residual dimension.

    Examples
    --------
    >>> from microlie.optim import Unit
    >>> Unit(2).sqrt_info.tolist()
    [[1.0, 0.0], [0.0, 1.0]]
    """

    def __init__(self, dim: int) -> None:
        super().__init__(dim, 1.0)


def as_noise(noise: Any, dim: int, what: str) -> NoiseModel:
    """The noise model of a factor: ``None`` is unit noise; a NoiseModel is checked against the
    residual dimension.

    Parameters
    ----------
    noise : NoiseModel or None
        The model.
    dim : int
        The residual dimension.
    what : str
        The factor's name, for the error message.

    Returns
    -------
    NoiseModel

    Raises
    ------
    ValueError
        The model's dimension is not ``dim``.

    Examples
    --------
    >>> from microlie.optim import Diagonal
    >>> from microlie.optim.core.noise import as_noise
    >>> as_noise(None, 3, "prior").sqrt_info.tolist() == [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    True
    >>> as_noise(Diagonal([1.0, 2.0]), 2, "prior").dim
    2
    """
    if noise is None:
        return Unit(dim)
    if not isinstance(noise, NoiseModel):
        raise TypeError(f"{what}: noise must be a NoiseModel (Information, Covariance, ...), "
                        f"got {type(noise).__name__}")
    if noise.dim != dim:
        raise ValueError(f"{what}: noise model of dimension {noise.dim} for a residual of "
                         f"dimension {dim}")
    return noise
