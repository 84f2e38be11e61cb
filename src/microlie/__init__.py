"""microlie: Lie theory for state estimation.

Groups SO(2), SE(2), SO(3), SE(3), Sim(3) with every operation and its analytic Jacobian,
batched over NumPy, PyTorch and JAX arrays.

Conventions: tangent vectors are translation first (SE(3): ``(rho, phi)``), quaternions are
``(x, y, z, w)``, ``plus``/``minus`` are right (``X Exp(tau)``, ``Log(X^-1 Y)``), and every
Jacobian is a right Jacobian unless ``side="left"`` is passed.
"""

from typing import TYPE_CHECKING, Any

from ._startup import command_blas_threads as _command_blas_threads
from ._startup import no_collection as _no_collection

_command_blas_threads()  # `microlie ape ...`: one BLAS thread (see microlie._startup)
with _no_collection():  # NumPy's and our modules load without cyclic collections
    from . import _fast
    from .groups import SE2, SE3, SE23, SO2, SO3, LieGroup, Product, R, Side, Sim3

    _fast.install()  # the compiled kernels of microlie[fast], when installed

__version__ = "0.1.0"

# The larger sub-packages load on first use (``microlie.imu.Preintegration`` after
# ``import microlie``), so that ``import microlie`` stays light (``microlie ape`` never
# imports ``uncertainty``).
_SUBPACKAGES = ("calibration", "imu", "optim", "traj", "uncertainty")
_LAZY = {"Gaussian": "uncertainty", "VectorGaussian": "uncertainty"}
if TYPE_CHECKING:
    from . import calibration, imu, optim, traj, uncertainty  # noqa: F401
    from .uncertainty import Gaussian, VectorGaussian


def __getattr__(name: str) -> Any:
    if name in _SUBPACKAGES or name in _LAZY:
        import importlib

        module = importlib.import_module(f"{__name__}.{_LAZY.get(name, name)}")
        return getattr(module, name) if name in _LAZY else module
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_SUBPACKAGES) | set(_LAZY))


__all__ = ["LieGroup", "SO2", "SE2", "SO3", "SE3", "SE23", "Sim3", "Product", "R", "Gaussian",
           "VectorGaussian", "Side", "uncertainty", "__version__"]
