"""The closed-form weights of graduated non-convexity and its starting ``mu`` (Yang,
Antonante, Tzoumas and Carlone, RA-L 2020); used by :mod:`microlie.optim.core.gnc` and
:mod:`microlie.optim.core.gnc_chordal`.

Examples
--------
>>> import numpy as np
>>> from microlie.optim.core.gnc_weights import tls_weights
>>> np.round(tls_weights(np.array([0.5, 4.0, 100.0]), 4.0, 1.0), 6).tolist()  # c^2 4, mu 1
[1.0, 0.414214, 0.0]
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["tls_weights", "gm_weights", "initial_mu"]


def tls_weights(s: np.ndarray, c2: Any, mu: float) -> np.ndarray:
    """GNC-TLS weights at squared residuals ``s``: 1 for ``s <= mu/(mu+1) c^2``, 0 for
    ``s >= (mu+1)/mu c^2``, ``c sqrt(mu (mu+1) / s) - mu`` between (the paper's closed form).

    Parameters
    ----------
    s : numpy.ndarray
        Whitened squared residual norms (>= 0).
    c2 : float or numpy.ndarray
        Inlier thresholds ``c^2`` (broadcast with ``s``).
    mu : float
        The surrogate's parameter, > 0.

    Returns
    -------
    numpy.ndarray
        Weights in ``[0, 1]``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.gnc import tls_weights
    >>> tls_weights(np.array([0.0, 8.9, 9.1]), 9.0, 1e6).tolist()  # large mu: a step at c^2
    [1.0, 1.0, 0.0]
    """
    s = np.asarray(s, dtype=np.float64)
    c2 = np.broadcast_to(np.asarray(c2, dtype=np.float64), s.shape)
    lo, hi = mu / (mu + 1.0) * c2, (mu + 1.0) / mu * c2
    with np.errstate(divide="ignore", invalid="ignore"):
        mid = np.sqrt(c2 * mu * (mu + 1.0) / s) - mu
    w = np.where(s <= lo, 1.0, np.where(s >= hi, 0.0, mid))
    return np.clip(w, 0.0, 1.0)


def gm_weights(s: np.ndarray, c2: Any, mu: float) -> np.ndarray:
    """GNC-GM weights at squared residuals ``s``: ``(mu c^2 / (s + mu c^2))^2``.

    Parameters
    ----------
    s : numpy.ndarray
        Whitened squared residual norms (>= 0).
    c2 : float or numpy.ndarray
        Inlier thresholds ``c^2`` (broadcast with ``s``).
    mu : float
        The surrogate's parameter, >= 1 (1 is Geman-McClure itself).

    Returns
    -------
    numpy.ndarray
        Weights in ``(0, 1]``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.gnc import gm_weights
    >>> gm_weights(np.array([0.0, 4.0]), 4.0, 1.0).tolist()
    [1.0, 0.25]
    """
    s = np.asarray(s, dtype=np.float64)
    m = mu * np.asarray(c2, dtype=np.float64)
    return (m / (s + m)) ** 2


def initial_mu(surrogate: str, s: np.ndarray, c2: np.ndarray) -> float | None:
    """The starting ``mu`` of the paper's Remark 5 from the residuals of the least-squares
    estimate: TLS ``c^2 / (2 s_max - c^2)`` (the smallest over the factors with
    ``2 s > c^2``), GM ``max(1, max 2 s / c^2)``.

    Parameters
    ----------
    surrogate : {"tls", "gm"}
        The surrogate.
    s : numpy.ndarray
        Squared residuals of the factors GNC judges.
    c2 : numpy.ndarray
        Their thresholds, ``s``'s shape.

    Returns
    -------
    float or None
        ``None`` for TLS when no residual exceeds half its threshold (least squares is then
        already the TLS solution).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.gnc import initial_mu
    >>> initial_mu("tls", np.array([1.0, 50.0]), np.array([10.0, 10.0]))  # 10 / 90
    0.1111111111111111
    >>> initial_mu("gm", np.array([1.0, 50.0]), np.array([10.0, 10.0]))
    10.0
    """
    if surrogate == "gm":
        return max(1.0, float(np.max(2.0 * s / c2, initial=0.0)))
    ex = 2.0 * s - c2
    pos = ex > 0
    if not pos.any():
        return None
    return float(np.min(c2[pos] / ex[pos]))
