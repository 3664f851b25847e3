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
