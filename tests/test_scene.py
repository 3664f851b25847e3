"""Scene files: schema validation, terrain sources, cache, materials and atmosphere."""

from __future__ import annotations

import math
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from chirplidar.atmosphere.turbulence import fried_parameter
from chirplidar.config.loader import ConfigError
from chirplidar.geometry import synthetic_terrain
from chirplidar.geometry.frames import geodetic_to_projected, projected_to_geodetic
from chirplidar.geometry.terrain import MATERIAL_CODES, MATERIAL_NAMES
from chirplidar.mission import scene_terrain
from chirplidar.mission.scene import load_scene, scene_from_text
from chirplidar.mission.scene_terrain import TerrainCacheWarning
from chirplidar.target.materials import MATERIALS

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"

ATMOSPHERE = """
[atmosphere]
cn2_profile = "none"
extinction_per_m = 1e-5
scale_height_m = 1200.0
"""


def flat_text(*, height=123.25, extra="", atmosphere=ATMOSPHERE, top="", material="firn",
              size=("200.0", "100.0"), resolution="10.0"):
    return textwrap.dedent(f"""\
        name = "flat test"
        epsg = 3413
        effects = []
        {top}
        [terrain]
        source = "flat"
        center_x_m = -200000.0
        center_y_m = -2500000.0
        size_x_m = {size[0]}
        size_y_m = {size[1]}
        resolution_m = {resolution}
        {extra}
        [terrain.flat]
        height_m = {height}
        material = "{material}"
        """) + atmosphere


