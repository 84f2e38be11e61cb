"""What SE(2), SE(3) and Sim(3) share: parameters ``(translation, rotation[, scale])``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .. import _array as A
from .._array import Array
from .._kernels import run
from .base import LieGroup

if TYPE_CHECKING:
    from typing_extensions import Self


class Pose(LieGroup):
    """A group whose parameters start with a translation followed by a rotation's parameters."""

    _rotation: ClassVar[Any]  # SO2 or SO3
    _rotation_slice: ClassVar[slice]  # test fact: the rotation's entries of the tangent

    def __init_subclass__(cls, **kwargs: Any) -> None:
        # test fact: the rotation's entries of the tangent, right after the translation's
        rot = cls.__dict__.get("_rotation")
        if rot is not None and "_rotation_slice" not in cls.__dict__:
            cls._rotation_slice = slice(rot.point_dim, rot.point_dim + rot.dof)
        super().__init_subclass__(**kwargs)

    @classmethod
    def _exact_pi_element(cls) -> Pose:
        """An element whose rotation is by exactly pi (the rotation group's
        ``_exact_pi_element``, no rounding), every other part non-zero: ``Exp(tau) X_pi`` with
        ``tau`` zero on the rotation."""
        n, r = cls._dims()
        p = np.array(cls._identity_params)
        p[n:r] = cls._rotation._exact_pi_element().params  # type: ignore[attr-defined]
        tau = np.linspace(0.3, 1.1, cls.dof) * (-1.0) ** np.arange(cls.dof)
        tau[cls._rotation_slice] = 0.0
        return cls.exp(tau) @ cls(p)  # type: ignore[return-value]

    @classmethod
    def log_matrix(cls, matrix: Any) -> np.ndarray:
        """``Log`` of homogeneous matrices ``[[R, t], [0, 1]]`` as a NumPy array, **unchecked**.

        The fast path for callers whose matrices are products of the group's own matrices
        (many small batches, e.g. residuals in a search): unlike
        ``from_matrix(matrix).log()`` nothing is validated (``R`` is read as a rotation, the
        last row is ignored), so garbage in is garbage out. The result is the group's own
        ``log`` kernel on the parameters read from the matrix: the same values as
        ``log()``, also at and near a rotation by pi.

        Parameters
        ----------
        matrix : array_like
            ``(..., n + 1, n + 1)`` float64 rigid motions.

        Returns
        -------
        numpy.ndarray
            ``(..., dof)``: translation part, then rotation part.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> X = SE2.from_xy_theta([1.0], [2.0], [np.pi])
        >>> bool(np.allclose(SE2.log_matrix(X.matrix()), X.log()))
        True
        """
        m = np.asarray(matrix, dtype=np.float64)
        n = cls._rotation.point_dim
        rot = cls._rotation._params_of_matrix(m[..., :n, :n])
        p = np.concatenate([m[..., :n, n], rot], axis=-1)
        return np.asarray(run(cls._K["log"], p))

    @classmethod
    def _dims(cls) -> tuple[int, int]:
        n = cls._rotation.point_dim
        return n, n + cls._rotation.param_dim  # translation size, end of the rotation params

    @classmethod
    def _validate_params(cls, p: Array, normalize: bool) -> Array:
        n, r = cls._dims()
        xp = A.namespace(p)
        rot = cls._rotation._validate_params(p[..., n:r], normalize)
        return xp.concat([p[..., :n], rot, p[..., r:]], axis=-1)

    @classmethod
    def from_rotation_translation(cls, rotation: Any, translation: Any) -> Self:
        """From a rotation and translations; the batch axes broadcast.

        Parameters
        ----------
        rotation : LieGroup or array_like
            An element of the rotation group (SO2 or SO3) or rotation matrices.
        translation : array_like
            ``(..., n)``.

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> T = SE3.from_rotation_translation(SO3.exp([0.0, 0.0, 0.5]), [[1.0, 2, 3], [4, 5, 6]])
        >>> T.batch_shape, T.translation()[1].tolist()
        ((2,), [4.0, 5.0, 6.0])
        """
        R = rotation if isinstance(rotation, cls._rotation) else \
            cls._rotation.from_matrix(rotation)
        n, _ = cls._dims()
        t = A.as_float_array(translation, like=R.params)
        A.check_last_dim(t, n, "translation")
        A.check_finite(t, "translation")
        return cls._wrap(concat_last(t, R.params))

    @classmethod
    def _split_matrix(cls, matrix: Any, normalize: bool) -> tuple[Array, Array]:
        """Check a homogeneous matrix; return its linear block and translation column."""
        m = cls.matrix_dim
        T = A.as_float_array(matrix)
        A.check_last_dim(T, (m, m), f"{cls.__name__} matrix")
        A.check_finite(T, f"{cls.__name__} matrix")
        check_bottom_row(T, f"{cls.__name__}.from_matrix")
        return T[..., : m - 1, : m - 1], T[..., : m - 1, m - 1]

    @classmethod
    def from_matrix(cls, matrix: Any, normalize: bool = False) -> Self:
        """From homogeneous matrices ``[[R, t], [0, 1]]``.

        Parameters
        ----------
        matrix : array_like
            ``(..., n + 1, n + 1)``.
        normalize : bool
            Project ``R`` onto the rotations; otherwise a matrix that is not a rotation within
            tolerance raises ``ValueError``.

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> M = np.array([[0.0, -1.0, 1.0], [1.0, 0.0, 2.0], [0.0, 0.0, 1.0]])
        >>> np.round(SE2.from_matrix(M).log(), 12)[2] == np.round(np.pi / 2, 12)
        np.True_
        """
        R, t = cls._split_matrix(matrix, normalize)
        return cls.from_rotation_translation(cls._rotation.from_matrix(R, normalize=normalize), t)

    def rotation(self) -> Any:
        """The rotation part, an element of the rotation group (SO2 or SO3).

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> from microlie import SE3
        >>> T = SE3.exp([1.0, 2.0, 3.0, 0.0, 0.0, 0.5])
        >>> type(T.rotation()).__name__, round(float(T.rotation().log()[2]), 12)
        ('SO3', 0.5)
        """
        n, r = self._dims()
        return self._rotation._wrap(self.params[..., n:r])

    def translation(self) -> Array:
        """The translation part.

        Returns
        -------
        array
            ``(*batch, n)``.

        Examples
        --------
        >>> from microlie import SE2
        >>> SE2.from_xy_theta(1.0, 2.0, 0.3).translation().tolist()
        [1.0, 2.0]
        """
        return self.params[..., : self._dims()[0]]


def concat_last(*arrays: Array) -> Array:
    """Concatenate along the last axis after broadcasting the batch axes."""
    xp = A.namespace(*arrays)
    batch = tuple(np.broadcast_shapes(*(tuple(a.shape[:-1]) for a in arrays)))
    return xp.concat([xp.broadcast_to(a, (*batch, a.shape[-1])) for a in arrays], axis=-1)


def check_bottom_row(T: Array, what: str) -> None:
    """The last row of a homogeneous matrix must be ``0 ... 0 1``."""
    v = A.host_values(T)
    if v is None or not v.size:
        return
    want = np.zeros(v.shape[-1])
    want[-1] = 1.0
    if float(np.max(np.abs(v[..., -1, :] - want))) > 1e-9:
        raise ValueError(f"{what}: the last row of a homogeneous matrix must be 0 ... 0 1")
