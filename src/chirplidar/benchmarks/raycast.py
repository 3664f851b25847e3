"""``chirplidar bench --what raycast``: rays per second of the project's ray casting against the
raw embree call on the same rays, timed in the same run."""

from __future__ import annotations

import time

import numpy as np


def bench_raycast(n_triangles: int = 1_000_000, n_rays: int = 200_000, *, repeats: int = 3):
    """Rays per second of ``cast_rays`` (with float64 refinement) and of the raw trimesh embree
    call (``RayMeshIntersector.intersects_first``) on the same rays, timed in the same run.

    Terrain: a flat plane gridded to at least n_triangles triangles (1 m step) at z = 0 with a
    deterministic ripple; rays: a deterministic lattice from 100 m altitude, up to 5 deg off
    nadir. The embree scene build is excluded from both timings (reported separately). Best of
    ``repeats``. Returns {"project_rays_per_s", "embree_rays_per_s", "ratio", "n_triangles",
    "n_rays", "build_s", "hit_fraction"}; ratio = project / embree.
    """
    import trimesh

    from ..geometry.raycast import GOLDEN_ANGLE_RAD, cast_rays, embree_available, whole_scene
    from ..geometry.synthetic_terrain import flat_plane
    from ..geometry.terrain import Terrain

    if not embree_available():
        raise RuntimeError("bench_raycast needs embreex (pip install embreex)")
    from trimesh.ray import ray_pyembree

    n_triangles, n_rays = int(n_triangles), int(n_rays)
    if n_triangles < 2 or n_rays < 1:
        raise ValueError(f"n_triangles >= 2 and n_rays >= 1 required, got {n_triangles}, {n_rays}")
    side = int(np.ceil(np.sqrt(n_triangles / 2.0))) + 1  # nodes per side
    terr = flat_plane(0.0, (0.0, side - 1.0, 0.0, side - 1.0), 1.0)
    v = terr.mesh.vertices.copy()
    v[:, 2] = 0.3 * np.sin(v[:, 0] / 7.0) * np.cos(v[:, 1] / 11.0)
    terr = Terrain(trimesh.Trimesh(v, terr.mesh.faces, process=False), terr.face_materials)
    k = np.arange(n_rays, dtype=np.float64)
    span = side - 1.0
    alt = 100.0  # 5 deg off nadir: <= 8.8 m offset on the ground
    inset = 0.1 * span
    xs = inset + (k * 0.6180339887498949) % 1.0 * (span - 2 * inset)
    ys = inset + (k + 0.5) / n_rays * (span - 2 * inset)
    origins = np.column_stack([xs, ys, np.full(n_rays, alt)])
    off = np.deg2rad(5.0) * ((k * 0.7548776662466927) % 1.0)
    az = k * GOLDEN_ANGLE_RAD
    dirs = np.column_stack([np.sin(off) * np.cos(az), np.sin(off) * np.sin(az), -np.cos(off)])
    inter = ray_pyembree.RayMeshIntersector(terr.mesh)
    inter.intersects_first(origins[:1], dirs[:1])  # builds trimesh's scene
    t = time.perf_counter()
    whole_scene(terr).first_hits(origins[:1], dirs[:1])  # builds ours
    build_s = time.perf_counter() - t
    best_p = best_e = np.inf
    for _ in range(max(1, int(repeats))):
        t = time.perf_counter()
        inter.intersects_first(origins, dirs)
        best_e = min(best_e, time.perf_counter() - t)
        t = time.perf_counter()
        hits = cast_rays(terr, origins, dirs)
        best_p = min(best_p, time.perf_counter() - t)
    p, e = n_rays / best_p, n_rays / best_e
    return {
        "project_rays_per_s": p,
        "embree_rays_per_s": e,
        "ratio": p / e,
        "n_triangles": terr.n_faces,
        "n_rays": n_rays,
        "build_s": build_s,
        "hit_fraction": float(hits.hit.mean()),
    }
