"""Simulated structured-light scanner: models, noise model on a plane, shadows, texture, robot in the scene."""

import math
from dataclasses import replace

import numpy as np
import pytest

from agiprobot_measurement.common.geometry import look_at, matrix_to_rpy
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.sensors.phoxi.device import load_camera_config
from agiprobot_measurement.sensors.phoxi.models import (
    RESOLUTION_HIGH,
    RESOLUTION_LOW,
    load_scanner_model,
    load_scanner_models,
)
from agiprobot_measurement.sensors.phoxi.renderer import (
    ScanSettings,
    StructuredLightScanner,
    depth_sigma_mm,
    rgb_texture,
)
from agiprobot_measurement.sensors.phoxi.scene_geometry import (
    RobotGeometry,
    SceneGeometry,
    primitive_mesh,
    scene_geometry,
)
from agiprobot_measurement.station import ConfigError
from agiprobot_measurement.station.urdf_model import UrdfModel


def translation(x=0.0, y=0.0, z=0.0):
    pose = np.eye(4)
    pose[:3, 3] = [x, y, z]
    return pose


def wall_at(depth_m, albedo=0.8, size=3.0, pose=None):
    """A thin box whose face towards the camera (at the origin, looking along +z) lies at ``depth_m``."""
    thickness = 0.01
    box = SceneGeometry.from_trimesh(primitive_mesh("box", [size, size, thickness]), "wall", albedo)
    placed = box.transformed(translation(z=depth_m + thickness / 2))
    return placed if pose is None else placed.transformed(pose)


@pytest.fixture(scope="module")
def model_m():
    return load_scanner_model("M")


@pytest.fixture(scope="module")
def scanner_m(model_m):
    return StructuredLightScanner(model_m)


# ------------------------------------------------------------------------------------------------ models
def test_models_carry_the_makers_figures():
    models = load_scanner_models()
    assert set(models) >= {"S", "M", "L"}
    m = models["M"]
    assert m.scanning_range_mm == (458.0, 1118.0) and m.sweet_spot_mm == 650.0 and m.baseline_mm == 350.0
    high, low = m.intrinsics(RESOLUTION_HIGH), m.intrinsics(RESOLUTION_LOW)
    assert (high.width, high.height, low.width, low.height) == (2064, 1544, 1032, 772)
    # the image spans the scanning area's width at the sweet spot
    half_width_mm = (high.width / 2) / high.fx * m.sweet_spot_mm
    assert half_width_mm == pytest.approx(m.scan_area_mm[0] / 2, rel=1e-3)
    # low resolution is 2x2 binning: same field of view, half the focal length in pixels
    assert low.fx == pytest.approx(high.fx / 2)


@pytest.mark.parametrize("name", ["S", "M", "L"])
def test_projector_axis_crosses_the_camera_axis_at_the_sweet_spot(name):
    model = load_scanner_model(name)
    pose = model.projector_pose()
    assert pose[0, 3] == pytest.approx(model.baseline_mm / 1000.0)
    # the projector's z axis from its origin reaches x = 0 at depth sweet_spot
    s = -pose[0, 3] / pose[0, 2]
    assert s * pose[2, 2] == pytest.approx(model.sweet_spot_mm / 1000.0)
    np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)


def test_unknown_model_and_bad_file_name_the_problem(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown PhoXi model 'XXL'.*S, M, L"):
        load_scanner_model("XXL")
    bad = tmp_path / "models.yaml"
    bad.write_text(
        "resolutions: {high: [2064, 1544], low: [1032, 772]}\n"
        "models:\n  Q: {scanning_range_mm: [500, 400], sweet_spot_mm: 450, scan_area_mm: [1, 1],"
        " baseline_mm: 1, projector_fov_deg: [40, 30], temporal_noise_mm: 0.1}\n"
    )
    with pytest.raises(ConfigError, match=r"models\.Q.*scanning_range_mm"):
        load_scanner_models(bad)


def test_camera_config_places_the_sensor_looking_at_the_work_area():
    config = load_camera_config()
    assert config.parent_frame == "world"
    z_axis = config.pose[:3, 2]
    to_target = np.array([0.35, -0.45, 1.0]) - config.pose[:3, 3]
    np.testing.assert_allclose(z_axis, to_target / np.linalg.norm(to_target), atol=1e-12)
    assert abs(config.pose[2, 0]) < 1e-12  # image x horizontal
    assert config.pose[2, 1] < 0.0  # image y (rows) points down in the world


def test_look_at_and_rpy_round_trip():
    from agiprobot_measurement.station import rpy_to_matrix

    pose = look_at([1.0, -1.1, 2.2], [0.3, -0.4, 1.0])
    np.testing.assert_allclose(rpy_to_matrix(matrix_to_rpy(pose[:3, :3])), pose[:3, :3], atol=1e-12)
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 2], [0, 0, 0])


