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
* Crossovers: the tracks' footprint polylines are thinned to vertices every ``cell_m / 2`` along
  track (:data:`TRACK_STEP_PER_CELL`), intersected, and each crossing is refined on the full-rate
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

__all__ = ["CoverageResult", "CoverageError", "GRID_VARIABLES", "SUMMARY_KEYS",
           "compute_coverage", "summary_json", "write_coverage"]

BLOCK_SHOTS = 1 << 20          # shot-beams read per block
SNR_RANGE_DB = (-30.0, 90.0)   # per-cell SNR histograms: this range, plus under/overflow bins
SNR_BIN_CHOICES_DB = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0)   # the finest whose histograms fit:
SNR_HISTOGRAM_ENTRIES = 1 << 24  # cells x bins at most (64 MB of counts)
GAP_PIXELS_PER_CELL = 20       # detection representatives: pixels of cell_m / 20
GAP_TOLERANCE_PER_CELL = 20    # largest gap: branch and bound to within C / 20
TRACK_STEP_PER_CELL = 2        # crossovers and across-track spacing: vertices every C / 2
_SPACING_BINS_PER_DECADE = 2000  # along-track spacing median: log bins (0.12 %)
ACROSS_TRACK_SAMPLES = 20_000  # track vertices the across-track spacing's median is taken over
SPACING_SAMPLE = 16            # the along-track spacing's median: of every 16th footprint pair
PLATFORM_STRIDE = 8            # flight length: chords over 8 shots (a turn of radius r at chord
                               # length s reads s^2 / (24 r^2) short: 1e-5 for 1.6 m, r = 100 m)
_SPACING_DECADES = (-4.0, 7.0)

#: The summary's keys, in order (``--json``).
SUMMARY_KEYS = ("cells_in_region", "cells_covered", "fraction_covered", "largest_gap_m",
                "median_detections_per_cell", "median_height_precision_m",
                "median_height_precision_predicted_m", "along_track_spacing_m",
                "across_track_spacing_m", "track_length_m", "flight_time_s", "crossovers",
                "crossover_rms_m", "shots", "detected_shots", "cell_m", "min_detections",
                "map_scale_factor", "region", "files")

_READ = ("x", "y", "detected", "snr_db", "h_li", "h_li_true", "h_li_sigma", "delta_time",
         "track", "platform_x", "platform_y")


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
                if len(self._cache) >= 16:
                    self._cache.pop(next(iter(self._cache)))
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


