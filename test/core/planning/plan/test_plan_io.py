"""Execution plan files: loading the original's plan, exact round trips, validation, and adapting the start."""

import copy
import itertools
import os
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from agiprobot_measurement.common import files
from agiprobot_measurement.motion.time_parameterization import time_optimal_trajectory
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.plan import plan_io
from agiprobot_measurement.planning.plan.plan_io import (
    CONNECT,
    MEASURE,
    ExecutionPlan,
    PlanError,
    PlanFileNotFoundError,
    PlanSegment,
    adapt_to_current_start_pose,
    dump_execution_plan,
    load_execution_plan,
    message_to_dict,
    plan_path,
    segment_from_dict,
    segment_from_message,
    segment_to_dict,
    store_execution_plan,
    validate_execution_plan,
)
from agiprobot_measurement.station import load_joint_limits

PLAN_NAME = "zylinder_low_sampling.yaml"


@pytest.fixture(scope="module")
def limits():
    return load_joint_limits()


@pytest.fixture(scope="module")
def plan_file(shared_dir):
    path = shared_dir / "plans" / PLAN_NAME
    if not path.is_file():
        pytest.skip(f"{path} is not present")
    return path


@pytest.fixture(scope="module")
def loaded_plan(plan_file):
    return load_execution_plan(plan_file)


@pytest.fixture
def plan(loaded_plan):
    """A fresh copy per test: tests edit it."""
    return copy.deepcopy(loaded_plan)


# libyaml when present: the same safe constructors, several times faster on the 260 kB plan
LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def read_yaml(path):
    with open(path) as stream:
        return yaml.load(stream, Loader=LOADER)


@pytest.fixture(scope="module")
def plan_document(plan_file):
    return read_yaml(plan_file)


