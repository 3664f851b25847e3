"""Chunked survey runs: chunk files and streamed merge, Dask workers, kill and resume.

Reference values: there are no physical numbers here. The reference for every comparison is
the pre-chunking code path, kept below as ``_in_memory_run`` (the body of ``run_mission``
before chunk files: all chunks in memory, concatenated, one ``build_dataset``, one
``write_netcdf``), and the uninterrupted serial run of the same mission and seed
(DESIGN.md: "Same seed, same output, serial or parallel").
"""

from __future__ import annotations

import os
import pickle
import shutil
import re
import signal
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import xarray as xr

from conftest import identical_files, write_small_uav

from chirplidar.cli import main
from chirplidar.config.loader import ConfigError
from chirplidar.mission import measure
from chirplidar.mission.results import (
    ChunkWriter,
    build_dataset,
    write_netcdf,
)
from chirplidar.mission.executors import CHUNK_DELAY_ENV
from chirplidar.mission.manifest import MANIFEST_NAME, chunk_dir_for
from chirplidar.mission.pipeline import config_toml as _config_toml
from chirplidar.mission.pipeline import per_shot_variables as _per_shot
from chirplidar.mission.pipeline import results_dataset
from chirplidar.mission.preflight import prepare
from chirplidar.mission.runner import run_mission
from chirplidar.mission.summary import summarise
from chirplidar.mission.survey import chunk_geometry, chunk_seeds

ROOT = Path(__file__).resolve().parents[1]
DATE = "2026-01-01T00:00:00Z"          # fixed date_created
DATE_EPOCH = "1767225600"              # the same instant as SOURCE_DATE_EPOCH (CLI runs)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The Greenland UAV mission over a coarse (50 m) copy of its scene, 30 s of flight at
    100 Hz = 3000 shots in 6 chunks of 500."""
    tmp = tmp_path_factory.mktemp("scale")
    mission = write_small_uav(tmp)
    cache = tmp / "cache"
    _, _, plan = prepare(mission, cache_dir=cache)
    assert plan.n_chunks == 6 and plan.n_shots == 3000
    serial = run_mission(mission, out=tmp / "serial.nc", cache_dir=cache, date_created=DATE)
    return SimpleNamespace(tmp=tmp, mission=mission, cache=cache, serial=serial)


def _in_memory_run(mission, out, cache):
    """The code path before chunk files (reference)."""

    config, scene, plan = prepare(mission, cache_dir=cache)
    sv = config.survey
    seeds = chunk_seeds(config.seed, plan.n_chunks)
    parts = []
    for i in range(plan.n_chunks):
        geom = chunk_geometry(plan, scene, config, plan.chunk_times(i), seeds[i],
                              sv.subrays_per_beam)
        parts.append(_per_shot(config, geom, measure.measure_link(config, scene, geom, seeds[i])))
    per_shot = {k: np.concatenate([p[k] for p in parts], axis=0).T for k in parts[0]}
    ds = results_dataset(per_shot, config, scene, str(mission), DATE)
    write_netcdf(ds, out, obs_chunk=plan.chunk_shots)   # a run's file: HDF5 chunks of a chunk
    return ds


def test_chunked_run_equals_in_memory_path(small, tmp_path):
    mission, cache, serial = small.mission, small.cache, small.serial
    ref = _in_memory_run(mission, tmp_path / "ref.nc", cache)
    xr.testing.assert_identical(serial.dataset, ref)
    identical_files(serial.path, tmp_path / "ref.nc")   # encoding and chunking included
    assert not chunk_dir_for(serial.path).exists()        # removed after the merge
    s, r = serial.summary, summarise(ref, serial.path, 0.0)
    for key in ("shots", "beams", "returns", "detected", "below_threshold", "no_surface",
                "median_snr_db", "range_error_p95_abs_m", "seed", "tier"):
        assert s[key] == r[key], key                       # exact (order statistics)
    for key in ("range_error_mean_m", "range_error_std_m", "range_error_rms_m"):
        assert s[key] == pytest.approx(r[key], rel=1e-12)  # sums in another order


def test_summary_streamed_beyond_its_memory_budget(small, tmp_path):
    """Past its memory budget the summary is streamed over the chunk files, or over a run's
    spill files (radix-select order statistics): counts, median and 95th percentile still
    exactly numpy's."""
    import netCDF4

    from chirplidar.mission.summary import SUMMARY_VARIABLES, SummaryPass
    from chirplidar.mission.summary import order_statistics as _order_statistics
    from chirplidar.mission.summary import summary_of_chunks as _summary_of_chunks

    serial = small.serial
    ds = serial.dataset
    writer = ChunkWriter(tmp_path / "chunks")
    files = [writer.write(i, ds.isel(obs=slice(a, a + 700)), compress=False)
             for i, a in enumerate(range(0, ds.sizes["obs"], 700))]
    ref = summarise(ds, "x.nc", 0.0)
    for budget in (10**9, 0):   # in memory, streamed
        got = _summary_of_chunks(files, "x.nc", "link", 2026, 1, 0.0, budget_bytes=budget)
        assert {k: got[k] for k in ("shots", "detected", "median_snr_db",
                                    "range_error_p95_abs_m")} == \
            {k: ref[k] for k in ("shots", "detected", "median_snr_db", "range_error_p95_abs_m")}
        for key in ("range_error_mean_m", "range_error_std_m", "range_error_rms_m"):
            assert got[key] == pytest.approx(ref[key], rel=1e-12)
    # A run's first pass spills the detected shots past its budget (the later passes read the
    # spill files, not the chunk files): the same summary, in blocks of the budget.
    for budget in (0, 16 * 100):
        first = SummaryPass(1, budget, spill_dir=tmp_path)
        for f in files:
            with netCDF4.Dataset(f) as src:
                for k in SUMMARY_VARIABLES:
                    src[k].set_auto_maskandscale(False)
                first.add(*(src[k][...] for k in SUMMARY_VARIABLES))
        assert first.spilled and (tmp_path / "summary_snr.f8").stat().st_size == 8 * ref[
            "detected"]
        got = _summary_of_chunks([], "x.nc", "link", 2026, 1, 0.0, budget_bytes=budget,
                                 first_pass=first)
        assert {k: got[k] for k in ("shots", "detected", "median_snr_db",
                                    "range_error_p95_abs_m")} == \
            {k: ref[k] for k in ("shots", "detected", "median_snr_db", "range_error_p95_abs_m")}
        for key in ("range_error_mean_m", "range_error_std_m", "range_error_rms_m"):
            assert got[key] == pytest.approx(ref[key], rel=1e-12)
    # order statistics of signed values with ties, over uneven blocks (reference: np.sort)
    rng = np.random.default_rng(4)
    blocks = [np.round(rng.normal(0, 3, n), 1) for n in (1, 500, 0, 77)]
    blocks[1][:3] = [-0.0, 0.0, np.finfo(float).max]
    ranks = [0, 1, 2, 300, 577]
    (got,) = _order_statistics(lambda: ((b,) for b in blocks), [ranks])
    assert got == np.sort(np.concatenate(blocks))[ranks].tolist()


