"""The ROS interface reference (docs/ros-interface.md) as data, and the same view of a running node.

The document has one section per node, headed ``### Node `/name` `` (``### Node `/name` (variant)`` for a second
node type started under the same name; its key is ``/name:variant``), each with one table whose rows are
``| kind | name | type | default | meaning |``. Kinds:

- ``publishes`` / ``subscribes``: a topic and its message type;
- ``service``: a service the node offers and its type;
- ``action server`` / ``action client``: an action by its namespace and its ``...Action`` type; it stands for the
  five topics actionlib makes of it (goal, cancel: subscribed by the server; status, feedback, result: published);
- ``parameter``: a parameter the node reads (private ones as ``~name``), with its default (``required`` when the
  node refuses to start without it);
- ``uses``: a service or action the node uses as a client when asked to (not visible on the master).

Names are written resolved (``/ns/topic``); ``~x`` in a parameter row is the node's private ``/node/x``.
The master shows, and this module leaves out, what every rospy node has: ``/rosout``, ``/clock`` (subscribed under
``use_sim_time``), ``~get_loggers`` and ``~set_logger_level``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

KINDS = ("publishes", "subscribes", "service", "action server", "action client", "parameter", "uses")
INFRASTRUCTURE_TOPICS = {"/rosout", "/clock"}
INFRASTRUCTURE_SERVICES = ("/get_loggers", "/set_logger_level")

_NODE_HEADING = re.compile(r"^### Node `(/[^`]+)`(?: \((\w+)\))?")
_ROW = re.compile(r"^\|(.+)\|\s*$")


@dataclass
class NodeInterface:
    """What one node offers and uses: topic -> type for publications and subscriptions, service -> type,
    action namespace -> action type, parameter name -> default text."""

    name: str
    publishes: dict[str, str] = field(default_factory=dict)
    subscribes: dict[str, str] = field(default_factory=dict)
    services: dict[str, str] = field(default_factory=dict)
    action_servers: dict[str, str] = field(default_factory=dict)
    action_clients: dict[str, str] = field(default_factory=dict)
    parameters: dict[str, str] = field(default_factory=dict)
    uses: dict[str, str] = field(default_factory=dict)

    def topics(self) -> tuple[dict[str, str], dict[str, str]]:
        """Publications and subscriptions with every action expanded into its five topics."""
        pub, sub = dict(self.publishes), dict(self.subscribes)
        for roles, out_role in ((self.action_servers, pub), (self.action_clients, sub)):
            in_role = sub if out_role is pub else pub
            for ns, action_type in roles.items():
                base = action_type[: -len("Action")] if action_type.endswith("Action") else action_type
                in_role[f"{ns}/goal"] = f"{base}ActionGoal"
                in_role[f"{ns}/cancel"] = "actionlib_msgs/GoalID"
                out_role[f"{ns}/status"] = "actionlib_msgs/GoalStatusArray"
                out_role[f"{ns}/feedback"] = f"{base}ActionFeedback"
                out_role[f"{ns}/result"] = f"{base}ActionResult"
        return pub, sub


def _cells(line: str) -> list[str]:
    return [cell.strip().strip("`").strip() for cell in _ROW.match(line).group(1).split("|")]


def parse(text: str) -> dict[str, NodeInterface]:
    """Every node section of the reference, by node name. Raises ValueError on a row it cannot read."""
    nodes: dict[str, NodeInterface] = {}
    current: NodeInterface | None = None
    for number, line in enumerate(text.splitlines(), 1):
        heading = _NODE_HEADING.match(line)
        if heading:
            key = heading.group(1) + (f":{heading.group(2)}" if heading.group(2) else "")
            current = nodes.setdefault(key, NodeInterface(heading.group(1)))
            continue
        if line.startswith("## ") or (line.startswith("### ") and not heading):
            current = None
            continue
        if current is None or not _ROW.match(line):
            continue
        cells = _cells(line)
        if cells[0] in ("kind", "") or set(cells[0]) <= set("-: "):
            continue
        if len(cells) != 5 or cells[0] not in KINDS:
            raise ValueError(f"ros-interface.md:{number}: expected | kind | name | type | default | meaning |")
        kind, name, type_, default = cells[:4]
        if kind == "parameter":
            current.parameters[_private(name, current.name)] = default
            continue
        target = {
            "publishes": current.publishes,
            "subscribes": current.subscribes,
            "service": current.services,
            "action server": current.action_servers,
            "action client": current.action_clients,
            "uses": current.uses,
        }[kind]
        target[_private(name, current.name)] = type_
    return nodes


def _private(name: str, node: str) -> str:
    return f"{node}/{name[1:]}" if name.startswith("~") else name


def load(path: Path) -> dict[str, NodeInterface]:
    return parse(Path(path).read_text())


def observe(node: str) -> NodeInterface:
    """The node's publications, subscriptions, services (with types) and private parameters, as the master and the
    parameter server show them now. Needs a running master (imports ROS client modules)."""
    import rosgraph
    import rosservice

    master = rosgraph.Master("/interface_reference")
    publishers, subscribers, providers = master.getSystemState()
    types = dict(master.getTopicTypes())
    seen = NodeInterface(node)
    for entries, target in ((publishers, seen.publishes), (subscribers, seen.subscribes)):
        for topic, nodes in entries:
            if node in nodes and topic not in INFRASTRUCTURE_TOPICS:
                target[topic] = types.get(topic, "?")
    for service, nodes in providers:
        if node in nodes and not service.endswith(INFRASTRUCTURE_SERVICES):
            try:
                seen.services[service] = rosservice.get_service_type(service) or "?"
            except rosservice.ROSServiceIOException:
                seen.services[service] = "?"
    names = master.getParamNames()
    prefix = node + "/"
    for name in names:
        if name.startswith(prefix):
            top = name[len(prefix) :].split("/")[0]
            seen.parameters[prefix + top] = ""
    return seen


def differences(documented: NodeInterface, running: NodeInterface) -> list[str]:
    """What the reference and the running node disagree on, one line each; empty when they agree.

    Topics and services must match exactly, types included; every private parameter on the parameter server must be
    documented (documented parameters that are absent are read with their default)."""
    problems: list[str] = []
    pub, sub = documented.topics()
    for what, doc, live in (
        ("publishes", pub, running.publishes),
        ("subscribes", sub, running.subscribes),
        ("service", documented.services, running.services),
    ):
        for name in sorted(set(doc) - set(live)):
            problems.append(f"{documented.name}: documented {what} {name} is not on the running node")
        for name in sorted(set(live) - set(doc)):
            problems.append(f"{documented.name}: running node {what} {name} ({live[name]}) is not documented")
        for name in sorted(set(doc) & set(live)):
            if doc[name] != live[name]:
                problems.append(f"{documented.name}: {what} {name} documented as {doc[name]}, running as {live[name]}")
    for name in sorted(set(running.parameters) - set(documented.parameters)):
        problems.append(f"{documented.name}: parameter {name} is set on the server but not documented")
    return problems
