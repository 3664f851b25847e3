"""Frames: projected <-> geodetic <-> ECEF, local bases, and ECEF rays in the scene frame."""

import numpy as np
import pytest
from pyproj import Transformer

from chirplidar.geometry import frames as F


@pytest.mark.parametrize("epsg, lat0", [(3413, 72.0), (3031, -75.0)])
def test_projected_geodetic_round_trip(epsg, lat0):
    # Reference: identity (round trip), tolerance from the brief: 1e-6 m.
    rng = np.random.default_rng(1)
    lat = lat0 + rng.uniform(-12, 12, 200)
    lon = rng.uniform(-180, 180, 200)
    h = rng.uniform(-100, 4000, 200)
    x, y, z = F.geodetic_to_projected(lat, lon, h, epsg)
    lat2, lon2, h2 = F.projected_to_geodetic(x, y, z, epsg)
    x2, y2, z2 = F.geodetic_to_projected(lat2, lon2, h2, epsg)
    assert np.max(np.abs(x2 - x)) < 1e-6 and np.max(np.abs(y2 - y)) < 1e-6
    assert np.max(np.abs(z2 - z)) < 1e-6
    assert np.allclose(z, h)  # z is the ellipsoidal height (pass-through)


def test_geodetic_to_ecef_reference_points():
    # Reference: WGS-84 defining constants (NIMA TR8350.2): a = 6378137 m, f = 1/298.257223563.
    x, y, z = F.geodetic_to_ecef([0.0, 90.0, 0.0], [0.0, 0.0, 90.0], [0.0, 0.0, 100.0])
    assert np.allclose(x, [6378137.0, 0.0, 0.0], atol=1e-6)
    assert np.allclose(y, [0.0, 0.0, 6378237.0], atol=1e-6)
    assert np.allclose(z, [0.0, 6378137.0 * (1 - 1 / 298.257223563), 0.0], atol=1e-6)
    _lat, _lon, h = F.ecef_to_geodetic(x, y, z)
    assert np.allclose(h, [0.0, 0.0, 100.0], atol=1e-6)


def test_enu_basis_orthonormal_and_up():
    # Reference: closed-form ENU basis (e.g. Hofmann-Wellenhof, GNSS, eq. 10.9); at (0, 0)
    # east = +Y, north = +Z, up = +X.
    B = F.enu_basis([0.0, 71.3, -80.0], [0.0, -42.0, 130.0])
    assert np.allclose(B[0], [[0, 1, 0], [0, 0, 1], [1, 0, 0]], atol=1e-15)
    assert np.allclose(np.einsum("nij,nkj->nik", B, B), np.eye(3), atol=1e-14)
    assert np.allclose(np.linalg.det(B), 1.0)
    assert np.allclose(B[:, 2], F.local_up_ecef([0.0, 71.3, -80.0], [0.0, -42.0, 130.0]))


def test_scale_factor_true_at_standard_parallel():
    # Reference: EPSG:3413 definition, latitude of true scale 70 N; EPSG:3031: 71 S.
    x, y, _ = F.geodetic_to_projected(70.0, -10.0, 0.0, 3413)
    assert abs(F.scale_factor(x, y, 3413) - 1.0) < 1e-8
    x, y, _ = F.geodetic_to_projected(-71.0, 10.0, 0.0, 3031)
    assert abs(F.scale_factor(x, y, 3031) - 1.0) < 1e-8
    assert F.scale_factor(0.0, 0.0, 3413) < 0.98  # pole: k ~ 0.970 (pyproj get_factors)


def _sat_ecef(lat, lon, h):
    return np.array(F.geodetic_to_ecef(lat, lon, h), dtype=float).T.reshape(-1, 3)


def test_nadir_ray_range_equals_ellipsoidal_height():
    # Reference: the geodetic height from pyproj (ECEF -> EPSG:4979) is the distance along the
    # ellipsoid normal; tolerance 1 cm (brief).
    lat, lon = np.array([72.5, 80.0, 61.0]), np.array([-40.0, 10.0, -45.0])
    o = _sat_ecef(lat, lon, 500e3 + np.array([0.0, 1234.5, 98765.0]))
    h_ref = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(
        o[:, 0], o[:, 1], o[:, 2])[2]
    d = -F.local_up_ecef(lat, lon)
    assert np.allclose(F.ray_ellipsoid_distance_m(o, d), h_ref, atol=0.01)
    rays = F.rays_projected_from_ecef(o, d, 3413, target_height_m=-500.0, entry_height_m=5000.0)
    assert rays.valid.all()
    t_ground = -rays.origin_m[:, 2] / rays.direction[:, 2]  # scene plane z = 0 = ellipsoid
    assert np.allclose(rays.range_m(t_ground), h_ref, atol=0.01)
    assert np.allclose(rays.origin_m[:, 2], 5000.0, atol=1e-3)
    assert np.allclose(rays.range_offset_m, h_ref - 5000.0, atol=0.01)


