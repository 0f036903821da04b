"""The node ``asr_robot_model_services`` (launched by nodes/asr_robot_model_services): the MILD's robot model
(:mod:`agiprobot_measurement.mild.robot_model`) as ROS services.

Services (in the node's namespace, /asr_robot_model_services/<Name>; types of this package):
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
the map on /map and the inflated map on ~costmap (nav_msgs/OccupancyGrid, latched) unless publishMap is false.

Parameters: the settings file's keys in the private namespace (config/mild_robot_model_services_{real,sim}.yaml),
the frame names (config/mild_robot_model_frames.yaml), ~kinematics (config/mild_kinematics.yaml), ~mapFile
(config/maps/mild_lab.yaml), ~publishMap (true).
"""

__all__ = ["RobotModelServices", "main"]


import functools
import math
import threading

import numpy as np
import rospy
import tf2_ros
from nav_msgs.msg import OccupancyGrid
from visualization_msgs.msg import Marker, MarkerArray

from agiprobot_measurement.errors import AgiprobotError, InputError
from agiprobot_measurement.mild.config import FrameNames, load_kinematics, load_map, settings_from_mapping
from agiprobot_measurement.mild.robot_model import MildRobotModel
from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros import mild_messages as mild_ros
from agiprobot_measurement.ros.conversions import matrix_to_pose, transform_to_matrix, xyz_array, xyzw_array
from agiprobot_measurement.ros.params import file_param
from agiprobot_measurement.srv import (
    CalculateCameraPose,
    CalculateCameraPoseCorrection,
    CalculateCameraPoseCorrectionResponse,
    CalculateCameraPoseResponse,
    CalculateRobotState,
    CalculateRobotStateResponse,
    GetDistance,
    GetDistanceResponse,
    GetPose,
    GetPoseResponse,
    IsPositionAllowed,
    IsPositionAllowedResponse,
)


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
        params = rospy.get_param("~")
        settings = settings_from_mapping(params, f"parameters of {name}")
        for warning in settings.warnings:
            rospy.logwarn("asr_robot_model_services: %s", warning)
        rospy.set_param("~IKAngleRatingInUse", settings.ik_angle_rating)
        frames = FrameNames.from_mapping(params, f"parameters of {name} (frame names)")
        kinematics = load_kinematics(file_param("~kinematics"), frames)
        occupancy = load_map(file_param("~mapFile"), settings)
        self.model = MildRobotModel(kinematics, settings, occupancy)
        occupancy.planner(settings.col_thresh)  # built now: not lazily inside concurrent service threads
        self.frames = frames
        self.tf_timeout = rospy.Duration(float(params.get("tfTimeout_s", 1.0)))
        self.tf_buffer = tf2_ros.Buffer()
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.ik_publisher = rospy.Publisher(settings.ik_visualization_topic, Marker, queue_size=200)
        self.frustum_publisher = rospy.Publisher("/nbv/frustum_marker_array", MarkerArray, queue_size=1)
        self.visualization_lock = threading.Lock()
        if bool(params.get("publishMap", True)):
            stamp = rospy.Time.now()
            map_publisher = rospy.Publisher("/map", OccupancyGrid, queue_size=1, latch=True)
            costmap_publisher = rospy.Publisher("~costmap", OccupancyGrid, queue_size=1, latch=True)
            map_publisher.publish(mild_ros.occupancy_grid_msg(occupancy, frames.map_frame, stamp))
            costmap_publisher.publish(mild_ros.occupancy_grid_msg(occupancy, frames.map_frame, stamp, inflated=True))
            self._latched = (map_publisher, costmap_publisher)
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
            occupancy.source,
        )

    # --------------------------------------------------------------------------------------------------- services
    @answers_errors
    def get_distance(self, request):
        return GetDistanceResponse(
            self.model.get_distance(xyz_array(request.sourcePosition), xyz_array(request.targetPosition))
        )

    @answers_errors
    def calculate_camera_pose(self, request):
        state = mild_ros.state_from_msg(request.sourceRobotState)
        return CalculateCameraPoseResponse(matrix_to_pose(self.model.calculate_camera_pose(state)))

    @answers_errors
    def is_position_allowed(self, request):
        return IsPositionAllowedResponse(self.model.is_position_allowed(xyz_array(request.targetPosition)))

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
        state = mild_ros.state_from_msg(request.sourceRobotState)
        position = xyz_array(request.position)
        correction = self.model.camera_pose_correction(state, position, xyzw_array(request.orientation))
        if correction.reason:
            rospy.logdebug("asr_robot_model_services: pose correction: %s", correction.reason)
        if self.model.settings.visualize_ik:
            corrected = RobotState(correction.pan, correction.tilt, state.rotation, state.x, state.y)
            pose = self.model.camera_pose(corrected)
            solution = _Corrected(corrected, correction.view_centre_m, self.model.view_centre(pose))
            self._publish_ik(solution, position, mild_ros.RED, "_poseCorrection")
        return CalculateCameraPoseCorrectionResponse(correction.pan, correction.tilt)

    @answers_errors
    def calculate_robot_state(self, request):
        source = mild_ros.state_from_msg(request.sourceRobotState)
        position = xyz_array(request.position)
        visualize = self.model.settings.visualize_ik
        solution = self.model.calculate_robot_state(
            source, position, xyzw_array(request.orientation), record_samples=visualize
        )
        if visualize:
            self._publish_ik(solution, position, mild_ros.BLUE, "")
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
    def _publish_ik(self, solution, position, colour, suffix):
        stamp = rospy.Time.now()
        frame = self.frames.map_frame
        with self.visualization_lock:
            if not suffix:  # a new IK clears the previous picture (the original deleted marker by marker)
                self.ik_publisher.publish(mild_ros.delete_all(frame, stamp))
            for marker in mild_ros.ik_markers(self.model, solution, position, frame, stamp, colour, suffix):
                self.ik_publisher.publish(marker)

    def publish_frustum(self, _event=None):
        try:
            transform = self.tf_buffer.lookup_transform(
                self.frames.map_frame, self.frames.camera_mount_frame, rospy.Time(0)
            )
        except tf2_ros.TransformException:
            return  # no robot on tf (yet): nothing to draw
        corners = self.model.frustum_corners(transform_to_matrix(transform))
        self.frustum_publisher.publish(mild_ros.frustum_marker_array(corners, self.frames.map_frame, rospy.Time.now()))


class _Corrected:
    """What ik_markers draws of a pose correction: the corrected state and its view centre."""

    def __init__(self, state, requested_centre, achieved_centre):
        self.state = state
        self.requested_view_centre_m = requested_centre
        self.achieved_view_centre_m = achieved_centre
        self.samples = None


def main():
    rospy.init_node("asr_robot_model_services")
    try:
        RobotModelServices()
    except AgiprobotError as exc:
        rospy.logfatal("asr_robot_model_services: %s", exc)
        raise SystemExit(1) from exc
    rospy.spin()