def test_merge_streams_chunk_slices(tmp_path):
    """Chunk files merged slice by slice give write_netcdf's file of the concatenation, with
    array allocations bounded by one chunk (tracemalloc sees numpy's buffers)."""
    rng = np.random.default_rng(1)
    n_chunks, m, beams = 10, 4000, 2
    config = '[survey]\ntier = "link"\n'
    kw = {"epsg": 3413, "epoch_iso": DATE, "config_toml": config, "seed": 3,
          "software_version": "0", "materials": {0: "snow"}, "date_created": DATE}
    full = {"delta_time": np.tile(np.arange(n_chunks * m) * 0.01, (beams, 1)),
            "x": rng.normal(0, 1e3, (beams, n_chunks * m)) - 2e5,
            "y": rng.normal(0, 1e3, (beams, n_chunks * m)) - 2.4e6,
            "range_measured": np.where(rng.random((beams, n_chunks * m)) < 0.1, np.nan,
                                       rng.normal(500, 1, (beams, n_chunks * m))),
            "detected": rng.integers(0, 3, (beams, n_chunks * m)),
            "surface_type": np.zeros((beams, n_chunks * m), dtype=int)}
    writer = ChunkWriter(tmp_path / "chunks")
    for i in range(n_chunks):
        part = {k: v[:, i * m:(i + 1) * m] for k, v in full.items()}
        writer.write(i, build_dataset(part, **kw), compress=i % 2 == 0)
    whole = build_dataset(full, **kw)
    write_netcdf(whole, tmp_path / "whole.nc")
    chunk_bytes = sum(v.nbytes for v in build_dataset(
        {k: v[:, :m] for k, v in full.items()}, **kw).variables.values())
    tracemalloc.start()
    try:
        writer.merge_to_file(tmp_path / "merged.nc", n_chunks=n_chunks)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    identical_files(tmp_path / "whole.nc", tmp_path / "merged.nc")
    total_bytes = sum(v.nbytes for v in whole.variables.values())
    assert peak < chunk_bytes, (peak, chunk_bytes)
    assert chunk_bytes < total_bytes / 5


