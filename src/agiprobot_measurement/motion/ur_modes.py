"""The UR controller's robot and safety modes, the dashboard commands that change them, and the steps ur_robot_driver's
``robot_state_helper`` takes to bring the robot into a requested mode (its ``set_mode`` action).

The numbering is ur_dashboard_msgs' (RobotMode, SafetyMode). The simulated controller knows the modes a measurement
cell meets: powered off, idle (powered, brakes held), running; the safety modes normal and protective stop. Changes are
immediate (a real controller takes seconds from power-on to idle).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

__all__ = [
    "HIGHER_MODE_MESSAGE",
    "MAX_SET_MODE_STEPS",
    "ModeStep",
    "RobotMode",
    "SafetyMode",
    "UrModes",
    "set_mode_step",
]


class RobotMode(IntEnum):
    NO_CONTROLLER = -1
    DISCONNECTED = 0
    CONFIRM_SAFETY = 1
    BOOTING = 2
    POWER_OFF = 3
    POWER_ON = 4
    IDLE = 5
    BACKDRIVE = 6
    RUNNING = 7
    UPDATING_FIRMWARE = 8


class SafetyMode(IntEnum):
    NORMAL = 1
    REDUCED = 2
    PROTECTIVE_STOP = 3
    RECOVERY = 4
    SAFEGUARD_STOP = 5
    SYSTEM_EMERGENCY_STOP = 6
    ROBOT_EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9
    VALIDATE_JOINT_ID = 10
    UNDEFINED_SAFETY_MODE = 11
    AUTOMATIC_MODE_SAFEGUARD_STOP = 12
    SYSTEM_THREE_POSITION_ENABLING_STOP = 13


#: the modes a set_mode goal may ask for
SELECTABLE = (RobotMode.POWER_OFF, RobotMode.IDLE, RobotMode.RUNNING)
HIGHER_MODE_MESSAGE = (
    "Robot reached higher mode than requested during recovery. This either means that something went wrong or that "
    "a higher mode was requested from somewhere else (e.g. the teach pendant.)"
)
#: a set_mode goal gives up after this many dashboard commands (a mode that does not follow its command)
MAX_SET_MODE_STEPS = 8


@dataclass
class UrModes:
    """The simulated controller's robot mode and the dashboard commands on it: each returns (success, the dashboard
    server's answer). The safety mode and whether the program runs live in the joint trajectory controller."""

    robot: RobotMode = RobotMode.RUNNING

    def power_on(self) -> tuple[bool, str]:
        if self.robot == RobotMode.POWER_OFF:
            self.robot = RobotMode.IDLE
        return True, "Powering on"

    def power_off(self) -> tuple[bool, str]:
        self.robot = RobotMode.POWER_OFF
        return True, "Powering off"

    def brake_release(self) -> tuple[bool, str]:
        if self.robot == RobotMode.IDLE:
            self.robot = RobotMode.RUNNING
        return True, "Brake releasing"

    @property
    def can_play(self) -> bool:
        """A program starts only on a running robot (powered, brakes released)."""
        return self.robot == RobotMode.RUNNING


@dataclass(frozen=True)
class ModeStep:
    """What the state helper does next: ``command`` a dashboard command to send ('power_off', 'power_on',
    'brake_release', 'unlock_protective_stop', 'restart_safety'), or ``done`` with ``success`` and ``message`` (the
    action's result), or neither: wait for the robot (a mode only the teach pendant or time changes)."""

    command: str = ""
    done: bool = False
    success: bool = False
    message: str = ""


def set_mode_step(target: int, robot: int, safety: int, first: bool = True) -> ModeStep:
    """The next step towards robot mode ``target`` from ``robot`` / ``safety`` (ur_dashboard_msgs numbers), as
    robot_state_helper v2.4.1 decides it: illegal and non-selectable targets abort; a lower target powers off; a
    protective stop is unlocked, a violation or fault restarts the safety system; then power on and brake release
    until the target is reached. ``first``: the goal has just arrived (later, a robot above the target aborts)."""
    try:
        wanted = RobotMode(target)
    except ValueError:
        return ModeStep(done=True, message="Requested illegal mode.")
    if wanted not in SELECTABLE:
        return ModeStep(done=True, message=f"Requested target mode {wanted.name} which cannot be explicitly selected.")
    if robot < wanted or safety > SafetyMode.REDUCED:
        return ModeStep(command=_transition(wanted, robot, safety))
    if robot == wanted:
        return ModeStep(done=True, success=True, message="Reached target robot mode.")
    if first:
        return ModeStep(command="power_off")
    return ModeStep(done=True, message=HIGHER_MODE_MESSAGE)


def _transition(target: RobotMode, robot: int, safety: int) -> str:
    if target < robot:
        return "power_off"
    if safety == SafetyMode.PROTECTIVE_STOP:
        return "unlock_protective_stop"
    if safety in (SafetyMode.VIOLATION, SafetyMode.FAULT):
        return "restart_safety"
    if safety in (SafetyMode.SYSTEM_EMERGENCY_STOP, SafetyMode.ROBOT_EMERGENCY_STOP):
        return ""  # the emergency stop is released by hand
    return {RobotMode.POWER_OFF: "power_on", RobotMode.IDLE: "brake_release"}.get(RobotMode(robot), "")
