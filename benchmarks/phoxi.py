"""The simulated PhoXi scanner rendering the station scene with the robot (frames/s per resolution).

Each frame is what the node does per trigger without ROS: the robot's links posed by FK at a different joint state
every frame, the scene (objects, part, robot) concatenated into one mesh, a fresh Embree scene, camera rays, shadow
rays, noise, normals and texture. ``--messages`` adds building the driver's messages (cloud, images, camera info).
Targets (conditions/phoxi.yaml): high resolution <= 2 s per frame, low resolution <= 0.6 s per frame (2-core
machine); saving a high-resolution frame as PTX <= 2 s.

  python -m benchmarks.phoxi                  # 5 frames each of high and low resolution, model of the config
  python -m benchmarks.phoxi --frames 10 --model M --messages
  python -m benchmarks.phoxi --ptx            # time V2/save_last_frame of one high-resolution frame (.ptx, .ply)
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.sensors.phoxi.device import PhoxiDevice, frame_output, load_camera_config
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_HIGH, RESOLUTION_LOW, load_scanner_model
from agiprobot_measurement.sensors.phoxi.renderer import RayCaster, ScanSettings, StructuredLightScanner
from agiprobot_measurement.sensors.phoxi.scene_geometry import (
    RobotGeometry,
    SceneGeometry,
    scene_geometry,
)
from agiprobot_measurement.station import Station
from agiprobot_measurement.station.urdf_model import UrdfModel
from benchmarks.harness import Target, format_targets, load_conditions

CONDITIONS = load_conditions("phoxi")
TARGETS = CONDITIONS.mapping("targets")


def build_messages(frame) -> None:
    # the ROS message modules only with --messages: the benchmark runs without ROS otherwise
    from std_msgs.msg import Header

    from agiprobot_measurement.ros import phoxi_messages

    header = Header(frame_id="PhoXi3Dscanner_sensor")
    points, normals = frame_output(frame)
    phoxi_messages.pointcloud2(points, normals, frame.valid, header, organized=True)
    phoxi_messages.image(frame.depth_mm, "32FC1", header)
    phoxi_messages.image(normals, "32FC3", header)
    phoxi_messages.image(frame.confidence, "32FC1", header)
    phoxi_messages.image(frame.texture, "32FC1", header)
    phoxi_messages.image(frame.rgb_texture(), "rgb8", header)
    phoxi_messages.camera_info(frame.intrinsics, header)


def bench_saving(model_name: str | None, repeats: int) -> int:
    """Seconds to write the last frame (high resolution, the station's scene) as PTX and as PLY, as the node's
    V2/save_last_frame does, against the PTX target."""
    station = Station.load()
    config = load_camera_config()
    model = load_scanner_model(model_name or config.model)
    with tempfile.TemporaryDirectory() as out:
        device = PhoxiDevice(
            model, scene_geometry(station.scene), out, settings=ScanSettings(resolution=RESOLUTION_HIGH)
        )
        device.connect(device.hardware_identification)
        frame = device.trigger(config.pose)
        intr = model.intrinsics(RESOLUTION_HIGH)
        print(f"PhoXi {model.name} {intr.width}x{intr.height}, {frame.stats['valid']:,} valid points")
        results = {}
        for extension in ("ptx", "ply"):
            times = []
            for i in range(max(1, repeats)):
                start = time.perf_counter()
                path = device.save_last_frame(f"last_{i}.{extension}")
                times.append(time.perf_counter() - start)
            size = Path(path).stat().st_size / 1e6
            results[extension] = statistics.mean(times)
            print(
                f"{extension}: {statistics.mean(times):.3f} s mean, min {min(times):.3f} s, max {max(times):.3f} s "
                f"({size:.1f} MB)"
            )
    limit = TARGETS["ptx_save_s"]
    target = Target(
        "save a high-resolution frame as .ptx", f"{results['ptx']:.3f} s", f"<= {limit:g} s", results["ptx"] <= limit
    )
    print(format_targets([target]))
    return 0 if target.ok else 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--frames",
        type=int,
        default=CONDITIONS.mapping("defaults")["frames"],
        help="timed frames per resolution (after one warm-up)",
    )
    parser.add_argument("--model", default=None, help="PhoXi model (default: config/phoxi_camera.yaml's)")
    parser.add_argument("--messages", action="store_true", help="also build the ROS messages of each frame")
    parser.add_argument("--workers", type=int, default=None, help="render threads (default: CPUs, at most 4)")
    parser.add_argument(
        "--ptx", action="store_true", help="time saving one high-resolution frame as .ptx and .ply instead of rendering"
    )
    args = parser.parse_args(argv)
    if args.ptx:
        return bench_saving(args.model, args.frames)

    station = Station.load()
    config = load_camera_config()
    model = load_scanner_model(args.model or config.model)
    scanner = StructuredLightScanner(model, workers=args.workers)
    scene = scene_geometry(station.scene)
    robot = RobotGeometry(UrdfModel(station.urdf_xml))
    kinematics = KinematicModel.from_station(station)
    rng = np.random.default_rng(0)
    print(
        f"PhoXi {model.name} at {np.round(config.pose[:3, 3], 3).tolist()} in world; scene {len(scene)} triangles, "
        f"robot {sum(len(g) for g in robot.links.values())} triangles; {os.cpu_count()} CPUs, "
        f"{scanner.workers} render threads, load average {os.getloadavg()[0]:.1f}"
        + ("; with messages" if args.messages else "")
    )
    targets = []
    for resolution, label, target in (
        (RESOLUTION_HIGH, "high", TARGETS["high_s_per_frame"]),
        (RESOLUTION_LOW, "low", TARGETS["low_s_per_frame"]),
    ):
        settings = ScanSettings(resolution=resolution)
        times, cpu, valid = [], [], []
        for i in range(args.frames + 1):
            q = rng.uniform(kinematics.lower, kinematics.upper) * 0.3
            start, start_cpu = time.perf_counter(), time.process_time()
            links = {name: pose[0] for name, pose in kinematics.link_poses_batch(q[None]).items()}
            geometry = SceneGeometry.concatenate([scene, robot.posed(links)])
            frame = scanner.capture(geometry, config.pose, settings, i, RayCaster(geometry))
            if args.messages:
                build_messages(frame)
            elapsed, elapsed_cpu = time.perf_counter() - start, time.process_time() - start_cpu
            if i:  # the first frame fills caches (pixel rays, page tables)
                times.append(elapsed)
                cpu.append(elapsed_cpu)
                valid.append(frame.stats["valid"])
        mean = statistics.mean(times)
        intr = model.intrinsics(resolution)
        print(
            f"{label:>4} {intr.width}x{intr.height}: {mean:.3f} s/frame ({1.0 / mean:.2f} frames/s), "
            f"min {min(times):.3f} s, max {max(times):.3f} s, CPU {statistics.mean(cpu):.3f} s/frame, "
            f"{statistics.mean(valid):,.0f} valid points"
        )
        targets.append(Target(f"{label} resolution per frame", f"{mean:.3f} s", f"<= {target:g} s", mean <= target))
    print(format_targets(targets))
    return 0 if all(t.ok for t in targets) else 1


if __name__ == "__main__":
    raise SystemExit(main())
