"""The simulated controller against a fake clock: accept/refuse rules, following, cancel, shutdown, placing."""

import numpy as np
import pytest

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.motion.controller_sim import (
    FEEDBACK_PERIOD_S,
    ExecutionStatus,
    PlacementRefused,
    SimulatedController,
    resolve_initial_state,
)
from agiprobot_measurement.motion.trajectory import CheckTolerances, JointTrajectory
from agiprobot_measurement.station import load_joint_limits, load_named_states

LIMITS = load_joint_limits()
NAMED = load_named_states()
JOINTS = list(LIMITS.names)
RATE_HZ = 100.0


class FakeClock:
    """Time advances only when the controller's rate sleeps; ``on_sleep`` sees each step."""

    def __init__(self, start_s=1000.0):
        self.t = start_s
        self.shutdown = False
        self.on_sleep = None
        self.rates = []

    def now_s(self):
        return self.t

    def is_shutdown(self):
        return self.shutdown

    def rate(self, rate_hz):
        self.rates.append(rate_hz)
        clock = self

        class _Rate:
            def sleep(self):
                clock.t += 1.0 / rate_hz
                if clock.on_sleep is not None:
                    clock.on_sleep(clock)

        return _Rate()


class RecordingPublisher:
    def __init__(self):
        self.messages = []

    def publish_joint_state(self, joint_names, positions_rad, velocities_rad_s):
        self.messages.append((list(joint_names), list(positions_rad), list(velocities_rad_s)))


class RecordingGoal:
    def __init__(self, cancel_at_s=None, clock=None):
        self.cancel_at_s, self.clock = cancel_at_s, clock
        self.feedback = []

    def is_cancel_requested(self):
        return self.cancel_at_s is not None and self.clock.now_s() >= self.cancel_at_s

    def publish_feedback(self, progress, time_from_start_s):
        self.feedback.append((progress, time_from_start_s))


def _controller(initial=None, tolerances=None):
    clock, publisher = FakeClock(), RecordingPublisher()
    start = NAMED["home"] if initial is None else np.asarray(initial, dtype=float)
    controller = SimulatedController(JOINTS, LIMITS, NAMED, start, clock, publisher, RATE_HZ, tolerances)
    return controller, clock, publisher


def _line(start, delta, duration_s, names=None):
    start = np.asarray(start, dtype=float)
    end = start + np.asarray(delta, dtype=float)
    return JointTrajectory(
        list(names or JOINTS), np.array([0.0, duration_s]), np.vstack([start, end]), np.zeros((2, len(start)))
    )


def test_resolve_initial_state():
    np.testing.assert_array_equal(resolve_initial_state("up", NAMED, 6), NAMED["up"])
    assert resolve_initial_state("up", NAMED, 6) is not NAMED["up"]
    np.testing.assert_array_equal(resolve_initial_state([0.1] * 6, NAMED, 6), [0.1] * 6)
    with pytest.raises(ConfigError, match="unknown named state 'nowhere'"):
        resolve_initial_state("nowhere", NAMED, 6)
    with pytest.raises(ConfigError, match="expected 6 finite joint values"):
        resolve_initial_state([0.0] * 5, NAMED, 6)
    with pytest.raises(ConfigError, match="expected 6 finite joint values"):
        resolve_initial_state([0.0] * 5 + [float("nan")], NAMED, 6)