# ------------------------------------------------------------------------------------- plane and noise
def test_plane_at_a_known_distance_is_measured_within_the_noise_model(scanner_m, model_m):
    distance_mm = 650.0
    settings = ScanSettings(resolution=RESOLUTION_LOW, seed=3)
    frame = scanner_m.capture(wall_at(distance_mm / 1000.0), np.eye(4), settings, frame_index=0)
    valid = frame.valid
    assert valid.mean() > 0.9, "the projector should light almost the whole image of a plane at the sweet spot"
    points = frame.points_m()[valid].astype(np.float64)
    # least-squares plane through the points: normal along the camera axis, offset at the true distance
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[2] * np.sign(vt[2][2])
    assert math.degrees(math.acos(min(1.0, normal[2]))) < 0.01
    residual_mm = (points - centroid) @ normal * 1000.0
    # the expected sigma per point from the documented model (cosine to the projector, albedo 0.8)
    projector = model_m.projector_pose()[:3, 3]
    to_projector = projector - points
    cos_p = -to_projector[:, 2] / np.linalg.norm(to_projector, axis=1)  # the wall's normal is -z
    expected = depth_sigma_mm(model_m, settings, np.full(len(points), distance_mm), cos_p, 0.8)
    rms_expected = math.sqrt(float(np.mean(expected**2)))
    assert np.std(residual_mm) == pytest.approx(rms_expected, rel=0.03)
    offset_mm = float(centroid[2] * 1000.0 - distance_mm)
    assert abs(offset_mm) < 5.0 * rms_expected / math.sqrt(len(points)) + 1e-3
    # the confidence map is the model's sigma of each point
    np.testing.assert_allclose(frame.confidence[valid], expected, rtol=1e-3)


def test_noise_grows_with_range_and_incidence(scanner_m, model_m):
    settings = ScanSettings(resolution=RESOLUTION_LOW, seed=5)
    near = scanner_m.capture(wall_at(0.6), np.eye(4), settings)
    far = scanner_m.capture(wall_at(1.05), np.eye(4), settings)
    centre = (slice(300, 470), slice(420, 610))
    std_near = np.std(near.depth_mm[centre][near.valid[centre]])
    std_far = np.std(far.depth_mm[centre][far.valid[centre]])
    assert std_far / std_near == pytest.approx((1.05 / 0.6) ** 2, rel=0.1)
    # a plane turned 60 deg about the image's vertical axis at the same centre depth: sigma grows as 1/sqrt(cos)
    turn = np.eye(4)
    angle = math.radians(60.0)
    turn[:3, :3] = [[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]]
    pivot = translation(z=0.65) @ turn @ translation(z=-0.65)
    tilted = scanner_m.capture(wall_at(0.65, pose=pivot), np.eye(4), settings)
    flat = scanner_m.capture(wall_at(0.65), np.eye(4), settings)
    u, v = 515, 385  # the centre pixel sees both planes at 650 mm
    assert tilted.depth_mm[v, u] == pytest.approx(650.0, abs=1.0)
    assert tilted.confidence[v, u] > 1.2 * flat.confidence[v, u]


def test_noise_is_seeded_and_noise_free_depth_is_exact(scanner_m):
    wall = wall_at(0.8)
    a = scanner_m.capture(wall, np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, seed=1), frame_index=4)
    b = scanner_m.capture(wall, np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, seed=1), frame_index=4)
    c = scanner_m.capture(wall, np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, seed=1), frame_index=5)
    np.testing.assert_array_equal(a.depth_mm, b.depth_mm)
    assert not np.array_equal(a.depth_mm, c.depth_mm)
    exact = scanner_m.capture(wall, np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, noise=False))
    np.testing.assert_allclose(exact.depth_mm[exact.valid], 800.0, atol=1e-3)


def test_more_exposure_means_less_noise_and_a_brighter_texture(scanner_m, model_m):
    base = ScanSettings(resolution=RESOLUTION_LOW)
    more = replace(base, scan_multiplier=4, single_pattern_exposure=6)  # 4 scans, 40.96 ms instead of 20.48
    sigma_base = depth_sigma_mm(model_m, base, 650.0, 1.0, 0.8)
    assert depth_sigma_mm(model_m, more, 650.0, 1.0, 0.8) == pytest.approx(sigma_base / math.sqrt(8.0))
    wall = wall_at(0.65, albedo=0.3)
    dim = scanner_m.capture(wall, np.eye(4), base)
    bright = scanner_m.capture(wall, np.eye(4), replace(base, single_pattern_exposure=6))
    assert bright.texture[385, 515] == pytest.approx(2.0 * dim.texture[385, 515], rel=1e-5)