def write(tmp_path, text, name="plan.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def no_temp_files(directory) -> bool:
    return not [p for p in os.listdir(directory) if p.endswith(".tmp")]


# ---------------------------------------------------------------------------------------- shared plan
def test_shared_plan_loads(plan, limits):
    assert plan.metadata == {"Timestamp": "Fri May 21 16:20:29 2021"}
    assert len(plan) == 8
    assert [s.kind for s in plan.segments] == [CONNECT, MEASURE] * 4
    assert len(plan.measurements()) == 4 and len(plan.connections()) == 4
    assert plan.joint_names == list(limits.names)
    for segment in plan.segments:
        trajectory = segment.trajectory
        assert trajectory.frame_id == "world"
        assert trajectory.velocities is not None and trajectory.accelerations is not None
        assert trajectory.time_from_start[0] == 0.0
        assert segment.multi_dof["points"] == []
    assert plan.duration == pytest.approx(31.7138, abs=1e-3)
    assert len(plan.segments[1].trajectory) == 91


def test_shared_plan_validates(plan, limits):
    verdict = validate_execution_plan(plan, limits, list(limits.names))
    assert verdict, verdict.reason
    assert validate_execution_plan(plan, limits, start_state=plan.start)
    named = dict(zip(limits.names, plan.start, strict=True))
    assert validate_execution_plan(plan, limits, start_state=named)


def test_shared_plan_round_trips_exactly(plan_file, plan, tmp_path):
    written = store_execution_plan(tmp_path / "copy.yaml", plan)
    assert written == tmp_path / "copy.yaml"
    assert read_yaml(written) == read_yaml(plan_file)
    with open(written) as stream:  # the reference loader, as the original read it
        assert yaml.safe_load(stream) == read_yaml(plan_file)
    # the same style as the original (block style, sorted keys): even the text is identical
    assert written.read_text() == plan_file.read_text()
    again = load_execution_plan(written)
    for a, b in zip(again.segments, plan.segments, strict=True):
        np.testing.assert_array_equal(a.trajectory.positions, b.trajectory.positions)
        np.testing.assert_array_equal(a.trajectory.velocities, b.trajectory.velocities)
        np.testing.assert_array_equal(a.trajectory.accelerations, b.trajectory.accelerations)
        np.testing.assert_array_equal(a.trajectory.time_from_start, b.trajectory.time_from_start)
        assert a.header == b.header and a.multi_dof == b.multi_dof and a.kind == b.kind


def test_round_trip_through_trajectory_msgs(plan):
    pytest.importorskip("rospy")
    from agiprobot_measurement.ros.conversions import plan_from_joint_trajectory_msgs, plan_to_joint_trajectory_msgs

    messages = plan_to_joint_trajectory_msgs(plan)
    assert len(messages) == 8 and messages[1].joint_names == plan.joint_names
    again = plan_from_joint_trajectory_msgs(messages, plan.metadata)
    assert dump_execution_plan(again) == dump_execution_plan(plan)


def test_robot_trajectory_message_like_objects(plan):
    pytest.importorskip("rospy")
    from trajectory_msgs.msg import MultiDOFJointTrajectory

    from agiprobot_measurement.ros.conversions import joint_trajectory_to_msg

    message = SimpleNamespace(
        joint_trajectory=joint_trajectory_to_msg(plan.segments[1].trajectory),
        multi_dof_joint_trajectory=MultiDOFJointTrajectory(),
    )
    segment = segment_from_message(message, 1)
    assert segment.kind == MEASURE
    assert segment_to_dict(segment) == segment_to_dict(plan.segments[1])
    stamp = message_to_dict(message.joint_trajectory.points[1].time_from_start)
    assert set(stamp) == {"secs", "nsecs"}
    # a store accepts messages, mappings and trajectories as segments
    mixed = [segment_to_dict(plan.segments[0]), message]
    assert dump_execution_plan(mixed) == dump_execution_plan(ExecutionPlan({}, plan.segments[:2]))


def test_segment_dict_conversion(plan):
    data = segment_to_dict(plan.segments[3])
    assert set(data) == {"joint_trajectory", "multi_dof_joint_trajectory"}
    assert segment_to_dict(segment_from_dict(data, 3)) == data
    bare = segment_to_dict(plan.segments[3].trajectory)
    assert bare["joint_trajectory"]["header"]["frame_id"] == "world"
    assert bare["multi_dof_joint_trajectory"] == plan_io.empty_multi_dof()


# ------------------------------------------------------------------------------------------- storing
@pytest.mark.parametrize(
    ("given", "written"),
    [("plan", "plan.yaml"), ("plan.yaml", "plan.yaml"), ("plan.yml", "plan.yml"), ("plan.v2", "plan.v2.yaml")],
)
def test_suffix_is_never_doubled(plan, tmp_path, given, written):
    # plan_path is what the CLI and the node apply to a plan name; store_execution_plan writes exactly its path
    assert plan_path(tmp_path / given) == tmp_path / written
    assert store_execution_plan(plan_path(tmp_path / given), plan) == tmp_path / written
    assert sorted(os.listdir(tmp_path)) == [written]
    assert store_execution_plan(tmp_path / given, plan) == tmp_path / given


def test_store_replaces_atomically_and_leaves_no_temp_files(plan, tmp_path):
    target = store_execution_plan(tmp_path / "plan.yaml", plan)
    store_execution_plan(str(target), plan, {"note": "second"})
    assert os.listdir(tmp_path) == ["plan.yaml"]
    assert read_yaml(target)[0] == {"Timestamp": "Fri May 21 16:20:29 2021", "note": "second"}
    assert oct(target.stat().st_mode & 0o777) != oct(0o600)  # not mkstemp's private mode


def test_failed_write_keeps_the_old_file(plan, tmp_path, monkeypatch):
    target = store_execution_plan(tmp_path / "plan", plan)
    before = target.read_text()
    with pytest.raises(PlanError, match="cannot write a object"):
        store_execution_plan(target, plan, {"bad": object()})

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(files.os, "replace", failing_replace)
    with pytest.raises(PlanError, match="disk full"):
        store_execution_plan(target, plan, {"new": 1})
    assert target.read_text() == before
    assert no_temp_files(tmp_path)


def test_store_refuses_a_missing_directory(plan, tmp_path):
    with pytest.raises(PlanError, match="does not exist"):
        store_execution_plan(tmp_path / "nowhere" / "plan.yaml", plan)
    assert not (tmp_path / "nowhere").exists()
    (tmp_path / "dir.yaml").mkdir()
    with pytest.raises(PlanError, match="is a directory"):
        store_execution_plan(tmp_path / "dir.yaml", plan)


def test_store_trajectories_with_metadata(tmp_path, limits):
    start = np.array([0.5, -1.5, -1.5, -1.0, 1.5, 0.0])
    legs = [start, start + 0.2, start + 0.3, start + 0.1]
    trajectories = [time_optimal_trajectory([a, b], limits) for a, b in itertools.pairwise(legs)]
    metadata = {"sampling_density": np.float64(0.01), "views": np.int64(3), "pose": np.array([1.0, 2.0])}
    path = store_execution_plan(tmp_path / "generated", trajectories, metadata)
    loaded = load_execution_plan(path)
    assert loaded.metadata == {"sampling_density": 0.01, "views": 3, "pose": [1.0, 2.0]}
    assert [s.kind for s in loaded.segments] == [CONNECT, MEASURE, CONNECT]
    assert validate_execution_plan(loaded, limits)
    for a, b in zip(loaded.trajectories(), trajectories, strict=True):
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_allclose(a.time_from_start, b.time_from_start, atol=1e-9)


def test_store_rejects_non_plans(tmp_path):
    with pytest.raises(PlanError, match="expected an ExecutionPlan"):
        store_execution_plan(tmp_path / "p", {"joint_trajectory": {}})
    with pytest.raises(PlanError, match="segment 1"):
        store_execution_plan(tmp_path / "p", [PlanSegment(CONNECT, _tiny()), 42])
    assert os.listdir(tmp_path) == []


def _tiny():
    return JointTrajectory(list(load_joint_limits().names), [0.0], np.zeros((1, 6)))


# ------------------------------------------------------------------------------------------- loading
def test_missing_file(tmp_path):
    with pytest.raises(PlanFileNotFoundError, match="not found"):
        load_execution_plan(tmp_path / "absent.yaml")
    with pytest.raises(FileNotFoundError):
        load_execution_plan(tmp_path / "absent.yaml")


def test_malformed_yaml(tmp_path):
    path = write(tmp_path, "- Timestamp: x\n- joint_trajectory: {header: [\n")
    with pytest.raises(PlanError, match="malformed YAML") as info:
        load_execution_plan(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "must be a YAML list.*empty document"),
        ("Timestamp: x\n", "must be a YAML list"),
        ("[]\n", "empty list"),
        ("- 3\n", "first entry must be the metadata"),
        ("- joint_trajectory: {joint_names: [], points: []}\n", "first entry must be the metadata.*a segment"),
        ("- {}\n- 5\n", "segment 0: expected a RobotTrajectory mapping"),
        ("- {}\n- {multi_dof_joint_trajectory: {}}\n", "segment 0: missing 'joint_trajectory'"),
        ("- {}\n- joint_trajectory: [1]\n", "segment 0: 'joint_trajectory' must be a mapping"),
        ("- {}\n- joint_trajectory: {points: []}\n", "segment 0: joint_trajectory.joint_names must be a list"),
    ],
)
def test_wrong_structure(tmp_path, text, match):
    with pytest.raises(PlanError, match=match):
        load_execution_plan(write(tmp_path, text))


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda p: p.update(positions=[0.1, "x", 0, 0, 0, 0]), "segment 2: point 3: 'positions' must be a list"),
        (lambda p: p.update(positions=[0.1] * 5), "segment 2: point 3: 'positions' has 5 values for 6 joints"),
        (lambda p: p.pop("positions"), "segment 2: point 3: missing 'positions'"),
        (lambda p: p.pop("time_from_start"), "segment 2: point 3: missing 'time_from_start'"),
        (lambda p: p.update(time_from_start={"secs": 1.5}), "segment 2: point 3: time_from_start must have integer"),
        (lambda p: p.update(velocities=[0.0] * 7), "segment 2: point 3: 'velocities' has 7 values"),
    ],
)
def test_bad_point(plan_document, tmp_path, change, match):
    document = copy.deepcopy(plan_document)
    change(document[3]["joint_trajectory"]["points"][3])
    path = write(tmp_path, yaml.dump(document, Dumper=DUMPER))
    with pytest.raises(PlanError, match=match) as info:
        load_execution_plan(path)
    assert str(path) in str(info.value)


