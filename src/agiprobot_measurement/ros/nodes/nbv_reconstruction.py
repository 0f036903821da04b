"""The ``nbv_reconstruction`` node (nodes/nbv_reconstruction): next-best-view reconstruction of an unknown part on the
station, the ROS layer over :class:`agiprobot_measurement.nbv.volumetric.reconstruction.Reconstructor`.

The loop is ROS-free; this node gives it the station's robot (:class:`~agiprobot_measurement.ros.nbv_interfaces.
RosNBVRobot`: the robot's trajectory action through the motion client and /joint_states) and the PhoXi on the flange
(:class:`~agiprobot_measurement.ros.nbv_interfaces.RosNBVCamera`: phoxi_camera's trigger_image / get_frame, the
frame's cloud and the sensor's pose from tf at its stamp), and maps the messages.

Action ``~reconstruct_object`` (agiprobot_measurement/ReconstructObject): the goal's empty / zero fields take the
defaults of ``~config`` (config/nbv.yaml ``request``); a bad goal (NaN or infinite numbers, a negative value, a ROI
with a zero or negative edge, a ROI or resolution whose grid would exceed ``~max_voxels``, an unknown gain or
candidate set, an output folder outside the allowed ones) is aborted at once with the reason in ``error``, and the
node goes on serving. Feedback per view and phase (search, capture, integrate, candidates, evaluate, plan_motion,
move, finish) with the best gain, candidate counts, observed area and, in simulation, the coverage. Cancel stops at
the next phase, or the robot where it is while it moves; the result then says ``cancelled`` (preempted). The result
names the termination reason and the output files (fused cloud PLY, mesh, map, view log). ``execute: false``
plans only: one frame from where the robot stands, fused (into the last plan-only goal's map when ROI,
resolutions, gain and candidates are the same: a user may move the robot between such goals), and the next best
view (pose, joints, gain) returned without moving.

Services: ``~reset`` (std_srvs/Trigger: forget the map; refused while a goal runs), ``~save`` (std_srvs/Trigger:
write the current map's outputs again, to a new folder under ~output_dir; the message names the files).
Topics (latched): ``~occupied_voxels``, ``~frontier_voxels``, ``~occlusion_plane`` (MarkerArray, one CUBE_LIST
each: full voxels coloured by height, the report's candidate voxels, unknown voxels next to empty ones),
``~candidate_views`` (MarkerArray arrows: feasible coloured by utility, rejected grey in ``rejected/<reason>``),
``~next_best_view`` (PoseStamped), ``~view_frustum`` (Marker LINE_LIST of the next view), ``~mesh`` (Marker
TRIANGLE_LIST of the run's TSDF mesh, at its end), ``~sensor_path`` (nav_msgs/Path of the views taken), ``~fused_cloud`` (PointCloud2 of the map's raw points, thinned to
``~cloud_voxel_m``), ``/diagnostics`` (the phase, or idle with the last termination reason), ``~accepted_goal`` (ReconstructObjectActionGoal: each goal as received, with its id, for the
bag script).

Parameters: ``~config`` (config/nbv.yaml), ``~scene`` (config/scene.yaml: the station the loop knows and, in
simulation, the part), ``~model`` (PhoXi model, "" = config's), ``~camera_ns`` (/phoxi_camera), ``~executor``
(follow_joint_trajectory | moveit), ``~controller_action`` ("" = the executor's action), ``~world_frame`` (world), ``~output_dir`` ("" = $ROS_HOME/nbv: where results go;
a goal's relative output_dir resolves under it), ``~allowed_output_dirs`` (where absolute ones may also point;
default /tmp), ``~ground_truth`` (true: the coverage of the scene's part's observable surface, simulation only),
``~max_voxels`` (2e7: the largest fine grid a goal may ask for), ``~start_at_home`` (false; true
in simulation: the robot is placed at config motion.home_rad at start through ``~set_joint_state_service``,
/ur_driver_sim/set_joint_state), ``~frame_timeout_s`` (30), ``~settle_s`` (0.1: after
a motion, for tf to show the final pose), ``~cloud_voxel_m`` (0.002), ``~marker_max_cubes`` (200000).
"""

