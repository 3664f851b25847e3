"""Sun elevation (Astronomical Almanac low-precision algorithm) against independent references:
pyerfa's Earth ephemeris (epv00) with the IAU 2006/2000A celestial-to-terrestrial rotation, and
closed forms at the equinox and the solstices."""

from __future__ import annotations

import numpy as np
import pytest

from chirplidar.geometry import earth_orientation as eo
from chirplidar.geometry.sun import sun_elevation_deg


def _erfa_elevation_deg(lat_deg, lon_deg, utc_iso):
    """Reference (pyerfa): the Sun's geocentric direction from erfa.epv00 (the Earth's
    heliocentric and barycentric position and velocity, ICRS axes; TDB ~ TT), annual aberration
    with erfa.ab, rotated to ITRS with erfa.c2t06a (IAU 2006/2000A, UT1 = UTC, no polar
    motion: < 0.005 deg), elevation against the geodetic vertical. No refraction, no parallax."""
    import erfa

    t = eo.parse_utc(utc_iso)
    u1, u2 = erfa.dtf2d("UTC", t.year, t.month, t.day, t.hour, t.minute,
                        t.second + t.microsecond * 1e-6)
    tt1, tt2 = erfa.taitt(*erfa.utctai(u1, u2))
    pvh, pvb = erfa.epv00(tt1, tt2)
    sun = -np.asarray(pvh["p"])                      # Earth -> Sun [au]
    dist = np.linalg.norm(sun)
    v = np.asarray(pvb["v"]) * erfa.DAU / erfa.DAYSEC / erfa.CMPS   # Earth velocity / c
    p = erfa.ab(sun / dist, v, dist, np.sqrt(1.0 - v @ v))
    u = erfa.c2t06a(tt1, tt2, u1, u2, 0.0, 0.0) @ p
    phi, lam = np.radians(lat_deg), np.radians(lon_deg)
    up = np.array([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])
    return float(np.degrees(np.arcsin(u @ up)))


CASES = [
    # (lat, lon, UTC): polar night and polar day at 75 S (Dome C / Kohnen latitudes), Greenland,
    # the equator, mid-latitudes, a low Sun, and times in 1999 and 2012
    (-75.0, 123.35, "2026-06-21T00:00:00Z"),
    (-75.0, 123.35, "2026-06-21T04:30:00Z"),
    (-75.0, 0.07, "2026-12-21T12:00:00Z"),
    (-75.0, 0.07, "2026-12-22T00:00:00Z"),
    (-67.75, 62.9, "2026-11-01T00:00:00Z"),
    (72.58, -38.46, "2026-07-15T15:00:00Z"),
    (69.2, -49.8, "2027-01-10T15:30:00Z"),
    (0.0, 0.0, "2026-09-23T12:00:00Z"),
    (45.0, -100.0, "2026-03-01T18:20:00Z"),
    (-33.9, 151.2, "2026-02-14T20:05:00Z"),
    (60.0, 25.0, "1999-08-11T11:00:00Z"),
    (-20.0, -70.0, "2012-05-05T23:59:00Z"),
]


def test_sun_elevation_matches_pyerfa_within_0p05_deg():
    ours = np.array([sun_elevation_deg(lat, lon, eo.mjd_utc(t)) for lat, lon, t in CASES])
    ref = np.array([_erfa_elevation_deg(lat, lon, t) for lat, lon, t in CASES])
    assert np.max(np.abs(ours - ref)) < 0.05
    # Polar night (Sun below the horizon all day) and polar day (above all night) at 75 S.
    assert ours[0] < 0 and ours[1] < 0 and ours[2] > 0 and ours[3] > 0


def test_sun_elevation_vectorised_like_scalar():
    lat = np.array([c[0] for c in CASES])
    lon = np.array([c[1] for c in CASES])
    mjd = np.array([eo.mjd_utc(c[2]) for c in CASES])
    scalar = [sun_elevation_deg(a, b, m) for a, b, m in zip(lat, lon, mjd)]
    assert sun_elevation_deg(lat, lon, mjd) == pytest.approx(scalar, abs=1e-12)


def test_equinox_sun_culminates_at_the_zenith_on_the_equator():
    # Closed form: at the March 2025 equinox (2025-03-20T09:01Z, USNO "Earth's Seasons") the
    # declination is 0, so on the equator the Sun culminates at 90 deg (local apparent noon:
    # the highest elevation along the equator).
    lon = np.linspace(-180.0, 180.0, 36001)
    el = sun_elevation_deg(0.0, lon, eo.mjd_utc("2025-03-20T09:01:00Z"))
    assert np.max(el) == pytest.approx(90.0, abs=0.05)
    # ... where the apparent solar time is 12 h: UTC + lon / 15 + E = 12 h with the equation of
    # time E = -7.4 min (USNO), lon = 15 * (12 - 9.017 + 0.123) = 46.6 E
    assert lon[np.argmax(el)] == pytest.approx(46.6, abs=0.3)


@pytest.mark.parametrize("lat, utc", [(90.0, "2025-06-21T02:42:00Z"),
                                      (-90.0, "2025-12-21T15:03:00Z"),
                                      (-90.0, "2025-12-21T03:03:00Z")])
def test_solstice_elevation_at_the_pole_is_the_obliquity(lat, utc):
    # Closed form: at a pole the elevation is +-declination at every hour ("midnight" included),
    # and at a solstice |declination| is the obliquity, 23.436 deg in 2025 (IAU 2006:
    # 84381.406" - 46.837" T). Solstice times: USNO "Earth's Seasons".
    el = sun_elevation_deg(lat, 0.0, eo.mjd_utc(utc))
    assert el == pytest.approx(23.44, abs=0.05)
    # Six hours from the solstice the declination has moved by < 0.001 deg.
    assert sun_elevation_deg(lat, 180.0, eo.mjd_utc(utc) + 0.25) == pytest.approx(el, abs=0.01)


def test_bad_arguments_name_the_argument():
    with pytest.raises(ValueError, match="lat_deg"):
        sun_elevation_deg(91.0, 0.0, 60000.0)
    with pytest.raises(ValueError, match="mjd_utc"):
        sun_elevation_deg(0.0, 0.0, float("nan"))
