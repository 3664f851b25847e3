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
  footprint centre, found by branch and bound on boxes
  (:func:`~chirplidar.analysis.coverage_summary.largest_gap`) to within C/20 of the
  representatives' value: C/20 + C/28 < C/10 of the true largest gap.
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

The computation is split by job: :mod:`~chirplidar.analysis.coverage_files` (reading the results
files), :mod:`~chirplidar.analysis.coverage_region` (the region),
:mod:`~chirplidar.analysis.coverage_accumulate` (the pass over the shots),
:mod:`~chirplidar.analysis.coverage_tracks` (tracks, spacings, crossovers),
:mod:`~chirplidar.analysis.coverage_grid` (the CF grid and its file) and
:mod:`~chirplidar.analysis.coverage_summary` (the summary); this module ties them together and
is the one to import.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from .coverage_accumulate import accumulate
from .coverage_files import CoverageError, ResultsFile, open_results_file
from .coverage_grid import GRID_VARIABLES, grid_dataset, write_coverage
from .coverage_region import format_bounds, region_option, region_polygon
from .coverage_summary import SUMMARY_KEYS, coverage_summary, jsonable, summary_json
from .coverage_tracks import crossovers as track_crossovers

# The public names of a coverage computation, importable from here wherever they live.
__all__ = ["CoverageResult", "CoverageError", "EDGE_WARNING", "GRID_VARIABLES", "SUMMARY_KEYS",
           "compute_coverage", "summary_json", "write_coverage"]

EDGE_WARNING = 0.25   # ~4 % of scattered footprints lie on a cell edge; above this, a warning
MAX_CELLS = 50_000_000   # a grid of more cells is refused (choose larger cells)


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

    paths, cell_m, min_detections = _checked_options(paths, cell_m, min_detections)
    files: list[ResultsFile] = []
    try:
        for i, p in enumerate(paths):
            files.append(open_results_file(p, i))
        epsg = _one_projection(files)
        geom, region_info = region_polygon(region, bounds, files, epsg)
        scenes = [wkt.loads(f.scene_wkt) for f in files if f.scene_wkt]
        if scenes and not any(geom.intersects(sc) for sc in scenes):
            raise CoverageError(f"{region_option(region_info)}: the region "
                                f"{format_bounds(geom.bounds)} (EPSG:{epsg}) misses the results' "
                                f"scenes ({'; '.join(format_bounds(sc.bounds) for sc in scenes)})")
        rx0, ry0, nx, ny = _grid_frame(geom, cell_m, grid_shift_m)
        xc = rx0 + (np.arange(nx) + 0.5) * cell_m
        yc = ry0 + (np.arange(ny) + 0.5) * cell_m
        in_region = intersects_xy(geom, *np.meshgrid(xc, yc)).astype(np.int8)
        acc = accumulate(files, rx0, ry0, cell_m, nx, ny, progress)
        if acc["n_detected"] == 0:
            raise CoverageError(f"no detected shot in {', '.join(str(p) for p in paths)}: "
                                "nothing to grid (check the run's detection threshold)")
        ex = acc["extent"]
        if acc["n_in_grid"] == 0 and not geom.intersects(box(*ex)):   # a hole is an answer
            raise CoverageError(f"{region_option(region_info)}: the region "
                                f"{format_bounds(geom.bounds)} (EPSG:{epsg}) "
                                f"misses the results, whose footprints span {format_bounds(ex)}")
        grid = grid_dataset(acc, in_region, xc, yc, cell_m, min_detections, epsg)
        crossovers = track_crossovers(files, acc["tracks"], cell_m, epsg)
    finally:
        for f in files:
            f.close()
    summary = coverage_summary(grid, acc, crossovers, geom, region_info, cell_m,
                               min_detections, epsg, paths)
    grid.attrs["summary_json"] = json.dumps(jsonable(summary), allow_nan=False)
    grid.attrs["region_wkt"] = geom.wkt
    tracks = tuple(pl.arrays()[:2] for pl in acc["tracks"])
    return CoverageResult(grid=grid, summary=summary, crossovers=crossovers, region=geom,
                          epsg=epsg, tracks=tracks)


def _checked_options(paths, cell_m, min_detections) -> tuple[list[Path], float, int]:
    """(paths, cell size [m], min_detections) checked: CoverageError for no file, a cell size
    that is not a positive number, a min_detections below 1 or a file given twice."""
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
    return paths, cell_m, min_detections


def _one_projection(files: list[ResultsFile]) -> int:
    """The EPSG code the results files share; CoverageError when they differ."""
    epsgs = sorted({f.epsg for f in files})
    if len(epsgs) > 1:
        which = ", ".join(f"{f.path} (EPSG:{f.epsg})" for f in files)
        raise CoverageError(f"the results files are in different projections: {which}; "
                            "coverage needs one grid")
    return epsgs[0]


def _grid_frame(geom, cell_m: float, grid_shift_m) -> tuple[float, float, int, int]:
    """(x0, y0, nx, ny) of the grid over the region ``geom``: its lower-left corner moved back
    by ``grid_shift_m`` [m], and the cells that cover it; CoverageError when a cell is larger
    than the region or the cells are too many."""
    rx0, ry0, rx1, ry1 = geom.bounds
    rx0, ry0 = rx0 - float(grid_shift_m[0]), ry0 - float(grid_shift_m[1])
    if cell_m > max(rx1 - rx0, ry1 - ry0):
        raise CoverageError(f"--cell-m {cell_m:g}: larger than the region "
                            f"({rx1 - rx0:.0f} m x {ry1 - ry0:.0f} m)")
    nx = max(1, int(math.ceil((rx1 - rx0) / cell_m - 1e-9)))
    ny = max(1, int(math.ceil((ry1 - ry0) / cell_m - 1e-9)))
    if nx * ny > MAX_CELLS:
        raise CoverageError(f"--cell-m {cell_m:g}: {nx} x {ny} cells over the region; "
                            "choose larger cells or a smaller region")
    return rx0, ry0, nx, ny