def write(tmp_path, text, name="scene.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def synthetic_text(resolution=50.0, seed=3):
    return textwrap.dedent(f"""\
        name = "small synthetic"
        epsg = 3413
        effects = ["speckle"]
        [terrain]
        source = "synthetic"
        center_lat_deg = 69.1
        center_lon_deg = -49.5
        size_x_m = 3000.0
        size_y_m = 1000.0
        resolution_m = {resolution}
        seed = {seed}
        [terrain.synthetic]
        divide_height_m = 600.0
        base_height_m = 300.0
        margin_x_m = -1000.0
        divide_x_m = 349000.0
        """) + ATMOSPHERE


# ------------------------------------------------------------------ shipped scenes
@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    cache = tmp_path_factory.mktemp("terrain-cache")
    return {name: load_scene(SCENES / f"{name}.toml", cache_dir=cache)
            for name in ("greenland_outlet", "antarctic_margin")}


@pytest.mark.parametrize("name, epsg, lat, lon", [
    ("greenland_outlet", 3413, 67.10, -50.05),
    ("antarctic_margin", 3031, -67.75, 62.90),
])
def test_shipped_scenes_frame_and_bounds(shipped, name, epsg, lat, lon):
    s = shipped[name]
    cfg = s.config.terrain
    assert s.epsg == epsg
    assert s.path.name == f"{name}.toml" and s.text.startswith("#")
    # the centre round-trips through pyproj within 1 m
    cx, cy = s.center_xy_m
    x, y, _ = geodetic_to_projected(lat, lon, 0.0, epsg)
    assert math.hypot(float(x) - cx, float(y) - cy) < 1e-6
    lat2, lon2, _ = projected_to_geodetic(cx, cy, 0.0, epsg)
    north = (float(lat2) - lat) * 111_000.0
    east = (float(lon2) - lon) * 111_000.0 * math.cos(math.radians(lat))
    assert math.hypot(north, east) < 1.0
    # the grid is centred on the centre with the configured size
    x0, x1, y0, y1 = s.bounds_xy
    assert x1 - x0 == pytest.approx(cfg.size_x_m, abs=1e-6)
    assert y1 - y0 == pytest.approx(cfg.size_y_m, abs=1e-6)
    assert ((x0 + x1) / 2, (y0 + y1) / 2) == pytest.approx((cx, cy), abs=1e-6)
    z0, z1 = s.height_range_m
    assert z0 == pytest.approx(cfg.synthetic.base_height_m)   # the ice-free ground
    assert z1 > z0 + 100.0


def test_shipped_greenland_materials_and_effects(shipped):
    s = shipped["greenland_outlet"]
    present = set(s.terrain.face_material_names())
    assert {"snow", "blue_ice", "open_water", "rock"} <= present
    assert s.effects == ("speckle",)
    assert s.terrain.n_faces == 2 * 1200 * 800          # 6 km x 4 km at 5 m
    assert shipped["antarctic_margin"].effects == ("speckle", "doppler")
    assert s.config.atmosphere.cn2_profile == "hufnagel_valley"


# ------------------------------------------------------------------ flat scene, ground height
def test_flat_ground_height_exact_and_nan_off_terrain(tmp_path):
    s = load_scene(write(tmp_path, flat_text()), cache_dir=tmp_path / "c")
    x0, x1, y0, y1 = s.bounds_xy
    assert (x0, x1, y0, y1) == pytest.approx((-200100.0, -199900.0, -2500050.0, -2499950.0))
    xs = np.array([[-200050.3, -199999.0], [-199901.0, -200099.9]])
    ys = np.array([[-2500000.0, -2500049.0], [-2499951.0, -2500010.0]])
    h = s.ground_height_m(xs, ys)
    assert h.shape == (2, 2)
    np.testing.assert_allclose(h, 123.25, rtol=0, atol=1e-9)
    # the outer edges and corners belong to the terrain
    edges = s.ground_height_m([x0, x1, x0, x1, x0], [y0, y1, y1, y0, -2500000.0])
    np.testing.assert_allclose(edges, 123.25, rtol=0, atol=1e-9)
    off = s.ground_height_m([-200200.0, -199000.0, np.nan], [-2500000.0, -2500000.0, 0.0])
    assert np.all(np.isnan(off))
    assert s.ground_height_m(-200000.0, -2500000.0).shape == ()


def test_sloped_scene_compass_azimuth(tmp_path):
    text = flat_text().replace('source = "flat"', 'source = "sloped"').replace(
        "[terrain.flat]\nheight_m = 123.25", "[terrain.sloped]\nslope_deg = 5.0\n"
        "azimuth_deg = 0.0\nheight_m = 50.0")
    s = load_scene(write(tmp_path, text), cache_dir=tmp_path / "c")
    cx, cy = s.center_xy_m
    h = s.ground_height_m([cx, cx, cx + 30.0], [cy, cy + 40.0, cy])
    # uphill towards grid north (+y): rises with y, flat along x
    np.testing.assert_allclose(h, [50.0, 50.0 + 40.0 * math.tan(math.radians(5.0)), 50.0],
                               atol=1e-9)


# ------------------------------------------------------------------ atmosphere
def test_transmission_closed_forms(tmp_path):
    s = load_scene(write(tmp_path, flat_text()), cache_dir=tmp_path / "c")
    a0, big_h = 1e-5, 1200.0
    lo = np.array([0.0, 100.0, 500.0])
    hi = np.array([3000.0, 700.0, 500e3])
    zen = np.array([0.0, 0.3, 0.5])
    tau = a0 * big_h * (np.exp(-lo / big_h) - np.exp(-hi / big_h)) / np.cos(zen)
    np.testing.assert_allclose(s.one_way_power_transmission(lo, hi, zen), np.exp(-tau),
                               rtol=1e-13)
    # order of the heights does not matter; broadcasting
    np.testing.assert_allclose(s.one_way_power_transmission(hi, lo, zen), np.exp(-tau),
                               rtol=1e-13)
    assert s.one_way_power_transmission(0.0, [10.0, 20.0], 0.0).shape == (2,)
    # short path at h = 0: Beer-Lambert exp(-alpha0 L) with L = dh / cos z, error ~ dh / 2H
    dh, z = 1e-3, 1.2
    length = dh / math.cos(z)
    t = s.one_way_power_transmission(0.0, dh, z)
    assert float(t) == pytest.approx(math.exp(-a0 * length), rel=1e-15)
    assert -math.log(float(t)) == pytest.approx(a0 * length, rel=dh / big_h)
    # uniform atmosphere (H = inf): Beer-Lambert over the whole slant path
    uni = flat_text(atmosphere=ATMOSPHERE.replace("1200.0", "inf"))
    s_uni = scene_from_text(uni, base_dir=tmp_path, cache_dir=tmp_path / "c")
    assert float(s_uni.one_way_power_transmission(100.0, 2100.0, 0.4)) == pytest.approx(
        math.exp(-a0 * 2000.0 / math.cos(0.4)), rel=1e-14)
    # zero extinction: transmission exactly 1
    clear = flat_text(atmosphere=ATMOSPHERE.replace("1e-5", "0.0"))
    s0 = scene_from_text(clear, base_dir=tmp_path, cache_dir=tmp_path / "c")
    np.testing.assert_array_equal(s0.one_way_power_transmission(lo, hi, zen), 1.0)
    with pytest.raises(ValueError, match="zenith_rad"):
        s.one_way_power_transmission(0.0, 10.0, math.pi / 2)


def test_fried_parameter_profiles(tmp_path):
    none = scene_from_text(flat_text(), base_dir=tmp_path, cache_dir=tmp_path / "c")
    r0 = none.fried_parameter_m(1.31e-6, 0.0, [100.0, 1000.0], 0.2)
    assert r0.shape == (2,) and np.all(np.isinf(r0))
    const = flat_text(atmosphere='\n[atmosphere]\ncn2_profile = "constant"\n'
                      'cn2_m_minus_2_3 = 1e-15\nextinction_per_m = 0.0\nscale_height_m = 1e3\n')
    s = scene_from_text(const, base_dir=tmp_path, cache_dir=tmp_path / "c")
    # vertical path: the slant length is the height difference; constant Cn2 closed form
    r0 = s.fried_parameter_m(1.31e-6, [100.0, 200.0], [600.0, 700.0], 0.0)
    ref = fried_parameter(1e-15, 1.31e-6, 500.0, wave="spherical")
    np.testing.assert_allclose(r0, ref, rtol=1e-6)
    hv = scene_from_text((SCENES / "greenland_outlet.toml").read_text().replace(
        "resolution_m = 5.0", "resolution_m = 200.0"), base_dir=SCENES,
        cache_dir=tmp_path / "c")
    # plane wave: every layer counts fully, so a longer path has the smaller r0
    r_short, r_long = hv.fried_parameter_m(1.31e-6, 400.0, [500.0, 5000.0], 0.0, wave="plane")
    assert 0 < r_long < r_short < np.inf
    # spherical wave from the lit spot (source "low", the return): the strong ground layer sits
    # next to the source, where it hardly decorrelates the wave; from the platform ("high") it
    # sits next to the receiver and counts fully
    up = hv.fried_parameter_m(1.31e-6, 400.0, 5000.0, 0.0)
    down = hv.fried_parameter_m(1.31e-6, 400.0, 5000.0, 0.0, source="high")
    assert 0 < down < up < np.inf
    with pytest.raises(ValueError, match="h_high_m"):
        hv.fried_parameter_m(1.31e-6, 500.0, 500.0, 0.0)


# ------------------------------------------------------------------ materials
def test_material_reflectivity_table_and_overrides(tmp_path):
    wl = 1.31e-6
    s = scene_from_text(flat_text(), base_dir=tmp_path, cache_dir=tmp_path / "c")
    r = s.material_reflectivity(wl)
    assert r.shape == (len(MATERIAL_NAMES),)
    for code, name in enumerate(MATERIAL_NAMES):
        assert r[code] == pytest.approx(float(MATERIALS[name].reflectivity_at(wl)))
    spec = s.material_specular()
    assert spec.dtype == bool
    assert spec[MATERIAL_CODES["open_water"]] and not spec[MATERIAL_CODES["snow"]]

    over = flat_text(top='', atmosphere=ATMOSPHERE + textwrap.dedent("""
        [materials.snow]
        reflectivity = 0.3
        [materials.open_water]
        scattering = "lambertian"
        """))
    s2 = scene_from_text(over, base_dir=tmp_path, cache_dir=tmp_path / "c")
    r2 = s2.material_reflectivity(wl)
    assert r2[MATERIAL_CODES["snow"]] == 0.3
    assert r2[MATERIAL_CODES["firn"]] == r[MATERIAL_CODES["firn"]]
    assert not s2.material_specular()[MATERIAL_CODES["open_water"]]
    # thesis_target is tabulated at 1310 nm only: unused -> NaN at 1550 nm, used -> error
    r3 = s.material_reflectivity(1.55e-6)
    assert np.isnan(r3[MATERIAL_CODES["thesis_target"]])
    assert np.isfinite(r3[MATERIAL_CODES["firn"]])
    target = scene_from_text(flat_text(material="thesis_target"), base_dir=tmp_path,
                             cache_dir=tmp_path / "c")
    with pytest.raises(ValueError, match="thesis_target"):
        target.material_reflectivity(1.55e-6)


# ------------------------------------------------------------------ bad inputs
def _mesh_text(path, coordinates="projected", centre=""):
    return textwrap.dedent(f"""\
        name = "mesh test"
        epsg = 3031
        effects = ["doppler"]
        [terrain]
        source = "mesh"
        {centre}
        [terrain.mesh]
        path = "{path}"
        material = "rock"
        coordinates = "{coordinates}"
        """) + ATMOSPHERE


def test_missing_mesh_file_names_file_and_key(tmp_path):
    p = write(tmp_path, _mesh_text("meshes/y.ply"), "x.toml")
    with pytest.raises(ConfigError) as exc:
        load_scene(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}: terrain.mesh.path: file meshes/y.ply does not exist")


@pytest.mark.parametrize("content, suffix", [
    (("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n"), "ply"),
    ("# nothing\n", "obj"),
    ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "obj"),   # a degenerate (zero-area) face only
])
def test_mesh_without_faces(tmp_path, content, suffix):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / f"empty.{suffix}").write_text(content)
    p = write(tmp_path, _mesh_text(f"meshes/empty.{suffix}"))
    with pytest.raises(ConfigError, match=rf"scene.toml: terrain\.mesh\.path: .*empty\.{suffix} "
                       r"has no faces"):
        load_scene(p)


