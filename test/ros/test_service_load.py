#!/usr/bin/env python3
"""rostest: 200 calls from 1 and from 4 concurrent clients to each cheap service of phoxi_camera and
asr_robot_model_services; every call must succeed, and the rates are printed (calls/s over all clients)."""

import sys
import threading
import time
import unittest

import rospy
import rostest
from asr_robot_model_services.srv import GetDistance, GetPose, IsPositionAllowed
from geometry_msgs.msg import Point
from phoxi_camera.srv import GetDeviceList, GetHardwareIdentification, IsConnected

CALLS_PER_CLIENT = 200
SERVICES = {
    "/phoxi_camera/is_connected": (IsConnected, ()),
    "/phoxi_camera/get_device_list": (GetDeviceList, ()),
    "/phoxi_camera/get_hardware_indentification": (GetHardwareIdentification, ()),
    "/asr_robot_model_services/GetDistance": (GetDistance, (Point(0.0, 0.0, 0.0), Point(1.0, 0.5, 0.0))),
    "/asr_robot_model_services/IsPositionAllowed": (IsPositionAllowed, (Point(0.5, 0.5, 0.0),)),
    "/asr_robot_model_services/GetRobotPose": (GetPose, ()),
}


def hammer(name: str, service_type, args: tuple, clients: int) -> tuple[int, int, float]:
    """(successful calls, failed calls, seconds) of ``clients`` threads with their own proxy each."""
    results = [[0, 0] for _ in range(clients)]

    def client(index: int) -> None:
        proxy = rospy.ServiceProxy(name, service_type, persistent=False)
        for _ in range(CALLS_PER_CLIENT):
            try:
                proxy(*args)
                results[index][0] += 1
            except (rospy.ServiceException, rospy.ROSException) as exc:
                results[index][1] += 1
                print(f"{name}: {exc}", file=sys.stderr)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    start = time.monotonic()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return sum(r[0] for r in results), sum(r[1] for r in results), time.monotonic() - start


class ServiceLoadTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_service_load")
        for name in SERVICES:
            rospy.wait_for_service(name, timeout=60.0)

    def test_cheap_services_under_load(self):
        rows = []
        for name, (service_type, args) in SERVICES.items():
            for clients in (1, 4):
                ok, failed, seconds = hammer(name, service_type, args, clients)
                rows.append(f"{name:48s} {clients} client(s): {ok / seconds:8.1f} calls/s, {failed} failed")
                self.assertEqual(failed, 0, rows[-1])
                self.assertEqual(ok, clients * CALLS_PER_CLIENT, rows[-1])
        print("\n" + "\n".join(rows), flush=True)
        rospy.loginfo("service load:\n%s", "\n".join(rows))


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "service_load", ServiceLoadTest)
