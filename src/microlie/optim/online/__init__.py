"""Online estimation: incremental smoothing (:mod:`.incremental`) and the fixed-lag smoother
(:mod:`.fixed_lag`).

>>> from microlie.optim.online import BatchFixedLagSmoother, IncrementalFixedLagSmoother
"""

from .fixed_lag import BatchFixedLagSmoother, Binding, IncrementalFixedLagSmoother, MarginalPrior
from .incremental import IncrementalSmoother, UpdateRecord

__all__ = ["BatchFixedLagSmoother", "Binding", "IncrementalFixedLagSmoother",
           "IncrementalSmoother", "MarginalPrior", "UpdateRecord"]
