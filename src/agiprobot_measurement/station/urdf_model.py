"""Build the station URDF from its xacro and read what the core needs from it: joints, chains, geometry.

The robot description is produced in-process with the ``xacro`` package from ``urdf/station.urdf.xacro`` and
the configuration files, exactly as ``launch/station.launch`` produces it, so the ROS-free core and the nodes
see the same robot.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement._paths import URDF_DIR
from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.common.geometry import pose_matrix

__all__ = [
    "UrdfGeometry",
    "UrdfJoint",
    "UrdfModel",
    "build_station_urdf",
]


def build_station_urdf(
    robot: str | Path | None = None,
    joint_limits: str | Path | None = None,
    scanner: str | Path | None = None,
    scene: str | Path | None = None,
    xacro_file: str | Path | None = None,
    kinematics: str | Path | None = None,
) -> str:
    """Expand the station xacro; arguments left ``None`` take the package's config files (``kinematics``: the arm's
    kinematics file, default the robot file's ``kinematics_config``)."""
    import xacro

    mappings = {}
    for key, value in (
        ("robot", robot),
        ("joint_limits", joint_limits),
        ("scanner", scanner),
        ("scene", scene),
        ("kinematics", kinematics),
    ):
        if value is not None:
            mappings[key] = str(Path(value).resolve())
    source = Path(xacro_file) if xacro_file else URDF_DIR / "station.urdf.xacro"
    try:
        document = xacro.process_file(str(source), mappings=mappings)
    except Exception as exc:  # xacro raises its own and Python errors for bad YAML/keys
        raise ConfigError(f"{source}: xacro failed: {exc}") from exc
    return document.toprettyxml(indent="  ")


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str  # revolute, continuous, prismatic, fixed
    parent: str
    child: str
    origin: np.ndarray  # 4x4 parent -> joint frame
    axis: np.ndarray
    lower: float
    upper: float
    velocity: float


@dataclass(frozen=True)
class UrdfGeometry:
    """One collision (or visual) shape of a link; ``origin`` is link -> shape (metres)."""

    link: str
    type: str  # box, cylinder, sphere, mesh
    origin: np.ndarray
    size: np.ndarray | None = None  # box
    radius: float | None = None  # cylinder, sphere
    length: float | None = None  # cylinder
    mesh: str | None = None
    scale: np.ndarray | None = None


def _floats(text: str | None, count: int, default: float = 0.0) -> np.ndarray:
    if text is None:
        return np.full(count, default)
    values = np.array([float(v) for v in text.split()])
    if values.shape != (count,):
        raise ConfigError(f"URDF: expected {count} numbers, got {text!r}")
    return values


def _origin(element: ET.Element | None) -> np.ndarray:
    if element is None:
        return np.eye(4)
    return pose_matrix(_floats(element.get("xyz"), 3), _floats(element.get("rpy"), 3))


def _geometry(link: str, element: ET.Element) -> UrdfGeometry | None:
    origin = _origin(element.find("origin"))
    geometry = element.find("geometry")
    if geometry is None or len(geometry) == 0:
        return None
    shape = geometry[0]
    if shape.tag == "box":
        return UrdfGeometry(link, "box", origin, size=_floats(shape.get("size"), 3))
    if shape.tag == "cylinder":
        return UrdfGeometry(
            link, "cylinder", origin, radius=float(shape.get("radius")), length=float(shape.get("length"))
        )
    if shape.tag == "sphere":
        return UrdfGeometry(link, "sphere", origin, radius=float(shape.get("radius")))
    if shape.tag == "mesh":
        return UrdfGeometry(link, "mesh", origin, mesh=shape.get("filename"), scale=_floats(shape.get("scale"), 3, 1.0))
    raise ConfigError(f"URDF: link {link}: unsupported geometry <{shape.tag}>")


def _inverted(joint: UrdfJoint) -> UrdfJoint:
    """A fixed joint walked from child to parent."""
    return UrdfJoint(
        f"{joint.name}_inverse",
        "fixed",
        joint.child,
        joint.parent,
        np.linalg.inv(joint.origin),
        joint.axis,
        joint.lower,
        joint.upper,
        joint.velocity,
    )


