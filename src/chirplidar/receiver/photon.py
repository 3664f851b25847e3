"""Photon-limited detection (thesis Sec. 2.2, eqs. 2.2.3-2.2.4 and Table 2.5).

A pulse of peak power P_T and duration tau returned by a Lambertian target of reflectivity rho at
range R into an aperture of area A_r carries (eq. 2.2.3)

    E_s = rho P_T A_r tau / (pi R^2)    [J],

that is n_s = E_s / (h nu) photons on average (eq. 2.2.4). A detector of quantum efficiency eta
emits a Poisson number of photoelectrons of mean eta n_s; at least K of them are needed to
detect: P(N >= K) = 1 - sum_{m < K} e^-mu mu^m / m! (Table 2.5 lists K = 1 for mu = 1..13).

Example::

    >>> round(float(photon_detection_probability(5.0)), 6)   # Table 2.5, mu = 5
    0.993262
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammainc

from .._checks import count, non_negative_array, positive, positive_array, unit_interval_array
from ..units import PLANCK_J_S, SPEED_OF_LIGHT_M_S


def received_pulse_energy_j(
    reflectivity, peak_power_w, aperture_area_m2, pulse_duration_s, range_m
):
    """rho P_T A_r tau / (pi R^2) [J] (eq. 2.2.3): the energy a Lambertian target at normal
    incidence returns into the aperture from one pulse (no atmospheric or optical losses)."""
    rho = unit_interval_array("reflectivity", reflectivity)
    p_t = positive_array("peak_power_w", peak_power_w)
    area = positive_array("aperture_area_m2", aperture_area_m2)
    tau = positive_array("pulse_duration_s", pulse_duration_s)
    r = positive_array("range_m", range_m)
    return (rho * p_t * area * tau / (np.pi * r**2))[()]


def mean_signal_photons(energy_j, wavelength_m: float):
    """E_s / (h nu) (eq. 2.2.4): the mean number of photons in ``energy_j`` (J, >= 0) at
    ``wavelength_m``."""
    positive("wavelength_m", wavelength_m)
    e = non_negative_array("energy_j", energy_j)
    return (e * wavelength_m / (PLANCK_J_S * SPEED_OF_LIGHT_M_S))[()]


def photon_detection_probability(mean_photoelectrons, min_count: int = 1):
    """P(N >= ``min_count``) for a Poisson count N of mean ``mean_photoelectrons`` (>= 0):
    the regularized lower incomplete gamma P(K, mu) (thesis Table 2.5 for K = 1: 1 - e^-mu)."""
    mu = non_negative_array("mean_photoelectrons", mean_photoelectrons)
    k = count("min_count", min_count)
    if k < 1:
        raise ValueError(f"min_count must be >= 1, got {k}")
    return gammainc(k, mu)[()]


#: Above this mean a photoelectron count is drawn from its normal limit: numpy's Poisson
#: sampler refuses means beyond ~1e19 (a strong pulsed return from a low platform reaches
#: them), and at 1e8 the Poisson's skewness 1 / sqrt(mean) is 1e-4.
POISSON_NORMAL_ABOVE = 1e8
#: A dead-time detector registers at most one count per dead time; arrivals beyond this many
#: per dead time in a bin are dropped before the dead time is applied (the detector then fires
#: within ~1/65 of a dead time of going live, as it would with them).
DEAD_TIME_ARRIVAL_CAP = 64


def poisson_counts(rng: np.random.Generator, mean) -> np.ndarray:
    """Poisson counts of ``mean`` (array, >= 0), from the normal limit N(mean, mean) rounded
    and floored at 0 above :data:`POISSON_NORMAL_ABOVE` (then as whole floats: a count may
    exceed int64)."""
    mu = np.asarray(mean, float)
    big = mu > POISSON_NORMAL_ABOVE
    if not np.any(big):
        return rng.poisson(mu)
    out = rng.poisson(np.where(big, 0.0, mu)).astype(float)
    draw = np.rint(mu[big] + np.sqrt(mu[big]) * rng.standard_normal(int(big.sum())))
    out[big] = np.maximum(draw, 0.0)
    return out


def apd_multiplied_electrons(rng: np.random.Generator, primary, excess_noise_factor: float):
    """The APD's output charge of ``primary`` (integer array, >= 0) primary photoelectrons,
    referred to the primary electrons (divided by the mean gain M).

    Each primary electron's gain G has mean M and <G^2> / M^2 = F (McIntyre 1966, IEEE TED 13,
    164: F = k M + (1 - k)(2 - 1/M)), so G / M has mean 1 and variance F - 1. Drawn as
    G / M ~ Gamma(shape 1 / (F - 1), scale F - 1), the sum over n electrons is
    Gamma(n / (F - 1), F - 1): mean n, variance n (F - 1) (total variance of a Poisson n of
    mean mu: F mu, the excess-noise shot noise). F = 1 returns n unchanged (no excess noise).
    """
    n = np.asarray(primary)
    if np.any(n < 0):
        raise ValueError("primary photoelectrons must be >= 0")
    f = float(excess_noise_factor)
    if not np.isfinite(f) or f < 1:
        raise ValueError(f"excess_noise_factor must be >= 1, got {excess_noise_factor!r}")
    if f == 1.0:
        return n.astype(float)
    return rng.gamma(n / (f - 1.0), f - 1.0)


def dead_time_counts(rng: np.random.Generator, counts, dt_s: float, dead_time_s: float):
    """Counts per bin a non-paralyzable detector of dead time ``dead_time_s`` registers from the
    arrivals ``counts`` (integer (batch, n_bins), bins of ``dt_s``).

    Arrivals are placed uniformly at random within their bin (the photon rate is taken constant
    over a bin) and taken in time order; an arrival registers when the detector is live and
    makes it dead for ``dead_time_s`` (Knoll 2010, "Radiation Detection and Measurement",
    Sec. 4.VII: a rate r reads r / (1 + r tau_d)). Vectorised over shots; the loop runs over
    the arrival rank (the largest count of a shot). ``dead_time_s`` = 0 returns ``counts``.
    A bin's arrivals are capped at :data:`DEAD_TIME_ARRIVAL_CAP` per dead time.
    """
    c = np.asarray(counts)
    if c.ndim != 2 or np.any(c < 0) or not np.all(np.isfinite(c)):
        raise ValueError("counts must be a (batch, n_bins) array of counts >= 0")
    positive("dt_s", dt_s)
    if dead_time_s < 0:
        raise ValueError(f"dead_time_s must be >= 0, got {dead_time_s}")
    if dead_time_s == 0.0 or c.sum() == 0:
        return c.copy()
    batch, n_bins = c.shape
    cap = DEAD_TIME_ARRIVAL_CAP * (int(np.ceil(dt_s / dead_time_s)) + 1)
    c = np.minimum(c, cap).astype(np.int64)
    per_shot = c.sum(axis=1)
    rows = np.repeat(np.arange(batch), per_shot)
    bins = np.repeat(np.tile(np.arange(n_bins), batch), c.ravel())
    times = np.full((batch, int(per_shot.max())), np.inf)
    rank = np.arange(rows.size) - np.repeat(np.cumsum(per_shot) - per_shot, per_shot)
    times[rows, rank] = (bins + rng.random(rows.size)) * dt_s
    times.sort(axis=1)
    live_from = np.full(batch, -np.inf)
    kept = np.zeros(times.shape, dtype=bool)
    for j in range(times.shape[1]):
        t = times[:, j]
        ok = np.isfinite(t) & (t >= live_from)
        kept[:, j] = ok
        live_from = np.where(ok, t + dead_time_s, live_from)
    r_idx, j_idx = np.nonzero(kept)
    b_idx = np.minimum((times[r_idx, j_idx] / dt_s).astype(np.int64), n_bins - 1)
    out = np.bincount(r_idx * n_bins + b_idx, minlength=batch * n_bins)
    return out.reshape(batch, n_bins)
