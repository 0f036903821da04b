"""Messages of the 3D next-best-view loop <-> its core types (needs the message packages, not a master).

:func:`request_mapping_from_goal` maps a ReconstructObject goal to the fields of
:class:`~agiprobot_measurement.nbv.volumetric.request.ReconstructionRequest` (zero / empty = the configured default);
:func:`captured_view` turns one PhoXi frame (organised cloud, confidence map, camera info) and the sensor's pose into
a :class:`~agiprobot_measurement.nbv.volumetric.interfaces.CapturedView`; :func:`candidate_arrays` reads the loop's last
candidate set for the markers. World frame, metres.
"""

from __future__ import annotations

import math

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.interfaces import CapturedView, CaptureError
from agiprobot_measurement.ros.conversions import xyz_array
from agiprobot_measurement.ros.phoxi_messages import CLOUD_NORMAL_SCALE, image_array, pointcloud2_arrays
from agiprobot_measurement.sensors.phoxi.models import CameraIntrinsics

__all__ = ["candidate_arrays", "captured_view", "intrinsics_from_camera_info", "request_mapping_from_goal"]


#: goal fields that are plain non-negative numbers, 0 = the default
_NUMBER_FIELDS = (
    "resolution_m",
    "planning_resolution_m",
    "cost_weight",
    "max_time_s",
    "max_joint_path_rad",
    "min_gain_area_mm2",
    "min_relative_gain",
)


def request_mapping_from_goal(goal, defaults: dict, max_voxels: float, default_roi_size_m=None) -> dict:
    """The :class:`ReconstructionRequest` fields of a ReconstructObject goal over ``defaults`` (config/nbv.yaml's
    ``request``): zero / empty goal fields keep the default. Raises InputError naming the field for NaN or infinite
    numbers, negative values, a ROI edge that is zero or negative while another is given, or a grid larger than
    ``max_voxels``: the goal's ROI, or ``default_roi_size_m`` (m, the station's a-priori ROI) when the goal leaves
    it at the default, at the goal's or the default resolution."""
    values = dict(defaults)
    centre, size = xyz_array(goal.roi_center), xyz_array(goal.roi_size)
    for name, value in (("roi_center", centre), ("roi_size", size)):
        if not np.all(np.isfinite(value)):
            raise InputError(f"{name} is not finite: {value.tolist()}")
    for name in _NUMBER_FIELDS:
        value = float(getattr(goal, name))
        if not math.isfinite(value):
            raise InputError(f"{name} is not finite: {value}")
        if value < 0.0:
            raise InputError(f"{name} must not be negative (0 = the default), got {value}")
        if value > 0.0:
            values[name] = value
    if np.any(centre != 0.0):
        values["roi_center_m"] = centre
    if np.any(size != 0.0):
        if np.any(size <= 0.0):
            raise InputError(
                f"roi_size: the region of interest is empty: every edge must be positive (all zero = the default "
                f"size), got {size.tolist()} m"
            )
        values["roi_size_m"] = size
        _check_voxels(size, float(values.get("resolution_m", 0.002)), max_voxels, "roi_size")
    elif default_roi_size_m is not None:
        default_size = np.asarray(default_roi_size_m, dtype=float)
        _check_voxels(default_size, float(values.get("resolution_m", 0.002)), max_voxels, "the default ROI")
    if goal.max_views < 0:
        raise InputError(f"max_views must not be negative (0 = the default), got {goal.max_views}")
    if goal.max_views > 0:
        values["max_views"] = int(goal.max_views)
    if goal.gain.strip():
        values["gain"] = goal.gain.strip()
    if goal.candidates.strip():
        values["candidates"] = goal.candidates.strip()
    values["execute"] = bool(goal.execute)
    values["seed"] = int(goal.seed)
    return values


