"""Terrain: triangle meshes in projected metres (z up) with a surface material per face.

Sources of terrain:

* ``Terrain.from_mesh_file``: OBJ / STL / PLY / GLB through trimesh, one material for all faces;
* ``Terrain.from_heightfield``: a regular grid (two triangles per cell, vectorised); NaN heights
  (DEM no-data) leave their cells out, counted in ``Terrain.holes``. The terrain keeps its grid
  (:class:`HeightGrid`): heights below a point are read off the grid's triangles directly, and
  ray casting builds its acceleration structure for the cells its rays can reach only;
* ``Terrain.from_dem``: a GeoTIFF (or any raster rasterio reads) via the optional ``dem`` extra;
* ``synthetic_ice_sheet``: a Vialov flow-line profile with crevasses, sastrugi, melt ponds and rock
  outcrops, all seeded by a ``numpy.random.Generator``;
* ``flat_plane`` / ``sloped_plane``: test surfaces with closed-form ranges.

Materials are integer codes into ``Terrain.material_names``; the default table is
``MATERIAL_NAMES`` (names of :data:`chirplidar.target.materials.MATERIALS`).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field

import numpy as np
import trimesh

from ..target.materials import MATERIALS

# Code <-> name table of surface materials. The order is fixed here (not taken from the order of
# MATERIALS) so that codes stay stable if materials.py is reordered or extended.
MATERIAL_NAMES: tuple[str, ...] = (
    "snow", "firn", "blue_ice", "open_water", "rock", "snow_fresh", "thesis_target")
_missing = [n for n in MATERIAL_NAMES if n not in MATERIALS]
if _missing:  # pragma: no cover - guards against a renamed material
    raise ImportError(f"terrain material table names unknown materials: {_missing}")
MATERIAL_CODES: dict[str, int] = {name: code for code, name in enumerate(MATERIAL_NAMES)}


def material_code(name: str) -> int:
    """Integer code of a material name of ``MATERIAL_NAMES``; ValueError if unknown."""
    try:
        return MATERIAL_CODES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown material {name!r}; known: {', '.join(MATERIAL_NAMES)}") \
            from None


def material_name(code: int) -> str:
    """Material name of an integer code of ``MATERIAL_NAMES``; ValueError if out of range."""
    c = int(code)
    if not 0 <= c < len(MATERIAL_NAMES):
        raise ValueError(f"material code {code!r} out of range 0..{len(MATERIAL_NAMES) - 1}")
    return MATERIAL_NAMES[c]


@dataclass(frozen=True, eq=False)
class HeightGrid:
    """The regular grid of a heightfield terrain, axes increasing (as its mesh is built).

    x_m (nx,), y_m (ny,): strictly increasing node coordinates (m); z_m (ny, nx): node heights
    (m), NaN for no-data; cell_face (ny-1, nx-1): index in the terrain's mesh of the first of
    the cell's two triangles (the second is the next one), -1 for a cell left out (hole).
    Cell (j, i) spans x_m[i]..x_m[i+1], y_m[j]..y_m[j+1]; with v_ab the node (j+b, i+a) its
    triangles are (v00, v10, v11) -- the half below the diagonal v00-v11, u >= v in the cell's
    unit coordinates -- and (v00, v11, v01), the half above it.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    cell_face: np.ndarray

    def __post_init__(self):
        ny, nx = self.y_m.size, self.x_m.size
        if self.z_m.shape != (ny, nx) or self.cell_face.shape != (ny - 1, nx - 1):
            raise ValueError(f"HeightGrid: z_m must be ({ny}, {nx}) and cell_face "
                             f"({ny - 1}, {nx - 1}), got {self.z_m.shape}, "
                             f"{self.cell_face.shape}")
        for a in (self.x_m, self.y_m, self.z_m, self.cell_face):
            a.setflags(write=False)

    def surface_height_m(self, x_m, y_m) -> np.ndarray:
        """Height (m) of the grid's triangles at points (x_m, y_m) (broadcast): the plane of
        the triangle that holds the point, evaluated directly (no ray casting).

        Points on a cell's edge or corner take a neighbouring cell when theirs is a hole, so
        the closed triangles count (as for a ray that grazes an edge). NaN outside the grid,
        inside holes and where x or y is not finite.
        """
        x, y = np.broadcast_arrays(np.asarray(x_m, dtype=np.float64),
                                   np.asarray(y_m, dtype=np.float64))
        gx, gy, z, cf = self.x_m, self.y_m, self.z_m, self.cell_face
        out = np.full(x.shape, np.nan)
        inside = (x >= gx[0]) & (x <= gx[-1]) & (y >= gy[0]) & (y <= gy[-1])  # False for NaN
        if not inside.any():
            return out
        px, py = x[inside], y[inside]
        i = np.clip(np.searchsorted(gx, px, side="right") - 1, 0, gx.size - 2)
        j = np.clip(np.searchsorted(gy, py, side="right") - 1, 0, gy.size - 2)
        u = (px - gx[i]) / (gx[i + 1] - gx[i])
        v = (py - gy[j]) / (gy[j + 1] - gy[j])
        # A point on the low edge (u = 0 or v = 0) of a hole cell also lies on the high edge of
        # its neighbour to the left, below or both: take the first of them that is terrain.
        i0, j0, u0, v0 = i, j, u, v
        for di, dj in ((1, 0), (0, 1), (1, 1)):
            ti, tj = np.maximum(i0 - di, 0), np.maximum(j0 - dj, 0)
            move = ((cf[j, i] < 0) & (cf[tj, ti] >= 0) & (i0 >= di) & (j0 >= dj)
                    & ((u0 == 0) | (di == 0)) & ((v0 == 0) | (dj == 0)))
            i, j = np.where(move, ti, i), np.where(move, tj, j)
            u, v = np.where(move, u0 + di, u), np.where(move, v0 + dj, v)
        # Barycentric weights: exact at the nodes, and the same sum on both sides of every
        # edge and of the diagonal, so the surface is continuous to the last bit.
        h = np.where(u >= v,
                     (1 - u) * z[j, i] + (u - v) * z[j, i + 1] + v * z[j + 1, i + 1],
                     (1 - v) * z[j, i] + (v - u) * z[j + 1, i] + u * z[j + 1, i + 1])
        out[inside] = np.where(cf[j, i] >= 0, h, np.nan)
        return out

    @functools.cached_property
    def steps_m(self) -> tuple[float, float] | None:
        """(dx, dy) of a grid with uniform steps (to 1e-9 relative), else None."""
        out = []
        for a in (self.x_m, self.y_m):
            d = np.diff(a)
            if np.ptp(d) > 1e-9 * d.mean():
                return None
            out.append(float(d.mean()))
        return out[0], out[1]

    @functools.cached_property
    def terrain_cells(self) -> np.ndarray:
        """Flat indices (row-major) of the cells that are terrain: cell of faces 2k, 2k+1."""
        return np.flatnonzero(self.cell_face.ravel() >= 0)

    def used_nodes(self) -> np.ndarray:
        """(ny, nx) bool: the nodes of the cells that are terrain (the mesh's vertices)."""
        ok = self.cell_face >= 0
        used = np.zeros(self.z_m.shape, dtype=bool)
        for dj, di in ((0, 0), (0, 1), (1, 0), (1, 1)):
            used[dj:dj + ok.shape[0], di:di + ok.shape[1]] |= ok
        return used

    def face_vertices(self, face_index) -> np.ndarray:
        """(k, 3, 3) float64 vertices of mesh faces ``face_index`` (k,), in face order (the
        values of the mesh's vertex array, read off the grid)."""
        f = np.asarray(face_index, dtype=np.int64)
        nx = self.x_m.size
        j, i = np.divmod(self.terrain_cells[f >> 1], nx - 1)
        up = f & 1               # 0: (v00, v10, v11); 1: the cell's second, (v00, v11, v01)
        n00 = j * nx + i
        x, y, z = self.x_m, self.y_m, self.z_m.ravel()
        out = np.empty((f.size, 3, 3))
        out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = x[i], y[j], z[n00]
        out[:, 1, 0], out[:, 1, 1], out[:, 1, 2] = x[i + 1], y[j + up], z[n00 + 1 + up * nx]
        out[:, 2, 0], out[:, 2, 1] = x[i + 1 - up], y[j + 1]
        out[:, 2, 2] = z[n00 + nx + 1 - up]
        return out

    def build_mesh(self) -> trimesh.Trimesh:
        """The triangle mesh of the grid (two triangles per terrain cell, see the class
        docstring); vertices are the used nodes in row-major order."""
        ny, nx = self.z_m.shape
        ok = (self.cell_face >= 0).ravel()
        idx = np.arange(ny * nx).reshape(ny, nx)
        v00, v10 = idx[:-1, :-1].ravel()[ok], idx[:-1, 1:].ravel()[ok]   # (j, i), (j, i+1)
        v01, v11 = idx[1:, :-1].ravel()[ok], idx[1:, 1:].ravel()[ok]     # (j+1, i), (j+1, i+1)
        faces = np.empty((2 * v00.size, 3), dtype=np.int64)
        faces[0::2] = np.column_stack([v00, v10, v11])
        faces[1::2] = np.column_stack([v00, v11, v01])
        used = self.used_nodes().ravel()
        xx, yy = np.meshgrid(self.x_m, self.y_m)
        verts = np.column_stack([xx.ravel()[used], yy.ravel()[used], self.z_m.ravel()[used]])
        remap = np.cumsum(used) - 1
        return trimesh.Trimesh(vertices=verts, faces=remap[faces], process=False)


