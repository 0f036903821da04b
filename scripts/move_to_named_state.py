#!/usr/bin/env python3
"""Drive the (simulated) robot through named states with direct joint moves.

  rosrun agiprobot_measurement move_to_named_state.py home up home [--velocity-scaling 0.5]

Each move is a synchronised point-to-point joint motion within the joint limits, sent to the controller's
ExecuteJointTrajectory action. Moves are straight lines in joint space: use them between states known to be
collision-free (the named states of config/named_states.yaml are).
"""

import argparse
import sys

import numpy as np
import rospy
from sensor_msgs.msg import JointState

from agiprobot_measurement.common.cli import run_main
from agiprobot_measurement.motion.point_to_point import point_to_point
from agiprobot_measurement.msg import ExecuteJointTrajectoryAction, ExecuteJointTrajectoryGoal
from agiprobot_measurement.ros.action_client import ActionClient
from agiprobot_measurement.ros.conversions import joint_trajectory_to_msg
from agiprobot_measurement.station import load_joint_limits, load_named_states


def current_state(joint_names, timeout_s=5.0):
    msg = rospy.wait_for_message("/joint_states", JointState, timeout=timeout_s)
    by_name = dict(zip(msg.name, msg.position, strict=True))
    return np.array([by_name[name] for name in joint_names])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("states", nargs="+", help="named states to visit in order")
    parser.add_argument("--velocity-scaling", type=float, default=0.5, help="fraction of the velocity limits")
    parser.add_argument("--acceleration-scaling", type=float, default=0.5, help="fraction of the acceleration limits")
    parser.add_argument("--action", default="/robot_sim/execute_trajectory", help="controller action name")
    args = parser.parse_args(rospy.myargv()[1:])
    rospy.init_node("move_to_named_state", anonymous=True)
    limits = load_joint_limits()
    named = load_named_states()
    unknown = [s for s in args.states if s not in named]
    if unknown:
        print(f"error: unknown named state(s) {unknown}; known: {', '.join(named)}", file=sys.stderr)
        return 2
    client = ActionClient(args.action, ExecuteJointTrajectoryAction)
    if not client.wait_for_server(rospy.Duration(10.0)):
        print(f"error: no controller action server at {args.action}", file=sys.stderr)
        return 1
    for name in args.states:
        start = current_state(list(limits.names))
        trajectory = point_to_point(start, named[name], limits, args.velocity_scaling, args.acceleration_scaling)
        rospy.loginfo("moving to '%s' (%.2f s)", name, trajectory.duration)
        client.send_goal(ExecuteJointTrajectoryGoal(trajectory=joint_trajectory_to_msg(trajectory)))
        client.wait_for_result(rospy.Duration(trajectory.duration + 10.0))
        result = client.get_result()
        if result is None or not result.success:
            print(f"error: move to '{name}' failed: {result.error if result else 'no result'}", file=sys.stderr)
            return 1
        reached = current_state(list(limits.names))
        print(f"reached '{name}': max joint error {np.abs(reached - named[name]).max():.2e} rad")
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
