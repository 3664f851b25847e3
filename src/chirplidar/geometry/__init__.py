"""Geometry: terrain meshes and DEMs, synthetic ice sheets, ray casting and beam footprints.

Frames and projections (ECEF, geodetic, EPSG:3413/3031 grids) are in :mod:`.frames`; platforms,
paths, orbits and beams in :mod:`.platform`.
"""

from ..lazy import lazy_exports

# Imported on first use (PEP 562): the submodules pull in scipy and trimesh.
__getattr__, __dir__ = lazy_exports(__name__, {
    "raycast": ("EmbreeUnavailableWarning", "FootprintReturns", "RayHits", "bench_raycast",
                "cast_rays", "embree_available", "footprint_returns", "footprint_subrays"),
    "terrain": ("MATERIAL_CODES", "MATERIAL_NAMES", "SYNTHETIC_FEATURES", "Terrain", "flat_plane",
                "material_code", "material_name", "sloped_plane", "synthetic_ice_sheet",
                "vialov_height"),
})

__all__ = [
    "MATERIAL_CODES",
    "MATERIAL_NAMES",
    "SYNTHETIC_FEATURES",
    "EmbreeUnavailableWarning",
    "FootprintReturns",
    "RayHits",
    "Terrain",
    "bench_raycast",
    "cast_rays",
    "embree_available",
    "flat_plane",
    "footprint_returns",
    "footprint_subrays",
    "material_code",
    "material_name",
    "sloped_plane",
    "synthetic_ice_sheet",
    "vialov_height",
]
