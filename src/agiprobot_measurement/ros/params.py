"""The one place this package's nodes read the ROS parameter server.

:func:`param` reads one parameter and hands it to a validator (``common.config``'s ``number``, ``whole``,
``positive``... or :func:`flag`, :func:`text`), so a bad value is a :class:`ConfigError` naming the parameter;
:func:`read_params` reads a declared list of :class:`Param` into one typed namespace. Vectors come from lists or
launch-argument strings (:func:`vector_param`); file parameters treat "" as the package default (:func:`file_param`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import rospy

from agiprobot_measurement.common.config import ConfigError

__all__ = [
    "REQUIRED",
    "Param",
    "file_param",
    "flag",
    "has_param",
    "param",
    "read_params",
    "text",
    "vector_param",
]

#: the default of a parameter that must be set (a missing one is a ConfigError)
REQUIRED = object()

#: a validator: (raw value, parameter name) -> typed value, raising ConfigError naming the parameter
Validator = Callable[[object, str], object]


def flag(value: object, where: str) -> bool:
    """A parameter read as a truth value (``bool(value)``, as the nodes always read their switches)."""
    return bool(value)


def text(value: object, where: str) -> str:
    """A parameter read as text."""
    return str(value)


def param(name: str, default: object = REQUIRED, validate: Validator | None = None) -> object:
    """The value of ROS parameter ``name`` (``default`` when unset), passed through ``validate(value, name)``."""
    if default is REQUIRED:
        if not rospy.has_param(name):
            raise ConfigError(f"{name}: required parameter is not set")
        value = rospy.get_param(name)
    else:
        value = rospy.get_param(name, default)
    return validate(value, name) if validate is not None else value


def has_param(name: str) -> bool:
    """Whether ROS parameter ``name`` is set."""
    return rospy.has_param(name)


@dataclass(frozen=True)
class Param:
    """One parameter of a node: its name (``~rate_hz``), default and validator; ``field`` is the attribute it is
    read into (default: the name without ``~`` and namespace)."""

    name: str
    default: object = REQUIRED
    validate: Validator | None = None
    field: str = ""

    @property
    def key(self) -> str:
        return self.field or self.name.lstrip("~").rsplit("/", 1)[-1]


def read_params(spec: Sequence[Param]) -> SimpleNamespace:
    """Every parameter of ``spec`` read and validated, as attributes named by :attr:`Param.key`."""
    return SimpleNamespace(**{p.key: param(p.name, p.default, p.validate) for p in spec})


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
