"""``chirplidar run``: a mission over its scene, chunk by chunk, into a CF trajectory NetCDF file.

mission.toml -> instrument + [scene] + [platform] + [attitude] + [beams] + [survey]
  plan (:func:`.preflight.prepare`: path, beams, shot clock) -> per chunk
  (:func:`.pipeline.run_chunk`): rays and footprint sub-rays on the terrain -> returns through
  the tier (link | baseband | rf) -> per-shot variables -> one atomic chunk file -> streamed
  merge into the results file (:class:`.results.ChunkMerge`) -> summary (:mod:`.summary`).

This module wires the jobs together (:func:`run_mission`); each lives in its own module:

- :mod:`.preflight`: the mission loaded and checked, planner warnings, the run's size.
- :mod:`.pipeline`: one chunk (geometry, returns, tier, records, chunk file).
- :mod:`.executors`: where the chunks are computed (serial, or Dask workers).
- :mod:`.manifest`: the chunk directory, its manifest, the output's lock and ``--resume``.
- :mod:`.results`: the results files (schema, writer, merge, read-back).
- :mod:`.summary`: the run's statistics and their text.
- :mod:`.faults`: faults outside the simulation, in one line (:class:`.faults.RunError`).

Finished chunks are appended to the results file in chunk order as soon as they and the
chunks before them exist (a temp file beside the output, renamed onto it atomically at the end;
chunk slice by chunk slice, so memory stays bounded by one chunk whatever the mission length).
The results file is stored in HDF5 chunks of ``survey.chunk_shots`` observations, and each
chunk file is written compressed in that layout by the process that computed it, so appending
copies its compressed HDF5 chunks as they are: with ``workers=N`` this process does it while
the workers compute later chunks (on a given ``scheduler``, whose workers may be threads of this
process, after the last chunk: netCDF calls must not run in two threads at once). The summary's
first pass reads the chunks as they are appended. When every chunk is in, the file is renamed
into place, the summary is finished and the chunk directory is removed once the file has been
read back (every variable). Output folders that cannot be written are refused before any work.
"""

from __future__ import annotations

import functools
import shutil
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from ..config.loader import ConfigError
from . import preflight
from .executors import Executor, check_parallel_args, executor_for, keep_freed_memory
from .faults import RunError, raise_run_fault
from .manifest import (build_manifest, check_chunk_dir, check_writable, chunk_dir_for,
                       open_chunk_dir, output_lock)
from .pipeline import (ChunkJob, config_toml, forget_prepared, pilot_chunk,
                       remember_prepared, run_chunk)
from .results import (BYTES_PER_BEAM_SHOT, ChunkMerge, ChunkWriter, read_netcdf,
                      verify_results_file)
from .summary import SUMMARY_VARIABLES, SummaryPass, summary_of_chunks

#: (The command line recognises a run's faults by this module's ``RunError``.)
__all__ = ["RunError", "RunResult", "check_output", "default_output", "preflight_run",
           "run_mission"]


@dataclass(frozen=True)
class RunResult:
    """Output path, summary and timings of a run. ``dataset`` reads the results file into memory
    on first access (the run itself never holds the whole mission in memory)."""

    path: Path
    summary: dict
    timings: dict = field(default_factory=dict)

    @functools.cached_property
    def dataset(self):
        """The results file, read into memory."""
        return read_netcdf(self.path)


def default_output(mission_path) -> Path:
    """The results file of a mission by default: ``outputs/<mission name>.nc``."""
    return Path("outputs") / (Path(mission_path).stem + ".nc")


def check_output(out, mission_path, *, overwrite: bool) -> Path:
    """The results path of a run (``out``, or the mission's default), refused before any work
    when it cannot be one: a directory, an existing file without ``overwrite`` (FileExistsError),
    not ``*.nc``, under a file, or in a folder this process cannot write in (an absent folder
    is reported when the run starts: the default ``outputs/`` is made then)."""
    out = Path(out) if out is not None else default_output(mission_path)
    if out.is_dir():
        raise ConfigError(f"--out {out}: is a directory; give a results file name (*.nc)")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists: pass --overwrite to replace it (nothing was run)")
    if out.suffix != ".nc":
        raise ConfigError(f"--out {out}: the results file must end in .nc")
    if out.parent.exists() and not out.parent.is_dir():
        raise ConfigError(f"--out {out}: {out.parent} is a file, not a directory")
    if out.parent.is_dir():
        check_writable(out.parent, f"--out {out}")
    return out


