"""Heightfield terrains keep their grid: direct surface heights and cropped ray casting.

References: the ray cast on the very same triangles without the grid (``Terrain(mesh, codes)``:
a plain mesh, cast on the whole of it) and closed forms (node heights, linear edges).
"""

import numpy as np
import pytest

from chirplidar.geometry import raycast
from chirplidar.geometry.raycast import cast_rays
from chirplidar.geometry.synthetic_terrain import flat_plane
from chirplidar.geometry.terrain import HeightGrid, Terrain


def _mesh_only(t: Terrain) -> Terrain:
    """The same triangles and materials as a plain mesh: ray casting on the whole mesh."""
    return Terrain(t.mesh, t.face_materials, t.material_names, t.holes)


# The ray cast's plane offsets n.v0 and n.o cancel at |y| ~ 2.5e6 m (EPSG:3413 northings):
# ~1e-9 m of rounding; the direct heights work in the cell's own coordinates.
ATOL_M = 1e-8


def _vertical_cast(t: Terrain, x, y):
    top = float(t.bounds[1, 2]) + 10.0
    o = np.column_stack([x, y, np.full(x.size, top)])
    h = cast_rays(t, o, np.tile([0.0, 0.0, -1.0], (x.size, 1)))
    return np.where(h.hit, top - h.ranges_m, np.nan)


def _rough(nx=41, ny=31, seed=0, holes=False, descending=False, uniform=False):
    """A rough heightfield on an uneven grid (steps differ; ``uniform``: 5 m x 4 m steps),
    optionally with no-data nodes."""
    rng = np.random.default_rng(seed)
    x = 1000.0 + np.cumsum(rng.uniform(2.0, 8.0, nx))
    y = -2.5e6 + np.cumsum(rng.uniform(2.0, 8.0, ny))
    if uniform:
        x, y = 1000.0 + 5.0 * np.arange(nx), -2.5e6 + 4.0 * np.arange(ny)
    z = 300.0 + rng.normal(0.0, 3.0, (ny, nx)) + 0.05 * x[None, :]
    codes = rng.integers(0, 5, (ny, nx)).astype(np.int32)
    if holes:
        z[5, 7] = np.nan                  # a single no-data node: 4 cells out
        z[12:15, 20:24] = np.nan          # a block
        z[:, 0] = np.nan                  # the whole first column (outer edge)
    if descending:
        return x[::-1], y[::-1], z[::-1, ::-1], codes[::-1, ::-1]
    return x, y, z, codes


def _points(x, y, n, rng):
    """Random points, points on node lines, nodes, cell diagonals, the outer boundary and
    points off the grid."""
    xs = [rng.uniform(x[0] - 5, x[-1] + 5, n),
          np.repeat(x, 3), rng.choice(x, n)]
    ys = [rng.uniform(y[0] - 5, y[-1] + 5, n),
          rng.uniform(y[0], y[-1], 3 * x.size), rng.choice(y, n)]
    i, j = rng.integers(0, x.size - 1, n), rng.integers(0, y.size - 1, n)
    f = rng.uniform(0, 1, n)
    xs.append(x[i] + f * (x[i + 1] - x[i]))                  # on the cells' diagonals
    ys.append(y[j] + f * (y[j + 1] - y[j]))
    edge = rng.uniform(0, 1, 4 * n)
    xs.append(np.concatenate([np.full(n, x[0]), np.full(n, x[-1]),
                              x[0] + edge[:2 * n] * (x[-1] - x[0])]))
    ys.append(np.concatenate([y[0] + edge[2 * n:3 * n] * (y[-1] - y[0]),
                              y[0] + edge[3 * n:] * (y[-1] - y[0]),
                              np.full(n, y[0]), np.full(n, y[-1])]))
    return np.concatenate(xs), np.concatenate(ys)


@pytest.mark.parametrize("holes", [False, True])
def test_surface_height_equals_vertical_ray_cast(holes):
    x, y, z, codes = _rough(holes=holes)
    t = Terrain.from_heightfield(x, y, z, codes)
    assert t.grid is not None and (t.holes > 0) == holes
    px, py = _points(x, y, 400, np.random.default_rng(1))
    direct = t.grid.surface_height_m(px, py)
    ref = _vertical_cast(_mesh_only(t), px, py)
    both = np.isfinite(ref)
    np.testing.assert_allclose(direct[both], ref[both], rtol=0, atol=ATOL_M)
    # where the ray misses, the point is off the terrain -- or exactly on the outer edge of a
    # triangle (a grazing ray), where the direct height is that edge's
    lone = np.isfinite(direct) & ~both
    on_line = np.isin(px, x) | np.isin(py, y)
    assert np.all(on_line[lone])
    off = (px < x[0]) | (px > x[-1]) | (py < y[0]) | (py > y[-1])
    assert np.all(np.isnan(direct[off]))


