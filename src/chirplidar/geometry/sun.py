"""Sun elevation from a low-precision solar position (the Astronomical Almanac's algorithm).

Source: J. J. Michalsky (1988), "The Astronomical Almanac's algorithm for approximate solar
position (1950-2050)", Solar Energy 40(3), 227-235, which takes the Sun's position from the
Astronomical Almanac's low-precision formulae (section C, "Low precision formulas for the Sun";
stated precision 0.01 deg in right ascension and declination for 1950-2050). With
``n = JD(UTC) - 2451545.0`` days from J2000.0::

    L   = 280.460 + 0.9856474 n                    mean longitude [deg]
    g   = 357.528 + 0.9856003 n                    mean anomaly [deg]
    lam = L + 1.915 sin(g) + 0.020 sin(2 g)        ecliptic longitude [deg]
    eps = 23.439 - 0.0000004 n                     obliquity of the ecliptic [deg]
    ra  = atan2(cos(eps) sin(lam), cos(lam)),  dec = asin(sin(eps) sin(lam))

The hour angle uses Greenwich mean sidereal time ``GMST = 18.697374558 + 24.06570982441908 n``
hours (USNO, "Approximate sidereal time", the form Michalsky's ``6.697375 + 0.0657098242 n +
hour`` rewrites), with UT1 taken as UTC (|UT1 - UTC| < 0.9 s: < 0.004 deg). The elevation is the
angle of the Sun's geocentric direction above the plane normal to the geodetic vertical::

    sin(el) = sin(lat) sin(dec) + cos(lat) cos(dec) cos(GMST + lon - ra)

Accuracy: ~0.01 deg in elevation for 1950-2050 (checked against pyerfa's ephemeris and
IAU 2006/2000A Earth orientation to < 0.05 deg in ``tests/test_sun.py``). Not applied:
atmospheric refraction (it lifts the Sun by ~0.57 deg at the horizon, ~0.1 deg at 10 deg
elevation), the equation of the equinoxes (< 0.005 deg) and the Sun's parallax (0.0024 deg).
The elevation is that of the Sun's centre.
"""

from __future__ import annotations

import numpy as np

from chirplidar import _checks

__all__ = ["sun_elevation_deg", "sun_ra_dec_deg"]

_MJD_J2000 = 51544.5  # MJD of JD 2451545.0 (2000-01-01T12:00)


def sun_ra_dec_deg(mjd_utc) -> tuple[np.ndarray, np.ndarray]:
    """Apparent right ascension and declination of the Sun [deg] at MJD (UTC) ``mjd_utc``
    (array), from the Astronomical Almanac's low-precision formulae (module docstring)."""
    n = _checks.real_array("mjd_utc", mjd_utc) - _MJD_J2000
    L = np.mod(280.460 + 0.9856474 * n, 360.0)
    g = np.radians(np.mod(357.528 + 0.9856003 * n, 360.0))
    lam = np.radians(L + 1.915 * np.sin(g) + 0.020 * np.sin(2.0 * g))
    eps = np.radians(23.439 - 4.0e-7 * n)
    ra = np.arctan2(np.cos(eps) * np.sin(lam), np.cos(lam))
    dec = np.arcsin(np.sin(eps) * np.sin(lam))
    return np.degrees(ra), np.degrees(dec)


def sun_elevation_deg(lat_deg, lon_deg, mjd_utc) -> np.ndarray:
    """Elevation of the Sun's centre above the geodetic horizon [deg], without refraction.

    lat_deg, lon_deg : geodetic latitude and longitude [deg] (east positive); mjd_utc : Modified
    Julian Date (UTC). Arrays broadcast together. Accuracy ~0.01 deg (1950-2050), see the module
    docstring for the source and what is left out.
    """
    lat = _checks.real_array("lat_deg", lat_deg)
    lon = _checks.real_array("lon_deg", lon_deg)
    mjd = _checks.real_array("mjd_utc", mjd_utc)
    if np.any(np.abs(lat) > 90.0):
        raise ValueError("lat_deg must lie in [-90, 90] degrees")
    try:
        lat, lon, mjd = np.broadcast_arrays(lat, lon, mjd)
    except ValueError:
        raise ValueError(
            f"lat_deg, lon_deg and mjd_utc must have broadcastable shapes, got "
            f"{lat.shape}, {lon.shape} and {mjd.shape}"
        ) from None
    ra, dec = sun_ra_dec_deg(mjd)
    gmst_h = np.mod(18.697374558 + 24.06570982441908 * (mjd - _MJD_J2000), 24.0)
    ha = np.radians(15.0 * gmst_h + lon - ra)
    phi, d = np.radians(lat), np.radians(dec)
    s = np.sin(phi) * np.sin(d) + np.cos(phi) * np.cos(d) * np.cos(ha)
    return np.degrees(np.arcsin(np.clip(s, -1.0, 1.0)))[()]
