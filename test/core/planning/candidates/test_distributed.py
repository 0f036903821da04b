"""Candidate evaluation on Dask: the same plan in process, on 1 and 2 local workers and on a cluster started with
the ``dask scheduler`` / ``dask worker`` commands; a killed worker's chunks are recomputed."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from agiprobot_measurement.planning.candidates import distributed
from agiprobot_measurement.planning.candidates.distributed import ClusterError, DaskEvaluator
from agiprobot_measurement.planning.candidates.streaming import StreamStats, evaluate_streaming
from agiprobot_measurement.planning.candidates.viewpoint import generate_viewpoint_poses
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.station import PACKAGE_ROOT

SCRIPT = PACKAGE_ROOT / "scripts" / "plan_measurement.py"
CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"
# tilt full: 27,000 candidates in several chunks, so two workers share the work
SMALL = ["--density", "0.005", "--orientations", "12", "--tilt", "full", "--solver", "IP_basic", "-q"]
DASK = Path(sys.executable).with_name("dask")


def plan_without_timing(path: Path):
    data = yaml.safe_load(path.read_text())
    head = dict(data[0])
    head.pop("Timestamp")
    head.pop("planning_time_s")
    return [head, *data[1:]]


def first_difference(a, b) -> str:
    """Where two plans (as loaded) differ first, for the failure message."""
    if len(a) != len(b):
        return f"{len(a)} vs {len(b)} entries"
    for index, (x, y) in enumerate(zip(a, b, strict=True)):
        if x != y:
            keys = [k for k in set(x) | set(y) if x.get(k) != y.get(k)] if isinstance(x, dict) else []
            return f"entry {index}, keys {keys}"
    return "none"


def plan(tmp_path, name, *extra):
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(CUBE), *SMALL, "-o", name, *extra],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return plan_without_timing(tmp_path / name)


def start(command, log):
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def stop(process):
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@pytest.mark.skipif(not DASK.exists(), reason="the dask command is installed with the pinned requirements")
def test_the_plan_is_the_same_in_process_on_local_workers_and_on_a_started_cluster(tmp_path):
    reference = plan(tmp_path, "in_process.yaml")
    assert len(reference) > 3  # metadata and segments
    for name, workers in (("one.yaml", "1"), ("two.yaml", "2")):
        other = plan(tmp_path, name, "--workers", workers)
        assert other == reference, first_difference(reference, other)

    scheduler_file = tmp_path / "scheduler.json"
    processes = []
    with open(tmp_path / "cluster.log", "w") as log:
        try:
            processes.append(
                start(
                    [str(DASK), "scheduler", "--scheduler-file", str(scheduler_file), "--port", "0", "--no-dashboard"],
                    log,
                )
            )
            deadline = time.monotonic() + 30
            while not scheduler_file.exists() and time.monotonic() < deadline:
                time.sleep(0.2)
            address = json.loads(scheduler_file.read_text())["address"]
            for _ in range(2):
                processes.append(
                    start(
                        [
                            str(DASK),
                            "worker",
                            "--scheduler-file",
                            str(scheduler_file),
                            "--nworkers",
                            "1",
                            "--nthreads",
                            "1",
                            "--no-dashboard",
                        ],
                        log,
                    )
                )
            other = plan(tmp_path, "cluster.yaml", "--scheduler", address)
            assert other == reference, first_difference(reference, other)
        finally:
            for process in reversed(processes):
                stop(process)
    log_text = (tmp_path / "cluster.log").read_text()
    assert log_text.count("Starting Worker") == 2, log_text[-2000:]


def _model_and_poses():
    import trimesh

    mesh = trimesh.load(CUBE)
    mesh.apply_translation(-mesh.bounds.mean(axis=0) + (650.0, 0.0, 250.0))
    points, faces = trimesh.sample.sample_surface_even(mesh, 600, seed=1)
    model = SensorModel.from_config()
    model.set_processing_context(mesh, points, faces)
    return model, generate_viewpoint_poses(points, mesh.face_normals[faces], 12, "full", model).poses


def test_a_killed_worker_has_its_chunks_recomputed(monkeypatch):
    import agiprobot_measurement.planning.candidates.streaming as streaming

    model, poses = _model_and_poses()
    reference, kept = evaluate_streaming(model, poses, 0.1, 500.0)
    monkeypatch.setattr(streaming, "CHUNK_TARGET_S", 1e-4)  # many small chunks: some are running when one dies
    with DaskEvaluator(workers=2) as evaluator:
        pids = evaluator.worker_pids()
        assert len(pids) == 2
        killed = []
        original = evaluator.evaluate

        def evaluate_and_kill(sensor_model, chunks, threshold, deflection, arrived, **options):
            def arrived_then_kill(index, block, columns, info):
                arrived(index, block, columns, info)
                if not killed:
                    victim = sorted(pids.values())[0]
                    os.kill(victim, signal.SIGKILL)
                    killed.append(victim)

            return original(sensor_model, chunks, threshold, deflection, arrived_then_kill, **options)

        monkeypatch.setattr(evaluator, "evaluate", evaluate_and_kill)
        stats = StreamStats()
        store, kept_there = evaluate_streaming(model, poses, 0.1, 500.0, executor=evaluator, stats=stats)
        assert killed and stats.chunks > 4
        assert killed[0] not in evaluator.worker_pids().values()
    np.testing.assert_array_equal(kept_there, kept)
    for name in ("indptr", "point_indices", "uncertainties", "trajectory_distances", "extent_min", "extent_max"):
        np.testing.assert_array_equal(getattr(store, name), getattr(reference, name))


def test_the_pilot_runs_on_the_workers_and_projects_what_it_projects_in_process():
    from agiprobot_measurement.planning.candidates.streaming import DOMINANCE_PILOT_SLICES, EvaluationSettings

    model, poses = _model_and_poses()
    settings = EvaluationSettings(drop_dominated=True)
    here = StreamStats()
    reference, kept = evaluate_streaming(model, poses, 0.1, 500.0, settings=settings, stats=here)
    # in process: the random spread in one piece, then the dominance slices
    assert len(here.pilot_spread_seconds) == 1 and len(here.pilot_dominance_seconds) == 2 * DOMINANCE_PILOT_SLICES
    with DaskEvaluator(workers=2) as evaluator:
        there = StreamStats()
        store, kept_there = evaluate_streaming(
            model, poses, 0.1, 500.0, settings=settings, executor=evaluator, stats=there
        )
    # on the cluster: the random spread split over the two workers, the slices as tasks of their own
    assert len(there.pilot_spread_seconds) == 2 and len(there.pilot_dominance_seconds) == 2 * DOMINANCE_PILOT_SLICES
    assert all(t > 0 for t in there.pilot_spread_seconds + there.pilot_dominance_seconds)
    assert there.projected_pairs == here.projected_pairs
    assert there.dominance_kept_share == here.dominance_kept_share
    assert there.scatter_s > 0
    np.testing.assert_array_equal(kept_there, kept)
    np.testing.assert_array_equal(store.point_indices, reference.point_indices)


def test_an_unreachable_scheduler_is_named(monkeypatch):
    import agiprobot_measurement.planning.candidates.distributed as distributed

    monkeypatch.setattr(distributed, "CONNECT_TIMEOUT_S", 2.0)
    with pytest.raises(ClusterError, match=r"tcp://127\.0\.0\.1:9"):
        DaskEvaluator(scheduler="tcp://127.0.0.1:9").client  # noqa: B018


def test_without_the_options_nothing_is_distributed():
    from agiprobot_measurement.planning.candidates.streaming import EvaluationSettings

    assert not EvaluationSettings().distributed
    assert EvaluationSettings(workers=2).distributed and EvaluationSettings(scheduler="tcp://h:1").distributed


def test_a_scheduler_address_that_accepts_but_never_answers_is_refused_in_bounded_time(monkeypatch):
    monkeypatch.setattr(distributed, "CONNECT_TIMEOUT_S", 1.0)
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(4)
    try:
        address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
        start = time.monotonic()
        with pytest.raises(ClusterError, match=r"does not speak Dask|cannot reach"):
            DaskEvaluator(scheduler=address).client  # noqa: B018
        assert time.monotonic() - start < 5.0
    finally:
        listener.close()
