"""The gain-based stopping rule: the predicted and the realised new surface against the ignored detail, and the
saturation of the observed surface (what the last views added together against a share of it)."""

from __future__ import annotations

from agiprobot_measurement.nbv.volumetric.stopping import StoppingRule


def fired(rule: StoppingRule, realised_mm2, expected_mm2=1000.0, observed_mm2=50_000.0) -> list[bool]:
    return [rule.update(1.0, expected_mm2 * 1e-6, r * 1e-6, observed_mm2 * 1e-6) for r in realised_mm2]


def test_saturation_fires_when_the_last_views_together_add_less_than_the_share():
    # 0.01 x 50,000 mm^2 = 500 mm^2 over the last 3 views; every view above the 100 mm^2 ignored detail
    rule = StoppingRule(100.0, 0.0, 3, min_growth_share=0.01)
    assert fired(rule, [20_000, 5_000, 300, 150, 120, 110]) == [False, False, False, False, False, True]
    # one big view in the window holds it off
    rule = StoppingRule(100.0, 0.0, 3, min_growth_share=0.01)
    assert fired(rule, [300, 150, 2_000, 150, 120, 110]) == [False, False, False, False, False, True]
    # off by default: the same views never fire it
    rule = StoppingRule(100.0, 0.0, 3)
    assert not any(fired(rule, [20_000, 5_000, 300, 150, 120, 110]))


def test_the_ignored_detail_rules_still_fire():
    rule = StoppingRule(100.0, 0.0, 3)
    assert fired(rule, [1_000, 1_000, 1_000], expected_mm2=50.0) == [False, True, True]  # predicted, twice running
    rule = StoppingRule(100.0, 0.0, 3)
    assert fired(rule, [50, 50, 50]) == [False, False, True]  # realised, three views running
