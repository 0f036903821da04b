"""Shared fixtures for the ROS-free core tests."""

import importlib.util
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


@pytest.fixture(scope="session")
def load_script():
    """``load_script("reconstruct")``: a command of ``scripts/`` as a module (its functions, its ``main``)."""

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, PACKAGE_ROOT / "scripts" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load
