"""The predicted-surface gain ("ours"): the unseen surface is expected where the seen one continues, not in the
unknown inside behind it; a view facing the continuation gains, one facing the seen surface or empty unknown space
does not; the weights, Kolmost and the area follow the docstring's formulas; bad input is refused."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.gains import (
    ExpectedSurfaceModel,
    expected_surface,
    expected_surface_fields,
)
from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

RES = 0.005  # m: 20^3 voxels over a 0.1 m cube

WALL_Y_INDEX = 10  # the seen wall's voxel layer (y 0.050-0.055 m)
LAST_FULL_X_INDEX = 9  # the wall covers x < 0.05 m: its full voxel columns are 0..9


def pose_along_y(x_m, z_m):
    """A camera at y = -0.3 m looking +y through (x_m, ., z_m)."""
    return look_at([x_m, -0.3, z_m], [x_m, 0.05, z_m])


def half_wall_map():
    """A wall seen from the front over x < 0.05 m (its raw points, normals towards the camera), and the space in
    front of it (y < 0.05 m) known free over the whole width: beyond x = 0.05 m the wall's continuation is unseen."""
    grid = VoxelMap([0, 0, 0], [0.1, 0.1, 0.1], MapConfig(resolution_m=RES, planning_resolution_m=RES))
    xs, zs = np.meshgrid(np.arange(0.0005, 0.05, 0.001), np.arange(0.0005, 0.1, 0.001))
    points = np.stack([xs.ravel(), np.full(xs.size, 0.0525), zs.ravel()], axis=1)
    grid.integrate([0.025, -0.3, 0.05], points, normals=np.tile([0.0, -1.0, 0.0], (len(points), 1)))
    grid.log_odds[:, :WALL_Y_INDEX, :] = -2.0
    grid.observed[:, :WALL_Y_INDEX, :] = True
    grid.invalidate()
    return grid


def test_the_surface_is_expected_beyond_the_seen_edge_and_not_inside_the_part():
    grid = half_wall_map()
    model = ExpectedSurfaceModel()
    weight, normals = expected_surface_fields(grid, model)
    weight = weight.reshape(grid.shape)
    normals = normals.reshape(*grid.shape, 3)
    row = weight[:, WALL_Y_INDEX, 10]
    # the seen wall expects nothing, nor the column next to it that holds the points of the wall's edge
    assert np.all(row[: LAST_FULL_X_INDEX + 2] == 0.0)
    # the wall's PCA plane extrapolated past the seen edge (radius 2 voxels): weight 1, the wall's normal (towards
    # the free space in front)
    assert row[LAST_FULL_X_INDEX + 2] == 1.0
    np.testing.assert_allclose(normals[LAST_FULL_X_INDEX + 2, WALL_Y_INDEX, 10], [0.0, -1.0, 0.0], atol=1e-6)
    # further out, the occlusion plane: occlusion_weight x (1 - d / max), d the distance to the nearest full voxel
    for k in range(3, 6):
        d = k * RES
        expected = model.occlusion_weight * (1.0 - d / model.occlusion_max_dist_m)
        assert row[LAST_FULL_X_INDEX + k] == pytest.approx(expected)
    # beyond occlusion_max_dist_m nothing, and nothing in the unknown behind the wall (no free neighbour)
    assert np.all(row[LAST_FULL_X_INDEX + 6 :] == 0.0)
    assert np.all(weight[:, WALL_Y_INDEX + 1 :, :] == 0.0)


def test_a_view_facing_the_continuation_gains_and_one_facing_the_seen_wall_does_not(narrow_view):
    grid = half_wall_map()
    view = narrow_view()
    poses = [pose_along_y(x, 0.05) for x in (0.025, 0.055, 0.075, 0.095)]
    gain, area_m2 = expected_surface(grid, np.array(poses), view)
    seen_wall, at_edge, further, far_away = gain
    assert seen_wall == 0.0 and area_m2[0] == 0.0
    assert at_edge > further > 0.0
    # unknown space with no seen surface nearby (x 0.083-0.1 m is beyond occlusion_max_dist_m) expects nothing
    assert far_away == 0.0 and area_m2[3] == 0.0
    # many poses at once (the parallel kernel) match one at a time
    for j, pose in enumerate(poses):
        one_gain, one_area = expected_surface(grid, pose, view)
        assert one_gain[0] == pytest.approx(gain[j]) and one_area[0] == pytest.approx(area_m2[j])


def test_kolmost_weights_the_gain_and_the_area_is_the_weight_sum(narrow_view):
    grid = half_wall_map()
    view = narrow_view()
    pose = pose_along_y(0.055, 0.05)
    plain_gain, area_m2 = expected_surface(grid, pose, view, ExpectedSurfaceModel(kolmost_weight=0.0))
    # w = 0: Kolmost is 1 for every voxel, so the gain is the weight sum = area / resolution^2
    assert plain_gain[0] == pytest.approx(area_m2[0] / RES**2) and area_m2[0] > 0.0
    for model_w in (0.5, 1.0):
        gain, area = expected_surface(grid, pose, view, ExpectedSurfaceModel(kolmost_weight=model_w))
        # w cos a + 1 - w <= 1: never more than the plain weight sum; the area does not depend on w
        assert 0.0 < gain[0] <= plain_gain[0] + 1e-9 and area[0] == pytest.approx(area_m2[0])
    # without the extrapolated plane and the occlusion plane, the seen edge itself leaves nothing to expect
    bare = ExpectedSurfaceModel(plane_radius_vox=0, occlusion_weight=0.0)
    assert expected_surface(grid, pose, view, bare)[0][0] == 0.0


def test_bad_expected_surface_input_is_refused(narrow_view):
    grid = half_wall_map()
    view = narrow_view()
    with pytest.raises(InputError, match="VoxelMap"):
        expected_surface("map", np.eye(4), view)
    with pytest.raises(InputError, match="ViewModel"):
        expected_surface(grid, np.eye(4), "phoxi")
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(InputError, match="finite"):
        expected_surface(grid, bad, view)
    with pytest.raises(InputError, match="finite"):
        expected_surface(grid, np.zeros((2, 3, 3)), view)
    assert expected_surface(grid, np.zeros((0, 4, 4)), view)[0].shape == (0,)
    with pytest.raises(InputError, match="plane_radius_vox"):
        ExpectedSurfaceModel(plane_radius_vox=9)
    with pytest.raises(InputError, match="kolmost_weight"):
        ExpectedSurfaceModel(kolmost_weight=1.5)
