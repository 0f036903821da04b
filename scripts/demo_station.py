#!/usr/bin/env python3
"""The station demo: bring up the simulated UR10e station, drive home -> up -> home through the controller's
action while recording a rosbag, take an rviz snapshot, and print where everything is.

  make demo                       # headless
  make demo GUI=1                 # with an rviz window
  scripts/demo_station.py --output-dir /tmp/demo
"""

import argparse
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from agiprobot_measurement.common.cli import start_process_group, stop_process_group
from agiprobot_measurement.errors import InternalError
from agiprobot_measurement.station import PACKAGE_ROOT

#: the robot's trajectory action (the UR driver's name, which the simulated controller serves)
ACTION = "/scaled_pos_joint_traj_controller/follow_joint_trajectory"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def run(cmd, env, timeout_s=120):
    print(f"$ {' '.join(str(c) for c in cmd)}", flush=True)
    return subprocess.run(cmd, env=env, timeout=timeout_s, check=True)


def wait_for_action_server(env, action=ACTION, timeout_s=30.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        topics = subprocess.run(["rostopic", "list"], env=env, capture_output=True, text=True).stdout
        if f"{action}/status" in topics.split():
            return
        time.sleep(0.5)
    raise InternalError(f"the station did not come up (no {action} action server)")


def bag_summary(bag_path: Path) -> str:
    import rosbag

    with rosbag.Bag(str(bag_path)) as bag:
        info = bag.get_type_and_topic_info()
        counts = ", ".join(f"{topic} {meta.message_count}" for topic, meta in sorted(info.topics.items()))
        return f"{bag.get_end_time() - bag.get_start_time():.1f} s; {counts}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output-dir", default=str(PACKAGE_ROOT / "demo_output"), help="where results go")
    parser.add_argument("--gui", type=int, default=0, help="1: open rviz on the current display")
    args = parser.parse_args()
    out = Path(args.output_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "station_demo.bag"
    snapshot = out / "station_demo.png"
    bag.unlink(missing_ok=True)

    # a private master so the demo never disturbs (or is disturbed by) another ROS session
    env = dict(os.environ, ROS_MASTER_URI=f"http://127.0.0.1:{free_port()}")
    launch_cmd = ["roslaunch", "agiprobot_measurement", "station.launch", "record:=true", f"bag:={bag}"]
    if args.gui:
        launch_cmd.append("rviz:=true")
    print("== starting the station ==", flush=True)
    log = (out / "station_demo.launch.log").open("w")
    launch = start_process_group(launch_cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    started = time.monotonic()
    try:
        wait_for_action_server(env)
        print(f"station up in {time.monotonic() - started:.1f} s", flush=True)
        print("== driving home -> up ==", flush=True)
        run(["rosrun", "agiprobot_measurement", "move_to_named_state.py", "home", "up"], env)
        print("== rviz snapshot ==", flush=True)
        run([str(PACKAGE_ROOT / "scripts" / "rviz_snapshot"), "-o", str(snapshot)], env)
        print("== driving up -> home ==", flush=True)
        run(["rosrun", "agiprobot_measurement", "move_to_named_state.py", "home"], env)
        time.sleep(0.5)
    except (RuntimeError, subprocess.SubprocessError) as exc:
        print(f"demo failed: {exc} (launch log: {out / 'station_demo.launch.log'})", file=sys.stderr)
        return 1
    finally:
        stop_process_group(launch)
        log.close()
    for _ in range(50):  # rosbag renames .bag.active to .bag once it has written its index
        if bag.exists():
            break
        time.sleep(0.2)
    print()
    print("== station demo done ==")
    print(f"rosbag:   {bag} ({bag_summary(bag)})")
    print(f"snapshot: {snapshot}")
    print(f"replay:   roslaunch agiprobot_measurement replay.launch bag:={bag} rviz:=true")
    return 0


if __name__ == "__main__":
    sys.exit(main())
