"""The pulsed tier: a short-pulse direct-detection altimeter (GLAS, MOLA; thesis Ch. 2, Tables
2.1-2.2, eqs. 2.1.1, 2.2.3-2.2.4, Table 2.5).

One shot, in primary photoelectrons per digitizer sample (bins of dt = 1 / sample_rate_hz over the
window of record_samples, its start ``returns.reference_delay_s`` or centred on ``delay_s``):

1. the mean (:func:`expected_waveform`): the received energy E_rx = E_tx x transmission x
   power_factor gives eta E_rx / (h nu) signal photoelectrons (eq. 2.2.4), shared among the
   footprint's echoes by their power weights (direct detection sums powers: the echoes' phases do
   not enter), each echo the transmitted pulse seen through the detector's Gaussian impulse
   response (sigma_h = sqrt(ln 2) / (2 pi B), B its -3 dB bandwidth), integrated exactly over
   each bin (:mod:`chirplidar.waveform.pulse`); plus the background eta P_b dt / (h nu) and the
   dark electrons per sample;
2. the draw: Poisson photoelectrons of that mean in each sample (the detector's response is
   applied to the rate, so a photon counter's timing jitter is exact and an APD's filtered shot
   noise has the right mean and variance per sample); an APD multiplies them (Gamma gain of mean
   1 and variance F - 1 per electron, referred to the primary) and adds its circuit noise
   (thermal, amplifier and surface leakage of ``receiver.detectors.apd_noise``: its variance per
   sample over the noise bandwidth min(1 / (4 sqrt(pi) sigma_h), fs / 2), white noise through
   the detector's response, so samples closer than sigma_h are correlated, :func:`circuit_noise`);
   a photon counter loses the arrivals within its dead time;
3. the digitizer (APD): codes 0 .. 2^bits - 1 over [0, full scale], full scale the shot's
   expected peak + 5 standard deviations (``agc``) or ``full_scale_photoelectrons``; a sample
   above full scale is clipped and flags ``saturation``; a photon counter's counts are exact;
4. detection: the first sample reaching the threshold, the mean background + threshold_sigma x
   the background's standard deviation per sample (APD); a photon counter sums its counts over a
   window of the received pulse's FWHM (a dead time leaves at most a count or so per sample, so
   a per-sample count K >= 2 would never be reached), its threshold the smallest count K whose
   Poisson tail under the window's background is at most the Gaussian tail Q(threshold_sigma)
   (a dead time lets at most floor(window / dead time) + 1 counts into the window: a threshold
   above that flags ``threshold_unreachable``);
5. the range estimator (``pulse_ranging.estimator``, :mod:`chirplidar.processing.pulse_estimators`).

SNR (Gardner 1992, IEEE TGRS 30(5) 1061, eq. 20; Abshire et al. 2000 for the APD):
N_s^2 / (F (N_s + N_b) + sigma_c^2) over the received pulse, N_s the signal photoelectrons,
N_b the background and dark electrons and sigma_c^2 the circuit and quantisation variance over
the pulse's equivalent duration (sum mu_s)^2 / sum mu_s^2 samples (F = 1, sigma_c = 0 for a
photon counter).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import fftconvolve

from ..processing.pulse_estimators import (
    centroid,
    gaussian_detection_probability,
    gaussian_false_alarm_probability,
    gaussian_fit,
    poisson_detection_probability,
    poisson_min_count,
    strongest_region,
    threshold_crossing,
    window_sums,
    arrival_time_crb_s,
)
from ..receiver import shot_psd
from ..receiver.detectors import apd_noise
from ..receiver.photon import apd_multiplied_electrons, dead_time_counts, poisson_counts
from ..units import ELEMENTARY_CHARGE_C, PLANCK_J_S, SPEED_OF_LIGHT_M_S, power_dbm, ratio_db
from ..waveform.pulse import (
    bin_energy_fractions,
    check_pulse_timing,
    impulse_sigma_s,
    peak_power_per_joule,
    response_fwhm_s,
)
from .model import Instrument, Measurements, Returns

#: What the pulsed tier reports for each shot (the chirped tiers' are thesis Table 4.10's,
#: ``tiers.common.OUTPUT_UNITS``): units and long names.
OUTPUT_UNITS: dict[str, str] = {
    "Ptx": "dBm",
    "Psig": "dBm",
    "E_rx_j": "J",
    "n_signal": "1",
    "n_background": "1",
    "SNR": "dB",
    "detected": "1",
    "p_detect": "1",
    "p_false_alarm": "1",
    "false_alarm_rate_hz": "Hz",
    "d_rx": "m",
    "d_error": "m",
    "d_sigma": "m",
    "pulse_width_s": "s",
}
OUTPUT_LONG_NAMES: dict[str, str] = {
    "Ptx": "transmitted peak optical power",
    "Psig": "received peak optical power of the unspread pulse",
    "E_rx_j": "received pulse energy",
    "n_signal": "mean signal photoelectrons",
    "n_background": "mean background and dark electrons in the range window",
    "SNR": "signal-to-noise ratio over the received pulse (Gardner 1992)",
    "detected": "the waveform reached the detection threshold",
    "p_detect": "detection probability of the expected waveform (closed form)",
    "p_false_alarm": "false-alarm probability per shot (closed form)",
    "false_alarm_rate_hz": "false alarms per second at the pulse rate",
    "d_rx": "measured range",
    "d_error": "range error dst - d_rx",
    "d_sigma": "Cramer-Rao bound of the range",
    "pulse_width_s": "RMS width of the received waveform",
}
_AGC_HEADROOM_SIGMA = 5.0  # an ideal AGC: full scale = expected peak + 5 std
_BLOCK = 1 << 22  # shots x echoes x samples per block of the expected waveform
_COUNT_FLOOR = 1.0 / 12.0  # variance of rounding to whole counts: a photon counter's fit floor


@dataclass(frozen=True)
class _Detector:
    """The pulsed receiver in primary photoelectrons per sample."""

    eta: float  # quantum or detection efficiency
    excess: float  # F (1 for a photon counter)
    dark_per_sample: float  # mean dark electrons per sample (multiplied for an APD)
    circuit_var: float  # circuit noise variance per sample, primary electrons^2
    dead_time_s: float
    analog: bool
    # The circuit noise's white-noise variance per sample, S dt / (2 q^2) (S its one-sided
    # current PSD): what a sum over the samples integrates, however fast they come (the
    # samples closer than the response are correlated, :func:`circuit_noise`).
    white_var: float = 0.0


def check_pulsed(instrument: Instrument) -> None:
    """ValueError (one line) for a pulsed instrument the tier cannot simulate."""
    for key in ("pulse", "pulse_receiver", "digitizer", "pulse_ranging"):
        if getattr(instrument, key) is None:
            raise ValueError(f"a pulsed instrument needs a [{key}] section")
    det = instrument.pulse_receiver.detector
    if det == "apd" and instrument.apd is None:
        raise ValueError("pulse_receiver.detector = 'apd' needs an [apd] section")
    if det == "photon_counting" and instrument.photon_counting is None:
        raise ValueError(
            "pulse_receiver.detector = 'photon_counting' needs a [photon_counting] section"
        )
    p, dig = instrument.pulse, instrument.digitizer
    check_pulse_timing(p.duration_s, p.prf_hz, dig.sample_rate_hz, dig.record_samples)


def _detector(instrument: Instrument) -> _Detector:
    fs = instrument.digitizer.sample_rate_hz
    dt = 1.0 / fs
    if instrument.pulse_receiver.detector == "photon_counting":
        pc = instrument.photon_counting
        return _Detector(
            pc.detection_efficiency, 1.0, pc.dark_count_rate_hz * dt, 0.0, pc.dead_time_s, False
        )
    a = instrument.apd
    noise = apd_noise(instrument, 1.0, 0.0)  # the circuit terms do not depend on the power
    psd = noise.thermal + noise.amplifier + float(shot_psd(a.leakage_current_a)) / a.gain**2
    noise_bw = min(1.0 / (4.0 * np.sqrt(np.pi) * sigma_h_s(instrument)), fs / 2.0)
    var_e = psd * noise_bw * (dt / ELEMENTARY_CHARGE_C) ** 2  # A^2 -> electrons^2 per sample
    bulk = (a.solar_current_a + a.background_current_a) * dt / ELEMENTARY_CHARGE_C
    white = psd * dt / (2.0 * ELEMENTARY_CHARGE_C**2)
    return _Detector(a.quantum_efficiency, a.excess_noise_factor, bulk, var_e, 0.0, True, white)


def sigma_h_s(instrument: Instrument) -> float:
    """The detector's Gaussian impulse response: sqrt(ln 2) / (2 pi B) [s]."""
    return impulse_sigma_s(instrument.pulse_receiver.bandwidth_hz)


