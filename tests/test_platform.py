"""Platforms: UAV paths, lawnmower, aircraft lines, Kepler orbits, beams and shots."""

import numpy as np
import pytest
import shapely
from pyproj import Transformer
from shapely.geometry import LineString, Polygon

from chirplidar.geometry import frames as F
from chirplidar.geometry import orbits, paths, pointing

MU = 3.986004418e14  # Vallado, Table D-1 (brief)
RE = 6378137.0


# ---------------------------------------------------------------- UAV


def test_uav_straight_segment_constant_speed():
    # Reference: closed form x = v t along a straight segment.
    uav = paths.UavPath(np.array([[0.0, 0.0, 100.0], [1000.0, 0.0, 100.0], [1000.0, 500.0, 150.0]]),
                    speed_mps=10.0)
    t = np.array([0.0, 25.0, 99.9])
    assert np.allclose(uav.positions(t), [[0, 0, 100], [250, 0, 100], [999, 0, 100]])
    assert np.allclose(np.linalg.norm(uav.velocities(t), axis=1), 10.0)
    # second segment: length sqrt(500^2 + 50^2), reached at 100 s
    L2 = np.hypot(500.0, 50.0)
    p = uav.positions(np.array([100.0 + L2 / 20.0]))
    assert np.allclose(p, [[1000.0, 250.0, 125.0]])
    assert uav.duration_s == pytest.approx((1000.0 + L2) / 10.0)
    with pytest.raises(ValueError, match="t_s"):
        uav.positions(np.array([uav.duration_s + 1.0]))
    with pytest.raises(ValueError, match="speed_mps"):
        paths.UavPath(np.zeros((2, 3)) + [[0, 0, 0], [1, 0, 0]], speed_mps=0.0)


def test_uav_above_ground_follows_terrain():
    # Reference: z = ground(x, y) + AGL; v_z = slope * v_x for a plane of slope 0.01.
    uav = paths.UavPath(np.array([[0.0, 0.0, 50.0], [1000.0, 0.0, 50.0]]), 5.0, "above_ground",
                    ground_height_m=lambda x, y: 2000.0 + 0.01 * x)
    t = np.array([10.0, 100.0])
    assert np.allclose(uav.positions(t)[:, 2], 2050.0 + 0.01 * 5.0 * t)
    assert np.allclose(uav.velocities(t)[:, 2], 0.05)
    with pytest.raises(ValueError, match="ground_height_m"):
        paths.UavPath(np.array([[0.0, 0.0, 50.0], [1.0, 0.0, 50.0]]), 5.0, "above_ground")


# ---------------------------------------------------------------- lawnmower


