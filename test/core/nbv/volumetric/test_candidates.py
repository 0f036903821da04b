"""Candidate views of the 3D NBV loop: geometry, the sphere of visibility, and the filter chain with its reasons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.candidates import (
    CandidateConfig,
    CandidateGenerator,
    Candidates,
    Targets,
    fibonacci_sphere,
    poses_from_directions,
    segments_clear,
    unknown_region_mesh,
)
from agiprobot_measurement.nbv.volumetric.settings import NBVSettings


@pytest.fixture(scope="module")
def station():
    from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation

    return SimulatedNBVStation(pixel_step=8)


@pytest.fixture(scope="module")
def generator(station):
    settings = NBVSettings.from_config(station.config).candidates
    return CandidateGenerator(station, CandidateConfig.from_settings(settings, station.scanner_model))


def test_fibonacci_sphere_is_uniform_unit_vectors():
    d = fibonacci_sphere(500)
    assert d.shape == (500, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert abs(d.mean(axis=0)).max() < 0.01  # balanced over the sphere
    assert (d[:, 2] > 0).sum() == 250
    with pytest.raises(InputError):
        fibonacci_sphere(0)


def test_poses_look_at_their_target_from_the_standoff_with_the_roll():
    target = np.array([[0.4, -0.5, 1.1]])
    direction = np.array([[0.0, 0.6, 0.8]])
    poses = poses_from_directions(target, direction, 0.442, [0.0, math.pi / 2])
    assert poses.shape == (2, 4, 4)
    for pose in poses:
        np.testing.assert_allclose(np.linalg.norm(pose[:3, 3] - target[0]), 0.442)
        np.testing.assert_allclose(pose[:3, 2], -direction[0], atol=1e-12)  # z looks back at the target
        np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)
        assert np.linalg.det(pose[:3, :3]) > 0
    assert abs(poses[0, 2, 0]) < 1e-12  # roll 0: image x horizontal
    np.testing.assert_allclose(poses[1, :3, 0], poses[0, :3, 1], atol=1e-12)  # roll 90 deg about the axis


def test_segments_clear_stops_at_blocked_voxels_only():
    blocked = np.zeros((10, 10, 10), dtype=bool)
    blocked[5, 5, 5] = True  # voxel [0.05, 0.06)^3 at 1 cm
    origin = np.zeros(3)
    starts = np.array([[0.005, 0.055, 0.055], [0.005, 0.015, 0.055], [0.055, 0.055, 0.2]])
    ends = np.array([[0.095, 0.055, 0.055], [0.095, 0.015, 0.055], [0.055, 0.055, 0.07]])
    np.testing.assert_array_equal(segments_clear(blocked, origin, 0.01, starts, ends), [False, True, True])


def test_unknown_region_mesh_is_closed_and_covers_the_unknown_voxels():
    from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

    grid = VoxelMap([0, 0, 0], [0.1, 0.1, 0.1], MapConfig(resolution_m=0.01, planning_resolution_m=0.01))
    mesh = unknown_region_mesh(grid)  # everything unknown: one box
    assert mesh.is_watertight
    lo, hi = mesh.bounds
    assert np.all(lo <= 0.0051) and np.all(hi >= 0.0949)


def test_pooled_unknown_region_mesh_holds_the_fine_one_with_fewer_faces():
    from types import SimpleNamespace

    labels = -np.ones((12, 12, 12), dtype=int)  # known free but for a ball and one voxel at the grid's far corner
    i, j, k = np.indices(labels.shape)
    labels[(i - 5) ** 2 + (j - 6) ** 2 + (k - 5) ** 2 <= 12] = 0
    labels[11, 11, 11] = 1
    grid = SimpleNamespace(labels=lambda: labels, static=np.zeros(labels.shape, bool), resolution_m=0.01,
                           origin_m=np.array([0.2, -0.1, 1.0]))  # fmt: skip
    fine, pooled = unknown_region_mesh(grid), unknown_region_mesh(grid, 2)
    assert fine.is_watertight and pooled.is_watertight
    assert np.all(pooled.bounds[0] <= fine.bounds[0] + 1e-9) and np.all(pooled.bounds[1] >= fine.bounds[1] - 1e-9)
    assert pooled.volume >= fine.volume
    assert np.all(pooled.bounds[1] >= grid.origin_m + 11.5 * 0.01 - 1e-9)  # the odd corner voxel is in a block

    labels[:] = 0
    assert len(unknown_region_mesh(grid, 2).faces) < len(unknown_region_mesh(grid).faces) / 3


def test_hemisphere_has_the_requested_views_at_the_standoff(generator):
    center = np.array([0.45, -0.55, 1.13])
    for n in (6, 12, 24):
        cands = generator.hemisphere(center, n)
        assert len(cands) == n
        elevation = np.degrees(np.arcsin((cands.poses[:, 2, 3] - center[2]) / 0.442))
        assert elevation.min() >= 14.9 and elevation.max() <= 75.1
    with pytest.raises(InputError):
        generator.hemisphere(center, 0)


def test_each_filter_rejects_with_its_reason(station, generator):
    from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

    center, size = station.default_roi()
    lo, hi = center - size / 2, center + size / 2
    grid = VoxelMap(lo, hi, MapConfig(resolution_m=0.01, planning_resolution_m=0.01))
    home = station.home_rad
    sphere = generator.filter(generator.sphere(center), grid, lo, hi, home)
    assert 0 < sphere.feasible.sum() < len(sphere)
    good = sphere.poses[np.nonzero(sphere.feasible)[0][0]]
    inside = good.copy()
    inside[:3, 3] = center
    low = good.copy()
    low[2, 3] = station.table_top_m + 0.01
    far = good.copy()
    far[:3, 3] = [2.5, 2.5, 2.0]
    poses = np.stack([good, inside, low, far])
    cands = Candidates(poses, np.repeat(center[None], 4, 0), np.full(4, -1), np.full(4, "sphere", dtype=object))
    generator.filter(cands, grid, lo, hi, home)
    assert cands.reason.tolist() == ["", "inside_roi", "below_table", "ik"]
    assert cands.feasible.tolist() == [True, False, False, False]
    assert cands.rejections() == {"inside_roi": 1, "below_table": 1, "ik": 1}
    q = cands.joints[0]
    np.testing.assert_allclose(station.sensor_pose(q), good, atol=1e-6)  # IK reaches the sensor pose

    # the same pose again: tabu
    again = Candidates(good[None], center[None], np.array([-1]), np.array(["sphere"], dtype=object))
    generator.filter(again, grid, lo, hi, home, tabu=[good])
    assert again.reason.tolist() == ["tabu"]

    # an obstacle where the wrist is at that joint state: scene collision
    wrist = station.link_poses(q)["wrist_2_link"]
    generator.scene_checker.add_box("probe", [0.05, 0.05, 0.05], wrist)
    try:
        blocked = Candidates(good[None], center[None], np.array([-1]), np.array(["sphere"], dtype=object))
        generator.filter(blocked, grid, lo, hi, home)
        assert blocked.reason.tolist() == ["collision_scene"]
    finally:
        generator.scene_checker.remove_object("probe")

    # an unknown region around the forearm (the sensor itself outside it): collision with the not-known-free space
    elbow = station.link_poses(q)["forearm_link"][:3, 3]
    wrist1 = station.link_poses(q)["wrist_1_link"][:3, 3]
    mid = 0.5 * (elbow + wrist1)
    region = VoxelMap(mid - 0.1, mid + 0.1, MapConfig(resolution_m=0.01, planning_resolution_m=0.01))
    assert np.linalg.norm(good[:3, 3] - mid) > 0.15
    unknown = Candidates(good[None], center[None], np.array([-1]), np.array(["sphere"], dtype=object))
    generator.filter(unknown, region, lo, hi, home)
    assert unknown.reason.tolist() == ["collision_unknown"]
    generator.update_unknown_obstacle(None)


def test_frontier_candidates_face_the_target_and_respect_the_sphere_of_visibility(station, generator):
    from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

    grid = VoxelMap([0.3, -0.7, 1.0], [0.6, -0.4, 1.3], MapConfig(resolution_m=0.005, planning_resolution_m=0.005))
    target = np.array([0.45, -0.55, 1.1])
    normal = np.array([0.0, 0.0, 1.0])
    targets = Targets(target[None], normal[None], np.array([10]))
    free = generator.frontier(grid, targets)
    cfg = generator.config
    per_roll = 1 + cfg.cone_azimuths * (len(cfg.cone_angles_rad) - 1)
    assert len(free) == per_roll * len(cfg.rolls_rad)
    view = -free.poses[:, :3, 2]
    np.testing.assert_allclose(np.linalg.norm(free.poses[:, :3, 3] - target, axis=1), cfg.standoff_m, atol=1e-9)
    angles = np.degrees(np.arccos(np.clip(view @ normal, -1, 1)))
    assert set(np.round(angles).astype(int)) == {0, 20, 40}
    # a full slab 3 cm above the target blocks every camera ray within 60 deg of the normal
    labels_full = np.zeros(grid.shape, dtype=bool)
    k = int((target[2] + 0.03 - grid.origin_m[2]) / grid.resolution_m)
    labels_full[:, :, k] = True
    grid.log_odds[labels_full] = 5.0
    grid._changed()
    blocked = generator.frontier(grid, targets)
    assert len(blocked) == 0
    assert blocked.pre_rejections["camera_occluded"] == len(free)


def test_phoxi_tool_urdf_mounts_the_models_housing_and_sensor_frame():
    from agiprobot_measurement.nbv.volumetric.station3d import phoxi_station_urdf
    from agiprobot_measurement.station.urdf_model import UrdfModel

    for model, length_m, baseline_m in (("S", 0.296, 0.230), ("M", 0.416, 0.350)):
        urdf = UrdfModel(phoxi_station_urdf(model=model))
        offset = urdf.fixed_transform("tool0", "PhoXi3Dscanner_sensor")
        np.testing.assert_allclose(offset[:3, :3], np.eye(3))  # looks along the flange's z
        assert offset[0, 3] == pytest.approx(-baseline_m / 2) and offset[2, 3] > 0.05
        (box,) = urdf.collision["PhoXi3Dscanner"]
        assert box.type == "box" and box.size[0] == pytest.approx(length_m)
    with pytest.raises(InputError, match="unknown PhoXi model"):
        phoxi_station_urdf(model="XL")


def test_the_unknown_region_tree_is_kept_while_the_map_has_not_changed(generator, monkeypatch):
    from agiprobot_measurement.nbv.volumetric import candidates as module
    from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

    built = []
    real = module.unknown_region_mesh

    def counting(grid, pool=1):
        built.append(grid.version)
        return real(grid, pool)

    monkeypatch.setattr(module, "unknown_region_mesh", counting)
    grid = VoxelMap([0.3, -0.7, 1.0], [0.6, -0.4, 1.3], MapConfig(resolution_m=0.01, planning_resolution_m=0.01))
    try:
        generator.update_unknown_obstacle(grid)
        generator.update_unknown_obstacle(grid)  # a second pool in the same view
        assert len(built) == 1
        assert module.UNKNOWN_OBSTACLE in generator.checker.object_names()
        assert module.UNKNOWN_OBSTACLE not in generator.scene_checker.object_names()
        grid.invalidate()  # the map changed: built again
        generator.update_unknown_obstacle(grid)
        assert len(built) == 2
    finally:
        generator.update_unknown_obstacle(None)
    assert module.UNKNOWN_OBSTACLE not in generator.checker.object_names()
