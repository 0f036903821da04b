"""Streaming candidate evaluation under a memory budget.

The candidates' metrology is computed chunk by chunk (in this process, or on a Dask cluster through
:mod:`~agiprobot_measurement.planning.candidates.distributed`) and only the sparse measurability of candidates that measure
something is kept. The result does not depend on the chunking, the number of threads or workers: every (view,
point) pair is evaluated with the same operations wherever it is evaluated, each chunk is reduced on its own
(types, dominated columns) and chunks are merged in candidate order.

Store types (:data:`COMPACT_ABOVE_PAIRS`): point ids are int32. A store projected above that many pairs keeps
uncertainty and ``t0`` as float32 (12 bytes per pair instead of 20) and every column's ``t0`` range as the range of
the stored float32 values, so the scan lines and the partial acceptance of a shortened scan line (which compares
the stored ``t0`` with the scan line's intact end) see the same numbers. float32 keeps 24 bits: an uncertainty
(at most the threshold, ~0.1 mm) to ~6e-9 mm, a ``t0`` (at most 500 mm) to 3e-5 mm. The rounding can change a plan
against the float64 store (ties in the set cover, scan lines 1e-5 mm shorter), so the choice depends only on the
pilot's projection, which is the same in every set-up (in process, 1 or N workers, a scheduler); smaller stores
keep float64 exactly as before. ``EvaluationSettings(compact=True/False)`` forces it.

Dominated candidates (:func:`dominated_columns`): a candidate whose measurable points are a subset of another
candidate's in the same group of :data:`REDUCTION_GROUP_VIEWS` consecutive candidates (the tilts and orientations
of some twenty neighbouring samples) adds nothing to the coverage while its dominator is executable. They are
dropped (on the workers, per fixed group, so the result does not depend on the chunking) when the pilot projects
more than :data:`DROP_DOMINATED_ABOVE_PAIRS` pairs or the budget requires it, or with
``EvaluationSettings(drop_dominated=True)``; the set cover evaluates a dropped candidate again when the mechanics
reject or shorten its dominator (``TrajectoryManager`` revives it from the reserve below), so dropping does not
lose points whose dominator cannot be driven. If that is not enough (measured: the 1 m^2
panel at tilt full keeps ~80 % of its pairs), the client keeps a ``redundancy``-fold cover
(:func:`redundant_columns_kept`, the largest of :data:`REDUNDANCY_STEPS` that fits): blocks are committed in
candidate order, and a candidate is kept while one of its points is measured by fewer than ``redundancy`` kept
candidates, so every coverable point stays coverable by min(redundancy, its candidates) candidates, the reserve
for views the mechanics stage rejects. Each dropped candidate is listed in :attr:`StreamStats.reserve_index`,
with a kept candidate measuring all its points in :attr:`StreamStats.reserve_dominator` (-1 for the cover's),
so a later stage can evaluate it again. Both reductions can change the plan (fewer, different candidates); both
are deterministic for a given budget (pass ``--max-memory`` for the same plan on machines with other free memory).

Before the work, a pilot (a fixed random 1 % of the candidates, at least 200) measures the pairs per candidate; the
store's size is projected from it (with dominated candidates dropped: from three contiguous chunk-sized slices)
and work that cannot fit the budget is refused with the estimate
(:class:`~agiprobot_measurement.planning.request.WorkTooLarge`). The chunk size follows from the pilot's time per
candidate (about :data:`CHUNK_TARGET_S` of work per chunk) and from the budget (chunks in flight take a small share
of it).

Sizes in bytes unless the name says otherwise.
"""

from __future__ import annotations

import itertools
import math
import mmap
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np

from agiprobot_measurement.planning.candidates import time_fit
from agiprobot_measurement.planning.request import WORKER_PROCESS_BYTES, WorkTooLarge
from agiprobot_measurement.sensors.laser_line.model import MeasurabilityResult

__all__ = [
    "BYTES_PER_KEPT_ENTRY",
    "BYTES_PER_KEPT_VIEW",
    "COMPACT_ABOVE_PAIRS",
    "DROP_DOMINATED_ABOVE_PAIRS",
    "EvaluationSettings",
    "StreamStats",
    "chunk_block",
    "default_max_memory_bytes",
    "dominated_columns",
    "evaluate_in_chunks",
    "evaluate_streaming",
    "machine_memory_bytes",
]

