"""Faults of a run reported in one line, not dumped (issue 15, item 5): a full disk while a
chunk, the manifest or the results file is written; folders and files without permission; the
Dask scheduler lost mid-run; Dask workers killed mid-run; any other error of ``run``.

Every fault keeps what is already written (sealed chunks), leaves nothing that blocks the next
run, and ``--resume`` then writes the same bytes as an uninterrupted run (the reference:
``small.serial``, the serial run of the same mission, seed and creation date).
"""

from __future__ import annotations

import ctypes
import errno
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from chirplidar.cli import main
from chirplidar.mission import runner
from chirplidar.mission.executors import CHUNK_DELAY_ENV
from chirplidar.mission.manifest import MANIFEST_NAME, chunk_dir_for
from chirplidar.mission.results import merge

import test_run_scale
from test_run_scale import DATE_EPOCH, _interrupted, _reap

small = test_run_scale.small   # the fixture: the small mission and its serial run

_Usage = namedtuple("_Usage", "total used free")


@pytest.fixture
def env(small, monkeypatch):
    """The command line's environment of the reference run (cache, creation date)."""
    values = {"CHIRPLIDAR_CACHE": str(small.cache), "SOURCE_DATE_EPOCH": DATE_EPOCH}
    for k, v in values.items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("CHIRPLIDAR_DEBUG", raising=False)
    return values


def _args(mission, out, *more):
    return ["run", str(mission), "--out", str(out), "--no-progress", *more]


def _one_line(err: str) -> str:
    """The only line of ``err`` (a fault's report), with no traceback."""
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def _leftovers(*folders) -> list[str]:
    """Temp files of writes and locks left in ``folders``: none may block or clutter."""
    return sorted(p.name for d in folders if d.is_dir() for p in d.iterdir()
                  if p.name.endswith((".tmp", ".lock")))


def _sealed(chunks: Path) -> list[int]:
    return sorted(int(p.stem[6:]) for p in chunks.glob("chunk_*.json")
                  if p.with_suffix(".nc").is_file()) if chunks.is_dir() else []


def _same_bytes(path, reference) -> None:
    digest = [hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in (path, reference)]
    assert digest[0] == digest[1], f"{path} differs from {reference}"


# ---------------------------------------------------------------------------- disk full
# Injected: the write itself fails as the OS (errno ENOSPC) or netCDF/HDF5 ("NetCDF: HDF
# error", no errno: then only the free space tells) report a full disk.
def _enospc(_path):
    return OSError(errno.ENOSPC, "No space left on device")


def _hdf_runtime(_path):
    return RuntimeError("NetCDF: HDF error")


def _hdf_oserror(_path):
    return OSError("NetCDF: HDF error")


def _fail_chunk_write(monkeypatch, make_error, index=2):
    """The netCDF write of chunk ``index`` writes a little, then fails."""
    real = xr.Dataset.to_netcdf

    def failing(self, path=None, *args, **kwargs):
        if path is not None and Path(path).name.startswith(f".chunk_{index:05d}.nc."):
            Path(path).write_bytes(b"CDF partial")
            raise make_error(path)
        return real(self, path, *args, **kwargs)

    monkeypatch.setattr(xr.Dataset, "to_netcdf", failing)


