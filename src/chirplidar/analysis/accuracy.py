"""Accuracy against time (docs/architecture.md rule 1): every fidelity knob with its measured price.

The study runs the Chapter 5 homodyne bench (``missions/thesis_ch5_bench.toml``) at a few SNR points,
placed with the link tier (SNR falls 1 dB per dB of ``atm.Pattn``), and compares each tier and each
knob setting with a REFERENCE run on the same shots (same seeds, same channel draws):

point-target study (at every SNR point), reference = rf tier at the mission's settings:
    ``sample_rate``    rf ``simulation.sample_rate_hz`` (values above 2 x the chirp top)
    ``delay_method``   rf ``simulation.delay_method = "resample"`` with ``upsample_factor`` 1, 4, ...
    ``peak_method``    rf ``processing.peak_method`` (parabolic, bin; dtft is the reference)
    ``zero_pad``       rf ``processing.zero_pad_factor`` (2, 4; 1 is the reference)
    ``baseband_rate``  baseband tier, ``simulation.baseband_rate_hz`` (None = the tier's default)
    ``precision``      baseband tier, ``simulation.baseband_precision = "double"`` (the default,
                       "single", is the ``baseband_rate`` family's default-rate row)
    ``link``           link tier (closed form)
footprint study (at the highest SNR point), reference = rf with ``sub_rays_reference`` echoes:
    ``sub_rays``       a Gaussian beam (1/e^2 radius w at the target) on a plane tilted by
                       ``slope_deg``, sampled by k sub-rays (k = 1; 3 = a Gauss-Hermite line along
                       the fall line; 7, 19, 37, ... = hexagonal grids whose cells tile
                       r <= 1.5 w, step 3 w / (2 m + 1) for m rings), weights
                       exp(-2 r^2 / w^2), independent uniform carrier phases per shot and sub-ray
                       (a diffuse surface), extra round-trip delay 2 n_g x tan(slope) / c. rf and
                       baseband tiers (the link tier has no footprint).
turbulence study (at the highest SNR point), reference = rf with ``screen_reference`` pixels:
    ``screen``         ``effects.turbulence.screen_pixels`` of the frozen-flow phase screen, on a
                       100 m free-space path (Cn2 = 3e-13, specular target, D/r0 ~ 6): the link
                       tier at every size (the screen is its whole cost), the rf tier at the
                       default size. Every tier runs the rf chunks here, so that rf and link at
                       one size see the same screens.
pulsed study (:mod:`chirplidar.analysis.accuracy_pulsed`): the GLAS bench
(``missions/glas_bench.toml``, its own mission) through the pulsed tier at ``pulsed_snr_db``
(placed with the tier's own SNR), reference = the pulsed tier at 4 GHz with ``gaussian_fit``:
    ``pulse_sample_rate``  ``digitizer.sample_rate_hz`` (Gaussian fit, same record duration)
    ``pulse_estimator``    ``pulse_ranging.estimator`` at the mission's sample rate

Measured per setting: range RMS error (RMS of d_error over the shots, with its standard error and
the difference from the reference's RMS), bias, fraction of outliers (|d_error| beyond 5 chirp
range-resolution cells; pulsed: 5 x c tau / 2), mean and standard deviation of SNR and their
differences from the reference's, and seconds per shot: the median over the setting's chunks of
the chunk's wall time over its shots, after one untimed warm-up shot that fills the caches a long
run would have filled (the median keeps a shared machine's load spikes out of the price).

Shots run in chunks of ``batch`` shots (rf) with child seeds SeedSequence(seed, spawn_key=(point,
chunk)); the baseband and link tiers take all shots in one call except in the turbulence study,
where every tier uses the rf chunks so that all see the same screens (one screen per chunk).
The pulsed study runs chunks of ``pulsed_batch`` shots with spawn keys (1000 + point, chunk).
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .accuracy_pulsed import PULSE_ESTIMATORS, PULSED_FAMILIES, PULSED_SNR_DB
from . import accuracy_receivers as ar

MISSION_NAME = "thesis_ch5_bench.toml"
DEFAULT_SNR_DB = (10.0, 20.0, 30.0)
FAMILIES = ("sample_rate", "delay_method", "peak_method", "zero_pad", "baseband_rate", "precision",
            "link", "sub_rays", "screen", *ar.RECEIVER_FAMILIES, *PULSED_FAMILIES)
STUDIES = {"point target": ("sample_rate", "delay_method", "peak_method", "zero_pad",
                            "baseband_rate", "precision", "link"),
           "footprint": ("sub_rays",), "turbulence": ("screen",), "receivers": ar.RECEIVER_FAMILIES,
           "pulsed": PULSED_FAMILIES}
PEAK_METHODS = ("bin", "parabolic", "dtft")
HEX_COUNTS = tuple(3 * m * (m + 1) + 1 for m in range(16))   # 1, 7, 19, 37, 61, 91, 127, ...
OUTLIER_CELLS = 5.0     # |d_error| beyond this many chirp range-resolution cells is an outlier

# The turbulence study's channel: a 100 m free-space path in strong near-ground turbulence, the
# bench's 8" f/5 telescope with a 30 % obstruction into SMF-28 (as benchmarks.timing.EFFECT_SETTINGS), a
# specular target (exact turbulent coupling), frozen flow at 10 m/s with 10 ms between shots
# (0.1 m of screen per shot). D/r0 ~ 6.1, plane-wave Rytov variance ~ 0.1.
TURBULENCE_SETTINGS = {
    "channel.free_space": True, "channel.distance_m": 100.0, "channel.cn2_m_minus_2_3": 3e-13,
    "channel.group_index": 1.00027, "channel.target_reflectivity": 1.0,
    "channel.target_radius_m": 1e9, "channel.atmospheric_transmission": 1.0,
    "channel.optical_transmission": 1.0, "system.reference_delay_s": 0.0,
    "transmitter.tx_split_loss_db": 0.0,
    "effects.enabled": ["coupling", "turbulence"],
    "effects.coupling.obstruction_ratio": 0.3, "effects.coupling.focal_length_m": 1.0,
    "effects.coupling.mode_field_radius_m": 4.6e-6,
    "effects.coupling.fiber_numerical_aperture": 0.14, "effects.coupling.target": "specular",
    "effects.turbulence.fading": "frozen_flow", "effects.turbulence.outer_scale_m": 20.0,
    "effects.turbulence.transverse_speed_mps": 10.0, "effects.turbulence.shot_interval_s": 0.01,
}

COLUMNS = ("snr_target_db", "pattn_db", "study", "family", "tier", "setting", "knob", "value",
           "reference", "shots", "batch", "range_rms_m", "range_rms_se_m", "range_rms_diff_m",
           "range_bias_m", "outlier_frac", "snr_mean_db", "snr_std_db", "snr_error_db",
           "snr_std_error_db", "s_per_shot", "cost_vs_reference", "flags")


def default_mission_path() -> Path:
    from ..mission_files import default_mission_path as find

    return find(MISSION_NAME)


@dataclass(frozen=True)
class Setting:
    """One run of the study: a tier with configuration overrides (and footprint echoes)."""

    study: str
    family: str
    tier: str
    setting: str                 # short label (plot, tables)
    knob: str                    # the key varied ('' for the reference or a whole tier)
    value: str                   # its value, as text
    overrides: dict = field(default_factory=dict)
    sub_rays: int | None = None
    reference: bool = False


# ------------------------------------------------------------------------------ argument checks

def _check_ints(name: str, values, minimum: int) -> tuple[int, ...]:
    out = []
    for v in values:
        if isinstance(v, bool) or not float(v).is_integer() or int(v) < minimum:
            raise ValueError(f"{name} must be integers >= {minimum}; got {v!r}")
        out.append(int(v))
    return tuple(out)


def _check_args(config, snr_db, shots, batch, families, sample_rates_hz, upsample_factors,
                peak_methods, zero_pad_factors, baseband_rates_hz, sub_rays, sub_rays_reference,
                slope_deg, screen_pixels, screen_reference):
    snr = tuple(float(s) for s in snr_db)
    if not snr or not all(math.isfinite(s) for s in snr):
        raise ValueError(f"snr_db must be one or more finite SNR targets in dB; got {snr_db!r}")
    if len(set(snr)) != len(snr):
        raise ValueError(f"snr_db lists a value twice: {list(snr)}")
    if isinstance(shots, bool) or int(shots) != shots or shots < 2:
        raise ValueError(f"shots must be an integer >= 2 (an RMS over shots); got {shots!r}")
    if isinstance(batch, bool) or int(batch) != batch or batch < 1:
        raise ValueError(f"batch must be an integer >= 1; got {batch!r}")
    fams = FAMILIES if families is None else tuple(families)
    unknown = [f for f in fams if f not in FAMILIES]
    if unknown or not fams:
        raise ValueError(f"families must be a non-empty subset of {', '.join(FAMILIES)}; got "
                         f"{list(fams)!r}")
    top = config.waveform.f_stop_hz + config.waveform.f_offset_hz
    for fs in sample_rates_hz:
        if not (math.isfinite(fs) and fs > 2 * top):
            raise ValueError(f"sample_rates_hz must exceed 2 x the chirp top (f_stop_hz + "
                             f"f_offset_hz = {top:g} Hz), i.e. > {2 * top:g} Hz; got {fs:g}")
    _check_ints("upsample_factors", upsample_factors, 1)
    bad = [m for m in peak_methods if m not in PEAK_METHODS]
    if bad:
        raise ValueError(f"peak_methods must be among {', '.join(PEAK_METHODS)}; got {bad}")
    _check_ints("zero_pad_factors", zero_pad_factors, 1)
    for r in baseband_rates_hz:
        if r is not None and not (math.isfinite(r) and r > 0):
            raise ValueError(f"baseband_rates_hz must be positive rates in Hz or None (the "
                             f"tier's default); got {r!r}")
    ks = _check_ints("sub_rays", sub_rays, 1)
    (k_ref,) = _check_ints("sub_rays_reference", [sub_rays_reference], 1)
    for k in (*ks, k_ref):
        if k != 3 and k not in HEX_COUNTS:
            raise ValueError(f"sub-ray counts must be 1, 3 (a Gauss-Hermite line) or a hexagonal "
                             f"number 3m(m+1)+1 ({', '.join(map(str, HEX_COUNTS[:8]))}, ...); "
                             f"got {k}")
    if "sub_rays" in fams and ks and k_ref <= max(ks):
        raise ValueError(f"sub_rays_reference ({k_ref}) must exceed every compared sub-ray count "
                         f"(largest {max(ks)})")
    if not (0.0 <= slope_deg < 90.0):
        raise ValueError(f"slope_deg must lie in [0, 90); got {slope_deg!r}")
    px = _check_ints("screen_pixels", screen_pixels, 16)
    (px_ref,) = _check_ints("screen_reference", [screen_reference], 16)
    if "screen" in fams and px and px_ref <= max(px):
        raise ValueError(f"screen_reference ({px_ref}) must exceed every compared screen size "
                         f"(largest {max(px)})")
    return snr, int(shots), int(batch), fams, ks, k_ref, px, px_ref


# ------------------------------------------------------------------------------ building blocks

def pattn_for_snr(config, snr_db: float, *, start_db: float | None = None,
                  iterations: int = 3) -> float:
    """``channel.extra_attenuation_db`` (atm.Pattn) at which the link tier's mean SNR is
    ``snr_db`` (it falls 1 dB per dB of attenuation; a few Newton steps of slope -1)."""
    from ..config import config_with
    from ..channel.lab import simulate_lab

    pattn = config.channel.extra_attenuation_db if start_db is None else start_db
    for _ in range(iterations):
        cfg = config_with(config, {"channel.extra_attenuation_db": pattn})
        snr = float(np.mean(simulate_lab(cfg, "link", np.random.default_rng(0))["SNR"]))
        if not math.isfinite(snr):
            raise ValueError(f"the link tier reads SNR = {snr} at atm.Pattn = {pattn:g} dB: no "
                             "return to place the SNR points with")
        if abs(snr - snr_db) < 1e-3:
            break
        pattn += snr - snr_db
    return float(pattn)


def slope_footprint_echoes(config, k: int, slope_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(delay offsets in s, power weights) of k sub-rays over the beam's footprint on a plane
    tilted by ``slope_deg`` (see the module docstring). Offsets have weighted mean 0."""
    from ..optics import beam_radius_m
    from ..units import SPEED_OF_LIGHT_M_S

    ch = config.channel
    w = float(beam_radius_m(ch.beam_radius_m, ch.divergence_half_angle_rad, ch.distance_m))
    if k == 1:
        x, weight = np.zeros(1), np.ones(1)
    elif k == 3:
        sigma = 0.5 * w                     # exp(-2 x^2 / w^2) = exp(-x^2 / (2 sigma^2))
        x = np.array([-np.sqrt(3.0) * sigma, 0.0, np.sqrt(3.0) * sigma])
        weight = np.array([1 / 6, 2 / 3, 1 / 6])
    else:
        m = HEX_COUNTS.index(k)
        step = 3.0 * w / (2 * m + 1)        # the hexagonal cells tile r <= 1.5 w
        pts = [(0.0, 0.0)]
        for ring in range(1, m + 1):        # hexagonal rings: 6 ring points per ring index
            for side in range(6):
                a0, a1 = np.pi / 3 * side, np.pi / 3 * (side + 1)
                c0 = ring * np.array([np.cos(a0), np.sin(a0)])
                c1 = ring * np.array([np.cos(a1), np.sin(a1)])
                for j in range(ring):
                    pts.append(tuple(step * (c0 + (c1 - c0) * j / ring)))
        xy = np.array(pts)
        x = xy[:, 0]
        weight = np.exp(-2.0 * np.sum(xy * xy, axis=1) / w**2)
    dtau = 2.0 * ch.group_index * x * np.tan(np.radians(slope_deg)) / SPEED_OF_LIGHT_M_S
    return dtau, weight / weight.sum()


