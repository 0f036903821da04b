#!/usr/bin/env python3
"""rostest: the running nodes named in ~nodes offer and use exactly what docs/ros-interface.md says: the same
published and subscribed topics with their types (actions expanded), the same services with their types, and no
private parameter on the server that the reference leaves out. ~nodes lists the reference's section keys
(``/name``, or ``/name:variant`` for a second node type started under the same name)."""

import sys
import time
import unittest
from pathlib import Path

import rospy
import rostest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import interface_reference

REFERENCE = Path(__file__).resolve().parents[2] / "docs" / "ros-interface.md"
STARTUP_S = 150.0


class InterfaceReferenceTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_ros_interface_reference")
        cls.reference = interface_reference.load(REFERENCE)
        cls.keys = str(rospy.get_param("~nodes")).split()

    def _observe_when_up(self, key: str) -> list[str]:
        """The differences once the node has created everything the reference lists (or the start-up time ran out)."""
        documented = self.reference[key]
        deadline = time.monotonic() + STARTUP_S
        while True:
            problems = interface_reference.differences(documented, interface_reference.observe(key.split(":")[0]))
            missing = [p for p in problems if "is not on the running node" in p]
            if not missing or time.monotonic() > deadline or rospy.is_shutdown():
                return problems
            time.sleep(2.0)

    def test_every_node_is_documented(self):
        missing = [key for key in self.keys if key not in self.reference]
        self.assertEqual(missing, [], f"no section in {REFERENCE.name}")

    def test_running_nodes_match_the_reference(self):
        problems = []
        for key in self.keys:
            if key in self.reference:
                problems += self._observe_when_up(key)
        self.assertEqual(problems, [], "\n" + "\n".join(problems))


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "ros_interface_reference", InterfaceReferenceTest)