def _fail_manifest_write(monkeypatch, make_error):
    real = Path.write_bytes

    def failing(self, data):
        if self.name.startswith(f".{MANIFEST_NAME}."):
            real(self, data[: len(data) // 2])
            raise make_error(self)
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", failing)


def _fail_merge_append(monkeypatch, make_error, index=3, chunk_shots=500):
    """The results file's append of chunk ``index`` fails (h5py's errors carry no file name)."""
    real = merge._copy_hdf5_variable

    def failing(src, dst, axis, start, last, record=None):
        if start == index * chunk_shots:
            raise make_error(None)
        return real(src, dst, axis, start, last, record)

    monkeypatch.setattr(merge, "_copy_hdf5_variable", failing)


_STAGES = {   # stage -> (inject, the file named, sealed chunks kept)
    "chunk": (_fail_chunk_write, lambda out: chunk_dir_for(out) / "chunk_00002.nc", [0, 1]),
    "manifest": (_fail_manifest_write, lambda out: chunk_dir_for(out) / MANIFEST_NAME, []),
    "merge": (_fail_merge_append, lambda out: out, [0, 1, 2, 3]),
}


@pytest.mark.parametrize("make_error", [_enospc, _hdf_runtime, _hdf_oserror],
                         ids=["errno", "hdf-runtime", "hdf-oserror"])
@pytest.mark.parametrize("stage", list(_STAGES))
def test_disk_full_is_one_line_and_resume_is_exact(small, env, tmp_path, monkeypatch, capsys,
                                                   stage, make_error):
    inject, named, kept = _STAGES[stage]
    out = tmp_path / "full.nc"
    chunks = chunk_dir_for(out)
    with monkeypatch.context() as m:
        inject(m, make_error)
        if make_error is not _enospc:   # the disk is full: the only sign of a library error
            m.setattr(shutil, "disk_usage", lambda p: _Usage(1 << 30, 1 << 30, 0))
        assert main(_args(small.mission, out)) == 74
    line = _one_line(capsys.readouterr().err)
    assert f"cannot write {named(out)}: no space left on device" in line, line
    assert not out.exists() and _leftovers(tmp_path, chunks) == []
    assert _sealed(chunks) == kept                  # nothing already written is lost
    if kept:
        assert f"{len(kept)} of 6 chunks done and kept in {chunks}" in line
        assert "run again with --resume" in line
    else:                                           # no empty folder to block the next run
        assert not chunks.exists()
    assert main(_args(small.mission, out, "--resume")) == 0
    _same_bytes(out, small.serial.path)
    assert not chunks.exists()


def test_a_library_error_with_free_space_is_not_called_disk_full(small, env, tmp_path,
                                                                 monkeypatch, capsys):
    """The same "NetCDF: HDF error" on a disk with space left is what it is: one line naming
    it (exit 1), the finished chunks kept."""
    out = tmp_path / "hdf.nc"
    with monkeypatch.context() as m:
        _fail_chunk_write(m, _hdf_runtime)
        m.setattr(shutil, "disk_usage", lambda p: _Usage(1 << 40, 1 << 30, 1 << 39))
        assert main(_args(small.mission, out)) == 1
    line = _one_line(capsys.readouterr().err)
    assert line == ("chirplidar run: failed: RuntimeError: NetCDF: HDF error "
                    "(CHIRPLIDAR_DEBUG=1 prints the traceback)"), line
    assert "no space" not in line
    assert _sealed(chunk_dir_for(out)) == [0, 1]
    assert main(_args(small.mission, out, "--resume")) == 0
    _same_bytes(out, small.serial.path)


# A real full disk: a small tmpfs (root only), filled at the chosen moment by a hook in a
# subprocess, so that netCDF, HDF5 and h5py meet ENOSPC themselves.
_FILL_DRIVER = r"""
import os, sys
from pathlib import Path
from chirplidar.mission import manifest, runner
from chirplidar.cli import main

stage, mount, argv = sys.argv[1], Path(sys.argv[2]), sys.argv[3:]

def fill():
    fd = os.open(mount / "filler", os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    try:
        for size in (1 << 16, 1 << 12, 1):
            while True:
                try:
                    os.write(fd, b"\0" * size)
                except OSError:
                    break
    finally:
        os.close(fd)

real_chunk, real_manifest = runner.run_chunk, manifest.write_manifest

def run_chunk(job, index, progress=None):
    if stage == "chunk" and index == 2:
        fill()                                     # chunk 2's file cannot be written
    path = real_chunk(job, index, progress)
    if stage == "merge" and index == 2:
        fill()                                     # its append to the results file cannot
    return path

def write_manifest(chunk_dir, manifest):
    if stage == "manifest":
        fill()
    return real_manifest(chunk_dir, manifest)

runner.run_chunk, manifest.write_manifest = run_chunk, write_manifest
if stage == "lock":
    fill()
sys.exit(main(argv))
"""


@pytest.fixture
def tmpfs(tmp_path):
    """A 16 MB tmpfs (skipped where this process may not mount one)."""
    mount = tmp_path / "fs"
    mount.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(mount)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True, check=False)


@pytest.mark.parametrize("stage, named, kept", [
    ("lock", lambda out: out.with_name(out.name + ".lock"), []),
    ("manifest", lambda out: chunk_dir_for(out) / MANIFEST_NAME, []),
    ("chunk", lambda out: chunk_dir_for(out) / "chunk_00002.nc", [0, 1]),
    ("merge", lambda out: out, [0, 1, 2]),
])
def test_real_full_disk(small, env, tmpfs, stage, named, kept):
    out = tmpfs / "o.nc"
    chunks = chunk_dir_for(out)
    proc = subprocess.run([sys.executable, "-c", _FILL_DRIVER, stage, str(tmpfs),
                           *_args(small.mission, out)], capture_output=True, text=True,
                          timeout=300, env={**os.environ, **env}, check=False)
    assert proc.returncode == 74, proc.stderr
    line = _one_line(proc.stderr)                   # no traceback, no HDF5 error stack, no crash
    assert f"cannot write {named(out)}: no space left on device" in line, line
    assert _leftovers(tmpfs, chunks) == [] and not out.exists()
    assert _sealed(chunks) == kept
    if not kept:
        assert not chunks.exists()
    (tmpfs / "filler").unlink()                     # space again
    assert main(_args(small.mission, out, "--resume")) == 0
    _same_bytes(out, small.serial.path)


def test_real_full_disk_with_workers(small, env, tmpfs):
    """--workers 2: the worker that computes chunk 2 fills the disk (the driver's hook, forked
    with it). Whichever write meets the full disk first -- a chunk in a worker or the results
    file here -- is the one line; the workers' own reports of the failed chunk are not shown."""
    out = tmpfs / "o.nc"
    chunks = chunk_dir_for(out)
    proc = subprocess.run([sys.executable, "-c", _FILL_DRIVER, "chunk", str(tmpfs),
                           *_args(small.mission, out, "--workers", "2")], capture_output=True,
                          text=True, timeout=300, env={**os.environ, **env}, check=False)
    assert proc.returncode == 74, proc.stderr
    line = _one_line(proc.stderr)
    assert line.startswith(f"chirplidar run: cannot write {tmpfs}/o.nc"), line
    assert ": no space left on device; " in line and "--resume" in line
    assert _leftovers(tmpfs) == [] and not out.exists()
    if " chunks done and kept in " in line:        # (the chunks 0, 1 may end after 2 starts)
        k = int(line.split("; ")[1].split()[0])
        assert len(_sealed(chunks)) == k >= 1, line
    else:
        assert "no chunk was finished" in line and not chunks.exists()
    (tmpfs / "filler").unlink()
    assert main(_args(small.mission, out, "--resume")) == 0
    _same_bytes(out, small.serial.path)


# ---------------------------------------------------------------------------- permissions
def _drop_dac_override():   # pragma: no cover - runs in the child before exec
    """Root without CAP_DAC_OVERRIDE / CAP_DAC_READ_SEARCH: file permissions apply to it."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):
        if libc.prctl(24, cap, 0, 0, 0) != 0:   # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


@pytest.fixture(scope="module")
def as_user(tmp_path_factory):
    """Popen keywords under which file permissions apply (root drops its override)."""
    secret = tmp_path_factory.mktemp("perm") / "secret"
    secret.write_text("x")
    secret.chmod(0)
    if os.geteuid() != 0:
        return {}
    try:
        probe = subprocess.run(["cat", str(secret)], preexec_fn=_drop_dac_override,
                               capture_output=True, check=False)
    except (OSError, subprocess.SubprocessError):
        probe = None
    if probe is None or probe.returncode == 0:
        pytest.skip("running as root, and cannot drop CAP_DAC_OVERRIDE")
    return {"preexec_fn": _drop_dac_override}


def _run_cli(args, env, as_user):
    return subprocess.run([sys.executable, "-m", "chirplidar.cli", *args], capture_output=True,
                          text=True, timeout=300, env={**os.environ, **env}, check=False,
                          **as_user)


def test_unwritable_output_folder_is_refused_before_any_work(small, env, as_user, tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    # a mission that would fail as it is prepared: the folder is checked before
    proc = _run_cli(_args(small.mission, folder / "o.nc", "--set", "survey.chunk_shots=0"),
                    env, as_user)
    assert proc.returncode == 2, proc.stderr
    assert _one_line(proc.stderr) == (f"chirplidar run: --out {folder / 'o.nc'}: cannot write "
                                      f"in {folder}: permission denied (nothing was run)")
    assert list(folder.iterdir()) == []


@pytest.mark.parametrize("option", ["--resume", "--overwrite"])
def test_unwritable_chunk_folder_is_refused_and_kept(small, env, as_user, tmp_path,
                                                     monkeypatch, option):
    out, chunks = _interrupted(small, tmp_path, monkeypatch, after=3)
    before = {p.name: p.read_bytes() for p in chunks.iterdir()}
    chunks.chmod(0o500)
    try:
        proc = _run_cli(_args(small.mission, out, option), env, as_user)
    finally:
        chunks.chmod(0o755)
    assert proc.returncode == 2, proc.stderr
    assert _one_line(proc.stderr) == (f"chirplidar run: {option}: cannot write in {chunks}: "
                                      "permission denied (nothing was run)")
    assert {p.name: p.read_bytes() for p in chunks.iterdir()} == before
    assert _leftovers(tmp_path) == [] and not out.exists()
    assert main(_args(small.mission, out, "--resume")) == 0   # writable again: nothing lost
    _same_bytes(out, small.serial.path)


def _dem_mission(tmp_path) -> tuple[Path, Path]:
    rasterio = pytest.importorskip("rasterio")
    from conftest import write_uav_mission
    from rasterio.transform import Affine

    from chirplidar.geometry import frames

    x0, y0 = frames.geodetic_to_projected(69.0, -49.0, 0.0, 3413)[:2]
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", height=50, width=50, count=1,
                       dtype="float32", crs="EPSG:3413",
                       transform=Affine(40.0, 0.0, float(x0) - 1000.0, 0.0, -40.0,
                                        float(y0) + 1000.0)) as dst:
        dst.write(np.full((50, 50), 100.0, np.float32), 1)
    scene = tmp_path / "dem_scene.toml"
    scene.write_text('name = "dem"\nepsg = 3413\neffects = []\n[terrain]\nsource = "dem"\n'
                     '[terrain.dem]\npath = "dem.tif"\nmaterial = "snow"\n[atmosphere]\n'
                     'cn2_profile = "none"\nextinction_per_m = 0.0\nscale_height_m = 1200.0\n')
    mission = write_uav_mission(tmp_path, scene, "dem_uav", altitude=600.0,
                                waypoints="[[-800.0, 0.0], [800.0, 0.0]]", stop="2.0")
    return mission, dem


@pytest.mark.parametrize("which", ["mission", "scene", "dem"])
def test_unreadable_input_is_one_line_exit_2(small, env, as_user, tmp_path, which):
    if which == "dem":
        mission, unreadable = _dem_mission(tmp_path)
    else:
        scene = tmp_path / "scene.toml"
        shutil.copy(small.tmp / "scene.toml", scene)
        mission = tmp_path / "m.toml"
        mission.write_text(small.mission.read_text())
        unreadable = mission if which == "mission" else scene
    unreadable.chmod(0)
    out = tmp_path / "o.nc"
    proc = _run_cli(_args(mission, out), env, as_user)
    assert proc.returncode == 2, proc.stderr
    line = _one_line(proc.stderr)
    assert unreadable.name in line and "permission denied" in line.lower(), line
    assert not out.exists() and not chunk_dir_for(out).exists() and _leftovers(tmp_path) == []


# ---------------------------------------------------------------------------- Dask
def _children(pid: int) -> list:
    import psutil

    try:
        return psutil.Process(pid).children()
    except psutil.NoSuchProcess:
        return []


def _cmdline(proc) -> str:
    import psutil

    try:
        return " ".join(proc.cmdline())
    except psutil.Error:
        return ""


def _wait_for(condition, proc, what: str, timeout=120.0, may_end=False):
    """Poll ``condition()`` (hang guard ``timeout``); the run ``proc`` must still be running
    (unless ``may_end``)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        if proc.poll() is not None:
            if may_end:
                return
            pytest.fail(f"the run ended before {what}: {proc.communicate()}")
        time.sleep(0.02)
    pytest.fail(f"no {what} within {timeout:g} s")


def _start(args, env, log):
    return subprocess.Popen([sys.executable, *args], env={**os.environ, **env},
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def _stop(proc) -> None:
    """A scheduler or worker started by a test (in a session of its own: with its nanny's
    worker process) killed."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def test_scheduler_lost_mid_run(small, env, tmp_path):
    """The scheduler is killed after the first chunk is sealed: one line naming it and the
    chunks kept (exit 1), no traceback; --resume (serial) finishes the file exactly."""
    sched_file = tmp_path / "scheduler.json"
    out = tmp_path / "s.nc"
    chunks = chunk_dir_for(out)
    with open(tmp_path / "dask.log", "w") as log:
        scheduler = _start(["-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                            "--port", "0", "--no-dashboard", "--scheduler-file",
                            str(sched_file)], {}, log)
        worker = run = None
        try:
            deadline = time.monotonic() + 120
            while not sched_file.is_file() or not sched_file.read_text().strip():
                assert scheduler.poll() is None and time.monotonic() < deadline, "no scheduler"
                time.sleep(0.05)
            address = json.loads(sched_file.read_text())["address"]
            # the worker sleeps 1 s after each chunk: the kill lands mid-run (the run waits
            # for it to join)
            worker = _start(["-m", "distributed.cli.dask_worker", "--scheduler-file",
                             str(sched_file), "--nthreads", "1", "--nworkers", "1",
                             "--no-dashboard"], {**env, CHUNK_DELAY_ENV: "1"}, log)
            run = subprocess.Popen([sys.executable, "-m", "chirplidar.cli",
                                    *_args(small.mission, out, "--scheduler", address)],
                                   env={**os.environ, **env}, stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True)
            _wait_for(lambda: len(_sealed(chunks)) >= 1, run, "sealed chunk")
            scheduler.send_signal(signal.SIGKILL)
            _, err = run.communicate(timeout=120)
        finally:
            if run is not None:
                _reap(run)
            for p in (worker, scheduler):
                if p is not None:
                    _stop(p)
    assert run.returncode == 1, err
    line = _one_line(err)
    head = f"chirplidar run: lost the Dask scheduler at {address} after "
    assert line.startswith(head), line
    k = int(line[len(head):].split()[0])
    assert line == (f"{head}{k} of 6 chunks; the finished chunks are kept in {chunks}: run "
                    "again with --resume")
    assert 1 <= k < 6 and len(_sealed(chunks)) >= k and not out.exists()
    assert main(_args(small.mission, out, "--resume")) == 0
    _same_bytes(out, small.serial.path)


def test_killed_workers_recover_without_tracebacks(small, env, tmp_path):
    """--workers 2: one worker killed (SIGKILL) after the first chunk is sealed, then every
    process the run has started. Each nanny starts its worker again, forked like the first ones:
    before, a restarted worker was spawned with a multiprocessing resource_tracker, whose
    death printed a KeyError traceback per tracked semaphore. The run finishes (exit 0), with
    the serial run's bytes and no traceback."""
    out = tmp_path / "w.nc"
    run = subprocess.Popen([sys.executable, "-m", "chirplidar.cli",
                            *_args(small.mission, out, "--workers", "2")],
                           env={**os.environ, **env, CHUNK_DELAY_ENV: "1"},
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen, killed = {}, set()

    def look():
        for c in _children(run.pid):
            seen.setdefault(c.pid, _cmdline(c))
        return [c for c in _children(run.pid) if c.pid not in killed]

    def kill(victims):
        for c in victims:
            killed.add(c.pid)
            c.send_signal(signal.SIGKILL)

    try:
        _wait_for(lambda: len(_sealed(chunk_dir_for(out))) >= 1 and len(look()) >= 2, run,
                  "sealed chunk")
        kill(look()[:1])
        _wait_for(lambda: len(look()) >= 2, run, "restarted worker")
        kill(look())
        _wait_for(lambda: len(look()) >= 2, run, "restarted workers", may_end=True)
        _, err = run.communicate(timeout=300)
    finally:
        _reap(run)
    assert run.returncode == 0, err
    assert "Traceback" not in err, err
    assert [c for c in seen.values() if "resource_tracker" in c or "spawn_main" in c] == []
    _same_bytes(out, small.serial.path)


# ---------------------------------------------------------------------------- other errors
def test_unexpected_error_is_one_line_traceback_on_request(small, env, tmp_path, monkeypatch,
                                                           capsys):
    real = runner.run_chunk

    def broken(job, index, progress=None):
        if index == 1:
            raise KeyError("boom")
        return real(job, index, progress)

    monkeypatch.setattr(runner, "run_chunk", broken)
    out = tmp_path / "b.nc"
    assert main(_args(small.mission, out)) == 1
    assert _one_line(capsys.readouterr().err) == (
        "chirplidar run: failed: KeyError: 'boom' (CHIRPLIDAR_DEBUG=1 prints the traceback)")
    assert _sealed(chunk_dir_for(out)) == [0]
    monkeypatch.setenv("CHIRPLIDAR_DEBUG", "1")
    assert main(_args(small.mission, out, "--resume")) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "in broken" in err
    assert err.strip().splitlines()[-1].startswith("chirplidar run: failed: KeyError: 'boom'")


def test_a_chunk_that_kills_every_worker_is_one_line_with_resume(tmp_path):
    """Dask's KilledWorker (the scheduler gave up on a chunk whose workers all died, e.g. out of
    memory) becomes one line naming the chunk's task, the chunks kept and --resume."""
    from types import SimpleNamespace

    from distributed.scheduler import KilledWorker

    from chirplidar.mission.faults import RunError, raise_run_fault
    from chirplidar.mission.results import ChunkWriter

    writer = ChunkWriter(tmp_path / "run.nc.chunks", run_id="r")
    for i in (0, 1):   # two sealed chunks
        writer.chunk_path(i).write_bytes(b"x")
        writer.seal_path(i).write_text("{}")
    exc = KilledWorker("chirplidar-chunk-abc-00002", SimpleNamespace(address="tcp://w:1"), 3)
    with pytest.raises(RunError) as err:
        raise_run_fault(exc, writer, 6, None)
    text = str(err.value)
    assert "\n" not in text and "chirplidar-chunk-abc-00002" in text
    assert "2 of 6 chunks done and kept" in text and text.endswith("run again with --resume")
    assert err.value.exit_code == 1