def test_mesh_coordinates_projected_and_scene_centre(tmp_path):
    box = trimesh.creation.box(extents=(100.0, 60.0, 10.0))
    box.apply_translation([0.0, 0.0, 200.0])
    box.export(tmp_path / "local.ply")
    local = load_scene(write(tmp_path, _mesh_text(
        "local.ply", "scene_centre", "center_x_m = 1500000.0\ncenter_y_m = 800000.0"), "a.toml"))
    assert local.bounds_xy == pytest.approx((1499950.0, 1500050.0, 799970.0, 800030.0))
    assert float(local.ground_height_m(1500000.0, 800000.0)) == pytest.approx(205.0)
    assert np.all(local.terrain.face_materials == MATERIAL_CODES["rock"])
    absolute = load_scene(write(tmp_path, _mesh_text("local.ply"), "b.toml"))
    assert absolute.bounds_xy == pytest.approx((-50.0, 50.0, -30.0, 30.0))
    assert absolute.center_xy_m == pytest.approx((0.0, 0.0))
    with pytest.raises(ConfigError, match=r"terrain\.center_lat_deg: missing"):
        load_scene(write(tmp_path, _mesh_text("local.ply", "scene_centre"), "c.toml"))
    with pytest.raises(ConfigError, match=r"terrain\.center_x_m: not used"):
        load_scene(write(tmp_path, _mesh_text("local.ply", "projected",
                                              "center_x_m = 1.0\ncenter_y_m = 2.0"), "d.toml"))


