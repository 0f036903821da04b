"""Helpers shared by the rostest nodes of the simulated PhoXi scanner."""

import threading
import time

import rospy
from dynamic_reconfigure.client import Client as ReconfigureClient
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

NODE = "/phoxi_camera"
FRAME_TOPICS = {
    "pointcloud": PointCloud2,
    "depth_map": Image,
    "texture": Image,
    "rgb_texture": Image,
    "confidence_map": Image,
    "normal_map": Image,
    "camera_info": CameraInfo,
}


def service(name, kind, timeout_s=30.0):
    full = f"{NODE}/{name}"
    rospy.wait_for_service(full, timeout=timeout_s)
    return rospy.ServiceProxy(full, kind)


def reconfigure(**changes):
    client = ReconfigureClient(NODE, timeout=20)
    try:
        return client.update_configuration(changes)
    finally:
        client.close()


class FrameRecorder:
    """Subscribes to the frame topics and keeps every message by topic; ``wait_for(seq)`` blocks for a frame."""

    def __init__(self, topics=tuple(FRAME_TOPICS)):
        self.lock = threading.Lock()
        self.messages = {name: [] for name in topics}
        self.subscribers = [
            rospy.Subscriber(f"{NODE}/{name}", FRAME_TOPICS[name], self._callback, callback_args=name, queue_size=5)
            for name in topics
        ]
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and any(s.get_num_connections() == 0 for s in self.subscribers):
            rospy.sleep(0.05)

    def _callback(self, msg, name):
        with self.lock:
            self.messages[name].append(msg)

    def of(self, name, seq):
        with self.lock:
            return next((m for m in self.messages[name] if m.header.seq == seq), None)

    def wait_for(self, seq, topics=None, timeout_s=30.0):
        """{topic: message of frame ``seq``} once every topic in ``topics`` has one; None on time-out."""
        topics = list(topics or self.messages)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            found = {name: self.of(name, seq) for name in topics}
            if all(found.values()):
                return found
            rospy.sleep(0.05)
        return None

    def count(self, name):
        with self.lock:
            return len(self.messages[name])

    def close(self):
        for subscriber in self.subscribers:
            subscriber.unregister()
