"""A Dask cluster of separate processes on 127.0.0.1, as other machines would run it: a
scheduler and two workers started with dask's own command lines, a ``chirplidar run
--scheduler`` on it, and one worker killed (SIGKILL) while it holds a chunk (issue 19).

Reference: the serial run of the same mission and seed, whose file the cluster's must equal
byte for byte in data, attributes and layout (DESIGN.md: "Same seed, same output, serial or
parallel").

The workers run without a nanny: a nanny would start a killed worker again, whereas here the
scheduler must hand the lost chunk to the other worker. A preload module (``_PRELOAD``, given
to ``dask worker --preload``) wraps each worker's chunk task: it records which process starts
and finishes each chunk, and holds the first attempt at chunk ``HOLD`` before any of its work,
so that the kill lands in the middle of the run with that chunk not yet written, every time.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import identical_files, write_small_uav

import chirplidar
from chirplidar.mission.manifest import chunk_dir_for
from chirplidar.mission.results import ChunkWriter
from chirplidar.mission.runner import run_mission

pytest.importorskip("distributed")

DATE = "2026-01-01T00:00:00Z"      # the serial run's date_created ...
DATE_EPOCH = "1767225600"          # ... the same instant as SOURCE_DATE_EPOCH for the CLI run
N_CHUNKS = 6                       # write_small_uav: 3000 shots in chunks of 500
HOLD = 2                           # the chunk whose worker is killed
MARKS_ENV, HOLD_ENV = "CHIRPLIDAR_TEST_MARKS", "CHIRPLIDAR_TEST_HOLD_CHUNK"
WAIT_S = 120.0                     # generous: every wait ends as soon as its event happens

_PRELOAD = f'''
"""Preloaded by each test worker: its chunk task records starts and ends, and holds the first
attempt at chunk ${HOLD_ENV} until the test kills this process."""
import os
import time
from pathlib import Path

from chirplidar.mission import pipeline

MARKS = Path(os.environ["{MARKS_ENV}"])
HOLD = int(os.environ["{HOLD_ENV}"])
# (dask may run this file twice in one worker: wrap the real task once)
_real_run_chunk = getattr(pipeline.run_chunk, "held_task", pipeline.run_chunk)


def run_chunk(job, index, progress=None):
    pid = os.getpid()
    (MARKS / f"start-{{index}}-{{pid}}").touch()
    if index == HOLD:
        try:
            os.mkdir(MARKS / "held")          # atomic: only the first attempt holds
        except FileExistsError:
            pass
        else:
            tmp = MARKS / "held" / "pid.tmp"
            tmp.write_text(str(pid))
            tmp.rename(MARKS / "held" / "pid")
            time.sleep(600)                   # killed long before this ends
    path = _real_run_chunk(job, index, progress)
    (MARKS / f"done-{{index}}-{{pid}}").touch()
    return path


run_chunk.held_task = _real_run_chunk
# The client ships the task by reference (module and name): this worker unpickles this one.
pipeline.run_chunk = run_chunk
'''


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cluster")
    mission = write_small_uav(tmp)
    cache = tmp / "cache"
    res = run_mission(mission, out=tmp / "serial.nc", cache_dir=cache, date_created=DATE)
    assert res.summary["shots"] == 3000
    return mission, cache, res.path


def _start(argv, env, log: Path) -> subprocess.Popen:
    # output to a file, not a pipe: a full pipe would stall the process
    with open(log, "w") as fh:
        return subprocess.Popen(argv, env=env, stdout=fh, stderr=subprocess.STDOUT)


def _wait_for(what: str, probe, procs):
    """``probe()`` until it returns something other than None (or fail, naming ``what``,
    after WAIT_S or when one of ``procs`` has ended)."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        got = probe()
        if got is not None:
            return got
        ended = [p.args for p in procs if p.poll() is not None]
        if ended:
            pytest.fail(f"waiting for {what}: {ended} ended")
        time.sleep(0.05)
    pytest.fail(f"no {what} within {WAIT_S:g} s")