class _LazyMesh:
    """``Terrain.mesh``: the mesh given, or for a heightfield (given as None) the grid's mesh,
    built on first access -- a run never needs it (heights, ray casting and face planes come
    from the grid), and for millions of cells it costs a good part of loading a scene."""

    def __set_name__(self, owner, name):
        self.attr = "_" + name

    def __get__(self, obj, objtype=None):
        if obj is None:
            raise AttributeError("mesh has no default")   # a required dataclass field
        mesh = obj.__dict__[self.attr]
        if mesh is None:
            mesh = obj.__dict__[self.attr] = obj.grid.build_mesh()
        return mesh

    def __set__(self, obj, value):
        obj.__dict__[self.attr] = value


@dataclass(frozen=True, eq=False)
class Terrain:
    """A triangle mesh (projected metres, z up) with one material code per face.

    mesh: ``trimesh.Trimesh`` with at least one face and finite vertices (not to be modified
    in place: derived data such as ``bounds`` and ray-casting structures are cached); None
    with a ``grid``: then built from it on first access.
    face_materials: int array (n_faces,), codes into ``material_names``.
    material_names: tuple of material names (default ``MATERIAL_NAMES``).
    holes: number of grid cells left out for no-data (0 for meshes from files).
    grid: the :class:`HeightGrid` of a heightfield terrain (``from_heightfield``), else None.
    """

    mesh: trimesh.Trimesh = _LazyMesh()
    face_materials: np.ndarray
    material_names: tuple[str, ...] = MATERIAL_NAMES
    holes: int = 0
    grid: HeightGrid | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        mesh = self.__dict__["_mesh"]      # as given (None: built from the grid when needed)
        if self.grid is not None and not isinstance(self.grid, HeightGrid):
            raise ValueError(f"grid must be a HeightGrid or None, got {type(self.grid).__name__}")
        if mesh is None and self.grid is not None:
            n_faces = 2 * int(np.count_nonzero(self.grid.cell_face >= 0))
        elif not isinstance(mesh, trimesh.Trimesh):
            raise ValueError(f"mesh must be a trimesh.Trimesh, got {type(mesh).__name__}")
        else:
            n_faces = len(mesh.faces)
            if not np.all(np.isfinite(mesh.vertices)):
                raise ValueError("mesh vertices must be finite (NaN/inf found)")
            if self.grid is not None and 2 * int(np.count_nonzero(self.grid.cell_face >= 0)) \
                    != n_faces:
                raise ValueError("grid must be the HeightGrid the mesh was built from "
                                 "(two faces per valid cell)")
        if n_faces == 0:
            raise ValueError("mesh has no faces")
        codes = np.asarray(self.face_materials)
        if codes.shape != (n_faces,) or not np.issubdtype(codes.dtype, np.integer):
            raise ValueError(f"face_materials must be an integer array of shape ({n_faces},), "
                             f"got {codes.dtype} {codes.shape}")
        names = tuple(self.material_names)
        if codes.min() < 0 or codes.max() >= len(names):
            raise ValueError(f"face_materials codes must lie in 0..{len(names) - 1}")
        unknown = [n for n in names if n not in MATERIALS]
        if unknown:
            raise ValueError(f"material_names has unknown materials {unknown}")
        if int(self.holes) < 0:
            raise ValueError(f"holes must be >= 0, got {self.holes!r}")
        codes = codes.astype(np.int32, copy=True)
        codes.setflags(write=False)
        object.__setattr__(self, "face_materials", codes)
        object.__setattr__(self, "material_names", names)
        object.__setattr__(self, "holes", int(self.holes))

    def __getstate__(self):
        # derived data (bounds, ray-casting structures, some not picklable): rebuilt on demand
        return {**self.__dict__, "_cache": {}}

    @property
    def n_faces(self) -> int:
        return len(self.face_materials)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) lowest and highest x, y, z (m) of the vertices that faces use (as
        ``mesh.bounds``, computed once: trimesh re-hashes the vertices on every access)."""
        b = self._cache.get("bounds")
        if b is None:
            if self.grid is not None:
                used = self.grid.used_nodes()
                xs = self.grid.x_m[used.any(axis=0)]
                ys = self.grid.y_m[used.any(axis=1)]
                zs = self.grid.z_m[used]
                b = np.array([[xs[0], ys[0], zs.min()], [xs[-1], ys[-1], zs.max()]])
            else:
                v = np.asarray(self.mesh.vertices)
                used = np.zeros(len(v), dtype=bool)
                used[np.asarray(self.mesh.faces).ravel()] = True
                if not used.all():
                    v = v[used]
                b = np.array([v.min(axis=0), v.max(axis=0)], dtype=np.float64)
            b.setflags(write=False)
            self._cache["bounds"] = b
        return b

    def face_vertices(self, face_index) -> np.ndarray:
        """(k, 3, 3) float64 vertices of faces ``face_index`` (k,) (from the grid of a
        heightfield, without building its mesh)."""
        if self.grid is not None:
            return self.grid.face_vertices(face_index)
        verts = np.asarray(self.mesh.vertices, dtype=np.float64)
        return np.take(verts, np.take(np.asarray(self.mesh.faces), face_index, axis=0), axis=0)

    def face_material_names(self) -> np.ndarray:
        """Material name of every face (object array)."""
        return np.asarray(self.material_names, dtype=object)[self.face_materials]

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_mesh_file(cls, path, material: str = "snow") -> Terrain:
        """Load OBJ/STL/PLY/GLB (anything trimesh reads); every face gets ``material``.

        Missing file: FileNotFoundError naming it. Unreadable file, a scene without geometry, or a
        mesh without (non-degenerate) faces: ValueError naming the file. Degenerate (zero-area)
        faces are dropped.
        """
        path = os.fspath(path)
        code = material_code(material)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"terrain mesh file not found: {path}")
        try:
            loaded = trimesh.load(path)
        except Exception as exc:  # trimesh raises many kinds for bad files
            raise ValueError(f"cannot read terrain mesh file {path}: {exc}") from exc
        if isinstance(loaded, trimesh.Scene):
            meshes = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
            if not meshes:
                raise ValueError(f"terrain mesh file {path} has no faces (no mesh geometry)")
            loaded = loaded.to_mesh()
        if isinstance(loaded, trimesh.PointCloud):   # vertices but no faces (e.g. PLY/OBJ)
            raise ValueError(f"terrain mesh file {path} has no faces "  # noqa: TRY004
                             f"(only {len(loaded.vertices)} vertices)")
        if not isinstance(loaded, trimesh.Trimesh):
            raise ValueError(  # noqa: TRY004 (project rule: ValueError)
                f"terrain mesh file {path} holds no triangle mesh "
                f"(got {type(loaded).__name__})")
        if len(loaded.faces) == 0:
            raise ValueError(f"terrain mesh file {path} has no faces")
        if not np.all(np.isfinite(loaded.vertices)):
            raise ValueError(f"terrain mesh file {path} has non-finite vertices")
        keep = loaded.nondegenerate_faces()
        if not np.any(keep):
            raise ValueError(f"terrain mesh file {path} has no faces of non-zero area "
                             f"({len(loaded.faces)} degenerate faces only)")
        mesh = trimesh.Trimesh(vertices=np.asarray(loaded.vertices, dtype=np.float64),
                               faces=np.asarray(loaded.faces)[keep], process=False)
        mesh.remove_unreferenced_vertices()
        return cls(mesh, np.full(len(mesh.faces), code, dtype=np.int32))

    @classmethod
    def from_heightfield(cls, x_m, y_m, z_m, material_codes,
                         material_names: tuple[str, ...] = MATERIAL_NAMES) -> Terrain:
        """Grid heights to a mesh: two triangles per cell, vectorised.

        x_m (nx,), y_m (ny,): strictly monotonic node coordinates (m). z_m (ny, nx): heights (m);
        NaN marks no-data, and every cell touching a NaN node is left out (no triangles); the
        number of such cells is ``holes``. material_codes: integer codes, either per node
        (ny, nx) -- a triangle takes the majority code of its three nodes (first node on a
        three-way tie) -- or per cell (ny-1, nx-1). Triangles are wound counter-clockwise seen
        from above, so face normals point up (+z) for increasing x and y.

        The terrain keeps the grid (``Terrain.grid``, axes made increasing); its ``mesh`` is
        built from it when first used.
        """
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        z = np.asarray(z_m, dtype=np.float64)
        for name, v in (("x_m", x), ("y_m", y)):
            if v.ndim != 1 or v.size < 2:
                raise ValueError(f"{name} must be a 1-D array of at least 2 nodes, got {v.shape}")
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be finite")
            d = np.diff(v)
            if not (np.all(d > 0) or np.all(d < 0)):
                raise ValueError(f"{name} must be strictly monotonic")
        ny, nx = y.size, x.size
        if z.shape != (ny, nx):
            raise ValueError(f"z_m must have shape (ny, nx) = ({ny}, {nx}), got {z.shape}")
        if np.any(np.isinf(z)):
            raise ValueError("z_m must not contain inf (use NaN for no-data)")
        nan = np.isnan(z)
        if nan.all():
            raise ValueError("z_m is all NaN (no-data): no terrain to build")
        codes = np.asarray(material_codes)
        if not np.issubdtype(codes.dtype, np.integer):
            raise ValueError(f"material_codes must be integers, got {codes.dtype}")
        if codes.shape not in ((ny, nx), (ny - 1, nx - 1)):
            raise ValueError(f"material_codes must have shape ({ny}, {nx}) or "
                             f"({ny - 1}, {nx - 1}), got {codes.shape}")
        if codes.min() < 0 or codes.max() >= len(material_names):
            raise ValueError(f"material_codes must lie in 0..{len(material_names) - 1}")

        # Orient so that the grid increases in x and y (keeps normals up).
        if x[1] < x[0]:
            x, z, codes = x[::-1], z[:, ::-1], codes[:, ::-1]
        if y[1] < y[0]:
            y, z, codes = y[::-1], z[::-1, :], codes[::-1, :]
        nan = np.isnan(z)
        cell_ok = ~(nan[:-1, :-1] | nan[:-1, 1:] | nan[1:, :-1] | nan[1:, 1:])
        n_ok = int(np.count_nonzero(cell_ok))
        if n_ok == 0:
            raise ValueError("z_m has no cell with four valid (non-NaN) corners")
        if codes.shape == (ny - 1, nx - 1):
            face_codes = np.repeat(codes[cell_ok], 2)
        else:   # per node: a triangle takes the majority of (v00, v10, v11) / (v00, v11, v01)
            c00, c10 = codes[:-1, :-1][cell_ok], codes[:-1, 1:][cell_ok]
            c01, c11 = codes[1:, :-1][cell_ok], codes[1:, 1:][cell_ok]
            face_codes = np.empty(2 * n_ok, dtype=codes.dtype)
            for k, (a, b, d) in enumerate(((c00, c10, c11), (c00, c11, c01))):
                face_codes[k::2] = np.where((a == b) | (a == d), a, np.where(b == d, b, a))
        cell_face = np.full(cell_ok.shape, -1, dtype=np.int64)
        cell_face[cell_ok] = 2 * np.arange(n_ok)   # the mesh's faces, cell by cell (row-major)
        grid = HeightGrid(x.copy(), y.copy(), z.copy(), cell_face)
        return cls(None, face_codes.astype(np.int32), tuple(material_names),
                   cell_ok.size - n_ok, grid)

    @classmethod
    def from_dem(cls, path, material: str = "snow", band: int = 1,
                 nodata: str = "holes") -> Terrain:
        """Load a DEM raster (GeoTIFF, ...) with rasterio, honouring its nodata value.

        Node coordinates are the pixel centres in the raster's CRS (projected metres expected;
        rotated/sheared transforms are refused); heights (m) are taken as they are stored.
        ``nodata`` says what to do with no-data pixels (the raster's nodata value, NaN, inf):

        * ``"holes"``: leave every cell touching one out (rays there miss; ``holes`` counts them);
        * ``"fill"``: give each the height of the nearest valid pixel (Euclidean pixel distance,
          ``scipy.ndimage.distance_transform_edt``); ``holes`` is then 0;
        * ``"error"``: ValueError naming the file, the number of no-data pixels and their
          bounding box (rows, columns and x/y in the raster's CRS).

        Requires the ``dem`` extra.
        """
        if nodata not in DEM_NODATA_MODES:
            raise ValueError(f"nodata must be one of {DEM_NODATA_MODES}, got {nodata!r}")
        try:
            import rasterio
        except ImportError as exc:
            raise ImportError("Terrain.from_dem needs rasterio: pip install chirplidar[dem]") \
                from exc
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"DEM file not found: {path}")
        code = material_code(material)
        try:
            with rasterio.open(path) as src:
                if not 1 <= int(band) <= src.count:
                    raise ValueError(f"DEM {path} has {src.count} band(s); band {band} "
                                     "does not exist")
                z = src.read(int(band)).astype(np.float64)
                nodata_value = src.nodata
                tr = src.transform
                if src.crs is not None and src.crs.is_geographic:
                    raise ValueError(f"DEM {path} is in geographic coordinates; "
                                     "reproject to a projected CRS in metres")
        except ValueError:
            raise
        except Exception as exc:
            raise ValueError(f"cannot read DEM file {path}: {exc}") from exc
        if tr.b != 0 or tr.d != 0:
            raise ValueError(f"DEM {path} has a rotated geotransform; not supported")
        if nodata_value is not None:
            z[z == nodata_value] = np.nan
        z[~np.isfinite(z)] = np.nan
        missing = np.isnan(z)
        if missing.all():
            raise ValueError(f"DEM {path} is all no-data")
        ny, nx = z.shape
        x = tr.c + tr.a * (np.arange(nx) + 0.5)
        y = tr.f + tr.e * (np.arange(ny) + 0.5)
        if missing.any():
            if nodata == "error":
                rows, cols = np.nonzero(missing)
                r0, r1, c0, c1 = rows.min(), rows.max(), cols.min(), cols.max()
                xs, ys = sorted((x[c0], x[c1])), sorted((y[r0], y[r1]))
                raise ValueError(
                    f"DEM {path} has {rows.size} no-data pixels (of {z.size}) in rows "
                    f"{r0}..{r1}, columns {c0}..{c1} (pixel centres x {xs[0]:.3f}..{xs[1]:.3f} m, "
                    f"y {ys[0]:.3f}..{ys[1]:.3f} m); choose nodata 'holes' (rays there miss) "
                    "or 'fill' (nearest valid height)")
            if nodata == "fill":
                from scipy.ndimage import distance_transform_edt
                # indices of the nearest valid (mask 0) pixel for every pixel
                idx = distance_transform_edt(missing, return_distances=False,
                                             return_indices=True)
                z = z[tuple(idx)]
        try:
            return cls.from_heightfield(x, y, z, np.full(z.shape, code, dtype=np.int32))
        except ValueError as exc:
            raise ValueError(f"DEM {path}: {exc}") from exc


#: What ``Terrain.from_dem`` does with no-data pixels.
DEM_NODATA_MODES = ("holes", "fill", "error")


# ---------------------------------------------------------------------- test surfaces
def _extent(extent_m):
    try:
        x0, x1, y0, y1 = (float(v) for v in extent_m)
    except (TypeError, ValueError):
        raise ValueError(f"extent_m must be (x0, x1, y0, y1) in metres, got {extent_m!r}") \
            from None
    if not all(np.isfinite([x0, x1, y0, y1])) or x1 <= x0 or y1 <= y0:
        raise ValueError(f"extent_m must be finite with x0 < x1 and y0 < y1, got {extent_m!r}")
    return x0, x1, y0, y1


def _grid(extent_m, resolution_m):
    x0, x1, y0, y1 = _extent(extent_m)
    res = float(resolution_m)
    if not np.isfinite(res) or res <= 0:
        raise ValueError(f"resolution_m must be > 0, got {resolution_m!r}")
    nx = int(np.ceil((x1 - x0) / res - 1e-9)) + 1
    ny = int(np.ceil((y1 - y0) / res - 1e-9)) + 1
    if nx * ny > 50_000_000:
        raise ValueError(f"resolution_m={res} gives {nx}x{ny} nodes (> 5e7); coarsen it")
    return np.linspace(x0, x1, max(nx, 2)), np.linspace(y0, y1, max(ny, 2))


def flat_plane_heightfield(height_m, extent_m, resolution_m, material: str = "snow"):
    """Heightfield ``(x_m, y_m, z_m, codes)`` of ``flat_plane`` (``Terrain.from_heightfield``)."""
    h = float(height_m)
    if not np.isfinite(h):
        raise ValueError(f"height_m must be finite, got {height_m!r}")
    x, y = _grid(extent_m, resolution_m)
    z = np.full((y.size, x.size), h)
    return x, y, z, np.full(z.shape, material_code(material), np.int32)


def flat_plane(height_m, extent_m, resolution_m, material: str = "snow") -> Terrain:
    """Horizontal plane z = height_m over extent_m = (x0, x1, y0, y1), grid step resolution_m."""
    return Terrain.from_heightfield(*flat_plane_heightfield(height_m, extent_m, resolution_m,
                                                            material))


def sloped_plane_heightfield(slope_rad, azimuth_rad, height_m, extent_m, resolution_m,
                             material: str = "snow", origin_m=(0.0, 0.0)):
    """Heightfield ``(x_m, y_m, z_m, codes)`` of ``sloped_plane``."""
    s, az, h = float(slope_rad), float(azimuth_rad), float(height_m)
    if not np.isfinite([s, az, h]).all() or not 0 <= s < np.pi / 2:
        raise ValueError(f"slope_rad must lie in [0, pi/2) and azimuth_rad, height_m be finite; "
                         f"got {slope_rad!r}, {azimuth_rad!r}, {height_m!r}")
    x, y = _grid(extent_m, resolution_m)
    xx, yy = np.meshgrid(x - origin_m[0], y - origin_m[1])
    z = h + np.tan(s) * (xx * np.cos(az) + yy * np.sin(az))
    return x, y, z, np.full(z.shape, material_code(material), np.int32)


def sloped_plane(slope_rad, azimuth_rad, height_m, extent_m, resolution_m,
                 material: str = "snow", origin_m=(0.0, 0.0)) -> Terrain:
    """Plane through (origin_m, height_m) rising at ``slope_rad`` towards ``azimuth_rad``.

    azimuth_rad is measured from +x towards +y (mathematical convention, not a compass bearing):
    z = height_m + tan(slope_rad) * ((x - x0) cos(az) + (y - y0) sin(az)).
    """
    return Terrain.from_heightfield(*sloped_plane_heightfield(
        slope_rad, azimuth_rad, height_m, extent_m, resolution_m, material, origin_m))


# ---------------------------------------------------------------------- synthetic ice sheet
def vialov_height(x_m, divide_height_m, margin_distance_m, divide_x_m=0.0):
    """Vialov (1958) steady ice-sheet profile, as in Cuffey & Paterson (2010) eq. 8.34.

    h(x) = H [1 - (|x - x_d| / L)^(4/3)]^(3/8) for |x - x_d| <= L, else 0 (Glen n = 3, flat bed,
    uniform accumulation). H = divide_height_m, L = margin_distance_m, x_d = divide_x_m.
    """
    H = float(divide_height_m)
    L = float(margin_distance_m)
    if not (np.isfinite(H) and H > 0):
        raise ValueError(f"divide_height_m must be > 0, got {divide_height_m!r}")
    if not (np.isfinite(L) and L > 0):
        raise ValueError(f"margin distance must be > 0, got {margin_distance_m!r}")
    xi = np.clip(np.abs(np.asarray(x_m, dtype=np.float64) - divide_x_m) / L, 0.0, 1.0)
    return H * (1.0 - xi ** (4.0 / 3.0)) ** (3.0 / 8.0)


SYNTHETIC_FEATURES = ("crevasses", "sastrugi", "ponds", "outcrops")


def _smooth_noise(rng, shape, dx, corr_along_m, corr_across_m, azimuth_rad):
    """Zero-mean unit-rms Gaussian random field with an anisotropic Gaussian correlation.

    FFT filtering of white noise; correlation lengths corr_along_m (along azimuth) and
    corr_across_m (across), grid step dx (m).
    """
    ny, nx = shape
    white = rng.standard_normal(shape)
    kx = 2 * np.pi * np.fft.fftfreq(nx, d=dx)[None, :]
    ky = 2 * np.pi * np.fft.fftfreq(ny, d=dx)[:, None]
    ka = kx * np.cos(azimuth_rad) + ky * np.sin(azimuth_rad)
    kc = -kx * np.sin(azimuth_rad) + ky * np.cos(azimuth_rad)
    filt = np.exp(-0.25 * ((ka * corr_along_m) ** 2 + (kc * corr_across_m) ** 2))
    field_ = np.fft.ifft2(np.fft.fft2(white) * filt).real
    rms = np.sqrt(np.mean(field_ ** 2))
    return field_ / rms if rms > 0 else field_


def synthetic_ice_sheet_heightfield(extent_m, resolution_m, rng: np.random.Generator, *,
                        divide_height_m: float, margin_x_m: float, divide_x_m: float = 0.0,
                        features=SYNTHETIC_FEATURES,
                        ela_fraction: float = 0.6,
                        crevasse_band=(0.80, 0.95), crevasse_spacing_m: float = 40.0,
                        crevasse_depth_m: float = 8.0,
                        sastrugi_rms_m: float = 0.1, sastrugi_length_m=(8.0, 1.5),
                        sastrugi_azimuth_rad: float = 0.0,
                        pond_band=(0.6, 0.85), n_ponds: int = 6,
                        pond_radius_m=(100.0, 400.0), pond_depth_m: float = 1.5,
                        pond_max_basin_m: float = 10.0,
                        n_outcrops: int = 4, outcrop_height_m=(20.0, 60.0),
                        outcrop_radius_m=(60.0, 200.0), outcrop_band=(0.9, 1.0)):
    """Heightfield ``(x_m, y_m, z_m, codes)`` of a simple, physically shaped ice-sheet margin.

    :func:`synthetic_ice_sheet` turns it into a :class:`Terrain` (same arguments); the scene
    loader caches the heightfield itself (the mesh is cheap to rebuild from it). ``z_m`` (ny, nx)
    is relative to the ice-free ground (0 m); ``codes`` (ny, nx) are per-node material codes.

    Surface (x is the flow-line coordinate, the sheet is extruded along y):

    * **Vialov profile** (Vialov 1958; Cuffey & Paterson 2010, eq. 8.34),
      h(x) = H [1 - (|x - x_d|/L)^(4/3)]^(3/8), H = ``divide_height_m`` at the divide x_d =
      ``divide_x_m``, zero at the margin x = ``margin_x_m`` (L = |margin_x_m - divide_x_m|);
      beyond the margin the ground is ice-free at 0 m (material ``rock``). Scale: km to 1000 km.
    * **Materials by zone**: ``snow`` up-glacier of the equilibrium line at
      ``ela_fraction`` * L from the divide, ``blue_ice`` below it (ablation zone).
    * **Crevasse field** (``"crevasses"``): parallel troughs transverse to flow in the band
      ``crevasse_band`` (fractions of L), z -= depth * max(0, cos(2 pi s / spacing + phase))^8
      with s the along-flow coordinate rotated by a seeded angle (+-10 deg) and a seeded smooth
      phase jitter across flow; spacing ``crevasse_spacing_m`` (tens of m), depth
      ``crevasse_depth_m`` (m). Needs resolution_m <~ spacing / 4 to be resolved.
    * **Sastrugi** (``"sastrugi"``): anisotropic Gaussian random relief, rms ``sastrugi_rms_m``
      (cm-dm), correlation lengths ``sastrugi_length_m`` = (along wind, across wind) (m) with the
      wind along ``sastrugi_azimuth_rad``; on snow only. Sub-resolution lengths act as per-node
      noise.
    * **Melt ponds / open water** (``"ponds"``): ``n_ponds`` seeded centres in ``pond_band``
      (fractions of L, ablation zone); each pond is a Gaussian basin of seeded radius r in
      ``pond_radius_m`` (hundreds of m) and depth ``pond_depth_m`` + min(4 * slope * r,
      ``pond_max_basin_m``) (deep enough to hold water on gentle regional slopes; on steep
      slopes only the downhill part floods), filled flat up to the lowest surface point
      of the ring at 0.7-0.8 r: a flat ``open_water`` patch at the local minimum.
    * **Rock outcrops** (``"outcrops"``): ``n_outcrops`` Gaussian hills (seeded heights in
      ``outcrop_height_m``, radii in ``outcrop_radius_m``) with centres in ``outcrop_band``
      (fractions of L; default the last 10 % of L before the margin); where the hill rises above
      the ice surface the surface is ``rock``.

    Every feature draws from its own child generator (``rng.spawn``), so disabling one does not
    change the random stream of the others; a disabled feature draws nothing.
    ``resolution_m`` is the grid step: the mesh has 2 (nx-1)(ny-1) triangles.
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")  # noqa: TRY004
    feats = set(features)
    unknown = feats - set(SYNTHETIC_FEATURES)
    if unknown:
        raise ValueError(f"features: unknown {sorted(unknown)}; known: {SYNTHETIC_FEATURES}")
    L = abs(float(margin_x_m) - float(divide_x_m))
    if not np.isfinite(L) or L <= 0:
        raise ValueError(f"margin_x_m must differ from divide_x_m, got {margin_x_m!r}")
    if not 0 < ela_fraction < 1:
        raise ValueError(f"ela_fraction must lie in (0, 1), got {ela_fraction!r}")
    for name, band in (("crevasse_band", crevasse_band), ("pond_band", pond_band),
                       ("outcrop_band", outcrop_band)):
        lo, hi = (float(v) for v in band)
        if not (np.isfinite([lo, hi]).all() and 0.0 <= lo <= hi):
            raise ValueError(f"{name} must be (lo, hi) fractions of L with 0 <= lo <= hi, "
                             f"got {band!r}")
    x, y = _grid(extent_m, resolution_m)
    dx = float(x[1] - x[0])
    xx, yy = np.meshgrid(x, y)
    sgn = 1.0 if margin_x_m > divide_x_m else -1.0
    xi = sgn * (xx - divide_x_m) / L          # 0 at the divide, 1 at the margin (signed)
    ice = vialov_height(xx, divide_height_m, L, divide_x_m)
    ice[xi < -1.0] = 0.0
    ice_free = np.abs(xi) >= 1.0
    z = ice.copy()
    codes = np.where(np.abs(xi) < ela_fraction, MATERIAL_CODES["snow"],
                     MATERIAL_CODES["blue_ice"]).astype(np.int32)
    codes[ice_free] = MATERIAL_CODES["rock"]
    gens = rng.spawn(len(SYNTHETIC_FEATURES))
    g = dict(zip(SYNTHETIC_FEATURES, gens))
    y_span = float(y[-1] - y[0])

    if "crevasses" in feats and crevasse_depth_m > 0:
        r = g["crevasses"]
        ang = r.uniform(-np.deg2rad(10), np.deg2rad(10))
        k = r.uniform(0.5, 2.0, 3) * 2 * np.pi / max(y_span, dx)
        ph = r.uniform(0, 2 * np.pi, 3)
        jitter = 0.6 * np.sum(np.sin(k[:, None, None] * yy[None] + ph[:, None, None]), axis=0)
        s = (xx - divide_x_m) * sgn * np.cos(ang) + yy * np.sin(ang)
        trough = np.maximum(0.0, np.cos(2 * np.pi * s / crevasse_spacing_m + jitter)) ** 8
        band = (np.abs(xi) >= crevasse_band[0]) & (np.abs(xi) <= crevasse_band[1])
        z = z - np.where(band, crevasse_depth_m * trough, 0.0)

    if "sastrugi" in feats and sastrugi_rms_m > 0:
        noise = _smooth_noise(g["sastrugi"], z.shape, dx, sastrugi_length_m[0],
                              sastrugi_length_m[1], sastrugi_azimuth_rad)
        z = z + np.where(codes == MATERIAL_CODES["snow"], sastrugi_rms_m * noise, 0.0)

    if "ponds" in feats and n_ponds > 0:
        r = g["ponds"]
        cxi = r.uniform(pond_band[0], pond_band[1], n_ponds)
        cx = divide_x_m + sgn * cxi * L
        cy = r.uniform(y[0], y[-1], n_ponds)
        rad = r.uniform(pond_radius_m[0], pond_radius_m[1], n_ponds)
        # regional surface slope at each centre: the basin must be deeper than the slope
        # drop across it to hold water (real lakes sit in bed-driven surface depressions)
        slope = np.abs(vialov_height(cx + rad, divide_height_m, L, divide_x_m)
                       - vialov_height(cx - rad, divide_height_m, L, divide_x_m)) / (2 * rad)
        for cxk, cyk, rk, gk in zip(cx, cy, rad, slope):   # a handful of ponds, not a ray loop
            d2 = ((xx - cxk) ** 2 + (yy - cyk) ** 2) / rk ** 2
            near = d2 < 4.0
            if not near.any():
                continue
            basin = pond_depth_m + min(4.0 * gk * rk, pond_max_basin_m)
            z = z - basin * np.exp(-d2) * near
            inside = d2 <= 0.64
            ring = inside & (d2 >= 0.49)
            if not ring.any():
                continue
            level = float(np.min(z[ring]))
            wet = inside & (z < level) & ~ice_free
            z[wet] = level
            codes[wet] = MATERIAL_CODES["open_water"]

    if "outcrops" in feats and n_outcrops > 0:
        r = g["outcrops"]
        oxi = r.uniform(outcrop_band[0], outcrop_band[1], n_outcrops)
        ox = divide_x_m + sgn * oxi * L
        oy = r.uniform(y[0], y[-1], n_outcrops)
        oh = r.uniform(outcrop_height_m[0], outcrop_height_m[1], n_outcrops)
        orad = r.uniform(outcrop_radius_m[0], outcrop_radius_m[1], n_outcrops)
        rock = np.zeros_like(z)
        for oxk, oyk, ohk, ork in zip(ox, oy, oh, orad):   # a few hills, not a ray loop
            d2 = ((xx - oxk) ** 2 + (yy - oyk) ** 2) / ork ** 2
            rock = np.maximum(rock, ohk * np.exp(-d2))
        above = rock > z
        z = np.where(above, rock, z)
        codes[above] = MATERIAL_CODES["rock"]

    return x, y, z, codes


def synthetic_ice_sheet(extent_m, resolution_m, rng: np.random.Generator, **params) -> Terrain:
    return Terrain.from_heightfield(
        *synthetic_ice_sheet_heightfield(extent_m, resolution_m, rng, **params))


synthetic_ice_sheet.__doc__ = (
    "A :class:`Terrain` from :func:`synthetic_ice_sheet_heightfield` (same arguments).\n\n"
    + (synthetic_ice_sheet_heightfield.__doc__ or ""))
