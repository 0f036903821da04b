"""Forward kinematics of the station's robot from its URDF: a PyKDL chain, and a vectorised numpy form.

``KinematicModel`` is built from the URDF produced by ``urdf/station.urdf.xacro`` (see
:mod:`agiprobot_measurement.station.urdf_model`), whose arm joint origins come from the robot's kinematics file
(ur_calibration's output in ur_description's format, :mod:`agiprobot_measurement.station.ur_kinematics`; config/
ur10e.yaml's ``kinematics_config``). :func:`ur_arm_frames` is the same chain straight from such a file, without a
URDF. Poses are 4x4 homogeneous matrices in metres; joint values in rad, in the order of the chain's movable joints.
"""

from __future__ import annotations

import copy
import dataclasses
from functools import cached_property
from pathlib import Path

import numpy as np
import PyKDL

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import number, read_yaml, require
from agiprobot_measurement.common.geometry import pose_matrix
from agiprobot_measurement.motion.errors import MotionInputError
from agiprobot_measurement.motion.kinematics_kernels import COMPILED_FROM_STATES, chain_frames
from agiprobot_measurement.station import ConfigError, JointLimits, Station, UrKinematics, load_ur_kinematics
from agiprobot_measurement.station.ur_kinematics import UR_BASE_RPY_RAD, UR_FLANGE_RPY_RAD, UR_TOOL0_RPY_RAD
from agiprobot_measurement.station.urdf_model import UrdfJoint, UrdfModel