def _check_voxels(size: np.ndarray, resolution: float, max_voxels: float, what: str) -> None:
    cells = float(np.prod(np.ceil(size / resolution))) if resolution > 0 else math.inf
    if not cells <= max_voxels:
        raise InputError(
            f"{what}: {size.tolist()} m at resolution {resolution} m is {cells:.3g} voxels, more than the node's "
            f"limit of {max_voxels:.3g} (~max_voxels): choose a smaller ROI or a coarser resolution_m"
        )


def candidate_arrays(candidates) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(poses (V,4,4), utilities (V,), reasons) of the loop's ``candidates_last``: a (poses, utilities, reasons)
    triple or a list of records with pose / utility / reason (or rejection) attributes; "" = feasible."""
    if candidates is None or len(candidates) == 0:
        return np.zeros((0, 4, 4)), np.zeros(0), []
    if isinstance(candidates, tuple | list) and len(candidates) == 3 and np.ndim(candidates[0]) == 3:
        poses, utilities, reasons = candidates
        return np.asarray(poses, float), np.asarray(utilities, float), ["" if r is None else str(r) for r in reasons]
    poses, utilities, reasons = [], [], []
    for c in candidates:
        get = c.get if isinstance(c, dict) else lambda k, d=None, c=c: getattr(c, k, d)
        poses.append(np.asarray(get("pose", get("camera_pose")), float))
        utility = get("utility", None)
        utilities.append(np.nan if utility is None else float(utility))
        reason = get("reason", None) or get("rejection", None) or ""
        reasons.append(str(reason))
    return np.asarray(poses).reshape(-1, 4, 4), np.asarray(utilities), reasons


def intrinsics_from_camera_info(msg: CameraInfo) -> CameraIntrinsics:
    """The pinhole intrinsics (pixels) of a CameraInfo (K; the PhoXi has no distortion model)."""
    k = np.asarray(msg.K, dtype=float).reshape(3, 3)
    return CameraIntrinsics(
        int(msg.width), int(msg.height), float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])
    )


def captured_view(cloud: PointCloud2, confidence: Image, info: CameraInfo, camera_pose: np.ndarray) -> CapturedView:
    """A :class:`CapturedView` of one PhoXi frame: ``cloud`` organised (H x W, invalid pixels all zero, the driver's
    normals 1/1000 long) in the sensor frame, ``confidence`` the sigma_z map (mm), ``camera_pose`` world <- sensor
    (4x4) at the frame's stamp. Raises CaptureError for messages that do not fit together."""
    if cloud.height <= 1 or cloud.width * cloud.height != info.width * info.height:
        raise CaptureError(
            f"the PhoXi cloud is not organised ({cloud.width} x {cloud.height} for a {info.width} x {info.height} "
            "image): set the driver's organized_cloud true (the map needs the pixels' grid for the depth image)"
        )
    points, normals, _ = pointcloud2_arrays(cloud)
    sigma = image_array(confidence)
    if sigma.shape != points.shape[:2]:
        raise CaptureError(f"confidence map {sigma.shape} does not match the cloud {points.shape[:2]}")
    depth = points[:, :, 2].astype(np.float64)
    valid = np.isfinite(points).all(axis=2) & (depth > 0.0)
    depth = np.where(valid, depth, 0.0)
    rotation, translation = camera_pose[:3, :3], camera_pose[:3, 3]
    local = points[valid].astype(np.float64)
    normal = normals[valid].astype(np.float64) / CLOUD_NORMAL_SCALE
    length = np.linalg.norm(normal, axis=1)
    # a valid point always has a normal in the driver's cloud; a zero one (none estimated) points back at the sensor
    fallback = -local / np.maximum(np.linalg.norm(local, axis=1), 1e-12)[:, None]
    normal = np.where(length[:, None] > 1e-9, normal / np.maximum(length, 1e-12)[:, None], fallback)
    return CapturedView(
        points_m=local @ rotation.T + translation,
        normals=normal @ rotation.T,
        sigma_mm=sigma[valid].astype(np.float64),
        camera_pose=np.asarray(camera_pose, dtype=float),
        depth_m=depth,
        intrinsics=intrinsics_from_camera_info(info),
        stamp_s=cloud.header.stamp.to_sec(),
    )
