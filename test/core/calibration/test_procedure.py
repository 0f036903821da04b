"""The calibration procedures without ROS: the whole collection and the test mode on the simulated station (PhoXi
rendered at a hidden, perturbed camera pose), and the procedure's branches (operator, unreachable points, bad input)
on cheap doubles (a point robot and a camera that sees a synthetic flange disc)."""

import os
import stat

import numpy as np
import pytest
import yaml

from agiprobot_measurement.calibration.config import load_calibration_config
from agiprobot_measurement.calibration.interfaces import CameraFrame, StepError, UnreachableError
from agiprobot_measurement.calibration.procedure import (
    auto_judge,
    detection_question,
    run_collection,
    run_test_mode,
)
from agiprobot_measurement.calibration.registration import (
    CalibrationError,
    plane_basis,
    pose_error,
    read_data_file,
    read_flag_points,
    write_result_yaml,
)
from agiprobot_measurement.calibration.session import CalibrationSession, zigzag_for
from agiprobot_measurement.calibration.simulation import (
    SimulatedStation,
    nominal_camera_pose,
    perturbed_pose,
    simulated_robot_and_camera,
)
from agiprobot_measurement.common.geometry import transform_points
from agiprobot_measurement.station import CONFIG_DIR

SHORT_PATH = {"fractions": [0.5], "jitter_m": 0.03, "seed": 0}  # one point per pair of flag points: 6 frames


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.fixture
def umask_022():
    previous = os.umask(0o022)
    yield
    os.umask(previous)


# --------------------------------------------------------------------------- the simulated station, end to end
@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """One cal_fine collection on the simulated station (collision checks on, as the node's default), kept for the
    test-mode test: the station, its robot and camera, the config, the outcome, the judge's questions, the files."""
    previous = os.umask(0o022)
    try:
        rng = np.random.default_rng(7)
        truth_pose = perturbed_pose(nominal_camera_pose(), rng, 0.02, np.radians(1.0))
        sim = SimulatedStation(truth_pose, noise_seed=3, scene_path=CONFIG_DIR / "calibration_scene.yaml")
        sim.scanner.workers = 2
        config = load_calibration_config()
        config["zigzag"] = dict(SHORT_PATH)
        robot, camera = simulated_robot_and_camera(sim, config["tool_z_towards_m"], check_collisions=True)
        out = tmp_path_factory.mktemp("calibration") / "results"  # missing: the writers create it
        result_file = out / "calibration_result.yaml"
        session = CalibrationSession.from_config(config, out / "calibration_data.txt")
        questions, published = [], []

        def judge(what, detection, expected_camera_m):
            questions.append(detection_question(what, detection, expected_camera_m))
            return True

        def publish(result, mode):
            published.append(mode)
            write_result_yaml(result_file, result, "base_link", "PhoXi3Dscanner_sensor", mode)

        outcome = run_collection(robot, camera, session, config, judge=judge, publish=publish)
    finally:
        os.umask(previous)
    return {
        "sim": sim,
        "robot": robot,
        "camera": camera,
        "config": config,
        "session": session,
        "outcome": outcome,
        "questions": questions,
        "published": published,
        "result_file": result_file,
    }


def test_collection_on_the_simulated_station_is_accurate(simulated):
    outcome, sim = simulated["outcome"], simulated["sim"]
    assert outcome.mode == "cal_fine" and outcome.flag_points == 4 and outcome.path_points == 6
    assert outcome.accepted >= 5, simulated["session"].listing()
    t_mm, r_deg = pose_error(outcome.result.transform, sim.camera_in_base)
    assert t_mm < 0.3 and r_deg < 0.1, (t_mm, r_deg)  # the rostest's bounds
    coarse_t_mm, _ = pose_error(outcome.coarse.transform, sim.camera_in_base)
    assert coarse_t_mm < 2.0
    assert simulated["published"] == ["cal_coarse", "cal_fine"]
    message = outcome.message(simulated["result_file"])
    assert message.startswith("coarse: 4 flag points, RMS ") and f"fine: {outcome.accepted}/6 path samples" in message
    # the robot really went there: the last motion ended at the last path point
    robot = simulated["robot"]
    last = robot.flange_position(robot.current_joints())
    np.testing.assert_allclose(last, simulated["session"].data.samples[-1].p_robot_m, atol=1e-6)


def test_collection_consults_the_judge_at_every_detection(simulated):
    questions, outcome = simulated["questions"], simulated["outcome"]
    flags = [q for q in questions if q.startswith("flag point")]
    path = [q for q in questions if q.startswith("path point")]
    assert len(flags) == 4 and "coarse prediction" not in flags[0]
    assert len(path) == outcome.accepted and all("mm from the coarse prediction" in q for q in path)


