"""The scanners' error models: configuration, per-device draws and the effects each block must have."""

import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.sensors.acceptance import evaluate_plane, fit_plane, fit_sphere
from agiprobot_measurement.sensors.error_models import (
    LaserErrors,
    PhoxiErrors,
    device_seed,
    load_error_model,
    reconstruct_depth,
    value_noise,
)
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.sensors.laser_line.simulator import LaserLineScannerSimulator, pose_chain_poses
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_LOW, load_scanner_model
from agiprobot_measurement.sensors.phoxi.renderer import ScanSettings, StructuredLightScanner
from agiprobot_measurement.sensors.phoxi.scene_geometry import SceneGeometry, primitive_mesh
from agiprobot_measurement.station import load_scanner_config


@pytest.fixture(scope="module")
def realistic():
    return load_error_model("realistic")


@pytest.fixture(scope="module")
def sensor():
    return SensorModel(load_scanner_config().sensor_parameters)


def test_ideal_is_everything_off_and_realistic_is_not(realistic):
    assert load_error_model("ideal").is_ideal
    assert not realistic.is_ideal
    assert all(realistic.phoxi.values()) and all(realistic.laser.values())
    assert realistic.phoxi["calibration"]["accuracy_mm"] == {"S": 0.05, "M": 0.1, "L": 0.2}
    assert PhoxiErrors.create(load_scanner_model("S"), "x", "ideal") is None


def test_bad_configurations_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="unknown error model"):
        load_error_model("no-such-model")
    bad = tmp_path / "bad.yaml"
    bad.write_text("laser: {noise: {sigma_mm: 0.01, sigma_typo: 1}}\n")
    with pytest.raises(ConfigError, match="sigma_typo"):
        load_error_model(bad)
    bad.write_text("phoxi: {fixed_pattern: {share: 1.5}}\n")
    with pytest.raises(ConfigError, match="share"):
        load_error_model(bad)
    off = tmp_path / "off.yaml"
    off.write_text("phoxi: {calibration: {enabled: false}, edges: {jump_rel: 0.02}}\n")
    model = load_error_model(off)
    assert model.phoxi["calibration"] is None and model.phoxi["edges"]["jump_rel"] == 0.02


def test_device_errors_are_fixed_per_serial(realistic):
    model = load_scanner_model("S")
    a1, a2 = (PhoxiErrors.create(model, "2019-04-011-LC3", realistic) for _ in range(2))
    b = PhoxiErrors.create(model, "2020-01-002-XYZ", realistic)
    assert a1.calibration.focal_scale == a2.calibration.focal_scale
    assert a1.calibration.focal_scale != b.calibration.focal_scale
    assert device_seed("a") == device_seed("a") != device_seed("b")


@pytest.mark.parametrize("name", ["S", "M", "L"])
def test_phoxi_calibration_error_is_scaled_to_the_makers_accuracy(realistic, name):
    model = load_scanner_model(name)
    cal = PhoxiErrors.create(model, "PhoXi3DScanner-sim", realistic).calibration
    intr = model.intrinsics(RESOLUTION_LOW)
    nominal = intr.pixel_rays().astype(float)[::997]
    true = cal.true_rays(intr, model.resolutions[1][0]).astype(float)[::997]
    depths = np.linspace(*model.scanning_range_mm, 4) / 1000.0

    def rms_mm(reconstruct, rays) -> float:
        errors = [reconstruct(nominal, rays * depth, model.projector_pose()) - depth for depth in depths]
        return 1000.0 * float(np.sqrt(np.mean(np.square(errors))))

    settings = realistic.phoxi["calibration"]
    accuracy, share = settings["accuracy_mm"][name], settings["decoding_share"]
    assert rms_mm(cal.reconstruct, true) == pytest.approx(accuracy, rel=0.2)
    # the budget's split: the optics carry sqrt(1 - share^2) of it, the local decoding residual share of it
    optics = replace(cal, decoding=None)
    assert rms_mm(optics.reconstruct, true) == pytest.approx(accuracy * math.sqrt(1.0 - share**2), rel=0.2)
    assert cal.decoding is not None
    residual = replace(cal, projector_pose=model.projector_pose())  # a perfect camera and projector pose
    assert rms_mm(residual.reconstruct, nominal) == pytest.approx(accuracy * share, rel=0.2)
    # the nominal calibration reconstructs exactly what the nominal geometry renders
    exact = reconstruct_depth(nominal, nominal * 0.5, model.projector_pose(), model.projector_pose())
    np.testing.assert_allclose(exact, 0.5, atol=1e-12)


