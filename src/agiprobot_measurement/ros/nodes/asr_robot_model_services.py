"""The node ``asr_robot_model_services`` (launched by packages/asr_robot_model_services/nodes/asr_robot_model_services,
the original package's node type): the MILD's robot model (:mod:`agiprobot_measurement.mild.robot_model`) as ROS
services. Also the node ``asr_robot_model_services_ik_test`` (:class:`IKTest`, test_IK.launch).

Services (in the node's namespace, /asr_robot_model_services/<Name>; types asr_robot_model_services/*, the original's,
except CalculateRobotState, agiprobot_measurement/CalculateRobotState):
  CalculateCameraPose            RobotStateMessage -> camera mount pose (forward kinematics)
  CalculateCameraPoseCorrection  (state, orientation, position) -> pan, tilt aiming at the view centre, base fixed
  GetDistance                    2-D distance, or the planned path's length with useGlobalPlanner; -1 without path
  GetRobotPose, GetCameraPose    (GetPose) tf map -> base frame / camera mount frame
  IsPositionAllowed              inflated map occupancy within [0, colThresh]; unknown is not allowed
  CalculateRobotState            (state, orientation, position) -> IK with base movement (robotModelId 1 or 2)
A request with NaN/infinite or absurd values (positions beyond 10 km, angles beyond 1000 rad), a zero quaternion, or a
source state whose pan or tilt lies outside the settings' PTU limits (as mild_sim/set_state refuses it) is answered
with an error naming the value and the limit; the node keeps serving.

Topics: IK markers (visualization_msgs/Marker) on the IKVisualization topic (/asr_robot_model_services/IK_Visualization)
when visualizeIK; the current camera's frustum on /nbv/frustum_marker_array (MarkerArray, frustumRate_hz from tf);
the inflated map on ~costmap (nav_msgs/OccupancyGrid, latched) once the node has a map.

The map: as the original, the node reads nav_msgs/OccupancyGrid from /map (a map_server's). With ~publishMap true it
loads ~mapFile itself and publishes it on /map (latched; RobotModelServiceSim.launch does, RobotModelServiceReal.launch
does not). Until a map has arrived the map's services (IsPositionAllowed, CalculateRobotState, GetDistance with
useGlobalPlanner) wait up to ~mapTimeout_s and then answer with an error naming /map; a later map replaces it.

Parameters: the original's keys in the private namespace (asr_robot_model_services' param/ files; absent keys take
the original's defaults, see agiprobot_measurement.mild.config), this package's additions (lpSolver, fov*_deg,
inflation radii, frustumRate_hz, tfTimeout_s), ~kinematics (config/mild_kinematics.yaml), ~mapFile
(config/maps/mild_lab.yaml), ~publishMap (false), ~mapTimeout_s (10). debugLevels selects which categories are
logged at debug level (PARAMETERS: the settings at start; ROBOT_MODEL: each request; MAP: maps received), as the
original's DebugHelper does.
"""

__all__ = ["IKTest", "RobotModelServices", "ik_test_main", "main"]


import functools
import math
import threading

import numpy as np
import rospy
import tf2_ros
from asr_robot_model_services.srv import (
    CalculateCameraPose,
    CalculateCameraPoseCorrection,
    CalculateCameraPoseCorrectionResponse,
    CalculateCameraPoseResponse,
    GetDistance,
    GetDistanceResponse,
    GetPose,
    GetPoseResponse,
    IsPositionAllowed,
    IsPositionAllowedResponse,
)
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.errors import AgiprobotError, InputError
from agiprobot_measurement.mild.config import DEFAULTS, FrameNames, load_kinematics, load_map, settings_from_mapping
from agiprobot_measurement.mild.robot_model import MildRobotModel
from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros import markers
from agiprobot_measurement.ros import mild_messages as mild_ros
from agiprobot_measurement.ros.conversions import matrix_to_pose, transform_to_matrix, xyz_array, xyzw_array
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import file_param, param
from agiprobot_measurement.srv import CalculateRobotState, CalculateRobotStateResponse


def answers_errors(handler):
    """The package's errors (a bad request: InputError; the rest: InternalError) and missing tf become service errors
    with the reason; nothing stops the node."""

    @functools.wraps(handler)
    def wrapper(self, request):
        try:
            return handler(self, request)
        except (AgiprobotError, tf2_ros.TransformException) as exc:
            if isinstance(exc, InputError):
                rospy.logwarn("asr_robot_model_services: %s refused: %s", handler.__name__, exc)
            else:
                rospy.logerr("asr_robot_model_services: %s failed: %s", handler.__name__, exc)
            raise rospy.ServiceException(str(exc)) from exc

    return wrapper


