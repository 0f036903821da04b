"""Shared fixtures for the ROS-free core tests."""

from pathlib import Path

import pytest

from agiprobot_measurement.station import PACKAGE_ROOT, Station

SHARED_DIR = PACKAGE_ROOT.parent / "shared"


@pytest.fixture(scope="session")
def station() -> Station:
    return Station.load()


@pytest.fixture(scope="session")
def kinematic_model(station):
    from agiprobot_measurement.motion.kinematics import KinematicModel

    return KinematicModel.from_station(station)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` beside the checkout (parts, plans); tests that need it skip when it is absent."""
    if not SHARED_DIR.is_dir():
        pytest.skip("../shared is not present beside the checkout")
    return SHARED_DIR
