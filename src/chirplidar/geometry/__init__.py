"""Geometry: terrain meshes and DEMs, synthetic ice sheets, ray casting and beam footprints.

Frames and projections (ECEF, geodetic, EPSG:3413/3031 grids) are in :mod:`.frames`; flight
paths in :mod:`.paths`, orbits in :mod:`.orbits`, attitude, beams and per-shot geometry in
:mod:`.pointing`; generated terrain in :mod:`.synthetic_terrain`; ray casting in :mod:`.raycast`
and beam footprints in :mod:`.footprints`.
"""

from ..lazy import lazy_exports

# Imported on first use (PEP 562): the submodules pull in scipy and trimesh.
__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "footprints": ("FootprintStats", "footprint_statistics", "footprint_subrays"),
        "raycast": (
            "EmbreeUnavailableWarning",
            "RayHits",
            "cast_rays",
            "embree_available",
        ),
        "synthetic_terrain": (
            "SYNTHETIC_FEATURES",
            "flat_plane",
            "sloped_plane",
            "synthetic_ice_sheet",
            "vialov_height",
        ),
        "terrain": (
            "MATERIAL_CODES",
            "MATERIAL_NAMES",
            "Terrain",
            "material_code",
            "material_name",
        ),
    },
)

__all__ = [
    "MATERIAL_CODES",
    "MATERIAL_NAMES",
    "SYNTHETIC_FEATURES",
    "EmbreeUnavailableWarning",
    "FootprintStats",
    "RayHits",
    "Terrain",
    "cast_rays",
    "embree_available",
    "flat_plane",
    "footprint_statistics",
    "footprint_subrays",
    "material_code",
    "material_name",
    "sloped_plane",
    "synthetic_ice_sheet",
    "vialov_height",
]
