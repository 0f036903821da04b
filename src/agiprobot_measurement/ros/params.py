"""Reading ROS parameters the way this package's nodes take them: vectors from lists or launch-argument strings,
file paths where "" means the package default. Errors are ConfigError naming the parameter."""

from __future__ import annotations

import numpy as np
import rospy

from agiprobot_measurement.common.config import ConfigError

__all__ = ["file_param", "vector_param"]


def vector_param(name: str, length: int) -> np.ndarray | None:
    """A list parameter of ``length`` finite numbers, or a string of them ('x y z' or 'x, y, z', as launch arguments
    pass them); None when unset or empty."""
    value = rospy.get_param(name, "")
    if value in ("", None, []):
        return None
    if isinstance(value, str):
        value = value.replace(",", " ").split()
    try:
        vec = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name}: expected {length} numbers, got {value!r}") from exc
    if vec.shape != (length,) or not np.all(np.isfinite(vec)):
        raise ConfigError(f"{name}: expected {length} numbers, got {value!r}")
    return vec


def file_param(name: str) -> str | None:
    """A file parameter: its value, or None (the package default) when unset or empty."""
    return rospy.get_param(name, None) or None
