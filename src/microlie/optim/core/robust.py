"""Robust losses ``rho(s)`` of the squared whitened residual norm ``s = |e|^2``.

A factor with a loss contributes ``0.5 * rho(s)`` to the robust cost (``rho(s) ~= s`` near 0,
so a loss changes nothing for small residuals). The solver applies a loss the way Ceres does:
residual and Jacobian are scaled by ``sqrt(rho'(s))`` (iteratively reweighted least squares),
and Triggs' rank-one curvature correction is added only where ``rho''(s) > 0``; where
``rho'' <= 0`` (the outlier region of every loss here) it is left out, as in Ceres, because it
would make the Gauss-Newton matrix indefinite.

``scale`` is ``c`` in the residual's units (whitened, i.e. in standard deviations): residuals
with ``|e|`` above about ``c`` are down-weighted.

Examples
--------
>>> import numpy as np
>>> h = Huber(1.0)
>>> [float(v) for v in h.rho(np.array([0.25, 4.0]))]
[0.25, 3.0]
"""

from __future__ import annotations

import numpy as np

__all__ = ["RobustLoss", "Huber", "Cauchy", "Tukey", "GemanMcClure", "DCS", "Barron",
           "make_loss"]


class RobustLoss:
    """Base class of the losses: ``evaluate(s)`` returns ``(rho, rho', rho'')`` as arrays of
    ``s``'s shape.

    Parameters
    ----------
    scale : float
        ``c``, in whitened units (standard deviations); positive.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import RobustLoss, Huber
    >>> isinstance(Huber(2.0), RobustLoss), Huber(2.0).scale
    (True, 2.0)
    """

    def __init__(self, scale: float = 1.0) -> None:
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"{type(self).__name__} scale must be positive, got {scale}")
        self.scale = float(scale)

    def evaluate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The loss and its first two derivatives at ``s = |e|^2``.

        Parameters
        ----------
        s : numpy.ndarray
            Squared whitened residual norms (non-negative).

        Returns
        -------
        rho, drho, d2rho : numpy.ndarray
            ``rho(s)``, ``rho'(s)`` and ``rho''(s)``, each of ``s``'s shape.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import Huber
        >>> [v.tolist() for v in Huber(1.0).evaluate(np.array([4.0]))]
        [[3.0], [0.5], [-0.0625]]
        """
        raise NotImplementedError

    def rho(self, s: np.ndarray) -> np.ndarray:
        """The loss ``rho(s)``.

        Parameters
        ----------
        s : array_like
            Squared whitened residual norms.

        Returns
        -------
        numpy.ndarray

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import Huber
        >>> Huber(1.0).rho(np.array([0.25, 4.0])).tolist()
        [0.25, 3.0]
        """
        return self.evaluate(np.asarray(s, dtype=np.float64))[0]

    def weight(self, s: np.ndarray) -> np.ndarray:
        """The IRLS weight ``rho'(s)``.

        Parameters
        ----------
        s : array_like
            Squared whitened residual norms.

        Returns
        -------
        numpy.ndarray

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import Cauchy
        >>> Cauchy(1.0).weight(np.array([0.0, 1.0, 3.0])).tolist()
        [1.0, 0.5, 0.25]
        """
        return self.evaluate(np.asarray(s, dtype=np.float64))[1]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.scale})"


class Huber(RobustLoss):
    """``rho = s`` for ``s <= c^2``, ``2 c sqrt(s) - c^2`` beyond (quadratic, then linear).

    Parameters
    ----------
    scale : float
        ``c``, in whitened units (standard deviations); positive.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import Huber
    >>> Huber(1.0).rho(np.array([0.25, 4.0])).tolist()
    [0.25, 3.0]
    """

    def evaluate(self, s):
        c = self.scale
        r = np.sqrt(s)
        inl = s <= c * c
        rs = np.where(inl, 1.0, r)
        return (np.where(inl, s, 2 * c * r - c * c), np.where(inl, 1.0, c / rs),
                np.where(inl, 0.0, -c / (2 * rs ** 3)))


class Cauchy(RobustLoss):
    """``rho = c^2 log(1 + s / c^2)``.

    Parameters
    ----------
    scale : float
        ``c``, in whitened units (standard deviations); positive.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import Cauchy
    >>> np.round(Cauchy(1.0).rho(np.array([1.0])), 6).tolist()
    [0.693147]
    """

    def evaluate(self, s):
        c2 = self.scale ** 2
        u = 1.0 + s / c2
        return c2 * np.log1p(s / c2), 1.0 / u, -1.0 / (c2 * u * u)


class Tukey(RobustLoss):
    """Tukey's biweight: ``rho = c^2/3 (1 - (1 - s/c^2)^3)`` for ``s <= c^2``, constant beyond
    (outliers get zero weight).

    Parameters
    ----------
    scale : float
        ``c``, in whitened units (standard deviations); positive.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import Tukey
    >>> s = np.array([4.0])
    >>> np.round(Tukey(1.0).rho(s), 6).tolist(), Tukey(1.0).weight(s).tolist()
    ([0.333333], [0.0])
    """

    def evaluate(self, s):
        c2 = self.scale ** 2
        inl = s <= c2
        v = np.where(inl, 1.0 - s / c2, 0.0)
        return (np.where(inl, c2 / 3.0 * (1.0 - v ** 3), c2 / 3.0), v * v,
                np.where(inl, -2.0 * v / c2, 0.0))


class GemanMcClure(RobustLoss):
    """``rho = c^2 s / (c^2 + s)``.

    Parameters
    ----------
    scale : float
        ``c``, in whitened units (standard deviations); positive.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import GemanMcClure
    >>> GemanMcClure(1.0).rho(np.array([1.0])).tolist()
    [0.5]
    """

    def evaluate(self, s):
        c2 = self.scale ** 2
        d = c2 + s
        return c2 * s / d, c2 * c2 / (d * d), -2.0 * c2 * c2 / (d ** 3)


class DCS(RobustLoss):
    """Dynamic covariance scaling (Agarwal et al. 2013) with ``Phi = scale``: the residual is
    weighted by ``rho'(s) = min(1, 2 Phi / (Phi + s))^2``; integrated consistently this is
    ``rho = s`` for ``s <= Phi`` and ``3 Phi - 4 Phi^2 / (Phi + s)`` beyond.

    Parameters
    ----------
    scale : float
        ``Phi``, positive.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import DCS
    >>> DCS(1.0).rho(np.array([3.0])).tolist(), DCS(1.0).weight(np.array([3.0])).tolist()
    ([2.0], [0.25])
    """

    def evaluate(self, s):
        p = self.scale
        inl = s <= p
        d = p + s
        return (np.where(inl, s, 3 * p - 4 * p * p / d), np.where(inl, 1.0, 4 * p * p / d ** 2),
                np.where(inl, 0.0, -8 * p * p / d ** 3))


class Barron(RobustLoss):
    """Barron's general loss with shape ``alpha`` (not 0 or 2) and scale ``c``:
    ``rho = 2 c^2 |a-2|/a ((s / (c^2 |a-2|) + 1)^(a/2) - 1)`` (``alpha=1`` is pseudo-Huber,
    ``alpha=-2`` Geman-McClure).

    Parameters
    ----------
    scale : float
        ``c``, positive.
    alpha : float
        The shape, finite and not 0 or 2.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import Barron
    >>> Barron(1.0, alpha=1.0).rho(np.array([3.0])).tolist()
    [2.0]
    """

    def __init__(self, scale: float = 1.0, alpha: float = 1.0) -> None:
        super().__init__(scale)
        if alpha in (0.0, 2.0) or not np.isfinite(alpha):
            raise ValueError("Barron alpha must be finite and not 0 or 2 (use Cauchy for 0, "
                             "no loss for 2)")
        self.alpha = float(alpha)

    def evaluate(self, s):
        a, c2 = self.alpha, self.scale ** 2
        b = abs(a - 2.0)
        u = s / (c2 * b) + 1.0
        return (2 * c2 * b / a * (u ** (a / 2) - 1.0), u ** (a / 2 - 1),
                (a / 2 - 1) * u ** (a / 2 - 2) / (c2 * b))


_LOSSES = {"huber": Huber, "cauchy": Cauchy, "tukey": Tukey, "gemanmcclure": GemanMcClure,
           "geman-mcclure": GemanMcClure, "dcs": DCS, "barron": Barron}


def make_loss(spec: str | RobustLoss | None) -> RobustLoss | None:
    """A robust loss from a specification.

    Parameters
    ----------
    spec : str, RobustLoss or None
        ``"name"`` or ``"name:scale"`` with name ``huber``, ``cauchy``, ``tukey``,
        ``gemanmcclure``, ``dcs`` or ``barron`` (scale 1 if omitted), a loss, or ``None``.

    Returns
    -------
    RobustLoss or None

    Examples
    --------
    >>> from microlie.optim import make_loss
    >>> make_loss("cauchy:2"), make_loss("huber"), make_loss(None)
    (Cauchy(2.0), Huber(1.0), None)
    """
    if spec is None or isinstance(spec, RobustLoss):
        return spec
    name, _, arg = str(spec).partition(":")
    cls = _LOSSES.get(name.strip().lower())
    if cls is None:
        raise ValueError(f"unknown robust loss {name!r}; known: {', '.join(sorted(_LOSSES))}")
    try:
        return cls(float(arg)) if arg else cls()
    except ValueError as e:
        raise ValueError(f"robust loss {spec!r}: {e}") from None


def corrected_weights(loss: RobustLoss, s: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                              np.ndarray]:
    """Ceres' corrector: returns ``(rho, residual_scale, alpha_over_s)`` such that the
    corrected residual is ``residual_scale * e`` and the corrected Jacobian is
    ``sqrt(rho') (I - alpha_over_s e e^T) A``."""
    rho, r1, r2 = loss.evaluate(s)
    r1 = np.maximum(r1, 0.0)
    sq = np.sqrt(r1)
    corr = (s > 0) & (r2 > 0) & (r1 > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        D = 1.0 + 2.0 * np.where(corr, s * r2 / np.where(r1 > 0, r1, 1.0), 0.0)
        alpha = 1.0 - np.sqrt(np.maximum(D, 0.0))
        scale = np.where(corr, sq / (1.0 - alpha), sq)
        aos = np.where(corr, alpha / np.where(s > 0, s, 1.0), 0.0)
    return rho, scale, aos