def _stats(outs: list[dict], threshold_m: float) -> dict[str, Any]:
    d = np.concatenate([np.asarray(o["d_error"], float) for o in outs])
    s = np.concatenate([np.asarray(o["SNR"], float) for o in outs])
    flags = sorted({str(f) for o in outs for f in o.get("flags", [])})
    fd, fs = d[np.isfinite(d)], s[np.isfinite(s)]
    if fd.size < d.size or fs.size < s.size:
        flags.append(f"non_finite:{d.size - fd.size}_range,{s.size - fs.size}_snr")
    ms = float(np.mean(fd * fd)) if fd.size else math.nan
    rms = math.sqrt(ms) if fd.size else math.nan
    se = (float(np.std(fd * fd, ddof=1) / math.sqrt(fd.size)) / (2 * rms)
          if fd.size > 1 and rms > 0 else math.nan)
    return {"range_rms_m": rms, "range_rms_se_m": se,
            "range_bias_m": float(np.mean(fd)) if fd.size else math.nan,
            "outlier_frac": float(np.mean(np.abs(fd) > threshold_m)) if fd.size else math.nan,
            "snr_mean_db": float(np.mean(fs)) if fs.size else math.nan,
            "snr_std_db": float(np.std(fs, ddof=1)) if fs.size > 1 else math.nan,
            "flags": ",".join(flags)}


