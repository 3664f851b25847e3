"""The pulsed tier (short-pulse direct detection, GLAS/MOLA; thesis Ch. 2) against the thesis's
tables, Gardner's (1992) pulse spreading, the Cramer-Rao bound and closed-form false alarms.

Instruments are built from plain numbers: GLAS from thesis Table 2.1 (1064 nm, 75 mJ, 5 ns,
40 Hz) with a 1 m telescope (Abshire et al. 2005, GRL 32 L21S02: the 1 m beryllium telescope),
a 1 GHz, 544-sample digitizer (Abshire et al. 2005: GLAS's land waveform) and, as stated
assumptions, a 200 MHz detector bandwidth, a 450 urad field of view and a 0.8 nm filter. The
analog APD is thesis Table 4.7 (missions/thesis_bench.toml [apd]) with an assumed silicon gain
M = 100 and McIntyre's F = k M + (1 - k)(2 - 1/M) = 2.9701 for k = 0.01.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import norm, poisson

from chirplidar.config import load_mission
from chirplidar.config.instrument import instrument_from_config
from chirplidar.config.models_instrument import APD
from chirplidar.config.models_pulsed import (
    Digitizer,
    PhotonCounting,
    Pulse,
    PulseRanging,
    PulseReceiver,
)
from chirplidar.geometry.footprints import footprint_subrays
from chirplidar.geometry.raycast import cast_rays
from chirplidar.geometry.terrain import Terrain
from chirplidar.processing.pulse_estimators import arrival_time_crb_s
from chirplidar.processing.ranging import two_way_delay_s
from chirplidar.receiver.photon import photon_detection_probability
from chirplidar.tiers import TIERS, UnsupportedError
from chirplidar.tiers.echoes import Echoes
from chirplidar.tiers.model import Instrument, Returns
from chirplidar.tiers.pulsed import (detection_window_samples, expected_waveform,
                                     sample_times_s, signal_waveform)
from chirplidar.units import PLANCK_J_S, SPEED_OF_LIGHT_M_S
from conftest import CH5, apd_circuit_variance

C = SPEED_OF_LIGHT_M_S
RANGE_M = 600e3  # GLAS's operating altitude (Table 2.1)
F_MCINTYRE = 0.01 * 100 + 0.99 * (2 - 1 / 100)  # k = 0.01, M = 100


def _apd(gain=100.0, excess=F_MCINTYRE):
    return APD(feedback_temperature_k=293.0, detector_temperature_k=77.0,
               feedback_resistance_ohm=1e3, feedback_capacitance_f=100e-15,
               amp_current_noise_a_per_rthz=137e-15, amp_voltage_noise_v_per_rthz=4e-9,
               dynamic_resistance_ohm=10e9, detector_capacitance_f=1e-12, gain=gain,
               excess_noise_factor=excess, solar_current_a=0.0, background_current_a=0.0,
               leakage_current_a=50e-12, quantum_efficiency=0.8, center_frequency_hz=3e3)


def glas(*, detector="apd", duration_s=5e-9, shape="gaussian", fs=1e9, samples=544,
         bandwidth_hz=200e6, estimator="gaussian_fit", threshold_sigma=4.0, bits=8,
         dead_time_s=0.0, dark_hz=0.0, apd=True) -> Instrument:
    pc = (PhotonCounting(detection_efficiency=0.5, dead_time_s=dead_time_s,
                         dark_count_rate_hz=dark_hz) if detector == "photon_counting" else None)
    return Instrument(
        telescope_diameter_m=1.0,
        pulse=Pulse(wavelength_m=1064e-9, energy_j=75e-3, duration_s=duration_s, shape=shape,
                    prf_hz=40.0),
        pulse_receiver=PulseReceiver(detector=detector, bandwidth_hz=bandwidth_hz,
                                     field_of_view_rad=450e-6, filter_bandwidth_m=0.8e-9),
        digitizer=Digitizer(sample_rate_hz=fs, bits=bits, record_samples=samples,
                            gain_control="agc"),
        pulse_ranging=PulseRanging(estimator=estimator, threshold_sigma=threshold_sigma),
        apd=_apd() if (detector == "apd" and apd) else None,
        photon_counting=pc,
    )


def _eta(inst):
    return (inst.apd.quantum_efficiency if inst.pulse_receiver.detector == "apd"
            else inst.photon_counting.detection_efficiency)


def returns(inst, n_signal, batch, *, background_per_sample=0.0, echoes=None,
            reference_delay_s=None):
    """Returns whose mean signal is ``n_signal`` photoelectrons (eq. 2.2.4 inverted) and whose
    background is ``background_per_sample`` photoelectrons per sample."""
    h_nu = PLANCK_J_S * C / inst.wavelength_m
    eta, dt = _eta(inst), 1 / inst.digitizer.sample_rate_hz
    return Returns(
        transmission=n_signal * h_nu / (eta * inst.pulse.energy_j),
        delay_s=float(two_way_delay_s(RANGE_M, 1.0)), range_m=RANGE_M, group_index=1.0,
        power_factor=np.ones(batch), phase_rad=0.0, doppler_hz=0.0, echoes=echoes,
        reference_delay_s=reference_delay_s,
        background_power_w=background_per_sample * h_nu / (eta * dt),
    )


def _fwhm_s(t, w):
    """Full width at half maximum of a sampled single-peaked waveform (linear interpolation)."""
    half = w.max() / 2
    above = np.nonzero(w >= half)[0]
    i0, i1 = above[0], above[-1]
    t_lo = np.interp(half, [w[i0 - 1], w[i0]], [t[i0 - 1], t[i0]])
    t_hi = np.interp(half, [w[i1 + 1], w[i1]], [t[i1 + 1], t[i1]])
    return t_hi - t_lo


@pytest.mark.parametrize("shape", ["gaussian", "rectangular"])
@pytest.mark.parametrize("duration_s, table_m", [
    (5e-9, 0.75),    # thesis Table 2.1: GLAS, 5 ns -> 75 cm
    (20e-9, 3.0),    # thesis Table 2.2: MOLA, 20 ns -> 3 m
    (540e-9, 81.0),  # thesis Table 2.2: MOLA, 540 ns -> 81 m
])
def test_range_resolution_eq_2_1_1_from_the_pulse_response(shape, duration_s, table_m):
    # Eq. 2.1.1: Delta R = c tau / 2, tau the FWHM of the model's own point-target waveform:
    # 200 samples per pulse and a detector 100 / tau wide, so neither widens it by 0.1 %.
    fs = 200 / duration_s
    inst = glas(duration_s=duration_s, shape=shape, fs=fs, samples=800,
                bandwidth_hz=100 / duration_s)
    ret = returns(inst, 1000.0, 1)
    w = expected_waveform(inst, ret)[0]
    resolution_m = C * _fwhm_s(sample_times_s(inst, ret), w) / 2
    assert resolution_m == pytest.approx(table_m, rel=0.01)


def test_photon_counting_detection_vs_table_2_5():
    # Thesis Table 2.5: P(at least one photoelectron) = 1 - exp(-n) for a mean of n = 1..13
    # (photon_detection_probability reproduces it to six decimals, tests/test_photon.py).
    # N = 20000 dark, dead-time-free shots each: the fraction of shots with a count within 3
    # standard errors sqrt(p (1 - p) / N) (at most 0.0035) of the table's probability. With
    # no background the threshold is one count (K = 1), so detected = "at least one count".
    inst = glas(detector="photon_counting", estimator="threshold", samples=64)
    rng = np.random.default_rng(25)
    n_shots = 20000
    for n in range(1, 14):
        out = TIERS["pulsed"].simulate(inst, returns(inst, float(n), n_shots), rng)
        in_window = float(out["n_signal"][0])  # the window holds all but ~1e-12 of the pulse
        p = float(photon_detection_probability(in_window))
        assert p == pytest.approx(float(photon_detection_probability(float(n))), abs=1e-9)
        assert np.allclose(out["p_detect"], p, atol=1e-9)
        se = np.sqrt(p * (1 - p) / n_shots)
        frac = float(np.mean(out["detected"]))
        assert abs(frac - p) <= 3 * se + 1e-12, (n, frac, p, se)


def _sloped_echoes(inst, slope_deg, theta_d, n_sub, extent_factor):
    """The footprint of a nadir beam from RANGE_M above the plane z = x tan(slope) as echoes:
    sub-ray delays 2 (r_k - R) / c with the beam's Gaussian weights (footprint_subrays)."""
    x = np.array([-2000.0, 2000.0])
    z = np.tan(np.radians(slope_deg)) * np.array([[x[0], x[1]], [x[0], x[1]]])
    plane = Terrain.from_heightfield(x, x.copy(), z, np.zeros((2, 2), np.int32))
    o, d, w = footprint_subrays(np.array([[0.0, 0.0, RANGE_M]]), np.array([[0.0, 0.0, -1.0]]),
                                theta_d, n_sub, extent_factor=extent_factor)
    hits = cast_rays(plane, o, d)
    assert np.all(hits.hit)
    offsets = 2 * (hits.ranges_m - RANGE_M) / C
    return Echoes(offsets[None, :], w, np.zeros_like(w))


