"""Per-shot measurements of a survey chunk: its footprint returns through the chosen tier.

The channel makes each shot-beam's footprint returns (``chirplidar.channel.footprint``); this
module aims the instrument at them (the range gate below) and hands them to the tier as
:class:`~chirplidar.tiers.model.Returns`: the link tier through its survey table
(``chirplidar.tiers.link_survey``), the rf tier shot by shot and the baseband tier in batches of
neighbouring ranges, both with the footprint's sub-rays as echoes
(``chirplidar.tiers.echoes.footprint_echoes``).

Doppler (``doppler`` in the scene's effects): f_d = 2 v / lambda from each shot's closing speed
(platform velocity along the beam; the terrain is fixed in ECEF, so for satellites the ECEF
velocity already holds the Earth's rotation). A shift the record resolves (|f_d| >= 1 / T_ov)
splits the homodyne line (thesis Appendix D): the SNR takes the link tier's split factor and the
lines sit at |f_R + f_d| and |f_R - f_d| with equal power: the peak search takes one of those
inside the processed band (either, with equal chance, when both are), as the rf and baseband
tiers do through their noise. Such a range is off by f_d / kappa: unless
``processing.doppler_recovery`` recovers it (squaring: rf tier; "dsp": the phase-diversity
receiver's combining DSP, which the link tier models as the zero-Doppler shot), the return is flagged
``doppler_displaced`` (``detected = 4``) whenever the record resolves it (|f_d| T_ov >= 1, T_ov
the chirps' overlap at the shot's lag).
``attitude.doppler_steering`` removes the shift at its source (beams in the body's across-track
plane perpendicular to the velocity); ``survey.doppler_compensation = "lo_offset"`` shifts each
beam's LO by its predicted Doppler (``ChunkGeometry.doppler_speed_mps`` is what is left).

Range window (``survey.range_window_m`` = W)
--------------------------------------------
As an altimeter's range gate, the reference delay follows each beam's range R_p predicted to the
scene's mid-height surface (:attr:`survey.ChunkGeometry.range_predicted_m`): returns with a mean
range in [R_p - W/2, R_p + W/2] beat between the high-pass corner f_hp and f_hp + kappa 2 n W / c,
which must lie in the processed band (:func:`check_range_window`):

    tau_ref = 2 n (R_p - W / 2) / c - f_hp / kappa

A return outside the window is flagged ``outside_range_gate`` (``detected = 3``): the
instrument does not look there, and its beat would alias or leave the band.

Without a window the reference delay is the configuration's (``system.reference_delay_s``, or
the ``sys.fmaxopt`` rule). A return whose delay lies outside [tau_ref, tau_ref + T) (T the chirp
period) beats like one whole periods away: its range would be off by a multiple of c T / 2n. It
is flagged ``range_ambiguous`` (``detected = 5``, whatever its SNR) and has no measured range.
A link-tier node whose chirps do not overlap has no tone (SNR 0): the shots it would be
interpolated into are evaluated on nodes at a lag with overlap, scaled by their own overlap
(``tiers.link_survey.unread_nodes``); a shot with no tone has no SNR (the fill value), never a
sentinel.
"""

from __future__ import annotations

import numpy as np

from ..channel.footprint import (FootprintReturns, footprint_returns, received,
                                 reference_attenuation_db, reference_power_fraction,
                                 shot_doppler_hz)
from ..channel.lab import lab_budget
from ..config.instrument import instrument_from_config
from ..streams import BASEBAND_BATCH, stream
from ..processing.ranging import two_way_delay_s
from ..tiers.budget import make_budget, reference_delay_s
from ..tiers.common import beat_flags
from ..tiers.common import range_ambiguous as _range_ambiguous
from ..tiers.echoes import Echoes, footprint_echoes
from ..tiers.link_survey import ShotStreams, SurveyPath, overlap_at, static_phase, survey_shots
from ..tiers.model import Returns
from ..tiers.registry import TIERS
from ..units import SPEED_OF_LIGHT_M_S, db_to_ratio