class RobotModelServices:
    def __init__(self):
        name = rospy.get_name()
        params = param("~", {})
        settings = settings_from_mapping(params, f"parameters of {name}")
        for warning in settings.warnings:
            rospy.logwarn("asr_robot_model_services: %s", warning)
        if settings.defaulted:
            rospy.loginfo(
                "asr_robot_model_services: not set, the original's defaults: %s",
                ", ".join(f"{key}={DEFAULTS[key]}" for key in settings.defaulted),
            )
        rospy.set_param("~IKAngleRatingInUse", settings.ik_angle_rating)
        frames = FrameNames.from_mapping(params, f"parameters of {name} (frame names)", require_all=False)
        self.kinematics = load_kinematics(file_param("~kinematics"), frames)
        self.settings = settings
        self.model = MildRobotModel(self.kinematics, settings, None)
        self.map_ready = threading.Event()
        self.map_timeout_s = float(params.get("mapTimeout_s", 10.0))
        self.frames = frames
        if settings.debug("PARAMETERS"):
            rospy.logdebug("asr_robot_model_services: settings %s; frames %s", settings, frames)
            rospy.logdebug(
                "asr_robot_model_services: speedFactorPTU %s, speedFactorBaseMove %s, speedFactorBaseRot %s "
                "(read as the original does; no answer depends on them)",
                *settings.speed_factors,
            )
        self.tf_timeout = rospy.Duration(float(params.get("tfTimeout_s", 1.0)))
        self.tf_buffer = tf2_ros.Buffer()
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.ik_publisher = rospy.Publisher(settings.ik_visualization_topic, Marker, queue_size=200)
        self.frustum_publisher = rospy.Publisher("/nbv/frustum_marker_array", MarkerArray, queue_size=1)
        self.costmap_publisher = rospy.Publisher("~costmap", OccupancyGrid, queue_size=1, latch=True)
        self.visualization_lock = threading.Lock()
        self.publish_map = _flag_param(params, "publishMap", False)
        if self.publish_map:
            occupancy = load_map(file_param("~mapFile"), settings)
            self.map_publisher = rospy.Publisher("/map", OccupancyGrid, queue_size=1, latch=True)
            self.map_publisher.publish(mild_ros.occupancy_grid_msg(occupancy, frames.map_frame, rospy.Time.now()))
            self._use_map(occupancy)
        else:
            self.map_subscriber = rospy.Subscriber("/map", OccupancyGrid, self.on_map, queue_size=1)
        self.services = [
            rospy.Service("~GetDistance", GetDistance, self.get_distance),
            rospy.Service("~CalculateCameraPose", CalculateCameraPose, self.calculate_camera_pose),
            rospy.Service("~IsPositionAllowed", IsPositionAllowed, self.is_position_allowed),
            rospy.Service("~GetRobotPose", GetPose, self.get_robot_pose),
            rospy.Service("~GetCameraPose", GetPose, self.get_camera_pose),
            rospy.Service(
                "~CalculateCameraPoseCorrection", CalculateCameraPoseCorrection, self.calculate_camera_pose_correction
            ),
            rospy.Service("~CalculateRobotState", CalculateRobotState, self.calculate_robot_state),
        ]
        rate = float(params.get("frustumRate_hz", 2.0))
        if rate > 0:
            self.frustum_timer = rospy.Timer(rospy.Duration(1.0 / rate), self.publish_frustum)
        model_name = {1: "MILDRobotModelWithExactIK", 2: "MILDRobotModelWithApproximatedIK"}[settings.robot_model_id]
        rospy.loginfo(
            "asr_robot_model_services: %s, pan [%.1f, %.1f] deg, tilt [%.1f, %.1f] deg, rating %s, map %s; "
            "RobotModel Service started.",
            model_name,
            *np.degrees(settings.pan_limits_rad),
            *np.degrees(settings.tilt_limits_rad),
            settings.ik_angle_rating,
            self.model.map.source if self.model.map is not None else "from /map (waiting)",
        )

    # --------------------------------------------------------------------------------------------------- the map
    def _use_map(self, occupancy) -> None:
        occupancy.planner(self.settings.col_thresh)  # built now: not lazily inside concurrent service threads
        # one assignment: a service thread sees the old model or the new one, never a half-built one
        self.model = MildRobotModel(self.kinematics, self.settings, occupancy)
        self.costmap_publisher.publish(
            mild_ros.occupancy_grid_msg(occupancy, self.frames.map_frame, rospy.Time.now(), inflated=True)
        )
        self.map_ready.set()

    def on_map(self, msg) -> None:
        s = self.settings
        try:
            occupancy = mild_ros.occupancy_from_msg(
                msg, s.inscribed_radius_m, s.inflation_radius_m, s.cost_scaling_per_m, "/map"
            )
        except AgiprobotError as exc:
            rospy.logerr("asr_robot_model_services: map on /map refused: %s", exc)
            return
        if s.debug("MAP"):
            rospy.logdebug(
                "asr_robot_model_services: map received: %d x %d cells of %.3f m",
                msg.info.width,
                msg.info.height,
                msg.info.resolution,
            )
        self._use_map(occupancy)

    def _mapped_model(self) -> MildRobotModel:
        """The model with a map; waits for the first map up to ~mapTimeout_s."""
        if not self.map_ready.wait(self.map_timeout_s):
            raise InputError(
                f"no map received on /map within {self.map_timeout_s:.1f} s (start a map_server, or set "
                "~publishMap true to publish ~mapFile)"
            )
        return self.model

    def _log_request(self, what: str, request) -> None:
        if self.settings.debug("ROBOT_MODEL"):
            rospy.logdebug("asr_robot_model_services: %s %s", what, str(request).replace("\n", " "))

    # --------------------------------------------------------------------------------------------------- services
    @answers_errors
    def get_distance(self, request):
        self._log_request("GetDistance", request)
        model = self._mapped_model() if self.settings.use_global_planner else self.model
        return GetDistanceResponse(
            model.get_distance(xyz_array(request.sourcePosition), xyz_array(request.targetPosition))
        )

    @answers_errors
    def calculate_camera_pose(self, request):
        state = mild_ros.state_from_msg(request.sourceRobotState)
        return CalculateCameraPoseResponse(matrix_to_pose(self.model.calculate_camera_pose(state)))

    @answers_errors
    def is_position_allowed(self, request):
        self._log_request("IsPositionAllowed", request)
        model = self._mapped_model()
        return IsPositionAllowedResponse(model.is_position_allowed(xyz_array(request.targetPosition)))

    def _lookup_pose(self, child: str):
        transform = self.tf_buffer.lookup_transform(self.frames.map_frame, child, rospy.Time(0), self.tf_timeout)
        t, q = transform.transform.translation, transform.transform.rotation
        response = GetPoseResponse()
        response.pose.position.x, response.pose.position.y, response.pose.position.z = t.x, t.y, t.z
        response.pose.orientation = q
        return response

    @answers_errors
    def get_robot_pose(self, _request):
        return self._lookup_pose(self.frames.base_frame)

    @answers_errors
    def get_camera_pose(self, _request):
        return self._lookup_pose(self.frames.camera_mount_frame)

    @answers_errors
    def calculate_camera_pose_correction(self, request):
        self._log_request("CalculateCameraPoseCorrection", request)
        model = self.model
        state = mild_ros.state_from_msg(request.sourceRobotState)
        position = xyz_array(request.position)
        correction = model.camera_pose_correction(state, position, xyzw_array(request.orientation))
        if correction.reason:
            rospy.logdebug("asr_robot_model_services: pose correction: %s", correction.reason)
        if model.settings.visualize_ik:
            corrected = RobotState(correction.pan, correction.tilt, state.rotation, state.x, state.y)
            pose = model.camera_pose(corrected)
            solution = _Corrected(corrected, correction.view_centre_m, model.view_centre(pose))
            self._publish_ik(model, solution, position, markers.RED, "_poseCorrection")
        return CalculateCameraPoseCorrectionResponse(correction.pan, correction.tilt)

    @answers_errors
    def calculate_robot_state(self, request):
        self._log_request("CalculateRobotState", request)
        model = self._mapped_model()
        source = mild_ros.state_from_msg(request.sourceRobotState)
        position = xyz_array(request.position)
        visualize = model.settings.visualize_ik
        solution = model.calculate_robot_state(
            source, position, xyzw_array(request.orientation), record_samples=visualize
        )
        if visualize:
            self._publish_ik(model, solution, position, markers.BLUE, "")
        response = CalculateRobotStateResponse()
        response.success = solution.ok
        response.message = solution.reason
        if solution.ok:
            response.targetRobotState = mild_ros.state_to_msg(solution.state)
            response.cameraFrame = matrix_to_pose(solution.camera_pose)
            response.angleDeviation = solution.angle_deviation_rad
        else:
            response.angleDeviation = math.nan
        return response

    # --------------------------------------------------------------------------------------------------- markers
    def _publish_ik(self, model, solution, position, colour, suffix):
        stamp = rospy.Time.now()
        frame = self.frames.map_frame
        with self.visualization_lock:
            if not suffix:  # a new IK clears the previous picture (the original deleted marker by marker)
                self.ik_publisher.publish(markers.clear(Header(frame_id=frame, stamp=stamp)))
            for marker in markers.ik_markers(model, solution, position, frame, stamp, colour, suffix):
                self.ik_publisher.publish(marker)

    def publish_frustum(self, _event=None):
        try:
            transform = self.tf_buffer.lookup_transform(
                self.frames.map_frame, self.frames.camera_mount_frame, rospy.Time(0)
            )
        except tf2_ros.TransformException:
            return  # no robot on tf (yet): nothing to draw
        corners = self.model.frustum_corners(transform_to_matrix(transform))
        self.frustum_publisher.publish(markers.frustum_marker_array(corners, self.frames.map_frame, rospy.Time.now()))