# ---------------------------------------------------------------------------------------- validation
def _with_trajectory(plan, index, trajectory):
    plan.segments[index] = PlanSegment(plan.segments[index].kind, trajectory)
    return plan


def test_validation_names_the_broken_segment(plan, limits):
    shifted = plan.segments[3].trajectory.copy()
    shifted.positions = shifted.positions + np.array([0, 0, 0.01, 0, 0, 0])
    verdict = validate_execution_plan(_with_trajectory(plan, 3, shifted), limits)
    assert not verdict and "between segment 2 and segment 3" in verdict.reason and "elbow_joint" in verdict.reason
    verdict = validate_execution_plan(plan, limits, continuity_tolerance_rad=0.05)
    assert verdict, verdict.reason


def test_validation_rejects_limit_violations(plan, limits):
    fast = plan.segments[5].trajectory.time_scaled(0.2)
    verdict = validate_execution_plan(_with_trajectory(plan, 5, fast), limits)
    assert not verdict and verdict.reason.startswith("segment 5 (measure):") and "limit violated" in verdict.reason


def test_validation_rejects_wrong_start(plan, limits):
    verdict = validate_execution_plan(plan, limits, start_state=plan.start + 0.1)
    assert not verdict and verdict.reason.startswith("segment 0 (connect):") and "current state" in verdict.reason
    verdict = validate_execution_plan(plan, limits, start_state=[0.0] * 5)
    assert not verdict and "start state" in verdict.reason


