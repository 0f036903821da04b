"""Traversals, the range finder's return rule and the model update."""

import math

import numpy as np
import pytest

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, UNKNOWN
from agiprobot_measurement.nbv.planar.range_finder import (
    NO_RETURN,
    RangeFinder2D,
    bkrangef2d,
    rangef2d,
    rangef2d_,
    scan,
)
from agiprobot_measurement.nbv.planar.traversal import line8_cells, supercover_cells


def _cells(a):
    return [tuple(map(int, c)) for c in a]


def test_supercover_includes_corner_touches_8_connected_does_not():
    # y = x / 3 passes exactly through the corner (1.5, 0.5): the supercover takes both cells at that corner
    assert _cells(supercover_cells((0, 0), (3, 1), (10, 10))) == [(0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (3, 1)]
    assert _cells(line8_cells((0, 0), (3, 1), (10, 10))) == [(0, 0), (1, 0), (2, 1), (3, 1)]
    # the diagonal through cell corners touches the side neighbours too
    assert _cells(supercover_cells((0, 0), (2, 2), (10, 10))) == [
        (0, 0),
        (0, 1),
        (1, 0),
        (1, 1),
        (1, 2),
        (2, 1),
        (2, 2),
    ]
    assert _cells(line8_cells((0, 0), (2, 2), (10, 10))) == [(0, 0), (1, 1), (2, 2)]
    # a segment lying on a cell edge touches both columns
    assert _cells(supercover_cells((0.5, 0), (0.5, 1), (10, 10))) == [(0, 0), (0, 1), (1, 0), (1, 1)]


def test_traversal_is_ordered_and_clipped():
    cells = supercover_cells((-5.0, 2.0), (20.0, 2.3), (10, 10))
    assert cells[:, 0].min() == 0 and cells[:, 0].max() == 9  # clipped to the grid
    assert (np.diff(cells[:, 0]) >= 0).all()  # ordered along the segment
    back = supercover_cells((20.0, 2.3), (-5.0, 2.0), (10, 10))
    assert _cells(back) == _cells(cells)[::-1]


def _rf():
    return RangeFinder2D(10.0, math.pi / 2, math.atan2(24.0, 10.0), 0.2)


def test_default_geometry_matches_the_laser_scanner():
    rf = RangeFinder2D.from_config()
    assert rf.standoff_cells == pytest.approx(181.82, abs=0.01)
    assert rf.rf_length_cells == pytest.approx(76.0, abs=0.1)
    assert math.degrees(rf.fr_gamma_rad) == pytest.approx(12.4, abs=0.1)
    longer = rf.with_length(150.0)
    assert longer.standoff_cells == pytest.approx(rf.standoff_cells)
    assert longer.triangulation_angle_rad > rf.triangulation_angle_rad


def test_pose_crosses_camera_axis_at_the_aim():
    rf = _rf()
    pos = rf.poses((20.0, 20.0), math.radians(90.0), 1)[0]
    src, cam, aim = pos
    assert np.hypot(*(aim - src)) == pytest.approx(24.0)
    assert np.hypot(*(cam - src)) == pytest.approx(10.0)
    to_s, to_a = src - cam, aim - cam
    ang = math.acos(np.dot(to_s, to_a) / np.hypot(*to_s) / np.hypot(*to_a))
    assert ang == pytest.approx(rf.rf_beta_rad)


def test_return_when_clear_and_blocked_on_the_camera_path():
    rf = _rf()
    truth = np.full((60, 60), EMPTY)
    truth[20:40, 10:20] = FULL  # top face at y = 19.5
    pos = rf.poses((30.0, 19.5), math.radians(90.0), 1)[0]
    hit = rangef2d(truth, pos, rf)
    np.testing.assert_allclose(hit, [30.0, 19.5])
    r = scan(truth, pos, rf)
    assert r.cell == (30, 19)
    # a wall between the hit and the camera (but not on the laser): no return
    cam = pos[1]
    blocked = truth.copy()
    mid = (np.array([30.0, 19.5]) + cam) / 2
    blocked[round(mid[0]), round(mid[1])] = FULL
    assert np.all(rangef2d(blocked, pos, rf) == NO_RETURN)
    assert scan(blocked, pos, rf) is None
    # a hit outside the camera's field of view gives no return either
    far = truth.copy()
    far[20:40, 10:20] = EMPTY
    far[28:33, 2:6] = FULL
    assert scan(far, pos, rf) is None


def test_rangef2d_and_rangef2d_agree_on_axis_rays():
    rf = _rf()
    truth = np.full((60, 60), EMPTY)
    truth[20:40, 10:20] = FULL
    pos = rf.poses((25.0, 19.5), math.radians(90.0), -1)[0]
    np.testing.assert_allclose(rangef2d(truth, pos, rf), rangef2d_(truth, pos, rf))


def test_bkrangef2d_updates_the_model_not_the_truth():
    rf = _rf()
    truth = np.full((60, 60), EMPTY)
    truth[20:40, 10:20] = FULL
    before = truth.copy()
    pos = rf.poses((30.0, 19.5), math.radians(90.0), 1)[0]
    hit = rangef2d(truth, pos, rf)
    model = np.zeros_like(truth)
    updated = bkrangef2d(model, pos, hit)
    np.testing.assert_array_equal(truth, before)
    np.testing.assert_array_equal(model, np.zeros_like(truth))  # copied, not modified
    assert updated[30, 19] == FULL
    assert updated[30, 25] == EMPTY and updated[30, 20] == EMPTY  # on the laser before the hit
    assert (updated == FULL).sum() == 1
    # every carved cell is free in the truth (noise-free consistency)
    assert (truth[updated == EMPTY] == EMPTY).all()
    # no return: nothing changes
    np.testing.assert_array_equal(bkrangef2d(model, pos, NO_RETURN), model)
    assert updated[5, 50] == UNKNOWN


def test_bad_parameters_raise():
    with pytest.raises(NbvInputError, match="RFlength"):
        RangeFinder2D(float("nan"), 1.0, 1.0, 0.2)
    with pytest.raises(NbvInputError, match="cross"):
        RangeFinder2D(10.0, 2.0, 2.0, 0.2)
    with pytest.raises(NbvInputError, match="3 x 2"):
        rangef2d(np.zeros((5, 5)), np.zeros((2, 2)), _rf())
    with pytest.raises(NbvInputError, match="NaN"):
        rangef2d(np.zeros((5, 5)), np.full((3, 2), np.nan), _rf())


def test_return_margin_leaves_the_start_of_the_return_path_uncarved():
    from agiprobot_measurement.nbv.planar.range_finder import measurement_cells

    pos = np.array([[10.0, 0.0], [0.0, 0.0], [10.0, 10.0]])
    point = np.array([10.0, 9.5])
    free0, _ = measurement_cells((20, 20), pos, point)
    free3, _ = measurement_cells((20, 20), pos, point, return_margin_cells=3.0)
    carved0 = {tuple(int(v) for v in c) for c in free0}
    carved3 = {tuple(int(v) for v in c) for c in free3}
    spared = carved0 - carved3
    assert carved3 <= carved0 and spared
    # only cells within the margin of the point on its way back to the camera are spared
    assert all(np.hypot(c[0] - point[0], c[1] - point[1]) < 3.0 + 1.5 for c in spared)
