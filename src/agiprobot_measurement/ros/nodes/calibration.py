"""Flange-based robot-camera calibration node (eye-to-hand): the ROS layer over ``calibration.procedure``.

The robot (bare flange disc, station ``tool:=flange_disc``) is moved to the flag points and the zig-zag path, a
frame is taken at each pose through the PhoXi driver (``<camera_ns>/get_frame`` with ``in_: -1``, then the next
``<camera_ns>/pointcloud``), the flange centre is detected in it and paired with the flange position (tool0 in
``base`` = the DH base, from the joint state by forward kinematics). The result H (base <- camera, metres) is written as
YAML and published on tf as a static transform ``base_frame -> camera_frame``. The procedure itself is ROS-free
(:func:`~agiprobot_measurement.calibration.procedure.run_collection`, ``run_test_mode``); this node implements its
robot (:class:`RosJointDriver` under a PlannedFlangeRobot) and camera (:class:`RosCamera`) and maps the messages.

Services (std_srvs; every handler answers, errors are ``success: false`` with the reason, the node keeps running):
  ~run (Trigger)              automatic collection as ``~mode`` says: flag points, coarse, (zig-zag, fine), result;
                              mode test: chessboard corners in the texture -> 3D (organised cloud) -> base frame
                              (the result YAML) -> flange moved to each corner; per corner: target, reached pose and,
                              when the scene file holds the chessboard (the simulated station), the positioning
                              error against its true corner (mm), in test_result.yaml next to the result
  ~add_flag_point (Trigger)   the robot's current flange position becomes a flag point (frame taken now)
  ~take_sample (Trigger)      a sample at the current robot pose (judged with the flag points' criteria)
  ~remove_sample (Trigger)    remove the last sample
  ~list_samples (Trigger)     the samples and the rejected frames with their reasons
  ~compute_coarse, ~compute_fine (Trigger)   calibrate the samples, write the result YAML, publish tf
  ~save_samples, ~load_samples (Trigger)     the data file (~data_file)
  ~clear (Trigger)            forget all samples and flag points
  ~judge (SetBool)            use_auto_judge false: the operator's answer to the pending detection of a run
                              (true = accept, false = reject); the question is on ~status and in the log,
                              the detected flange centre on ~flange_detection (PointStamped, camera frame)
Parameters: ~config (config/calibration.yaml; its keys can be overridden as private parameters: ~mode
(cal_fine | cal_coarse | test), ~use_mp, ~use_auto_judge, ~flag_points_file, ~zigzag, ~output_dir,
~result_file, ~data_file, ~base_frame, ~camera_frame; ~mode, ~flag_points_file and ~zigzag are read again at
every run and checked before the robot moves; a flag point file named at run time must lie in the output folder
or the folder of the flag point file the node started with, and its lines are never quoted), ~camera_ns (/phoxi_camera), ~executor
(follow_joint_trajectory | moveit), ~controller_action ("" = the executor's action), ~velocity_scaling (0.3), ~check_collisions (true: every motion is checked along
its whole path and planned around obstacles with OMPL when the straight joint move is blocked), ~scene (the
station's scene file, config/scene.yaml; its obstacles for the collision checks, its chessboard for test mode),
~frame_timeout_s (60), ~judge_timeout_s (600: how long a run waits for the operator).
Topic ~status (std_msgs/String, latched): the last outcome.
"""

from __future__ import annotations

import os
import threading
import traceback
from pathlib import Path

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PointStamped
from phoxi_camera.srv import GetFrame
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import SetBool, SetBoolResponse, Trigger, TriggerResponse

