"""Coverage of survey results on a regular grid: where the footprints fell, what was detected,
how precise the heights are, where the gaps are, and where tracks cross (crossovers).

Input: one or more results files of ``chirplidar run`` (CF trajectory NetCDF, see
:mod:`chirplidar.mission.results`) in one projection. Output: a :class:`CoverageResult` with

* ``grid``: an ``xarray.Dataset`` on cells of ``cell_m`` in the results' projected metres, dims
  ``(y, x)``, cell (i, j) covering ``[x0 + i C, x0 + (i + 1) C) x [y0 + j C, y0 + (j + 1) C)``;
  a shot belongs to the cell that holds its footprint centre (``x``, ``y``);
* ``summary``: one dict of figures (cells in the region, covered, largest gap, spacings,
  crossovers ...);
* ``crossovers``: an ``xarray.Dataset`` with one row per crossing of two tracks.

Definitions
-----------
* Shots: shot-beam pairs with a surface in the beam (finite ``x``, ``y``); ``detected`` ones have
  ``detected == 1``.
* Tracks: a results file's survey lines or its pass (``track``; files written before the
  variable existed count as one track). Distinct tracks of a cell are distinct (file, track)
  pairs: the beams of one line or pass are one track, and a file's turns and transits
  (``track == -1``) count as one. Crossovers are sought between the footprint tracks of each
  beam of each line or pass (turns and transits left out), of different (file, track) pairs.
* Heights: ``height_error_std`` is the sample standard deviation of ``h_li - h_li_true`` over a
  cell's detected shots (two or more), the measured precision of one shot;
  ``height_sigma_predicted`` the RMS of their ``h_li_sigma`` (the Cramer-Rao spread each shot
  predicts); ``height_precision_measured`` and ``height_precision_predicted`` are these divided
  by sqrt(N), the precision of the cell's mean height from N detected shots.
* ``median_snr_db``: median of ``snr_db`` over the cell's shots (detected or not), from a
  histogram per cell over ``SNR_RANGE_DB`` (0.1 dB bins up to 2^24 / 1202 cells, coarser for
  more; the width used is in the variable's ``comment``), interpolated linearly within the
  median's bin (the grouped median: exact to the bin width, closer where the SNRs spread over
  several bins); -inf where the median lies below the range (or the power is zero).
* ``gap``: distance from the cell centre to the nearest detected footprint centre. The
  detections are represented by the centres of the pixels of ``cell_m / GAP_PIXELS_PER_CELL``
  that hold one, so a distance is off by half a pixel diagonal at most (C / 28).
* ``largest_gap_m``: the largest distance from any point of the region to the nearest detected
  footprint centre, found by branch and bound on boxes (:func:`_largest_gap`) to within C/20
  of the representatives' value: C/20 + C/28 < C/10 of the true largest gap.
* Cell edges: a track flown along a grid line puts its footprints, scattered by the pointing
  noise, in the cells on both sides. ``footprints_on_cell_edges`` in the summary is the fraction
  of the footprints within C / 100 of an edge (about 4 % for scattered ones); the command line
  warns above a quarter.
* Crossovers: the tracks' footprint polylines are thinned to vertices every ``cell_m / 2`` along
  track (:data:`TRACK_STEP_PER_CELL`; a beam whose footprints do not follow a line, a conical
  scan, has none), intersected where they cross at 5 degrees or more (a repeated line is not a
  crossover), and each crossing is refined on the full-rate
  footprints around it: the crossing point of the two full-rate polylines, each track's time
  there (interpolated), and the nearest detected shot of each track: ``dh = h_li(later) -
  h_li(earlier)`` (the crossover residual altimetry missions check themselves with) and
  ``dh_true``, the same for ``h_li_true`` (what the footprints' offset on a sloping surface adds).
* Distances, spacings and lengths are in projected metres (the grid's units); the map scale
  factor at the region's centre (``map_scale_factor`` in the summary, within 4 % of 1 in the
  polar stereographic grids) turns them into metres on the ground (divide by it).

Memory: the files are read block by block along ``obs`` (about ``BLOCK_SHOTS`` shot-beams);
what is kept grows with the grid, the SNR bins and pixels occupied and the thinned tracks, not
with the number of shots.

Example
-------
>>> from chirplidar.analysis.coverage import compute_coverage       # doctest: +SKIP
>>> cov = compute_coverage(["outputs/greenland_uav.nc"], cell_m=100.0)  # doctest: +SKIP
>>> cov.summary["fraction_covered"], cov.summary["largest_gap_m"]      # doctest: +SKIP
>>> cov.grid["detected_shots"].plot()                                  # doctest: +SKIP
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from ..mission.results import NETCDF_LOCK
from .coverage_tracks import (TRACK_STEP_PER_CELL, TrackBuilder, across_track_spacing,
                              spacing_median)
from .coverage_tracks import crossovers as track_crossovers

__all__ = ["CoverageResult", "CoverageError", "GRID_VARIABLES", "SUMMARY_KEYS",
           "compute_coverage", "summary_json", "write_coverage"]

BLOCK_SHOTS = 1 << 20          # shot-beams read per block
WINDOW_CACHE_BYTES = 1 << 28   # crossovers: HDF5 chunks kept decompressed (at least two)
EDGE_BAND = 0.01               # footprints closer than C / 100 to a cell edge are "on" it ...
EDGE_WARNING = 0.25            # ... which ~4 % of scattered ones are; above this, a warning
SNR_RANGE_DB = (-30.0, 90.0)   # per-cell SNR histograms: this range, plus under/overflow bins
SNR_BIN_CHOICES_DB = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)   # the finest whose histograms fit:
SNR_HISTOGRAM_ENTRIES = 1 << 24  # cells x bins at most (64 MB of counts)
GAP_PIXELS_PER_CELL = 20       # detection representatives: pixels of cell_m / 20
GAP_TOLERANCE_PER_CELL = 20    # largest gap: branch and bound to within C / 20
FLIGHT_PAUSE_S = 60.0          # a longer step of the shot clock is a pause (between passes)
PLATFORM_STRIDE = 8            # flight length: chords over 8 shots (a turn of radius r at chord
                               # length s reads s^2 / (24 r^2) short: 1e-5 for 1.6 m, r = 100 m)

#: The summary's keys, in order (``--json``).
SUMMARY_KEYS = ("cells_in_region", "cells_covered", "fraction_covered", "largest_gap_m",
                "median_detections_per_cell", "median_height_precision_m",
                "median_height_precision_predicted_m", "along_track_spacing_m",
                "across_track_spacing_m", "track_length_m", "flight_time_s", "crossovers",
                "crossover_rms_m", "cells_revisited", "median_revisit_s", "shots",
                "detected_shots", "footprints_on_cell_edges",
                "cell_m", "min_detections",
                "map_scale_factor", "region", "files")

_READ = ("x", "y", "detected", "snr_db", "h_li", "h_li_true", "h_li_sigma", "delta_time",
         "track", "platform_x", "platform_y")
_BLOCK_VARIABLES = tuple(v for v in _READ if v != "delta_time")   # its ends are read alone


class CoverageError(ValueError):
    """Bad input to a coverage computation (one line naming the file, option or key)."""


# ----------------------------------------------------------------------------------- files
@dataclass
class _File:
    """A results file opened for reading (h5py), with what coverage needs from its header."""

    path: Path
    index: int
    h5: object
    epsg: int
    n_beams: int
    n_obs: int
    obs_chunk: int
    has: frozenset
    survey_wkt: str | None
    scene_wkt: str | None
    epoch: _dt.datetime | None    # mission epoch: delta_time = 0

    _cache: dict = field(default_factory=dict)   # HDF5 chunk index -> window variables

    @property
    def epoch_s(self) -> float:
        """The mission epoch as Unix seconds (0 when the file has none): absolute times for
        comparing files."""
        return self.epoch.timestamp() if self.epoch is not None else 0.0

    def read(self, name: str, sl) -> np.ndarray:
        with NETCDF_LOCK:
            return self.h5[name][sl]

    def window(self, beam: int, o_lo: int, o_hi: int, names) -> dict:
        """Variables ``names`` of one beam over obs ``o_lo..o_hi`` (clipped to the file), read
        by whole HDF5 chunks kept in a small cache (crossovers revisit the same chunks)."""
        o_lo, o_hi = max(0, o_lo), min(self.n_obs, o_hi)
        c0, c1 = o_lo // self.obs_chunk, (o_hi - 1) // self.obs_chunk
        parts = []
        for c in range(c0, c1 + 1):
            block = self._cache.get(c)
            if block is None:
                sl = (slice(None), slice(c * self.obs_chunk, (c + 1) * self.obs_chunk))
                block = {k: self.read(k, sl) for k in names if k in self.has}
                size = self.obs_chunk * self.n_beams * 8 * len(names)
                if len(self._cache) >= max(2, WINDOW_CACHE_BYTES // size):
                    self._cache.pop(next(iter(self._cache)))   # the oldest
                self._cache[c] = block
            parts.append(block)
        lo = o_lo - c0 * self.obs_chunk
        return {k: np.concatenate([p[k][beam] for p in parts])[lo:lo + o_hi - o_lo]
                for k in parts[0]}

    def close(self) -> None:
        with NETCDF_LOCK:
            self.h5.close()


def _attr_str(value) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return _attr_str(value.reshape(-1)[0]) if value.size else None
    return str(value)


def _epoch(value) -> _dt.datetime | None:
    text = _attr_str(value)
    try:
        return _dt.datetime.fromisoformat(text.replace("Z", "+00:00")) if text else None
    except ValueError:
        return None


def _open(path, index: int) -> _File:
    import h5py

    path = Path(path)
    if not path.is_file():
        raise CoverageError(f"{path}: results file does not exist")
    try:
        with NETCDF_LOCK:
            h5 = h5py.File(path, "r")
    except OSError as exc:
        raise CoverageError(f"{path}: not a readable results file (NetCDF-4/HDF5): {exc}") \
            from None
    try:
        attrs = h5.attrs
        missing = [v for v in ("x", "y", "detected", "delta_time") if v not in h5]
        if missing or _attr_str(attrs.get("featureType")) != "trajectory":
            raise CoverageError(f"{path}: not a chirplidar results file (needs a CF trajectory "
                                f"with x, y, detected, delta_time; missing {missing or 'featureType'})")
        code = _attr_str(attrs.get("epsg_code")) or ""
        if not code.upper().startswith("EPSG:"):
            raise CoverageError(f"{path}: no epsg_code attribute: cannot tell its projection")
        shape = h5["x"].shape
        chunks = h5["x"].chunks
        return _File(path=path, index=index, h5=h5, epsg=int(code.split(":")[1]),
                     n_beams=int(shape[0]), n_obs=int(shape[1]),
                     obs_chunk=int(chunks[1]) if chunks else max(1, int(shape[1])),
                     has=frozenset(v for v in _READ if v in h5),
                     survey_wkt=_attr_str(attrs.get("survey_polygon_wkt")),
                     scene_wkt=_attr_str(attrs.get("scene_extent_wkt")),
                     epoch=_epoch(attrs.get("mission_epoch")))
    except BaseException:
        with NETCDF_LOCK:
            h5.close()
        raise


def _blocks(f: _File, names):
    """(obs start, dict name -> (n_beams, m) array) over the file, HDF5-chunk aligned, for the
    variables ``names`` the file has. The arrays are buffers reused from block to block (fresh
    ones would cost their page faults again: 25 % of the reading): copy what must outlive one."""
    per = max(1, BLOCK_SHOTS // max(f.n_beams, 1))
    step = max(f.obs_chunk, (per // f.obs_chunk) * f.obs_chunk)
    names = [n for n in names if n in f.has]
    with NETCDF_LOCK:
        dsets = {n: f.h5[n] for n in names}
        bufs = {n: np.empty((f.n_beams, min(step, f.n_obs)), dsets[n].dtype) for n in names}
    for o0 in range(0, f.n_obs, step):
        m = min(f.n_obs, o0 + step) - o0
        with NETCDF_LOCK:
            for n in names:
                dsets[n].read_direct(bufs[n], np.s_[:, o0:o0 + m], np.s_[:, :m])
        yield o0, {n: b[:, :m] for n, b in bufs.items()}


# ----------------------------------------------------------------------------------- region
def _region_polygon(region, bounds, files: list[_File], epsg: int):
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


# ----------------------------------------------------------------------------------- accumulators
class _KeySet:
    """A set of int64 keys, added block by block: each block's keys not yet in the sorted
    set wait in a list, merged into it once they reach a quarter of its size (or 2^20), so
    memory stays near the number of distinct keys however often they recur."""

    def __init__(self):
        self._keys = np.zeros(0, np.int64)     # sorted, distinct
        self._new: list[np.ndarray] = []
        self._n_new = 0

    def add(self, keys: np.ndarray) -> None:
        """Add distinct sorted ``keys`` (``np.unique``'s output)."""
        if keys.size == 0:
            return
        if self._keys.size:
            at = np.minimum(np.searchsorted(self._keys, keys), self._keys.size - 1)
            keys = keys[self._keys[at] != keys]
        if keys.size:
            self._new.append(keys)
            self._n_new += keys.size
            if self._n_new > max(1 << 20, self._keys.size // 4):
                self._merge()

    def _merge(self) -> None:
        if self._new:
            self._keys = np.union1d(self._keys, np.concatenate(self._new))
            self._new, self._n_new = [], 0

    def keys(self) -> np.ndarray:
        self._merge()
        return self._keys


class _Representatives:
    """The pixels that hold a detected footprint centre; a pixel's centre represents them (no
    detection is farther than half its diagonal from its pixel's centre)."""

    def __init__(self, x0: float, y0: float, pixel_m: float):
        self.x0, self.y0, self.pixel = x0, y0, pixel_m
        self._pixels = _KeySet()

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        if x.size == 0:
            return
        inv = 1.0 / self.pixel    # pixel indices offset by 2^30: the key stays positive
        fx, fy = np.floor((x - self.x0) * inv), np.floor((y - self.y0) * inv)
        if max(-fx.min(), fx.max(), -fy.min(), fy.max()) >= (1 << 30):
            raise CoverageError(f"--cell-m {self.pixel * GAP_PIXELS_PER_CELL:g}: too small for "
                                "footprints this far from the region (give larger cells)")
        keys = fx.astype(np.int64) + (1 << 30)
        keys <<= 32
        keys |= fy.astype(np.int64) + (1 << 30)
        # consecutive shots share pixels, or alternate between two across a pixel edge: drop
        # repeats of the last two keys before the sort
        keep = np.ones(keys.size, bool)
        np.not_equal(keys[1:], keys[:-1], out=keep[1:])
        keep[2:] &= keys[2:] != keys[:-2]
        self._pixels.add(np.unique(keys[keep]))

    def points(self) -> np.ndarray:
        """(n, 2) centres of the pixels with a detection."""
        keys = self._pixels.keys()
        ix = (keys >> 32) - (1 << 30)
        iy = (keys & 0xFFFFFFFF) - (1 << 30)
        return np.column_stack([self.x0 + (ix + 0.5) * self.pixel,
                                self.y0 + (iy + 0.5) * self.pixel])


# ----------------------------------------------------------------------------------- result
@dataclass(frozen=True)
class CoverageResult:
    """``grid`` (CF grid Dataset), ``summary`` (dict, :data:`SUMMARY_KEYS`), ``crossovers``
    (Dataset, dim ``crossover``) and the region (shapely geometry, projected metres)."""

    grid: xr.Dataset
    summary: dict
    crossovers: xr.Dataset
    region: object
    epsg: int
    tracks: tuple = ()      # the thinned footprint tracks: (x, y) arrays, for maps


def compute_coverage(paths, *, cell_m: float, region=None, bounds=None,
                     min_detections: int = 1, progress: bool = False,
                     grid_shift_m: tuple[float, float] = (0.0, 0.0)) -> CoverageResult:
    """Coverage of the results files ``paths`` on cells of ``cell_m`` projected metres.

    ``region``: ``"survey"`` (the runs' survey polygon; the default where one exists),
    ``"scene"`` (the scene extent) or a GeoJSON file (WGS-84 polygon); or ``bounds`` =
    (xmin, ymin, xmax, ymax) in the results' projected metres. A cell is in the region when its
    centre is (on the boundary counts); it is covered with ``min_detections`` or more detected
    shots. CoverageError (one line) on bad input: no files, files in different projections,
    a cell size <= 0 or larger than the region, a region that misses every footprint, no
    detected shot at all. The grid starts at the region's lower-left corner, moved back by
    ``grid_shift_m`` (x, y) [m] (``chirplidar plan`` checks a second grid shifted by half a
    cell: survey lines on cell edges cover both neighbours in one grid and one in the other).
    """
    from shapely import intersects_xy, wkt
    from shapely.geometry import box

    paths = [Path(p) for p in (paths if isinstance(paths, (list, tuple)) else [paths])]
    if not paths:
        raise CoverageError("no results file given")
    try:
        cell_m = float(cell_m)
    except (TypeError, ValueError):
        raise CoverageError(f"--cell-m: expected a number of metres, got {cell_m!r}") from None
    if not math.isfinite(cell_m) or cell_m <= 0:
        raise CoverageError(f"--cell-m: the cell size must be a positive number of metres, "
                            f"got {cell_m:g}")
    if isinstance(min_detections, (bool, np.bool_)) or int(min_detections) != min_detections \
            or min_detections < 1:
        raise CoverageError(f"--min-detections: expected an integer >= 1, got {min_detections!r}")
    min_detections = int(min_detections)

    seen: dict = {}
    for p in paths:
        key = p.resolve()
        if key in seen:
            raise CoverageError(f"{p}: given twice (also as {seen[key]}): its shots would count "
                                "twice")
        seen[key] = p
    files: list[_File] = []
    try:
        for i, p in enumerate(paths):
            files.append(_open(p, i))
        epsgs = sorted({f.epsg for f in files})
        if len(epsgs) > 1:
            which = ", ".join(f"{f.path} (EPSG:{f.epsg})" for f in files)
            raise CoverageError(f"the results files are in different projections: {which}; "
                                "coverage needs one grid")
        epsg = epsgs[0]
        geom, region_info = _region_polygon(region, bounds, files, epsg)
        scenes = [wkt.loads(f.scene_wkt) for f in files if f.scene_wkt]
        if scenes and not any(geom.intersects(sc) for sc in scenes):
            raise CoverageError(f"{_region_option(region_info)}: the region "
                                f"{_fmt_bounds(geom.bounds)} (EPSG:{epsg}) misses the results' "
                                f"scenes ({'; '.join(_fmt_bounds(sc.bounds) for sc in scenes)})")
        rx0, ry0, rx1, ry1 = geom.bounds
        rx0, ry0 = rx0 - float(grid_shift_m[0]), ry0 - float(grid_shift_m[1])
        if cell_m > max(rx1 - rx0, ry1 - ry0):
            raise CoverageError(f"--cell-m {cell_m:g}: larger than the region "
                                f"({rx1 - rx0:.0f} m x {ry1 - ry0:.0f} m)")
        nx = max(1, int(math.ceil((rx1 - rx0) / cell_m - 1e-9)))
        ny = max(1, int(math.ceil((ry1 - ry0) / cell_m - 1e-9)))
        if nx * ny > 50_000_000:
            raise CoverageError(f"--cell-m {cell_m:g}: {nx} x {ny} cells over the region; "
                                "choose larger cells or a smaller region")
        xc = rx0 + (np.arange(nx) + 0.5) * cell_m
        yc = ry0 + (np.arange(ny) + 0.5) * cell_m
        in_region = intersects_xy(geom, *np.meshgrid(xc, yc)).astype(np.int8)
        acc = _accumulate(files, rx0, ry0, cell_m, nx, ny, progress)
        if acc["n_detected"] == 0:
            raise CoverageError(f"no detected shot in {', '.join(str(p) for p in paths)}: "
                                "nothing to grid (check the run's detection threshold)")
        ex = acc["extent"]
        if acc["n_in_grid"] == 0 and not geom.intersects(box(*ex)):   # a hole is an answer
            raise CoverageError(f"{_region_option(region_info)}: the region "
                                f"{_fmt_bounds(geom.bounds)} (EPSG:{epsg}) "
                                f"misses the results, whose footprints span {_fmt_bounds(ex)}")
        grid = _grid_dataset(acc, in_region, xc, yc, cell_m, min_detections, epsg)
        crossovers = track_crossovers(files, acc["tracks"], cell_m, epsg)
    finally:
        for f in files:
            f.close()
    summary = _summary(grid, acc, crossovers, geom, region_info, cell_m, min_detections, epsg,
                       paths)
    grid.attrs["summary_json"] = json.dumps(_jsonable(summary), allow_nan=False)
    grid.attrs["region_wkt"] = geom.wkt
    tracks = tuple(pl.arrays()[:2] for pl in acc["tracks"])
    return CoverageResult(grid=grid, summary=summary, crossovers=crossovers, region=geom,
                          epsg=epsg, tracks=tracks)


def _region_option(info: dict) -> str:
    return "--bounds" if info["kind"] == "bounds" else f"--region {info.get('file', info['kind'])}"


def _fmt_bounds(b) -> str:
    return f"x {b[0]:.0f}..{b[2]:.0f} m, y {b[1]:.0f}..{b[3]:.0f} m"


def _snr_bin_db(n_cells: int) -> float:
    span = SNR_RANGE_DB[1] - SNR_RANGE_DB[0]
    for w in SNR_BIN_CHOICES_DB:
        if n_cells * (round(span / w) + 2) <= SNR_HISTOGRAM_ENTRIES:
            return w
    most = SNR_HISTOGRAM_ENTRIES // (round(span / SNR_BIN_CHOICES_DB[-1]) + 2)
    raise CoverageError(f"--cell-m: {n_cells} cells over the region, more than the {most} the "
                        "per-cell SNR histograms hold; choose larger cells or a smaller region")


def _accumulate(files, x0, y0, cell_m, nx, ny, progress) -> dict:
    """One pass over every file's blocks: per-cell counts, sums and SNR histograms, tracks per
    cell, detection representatives (and their k-d tree), thinned tracks, along-track spacings,
    flight time and length."""
    from scipy.spatial import cKDTree

    n_cells = nx * ny
    shots = np.zeros(n_cells, np.int64)
    detected = np.zeros(n_cells, np.int64)
    e_n = np.zeros(n_cells, np.int64)
    e_sum = np.zeros(n_cells)
    e_sq = np.zeros(n_cells)
    s_n = np.zeros(n_cells, np.int64)
    s_sq = np.zeros(n_cells)
    snr_w = _snr_bin_db(n_cells)
    n_bins = int(round((SNR_RANGE_DB[1] - SNR_RANGE_DB[0]) / snr_w)) + 2   # under, overflow
    snr_hist = np.zeros(n_cells * n_bins, np.int32)
    cell_tracks = _KeySet()
    detected_tracks = _KeySet()          # (cell, track) pairs with a detection: revisits
    track_ids: dict = {}
    track_start: dict = {}               # track id -> its first shot's time [s, Unix]
    reps = _Representatives(x0, y0, cell_m / GAP_PIXELS_PER_CELL)
    tracks = TrackBuilder(cell_m / TRACK_STEP_PER_CELL)
    flight_time = track_length = 0.0
    n_shots = n_detected = n_in_grid = n_on_edge = 0
    ext = [np.inf, np.inf, -np.inf, -np.inf]
    inv_c = 1.0 / cell_m
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(f.n_obs * f.n_beams for f in files), unit="shot", desc="coverage",
                   leave=False)
    try:
        for f in files:
            last_platform = last_clock = None
            tracks.new_file(f.index, f.n_beams)
            for o0, v in _blocks(f, _BLOCK_VARIABLES):
                x, y = v["x"], v["y"]
                nb, m = x.shape
                ok = np.isfinite(x) & np.isfinite(y)
                det = (v["detected"] == 1) & ok
                n_ok = int(np.count_nonzero(ok))
                n_shots += n_ok
                n_detected += int(np.count_nonzero(det))
                if n_ok:
                    xo, yo = x[ok], y[ok]
                    ext = [min(ext[0], float(xo.min())), min(ext[1], float(yo.min())),
                           max(ext[2], float(xo.max())), max(ext[3], float(yo.max()))]
                # cells (NaN positions compare False: outside)
                fx = (x - x0) * inv_c
                fy = (y - y0) * inv_c
                inside = (fx >= 0) & (fx < nx) & (fy >= 0) & (fy < ny)
                fxi, fyi = fx[inside], fy[inside]
                ixi, iyi = fxi.astype(np.int64), fyi.astype(np.int64)
                cell = iyi * nx + ixi
                n_in_grid += cell.size
                rx, ry = fxi - ixi, fyi - iyi
                n_on_edge += int(np.count_nonzero(
                    (np.minimum(rx, 1.0 - rx) < EDGE_BAND) | (np.minimum(ry, 1.0 - ry) < EDGE_BAND)))
                shots += np.bincount(cell, minlength=n_cells)
                d_in = det[inside]
                c_det = cell[d_in]
                detected += np.bincount(c_det, minlength=n_cells)
                if "h_li" in v and "h_li_true" in v:
                    err = (v["h_li"][inside] - v["h_li_true"][inside])[d_in]
                    good = np.isfinite(err)
                    c, e = c_det[good], err[good]
                    e_n += np.bincount(c, minlength=n_cells)
                    e_sum += np.bincount(c, weights=e, minlength=n_cells)
                    e_sq += np.bincount(c, weights=e * e, minlength=n_cells)
                if "h_li_sigma" in v:
                    sig = v["h_li_sigma"][inside][d_in]
                    good = np.isfinite(sig)
                    s_n += np.bincount(c_det[good], minlength=n_cells)
                    s_sq += np.bincount(c_det[good], weights=sig[good] ** 2, minlength=n_cells)
                # SNR histograms (NaN snr: no power, the underflow bin)
                if "snr_db" in v:
                    b = (v["snr_db"][inside] - SNR_RANGE_DB[0]) * (1.0 / snr_w) + 1.0
                    b = np.clip(np.nan_to_num(b, nan=0.0), 0.0, n_bins - 1).astype(np.int64)
                else:
                    b = np.zeros(cell.size, np.int64)
                key = cell * n_bins + b
                if key.size:
                    lo = int(key.min())
                    part = np.bincount(key - lo)
                    snr_hist[lo:lo + part.size] += part.astype(np.int32)
                # distinct (file, track) per cell; runs of one cell and track compress first
                tr = v["track"] if "track" in v else np.zeros((nb, m), np.int32)
                tid = _track_ids(tr, f.index, track_ids)
                key = cell * (1 << 24) + tid[inside]
                keep = np.ones(key.size, bool)
                keep[1:] = key[1:] != key[:-1]
                cell_tracks.add(np.unique(key[keep]))
                detected_tracks.add(np.unique(key[d_in]))
                # when each track was flown: its first shot (beam 0 carries the shot clock)
                clock = f.read("delta_time", (0, np.s_[o0:o0 + m]))
                first = np.ones(m, bool)
                first[1:] = tid[0, 1:] != tid[0, :-1]
                for k, t in zip(tid[0, first].tolist(), (clock[first] + f.epoch_s).tolist()):
                    if t < track_start.get(k, np.inf):
                        track_start[k] = t
                # flight time: the shot clock's steps, a pause (between a campaign's passes)
                # excluded
                steps = np.diff(clock if last_clock is None else np.append(last_clock, clock))
                flight_time += float(np.sum(steps[steps <= FLIGHT_PAUSE_S]))
                last_clock = clock[-1]
                # detection representatives (every detection, inside the grid or not)
                reps.add(x[det], y[det])
                # thinned tracks and along-track spacings
                tracks.add(f.index, o0, x, y, tr)
                # flight length: the platform's ground track (beam 0) through every
                # PLATFORM_STRIDE-th shot and the last
                if "platform_x" in v:
                    at = np.arange(0, m, PLATFORM_STRIDE)
                    if (m - 1) % PLATFORM_STRIDE:
                        at = np.append(at, m - 1)
                    px, py, pt = v["platform_x"][0, at], v["platform_y"][0, at], clock[at]
                    if last_platform is not None:
                        px, py, pt = (np.concatenate([[a], b]) for a, b in
                                      zip(last_platform, (px, py, pt)))
                    chord = np.hypot(np.diff(px), np.diff(py))
                    track_length += float(np.nansum(chord[np.diff(pt) <= FLIGHT_PAUSE_S]))
                    last_platform = (px[-1], py[-1], pt[-1])
                if bar is not None:
                    bar.update(nb * m)
    finally:
        if bar is not None:
            bar.close()
    reps_xy = reps.points()
    return {"shots": shots, "detected": detected, "e_n": e_n, "e_sum": e_sum, "e_sq": e_sq,
            "s_n": s_n, "s_sq": s_sq, "snr_hist": snr_hist.reshape(n_cells, n_bins),
            "snr_bin_db": snr_w, "cell_tracks": cell_tracks.keys(),
            "detected_tracks": detected_tracks.keys(), "track_start": track_start,
            "reps": reps_xy,
            "tree": cKDTree(reps_xy), "tracks": tracks.finish(),
            "spacing_hist": tracks.spacing_hist,
            "flight_time_s": flight_time, "track_length_m": track_length,
            "n_shots": n_shots, "n_detected": n_detected, "n_in_grid": n_in_grid,
            "n_on_edge": n_on_edge,
            "extent": ext, "nx": nx, "ny": ny}


def _track_ids(track: np.ndarray, file_index: int, ids: dict) -> np.ndarray:
    """Compact ids of the (file, track) pairs of a block (``ids`` grows as pairs appear)."""
    flat = track.ravel()
    starts = np.ones(flat.size, bool)
    starts[1:] = flat[1:] != flat[:-1]
    present = np.unique(flat[starts])                       # tracks come in runs: few
    lut = np.zeros(int(present[-1] - present[0]) + 1, np.int64)
    lut[present - present[0]] = [ids.setdefault((file_index, int(t)), len(ids)) for t in present]
    return lut[track - present[0]]


# ----------------------------------------------------------------------------------- the grid
def _crs_variable(epsg: int):
    from ..mission.results import crs_attributes

    return xr.Variable((), np.int32(0), crs_attributes(epsg))


def _cell_medians(hist: np.ndarray, bin_db: float) -> np.ndarray:
    """Grouped median [dB] of each row of ``hist`` (cells x bins: underflow, the bins of
    ``bin_db`` over SNR_RANGE_DB, overflow): linear within the median's bin; -inf below the
    range, +inf above it, NaN for an empty cell."""
    out = np.full(hist.shape[0], np.nan)
    for c0 in range(0, hist.shape[0], 4096):              # rows in blocks: bounded memory
        h = hist[c0:c0 + 4096]
        cum = np.cumsum(h, axis=1, dtype=np.int64)
        n = cum[:, -1]
        have = np.flatnonzero(n)
        if have.size == 0:
            continue
        cum, h = cum[have], h[have]
        half = 0.5 * n[have]
        k = np.argmax(cum >= half[:, None], axis=1)       # the median's bin
        rows = np.arange(have.size)
        below = np.where(k > 0, cum[rows, np.maximum(k - 1, 0)], 0)
        lo = SNR_RANGE_DB[0] + (k - 1) * bin_db
        value = lo + bin_db * (half - below) / np.maximum(h[rows, k], 1)
        out[c0 + have] = np.where(k == 0, -np.inf, np.where(k == hist.shape[1] - 1, np.inf,
                                                            value))
    return out


_GRID_VARS = {   # name: (units, long_name, comment)
    "in_region": ("1", "cell centre in the region", ""),
    "shots": ("1", "shots in the cell",
              "shot-beams whose footprint centre (x, y) lies in the cell"),
    "detected_shots": ("1", "detected shots in the cell", ""),
    "detection_fraction": ("1", "detected fraction of the cell's shots", ""),
    "tracks": ("1", "tracks through the cell",
               "distinct (file, survey line or pass) pairs; a file's turns and transits count "
               "as one"),
    "detected_tracks": ("1", "tracks with a detection in the cell",
                        "distinct (file, survey line or pass) pairs with a detected shot"),
    "revisit_median_s": ("s", "median time between successive detected tracks",
                         "between the first shots of the tracks (passes, lines) that detect "
                         "in the cell, in time order; NaN with fewer than two"),
    "median_snr_db": ("dB", "median SNR of the cell's shots", "detected or not"),
    "height_error_std": ("m", "measured height error of one shot",
                         "sample standard deviation of h_li - h_li_true over the cell's "
                         "detected shots (two or more)"),
    "height_sigma_predicted": ("m", "predicted height error of one shot",
                               "RMS of the detected shots' h_li_sigma"),
    "height_precision_measured": ("m", "measured precision of the cell's mean height",
                                  "height_error_std / sqrt(N), N the detected shots"),
    "height_precision_predicted": ("m", "predicted precision of the cell's mean height",
                                   "height_sigma_predicted / sqrt(N)"),
    "gap": ("m", "distance to the nearest detection",
            "from the cell centre to the nearest detected footprint centre"),
    "covered": ("1", "cell covered", "in the region with at least min_detections detected "
                "shots"),
}


#: The grid's data variables (``--var`` of the map).
GRID_VARIABLES = tuple(_GRID_VARS)


def _revisit_medians(keys: np.ndarray, start: dict, n_cells: int) -> np.ndarray:
    """(n_cells,) median interval [s] between the start times of the successive tracks in each
    cell (``keys``: sorted cell << 24 | track id), NaN where fewer than two tracks."""
    out = np.full(n_cells, np.nan)
    if keys.size < 2:
        return out
    cell = keys >> 24
    ids = keys & ((1 << 24) - 1)
    lut = np.full(int(ids.max()) + 1, np.nan)
    lut[list(start)] = list(start.values())
    t = lut[ids]
    order = np.lexsort((t, cell))
    cell, t = cell[order], t[order]
    same = cell[1:] == cell[:-1]
    gap_cell, gap = cell[1:][same], np.diff(t)[same]
    order = np.lexsort((gap, gap_cell))           # intervals sorted within each cell
    gap_cell, gap = gap_cell[order], gap[order]
    cells, first, count = np.unique(gap_cell, return_index=True, return_counts=True)
    lo, hi = first + (count - 1) // 2, first + count // 2
    out[cells] = 0.5 * (gap[lo] + gap[hi])
    return out


def _grid_dataset(acc, in_region, xc, yc, cell_m, min_detections, epsg) -> xr.Dataset:

    from .. import __version__

    ny, nx = in_region.shape
    shape = (ny, nx)
    shots = acc["shots"].reshape(shape)
    det = acc["detected"].reshape(shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(shots > 0, det / np.maximum(shots, 1), np.nan)
        n = acc["e_n"].astype(float)
        mean = acc["e_sum"] / np.maximum(n, 1)
        var = np.maximum(acc["e_sq"] - n * mean * mean, 0.0) / np.maximum(n - 1, 1)
        std = np.where(n >= 2, np.sqrt(var), np.nan).reshape(shape)
        ns = acc["s_n"].astype(float)
        sig = np.where(ns >= 1, np.sqrt(acc["s_sq"] / np.maximum(ns, 1)), np.nan).reshape(shape)
        prec_meas = std / np.sqrt(n.reshape(shape))
        prec_pred = sig / np.sqrt(ns.reshape(shape))
    tracks = np.bincount(acc["cell_tracks"] >> 24, minlength=nx * ny).reshape(shape)
    det_tracks = np.bincount(acc["detected_tracks"] >> 24, minlength=nx * ny).reshape(shape)
    revisit = _revisit_medians(acc["detected_tracks"], acc["track_start"], nx * ny).reshape(shape)
    median_snr = _cell_medians(acc["snr_hist"], acc["snr_bin_db"]).reshape(shape)
    tree = acc["tree"]
    gx, gy = np.meshgrid(xc, yc)
    gap = tree.query(np.column_stack([gx.ravel(), gy.ravel()]))[0].reshape(shape)
    covered = ((det >= min_detections) & (in_region == 1)).astype(np.int8)
    values = {"in_region": in_region, "shots": shots.astype(np.int32),
              "detected_shots": det.astype(np.int32), "detection_fraction": frac,
              "tracks": tracks.astype(np.int32), "detected_tracks": det_tracks.astype(np.int32),
              "revisit_median_s": revisit, "median_snr_db": median_snr,
              "height_error_std": std, "height_sigma_predicted": sig,
              "height_precision_measured": prec_meas, "height_precision_predicted": prec_pred,
              "gap": gap, "covered": covered}
    data = {}
    for k, v in values.items():
        units, long_name, comment = _GRID_VARS[k]
        attrs = {"units": units, "long_name": long_name, "grid_mapping": "crs"}
        if comment:
            attrs["comment"] = comment
        data[k] = (("y", "x"), v, attrs)
    for k in ("in_region", "covered"):
        data[k][2].update(flag_values=np.array([0, 1], np.int8),
                          flag_meanings="no yes")
    data["median_snr_db"][2]["comment"] += (
        f"; grouped median of {acc['snr_bin_db']:g} dB bins over {SNR_RANGE_DB[0]:g} to "
        f"{SNR_RANGE_DB[1]:g} dB, linear within the median's bin; -inf: below the range or no "
        "power")
    data["gap"][2]["comment"] += (f", represented by the centres of the pixels of "
                                  f"cell_size_m / {GAP_PIXELS_PER_CELL} that hold one: within "
                                  "half a pixel diagonal")
    ds = xr.Dataset(data, coords={
        "x": ("x", xc, {"standard_name": "projection_x_coordinate", "units": "m", "axis": "X",
                        "long_name": "x of the cell centre"}),
        "y": ("y", yc, {"standard_name": "projection_y_coordinate", "units": "m", "axis": "Y",
                        "long_name": "y of the cell centre"})})
    ds["crs"] = _crs_variable(epsg)
    ds.attrs.update({
        "Conventions": "CF-1.8", "title": "chirplidar coverage grid",
        "source": f"chirplidar {__version__}", "cell_size_m": float(cell_m),
        "min_detections": int(min_detections), "epsg_code": f"EPSG:{epsg}",
        "history": f"{_dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()} "
                   f"chirplidar {__version__}: coverage"})
    return ds


def _largest_gap(tree, points, geom, cell_m: float, x0: float, y0: float, nx: int,
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


# ----------------------------------------------------------------------------------- summary
def _map_scale_factor(geom, epsg: int) -> float:
    from pyproj import Proj, Transformer

    c = geom.centroid
    lon, lat = Transformer.from_crs(epsg, 4326, always_xy=True).transform(c.x, c.y)
    return float(Proj(f"EPSG:{epsg}").get_factors(lon, lat).meridional_scale)


def _summary(grid, acc, crossovers, geom, region_info, cell_m, min_detections, epsg,
             paths) -> dict:

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

    gap = _largest_gap(acc["tree"], acc["reps"], geom, cell_m, float(grid.x[0]) - cell_m / 2,
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


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (bool, str)) or obj is None:
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    f = float(obj)
    return f if math.isfinite(f) else None


def summary_json(summary: dict) -> str:
    """The summary as one JSON object (non-finite numbers as null)."""
    return json.dumps(_jsonable({k: summary[k] for k in SUMMARY_KEYS}), allow_nan=False)


# ----------------------------------------------------------------------------------- writing
def write_coverage(result: CoverageResult, path, *, overwrite: bool = False) -> Path:
    """Write the grid (CF-1.8, root group) and the crossovers (group ``crossovers``) to one
    NetCDF-4 file, atomically; an existing file is kept unless ``overwrite``."""
    from ..mission.results import write_atomic

    path = Path(path)
    grid = result.grid
    enc = {k: ({"_FillValue": np.nan, "zlib": True, "complevel": 4}
               if np.issubdtype(v.dtype, np.floating) else {"_FillValue": None})
           for k, v in grid.data_vars.items() if v.ndim}
    enc.update({k: {"_FillValue": None} for k in ("x", "y")})
    xo = result.crossovers
    xenc = {k: ({"_FillValue": np.nan} if np.issubdtype(v.dtype, np.floating)
                else {"_FillValue": None}) for k, v in xo.variables.items()}

    def write(tmp):
        with NETCDF_LOCK:
            grid.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=enc)
            xo.to_netcdf(tmp, mode="a", group="crossovers", engine="netcdf4", encoding=xenc)

    return write_atomic(path, write, overwrite=overwrite)
