"""Executors: where a run's chunks are computed, behind one interface (:class:`Executor`).

:class:`SerialExecutor` runs the chunks one after the other in this process (no Dask cluster
or client). :class:`DaskExecutor` runs one Dask task per chunk: ``workers=N`` on a
``dask.distributed.LocalCluster(n_workers=N, threads_per_worker=1, processes=True)`` of its
own, ``scheduler=ADDRESS`` on an existing cluster (the mission, scene, cache and output paths
must then be visible to the workers under the same absolute paths). On Linux the local
cluster's workers are forked after the mission is prepared (they inherit it); elsewhere, and
on an existing cluster, each worker process prepares it once. :func:`executor_for` picks one.

Every executor runs a chunk task (:func:`.pipeline.run_chunk`) for each missing chunk and calls
``on_chunk()`` in this process after each one; the results are the same whichever runs them.

Test hook: the environment variable ``CHIRPLIDAR_TEST_CHUNK_DELAY_S`` (seconds, default 0) makes
a serial run, or a Dask worker (set in the worker's environment), sleep after each chunk file is
written, so that tests can kill a run, a worker or the scheduler between chunks reliably. It
changes no result.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
import uuid
import warnings
from pathlib import Path
from typing import Callable, Protocol

import numpy as np

from ..config.loader import ConfigError
from .faults import SchedulerLost
from .pipeline import ChunkJob
from .results import NETCDF_LOCK, ChunkWriter

CHUNK_DELAY_ENV = "CHIRPLIDAR_TEST_CHUNK_DELAY_S"

#: A chunk task: ``task(job, index, progress)`` computes chunk ``index`` of ``job`` and returns
#: its file; ``progress(n)``, when given, is called with finished shot-beams.
ChunkTask = Callable[..., Path]


class Executor(Protocol):
    """Runs a run's chunk tasks (one interface for serial and Dask runs).

    ``appends_while_running``: whether ``on_chunk`` may make netCDF/HDF5 calls while tasks
    still run (no task runs in a thread of this process). ``timings``: seconds spent starting
    and closing a cluster (``cluster_start_s``, ``cluster_close_s``), if any."""

    appends_while_running: bool
    timings: dict

    def run(self, task: ChunkTask, job: ChunkJob, todo: list[int], plan, *, progress=None,
            on_chunk=None) -> None:
        """``task(job, i)`` for every chunk ``i`` in ``todo`` (of ``plan``); ``progress``
        (a tqdm bar or None) follows the finished shot-beams, ``on_chunk()`` is called in this
        process after each chunk. Finished chunks stay when a task fails."""


def chunk_delay_s() -> float:
    """The test hook's delay after each chunk (seconds, 0 without it)."""
    raw = os.environ.get(CHUNK_DELAY_ENV, "").strip()
    if not raw:
        return 0.0
    try:
        delay = float(raw)
    except ValueError:
        delay = -1.0
    if not (math.isfinite(delay) and delay >= 0):
        raise ConfigError(f"{CHUNK_DELAY_ENV}={raw!r}: must be a number of seconds >= 0")
    return delay



class SerialExecutor:
    """The chunks one after the other, in this process."""

    appends_while_running = True

    def __init__(self):
        self.timings: dict = {}

    def run(self, task: ChunkTask, job: ChunkJob, todo: list[int], plan, *, progress=None,
            on_chunk=None) -> None:
        delay = chunk_delay_s()
        for i in todo:
            task(job, i, progress=progress.update if progress else None)
            if on_chunk is not None:
                on_chunk()
            if delay:
                time.sleep(delay)


def executor_for(workers: int | None, scheduler: str | None) -> Executor:
    """A :class:`SerialExecutor` without ``workers`` (or with 1) and ``scheduler``, else a
    :class:`DaskExecutor`."""
    if scheduler is None and (workers is None or workers == 1):
        return SerialExecutor()
    return DaskExecutor(workers=workers, scheduler=scheduler)


