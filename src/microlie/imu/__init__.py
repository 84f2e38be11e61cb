"""Inertial estimation: IMU preintegration, IMU factors, synthetic IMU data, filters.

Conventions: navigation states are ``SE23`` elements (tangent ``(rho, phi, nu)``: position,
rotation, velocity); biases are ordered ``(b_g, b_a)`` (gyroscope, accelerometer); the
preintegration covariance is in the order ``(dphi, dv, dp)`` (Forster et al. 2017); the
filters' errors are ``(dtheta, dp, dv, db_g, db_a)`` (``ErrorStateEKF``) and
``(rho, phi, nu, db_g, db_a)`` (``InvariantEKF``). Each class names its order in
``tangent_order`` and its ``repr``.

>>> from microlie.imu import Preintegration
"""

from .factors import BiasRandomWalkFactor, ImuFactor, PositionFactor
from .filters import ErrorStateEKF, InvariantEKF, UpdateResult
from .preintegration import Preintegration
from .residual import Deltas, imu_residual
from .simulate import EUROC_ADIS16448, ImuData, SmoothTrajectory, simulate_imu

__all__ = ["Preintegration", "ImuFactor", "BiasRandomWalkFactor", "PositionFactor",
           "Deltas", "imu_residual",
           "EUROC_ADIS16448", "ImuData", "SmoothTrajectory", "simulate_imu", "ErrorStateEKF",
           "InvariantEKF", "UpdateResult"]