def test_publish_state_sends_names_positions_velocities():
    controller, _, publisher = _controller(initial=[0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
    controller.publish_state()
    assert publisher.messages == [(JOINTS, [0.1, -0.2, 0.3, -0.4, 0.5, -0.6], [0.0] * 6)]


def test_place_named_and_positions():
    controller, _, _ = _controller()
    np.testing.assert_array_equal(controller.place("up"), NAMED["up"])
    np.testing.assert_array_equal(controller.state()[0], NAMED["up"])
    q = [0.2, -1.0, -0.5, -1.0, 0.3, 0.1]  # inside every joint's limits
    np.testing.assert_array_equal(controller.place("", q), q)
    positions, velocities = controller.state()
    np.testing.assert_array_equal(positions, q)
    np.testing.assert_array_equal(velocities, np.zeros(6))


@pytest.mark.parametrize(
    ("named", "positions", "reason"),
    [
        ("nowhere", None, "unknown named state 'nowhere'"),
        ("", [0.0] * 5, "expected 6 positions, got 5"),
        ("", None, "expected 6 positions, got 0"),
        ("", [0.0] * 5 + [float("inf")], "positions must be finite"),
        ("", [0.0, 1.5, 0.0, 0.0, 0.0, 0.0], "positions outside the joint limits"),
    ],
)
def test_place_refuses_bad_states(named, positions, reason):
    controller, _, _ = _controller()
    with pytest.raises(PlacementRefused, match=reason) as caught:
        controller.place(named, positions)
    assert isinstance(caught.value, InputError)
    np.testing.assert_array_equal(controller.state()[0], NAMED["home"])


def test_follows_a_trajectory_in_clock_time():
    controller, clock, publisher = _controller()
    trajectory = _line(NAMED["home"], [0.3, -0.2, 0.1, 0.0, 0.0, 0.0], 2.0)
    start_s = clock.t
    seen = []

    def step(c):
        assert controller.executing
        controller.publish_state()
        seen.append((c.t - start_s, controller.state()))

    clock.on_sleep = step
    goal = RecordingGoal()
    outcome = controller.execute(trajectory, goal)
    assert outcome.status is ExecutionStatus.SUCCEEDED and outcome.message == ""
    assert clock.rates == [RATE_HZ]
    assert not controller.executing
    assert len(seen) == pytest.approx(2.0 * RATE_HZ, abs=1)
    # after each sleep the state is the interpolation at the step's start
    for elapsed, (positions, velocities) in seen[:-1]:
        pos, vel, _ = trajectory.sample(np.array([elapsed - 1.0 / RATE_HZ]))
        np.testing.assert_allclose(positions, pos[0], atol=1e-12)
        np.testing.assert_allclose(velocities, vel[0], atol=1e-12)
    positions, velocities = controller.state()
    np.testing.assert_array_equal(positions, trajectory.end)
    np.testing.assert_array_equal(velocities, np.zeros(6))
    assert len(publisher.messages) == len(seen)
    # feedback: at once, then at most every FEEDBACK_PERIOD_S, finally complete
    assert goal.feedback[0] == (0.0, 0.0)
    assert goal.feedback[-1] == (1.0, 2.0)
    gaps = np.diff([t for _, t in goal.feedback[:-1]])
    assert np.all(gaps >= FEEDBACK_PERIOD_S - 1e-9) and np.all(gaps < FEEDBACK_PERIOD_S + 2.0 / RATE_HZ)
    progress = [p for p, _ in goal.feedback]
    assert progress == sorted(progress)
    for p, t in goal.feedback:
        assert p == pytest.approx(t / 2.0)


def test_reorders_a_trajectory_with_other_joint_order():
    controller, _, _ = _controller()
    order = [5, 4, 3, 2, 1, 0]
    delta = np.array([0.1, -0.1, 0.05, 0.0, 0.2, 0.0])
    trajectory = _line(NAMED["home"][order], delta[order], 1.0, names=[JOINTS[i] for i in order])
    assert controller.execute(trajectory, RecordingGoal()).status is ExecutionStatus.SUCCEEDED
    np.testing.assert_allclose(controller.state()[0], NAMED["home"] + delta)


def test_single_point_trajectory_succeeds_at_once():
    controller, clock, _ = _controller()
    start = NAMED["home"].reshape(1, -1)
    trajectory = JointTrajectory(JOINTS, np.array([0.0]), start.copy(), np.zeros((1, 6)))
    goal = RecordingGoal()
    assert controller.execute(trajectory, goal).status is ExecutionStatus.SUCCEEDED
    assert goal.feedback == [(1.0, 0.0)]
    assert clock.t == 1000.0


@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (lambda: _line(NAMED["home"] + 0.05, [0.1] + [0.0] * 5, 2.0), "does not start at the current state"),
        (lambda: _line(NAMED["home"], [0.1] + [0.0] * 5, 2.0, names=["a", *JOINTS[1:]]), "wrong joint names"),
        (lambda: _line(NAMED["home"], [1.5] + [0.0] * 5, 0.5), "limit violated"),
        (lambda: _line(NAMED["home"], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0], 20.0), "position limit violated"),
    ],
)
def test_rejects_without_moving(make, reason):
    controller, clock, publisher = _controller()
    goal = RecordingGoal()
    outcome = controller.execute(make(), goal)
    assert outcome.status is ExecutionStatus.REJECTED
    assert reason in outcome.message
    assert goal.feedback == [] and clock.rates == [] and publisher.messages == []
    np.testing.assert_array_equal(controller.state()[0], NAMED["home"])
    assert not controller.executing


