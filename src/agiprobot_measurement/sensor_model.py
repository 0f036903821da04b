"""Documented import path (kept permanently); the implementation is :mod:`agiprobot_measurement.sensors.laser_line.model`."""

from agiprobot_measurement.sensors.laser_line.model import *  # noqa: F403
from agiprobot_measurement.sensors.laser_line.model import __all__  # noqa: F401