def survey_returns(config, range_m: float, transmission: float, batch: int = 1, *,
                   reference_delay_s=None, power_factor=1.0, phase_rad=0.0, doppler_hz=0.0,
                   echoes=None) -> Returns:
    """:class:`~chirplidar.tiers.model.Returns` of ``batch`` survey shots whose (mean) return
    lies at ``range_m`` with received / transmitted power ``transmission`` (W/W), the carrier
    phase setting and group index of the configuration's path."""
    ch = config.channel
    delay = float(two_way_delay_s(range_m, ch.group_index))
    return Returns(transmission=transmission, delay_s=delay, range_m=range_m,
                   group_index=ch.group_index, power_factor=power_factor, phase_rad=phase_rad,
                   doppler_hz=doppler_hz, carrier_phase=ch.carrier_phase, echoes=echoes,
                   reference_delay_s=reference_delay_s, batch=batch)


def survey_path(config) -> SurveyPath:
    """The link tier's :class:`~chirplidar.tiers.link_survey.SurveyPath` of a survey."""
    d_tel = config.channel.telescope_diameter_m
    return SurveyPath(group_index=config.channel.group_index,
                      reference_fraction=lambda r: reference_power_fraction(d_tel, r),
                      carrier_phase=config.channel.carrier_phase)

def check_range_window(config, source: str) -> None:
    """ConfigError unless ``survey.range_window_m``'s beats fit in the processed band."""
    from ..config.loader import ConfigError
    from ..tiers.common import peak_search_max_hz

    w = config.survey.range_window_m
    if w is None:
        return
    bud = lab_budget(config)
    lag_span = 2.0 * config.channel.group_index * w / SPEED_OF_LIGHT_M_S   # near to far edge
    span = bud.rate_hz_per_s * lag_span                                    # its beats [Hz]
    top = peak_search_max_hz(instrument_from_config(config), bud)
    room = top - config.processing.highpass_hz
    if lag_span >= bud.train.rise_s:
        raise ConfigError(f"{source}: survey.range_window_m = {w:g} m is longer than the chirp: "
                          f"its far edge lags the reference by {lag_span * 1e6:.3g} us, beyond "
                          f"the {bud.train.rise_s * 1e6:.3g} us ramp (no overlap, and ranges "
                          "would alias by c T / 2)")
    if span > room:
        w_max = w * room / span
        raise ConfigError(f"{source}: survey.range_window_m = {w:g} m needs beats from "
                          f"{config.processing.highpass_hz / 1e6:g} to "
                          f"{(config.processing.highpass_hz + span) / 1e6:.3g} MHz, above the "
                          f"processed band's top {top / 1e6:.3g} MHz: at most {w_max:.0f} m")


def window_reference_delay_s(config, geom, r_mean_m):
    """Per shot-beam (reference delay [s], outside-the-window mask) of ``survey.range_window_m``,
    or (None, all False) when the survey has no range window (module docstring)."""
    w = config.survey.range_window_m
    outside = np.zeros(np.shape(r_mean_m), bool)
    if w is None:
        return None, outside
    n_grp = config.channel.group_index
    near = geom.range_predicted_m - 0.5 * w
    rate = lab_budget(config).rate_hz_per_s
    ref = 2.0 * n_grp * np.where(np.isfinite(near), near, 0.0) / SPEED_OF_LIGHT_M_S \
        - config.processing.highpass_hz / rate
    with np.errstate(invalid="ignore"):
        outside = ~((r_mean_m >= near) & (r_mean_m <= near + w))
    return ref, outside & np.isfinite(r_mean_m)


def gate_lags(config, bud, geom, r_mean_m):
    """Per shot-beam (tau - tau_ref reduced to a chirp period [s], reference delay [s], outside
    the range window) of the shots' power-weighted mean ranges: the range window's gate, else
    the configuration's reference delay (fixed or the ``sys.fmaxopt`` rule)."""
    ok = np.isfinite(r_mean_m)
    delay = 2.0 * config.channel.group_index * np.where(ok, r_mean_m, 1.0) / SPEED_OF_LIGHT_M_S
    ref, outside = window_reference_delay_s(config, geom, r_mean_m)
    if ref is None:
        ref = reference_delay_s(instrument_from_config(config), delay, bud.rate_hz_per_s)
    return np.mod(delay - ref, bud.train.period_s), ref, outside