from agiprobot_measurement.calibration.config import check_mode, flange_station, load_calibration_config
from agiprobot_measurement.calibration.flange_detection import FlangeDetection, detect_flange, detect_flange_candidates
from agiprobot_measurement.calibration.flange_motion import PlannedFlangeRobot, flange_collision_checker
from agiprobot_measurement.calibration.interfaces import CameraFrame, StepError
from agiprobot_measurement.calibration.procedure import (
    auto_judge,
    detection_question,
    run_collection,
    run_test_mode,
)
from agiprobot_measurement.calibration.registration import CalibrationError, write_result_yaml
from agiprobot_measurement.calibration.session import CalibrationSession, check_zigzag, detector_config
from agiprobot_measurement.common.config import number
from agiprobot_measurement.common.files import FileRoot
from agiprobot_measurement.errors import AgiprobotError, InputError
from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.plan.execution import ExecutionCancelled, ExecutionError
from agiprobot_measurement.ros.conversions import cloud_xyz, transform_stamped
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import flag, has_param, param, text
from agiprobot_measurement.ros.phoxi_messages import image_array, pointcloud2_arrays
from agiprobot_measurement.ros.robot_client import (
    DEFAULT_MOTION,
    MotionSettings,
    make_motion_client,
    read_motion_settings,
)
from agiprobot_measurement.station import JointLimits, load_joint_limits

__all__ = ["CalibrationNode", "RosCamera", "RosJointDriver", "main"]

#: config keys a private parameter of the same name overrides
OVERRIDES = (
    "mode",
    "use_mp",
    "use_auto_judge",
    "flag_points_file",
    "output_dir",
    "result_file",
    "data_file",
    "base_frame",
    "camera_frame",
)


class RosJointDriver:
    """The robot: ``/joint_states`` and the motion client ``settings`` name (FollowJointTrajectory or MoveIt's
    ExecuteTrajectory; each motion's start and ``limits`` are checked before it is sent)."""

    def __init__(self, limits: JointLimits, settings: MotionSettings = DEFAULT_MOTION, state_timeout_s: float = 5.0):
        self.joints = JointStateCache(list(limits.names))
        self.state_timeout_s = state_timeout_s
        self.client = make_motion_client(settings, limits, self.joints.latest)

    def current_joints(self) -> np.ndarray:
        joints = self.joints.wait(self.state_timeout_s)
        if joints is None:
            raise StepError("no /joint_states: is the robot running?")
        return joints

    def execute(self, trajectory: JointTrajectory, settle_s: float) -> None:
        if not self.client.wait_for_server(10.0):
            raise StepError(f"robot controller action {self.client.action} not available")
        try:
            self.client.execute(trajectory)
        except (ExecutionError, ExecutionCancelled) as exc:
            raise StepError(f"robot motion failed: {exc}") from exc
        if settle_s > 0.0:
            rospy.sleep(settle_s)


class RosCamera:
    """The PhoXi driver: ``get_frame`` (in_ -1), then the next ``pointcloud`` (and ``texture``) message."""

    def __init__(self, camera_ns: str, frame_timeout_s: float = 60.0):
        self.camera_ns = camera_ns.rstrip("/")
        self.frame_timeout_s = frame_timeout_s
        self.cloud_msg = None
        self.cloud_event = threading.Event()
        self.texture_msg = None
        self.texture_event = threading.Event()
        rospy.Subscriber(f"{self.camera_ns}/pointcloud", PointCloud2, self._on_cloud, queue_size=1, buff_size=2**28)
        self.texture_sub = None  # subscribed on the first texture frame: the camera builds textures for subscribers
        self.get_frame = rospy.ServiceProxy(f"{self.camera_ns}/get_frame", GetFrame)

    def _on_cloud(self, msg):
        self.cloud_msg = msg
        self.cloud_event.set()

    def _on_texture(self, msg):
        self.texture_msg = msg
        self.texture_event.set()

    def _subscribe_texture(self) -> None:
        if self.texture_sub is not None:
            return
        self.texture_sub = rospy.Subscriber(
            f"{self.camera_ns}/texture", Image, self._on_texture, queue_size=1, buff_size=2**26
        )
        deadline = rospy.Time.now() + rospy.Duration(5.0)
        while self.texture_sub.get_num_connections() == 0 and rospy.Time.now() < deadline:
            rospy.sleep(0.05)

    def capture(self, texture: bool = False) -> CameraFrame:
        if texture:
            self._subscribe_texture()
        self.cloud_event.clear()
        self.texture_event.clear()
        try:
            self.get_frame.wait_for_service(10.0)
            response = self.get_frame(in_=-1)
        except (rospy.ServiceException, rospy.ROSException) as exc:
            raise StepError(f"camera: {exc}") from exc
        if not response.success:
            hint = ""
            if "No scanner connected" in response.message:  # the driver starts disconnected when scanner_id is ""
                hint = f" (give the driver a scanner_id, or call {self.camera_ns}/connect_camera)"
            raise StepError(f"camera: {response.message}{hint}")
        if not self.cloud_event.wait(self.frame_timeout_s):
            raise StepError("camera: no point cloud after get_frame")
        if not texture:
            return CameraFrame(cloud_xyz(self.cloud_msg))
        if not self.texture_event.wait(self.frame_timeout_s):
            raise StepError("camera: no texture image after get_frame")
        if self.texture_msg.encoding != "32FC1":
            raise StepError(f"camera: texture encoding {self.texture_msg.encoding}, expected 32FC1")
        organized = pointcloud2_arrays(self.cloud_msg)[0]
        return CameraFrame(cloud_xyz(self.cloud_msg), organized_m=organized, texture=image_array(self.texture_msg))


