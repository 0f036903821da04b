"""Candidate evaluation on a Dask cluster: a local cluster of worker processes (``workers``) or an existing one
(``scheduler`` address, e.g. workers started with ``dask scheduler`` / ``dask worker`` on other machines).

The sensor model, holding the mesh and the samples, goes to every worker once (scattered, broadcast); a copy
rebuilds its ray tracer on arrival. Each chunk task returns its sparse block
(:func:`~agiprobot_measurement.planning.candidates.streaming.chunk_block`: compact types, empty columns dropped). The client
keeps a bounded number of tasks in flight, merges blocks in candidate order and reports progress as futures
complete. A worker that dies takes its running tasks with it; the scheduler reruns them elsewhere, and a task
that still fails for a reason outside the evaluation (the worker lost, the connection reset) is submitted again,
up to :data:`MAX_ATTEMPTS` times. Errors raised by the evaluation itself are not retried. Which worker ran a
chunk does not change its block, so the plan is the same.
"""

from __future__ import annotations

import logging
import os
import resource
import threading
import time
from collections.abc import Callable

from agiprobot_measurement.errors import InputError, InternalError
from agiprobot_measurement.planning.candidates.streaming import block_summary, chunk_block
from agiprobot_measurement.planning.errors import PlanningInputError

__all__ = ["MAX_ATTEMPTS", "ClusterError", "DaskEvaluator", "peak_rss_bytes"]

LOG = logging.getLogger(__name__)

#: submissions of one chunk before the evaluation gives up
MAX_ATTEMPTS = 4
#: tasks in flight per worker thread (enough to hide the round trip, few enough to bound the client's memory)
IN_FLIGHT_PER_THREAD = 3
#: how long to wait for an existing scheduler or a local cluster's workers (s)
CONNECT_TIMEOUT_S = 30.0


#: Dask configuration of the workers of a local cluster (an existing cluster keeps its own)
LOCAL_WORKER_CONFIG = {"distributed.worker.profile.enabled": False}


class ClusterError(InputError):
    """The Dask cluster cannot be reached or has no workers (the address, the workers' state)."""


