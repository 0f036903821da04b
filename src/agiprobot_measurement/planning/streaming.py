"""Streaming candidate evaluation under a memory budget.

The candidates' metrology is computed chunk by chunk (in this process, or on a Dask cluster through
:mod:`~agiprobot_measurement.planning.distributed`) and only the sparse measurability of candidates that measure
something is kept: point ids int32, uncertainties and ``t0`` float64 (20 bytes per measurable pair), plus the exact
``t0`` range per view. Quantising uncertainty or ``t0`` to float32 changed plans (measured; see
:data:`UNCERTAINTY_DTYPE` and :data:`T0_DTYPE`), so only ``EvaluationSettings(compact=True)`` stores float32
uncertainties. The result does not depend on the chunking, the number of threads or workers:
every (view, point) pair is evaluated with the same operations wherever it is evaluated, and chunks are merged in
candidate order.

Before the work, a pilot (a fixed random 1 % of the candidates, at least 200) measures the pairs per candidate; the store's
size is projected from it and work that cannot fit the budget is refused with the estimate
(:class:`~agiprobot_measurement.planning.request.WorkTooLarge`). The chunk size follows from the pilot's time per
candidate (about a second of work per chunk) and from the budget (chunks in flight take a small share of it).

Sizes in bytes unless the name says otherwise.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.planning.request import WorkTooLarge
from agiprobot_measurement.sensors.laser_line.model import MeasurabilityResult

__all__ = [
    "BYTES_PER_KEPT_ENTRY",
    "BYTES_PER_KEPT_VIEW",
    "EvaluationSettings",
    "StreamStats",
    "chunk_block",
    "default_max_memory_bytes",
    "evaluate_in_chunks",
    "evaluate_streaming",
    "machine_memory_bytes",
]

#: the stored uncertainty's type with ``compact``: float32 changed plans (measured on the cylinder at 0.01
#: points/mm^2: the set cover breaks ties by the values), so the default keeps float64
UNCERTAINTY_DTYPE = np.float32
#: the stored t0's type: float64, because float32 t0s changed plans (measured: a shortened scan line's intact end
#: equals its extreme t0 exactly, and the partial acceptance compares the t0s with it at 1e-9 mm)
T0_DTYPE = np.float64
#: a kept measurable pair: point id (int32), uncertainty (float64), t0 (float64); 4 less with ``compact``
BYTES_PER_KEPT_ENTRY = 4 + 8 + np.dtype(T0_DTYPE).itemsize
#: a kept candidate: its column pointer, exact t0 range, candidate index, and the ViewPoint built for it later
#: (pose arrays and attributes, measured ~2.5 kB)
BYTES_PER_KEPT_VIEW = 8 + 16 + 8 + 2500
#: the share of the budget the default leaves to the rest of the machine
DEFAULT_MEMORY_SHARE = 0.8
#: the planning stages after the evaluation copy the kept pairs a few times (alive mask, cover matrix): the store
#: must fit this many times its own size
STORE_HEADROOM = 2.0
#: target wall time of one chunk (s): long against the per-task overhead of a cluster, short for the progress bar
CHUNK_TARGET_S = 1.0
#: the pilot evaluates this share of the candidates, at least PILOT_MIN_VIEWS of them
PILOT_SHARE = 0.01
PILOT_MIN_VIEWS = 200
#: the most one chunk's raw (float64) result may take: its temporaries are what the evaluation adds to the store
MAX_CHUNK_RESULT_BYTES = 32e6
#: chunk bounds (candidates)
MIN_CHUNK_VIEWS = 256
MAX_CHUNK_VIEWS = 50_000


def machine_memory_bytes() -> tuple[int, int]:
    """(total, available) physical memory of this machine (``/proc/meminfo``; total twice where unreadable)."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    available = total
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(total), int(available)


def default_max_memory_bytes() -> int:
    """The default budget: :data:`DEFAULT_MEMORY_SHARE` of the memory available now."""
    return int(DEFAULT_MEMORY_SHARE * machine_memory_bytes()[1])


@dataclass(frozen=True)
class EvaluationSettings:
    """Where and within what the candidates are evaluated.

    ``workers``: processes of a local Dask cluster (0 = in this process, as without Dask); ``scheduler``: address
    of an existing Dask scheduler (e.g. ``tcp://host:8786``; overrides ``workers``); ``max_memory_bytes``: the
    budget of this process (None = :func:`default_max_memory_bytes`); ``compact``: keep uncertainties as float32
    (4 bytes less per pair; off by default because it changed plans, see :data:`UNCERTAINTY_DTYPE`).
    """

    workers: int = 0
    scheduler: str = ""
    max_memory_bytes: float | None = None
    compact: bool = False

    @property
    def distributed(self) -> bool:
        return bool(self.scheduler) or self.workers > 0

    def budget_bytes(self) -> float:
        return float(self.max_memory_bytes) if self.max_memory_bytes else float(default_max_memory_bytes())


