"""Frontier re-acquisition: which cells are frontier, their outward direction, and the planned view."""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, UNKNOWN
from agiprobot_measurement.nbv.planar.range_finder import RangeFinder2D
from agiprobot_measurement.nbv.planar.reacquisition import (
    frontier_normal,
    frontier_targets,
    is_frontier_cell,
    plan_frontier_view,
)
from agiprobot_measurement.nbv.planar.scoring import ScoreConfig
from agiprobot_measurement.nbv.planar.strategies import NoView
from agiprobot_measurement.nbv.planar.traversal import first_blocking


def _model():
    # known empty below row 20, unknown above; a known full cell at (30, 21)
    m = np.full((60, 60), UNKNOWN)
    m[:, :20] = EMPTY
    m[30, 21] = FULL
    return m


def test_frontier_cells_border_known_empty_and_come_nearest_to_the_body_first():
    m = _model()
    tried = np.zeros(m.shape, dtype=bool)
    cells = frontier_targets(m, tried, max_distance_cells=5.0)
    assert len(cells) > 0
    assert all(is_frontier_cell(m, c) for c in cells)
    assert set(cells[:, 1]) == {20}  # the unknown row next to the empty half, nothing deeper
    d = np.hypot(cells[:, 0] - 30, cells[:, 1] - 21)
    assert np.all(d <= 5.0 + 1e-9) and np.all(np.diff(d) >= -1e-9)
    assert tuple(cells[0]) in {(29, 20), (30, 20), (31, 20)}
    tried[30, 20] = True
    assert (30, 20) not in {tuple(c) for c in frontier_targets(m, tried, 5.0)}
    # no known body, no frontier to re-acquire
    m2 = m.copy()
    m2[30, 21] = UNKNOWN
    assert len(frontier_targets(m2, tried, 5.0)) == 0
    assert not is_frontier_cell(m, (30, 21)) and not is_frontier_cell(m, (30, 25))


def test_the_outward_direction_points_into_known_empty_space():
    m = _model()
    n = frontier_normal(m, (30, 20))
    assert n is not None and n[1] < -0.9
    assert frontier_normal(m, (30, 40)) is None


def test_the_planned_view_comes_from_the_empty_side_and_no_full_cell_blocks_it():
    m = np.full((400, 400), UNKNOWN)
    m[:, :200] = EMPTY
    m[200, 201] = FULL
    # a known full wall in the empty half that hides part of the frontier cell's empty side
    m[150:199, 120] = FULL
    rf = RangeFinder2D.from_config().with_length(250.0)
    target = (200, 200)
    full_cells = np.argwhere(m == FULL)
    plan = plan_frontier_view(m, rf, target, np.array([[200.0, 200.0]]), full_cells, None, ScoreConfig())
    assert not isinstance(plan, NoView)
    src, cam, aim = plan.pos
    assert src[1] < 200 and np.allclose(aim, target)
    assert math.isclose(float(np.hypot(*(src - aim))), rf.standoff_cells, rel_tol=1e-9)
    full = m == FULL
    assert first_blocking(full, src, aim, skip=target)[0] < 0
    assert first_blocking(full, aim, cam, skip=target)[0] < 0
    # walled in by known full cells on every side: nothing to plan
    boxed = m.copy()
    boxed[195:206, 195] = FULL
    boxed[195:206, 205] = FULL
    boxed[195, 195:206] = FULL
    boxed[205, 195:206] = FULL
    plan = plan_frontier_view(
        boxed, rf, target, np.array([[200.0, 200.0]]), np.argwhere(boxed == FULL), None, ScoreConfig()
    )
    assert isinstance(plan, NoView)
