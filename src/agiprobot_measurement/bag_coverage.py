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

from agiprobot_measurement.laser_line_scanner import measured_samples

SAMPLES_TOPIC = "/trajectory_manager/surface_points"
PROFILE_TOPIC = "/laser_scanner/profile"


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


def coverage_from_bag(bag_path: str | Path, radius_mm: float = 1.0) -> BagCoverage:
    """Measured coverage of the last planned sample set in ``bag_path`` (of the coverable samples)."""
    import rosbag

    from agiprobot_measurement.ros_conversions import cloud_xyz

    samples_msg = None
    chunks = []
    with rosbag.Bag(str(bag_path)) as bag:
        for topic, msg, _ in bag.read_messages(topics=[SAMPLES_TOPIC, PROFILE_TOPIC]):
            if topic == SAMPLES_TOPIC:
                if msg.width * msg.height:
                    samples_msg = msg
                    chunks = []  # a new plan: profiles before it belong to an older one
            else:
                points = cloud_xyz(msg)
                if len(points):
                    chunks.append(points * 1000.0)
        profiles = bag.get_message_count(topic_filters=[PROFILE_TOPIC])
    if samples_msg is None:
        raise ValueError(f"{bag_path}: no sample points ({SAMPLES_TOPIC}) in the bag")
    samples = cloud_xyz(samples_msg) * 1000.0
    colors = _rgb(samples_msg)
    # red (predicted unmeasurable) samples are not coverable; the node colours them (230, 25, 25)
    coverable = np.ones(len(samples), dtype=bool) if colors is None else ~((colors[:, 0] > 200) & (colors[:, 1] < 60))
    measured_points = np.vstack(chunks) if chunks else np.zeros((0, 3))
    measured = measured_samples(samples, measured_points, radius_mm)
    return BagCoverage(
        len(samples), int(coverable.sum()), int((measured & coverable).sum()), profiles, len(measured_points)
    )