def test_off_nadir_satellite_ray_range_matches_ecef():
    # Reference: distance along the straight ECEF line to ellipsoidal height 1000 m, verified
    # with pyproj's geodetic height; the scene-frame chord must reproduce it within 1 cm.
    lat, lon = np.array([75.0, 68.0]), np.array([-38.0, -50.0])
    o = _sat_ecef(lat, lon, np.array([500e3, 520e3]))
    B = F.enu_basis(lat, lon)
    th = np.radians(2.0)
    d_enu = np.array([[np.sin(th), 0.0, -np.cos(th)], [0.0, -np.sin(th), -np.cos(th)]])
    d = np.einsum("ni,nij->nj", d_enu, B)
    s = F.ray_ellipsoid_distance_m(o, d, 1000.0)
    p = o + s[:, None] * d
    assert np.allclose(F.ecef_to_geodetic(p[:, 0], p[:, 1], p[:, 2])[2], 1000.0, atol=1e-3)
    rays = F.rays_projected_from_ecef(o, d, 3413, target_height_m=0.0, entry_height_m=3000.0)
    t = (1000.0 - rays.origin_m[:, 2]) / rays.direction[:, 2]
    assert np.allclose(rays.range_m(t), s, atol=0.01)
    hit = rays.origin_m + t[:, None] * rays.direction
    assert np.allclose(rays.range_to_points_m(hit), s, atol=0.01)
    # the hit point's horizontal position agrees with the ECEF point projected (1 cm)
    q = F.ecef_to_projected(p, 3413)
    assert np.allclose(hit[:, :2], q[:, :2], atol=0.01)


def test_upward_ray_is_invalid_and_finite():
    o = _sat_ecef(np.array([72.0]), np.array([-40.0]), np.array([500e3]))
    d = F.local_up_ecef([72.0], [-40.0])
    rays = F.rays_projected_from_ecef(o, d, 3413, target_height_m=0.0, entry_height_m=4000.0)
    assert not rays.valid[0]
    assert np.all(np.isfinite(rays.origin_m)) and np.all(np.isfinite(rays.direction))
    assert rays.range_m(np.array([10.0]))[0] == np.inf


def test_local_rays_correct_for_scale_factor():
    # Reference: flat-Earth trigonometry in true metres: a beam theta off nadir reaches a plane
    # D below the origin at slant range D / cos(theta), horizontal offset D tan(theta); in the
    # grid the horizontal offset is scaled by k.
    o = np.array([[0.0, -300e3, 1500.0]])  # near the pole, k ~ 0.97
    k = F.scale_factor(o[:, 0], o[:, 1], 3413)[0]
    assert abs(k - 1) > 0.02
    th = np.radians(20.0)
    d = np.array([[np.sin(th), 0.0, -np.cos(th)]])
    rays = F.rays_projected_local(o, d, 3413)
    t = 1000.0 / -rays.direction[0, 2]
    assert rays.range_m(t) == pytest.approx(1000.0 / np.cos(th), rel=1e-12)
    assert rays.direction[0, 0] * t == pytest.approx(k * 1000.0 * np.tan(th), rel=1e-12)


def test_bad_inputs_name_the_argument():
    with pytest.raises(ValueError, match="epsg"):
        F.projected_to_geodetic(0.0, 0.0, 0.0, 4326)
    with pytest.raises(ValueError, match="lat"):
        F.geodetic_to_ecef(91.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="direction_ecef"):
        F.rays_projected_from_ecef([[7e6, 0, 0]], [[-2.0, 0, 0]], 3413, target_height_m=0.0)
    with pytest.raises(ValueError, match="entry_height_m"):
        F.rays_projected_from_ecef([[7e6, 0, 0]], [[-1.0, 0, 0]], 3413, target_height_m=0.0,
                                   entry_height_m=-10.0)


