#!/usr/bin/env python3
"""rostest: the faults a real UR cell has, against the trajectory_manager on the simulated UR driver.

In order: a plan; the UR program stopped during a measurement segment (``/ur_driver_sim/set_program_running``
false): the execution must stop within 1 s, say that the program stopped and keep the plan; once the program runs,
the full plan at 100 % speed (duration, measured coverage); a protective stop likewise
(``/ur_driver_sim/protective_stop``, then ``unlock_protective_stop``), after which the plan runs with the speed slider
at ~speed_slider (0.5; the benchmark: 0.3) (``/ur_hardware_interface/set_speed_slider``): it takes longer and
measures the same coverage. The figures
(stop latencies, durations, coverages) are printed and, given ``~figures_file``, written there as YAML
(``python -m benchmarks.reliability.real_cell`` runs this test for them).
"""

import sys
import threading
import time
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
import yaml
from actionlib_msgs.msg import GoalStatus
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger
from ur_msgs.srv import SetSpeedSliderFraction

from agiprobot_measurement.msg import ExecutePlanAction, ExecutePlanGoal, PlanMeasurementAction
from agiprobot_measurement.ros.action_client import ActionClient
from agiprobot_measurement.ros.robot_client import PROGRAM_RUNNING_TOPIC
from agiprobot_measurement.srv import GetCoverageReport

sys.path.insert(0, str(Path(__file__).resolve().parent))
from station_test_utils import quick_goal

NODE = "/trajectory_manager"
SIM = "/ur_driver_sim"
#: joint motion below this (rad, any joint, between two /joint_states) counts as standing
STILL_RAD = 1e-5
#: /joint_states kept for the stop latency: 240 s at the driver's 500 Hz (a loaded machine answers late)
KEEP_SAMPLES = 120000
#: the robot must stand within this after the fault (s)
STOP_WITHIN_S = 1.0
#: ... and stay standing for this long (s)
STILL_HOLD_S = 0.3
#: measured coverage at the slowed vs 100 % speed (share of the sample points)
COVERAGE_TOLERANCE = 0.01


class _JointRecorder:
    """Every /joint_states (monotonic receive time, positions by name) for the stop latency."""

    def __init__(self):
        self.lock = threading.Lock()
        self.samples = []
        self.sub = rospy.Subscriber("/joint_states", JointState, self.on_state, queue_size=100)

    def on_state(self, msg):
        positions = dict(zip(msg.name, msg.position, strict=True))
        with self.lock:
            self.samples.append((time.monotonic(), np.array([positions[n] for n in sorted(positions)])))
            del self.samples[:-KEEP_SAMPLES]

    def stood_still_at(self, since: float, hold_s: float = STILL_HOLD_S) -> float | None:
        """The first receive time after ``since`` from which the joints stay within STILL_RAD for ``hold_s``."""
        with self.lock:
            if not self.samples or self.samples[0][0] > since:
                raise AssertionError("the /joint_states around the fault are no longer kept")
            samples = [s for s in self.samples if s[0] >= since]
        for i in range(1, len(samples)):
            start_t, start_q = samples[i - 1]
            later = [q for t, q in samples[i:] if t - start_t <= hold_s]
            if samples[-1][0] - start_t < hold_s:
                return None
            if all(np.abs(q - start_q).max() < STILL_RAD for q in later):
                return start_t
        return None


class RealCellFaultTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_real_cell_faults")
        cls.figures = {}
        cls.planner = ActionClient(f"{NODE}/plan_measurement", PlanMeasurementAction)
        cls.executor = ActionClient(f"{NODE}/execute_plan", ExecutePlanAction)
        assert cls.planner.wait_for_server(rospy.Duration(60)), "no plan_measurement action"
        assert cls.executor.wait_for_server(rospy.Duration(10)), "no execute_plan action"
        for name in (f"{SIM}/set_program_running", f"{SIM}/protective_stop", f"{SIM}/unlock_protective_stop"):
            rospy.wait_for_service(name, timeout=30)
        rospy.wait_for_service("/ur_hardware_interface/set_speed_slider", timeout=30)
        cls.set_program_running = rospy.ServiceProxy(f"{SIM}/set_program_running", SetBool)
        cls.protective_stop = rospy.ServiceProxy(f"{SIM}/protective_stop", Trigger)
        cls.unlock = rospy.ServiceProxy(f"{SIM}/unlock_protective_stop", Trigger)
        cls.speed_slider = rospy.ServiceProxy("/ur_hardware_interface/set_speed_slider", SetSpeedSliderFraction)
        cls.report = rospy.ServiceProxy(f"{NODE}/get_coverage_report", GetCoverageReport)
        cls.program = []
        cls.program_sub = rospy.Subscriber(PROGRAM_RUNNING_TOPIC, Bool, lambda m: cls.program.append(m.data))
        cls.joints = _JointRecorder()

    @classmethod
    def tearDownClass(cls):
        figures_file = rospy.get_param("~figures_file", "")
        print(f"[real cell] figures: {cls.figures}")
        if figures_file:
            Path(figures_file).write_text(yaml.safe_dump(cls.figures, sort_keys=False))

    # ------------------------------------------------------------------------------------- helpers
    def _program_running(self, timeout_s: float = 5.0) -> None:
        """Make sure the UR program runs (start it when it does not)."""
        if not (self.program and self.program[-1]):
            self.unlock()  # a protective stop left by a failed test ("no protective stop to unlock" otherwise)
            reply = self.set_program_running(True)
            self.assertTrue(reply.success, reply.message)
        deadline = time.monotonic() + timeout_s
        while not (self.program and self.program[-1]) and time.monotonic() < deadline:
            time.sleep(0.05)
        self.assertTrue(self.program and self.program[-1], "the UR program does not run")

    def _execute(self, feedback=None, timeout_s=600.0):
        """The execute_plan result and its wall time; ``self.phases`` gets the wall time per phase (connect,
        measure: from a segment's feedback to the next one's, the last one to the result)."""
        started = time.monotonic()
        marks = []

        def on_feedback(fb):
            if not marks or marks[-1][1] != fb.segment:
                marks.append((time.monotonic(), fb.segment, fb.phase))
            if feedback is not None:
                feedback(fb)

        self.executor.send_goal(ExecutePlanGoal(plan_file=""), feedback_cb=on_feedback)
        self.assertTrue(self.executor.wait_for_result(rospy.Duration(timeout_s)), "execution timed out")
        ended = time.monotonic()
        self.phases = {"connect": 0.0, "measure": 0.0}
        for (t, _, phase), following in zip(marks, [*marks[1:], (ended, None, None)], strict=True):
            self.phases[phase] = round(self.phases.get(phase, 0.0) + following[0] - t, 2)
        return self.executor.get_state(), self.executor.get_result(), ended - started

    def _plan_source(self) -> str:
        reply = self.report("")
        self.assertTrue(reply.success, reply.message)
        return reply.message

    def _fault_during_measurement(self, name: str, inject, recover, expected_words):
        """Execute, inject the fault in the second measurement segment, check the stop and the reason, the plan kept;
        then recover (the next execution is the caller's)."""
        self._program_running()
        source = self._plan_source()
        fault = {}

        def feedback(fb):
            measuring = fb.phase == "measure"
            if measuring:
                fault["measure_seen"] = fault.get("measure_seen", 0) + 1
            if measuring and fault.get("measure_seen", 0) >= 2 and "at" not in fault:
                fault["segment"] = fb.segment
                # mid-segment: a thread, so that the feedback callback is not held
                threading.Timer(0.5, lambda: (fault.__setitem__("at", time.monotonic()), inject())).start()

        state, result, _ = self._execute(feedback)
        done = time.monotonic()
        self.assertIn("at", fault, f"the execution ended before the {name}")
        # the result can come before the robot has stood for the hold time: keep recording until it could have
        time.sleep(max(0.0, fault["at"] + STOP_WITHIN_S + STILL_HOLD_S - time.monotonic()))
        still = self.joints.stood_still_at(fault["at"])
        self.assertIsNotNone(still, "the robot did not stand still after the fault")
        stop_s, result_s = still - fault["at"], done - fault["at"]
        print(f"[real cell] {name} in segment {fault['segment']}: robot stood after {stop_s:.3f} s, "
              f"result after {result_s:.3f} s: {result.error}")  # fmt: skip
        self.assertEqual(state, GoalStatus.ABORTED)
        self.assertFalse(result.success)
        for word in expected_words:
            self.assertIn(word, result.error)
        self.assertLess(stop_s, STOP_WITHIN_S)
        self.assertEqual(self._plan_source(), source, "the plan was not kept")
        self.figures[name] = {
            "segment": int(fault["segment"]),
            "robot_stood_after_s": round(stop_s, 3),
            "result_after_s": round(result_s, 3),
            "error": result.error,
        }
        recover()
        self._program_running()

    def _speed_figures(self, fraction: float, name: str, duration: float, result) -> None:
        self.figures[f"speed_{float(fraction)}"] = {
            "duration_s": round(duration, 2),
            "phases_s": self.phases,
            "measured_coverage": result.measured_coverage,
        }
        self.figures[name]["next_execution_s"] = round(duration, 2)

    # ------------------------------------------------------------------------------------- tests
    def test_1_plan(self):
        self.planner.send_goal(quick_goal(solver_type="greedy"))
        self.assertTrue(self.planner.wait_for_result(rospy.Duration(300)), "planning timed out")
        state, result = self.planner.get_state(), self.planner.get_result()
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        self.figures["plan"] = {
            "views": int(result.number_of_views),
            "estimated_s": float(result.estimated_execution_time_s),
        }

    def test_2_program_stopped_mid_segment_then_the_full_plan(self):
        """The program stops; once it runs again the whole plan executes at 100 % (the reference of the slider)."""

        def stop():
            reply = self.set_program_running(False)
            self.assertTrue(reply.success, reply.message)

        self._fault_during_measurement("program_stopped", stop, lambda: None, ["robot program stopped"])
        state, result, duration = self._execute()
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        self.assertGreater(result.measured_coverage, 0.5)
        self._speed_figures(1.0, "program_stopped", duration, result)
        print(f"[real cell] 100 %: {duration:.2f} s, measured coverage {result.measured_coverage:.4f}")

    def test_3_protective_stop_mid_segment_then_the_speed_slider(self):
        """A protective stop; once unlocked and the program runs, the plan executes at the speed slider's fraction:
        it takes longer and measures the same coverage."""

        def stop():
            reply = self.protective_stop()
            self.assertTrue(reply.success, reply.message)

        def recover():
            reply = self.unlock()
            self.assertTrue(reply.success, reply.message)

        self._fault_during_measurement("protective_stop", stop, recover, ["PROTECTIVE_STOP", "robot program stopped"])
        fraction = float(rospy.get_param("~speed_slider", 0.5))
        reply = self.speed_slider(fraction)
        self.assertTrue(reply.success)
        try:
            state, result, duration = self._execute()
        finally:
            self.speed_slider(1.0)
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        self.assertIn("speed_1.0", self.figures, "no execution at 100 % to compare with")
        full = self.figures["speed_1.0"]
        print(f"[real cell] {fraction:.0%}: {duration:.2f} s (100 %: {full['duration_s']:.2f} s), "
              f"measured coverage {result.measured_coverage:.4f} (100 %: {full['measured_coverage']:.4f})")  # fmt: skip
        self._speed_figures(fraction, "protective_stop", duration, result)
        # the motion slows by the fraction; what happens between the segments (stitching, the scanner) does not
        self.assertGreater(duration, 0.6 / fraction * full["duration_s"])
        self.assertLess(abs(result.measured_coverage - full["measured_coverage"]), COVERAGE_TOLERANCE)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "real_cell_faults", RealCellFaultTest)