def _run(setting: Setting, cfg, seed: int, point: int, shots: int, chunk: int,
         echo_offsets=None, echo_weights=None, echo_phases=None) -> tuple[list[dict], float]:
    """All shots of one setting: (tier outputs per chunk, seconds per shot: the median over the
    chunks of the chunk's wall time over its shots, the warm-up excluded)."""
    from ..channel.lab import simulate_lab
    from ..tiers.echoes import Echoes

    def fn(cfg, rng, **kw):
        return simulate_lab(cfg, setting.tier, rng, **kw)

    def echoes(rows: slice):
        if echo_offsets is None:
            return {}
        return {"echoes": Echoes(echo_offsets, echo_weights, echo_phases[rows])}

    # Warm-up on an unrelated stream: fills the caches (modulator fields, FFT plans, Bessel tables,
    # screen covariances) that a long run fills once.
    fn(cfg, np.random.default_rng([seed, 2**31 - 1]), batch=1, **echoes(slice(0, 1)))
    outs, per_shot = [], []
    for c, start in enumerate(range(0, shots, chunk)):
        m = min(chunk, shots - start)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(point, c)))
        t0 = time.perf_counter()
        outs.append(fn(cfg, rng, batch=m, **echoes(slice(start, start + m))))
        per_shot.append((time.perf_counter() - t0) / m)
    # The median over chunks: a shared machine's load spikes in one chunk do not set the price.
    return outs, float(np.median(per_shot))


