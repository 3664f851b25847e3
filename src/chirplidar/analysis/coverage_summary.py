"""The summary of a coverage computation (:mod:`chirplidar.analysis.coverage`): the covered
fraction, the largest gap (branch and bound), the median precisions, spacings, crossovers and
revisits, and its JSON form."""

from __future__ import annotations

import json
import math

import numpy as np

from .coverage_tracks import across_track_spacing, spacing_median

GAP_TOLERANCE_PER_CELL = 20    # largest gap: branch and bound to within C / 20

#: The summary's keys, in order (``--json``).
SUMMARY_KEYS = ("cells_in_region", "cells_covered", "fraction_covered", "largest_gap_m",
                "median_detections_per_cell", "median_height_precision_m",
                "median_height_precision_predicted_m", "along_track_spacing_m",
                "across_track_spacing_m", "track_length_m", "flight_time_s", "crossovers",
                "crossover_rms_m", "cells_revisited", "median_revisit_s", "shots",
                "detected_shots", "footprints_on_cell_edges",
                "cell_m", "min_detections",
                "map_scale_factor", "region", "files")


def largest_gap(tree, points, geom, cell_m: float, x0: float, y0: float, nx: int,
                ny: int) -> float:
    """Largest distance from a point of ``geom`` to the nearest of ``points`` (the
    representatives, indexed by the k-d ``tree``), to within ``cell_m`` /
    :data:`GAP_TOLERANCE_PER_CELL`: branch and bound on square boxes, the grid's cells first.

    Bound: if q is the nearest point to a box's centre, no point p of the box is farther from
    its nearest point than |p - q| <= |k - q|, k the box's corner farthest from q (|p - q| is
    convex, so its maximum over the box is at a corner). The best value so far is the distance
    at a point of the region: a box centre or that corner when inside it, else the region's
    point nearest the corner. A box whose bound does not beat the best by more than the
    tolerance is dropped, the others are split in four. Between two parallel tracks the corner
    next to the ridge reaches the ridge's distance at once, so the long ridges halfway between
    survey lines end at the first levels."""
    import shapely

    shapely.prepare(geom)
    boundary = geom.boundary
    hs = cell_m / 2.0                       # half side
    gx, gy = np.meshgrid(x0 + (np.arange(nx) + 0.5) * cell_m, y0 + (np.arange(ny) + 0.5) * cell_m)
    cx, cy = gx.ravel(), gy.ravel()
    tol = cell_m / GAP_TOLERANCE_PER_CELL
    best = 0.0

    def lower(px, py):   # distance at region points: these, or the region's nearest points
        inside = shapely.intersects_xy(geom, px, py)
        d = tree.query(np.column_stack([px[inside], py[inside]]))[0] if inside.any() else []
        out = np.flatnonzero(~inside)
        if out.size:
            at = shapely.get_coordinates(shapely.shortest_line(shapely.points(px[out], py[out]),
                                                               boundary))[1::2]
            d = np.concatenate([d, tree.query(at)[0]])
        return float(np.max(d))

    while cx.size:
        h = hs * math.sqrt(2.0)
        inside = shapely.intersects_xy(geom, cx, cy)
        out = np.flatnonzero(~inside)
        if out.size:   # keep the boxes the region reaches (its boundary within h of the centre)
            reach = inside.copy()
            reach[out] = shapely.distance(boundary, shapely.points(cx[out], cy[out])) <= h
            cx, cy, inside = cx[reach], cy[reach], inside[reach]
            if cx.size == 0:
                break
        d, idx = tree.query(np.column_stack([cx, cy]))
        if inside.any():
            best = max(best, float(d[inside].max()))
        q = points[idx]
        kx = cx + np.where(cx >= q[:, 0], hs, -hs)
        ky = cy + np.where(cy >= q[:, 1], hs, -hs)
        bound = np.hypot(kx - q[:, 0], ky - q[:, 1])
        cand = bound > best + tol
        if cand.any():
            best = max(best, lower(kx[cand], ky[cand]))
        live = bound > best + tol
        cx, cy, q, hs = cx[live], cy[live], q[live], hs / 2.0
        cx = np.concatenate([cx - hs, cx + hs, cx - hs, cx + hs])
        cy = np.concatenate([cy - hs, cy - hs, cy + hs, cy + hs])
        # the parent's nearest point bounds a child too: drop those it settles, unqueried
        q = np.concatenate([q] * 4)
        far = np.hypot(np.abs(cx - q[:, 0]) + hs, np.abs(cy - q[:, 1]) + hs) > best + tol
        cx, cy = cx[far], cy[far]
    return best


