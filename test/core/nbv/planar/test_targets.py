"""The planner changes made for the benchmark targets: noisy returns, predicted returns, strategy 2, circpix."""

import math

import numpy as np
import pytest

from agiprobot_measurement.nbv.planar.evaluation import measurable_boundary, summarize
from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL
from agiprobot_measurement.nbv.planar.loop import run
from agiprobot_measurement.nbv.planar.range_finder import (
    RangeFinder2D,
    assign_noisy_cell,
    measurement_cells,
    noisy_return_margin_cells,
)
from agiprobot_measurement.nbv.planar.run_config import RunConfig
from agiprobot_measurement.nbv.planar.strategies import Kind, classify, predicted_return_free


def _laser_up_pose(x=10.0, y_src=-20.0, y_aim=5.0):
    # source below, laser along +y, camera to the side
    return np.array([[x, y_src], [x + 8.0, y_src], [x, y_aim]])


# --- noisy returns ---------------------------------------------------------------------------------------------


def test_noisy_cell_is_the_half_cell_deeper_guess_when_that_cell_is_not_known_empty():
    m = np.zeros((20, 20))
    pos = _laser_up_pose()
    # surface point on the entry edge of cell (10, 5) (y = 4.5), measured 0.3 short: the guess is still (10, 5)
    cell, snapped = assign_noisy_cell(m, pos, np.array([10.0, 4.2]), 0.6)
    assert cell == (10, 5) and not snapped


def test_noisy_cell_in_known_empty_space_snaps_to_the_next_cell_that_is_not_known_empty():
    m = np.zeros((20, 20))
    m[10, :6] = EMPTY  # the laser has proven (10, 0..5) free before
    pos = _laser_up_pose()
    cell, snapped = assign_noisy_cell(m, pos, np.array([10.0, 5.1]), 0.6)  # guess (10, 6) is unknown: kept
    assert cell == (10, 6) and not snapped
    cell, snapped = assign_noisy_cell(m, pos, np.array([10.0, 4.7]), 0.6)  # guess (10, 5) is known empty
    assert cell == (10, 6) and snapped


def test_noisy_cell_keeps_the_guess_when_the_whole_window_is_known_empty():
    m = np.zeros((20, 20))
    m[10, :12] = EMPTY
    cell, snapped = assign_noisy_cell(m, _laser_up_pose(), np.array([10.0, 4.7]), 0.6)
    # the report's fusion then makes the conflicting cell unknown again
    assert cell == (10, 5) and not snapped


def test_noisy_return_margin_grows_with_the_laser_camera_angle():
    short = RangeFinder2D.from_config().with_length(40.0)
    long = RangeFinder2D.from_config().with_length(250.0)
    aim = np.array([100.0, 21.0])
    x = np.array([100.0, 21.0])
    m_short = noisy_return_margin_cells(short.poses(aim, -math.pi / 2, 1)[0], x, 0.6)
    m_long = noisy_return_margin_cells(long.poses(aim, -math.pi / 2, 1)[0], x, 0.6)
    assert m_short == pytest.approx(0.5 + 0.6 / math.cos(short.triangulation_angle_rad), rel=1e-3)
    assert m_long == pytest.approx(0.5 + 0.6 / math.cos(long.triangulation_angle_rad), rel=1e-3)
    assert m_long > m_short > 1.0


@pytest.mark.parametrize("side", [1, -1])
def test_a_too_deep_point_does_not_carve_the_body_with_the_angle_aware_margin(side):
    rf = RangeFinder2D.from_config().with_length(250.0)
    pos = rf.poses(np.array([100.0, 21.0]), -math.pi / 2, side)[0]
    # the body is y >= 20.5 (cells j >= 21); the point is measured 0.45 too deep
    x = np.array([100.0, 20.95])
    old, _ = measurement_cells((200, 200), pos, x, (100, 21), laser_margin_cells=0.5, return_margin_cells=0.5)
    margin = noisy_return_margin_cells(pos, x, 0.6)
    new, _ = measurement_cells((200, 200), pos, x, (100, 21), laser_margin_cells=0.5, return_margin_cells=margin)
    assert (old[:, 1] >= 21).any()  # the fixed half-cell margin erases body cells next to the point
    assert not (new[:, 1] >= 21).any()


# --- classification and predicted returns ----------------------------------------------------------------------


def test_strategy_2_counts_any_unknown_cell_next_to_a_full_one_as_its_candidate():
    m = np.zeros((10, 10))
    m[4, 4] = FULL  # no empty cell known anywhere: no getcandidates2d candidate exists
    assert classify((5, 5), None, m, m) is Kind.C
    assert classify((5, 5), None, m, m, general_candidates=True) is Kind.B
    assert classify((8, 8), None, m, m, general_candidates=True) is Kind.C