def _point_settings(config, fams, sample_rates_hz, upsample_factors, peak_methods,
                    zero_pad_factors, baseband_rates_hz) -> list[Setting]:
    sim, proc = config.simulation, config.processing
    study = "point target"
    ref = Setting(study, "reference", "rf",
                  f"rf ref ({sim.sample_rate_hz / 1e9:g} GHz, {proc.peak_method}, "
                  f"zp{proc.zero_pad_factor})", "", "mission", reference=True)
    out = [ref]
    if "sample_rate" in fams:
        out += [Setting(study, "sample_rate", "rf", f"Fs {fs / 1e9:g} GHz",
                        "simulation.sample_rate_hz", f"{fs:g}",
                        {"simulation.sample_rate_hz": float(fs)})
                for fs in sample_rates_hz if fs != sim.sample_rate_hz]
    if "delay_method" in fams:
        out += [Setting(study, "delay_method", "rf", f"resample x{u}",
                        "simulation.delay_method+upsample_factor", f"resample,{u}",
                        {"simulation.delay_method": "resample", "simulation.upsample_factor": u})
                for u in upsample_factors]
    if "peak_method" in fams:
        out += [Setting(study, "peak_method", "rf", f"peak {m}", "processing.peak_method", m,
                        {"processing.peak_method": m})
                for m in peak_methods if m != proc.peak_method]
    if "zero_pad" in fams:
        out += [Setting(study, "zero_pad", "rf", f"zero pad x{z}", "processing.zero_pad_factor",
                        str(z), {"processing.zero_pad_factor": z})
                for z in zero_pad_factors if z != proc.zero_pad_factor]
    if "baseband_rate" in fams:
        for r in baseband_rates_hz:
            over = {} if r is None else {"simulation.baseband_rate_hz": float(r)}
            label = "baseband (default rate)" if r is None else f"baseband {r / 1e6:g} MHz"
            out.append(Setting(study, "baseband_rate", "baseband", label,
                               "simulation.baseband_rate_hz", "default" if r is None else f"{r:g}",
                               over))
    if "precision" in fams:
        out.append(Setting(study, "precision", "baseband", "baseband double precision",
                           "simulation.baseband_precision", "double",
                           {"simulation.baseband_precision": "double"}))
    if "link" in fams:
        out.append(Setting(study, "link", "link", "link", "", "closed form"))
    return out


