"""The 3D voxel map: fusion against hand-computed voxels, carving only along given (valid) rays, hits winning,
clamping, static masking, the report's labels, the planning grid, persistence and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.voxel_map import EMPTY, FULL, UNKNOWN, MapConfig, VoxelMap, logit
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply

L_HIT = logit(0.7)
L_MISS = logit(0.4)


def fine_map(roi_max, res=0.001, **config):
    return VoxelMap([0, 0, 0], roi_max, MapConfig(resolution_m=res, planning_resolution_m=res, **config))


def cells(mask):
    return {tuple(int(v) for v in idx) for idx in np.argwhere(mask)}


def test_a_ray_along_x_frees_the_voxels_before_its_point_and_hits_its_voxel():
    grid = VoxelMap([0, 0, 0], [0.01, 0.002, 0.002], MapConfig(resolution_m=0.002, planning_resolution_m=0.002))
    assert grid.shape == (5, 1, 1)
    stats = grid.integrate([-0.1, 0.001, 0.001], [[0.009, 0.001, 0.001]])
    assert stats["free_updates"] == 4 and stats["hit_updates"] == 1 and stats["points_kept"] == 1
    np.testing.assert_allclose(grid.log_odds[:, 0, 0], [L_MISS] * 4 + [L_HIT], rtol=1e-6)
    assert grid.labels()[:, 0, 0].tolist() == [EMPTY] * 4 + [FULL]


def test_a_diagonal_ray_visits_exactly_the_hand_computed_voxels():
    # grid units: from (0.5, 0.5, 0.5) to (3.5, 2.5, 0.5), slope 2/3: it crosses x=1 (y=0.83), y=1 (x=1.25), x=2
    # (y=1.5), y=2 (x=2.75), x=3 (y=2.17); the sensor's own voxel is crossed too
    grid = fine_map([0.004, 0.004, 0.001])
    grid.integrate([0.0005, 0.0005, 0.0005], [[0.0035, 0.0025, 0.0005]])
    free = {(0, 0, 0), (1, 0, 0), (1, 1, 0), (2, 1, 0), (2, 2, 0)}
    assert cells(grid.labels() == EMPTY) == free
    assert cells(grid.labels() == FULL) == {(3, 2, 0)}
    assert cells(grid.observed) == free | {(3, 2, 0)}


def test_a_ray_from_outside_is_clipped_to_the_roi_and_a_point_outside_carves_only_inside():
    grid = fine_map([0.004, 0.001, 0.001])
    stats = grid.integrate([-1.0, 0.0005, 0.0005], [[0.5, 0.0005, 0.0005]])
    assert stats["points_outside"] == 1 and stats["points_kept"] == 0 and stats["hit_updates"] == 0
    assert grid.labels()[:, 0, 0].tolist() == [EMPTY] * 4
    assert len(grid.raw) == 0


def test_only_the_given_valid_points_carve_a_missing_pixel_leaves_its_ray_unknown():
    grid = fine_map([0.006, 0.003, 0.001])
    # two parallel rays along x in rows y=0 and y=2; only row 0's pixel was valid (row 2 was a projector shadow)
    grid.integrate([-0.01, 0.0005, 0.0005], [[0.0055, 0.0005, 0.0005]])
    assert grid.labels()[:, 0, 0].tolist() == [EMPTY] * 5 + [FULL]
    assert not grid.observed[:, 1:, :].any()
    assert (grid.labels()[:, 2, 0] == UNKNOWN).all()


def test_an_organised_frame_with_a_shadowed_patch_carves_nothing_behind_the_patch():
    from agiprobot_measurement.common.geometry import look_at
    from agiprobot_measurement.sensors.phoxi.models import CameraIntrinsics

    intr = CameraIntrinsics(width=40, height=30, fx=60.0, fy=60.0, cx=19.5, cy=14.5)
    grid = VoxelMap([-0.1, -0.1, -0.02], [0.1, 0.1, 0.02], MapConfig(resolution_m=0.004, planning_resolution_m=0.004))
    pose = look_at([0.0, 0.0, 0.4], [0.0, 0.0, 0.0], up=(0, 1, 0))
    depth = np.full((30, 40), 0.398)  # the plane z = 2 mm (mid-voxel)
    depth[10:20, 25:35] = 0.0  # invalid (a projector shadow): the plane is there but unmeasured
    stats = grid.integrate_organised(depth, intr, pose, view_id=2)
    assert stats["points"] == 30 * 40 - 100
    # the column above a shadowed pixel's patch of the plane stays unknown; above a measured one it is free
    rays = intr.pixel_rays().reshape(30, 40, 3)
    shadowed = grid.world_to_index(transform_ray(pose, rays[15, 30], 0.398))
    measured = grid.world_to_index(transform_ray(pose, rays[15, 10], 0.398))
    assert grid.labels()[tuple(measured)] == FULL
    assert grid.labels()[measured[0], measured[1], measured[2] + 2] == EMPTY
    assert not grid.observed[shadowed[0], shadowed[1], :].any()


def transform_ray(pose, ray, depth):
    return pose[:3, :3] @ (ray * depth) + pose[:3, 3]


def test_hits_win_within_a_frame_and_each_voxel_is_updated_once_per_frame():
    grid = fine_map([0.006, 0.001, 0.001])
    origin = [-0.01, 0.0005, 0.0005]
    # a near point in voxel 2 (three points in it), a far point in voxel 5 whose ray crosses voxel 2
    points = [[0.0025, 0.0005, 0.0005], [0.0021, 0.0004, 0.0006], [0.0029, 0.0005, 0.0005], [0.0055, 0.0005, 0.0005]]
    stats = grid.integrate(origin, points)
    assert stats["hit_updates"] == 2 and stats["free_updates"] == 4  # voxels 0, 1, 3, 4 once each
    np.testing.assert_allclose(grid.log_odds[:, 0, 0], [L_MISS, L_MISS, L_HIT, L_MISS, L_MISS, L_HIT], rtol=1e-6)
    assert grid.hits[:, 0, 0].tolist() == [0, 0, 3, 0, 0, 1]


def test_log_odds_are_clamped_as_octomap_does():
    grid = fine_map([0.004, 0.001, 0.001])
    for _ in range(20):
        grid.integrate([-0.01, 0.0005, 0.0005], [[0.0035, 0.0005, 0.0005]])
    np.testing.assert_allclose(grid.log_odds[:3, 0, 0], logit(0.1192), rtol=1e-6)
    np.testing.assert_allclose(grid.log_odds[3, 0, 0], logit(0.971), rtol=1e-6)
    # a hit after many misses needs several frames to turn the voxel (the clamp bounds how long)
    for _ in range(2):
        grid.integrate([-0.01, 0.0005, 0.0005], [[0.0005, 0.0005, 0.0005]])
    assert grid.labels()[0, 0, 0] != FULL
    for _ in range(2):
        grid.integrate([-0.01, 0.0005, 0.0005], [[0.0005, 0.0005, 0.0005]])
    assert grid.labels()[0, 0, 0] == FULL


def test_static_geometry_is_full_never_updated_and_points_near_it_are_dropped():
    grid = VoxelMap([0, 0, 0], [0.02, 0.02, 0.02], MapConfig(resolution_m=0.002, planning_resolution_m=0.002))
    table = trimesh.creation.box(extents=[0.1, 0.1, 0.004])  # top face at z = 0.002 - 0.002 = 0 +- 0.002
    table.apply_translation([0.01, 0.01, 0.0])
    grid.set_static(table)
    assert grid.static[:, :, 0].all() and not grid.static[:, :, 2:].any()
    before = grid.log_odds.copy()
    # a ray through the table to a point below: no static voxel changes; a table point is dropped; a point 1 cm up
    # is kept
    stats = grid.integrate(
        [0.011, 0.011, 0.05], [[0.011, 0.011, 0.0019], [0.011, 0.013, 0.0101], [0.0151, 0.0151, -0.01]]
    )
    assert stats["points_static"] == 1 and stats["points_kept"] == 1 and stats["points_outside"] == 1
    assert np.array_equal(grid.log_odds[grid.static], before[grid.static])
    assert (grid.labels()[grid.static] == FULL).all()
    assert not grid.growth_mask()[grid.static].any()
    assert grid.observed_surface_area_m2() == pytest.approx(0.002**2)


def test_static_bodies_touching_each_other_fill_only_their_own_insides():
    grid = VoxelMap(
        [-0.02, -0.02, -0.01], [0.02, 0.02, 0.05], MapConfig(resolution_m=0.002, planning_resolution_m=0.002)
    )
    table = trimesh.creation.box(extents=[0.2, 0.2, 0.02])
    table.apply_translation([0, 0, -0.01])
    fixture = trimesh.creation.box(extents=[0.02, 0.02, 0.02])  # stands on the table: a shared face at z = 0
    fixture.apply_translation([0, 0, 0.01])
    grid.set_static(trimesh.util.concatenate([table, fixture]))
    z = grid.index_to_world(np.argwhere(grid.static))[:, 2]
    assert z.max() < 0.021  # nothing above the fixture's top (a parity flip would fill the column to the ROI top)
    assert grid.static[10, 10, : grid.world_to_index([0, 0, 0.019])[2]].all()  # the fixture's inside is static


def hand_map():
    grid = VoxelMap([0, 0, 0], [0.005] * 3, MapConfig(resolution_m=0.001, planning_resolution_m=0.001))
    grid.log_odds[2, 2, 2] = 2.0  # full
    grid.log_odds[2, 2, 3] = -2.0  # empty
    grid.log_odds[0, 0, 0] = 2.0  # full, but enclosed by full / empty voxels below
    for idx in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)]:
        grid.log_odds[idx] = 2.0 if idx == (1, 1, 1) else -2.0
    grid.observed[grid.log_odds != 0] = True
    grid.invalidate()
    return grid


def test_growth_candidates_and_occlusion_plane_on_a_hand_made_map():
    grid = hand_map()
    # (0,0,0) has no unknown neighbour; (1,1,1) does (e.g. (2,2,2) is full, but (2,1,1) is unknown)
    assert cells(grid.growth_mask()) == {(2, 2, 2), (1, 1, 1)}
    near_empty_223 = {
        (x, y, z) for x in (1, 2, 3) for y in (1, 2, 3) for z in (2, 3, 4) if (x, y, z) not in {(2, 2, 2), (2, 2, 3)}
    }
    assert near_empty_223 <= cells(grid.occlusion_plane_mask())
    # candidates: unknown, next to an empty and a growth voxel; next to (2,2,3) and (2,2,2): x, y in 1..3, z in 2..3
    expected = {(x, y, z) for x in (1, 2, 3) for y in (1, 2, 3) for z in (2, 3)} - {(2, 2, 2), (2, 2, 3)}
    # the empty corner voxels and growth voxel (1,1,1) add candidates around the corner
    corner_empty = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1)]
    for e in corner_empty:
        for x in range(e[0] - 1, e[0] + 2):
            for y in range(e[1] - 1, e[1] + 2):
                for z in range(e[2] - 1, e[2] + 2):
                    c = (x, y, z)
                    if min(c) >= 0 and max(abs(a - b) for a, b in zip(c, (1, 1, 1), strict=True)) <= 1:
                        if grid.labels()[c] == UNKNOWN:
                            expected.add(c)
    assert cells(grid.candidate_mask()) == expected
    assert (grid.labels()[grid.candidate_mask()] == UNKNOWN).all()
    assert np.array_equal(grid.growth_voxels(), np.argwhere(grid.growth_mask()))
    assert grid.frontier_area_m2() == pytest.approx(len(expected) * 1e-6)


def test_predicted_surface_is_the_points_plane_with_its_normal_towards_free_space():
    grid = VoxelMap([0, 0, 0], [0.03] * 3, MapConfig(resolution_m=0.003, planning_resolution_m=0.003))
    rng = np.random.default_rng(1)
    xy = rng.uniform(0.003, 0.027, size=(4000, 2))
    z = 0.0165 + 0.0002 * rng.standard_normal(4000)
    points = np.column_stack([xy, z])
    # seen from below: the free side is -z
    grid.integrate([0.015, 0.015, -0.4], points)
    growth = grid.growth_voxels()
    assert len(growth) > 0 and np.all(growth[:, 2] == 5)
    centroids, normals = grid.predicted_surface(growth)
    np.testing.assert_allclose(centroids[:, 2], 0.0165, atol=2e-4)
    assert np.all(normals[:, 2] < -0.99)


def test_the_planning_grid_max_pools_occupancy_and_min_pools_free():
    grid = VoxelMap([0, 0, 0], [0.02, 0.02, 0.02], MapConfig(resolution_m=0.002, planning_resolution_m=0.005))
    grid.log_odds[...] = -1.0  # all empty
    grid.log_odds[0, 0, 0] = 2.0  # one full fine voxel in coarse (0,0,0)
    grid.log_odds[4, 4, 4] = 0.0  # one unknown fine voxel: centre 9 mm -> coarse (1,1,1)
    grid.observed[...] = True
    grid.observed[4, 4, 4] = False
    grid.invalidate()
    coarse = grid.coarse()
    assert coarse.shape == (4, 4, 4) and coarse.resolution_m == 0.005
    labels = coarse.labels()
    assert labels[0, 0, 0] == FULL and labels[1, 1, 1] == UNKNOWN
    assert (labels == EMPTY).sum() == 64 - 2
    assert coarse.raw is grid.raw
    assert grid.coarse() is coarse  # cached until the map changes


def test_fusing_a_sphere_puts_hits_on_its_surface_and_frees_the_space_in_front():
    grid = VoxelMap([-0.06, -0.06, -0.06], [0.06, 0.06, 0.06], MapConfig(resolution_m=0.002))
    rng = np.random.default_rng(0)
    d = rng.standard_normal((40000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sensor = np.array([0.0, 0.0, 0.45])
    pts = 0.04 * d
    seen = np.einsum("ij,ij->i", d, sensor - pts) > 0
    stats = grid.integrate(sensor, pts[seen], normals=d[seen], sigma_mm=np.full(seen.sum(), 0.05))
    assert stats["points_kept"] == seen.sum()
    full = grid.index_to_world(np.argwhere(grid.labels() == FULL))
    radius = np.linalg.norm(full, axis=1)
    assert np.all(np.abs(radius - 0.04) < 0.002 * math.sqrt(3))
    # the column above the sphere's top is free, the centre unknown (never crossed)
    assert (grid.labels()[30, 30, 51:] == EMPTY).all()
    assert grid.labels()[30, 30, 30] == UNKNOWN
    assert len(grid.raw) == seen.sum() and np.all(grid.raw.view == 0)
    # normals face the sensor
    assert np.all(np.einsum("ij,ij->i", grid.raw.normal, sensor - grid.raw.xyz_m) > 0)


def test_npz_round_trip_and_cloud_export(tmp_path):
    grid = fine_map([0.006, 0.003, 0.003])
    grid.integrate(
        [-0.01, 0.0005, 0.0005],
        [[0.0051, 0.0005, 0.0005], [0.0052, 0.0006, 0.0005]],
        view_id=3,
        sigma_mm=[0.2, 0.1],
        normals=[[-1, 0, 0], [-1, 0, 0]],
    )
    grid.integrate([-0.01, 0.0025, 0.0025], [[0.0045, 0.0025, 0.0025]], view_id=4, sigma_mm=[0.3])
    path = grid.save_npz(tmp_path / "map.npz")
    back = VoxelMap.load_npz(path)
    assert back.shape == grid.shape and np.array_equal(back.log_odds, grid.log_odds)
    assert np.array_equal(back.raw.view, [3, 3, 4]) and np.allclose(back.raw.sigma_mm, [0.2, 0.1, 0.3])
    assert back.config == grid.config
    # each view's sensor origin comes back (the sampling model's angular pitch needs it)
    assert sorted(back.raw.origins) == [3, 4]
    np.testing.assert_allclose(back.raw.origins[4], [-0.01, 0.0025, 0.0025])
    with np.load(path) as data:
        fields = dict(data)
    fields["raw_origin_m"] = np.full((2, 3), np.nan)
    np.savez(tmp_path / "bad_origins.npz", **fields)
    with pytest.raises(InputError, match=r"bad_origins\.npz: raw_origin_m"):
        VoxelMap.load_npz(tmp_path / "bad_origins.npz")
    del fields["raw_origin_view"], fields["raw_origin_m"]
    np.savez(tmp_path / "older.npz", **fields)
    assert VoxelMap.load_npz(tmp_path / "older.npz").raw.origins == {}  # a map written before: no origins
    n = grid.export_cloud_ply(tmp_path / "cloud.ply", voxel_m=0.001)
    assert n == 2  # the first two points share a 1 mm cell
    ply = read_ply(tmp_path / "cloud.ply")
    order = np.argsort(ply["x"])
    assert ply["view"][order].tolist() == [4, 3]
    np.testing.assert_allclose(ply["sigma_mm"][order], [0.3, 0.15], rtol=1e-6)
    np.testing.assert_allclose(ply["x"][order], [0.0045, 0.00515], rtol=1e-5)
    assert ply["count"][order].tolist() == [1, 2]
    (tmp_path / "junk.npz").write_bytes(b"not a map")
    with pytest.raises(InputError, match=r"junk\.npz"):
        VoxelMap.load_npz(tmp_path / "junk.npz")
    with pytest.raises(InputError, match="no such map file"):
        VoxelMap.load_npz(tmp_path / "missing.npz")


def test_save_bt_writes_the_observed_voxels_as_octomap_free_and_occupied(tmp_path):
    octomap = pytest.importorskip("octomap")  # pinned in requirements.txt; optional for the map itself
    grid = fine_map([0.004, 0.001, 0.001])
    grid.integrate([-0.01, 0.0005, 0.0005], [[0.0035, 0.0005, 0.0005]])
    grid.integrate([-0.01, 0.0005, 0.0005], [[0.0035, 0.0005, 0.0005]])
    assert grid.save_bt(tmp_path / "map.bt") is True
    tree = octomap.OcTree(str(tmp_path / "map.bt").encode())
    assert tree.getResolution() == pytest.approx(0.001)
    # .bt is OctoMap's max-likelihood format: each node read back is free or occupied, at the clamping bounds
    for i, occupied in enumerate([False] * 3 + [True]):
        node = tree.search(grid.index_to_world([i, 0, 0]))
        assert node is not None and tree.isNodeOccupied(node) is occupied
        assert node.getLogOdds() == pytest.approx(logit(0.971) if occupied else logit(0.1192), rel=1e-4)
    assert tree.getNumLeafNodes() == 4  # the never-observed voxels are absent (OctoMap's unknown)


@pytest.mark.parametrize(
    ("roi_min", "roi_max", "config", "message"),
    [
        ([0, 0, 0], [0.1, 0.0, 0.1], {}, "empty or inverted ROI"),
        ([0, 0, 0], [-0.1, 0.1, 0.1], {}, "empty or inverted ROI"),
        ([0, 0, float("nan")], [0.1, 0.1, 0.1], {}, "roi_min_m"),
        ([0, 0, 0], [10.0, 10.0, 10.0], {}, r"125,000,000,000 voxels"),
    ],
)
def test_bad_rois_are_refused_with_the_reason(roi_min, roi_max, config, message):
    with pytest.raises(InputError, match=message):
        VoxelMap(roi_min, roi_max, MapConfig(**config))


@pytest.mark.parametrize("res", [0.0, float("nan"), -0.002, float("inf")])
def test_bad_resolutions_are_refused(res):
    with pytest.raises(InputError, match="resolution_m"):
        MapConfig(resolution_m=res)


def test_bad_sensor_model_and_band_are_refused():
    with pytest.raises(InputError, match=r"prob_miss < 0\.5 < prob_hit"):
        MapConfig(prob_hit=0.4)
    with pytest.raises(InputError, match="free_below"):
        MapConfig(free_below=0.6)


def test_nan_points_are_dropped_and_counted_and_bad_shapes_refused():
    grid = fine_map([0.004, 0.001, 0.001])
    stats = grid.integrate([-0.01, 0.0005, 0.0005], [[0.0035, 0.0005, 0.0005], [np.nan, 0, 0], [0, np.inf, 0]])
    assert stats["points"] == 3 and stats["points_nan"] == 2 and stats["points_kept"] == 1
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        grid.integrate([0, 0, 0], np.zeros((4, 2)))
    with pytest.raises(InputError, match="sensor_origin_m"):
        grid.integrate([np.nan, 0, 0], np.zeros((1, 3)))
    with pytest.raises(InputError, match="normals"):
        grid.integrate([0, 0, 0], np.zeros((2, 3)), normals=np.zeros((3, 3)))


def fuse_sphere_labels():
    grid = VoxelMap([-0.06] * 3, [0.06] * 3, MapConfig(resolution_m=0.004, planning_resolution_m=0.004))
    rng = np.random.default_rng(3)
    d = rng.standard_normal((5000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sensor = np.array([0.05, 0.0, 0.45])
    pts = 0.04 * d
    seen = np.einsum("ij,ij->i", d, sensor - pts) > 0
    stats = grid.integrate(sensor, pts[seen], normals=d[seen])
    return grid.log_odds.copy(), stats["free_updates"], stats["hit_updates"]


def test_a_forked_child_fuses_with_the_serial_kernels_and_gets_the_same_map(monkeypatch):
    import multiprocessing

    from agiprobot_measurement.nbv.volumetric import raycast3d

    parent = fuse_sphere_labels()  # the parent has run the threaded kernels: GNU OpenMP is not fork-safe
    with multiprocessing.get_context("fork").Pool(1) as pool:
        child = pool.apply(fuse_sphere_labels)
    assert np.array_equal(parent[0], child[0]) and parent[1:] == child[1:]
    monkeypatch.setattr(raycast3d, "_FORKED", True)
    assert not raycast3d.parallel_allowed()
    serial = fuse_sphere_labels()
    assert np.array_equal(parent[0], serial[0]) and parent[1:] == serial[1:]
