"""Online estimation: the fixed-lag smoother (:mod:`.fixed_lag`).

>>> from microlie.optim.online import BatchFixedLagSmoother
"""

from .fixed_lag import BatchFixedLagSmoother, Binding, MarginalPrior

__all__ = ["BatchFixedLagSmoother", "Binding", "MarginalPrior"]