# ------------------------------------------------------------------------------------ the study

def accuracy_study(mission: str | Path | None = None, overrides: Sequence[str] = (), *,
                   snr_db: Sequence[float] = DEFAULT_SNR_DB, shots: int = 100, seed: int = 2024,
                   batch: int = 20, families: Sequence[str] | None = None,
                   sample_rates_hz: Sequence[float] = (0.7e9, 1.0e9, 1.5e9, 2.0e9),
                   upsample_factors: Sequence[int] = (1, 4, 16),
                   peak_methods: Sequence[str] = ("parabolic", "bin"),
                   zero_pad_factors: Sequence[int] = (2, 4),
                   baseband_rates_hz: Sequence[float | None] = (None, 50e6, 100e6, 400e6),
                   sub_rays: Sequence[int] = (1, 3, 7, 19, 37), sub_rays_reference: int = 127,
                   slope_deg: float = 10.0, footprint_shots: int | None = None,
                   screen_pixels: Sequence[int] = (16, 24, 32, 64), screen_reference: int = 128,
                   turbulence_shots: int | None = None,
                   pulsed_mission: str | Path | None = None,
                   pulsed_snr_db: Sequence[float] = PULSED_SNR_DB,
                   pulse_sample_rates_hz: Sequence[float] = (0.25e9, 0.5e9, 1e9, 2e9),
                   pulse_reference_rate_hz: float = 4e9,
                   pulse_estimators: Sequence[str] = PULSE_ESTIMATORS,
                   pulsed_shots: int | None = None, pulsed_batch: int = 100,
                   progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Run the accuracy-versus-time study; one dict per setting with the keys of ``COLUMNS``.

    ``shots`` per setting of the point-target study; the footprint study runs ``footprint_shots``
    (default 0.6 x shots: its rf reference sums 127 echoes per shot) and the turbulence study
    ``turbulence_shots`` (default 3 x shots: its SNR fades by ~6 dB rms and successive shots are
    correlated). The pulsed study runs ``pulsed_shots`` (default 10 x shots: a pulsed shot costs
    a fraction of a millisecond) in chunks of ``pulsed_batch``.

    ``mission`` defaults to missions/thesis_ch5_bench.toml (homodyne); ``overrides`` are
    ``--set``-style strings applied to it. ``pulsed_mission`` (default missions/glas_bench.toml)
    is the pulsed study's, loaded as it is. ``families`` restricts the knob families (default: all
    of ``FAMILIES``); the reference rows of the selected studies always run (the point-target
    reference with any chirped family, the pulsed reference with any pulsed family).
    ``progress`` receives one line per setting. Raises ValueError for bad arguments (before
    anything runs).
    """
    from ..config import config_with, load_mission
    from . import accuracy_pulsed as ap

    base = load_mission(mission if mission is not None else default_mission_path(),
                        list(overrides))
    snr, shots, batch, fams, ks, k_ref, px, px_ref = _check_args(
        base, snr_db, shots, batch, families, sample_rates_hz, upsample_factors, peak_methods,
        zero_pad_factors, baseband_rates_hz, sub_rays, sub_rays_reference, slope_deg,
        screen_pixels, screen_reference)
    chirped = any(f not in PULSED_FAMILIES for f in fams)
    if any(f in PULSED_FAMILIES for f in fams):
        pulsed = load_mission(pulsed_mission if pulsed_mission is not None
                              else ap.default_pulsed_mission_path())
        p_snr, p_rates, p_ref, p_est = ap.check_pulsed_args(
            pulsed, pulsed_snr_db, pulse_sample_rates_hz, pulse_reference_rate_hz,
            pulse_estimators)
        n_pulse = 10 * shots if pulsed_shots is None else pulsed_shots
        for name, value, low in (("pulsed_shots", n_pulse, 2), ("pulsed_batch", pulsed_batch, 1)):
            if isinstance(value, bool) or int(value) != value or value < low:
                raise ValueError(f"{name} must be an integer >= {low}; got {value!r}")
    if chirped and (base.system.receiver != "coherent" or base.system.coherent_mode != "homodyne"):
        raise ValueError("the accuracy study runs the self-chirped homodyne receiver (system."
                         "receiver = 'coherent', coherent_mode = 'homodyne'); the mission has "
                         f"{base.system.receiver!r} / {base.system.coherent_mode!r}")
    n_foot = max(2, round(0.6 * shots)) if footprint_shots is None else footprint_shots
    n_turb = 3 * shots if turbulence_shots is None else turbulence_shots
    for name, value in (("footprint_shots", n_foot), ("turbulence_shots", n_turb)):
        if isinstance(value, bool) or int(value) != value or value < 2:
            raise ValueError(f"{name} must be an integer >= 2; got {value!r}")
    n_foot, n_turb = int(n_foot), int(n_turb)
    say = progress or (lambda line: None)
    wf = base.waveform
    cell_m = 2.99792458e8 / (2 * base.channel.group_index * (wf.f_stop_hz - wf.f_start_hz))
    rows: list[dict[str, Any]] = []

    def record(setting, cfg, snr_target, pattn, point, chunk_all, ref_row, echo=None,
               n_shots=shots, chunk=None, outlier_m=OUTLIER_CELLS * cell_m):
        if chunk is None:
            chunk = batch if (setting.tier == "rf" or chunk_all) else n_shots
        outs, per_shot = _run(setting, cfg, seed, point, n_shots, chunk,
                              *(echo or (None, None, None)))
        row = {"snr_target_db": snr_target, "pattn_db": pattn, "study": setting.study,
               "family": setting.family, "tier": setting.tier, "setting": setting.setting,
               "knob": setting.knob, "value": setting.value, "reference": setting.reference,
               "shots": n_shots, "batch": min(chunk, n_shots),
               **_stats(outs, outlier_m),
               "s_per_shot": per_shot}
        ref = row if ref_row is None else ref_row
        row["range_rms_diff_m"] = row["range_rms_m"] - ref["range_rms_m"]
        row["snr_error_db"] = row["snr_mean_db"] - ref["snr_mean_db"]
        row["snr_std_error_db"] = row["snr_std_db"] - ref["snr_std_db"]
        row["cost_vs_reference"] = row["s_per_shot"] / ref["s_per_shot"]
        rows.append({c: row[c] for c in COLUMNS})
        say(f"SNR {snr_target:g} dB  {setting.study:<12} {setting.setting:<32} "
            f"{row['s_per_shot'] * 1e3:9.3f} ms/shot  range RMS {row['range_rms_m']:.4g} m  "
            f"SNR {row['snr_mean_db']:.2f} dB")
        return rows[-1]

    point_fams = [f for f in fams if f in STUDIES["point target"]]
    for point, target in enumerate(snr if chirped else ()):
        pattn = pattn_for_snr(base, target)
        cfg0 = config_with(base, {"channel.extra_attenuation_db": pattn})
        settings = _point_settings(base, point_fams, sample_rates_hz, upsample_factors,
                                   peak_methods, zero_pad_factors, baseband_rates_hz)
        ref_row = None
        for s in settings:
            cfg = config_with(cfg0, s.overrides) if s.overrides else cfg0
            row = record(s, cfg, target, pattn, point, False, ref_row)
            ref_row = row if s.reference else ref_row

    top, top_point = max(snr), snr.index(max(snr))
    if "sub_rays" in fams:
        pattn = pattn_for_snr(base, top)
        cfg = config_with(base, {"channel.extra_attenuation_db": pattn})
        phase_rng = np.random.default_rng([seed, 7])
        runs = [Setting("footprint", "sub_rays", "rf", f"rf {k_ref} sub-rays", "sub_rays",
                        str(k_ref), sub_rays=k_ref, reference=True)]
        runs += [Setting("footprint", "sub_rays", "rf", f"rf {k} sub-rays", "sub_rays", str(k),
                         sub_rays=k) for k in ks]
        runs += [Setting("footprint", "sub_rays", "baseband", f"bb {k} sub-rays", "sub_rays",
                         str(k), sub_rays=k) for k in ks]
        phases = {k: phase_rng.uniform(0.0, 2 * np.pi, (n_foot, k)) for k in (*ks, k_ref)}
        ref_row = None
        for s in runs:
            off, w = slope_footprint_echoes(cfg, s.sub_rays, slope_deg)
            row = record(s, cfg, top, pattn, top_point, False, ref_row,
                         echo=(off, w, phases[s.sub_rays]), n_shots=n_foot)
            ref_row = row if s.reference else ref_row

    if "screen" in fams:
        turb = config_with(base, TURBULENCE_SETTINGS)
        mean = config_with(turb, {"effects.turbulence.fading": "mean"})
        pattn = pattn_for_snr(mean, top, start_db=0.0)   # the SNR of the mean coupling
        turb = config_with(turb, {"channel.extra_attenuation_db": pattn})
        from ..channel.effects import turbulence_d_over_r0

        rule = max(64, int(np.ceil(4 * turbulence_d_over_r0(turb))))

        def label(tier, n):
            return f"{tier} {n} px" + (" (default)" if n == rule else "")

        runs = [Setting("turbulence", "screen", "rf", label("rf", px_ref),
                        "effects.turbulence.screen_pixels", str(px_ref),
                        {"effects.turbulence.screen_pixels": px_ref}, reference=True)]
        runs += [Setting("turbulence", "screen", "rf", label("rf", n),
                         "effects.turbulence.screen_pixels", str(n),
                         {"effects.turbulence.screen_pixels": n}) for n in px if n == rule]
        runs += [Setting("turbulence", "screen", "link", label("link", n),
                         "effects.turbulence.screen_pixels", str(n),
                         {"effects.turbulence.screen_pixels": n}) for n in (*px, px_ref)]
        ref_row = None
        for s in runs:
            row = record(s, config_with(turb, s.overrides), top, pattn, top_point, True, ref_row,
                         n_shots=n_turb)
            ref_row = row if s.reference else ref_row

    if "receiver" in fams:
        rx = ar.receiver_base()
        pattn = pattn_for_snr(config_with(rx, {"effects.enabled": []}), top, start_db=0.0)
        ref_row = None
        for label, tier, arch, comb in ar.RECEIVER_CASES:
            s = Setting("receivers", "receiver", tier, label, "receiver.architecture",
                        arch if comb is None else f"fpa {comb}", ar.case_overrides(arch, comb),
                        reference=ref_row is None)
            cfg = config_with(rx, {**s.overrides, "channel.extra_attenuation_db": pattn})
            row = record(s, cfg, top, pattn, top_point, True, ref_row)
            ref_row = row if s.reference else ref_row

    if any(f in PULSED_FAMILIES for f in fams):
        runs = ap.pulsed_settings(pulsed, fams, p_rates, p_ref, p_est)
        for point, target in enumerate(p_snr):
            pattn = ap.attenuation_for_pulsed_snr(pulsed, target)
            cfg0 = config_with(pulsed, {"channel.extra_attenuation_db": pattn})
            ref_row = None
            for s in runs:
                row = record(s, config_with(cfg0, s.overrides), target, pattn, 1000 + point,
                             False, ref_row, n_shots=int(n_pulse), chunk=int(pulsed_batch),
                             outlier_m=ap.outlier_threshold_m(pulsed))
                ref_row = row if s.reference else ref_row
    return rows


# ------------------------------------------------------------------------------------- outputs

def _fmt(value: Any, digits: int = 4) -> str:
    if isinstance(value, bool):
        return "yes" if value else ""
    if isinstance(value, (int, np.integer)):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        return f"{value:.{digits}g}"
    return str(value)


def write_csv(rows: Sequence[dict], path: str | Path) -> Path:
    """The study's rows as CSV (columns of ``COLUMNS``, SI units: m, dB, s)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(COLUMNS))
        writer.writeheader()
        for r in rows:
            writer.writerow({c: (r[c] if not isinstance(r[c], float) else repr(r[c]))
                             for c in COLUMNS})
    return path


