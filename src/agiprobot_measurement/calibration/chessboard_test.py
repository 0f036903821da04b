"""Test mode of the calibration, ROS-free: chessboard corners seen by the camera, mapped into the robot base frame.

The original's ``test`` mode: detect the inner corners of a chessboard (8 x 11 in the original) in the camera's
texture image (OpenCV), take each corner's 3D point from the organised point cloud (bilinear at the sub-pixel corner,
projected onto the board plane fitted around it), transform it with the calibration H (base <- camera) and move the
tip there. In the simulation the robot reaches every target exactly, so the positioning error per corner is
|H p_camera - p_true| (mm). Metres everywhere except names ending in ``_mm``.
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.calibration.registration import CalibrationError
from agiprobot_measurement.common.geometry import fit_plane, transform_points

__all__ = [
    "chessboard_corners_board",
    "corner_points",
    "detect_corners",
    "match_to_truth",
    "positioning_errors_mm",
    "scene_chessboard_corners",
    "scene_chessboards",
]


def chessboard_corners_board(inner_corners=(8, 11), square_m: float = 0.03) -> np.ndarray:
    """Inner corners (rows x cols, 3) in the board frame: the board's centre at the origin, z = board normal."""
    rows, cols = inner_corners
    u = (np.arange(cols) - (cols - 1) / 2.0) * square_m
    v = (np.arange(rows) - (rows - 1) / 2.0) * square_m
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel(), np.zeros(uu.size)])


def scene_chessboards(scene) -> list:
    """The chessboard objects of a station scene (station.Scene)."""
    return [obj for obj in scene.objects if obj.type == "chessboard"]


def scene_chessboard_corners(board) -> np.ndarray:
    """True inner corners (N, 3) of a scene file's chessboard object in the scene frame (metres)."""
    return transform_points(board.pose, chessboard_corners_board(board.inner_corners, board.square_m))


def detect_corners(texture: np.ndarray, inner_corners=(8, 11)) -> np.ndarray:
    """Sub-pixel inner corners (N, 2) (x = column, y = row) in a texture image; CalibrationError when not found."""
    import cv2

    image = np.nan_to_num(np.asarray(texture, dtype=np.float64))
    high = np.percentile(image[image > 0], 99.5) if np.any(image > 0) else 1.0
    gray = np.clip(image / max(high, 1e-9) * 255.0, 0, 255).astype(np.uint8)
    rows, cols = inner_corners
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, (cols, rows), flags=flags)
    if not found:
        raise CalibrationError(f"no chessboard with {rows} x {cols} inner corners in the texture image")
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.01)
    corners = cv2.cornerSubPix(gray, corners, (7, 7), (-1, -1), criteria)
    return corners.reshape(-1, 2).astype(float)


def corner_points(organized_m: np.ndarray, pixels: np.ndarray, window: int = 8) -> np.ndarray:
    """3D points (N, 3, camera frame) of sub-pixel image positions of an organised cloud (H, W, 3).

    Dark squares often give no depth, so the point is not read from the cloud: the plane is fitted to the valid
    points in a (2 window + 1)^2 neighbourhood, the pixel's viewing ray is interpolated from their directions (an
    affine function of column and row), and the ray meets the plane. NaN where the neighbourhood has too few points.
    """
    cloud = np.asarray(organized_m, dtype=float)
    h, w = cloud.shape[:2]
    valid = np.isfinite(cloud).all(axis=2) & (np.abs(cloud).sum(axis=2) > 0)
    out = np.full((len(pixels), 3), np.nan)
    for k, (x, y) in enumerate(np.asarray(pixels, dtype=float)):
        r0, c0 = round(float(y)), round(float(x))
        rows = slice(max(r0 - window, 0), min(r0 + window + 1, h))
        cols = slice(max(c0 - window, 0), min(c0 + window + 1, w))
        mask = valid[rows, cols]
        if mask.sum() < 20:
            continue
        patch = cloud[rows, cols][mask]
        rr, cc = np.nonzero(mask)
        design = np.column_stack([np.ones(len(rr)), cc + cols.start, rr + rows.start])
        directions = patch / np.linalg.norm(patch, axis=1, keepdims=True)
        coef, *_ = np.linalg.lstsq(design, directions, rcond=None)
        ray = np.array([1.0, x, y]) @ coef
        ray /= np.linalg.norm(ray)
        centroid, normal = fit_plane(patch)
        out[k] = ray * (centroid @ normal) / (ray @ normal)
    return out


def match_to_truth(estimated_m: np.ndarray, truth_m: np.ndarray) -> np.ndarray:
    """Index of the nearest true corner per estimated corner (OpenCV's corner order may start at any end)."""
    d = np.linalg.norm(np.asarray(estimated_m)[:, None] - np.asarray(truth_m)[None], axis=2)
    return np.argmin(d, axis=1)


def positioning_errors_mm(h_base_camera: np.ndarray, corners_camera_m: np.ndarray, truth_base_m: np.ndarray):
    """Per corner: |H p_camera - p_true| (mm); NaN where the corner had no 3D point."""
    targets = transform_points(h_base_camera, corners_camera_m)
    ok = np.isfinite(targets).all(axis=1)
    errors = np.full(len(targets), np.nan)
    if ok.any():
        idx = match_to_truth(targets[ok], truth_base_m)
        errors[ok] = np.linalg.norm(targets[ok] - np.asarray(truth_base_m)[idx], axis=1) * 1000.0
    return errors
