"""Terrain construction: files, heightfields with no-data holes, synthetic ice sheet."""

import numpy as np
import pytest
import trimesh

from chirplidar.geometry.raycast import cast_rays
from chirplidar.geometry.synthetic_terrain import (
    flat_plane,
    sloped_plane,
    synthetic_ice_sheet,
    vialov_height,
)
from chirplidar.geometry.terrain import (
    MATERIAL_CODES,
    MATERIAL_NAMES,
    Terrain,
    material_code,
    material_name,
)
from chirplidar.target.materials import MATERIALS


def _nadir(x, y, z0=1e4):
    x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    o = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z0)])
    d = np.tile([0.0, 0.0, -1.0], (x.size, 1))
    return o, d


# ------------------------------------------------------------------ material table
def test_material_table_round_trip_and_names_exist():
    for name in MATERIAL_NAMES:
        assert name in MATERIALS
        assert material_name(material_code(name)) == name
    with pytest.raises(ValueError, match="unknown material"):
        material_code("lava")
    with pytest.raises(ValueError, match="out of range"):
        material_name(99)


# ------------------------------------------------------------------ mesh files
def test_from_mesh_file_round_trip(tmp_path):
    box = trimesh.creation.box(extents=(10.0, 20.0, 5.0))
    for ext in ("stl", "ply", "obj", "glb"):
        p = tmp_path / f"box.{ext}"
        box.export(p)
        t = Terrain.from_mesh_file(p, material="rock")
        assert t.n_faces == 12
        assert np.all(t.face_materials == MATERIAL_CODES["rock"])
        np.testing.assert_allclose(t.mesh.bounds, box.bounds)


def test_from_mesh_file_missing_names_path(tmp_path):
    p = tmp_path / "nope.obj"
    with pytest.raises(FileNotFoundError, match="nope.obj"):
        Terrain.from_mesh_file(p)


def test_from_mesh_file_empty_mesh_names_file(tmp_path):
    p = tmp_path / "empty.obj"
    p.write_text("# nothing here\n")
    with pytest.raises(ValueError, match="empty.obj"):
        Terrain.from_mesh_file(p)
    q = tmp_path / "points.obj"
    q.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")   # vertices but no faces
    with pytest.raises(ValueError, match="points.obj"):
        Terrain.from_mesh_file(q)


def test_from_mesh_file_degenerate_only_names_file(tmp_path):
    p = tmp_path / "degenerate.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")   # collinear: zero area
    with pytest.raises(ValueError, match="degenerate.obj"):
        Terrain.from_mesh_file(p)


def test_terrain_rejects_empty_mesh_and_bad_codes():
    with pytest.raises(ValueError, match="no faces"):
        Terrain(trimesh.Trimesh(), np.zeros(0, dtype=np.int32))
    m = trimesh.creation.box()
    with pytest.raises(ValueError, match="face_materials"):
        Terrain(m, np.zeros(3, dtype=np.int32))
    with pytest.raises(ValueError, match="face_materials"):
        Terrain(m, np.full(12, 99, dtype=np.int32))


# ------------------------------------------------------------------ heightfields
def test_heightfield_triangle_count_and_normals_up():
    x = np.linspace(0.0, 40.0, 5)
    y = np.linspace(0.0, 30.0, 4)
    z = np.zeros((4, 5))
    t = Terrain.from_heightfield(x, y, z, np.zeros((4, 5), dtype=np.int32))
    assert t.n_faces == 2 * 4 * 3        # two triangles per cell
    assert t.holes == 0
    assert np.all(t.mesh.face_normals[:, 2] > 0.999)


def test_heightfield_decreasing_axes_keep_normals_up():
    x = np.linspace(40.0, 0.0, 5)
    y = np.linspace(30.0, 0.0, 4)
    t = Terrain.from_heightfield(x, y, np.zeros((4, 5)), np.zeros((4, 5), dtype=np.int32))
    assert np.all(t.mesh.face_normals[:, 2] > 0.999)