def _scheduler_address(path: Path):
    try:
        return json.loads(path.read_text())["address"]
    except (OSError, ValueError, KeyError):   # not written yet, or half written
        return None


def _held_pid(marks: Path):
    try:
        return int((marks / "held" / "pid").read_text())
    except (OSError, ValueError):
        return None


def _stop(proc: subprocess.Popen) -> None:
    """A test's process never outlives it."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=30)


def _marks(marks: Path, kind: str) -> list[tuple[int, int]]:
    """(chunk, pid) of the ``kind`` ("start" or "done") marks, sorted."""
    return sorted((int(p.name.split("-")[1]), int(p.name.split("-")[2]))
                  for p in marks.glob(f"{kind}-*"))


def _worker_pids(address: str, n: int) -> dict:
    """{worker address: pid} once ``n`` workers have joined the scheduler at ``address``."""
    from dask.distributed import Client

    with Client(address, timeout=WAIT_S) as client:
        client.wait_for_workers(n, timeout=WAIT_S)
        return client.run(os.getpid)


def test_run_on_separate_processes_survives_a_killed_worker(serial, tmp_path):
    mission, cache, serial_path = serial
    marks = tmp_path / "marks"
    marks.mkdir()
    preload = tmp_path / "hold_chunk.py"
    preload.write_text(_PRELOAD)
    src = str(Path(chirplidar.__file__).resolve().parents[1])   # this chirplidar, everywhere
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
               [src, *filter(None, [os.environ.get("PYTHONPATH")])]),
           "CHIRPLIDAR_CACHE": str(cache), "SOURCE_DATE_EPOCH": DATE_EPOCH,
           MARKS_ENV: str(marks), HOLD_ENV: str(HOLD)}
    out = tmp_path / "cluster.nc"
    chunks = chunk_dir_for(out)
    procs: list[subprocess.Popen] = []
    try:
        scheduler_file = tmp_path / "scheduler.json"
        procs.append(_start([sys.executable, "-m", "distributed.cli.dask_scheduler",
                             "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                             "--scheduler-file", str(scheduler_file)],
                            env, tmp_path / "scheduler.log"))
        address = _wait_for("scheduler file", lambda: _scheduler_address(scheduler_file),
                            procs)
        workers = [_start([sys.executable, "-m", "distributed.cli.dask_worker", address,
                           "--host", "127.0.0.1", "--nthreads", "1", "--nworkers", "1",
                           "--no-nanny", "--no-dashboard", "--death-timeout", "60",
                           "--preload", str(preload), "--name", f"w{k}"],
                          env, tmp_path / f"worker{k}.log") for k in range(2)]
        procs += workers
        pids = _worker_pids(address, 2)
        assert sorted(pids.values()) == sorted(w.pid for w in workers)   # no nanny between

        run = _start([sys.executable, "-m", "chirplidar.cli", "run", str(mission),
                      "--out", str(out), "--no-progress", "--scheduler", address],
                     env, tmp_path / "run.log")
        procs.append(run)
        held = _wait_for(f"a worker holding chunk {HOLD}", lambda: _held_pid(marks), procs)
        victim = next(w for w in workers if w.pid == held)
        written = ChunkWriter(chunks, create=False).completed_chunks()
        assert HOLD not in written and len(written) < N_CHUNKS, written   # part way
        victim.send_signal(signal.SIGKILL)
        victim.wait(timeout=30)
        assert victim.returncode == -signal.SIGKILL

        code = run.wait(timeout=4 * WAIT_S)
        log = (tmp_path / "run.log").read_text()
        assert code == 0, log
        assert "chirplidar run: 3000 shots" in log and "Traceback" not in log, log
    finally:
        for proc in reversed(procs):
            _stop(proc)

    identical_files(out, serial_path)
    assert not chunks.exists()
    survivor = next(w.pid for w in workers if w.pid != held)
    done = _marks(marks, "done")
    assert sorted(c for c, _ in done) == list(range(N_CHUNKS))   # every chunk once
    assert (HOLD, survivor) in done                               # the lost one recomputed
    assert [p for c, p in _marks(marks, "start") if c == HOLD] == sorted([held, survivor])
