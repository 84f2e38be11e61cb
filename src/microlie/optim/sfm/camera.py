"""Camera models and batched reprojection residuals with analytic Jacobians.

A camera is a world-to-camera rigid transform ``P = R X + t`` (the BAL convention: the rotation
and translation map a world point ``X`` into the camera frame) and a vector of intrinsics. The
pose is perturbed on **SO(3) x R^3**, not SE(3): ``R <- R Exp(dphi)`` (right, as everywhere in
microlie) and ``t <- t + dt``. BAL stores exactly these two blocks (angle-axis and a camera-frame
translation), so the translation Jacobian is the identity and the Jacobi column scaling acts on
the same quantities as Ceres'. To first order this is the SE(3) right perturbation
``T Exp(rho, phi)`` with ``rho = R^T dt`` (used to report marginals as SE(3) Gaussians).

The camera tangent is ordered translation first, ``(dt, dphi, d_intrinsics)``: 9 numbers for the
BAL model ``(dt, dphi, df, dk1, dk2)``. Points are plain 3-vectors.

Models (both evaluate *all* observations in one vectorised call):

* :class:`BALCamera` (default): ``p = -P_xy / P_z``, ``uv = f (1 + k1 r^2 + k2 r^4) p`` with
  ``r^2 = |p|^2``, as Ceres' ``SnavelyReprojectionError``; the camera looks down its ``-z`` axis.
* :class:`PinholeCamera`: ``x = P_xy / P_z``, radial-tangential distortion ``(k1, k2, p1, p2)``
  when ``distortion=True``, ``uv = (fx x_d + cx, fy y_d + cy)``; the camera looks down ``+z``.

Points at or behind the camera (``P_z >= 0`` for BAL, ``P_z <= 0`` for the pinhole model):
``behind="evaluate"`` (the default, the standard BAL model; initial cost 850912.46 on
problem-49-7776) projects them like any other point; ``behind="drop"`` gives them a zero
residual and zero Jacobians at every evaluation, as GTSAM's ``GeneralSFMFactor`` and COLMAP do
(850802.09 on the same file). A point exactly on the camera plane (``P_z = 0``) has an
infinite residual under ``"evaluate"`` (a solver rejects such a step). The two objectives
have different optima (13344.3184 and 13308.4836): compare solvers within one convention only.

>>> import numpy as np
>>> from microlie.optim.sfm.camera import BALCamera, reproject
>>> R = np.eye(3)[None]; t = np.array([[0.0, 0.0, -5.0]]); K = np.array([[500.0, 0.0, 0.0]])
>>> X = np.array([[0.1, -0.2, 0.0]])
>>> r = reproject(BALCamera(), R, t, K, X, np.array([0]), np.array([0]), np.zeros((1, 2)))
>>> np.round(r.residuals, 6)
array([[ 10., -20.]])
>>> r.J_cam.shape, r.J_point.shape
((1, 2, 9), (1, 2, 3))
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

__all__ = ["BALCamera", "PinholeCamera", "CameraModel", "Reprojection", "reproject",
           "transform_points", "camera_model", "BEHIND"]

Behind = Literal["evaluate", "drop"]
BEHIND: tuple[str, str] = ("evaluate", "drop")


class CameraModel:
    """A projection ``uv = project(P, K)`` of camera-frame points ``P`` with intrinsics ``K``
    (the base of :class:`BALCamera` and :class:`PinholeCamera`).

    Examples
    --------
    >>> from microlie.optim.sfm.camera import BALCamera, CameraModel, PinholeCamera
    >>> [isinstance(m, CameraModel) for m in (BALCamera(), PinholeCamera())]
    [True, True]
    """

    name: str = ""
    intrinsic_names: tuple[str, ...] = ()

    @property
    def n_intrinsics(self) -> int:
        return len(self.intrinsic_names)

    def in_front(self, P: np.ndarray) -> np.ndarray:
        """Boolean mask of camera-frame points strictly in front of the camera.

        Parameters
        ----------
        P : numpy.ndarray
            ``(n, 3)`` camera-frame points.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` booleans.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PinholeCamera
        >>> PinholeCamera().in_front(np.array([[0.0, 0.0, 1.0]])).tolist()
        [True]
        """
        raise NotImplementedError

    def project(self, P: np.ndarray, K: np.ndarray, jac: bool = True,
                out: np.ndarray | None = None) -> tuple[Any, Any, Any]:
        """Pixels and Jacobians of camera-frame points.

        Parameters
        ----------
        P : numpy.ndarray
            ``(n, 3)`` camera-frame points.
        K : numpy.ndarray
            ``(n, k)`` intrinsics.
        jac : bool
            Also return the Jacobians.
        out : numpy.ndarray, optional
            ``(n, 2, 6 + k)``: the two Jacobians are written into its columns ``0:3`` and ``6:``
            (the camera Jacobian's layout).

        Returns
        -------
        uv : numpy.ndarray
            ``(n, 2)``.
        J_P, J_K : numpy.ndarray or None
            ``d uv / d P`` ``(n, 2, 3)`` and ``d uv / d K`` ``(n, 2, k)`` (``None`` when
            ``jac=False``).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PinholeCamera
        >>> K = np.array([[500.0, 500.0, 320.0, 240.0]])
        >>> PinholeCamera().project(np.array([[0.0, 0.0, 2.0]]), K, jac=False)[0].tolist()
        [[320.0, 240.0]]
        """
        raise NotImplementedError

    def check_intrinsics(self, K: np.ndarray, n_cameras: int) -> np.ndarray:
        """Validated intrinsics of ``n_cameras`` cameras.

        Parameters
        ----------
        K : array_like
            ``(n_cameras, n_intrinsics)``.
        n_cameras : int
            The expected number of cameras.

        Returns
        -------
        numpy.ndarray
            ``K`` as float64.

        Raises
        ------
        ValueError
            Wrong shape or non-finite values (the message names the intrinsics).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALCamera
        >>> BALCamera().check_intrinsics([[500.0, 0.0, 0.0]], 1).tolist()
        [[500.0, 0.0, 0.0]]
        """
        K = np.asarray(K, dtype=float)
        if K.shape != (n_cameras, self.n_intrinsics):
            raise ValueError(f"{self.name} intrinsics must have shape ({n_cameras}, "
                             f"{self.n_intrinsics}) {self.intrinsic_names}, got {K.shape}")
        if not np.all(np.isfinite(K)):
            raise ValueError(f"{self.name} intrinsics contain non-finite values")
        return K


class BALCamera(CameraModel):
    """The BAL / Ceres ``SnavelyReprojectionError`` model, intrinsics ``(f, k1, k2)``.

    ``p = -P_xy / P_z``; ``uv = f (1 + k1 |p|^2 + k2 |p|^4) p``. No principal point; the
    camera looks down its negative z axis.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALCamera
    >>> uv, _, _ = BALCamera().project(np.array([[0.1, 0.2, -2.0]]), np.array([[500.0, 0, 0]]),
    ...                                jac=False)
    >>> uv.tolist()
    [[25.0, 50.0]]
    """

    name = "bal"
    intrinsic_names = ("f", "k1", "k2")

    def in_front(self, P: np.ndarray) -> np.ndarray:
        """Boolean mask of camera-frame points strictly in front of the camera (``P_z < 0``).

        Parameters
        ----------
        P : numpy.ndarray
            ``(n, 3)`` camera-frame points.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` boolean mask of the points strictly in front of the camera.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALCamera
        >>> BALCamera().in_front(np.array([[0.1, 0.2, -2.0], [0.0, 0.0, 1.0]])).tolist()
        [True, False]
        """
        return P[:, 2] < 0.0

    def project(self, P, K, jac=True, out=None):
        """Project camera-frame points to pixels.

        Parameters
        ----------
        P : numpy.ndarray
            ``(n, 3)`` camera-frame points.
        K : numpy.ndarray
            ``(n, k)`` intrinsics (per observation).
        jac : bool
            Also return the Jacobians.
        out : numpy.ndarray, optional
            ``(n, 2, 6 + k)``: the two Jacobians are written into its columns ``0:3`` and ``6:``
            (the camera Jacobian's layout).

        Returns
        -------
        uv : numpy.ndarray
            ``(n, 2)`` pixels.
        J_P : numpy.ndarray or None
            ``(n, 2, 3)``, ``d uv / d P`` (``None`` when ``jac=False``).
        J_K : numpy.ndarray or None
            ``(n, 2, k)``, ``d uv / d K``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALCamera
        >>> P, K = np.array([[0.1, 0.2, -2.0]]), np.array([[500.0, 0, 0]])
        >>> uv, JP, JK = BALCamera().project(P, K)
        >>> uv.tolist(), JP.shape, JK.shape
        ([[25.0, 50.0]], (1, 2, 3), (1, 2, 3))
        """
        n = P.shape[0]
        f, k1, k2 = K[:, 0], K[:, 1], K[:, 2]
        iz = -1.0 / P[:, 2]
        px, py = P[:, 0] * iz, P[:, 1] * iz
        r2 = px * px + py * py
        d = 1.0 + r2 * (k1 + k2 * r2)
        fd = f * d
        uv = np.empty((n, 2))
        uv[:, 0] = fd * px
        uv[:, 1] = fd * py
        if not jac:
            return uv, None, None
        # d uv / d p = f (d I + 2 (k1 + 2 k2 r2) p p^T);  d p / d P = iz [[1, 0, px], [0, 1, py]]
        g = 2.0 * f * (k1 + 2.0 * k2 * r2)
        a00 = fd + g * px * px
        a01 = g * px * py
        a11 = fd + g * py * py
        JP = np.empty((n, 2, 3)) if out is None else out[:, :, 0:3]
        JP[:, 0, 0] = a00 * iz
        JP[:, 0, 1] = a01 * iz
        JP[:, 0, 2] = (a00 * px + a01 * py) * iz
        JP[:, 1, 0] = a01 * iz
        JP[:, 1, 1] = a11 * iz
        JP[:, 1, 2] = (a01 * px + a11 * py) * iz
        JK = np.empty((n, 2, 3)) if out is None else out[:, :, 6:9]
        fr2 = f * r2
        JK[:, 0, 0] = d * px
        JK[:, 1, 0] = d * py
        JK[:, 0, 1] = fr2 * px
        JK[:, 1, 1] = fr2 * py
        JK[:, 0, 2] = fr2 * r2 * px
        JK[:, 1, 2] = fr2 * r2 * py
        return uv, JP, JK


class PinholeCamera(CameraModel):
    """Pinhole ``(fx, fy, cx, cy)``, with ``distortion=True`` also ``(k1, k2, p1, p2)``.

    ``x = P_x / P_z``, ``y = P_y / P_z``, ``r^2 = x^2 + y^2``, ``a = 1 + k1 r^2 + k2 r^4``,
    ``x_d = a x + 2 p1 x y + p2 (r^2 + 2 x^2)``, ``y_d = a y + p1 (r^2 + 2 y^2) + 2 p2 x y``
    (OpenCV's radial-tangential model), ``uv = (fx x_d + cx, fy y_d + cy)``.

    Parameters
    ----------
    distortion : bool
        Add the four distortion coefficients.

    Examples
    --------
    >>> from microlie.optim import PinholeCamera
    >>> PinholeCamera().n_intrinsics, PinholeCamera(distortion=True).n_intrinsics
    (4, 8)
    """

    name = "pinhole"

    def __init__(self, distortion: bool = False) -> None:
        self.distortion = bool(distortion)
        self.intrinsic_names = (("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2") if distortion
                                else ("fx", "fy", "cx", "cy"))

    def in_front(self, P: np.ndarray) -> np.ndarray:
        """Boolean mask of camera-frame points strictly in front of the camera (``P_z > 0``).

        Parameters
        ----------
        P : numpy.ndarray
            ``(n, 3)`` camera-frame points.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` boolean mask of the points strictly in front of the camera.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PinholeCamera
        >>> PinholeCamera().in_front(np.array([[0.1, 0.2, 2.0], [0.0, 0.0, -1.0]])).tolist()
        [True, False]
        """
        return P[:, 2] > 0.0

    def project(self, P, K, jac=True, out=None):
        """Project camera-frame points to pixels.

        Parameters
        ----------
        P : numpy.ndarray
            ``(n, 3)`` camera-frame points.
        K : numpy.ndarray
            ``(n, k)`` intrinsics (per observation).
        jac : bool
            Also return the Jacobians.
        out : numpy.ndarray, optional
            ``(n, 2, 6 + k)``: the two Jacobians are written into its columns ``0:3`` and ``6:``
            (the camera Jacobian's layout).

        Returns
        -------
        uv : numpy.ndarray
            ``(n, 2)`` pixels.
        J_P : numpy.ndarray or None
            ``(n, 2, 3)``, ``d uv / d P`` (``None`` when ``jac=False``).
        J_K : numpy.ndarray or None
            ``(n, 2, k)``, ``d uv / d K``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PinholeCamera
        >>> K = np.array([[500.0, 500.0, 320.0, 240.0]])
        >>> uv, JP, JK = PinholeCamera().project(np.array([[0.1, 0.2, 2.0]]), K)
        >>> uv.tolist(), JK.shape
        ([[345.0, 290.0]], (1, 2, 4))
        """
        n = P.shape[0]
        iz = 1.0 / P[:, 2]
        x, y = P[:, 0] * iz, P[:, 1] * iz
        fx, fy = K[:, 0], K[:, 1]
        if out is None:
            JK = np.zeros((n, 2, self.n_intrinsics))
        else:
            JK = out[:, :, 6:]
            JK[...] = 0.0
        if self.distortion:
            k1, k2, p1, p2 = K[:, 4], K[:, 5], K[:, 6], K[:, 7]
            r2 = x * x + y * y
            a = 1.0 + r2 * (k1 + k2 * r2)
            xd = a * x + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = a * y + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            da = 2.0 * (k1 + 2.0 * k2 * r2)           # d a / d r2 times 2 (d r2 / dx = 2x)
            dxx = a + da * x * x + 2.0 * p1 * y + 6.0 * p2 * x
            dxy = da * x * y + 2.0 * p1 * x + 2.0 * p2 * y
            dyx = da * x * y + 2.0 * p1 * x + 2.0 * p2 * y
            dyy = a + da * y * y + 6.0 * p1 * y + 2.0 * p2 * x
            JK[:, 0, 4] = fx * r2 * x
            JK[:, 1, 4] = fy * r2 * y
            JK[:, 0, 5] = fx * r2 * r2 * x
            JK[:, 1, 5] = fy * r2 * r2 * y
            JK[:, 0, 6] = fx * 2.0 * x * y
            JK[:, 1, 6] = fy * (r2 + 2.0 * y * y)
            JK[:, 0, 7] = fx * (r2 + 2.0 * x * x)
            JK[:, 1, 7] = fy * 2.0 * x * y
        else:
            xd, yd = x, y
            dxx = dyy = np.ones(n)
            dxy = dyx = np.zeros(n)
        uv = np.empty((n, 2))
        uv[:, 0] = fx * xd + K[:, 2]
        uv[:, 1] = fy * yd + K[:, 3]
        if not jac:
            return uv, None, None
        JK[:, 0, 0] = xd
        JK[:, 1, 1] = yd
        JK[:, 0, 2] = 1.0
        JK[:, 1, 3] = 1.0
        # d (x, y) / d P = iz [[1, 0, -x], [0, 1, -y]]
        b00, b01, b10, b11 = fx * dxx, fx * dxy, fy * dyx, fy * dyy
        JP = np.empty((n, 2, 3)) if out is None else out[:, :, 0:3]
        JP[:, 0, 0] = b00 * iz
        JP[:, 0, 1] = b01 * iz
        JP[:, 0, 2] = -(b00 * x + b01 * y) * iz
        JP[:, 1, 0] = b10 * iz
        JP[:, 1, 1] = b11 * iz
        JP[:, 1, 2] = -(b10 * x + b11 * y) * iz
        return uv, JP, JK


def camera_model(spec: str | CameraModel) -> CameraModel:
    """A camera model by name.

    Parameters
    ----------
    spec : str or CameraModel
        ``"bal"`` (:class:`BALCamera`), ``"pinhole"`` (:class:`PinholeCamera`),
        ``"pinhole-radtan"`` (``PinholeCamera(distortion=True)``) or a model (returned as is).

    Returns
    -------
    CameraModel

    Raises
    ------
    ValueError
        An unknown name (the message lists the known ones).

    Examples
    --------
    >>> from microlie.optim.sfm.camera import camera_model
    >>> type(camera_model("pinhole-radtan")).__name__, camera_model("pinhole-radtan").n_intrinsics
    ('PinholeCamera', 8)
    """
    if isinstance(spec, CameraModel):
        return spec
    models = {"bal": BALCamera, "pinhole": PinholeCamera,
              "pinhole-radtan": lambda: PinholeCamera(distortion=True)}
    if not isinstance(spec, str) or spec not in models:
        raise ValueError(f"model must be a CameraModel or one of {', '.join(models)}; got "
                         f"{spec!r}")
    return models[spec]()  # type: ignore[operator]


@dataclass(frozen=True)
class Reprojection:
    """Reprojection residuals ``uv - observed`` with Jacobians (returned by :func:`reproject`).

    Attributes
    ----------
    residuals : numpy.ndarray
        ``(n, 2)`` pixels.
    J_cam : numpy.ndarray or None
        ``(n, 2, 6 + k)`` with respect to the camera tangent ``(dt, dphi, dK)``.
    J_point : numpy.ndarray or None
        ``(n, 2, 3)`` with respect to the world point.
    valid : numpy.ndarray
        The observations that were evaluated (all of them unless ``behind="drop"``).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.sfm.camera import BALCamera, reproject, transform_points
    >>> R, t = np.eye(3)[None], np.array([[0.0, 0.0, -5.0]])
    >>> K, X = np.array([[500.0, 0.0, 0.0]]), np.array([[0.1, 0.2, 0.0], [0.0, 0.0, 1.0]])
    >>> cam, pt = np.array([0, 0]), np.array([0, 1])
    >>> rep = reproject(BALCamera(), R, t, K, X, cam, pt, np.zeros((2, 2)))
    >>> rep.J_cam.shape, rep.J_point.shape, rep.valid.tolist()
    ((2, 2, 9), (2, 2, 3), [True, True])
    """

    residuals: np.ndarray
    J_cam: np.ndarray | None
    J_point: np.ndarray | None
    valid: np.ndarray


def transform_points(R: np.ndarray, t: np.ndarray, X: np.ndarray, cam: np.ndarray | None,
                     pt: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``P = R[cam] X[pt] + t[cam]`` for every observation.

    Parameters
    ----------
    R, t : numpy.ndarray
        ``(n_cameras, 3, 3)`` and ``(n_cameras, 3)`` world-to-camera transforms.
    X : numpy.ndarray
        ``(n_points, 3)``.
    cam, pt : numpy.ndarray or None
        ``(n,)`` indices; ``None``: ``R, t`` (``cam``) or ``X`` (``pt``) already hold one row
        per observation.

    Returns
    -------
    P : numpy.ndarray
        ``(n, 3)`` camera-frame points.
    R_obs, X_obs : numpy.ndarray
        The gathered ``R`` and ``X`` (used by the Jacobians).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.sfm.camera import BALCamera, reproject, transform_points
    >>> R, t = np.eye(3)[None], np.array([[0.0, 0.0, -5.0]])
    >>> K, X = np.array([[500.0, 0.0, 0.0]]), np.array([[0.1, 0.2, 0.0], [0.0, 0.0, 1.0]])
    >>> cam, pt = np.array([0, 0]), np.array([0, 1])
    >>> transform_points(R, t, X, cam, pt)[0].tolist()
    [[0.1, 0.2, -5.0], [0.0, 0.0, -4.0]]
    """
    Rc = R if cam is None else np.take(R, cam, axis=0)
    Xo = X if pt is None else np.take(X, pt, axis=0)
    P = np.matmul(Rc, Xo[:, :, None])[:, :, 0]
    P += t if cam is None else np.take(t, cam, axis=0)
    return P, Rc, Xo


def reproject(model: CameraModel, R: np.ndarray, t: np.ndarray, K: np.ndarray, X: np.ndarray,
              cam: np.ndarray | None, pt: np.ndarray | None, observed: np.ndarray, *,
              jac: bool = True,
              behind: Behind = "evaluate") -> Reprojection:
    """Reprojection residuals of all observations ``(cam[i], pt[i], observed[i])`` at once.

    Jacobians: ``d r / d dt = A``, ``d r / d dphi = -A R [X]_x`` (right perturbation
    ``R Exp(dphi)``), ``d r / d X = A R`` with ``A = d uv / d P``.

    Parameters
    ----------
    model : CameraModel
        The projection.
    R : numpy.ndarray
        ``(n_cameras, 3, 3)`` world-to-camera rotations.
    t : numpy.ndarray
        ``(n_cameras, 3)`` world-to-camera translations.
    K : numpy.ndarray
        ``(n_cameras, k)`` intrinsics.
    X : numpy.ndarray
        ``(n_points, 3)`` world points.
    cam, pt : numpy.ndarray or None
        ``(n,)`` camera and point of each observation; ``None``: ``R, t, K`` (``cam``) or
        ``X`` (``pt``) already hold one row per observation (what
        :class:`~microlie.optim.sfm.reprojection.ReprojectionFactor` passes).
    observed : numpy.ndarray
        ``(n, 2)`` pixels.
    jac : bool
        Also compute the Jacobians.
    behind : {"evaluate", "drop"}
        Points behind a camera: evaluated (BAL) or dropped (GTSAM/COLMAP).

    Returns
    -------
    Reprojection

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.sfm.camera import BALCamera, reproject, transform_points
    >>> R, t = np.eye(3)[None], np.array([[0.0, 0.0, -5.0]])
    >>> K, X = np.array([[500.0, 0.0, 0.0]]), np.array([[0.1, 0.2, 0.0], [0.0, 0.0, 1.0]])
    >>> cam, pt = np.array([0, 0]), np.array([0, 1])
    >>> rep = reproject(BALCamera(), R, t, K, X, cam, pt, np.zeros((2, 2)), jac=False)
    >>> np.round(rep.residuals, 12).tolist()  # -f P_xy / P_z with P = X + (0, 0, -5)
    [[10.0, 20.0], [0.0, 0.0]]
    """
    if behind not in BEHIND:
        raise ValueError(f"behind must be one of {BEHIND}, got {behind!r}")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # P_z = 0: inf cost
        return _reproject(model, R, t, K, X, cam, pt, observed, jac, behind)


def _reproject(model, R, t, K, X, cam, pt, observed, jac, behind):
    P, Rc, Xo = transform_points(R, t, X, cam, pt)
    n, k = len(P), model.n_intrinsics
    Jc = np.empty((n, 2, 6 + k)) if jac else None
    Ko = K if cam is None else np.take(K, cam, axis=0)
    uv, JP, JK = model.project(P, Ko, jac, out=Jc)   # JP, JK inside Jc
    res = uv - observed
    valid = np.ones(n, dtype=bool) if behind == "evaluate" else model.in_front(P)
    if not jac:
        if behind == "drop":
            res[~valid] = 0.0
        return Reprojection(res, None, None, valid)
    assert Jc is not None
    Jp = np.matmul(JP, Rc)                     # d r / d X = A R
    # d r / d dphi = -A R [X]_x = -Jp [X]_x: row i is X x Jp_i
    x0, x1, x2 = Xo[:, 0], Xo[:, 1], Xo[:, 2]
    for i in range(2):
        j0, j1, j2 = Jp[:, i, 0], Jp[:, i, 1], Jp[:, i, 2]
        Jc[:, i, 3] = x1 * j2 - x2 * j1
        Jc[:, i, 4] = x2 * j0 - x0 * j2
        Jc[:, i, 5] = x0 * j1 - x1 * j0
    if behind == "drop":
        bad = ~valid
        res[bad] = 0.0
        Jc[bad] = 0.0
        Jp[bad] = 0.0
    return Reprojection(res, Jc, Jp, valid)