def _rms_width_s(t, w):
    m = np.sum(w * t) / np.sum(w)
    return np.sqrt(np.sum(w * (t - m) ** 2) / np.sum(w))


@pytest.mark.parametrize("slope_deg", [0.0, 2.0, 5.0, 10.0])
def test_pulse_spreading_on_a_slope_vs_gardner_1992(slope_deg):
    # Gardner (1992, IEEE TGRS 30(5) 1061, eq. 14 at nadir, flat-Earth and no roughness):
    # sigma_tau^2 = sigma_p^2 + sigma_h^2 + (4 z^2 tan^2(theta_T) / c^2) tan^2(S), theta_T the
    # beam's RMS half-width: theta_d / 2 for a 1/e^2 half-angle theta_d. GLAS's 70 m footprint
    # (Schutz et al. 2005, GRL 32 L21S01) as a 1/e^2 diameter: theta_d = 35 m / 600 km. The
    # sampled waveform adds the bins' dt^2 / 12. 400 sub-rays out to 2.5 theta_d (the
    # Gaussian's weight beyond it is exp(-12.5) = 4e-6) sample the beam; within 10 %.
    theta_d = 35.0 / RANGE_M
    inst = glas(fs=10e9, samples=4096)
    echoes = _sloped_echoes(inst, slope_deg, theta_d, 400, 2.5)
    ret = returns(inst, 1000.0, 1, echoes=echoes)
    t = sample_times_s(inst, ret)
    width = _rms_width_s(t, signal_waveform(inst, ret)[0])
    sigma_p = 5e-9 / (2 * np.sqrt(2 * np.log(2)))
    sigma_h = np.sqrt(np.log(2)) / (2 * np.pi * 200e6)  # -3 dB at 200 MHz (waveform.pulse)
    spread2 = 4 * RANGE_M**2 * np.tan(theta_d / 2) ** 2 / C**2 * np.tan(np.radians(slope_deg)) ** 2
    gardner = np.sqrt(sigma_p**2 + sigma_h**2 + spread2 + (1 / 10e9) ** 2 / 12)
    assert width == pytest.approx(gardner, rel=0.10), (width, gardner)


