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
    from agiprobot_measurement.calibration.config import tool_rotation

    for towards in ([0.3, 0.2, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 2.0]):
        rotation = tool_rotation(np.array(towards), np.zeros(3))
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        np.testing.assert_allclose(rotation[:, 2], np.array(towards) / np.linalg.norm(towards), atol=1e-12)
    with pytest.raises(ValueError, match="coincides"):
        tool_rotation(np.ones(3), np.ones(3))


def test_serpentine_order_reverses_every_other_row():
    from agiprobot_measurement.calibration.chessboard_test import serpentine_order

    order = serpentine_order(12, (3, 4))
    assert order.tolist() == [0, 1, 2, 3, 7, 6, 5, 4, 8, 9, 10, 11]
    assert serpentine_order(5, (3, 4)).tolist() == [0, 1, 2, 3, 4]  # not a full board: detection order


def test_chessboard_truth_of_the_calibration_scene():
    from agiprobot_measurement.calibration.chessboard_test import chessboard_truth
    from agiprobot_measurement.station import CONFIG_DIR, load_scene

    scene = load_scene(CONFIG_DIR / "calibration_scene.yaml")
    truth = chessboard_truth(scene, (8, 11))
    assert truth.corners_base_m.shape == (88, 3)
    assert np.linalg.norm(truth.normal_base) == pytest.approx(1.0)
    np.testing.assert_allclose(truth.nearest_corner(truth.corners_base_m[17] + 0.003), truth.corners_base_m[17])
    assert chessboard_truth(scene, (6, 9)) is None
    assert chessboard_truth(load_scene(CONFIG_DIR / "scene.yaml"), (8, 11)) is None


def test_corner_targets_need_an_organised_cloud(frame_and_board):
    from agiprobot_measurement.calibration.chessboard_test import corner_targets

    frame, _ = frame_and_board
    pixels = detect_corners(frame.texture, (8, 11))
    h = np.eye(4)
    h[:3, 3] = [0.0, 0.0, 2.0]  # camera 2 m above the base: the board normal points up to it
    targets, found, normal = corner_targets(h, frame.points_m(), pixels)
    assert len(found) == 88 and targets.shape == (88, 3)
    assert normal @ (h[:3, 3] - targets.mean(axis=0)) > 0.0
    with pytest.raises(CalibrationError, match="organised point cloud"):
        corner_targets(h, frame.points_m().reshape(-1, 3), pixels)
    with pytest.raises(CalibrationError, match="only 0 of 88 corners"):
        corner_targets(h, np.zeros_like(frame.points_m()), pixels)


def test_test_report_summary_and_message(tmp_path):
    import os
    import stat

    from agiprobot_measurement.calibration import chessboard_test  # by module: pytest would collect test_report

    corners = [
        {"corner": 0, "distance_to_target_mm": 0.01, "positioning_error_mm": 0.2},
        {"corner": 1, "distance_to_target_mm": 0.02, "positioning_error_mm": 0.4},
        {"corner": 2, "error": "no IK solution for [1.0, 0.0, 0.0]"},
    ]
    report = chessboard_test.test_report(corners, 3, 3, 0.02, tmp_path / "r.yaml")
    summary = report["summary"]
    assert summary["corners_reached"] == 2 and summary["positioning_error_max_mm"] == pytest.approx(0.4)
    assert summary["positioning_error_rms_mm"] == pytest.approx(np.sqrt(0.1))
    assert chessboard_test.test_message(report) == (
        "test: 3 corners detected, 3 in 3D, 2 reached; positioning error against the true corners mean 0.300 mm, "
        "max 0.400 mm"
    )
    no_truth = chessboard_test.test_report([{"corner": 0, "distance_to_target_mm": 0.01}], 1, 1, 0.02, "r.yaml")
    assert chessboard_test.test_message(no_truth).endswith(
        "(the scene file has no chessboard: no true corners to compare with)"
    )
    previous = os.umask(0o022)
    try:
        path = chessboard_test.write_test_report(tmp_path / "new" / "test_result.yaml", report)
    finally:
        os.umask(previous)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