def test_workers_identical_to_serial(small, tmp_path):
    mission, cache, serial = small.mission, small.cache, small.serial
    par = run_mission(mission, out=tmp_path / "w2.nc", cache_dir=cache, date_created=DATE,
                      workers=2)
    xr.testing.assert_identical(par.dataset, serial.dataset)
    assert par.summary == {**serial.summary, "output": str(par.path),
                           "elapsed_s": par.summary["elapsed_s"]}
    assert "cluster_start_s" in par.timings


def test_scale_bench_pairs_alternate_and_agree(small, monkeypatch):
    """``bench --what scale`` on the small mission: pairs of full runs whose order alternates,
    identical files, and the speedup is the median of the pairs' ratios."""
    from chirplidar.benchmarks import scale as scale_bench
    from chirplidar.mission import runner

    monkeypatch.setenv("CHIRPLIDAR_CACHE", str(small.cache))
    order = []
    real_run = runner.run_mission

    def spy(*args, **kwargs):
        order.append(kwargs["workers"])
        return real_run(*args, **kwargs)

    monkeypatch.setattr(runner, "run_mission", spy)
    lines = []
    res = scale_bench.bench_scale(small.mission, repeats=2, progress=lines.append)
    assert order == [None, 2, 2, None]
    assert res["identical"] is True
    assert res["shots"] == small.serial.summary["shots"]
    assert len(res["pair_speedups"]) == 2 and len(lines) == 2
    assert res["speedup"] == pytest.approx(np.median(res["pair_speedups"]), rel=1e-12)
    assert "cluster_start_s" in res["workers_parts_s"]
    assert "pairs of runs" in scale_bench.format_scale(res)
    assert "goal >= 1.6)" in scale_bench.format_scale(res)   # a short run: issue 5's goal
    assert "goal >= 1.75)" in scale_bench.format_scale({**res, "serial_s": 60.0})  # issue 19


def test_run_bench_times_a_run_and_its_peak_memory(small, monkeypatch):
    """``bench --what run`` on the small mission, serially and on 2 workers: the run's shots
    and chunks, a peak memory of the processes together at least this process's own
    resident memory now (the sampler's floor) and, with workers, above the largest single
    process (three processes are summed), the file's size on disk. No timed assertion."""
    import psutil

    from chirplidar.benchmarks import scale as scale_bench

    monkeypatch.setenv("CHIRPLIDAR_CACHE", str(small.cache))
    for workers in (1, 2):
        res = scale_bench.bench_run(small.mission, workers=workers)
        assert res["shots"] == small.serial.summary["shots"] and res["chunks"] == 6
        assert res["seconds"] > 0 and res["shots_per_s"] == pytest.approx(
            res["shots"] / res["seconds"], rel=1e-12)
        assert res["estimated_seconds"] > 0
        assert res["peak_memory_mb"] >= 0.5 * psutil.Process().memory_info().rss / 1e6
        if workers == 2:
            assert res["peak_memory_mb"] > res["largest_process_mb"]
        assert res["file_mb"] == pytest.approx(small.serial.path.stat().st_size / 1e6,
                                               rel=0.2)
        assert f"on {workers} worker(s)" in scale_bench.format_run(res)