@dataclass
class StreamStats:
    """What a streaming evaluation did: candidates, kept columns and pairs, chunks, the pilot's projection, the
    budget, per-chunk wall times on their worker (s) and the stage's wall time (s)."""

    candidates: int = 0
    kept_views: int = 0
    kept_pairs: int = 0
    chunks: int = 0
    chunk_views: int = 0
    projected_pairs: float = 0.0
    projected_bytes: float = 0.0
    budget_bytes: float = 0.0
    store_bytes: int = 0
    pilot_s: float = 0.0
    scatter_s: float = 0.0
    merge_s: float = 0.0
    wall_s: float = 0.0
    chunk_seconds: list | None = None
    where: str = "in-process"


def chunk_block(sensor_model, poses, threshold_mm, deflection_mm, threads=None, compact=False):
    """Evaluate one chunk of candidate poses; returns (compact result of its non-empty columns, their indices in
    the chunk, wall time s). Runs wherever the chunk is sent (this process or a Dask worker)."""
    started = time.perf_counter()
    result = sensor_model.evaluate_viewpoints_batch(poses, threshold_mm, deflection_mm, workers=threads)
    counts = result.counts
    columns = np.flatnonzero(counts > 0)
    t0_min, t0_max = result.t0_min[columns], result.t0_max[columns]
    indptr = np.zeros(columns.size + 1, dtype=np.int64)
    np.cumsum(counts[columns], out=indptr[1:])
    # empty columns have no entries: dropping them leaves the entry arrays as they are
    block = MeasurabilityResult(
        result.n_points,
        columns.size,
        indptr,
        result.point_indices.astype(np.int32, copy=False),
        result.uncertainties.astype(UNCERTAINTY_DTYPE if compact else np.float64, copy=False),
        result.trajectory_distances.astype(T0_DTYPE if compact else np.float64, copy=False),
        t0_min,
        t0_max,
    )
    return block, columns.astype(np.int64), time.perf_counter() - started


def _merge(blocks: list[MeasurabilityResult], n_points: int) -> MeasurabilityResult:
    """Blocks in order into one result; one entry array at a time, each block's copy freed once merged, so the
    peak stays near the result's size (plus one array of the blocks)."""
    if not blocks:
        return MeasurabilityResult(
            n_points, 0, np.zeros(1, dtype=np.int64), np.zeros(0, np.int32), np.zeros(0, np.float32),
            np.zeros(0), np.zeros(0), np.zeros(0),
        )  # fmt: skip
    indptr = np.zeros(sum(b.n_views for b in blocks) + 1, dtype=np.int64)
    np.cumsum(np.concatenate([b.counts for b in blocks]), out=indptr[1:])
    extent_min = np.concatenate([b.extent_min for b in blocks])
    extent_max = np.concatenate([b.extent_max for b in blocks])
    entries = {}
    for name in ("point_indices", "uncertainties", "trajectory_distances"):
        entries[name] = np.concatenate([getattr(b, name) for b in blocks])
        for index, block in enumerate(blocks):
            blocks[index] = _without(block, name)
    return MeasurabilityResult(
        n_points, indptr.size - 1, indptr, extent_min=extent_min, extent_max=extent_max, **entries
    )


def _without(block: MeasurabilityResult, name: str) -> MeasurabilityResult:
    import dataclasses

    return dataclasses.replace(block, **{name: np.zeros(0, dtype=getattr(block, name).dtype)})


