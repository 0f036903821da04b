"""Errors of the 3D loop beyond the device errors of :mod:`.interfaces`."""

from __future__ import annotations

from agiprobot_measurement.errors import InternalError

__all__ = ["MapWriteError"]


class MapWriteError(InternalError, OSError):
    """A map export could not be written. Also an ``OSError``, which the loop's output step reports."""
