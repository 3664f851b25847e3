"""The link tier: closed-form link budget for the same configuration as the rf tier.

Signal: the beat tone an FFT over the record reads, (1/2) <A(t)>^2 for a tone of slowly varying
current amplitude A(t) (gated by the chirp overlap), with A from the Jacobi-Anger closed forms of the
MZM (see :mod:`chirplidar.transmitter.mzm`). Noise: the one-sided current PSDs of the detector at its
mean operating point. SNR = tone / (noise PSD x RBW), as the rf tier measures it (eq. 2.6.12).

Range: the measured beat is drawn around the true one with the Cramer-Rao spread of a tone of the
overlap duration (Rife & Boorstyn 1974), so the link tier's d_rx has a realistic scatter; no spectrum.

Doppler: a shift the record resolves (|f_d| T_ov >= 1) splits the real homodyne line into
|f_R +- f_d| of a quarter of the optimum-phase power each (Appendix D) and the peak search takes one
of them. With the combining DSP's compensation (``processing.doppler_recovery = "dsp"``, the
phase-diversity receiver) the shot is the zero-Doppler one: its SNR, and the beat drawn about f_R
with the Cramer-Rao spread. That holds while the estimate locks: both lines f_d +- f_R of the
complex record inside the processed band (else flagged ``doppler_beyond_dsp_band``; the closed form
then overstates the shot) and a beat strong enough to be detected at all (the estimate reads the
same two lines; tests/test_doppler_dsp.py measures it on the rf and baseband tiers).

Carrier phase ``random``: :func:`simulate_link` uses the mean over a uniform phase (half the
optimum-phase power; its SNR is the mean SNR that sweeps and sensitivity curves need). The per-shot
fading about that mean (thesis eq. 3.3.12, Sec. 5 field trial, Appendix D), after the record's
averaging, is :func:`carrier_fading_factor`; survey runs (``tiers.link_survey.survey_shots``) apply it
shot by shot, as the rf and baseband tiers draw the phase per record. For the static phases
("optimal", "propagation", plus a speckle phase) they apply :func:`static_phase_factor` of each
shot's own phase to the optimum-phase SNR.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np
from scipy.special import j0

from ..processing.spectrum import PeakResult
from ..receiver import COUPLER_3DB, HYBRID_90, single_pole
from ..receiver.detectors import apd_noise, balanced_noise, pin_noise
from ..receiver.fpa import estimated_mrc_factor
from ..transmitter.mzm import mzm_drive_angles, mzm_fundamental_field, mzm_power_fundamental
from ..units import SPEED_OF_LIGHT_M_S
from .baseband_product import field_peak
from .budget import (
    arm_cross,
    coupler_field_transmission,
    if_half_width_hz,
    make_budget,
    receiver_coupler,
    responsivities,
)
from .common import (
    assemble_outputs,
    detection_flags,
    doppler_line_hz,
    optimal_phase,
    peak_search_max_hz,
)
from .model import CarrierPhase, Instrument, Measurements, Returns
from .registry import LINK_SUPPORTS

_GRID = 8192  # points over the record for slowly varying envelopes


@lru_cache(maxsize=1024)
def grid_envelope(train, duration_s: float, *shifts_s: float) -> np.ndarray:
    """``train.envelope(mod(t - s_1 - s_2 ..., period))`` on the record grid t of ``_GRID``
    points (read-only). Remembered: a survey's table nodes share their reference's and their
    range's envelopes (the train is frozen and hashable; the shifts are subtracted one by one,
    so the values are those of the expression written out)."""
    t = (np.arange(_GRID) + 0.5) * (duration_s / _GRID)
    for s in shifts_s:
        t = t - s
    out = train.envelope(np.mod(t, train.period_s))
    out.setflags(write=False)
    return out


@lru_cache(maxsize=1024)
def grid_fundamental_field(
    train, bias_v: float, v_pi_v: float, duration_s: float, shift_s: float
) -> np.ndarray:
    """``mzm_fundamental_field`` of :func:`grid_envelope` (read-only, remembered likewise)."""
    out = mzm_fundamental_field(train, bias_v, v_pi_v, grid_envelope(train, duration_s, shift_s))
    out.setflags(write=False)
    return out


def _coherence(a: np.ndarray, dt: float, linewidth_hz: float, lag_s: float) -> float:
    """E|sum A_n exp(j dtheta_n)|^2 / (sum A_n)^2 for self-homodyne phase noise.

    dtheta(t) = theta(t - tau_ref) - theta(t - tau); E exp(j(dtheta_1 - dtheta_2)) =
    exp(-2 pi dnu min(|t1 - t2|, lag)).
    """
    if linewidth_hz <= 0 or a.sum() == 0:
        return 1.0
    n = a.size
    acf = np.fft.irfft(np.abs(np.fft.rfft(a, 2 * n)) ** 2)[:n]
    d = np.arange(n) * dt
    rho = np.exp(-2 * np.pi * linewidth_hz * np.minimum(d, lag_s))
    total = acf[0] * rho[0] + 2 * np.sum(acf[1:] * rho[1:])
    return float(total / a.sum() ** 2)


#: The laser linewidth up to which the link tier's coherence factor is checked against the rf
#: tier (within 1 dB on the Chapter 5 bench, tests/test_link_fading.py); beyond it the closed
#: form leaves out the phase-noise pedestal that fills the band (at 1 GHz: 48.6 dB where rf
#: reads 5.8), so its shots are flagged ``linewidth_beyond_link_tier``.
LINK_MAX_LINEWIDTH_HZ = 20e3


def crb_sigma_f_hz(snr, rbw_hz: float, duration_s):
    """Cramer-Rao bound (Rife & Boorstyn 1974) on the frequency of a tone of ``duration_s`` whose
    SNR in ``rbw_hz`` is ``snr`` (linear): sqrt(6 / (E/N0)) / (2 pi T), E/N0 = snr rbw T."""
    e_over_n0 = np.asarray(snr, float) * rbw_hz * duration_s
    return np.sqrt(6.0 / np.maximum(e_over_n0, 1e-12)) / (2 * np.pi * np.asarray(duration_s, float))


_FADING_BLOCK = 1 << 20  # shots x records per block of carrier-phase draws (8 MB per array)


def carrier_fading_factor(
    config: Instrument, carrier_phase: CarrierPhase, rng: np.random.Generator, n: int
) -> np.ndarray:
    """(n,) per-shot factors, mean 1, on the link tier's SNR for a uniformly random carrier phase.

    The balanced pair reads 2 R Im(E_LO E_s*): a record's beat power goes as sin^2(psi) (thesis eq.
    3.3.12, "a homodyne fading term"); :func:`simulate_link` uses its mean 1/2. A record of K chirps
    (``processing.averages``), each with its own uniform psi_k (the phase wanders between chirps, as
    the rf and baseband tiers draw it), gives the SNR times

    * power averaging: F = (2/K) sum_k sin^2 psi_k (K = 1: 2 sin^2 psi, arcsine law; F -> 1 with
      variance 1/(2K) as K grows);
    * coherent averaging: F = (2/K) (sum_k sin psi_k)^2 (the mean record's amplitude; chi-square of
      one degree of freedom for large K: coherent averaging never removes the fading).

    The phase-diversity arms read sin^2 and cos^2 (Appendix C) and their spectra are summed, so
    F = (r1^2 p1 + r2^2 p2) / ((r1^2 + r2^2) / 2), p1 and p2 the two quadratures' shares as above
    (power averaging: p1 + p2 = 1, no fading for matched arms). Ones for the other carrier phases
    and receivers (the optimum and propagation phases are deterministic; direct and heterodyne
    detection do not depend on the optical phase). A Doppler shift the record resolves replaces
    the fading by the line split (Appendix D): the caller leaves those shots at 1. Laser phase noise
    over the lag is a separate mean factor (the coherence in :func:`simulate_link`); only the
    static phase fades here. Draws n x K uniforms from ``rng`` when the factor is not 1.
    """
    n = int(n)
    ones = np.ones(n)
    sysc, proc = config.system, config.processing
    if (
        carrier_phase != "random"
        or sysc.receiver != "coherent"
        or sysc.coherent_mode not in ("homodyne", "phase_diversity")
        or n == 0
    ):
        return ones
    k = int(proc.averages)
    p1, p2 = np.empty(n), np.empty(n)
    rows = max(1, _FADING_BLOCK // k)
    for s0 in range(0, n, rows):
        sl = slice(s0, min(n, s0 + rows))
        psi = rng.uniform(0.0, 2 * np.pi, (sl.stop - sl.start, k))
        s = np.sin(psi)
        if proc.averaging == "coherent":
            p1[sl] = np.sum(s, axis=1) ** 2 / k
            p2[sl] = np.sum(np.cos(psi), axis=1) ** 2 / k
        else:  # only sin^2: cos^2 = 1 - sin^2 in power (one transcendental per draw)
            p1[sl] = np.mean(s * s, axis=1)
            p2[sl] = 1.0 - p1[sl]
    if sysc.coherent_mode == "homodyne":
        return 2.0 * p1
    resp = responsivities(config, SPEED_OF_LIGHT_M_S / config.laser.wavelength_m)
    w1, w2 = resp["balanced_1"] ** 2, resp["balanced_2"] ** 2
    return (w1 * p1 + w2 * p2) / (0.5 * (w1 + w2))


def static_phase_factor(config: Instrument, psi_rad) -> np.ndarray:
    """SNR at a static carrier phase ``psi_rad`` (signal relative to the LO, rad; array) over the
    SNR at :func:`~chirplidar.tiers.common.optimal_phase`, as :func:`simulate_link` weighs it.

    * balanced pair (homodyne): i1 - i2 = 2 R Im(E_LO E_s*), the beat power goes as sin^2 psi
      (thesis eq. 3.3.12), so the factor is sin^2 psi;
    * phase diversity: arm 1 reads cos^2(psi - a), arm 2 sin^2(psi - a), a = arg(S00 S01*), and
      the arms' spectra are summed: (r1^2 cos^2(psi - a) + r2^2 sin^2(psi - a)) / r1^2;
    * direct and heterodyne detection: 1 (they do not depend on the optical phase).

    Survey runs use it shot by shot (``tiers.link_survey.survey_shots``) for the optimum and
    propagation phases, with a speckle phase added when that effect is on; its mean over a uniform
    psi is the ``random`` setting's mean phase power relative to the optimum (1/2 for homodyne).
    """
    psi = np.asarray(psi_rad, float)
    sysc = config.system
    if sysc.receiver != "coherent" or sysc.coherent_mode not in ("homodyne", "phase_diversity"):
        return np.ones(psi.shape)
    if sysc.coherent_mode == "homodyne":
        return np.sin(psi) ** 2
    a = np.angle(HYBRID_90[0, 0] * np.conj(HYBRID_90[0, 1]))
    resp = responsivities(config, SPEED_OF_LIGHT_M_S / config.laser.wavelength_m)
    w1, w2 = resp["balanced_1"] ** 2, resp["balanced_2"] ** 2
    p1 = np.cos(psi - a) ** 2
    return (w1 * p1 + w2 * (1.0 - p1)) / w1


def overlap_duration_s(config: Instrument, bud, lag_s, *, ref_delay_s: float = 0.0) -> np.ndarray:
    """Time [s] within the record where the reference and signal chirps overlap (envelope product
    above 1/4, at least one grid step) at each lag ``lag_s`` = tau - tau_ref (array), the
    reference delayed by ``ref_delay_s``: the tone's duration T_ov."""
    sim, train = config.simulation, bud.train
    t = (np.arange(_GRID) + 0.5) * (sim.duration_s / _GRID)
    gate = train.record_gate(t, sim.duration_s)
    w_lo = grid_envelope(train, sim.duration_s, ref_delay_s) * gate
    lags = np.atleast_1d(np.asarray(lag_s, float))
    out = np.empty(lags.shape)
    for k, lag in enumerate(lags.ravel()):  # a few lags per call (the table's nodes)
        w_sig = grid_envelope(train, sim.duration_s, ref_delay_s, float(lag))
        out.flat[k] = max(float(np.mean(w_lo * w_sig > 0.25)), 1.0 / _GRID) * sim.duration_s
    return out.reshape(np.shape(lag_s))


