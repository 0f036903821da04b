"""The 3D benchmark's --ours-option (numeric request fields for 'ours') and --ours-weight (its score terms):
bad items named."""

from __future__ import annotations

import pytest

from agiprobot_measurement.errors import InputError
from benchmarks.nbv3d import loop as bench


def test_numeric_request_fields_become_overrides():
    assert bench.ours_overrides(["cost_weight=0.15", "min_gain_area_mm2=50"]) == {
        "cost_weight": 0.15,
        "min_gain_area_mm2": 50.0,
    }


@pytest.mark.parametrize(
    ("item", "named"),
    [
        ("gain=ours", "expected FIELD=NUMBER"),  # not numeric: --methods chooses it
        ("seed=3", "expected FIELD=NUMBER"),  # --seed / --seeds
        ("cost_weight", "expected FIELD=NUMBER"),
        ("cost_weight=fast", "expected a number"),
    ],
)
def test_bad_items_are_refused_with_their_text(item, named):
    with pytest.raises(InputError, match=named) as error:
        bench.ours_overrides([item])
    assert repr(item) in str(error.value)


def test_score_weights_replace_the_configured_ones():
    assert bench.ours_weights([]) is None
    assert bench.ours_weights(["proximity_count=1", "average_entropy=2", "expected_surface=0"]) == {
        "proximity_count": 1.0,
        "average_entropy": 2.0,
        "expected_surface": 0.0,
    }


@pytest.mark.parametrize(
    ("items", "named"),
    [
        (["curiosity=1"], "expected TERM=WEIGHT"),
        (["proximity_count"], "expected TERM=WEIGHT"),
        (["proximity_count=lots"], "expected a number"),
        (["proximity_count=-1"], "must be >= 0"),
        (["proximity_count=nan"], "must be a finite number"),
        (["proximity_count=0"], "at least one weight must be positive"),
    ],
)
def test_bad_score_weights_are_refused(items, named):
    with pytest.raises(InputError, match=named):
        bench.ours_weights(items)


def test_config_options_override_numeric_entries():
    config = {"motion": {"opening_elevation_deg": 90.0, "via_poses": 8}, "planning": {"cost_schedule": "constant"}}
    assert bench.config_overrides(["motion.opening_elevation_deg=55", "motion.via_poses=0"], config) == {
        ("motion", "opening_elevation_deg"): 55.0,
        ("motion", "via_poses"): 0.0,
    }


@pytest.mark.parametrize(
    ("item", "named"),
    [
        ("motion.opening_elevation_deg", "expected SECTION.KEY=NUMBER"),
        ("opening_elevation_deg=55", "expected SECTION.KEY=NUMBER"),
        ("motion.warp_speed=9", "no numeric entry motion.warp_speed"),
        ("planning.cost_schedule=1", "no numeric entry planning.cost_schedule"),  # a string entry
        ("motion.opening_elevation_deg=steep", "expected a number"),
        ("motion.opening_elevation_deg=inf", "must be a finite number"),
    ],
)
def test_bad_config_options_are_refused(item, named):
    config = {"motion": {"opening_elevation_deg": 90.0}, "planning": {"cost_schedule": "constant"}}
    with pytest.raises(InputError, match=named):
        bench.config_overrides([item], config)


def test_compared_mixes_are_refused_under_their_own_option():
    assert bench.ours_weights(["proximity_count=1", "report=0.3"], flag="--compare-weights") == {
        "proximity_count": 1.0,
        "report": 0.3,
    }
    with pytest.raises(InputError, match="--compare-weights 'report=much'"):
        bench.ours_weights(["report=much"], flag="--compare-weights")
