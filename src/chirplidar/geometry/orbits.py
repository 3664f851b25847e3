"""Satellite orbits: a Keplerian orbit with J2 secular drift (design studies) and SGP4 from a
two-line element set (flown missions); both give ECEF states (``frame = "ecef"``).

Time and Earth rotation (KeplerOrbit): ``t_s`` is seconds on the same scale as ``epoch_s``. The
ECI frame is an inertial frame whose z axis is the Earth's rotation axis; the ECI -> ECEF rotation
angle is the linear model ``theta(t) = gmst_at_epoch_rad + OMEGA_EARTH_RAD_S * (t - epoch_s)``
(no precession, nutation, polar motion or UT1-UTC; ECI = ECEF at epoch by default). This is
adequate for shot geometry over a scene, not for absolute astronomy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chirplidar import _checks
from chirplidar.doppler import earth_rotation_velocity_mps
from chirplidar.units import OMEGA_EARTH_RAD_S, WGS84_A_M

__all__ = [
    "J2_EARTH",
    "MU_EARTH_M3_S2",
    "R_EARTH_M",
    "TLE_MAX_AGE_DAYS",
    "KeplerOrbit",
    "TleOrbit",
]


#: Earth constants (Vallado, Fundamentals of Astrodynamics, 4th ed., Table D-1 / WGS-84); the
#: equatorial radius and rotation rate are the WGS-84 ones of chirplidar.units.
MU_EARTH_M3_S2 = 3.986004418e14
J2_EARTH = 1.08262668e-3
R_EARTH_M = WGS84_A_M


def _rot3(theta):
    """Rotation matrices R3(theta) (n, 3, 3): frame rotation about z, v' = R v."""
    c, s = np.cos(theta), np.sin(theta)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack(
        [np.stack([c, s, z], -1), np.stack([-s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def _eci_to_ecef(r, v, theta):
    """Rotate ECI states by the Earth rotation angle theta (n,) (Earth rotating at OMEGA)."""
    R = _rot3(theta)
    r_e = np.einsum("nij,nj->ni", R, r)
    v_e = np.einsum("nij,nj->ni", R, v) - earth_rotation_velocity_mps(r_e)
    return r_e, v_e


@dataclass(frozen=True)
class KeplerOrbit:
    """Keplerian orbit with J2 secular drift of RAAN and argument of perigee.

    Elements at ``epoch_s``: semi-major axis [m], eccentricity, inclination, RAAN, argument of
    perigee, mean anomaly [rad]. Secular rates (Vallado, Fundamentals of Astrodynamics, eqs. for
    the J2 secular effects, 9-41 and 9-42 in the 4th ed.), with ``n = sqrt(mu / a**3)``,
    ``p = a (1 - e**2)``::

        dRAAN/dt  = -3/2 n J2 (R_E / p)**2 cos(i)
        dargp/dt  =  3/4 n J2 (R_E / p)**2 (4 - 5 sin(i)**2)
        dM/dt     =  n + 3/4 n J2 (R_E / p)**2 sqrt(1 - e**2) (2 - 3 sin(i)**2)

    ``j2=False`` switches the drift off (pure two-body). Velocities are the exact time derivative
    of the modelled positions (including the drift terms). ECI -> ECEF uses the linear
    Earth-rotation model of the module docstring.

    What it is for: design studies (an orbit placed over a scene at any altitude and
    inclination, no element set needed). The secular rates leave out J2's short-period terms,
    drag and the higher harmonics: against SGP4 started from the same mean elements it drifts
    by ~2 km over a 10-minute pass (an orbit of 496 km, e ~ 0; measured in
    ``tests/test_orbit.py``), mostly along track. Flown missions and pass predictions use
    :class:`TleOrbit`.
    """

    semi_major_axis_m: float
    eccentricity: float
    inclination_rad: float
    raan_rad: float
    arg_perigee_rad: float
    mean_anomaly_rad: float
    epoch_s: float
    j2: bool = True
    gmst_at_epoch_rad: float = 0.0
    frame: str = field(default="ecef", init=False)

    def __post_init__(self):
        a = _checks.positive("semi_major_axis_m", self.semi_major_axis_m)
        e = _checks.real_scalar("eccentricity", self.eccentricity)
        if not 0.0 <= e < 1.0:
            raise ValueError(f"eccentricity must lie in [0, 1) (closed orbit), got {e}")
        if a * (1.0 - e) <= R_EARTH_M:
            raise ValueError(
                f"semi_major_axis_m and eccentricity put the perigee radius "
                f"{a * (1 - e):.0f} m inside the Earth (R_E = {R_EARTH_M} m)"
            )
        for name in (
            "inclination_rad",
            "raan_rad",
            "arg_perigee_rad",
            "mean_anomaly_rad",
            "epoch_s",
            "gmst_at_epoch_rad",
        ):
            object.__setattr__(self, name, _checks.real_scalar(name, getattr(self, name)))
        if not 0.0 <= self.inclination_rad <= np.pi:
            raise ValueError("inclination_rad must lie in [0, pi]")
        object.__setattr__(self, "semi_major_axis_m", a)
        object.__setattr__(self, "eccentricity", e)

    @property
    def mean_motion_rad_s(self) -> float:
        return float(np.sqrt(MU_EARTH_M3_S2 / self.semi_major_axis_m**3))

    @property
    def period_s(self) -> float:
        """Keplerian (anomalistic, two-body) period 2 pi sqrt(a^3 / mu) [s]."""
        return 2 * np.pi / self.mean_motion_rad_s

    @property
    def _k(self) -> float:
        if not self.j2:
            return 0.0
        p = self.semi_major_axis_m * (1 - self.eccentricity**2)
        return self.mean_motion_rad_s * J2_EARTH * (R_EARTH_M / p) ** 2

    @property
    def raan_rate_rad_s(self) -> float:
        return -1.5 * self._k * np.cos(self.inclination_rad)

    @property
    def arg_perigee_rate_rad_s(self) -> float:
        return 0.75 * self._k * (4 - 5 * np.sin(self.inclination_rad) ** 2)

    @property
    def mean_anomaly_rate_rad_s(self) -> float:
        """Secular rate of the mean anomaly: n plus its J2 term [rad/s]."""
        return self.mean_motion_rad_s + 0.75 * self._k * np.sqrt(1 - self.eccentricity**2) * (
            2 - 3 * np.sin(self.inclination_rad) ** 2
        )

    def states_eci(self, t_s):
        """ECI positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        t = _checks.time_array("t_s", t_s)
        dt = t - self.epoch_s
        a, e, n = self.semi_major_axis_m, self.eccentricity, self.mean_motion_rad_s
        M = self.mean_anomaly_rad + self.mean_anomaly_rate_rad_s * dt
        E = M + e * np.sin(M)
        for _ in range(50):  # Newton on Kepler's equation, all shots at once
            dE = (E - e * np.sin(E) - M) / (1 - e * np.cos(E))
            E = E - dE
            if np.all(np.abs(dE) < 1e-14):
                break
        cE, sE = np.cos(E), np.sin(E)
        q = np.sqrt(1 - e * e)
        r_norm = a * (1 - e * cE)
        x, y = a * (cE - e), a * q * sE
        vf = np.sqrt(MU_EARTH_M3_S2 * a) / r_norm * (self.mean_anomaly_rate_rad_s / n)
        wdot = self.arg_perigee_rate_rad_s
        vx, vy = -vf * sE - wdot * y, vf * q * cE + wdot * x
        raan = self.raan_rad + self.raan_rate_rad_s * dt
        argp = self.arg_perigee_rad + wdot * dt
        i = self.inclination_rad
        cO, sO, cw, sw, ci, si = (
            np.cos(raan),
            np.sin(raan),
            np.cos(argp),
            np.sin(argp),
            np.cos(i),
            np.sin(i),
        )
        P = np.stack([cO * cw - sO * sw * ci, sO * cw + cO * sw * ci, sw * si], axis=-1)
        Q = np.stack([-cO * sw - sO * cw * ci, -sO * sw + cO * cw * ci, cw * si], axis=-1)
        r = x[:, None] * P + y[:, None] * Q
        v = vx[:, None] * P + vy[:, None] * Q
        v = v + np.cross(np.array([0.0, 0.0, self.raan_rate_rad_s]), r)
        return r, v

    def earth_rotation_angle_rad(self, t_s) -> np.ndarray:
        return self.gmst_at_epoch_rad + OMEGA_EARTH_RAD_S * (
            _checks.time_array("t_s", t_s) - self.epoch_s
        )

    def states(self, t_s):
        """ECEF positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        r, v = self.states_eci(t_s)
        return _eci_to_ecef(r, v, self.earth_rotation_angle_rad(t_s))

    def positions(self, t_s) -> np.ndarray:
        return self.states(t_s)[0]

    def velocities(self, t_s) -> np.ndarray:
        return self.states(t_s)[1]


#: Largest distance [days] between a TLE's epoch and the times it is propagated to. SGP4's
#: along-track error grows by ~1-3 km per day from the epoch (Vallado et al. 2006); beyond a
#: few weeks a fresher element set is needed, and a campaign of a season is a planning estimate.
TLE_MAX_AGE_DAYS = 120.0


@dataclass(frozen=True)
class TleOrbit:
    """SGP4 orbit from a two-line element set, in ITRS (ECEF) with Earth orientation.

    ``t_s`` is seconds after ``epoch_utc`` (ISO 8601 UTC, the run's time origin). SGP4 (the
    ``sgp4`` package) gives TEME states; :func:`earth_orientation.teme_to_itrs` rotates them to
    ITRS with UT1 - UTC and polar motion from the shipped IERS table.
    """

    line1: str
    line2: str
    epoch_utc: str
    frame: str = field(default="ecef", init=False)
    # set by __post_init__: the sgp4 Satrec and epoch_utc as MJD (UTC)
    _sat: Any = field(init=False, repr=False, compare=False)
    _epoch_mjd: float = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        from sgp4.api import Satrec

        from chirplidar.geometry import earth_orientation as eo

        l1, l2 = str(self.line1).rstrip(), str(self.line2).rstrip()
        for name, line, first in (("line1", l1, "1"), ("line2", l2, "2")):
            if len(line) != 69 or line[0] != first:
                raise ValueError(
                    f"{name} is not line {first} of a TLE (69 characters starting "
                    f"with '{first} ', got {len(line)}: {line[:20]!r}...)"
                )
            digits = sum(int(c) for c in line[:68] if c.isdigit()) + line[:68].count("-")
            if not line[68].isdigit() or digits % 10 != int(line[68]):
                raise ValueError(
                    f"{name}: TLE checksum fails (column 69 is {line[68]!r}, the "
                    f"line's digits and minus signs sum to {digits} -> "
                    f"{digits % 10}): a damaged or mistyped element set"
                )
        if l1[2:7] != l2[2:7]:
            raise ValueError(
                f"line1 and line2 belong to different satellites "
                f"({l1[2:7].strip()} and {l2[2:7].strip()})"
            )
        sat = Satrec.twoline2rv(l1, l2)
        if sat.error:
            raise ValueError(f"line1/line2 are not a valid TLE (sgp4 error {sat.error})")
        t0 = eo.mjd_utc(eo.parse_utc(self.epoch_utc, "epoch_utc"))
        object.__setattr__(self, "line1", l1)
        object.__setattr__(self, "line2", l2)
        object.__setattr__(self, "_sat", sat)
        object.__setattr__(self, "_epoch_mjd", t0)

    @property
    def tle_epoch_mjd(self) -> float:
        """The element set's epoch, MJD (UTC)."""
        return float(self._sat.jdsatepoch - 2400000.5 + self._sat.jdsatepochF)

    @property
    def epoch_mjd(self) -> float:
        """The run's time origin ``epoch_utc``, MJD (UTC)."""
        return float(self._epoch_mjd)

    def check_window(self, t0_s: float, t1_s: float, key: str = "t_s") -> None:
        """ValueError naming ``key`` when [t0_s, t1_s] (s after ``epoch_utc``) reaches more than
        :data:`TLE_MAX_AGE_DAYS` from the TLE epoch."""
        age = np.array([t0_s, t1_s]) / 86400.0 + self.epoch_mjd - self.tle_epoch_mjd
        if np.max(np.abs(age)) > TLE_MAX_AGE_DAYS:
            raise ValueError(
                f"{key}: the window reaches {np.max(np.abs(age)):.1f} days from the "
                f"TLE epoch; SGP4 is not trusted beyond {TLE_MAX_AGE_DAYS:.0f} days "
                "(its error grows by km per day): use an element set from the "
                "window's time"
            )

    def states_teme(self, t_s):
        """TEME positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        t = _checks.time_array("t_s", t_s)
        sat = self._sat
        d = self.epoch_mjd - self.tle_epoch_mjd + t / 86400.0  # days after the TLE epoch
        jd = np.full(t.shape, sat.jdsatepoch)
        fr = sat.jdsatepochF + d
        err, r, v = sat.sgp4_array(jd, fr)
        if np.any(err != 0):
            raise ValueError(
                f"t_s: SGP4 propagation failed (error codes "
                f"{sorted(set(err[err != 0].tolist()))}: decayed or invalid orbit)"
            )
        return np.asarray(r).reshape(-1, 3) * 1e3, np.asarray(v).reshape(-1, 3) * 1e3

    def states(self, t_s):
        """ITRS positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        from chirplidar.geometry.earth_orientation import teme_to_itrs

        t = _checks.time_array("t_s", t_s)
        r, v = self.states_teme(t)
        return teme_to_itrs(r, v, self.epoch_mjd + t / 86400.0)

    def positions(self, t_s):
        return self.states(t_s)[0]

    def velocities(self, t_s):
        return self.states(t_s)[1]
