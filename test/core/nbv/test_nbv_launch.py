"""nbv.launch restarts its simulated devices when they die: the UR10e controller and phoxi_camera alike."""

import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT

roslaunch = pytest.importorskip("roslaunch")


def test_the_simulated_camera_and_robot_respawn():
    config = roslaunch.config.load_config_default([str(PACKAGE_ROOT / "launch" / "nbv.launch")], None, verbose=False)
    nodes = {node.name: node for node in config.nodes}
    assert nodes["phoxi_camera"].respawn, "phoxi_camera is not respawned in nbv.launch"
    assert nodes["ur_hardware_interface"].respawn
