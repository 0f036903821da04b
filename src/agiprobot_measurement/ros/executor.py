"""Executing a plan in ROS: the robot controller's action and the simulated scanner behind the core's
executor interface (:class:`~agiprobot_measurement.planning.plan.execution.SegmentExecutor`).

:class:`ScannerClient` talks to the laser_scanner node (target, stitching, the measured cloud) and collects the
profiles it publishes; :class:`RosSegmentExecutor` runs one segment through the controller's
ExecuteJointTrajectory action, switches stitching on for measurement segments only and cancels the robot when
the caller asks. :class:`ControllerWatch` tells whether the controller is alive (its ``/joint_states``
heartbeat and its action server's status connection); a segment whose controller dies ends within
``heartbeat_timeout_s`` + a poll with :class:`~agiprobot_measurement.planning.plan.execution.ControllerLost`.
Points are mm in the core and m on the wire.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
import rospy
from actionlib_msgs.msg import GoalStatus
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Empty, Trigger

from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.msg import ExecuteJointTrajectoryGoal
from agiprobot_measurement.planning.plan.execution import ControllerLost, ExecutionCancelled, ExecutionError, PlanPart
from agiprobot_measurement.ros.conversions import cloud_xyz, joint_trajectory_to_msg
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.srv import SetScanTarget, SetStitching

__all__ = ["ControllerWatch", "RosSegmentExecutor", "ScannerClient", "ScannerError"]

#: a node starved of CPU must not drop profiles: the queue holds a minute of them
PROFILE_QUEUE = 6000


class ScannerError(ExecutionError):
    """The scanner refused a request (no target, an unreadable mesh)."""


class ControllerWatch:
    """Whether the robot controller is alive: a ``/joint_states`` message (``joint_states``) younger than
    ``heartbeat_timeout_s`` (ROS time) and a live connection to the status topic of its action server
    (``robot``: an actionlib SimpleActionClient), which drops as soon as the controller's process dies."""

    def __init__(self, joint_states: JointStateCache, robot, heartbeat_timeout_s: float = 1.0):
        self.joint_states = joint_states
        self.robot = robot
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)

    def problem(self) -> str:
        """'' while the controller is alive, else what is missing."""
        stamp = self.joint_states.latest_stamp()
        if stamp is None:
            return f"no {self.joint_states.topic} received yet"
        age_s = (rospy.Time.now() - stamp).to_sec()
        if age_s > self.heartbeat_timeout_s:
            return f"no {self.joint_states.topic} for {age_s:.1f} s"
        status = getattr(getattr(self.robot, "action_client", None), "status_sub", None)
        if status is not None and status.get_num_connections() == 0:
            return "its action server's status topic has no publisher (the controller's process is gone)"
        return ""


class ScannerClient:
    """The laser_scanner node's services and topics under ``namespace`` (e.g. /laser_scanner)."""

    def __init__(self, namespace: str, service_timeout_s: float = 5.0):
        self.namespace = namespace.rstrip("/")
        self.service_timeout_s = service_timeout_s
        self.lock = threading.Lock()
        self.collecting = False
        self.profiles_received = 0
        self.chunks_mm: list[np.ndarray] = []
        self.measured_cloud: PointCloud2 | None = None
        rospy.Subscriber(
            f"{self.namespace}/profile", PointCloud2, self._on_profile, queue_size=PROFILE_QUEUE, buff_size=2**24
        )
        rospy.Subscriber(
            f"{self.namespace}/measured_cloud", PointCloud2, self._on_measured_cloud, queue_size=1, buff_size=2**26
        )

    def _call(self, name: str, service_type, *args):
        rospy.wait_for_service(f"{self.namespace}/{name}", timeout=self.service_timeout_s)
        return rospy.ServiceProxy(f"{self.namespace}/{name}", service_type)(*args)

    def _on_profile(self, msg):
        if self.collecting:
            self.profiles_received += 1
            points = cloud_xyz(msg) * 1000.0
            if len(points):
                self.chunks_mm.append(points)

    def _on_measured_cloud(self, msg):
        if not self.collecting:
            self.measured_cloud = msg

    def set_target(self, part: PlanPart) -> None:
        """Scan ``part`` from now on and forget what was measured before."""
        reply = self._call(
            "set_target", SetScanTarget, part.mesh_file, part.units, part.file_units_placement.reshape(-1).tolist()
        )
        if not reply.success:
            raise ScannerError(f"scanner: {reply.message}")
        self._call("clear", Empty)

    def set_stitching(self, on: bool) -> int:
        """Switch stitching; returns the scanner's profile count since its last clear."""
        return int(self._call("set_stitching", SetStitching, on).profiles)

    def start_collecting(self) -> None:
        self.chunks_mm = []
        self.profiles_received = 0
        self.collecting = True

    def finish_collecting(self, profile_wait_s: float = 5.0, cloud_wait_s: float = 10.0) -> np.ndarray:
        """Stop stitching and return every point measured since :meth:`start_collecting` (mm): the scanner's
        whole measured cloud (one message, which a bag records as well), else the profiles received."""
        expected = None
        try:
            expected = self.set_stitching(False)
        except rospy.ROSException:
            pass
        # the last profiles are still in flight: wait for them (bounded)
        deadline = rospy.Time.now() + rospy.Duration(profile_wait_s)
        while expected is not None and self.profiles_received < expected and rospy.Time.now() < deadline:
            rospy.sleep(0.05)
        self.collecting = False
        self.measured_cloud = None
        try:
            self._call("publish_measured_cloud", Trigger)
            deadline = rospy.Time.now() + rospy.Duration(cloud_wait_s)
            while self.measured_cloud is None and rospy.Time.now() < deadline:
                rospy.sleep(0.05)
        except rospy.ROSException:
            pass
        if self.measured_cloud is not None:
            return cloud_xyz(self.measured_cloud) * 1000.0
        return np.vstack(self.chunks_mm) if self.chunks_mm else np.zeros((0, 3))