def test_range_limits_and_the_confidence_threshold(scanner_m, model_m):
    too_far = scanner_m.capture(wall_at(1.2), np.eye(4), ScanSettings(resolution=RESOLUTION_LOW))
    assert not too_far.valid.any() and (too_far.texture > 0).all()  # seen by the camera, no depth
    loose = scanner_m.capture(wall_at(0.65), np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, confidence=3.0))
    # sigma varies over the plane with the angle to the projector: a threshold at its median keeps half
    threshold = float(np.median(loose.confidence[loose.valid]))
    strict = scanner_m.capture(wall_at(0.65), np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, confidence=threshold))
    assert strict.valid.sum() == pytest.approx(0.5 * loose.valid.sum(), rel=0.02)
    assert strict.confidence[strict.valid].max() <= threshold
    camera_only = scanner_m.capture(
        wall_at(0.65), np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, camera_only_mode=True)
    )
    assert not camera_only.valid.any() and camera_only.texture.max() > 0


# ---------------------------------------------------------------------------------------------- shadows
def test_a_point_in_the_projectors_shadow_is_invalid(scanner_m, model_m):
    """An occluder at 0.6 m in front of a wall at 0.9 m: the projector (0.35 m to the right of the camera) casts
    its shadow onto the wall at x = -0.175 m, where the camera still sees the wall beside the occluder."""
    wall = wall_at(0.9)
    occluder = SceneGeometry.from_trimesh(primitive_mesh("box", [0.05, 0.05, 0.05]), "occluder", 0.8).transformed(
        translation(z=0.6)
    )
    b = model_m.baseline_mm / 1000.0
    shadow_x = b * (1.0 - 0.9 / 0.6)  # the projector ray through the occluder's centre meets the wall here
    intr = model_m.intrinsics(RESOLUTION_LOW)
    (u_shadow, v), (u_lit, _) = np.round(intr.project(np.array([[shadow_x, 0, 0.9], [-shadow_x, 0, 0.9]]))).astype(int)
    settings = ScanSettings(resolution=RESOLUTION_LOW, noise=False)
    with_occluder = scanner_m.capture(SceneGeometry.concatenate([wall, occluder]), np.eye(4), settings)
    without = scanner_m.capture(wall, np.eye(4), settings)
    assert without.valid[v, u_shadow] and without.depth_mm[v, u_shadow] == pytest.approx(900.0, abs=1e-3)
    assert not with_occluder.valid[v, u_shadow], "a point in the projector's shadow must be invalid"
    # the camera still sees the wall there (ambient light only), and the mirrored point stays lit and valid
    assert 0 < with_occluder.texture[v, u_shadow] < 0.2 * with_occluder.texture[v, u_lit]
    assert with_occluder.valid[v, u_lit] and with_occluder.depth_mm[v, u_lit] == pytest.approx(900.0, abs=1e-3)
    # the occluder itself is measured at 0.575 m (its front face)
    u_c, v_c = np.round(intr.project(np.array([[0.0, 0.0, 0.575]]))[0]).astype(int)
    assert with_occluder.depth_mm[v_c, u_c] == pytest.approx(575.0, abs=1e-3)


def test_outside_the_projectors_field_of_view_is_invalid(model_m):
    narrow = StructuredLightScanner(replace(model_m, projector_fov_deg=(10.0, 10.0)))
    frame = narrow.capture(wall_at(0.65), np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, noise=False))
    assert frame.valid[385, 515] and not frame.valid[385, 50] and not frame.valid[50, 515]
    assert frame.texture[385, 50] > 0


# ------------------------------------------------------------------------------------ normals, texture
def test_normals_face_the_camera_and_texture_follows_lambert(scanner_m):
    frame = scanner_m.capture(wall_at(0.65), np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, noise=False))
    valid = frame.valid
    np.testing.assert_allclose(frame.normals[valid], np.broadcast_to([0, 0, -1], (valid.sum(), 3)), atol=1e-6)
    np.testing.assert_array_equal(frame.normals[~valid], 0.0)
    dark = scanner_m.capture(wall_at(0.65, albedo=0.2), np.eye(4), ScanSettings(resolution=RESOLUTION_LOW, noise=False))
    assert dark.texture[385, 515] == pytest.approx(frame.texture[385, 515] * 0.2 / 0.8, rel=1e-5)


