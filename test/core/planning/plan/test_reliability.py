"""Issue 13 regressions of the planning core: hostile plan files (alias bombs, bad part transforms), the work
budget of a planning request, the file policy of plan files and figures, a refused plan keeping the current one,
and a lost controller ending the execution loop with its segment."""

import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from agiprobot_measurement.common.files import PathPolicyError
from agiprobot_measurement.planning.plan.execution import (
    ControllerLost,
    SimulatedExecutor,
    execute_segments,
    plan_part,
    state_jump,
)
from agiprobot_measurement.planning.plan.plan_io import (
    ExecutionPlan,
    PlanError,
    dump_execution_plan,
    load_execution_plan,
    store_execution_plan,
)
from agiprobot_measurement.planning.plan.session import GoalError, MeasurementSession
from agiprobot_measurement.planning.request import (
    PlanRequest,
    PlanRequestError,
    WorkBudget,
    WorkTooLarge,
    estimate_work,
    load_planning_defaults,
    load_work_budget,
)
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.station import PACKAGE_ROOT, Station

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"
QUICK = {"sampling_density": 0.005, "orientations_around_boresight": 4, "solver_type": "greedy"}


def alias_bomb(levels: int, width: int) -> str:
    """YAML metadata whose anchors and aliases expand to ``width ** levels`` leaves."""
    lines = ["- Timestamp: now", "  bomb:", "    l0: &l0 [x]"]
    for level in range(1, levels + 1):
        lines.append(f"    l{level}: &l{level} [{', '.join([f'*l{level - 1}'] * width)}]")
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def station():
    return Station.load()


@pytest.fixture(scope="module")
def planned(station, tmp_path_factory):
    directory = tmp_path_factory.mktemp("plans")
    session = MeasurementSession(station, load_planning_defaults(), plan_directory=directory)
    session.plan_measurement(session.request(plan_file="cube", **QUICK), station.named_states["home"])
    return session, directory


# ------------------------------------------------------------------------------------ row 1: alias bombs
def test_an_alias_bomb_plan_is_refused_at_load(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(alias_bomb(levels=9, width=9))
    started = time.perf_counter()
    with pytest.raises(PlanError, match="aliases"):
        load_execution_plan(path)
    assert time.perf_counter() - started < 5.0


def test_shared_metadata_is_written_as_loaded_not_expanded(tmp_path):
    path = tmp_path / "shared.yaml"
    path.write_text(alias_bomb(levels=6, width=6))  # 46656 leaves expanded: within the loader's bound
    plan = load_execution_plan(path)
    text = dump_execution_plan(plan)
    assert len(text) < 2000 and "&" in text and "*" in text  # anchors and aliases again
    out = store_execution_plan(tmp_path / "copy", plan)
    assert load_execution_plan(out).metadata["bomb"]["l6"][0][0][0][0][0][0][0] == "x"


# ------------------------------------------------------------------------------------ row 10: bad transform
@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ([1.0, 2.0, 3.0], "shape"),
        ([[1.0, "a"]] * 8, "16 numbers"),
        ([float("nan")] * 16, "NaN"),
        # finite but absurd: executed "successfully" 1e300 mm away with nothing measured
        ([[1.0, 0.0, 0.0, 1e300], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], "1e\\+300 mm"),
        ([[1e9, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], "unit scale"),
        ([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 5.0, 1.0]], "0 0 0 1"),
    ],
)
def test_a_bad_part_transform_names_file_and_key(value, expected):
    plan = ExecutionPlan(
        {"parameters": {"part_file": str(CUBE), "part_transform_mm": value}}, [], Path("/plans/bad.yaml")
    )
    with pytest.raises(PlanError, match=expected) as info:
        plan_part(plan)
    assert "/plans/bad.yaml" in str(info.value) and "parameters.part_transform_mm" in str(info.value)


def test_a_part_in_metres_near_the_robot_is_accepted():
    placement = np.diag([1000.0, 1000.0, 1000.0, 1.0])
    placement[:3, 3] = [800.0, -300.0, 50.0]
    plan = ExecutionPlan({"parameters": {"part_file": str(CUBE), "part_transform_mm": placement.tolist()}}, [])
    assert plan_part(plan).scale_to_mm == 1000.0