def test_start_tolerance_is_the_controllers():
    trajectory = _line(NAMED["home"] + 0.02, [0.1] + [0.0] * 5, 2.0)
    strict, _, _ = _controller()
    assert strict.execute(trajectory, RecordingGoal()).status is ExecutionStatus.REJECTED
    loose, _, _ = _controller(tolerances=CheckTolerances(start_rad=0.05))
    assert loose.execute(trajectory, RecordingGoal()).status is ExecutionStatus.SUCCEEDED


def test_cancel_stops_where_the_robot_is():
    controller, clock, _ = _controller()
    trajectory = _line(NAMED["home"], [0.4] + [0.0] * 5, 4.0)
    goal = RecordingGoal(cancel_at_s=clock.t + 0.995, clock=clock)
    outcome = controller.execute(trajectory, goal)
    assert outcome.status is ExecutionStatus.CANCELLED
    positions, velocities = controller.state()
    np.testing.assert_array_equal(velocities, np.zeros(6))
    expected, _, _ = trajectory.sample(np.array([0.99]))  # the last step before the cancel
    np.testing.assert_allclose(positions, expected[0], atol=1e-6)
    assert 0.0 < positions[0] < 0.4
    assert outcome.message == (f"cancelled after 1.00 s of 4.00 s; stopped at {np.round(positions, 4).tolist()}")
    assert all(progress < 1.0 for progress, _ in goal.feedback)
    assert not controller.executing


def test_placing_is_refused_while_following():
    controller, clock, _ = _controller()
    refusals = []

    def try_place(_clock):
        with pytest.raises(PlacementRefused, match="refused: a trajectory is executing") as caught:
            controller.place("up")
        refusals.append(caught.value)

    clock.on_sleep = try_place
    outcome = controller.execute(_line(NAMED["home"], [0.1] + [0.0] * 5, 1.0), RecordingGoal())
    assert outcome.status is ExecutionStatus.SUCCEEDED
    assert refusals
    clock.on_sleep = None
    np.testing.assert_array_equal(controller.place("up"), NAMED["up"])


def test_shutdown_puts_the_robot_at_the_end_without_a_result():
    controller, clock, _ = _controller()
    trajectory = _line(NAMED["home"], [0.4] + [0.0] * 5, 4.0)

    def stop_later(c):
        if c.t - 1000.0 >= 0.5:
            c.shutdown = True

    clock.on_sleep = stop_later
    goal = RecordingGoal()
    outcome = controller.execute(trajectory, goal)
    assert outcome.status is ExecutionStatus.SHUTDOWN
    np.testing.assert_array_equal(controller.state()[0], trajectory.end)
    assert all(progress < 1.0 for progress, _ in goal.feedback)
    assert not controller.executing


def test_an_exception_of_the_clock_leaves_the_controller_idle():
    controller, clock, _ = _controller()

    def interrupted(_clock):
        raise KeyboardInterrupt

    clock.on_sleep = interrupted
    with pytest.raises(KeyboardInterrupt):
        controller.execute(_line(NAMED["home"], [0.1] + [0.0] * 5, 1.0), RecordingGoal())
    assert not controller.executing
