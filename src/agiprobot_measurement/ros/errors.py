"""The errors of the ROS layer, under the package's one root (:mod:`agiprobot_measurement.errors`)."""

from __future__ import annotations

from agiprobot_measurement.errors import InputError, InternalError

__all__ = ["BagReadError", "MessageError", "RvizSnapshotError"]


class MessageError(InputError):
    """A ROS message, bag or marker request does not have the content or shape the conversion needs."""


class BagReadError(MessageError):
    """A bag cannot be read (rosbag's own errors, wrapped with the bag's name)."""


class RvizSnapshotError(InternalError):
    """rviz, Xvfb or a screenshot tool is missing or failed."""
