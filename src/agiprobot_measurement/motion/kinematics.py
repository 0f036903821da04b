"""Forward kinematics of the station's robot from its URDF: a PyKDL chain, and a vectorised numpy form.

``KinematicModel`` is built from the URDF produced by ``urdf/station.urdf.xacro`` (see
:mod:`agiprobot_measurement.station.urdf_model`). Poses are 4x4 homogeneous matrices in metres; joint values in rad,
in the order of the chain's movable joints.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import PyKDL

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.common.config import number, read_yaml, require, vector
from agiprobot_measurement.motion.errors import MotionInputError
from agiprobot_measurement.station import ConfigError, JointLimits, Station
from agiprobot_measurement.station.urdf_model import UrdfJoint, UrdfModel

__all__ = [
    "DhCorrection",
    "KinematicModel",
    "TrueKinematics",
    "dh_frames",
    "frame_to_matrix",
    "load_kinematics_correction",
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


# ------------------------------------------------------------------------------ true (calibrated) kinematics
@dataclass(frozen=True)
class DhCorrection:
    """A robot's kinematic calibration in the UR controller's form: per joint, deltas added to the nominal standard
    DH parameters, ``Rz(theta + delta_theta + q) Tz(d + delta_d) Tx(a + delta_a) Rx(alpha + delta_alpha)``
    (metres, rad, joint order of the robot configuration)."""

    delta_a_m: np.ndarray
    delta_d_m: np.ndarray
    delta_alpha_rad: np.ndarray
    delta_theta_rad: np.ndarray

    def __post_init__(self):
        for name in ("delta_a_m", "delta_d_m", "delta_alpha_rad", "delta_theta_rad"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (6,) or not np.all(np.isfinite(value)):
                raise ConfigError(f"kinematics correction: '{name}' must be 6 finite numbers, got {value.tolist()}")
            object.__setattr__(self, name, value)

    @classmethod
    def zero(cls) -> DhCorrection:
        return cls(np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6))

    def scaled(self, factor: float) -> DhCorrection:
        """Every delta times ``factor`` (0: the nominal robot)."""
        return DhCorrection(
            self.delta_a_m * factor,
            self.delta_d_m * factor,
            self.delta_alpha_rad * factor,
            self.delta_theta_rad * factor,
        )

    @property
    def is_zero(self) -> bool:
        return not any(
            np.any(v != 0.0) for v in (self.delta_a_m, self.delta_d_m, self.delta_alpha_rad, self.delta_theta_rad)
        )


def load_kinematics_correction(path: str | Path | None = None) -> tuple[bool, DhCorrection]:
    """``(true_kinematics enabled, correction, deviation scale)`` from a correction file (default
    ``config/ur10e_kinematics_correction.yaml``); ConfigError naming the key on bad content."""
    path = Path(path) if path else CONFIG_DIR / "ur10e_kinematics_correction.yaml"
    data = read_yaml(path)
    where = str(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")
    enabled = require(data, "true_kinematics", where)
    if not isinstance(enabled, bool):
        raise ConfigError(f"{where}: 'true_kinematics' must be true or false")
    scale = number(data.get("scale", 1.0), f"{where}: 'scale'")
    deltas = require(data, "dh_delta", where)
    correction = DhCorrection(
        *(
            vector(require(deltas, key, where), 6, f"{where}: dh_delta.{key}")
            for key in ("delta_a_m", "delta_d_m", "delta_alpha_rad", "delta_theta_rad")
        )
    )
    return enabled, correction, scale


def dh_frames(q: np.ndarray, d_m, a_m, alpha_rad, theta_offset_rad=None) -> np.ndarray:
    """Frames 0..6 of a standard-DH chain in its base frame for joint states (N, 6): (N, 7, 4, 4)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    theta = q + (0.0 if theta_offset_rad is None else np.asarray(theta_offset_rad, dtype=float))
    n = q.shape[0]
    frames = np.empty((n, 7, 4, 4))
    frames[:, 0] = np.eye(4)
    for i in range(6):
        ct, st = np.cos(theta[:, i]), np.sin(theta[:, i])
        ca, sa = np.cos(alpha_rad[i]), np.sin(alpha_rad[i])
        link = np.zeros((n, 4, 4))
        link[:, 0, 0], link[:, 0, 1], link[:, 0, 2], link[:, 0, 3] = ct, -st * ca, st * sa, a_m[i] * ct
        link[:, 1, 0], link[:, 1, 1], link[:, 1, 2], link[:, 1, 3] = st, ct * ca, -ct * sa, a_m[i] * st
        link[:, 2, 1], link[:, 2, 2], link[:, 2, 3] = sa, ca, d_m[i]
        link[:, 3, 3] = 1.0
        frames[:, i + 1] = frames[:, i] @ link
    return frames


