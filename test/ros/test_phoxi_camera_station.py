#!/usr/bin/env python3
"""rostest: the simulated PhoXi scanner in the station: its frame on tf, the part in the cloud at its place in the
world, and the robot's links from tf in the cloud (moving the robot changes the cloud where its links are)."""

import sys
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
import tf2_ros

sys.path.insert(0, str(Path(__file__).resolve().parent))
from phoxi_camera.srv import GetFrame, IsConnected, TriggerImage
from phoxi_test_utils import FrameRecorder, reconfigure, service
from station_test_utils import place_robot

from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.ros import phoxi_messages
from agiprobot_measurement.sensors.phoxi.device import load_camera_config, transform_from_quaternion
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_LOW, load_scanner_model
from agiprobot_measurement.sensors.phoxi.renderer import ScanSettings, StructuredLightScanner
from agiprobot_measurement.sensors.phoxi.scene_geometry import RobotGeometry, SceneGeometry, scene_geometry
from agiprobot_measurement.srv import SetJointState
from agiprobot_measurement.station import Station
from agiprobot_measurement.station.urdf_model import UrdfModel

MOVED = np.array([-0.5, 0.0, 0.0, 0.0, 0.0, 0.0])  # shoulder pan towards the camera side


class PhoxiStationTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_phoxi_camera_station")
        cls.trigger = service("trigger_image", TriggerImage)
        cls.get_frame = service("get_frame", GetFrame)
        # the station's launch file names the simulated scanner: connected from the start, unlike the driver's default
        cls.connected_at_start = service("is_connected", IsConnected)().connected
        reconfigure(resolution=RESOLUTION_LOW)
        cls.recorder = FrameRecorder(["pointcloud", "depth_map", "confidence_map"])
        cls.tf_buffer = tf2_ros.Buffer()
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)
        cls.config = load_camera_config()
        cls.station = Station.load()

    def _frame(self):
        reply = self.trigger()  # triggers only; get_frame(id) publishes, as the driver
        self.assertTrue(reply.success, reply.message)
        published = self.get_frame(in_=reply.id)
        self.assertTrue(published.success, published.message)
        messages = self.recorder.wait_for(reply.id)
        self.assertIsNotNone(messages, f"frame {reply.id} was not published")
        points, _, _ = phoxi_messages.pointcloud2_arrays(messages["pointcloud"])
        depth = phoxi_messages.image_array(messages["depth_map"])
        return points, depth, phoxi_messages.image_array(messages["confidence_map"])

    def _sensor_pose(self):
        transform = self.tf_buffer.lookup_transform(
            "world", "PhoXi3Dscanner_sensor", rospy.Time(0), rospy.Duration(10.0)
        ).transform
        t, q = transform.translation, transform.rotation
        return transform_from_quaternion([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])

    def test_the_station_launch_connects_to_the_simulated_scanner(self):
        self.assertTrue(self.connected_at_start)

    def test_sensor_frame_is_on_tf_at_the_configured_pose(self):
        np.testing.assert_allclose(self._sensor_pose(), self.config.pose, atol=1e-9)

    def test_cloud_shows_the_part_at_its_place_in_the_world(self):
        place_robot("home")
        points, depth, _ = self._frame()
        pose = self._sensor_pose()
        world = points[depth > 0] @ pose[:3, :3].T + pose[:3, 3]
        part = self.station.scene.part.pose[:3, 3]  # bottom centre of the 100 mm cube on the fixture
        top = (np.abs(world[:, 0] - part[0]) < 0.04) & (np.abs(world[:, 1] - part[1]) < 0.04)
        self.assertGreater(top.sum(), 500)
        heights = world[top, 2] - (part[2] + 0.1)
        self.assertLess(abs(np.mean(heights)), 0.0005)
        self.assertLess(np.percentile(np.abs(heights), 99), 0.002)

    def test_moving_the_robot_changes_the_cloud_where_its_links_are(self):
        set_joint_state = rospy.ServiceProxy("/ur_driver_sim/set_joint_state", SetJointState)
        clouds = []
        for q in (np.zeros(6), MOVED):
            reply = set_joint_state(positions=list(q), named_state="")
            self.assertTrue(reply.success, reply.message)
            rospy.sleep(0.5)  # robot_state_publisher puts the new pose on tf
            clouds.append(self._frame()[1:])
        place_robot("home")
        (a, sigma_a), (b, sigma_b) = clouds
        # the frames' noise differs: a change is more than 6 sigma of either (the confidence map), and 2 mm
        changed = ((a > 0) != (b > 0)) | (np.abs(a - b) > np.maximum(2.0, 6.0 * np.maximum(sigma_a, sigma_b)))
        # where the robot is and the shadows it casts, from the ROS-free renderer with the links posed by FK
        model = load_scanner_model(self.config.model)
        scanner = StructuredLightScanner(model)
        settings = ScanSettings(resolution=RESOLUTION_LOW, noise=False)
        scene = scene_geometry(self.station.scene)
        robot = RobotGeometry(UrdfModel(self.station.urdf_xml))
        kinematics = KinematicModel.from_station(self.station)
        scene_only = scanner.capture(scene, self.config.pose, settings)
        expected, robot_frames = np.zeros_like(changed), []
        for q in (np.zeros(6), MOVED):
            links = {name: p[0] for name, p in kinematics.link_poses_batch(q[None]).items()}
            robot_only = scanner.capture(robot.posed(links), self.config.pose, settings)
            full = scanner.capture(SceneGeometry.concatenate([scene, robot.posed(links)]), self.config.pose, settings)
            silhouette = robot_only.texture > 0
            expected |= silhouette | (scene_only.valid & ~full.valid & ~silhouette)
            robot_frames.append(robot_only)
        self.assertGreater(changed.sum(), 2000)
        stray = (changed & ~expected).sum()
        self.assertLessEqual(stray, 0.01 * changed.sum(), f"{stray} pixels changed away from the robot")
        arrived = (robot_frames[1].texture > 0) & ~(robot_frames[0].texture > 0) & robot_frames[1].valid
        self.assertGreater(arrived.sum(), 2000)
        # where a link moved in, the node's cloud shows the link at its depth (tf poses = FK poses)
        at_link = np.abs(b - robot_frames[1].depth_mm)[arrived] < 2.0
        print(
            f"changed {changed.sum()} px, {stray} away from the robot; link arrived at {arrived.sum()} px, {at_link.mean():.4f} at its depth"
        )
        self.assertGreater(at_link.mean(), 0.95)
        self.assertGreater(changed[arrived].mean(), 0.95)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "phoxi_camera_station", PhoxiStationTest)