def _link_flags(
    config: Instrument, bud, returns: Returns, mode: str, s_sig: float, resp, nyquist_hz: float
) -> list[str]:
    """The batch's detection flags, ``linewidth_beyond_link_tier`` and the balanced pair's
    ``saturation``."""
    flags = detection_flags(config, bud, returns, nyquist_hz=nyquist_hz)
    if config.laser.linewidth_hz > LINK_MAX_LINEWIDTH_HZ:
        flags.append("linewidth_beyond_link_tier")
    if mode == "homodyne" and _saturates(config, bud, s_sig, resp, returns.power_factor):
        flags.append("saturation")
    return flags


def simulate_link(
    config: Instrument, returns: Returns, rng: np.random.Generator, *, keep_spectrum: bool = False
) -> Measurements:
    """The batch of ``returns`` through the closed-form link budget; arrays of shape (batch,)
    (``keep_spectrum`` is accepted and ignored: the link tier draws no spectrum)."""
    LINK_SUPPORTS.check("link", config, returns)
    batch = returns.batch
    bud = make_budget(config, returns)
    sim, proc = config.simulation, config.processing
    train = bud.train
    t = (np.arange(_GRID) + 0.5) * (sim.duration_s / _GRID)
    gate = train.record_gate(t, sim.duration_s).astype(float)
    w_sig = grid_envelope(train, sim.duration_s, bud.delay_s)
    s_sig = config.laser.power_w * bud.tx_gain * bud.h
    resp = responsivities(config, bud.nu_hz)
    mode = config.system.coherent_mode if config.system.receiver == "coherent" else "direct"
    nyquist = sim.sample_rate_hz / 2  # the rf chain this closed form stands for samples at Fs
    flags = _link_flags(config, bud, returns, mode, s_sig, resp, nyquist)
    # Overlap time of the two chirps: sets the resolution and the frequency scatter below.
    # (At least one grid cell: with no overlap the SNR is zero and the scatter spans the band.)
    t_ov = float(overlap_duration_s(config, bud, bud.lag_s, ref_delay_s=bud.ref_delay_s))
    # Doppler (Appendix D): a shift the record resolves splits the real beat into lines at
    # f_R +- f_d of a quarter of the optimum-phase power each, whatever the carrier phase. The
    # combining DSP ("dsp") removes f_d from the complex record first: no split (its validity,
    # both lines f_d +- f_R in the band, is flagged: doppler_beyond_dsp_band).
    f_d = np.abs(returns.doppler_hz)
    split = (f_d >= 1.0 / t_ov) & (proc.doppler_recovery != "dsp")
    extra = {}
    if mode in ("homodyne", "phase_diversity"):
        phase_power = np.where(split, 0.25, _phase_power(returns, bud, mode))
        tone, noise, snr, noise_psd, h2, extra = _coherent_link(
            config, bud, batch, mode, t, gate, w_sig, s_sig, resp, phase_power, split
        )
    else:
        # Direct and heterodyne chains filter before their nonlinearity or mixer: the detector
        # response is inside these closed forms, not applied at the beat frequency.
        h2 = 1.0
        chain = _heterodyne_link if mode == "heterodyne" else _direct_link
        tone, noise, snr, noise_psd = chain(config, bud, train, t, gate, w_sig, s_sig, resp)
    if (
        proc.averaging == "coherent"
        and returns.carrier_phase != "random"
        and config.laser.linewidth_hz == 0
    ):
        snr = snr * proc.averages  # a stable beat adds in amplitude, the noise in power
    # Speckle (or any effect on the received power) scales each shot's beat.
    tone = tone * returns.power_factor
    snr = snr * returns.power_factor
    snr = snr * estimated_gain_factor(config, snr, proc.rbw_hz, t_ov)
    out_scale = noise.gain_ohm**2 / noise.load_ohm * h2
    # Range scatter: Cramer-Rao bound for the frequency of a tone of duration T_ov (Rife & Boorstyn).
    sigma_f = crb_sigma_f_hz(snr, proc.rbw_hz, t_ov)
    extra = {**extra, "t_overlap_s": np.full(batch, t_ov)}
    noise_draw = rng.standard_normal(batch)
    f_meas = (
        doppler_line_hz(config, bud, np.full(batch, bud.f_beat_hz), np.where(split, f_d, 0.0), rng)
        + sigma_f * noise_draw
    )
    if config.system.modulation == "fm_chirp":
        f_meas = _noise_peak_outside_band(config, bud, f_meas, sigma_f, rng)
    half_width = 0.443 / t_ov  # -3 dB half width of a rectangular-envelope tone
    result = PeakResult(
        f_peak_hz=f_meas,
        peak_power_w=np.broadcast_to(tone * out_scale, (batch,)),
        noise_psd_w_per_hz=np.full(batch, noise_psd * out_scale),
        f_lo_hz=f_meas - half_width,
        f_hi_hz=f_meas + half_width,
        snr=np.broadcast_to(np.asarray(snr, float), (batch,)),
    )
    return assemble_outputs(
        config,
        bud,
        result,
        noise,
        flags,
        range_m=returns.range_m,
        extra=extra,
        tier="link",
        power_factor=returns.power_factor,
        nyquist_hz=nyquist,
    )


