"""Compiled kernels for microlie's kernel registry (see ``microlie._kernels``).

Installed with ``pip install "microlie[fast]"`` (from a checkout: ``pip install ./fast``);
microlie registers them for NumPy inputs when this package is importable, unless the environment
variable ``MICROLIE_FAST=0`` is set. Each function takes C-contiguous float64 arrays of shape
``(N, k)`` and returns a tuple of fresh float64 arrays.
"""

from . import _lie

__all__ = ["_lie"]