def _check_lawnmower(poly_xy, spacing, heading):
    lines = paths.lawnmower_lines(poly_xy, spacing, heading)
    wp, legs = paths.lawnmower(poly_xy, spacing, heading)
    assert wp.shape == (2 * len(lines), 2)
    # legs 2i are the lines (numbered in flight order), legs 2i + 1 the transits between them
    assert legs.tolist() == [i // 2 if i % 2 == 0 else -1 for i in range(2 * len(lines) - 1)]
    u = np.array([np.sin(heading), np.cos(heading)])  # clockwise from grid north
    nrm = np.array([-u[1], u[0]])
    offsets = []
    for a, b in lines:
        d = (b - a) / np.linalg.norm(b - a)
        assert abs(abs(d @ u) - 1) < 1e-9  # lines run along the heading
        offsets.append(a @ nrm)
    levels = np.unique(np.round(offsets, 6))
    assert np.allclose(np.diff(levels), spacing)  # reference: the requested line spacing
    strips = shapely.union_all([LineString([a, b]).buffer(spacing / 2, cap_style="flat")
                                for a, b in lines])
    poly = Polygon(poly_xy)
    assert poly.difference(strips).area < 1e-6 * poly.area  # covered


def test_lawnmower_rectangle():
    _check_lawnmower(np.array([[0, 0], [1000, 0], [1000, 430], [0, 430]], float), 50.0, np.pi / 2)


def test_lawnmower_concave_rotated():
    L = np.array([[0, 0], [800, 0], [800, 300], [300, 300], [300, 900], [0, 900]], float)
    _check_lawnmower(L, 40.0, np.radians(30.0))


def test_uav_track_index_follows_the_legs():
    # three legs: line 0, a transit (-1), line 1; a repeated waypoint (zero-length leg) is dropped
    # with its track entry, so the legs keep their tracks
    w = np.array([[0, 0, 50], [100, 0, 50], [100, 0, 50], [100, 20, 50], [0, 20, 50]], float)
    path = paths.UavPath(w, 10.0, segment_tracks=np.array([0, 7, -1, 1]))
    t = np.array([0.0, 5.0, 10.5, 11.9, 12.5, 21.9])  # s; legs end at 10, 12 and 22 s
    assert path.track_index(t).tolist() == [0, 0, -1, -1, 1, 1]
    # default: each leg its own track
    assert paths.UavPath(w, 10.0).track_index(np.array([1.0, 11.0, 15.0])).tolist() == [0, 2, 3]
    with pytest.raises(ValueError, match="segment_tracks"):
        paths.UavPath(w, 10.0, segment_tracks=np.array([0, 1]))


def test_lawnmower_self_intersecting_raises():
    bowtie = np.array([[0, 0], [100, 100], [100, 0], [0, 100]], float)
    with pytest.raises(ValueError, match="polygon"):
        paths.lawnmower(bowtie, 10.0, 0.0)


# ---------------------------------------------------------------- aircraft


def test_aircraft_semicircle_turn_and_continuity():
    # Reference: for line spacing = 2 r the Dubins turn is a semicircle of radius r centred
    # between the line ends; path length 2 L + pi r.
    r, v = 200.0, 60.0
    ac = paths.AircraftLines([((0, 0), (1000, 0)), ((1000, 400), (0, 400))], 500.0, v, r)
    assert ac.duration_s == pytest.approx((2000.0 + np.pi * r) / v)
    t = np.linspace(1000.0 / v, (1000.0 + np.pi * r) / v, 50)
    p = ac.positions(t)
    assert np.allclose(np.hypot(p[:, 0] - 1000.0, p[:, 1] - 200.0), r)
    assert np.all(ac.track_index(t[1:-1]) == -1)
    assert np.allclose(p[:, 2], 500.0)


@pytest.mark.parametrize("lines", [
    [((0, 0), (1000, 0)), ((1000, 1000), (0, 1000)), ((0, 1300), (1500, 1300))],  # wide, tight
    [((0, 0), (1000, 0)), ((1500, 300), (2500, 300))],                             # S-turn (RSL/LSR)
])
def test_aircraft_position_and_heading_continuous(lines):
    r, v = 250.0, 70.0
    ac = paths.AircraftLines(lines, 800.0, v, r)
    t = np.linspace(0.0, ac.duration_s, 200001)
    p = ac.positions(t)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    dt = t[1] - t[0]
    assert step.max() <= v * dt * (1 + 1e-6)  # no jumps at joins (reference: |dp| <= v dt)
    vel = ac.velocities(t)
    assert np.allclose(np.linalg.norm(vel, axis=1), v)
    dv = np.linalg.norm(np.diff(vel, axis=0), axis=1)
    assert dv.max() <= v * v / r * dt * (1 + 1e-6)  # heading continuous, |a| <= v^2 / r
    ends = ac.positions(np.array([ac.duration_s]))[0, :2]
    assert np.allclose(ends, lines[-1][1])


# ---------------------------------------------------------------- orbits


I_SSO = np.radians(97.4)  # sun-synchronous inclination at 500 km (brief)


def _circular(i_rad=I_SSO, j2=True, **kw):
    return orbits.KeplerOrbit(RE + 500e3, 0.0, i_rad, 0.3, 0.0, 0.0, 0.0, j2=j2, **kw)


def test_kepler_circular_radius_and_period():
    # Reference: two-body circular orbit, |r| = a, T = 2 pi sqrt(a^3 / mu).
    orb = _circular(j2=False)
    a = RE + 500e3
    T = 2 * np.pi * np.sqrt(a ** 3 / MU)
    assert orb.period_s == pytest.approx(T, rel=1e-12)
    t = np.linspace(0.0, 2 * T, 1001)
    r, _v = orb.states_eci(t)
    assert np.allclose(np.linalg.norm(r, axis=1), a, rtol=1e-12)
    r0, rT = orb.states_eci(np.array([0.0, T]))[0]
    assert np.linalg.norm(rT - r0) / a < 1e-6
    # ECEF radius is the same (rotation), and J2 drift keeps it too
    assert np.allclose(np.linalg.norm(orb.positions(t), axis=1), a, rtol=1e-12)
    assert np.allclose(np.linalg.norm(_circular().positions(t), axis=1), a, rtol=1e-12)


def test_j2_raan_rate_sun_synchronous():
    # Reference: Vallado eq. for dRAAN/dt (J2 secular); a sun-synchronous orbit precesses at
    # 360 deg / 365.2422 d = 0.9856 deg/day. 500 km at 97.4 deg is sun-synchronous.
    orb = _circular()
    a = RE + 500e3
    n = np.sqrt(MU / a ** 3)
    closed = -1.5 * n * 1.08262668e-3 * (RE / a) ** 2 * np.cos(np.radians(97.4))
    assert orb.raan_rate_rad_s == pytest.approx(closed, rel=1e-12)
    deg_day = np.degrees(orb.raan_rate_rad_s) * 86400.0
    assert deg_day == pytest.approx(360.0 / 365.2422, abs=0.01)
    # propagated orbit-plane normal (ECI) turns at that rate over 10 days
    T = orb.period_s
    ts = np.array([0.0, T / 4, 10 * 86400.0, 10 * 86400.0 + T / 4])
    r = orb.states_eci(ts)[0]
    h0, h1 = np.cross(r[0], r[1]), np.cross(r[2], r[3])
    node = lambda h: np.arctan2(h[0], -h[1])
    assert node(h1) - node(h0) == pytest.approx(orb.raan_rate_rad_s * 10 * 86400.0, rel=0.01)


def test_kepler_velocity_is_derivative_and_vis_viva():
    # Reference: vis-viva v^2 = mu (2 / r - 1 / a) (two-body); central differences of position.
    orb = orbits.KeplerOrbit(7.2e6, 0.05, 1.2, 0.4, 0.7, 2.0, 100.0, j2=False)
    r, v = orb.states_eci(np.array([130.0, 2000.0]))
    rn = np.linalg.norm(r, axis=1)
    assert np.allclose(np.sum(v * v, axis=1), MU * (2 / rn - 1 / 7.2e6), rtol=1e-10)
    orb = orbits.KeplerOrbit(7.2e6, 0.05, 1.2, 0.4, 0.7, 2.0, 100.0)  # with J2 drift, ECEF
    t = np.array([500.0, 4000.0])
    h = 1e-3
    fd = (orb.positions(t + h) - orb.positions(t - h)) / (2 * h)
    assert np.allclose(orb.velocities(t), fd, atol=1e-4)


def test_kepler_bad_inputs():
    with pytest.raises(ValueError, match="eccentricity"):
        orbits.KeplerOrbit(7e6, 1.2, 1.0, 0, 0, 0, 0)
    with pytest.raises(ValueError, match="perigee"):
        orbits.KeplerOrbit(6.5e6, 0.1, 1.0, 0, 0, 0, 0)


def test_tle_orbit_needs_sgp4():
    try:
        import sgp4  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match=r"chirplidar\[orbit\]"):
            orbits.TleOrbit("1", "2")
    else:
        pytest.skip("sgp4 installed")


