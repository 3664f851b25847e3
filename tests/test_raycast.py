"""Ray casting against closed forms: planes, slopes, footprints, misses, embree fallback."""

import warnings

import numpy as np
import pytest

from chirplidar.geometry import raycast
from chirplidar.geometry.footprints import footprint_statistics, footprint_subrays
from chirplidar.benchmarks.raycast import bench_raycast
from chirplidar.geometry.raycast import EmbreeUnavailableWarning, cast_rays
from chirplidar.geometry.synthetic_terrain import flat_plane, sloped_plane
from chirplidar.geometry.terrain import MATERIAL_CODES, Terrain


def _dir(off_nadir_rad, azimuth_rad=0.0):
    return np.array([np.sin(off_nadir_rad) * np.cos(azimuth_rad),
                     np.sin(off_nadir_rad) * np.sin(azimuth_rad), -np.cos(off_nadir_rad)])


H, A = 100.0, 1000.0


@pytest.fixture(scope="module")
def plane():
    return flat_plane(H, (-1000.0, 1000.0, -1000.0, 1000.0), 50.0, "snow")


def test_flat_plane_nadir_and_off_nadir_closed_form(plane):
    """Closed form: nadir range A - h; off-nadir theta: (A - h) / cos(theta); incidence theta."""
    th = np.deg2rad(20.0)
    o = np.array([[3.0, -7.0, A], [3.0, -7.0, A], [10.0, 20.0, A]])
    d = np.array([_dir(0.0), _dir(th), _dir(th, 2.0)])
    h = cast_rays(plane, o, d)
    assert abs(h.ranges_m[0] - (A - H)) < 1e-3
    np.testing.assert_allclose(h.ranges_m[1:], (A - H) / np.cos(th), atol=1e-3)
    np.testing.assert_allclose(h.incidence_rad, [0.0, th, th], atol=1e-9)
    np.testing.assert_allclose(h.points_m[:, 2], H, atol=1e-6)
    np.testing.assert_array_equal(h.material_codes, MATERIAL_CODES["snow"])
    # points are origin + range * unit direction (directions need not be unit on input)
    h2 = cast_rays(plane, o, 7.5 * d)
    np.testing.assert_allclose(h2.ranges_m, h.ranges_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(h.points_m, o + h.ranges_m[:, None] * d, atol=1e-6)


def test_satellite_range_in_projected_coordinates_exact():
    """Hard case: 500 km range over EPSG:3413-sized coordinates (|y| ~ 2.5e6 m). Closed form
    (A - h) / cos(theta); float32 embree alone would be off by centimetres to decimetres."""
    x0, y0 = -212_345.678, -2_512_345.678
    t = flat_plane(1234.5, (x0 - 2000, x0 + 2000, y0 - 2000, y0 + 2000), 100.0)
    alt = 500_000.0
    th = np.deg2rad([0.0, 0.1, 0.2])
    o = np.column_stack([x0 - (alt - 1234.5) * np.tan(th), np.full(3, y0), np.full(3, alt)])
    d = np.array([_dir(a) for a in th])
    h = cast_rays(t, o, d)
    np.testing.assert_allclose(h.ranges_m, (alt - 1234.5) / np.cos(th), rtol=0, atol=1e-4)
    np.testing.assert_allclose(h.points_m[:, :2], [[x0, y0]] * 3, rtol=0, atol=1e-4)


def test_sloped_plane_incidence_and_range():
    """Closed form for a plane of slope s through (0, 0, 0) rising along +x and a nadir ray
    from (0, 0, A): range A, incidence s; for the ray at off-nadir theta towards +x,
    range = A cos(s) / cos(theta - s)."""
    s = np.deg2rad(15.0)
    t = sloped_plane(s, 0.0, 0.0, (-500.0, 500.0, -500.0, 500.0), 25.0)
    th = np.deg2rad(5.0)
    o = np.array([[0.0, 0.0, A], [0.0, 0.0, A]])
    h = cast_rays(t, o, np.array([_dir(0.0), _dir(th)]))
    np.testing.assert_allclose(h.ranges_m, [A, A * np.cos(s) / np.cos(th - s)], atol=1e-6)
    np.testing.assert_allclose(h.incidence_rad, [s, s - th], atol=1e-9)


def test_misses_are_inf_and_minus_one_without_nan(plane):
    o = np.array([[0.0, 0.0, A], [5000.0, 0.0, A], [0.0, 0.0, A], [0.0, 0.0, 50.0],
                  [0.0, 0.0, A]])
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0],
                  [0.0, 0.0, -1.0]])
    h = cast_rays(plane, o, d)
    np.testing.assert_array_equal(h.face_index[:4], -1)
    np.testing.assert_array_equal(h.material_codes[:4], -1)
    assert np.all(np.isinf(h.ranges_m[:4])) and np.all(np.isinf(h.incidence_rad[:4]))
    assert np.all(np.isinf(h.points_m[:4]))
    assert h.hit.tolist() == [False, False, False, False, True]
    for arr in (h.ranges_m, h.points_m, h.incidence_rad):
        assert not np.any(np.isnan(arr))