__all__ = [
    "UR_ARM_LINKS",
    "UR_FIXED_FRAMES",
    "KinematicModel",
    "TrueKinematics",
    "frame_to_matrix",
    "load_kinematics_correction",
    "scaled_origin",
    "ur_arm_frames",
    "with_arm_kinematics",
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


#: ur_description's fixed frames of a UR arm (parent, child, xyz m, rpy rad)
UR_FIXED_FRAMES = (
    ("base_link", "base_link_inertia", (0.0, 0.0, 0.0), UR_BASE_RPY_RAD),
    ("base_link", "base", (0.0, 0.0, 0.0), UR_BASE_RPY_RAD),
    ("wrist_3_link", "flange", (0.0, 0.0, 0.0), UR_FLANGE_RPY_RAD),
    ("flange", "tool0", (0.0, 0.0, 0.0), UR_TOOL0_RPY_RAD),
)
UR_ARM_LINKS = ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")


def ur_arm_frames(arm: UrKinematics, q: np.ndarray) -> dict[str, np.ndarray]:
    """ur_description's frames of a UR arm in ``base_link`` (REP-103) for joint states (N, 6) rad: (N, 4, 4) each.

    The chain of ur_description's ur_macro.xacro: base_link -> base_link_inertia rpy(0, 0, pi) -> shoulder_pan_joint
    (origin ``arm``'s shoulder) -> shoulder_link -> ... -> wrist_3_link; base_link -> base rpy(0, 0, pi) (the DH
    base, the controller's Base); wrist_3_link -> flange rpy(0, -pi/2, -pi/2) -> tool0 rpy(pi/2, 0, pi/2). Every
    joint turns about its frame's z axis."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.ndim != 2 or q.shape[1] != 6 or not np.all(np.isfinite(q)):
        raise MotionInputError(f"expected finite joint states of shape (N, 6), got shape {q.shape}")
    n = q.shape[0]
    fixed = {child: (parent, pose_matrix(xyz, rpy)) for parent, child, xyz, rpy in UR_FIXED_FRAMES}
    frames = {"base_link": np.broadcast_to(np.eye(4), (n, 4, 4)).copy()}
    frames["base_link_inertia"] = frames["base_link"] @ fixed["base_link_inertia"][1]
    frames["base"] = frames["base_link"] @ fixed["base"][1]
    current = frames["base_link_inertia"]
    z = np.array([0.0, 0.0, 1.0])
    for i, (link, origin) in enumerate(zip(UR_ARM_LINKS, arm.joint_origins(), strict=True)):
        motion = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        motion[:, :3, :3] = _axis_rotation_batch(z, q[:, i])
        current = current @ origin @ motion
        frames[link] = current
    frames["flange"] = frames["wrist_3_link"] @ fixed["flange"][1]
    frames["tool0"] = frames["flange"] @ fixed["tool0"][1]
    return frames


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
            raise MotionInputError(
                f"expected {self.dof} joint values ({', '.join(self.joint_names)}), got shape {q.shape}"
            )
        if not np.all(np.isfinite(q)):
            raise MotionInputError("joint values must be finite (got NaN or inf)")
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
    @cached_property
    def _segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The chain folded for FK: per movable joint the transform from the previous joint's moving frame to its
        frame (dof, 4, 4) and its unit axis (dof, 3); the last moving frame -> tip (4, 4)."""
        pre, axes, acc = [], [], np.eye(4)
        for joint in self.chain_joints:
            acc = acc @ joint.origin
            if joint.type != "fixed":
                pre.append(acc)
                axes.append(np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis))
                acc = np.eye(4)
        return np.array(pre).reshape(-1, 4, 4), np.array(axes).reshape(-1, 3), acc

    @property
    def fk_segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The chain folded for FK (read only): per movable joint the transform (dof, 4, 4) from the previous
        moving frame to its frame, its unit axis (dof, 3), and the last moving frame -> tip (4, 4); metres."""
        return self._segments

    def _moving_frames(self, q: np.ndarray, joints: bool = False) -> tuple[np.ndarray | None, np.ndarray]:
        """The tip poses (N, 4, 4) and, with ``joints``, each joint's frame before its rotation (N, dof, 4, 4), for
        (N, dof) joint states: rotations and translations kept apart, a turn about z as two column mixes."""
        pre, axes, tip = self._segments
        n = q.shape[0]
        if not joints and n >= COMPILED_FROM_STATES:
            return None, chain_frames(q, pre, axes, tip)[1]
        rotation = np.broadcast_to(np.eye(3), (n, 3, 3))
        translation = np.zeros((n, 3))
        frames = np.zeros((n, self.dof, 4, 4)) if joints else None
        for k in range(self.dof):
            translation = translation + rotation @ pre[k, :3, 3]
            rotation = rotation @ pre[k, :3, :3]
            if joints:
                frames[:, k, :3, :3], frames[:, k, :3, 3], frames[:, k, 3, 3] = rotation, translation, 1.0
            if axes[k, 2] == 1.0:
                c, s = np.cos(q[:, k])[:, None], np.sin(q[:, k])[:, None]
                x, y = rotation[:, :, 0], rotation[:, :, 1]
                rotation = np.stack([x * c + y * s, y * c - x * s, rotation[:, :, 2]], axis=2)
            else:
                rotation = rotation @ _axis_rotation_batch(axes[k], q[:, k])
        poses = np.zeros((n, 4, 4))
        poses[:, :3, :3] = rotation @ tip[:3, :3]
        poses[:, :3, 3] = translation + rotation @ tip[:3, 3]
        poses[:, 3, 3] = 1.0
        return frames, poses

    def fk(self, q: np.ndarray) -> np.ndarray:
        """Tip pose for one joint state (4x4) or a batch (N, 4, 4)."""
        q = self._check_q(q)
        poses = self._moving_frames(np.atleast_2d(q))[1]
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

    def fk_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip poses (N, 4, 4) and geometric Jacobians (N, 6, dof) for (N, dof) joint states, in the base frame:
        rows 0-2 the tip origin's velocity (m/rad), rows 3-5 the angular velocity (rad/rad)."""
        q = self._check_q(np.atleast_2d(q))
        joints, tip = self._moving_frames(q, joints=True)
        axes = np.einsum("nkij,kj->nki", joints[:, :, :3, :3], self._segments[1])  # (N, dof, 3)
        lever = tip[:, None, :3, 3] - joints[:, :, :3, 3]
        jacobian = np.concatenate([np.cross(axes, lever), axes], axis=2)  # (N, dof, 6)
        return tip, np.swapaxes(jacobian, 1, 2)

    def within_limits(self, q: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.lower - tolerance) & (q <= self.upper + tolerance), axis=-1)


# ------------------------------------------------------------------------------ true (calibrated) kinematics
def load_kinematics_correction(path: str | Path | None = None) -> tuple[bool, UrKinematics, float]:
    """``(true_kinematics enabled, the true robot's kinematics file, deviation scale)`` from the simulation's true
    robot file (default ``config/ur10e_kinematics_correction.yaml``: ``true_kinematics``, ``kinematics_config`` (a
    kinematics file in ur_calibration's format, relative to the file's folder), ``scale``); ConfigError naming the
    key on bad content."""
    path = Path(path) if path else CONFIG_DIR / "ur10e_kinematics_correction.yaml"
    data = read_yaml(path)
    where = str(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")
    enabled = require(data, "true_kinematics", where)
    if not isinstance(enabled, bool):
        raise ConfigError(f"{where}: 'true_kinematics' must be true or false")
    scale = number(data.get("scale", 1.0), f"{where}: 'scale'", low=0.0, high=100.0)
    name = require(data, "kinematics_config", where)
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"{where}: 'kinematics_config' must be a file name, got {name!r}")
    arm_path = Path(name) if Path(name).is_absolute() else path.parent / name
    return enabled, load_ur_kinematics(arm_path), scale