def markdown_table(rows: Sequence[dict]) -> str:
    """A Markdown table of the study: one line per setting, grouped by SNR point and study."""
    head = ("| SNR target | study | setting | ms / shot | x ref time | range RMS (m) | "
            "RMS - ref (m) | bias (m) | outliers | SNR - ref (dB) | SNR std - ref (dB) |")
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        rms = f"{_fmt(r['range_rms_m'], 3)} ± {_fmt(r['range_rms_se_m'], 2)}"
        name = f"**{r['setting']}**" if r["reference"] else r["setting"]
        lines.append(
            f"| {r['snr_target_db']:g} dB | {r['study']} | {name} | "
            f"{_fmt(r['s_per_shot'] * 1e3, 3)} | {_fmt(r['cost_vs_reference'], 2)} | {rms} | "
            f"{r['range_rms_diff_m']:+.3g} | {r['range_bias_m']:+.3g} | "
            f"{_fmt(r['outlier_frac'], 2)} | {r['snr_error_db']:+.2f} | "
            f"{r['snr_std_error_db']:+.2f} |")
    return "\n".join(lines) + "\n"


def write_markdown(rows: Sequence[dict], path: str | Path, *, header: str = "") -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text((header + "\n\n" if header else "") + markdown_table(rows))
    return path


