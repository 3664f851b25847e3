"""Kernels of the pulsed tier: pulse shapes through a Gaussian detector (waveform.pulse), the
background equation (receiver.background), APD gain and dead time (receiver.photon), and the
pulse estimators (processing.pulse_estimators), against closed forms and independent numerics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm, poisson

from chirplidar.processing.pulse_estimators import (
    arrival_time_crb_s,
    centroid,
    gaussian_false_alarm_probability,
    gaussian_fit,
    poisson_detection_probability,
    poisson_min_count,
    strongest_region,
    threshold_crossing,
)
from chirplidar.receiver.background import (
    background_power_w,
    surface_solar_radiance_w_m2_sr_m,
)
from chirplidar.receiver.photon import apd_multiplied_electrons, dead_time_counts
from chirplidar.waveform.pulse import (
    bin_energy_fractions,
    impulse_sigma_s,
    response_fwhm_s,
)


_FINE = 1e-12  # grid of the numerical convolution (s)


def _convolved(shape, tau, sigma_h):
    """(t, p * h (t)) by a discrete convolution on a 1 ps grid (independent of the closed
    forms): the pulse's unit-energy envelope and the Gaussian impulse response, both sampled."""
    u = np.arange(-40000, 40001) * _FINE
    if shape == "gaussian":
        sp = tau / (2 * np.sqrt(2 * np.log(2)))
        p = np.exp(-(u**2) / (2 * sp * sp)) / (np.sqrt(2 * np.pi) * sp)
    else:
        p = np.where(np.abs(u) <= tau / 2, 1 / tau, 0.0)
    h = np.exp(-(u**2) / (2 * sigma_h**2)) / (np.sqrt(2 * np.pi) * sigma_h)
    y = np.convolve(p, h, mode="same") * _FINE
    return u, y


@pytest.mark.parametrize("shape", ["gaussian", "rectangular"])
def test_bin_fractions_integrate_the_convolution(shape):
    # Each bin's fraction against the numerical convolution summed over the bin; the fractions
    # of bins covering the pulse sum to 1 (energy).
    tau, sh, dt = 5e-9, 0.8e-9, 1e-9
    starts = np.arange(-20, 20) * dt + 0.3e-9
    frac = bin_energy_fractions(shape, tau, sh, starts, dt)
    assert frac.sum() == pytest.approx(1.0, abs=1e-9)
    u, y = _convolved(shape, tau, sh)
    for a, f in zip(starts[12:28], frac[12:28]):
        inside = (u >= a) & (u < a + dt)
        assert f == pytest.approx(y[inside].sum() * _FINE, abs=2e-4)


def test_rectangular_without_detector_is_the_overlap():
    f = bin_energy_fractions("rectangular", 4e-9, 0.0, np.array([-3e-9, -1e-9, 1.5e-9]), 1e-9)
    np.testing.assert_allclose(f, [0.0, 1 / 4, 0.5 / 4], atol=1e-12)


def test_impulse_response_is_3db_down_at_the_bandwidth():
    # The numerical Fourier transform of the Gaussian impulse response: |H(B)|^2 = 1/2.
    bw = 200e6
    sh = impulse_sigma_s(bw)
    t = np.linspace(-20 * sh, 20 * sh, 4001)
    h = norm(0, sh).pdf(t)
    h_b = np.trapezoid(h * np.exp(-2j * np.pi * bw * t), t)
    assert abs(h_b) ** 2 == pytest.approx(0.5, rel=1e-6)


def test_rectangular_response_fwhm_numerically():
    tau, sh = 5e-9, 1e-9
    u, y = _convolved("rectangular", tau, sh)
    above = u[y >= y.max() / 2]
    assert response_fwhm_s("rectangular", tau, sh) == pytest.approx(
        above[-1] - above[0], abs=3 * _FINE)
    assert response_fwhm_s("gaussian", tau, 0.0) == pytest.approx(tau, rel=1e-12)


def test_background_equation_closed_form():
    # Hand-computed (Measures 1984, Sec. 7.2): rho = 0.9, E = 6.4e8 W m^-2 m^-1 (ASTM E-490 at
    # 1064 nm), sun 30 deg up, T = 0.8: L = 0.9 * 6.4e8 * 0.5 * 0.8 / pi = 7.3339e7; a 1 m
    # telescope (A = 0.785398 m^2), 450 urad (Omega = pi * 225e-6^2 = 1.590431e-7 sr), 0.8 nm
    # filter, T_opt = 0.5: P_b = 7.3339e7 * 0.8e-9 * 0.785398 * 1.590431e-7 * 0.5 = 3.6645e-9 W.
    radiance = surface_solar_radiance_w_m2_sr_m(6.4e8, np.radians(30.0), 0.9, 0.8)
    assert radiance == pytest.approx(7.3339e7, rel=1e-4)
    assert background_power_w(radiance, 0.8e-9, 1.0, 450e-6, 0.5) == pytest.approx(
        3.6645e-9, rel=1e-4)
    assert surface_solar_radiance_w_m2_sr_m(6.4e8, np.radians(-5.0), 0.9, 0.8) == 0.0
    with pytest.raises(ValueError, match="reflectance"):
        surface_solar_radiance_w_m2_sr_m(6.4e8, 0.5, 1.5, 0.8)