def doppler_displaced(config, scene, geom, bud, lag_s) -> np.ndarray:
    """(n, b) shots whose Doppler shift the record resolves (|f_d| T_ov >= 1, T_ov the chirps'
    overlap at the shot's lag ``lag_s``, as the link tier splits the line: it moves by more than
    the range resolution) with nothing to recover it (module docstring)."""
    f_d = np.abs(shot_doppler_hz(config, scene, geom))
    out = np.zeros(f_d.shape, bool)
    have = (f_d > 0) & np.isfinite(lag_s)
    if config.processing.doppler_recovery != "none" or not np.any(have):
        return out
    out[have] = f_d[have] * overlap_at(instrument_from_config(config), bud, lag_s[have]) >= 1.0
    return out


def range_ambiguous(bud, delay_minus_ref_s) -> np.ndarray:
    """Shots whose delay lies outside [tau_ref, tau_ref + T) (T the chirp period): the beat is
    that of a delay whole periods away and the range read from it is off by a multiple of
    c T / (2 n) (``tiers.common.range_ambiguous``; ``detected = 5``)."""
    return np.asarray(_range_ambiguous(bud, delay_minus_ref_s), bool)


def _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
            out_of_band, outside_window, displaced, ambiguous=None) -> dict:
    """The survey's per-shot fields; ``detected`` says why a return does not count: 2 no
    surface; 3 outside the range gate (``survey.range_window_m``, or without one the ranges
    whose beat lies in the processed band with the chirps overlapping); 5 range ambiguous (the
    delay lies outside [tau_ref, tau_ref + T): the range read is off by a multiple of
    c T / 2n), whatever its SNR; 4 Doppler-displaced; 0 below the detection threshold. An SNR
    of zero (no tone) is written as NaN (the fill value), never as a sentinel dB value."""
    thr = float(db_to_ratio(config.survey.detection_threshold_db))
    hit = np.isfinite(geom.range_true_m)
    outside = outside_window | (ok & (no_overlap | out_of_band))
    seen = np.where(ok & (snr >= thr), 1, 0)
    detected = np.where(displaced & (seen == 1), 4, seen)
    if ambiguous is not None:
        detected = np.where(ok & ambiguous, 5, detected)
    detected = np.where(~hit, 2, np.where(outside, 3, detected))
    det = detected == 1
    with np.errstate(divide="ignore"):
        snr_db = np.where(ok & (snr > 0), 10.0 * np.log10(np.where(snr > 0, snr, 1.0)), np.nan)
    return {
        "received_power": np.where(hit, psig, np.nan),
        "snr_db": np.where(hit, snr_db, np.nan),
        "beat_frequency": np.where(det, f_meas, np.nan),
        "beat_width": np.where(det, width, np.nan),
        "range_measured": np.where(det, range_meas, np.nan),
        "detected": detected.astype(np.int8),
    }


def rf_shot_stream(seq, flat: int) -> np.random.Generator:
    """The rf tier's random stream of shot-beam ``flat`` (= shot index x beams + beam) of the
    chunk whose SeedSequence is ``seq``."""
    return stream(seq, "rf_shot", int(flat))


