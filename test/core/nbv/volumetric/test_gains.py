"""Per-view gains on small hand-made maps: unknown vs known space, occlusion, the projector's shadow, incidence,
the paper's visibility against the rpg code's, each metric's defining case, Kolmost, utilities and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agiprobot_measurement.common.geometry import look_at
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric import raycast3d
from agiprobot_measurement.nbv.volumetric.gains import (
    GAIN_NAMES,
    ViewModel,
    camera_ray_directions,
    evaluate_views,
    utility,
)
from agiprobot_measurement.nbv.volumetric.voxel_map import MapConfig, VoxelMap
from agiprobot_measurement.sensors.phoxi.models import load_scanner_model

RES = 0.005  # 20^3 voxels over a 0.1 m cube


def blank_map():
    return VoxelMap([0, 0, 0], [0.1, 0.1, 0.1], MapConfig(resolution_m=RES, planning_resolution_m=RES))


def set_voxels(grid, region, log_odds):
    grid.log_odds[region] = log_odds
    grid.observed[region] = True
    grid.invalidate()


def pose_along_y(x, z, distance=0.3):
    """A camera at y = -distance looking +y through (x, ., z)."""
    return look_at([x, -distance, z], [x, 0.05, z])


def gains_of(grid, poses, view, **kwargs):
    return evaluate_views(grid, np.array(poses), view, **kwargs)


def test_a_view_into_unknown_space_gains_more_than_one_into_known_free_space(narrow_view):
    grid = blank_map()
    set_voxels(grid, np.s_[:10, :, :], -2.0)  # x < 0.05 m known free; the rest never observed
    result = gains_of(grid, [pose_along_y(0.075, 0.05), pose_along_y(0.025, 0.05)], narrow_view())
    uv = result.all_gains["unobserved_voxel"]
    assert uv[0] > 1.0 and uv[1] == 0.0
    oa_rpg = gains_of(grid, [pose_along_y(0.075, 0.05), pose_along_y(0.025, 0.05)], narrow_view(), rpg_compat=True)
    assert oa_rpg.gain[0] > oa_rpg.gain[1] > 0.0
    assert result.visible_voxels[0] > 0 and result.visible_voxels[1] > 0


def test_a_full_voxel_occludes_what_lies_behind_it(narrow_view):
    grid = blank_map()
    view = narrow_view()
    pose = [pose_along_y(0.05, 0.05)]
    open_uv = gains_of(grid, pose, view, gain="unobserved_voxel").gain[0]
    set_voxels(grid, np.s_[:, 0, :], 2.0)  # a full wall on the ROI's camera-side face
    walled = gains_of(grid, pose, view)
    assert open_uv > 0.5 and walled.all_gains["unobserved_voxel"][0] == 0.0
    # only the wall's voxels are seen: one or a few per ray
    assert 0 < walled.visible_voxels[0] <= 8 * 8


def test_a_voxel_the_projector_cannot_light_is_not_counted(narrow_view):
    grid = blank_map()
    set_voxels(grid, np.s_[:, :, :], -2.0)
    grid.log_odds[9:11, 10:12, 9:11] = 0.0  # a 2x2x2 unknown target at (0.05, 0.055, 0.05)
    grid.observed[9:11, 10:12, 9:11] = False
    grid.invalidate()
    pose = [pose_along_y(0.05, 0.05)]
    projector = {
        "projector_fov_h_rad": math.radians(100),
        "projector_fov_v_rad": math.radians(20),
        "projector_rays_h": 400,
        "projector_rays_v": 40,
    }
    offset_view = narrow_view(fov_deg=1.5, offset=(0.2, 0.0, 0.0), **projector)
    coincident_view = narrow_view(fov_deg=1.5, **projector)
    lit = gains_of(grid, pose, offset_view, gain="unobserved_voxel").gain[0]
    assert lit > 0.0
    # a wall on the projector's segment to the target, outside the camera's frustum (x 0.065-0.085 m)
    set_voxels(grid, np.s_[13:17, 0:4, 8:12], 2.0)
    assert gains_of(grid, pose, offset_view, gain="unobserved_voxel").gain[0] == 0.0
    assert gains_of(grid, pose, coincident_view, gain="unobserved_voxel").gain[0] == pytest.approx(lit)


def test_a_surface_seen_at_grazing_incidence_is_not_counted(narrow_view):
    grid = blank_map()
    set_voxels(grid, np.s_[:, 10, :], 2.0)
    pose = [pose_along_y(0.05, 0.05)]
    grid.normal_sum[:, 10, :] = [0.0, -1.0, 0.0]  # facing the camera
    grid.invalidate()
    facing = gains_of(grid, pose, narrow_view()).visible_voxels[0]
    grid.normal_sum[:, 10, :] = [1.0, 0.0, 0.0]  # seen edge-on
    grid.invalidate()
    grazing = gains_of(grid, pose, narrow_view()).visible_voxels[0]
    assert facing - grazing > 0
    # the wall's seen voxels are exactly the difference: with the normals gone, the count is back
    grid.normal_sum[...] = 0.0
    grid.invalidate()
    assert gains_of(grid, pose, narrow_view()).visible_voxels[0] == facing


def test_rpg_compat_visibility_lets_known_free_space_occlude_as_the_rpg_code_does(narrow_view):
    grid = blank_map()
    set_voxels(grid, np.s_[:, :10, :], -2.0)  # the camera-side half is known free, the far half never observed
    pose = [pose_along_y(0.05, 0.05)]
    paper = gains_of(grid, pose, narrow_view(), gain="unobserved_voxel").gain[0]
    rpg = gains_of(grid, pose, narrow_view(), gain="unobserved_voxel", rpg_compat=True).gain[0]
    # paper: visibility prod(1 - p) = 0.88^10 ~ 0.28 after the free half; rpg: prod(p) = 0.12^10 ~ 6e-10
    assert paper > 0.1 and rpg < 1e-6 * paper
    # where every voxel is p = 0.5 the two forms agree (1 - p = p)
    blank = blank_map()
    a = gains_of(blank, pose, narrow_view()).all_gains
    b = gains_of(blank, pose, narrow_view(), rpg_compat=True).all_gains
    for name in GAIN_NAMES:
        assert a[name][0] == pytest.approx(b[name][0]), name


def test_rear_side_voxel_and_entropy_count_full_voxels_reached_through_unknown_space(narrow_view):
    pose = [pose_along_y(0.05, 0.05)]
    behind_unknown = blank_map()
    set_voxels(behind_unknown, np.s_[:, 10, :], 2.0)
    behind_free = blank_map()
    set_voxels(behind_free, np.s_[:, :10, :], -2.0)
    set_voxels(behind_free, np.s_[:, 10, :], 2.0)
    a = gains_of(behind_unknown, pose, narrow_view()).all_gains
    b = gains_of(behind_free, pose, narrow_view()).all_gains
    assert a["rear_side_voxel"][0] >= 1 and b["rear_side_voxel"][0] == 0
    assert a["rear_side_entropy"][0] > b["rear_side_entropy"][0] > 0  # b: only the end voxels' own entropy
    # average entropy: over rays ending in a full voxel only; a view hitting nothing has none
    assert a["average_entropy"][0] > 0
    assert gains_of(blank_map(), pose, narrow_view()).all_gains["average_entropy"][0] == 0.0


def test_proximity_count_rewards_unobserved_voxels_near_occupied_ones(narrow_view):
    grid = blank_map()
    set_voxels(grid, np.s_[9:11, 9:11, 9:11], 2.0)
    near = pose_along_y(0.05, 0.05)
    far = pose_along_y(0.005, 0.005)  # its voxels (x, z index <= 1) are >= 57 mm from the block, beyond 50 mm
    pc = gains_of(grid, [near, far], narrow_view(fov_deg=1.0), gain="proximity_count").gain
    assert pc[0] > 0 and pc[1] == 0
    wider = gains_of(grid, [far], narrow_view(fov_deg=1.0), gain="proximity_count", proximity_max_dist_m=0.09).gain
    assert wider[0] > 0


def test_area_factor_is_vasquez_gomez_cubic(narrow_view):
    for alpha in (0.2, 0.8):
        assert raycast3d._area_factor(0.0, alpha) == pytest.approx(0.0)
        assert raycast3d._area_factor(alpha, alpha) == pytest.approx(1.0)
        assert raycast3d._area_factor(1.0, alpha) == pytest.approx(0.0, abs=1e-12)
        # continuous with zero slope at alpha
        assert raycast3d._area_factor(alpha - 1e-4, alpha) == pytest.approx(1.0, abs=1e-6)
        assert raycast3d._area_factor(alpha + 1e-4, alpha) == pytest.approx(1.0, abs=1e-6)
    # a view whose rays all reach an occlusion plane (unknown next to free) scores the occplane cubic at 1.0 -> 0
    grid = blank_map()
    set_voxels(grid, np.s_[:, :10, :], -2.0)
    grid.log_odds[:, 10, :] = 0.1  # observed, still unknown: the occlusion plane
    grid.observed[:, 10, :] = True
    grid.invalidate()
    af = gains_of(grid, [pose_along_y(0.05, 0.05)], narrow_view(), gain="area_factor").gain[0]
    assert af == pytest.approx(raycast3d._area_factor(1.0, 0.8) + raycast3d._area_factor(0.0, 0.2), abs=1e-9)


def surface_with_open_border():
    """A full plane y = 10 over x < 10 facing -y (fused normals), free space in front, unknown behind and beside."""
    grid = blank_map()
    set_voxels(grid, np.s_[:, :10, :], -2.0)
    set_voxels(grid, np.s_[:10, 10, :], 2.0)
    grid.normal_sum[:10, 10, :] = [0.0, -1.0, 0.0]
    grid.invalidate()
    return grid


def test_report_gain_counts_growth_neighbours_seen_weighted_by_kolmost(narrow_view):
    grid = surface_with_open_border()
    assert grid.growth_neighbour_mask()[10, 10:, :].any()
    target = np.array([0.05, 0.055, 0.05])
    head_on = look_at(target + np.array([0.0, -0.4, 0.0]), target)
    oblique = look_at(target + 0.4 * np.array([math.sin(math.radians(60)), -math.cos(math.radians(60)), 0]), target)
    view = narrow_view(fov_deg=8.0)
    for pose, low, high in ((head_on, 0.97, 1.0), (oblique, 0.70, 0.80)):
        plain = gains_of(grid, [pose], view, gain="report", kolmost_weight=0.0)
        weighted = gains_of(grid, [pose], view, gain="report", kolmost_weight=0.5)
        assert plain.gain[0] > 0
        # with w = 0 the report gain is the count of targets seen, which is also the expected new area
        assert plain.gain[0] * RES**2 == pytest.approx(plain.new_surface_area_m2[0])
        assert low <= weighted.gain[0] / plain.gain[0] <= high


def test_utility_formulas():
    g = np.array([2.0, 1.0, 1.0])
    c = np.array([1.0, 1.0, 2.0])
    np.testing.assert_allclose(utility(g, c, "rpg", 0.0), g / 4)
    np.testing.assert_allclose(utility(g, c, "rpg", 1.0), g / 4 - c / 4)
    np.testing.assert_allclose(utility(g, c, "exp", 0.5), g * np.exp(-0.5 * c))
    np.testing.assert_allclose(utility(np.zeros(3), np.zeros(3), "rpg", 1.0), 0.0)
    with pytest.raises(InputError, match="unknown utility method"):
        utility(g, c, "sum")
    with pytest.raises(InputError, match="one value per view"):
        utility(g, c[:2])
    with pytest.raises(InputError, match="cost_s must be >= 0"):
        utility(g, -c)


def test_view_model_from_the_phoxi_s():
    view = ViewModel.from_scanner_model(load_scanner_model("S"))
    assert math.degrees(view.fov_h_rad) == pytest.approx(2 * math.degrees(math.atan(180 / 442)), abs=0.01)
    assert (view.range_min_m, view.range_max_m) == (0.384, 0.52)
    np.testing.assert_allclose(view.projector_offset_m, [0.23, 0.0, 0.0])
    # the projector looks back towards the camera's axis, crossing it at the sweet spot
    axis = view.projector_rotation[:, 2]
    crossing = view.projector_offset_m + axis * (-0.23 / axis[0])
    assert crossing[2] == pytest.approx(0.442)
    dirs = camera_ray_directions(view)
    assert dirs.shape == (64 * 48, 3) and np.allclose(np.linalg.norm(dirs, axis=1), 1.0)


def test_many_views_at_once_match_one_at_a_time(narrow_view):
    grid = surface_with_open_border()
    rng = np.random.default_rng(0)
    poses = [
        look_at([0.05, 0.05, 0.05] + 0.35 * d / np.linalg.norm(d), [0.05, 0.05, 0.05])
        for d in rng.standard_normal((7, 3)) + np.array([0.0, -2.0, 0.0])
    ]
    view = narrow_view(fov_deg=20.0)
    together = gains_of(grid, poses, view)
    for i, pose in enumerate(poses):
        alone = gains_of(grid, [pose], view)
        for name in GAIN_NAMES:
            assert alone.all_gains[name][0] == pytest.approx(together.all_gains[name][i]), name
        assert alone.visible_voxels[0] == together.visible_voxels[i]


def test_bad_gain_inputs_are_refused(narrow_view):
    grid = blank_map()
    view = narrow_view()
    with pytest.raises(InputError, match="unknown gain"):
        evaluate_views(grid, np.eye(4)[None], view, gain="magic")
    with pytest.raises(InputError, match=r"\(V, 4, 4\)"):
        evaluate_views(grid, np.zeros((2, 3, 4)), view)
    with pytest.raises(InputError, match="NaN"):
        evaluate_views(grid, np.full((1, 4, 4), np.nan), view)
    with pytest.raises(InputError, match="range_min_m"):
        narrow_view().__class__(0.5, 0.5, 1.0, 0.5, np.zeros(3))
    empty = evaluate_views(grid, np.zeros((0, 4, 4)), view)
    assert empty.gain.shape == (0,) and set(empty.all_gains) == set(GAIN_NAMES)


def test_the_serial_kernel_of_forked_children_gives_the_same_gains(monkeypatch, narrow_view):
    grid = surface_with_open_border()
    poses = [pose_along_y(0.05, 0.05), pose_along_y(0.03, 0.06), pose_along_y(0.07, 0.04)]
    threaded = gains_of(grid, poses, narrow_view(fov_deg=20.0))
    monkeypatch.setattr(raycast3d, "_FORKED", True)
    serial = gains_of(grid, poses, narrow_view(fov_deg=20.0))
    for name in GAIN_NAMES:
        np.testing.assert_allclose(serial.all_gains[name], threaded.all_gains[name], rtol=1e-12, err_msg=name)
    assert np.array_equal(serial.visible_voxels, threaded.visible_voxels)