def test_surface_height_closed_forms_nodes_edges_holes():
    x, y, z, codes = _rough(holes=True)
    t = Terrain.from_heightfield(x, y, z, codes)
    g = t.grid
    # every node of a valid cell: its own height, exactly
    valid_node = np.zeros(z.shape, dtype=bool)
    ok = g.cell_face >= 0
    for dj, di in ((0, 0), (0, 1), (1, 0), (1, 1)):
        valid_node[dj:dj + ok.shape[0], di:di + ok.shape[1]] |= ok
    jj, ii = np.nonzero(valid_node)
    np.testing.assert_array_equal(g.surface_height_m(x[ii], y[jj]), z[jj, ii])
    # nodes that only hole cells touch, and points inside holes: NaN
    jj, ii = np.nonzero(~valid_node)
    assert np.all(np.isnan(g.surface_height_m(x[ii], y[jj])))
    xc, yc = (x[21] + x[22]) / 2, (y[13] + y[14]) / 2
    assert np.isnan(g.surface_height_m(xc, yc))
    # the edge x = x[8] from y[4] to y[5]: cell (4, 8) is a hole (node (5, 7)... no: node
    # (5, 7) takes out cells (4..5, 6..7)); its right neighbour's edge is linear in y
    f = np.linspace(0.0, 1.0, 11)
    xe = np.full(f.size, x[7])                    # low edge of hole cells (4, 7), (5, 7)
    ye = y[3] + f * (y[4] - y[3])                 # ... along cell row 3 (valid)
    np.testing.assert_allclose(g.surface_height_m(xe, ye),
                               (1 - f) * z[3, 7] + f * z[4, 7], rtol=0, atol=1e-9)
    # x = x[8] is the high edge of hole cell (5, 7) and the low edge of valid cell (5, 8)
    ye = y[5] + f * (y[6] - y[5])
    np.testing.assert_allclose(g.surface_height_m(np.full(f.size, x[8]), ye),
                               (1 - f) * z[5, 8] + f * z[6, 8], rtol=0, atol=1e-9)
    # x = x[1]: the left edge of the terrain (column 0 is no-data): the cells right of it
    ye = y[2] + f * (y[3] - y[2])
    np.testing.assert_allclose(g.surface_height_m(np.full(f.size, x[1]), ye),
                               (1 - f) * z[2, 1] + f * z[3, 1], rtol=0, atol=1e-9)
    assert np.all(np.isnan(g.surface_height_m(np.full(f.size, x[0]), ye)))
    # non-finite input: NaN; shapes broadcast
    assert np.isnan(g.surface_height_m(np.nan, y[3])) and np.isnan(g.surface_height_m(np.inf, 0))
    assert g.surface_height_m(x[3], y[:5][:, None] + 0 * x[:2]).shape == (5, 2)


def test_descending_axes_same_surface():
    asc = Terrain.from_heightfield(*_rough(holes=True))
    desc = Terrain.from_heightfield(*_rough(holes=True, descending=True))
    np.testing.assert_array_equal(desc.grid.x_m, asc.grid.x_m)
    np.testing.assert_array_equal(desc.grid.z_m, asc.grid.z_m)
    x, y = asc.grid.x_m, asc.grid.y_m
    px, py = _points(x, y, 300, np.random.default_rng(2))
    np.testing.assert_array_equal(desc.grid.surface_height_m(px, py),
                                  asc.grid.surface_height_m(px, py))
    ref = _vertical_cast(_mesh_only(desc), px, py)
    both = np.isfinite(ref)
    np.testing.assert_allclose(desc.grid.surface_height_m(px, py)[both], ref[both],
                               rtol=0, atol=ATOL_M)