from __future__ import annotations

import os
import threading
import time
import traceback
from pathlib import Path

import actionlib
import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger, TriggerResponse
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.common.config import ConfigError, number, whole
from agiprobot_measurement.common.files import FileRoot
from agiprobot_measurement.common.limits import LIMITS
from agiprobot_measurement.errors import AgiprobotError, InputError
from agiprobot_measurement.msg import (
    ReconstructObjectAction,
    ReconstructObjectActionGoal,
    ReconstructObjectFeedback,
    ReconstructObjectResult,
)
from agiprobot_measurement.nbv.volumetric.interfaces import CapturedView
from agiprobot_measurement.nbv.volumetric.reconstruction import Reconstructor
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest
from agiprobot_measurement.nbv.volumetric.results import Progress
from agiprobot_measurement.ros import markers
from agiprobot_measurement.ros.conversions import pose_stamped, sensor_path, xyz_cloud
from agiprobot_measurement.ros.nbv_interfaces import RosNBVCamera, RosNBVRobot
from agiprobot_measurement.ros.nbv_messages import candidate_arrays, request_mapping_from_goal
from agiprobot_measurement.ros.nbv_setup import nbv_station
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, file_param, flag, read_params, text
from agiprobot_measurement.ros.robot_client import MotionSettings, motion_parameters
from agiprobot_measurement.srv import SetJointState

__all__ = ["NBVReconstructionNode", "main"]


class _RecordingCamera:
    """The camera as the loop sees it, keeping the sensor pose of every view for ~sensor_path."""

    def __init__(self, camera, on_view):
        self.camera = camera
        self.on_view = on_view

    def capture(self) -> CapturedView:
        view = self.camera.capture()
        self.on_view(view)
        return view


def _map_key(request) -> tuple:
    """What makes two requests build the same map (a plan-only goal goes on with the last one's)."""
    roi = tuple(None if v is None else tuple(np.round(np.asarray(v, dtype=float), 9)) for v in (
        request.roi_center_m, request.roi_size_m))  # fmt: skip
    return (*roi, request.resolution_m, request.planning_resolution_m, request.gain, request.candidates)


#: the node's parameters (name, default, validator), read once at start
PARAMETERS = (
    Param("~model", ""),
    Param("~ground_truth", False, flag),
    Param("~world_frame", "world", text),
    Param("~output_dir", ""),
    Param("~allowed_output_dirs", ""),
    Param("~max_voxels", 2e7, number),
    Param("~cloud_voxel_m", 0.002, number),
    Param("~marker_max_cubes", markers.MAX_CUBES, whole),
    *motion_parameters("~"),
    Param("~settle_s", 0.1, number),
    Param("~camera_ns", "/phoxi_camera"),
    Param("~frame_timeout_s", 30.0, number),
    Param("~start_at_home", False),
    Param("~set_joint_state_service", "/ur_driver_sim/set_joint_state"),
)


