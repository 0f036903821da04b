#!/usr/bin/env python3
"""Plan and execute a measurement through the trajectory_manager node's actions (measurement.launch running).

  rosrun agiprobot_measurement measure.py --part parts/objectA_wuerfel.stl --density 0.03 --plan-file cube
  rosrun agiprobot_measurement measure.py --execute-only cube
  rosrun agiprobot_measurement measure.py --no-execute --solver greedy

Plan names follow the node's file policy: they resolve under its ~plan_directory (plans/), absolute names only
inside it or ~allowed_plan_dirs, '..' and '~' are refused, and an existing plan is replaced only with --overwrite.
Prints the planning stages and the execution's segments as they progress, then the result.
"""

import argparse
import sys

import rospy
from actionlib_msgs.msg import GoalStatus

from agiprobot_measurement.msg import (
    ExecutePlanAction,
    ExecutePlanGoal,
    PlanMeasurementAction,
    PlanMeasurementGoal,
)
from agiprobot_measurement.ros.action_client import ActionClient

NODE = "/trajectory_manager"


def plan(args) -> bool:
    client = ActionClient(f"{NODE}/plan_measurement", PlanMeasurementAction)
    if not client.wait_for_server(rospy.Duration(20.0)):
        print(f"error: no {NODE}/plan_measurement action server (is measurement.launch running?)", file=sys.stderr)
        return False
    goal = PlanMeasurementGoal(
        part_file=args.part or "",
        units=args.units or "",
        sampling_density=args.density or 0.0,
        orientations_around_boresight=args.orientations or 0,
        viewpoint_tilt_mode=args.tilt or "",
        solver_type=args.solver or "",
        uncertainty_threshold_mm=args.threshold or 0.0,
        plan_file=args.plan_file or "",
        overwrite=bool(args.overwrite),
    )
    last = {"stage": None}

    def feedback(fb):
        if fb.stage != last["stage"]:
            print(f"  planning: {fb.stage}", flush=True)
            last["stage"] = fb.stage
        if fb.message and args.verbose:
            print(f"    {100 * fb.progress:5.1f} %  {fb.message}", flush=True)

    client.send_goal(goal, feedback_cb=feedback)
    client.wait_for_result()
    result = client.get_result()
    if client.get_state() != GoalStatus.SUCCEEDED:
        print(f"error: planning failed: {result.error if result else 'no result'}", file=sys.stderr)
        return False
    print(
        f"planned {result.number_of_views} views: coverage {100 * result.coverage:.1f} % of coverable points "
        f"({100 * result.coverage_of_samples:.1f} % of all samples), estimated execution "
        f"{result.estimated_execution_time_s:.1f} s" + (f", stored in {result.plan_file}" if result.plan_file else "")
    )
    return True


def execute(plan_file: str) -> bool:
    client = ActionClient(f"{NODE}/execute_plan", ExecutePlanAction)
    if not client.wait_for_server(rospy.Duration(20.0)):
        print(f"error: no {NODE}/execute_plan action server", file=sys.stderr)
        return False
    last = {"segment": 0}

    def feedback(fb):
        if fb.segment != last["segment"]:
            print(
                f"  segment {fb.segment}/{fb.number_of_segments} ({fb.phase}), {100 * fb.progress:.0f} % done",
                flush=True,
            )
            last["segment"] = fb.segment

    client.send_goal(ExecutePlanGoal(plan_file=plan_file), feedback_cb=feedback)
    client.wait_for_result()
    result = client.get_result()
    if client.get_state() != GoalStatus.SUCCEEDED:
        print(f"error: execution failed: {result.error if result else 'no result'}", file=sys.stderr)
        return False
    measured = f"{100 * result.measured_coverage:.1f} %" if result.measured_coverage >= 0 else "n/a"
    predicted = f"{100 * result.predicted_coverage:.1f} %" if result.predicted_coverage >= 0 else "n/a"
    print(f"executed {result.segments_executed} segments: coverage predicted {predicted}, measured {measured}")
    return True


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", help="part file (default: the node's configured part)")
    parser.add_argument("--units", help="the part file's unit (mm, cm, dm, m, inch, ft)")
    parser.add_argument("--density", type=float, help="sampling density, points per mm^2")
    parser.add_argument("--orientations", type=int, help="orientations around the boresight")
    parser.add_argument("--tilt", help="none, limited or full")
    parser.add_argument("--solver", help="greedy, IP_basic, IP_uncertainty or IP_time")
    parser.add_argument("--threshold", type=float, help="uncertainty threshold, mm")
    parser.add_argument("--plan-file", help="store the plan under this name (in the node's plan directory)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing plan of that name")
    parser.add_argument("--no-execute", action="store_true", help="plan only")
    parser.add_argument("--execute-only", metavar="PLAN", help="execute a stored plan instead of planning")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(rospy.myargv()[1:])
    import rosgraph

    if not rosgraph.is_master_online():
        print("error: no ROS master: start `roslaunch agiprobot_measurement measurement.launch` first", file=sys.stderr)
        return 2
    rospy.init_node("measure", anonymous=True)
    if args.execute_only:
        return 0 if execute(args.execute_only) else 1
    if not plan(args):
        return 1
    if args.no_execute:
        return 0
    return 0 if execute("") else 1


if __name__ == "__main__":
    sys.exit(main())