def preflight_run(mission_path, *, overrides=(), tier=None, seed=None, cache_dir=None,
                  cores=1, estimate=True):
    """What a run checks before any work, and what ``chirplidar run --dry-run`` shows:
    :func:`.preflight.prepare`, the planner's warnings (issued as
    :class:`.preflight.PlannerWarning`) and, if ``estimate``, the run's size
    (:func:`.preflight.run_estimate`, timed through :func:`.pipeline.pilot_chunk`: a chunk's
    measurement and its compressed file; else None). Returns (config, scene, plan, planner warnings, estimate)."""
    config, scene, plan = preflight.prepare(mission_path, overrides=overrides, tier=tier,
                                            seed=seed, cache_dir=cache_dir)
    sv = config.survey
    if plan.n_shots == 0:
        raise ConfigError(f"{mission_path}: survey span {sv.start_s:g}..{sv.stop_s} s at "
                          f"{sv.prf_hz:g} Hz holds no shot")
    notes = tuple(preflight.planner_warnings(config, scene, plan))
    for text in notes:
        warnings.warn(text, preflight.PlannerWarning, stacklevel=2)
    size = (preflight.run_estimate(config, scene, plan, cores=cores, pilot_chunk=pilot_chunk)
            if estimate else None)
    return config, scene, plan, notes, size


def run_mission(mission_path, *, overrides=(), tier=None, out=None, seed=None,
                overwrite=False, progress=False, cache_dir=None, date_created=None,
                workers=None, scheduler=None, resume=False, yes=True) -> RunResult:
    """Run a survey mission and write its results; returns the path, summary and timings.

    ``out`` defaults to ``outputs/<mission name>.nc``. An existing ``out`` raises
    FileExistsError before any work unless ``overwrite``; the file is written atomically, so an
    interrupted run leaves any previous file intact. Chunks go to ``<out>.chunks/`` first (see
    the module docstring): an existing chunk directory raises FileExistsError unless ``resume``
    (finish that run: its finished chunks are kept, its manifest must match) or ``overwrite``
    (discard it). ``workers`` > 1 runs the chunks on a local Dask cluster, ``scheduler`` on an
    existing one; the results are the same as a serial run's. ``date_created`` (ISO 8601)
    defaults to now, or ``$SOURCE_DATE_EPOCH``; a resumed run reuses the one of its manifest.
    Before any work the planner's warnings are issued and, when ``progress`` or not ``yes``,
    the run is sized (:func:`preflight_run`; the size printed when ``progress``); a run above
    the limits of :mod:`.preflight` is refused unless ``yes`` (the command line asks for
    ``--yes``).
    An output or chunk folder this process cannot write in raises ConfigError before any work;
    a full disk, a file-system error or a lost ``scheduler`` during the run raise
    :class:`.faults.RunError` (one line; the finished chunks kept for ``resume``).
    """
    t0 = time.perf_counter()
    check_parallel_args(workers, scheduler)
    out = check_output(out, mission_path, overwrite=overwrite)
    if out == default_output(mission_path):
        out.parent.mkdir(parents=True, exist_ok=True)   # outputs/: made for the default
    run = functools.partial(_run_locked, mission_path, out, overrides=overrides, tier=tier,
                            seed=seed, overwrite=overwrite, progress=progress,
                            cache_dir=cache_dir, date_created=date_created, workers=workers,
                            scheduler=scheduler, resume=resume, yes=yes, t0=t0)
    if out.parent.is_dir():
        check_writable(out.parent, f"--out {out}")
        with output_lock(out):
            return run()
    return run()