def test_collection_files_are_written_readable(simulated):
    result_file = simulated["result_file"]
    data_file = simulated["session"].data_file
    assert _mode(result_file) == 0o644 and _mode(data_file) == 0o644
    assert len(read_data_file(data_file).samples) == len(simulated["session"].data.samples)
    assert yaml.safe_load(result_file.read_text())["mode"] == "cal_fine"


def test_test_mode_reaches_every_corner(simulated, umask_022):
    robot, sim = simulated["robot"], simulated["sim"]
    outcome = run_test_mode(
        robot,
        simulated["camera"],
        simulated["result_file"],
        simulated["config"],
        sim.station.named_states,
        scene=sim.station.scene,
    )
    assert outcome.success, outcome.message
    summary, corners = outcome.report["summary"], outcome.report["corners"]
    assert summary["corners_detected"] == 88 and summary["corners_reached"] == 88
    assert sorted(c["corner"] for c in corners) == list(range(88))
    assert [c["corner"] for c in corners[9:14]] == [9, 10, 21, 20, 19]  # 8 rows of 11: the second backwards
    errors = np.array([c["positioning_error_mm"] for c in corners])
    assert errors.max() < 1.0  # calibration + corner detection, mm
    assert summary["positioning_error_max_mm"] == pytest.approx(errors.max())
    reached = np.array([c["reached_m"] for c in corners])
    targets = np.array([c["target_m"] for c in corners])
    assert np.abs(reached - targets).max() < 1e-4
    assert np.ptp(reached[:, 0]) + np.ptp(reached[:, 1]) > 0.33
    assert "positioning error against the true corners" in outcome.message
    assert outcome.path == simulated["result_file"].parent / "test_result.yaml" and _mode(outcome.path) == 0o644
    assert yaml.safe_load(outcome.path.read_text())["summary"] == summary
    np.testing.assert_allclose(robot.current_joints(), sim.station.named_states["up"], atol=1e-9)  # back out of view


# ------------------------------------------------------------------------------------------ cheap doubles
RADIUS_M = 0.0315


def _h_base_camera():
    h = np.eye(4)
    c, s = np.cos(2.3), np.sin(2.3)
    h[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.0, -1.0, -1.0])
    h[:3, 3] = [-1.0, 1.1, 1.6]
    return h


class PointRobot:
    """The flange goes exactly where it is asked to; ``unreachable``: positions it refuses."""

    def __init__(self, unreachable=()):
        self.position = np.zeros(3)
        self.unreachable = [np.asarray(p, dtype=float) for p in unreachable]
        self.moves = 0

    def current_joints(self):
        return np.concatenate([self.position, np.zeros(3)])

    def flange_position(self, joints_rad):
        return np.asarray(joints_rad)[:3]

    def move_to(self, position_m, z_towards_m=None, settle_s=0.3, free_yaw=False):
        if any(np.allclose(position_m, p) for p in self.unreachable):
            raise UnreachableError(f"no IK solution for {np.round(position_m, 3).tolist()}")
        self.position = np.asarray(position_m, dtype=float)
        self.moves += 1
        return self.current_joints()

    def move_to_joints(self, joints_rad, what, settle_s=0.3):
        self.position = np.asarray(joints_rad, dtype=float)[:3]


class DiscCamera:
    """Sees a flange disc (radius 31.5 mm, facing the camera, 0.2 mm noise) where the robot has it; ``fail_at``:
    capture numbers that raise a camera StepError."""

    def __init__(self, robot, fail_at=()):
        self.robot, self.fail_at, self.count = robot, set(fail_at), 0
        self.rng = np.random.default_rng(0)

    def capture(self, texture=False):
        self.count += 1
        if self.count in self.fail_at:
            raise StepError("camera: no point cloud after get_frame")
        centre = transform_points(np.linalg.inv(_h_base_camera()), self.robot.position[None])[0]
        normal = -centre / np.linalg.norm(centre)
        g = np.arange(-0.04, 0.04, 0.0008)
        uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
        uv = uv[np.linalg.norm(uv, axis=1) <= RADIUS_M]
        points = centre + uv @ plane_basis(normal) + self.rng.normal(0, 0.0002, (len(uv), 1)) * normal
        return CameraFrame(points)


@pytest.fixture
def config():
    config = load_calibration_config()
    config["zigzag"] = dict(SHORT_PATH)
    return config


