#!/usr/bin/env python3
"""Drive the (simulated) robot through named states with direct joint moves.

  rosrun agiprobot_measurement move_to_named_state.py home up home [--velocity-scaling 0.5] [--executor moveit]

Each move is a synchronised point-to-point joint motion within the joint limits, sent to the controller's
control_msgs/FollowJointTrajectory action (a UR driver's or the simulator's; --executor moveit: move_group's
ExecuteTrajectory). The start and the limits are checked before each move is sent. Moves are straight lines in joint space: use them between states known to be
collision-free (the named states of config/named_states.yaml are).
"""

import argparse
import sys

import numpy as np
import rospy

from agiprobot_measurement.common.cli import run_main
from agiprobot_measurement.motion.point_to_point import point_to_point
from agiprobot_measurement.planning.plan.execution import ExecutionError
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.robot_client import EXECUTORS, MotionSettings, make_motion_client
from agiprobot_measurement.station import load_joint_limits, load_named_states


def current_state(joint_states: JointStateCache, timeout_s=5.0):
    state = joint_states.wait(timeout_s)
    if state is None:
        raise ExecutionError(f"no {joint_states.topic} for {timeout_s:.0f} s: is the robot running?")
    return state


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("states", nargs="+", help="named states to visit in order")
    parser.add_argument("--velocity-scaling", type=float, default=0.5, help="fraction of the velocity limits")
    parser.add_argument("--acceleration-scaling", type=float, default=0.5, help="fraction of the acceleration limits")
    parser.add_argument("--executor", choices=list(EXECUTORS), default="follow_joint_trajectory", help="motion client")
    parser.add_argument(
        "--action",
        default="",
        help=f"the action's name (default: {EXECUTORS['follow_joint_trajectory']}, for moveit {EXECUTORS['moveit']})",
    )
    args = parser.parse_args(rospy.myargv()[1:])
    rospy.init_node("move_to_named_state", anonymous=True)
    limits = load_joint_limits()
    named = load_named_states()
    unknown = [s for s in args.states if s not in named]
    if unknown:
        print(f"error: unknown named state(s) {unknown}; known: {', '.join(named)}", file=sys.stderr)
        return 2
    joint_states = JointStateCache(list(limits.names))
    client = make_motion_client(MotionSettings(args.executor, args.action), limits, joint_states.latest)
    if not client.wait_for_server(10.0):
        print(f"error: no controller action server at {client.action}", file=sys.stderr)
        return 1
    for name in args.states:
        start = current_state(joint_states)
        trajectory = point_to_point(start, named[name], limits, args.velocity_scaling, args.acceleration_scaling)
        rospy.loginfo("moving to '%s' (%.2f s)", name, trajectory.duration)
        try:
            client.execute(trajectory)
        except ExecutionError as exc:
            print(f"error: move to '{name}' failed: {exc}", file=sys.stderr)
            return 1
        rospy.sleep(0.05)  # a /joint_states after the end
        reached = current_state(joint_states)
        print(f"reached '{name}': max joint error {np.abs(reached - named[name]).max():.2e} rad")
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