# ------------------------------------------------------------------------------------ row 11: directory part
def test_a_directory_as_part_file_says_so(tmp_path):
    with pytest.raises(PlanRequestError, match="is a directory") as info:
        PlanRequest.from_defaults(load_planning_defaults(), part_file=str(tmp_path)).validate()
    assert "not found" not in str(info.value)


# ------------------------------------------------------------------------------------ row 2: the budget
def test_the_estimate_states_samples_candidates_entries_and_memory():
    none = estimate_work(60000.0, 0.03, 12, "none")
    assert none.samples == pytest.approx(1800) and none.candidates == pytest.approx(1800 * 12)
    full = estimate_work(60000.0, 0.03, 12, "full")
    assert full.candidates == pytest.approx(9 * none.candidates) and full.memory_gb > none.memory_gb
    assert "1,800 samples" in none.describe() and "GB" in none.describe()
    huge = estimate_work(60000.0, 1e300, 2**31 - 1, "full")  # floats: no overflow, no allocation
    assert huge.samples > 1e300


def test_the_budget_refuses_with_estimate_and_budget():
    budget = WorkBudget(max_samples=1000, max_candidates=1e9, max_memory_gb=100)
    with pytest.raises(WorkTooLarge, match="max_samples = 1,000") as info:
        budget.check(estimate_work(60000.0, 0.03, 12, "none"))
    assert "1,800 samples" in str(info.value)
    with pytest.raises(WorkTooLarge, match="max_memory_gb"):
        WorkBudget(max_memory_gb=0.001).check(estimate_work(60000.0, 0.03, 12, "none"))
    assert budget.check(estimate_work(100.0, 0.03, 12, "none")).samples == pytest.approx(3)


def test_the_configured_budget_and_its_checks(tmp_path):
    budget = load_work_budget()
    assert budget.max_samples > 0 and budget.max_candidates > 0 and budget.max_memory_gb > 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("budget: {max_samples: -1}\n")
    with pytest.raises(Exception, match=r"budget\.max_samples"):
        load_work_budget(bad)
    with pytest.raises(Exception, match="unknown key"):
        WorkBudget.from_mapping({"max_rays": 1})


@pytest.mark.parametrize("density", [1000.0, 1e6])
def test_a_huge_density_on_the_cube_is_refused_in_well_under_a_second(station, density):
    manager = TrajectoryManager(station)
    manager.load_target_mesh(str(CUBE))
    started = time.perf_counter()
    with pytest.raises(WorkTooLarge, match="max_samples") as info:
        manager.generate_samples_and_viewpoints(density, 0.1, 12, "none")
    assert time.perf_counter() - started < 0.5
    assert "samples" in str(info.value) and manager.samples is None


# ------------------------------------------------------------------------------------ rows 3, 5, 6, 7, 13
def test_store_refuses_to_overwrite_unless_asked(planned):
    session = planned[0]
    first = session.store("kept")
    before = first.read_bytes()
    with pytest.raises(PathPolicyError, match="exists"):
        session.store("kept")
    with pytest.raises(PathPolicyError, match="exists"):
        session.store("kept.yaml")
    assert first.read_bytes() == before
    assert session.store("kept", overwrite=True) == first


@pytest.mark.parametrize("name", ["../victim/settings", "../../x", "~/x", "/etc/agiprobot_plan", "sub/../../x"])
def test_plan_names_cannot_escape_the_plan_directory(planned, name):
    session, directory = planned
    with pytest.raises(PathPolicyError) as info:
        session.store(name, overwrite=True)
    assert str(directory) in str(info.value)
    with pytest.raises(PathPolicyError):
        session.load(name)


def test_load_plan_cannot_probe_files_outside_its_root(planned):
    session = planned[0]
    plan = session.plan
    for name in ("../../../../etc/shadow", "/etc/passwd", "/etc/shadow"):
        with pytest.raises(PathPolicyError, match=r"outside the allowed folder|'\.\.' is not allowed"):
            session.load(name)
    assert session.plan is plan


@pytest.mark.parametrize("name", ["baseline", "baseline.yaml", "baseline.v2", "sub/baseline"])
def test_store_name_and_load_name_agree(planned, name):
    session, directory = planned
    (directory / "sub").mkdir(exist_ok=True)
    written = session.store(name, overwrite=True)
    assert written.is_relative_to(directory)
    assert session.load(name).path == written
    assert session.load(str(written)).path == written


