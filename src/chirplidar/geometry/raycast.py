"""Ray casting on a :class:`~chirplidar.geometry.terrain.Terrain`: first hits and exact ranges
(beam footprints, as many sub-rays, are in :mod:`.footprints`).

* ``cast_rays``: first hit of every ray. Embree (float32 after the shift and scale to a box of
  about 100 units that trimesh's embree wrapper uses) finds the hit triangle; the range is then
  recomputed in float64 by intersecting the ray with that triangle's plane, so ranges are exact
  to far below a millimetre even at satellite distances. Without embree, trimesh's pure-numpy
  ``ray_triangle`` intersector is used (slow; warned once with :class:`EmbreeUnavailableWarning`).
* Heightfield terrains (``Terrain.grid``): a first hit lies where the ray crosses the terrain's
  height range, so embree gets only the grid cells under those stretches of the call's rays
  (plus one cell around them): its build costs in proportion to the cells a batch of rays can
  reach, not to the terrain. The cells' triangles are the terrain's own (same vertices, same
  float32 values, same face indices), so the hits are too (a ray exactly through an edge or
  vertex that triangles share may get either of them, as from any two embree structures, but
  always the same one for the same batch of rays). Where they would be more than
  ``CROP_MAX_FRACTION`` of the terrain, the whole terrain's structure is built (once per
  process) and used instead.

Misses: range, points and incidence are ``inf``, face index and material code ``-1`` (never NaN).
Incidence is the angle between -direction and the face normal folded to [0, pi/2] (surfaces are
two-sided: a mesh from a file may be wound either way).
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass

import numpy as np
import trimesh
from trimesh.ray import ray_triangle as _ray_triangle

from .terrain import HeightGrid, Terrain

#: The golden angle (rad): successive points of a Fibonacci spiral or lattice.
GOLDEN_ANGLE_RAD = np.pi * (3.0 - np.sqrt(5.0))


class EmbreeUnavailableWarning(UserWarning):
    """embreex is not importable: ray casting falls back to trimesh's slow intersector."""


try:  # embreex is a hard dependency, but keep a working (slow) path without it
    from embreex import rtcore_scene as _embree
    from embreex.mesh_construction import TriangleMesh as _EmbreeTriangles
except ImportError:  # pragma: no cover - depends on the environment
    _embree = None

_fallback_warned = False
_WHOLE_LOCK = threading.Lock()

#: A heightfield crop is built for a batch of rays only while it holds at most this share of
#: the terrain's faces; beyond it the whole terrain's structure (built once) is used.
CROP_MAX_FRACTION = 0.5
#: Ray stretches longer than this many cells are marked piecewise (a band along an oblique
#: ray, not its whole bounding box).
_PIECE_CELLS = 16


def embree_available() -> bool:
    return _embree is not None


@dataclass(frozen=True)
class RayHits:
    """First hits of n rays. Misses: ranges/points/incidence inf, face_index/material_codes -1."""

    ranges_m: np.ndarray  # (n,) distance origin -> hit along the unit direction (m)
    points_m: np.ndarray  # (n, 3) hit points (m)
    face_index: np.ndarray  # (n,) int64 face index into terrain.mesh.faces
    incidence_rad: np.ndarray  # (n,) angle between -direction and the face normal, [0, pi/2]
    material_codes: np.ndarray  # (n,) int32 codes into terrain.material_names

    @property
    def hit(self) -> np.ndarray:
        return self.face_index >= 0


