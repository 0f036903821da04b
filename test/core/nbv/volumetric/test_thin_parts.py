"""A thin flat part on the fixture: its points survive the static margin at the planning resolution, and ours does
not stop ("frontier exhausted") while views from low elevations would still see its rim."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth, simulate
from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest
from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap


def test_a_plate_thinner_than_a_voxel_keeps_its_points_on_the_fixture():
    # the ROI starts 10 mm below the table top (as the station's): the top lies on a voxel boundary of the 5 mm grid
    grid = VoxelMap([0, 0, -0.01], [0.1, 0.1, 0.09], MapConfig(resolution_m=0.005, planning_resolution_m=0.005))
    table = trimesh.creation.box(extents=[0.3, 0.3, 0.02])
    table.apply_translation([0.05, 0.05, -0.01])  # top face at z = 0
    grid.set_static(table)
    assert not grid.static[:, :, grid.world_to_index([0, 0, 0.001])[2]].any()  # the layer above the top is free
    # the top of a 4 mm plate, a point 1 mm above the table (within the 2 mm margin), a point in the table
    stats = grid.integrate([0.05, 0.05, 0.5], [[0.05, 0.05, 0.004], [0.06, 0.05, 0.001], [0.07, 0.05, -0.003]])
    assert stats["points_kept"] == 1 and stats["points_static"] == 2
    assert grid.full_mask().sum() == 1


def test_the_top_of_a_plate_on_the_fixture_counts_as_new_surface():
    from types import SimpleNamespace

    from agiprobot_measurement.common.geometry import look_at
    from agiprobot_measurement.nbv.volumetric.novelty import NoveltyTracker

    # the output map's resolution: a 3 mm plate lies within two voxels of the table (a voxel band around the
    # static scene once dropped all of it, so its views added nothing and the realised-gain stop fired)
    grid = VoxelMap([0, 0, -0.01], [0.1, 0.1, 0.09], MapConfig(resolution_m=0.002, planning_resolution_m=0.005))
    table = trimesh.creation.box(extents=[0.3, 0.3, 0.02])
    table.apply_translation([0.05, 0.05, -0.01])  # top face at z = 0
    grid.set_static(table)
    novelty = NoveltyTracker(grid.roi_min_m, grid.roi_max_m, grid, default_fx=400.0)  # 1 mm pixels at 0.4 m
    ax = np.arange(0.02, 0.08, 0.001)
    x, y = (a.ravel() for a in np.meshgrid(ax, ax, indexing="ij"))

    def frame(z_m):
        points = np.stack([x, y, np.full(len(x), z_m)], axis=1)
        pose = look_at([0.05, 0.05, 0.4], [0.05, 0.05, 0.0], up=[0.0, 1.0, 0.0])
        return SimpleNamespace(points_m=points, normals=np.tile([0.0, 0.0, 1.0], (len(x), 1)), camera_pose=pose,
                               intrinsics=None)  # fmt: skip

    assert novelty.add(frame(0.001)) == 0.0  # on the fixture's top (within the static margin): not the part
    plate = novelty.add(frame(0.003))
    assert plate == pytest.approx(0.06 * 0.06, rel=0.05)  # the plate's 60 x 60 mm
    assert novelty.add(frame(0.003)) == 0.0  # seen before


def test_ours_does_not_quit_early_on_a_thin_plate():
    station = SimulatedNBVStation("plate_1", "mm", None, pixel_step=8)  # 219 x 91 x 4 mm, generated
    truth = GroundTruth(station, spacing_m=0.003, directions=100)
    request = ReconstructionRequest.with_config_defaults(gain="ours", max_views=5, seed=0)
    run = simulate(station, request, truth, chamfer=False)
    assert run["termination_reason"] != "frontier_exhausted", run["coverage_curve"]
    # before the fallback: "frontier exhausted" after the first view at 0.75
    assert run["views"] >= 4 and run["coverage"] >= 0.95, run["coverage_curve"]
    assert np.all(np.diff(run["coverage_curve"]) >= -1e-9)
