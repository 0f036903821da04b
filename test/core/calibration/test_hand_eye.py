"""The OpenCV hand-eye peers: the board on the flange, its pose in a rendered frame, the AX = XB solvers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agiprobot_measurement.calibration.config import load_calibration_config, tool_rotation
from agiprobot_measurement.calibration.hand_eye import (
    HAND_EYE_METHODS,
    ROBOT_WORLD_METHODS,
    FlangeBoard,
    detect_board_pose,
    solve_many,
)
from agiprobot_measurement.calibration.registration import CalibrationError, pose_error
from agiprobot_measurement.calibration.simulation import SimulatedStation, nominal_camera_pose
from agiprobot_measurement.motion.kinematics import load_kinematics_correction
from agiprobot_measurement.station import CONFIG_DIR


def _pose(rotvec, xyz):
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    pose[:3, 3] = xyz
    return pose


def _synthetic(count=12, seed=0):
    """Exact eye-to-hand data: camera <- board = (base <- camera)^-1 (base <- tool0) (tool0 <- board)."""
    rng = np.random.default_rng(seed)
    base_camera = _pose([0.3, -2.2, 0.4], [-1.0, 1.1, 1.2])
    tool0_board = _pose([0.0, 0.0, 0.02], [0.004, -0.003, 0.013])
    robot = np.array(
        [_pose(rng.uniform(-0.6, 0.6, 3), rng.uniform([-0.7, 0.2, 0.1], [-0.3, 0.8, 0.4])) for _ in range(count)]
    )
    board = np.linalg.inv(base_camera) @ robot @ tool0_board
    return base_camera, robot, board


def test_every_solver_recovers_the_camera_from_exact_data():
    truth, robot, board = _synthetic()
    (solved,) = solve_many([(robot, board)])
    assert set(solved) == set(HAND_EYE_METHODS + ROBOT_WORLD_METHODS)
    for method, estimate in solved.items():
        t_mm, r_deg = pose_error(estimate, truth)
        assert t_mm < 1e-3 and r_deg < 1e-4, method


def test_solvers_see_a_wrong_frame_convention():
    # passing the robot poses un-inverted (the eye-in-hand convention) must not give the camera back
    truth, robot, board = _synthetic(seed=1)
    (solved,) = solve_many([(np.linalg.inv(robot), board)])
    assert pose_error(solved["TSAI"], truth)[0] > 10.0


def test_bad_input_is_refused():
    _, robot, board = _synthetic(count=5)
    with pytest.raises(CalibrationError, match="robot poses but"):
        solve_many([(robot, board[:4])])
    with pytest.raises(CalibrationError, match="at least 3"):
        solve_many([(robot[:2], board[:2])])
    with pytest.raises(CalibrationError, match="odd sum"):
        FlangeBoard(inner_corners=(6, 8))


@pytest.fixture(scope="module")
def board_station():
    _, correction, _ = load_kinematics_correction()
    station = SimulatedStation(
        nominal_camera_pose(),
        scene_path=CONFIG_DIR / "calibration_scene.yaml",
        board=FlangeBoard(),
        true_kinematics=correction,
    )
    station.scanner.workers = 1
    return station


@pytest.mark.parametrize("roll_deg", [20.0, 200.0])
def test_board_pose_in_a_rendered_frame(board_station, roll_deg):
    # rolled by more than a half turn too: the corner order's ambiguity must be resolved by the board's colours
    cfg = load_calibration_config()
    position = np.array([-0.52, 0.5, 0.3])
    pose = np.eye(4)
    pose[:3, :3] = (
        tool_rotation(cfg["tool_z_towards_m"], position)
        @ Rotation.from_euler("xyz", [15.0, -10.0, roll_deg], degrees=True).as_matrix()
    )
    pose[:3, 3] = position
    q = board_station.joints_placing(pose)
    assert q is not None
    # the true robot (the original's real UR10e) puts the flange at the pose; the nominal model reports it elsewhere
    # (1.8 mm here)
    np.testing.assert_allclose(board_station.true_flange_pose(q), pose, atol=1e-9)
    assert np.linalg.norm(board_station.reported_flange_pose(q)[:3, 3] - position) > 1e-3
    frame = board_station.capture(q, 7)
    found = detect_board_pose(frame.texture, frame.intrinsics.matrix(), board_station.board)
    truth = np.linalg.inv(board_station.camera_in_base) @ pose @ board_station.board.tool0_from_board
    # the board is rendered where the true robot holds it: found within 1 mm there, not where the robot says
    t_mm, r_deg = pose_error(found.camera_from_board, truth)
    assert t_mm < 1.0 and r_deg < 0.5
    assert found.reprojection_rms_px < 0.5


def test_no_board_in_view(board_station):
    frame = board_station.capture(board_station.station.named_states["up"], 3)
    with pytest.raises(CalibrationError):
        detect_board_pose(frame.texture, frame.intrinsics.matrix(), board_station.board)
