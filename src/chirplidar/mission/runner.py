"""``chirplidar run``: a mission over its scene, chunk by chunk, into a CF trajectory NetCDF file.

mission.toml -> instrument + [scene] + [platform] + [attitude] + [beams] + [survey]
  plan (path, beams, shot clock) -> per chunk (:func:`run_chunk`): rays and footprint sub-rays
  on the terrain -> returns through the tier (link | baseband | rf) -> per-shot variables ->
  results.build_dataset -> one atomic chunk file -> streamed merge into the results file.

The scene's ``effects`` list is the run's ``effects.enabled`` (DESIGN.md: a scene enables
effects); their parameters come from the instrument's ``[effects.*]`` sections.

Chunks, resume and workers
--------------------------
Every chunk (``survey.chunk_shots`` shots) is computed by :func:`run_chunk`, a module-level
function of small, picklable arguments (a :class:`ChunkJob` and the chunk index): it prepares the
mission once per process (a small cache keyed by the job), computes geometry, measurement and
the per-shot variables and writes ``chunk_NNNNN.nc`` atomically into the chunk directory beside
the output (``<out>.chunks/``, e.g. ``outputs/greenland_uav.nc.chunks/``). A chunk's result
depends only on (configuration, scene, plan, chunk index) -- its random streams are child
``index`` of ``SeedSequence(seed)`` -- so chunks may run in any order, in any process, and give
the same file as a serial run.

The chunk directory also holds ``manifest.json`` (written atomically before any chunk): mission
file, resolved configuration and its SHA-256, seed, tier, scene file and the SHA-256 of its
text, the SHA-256 of the terrain's DEM or mesh file, shot and chunk counts, software version and
the ``date_created`` of the run, so that a resumed run (``resume=True``) writes the same global
attributes as an uninterrupted one. A run killed at any moment loses no finished chunk;
``--resume`` skips them, removes temp files of killed writes and refuses a manifest that does
not match the current run. Each chunk is sealed (``chunk_NNNNN.json``: index, run, SHA-256,
:class:`results.ChunkWriter`): a resumed run computes again, with a warning naming it, any chunk
whose seal does not vouch for it, and the merge checks each seal before copying a chunk. The
output is locked (``<out>.lock``, :func:`_output_lock`) for the run's life.

Finished chunks are appended to the results file in chunk order as soon as they and the
chunks before them exist (:class:`results.ChunkMerge`: a temp file beside the output, renamed
onto it atomically at the end; chunk slice by chunk slice, so memory stays bounded by one chunk
whatever the mission length). The results file is stored in HDF5 chunks of
``survey.chunk_shots`` observations, and each chunk file is written compressed in that layout
by the process that computed it, so appending copies its compressed HDF5 chunks as they are:
with ``workers=N`` this process does it while the workers compute later chunks (on a given
``scheduler``, whose workers may be threads of this process, after the last chunk: netCDF
calls must not run in two threads at once). The summary's first pass reads the chunks as they
are appended. When every chunk is in, the file is renamed into place, the summary is finished
and the chunk directory is removed once the file has been read back (every variable).

``workers=N`` (N > 1) runs the chunks on a ``dask.distributed.LocalCluster(n_workers=N,
threads_per_worker=1, processes=True)``; ``scheduler=ADDRESS`` on an existing cluster (the
mission, scene, cache and output paths must then be visible to the workers under the same
absolute paths). On Linux the local cluster's workers are forked after the mission is prepared
(they inherit it); elsewhere, and on an existing cluster, each worker process prepares it once.
Without either option, chunks run serially in this process (no Dask cluster or client).

Test hook: the environment variable ``CHIRPLIDAR_TEST_CHUNK_DELAY_S`` (seconds, default 0) makes
a serial run, or a Dask worker (set in the worker's environment), sleep after each chunk file is
written, so that tests can kill a run, a worker or the scheduler between chunks reliably. It
changes no result.

Faults: a full disk, a missing permission or a failing file system while a chunk, the manifest
or the results file is written, and a lost ``--scheduler``, stop the run with a
:class:`RunError`: one line naming the file (or scheduler), how many chunks are finished and
kept, and what to do (``--resume``). A chunk folder with no finished chunk is removed, so that
it does not block the next run. Output folders that cannot be written are refused before any
work.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import functools
import hashlib
import json
import math
import os
import shutil
import sys
import threading
import time
import uuid
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from shapely.geometry import Polygon, box

from .. import __version__
from ..config.loader import (ConfigError, config_flat, config_with, load_mission,
                             scene_overrides)
from . import measure, preflight
from .results import (
    BYTES_PER_BEAM_SHOT,
    DETECTED_FLAG_VALUES,
    NETCDF_LOCK,
    ChunkWriter,
    build_dataset,
    read_netcdf,
    verify_results_file,
    write_bytes_atomic,
    write_error,
)
from .survey import (check_crosses_scene, chunk_geometry, chunk_seeds, plan_survey,
                     survey_polygon_xy)

#: The codes of the ``detected`` flag the summary counts (0 .. 5).
N_DETECTED_CODES = DETECTED_FLAG_VALUES.size

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

TIERS = ("link", "baseband", "rf")
NO_SURFACE_CODE = -1
MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = "chirplidar-run-chunks/1"
CHUNK_DELAY_ENV = "CHIRPLIDAR_TEST_CHUNK_DELAY_S"
# Manifest keys that identify a run: a resumed run must match them all.
_IDENTITY = ("format", "mission_file", "configuration_sha256", "seed", "tier", "scene_file",
             "scene_sha256", "input_files_sha256", "n_shots", "n_beams", "n_chunks",
             "chunk_shots", "software_version")


class RunError(Exception):
    """A run stopped by a fault outside the simulation -- a full disk, a missing permission, a
    failing file system, the Dask scheduler lost -- as one line naming the file or address,
    what is kept and what to do. The finished (sealed) chunks are kept for ``--resume``.
    ``errno``: the OS error number, when there is one; ``exit_code``: the command line's
    (:data:`EXIT_IO` for file-system faults, 1 otherwise)."""

    def __init__(self, message: str, os_errno: int | None = None):
        super().__init__(message)
        self.errno = os_errno

    @property
    def exit_code(self) -> int:
        return EXIT_IO if self.errno else 1


#: Exit code of a run stopped by a file-system fault (disk full, permission, I/O error):
#: sysexits.h's EX_IOERR.
EXIT_IO = 74


@dataclass(frozen=True)
class RunResult:
    """Output path, summary and timings of a run. ``dataset`` reads the results file into memory
    on first access (the run itself never holds the whole mission in memory)."""

    path: Path
    summary: dict
    timings: dict = field(default_factory=dict)

    @functools.cached_property
    def dataset(self):
        return read_netcdf(self.path)


def _config_toml(config) -> str:
    import tomli_w

    from ..config.loader import _unflatten

    return tomli_w.dumps(_unflatten(config_flat(config)))


def _file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def default_output(mission_path) -> Path:
    return Path("outputs") / (Path(mission_path).stem + ".nc")


def chunk_dir_for(out) -> Path:
    """The chunk directory of a run writing ``out``: ``<out>.chunks`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".chunks")


def prepare(mission_path, *, overrides=(), tier=None, seed=None, cache_dir=None):
    """Load and check everything a run needs, before any shot: (config, scene, plan)."""
    from .scene import load_scene

    mission_path = Path(mission_path)
    if mission_path.is_dir():
        raise ConfigError(f"{mission_path}: is a directory, not a mission file")
    if not mission_path.is_file():
        raise ConfigError(f"{mission_path}: mission file does not exist")
    config = load_mission(mission_path, overrides)
    src = str(mission_path)
    if config.scene is None:
        raise ConfigError(f"{src}: a survey run needs a [scene] section with file = "
                          "\"../scenes/NAME.toml\"")
    extra = {}
    if tier is not None:
        if tier not in TIERS:
            raise ConfigError(f"--tier {tier}: choose one of {', '.join(TIERS)}")
        extra["survey.tier"] = tier
    if seed is not None:
        extra["seed"] = int(seed)
    if extra:
        config = config_with(config, extra)
    scene_path = (mission_path.parent / config.scene.file).resolve()
    if not scene_path.is_file():
        raise ConfigError(f"{src}: scene.file: {config.scene.file} does not exist "
                          f"(looked for {scene_path})")
    changes = scene_overrides(config)
    try:
        scene = load_scene(scene_path, cache_dir=cache_dir, overrides=changes)
    except ConfigError as exc:
        if not changes:
            raise
        raise ConfigError(f"{exc} (with the mission's scene keys "
                          f"{', '.join('scene.' + k for k in changes)})") from None
    try:
        config = config_with(config, {"effects.enabled": list(scene.effects)})
    except ConfigError as exc:
        raise ConfigError(f"{src} with scene {scene_path.name} (effects = "
                          f"{list(scene.effects)}): {str(exc).removeprefix('override: ')}") from None
    if config.survey is not None and config.survey.tier == "baseband":
        from ..config.instrument import instrument_from_config
        from ..tiers.registry import get_tier

        try:
            get_tier("baseband").check(instrument_from_config(config))
        except ValueError as exc:
            raise ConfigError(f"{src}: survey.tier = 'baseband': {exc}") from None
    plan = plan_survey(config, scene, src)
    measure.check_range_window(config, src)
    check_crosses_scene(plan, scene, config, src)
    return config, scene, plan


def preflight_run(mission_path, *, overrides=(), tier=None, seed=None, cache_dir=None,
                  cores=1, estimate=True):
    """What a run checks before any work, and what ``chirplidar run --dry-run`` shows:
    :func:`prepare`, the planner's warnings (issued as :class:`.preflight.PlannerWarning`) and,
    if ``estimate``, the run's size (:func:`.preflight.run_estimate`, else None). Returns
    (config, scene, plan, planner warnings, estimate)."""
    config, scene, plan = prepare(mission_path, overrides=overrides, tier=tier, seed=seed,
                                  cache_dir=cache_dir)
    sv = config.survey
    if plan.n_shots == 0:
        raise ConfigError(f"{mission_path}: survey span {sv.start_s:g}..{sv.stop_s} s at "
                          f"{sv.prf_hz:g} Hz holds no shot")
    notes = tuple(preflight.planner_warnings(config, scene, plan))
    for text in notes:
        warnings.warn(text, preflight.PlannerWarning, stacklevel=2)
    size = (preflight.run_estimate(config, scene, plan, cores=cores, measure_chunk=_measure)
            if estimate else None)
    return config, scene, plan, notes, size


def _measure(config, scene, geom, seq, progress=None) -> dict:
    """The measurement of one chunk through the run's tier (the one place that dispatches on
    ``survey.tier``). ``progress(n)`` is called with the number of finished shot-beams."""
    if config.survey.tier == "rf":
        return measure.measure_rf(config, scene, geom, seq, progress=progress)
    if config.survey.tier == "baseband":
        return measure.measure_baseband(config, scene, geom, seq, progress=progress)
    meas = measure.measure_link(config, scene, geom, seq)
    if progress is not None:
        progress(int(geom.range_true_m.size))
    return meas


def _height_sigma_m(config, geom, meas, r_meas, det) -> np.ndarray:
    """(n, b) predicted 1-sigma error of the measured height of the detected shots (NaN
    elsewhere): the Cramer-Rao spread of the beat frequency (Rife & Boorstyn 1974,
    ``tiers.link.crb_sigma_f_hz``) at the shot's SNR, for a tone of the duration 0.886 / (3 dB
    width) that its beat width implies, turned into range by c / (2 n kappa) and into height by
    the height change per metre of range along the beam (its vertical component)."""
    from ..channel.lab import lab_budget
    from ..tiers.link import crb_sigma_f_hz
    from ..units import SPEED_OF_LIGHT_M_S

    width = meas["beat_width"]
    ok = det & (width > 0)
    snr = 10.0 ** (np.where(ok, meas["snr_db"], 0.0) / 10.0)
    t_eff = 0.886 / np.where(ok, width, 1.0)
    rate = lab_budget(config).rate_hz_per_s
    sigma_r = (crb_sigma_f_hz(snr, config.processing.rbw_hz, t_eff) * SPEED_OF_LIGHT_M_S
               / (2.0 * config.channel.group_index * rate))
    r = np.where(ok, r_meas, 0.0)
    dz_dr = geom.point_at_range(r + 1.0)[..., 2] - geom.point_at_range(r)[..., 2]
    return np.where(ok, sigma_r * np.abs(dz_dr), np.nan)


def _per_shot(config, geom, meas) -> dict:
    """Schema variables (n, b) of one chunk (transposed to (b, n) when assembled)."""
    n, b = geom.range_true_m.shape
    hit = np.isfinite(geom.range_true_m)
    nan = np.nan
    rng_true = np.where(hit, geom.range_true_m, nan)
    det = meas["detected"] == 1
    r_meas = meas["range_measured"]
    h_meas = np.where(det, geom.point_at_range(np.where(det, r_meas, 0.0))[..., 2], nan)
    xyz = geom.hit_xyz_m
    out = {
        "delta_time": np.broadcast_to(geom.t_s[:, None], (n, b)),
        "x": xyz[..., 0], "y": xyz[..., 1],
        "platform_x": np.broadcast_to(geom.platform_xyh[:, 0:1], (n, b)),
        "platform_y": np.broadcast_to(geom.platform_xyh[:, 1:2], (n, b)),
        "platform_altitude": np.broadcast_to(geom.platform_xyh[:, 2:3], (n, b)),
        "track": np.broadcast_to(geom.track[:, None], (n, b)),
        "off_nadir_angle": geom.off_nadir_rad, "azimuth_angle": geom.azimuth_rad,
        "incidence_angle": np.where(hit, geom.incidence_rad, nan),
        "range_true": rng_true,
        "range_measured": r_meas,
        "range_error": rng_true - r_meas,
        "h_li_true": xyz[..., 2],
        "h_li": h_meas,
        "h_li_sigma": _height_sigma_m(config, geom, meas, r_meas, det),
        "snr_db": meas["snr_db"],
        "received_power": meas["received_power"],
        "beat_frequency": meas["beat_frequency"],
        "beat_width": meas["beat_width"],
        "footprint_diameter": 2.0 * geom.beam_radius_m,
        "detected": meas["detected"],
        "surface_type": np.where(hit, geom.material, NO_SURFACE_CODE),
    }
    return out


def results_dataset(per_shot: dict, config, scene, mission_label: str, date_created: str,
                    planner_warnings=()):
    """The results dataset (schema, CF metadata, global attributes) of ``per_shot`` arrays of
    shape (n_beams, n_shots): a chunk of a run, or a whole run assembled in memory.
    ``planner_warnings`` (:func:`.preflight.planner_warnings`) go in an attribute of that name,
    one per line, when there are any."""
    sv = config.survey
    materials = {NO_SURFACE_CODE: "no_surface",
                 **{c: name for c, name in enumerate(scene.terrain.material_names)}}
    n_beams = next(iter(per_shot.values())).shape[0]
    ds = build_dataset({**per_shot, "beam": np.arange(n_beams)}, epsg=scene.epsg,
                       epoch_iso=sv.epoch_utc, config_toml=_config_toml(config),
                       seed=config.seed, software_version=__version__, materials=materials,
                       title=f"chirplidar survey: {Path(mission_label).stem} over {scene.name}",
                       date_created=date_created)
    x0, x1, y0, y1 = scene.bounds_xy
    ds.attrs.update({
        "tier": sv.tier, "mission_file": str(Path(mission_label)),
        "scene_file": str(scene.path), "scene_configuration": scene.text,
        "platform": config.platform.kind, "beam_pattern": config.beams.pattern,
        "scene_extent_wkt": box(x0, y0, x1, y1).wkt,
    })
    polygon = survey_polygon_xy(config, scene)
    if polygon is not None:
        ds.attrs["survey_polygon_wkt"] = Polygon(polygon).wkt
    if planner_warnings:
        ds.attrs["planner_warnings"] = "\n".join(planner_warnings)
    return ds


# ---------------------------------------------------------------------------- one chunk
@dataclass(frozen=True)
class ChunkJob:
    """What a process needs to compute a chunk of a run: small and picklable (paths, not data).

    ``mission_path``, ``cache_dir`` and ``chunk_dir`` are absolute; ``mission_label`` is the
    mission path as the user gave it (messages and the ``mission_file`` attribute). The two
    hashes pin the resolved configuration and the scene text: a process that prepares the
    mission itself checks that it got the same run. ``planner_warnings``: the run's
    (:func:`.preflight.planner_warnings`, found once before any work), for every chunk's file.
    """

    mission_path: str
    mission_label: str
    overrides: tuple
    tier: str | None
    seed: int | None
    cache_dir: str | None
    chunk_dir: str
    date_created: str
    configuration_sha256: str
    scene_sha256: str
    planner_warnings: tuple = ()


_PREPARED: OrderedDict = OrderedDict()   # per process: job key -> (config, scene, plan)
_PREPARED_MAX = 2
_PREPARED_LOCK = threading.RLock()        # workers with several threads share the cache


def _job_key(job: ChunkJob) -> tuple:
    return (job.mission_path, tuple(job.overrides), job.tier, job.seed, job.cache_dir,
            job.configuration_sha256, job.scene_sha256)


def _remember(job: ChunkJob, prepared: tuple) -> None:
    key = _job_key(job)
    with _PREPARED_LOCK:
        _PREPARED[key] = prepared
        _PREPARED.move_to_end(key)
        while len(_PREPARED) > _PREPARED_MAX:
            _PREPARED.popitem(last=False)


def _prepared(job: ChunkJob) -> tuple:
    """(config, scene, plan) of ``job``, prepared once per process (scene load, survey plan)
    and kept in a small cache; ConfigError if the files changed since the run started (their
    hashes differ from the job's)."""
    key = _job_key(job)
    with _PREPARED_LOCK:   # one preparation per process, also with several worker threads
        hit = _PREPARED.get(key)
        if hit is not None:
            _PREPARED.move_to_end(key)
            return hit
        config, scene, plan = prepare(job.mission_path, overrides=list(job.overrides),
                                      tier=job.tier, seed=job.seed, cache_dir=job.cache_dir)
        changed = [name for name, now, then in (
            ("the resolved configuration", _sha256(_config_toml(config)),
             job.configuration_sha256),
            (f"the scene file {scene.path}", _sha256(scene.text), job.scene_sha256))
            if now != then]
        if changed:
            raise ConfigError(f"{job.mission_label}: {' and '.join(changed)} changed on disk "
                              f"since the run started (chunks in {job.chunk_dir}); rerun it")
        _remember(job, (config, scene, plan))
        return config, scene, plan


def run_chunk(job: ChunkJob, index: int, progress=None) -> Path:
    """Compute chunk ``index`` of ``job`` and write it atomically as ``chunk_NNNNN.nc`` in
    ``job.chunk_dir``; returns its path. Pure in its arguments (a rerun rewrites the same file),
    so any process may run it (Dask workers included)."""
    config, scene, plan = _prepared(job)
    if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)) \
            or not 0 <= int(index) < plan.n_chunks:
        raise ValueError(f"index must be a chunk index in 0..{plan.n_chunks - 1}, got {index!r}")
    index = int(index)
    seq = chunk_seeds(config.seed, plan.n_chunks)[index]
    t = plan.chunk_times(index)
    try:
        geom = chunk_geometry(plan, scene, config, t, seq, config.survey.subrays_per_beam)
    except ValueError as exc:
        raise ConfigError(f"{job.mission_label}: [platform]: {exc}") from None
    meas = _measure(config, scene, geom, seq, progress)
    per_shot = {k: np.ascontiguousarray(v.T) for k, v in _per_shot(config, geom, meas).items()}
    ds = results_dataset(per_shot, config, scene, job.mission_label, job.date_created,
                         job.planner_warnings)
    # Compressed here, in the results file's HDF5 chunks: the merge copies them as they are.
    # The directory is not created here: a straggler of a run that is over cannot leave a
    # manifest-less chunk.
    return ChunkWriter(job.chunk_dir, create=False, run_id=_run_id(job)).write(
        index, ds, overwrite=True, obs_chunk=plan.chunk_shots)


def _run_id(job: ChunkJob) -> str:
    """The identity a run's chunks are sealed with: its configuration, scene and creation
    date."""
    return f"{job.configuration_sha256}/{job.scene_sha256}/{job.date_created}"


def _dask_run_chunk(job: ChunkJob, index: int) -> str:
    """:func:`run_chunk` in a Dask worker, the path back as a string.

    No thread limit is set here: a chunk's kernels are single-threaded numpy, scipy FFTs (one
    worker thread by default) and embree queries (a serial run of the demo uses one core), and
    spawned Dask workers start with OMP/MKL/OPENBLAS_NUM_THREADS=1 anyway.

    xarray, asked to write a file inside a Dask worker, would guard every netCDF call with a
    cluster-wide lock (one round trip to the scheduler each: hundreds per chunk file, measured
    ~25 % of a chunk's time on the demo). Each chunk is its own file, so chunks run under
    the synchronous scheduler: xarray then takes a lock local to this process. (Worker threads
    of one process write their chunk files one at a time: :data:`results.NETCDF_LOCK`.)
    """
    # Dask computes a finished task again when the worker holding its result dies: a chunk
    # already sealed for this run is not written again (the merge may be reading it, and its
    # seal would be missing while it is rewritten).
    writer = ChunkWriter(job.chunk_dir, create=False, run_id=_run_id(job))
    with contextlib.suppress(ValueError):   # (a bad index: run_chunk says why)
        if writer.is_ready(index) and writer.chunk_problem(index) is None:
            return str(writer.chunk_path(index))
    with _synchronous_dask():
        path = str(run_chunk(job, index))
    delay = _chunk_delay_s()   # the test hook, as in a serial run
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


# ---------------------------------------------------------------------------- manifest
def _default_date_created() -> str:
    """Now (UTC, ISO 8601, seconds), or ``$SOURCE_DATE_EPOCH`` when set (reproducible files)."""
    env = os.environ.get("SOURCE_DATE_EPOCH")
    if env is not None and env.strip():
        try:
            t = int(env)
        except ValueError:
            raise ConfigError(f"SOURCE_DATE_EPOCH={env!r}: must be an integer number of "
                              "seconds since 1970-01-01 UTC") from None
    else:
        t = int(time.time())
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).isoformat().replace("+00:00", "Z")


def _manifest(mission_path: Path, config, scene, plan, config_toml: str) -> dict:
    return {
        "format": MANIFEST_FORMAT,
        "mission_file": str(mission_path.resolve()),
        "configuration_sha256": _sha256(config_toml),
        "seed": int(config.seed),
        "tier": config.survey.tier,
        "scene_file": str(Path(scene.path).resolve()),
        "scene_sha256": _sha256(scene.text),
        # the terrain's own files (mesh, DEM): the mission's TLE and instrument files are in
        # the resolved configuration, the scene in its text
        "input_files_sha256": {str(p): _file_sha256(p) for p in scene.input_files},
        "n_shots": plan.n_shots,
        "n_beams": plan.beams.n_beams,
        "n_chunks": plan.n_chunks,
        "chunk_shots": plan.chunk_shots,
        "software_version": __version__,
        "configuration": config_toml,
    }


def _flat_toml(text: str) -> dict:
    out = {}

    def walk(node, prefix):
        for k, v in node.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                out[f"{prefix}{k}"] = v
    try:
        walk(tomllib.loads(text), "")
    except (tomllib.TOMLDecodeError, AttributeError):
        return {}
    return out


def _manifest_differences(old: dict, new: dict) -> list[str]:
    diffs = []
    for key in _IDENTITY:
        if old.get(key) == new.get(key):
            continue
        if key == "configuration_sha256":
            a, b = _flat_toml(str(old.get("configuration", ""))), _flat_toml(new["configuration"])
            keys = sorted(k for k in set(a) | set(b)
                          if a.get(k) != b.get(k) and k not in ("seed", "survey.tier"))
            if keys:
                shown = ", ".join(f"{k} = {a.get(k, '(unset)')!r} there, "
                                  f"{b.get(k, '(unset)')!r} now" for k in keys[:5])
                more = f" and {len(keys) - 5} more" if len(keys) > 5 else ""
                diffs.append(f"configuration: {shown}{more}")
            elif old.get("seed") == new.get("seed") and old.get("tier") == new.get("tier"):
                diffs.append("configuration: the resolved configuration differs")
            continue
        if key == "scene_sha256":
            diffs.append("scene: the scene file's text differs")
            continue
        if key == "input_files_sha256":
            a, b = old.get(key) or {}, new.get(key) or {}
            changed = sorted(p for p in set(a) | set(b) if a.get(p) != b.get(p))
            if not changed:   # a manifest written before the key existed: no terrain files
                continue
            diffs.append(f"terrain file(s) {', '.join(changed)} changed on disk since the "
                         "chunks were computed")
            continue
        diffs.append(f"{key}: {old.get(key)!r} there, {new.get(key)!r} now")
    return diffs


def _read_manifest(chunk_dir: Path) -> dict | None:
    path = chunk_dir / MANIFEST_NAME
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: unreadable run manifest ({exc}); pass --overwrite to "
                          "discard the chunks in that directory") from None
    if not isinstance(data, dict) or not isinstance(data.get("date_created"), str):
        raise ConfigError(f"{path}: not a chirplidar run manifest; pass --overwrite to discard "
                          "the chunks in that directory")
    return data


def _write_manifest(chunk_dir: Path, manifest: dict) -> None:
    text = json.dumps(manifest, indent=1, sort_keys=True) + "\n"
    write_bytes_atomic(chunk_dir / MANIFEST_NAME, text.encode("utf-8"), overwrite=True)


def _remove_temporaries(chunk_dir: Path, out: Path) -> None:
    """Temp files of writes killed mid-way: chunks, the manifest and the results file."""
    ChunkWriter(chunk_dir).remove_temporaries()
    for pattern, where in ((f".{MANIFEST_NAME}.*.tmp", chunk_dir), (f".{out.name}.*.tmp",
                                                                      out.parent)):
        for p in where.glob(pattern):
            p.unlink(missing_ok=True)


# ---------------------------------------------------------------------------- summary
def summarise(ds, path, elapsed_s: float) -> dict:
    """Summary of a results dataset in memory (the reference for :func:`_summary_of_chunks`)."""
    det = ds["detected"].values
    err = ds["range_error"].values[det == 1]
    snr = ds["snr_db"].values[det == 1]
    n_obs = int(ds.sizes["obs"])
    return {
        "output": str(path), "tier": ds.attrs.get("tier", ""), "seed": int(ds.attrs["seed"]),
        "beams": int(ds.sizes["trajectory"]), "shots": n_obs,
        "returns": int(det.size), "detected": int(np.sum(det == 1)),
        "below_threshold": int(np.sum(det == 0)), "no_surface": int(np.sum(det == 2)),
        "outside_range_gate": int(np.sum(det == 3)), "doppler_displaced": int(np.sum(det == 4)),
        "range_ambiguous": int(np.sum(det == 5)),
        "median_snr_db": float(np.median(snr)) if snr.size else float("nan"),
        "range_error_mean_m": float(np.mean(err)) if err.size else float("nan"),
        "range_error_std_m": float(np.std(err)) if err.size else float("nan"),
        "range_error_rms_m": float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan"),
        "range_error_p95_abs_m": float(np.percentile(np.abs(err), 95)) if err.size else float("nan"),
        "elapsed_s": elapsed_s,
    }


_SIGN = np.uint64(1 << 63)


def _sortable_keys(x: np.ndarray) -> np.ndarray:
    """uint64 keys in the order of the (finite) float64 values ``x``."""
    b = np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)
    return np.where(b & _SIGN, ~b, b | _SIGN)


def _key_value(key: int) -> float:
    k = np.uint64(key)
    b = k ^ _SIGN if k & _SIGN else ~k
    return float(np.array([b], dtype=np.uint64).view(np.float64)[0])


def _order_statistics(blocks, ranks: list[list[int]], first_pass=None) -> list[list[float]]:
    """Exact order statistics of several streams, with memory bounded by one block.

    ``blocks()`` yields, per block, a tuple of 1-D float64 arrays (one per stream, finite
    values) and is re-iterated; ``ranks[s]`` are 0-based ranks into the sorted union of stream
    ``s``. A 4-pass radix select on 16-bit digits of order-preserving uint64 keys (2^16 counters
    per rank). ``first_pass(block)``, if given, is also called on every block of the first pass.
    """
    prefix = [[0] * len(r) for r in ranks]
    left = [list(r) for r in ranks]
    for shift in (48, 32, 16, 0):
        hist = [[np.zeros(1 << 16, dtype=np.int64) for _ in r] for r in ranks]
        for block in blocks():
            if shift == 48 and first_pass is not None:
                first_pass(block)
            for s, x in enumerate(block):
                if not ranks[s]:
                    continue
                keys = _sortable_keys(x)
                for j in range(len(ranks[s])):
                    sel = keys if shift == 48 else keys[
                        (keys >> np.uint64(shift + 16)) == np.uint64(prefix[s][j] >> (shift + 16))]
                    digit = ((sel >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.int64)
                    hist[s][j] += np.bincount(digit, minlength=1 << 16)
        for s in range(len(ranks)):
            for j in range(len(ranks[s])):
                c = np.cumsum(hist[s][j])
                d = int(np.searchsorted(c, left[s][j], side="right"))
                left[s][j] -= int(c[d - 1]) if d else 0
                prefix[s][j] |= d << shift
    return [[_key_value(p) for p in ps] for ps in prefix]


def quantile_ranks(n: int, q: float) -> tuple[int, int, float]:
    """``np.percentile``'s linear method on n sorted values: (lower rank, upper rank, weight of
    the upper); :func:`quantile_between` of the two order statistics is the quantile q."""
    v = (n - 1) * q
    lo = min(math.floor(v), n - 1)
    hi = min(lo + 1, n - 1)
    return lo, hi, (0.0 if v >= n - 1 else v - lo)


def quantile_between(a: float, b: float, g: float) -> float:
    """numpy's linear interpolation between the order statistics a <= b with weight g of b
    (its rounding: from b downwards when g >= 1/2)."""
    diff = b - a
    return b - diff * (1 - g) if g >= 0.5 else a + diff * g


#: The chunk variables the summary reads.
SUMMARY_VARIABLES = ("detected", "snr_db", "range_error")


class _SummaryPass:
    """First pass of :func:`_summary_of_chunks`, fed chunk by chunk in chunk order with the
    stored ``detected``, ``snr_db`` and ``range_error`` values: counts, sums, and the detected
    shots' SNR and range errors while they fit in ``budget_bytes``."""

    def __init__(self, n_beams: int, budget_bytes: int):
        self.n_beams, self.budget_bytes = n_beams, budget_bytes
        self.n_obs = 0
        self.counts = np.zeros(N_DETECTED_CODES, dtype=np.int64)
        self.s1 = self.s2 = 0.0
        self.kept: list | None = []

    @staticmethod
    def detected_columns(det, snr, err):
        """(detected flags, SNR and range errors of the detected shots), flattened."""
        det = np.asarray(det).ravel()
        ok = det == 1
        return (det, np.asarray(snr).ravel()[ok].astype(np.float64),
                np.asarray(err).ravel()[ok].astype(np.float64))

    def add(self, det, snr, err) -> None:
        det, snr, err = self.detected_columns(det, snr, err)
        self.n_obs += det.size // max(self.n_beams, 1)
        self.counts += np.bincount(det.astype(np.int64),
                                   minlength=N_DETECTED_CODES)[:N_DETECTED_CODES]
        self.s1 += float(np.sum(err))
        self.s2 += float(np.sum(err * err))
        if self.kept is not None:
            self.kept.append((snr, err))
            if 16 * int(self.counts[1]) > self.budget_bytes:
                self.kept = None


def _summary_of_chunks(files: list[Path], path, tier: str, seed: int, n_beams: int,
                       elapsed_s: float, budget_bytes: int,
                       first_pass: _SummaryPass | None = None) -> dict:
    """:func:`summarise` of the run whose chunk files are ``files``, chunk by chunk, in memory
    bounded by ``budget_bytes`` (the run passes one chunk's size).

    The detected shots' SNR and range errors are kept while they fit in the budget; then the
    statistics are numpy's own (as :func:`summarise`). Beyond it they are streamed: counts
    and quantiles exactly as numpy's (``np.median``; ``np.percentile``, linear method) from
    :func:`_order_statistics`, mean, standard deviation and RMS as sums over chunks (last-bit
    differences from numpy's pairwise sums); five passes over the chunk files.
    ``first_pass``: the first pass, already fed with every chunk (a run feeds it while it
    appends chunks to the results file); without it the files are read.
    """
    import netCDF4

    def stored():
        for f in files:
            with NETCDF_LOCK, netCDF4.Dataset(f) as src:
                cols = []
                for name in SUMMARY_VARIABLES:
                    v = src[name]
                    v.set_auto_maskandscale(False)
                    cols.append(v[...])
            yield cols

    def columns():
        return (_SummaryPass.detected_columns(*cols) for cols in stored())

    if first_pass is None:
        first_pass = _SummaryPass(n_beams, budget_bytes)
        for cols in stored():
            first_pass.add(*cols)
    n_obs, counts, kept = first_pass.n_obs, first_pass.counts, first_pass.kept
    s1, s2 = first_pass.s1, first_pass.s2
    n_det = int(counts[1])
    nan = float("nan")
    median = mean = std = rms = p95 = nan
    if n_det and kept is not None:
        snr = np.concatenate([k[0] for k in kept])
        err = np.concatenate([k[1] for k in kept])
        median, mean, std = np.median(snr), np.mean(err), np.std(err)
        rms, p95 = np.sqrt(np.mean(err ** 2)), np.percentile(np.abs(err), 95)
    elif n_det:
        mean = s1 / n_det
        rms = math.sqrt(s2 / n_det)
        # np.median: the middle value or the mean of the middle two.
        mid = [n_det // 2] if n_det % 2 else [n_det // 2 - 1, n_det // 2]
        lo, hi, g = quantile_ranks(n_det, 0.95)     # np.percentile(.., 95), linear method
        dev = [0.0]

        def add_dev(block):
            dev[0] += float(np.sum((block[2] - mean) ** 2))

        snr_q, err_q, _ = _order_statistics(
            lambda: ((snr, np.abs(err), err) for _, snr, err in columns()), [mid, [lo, hi], []],
            add_dev)
        std = math.sqrt(dev[0] / n_det)
        median = snr_q[0] if len(mid) == 1 else (snr_q[0] + snr_q[1]) / 2
        p95 = quantile_between(*err_q, g)
    return {
        "output": str(path), "tier": tier, "seed": int(seed), "beams": int(n_beams),
        "shots": int(n_obs), "returns": int(n_obs * n_beams), "detected": n_det,
        "below_threshold": int(counts[0]), "no_surface": int(counts[2]),
        "outside_range_gate": int(counts[3]), "doppler_displaced": int(counts[4]),
        "range_ambiguous": int(counts[5]),
        "median_snr_db": float(median), "range_error_mean_m": float(mean),
        "range_error_std_m": float(std), "range_error_rms_m": float(rms),
        "range_error_p95_abs_m": float(p95), "elapsed_s": elapsed_s,
    }


def format_summary(s: dict) -> str:
    pct = 100.0 * s["detected"] / s["returns"] if s["returns"] else 0.0
    lines = [
        f"chirplidar run: {s['shots']} shots x {s['beams']} beam(s), tier {s['tier']}, "
        f"seed {s['seed']}, {s['elapsed_s']:.1f} s",
        f"  detected         {s['detected']} of {s['returns']} ({pct:.1f} %); "
        f"{s['below_threshold']} below threshold, {s['no_surface']} with no surface in the beam"
        + "".join(f", {s[k]} {text}" for k, text in (
            ("outside_range_gate", "outside the range gate (window or processed band)"),
            ("doppler_displaced", "displaced by an uncompensated Doppler shift"),
            ("range_ambiguous", "ambiguous by a chirp period (reference delay)")) if s.get(k)),
    ]
    if s["detected"]:
        lines += [
            f"  median SNR       {s['median_snr_db']:.1f} dB (detected shots)",
            f"  range error      mean {s['range_error_mean_m'] * 100:.2f} cm, std "
            f"{s['range_error_std_m'] * 100:.2f} cm, RMS {s['range_error_rms_m'] * 100:.2f} cm, "
            f"95 % |err| < {s['range_error_p95_abs_m'] * 100:.2f} cm"]
    else:
        lines.append("  no shot detected: no SNR or range-error statistics")
    lines.append(f"  output           {s['output']}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- executing
#: Freed memory that glibc's malloc may keep for reuse (its trim threshold), see
#: :func:`_keep_freed_memory`.
MALLOC_KEEP_BYTES = 256 << 20
#: Blocks up to this size come from malloc's heap (reused), larger ones from mmap: glibc's
#: largest dynamic mmap threshold on 64-bit systems (DEFAULT_MMAP_THRESHOLD_MAX).
MALLOC_MMAP_THRESHOLD_BYTES = 32 << 20
_MALLOC_KEPT: list = []


def _keep_freed_memory() -> None:
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

def _chunk_delay_s() -> float:
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


def _run_serial(job: ChunkJob, todo: list[int], bar, on_chunk=None) -> None:
    """The missing chunks in this process; ``on_chunk()`` after each one."""
    delay = _chunk_delay_s()
    for i in todo:
        run_chunk(job, i, progress=bar.update if bar else None)
        if on_chunk is not None:
            on_chunk()
        if delay:
            time.sleep(delay)


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


def _worker_wait_s() -> float:
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


def _run_dask(job: ChunkJob, todo: list[int], plan, workers, scheduler, bar,
              timings: dict, on_chunk=None) -> None:
    """One Dask task per missing chunk; the progress bar follows completed futures and
    ``on_chunk()`` is called (in this process) as each one finishes. On an error or interrupt
    the other tasks are cancelled and the cluster closed; finished chunks stay."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError as exc:
        raise ConfigError(f"--workers/--scheduler need dask.distributed ({exc}); "
                          "pip install 'dask[distributed]'") from None
    t0 = time.perf_counter()
    cluster = client = None
    futures = []
    life = contextlib.ExitStack()   # settings held while our local cluster lives
    lost = False                    # the scheduler (--scheduler) is gone
    try:
        if scheduler is not None:
            try:
                client = Client(scheduler)   # dask's distributed.comm.timeouts.connect
            except (OSError, TimeoutError, ValueError) as exc:
                raise ConfigError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
            wait = _worker_wait_s()
            try:   # a scheduler with no worker would wait for ever, without a word
                client.wait_for_workers(1, timeout=wait)
            except (TimeoutError, OSError):
                raise ConfigError(f"--scheduler {scheduler}: no worker joined within {wait:g} s "
                                  f"({WORKER_WAIT_ENV}); start workers (`dask worker "
                                  f"{scheduler}`), then rerun with --resume") from None
        else:
            import dask

            # Linux: fork the worker processes from this one, after prepare(): they inherit the
            # imported modules and the prepared mission (configuration, scene, plan) in the
            # cache of _prepared, instead of paying both again per worker.
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
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1,
                                   processes=True, dashboard_address=None)
            client = Client(cluster)
        timings["cluster_start_s"] = time.perf_counter() - t0
        token = uuid.uuid4().hex[:12]
        shots = {}
        for i in todo:
            # priority: chunks start in chunk order, so that they can be appended as they end
            fut = client.submit(_dask_run_chunk, job, i, key=f"chirplidar-chunk-{token}-{i:05d}",
                                pure=False, retries=0, priority=-i)
            shots[fut.key] = plan.chunk_times(i).size * plan.beams.n_beams
            futures.append(fut)
        try:
            for fut in as_completed(futures):
                fut.result()   # re-raises a worker's error (ConfigError, ValueError, ...) as is
                if bar:
                    bar.update(shots[fut.key])
                if on_chunk is not None:
                    on_chunk()
        except Exception as exc:
            if scheduler is not None and _scheduler_lost(client, exc):
                raise _SchedulerLost(scheduler) from exc
            raise
        if cluster is not None:
            # Every chunk is in: our workers' shutdown can only log noise now (a heartbeat
            # in flight as the cluster closes logs a traceback, dask/distributed#7105; seen
            # about once in 50 runs). Never worth failing a finished run for.
            with contextlib.suppress(Exception):
                client.run(_quiet_worker_logs)
    except BaseException as exc:
        lost = isinstance(exc, _SchedulerLost)
        if client is not None and futures and not lost:
            try:
                if cluster is not None:   # our workers: their tasks' cancellation is no news
                    client.run(_quiet_worker_logs)
                client.cancel(futures)
            except Exception:  # noqa: BLE001, S110 - closing anyway; the original error matters
                pass
        raise
    finally:
        t1 = time.perf_counter()
        if client is not None:
            # With the scheduler lost, the client is trying to reconnect: closing it stops that,
            # and distributed logs the stop as an error with its traceback. The run reports the
            # loss itself, in one line.
            with _logs_muted("distributed.client") if lost else contextlib.nullcontext():
                client.close()
        if cluster is not None:
            cluster.close()
        life.close()
        timings["cluster_close_s"] = time.perf_counter() - t1


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
    :data:`results.NETCDF_LOCK` held by a thread it does not have, and wait for ever to write
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


