"""stratpix's strategy-2 orbit budget: the predicted orbit motion and the switch to strategy 1's jump."""

import math

import numpy as np
import pytest

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.loop import run
from agiprobot_measurement.nbv.planar.range_finder import RangeFinder2D
from agiprobot_measurement.nbv.planar.run_config import RunConfig
from agiprobot_measurement.nbv.planar.strategies import OrbitState, orbit_motion_to, plan_s2


def _rf():
    return RangeFinder2D(12.0, math.pi / 2, math.atan2(30.0, 12.0), 0.45)


def _orbit(rotation=1, max_turn_deg=360.0):
    # start on the -y normal of pp = (20, 20), turning by 10 degrees per step
    return OrbitState((20, 20), -math.pi / 2, rotation, math.radians(10.0), max_turn_rad=math.radians(max_turn_deg))


def test_orbit_motion_to_the_first_step_is_the_lead_in_only():
    rf, orbit = _rf(), _orbit()
    first = plan_s2(rf, _orbit()).pos[0]
    src = first + np.array([3.0, 4.0])
    # step 1's laser aims at pp + u(theta_1 + 90 deg)
    theta1 = -math.pi / 2 + math.radians(10.0)
    q = np.array([20.0, 20.0]) + np.array([math.cos(theta1 + math.pi / 2), math.sin(theta1 + math.pi / 2)])
    assert orbit_motion_to(rf, orbit, q, src) == pytest.approx(5.0)
    assert orbit.k == 0  # not advanced


def test_orbit_motion_to_adds_one_chord_per_further_step_and_is_inf_beyond_the_turn():
    rf = _rf()
    chord = 2 * rf.standoff_cells * math.sin(math.radians(5.0))
    theta4 = -math.pi / 2 + 4 * math.radians(10.0)
    q4 = np.array([20.0, 20.0]) + np.array([math.cos(theta4 + math.pi / 2), math.sin(theta4 + math.pi / 2)])
    first = plan_s2(rf, _orbit()).pos[0]
    assert orbit_motion_to(rf, _orbit(), q4, first) == pytest.approx(3 * chord)
    # the same cell needs 4 steps, but the orbit gives up after 3
    assert math.isinf(orbit_motion_to(rf, _orbit(max_turn_deg=30.0), q4, first))
    # turning the other way: 14 steps to theta = 130 deg, whose laser aims at pp + u(40 deg) as well; the first pose
    # (-100 deg) is two chords from the other orbit's first pose (-80 deg)
    expected = 2 * rf.standoff_cells * math.sin(math.radians(10.0)) + 13 * chord
    assert orbit_motion_to(rf, _orbit(rotation=-1), q4, first) == pytest.approx(expected)


@pytest.mark.parametrize(
    "kw", [{"s2_orbit_budget": "cheap"}, {"s2_orbit_budget_factor": float("nan")}, {"s2_orbit_budget_factor": 0}]
)
def test_bad_orbit_budget_options_are_refused(kw):
    with pytest.raises(NbvInputError, match="s2_orbit_budget"):
        RunConfig(script="stratpix", **kw)


def _triangle(n=100):
    # an acute apex at the top: strategy 2 orbits round it
    xs, ys = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return (ys >= 30) & (ys <= 70) & (np.abs(xs - 50) <= (70 - ys) * 0.3)


def test_stratpix_leaves_an_orbit_that_outgrows_strategy_1s_jump():
    rf = _rf()
    truth = _triangle()
    budget = run(truth, rf, RunConfig(script="stratpix", s2_orbit_budget="s1_jump", s2_orbit_budget_factor=1.0))
    free = run(truth, rf, RunConfig(script="stratpix", s2_orbit_budget="none"))
    assert budget.termination == free.termination == "growth_points_exhausted"
    assert budget.outcomes["S2 orbit left for S1: longer than S1's jump"] > 0
    assert free.outcomes["S2 orbit left for S1: longer than S1's jump"] == 0
    assert budget.outcomes["D2"] < free.outcomes["D2"]


def _orbit_outcomes(result):
    return {k: v for k, v in result.outcomes.items() if k.startswith("S2")}


def test_s1_view_is_the_default_and_a_known_budget():
    assert RunConfig().s2_orbit_budget == "s1_view"
    assert RunConfig(script="stratpix", s2_orbit_budget="s1_view").s2_orbit_budget == "s1_view"


def test_stratpix_leaves_an_orbit_whose_step_leads_away_from_strategy_1s_view():
    rf = _rf()
    truth = _triangle()
    steered = run(truth, rf, RunConfig(script="stratpix", s2_orbit_budget="s1_view"))
    free = run(truth, rf, RunConfig(script="stratpix", s2_orbit_budget="none"))
    assert steered.termination == free.termination == "growth_points_exhausted"
    assert steered.outcomes["S2 orbit left for S1: step leads away from S1's view"] > 0
    assert _orbit_outcomes(free).get("S2 orbit left for S1: step leads away from S1's view", 0) == 0
    assert steered.outcomes["D2"] < free.outcomes["D2"]


def test_s1_view_ends_the_candidate_when_no_switch_is_left():
    # with one switch per candidate the step leading away cannot hand over to strategy 1: cc is unmeasurable
    result = run(_triangle(), _rf(), RunConfig(script="stratpix", max_switches_per_candidate=1))
    assert result.termination == "growth_points_exhausted"
    assert result.outcomes["S2 orbit ended: leads away from S1's view, no switch left"] > 0


def test_stratpix_goes_back_to_strategy_0_when_strategy_1_has_no_view():
    rf = _rf()
    truth = _triangle()
    back = run(truth, rf, RunConfig(script="stratpix", s2_no_s1_view_back_to_s0=True))
    off = run(truth, rf, RunConfig(script="stratpix", s2_no_s1_view_back_to_s0=False))
    assert back.termination == off.termination == "growth_points_exhausted"
    assert back.outcomes["S2 not started: S1 finds no view, back to S0"] > 0
    assert off.outcomes["S2 not started: S1 finds no view, back to S0"] == 0
    # each candidate sent back is one that would otherwise have been marked unmeasurable on the spot
    assert off.outcomes["S2 not started: S1 finds no view"] > back.outcomes["S2 not started: S1 finds no view"]
