"""Documented import path (kept permanently); the implementation is :mod:`agiprobot_measurement.planning.trajectory_manager`."""

from agiprobot_measurement.planning.trajectory_manager import *  # noqa: F403
from agiprobot_measurement.planning.trajectory_manager import __all__  # noqa: F401
