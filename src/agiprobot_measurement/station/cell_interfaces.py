"""What a real cell's drivers must offer before a measurement starts, and what is missing.

``config/cell_interfaces.yaml`` lists per role (``robot``: ur_robot_driver, ``scanner``: the Micro-Epsilon
scanCONTROL driver, ``stitcher``, ``phoxi``) the interfaces to wait for, each with its kind (``action``, ``topic``,
``service``, ``param``), its resolved name and its type (``package/Name``; a parameter has none), and the launch file
that provides them (``provider``), which the messages name. :func:`load_cell_interfaces` reads and checks the file;
:func:`missing_interfaces` compares the chosen roles with what a master reports (:class:`MasterSnapshot`: the
published topics with their types, the offered services with theirs, the parameters that are set) and returns one
:class:`Missing` per absent or wrongly typed interface, with a text that says what to start:

    robot: no action server /scaled_pos_joint_traj_controller/follow_joint_trajectory (<its type from the file>)
    — is ur_robot_driver's ur10e_bringup.launch running?

An action server counts as present when its ``status``, ``feedback`` and ``result`` topics are published (the
topics every action server publishes); its type is read from the ``result`` topic's type, ``<action type>ActionResult``.
ROS-free: the node ``cell_check`` (``ros/nodes/cell_check.py``) builds the snapshot from the master.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import ConfigError, read_yaml, require

__all__ = [
    "ACTION_RESULT_SUFFIX",
    "ACTION_TOPICS",
    "CELL_INTERFACES_FILE",
    "KINDS",
    "CellInterfaces",
    "Interface",
    "MasterSnapshot",
    "Missing",
    "Role",
    "load_cell_interfaces",
    "missing_interfaces",
    "parse_roles",
]

CELL_INTERFACES_FILE = CONFIG_DIR / "cell_interfaces.yaml"
KINDS = ("action", "topic", "service", "param")
#: the topics an action server publishes under its namespace (goal and cancel are the clients')
ACTION_TOPICS = ("status", "feedback", "result")
#: the result topic's type is the action's type with this suffix (what genaction generates)
ACTION_RESULT_SUFFIX = "ActionResult"
_TYPE = re.compile(r"^[A-Za-z][\w]*/[A-Za-z]\w*$")
_NAME = re.compile(r"^(/[A-Za-z][\w]*)+$")
_ROLE = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class Interface:
    """One interface a role must offer: kind (:data:`KINDS`), resolved name, type (``package/Name``, "" for a
    parameter)."""

    kind: str
    name: str
    type: str = ""

    def describe(self) -> str:
        """``/name (package/Name)``, or ``/name`` for a parameter."""
        return f"{self.name} ({self.type})" if self.type else self.name


@dataclass(frozen=True)
class Role:
    """A role of the cell (robot, scanner, ...), the launch file that provides it, and its interfaces."""

    name: str
    provider: str
    interfaces: tuple[Interface, ...]


@dataclass(frozen=True)
class CellInterfaces:
    """Every role of the file, in its order."""

    roles: dict[str, Role]
    source: Path | None = None

    def select(self, names: Iterable[str]) -> list[Role]:
        """The roles named (in the order given, each once), or ConfigError naming the unknown ones and the known."""
        chosen, unknown = [], []
        for name in names:
            if name not in self.roles:
                unknown.append(name)
            elif self.roles[name] not in chosen:
                chosen.append(self.roles[name])
        if unknown:
            raise ConfigError(f"unknown role(s) {', '.join(map(repr, unknown))}; the cell has {', '.join(self.roles)}")
        if not chosen:
            raise ConfigError(f"no role chosen; the cell has {', '.join(self.roles)}")
        return chosen

    def wanted(self, names: Iterable[str], kind: str) -> list[str]:
        """Names of the chosen roles' interfaces of ``kind`` (what a snapshot must look up, e.g. service types)."""
        return [i.name for role in self.select(names) for i in role.interfaces if i.kind == kind]


@dataclass(frozen=True)
class MasterSnapshot:
    """What a ROS master reports at one moment: published topics with their types, offered services with their
    types ("" when a service's type could not be read), and the parameters that are set (at least those asked for)."""

    topics: Mapping[str, str] = field(default_factory=dict)
    services: Mapping[str, str] = field(default_factory=dict)
    params: frozenset[str] = frozenset()


