"""The pulsed study of the accuracy-versus-time bench (:mod:`chirplidar.analysis.accuracy`).

The GLAS bench (``missions/glas_bench.toml``: instruments/glas.toml, thesis Table 2.1, its point
target at 600 km) through the pulsed tier, at a few SNR points placed with the tier's own SNR
(Gardner 1992, eq. 20: N_s^2 / (F (N_s + N_b) + sigma_c^2), a function of the mean return only,
so one shot reads it) at the mission's settings, by Newton steps on ``channel.extra_attenuation_db``
with a numerical slope (the SNR falls 1 dB per dB where shot noise dominates and 2 dB per dB where
the circuit noise does). Reference: the pulsed tier at ``reference_rate_hz`` (4 GHz: 20 samples
per 5 ns pulse) with ``gaussian_fit``. Knob families:

    ``pulse_sample_rate``  ``digitizer.sample_rate_hz`` with the Gaussian fit; the record keeps its
                           duration (``digitizer.record_samples`` scaled with the rate, rounded)
    ``pulse_estimator``    ``pulse_ranging.estimator`` (threshold, centroid, gaussian_fit) at the
                           mission's sample rate

Outliers: |d_error| beyond 5 range-resolution cells c tau / (2 n_g) (eq. 2.1.1; GLAS: 5 x 0.75 m).
Undetected shots (NaN ranges) are left out of the statistics and counted in the row's flags.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

PULSED_MISSION_NAME = "glas_bench.toml"
PULSED_FAMILIES = ("pulse_sample_rate", "pulse_estimator")
PULSE_ESTIMATORS = ("threshold", "centroid", "gaussian_fit")
PULSED_SNR_DB = (20.0, 30.0, 40.0)
OUTLIER_RESOLUTIONS = 5.0   # |d_error| beyond this many c tau / 2 cells is an outlier


def default_pulsed_mission_path() -> Path:
    from ..mission_files import default_mission_path as find

    return find(PULSED_MISSION_NAME)


def rate_overrides(config, rate_hz: float) -> dict[str, float | int]:
    """Overrides that sample at ``rate_hz`` over the mission's record duration."""
    dig = config.digitizer
    samples = int(round(dig.record_samples * rate_hz / dig.sample_rate_hz))
    return {"digitizer.sample_rate_hz": float(rate_hz), "digitizer.record_samples": samples}


def check_pulsed_args(config, snr_db, sample_rates_hz, reference_rate_hz, estimators):
    """(SNR points, rates, reference rate, estimators) checked; ValueError naming the argument."""
    if config.pulse is None:
        raise ValueError("pulsed_mission must hold a pulsed instrument (a [pulse] section, e.g. "
                         "missions/glas_bench.toml)")
    snr = tuple(float(s) for s in snr_db)
    if not snr or not all(math.isfinite(s) for s in snr) or len(set(snr)) != len(snr):
        raise ValueError(f"pulsed_snr_db must be distinct finite SNR targets in dB; got "
                         f"{list(snr_db)!r}")
    tau, n0 = config.pulse.duration_s, config.digitizer.record_samples
    rates = tuple(float(r) for r in sample_rates_hz)
    for r in (*rates, float(reference_rate_hz)):
        if not (math.isfinite(r) and r * tau >= 1.0):
            raise ValueError(f"pulse sample rates must be at least 1 / pulse.duration_s "
                             f"({1 / tau:g} Hz: a sample per pulse); got {r:g}")
        if round(n0 * r / config.digitizer.sample_rate_hz) < 8:
            raise ValueError(f"pulse sample rate {r:g} Hz leaves fewer than 8 samples in the "
                             f"mission's record")
    if rates and float(reference_rate_hz) <= max(rates):
        raise ValueError(f"pulse_reference_rate_hz ({reference_rate_hz:g}) must exceed every "
                         f"compared sample rate (largest {max(rates):g})")
    bad = [e for e in estimators if e not in PULSE_ESTIMATORS]
    if bad or not estimators:
        raise ValueError(f"pulse_estimators must be among {', '.join(PULSE_ESTIMATORS)}; got "
                         f"{list(estimators)!r}")
    return snr, rates, float(reference_rate_hz), tuple(estimators)


def attenuation_for_pulsed_snr(config, snr_db: float, *, iterations: int = 30) -> float:
    """``channel.extra_attenuation_db`` at which the pulsed tier's SNR of the mission's mean
    return is ``snr_db`` (Newton steps, slope from a 0.1 dB difference; see the module doc)."""
    from ..channel.lab import simulate_lab
    from ..config import config_with

    def snr_at(p):
        cfg = config_with(config, {"channel.extra_attenuation_db": p})
        return float(np.mean(simulate_lab(cfg, "pulsed", np.random.default_rng(0))["SNR"]))

    p = float(config.channel.extra_attenuation_db)
    for _ in range(iterations):
        snr = snr_at(p)
        if not math.isfinite(snr):
            raise ValueError(f"the pulsed tier reads SNR = {snr} at channel.extra_attenuation_db"
                             f" = {p:g} dB: no return to place the SNR points with")
        if abs(snr - snr_db) < 1e-3:
            return p
        slope = (snr_at(p + 0.1) - snr) / 0.1
        # the SNR falls 1 to 2 dB per dB; a slope outside [-3, -0.5] is a step out of range
        p += (snr - snr_db) / min(max(-slope, 0.5), 3.0)
    raise ValueError(f"the pulsed tier's SNR does not reach {snr_db:g} dB (last "
                     f"{snr:.3f} dB at channel.extra_attenuation_db = {p:g} dB)")


def pulsed_settings(config, fams: Sequence[str], sample_rates_hz, reference_rate_hz,
                    estimators) -> list:
    """The pulsed study's settings: the reference first, then each family's."""
    from .accuracy import Setting

    study, dig = "pulsed", config.digitizer
    est0, fs0 = config.pulse_ranging.estimator, dig.sample_rate_hz

    def rate(fs):
        return f"{fs / 1e9:g} GHz"

    out = [Setting(study, "reference", "pulsed", f"pulsed ref ({rate(reference_rate_hz)}, "
                   "gaussian_fit)", "digitizer.sample_rate_hz+pulse_ranging.estimator",
                   f"{reference_rate_hz:g},gaussian_fit",
                   {**rate_overrides(config, reference_rate_hz),
                    "pulse_ranging.estimator": "gaussian_fit"}, reference=True)]
    if "pulse_sample_rate" in fams:
        out += [Setting(study, "pulse_sample_rate", "pulsed",
                        f"Fs {rate(fs)}" + (" (mission)" if fs == fs0 else ""),
                        "digitizer.sample_rate_hz", f"{fs:g}",
                        {**rate_overrides(config, fs), "pulse_ranging.estimator": "gaussian_fit"})
                for fs in sample_rates_hz]
    if "pulse_estimator" in fams:
        out += [Setting(study, "pulse_estimator", "pulsed",
                        f"{e} ({rate(fs0)})" + (" (mission)" if e == est0 else ""),
                        "pulse_ranging.estimator", e, {"pulse_ranging.estimator": e})
                for e in estimators]
    return out


def outlier_threshold_m(config) -> float:
    """5 range-resolution cells c tau / (2 n_g) (eq. 2.1.1) of the pulsed mission, m."""
    from ..units import SPEED_OF_LIGHT_M_S

    return OUTLIER_RESOLUTIONS * SPEED_OF_LIGHT_M_S * config.pulse.duration_s / (
        2.0 * config.channel.group_index)
