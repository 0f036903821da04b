"""The 3D next-best-view map and coverage rebuilt from a recorded bag alone (``nbv.launch record:=true``).

The bag holds the goal of each ReconstructObject run, its feedback and result, every PhoXi frame (organised cloud,
confidence map, camera info) and tf. One run's window runs from its goal to its result; its frames are those inside
the window; each frame's sensor pose is tf world <- the cloud's frame at the cloud's stamp (from the recorded
/tf and /tf_static), as the node looked it up live. The frames are fused again in the order they were taken by the
core's loop (:meth:`Reconstructor.integrate` on a map of the goal's ROI and resolution), so the rebuilt map and
coverage are the live run's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import rosbag
import rospy
import tf2_ros
from geometry_msgs.msg import Quaternion, TransformStamped, Vector3

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.reconstruction import Reconstructor
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest
from agiprobot_measurement.nbv.volumetric.station3d import NBVStation, load_nbv_config
from agiprobot_measurement.ros.conversions import transform_to_matrix
from agiprobot_measurement.ros.nbv_messages import captured_view, request_mapping_from_goal

__all__ = [
    "ACCEPTED_TOPIC",
    "CLOUD_TOPIC",
    "CONFIDENCE_TOPIC",
    "GOAL_TOPIC",
    "INFO_TOPIC",
    "RESULT_TOPIC",
    "BagReconstruction",
    "points_summary",
    "reconstruction_from_bag",
    "recorded_runs",
]

ACTION = "/nbv_reconstruction/reconstruct_object"
GOAL_TOPIC = f"{ACTION}/goal"
#: the node's own copy of each goal (a recorder may miss the first goal of a client that just connected)
ACCEPTED_TOPIC = "/nbv_reconstruction/accepted_goal"
RESULT_TOPIC = f"{ACTION}/result"
CLOUD_TOPIC = "/phoxi_camera/pointcloud"
CONFIDENCE_TOPIC = "/phoxi_camera/confidence_map"
INFO_TOPIC = "/phoxi_camera/camera_info"
FRAME_TOPICS = {CLOUD_TOPIC: "pointcloud", CONFIDENCE_TOPIC: "confidence_map", INFO_TOPIC: "camera_info"}


@dataclass
class BagReconstruction:
    views: int  # frames fused
    observed_surface_area_m2: float
    remaining_frontier_area_m2: float
    coverage: float | None  # None without a ground truth
    live: dict = field(default_factory=dict)  # the run's recorded result (number_of_views, areas, coverage, reason)
    reconstructor: object = None  # the rebuilt loop state (its map holds every fused point)


def _transform(recorded) -> TransformStamped:
    """A recorded transform as geometry_msgs' own type (a bag's messages are of types built from the bag's
    definitions, which tf2 warns about)."""
    t, r = recorded.transform.translation, recorded.transform.rotation
    transform = TransformStamped(child_frame_id=recorded.child_frame_id)
    transform.header.stamp = recorded.header.stamp
    transform.header.frame_id = recorded.header.frame_id
    transform.transform.translation = Vector3(t.x, t.y, t.z)
    transform.transform.rotation = Quaternion(r.x, r.y, r.z, r.w)
    return transform


def _tf_buffer(bag, duration_s: float) -> tf2_ros.Buffer:
    # debug=False: no frames service, so no ROS master is needed
    buffer = tf2_ros.Buffer(cache_time=rospy.Duration(max(10.0, duration_s + 10.0)), debug=False)
    for topic, msg, _ in bag.read_messages(topics=["/tf", "/tf_static"]):
        for recorded in msg.transforms:
            transform = _transform(recorded)
            if topic == "/tf_static":
                buffer.set_transform_static(transform, "bag")
            else:
                buffer.set_transform(transform, "bag")
    return buffer


def recorded_runs(bag) -> list[dict]:
    """Every recorded goal with its window [goal stamp, result stamp] and its result message (or None). The goals
    come from the node's ``accepted_goal`` topic, or from the action's goal topic in bags without it."""
    goal_topic = ACCEPTED_TOPIC if bag.get_message_count(topic_filters=[ACCEPTED_TOPIC]) else GOAL_TOPIC
    runs, by_id = [], {}
    for topic, msg, stamp in bag.read_messages(topics=[goal_topic, RESULT_TOPIC]):
        if topic == goal_topic:
            if msg.goal_id.id in by_id:
                continue
            run = {"id": msg.goal_id.id, "goal": msg.goal, "begin": stamp.to_sec(), "end": float("inf"), "result": None}
            runs.append(run)
            by_id[run["id"]] = run
        else:
            run = by_id.get(msg.status.goal_id.id)
            if run is not None:
                run["end"], run["result"] = stamp.to_sec(), msg.result
    return runs


def reconstruction_from_bag(
    bag_path: str | Path,
    run_index: int = -1,
    config: dict | None = None,
    station=None,
    ground_truth=None,
    world_frame: str = "world",
) -> BagReconstruction:
    """Map and coverage of one recorded run (default: the last) of ``bag_path``; ``config`` (config/nbv.yaml),
    ``station`` (the NBVStation the node used) and ``ground_truth`` (for the coverage) as the node had them.
    Raises InputError for a bag without a run or frames."""
    config = config if config is not None else load_nbv_config()
    with rosbag.Bag(str(bag_path)) as bag:
        runs = recorded_runs(bag)
        if not runs:
            raise InputError(f"{bag_path}: no ReconstructObject goal ({ACCEPTED_TOPIC} or {GOAL_TOPIC}) recorded")
        try:
            run = runs[run_index]
        except IndexError:
            raise InputError(f"{bag_path}: no run {run_index} (the bag has {len(runs)})") from None
        tf_buffer = _tf_buffer(bag, bag.get_end_time() - bag.get_start_time())
        frames: dict[int, dict] = {}
        order: list[int] = []
        for topic, msg, stamp in bag.read_messages(topics=list(FRAME_TOPICS)):
            if not run["begin"] <= stamp.to_sec() <= run["end"] + 1.0:
                continue
            seq = int(msg.header.seq)
            if seq not in frames:
                frames[seq] = {}
                order.append(seq)
            frames[seq][FRAME_TOPICS[topic]] = msg
    complete = [seq for seq in order if len(frames[seq]) == len(FRAME_TOPICS)]
    if not complete:
        raise InputError(f"{bag_path}: run {run_index} has no complete PhoXi frame (cloud, confidence, camera info)")
    values = request_mapping_from_goal(run["goal"], dict(config.get("request", {})), max_voxels=float("inf"))
    values["execute"] = False
    request = ReconstructionRequest.from_mapping(values)
    if station is None:
        station = NBVStation(config=config)
    if ground_truth is not None:
        ground_truth.reset()  # the coverage of this run's frames only
    reconstructor = Reconstructor(None, None, request, station=station, ground_truth=ground_truth)
    for seq in complete:
        frame = frames[seq]
        cloud = frame["pointcloud"]
        try:
            transform = tf_buffer.lookup_transform(world_frame, cloud.header.frame_id, cloud.header.stamp)
        except tf2_ros.TransformException as exc:
            raise InputError(f"{bag_path}: frame {seq}: no pose of {cloud.header.frame_id} on tf: {exc}") from exc
        view = captured_view(cloud, frame["confidence_map"], frame["camera_info"], transform_to_matrix(transform))
        reconstructor.integrate(view)
    grid = reconstructor.map
    coverage = None if ground_truth is None else ground_truth.coverage()
    live = {}
    if run["result"] is not None:
        result = run["result"]
        live = {
            "termination_reason": result.termination_reason,
            "number_of_views": result.number_of_views,
            "observed_surface_area_m2": result.observed_surface_area_m2,
            "remaining_frontier_area_m2": result.remaining_frontier_area_m2,
            "coverage": None if result.coverage < 0 else result.coverage,
        }
    return BagReconstruction(
        views=len(complete),
        observed_surface_area_m2=float(grid.observed_surface_area_m2()),
        remaining_frontier_area_m2=float(grid.frontier_area_m2()),
        coverage=None if coverage is None else float(coverage),
        live=live,
        reconstructor=reconstructor,
    )


def points_summary(reconstruction: BagReconstruction) -> str:
    """One line for the script."""
    grid = reconstruction.reconstructor.map
    return f"{len(grid.raw)} points kept, grid {grid.shape} at {grid.resolution_m * 1000:.1f} mm"
