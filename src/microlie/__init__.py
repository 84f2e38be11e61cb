"""microlie: Lie theory for state estimation.

Groups SO(2), SE(2), SO(3), SE(3), Sim(3) with every operation and its analytic Jacobian,
batched over NumPy, PyTorch and JAX arrays.

Conventions: tangent vectors are translation first (SE(3): ``(rho, phi)``), quaternions are
``(x, y, z, w)``, ``plus``/``minus`` are right (``X Exp(tau)``, ``Log(X^-1 Y)``), and every
Jacobian is a right Jacobian unless ``side="left"`` is passed.
"""

from typing import TYPE_CHECKING, Any

from ._startup import command_setup as _command_setup

_command_setup()  # `microlie ape ...`: one BLAS thread, no cyclic GC (see microlie._startup)

from . import _fast  # noqa: E402 - after the command's set-up, before NumPy loads
from .groups import SE2, SE3, SE23, SO2, SO3, LieGroup, Product, R, Side, Sim3  # noqa: E402

_fast.install()  # the compiled kernels (microlie._c), when they were built

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