def test_predicted_return_leaves_from_the_laser_entry_point_not_from_the_cell_centre():
    full = np.zeros((30, 30), dtype=bool)
    full[9, 11] = True  # the known full diagonal neighbour of cc = (10, 10), up-left
    cc = (10, 10)
    # laser straight down, entering cc through its top edge near the left corner; camera far to the left, nearly
    # level (a long laser-camera distance)
    src = np.array([9.6, 40.0])
    aim = np.array([9.6, 10.4])
    cam = np.array([-10.0, 11.2])
    pos = np.stack([src, cam, aim])
    from agiprobot_measurement.nbv.planar.traversal import first_blocking

    # from the centre the camera ray is clear ...
    assert first_blocking(full, np.array(cc, dtype=float), cam, skip=cc)[0] < 0
    # ... but the return leaves from where the laser enters cc and grazes the neighbour
    assert not predicted_return_free(full, pos, cc)
    full[9, 11] = False
    assert predicted_return_free(full, pos, cc)


# --- whole runs ------------------------------------------------------------------------------------------------


def _rf_long():
    # a small rig with a large laser-camera angle (about 50 deg at the 20-cell standoff)
    return RangeFinder2D(24.0, math.pi / 2, math.atan2(20.0, 24.0), 0.5)


def _u_shape(n=100):
    t = np.zeros((n, n), dtype=bool)
    t[30:70, 30:70] = True
    t[46:54, 42:70] = False  # a narrow, deep slot
    return t


@pytest.mark.parametrize(("strict", "known_empty_behind"), [(True, 0), (False, 0), (False, 5), (False, 4)])
def test_circpix_strict_check_refuses_a_candidate_with_known_full_cells_behind_it(strict, known_empty_behind):
    from agiprobot_measurement.nbv.planar.loop import _Engine

    rf = RangeFinder2D(12.0, math.pi / 2, math.atan2(30.0, 12.0), 0.45)
    truth = np.full((60, 60), EMPTY)
    truth[30, 30] = FULL
    eng = _Engine(truth, rf, RunConfig(script="circpix", circ_strict_d0_check=strict))
    eng.m[30, 30] = FULL
    eng.m[20:30, 31] = EMPTY
    eng.m[29, 30] = eng.m[29, 32] = EMPTY
    # 8 cells behind cc = (30, 31) on the laser from (0, 31), past unknown cells: an empty cc would give a D0
    eng.m[38, 31] = FULL
    # cells 31.. behind cc already known empty: 7 - known_empty_behind unknown cells are left before the full one
    eng.m[31 : 31 + known_empty_behind, 31] = EMPTY
    eng.w[:] = eng.m
    eng.bbox = [20, 40, 28, 34]
    near, far = rf.depth_window_cells()
    _, cc = eng._circ_plan(np.array([0.0, 31.0]), near, far)
    unknown_between = 7 - known_empty_behind
    if strict or unknown_between <= eng.cfg.circ_d0_max_unknown_cells:
        assert cc != (30, 31)
    else:  # the loose rule (first cell behind not known full, none within 5 cells) accepts it
        assert cc == (30, 31)


def test_stratpix_does_not_orbit_for_a_candidate_strategy_1_cannot_plan():
    rf = RangeFinder2D(12.0, math.pi / 2, math.atan2(30.0, 12.0), 0.45)
    truth = _u_shape()
    # without strategy 0's re-plan, so that a candidate strategy 1 cannot plan ends unmeasurable on the spot
    on = run(truth, rf, RunConfig(script="stratpix", s2_no_s1_view_back_to_s0=False))
    off = run(truth, rf, RunConfig(script="stratpix", s2_feasibility_check=False, s2_no_s1_view_back_to_s0=False))
    assert on.termination == off.termination == "growth_points_exhausted"
    assert on.outcomes["S2 not started: S1 finds no view"] > 0
    assert on.outcomes["D2"] < off.outcomes["D2"]


def test_noise_with_a_long_baseline_keeps_the_surface():
    rf = _rf_long()
    xs, ys = np.meshgrid(np.arange(100), np.arange(100), indexing="ij")
    truth = (xs - 50) ** 2 + (ys - 50) ** 2 <= 15**2
    meas = measurable_boundary(np.where(truth, FULL, EMPTY), rf)
    cov = {}
    for k in (0.0, 2.0):
        # a single pass: reopening the marked candidates (or re-acquisition by sweeps or frontier views) would also
        # win back what the missing margin erased
        config = RunConfig(
            script="fullpix",
            noise_sigma_cells=0.3,
            seed=0,
            noise_return_margin_sigmas=k,
            noise_reopen_passes=0,
            reacquire_sweeps=0,
            reacquire_frontier=False,
        )
        cov[k] = summarize(run(truth, rf, config), meas, "disc")["coverage"]
    assert cov[2.0] >= 0.9
    assert cov[2.0] > cov[0.0]
