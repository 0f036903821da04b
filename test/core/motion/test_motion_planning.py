"""Joint-space planning with OMPL and the FCL checker: valid paths, fast failures with reasons, bad input."""

import math
import time

import numpy as np
import pytest

from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.motion_planning import (
    MotionPlanner,
    PlanningResult,
    available_planners,
    collision_free_trajectory,
    interpolate_path,
)

THROUGH_TABLE = np.array([0.0, 0.5, 0.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def checker(station, kinematic_model):
    return CollisionChecker.from_station(station, model=kinematic_model)


@pytest.fixture(scope="module")
def planner(checker):
    # no straight-line shortcut: the tests must exercise OMPL
    return MotionPlanner(checker, try_direct=False, time_budget_s=5.0, seed=11)


@pytest.fixture(scope="module")
def hard_pairs(checker, kinematic_model):
    """Seeded pairs of valid states whose straight line collides (so a planner is needed)."""
    rng = np.random.default_rng(5)
    probe = MotionPlanner(checker)
    pairs = []
    while len(pairs) < 6:
        q = rng.uniform(kinematic_model.lower, kinematic_model.upper, size=(2, kinematic_model.dof))
        if checker.check_states(q).all() and probe.check_path(q) >= 0:
            pairs.append(q)
    return pairs


def _assert_valid_path(result: PlanningResult, start, goal, checker, resolution):
    assert result.success, result.reason
    assert result.reason == ""
    assert result.path.ndim == 2 and result.path.shape[1] == 6 and len(result.path) >= 2
    np.testing.assert_array_equal(result.path[0], start)
    np.testing.assert_array_equal(result.path[-1], goal)
    dense = interpolate_path(result.path, resolution)
    assert np.all(np.abs(np.diff(dense, axis=0)) <= resolution + 1e-12)
    valid = checker.check_states(dense)
    assert valid.all(), f"state {np.argmin(valid)} of the interpolated path is invalid"
    # one by one too: the batch path of the checker must not be the only judge
    assert all(checker.is_state_valid(q) for q in dense[:: max(1, len(dense) // 40)])


def test_plans_are_collision_free_when_densely_interpolated(planner, checker, hard_pairs):
    for start, goal in hard_pairs:
        result = planner.plan(start, goal)
        _assert_valid_path(result, start, goal, checker, planner.resolution_rad)
        assert result.planner == "RRTConnect"
        assert result.planning_time > 0.0


def test_straight_line_is_taken_when_free(checker, station):
    planner = MotionPlanner(checker)
    start = station.named_states["home"]
    goal = start + np.array([0.2, -0.2, 0.1, 0.1, 0.1, 0.1])
    result = planner.plan(start, goal)
    _assert_valid_path(result, start, goal, checker, planner.resolution_rad)
    assert result.planner == "direct" and len(result.path) == 2


def test_start_equals_goal_is_trivial(planner, station):
    home = station.named_states["home"]
    result = planner.plan(home, home.copy())
    assert result.success and result.planner == "trivial"
    np.testing.assert_array_equal(result.path, [home, home])


def test_goal_in_collision_fails_fast_with_reason(planner, station):
    started = time.perf_counter()
    result = planner.plan(station.named_states["home"], THROUGH_TABLE)
    assert time.perf_counter() - started < 0.5
    assert not result.success and not result
    assert result.reason.startswith("goal state in collision:")
    assert "- table" in result.reason
    assert result.path.shape == (0, 6)


def test_start_outside_joint_limits_fails_with_reason(planner, station):
    start = station.named_states["up"].copy()
    start[2] = 1.0
    result = planner.plan(start, station.named_states["home"])
    assert not result.success
    assert "start state outside joint limits" in result.reason and "elbow_joint" in result.reason


def test_unknown_planner_lists_valid_names(planner, checker, station):
    home, up = station.named_states["home"], station.named_states["up"]
    with pytest.raises(ValueError, match="RRTConnect") as info:
        planner.plan(home, up, planner="RRTNope")
    assert "PRM" in str(info.value) and "KPIECE1" in str(info.value)
    with pytest.raises(ValueError, match="unknown planner"):
        MotionPlanner(checker, planner="nonsense")


@pytest.mark.parametrize(
    "start, goal",
    [
        (np.full(6, np.nan), np.zeros(6)),
        (np.zeros(6), np.array([0.0, 0.0, np.inf, 0.0, 0.0, 0.0])),
        (np.zeros(5), np.zeros(6)),
        (np.zeros(6), np.zeros((2, 6))),
    ],
)
def test_bad_input_raises(planner, start, goal):
    with pytest.raises(ValueError):
        planner.plan(start, goal)


def test_time_budget_bounds_the_call(checker, hard_pairs):
    planner = MotionPlanner(checker, try_direct=False, time_budget_s=0.02, max_attempts=2)
    start, goal = hard_pairs[0]
    started = time.perf_counter()
    result = planner.plan(start, goal)
    assert time.perf_counter() - started < 0.5
    assert result.attempts <= 2
    if not result.success:
        assert result.reason.startswith("no path found by RRTConnect")


@pytest.mark.parametrize("name", ["RRT", "PRM", "KPIECE1", "BKPIECE1"])
def test_other_planners(checker, hard_pairs, name):
    planner = MotionPlanner(checker, planner=name, try_direct=False, time_budget_s=10.0)
    start, goal = hard_pairs[1]
    result = planner.plan(start, goal)
    _assert_valid_path(result, start, goal, checker, planner.resolution_rad)
    assert result.planner == name


def test_planner_sees_obstacles_added_later(station, kinematic_model):
    checker = CollisionChecker.from_station(station, model=kinematic_model)
    planner = MotionPlanner(checker)
    start = np.array([0.0, -0.5, 0.0, 0.0, 0.0, 0.0])  # arm raised above the table, stretched out
    goal = start + np.array([-1.2, 0.0, 0.0, 0.0, 0.0, 0.0])  # a pan over the table
    assert planner.plan(start, goal).planner == "direct"
    # a wall across the sweep of the straight-line motion
    halfway = kinematic_model.link_poses_batch(((start + goal) / 2)[None], ["wrist_2_link"])["wrist_2_link"][0]
    wall = np.eye(4)
    wall[:3, 3] = halfway[:3, 3]
    checker.add_box("wall", [0.25, 0.25, 0.25], wall)
    assert checker.check_states(np.array([start, goal])).all()
    assert planner.check_path(np.array([start, goal])) >= 0
    result = planner.plan(start, goal)
    _assert_valid_path(result, start, goal, checker, planner.resolution_rad)
    assert result.planner == "RRTConnect"


def test_check_path_finds_the_collision(planner, station):
    path = np.array([station.named_states["home"], THROUGH_TABLE])
    index = planner.check_path(path)
    assert index > 0
    assert planner.check_path(np.array([station.named_states["home"], station.named_states["home"]])) == -1


def test_interpolate_path_keeps_waypoints_and_step():
    path = np.array([[0.0] * 6, [0.1, 0, 0, 0, 0, 0.05], [0.1, 0.3, 0, 0, 0, 0]])
    dense = interpolate_path(path, math.radians(1.0))
    for waypoint in path:
        assert np.any(np.all(dense == waypoint, axis=1))
    assert np.abs(np.diff(dense, axis=0)).max() <= math.radians(1.0) + 1e-12
    with pytest.raises(ValueError):
        interpolate_path(path, 0.0)


def test_available_planners_include_the_usual_ones():
    names = available_planners()
    for name in ("RRTConnect", "RRT", "RRTstar", "PRM", "KPIECE1", "BITstar"):
        assert name in names


def test_collision_free_trajectory_goes_straight_when_free_and_around_when_blocked(station, kinematic_model):
    checker = CollisionChecker.from_station(station, model=kinematic_model)
    limits = station.limits
    start = np.array([0.0, -0.5, 0.0, 0.0, 0.0, 0.0])
    goal = start + np.array([-1.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    straight = collision_free_trajectory(start, goal, limits, checker, velocity_scaling=0.5)
    # the synchronised straight joint move: every sample on the line from start to goal
    along = (straight.positions - start) @ (goal - start) / np.dot(goal - start, goal - start)
    np.testing.assert_allclose(straight.positions, start + along[:, None] * (goal - start), atol=1e-9)
    assert np.abs(straight.velocities).max(axis=0)[0] <= 0.5 * limits.max_velocity[0] + 1e-9
    halfway = kinematic_model.link_poses_batch(((start + goal) / 2)[None], ["wrist_2_link"])["wrist_2_link"][0]
    wall = np.eye(4)
    wall[:3, 3] = halfway[:3, 3]
    checker.add_box("wall", [0.25, 0.25, 0.25], wall)
    assert collision_free_trajectory(start, goal, limits, checker) is None  # blocked, and no planner given
    created = []

    def make_planner():
        created.append(MotionPlanner(checker, seed=3))
        return created[-1]

    around = collision_free_trajectory(start, goal, limits, checker, make_planner, velocity_scaling=0.5)
    assert len(created) == 1 and around is not None
    np.testing.assert_allclose(around.positions[0], start, atol=1e-9)
    np.testing.assert_allclose(around.positions[-1], goal, atol=1e-9)
    samples, velocities, _ = around.sample(around.dense_times(step_s=0.005, per_segment=4))
    assert checker.check_states(samples).all()
    assert (np.abs(velocities) <= 0.5 * limits.max_velocity + 1e-6).all()
    # a free straight move never sets up the planner
    collision_free_trajectory(start, start + 0.05, limits, checker, make_planner)
    assert len(created) == 1


def test_best_of_returns_the_shortest_of_its_solutions(checker, hard_pairs, monkeypatch):
    planner = MotionPlanner(checker, try_direct=False, time_budget_s=10.0, max_attempts=6, best_of=4, seed=11)
    accepted = []
    check_path = MotionPlanner.check_path

    def recording(self, path, resolution_rad=None):
        first_invalid = check_path(self, path, resolution_rad)
        if first_invalid < 0 and len(path) > 2:  # a collision-free OMPL solution (not the straight line)
            accepted.append(float(np.abs(np.diff(path, axis=0)).sum()))
        return first_invalid

    monkeypatch.setattr(MotionPlanner, "check_path", recording)
    start, goal = hard_pairs[2]
    result = planner.plan(start, goal)
    _assert_valid_path(result, start, goal, checker, planner.resolution_rad)
    assert result.stats["solutions"] == 4 and len(accepted) == 4
    assert np.abs(np.diff(result.path, axis=0)).sum() == pytest.approx(min(accepted))


def test_best_of_must_be_positive(checker):
    with pytest.raises(ValueError, match="best_of"):
        MotionPlanner(checker, best_of=0)


def test_a_path_whose_spline_leaves_the_limits_is_timed_as_point_to_point_moves(station):
    """The elbow held at its upper limit between two corners: every spline through the path overshoots the limit
    (time_optimal_trajectory refuses it at any waypoint density); path_trajectory falls back to point-to-point moves
    along the polyline, within the limits."""
    from agiprobot_measurement.motion.motion_planning import path_trajectory
    from agiprobot_measurement.motion.time_parameterization import TimeParameterizationError, time_optimal_trajectory

    limits = station.limits
    upper = limits.upper[2]
    path = np.array([[0, -1.5, -0.5, 0, 0, 0], [0, -1.5, upper, 0, 0, 0], [0.3, -1.5, upper, 0, 0, 0],
                     [0.3, -1.5, -0.5, 0, 0, 0]], dtype=float)  # fmt: skip
    for step in (None, 0.01, 0.002):
        with pytest.raises(TimeParameterizationError):
            time_optimal_trajectory(path, limits, max_waypoint_step_rad=step)
    trajectory = path_trajectory(path, limits)
    positions, velocities, _ = trajectory.sample(trajectory.dense_times())
    assert np.all(positions <= limits.upper + 1e-9) and np.all(positions >= limits.lower - 1e-9)
    assert np.all(np.abs(velocities) <= limits.max_velocity + 1e-6)
    np.testing.assert_allclose(trajectory.start, path[0])
    np.testing.assert_allclose(trajectory.end, path[-1])
    # it passes every corner of the path
    for corner in path[1:-1]:
        assert np.min(np.abs(positions - corner).max(axis=1)) < 1e-6