def check_parallel_args(workers, scheduler) -> None:
    """ValueError unless ``workers`` (an integer >= 1) and ``scheduler`` (an address) are valid
    and not both given."""
    if workers is not None and (isinstance(workers, (bool, np.bool_))
                                or not isinstance(workers, (int, np.integer)) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if scheduler is not None:
        if workers is not None:
            raise ValueError("workers and scheduler are exclusive: give one of them")
        if not isinstance(scheduler, str) or not scheduler.strip():
            raise ValueError(f"scheduler must be an address such as tcp://host:8786, "
                             f"got {scheduler!r}")


#: Freed memory that glibc's malloc may keep for reuse (its trim threshold), see
#: :func:`keep_freed_memory`.
MALLOC_KEEP_BYTES = 256 << 20
#: Blocks up to this size come from malloc's heap (reused), larger ones from mmap: glibc's
#: largest dynamic mmap threshold on 64-bit systems (DEFAULT_MMAP_THRESHOLD_MAX).
MALLOC_MMAP_THRESHOLD_BYTES = 32 << 20
_MALLOC_KEPT: list = []


def keep_freed_memory() -> None:
    """Let glibc's malloc keep up to ``MALLOC_KEEP_BYTES`` of freed memory in this process
    (and in the worker processes a local cluster forks from it), once per process.

    A chunk allocates and frees some 100 MB of arrays (demo mission). By default malloc hands
    freed memory back to the system and the next chunk takes it back page by page: measured
    on the demo, ~30 thousand page faults per serial run, and ~40 thousand per worker process
    in a 2-worker run (a Dask task runs in a thread, whose malloc arena returns memory more
    eagerly than the main one): 0.1-0.2 s of system time per process. Elsewhere than glibc
    (macOS, musl) nothing is changed.

    Setting the trim threshold stops glibc from raising its mmap threshold as large blocks are
    freed, so that threshold is set too (to ``MALLOC_MMAP_THRESHOLD_BYTES``, where glibc's own
    adjustment ends): left where this process's history had brought it, a call before any
    large block was freed kept it at 128 kB, and every array above that was mapped afresh in
    every chunk (measured: 35-50 thousand page faults and 0.55-0.75 s per demo chunk, against
    ~10 faults and 0.45-0.52 s).
    """
    if _MALLOC_KEPT:
        return
    _MALLOC_KEPT.append(True)
    import platform

    if platform.libc_ver()[0] != "glibc":
        return
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):   # pragma: no cover - glibc always has it
        return
    m_trim_threshold, m_mmap_threshold = -1, -3   # <malloc.h>: M_TRIM_/M_MMAP_THRESHOLD
    mallopt(ctypes.c_int(m_trim_threshold), ctypes.c_int(MALLOC_KEEP_BYTES))
    mallopt(ctypes.c_int(m_mmap_threshold), ctypes.c_int(MALLOC_MMAP_THRESHOLD_BYTES))


# ---------------------------------------------------------------------------- Dask
#: Our own local cluster runs one batch of chunk tasks with no dashboard: its housekeeping
#: would cost CPU that the chunks need (on 2 cores about a tenth of a core for the demo run):
#: no statistical profiler (10 ms samples of every worker), no work stealing (the tasks are
#: queued on the scheduler and handed out in chunk order as workers free up), and event-loop,
#: memory and system monitors every second instead of every 20-500 ms.
_LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
}


#: Seconds a run on a given scheduler waits for its first worker (environment override).
WORKER_WAIT_ENV = "CHIRPLIDAR_WORKER_WAIT_S"
WORKER_WAIT_S = 60.0


def worker_wait_s() -> float:
    """Seconds a run on a given scheduler waits for its first worker."""
    raw = os.environ.get(WORKER_WAIT_ENV, "").strip()
    if not raw:
        return WORKER_WAIT_S
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{WORKER_WAIT_ENV}={raw!r}: must be a positive number of seconds")
    return value



