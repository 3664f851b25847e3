"""Satellite orbits against independent references: skyfield's SGP4 and ITRS (UT1, polar motion),
sgp4's own GMST, and the Kepler + J2 design orbit's stated error against SGP4."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from chirplidar.geometry import earth_orientation as eo
from chirplidar.geometry.orbits import KeplerOrbit, TleOrbit

# ICESat-2 (NORAD 43613), the public element set of 2026-10-04 (CelesTrak / Space-Track).
ICESAT2_L1 = "1 43613U 18070A   26277.57046165  .00001587  00000+0  57409-4 0  9990"
ICESAT2_L2 = "2 43613  91.9994 320.5065 0005609  71.5392 288.6467 15.28297940449160"


def _skyfield_itrs(l1, l2, start_utc, t_s):
    """Positions and velocities in ITRS from skyfield (its own SGP4 call, TEME -> GCRS -> ITRS
    with its own UT1 and the polar motion of the IERS finals table)."""
    import astropy_iers_data
    from skyfield.api import EarthSatellite, Loader
    from skyfield.data import iers
    from skyfield.framelib import itrs

    loader = Loader(os.path.dirname(astropy_iers_data.IERS_A_FILE))
    ts = loader.timescale(builtin=False)
    with loader.open("finals2000A.all") as f:
        iers.install_polar_motion_table(ts, iers.parse_x_y_dut1_from_finals_all(f))
    t0 = eo.parse_utc(start_utc)
    t = ts.utc(t0.year, t0.month, t0.day, t0.hour, t0.minute, t0.second + np.asarray(t_s))
    p, v = EarthSatellite(l1, l2, ts=ts).at(t).frame_xyz_and_velocity(itrs)
    return p.m.T, v.m_per_s.T


def test_tle_positions_match_skyfield_itrs_within_2_m():
    # A 10-minute pass a day after the element set's epoch.
    t = np.linspace(0.0, 600.0, 41)
    orbit = TleOrbit(ICESAT2_L1, ICESAT2_L2, "2026-10-05T06:00:00Z")
    r, v = orbit.states(t)
    r_ref, v_ref = _skyfield_itrs(ICESAT2_L1, ICESAT2_L2, "2026-10-05T06:00:00Z", t)
    assert np.max(np.linalg.norm(r - r_ref, axis=1)) < 2.0
    assert np.max(np.linalg.norm(v - v_ref, axis=1)) < 2e-3
    # The comparison can fail: leaving out the Earth orientation moves the orbit by more than 2 m.
    r_teme, v_teme = orbit.states_teme(t)
    r_no_pm, _ = eo.teme_to_itrs(r_teme, v_teme, orbit.epoch_mjd + t / 86400, polar_motion=False)
    assert np.max(np.linalg.norm(r_no_pm - r_ref, axis=1)) > 5.0


def test_gmst82_matches_sgp4_gstime():
    from sgp4.propagation import gstime

    jd = np.array([2451545.0, 2461000.3, 2461344.77])
    assert eo.gmst82_rad(jd) == pytest.approx([gstime(x) for x in jd], abs=1e-12)


def test_ut1_minus_utc_matches_skyfield_builtin():
    """A measured (not predicted) day: the shipped IERS table against skyfield's own built-in
    UT1 (its delta-T file and leap seconds), to 1 ms (0.5 m on the equator). Skyfield's
    built-in predictions are older than the table's, so later days differ by ~0.1 s."""
    from skyfield.api import load

    ts = load.timescale(builtin=True)
    t = ts.utc(2025, 6, 1, 12)
    dut1_skyfield = float(t.dut1)   # skyfield's UT1 - UTC
    assert eo.ut1_minus_utc_s(eo.mjd_utc("2025-06-01T12:00:00Z")) == pytest.approx(
        dut1_skyfield, abs=1e-3)


def test_earth_orientation_warns_beyond_the_table():
    _, last = eo.table_span_mjd()
    with pytest.warns(eo.EarthOrientationWarning, match="outside the IERS"):
        eo.ut1_minus_utc_s(last + 400.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        eo.polar_motion_rad(last - 10.0)


def _kepler_from_tle(orbit: TleOrbit, j2: bool) -> KeplerOrbit:
    """Kepler + J2 from the element set's mean (Brouwer) elements, t = 0 at the run epoch."""
    s = orbit._sat
    dt0 = (orbit.epoch_mjd - orbit.tle_epoch_mjd) * 86400.0
    return KeplerOrbit(s.a * s.radiusearthkm * 1e3, s.ecco, s.inclo, s.nodeo, s.argpo, s.mo,
                       -dt0, j2=j2)


def test_kepler_j2_within_the_documented_error_of_sgp4():
    """KeplerOrbit's docstring: within 20 km of SGP4 over a day from the same mean elements
    (J2's short-period terms, ~10 km, are left out). Without the J2 rates it drifts by hundreds
    of km a day, so the bound tests the secular rates (the mean anomaly's J2 rate alone is
    ~5 m/s along track: ~460 km a day)."""
    orbit = TleOrbit(ICESAT2_L1, ICESAT2_L2, "2026-10-04T13:41:27Z")
    t = np.linspace(0.0, 86400.0, 2001)
    r_sgp4, _ = orbit.states_teme(t)
    err = np.linalg.norm(_kepler_from_tle(orbit, True).states_eci(t)[0] - r_sgp4, axis=1)
    assert err.max() < 20e3
    err_two_body = np.linalg.norm(_kepler_from_tle(orbit, False).states_eci(t)[0] - r_sgp4,
                                  axis=1)
    assert err_two_body.max() > 200e3


def test_kepler_velocity_is_the_derivative_of_position():
    k = KeplerOrbit(6.87e6, 0.01, np.radians(92.0), 0.3, 0.2, 0.1, 0.0, j2=True)
    t = np.array([100.0, 2000.0])
    h = 1e-3
    fd = (k.states_eci(t + h)[0] - k.states_eci(t - h)[0]) / (2 * h)
    assert np.max(np.abs(fd - k.states_eci(t)[1])) < 1e-4


@pytest.mark.parametrize(("line1", "line2", "match"), [
    (ICESAT2_L1[:-1] + "1", ICESAT2_L2, "checksum"),
    (ICESAT2_L1, ICESAT2_L2[:30] + "9" + ICESAT2_L2[31:], "checksum"),
    (ICESAT2_L1[:50], ICESAT2_L2, "line1 is not line 1"),
    (ICESAT2_L2, ICESAT2_L1, "line1 is not line 1"),
])
def test_bad_tle_is_refused(line1, line2, match):
    with pytest.raises(ValueError, match=match):
        TleOrbit(line1, line2, "2026-10-05T00:00:00Z")


def test_window_far_from_the_tle_epoch_is_refused():
    orbit = TleOrbit(ICESAT2_L1, ICESAT2_L2, "2026-10-05T00:00:00Z")
    orbit.check_window(0.0, 90 * 86400.0, "survey")
    with pytest.raises(ValueError, match=r"survey: the window reaches 2\d\d\.\d days"):
        orbit.check_window(0.0, 250 * 86400.0, "survey")