class _Store:
    """The kept measurability, filled in candidate order as blocks arrive. The entry arrays are allocated for the
    pilot's projection with slack; untouched pages of ``np.empty`` take no memory, so the slack is free. A block
    beyond the capacity grows the arrays by half (one copy). The peak stays near the store's own size."""

    def __init__(self, n_points: int, capacity: int):
        self.n_points = n_points
        self.capacity = max(int(capacity), 1024)
        self.arrays = None  # point ids, uncertainties, t0
        self.nnz = 0
        self.counts, self.extent_min, self.extent_max, self.columns = [], [], [], []

    def append(self, block: MeasurabilityResult, columns: np.ndarray) -> None:
        names = ("point_indices", "uncertainties", "trajectory_distances")
        if self.arrays is None:
            self.arrays = [np.empty(self.capacity, dtype=getattr(block, n).dtype) for n in names]
        end = self.nnz + block.nnz
        if end > self.capacity:
            self.capacity = max(end, int(1.5 * self.capacity))
            grown = []
            for array in self.arrays:
                bigger = np.empty(self.capacity, dtype=array.dtype)
                bigger[: self.nnz] = array[: self.nnz]
                grown.append(bigger)
            self.arrays = grown
        for array, name in zip(self.arrays, names, strict=True):
            array[self.nnz : end] = getattr(block, name)
        self.nnz = end
        self.counts.append(block.counts)
        self.extent_min.append(block.extent_min)
        self.extent_max.append(block.extent_max)
        self.columns.append(columns)

    def result(self) -> tuple[MeasurabilityResult, np.ndarray]:
        if self.arrays is None:
            return _merge([], self.n_points), np.zeros(0, dtype=np.int64)
        counts = np.concatenate(self.counts)
        indptr = np.zeros(counts.size + 1, dtype=np.int64)
        np.cumsum(counts, out=indptr[1:])
        entries = [array[: self.nnz] for array in self.arrays]
        store = MeasurabilityResult(
            self.n_points,
            counts.size,
            indptr,
            *entries,
            np.concatenate(self.extent_min),
            np.concatenate(self.extent_max),
        )
        return store, np.concatenate(self.columns)


def _refuse(message: str) -> WorkTooLarge:
    return WorkTooLarge("max_memory_gb", message)


