"""Making the MILD look at a 3-D focus point: the PTU aimed at it, the base turned in place first when the PTU's
limits keep the camera from facing it.

The robot model is reached through :class:`FocusServices` (the node set_focus_point calls asr_robot_model_services'
CalculateCameraPose and CalculateCameraPoseCorrection; tests use :class:`ModelFocusServices` over a
:class:`~agiprobot_measurement.mild.robot_model.MildRobotModel`). Metres and radians, map frame; camera poses are the
camera mount frame's (the camera looks along its +x axis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from agiprobot_measurement.mild.robot_model import MildRobotModel
from agiprobot_measurement.mild.state import RobotState, check_position

__all__ = ["FocusResult", "FocusServices", "ModelFocusServices", "aim_at", "focus_on"]


class FocusServices(Protocol):
    """The two robot-model calls focusing needs."""

    def camera_pose(self, state: RobotState) -> np.ndarray:
        """map <- camera mount (4x4) of ``state`` (forward kinematics)."""

    def pose_correction(self, state: RobotState, orientation_xyzw: np.ndarray, position_m: np.ndarray):
        """(pan, tilt) rad aiming the camera at the view centre of the requested pose, the base kept where it is."""


class ModelFocusServices:
    """:class:`FocusServices` answered by a :class:`MildRobotModel` in the same process."""

    def __init__(self, model: MildRobotModel):
        self.model = model

    def camera_pose(self, state: RobotState) -> np.ndarray:
        return self.model.camera_pose(state)

    def pose_correction(self, state, orientation_xyzw, position_m):
        correction = self.model.camera_pose_correction(state, position_m, orientation_xyzw)
        return correction.pan, correction.tilt


@dataclass(frozen=True)
class FocusResult:
    """Where to send the MILD, and how far (rad) its view axis then still misses the point."""

    state: RobotState
    miss_rad: float
    turned_base: bool


def aim_at(services: FocusServices, state: RobotState, point_m, view_distance_m: float) -> tuple[RobotState, float]:
    """The PTU correction towards ``point_m`` from ``state``'s base, and the angle (rad) left between the corrected
    camera's view axis and the point."""
    point = np.asarray(point_m, dtype=float)
    camera = services.camera_pose(state)
    direction = point - camera[:3, 3]
    direction /= np.linalg.norm(direction)
    # any pose whose view centre is the point will do: from the current camera towards it
    yaw, pitch = math.atan2(direction[1], direction[0]), math.asin(np.clip(direction[2], -1, 1))
    orientation = Rotation.from_euler("ZY", [yaw, -pitch]).as_quat()
    position = point - view_distance_m * direction
    pan, tilt = services.pose_correction(state, orientation, position)
    aimed = RobotState(pan, tilt, state.rotation, state.x, state.y)
    pose = services.camera_pose(aimed)
    to_point = point - pose[:3, 3]
    miss = math.acos(np.clip(pose[:3, 0] @ to_point / np.linalg.norm(to_point), -1.0, 1.0))
    return aimed, miss


def focus_on(
    services: FocusServices, state: RobotState, point_m, view_distance_m: float, tolerance_rad: float
) -> FocusResult:
    """The state that looks at ``point_m``: the PTU aimed from where the base is; when that misses by more than
    ``tolerance_rad``, the base turned in place towards the point (pan 0) and the PTU aimed again. A point that is not
    finite or absurdly far (:func:`~agiprobot_measurement.mild.state.check_position`) is an InputError."""
    point = check_position(point_m, "focus point", size=3)
    target, miss = aim_at(services, state, point, view_distance_m)
    if miss <= tolerance_rad:
        return FocusResult(target, miss, False)
    heading = math.atan2(point[1] - state.y, point[0] - state.x)
    turned = RobotState(0.0, state.tilt, heading, state.x, state.y)
    target, miss = aim_at(services, turned, point, view_distance_m)
    return FocusResult(target, miss, True)
