"""The motion router: the straight move when it is free, else a via configuration, else OMPL (built only then)."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.motion.routing import Router, RouteSettings, path_length_rad


class _Band:
    """Joint 0 within ``[0.4, 0.6]`` with joint 1 within ``+-0.1`` collides; ``free`` switches everything free."""

    def __init__(self, free=False):
        self.free = free

    def check_states(self, states):
        d = np.atleast_2d(states)
        if self.free:
            return np.ones(len(d), dtype=bool)
        return ~((d[:, 0] > 0.4) & (d[:, 0] < 0.6) & (np.abs(d[:, 1]) < 0.1))


def _never():
    raise AssertionError("OMPL must not be asked")


def test_a_free_straight_move_is_taken_without_ompl(station):
    router = Router(_Band(free=True), station.limits, _never)
    goal = np.array([1.0, 0, 0, 0, 0, 0])
    for trajectory in (router.route(np.zeros(6), goal), router.connect(np.zeros(6), goal)):
        assert np.allclose(trajectory.positions[-1], goal)
        assert path_length_rad(trajectory) == pytest.approx(1.0)


def test_a_blocked_move_goes_through_a_via_and_connect_without_a_planner_gives_none(station):
    router = Router(_Band(), station.limits, None, RouteSettings(via_poses=2))
    goal = np.array([1.0, 0, 0, 0, 0, 0])
    assert router.connect(np.zeros(6), goal) is None  # no straight move, no planner
    trajectory = router.route(np.zeros(6), goal, vias=[[0.5, 0.2, 0, 0, 0, 0]])
    positions = np.asarray(trajectory.positions)
    assert router.checker.check_states(positions).all()
    assert positions[:, 1].max() == pytest.approx(0.2, abs=0.01)
    assert router.planner() is None