class RosSegmentExecutor:
    """Runs plan segments through the controller's action (``robot``: an ActionClient of
    ExecuteJointTrajectory). ``current_state()`` gives the robot's joint state (rad); ``cancel_requested()`` is
    polled while a segment runs; ``on_measure(view or None, active)`` hears of each measurement segment's start
    and end (the node shows the points it measures)."""

    def __init__(
        self,
        robot,
        scanner: ScannerClient,
        current_state: Callable[[], np.ndarray],
        cancel_requested: Callable[[], bool],
        on_measure: Callable[[object, bool], None] | None = None,
        poll_s: float = 0.05,
        controller_problem: Callable[[], str] | None = None,
    ):
        self.robot = robot
        self.scanner = scanner
        self._current_state = current_state
        self.cancel_requested = cancel_requested
        self.on_measure = on_measure
        self.poll_s = poll_s
        self.controller_problem = controller_problem or (lambda: "")

    def _stitching(self, on: bool) -> None:
        try:
            self.scanner.set_stitching(on)
        except (rospy.ROSException, rospy.ServiceException) as exc:
            raise ScannerError(f"scanner: cannot switch stitching {'on' if on else 'off'}: {exc}") from exc

    def current_state(self) -> np.ndarray:
        return self._current_state()

    def execute_segment(self, trajectory: JointTrajectory, kind: str, viewpoint=None) -> None:
        measuring = kind == "measure"
        problem = self.controller_problem()
        if problem:
            raise ControllerLost(problem)
        if measuring:
            self._stitching(True)
            if self.on_measure is not None:
                self.on_measure(viewpoint, True)
        lost = False
        try:
            self._run(trajectory)
        except ControllerLost:
            lost = True
            raise
        finally:
            if measuring:
                if lost:  # the abort must not wait for the scanner to settle without a robot: stop it meanwhile
                    threading.Thread(target=self._stop_stitching, daemon=True).start()
                else:
                    self._stop_stitching()
                if self.on_measure is not None:
                    self.on_measure(viewpoint, False)

    def _stop_stitching(self) -> None:
        try:
            self._stitching(False)
        except ScannerError as exc:  # the segment's own outcome matters more; the caller stops the scanner again
            rospy.logwarn("trajectory_manager: %s", exc)

    def _run(self, trajectory: JointTrajectory) -> None:
        self.robot.send_goal(ExecuteJointTrajectoryGoal(trajectory=joint_trajectory_to_msg(trajectory)))
        while not self.robot.wait_for_result(rospy.Duration(self.poll_s)):
            if self.cancel_requested() or rospy.is_shutdown():
                self.robot.cancel_goal()
                self.robot.wait_for_result(rospy.Duration(2.0))
                raise ExecutionCancelled("cancelled; robot stopped")
            problem = self.controller_problem()
            if problem:
                self.robot.cancel_goal()  # a controller that only stalled must not go on moving
                raise ControllerLost(problem)
        state, result = self.robot.get_state(), self.robot.get_result()
        if state != GoalStatus.SUCCEEDED or result is None or not result.success:
            raise ExecutionError(result.error if result is not None and result.error else f"controller state {state}")