def estimated_gain_factor(config: Instrument, snr, rbw_hz: float, duration_s):
    """The SNR factor of an FPA whose DSP estimates each pixel's gain from its own beat
    (``receiver.combining = "mrc_estimated"``): ``fpa.estimated_mrc_factor`` of the record's
    energy SNR snr x RBW x T (the amplitudes are read over the tone's duration T), the
    channel having applied the known-gain sum; 1 for every other receiver. A survey's shots get
    it through the link table's nodes (``tiers.link_survey``): a node's attenuation holds the
    receiver's gain, so its SNR is the shot's before fading."""
    rx = config.receiver
    if rx is None or rx.architecture != "fpa" or rx.combining != "mrc_estimated":
        return 1.0
    energy = np.asarray(snr, float) * rbw_hz * np.asarray(duration_s, float)
    return estimated_mrc_factor(energy, rx.pixel_count)


def _phase_power(returns: Returns, bud, mode: str):
    """The beat power's carrier-phase factor of each shot: the mean 1/2 over a uniform phase
    ("random"; the per-shot fading is :func:`carrier_fading_factor`), else of each shot's static
    phase plus its speckle phase: the balanced pair reads sin^2 (i1 - i2 = 2 R Im(E_LO E_s*)),
    hybrid arm 1 cos^2(psi - arg S00 S01*)."""
    cp = returns.carrier_phase
    if cp == "random":
        return np.full(returns.batch, 0.5)
    psi = (
        optimal_phase(mode)
        if cp == "optimal"
        else -2 * np.pi * np.mod(bud.nu_hz * (bud.delay_s - bud.ref_delay_s), 1.0)
    )
    psi = psi + returns.phase_rad
    if mode == "phase_diversity":
        return np.cos(psi - np.angle(HYBRID_90[0, 0] * np.conj(HYBRID_90[0, 1]))) ** 2
    return np.sin(psi) ** 2