def _flag_param(params: dict, key: str, default: bool) -> bool:
    value = params.get(key, default)
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    raise InputError(f"~{key} must be true or false, got {value!r}")


class _Corrected:
    """What ik_markers draws of a pose correction: the corrected state and its view centre."""

    def __init__(self, state, requested_centre, achieved_centre):
        self.state = state
        self.requested_view_centre_m = requested_centre
        self.achieved_view_centre_m = achieved_centre
        self.samples = None


def main():
    run_node("asr_robot_model_services", RobotModelServices)


# ------------------------------------------------------------------------------------------------------- IK test
#: The original's IK test poses (src/test_cases/IKTest.cpp): camera position (m, map frame) and orientation as
#: intrinsic Z-X-Z angles (deg), among them poses whose view axis has a zero x or y component and a few that cannot
#: be reached (too high, too low).
IK_TEST_POSES = (
    ((0.0, 0.0, 0.0), (0, 0, 0)),
    ((0.404993116856, -2.28920769691, 1.3), (0, 0, 0)),
    ((0.404993116856, -2.28920769691, 1.3), (90, 0, 0)),
    ((0.404993116856, -2.28920769691, 1.3), (180, 0, 0)),
    ((0.404993116856, -2.28920769691, 1.3), (270, 0, 0)),
    ((0.404993116856, -2.28920769691, 1.4), (-170, 0, 0)),
    ((0.404993116856, -2.28920769691, 1.4), (-170, 80, 0)),
    ((0.404993116856, -2.28920769691, 1.4), (-180, 100, 0)),
    ((0.404993116856, -2.28920769691, 1.4), (-200, 40, 0)),
    ((0.404993116856, -2.28920769691, 1.4), (-180, -30, 0)),
    ((0.404993116856, -2.28920769691, 1.4), (-190, -50, 0)),
    ((-0.404993116856, -0.28920769691, 1.4), (-120, -20, 0)),
    ((0.804993116856, 0.98920769691, 1.4), (120, -20, 0)),
    ((0.004993116856, 2.08920769691, 1.5), (20, -20, 0)),
    ((0.404993116856, 0.28920769691, 0.8), (-10, 0, 0)),
    ((0.404993116856, -2.28920769691, 1.7), (-170, 0, 0)),
    ((0.404993116856, -1.28920769691, 0.4), (-170, 80, 0)),
    ((0.404993116856, -1.28920769691, 0.5), (-180, 100, 0)),
    ((0.404993116856, -2.28920769691, 1.0), (-200, 40, 0)),
    ((0.404993116856, -2.28920769691, 1.8), (-180, -30, 0)),
    ((0.404993116856, -2.28920769691, 1.3), (-190, -50, 0)),
    ((0.404993116856, -2.28920769691, 1.1), (-120, -20, 0)),
    ((0.404993116856, -2.28920769691, 1.7), (120, -20, 0)),
    ((0.404993116856, -2.28920769691, 1.0), (20, -20, 0)),
    ((0.404993116856, -2.28920769691, 0.9), (-10, 0, 0)),
    ((0.404993116856, -2.28920769691, 2.5), (-20, -20, 0)),
    ((0.404993116856, -2.28920769691, 0.0), (-10, 30, 0)),
    ((0.404993116856, -2.28920769691, -1.0), (-10, 30, 0)),
)
#: The original test's start state: PTU at zero, base at (-0.1139, -1.6032) m turned by -1.57 rad
IK_TEST_START = RobotState(0.0, 0.0, -1.57, -0.113948535919, -1.60322499275)


