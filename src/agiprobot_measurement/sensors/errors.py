"""The errors of the sensors subpackage, under the package's one root (:mod:`agiprobot_measurement.errors`)."""

from __future__ import annotations

from agiprobot_measurement.errors import InputError, InternalError

__all__ = [
    "PointCloudFormatError",
    "PointCloudWriteError",
    "SensorInputError",
    "SensorStateError",
    "SensorTypeError",
    "ViewIndexError",
]


class SensorInputError(InputError):
    """A sensor parameter, pose, sample set or scan request is malformed or out of range."""


class SensorTypeError(SensorInputError, TypeError):
    """A sensor input has the wrong type (also a ``TypeError``)."""


class ViewIndexError(SensorInputError, IndexError):
    """A viewpoint index outside the evaluated viewpoints (also an ``IndexError``)."""


class SensorStateError(InternalError):
    """A sensor object is used before it is set up (e.g. a scan without a target)."""


class PointCloudFormatError(SensorInputError):
    """A point-cloud file or table does not have the format its reader or writer expects."""


class PointCloudWriteError(InternalError, OSError):
    """A point-cloud writer failed to produce its file (also an ``OSError``)."""