def evaluate_streaming(
    sensor_model,
    poses: np.ndarray,
    threshold_mm: float,
    deflection_mm: float,
    report: Callable[[str, float, str], None] | None = None,
    *,
    settings: EvaluationSettings | None = None,
    executor=None,
    fixed_bytes: float = 0.0,
    stats: StreamStats | None = None,
) -> tuple[MeasurabilityResult, np.ndarray]:
    """Evaluate ``poses`` (V, 4, 4 mm) in chunks; return (the compact measurability of the candidates that
    measure something, their indices into ``poses``, ascending).

    ``executor``: a :class:`~agiprobot_measurement.planning.distributed.DaskEvaluator` (None = this process);
    ``fixed_bytes``: memory this process already holds for the run (samples, candidate poses), counted against
    the budget. ``report(stage, fraction, message)`` follows the completed chunks (stage 'metrology'). ``stats``
    is filled in. Raises :class:`~agiprobot_measurement.planning.request.WorkTooLarge` when the projected store
    does not fit the budget.
    """
    settings = settings or EvaluationSettings()
    stats = stats if stats is not None else StreamStats()
    started = time.perf_counter()
    poses = np.asarray(poses, dtype=float)
    n = len(poses)
    n_points = len(sensor_model.sampled_surface_points)
    budget = settings.budget_bytes()
    stats.candidates, stats.budget_bytes = n, budget
    stats.where = executor.describe() if executor is not None else "in-process"
    if n == 0:
        return _merge([], n_points), np.zeros(0, dtype=np.int64)

    # the pilot: a fixed random spread of candidates (a stride would alias with the orientation / tilt pattern)
    pilot_n = min(n, max(PILOT_MIN_VIEWS, round(PILOT_SHARE * n)))
    pilot_index = np.sort(np.random.default_rng(0).choice(n, pilot_n, replace=False))
    pilot_started = time.perf_counter()
    pilot, _, _ = chunk_block(sensor_model, poses[pilot_index], threshold_mm, deflection_mm)
    stats.pilot_s = time.perf_counter() - pilot_started
    per_view_s = stats.pilot_s / pilot_n
    pairs_per_view = pilot.nnz / pilot_n
    kept_share = pilot.n_views / pilot_n
    stats.projected_pairs = pairs_per_view * n
    store = stats.projected_pairs * BYTES_PER_KEPT_ENTRY + kept_share * n * BYTES_PER_KEPT_VIEW
    stats.projected_bytes = STORE_HEADROOM * store + fixed_bytes
    if stats.projected_bytes > budget:
        raise _refuse(
            f"request refused before the evaluation: a pilot of {pilot_n} of the {n:,} candidates measures "
            f"{pairs_per_view:.0f} points each, so the run would keep ~{stats.projected_pairs:,.0f} measurable pairs "
            f"(~{store / 1e9:.2f} GB, ~{stats.projected_bytes / 1e9:.2f} GB with the later stages' copies and the "
            f"candidates); the memory budget is {budget / 1e9:.2f} GB (--max-memory / max_memory_gb, default "
            f"{DEFAULT_MEMORY_SHARE:.0%} of the available memory): raise it, or lower the sampling density, the "
            "orientations or the tilt mode"
        )
    del pilot

    # chunks: about CHUNK_TARGET_S of work each, several per worker, and the chunks in flight within a tenth of
    # the budget left after the store
    parallel = executor.parallelism() if executor is not None else 1
    chunk = int(CHUNK_TARGET_S / max(per_view_s, 1e-9))
    chunk = min(chunk, max(MIN_CHUNK_VIEWS, math.ceil(n / (4 * parallel))))
    in_flight_bytes = 0.1 * max(budget - stats.projected_bytes, 0.0)
    per_chunk_bytes = max(pairs_per_view, 1.0) * (8 + 8 + 8) * 2  # raw float64 result and its compact copy
    chunk = min(chunk, int(min(in_flight_bytes / max(1, 2 * parallel), MAX_CHUNK_RESULT_BYTES) / per_chunk_bytes))
    chunk = int(min(max(chunk, MIN_CHUNK_VIEWS), MAX_CHUNK_VIEWS, n))
    starts = list(range(0, n, chunk))
    stats.chunks, stats.chunk_views = len(starts), chunk

    store = _Store(n_points, 1.5 * stats.projected_pairs)
    waiting: dict = {}  # blocks that arrived before an earlier one
    next_index = 0
    seconds = [0.0] * len(starts)
    done_views = 0
    kept_pairs = 0
    limit = budget - fixed_bytes

    def arrived(index: int, block: MeasurabilityResult, columns: np.ndarray, wall_s: float) -> None:
        nonlocal done_views, kept_pairs, next_index
        start = starts[index]
        waiting[index] = (block, columns + start)
        while next_index in waiting:
            store.append(*waiting.pop(next_index))
            next_index += 1
        seconds[index] = wall_s
        done_views += min(chunk, n - start)
        kept_pairs += block.nnz
        if kept_pairs * BYTES_PER_KEPT_ENTRY * STORE_HEADROOM > limit:
            raise _refuse(
                f"the evaluation stopped: {kept_pairs:,} measurable pairs kept after {done_views:,} of {n:,} "
                f"candidates exceed the memory budget of {budget / 1e9:.2f} GB (the pilot projected "
                f"{stats.projected_pairs:,.0f}); raise --max-memory or lower the density, orientations or tilts"
            )
        if report is not None:
            report("metrology", done_views / n, f"{done_views} of {n} viewpoints")

    chunks = [poses[s : s + chunk] for s in starts]
    if executor is None:
        for index, part in enumerate(chunks):
            arrived(index, *chunk_block(sensor_model, part, threshold_mm, deflection_mm, compact=settings.compact))
    else:
        executor.evaluate(sensor_model, chunks, threshold_mm, deflection_mm, arrived, compact=settings.compact)
    del chunks
    merge_started = time.perf_counter()
    result, kept = store.result()
    stats.kept_views, stats.kept_pairs = result.n_views, result.nnz
    stats.store_bytes = result.nbytes + kept.nbytes
    stats.chunk_seconds = seconds
    stats.merge_s = time.perf_counter() - merge_started
    stats.scatter_s = getattr(executor, "last_scatter_s", 0.0)
    stats.wall_s = time.perf_counter() - started
    return result, kept


def evaluate_in_chunks(
    sensor_model,
    poses: np.ndarray,
    threshold_mm: float,
    deflection: float,
    report: Callable[[str, float, str], None] | None = None,
) -> MeasurabilityResult:
    """Batch metrology with progress (stage 'metrology') over all ``poses``, empty columns included (the former
    API; planning uses :func:`evaluate_streaming`)."""
    result, kept = evaluate_streaming(
        sensor_model, poses, threshold_mm, deflection, report, settings=EvaluationSettings(max_memory_bytes=1e15)
    )
    counts = np.zeros(len(poses), dtype=np.int64)
    counts[kept] = result.counts
    indptr = np.zeros(len(poses) + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    t0_min = np.full(len(poses), np.nan)
    t0_max = np.full(len(poses), np.nan)
    t0_min[kept], t0_max[kept] = result.t0_min, result.t0_max
    return MeasurabilityResult(
        result.n_points,
        len(poses),
        indptr,
        result.point_indices,
        result.uncertainties,
        result.trajectory_distances,
        t0_min,
        t0_max,
    )
