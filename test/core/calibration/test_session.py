"""Calibration robustness and session (ROS-free, fast): consistent flag selection, the next disc candidate, non-discs
refused, the session's criteria, sample bookkeeping and the data file rewritten sample by sample."""

import numpy as np
import pytest

from agiprobot_measurement.calibration.config import load_calibration_config
from agiprobot_measurement.calibration.flange_detection import (
    FlangeDetection,
    FlangeDetectorConfig,
    detect_flange,
    detect_flange_candidates,
)
from agiprobot_measurement.calibration.registration import (
    CalibrationError,
    plane_basis,
    read_data_file,
    select_consistent_flags,
)
from agiprobot_measurement.calibration.session import CalibrationSession, detector_config
from agiprobot_measurement.common.geometry import transform_points

RADIUS_M = 0.0315
FLAGS = np.array([[-0.55, 0.25, 0.25], [-0.25, 0.60, 0.30], [-0.40, 0.35, 0.45], [-0.60, 0.55, 0.50]])


def _h():
    h = np.eye(4)
    c, s = np.cos(0.7), np.sin(0.7)
    h[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    h[:3, 3] = [0.3, -0.2, 1.1]
    return h


def _camera(points):
    return transform_points(np.linalg.inv(_h()), points)


def _planar(centre, normal, shape, rng, pitch_m=0.0006, noise_m=0.0002):
    """Points of a disc ("disc") or a 60 x 40 mm plate ("plate") around ``centre`` (metres)."""
    basis = plane_basis(normal)
    g = np.arange(-0.05, 0.05, pitch_m)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2) + rng.uniform(-pitch_m / 2, pitch_m / 2, (len(g) ** 2, 2))
    if shape == "disc":
        uv = uv[np.linalg.norm(uv, axis=1) <= RADIUS_M]
    else:
        uv = uv[(np.abs(uv[:, 0]) <= 0.03) & (np.abs(uv[:, 1]) <= 0.02)]
    return centre + uv @ basis + rng.normal(0, noise_m, (len(uv), 1)) * normal


def test_consistent_flags_pick_the_right_candidates():
    cam = _camera(FLAGS)
    decoy = cam[2] + [0.08, 0.0, 0.0]
    candidates = [[cam[0]], [cam[1] + [0.0, 0.09, 0.0], cam[1]], [decoy, cam[2]], [cam[3]]]
    assert select_consistent_flags(FLAGS, candidates) == [0, 1, 1, 0]


def test_inconsistent_flags_name_the_flag_point():
    cam = _camera(FLAGS)
    cam[3] += [0.0, 0.05, 0.0]  # the wrong disc at flag point 3 only
    with pytest.raises(CalibrationError, match="flag point 3"):
        select_consistent_flags(FLAGS, [[c] for c in cam])
    with pytest.raises(CalibrationError, match="no flange found"):
        select_consistent_flags(FLAGS, [[cam[0]], [], [cam[2]], [cam[3]]])


def test_next_candidate_when_the_nearest_is_not_a_disc():
    rng = np.random.default_rng(7)
    normal = np.array([0.1, -0.2, -1.0])
    normal /= np.linalg.norm(normal)
    centre = np.array([0.05, 0.02, 1.25])
    u = plane_basis(normal)[0]
    plate = _planar(centre - 0.085 * u + 0.01 * normal, normal, "plate", rng)  # nearer the expected centre
    cloud = np.vstack([_planar(centre, normal, "disc", rng), plate])
    det = detect_flange(cloud, FlangeDetectorConfig(crop_radius_m=0.2, max_offset_m=0.1), centre - 0.06 * u)
    assert det.ok, det.reason
    assert np.linalg.norm(det.centre_m - centre) < 2e-4


def test_plate_alone_and_far_disc_are_refused():
    rng = np.random.default_rng(8)
    normal = np.array([0.0, 0.0, -1.0])
    plate = _planar(np.array([0.0, 0.0, 1.2]), normal, "plate", rng)
    found, reason = detect_flange_candidates(plate, FlangeDetectorConfig(), np.array([0.0, 0.0, 1.2]))
    assert not found and reason
    disc = _planar(np.array([0.0, 0.0, 1.2]), normal, "disc", rng)
    det = detect_flange(disc, FlangeDetectorConfig(max_offset_m=0.02), np.array([0.0, 0.05, 1.2]))
    assert not det.ok and "expected centre" in det.reason


def _detection(centre, plane=1000, line=100):
    return FlangeDetection(True, centre_m=np.asarray(centre, float), plane_points=plane, circle_inliers=line)


def test_session_criteria_samples_and_data_file(tmp_path):
    config = load_calibration_config()
    data_file = tmp_path / "data.txt"
    session = CalibrationSession.from_config(config, data_file)
    cam = _camera(FLAGS)
    session.add_flags(FLAGS, [[_detection(c, 1000 + i, 100 + i)] for i, c in enumerate(cam)])
    assert (session.data.criteria_plane, session.data.criteria_line) == (1000, 100)
    assert len(read_data_file(data_file).samples) == 4  # written as they come
    coarse = session.compute("cal_coarse")
    assert np.allclose(coarse.transform, _h(), atol=1e-9)
    assert read_data_file(data_file).h_coarse is not None
    p = np.array([-0.45, 0.4, 0.35])
    assert np.allclose(session.expected_camera_point(p), _camera(p[None])[0])
    ok, reason = session.add_sample(p, _detection(_camera(p[None])[0], plane=700))
    assert not ok and "points on the flange plane" in reason
    ok, reason = session.add_sample(p, FlangeDetection(False, reason="only 0 points in the crop region"))
    assert not ok and "crop region" in reason
    ok, index = session.add_sample(p, _detection(_camera(p[None])[0]))
    assert ok and len(read_data_file(data_file).samples) == 5
    assert "rejected" in session.listing() and index in session.listing()
    assert session.remove("last").index == index
    assert len(read_data_file(data_file).samples) == 4
    with pytest.raises(CalibrationError, match="no sample"):
        session.remove("nope")
    fresh = CalibrationSession.from_config(config, data_file)
    assert fresh.load() == 4


def test_detector_config_from_yaml():
    detector = detector_config(load_calibration_config())
    assert detector.radius_m == pytest.approx(0.0315) and detector.max_candidates == 8