def _run_locked(mission_path, out: Path, *, overrides, tier, seed, overwrite, progress,
                cache_dir, date_created, workers, scheduler, resume, yes, t0) -> RunResult:
    """:func:`run_mission` once the output's lock is held: the checks before any work, the
    chunk directory (new or resumed), then the chunks, the merge and the summary."""
    chunk_dir = chunk_dir_for(out)
    check_chunk_dir(chunk_dir, resume=resume, overwrite=overwrite)
    config, scene, plan, notes = _checked_run(
        mission_path, out, overrides=overrides, tier=tier, seed=seed, cache_dir=cache_dir,
        cores=workers or 1, progress=progress, yes=yes)
    timings = {"prepare_s": time.perf_counter() - t0}

    manifest = build_manifest(Path(mission_path), config, scene, plan, config_toml(config))
    date_created = open_chunk_dir(chunk_dir, out, manifest, resume=resume,
                                  date_created=date_created)
    job = ChunkJob(
        mission_path=str(Path(mission_path).resolve()), mission_label=str(mission_path),
        overrides=tuple(str(o) for o in overrides), tier=tier,
        seed=None if seed is None else int(seed),
        cache_dir=None if cache_dir is None else str(Path(cache_dir).resolve()),
        chunk_dir=str(chunk_dir.resolve()), date_created=date_created,
        configuration_sha256=manifest["configuration_sha256"],
        scene_sha256=manifest["scene_sha256"], planner_warnings=notes)
    remember_prepared(job, (config, scene, plan))
    try:
        return _execute(job, config, plan, out, chunk_dir, overwrite=overwrite,
                        progress=progress, executor=executor_for(workers, scheduler),
                        scheduler=scheduler, timings=timings, t0=t0)
    finally:
        forget_prepared(job)   # this process needs it no more (workers keep theirs)


def _checked_run(mission_path, out: Path, *, overrides, tier, seed, cache_dir, cores: int,
                 progress: bool, yes: bool) -> tuple:
    """:func:`preflight_run` (sized when ``progress`` or not ``yes``: its pilot costs a second),
    the size printed when ``progress``; ConfigError for a large run without ``yes`` and for an
    absent output folder. Returns (config, scene, plan, planner warnings)."""
    config, scene, plan, notes, estimate = preflight_run(
        mission_path, overrides=overrides, tier=tier, seed=seed, cache_dir=cache_dir,
        cores=cores, estimate=progress or not yes)
    if progress:
        print(f"chirplidar run: {preflight.format_estimate(estimate)}", file=sys.stderr)
    if estimate is not None and estimate.large and not yes:
        raise ConfigError(f"{mission_path}: a large run ({preflight.format_estimate(estimate)}; "
                          f"the limits are {preflight.LARGE_RUN_HOURS:g} h and "
                          f"{preflight.LARGE_RUN_GB:g} GB): pass --yes to start it, or "
                          "--dry-run to see its plan (nothing was run)")
    if not out.parent.is_dir():   # (the default's outputs/ is made before the lock)
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
    return config, scene, plan, notes