def test_heightfield_nan_holes_leave_cells_out_and_rays_miss():
    x = np.arange(0.0, 101.0, 10.0)   # 11 nodes, 10 cells
    y = np.arange(0.0, 101.0, 10.0)
    z = np.full((11, 11), 50.0)
    z[5, 5] = np.nan                  # one no-data node removes its 4 cells
    t = Terrain.from_heightfield(x, y, z, np.zeros(z.shape, dtype=np.int32))
    assert t.holes == 4
    assert t.n_faces == 2 * (100 - 4)
    assert np.all(np.isfinite(t.mesh.vertices))
    # rays through the hole (cells 40..60 m) miss; rays elsewhere hit at z = 50 exactly
    o, d = _nadir([45.0, 55.0, 15.0, 85.0], [52.0, 47.0, 15.0, 85.0])
    h = cast_rays(t, o, d)
    np.testing.assert_array_equal(h.face_index[:2], [-1, -1])
    assert np.all(np.isinf(h.ranges_m[:2]))
    np.testing.assert_allclose(h.ranges_m[2:], 1e4 - 50.0, atol=1e-6)


def test_heightfield_all_nan_raises_naming_argument():
    x = np.arange(3.0)
    z = np.full((3, 3), np.nan)
    with pytest.raises(ValueError, match="z_m"):
        Terrain.from_heightfield(x, x, z, np.zeros((3, 3), dtype=np.int32))


def test_heightfield_bad_shapes_name_argument():
    x = np.arange(3.0)
    with pytest.raises(ValueError, match="z_m"):
        Terrain.from_heightfield(x, x, np.zeros((2, 3)), np.zeros((2, 3), dtype=np.int32))
    with pytest.raises(ValueError, match="material_codes"):
        Terrain.from_heightfield(x, x, np.zeros((3, 3)), np.zeros((3, 3)))   # float codes
    with pytest.raises(ValueError, match="x_m"):
        Terrain.from_heightfield([0.0, 0.0, 1.0], x, np.zeros((3, 3)),
                                 np.zeros((3, 3), dtype=np.int32))


def test_heightfield_material_majority_and_per_cell():
    x = np.arange(3.0)
    codes_nodes = np.full((3, 3), MATERIAL_CODES["snow"], dtype=np.int32)
    codes_nodes[0, :] = MATERIAL_CODES["rock"]
    codes_nodes[1, 0] = MATERIAL_CODES["rock"]
    t = Terrain.from_heightfield(x, x, np.zeros((3, 3)), codes_nodes)
    # cell (0,0): triangle (00,01,11) has rock,rock,snow -> rock; (00,11,10) rock,snow,rock -> rock
    assert t.face_materials[0] == MATERIAL_CODES["rock"]
    assert t.face_materials[1] == MATERIAL_CODES["rock"]
    cell = np.array([[1, 2], [3, 4]], dtype=np.int32)
    t2 = Terrain.from_heightfield(x, x, np.zeros((3, 3)), cell)
    np.testing.assert_array_equal(t2.face_materials, [1, 1, 2, 2, 3, 3, 4, 4])


def test_from_dem_missing_rasterio_or_file(tmp_path):
    try:
        import rasterio  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match=r"chirplidar\[dem\]"):
            Terrain.from_dem(tmp_path / "dem.tif")
        return
    with pytest.raises(FileNotFoundError, match="dem.tif"):
        Terrain.from_dem(tmp_path / "dem.tif")


def test_flat_and_sloped_planes():
    t = flat_plane(12.5, (0.0, 100.0, 0.0, 50.0), 10.0, "firn")
    np.testing.assert_allclose(t.mesh.vertices[:, 2], 12.5)
    assert np.all(t.face_materials == MATERIAL_CODES["firn"])
    s = np.deg2rad(10.0)
    sp = sloped_plane(s, np.pi / 2, 0.0, (-50.0, 50.0, -50.0, 50.0), 10.0)
    v = sp.mesh.vertices
    np.testing.assert_allclose(v[:, 2], np.tan(s) * v[:, 1], atol=1e-12)   # rises along +y
    with pytest.raises(ValueError, match="resolution_m"):
        flat_plane(0.0, (0.0, 1.0, 0.0, 1.0), 0.0)
    with pytest.raises(ValueError, match="extent_m"):
        flat_plane(0.0, (1.0, 0.0, 0.0, 1.0), 0.1)


