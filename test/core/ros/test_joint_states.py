"""JointStateCache orders /joint_states by the node's joint names and ignores foreign or malformed messages."""

import numpy as np
import pytest
import rospy
from sensor_msgs.msg import JointState

from agiprobot_measurement.ros import joint_states
from agiprobot_measurement.ros.joint_states import JointStateCache, positions_by_name


class _Subscriber:
    def __init__(self, topic, msg_type, callback, queue_size):
        self.topic, self.msg_type, self.callback, self.queue_size = topic, msg_type, callback, queue_size
        self.unregistered = False

    def unregister(self):
        self.unregistered = True


@pytest.fixture
def cache(monkeypatch):
    monkeypatch.setattr(joint_states.rospy, "Subscriber", _Subscriber)
    return JointStateCache(["a", "b", "c"])


def _msg(names, positions, stamp_s=0.0):
    msg = JointState(name=list(names), position=list(positions))
    msg.header.stamp = rospy.Time.from_sec(stamp_s)
    return msg


def test_positions_by_name_reorders_and_rejects():
    np.testing.assert_array_equal(positions_by_name(["c", "a", "b"], [3.0, 1.0, 2.0], ["a", "b", "c"]), [1, 2, 3])
    assert positions_by_name(["a", "b"], [1.0, 2.0], ["a", "b", "c"]) is None
    assert positions_by_name(["a", "b", "c"], [1.0, 2.0], ["a", "b"]) is None


def test_cache_subscribes_and_keeps_the_latest(cache):
    sub = cache._subscriber
    assert sub.topic == "/joint_states" and sub.msg_type is JointState and sub.queue_size == 1
    assert cache.latest() is None
    sub.callback(_msg(["b", "c", "a", "extra"], [2.0, 3.0, 1.0, 9.0], 1.5))
    np.testing.assert_array_equal(cache.latest(), [1.0, 2.0, 3.0])
    assert cache.latest_stamp().to_sec() == 1.5
    sub.callback(_msg(["pan", "tilt"], [0.1, 0.2]))  # another robot on the topic
    sub.callback(_msg(["a", "b", "c"], [1.0]))  # malformed
    np.testing.assert_array_equal(cache.latest(), [1.0, 2.0, 3.0])
    cache.latest()[0] = 99.0  # a copy
    assert cache.latest()[0] == 1.0
    cache.unregister()
    assert sub.unregistered


def test_wait_returns_at_once_when_a_state_is_there(cache, monkeypatch):
    cache._subscriber.callback(_msg(["a", "b", "c"], [1.0, 2.0, 3.0]))
    monkeypatch.setattr(joint_states.rospy.Time, "now", staticmethod(lambda: rospy.Time.from_sec(10.0)))
    np.testing.assert_array_equal(cache.wait(1.0), [1.0, 2.0, 3.0])


def test_wait_times_out_in_ros_time(cache, monkeypatch):
    clock = {"t": 10.0}
    monkeypatch.setattr(joint_states.rospy.Time, "now", staticmethod(lambda: rospy.Time.from_sec(clock["t"])))
    monkeypatch.setattr(joint_states.rospy, "is_shutdown", lambda: False)

    def sleep(duration_s):
        clock["t"] += duration_s

    monkeypatch.setattr(joint_states.rospy, "sleep", sleep)
    assert cache.wait(0.5) is None
    assert clock["t"] == pytest.approx(10.5, abs=0.051)


def test_wait_sees_a_state_arriving_while_waiting(cache, monkeypatch):
    clock = {"t": 0.0}
    monkeypatch.setattr(joint_states.rospy.Time, "now", staticmethod(lambda: rospy.Time.from_sec(clock["t"])))
    monkeypatch.setattr(joint_states.rospy, "is_shutdown", lambda: False)

    def sleep(duration_s):
        clock["t"] += duration_s
        if clock["t"] > 0.2:
            cache._subscriber.callback(_msg(["a", "b", "c"], [4.0, 5.0, 6.0]))

    monkeypatch.setattr(joint_states.rospy, "sleep", sleep)
    np.testing.assert_array_equal(cache.wait(3.0), [4.0, 5.0, 6.0])
    assert clock["t"] < 0.3


def test_the_ur_drivers_alphabetical_order_maps_to_the_stations_order():
    # ur_robot_driver's joint_state_controller names the joints alphabetically (ros_control's std::map)
    from agiprobot_measurement.station import load_joint_limits

    station = list(load_joint_limits().names)
    alphabetical = sorted(station)
    assert alphabetical != station  # the two orders differ: the mapping matters
    by_name = {name: 0.1 * (i + 1) for i, name in enumerate(station)}
    mapped = positions_by_name(alphabetical, [by_name[n] for n in alphabetical], station)
    assert np.allclose(mapped, [by_name[n] for n in station])
