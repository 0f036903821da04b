"""Test mode of the calibration (ROS-free): chessboard corners in a rendered PhoXi frame, 3D, transformed."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agiprobot_measurement.calibration.chessboard_test import (
    chessboard_corners_board,
    corner_points,
    detect_corners,
    positioning_errors_mm,
)
from agiprobot_measurement.calibration.registration import CalibrationError
from agiprobot_measurement.common.geometry import transform_points
from agiprobot_measurement.sensors.phoxi.renderer import (
    ScanSettings,
    StructuredLightScanner,
    chessboard_geometry,
    load_scanner_model,
)


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


def test_chessboard_of_the_calibration_scene_is_rendered_and_found():
    """The scene file's chessboard object as phoxi_camera renders it: 88 corners at their true 3D positions."""
    from agiprobot_measurement.calibration.chessboard_test import scene_chessboard_corners, scene_chessboards
    from agiprobot_measurement.calibration.simulation import nominal_camera_pose
    from agiprobot_measurement.sensors.phoxi.renderer import scene_geometry
    from agiprobot_measurement.station import CONFIG_DIR, load_scene

    scene = load_scene(CONFIG_DIR / "calibration_scene.yaml")
    (board,) = scene_chessboards(scene)
    camera = nominal_camera_pose()  # world <- camera
    scanner = StructuredLightScanner(load_scanner_model("L"))
    scanner.workers = 1
    frame = scanner.capture(scene_geometry(scene), camera, ScanSettings(seed=1), frame_index=0)
    pixels = detect_corners(frame.texture, board.inner_corners)
    assert pixels.shape == (88, 2)
    points = corner_points(frame.points_m(), pixels)
    errors = positioning_errors_mm(camera, points, scene_chessboard_corners(board))
    assert np.isfinite(errors).all()
    assert errors.max() < 0.6  # mm, the simulated PhoXi L at 1.6 m
    # each true corner is found once
    nearest = np.argmin(
        np.linalg.norm(transform_points(camera, points)[:, None] - scene_chessboard_corners(board)[None], axis=2),
        axis=1,
    )
    assert len(set(nearest.tolist())) == 88


def test_tool_rotation_faces_the_point_also_straight_down():
    from agiprobot_measurement.calibration.simulation import tool_rotation

    for towards in ([0.3, 0.2, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 2.0]):
        rotation = tool_rotation(np.array(towards), np.zeros(3))
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        np.testing.assert_allclose(rotation[:, 2], np.array(towards) / np.linalg.norm(towards), atol=1e-12)
    with pytest.raises(ValueError, match="coincides"):
        tool_rotation(np.ones(3), np.ones(3))