def measure_link(config, scene, geom, seq) -> dict:
    """Link-tier measurements of every shot-beam of a chunk: arrays (n, b)."""
    if config.system.modulation != "fm_chirp":
        raise ValueError("survey runs model FM chirps (system.modulation = 'fm_chirp')")
    bud = lab_budget(config)
    psig, r_mean, r_std, _, eff_phase = received(config, scene, geom, seq)
    n_grp = config.channel.group_index
    rate = bud.rate_hz_per_s
    ok = np.isfinite(r_mean) & (psig > 0)
    snr = np.full(psig.shape, 0.0)
    f_meas, range_meas, width = (np.full(psig.shape, np.nan) for _ in range(3))
    delay = 2.0 * n_grp * np.where(ok, r_mean, 1.0) / SPEED_OF_LIGHT_M_S
    lag, ref, outside = gate_lags(config, bud, geom, np.where(ok, r_mean, np.nan))
    f_b = rate * lag
    no_overlap, out_of_band = beat_flags(instrument_from_config(config), bud, lag, f_b)
    if np.any(ok):
        window = config.survey.range_window_m
        streams = ShotStreams(fading=stream(seq, "link_fading"), noise=stream(seq, "link_noise"),
                              sideband=stream(seq, "doppler_sideband"))
        shots = survey_shots(
            instrument_from_config(config), survey_path(config), bud, streams,
            range_m=r_mean[ok], range_std_m=r_std[ok],
            att_db=reference_attenuation_db(config.channel.telescope_diameter_m, r_mean[ok],
                                            psig[ok] / bud.ptx_w),
            delay_s=delay[ok], ref_delay_s=ref[ok], lag_s=lag[ok], f_beat_hz=f_b[ok],
            no_overlap=no_overlap[ok], phase_rad=eff_phase[ok],
            doppler_hz=shot_doppler_hz(config, scene, geom)[ok],
            doppler="doppler" in scene.effects,
            window_lag_s=None if window is None else (config.processing.highpass_hz / rate
                                                      + n_grp * window / SPEED_OF_LIGHT_M_S))
        snr[ok], width[ok], f_meas[ok] = shots["snr"], shots["width_hz"], shots["f_meas_hz"]
        range_meas[ok] = SPEED_OF_LIGHT_M_S * (shots["f_meas_hz"] / rate + ref[ok]) / (2.0 * n_grp)
    return _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
                   out_of_band, outside,
                   doppler_displaced(config, scene, geom, bud, np.where(ok, lag, np.nan)),
                   ambiguous=ok & range_ambiguous(bud, delay - ref))


def rf_shot_returns(config, instrument, ptx_w: float, geom, fr: FootprintReturns, i: int, j: int,
                    doppler_hz, window_ref=None) -> Returns:
    """The rf tier's returns of shot ``i``, beam ``j`` of a chunk: the footprint's power-weighted
    mean range R0 with the received power P_sig of the footprint (``fr``), its sub-rays as
    echoes at their delay offsets 2 n (R_k - R0) / c (:func:`~chirplidar.tiers.echoes.
    footprint_echoes`, whose gain g scales the received power), the shot's Doppler shift
    ``doppler_hz[i, j]`` and, with ``survey.range_window_m``, the shot's range gate
    (``window_ref``: the chunk's, as :func:`window_reference_delay_s` gives them; computed when
    not passed)."""
    n_grp = config.channel.group_index
    r0 = float(fr.range_m[i, j])
    ref = window_ref if window_ref is not None else window_reference_delay_s(
        config, geom, fr.range_m)[0]
    gate = None if ref is None else float(ref[i, j])
    mean = survey_returns(config, r0, float(fr.psig_w[i, j]) / ptx_w, reference_delay_s=gate,
                          doppler_hz=float(doppler_hz[i, j]))
    w = fr.frac[i, j]
    keep = w > 0
    dtau = 2.0 * n_grp * (geom.sub_range_m[i, j][keep] - r0) / SPEED_OF_LIGHT_M_S
    offs, pw, phase, gain = footprint_echoes(
        instrument, make_budget(instrument, mean), w[keep][None], dtau[None],
        None if fr.fields is None else fr.fields[i, j][keep][None])
    # The record receives the footprint's power times the echoes' gain.
    return survey_returns(config, r0, mean.transmission * gain[0], reference_delay_s=gate,
                          doppler_hz=mean.doppler_hz, echoes=Echoes(offs[0], pw[0], phase[0]))


def _tier_columns(n: int, b: int):
    """Empty (n, b) columns of a time-domain tier's survey measurements."""
    return {"snr": np.zeros((n, b)), "f_meas": np.full((n, b), np.nan),
            "range_meas": np.full((n, b), np.nan), "width": np.full((n, b), np.nan),
            "no_overlap": np.zeros((n, b), bool), "out_of_band": np.zeros((n, b), bool)}


