"""The original planner's objects: plan segments and view trajectories read as ``moveit_msgs/RobotTrajectory``,
``execute`` takes RobotTrajectory-shaped items, ``store_execution_plan`` writes the exact path, and the source's
``get/set_trajectory_to_viewpoint`` names exist. Without ROS: the executor is the instant simulated one."""

from types import SimpleNamespace

import numpy as np
import pytest

from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.plan import executors
from agiprobot_measurement.planning.plan.execution import (
    ExecutionError,
    SimulatedExecutor,
    segment_triples,
)
from agiprobot_measurement.planning.plan.plan_io import (
    MessageTime,
    PlanError,
    load_execution_plan,
    message_to_dict,
    segment_to_dict,
)
from agiprobot_measurement.planning.trajectory_manager import PlanningError, TrajectoryManager
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


@pytest.fixture(scope="module")
def planned():
    manager = TrajectoryManager()
    manager.load_target_mesh(str(CUBE))
    points, views = manager.generate_samples_and_viewpoints(0.005, 0.1, 4, "none")
    ordered = manager.connect_viewpoints(manager.solve_scp(views, "greedy"))
    assert ordered, "the cube must give at least one connected view"
    return manager, points, ordered, manager.convert_viewpointlist_to_execution_plan(ordered)


def test_segments_read_as_robot_trajectories(planned):
    _, _, _, segments = planned
    for segment in segments:
        trajectory = segment.trajectory
        shape = segment.joint_trajectory
        assert list(shape.joint_names) == trajectory.joint_names
        assert len(shape.points) == len(trajectory)
        last = shape.points[-1]
        assert isinstance(last.time_from_start, MessageTime)
        assert last.time_from_start.to_sec() == pytest.approx(trajectory.duration, abs=1e-9)
        np.testing.assert_allclose(np.array([p.positions for p in shape.points]), trajectory.positions)
        assert shape.header.frame_id == trajectory.frame_id
        assert list(segment.multi_dof_joint_trajectory.points) == []
        # the shape is the segment's stored mapping, attribute for attribute
        assert message_to_dict(shape) == segment_to_dict(segment)["joint_trajectory"]
    with pytest.raises(AttributeError, match="snapshot"):
        segments[0].joint_trajectory.joint_names = []


def test_view_trajectories_read_as_robot_trajectories_and_the_source_names_exist(planned):
    _, _, ordered, _ = planned
    view = ordered[0]
    connection = view.get_trajectory_to_view()
    # the original's own execute_views prints this before every move
    assert connection.joint_trajectory.points[-1].time_from_start.to_sec() == pytest.approx(connection.duration)
    assert view.get_trajectory_to_viewpoint() is connection
    replacement = view.get_trajectory_for_measurement()
    view.set_trajectory_to_viewpoint(replacement)
    try:
        assert view.get_trajectory_to_view() is replacement
    finally:
        view.set_trajectory_to_view(connection)
    assert ViewPoint.get_trajectory_to_viewpoint is ViewPoint.get_trajectory_to_view


def test_execute_takes_robot_trajectory_shaped_items(planned):
    manager, _, _, segments = planned
    assert not executors.registered(executors.STATION)  # the core alone registers no station executor
    # what code written for the original hands over: objects with joint_trajectory / multi_dof_joint_trajectory
    shaped = [
        SimpleNamespace(joint_trajectory=s.joint_trajectory, multi_dof_joint_trajectory=s.multi_dof_joint_trajectory)
        for s in segments
    ]
    triples = segment_triples(shaped)
    assert [kind for kind, _, _ in triples] == [s.kind for s in segments]
    for (_, trajectory, _), segment in zip(triples, segments, strict=True):
        np.testing.assert_allclose(trajectory.positions, segment.trajectory.positions)
    manager.current_state = segments[0].trajectory.start.copy()
    assert manager.execute(shaped) is True  # outside ROS: the instant simulated robot
    np.testing.assert_allclose(manager.current_state, segments[-1].trajectory.end)
    # expanded mappings (a plan file's entries) as well
    manager.current_state = segments[0].trajectory.start.copy()
    assert manager.execute([segment_to_dict(s) for s in segments], executor="simulated") is True
    np.testing.assert_allclose(manager.current_state, segments[-1].trajectory.end)


def test_execute_refuses_what_is_no_trajectory_before_moving(planned):
    manager, _, _, segments = planned
    manager.current_state = segments[0].trajectory.start.copy()
    with pytest.raises(PlanError, match="segment 1"):
        manager.execute([segments[0], 42])
    np.testing.assert_allclose(manager.current_state, segments[0].trajectory.start)
    with pytest.raises(PlanningError, match="executor must be one of"):
        manager.execute(segments, executor="moveit")
    with pytest.raises(ExecutionError, match="not a ROS process"):  # explicit, never a silent simulation
        manager.execute(segments, executor="station")


def test_execute_with_an_explicit_executor(planned):
    manager, _, ordered, _ = planned
    executor = SimulatedExecutor(ordered[0].get_trajectory_to_view().start, manager.limits)
    assert manager.execute(ordered, executor=executor) is True
    np.testing.assert_allclose(executor.current_state(), ordered[-1].get_trajectory_for_measurement().end)


def test_store_execution_plan_writes_exactly_the_given_path(planned, tmp_path):
    manager, _, _, segments = planned
    for name in ("plan_noext", "plan.yaml", "plan.yaml.yaml", "plan.txt"):
        target = tmp_path / name
        assert manager.store_execution_plan(str(target), segments) is True
        assert manager.last_plan_path == target and target.is_file()
        assert len(load_execution_plan(target).segments) == len(segments)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.txt", "plan.yaml", "plan.yaml.yaml", "plan_noext"]
