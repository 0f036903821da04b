"""Shared by the scanner rostests: a plate placed in front of the laser emitter (as the simulated sensor's target),
and the profiles of /scancontrol_pointcloud as arrays."""

import tempfile

import numpy as np
import rospy
import tf2_ros
import trimesh

from agiprobot_measurement.ros.conversions import transform_to_matrix
from agiprobot_measurement.srv import SetScanTarget

#: the plate's lower face along the emitter's boresight (mm): inside the measuring range (127-227 mm)
PLATE_DISTANCE_MM = 180.0
PLATE_SIZE_MM = (300.0, 300.0, 10.0)


def emitter_pose_mm(timeout_s: float = 60.0) -> np.ndarray:
    """The world pose of laser_emitter_frame now (4x4, mm)."""
    buffer = tf2_ros.Buffer()
    tf2_ros.TransformListener(buffer)
    transform = buffer.lookup_transform("world", "laser_emitter_frame", rospy.Time(0), rospy.Duration(timeout_s))
    pose = transform_to_matrix(transform)
    pose[:3, 3] *= 1000.0
    return pose


def place_plate(service: str = "/scancontrol_driver/set_target") -> np.ndarray:
    """Make a plate facing the emitter at :data:`PLATE_DISTANCE_MM` the scan target; returns the world pose of the
    plate's lower face (4x4, mm: its z axis is the emitter's boresight)."""
    pose = emitter_pose_mm()
    plate = trimesh.creation.box(extents=PLATE_SIZE_MM)
    plate.apply_translation([0.0, 0.0, PLATE_SIZE_MM[2] / 2.0])
    path = tempfile.NamedTemporaryFile(suffix=".stl", delete=False).name
    plate.export(path)
    face = pose.copy()
    face[:3, 3] += PLATE_DISTANCE_MM * pose[:3, 2]
    rospy.wait_for_service(service, timeout=60.0)
    reply = rospy.ServiceProxy(service, SetScanTarget)(path, "mm", face.reshape(-1).tolist())
    assert reply.success, reply.message
    return face


def profile_array(msg) -> np.ndarray:
    """(width, 4) float32 x, y, z, intensity of a driver message (fields in that order, float32)."""
    return np.frombuffer(msg.data, dtype=np.float32).reshape(msg.width * msg.height, 4)