@pytest.mark.parametrize("detector", ["photon_counting", "apd"])
def test_gaussian_fit_precision_near_its_cramer_rao_bound(detector):
    # The Gaussian fit's range precision at high SNR (3000 signal photoelectrons, 0.5 background
    # photoelectrons per sample, no dead time) within 20 % of the Cramer-Rao bound
    # 1 / sqrt(sum (d mu_k / d t0)^2 / v_k) (Kay 1993, eq. 3.33), v_k = F mu_k + the circuit
    # noise (photon counting: v_k = mu_k, Poisson). N = 2000 shots: the standard error of the
    # sample standard deviation is sigma / sqrt(2 (N - 1)) = 1.6 %. The APD reads 16 bits, so its
    # quantisation (LSB^2 / 12) is negligible; its circuit variance is written out below.
    inst = glas(detector=detector, bits=16)
    n_shots = 2000
    ret = returns(inst, 3000.0, n_shots, background_per_sample=0.5)
    start = sample_times_s(inst, ret)[0] - 0.5e-9  # the same window for the derivative
    out = TIERS["pulsed"].simulate(inst, ret, np.random.default_rng(7))
    assert np.all(out["detected"])
    t_err = 2 * out["d_rx"] / C - ret.delay_s
    h = 1e-12
    fixed = dict(reference_delay_s=start, background_per_sample=0.5)
    one = returns(inst, 3000.0, 1, **fixed)
    mu = expected_waveform(inst, one)[0]

    def shifted(dtau):
        return signal_waveform(inst, dataclasses.replace(one, delay_s=one.delay_s + dtau))[0]

    dmu = (shifted(h) - shifted(-h)) / (2 * h)
    if detector == "apd":   # the circuit noise as white over fs / 2 (see _apd_circuit_variance)
        var = inst.apd.excess_noise_factor * mu + _apd_circuit_variance(inst, white=True)
    else:
        var = mu
    crb = float(arrival_time_crb_s(dmu, var))
    std = float(np.std(t_err, ddof=1))
    assert std == pytest.approx(crb, rel=0.20), (std, crb)
    # The tier's own range bound (d_sigma, the survey's h_li_sigma) is that bound in metres; its
    # window is centred on each shot, this one fixed 0.5 ns earlier (2 %: the bins' placement).
    assert np.median(out["d_sigma"]) == pytest.approx(C * crb / 2, rel=0.02)


