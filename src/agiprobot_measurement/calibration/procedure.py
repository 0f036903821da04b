"""The calibration procedures, ROS-free: the automatic collection (flag points, coarse, zig-zag path, fine) and the
chessboard test mode, over a :class:`~agiprobot_measurement.calibration.interfaces.FlangeRobot` and a
:class:`~agiprobot_measurement.calibration.interfaces.Camera`.

The ROS node runs them on the station's robot and PhoXi, the tests on :mod:`.simulation`'s doubles. The operator's
say on each detection is a :data:`Judge` callback (:func:`auto_judge`, the default, leaves it to the acceptance
criteria); progress goes to a :class:`ProgressLog`; every result is handed to a ``publish`` callback (the node writes
the result YAML and sends the tf). Metres in the robot base / camera frame, joints in rad.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from agiprobot_measurement.calibration.chessboard_test import (
    TEST_RESULT_FILE,
    chessboard_truth,
    corner_targets,
    detect_corners,
    serpentine_order,
    test_message,
    test_report,
    write_test_report,
)
from agiprobot_measurement.calibration.config import check_mode
from agiprobot_measurement.calibration.flange_detection import FlangeDetection, detect_flange, detect_flanges
from agiprobot_measurement.calibration.interfaces import STEP_FAILURES, Camera, FlangeRobot
from agiprobot_measurement.calibration.registration import (
    CalibrationError,
    CalibrationResult,
    read_flag_points,
    read_result_yaml,
)
from agiprobot_measurement.calibration.session import CalibrationSession, check_zigzag, detector_config, zigzag_for

__all__ = [
    "CollectionOutcome",
    "Judge",
    "ProgressLog",
    "Publish",
    "SilentLog",
    "TestOutcome",
    "auto_judge",
    "detection_question",
    "run_collection",
    "run_test_mode",
]

#: ``judge(what, detection, expected_camera_m) -> accept``: the operator's answer on a detection that passed the
#: automatic criteria; ``expected_camera_m`` is the coarse calibration's prediction (None at the flag points)
Judge = Callable[[str, FlangeDetection, "np.ndarray | None"], bool]

#: ``publish(result, mode)``: called with every calibration a run computes (coarse, then fine)
Publish = Callable[[CalibrationResult, str], None]


def auto_judge(what: str, detection: FlangeDetection, expected_camera_m: np.ndarray | None = None) -> bool:
    """No operator: every detection the acceptance criteria pass is accepted."""
    return True


def detection_question(what: str, detection: FlangeDetection, expected_camera_m: np.ndarray | None = None) -> str:
    """What the operator is asked about a detection: where the flange was found (camera frame, mm), its counts
    and, with the coarse prediction, how far from it."""
    centre = np.asarray(detection.centre_m, dtype=float)
    detail = (
        f"{what}: flange found at {np.round(centre * 1000.0, 1).tolist()} mm (camera frame), "
        f"{detection.plane_points} points on its plane, {detection.circle_inliers} circle inliers"
    )
    if expected_camera_m is not None:
        detail += f", {np.linalg.norm(centre - expected_camera_m) * 1000.0:.1f} mm from the coarse prediction"
    return detail


class ProgressLog(Protocol):
    def info(self, message: str) -> None: ...

    def warn(self, message: str) -> None: ...


class SilentLog:
    """A :class:`ProgressLog` that drops everything."""

    def info(self, message: str) -> None:
        pass

    def warn(self, message: str) -> None:
        pass


@dataclass
class CollectionOutcome:
    """What :func:`run_collection` did: the flag points, the coarse result and, in cal_fine, the path and the fine
    result (``accepted`` of ``path_points`` path samples)."""

    mode: str
    flag_points: int
    coarse: CalibrationResult
    fine: CalibrationResult | None = None
    path_points: int = 0
    accepted: int = 0

    @property
    def result(self) -> CalibrationResult:
        """The final calibration (fine when there is one)."""
        return self.fine if self.fine is not None else self.coarse

    def message(self, result_file) -> str:
        text = f"coarse: {self.flag_points} flag points, RMS {self.coarse.rms_mm:.3f} mm"
        if self.fine is None:
            return text + f", result {result_file}"
        fine = self.fine
        return (
            f"{text}; fine: {self.accepted}/{self.path_points} path samples accepted, "
            f"{int(fine.inliers.sum())}/{len(fine.inliers)} inliers, RMS {fine.rms_mm:.3f} mm, result {result_file}"
        )


def run_collection(
    robot: FlangeRobot,
    camera: Camera,
    session: CalibrationSession,
    config: Mapping,
    judge: Judge = auto_judge,
    publish: Publish | None = None,
    log: ProgressLog | None = None,
) -> CollectionOutcome:
    """The automatic collection as ``config['mode']`` says (cal_coarse or cal_fine).

    The flange is moved to every flag point of ``config['flag_points_file']`` and a frame taken; up to 3 disc
    candidates per frame, the combination whose distances agree with the robot's becomes the flag samples (each
    judged), coarse calibration; cal_fine goes on along the zig-zag path (``config['zigzag']``): per point a frame,
    the disc nearest the coarse prediction, judged by the session's criteria and ``judge``; fine calibration. A path
    point the robot cannot reach or the camera fails at is recorded as rejected and skipped.
    Raises :class:`CalibrationError` for bad flag points (file, no flange in view, rejected) and a failed
    calibration, robot/camera errors at a flag point as they come.
    """
    log = log or SilentLog()
    mode = check_mode(config.get("mode", "cal_fine"))
    if mode == "test":
        raise CalibrationError("run_collection: mode test is run_test_mode's")
    detector = detector_config(config)
    flags = read_flag_points(config["flag_points_file"])
    if mode == "cal_fine":  # before the robot moves: a bad value must not cost the flag points' motions
        check_zigzag(config.get("zigzag"))
    session.clear()
    clouds = []
    for i, p in enumerate(flags):
        robot.move_to(p)
        clouds.append(camera.capture().points_m)
        log.info(f"flag point {i + 1}/{len(flags)} taken")
    workers = 2 if config.get("use_mp", False) else 1
    jobs = detect_flanges(clouds, detector, workers=workers, max_results=3)
    for i, (found, reason) in enumerate(jobs):
        if not found:
            raise CalibrationError(f"flag point {i} {flags[i].tolist()}: {reason}; move it so the flange is in view")
    chosen = session.add_flags(flags, [found for found, _ in jobs])
    for i, sample in enumerate(chosen):
        detection = next(d for d in jobs[i][0] if np.allclose(d.centre_m, sample.p_camera_m))
        if not judge(f"flag point {i} {flags[i].tolist()}", detection, None):
            session.clear()
            raise CalibrationError(f"flag point {i} rejected by the operator: move it and run again")
    coarse = session.compute("cal_coarse")
    if publish is not None:
        publish(coarse, "cal_coarse")
    outcome = CollectionOutcome(mode, len(flags), coarse)
    if mode == "cal_coarse":
        return outcome
    path = zigzag_for(flags, config)
    outcome.path_points = len(path)
    for k, p in enumerate(path):
        what = f"path point {k} {np.round(p, 3).tolist()}"
        expected = session.expected_camera_point(p)
        try:
            robot.move_to(p)
            detection = detect_flange(camera.capture().points_m, detector, expected)
        except STEP_FAILURES as exc:
            session.rejections.append((what, str(exc)))
            log.warn(f"{what} skipped: {exc}")
            continue
        # the operator is asked only about detections the criteria would accept
        if detection.ok and not session.judge(detection) and not judge(what, detection, expected):
            session.rejections.append((what, "rejected by the operator"))
            log.warn(f"{what} rejected by the operator")
            continue
        ok, text = session.add_sample(p, detection, what)
        outcome.accepted += ok
        if not ok:
            log.warn(f"{what} rejected: {text}")
    outcome.fine = session.compute("cal_fine")
    if publish is not None:
        publish(outcome.fine, "cal_fine")
    return outcome


@dataclass
class TestOutcome:
    """What :func:`run_test_mode` did: its report (summary + per corner), where it was written, one line on it;
    ``success`` when at least one corner was reached."""

    report: dict
    path: Path
    message: str

    __test__ = False  # not a pytest test class, whatever its name

    @property
    def success(self) -> bool:
        return self.report["summary"]["corners_reached"] > 0


def _vector(values) -> list[float]:
    return [float(v) for v in values]


def run_test_mode(
    robot: FlangeRobot,
    camera: Camera,
    result_file: str | Path,
    config: Mapping,
    named_states: Mapping[str, np.ndarray],
    scene=None,
    log: ProgressLog | None = None,
) -> TestOutcome:
    """Test mode: the robot goes to ``chessboard.capture_state`` (out of the camera's view), a frame is taken, the
    chessboard's inner corners are found in its texture, taken to 3D through the organised cloud and to the base
    frame with the calibration in ``result_file``; the flange is moved to each corner (``chessboard.approach_offset_m``
    above it along the board normal, row by row in a serpentine) and back to the capture state. Writes
    ``test_result.yaml`` next to the result: per corner the pixel, target, reached position and, when the station
    ``scene`` holds the board (the simulated station), the positioning error against its true corner (mm). A corner
    the robot cannot reach is recorded with its error and skipped."""
    log = log or SilentLog()
    result_file = Path(result_file)
    if not result_file.is_file():
        raise CalibrationError(f"test mode needs a calibration: no result file {result_file} (run cal_fine first)")
    h_base_camera = read_result_yaml(result_file)
    board = config.get("chessboard", {}) or {}
    inner = tuple(int(v) for v in board.get("inner_corners", (8, 11)))
    offset = float(board.get("approach_offset_m", 0.02))
    dwell = float(board.get("dwell_s", 0.1))
    capture_state = board.get("capture_state", "up")
    truth = chessboard_truth(scene, inner) if scene is not None else None
    if capture_state:
        if capture_state not in named_states:
            raise CalibrationError(
                f"chessboard.capture_state {capture_state!r} is not a named state ({', '.join(named_states)})"
            )
        robot.move_to_joints(named_states[capture_state], f"named state {capture_state}")
    frame = camera.capture(texture=True)
    pixels = detect_corners(frame.texture, inner)
    targets, found, normal = corner_targets(h_base_camera, frame.organized_m, pixels)
    corners = []
    for k in serpentine_order(len(pixels), inner):
        entry = {"corner": int(k), "pixel": _vector(pixels[k])}
        corners.append(entry)
        if not np.isfinite(targets[k]).all():
            entry["error"] = "no 3D point at this pixel"
            continue
        goal = targets[k] + offset * normal
        entry["target_m"] = _vector(goal)
        try:
            q = robot.move_to(goal, z_towards_m=goal - normal, settle_s=dwell, free_yaw=True)
        except STEP_FAILURES as exc:
            entry["error"] = str(exc)
            log.warn(f"test corner {k}: {exc}")
            continue
        reached = robot.flange_position(robot.current_joints())
        entry["joints_rad"] = _vector(q)
        entry["reached_m"] = _vector(reached)
        entry["distance_to_target_mm"] = float(np.linalg.norm(reached - goal) * 1000.0)
        if truth is not None:
            nearest = truth.nearest_corner(targets[k])
            entry["true_corner_m"] = _vector(nearest)
            true_goal = nearest + offset * truth.normal_base
            entry["positioning_error_mm"] = float(np.linalg.norm(reached - true_goal) * 1000.0)
    if capture_state:
        try:
            robot.move_to_joints(named_states[capture_state], f"named state {capture_state}")
        except STEP_FAILURES as exc:
            log.warn(f"back to {capture_state}: {exc}")
    report = test_report(corners, len(pixels), len(found), offset, result_file)
    path = write_test_report(result_file.parent / TEST_RESULT_FILE, report)
    return TestOutcome(report, path, f"{test_message(report)}; per corner in {path}")
