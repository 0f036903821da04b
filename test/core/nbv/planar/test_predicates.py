"""The report's predicates and helpers on small hand-made grids."""

import numpy as np
import pytest

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, PROBABLY_EMPTY, UNKNOWN
from agiprobot_measurement.nbv.planar.predicates import (
    candidate_mask,
    compute_direction,
    general_growth_mask,
    get_distance_vc,
    get_nearest_pp,
    getcandidates2d,
    getpoints2d,
    growth_mask,
    predicted_point,
    trace_contour,
    verifypoint2d,
)


def _segment_grid():
    """A measured horizontal contour (cells (2..5, 3)) with the free side below and unknown above / beyond."""
    w = np.zeros((10, 8))
    w[:, 0:3] = EMPTY
    w[2:6, 3] = FULL
    w[0:2, 3] = EMPTY
    return w


def test_general_and_strict_candidates():
    w = _segment_grid()
    general = candidate_mask(w)
    assert general[3, 4] and general[6, 3] and general[6, 4]  # unknown next to full
    assert not general[8, 5]  # far from any full cell
    c = {tuple(x) for x in getcandidates2d(w, (5, 3))}
    # unknown, next to an empty cell and to X: only the cell beyond the contour's end; (6, 4) and (4, 4) touch no
    # empty cell, (6, 2) is empty itself
    assert c == {(6, 3)}
    assert {tuple(x) for x in getcandidates2d(w, (2, 3))} == {(1, 4), (2, 4), (3, 4)} - {(3, 4)}


def test_growth_points_and_verification():
    w = _segment_grid()
    g = growth_mask(w)
    assert g[5, 3] and g[2, 3]  # both ends touch unknown cells next to empty ones
    assert g[3, 3]  # (2, 4) next to it touches the empty (1, 3)
    assert not g[4, 3]  # its unknown neighbours touch no empty cell
    assert general_growth_mask(w)[4, 3]  # the report's loose definition includes it
    assert verifypoint2d(w, (5, 3)) == 1 and verifypoint2d(w, (4, 3)) == 0 and verifypoint2d(w, (0, 0)) == 0
    assert {tuple(p) for p in getpoints2d(w)} == {tuple(p) for p in np.argwhere(g)}
    w2 = w.copy()
    w2[w2 == UNKNOWN] = PROBABLY_EMPTY  # every candidate used up
    assert getpoints2d(w2).tolist() == [[-1, -1]]
    assert get_nearest_pp(w2, None, (5, 3)) == (-1, -1)
    assert get_nearest_pp(w, None, (9, 3)) == (5, 3)
    assert get_nearest_pp(w, None, (0, 3)) == (2, 3)


def test_contour_line_and_predicted_point():
    w = _segment_grid()
    traced = trace_contour(w, (5, 3), 3)
    assert [tuple(t) for t in traced] == [(5, 3), (4, 3), (3, 3)]
    d = compute_direction(w, (5, 3), 4)
    np.testing.assert_allclose(d, [1.0, 0.0], atol=1e-12)  # points where the contour goes on
    assert predicted_point(w, (5, 3)) == (6, 3)  # on the line, ahead
    assert compute_direction(w, (0, 0), 4) is None
    assert get_distance_vc((0, 0), (1, 0), (3, 2)) == pytest.approx(2.0)
    with pytest.raises(NbvInputError):
        get_distance_vc((1, 1), (1, 1), (0, 0))


def test_diagonal_contour_direction():
    w = np.full((12, 12), EMPTY)
    for k in range(2, 7):
        w[k, k] = FULL
    w[7:, :] = UNKNOWN
    d = compute_direction(w, (6, 6), 5)
    np.testing.assert_allclose(d, np.array([1.0, 1.0]) / np.sqrt(2), atol=1e-9)


def _apex_grid():
    """A measured row (2..5, 3) whose free side is known only near its start (x <= 2): around the end (5, 3) no ray
    has passed yet, as beyond an acute apex, so no unknown cell there touches an empty one."""
    w = np.zeros((10, 8))
    w[0:3, 0:3] = EMPTY
    w[0:2, 3:] = EMPTY
    w[2:6, 3] = FULL
    return w


def test_contour_end_takes_the_general_candidates():
    from agiprobot_measurement.nbv.planar.predicates import contour_end_mask, driving_candidate_mask

    w = _apex_grid()
    ends = contour_end_mask(w)
    assert ends[2, 3] and ends[5, 3] and not ends[3, 3] and not ends[4, 3]
    end = (5, 3)
    c = {tuple(x) for x in getcandidates2d(w, end)}
    # the report's strict rule finds nothing here; the end takes its unknown 8-neighbours
    assert c == {(4, 2), (5, 2), (6, 2), (6, 3), (6, 4), (5, 4), (4, 4)}
    assert growth_mask(w)[end] and verifypoint2d(w, end) == 1
    assert predicted_point(w, end) == (6, 3)  # straight on, where the contour most probably continues
    # the start (2, 3) keeps the strict candidates: it has some
    assert {tuple(x) for x in getcandidates2d(w, (2, 3))} == {(3, 2), (2, 4)}
    # the vectorised mask is the union of the per-growth-point candidates
    union = set()
    for p in np.argwhere(growth_mask(w)):
        union |= {tuple(x) for x in getcandidates2d(w, p)}
    assert {tuple(x) for x in np.argwhere(driving_candidate_mask(w))} == union
    # used-up candidates stop the end being a growth point
    for x in c:
        w[x] = PROBABLY_EMPTY
    assert not growth_mask(w)[end] and verifypoint2d(w, end) == 0


def test_a_right_angle_corner_is_not_a_contour_end():
    from agiprobot_measurement.nbv.planar.predicates import contour_end_mask

    w = np.zeros((9, 9))
    w[2:6, 3] = FULL
    w[5, 4:7] = FULL
    w[6, 7] = FULL
    assert {tuple(x) for x in np.argwhere(contour_end_mask(w))} == {(2, 3), (6, 7)}
    lonely = np.zeros((5, 5))
    lonely[2, 2] = FULL
    assert not contour_end_mask(lonely).any()  # an isolated cell is no contour