def _execute(job: ChunkJob, config, plan, out: Path, chunk_dir: Path, *, overwrite: bool,
             progress: bool, executor: Executor, scheduler, timings: dict,
             t0: float) -> RunResult:
    """The missing chunks (on ``executor``), each appended to the results file (in chunk order)
    as soon as it and the chunks before it exist, then the end of the merge, the summary and
    the removal of the chunk directory.

    The results file is stored in HDF5 chunks of ``survey.chunk_shots`` observations, as the
    chunk files are: appending copies their compressed chunks (see the module docstring).
    ``timings["chunk_appends_s"]`` is the part of ``chunks_s`` spent appending."""
    keep_freed_memory()    # before a local cluster forks its workers: they inherit it
    writer = ChunkWriter(chunk_dir, run_id=job.run_id)
    todo, done = _chunks_to_compute(writer, plan)
    bar = _progress_bar(plan, config.survey.tier, done) if progress else None
    t1 = time.perf_counter()
    one_chunk = plan.chunk_shots * plan.beams.n_beams * BYTES_PER_BEAM_SHOT
    summary_pass = SummaryPass(plan.beams.n_beams, budget_bytes=one_chunk, spill_dir=chunk_dir)
    merge = _start_merge(writer, out, plan, overwrite=overwrite, summary_pass=summary_pass,
                         bar=bar, scheduler=scheduler)
    appends_s = _compute(executor, job, todo, plan, merge, writer, bar, scheduler)
    timings.update(executor.timings)
    timings["chunks_s"] = time.perf_counter() - t1
    timings["chunk_appends_s"] = appends_s
    t2 = time.perf_counter()
    try:
        with merge:
            path = merge.finish()
    except BaseException as exc:
        raise_run_fault(exc, writer, plan.n_chunks, scheduler)
        raise
    # Every variable read back before the chunks go: they are the only other copy.
    verify_results_file(path, plan.n_shots, plan.beams.n_beams, block_obs=4 * plan.chunk_shots,
                        stored_chunks=merge.stored_chunks)
    files = [writer.chunk_path(i) for i in range(plan.n_chunks)]
    summary = summary_of_chunks(files, path, config.survey.tier, config.seed,
                                plan.beams.n_beams, 0.0, budget_bytes=one_chunk,
                                first_pass=summary_pass)
    shutil.rmtree(chunk_dir, ignore_errors=True)
    timings["merge_s"] = time.perf_counter() - t2
    summary["elapsed_s"] = time.perf_counter() - t0
    return RunResult(path, summary, timings)


def _chunks_to_compute(writer: ChunkWriter, plan) -> tuple[list[int], set[int]]:
    """(the chunks to compute, the finished ones). A resumed run's chunks whose seals do not
    vouch for them are removed (never merged), with a warning naming each."""
    for i, why in writer.check_chunks().items():
        warnings.warn(f"chunk {i} ({writer.chunk_path(i)}): {why}; computing it again",
                      stacklevel=2)
        writer.discard(i)
    done = {i for i in writer.completed_chunks() if writer.is_ready(i)}
    return [i for i in range(plan.n_chunks) if i not in done], done


def _progress_bar(plan, tier: str, done: set[int]):
    """A tqdm bar of the run's shot-beams, the finished chunks' already counted."""
    from tqdm import tqdm

    n_beams = plan.beams.n_beams
    return tqdm(total=plan.n_shots * n_beams, unit="shot", desc=f"run {tier}", leave=False,
                initial=sum(plan.chunk_times(i).size for i in done) * n_beams)


def _start_merge(writer: ChunkWriter, out: Path, plan, *, overwrite: bool,
                 summary_pass: SummaryPass, bar, scheduler) -> ChunkMerge:
    """The results file's merge, feeding the summary's first pass as it appends chunks."""
    try:
        return writer.start_merge(
            out, [plan.chunk_times(i).size for i in range(plan.n_chunks)], overwrite=overwrite,
            obs_chunk=plan.chunk_shots, on_append_variables=SUMMARY_VARIABLES,
            on_append=lambda values: summary_pass.add(*(values[k] for k in SUMMARY_VARIABLES)))
    except BaseException as exc:
        if bar:
            bar.close()
        raise_run_fault(exc, writer, plan.n_chunks, scheduler)
        raise


def _compute(executor: Executor, job: ChunkJob, todo: list[int], plan, merge: ChunkMerge,
             writer: ChunkWriter, bar, scheduler) -> float:
    """The chunks ``todo`` on ``executor``, each appended to the results file when it can be
    (see :attr:`.executors.Executor.appends_while_running`); returns the seconds spent
    appending. On a fault the unfinished results file is removed."""
    appends_s = 0.0

    def append_ready():
        nonlocal appends_s
        t = time.perf_counter()
        merge.append_ready()
        appends_s += time.perf_counter() - t

    try:
        append_ready()   # the chunks a resumed run has already
        # run_chunk: looked up here at each run (tests replace it in this module)
        executor.run(run_chunk, job, todo, plan, progress=bar,
                     on_chunk=append_ready if executor.appends_while_running else None)
    except BaseException as exc:
        merge.abort()
        raise_run_fault(exc, writer, plan.n_chunks, scheduler)
        raise
    finally:
        if bar:
            bar.close()
    return appends_s