def _coherent_link(
    config: Instrument, bud, batch: int, mode: str, t, gate, w_sig, s_sig, resp, phase_power, split
):
    """The self-chirped coherent receivers' closed form: (tone, noise, SNR, noise PSD,
    |H(f_beat)|^2, extra outputs of the phase-diversity arms). ``split``: the shots whose
    Doppler shift the record resolves (each arm then holds a quarter of the power)."""
    b, proc, train = config.balanced, config.processing, bud.train
    bias, vpi = config.modulator.bias_v, config.modulator.v_pi_v
    duration = config.simulation.duration_s
    c_lo = grid_fundamental_field(train, bias, vpi, duration, bud.ref_delay_s)
    c_sig = grid_fundamental_field(train, bias, vpi, duration, bud.delay_s)
    s_lo = bud.lo_power_scale(b.lo_power_w)
    # Beat of the two fields' fundamentals: (1/2) c_lo c_sig cos(phi_lo - phi_sig).
    env = 0.5 * c_lo * c_sig * gate * np.sqrt(s_lo * s_sig)
    coherence = _coherence(env, t[1] - t[0], config.laser.linewidth_hz, bud.lag_s)
    loss = coupler_field_transmission(config) ** 2
    env = env * loss
    S = COUPLER_3DB if mode == "homodyne" else HYBRID_90
    mean_p = [
        loss * (abs(S[k, 0]) ** 2 * b.lo_power_w + abs(S[k, 1]) ** 2 * bud.psig_w) for k in (0, 1)
    ]
    h2 = abs(single_pole(b.bandwidth_hz)(bud.f_beat_hz)) ** 2
    r1, r2 = resp["balanced_1"], resp["balanced_2"]
    if mode == "homodyne":
        amp = (r1 + r2) * np.mean(env)  # 2 R Im(E_LO E_s*)
        tone = 0.5 * amp**2 * phase_power * coherence
        noise = balanced_noise(config, r1, r2, *mean_p)
        if bud.ase_psd_w_per_hz > 0:
            # Received ASE (two-sided PSD h S per complex envelope) beating with the LO through
            # i1 - i2 = 2 R Im(E_LO n*): one-sided current PSD 4 R^2 <|E_LO|^2> h S. Modelled for
            # the balanced pair only; the phase-diversity link leaves it out (known limits).
            r_mean = 0.5 * (r1 + r2)
            noise = dataclasses.replace(
                noise, beat=4 * r_mean**2 * loss**2 * b.lo_power_w * bud.h * bud.ase_psd_w_per_hz
            )
        return tone, noise, tone / (noise.total * proc.rbw_hz), noise.total, h2, {}
    k01 = 2 * abs(HYBRID_90[0, 0] * HYBRID_90[0, 1])
    arm_snr, arm_tone = [], []
    for arm, share in ((0, phase_power), (1, np.where(split, 0.25, 1.0 - phase_power))):
        tone_k = 0.5 * ((r1, r2)[arm] * k01 * np.mean(env)) ** 2 * share * coherence
        nz = balanced_noise(config, r1, r2, *mean_p, arm=arm)
        arm_tone.append(tone_k)
        arm_snr.append(tone_k / (nz.total * proc.rbw_hz))
    noise = balanced_noise(config, r1, r2, *mean_p, arm=0)
    # Summed arms, as the rf tier sums their spectra (thesis Fig. 5.13).
    noise_psd = sum(balanced_noise(config, r1, r2, *mean_p, arm=a).total for a in (0, 1))
    tone = sum(arm_tone)
    to_out = h2 * noise.gain_ohm**2 / noise.load_ohm
    each = lambda v: np.broadcast_to(np.asarray(v, float), (batch,))  # noqa: E731
    extra = {
        "arm1_Crx_w": each(arm_tone[0] * to_out),
        "arm2_Crx_w": each(arm_tone[1] * to_out),
        "arm1_snr": each(arm_snr[0]),
        "arm2_snr": each(arm_snr[1]),
    }
    return tone, noise, tone / (noise_psd * proc.rbw_hz), noise_psd, h2, extra


