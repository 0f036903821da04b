"""The trajectory_manager's work without ROS: plan from a request, store and load plans, adapt a plan's start
to the robot's state, the execution loop (success, cancel, a failing segment) and measured coverage, against
simulated executor doubles."""

import numpy as np
import pytest
import yaml

from agiprobot_measurement.common.files import PathPolicyError
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.plan.execution import (
    ExecutionCancelled,
    ExecutionError,
    PlanRejected,
    SimulatedExecutor,
    execute_segments,
    load_plan,
)
from agiprobot_measurement.planning.plan.plan_io import load_execution_plan
from agiprobot_measurement.planning.plan.session import GoalError, MeasurementSession
from agiprobot_measurement.planning.request import load_planning_defaults
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.station import Station

QUICK = {"sampling_density": 0.005, "orientations_around_boresight": 4, "solver_type": "greedy"}


class FailingExecutor(SimulatedExecutor):
    """Fails (or is cancelled) when it reaches segment ``at`` (1-based)."""

    def __init__(self, start_state, limits, at: int, error: type[Exception]):
        super().__init__(start_state, limits)
        self.at, self.error, self.count = at, error, 0

    def execute_segment(self, trajectory, kind, viewpoint=None):
        self.count += 1
        if self.count == self.at:
            raise self.error(f"simulated {self.error.__name__} in a {kind} segment")
        super().execute_segment(trajectory, kind, viewpoint)


@pytest.fixture(scope="module")
def station():
    return Station.load()


@pytest.fixture(scope="module")
def planned(station, tmp_path_factory):
    """A session that planned the cube quickly and stored the plan."""
    directory = tmp_path_factory.mktemp("plans")
    session = MeasurementSession(station, load_planning_defaults(), plan_directory=directory)
    request = session.request(plan_file="cube", **QUICK)
    outcome = session.plan_measurement(request, station.named_states["home"])
    return session, outcome, directory


def test_planning_from_a_request(planned):
    session, outcome, directory = planned
    assert outcome.plan_file == str(directory / "cube.yaml")
    assert outcome.report.n_views == len(session.views) > 0
    assert len(session.plan.segments) == 2 * len(session.views)
    assert outcome.report.coverage_of_coverable >= 0.99
    assert session.part is not None and session.part.mesh_file.endswith("objectA_wuerfel.stl")
    assert session.coverable_mask.sum() == outcome.report.n_coverable
    assert session.predicted_mask.sum() == outcome.report.n_covered
    stored = load_execution_plan(outcome.plan_file)
    assert stored.metadata["parameters"]["sampling_density"] == QUICK["sampling_density"]


def test_bad_request_fields_are_input_errors(planned):
    session = planned[0]
    with pytest.raises(InputError, match="sampling_density"):
        session.request(sampling_density=-1.0)
    with pytest.raises(PathPolicyError, match="outside the allowed folder"):
        session.plan_path("/nonexistent_dir/plan.yaml")
    with pytest.raises(GoalError, match="plan directory does not exist"):
        session.plan_path("nonexistent_dir/plan.yaml")


def test_execution_of_the_planned_views(planned, station):
    session = planned[0]
    state = station.named_states["home"]
    plan = session.prepared_plan(state)
    assert plan is session.plan  # it starts where the robot is: nothing to adapt
    measured = []
    executor = SimulatedExecutor(state, station.limits, on_measure=measured.append)
    feedback = []
    outcome = session.execute(plan, executor, feedback.append)
    assert outcome.ok and outcome.segments_executed == len(plan.segments) and outcome.describe() == ""
    assert measured == session.views  # each measurement names its view
    assert [f.number for f in feedback] == list(range(1, len(plan.segments) + 1))
    assert [f.kind for f in feedback[:2]] == ["connect", "measure"]
    assert feedback[0].done_fraction == 0.0 and all(0 <= f.done_fraction < 1 for f in feedback)
    np.testing.assert_allclose(executor.current_state(), plan.segments[-1].trajectory.end)
    # what the scanner measured: every sample the plan covers -> measured coverage as predicted
    coverage = session.measured(session.samples_mm[session.predicted_mask])
    assert coverage.measured_coverage == pytest.approx(coverage.predicted_coverage)
    assert session.last_measured_coverage == coverage.measured_coverage
    assert session.measured(np.zeros((0, 3))).measured_coverage == 0.0


