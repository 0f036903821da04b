"""Test mode of the calibration, ROS-free: chessboard corners seen by the camera, mapped into the robot base frame.

The original's ``test`` mode: detect the inner corners of a chessboard (8 x 11 in the original) in the camera's
texture image (OpenCV), take each corner's 3D point from the organised point cloud (bilinear at the sub-pixel corner,
projected onto the board plane fitted around it), transform it with the calibration H (base <- camera) and move the
tip there. In the simulation the robot reaches every target exactly, so the positioning error per corner is
|H p_camera - p_true| (mm). Also the pieces of the node's test mode (run by
:func:`~agiprobot_measurement.calibration.procedure.run_test_mode`): the targets above the corners, the serpentine
order they are visited in, the true corners of a scene file's board and the report. Metres everywhere except names
ending in ``_mm``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from agiprobot_measurement.calibration.registration import CalibrationError
from agiprobot_measurement.common.files import atomic_write_text
from agiprobot_measurement.common.geometry import fit_plane, transform_points

__all__ = [
    "TEST_RESULT_FILE",
    "ChessboardTruth",
    "chessboard_corners_board",
    "chessboard_truth",
    "corner_points",
    "corner_targets",
    "detect_corners",
    "match_to_truth",
    "positioning_errors_mm",
    "scene_chessboard_corners",
    "scene_chessboards",
    "serpentine_order",
    "test_message",
    "test_report",
    "write_test_report",
]

#: the test mode's report, next to the calibration result it tested
TEST_RESULT_FILE = "test_result.yaml"


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


@dataclass
class ChessboardTruth:
    """Where a board really is (the simulated station's scene file knows): its inner corners (N, 3) and its normal
    (the board's z axis), robot base frame, metres."""

    corners_base_m: np.ndarray
    normal_base: np.ndarray

    def nearest_corner(self, point_base_m: np.ndarray) -> np.ndarray:
        """The true corner nearest ``point_base_m`` (:func:`match_to_truth`)."""
        return self.corners_base_m[match_to_truth(np.asarray(point_base_m, dtype=float)[None], self.corners_base_m)[0]]


def chessboard_truth(scene, inner_corners) -> ChessboardTruth | None:
    """The true corners of the scene's chessboards with ``inner_corners`` (rows, cols) in the robot base frame;
    None when the scene has no such board (a real station)."""
    boards = [b for b in scene_chessboards(scene) if tuple(b.inner_corners) == tuple(inner_corners)]
    if not boards:
        return None
    base_from_scene = np.linalg.inv(scene.robot_dh_base_pose)
    corners = np.vstack([transform_points(base_from_scene, scene_chessboard_corners(b)) for b in boards])
    return ChessboardTruth(corners, (base_from_scene[:3, :3] @ boards[0].pose[:3, :3])[:, 2])


def serpentine_order(count: int, inner_corners) -> np.ndarray:
    """The order to visit ``count`` detected corners in: OpenCV gives a full board row by row, so every other row
    is reversed (the flange sweeps back and forth); any other count is kept in detection order."""
    rows, cols = inner_corners
    order = np.arange(count)
    if count == rows * cols:
        grid = order.reshape(rows, cols)
        grid[1::2] = grid[1::2, ::-1]
        order = grid.ravel()
    return order


def corner_targets(h_base_camera: np.ndarray, organized_m, pixels: np.ndarray):
    """The detected corners in the robot base frame: (targets (N, 3), NaN where a corner has no 3D point; indices of
    the found ones; the board normal (unit, towards the camera)). ``organized_m``: the frame's (H, W, 3) cloud.
    :class:`CalibrationError` without an organised cloud or with fewer than 3 corners in 3D."""
    organized = None if organized_m is None else np.asarray(organized_m)
    if organized is None or organized.ndim != 3 or organized.shape[0] < 2:
        raise CalibrationError("test mode needs an organised point cloud (phoxi_camera organized_cloud:=true)")
    targets = transform_points(h_base_camera, corner_points(organized, pixels))
    found = np.flatnonzero(np.isfinite(targets).all(axis=1))
    if len(found) < 3:
        raise CalibrationError(f"test mode: only {len(found)} of {len(pixels)} corners have a 3D point")
    _, normal = fit_plane(targets[found])
    if normal @ (h_base_camera[:3, 3] - targets[found].mean(axis=0)) < 0.0:
        normal = -normal
    return targets, found, normal


def test_report(corners: list[dict], detected: int, in_3d: int, approach_offset_m: float, calibration) -> dict:
    """The test mode's report: ``corners`` (per corner: pixel, target, reached position, errors, as visited) and
    a summary with the counts and, when true corners were known, the positioning error's mean / max / RMS (mm)."""
    errors = [c["positioning_error_mm"] for c in corners if "positioning_error_mm" in c]
    summary = {
        "corners_detected": int(detected),
        "corners_in_3d": int(in_3d),
        "corners_reached": sum("distance_to_target_mm" in c for c in corners),
        "approach_offset_m": float(approach_offset_m),
        "calibration": str(calibration),
    }
    if errors:
        summary.update(
            positioning_error_mean_mm=float(np.mean(errors)),
            positioning_error_max_mm=float(np.max(errors)),
            positioning_error_rms_mm=float(np.sqrt(np.mean(np.square(errors)))),
        )
    return {"summary": summary, "corners": corners}


def test_message(report: dict) -> str:
    """One line on a :func:`test_report`: the counts and the positioning error against the true corners."""
    summary = report["summary"]
    message = (
        f"test: {summary['corners_detected']} corners detected, {summary['corners_in_3d']} in 3D, "
        f"{summary['corners_reached']} reached"
    )
    if "positioning_error_mean_mm" in summary:
        message += (
            f"; positioning error against the true corners mean {summary['positioning_error_mean_mm']:.3f} mm, "
            f"max {summary['positioning_error_max_mm']:.3f} mm"
        )
    elif summary["corners_reached"]:
        message += " (the scene file has no chessboard: no true corners to compare with)"
    return message


def write_test_report(path: str | Path, report: dict) -> Path:
    """Write a :func:`test_report` as YAML (folders created, atomic, the umask's permissions)."""
    return atomic_write_text(path, yaml.safe_dump(report, sort_keys=False), make_parents=True)
