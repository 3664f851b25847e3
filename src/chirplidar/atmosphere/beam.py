"""Gaussian beam through weak turbulence on a horizontal (constant Cn^2) path.

Andrews & Phillips, *Laser Beam Propagation through Random Media*, 2nd ed. (SPIE 2005), Ch. 4
(beam parameters) and Ch. 6 (long-term spread, beam wander); infinite outer scale, zero inner scale.

Beam parameters at the transmitter (W0 = 1/e^2-intensity radius, F0 = phase-front radius of
curvature, F0 = inf collimated, F0 = L focused on the target) and at the receiver:

    Theta0 = 1 - L / F0,  Lambda0 = 2 L / (k W0^2),
    Theta  = Theta0 / (Theta0^2 + Lambda0^2),  Lambda = Lambda0 / (Theta0^2 + Lambda0^2),
    W = W0 sqrt(Theta0^2 + Lambda0^2)                       (diffraction-limited radius at L).

Long-term radius (weak fluctuations, sigma_R^2 < 1):  W_LT^2 = W^2 (1 + 1.33 sigma_R^2 Lambda^(5/6)),
sigma_R^2 = 1.23 Cn2 k^(7/6) L^(11/6) the plane-wave Rytov variance.

Beam wander (rms displacement of the short-term centroid, geometrical-optics approximation):
<r_c^2> = 2.42 Cn2 L^3 W0^(-1/3) 2F1(1/3, 1; 4; 1 - |Theta0|), which is 2.42 Cn2 L^3 W0^(-1/3) for a
collimated beam (Theta0 = 1) and 9/8 of that for a beam focused at L (Theta0 = 0).
"""

from __future__ import annotations

import numpy as np
from scipy import special

from ._checks import (
    cn2_array,
    path_length_array,
    positive,
    real_scalar,
    scalar_or_array,
    wavenumber,
)
from .turbulence import rytov_variance


def _focus(focus_m) -> float:
    f = real_scalar("focus_m", focus_m, allow_inf=True)
    if f == 0.0:
        raise ValueError("focus_m must be non-zero (numpy.inf for a collimated beam)")
    return f


def gaussian_beam_parameters(
    w0_m: float, wavelength_m: float, path_length_m, *, focus_m: float = np.inf
) -> dict:
    """Andrews & Phillips Gaussian-beam parameters (dimensionless) and the free-space radius W (m).

    Returns a dict with keys ``theta0``, ``lambda0``, ``theta``, ``lambda_``, ``w_m`` (floats for
    scalar ``path_length_m``, else arrays of its shape).
    """
    w0 = positive("w0_m", w0_m)
    k = wavenumber(wavelength_m)
    length = path_length_array(path_length_m)
    f0 = _focus(focus_m)
    theta0 = 1.0 - length / f0
    lambda0 = 2.0 * length / (k * w0 * w0)
    q = theta0**2 + lambda0**2
    return {
        "theta0": scalar_or_array(theta0),
        "lambda0": scalar_or_array(lambda0),
        "theta": scalar_or_array(theta0 / q),
        "lambda_": scalar_or_array(lambda0 / q),
        "w_m": scalar_or_array(w0 * np.sqrt(q)),
    }


def long_term_beam_radius(
    w0_m: float, wavelength_m: float, path_length_m, cn2, *, focus_m: float = np.inf
):
    """Long-term (time-averaged) 1/e^2 beam radius W_LT in m, weak fluctuations (A&P Ch. 6).

    W_LT = W sqrt(1 + 1.33 sigma_R^2 Lambda^(5/6)). Raises ValueError if sigma_R^2 >= 1 (outside
    the weak-fluctuation theory). Float for scalar inputs, else array (broadcast).
    """
    p = gaussian_beam_parameters(w0_m, wavelength_m, path_length_m, focus_m=focus_m)
    sigma2 = np.asarray(rytov_variance(cn2, wavelength_m, path_length_m, "plane"))
    if np.any(sigma2 >= 1.0):
        raise ValueError(
            f"the plane-wave Rytov variance reaches {sigma2.max():.3g} >= 1: the "
            f"weak-fluctuation long-term spread does not apply (reduce cn2 or "
            f"path_length_m)"
        )
    w = np.asarray(p["w_m"])
    lam = np.asarray(p["lambda_"])
    return scalar_or_array(w * np.sqrt(1.0 + 1.33 * sigma2 * lam ** (5.0 / 6.0)))


def beam_wander_variance(
    w0_m: float, wavelength_m: float, path_length_m, cn2, *, focus_m: float = np.inf
):
    """Beam-wander variance <r_c^2> in m^2 (A&P Ch. 6, infinite outer scale).

    <r_c^2> = 2.42 Cn2 L^3 W0^(-1/3) 2F1(1/3, 1; 4; 1 - |Theta0|). ``wavelength_m`` enters only
    through Theta0's independence of it (kept for a uniform signature and validated).
    Float for scalar inputs, else array (broadcast).
    """
    w0 = positive("w0_m", w0_m)
    wavenumber(wavelength_m)
    length = path_length_array(path_length_m)
    c = cn2_array(cn2)
    theta0 = 1.0 - length / _focus(focus_m)
    hyp = special.hyp2f1(1.0 / 3.0, 1.0, 4.0, 1.0 - np.abs(theta0))
    return scalar_or_array(2.42 * c * length**3 * w0 ** (-1.0 / 3.0) * hyp)