# ---------------------------------------------------------------------- validation
def validated_rays(origins_m, directions):
    """(n, 3) float64 origins (m) and unit directions; ValueError naming a bad argument."""
    o = np.asarray(origins_m, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ValueError(f"origins_m must have shape (n, 3), got {o.shape}")
    if d.shape != o.shape:
        raise ValueError(f"directions must have the shape of origins_m {o.shape}, got {d.shape}")
    if not np.all(np.isfinite(o)):
        raise ValueError("origins_m must be finite")
    if not np.all(np.isfinite(d)):
        raise ValueError("directions must be finite")
    norm = np.sqrt(np.einsum("ij,ij->i", d, d))  # 3x faster than np.linalg.norm here
    if np.any(norm == 0):
        raise ValueError("directions must be non-zero vectors")
    return o, d / norm[:, None]


def _terrain(terrain):
    if not isinstance(terrain, Terrain):
        raise ValueError(f"terrain must be a Terrain, got {type(terrain).__name__}")  # noqa: TRY004 (project rule: ValueError)
    return terrain


# ---------------------------------------------------------------------- intersection
def _geometry(terrain: Terrain) -> dict:
    """Per-terrain constants: the padded bounding box and embree's float32 shift and scale."""
    c = terrain._cache
    if "box" not in c:
        lo, hi = terrain.bounds
        pad = max(1.0, 1e-4 * float(np.max(hi - lo)))
        c["box"] = (lo - pad, hi + pad)
        # trimesh's embree wrapper: shift to the lowest corner, scale the diagonal to 100
        diagonal = float(((hi - lo) ** 2).sum() ** 0.5)
        c["embree_frame"] = (lo.copy(), 100.0 / diagonal if diagonal > trimesh.tol.zero else 100.0)
    return c


class _EmbreeScene:
    """Embree scene of triangles in the terrain's float32 frame (see ``_geometry``).

    Every scene of a terrain, whole or cropped, shares that frame, so a triangle has the same
    float32 vertices in each and a ray the same float32 origin.
    """

    def __init__(self, vertices, faces, frame):
        self.origin, self.scale = frame
        self.scene = _embree.EmbreeScene()
        _EmbreeTriangles(
            scene=self.scene,
            vertices=((vertices - self.origin) * self.scale).astype(np.float32),
            indices=np.asarray(faces).astype(np.int32),
        )

    def first_hits(self, origins, directions) -> np.ndarray:
        """Index of the first triangle hit by each ray, -1 for a miss."""
        o = ((origins - self.origin) * self.scale).astype(np.float32)
        return np.asarray(self.scene.run(o, directions.astype(np.float32)), dtype=np.int64)


def whole_scene(terrain: Terrain) -> _EmbreeScene:
    """The embree scene of all of the terrain, built once (and committed: queries from several
    threads may then share it)."""
    c = terrain._cache
    with _WHOLE_LOCK:
        if "embree" not in c:
            scene = _EmbreeScene(
                np.asarray(terrain.mesh.vertices, dtype=np.float64),
                terrain.mesh.faces,
                _geometry(terrain)["embree_frame"],
            )
            scene.first_hits(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))  # commits it
            c["embree"] = scene
    return c["embree"]


def _whole_planes(terrain: Terrain):
    """``_face_planes`` of every face of the terrain, computed once (casts on the whole
    terrain then gather one row per hit)."""
    c = terrain._cache
    with _WHOLE_LOCK:
        if "planes" not in c:
            c["planes"] = _face_planes(terrain, np.arange(terrain.n_faces))
    return c["planes"]


def _height_grid(terrain: Terrain) -> HeightGrid:
    """The grid of a heightfield terrain (callers check ``terrain.grid`` first)."""
    if terrain.grid is None:
        raise ValueError("terrain has no height grid (not a heightfield)")
    return terrain.grid