class NBVReconstructionNode:
    def __init__(self):
        settings = read_params(PARAMETERS)
        self.model = str(settings.model or "")
        self.use_ground_truth = settings.ground_truth
        # the station the loop knows (scene, robot with the PhoXi, IK, collision); in simulation also the truth
        self.config, self.station, self.ground_truth = nbv_station(
            file_param("~config"), file_param("~scene"), self.model, self.use_ground_truth
        )
        self.defaults = dict(self.config.get("request", {}))
        self.world_frame = settings.world_frame
        ros_home = Path(os.environ.get("ROS_HOME") or "~/.ros").expanduser()
        output_dir = str(settings.output_dir or ros_home / "nbv")
        allowed = settings.allowed_output_dirs or ["/tmp"]
        if isinstance(allowed, str):
            allowed = allowed.replace(",", " ").split()
        Path(output_dir).expanduser().mkdir(parents=True, exist_ok=True)
        self.files = FileRoot(Path(output_dir).expanduser(), tuple(Path(d) for d in allowed), purpose="NBV output")
        self.max_voxels = settings.max_voxels
        self.cloud_voxel_m = settings.cloud_voxel_m
        self.max_cubes = settings.marker_max_cubes
        if not (self.max_voxels > 0 and self.cloud_voxel_m > 0 and self.max_cubes > 0):
            raise ConfigError("~max_voxels, ~cloud_voxel_m and ~marker_max_cubes must be positive")
        if self.max_voxels > LIMITS.map_voxels:
            raise ConfigError(
                f"~max_voxels {self.max_voxels:.3g} is above the package's limit of {LIMITS.map_voxels:.3g}"
            )

        self.server = actionlib.SimpleActionServer(
            "~reconstruct_object", ReconstructObjectAction, execute_cb=self.on_goal, auto_start=False
        )
        self.robot = RosNBVRobot(
            self.station.limits,
            MotionSettings(settings.executor, settings.controller_action),
            settle_s=settings.settle_s,
            cancel_requested=self._cancel_requested,
        )
        self.camera = RosNBVCamera(
            settings.camera_ns,
            world_frame=self.world_frame,
            frame_timeout_s=settings.frame_timeout_s,
        )
        self.lock = threading.Lock()  # one goal or reset / save at a time
        self.reconstructor = None
        self.plan_only_key = None  # the map a plan-only goal goes on with (see _make_reconstructor)
        self.plan_only_views = 0
        self.view_poses: list[np.ndarray] = []
        self._published = (None, -1)  # (map, points) last shown on the topics

        latched = {"queue_size": 1, "latch": True}
        self.pubs = {
            "occupied_voxels": rospy.Publisher("~occupied_voxels", MarkerArray, **latched),
            "frontier_voxels": rospy.Publisher("~frontier_voxels", MarkerArray, **latched),
            "occlusion_plane": rospy.Publisher("~occlusion_plane", MarkerArray, **latched),
            "candidate_views": rospy.Publisher("~candidate_views", MarkerArray, **latched),
            "next_best_view": rospy.Publisher("~next_best_view", PoseStamped, **latched),
            "view_frustum": rospy.Publisher("~view_frustum", Marker, **latched),
            "mesh": rospy.Publisher("~mesh", Marker, **latched),
            "sensor_path": rospy.Publisher("~sensor_path", PathMsg, **latched),
            "fused_cloud": rospy.Publisher("~fused_cloud", PointCloud2, **latched),
            # every goal as the node received it, from the node's own publisher (a recorder may miss the first
            # message of a client that just connected): the bag script takes the runs from here
            "diagnostics": rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5),
            "accepted_goal": rospy.Publisher("~accepted_goal", ReconstructObjectActionGoal, queue_size=10, latch=True),
        }
        self.services = [
            rospy.Service("~reset", Trigger, self.on_reset),
            rospy.Service("~save", Trigger, self.on_save),
        ]
        if settings.start_at_home:
            self._place_at_home(settings.set_joint_state_service)
        self.server.start()
        rospy.loginfo(
            "nbv_reconstruction: ready (PhoXi %s, outputs under %s%s)",
            self.model or self.config.get("phoxi_tool", {}).get("model", "?"),
            self.files.root,
            ", coverage against the scene's part" if self.ground_truth is not None else "",
        )

    # ------------------------------------------------------------------------------------ set-up
    def _place_at_home(self, service: str) -> None:
        """Simulation: put the robot at config/nbv.yaml's motion.home_rad at once (robot_sim's set_joint_state), so
        the launch file need not repeat the configured joints."""
        try:
            rospy.wait_for_service(service, timeout=20.0)
            reply = rospy.ServiceProxy(service, SetJointState)(positions=list(self.station.home_rad), named_state="")
        except (rospy.ROSException, rospy.ServiceException) as exc:
            raise ConfigError(f"~start_at_home: {service}: {exc}") from exc
        if not reply.success:
            raise ConfigError(f"~start_at_home: {service} refused the home joints: {reply.message}")
        rospy.loginfo("nbv_reconstruction: robot placed at the home joints %s", np.round(self.station.home_rad, 3))

    def _header(self) -> Header:
        return Header(stamp=rospy.Time.now(), frame_id=self.world_frame)

    def _cancel_requested(self) -> bool:
        return self.server.is_preempt_requested() or rospy.is_shutdown()

    # ------------------------------------------------------------------------------------ goal
    def _output_dir(self, requested: str, prefix: str = "run") -> Path:
        """The goal's output folder: ``requested`` (its files are replaced, each atomically), or a new folder
        ``<prefix>_<date>_<time>[_n]`` under ~output_dir."""
        if requested.strip():
            path = self.files.resolve(requested.strip())
            if path.exists() and not path.is_dir():
                raise InputError(f"output_dir: {path} exists and is not a folder")
            return path
        name = time.strftime(f"{prefix}_%Y%m%d_%H%M%S")
        path, n = self.files.resolve(name), 1
        while path.exists():
            n += 1
            path = self.files.resolve(f"{name}_{n}")
        return path

    def _make_reconstructor(self, goal):
        """The loop for ``goal`` and its output folder; a plan-only goal over the same map as the last plan-only
        goal (ROI, resolutions, gain, candidates) goes on with that map, so a user who moves the robot between
        plan-only goals builds one map (``~reset`` starts a new one)."""
        values = request_mapping_from_goal(goal, self.defaults, self.max_voxels, self.station.default_roi()[1])
        output_dir = self._output_dir(goal.output_dir)
        values["output_dir"] = str(output_dir)
        request = ReconstructionRequest.from_mapping(values)
        key = _map_key(request)
        previous = self.reconstructor
        if not request.execute and previous is not None and self.plan_only_key == key:
            return previous, output_dir
        self.view_poses, self.plan_only_views = [], 0
        if self.ground_truth is not None:
            self.ground_truth.reset()
        camera = _RecordingCamera(self.camera, self._on_view)
        reconstructor = Reconstructor(self.robot, camera, request, station=self.station, ground_truth=self.ground_truth)
        self.plan_only_key = None if request.execute else key
        return reconstructor, output_dir

    def on_goal(self, goal):
        result = ReconstructObjectResult(success=False, coverage=-1.0)
        if not self.lock.acquire(blocking=False):
            result.error = "busy: a reset or save is running"
            self.server.set_aborted(result, result.error)
            return
        phase = {"name": "setup", "view": 0}
        self._announce(goal)
        try:
            try:
                reconstructor, output_dir = self._make_reconstructor(goal)
            except AgiprobotError as exc:  # a bad goal: refused before anything moves
                result.error = f"bad goal: {exc}"
                result.termination_reason = "error"
                rospy.logwarn("nbv_reconstruction: %s", result.error)
                self.server.set_aborted(result, result.error)
                return
            if reconstructor is not self.reconstructor:
                self._clear_markers()
            self.reconstructor = reconstructor
            last = {"progress": None}

            def on_progress(progress):
                phase["name"], phase["view"] = progress.phase, progress.view
                last["progress"] = progress
                self.server.publish_feedback(self._feedback(progress))
                self._publish_progress(progress)

            if goal.execute:
                outcome = reconstructor.run(on_progress=on_progress, should_cancel=self._cancel_requested)
                self._fill_result(result, outcome)
                outputs_error = outcome.outputs_error  # the run's files are not all written: the goal failed
                pose = self.view_poses[-1] if self.view_poses else None
            else:
                outputs_error = ""
                pose = self._plan_only(result, reconstructor, output_dir, on_progress)
            if pose is not None:
                result.next_view = pose_stamped(pose, self._header())
                self.pubs["next_best_view"].publish(result.next_view)
            self._visual(self._publish_map)
            self._visual(lambda: self._publish_mesh(result.mesh_file))
            if self.server.is_preempt_requested() or result.termination_reason == "cancelled":
                result.termination_reason = "cancelled"
                result.error = f"cancelled during {phase['name']} of view {phase['view']}"
                self.server.set_preempted(result, result.error)
            elif result.termination_reason == "error" or outputs_error:
                result.error = result.error or outputs_error or "the reconstruction failed (see the node's log)"
                rospy.logwarn("nbv_reconstruction: %s", result.error)
                self.server.set_aborted(result, result.error)
            else:
                result.success = True
                self.server.set_succeeded(result)
            self._diagnose(
                f"idle: {result.termination_reason} after {result.number_of_views} views",
                DiagnosticStatus.OK
                if result.success or result.termination_reason == "cancelled"
                else DiagnosticStatus.WARN,
                error=result.error,
            )
            rospy.loginfo(
                "nbv_reconstruction: %s after %d views, observed %.4f m^2%s",
                result.termination_reason,
                result.number_of_views,
                result.observed_surface_area_m2,
                f", coverage {100 * result.coverage:.1f} %" if result.coverage >= 0 else "",
            )
        except Exception as exc:  # keep serving after any failure, with the trace of an unexpected one in the log
            if isinstance(exc, AgiprobotError | OSError):
                result.error = f"{phase['name']} (view {phase['view']}): {exc}"
                rospy.logwarn("nbv_reconstruction: %s", result.error)
            else:
                result.error = f"internal error during {phase['name']}: {type(exc).__name__}: {exc}"
                rospy.logerr("nbv_reconstruction: %s\n%s", result.error, traceback.format_exc())
            result.termination_reason = "cancelled" if self.server.is_preempt_requested() else "error"
            if self.server.is_preempt_requested():
                self.server.set_preempted(result, result.error)
            else:
                self.server.set_aborted(result, result.error)
        finally:
            self.lock.release()

    def _announce(self, goal) -> None:
        accepted = ReconstructObjectActionGoal(goal=goal)
        accepted.header.stamp = rospy.Time.now()
        handle = getattr(self.server, "current_goal", None)
        if handle is not None and handle.get_goal_id() is not None:
            accepted.goal_id = handle.get_goal_id()
        self.pubs["accepted_goal"].publish(accepted)

    def _feedback(self, progress) -> ReconstructObjectFeedback:
        feedback = ReconstructObjectFeedback(
            view=int(progress.view),
            phase=str(progress.phase),
            best_gain=float(progress.best_gain),
            relative_gain=float(progress.relative_gain),
            candidates_total=int(progress.candidates_total),
            candidates_feasible=int(progress.candidates_feasible),
            observed_surface_area_m2=float(progress.observed_area_m2),
            coverage=-1.0 if progress.coverage is None else float(progress.coverage),
            progress=float(progress.progress),
        )
        if progress.next_view_pose is not None:
            feedback.next_view = pose_stamped(progress.next_view_pose, self._header())
        return feedback

    def _fill_result(self, result, outcome) -> None:
        result.termination_reason = str(outcome.termination_reason)
        result.error = str(getattr(outcome, "error", "") or "")
        result.number_of_views = len(outcome.views)
        result.observed_surface_area_m2 = float(outcome.observed_surface_area_m2)
        result.remaining_frontier_area_m2 = float(outcome.remaining_frontier_area_m2)
        result.coverage = -1.0 if outcome.coverage is None else float(outcome.coverage)
        result.joint_path_rad = float(outcome.joint_path_rad)
        result.tcp_path_m = float(outcome.tcp_path_m)
        result.planning_time_s = float(outcome.planning_time_s)
        result.execution_time_s = float(outcome.execution_time_s)
        result.cloud_file, result.mesh_file = str(outcome.cloud_file or ""), str(outcome.mesh_file or "")
        result.map_file, result.log_file = str(outcome.map_file or ""), str(outcome.log_file or "")

    def _plan_only(self, result, reconstructor, output_dir, on_progress):
        """execute false: one frame from where the robot stands, fused into the map, and the next best view from
        there; nothing moves. Returns the view's pose (None when there is none; the reason is the result's)."""

        def report(phase, **values):
            grid = reconstructor.map
            coverage = None if self.ground_truth is None else self.ground_truth.coverage()
            on_progress(
                Progress(
                    view=self.plan_only_views + 1,
                    phase=phase,
                    observed_area_m2=grid.observed_surface_area_m2(),
                    coverage=coverage,
                    **values,
                )
            )

        report("capture")
        view = reconstructor.camera.capture()
        if self._cancel_requested():
            result.termination_reason = "cancelled"
            return None
        report("integrate")
        reconstructor.integrate(view)
        self.plan_only_views += 1
        report("evaluate")
        started = time.perf_counter()
        pose, joints, gain, reason = reconstructor.next_best_view()
        result.planning_time_s = time.perf_counter() - started
        result.termination_reason = "plan_only" if pose is not None else (reason or "nothing_found")
        result.number_of_views = self.plan_only_views
        result.observed_surface_area_m2 = float(reconstructor.map.observed_surface_area_m2())
        result.remaining_frontier_area_m2 = float(reconstructor.map.frontier_area_m2())
        result.coverage = -1.0 if self.ground_truth is None else float(self.ground_truth.coverage())
        result.next_view_joints = [] if joints is None else [float(v) for v in joints]
        result.next_view_gain = float(gain)
        files = reconstructor.save_outputs(str(output_dir))
        result.cloud_file, result.mesh_file = files.get("cloud", ""), files.get("mesh", "")
        result.map_file, result.log_file = files.get("map", ""), files.get("log", "")
        report("finish", best_gain=float(gain), next_view_pose=pose)
        if pose is None:
            rospy.loginfo("nbv_reconstruction: plan only: no next best view: %s", reason)
        return pose

    # ------------------------------------------------------------------------------------ visuals
    def _on_view(self, view: CapturedView) -> None:
        self.view_poses.append(np.asarray(view.camera_pose, dtype=float))
        self.pubs["sensor_path"].publish(sensor_path(self.view_poses, self._header()))

    def _diagnose(self, message: str, level=DiagnosticStatus.OK, **values) -> None:
        status = DiagnosticStatus(level=level, name="nbv_reconstruction", message=message, hardware_id="none")
        status.values = [KeyValue(key, str(value)) for key, value in values.items()]
        self.pubs["diagnostics"].publish(DiagnosticArray(header=self._header(), status=[status]))

    def _publish_progress(self, progress) -> None:
        self._diagnose(
            f"view {progress.view}: {progress.phase}",
            observed_surface_area_m2=round(float(progress.observed_area_m2), 6),
            coverage=-1.0 if progress.coverage is None else round(float(progress.coverage), 4),
        )
        try:
            # the map changes between a frame's "integrate" and the next phase
            if progress.phase in ("search", "candidates", "evaluate", "finish"):
                self._publish_map()
            if progress.phase in ("evaluate", "plan_motion") and self.reconstructor is not None:
                poses, utilities, reasons = candidate_arrays(self.reconstructor.candidates_last)
                self.pubs["candidate_views"].publish(
                    markers.candidate_markers(poses, utilities, reasons, self._header())
                )
            if progress.next_view_pose is not None:
                header = self._header()
                self.pubs["next_best_view"].publish(pose_stamped(progress.next_view_pose, header))
                self._publish_frustum(progress.next_view_pose, header)
        except Exception as exc:  # a picture must not end a reconstruction (the loop would stop with "error")
            rospy.logwarn_throttle(10.0, "nbv_reconstruction: markers: %s: %s", type(exc).__name__, exc)

    @staticmethod
    def _visual(publish) -> None:
        try:
            publish()
        except Exception as exc:  # a picture must not turn a finished reconstruction into a failure
            rospy.logwarn("nbv_reconstruction: markers: %s: %s", type(exc).__name__, exc)

    def _publish_mesh(self, mesh_file: str) -> None:
        """The run's TSDF mesh (its PLY) on ~mesh; an empty marker when there is none."""
        marker = Marker(header=self._header(), ns="mesh", id=0, type=Marker.TRIANGLE_LIST, action=Marker.DELETE)
        if mesh_file:
            import trimesh

            try:
                mesh = trimesh.load(mesh_file, force="mesh")
                marker = markers.mesh_marker(mesh.vertices, mesh.faces, self._header())
            except Exception as exc:  # trimesh raises many kinds for an unreadable file; a picture is not the result
                rospy.logwarn("nbv_reconstruction: mesh %s not shown: %s", mesh_file, exc)
        self.pubs["mesh"].publish(marker)

    def _publish_frustum(self, pose, header) -> None:
        view_model = getattr(self.reconstructor, "view_model", None)
        if view_model is None:
            return
        self.pubs["view_frustum"].publish(
            markers.frustum_marker(
                pose,
                view_model.fov_h_rad,
                view_model.fov_v_rad,
                (view_model.range_min_m, view_model.range_max_m),
                header,
            )
        )

    def _publish_map(self) -> None:
        """The map's layers and fused cloud, when points were fused since the last time."""
        grid = getattr(self.reconstructor, "map", None)
        if grid is None or (grid is self._published[0] and len(grid.raw) == self._published[1]):
            return
        self._published = (grid, len(grid.raw))
        header = self._header()
        size = float(grid.resolution_m)
        layers = (
            ("occupied_voxels", np.argwhere(grid.labels() == 1), None),
            ("frontier_voxels", grid.candidate_voxels(), markers.FRONTIER_RGBA),
            ("occlusion_plane", grid.occlusion_plane(), markers.OCCLUSION_RGBA),
        )
        for name, indices, rgba in layers:
            centres = grid.index_to_world(np.asarray(indices).reshape(-1, 3))
            self.pubs[name].publish(markers.voxel_markers(centres, size, header, name, rgba, self.max_cubes))
        points = np.asarray(grid.raw.xyz_m, dtype=float).reshape(-1, 3)
        if len(points):
            keys = np.floor(points / self.cloud_voxel_m).astype(np.int64)
            _, first = np.unique(keys, axis=0, return_index=True)
            points = points[np.sort(first)]
        self.pubs["fused_cloud"].publish(xyz_cloud(points, header))

    def _clear_markers(self) -> None:
        header = self._header()
        self._published = (None, -1)
        for name in ("occupied_voxels", "frontier_voxels", "occlusion_plane", "candidate_views"):
            self.pubs[name].publish(MarkerArray(markers=[markers.clear(header)]))
        self.pubs["sensor_path"].publish(sensor_path([], header))
        self.pubs["fused_cloud"].publish(xyz_cloud(np.zeros((0, 3)), header))

    # ------------------------------------------------------------------------------------ services
    def on_reset(self, _request):
        if not self.lock.acquire(blocking=False):
            return TriggerResponse(success=False, message="busy: a reconstruction is running (cancel it first)")
        try:
            self.reconstructor, self.view_poses = None, []
            self.plan_only_key, self.plan_only_views = None, 0
            self._clear_markers()
        finally:
            self.lock.release()
        return TriggerResponse(success=True, message="map cleared")

    def on_save(self, _request):
        if not self.lock.acquire(blocking=False):
            return TriggerResponse(success=False, message="busy: a reconstruction is running; it saves at its end")
        try:
            if self.reconstructor is None or getattr(self.reconstructor, "map", None) is None:
                return TriggerResponse(success=False, message="nothing to save: no map (run a goal first)")
            folder = self._output_dir("", prefix="save")
            files = self.reconstructor.save_outputs(str(folder))
        except (AgiprobotError, OSError) as exc:
            return TriggerResponse(success=False, message=f"save failed: {exc}")
        finally:
            self.lock.release()
        listing = ", ".join(f"{k}: {v}" for k, v in sorted(files.items()) if v)
        return TriggerResponse(success=True, message=f"saved to {folder}: {listing}")


def main():
    run_node("nbv_reconstruction", NBVReconstructionNode)
