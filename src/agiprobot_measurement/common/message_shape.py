"""Message-shaped snapshots: expanded ROS message mappings read with attribute access, without ROS.

Code written for the original planner treats plan segments and view trajectories as
``moveit_msgs/RobotTrajectory`` (``traj.joint_trajectory.points[-1].time_from_start.to_sec()``). The core keeps
its own arrays; these classes give that code the same attribute paths over a snapshot of them.
"""

from __future__ import annotations

from collections.abc import Mapping

from agiprobot_measurement.errors import InputError

__all__ = ["MessageShape", "MessageTime", "ReadOnlySnapshotError", "message_shape"]


class ReadOnlySnapshotError(InputError, AttributeError):
    """An attribute of a :class:`MessageShape` snapshot is assigned (also an ``AttributeError``)."""


class MessageTime:
    """A ``genpy.Time``/``Duration``-shaped value (``secs``, ``nsecs``, ``to_sec()``, ``to_nsec()``)."""

    __slots__ = ("nsecs", "secs")

    def __init__(self, secs: int = 0, nsecs: int = 0):
        self.secs = int(secs)
        self.nsecs = int(nsecs)

    def to_sec(self) -> float:
        return self.secs + 1e-9 * self.nsecs

    def to_nsec(self) -> int:
        return self.secs * 1_000_000_000 + self.nsecs

    def __repr__(self) -> str:
        return f"MessageTime(secs={self.secs}, nsecs={self.nsecs})"


class MessageShape:
    """A read-only, attribute-access snapshot of an expanded ROS message mapping (``msg.points[0].positions``),
    so that code written for ``moveit_msgs/RobotTrajectory`` runs on plan segments without ROS."""

    def __init__(self, mapping: Mapping):
        for key, value in mapping.items():
            object.__setattr__(self, str(key), message_shape(value))

    def __setattr__(self, name, value):
        raise ReadOnlySnapshotError(
            f"{type(self).__name__} is a snapshot of a plan segment; change the segment's trajectory instead"
        )

    def __repr__(self) -> str:
        return f"MessageShape({', '.join(sorted(vars(self)))})"


def message_shape(value: object) -> object:
    """``value`` (an expanded message mapping) with mappings as :class:`MessageShape`, ``{secs, nsecs}`` as
    :class:`MessageTime`, lists of numbers as tuples (as genpy gives float64[] fields) and other lists as lists."""
    if isinstance(value, Mapping):
        if set(value) == {"secs", "nsecs"}:
            return MessageTime(value["secs"], value["nsecs"])
        return MessageShape(value)
    if isinstance(value, list | tuple):
        if all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            return tuple(value)
        return [message_shape(v) for v in value]
    return value
