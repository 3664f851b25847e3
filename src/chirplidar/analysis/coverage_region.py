"""The region of a coverage computation (:mod:`chirplidar.analysis.coverage`): a ``--bounds``
box, the runs' survey polygon or scene extent, the footprints' extent, or a GeoJSON polygon
(WGS-84) carried into the results' projected metres."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .coverage_files import BLOCK_SHOTS, CoverageError, ResultsFile


def region_polygon(region, bounds, files: list[ResultsFile], epsg: int):
    """(shapely geometry in projected metres, description dict)."""
    from shapely import wkt
    from shapely.geometry import box
    from shapely.ops import unary_union

    if bounds is not None:
        if region is not None:
            raise CoverageError("give --bounds or --region, not both")
        try:
            b = [float(v) for v in bounds]
        except (TypeError, ValueError):
            raise CoverageError(f"--bounds: expected XMIN,YMIN,XMAX,YMAX, got {bounds!r}") from None
        if len(b) != 4 or not all(math.isfinite(v) for v in b) or b[0] >= b[2] or b[1] >= b[3]:
            raise CoverageError(f"--bounds: expected four finite numbers XMIN,YMIN,XMAX,YMAX "
                                f"with XMIN < XMAX and YMIN < YMAX, got {bounds!r}")
        return box(*b), {"kind": "bounds", "bounds": b}
    kind = region
    if kind is None:   # the survey polygon, else the scene, else the footprints' extent
        kind = next((k for k, a in (("survey", "survey_wkt"), ("scene", "scene_wkt"))
                     if any(getattr(f, a) for f in files)), "footprints")
    if kind in ("survey", "scene"):
        attr = "survey_wkt" if kind == "survey" else "scene_wkt"
        shapes = [wkt.loads(getattr(f, attr)) for f in files if getattr(f, attr)]
        if not shapes:
            what = ("no survey polygon (a satellite pass or a waypoint path has none; use "
                    "--region scene, --bounds or a GeoJSON file)" if kind == "survey"
                    else "no scene extent (written by chirplidar run since coverage exists)")
            raise CoverageError(f"--region {kind}: {files[0].path} carries {what}")
        geom = unary_union(shapes)
        return geom, {"kind": kind, "bounds": list(geom.bounds)}
    if kind == "footprints":
        ext = _footprint_extent(files)
        return box(*ext), {"kind": "footprints", "bounds": list(ext)}
    return _geojson_region(Path(kind), epsg)


def _footprint_extent(files) -> tuple:
    """(xmin, ymin, xmax, ymax) of every footprint centre (a pass over x and y)."""
    lo, hi = np.array([np.inf, np.inf]), np.array([-np.inf, -np.inf])
    for f in files:
        per = max(f.obs_chunk, BLOCK_SHOTS // max(f.n_beams, 1))
        for o0 in range(0, f.n_obs, per):
            sl = (slice(None), slice(o0, o0 + per))
            for k, name in enumerate(("x", "y")):
                v = f.read(name, sl)
                v = v[np.isfinite(v)]
                if v.size:
                    lo[k], hi[k] = min(lo[k], v.min()), max(hi[k], v.max())
    if not np.all(np.isfinite(lo)) or np.any(hi <= lo):
        raise CoverageError(f"{files[0].path}: the footprints span no area (no surface in "
                            "any beam?); give --bounds")
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _geojson_region(path: Path, epsg: int):
    """A GeoJSON polygon (WGS-84 lon/lat) in the results' projected metres."""
    import shapely
    from pyproj import Transformer
    from shapely.geometry import shape
    from shapely.ops import unary_union
    from shapely.validation import explain_validity

    if path.suffix.lower() not in (".geojson", ".json"):
        raise CoverageError(f"--region {path}: expected survey, scene or a .geojson file")
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise CoverageError(f"--region {path}: cannot read it ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise CoverageError(f"--region {path}: not valid JSON ({exc.msg}, line {exc.lineno})") \
            from None
    feats = (data.get("features", []) if data.get("type") == "FeatureCollection"
             else [data.get("geometry", data)] if data.get("type") == "Feature" else [data])
    geoms = []
    for ft in feats:
        g = ft.get("geometry", ft) if isinstance(ft, dict) else None
        if isinstance(g, dict) and g.get("type") in ("Polygon", "MultiPolygon"):
            try:
                geoms.append(shape(g))
            except (ValueError, TypeError, IndexError, AttributeError) as exc:
                raise CoverageError(f"--region {path}: a bad polygon ({exc})") from None
    if not geoms:
        raise CoverageError(f"--region {path}: holds no Polygon or MultiPolygon")
    bad = [explain_validity(g) for g in geoms if not g.is_valid]
    if bad:
        raise CoverageError(f"--region {path}: not a simple polygon ({bad[0]}); "
                            "self-intersecting outlines are refused")
    lonlat = unary_union(geoms)
    lon0, lat0, lon1, lat1 = lonlat.bounds
    if not (-180 <= lon0 <= lon1 <= 360 and -90 <= lat0 <= lat1 <= 90):
        raise CoverageError(f"--region {path}: coordinates must be WGS-84 longitude, latitude "
                            f"in degrees (RFC 7946), got bounds {lonlat.bounds}")
    # edges are straight in lon/lat, curved in the projection: densify before transforming
    tr = Transformer.from_crs(4326, epsg, always_xy=True)
    geom = shapely.transform(shapely.segmentize(lonlat, 0.005), tr.transform, interleaved=False)
    if not geom.is_valid or geom.area <= 0:
        raise CoverageError(f"--region {path}: the polygon is not valid in EPSG:{epsg}")
    return geom, {"kind": "geojson", "file": str(path), "bounds": list(geom.bounds)}


def region_option(info: dict) -> str:
    """The option that gave the region (``--bounds`` or ``--region ...``), for messages."""
    return "--bounds" if info["kind"] == "bounds" else f"--region {info.get('file', info['kind'])}"


def format_bounds(b) -> str:
    """Bounds (xmin, ymin, xmax, ymax) as text for messages, whole metres."""
    return f"x {b[0]:.0f}..{b[2]:.0f} m, y {b[1]:.0f}..{b[3]:.0f} m"