def _wall(depth_m, albedo=0.8, name="wall"):
    box = SceneGeometry.from_trimesh(primitive_mesh("box", [3.0, 3.0, 0.01]), name, albedo)
    pose = np.eye(4)
    pose[2, 3] = depth_m + 0.005
    return box.transformed(pose)


def _small(name="S"):
    """The model with an image 8x smaller per side (same optics): fast frames for tests."""
    return replace(load_scanner_model(name), resolutions={1: (258, 193), 0: (129, 96)})


def test_averaged_phoxi_frames_floor_at_the_calibration_accuracy(realistic):
    model = _small()
    floors = {}
    for name, errors in (("ideal", None), ("realistic", PhoxiErrors.create(model, "PhoXi3DScanner-sim", realistic))):
        scanner = StructuredLightScanner(model, errors=errors)
        settings = ScanSettings(resolution=RESOLUTION_LOW, seed=3)
        frames = np.array([scanner.capture(_wall(0.442), np.eye(4), settings, i).depth_mm for i in range(16)])
        valid = np.all(frames > 0, axis=0)
        floors[name] = float(np.sqrt(np.mean((frames.mean(axis=0)[valid] - 442.0) ** 2)))
    # 16 frames: the random part falls to sigma / 4 ~ 0.013 mm; the calibration error (0.05 mm) stays
    assert floors["ideal"] < 0.4 * 0.05
    assert floors["realistic"] > 0.8 * 0.05


def test_phoxi_material_dark_and_specular_surfaces_drop_out(realistic):
    model = _small()
    shiny = realistic.with_blocks(
        "phoxi", material={**realistic.phoxi["material"], "specular_share": {"default": 0.0, "mirror": 1.0}}
    )
    scanner = StructuredLightScanner(model, errors=PhoxiErrors.create(model, "x", shiny))
    settings = ScanSettings(resolution=RESOLUTION_LOW, noise=False)
    grey = scanner.capture(_wall(0.442, 0.8), np.eye(4), settings).valid.mean()
    dark = scanner.capture(_wall(0.442, 0.01), np.eye(4), settings).valid.mean()
    mirror = scanner.capture(_wall(0.442, 0.8, "mirror"), np.eye(4), settings).valid.mean()
    assert grey > 0.9
    assert dark < 0.05
    assert 0.0 < mirror < grey - 0.01  # the glint around the mirror direction saturates, the rest is dark


def test_phoxi_mixed_pixels_appear_at_depth_edges(realistic):
    model = load_scanner_model("S")
    step = SceneGeometry.concatenate(
        [
            _wall(0.48),
            SceneGeometry.from_trimesh(primitive_mesh("box", [0.1, 3.0, 0.01]), "step", 0.8).transformed(
                np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.425], [0, 0, 0, 1.0]])
            ),
        ]
    )
    settings = ScanSettings(resolution=RESOLUTION_LOW, noise=True, seed=1)
    edges_only = realistic.with_blocks("phoxi", calibration=None, fixed_pattern=None, material=None)
    mixed = {}
    for name, errors in (("ideal", None), ("edges", PhoxiErrors.create(model, "x", edges_only))):
        depth = StructuredLightScanner(model, errors=errors).capture(step, np.eye(4), settings).depth_mm
        inside = depth[depth > 0]
        mixed[name] = int(np.sum((inside > 421.0) & (inside < 479.0)))
    assert mixed["ideal"] == 0
    assert mixed["edges"] > 50