def _reachable_cells(terrain: Terrain, origins, directions):
    """Flat indices (ascending) of the terrain cells of ``terrain.grid`` that can hold a first
    hit of the rays, or None when they are more than ``CROP_MAX_FRACTION`` of the terrain.

    A hit lies in the terrain's padded bounding box, so on the stretch of its ray inside that
    box; the cells under each stretch's x-y extent, one more all round (rounding), hold it.
    Long stretches are cut into pieces of about ``_PIECE_CELLS`` cells first.
    """
    grid = _height_grid(terrain)
    gx, gy = grid.x_m, grid.y_m
    ncx, ncy = gx.size - 1, gy.size - 1
    lo, hi = _geometry(terrain)["box"]
    t0, t1, meets = _box_clip(origins, directions, lo, hi)
    if not meets.all():
        origins, directions, t0, t1 = origins[meets], directions[meets], t0[meets], t1[meets]
    if origins.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)

    steps = grid.steps_m

    def cell(axis, step, v):
        """Index of the cell holding v (searchsorted; arithmetic on a uniform grid, where
        rounding may shift it by one: the margin covers that)."""
        if step is None:
            return np.searchsorted(axis, v, side="right") - 1
        return np.floor((v - axis[0]) / step).astype(np.int64)

    def cell_ranges(ta, tb):
        """Inclusive cell index ranges (with the margin) of the stretches ta..tb."""
        xa = origins[:, 0] + ta * directions[:, 0]
        xb = origins[:, 0] + tb * directions[:, 0]
        ya = origins[:, 1] + ta * directions[:, 1]
        yb = origins[:, 1] + tb * directions[:, 1]
        sx, sy = steps if steps is not None else (None, None)
        i0 = cell(gx, sx, np.minimum(xa, xb)) - 1
        i1 = cell(gx, sx, np.maximum(xa, xb)) + 1
        j0 = cell(gy, sy, np.minimum(ya, yb)) - 1
        j1 = cell(gy, sy, np.maximum(ya, yb)) + 1
        return (
            np.clip(i0, 0, ncx - 1),
            np.clip(i1, 0, ncx - 1),
            np.clip(j0, 0, ncy - 1),
            np.clip(j1, 0, ncy - 1),
        )

    i0, i1, j0, j1 = cell_ranges(t0, t1)
    pieces = 1 + np.maximum(i1 - i0, j1 - j0) // _PIECE_CELLS
    if pieces.max() > 1:
        total = int(pieces.sum())
        if total > ncx * ncy:  # stretches across the whole grid: no crop
            return None
        ray = np.repeat(np.arange(pieces.size), pieces)
        k = np.arange(total) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        span = (t1 - t0)[ray] / pieces[ray]
        origins, directions = origins[ray], directions[ray]
        i0, i1, j0, j1 = cell_ranges(t0[ray] + k * span, t0[ray] + (k + 1) * span)
    # Mark the rectangles of cells in a window around them: +-1 at their corners in a
    # difference array, then cumulative sums along both axes.
    wi, wj = int(i0.min()), int(j0.min())
    w, h = int(i1.max()) - wi + 2, int(j1.max()) - wj + 2
    corner = np.concatenate(
        [
            (j0 - wj) * w + (i0 - wi),
            (j1 + 1 - wj) * w + (i1 + 1 - wi),
            (j0 - wj) * w + (i1 + 1 - wi),
            (j1 + 1 - wj) * w + (i0 - wi),
        ]
    )
    n = i0.size
    diff = (
        np.bincount(corner[: 2 * n], minlength=w * h)
        - np.bincount(corner[2 * n :], minlength=w * h)
    ).reshape(h, w)
    covered = np.cumsum(np.cumsum(diff, axis=0), axis=1)[:-1, :-1] > 0
    faces = grid.cell_face[wj : wj + h - 1, wi : wi + w - 1]
    jj, ii = np.nonzero(covered & (faces >= 0))
    if 2 * jj.size > CROP_MAX_FRACTION * terrain.n_faces:
        return None
    return (jj + wj) * ncx + (ii + wi)


