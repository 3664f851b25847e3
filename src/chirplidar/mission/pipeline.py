"""The per-chunk pipeline of a run: geometry -> returns through the tier -> per-shot records ->
one chunk file.

Every chunk (``survey.chunk_shots`` shots) is computed by :func:`run_chunk`, a module-level
function of small, picklable arguments (a :class:`ChunkJob` and the chunk index): it prepares the
mission once per process (a small cache keyed by the job, :func:`prepared_mission`), computes
the chunk's geometry (:func:`.survey.chunk_geometry`: rays and footprint sub-rays on the
terrain), its measurement through the run's tier (:func:`measure_chunk`), the per-shot
variables (:func:`per_shot_variables`) and the results dataset (:func:`results_dataset`), and
writes ``chunk_NNNNN.nc`` atomically into the run's chunk directory. A chunk's result depends
only on (configuration, scene, plan, chunk index) -- its random streams are child ``index`` of
``SeedSequence(seed)`` -- so chunks may run in any order, in any process (the executors of
:mod:`.executors`), and give the same file as a serial run.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from shapely.geometry import Polygon, box

from .. import __version__
from ..config.loader import ConfigError, config_flat
from . import measure
from .manifest import sha256_text
from .preflight import prepare
from .results import ChunkWriter, build_dataset
from .survey import chunk_geometry, chunk_seeds, survey_polygon_xy

#: ``surface_type`` of a shot whose beam meets no surface.
NO_SURFACE_CODE = -1


def config_toml(config) -> str:
    """The resolved configuration as TOML text (the results file's ``configuration``)."""
    import tomli_w

    from ..config.loader import unflatten

    return tomli_w.dumps(unflatten(config_flat(config)))


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

    @property
    def run_id(self) -> str:
        """The identity a run's chunks are sealed with (:class:`.results.ChunkWriter`): its
        configuration, scene and creation date."""
        return f"{self.configuration_sha256}/{self.scene_sha256}/{self.date_created}"


_PREPARED: OrderedDict = OrderedDict()   # per process: job key -> (config, scene, plan)
_PREPARED_MAX = 2
_PREPARED_LOCK = threading.RLock()        # workers with several threads share the cache


def _job_key(job: ChunkJob) -> tuple:
    return (job.mission_path, tuple(job.overrides), job.tier, job.seed, job.cache_dir,
            job.configuration_sha256, job.scene_sha256)


def remember_prepared(job: ChunkJob, prepared: tuple) -> None:
    """Keep ``prepared`` = (config, scene, plan) of ``job`` in this process's cache (a run does
    before its local workers fork: they inherit it)."""
    key = _job_key(job)
    with _PREPARED_LOCK:
        _PREPARED[key] = prepared
        _PREPARED.move_to_end(key)
        while len(_PREPARED) > _PREPARED_MAX:
            _PREPARED.popitem(last=False)


def forget_prepared(job: ChunkJob) -> None:
    """Drop ``job`` from this process's cache (its workers keep theirs)."""
    with _PREPARED_LOCK:
        _PREPARED.pop(_job_key(job), None)


def prepared_mission(job: ChunkJob) -> tuple:
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
            ("the resolved configuration", sha256_text(config_toml(config)),
             job.configuration_sha256),
            (f"the scene file {scene.path}", sha256_text(scene.text), job.scene_sha256))
            if now != then]
        if changed:
            raise ConfigError(f"{job.mission_label}: {' and '.join(changed)} changed on disk "
                              f"since the run started (chunks in {job.chunk_dir}); rerun it")
        remember_prepared(job, (config, scene, plan))
        return config, scene, plan


def measure_chunk(config, scene, geom, seq, progress=None) -> dict:
    """The measurement of one chunk through the run's tier (the one place that dispatches on
    ``survey.tier``). ``progress(n)`` is called with the number of finished shot-beams."""
    if config.survey.tier == "rf":
        return measure.measure_rf(config, scene, geom, seq, progress=progress)
    if config.survey.tier == "baseband":
        return measure.measure_baseband(config, scene, geom, seq, progress=progress)
    if config.survey.tier == "pulsed":
        from .measure_pulsed import measure_pulsed

        return measure_pulsed(config, scene, geom, seq, progress=progress)
    meas = measure.measure_link(config, scene, geom, seq)
    if progress is not None:
        progress(int(geom.range_true_m.size))
    return meas


def _height_sigma_m(config, geom, meas, r_meas, det) -> np.ndarray:
    """(n, b) predicted 1-sigma error of the measured height of the detected shots (NaN
    elsewhere): the Cramer-Rao spread of the beat frequency (Rife & Boorstyn 1974,
    ``tiers.link.crb_sigma_f_hz``) at the shot's SNR, for a tone of the duration 0.886 / (3 dB
    width) that its beat width implies, turned into range by c / (2 n kappa) and into height by
    the height change per metre of range along the beam (its vertical component). A pulsed
    instrument's range bound comes from its tier (``range_sigma``: the arrival time's
    Cramer-Rao bound of its expected waveform)."""
    from ..channel.lab import lab_budget
    from ..tiers.link import crb_sigma_f_hz
    from ..units import SPEED_OF_LIGHT_M_S

    if config.kind == "pulsed":   # the pulsed tier's own bound for its estimator
        sigma_r = meas["range_sigma"]
        ok = det & np.isfinite(sigma_r)
    else:
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


def per_shot_variables(config, geom, meas) -> dict:
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
        "pulse_width": meas.get("pulse_width", np.full((n, b), nan)),
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
                       epoch_iso=sv.epoch_utc, config_toml=config_toml(config),
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


def pilot_chunk(config, scene, geom, seq) -> None:
    """A chunk's work after its geometry, as :func:`run_chunk` does it -- measurement,
    per-shot variables, dataset, compressed file (written to a temporary directory and
    removed) -- for the run's estimate (:func:`.preflight.run_estimate`)."""
    import tempfile

    from .results import write_netcdf

    meas = measure_chunk(config, scene, geom, seq)
    per_shot = {k: np.ascontiguousarray(v.T)
                for k, v in per_shot_variables(config, geom, meas).items()}
    ds = results_dataset(per_shot, config, scene, "pilot", "2026-01-01T00:00:00Z")
    with tempfile.TemporaryDirectory(prefix="chirplidar-pilot-") as tmp:
        write_netcdf(ds, Path(tmp) / "pilot.nc", obs_chunk=max(1, ds.sizes["obs"]))


def run_chunk(job: ChunkJob, index: int, progress=None) -> Path:
    """Compute chunk ``index`` of ``job`` and write it atomically as ``chunk_NNNNN.nc`` in
    ``job.chunk_dir``; returns its path. Pure in its arguments (a rerun rewrites the same file),
    so any process may run it (Dask workers included)."""
    config, scene, plan = prepared_mission(job)
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
    meas = measure_chunk(config, scene, geom, seq, progress)
    per_shot = {k: np.ascontiguousarray(v.T)
                for k, v in per_shot_variables(config, geom, meas).items()}
    ds = results_dataset(per_shot, config, scene, job.mission_label, job.date_created,
                         job.planner_warnings)
    # Compressed here, in the results file's HDF5 chunks: the merge copies them as they are.
    # The directory is not created here: a straggler of a run that is over cannot leave a
    # manifest-less chunk.
    return ChunkWriter(job.chunk_dir, create=False, run_id=job.run_id).write(
        index, ds, overwrite=True, obs_chunk=plan.chunk_shots)
