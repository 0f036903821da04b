"""The simulated MILD's motion (agiprobot_measurement.mild.sim): limits, the drive to a command, placing."""

import math

import numpy as np
import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.mild.sim import MildMotion, MotionRefused
from agiprobot_measurement.mild.state import RobotState

PAN = (math.radians(-60), math.radians(60))
TILT = (math.radians(-30), math.radians(30))
SPEEDS = (1.0, 0.5, 0.8, 0.5)  # pan, tilt, rotation rad/s; base m/s


@pytest.fixture()
def motion():
    return MildMotion(RobotState(0.0, 0.0, 0.0, 1.0, 1.0), PAN, TILT, SPEEDS)


def test_refuses_states_outside_the_ptu_limits_and_non_finite_ones(motion):
    assert motion.problem(RobotState(math.radians(60), 0.0)) == ""
    assert "pan 70.00 deg outside [-60.0, 60.0]" in motion.problem(RobotState(math.radians(70), 0.0))
    assert "tilt -40.00 deg outside [-30.0, 30.0]" in motion.problem(RobotState(0.0, math.radians(-40)))
    assert "x = nan is not finite" in motion.problem(RobotState(0.0, 0.0, 0.0, math.nan, 0.0))
    with pytest.raises(MotionRefused, match="pan") as error:
        motion.command(RobotState(2.0, 0.0), now_s=0.0)
    assert isinstance(error.value, InputError)
    with pytest.raises(MotionRefused):
        MildMotion(RobotState(0.0, 1.0), PAN, TILT, SPEEDS)
    assert not motion.moving


def test_the_sim_and_the_robot_model_services_refuse_with_the_same_check(motion):
    from agiprobot_measurement.mild.state import state_problem

    for state in (RobotState(1e12, 0.0), RobotState(0.0, math.radians(31)), RobotState(0.0, 0.0, 1e12, 1.0, 1.0)):
        assert motion.problem(state) == state_problem(state, PAN, TILT, "state") != ""
    assert "1e+12 rad" in motion.problem(RobotState(1e12, 0.0))
    with pytest.raises(MotionRefused, match="x = 1e\\+12 m lies beyond"):
        motion.place(RobotState(0.0, 0.0, 0.0, 1e12, 1.0))


def test_every_axis_finishes_together_at_the_slowest_axis_pace(motion):
    target = RobotState(0.5, 0.25, 0.4, 2.0, 1.0)  # pan 0.5 s, tilt 0.5 s, rotation 0.5 s, base 1 m -> 2 s
    assert motion.command(target, now_s=10.0) == pytest.approx(2.0)
    halfway = motion.state_at(11.0)
    np.testing.assert_allclose(halfway.as_array(), [0.25, 0.125, 0.2, 1.5, 1.0])
    assert motion.moving
    np.testing.assert_allclose(motion.state_at(12.5).as_array(), target.as_array())
    assert not motion.moving


def test_the_base_turns_the_shorter_way_round_and_ends_wrapped(motion):
    motion.place(RobotState(0.0, 0.0, math.radians(170), 1.0, 1.0))
    duration = motion.command(RobotState(0.0, 0.0, math.radians(-170), 1.0, 1.0), now_s=0.0)
    assert duration == pytest.approx(math.radians(20) / SPEEDS[2])
    assert motion.state_at(duration / 2).rotation == pytest.approx(math.radians(180))
    assert motion.state_at(duration).rotation == pytest.approx(math.radians(-170))


def test_a_new_command_replaces_the_old_one_and_placing_stops_the_drive(motion):
    motion.command(RobotState(0.0, 0.0, 0.0, 3.0, 1.0), now_s=0.0)
    motion.state_at(1.0)  # the base at x = 1.5 m
    motion.command(RobotState(0.0, 0.0, 0.0, 1.5, 2.0), now_s=1.0)
    np.testing.assert_allclose(motion.state_at(3.0).as_array(), [0.0, 0.0, 0.0, 1.5, 2.0])
    motion.command(RobotState(0.0, 0.0, 0.0, 0.0, 0.0), now_s=3.0)
    motion.place(RobotState(0.1, 0.1, 0.1, 5.0, 5.0))
    assert not motion.moving
    np.testing.assert_allclose(motion.state_at(100.0).as_array(), [0.1, 0.1, 0.1, 5.0, 5.0])
