"""The catkin install space holds every subpackage and finds its data (config/, urdf/) without the source tree."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT


@pytest.fixture(scope="module")
def install_prefix(tmp_path_factory) -> Path:
    workspace = os.environ.get("AGIPROBOT_WS")
    build = Path(workspace or "/nonexistent") / "build"
    if not (build / "CMakeCache.txt").is_file():
        pytest.skip("no built catkin workspace (source tools/env.sh after make setup)")
    destdir = tmp_path_factory.mktemp("destdir")
    # the real install rules of the built workspace (catkin_python_setup, catkin_install_python, install(DIRECTORY));
    # DESTDIR, because catkin's setup.py step has the configured prefix baked in
    result = subprocess.run(
        ["cmake", "--install", str(build)],
        env={**os.environ, "DESTDIR": str(destdir)},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    prefix = Path(workspace).resolve() / "install"
    return destdir / prefix.relative_to("/")


def test_install_space_imports_every_subpackage_and_finds_its_data(install_prefix):
    site = install_prefix / "lib" / "python3" / "dist-packages"
    installed = {p.parent.relative_to(site).as_posix() for p in site.rglob("__init__.py")}
    source = {
        p.parent.relative_to(PACKAGE_ROOT / "src").as_posix()
        for p in (PACKAGE_ROOT / "src" / "agiprobot_measurement").rglob("__init__.py")
    }
    assert source <= installed, f"subpackages missing from the install space: {sorted(source - installed)}"
    script = (
        "import agiprobot_measurement, agiprobot_measurement._paths as p\n"
        "from agiprobot_measurement.station import Station\n"
        "from agiprobot_measurement.trajectory_manager import TrajectoryManager\n"
        "import agiprobot_measurement.planning.set_cover, agiprobot_measurement.calibration.registration\n"
        "Station.load()\n"
        "print(agiprobot_measurement.__file__)\n"
        "print(p.PACKAGE_ROOT)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AGIPROBOT_MEASUREMENT_ROOT")}
    env["PYTHONPATH"] = str(site)
    result = subprocess.run(
        [sys.executable, "-c", script], cwd="/", env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-3000:]
    module_file, root = result.stdout.split()[-2:]
    assert Path(module_file).is_relative_to(site), module_file
    assert Path(root) == install_prefix / "share" / "agiprobot_measurement"