class DaskExecutor:
    """One Dask task per missing chunk, on a local cluster of ``workers`` processes or on the
    cluster of ``scheduler`` (see the module docstring). The progress bar follows completed
    futures and ``on_chunk()`` is called (in this process) as each one finishes. On an error or
    interrupt the other tasks are cancelled and the cluster closed; finished chunks stay. A lost
    ``scheduler`` raises :class:`.faults.SchedulerLost`."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None):
        self.workers, self.scheduler = workers, scheduler
        self.timings: dict = {}
        self._cluster = self._client = None

    @property
    def appends_while_running(self) -> bool:
        # Appending reads and writes netCDF files, and netCDF/HDF5 calls must not run in two
        # threads of a process at once: only while the chunks are computed in worker processes
        # of our own cluster; on a given scheduler, whose workers may be threads of this
        # process, at the end.
        return self.scheduler is None

    def run(self, task: ChunkTask, job: ChunkJob, todo: list[int], plan, *, progress=None,
            on_chunk=None) -> None:
        try:
            import dask.distributed  # noqa: F401
        except ImportError as exc:
            raise ConfigError(f"--workers/--scheduler need dask.distributed ({exc}); "
                              "pip install 'dask[distributed]'") from None
        t0 = time.perf_counter()
        self._cluster = self._client = None
        futures: list = []              # submitted so far (cancelled on an error)
        life = contextlib.ExitStack()   # settings held while our local cluster lives
        lost = False                    # the scheduler (--scheduler) is gone
        try:
            if self.scheduler is not None:
                self._connect()
            else:
                self._start_local_cluster(life)
            self.timings["cluster_start_s"] = time.perf_counter() - t0
            shots = self._submit(task, job, todo, plan, futures)
            self._gather(futures, shots, progress, on_chunk)
            if self._cluster is not None:
                # Every chunk is in: our workers' shutdown can only log noise now (a heartbeat
                # in flight as the cluster closes logs a traceback, dask/distributed#7105; seen
                # about once in 50 runs). Never worth failing a finished run for.
                with contextlib.suppress(Exception):
                    self._client.run(_quiet_worker_logs)
        except BaseException as exc:
            lost = isinstance(exc, SchedulerLost)
            if self._client is not None and futures and not lost:
                self._cancel(futures)
            raise
        finally:
            self._close(life, lost)

    def _connect(self) -> None:
        """A client of ``scheduler``, once a worker has joined it (ConfigError otherwise)."""
        from dask.distributed import Client

        scheduler = self.scheduler
        try:
            self._client = Client(scheduler)   # dask's distributed.comm.timeouts.connect
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        wait = worker_wait_s()
        try:   # a scheduler with no worker would wait for ever, without a word
            self._client.wait_for_workers(1, timeout=wait)
        except (TimeoutError, OSError):
            raise ConfigError(f"--scheduler {scheduler}: no worker joined within {wait:g} s "
                              f"({WORKER_WAIT_ENV}); start workers (`dask worker "
                              f"{scheduler}`), then rerun with --resume") from None

    def _start_local_cluster(self, life: contextlib.ExitStack) -> None:
        """Our own local cluster of ``workers`` processes and its client; ``life`` holds the
        settings it needs until it is closed."""
        import dask
        from dask.distributed import Client, LocalCluster

        # Linux: fork the worker processes from this one, after prepare(): they inherit the
        # imported modules and the prepared mission (configuration, scene, plan) in the
        # cache of pipeline.prepared_mission, instead of paying both again per worker.
        method = "fork" if sys.platform.startswith("linux") else \
            dask.config.get("distributed.worker.multiprocessing-method")
        # (Python >= 3.12 warns about fork in a process with threads: the cluster's own
        # event-loop thread is one; the workers start single-threaded from the forking one.)
        # Held for the cluster's whole life, not only its start: a worker that dies is
        # started again by its nanny, with the settings of that moment (spawned instead of
        # forked, it would prepare the mission again, and its multiprocessing
        # resource_tracker printed tracebacks as the cluster closed).
        life.enter_context(dask.config.set({
            "distributed.worker.multiprocessing-method": method, **_LOCAL_CLUSTER_CONFIG}))
        life.enter_context(warnings.catch_warnings())
        warnings.filterwarnings("ignore", message=r".*use of fork\(\) may lead to",
                                category=DeprecationWarning)
        life.enter_context(_forks_wait_for_netcdf())
        # (forked workers inherit it: their report of a failed chunk, with its traceback,
        # is the error this process raises and reports itself, in one line)
        life.enter_context(_log_filter("distributed.worker", _no_compute_failed))
        self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1,
                                     processes=True, dashboard_address=None)
        self._client = Client(self._cluster)

    def _submit(self, task: ChunkTask, job: ChunkJob, todo: list[int], plan,
                futures: list) -> dict:
        """One task per chunk of ``todo``, its future appended to ``futures``; returns the
        shot-beams of each future's key."""
        token = uuid.uuid4().hex[:12]
        shots = {}
        for i in todo:
            # priority: chunks start in chunk order, so that they can be appended as they end
            fut = self._client.submit(run_in_worker, task, job, i,
                                      key=f"chirplidar-chunk-{token}-{i:05d}", pure=False,
                                      retries=0, priority=-i)
            shots[fut.key] = plan.chunk_times(i).size * plan.beams.n_beams
            futures.append(fut)
        return shots

    def _gather(self, futures: list, shots: dict, progress, on_chunk) -> None:
        """Wait for the futures as they complete (a worker's error re-raised as is)."""
        from dask.distributed import as_completed

        try:
            for fut in as_completed(futures):
                fut.result()   # re-raises a worker's error (ConfigError, ValueError, ...) as is
                if progress:
                    progress.update(shots[fut.key])
                if on_chunk is not None:
                    on_chunk()
        except Exception as exc:
            if self.scheduler is not None and _scheduler_lost(self._client, exc):
                raise SchedulerLost(self.scheduler) from exc
            raise

    def _cancel(self, futures: list) -> None:
        """Cancel the run's futures after an error (quietly, on our own workers)."""
        try:
            if self._cluster is not None:   # our workers: their tasks' cancellation is no news
                self._client.run(_quiet_worker_logs)
            self._client.cancel(futures)
        except Exception:  # noqa: BLE001, S110 - closing anyway; the original error matters
            pass

    def _close(self, life: contextlib.ExitStack, lost: bool) -> None:
        """Close the client, our cluster and its settings."""
        t1 = time.perf_counter()
        if self._client is not None:
            # With the scheduler lost, the client is trying to reconnect: closing it stops that,
            # and distributed logs the stop as an error with its traceback. The run reports the
            # loss itself, in one line.
            with _logs_muted("distributed.client") if lost else contextlib.nullcontext():
                self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        life.close()
        self._cluster = self._client = None
        self.timings["cluster_close_s"] = time.perf_counter() - t1


