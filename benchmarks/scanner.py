"""The stitched cloud's accuracy against the part under scanner latency: the simulated scanCONTROL driver stamps
each profile ``latency`` after its exposure (as a real driver stamping on receipt does), the stitcher subtracts
``compensation`` and looks the sensor pose up in tf at the result; the error is each stitched point's distance to
the part's mesh surface (mm).

    python -m benchmarks.scanner                        # 0 ms; 5 ms uncompensated; 5 ms compensated by 5 ms
    python -m benchmarks.scanner --conditions 0:0 0.010:0 --part parts/objectB_zylinder.stl --placement fixture

Each condition runs the whole measurement stack (``measurement.launch scanner_latency_s:=... latency_compensation_s:=...``)
on a private master and executes the same plan (planned once, in the first condition) through the trajectory_manager;
the stitched cloud is the stitcher's whole cloud (``/laser_scanner/measured_cloud``). A latency shifts the points
along the scan (speed x latency: 0.25 mm at 50 mm/s and 5 ms); on a flat face that shift stays in the face, so the
surface distance sees it where the cloud reaches past an edge of the part (the largest distances) and on curved
surfaces. By default the scanner has no noise (``--noise-scale 0``), so what remains is the stitching's own error.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.cli import start_process_group, stop_process_group
from agiprobot_measurement.planning.part_loading import load_part
from agiprobot_measurement.planning.plan.execution import plan_part
from agiprobot_measurement.planning.plan.plan_io import load_execution_plan
from agiprobot_measurement.station import PACKAGE_ROOT

#: (scanner latency s, stitcher compensation s): none; 5 ms uncompensated; 5 ms compensated
DEFAULT_CONDITIONS = ("0:0", "0.005:0", "0.005:0.005")
#: how long the stack may take to come up (s)
STARTUP_S = 120.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def surface_distances_mm(points_mm: np.ndarray, part_mesh, count: int, seed: int) -> np.ndarray:
    """Distances (mm) of up to ``count`` of the points (a seeded sample) to the mesh surface."""
    rng = np.random.default_rng(seed)
    if len(points_mm) > count:
        points_mm = points_mm[rng.choice(len(points_mm), count, replace=False)]
    _, distance, _ = part_mesh.nearest.on_surface(points_mm)
    return np.asarray(distance)


def run_condition(latency_s: float, compensation_s: float, args, plan_file: Path, out: Path) -> dict:
    """One stack with this latency and compensation: plan (when ``plan_file`` does not exist yet), execute, and
    return the stitched cloud's figures."""
    os.environ["ROS_MASTER_URI"] = f"http://127.0.0.1:{free_port()}"
    log_path = out / f"launch_{latency_s:g}_{compensation_s:g}.log"
    command = [
        "roslaunch",
        "agiprobot_measurement",
        "measurement.launch",
        f"scanner_latency_s:={latency_s}",
        f"latency_compensation_s:={compensation_s}",
        f"allowed_plan_dirs:={out}",
        f"seed:={args.seed}",
        f"scanner_noise_scale:={args.noise_scale}",
    ]
    with log_path.open("w") as log:
        launch = start_process_group(command, stdout=log, stderr=subprocess.STDOUT)
        try:
            return _measure(latency_s, compensation_s, args, plan_file, launch)
        finally:
            stop_process_group(launch)