# DEM: 8 rows x 10 columns of 10 m pixels in EPSG:3413; z = 100 + 2 col + 50 row
DEM_WEST, DEM_NORTH, DEM_RES = -200000.0, -2500000.0, 10.0


def _write_dem(path, block, *, epsg=3413, nan=False):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    rows, cols = np.mgrid[0:8, 0:10]
    z = (100.0 + 2.0 * cols + 50.0 * rows).astype(np.float32)
    z[block] = np.nan if nan else -9999.0
    with rasterio.open(path, "w", driver="GTiff", height=8, width=10, count=1,
                       dtype="float32", crs=f"EPSG:{epsg}", nodata=-9999.0,
                       transform=Affine(DEM_RES, 0.0, DEM_WEST, 0.0, -DEM_RES, DEM_NORTH)
                       ) as dst:
        dst.write(z, 1)
    return z


def _dem_text(nodata=None):
    line = f'nodata = "{nodata}"' if nodata else ""
    return textwrap.dedent(f"""\
        name = "dem test"
        epsg = 3413
        effects = []
        [terrain]
        source = "dem"
        [terrain.dem]
        path = "dem/small.tif"
        material = "snow"
        {line}
        """) + ATMOSPHERE


def _pixel_xy(row, col):
    return DEM_WEST + (col + 0.5) * DEM_RES, DEM_NORTH - (row + 0.5) * DEM_RES