class UrdfModel:
    """The tree of a URDF: joints by child link, collision and visual geometry per link."""

    def __init__(self, xml: str):
        try:
            root = ET.fromstring(xml)
        except ET.ParseError as exc:
            raise ConfigError(f"URDF: not valid XML: {exc}") from exc
        if root.tag != "robot":
            raise ConfigError("URDF: root element must be <robot>")
        self.name = root.get("name", "")
        self.links: list[str] = [link.get("name") for link in root.findall("link")]
        self.collision: dict[str, list[UrdfGeometry]] = {}
        self.visual: dict[str, list[UrdfGeometry]] = {}
        for link in root.findall("link"):
            name = link.get("name")
            self.collision[name] = [g for g in (_geometry(name, c) for c in link.findall("collision")) if g]
            self.visual[name] = [g for g in (_geometry(name, v) for v in link.findall("visual")) if g]
        self.joints: dict[str, UrdfJoint] = {}
        self.joint_by_child: dict[str, UrdfJoint] = {}
        for joint in root.findall("joint"):
            limit = joint.find("limit")
            axis = joint.find("axis")
            parsed = UrdfJoint(
                name=joint.get("name"),
                type=joint.get("type"),
                parent=joint.find("parent").get("link"),
                child=joint.find("child").get("link"),
                origin=_origin(joint.find("origin")),
                axis=_floats(axis.get("xyz") if axis is not None else None, 3, 0.0)
                if axis is not None
                else np.array([1.0, 0.0, 0.0]),
                lower=float(limit.get("lower", 0.0)) if limit is not None else -np.inf,
                upper=float(limit.get("upper", 0.0)) if limit is not None else np.inf,
                velocity=float(limit.get("velocity", 0.0)) if limit is not None else np.inf,
            )
            self.joints[parsed.name] = parsed
            self.joint_by_child[parsed.child] = parsed

    @classmethod
    def from_station(cls, **kwargs) -> UrdfModel:
        return cls(build_station_urdf(**kwargs))

    def _ancestors(self, link: str) -> list[str]:
        """``link`` and the links above it up to the root."""
        out = [link]
        while out[-1] in self.joint_by_child:
            out.append(self.joint_by_child[out[-1]].parent)
        return out

    def chain(self, base: str, tip: str) -> list[UrdfJoint]:
        """Joints from ``base`` to ``tip`` (fixed joints included), in order.

        ``base`` need not be above ``tip``: the path may first climb from ``base`` to a common ancestor through
        fixed joints (e.g. ``base`` -> ``base_link`` -> ... -> ``tool0``); those come back inverted (parent and child
        swapped, origin inverted). A movable joint on the climb is a ConfigError."""
        for frame in (base, tip):
            if frame not in self.links:
                raise ConfigError(f"unknown frame '{frame}'; frames of this robot: {', '.join(self.links)}")
        above_tip = self._ancestors(tip)
        above_base = self._ancestors(base)
        common = next((link for link in above_base if link in above_tip), None)
        if common is None:
            raise ConfigError(f"frames '{base}' and '{tip}' are not connected in the URDF tree")
        climb = []
        for link in above_base[: above_base.index(common)]:
            joint = self.joint_by_child[link]
            if joint.type != "fixed":
                raise ConfigError(f"frame '{tip}' is not below '{base}' in the URDF tree (joint '{joint.name}' moves)")
            climb.append(_inverted(joint))
        descent = [self.joint_by_child[link] for link in above_tip[: above_tip.index(common)]]
        return climb + descent[::-1]

    def movable_joint_names(self, base: str, tip: str) -> list[str]:
        return [j.name for j in self.chain(base, tip) if j.type != "fixed"]

    def fixed_transform(self, base: str, tip: str) -> np.ndarray:
        """Transform base -> tip when every joint between them is fixed."""
        pose = np.eye(4)
        for joint in self.chain(base, tip):
            if joint.type != "fixed":
                raise ConfigError(f"joint '{joint.name}' between {base} and {tip} is not fixed")
            pose = pose @ joint.origin
        return pose
