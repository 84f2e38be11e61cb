"""Compiled kernels for microlie's kernel registry (see ``microlie._kernels``).

Installed with ``pip install "microlie[fast]"`` (from a checkout: ``pip install ./fast``);
``import microlie`` registers them for NumPy inputs when this package is importable, unless the
environment variable ``MICROLIE_FAST=0`` is set (``microlie._fast``). ``_lie.KERNELS`` maps each
registry name (``"SE3.exp"``) to the function of ``_lie`` that implements it; each function takes
C-contiguous arrays of shape ``(N, k)``, all float64 or all float32, and returns a tuple of fresh
arrays of that dtype, one per output.
"""

from . import _lie

__all__ = ["_lie"]
