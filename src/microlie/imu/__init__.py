"""Inertial estimation: IMU preintegration, IMU factors, synthetic IMU data, filters.

>>> from microlie.imu import Preintegration
"""

from .preintegration import Preintegration

__all__ = ["Preintegration"]