def _apd_circuit_variance(inst, white=False):
    """:func:`conftest.apd_circuit_variance` of the instrument's [apd] and detector."""
    return apd_circuit_variance(inst.apd, inst.pulse_receiver.bandwidth_hz,
                                inst.digitizer.sample_rate_hz, white=white)


@pytest.mark.parametrize("detector", ["apd", "photon_counting"])
def test_threshold_false_alarms_vs_closed_form(detector):
    # Noise-only shots (no signal): the fraction whose waveform reaches the threshold anywhere in
    # the 64-sample window against the closed form for independent samples, within 3 standard
    # errors sqrt(p (1 - p) / N), N = 20000.
    # APD, dark: Gaussian circuit noise only (16 bits), 1 - (1 - Q(3))^64 (Q the normal tail).
    # Photon counting, 0.05 background photoelectrons per sample: the threshold K is the smallest
    # count with a Poisson tail P(N >= K) <= Q(3) (here K = 2), and 1 - (1 - P(N >= K))^64.
    # The photon counter samples at 200 MHz: its detection window (the received pulse's FWHM,
    # 5.2 ns) is then one sample, whose counts are independent.
    inst = glas(detector=detector, estimator="threshold", threshold_sigma=3.0, samples=64,
                bits=16, fs=1e9 if detector == "apd" else 200e6)
    assert detection_window_samples(inst) == 1
    n_shots, k = 20000, 3.0
    bg = 0.0 if detector == "apd" else 0.05
    out = TIERS["pulsed"].simulate(inst, returns(inst, 0.0, n_shots, background_per_sample=bg),
                                   np.random.default_rng(11))
    if detector == "apd":
        p_sample = norm.sf(k)
    else:
        min_count = next(c for c in range(1, 50) if poisson.sf(c - 1, bg) <= norm.sf(k))
        assert min_count == 2
        p_sample = poisson.sf(min_count - 1, bg)
    p = 1 - (1 - p_sample) ** 64
    assert np.allclose(out["p_false_alarm"], p, rtol=1e-9)
    assert np.allclose(out["false_alarm_rate_hz"], p * 40.0, rtol=1e-9)
    se = np.sqrt(p * (1 - p) / n_shots)
    frac = float(np.mean(out["detected"]))
    assert abs(frac - p) <= 3 * se, (frac, p, se)