def test_scale_bench_pair_statistics():
    """Reference: hand computation. Ratios 4/2, 5/2.5, 6/4 = 2, 2, 1.5: median 2; numpy's
    linear quartiles of (1.5, 2, 2) are 1.75 and 2; the time medians are 5 and 2.5 s."""
    from chirplidar.benchmarks.scale import pair_statistics

    st = pair_statistics([4.0, 5.0, 6.0], [2.0, 2.5, 4.0])
    assert st["serial_s"] == 5.0 and st["workers_s"] == 2.5
    assert st["speedup"] == pytest.approx(2.0)
    assert st["speedup_quartiles"] == pytest.approx([1.75, 2.0])
    assert st["pair_speedups"] == pytest.approx([2.0, 2.0, 1.5])
    with pytest.raises(ValueError, match="one time per pair"):
        pair_statistics([4.0, 5.0], [2.0])
    with pytest.raises(ValueError, match="finite and > 0"):
        pair_statistics([4.0], [0.0])


def test_scheduler_address_with_threaded_workers(small, tmp_path):
    """``scheduler=ADDRESS`` runs on an existing cluster: here one in-process worker with two
    threads (chunks of one process at once: shared preparation cache, dask's configuration
    restored after the run). Same file as the serial run."""
    import dask
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=None) as cluster:
        res = run_mission(small.mission, out=tmp_path / "s.nc", cache_dir=small.cache,
                          date_created=DATE, scheduler=cluster.scheduler_address)
    identical_files(res.path, small.serial.path)
    assert dask.config.get("scheduler", None) is None


def test_worker_error_surfaces_like_serial(small, tmp_path):
    """A chunk that fails in a Dask worker raises the same ConfigError (same message) in the
    caller as it does in a serial run: here a job whose scene hash does not match the file."""
    from chirplidar.mission import pipeline
    from chirplidar.mission.executors import DaskExecutor
    from chirplidar.mission.manifest import sha256_text

    mission, cache = small.mission, small.cache
    config, _, plan = prepare(mission, cache_dir=cache)
    job = pipeline.ChunkJob(
        mission_path=str(mission.resolve()), mission_label=str(mission), overrides=(),
        tier=None, seed=None, cache_dir=str(cache), chunk_dir=str(tmp_path / "c"),
        date_created=DATE, configuration_sha256=sha256_text(_config_toml(config)),
        scene_sha256="0" * 64)
    with pytest.raises(ConfigError) as serial_err:
        pipeline.run_chunk(job, 0)
    assert "changed on disk" in str(serial_err.value)
    with pytest.raises(ConfigError) as worker_err:
        DaskExecutor(workers=2).run(pipeline.run_chunk, job, [0, 1], plan)
    assert str(worker_err.value) == str(serial_err.value)
    assert pickle.loads(pickle.dumps(job)) == job   # plain data, as shipped to workers


def _cli(*args, env=None, **kw):
    return subprocess.Popen([sys.executable, "-m", "chirplidar.cli", *args],
                            env={**os.environ, **(env or {})}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def _sigkill(proc) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)


def _reap(proc) -> None:
    """A test's subprocess never outlives it."""
    if proc.poll() is None:
        proc.kill()
        proc.communicate()