def _noise_peak_outside_band(config, bud, f_meas, sigma_f, rng: np.random.Generator):
    """``f_meas`` kept within the processed band the peak is searched in: a peak the
    Cramer-Rao spread ``sigma_f`` put outside it is drawn uniformly in the band where the spread
    is a tenth of the band or more (SNR far below 0 dB: the strongest bin is a noise bin
    anywhere, as the rf tier finds), else put at the band's edge. Draws nothing when every peak
    is in the band."""
    lo, hi = config.processing.highpass_hz, peak_search_max_hz(config, bud)
    outside = (f_meas < lo) | (f_meas > hi)
    if not np.any(outside) or not hi > lo:
        return f_meas
    wide = np.broadcast_to(sigma_f, np.shape(f_meas)) >= 0.1 * (hi - lo)
    noise_peak = rng.uniform(lo, hi, np.shape(f_meas))
    return np.where(outside & wide, noise_peak, np.clip(f_meas, lo, hi))


def _saturates(config, bud, s_sig: float, resp: dict, power_factor) -> bool:
    """The balanced pair's RF amplifier saturates (the rf and baseband tiers' ``saturation``
    test): the differential optical power that balancing leaves, at its peak, exceeds
    ``balanced.saturation_power_w``. Its peak is the baseband tier's bound of the full-rate
    difference current, 2 |c_1 - c_2| sqrt(P_lo P_sig) max|a_lo| max|a_sig| over the mean
    responsivity (c_j the arms' coupler products r_j S_j0 S_j1*), for the strongest shot."""
    b = config.balanced
    r1, r2 = resp["balanced_1"], resp["balanced_2"]
    c1, c2 = arm_cross(receiver_coupler(config, "homodyne"), (r1, r2))
    cross = c1 - c2
    s_lo = bud.lo_power_scale(b.lo_power_w)
    pf = float(np.max(power_factor)) if np.size(power_factor) else 0.0
    amp = np.sqrt(s_lo * s_sig * max(pf, 0.0))
    diff_peak = amp * 2 * abs(cross) * field_peak(config, bud) ** 2 / (0.5 * (r1 + r2))
    return bool(diff_peak > b.saturation_power_w)


