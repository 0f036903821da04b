"""The seen surface sampled too sparsely (``nbv/volumetric/sampling.py``, ours' ``undersampled_surface`` term): the
sample spacing and angular pitch of a view come from its own points, the missed share follows min(1, pi r^2 / s^2)
per view, the open border of the fused points is found (and a fold seen from both sides is none), and a view that
would sample the sparse half of a wall densely gains while one facing the dense half does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.gains import undersampled_surface
from agiprobot_measurement.nbv.volumetric.sampling import SamplingModel, SamplingState, covered_share, open_edges
from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap

RES = 0.005
WALL_Y = 0.0525  # the wall's plane (m), voxel layer 10
SENSOR = np.array([0.05, -0.3, 0.05])
DENSE_M = 0.001
SPARSE_M = 0.006


def wall_map():
    """A wall y = 0.0525 m seen from SENSOR: x < 0.05 m sampled every 1 mm, x > 0.05 m every 6 mm; free in front."""
    grid = VoxelMap([0, 0, 0], [0.1, 0.1, 0.1], MapConfig(resolution_m=RES, planning_resolution_m=RES))
    chunks = []
    for lo, hi, step in ((0.0, 0.05, DENSE_M), (0.05, 0.1, SPARSE_M)):
        xs, zs = np.meshgrid(np.arange(lo + step / 2, hi, step), np.arange(step / 2, 0.1, step))
        chunks.append(np.stack([xs.ravel(), np.full(xs.size, WALL_Y), zs.ravel()], axis=1))
    points = np.concatenate(chunks)
    grid.integrate(SENSOR, points, normals=np.tile([0.0, -1.0, 0.0], (len(points), 1)), view_id=0)
    grid.log_odds[:, :10, :] = -2.0
    grid.observed[:, :10, :] = True
    grid.invalidate()
    return grid


def test_covered_share_is_one_up_to_sqrt_pi_r_and_falls_with_the_square_of_the_spacing():
    r = 0.002
    assert covered_share(np.array([0.001, math.sqrt(math.pi) * r]), r) == pytest.approx([1.0, 1.0])
    assert covered_share(np.array([0.006]), r)[0] == pytest.approx(math.pi * 4 / 36)
    assert covered_share(np.array([0.012]), r)[0] == pytest.approx(0.25 * covered_share(np.array([0.006]), r)[0])


def test_the_missed_share_and_the_pitch_come_from_the_views_own_points():
    grid = wall_map()
    state = SamplingState(SamplingModel(coverage_radius_m=0.002, neighbours=4))
    missed, pitch = state.missed_share(grid)
    missed = missed.reshape(grid.shape)
    dense = missed[1:9, 10, 1:19]
    sparse = missed[11:19, 10, 1:19]
    assert np.all(dense == 0.0)
    # 6 mm samples on a square grid: the 4th neighbour is 6 mm away
    assert np.median(sparse) == pytest.approx(1.0 - math.pi * 4 / 36, abs=1e-6)
    # nothing is missed off the wall (free or unknown voxels)
    assert np.all(missed[:, :10, :] == 0.0) and np.all(missed[:, 11:, :] == 0.0)
    # the pitch: spacing x cos(incidence) / distance, the median over the view's points (mostly the dense ones)
    assert pitch == pytest.approx(DENSE_M / 0.35, rel=0.2)
    # a second view of the sparse half, densely sampled, leaves nothing missed there
    xs, zs = np.meshgrid(np.arange(0.0505, 0.1, DENSE_M), np.arange(0.0005, 0.1, DENSE_M))
    points = np.stack([xs.ravel(), np.full(xs.size, WALL_Y), zs.ravel()], axis=1)
    grid.integrate(SENSOR, points, normals=np.tile([0.0, -1.0, 0.0], (len(points), 1)), view_id=1)
    again, _ = state.missed_share(grid)
    assert np.all(again.reshape(grid.shape)[11:19, 10, 1:19] == 0.0)
    assert sorted(state.views) == [0, 1]


def test_a_view_that_samples_the_sparse_half_densely_gains_and_one_of_the_dense_half_does_not(narrow_view):
    grid = wall_map()
    state = SamplingState()
    missed, pitch = state.missed_share(grid)
    view = narrow_view()
    poses = np.array([look_at([x, -0.3, 0.05], [x, WALL_Y, 0.05]) for x in (0.025, 0.075)])
    gain, area = undersampled_surface(grid, poses, view, missed, pitch, 0.002)
    assert gain[0] == 0.0 and area[0] == 0.0
    assert gain[1] > 0.0
    # close enough to sample densely, the view measures all the missed share of the voxels it sees: the area is the
    # sum of their weights x resolution^2
    assert area[1] / RES**2 == pytest.approx(gain[1])
    # from 4 x as far the spacing is 4 x wider: much less of the missed surface is measured
    far = look_at([0.075, -0.9, 0.05], [0.075, WALL_Y, 0.05])
    far_gain, _ = undersampled_surface(grid, far, narrow_view(), missed, pitch * 8, 0.002)
    near_gain, _ = undersampled_surface(grid, poses[1], narrow_view(), missed, pitch * 8, 0.002)
    assert 0.0 < far_gain[0] < near_gain[0]
    with pytest.raises(InputError, match="one value per planning voxel"):
        undersampled_surface(grid, poses, view, missed[:-1], pitch, 0.002)


def test_the_open_border_is_found_and_a_fold_seen_from_both_sides_is_none():
    g = np.arange(-20, 21) * 0.002
    x, y = np.meshgrid(g, g)
    plane = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    half = plane[plane[:, 1] >= 0]
    up = np.tile([0.0, 0.0, 1.0], (len(half), 1))
    border, outward = open_edges(half, up, 0.0045)
    edge = (half[:, 1] == 0) & (np.abs(half[:, 0]) < 0.035)
    inner = (half[:, 1] > 0.004) & (half[:, 1] < 0.035) & (np.abs(half[:, 0]) < 0.035)
    assert border[edge].all() and not border[inner].any()
    np.testing.assert_allclose(outward[edge], np.tile([0.0, -1.0, 0.0], (edge.sum(), 1)), atol=1e-9)
    # the same half-plane folded down by 90 degrees at y = 0, both faces sampled: the fold is no border
    other = half[half[:, 1] > 0] * np.array([1.0, 0.0, 0.0]) + np.outer(-half[half[:, 1] > 0][:, 1], [0, 0, 1])
    fold = np.concatenate([half, other])
    normals = np.concatenate([up, np.tile([0.0, -1.0, 0.0], (len(other), 1))])
    border, _ = open_edges(fold, normals, 0.0045)
    assert not border[: len(half)][edge].any()


def test_bad_sampling_settings_are_refused():
    with pytest.raises(InputError, match="coverage_radius_m"):
        SamplingModel(coverage_radius_m=0.0)
    with pytest.raises(InputError, match="neighbours"):
        SamplingModel(neighbours=0)


def test_the_open_border_of_a_half_wall_is_expected_surface_turned_outwards():
    grid = VoxelMap([0, 0, 0], [0.1, 0.1, 0.1], MapConfig(resolution_m=RES, planning_resolution_m=RES))
    xs, zs = np.meshgrid(np.arange(0.0205, 0.05, DENSE_M), np.arange(0.0205, 0.08, DENSE_M))
    points = np.stack([xs.ravel(), np.full(xs.size, WALL_Y), zs.ravel()], axis=1)
    grid.integrate(SENSOR, points, normals=np.tile([0.0, -1.0, 0.0], (len(points), 1)), view_id=0)
    state = SamplingState()
    weight, direction = state.open_border(grid)
    weight = weight.reshape(grid.shape)
    direction = direction.reshape(*grid.shape, 3)
    # the wall's right border (x = 0.05 m, voxel column 9) expects surface, its inside does not
    assert np.all(weight[9, 10, 5:15] > 0.0) and np.all(weight[5:8, 10, 6:14] == 0.0)
    # per border point: the spacing (1 mm) x twice the coverage radius, over resolution^2
    one = DENSE_M * 2 * 0.002 / RES**2
    assert weight[9, 10, 8] == pytest.approx(5 * one, rel=0.25)  # 5 border points per voxel along z
    turned = direction[9, 10, 8] / np.linalg.norm(direction[9, 10, 8])
    np.testing.assert_allclose(turned, [math.sqrt(0.5), -math.sqrt(0.5), 0.0], atol=0.05)
    # the fields add the border to the missed share with the weight given, and turn the incidence direction there
    missed, normals, _ = state.fields(grid, 2.0)
    assert missed.reshape(grid.shape)[9, 10, 8] == pytest.approx(2.0 * weight[9, 10, 8])
    np.testing.assert_allclose(normals.reshape(*grid.shape, 3)[9, 10, 8], turned, atol=0.05)
    assert state.fields(grid, 0.0)[1] is None
