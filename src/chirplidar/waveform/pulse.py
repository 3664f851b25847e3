"""Short pulses of a pulsed altimeter (thesis Sec. 2.1, eq. 2.1.1; Tables 2.1-2.2) seen through a
detector with a Gaussian impulse response, integrated exactly over the digitizer's sample bins.

A pulse of power envelope p(t) (unit energy) through a detector of impulse response
h(t) = exp(-t^2 / 2 sigma_h^2) / (sqrt(2 pi) sigma_h) gives the waveform p * h; the energy
fraction of sample bin [a, b) is the integral of p * h over it, in closed form, so a pulse a few
samples long is neither aliased nor mis-weighted by point sampling:

* gaussian (FWHM tau): p * h is Gaussian with sigma^2 = (tau / 2 sqrt(2 ln 2))^2 + sigma_h^2,
  and the bin's share is [erf((b - t0) / sqrt(2) sigma) - erf((a - t0) / sqrt(2) sigma)] / 2;
* rectangular (duration tau): p * h = [Phi((t - t0 + tau/2) / sigma_h) - Phi((t - t0 - tau/2) /
  sigma_h)] / tau, whose integral uses G(x) = x Phi(x) + phi(x) (G' = Phi); with sigma_h = 0 it is
  the overlap of the bin with the pulse, / tau.

A Gaussian impulse response of -3 dB (power) bandwidth B has |H(f)|^2 = exp(-4 pi^2 sigma_h^2 f^2)
= 1/2 at f = B: sigma_h = sqrt(ln 2) / (2 pi B) (:func:`impulse_sigma_s`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq
from scipy.special import erf, ndtr

from .._checks import non_negative, positive

#: FWHM of a Gaussian = this x its standard deviation: 2 sqrt(2 ln 2).
FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))
PULSE_SHAPES = ("gaussian", "rectangular")


def _shape(shape: str) -> str:
    if shape not in PULSE_SHAPES:
        raise ValueError(f"pulse.shape must be one of {', '.join(PULSE_SHAPES)}; got {shape!r}")
    return shape


def gaussian_sigma_s(fwhm_s):
    """sigma = FWHM / (2 sqrt(2 ln 2)) [s] of a Gaussian power envelope."""
    return np.asarray(fwhm_s, float) / FWHM_PER_SIGMA


def impulse_sigma_s(bandwidth_hz: float) -> float:
    """sigma_h = sqrt(ln 2) / (2 pi B) [s]: the Gaussian impulse response whose power transfer
    exp(-4 pi^2 sigma_h^2 f^2) is -3 dB at ``bandwidth_hz`` (B, Hz)."""
    positive("bandwidth_hz", bandwidth_hz)
    return float(np.sqrt(np.log(2.0)) / (2.0 * np.pi * bandwidth_hz))


def pulse_rms_width_s(shape: str, duration_s: float) -> float:
    """RMS width of the transmitted power envelope [s]: FWHM / 2.3548 (gaussian), tau / sqrt(12)
    (rectangular)."""
    positive("duration_s", duration_s)
    if _shape(shape) == "gaussian":
        return float(gaussian_sigma_s(duration_s))
    return duration_s / np.sqrt(12.0)


def peak_power_per_joule(shape: str, duration_s: float) -> float:
    """Peak of the unit-energy power envelope [W/J]: 1 / (sqrt(2 pi) sigma) or 1 / tau (GLAS:
    75 mJ x 0.94 / 5 ns = 14 MW, Table 2.1's 15 MW peak)."""
    positive("duration_s", duration_s)
    if _shape(shape) == "gaussian":
        return float(1.0 / (np.sqrt(2.0 * np.pi) * gaussian_sigma_s(duration_s)))
    return 1.0 / duration_s


def _g(x):
    """Antiderivative of the standard normal CDF: x Phi(x) + phi(x)."""
    return x * ndtr(x) + np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi)


def bin_energy_fractions(
    shape: str, duration_s: float, sigma_h_s: float, offset_start_s, dt_s: float
):
    """Energy fraction of a unit-energy pulse, seen through the Gaussian impulse response of
    standard deviation ``sigma_h_s``, in the bin [a, a + dt_s) for each ``offset_start_s`` = a
    - t0 (the bin's start relative to the pulse's centre t0; any shape). The fractions of a
    grid of bins covering the pulse sum to 1."""
    positive("duration_s", duration_s)
    non_negative("sigma_h_s", sigma_h_s)
    positive("dt_s", dt_s)
    a = np.asarray(offset_start_s, float)
    b = a + dt_s
    if _shape(shape) == "gaussian":
        s = np.sqrt(gaussian_sigma_s(duration_s) ** 2 + sigma_h_s**2) * np.sqrt(2.0)
        return 0.5 * (erf(b / s) - erf(a / s))
    half = 0.5 * duration_s
    if sigma_h_s == 0.0:
        return np.clip(np.minimum(b, half) - np.maximum(a, -half), 0.0, None) / duration_s
    s = sigma_h_s

    def big_g(x):
        return s * (_g((x + half) / s) - _g((x - half) / s))

    return (big_g(b) - big_g(a)) / duration_s


def response_fwhm_s(shape: str, duration_s: float, sigma_h_s: float) -> float:
    """FWHM [s] of the pulse seen through the detector (p * h): FWHM_per_sigma x
    sqrt(sigma_p^2 + sigma_h^2) (gaussian); for a rectangular pulse, twice the root of
    p * h (t) = p * h (0) / 2, found numerically (tau when sigma_h = 0)."""
    positive("duration_s", duration_s)
    non_negative("sigma_h_s", sigma_h_s)
    if _shape(shape) == "gaussian":
        return float(FWHM_PER_SIGMA * np.hypot(gaussian_sigma_s(duration_s), sigma_h_s))
    half = 0.5 * duration_s
    if sigma_h_s == 0.0:
        return duration_s

    def level(t):
        return ndtr((t + half) / sigma_h_s) - ndtr((t - half) / sigma_h_s)

    peak = level(0.0)
    return 2.0 * brentq(lambda t: level(t) - 0.5 * peak, 0.0, half + 10.0 * sigma_h_s)


def check_pulse_timing(
    duration_s: float, prf_hz: float, sample_rate_hz: float, record_samples: int
) -> None:
    """ValueError (one line, naming the keys) for a pulse shorter than one digitizer sample,
    or a range window (record_samples / sample_rate_hz) not shorter than the pulse period
    1 / prf_hz, which the next pulse's return would overlap."""
    if duration_s < 1.0 / sample_rate_hz:
        raise ValueError(
            f"pulse.duration_s = {duration_s:g} s is shorter than one digitizer sample "
            f"(1 / digitizer.sample_rate_hz = {1.0 / sample_rate_hz:g} s): the pulse falls "
            "between samples; raise the sample rate"
        )
    window = record_samples / sample_rate_hz
    if window >= 1.0 / prf_hz:
        raise ValueError(
            f"digitizer.record_samples / digitizer.sample_rate_hz = {window:g} s is not shorter "
            f"than the pulse period 1 / pulse.prf_hz = {1.0 / prf_hz:g} s: the next pulse would "
            "overlap the range window; lower the PRF or the record"
        )