def test_dem_nodata_error_by_default(tmp_path):
    (tmp_path / "dem").mkdir()
    _write_dem(tmp_path / "dem" / "small.tif", (slice(3, 6), slice(4, 7)))
    p = write(tmp_path, _dem_text())
    with pytest.raises(ConfigError) as exc:
        load_scene(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}: terrain.dem.nodata: ")
    assert "small.tif" in msg and "9 no-data pixels" in msg
    assert "rows 3..5" in msg and "columns 4..6" in msg
    x0, _ = _pixel_xy(0, 4)
    x1, _ = _pixel_xy(0, 6)
    assert f"x {x0:.3f}..{x1:.3f} m" in msg


def test_dem_nodata_holes_and_fill(tmp_path):
    (tmp_path / "dem").mkdir()
    z = _write_dem(tmp_path / "dem" / "small.tif", (slice(3, 6), slice(4, 7)), nan=True)
    holes = load_scene(write(tmp_path, _dem_text("holes")))
    assert holes.terrain.holes == 16          # a 3x3 pixel block touches 4x4 cells
    assert holes.terrain.n_faces == 2 * (7 * 9 - 16)
    assert np.isnan(holes.ground_height_m(*_pixel_xy(4, 5)))
    assert float(holes.ground_height_m(*_pixel_xy(1, 1))) == pytest.approx(z[1, 1])
    assert holes.center_xy_m == pytest.approx((DEM_WEST + 50.0, DEM_NORTH - 40.0))

    # fill: a no-data top row takes the heights of the row below (its nearest valid pixels),
    # so the first row of cells is level across y (probed 1 m inside the raster's edge)
    _write_dem(tmp_path / "dem" / "small.tif", (slice(0, 1), slice(None)))
    filled = load_scene(write(tmp_path, _dem_text("fill")))
    assert filled.terrain.holes == 0
    for col in (0, 1, 4, 8, 9):
        x, y = _pixel_xy(0, col)
        assert float(filled.ground_height_m(x, y - 1.0)) == pytest.approx(z[1, col], abs=1e-9)
        assert float(filled.ground_height_m(x, y)) == pytest.approx(z[1, col], abs=1e-9)
    top = filled.terrain.mesh.vertices
    top = top[np.abs(top[:, 1] - _pixel_xy(0, 0)[1]) < 1e-6]
    np.testing.assert_allclose(np.sort(top[:, 2]), np.sort(z[1]), atol=1e-9)


def test_dem_crs_must_match_scene(tmp_path):
    (tmp_path / "dem").mkdir()
    _write_dem(tmp_path / "dem" / "small.tif", (slice(0, 0), slice(0, 0)), epsg=3031)
    with pytest.raises(ConfigError, match=r"terrain\.dem\.path: .*EPSG:3031.*EPSG:3413"):
        load_scene(write(tmp_path, _dem_text()))


def test_unknown_key_with_close_match(tmp_path):
    p = write(tmp_path, flat_text(extra="resolution = 5.0").replace(
        "height_m = 123.25", "heigth_m = 123.25"))
    with pytest.raises(ConfigError) as exc:
        load_scene(p)
    msg = str(exc.value)
    assert "; terrain.resolution: unknown key (did you mean: terrain.resolution_m" in msg
    assert "terrain.flat.heigth_m: unknown key (did you mean: terrain.flat.height_m," in msg
    assert f"{p}: missing key terrain.flat.height_m; " in msg
    bad = write(tmp_path, flat_text(atmosphere=ATMOSPHERE + "[materials.snow]\nreflectance = 1\n"))
    with pytest.raises(ConfigError, match=r"materials\.snow\.reflectance: unknown key \(did you "
                       r"mean: materials\.snow\.reflectivity"):
        load_scene(bad)


