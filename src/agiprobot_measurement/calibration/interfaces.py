"""What the calibration procedure needs of the robot and the camera: two small protocols, a frame, two errors.

The procedure (:mod:`~agiprobot_measurement.calibration.procedure`) sees only these; the ROS node implements them
over ``robot_sim`` / ``/joint_states`` and the ``phoxi_camera`` services, :mod:`.simulation` over the ROS-free
renderer for the tests and the benchmark. Positions in metres in the robot base frame, joints in rad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.motion.trajectory import JointTrajectory

__all__ = [
    "STEP_FAILURES",
    "Camera",
    "CameraFrame",
    "FlangeRobot",
    "JointDriver",
    "StepError",
    "UnreachableError",
]


class StepError(InternalError):
    """A step of the collection failed on the robot's or the camera's side (no joint states, the controller or the
    camera service failed); the message says why."""


class UnreachableError(InputError):
    """A flange pose has no collision-free IK solution or no collision-free motion leads there: the point (flag
    point, path point, chessboard corner) must be moved."""


#: the failures of one robot or camera step; the path and test loops skip the point and go on
STEP_FAILURES = (StepError, UnreachableError)


@dataclass
class CameraFrame:
    """One frame of the camera, camera frame, metres.

    ``points_m``: the cloud the flange is detected in ((N, 3), or (H, W, 3) with zeros where invalid);
    ``organized_m``: the (H, W, 3) cloud and ``texture`` the (H, W) intensity image, when asked for (test mode).
    """

    points_m: np.ndarray
    organized_m: np.ndarray | None = None
    texture: np.ndarray | None = None


class Camera(Protocol):
    def capture(self, texture: bool = False) -> CameraFrame:
        """A new frame taken now; ``texture``: with the organised cloud and the texture image. Raises
        :class:`StepError` when the camera fails."""


class FlangeRobot(Protocol):
    """The robot as the calibration sees it: where its flange (tool0) is and how to move it there."""

    def current_joints(self) -> np.ndarray:
        """The joint state now (rad); :class:`StepError` when it is not known."""

    def flange_position(self, joints_rad: np.ndarray) -> np.ndarray:
        """tool0's origin in the robot base frame (metres) at ``joints_rad`` (forward kinematics)."""

    def move_to(
        self, position_m: np.ndarray, z_towards_m=None, settle_s: float = 0.3, free_yaw: bool = False
    ) -> np.ndarray:
        """Move tool0 to ``position_m``, its z axis towards ``z_towards_m`` (None: the configured point); returns
        the reached joint state. ``free_yaw``: any turn about the flange axis will do."""

    def move_to_joints(self, joints_rad: np.ndarray, what: str, settle_s: float = 0.3) -> None:
        """Move to a joint state; ``what`` names the target in error messages."""


class JointDriver(Protocol):
    """The bare robot under :class:`~agiprobot_measurement.calibration.flange_motion.PlannedFlangeRobot`."""

    def current_joints(self) -> np.ndarray:
        """The joint state now (rad); :class:`StepError` when it is not known."""

    def execute(self, trajectory: JointTrajectory, settle_s: float) -> None:
        """Run ``trajectory`` to its end and wait ``settle_s`` more (so that joint states and tf of the final pose
        reach the camera); :class:`StepError` when the motion fails."""
