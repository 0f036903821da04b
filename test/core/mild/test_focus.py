"""Looking at a focus point (agiprobot_measurement.mild.focus) with the robot model in process as the services."""

import math

import numpy as np
import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.mild.focus import ModelFocusServices, aim_at, focus_on
from agiprobot_measurement.mild.robot_model import MildRobotModel
from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.station import CONFIG_DIR

TOLERANCE = math.radians(0.5)


@pytest.fixture(scope="module")
def services():
    # the real MILD: pan +/-20 deg, so a point behind needs the base to turn
    return ModelFocusServices(MildRobotModel.load(CONFIG_DIR / "mild_robot_model_services_real.yaml", map_file=False))


def _miss(services, state, point):
    pose = services.camera_pose(state)
    to_point = np.asarray(point) - pose[:3, 3]
    return math.acos(np.clip(pose[:3, 0] @ to_point / np.linalg.norm(to_point), -1.0, 1.0))


def test_a_point_in_front_is_faced_by_the_ptu_alone(services):
    state = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
    point = np.array([2.5, 1.4, 1.0])
    result = focus_on(services, state, point, 0.95, TOLERANCE)
    assert not result.turned_base and result.miss_rad <= TOLERANCE
    assert (result.state.rotation, result.state.x, result.state.y) == (0.0, 1.0, 1.0)
    assert result.state.pan > 0.0  # the point is to the left (+y)
    assert _miss(services, result.state, point) == pytest.approx(result.miss_rad, abs=1e-9)


def test_a_point_behind_turns_the_base_towards_it_first(services):
    state = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
    point = np.array([-1.0, 1.0, 1.0])
    _, miss = aim_at(services, state, point, 0.95)
    assert miss > TOLERANCE  # the pan limits keep the camera from turning round
    result = focus_on(services, state, point, 0.95, TOLERANCE)
    assert result.turned_base and result.miss_rad <= TOLERANCE
    assert result.state.rotation == pytest.approx(math.pi)
    assert (result.state.x, result.state.y) == (1.0, 1.0)


def test_a_point_out_of_the_tilt_range_is_reported_as_missed(services):
    state = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
    result = focus_on(services, state, [1.3, 1.0, 4.0], 0.95, TOLERANCE)  # almost straight above
    assert result.miss_rad > TOLERANCE
    assert result.state.tilt == pytest.approx(services.model.tilt_limits[1])


@pytest.mark.parametrize("point", [[np.nan, 1.0, 1.0], [1.0, np.inf, 1.0], [1e12, 0.0, 1.0], [1.0, 1.0]])
def test_a_bad_focus_point_is_refused_before_any_call(point):
    class Refusing:
        def camera_pose(self, state):
            raise AssertionError("no service call for a bad point")

        pose_correction = camera_pose

    with pytest.raises(InputError, match="focus point"):
        focus_on(Refusing(), RobotState(0.0, 0.0, 0.0, 1.0, 1.0), point, 0.95, TOLERANCE)
