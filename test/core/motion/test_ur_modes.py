"""The UR robot modes and the set_mode steps of ur_robot_driver's robot_state_helper, without ROS."""

import pytest

from agiprobot_measurement.motion.ur_modes import (
    HIGHER_MODE_MESSAGE,
    MAX_SET_MODE_STEPS,
    RobotMode,
    SafetyMode,
    UrModes,
    set_mode_step,
)


def drive(target: int, start: RobotMode, protective_stop: bool = False) -> tuple[list[str], object, UrModes]:
    """Run the helper's steps against the simulated modes: the commands sent and the final step."""
    modes, stopped, commands, first = UrModes(start), protective_stop, [], True
    for _ in range(MAX_SET_MODE_STEPS):
        safety = SafetyMode.PROTECTIVE_STOP if stopped else SafetyMode.NORMAL
        step = set_mode_step(target, modes.robot, safety, first)
        first = False
        if step.done or not step.command:
            return commands, step, modes
        commands.append(step.command)
        if step.command == "unlock_protective_stop":
            stopped = False
        else:
            assert getattr(modes, step.command)()[0]
    raise AssertionError(f"no end after {commands}")


@pytest.mark.parametrize(
    ("start", "target", "commands"),
    [
        (RobotMode.RUNNING, RobotMode.POWER_OFF, ["power_off"]),
        (RobotMode.RUNNING, RobotMode.IDLE, ["power_off", "power_on"]),
        (RobotMode.POWER_OFF, RobotMode.RUNNING, ["power_on", "brake_release"]),
        (RobotMode.IDLE, RobotMode.RUNNING, ["brake_release"]),
        (RobotMode.RUNNING, RobotMode.RUNNING, []),
    ],
)
def test_set_mode_reaches_each_selectable_mode_with_the_helpers_commands(start, target, commands):
    sent, step, modes = drive(int(target), start)
    assert sent == commands
    assert step.done and step.success and step.message == "Reached target robot mode."
    assert modes.robot == target


def test_a_protective_stop_is_unlocked_before_running():
    sent, step, modes = drive(int(RobotMode.RUNNING), RobotMode.RUNNING, protective_stop=True)
    assert sent == ["unlock_protective_stop"] and step.success and modes.robot == RobotMode.RUNNING


def test_targets_that_cannot_be_selected_abort_with_the_drivers_messages():
    booting = set_mode_step(int(RobotMode.BOOTING), RobotMode.RUNNING, SafetyMode.NORMAL)
    assert booting.done and not booting.success
    assert booting.message == "Requested target mode BOOTING which cannot be explicitly selected."
    illegal = set_mode_step(42, RobotMode.RUNNING, SafetyMode.NORMAL)
    assert illegal.done and not illegal.success and illegal.message == "Requested illegal mode."


def test_an_emergency_stop_waits_for_a_human_and_a_higher_mode_later_aborts():
    stopped = set_mode_step(int(RobotMode.RUNNING), RobotMode.RUNNING, SafetyMode.ROBOT_EMERGENCY_STOP)
    assert not stopped.done and stopped.command == ""
    overshoot = set_mode_step(int(RobotMode.IDLE), RobotMode.RUNNING, SafetyMode.NORMAL, first=False)
    assert overshoot.done and not overshoot.success and overshoot.message == HIGHER_MODE_MESSAGE


def test_a_program_plays_only_on_a_running_robot():
    modes = UrModes(RobotMode.RUNNING)
    assert modes.can_play
    assert modes.power_off() == (True, "Powering off") and not modes.can_play
    assert modes.brake_release() == (True, "Brake releasing") and modes.robot == RobotMode.POWER_OFF  # no effect
    assert modes.power_on() == (True, "Powering on") and modes.robot == RobotMode.IDLE and not modes.can_play
    modes.brake_release()
    assert modes.can_play