def run_in_worker(task: ChunkTask, job: ChunkJob, index: int) -> str:
    """``task(job, index)`` (:func:`.pipeline.run_chunk`) in a Dask worker, the path back as a
    string.

    No thread limit is set here: a chunk's kernels are single-threaded numpy, scipy FFTs (one
    worker thread by default) and embree queries (a serial run of the demo uses one core), and
    spawned Dask workers start with OMP/MKL/OPENBLAS_NUM_THREADS=1 anyway.

    xarray, asked to write a file inside a Dask worker, would guard every netCDF call with a
    cluster-wide lock (one round trip to the scheduler each: hundreds per chunk file, measured
    ~25 % of a chunk's time on the demo). Each chunk is its own file, so chunks run under
    the synchronous scheduler: xarray then takes a lock local to this process. (Worker threads
    of one process write their chunk files one at a time: :data:`.results.NETCDF_LOCK`.)
    """
    # Dask computes a finished task again when the worker holding its result dies: a chunk
    # already sealed for this run is not written again (the merge may be reading it, and its
    # seal would be missing while it is rewritten).
    writer = ChunkWriter(job.chunk_dir, create=False, run_id=job.run_id)
    with contextlib.suppress(ValueError):   # (a bad index: the task says why)
        if writer.is_ready(index) and writer.chunk_problem(index) is None:
            return str(writer.chunk_path(index))
    with _synchronous_dask():
        path = str(task(job, index))
    delay = chunk_delay_s()   # the test hook, as in a serial run
    if delay:
        time.sleep(delay)
    return path