def test_an_allowed_directory_takes_absolute_names(station, tmp_path):
    extra = tmp_path / "extra"
    extra.mkdir()
    session = MeasurementSession(
        station, load_planning_defaults(), plan_directory=tmp_path / "plans", allowed_directories=[extra]
    )
    assert session.plan_path(str(extra / "p")) == extra / "p.yaml"
    assert session.plan_path("p") == tmp_path / "plans" / "p.yaml"
    assert (tmp_path / "plans").is_dir()  # the plan directory is created on first use
    with pytest.raises(PathPolicyError, match="outside the allowed folder"):
        session.plan_path(str(tmp_path / "elsewhere.yaml"))


def test_a_planning_request_for_an_existing_plan_file_is_refused_before_planning(planned, station):
    session, directory = planned
    (directory / "taken.yaml").write_text("keep me")
    plan = session.plan
    started = time.perf_counter()
    with pytest.raises(PathPolicyError, match="exists"):
        session.plan_measurement(session.request(plan_file="taken", **QUICK), station.named_states["home"])
    assert time.perf_counter() - started < 1.0
    assert (directory / "taken.yaml").read_text() == "keep me" and session.plan is plan


def test_figures_stay_in_their_root_and_never_replace_a_file(station, tmp_path):
    directory = tmp_path  # a session of its own: the shared one may hold a loaded plan, which has no figure
    session = MeasurementSession(station, load_planning_defaults(), plan_directory=directory)
    session.plan_measurement(session.request(**QUICK), station.named_states["home"])
    for name in ("/etc/fig.png", "../fig.png", "~/fig.png"):
        with pytest.raises(PathPolicyError):
            session.write_figure(name)
    assert not Path("/etc/fig.png").exists()
    first = session.write_figure("coverage.png")
    second = session.write_figure("coverage.png")
    assert first == directory / "coverage.png" and second == directory / "coverage_2.png"
    assert session.write_figure("coverage.png", overwrite=True) == first
    with pytest.raises(GoalError, match=r"\.png"):
        session.write_figure("coverage.txt")


# ------------------------------------------------------------------------------------ row 4: refused plans
def test_a_refused_plan_file_keeps_the_current_plan(planned, tmp_path):
    session, directory = planned
    plan, source, views = session.plan, session.plan_source, list(session.views)
    data = yaml.safe_load((directory / "cube.yaml").read_text())
    for segment in data[1:]:
        segment["joint_trajectory"]["joint_names"] = [f"arm_joint_{i}" for i in range(6)]
    (directory / "other_robot.yaml").write_text(yaml.safe_dump(data))
    (directory / "bad_part.yaml").write_text(
        (directory / "cube.yaml").read_text().replace("part_transform_mm:", "part_transform_mm: [1, 2, 3]\n  old:")
    )
    for name in ("other_robot", "bad_part", "missing", "../cube"):
        with pytest.raises(Exception):  # noqa: B017 (each is an InputError of its own kind)
            session.load(name)
        assert session.plan is plan and session.plan_source == source and session.views == views
    # reading a candidate does not adopt it; adopting does
    candidate = session.read("cube")
    assert session.plan is plan
    prepared = session.prepared_plan(candidate.plan.segments[0].trajectory.start, candidate)
    assert prepared is candidate.plan
    session.adopt(candidate)
    assert session.plan is candidate.plan and session.views == []


# ------------------------------------------------------------------------------------ row 8: lost controller
class LosingExecutor(SimulatedExecutor):
    def __init__(self, start_state, limits, at):
        super().__init__(start_state, limits)
        self.at, self.count = at, 0

    def execute_segment(self, trajectory, kind, viewpoint=None):
        self.count += 1
        if self.count == self.at:
            raise ControllerLost("no /joint_states for 1.2 s")
        super().execute_segment(trajectory, kind, viewpoint)


class RestartedExecutor(SimulatedExecutor):
    """A controller killed and respawned after segment ``at`` - 1: it starts at all-zero joints and refuses the
    next segment as not starting at its state."""

    def __init__(self, start_state, limits, at):
        super().__init__(start_state, limits)
        self.at, self.count = at, 0

    def execute_segment(self, trajectory, kind, viewpoint=None):
        self.count += 1
        if self.count == self.at:
            self.state = np.zeros_like(self.state)
        super().execute_segment(trajectory, kind, viewpoint)