def sample_times_s(instrument: Instrument, returns: Returns) -> np.ndarray:
    """(n,) centres of the digitizer's samples (absolute round-trip delay, s)."""
    dig = instrument.digitizer
    dt, n = 1.0 / dig.sample_rate_hz, dig.record_samples
    start = (
        returns.reference_delay_s
        if returns.reference_delay_s is not None
        else returns.delay_s - 0.5 * n * dt
    )
    return start + (np.arange(n) + 0.5) * dt


def photon_energy_j(instrument: Instrument) -> float:
    """h nu = h c / lambda [J]."""
    return PLANCK_J_S * SPEED_OF_LIGHT_M_S / instrument.wavelength_m


def received_energy_j(instrument: Instrument, returns: Returns) -> np.ndarray:
    """(batch,) E_rx = E_tx x transmission x power_factor [J]."""
    return instrument.pulse.energy_j * returns.transmission * returns.power_factor


def signal_waveform(instrument: Instrument, returns: Returns) -> np.ndarray:
    """(batch, n) mean signal photoelectrons per sample: eta E_rx / (h nu) (eq. 2.2.4) shared
    among the echoes by power, each the pulse through the detector, integrated over the bins."""
    check_pulsed(instrument)
    det = _detector(instrument)
    n_pe = det.eta * received_energy_j(instrument, returns) / photon_energy_j(instrument)
    echoes = returns.echo_arrays()
    if echoes is None:
        offsets, weights = np.zeros((returns.batch, 1)), np.ones((returns.batch, 1))
    else:
        offsets, weights, _ = echoes  # direct detection sums powers: phases do not enter
    t = sample_times_s(instrument, returns)
    dt = 1.0 / instrument.digitizer.sample_rate_hz
    p, sh = instrument.pulse, sigma_h_s(instrument)
    out = np.empty((returns.batch, t.size))
    rows = max(1, _BLOCK // (offsets.shape[1] * t.size))
    for r0 in range(0, returns.batch, rows):
        sl = slice(r0, min(returns.batch, r0 + rows))
        centre = returns.delay_s + offsets[sl]  # (r, k)
        a = (t - 0.5 * dt)[None, None, :] - centre[:, :, None]
        frac = bin_energy_fractions(p.shape, p.duration_s, sh, a, dt)
        out[sl] = np.einsum("rk,rkn->rn", weights[sl], frac) * n_pe[sl, None]
    return out


def background_per_sample(instrument: Instrument, returns: Returns) -> np.ndarray:
    """(batch,) mean background and dark electrons per sample: eta P_b dt / (h nu) + dark."""
    check_pulsed(instrument)
    det = _detector(instrument)
    dt = 1.0 / instrument.digitizer.sample_rate_hz
    return det.eta * returns.background_power_w * dt / photon_energy_j(instrument) + (
        det.dark_per_sample
    )


def expected_waveform(instrument: Instrument, returns: Returns) -> np.ndarray:
    """(batch, n) the noise-free mean primary photoelectrons per sample of the digitizer window:
    :func:`signal_waveform` + :func:`background_per_sample`."""
    return (
        signal_waveform(instrument, returns) + background_per_sample(instrument, returns)[:, None]
    )


def _draw(instrument: Instrument, det: _Detector, mean: np.ndarray, rng: np.random.Generator):
    """One noisy waveform per shot, primary electrons per sample (before the digitizer)."""
    counts = poisson_counts(rng, mean)
    if not det.analog:
        dt = 1.0 / instrument.digitizer.sample_rate_hz
        return dead_time_counts(rng, counts, dt, det.dead_time_s).astype(float)
    x = apd_multiplied_electrons(rng, counts, det.excess)
    if det.circuit_var > 0:
        x = x + circuit_noise(instrument, det, x.shape, rng)
    return x


def circuit_noise(instrument: Instrument, det: _Detector, shape, rng: np.random.Generator):
    """(batch, n) the APD's circuit noise, primary electrons per sample: white noise through
    the detector's Gaussian impulse response (sigma_h), scaled to ``det.circuit_var`` per
    sample. Samples closer than the response are correlated, so sampling faster than the
    detector's bandwidth gains nothing against it; a response shorter than half a sample
    leaves them independent."""
    width = sigma_h_s(instrument) * instrument.digitizer.sample_rate_hz  # in samples
    if width < 0.5:
        return rng.standard_normal(shape) * np.sqrt(det.circuit_var)
    half = int(np.ceil(4.0 * width))
    k = np.arange(-half, half + 1)
    g = np.exp(-0.5 * (k / width) ** 2)
    white = rng.standard_normal((shape[0], shape[1] + 2 * half))
    out = fftconvolve(white, g[None, :], mode="valid", axes=1)
    return out * np.sqrt(det.circuit_var / np.sum(g * g))


def _digitize(instrument: Instrument, det: _Detector, x, mean):
    """(quantised waveform, saturated (batch,), quantisation variance (batch,))."""
    if not det.analog:
        return x, np.zeros(x.shape[0], bool), np.zeros(x.shape[0])
    dig = instrument.digitizer
    top = 2**dig.bits - 1
    if dig.gain_control == "agc":
        peak = mean.max(axis=1)
        full = peak + _AGC_HEADROOM_SIGMA * np.sqrt(det.excess * peak + det.circuit_var)
    else:
        full = np.full(x.shape[0], float(dig.full_scale_photoelectrons))
    lsb = np.maximum(full, 1.0) / 2**dig.bits  # at least one photoelectron full scale
    codes = np.round(x / lsb[:, None])
    saturated = np.any(codes > top, axis=1)
    return np.clip(codes, 0, top) * lsb[:, None], saturated, lsb**2 / 12.0


def detection_window_samples(instrument: Instrument) -> int:
    """Samples a photon counter sums to detect: the received pulse's FWHM (1 for an APD)."""
    if instrument.pulse_receiver.detector != "photon_counting":
        return 1
    p = instrument.pulse
    fwhm = response_fwhm_s(p.shape, p.duration_s, sigma_h_s(instrument))
    return max(1, int(round(fwhm * instrument.digitizer.sample_rate_hz)))


def _threshold(instrument: Instrument, det: _Detector, mu_b, q_var):
    """(threshold per shot (batch,), background variance per sample (batch,)); a photon
    counter's threshold is on its window sums (:func:`detection_window_samples`)."""
    k = instrument.pulse_ranging.threshold_sigma
    if det.analog:
        var_b = det.excess * mu_b + det.circuit_var + q_var
        return mu_b + k * np.sqrt(var_b), var_b
    n_w = detection_window_samples(instrument)
    return poisson_min_count(mu_b * n_w, k).astype(float), mu_b


def _estimate(instrument: Instrument, det: _Detector, w, t, mu_b, thr, var_floor):
    """(round-trip delay, RMS width, valid), each (batch,), by the configured estimator."""
    dt = t[1] - t[0]
    p, sh = instrument.pulse, sigma_h_s(instrument)
    fwhm = response_fwhm_s(p.shape, p.duration_s, sh)
    seen = window_sums(w, detection_window_samples(instrument))
    t_cross, j0 = threshold_crossing(seen, thr[:, None], t)
    start, stop = strongest_region(seen, thr[:, None])
    tc, width, ok = centroid(w, mu_b[:, None], t, start, stop, int(np.ceil(fwhm / dt)))
    est = instrument.pulse_ranging.estimator
    if est == "threshold":  # the leading edge at the threshold, referred to the half maximum
        return t_cross + 0.5 * fwhm, width, j0 >= 0
    if est == "centroid":
        return tc, width, ok
    fit = gaussian_fit(w, t, tc, width, mu_b, det.excess, var_floor)
    return fit.t0_s, fit.sigma_s, fit.valid & ok


def _closed_forms(instrument: Instrument, det: _Detector, mu_s, mu_b, thr, var_b):
    """(p_detect, p_false_alarm), each (batch,), for independent samples."""
    mean = mu_s + mu_b[:, None]
    n = mu_s.shape[1]
    if det.analog:
        std = np.sqrt(det.excess * mean + (var_b - det.excess * mu_b)[:, None])
        p_d = gaussian_detection_probability(mean, std, thr[:, None])
        p_fa = np.full(
            mu_s.shape[0],
            gaussian_false_alarm_probability(instrument.pulse_ranging.threshold_sigma, n),
        )
        return p_d, p_fa
    # the window sums of disjoint windows, taken as independent
    n_w = detection_window_samples(instrument)
    k = thr.astype(np.int64)[:, None]
    windows = window_sums(mean, n_w)[:, ::n_w]
    p_d = poisson_detection_probability(windows, k)
    p_fa = poisson_detection_probability(np.broadcast_to(n_w * mu_b[:, None], windows.shape), k)
    return p_d, p_fa


def _snr(det: _Detector, mu_s, mu_b, q_var):
    """N_s^2 / (F (N_s + N_b) + sigma_c^2) over the pulse's equivalent duration (module doc);
    sigma_c^2 the circuit noise integrated over that duration (S T / 2 q^2, whatever the
    sample rate) plus the quantisation's."""
    n_s = mu_s.sum(axis=1)
    sq = np.einsum("bn,bn->b", mu_s, mu_s)
    n_eq = np.where(sq > 0, n_s**2 / np.where(sq > 0, sq, 1.0), 0.0)
    noise = det.excess * (n_s + mu_b * n_eq) + (det.white_var + q_var) * n_eq
    return np.where(
        noise > 0, n_s**2 / np.where(noise > 0, noise, 1.0), np.where(n_s > 0, np.inf, 0.0)
    )


def range_bound_m(instrument: Instrument, returns: Returns, det: _Detector, mu_s, mu_b, q_var):
    """(batch,) c / 2n x the Cramer-Rao bound of the return's arrival time
    (:func:`~chirplidar.processing.pulse_estimators.arrival_time_crb_s`) for its expected
    waveform: d mu / d t0 by a central difference of :func:`signal_waveform` in a fixed window,
    the variance per sample F mu + circuit + quantisation (a photon counter: mu), the circuit
    noise as its white-noise variance per sample (``_Detector.white_var``): for samples closer
    than the detector's response, whose circuit noise is correlated, a slightly conservative
    bound (the response smooths the derivative too). What an efficient estimator (the Gaussian
    fit at high SNR) reaches; NaN without signal."""
    t = sample_times_s(instrument, returns)
    dt = t[1] - t[0]
    start = float(t[0] - 0.5 * dt)  # the window held fixed while the delay moves
    h = 1e-3 * dt

    def shifted(delay_s: float) -> np.ndarray:
        return signal_waveform(
            instrument, replace(returns, delay_s=delay_s, reference_delay_s=start)
        )

    up, down = shifted(returns.delay_s + h), shifted(returns.delay_s - h)
    mean = mu_s + mu_b[:, None]
    var = det.excess * mean + (det.white_var + q_var)[:, None] if det.analog else mean
    live = var > 0
    slope = np.where(live, (up - down) / (2.0 * h), 0.0)
    with np.errstate(divide="ignore"):
        sigma_t = arrival_time_crb_s(slope, np.where(live, var, 1.0))
    return np.where(
        np.isfinite(sigma_t), SPEED_OF_LIGHT_M_S * sigma_t / (2.0 * returns.group_index), np.nan
    )


def _unreachable(instrument: Instrument, det: _Detector, thr) -> np.ndarray:
    """(batch,) shots whose threshold count a dead-time-limited photon counter cannot reach in
    its detection window: at most floor(window / dead time) + 1 counts fit in it."""
    if det.analog or det.dead_time_s <= 0:
        return np.zeros(np.shape(thr), bool)
    window_s = detection_window_samples(instrument) / instrument.digitizer.sample_rate_hz
    return thr > np.floor(window_s / det.dead_time_s) + 1


def simulate_pulsed(
    instrument: Instrument,
    returns: Returns,
    rng: np.random.Generator,
    *,
    keep_spectrum: bool = False,
) -> Measurements:
    """The pulsed tier (module doc): measurements of a batch of shots, each (batch,):
    ``d_rx`` (m, c t / 2 n_g, NaN when not detected), ``d_error`` (range_m - d_rx, the sign of
    Table 4.10), ``SNR`` (dB), ``Psig`` (dBm, the peak received power of an unspread return),
    ``Ptx`` (dBm, the transmitted peak), ``E_rx_j``, ``n_signal`` and ``n_background`` (mean
    photoelectrons in the window), ``detected``, ``p_detect`` and ``p_false_alarm`` (closed forms
    for the expected waveform, independent samples, no dead time), ``false_alarm_rate_hz``
    (p_false_alarm x prf), ``pulse_width_s`` (the fit's sigma, else the second moment),
    ``d_sigma`` (m, the range's Cramer-Rao bound, :func:`range_bound_m`).
    ``keep_spectrum``: a pulsed tier draws no spectrum (ignored)."""
    check_pulsed(instrument)
    det = _detector(instrument)
    t = sample_times_s(instrument, returns)
    mu_s = signal_waveform(instrument, returns)
    mu_b = background_per_sample(instrument, returns)
    mean = mu_s + mu_b[:, None]
    w, saturated, q_var = _digitize(instrument, det, _draw(instrument, det, mean, rng), mean)
    thr, var_b = _threshold(instrument, det, mu_b, q_var)
    floor = det.circuit_var + q_var if det.analog else np.full(returns.batch, _COUNT_FLOOR)
    delay, width, valid = _estimate(instrument, det, w, t, mu_b, thr, floor)
    detected = valid & np.isfinite(delay)
    d_rx = np.where(detected, SPEED_OF_LIGHT_M_S * delay / (2.0 * returns.group_index), np.nan)
    p_d, p_fa = _closed_forms(instrument, det, mu_s, mu_b, thr, var_b)
    e_rx = received_energy_j(instrument, returns)
    peak = peak_power_per_joule(instrument.pulse.shape, instrument.pulse.duration_s)
    values = {
        "d_rx": d_rx,
        "d_error": returns.range_m - d_rx,
        "SNR": np.atleast_1d(ratio_db(_snr(det, mu_s, mu_b, q_var))),
        "Psig": np.atleast_1d(power_dbm(e_rx * peak)),
        "Ptx": np.full(returns.batch, power_dbm(instrument.pulse.energy_j * peak)),
        "E_rx_j": e_rx,
        "n_signal": mu_s.sum(axis=1),
        "n_background": mu_b * t.size,
        "detected": detected,
        "p_detect": p_d,
        "p_false_alarm": p_fa,
        "false_alarm_rate_hz": p_fa * instrument.pulse.prf_hz,
        "pulse_width_s": np.where(detected, width, np.nan),
        "d_sigma": range_bound_m(instrument, returns, det, mu_s, mu_b, q_var),
    }
    masks = {
        "saturation": saturated,
        "not_detected": ~detected,
        "threshold_unreachable": _unreachable(instrument, det, thr),
    }
    flags = [name for name, m in masks.items() if m.any()]
    return Measurements("pulsed", values, flags, flag_masks={name: masks[name] for name in flags})
