"""Earth orientation: UTC times, UT1 - UTC, polar motion and the TEME -> ITRS rotation.

The IERS Bulletin A values (UT1 - UTC and the pole coordinates x_p, y_p, measured and a year of
predictions) come from the ``finals2000A.all`` table that the ``astropy-iers-data`` package ships;
nothing is downloaded at run time. Between the daily values they are interpolated linearly (a
leap second's jump of UT1 - UTC is kept as a step). A time outside the table gets an
:class:`EarthOrientationWarning` and the nearest end value.

TEME -> ITRS (Vallado, Crawford, Hujsak & Kelso 2006, "Revisiting Spacetrack Report #3",
AIAA 2006-6753, sec. on TEME; Vallado, Fundamentals of Astrodynamics, 4th ed., eqs. 3-47, 3-77)::

    r_PEF  = R3(GMST82(UT1)) r_TEME
    v_PEF  = R3(GMST82(UT1)) v_TEME - omega_E x r_PEF
    r_ITRS = W^T r_PEF,  W = R1(y_p) R2(x_p)   (polar motion, 1980 convention)

Neglecting UT1 - UTC moves a ground point by omega_E R_E cos(lat) |UT1 - UTC| (~0.4 km at the
equator for 0.9 s); neglecting polar motion by up to ~15 m.
"""

from __future__ import annotations

import datetime as _dt
import functools
import warnings
from pathlib import Path

import numpy as np

from chirplidar.units import OMEGA_EARTH_RAD_S

__all__ = [
    "EarthOrientationWarning",
    "MJD_UNIX_EPOCH",
    "gmst82_rad",
    "mjd_iso",
    "mjd_utc",
    "parse_utc",
    "polar_motion_rad",
    "table_span_mjd",
    "teme_to_itrs",
    "ut1_minus_utc_s",
    "utc_iso",
]

MJD_UNIX_EPOCH = 40587.0  # MJD of 1970-01-01T00:00:00 UTC
_ARCSEC_RAD = np.pi / (180.0 * 3600.0)


class EarthOrientationWarning(UserWarning):
    """A time lies outside the shipped IERS table: UT1 - UTC and the pole are extrapolated."""


def parse_utc(value, key: str = "time") -> _dt.datetime:
    """An aware UTC datetime from an ISO 8601 string (``Z`` or an offset) or a datetime;
    ValueError naming ``key`` otherwise (a naive time is refused: its zone is unknown)."""
    if isinstance(value, str):
        try:
            value = _dt.datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"{key}: not an ISO 8601 date-time: {value!r}") from None
    if not isinstance(value, _dt.datetime):
        raise ValueError(f"{key}: expected an ISO 8601 UTC date-time, got {value!r}")
    if value.tzinfo is None:
        raise ValueError(f"{key}: give the time zone (a Z for UTC): {value.isoformat()}")
    return value.astimezone(_dt.timezone.utc)


def utc_iso(value: _dt.datetime) -> str:
    """ISO 8601 UTC with a Z and whole milliseconds (e.g. ``2026-11-01T03:04:05.250Z``)."""
    v = value.astimezone(_dt.timezone.utc)
    return v.strftime("%Y-%m-%dT%H:%M:%S.") + f"{v.microsecond // 1000:03d}Z"


def mjd_iso(mjd: float) -> str:
    """:func:`utc_iso` of a Modified Julian Date (UTC); the inverse of :func:`mjd_utc`."""
    return utc_iso(
        _dt.datetime.fromtimestamp((float(mjd) - MJD_UNIX_EPOCH) * 86400.0, _dt.timezone.utc)
    )


def mjd_utc(value) -> float:
    """Modified Julian Date (UTC) of a datetime or ISO string."""
    t = parse_utc(value)
    return MJD_UNIX_EPOCH + t.timestamp() / 86400.0


