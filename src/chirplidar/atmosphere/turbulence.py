"""Optical turbulence strength: Cn^2 profiles, Fried parameter, coherence radius, Rytov variance.

All kernels are in SI units (metres, radians, Cn^2 in m^-2/3). Sources:

* A&P = L. C. Andrews and R. L. Phillips, *Laser Beam Propagation through Random Media*, 2nd ed.
  (SPIE Press, 2005). Section numbers below refer to that edition; the formulas are the standard
  ones quoted there (equation numbers are deliberately not given).
* Fried (1966), J. Opt. Soc. Am. 56, 1372: r0 = [0.423 k^2 int Cn^2 ds]^(-3/5) for a plane wave.
* Hufnagel-Valley model (A&P Ch. 12, "HV-5/7" with A = 1.7e-14 m^-2/3 and v = 21 m/s, named for
  r0 ~ 5 cm and isoplanatic angle ~ 7 urad at 0.5 um, zenith).

Path geometry (``*_profile`` functions): a straight ray between a lower and an upper altitude over a
spherical Earth (radius ``earth_radius_m``; ``numpy.inf`` gives the flat-Earth sec(zenith) path).
The zenith angle is the one seen from the *lower* end. ``s`` is the distance along the ray from
the source (where the wave starts) and ``L`` the path length; the receiver is at s = L.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np
from scipy.integrate import quad

from ._checks import (
    cn2_array,
    non_negative,
    path_length_array,
    real_scalar,
    scalar_or_array,
    wave_kind,
    wavenumber,
)

#: HV-5/7 ground-layer coefficient A (m^-2/3) and rms upper-wind speed (m/s), A&P Ch. 12.
HV57_GROUND_CN2 = 1.7e-14
HV57_RMS_WIND_MPS = 21.0
#: Mean Earth radius (m) for slant-path geometry.
EARTH_RADIUS_M = 6_371_000.0

#: Plane-wave Fried coefficient 0.423 (Fried 1966; A&P Ch. 6): r0^(-5/3) = 0.423 k^2 int Cn^2 ds.
FRIED_COEFF = 0.423
#: Spherical-wave path weight for constant Cn^2: int_0^1 u^(5/3) du = 3/8.
SPHERICAL_WEIGHT = 3.0 / 8.0
#: r0 = 2.1 rho0 (A&P Ch. 6: rho0 is the 1/e point of the wave-structure-function MCF).
R0_OVER_RHO0 = 2.1

#: Height h_m (m) -> Cn^2 (m^-2/3): a float, or a 0-d array, for a scalar height.
Cn2Profile = Callable[[float], float | np.ndarray]


# --- profiles -------------------------------------------------------------------------------------


def cn2_hufnagel_valley(
    h_m, ground_cn2: float = HV57_GROUND_CN2, rms_wind_mps: float = HV57_RMS_WIND_MPS
):
    """Hufnagel-Valley Cn^2 profile (A&P Ch. 12):

        Cn2(h) = 0.00594 (v/27)^2 (1e-5 h)^10 exp(-h/1000) + 2.7e-16 exp(-h/1500) + A exp(-h/100)

    Parameters
    ----------
    h_m : float or array, altitude above ground in metres (>= 0).
    ground_cn2 : A, the ground-layer coefficient in m^-2/3 (HV-5/7: 1.7e-14). Note that
        Cn2(0) = A + 2.7e-16.
    rms_wind_mps : v, rms upper (5-20 km) wind speed in m/s (HV-5/7: 21).

    Returns
    -------
    Cn^2 in m^-2/3, float64 of the shape of ``h_m`` (float for scalar input).
    """
    a = non_negative("ground_cn2", ground_cn2)
    v = non_negative("rms_wind_mps", rms_wind_mps)
    h = np.asarray(h_m, dtype=float)
    if not np.all(np.isfinite(h)) or np.any(h < 0.0):
        raise ValueError("h_m must be finite altitudes >= 0 m")
    out = (
        0.00594 * (v / 27.0) ** 2 * (1e-5 * h) ** 10 * np.exp(-h / 1000.0)
        + 2.7e-16 * np.exp(-h / 1500.0)
        + a * np.exp(-h / 100.0)
    )
    return float(out) if out.ndim == 0 else out


def hufnagel_valley_profile(
    ground_cn2: float = HV57_GROUND_CN2, rms_wind_mps: float = HV57_RMS_WIND_MPS
) -> Cn2Profile:
    """The HV profile as a callable h_m -> Cn^2 (m^-2/3) for the ``*_profile`` path integrals."""
    a = non_negative("ground_cn2", ground_cn2)
    v = non_negative("rms_wind_mps", rms_wind_mps)
    return lambda h: cn2_hufnagel_valley(h, a, v)


def constant_profile(cn2: float) -> Cn2Profile:
    """A height-independent Cn^2 (m^-2/3) as a callable (horizontal or short paths)."""
    c = non_negative("cn2", cn2)
    return lambda h: c + 0.0 * np.asarray(h, dtype=float)


# --- constant-Cn^2 closed forms -------------------------------------------------------------------


def fried_parameter(cn2, wavelength_m: float, path_length_m, wave: str = "plane"):
    """Fried parameter r0 (m) of a path with constant Cn^2 (Fried 1966; A&P Ch. 6).

        plane:      r0 = (0.423 k^2 Cn2 L)^(-3/5)
        spherical:  r0 = (0.423 k^2 Cn2 L 3/8)^(-3/5)    [weight (s/L)^(5/3) averaged over the path]

    so r0_spherical / r0_plane = (3/8)^(-3/5) = 1.80.

    Parameters
    ----------
    cn2 : m^-2/3, > 0 (float or array). wavelength_m : m. path_length_m : m, > 0 (float or array).
    wave : "plane" (distant source) or "spherical" (point source, e.g. a lit spot on the ground).

    Returns
    -------
    r0 in metres: float for scalar inputs, else float64 array of the broadcast shape.
    """
    k = wavenumber(wavelength_m)
    weight = 1.0 if wave_kind(wave) == "plane" else SPHERICAL_WEIGHT
    c, length = cn2_array(cn2), path_length_array(path_length_m)
    return scalar_or_array((FRIED_COEFF * k * k * c * length * weight) ** (-3.0 / 5.0))


def coherence_radius(r0_m):
    """Spatial coherence radius rho0 = r0 / 2.1 (m) (A&P Ch. 6). Float or array like ``r0_m``."""
    return scalar_or_array(np.asarray(r0_m, dtype=float) / R0_OVER_RHO0)


def rytov_variance(cn2, wavelength_m: float, path_length_m, wave: str = "plane"):
    """Rytov variance (dimensionless) of a path with constant Cn^2 (A&P Chs. 5-6).

        plane:      sigma_R^2 = 1.23 Cn2 k^(7/6) L^(11/6)
        spherical:  beta_0^2  = 0.5  Cn2 k^(7/6) L^(11/6)

    Weak fluctuations when the value is below 1. Float for scalar inputs, else array.
    """
    k = wavenumber(wavelength_m)
    coeff = 1.23 if wave_kind(wave) == "plane" else 0.5
    c, length = cn2_array(cn2), path_length_array(path_length_m)
    return scalar_or_array(coeff * c * k ** (7.0 / 6.0) * length ** (11.0 / 6.0))


# --- slant paths through a profile ----------------------------------------------------------------

# Altitudes (m) where profiles change character; the quadrature is split there.
_BREAKS_M = (30.0, 100.0, 300.0, 1e3, 1.5e3, 3e3, 6e3, 1e4, 1.5e4, 2e4, 3e4, 5e4, 1e5)


class _SlantPath:
    """Straight ray from altitude h_lo to h_hi with zenith angle z at h_lo over a sphere."""

    def __init__(self, h_lo: float, h_hi: float, zenith: float, earth_radius: float):
        self.h_lo, self.h_hi, self.zenith, self.re = h_lo, h_hi, zenith, earth_radius
        self.length = float(self.s_of_h(h_hi))

    def s_of_h(self, h):
        """Distance along the ray from the lower end to altitude h."""
        if np.isinf(self.re):
            return (h - self.h_lo) / np.cos(self.zenith)
        r0 = self.re + self.h_lo
        r = self.re + h
        c = np.cos(self.zenith)
        # s = sqrt(r^2 - r0^2 sin^2 z) - r0 cos z, written without cancellation for small s.
        return (r * r - r0 * r0) / (np.sqrt(r * r - (r0 * np.sin(self.zenith)) ** 2) + r0 * c)

    def ds_dh(self, h):
        if np.isinf(self.re):
            return 1.0 / np.cos(self.zenith)
        r0 = self.re + self.h_lo
        r = self.re + h
        return r / np.sqrt(r * r - (r0 * np.sin(self.zenith)) ** 2)


def slant_path_length(
    lower_altitude_m: float,
    upper_altitude_m: float,
    zenith_angle_rad: float,
    *,
    earth_radius_m: float = EARTH_RADIUS_M,
) -> float:
    """Length (m) of the straight ray between two altitudes, zenith angle seen from the lower end.

    Spherical Earth of radius ``earth_radius_m`` (numpy.inf: flat Earth, L = dh / cos z).
    """
    lo = non_negative("lower_altitude_m", lower_altitude_m)
    hi = non_negative("upper_altitude_m", upper_altitude_m)
    if hi <= lo:
        raise ValueError(f"upper_altitude_m ({hi}) must exceed lower_altitude_m ({lo})")
    return _SlantPath(lo, hi, _zenith(zenith_angle_rad), _earth(earth_radius_m)).length


def _zenith(zenith_angle_rad) -> float:
    z = real_scalar("zenith_angle_rad", zenith_angle_rad)
    if not 0.0 <= z < 0.5 * np.pi:
        raise ValueError(f"zenith_angle_rad must be in [0, pi/2) rad (the ray must climb), got {z}")
    return z


def _earth(earth_radius_m) -> float:
    re = real_scalar("earth_radius_m", earth_radius_m, allow_inf=True)
    if not re > 0.0:
        raise ValueError(f"earth_radius_m must be > 0 (numpy.inf for a flat Earth), got {re}")
    return re


def _path_integral(
    cn2_profile, source_altitude_m, receiver_altitude_m, zenith_angle_rad, earth_radius_m, weight
):
    """int_0^L Cn2(h(s)) weight(s_src, L) ds, s_src = distance from the source (units m^1/3 x w).

    The integral runs over altitude (ds = (ds/dh) dh) with the quadrature split at the profile
    breakpoints ``_BREAKS_M``; each piece is scipy.integrate.quad (epsrel 1e-9).
    """
    if not callable(cn2_profile):
        raise ValueError(
            "cn2_profile must be a callable altitude_m -> Cn^2 (m^-2/3), e.g. "
            "hufnagel_valley_profile()"
        )
    hs = non_negative("source_altitude_m", source_altitude_m)
    hr = non_negative("receiver_altitude_m", receiver_altitude_m)
    if hs == hr:
        raise ValueError(
            "source_altitude_m and receiver_altitude_m must differ (use the "
            "constant-Cn^2 functions for horizontal paths)"
        )
    lo, hi = min(hs, hr), max(hs, hr)
    path = _SlantPath(lo, hi, _zenith(zenith_angle_rad), _earth(earth_radius_m))
    length = path.length
    source_low = hs < hr

    def integrand(h):
        s = path.s_of_h(h)
        s_src = s if source_low else length - s
        c = float(cn2_profile(h))
        if not (np.isfinite(c) and c >= 0.0):
            raise ValueError(f"cn2_profile returned {c!r} at h = {h} m (must be finite, >= 0)")
        return c * weight(s_src, length) * path.ds_dh(h)

    edges = [lo] + [b for b in _BREAKS_M if lo < b < hi] + [hi]
    total = 0.0
    for a, b in itertools.pairwise(edges):
        val, _ = quad(integrand, a, b, epsabs=0.0, epsrel=1e-9, limit=200)
        total += val
    return total, length


def cn2_path_integral(
    cn2_profile: Cn2Profile,
    *,
    source_altitude_m: float,
    receiver_altitude_m: float,
    zenith_angle_rad: float = 0.0,
    earth_radius_m: float = EARTH_RADIUS_M,
) -> float:
    """Integrated turbulence int_0^L Cn^2(h(s)) ds along the slant path, in m^(1/3)."""
    total, _ = _path_integral(
        cn2_profile,
        source_altitude_m,
        receiver_altitude_m,
        zenith_angle_rad,
        earth_radius_m,
        lambda s, length: 1.0,
    )
    return total


def fried_parameter_profile(
    cn2_profile: Cn2Profile,
    wavelength_m: float,
    *,
    source_altitude_m: float,
    receiver_altitude_m: float,
    zenith_angle_rad: float = 0.0,
    wave: str = "plane",
    earth_radius_m: float = EARTH_RADIUS_M,
) -> float:
    """Fried parameter r0 (m) at the receiver of a slant path through a Cn^2 profile.

        r0 = [0.423 k^2 int_0^L Cn2(s) w(s) ds]^(-3/5),
        w = 1 (plane wave),  w = (s/L)^(5/3) = (1 - z/L)^(5/3) (spherical wave),

    with s the distance from the source and z = L - s the distance from the receiver (A&P Ch. 12;
    turbulence next to a point source does not decorrelate the wave). For constant Cn^2 these
    reduce to ``fried_parameter`` (the spherical weight averages to 3/8).

    Parameters
    ----------
    cn2_profile : callable altitude_m -> Cn^2 in m^-2/3 (``hufnagel_valley_profile()``,
        ``constant_profile(c)`` or your own scalar function).
    wavelength_m : m. source_altitude_m, receiver_altitude_m : m above ground (>= 0, different).
    zenith_angle_rad : zenith angle at the lower end, [0, pi/2). Ground to aircraft: lower end is
        the ground; ground to a 500 km satellite: likewise.
    wave : "plane" or "spherical". earth_radius_m : numpy.inf for a flat Earth.

    Returns
    -------
    r0 in metres (float); numpy.inf if the path carries no turbulence.
    """
    k = wavenumber(wavelength_m)
    spherical = wave_kind(wave) == "spherical"
    weight = (
        (lambda s, length: (s / length) ** (5.0 / 3.0)) if spherical else (lambda s, length: 1.0)
    )
    total, _ = _path_integral(
        cn2_profile,
        source_altitude_m,
        receiver_altitude_m,
        zenith_angle_rad,
        earth_radius_m,
        weight,
    )
    if total <= 0.0:
        return float("inf")
    return float((FRIED_COEFF * k * k * total) ** (-3.0 / 5.0))


def rytov_variance_profile(
    cn2_profile: Cn2Profile,
    wavelength_m: float,
    *,
    source_altitude_m: float,
    receiver_altitude_m: float,
    zenith_angle_rad: float = 0.0,
    wave: str = "plane",
    earth_radius_m: float = EARTH_RADIUS_M,
) -> float:
    """Rytov variance (dimensionless) of a slant path through a Cn^2 profile (A&P Chs. 5, 12).

        plane:      sigma_R^2 = 2.25 k^(7/6) int_0^L Cn2(s) (L - s)^(5/6) ds
        spherical:  beta_0^2  = 2.25 k^(7/6) int_0^L Cn2(s) (s/L)^(5/6) (L - s)^(5/6) ds

    s measured from the source. Constant Cn^2 gives 1.23 (plane) and 2.25 B(11/6, 11/6) = 0.496
    (~0.5, spherical) times Cn2 k^(7/6) L^(11/6), i.e. ``rytov_variance``. Arguments as in
    ``fried_parameter_profile``.
    """
    k = wavenumber(wavelength_m)
    spherical = wave_kind(wave) == "spherical"
    if spherical:

        def weight(s, length):
            return (s / length) ** (5.0 / 6.0) * max(length - s, 0.0) ** (5.0 / 6.0)
    else:

        def weight(s, length):
            return max(length - s, 0.0) ** (5.0 / 6.0)

    total, _ = _path_integral(
        cn2_profile,
        source_altitude_m,
        receiver_altitude_m,
        zenith_angle_rad,
        earth_radius_m,
        weight,
    )
    return float(2.25 * k ** (7.0 / 6.0) * total)


def isoplanatic_angle(
    cn2_profile: Cn2Profile,
    wavelength_m: float,
    *,
    receiver_altitude_m: float,
    source_altitude_m: float,
    zenith_angle_rad: float = 0.0,
    earth_radius_m: float = EARTH_RADIUS_M,
) -> float:
    """Isoplanatic angle theta0 (rad) seen from the receiver, plane-wave form (Fried 1982; A&P Ch. 12):

        theta0 = [2.91 k^2 int_0^L Cn2(s) (L - s)^(5/3) ds]^(-3/5),

    L - s being the distance of the turbulence from the receiver. HV-5/7 at 0.5 um, ground to space
    at zenith: about 7 urad (the "7" of HV-5/7).
    """
    k = wavenumber(wavelength_m)
    total, _ = _path_integral(
        cn2_profile,
        source_altitude_m,
        receiver_altitude_m,
        zenith_angle_rad,
        earth_radius_m,
        lambda s, length: max(length - s, 0.0) ** (5.0 / 3.0),
    )
    if total <= 0.0:
        return float("inf")
    return float((2.91 * k * k * total) ** (-3.0 / 5.0))