def test_rgb_texture_is_normalised_equalised_grey():
    rng = np.random.default_rng(0)
    texture = (rng.uniform(0.0, 1.0, (120, 160)) ** 3 * 900.0 + 100.0).astype(np.float32)
    rgb = rgb_texture(texture)
    assert rgb.shape == (120, 160, 3) and rgb.dtype == np.uint8
    np.testing.assert_array_equal(rgb[:, :, 0], rgb[:, :, 1])
    np.testing.assert_array_equal(rgb[:, :, 1], rgb[:, :, 2])
    grey = rgb[:, :, 0].astype(int)
    assert grey.max() == 255
    # equalised: the cubic distribution's dark bulk is spread evenly, so the quartiles are evenly spaced (plain
    # min-max scaling would leave them at 4, 32 and 108); brighter texture never gets a darker grey
    q25, q50, q75 = np.percentile(grey, [25, 50, 75])
    assert q75 - q50 > 60 and abs((q75 - q50) - (q50 - q25)) < 10
    order = np.argsort(texture.reshape(-1))
    assert np.all(np.diff(grey.reshape(-1)[order]) >= 0)


# ---------------------------------------------------------------------------------------- the station
@pytest.fixture(scope="module")
def station_render(station):
    config = load_camera_config()
    model = load_scanner_model(config.model)
    kinematics = KinematicModel.from_station(station)
    return {
        "scanner": StructuredLightScanner(model),
        "scene": scene_geometry(station.scene),
        "robot": RobotGeometry(UrdfModel(station.urdf_xml)),
        "kinematics": kinematics,
        "pose": config.pose,
    }


def _robot_at(render, q):
    poses = render["kinematics"].link_poses_batch(np.asarray(q, dtype=float)[None])
    return render["robot"].posed({name: pose[0] for name, pose in poses.items()})


def test_station_frame_shows_the_part_on_its_fixture(station, station_render):
    scanner = station_render["scanner"]
    settings = ScanSettings(resolution=RESOLUTION_LOW, noise=False)
    frame = scanner.capture(station_render["scene"], station_render["pose"], settings)
    points = frame.points_m()[frame.valid]
    world = points @ station_render["pose"][:3, :3].T + station_render["pose"][:3, 3]
    part = station.scene.part.pose[:3, 3]  # the cube's bottom centre (100 mm cube)
    on_top = (np.abs(world[:, 0] - part[0]) < 0.04) & (np.abs(world[:, 1] - part[1]) < 0.04)
    assert on_top.sum() > 500
    np.testing.assert_allclose(world[on_top, 2], part[2] + 0.1, atol=1e-4)


def test_moving_the_robot_changes_the_cloud_where_its_links_are(station_render):
    scanner, pose = station_render["scanner"], station_render["pose"]
    settings = ScanSettings(resolution=RESOLUTION_LOW, noise=False)
    home = np.zeros(6)
    moved = np.array([-0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    frames, robot_only = [], []
    for q in (home, moved):
        robot = _robot_at(station_render, q)
        frames.append(scanner.capture(SceneGeometry.concatenate([station_render["scene"], robot]), pose, settings))
        robot_only.append(scanner.capture(robot, pose, settings))
    silhouettes = [r.texture > 0 for r in robot_only]
    scene_only = scanner.capture(station_render["scene"], pose, settings)
    a, b = frames
    changed = (a.valid != b.valid) | (np.abs(a.depth_mm - b.depth_mm) > 1.0)
    assert changed.sum() > 2000
    # the robot itself, and the projector shadows it casts onto the scene
    shadows = [scene_only.valid & ~f.valid & ~s for f, s in zip(frames, silhouettes, strict=True)]
    expected = silhouettes[0] | silhouettes[1] | shadows[0] | shadows[1]
    assert (changed & ~expected).sum() <= 0.002 * changed.sum(), "the cloud changed away from the robot"
    # where a link moved in and is measured, the cloud shows the link (at its depth) instead of what was behind it
    arrived = silhouettes[1] & ~silhouettes[0] & robot_only[1].valid
    assert arrived.sum() > 2000
    assert np.mean(np.abs(b.depth_mm - robot_only[1].depth_mm)[arrived] < 0.01) > 0.95
    assert np.mean(changed[arrived]) > 0.95


def test_a_scaled_scene_keeps_unit_normals_at_their_directions():
    # e.g. a part in mm put into a scene in metres by a scaling transform: the renderer's incidence and noise read
    # the normals, which must stay unit vectors (a plain rotation of the normals shrank them by the scale)
    scene = SceneGeometry.from_trimesh(primitive_mesh("box", [10.0, 20.0, 30.0]), "box", 0.8)
    turn = np.eye(4)
    turn[:3, :3] = look_at(np.zeros(3), np.array([1.0, 2.0, 3.0]))[:3, :3]
    scaled = turn.copy()
    scaled[:3, :3] *= 0.001
    rotated, shrunk = scene.transformed(turn), scene.transformed(scaled)
    np.testing.assert_allclose(np.linalg.norm(shrunk.normals, axis=1), 1.0)
    np.testing.assert_allclose(shrunk.normals, rotated.normals, atol=1e-12)
    np.testing.assert_allclose(shrunk.triangles, rotated.triangles * 0.001, atol=1e-12)
