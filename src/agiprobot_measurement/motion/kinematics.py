"""Forward kinematics of the station's robot from its URDF: a PyKDL chain, and a vectorised numpy form.

``KinematicModel`` is built from the URDF produced by ``urdf/station.urdf.xacro`` (see
:mod:`agiprobot_measurement.station.urdf_model`). Poses are 4x4 homogeneous matrices in metres; joint values in rad,
in the order of the chain's movable joints.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import PyKDL

from agiprobot_measurement.station import ConfigError, JointLimits, Station
from agiprobot_measurement.station.urdf_model import UrdfJoint, UrdfModel

__all__ = [
    "KinematicModel",
    "frame_to_matrix",
]


def _frame_from_matrix(pose: np.ndarray) -> PyKDL.Frame:
    r = pose[:3, :3]
    return PyKDL.Frame(
        PyKDL.Rotation(r[0, 0], r[0, 1], r[0, 2], r[1, 0], r[1, 1], r[1, 2], r[2, 0], r[2, 1], r[2, 2]),
        PyKDL.Vector(pose[0, 3], pose[1, 3], pose[2, 3]),
    )


def frame_to_matrix(frame: PyKDL.Frame) -> np.ndarray:
    pose = np.eye(4)
    for i in range(3):
        for j in range(3):
            pose[i, j] = frame.M[i, j]
        pose[i, 3] = frame.p[i]
    return pose


def _axis_rotation_batch(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rodrigues rotation about a unit ``axis`` for each angle: (N, 3, 3)."""
    axis = axis / np.linalg.norm(axis)
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


class KinematicModel:
    """Kinematics of one chain ``base_frame`` -> ``tip_frame`` of a URDF, plus the poses of every link on it.

    Links hanging off the chain by fixed joints (e.g. the scanner housing on ``tool0``) are posed too, so
    collision checking can use :meth:`link_poses_batch`.
    """

    def __init__(
        self,
        urdf: UrdfModel,
        base_frame: str = "world",
        tip_frame: str = "laser_emitter_frame",
        limits: JointLimits | None = None,
    ):
        self.urdf = urdf
        self.base_frame = base_frame
        self.tip_frame = tip_frame
        self.chain_joints: list[UrdfJoint] = urdf.chain(base_frame, tip_frame)
        self.joint_names: list[str] = [j.name for j in self.chain_joints if j.type != "fixed"]
        for joint in self.chain_joints:
            if joint.type not in ("fixed", "revolute", "continuous"):
                raise ConfigError(f"joint '{joint.name}': type '{joint.type}' is not supported")
        if limits is not None:
            missing = [n for n in self.joint_names if n not in limits.names]
            if missing:
                raise ConfigError(f"joint limits lack joints {missing}")
            order = [limits.names.index(n) for n in self.joint_names]
            self.lower = limits.lower[order]
            self.upper = limits.upper[order]
            self.max_velocity = limits.max_velocity[order]
            self.max_acceleration = limits.max_acceleration[order]
        else:
            movable = [j for j in self.chain_joints if j.type != "fixed"]
            self.lower = np.array([j.lower for j in movable])
            self.upper = np.array([j.upper for j in movable])
            self.max_velocity = np.array([j.velocity for j in movable])
            self.max_acceleration = np.full(len(movable), np.inf)
        self.dof = len(self.joint_names)
        self._kdl_fk = PyKDL.ChainFkSolverPos_recursive(self.kdl_chain)

    @classmethod
    def from_station(cls, station: Station | None = None, tip_frame: str | None = None, base_frame: str = "world"):
        station = station or Station.load()
        return cls(
            UrdfModel(station.urdf_xml),
            base_frame=base_frame,
            tip_frame=tip_frame or station.robot.default_tip_frame,
            limits=station.limits,
        )

    # ----------------------------------------------------------------------------------------- KDL
    @cached_property
    def kdl_chain(self) -> PyKDL.Chain:
        """The chain as a PyKDL.Chain (fixed joints folded into segments, joints rotate about their axes)."""
        chain = PyKDL.Chain()
        pending = np.eye(4)  # transform accumulated since the last segment
        for joint in self.chain_joints:
            if joint.type == "fixed":
                pending = pending @ joint.origin
                continue
            # KDL: a segment = joint (at the segment's start frame) + tip transform. We place the joint at
            # the accumulated origin, and the tip at the joint frame, so consecutive origins compose.
            frame = _frame_from_matrix(pending @ joint.origin)
            axis = frame.M * PyKDL.Vector(*joint.axis)
            kdl_joint = PyKDL.Joint(joint.name, frame.p, axis, PyKDL.Joint.RotAxis)
            chain.addSegment(PyKDL.Segment(joint.name, kdl_joint, frame))
            pending = np.eye(4)
        chain.addSegment(PyKDL.Segment("tip", PyKDL.Joint(PyKDL.Joint.Fixed), _frame_from_matrix(pending)))
        return chain

    def _check_q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape[-1:] != (self.dof,):
            raise ValueError(f"expected {self.dof} joint values ({', '.join(self.joint_names)}), got shape {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError("joint values must be finite (got NaN or inf)")
        return q

    def fk_kdl(self, q: np.ndarray) -> np.ndarray:
        """Tip pose for one joint state, computed by KDL (4x4, metres)."""
        q = self._check_q(q)
        array = PyKDL.JntArray(self.dof)
        for i, value in enumerate(q):
            array[i] = float(value)
        frame = PyKDL.Frame()
        self._kdl_fk.JntToCart(array, frame)
        return frame_to_matrix(frame)

    # --------------------------------------------------------------------------------------- numpy
    def fk(self, q: np.ndarray) -> np.ndarray:
        """Tip pose for one joint state (4x4) or a batch (N, 4, 4)."""
        q = self._check_q(q)
        poses = self.link_poses_batch(np.atleast_2d(q), links=[self.tip_frame])[self.tip_frame]
        return poses[0] if q.ndim == 1 else poses

    def fk_batch(self, q: np.ndarray) -> np.ndarray:
        """Tip poses for (N, dof) joint states: (N, 4, 4)."""
        return self.fk(np.atleast_2d(q))

    def link_names(self) -> list[str]:
        """Every link posed by :meth:`link_poses_batch`: the chain and the links fixed to it."""
        return list(self.link_poses_batch(np.zeros((1, self.dof))))

    def link_poses_batch(self, q: np.ndarray, links: list[str] | None = None) -> dict[str, np.ndarray]:
        """Poses (N, 4, 4) of the chain's links (and links fixed to them) for (N, dof) joint states."""
        q = self._check_q(np.atleast_2d(q))
        n = q.shape[0]
        current = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        poses = {self.base_frame: current}
        index = 0
        for joint in self.chain_joints:
            current = current @ joint.origin
            if joint.type != "fixed":
                motion = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
                motion[:, :3, :3] = _axis_rotation_batch(joint.axis, q[:, index])
                current = current @ motion
                index += 1
            poses[joint.child] = current
        # fixed children of chain links that are not themselves on the chain
        frontier = list(poses)
        while frontier:
            parent = frontier.pop()
            for joint in self.urdf.joints.values():
                if joint.parent == parent and joint.type == "fixed" and joint.child not in poses:
                    poses[joint.child] = poses[parent] @ joint.origin
                    frontier.append(joint.child)
        if links is None:
            return poses
        unknown = [link for link in links if link not in poses]
        if unknown:
            raise ConfigError(f"unknown frame(s) {unknown}; frames: {', '.join(poses)}")
        return {link: poses[link] for link in links}

    def within_limits(self, q: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.lower - tolerance) & (q <= self.upper + tolerance), axis=-1)