def scaled_origin(nominal: np.ndarray, true: np.ndarray, scale: float) -> np.ndarray:
    """A joint origin (4x4) deviating from ``nominal`` by ``scale`` times ``true``'s deviation, in the nominal
    frame's own coordinates (offset times the scale, rotation angle times the scale)."""
    from scipy.spatial.transform import Rotation

    local = np.linalg.inv(nominal) @ true
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(Rotation.from_matrix(local[:3, :3]).as_rotvec() * scale).as_matrix()
    out[:3, 3] = local[:3, 3] * scale
    return nominal @ out


def with_arm_kinematics(model: KinematicModel, arm: UrKinematics, deviation_scale: float = 1.0) -> KinematicModel:
    """``model`` with the arm's joint origins taken from ``arm`` (a kinematics file): the same chain, links, limits
    and geometry, the robot of that file. ``deviation_scale`` != 1: each joint origin deviates from ``model``'s by
    that multiple of ``arm``'s deviation (0: ``model`` itself)."""
    urdf = copy.copy(model.urdf)
    urdf.joints = dict(model.urdf.joints)
    urdf.joint_by_child = dict(model.urdf.joint_by_child)
    for name, origin in zip(arm.joint_names, arm.joint_origins(), strict=True):
        joint = urdf.joints.get(name)
        if joint is None:
            raise ConfigError(f"kinematics file {arm.source}: the URDF has no joint '{name}'")
        if deviation_scale != 1.0:
            origin = scaled_origin(joint.origin, origin, deviation_scale)
        changed = dataclasses.replace(joint, origin=origin)
        urdf.joints[name] = changed
        urdf.joint_by_child[changed.child] = changed
    out = copy.copy(model)
    out.urdf = urdf
    out.chain_joints = urdf.chain(model.base_frame, model.tip_frame)
    out.__dict__.pop("kdl_chain", None)
    out.__dict__.pop("_segments", None)
    out._kdl_fk = PyKDL.ChainFkSolverPos_recursive(out.kdl_chain)
    return out


class TrueKinematics:
    """Where a robot whose kinematics differ from the model's really puts its links: the model's chain with the
    joint origins of the true robot's kinematics file (ur_calibration's output of that robot).

    The simulation renders and moves the links by this; the planner, IK and calibration keep their
    :class:`KinematicModel` (the nominal arm, or a kinematics file of their own). Same call signatures as
    :class:`KinematicModel` for ``link_poses_batch`` and ``fk``.

    ``deviation_scale``: a robot whose every joint origin deviates from the model's by this multiple of the true
    file's deviation (offset times the scale, rotation angle times the scale): the flange error grows about
    linearly with it.
    """

    def __init__(self, nominal: KinematicModel, true_arm: UrKinematics, deviation_scale: float = 1.0):
        self.nominal = nominal
        self.arm = true_arm
        self.deviation_scale = float(deviation_scale)
        self.model = with_arm_kinematics(nominal, true_arm, self.deviation_scale)
        self.dof = nominal.dof
        self.joint_names = nominal.joint_names
        self.base_frame, self.tip_frame = nominal.base_frame, nominal.tip_frame

    def link_poses_batch(self, q: np.ndarray, links: list[str] | None = None) -> dict[str, np.ndarray]:
        """True poses (N, 4, 4) of the links :meth:`KinematicModel.link_poses_batch` poses."""
        return self.model.link_poses_batch(q, links)

    def fk(self, q: np.ndarray) -> np.ndarray:
        """True tip pose for one joint state (4x4) or a batch (N, 4, 4)."""
        q = np.asarray(q, dtype=float)
        poses = self.link_poses_batch(np.atleast_2d(q), links=[self.tip_frame])[self.tip_frame]
        return poses[0] if q.ndim == 1 else poses

    def solve_near(self, pose: np.ndarray, seed_q: np.ndarray, iterations: int = 20, tolerance: float = 1e-12):
        """Joint state (6,) near ``seed_q`` at which the true tip reaches ``pose`` (4x4): Gauss-Newton on the
        position and rotation-vector error with a numeric Jacobian. None when it does not converge (1e-9 m/rad)."""
        from scipy.spatial.transform import Rotation

        def error(q_batch):
            reached = self.fk(q_batch)
            position = pose[:3, 3] - reached[:, :3, 3]
            rotation = Rotation.from_matrix(pose[:3, :3] @ np.swapaxes(reached[:, :3, :3], 1, 2)).as_rotvec()
            return np.concatenate([position, rotation], axis=1)

        q = np.array(seed_q, dtype=float)
        step = 1e-7
        for _ in range(iterations):
            batch = np.vstack([q, q + step * np.eye(6)])
            errors = error(batch)
            e = errors[0]
            if e @ e < tolerance**2:
                return q
            jacobian = -(errors[1:] - e).T / step
            q = q + np.linalg.lstsq(jacobian, e, rcond=None)[0]
        e = error(q[None])[0]
        return q if np.abs(e).max() < 1e-9 else None
