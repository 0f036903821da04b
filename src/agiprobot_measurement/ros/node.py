"""The one way a node of this package starts: init, build, spin; an :class:`AgiprobotError` while building is
logged once as fatal and ends the process with exit code 1."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TypeVar

import rospy

from agiprobot_measurement.errors import AgiprobotError

__all__ = ["EXIT_START_FAILED", "run_node"]

#: the exit code of a node that could not start (its settings or its files are wrong)
EXIT_START_FAILED = 1

T = TypeVar("T")


def run_node(name: str, factory: Callable[[], T], label: str | None = None, spin: bool = True) -> T:
    """Start ROS node ``name``, call ``factory()`` to build it, then spin until shutdown; returns what the factory
    built (after the spin). An :class:`AgiprobotError` from the factory is logged as ``"<label>: <message>"``
    (``label`` defaults to ``name``) and exits with :data:`EXIT_START_FAILED`."""
    rospy.init_node(name)
    try:
        built = factory()
    except AgiprobotError as exc:
        rospy.logfatal("%s: %s", label or name, exc)
        sys.exit(EXIT_START_FAILED)
    if spin:
        rospy.spin()
    return built