class TrueKinematics:
    """Where a robot with a kinematic error really puts its links: the nominal model's link poses moved by the
    difference between the corrected and the nominal DH frames.

    The URDF is built from the DH parameters (``urdf/ur10e.xacro``): ``base_link`` is the DH base frame and the child
    link of joint k moves rigidly with DH frame k, as do the links fixed to it (``tool0`` = frame 6, the flange disc,
    a board on it). So a link's true pose is ``F_true_k(q) F_nom_k(q)^-1`` (base_link frame) times its nominal pose.
    The planner, IK and calibration keep the nominal :class:`KinematicModel`; only the simulation uses this.
    Same call signatures as :class:`KinematicModel` for ``link_poses_batch`` and ``fk``.

    ``deviation_scale``: a robot whose every DH frame deviates from the nominal one by this multiple of the
    correction's deviation, in the frame's own coordinates (offset times the scale, rotation angle times the scale):
    the flange error grows linearly with it. Multiplying the controller's deltas instead (:meth:`DhCorrection.scaled`)
    does not: they compensate each other (the metre-sized delta_d of the parallel joints), so half the deltas can
    give a larger error than all of them.
    """

    def __init__(self, nominal: KinematicModel, robot, correction: DhCorrection, deviation_scale: float = 1.0):
        if list(robot.joint_names) != nominal.joint_names:
            raise ConfigError(
                f"true kinematics: the chain's joints {nominal.joint_names} are not the robot's {list(robot.joint_names)}"
            )
        self.nominal = nominal
        self.robot = robot
        self.correction = correction
        self.deviation_scale = float(deviation_scale)
        self.dof = nominal.dof
        self.joint_names = nominal.joint_names
        self.base_frame, self.tip_frame = nominal.base_frame, nominal.tip_frame
        self._chain_from_dh = nominal.urdf.fixed_transform(nominal.base_frame, robot.base_frame)
        self._dh_from_chain = np.linalg.inv(self._chain_from_dh)
        self._frame_index = self._link_frame_index()
        self._verify_nominal_against_urdf()

    def _link_frame_index(self) -> dict[str, int | None]:
        """Per posed link: the DH frame it moves with (None: fixed to the chain's base, before the robot)."""
        index: dict[str, int | None] = {self.nominal.base_frame: None}
        k = 0
        for joint in self.nominal.chain_joints:
            if joint.type != "fixed":
                k += 1
            index[joint.child] = k if (k or joint.child == self.robot.base_frame) else None
        frontier = list(index)
        while frontier:
            parent = frontier.pop()
            for joint in self.nominal.urdf.joints.values():
                if joint.parent == parent and joint.type == "fixed" and joint.child not in index:
                    index[joint.child] = index[parent]
                    frontier.append(joint.child)
        return index

    def _verify_nominal_against_urdf(self) -> None:
        states = np.random.default_rng(0).uniform(-np.pi, np.pi, (8, 6))
        nominal = dh_frames(states, self.robot.d_m, self.robot.a_m, self.robot.alpha_rad)
        flange = self.nominal.link_poses_batch(states, links=[self.robot.flange_frame])[self.robot.flange_frame]
        if np.abs(self._chain_from_dh @ nominal[:, 6] - flange).max() > 1e-9:
            raise ConfigError("true kinematics: the DH parameters do not reproduce the URDF's flange frame")

    def frame_corrections(self, q: np.ndarray) -> np.ndarray:
        """(N, 7, 4, 4): F_true_k F_nom_k^-1 per DH frame k, in the chain's base frame."""
        r, c = self.robot, self.correction
        nominal = dh_frames(q, r.d_m, r.a_m, r.alpha_rad)
        true = dh_frames(
            q, r.d_m + c.delta_d_m, r.a_m + c.delta_a_m, r.alpha_rad + c.delta_alpha_rad, c.delta_theta_rad
        )
        if self.deviation_scale != 1.0:
            from scipy.spatial.transform import Rotation

            local = np.linalg.inv(nominal) @ true  # (N, 7, 4, 4): each frame's deviation in its own coordinates
            shape = local.shape[:2]
            rotvec = Rotation.from_matrix(local[..., :3, :3].reshape(-1, 3, 3)).as_rotvec() * self.deviation_scale
            local[..., :3, :3] = Rotation.from_rotvec(rotvec).as_matrix().reshape(*shape, 3, 3)
            local[..., :3, 3] *= self.deviation_scale
            true = nominal @ local
        return self._chain_from_dh @ true @ np.linalg.inv(nominal) @ self._dh_from_chain

    def link_poses_batch(self, q: np.ndarray, links: list[str] | None = None) -> dict[str, np.ndarray]:
        """True poses (N, 4, 4) of the links :meth:`KinematicModel.link_poses_batch` poses."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        poses = self.nominal.link_poses_batch(q, links)
        corrections = self.frame_corrections(q)
        out = {}
        for link, pose in poses.items():
            k = self._frame_index.get(link)
            out[link] = pose if not k else corrections[:, k] @ pose
        return out

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
