"""The original calibration's Code API, ROS-free part (``calibration.original.utils`` / ``.calibration``): names,
inputs and outputs as the design note documents them, on the project's implementation; circle_fitting on a PLY the
simulated PhoXi rendered."""

import math

import numpy as np
import pytest

from agiprobot_measurement.calibration.config import load_calibration_config, tool_rotation
from agiprobot_measurement.calibration.original import calibration as cal
from agiprobot_measurement.calibration.original import utils
from agiprobot_measurement.calibration.registration import CalibrationError, pose_error, read_data_file
from agiprobot_measurement.common.geometry import rpy_to_matrix, transform_points
from agiprobot_measurement.sensors.phoxi.point_cloud_io import write_ply


def _truth() -> np.ndarray:
    h = np.eye(4)
    h[:3, :3] = rpy_to_matrix([0.2, -0.1, 2.5])
    h[:3, 3] = [-0.4, 1.2, 0.9]
    return h


def _pairs(count=10, noise_m=0.0, seed=0):
    rng = np.random.default_rng(seed)
    p_camera = rng.uniform([-0.3, -0.2, 1.0], [0.3, 0.2, 1.5], (count, 3))
    return transform_points(_truth(), p_camera) + rng.normal(0.0, noise_m, (count, 3)), p_camera


def _write_pairs(path, p_robot, p_camera, flags=4):
    for k in range(len(p_robot)):
        pose = [*p_robot[k].tolist(), 0.0, 0.0, 0.0, 1.0]  # the original's 7-value robot pose
        index = f"flag{k}_17330000{k:02d}0_5" if k < flags else f"17330000{k:02d}0_5"
        utils.write_data(path, [pose, p_camera[k].tolist()], index, type="point_pair")


def test_point_pairs_and_matrices():
    pp = utils.PointPair([1.0, 2.0, 3.0], [4.0, 5.0, 6.0])
    assert (pp.p_robot, pp.p_camera, pp.index) == ([1.0, 2.0, 3.0], [4.0, 5.0, 6.0], 999)
    p_robot, p_camera = _pairs(5)
    pairs = [utils.PointPair(r, c, k) for k, (r, c) in enumerate(zip(p_robot, p_camera, strict=True))]
    cam_mat, rob_mat = utils.pp2mat(pairs)
    assert isinstance(cam_mat, np.matrix) and cam_mat.shape == (4, 5)
    np.testing.assert_allclose(cam_mat[:3].T, p_camera)
    np.testing.assert_allclose(rob_mat[3], np.ones((1, 5)))
    np.testing.assert_allclose(_truth() @ np.asarray(cam_mat), rob_mat, atol=1e-12)  # the H the solvers look for


def test_write_read_and_point_pair_list(tmp_path, capsys):
    path = tmp_path / "data.txt"
    p_robot, p_camera = _pairs(6)
    _write_pairs(path, p_robot, p_camera)
    utils.write_data(path, 1200, "criteria:plane", type="criteria")
    utils.write_data(path, 90, "circle:line", type="criteria")  # the seed's key
    utils.write_data(path, _truth(), "H_coarse", type="mat")
    text = path.read_text()
    assert text.startswith("p_robot 6-DoF index:flag0_17330000000_5\n")
    assert "criteria:plane\n1200\n\n \n" in text
    robots, cameras = utils.read_data(path, "piont_pair")  # the design note's spelling
    np.testing.assert_allclose(robots, p_robot)
    np.testing.assert_allclose(cameras, p_camera)
    assert utils.read_data(path, "criteria") == [1200, 90]
    np.testing.assert_allclose(utils.read_data(path, "H"), _truth(), atol=1e-15)
    pairs = utils.get_point_pair_list(path)
    assert [pp.index for pp in pairs] == list(range(6))
    np.testing.assert_allclose(pairs[2].p_camera, p_camera[2])
    utils.print_point_pair_list(pairs[:2])
    assert capsys.readouterr().out.count("r:[") == 2
    with pytest.raises(CalibrationError, match="type must be"):
        utils.write_data(path, 1, "x", type="nonsense")
    with pytest.raises(CalibrationError, match="p_robot needs 3 or 7 values"):
        utils.write_data(path, [[1.0, 2.0], [1.0, 2.0, 3.0]], "1_0", type="point_pair")
    assert utils.read_data(_empty(tmp_path), "criteria") is None


def _empty(tmp_path):
    path = tmp_path / "empty.txt"
    path.write_text("")
    return path