_SYNC_LOCK = threading.Lock()
_SYNC_STATE: dict = {"users": 0, "config": None}


@contextlib.contextmanager
def _synchronous_dask():
    """``dask.config.set(scheduler="synchronous")`` while any chunk of this process runs.

    dask's configuration is global to the process, so with several worker threads a plain
    ``with dask.config.set(...)`` per task could restore the setting out of order; the first
    chunk in sets it and the last one out restores the previous configuration."""
    import dask

    with _SYNC_LOCK:
        if _SYNC_STATE["users"] == 0:
            _SYNC_STATE["config"] = dask.config.set(scheduler="synchronous")
        _SYNC_STATE["users"] += 1
    try:
        yield
    finally:
        with _SYNC_LOCK:
            _SYNC_STATE["users"] -= 1
            if _SYNC_STATE["users"] == 0:
                _SYNC_STATE["config"].__exit__(None, None, None)
                _SYNC_STATE["config"] = None


_FORK_GUARD = {"clusters": 0, "held": 0}


def _fork_before() -> None:
    if _FORK_GUARD["clusters"]:
        NETCDF_LOCK.acquire()
        _FORK_GUARD["held"] += 1


def _fork_after() -> None:
    if _FORK_GUARD["held"]:
        _FORK_GUARD["held"] -= 1
        with contextlib.suppress(RuntimeError):
            NETCDF_LOCK.release()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_fork_before, after_in_parent=_fork_after,
                        after_in_child=_fork_after)


@contextlib.contextmanager
def _forks_wait_for_netcdf():
    """While our local cluster lives, a worker process its nanny forks (to replace one that
    died) waits for this process's netCDF/HDF5 call in flight (the results file is appended to
    while the workers compute): forked in the middle of one, the worker would inherit
    :data:`.results.NETCDF_LOCK` held by a thread it does not have, and wait for ever to write
    its chunk."""
    _FORK_GUARD["clusters"] += 1
    try:
        yield
    finally:
        _FORK_GUARD["clusters"] -= 1


@contextlib.contextmanager
def _logs_muted(*names: str):
    """The loggers ``names`` quiet below CRITICAL for the block."""
    import logging

    loggers = [logging.getLogger(name) for name in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _scheduler_lost(client, exc: BaseException) -> bool:
    """Whether ``exc``, raised while a run's futures complete, means that the scheduler is gone:
    the client no longer runs (it cancels every future, "scheduler-connection-lost", and tries
    to reconnect) or its connection closed."""
    from distributed.comm.core import CommClosedError

    return (client.status != "running" or isinstance(exc, CommClosedError)
            or "scheduler-connection-lost" in str(exc))


def _no_compute_failed(record) -> bool:
    """A logging filter: not a Dask worker's "Compute Failed" report."""
    return not str(record.msg).startswith("Compute Failed")


@contextlib.contextmanager
def _log_filter(name: str, keep):
    """The logger ``name`` passes only the records for which ``keep(record)`` holds, for the
    block."""
    import logging

    logger = logging.getLogger(name)
    logger.addFilter(keep)
    try:
        yield
    finally:
        logger.removeFilter(keep)


def _quiet_worker_logs() -> None:
    """In a worker of our local cluster, at the end of a run: its log stays quiet below
    CRITICAL while it shuts down."""
    import logging

    for name in ("distributed.worker", "distributed.core", "distributed.comm"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
