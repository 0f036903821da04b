"""ROS messages of a simulated PhoXi frame, laid out as the real driver publishes them, and back to arrays.

Needs the ROS message packages (sensor_msgs, std_msgs), not a running master. The point cloud has the layout of
PCL's ``pcl::PointNormal`` (what the driver converts with ``pcl::toROSMsg``): x y z at bytes 0-11, normal_x/y/z at
16-27, curvature at 32, 48 bytes per point, metres. The driver divides the normals by 1000 as it converts the
points from mm to m (PhoXiInterface.cpp, getOrganizedCloudFromFrame), so a cloud's normals are
:data:`CLOUD_NORMAL_SCALE` long; the normal_map image keeps unit normals. Images: depth_map 32FC1 (mm), texture and
confidence_map 32FC1, normal_map 32FC3, rgb_texture rgb8.
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.ros.errors import MessageError
from agiprobot_measurement.sensors.phoxi.models import CameraIntrinsics

__all__ = [
    "CLOUD_NORMAL_SCALE",
    "IMAGE_ENCODINGS",
    "POINT_FIELDS",
    "POINT_STEP",
    "camera_info",
    "image",
    "image_array",
    "pointcloud2",
    "pointcloud2_arrays",
]

#: (name, byte offset) of the point fields; every field is FLOAT32 (PointField.FLOAT32 = 7)
POINT_FIELDS = (
    ("x", 0),
    ("y", 4),
    ("z", 8),
    ("normal_x", 16),
    ("normal_y", 20),
    ("normal_z", 24),
    ("curvature", 32),
)
POINT_STEP = 48
#: length of the normals in the driver's point cloud (unit normals divided by 1000); multiply by 1000 for unit ones
CLOUD_NORMAL_SCALE = 1e-3
_FLOATS_PER_POINT = POINT_STEP // 4

IMAGE_ENCODINGS = {"32FC1": (np.float32, 1), "32FC3": (np.float32, 3), "rgb8": (np.uint8, 3), "mono8": (np.uint8, 1)}


def pointcloud2(
    points: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
    header,
    organized: bool = True,
    normal_scale: float = CLOUD_NORMAL_SCALE,
):
    """PointCloud2 from (H, W, 3) points (m) and unit normals, the normals multiplied by ``normal_scale`` (the
    driver's 1/1000); organised H x W with zeros kept, or only valid points."""
    from sensor_msgs.msg import PointCloud2, PointField

    height, width = points.shape[:2]
    if organized:
        xyz, nrm = points.reshape(-1, 3), normals.reshape(-1, 3)
    else:
        keep = np.asarray(valid).reshape(-1)
        xyz, nrm = points.reshape(-1, 3)[keep], normals.reshape(-1, 3)[keep]
        height, width = 1, len(xyz)
    table = np.zeros((len(xyz), _FLOATS_PER_POINT), dtype="<f4")
    table[:, 0:3] = xyz
    table[:, 4:7] = nrm * normal_scale
    msg = PointCloud2()
    msg.header = header
    msg.height, msg.width = int(height), int(width)
    msg.fields = [
        PointField(name=name, offset=offset, datatype=PointField.FLOAT32, count=1) for name, offset in POINT_FIELDS
    ]
    msg.is_bigendian = False
    msg.point_step = POINT_STEP
    msg.row_step = POINT_STEP * msg.width
    msg.data = table.tobytes()
    msg.is_dense = True  # invalid points are zeros, not NaN: every value is finite (as the driver's PCL cloud)
    return msg


def pointcloud2_arrays(msg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, normals, curvature) of a PointCloud2 with float32 fields x..normal_z, curvature; shaped (H, W, .)."""
    offsets = {f.name: f.offset for f in msg.fields}
    missing = [name for name, _ in POINT_FIELDS if name not in offsets]
    if missing:
        raise MessageError(f"PointCloud2 lacks fields {missing}")
    dtype = np.dtype(
        {
            "names": [name for name, _ in POINT_FIELDS],
            "formats": [(">f4" if msg.is_bigendian else "<f4")] * len(POINT_FIELDS),
            "offsets": [offsets[name] for name, _ in POINT_FIELDS],
            "itemsize": msg.point_step,
        }
    )
    table = np.frombuffer(bytes(msg.data), dtype=dtype, count=msg.height * msg.width)
    shape = (msg.height, msg.width)
    points = np.stack([table["x"], table["y"], table["z"]], axis=-1).reshape(*shape, 3)
    normals = np.stack([table["normal_x"], table["normal_y"], table["normal_z"]], axis=-1).reshape(*shape, 3)
    return points, normals, table["curvature"].reshape(shape)


def image(array: np.ndarray, encoding: str, header):
    """sensor_msgs/Image of an (H, W[, C]) array in one of :data:`IMAGE_ENCODINGS`."""
    from sensor_msgs.msg import Image

    dtype, channels = IMAGE_ENCODINGS[encoding]
    array = np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<"))
    if array.ndim == 2:
        array = array[:, :, None]
    if array.shape[2] != channels:
        raise MessageError(f"{encoding} needs {channels} channel(s), got {array.shape[2]}")
    msg = Image()
    msg.header = header
    msg.height, msg.width = int(array.shape[0]), int(array.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = int(array.shape[1] * array.shape[2] * array.itemsize)
    msg.data = array.tobytes()
    return msg


def image_array(msg) -> np.ndarray:
    """(H, W) or (H, W, C) array of an Image in one of :data:`IMAGE_ENCODINGS`."""
    if msg.encoding not in IMAGE_ENCODINGS:
        raise MessageError(f"unsupported encoding {msg.encoding!r}")
    dtype, channels = IMAGE_ENCODINGS[msg.encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.step)
    array = row[:, : msg.width * channels * dtype.itemsize].copy().view(dtype).reshape(msg.height, msg.width, channels)
    return array[:, :, 0] if channels == 1 else array


def camera_info(intrinsics: CameraIntrinsics, header):
    """sensor_msgs/CameraInfo of the sensor: pinhole K and P, no distortion (plumb_bob with zeros), R identity."""
    from sensor_msgs.msg import CameraInfo

    msg = CameraInfo()
    msg.header = header
    msg.width, msg.height = intrinsics.width, intrinsics.height
    msg.distortion_model = "plumb_bob"
    msg.D = [0.0] * 5
    msg.K = intrinsics.matrix().reshape(-1).tolist()
    msg.R = np.eye(3).reshape(-1).tolist()
    projection = np.zeros((3, 4))
    projection[:, :3] = intrinsics.matrix()
    msg.P = projection.reshape(-1).tolist()
    return msg
