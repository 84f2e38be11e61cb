"""microlie: Lie theory for state estimation.

Groups SO(2), SE(2), SO(3), SE(3), Sim(3) with every operation and its analytic Jacobian,
batched over NumPy, PyTorch and JAX arrays.

Conventions: tangent vectors are translation first (SE(3): ``(rho, phi)``), quaternions are
``(x, y, z, w)``, ``plus``/``minus`` are right (``X Exp(tau)``, ``Log(X^-1 Y)``), and every
Jacobian is a right Jacobian unless ``side="left"`` is passed.
"""

from typing import TYPE_CHECKING, Any

from . import _fast, uncertainty
from .groups import SE2, SE3, SE23, SO2, SO3, LieGroup, Product, R, Side, Sim3
from .uncertainty import Gaussian, VectorGaussian

_fast.install()  # the compiled kernels of microlie[fast], when installed

__version__ = "0.1.0"

# The larger sub-packages load on first use (``microlie.imu.Preintegration`` after
# ``import microlie``), so that ``import microlie`` stays light.
_SUBPACKAGES = ("calibration", "imu", "optim", "traj")
if TYPE_CHECKING:
    from . import calibration, imu, optim, traj  # noqa: F401


def __getattr__(name: str) -> Any:
    if name in _SUBPACKAGES:
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["LieGroup", "SO2", "SE2", "SO3", "SE3", "SE23", "Sim3", "Product", "R", "Gaussian",
           "VectorGaussian", "Side", "uncertainty", "__version__"]