# ------------------------------------------------------------------------------------------------- laser
def _sweep(sim, mesh, pitch=0.25):
    sim.set_target(mesh)
    xs = np.arange(mesh.bounds[0, 0] - 1.0, mesh.bounds[1, 0] + 1.0, pitch)
    poses = np.repeat(np.eye(4)[None], len(xs), axis=0)
    poses[:, 0, 3] = xs
    return sim.profiles(poses)


def _plane(depth, tilt_deg=0.0, size=(40.0, 40.0)):
    box = trimesh.creation.box([size[0], size[1], 2.0])
    box.apply_translation([0.0, 0.0, 1.0])
    a = math.radians(tilt_deg)
    pose = np.eye(4)
    # front face (artefact +z) towards the emitter, tilted about x (in the fan plane)
    pose[:3, :3] = np.array([[1, 0, 0], [0, -math.cos(a), math.sin(a)], [0, -math.sin(a), -math.cos(a)]])
    pose[2, 3] = depth
    box.apply_transform(pose)
    return box, pose


def test_laser_noise_grows_with_incidence_unlike_the_planning_u(realistic, sensor):
    noise_only = realistic.with_blocks("laser", calibration=None, material=None, edges=None, pose_chain=None)
    noise_errors = LaserErrors.create(sensor, noise_only)
    sigma = {}
    for name, errors in (("ideal", None), ("realistic", noise_errors)):
        for tilt in (0.0, 40.0):
            sim = LaserLineScannerSimulator(sensor, points_per_profile=320, seed=2, errors=errors)
            mesh, _ = _plane(182.0, tilt)
            points = np.vstack([p.points_mm for p in _sweep(sim, mesh)])
            sigma[name, tilt] = evaluate_plane(points)["sigma"]
    assert sigma["ideal", 40.0] < sigma["ideal", 0.0]  # the planning figure's |s . n| factor (known, documented)
    assert sigma["realistic", 40.0] > 1.05 * sigma["realistic", 0.0]
    expected = float(noise_errors.sigma_mm(np.array([182.0]), np.array([1.0]), sensor.optimal_standoff)[0])
    assert sigma["realistic", 0.0] == pytest.approx(expected, rel=0.25)


def test_laser_profiles_report_the_error_models_noise_not_the_planning_u(realistic, sensor):
    noise_only = realistic.with_blocks("laser", calibration=None, material=None, edges=None, pose_chain=None)
    errors = LaserErrors.create(sensor, noise_only)
    for tilt in (0.0, 40.0):
        mesh, _ = _plane(182.0, tilt)
        planning = np.concatenate([p.uncertainties_mm for p in _sweep(
            LaserLineScannerSimulator(sensor, points_per_profile=320, seed=2), mesh)])  # fmt: skip
        profiles = _sweep(LaserLineScannerSimulator(sensor, points_per_profile=320, seed=2, errors=errors), mesh)
        reported = np.concatenate([p.uncertainties_mm for p in profiles])
        hits = np.concatenate([p.true_points_mm for p in profiles])
        rays = hits * [0.0, 1.0, 1.0]  # from the emitter at (x, 0, 0): the fan lies in its y-z plane
        normal = np.array([0.0, math.sin(math.radians(tilt)), -math.cos(math.radians(tilt))])
        cosines = np.abs(rays @ normal) / np.linalg.norm(rays, axis=1)
        expected = errors.sigma_mm(hits[:, 2], cosines, sensor.optimal_standoff)
        assert np.allclose(reported, expected, rtol=0.02)
        assert not np.allclose(np.median(reported), np.median(planning), rtol=0.05)


