"""Connection moves without a planning run: the connection planner moves straight when the way is free, around
an obstacle with OMPL otherwise, and a session adapts a stored plan's start with it."""

import numpy as np

from agiprobot_measurement.planning.connection import ConnectionPlanner
from agiprobot_measurement.planning.plan.plan_io import START_TOLERANCE_RAD
from agiprobot_measurement.station import Station


def test_a_free_straight_move_starts_and_ends_where_asked():
    station = Station.load()
    planner = ConnectionPlanner.for_station(station)
    home, up = station.named_states["home"], station.named_states["up"]
    move = planner.connect(home, up)
    assert move is not None
    np.testing.assert_allclose(move.start, home, atol=START_TOLERANCE_RAD)
    np.testing.assert_allclose(move.end, up, atol=START_TOLERANCE_RAD)
    assert move.duration > 0
    assert planner.collision.check_states(np.array([move.start, move.end])).all()


def test_the_same_state_is_a_one_point_move():
    station = Station.load()
    home = station.named_states["home"]
    move = ConnectionPlanner.for_station(station).connect(home, home)
    assert len(move) == 1