def _store(cols: dict, rows, out, bud, n_grp: float) -> None:
    """Write a tier's :class:`~chirplidar.tiers.model.Measurements` into ``cols`` at ``rows``."""
    cols["snr"][rows] = db_to_ratio(out["SNR"])
    cols["f_meas"][rows] = out["f_beat_hz"]
    cols["range_meas"][rows] = out["d_rx"]
    cols["width"][rows] = out["d_3dB"] * 2.0 * n_grp * bud.rate_hz_per_s / SPEED_OF_LIGHT_M_S


def measure_rf(config, scene, geom, seq, progress=None) -> dict:
    """rf-tier measurements: each shot-beam is simulated at full rate, its footprint's sub-rays
    summed as delayed echoes (:func:`rf_shot_returns`): a sloped or rough footprint broadens the
    beat peak. With ``speckle`` enabled each sub-ray carries its own speckle field (their sum is
    the footprint's speckle, so the speckle effect's per-shot draw is not applied); otherwise the
    footprint returns its mean power with one common carrier phase (no interference between the
    sub-ray samples). ``chirplidar shot`` on a survey mission evaluates one of these shots."""
    bud = lab_budget(config)
    instrument = instrument_from_config(config)
    fr = footprint_returns(config, scene, geom, seq)
    n, b = fr.psig_w.shape
    cols = _tier_columns(n, b)
    n_grp = config.channel.group_index
    lags, window_ref, outside = gate_lags(config, bud, geom, fr.range_m)
    gate_ref = window_ref
    if config.survey.range_window_m is None:
        window_ref = None
    f_d = shot_doppler_hz(config, scene, geom)
    for flat in np.flatnonzero(fr.ok.ravel()):  # the rf tier is the reference: one shot at a time
        i, j = divmod(int(flat), b)
        returns = rf_shot_returns(config, instrument, bud.ptx_w, geom, fr, i, j, f_d, window_ref)
        out = TIERS["rf"].simulate(instrument, returns, rf_shot_stream(seq, flat))
        _store(cols, (i, j), {k: out[k][0] for k in ("SNR", "f_beat_hz", "d_rx", "d_3dB")},
               bud, n_grp)
        cols["no_overlap"][i, j] = "no_overlap" in out["flags"]
        cols["out_of_band"][i, j] = "beat_out_of_band" in out["flags"]
        if progress is not None:
            progress(1)
    delay = 2.0 * n_grp * np.where(fr.ok, fr.range_m, 1.0) / SPEED_OF_LIGHT_M_S
    return _finish(config, geom, fr.psig_w, cols["snr"], cols["f_meas"], cols["range_meas"],
                   cols["width"], fr.ok, cols["no_overlap"], cols["out_of_band"], outside,
                   doppler_displaced(config, scene, geom, bud, np.where(fr.ok, lags, np.nan)),
                   ambiguous=fr.ok & range_ambiguous(bud, delay - gate_ref))


