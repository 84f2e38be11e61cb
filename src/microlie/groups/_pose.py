"""What SE(2), SE(3) and Sim(3) share: parameters ``(translation, rotation[, scale])``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .. import _array as A
from .._array import Array
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
        """From a rotation (an element of the rotation group, or rotation matrices) and
        translations ``(..., n)``; the batch axes broadcast."""
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
        """From homogeneous matrices ``[[R, t], [0, 1]]``. ``R`` must be a rotation within
        tolerance (``ValueError`` otherwise) unless ``normalize=True`` projects it."""
        R, t = cls._split_matrix(matrix, normalize)
        return cls.from_rotation_translation(cls._rotation.from_matrix(R, normalize=normalize), t)

    def rotation(self) -> Any:
        """The rotation part, an element of the rotation group."""
        n, r = self._dims()
        return self._rotation._wrap(self.params[..., n:r])

    def translation(self) -> Array:
        """The translation part ``(..., n)``."""
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
