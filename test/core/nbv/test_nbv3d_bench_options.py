"""scripts/bench_nbv.py's --ours-option: numeric request fields for 'ours', bad items named."""

from __future__ import annotations

import pytest

from agiprobot_measurement.errors import InputError


@pytest.fixture(scope="module")
def bench(load_script):
    return load_script("bench_nbv")


def test_numeric_request_fields_become_overrides(bench):
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
        ("cost_weight=fast", "is not a number"),
    ],
)
def test_bad_items_are_refused_with_their_text(bench, item, named):
    with pytest.raises(InputError, match=named) as error:
        bench.ours_overrides([item])
    assert repr(item) in str(error.value)