def test_laser_speckle_follows_the_dorsch_law_and_does_not_shrink_as_z_squared(realistic, sensor):
    errors = LaserErrors.create(sensor, realistic)
    noise = realistic.laser["noise"]
    z_opt = sensor.optimal_standoff
    z = np.array([0.8 * z_opt, z_opt, 1.2 * z_opt])
    temporal, speckle = errors.noise_parts_mm(z, np.ones(3), z_opt)
    assert temporal[1] == pytest.approx(noise["sigma_mm"])
    # C lambda / (2 pi sin u_obs sin(theta)) at the optimal standoff, where theta is the triangulation angle alpha
    floor = noise["speckle_contrast"] * noise["wavelength_nm"] * 1e-6 / (2 * math.pi * noise["aperture_sin"])
    assert speckle[1] == pytest.approx(floor / math.sin(sensor.alpha), rel=1e-6)
    assert speckle[0] / speckle[1] > (0.8**2) * 1.02  # the baseline term keeps it above the z^2 law near the head
    assert temporal[0] / temporal[1] == pytest.approx(0.8**2)


def test_laser_speckle_is_static_and_the_rest_temporal(realistic, sensor):
    errors = LaserErrors.create(
        sensor, realistic.with_blocks("laser", calibration=None, material=None, edges=None, pose_chain=None)
    )
    mesh, _ = _plane(182.0)
    runs = []
    for seed in (1, 2):
        sim = LaserLineScannerSimulator(sensor, points_per_profile=320, seed=seed, errors=errors)
        runs.append(np.concatenate([p.points_mm[:, 2] for p in _sweep(sim, mesh)]))
    residuals = [r - r.mean() for r in runs]
    correlation = float(np.corrcoef(*residuals)[0, 1])
    temporal, speckle = errors.noise_parts_mm(np.array([182.0]), np.array([1.0]), sensor.optimal_standoff)
    static_share = float(speckle[0] ** 2 / (speckle[0] ** 2 + temporal[0] ** 2))
    assert correlation == pytest.approx(static_share, abs=0.12)
    field = value_noise(np.random.default_rng(0).uniform(0, 10, (20000, 3)), 0.1, 7)
    assert field.std() == pytest.approx(1.0, rel=0.2)


def test_value_noise_takes_any_device_seed():
    # a serial's seed is any non-negative integer (hashes of serials reach 2^64): the field is defined and fixed
    points = np.random.default_rng(1).uniform(0, 10, (2000, 3))
    small = value_noise(points, 0.5, 7)
    for seed in (2**32 + 5, 2**40, 2**64 - 1):
        field = value_noise(points, 0.5, seed)
        assert np.all(np.isfinite(field)) and np.array_equal(field, value_noise(points, 0.5, seed))
        assert not np.array_equal(field, small)


def test_laser_calibration_error_stays_within_the_linearity_envelope(realistic, sensor):
    errors = LaserErrors.create(sensor, realistic)
    cal = errors.calibration
    z = np.linspace(sensor.minimum_standoff, sensor.maximum_standoff, 50)
    baseline = math.tan(sensor.alpha) * sensor.optimal_standoff
    measured, _ = cal.reconstruct(z, np.zeros_like(z), baseline, sensor.alpha)
    deviation = measured - z
    envelope = realistic.laser["calibration"]["linearity_fso"] * (sensor.maximum_standoff - sensor.minimum_standoff)
    assert 0.3 * envelope < np.abs(deviation).max() <= 1.05 * envelope
    assert abs(deviation.mean()) < 0.5 * envelope


def test_laser_material_and_edges(realistic, sensor):
    errors = LaserErrors.create(sensor, realistic.with_blocks("laser", calibration=None, pose_chain=None))
    sim = LaserLineScannerSimulator(sensor, points_per_profile=320, seed=0, errors=errors)
    mesh, _ = _plane(182.0)
    sim.set_target(mesh)
    lit = sum(len(p) for p in _sweep(sim, mesh))
    sim_dark = LaserLineScannerSimulator(sensor, points_per_profile=320, seed=0, errors=errors)
    sim_dark.set_target(mesh, material={"albedo": 0.005})
    dark = sum(len(p) for p in sim_dark.profiles(np.eye(4)[None]))
    assert lit > 1000 and dark == 0
    # a 10 mm step across the line: mixed points between the two levels
    low, _ = _plane(190.0, size=(20.0, 60.0))
    high = trimesh.creation.box([20.0, 30.0, 10.0])
    high.apply_translation([0.0, 15.0, 185.0])
    points = np.vstack([p.points_mm for p in _sweep(sim, trimesh.util.concatenate([low, high]))])
    between = (points[:, 2] > 181.0) & (points[:, 2] < 189.0)
    assert between.sum() > 10


