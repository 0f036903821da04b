"""The peers of the flange calibration: a chessboard plate on the flange and OpenCV's AX = XB hand-eye solvers.

What users of easy_handeye or moveit_calibration do on a station with a fixed camera (eye-to-hand): a board is
bolted to the flange, each frame gives the board's pose in the camera (corners found in the texture image, sub-pixel,
:func:`cv2.solvePnP` with the camera's intrinsics, from ``camera_info``), the robot gives the flange pose, and
:func:`cv2.calibrateHandEye` (Tsai, Park, Horaud, Andreff, Daniilidis) or :func:`cv2.calibrateRobotWorldHandEye`
(Shah, Li) solve for the camera in the robot base frame. For eye-to-hand OpenCV documents passing the inverted robot
poses (base -> gripper) in place of gripper -> base; the "cam2gripper" result is then base <- camera.

The project pins OpenCV 4.14 (opencv-python-headless==4.14.0.94): the 5.0.0 wheels lack these two solvers in their
Python bindings (opencv/opencv#29565, fixed after that release).

Frames: ``base`` = the robot base frame (the DH base, ur_description's ``base``), ``tool0`` = the flange, ``board`` = the board's corner plane
(origin at the centre of the inner corners, z out of the printed face), ``camera`` = the optical frame. Metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.calibration.chessboard_test import chessboard_corners_board, detect_corners
from agiprobot_measurement.calibration.registration import CalibrationError
from agiprobot_measurement.common.geometry import invert_pose
from agiprobot_measurement.sensors.phoxi.scene_geometry import chessboard_geometry

__all__ = [
    "HAND_EYE_METHODS",
    "ROBOT_WORLD_METHODS",
    "BoardDetection",
    "FlangeBoard",
    "calibrate_eye_to_hand",
    "calibrate_robot_world",
    "detect_board_pose",
    "solve_all",
    "solve_many",
]


def _cv2():
    import cv2  # lazily: the calibration package is imported by nodes that never use the peers

    return cv2


HAND_EYE_METHODS = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS")
ROBOT_WORLD_METHODS = ("SHAH", "LI")


@dataclass(frozen=True)
class FlangeBoard:
    """A chessboard plate bolted to the flange: ``inner_corners`` (rows, cols), squares ``square_m``, its printed
    face ``standoff_m`` in front of the flange face along tool0's z, board x along tool0's x.

    (rows + 1) + (cols + 1) squares must be odd so that the board is not symmetric under a half turn (the colour
    of the corner squares tells the two ends apart, :func:`detect_board_pose`)."""

    inner_corners: tuple[int, int] = (6, 9)
    square_m: float = 0.025
    thickness_m: float = 0.003
    standoff_m: float = 0.013  # 10 mm adapter plate + the 3 mm board

    def __post_init__(self):
        rows, cols = self.inner_corners
        if rows < 2 or cols < 2 or (rows + cols) % 2 == 0:
            raise CalibrationError(
                f"flange board {rows} x {cols} inner corners: need at least 2 x 2 and an odd sum (a board that a half "
                "turn does not map onto itself)"
            )
        if not (self.square_m > 0 and self.thickness_m > 0 and self.standoff_m >= self.thickness_m):
            raise CalibrationError("flange board: square_m, thickness_m > 0 and standoff_m >= thickness_m needed")

    @property
    def tool0_from_board(self) -> np.ndarray:
        pose = np.eye(4)
        pose[2, 3] = self.standoff_m
        return pose

    def corners_board_m(self) -> np.ndarray:
        """Inner corners (rows * cols, 3) in the board frame, OpenCV's row-major order."""
        return chessboard_corners_board(self.inner_corners, self.square_m)

    def geometry(self):
        """The plate as renderer geometry in the tool0 frame (sensors.phoxi.scene_geometry.SceneGeometry)."""
        return chessboard_geometry(self.tool0_from_board, self.inner_corners, self.square_m, self.thickness_m)


@dataclass
class BoardDetection:
    """A board found in one frame: camera <- board (4x4), the corners (N, 2 pixels, board order), the RMS
    reprojection error (pixels)."""

    camera_from_board: np.ndarray
    pixels: np.ndarray
    reprojection_rms_px: float