def _baseband_batch(config, instrument, bud, geom, fr: FootprintReturns, idx, window_ref, f_d):
    """The returns of one baseband batch (flat shot-beam indices ``idx``), aimed at the batch's
    median range (and median range gate, with a range window): each shot's own delay enters as
    its echoes' offsets from that range, its own power as its power factor and, with
    ``channel.carrier_phase = "propagation"``, its own delay's propagation phase."""
    b = fr.psig_w.shape[1]
    ii, jj = np.divmod(idx, b)
    n_grp = config.channel.group_index
    r0 = float(np.median(fr.range_m[ii, jj]))
    gate = None if window_ref is None else float(np.median(window_ref[ii, jj]))
    mean = survey_returns(config, r0, reference_power_fraction(
        config.channel.telescope_diameter_m, r0).item(), reference_delay_s=gate)
    bud_batch = make_budget(instrument, mean)
    w = fr.frac[ii, jj]                                                  # (m, k)
    dtau = 2.0 * n_grp * (np.where(w > 0, geom.sub_range_m[ii, jj], r0) - r0) / SPEED_OF_LIGHT_M_S
    offs, pw, phase, gain = footprint_echoes(instrument, bud_batch, w, dtau,
                                             None if fr.fields is None else fr.fields[ii, jj])
    delay = 2.0 * n_grp * fr.range_m[ii, jj] / SPEED_OF_LIGHT_M_S
    shot_phase = np.zeros(idx.size)
    if config.channel.carrier_phase == "propagation":
        # The tier applies the batch's propagation phase; each shot's is its own delay's.
        cp = config.channel.carrier_phase
        shot_phase = (static_phase(instrument, cp, bud_batch, delay, bud_batch.ref_delay_s)
                      - static_phase(instrument, cp, bud_batch, bud_batch.delay_s,
                                     bud_batch.ref_delay_s))
    returns = survey_returns(config, r0, mean.transmission, idx.size, reference_delay_s=gate,
                             power_factor=fr.psig_w[ii, jj] / bud_batch.psig_w * gain,
                             phase_rad=shot_phase, doppler_hz=f_d[ii, jj],
                             echoes=Echoes(offs, pw, phase))
    return returns, np.mod(delay - bud_batch.ref_delay_s, bud.train.period_s), \
        delay - bud_batch.ref_delay_s


def measure_baseband(config, scene, geom, seq, progress=None) -> dict:
    """Baseband-tier measurements of a chunk, in batches of shots: each shot's footprint sub-rays
    become echoes (as in :func:`measure_rf`), its received power, carrier phase and Doppler
    per-shot returns. Shots are sorted by range and batched; a batch shares one instrument
    aim at its median range (:func:`_baseband_batch`), so the ``sys.fmaxopt`` range gate (when
    ``system.reference_delay_s`` is unset) is set per batch of at most BASEBAND_BATCH
    neighbouring ranges, not per shot."""
    from ..tiers.baseband import band_top_hz_or_nyquist, baseband_grid

    bud = lab_budget(config)
    instrument = instrument_from_config(config)
    band_top = band_top_hz_or_nyquist(instrument, baseband_grid(instrument)[0])
    fr = footprint_returns(config, scene, geom, seq)
    n, b = fr.psig_w.shape
    cols = _tier_columns(n, b)
    f_d = shot_doppler_hz(config, scene, geom)
    window_ref, outside = window_reference_delay_s(config, geom, fr.range_m)
    lags = np.full((n, b), np.nan)
    ambiguous = np.zeros((n, b), bool)
    flat = np.flatnonzero(fr.ok.ravel())
    order_by = fr.range_m if window_ref is None else window_ref
    flat = flat[np.argsort(order_by.ravel()[flat], kind="stable")]
    for batch_index, start in enumerate(range(0, flat.size, BASEBAND_BATCH)):
        idx = flat[start:start + BASEBAND_BATCH]
        rows = np.divmod(idx, b)
        returns, lag, delay_minus_ref = _baseband_batch(config, instrument, bud, geom, fr, idx,
                                                        window_ref, f_d)
        out = TIERS["baseband"].simulate(instrument, returns,
                                         stream(seq, "baseband_batch", batch_index))
        _store(cols, rows, out, bud, config.channel.group_index)
        # Per-shot flags from each shot's own lag (the tier's flags describe the batch's centre).
        lags[rows] = lag
        ambiguous[rows] = range_ambiguous(bud, delay_minus_ref)
        f_b = bud.rate_hz_per_s * lag
        cols["no_overlap"][rows], cols["out_of_band"][rows] = beat_flags(instrument, bud, lag,
                                                                         f_b)
        cols["out_of_band"][rows] |= f_b > band_top
        if progress is not None:
            progress(idx.size)
    return _finish(config, geom, fr.psig_w, cols["snr"], cols["f_meas"], cols["range_meas"],
                   cols["width"], fr.ok, cols["no_overlap"], cols["out_of_band"], outside,
                   doppler_displaced(config, scene, geom, bud, lags), ambiguous=ambiguous)