@pytest.mark.parametrize("estimator", ["threshold", "centroid", "gaussian_fit"])
def test_estimators_range_a_strong_return(estimator):
    # A strong point return (5000 photoelectrons, APD): the centroid and the fit read the true
    # range within 4 standard errors of their mean. The threshold estimator's threshold
    # sits far below half the peak, so its leading edge reads short by the range walk: for the
    # mean Gaussian return (sigma_r^2 = sigma_p^2 + sigma_h^2, peak A, threshold T) the edge
    # crosses sigma_r (sqrt(2 ln(A / T)) - sqrt(2 ln 2)) before the half maximum; noise on the
    # edge only makes the first crossing earlier (at most twice the walk here).
    # A 5.5-sigma threshold: false alarms (1 - Phi(5.5)) x 544 = 1e-5 per shot do not enter.
    inst = glas(estimator=estimator, threshold_sigma=5.5)
    out = TIERS["pulsed"].simulate(inst, returns(inst, 5000.0, 500), np.random.default_rng(3))
    assert np.all(out["detected"]) and out["flags"] == []
    bias = float(np.mean(out["d_error"]))
    spread = float(np.std(out["d_error"]))
    if estimator == "threshold":
        sigma_r = np.hypot(5e-9 / (2 * np.sqrt(2 * np.log(2))),
                           np.sqrt(np.log(2)) / (2 * np.pi * 200e6))
        peak = 5000 / (np.sqrt(2 * np.pi) * sigma_r * 1e9)  # photoelectrons per 1 ns sample
        threshold = 5.5 * np.sqrt(_apd_circuit_variance(inst))  # dark: circuit noise (and a
        # quantisation LSB^2 / 12 of ~1 electron^2 left out: 0.2 % of the log below)
        walk = C / 2 * sigma_r * (np.sqrt(2 * np.log(peak / threshold)) - np.sqrt(2 * np.log(2)))
        assert walk * 0.9 < bias < 2 * walk and spread < 0.1, (bias, walk)
    else:
        assert abs(bias) < 4 * spread / np.sqrt(500) + 1e-3 and spread < 0.05
    assert np.all(out["pulse_width_s"] > 0)


def test_fixed_full_scale_saturates():
    # A fixed full scale below the return's peak clips it: saturation flagged on every shot.
    inst = dataclasses.replace(glas(), digitizer=Digitizer(
        sample_rate_hz=1e9, bits=8, record_samples=544, gain_control="fixed",
        full_scale_photoelectrons=50.0))
    out = TIERS["pulsed"].simulate(inst, returns(inst, 5000.0, 4), np.random.default_rng(0))
    assert "saturation" in out["flags"] and out.flag_masks["saturation"].all()