def peak_rss_bytes() -> int:
    """Peak resident memory of this process (bytes; Linux reports kB)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


#: glibc's mallopt parameters for the mmap and the trim thresholds, and the values set on a worker (bytes)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
WORKER_MMAP_THRESHOLD_BYTES = 256 * 1024 * 1024
WORKER_TRIM_THRESHOLD_BYTES = 512 * 1024 * 1024
_heap_tuned = False


def _tune_worker_heap() -> None:
    """Let the worker's heap reuse freed blocks up to :data:`WORKER_MMAP_THRESHOLD_BYTES` and keep up to
    :data:`WORKER_TRIM_THRESHOLD_BYTES` of free heap for the next chunk.

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_`` set (64 kB), which also fixes glibc's mmap
    threshold at 128 kB: every temporary array of a chunk is then mapped and faulted in afresh, and a chunk takes
    4-5 times as long as in the planning process (measured). Raising the mmap threshold puts the temporaries on
    the heap; raising the trim threshold stops the heap from handing its top back after every chunk, which made
    the next chunk fault ~100 MB in again (26,000 faults per chunk on the 1 m^2 panel, 2.4 s of CPU per GB). A
    worker then holds about one chunk's temporaries between tasks, which its peak holds anyway.
    """
    global _heap_tuned
    if _heap_tuned:
        return
    _heap_tuned = True
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(_M_MMAP_THRESHOLD, WORKER_MMAP_THRESHOLD_BYTES)
        libc.mallopt(_M_TRIM_THRESHOLD, WORKER_TRIM_THRESHOLD_BYTES)
    except (OSError, AttributeError):  # not glibc: nothing to tune
        pass


def _evaluate_task(sensor_model, poses, threshold_mm, deflection_mm, compact, drop_dominated, redundancy):
    _tune_worker_heap()

    # one thread per task: a worker process is one core's share of the cluster
    return chunk_block(
        sensor_model, poses, threshold_mm, deflection_mm, threads=1, compact=compact, drop_dominated=drop_dominated,
        redundancy=redundancy,
    )  # fmt: skip


def _summary_task(sensor_model, poses, threshold_mm, deflection_mm, compact, drop_dominated):
    _tune_worker_heap()
    return block_summary(sensor_model, poses, threshold_mm, deflection_mm, 1, compact, drop_dominated)


def _worker_pid():
    return os.getpid()


class DaskEvaluator:
    """A Dask client for the evaluation: ``workers`` local processes or the cluster at ``scheduler``.

    ``local_threads``: threads per local worker process (1: a process per core). Use as a context manager or call
    :meth:`close`; a local cluster lives as long as the evaluator.
    """

    def __init__(self, workers: int = 0, scheduler: str = "", local_threads: int = 1):
        if not scheduler and workers < 1:
            raise PlanningInputError("DaskEvaluator needs workers >= 1 or a scheduler address")
        self.workers = int(workers)
        self.scheduler = str(scheduler or "")
        self.local_threads = int(local_threads)
        self._client = None
        self._cluster = None
        self._scattered = None  # (model id, context id, future)
        self.attempts_resubmitted = 0
        #: wall time of the last scatter of the sensor model to the workers (s)
        self.last_scatter_s = 0.0

    # ------------------------------------------------------------------------------------------ cluster
    @property
    def client(self):
        if self._client is None:
            try:
                from distributed import Client, LocalCluster
            except ImportError as exc:  # pragma: no cover - pinned in requirements.txt
                raise ClusterError("Dask is not installed: pip install dask distributed") from exc
            if self.scheduler:
                self._client = _connect(Client, self.scheduler)
            else:
                import dask.config

                # without a dashboard nobody reads the workers' statistical profiler, which samples the running
                # task's stack every 10 ms (its cost was within this machine's run-to-run noise of a few %)
                with dask.config.set(LOCAL_WORKER_CONFIG):
                    self._cluster = LocalCluster(
                        n_workers=self.workers,
                        threads_per_worker=self.local_threads,
                        processes=True,
                        dashboard_address=None,
                        silence_logs=logging.ERROR,
                    )
                self._client = Client(self._cluster)
            try:
                self._client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError) as exc:
                where = self.scheduler or "the local cluster"
                raise ClusterError(f"no Dask worker joined {where} within {CONNECT_TIMEOUT_S:g} s") from exc
        return self._client

    def describe(self) -> str:
        return f"Dask scheduler {self.scheduler}" if self.scheduler else f"{self.workers} local Dask workers"

    def parallelism(self) -> int:
        """Worker threads in the cluster now (at least 1)."""
        info = self.client.scheduler_info(n_workers=-1) if _takes_n_workers() else self.client.scheduler_info()
        return max(1, sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()))

    def worker_pids(self) -> dict[str, int]:
        """Process id of every worker, by worker address."""
        return self.client.run(_worker_pid)

    def worker_peak_rss_bytes(self) -> dict[str, int]:
        """Peak resident memory of every worker process (bytes), by worker address."""
        return self.client.run(peak_rss_bytes)

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        self._client = self._cluster = self._scattered = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --------------------------------------------------------------------------------------- evaluation
    def _model_future(self, sensor_model, refresh: bool = False):
        key = (id(sensor_model), id(sensor_model._context))
        if refresh or self._scattered is None or self._scattered[:2] != key:
            started = time.perf_counter()
            future = self.client.scatter(sensor_model, broadcast=True, hash=False)
            self._scattered = (*key, future)
            self.last_scatter_s = time.perf_counter() - started
        return self._scattered[2]

    def prepare(self, sensor_model) -> None:
        """Send the sensor model to every worker now (once per model; :attr:`last_scatter_s` times it)."""
        self._model_future(sensor_model)

    def evaluate(
        self,
        sensor_model,
        chunks: list,
        threshold_mm: float,
        deflection_mm: float,
        arrived: Callable[[int, object, object, dict], None],
        compact: bool = False,
        drop_dominated: bool = False,
        redundancy: int = 0,
    ) -> None:
        """Evaluate every chunk of poses on the cluster; ``arrived(index, block, columns, info)`` for each (see
        :func:`~agiprobot_measurement.planning.candidates.streaming.chunk_block`), in the order they complete (the caller
        merges by index)."""
        options = (threshold_mm, deflection_mm, compact, drop_dominated, redundancy)
        self._run(_evaluate_task, sensor_model, chunks, options, lambda index, out: arrived(index, *out))

    def summaries(
        self, sensor_model, blocks: list, threshold_mm: float, deflection_mm: float, compact=False, drop_dominated=False
    ) -> list[dict]:
        """:func:`~agiprobot_measurement.planning.candidates.streaming.block_summary` of every block of poses, on the cluster
        (the pilot's work spread over the workers), in the order of ``blocks``."""
        out: list = [None] * len(blocks)

        def arrived(index, summary):
            out[index] = summary

        self._run(_summary_task, sensor_model, blocks, (threshold_mm, deflection_mm, compact, drop_dominated), arrived)
        return out

    def _run(self, task, sensor_model, pieces: list, options: tuple, arrived: Callable[[int, object], None]) -> None:
        """``task(model, piece, *options)`` for every piece, a bounded number in flight; ``arrived(index, output)``
        as each completes. A piece lost with its worker is submitted again (up to MAX_ATTEMPTS); an error of the
        task itself is raised."""
        from distributed import as_completed

        client = self.client
        model = self._model_future(sensor_model)
        limit = IN_FLIGHT_PER_THREAD * self.parallelism()
        attempts = [0] * len(pieces)
        pending = list(range(len(pieces)))[::-1]  # popped from the end: piece 0 first
        index_of = {}

        def submit(index):
            attempts[index] += 1
            future = client.submit(task, model, pieces[index], *options, pure=False, retries=1)
            index_of[future.key] = index
            return future

        running = as_completed([submit(pending.pop()) for _ in range(min(limit, len(pending)))])
        for future in running:
            index = index_of.pop(future.key)
            try:
                output = future.result()
            except Exception as exc:  # the task's own error or the cluster's: sorted below
                error = exc
            else:
                future.release()
                arrived(index, output)
                error = None
            if error is not None:
                future.release()
                if not _is_cluster_failure(error):
                    raise error
                if attempts[index] >= MAX_ATTEMPTS:
                    raise InternalError(
                        f"chunk {index} failed {attempts[index]} times on the Dask cluster: {error!r}"
                    ) from error
                LOG.warning("chunk %d lost on the cluster (%r); submitting it again", index, error)
                self.attempts_resubmitted += 1
                time.sleep(0.5)
                model = self._model_future(sensor_model, refresh=True)
                pending.append(index)
            while pending and running.count() < limit:
                running.add(submit(pending.pop()))


def _connect(client_class, address: str):
    """A client of the scheduler at ``address``, connected and past the handshake within
    :data:`CONNECT_TIMEOUT_S`: Dask bounds a refused or unanswered connect, but not a peer that accepts and then
    says nothing or speaks another protocol (an HTTP server), so the connect runs in a thread that is waited for
    with that bound. :class:`ClusterError` otherwise (the thread, a daemon, is left to Dask's own timeouts)."""
    outcome: dict = {}

    def connect():
        try:
            outcome["client"] = client_class(address, timeout=CONNECT_TIMEOUT_S)
        except BaseException as exc:  # handed to the caller below
            outcome["error"] = exc

    thread = threading.Thread(target=connect, name="dask-connect", daemon=True)
    thread.start()
    thread.join(CONNECT_TIMEOUT_S + 1.0)
    if "client" in outcome:
        return outcome["client"]
    error = outcome.get("error")
    if error is None:
        raise ClusterError(
            f"no Dask scheduler answered at {address} within {CONNECT_TIMEOUT_S:g} s: something accepts "
            "connections there but does not speak Dask's protocol (another service on that port?)"
        )
    if isinstance(error, OSError | TimeoutError):
        raise ClusterError(f"cannot reach the Dask scheduler at {address}: {error}") from error
    raise error


def _takes_n_workers() -> bool:
    import inspect

    from distributed import Client

    return "n_workers" in inspect.signature(Client.scheduler_info).parameters


def _is_cluster_failure(error: BaseException) -> bool:
    """Whether ``error`` comes from the cluster (a worker or the data lost), not from the evaluation."""
    from distributed.client import FutureCancelledError
    from distributed.scheduler import KilledWorker

    lost = (KilledWorker, FutureCancelledError, OSError, TimeoutError, ConnectionError)
    if isinstance(error, lost):
        return True
    return type(error).__name__ in {"CommClosedError", "StreamClosedError", "CancelledError"}
