"""Streaming candidate evaluation: compact store, independence of chunking and culling, the memory budget."""

import dataclasses
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.planning.candidates.streaming import (
    HUGE_PAGE_MIN_BYTES,
    EvaluationSettings,
    StreamStats,
    _empty_huge_paged,
    chunk_block,
    dominated_columns,
    evaluate_in_chunks,
    evaluate_streaming,
    redundant_columns_kept,
)
from agiprobot_measurement.planning.candidates.viewpoint import generate_viewpoint_poses
from agiprobot_measurement.planning.request import PlanRequest, PlanRequestError, WorkTooLarge
from agiprobot_measurement.sensors.laser_line.model import MeasurabilityResult, SensorModel
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


def test_stream_is_compact_consistent_in_extents_and_independent_of_chunking(pocket_part, monkeypatch):
    model, poses = pocket_part
    full = model.evaluate_viewpoints_batch(poses, 0.1, 500.0)
    stats = StreamStats()
    store, kept = evaluate_streaming(model, poses, 0.1, 500.0, stats=stats, settings=EvaluationSettings(compact=True))
    np.testing.assert_array_equal(kept, np.flatnonzero(full.counts > 0))
    assert stats.compact and not stats.drop_dominated
    assert store.point_indices.dtype == np.int32
    assert store.uncertainties.dtype == np.float32 and store.trajectory_distances.dtype == np.float32
    # float32 roundings of the exact values, and each column's t0 range is that of the stored t0s (the scan line's
    # ends and the partial acceptance then compare the same numbers)
    np.testing.assert_array_equal(store.uncertainties, full.uncertainties.astype(np.float32))
    np.testing.assert_array_equal(store.trajectory_distances, full.trajectory_distances.astype(np.float32))
    starts = store.indptr[:-1]
    np.testing.assert_array_equal(store.t0_min, np.minimum.reduceat(store.trajectory_distances, starts))
    np.testing.assert_array_equal(store.t0_max, np.maximum.reduceat(store.trajectory_distances, starts))
    assert store.t0_min.dtype == np.float64
    np.testing.assert_allclose(store.t0_min, full.t0_min[kept], atol=1e-4)
    assert stats.kept_pairs == full.nnz and stats.kept_views == kept.size
    # the pilot's projection is close to what was kept
    assert stats.projected_pairs == pytest.approx(full.nnz, rel=0.25)
    # other chunk sizes give the same bytes
    import agiprobot_measurement.planning.candidates.streaming as streaming

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
    # a store in huge-page mappings (as large ones are) holds the same bytes
    monkeypatch.setattr(streaming, "HUGE_PAGE_MIN_BYTES", 1)
    mapped, _ = evaluate_streaming(model, poses, 0.1, 500.0, settings=EvaluationSettings(compact=True))
    for name in ("indptr", "point_indices", "uncertainties", "trajectory_distances"):
        np.testing.assert_array_equal(getattr(mapped, name), getattr(store, name))
    # a store this small keeps float64 by default: the exact values
    exact, _ = evaluate_streaming(model, poses, 0.1, 500.0, stats=small)
    assert not small.compact and exact.uncertainties.dtype == np.float64
    np.testing.assert_array_equal(exact.uncertainties, full.uncertainties)
    np.testing.assert_array_equal(exact.t0_min, full.t0_min[kept])
    # ... and the compact types above COMPACT_ABOVE_PAIRS projected pairs, decided by the projection alone
    monkeypatch.setattr(streaming, "COMPACT_ABOVE_PAIRS", 0.5 * full.nnz)
    auto, _ = evaluate_streaming(model, poses, 0.1, 500.0, stats=small)
    assert small.compact and auto.trajectory_distances.dtype == np.float32
    # the former API keeps every column, empty ones included
    old = evaluate_in_chunks(model, poses, 0.1, 500.0)
    assert old.n_views == len(poses)
    np.testing.assert_array_equal(old.counts, full.counts)


