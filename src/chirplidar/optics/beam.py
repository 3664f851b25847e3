"""Gaussian transmit beam: radius and footprint at range (thesis Table 4.6: atm.Wo, atm.div).

Default model "gaussian": an embedded-Gaussian (M^2) beam with its waist at the exit aperture,

    W(R) = sqrt(W0^2 + (theta R)^2),

W0 the 1/e^2 intensity radius at the aperture (atm.Wo) and theta the far-field 1/e^2 half-angle
divergence (atm.div). For a diffraction-limited beam theta = lambda / (pi W0) and this is the exact
Gaussian-beam law W0 sqrt(1 + (R / z_R)^2). Model "linear" is W0 + theta R (the bench channel of
thesis TX_model.m as coded in ``chirplidar.channel.lab``); the two agree to within W0 and differ
by less than W0^2 / (2 theta R) in the far field.
"""

from __future__ import annotations

import numpy as np

from ._checks import non_negative_array, positive_array

_MODELS = ("gaussian", "linear")


def beam_radius_m(w0_m, divergence_half_angle_rad, range_m, *, model: str = "gaussian"):
    """1/e^2 intensity radius (m) of the transmit beam at range R (m). Broadcasts; float or array.

    w0_m : radius at the exit aperture (> 0); divergence_half_angle_rad : far-field half-angle
    (>= 0); range_m : >= 0; model : "gaussian" sqrt(W0^2 + (theta R)^2) or "linear" W0 + theta R.
    """
    w0 = positive_array("w0_m", w0_m)
    th = non_negative_array("divergence_half_angle_rad", divergence_half_angle_rad)
    r = non_negative_array("range_m", range_m)
    if model == "gaussian":
        w = np.hypot(w0, th * r)
    elif model == "linear":
        w = w0 + th * r
    else:
        raise ValueError(f"model must be one of {_MODELS}, got {model!r}")
    return float(w) if np.ndim(w) == 0 else w


def footprint_diameter_m(w0_m, divergence_half_angle_rad, range_m, *, model: str = "gaussian"):
    """1/e^2 intensity diameter (m) of the beam footprint at range R: 2 W(R) (see beam_radius_m)."""
    return 2.0 * beam_radius_m(w0_m, divergence_half_angle_rad, range_m, model=model)


def diffraction_divergence_rad(w0_m, wavelength_m):
    """Far-field 1/e^2 half-angle of a diffraction-limited Gaussian beam: lambda / (pi W0) (rad)."""
    w0 = positive_array("w0_m", w0_m)
    lam = positive_array("wavelength_m", wavelength_m)
    out = lam / (np.pi * w0)
    return float(out) if out.ndim == 0 else out


def rayleigh_range_m(w0_m, wavelength_m):
    """z_R = pi W0^2 / lambda (m) of a diffraction-limited Gaussian beam with waist radius W0."""
    w0 = positive_array("w0_m", w0_m)
    lam = positive_array("wavelength_m", wavelength_m)
    out = np.pi * w0 * w0 / lam
    return float(out) if out.ndim == 0 else out


def beam_fraction_in_disc(beam_radius, disc_radius):
    """Fraction of a centred Gaussian beam's power inside a disc: 1 - exp(-2 a^2 / W^2).

    Both radii in the same units (m); W the 1/e^2 intensity radius. Broadcasts.
    """
    w = positive_array("beam_radius", beam_radius)
    a = non_negative_array("disc_radius", disc_radius)
    out = -np.expm1(-2.0 * a * a / (w * w))
    return float(out) if out.ndim == 0 else out
