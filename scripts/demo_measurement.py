#!/usr/bin/env python3
"""The product demo: plan a measurement of the embedded demo part (the 100 mm cube) and execute it on the
simulated station with the simulated laser line scanner, recording everything.

  make demo              # headless
  make demo GUI=1        # with rviz on your display
  scripts/demo_measurement.py --output-dir /tmp/demo [--density 0.03] [--orientations 12] [--solver IP_basic]

Writes to the output directory: the plan (YAML), a rosbag of the run, an rviz snapshot taken during execution,
the coverage figure and a text summary; prints where they are.
"""

import argparse
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from agiprobot_measurement.common.cli import start_process_group, stop_process_group
from agiprobot_measurement.station import PACKAGE_ROOT


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output-dir", default=str(PACKAGE_ROOT / "demo_output"))
    parser.add_argument("--gui", type=int, default=0, help="1: open rviz on the current display")
    parser.add_argument("--part", default="parts/objectA_wuerfel.stl")
    parser.add_argument("--units", default="mm")
    parser.add_argument("--density", type=float, default=0.03, help="points per mm^2")
    parser.add_argument("--orientations", type=int, default=12)
    parser.add_argument("--tilt", default="none")
    parser.add_argument("--solver", default="IP_basic")
    args = parser.parse_args()
    out = Path(args.output_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    bag, plan_file = out / "measurement_demo.bag", out / "measurement_demo_plan.yaml"
    snapshot, figure, summary = out / "measurement_demo.png", out / "coverage.png", out / "summary.txt"
    # the demo owns these files in its output folder: each run replaces them
    for stale in (bag, snapshot, figure):
        stale.unlink(missing_ok=True)

    # a private master so the demo never disturbs (or is disturbed by) another ROS session
    os.environ["ROS_MASTER_URI"] = f"http://127.0.0.1:{free_port()}"
    launch_cmd = [
        "roslaunch",
        "agiprobot_measurement",
        "measurement.launch",
        "record:=true",
        f"bag:={bag}",
        f"allowed_plan_dirs:={out}",  # the node writes plans and figures only where it is allowed to
    ]
    if args.gui:
        launch_cmd.append("rviz:=true")
    log_path = out / "measurement_demo.launch.log"
    started = time.monotonic()
    print("== starting the station, the scanner and the trajectory_manager ==", flush=True)
    with log_path.open("w") as log:
        launch = start_process_group(launch_cmd, stdout=log, stderr=subprocess.STDOUT)
        try:
            return run_demo(args, launch, out, bag, plan_file, snapshot, figure, summary, started)
        finally:
            stop_process_group(launch)


def run_demo(args, launch, out, bag, plan_file, snapshot, figure, summary, started) -> int:
    import rospy
    from actionlib_msgs.msg import GoalStatus

    from agiprobot_measurement.msg import (
        ExecutePlanAction,
        ExecutePlanGoal,
        PlanMeasurementAction,
        PlanMeasurementGoal,
    )
    from agiprobot_measurement.ros.action_client import ActionClient
    from agiprobot_measurement.srv import GetCoverageReport

    for _ in range(100):
        if launch.poll() is not None:
            print(f"demo failed: the launch file exited (log: {out / 'measurement_demo.launch.log'})", file=sys.stderr)
            return 1
        import rosgraph

        if rosgraph.is_master_online():
            break
        time.sleep(0.2)
    rospy.init_node("measurement_demo", anonymous=True, disable_signals=True)
    planner = ActionClient("/trajectory_manager/plan_measurement", PlanMeasurementAction)
    executor = ActionClient("/trajectory_manager/execute_plan", ExecutePlanAction)
    if not (planner.wait_for_server(rospy.Duration(60)) and executor.wait_for_server(rospy.Duration(10))):
        print("demo failed: the trajectory_manager did not come up", file=sys.stderr)
        return 1
    print(f"up in {time.monotonic() - started:.1f} s", flush=True)

    print(
        f"== planning {args.part} ({args.density} points/mm^2, {args.orientations} orientations, tilt {args.tilt}, "
        f"{args.solver}) ==",
        flush=True,
    )
    stage = {"name": None}

    def plan_feedback(fb):
        if fb.stage != stage["name"]:
            stage["name"] = fb.stage
            print(f"  {fb.stage} ...", flush=True)

    plan_started = time.monotonic()
    planner.send_goal(
        PlanMeasurementGoal(
            part_file=str((PACKAGE_ROOT / args.part).resolve()) if not Path(args.part).is_absolute() else args.part,
            units=args.units,
            sampling_density=args.density,
            orientations_around_boresight=args.orientations,
            viewpoint_tilt_mode=args.tilt,
            solver_type=args.solver,
            plan_file=str(plan_file),
            overwrite=True,
        ),
        feedback_cb=plan_feedback,
    )
    planner.wait_for_result()
    plan = planner.get_result()
    if planner.get_state() != GoalStatus.SUCCEEDED:
        print(f"demo failed: planning: {plan.error if plan else 'no result'}", file=sys.stderr)
        return 1
    plan_time = time.monotonic() - plan_started
    print(
        f"planned {plan.number_of_views} views in {plan_time:.1f} s: predicted coverage "
        f"{100 * plan.coverage:.1f} %, estimated execution {plan.estimated_execution_time_s:.1f} s",
        flush=True,
    )

    print("== executing on the simulated station ==", flush=True)
    snap = {"thread": None, "result": None}

    def take_snapshot():
        completed = subprocess.run(
            [
                str(PACKAGE_ROOT / "scripts" / "rviz_snapshot"),
                "-o",
                str(snapshot),
                "--config",
                str(PACKAGE_ROOT / "rviz" / "measurement.rviz"),
                "--settle",
                "15",
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        snap["result"] = completed.stdout.strip() or completed.stderr.strip()

    def execute_feedback(fb):
        print(f"  segment {fb.segment}/{fb.number_of_segments} ({fb.phase})", flush=True)
        # the snapshot shows the scan in progress: start it at the middle measurement segment
        if snap["thread"] is None and fb.phase == "measure" and fb.segment >= fb.number_of_segments // 2:
            snap["thread"] = threading.Thread(target=take_snapshot, daemon=True)
            snap["thread"].start()

    exec_started = time.monotonic()
    executor.send_goal(ExecutePlanGoal(plan_file=""), feedback_cb=execute_feedback)
    executor.wait_for_result()
    executed = executor.get_result()
    if executor.get_state() != GoalStatus.SUCCEEDED:
        print(f"demo failed: execution: {executed.error if executed else 'no result'}", file=sys.stderr)
        return 1
    exec_time = time.monotonic() - exec_started
    if snap["thread"] is not None:
        snap["thread"].join(timeout=120)
    report = rospy.ServiceProxy("/trajectory_manager/get_coverage_report", GetCoverageReport)(str(figure))
    lines = [
        "agiprobot_measurement demo",
        f"part:                  {args.part} ({args.units})",
        f"samples:               {report.number_of_samples} ({args.density} points/mm^2)",
        f"views:                 {report.number_of_views}",
        f"predicted coverage:    {100 * report.predicted_coverage:.1f} % of {report.number_of_coverable} coverable",
        f"measured coverage:     {100 * executed.measured_coverage:.1f} % (simulated scanner)",
        f"estimated execution:   {report.estimated_execution_time_s:.1f} s (executed in {exec_time:.1f} s)",
        f"uncertainty mean/max:  {report.mean_uncertainty_mm:.4f} / {report.max_uncertainty_mm:.4f} mm",
        f"planning time:         {plan_time:.1f} s",
        f"total demo time:       {time.monotonic() - started:.1f} s",
    ]
    summary.write_text("\n".join(lines) + "\n\n" + report.report_yaml)
    rospy.signal_shutdown("demo done")
    os.killpg(launch.pid, signal.SIGINT)
    launch.wait(timeout=30)
    for _ in range(50):  # rosbag renames .bag.active once it has written its index
        if bag.exists():
            break
        time.sleep(0.2)
    print()
    print("\n".join(lines))
    print()
    print(f"plan:            {plan_file}")
    print(f"rosbag:          {bag}")
    print(f"rviz snapshot:   {snapshot} ({snap['result'] or 'not taken'})")
    print(f"coverage figure: {report.figure_file or figure}")
    print(f"summary:         {summary}")
    print(
        f"replay:          roslaunch agiprobot_measurement replay.launch bag:={bag} rviz:=true "
        f"rviz_config:={PACKAGE_ROOT / 'rviz' / 'measurement.rviz'}"
    )
    print(f"coverage again:  scripts/coverage_from_bag.py {bag}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