@functools.lru_cache(maxsize=1)
def _table() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(mjd, ut1_utc_s, xp_arcsec, yp_arcsec) of Bulletin A, rows with all three values."""
    import astropy_iers_data

    path = Path(astropy_iers_data.IERS_A_FILE)
    mjd, dut, xp, yp = [], [], [], []
    with path.open("r", encoding="ascii") as f:
        for line in f:  # ~20 000 fixed-width rows (ReadMe.finals2000A), read once per process
            ut1 = line[58:68].strip()
            x, y = line[18:27].strip(), line[37:46].strip()
            if not (ut1 and x and y):
                continue
            mjd.append(float(line[7:15]))
            dut.append(float(ut1))
            xp.append(float(x))
            yp.append(float(y))
    if not mjd:
        raise RuntimeError(f"{path}: no IERS Bulletin A rows found")
    return np.array(mjd), np.array(dut), np.array(xp), np.array(yp)


def table_span_mjd() -> tuple[float, float]:
    """First and last MJD (UTC) of the shipped IERS table."""
    m = _table()[0]
    return float(m[0]), float(m[-1])


def _warn_outside(mjd: np.ndarray) -> None:
    lo, hi = table_span_mjd()
    if mjd.size and (np.min(mjd) < lo or np.max(mjd) > hi):

        def day(m):
            return mjd_iso(m)[:10]

        bad = float(np.min(mjd)) if np.min(mjd) < lo else float(np.max(mjd))
        warnings.warn(
            f"{day(bad)} lies outside the IERS Earth-orientation table shipped with "
            f"astropy-iers-data ({day(lo)} .. {day(hi)}): UT1 - UTC and polar motion "
            "are held at the table's end (update astropy-iers-data for newer values)",
            EarthOrientationWarning,
            stacklevel=3,
        )


def ut1_minus_utc_s(mjd) -> np.ndarray:
    """UT1 - UTC [s] at MJD (UTC) ``mjd`` (array); leap-second steps are kept."""
    m = np.asarray(mjd, dtype=float)
    _warn_outside(m)
    tm, dut, _, _ = _table()
    i = np.clip(np.searchsorted(tm, m, side="right") - 1, 0, tm.size - 2)
    f = np.clip((m - tm[i]) / (tm[i + 1] - tm[i]), 0.0, 1.0)
    step = np.abs(dut[i + 1] - dut[i]) > 0.5  # a leap second between the two days
    return np.where(step, dut[i], dut[i] + f * (dut[i + 1] - dut[i]))[()]


def polar_motion_rad(mjd) -> tuple[np.ndarray, np.ndarray]:
    """Pole coordinates (x_p, y_p) [rad] at MJD (UTC) ``mjd`` (array)."""
    m = np.asarray(mjd, dtype=float)
    _warn_outside(m)
    tm, _, xp, yp = _table()
    return (np.interp(m, tm, xp) * _ARCSEC_RAD)[()], (np.interp(m, tm, yp) * _ARCSEC_RAD)[()]


def gmst82_rad(jd_ut1) -> np.ndarray:
    """Greenwich mean sidereal time, IAU-82 (Vallado eq. 3-47; sgp4's ``gstime``) [rad]."""
    t = (np.asarray(jd_ut1, dtype=float) - 2451545.0) / 36525.0
    sec = -6.2e-6 * t**3 + 0.093104 * t**2 + (876600.0 * 3600.0 + 8640184.812866) * t + 67310.54841
    return np.mod(sec * (np.pi / 180.0) / 240.0, 2.0 * np.pi)[()]


def _r3(theta):
    c, s = np.cos(theta), np.sin(theta)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack(
        [np.stack([c, s, z], -1), np.stack([-s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def teme_to_itrs(r_teme_m, v_teme_mps, mjd_utc_values, *, polar_motion: bool = True):
    """ITRS (ECEF) positions (n, 3) [m] and velocities (n, 3) [m/s] of TEME states at the UTC
    times ``mjd_utc_values`` (n,), with UT1 - UTC and polar motion from the IERS table."""
    r = np.asarray(r_teme_m, float).reshape(-1, 3)
    v = np.asarray(v_teme_mps, float).reshape(-1, 3)
    m = np.asarray(mjd_utc_values, float).reshape(-1)
    jd_ut1 = m + 2400000.5 + ut1_minus_utc_s(m) / 86400.0
    rot = _r3(gmst82_rad(jd_ut1))
    r_pef = np.einsum("nij,nj->ni", rot, r)
    v_pef = np.einsum("nij,nj->ni", rot, v) - np.cross([0.0, 0.0, OMEGA_EARTH_RAD_S], r_pef)
    if not polar_motion:
        return r_pef, v_pef
    xp, yp = polar_motion_rad(m)
    cx, sx, cy, sy = np.cos(xp), np.sin(xp), np.cos(yp), np.sin(yp)
    z = np.zeros_like(cx)
    # W = R1(y_p) R2(x_p) takes ITRS to PEF (Vallado eq. 3-77, 1980 convention); ITRS = W^T PEF.
    w = np.stack(
        [
            np.stack([cx, z, -sx], -1),
            np.stack([sx * sy, cy, cx * sy], -1),
            np.stack([sx * cy, -sy, cx * cy], -1),
        ],
        -2,
    )
    return np.einsum("nji,nj->ni", w, r_pef), np.einsum("nji,nj->ni", w, v_pef)
