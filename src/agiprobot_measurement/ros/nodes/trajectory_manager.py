"""trajectory_manager node: plan, store, load and execute measurement trajectories in ROS.

The node maps messages to the core and back; the work is done by
:class:`~agiprobot_measurement.planning.plan.session.MeasurementSession` (planning, plan files, start adaptation,
execution loop, measured coverage) and :class:`~agiprobot_measurement.ros.executor.RosSegmentExecutor` (the robot
controller's action, the scanner's stitching, cancel).

Actions: ~plan_measurement (PlanMeasurement: feedback per stage, cancel at any stage), ~execute_plan
(ExecutePlan: segment by segment through the robot controller's action; the simulated scanner stitches during
measurement segments only). Services: ~load_plan, ~store_plan, ~get_coverage_report.
Topics: ~surface_points (sampled points coloured by predicted uncertainty: red = not measurable, green = low,
blue = high), ~viewpoints (scan lines), ~planned_path (the scanner's path), ~part (the part's mesh),
~measured_samples (after execution: green = measured, red = missed), /currently_measured_points (the points the
current measurement segment measures, during measurement segments only).
Parameters: ~planning/* (defaults of every goal field, config/trajectory_manager.yaml; also ~planning/workers: a
local Dask cluster of that many processes evaluates the candidates, ~planning/scheduler: the address of an
existing Dask cluster to use instead, ~planning/max_memory_gb: the evaluation's memory budget, 0 = from the
machine), ~budget/* (the most
work one planning run may cause: max_samples, max_candidates, max_memory_gb), ~plan_directory (the root of plan
files and figures), ~allowed_plan_dirs (where absolute plan and figure names may also point; default ROS_HOME and /tmp),
~controller_heartbeat_timeout_s (1.0: an execution aborts when /joint_states is older), ~measured_radius_mm, ~scene / ~scanner / ~robot_config / ~joint_limits / ~named_states (station files),
~executor (follow_joint_trajectory: control_msgs/FollowJointTrajectory, as a UR driver serves it; moveit: move_group's
moveit_msgs/ExecuteTrajectory), ~controller_action ("" = the executor's action:
/scaled_pos_joint_traj_controller/follow_joint_trajectory or /execute_trajectory), ~scanner_namespace (/laser_scanner). The sensor model's
parameters are put on the parameter server under ~sensor_model as the original did.

Files follow the package's one file policy (:class:`~agiprobot_measurement.common.files.FileRoot`): plan and
figure names resolve under ~plan_directory; absolute names only inside it or ~allowed_plan_dirs; ``..`` and ``~``
are refused; store_plan and PlanMeasurement replace an existing plan only with ``overwrite: true``, a figure
gets a new version name. A refused ExecutePlan keeps the node's current plan.
"""

from __future__ import annotations

import dataclasses
import os
import traceback
from pathlib import Path

import actionlib
import numpy as np
import rospy
import yaml
from sensor_msgs.msg import PointCloud, PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.common.config import number
from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.msg import (
    ExecutePlanAction,
    ExecutePlanFeedback,
    ExecutePlanResult,
    PlanMeasurementAction,
    PlanMeasurementFeedback,
    PlanMeasurementResult,
)
from agiprobot_measurement.planning.plan.session import GoalError, MeasurementSession
from agiprobot_measurement.planning.report.coverage import measured_colors, uncertainty_colors
from agiprobot_measurement.planning.report.progress import overall_progress
from agiprobot_measurement.planning.request import PlanRequest, PlanRequestError, WorkBudget
from agiprobot_measurement.planning.trajectory_manager import PlanningCancelled
from agiprobot_measurement.ros.conversions import pose_to_matrix, xyz_cloud, xyz_point_cloud
from agiprobot_measurement.ros.executor import ControllerWatch, RosSegmentExecutor
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.markers import part_markers, path_marker, scan_line_markers
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, file_param, read_params
from agiprobot_measurement.ros.robot_client import MotionSettings, make_motion_client, motion_parameters
from agiprobot_measurement.ros.scanner_client import ScannerClient
from agiprobot_measurement.srv import (
    GetCoverageReport,
    GetCoverageReportResponse,
    LoadPlan,
    LoadPlanResponse,
    StorePlan,
    StorePlanResponse,
)
from agiprobot_measurement.station import Station

__all__ = ["TrajectoryManagerNode", "coverage_summary", "main", "plan_request_from_goal", "yaml_plain"]

