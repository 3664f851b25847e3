"""The coverage grid as CF-1.8 (:mod:`chirplidar.analysis.coverage`): the per-cell variables from
the accumulated sums (counts, height spreads, SNR medians, revisits, gaps) with their units and
long names, and the NetCDF-4 file of the grid and its crossovers."""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from ..mission.results import NETCDF_LOCK
from .coverage_accumulate import GAP_PIXELS_PER_CELL, SNR_RANGE_DB

if TYPE_CHECKING:
    from .coverage import CoverageResult


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


def grid_dataset(acc, in_region, xc, yc, cell_m, min_detections, epsg) -> xr.Dataset:
    """The CF grid Dataset (dims ``(y, x)``, cell centres ``xc``, ``yc``) of the sums ``acc``
    (:func:`~chirplidar.analysis.coverage_accumulate.accumulate`) and the ``in_region`` mask."""
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
