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
        "import agiprobot_measurement.planning.cover.solve, agiprobot_measurement.calibration.registration\n"
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


INTERFACE_PACKAGES = {
    # package: the folders installed to share/ besides package.xml, and the node types installed to lib/
    "phoxi_camera": (("launch", "config", "urdf", "rviz"), ("phoxi_camera",)),
    "asr_robot_model_services": (("launch", "param"), ("asr_robot_model_services",)),
}


@pytest.mark.parametrize("package", sorted(INTERFACE_PACKAGES))
def test_install_space_holds_the_interface_packages(install_prefix, package):
    source = PACKAGE_ROOT / "packages" / package
    share = install_prefix / "share" / package
    folders, node_types = INTERFACE_PACKAGES[package]
    assert (share / "package.xml").is_file()
    for folder in folders:
        expected = {p.relative_to(source).as_posix() for p in (source / folder).rglob("*") if p.is_file()}
        installed = {p.relative_to(share).as_posix() for p in (share / folder).rglob("*") if p.is_file()}
        assert expected, f"packages/{package}/{folder} is empty"
        assert expected <= installed, f"missing from share/{package}: {sorted(expected - installed)}"
    lib = install_prefix / "lib" / package
    for node in {*node_types, *(p.name for p in (source / "nodes").iterdir() if p.is_file())}:
        assert os.access(lib / node, os.X_OK), f"lib/{package}/{node} is not installed as an executable"


def test_install_space_node_modules_import_with_the_interface_types(install_prefix):
    site = install_prefix / "lib" / "python3" / "dist-packages"
    script = (
        "import phoxi_camera.srv, phoxi_camera.msg, asr_robot_model_services.srv, asr_robot_model_services.msg\n"
        "import agiprobot_measurement.srv\n"
        "import agiprobot_measurement.ros.nodes.phoxi_camera, agiprobot_measurement.ros.nodes.asr_robot_model_services\n"
        "for module in (phoxi_camera.srv, asr_robot_model_services.srv, agiprobot_measurement.srv):\n"
        "    print(module.__file__)\n"
        "print(phoxi_camera.srv.GetFrame._type, asr_robot_model_services.srv.GetPose._type)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AGIPROBOT_MEASUREMENT_ROOT")}
    env["PYTHONPATH"] = str(site)
    result = subprocess.run(
        [sys.executable, "-c", script], cwd="/", env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-3000:]
    *files, types = result.stdout.split("\n")[-5:-1]
    assert all(Path(f).is_relative_to(site) for f in files), files
    assert types == "phoxi_camera/GetFrame asr_robot_model_services/GetPose"
