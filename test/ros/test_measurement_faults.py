#!/usr/bin/env python3
"""rostest: fault injection against the trajectory_manager node.

The tests run in order: a good plan first, then the probes (an alias-bomb plan file, huge sampling densities,
overwriting, names that escape the plan folder, refused executions, a bad part transform, a directory as part
file), each followed by a good request the node must still serve; then the robot controller is killed by its PID
during an execution (the goal must abort within 2 s naming the segment, the plan must stay, and the respawned
controller must run the next goal); finally a load test of the node's cheap services (1 and 4 clients, 200 calls
each) that prints the rates. No probe may write a file outside the plan folder.
"""

import os
import signal
import sys
import threading
import time
import unittest
import xmlrpc.client
from pathlib import Path

import rosgraph
import rospy
import rostest
import yaml
from actionlib_msgs.msg import GoalStatus
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from agiprobot_measurement.msg import ExecutePlanAction, ExecutePlanGoal, PlanMeasurementAction, PlanMeasurementGoal
from agiprobot_measurement.ros.action_client import ActionClient
from agiprobot_measurement.srv import GetCoverageReport, LoadPlan, StorePlan

sys.path.insert(0, str(Path(__file__).resolve().parent))
from station_test_utils import quick_goal as station_quick_goal


def quick_goal(**overrides) -> PlanMeasurementGoal:
    return station_quick_goal(solver_type="greedy", **overrides)


NODE = "/trajectory_manager"
ESCAPES = ["../victim/settings", "../../x", "~/x", "/etc/agiprobot_fault_plan", "sub/../../y"]
LOAD_CALLS = 200


def alias_bomb(levels: int = 9, width: int = 9) -> str:
    lines = ["- Timestamp: now", "  bomb:", "    l0: &l0 [lol]"]
    for level in range(1, levels + 1):
        lines.append(f"    l{level}: &l{level} [{', '.join([f'*l{level - 1}'] * width)}]")
    return "\n".join(lines) + "\n"


def files_under(directory: Path) -> set[Path]:
    return {p for p in directory.rglob("*")} if directory.is_dir() else set()


def node_pid(name: str) -> int:
    uri = rosgraph.Master("/test_measurement_faults").lookupNode(name)
    code, message, pid = xmlrpc.client.ServerProxy(uri).getPid("/test_measurement_faults")
    if code != 1:
        raise RuntimeError(f"getPid of {name}: {message}")
    return int(pid)


class MeasurementFaultTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_measurement_faults")
        cls.root = Path(rospy.get_param("~plan_directory"))
        cls.root.mkdir(parents=True, exist_ok=True)
        for stale in cls.root.rglob("*"):
            if stale.is_file():
                stale.unlink()
        cls.outside_before = files_under(cls.root.parent) - files_under(cls.root)
        cls.planner = ActionClient(f"{NODE}/plan_measurement", PlanMeasurementAction)
        cls.executor = ActionClient(f"{NODE}/execute_plan", ExecutePlanAction)
        assert cls.planner.wait_for_server(rospy.Duration(60)), "no plan_measurement action"
        assert cls.executor.wait_for_server(rospy.Duration(10)), "no execute_plan action"
        for name in ("load_plan", "store_plan", "get_coverage_report"):
            rospy.wait_for_service(f"{NODE}/{name}", timeout=30)
        cls.load = rospy.ServiceProxy(f"{NODE}/load_plan", LoadPlan)
        cls.store = rospy.ServiceProxy(f"{NODE}/store_plan", StorePlan)
        cls.report = rospy.ServiceProxy(f"{NODE}/get_coverage_report", GetCoverageReport)
        cls.stitching = []
        rospy.Subscriber("/laser_scanner/stitching", Bool, lambda msg: cls.stitching.append(msg.data))
        cls.node_log = []
        rospy.Subscriber(
            "/rosout", Log, lambda msg: cls.node_log.append(msg.msg) if msg.name == NODE else None, queue_size=100
        )

    def _plan(self, goal, timeout_s=240.0):
        self.planner.send_goal(goal)
        self.assertTrue(self.planner.wait_for_result(rospy.Duration(timeout_s)), "planning timed out")
        return self.planner.get_state(), self.planner.get_result()

    def _execute(self, plan_file="", timeout_s=300.0, feedback=None):
        self.executor.send_goal(ExecutePlanGoal(plan_file=plan_file), feedback_cb=feedback)
        self.assertTrue(self.executor.wait_for_result(rospy.Duration(timeout_s)), "execution timed out")
        return self.executor.get_state(), self.executor.get_result()

    def _plan_source(self) -> str:
        reply = self.report("")
        self.assertTrue(reply.success, reply.message)
        return reply.message

    def _serves_a_good_request(self):
        reply = self.report("")
        self.assertTrue(reply.success, reply.message)
        self.assertGreater(reply.number_of_views, 0)

    # ------------------------------------------------------------------------------------- a good plan
    def test_1_plan(self):
        state, result = self._plan(quick_goal())
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        self.assertEqual(result.plan_file, "")

    # ------------------------------------------------------------------------------------- row 2: budget
    def test_2_huge_densities_are_refused_up_front(self):
        for density in (1000.0, 1e6):
            started = time.monotonic()
            state, result = self._plan(quick_goal(sampling_density=density), timeout_s=60)
            elapsed = time.monotonic() - started
            self.assertEqual(state, GoalStatus.ABORTED)
            self.assertIn("max_samples", result.error)
            self.assertIn("samples", result.error)
            self.assertNotIn("internal error", result.error)
            self.assertLess(elapsed, 10.0, f"density {density} took {elapsed:.1f} s to refuse")
            print(f"[faults] density {density:g} refused in {elapsed:.2f} s: {result.error[:120]}...")
        self._serves_a_good_request()

    # ------------------------------------------------------------------------------------- row 1: alias bomb
    def test_3_an_alias_bomb_plan_is_refused_and_the_plan_kept(self):
        source = self._plan_source()
        (self.root / "bomb.yaml").write_text(alias_bomb())
        started = time.monotonic()
        reply = self.load("bomb")
        self.assertFalse(reply.success)
        self.assertIn("aliases", reply.message)
        self.assertLess(time.monotonic() - started, 10.0)
        self.assertEqual(self._plan_source(), source)
        stored = self.store(plan_file="after_bomb")  # returns at once: the current plan, not the bomb
        self.assertTrue(stored.success, stored.message)
        self.assertLess((self.root / "after_bomb.yaml").stat().st_size, 10_000_000)

    # ------------------------------------------------------------------------------------- rows 3, 13
    def test_4_store_does_not_overwrite_unless_asked_and_load_finds_the_name(self):
        first = self.store(plan_file="baseline")
        self.assertTrue(first.success, first.message)
        self.assertEqual(first.plan_file, str(self.root / "baseline.yaml"))
        before = (self.root / "baseline.yaml").read_bytes()
        again = self.store(plan_file="baseline")
        self.assertFalse(again.success)
        self.assertIn("exists", again.message)
        self.assertEqual((self.root / "baseline.yaml").read_bytes(), before)
        self.assertTrue(self.store(plan_file="baseline", overwrite=True).success)
        loaded = self.load("baseline")
        self.assertTrue(loaded.success, loaded.message)
        self.assertGreater(loaded.number_of_segments, 0)
        # a planning goal for an existing plan file is refused before planning
        started = time.monotonic()
        state, result = self._plan(quick_goal(plan_file="baseline"), timeout_s=60)
        self.assertEqual(state, GoalStatus.ABORTED)
        self.assertIn("exists", result.error)
        self.assertLess(time.monotonic() - started, 10.0)
        state, result = self._plan(quick_goal(plan_file="baseline", overwrite=True))
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        self.assertEqual(result.plan_file, str(self.root / "baseline.yaml"))

    # ------------------------------------------------------------------------------------- rows 5, 6, 7
    def test_5_names_cannot_escape_the_plan_folder(self):
        for name in ESCAPES:
            reply = self.store(plan_file=name, overwrite=True)
            self.assertFalse(reply.success, f"store_plan {name!r} was accepted")
            self.assertIn(str(self.root), reply.message)
            self.assertFalse(self.load(name).success)
        for name in ("../../../../etc/shadow", "/etc/shadow", "/etc/passwd"):
            reply = self.load(name)
            self.assertFalse(reply.success)
            self.assertIn(str(self.root), reply.message)
            self.assertNotIn("not found", reply.message)  # it does not tell whether the file exists
        for name in ("/etc/fig.png", "../fig.png", "~/fig.png"):
            reply = self.report(name)
            self.assertFalse(reply.success, f"figure {name!r} was accepted")
        self.assertFalse(Path("/etc/fig.png").exists())
        self.assertFalse(Path("~/x.yaml").expanduser().exists())
        figure = self.report("coverage.png")
        self.assertTrue(figure.success, figure.message)
        self.assertEqual(figure.figure_file, str(self.root / "coverage.png"))
        second = self.report("coverage.png")
        self.assertEqual(second.figure_file, str(self.root / "coverage_2.png"))  # never replaced
        self._serves_a_good_request()

    # ------------------------------------------------------------------------------------- rows 4, 10, 11
    def test_6_refused_plans_keep_the_current_one(self):
        source = self._plan_source()
        data = yaml.safe_load((self.root / "baseline.yaml").read_text())
        data[0]["parameters"]["part_file"] = str(self.root / "no_such_part.stl")
        (self.root / "unscannable.yaml").write_text(yaml.safe_dump(data))
        state, result = self._execute("unscannable", timeout_s=60)
        self.assertEqual(state, GoalStatus.ABORTED)
        self.assertIn("scanner", result.error)
        self.assertEqual(self._plan_source(), source)
        stored = self.store(plan_file="after_refusal")
        self.assertTrue(stored.success, stored.message)
        self.assertNotIn("no_such_part", (self.root / "after_refusal.yaml").read_text())
        # a bad part transform names the file and the key
        data[0]["parameters"]["part_transform_mm"] = [1.0, 2.0, 3.0]
        (self.root / "bad_transform.yaml").write_text(yaml.safe_dump(data))
        reply = self.load("bad_transform")
        self.assertFalse(reply.success)
        self.assertIn("bad_transform.yaml", reply.message)
        self.assertIn("part_transform_mm", reply.message)
        self.assertNotIn("reshape", reply.message)
        # a finite but absurd one too (it executed "successfully" 1e300 mm away)
        data[0]["parameters"]["part_transform_mm"] = [[1, 0, 0, 1.0e300], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
        (self.root / "far_transform.yaml").write_text(yaml.safe_dump(data))
        reply = self.load("far_transform")
        self.assertFalse(reply.success)
        self.assertIn("far_transform.yaml: parameters.part_transform_mm places the part 1e+300 mm", reply.message)
        # a directory as part file says so
        state, result = self._plan(quick_goal(part_file=str(self.root)), timeout_s=60)
        self.assertEqual(state, GoalStatus.ABORTED)
        self.assertIn("is a directory", result.error)
        self.assertEqual(self._plan_source(), source)
        self._serves_a_good_request()

    def test_6b_the_report_counts_the_views_of_the_plan_it_names(self):
        planned = self.report("")
        self.assertTrue(planned.success, planned.message)
        self.assertGreater(planned.predicted_coverage, 0.0)
        data = yaml.safe_load((self.root / "baseline.yaml").read_text())
        (self.root / "one_view.yaml").write_text(yaml.safe_dump(data[:3]))  # the metadata and the first view
        try:
            self.assertTrue(self.load("one_view").success)
            reply = self.report("")
            self.assertTrue(reply.success, reply.message)
            self.assertIn(f"plan: {self.root / 'one_view.yaml'} (loaded: no coverage prediction", reply.message)
            self.assertEqual(reply.number_of_views, 1)
            self.assertEqual(reply.predicted_coverage, -1.0)
            self.assertEqual(yaml.safe_load(reply.report_yaml)["number_of_views"], 1)
            self.assertFalse(self.report(str(self.root / "one_view.png")).success, "no figure of another plan")
        finally:  # the later tests execute the planned plan again
            state, result = self._plan(quick_goal())
            self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)

    # ------------------------------------------------------------------------------------- row 8
    def test_7_a_killed_controller_aborts_the_execution_and_a_restart_works(self):
        source = self._plan_source()
        pid = node_pid("/ur_hardware_interface")
        killed = {}

        def feedback(fb):
            if fb.segment >= 2 and "at" not in killed:
                killed["segment"] = fb.segment
                killed["at"] = time.monotonic()
                os.kill(pid, signal.SIGKILL)

        self.executor.send_goal(ExecutePlanGoal(plan_file=""), feedback_cb=feedback)
        self.assertTrue(self.executor.wait_for_result(rospy.Duration(120)), "no result after the controller died")
        done = time.monotonic()
        state, result = self.executor.get_state(), self.executor.get_result()
        self.assertIn("at", killed, "the execution ended before the controller was killed")
        elapsed = done - killed["at"]
        print(
            f"[faults] controller killed in segment {killed['segment']}; result after {elapsed:.2f} s: {result.error}"
        )
        self.assertEqual(state, GoalStatus.ABORTED)
        self.assertRegex(result.error, r"controller lost during segment \d+ of \d+")
        self.assertLess(elapsed, 2.5)  # 2 s, and the time the result takes to arrive on a loaded machine
        deadline = time.monotonic() + 3.0
        while not (self.stitching and self.stitching[-1] is False) and time.monotonic() < deadline:
            time.sleep(0.05)
        self.assertTrue(self.stitching and self.stitching[-1] is False, "scanning not stopped")
        self.assertEqual(self._plan_source(), source)
        # roslaunch respawns the controller: the next goal works
        deadline = time.monotonic() + 60
        new_pid = None
        while time.monotonic() < deadline:
            try:
                new_pid = node_pid("/ur_hardware_interface")
                if new_pid != pid:
                    break
            except Exception:
                pass
            time.sleep(0.5)
        self.assertNotEqual(new_pid, pid, "the controller ur_hardware_interface was not respawned")
        rospy.wait_for_message("/joint_states", JointState, timeout=30)
        time.sleep(2.0)
        # the next goal works on the respawned controller: test_7b executes on it up to its second segment

    def test_7b_a_stalled_controller_is_noticed_by_its_heartbeat(self):
        """(After test_7: the respawned controller executes the plan's first segment before it is stalled.)"""
        source = self._plan_source()
        pid = node_pid("/ur_hardware_interface")
        stopped = {}

        def feedback(fb):
            if fb.segment >= 2 and "at" not in stopped:
                stopped["at"] = time.monotonic()
                os.kill(pid, signal.SIGSTOP)  # alive but silent: only the /joint_states heartbeat tells

        try:
            self.executor.send_goal(ExecutePlanGoal(plan_file=""), feedback_cb=feedback)
            self.assertTrue(
                self.executor.wait_for_result(rospy.Duration(120)), "no result after the controller stalled"
            )
            self.assertIn("at", stopped, f"the first segment did not execute: {self.executor.get_result().error}")
            elapsed = time.monotonic() - stopped["at"]
        finally:
            os.kill(pid, signal.SIGCONT)
        result = self.executor.get_result()
        print(f"[faults] controller stalled; result after {elapsed:.2f} s: {result.error}", flush=True)
        self.assertEqual(self.executor.get_state(), GoalStatus.ABORTED)
        self.assertRegex(result.error, r"controller lost during segment \d+ of \d+: no /joint_states for")
        self.assertLess(elapsed, 2.5)
        self.assertEqual(self._plan_source(), source)
        # the resumed controller publishes again (on a loaded machine it may take seconds to catch up)
        rospy.wait_for_message("/joint_states", JointState, timeout=30)
        time.sleep(2.0)
        # a plan file runs on the resumed controller; its log line says the coverage is not known, not -100 %
        state, result = self._execute("baseline")
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        time.sleep(1.0)
        executed = [line for line in self.node_log if "executed" in line and "segments" in line]
        self.assertTrue(executed, "no execution log line")
        self.assertIn("coverage not known", executed[-1])
        self.assertFalse(any("-100.0 %" in line for line in self.node_log))

    def test_7c_a_cancel_names_the_stage_of_the_last_feedback(self):
        stages = []

        def feedback(fb):
            stages.append(fb.stage)
            if fb.stage == "metrology" and len(stages) > 1:
                self.planner.cancel_goal()

        self.planner.send_goal(
            quick_goal(sampling_density=0.03, orientations_around_boresight=12), feedback_cb=feedback
        )
        self.assertTrue(self.planner.wait_for_result(rospy.Duration(120)))
        time.sleep(0.5)
        self.assertEqual(self.planner.get_state(), GoalStatus.PREEMPTED)
        self.assertEqual(self.planner.get_result().error, f"cancelled during {stages[-1]}")
        self._serves_a_good_request()

    # ------------------------------------------------------------------------------------- load test
    def _load(self, name: str, service_type, call, clients: int) -> float:
        """``clients`` threads, each calling ``name`` LOAD_CALLS times through ``call(proxy)`` (which returns ''
        or what went wrong); asserts zero failures and returns the rate (calls/s)."""
        failures: list = []

        def client():
            proxy = rospy.ServiceProxy(f"{NODE}/{name}", service_type)
            for _ in range(LOAD_CALLS):
                try:
                    problem = call(proxy)
                except Exception as exc:
                    problem = repr(exc)
                if problem:
                    failures.append(problem)

        threads = [threading.Thread(target=client) for _ in range(clients)]
        started = time.monotonic()
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        elapsed = time.monotonic() - started
        rate = clients * LOAD_CALLS / elapsed
        print(
            f"[faults] {name}: {clients} client(s) x {LOAD_CALLS} calls in {elapsed:.2f} s = {rate:.0f} calls/s, "
            f"{len(failures)} failures",
            flush=True,
        )
        self.assertEqual(failures, [], f"{len(failures)} failures, first: {failures[:1]}")
        return rate

    def test_8_cheap_services_under_load(self):
        def report(proxy):
            reply = proxy("")
            return "" if reply.success else reply.message

        def refused_load(proxy):  # the refusal path: cheap, and it must stay clean
            reply = proxy("missing_plan")
            return "" if not reply.success and "not found" in reply.message else f"unexpected: {reply.message}"

        for clients in (1, 4):
            self._load("get_coverage_report", GetCoverageReport, report, clients)
            self._load("load_plan", LoadPlan, refused_load, clients)
        self._serves_a_good_request()

    def test_8b_a_plan_whose_file_cannot_be_written_is_kept(self):
        late = self.root / "taken_meanwhile.yaml"
        late.unlink(missing_ok=True)

        def take_the_name(feedback):  # after the goal's up-front check: the final write is refused
            if not late.exists():
                late.write_text("someone else's file\n")

        self.planner.send_goal(quick_goal(plan_file="taken_meanwhile"), feedback_cb=take_the_name)
        self.assertTrue(self.planner.wait_for_result(rospy.Duration(240.0)), "planning timed out")
        result = self.planner.get_result()
        self.assertEqual(self.planner.get_state(), GoalStatus.ABORTED)
        self.assertIn("is the current plan", result.error)
        self.assertIn("taken_meanwhile.yaml", result.error)
        self.assertGreater(result.number_of_views, 0)
        self.assertEqual(late.read_text(), "someone else's file\n")
        # the plan made is the current one: it can be stored elsewhere
        self.assertIn("(planned, not stored)", self._plan_source())
        stored = self.store(plan_file="rescued", overwrite=True)
        self.assertTrue(stored.success, stored.message)

    # ------------------------------------------------------------------------------------- nothing outside
    def test_9_nothing_was_written_outside_the_plan_folder(self):
        outside_now = files_under(self.root.parent) - files_under(self.root)
        new = {p for p in outside_now - self.outside_before if "fault_plans" not in str(p)}
        # other tests' artifacts may appear next to the folder meanwhile; none of the probes' names may
        probes = {"victim", "settings", "x.yaml", "y.yaml", "fig.png", "agiprobot_fault_plan.yaml"}
        self.assertEqual({p for p in new if p.name in probes or p.parent.name in probes}, set())
        for escape in ("/etc/agiprobot_fault_plan.yaml", "/etc/fig.png"):
            self.assertFalse(Path(escape).exists())


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "measurement_faults", MeasurementFaultTest, sys.argv)
