"""Kernels against closed forms and independent numerical methods."""

import numpy as np
from scipy import stats

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


def test_unit_normals_are_standard_gaussian():
    # Box-Muller (receiver.detectors.unit_normals) against N(0, 1): KS test, the first four
    # moments within 5 standard errors, the two-sided tail beyond 4 sigma (2 Phi(-4) = 6.33e-5)
    # within 5 binomial sigmas, and no correlation between the cos and sin halves of the pairs.
    from chirplidar.receiver.detectors import unit_normals

    n = 2_000_001   # odd: the last pair is cut
    x = unit_normals(np.random.default_rng(7), n).astype(float)
    assert x.shape == (n,) and np.all(np.isfinite(x))
    assert stats.kstest(x, "norm").pvalue > 1e-3
    se = 1 / np.sqrt(n)
    assert abs(x.mean()) < 5 * se
    assert abs(x.var() - 1) < 5 * np.sqrt(2) * se
    assert abs(stats.skew(x)) < 5 * np.sqrt(6) * se
    assert abs(stats.kurtosis(x)) < 5 * np.sqrt(24) * se
    p = 2 * stats.norm.sf(4.0)
    assert abs(np.mean(np.abs(x) > 4) - p) < 5 * np.sqrt(p / n)
    half = (n + 1) // 2
    m = n - half
    assert abs(np.corrcoef(x[:m], x[half:half + m])[0, 1]) < 5 / np.sqrt(m)
    a = unit_normals(np.random.default_rng(3), (4, 2, 5))
    assert a.shape == (4, 2, 5) and a.dtype == np.float32
    assert np.array_equal(a, unit_normals(np.random.default_rng(3), (4, 2, 5)))


def _crossings_loop(x, y, level, start, lo, hi):
    """The 3 dB walk of the thesis's FFT_peak.m, one row at a time (reference for _crossings)."""
    out = np.full((2, y.shape[0]), np.nan)
    for b in range(y.shape[0]):
        xb = x if x.ndim == 1 else x[b]
        if y[b, start[b]] < level[b]:
            continue
        for side, step in ((0, -1), (1, 1)):
            j = start[b] + step
            while lo[b] <= j <= hi[b] and y[b, j] >= level[b]:
                j += step
            if lo[b] <= j <= hi[b]:
                k = j - step
                frac = (y[b, k] - level[b]) / (y[b, k] - y[b, j])
                out[side, b] = xb[k] + frac * (xb[j] - xb[k])
    return out


def test_windowed_crossings_and_range_sums_match_loops():
    # The windowed 3 dB search (narrow and wide peaks, peaks at the edges, walks that leave the
    # window or the allowed range) and the noise-window sums equal straightforward loops.
    from chirplidar.processing.spectrum import _crossings, _range_sums

    rng = np.random.default_rng(11)
    b, n = 64, 700
    x = np.arange(n) * 0.5
    y = rng.exponential(size=(b, n))
    start = rng.integers(0, n, b)
    start[:3] = (0, n - 1, 5)
    width = rng.choice([1.0, 4.0, 40.0, 400.0], b)
    idx = np.arange(n)
    y += 50 * np.exp(-0.5 * ((idx - start[:, None]) / width[:, None]) ** 2)
    level = 0.5 * y[np.arange(b), start]
    lo = np.maximum(start - rng.integers(0, 300, b), 0)
    hi = np.minimum(start + rng.integers(0, 300, b), n - 1)
    ref = _crossings_loop(x, y, level, start, lo, hi)
    for window in (None, 8, 64):
        got = np.array(_crossings(x, y, level, start, lo, hi, window=window))
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12, equal_nan=True)
    a = rng.integers(-5, n + 5, b)
    for span in (30, n):     # the gathering and the prefix-sum branches
        z = np.minimum(a + rng.integers(-3, span, b), n + 5)
        want = [y[k, max(a[k], 0):max(min(z[k], n), 0)].sum() if z[k] > a[k] else 0.0
                for k in range(b)]
        np.testing.assert_allclose(_range_sums(y, a, z), want, rtol=1e-12, atol=1e-12)