def _map_scale_factor(geom, epsg: int) -> float:
    """The map scale factor (meridional) of the projection at the region's centroid."""
    from pyproj import Proj, Transformer

    c = geom.centroid
    lon, lat = Transformer.from_crs(epsg, 4326, always_xy=True).transform(c.x, c.y)
    return float(Proj(f"EPSG:{epsg}").get_factors(lon, lat).meridional_scale)


def coverage_summary(grid, acc, crossovers, geom, region_info, cell_m, min_detections, epsg,
                     paths) -> dict:
    """The summary dict (:data:`SUMMARY_KEYS`) of a coverage grid, its accumulated sums
    ``acc``, crossovers and region ``geom``."""
    inr = grid["in_region"].values == 1
    n_in = int(inr.sum())
    covered = int(grid["covered"].values.sum())
    det = grid["detected_shots"].values[inr]
    std = grid["height_error_std"].values[inr]
    sig = grid["height_sigma_predicted"].values[inr]
    dh = crossovers["dh"].values
    dh = dh[np.isfinite(dh)]

    def median(a):
        a = a[np.isfinite(a)]
        return float(np.median(a)) if a.size else float("nan")

    gap = largest_gap(acc["tree"], acc["reps"], geom, cell_m, float(grid.x[0]) - cell_m / 2,
                      float(grid.y[0]) - cell_m / 2, acc["nx"], acc["ny"])
    return {
        "cells_in_region": n_in, "cells_covered": covered,
        "fraction_covered": covered / n_in if n_in else float("nan"),
        "largest_gap_m": gap,
        "median_detections_per_cell": float(np.median(det)) if det.size else float("nan"),
        "median_height_precision_m": median(std),
        "median_height_precision_predicted_m": median(sig),
        "along_track_spacing_m": spacing_median(acc["spacing_hist"]),
        "across_track_spacing_m": across_track_spacing(acc["tracks"]),
        "track_length_m": acc["track_length_m"], "flight_time_s": acc["flight_time_s"],
        "crossovers": int(crossovers.sizes["crossover"]),
        "crossover_rms_m": float(np.sqrt(np.mean(dh ** 2))) if dh.size else float("nan"),
        "cells_revisited": int(np.count_nonzero(grid["detected_tracks"].values[inr] >= 2)),
        "median_revisit_s": median(grid["revisit_median_s"].values[inr]),
        "shots": int(acc["n_shots"]), "detected_shots": int(acc["n_detected"]),
        "footprints_on_cell_edges": acc["n_on_edge"] / max(acc["n_in_grid"], 1),
        "cell_m": float(cell_m), "min_detections": int(min_detections),
        "map_scale_factor": _map_scale_factor(geom, epsg),
        "region": {**region_info, "epsg": epsg}, "files": [str(p) for p in paths],
    }


def jsonable(obj):
    """``obj`` (dicts, lists, numbers, strings) with numpy numbers as Python ones and
    non-finite numbers as None: what ``json.dumps(..., allow_nan=False)`` takes."""
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (bool, str)) or obj is None:
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    f = float(obj)
    return f if math.isfinite(f) else None


def summary_json(summary: dict) -> str:
    """The summary as one JSON object (non-finite numbers as null)."""
    return json.dumps(jsonable({k: summary[k] for k in SUMMARY_KEYS}), allow_nan=False)