def _one_line_error(fn, exc, match):
    with pytest.raises(exc, match=match) as info:
        fn()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("make, match", [
    (lambda: glas(duration_s=0.5e-9), r"pulse.duration_s = 5e-10 s .*digitizer.sample_rate_hz"),
    (lambda: dataclasses.replace(glas(), pulse=Pulse(
        wavelength_m=1064e-9, energy_j=75e-3, duration_s=5e-9, shape="gaussian", prf_hz=2e6)),
     r"record_samples / digitizer.sample_rate_hz = 5.44e-07 s .*1 / pulse.prf_hz = 5e-07 s"),
    (lambda: glas(apd=False), r"\[apd\] section"),
    (lambda: dataclasses.replace(glas(detector="photon_counting"), photon_counting=None),
     r"\[photon_counting\] section"),
    (lambda: dataclasses.replace(glas(), digitizer=None), r"\[digitizer\] section"),
    (lambda: dataclasses.replace(glas(), pulse_ranging=None), r"\[pulse_ranging\] section"),
])
def test_bad_pulsed_instrument_is_refused_in_one_line(make, match):
    inst = make()
    rng = np.random.default_rng(0)
    ret = Returns(1e-12, 4e-3, RANGE_M, 1.0, np.ones(2), 0.0, 0.0)
    _one_line_error(lambda: TIERS["pulsed"].simulate(inst, ret, rng), ValueError, match)


def test_wrong_kind_of_instrument_is_unsupported():
    chirped = instrument_from_config(load_mission(CH5))
    assert chirped.kind == "chirped" and glas().kind == "pulsed"
    ret = Returns(1e-12, 4e-3, RANGE_M, 1.0, np.ones(1), 0.0, 0.0)
    rng = np.random.default_rng(0)
    _one_line_error(lambda: TIERS["pulsed"].simulate(chirped, ret, rng), UnsupportedError,
                    "pulsed tier does not model a chirped instrument")
    _one_line_error(lambda: TIERS["link"].simulate(glas(), ret, rng), UnsupportedError,
                    "link tier does not model a pulsed instrument")


@pytest.mark.parametrize("detector, dead_time_s", [("apd", 0.0), ("photon_counting", 0.02e-9)])
def test_same_seed_same_output(detector, dead_time_s):
    inst = glas(detector=detector, dead_time_s=dead_time_s, dark_hz=1e5)
    ret = returns(inst, 300.0, 50, background_per_sample=0.2)
    a = TIERS["pulsed"].simulate(inst, ret, np.random.default_rng(5))
    b = TIERS["pulsed"].simulate(inst, ret, np.random.default_rng(5))
    c = TIERS["pulsed"].simulate(inst, ret, np.random.default_rng(6))
    for key in a.arrays:
        np.testing.assert_array_equal(a[key], b[key])
    assert a.flags == b.flags
    assert np.all(a["detected"]) and not np.array_equal(a["d_rx"], c["d_rx"])


def test_photon_counting_detects_over_its_window_and_flags_an_unreachable_threshold():
    # A 1 GHz photon counter: its counts are summed over the received pulse's FWHM (5 samples),
    # so a 300-photoelectron return is detected although no single sample may hold the
    # threshold's count. The closed form p_detect (disjoint windows, no dead time) is 1 there.
    inst = glas(detector="photon_counting", dead_time_s=0.0)
    assert detection_window_samples(inst) == 5
    out = TIERS["pulsed"].simulate(inst, returns(inst, 300.0, 200, background_per_sample=0.2),
                                   np.random.default_rng(3))
    assert np.all(out["p_detect"] > 0.999999) and np.all(out["detected"])
    # With a 2 ns dead time at most floor(5 ns / 2 ns) + 1 = 3 counts fit in the window, fewer
    # than the threshold the window's background of 1 photoelectron needs at 4 sigma
    # (P(N >= K) <= Q(4) = 3.2e-5 for a Poisson mean of 1: K = 8): every shot is flagged.
    inst = glas(detector="photon_counting", dead_time_s=2e-9)
    out = TIERS["pulsed"].simulate(inst, returns(inst, 300.0, 200, background_per_sample=0.2),
                                   np.random.default_rng(3))
    assert min(c for c in range(1, 50) if poisson.sf(c - 1, 1.0) <= norm.sf(4.0)) == 8
    assert "threshold_unreachable" in out["flags"]
    assert np.all(out.flag_masks["threshold_unreachable"]) and not np.any(out["detected"])