def _measure(latency_s, compensation_s, args, plan_file: Path, launch) -> dict:
    import rosgraph
    import rospy
    from actionlib_msgs.msg import GoalStatus
    from sensor_msgs.msg import PointCloud2
    from std_srvs.srv import Trigger

    from agiprobot_measurement.msg import ExecutePlanAction, ExecutePlanGoal, PlanMeasurementAction, PlanMeasurementGoal
    from agiprobot_measurement.ros.action_client import ActionClient
    from agiprobot_measurement.ros.conversions import cloud_xyz

    deadline = time.monotonic() + STARTUP_S
    while not rosgraph.is_master_online():
        if launch.poll() is not None or time.monotonic() > deadline:
            raise SystemExit("the launch file exited or the master did not come up")
        time.sleep(0.2)
    rospy.init_node("scanner_benchmark", anonymous=True, disable_signals=True)
    planner = ActionClient("/trajectory_manager/plan_measurement", PlanMeasurementAction)
    executor = ActionClient("/trajectory_manager/execute_plan", ExecutePlanAction)
    if not (planner.wait_for_server(rospy.Duration(STARTUP_S)) and executor.wait_for_server(rospy.Duration(30))):
        raise SystemExit("the trajectory_manager did not come up")
    plan_s = 0.0
    execute_file = str(plan_file)
    if not plan_file.exists():
        started = time.monotonic()
        part = Path(args.part)
        planner.send_goal(
            PlanMeasurementGoal(
                part_file=str(part if part.is_absolute() else (PACKAGE_ROOT / part).resolve()),
                units=args.units,
                sampling_density=args.density,
                orientations_around_boresight=args.orientations,
                viewpoint_tilt_mode="none",
                solver_type="IP_basic",
                plan_file=str(plan_file),
                overwrite=True,
                placement=args.placement,
            )
        )
        planner.wait_for_result()
        if planner.get_state() != GoalStatus.SUCCEEDED:
            raise SystemExit(f"planning failed: {planner.get_result().error}")
        plan_s = time.monotonic() - started
        execute_file = ""  # the node's own plan: it reports the measured coverage of its samples
    started = time.monotonic()
    executor.send_goal(ExecutePlanGoal(plan_file=execute_file))
    executor.wait_for_result()
    result = executor.get_result()
    if executor.get_state() != GoalStatus.SUCCEEDED:
        raise SystemExit(f"execution failed: {result.error if result else 'no result'}")
    execute_s = time.monotonic() - started
    received = {}
    rospy.Subscriber("/laser_scanner/measured_cloud", PointCloud2, lambda m: received.setdefault("cloud", m))
    time.sleep(1.0)
    received.clear()
    rospy.ServiceProxy("/laser_scanner/publish_measured_cloud", Trigger)()
    wait_until = time.monotonic() + 30
    while "cloud" not in received and time.monotonic() < wait_until:
        time.sleep(0.05)
    points_mm = cloud_xyz(received["cloud"]) * 1000.0
    rospy.signal_shutdown("condition done")
    part = plan_part(load_execution_plan(plan_file))
    mesh = load_part(part.mesh_file, units=part.units, transform=part.file_units_placement, remove_downside=False).mesh
    distance = surface_distances_mm(points_mm, mesh, args.sample_points, args.seed)
    return {
        "latency_ms": 1000.0 * latency_s,
        "compensation_ms": 1000.0 * compensation_s,
        "points": len(points_mm),
        "measured_coverage": float(result.measured_coverage),
        "mean_mm": float(np.mean(distance)),
        "p95_mm": float(np.percentile(distance, 95)),
        "p999_mm": float(np.percentile(distance, 99.9)),
        "max_mm": float(np.max(distance)),
        "plan_s": plan_s,
        "execute_s": execute_s,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--conditions", nargs="+", default=list(DEFAULT_CONDITIONS), help="latency_s:compensation_s")
    parser.add_argument("--part", default="parts/objectA_wuerfel.stl")
    parser.add_argument("--units", default="mm")
    parser.add_argument("--placement", default="scene", help="scene (the scene's part pose) or fixture (on top of it)")
    parser.add_argument("--density", type=float, default=0.03, help="sampling density (points per mm^2)")
    parser.add_argument("--orientations", type=int, default=12)
    parser.add_argument("--sample-points", type=int, default=200000, help="stitched points compared with the mesh")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--noise-scale", type=float, default=0.0, help="the scanner's noise (0: none, so only stitching errs)"
    )
    parser.add_argument("--output-dir", default="", help="plan and launch logs (default: a temporary folder)")
    parser.add_argument("--json", default="", help="write the figures here too")
    args = parser.parse_args(argv)
    out = Path(args.output_dir or tempfile.mkdtemp(prefix="scanner_bench_")).resolve()
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"part {args.part}; scanner noise scale {args.noise_scale:g}; plan and logs in {out}", flush=True)
    print(
        f"{'latency ms':>10} {'comp. ms':>9} {'points':>9} {'coverage':>9} {'mean mm':>8} {'95% mm':>8} "
        f"{'99.9% mm':>9} {'max mm':>8} {'exec s':>7}",
        flush=True,
    )
    for condition in args.conditions:
        # each condition in a fresh process: rospy allows one node per process
        completed = subprocess.run(
            [sys.executable, "-m", "benchmarks.scanner", "--_one", condition, *sys_args(args, out)],
            capture_output=True,
            text=True,
            cwd=PACKAGE_ROOT,
        )
        if completed.returncode != 0:
            print(completed.stdout[-2000:], completed.stderr[-4000:], file=sys.stderr)
            return 1
        row = json.loads(completed.stdout.strip().splitlines()[-1])
        rows.append(row)
        print(
            f"{row['latency_ms']:>10.1f} {row['compensation_ms']:>9.1f} {row['points']:>9d} "
            f"{coverage_text(row['measured_coverage']):>9} {row['mean_mm']:>8.4f} {row['p95_mm']:>8.4f} "
            f"{row['p999_mm']:>9.4f} {row['max_mm']:>8.4f} {row['execute_s']:>7.1f}",
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps({"part": args.part, "conditions": rows}, indent=2))
    return 0


def coverage_text(coverage: float) -> str:
    """The measured coverage in percent; n/a where the node has no samples (a plan executed from its file)."""
    return f"{100 * coverage:.1f}%" if coverage >= 0 else "n/a"


def sys_args(args, out: Path) -> list[str]:
    return [
        "--part",
        args.part,
        "--units",
        args.units,
        "--placement",
        args.placement,
        "--density",
        str(args.density),
        "--orientations",
        str(args.orientations),
        "--sample-points",
        str(args.sample_points),
        "--seed",
        str(args.seed),
        "--noise-scale",
        str(args.noise_scale),
        "--output-dir",
        str(out),
    ]


def one(argv) -> int:
    """The child process of one condition: prints its figures as one JSON line."""
    parser = argparse.ArgumentParser()
    parser.add_argument("--_one", dest="condition")
    parser.add_argument("--part")
    parser.add_argument("--units")
    parser.add_argument("--placement")
    parser.add_argument("--density", type=float)
    parser.add_argument("--orientations", type=int)
    parser.add_argument("--sample-points", type=int)
    parser.add_argument("--seed", type=int)
    parser.add_argument("--noise-scale", type=float)
    parser.add_argument("--output-dir")
    args = parser.parse_args(argv)
    latency_s, compensation_s = (float(v) for v in args.condition.split(":"))
    out = Path(args.output_dir)
    row = run_condition(latency_s, compensation_s, args, out / "scanner_bench_plan.yaml", out)
    print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    if "--_one" in sys.argv:
        sys.exit(one(sys.argv[1:]))
    sys.exit(main())