def test_satellite_nadir_ray_hits_ellipsoid_at_height():
    # Reference: geodetic height from pyproj (ECEF -> EPSG:4979), 1 cm (brief).
    # argument of latitude 80 deg at epoch: the satellite is at high northern latitude.
    orb = orbits.KeplerOrbit(RE + 500e3, 0.001, np.radians(97.4), np.radians(250.0), 0.0,
                        np.radians(80.0), 0.0)
    t = pointing.shot_times(0.0, 0.05, 200.0)
    g = pointing.shot_geometry(orb, t, pointing.nadir_beam(), epsg=3413, target_height_m=-200.0,
                        entry_height_m=4000.0)
    pos = g.position_m
    lon, lat, h = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(
        pos[:, 0], pos[:, 1], pos[:, 2])
    assert np.all(lat > 60.0)
    assert np.allclose(g.direction[:, 0], -F.local_up_ecef(lat, lon), atol=1e-12)
    rays = g.rays
    assert rays.origin_m.shape == (10, 1, 3) and rays.valid.all()
    t_ground = -rays.origin_m[..., 2] / rays.direction[..., 2]
    assert np.allclose(rays.range_m(t_ground)[:, 0], h, atol=0.01)


# ---------------------------------------------------------------- beams


def _frames(n, seed=3):
    rng = np.random.default_rng(seed)
    up = rng.normal(size=(n, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v, up


def _angle(a, b):
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1))


