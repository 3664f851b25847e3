"""``chirplidar run``: a mission over its scene, chunk by chunk, into a CF trajectory NetCDF file.

mission.toml -> instrument + [scene] + [platform] + [attitude] + [beams] + [survey]
  plan (path, beams, shot clock) -> per chunk: rays and footprint sub-rays on the terrain
  -> returns through the tier (link | rf) -> per-shot variables -> results.build_dataset
  -> atomic NetCDF write.

The scene's ``effects`` list is the run's ``effects.enabled`` (DESIGN.md: a scene enables
effects); their parameters come from the instrument's ``[effects.*]`` sections.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from ..config.loader import ConfigError, config_flat, config_with, load_mission
from . import measure
from .results import build_dataset, write_netcdf
from .survey import chunk_geometry, chunk_seeds, check_crosses_scene, plan_survey

TIERS = ("link", "baseband", "rf")
NO_SURFACE_CODE = -1


@dataclass(frozen=True)
class RunResult:
    path: Path
    dataset: object
    summary: dict


def _config_toml(config) -> str:
    import tomli_w

    from ..config.loader import _unflatten

    return tomli_w.dumps(_unflatten(config_flat(config)))


def default_output(mission_path) -> Path:
    return Path("outputs") / (Path(mission_path).stem + ".nc")


def prepare(mission_path, *, overrides=(), tier=None, seed=None, cache_dir=None):
    """Load and check everything a run needs, before any shot: (config, scene, plan)."""
    from .scene import load_scene

    mission_path = Path(mission_path)
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
    scene = load_scene(scene_path, cache_dir=cache_dir)
    try:
        config = config_with(config, {"effects.enabled": list(scene.effects)})
    except ConfigError as exc:
        raise ConfigError(f"{src} with scene {scene_path.name} (effects = "
                          f"{list(scene.effects)}): {str(exc).removeprefix('override: ')}") from None
    if config.survey is not None and config.survey.tier == "baseband":
        from ..tiers.baseband import check_supported

        try:
            check_supported(config)
        except ValueError as exc:
            raise ConfigError(f"{src}: survey.tier = 'baseband': {exc}") from None
    plan = plan_survey(config, scene, src)
    check_crosses_scene(plan, scene, config, src)
    return config, scene, plan


def _per_shot(geom, meas) -> dict:
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
        "off_nadir_angle": geom.off_nadir_rad, "azimuth_angle": geom.azimuth_rad,
        "incidence_angle": np.where(hit, geom.incidence_rad, nan),
        "range_true": rng_true,
        "range_measured": r_meas,
        "range_error": rng_true - r_meas,
        "h_li_true": xyz[..., 2],
        "h_li": h_meas,
        "snr_db": meas["snr_db"],
        "received_power": meas["received_power"],
        "beat_frequency": meas["beat_frequency"],
        "beat_width": meas["beat_width"],
        "footprint_diameter": 2.0 * geom.beam_radius_m,
        "detected": meas["detected"],
        "surface_type": np.where(hit, geom.material, NO_SURFACE_CODE),
    }
    return out


def summarise(ds, path, elapsed_s: float) -> dict:
    det = ds["detected"].values
    err = ds["range_error"].values[det == 1]
    snr = ds["snr_db"].values[det == 1]
    n_obs = int(ds.sizes["obs"])
    return {
        "output": str(path), "tier": ds.attrs.get("tier", ""), "seed": int(ds.attrs["seed"]),
        "beams": int(ds.sizes["trajectory"]), "shots": n_obs,
        "returns": int(det.size), "detected": int(np.sum(det == 1)),
        "below_threshold": int(np.sum(det == 0)), "no_surface": int(np.sum(det == 2)),
        "median_snr_db": float(np.median(snr)) if snr.size else float("nan"),
        "range_error_mean_m": float(np.mean(err)) if err.size else float("nan"),
        "range_error_std_m": float(np.std(err)) if err.size else float("nan"),
        "range_error_rms_m": float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan"),
        "range_error_p95_abs_m": float(np.percentile(np.abs(err), 95)) if err.size else float("nan"),
        "elapsed_s": elapsed_s,
    }


def format_summary(s: dict) -> str:
    pct = 100.0 * s["detected"] / s["returns"] if s["returns"] else 0.0
    lines = [
        f"chirplidar run: {s['shots']} shots x {s['beams']} beam(s), tier {s['tier']}, "
        f"seed {s['seed']}, {s['elapsed_s']:.1f} s",
        f"  detected         {s['detected']} of {s['returns']} ({pct:.1f} %); "
        f"{s['below_threshold']} below threshold, {s['no_surface']} with no surface in the beam",
        f"  median SNR       {s['median_snr_db']:.1f} dB (detected shots)",
        f"  range error      mean {s['range_error_mean_m'] * 100:.2f} cm, std "
        f"{s['range_error_std_m'] * 100:.2f} cm, RMS {s['range_error_rms_m'] * 100:.2f} cm, "
        f"95 % |err| < {s['range_error_p95_abs_m'] * 100:.2f} cm",
        f"  output           {s['output']}",
    ]
    return "\n".join(lines)


def run_mission(mission_path, *, overrides=(), tier=None, out=None, seed=None,
                overwrite=False, progress=False, cache_dir=None, date_created=None) -> RunResult:
    """Run a survey mission and write its results; returns the path, dataset and summary.

    ``out`` defaults to ``outputs/<mission name>.nc``. An existing ``out`` raises
    FileExistsError before any work unless ``overwrite``; the file is written atomically, so an
    interrupted run leaves any previous file intact.
    """
    t0 = time.perf_counter()
    out = Path(out) if out is not None else default_output(mission_path)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists: pass --overwrite to replace it (nothing was run)")
    if out.suffix != ".nc":
        raise ConfigError(f"--out {out}: the results file must end in .nc")
    config, scene, plan = prepare(mission_path, overrides=overrides, tier=tier, seed=seed,
                                  cache_dir=cache_dir)
    sv = config.survey
    if plan.n_shots == 0:
        raise ConfigError(f"{mission_path}: survey span {sv.start_s:g}..{sv.stop_s} s at "
                          f"{sv.prf_hz:g} Hz holds no shot")
    seeds = chunk_seeds(config.seed, plan.n_chunks)
    parts = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=plan.n_shots * plan.beams.n_beams, unit="shot", desc=f"run {sv.tier}",
                   leave=False)
    try:
        for i in range(plan.n_chunks):  # chunks bound the memory; shots inside are vectorised
            t = plan.chunk_times(i)
            try:
                geom = chunk_geometry(plan, scene, config, t, seeds[i], sv.subrays_per_beam)
            except ValueError as exc:
                raise ConfigError(f"{mission_path}: [platform]: {exc}") from None
            if sv.tier in ("rf", "baseband"):
                measure_tier = measure.measure_rf if sv.tier == "rf" else measure.measure_baseband
                meas = measure_tier(config, scene, geom, seeds[i],
                                    progress=bar.update if bar else None)
            else:
                meas = measure.measure_link(config, scene, geom, seeds[i])
                if bar:
                    bar.update(t.size * plan.beams.n_beams)
            parts.append(_per_shot(geom, meas))
    finally:
        if bar:
            bar.close()
    per_shot = {k: np.concatenate([p[k] for p in parts], axis=0).T for k in parts[0]}
    materials = {NO_SURFACE_CODE: "no_surface",
                 **{c: name for c, name in enumerate(scene.terrain.material_names)}}
    per_shot["beam"] = np.arange(plan.beams.n_beams)
    ds = build_dataset(per_shot, epsg=scene.epsg, epoch_iso=sv.epoch_utc,
                       config_toml=_config_toml(config), seed=config.seed,
                       software_version=__version__, materials=materials,
                       title=f"chirplidar survey: {Path(mission_path).stem} over {scene.name}",
                       date_created=date_created)
    ds.attrs.update({
        "tier": sv.tier, "mission_file": str(Path(mission_path)),
        "scene_file": str(scene.path), "scene_configuration": scene.text,
        "platform": config.platform.kind, "beam_pattern": config.beams.pattern,
    })
    path = write_netcdf(ds, out, overwrite=overwrite)
    return RunResult(path, ds, summarise(ds, path, time.perf_counter() - t0))