def test_kill_and_resume(small, tmp_path):
    mission, cache, serial = small.mission, small.cache, small.serial
    out = tmp_path / "killed.nc"
    chunks = chunk_dir_for(out)
    args = ["run", str(mission), "--out", str(out), "--no-progress"]
    env = {"CHIRPLIDAR_CACHE": str(cache), "SOURCE_DATE_EPOCH": DATE_EPOCH}
    # the test hook: 0.5 s after every chunk, so the kill lands between chunks 2 and 6
    proc = _cli(*args, env={**env, CHUNK_DELAY_ENV: "0.5"})
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if chunks.is_dir() and len(ChunkWriter(chunks).completed_chunks()) >= 2:
                break
            if proc.poll() is not None:
                pytest.fail(f"run ended before it was killed: {proc.communicate()}")
            time.sleep(0.02)
        else:
            pytest.fail("no two chunk files within 120 s")
        _sigkill(proc)
    finally:
        _reap(proc)
    done = ChunkWriter(chunks).completed_chunks()
    assert 2 <= len(done) < 6 and done == list(range(len(done)))
    assert not out.exists() and (chunks / MANIFEST_NAME).is_file()
    (chunks / ".chunk_00005.nc.killed.tmp").write_bytes(b"CDF partial")  # a killed write

    # without --resume: refused, nothing touched
    before = sorted(p.name for p in chunks.iterdir())
    assert main([*args]) == 2
    assert sorted(p.name for p in chunks.iterdir()) == before
    # a different run (seed) cannot resume these chunks: the error names the directory
    with pytest.raises(ConfigError, match=rf"{re.escape(str(chunks))}.*seed: 2026 there, 7 now"):
        run_mission(mission, out=out, cache_dir=cache, resume=True, seed=7)
    with pytest.raises(ConfigError, match=r"survey\.prf_hz = 100\.0 there, 50\.0 now"):
        run_mission(mission, out=out, cache_dir=cache, resume=True,
                    overrides=["survey.prf_hz=50"])
    assert sorted(p.name for p in chunks.iterdir()) == before

    # resume later (another SOURCE_DATE_EPOCH: the manifest's date must win); a serial run
    # never uses dask.distributed (blocked here; xarray on its own imports dask.array and
    # asks `distributed` for a client when they are installed)
    script = ("import sys; sys.modules['dask.distributed'] = None; "
              "from chirplidar.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = subprocess.Popen([sys.executable, "-c", script, *args, "--resume"],
                            env={**os.environ, **env, "SOURCE_DATE_EPOCH": "1900000000"},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert "chirplidar run: 3000 shots" in stdout
    assert not chunks.exists()
    identical_files(out, serial.path)


def test_existing_chunk_dir_needs_resume_or_overwrite(small, tmp_path, capsys):
    mission, cache, serial = small.mission, small.cache, small.serial
    out = tmp_path / "x.nc"
    stale = chunk_dir_for(out)
    stale.mkdir()
    (stale / "chunk_00000.nc").write_bytes(b"not a chunk of this run")
    args = ["run", str(mission), "--out", str(out), "--no-progress"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert str(stale) in err and "--resume" in err and "--overwrite" in err
    # --resume: chunk files without a manifest cannot be matched to the run
    with pytest.raises(ConfigError, match=rf"{re.escape(str(stale))}: chunk files without a manifest\.json"):
        run_mission(mission, out=out, cache_dir=cache, resume=True)
    # --overwrite discards them (and the temp results file of that run) and runs
    (tmp_path / ".x.nc.killed.tmp").write_bytes(b"CDF partial")
    res = run_mission(mission, out=out, cache_dir=cache, overwrite=True, date_created=DATE)
    identical_files(res.path, serial.path)
    assert sorted(os.listdir(tmp_path)) == ["x.nc"]


@pytest.mark.parametrize("argv, message", [
    (["--workers", "0"], "--workers must be >= 1"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "exclusive"),
])
def test_cli_parallel_options_checked(small, argv, message, capsys):
    tmp, mission = small.tmp, small.mission
    assert main(["run", str(mission), "--out", str(tmp / "never.nc"), *argv]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp / "never.nc").exists() and not chunk_dir_for(tmp / "never.nc").exists()


def test_run_mission_parallel_arguments_checked(small):
    tmp, mission = small.tmp, small.mission
    with pytest.raises(ValueError, match="workers must be an integer >= 1"):
        run_mission(mission, out=tmp / "never.nc", workers=0)
    with pytest.raises(ValueError, match="exclusive"):
        run_mission(mission, out=tmp / "never.nc", workers=2, scheduler="tcp://127.0.0.1:1")


_MALLOC_PROBE = """
import resource, numpy as np
from chirplidar.mission.executors import keep_freed_memory
keep_freed_memory()                  # first thing: no large block has been freed yet

def faults_of_one_round():
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    blocks = [np.ones(1 << 17) for _ in range(16)]   # 16 x 1 MiB, below numpy's huge pages
    del blocks
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

faults_of_one_round()
print(min(faults_of_one_round() for _ in range(3)))
"""


@pytest.mark.skipif(sys.platform != "linux", reason="glibc malloc settings")
def test_freed_chunk_memory_is_reused_whenever_the_setting_is_made():
    """``keep_freed_memory`` called before any large block was freed: 1 MiB arrays freed
    and allocated again reuse malloc's heap. Reference: 16 MiB mapped afresh is 4096 page
    faults of 4 KiB (what glibc did with its mmap threshold left at 128 KiB); reuse needs
    none, so fewer than a tenth of that."""
    import platform

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("glibc malloc settings")
    out = subprocess.run([sys.executable, "-c", _MALLOC_PROBE], capture_output=True,
                         text=True, check=True)
    assert int(out.stdout.strip()) < 4096 // 10, out.stdout


class _Stop(Exception):
    pass


def _interrupted(small, tmp_path, monkeypatch, after: int = 4, seed=None):
    """A serial run of the small mission stopped after ``after`` chunks: its out path and chunk
    directory (with the manifest and ``after`` sealed chunks)."""
    from chirplidar.mission import runner

    real = runner.run_chunk
    count = {"n": 0}

    def stopping(job, index, progress=None):
        if count["n"] == after:
            raise _Stop
        count["n"] += 1
        return real(job, index, progress)

    out = tmp_path / "cut.nc"
    monkeypatch.setattr(runner, "run_chunk", stopping)
    with pytest.raises(_Stop):
        run_mission(small.mission, out=out, cache_dir=small.cache, date_created=DATE,
                    seed=seed)
    monkeypatch.setattr(runner, "run_chunk", real)
    chunks = chunk_dir_for(out)
    assert ChunkWriter(chunks).completed_chunks() == list(range(after))
    return out, chunks


def _flip(path: Path, offset: int, n: int = 64) -> None:
    data = bytearray(path.read_bytes())
    for k in range(offset, offset + n):
        data[k] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["inverted", "truncated", "swapped", "foreign", "unsealed"])
def test_resume_recomputes_bad_chunks_and_merges_none(small, tmp_path, monkeypatch, damage):
    """Issue 15: a chunk damaged inside its data (64 bytes inverted), truncated, swapped with
    another, copied from another run, or left without its seal (a write cut short) is named,
    computed again by --resume and never merged: the file equals an uninterrupted run's."""
    out, chunks = _interrupted(small, tmp_path, monkeypatch)
    writer = ChunkWriter(chunks)
    c1, c2 = writer.chunk_path(1), writer.chunk_path(2)
    if damage == "inverted":
        _flip(c1, c1.stat().st_size // 2)
    elif damage == "truncated":
        c1.write_bytes(c1.read_bytes()[: c1.stat().st_size // 3])
    elif damage == "swapped":
        for suffix in (".nc", ".json"):
            a, b = c1.with_suffix(suffix), c2.with_suffix(suffix)
            tmp = a.with_name("swap" + suffix)
            a.rename(tmp)
            b.rename(a)
            tmp.rename(b)
    elif damage == "foreign":   # chunk 1 of the same mission run with another seed
        (tmp_path / "other").mkdir()
        _, other = _interrupted(small, tmp_path / "other", monkeypatch, after=2, seed=7)
        shutil.copy(ChunkWriter(other).chunk_path(1), c1)
        shutil.copy(ChunkWriter(other).seal_path(1), c1.with_suffix(".json"))
    else:
        c1.with_suffix(".json").unlink()
    with pytest.warns(UserWarning) as caught:
        res = run_mission(small.mission, out=out, cache_dir=small.cache, resume=True)
    named = [str(w.message) for w in caught]
    for k in ((1, 2) if damage == "swapped" else (1,)):
        assert any(re.search(rf"chunk {k} \(.*chunk_0000{k}\.nc\): .*computing it again", m)
                   for m in named), named
    assert not chunks.exists()
    identical_files(res.path, small.serial.path)


def test_a_chunk_damaged_after_its_seal_is_never_merged(small, tmp_path, monkeypatch):
    """The merge checks each chunk's seal as it copies it: a chunk damaged between its write
    and its merge stops the run with its name (its folder kept for --resume)."""
    from chirplidar.mission import runner

    real = runner.run_chunk

    def damaging(job, index, progress=None):
        path = real(job, index, progress)
        if index == 3:
            _flip(Path(path), Path(path).stat().st_size // 2)
        return path

    monkeypatch.setattr(runner, "run_chunk", damaging)
    out = tmp_path / "damaged.nc"
    with pytest.raises(ValueError, match=r"chunk 3 .*damaged: its SHA-256 differs"):
        run_mission(small.mission, out=out, cache_dir=small.cache, date_created=DATE)
    assert not out.exists() and chunk_dir_for(out).is_dir()


def test_one_run_per_output(small, tmp_path, capsys):
    """Issue 15: two runs on one output; the second is refused at once, naming the holder; the
    lock of a killed run is taken over (with a warning) by the next one."""
    out = tmp_path / "shared.nc"
    args = ["run", str(small.mission), "--out", str(out), "--no-progress"]
    env = {"CHIRPLIDAR_CACHE": str(small.cache), "SOURCE_DATE_EPOCH": DATE_EPOCH}
    proc = _cli(*args, env={**env, CHUNK_DELAY_ENV: "0.5"})
    lock = out.with_name(out.name + ".lock")
    try:
        deadline = time.monotonic() + 60
        while not lock.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        assert lock.exists(), proc.communicate()
        t = time.monotonic()
        assert main([*args, "--overwrite"]) == 2
        assert time.monotonic() - t < 5.0
        err = capsys.readouterr().err
        assert f"another run is writing it (pid {proc.pid} on" in err
        assert len(err.strip().splitlines()) == 1
        _sigkill(proc)
    finally:
        _reap(proc)
    assert lock.exists()                       # SIGKILL: nothing removed it
    with pytest.warns(UserWarning, match=rf"taking over the lock of pid {proc.pid}"):
        res = run_mission(small.mission, out=out, cache_dir=small.cache, overwrite=True,
                          date_created=DATE)
    assert not lock.exists()
    identical_files(res.path, small.serial.path)


def test_output_that_is_a_directory_is_refused_before_any_work(small, tmp_path, capsys):
    target = tmp_path / "results.nc"
    target.mkdir()
    assert main(["run", str(small.mission), "--out", str(target), "--overwrite"]) == 2
    assert "is a directory" in capsys.readouterr().err
    assert not chunk_dir_for(target).exists()


_FLAT_AIR = ('[atmosphere]\ncn2_profile = "none"\nextinction_per_m = 0.0\n'
             'scale_height_m = 1200.0\n')


def _resume_refused_after_terrain_change(tmp_path, monkeypatch, scene_text, terrain: Path,
                                         write_terrain):
    """A UAV run over ``scene_text`` (its terrain file ``terrain`` written by
    ``write_terrain(height)``) stopped after two chunks; the file rewritten at another height
    makes --resume refuse, naming it; the same heights again let it finish."""
    from conftest import write_uav_mission

    write_terrain(100.0)
    scene = tmp_path / "terrain_scene.toml"
    scene.write_text(scene_text + _FLAT_AIR)
    mission = write_uav_mission(tmp_path, scene, "terrain_uav", altitude=600.0,
                                waypoints="[[-800.0, 0.0], [800.0, 0.0]]", stop="10.0",
                                extra="chunk_shots = 50")
    small = SimpleNamespace(mission=mission, cache=tmp_path / "cache")
    out, _ = _interrupted(small, tmp_path, monkeypatch, after=2)
    write_terrain(110.0)                               # the file changes on disk
    with pytest.raises(ConfigError,
                       match=rf"terrain file\(s\) {re.escape(str(terrain))} changed"):
        run_mission(mission, out=out, cache_dir=small.cache, resume=True)
    write_terrain(100.0)                               # the same heights again: resumes
    res = run_mission(mission, out=out, cache_dir=small.cache, resume=True)
    assert res.summary["shots"] == 200


def test_resume_refuses_a_changed_dem(tmp_path, monkeypatch):
    """Issue 15: the manifest holds the SHA-256 of the terrain's DEM; a DEM changed between a
    stopped run and --resume is refused, naming the file."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from chirplidar.geometry import frames

    x0, y0 = frames.geodetic_to_projected(69.0, -49.0, 0.0, 3413)[:2]
    dem = tmp_path / "dem.tif"

    def write_dem(height):
        with rasterio.open(dem, "w", driver="GTiff", height=200, width=200, count=1,
                           dtype="float32", crs="EPSG:3413",
                           transform=Affine(10.0, 0.0, float(x0) - 1000.0, 0.0, -10.0,
                                            float(y0) + 1000.0)) as dst:
            dst.write(np.full((200, 200), height, np.float32), 1)

    _resume_refused_after_terrain_change(
        tmp_path, monkeypatch, 'name = "dem"\nepsg = 3413\neffects = []\n[terrain]\n'
        'source = "dem"\n[terrain.dem]\npath = "dem.tif"\nmaterial = "snow"\n', dem, write_dem)


def test_resume_refuses_a_changed_mesh(tmp_path, monkeypatch):
    """Issue 15: as for a DEM, a terrain mesh file changed between a stopped run and --resume is
    refused, naming the file."""
    mesh = tmp_path / "plane.obj"

    def write_mesh(height):   # a 3 km square at one height, metres from the scene centre
        mesh.write_text("".join(f"v {x} {y} {height}\n" for x, y in
                                ((-1500, -1500), (1500, -1500), (1500, 1500), (-1500, 1500)))
                        + "f 1 2 3\nf 1 3 4\n")

    _resume_refused_after_terrain_change(
        tmp_path, monkeypatch, 'name = "mesh"\nepsg = 3413\neffects = []\n[terrain]\n'
        'source = "mesh"\ncenter_lat_deg = 69.0\ncenter_lon_deg = -49.0\n[terrain.mesh]\n'
        'path = "plane.obj"\ncoordinates = "scene_centre"\nmaterial = "snow"\n', mesh, write_mesh)


def test_the_results_file_is_read_back_before_the_chunks_go(small, tmp_path):
    """verify_results_file (run before the chunk folder is deleted) reads every variable: the
    serial run's file passes; a copy with 64 bytes inverted in its data, or cut short, fails
    with one line naming the file."""
    from chirplidar.mission.results import verify_results_file

    verify_results_file(small.serial.path, 3000, 1, block_obs=500)
    damaged = tmp_path / "damaged.nc"
    shutil.copy(small.serial.path, damaged)
    _flip(damaged, damaged.stat().st_size // 2)
    with pytest.raises(ValueError, match=re.escape(str(damaged))):
        verify_results_file(damaged, 3000, 1, block_obs=500)
    cut = tmp_path / "cut.nc"
    cut.write_bytes(small.serial.path.read_bytes()[: small.serial.path.stat().st_size // 2])
    with pytest.raises(ValueError, match=re.escape(str(cut))):
        verify_results_file(cut, 3000, 1, block_obs=500)
    with pytest.raises(ValueError, match="2999 expected"):
        verify_results_file(small.serial.path, 2999, 1)


def test_the_read_back_of_copied_chunks_compares_their_stored_bytes(small, tmp_path):
    """A run verifies the variables its merge copied as stored by their HDF5 chunks' digests
    (no decompression): the good file passes with its own digests; the copy with 64 bytes
    inverted in its data fails with one line naming the file and the variable; a missing
    chunk fails too."""
    import h5py

    from chirplidar.mission.results import verify_results_file
    from chirplidar.mission.results.merge import chunk_digest

    with h5py.File(small.serial.path, "r") as f:
        stored = {name: {tuple(off): chunk_digest(var.id.read_direct_chunk(off)[1])
                         for off in (var.id.get_chunk_info(k).chunk_offset
                                     for k in range(var.id.get_num_chunks()))}
                  for name, var in f.items() if isinstance(var, h5py.Dataset)
                  and var.compression == "gzip"}
    assert len(stored) > 10
    verify_results_file(small.serial.path, 3000, 1, stored_chunks=stored)
    damaged = tmp_path / "damaged.nc"
    shutil.copy(small.serial.path, damaged)
    _flip(damaged, damaged.stat().st_size // 2)
    with pytest.raises(ValueError, match=re.escape(str(damaged)) + r".*variable \w+"):
        verify_results_file(damaged, 3000, 1, stored_chunks=stored)
    name = next(iter(stored))
    extra = {**stored, name: {**stored[name], (0, 10**6): (1, 0)}}
    with pytest.raises(ValueError, match=f"variable {name}: stored chunks at"):
        verify_results_file(small.serial.path, 3000, 1, stored_chunks=extra)


def test_scheduler_without_workers_times_out_with_a_message(small, tmp_path, monkeypatch):
    """Issue 15: a scheduler with no worker used to wait for ever; now a clear error after
    CHIRPLIDAR_WORKER_WAIT_S (here 2 s), and no chunk folder left to block the next run."""
    from dask.distributed import LocalCluster

    monkeypatch.setenv("CHIRPLIDAR_WORKER_WAIT_S", "2")
    out = tmp_path / "lonely.nc"
    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        t = time.monotonic()
        with pytest.raises(ConfigError, match=r"no worker joined within 2 s"):
            run_mission(small.mission, out=out, cache_dir=small.cache,
                        scheduler=cluster.scheduler_address)
        assert time.monotonic() - t < 30.0
    assert not out.exists() and not chunk_dir_for(out).exists()