# ------------------------------------------------------------------ synthetic ice sheet
KW = {"divide_height_m": 400.0, "margin_x_m": 20_000.0}
EXTENT = (0.0, 23_000.0, -1_500.0, 1_500.0)


def test_synthetic_same_seed_same_mesh_different_seed_differs():
    a = synthetic_ice_sheet(EXTENT, 25.0, np.random.default_rng(7), **KW)
    b = synthetic_ice_sheet(EXTENT, 25.0, np.random.default_rng(7), **KW)
    c = synthetic_ice_sheet(EXTENT, 25.0, np.random.default_rng(8), **KW)
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_array_equal(a.mesh.faces, b.mesh.faces)
    np.testing.assert_array_equal(a.face_materials, b.face_materials)
    assert not np.array_equal(a.mesh.vertices, c.mesh.vertices)


def test_synthetic_materials_include_snow_water_rock():
    t = synthetic_ice_sheet(EXTENT, 25.0, np.random.default_rng(3), **KW)
    present = set(t.face_material_names())
    assert {"snow", "blue_ice", "open_water", "rock"} <= present
    # melt ponds are flat water surfaces: interior water faces are horizontal (shore
    # triangles, with one dry node, take the majority code "open_water" but are tilted)
    water = t.face_materials == MATERIAL_CODES["open_water"]
    flat = np.abs(t.mesh.face_normals[water, 2]) > 1.0 - 1e-12
    assert flat.mean() > 0.5


def test_synthetic_resolution_controls_triangle_count():
    t = synthetic_ice_sheet(EXTENT, 100.0, np.random.default_rng(0), **KW)
    nx, ny = 231, 31       # nodes: 23 km / 100 m + 1, 3 km / 100 m + 1
    assert t.n_faces == 2 * (nx - 1) * (ny - 1)


def test_synthetic_disabling_a_feature_keeps_other_streams():
    # ponds off: crevasses and sastrugi identical (each feature has its own child stream)
    full = synthetic_ice_sheet(EXTENT, 50.0, np.random.default_rng(5), **KW,
                               features=("crevasses", "sastrugi"))
    more = synthetic_ice_sheet(EXTENT, 50.0, np.random.default_rng(5), **KW,
                               features=("sastrugi", "crevasses", "outcrops"))
    v1, v2 = full.mesh.vertices, more.mesh.vertices
    # away from the outcrops (last 10% of L and beyond) the two surfaces coincide
    far = v1[:, 0] < 0.85 * KW["margin_x_m"]
    np.testing.assert_array_equal(v1[far], v2[far])


def test_synthetic_vialov_centre_line_matches_closed_form():
    """Closed form: Vialov (1958) / Cuffey & Paterson (2010) eq. 8.34,
    h = H [1 - (x/L)^(4/3)]^(3/8). The mesh is the piecewise-linear interpolant of the profile,
    so between nodes |mesh - h| <= dx^2/8 max|h''| over the cell (linear interpolation bound)."""
    H, L, dx = KW["divide_height_m"], KW["margin_x_m"], 50.0
    t = synthetic_ice_sheet(EXTENT, dx, np.random.default_rng(0), **KW, features=())
    xs = np.linspace(10.0, 0.95 * L, 400)          # nodes and in-between points, centre line
    o, d = _nadir(xs, np.zeros_like(xs))
    h = cast_rays(t, o, d)
    z_mesh = h.points_m[:, 2]
    z_true = vialov_height(xs, H, L)
    # interpolation bound from the closed form's curvature on each cell (fine differences)
    xf = np.linspace(0.0, L * 0.96, 200_001)
    hf = vialov_height(xf, H, L)
    curv = np.abs(np.gradient(np.gradient(hf, xf), xf))
    cell = np.floor(xs / dx).astype(int)
    cmax = np.array([curv[(xf >= c * dx) & (xf <= (c + 1) * dx)].max() for c in cell])
    bound = dx ** 2 / 8.0 * cmax + 1e-6
    assert np.all(np.abs(z_mesh - z_true) <= bound)
    # at grid nodes the mesh is the closed form itself
    xn = np.arange(100.0, 0.9 * L, dx)
    o, d = _nadir(xn, np.zeros_like(xn))
    np.testing.assert_allclose(cast_rays(t, o, d).points_m[:, 2], vialov_height(xn, H, L),
                               atol=1e-6)
    # beyond the margin: ice-free rock at 0 m
    o, d = _nadir([21_500.0], [0.0])
    hh = cast_rays(t, o, d)
    assert hh.material_codes[0] == MATERIAL_CODES["rock"]
    assert abs(hh.points_m[0, 2]) < 1e-9


