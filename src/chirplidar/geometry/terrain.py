"""Terrain: triangle meshes in projected metres (z up) with a surface material per face.

Sources of terrain:

* ``Terrain.from_mesh_file``: OBJ / STL / PLY / GLB through trimesh, one material for all faces;
* ``Terrain.from_heightfield``: a regular grid (two triangles per cell, vectorised); NaN heights
  (DEM no-data) leave their cells out, counted in ``Terrain.holes``. The terrain keeps its grid
  (:class:`HeightGrid`): heights below a point are read off the grid's triangles directly, and
  ray casting builds its acceleration structure for the cells its rays can reach only;
* ``Terrain.from_dem``: a GeoTIFF (or any raster rasterio reads) via the optional ``dem`` extra;
* generated surfaces (:mod:`chirplidar.geometry.synthetic_terrain`): ``synthetic_ice_sheet``, a
  Vialov flow-line profile with crevasses, sastrugi, melt ponds and rock outcrops, all seeded by a
  ``numpy.random.Generator``; ``flat_plane`` / ``sloped_plane``, test surfaces with closed-form
  ranges.

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
    "snow",
    "firn",
    "blue_ice",
    "open_water",
    "rock",
    "snow_fresh",
    "thesis_target",
)
_missing = [n for n in MATERIAL_NAMES if n not in MATERIALS]
if _missing:  # pragma: no cover - guards against a renamed material
    raise ImportError(f"terrain material table names unknown materials: {_missing}")
MATERIAL_CODES: dict[str, int] = {name: code for code, name in enumerate(MATERIAL_NAMES)}


def material_code(name: str) -> int:
    """Integer code of a material name of ``MATERIAL_NAMES``; ValueError if unknown."""
    try:
        return MATERIAL_CODES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown material {name!r}; known: {', '.join(MATERIAL_NAMES)}") from None


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
            raise ValueError(
                f"HeightGrid: z_m must be ({ny}, {nx}) and cell_face "
                f"({ny - 1}, {nx - 1}), got {self.z_m.shape}, "
                f"{self.cell_face.shape}"
            )
        for a in (self.x_m, self.y_m, self.z_m, self.cell_face):
            a.setflags(write=False)

    def surface_height_m(self, x_m, y_m) -> np.ndarray:
        """Height (m) of the grid's triangles at points (x_m, y_m) (broadcast): the plane of
        the triangle that holds the point, evaluated directly (no ray casting).

        Points on a cell's edge or corner take a neighbouring cell when theirs is a hole, so
        the closed triangles count (as for a ray that grazes an edge). NaN outside the grid,
        inside holes and where x or y is not finite.
        """
        x, y = np.broadcast_arrays(
            np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64)
        )
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
            move = (
                (cf[j, i] < 0)
                & (cf[tj, ti] >= 0)
                & (i0 >= di)
                & (j0 >= dj)
                & ((u0 == 0) | (di == 0))
                & ((v0 == 0) | (dj == 0))
            )
            i, j = np.where(move, ti, i), np.where(move, tj, j)
            u, v = np.where(move, u0 + di, u), np.where(move, v0 + dj, v)
        # Barycentric weights: exact at the nodes, and the same sum on both sides of every
        # edge and of the diagonal, so the surface is continuous to the last bit.
        h = np.where(
            u >= v,
            (1 - u) * z[j, i] + (u - v) * z[j, i + 1] + v * z[j + 1, i + 1],
            (1 - v) * z[j, i] + (v - u) * z[j + 1, i] + u * z[j + 1, i + 1],
        )
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
            used[dj : dj + ok.shape[0], di : di + ok.shape[1]] |= ok
        return used

    def face_vertices(self, face_index) -> np.ndarray:
        """(k, 3, 3) float64 vertices of mesh faces ``face_index`` (k,), in face order (the
        values of the mesh's vertex array, read off the grid)."""
        f = np.asarray(face_index, dtype=np.int64)
        nx = self.x_m.size
        j, i = np.divmod(self.terrain_cells[f >> 1], nx - 1)
        up = f & 1  # 0: (v00, v10, v11); 1: the cell's second, (v00, v11, v01)
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
        v00, v10 = idx[:-1, :-1].ravel()[ok], idx[:-1, 1:].ravel()[ok]  # (j, i), (j, i+1)
        v01, v11 = idx[1:, :-1].ravel()[ok], idx[1:, 1:].ravel()[ok]  # (j+1, i), (j+1, i+1)
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

    def __set_name__(self, owner: type, name: str) -> None:
        self.attr = "_" + name

    def __get__(self, obj: Terrain | None, objtype: type | None = None) -> trimesh.Trimesh:
        if obj is None:
            raise AttributeError("mesh has no default")  # a required dataclass field
        mesh = obj.__dict__[self.attr]
        if mesh is None and obj.grid is not None:  # (__post_init__ refuses neither)
            mesh = obj.__dict__[self.attr] = obj.grid.build_mesh()
        return mesh

    def __set__(self, obj: Terrain, value: trimesh.Trimesh | None) -> None:
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

    mesh: _LazyMesh = _LazyMesh()
    # mypy takes the descriptor for a default; it is none (its class-level __get__ raises)
    face_materials: np.ndarray  # type: ignore[misc]
    material_names: tuple[str, ...] = MATERIAL_NAMES
    holes: int = 0
    grid: HeightGrid | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        mesh = self.__dict__["_mesh"]  # as given (None: built from the grid when needed)
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
            if (
                self.grid is not None
                and 2 * int(np.count_nonzero(self.grid.cell_face >= 0)) != n_faces
            ):
                raise ValueError(
                    "grid must be the HeightGrid the mesh was built from (two faces per valid cell)"
                )
        if n_faces == 0:
            raise ValueError("mesh has no faces")
        codes = np.asarray(self.face_materials)
        if codes.shape != (n_faces,) or not np.issubdtype(codes.dtype, np.integer):
            raise ValueError(
                f"face_materials must be an integer array of shape ({n_faces},), "
                f"got {codes.dtype} {codes.shape}"
            )
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
        if isinstance(loaded, trimesh.PointCloud):  # vertices but no faces (e.g. PLY/OBJ)
            raise ValueError(
                f"terrain mesh file {path} has no faces "  # noqa: TRY004
                f"(only {len(loaded.vertices)} vertices)"
            )
        if not isinstance(loaded, trimesh.Trimesh):
            raise ValueError(  # noqa: TRY004 (project rule: ValueError)
                f"terrain mesh file {path} holds no triangle mesh (got {type(loaded).__name__})"
            )
        if len(loaded.faces) == 0:
            raise ValueError(f"terrain mesh file {path} has no faces")
        if not np.all(np.isfinite(loaded.vertices)):
            raise ValueError(f"terrain mesh file {path} has non-finite vertices")
        keep = loaded.nondegenerate_faces()
        if not np.any(keep):
            raise ValueError(
                f"terrain mesh file {path} has no faces of non-zero area "
                f"({len(loaded.faces)} degenerate faces only)"
            )
        mesh = trimesh.Trimesh(
            vertices=np.asarray(loaded.vertices, dtype=np.float64),
            faces=np.asarray(loaded.faces)[keep],
            process=False,
        )
        mesh.remove_unreferenced_vertices()
        return cls(mesh, np.full(len(mesh.faces), code, dtype=np.int32))

    @classmethod
    def from_heightfield(
        cls, x_m, y_m, z_m, material_codes, material_names: tuple[str, ...] = MATERIAL_NAMES
    ) -> Terrain:
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
            raise ValueError(
                f"material_codes must have shape ({ny}, {nx}) or "
                f"({ny - 1}, {nx - 1}), got {codes.shape}"
            )
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
        else:  # per node: a triangle takes the majority of (v00, v10, v11) / (v00, v11, v01)
            c00, c10 = codes[:-1, :-1][cell_ok], codes[:-1, 1:][cell_ok]
            c01, c11 = codes[1:, :-1][cell_ok], codes[1:, 1:][cell_ok]
            face_codes = np.empty(2 * n_ok, dtype=codes.dtype)
            for k, (a, b, d) in enumerate(((c00, c10, c11), (c00, c11, c01))):
                face_codes[k::2] = np.where((a == b) | (a == d), a, np.where(b == d, b, a))
        cell_face = np.full(cell_ok.shape, -1, dtype=np.int64)
        cell_face[cell_ok] = 2 * np.arange(n_ok)  # the mesh's faces, cell by cell (row-major)
        grid = HeightGrid(x.copy(), y.copy(), z.copy(), cell_face)
        return cls(
            None, face_codes.astype(np.int32), tuple(material_names), cell_ok.size - n_ok, grid
        )

    @classmethod
    def from_dem(
        cls, path, material: str = "snow", band: int = 1, nodata: str = "holes"
    ) -> Terrain:
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
            raise ImportError(
                "Terrain.from_dem needs rasterio: pip install chirplidar[dem]"
            ) from exc
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"DEM file not found: {path}")
        code = material_code(material)
        try:
            with rasterio.open(path) as src:
                if not 1 <= int(band) <= src.count:
                    raise ValueError(
                        f"DEM {path} has {src.count} band(s); band {band} does not exist"
                    )
                z = src.read(int(band)).astype(np.float64)
                nodata_value = src.nodata
                tr = src.transform
                if src.crs is not None and src.crs.is_geographic:
                    raise ValueError(
                        f"DEM {path} is in geographic coordinates; "
                        "reproject to a projected CRS in metres"
                    )
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
                    "or 'fill' (nearest valid height)"
                )
            if nodata == "fill":
                from scipy.ndimage import distance_transform_edt

                # indices of the nearest valid (mask 0) pixel for every pixel
                idx = distance_transform_edt(missing, return_distances=False, return_indices=True)
                z = z[tuple(idx)]
        try:
            return cls.from_heightfield(x, y, z, np.full(z.shape, code, dtype=np.int32))
        except ValueError as exc:
            raise ValueError(f"DEM {path}: {exc}") from exc


#: What ``Terrain.from_dem`` does with no-data pixels.
DEM_NODATA_MODES = ("holes", "fill", "error")