def test_grid_faces_are_the_mesh_faces_and_the_mesh_is_built_on_demand():
    x, y, z, codes = _rough(holes=True)
    t = Terrain.from_heightfield(x, y, z, codes)
    # heights, ray casts and bounds come from the grid: no mesh yet
    t.grid.surface_height_m(x[3], y[4])
    cast_rays(t, [[x[3], y[4], 500.0]], [[0.0, 0.0, -1.0]])
    assert t.__dict__["_mesh"] is None
    b = t.bounds.copy()
    mesh = t.mesh                                   # built now, from the grid
    assert t.mesh is mesh and t.n_faces == len(mesh.faces) == len(t.face_materials)
    np.testing.assert_array_equal(b, mesh.bounds)
    f = np.arange(t.n_faces)
    np.testing.assert_array_equal(t.face_vertices(f), mesh.vertices[mesh.faces])
    np.testing.assert_array_equal(_mesh_only(t).face_vertices(f[::7]),
                                  mesh.vertices[mesh.faces[::7]])
    # two triangles per terrain cell, wound counter-clockwise seen from above (normals up)
    assert t.n_faces == 2 * ((x.size - 1) * (y.size - 1) - t.holes)
    assert np.all(mesh.face_normals[:, 2] > 0)


def test_grid_does_not_freeze_the_callers_arrays():
    x, y, z, codes = _rough()
    Terrain.from_heightfield(x, y, z, codes)
    z[0, 0] = 1.0          # the caller's arrays stay writable
    x[0] = x[0]


def test_bad_grid_refused():
    t = flat_plane(0.0, (0.0, 10.0, 0.0, 10.0), 5.0)
    g = t.grid
    with pytest.raises(ValueError, match="grid"):
        Terrain(t.mesh, t.face_materials, grid="grid")
    half = np.where(np.arange(g.cell_face.size).reshape(g.cell_face.shape) == 0, -1,
                    g.cell_face)
    with pytest.raises(ValueError, match="grid"):
        Terrain(t.mesh, t.face_materials,
                grid=HeightGrid(g.x_m.copy(), g.y_m.copy(), g.z_m.copy(), half))
    with pytest.raises(ValueError, match="cell_face"):
        HeightGrid(g.x_m.copy(), g.y_m.copy(), g.z_m.copy(), g.cell_face[:1].copy())


# ------------------------------------------------------------------ cropped ray casting
def _spy_crops(monkeypatch):
    sizes = []
    real = raycast._crop_scene

    def spy(terrain, cells):
        sizes.append(int(cells.size))
        return real(terrain, cells)

    monkeypatch.setattr(raycast, "_crop_scene", spy)
    return sizes


def _same_hits(a, b):
    np.testing.assert_array_equal(a.face_index, b.face_index)
    np.testing.assert_array_equal(a.ranges_m, b.ranges_m)
    np.testing.assert_array_equal(a.material_codes, b.material_codes)
    np.testing.assert_array_equal(a.incidence_rad, b.incidence_rad)


