"""Streaming candidate evaluation: compact store, independence of chunking and culling, the memory budget."""

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.planning.request import PlanRequest, PlanRequestError, WorkTooLarge
from agiprobot_measurement.planning.streaming import (
    EvaluationSettings,
    StreamStats,
    chunk_block,
    evaluate_in_chunks,
    evaluate_streaming,
)
from agiprobot_measurement.planning.viewpoint import generate_viewpoint_poses
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


@pytest.fixture(scope="module")
def pocket_part():
    """A plate with a pocket and a rib (occlusion matters), sampled, and its candidate poses (tilt full)."""
    plate = trimesh.creation.box((260.0, 180.0, 30.0))
    pocket = trimesh.creation.box((120.0, 80.0, 20.0))
    pocket.apply_translation((0.0, 0.0, 6.0))
    rib = trimesh.creation.box((10.0, 80.0, 14.0))
    rib.apply_translation((0.0, 0.0, 2.0))
    mesh = (
        trimesh.boolean.difference([plate, pocket], check_volume=False) if trimesh.boolean.engines_available else None
    )
    if mesh is None:
        mesh = trimesh.util.concatenate([plate, rib])
    else:
        mesh = trimesh.util.concatenate([mesh, rib])
    mesh.apply_translation((600.0, 0.0, 300.0))
    model = SensorModel.from_config()
    points, faces = trimesh.sample.sample_surface_even(mesh, 900, seed=3)
    up = mesh.face_normals[faces][:, 2] > -0.3
    points, faces = points[up], faces[up]
    model.set_processing_context(mesh, points, faces)
    poses = generate_viewpoint_poses(points, mesh.face_normals[faces], 6, "full", model).poses
    return model, poses[::3]


def test_culled_and_dense_evaluations_are_identical(pocket_part):
    model, poses = pocket_part
    dense = model.evaluate_viewpoints_batch(poses, 0.1, 500.0, spatial_cull=False)
    culled = model.evaluate_viewpoints_batch(poses, 0.1, 500.0, spatial_cull=True, chunk_elements=1 << 14)
    assert dense.nnz > 10_000
    for name in ("indptr", "point_indices", "uncertainties", "trajectory_distances"):
        np.testing.assert_array_equal(getattr(dense, name), getattr(culled, name))


def test_stream_is_compact_exact_in_extents_and_independent_of_chunking(pocket_part, monkeypatch):
    model, poses = pocket_part
    full = model.evaluate_viewpoints_batch(poses, 0.1, 500.0)
    stats = StreamStats()
    store, kept = evaluate_streaming(model, poses, 0.1, 500.0, stats=stats, settings=EvaluationSettings(compact=True))
    np.testing.assert_array_equal(kept, np.flatnonzero(full.counts > 0))
    assert store.point_indices.dtype == np.int32
    assert store.uncertainties.dtype == np.float32 and store.trajectory_distances.dtype == np.float64
    # the extents and t0s are the exact float64 ones; the uncertainties float32 roundings of the exact values
    np.testing.assert_array_equal(store.t0_min, full.t0_min[kept])
    np.testing.assert_array_equal(store.t0_max, full.t0_max[kept])
    np.testing.assert_array_equal(store.uncertainties, full.uncertainties.astype(np.float32))
    np.testing.assert_array_equal(store.trajectory_distances, full.trajectory_distances)
    assert stats.kept_pairs == full.nnz and stats.kept_views == kept.size
    # the pilot's projection is close to what was kept
    assert stats.projected_pairs == pytest.approx(full.nnz, rel=0.25)
    # other chunk sizes give the same bytes
    import agiprobot_measurement.planning.streaming as streaming

    monkeypatch.setattr(streaming, "MIN_CHUNK_VIEWS", 1)
    monkeypatch.setattr(streaming, "CHUNK_TARGET_S", 1e-6)
    small = StreamStats()
    again, kept_again = evaluate_streaming(
        model, poses, 0.1, 500.0, stats=small, settings=EvaluationSettings(compact=True)
    )
    assert small.chunks > stats.chunks
    np.testing.assert_array_equal(kept_again, kept)
    for name in ("indptr", "point_indices", "uncertainties", "trajectory_distances", "extent_min", "extent_max"):
        np.testing.assert_array_equal(getattr(again, name), getattr(store, name))
    # the default keeps float64: the exact values
    exact, _ = evaluate_streaming(model, poses, 0.1, 500.0)
    assert exact.uncertainties.dtype == np.float64
    np.testing.assert_array_equal(exact.uncertainties, full.uncertainties)
    # the former API keeps every column, empty ones included
    old = evaluate_in_chunks(model, poses, 0.1, 500.0)
    assert old.n_views == len(poses)
    np.testing.assert_array_equal(old.counts, full.counts)