def test_apd_gain_has_mcintyre_mean_and_variance():
    # Referred to the primary electrons: mean n, variance n (F - 1) for n electrons (McIntyre
    # 1966); a Poisson n of mean mu then has variance F mu. 200000 draws: the SE of the mean is
    # sqrt(var / N), of the variance var sqrt(2 / N) (Gaussian approximation); 4 SE.
    rng = np.random.default_rng(1)
    n_draw, f = 200_000, 3.0
    x = apd_multiplied_electrons(rng, np.full(n_draw, 10), f)
    assert abs(x.mean() - 10) <= 4 * np.sqrt(20 / n_draw)
    assert abs(x.var() - 20) <= 4 * 20 * np.sqrt(2 / n_draw) * 1.5  # gamma's kurtosis: x 1.5
    y = apd_multiplied_electrons(rng, rng.poisson(7.0, n_draw), f)
    assert abs(y.var() - 21) <= 4 * 21 * np.sqrt(2 / n_draw) * 1.5
    np.testing.assert_array_equal(apd_multiplied_electrons(rng, np.array([0, 3]), 1.0), [0, 3])


def test_non_paralyzable_dead_time_rate():
    # A constant rate r through a non-paralyzable dead time tau_d registers r / (1 + r tau_d)
    # (Knoll 2010, eq. 4.23) in the long run; 400 records of 4000 bins, r tau_d = 1 (half). The
    # count of a renewal process with interval mean m and variance v has variance ~ T v / m^3;
    # 4 SE of the mean over the records, plus the record's start-up (one dead time).
    rng = np.random.default_rng(2)
    dt, tau_d, rate = 1e-9, 5e-9, 2e8
    counts = rng.poisson(rate * dt, (400, 4000))
    kept = dead_time_counts(rng, counts, dt, tau_d)
    t_rec = 4000 * dt
    m, v = tau_d + 1 / rate, 1 / rate**2
    expected = t_rec / m
    se = np.sqrt(t_rec * v / m**3 / 400)
    assert abs(kept.sum(axis=1).mean() - expected) <= 4 * se + 1.0
    assert np.all(kept <= counts)
    np.testing.assert_array_equal(dead_time_counts(rng, counts, dt, 0.0), counts)


def test_threshold_crossing_interpolates_a_ramp():
    t = np.arange(10) * 1.0
    w = np.array([[0, 0, 1, 2, 3, 4, 5, 4, 0, 0], [0] * 10], float)
    tc, j = threshold_crossing(w, 2.5, t)
    assert tc[0] == pytest.approx(3.5) and j[0] == 4
    assert np.isnan(tc[1]) and j[1] == -1


def test_centroid_and_fit_recover_a_noise_free_gaussian():
    t = np.arange(200) * 1e-9
    t0, s, a, b = 101.3e-9, 2.2e-9, 50.0, 3.0
    w = (a * np.exp(-((t - t0) ** 2) / (2 * s * s)) + b)[None, :]
    start, stop = strongest_region(w, b + 5)
    tc, width, ok = centroid(w, b, t, start, stop, 8)
    assert ok[0] and tc[0] == pytest.approx(t0, abs=1e-12) and width[0] == pytest.approx(
        s, rel=2e-3)
    fit = gaussian_fit(w, t, tc + 0.7e-9, width * 1.3, b + 1.0, 1.0, 0.1)
    assert fit.valid[0]
    assert fit.t0_s[0] == pytest.approx(t0, abs=1e-15)
    assert fit.sigma_s[0] == pytest.approx(s, rel=1e-9)
    assert fit.amplitude[0] == pytest.approx(a, rel=1e-9)
    assert fit.background[0] == pytest.approx(b, rel=1e-9)


def test_crb_of_a_sampled_gaussian_in_white_noise():
    # A Gaussian of amplitude A and width s finely sampled (dt << s) in white noise of variance
    # v: sum (dmu/dt0)^2 / v -> A^2 sqrt(pi) / (2 s dt v) (the integral of u^2 exp(-u^2)), so
    # the bound is sqrt(2 s dt v / (A^2 sqrt(pi))).
    dt, s, a, v = 1e-11, 2e-9, 10.0, 4.0
    t = np.arange(-4000, 4001) * dt
    d = a * np.exp(-(t**2) / (2 * s * s)) * t / s**2
    assert arrival_time_crb_s(d, v) == pytest.approx(
        np.sqrt(2 * s * dt * v / (a * a * np.sqrt(np.pi))), rel=1e-9)


def test_detection_and_false_alarm_closed_forms():
    assert gaussian_false_alarm_probability(3.0, 64) == pytest.approx(
        1 - norm.cdf(3.0) ** 64, rel=1e-12)
    assert poisson_min_count(0.0, 4.0) == 1
    k = int(poisson_min_count(0.3, 4.0))
    assert poisson.sf(k - 1, 0.3) <= norm.sf(4.0) < poisson.sf(k - 2, 0.3)
    mu = np.array([[0.1, 2.0, 0.1]])
    assert poisson_detection_probability(mu, 2)[0] == pytest.approx(
        1 - np.prod(poisson.cdf(1, mu)), rel=1e-12)