class IKTest:
    """The node ``asr_robot_model_services_ik_test`` (test_IK.launch): the IK for the original's test poses from its
    start state, each result logged and drawn (IK markers on the IKVisualization topic), ~step_s apart (the
    original waited for Enter and 2 s). The start pose goes to /initialpose as the original's test published it.
    The settings come from the private parameters as for the services node; no map (the original test had none).
    The summary ends up in ~result: {solved, total, unsolved (1-based pose numbers)}."""

    def __init__(self):
        params = param("~", {})
        self.settings = settings_from_mapping(params, f"parameters of {rospy.get_name()}")
        frames = FrameNames.from_mapping(params, f"parameters of {rospy.get_name()} (frame names)", require_all=False)
        self.model = MildRobotModel(load_kinematics(file_param("~kinematics"), frames), self.settings, None)
        self.frame = frames.map_frame
        self.step_s = float(params.get("step_s", 2.0))
        self.ik_publisher = rospy.Publisher(self.settings.ik_visualization_topic, Marker, queue_size=200)
        self.initial_pose_publisher = rospy.Publisher(
            "/initialpose", PoseWithCovarianceStamped, queue_size=1, latch=True
        )

    def run(self) -> tuple[int, int]:
        """(solved, total)."""
        from scipy.spatial.transform import Rotation

        start = PoseWithCovarianceStamped()
        start.header.frame_id, start.header.stamp = self.frame, rospy.Time.now()
        start.pose.pose.position.x, start.pose.pose.position.y = IK_TEST_START.x, IK_TEST_START.y
        start.pose.pose.orientation = mild_ros.base_quaternion(IK_TEST_START.rotation)
        self.initial_pose_publisher.publish(start)
        solved, unsolved = 0, []
        for index, (position, zxz_deg) in enumerate(IK_TEST_POSES, start=1):
            if rospy.is_shutdown():
                break
            orientation = Rotation.from_euler("ZXZ", zxz_deg, degrees=True).as_quat()
            try:
                solution = self.model.calculate_robot_state(
                    IK_TEST_START, np.array(position), orientation, record_samples=self.settings.visualize_ik
                )
            except InputError as exc:  # e.g. limits that do not admit the start state
                rospy.logerr("asr_robot_model_services_ik_test: test pose %d refused: %s", index, exc)
                unsolved.append(index)
                continue
            solved += bool(solution.ok)
            if not solution.ok:
                unsolved.append(index)
            rospy.loginfo(
                "asr_robot_model_services_ik_test: test pose %d of %d %s: %s",
                index,
                len(IK_TEST_POSES),
                position,
                f"state {np.round(solution.state.as_array(), 4).tolist()}, deviation "
                f"{math.degrees(solution.angle_deviation_rad):.2f} deg"
                if solution.ok
                else solution.reason,
            )
            if self.settings.visualize_ik:
                stamp = rospy.Time.now()
                self.ik_publisher.publish(markers.clear(Header(frame_id=self.frame, stamp=stamp)))
                for marker in markers.ik_markers(self.model, solution, position, self.frame, stamp, markers.BLUE):
                    self.ik_publisher.publish(marker)
            rospy.sleep(self.step_s)
        rospy.loginfo(
            "asr_robot_model_services_ik_test: all tests done, %d of %d poses solved", solved, len(IK_TEST_POSES)
        )
        # the summary outlives the node (it exits, as the original's test did)
        rospy.set_param("~result", {"solved": solved, "total": len(IK_TEST_POSES), "unsolved": unsolved})
        return solved, len(IK_TEST_POSES)


def ik_test_main():
    run_node("asr_robot_model_services", lambda: IKTest().run(), label="asr_robot_model_services_ik_test", spin=False)