def test_collection_with_doubles_recovers_the_transform(config, tmp_path):
    robot = PointRobot()
    session = CalibrationSession.from_config(config, tmp_path / "data.txt")
    outcome = run_collection(robot, DiscCamera(robot), session, config)
    assert outcome.accepted == 6 and robot.moves == 10
    t_mm, r_deg = pose_error(outcome.result.transform, _h_base_camera())
    assert t_mm < 0.3 and r_deg < 0.1


def test_coarse_mode_stops_after_the_flag_points(config):
    config["mode"] = "cal_coarse"
    robot = PointRobot()
    outcome = run_collection(robot, DiscCamera(robot), CalibrationSession.from_config(config, None), config)
    assert outcome.fine is None and robot.moves == 4
    assert outcome.result is outcome.coarse and outcome.message("r.yaml").endswith(", result r.yaml")


def test_operator_rejecting_a_flag_point_stops_the_run(config):
    robot = PointRobot()
    session = CalibrationSession.from_config(config, None)
    asked = []

    def judge(what, detection, expected_camera_m):
        asked.append(what)
        return not what.startswith("flag point 2")

    with pytest.raises(CalibrationError, match="flag point 2 rejected by the operator"):
        run_collection(robot, DiscCamera(robot), session, config, judge=judge)
    assert len(asked) == 3 and not session.data.samples


def test_operator_rejections_and_failed_steps_skip_path_points(config):
    path = zigzag_for(read_flag_points(config["flag_points_file"]), config)
    robot = PointRobot(unreachable=[path[0]])
    camera = DiscCamera(robot, fail_at={6})  # 4 flag frames, path point 0 unreachable: path point 2's frame
    session = CalibrationSession.from_config(config, None)

    def judge(what, detection, expected_camera_m):
        return not what.startswith("path point 3")

    outcome = run_collection(robot, camera, session, config, judge=judge)
    assert outcome.accepted == 3 and outcome.path_points == 6
    reasons = dict(session.rejections)
    assert len(reasons) == 3
    assert any("no IK solution" in r for r in reasons.values())
    assert any("no point cloud" in r for r in reasons.values())
    assert any(w.startswith("path point 3") and r == "rejected by the operator" for w, r in reasons.items())


def test_no_flange_at_a_flag_point_names_it(config):
    class EmptyCamera:
        def capture(self, texture=False):
            return CameraFrame(np.zeros((0, 3)))

    with pytest.raises(CalibrationError, match=r"flag point 0 .*move it so the flange is in view"):
        run_collection(PointRobot(), EmptyCamera(), CalibrationSession.from_config(config, None), config)


def test_bad_mode_and_missing_flag_file(config, tmp_path):
    robot = PointRobot()
    session = CalibrationSession.from_config(config, None)
    for mode in ("test", "fine"):
        with pytest.raises(CalibrationError, match="mode"):
            run_collection(robot, DiscCamera(robot), session, {**config, "mode": mode})
    missing = tmp_path / "flags.txt"
    with pytest.raises(CalibrationError, match="not found"):
        run_collection(robot, DiscCamera(robot), session, {**config, "flag_points_file": str(missing)})
    assert robot.moves == 0


def test_test_mode_needs_a_calibration_and_a_named_capture_state(config, tmp_path):
    robot = PointRobot()
    with pytest.raises(CalibrationError, match="no result file"):
        run_test_mode(robot, DiscCamera(robot), tmp_path / "none.yaml", config, {"up": np.zeros(6)})
    result = tmp_path / "r.yaml"
    result.write_text(yaml.safe_dump({"matrix": np.eye(4).tolist()}))
    config["chessboard"] = {**config["chessboard"], "capture_state": "nowhere"}
    with pytest.raises(CalibrationError, match="'nowhere' is not a named state"):
        run_test_mode(robot, DiscCamera(robot), result, config, {"up": np.zeros(6)})


def test_auto_judge_accepts_and_the_question_names_the_offset():
    from agiprobot_measurement.calibration.flange_detection import FlangeDetection

    detection = FlangeDetection(True, centre_m=np.array([0.1, 0.0, 1.2]), plane_points=900, circle_inliers=80)
    assert auto_judge("flag point 0", detection, None)
    question = detection_question("path point 1", detection, np.array([0.1, 0.002, 1.2]))
    assert question == (
        "path point 1: flange found at [100.0, 0.0, 1200.0] mm (camera frame), 900 points on its plane, "
        "80 circle inliers, 2.0 mm from the coarse prediction"
    )
