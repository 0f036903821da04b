"""The 3D next-best-view loop's robot and camera (``nbv.interfaces``) over ROS.

:class:`RosNBVRobot` is the station's controller: ``/joint_states`` and its trajectory action through the motion
client (:mod:`.robot_client`: FollowJointTrajectory of a UR driver or the simulator, or MoveIt's ExecuteTrajectory),
as the other nodes drive it. :class:`RosNBVCamera` is the PhoXi driver
(the simulated phoxi_camera node or the real one): ``trigger_image`` answers the new frame's id, ``get_frame(id)``
publishes it, and the frame's ``pointcloud`` (organised, camera space), ``confidence_map`` and ``camera_info``
messages are matched by their header's seq (the frame id, as the driver numbers them). The sensor's pose is the
tf transform world <- the cloud's frame at the cloud's stamp: with the scanner on the arm the phoxi_camera node
stamps a frame with the tf time it was rendered at, so this is exactly the pose the frame was taken from.

:func:`~agiprobot_measurement.ros.nbv_messages.captured_view` turns those messages into the loop's :class:`~agiprobot_measurement.nbv.volumetric.interfaces.CapturedView`
(world frame, valid pixels only, unit normals, sigma = the confidence map in mm, the organised depth for the TSDF).
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import rospy
import tf2_ros
from phoxi_camera.srv import GetFrame, TriggerImage
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.nbv.volumetric.interfaces import CapturedView, CaptureError, MotionError
from agiprobot_measurement.planning.plan.execution import (
    ControllerLost,
    ExecutionCancelled,
    ExecutionError,
    state_jump,
)
from agiprobot_measurement.ros.conversions import transform_to_matrix
from agiprobot_measurement.ros.executor import ControllerWatch
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.nbv_messages import captured_view
from agiprobot_measurement.ros.params import param, text
from agiprobot_measurement.ros.robot_client import DEFAULT_MOTION, MotionSettings, make_motion_client
from agiprobot_measurement.station.config import JointLimits

__all__ = ["MotionCancelled", "RosNBVCamera", "RosNBVRobot"]

#: the longest wait (s) for the arm to stand after a motion before the next frame
STAND_TIMEOUT_S = 2.0
#: the PhoXi coordinate space whose clouds are in the sensor frame (the driver's coordinate_space 1)
CAMERA_SPACE = 1


class MotionCancelled(MotionError):
    """The motion was stopped because the caller cancelled (the robot stands where it stopped)."""


class RosNBVRobot:
    """The robot over ``/joint_states`` and the motion client ``settings`` name (the station's ``limits`` fix the
    joint order and are checked before each motion is sent, with its start against ``/joint_states``).

    ``execute`` blocks until the controller reports the trajectory done, then waits ``settle_s`` (ROS time) for a
    joint state stamped after that, so that tf (robot_state_publisher) shows the final pose before the next frame.
    ``cancel_requested()`` is polled while the robot moves: when it answers true the goal is cancelled (the robot
    stops where it is) and :class:`MotionCancelled` raised. A controller whose ``/joint_states`` stop for
    ``heartbeat_timeout_s`` is lost: the goal is cancelled and MotionError raised.
    """

    def __init__(
        self,
        limits: JointLimits,
        settings: MotionSettings = DEFAULT_MOTION,
        state_timeout_s: float = 5.0,
        settle_s: float = 0.1,
        cancel_requested=None,
        heartbeat_timeout_s: float = 1.0,
        poll_s: float = 0.05,
    ):
        self.joint_names = list(limits.names)
        self.joints = JointStateCache(self.joint_names)
        self.state_timeout_s = float(state_timeout_s)
        self.settle_s = float(settle_s)
        self.cancel_requested = cancel_requested or (lambda: False)
        self.poll_s = float(poll_s)
        self.client = make_motion_client(settings, limits, self.joints.latest)
        self.controller_action = self.client.action
        self.watch = ControllerWatch(self.joints, self.client, heartbeat_timeout_s)
        self.last_end: np.ndarray | None = None  # where the last motion ended (rad)

    def current_joints(self) -> np.ndarray:
        joints = self.joints.wait(self.state_timeout_s)
        if joints is None:
            raise MotionError(
                f"no {self.joints.topic} for {self.state_timeout_s:.0f} s: is the robot (robot_sim) running?"
            )
        return joints

    def execute(self, trajectory: JointTrajectory) -> None:
        if not self.client.wait_for_server(10.0):
            raise MotionError(f"the robot controller's action {self.controller_action} is not available")
        expected, self.last_end = self.last_end, None  # known again only once this motion succeeded
        try:
            self.client.execute(trajectory, self.cancel_requested, self.watch.problem)
        except ExecutionCancelled as exc:
            raise MotionCancelled("cancelled; robot stopped") from exc
        except ControllerLost as exc:
            raise MotionError(f"robot controller lost: {exc}") from exc
        except ExecutionError as exc:
            # a controller restarted between moves stands elsewhere: the client refuses the next start
            jump = state_jump(self.joints.latest(), expected, "the last motion")
            if jump:
                raise MotionError(f"robot controller lost: {jump}; the motion failed: {exc}") from exc
            raise MotionError(f"robot motion failed: {exc}") from exc
        self.last_end = np.asarray(trajectory.end, dtype=float)
        # the controller reports success within its goal tolerance; the arm still converges (a UR's servo lag):
        # the next frame is taken from where it stands
        self.client.wait_until_still(STAND_TIMEOUT_S)
        self._settle()

    def _settle(self) -> None:
        done = rospy.Time.now()
        deadline = done + rospy.Duration(self.settle_s + 2.0)
        target = done + rospy.Duration(self.settle_s)
        while not rospy.is_shutdown():
            stamp = self.joints.latest_stamp()
            if stamp is not None and stamp >= target:
                return
            if rospy.Time.now() > deadline:
                raise MotionError(f"no {self.joints.topic} after the motion: is the robot (robot_sim) running?")
            rospy.sleep(0.01)


class RosNBVCamera:
    """The PhoXi driver under ``camera_ns``: ``capture()`` takes a new frame (trigger_image, then get_frame(id)),
    waits up to ``frame_timeout_s`` for its cloud, confidence map and camera info, and looks the sensor's pose up on
    tf (``world_frame`` <- the cloud's frame at its stamp, waiting up to ``tf_timeout_s``). Needs the driver's
    ``organized_cloud`` true and coordinate space 1 (camera), the driver's defaults.
    """

    TOPICS = (("pointcloud", PointCloud2), ("confidence_map", Image), ("camera_info", CameraInfo))
    #: frames kept while waiting (the driver numbers frames; older ones are dropped)
    KEEP = 4
    #: tf history (s) a new camera gathers before its first frame
    TF_HISTORY_S = 0.3

    def __init__(
        self,
        camera_ns: str = "/phoxi_camera",
        world_frame: str = "world",
        frame_timeout_s: float = 30.0,
        tf_timeout_s: float = 2.0,
        tf_buffer: tf2_ros.Buffer | None = None,
    ):
        self.camera_ns = camera_ns.rstrip("/")
        self.world_frame = world_frame
        self.frame_timeout_s = float(frame_timeout_s)
        self.tf_timeout = rospy.Duration(float(tf_timeout_s))
        if tf_buffer is None:
            tf_buffer = tf2_ros.Buffer()
            self._tf_listener = tf2_ros.TransformListener(tf_buffer)
        self.tf_buffer = tf_buffer
        self._tf_ready = False
        self.lock = threading.Condition()
        self.frames: OrderedDict[int, dict] = OrderedDict()
        self.subscribers = [
            rospy.Subscriber(
                f"{self.camera_ns}/{name}", kind, self._on_message, callback_args=name, queue_size=2, buff_size=2**28
            )
            for name, kind in self.TOPICS
        ]
        self.trigger = rospy.ServiceProxy(f"{self.camera_ns}/trigger_image", TriggerImage)
        self.get_frame = rospy.ServiceProxy(f"{self.camera_ns}/get_frame", GetFrame)

    def _on_message(self, msg, name: str) -> None:
        with self.lock:
            self.frames.setdefault(int(msg.header.seq), {})[name] = msg
            while len(self.frames) > self.KEEP:
                self.frames.popitem(last=False)
            self.lock.notify_all()

    def _check_driver(self) -> None:
        """The settings the conversion relies on (refused before a frame is taken)."""
        space = param(f"{self.camera_ns}/coordinate_space", CAMERA_SPACE)
        if int(space) != CAMERA_SPACE:
            raise CaptureError(
                f"{self.camera_ns}: coordinate_space is {space}; the map needs camera space (1): its points in the "
                "sensor frame, placed by tf"
            )
        if not param(f"{self.camera_ns}/organized_cloud", True):
            raise CaptureError(f"{self.camera_ns}: organized_cloud is false; the map needs the organised cloud")
        if not param(f"{self.camera_ns}/send_point_cloud", True) or not param(
            f"{self.camera_ns}/send_confidence_map", True
        ):
            raise CaptureError(f"{self.camera_ns}: send_point_cloud and send_confidence_map must be true")

    def _wait_subscribed(self, timeout_s: float = 5.0) -> None:
        # the driver builds a frame's messages only for connected subscribers
        deadline = rospy.Time.now() + rospy.Duration(timeout_s)
        while any(s.get_num_connections() == 0 for s in self.subscribers) and rospy.Time.now() < deadline:
            rospy.sleep(0.05)

    def _wait_for_tf(self) -> None:
        """Before the first frame: tf must know the sensor, and hold some history, because the frame's stamp is the
        driver's newest tf time, which may lie a little before this listener's first message."""
        if self._tf_ready:
            return
        frame = param(f"{self.camera_ns}/frame_id", "PhoXi3Dscanner_sensor", text)
        if not self.tf_buffer.can_transform(self.world_frame, frame, rospy.Time(0), rospy.Duration(10.0)):
            raise CaptureError(
                f"no pose of {frame} in {self.world_frame} on tf: is the robot (robot_state_publisher) up?"
            )
        rospy.sleep(self.TF_HISTORY_S)
        self._tf_ready = True

    def capture(self) -> CapturedView:
        self._check_driver()
        try:
            self.trigger.wait_for_service(10.0)
            self._wait_subscribed()
            self._wait_for_tf()
            triggered = self.trigger()
        except (rospy.ServiceException, rospy.ROSException) as exc:
            raise CaptureError(f"camera {self.camera_ns}: {exc}") from exc
        if not triggered.success:
            hint = ""
            if "No scanner connected" in triggered.message:
                hint = f" (give the driver a scanner_id, or call {self.camera_ns}/connect_camera)"
            raise CaptureError(f"camera {self.camera_ns}: {triggered.message}{hint}")
        try:
            published = self.get_frame(in_=int(triggered.id))
        except (rospy.ServiceException, rospy.ROSException) as exc:
            raise CaptureError(f"camera {self.camera_ns}: {exc}") from exc
        if not published.success:
            raise CaptureError(f"camera {self.camera_ns}: frame {triggered.id}: {published.message}")
        messages = self._wait_frame(int(triggered.id))
        cloud = messages["pointcloud"]
        try:
            transform = self.tf_buffer.lookup_transform(
                self.world_frame, cloud.header.frame_id, cloud.header.stamp, self.tf_timeout
            )
        except tf2_ros.TransformException as exc:
            raise CaptureError(
                f"no pose of {cloud.header.frame_id} in {self.world_frame} on tf at the frame's stamp "
                f"{cloud.header.stamp.to_sec():.3f}: {exc}"
            ) from exc
        return captured_view(cloud, messages["confidence_map"], messages["camera_info"], transform_to_matrix(transform))

    def _wait_frame(self, index: int) -> dict:
        names = [name for name, _ in self.TOPICS]
        deadline = rospy.Time.now() + rospy.Duration(self.frame_timeout_s)
        with self.lock:
            while not rospy.is_shutdown():
                found = self.frames.get(index, {})
                if all(name in found for name in names):
                    return dict(found)
                if rospy.Time.now() > deadline:
                    missing = [name for name in names if name not in found]
                    raise CaptureError(
                        f"camera {self.camera_ns}: frame {index}: no {', '.join(missing)} within "
                        f"{self.frame_timeout_s:.0f} s"
                    )
                self.lock.wait(0.05)
        raise CaptureError("shutting down")