#: colours of the scan-line arrows, the planned path and the part


def part_transform_from_pose(pose) -> np.ndarray:
    """4x4 (translation mm) of a goal's part_pose (m): an all-zero pose is the identity, a zero quaternion with
    a position a pure translation. Raises PlanRequestError naming part_pose."""
    quaternion = [pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w]
    position = (pose.position.x, pose.position.y, pose.position.z)
    if np.linalg.norm(quaternion) < 1e-12 and not any(position):
        return np.eye(4)
    if np.linalg.norm(quaternion) < 1e-12:
        fixed = pose.__class__()
        fixed.position = pose.position
        fixed.orientation.w = 1.0
        pose = fixed
    try:
        transform = pose_to_matrix(pose)
    except ValueError as exc:
        raise PlanRequestError("part_pose", f"part_pose: {exc}") from exc
    transform[:3, 3] *= 1000.0
    return transform


def plan_request_from_goal(goal, session: MeasurementSession) -> PlanRequest:
    """The validated request of a PlanMeasurement goal (empty / zero fields take the configured defaults)."""
    return session.request(
        part_file=goal.part_file,
        units=goal.units,
        sampling_density=goal.sampling_density,
        orientations_around_boresight=goal.orientations_around_boresight,
        viewpoint_tilt_mode=goal.viewpoint_tilt_mode,
        solver_type=goal.solver_type,
        uncertainty_threshold_mm=goal.uncertainty_threshold_mm,
        plan_file=goal.plan_file,
        overwrite=goal.overwrite,
        part_transform_mm=part_transform_from_pose(goal.part_pose),
        time_limit_s=goal.time_limit_s,
        placement=goal.placement,
        tessellation_tolerance_mm=goal.tessellation_tolerance_mm,
    )


