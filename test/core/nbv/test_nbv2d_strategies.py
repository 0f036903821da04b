"""Outcome classification per strategy and the transition tables."""

import numpy as np
import pytest

from agiprobot_measurement.nbv.grid import EMPTY, FULL
from agiprobot_measurement.nbv.strategies import LABELS, TRANSITIONS, Action, Kind, Strategy, classify, label_of


def _model():
    m = np.zeros((10, 10))
    m[:, 0:3] = EMPTY
    m[2:6, 3] = FULL
    return m


@pytest.mark.parametrize(
    ("hit", "kind"),
    [
        ((6, 3), Kind.A),  # the target
        ((1, 3), Kind.B),  # another candidate: unknown, next to empty and full
        ((7, 7), Kind.C),  # another unknown cell
        ((4, 3), Kind.D),  # already seen (full)
        ((4, 1), Kind.D),  # already seen (empty)
        (None, Kind.E),
    ],
)
def test_classify(hit, kind):
    m = _model()
    assert classify(hit, (6, 3), m, m) is kind


def test_labels_per_strategy():
    assert [label_of(Strategy.S0, k) for k in Kind] == ["A0", "B0", "C0", "D0", "E0"]
    assert [label_of(Strategy.S1, k) for k in Kind] == ["A1", "B1", "B1", "C1", "D1"]
    assert [label_of(Strategy.S2, k) for k in Kind] == ["A2", "A2", "B2", "C2", "D2"]


def test_transition_tables_cover_every_label_of_their_strategies():
    assert set(TRANSITIONS["fullpix"]) == set(LABELS[Strategy.S0].values()) | set(LABELS[Strategy.S1].values())
    assert set(TRANSITIONS["stratpix"]) == {lab for s in Strategy for lab in LABELS[s].values()}
    full, strat = TRANSITIONS["fullpix"], TRANSITIONS["stratpix"]
    assert full["A0"] == (Action.SUCCESS, Strategy.S0)
    assert full["D0"][0] is Action.REPLAN and full["C0"][0] is Action.REPLAN
    assert full["E0"] == (Action.SWITCH, Strategy.S1) and strat["E0"] == (Action.SWITCH, Strategy.S2)
    assert full["C1"][0] is Action.NEXT_CANDIDATE
    assert strat["B2"] == (Action.SWITCH, Strategy.S1) and strat["D2"][0] is Action.NEXT_ANGLE


def test_views_from_behind_the_contour_line_are_not_visible():
    from agiprobot_measurement.nbv.range_finder import RangeFinder2D
    from agiprobot_measurement.nbv.scoring import ScoreConfig, score_views
    from agiprobot_measurement.nbv.visibility import N_SECTORS

    rf = RangeFinder2D.from_config()
    aims = np.array([[50.0, 50.0]])
    circles = np.ones((1, N_SECTORS), dtype=np.uint8)
    normal = np.array([1.0, 0.0])  # the empty side is +x
    views = score_views(rf, aims, circles, normal, None, ScoreConfig(front_only=True))
    cos_a = np.cos(np.radians(views.sector + 0.5))
    assert not views.visibility[cos_a < 0].any()
    assert views.visibility[cos_a > 0].any()
    loose = score_views(rf, aims, circles, normal, None, ScoreConfig())
    assert loose.visibility[cos_a < 0].any()