class _RosLog:
    """The procedures' progress on rosout."""

    def info(self, message: str) -> None:
        rospy.loginfo("calibration: %s", message)

    def warn(self, message: str) -> None:
        rospy.logwarn("calibration: %s", message)


class CalibrationNode:
    def __init__(self):
        config_path = param("~config", "") or None
        self.config = load_calibration_config(config_path)
        for key in OVERRIDES:
            if has_param(f"~{key}"):
                self.config[key] = param(f"~{key}")
        self.mode = check_mode(self.config.get("mode", "cal_fine"))
        self.use_auto_judge = bool(self.config.get("use_auto_judge", True))
        self.base_frame = str(self.config.get("base_frame", "base"))
        self.camera_frame = str(self.config.get("camera_frame", "PhoXi3Dscanner_sensor"))
        output_dir = str(self.config.get("output_dir", "") or "")
        self.output_dir = Path(output_dir or Path(os.environ.get("ROS_HOME", "~/.ros")) / "calibration").expanduser()
        self.result_file = self._in_output(self.config.get("result_file", "calibration_result.yaml"))
        # the flag point files a client may name at run time: in the output folder or beside the start-up one
        self.flag_files = FileRoot(
            self.output_dir, (Path(str(self.config["flag_points_file"])).expanduser().parent,), "~flag_points_file"
        )
        self.detector = detector_config(self.config)
        self.session = CalibrationSession.from_config(
            self.config, self._in_output(self.config.get("data_file", "calibration_data.txt"))
        )
        self.flag_points: list[np.ndarray] = []
        self.flag_candidates: list = []
        self.lock = threading.Lock()
        self.log = _RosLog()

        # the station with the bare flange disc on tool0 (station.launch tool:=flange_disc), for IK and collisions
        self.station = flange_station(param("~scene", "") or None)
        kinematics = KinematicModel.from_station(self.station, tip_frame="tool0", base_frame=self.base_frame)
        limits = load_joint_limits()
        collision = flange_collision_checker(self.station) if param("~check_collisions", True) else None
        self.robot = PlannedFlangeRobot(
            RosJointDriver(limits, read_motion_settings("~")),
            kinematics,
            make_ik_solver(kinematics, self.station.robot),
            limits,
            self.config["tool_z_towards_m"],
            collision=collision,
            velocity_scaling=param("~velocity_scaling", 0.3, number),
        )
        self.camera = RosCamera(param("~camera_ns", "/phoxi_camera"), param("~frame_timeout_s", 60.0, number))
        self.tf_broadcaster = tf2_ros.StaticTransformBroadcaster()
        self.status_pub = rospy.Publisher("~status", String, queue_size=1, latch=True)
        self.detection_pub = rospy.Publisher("~flange_detection", PointStamped, queue_size=1, latch=True)
        self.judge_timeout = param("~judge_timeout_s", 600.0, number)
        self.pending_question = ""
        self.judgement = None
        self.judgement_event = threading.Event()

        services = {
            "run": self.run,
            "add_flag_point": self.add_flag_point,
            "take_sample": self.take_sample,
            "remove_sample": self.remove_sample,
            "compute_coarse": lambda _r: self.compute("cal_coarse"),
            "compute_fine": lambda _r: self.compute("cal_fine"),
            "save_samples": self.save_samples,
            "load_samples": self.load_samples,
            "clear": self.clear,
        }
        self.services = [rospy.Service(f"~{name}", Trigger, self._guarded(h)) for name, h in services.items()]
        # answers during a run too (no lock): what has been collected so far
        self.services.append(
            rospy.Service("~list_samples", Trigger, lambda _r: TriggerResponse(True, self.session.listing()))
        )
        self.services.append(rospy.Service("~judge", SetBool, self.judge))  # answers while a run waits for it
        rospy.loginfo(
            "calibration: mode %s, flag points %s, data %s, result %s",
            self.mode,
            self.config["flag_points_file"],
            self.session.data_file,
            self.result_file,
        )

    def _in_output(self, name) -> Path:
        path = Path(str(name)).expanduser()
        return path if path.is_absolute() else self.output_dir / path

    def _guarded(self, handler):
        def call(request):
            if not self.lock.acquire(blocking=False):
                return TriggerResponse(success=False, message="busy: another calibration request is running")
            try:
                response = handler(request)
            except AgiprobotError as exc:
                if not isinstance(exc, InputError):
                    rospy.logerr("calibration: %s", exc)
                response = TriggerResponse(success=False, message=str(exc))
            except OSError as exc:  # the output folder or a data file: permissions, a full disk
                response = TriggerResponse(success=False, message=str(exc))
            except Exception as exc:  # a bug must not take the node down; the log has the trace
                rospy.logerr("calibration: %s", traceback.format_exc())
                response = TriggerResponse(success=False, message=f"internal error: {type(exc).__name__}: {exc}")
            finally:
                self.lock.release()
            (rospy.loginfo if response.success else rospy.logwarn)("calibration: %s", response.message)
            self.status_pub.publish(String(data=response.message))
            return response

        return call

    # ---------------------------------------------------------------------------------------- services
    def add_flag_point(self, _request):
        p = self.robot.flange_position(self.robot.current_joints())
        found, reason = detect_flange_candidates(self.camera.capture().points_m, self.detector, max_results=3)
        if not found:
            return TriggerResponse(success=False, message=f"flag point {np.round(p, 4).tolist()} refused: {reason}")
        self.flag_points.append(p)
        self.flag_candidates.append(found)
        message = f"flag point {len(self.flag_points)} at {np.round(p, 4).tolist()}"
        if len(self.flag_points) >= 4:
            self.session.add_flags(np.array(self.flag_points), self.flag_candidates)
            message += f"; {len(self.flag_points)} flag samples stored"
        return TriggerResponse(success=True, message=message)

    def take_sample(self, _request):
        p = self.robot.flange_position(self.robot.current_joints())
        expected = self.session.expected_camera_point(p) if self.session.data.h_coarse is not None else None
        detection = detect_flange(self.camera.capture().points_m, self.detector, expected)
        ok, text = self.session.add_sample(p, detection, f"sample at {np.round(p, 4).tolist()}")
        return TriggerResponse(success=ok, message=f"sample {text}" if ok else f"sample rejected: {text}")

    def remove_sample(self, _request):
        removed = self.session.remove("last")
        return TriggerResponse(success=True, message=f"removed sample {removed.index}")

    def save_samples(self, _request):
        path = self.session.save()
        return TriggerResponse(success=True, message=f"{len(self.session.data.samples)} samples in {path}")

    def load_samples(self, _request):
        count = self.session.load()
        return TriggerResponse(success=True, message=f"{count} samples from {self.session.data_file}")

    def clear(self, _request):
        self.session.clear()
        self.flag_points, self.flag_candidates = [], []
        return TriggerResponse(success=True, message="samples cleared")

    def compute(self, mode):
        result = self.session.compute(mode)
        self.publish_result(result, mode)
        return TriggerResponse(
            success=True,
            message=f"{mode}: {int(result.inliers.sum())}/{len(result.inliers)} samples, RMS {result.rms_mm:.3f} mm, "
            f"max {result.max_mm:.3f} mm, result {self.result_file}",
        )

    def publish_result(self, result, mode):
        write_result_yaml(self.result_file, result, self.base_frame, self.camera_frame, mode)
        self.tf_broadcaster.sendTransform(
            transform_stamped(result.transform, self.base_frame, self.camera_frame, rospy.Time.now())
        )

    def judge(self, request):
        """The operator's answer to the detection a run is waiting on."""
        if not self.pending_question:
            return SetBoolResponse(success=False, message="no detection is waiting for a judgement")
        self.judgement = bool(request.data)
        self.judgement_event.set()
        return SetBoolResponse(
            success=True, message=("accepted: " if request.data else "rejected: ") + self.pending_question
        )

    def operator_accepts(self, what: str, detection: FlangeDetection, expected_camera_m=None) -> bool:
        """use_auto_judge false (the procedure's judge): show the detection and wait for ~judge (true / false)."""
        point = PointStamped()
        point.header.stamp = rospy.Time.now()
        point.header.frame_id = self.camera_frame
        point.point.x, point.point.y, point.point.z = (float(v) for v in detection.centre_m)
        self.detection_pub.publish(point)
        detail = detection_question(what, detection, expected_camera_m)
        self.judgement, self.pending_question = None, detail
        self.judgement_event.clear()
        question = f"waiting for the operator: {detail}; accept with ~judge true, reject with ~judge false"
        rospy.loginfo("calibration: %s", question)
        self.status_pub.publish(String(data=question))
        try:
            deadline = rospy.get_time() + self.judge_timeout
            while not self.judgement_event.wait(0.1):
                if rospy.is_shutdown() or rospy.get_time() > deadline:
                    raise CalibrationError(f"no judgement from the operator within {self.judge_timeout:.0f} s ({what})")
            return bool(self.judgement)
        finally:
            self.pending_question = ""

    def run(self, _request):
        """The automatic collection (flag points, coarse, zig-zag path, fine) or, in mode test, the test mode."""
        self.mode = check_mode(param("~mode", self.mode))
        self.config["mode"] = self.mode
        if self.mode == "test":
            outcome = run_test_mode(
                self.robot,
                self.camera,
                self.result_file,
                self.config,
                self.station.named_states,
                scene=self.station.scene,
                log=self.log,
            )
            return TriggerResponse(success=outcome.success, message=outcome.message)
        self.use_auto_judge = param("~use_auto_judge", self.use_auto_judge, flag)
        flag_file = param("~flag_points_file", self.config["flag_points_file"], text)
        self.config["flag_points_file"] = str(self.flag_files.for_reading(flag_file))
        zigzag = param("~zigzag", self.config.get("zigzag", {}))
        if self.mode == "cal_fine":
            check_zigzag(zigzag, "~zigzag")
        self.config["zigzag"] = zigzag
        self.flag_points, self.flag_candidates = [], []
        outcome = run_collection(
            self.robot,
            self.camera,
            self.session,
            self.config,
            judge=auto_judge if self.use_auto_judge else self.operator_accepts,
            publish=self.publish_result,
            log=self.log,
        )
        return TriggerResponse(success=True, message=outcome.message(self.result_file))


def main():
    run_node("calibration", CalibrationNode)