#: the compact store's uncertainty and t0 type (see the module's docstring for the precision and the effect)
UNCERTAINTY_DTYPE = np.float32
T0_DTYPE = np.float32
#: a store projected above this many measurable pairs (about 1 GB in float64) is kept in the compact types; the
#: parts of the benchmarks and tests today (the cube at tilt full: 38 million) stay float64 and keep their plans
COMPACT_ABOVE_PAIRS = 60e6
#: a store projected above this many measurable pairs drops dominated candidates (the cube at tilt full: 38 million
#: pairs, ~70 % of its columns dominated); smaller ones (tilt none on the benchmark parts) keep every candidate
DROP_DOMINATED_ABOVE_PAIRS = 10e6
#: a kept measurable pair: point id (int32), uncertainty, t0 (float64; float32 when compact)
BYTES_PER_KEPT_ENTRY = 4 + 8 + 8
BYTES_PER_COMPACT_ENTRY = 4 + np.dtype(UNCERTAINTY_DTYPE).itemsize + np.dtype(T0_DTYPE).itemsize
#: a kept candidate: its column pointer, exact t0 range, candidate index, and the ViewPoint built for it later
#: (pose arrays and attributes, measured ~2.5 kB)
BYTES_PER_KEPT_VIEW = 8 + 16 + 8 + 2500
#: the share of the budget the default leaves to the rest of the machine
DEFAULT_MEMORY_SHARE = 0.8
#: the planning stages after the evaluation copy the kept pairs a few times (alive mask, cover matrix): the store
#: must fit this many times its own size (``EvaluationSettings.store_headroom``; 1 for the evaluation alone)
STORE_HEADROOM = 2.0
#: dominated candidates and the redundancy-fold cover are found within groups of this many consecutive candidates
#: (about 19 samples' orientations and tilts at tilt full), aligned at its multiples: the result does not depend
#: on the chunk size (measured on the 1 m^2 panel at tilt full: groups of 1,000 / 4,000 / 16,000 candidates keep
#: 81 / 81 / 79 % of the pairs by dominance)
REDUCTION_GROUP_VIEWS = 2048
#: the dominance pilot: this many slices of two groups each, spread over the candidates
DOMINANCE_PILOT_SLICES = 3
#: the redundancies tried, largest first, when dropping dominated candidates does not fit the budget: each point
#: stays measured by this many kept candidates (where it has them), a reserve for the scan lines the mechanics
#: stage rejects. The cover runs in the client over the blocks in candidate order (so it does not depend on the
#: workers); it keeps at most redundancy x points candidates, which bounds its projection
REDUNDANCY_STEPS = (256, 128, 64, 32, 16, 8, 4, 2, 1)
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
    budget of this process (None = :func:`default_max_memory_bytes`); ``compact``: float32 uncertainties and t0
    (None = above :data:`COMPACT_ABOVE_PAIRS` projected pairs); ``drop_dominated``: drop dominated candidates
    (None = above :data:`DROP_DOMINATED_ABOVE_PAIRS` projected pairs or when the budget requires it); ``redundancy``: keep per chunk only a ``redundancy``-fold cover of its
    points (:func:`redundant_columns_kept`; None = the largest of :data:`REDUNDANCY_STEPS` the budget allows when
    dropping dominated candidates is not enough, 0 = never); ``store_headroom``: how many times the store must fit the budget
    (:data:`STORE_HEADROOM`; 1 when nothing runs after the evaluation).
    """

    workers: int = 0
    scheduler: str = ""
    max_memory_bytes: float | None = None
    compact: bool | None = None
    drop_dominated: bool | None = None
    redundancy: int | None = None
    store_headroom: float = STORE_HEADROOM

    @property
    def distributed(self) -> bool:
        return bool(self.scheduler) or self.workers > 0

    def budget_bytes(self) -> float:
        """The store's budget: ``max_memory_bytes`` (or the default) less what the local workers take themselves
        (:data:`WORKER_PROCESS_BYTES` each; an existing cluster's workers run elsewhere)."""
        total = float(self.max_memory_bytes) if self.max_memory_bytes else float(default_max_memory_bytes())
        return total - self.local_worker_bytes()

    def local_worker_bytes(self) -> float:
        """Memory the local Dask worker processes take by themselves (bytes; 0 in process or on a cluster)."""
        return 0.0 if self.scheduler else float(self.workers) * WORKER_PROCESS_BYTES


@dataclass
class StreamStats:
    """What a streaming evaluation did: candidates, kept columns and pairs, chunks, the pilot's projection, the
    budget, the store's types, dominated candidates dropped (and their reserve), per-chunk wall and CPU times on
    their worker (s) and the stage's wall time (s)."""

    candidates: int = 0
    kept_views: int = 0
    kept_pairs: int = 0
    chunks: int = 0
    chunk_views: int = 0
    projected_pairs: float = 0.0
    projected_bytes: float = 0.0
    budget_bytes: float = 0.0
    store_bytes: int = 0
    compact: bool = False
    drop_dominated: bool = False
    #: share of the measurable pairs the dominance pilot kept (1 without dropping), and the redundancy chosen (0:
    #: dominated candidates only)
    dominance_kept_share: float = 1.0
    redundancy: int = 0
    dropped_views: int = 0
    dropped_pairs: int = 0
    #: dropped candidates (indices into the evaluated poses, ascending) and, for each, a kept candidate that
    #: measures all its points
    reserve_index: np.ndarray | None = None
    reserve_dominator: np.ndarray | None = None
    pilot_s: float = 0.0
    #: the pilot's tasks' work (s each): the random spread (one piece per worker thread; in process one piece) and
    #: the dominance slices (one task each); scatter_s: sending the sensor model to the workers, before the pilot
    pilot_spread_seconds: list = field(default_factory=list)
    pilot_dominance_seconds: list = field(default_factory=list)
    scatter_s: float = 0.0
    merge_s: float = 0.0
    wall_s: float = 0.0
    chunk_seconds: list | None = None
    chunk_cpu_seconds: list | None = None
    where: str = "in-process"
    #: candidates actually evaluated (fewer than ``candidates`` when the time limit did not leave time for all)
    #: and why: "" (all), "projected" (a random spread that the pilot projected to fit), "stopped" (the evaluation
    #: ran into its deadline and kept the chunks done)
    evaluated: int = 0
    time_limited: str = ""


@numba.njit(cache=True)
def _dominated(indptr, ids, n_points):  # pragma: no cover - compiled
    n = indptr.size - 1
    local = np.full(n_points, -1, np.int64)
    m = 0
    for k in range(ids.size):
        if local[ids[k]] < 0:
            local[ids[k]] = m
            m += 1
    words = (m + 63) // 64
    bits = np.zeros((n, words), np.uint64)
    freq = np.zeros(m, np.int64)
    for j in range(n):
        for k in range(indptr[j], indptr[j + 1]):
            q = local[ids[k]]
            bits[j, q >> 6] |= np.uint64(1) << np.uint64(q & 63)
            freq[q] += 1
    by = np.full(n, -1, np.int64)
    for i in range(n):
        size_i = indptr[i + 1] - indptr[i]
        if size_i == 0:
            continue
        # a dominator contains i's rarest point: one word test rules most columns out
        rare = local[ids[indptr[i]]]
        for k in range(indptr[i] + 1, indptr[i + 1]):
            q = local[ids[k]]
            if freq[q] < freq[rare]:
                rare = q
        if freq[rare] < 2:
            continue
        word, mask = rare >> 6, np.uint64(1) << np.uint64(rare & 63)
        for j in range(n):
            size_j = indptr[j + 1] - indptr[j]
            # equal sets: the first one stays
            if j == i or size_j < size_i or (size_j == size_i and j > i) or (bits[j, word] & mask) == 0:
                continue
            subset = True
            for t in range(words):
                if bits[i, t] & ~bits[j, t]:
                    subset = False
                    break
            if subset:
                by[i] = j
                break
    # a dominator may be dominated itself: follow the chain to a kept one (sizes grow along it, so it ends)
    for i in range(n):
        j = by[i]
        while j >= 0 and by[j] >= 0:
            j = by[j]
        by[i] = j
    return by


def dominated_columns(result: MeasurabilityResult) -> np.ndarray:
    """For every column of ``result``: -1 if it is kept, else the index of a kept column whose measurable points
    include all of its points (a strict superset, or an equal set earlier in the result). Exact (bit sets over
    the result's points); the maximal columns stay, so dropping the others keeps the coverage."""
    if result.n_views == 0:
        return np.zeros(0, dtype=np.int64)
    return _dominated(np.asarray(result.indptr, dtype=np.int64), np.asarray(result.point_indices), int(result.n_points))


@numba.njit(cache=True)
def _k_cover(indptr, ids, count, order, k):  # pragma: no cover - compiled
    keep = np.zeros(indptr.size - 1, np.bool_)
    for c in order:
        needed = False
        for e in range(indptr[c], indptr[c + 1]):
            if count[ids[e]] < k:
                needed = True
                break
        if needed:
            keep[c] = True
            for e in range(indptr[c], indptr[c + 1]):
                count[ids[e]] += 1
    return keep


def redundant_columns_kept(result: MeasurabilityResult, redundancy: int, covered=None) -> np.ndarray:
    """Which columns of ``result`` a ``redundancy``-fold cover keeps: the columns in order of size (largest first,
    then by index), each kept while one of its points is measured by fewer than ``redundancy`` kept columns. Every
    point of ``result`` stays measured by min(redundancy, its columns) kept columns; deterministic. ``covered``
    ((n_points,) int32, updated in place): the kept columns per point so far, to continue a cover over blocks."""
    counts = result.counts
    order = np.argsort(-counts, kind="stable").astype(np.int64)
    if covered is None:
        covered = np.zeros(result.n_points, dtype=np.int32)
    return _k_cover(
        np.asarray(result.indptr, dtype=np.int64), np.asarray(result.point_indices), covered, order, int(redundancy)
    )


def _select(result: MeasurabilityResult, columns: np.ndarray) -> MeasurabilityResult:
    """The columns ``columns`` (ascending) of ``result``."""
    counts = result.counts[columns]
    indptr = np.zeros(columns.size + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    starts = result.indptr[columns]
    entries = np.repeat(starts - indptr[:-1], counts) + np.arange(indptr[-1])
    return MeasurabilityResult(
        result.n_points,
        columns.size,
        indptr,
        result.point_indices[entries],
        result.uncertainties[entries],
        result.trajectory_distances[entries],
        result.extent_min[columns],
        result.extent_max[columns],
    )


def chunk_block(
    sensor_model, poses, threshold_mm, deflection_mm, threads=None, compact=False, drop_dominated=False, redundancy=0
):
    """Evaluate one chunk of candidate poses; returns (the result of its kept columns, their indices in the chunk,
    info). Empty columns are dropped, and dominated ones with ``drop_dominated``; ``compact``: float32 uncertainty
    and t0, the t0 range of a column that of its stored values. ``info``: ``wall_s`` and ``cpu_s`` (this process's
    CPU time) of the chunk, the dropped columns ``dropped`` and a kept column measuring all their points,
    ``dominator`` (indices in the chunk; -1 for a column dropped by the ``redundancy``-fold cover,
    :func:`redundant_columns_kept`, which follows the dominance when ``redundancy`` > 0). Runs wherever the chunk is sent (this process or a Dask worker)."""
    started, cpu_started = time.perf_counter(), time.process_time()
    result = sensor_model.evaluate_viewpoints_batch(poses, threshold_mm, deflection_mm, workers=threads)
    counts = result.counts
    columns = np.flatnonzero(counts > 0)
    indptr = np.zeros(columns.size + 1, dtype=np.int64)
    np.cumsum(counts[columns], out=indptr[1:])
    values = np.float32 if compact else np.float64
    t0 = result.trajectory_distances.astype(T0_DTYPE if compact else np.float64, copy=False)
    if compact:  # the range of the stored values: the later stages compare those with the scan line's ends
        block = MeasurabilityResult(result.n_points, columns.size, indptr, result.point_indices, t0, t0)
        t0_min, t0_max = block.t0_min.astype(np.float64), block.t0_max.astype(np.float64)
    else:
        t0_min, t0_max = result.t0_min[columns], result.t0_max[columns]
    # empty columns have no entries: dropping them leaves the entry arrays as they are
    block = MeasurabilityResult(
        result.n_points,
        columns.size,
        indptr,
        result.point_indices.astype(np.int32, copy=False),
        result.uncertainties.astype(values, copy=False),
        t0,
        t0_min,
        t0_max,
    )
    del result
    dropped = dominator = np.zeros(0, dtype=np.int64)
    if (drop_dominated or redundancy > 0) and block.n_views > 1:
        # reduced per group of REDUCTION_GROUP_VIEWS candidates (the chunks start at multiples of it), so the kept
        # columns do not depend on the chunk size, the workers or the timing
        keep = np.ones(block.n_views, dtype=bool)
        by = np.full(block.n_views, -1, dtype=np.int64)
        bounds = np.searchsorted(columns, np.arange(0, len(poses) + REDUCTION_GROUP_VIEWS, REDUCTION_GROUP_VIEWS))
        for lo, hi in itertools.pairwise(bounds.tolist()):
            if hi - lo < 2:
                continue
            group = _select(block, np.arange(lo, hi))
            if drop_dominated:
                by_group = dominated_columns(group)
                gone = np.flatnonzero(by_group >= 0)
                keep[lo + gone], by[lo + gone] = False, lo + by_group[gone]
            if redundancy > 0:
                alive = np.flatnonzero(keep[lo:hi])
                covered = redundant_columns_kept(_select(group, alive), redundancy)
                keep[lo + alive[~covered]] = False
        if not keep.all():
            gone = np.flatnonzero(~keep)
            dropped = columns[gone]
            dominator = np.where(by[gone] >= 0, columns[np.maximum(by[gone], 0)], -1)
            block, columns = _select(block, np.flatnonzero(keep)), columns[keep]
    info = {
        "wall_s": time.perf_counter() - started,
        "cpu_s": time.process_time() - cpu_started,
        "dropped": dropped,
        "dominator": dominator,
        "dropped_pairs": int(counts[dropped].sum()),
    }
    return block, columns.astype(np.int64), info


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


def block_summary(
    sensor_model, poses, threshold_mm, deflection_mm, threads=None, compact=False, drop_dominated=False
) -> dict:
    """What the pilot needs of one block of poses (:func:`chunk_block`), without the block: ``views`` evaluated,
    ``nnz`` kept pairs, ``n_views`` kept columns, ``dropped_pairs`` (by dominance) and ``wall_s`` of the work."""
    block, _, info = chunk_block(
        sensor_model, poses, threshold_mm, deflection_mm, threads=threads, compact=compact,
        drop_dominated=drop_dominated,
    )  # fmt: skip
    return {
        "views": len(poses),
        "nnz": int(block.nnz),
        "n_views": int(block.n_views),
        "dropped_pairs": int(info["dropped_pairs"]),
        "wall_s": float(info["wall_s"]),
    }


#: arrays from this size on are mapped with transparent huge pages (:func:`_empty_huge_paged`)
HUGE_PAGE_MIN_BYTES = 64 * 1024 * 1024


def _empty_huge_paged(count: int, dtype) -> np.ndarray:
    """``np.empty(count, dtype)``, asking the kernel for transparent huge pages when the array is large.

    The store is written once, block by block, so every one of its pages is faulted in once. Writing recently
    freed memory took 2.4 s of CPU per GB with 4 kB pages and 0.18 s with huge pages (THP in ``madvise`` mode,
    Debian's default); on a 2-core machine those faults are CPU taken from the workers. Memory the machine has
    not used for a while cost ~2.4 s per GB at first touch on this VM with either page size (the host backs it
    then). Untouched pages still take no memory. Falls back to ``np.empty`` where the kernel or the platform
    does not offer huge pages.
    """
    dtype = np.dtype(dtype)
    nbytes = int(count) * dtype.itemsize
    advice = getattr(mmap, "MADV_HUGEPAGE", None)
    if nbytes < HUGE_PAGE_MIN_BYTES or advice is None:
        return np.empty(count, dtype=dtype)
    mapping = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    try:
        mapping.madvise(advice)
    except OSError:  # THP disabled ("never"): ordinary pages
        pass
    return np.frombuffer(mapping, dtype=dtype, count=count)


class _Store:
    """The kept measurability, filled in candidate order as blocks arrive. The entry arrays are allocated for the
    pilot's projection with slack; untouched pages take no memory, so the slack is free. A block
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
            self.arrays = [_empty_huge_paged(self.capacity, getattr(block, n).dtype) for n in names]
        end = self.nnz + block.nnz
        if end > self.capacity:
            self.capacity = max(end, int(1.5 * self.capacity))
            grown = []
            for array in self.arrays:
                bigger = _empty_huge_paged(self.capacity, array.dtype)
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
    deadline_s: float | None = None,
) -> tuple[MeasurabilityResult, np.ndarray]:
    """Evaluate ``poses`` (V, 4, 4 mm) in chunks; return (the compact measurability of the candidates that
    measure something, their indices into ``poses``, ascending).

    ``executor``: a :class:`~agiprobot_measurement.planning.candidates.distributed.DaskEvaluator` (None = this process);
    ``fixed_bytes``: memory this process already holds for the run (samples, candidate poses), counted against
    the budget. ``report(stage, fraction, message)`` follows the completed chunks (stage 'metrology'). ``stats``
    is filled in. Raises :class:`~agiprobot_measurement.planning.request.WorkTooLarge` when the projected store
    does not fit the budget.

    ``deadline_s`` (a ``time.perf_counter()`` value, None = none): when the pilot projects that the candidates do
    not fit before it, a fixed random spread of them that does is evaluated (spread over the whole part, not its
    first candidates); should the evaluation still reach it, the chunks done are kept and the rest skipped.
    ``stats.evaluated`` and ``stats.time_limited`` say so; the returned indices are into ``poses`` either way.
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
    parallel = 1
    if executor is not None:
        parallel = executor.parallelism()
        executor.prepare(sensor_model)  # the sensor model to every worker once, timed apart from the pilot
    pilot_started = time.perf_counter()

    def summaries(blocks, **options) -> list[dict]:
        # on a cluster the pilot's work is spread over the workers like the chunks (it would otherwise be serial
        # work in the client while every worker waits); its figures do not depend on where it ran
        if executor is None:
            return [block_summary(sensor_model, b, threshold_mm, deflection_mm, **options) for b in blocks]
        return executor.summaries(sensor_model, blocks, threshold_mm, deflection_mm, **options)

    pilot = summaries(np.array_split(poses[pilot_index], min(parallel, pilot_n)))
    stats.pilot_spread_seconds = [p["wall_s"] for p in pilot]
    # time per view on one worker thread (in process: on this process's threads), what a chunk's size follows
    per_view_s = (
        sum(stats.pilot_spread_seconds) / pilot_n
        if executor is not None
        else (time.perf_counter() - pilot_started) / pilot_n
    )
    pairs_per_view = sum(p["nnz"] for p in pilot) / pilot_n
    kept_share = sum(p["n_views"] for p in pilot) / pilot_n
    subset = time_fit.fitting_subset(n, per_view_s / parallel, deadline_s)
    if subset is not None:
        poses, n = poses[subset], subset.size
        stats.time_limited = "projected"
    stats.projected_pairs = pairs_per_view * n
    # the store's types follow the projection only, so every set-up keeps the same values
    compact = settings.compact if settings.compact is not None else stats.projected_pairs > COMPACT_ABOVE_PAIRS
    per_entry = BYTES_PER_COMPACT_ENTRY if compact else BYTES_PER_KEPT_ENTRY
    stats.compact = bool(compact)
    headroom = float(settings.store_headroom)

    def projected(pair_share: float, view_share: float) -> tuple[float, float]:
        store = pair_share * stats.projected_pairs * per_entry + view_share * n * BYTES_PER_KEPT_VIEW
        return store, headroom * store + fixed_bytes

    store_bytes, stats.projected_bytes = projected(1.0, kept_share)

    # chunks: about CHUNK_TARGET_S of work each, several per worker, and the chunks in flight within a tenth of
    # the budget left after the store
    chunk = int(CHUNK_TARGET_S / max(per_view_s, 1e-9))
    chunk = min(chunk, max(MIN_CHUNK_VIEWS, math.ceil(n / (4 * parallel))))
    in_flight_bytes = 0.1 * max(budget - min(stats.projected_bytes, budget / 2), 0.0)
    per_chunk_bytes = max(pairs_per_view, 1.0) * (8 + 8 + 8) * 2  # raw float64 result and its compact copy
    chunk = min(chunk, int(min(in_flight_bytes / max(1, 2 * parallel), MAX_CHUNK_RESULT_BYTES) / per_chunk_bytes))
    chunk = int(min(max(chunk, MIN_CHUNK_VIEWS), MAX_CHUNK_VIEWS, n))

    drop = settings.drop_dominated
    if drop is None:  # above the size where the store dominates the memory, or when the budget requires it
        drop = stats.projected_pairs > DROP_DOMINATED_ABOVE_PAIRS or stats.projected_bytes > budget
    redundancy = int(settings.redundancy or 0)
    if drop or redundancy:
        group = REDUCTION_GROUP_VIEWS
        chunk = int(min(max(group, (chunk // group) * group), max(n, 1)))
    if drop:
        # what dropping keeps, from contiguous chunk-sized slices (a random spread has no dominated columns), for
        # dominance alone and for the redundancy-fold covers after it
        steps = (settings.redundancy,) if settings.redundancy is not None else (0, *REDUNDANCY_STEPS)
        group = REDUCTION_GROUP_VIEWS
        slices = []
        for k in range(DOMINANCE_PILOT_SLICES):
            start = int((k + 0.5) / DOMINANCE_PILOT_SLICES * n) // group * group - group
            start = min(max(start, 0), max(n - 2 * group, 0)) // group * group
            slices += [poses[at : at + group] for at in (start, start + group)]
        dominance = summaries(slices, compact=compact, drop_dominated=True)
        stats.pilot_dominance_seconds = [d["wall_s"] for d in dominance]
        kept, views = sum(d["nnz"] for d in dominance), sum(d["n_views"] for d in dominance)
        evaluated = kept + sum(d["dropped_pairs"] for d in dominance)
        sliced = sum(d["views"] for d in dominance)
        share, view_share = kept / max(evaluated, 1), views / max(sliced, 1)
        size = kept / max(views, 1)  # pairs of a column that survives dominance
        for step in steps:
            # the cover keeps at most step x points columns, each of about a surviving column's size
            bound = min(1.0, step * n_points * size / max(share * stats.projected_pairs, 1.0)) if step else 1.0
            store_bytes, stats.projected_bytes = projected(
                share * bound, min(view_share, step * n_points / n) if step else view_share
            )
            redundancy = int(step or 0)
            if stats.projected_bytes <= budget:
                break
        stats.dominance_kept_share = share
    stats.redundancy = redundancy
    stats.drop_dominated = bool(drop)
    stats.pilot_s = time.perf_counter() - pilot_started
    if stats.projected_bytes > budget:
        dropping = (
            f", {100 * stats.dominance_kept_share:.0f} % of them after dropping dominated candidates"
            + (f" and keeping a {redundancy}-fold cover" if redundancy else "")
            if drop
            else ""
        )
        workers_note = (
            f"(after {settings.local_worker_bytes() / 1e9:.2f} GB for {settings.workers} local worker processes: "
            "fewer --workers leave more) "
            if settings.local_worker_bytes()
            else ""
        )
        raise _refuse(
            f"request refused before the evaluation: a pilot of {pilot_n} of the {n:,} candidates measures "
            f"{pairs_per_view:.0f} points each, so the run would keep ~{stats.projected_pairs:,.0f} measurable pairs"
            f"{dropping} (~{store_bytes / 1e9:.2f} GB at {per_entry} bytes per pair, ~{stats.projected_bytes / 1e9:.2f}"
            f" GB with the later stages' copies and the candidates); the memory budget is {budget / 1e9:.2f} GB "
            f"{workers_note}"
            f"(--max-memory / max_memory_gb, default {DEFAULT_MEMORY_SHARE:.0%} of the available memory): raise it, "
            "or lower the sampling density, the orientations or the tilt mode"
        )

    starts = list(range(0, n, chunk))
    stats.chunks, stats.chunk_views = len(starts), chunk
    store = _Store(n_points, 1.5 * stats.projected_pairs * stats.dominance_kept_share)
    waiting: dict = {}  # blocks that arrived before an earlier one
    next_index = 0
    seconds = [0.0] * len(starts)
    cpu_seconds = [0.0] * len(starts)
    reserve, reserve_by = [], []
    done_views = 0
    kept_pairs = 0
    limit = budget - fixed_bytes

    covered = np.zeros(n_points, dtype=np.int32) if redundancy else None

    def arrived(index: int, block: MeasurabilityResult, columns: np.ndarray, info: dict) -> None:
        nonlocal done_views, kept_pairs, next_index
        start = starts[index]
        waiting[index] = (block, columns + start)
        while next_index in waiting:
            block_here, columns_here = waiting.pop(next_index)
            if redundancy and block_here.n_views:
                # the redundancy-fold cover in candidate order: the same wherever and whenever blocks arrive
                keep = redundant_columns_kept(block_here, redundancy, covered)
                if not keep.all():
                    reserve.append(columns_here[~keep])
                    reserve_by.append(np.full(int((~keep).sum()), -1, dtype=np.int64))
                    stats.dropped_pairs += int(block_here.counts[~keep].sum())
                    block_here, columns_here = _select(block_here, np.flatnonzero(keep)), columns_here[keep]
            store.append(block_here, columns_here)
            next_index += 1
        seconds[index], cpu_seconds[index] = info["wall_s"], info["cpu_s"]
        if info["dropped"].size:
            reserve.append(info["dropped"] + start)
            reserve_by.append(np.where(info["dominator"] >= 0, info["dominator"] + start, -1))
            stats.dropped_pairs += info["dropped_pairs"]
        done_views += min(chunk, n - start)
        kept_pairs = store.nnz + sum(b.nnz for b, _ in waiting.values())
        if kept_pairs * per_entry * headroom > limit:
            raise _refuse(
                f"the evaluation stopped: {kept_pairs:,} measurable pairs kept after {done_views:,} of {n:,} "
                f"candidates exceed the memory budget of {budget / 1e9:.2f} GB (the pilot projected "
                f"{stats.projected_pairs * stats.dominance_kept_share:,.0f}); raise --max-memory or lower the "
                "density, orientations or tilts"
            )
        if report is not None:
            report("metrology", done_views / n, f"{done_views} of {n} viewpoints")
        late = deadline_s is not None and time.perf_counter() > deadline_s
        if late and time_fit.MIN_FITTING_VIEWS < n > done_views:
            raise time_fit.DeadlineReached

    chunks = [poses[s : s + chunk] for s in starts]
    options = {"compact": bool(compact), "drop_dominated": bool(drop)}
    try:
        if executor is None:
            for index, part in enumerate(chunks):
                arrived(index, *chunk_block(sensor_model, part, threshold_mm, deflection_mm, **options))
        else:
            executor.evaluate(sensor_model, chunks, threshold_mm, deflection_mm, arrived, **options)
    except time_fit.DeadlineReached:
        stats.time_limited = "stopped"
    del chunks
    stats.evaluated = min(next_index * chunk, n)  # the chunks merged into the store
    merge_started = time.perf_counter()
    result, kept = store.result()
    stats.kept_views, stats.kept_pairs = result.n_views, result.nnz
    if reserve:
        order_index, order_by = np.concatenate(reserve).astype(np.int64), np.concatenate(reserve_by)
        order = np.argsort(order_index, kind="stable")
        stats.reserve_index, stats.reserve_dominator = order_index[order], order_by[order]
    else:
        stats.reserve_index = stats.reserve_dominator = np.zeros(0, dtype=np.int64)
    if subset is not None:  # back to indices into the caller's poses
        kept, stats.reserve_index = subset[kept], subset[stats.reserve_index]
        by = stats.reserve_dominator
        stats.reserve_dominator = np.where(by >= 0, subset[np.maximum(by, 0)], -1)
    stats.dropped_views = int(stats.reserve_index.size)
    stats.store_bytes = result.nbytes + kept.nbytes
    stats.chunk_seconds, stats.chunk_cpu_seconds = seconds, cpu_seconds
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
        sensor_model,
        poses,
        threshold_mm,
        deflection,
        report,
        settings=EvaluationSettings(max_memory_bytes=1e15, compact=False, drop_dominated=False),
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