class _SchedulerLost(Exception):
    """The client lost its connection to the run's ``--scheduler`` (:func:`_raise_run_fault`
    turns it into a :class:`RunError` that says which chunks are kept)."""


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


def _check_parallel_args(workers, scheduler) -> None:
    if workers is not None and (isinstance(workers, (bool, np.bool_))
                                or not isinstance(workers, (int, np.integer)) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if scheduler is not None:
        if workers is not None:
            raise ValueError("workers and scheduler are exclusive: give one of them")
        if not isinstance(scheduler, str) or not scheduler.strip():
            raise ValueError(f"scheduler must be an address such as tcp://host:8786, "
                             f"got {scheduler!r}")


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
    :class:`RunError` (one line; the finished chunks kept for ``resume``).
    """
    t0 = time.perf_counter()
    _check_parallel_args(workers, scheduler)
    out = check_output(out, mission_path, overwrite=overwrite)
    if out == default_output(mission_path):
        out.parent.mkdir(parents=True, exist_ok=True)   # outputs/: made for the default
    if out.parent.is_dir():
        _check_writable(out.parent, f"--out {out}")
        with _output_lock(out):
            return _run_locked(mission_path, out, overrides=overrides, tier=tier, seed=seed,
                               overwrite=overwrite, progress=progress, cache_dir=cache_dir,
                               date_created=date_created, workers=workers,
                               scheduler=scheduler, resume=resume, yes=yes, t0=t0)
    return _run_locked(mission_path, out, overrides=overrides, tier=tier, seed=seed,
                       overwrite=overwrite, progress=progress, cache_dir=cache_dir,
                       date_created=date_created, workers=workers, scheduler=scheduler,
                       resume=resume, yes=yes, t0=t0)


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
        _check_writable(out.parent, f"--out {out}")
    return out


LOCK_SUFFIX = ".lock"


def _check_writable(directory: Path, what: str) -> None:
    """ConfigError, before any work, unless this process may create files in ``directory``."""
    if os.access(directory, os.W_OK | os.X_OK):
        return
    try:
        read_only = bool(os.statvfs(directory).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        read_only = False
    reason = os.strerror(errno.EROFS if read_only else errno.EACCES).lower()
    raise ConfigError(f"{what}: cannot write in {directory}: {reason} (nothing was run)")


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # someone else's process: alive
        return True
    return True


@contextlib.contextmanager
def _output_lock(out: Path):
    """Hold ``<out>.lock`` (this process's pid, host and start) for the run's life: a second
    run on the same output is refused at once, naming the holder; a lock left by a process of
    this host that no longer runs is taken over with a warning."""
    import socket

    lock = out.with_name(out.name + LOCK_SUFFIX)
    me = {"pid": os.getpid(), "host": socket.gethostname(),
          "since": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()}
    for attempt in (0, 1):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            break
        except FileExistsError:
            try:
                holder = json.loads(lock.read_text(encoding="utf-8"))
                pid, host = int(holder["pid"]), str(holder["host"])
            except (OSError, ValueError, KeyError, TypeError):
                holder, pid, host = {}, -1, ""
            stale = host == me["host"] and pid > 0 and not _process_alive(pid)
            if not stale or attempt:
                who = (f"pid {pid} on {host} since {holder.get('since', '?')}" if holder
                       else "an unknown process")
                raise FileExistsError(f"{out}: another run is writing it ({who}; lock "
                                      f"{lock}); wait for it to finish, or delete the lock if "
                                      "that run is gone") from None
            warnings.warn(f"{lock}: taking over the lock of pid {pid}, which no longer runs",
                          stacklevel=3)
            lock.unlink(missing_ok=True)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(me, f)
    except BaseException as exc:   # e.g. a full disk: no lock left behind to block the next run
        lock.unlink(missing_ok=True)
        err = write_error(exc, lock)
        if err is not None and _is_os_fault(err):
            raise RunError(f"{_os_fault_text(err)}; nothing was run: "
                           f"{_FIXES.get(err.errno, 'fix that')}, then run again",
                           err.errno) from exc
        raise
    try:
        yield lock
    finally:
        lock.unlink(missing_ok=True)


def _run_locked(mission_path, out: Path, *, overrides, tier, seed, overwrite, progress,
                cache_dir, date_created, workers, scheduler, resume, yes, t0) -> RunResult:
    """:func:`run_mission` once the output's lock is held."""
    chunk_dir = chunk_dir_for(out)
    if chunk_dir.exists() and not (resume or overwrite):
        raise FileExistsError(
            f"{chunk_dir} holds the chunks of an unfinished run: pass --resume to finish it or "
            "--overwrite to discard it (nothing was run)")
    if chunk_dir.is_dir():
        _check_writable(chunk_dir, "--resume" if resume else "--overwrite")
    config, scene, plan, notes, estimate = preflight_run(
        mission_path, overrides=overrides, tier=tier, seed=seed, cache_dir=cache_dir,
        cores=workers or 1, estimate=progress or not yes)   # its pilot costs a second
    if progress:
        print(f"chirplidar run: {preflight.format_estimate(estimate)}", file=sys.stderr)
    if estimate is not None and estimate.large and not yes:
        raise ConfigError(f"{mission_path}: a large run ({preflight.format_estimate(estimate)}; "
                          f"the limits are {preflight.LARGE_RUN_HOURS:g} h and "
                          f"{preflight.LARGE_RUN_GB:g} GB): pass --yes to start it, or "
                          "--dry-run to see its plan (nothing was run)")
    if not out.parent.is_dir():   # (the default's outputs/ is made before the lock)
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
    timings = {"prepare_s": time.perf_counter() - t0}

    config_toml = _config_toml(config)
    manifest = _manifest(Path(mission_path), config, scene, plan, config_toml)
    old = None
    if chunk_dir.exists() and resume:
        if not chunk_dir.is_dir():
            raise ConfigError(f"{chunk_dir}: exists and is not a chunk directory")
        old = _read_manifest(chunk_dir)
        if old is None and ChunkWriter(chunk_dir).completed_chunks():
            raise ConfigError(f"{chunk_dir}: chunk files without a {MANIFEST_NAME}: cannot tell "
                              "which run they belong to; pass --overwrite to discard them")
        if old is not None:
            diffs = _manifest_differences(old, manifest)
            if date_created is not None and date_created != old["date_created"]:
                diffs.append(f"date_created: {old['date_created']!r} there, "
                             f"{date_created!r} now")
            if diffs:
                raise ConfigError(f"{chunk_dir}: --resume: the chunks there belong to a "
                                  f"different run ({'; '.join(diffs)}); rerun with the same "
                                  "settings, or pass --overwrite to discard them")
            date_created = old["date_created"]
        _remove_temporaries(chunk_dir, out)
    elif chunk_dir.exists():   # overwrite: discard the unfinished run (and its results temp)
        _remove_temporaries(chunk_dir, out)
        shutil.rmtree(chunk_dir)
    if old is None:
        if date_created is None:
            date_created = _default_date_created()
        try:
            chunk_dir.mkdir(exist_ok=True)
            _write_manifest(chunk_dir, {**manifest, "date_created": date_created})
        except BaseException as exc:   # e.g. a full disk: no chunk folder left to block a rerun
            if chunk_dir.is_dir() and not ChunkWriter(chunk_dir).completed_chunks():
                shutil.rmtree(chunk_dir, ignore_errors=True)
            if _is_os_fault(exc):
                raise RunError(f"{_os_fault_text(exc)}; no chunk was computed: "
                               f"{_FIXES.get(exc.errno, 'fix that')}, then run again",
                               exc.errno) from exc
            raise

    job = ChunkJob(
        mission_path=str(Path(mission_path).resolve()), mission_label=str(mission_path),
        overrides=tuple(str(o) for o in overrides), tier=tier,
        seed=None if seed is None else int(seed),
        cache_dir=None if cache_dir is None else str(Path(cache_dir).resolve()),
        chunk_dir=str(chunk_dir.resolve()), date_created=date_created,
        configuration_sha256=manifest["configuration_sha256"],
        scene_sha256=manifest["scene_sha256"], planner_warnings=notes)
    _remember(job, (config, scene, plan))
    try:
        return _execute(job, config, plan, out, chunk_dir, overwrite=overwrite,
                        progress=progress, workers=workers, scheduler=scheduler,
                        timings=timings, t0=t0)
    finally:
        _PREPARED.pop(_job_key(job), None)   # this process needs it no more (workers keep theirs)


#: What to do about a file-system fault, by its error number.
_FIXES = {errno.ENOSPC: "free some space", errno.EDQUOT: "free some space (disk quota)",
          errno.EACCES: "fix the permissions", errno.EPERM: "fix the permissions",
          errno.EROFS: "make the file system writable"}


def _os_fault_text(exc: OSError) -> str:
    """``cannot write PATH: no space left on device`` (one line) of an OSError of a write."""
    where = exc.filename if exc.filename is not None else "a file"
    reason = os.strerror(exc.errno).lower()   # (h5py puts its error stack in exc.strerror)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM):
        return f"cannot write {where}: {reason}"
    return f"{where}: {reason}"


def _is_os_fault(exc: BaseException) -> bool:
    """An OSError of the file system (with an error number), not of the run's own logic."""
    return (isinstance(exc, OSError) and not isinstance(exc, FileExistsError)
            and isinstance(exc.errno, int) and exc.errno > 0)


def _raise_run_fault(exc: BaseException, writer: ChunkWriter, n_chunks: int,
                     scheduler) -> None:
    """After ``exc`` stopped a run: a chunk folder with no sealed chunk is removed (nothing to
    resume, and it would block the next run); a fault outside the simulation (file system,
    lost scheduler) is raised as a :class:`RunError` saying what is kept and what to do.
    Returns (for the caller to re-raise ``exc``) otherwise."""
    chunk_dir = writer.path_dir
    kept = sum(1 for i in range(n_chunks) if writer.is_ready(i)) if chunk_dir.is_dir() else 0
    if not kept:   # (unsealed chunk files would be computed again anyway)
        shutil.rmtree(chunk_dir, ignore_errors=True)
    if isinstance(exc, _SchedulerLost):
        if kept:
            raise RunError(f"lost the Dask scheduler at {scheduler} after {kept} of {n_chunks} "
                           f"chunks; the finished chunks are kept in {chunk_dir}: run again "
                           "with --resume") from exc
        raise RunError(f"lost the Dask scheduler at {scheduler} before any of the {n_chunks} "
                       "chunks was finished: run again when it is back") from exc
    if _is_os_fault(exc):
        fix = _FIXES.get(exc.errno, "fix that")
        if kept:
            raise RunError(f"{_os_fault_text(exc)}; {kept} of {n_chunks} chunks done and "
                           f"kept in {chunk_dir}: {fix}, then run again with --resume",
                           exc.errno) from exc
        raise RunError(f"{_os_fault_text(exc)}; no chunk was finished, nothing is kept: {fix}, "
                       "then run again", exc.errno) from exc


def _execute(job: ChunkJob, config, plan, out: Path, chunk_dir: Path, *, overwrite: bool,
             progress: bool, workers, scheduler, timings: dict, t0: float) -> RunResult:
    """The missing chunks (serial or Dask), each appended to the results file (in chunk order)
    as soon as it and the chunks before it exist, then the end of the merge, the summary and
    the removal of the chunk directory.

    The results file is stored in HDF5 chunks of ``survey.chunk_shots`` observations, as the
    chunk files are: appending copies their compressed chunks (see the module docstring).
    ``timings["chunk_appends_s"]`` is the part of ``chunks_s`` spent appending."""
    sv = config.survey
    _keep_freed_memory()    # before a local cluster forks its workers: they inherit it
    writer = ChunkWriter(chunk_dir, run_id=_run_id(job))
    for i, why in writer.check_chunks().items():   # a resumed run's chunks: never merge these
        warnings.warn(f"chunk {i} ({writer.chunk_path(i)}): {why}; computing it again",
                      stacklevel=2)
        writer.discard(i)
    done = {i for i in writer.completed_chunks() if writer.is_ready(i)}
    todo = [i for i in range(plan.n_chunks) if i not in done]
    bar = None
    if progress:
        from tqdm import tqdm

        n_beams = plan.beams.n_beams
        bar = tqdm(total=plan.n_shots * n_beams, unit="shot", desc=f"run {sv.tier}",
                   leave=False, initial=sum(plan.chunk_times(i).size for i in done) * n_beams)
    t1 = time.perf_counter()
    one_chunk = plan.chunk_shots * plan.beams.n_beams * BYTES_PER_BEAM_SHOT
    summary_pass = _SummaryPass(plan.beams.n_beams, budget_bytes=one_chunk)
    try:
        merge = writer.start_merge(
            out, [plan.chunk_times(i).size for i in range(plan.n_chunks)], overwrite=overwrite,
            obs_chunk=plan.chunk_shots, on_append_variables=SUMMARY_VARIABLES,
            on_append=lambda values: summary_pass.add(*(values[k] for k in SUMMARY_VARIABLES)))
    except BaseException as exc:
        if bar:
            bar.close()
        _raise_run_fault(exc, writer, plan.n_chunks, scheduler)
        raise
    appends_s = [0.0]

    def append_ready():
        t = time.perf_counter()
        merge.append_ready()
        appends_s[0] += time.perf_counter() - t

    try:
        append_ready()   # the chunks a resumed run has already
        if scheduler is None and (workers is None or workers == 1):
            _run_serial(job, todo, bar, append_ready)
        else:
            # Appending reads and writes netCDF files, and netCDF/HDF5 calls must not run in
            # two threads of a process at once: only while the chunks are computed in worker
            # processes of our own cluster; on a given scheduler, whose workers may be threads
            # of this process, at the end.
            _run_dask(job, todo, plan, workers, scheduler, bar, timings,
                      append_ready if scheduler is None else None)
    except BaseException as exc:
        merge.abort()
        _raise_run_fault(exc, writer, plan.n_chunks, scheduler)
        raise
    finally:
        if bar:
            bar.close()
    timings["chunks_s"] = time.perf_counter() - t1
    timings["chunk_appends_s"] = appends_s[0]
    t2 = time.perf_counter()
    try:
        with merge:
            path = merge.finish()
    except BaseException as exc:
        _raise_run_fault(exc, writer, plan.n_chunks, scheduler)
        raise
    # Every variable read back before the chunks go: they are the only other copy.
    verify_results_file(path, plan.n_shots, plan.beams.n_beams, block_obs=4 * plan.chunk_shots)
    files = [writer.chunk_path(i) for i in range(plan.n_chunks)]
    summary = _summary_of_chunks(files, path, sv.tier, config.seed, plan.beams.n_beams, 0.0,
                                 budget_bytes=one_chunk, first_pass=summary_pass)
    shutil.rmtree(chunk_dir, ignore_errors=True)
    timings["merge_s"] = time.perf_counter() - t2
    summary["elapsed_s"] = time.perf_counter() - t0
    return RunResult(path, summary, timings)