def test_target_file(tmp_path):
    path = tmp_path / "target.txt"
    path.write_text("[-0.3, 0.73, 0.39]\n[-0.52, 0.2, 0.17]\n[-0.74, 0.58, 0.29]\n[-0.37, 0.82, 0.23]\n")
    assert utils.read_data(path, "target")[1] == [-0.52, 0.2, 0.17]
    path.write_text("[0, 0, 0]\n[1, 0, 0]\n[0, 1, 0]\n[1, 1, 0]\n")
    with pytest.raises(CalibrationError, match="coplanar"):
        utils.read_data(path, "target")


def test_draws_and_the_determinant_check():
    p_robot, p_camera = _pairs(8)
    pairs = [utils.PointPair(r, c) for r, c in zip(p_robot, p_camera, strict=True)]
    cam, rob = utils.point_valid_check(pairs, num_list=[0, 1, 2, 3])
    assert cam.shape == (4, 4) and rob.shape == (4, 4)
    flat = [utils.PointPair(c, c) for c in ([0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1])]
    assert utils.point_valid_check(flat) is False
    assert utils.point_valid_check(flat + flat[:1]) is not False  # only 4 pairs are checked, as documented
    cam, rob = utils.get_rand_list(pairs)
    assert cam.shape == (4, 4)
    cam, _ = utils.get_rand_list(pairs, num_points=6)
    assert cam.shape == (4, 6)
    cam, _ = utils.get_rand_list(pairs, exact_list=[7, 6, 5, 4])
    np.testing.assert_allclose(cam[:3, 0].T, [p_camera[7]])
    assert utils.get_rand_list(flat) is False  # every draw coplanar: gives up after 10
    with pytest.raises(CalibrationError, match="at least 4"):
        utils.get_rand_list(pairs, num_point=3)


def test_solvers_ransac_and_calibrate(tmp_path):
    p_robot, p_camera = _pairs(12, noise_m=0.0002)
    p_robot[5] += [0.05, 0.0, 0.0]  # a wrong detection
    pairs = [utils.PointPair(r, c, k) for k, (r, c) in enumerate(zip(p_robot, p_camera, strict=True))]
    cam, rob = utils.pp2mat(pairs[:4])
    h_dlm = cal.get_calibrate(4)(rob, cam)
    assert isinstance(h_dlm, np.matrix)
    h_svd = cal.get_calibrate(6)(*utils.pp2mat([pairs[k] for k in (0, 1, 2, 3, 4, 6)])[::-1])
    np.testing.assert_allclose(np.linalg.det(np.asarray(h_svd)[:3, :3]), 1.0, atol=1e-12)
    assert cal.get_calibrate(3) is False
    h, error = cal.ransac(pairs, num_point=4, max_iteration=300)
    t_mm, r_deg = pose_error(np.asarray(h), _truth())
    assert t_mm < 1.5 and r_deg < 0.05  # the camera origin lies 1.2 m beyond the points: 0.2 mm noise grows
    inliers = [pp for pp in pairs if pp.index != 5]
    h_inliers = cal.get_calibrate(11)(*utils.pp2mat(inliers)[::-1])
    np.testing.assert_allclose(h, h_inliers, atol=1e-9)  # the wrong detection has no say
    residuals = np.linalg.norm(transform_points(np.asarray(h), p_camera) - p_robot, axis=1)
    assert error == pytest.approx(math.sqrt(np.mean(residuals**2)))  # RMS over all pairs, the outlier included
    assert 0.05 / math.sqrt(12) * 0.9 < error < 0.05 / math.sqrt(12) * 1.1
    np.testing.assert_allclose(cal.pose_diff(h, h), np.eye(4), atol=1e-12)
    with pytest.raises(CalibrationError, match="num_point=5"):
        cal.ransac(pairs, num_point=5)
    path = tmp_path / "data.txt"
    _write_pairs(path, p_robot, p_camera)
    h_file, error_file = cal.calibrate(str(path), num_point=4, max_iteration=300)
    np.testing.assert_allclose(h_file, h, atol=1e-12)
    assert error_file == pytest.approx(error)
    trans, rot = utils.H2trans_rot(h_file)
    np.testing.assert_allclose(trans, _truth()[:3, 3], atol=5e-4)
    np.testing.assert_allclose(rpy_to_matrix(rot), _truth()[:3, :3], atol=1e-3)
    with pytest.raises(CalibrationError, match="at least 4"):
        cal.calibrate(_write_three(tmp_path))


def _write_three(tmp_path):
    path = tmp_path / "three.txt"
    p_robot, p_camera = _pairs(3)
    _write_pairs(path, p_robot, p_camera, flags=3)
    return path