def _crop_scene(terrain: Terrain, cells):
    """Embree scene of the triangles of ``cells`` (flat cell indices of ``terrain.grid``) and
    the terrain face index of each of its triangles."""
    grid = _height_grid(terrain)
    nx = grid.x_m.size
    j, i = np.divmod(cells, nx - 1)
    n00 = j * nx + i  # node (j, i), as Terrain.from_heightfield numbers
    corners = (n00, n00 + 1, n00 + nx, n00 + nx + 1)  # v00, v10, v01, v11
    nodes = np.unique(np.concatenate(corners))
    v00, v10, v01, v11 = (np.searchsorted(nodes, c) for c in corners)
    faces = np.empty((2 * cells.size, 3), dtype=np.int64)
    faces[0::2] = np.column_stack([v00, v10, v11])  # the terrain's own triangles, in its
    faces[1::2] = np.column_stack([v00, v11, v01])  # vertex order
    nj, ni = np.divmod(nodes, nx)
    verts = np.column_stack([grid.x_m[ni], grid.y_m[nj], grid.z_m.ravel()[nodes]])
    face_of = np.empty(2 * cells.size, dtype=np.int64)
    face_of[0::2] = grid.cell_face.ravel()[cells]
    face_of[1::2] = face_of[0::2] + 1
    return _EmbreeScene(verts, faces, _geometry(terrain)["embree_frame"]), face_of


def _first_triangle(terrain: Terrain, origins, directions):
    """(tri, face_of): index of the first triangle hit by each ray (-1 for a miss) in the
    structure cast on, and the terrain face index of each of its triangles (None: they are
    the terrain's own indices, the whole terrain). Unit directions."""
    global _fallback_warned
    if origins.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), None
    if _embree is not None:
        cells = None if terrain.grid is None else _reachable_cells(terrain, origins, directions)
        if cells is None:
            return whole_scene(terrain).first_hits(origins, directions), None
        if cells.size == 0:
            return np.full(origins.shape[0], -1, dtype=np.int64), None
        scene, face_of = _crop_scene(terrain, cells)
        return scene.first_hits(origins, directions), face_of
    if not _fallback_warned:
        warnings.warn(
            "embreex is not available: using trimesh's ray_triangle intersector "
            "(orders of magnitude slower); pip install embreex",
            EmbreeUnavailableWarning,
            stacklevel=3,
        )
        _fallback_warned = True
    try:
        import rtree  # noqa: F401  (trimesh's ray_triangle builds an r-tree of the faces)
    except ImportError as exc:
        raise ImportError(
            "ray casting needs embreex (pip install embreex) or, for the slow "
            "fallback, rtree (pip install rtree)"
        ) from exc
    c = terrain._cache
    if "triangle" not in c:
        c["triangle"] = _ray_triangle.RayMeshIntersector(terrain.mesh)
    return np.asarray(c["triangle"].intersects_first(origins, directions), dtype=np.int64), None


def _face_planes(terrain: Terrain, faces):
    """Planes (k, 4) of faces -- unit normal and offset n.v0 -- and their first vertices v0
    (k, 3).

    Element-wise arithmetic only, so a face's plane is the same to the last bit whether it is
    computed alone or in a table (of a crop's faces).
    """
    v = terrain.face_vertices(faces)
    v0 = v[:, 0]
    nrm = np.cross(v[:, 1] - v0, v[:, 2] - v0)
    length = np.sqrt(nrm[:, 0] * nrm[:, 0] + nrm[:, 1] * nrm[:, 1] + nrm[:, 2] * nrm[:, 2])
    nrm = np.divide(nrm, length[:, None], out=np.zeros_like(nrm), where=length[:, None] > 0)
    offset = nrm[:, 0] * v0[:, 0] + nrm[:, 1] * v0[:, 1] + nrm[:, 2] * v0[:, 2]
    return np.column_stack([nrm, offset]), v0


