"""Documented import path (kept permanently); the implementation is :mod:`agiprobot_measurement.planning.viewpoint`."""

from agiprobot_measurement.planning.viewpoint import *  # noqa: F403
from agiprobot_measurement.planning.viewpoint import __all__  # noqa: F401