def test_unknown_effect_material_and_epsg(tmp_path):
    p = write(tmp_path, flat_text().replace("effects = []", 'effects = ["speckle", "lava"]'))
    with pytest.raises(ConfigError, match=rf"{p}: effects: unknown effect\(s\) \['lava'\]; "
                       r"known: phase_noise, speckle, doppler, coupling, turbulence"):
        load_scene(p)
    p = write(tmp_path, flat_text(material="lava"))
    with pytest.raises(ConfigError, match=rf"{p}: terrain\.flat\.material: unknown material "
                       r"'lava'; known: snow, firn"):
        load_scene(p)
    p = write(tmp_path, flat_text(atmosphere=ATMOSPHERE + "[materials.lava]\nreflectivity = 0.1\n"))
    with pytest.raises(ConfigError, match=rf"{p}: materials\.lava: unknown material; known: "
                       r"snow, firn"):
        load_scene(p)
    p = write(tmp_path, flat_text().replace("epsg = 3413", "epsg = 4326"))
    with pytest.raises(ConfigError, match=rf"{p}: epsg: must be one of 3413 .*3031 .*got 4326"):
        load_scene(p)


def test_inconsistent_sections_name_the_key(tmp_path):
    cases = [
        (flat_text().replace('source = "flat"', 'source = "sloped"'),
         r"terrain\.sloped: missing section"),
        (flat_text(extra="seed = 1"), r"terrain\.seed: not used"),
        (flat_text().replace("resolution_m = 10.0", ""), r"terrain\.resolution_m: missing"),
        (flat_text().replace("center_y_m = -2500000.0", ""), r"terrain\.center_y_m: missing"),
        (flat_text(atmosphere=ATMOSPHERE.replace('"none"', '"hufnagel_valley"')),
         r"atmosphere\.ground_cn2_m_minus_2_3: missing"),
        (flat_text(atmosphere=ATMOSPHERE.replace("1e-5", "-1e-5")),
         r"atmosphere\.extinction_per_m: Input should be greater than or equal to 0"),
        (synthetic_text().replace("margin_x_m = -1000.0", "margin_x_m = 349000.0"),
         r"terrain\.synthetic\.margin_x_m: must differ from divide_x_m"),
        (synthetic_text().replace("center_lat_deg = 69.1", "center_lat_deg = -69.1"),
         r"terrain\.center_lat_deg: -69\.1 deg is outside EPSG:3413"),
        ("name = 'x'\nepsg = 3413\neffects = [\n", r"not valid TOML"),
        # a centre no projected frame holds (it made the grid's coordinates all equal)
        (flat_text().replace("-200000.0", "1e30"), r"terrain\.center_x_m: .*less than or "
         r"equal to 20000000"),
    ]
    for i, (text, pattern) in enumerate(cases):
        p = write(tmp_path, text, f"case{i}.toml")
        with pytest.raises(ConfigError, match=rf"case{i}\.toml: {pattern}"):
            load_scene(p, cache_dir=tmp_path / "c")


# ------------------------------------------------------------------ synthetic, overrides, text
def test_synthetic_scene_overrides_and_rebuild_from_text(tmp_path):
    p = write(tmp_path, synthetic_text())
    s = load_scene(p, cache_dir=tmp_path / "c", overrides=["terrain.resolution_m=100"])
    assert s.terrain.n_faces == 2 * 30 * 10
    assert s.overrides == (("terrain.resolution_m", 100),)
    base = s.config.terrain.synthetic.base_height_m
    # beyond the margin: ice-free rock at the base height
    cx, cy = s.center_xy_m
    assert float(s.ground_height_m(cx - 1200.0, cy)) == pytest.approx(base)
    again = scene_from_text(s.text, base_dir=tmp_path, overrides=dict(s.overrides),
                            use_cache=False)
    np.testing.assert_array_equal(again.terrain.mesh.vertices, s.terrain.mesh.vertices)
    np.testing.assert_array_equal(again.terrain.face_materials, s.terrain.face_materials)
    with pytest.raises(ConfigError, match=r"terrain\.resolutionm: unknown key \(did you mean: "
                       r"terrain\.resolution_m"):
        load_scene(p, cache_dir=tmp_path / "c", overrides={"terrain.resolutionm": 10})


