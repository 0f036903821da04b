"""Test mode of the calibration (ROS-free): chessboard corners in a rendered PhoXi frame, 3D, transformed."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agiprobot_measurement.calibration import CalibrationError, transform_points
from agiprobot_measurement.chessboard_check import (
    chessboard_corners_board,
    chessboard_geometry,
    corner_points,
    detect_corners,
    positioning_errors_mm,
)
from agiprobot_measurement.structured_light import ScanSettings, StructuredLightScanner, load_scanner_model


@pytest.fixture(scope="module")
def frame_and_board():
    board = np.eye(4)  # camera frame: 1 m in front, turned 17 deg about x and 6 deg about z
    board[:3, :3] = Rotation.from_euler("xyz", [np.pi + 0.3, 0.0, 0.1]).as_matrix()
    board[:3, 3] = [0.02, -0.01, 1.0]
    scanner = StructuredLightScanner(load_scanner_model("L"))
    scanner.workers = 1
    frame = scanner.capture(chessboard_geometry(board), np.eye(4), ScanSettings(seed=0), frame_index=0)
    return frame, board


def test_corners_in_3d_and_positioning_error(frame_and_board):
    frame, board = frame_and_board
    pixels = detect_corners(frame.texture, (8, 11))
    assert pixels.shape == (88, 2)
    points = corner_points(frame.points_m(), pixels)
    truth_camera = transform_points(board, chessboard_corners_board((8, 11), 0.03))
    h = np.eye(4)
    h[:3, 3] = [0.5, -0.2, 0.1]  # a calibration: base <- camera
    errors = positioning_errors_mm(h, points, transform_points(h, truth_camera))
    assert np.isfinite(errors).all()
    assert errors.max() < 0.5  # mm, the noise of the simulated PhoXi at 1 m
    shifted = h.copy()
    shifted[0, 3] += 0.002  # a calibration 2 mm off shows as 2 mm at every corner
    assert np.allclose(positioning_errors_mm(shifted, points, transform_points(h, truth_camera)), 2.0, atol=0.5)


def test_no_chessboard_is_a_clear_error():
    with pytest.raises(CalibrationError, match="8 x 11 inner corners"):
        detect_corners(np.zeros((100, 120)), (8, 11))