def write_outputs(rows: Sequence[dict], out_dir: str | Path, *, header: str = "") -> dict[str, Path]:
    """Write ``accuracy_vs_time.{csv,md,png}`` into ``out_dir``; returns the paths by kind."""
    if not rows:
        raise ValueError("no rows to write: run accuracy_study first")
    missing = [c for c in COLUMNS if c not in rows[0]]
    if missing:
        raise ValueError(f"rows lack the study's columns {missing}")
    from ..viz.accuracy import plot_accuracy   # lazy: physics never imports viz

    out = Path(out_dir)
    return {"csv": write_csv(rows, out / "accuracy_vs_time.csv"),
            "md": write_markdown(rows, out / "accuracy_vs_time.md", header=header),
            "png": plot_accuracy(rows, out / "accuracy_vs_time.png")}


def run_accuracy_bench(out_dir: str | Path = "outputs", mission: str | Path | None = None,
                       overrides: Sequence[str] = (), progress: Callable[[str], None] | None = None,
                       **study_kwargs) -> tuple[list[dict], dict[str, Path], float]:
    """Run the study and write its three files: (rows, paths, wall seconds of the study)."""
    import os
    import platform

    t0 = time.perf_counter()
    rows = accuracy_study(mission, overrides, progress=progress, **study_kwargs)
    elapsed = time.perf_counter() - t0
    shots = {}
    for r in rows:
        shots.setdefault(r["study"], r["shots"])
    pulsed = ""
    if any(r["study"] == "pulsed" for r in rows):
        from .accuracy_pulsed import default_pulsed_mission_path

        name = Path(str(study_kwargs.get("pulsed_mission") or default_pulsed_mission_path())).name
        pulsed = f" (pulsed study: {name})"
    header = (f"# Accuracy versus time\n\nMission {Path(str(mission or default_mission_path())).name}"
              f"{' with ' + ' '.join(overrides) if overrides else ''}{pulsed}; shots per setting: "
              + ", ".join(f"{k} {v}" for k, v in shots.items())
              + f"; measured on {os.cpu_count()}-core {platform.machine()} "
              f"({time.strftime('%Y-%m-%d')}), study wall time {elapsed:.0f} s. Seconds per shot: "
              "the median over chunks of a chunk's time over its shots, after one untimed "
              "warm-up shot. Range RMS ± its standard error; differences are from the "
              "reference row (bold) of the same SNR point and study.")
    paths = write_outputs(rows, out_dir, header=header)
    return rows, paths, elapsed