def test_criteria_are_written_by_flag_points_and_judge_the_rest(tmp_path, capsys):
    path = tmp_path / "data.txt"
    with pytest.raises(CalibrationError, match="no criteria yet"):
        cal.circle_feasibility_exam(path, "1733_0", 100, 10)
    assert cal.circle_feasibility_exam(path, "flag0_1733", 4000, 200)
    assert cal.circle_feasibility_exam(path, "flag1_1733", 2000, 120)
    assert utils.read_data(path, "criteria") == [2000, 120]  # the smallest flag point
    assert cal.circle_feasibility_exam(path, "1733_1", 1500, 60)  # 0.75 x 2000, 0.5 x 120
    assert not cal.circle_feasibility_exam(path, "1733_2", 1499, 60)
    assert "1499 points on the flange plane" in capsys.readouterr().out
    assert not cal.circle_feasibility_exam(path, "1733_3", 1500, 59)
    assert cal.circle_feasibility_exam(path, "1733_4", None, 60)  # not counted: not checked


# ----------------------------------------------------------------------------- circle fitting on a saved cloud
@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    """PLY files of the simulated PhoXi (low resolution): the flange at two flag points, and out of view."""
    from agiprobot_measurement.calibration.registration import read_flag_points
    from agiprobot_measurement.calibration.simulation import SimulatedStation, nominal_camera_pose
    from agiprobot_measurement.sensors.phoxi.renderer import ScanSettings, SceneGeometry
    from agiprobot_measurement.station import CONFIG_DIR

    folder = tmp_path_factory.mktemp("shots")
    config = load_calibration_config()
    sim = SimulatedStation(nominal_camera_pose(), scene_path=CONFIG_DIR / "calibration_scene.yaml")
    flags = read_flag_points(config["flag_points_file"])
    rotation = tool_rotation(config["tool_z_towards_m"], flags[0])
    camera_from_base = np.linalg.inv(sim.camera_in_base)
    out = {"truth": [transform_points(camera_from_base, [p])[0] for p in (flags[0], flags[2])], "names": []}
    poses = [sim.joints_for(flags[0], rotation), sim.joints_for(flags[2], rotation), sim.station.named_states["up"]]
    for k, q in enumerate(poses):
        geometry = SceneGeometry.concatenate([sim.scene, sim.robot.posed(sim.link_poses(np.asarray(q, dtype=float)))])
        frame = sim.scanner.capture(geometry, sim.camera_pose_world, ScanSettings(resolution=0), frame_index=k)
        points = frame.points_m().reshape(-1, 3)
        name = folder / f"im17330000{k}0_5"
        write_ply(f"{name}.ply", points[frame.valid.reshape(-1)], comments=("units: metres",))
        out["names"].append(str(name))
    out["folder"] = folder
    return out


def test_circle_fitting_on_saved_point_clouds(shots):
    first, second, empty = shots["names"]
    centre = cal.circle_fitting(first, "flag0_17330000000_5", need_judge=False)
    assert isinstance(centre, list) and len(centre) == 3
    assert np.linalg.norm(np.array(centre) - shots["truth"][0]) < 0.0005
    data = shots["folder"] / "data.txt"  # next to the clouds, as the original's data_path
    criteria = utils.read_data(data, "criteria")
    assert criteria is not None and criteria[0] > 1000 and criteria[1] > 50
    centre = cal.circle_fitting(second, "17330000010_5", need_judge=True)
    assert np.linalg.norm(np.array(centre) - shots["truth"][1]) < 0.0005
    assert cal.circle_fitting(empty, "17330000020_5", need_judge=True) is False
    assert cal.circle_fitting(second + ".ply", 7, need_judge=False) == centre  # a full name works too
    assert len(read_data_file(data).samples) == 0  # criteria only: circle_fitting writes no pairs


def test_circle_fitting_reads_millimetre_clouds_and_refuses_missing_ones(shots, tmp_path):
    from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply

    vertices = read_ply(shots["names"][0] + ".ply")
    points_mm = np.column_stack([vertices["x"], vertices["y"], vertices["z"]]) * 1000.0
    write_ply(tmp_path / "mm.ply", points_mm, comments=("units: millimetres",))
    centre = cal.circle_fitting(str(tmp_path / "mm"), 1, need_judge=False)
    assert np.linalg.norm(np.array(centre) - shots["truth"][0]) < 0.0005
    with pytest.raises(CalibrationError, match="point cloud not found"):
        cal.circle_fitting(str(tmp_path / "missing"), 1)
    (tmp_path / "broken.ply").write_text("not a ply")
    with pytest.raises(CalibrationError, match="not a readable PLY"):
        cal.circle_fitting(str(tmp_path / "broken"), 1, need_judge=False)