@pytest.mark.parametrize(("error", "status"), [(ExecutionCancelled, "cancelled"), (ExecutionError, "failed")])
def test_cancel_and_a_failing_segment_stop_the_loop(planned, station, error, status):
    session = planned[0]
    state = station.named_states["home"]
    executor = FailingExecutor(state, station.limits, at=3, error=error)
    outcome = session.execute(session.plan, executor)
    assert outcome.status == status and not outcome.ok
    assert outcome.segments_executed == 2 and executor.count == 3
    total = len(session.plan.segments)
    if status == "cancelled":
        assert outcome.describe() == f"cancelled during segment 3 of {total}; robot stopped"
    else:
        assert outcome.describe().startswith(f"segment 3 of {total} failed: simulated ExecutionError")
    # the robot stayed where the last executed segment ended
    np.testing.assert_allclose(executor.current_state(), session.plan.segments[1].trajectory.end)


def test_the_api_raises_what_the_loop_returns(planned, station):
    session = planned[0]
    manager = session.manager
    home = station.named_states["home"]
    with pytest.raises(ExecutionCancelled, match="cancelled during segment 2"):
        manager.execute(session.plan.segments, executor=FailingExecutor(home, station.limits, 2, ExecutionCancelled))
    with pytest.raises(ExecutionError, match="simulated ExecutionError"):
        manager.execute(session.plan.segments, executor=FailingExecutor(home, station.limits, 1, ExecutionError))
    outcome = manager.execute_with_outcome(session.plan.segments, SimulatedExecutor(home, station.limits))
    assert outcome.ok


def test_a_missing_trajectory_fails_its_segment(planned, station):
    session = planned[0]
    segments = [(s.kind, s.trajectory, None) for s in session.plan.segments[:2]] + [("connect", None, None)]
    outcome = execute_segments(segments, SimulatedExecutor(station.named_states["home"], station.limits))
    assert outcome.status == "failed" and outcome.segments_executed == 2 and "has no trajectory" in outcome.error


def test_loading_a_stored_plan_and_adapting_its_start(planned, station):
    stored = planned[1].plan_file
    session = MeasurementSession(station, load_planning_defaults(), plan_directory=planned[2])
    with pytest.raises(GoalError, match="no plan"):
        session.prepared_plan(station.named_states["home"])
    loaded = session.load("cube.yaml")  # relative names: the plan directory
    assert str(loaded.path) == stored and session.manager is None and session.samples_mm is None
    assert loaded.part is not None and loaded.part.mesh_file.endswith("objectA_wuerfel.stl")
    assert loaded.part.scale_to_mm == pytest.approx(1.0)
    up = station.named_states["up"]
    adapted = session.prepared_plan(up)
    assert adapted is not session.plan and len(adapted.segments) == len(session.plan.segments)
    np.testing.assert_allclose(adapted.segments[0].trajectory.start, up, atol=1e-9)
    np.testing.assert_allclose(adapted.segments[1].trajectory.start, session.plan.segments[1].trajectory.start)
    outcome = session.execute(adapted, SimulatedExecutor(up, station.limits))
    assert outcome.ok and outcome.segments_executed == len(adapted.segments)
    assert session.measured(np.zeros((0, 3))) is None  # a loaded plan has no samples to compare
    # and the API's loading does the same
    manager = TrajectoryManager(station, start_state="up")
    segments = manager.load_execution_plan(stored, adapt_to_current_start_pose=True)
    np.testing.assert_allclose(segments[0].trajectory.start, up, atol=1e-9)


def test_a_plan_for_another_robot_is_rejected(planned, station, tmp_path):
    data = yaml.safe_load(open(planned[1].plan_file).read())
    for segment in data[1:]:
        segment["joint_trajectory"]["joint_names"] = [f"arm_joint_{i}" for i in range(6)]
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump(data))
    with pytest.raises(PlanRejected, match="not a plan for this robot"):
        load_plan(other, station.limits, station.limits.names)
    session = MeasurementSession(station, load_planning_defaults(), plan_directory=tmp_path)
    with pytest.raises(InputError):
        session.load(str(other))
    with pytest.raises(GoalError, match="no plan to store"):
        session.store("x.yaml")
