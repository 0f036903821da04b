"""Probes of the ROS nodes: each starts its own ``roslaunch -p PORT`` (a private master on a free port, ``ROS_HOME``
in the scratch folder), waits for the node's interface, sends one hostile request through a small Python client
(a child process under the same watch as the CLI probes), and watches the node's resident memory meanwhile.

A row holds when the node refuses within the refusal bound (time at the client), its reply is at most
``max_message_chars`` long, its memory grows by at most the refusal bound's memory and it is still running.
The launch is stopped with SIGINT to its process group (SIGKILL after 20 s); nothing of it is left running.

- K22: calibration ``load_samples`` on a 63 MB data file of NUL bytes (under the size cap).
- N19: ``ReconstructObject`` with ``resolution_m`` 0.0009 and the default region of interest (30 M voxels, over the
  node's ``~max_voxels``), plan-only.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import psutil

from agiprobot_measurement.common.cli import start_process_group, stop_process_group

from . import inputs
from .judge import Expectation, Verdict, judge, run_watched

__all__ = ["NODE_PROBES", "NodeProbe"]

#: how long a launch may take to offer its interface
STARTUP_S = 120.0

_LOAD_SAMPLES = """
import json, sys, time, rospy
from std_srvs.srv import Trigger
rospy.init_node("fuzz_client", anonymous=True)
rospy.wait_for_service("/calibration/load_samples", 60)
start = time.perf_counter()
reply = rospy.ServiceProxy("/calibration/load_samples", Trigger)()
print(json.dumps({"seconds": time.perf_counter() - start, "success": reply.success, "chars": len(reply.message),
                  "message": reply.message[:300]}))
"""

_NBV_GOAL = """
import json, sys, time, rospy, actionlib
from agiprobot_measurement.msg import ReconstructObjectAction, ReconstructObjectGoal
rospy.init_node("fuzz_client", anonymous=True)
client = actionlib.SimpleActionClient("/nbv_reconstruction/reconstruct_object", ReconstructObjectAction)
client.wait_for_server(rospy.Duration(60))
start = time.perf_counter()
client.send_goal(ReconstructObjectGoal(resolution_m=0.0009, execute=False))
done = client.wait_for_result(rospy.Duration(float(sys.argv[1])))
seconds = time.perf_counter() - start
if not done:
    client.cancel_goal()
    print(json.dumps({"seconds": seconds, "success": None, "chars": 0, "message": "no result (cancelled)"}))
    sys.exit(0)
result = client.get_result()
print(json.dumps({"seconds": seconds, "success": result.success, "chars": len(result.error),
                  "message": (result.error or result.termination_reason)[:300], "state": client.get_state()}))
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _node_process(launch_pid: int, name: str) -> psutil.Process | None:
    try:
        for proc in psutil.Process(launch_pid).children(recursive=True):
            if any(arg == f"__name:={name}" for arg in proc.cmdline()):
                return proc
    except psutil.Error:
        return None
    return None


class _Watch(threading.Thread):
    """Samples one process's resident memory at 10 Hz until stopped."""

    def __init__(self, proc: psutil.Process):
        super().__init__(daemon=True)
        self.proc, self.peak_mb, self.alive, self.stopping = proc, 0.0, True, threading.Event()

    def sample(self) -> float:
        try:
            return self.proc.memory_info().rss / 2**20
        except psutil.Error:
            self.alive = False
            return 0.0

    def run(self):
        while not self.stopping.wait(0.1):
            self.peak_mb = max(self.peak_mb, self.sample())