def test_local_rays_exact_mode_for_aircraft():
    # Reference: pyproj conversions of origin and hit to ECEF: the exact mode's hit lies at
    # ellipsoidal height 1000 m, at true range |hit - origin| (ECEF) and at a true 20 deg from
    # the ellipsoid normal at the origin. The flat mode is short by the curvature drop
    # (H tan th)^2 / (2 R cos th), R = sqrt(M N) (Gaussian radius), within 3 %.
    o = np.array([[-2.0e5, -2.1e6, 6000.0], [-2.0e5, -2.1e6, 6000.0]])
    th = np.radians(20.0)
    d = np.array([[np.sin(th), 0.0, -np.cos(th)], [0.0, 0.0, -1.0]])
    # target height = the surface: the hit is the chord's end (exact; in between, the chord sags)
    exact = F.rays_projected_local(o, d, 3413, target_height_m=1000.0, entry_height_m=5500.0)
    t = (1000.0 - exact.origin_m[:, 2]) / exact.direction[:, 2]
    hit = exact.origin_m + t[:, None] * exact.direction
    r = exact.range_m(t)
    o_e, h_e = F.projected_to_ecef(o, 3413), F.projected_to_ecef(hit, 3413)
    assert np.allclose(np.linalg.norm(h_e - o_e, axis=1), r, atol=0.01)
    assert r[1] == pytest.approx(5000.0, abs=0.01)
    lat, lon, _ = F.projected_to_geodetic(o[:, 0], o[:, 1], o[:, 2], 3413)
    u = (h_e - o_e) / np.linalg.norm(h_e - o_e, axis=1, keepdims=True)
    down = -F.local_up_ecef(lat, lon)
    ang = np.arctan2(np.linalg.norm(np.cross(u, down), axis=1), np.sum(u * down, axis=1))
    assert np.allclose(ang, [th, 0.0], atol=1e-8)
    flat = F.rays_projected_local(o, d, 3413)
    r_flat = flat.range_m(5000.0 / -flat.direction[:, 2])
    e2, a = F.WGS84_E2, F.WGS84_A_M
    s2 = np.sin(np.radians(lat[0])) ** 2
    R = a * np.sqrt(1 - e2) / (1 - e2 * s2)
    drop = (5000.0 * np.tan(th)) ** 2 / (2 * R * np.cos(th))
    assert r[0] - r_flat[0] == pytest.approx(drop, rel=0.03)
    assert abs(r[1] - r_flat[1]) < 1e-6


@pytest.mark.parametrize("epsg, x0, y0", [(3413, -2.0e5, -2.5e6), (3031, 1.0e6, -0.5e6),
                                          (3031, -1.5e6, 0.3e6)])
def test_grid_axes_match_pyproj(epsg, x0, y0):
    # References (pyproj, independent of the closed form): PROJ's meridian convergence
    # (Proj.get_factors) for the angle, and the grid axes as pyproj central differences of +-1 m
    # in x and y made orthogonal to the ellipsoid normal (their own error: ~1 m / R ~ 2e-7).
    from pyproj import Proj

    rng = np.random.default_rng(3)
    o = np.column_stack([x0 + rng.uniform(-5e4, 5e4, 40), y0 + rng.uniform(-5e4, 5e4, 40),
                         rng.uniform(-100.0, 4000.0, 40)])
    lat, lon, _ = F.projected_to_geodetic(o[:, 0], o[:, 1], o[:, 2], epsg)
    c, s = F.grid_convergence(lon, epsg)
    gamma_ref = Proj(f"EPSG:{epsg}").get_factors(lon, lat).meridian_convergence
    assert np.allclose(np.degrees(np.arctan2(s, c)), gamma_ref, atol=1e-9)
    o_e, ex, ey, up = F.grid_axes_ecef(o, epsg)
    assert np.allclose(o_e, F.projected_to_ecef(o, epsg), atol=1e-6)
    p = F.projected_to_ecef(np.stack([o + [1, 0, 0], o - [1, 0, 0], o + [0, 1, 0],
                                      o - [0, 1, 0]]), epsg)
    for axis, v in ((ex, p[0] - p[1]), (ey, p[2] - p[3])):
        v = v - np.sum(v * up, axis=-1, keepdims=True) * up
        assert np.allclose(axis, v / np.linalg.norm(v, axis=-1, keepdims=True), atol=2e-7)
    assert np.allclose(np.sum(ex * ey, axis=-1), 0.0, atol=1e-14)
    assert np.allclose(np.cross(ex, ey), up, atol=1e-14)


def test_height_crossing_meets_its_height_for_steep_and_grazing_rays():
    # Reference: pyproj's geodetic height of the returned point equals the asked height (the
    # Newton iteration stops once its own error bound is below 10 um).
    o = F.projected_to_ecef(np.array([[-2.0e5, -2.1e6, 6000.0]] * 4), 3413)
    lat, lon, _ = F.ecef_to_geodetic(o[:, 0], o[:, 1], o[:, 2])
    enu = F.enu_basis(lat, lon)[0]
    d = []
    for th in np.radians([0.0, 30.0, 70.0, 85.0]):
        v = np.sin(th) * enu[0] - np.cos(th) * enu[2]
        d.append(v / np.linalg.norm(v))
    for h in (1000.0, -50.0, 5999.0):
        s = F.ray_ellipsoid_distance_m(o, np.array(d), h)
        p = o + s[:, None] * np.array(d)
        assert np.allclose(F.ecef_to_geodetic(p[:, 0], p[:, 1], p[:, 2])[2], h, atol=1e-5)