def test_validation_rejects_structure(plan, limits):
    assert "no segments" in validate_execution_plan(ExecutionPlan({}, []), limits).reason
    swapped = ExecutionPlan({}, [plan.segments[1], plan.segments[2]])
    verdict = validate_execution_plan(swapped, limits)
    assert not verdict and "segment 0 (measure): expected a connect segment" in verdict.reason
    renamed = plan.segments[4].trajectory.copy()
    renamed.joint_names[0] = "base_joint"
    verdict = validate_execution_plan(_with_trajectory(plan, 4, renamed), limits)
    assert not verdict and "segment 4" in verdict.reason and "base_joint" in verdict.reason
    assert not validate_execution_plan(plan, limits, joint_names=["a", "b"])


def test_validation_rejects_multi_dof_points_and_motion_at_the_ends(plan, limits):
    plan.segments[6].multi_dof["points"] = [{"transforms": []}]
    verdict = validate_execution_plan(plan, limits)
    assert not verdict and "segment 6" in verdict.reason and "multi-DOF" in verdict.reason
    plan.segments[6].multi_dof["points"] = []
    moving = plan.segments[7].trajectory.copy()
    moving.velocities[-1, 1] = 0.05
    verdict = validate_execution_plan(_with_trajectory(plan, 7, moving), limits)
    assert not verdict and "segment 7" in verdict.reason and "does not end at rest" in verdict.reason


def test_validation_rejects_bad_time(plan, limits):
    broken = plan.segments[2].trajectory.copy()
    broken.time_from_start[4] = broken.time_from_start[3]
    verdict = validate_execution_plan(_with_trajectory(plan, 2, broken), limits)
    assert not verdict and "segment 2" in verdict.reason and "strictly increasing" in verdict.reason


# ---------------------------------------------------------------------------------------- adaptation
class RecordingPlanner:
    def __init__(self, limits):
        self.limits = limits
        self.calls = []

    def __call__(self, start_q, goal_q):
        self.calls.append((start_q, goal_q))
        return time_optimal_trajectory(np.array([start_q, goal_q]), self.limits)


def test_adapt_prepends_a_motion(plan, limits):
    current = plan.start + np.array([0.3, -0.2, 0.1, 0.2, -0.1, 0.4])
    planner = RecordingPlanner(limits)
    adapted = adapt_to_current_start_pose(plan, current, planner)
    assert len(planner.calls) == 1
    np.testing.assert_allclose(planner.calls[0][0], current)
    np.testing.assert_allclose(planner.calls[0][1], plan.start)
    assert len(adapted) == len(plan)
    first = adapted.segments[0].trajectory
    np.testing.assert_allclose(first.start, current)
    np.testing.assert_allclose(first.end, plan.segments[0].trajectory.end)
    assert first.duration > plan.segments[0].trajectory.duration
    verdict = validate_execution_plan(adapted, limits, start_state=current)
    assert verdict, verdict.reason
    # the rest of the plan is untouched, and so is the original plan
    assert segment_to_dict(adapted.segments[5]) == segment_to_dict(plan.segments[5])
    assert not validate_execution_plan(plan, limits, start_state=current)


def test_adapt_replaces_the_first_connection(plan, limits):
    current = plan.start + 0.2
    planner = RecordingPlanner(limits)
    adapted = adapt_to_current_start_pose(plan, current, planner, mode="replace")
    np.testing.assert_allclose(planner.calls[0][1], plan.segments[0].trajectory.end)
    assert len(adapted) == len(plan)
    assert validate_execution_plan(adapted, limits, start_state=current)


def test_adapt_leaves_a_plan_that_starts_here(plan, limits):
    planner = RecordingPlanner(limits)
    adapted = adapt_to_current_start_pose(plan, plan.start + 1e-4, planner)
    assert planner.calls == []
    assert dump_execution_plan(adapted) == dump_execution_plan(plan)


def test_adapt_plan_starting_with_a_measurement(plan, limits):
    measuring = ExecutionPlan({}, [PlanSegment(MEASURE, plan.segments[1].trajectory)])
    current = measuring.start - 0.1
    adapted = adapt_to_current_start_pose(measuring, current, RecordingPlanner(limits))
    assert [s.kind for s in adapted.segments] == [CONNECT, MEASURE]
    assert validate_execution_plan(adapted, limits, start_state=current)


def test_adapt_rejects_a_bad_planner(plan, limits):
    def elsewhere(start_q, goal_q):
        return time_optimal_trajectory(np.array([start_q + 0.1, goal_q]), limits)

    with pytest.raises(PlanError, match="does not start where asked"):
        adapt_to_current_start_pose(plan, plan.start + 0.2, elsewhere)
    with pytest.raises(PlanError, match="must return a JointTrajectory"):
        adapt_to_current_start_pose(plan, plan.start + 0.2, lambda s, g: None)
    with pytest.raises(PlanError, match="6 joint values"):
        adapt_to_current_start_pose(plan, [0.0, 1.0], RecordingPlanner(limits))
    with pytest.raises(PlanError, match="mode"):
        adapt_to_current_start_pose(plan, plan.start, RecordingPlanner(limits), mode="insert")