def test_synthetic_bad_arguments():
    with pytest.raises(ValueError, match="rng"):
        synthetic_ice_sheet(EXTENT, 100.0, 42, **KW)
    with pytest.raises(ValueError, match="features"):
        synthetic_ice_sheet(EXTENT, 100.0, np.random.default_rng(0), **KW, features=("lava",))
    with pytest.raises(ValueError, match="divide_height_m"):
        synthetic_ice_sheet(EXTENT, 100.0, np.random.default_rng(0), divide_height_m=-1.0,
                            margin_x_m=1e4)


# ------------------------------------------------------------------ DEM no-data modes
def _dem(path, z, nodata=-9999.0):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    with rasterio.open(path, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1,
                       dtype="float64", crs="EPSG:3413", nodata=nodata,
                       transform=Affine(10.0, 0.0, 1000.0, 0.0, -10.0, 5000.0)) as dst:
        dst.write(z, 1)


def test_from_dem_nodata_modes(tmp_path):
    z = np.arange(6 * 7, dtype=np.float64).reshape(6, 7)
    z[2, 3] = -9999.0                      # the raster's nodata value
    z[4, 5] = np.nan                       # NaN is no-data too
    p = tmp_path / "dem.tif"
    _dem(p, z)
    with pytest.raises(ValueError, match=r"dem\.tif has 2 no-data pixels .* rows 2\.\.4, "
                       r"columns 3\.\.5"):
        Terrain.from_dem(p, nodata="error")
    holes = Terrain.from_dem(p)            # default: holes, as before
    assert holes.holes == 8                # two isolated pixels, 4 cells each
    filled = Terrain.from_dem(p, nodata="fill")
    assert filled.holes == 0 and filled.n_faces == 2 * 5 * 6
    v = filled.mesh.vertices
    node = v[(np.abs(v[:, 0] - 1035.0) < 1e-9) & (np.abs(v[:, 1] - 4975.0) < 1e-9)]
    # the nearest valid pixels of (2, 3) are its four neighbours; EDT picks one of them
    assert node[0, 2] in {z[1, 3], z[3, 3], z[2, 2], z[2, 4]}
    with pytest.raises(ValueError, match="nodata must be one of"):
        Terrain.from_dem(p, nodata="zero")
    with pytest.raises(ValueError, match="band 2 does not exist"):
        Terrain.from_dem(p, band=2)


def test_heightfield_functions_match_terrain_builders():
    from chirplidar.geometry.synthetic_terrain import synthetic_ice_sheet_heightfield

    x, y, z, codes = synthetic_ice_sheet_heightfield(EXTENT, 200.0, np.random.default_rng(2),
                                                     **KW)
    t = synthetic_ice_sheet(EXTENT, 200.0, np.random.default_rng(2), **KW)
    np.testing.assert_array_equal(Terrain.from_heightfield(x, y, z, codes).mesh.vertices,
                                  t.mesh.vertices)


def test_synthetic_outcrop_band_places_rock():
    # outcrops only in 0.2-0.3 L from the divide, tall enough to rise through the ice there
    t = synthetic_ice_sheet(EXTENT, 50.0, np.random.default_rng(1), **KW, features=("outcrops",),
                            outcrop_band=(0.2, 0.3), outcrop_height_m=(900.0, 1000.0),
                            outcrop_radius_m=(300.0, 400.0))
    c = t.mesh.triangles_center
    rock = (t.face_materials == MATERIAL_CODES["rock"]) & (c[:, 0] < 0.9 * KW["margin_x_m"])
    assert rock.any()
    assert np.all(np.abs(c[rock, 0] - 0.25 * KW["margin_x_m"]) < 0.05 * KW["margin_x_m"] + 800)
    with pytest.raises(ValueError, match="outcrop_band"):
        synthetic_ice_sheet(EXTENT, 100.0, np.random.default_rng(0), **KW, outcrop_band=(0.5, 0.4))