# ------------------------------------------------------------------ cache
def test_second_load_reads_cache(tmp_path, monkeypatch):
    p = write(tmp_path, synthetic_text())
    cache = tmp_path / "cache"
    first = load_scene(p, cache_dir=cache)
    assert not first.cache_hit and first.cache_file is not None and first.cache_file.is_file()
    assert list(cache.glob("*.tmp")) == []      # the atomic write left no temporary file

    def fail(*args, **kwargs):
        raise AssertionError("the generator ran although the heightfield is cached")

    monkeypatch.setattr(synthetic_terrain, "synthetic_ice_sheet_heightfield", fail)
    second = load_scene(p, cache_dir=cache)
    assert second.cache_hit and second.cache_file == first.cache_file
    np.testing.assert_array_equal(second.terrain.mesh.vertices, first.terrain.mesh.vertices)
    np.testing.assert_array_equal(second.terrain.face_materials, first.terrain.face_materials)
    # a different seed is a different cache entry: it must generate (and here fails)
    with pytest.raises(AssertionError, match="generator ran"):
        load_scene(write(tmp_path, synthetic_text(seed=4), "other.toml"), cache_dir=cache)


def test_corrupt_cache_is_regenerated_with_warning(tmp_path):
    p = write(tmp_path, synthetic_text())
    cache = tmp_path / "cache"
    first = load_scene(p, cache_dir=cache)
    first.cache_file.write_bytes(b"not a zip file")
    with pytest.warns(TerrainCacheWarning, match="unreadable"):
        again = load_scene(p, cache_dir=cache)
    assert not again.cache_hit
    np.testing.assert_array_equal(again.terrain.mesh.vertices, first.terrain.mesh.vertices)
    with warnings.catch_warnings():
        warnings.simplefilter("error")            # rewritten: the next load is a clean hit
        assert load_scene(p, cache_dir=cache).cache_hit


def test_cache_dir_default_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("CHIRPLIDAR_CACHE", str(tmp_path / "env-cache"))
    assert scene_terrain.default_cache_dir() == tmp_path / "env-cache"
    s = load_scene(write(tmp_path, flat_text()))
    assert s.cache_file.parent == tmp_path / "env-cache"
    assert load_scene(write(tmp_path, flat_text())).cache_hit
    assert not load_scene(write(tmp_path, flat_text()), use_cache=False).cache_hit


def test_specular_slopes_required_and_given(tmp_path, shipped):
    assert shipped["greenland_outlet"].water_mss() == pytest.approx(0.003 + 5.12e-3 * 3.0)
    mss = shipped["antarctic_margin"].material_mss()
    assert np.isnan(mss[MATERIAL_CODES["snow"]])
    # a terrain with open water but no slopes is refused, naming the key
    p = write(tmp_path, flat_text(material="open_water"))
    with pytest.raises(ConfigError, match=rf"{p}: materials\.open_water\.wind_speed_mps: missing"):
        load_scene(p, cache_dir=tmp_path / "c")
    ok = flat_text(material="open_water", atmosphere=ATMOSPHERE + "[materials.open_water]\n"
                   "mean_square_slope = 0.0\n")
    assert scene_from_text(ok, base_dir=tmp_path, use_cache=False).water_mss() == 0.0
    # slopes on a Lambertian material make no sense
    bad = write(tmp_path, flat_text(atmosphere=ATMOSPHERE + "[materials.snow]\n"
                                    "wind_speed_mps = 3.0\n"), "bad.toml")
    with pytest.raises(ConfigError, match=r"materials\.snow\.wind_speed_mps: only for specular"):
        load_scene(bad)
