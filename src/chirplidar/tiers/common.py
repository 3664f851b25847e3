"""What every tier shares: Table 4.10 outputs, flags, the operator's optimal carrier phase."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..processing.ranging import range_accuracy_m
from ..processing.spectrum import PeakResult
from ..receiver import HYBRID_90
from ..transmitter.mzm import mzm_harmonic_dominates
from ..units import power_dbm, ratio_db
from .model import Instrument, Measurements, Returns

# Thesis Table 4.10: output names and units.
OUTPUT_UNITS: dict[str, str] = {
    "Pchrp": "dBm",
    "Ptx": "dBm",
    "Psig": "dBm",
    "Ne": "dBm/Hz",
    "Ns": "dBm/Hz",
    "Nt": "dBm/Hz",
    "d_offset": "m",
    "d_rx": "m",
    "d_lo": "m",
    "d_hi": "m",
    "d_error": "m",
    "d_3dB": "m",
    "d_res": "m",
    "Crx": "dBm",
    "Navg": "dBm",
    "SNR": "dB",
}
OUTPUT_NAMES: tuple[str, ...] = tuple(OUTPUT_UNITS)
OUTPUT_LONG_NAMES: dict[str, str] = {
    "Pchrp": "chirp waveform generator output power",
    "Ptx": "transmitted optical power",
    "Psig": "received optical power",
    "Ne": "equivalent amplifier input noise PSD",
    "Ns": "photodiode shot noise PSD",
    "Nt": "photodiode thermal noise PSD",
    "d_offset": "distance offset due to local (reference) delay",
    "d_rx": "detected target distance",
    "d_lo": "lower bound of the 3 dB range uncertainty",
    "d_hi": "upper bound of the 3 dB range uncertainty",
    "d_error": "range error dst - d_rx",
    "d_3dB": "3 dB range resolution d_hi - d_lo",
    "d_res": "analytical range resolution c / (2 B sqrt(2 SNR)) (eq. 2.2.2)",
    "Crx": "received beat power read from the spectrum",
    "Navg": "noise level in the RBW read from the spectrum",
    "SNR": "signal-to-noise ratio in the RBW (eq. 2.6.12)",
}


def optimal_phase(mode: str) -> float:
    """Signal carrier phase (rad, relative to the LO) that maximises the primary beat.

    Balanced 3 dB coupler: i1 - i2 = 2 R Im(E_LO E_s*), largest for psi = -pi/2.
    Hybrid arm 1: 2 Re(S00 S01* E_LO E_s*), largest for psi = arg(S00 S01*).
    Direct and heterodyne detection do not depend on it.
    """
    if mode == "homodyne":
        return -0.5 * np.pi
    if mode == "phase_diversity":
        return float(np.angle(HYBRID_90[0, 0] * np.conj(HYBRID_90[0, 1])))
    return 0.0


def peak_search_max_hz(config, bud) -> float:
    """Top of the peak search: ``processing.peak_search_max_hz``, else Nyquist; for phase diversity
    the chirp's start frequency (the unbalanced arms' own LO terms lie at and above it)."""
    if config.processing.peak_search_max_hz is not None:
        return config.processing.peak_search_max_hz
    if config.system.receiver == "coherent" and config.system.coherent_mode == "phase_diversity":
        return bud.train.f_start_hz
    return config.simulation.sample_rate_hz / 2


def doppler_line_hz(config, bud, f_beat_hz, f_doppler_hz, rng) -> np.ndarray:
    """The beat line the peak search finds when a resolved Doppler shift f_d splits the beat f_R
    into |f_R + f_d| and |f_R - f_d| of equal power (Appendix D): one inside the processed band,
    either with equal chance when both are (the rf and baseband tiers' noise decides), the upper
    one when neither is. f_d = 0: the beat itself."""
    f_b = np.asarray(f_beat_hz, float)
    f_d = np.broadcast_to(np.asarray(f_doppler_hz, float), f_b.shape)
    if not np.any(f_d != 0):
        return f_b  # no draw: outputs without Doppler keep their random streams
    up, down = np.abs(f_b + f_d), np.abs(f_b - f_d)
    lo, hi = config.processing.highpass_hz, peak_search_max_hz(config, bud)
    up_in, down_in = (lo <= up) & (up <= hi), (lo <= down) & (down <= hi)
    coin = rng.random(f_b.shape) < 0.5
    return np.where(down_in & (~up_in | coin), down, up)


def dsp_doppler_unlocked(config, bud, f_doppler_hz) -> np.ndarray:
    """Shots whose Doppler shift ``processing.doppler_recovery = "dsp"`` cannot lock on: a line
    of the complex record, f_d + f_R or f_d - f_R, outside the processed band
    highpass_hz <= |f| <= :func:`peak_search_max_hz` that the DSP band-passes the arms to
    (:func:`~chirplidar.tiers.records.dsp_compensated_arms`): without the pair the centre of
    symmetry is not f_d. Shots without Doppler are never flagged."""
    f_d = np.asarray(f_doppler_hz, float)
    lo, hi = config.processing.highpass_hz, peak_search_max_hz(config, bud)
    lines = np.abs(np.stack([f_d + bud.f_beat_hz, f_d - bud.f_beat_hz]))
    return (f_d != 0) & np.any((lines < lo) | (lines > hi), axis=0)


def detection_flags(
    config: Instrument, bud, returns: Returns | None = None, *, nyquist_hz=None
) -> list[str]:
    """Flags of a batch from its budget: ``no_return`` (zero received power), ``no_lo`` (a
    coherent receiver with zero LO power: nothing to beat with), ``no_chirp`` (no drive voltage
    on the modulator: no chirp, so no beat), ``harmonic_beat`` (the modulator's bias puts more
    power at twice the chirp phase than at the chirp: the strongest beat is at 2 f_R, not read),
    ``fiber_acceptance_exceeded``,
    ``doppler_ambiguous`` (or, with the DSP's Doppler compensation, ``doppler_beyond_dsp_band``:
    :func:`dsp_doppler_unlocked`); FM chirps: ``no_overlap``, ``beat_out_of_band``,
    ``beat_above_nyquist`` (the beat kappa x lag above ``nyquist_hz``: the tier's Nyquist
    frequency, or the top of the band the baseband tier simulates) and ``range_ambiguous`` (the
    delay differs from the reference delay by less than zero or a chirp period or more: the
    range read from the beat is off by a multiple of c T / 2n)."""
    flags = []
    if bud.psig_w <= 0 or (returns is not None and not np.any(returns.power_factor > 0)):
        flags.append("no_return")
    if config.system.receiver == "coherent" and config.balanced.lo_power_w <= 0:
        flags.append("no_lo")
    if config.waveform.vpp_v <= 0:
        flags.append("no_chirp")
    elif config.system.modulation == "fm_chirp" and mzm_harmonic_dominates(
        bud.train,
        config.modulator.bias_v,
        config.modulator.v_pi_v,
        field=config.system.receiver == "coherent",
    ):
        flags.append("harmonic_beat")
    if config.fiber is not None and config.fiber.exceeded:
        flags.append("fiber_acceptance_exceeded")
    if returns is not None and config.processing.doppler_recovery == "dsp":
        # The complex record keeps the sign of f_d; the estimate needs both lines in the band.
        if np.any(dsp_doppler_unlocked(config, bud, returns.doppler_hz)):
            flags.append("doppler_beyond_dsp_band")
    elif returns is not None and np.any(np.abs(returns.doppler_hz) >= bud.f_beat_hz):
        # Appendix D: the line at f_R - f_d folds through zero; its sign is lost.
        flags.append("doppler_ambiguous")
    if config.system.modulation == "fm_chirp":
        no_overlap, out_of_band = beat_flags(config, bud, bud.lag_s, bud.f_beat_hz)
        if no_overlap:
            flags.append("no_overlap")
        above = nyquist_hz is not None and bud.f_beat_hz > nyquist_hz
        if out_of_band or above:
            flags.append("beat_out_of_band")
        if above:
            flags.append("beat_above_nyquist")
        if range_ambiguous(bud, bud.delay_s - bud.ref_delay_s):
            flags.append("range_ambiguous")
    return flags


def range_ambiguous(bud, delay_minus_ref_s):
    """True (elementwise) where a return's delay minus the reference delay lies outside
    [0, T), T the chirp period: its beat is that of a delay a whole number of periods away, so
    the range read from it is off by a multiple of c T / (2 n); or where its strongest tone is
    that of the next reference chirp (:func:`next_chirp_tone`)."""
    d = np.asarray(delay_minus_ref_s, float)
    return ((d < 0) | (d >= bud.train.period_s) | next_chirp_tone(bud, d))[()]


def next_chirp_tone(bud, delay_minus_ref_s):
    """True (elementwise) where the lag within the period, tau - tau_ref mod T, is over half the
    period and the return's ramp overlaps the next reference ramp (T - lag < the rise time):
    that overlap, longer than the return's own (rise - lag, if any), gives the strongest tone,
    kappa (T - lag), the beat of a lag of lag - T: the range read from it is off by c T / 2n."""
    period, rise = bud.train.period_s, bud.train.rise_s
    lag = np.mod(np.asarray(delay_minus_ref_s, float), period)
    return ((lag > 0.5 * period) & (period - lag < rise))[()]


# Outputs that say where the beat is (the range and the line's width), and those read from the
# spectrum's peak (its power, SNR and the resolution derived from it).
_BEAT_KEYS = ("f_beat_hz", "d_rx", "d_lo", "d_hi", "d_error", "d_3dB")
_RANGE_KEYS = ("d_rx", "d_lo", "d_hi", "d_error")


#: Flags of a batch with nothing to beat: no beat or range is reported.
_NO_BEAT = ("no_return", "no_lo", "no_chirp")


def unmeasured_masks(
    config,
    bud,
    flags: list,
    n: int,
    *,
    power_factor=None,
    delay_offset_s=None,
    nyquist_hz=None,
    shot_flags: dict | None = None,
):
    """Per-shot masks (silent, off_band, ambiguous) of the shots whose beat a tier cannot read:

    * silent: no signal to beat: zero received power (``no_return``), no LO (``no_lo``), no
      chirp (``no_chirp``), or FM chirps that do not overlap (``no_overlap``);
    * off_band: the beat lies outside the processed band (``beat_out_of_band``) or above the
      Nyquist frequency ``nyquist_hz`` (``beat_above_nyquist``): the peak found is not the beat;
    * ambiguous: the delay lies outside [tau_ref, tau_ref + T) or the strongest tone is the
      next chirp's (``range_ambiguous``; the latter also ``next_chirp_tone`` and off_band).

    ``delay_offset_s`` (n,): each shot's power-weighted mean echo delay offset from the budget's
    delay (footprint echoes), else 0. The flags a shot has and ``flags`` lacks are appended to
    ``flags``; ``shot_flags`` (optional) receives the per-shot masks of the flags judged shot by
    shot (``no_return``; FM chirps: ``no_overlap``, ``beat_out_of_band``, ``beat_above_nyquist``,
    ``range_ambiguous``, ``next_chirp_tone``)."""
    pf = (
        np.ones(n)
        if power_factor is None
        else np.broadcast_to(np.asarray(power_factor, float), (n,))
    )
    per_shot = {"no_return": bud.psig_w * pf <= 0}
    silent = per_shot["no_return"] | any(f in flags for f in _NO_BEAT)
    off_band = np.zeros(n, bool)
    ambiguous = np.zeros(n, bool)
    if config.system.modulation == "fm_chirp":
        off = (
            0.0
            if delay_offset_s is None
            else np.broadcast_to(np.asarray(delay_offset_s, float), (n,))
        )
        raw = np.broadcast_to((bud.delay_s + off) - bud.ref_delay_s, (n,))
        lag = np.mod(raw, bud.train.period_s)
        f_b = bud.rate_hz_per_s * lag
        no_overlap, out_of_band = (
            np.broadcast_to(m, (n,)) for m in beat_flags(config, bud, lag, f_b)
        )
        above = (f_b > nyquist_hz) if nyquist_hz is not None else np.zeros(n, bool)
        ambiguous = np.broadcast_to(range_ambiguous(bud, raw), (n,))
        other_tone = np.broadcast_to(next_chirp_tone(bud, raw), (n,))
        for name, mask in (
            ("no_overlap", no_overlap),
            ("beat_out_of_band", out_of_band | above),
            ("beat_above_nyquist", above),
            ("range_ambiguous", ambiguous),
            ("next_chirp_tone", other_tone),
        ):
            per_shot[name] = mask
            if np.any(mask) and name not in flags:
                flags.append(name)
        silent = silent | no_overlap
        # the beat of the next chirp's tone is not this lag's: not read, as out of band
        off_band = out_of_band | above | other_tone | ("harmonic_beat" in flags)
    if shot_flags is not None:
        shot_flags.update(per_shot)
    return silent, off_band, ambiguous


def null_unmeasured(out: dict, silent, off_band, ambiguous, *, spectrum_read: bool) -> dict:
    """``out`` with no number a tier cannot stand behind (:func:`unmeasured_masks`): silent
    shots read zero beat power (Crx, SNR -inf dB, d_res inf) and no beat or range (NaN);
    off-band shots no beat or range, and when the tier reads its numbers off a spectrum
    (``spectrum_read``) no peak power, SNR or resolution either (the peak is not the beat);
    ambiguous shots no range. Arrays of the other shots are untouched."""
    out = dict(out)

    def put(key, mask, value):
        if key in out and np.any(mask):
            out[key] = np.where(mask, value, out[key])

    for key in _BEAT_KEYS:
        put(key, silent | off_band, np.nan)
    for key in _RANGE_KEYS:
        put(key, ambiguous, np.nan)
    peak_keys = ["Crx", "SNR"] + [k for k in out if k.endswith(("_Crx", "_SNR"))]
    if spectrum_read:
        for key in peak_keys + ["d_res"]:
            put(key, off_band & ~silent, np.nan)
    for key in peak_keys:
        put(key, silent, -np.inf)
    put("d_res", silent, np.inf)
    return out


def beat_flags(config, bud, lag_s, f_beat_hz):
    """(no_overlap, beat_out_of_band) for FM chirps, elementwise over ``lag_s`` and ``f_beat_hz``:
    the signal and reference ramps do not overlap, or the beat lies outside the processed band."""
    rise, period = bud.train.rise_s, bud.train.period_s
    lag, f_b = np.asarray(lag_s, float), np.asarray(f_beat_hz, float)
    no_overlap = (lag >= rise) & (period - lag >= rise)
    out_of_band = ~(
        (config.processing.highpass_hz <= f_b) & (f_b <= peak_search_max_hz(config, bud))
    )
    return no_overlap[()], out_of_band[()]


def assemble_outputs(
    config: Instrument,
    bud,
    result: PeakResult,
    noise,
    flags,
    *,
    range_m: float,
    extra=None,
    tier: str,
    lag_s=None,
    lag_lo_s=None,
    lag_hi_s=None,
    power_factor=None,
    nyquist_hz=None,
    delay_offset_s=None,
) -> Measurements:
    """Table 4.10 outputs (arrays over the batch) from a peak result and the noise model.

    ``range_m``: the true range ``d_error`` is measured against. ``power_factor`` (per shot) is
    what the channel's effects did to the received power (speckle): Psig reports each shot's own
    received power. Shots whose beat the tier cannot read (no signal, no LO, no chirp overlap, a
    beat outside the processed band or above ``nyquist_hz``, a range ambiguous by a chirp period:
    :func:`unmeasured_masks`, ``delay_offset_s`` the shots' mean echo offsets) report NaN (JSON
    null) for what is not measured, and their flags.
    """
    flags = list(flags)
    n = np.size(result.snr)
    out = _table_4_10(
        config,
        bud,
        result,
        noise,
        n,
        range_m=range_m,
        no_return="no_return" in flags,
        lag_s=lag_s,
        lag_lo_s=lag_lo_s,
        lag_hi_s=lag_hi_s,
        power_factor=power_factor,
    )
    out = {k: np.atleast_1d(v) for k, v in out.items()}
    out["f_beat_hz"] = np.atleast_1d(np.asarray(result.f_peak_hz, float))
    out.update(_extra_outputs(extra or {}))
    shot_flags: dict[str, np.ndarray] = {}
    masks = unmeasured_masks(
        config,
        bud,
        flags,
        n,
        power_factor=power_factor,
        delay_offset_s=delay_offset_s,
        nyquist_hz=nyquist_hz,
        shot_flags=shot_flags,
    )
    if any(np.any(m) for m in masks):
        out = null_unmeasured(out, *masks, spectrum_read=tier != "link")
    return Measurements(
        tier,
        out,
        flags,
        _spectrum(result, config.processing.rbw_hz),
        flag_masks=_flag_masks(flags, shot_flags, n),
    )


def _table_4_10(
    config: Instrument,
    bud,
    result: PeakResult,
    noise,
    n: int,
    *,
    range_m: float,
    no_return: bool,
    lag_s,
    lag_lo_s,
    lag_hi_s,
    power_factor,
) -> dict:
    """The thesis Table 4.10 outputs of a peak result (lags in seconds, or None: read from the
    peak's frequencies) and the noise model, before the unmeasured shots are nulled."""
    rate = bud.rate_hz_per_s
    if lag_s is None:
        lag_s = result.f_peak_hz / rate
        lag_lo_s, lag_hi_s = result.f_lo_hz / rate, result.f_hi_hz / rate
    d_rx = bud.range_from_lag_m(lag_s)
    d_lo, d_hi = bud.range_from_lag_m(lag_lo_s), bud.range_from_lag_m(lag_hi_s)
    snr = np.asarray(result.snr, dtype=float)
    d_res = _resolution_m(bud, snr)

    def full(v):
        return np.full(n, float(v))

    out = {
        "Pchrp": full(power_dbm(bud.pchrp_w)),
        "Ptx": full(power_dbm(bud.ptx_w)),
        "Psig": (
            full(power_dbm(bud.psig_w))
            if power_factor is None
            else np.atleast_1d(power_dbm(bud.psig_w * np.asarray(power_factor, float)))
        ),
        "Ne": full(power_dbm(noise.output_psd_w_per_hz(noise.amplifier))),
        "Ns": full(power_dbm(noise.output_psd_w_per_hz(noise.shot))),
        "Nt": full(power_dbm(noise.output_psd_w_per_hz(noise.thermal))),
        "d_offset": full(bud.d_offset_m),
        "d_rx": np.asarray(d_rx, float),
        "d_lo": np.asarray(d_lo, float),
        "d_hi": np.asarray(d_hi, float),
        "d_error": range_m - np.asarray(d_rx, float),
        "d_3dB": np.asarray(d_hi, float) - np.asarray(d_lo, float),
        "d_res": d_res,
        # Zero received power: there is no signal to read, whatever the noise peak is.
        "Crx": np.full(n, -np.inf) if no_return else power_dbm(result.peak_power_w),
        "Navg": power_dbm(result.noise_psd_w_per_hz * config.processing.rbw_hz),
        "SNR": np.full(n, -np.inf) if no_return else ratio_db(snr),
    }
    if no_return:
        out["d_res"] = np.full(n, np.inf)
    return out


def _flag_masks(flags, shot_flags: dict, n: int) -> dict[str, np.ndarray]:
    """Every flag of the batch as a (batch,) mask: the ones judged shot by shot, else all."""
    return {name: np.array(np.broadcast_to(shot_flags.get(name, True), (n,))) for name in flags}


def _resolution_m(bud, snr: np.ndarray) -> np.ndarray:
    """The analytical range resolution c / (2 n B sqrt(2 SNR)) (m, eq. 2.2.2); inf at SNR 0."""
    return np.asarray(range_accuracy_m(bud.train.bandwidth_hz, snr, bud.group_index))


def _extra_outputs(extra: dict) -> dict[str, np.ndarray]:
    """A tier's extra per-shot outputs: ``*_w`` powers in dBm without the suffix, ``*_snr``
    ratios as ``*_SNR`` in dB, the others as they are."""
    out = {}
    for key, value in extra.items():
        if key.endswith("_w"):
            out[key[:-2]] = np.atleast_1d(power_dbm(value))
        elif key.endswith("_snr"):
            out[key[:-4] + "_SNR"] = np.atleast_1d(ratio_db(value))
        else:
            out[key] = np.atleast_1d(value)
    return out


def _spectrum(result: PeakResult, rbw_hz: float) -> dict | None:
    """The spectrum a tier kept (``keep_spectrum``) with its peak and noise level, or None."""
    if result.spectrum_f_hz is None:
        return None
    return {
        "f_hz": result.spectrum_f_hz,
        "psd_w_per_hz": result.spectrum_w_per_hz,
        "f_peak_hz": result.f_peak_hz,
        "f_lo_hz": result.f_lo_hz,
        "f_hi_hz": result.f_hi_hz,
        "noise_psd_w_per_hz": result.noise_psd_w_per_hz,
        "rbw_hz": rbw_hz,
    }


def finish_outputs(
    config: Instrument,
    bud,
    result: PeakResult,
    extra: dict,
    noise,
    flags,
    returns: Returns,
    *,
    tier: str,
    nyquist_hz=None,
    delay_offset_s=None,
) -> Measurements:
    """Table 4.10 outputs of :func:`analyze_block`'s result (PN results carry lags in seconds);
    ``nyquist_hz``, ``delay_offset_s``: see :func:`assemble_outputs`."""
    read: dict[str, Any]
    if config.system.modulation == "pn_code":  # the correlation peak's lags, in seconds
        read = dict(lag_s=result.f_peak_hz, lag_lo_s=result.f_lo_hz, lag_hi_s=result.f_hi_hz)
    else:
        read = dict(extra=extra, nyquist_hz=nyquist_hz, delay_offset_s=delay_offset_s)
    return assemble_outputs(
        config,
        bud,
        result,
        noise,
        flags,
        range_m=returns.range_m,
        tier=tier,
        power_factor=returns.power_factor,
        **read,
    )


def echo_mean_offset_s(echo_arrays):
    """(batch,) power-weighted mean delay offset of each shot's echoes ``(offsets, weights,
    phases)`` (arrays (batch, k)), or None for a point target."""
    if echo_arrays is None:
        return None
    offsets, weights = np.asarray(echo_arrays[0], float), np.asarray(echo_arrays[1], float)
    total = weights.sum(axis=-1)
    return np.sum(weights * offsets, axis=-1) / np.where(total > 0, total, 1.0)
