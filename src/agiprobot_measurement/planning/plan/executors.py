"""The registry of station executors: the layers above the core register theirs by name.

A factory is called as ``factory(joint_names, surface_points_mm=None, part=None)`` and returns a
:class:`~agiprobot_measurement.planning.plan.execution.SegmentExecutor`, or None when its station does not answer
(this process is not connected to one, no controller runs). The core ships no station executor: the ROS layer
registers :data:`STATION` when its plugins module is imported, as tf2's extension packages register their
conversions with the core. ``TrajectoryManager.execute`` looks :data:`STATION` up; sessions and nodes hand their
executor in explicitly.
"""

from __future__ import annotations

from collections.abc import Callable

from agiprobot_measurement.errors import InputError

__all__ = ["STATION", "ExecutorFactory", "UnknownExecutor", "get", "known", "register", "registered"]

#: the name under which a layer registers the executor of the running station
STATION = "station"

#: ``(joint_names, surface_points_mm=None, part=None) -> SegmentExecutor | None``
ExecutorFactory = Callable[..., object]

_FACTORIES: dict[str, ExecutorFactory] = {}


class UnknownExecutor(InputError):
    """No executor is registered under the name asked for; the message lists the known names."""


def register(name: str, factory: ExecutorFactory) -> None:
    """Register ``factory`` under ``name`` (a later registration under the same name replaces it)."""
    if not isinstance(name, str) or not name:
        raise InputError(f"an executor's name must be a non-empty string, got {name!r}")
    if not callable(factory):
        raise InputError(f"executor {name!r}: the factory must be callable, got {type(factory).__name__}")
    _FACTORIES[name] = factory


def registered(name: str) -> bool:
    """Whether a factory is registered under ``name``."""
    return name in _FACTORIES


def known() -> tuple[str, ...]:
    """The registered names, sorted."""
    return tuple(sorted(_FACTORIES))


def get(name: str) -> ExecutorFactory:
    """The factory registered under ``name``; :class:`UnknownExecutor` (naming the known ones) if there is none."""
    try:
        return _FACTORIES[name]
    except KeyError:
        names = ", ".join(known()) or "none"
        raise UnknownExecutor(f"no executor registered as {name!r}; known: {names}") from None