def _mixer_noise_factor(train, t, gate, f_b, bandwidth_hz, ref_delay_s):
    """Mean |H|^2-weighted <r^2>/4 (S(f_b + f_inst) + S(f_inst - f_b)) factor of RF dechirp mixing."""
    tc = np.mod(t - ref_delay_s, train.period_s)
    w = train.envelope(tc) * gate
    f_inst = train.f_start_hz + train.rate_hz_per_s * tc
    H = single_pole(bandwidth_hz)
    h2 = np.abs(H(f_inst + f_b)) ** 2 + np.abs(H(np.abs(f_inst - f_b))) ** 2
    return float(np.mean(w**2 * h2) / 4.0), w, np.abs(H(f_inst))


def _direct_link(config, bud, train, t, gate, w_sig, s_sig, resp):
    """Direct detection: photocurrent at the chirp frequency, RF dechirp against the reference."""
    rx = config.system.receiver
    if rx == "pin":
        r, noise = resp["pin"], pin_noise(config, resp["pin"], bud.psig_w)
    else:
        r, noise = resp["apd"], apd_noise(config, resp["apd"], bud.psig_w)
    if bud.ase_psd_w_per_hz > 0:
        # Signal-ASE beat: |E_s + n|^2 -> 2 Re(E_s n*), one-sided PSD 4 R^2 P_sig h S.
        noise = dataclasses.replace(
            noise, beat=4 * r**2 * bud.psig_w * bud.h * bud.ase_psd_w_per_hz
        )
    p1 = mzm_power_fundamental(train, config.modulator.bias_v, config.modulator.v_pi_v, w_sig)
    mix, w_ref, h_sig = _mixer_noise_factor(
        train, t, gate, bud.f_beat_hz, noise.bandwidth_hz, bud.ref_delay_s
    )
    # The signal's instantaneous chirp frequency equals the reference's, delayed by the lag.
    tc_sig = np.mod(t - bud.delay_s, train.period_s)
    h_at_sig = np.abs(
        single_pole(noise.bandwidth_hz)(train.f_start_hz + train.rate_hz_per_s * tc_sig)
    )
    beat = 0.5 * r * s_sig * p1 * h_at_sig * w_ref
    tone = 0.5 * np.mean(beat) ** 2
    noise_psd = noise.total * mix
    return tone, noise, tone / (noise_psd * config.processing.rbw_hz), noise_psd


