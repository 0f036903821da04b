"""The generated 2D bodies (fixed seeds, tuning / evaluation halves) and the five-pointed star with acute spikes:
the planner must not give up after a spike with either aim."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.evaluation import coverage, plannable_boundary
from agiprobot_measurement.nbv.planar.families import FAMILIES, family_bodies, make_body
from agiprobot_measurement.nbv.planar.loop import run
from agiprobot_measurement.nbv.planar.range_finder import RangeFinder2D
from agiprobot_measurement.nbv.planar.run_config import RunConfig


def test_the_halves_are_disjoint_cover_every_family_and_are_reproducible():
    tuning, evaluation = family_bodies("tuning"), family_bodies("evaluation")
    assert not set(tuning) & set(evaluation)
    assert sorted(tuning + evaluation) == sorted(family_bodies("all"))
    for half in (tuning, evaluation):
        assert {name.rsplit("_", 1)[0] for name in half} == set(FAMILIES)
    for name in family_bodies("all"):
        body = make_body(name)
        assert body.shape == (400, 400) and (body == 1).sum() > 500, name
        assert np.array_equal(body, make_body(name)), name  # fixed seeds
        # within the grid with room for the standoff's search: nothing near the border
        assert not (body[:40] == 1).any() and not (body[-40:] == 1).any(), name
    assert not np.array_equal(make_body("star_0"), make_body("star_1"))
    with pytest.raises(NbvInputError):
        make_body("star_99")
    with pytest.raises(NbvInputError):
        family_bodies("validation")


@pytest.mark.parametrize("aim", ["centre", "edge_midpoints"])
def test_the_star_is_followed_round_its_acute_spikes(aim):
    # without re-acquisition the contour chain ends at a spike tip: 31 % (centre) and 29 % (edge midpoints) of the
    # plannable boundary with stratpix; the sweeps round the body brought it to 0.95 / 0.98, the frontier views on top
    # must not lose that
    rf = RangeFinder2D.from_config().with_length(250.0)
    truth = make_body("star5")
    plannable = plannable_boundary(truth, rf, aim)
    result = run(truth, rf, RunConfig(script="stratpix", aim=aim))
    assert result.termination == "growth_points_exhausted"
    assert result.outcomes["reacquire: new contour"] + result.outcomes["reacquire: frontier contour"] >= 1
    assert coverage(result.model, plannable) >= 0.95
    # without either re-acquisition (and the centre fallback) the same run stops early
    bare = RunConfig(
        script="stratpix", aim=aim, reacquire_sweeps=0, reacquire_frontier=False, aim_fallback_centre=False
    )
    single = run(truth, rf, bare)
    assert coverage(single.model, plannable) < 0.6
    if aim == "edge_midpoints":
        # a candidate without an edge-midpoint view is planned onto its centre: the chain goes on past the spikes
        fallback = run(truth, rf, replace(bare, aim_fallback_centre=True))
        assert fallback.outcomes["aim fallback: centre"] >= 1
        assert coverage(fallback.model, plannable) >= coverage(single.model, plannable) + 0.2


def test_frontier_views_recover_a_spiked_star_the_sweeps_leave():
    # the tuning body with seven narrow spikes: the sweeps look along rays through the body's centre only and leave
    # the spikes' flanks unseen (fullpix, centre aim: 0.50 of the plannable boundary); the frontier views after
    # them find the flanks (0.98). Alone, without the sweeps, they do not (0.27): they stay near the known body
    rf = RangeFinder2D.from_config().with_length(250.0)
    truth = make_body("star_4")
    plannable = plannable_boundary(truth, rf, "centre")
    sweeps_only = run(truth, rf, RunConfig(script="fullpix", reacquire_frontier=False))
    both = run(truth, rf, RunConfig(script="fullpix"))
    assert coverage(sweeps_only.model, plannable) < 0.8
    assert both.outcomes["reacquire: frontier contour"] >= 1
    assert coverage(both.model, plannable) >= 0.95