def test_pose_chain_reports_through_the_nominal_pose(realistic, sensor):
    errors = LaserErrors.create(sensor, realistic.with_blocks("laser", calibration=None, noise=None, edges=None))
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=10.0)
    sphere.apply_translation([0.0, 0.0, 182.0])
    flange = np.repeat(np.eye(4)[None], 81, axis=0)
    flange[:, 0, 3] = np.linspace(-12.0, 12.0, 81)
    true_flange = flange.copy()
    true_flange[:, 1, 3] += 0.3  # the true robot stands 0.3 mm off along y
    true, reported = pose_chain_poses(errors, true_flange, flange, np.eye(4), np.array([20.0, 0.0, 0.0]))
    sim = LaserLineScannerSimulator(sensor, points_per_profile=320, seed=0, errors=errors)
    sim.set_target(sphere)
    points = np.vstack([p.points_mm for p in sim.profiles(true, reported)])
    centre = fit_sphere(points)[0]
    # the sphere appears where the true pose chain's error puts it: 0.3 mm against y, plus hand-eye and latency
    assert centre[1] == pytest.approx(-0.3, abs=0.35)
    assert np.linalg.norm(centre - [0.0, 0.0, 182.0]) > 0.1
    ideal_true, ideal_reported = pose_chain_poses(None, flange, flange, np.eye(4))
    np.testing.assert_array_equal(ideal_true, ideal_reported)


def test_plane_fit_recovers_a_plane():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-10, 10, (500, 2))
    points = np.column_stack([xy, 0.1 * xy[:, 0] + 3.0])
    _, normal, residual = fit_plane(points)
    assert np.abs(residual).max() < 1e-9
    assert abs(normal @ np.array([-0.1, 0.0, 1.0]) / math.hypot(0.1, 1.0)) == pytest.approx(1.0)


def test_phoxi_interreflection_off_a_mirror_corrupts_the_points_it_lights(realistic):
    model = _small()
    # a diffuse back wall and, in front of it on the projector's side, a plate turned 45 deg towards the camera's left:
    # projector light mirrored by the plate lands on the wall left of it, where the camera sees the wall
    plate = SceneGeometry.from_trimesh(primitive_mesh("box", [0.1, 0.2, 0.004]), "plate", 0.8)
    turn = np.eye(4)
    c = math.sqrt(0.5)
    turn[:3, :3] = np.array([[c, 0.0, -c], [0.0, 1.0, 0.0], [c, 0.0, c]])  # normal (z) to (-1, 0, -1) / sqrt 2
    turn[:3, 3] = [0.05, 0.0, 0.40]
    scene = SceneGeometry.concatenate([_wall(0.47), plate.transformed(turn)])
    settings = ScanSettings(resolution=1, noise=True, seed=2)
    depths = {}
    for share in (0.0, 1.0):
        material = {**realistic.phoxi["material"], "specular_share": {"default": 0.0, "plate": share}}
        model_errors = realistic.with_blocks(
            "phoxi", calibration=None, fixed_pattern=None, edges=None, material=material
        )
        errors = PhoxiErrors.create(model, "x", model_errors)
        depths[share] = StructuredLightScanner(model, errors=errors).capture(scene, np.eye(4), settings).depth_mm
    wall = depths[0.0] > 465.0
    # wall points decoded with the plate's pattern: triangulated off the wall, or dropped when that lies out of range
    hit = wall & ((depths[1.0] == 0.0) | (np.abs(depths[1.0] - depths[0.0]) > 2.0))
    assert 20 < hit.sum() < 0.5 * wall.sum()
