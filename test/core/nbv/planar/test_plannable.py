"""The plannable boundary (views planned onto the cell, the benchmark's denominator) and the noisy laser margin."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.evaluation import boundary_cells, measurable_boundary, plannable_boundary
from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL
from agiprobot_measurement.nbv.planar.range_finder import RangeFinder2D, measurement_cells, scan
from agiprobot_measurement.nbv.planar.run_config import RunConfig
from agiprobot_measurement.nbv.planar.scoring import aim_points


def _grid(n=140):
    return np.full((n, n), EMPTY, dtype=float)


def _slot_body():
    """A block with a slot 8 cells wide and 40 deep, opening towards +y."""
    t = _grid()
    t[40:100, 40:100] = FULL
    t[66:74, 60:100] = EMPTY
    return t


def test_convex_body_everything_plannable():
    t = _grid()
    t[50:90, 55:85] = FULL
    rf = RangeFinder2D.from_config()
    meas = measurable_boundary(t, rf)
    n = len(boundary_cells(t))
    for aim in ("centre", "edge_midpoints"):
        plan = plannable_boundary(t, rf, aim)
        assert plan.sum() == meas.sum() == n


@pytest.mark.parametrize("length", [40.0, 250.0])
def test_slot_centre_views_reach_less(length):
    t = _slot_body()
    rf = RangeFinder2D.from_config().with_length(length)
    meas = measurable_boundary(t, rf)
    centre = plannable_boundary(t, rf, "centre")
    edge = plannable_boundary(t, rf, "edge_midpoints")
    # a view planned onto a cell centre needs both sectors free at the centre: deep slot walls are out of reach
    assert not (centre & ~meas).any()
    assert centre.sum() < meas.sum()
    lost = np.argwhere(meas & ~centre)
    assert ((lost[:, 0] >= 65) & (lost[:, 0] <= 74) & (lost[:, 1] >= 59)).all()  # only in the slot
    assert edge.sum() > centre.sum()


def test_plannable_cells_are_confirmed_by_a_real_scan():
    """For a plannable slot-wall cell, some planned pose onto its centre returns exactly that cell on the truth."""
    t = _slot_body()
    rf = RangeFinder2D.from_config()
    centre = plannable_boundary(t, rf, "centre")
    cells = np.argwhere(centre & (np.arange(t.shape[0])[:, None] == 65))[:3]
    assert len(cells)
    phi = np.radians(np.arange(360) + 0.5)
    for c in cells:
        poses = [rf.poses(aim_points(c, "centre")[0], phi, side) for side in (1, -1)]
        hits = [scan(t, p, rf) for ps in poses for p in ps]
        assert any(h is not None and h.cell == (int(c[0]), int(c[1])) for h in hits)


def test_laser_margin_keeps_a_too_deep_point_from_carving_the_body():
    t = _grid(40)
    t[:, 20:] = FULL  # a wall facing -y
    rf = RangeFinder2D.from_config()
    # a laser grazing the wall at 10 deg, its point measured 0.8 cells too deep
    d = np.array([np.cos(np.radians(10.0)), np.sin(np.radians(10.0))])
    hit = np.array([20.0, 19.5])
    src = hit - 30 * d
    pos = rf.pose_through(src, hit, -1)
    point = hit + 0.8 * d
    free0, _ = measurement_cells(t.shape, pos, point, None, False, 0.5, 1e9)
    free2, _ = measurement_cells(t.shape, pos, point, None, False, 0.5 + 2 * 0.3, 1e9)
    assert (t[free0[:, 0], free0[:, 1]] == FULL).any()
    assert not (t[free2[:, 0], free2[:, 1]] == FULL).any()
    with pytest.raises(NbvInputError, match="noise_laser_margin_sigmas"):
        RunConfig(noise_laser_margin_sigmas=float("nan"))