def yaml_plain(value):
    """``value`` with numpy scalars as Python numbers and tuples as lists (for yaml.safe_dump)."""
    if isinstance(value, dict):
        return {str(k): yaml_plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [yaml_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


#: the node's parameters (name, default, validator) besides the station files, read once at start
PARAMETERS = (
    Param("~allowed_plan_dirs", []),
    Param("~planning", {}),
    Param("~plan_directory", "plans"),
    Param("~measured_radius_mm", 1.0, number),
    Param("~budget", {}),
    Param("~scanner_namespace", "/laser_scanner"),
    *motion_parameters("~"),
    Param("~controller_heartbeat_timeout_s", 1.0, number),
)


class TrajectoryManagerNode:
    def __init__(self):
        settings = read_params(PARAMETERS)
        station = Station.load(
            robot=file_param("~robot_config"),
            joint_limits=file_param("~joint_limits"),
            named_states=file_param("~named_states"),
            scanner=file_param("~scanner"),
            scene=file_param("~scene"),
        )
        allowed = settings.allowed_plan_dirs or [os.environ.get("ROS_HOME") or "~/.ros", "/tmp"]
        if isinstance(allowed, str):
            allowed = allowed.split()
        self.session = MeasurementSession(
            station,
            dict(settings.planning),
            plan_directory=settings.plan_directory,
            measured_radius_mm=settings.measured_radius_mm,
            allowed_directories=[Path(d).expanduser() for d in allowed],
            work_budget=WorkBudget.from_mapping(settings.budget, "~budget"),
        )
        rospy.set_param("~sensor_model", dict(station.scanner.sensor_parameters))
        self.joint_states = JointStateCache(self.session.joint_names)

        latched = {"queue_size": 1, "latch": True}
        self.surface_pub = rospy.Publisher("~surface_points", PointCloud2, **latched)
        self.measured_pub = rospy.Publisher("~measured_samples", PointCloud2, **latched)
        self.viewpoint_pub = rospy.Publisher("~viewpoints", MarkerArray, **latched)
        self.path_pub = rospy.Publisher("~planned_path", Marker, **latched)
        self.part_pub = rospy.Publisher("~part", MarkerArray, **latched)
        # sensor_msgs/PointCloud, as the original published it: scripts and rviz configs for it subscribe so
        self.current_pub = rospy.Publisher("/currently_measured_points", PointCloud, **latched)
        self.scanner = ScannerClient(settings.scanner_namespace)
        self.robot = make_motion_client(
            MotionSettings(settings.executor, settings.controller_action), station.limits, self.joint_states.latest
        )
        self.controller = ControllerWatch(self.joint_states, self.robot, settings.controller_heartbeat_timeout_s)
        self.plan_server = actionlib.SimpleActionServer(
            "~plan_measurement", PlanMeasurementAction, execute_cb=self.on_plan, auto_start=False
        )
        self.execute_server = actionlib.SimpleActionServer(
            "~execute_plan", ExecutePlanAction, execute_cb=self.on_execute, auto_start=False
        )
        rospy.Service("~load_plan", LoadPlan, self.on_load_plan)
        rospy.Service("~store_plan", StorePlan, self.on_store_plan)
        rospy.Service("~get_coverage_report", GetCoverageReport, self.on_get_report)
        self.plan_server.start()
        self.execute_server.start()
        rospy.loginfo(
            "trajectory_manager: ready (plans go to %s; absolute names may also point into %s)",
            self.session.plan_directory,
            ", ".join(str(r) for r in self.session.plan_files.extra_roots) or "nothing else",
        )

    def _current_state(self, timeout_s: float = 3.0) -> np.ndarray:
        state = self.joint_states.wait(timeout_s)
        if state is None:
            raise GoalError("no /joint_states from the robot: is the station (robot_sim) running?")
        return state

    # ------------------------------------------------------------------------------------ planning
    def on_plan(self, goal):
        result = PlanMeasurementResult(success=False)
        stage_state = {"stage": "sampling"}

        def progress(stage, fraction, message):
            if self.plan_server.is_preempt_requested() or rospy.is_shutdown():
                # the stage the client last heard of, not the one about to start
                raise PlanningCancelled(f"cancelled during {stage_state['stage']}")
            stage_state["stage"] = stage
            self.plan_server.publish_feedback(
                PlanMeasurementFeedback(
                    stage=stage, stage_progress=fraction, progress=overall_progress(stage, fraction), message=message
                )
            )

        try:
            request = plan_request_from_goal(goal, self.session)
            store_name = request.plan_file
            if store_name:  # a plan file that cannot be written is refused before minutes of planning
                self.session.plan_path(store_name, overwrite=request.overwrite)
            # the plan is stored after it became the session's plan: a failed write loses no planning
            request = dataclasses.replace(request, plan_file="")
            outcome = self.session.plan_measurement(request, self._current_state(), progress)
        except PlanningCancelled as exc:
            result.error = str(exc)
            rospy.loginfo("trajectory_manager: planning %s", exc)
            self.plan_server.set_preempted(result, result.error)
            return
        except Exception as exc:  # keep serving after any error, with the trace of an unexpected one in the log
            if isinstance(exc, AgiprobotError):
                result.error = f"{stage_state['stage']}: {exc}"
                rospy.logwarn("trajectory_manager: planning failed: %s", result.error)
            else:
                result.error = f"internal error during {stage_state['stage']}: {type(exc).__name__}: {exc}"
                rospy.logerr("trajectory_manager: %s\n%s", result.error, traceback.format_exc())
            self.plan_server.set_aborted(result, result.error)
            return
        self._publish_plan_visuals()
        report = outcome.report
        result.success = True
        write_error = ""
        if store_name:
            try:
                result.plan_file = self._store_planned(store_name, request.overwrite)
            except (AgiprobotError, OSError) as exc:
                write_error = (
                    f"the plan was made and is the current plan, but its file was not written: {exc}; "
                    "store it elsewhere with store_plan"
                )
        result.number_of_views = report.n_views
        result.coverage = report.coverage_of_coverable
        result.coverage_of_samples = report.coverage_of_samples
        result.estimated_execution_time_s = report.estimated_execution_time_s
        result.number_of_samples = report.n_samples
        result.number_coverable_metrology = report.n_coverable_metrology
        result.number_coverable_executable = report.n_coverable
        result.number_covered = report.n_covered
        result.number_unverified = report.n_unverified
        result.optimality_gap = -1.0 if report.solver_gap is None else float(report.solver_gap)
        result.time_limit_hit = bool(report.time_limit_hit)
        result.tilt_mode_used = str(outcome.tilt_choice or report.tilt_mode)
        result.reachable_share = -1.0 if report.reachable_share is None else float(report.reachable_share)
        result.warnings = [str(w) for w in report.warnings]
        if write_error:
            result.success, result.error = False, write_error
            result.warnings.append(write_error)
            rospy.logwarn("trajectory_manager: %s", write_error)
            self.plan_server.set_aborted(result, write_error)
            return
        rospy.loginfo(
            "trajectory_manager: planned %d views covering %.1f %% of %d points coverable by executable views "
            "(%d measurable, %d samples; est. %.1f s)%s",
            report.n_views,
            100 * report.coverage_of_coverable,
            report.n_coverable,
            report.n_coverable_metrology,
            report.n_samples,
            report.estimated_execution_time_s,
            f", stored in {result.plan_file}" if result.plan_file else "",
        )
        self.plan_server.set_succeeded(result)

    def _store_planned(self, name: str, overwrite: bool) -> str:
        """Write the plan just made (the session's) to ``name`` as the planning run writes it; the path."""
        session = self.session
        manager = session.manager
        manager.store_execution_plan(str(session.plan_path(name, overwrite)), session.plan.segments)
        with session.lock:
            session.plan_source = str(manager.last_plan_path)
        return str(manager.last_plan_path)

    # ------------------------------------------------------------------------------------ visuals
    def _publish_plan_visuals(self):
        session, manager = self.session, self.session.manager
        header = Header(stamp=rospy.Time.now(), frame_id="world")
        colors = uncertainty_colors(
            manager.point_uncertainties(),
            manager.sensor_model.get_min_uncertainty(),
            manager.sensor_model.get_max_uncertainty(),
            session.coverable_mask,
        )
        self.surface_pub.publish(xyz_cloud(manager.samples.points / 1000.0, header, colors))
        self.measured_pub.publish(xyz_cloud(np.zeros((0, 3)), header))
        self.viewpoint_pub.publish(scan_line_markers(manager.scan_lines_mm(session.views), header))
        self._publish_path(header)
        self.part_pub.publish(part_markers(session.part, header))

    def _publish_path(self, header):
        manager = self.session.manager
        model = manager.kinematics if manager is not None else None
        self.path_pub.publish(path_marker(self.session.plan, model, header))

    # ------------------------------------------------------------------------------------ plans
    def on_load_plan(self, request):
        try:
            loaded = self.session.load(request.plan_file)
        except AgiprobotError as exc:
            return LoadPlanResponse(False, str(exc), 0, 0.0)
        if self.session.manager is not None:
            self._publish_path(Header(stamp=rospy.Time.now(), frame_id="world"))
        return LoadPlanResponse(True, f"loaded {loaded.path}", len(loaded.plan.segments), loaded.plan.duration)

    def on_store_plan(self, request):
        try:
            written = self.session.store(request.plan_file, overwrite=request.overwrite)
        except (AgiprobotError, OSError) as exc:
            return StorePlanResponse(False, str(exc), "")
        return StorePlanResponse(True, f"stored {written}", str(written))

    def on_get_report(self, request):
        try:  # the numbers belong to the plan the message names (a loaded plan has no prediction)
            summary = self.session.summary()
        except AgiprobotError as exc:
            return GetCoverageReportResponse(success=False, message=str(exc), measured_coverage=-1.0)
        figure = ""
        if request.figure_file:
            try:
                figure = str(self.session.write_figure(request.figure_file))
            except (AgiprobotError, ValueError, OSError) as exc:
                return GetCoverageReportResponse(success=False, message=f"figure: {exc}", measured_coverage=-1.0)
        report = summary.report
        response = GetCoverageReportResponse(
            figure_file=figure,
            success=True,
            message=summary.message,
            number_of_views=summary.number_of_views,
            predicted_coverage=-1.0,
            measured_coverage=summary.measured_coverage,
            estimated_execution_time_s=summary.estimated_execution_time_s,
            mean_uncertainty_mm=-1.0,
            max_uncertainty_mm=-1.0,
            report_yaml=yaml.safe_dump(yaml_plain(summary.as_dict()), sort_keys=False),
        )
        if report is not None:
            response.number_of_samples = report.n_samples
            response.number_of_coverable = report.n_coverable
            response.number_of_covered = report.n_covered
            response.predicted_coverage = report.coverage_of_coverable
            response.mean_uncertainty_mm = report.mean_uncertainty_mm
            response.max_uncertainty_mm = report.max_uncertainty_mm
        return response

    # ------------------------------------------------------------------------------------ execution
    def on_execute(self, goal):
        result = ExecutePlanResult(success=False, predicted_coverage=-1.0, measured_coverage=-1.0)
        session = self.session
        try:
            # a plan file is adopted only once everything accepted it: a refused goal keeps the current plan
            candidate = session.read(goal.plan_file) if goal.plan_file else None
            if candidate is None and session.plan is None:
                raise GoalError("no plan: plan one, load one, or give plan_file")
            if not self.robot.wait_for_server(5.0):
                raise GoalError(f"the robot controller's action server {self.robot.action} is not available")
            problem = self.controller.problem()
            if problem:
                raise GoalError(f"the robot controller is not running: {problem}")
            stopped = self.robot.stop_reason()
            if stopped:
                raise GoalError(f"the robot cannot move: {stopped}")
            plan = session.prepared_plan(self._current_state(), candidate)
            part = candidate.part if candidate is not None else session.part
            if part is not None:
                self.scanner.set_target(part)
            if candidate is not None:
                session.adopt(candidate)
        except (AgiprobotError, rospy.ROSException, rospy.ServiceException) as exc:
            result.error = str(exc)
            rospy.logwarn("trajectory_manager: execution refused: %s", exc)
            self.execute_server.set_aborted(result, result.error)
            return
        except Exception as exc:  # keep serving after an unexpected error, with its trace in the log
            result.error = f"internal error: {type(exc).__name__}: {exc}"
            rospy.logerr("trajectory_manager: %s\n%s", result.error, traceback.format_exc())
            self.execute_server.set_aborted(result, result.error)
            return
        executor = RosSegmentExecutor(
            self.robot,
            self.scanner,
            current_state=lambda: self.joint_states.latest(),
            cancel_requested=self.execute_server.is_preempt_requested,
            on_measure=self._show_measured_points,
            controller_problem=self.controller.problem,
        )

        def on_segment(feedback):
            phase = "measure" if feedback.kind == "measure" else "connect"
            self.execute_server.publish_feedback(
                ExecutePlanFeedback(feedback.number, feedback.total, phase, feedback.done_fraction)
            )

        self.scanner.start_collecting()
        try:
            outcome = session.execute(plan, executor, on_segment)
        except BaseException:
            self.scanner.finish_collecting()
            raise
        result.segments_executed = outcome.segments_executed
        if outcome.status == "controller_lost":
            # the client hears at once; what was measured without a robot is not worth waiting for
            result.error = outcome.describe()
            rospy.logwarn("trajectory_manager: execution aborted: %s", result.error)
            self.execute_server.set_aborted(result, result.error)
            self.scanner.finish_collecting(profile_wait_s=0.0, cloud_wait_s=0.0)
            return
        measured_points = self.scanner.finish_collecting()
        coverage = session.measured(measured_points)
        if coverage is not None:
            result.predicted_coverage = coverage.predicted_coverage
            result.measured_coverage = coverage.measured_coverage
            self.measured_pub.publish(
                xyz_cloud(
                    session.samples_mm / 1000.0,
                    Header(stamp=rospy.Time.now(), frame_id="world"),
                    measured_colors(coverage.measured),
                )
            )
        if outcome.status == "cancelled":
            result.error = outcome.describe()
            self.execute_server.set_preempted(result, result.error)
        elif not outcome.ok:
            result.error = outcome.describe()
            rospy.logwarn("trajectory_manager: execution aborted: %s", result.error)
            self.execute_server.set_aborted(result, result.error)
        else:
            result.success = True
            self.execute_server.set_succeeded(result)
        rospy.loginfo(
            "trajectory_manager: executed %d of %d segments; %s",
            result.segments_executed,
            outcome.total,
            coverage_summary(result.predicted_coverage, result.measured_coverage),
        )

    def _show_measured_points(self, view, active: bool) -> None:
        header = Header(stamp=rospy.Time.now(), frame_id="world")
        if active and view is not None and self.session.samples_mm is not None:
            self.current_pub.publish(xyz_point_cloud(self.session.samples_mm[view.measurable_indices] / 1000.0, header))
        elif not active:
            self.current_pub.publish(xyz_point_cloud(np.zeros((0, 3)), header))


def coverage_summary(predicted: float, measured: float) -> str:
    """The coverage part of the execution log line; a negative share is unknown (a loaded plan has no samples)."""
    if predicted < 0 and measured < 0:
        return "coverage not known (a loaded plan has no sample points to compare)"
    return f"coverage predicted {100 * predicted:.1f} %, measured {100 * measured:.1f} %"


def main():
    run_node("trajectory_manager", TrajectoryManagerNode)