def _sample(image: np.ndarray, xy: np.ndarray) -> float:
    """Mean intensity of a 3 x 3 pixel patch at ``xy`` (column, row); NaN outside the image."""
    c, r = round(float(xy[0])), round(float(xy[1]))
    h, w = image.shape
    if not (1 <= r < h - 1 and 1 <= c < w - 1):
        return float("nan")
    return float(image[r - 1 : r + 2, c - 1 : c + 2].mean())


def _first_corner_is_dark_end(image: np.ndarray, grid: np.ndarray) -> bool:
    """Whether corner (0, 0) of a (rows, cols, 2) pixel grid is the board's dark-square end: the square diagonally
    outside it is dark in the board layout (scene.chessboard_dark_squares), the square beside it light; at the far
    corner the other way round (odd square sum). Both ends vote, so one end may lie outside the image."""
    along_row, along_col = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    first, last = grid[0, 0], grid[-1, -1]
    near = _sample(image, first - 0.5 * along_row - 0.5 * along_col) - _sample(
        image, first + 0.5 * along_row - 0.5 * along_col
    )
    far = _sample(image, last + 0.5 * along_row + 0.5 * along_col) - _sample(
        image, last - 0.5 * along_row + 0.5 * along_col
    )
    if np.isnan(near) and np.isnan(far):
        raise CalibrationError("board: neither end's corner squares are in the image, its orientation is unknown")
    return bool(np.nan_to_num(far) - np.nan_to_num(near) > 0.0)


def detect_board_pose(texture: np.ndarray, camera_matrix: np.ndarray, board: FlangeBoard, dist_coeffs=None):
    """The board's pose in one texture image: corners (:func:`chessboard_test.detect_corners`: OpenCV, sub-pixel),
    the corner order made right-handed (seen from the printed face) and its half-turn ambiguity resolved by the
    corner squares' colour, then
    :func:`cv2.solvePnP` (IPPE for a plane, refined by Levenberg-Marquardt). :class:`CalibrationError` when not found.
    """
    cv2 = _cv2()
    rows, cols = board.inner_corners
    pixels = detect_corners(texture, board.inner_corners)
    grid = pixels.reshape(rows, cols, 2)
    # OpenCV's order may run the rows either way: the board frame's x (along a row) and y (down the columns) must
    # appear with z = x cross y pointing at the camera (seen from the printed face), negative in the image's (x right,
    # y down) cross product
    along_row, along_col = grid[0, -1] - grid[0, 0], grid[-1, 0] - grid[0, 0]
    if along_row[0] * along_col[1] - along_row[1] * along_col[0] > 0:
        grid = grid[::-1]
    image = np.nan_to_num(np.asarray(texture, dtype=np.float64))
    if not _first_corner_is_dark_end(image, grid):
        grid = grid[::-1, ::-1]
    pixels = np.ascontiguousarray(grid.reshape(-1, 2))
    objects = board.corners_board_m()
    dist = np.zeros(5) if dist_coeffs is None else np.asarray(dist_coeffs, dtype=float)
    k = np.asarray(camera_matrix, dtype=float)
    ok, rvec, tvec = cv2.solvePnP(objects, pixels, k, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationError("solvePnP found no board pose")
    rvec, tvec = cv2.solvePnPRefineLM(objects, pixels, k, dist, rvec, tvec)
    projected, _ = cv2.projectPoints(objects, rvec, tvec, k, dist)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - pixels) ** 2, axis=1))))
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = tvec.ravel()
    if pose[2, 3] <= 0 or pose[:3, 2] @ pose[:3, 3] >= 0:  # behind the camera, or seen from its back
        raise CalibrationError("board pose from solvePnP is behind the camera or faces away: corner order wrong")
    return BoardDetection(pose, pixels, rms)


def _split(poses: np.ndarray):
    poses = np.asarray(poses, dtype=float)
    return [p[:3, :3] for p in poses], [p[:3, 3].reshape(3, 1) for p in poses]


def _check_pairs(base_from_tool0: np.ndarray, camera_from_board: np.ndarray) -> None:
    if len(base_from_tool0) != len(camera_from_board):
        raise CalibrationError(f"hand-eye: {len(base_from_tool0)} robot poses but {len(camera_from_board)} board poses")
    if len(base_from_tool0) < 3:
        raise CalibrationError(f"hand-eye needs at least 3 pose pairs, got {len(base_from_tool0)}")