def test_nadir_and_off_nadir_beams():
    # Reference: definition of off-nadir angle (angle to -up).
    v, up = _frames(50)
    d = pointing.beam_directions(v, up, None, pointing.nadir_beam())
    assert d.shape == (50, 1, 3)
    assert np.allclose(d[:, 0], -up, atol=1e-12)
    th = np.radians(20.0)
    beams = pointing.BeamPattern(np.full(4, th), np.radians([0.0, 90.0, 180.0, 270.0]))
    d = pointing.beam_directions(v, up, pointing.Attitude(), beams)
    assert np.allclose(_angle(d, -up[:, None, :]), th, atol=1e-12)
    assert np.allclose(np.linalg.norm(d, axis=-1), 1.0)
    # azimuth 0 leans forward, 90 deg to the right (right = forward x up)
    fwd = v - np.sum(v * up, axis=1, keepdims=True) * up
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    right = np.cross(fwd, up)
    assert np.allclose(np.sum(d[:, 0] * fwd, axis=1), np.sin(th))
    assert np.allclose(np.sum(d[:, 1] * right, axis=1), np.sin(th))


def test_attitude_roll_pitch():
    # Reference: aerospace convention, positive roll = right wing down (nadir beam looks left),
    # positive pitch = nose up (nadir beam looks forward).
    v = np.array([[1.0, 0, 0]])
    up = np.array([[0.0, 0, 1]])
    d = pointing.beam_directions(v, up, pointing.Attitude(roll_rad=0.1), pointing.nadir_beam())[0, 0]
    assert np.allclose(d, [0.0, np.sin(0.1), -np.cos(0.1)])  # left of +x heading is +y
    d = pointing.beam_directions(v, up, pointing.Attitude(pitch_rad=0.1), pointing.nadir_beam())[0, 0]
    assert np.allclose(d, [np.sin(0.1), 0.0, -np.cos(0.1)])


def test_paired_beams_and_conical_scan():
    v = np.array([[0.0, 1.0, 0]] * 3)
    up = np.array([[0.0, 0, 1]] * 3)
    pat = pointing.paired_beams_across_track(6.65e-3, 1.8e-4)
    d = pointing.beam_directions(v, up, None, pat)
    assert d.shape == (3, 6, 3)
    across = np.arctan2(d[0, :, 0], -d[0, :, 2])  # +x is right of a +y heading
    expect = np.array([-6.65e-3 - 9e-5, -6.65e-3 + 9e-5, -9e-5, 9e-5, 6.65e-3 - 9e-5,
                       6.65e-3 + 9e-5])
    assert np.allclose(across, expect, atol=1e-15)
    # conical: 10 deg cone, quarter turn per second -> azimuth 0, 90, 180 deg at t = 0, 1, 2 s
    cone = pointing.conical_scan(np.radians(10.0), np.pi / 2)
    d = pointing.beam_directions(v, up, None, cone, t_s=np.array([0.0, 1.0, 2.0]))[:, 0]
    s = np.sin(np.radians(10.0))
    assert np.allclose(d[:, :2], [[0, s], [s, 0], [0, -s]], atol=1e-12)
    with pytest.raises(ValueError, match="t_s"):
        pointing.beam_directions(v, up, None, cone)


def test_jitter_statistics_and_no_draws_when_off():
    # Reference: two independent normal tilts of sigma -> E[angle^2] = 2 sigma^2.
    n = 20000
    v = np.tile([[1.0, 0, 0]], (n, 1))
    up = np.tile([[0.0, 0, 1]], (n, 1))
    rng = np.random.default_rng(7)
    d = pointing.beam_directions(v, up, None, pointing.nadir_beam(), jitter_rad_rms=1e-4, rng=rng)
    a = _angle(d[:, 0], -up)
    assert np.mean(a ** 2) == pytest.approx(2e-8, rel=0.05)
    rng = np.random.default_rng(7)
    state = rng.bit_generator.state
    pointing.beam_directions(v[:5], up[:5], None, pointing.nadir_beam(), rng=rng)
    assert rng.bit_generator.state == state
    with pytest.raises(ValueError, match="rng"):
        pointing.beam_directions(v[:5], up[:5], None, pointing.nadir_beam(), jitter_rad_rms=1e-4)


def test_vertical_velocity_raises():
    with pytest.raises(ValueError, match="velocity_unit"):
        pointing.beam_directions(np.array([[0.0, 0, 1]]), np.array([[0.0, 0, 1]]), None, pointing.nadir_beam())


# ---------------------------------------------------------------- shots


def test_shot_times():
    t = pointing.shot_times(1.0, 2.0, 10.0)
    assert np.allclose(t, 1.0 + np.arange(10) / 10.0)
    assert pointing.shot_times(5.0, 5.0, 1e4).shape == (0,)
    with pytest.raises(ValueError, match="prf_hz"):
        pointing.shot_times(0.0, 1.0, 0.0)


