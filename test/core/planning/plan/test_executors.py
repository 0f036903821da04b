"""The executor registry: a layer registers its station executor by name, the core looks it up, an unknown name
is refused naming the known ones, and ``TrajectoryManager.execute`` takes the registered station executor."""

import numpy as np
import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.plan import executors
from agiprobot_measurement.planning.plan.execution import SimulatedExecutor, choose_executor
from agiprobot_measurement.station import Station


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setattr(executors, "_FACTORIES", {})
    return executors


def test_a_registered_factory_is_found_by_its_name(registry):
    def factory(joint_names, surface_points_mm=None, part=None):
        return None

    registry.register("bench", factory)
    assert registry.registered("bench") and registry.get("bench") is factory
    assert registry.known() == ("bench",)


def test_an_unknown_name_is_refused_naming_the_known_ones(registry):
    registry.register("bench", lambda *args, **kwargs: None)
    with pytest.raises(executors.UnknownExecutor, match=r"no executor registered as 'robot'; known: bench"):
        registry.get("robot")
    assert issubclass(executors.UnknownExecutor, InputError)


@pytest.mark.parametrize("name, factory", [("", lambda: None), ("x", "not callable")])
def test_a_bad_registration_is_refused(registry, name, factory):
    with pytest.raises(InputError):
        registry.register(name, factory)


def test_auto_takes_the_registered_station_executor_and_falls_back_to_the_simulated_one(registry):
    station = Station.load()
    names, state = list(station.limits.names), station.named_states["home"]
    calls = []

    class Fake:
        def current_state(self):
            return state

    def factory(joint_names, surface_points_mm=None, part=None):
        calls.append((list(joint_names), surface_points_mm, part))
        return Fake() if len(calls) == 1 else None

    assert isinstance(choose_executor(None, names, {}, state, station.limits), SimulatedExecutor)
    registry.register(executors.STATION, factory)
    assert isinstance(choose_executor("auto", names, {}, state, station.limits, np.zeros((1, 3))), Fake)
    assert calls[0][0] == names and calls[0][1].shape == (1, 3)
    # no controller answers: auto simulates, station refuses
    assert isinstance(choose_executor("auto", names, {}, state, station.limits), SimulatedExecutor)
    with pytest.raises(Exception, match="executor='station'"):
        choose_executor("station", names, {}, state, station.limits)
    with pytest.raises(InputError, match="executor must be one of"):
        choose_executor("moveit", names, {}, state, station.limits)
