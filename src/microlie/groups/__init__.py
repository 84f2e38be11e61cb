"""The Lie groups: one module per group, all derived from :class:`LieGroup`."""

from .base import LieGroup, Side
from .product import Product, ProductGroup, R, VectorSpace
from .se2 import SE2
from .se3 import SE3
from .se23 import SE23
from .sim3 import Sim3
from .so2 import SO2
from .so3 import SO3

__all__ = ["LieGroup", "SO2", "SE2", "SO3", "SE3", "SE23", "Sim3", "Product", "ProductGroup", "R",
           "VectorSpace", "Side"]
