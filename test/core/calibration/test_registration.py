"""Flange-based calibration core: circle fit, registration, RANSAC, flag points, data file (ROS-free, fast)."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from agiprobot_measurement.calibration.flange_detection import FlangeDetectorConfig, detect_flange
from agiprobot_measurement.calibration.registration import (
    CalibrationData,
    CalibrationError,
    Sample,
    calibrate,
    calibrate_data,
    check_flag_points,
    direct_linear,
    fit_circle_ransac,
    plane_basis,
    pose_error,
    read_data_file,
    read_flag_points,
    read_result_yaml,
    umeyama,
    write_data_file,
    write_result_yaml,
    zigzag_path,
)
from agiprobot_measurement.common.geometry import transform_points

RADIUS_M = 0.0315


def _transform(seed=1):
    rng = np.random.default_rng(seed)
    h = np.eye(4)
    h[:3, :3] = Rotation.from_rotvec(rng.uniform(-2, 2, 3)).as_matrix()
    h[:3, 3] = rng.uniform(-1.5, 1.5, 3)
    return h


def _pairs(n=22, seed=2, noise_m=0.0):
    rng = np.random.default_rng(seed)
    pc = rng.uniform([-0.3, -0.3, 1.0], [0.3, 0.3, 1.6], (n, 3))
    h = _transform()
    pr = transform_points(h, pc) + rng.normal(0, noise_m, (n, 3))
    return pc, pr, h


def _disc_cloud(centre, normal, rng, pitch_m=0.0006, noise_m=0.0003, clutter=True, cut=False):
    basis = plane_basis(normal)
    g = np.arange(-0.05, 0.05, pitch_m)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2) + rng.uniform(-pitch_m / 2, pitch_m / 2, (len(g) ** 2, 2))
    disc = uv[np.linalg.norm(uv, axis=1) <= RADIUS_M]
    if cut:
        disc = disc[disc[:, 0] < 0.6 * RADIUS_M]  # a third of the flange occluded
    points = centre + disc @ basis + rng.normal(0, noise_m, (len(disc), 1)) * normal
    if clutter:
        ring = uv[(np.linalg.norm(uv, axis=1) > 0.036) & (np.linalg.norm(uv, axis=1) < 0.045)]
        behind = centre - 0.0055 * normal + ring @ basis  # the wrist's end face behind the flange
        spray = centre + rng.uniform(-0.08, 0.08, (300, 3))  # isolated outliers
        points = np.vstack([points, behind, spray])
    return points


@pytest.mark.parametrize("cut", [False, True])
def test_circle_fit_on_noisy_disc_with_clutter(cut):
    rng = np.random.default_rng(3)
    centre = np.array([0.1, -0.05, 1.3])
    normal = np.array([0.2, -0.3, -1.0])
    normal /= np.linalg.norm(normal)
    det = detect_flange(_disc_cloud(centre, normal, rng, cut=cut), FlangeDetectorConfig(), centre + 0.01)
    assert det.ok, det.reason
    # full disc: within 0.1 mm; a third of it occluded (the chord's ends touch the circle): within 0.2 mm
    assert np.linalg.norm(det.centre_m - centre) * 1000.0 < (0.2 if cut else 0.1)
    assert det.radius_m == pytest.approx(RADIUS_M, abs=0.001)


def test_no_flange_in_view_is_rejected_with_reason():
    rng = np.random.default_rng(4)
    cloud = rng.uniform(-0.1, 0.1, (5000, 3)) + np.array([0, 0, 1.2])  # clutter only
    det = detect_flange(cloud, FlangeDetectorConfig(), np.array([0.0, 0.0, 1.2]))
    assert not det.ok and det.reason
    det = detect_flange(np.zeros((10, 10, 3)))
    assert not det.ok and "no flange in view" in det.reason


def test_circle_ransac_rejects_clutter():
    rng = np.random.default_rng(5)
    a = rng.uniform(0, 2 * math.pi, 300)
    ring = np.column_stack([np.cos(a), np.sin(a)]) * RADIUS_M + [0.01, 0.02]
    points = np.vstack([ring, rng.uniform(-0.05, 0.05, (150, 2))])
    fit = fit_circle_ransac(points, RADIUS_M, 0.0003)
    assert np.linalg.norm(fit.centre - [0.01, 0.02]) < 1e-5  # 0.01 mm: a few clutter points lie in the band
    assert fit.inliers[:300].all()


def test_exact_without_noise_direct_and_umeyama():
    pc, pr, h = _pairs()
    assert np.allclose(direct_linear(pc[:4], pr[:4]), h, atol=1e-9)
    assert np.allclose(umeyama(pc, pr), h, atol=1e-12)
    result = calibrate(pc, pr)
    assert np.allclose(result.transform, h, atol=1e-12)
    assert result.inliers.all() and result.rms_mm < 1e-6


def test_umeyama_keeps_a_proper_rotation():
    pc, pr, _ = _pairs(n=6, noise_m=0.05)
    pr[:, 2] *= -1.0  # a mirrored configuration: the best orthogonal fit would be a reflection
    assert np.linalg.det(umeyama(pc, pr)[:3, :3]) == pytest.approx(1.0)


def test_ransac_rejects_planted_outliers():
    pc, pr, h = _pairs(n=30, noise_m=0.00005)
    planted = [3, 11, 17, 25, 28, 29]
    pr[planted] += np.random.default_rng(6).choice([-1, 1], (6, 3)) * 0.004
    result = calibrate(pc, pr)
    assert set(result.rejected) == set(planted)
    t_mm, r_deg = pose_error(result.transform, h)
    assert t_mm < 0.2 and r_deg < 0.01
    assert "REJECTED" in result.report()


def test_four_flag_points_work():
    pc, pr, h = _pairs(n=4)
    result = calibrate(pc, pr)
    assert result.draws == 1
    assert np.allclose(result.transform, h, atol=1e-9)


def test_coplanar_flag_points_give_a_clear_error(tmp_path):
    points = [[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0.3, 0.3, 0.002]]
    with pytest.raises(CalibrationError, match="coplanar"):
        check_flag_points(np.array(points))
    path = tmp_path / "flags.txt"
    path.write_text("\n".join(str(p) for p in points) + "\n")
    with pytest.raises(CalibrationError, match="coplanar"):
        read_flag_points(path)


def test_flag_file_bad_input(tmp_path):
    with pytest.raises(CalibrationError, match="not found"):
        read_flag_points(tmp_path / "missing.txt")
    path = tmp_path / "three.txt"
    path.write_text("[0, 0, 0]\n[1, 0, 0]\n[0, 1, 0]\n")
    with pytest.raises(CalibrationError, match="at least 4"):
        read_flag_points(path)
    path.write_text("[0, 0, 0]\n[1, 0]\n")
    with pytest.raises(CalibrationError, match=r"three.txt:2"):
        read_flag_points(path)


def test_zigzag_path():
    flags = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    path = zigzag_path(flags, seed=7)
    assert path.shape == (18, 3)
    plain = zigzag_path(flags, jitter_m=0.0)
    assert np.allclose(plain[:3], [[0.25, 0, 0], [0.5, 0, 0], [0.75, 0, 0]])
    assert np.abs(path - plain).max() <= 0.03
    assert np.array_equal(path, zigzag_path(flags, seed=7))


def test_data_file_round_trip_and_recalibration(tmp_path):
    pc, pr, h = _pairs(n=12, noise_m=0.0001)
    data = CalibrationData(
        samples=[Sample(f"{1544627186 + i}_{i:012d}", pr[i], pc[i], flag=i < 4) for i in range(12)],
        h_coarse=h,
        criteria_plane=1234,
        criteria_line=321,
    )
    path = write_data_file(tmp_path / "data.txt", data)
    back = read_data_file(path)
    assert [s.index for s in back.samples] == [s.index for s in data.samples]
    assert [s.flag for s in back.samples] == [s.flag for s in data.samples]
    assert np.array_equal(back.arrays()[0], pc) and np.array_equal(back.arrays()[1], pr)
    assert np.array_equal(back.h_coarse, h)
    assert (back.criteria_plane, back.criteria_line) == (1234, 321)
    fine, again = calibrate_data(data), calibrate_data(back)
    assert np.array_equal(fine.transform, again.transform)
    coarse = calibrate_data(back, "cal_coarse")
    assert len(coarse.inliers) == 4
    out = write_result_yaml(tmp_path / "result.yaml", fine, "base_link", "camera", "cal_fine")
    assert np.allclose(read_result_yaml(out), fine.transform)


def test_data_file_errors(tmp_path):
    with pytest.raises(CalibrationError, match="not found"):
        read_data_file(tmp_path / "none.txt")
    path = tmp_path / "bad.txt"
    path.write_text("p_robot 3-DoF index:1_2\n[0.1, 0.2]\n")
    with pytest.raises(CalibrationError, match=r"bad\.txt:2"):
        read_data_file(path)
    path.write_text("p_robot 3-DoF index:1_2\n[0.1, 0.2, 0.3]\n")
    with pytest.raises(CalibrationError, match="no p_camera"):
        read_data_file(path)


def test_unreadable_data_files_name_the_problem(tmp_path):
    # binary bytes used to give only "'utf-8' codec can't decode byte 0x80"
    binary = tmp_path / "calibration_data.txt"
    binary.write_bytes(b"p_robot\x80\x81\x00 binary")
    with pytest.raises(CalibrationError, match=r"calibration_data\.txt: the data file is not UTF-8 text \(byte 0x80"):
        read_data_file(binary)
    with pytest.raises(CalibrationError, match="data file is a directory"):
        read_data_file(tmp_path)
    with pytest.raises(CalibrationError, match="data file not found"):
        read_data_file(tmp_path / "missing.txt")
    with pytest.raises(CalibrationError, match="calibration result is not UTF-8"):
        read_result_yaml(binary)
    bomb = tmp_path / "result.yaml"
    bomb.write_text("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"l{i}: &l{i} [" + ", ".join([f"*{'a' if i == 0 else f'l{i - 1}'}"] * 10) + "]\n" for i in range(9)
    ))  # fmt: skip
    with pytest.raises(CalibrationError, match="expands to more than"):
        read_result_yaml(bomb)
