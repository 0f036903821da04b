"""Documented import path (kept permanently); the implementation is :mod:`agiprobot_measurement.planning.candidates.viewpoint`."""

from agiprobot_measurement.planning.candidates.viewpoint import *  # noqa: F403
from agiprobot_measurement.planning.candidates.viewpoint import __all__  # noqa: F401