def test_a_chunk_block_drops_empty_columns_only(pocket_part):
    model, poses = pocket_part
    block, columns, wall_s = chunk_block(model, poses[:500], 0.1, 500.0, compact=False)
    full = model.evaluate_viewpoints_batch(poses[:500], 0.1, 500.0)
    np.testing.assert_array_equal(columns, np.flatnonzero(full.counts > 0))
    np.testing.assert_array_equal(block.uncertainties, full.uncertainties)
    assert wall_s > 0


def test_work_beyond_the_budget_is_refused_with_the_estimate(pocket_part):
    model, poses = pocket_part
    with pytest.raises(WorkTooLarge, match=r"pilot of \d+ of the [\d,]+ candidates") as info:
        evaluate_streaming(model, poses, 0.1, 500.0, settings=EvaluationSettings(max_memory_bytes=1e6))
    assert "0.00 GB" in str(info.value) and "--max-memory" in str(info.value)


def test_the_sensor_model_travels_and_rebuilds_its_ray_tracer(pocket_part):
    import pickle

    model, poses = pocket_part
    copy = pickle.loads(pickle.dumps(model))
    a = model.evaluate_viewpoints_batch(poses[:300], 0.1, 500.0)
    b = copy.evaluate_viewpoints_batch(poses[:300], 0.1, 500.0)
    np.testing.assert_array_equal(a.point_indices, b.point_indices)
    np.testing.assert_array_equal(a.uncertainties, b.uncertainties)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("workers", -1, "workers must be a whole number"),
        ("workers", 1.5, "workers must be a whole number"),
        ("scheduler", "localhost", "Dask scheduler address"),
        ("scheduler", "tcp://host:port", "Dask scheduler address"),
        ("max_memory_gb", float("nan"), "max_memory_gb must be a number of GB"),
        ("max_memory_gb", -2, "max_memory_gb must be a number of GB"),
    ],
)
def test_request_checks_the_distribution_fields(field, value, message):
    request = dataclasses.replace(PlanRequest(part_file=str(CUBE)), **{field: value})
    with pytest.raises(PlanRequestError, match=message) as info:
        request.validate()
    assert info.value.field == field


def test_request_accepts_the_distribution_fields():
    request = dataclasses.replace(
        PlanRequest(part_file=str(CUBE)), workers=2, scheduler=" tcp://10.0.0.5:8786 ", max_memory_gb=4
    ).validate()
    assert (request.workers, request.scheduler, request.max_memory_gb) == (2, "tcp://10.0.0.5:8786", 4.0)


def test_cli_refuses_work_beyond_max_memory(tmp_path):
    done = subprocess.run(
        [
            sys.executable,
            str(PACKAGE_ROOT / "scripts" / "plan_measurement.py"),
            str(CUBE),
            "--tilt",
            "full",
            "--max-memory",
            "0.01",
            "-q",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    assert "request refused before the evaluation" in done.stderr and "0.01 GB" in done.stderr
    assert not list(tmp_path.iterdir())
