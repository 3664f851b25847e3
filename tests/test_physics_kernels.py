"""Kernels against closed forms and independent numerical methods."""

import numpy as np

from chirplidar.config import load_mission
from chirplidar.processing import analyze_records
from chirplidar.transmitter import mzm_field, mzm_mean_power_transmission, wiener_phase
from chirplidar.waveform import ChirpTrain
from conftest import BENCH


def test_mzm_mean_transmission_bessel_matches_sampled_average():
    # Closed form (Jacobi-Anger) against the time average of eq. 2.4.16 on a fine grid.
    for bias in (1.0, 1.5, 2.0):
        cfg = load_mission(BENCH, {"mzm.Vdc": bias})
        tr = ChirpTrain.from_config(cfg)
        t = np.arange(0, tr.period_s, 1 / 12e9)
        numeric = np.mean(mzm_field(bias + tr.voltage(t), 2.0) ** 2)
        assert abs(mzm_mean_power_transmission(tr, bias, 2.0) - numeric) < 2e-4


def test_mzm_null_bias_doubles_the_power_frequency():
    # At V_b = V_pi the power is even in the drive: no component at the chirp frequency (Sec. 3.1).
    t = np.arange(4096) / 4096e6
    v = np.sin(2 * np.pi * 64e6 * t)
    p = mzm_field(2.0 + v, 2.0) ** 2
    spec = np.abs(np.fft.rfft(p)) ** 2
    assert spec[64] < 1e-20 * spec[128]


def test_wiener_phase_difference_variance():
    # Self-homodyne phase difference over tau has variance 2 pi dnu tau (Lorentzian line).
    rng = np.random.default_rng(7)
    dnu, tau = 1e5, 3.3e-6
    t = np.linspace(0, 10e-6, 50)
    a, b = wiener_phase([t, t - tau], dnu, rng, batch=4000)
    var = np.var(a - b, axis=0)
    np.testing.assert_allclose(var.mean(), 2 * np.pi * dnu * tau, rtol=0.05)


def _analyze(v, fs, r, method="dtft", span=4e6):
    return analyze_records(v[None, None], fs, r, rbw_hz=30e3, highpass_hz=1e6, zero_pad=1,
                           peak_method=method, noise_span_hz=span, noise_guard_hz=1e6)


def test_tone_calibration_and_scalloping():
    # A cos tone reads A^2 / (2 R): eq. 2.6.6 made one-sided (a spectrum analyzer's reading).
    fs, n, r, amp = 1e9, 2**16, 50.0, 1e-3
    t = np.arange(n) / fs
    f0 = 8090.5 * fs / n  # half a bin off the FFT grid (about 123.45 MHz)
    v = amp * np.cos(2 * np.pi * f0 * t)
    res = _analyze(v, fs, r)
    # Tolerance: the +-48-bin Dirichlet sum omits a tail of ~2/(pi^2 48) = 0.4 % in amplitude for
    # an untapered tone half a bin off the grid (0.04 dB); tapered beats lose less.
    assert abs(10 * np.log10(res.peak_power_w[0] / (amp**2 / (2 * r)))) < 0.05
    assert abs(res.f_peak_hz[0] - f0) < 0.005 * fs / n
    # The plain argmax (thesis FFT_peak.m) loses the rectangular-window scalloping at half a bin:
    # 20 log10(pi/2) = 3.92 dB (closed form, sinc(1/2) = 2/pi).
    loss = 10 * np.log10(res.peak_power_w[0] / _analyze(v, fs, r, "bin").peak_power_w[0])
    assert abs(loss - 20 * np.log10(np.pi / 2)) < 0.05


def test_white_noise_calibration():
    # White noise of variance s^2 reads 2 s^2 / (Fs R) per Hz (eqs. 2.6.3-2.6.5 made one-sided).
    rng = np.random.default_rng(1)
    fs, n, r, sigma = 1e9, 2**16, 50.0, 1e-5
    res = _analyze(sigma * rng.standard_normal(n), fs, r, span=80e6)
    # ~5000 bins averaged: standard error 1.4 % (0.06 dB).
    assert abs(10 * np.log10(res.noise_psd_w_per_hz[0] / (2 * sigma**2 / (fs * r)))) < 0.25