def calibrate_eye_to_hand(base_from_tool0: np.ndarray, camera_from_board: np.ndarray, method: str) -> np.ndarray:
    """base <- camera (4x4) by :func:`cv2.calibrateHandEye` for a fixed camera: the robot poses go in inverted
    (tool0 <- base as "gripper2base"), the result "cam2gripper" is then base <- camera."""
    cv2 = _cv2()
    if method not in HAND_EYE_METHODS:
        raise CalibrationError(f"unknown hand-eye method {method!r} ({', '.join(HAND_EYE_METHODS)})")
    _check_pairs(base_from_tool0, camera_from_board)
    r_robot, t_robot = _split(np.linalg.inv(np.asarray(base_from_tool0, dtype=float)))
    r_board, t_board = _split(camera_from_board)
    rotation, translation = cv2.calibrateHandEye(
        r_robot, t_robot, r_board, t_board, method=getattr(cv2, f"CALIB_HAND_EYE_{method}")
    )
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, translation.ravel()
    return out


def calibrate_robot_world(base_from_tool0: np.ndarray, camera_from_board: np.ndarray, method: str):
    """(base <- camera, tool0 <- board) by :func:`cv2.calibrateRobotWorldHandEye` (A X = Z B) for a fixed camera:
    the board plays OpenCV's camera and the camera its world, so "world2cam" = board <- camera, "base2gripper" =
    tool0 <- base; "base2world" is then camera <- base and "gripper2cam" board <- tool0."""
    cv2 = _cv2()
    if method not in ROBOT_WORLD_METHODS:
        raise CalibrationError(f"unknown robot-world method {method!r} ({', '.join(ROBOT_WORLD_METHODS)})")
    _check_pairs(base_from_tool0, camera_from_board)
    r_a, t_a = _split(np.linalg.inv(np.asarray(camera_from_board, dtype=float)))
    r_b, t_b = _split(np.linalg.inv(np.asarray(base_from_tool0, dtype=float)))
    r_x, t_x, r_z, t_z = cv2.calibrateRobotWorldHandEye(
        r_a, t_a, r_b, t_b, method=getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{method}")
    )
    camera_from_base, board_from_tool0 = np.eye(4), np.eye(4)
    camera_from_base[:3, :3], camera_from_base[:3, 3] = r_x, t_x.ravel()
    board_from_tool0[:3, :3], board_from_tool0[:3, 3] = r_z, t_z.ravel()
    return invert_pose(camera_from_base), invert_pose(board_from_tool0)


def solve_all(base_from_tool0: np.ndarray, camera_from_board: np.ndarray) -> dict[str, np.ndarray]:
    """base <- camera by every OpenCV method, keyed by the method's name; a failing method raises (see
    :func:`solve_many`, which leaves it out instead)."""
    out = {m: calibrate_eye_to_hand(base_from_tool0, camera_from_board, m) for m in HAND_EYE_METHODS}
    out.update({m: calibrate_robot_world(base_from_tool0, camera_from_board, m)[0] for m in ROBOT_WORLD_METHODS})
    return out


def solve_many(problems: list[tuple[np.ndarray, np.ndarray]]) -> list[dict[str, np.ndarray]]:
    """:func:`solve_all` for each (base_from_tool0 (N, 4, 4), camera_from_board (N, 4, 4)); a method that fails on a
    problem (OpenCV refuses degenerate motions) is left out of that problem's result, so it cannot hide the others'.
    CalibrationError on malformed input."""
    for robot, board in problems:
        _check_pairs(robot, board)
    cv2 = _cv2()
    results = []
    for robot, board in problems:
        solved = {}
        for method in HAND_EYE_METHODS + ROBOT_WORLD_METHODS:
            try:
                if method in HAND_EYE_METHODS:
                    solved[method] = calibrate_eye_to_hand(robot, board, method)
                else:
                    solved[method] = calibrate_robot_world(robot, board, method)[0]
            except (cv2.error, CalibrationError):
                continue
        results.append(solved)
    return results