def test_a_controller_restarted_between_moves_is_reported_as_lost(planned, station):
    session = planned[0]
    home = station.named_states["home"]
    plan = session.prepared_plan(home)
    outcome = session.execute(plan, RestartedExecutor(home, station.limits, at=3))
    total = len(plan.segments)
    assert outcome.status == "controller_lost" and outcome.segments_executed == 2, outcome
    message = outcome.describe()
    assert message.startswith(f"controller lost during segment 3 of {total}: the robot's joint "), message
    assert "from where segment 2 ended without a command: the controller was restarted or lost" in message
    assert "the segment failed: measure segment rejected" in message or "connect segment rejected" in message
    # a segment that fails while the robot stays where it was is still a failure, not a lost controller
    bad = [(s.kind, s.trajectory, None) for s in plan.segments]
    bad[2] = (bad[2][0], bad[4][1], None)
    outcome = execute_segments(bad, SimulatedExecutor(home, station.limits))
    assert outcome.status == "failed" and outcome.segments_executed == 2


def test_a_state_jump_names_the_joint_and_ignores_what_it_cannot_compare():
    end = np.array([2.886, -1.0, 0.5])
    assert state_jump(np.zeros(3), end, "the last motion") == (
        "the robot's joint 1 is 2.886 rad from where the last motion ended without a command: the controller was "
        "restarted or lost between moves"
    )
    assert state_jump(end + 0.01, end, "segment 2") == ""  # tracking error
    assert state_jump(None, end, "x") == state_jump(np.zeros(3), None, "x") == state_jump(np.zeros(2), end, "x") == ""


def test_a_lost_controller_ends_the_loop_naming_its_segment(planned, station):
    session = planned[0]
    home = station.named_states["home"]
    plan = session.prepared_plan(home)
    outcome = session.execute(plan, LosingExecutor(home, station.limits, at=2))
    total = len(plan.segments)
    assert outcome.status == "controller_lost" and not outcome.ok and outcome.segments_executed == 1
    assert outcome.describe().startswith(f"controller lost during segment 2 of {total}: no /joint_states")
    outcome = execute_segments(
        [(s.kind, s.trajectory, None) for s in plan.segments], SimulatedExecutor(home, station.limits)
    )
    assert outcome.ok
    np.testing.assert_allclose(plan.segments[0].trajectory.start, home, atol=1e-3)


# ------------------------------------------------------------------------------------ the report names its plan
def test_the_report_counts_the_views_of_the_plan_it_names(station, tmp_path):
    """After another plan file was adopted, the report named that file with the planning run's view count."""
    session = MeasurementSession(station, load_planning_defaults(), plan_directory=tmp_path)
    session.plan_measurement(session.request(**QUICK), station.named_states["home"])
    planned = session.summary()
    assert planned.source == "(planned, not stored)" and planned.report is not None
    assert planned.number_of_views == planned.report.n_views >= 2
    assert planned.message == "plan: (planned, not stored)"
    fewer = ExecutionPlan(session.plan.metadata, session.plan.segments[:2])  # the first view only
    store_execution_plan(tmp_path / "one_view.yaml", fewer)
    session.load("one_view")
    summary = session.summary()
    assert summary.source == str(tmp_path / "one_view.yaml") and summary.report is None
    assert summary.number_of_views == 1 and summary.estimated_execution_time_s == pytest.approx(fewer.duration)
    assert summary.message.startswith(f"plan: {tmp_path / 'one_view.yaml'} (loaded: no coverage prediction")
    assert summary.as_dict()["number_of_views"] == 1 and summary.as_dict()["predicted_coverage"] is None
    with pytest.raises(GoalError, match="loaded from a file"):
        session.write_figure("coverage.png")
    assert not (tmp_path / "coverage.png").exists()


def test_the_report_needs_a_plan(station, tmp_path):
    session = MeasurementSession(station, load_planning_defaults(), plan_directory=tmp_path)
    with pytest.raises(GoalError, match="nothing planned or loaded yet"):
        session.summary()
