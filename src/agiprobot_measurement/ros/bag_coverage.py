"""Measured coverage recomputed from a recorded bag alone (sample points + scanner profiles).

The trajectory_manager node publishes the plan's sample points on ``/trajectory_manager/surface_points``
(latched, red = predicted unmeasurable) and the simulated scanner its profiles on ``/laser_scanner/profile``;
a bag recorded by ``measurement.launch record:=true`` holds both, so the coverage a run actually measured can be
recomputed later without the nodes, the same way the node computes it live.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rosbag

from agiprobot_measurement.planning.report.coverage import is_uncoverable_color
from agiprobot_measurement.ros.conversions import cloud_xyz
from agiprobot_measurement.ros.errors import MessageError
from agiprobot_measurement.sensors.laser_line.simulator import measured_samples

__all__ = [
    "CLOUD_TOPIC",
    "FEEDBACK_TOPIC",
    "PROFILE_TOPIC",
    "RESULT_TOPIC",
    "SAMPLES_TOPIC",
    "BagCoverage",
    "coverage_from_bag",
]

SAMPLES_TOPIC = "/trajectory_manager/surface_points"
PROFILE_TOPIC = "/laser_scanner/profile"
CLOUD_TOPIC = "/laser_scanner/measured_cloud"


@dataclass(frozen=True)
class BagCoverage:
    samples: int
    coverable: int
    measured: int
    profiles: int
    measured_points: int

    @property
    def measured_coverage(self) -> float:
        return self.measured / self.coverable if self.coverable else 0.0


def _rgb(msg) -> np.ndarray | None:
    offsets = {f.name: f.offset for f in msg.fields}
    if "rgb" not in offsets:
        return None
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.width * msg.height, msg.point_step)
    packed = raw[:, offsets["rgb"] : offsets["rgb"] + 4].copy().view(np.uint32).reshape(-1)
    return np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1)


FEEDBACK_TOPIC = "/trajectory_manager/execute_plan/feedback"
RESULT_TOPIC = "/trajectory_manager/execute_plan/result"


def coverage_from_bag(bag_path: str | Path, radius_mm: float = 1.0, execution_index: int = -1) -> BagCoverage:
    """Measured coverage of one recorded execution (default: the last) in ``bag_path``.

    The execution's window runs from its first ExecutePlan feedback to its result; its samples are the last
    sample set published before the window; its measurement is every scanner profile inside the window.
    Bags without the action topics count all profiles after the last sample set."""
    with rosbag.Bag(str(bag_path)) as bag:
        windows: dict[str, list[float]] = {}
        order: list[str] = []
        for topic, msg, stamp in bag.read_messages(topics=[FEEDBACK_TOPIC, RESULT_TOPIC]):
            goal = msg.status.goal_id.id
            if goal not in windows:
                windows[goal] = [stamp.to_sec(), float("inf")]
                order.append(goal)
            if topic == RESULT_TOPIC:
                windows[goal][1] = stamp.to_sec()
        if order:
            try:
                begin, end = windows[order[execution_index]]
            except IndexError:
                raise MessageError(f"{bag_path}: no execution {execution_index} (the bag has {len(order)})") from None
        else:
            begin, end = None, float("inf")
        samples_msg, chunks, profiles, whole = None, [], 0, None
        for topic, msg, stamp in bag.read_messages(topics=[SAMPLES_TOPIC, PROFILE_TOPIC, CLOUD_TOPIC]):
            t = stamp.to_sec()
            inside = (begin is None or begin <= t) and t <= end + 1.0
            if topic == SAMPLES_TOPIC:
                if msg.width * msg.height and (begin is None or t <= begin):
                    samples_msg = msg
                    if begin is None:
                        chunks, profiles, whole = [], 0, None  # a new plan: older measurements do not count
            elif topic == CLOUD_TOPIC:
                if inside and msg.width * msg.height:
                    whole = msg  # the scanner's whole measured cloud of this execution (what the node used)
            elif inside:
                profiles += 1
                points = cloud_xyz(msg)
                if len(points):
                    chunks.append(points * 1000.0)
        if whole is not None:
            chunks = [cloud_xyz(whole) * 1000.0]
    if samples_msg is None:
        raise MessageError(f"{bag_path}: no sample points ({SAMPLES_TOPIC}) before the execution")
    samples = cloud_xyz(samples_msg) * 1000.0
    colors = _rgb(samples_msg)
    # red samples are not coverable: no viewpoint measures them (the node colours them UNCOVERABLE_RGB)
    coverable = np.ones(len(samples), dtype=bool) if colors is None else ~is_uncoverable_color(colors)
    measured_points = np.vstack(chunks) if chunks else np.zeros((0, 3))
    measured = measured_samples(samples, measured_points, radius_mm)
    return BagCoverage(
        len(samples), int(coverable.sum()), int((measured & coverable).sum()), profiles, len(measured_points)
    )