def test_zero_shots_give_empty_arrays():
    uav = paths.UavPath(np.array([[0.0, 0.0, 100.0], [100.0, 0.0, 100.0]]), 5.0)
    pat = pointing.paired_beams_across_track(0.01, 0.001)
    g = pointing.shot_geometry(uav, pointing.shot_times(3.0, 3.0, 1000.0), pat, epsg=3413)
    assert g.t_s.shape == (0,) and g.position_m.shape == (0, 3) and g.velocity_mps.shape == (0, 3)
    assert g.direction.shape == (0, 6, 3)
    assert g.rays.origin_m.shape == (0, 6, 3) and g.rays.range_offset_m.shape == (0, 6)
    orb = _circular()
    g = pointing.shot_geometry(orb, np.zeros(0), pointing.nadir_beam())
    assert g.position_m.shape == (0, 3) and g.direction.shape == (0, 1, 3) and g.rays is None


def test_shot_geometry_uav_rays_in_scene_frame():
    # Reference: flat-Earth slant range (h_agl / cos theta) for a 15 deg beam over the plane
    # z = 1000 m in true metres; the scale factor k must not change it.
    uav = paths.UavPath(np.array([[0.0, -1.5e6, 1100.0], [2000.0, -1.5e6, 1100.0]]), 15.0)
    t = pointing.shot_times(0.0, 10.0, 5.0)
    pat = pointing.BeamPattern(np.array([0.0, np.radians(15.0)]), np.array([0.0, np.pi / 2]))
    g = pointing.shot_geometry(uav, t, pat, epsg=3413)
    rays = g.rays
    tt = (1000.0 - rays.origin_m[..., 2]) / rays.direction[..., 2]
    rng_m = rays.range_m(tt)
    assert np.allclose(rng_m[:, 0], 100.0, atol=1e-9)
    assert np.allclose(rng_m[:, 1], 100.0 / np.cos(np.radians(15.0)), rtol=1e-12)


def test_uav_climb_limited_profile_keeps_limits_and_clearance():
    """Over a 60 m ridge (a closed-form ground: a triangle 200 m wide) at 20 m/s with 2 m/s
    climb and 3 m/s descent: never below 100 m above ground, vertical speed within the limits,
    the top of the ridge cleared by exactly 100 m (the lowest feasible profile touches it)."""
    def ground(x, y):
        return np.maximum(0.0, 60.0 - 0.6 * np.abs(np.asarray(x) - 1000.0))

    w = np.array([[0.0, 0.0, 100.0], [2000.0, 0.0, 100.0]])
    path = paths.UavPath(w, 20.0, "above_ground", ground, max_climb_mps=2.0, max_descent_mps=3.0,
                     profile_step_m=1.0)
    t = np.linspace(0.0, path.duration_s, 4001)
    p, v = path.positions(t), path.velocities(t)
    agl = p[:, 2] - ground(p[:, 0], p[:, 1])
    assert agl.min() >= 100.0 - 1e-6
    assert v[:, 2].max() <= 2.0 + 1e-9 and v[:, 2].min() >= -3.0 - 1e-9
    assert p[np.argmin(np.abs(p[:, 0] - 1000.0)), 2] == pytest.approx(160.0, abs=0.1)
    # the climb starts 60 m / (2 / 20) = 600 m before the ridge top (closed form): at x = 400 m
    top = paths.UavPath(w, 20.0, "above_ground", ground, max_climb_mps=2.0, max_descent_mps=3.0,
                    profile_step_m=1.0)
    z = top.positions(np.array([390.0, 410.0]) / 20.0)[:, 2]
    assert z[0] == pytest.approx(100.0, abs=1e-6) and z[1] == pytest.approx(101.0, abs=0.01)
    rep = path.profile_report()
    assert rep["min_clearance_m"] == pytest.approx(100.0, abs=1e-6)
    assert rep["max_climb_mps"] == pytest.approx(2.0, rel=1e-9)
    # without limits the path follows the ground exactly: 0.6 x 20 m/s = 12 m/s on the slope
    exact = paths.UavPath(w, 20.0, "above_ground", ground)
    assert exact.velocities(np.array([47.5]))[0, 2] == pytest.approx(12.0, rel=1e-6)   # x = 950 m
    assert exact.profile_report() is None
    with pytest.raises(ValueError, match="go together"):
        paths.UavPath(w, 20.0, "above_ground", ground, max_climb_mps=2.0)
    with pytest.raises(ValueError, match="absolute altitude"):
        paths.UavPath(w, 20.0, "absolute", None, max_climb_mps=2.0, max_descent_mps=3.0)