@pytest.mark.parametrize("holes, uniform", [(False, False), (True, False), (True, True)])
def test_cropped_cast_same_triangles_as_whole_mesh(monkeypatch, holes, uniform):
    """Nadir and oblique rays (up to 75 deg off nadir, long stretches across the grid), rays
    hitting from below, rays that miss: crops give the whole mesh's hits, face for face."""
    x, y, z, codes = _rough(nx=121, ny=101, seed=3, holes=holes, uniform=uniform)
    t = Terrain.from_heightfield(x, y, z, codes)
    assert (t.grid.steps_m is not None) == uniform
    rng = np.random.default_rng(4)
    n = 3000
    cx = rng.uniform(x[0] - 50, x[-1] + 50, n)
    cy = rng.uniform(y[0] - 50, y[-1] + 50, n)
    off = np.concatenate([rng.uniform(0, 0.02, n // 2), rng.uniform(0, 1.3, n - n // 2)])
    az = rng.uniform(0, 2 * np.pi, n)
    d = np.column_stack([np.sin(off) * np.cos(az), np.sin(off) * np.sin(az), -np.cos(off)])
    d[:100, 2] *= -1.0                                         # upwards ...
    o = np.column_stack([cx, cy, np.full(n, 600.0)]) - 400.0 * d
    o[:50, 2] += 500.0                                         # ... from above: miss
    sizes = _spy_crops(monkeypatch)
    # small batches (a crop each) and one batch over everything
    got = [cast_rays(t, o[k:k + 10], d[k:k + 10]) for k in range(0, n, 10)]
    ref = cast_rays(_mesh_only(t), o, d)
    for k, h in zip(range(0, n, 10), got):
        sl = slice(k, k + 10)
        np.testing.assert_array_equal(h.face_index, ref.face_index[sl])
        np.testing.assert_array_equal(h.ranges_m, ref.ranges_m[sl])
        np.testing.assert_array_equal(h.material_codes, ref.material_codes[sl])
    assert ref.hit.mean() > 0.5 and not ref.hit[:50].any() and ref.hit[50:100].any()
    crops = [s for s in sizes if s]
    assert crops and max(crops) < 0.5 * t.n_faces / 2        # crops, far smaller than the grid


def test_crop_or_whole_terrain_and_no_cells(monkeypatch):
    x, y, z, codes = _rough(nx=81, ny=61, seed=5)
    t = Terrain.from_heightfield(x, y, z, codes)
    sizes = _spy_crops(monkeypatch)
    # nadir rays along a line: a thin band of cells (off the node lines: a ray exactly through
    # an edge shared by two triangles may get either of them from embree)
    xs = np.linspace(x[2] + 0.1234, x[-3] - 0.0567, 500)
    o = np.column_stack([xs, np.full(xs.size, y[30] + 0.3), np.full(xs.size, 500.0)])
    d = np.tile([0.0, 0.0, -1.0], (xs.size, 1))
    _same_hits(cast_rays(t, o, d), cast_rays(_mesh_only(t), o, d))
    assert sizes[-1] <= 3 * (x.size - 1)
    # rays spread over the whole grid: the whole terrain's structure, no crop
    gx, gy = np.meshgrid(np.linspace(x[0], x[-1], 40), np.linspace(y[0], y[-1], 40))
    o = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, 500.0)])
    d = np.tile([0.0, 0.0, -1.0], (gx.size, 1))
    n_crops = len(sizes)
    _same_hits(cast_rays(t, o, d), cast_rays(_mesh_only(t), o, d))
    assert len(sizes) == n_crops and "embree" in t._cache
    # rays that cannot reach the terrain: no structure at all, all misses
    o = np.array([[x[0] - 100.0, y[0], 500.0], [x[5], y[5], 500.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    h = cast_rays(t, o, d)
    assert not h.hit.any() and len(sizes) == n_crops


def test_cropped_cast_from_orbit():
    """Satellite-like rays (origins 500 km up, clipped to the terrain's box before embree)."""
    x, y, z, codes = _rough(nx=81, ny=61, seed=6)
    t = Terrain.from_heightfield(x, y, z, codes)
    rng = np.random.default_rng(7)
    n = 200
    th = rng.uniform(0, 0.002, n)
    az = rng.uniform(0, 2 * np.pi, n)
    d = np.column_stack([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), -np.cos(th)])
    target = np.column_stack([rng.uniform(x[0], x[-1], n), rng.uniform(y[0], y[-1], n),
                              np.full(n, 300.0)])
    o = target - 5e5 * d
    _same_hits(cast_rays(t, o, d), cast_rays(_mesh_only(t), o, d))


def test_terrain_pickles_after_ray_casting():
    """Cached ray-casting structures are not pickled (embree's are not picklable): a copy
    rebuilds them and casts the same hits."""
    import pickle

    import trimesh

    grid = Terrain.from_heightfield(*_rough(seed=8))
    mesh = Terrain(trimesh.creation.box(extents=(10.0, 10.0, 2.0)), np.zeros(12, np.int32))
    for t, o in ((grid, [[grid.grid.x_m[5] + 0.3, grid.grid.y_m[5] + 0.2, 500.0]]),
                 (mesh, [[0.2, 0.3, 10.0]])):
        d = [[0.0, 0.0, -1.0]]
        ref = cast_rays(t, o, d)
        mesh_only = _mesh_only(t)
        cast_rays(mesh_only, o, d)                     # whole-mesh embree scene in its cache
        for t2 in (pickle.loads(pickle.dumps(t)), pickle.loads(pickle.dumps(mesh_only))):
            _same_hits(cast_rays(t2, o, d), ref)


def test_misses_build_nothing_for_the_whole_terrain():
    """Rays that reach no cell of a heightfield miss without any structure (no crop, and
    neither the whole terrain's scene nor its plane table)."""
    t = Terrain.from_heightfield(*_rough(seed=9))
    x0, y0 = t.grid.x_m[0], t.grid.y_m[0]
    h = cast_rays(t, [[x0 - 50.0, y0, 500.0], [x0 + 20.0, y0 + 20.0, 500.0]],
                  [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    assert not h.hit.any() and np.all(np.isinf(h.ranges_m))
    assert not {"embree", "planes"} & set(t._cache) and t.__dict__["_mesh"] is None