def test_large_store_arrays_are_writeable_huge_page_mappings_and_small_ones_ordinary():
    large = _empty_huge_paged(HUGE_PAGE_MIN_BYTES // 4, np.float32)
    assert large.dtype == np.float32 and large.size == HUGE_PAGE_MIN_BYTES // 4
    assert isinstance(large.base, memoryview)  # of the anonymous mapping
    large[-3:] = (1.0, 2.0, 3.0)
    assert large[-3:].tolist() == [1.0, 2.0, 3.0]
    small = _empty_huge_paged(1000, np.int32)
    assert small.base is None and small.dtype == np.int32 and small.size == 1000


def test_a_chunk_block_drops_empty_columns_only(pocket_part):
    model, poses = pocket_part
    block, columns, info = chunk_block(model, poses[:500], 0.1, 500.0, compact=False)
    full = model.evaluate_viewpoints_batch(poses[:500], 0.1, 500.0)
    np.testing.assert_array_equal(columns, np.flatnonzero(full.counts > 0))
    np.testing.assert_array_equal(block.uncertainties, full.uncertainties)
    assert info["wall_s"] > 0 and info["cpu_s"] > 0 and info["dropped"].size == 0


def _point_sets(result):
    return [set(result.point_indices[result.indptr[j] : result.indptr[j + 1]].tolist()) for j in range(result.n_views)]


def test_dominated_columns_are_exactly_the_subsets_and_their_dominators_are_kept():
    # columns: {0,1,2}, {0,1} (in 0), {3}, {0,1,2} (equal to 0: the first stays), {2,3} , {3} (equal to 2, in 4)
    sets = [[0, 1, 2], [0, 1], [3], [0, 1, 2], [2, 3], [3]]
    indptr = np.cumsum([0] + [len(c) for c in sets])
    ids = np.concatenate(sets).astype(np.int32)
    result = MeasurabilityResult(5, len(sets), indptr, ids, np.ones(ids.size), np.zeros(ids.size))
    np.testing.assert_array_equal(dominated_columns(result), [-1, 0, 4, 0, -1, 4])


def test_a_redundant_cover_keeps_every_point_measured_k_times_where_it_can(pocket_part):
    model, poses = pocket_part
    block, _, _ = chunk_block(model, poses[:600], 0.1, 500.0)
    total = np.bincount(block.point_indices, minlength=block.n_points)
    for k in (1, 3):
        keep = redundant_columns_kept(block, k)
        assert 0 < keep.sum() < block.n_views
        entries = np.concatenate(
            [block.point_indices[block.indptr[j] : block.indptr[j + 1]] for j in np.flatnonzero(keep)]
        )
        np.testing.assert_array_equal(np.bincount(entries, minlength=block.n_points) >= np.minimum(total, k), True)
    reduced, _, info = chunk_block(model, poses[:600], 0.1, 500.0, drop_dominated=True, redundancy=3)
    assert (info["dominator"] == -1).any() and reduced.n_views < block.n_views
    assert np.array_equal(np.unique(reduced.point_indices), np.unique(block.point_indices))


def test_dropping_dominated_candidates_keeps_the_coverage_and_a_reserve(pocket_part, monkeypatch):
    model, poses = pocket_part
    plain, kept = evaluate_streaming(model, poses, 0.1, 500.0, settings=EvaluationSettings(drop_dominated=False))
    stats = StreamStats()
    settings = EvaluationSettings(drop_dominated=True, redundancy=0)
    dropped, kept_dropped = evaluate_streaming(model, poses, 0.1, 500.0, settings=settings, stats=stats)
    assert stats.drop_dominated and 0 < stats.dropped_views < plain.n_views
    assert kept_dropped.size + stats.dropped_views == kept.size
    np.testing.assert_array_equal(np.sort(np.concatenate([kept_dropped, stats.reserve_index])), kept)
    assert stats.dropped_pairs + dropped.nnz == plain.nnz
    assert 0 < stats.dominance_kept_share < 1
    # every dropped candidate's points are all measured by its (kept) dominator; the kept columns are unchanged
    plain_sets = dict(zip(kept.tolist(), _point_sets(plain), strict=True))
    kept_sets = dict(zip(kept_dropped.tolist(), _point_sets(dropped), strict=True))
    for index, by in zip(stats.reserve_index.tolist(), stats.reserve_dominator.tolist(), strict=True):
        assert by in kept_sets and plain_sets[index] <= kept_sets[by]
    for index, points in kept_sets.items():
        assert points == plain_sets[index]
    # the same points stay coverable
    np.testing.assert_array_equal(np.unique(dropped.point_indices), np.unique(plain.point_indices))
    # the reduction works on fixed groups of candidates: other chunk sizes keep the same columns
    import agiprobot_measurement.planning.candidates.streaming as streaming

    monkeypatch.setattr(streaming, "REDUCTION_GROUP_VIEWS", 512)
    reference, reference_kept = evaluate_streaming(model, poses, 0.1, 500.0, settings=settings)
    monkeypatch.setattr(streaming, "CHUNK_TARGET_S", 1e-6)
    small = StreamStats()
    again, again_kept = evaluate_streaming(model, poses, 0.1, 500.0, settings=settings, stats=small)
    assert small.chunks > 4 and small.chunk_views % 512 == 0
    np.testing.assert_array_equal(again_kept, reference_kept)
    np.testing.assert_array_equal(again.point_indices, reference.point_indices)
    # by default nothing is dropped when the store fits the budget
    auto = StreamStats()
    evaluate_streaming(model, poses, 0.1, 500.0, stats=auto)
    assert not auto.drop_dominated and auto.dropped_views == 0


def test_a_deadline_too_near_for_every_candidate_evaluates_a_spread_of_them(pocket_part, monkeypatch):
    import agiprobot_measurement.planning.candidates.streaming as streaming
    import agiprobot_measurement.planning.candidates.time_fit as time_fit

    model, poses = pocket_part
    plain, kept = evaluate_streaming(model, poses, 0.1, 500.0, settings=EvaluationSettings(drop_dominated=False))
    everything = StreamStats()
    far = time.perf_counter() + 3600.0
    _, far_kept = evaluate_streaming(model, poses, 0.1, 500.0, stats=everything, deadline_s=far)
    assert not everything.time_limited and everything.evaluated == len(poses)
    np.testing.assert_array_equal(far_kept, kept)
    # a deadline already past: the minimum spread, over the whole candidate range, in the caller's indices
    monkeypatch.setattr(time_fit, "MIN_FITTING_VIEWS", len(poses) // 4)
    stats = StreamStats()
    some, some_kept = evaluate_streaming(
        model, poses, 0.1, 500.0, stats=stats, settings=EvaluationSettings(drop_dominated=False),
        deadline_s=time.perf_counter() - 1.0,
    )  # fmt: skip
    assert stats.time_limited == "projected" and stats.evaluated == len(poses) // 4 == stats.candidates // 4
    assert np.all(np.diff(some_kept) > 0) and set(some_kept.tolist()) <= set(kept.tolist())
    assert some_kept.min() < len(poses) // 4 and some_kept.max() > 3 * len(poses) // 4  # spread, not the first
    plain_sets = dict(zip(kept.tolist(), _point_sets(plain), strict=True))
    for index, points in zip(some_kept.tolist(), _point_sets(some), strict=True):
        assert points == plain_sets[index]
    # a projection that was too hopeful: the chunks done when the deadline came are kept, the rest skipped
    monkeypatch.setattr(time_fit, "fitting_subset", lambda *args: None)
    monkeypatch.setattr(time_fit, "MIN_FITTING_VIEWS", 0)
    monkeypatch.setattr(streaming, "CHUNK_TARGET_S", 1e-6)
    stopped = StreamStats()
    first, first_kept = evaluate_streaming(
        model, poses, 0.1, 500.0, stats=stopped, settings=EvaluationSettings(drop_dominated=False),
        deadline_s=time.perf_counter() - 1.0,
    )  # fmt: skip
    assert stopped.time_limited == "stopped" and stopped.chunks > 1 and stopped.evaluated == stopped.chunk_views
    np.testing.assert_array_equal(first_kept, kept[kept < stopped.chunk_views])
    assert first.n_views == first_kept.size


def test_the_budget_turns_dropping_on_before_it_refuses(pocket_part):
    model, poses = pocket_part
    probe = StreamStats()
    evaluate_streaming(model, poses, 0.1, 500.0, stats=probe, settings=EvaluationSettings(store_headroom=1.0))
    # a budget between the store with and without the dominated candidates
    budget = probe.projected_bytes * 0.97
    stats = StreamStats()
    evaluate_streaming(
        model, poses, 0.1, 500.0, stats=stats, settings=EvaluationSettings(max_memory_bytes=budget, store_headroom=1)
    )
    assert stats.drop_dominated and stats.dropped_views > 0 and stats.projected_bytes <= budget
    # a budget dominance alone cannot meet: a redundancy-fold cover, the largest that fits
    tight = probe.projected_bytes * 0.3
    evaluate_streaming(
        model, poses, 0.1, 500.0, stats=stats, settings=EvaluationSettings(max_memory_bytes=tight, store_headroom=1)
    )
    assert stats.redundancy > 0 and stats.projected_bytes <= tight and stats.kept_pairs < 0.5 * probe.projected_pairs


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