def _blocks(f: _File):
    """(obs start, dict name -> (n_beams, m) array) over the file, HDF5-chunk aligned."""
    per = max(1, BLOCK_SHOTS // max(f.n_beams, 1))
    step = max(f.obs_chunk, (per // f.obs_chunk) * f.obs_chunk)
    for o0 in range(0, f.n_obs, step):
        sl = (slice(None), slice(o0, min(f.n_obs, o0 + step)))
        yield o0, {name: f.read(name, sl) for name in f.has}


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
class _SparseCounts:
    """Counts of int64 keys, merged lazily: memory grows with the distinct keys, not the adds."""

    def __init__(self):
        self._parts: list[tuple[np.ndarray, np.ndarray]] = []
        self._size = 0
        self._merged_size = 0

    def add(self, keys: np.ndarray, counts: np.ndarray | None = None) -> None:
        if keys.size == 0:
            return
        if counts is None:
            keys, counts = np.unique(keys, return_counts=True)
        self._parts.append((keys, counts.astype(np.int64)))
        self._size += keys.size
        if self._size > 2 * self._merged_size + (1 << 20):
            self._merge()

    def _merge(self) -> None:
        if len(self._parts) > 1:
            k = np.concatenate([p[0] for p in self._parts])
            c = np.concatenate([p[1] for p in self._parts])
            u, inv = np.unique(k, return_inverse=True)
            self._parts = [(u, np.bincount(inv, weights=c, minlength=u.size).astype(np.int64))]
        self._size = self._merged_size = self._parts[0][0].size if self._parts else 0

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        self._merge()
        if not self._parts:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return self._parts[0]


class _Representatives:
    """The pixels that hold a detected footprint centre; a pixel's centre represents them (no
    detection is farther than half its diagonal from its pixel's centre)."""

    def __init__(self, x0: float, y0: float, pixel_m: float):
        self.x0, self.y0, self.pixel = x0, y0, pixel_m
        self._pixels = _SparseCounts()

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
        # consecutive shots share pixels: drop repeats before the sort
        keep = np.empty(keys.size, bool)
        keep[0] = True
        np.not_equal(keys[1:], keys[:-1], out=keep[1:])
        keys = np.unique(keys[keep])
        self._pixels.add(keys, np.ones(keys.size, np.int64))

    def points(self) -> np.ndarray:
        """(n, 2) centres of the pixels with a detection."""
        keys = self._pixels.result()[0]
        ix = (keys >> 32) - (1 << 30)
        iy = (keys & 0xFFFFFFFF) - (1 << 30)
        return np.column_stack([self.x0 + (ix + 0.5) * self.pixel,
                                self.y0 + (iy + 0.5) * self.pixel])


@dataclass
class _Polyline:
    """A thinned footprint track: vertices (x, y) with their obs indices."""

    file: int
    beam: int
    track: int
    x: list = field(default_factory=list)
    y: list = field(default_factory=list)
    obs: list = field(default_factory=list)

    def arrays(self):
        return (np.concatenate(self.x), np.concatenate(self.y), np.concatenate(self.obs))


class _TrackBuilder:
    """Thinned polylines of every (file, beam, track >= 0), built block by block: a vertex every
    ``step_m`` along track, the first and last point of each track, and a break where the
    footprints jump (a beam off the terrain)."""

    def __init__(self, step_m: float):
        self.step = step_m
        self.done: list[_Polyline] = []
        # (file, beam) -> [polyline, last x, last y, last obs, along-track distance so far]
        self._open: dict = {}
        lo_dec, hi_dec = _SPACING_DECADES
        #: histogram of the distances between consecutive footprints of a beam (log bins)
        self.spacing_hist = np.zeros(int((hi_dec - lo_dec) * _SPACING_BINS_PER_DECADE) + 2,
                                     np.int64)

    def new_file(self, fi: int, n_beams: int) -> None:
        """A file starts: its beams' tracks start afresh."""
        for b in range(n_beams):
            self._close(fi, b)

    def _spacings(self, x, y, idx) -> None:
        """Distances between consecutive footprints (obs i, i + 1, both with a surface), from
        every SPACING_SAMPLE-th footprint: into the histogram."""
        i = np.arange(0, idx.size - 1, SPACING_SAMPLE)
        i = i[idx[i + 1] == idx[i] + 1]
        seg = np.hypot(x[idx[i + 1]] - x[idx[i]], y[idx[i + 1]] - y[idx[i]])
        seg = seg[seg > 0]
        if seg.size:
            k = (np.log10(seg) - _SPACING_DECADES[0]) * _SPACING_BINS_PER_DECADE + 1.0
            k = np.clip(k, 0, self.spacing_hist.size - 1).astype(np.int64)
            self.spacing_hist += np.bincount(k, minlength=self.spacing_hist.size)

    def add(self, fi: int, o0: int, x: np.ndarray, y: np.ndarray, track: np.ndarray) -> None:
        for b in range(x.shape[0]):
            self._add_beam(fi, b, o0, x[b], y[b], track[b])

    def _add_beam(self, fi, b, o0, x, y, track) -> None:
        idx = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
        if idx.size == 0:
            return
        tb = track[idx]
        state = self._open.get((fi, b))
        # the footprint spacing, from the block's first points: the thinning looks at every
        # k-th footprint (vertices come every step, k spacings are an eighth of it at most)
        head = idx[:257]
        est = float(np.median(np.hypot(np.diff(x[head]), np.diff(y[head])))) if head.size > 1 \
            else self.step
        k = max(1, int(self.step / (8.0 * est))) if est > 0 else 1
        self._spacings(x, y, idx)
        # polylines start where the track changes, and where the footprints jump across a gap
        # (a beam off the terrain) by more than max(5 steps, 10 spacings)
        pt = state[0].track if state is not None else -2
        change = tb != np.concatenate([[pt], tb[:-1]])
        prev_obs = state[3] - o0 if state is not None else idx[0] - 1
        gap = np.flatnonzero(np.diff(idx, prepend=prev_obs) > 1)
        if gap.size:
            px = np.where(gap > 0, x[idx[np.maximum(gap - 1, 0)]], state[1] if state else 0.0)
            py = np.where(gap > 0, y[idx[np.maximum(gap - 1, 0)]], state[2] if state else 0.0)
            dist = np.hypot(x[idx[gap]] - px, y[idx[gap]] - py)
            change[gap[dist > max(5.0 * self.step, 10.0 * est)]] = True
        starts = np.flatnonzero(change)
        sample = np.unique(np.concatenate([np.arange(0, idx.size, k), starts,
                                           np.maximum(starts - 1, 0), [idx.size - 1]]))
        new_at = change[sample]
        xs, ys, ts, os_ = x[idx[sample]], y[idx[sample]], tb[sample], o0 + idx[sample]
        lx, ly = (state[1], state[2]) if state is not None else (xs[0], ys[0])
        seg = np.hypot(np.diff(xs, prepend=lx), np.diff(ys, prepend=ly))
        cuts = np.concatenate([[0], np.flatnonzero(new_at), [sample.size]])
        for a, z in zip(cuts[:-1], cuts[1:]):
            if z <= a:
                continue
            if new_at[a] or state is None:
                self._close(fi, b)
                pl = _Polyline(fi, b, int(ts[a]))
                state = [pl, xs[a], ys[a], os_[a], 0.0]
                if pl.track >= 0:         # turns and transits (-1) keep no vertices
                    pl.x.append(xs[a:a + 1]), pl.y.append(ys[a:a + 1])
                    pl.obs.append(os_[a:a + 1])
                lo = a + 1
            else:
                lo = a
            pl = state[0]
            if pl.track >= 0 and z > lo:
                cum = state[4] + np.cumsum(seg[lo:z])
                n_step = np.floor(cum / self.step)
                prev = np.concatenate([[np.floor(state[4] / self.step)], n_step[:-1]])
                sel = np.flatnonzero(n_step > prev)
                if sel.size:
                    pl.x.append(xs[lo + sel]), pl.y.append(ys[lo + sel])
                    pl.obs.append(os_[lo + sel])
                state[4] = float(cum[-1])
            state[1], state[2], state[3] = xs[z - 1], ys[z - 1], os_[z - 1]
            self._open[(fi, b)] = state

    def _close(self, fi: int, b: int) -> None:
        state = self._open.pop((fi, b), None)
        if state is None or state[0].track < 0:
            return
        pl = state[0]
        if pl.obs[-1][-1] != state[3]:        # the track's last point
            pl.x.append(np.array([state[1]])), pl.y.append(np.array([state[2]]))
            pl.obs.append(np.array([state[3]]))
        self.done.append(pl)

    def finish(self) -> list[_Polyline]:
        for key in list(self._open):
            self._close(*key)
        return self.done


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
                     min_detections: int = 1, progress: bool = False) -> CoverageResult:
    """Coverage of the results files ``paths`` on cells of ``cell_m`` projected metres.

    ``region``: ``"survey"`` (the runs' survey polygon; the default where one exists),
    ``"scene"`` (the scene extent) or a GeoJSON file (WGS-84 polygon); or ``bounds`` =
    (xmin, ymin, xmax, ymax) in the results' projected metres. A cell is in the region when its
    centre is (on the boundary counts); it is covered with ``min_detections`` or more detected
    shots. CoverageError (one line) on bad input: no files, files in different projections,
    a cell size <= 0 or larger than the region, a region that misses every footprint, no
    detected shot at all.
    """
    from shapely import intersects_xy
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
        rx0, ry0, rx1, ry1 = geom.bounds
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
            what = "--bounds" if region_info["kind"] == "bounds" else \
                f"--region {region_info.get('file', region_info['kind'])}"
            raise CoverageError(f"{what}: the region {_fmt_bounds(geom.bounds)} (EPSG:{epsg}) "
                                f"misses the results, whose footprints span {_fmt_bounds(ex)}")
        grid = _grid_dataset(acc, in_region, xc, yc, cell_m, min_detections, epsg)
        crossovers = _crossovers(files, acc["tracks"], cell_m, epsg)
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


def _fmt_bounds(b) -> str:
    return f"x {b[0]:.0f}..{b[2]:.0f} m, y {b[1]:.0f}..{b[3]:.0f} m"


def _snr_bin_db(n_cells: int) -> float:
    span = SNR_RANGE_DB[1] - SNR_RANGE_DB[0]
    for w in SNR_BIN_CHOICES_DB:
        if n_cells * (round(span / w) + 2) <= SNR_HISTOGRAM_ENTRIES:
            return w
    raise CoverageError(f"{n_cells} cells: too many for the SNR histograms; choose larger "
                        "cells or a smaller region")


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
    cell_tracks = _SparseCounts()
    track_ids: dict = {}
    reps = _Representatives(x0, y0, cell_m / GAP_PIXELS_PER_CELL)
    tracks = _TrackBuilder(cell_m / TRACK_STEP_PER_CELL)
    flight_time = track_length = 0.0
    n_shots = n_detected = n_in_grid = 0
    ext = [np.inf, np.inf, -np.inf, -np.inf]
    inv_c = 1.0 / cell_m
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(f.n_obs * f.n_beams for f in files), unit="shot", desc="coverage",
                   leave=False)
    try:
        for f in files:
            last_platform = None
            tracks.new_file(f.index, f.n_beams)
            for o0, v in _blocks(f):
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
                cell = fy[inside].astype(np.int64) * nx + fx[inside].astype(np.int64)
                n_in_grid += cell.size
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
                key = np.unique(key[keep])
                cell_tracks.add(key, np.ones(key.size, np.int64))
                # detection representatives (every detection, inside the grid or not)
                reps.add(x[det], y[det])
                # thinned tracks and along-track spacings
                tracks.add(f.index, o0, x, y, tr)
                # flight length: the platform's ground track (beam 0) through every
                # PLATFORM_STRIDE-th shot and the last
                if "platform_x" in v:
                    px = v["platform_x"][0, ::PLATFORM_STRIDE]
                    py = v["platform_y"][0, ::PLATFORM_STRIDE]
                    if (m - 1) % PLATFORM_STRIDE:
                        px = np.append(px, v["platform_x"][0, -1])
                        py = np.append(py, v["platform_y"][0, -1])
                    if last_platform is not None:
                        px = np.concatenate([[last_platform[0]], px])
                        py = np.concatenate([[last_platform[1]], py])
                    track_length += float(np.nansum(np.hypot(np.diff(px), np.diff(py))))
                    last_platform = (px[-1], py[-1])
                if bar is not None:
                    bar.update(nb * m)
            if f.n_obs:
                t = f.read("delta_time", (0, [0, f.n_obs - 1]))
                flight_time += float(t[-1] - t[0])
    finally:
        if bar is not None:
            bar.close()
    reps_xy = reps.points()
    return {"shots": shots, "detected": detected, "e_n": e_n, "e_sum": e_sum, "e_sq": e_sq,
            "s_n": s_n, "s_sq": s_sq, "snr_hist": snr_hist.reshape(n_cells, n_bins),
            "snr_bin_db": snr_w, "cell_tracks": cell_tracks.result()[0], "reps": reps_xy,
            "tree": cKDTree(reps_xy), "tracks": tracks.finish(),
            "spacing_hist": tracks.spacing_hist,
            "flight_time_s": flight_time, "track_length_m": track_length,
            "n_shots": n_shots, "n_detected": n_detected, "n_in_grid": n_in_grid,
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


_GRID_VARS = {   # name: (units, long_name)
    "in_region": ("1", "cell centre inside the region (1) or not (0)"),
    "shots": ("1", "shots with their footprint centre in the cell"),
    "detected_shots": ("1", "detected shots with their footprint centre in the cell"),
    "detection_fraction": ("1", "detected shots / shots"),
    "tracks": ("1", "distinct tracks (survey lines, passes, files) that sampled the cell"),
    "median_snr_db": ("dB", "median SNR of the cell's shots (detected or not)"),
    "height_error_std": ("m", "standard deviation of h_li - h_li_true over the detected shots "
                              "(measured precision of one shot)"),
    "height_sigma_predicted": ("m", "RMS of the detected shots' h_li_sigma (predicted "
                                    "precision of one shot)"),
    "height_precision_measured": ("m", "height_error_std / sqrt(N): precision of the cell's "
                                       "mean height from N detected shots"),
    "height_precision_predicted": ("m", "height_sigma_predicted / sqrt(N)"),
    "gap": ("m", "distance from the cell centre to the nearest detected footprint centre"),
    "covered": ("1", "in the region with at least min_detections detected shots (1) or not (0)"),
}


#: The grid's data variables (``--var`` of the map).
GRID_VARIABLES = tuple(_GRID_VARS)


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
    median_snr = _cell_medians(acc["snr_hist"], acc["snr_bin_db"]).reshape(shape)
    tree = acc["tree"]
    gx, gy = np.meshgrid(xc, yc)
    gap = tree.query(np.column_stack([gx.ravel(), gy.ravel()]))[0].reshape(shape)
    covered = ((det >= min_detections) & (in_region == 1)).astype(np.int8)
    values = {"in_region": in_region, "shots": shots.astype(np.int32),
              "detected_shots": det.astype(np.int32), "detection_fraction": frac,
              "tracks": tracks.astype(np.int32), "median_snr_db": median_snr,
              "height_error_std": std, "height_sigma_predicted": sig,
              "height_precision_measured": prec_meas, "height_precision_predicted": prec_pred,
              "gap": gap, "covered": covered}
    data = {k: (("y", "x"), v, {"units": _GRID_VARS[k][0], "long_name": _GRID_VARS[k][1],
                                "grid_mapping": "crs"}) for k, v in values.items()}
    for k in ("in_region", "covered"):
        data[k][2].update(flag_values=np.array([0, 1], np.int8),
                          flag_meanings="no yes")
    data["median_snr_db"][2]["comment"] = (
        f"grouped median of {acc['snr_bin_db']:g} dB bins over {SNR_RANGE_DB[0]:g} to "
        f"{SNR_RANGE_DB[1]:g} dB, linear within the median's bin; -inf: below the range or no "
        "power")
    data["gap"][2]["comment"] = (f"to the centres of the pixels of cell_size_m / "
                                 f"{GAP_PIXELS_PER_CELL} that hold a detection: within half a "
                                 "pixel diagonal")
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


# ----------------------------------------------------------------------------------- tracks
def _polyline_arrays(polylines):
    """Vertices of every polyline with >= 2 of them: x, y, obs, polyline id (concatenated)."""
    xs, ys, obs, pid = [], [], [], []
    for i, pl in enumerate(polylines):
        x, y, o = pl.arrays()
        if x.size < 2:
            continue
        xs.append(x), ys.append(y), obs.append(o), pid.append(np.full(x.size, i))
    if not xs:
        return (np.zeros(0),) * 2 + (np.zeros(0, np.int64),) * 2
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(obs), np.concatenate(pid)


def _across_track_spacing(polylines) -> float:
    """Median over the thinned tracks' vertices of the distance to the nearest other track
    (another beam, line, pass or file): the nearest vertex with another label (k-d tree, k
    doubled until found), refined to the distance to its two segments."""
    from scipy.spatial import cKDTree

    x, y, _, pid = _polyline_arrays(polylines)
    keys = {}
    label = np.array([keys.setdefault((pl.file, pl.beam, pl.track), len(keys))
                      for pl in polylines], dtype=np.int64)
    if x.size == 0 or np.unique(label[pid]).size < 2:
        return float("nan")
    lab = label[pid]
    pts = np.column_stack([x, y])
    tree = cKDTree(pts)
    other = np.full(x.size, -1)
    # the median over at most ACROSS_TRACK_SAMPLES vertices, evenly strided
    todo = np.arange(0, x.size, max(1, x.size // ACROSS_TRACK_SAMPLES))
    k = 8
    while todo.size and k <= 4096:
        kk = min(k, x.size)
        _, nn = tree.query(pts[todo], k=kk)
        diff = lab[nn] != lab[todo][:, None]
        found = diff.any(axis=1)
        other[todo[found]] = nn[found, np.argmax(diff[found], axis=1)]
        todo = todo[~found]
        if kk == x.size:
            break
        k *= 4
    ok = other >= 0
    q, v = pts[ok], other[ok]
    best = np.hypot(*(q - pts[v]).T)
    for nb in (v - 1, v + 1):               # segments at the nearest vertex, same polyline
        good = (nb >= 0) & (nb < x.size)
        nb = np.where(good, nb, v)
        good &= pid[nb] == pid[v]
        a, b = pts[v], pts[nb]
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab),
                                                                     1e-300), 0.0, 1.0)
        dist = np.hypot(*(q - (a + t[:, None] * ab)).T)
        best = np.where(good, np.minimum(best, dist), best)
    return float(np.median(best)) if best.size else float("nan")


def _segment_crossings(polylines, step_m: float):
    """Candidate crossings of the thinned tracks: list of (polyline a, vertex index in a,
    polyline b, vertex index in b, x, y) with a's (file, track) != b's; one per pair of
    polylines within ``step_m``."""
    import shapely

    segs_x0, segs_y0, segs_x1, segs_y1, seg_pl, seg_k, n_seg = [], [], [], [], [], [], []
    for i, pl in enumerate(polylines):
        x, y, _ = pl.arrays()
        if x.size < 2:
            n_seg.append(0)
            continue
        segs_x0.append(x[:-1]), segs_y0.append(y[:-1]), segs_x1.append(x[1:])
        segs_y1.append(y[1:]), seg_pl.append(np.full(x.size - 1, i))
        seg_k.append(np.arange(x.size - 1))
        n_seg.append(x.size - 1)
    if not segs_x0:
        return []
    x0, y0 = np.concatenate(segs_x0), np.concatenate(segs_y0)
    x1, y1 = np.concatenate(segs_x1), np.concatenate(segs_y1)
    pl_of, k_of = np.concatenate(seg_pl), np.concatenate(seg_k)
    lines = shapely.linestrings(np.stack([np.column_stack([x0, y0]), np.column_stack([x1, y1])],
                                         axis=1))
    tree = shapely.STRtree(lines)
    i, j = tree.query(lines, predicate="intersects")
    keep = i < j
    i, j = i[keep], j[keep]
    ft = np.array([(pl.file, pl.track) for pl in polylines], dtype=np.int64)
    a, b = pl_of[i], pl_of[j]
    other = (ft[a, 0] != ft[b, 0]) | (ft[a, 1] != ft[b, 1])
    i, j = i[other], j[other]
    # the end of one leg of a waypoint path touches the start of the next: not a crossover
    a, b = pl_of[i], pl_of[j]
    last = np.array(n_seg) - 1
    consecutive = ((ft[a, 0] == ft[b, 0]) & (np.abs(ft[a, 1] - ft[b, 1]) == 1)
                   & (((k_of[i] == last[a]) & (k_of[j] == 0) & (ft[a, 1] < ft[b, 1]))
                      | ((k_of[j] == last[b]) & (k_of[i] == 0) & (ft[b, 1] < ft[a, 1]))))
    i, j = i[~consecutive], j[~consecutive]
    # crossing points of the segment pairs
    dx1, dy1 = x1[i] - x0[i], y1[i] - y0[i]
    dx2, dy2 = x1[j] - x0[j], y1[j] - y0[j]
    den = dx1 * dy2 - dy1 * dx2
    with np.errstate(invalid="ignore", divide="ignore"):
        t = ((x0[j] - x0[i]) * dy2 - (y0[j] - y0[i]) * dx2) / den
    t = np.where(np.isfinite(t), np.clip(t, 0.0, 1.0), 0.5)   # collinear overlaps: mid-point
    px, py = x0[i] + t * dx1, y0[i] + t * dy1
    out = []
    seen: dict = {}
    for n in range(i.size):
        pa, pb = int(pl_of[i[n]]), int(pl_of[j[n]])
        key = (min(pa, pb), max(pa, pb))
        prev = seen.setdefault(key, [])
        if any(math.hypot(px[n] - qx, py[n] - qy) < step_m for qx, qy in prev):
            continue                                   # the same crossing through a vertex
        prev.append((px[n], py[n]))
        out.append((pa, int(k_of[i[n]]), pb, int(k_of[j[n]]), float(px[n]), float(py[n])))
    return out


_WINDOW_VARS = ("x", "y", "delta_time", "detected", "h_li", "h_li_true")


def _visit(win: dict, point) -> dict:
    """One track's visit of a crossing: time there and nearest detected shot."""
    from shapely.geometry import LineString

    ok = np.isfinite(win["x"]) & np.isfinite(win["y"])
    x, y, t = win["x"][ok], win["y"][ok], win["delta_time"][ok]
    out = {"time": np.nan, "h_li": np.nan, "h_li_true": np.nan, "distance": np.nan}
    if x.size >= 2:
        line = LineString(np.column_stack([x, y]))
        s = line.project(point)
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
        out["time"] = float(np.interp(s, cum, t))
    elif x.size:
        out["time"] = float(t[0])
    det = (win["detected"] == 1) & ok
    if "h_li" in win:
        det &= np.isfinite(win["h_li"])
    if det.any():
        d = np.hypot(win["x"][det] - point.x, win["y"][det] - point.y)
        k = int(np.argmin(d))
        out["distance"] = float(d[k])
        out["h_li"] = float(win["h_li"][det][k])
        out["h_li_true"] = float(win["h_li_true"][det][k]) if "h_li_true" in win else np.nan
    return out


def _crossovers(files: list[_File], polylines, cell_m: float, epsg: int) -> xr.Dataset:
    """The crossings of the tracks, refined on the full-rate footprints (module docstring)."""
    from shapely.geometry import LineString, Point

    step = cell_m / TRACK_STEP_PER_CELL
    epochs = [f.epoch for f in files]
    ref = min((e for e in epochs if e is not None), default=None)
    offset = [((e - ref).total_seconds() if (e is not None and ref is not None) else 0.0)
              for e in epochs]
    rows = []
    for pa, ka, pb, kb, x, y in _segment_crossings(polylines, step):
        sides = []
        for p, k in ((pa, ka), (pb, kb)):
            pl = polylines[p]
            _, _, obs = pl.arrays()
            lo, hi = int(obs[k]), int(obs[min(k + 1, obs.size - 1)])
            margin = max(2, hi - lo)
            sides.append((pl, files[pl.file].window(pl.beam, lo - margin, hi + margin + 1,
                                                    _WINDOW_VARS)))
        point = Point(x, y)
        (pl1, w1), (pl2, w2) = sides
        ok1 = np.isfinite(w1["x"]) & np.isfinite(w1["y"])
        ok2 = np.isfinite(w2["x"]) & np.isfinite(w2["y"])
        if ok1.sum() >= 2 and ok2.sum() >= 2:
            fine = LineString(np.column_stack([w1["x"][ok1], w1["y"][ok1]])).intersection(
                LineString(np.column_stack([w2["x"][ok2], w2["y"][ok2]])))
            if not fine.is_empty:
                pts = [g for g in getattr(fine, "geoms", [fine])]
                cands = [q for g in pts for q in (
                    [g] if g.geom_type == "Point" else [g.interpolate(0.5, normalized=True)])]
                point = min(cands, key=lambda q: q.distance(Point(x, y)))
        v1, v2 = _visit(w1, point), _visit(w2, point)
        t1 = v1["time"] + offset[pl1.file]
        t2 = v2["time"] + offset[pl2.file]
        if t2 < t1:
            (pl1, v1, t1), (pl2, v2, t2) = (pl2, v2, t2), (pl1, v1, t1)
        rows.append((point.x, point.y, t1, t2, v1, v2, pl1, pl2))
    n = len(rows)

    def col(fn, dtype=float):
        return np.array([fn(r) for r in rows], dtype=dtype) if n else np.zeros(0, dtype)

    xs, ys = col(lambda r: r[0]), col(lambda r: r[1])
    lat = lon = np.zeros(0)
    if n:
        from pyproj import Transformer

        lon, lat = Transformer.from_crs(epsg, 4326, always_xy=True).transform(xs, ys)
    since = f"seconds since {ref.isoformat().replace('+00:00', 'Z')}" if ref else "s"
    dims = ("crossover",)

    def var(values, units, long_name, **extra):
        return (dims, values, {"units": units, "long_name": long_name, **extra})

    h1, h2 = col(lambda r: r[4]["h_li"]), col(lambda r: r[5]["h_li"])
    g1, g2 = col(lambda r: r[4]["h_li_true"]), col(lambda r: r[5]["h_li_true"])
    ds = xr.Dataset({
        "time_1": var(col(lambda r: r[2]), since, "time of the earlier visit"),
        "time_2": var(col(lambda r: r[3]), since, "time of the later visit"),
        "time_between_visits": var(col(lambda r: r[3] - r[2]), "s",
                                   "time between the two visits"),
        "h_li_1": var(h1, "m", "h_li of the earlier track's detected shot nearest the crossing"),
        "h_li_2": var(h2, "m", "h_li of the later track's detected shot nearest the crossing"),
        "dh": var(h2 - h1, "m", "crossover height residual h_li_2 - h_li_1"),
        "dh_true": var(g2 - g1, "m", "h_li_true_2 - h_li_true_1 of the same shots (the part "
                                     "the footprints' offset on a sloping surface explains)"),
        "distance_1": var(col(lambda r: r[4]["distance"]), "m",
                          "distance from the crossing to the earlier track's nearest detected shot"),
        "distance_2": var(col(lambda r: r[5]["distance"]), "m",
                          "distance from the crossing to the later track's nearest detected shot"),
        "file_1": var(col(lambda r: r[6].file, np.int32), "1", "index of the earlier track's file"),
        "file_2": var(col(lambda r: r[7].file, np.int32), "1", "index of the later track's file"),
        "beam_1": var(col(lambda r: r[6].beam, np.int32), "1", "beam (trajectory) of the earlier track"),
        "beam_2": var(col(lambda r: r[7].beam, np.int32), "1", "beam (trajectory) of the later track"),
        "track_1": var(col(lambda r: r[6].track, np.int32), "1", "track (line or pass) number, earlier"),
        "track_2": var(col(lambda r: r[7].track, np.int32), "1", "track (line or pass) number, later"),
    }, coords={
        "x": var(xs, "m", "x of the crossing", standard_name="projection_x_coordinate"),
        "y": var(ys, "m", "y of the crossing", standard_name="projection_y_coordinate"),
        "latitude": var(np.asarray(lat, float), "degrees_north", "latitude of the crossing",
                        standard_name="latitude"),
        "longitude": var(np.asarray(lon, float), "degrees_east", "longitude of the crossing",
                         standard_name="longitude"),
    })
    ds.attrs.update({"featureType": "point", "files": json.dumps([str(f.path) for f in files]),
                     "epsg_code": f"EPSG:{epsg}"})
    return ds


# ----------------------------------------------------------------------------------- summary
def _spacing_median(hist: np.ndarray) -> float:
    n = int(hist.sum())
    if n == 0:
        return float("nan")
    k = int(np.searchsorted(np.cumsum(hist), (n + 1) // 2))
    lo_dec = _SPACING_DECADES[0]
    return float(10 ** (lo_dec + (k - 0.5) / _SPACING_BINS_PER_DECADE))


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
        "along_track_spacing_m": _spacing_median(acc["spacing_hist"]),
        "across_track_spacing_m": _across_track_spacing(acc["tracks"]),
        "track_length_m": acc["track_length_m"], "flight_time_s": acc["flight_time_s"],
        "crossovers": int(crossovers.sizes["crossover"]),
        "crossover_rms_m": float(np.sqrt(np.mean(dh ** 2))) if dh.size else float("nan"),
        "shots": int(acc["n_shots"]), "detected_shots": int(acc["n_detected"]),
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
