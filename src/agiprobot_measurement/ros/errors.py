"""The errors of the ROS layer, under the package's one root (:mod:`agiprobot_measurement.errors`)."""

from __future__ import annotations

from agiprobot_measurement.errors import InputError, InternalError

__all__ = ["MessageError", "RvizSnapshotError"]


class MessageError(InputError):
    """A ROS message, bag or marker request does not have the content or shape the conversion needs."""


class RvizSnapshotError(InternalError):
    """rviz, Xvfb or a screenshot tool is missing or failed."""
