"""The gain-based stopping rule: the predicted and the realised new surface against the ignored detail, and the
saturation against the budget (what the rest of the views would add at the map's recent growth, against a share of
the observed surface)."""

from __future__ import annotations

import math

from agiprobot_measurement.nbv.volumetric.stopping import StoppingRule


def fired(rule: StoppingRule, growth_mm2, views_left, realised_mm2=1000.0, expected_mm2=1000.0,
          observed_mm2=50_000.0) -> list[bool]:  # fmt: skip
    return [
        rule.update(1.0, expected_mm2 * 1e-6, realised_mm2 * 1e-6, observed_mm2 * 1e-6, g * 1e-6, left)
        for g, left in zip(growth_mm2, views_left, strict=True)
    ]


def test_saturation_fires_when_the_rest_of_the_budget_would_add_less_than_the_share():
    # 0.05 x 50,000 mm^2 = 2,500 mm^2 for the rest of the budget; every view above the 100 mm^2 ignored detail
    rule = StoppingRule(100.0, 0.0, 3, budget_growth_share=0.05, growth_window=3)
    # the mean of the last 3 times the views left: 3,133 x 10, 567 x 9, 400 x 8 = 3,200, 300 x 7 = 2,100 < 2,500
    growth = [8_000, 800, 600, 300, 300, 300]
    assert fired(rule, growth, [12, 11, 10, 9, 8, 7]) == [False] * 5 + [True]


def test_saturation_weighs_the_views_left():
    # the same slow growth fires near the end of the budget, not with many views left
    growth = [400, 400, 400, 400]
    early = StoppingRule(100.0, 0.0, 3, budget_growth_share=0.05, growth_window=3)
    assert not any(fired(early, growth, [19, 18, 17, 16]))
    late = StoppingRule(100.0, 0.0, 3, budget_growth_share=0.05, growth_window=3)
    assert fired(late, growth, [8, 7, 6, 5]) == [False, False, True, True]  # 400 x 6 = 2,400 < 2,500


def test_saturation_needs_a_full_window_and_is_off_by_default():
    rule = StoppingRule(100.0, 0.0, 3, budget_growth_share=0.05, growth_window=3)
    assert rule.projected_growth_m2(5) == math.inf
    assert fired(rule, [0, 0, 0], [3, 2, 1]) == [False, False, True]
    rule = StoppingRule(100.0, 0.0, 3)
    assert not any(fired(rule, [0, 0, 0, 0], [4, 3, 2, 1]))


def test_the_ignored_detail_rules_still_fire():
    rule = StoppingRule(100.0, 0.0, 3)
    assert fired(rule, [1_000] * 3, [10] * 3, expected_mm2=50.0) == [False, True, True]  # predicted, twice running
    rule = StoppingRule(100.0, 0.0, 3)
    assert fired(rule, [1_000] * 3, [10] * 3, realised_mm2=50.0) == [False, False, True]  # realised, three running
