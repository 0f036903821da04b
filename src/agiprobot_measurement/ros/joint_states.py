"""The robot's latest joint state from ``/joint_states``, ordered by the joint names a node works with.

``JointStateCache`` replaces the subscriber + callback + polling loop each node had: it keeps the newest message
that names all of the node's joints (messages of other robots on the same topic, or malformed ones whose name and
position lists differ in length, are ignored) and hands the positions out as a numpy array in the node's order.
``positions_by_name`` is the ordering itself, usable without a subscription.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np
import rospy
from sensor_msgs.msg import JointState

__all__ = [
    "JointStateCache",
    "positions_by_name",
]


def positions_by_name(
    names: Sequence[str], positions: Sequence[float], joint_names: Sequence[str]
) -> np.ndarray | None:
    """``positions`` (rad or m, as published) reordered to ``joint_names``; None if a joint is missing or the
    message is malformed (``names`` and ``positions`` of different lengths)."""
    if len(names) != len(positions):
        return None
    by_name = dict(zip(names, positions, strict=True))
    try:
        return np.array([by_name[name] for name in joint_names], dtype=float)
    except KeyError:
        return None


class JointStateCache:
    """Subscribes ``topic`` and keeps the latest positions of ``joint_names`` (in that order).

    ``latest()`` returns a copy of them or None before the first complete message; ``wait(timeout_s)`` waits up to
    ``timeout_s`` seconds of ROS time (simulated time under ``use_sim_time``) for one.
    """

    POLL_S = 0.05

    def __init__(self, joint_names: Sequence[str], topic: str = "/joint_states", queue_size: int = 1):
        self.joint_names = list(joint_names)
        self.topic = topic
        self._lock = threading.Lock()
        self._positions: np.ndarray | None = None
        self._stamp: rospy.Time | None = None
        self._subscriber = rospy.Subscriber(topic, JointState, self._on_joint_state, queue_size=queue_size)

    def _on_joint_state(self, msg: JointState) -> None:
        positions = positions_by_name(msg.name, msg.position, self.joint_names)
        if positions is None:
            return
        with self._lock:
            self._positions, self._stamp = positions, msg.header.stamp

    def latest(self) -> np.ndarray | None:
        """The newest positions in ``joint_names`` order (a copy), None if none arrived yet."""
        with self._lock:
            return None if self._positions is None else self._positions.copy()

    def latest_stamp(self) -> rospy.Time | None:
        """The header stamp of the message ``latest()`` comes from."""
        with self._lock:
            return self._stamp

    def wait(self, timeout_s: float) -> np.ndarray | None:
        """``latest()``, waiting up to ``timeout_s`` (ROS time) for a first message; None on timeout or shutdown."""
        deadline = rospy.Time.now() + rospy.Duration(timeout_s)
        positions = self.latest()
        while positions is None and rospy.Time.now() < deadline and not rospy.is_shutdown():
            rospy.sleep(self.POLL_S)
            positions = self.latest()
        return positions

    def unregister(self) -> None:
        """Stops the subscription (the last positions stay readable)."""
        self._subscriber.unregister()