def test_zero_rays_and_bad_rays(plane):
    h = cast_rays(plane, np.zeros((0, 3)), np.zeros((0, 3)))
    assert h.ranges_m.shape == (0,) and h.points_m.shape == (0, 3)
    with pytest.raises(ValueError, match="origins_m"):
        cast_rays(plane, np.zeros((2, 2)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="directions"):
        cast_rays(plane, np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="directions"):
        cast_rays(plane, np.zeros((1, 3)), np.array([[np.nan, 0.0, -1.0]]))
    with pytest.raises(ValueError, match="terrain"):
        cast_rays("mesh.obj", np.zeros((1, 3)), np.array([[0.0, 0.0, -1.0]]))


def test_first_hit_only_two_layers():
    """Two stacked planes (z = 0 and z = 10): a nadir ray from 100 m returns the upper one."""
    a = flat_plane(0.0, (-10.0, 10.0, -10.0, 10.0), 5.0, "rock")
    b = flat_plane(10.0, (-10.0, 10.0, -10.0, 10.0), 5.0, "open_water")
    import trimesh
    m = trimesh.util.concatenate([a.mesh, b.mesh])
    t = Terrain(m, np.concatenate([a.face_materials, b.face_materials]))
    h = cast_rays(t, [[1.0, 2.0, 100.0]], [[0.0, 0.0, -1.0]])
    assert abs(h.ranges_m[0] - 90.0) < 1e-9
    assert h.material_codes[0] == MATERIAL_CODES["open_water"]


# ------------------------------------------------------------------ footprints
def test_subray_weights_and_pattern():
    th_d = 1e-3
    o, d, w = footprint_subrays([[0.0, 0.0, A], [1.0, 1.0, A]], [_dir(0.0), _dir(0.3)], th_d, 64)
    assert o.shape == (128, 3) and d.shape == (128, 3) and w.shape == (2, 64)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    # angle from the beam axis: max exactly theta_d (pattern extent); weight exp(-2 th^2/th_d^2)
    ang = np.arccos(np.clip(d[:64] @ _dir(0.0), -1, 1))
    assert abs(ang.max() - th_d) < 1e-9
    g = np.exp(-2 * ang ** 2 / th_d ** 2)
    np.testing.assert_allclose(w[0], g / g.sum(), rtol=1e-6)
    ang1 = np.arccos(np.clip(d[64:] @ _dir(0.3), -1, 1))
    np.testing.assert_allclose(np.sort(ang1), np.sort(ang), atol=1e-9)
    # deterministic without rng; seeded rotation with rng
    _, d2, _ = footprint_subrays([[0.0, 0.0, A]], [_dir(0.0)], th_d, 64)
    np.testing.assert_array_equal(d2, d[:64])
    _, d3, _ = footprint_subrays([[0.0, 0.0, A]], [_dir(0.0)], th_d, 64,
                                 np.random.default_rng(1))
    _, d4, _ = footprint_subrays([[0.0, 0.0, A]], [_dir(0.0)], th_d, 64,
                                 np.random.default_rng(1))
    np.testing.assert_array_equal(d3, d4)
    assert not np.allclose(d3, d[:64])
    with pytest.raises(ValueError, match="divergence_half_angle_rad"):
        footprint_subrays([[0.0, 0.0, A]], [_dir(0.0)], 0.0, 8)
    with pytest.raises(ValueError, match="n_sub"):
        footprint_subrays([[0.0, 0.0, A]], [_dir(0.0)], th_d, 0)


def test_sloped_plane_footprint_range_spread():
    """Closed form (small footprint): a nadir beam over a plane of slope s sees a range spread
    max - min = tan(s) * d, with d the footprint diameter along the slope. d is taken as the
    sub-ray pattern's extent: the spread of the sub-rays' ground offsets along the slope
    direction at the nadir range (2 R tan(theta_max) for a full ring)."""
    th_d = 2e-3
    n_sub = 400
    for s_deg, az in ((5.0, 0.0), (20.0, 1.0)):
        s = np.deg2rad(s_deg)
        t = sloped_plane(s, az, 0.0, (-200.0, 200.0, -200.0, 200.0), 20.0)
        o = np.array([[0.0, 0.0, A]])
        fr = footprint_statistics(t, o, [_dir(0.0)], th_d, n_sub)
        _, d, _ = footprint_subrays(o, [_dir(0.0)], th_d, n_sub)
        along = (d[:, 0] * np.cos(az) + d[:, 1] * np.sin(az)) / -d[:, 2]
        diameter = A * (along.max() - along.min())
        assert abs(diameter - 2 * A * np.tan(th_d)) / diameter < 0.02   # edge well sampled
        expected = np.tan(s) * diameter
        assert abs(fr.range_spread_m[0] - expected) / expected < 0.05
        assert fr.hit_fraction[0] == pytest.approx(1.0)
        assert fr.incidence_mean_rad[0] == pytest.approx(s, abs=th_d)
        # weighted mean of a symmetric beam on a plane: the nadir range A to first order
        assert fr.range_mean_m[0] == pytest.approx(A, rel=1e-5)
        assert 0 < fr.range_std_m[0] < fr.range_spread_m[0]


def test_footprint_partial_and_full_miss():
    """A beam centred on the edge of a plane hits about half its weight (closed form: 1/2 for a
    symmetric pattern cut through its centre); a beam far away misses entirely."""
    t = flat_plane(0.0, (0.0, 100.0, -50.0, 50.0), 10.0, "rock")
    o = np.array([[0.0, 0.0, A], [50.0, 0.0, A], [1e4, 0.0, A]])
    fr = footprint_statistics(t, o, np.tile(_dir(0.0), (3, 1)), 5e-3, 256)
    assert 0.35 < fr.hit_fraction[0] < 0.65
    assert fr.hit_fraction[1] == pytest.approx(1.0)
    assert fr.hit_fraction[2] == 0.0
    assert fr.material_code.tolist() == [MATERIAL_CODES["rock"]] * 2 + [-1]
    assert np.isinf(fr.range_mean_m[2]) and np.isinf(fr.range_spread_m[2])
    for f in (fr.range_mean_m, fr.range_std_m, fr.range_spread_m, fr.incidence_mean_rad):
        assert not np.any(np.isnan(f))


def test_footprint_majority_material():
    x = np.linspace(-100.0, 100.0, 21)
    codes = np.full((20, 20), MATERIAL_CODES["snow"], dtype=np.int32)
    codes[:, 10:] = MATERIAL_CODES["open_water"]             # x > 0 is water
    t = Terrain.from_heightfield(x, x, np.zeros((21, 21)), codes)
    o = np.array([[-10.0, 0.0, A], [10.0, 0.0, A]])          # beam radius ~ A * 0.03 = 30 m
    fr = footprint_statistics(t, o, np.tile(_dir(0.0), (2, 1)), 0.03, 300)
    assert fr.material_code.tolist() == [MATERIAL_CODES["snow"], MATERIAL_CODES["open_water"]]


# ------------------------------------------------------------------ fallback and bench
def test_fallback_without_embree_warns_once_and_agrees(monkeypatch, plane):
    o = np.array([[0.0, 0.0, A], [5.0, 5.0, A], [0.0, 0.0, A]])
    d = np.array([_dir(0.0), _dir(0.2, 1.0), [0.0, 0.0, 1.0]])
    ref = cast_rays(plane, o, d)
    small = flat_plane(H, (-1000.0, 1000.0, -1000.0, 1000.0), 50.0, "snow")  # fresh cache
    monkeypatch.setattr(raycast, "_embree", None)
    monkeypatch.setattr(raycast, "_fallback_warned", False)
    try:
        import rtree  # noqa: F401  (trimesh's ray_triangle needs it)
    except ImportError:
        with pytest.warns(EmbreeUnavailableWarning), pytest.raises(ImportError, match="rtree"):
            cast_rays(small, o, d)
        return
    with pytest.warns(EmbreeUnavailableWarning, match="embree"):
        h = cast_rays(small, o, d)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EmbreeUnavailableWarning)
        cast_rays(small, o, d)                                 # second call: no warning
    np.testing.assert_allclose(h.ranges_m, ref.ranges_m, atol=1e-9)
    np.testing.assert_array_equal(h.face_index >= 0, ref.face_index >= 0)


def test_bench_raycast_small():
    r = bench_raycast(20_000, 5_000, repeats=1)
    assert {"project_rays_per_s", "embree_rays_per_s", "ratio"} <= set(r)
    assert r["n_triangles"] >= 20_000
    assert r["project_rays_per_s"] > 0 and r["embree_rays_per_s"] > 0
    assert r["hit_fraction"] == 1.0
