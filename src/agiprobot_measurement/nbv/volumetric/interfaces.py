"""What the 3D next-best-view loop needs from a robot and a camera.

The loop (:mod:`.reconstruction`) plans every motion itself (closed-form IK, FCL collision, OMPL) and only asks
the robot for its joint state and to run a trajectory, and the camera for one frame. The simulated station
(:mod:`agiprobot_measurement.nbv.simulation.station3d`) and the ROS node (``ros/nbv_interfaces.py``) implement these protocols. World frame, metres,
rad throughout; ``sigma_mm`` is the one per-point quantity in millimetres (the PhoXi confidence).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from agiprobot_measurement.errors import InternalError

if TYPE_CHECKING:  # the protocols name the type; importing motion here would load it for every user of this module
    from agiprobot_measurement.motion.trajectory import JointTrajectory

__all__ = ["CaptureError", "CapturedView", "MotionError", "NBVCamera", "NBVRobot"]


class CaptureError(InternalError):
    """A camera frame could not be taken (device fault, timeout, no pose at the capture stamp)."""


class MotionError(InternalError):
    """The robot did not complete a trajectory (aborted, preempted, timeout, not starting at the current state)."""


@dataclass
class CapturedView:
    """One frame of the scanner, ready to fuse.

    ``points_m`` holds ONLY valid pixels (world frame), so that the map carves free space only along rays that
    really hit something: a missing PhoXi pixel may be a projector shadow.
    """

    points_m: np.ndarray  # (N,3) world frame, valid pixels only
    normals: np.ndarray  # (N,3) world frame unit normals
    sigma_mm: np.ndarray  # (N,) per-point inaccuracy (PhoXi confidence), mm
    camera_pose: np.ndarray  # world <- camera (4,4) at capture time, z = optical axis
    depth_m: np.ndarray | None = None  # (H,W) organised depth (0 = invalid) for the TSDF, camera frame, m
    intrinsics: object | None = None  # sensors.phoxi CameraIntrinsics of depth_m
    stamp_s: float = 0.0


@runtime_checkable
class NBVCamera(Protocol):
    def capture(self) -> CapturedView:
        """One frame at the current sensor pose; raises :class:`CaptureError`."""
        ...


@runtime_checkable
class NBVRobot(Protocol):
    def current_joints(self) -> np.ndarray:
        """Joint state, rad, UR10e order (shoulder_pan ... wrist_3)."""
        ...

    def execute(self, trajectory: JointTrajectory) -> None:
        """Run ``trajectory`` and block until done; raises :class:`MotionError`."""
        ...