def _box_clip(origins, directions, lo, hi):
    """Slab test: entry and exit parameters t0 >= 0, t1 and whether the ray meets the box.

    A zero direction component gives +-inf slab parameters (or NaN on the slab's face, which
    fmin/fmax ignore), so rays parallel to a slab are kept exactly when they lie inside it.
    """
    n = origins.shape[0]
    t0 = np.zeros(n)
    t1 = np.full(n, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(3):  # three axes, each vectorised over all rays
            ok = origins[:, k]
            inv = 1.0 / directions[:, k]
            ta = (lo[k] - ok) * inv
            tb = (hi[k] - ok) * inv
            np.fmax(t0, np.fmin(ta, tb), out=t0)
            np.fmin(t1, np.fmax(ta, tb), out=t1)
    return t0, t1, t0 <= t1


def cast_rays(terrain: Terrain, origins_m, directions) -> RayHits:
    """First hit of each ray on ``terrain``; vectorised, exact float64 ranges.

    origins_m (n, 3) in the terrain's projected metres; directions (n, 3), any non-zero length
    (normalised here). Ray casting starts at the entry into the mesh's (padded) bounding box, so
    far origins (satellites) do not lose float32 precision in embree; the range is then the
    float64 intersection of the full ray with the plane of the hit triangle.
    """
    terrain = _terrain(terrain)
    o, d = validated_rays(origins_m, directions)
    n = o.shape[0]
    ranges = np.full(n, np.inf)
    points = np.full((n, 3), np.inf)
    face = np.full(n, -1, dtype=np.int64)
    inc = np.full(n, np.inf)
    mat = np.full(n, -1, dtype=np.int32)
    if n == 0:
        return RayHits(ranges, points, face, inc, mat)
    lo, hi = _geometry(terrain)["box"]
    centre, size = 0.5 * (lo + hi), float(np.max(hi - lo))
    if np.max(np.abs(o - centre)) < 10.0 * size:
        # Origins near the terrain (UAV, aircraft): float32 in embree is fine from there and
        # rays that miss the box simply miss; no clipping pass (it costs a tenth of the cast).
        t0, cand = np.zeros(n), None
    else:
        t0, _, cand = _box_clip(o, d, lo, hi)
    if cand is None or cand.all():  # common case: no gather needed
        idx, oc, dc, tc = None, o, d, t0
    else:
        idx = np.flatnonzero(cand)
        oc, dc, tc = o[idx], d[idx], t0[idx]
    tri, face_of = _first_triangle(terrain, oc + dc * tc[:, None], dc)
    ok = tri >= 0
    if ok.all():
        oo, dd = oc, dc
        sel: np.ndarray | slice = slice(None) if idx is None else idx
    else:
        oo, dd, tri = oc[ok], dc[ok], tri[ok]
        sel = np.flatnonzero(ok) if idx is None else idx[ok]
        if tri.size == 0:
            return RayHits(ranges, points, face, inc, mat)
    # the planes of the structure's faces (the whole terrain's: once), one gather per hit
    # (np.take: ~6x faster than fancy indexing rows)
    planes, v0 = _whole_planes(terrain) if face_of is None else _face_planes(terrain, face_of)
    pl = np.take(planes, tri, axis=0)
    nrm = pl[:, :3]
    ndotd = np.einsum("ij,ij->i", nrm, dd)
    num = pl[:, 3] - np.einsum("ij,ij->i", nrm, oo)
    grazing = np.abs(ndotd) < 1e-12
    if grazing.any():  # ray (numerically) in the face's plane: range to its first vertex
        gi = np.flatnonzero(grazing)
        num[gi] = np.einsum("ij,ij->i", v0[tri[gi]] - oo[gi], dd[gi])
        ndotd_safe = ndotd.copy()
        ndotd_safe[gi] = 1.0
        t = num / ndotd_safe
    else:
        t = num / ndotd
    if face_of is not None:
        tri = np.take(face_of, tri)
    ranges[sel] = t
    points[sel] = oo + dd * t[:, None]
    face[sel] = tri
    inc[sel] = np.arccos(np.minimum(np.abs(ndotd), 1.0))
    mat[sel] = np.take(terrain.face_materials, tri)
    return RayHits(ranges, points, face, inc, mat)


# ---------------------------------------------------------------------- benchmark