@dataclass(frozen=True)
class Missing:
    """An interface of ``role`` that is absent (``found`` "") or has another type (``found`` that type)."""

    role: Role
    interface: Interface
    found: str = ""

    @property
    def text(self) -> str:
        role, wanted = self.role, self.interface
        what = {"action": "action server", "topic": "publisher of topic", "service": "service", "param": "parameter"}
        if not self.found:
            return f"{role.name}: no {what[wanted.kind]} {wanted.describe()} — is {role.provider} running?"
        noun = {"action": "action server", "topic": "topic", "service": "service"}[wanted.kind]
        return (
            f"{role.name}: {noun} {wanted.name} is {self.found}, expected {wanted.type} — is it {role.provider} "
            "that offers it?"
        )


def _interface(entry: object, where: str, seen: set[tuple[str, str]]) -> Interface:
    kind = str(require(entry, "kind", where))
    if kind not in KINDS:
        raise ConfigError(f"{where}: kind {kind!r} is not one of {', '.join(KINDS)}")
    name = str(require(entry, "name", where))
    if not _NAME.match(name):
        raise ConfigError(f"{where}: name {name!r} must be a resolved ROS name (/a/b)")
    unknown = set(entry) - {"kind", "name", "type"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)} (known: kind, name, type)")
    if kind == "param":
        if entry.get("type"):
            raise ConfigError(f"{where}: a param has no type to check; leave 'type' out")
        kind_type = ""
    else:
        kind_type = str(require(entry, "type", where))
        if not _TYPE.match(kind_type):
            raise ConfigError(f"{where}: type {kind_type!r} must be package/Name")
    if (kind, name) in seen:
        raise ConfigError(f"{where}: {kind} {name} is listed twice")
    seen.add((kind, name))
    return Interface(kind, name, kind_type)


def _role(name: object, entry: object, where: str) -> Role:
    if not isinstance(name, str) or not _ROLE.match(name):
        raise ConfigError(f"{where}: role name {name!r} must be lower-case letters, digits, '_'")
    provider = require(entry, "provider", where)
    if not isinstance(provider, str) or not provider.strip():
        raise ConfigError(f"{where}.provider: expected the launch file that provides the role, got {provider!r}")
    unknown = set(entry) - {"provider", "interfaces"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)} (known: provider, interfaces)")
    entries = require(entry, "interfaces", where)
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}.interfaces: expected a non-empty list")
    seen: set[tuple[str, str]] = set()
    interfaces = tuple(_interface(e, f"{where}.interfaces[{i}]", seen) for i, e in enumerate(entries))
    return Role(name, provider.strip(), interfaces)


def load_cell_interfaces(path: str | Path | None = None) -> CellInterfaces:
    """The roles of ``path`` (default ``config/cell_interfaces.yaml``), checked; ConfigError names the bad key."""
    path = Path(path) if path else CELL_INTERFACES_FILE
    where = str(path)
    roles = require(read_yaml(path), "roles", where)
    if not isinstance(roles, dict) or not roles:
        raise ConfigError(f"{where}: roles must be a non-empty mapping of role name to provider and interfaces")
    return CellInterfaces({name: _role(name, entry, f"{where}: roles.{name}") for name, entry in roles.items()}, path)


def parse_roles(value: object, where: str) -> list[str]:
    """Role names from a list or a string of names separated by spaces or commas (as a launch argument passes them)."""
    if isinstance(value, str):
        value = value.replace(",", " ").split()
    if not isinstance(value, list) or not all(isinstance(v, str) and v.strip() for v in value):
        raise ConfigError(f"{where}: expected a list of role names, got {value!r}")
    return [v.strip() for v in value]


def _found(interface: Interface, master: MasterSnapshot) -> tuple[bool, str]:
    """(present, type found) of one interface."""
    if interface.kind == "param":
        return interface.name in master.params, ""
    if interface.kind == "topic":
        return interface.name in master.topics, master.topics.get(interface.name, "")
    if interface.kind == "service":
        return interface.name in master.services, master.services.get(interface.name, "")
    topics = [f"{interface.name}/{suffix}" for suffix in ACTION_TOPICS]
    if not all(t in master.topics for t in topics):
        return False, ""
    return True, master.topics[f"{interface.name}/result"].removesuffix(ACTION_RESULT_SUFFIX)


def missing_interfaces(cell: CellInterfaces, roles: Sequence[str], master: MasterSnapshot) -> list[Missing]:
    """Every interface of ``roles`` that ``master`` lacks or offers with another type, in the file's order (an empty
    list: the cell is ready). A type that could not be read ("") is not held against the interface."""
    missing = []
    for role in cell.select(roles):
        for interface in role.interfaces:
            present, found = _found(interface, master)
            if not present:
                missing.append(Missing(role, interface))
            elif found and interface.type and found != interface.type:
                missing.append(Missing(role, interface, found))
    return missing