@dataclass(frozen=True)
class NodeProbe:
    id: str
    tool: str
    what: str
    launch: str
    node: str
    ready: str  # a topic or service name that is there once the node serves
    client: str  # the client's Python code
    prepare: Callable[[Path], list[str]]  # the launch's arguments, after building the probe's inputs
    ends: str = "refuse"
    bound: str = "refusal"
    message: str = ""
    forbid: tuple[str, ...] = ()

    def run(self, folder: Path, timeout_s: float, expect: Expectation, conditions) -> dict:
        """Launch, probe, stop; the table row (``peak_mb``: the node's growth during the request)."""
        out = folder / "out" / self.id
        out.mkdir(parents=True, exist_ok=True)
        port = _free_port()
        env = dict(os.environ, ROS_MASTER_URI=f"http://127.0.0.1:{port}", ROS_HOME=str(folder / "roshome"))
        log = open(out / "roslaunch.log", "wb")
        launch = start_process_group(
            ["roslaunch", "-p", str(port), "agiprobot_measurement", self.launch, *self.prepare(out)],
            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
        )  # fmt: skip
        try:
            verdict, seconds, growth, exit_code = self._probe(launch.pid, env, expect, timeout_s, conditions)
        finally:
            stop_process_group(launch, timeout_s=20.0)
            log.close()
        return {
            "id": self.id, "entry": self.tool, "input": self.what,
            "expected": f"{self.ends} <= {expect.seconds:g} s, +{expect.memory_mb:g} MB",
            "result": verdict.label, "seconds": round(seconds, 2), "cpu_s": None, "peak_mb": round(growth),
            "exit": exit_code, "reason": verdict.reason,
        }  # fmt: skip

    def _probe(self, launch_pid, env, expect, timeout_s, conditions) -> tuple[Verdict, float, float, str | None]:
        started = time.perf_counter()
        node = None
        while time.perf_counter() - started < STARTUP_S:
            node = node or _node_process(launch_pid, self.node)
            listed = subprocess.run(
                ["rosservice" if "/" in self.ready and not self.ready.endswith("status") else "rostopic", "list"],
                capture_output=True, text=True, env=env, check=False,
            )  # fmt: skip
            if node and self.ready in listed.stdout.split():
                break
            time.sleep(1.0)
        else:
            return Verdict(False, f"the launch offered no {self.ready} within {STARTUP_S:g} s"), 0.0, 0.0, None
        time.sleep(2.0)  # let the node settle
        watch = _Watch(node)
        baseline = watch.sample()
        watch.start()
        kill_after = min(timeout_s, conditions.number("kill_factor", 1) * expect.seconds + 20.0)
        outcome = run_watched(
            [sys.executable, "-c", self.client, str(kill_after - 10.0)], kill_after,
            conditions.number("memory_cap_mb", 1), env=env,
        )  # fmt: skip
        watch.stopping.set()
        watch.join()
        growth = max(0.0, watch.peak_mb - baseline)
        lines = [x for x in outcome.result.stdout.splitlines() if x.startswith("{")]
        if outcome.killed == "time":
            reason = f"no answer within {outcome.result.seconds:.0f} s (bound {expect.seconds:g} s)"
            return Verdict(False, reason), outcome.result.seconds, growth, None
        if outcome.result.returncode != 0 or not lines:
            return judge(outcome, Expectation("succeed", kill_after, 1e9)), outcome.result.seconds, growth, None
        reply = json.loads(lines[-1])
        seconds = reply["seconds"]
        if not watch.alive:
            verdict = Verdict(False, "the node died")
        elif reply["success"] is None:
            verdict = Verdict(False, f"no result within {seconds:.0f} s (bound {expect.seconds:g} s)")
        elif reply["success"] and self.ends == "refuse":
            verdict = Verdict(False, f"accepted where a refusal was expected: {reply['message'][:80]}")
        elif reply["chars"] > expect.max_message_chars:
            verdict = Verdict(False, f"reply of {reply['chars']:,} characters")
        elif seconds > expect.seconds:
            verdict = Verdict(False, f"answered after {seconds:.1f} s (bound {expect.seconds:g} s)")
        elif growth > expect.memory_mb:
            verdict = Verdict(False, f"node grew by {growth:.0f} MB (bound {expect.memory_mb:g} MB)")
        else:
            verdict = Verdict(True, reply["message"][:90])
        return verdict, seconds, growth, {None: "-", True: "success", False: "failure"}[reply["success"]]


def _calibration_nul_file(out: Path) -> list[str]:
    folder = out / "calnode"
    folder.mkdir(exist_ok=True)
    (folder / "calibration_data.txt").unlink(missing_ok=True)
    inputs.make(folder, "sparse_63M.txt").rename(folder / "calibration_data.txt")
    return [f"output_dir:={folder}"]


def _nbv(out: Path) -> list[str]:
    (out / "nbv_out").mkdir(exist_ok=True)
    return [f"output_dir:={out / 'nbv_out'}", "pixel_step:=4"]


NODE_PROBES: tuple[NodeProbe, ...] = (
    NodeProbe(
        "K22",
        "calibration load_samples",
        "63 MB data file of NUL bytes",
        "calibration.launch",
        "calibration",
        "/calibration/load_samples",
        _LOAD_SAMPLES,
        _calibration_nul_file,
    ),
    NodeProbe(
        "N19",
        "nbv ReconstructObject",
        "resolution_m 0.0009, default ROI (30 M voxels)",
        "nbv.launch",
        "nbv_reconstruction",
        "/nbv_reconstruction/reconstruct_object/status",
        _NBV_GOAL,
        _nbv,
    ),
)