def _heterodyne_link(config, bud, train, t, gate, w_sig, s_sig, resp):
    """Heterodyne: IF cross term, synchronous or envelope demodulation, RF dechirp.

    Envelope detection is modelled by the fundamental of |a(t)| (rectified field) and, below an IF
    SNR of a few, by the square-law small-signal suppression factor rho / (rho + 1/2)
    (Davenport & Root 1958, Ch. 12) - an approximation; the rf tier is the reference.
    """
    b, h = config.balanced, config.heterodyne
    r = resp["heterodyne"]
    bias, vpi = config.modulator.bias_v, config.modulator.v_pi_v
    arms = 1 if h.capped_arm else 2
    loss = coupler_field_transmission(config) ** 2
    mean_p1 = 0.5 * loss * (b.lo_power_w + bud.psig_w)
    noise = balanced_noise(
        config, r, r, mean_p1, mean_p1 if arms == 2 else 0.0, arm=0 if arms == 1 else None
    )
    alpha, beta = mzm_drive_angles(train, bias, vpi)
    if h.demodulation == "envelope":
        # Fundamental of |cos(alpha + beta w sin phi)| over phi, per envelope value.
        phi = np.linspace(0, 2 * np.pi, 256, endpoint=False)
        wg = np.linspace(0, 1, 65)
        fund = np.array(
            [
                abs(2 * np.mean(np.abs(np.cos(alpha + beta * w * np.sin(phi))) * np.sin(phi)))
                for w in wg
            ]
        )
        c = np.interp(w_sig, wg, fund)
    else:
        c = mzm_fundamental_field(train, bias, vpi, w_sig)
    # IF cross term amplitude: arms x R sqrt(P_LO s_sig) |a|; the demodulated fundamental c(w).
    base = arms * r * loss * np.sqrt(b.lo_power_w * s_sig)
    mix, w_ref, _ = _mixer_noise_factor(train, t, gate, bud.f_beat_hz, 1e30, bud.ref_delay_s)
    beat = 0.5 * base * c * w_ref * gate
    tone = 0.5 * np.mean(beat) ** 2
    # Demodulated baseband noise: one-sided PSD 2 S per quadrature of the complex envelope.
    noise_psd = 2.0 * noise.total * mix * 2.0
    snr = tone / (noise_psd * config.processing.rbw_hz)
    if h.demodulation == "envelope":
        # <a^2> over the record: (1 + cos(2 alpha) J0(2 beta w)) / 2 (Jacobi-Anger).
        mean_a2 = 0.5 * (1 + np.cos(2 * alpha) * np.mean(j0(2 * beta * w_sig)))
        if_power = 0.5 * base**2 * mean_a2
        rho = if_power / (noise.total * 2 * if_half_width_hz(config, bud))
        snr *= rho / (rho + 0.5)
    return tone, noise, snr, noise_psd
