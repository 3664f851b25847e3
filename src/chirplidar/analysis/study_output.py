"""The outputs of a mission study (:mod:`chirplidar.analysis.study`): its dataset and NetCDF file,
its records (``--json``) and its table.

The study dataset has one dimension per varied key, named after the resolved mission key with
every character outside [A-Za-z0-9_] replaced by ``_`` (``platform.uav.altitude_m`` ->
``platform_uav_altitude_m``, ``lsr.Po`` -> ``laser_power_w``); the coordinate holds the values
(strings for string values) with ``long_name``, ``units`` (from the key's suffix: ``_m`` m,
``_deg`` degree, ``_w`` W, ``_mps`` m s-1, ``_db`` dB, ... ``1`` for dimensionless keys and
labels), ``study_key`` (as given) and ``mission_key`` (resolved). Every metric has ``units``
and ``long_name``. Global attributes: mission file, seed, tier, span, ``--set`` list, ``--vary``
specs, cell size, software version.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import xarray as xr

from .study_grid import axis_coordinate, key_units
from .study_metrics import COUNT_METRICS, METRICS
from .study_plan import StudyPlan


def study_dataset(plan: StudyPlan, metrics: dict, *, elapsed_s: float | None = None,
                  date_created: str | None = None) -> xr.Dataset:
    """The study dataset of ``plan`` from metric arrays shaped like the grid."""
    from .. import __version__
    from ..mission.manifest import default_date_created

    dims = tuple(a.dim for a in plan.axes)
    coords = {}
    for a in plan.axes:
        values, kind = axis_coordinate(a)
        units, _ = key_units(a.mission_key) if kind == "number" else ("1", "")
        named = a.key if a.key == a.mission_key else f"{a.key} ({a.mission_key})"
        attrs = {"long_name": f"varied mission key {named}", "units": units,
                 "study_key": a.key, "mission_key": a.mission_key, "spacing": a.spacing,
                 "vary_spec": a.spec}
        if kind == "number" and any(isinstance(v, list) for v in a.values):
            attrs["comment"] = "each value is the one element of the list given to the key"
        coords[a.dim] = ((a.dim,), values, attrs)
    data_vars = {}
    for name, (units, long_name) in METRICS.items():
        if name == "fraction_covered" and plan.cell_m is None:
            continue
        attrs = {"units": units, "long_name": long_name}
        if name == "fraction_covered":
            attrs["cell_size_m"] = float(plan.cell_m)
        data_vars[name] = (dims, np.asarray(metrics[name]), attrs)
    date_created = date_created or default_date_created()
    source = f"chirplidar {__version__}"
    span = ("the whole mission" if plan.span_s is None
            else f"survey.start_s .. survey.start_s + {plan.span_s:g} s")
    attrs = {
        "Conventions": "CF-1.8",
        "title": f"chirplidar mission study: {plan.mission_path.stem} over "
                 f"{' x '.join(a.key for a in plan.axes)}",
        "source": source,
        "history": f"{date_created} {source}: chirplidar study of {plan.mission_path}",
        "date_created": date_created,
        "software_version": __version__,
        "mission_file": str(plan.mission_path),
        "seed": np.int64(plan.seed),
        "tier": plan.tier,
        "span": span,
        "set_overrides": json.dumps(list(plan.overrides)),
        "vary": json.dumps([a.spec for a in plan.axes]),
        "points": np.int64(len(plan.points)),
    }
    if plan.span_s is not None:
        attrs["span_s"] = float(plan.span_s)
    if plan.cell_m is not None:
        attrs["cell_m"] = float(plan.cell_m)
    if elapsed_s is not None:
        attrs["elapsed_s"] = float(elapsed_s)
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def write_study(ds: xr.Dataset, path, *, overwrite: bool = False) -> Path:
    """Write a study dataset to NetCDF atomically (temp file beside it, fsync, rename); an
    existing ``path`` raises FileExistsError unless ``overwrite``. NaN is the fill value of
    the float metrics (no value); -inf stays -inf (zero signal)."""
    from ..mission.results import NETCDF_LOCK, write_atomic

    for name, var in ds.variables.items():
        if "units" not in var.attrs or "long_name" not in var.attrs:
            raise ValueError(f"study variable {name!r} needs units and long_name")
    encoding = {name: {"_FillValue": np.nan} for name, var in ds.data_vars.items()
                if np.issubdtype(var.dtype, np.floating)}
    encoding.update({name: {"_FillValue": None} for name, var in ds.variables.items()
                     if np.issubdtype(var.dtype, np.integer)})

    def write(tmp):
        with NETCDF_LOCK:
            ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=encoding)

    return write_atomic(Path(path), write, overwrite=overwrite)


def _axis_dims(ds: xr.Dataset) -> list[str]:
    return [d for d in ds["detection_probability"].dims]


def study_records(ds: xr.Dataset) -> list[dict]:
    """One dict per point (C order over the varied keys): each varied key as given (its
    value), then the metrics (Python floats, -inf/NaN as they are; JSON writers map them)."""
    dims = _axis_dims(ds)
    names = [n for n in METRICS if n in ds.data_vars]
    records = []
    for index in np.ndindex(*[ds.sizes[d] for d in dims]):
        rec = {}
        for d, i in zip(dims, index):
            v = ds[d].values[i]
            rec[str(ds[d].attrs.get("study_key", d))] = v.item() if hasattr(v, "item") else v
        for n in names:
            v = ds[n].values[index]
            rec[n] = int(v) if n in COUNT_METRICS else float(v)
        records.append(rec)
    return records


def _fmt(value, scale: float = 1.0, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "-inf" if value < 0 else "inf"
    return f"{value * scale:.{digits}f}"


def format_study(ds: xr.Dataset) -> str:
    """A readable table of a study: one row per point."""
    dims = _axis_dims(ds)
    keys = [str(ds[d].attrs.get("study_key", d)) for d in dims]
    cols = [("P_det", "%", "detection_probability", 100.0, 1),
            ("SNR p50", "dB", "median_snr_db", 1.0, 1),
            ("p01", "dB", "snr_p01_db", 1.0, 1),
            ("p10", "dB", "snr_p10_db", 1.0, 1),
            ("p90", "dB", "snr_p90_db", 1.0, 1),
            ("Psig p50", "dBm", "median_received_power_dbm", 1.0, 1),
            ("range RMS", "cm", "range_rms_m", 100.0, 2),
            ("h prec", "cm", "height_precision_m", 100.0, 2)]
    if "fraction_covered" in ds.data_vars:
        cols.append(("covered", "%", "fraction_covered", 100.0, 1))
    cols += [("flight", "s", "flight_time_s", 1.0, 1),
             ("shots", "", "shots", 1.0, 0)]
    if "detected_shots" in ds.data_vars:   # study files written before it existed lack it
        cols.append(("detected", "", "detected_shots", 1.0, 0))
    cols.append(("threshold", "dB", "detection_threshold_db", 1.0, 1))
    key_w = [max(len(k), 10) for k in keys]
    col_w = [max(len(c[0]), len(c[1]) + 2, 8) for c in cols]
    head1 = "  ".join(k.rjust(w) for k, w in zip(keys, key_w)) + "  " + "  ".join(
        c[0].rjust(w) for c, w in zip(cols, col_w))
    units = []
    for d, w in zip(dims, key_w):
        u = ds[d].attrs.get("units", "1")
        units.append((f"({u})" if u not in ("1", "") else "").rjust(w))
    head2 = "  ".join(units) + "  " + "  ".join(
        (f"({c[1]})" if c[1] else "").rjust(w) for c, w in zip(cols, col_w))
    span = ds.attrs.get("span", "")
    header = (f"chirplidar study: {ds.attrs.get('mission_file', '')}, "
              f"{int(ds.attrs.get('points', 0))} points, tier {ds.attrs.get('tier', '')}, "
              f"seed {int(ds.attrs.get('seed', 0))}, span {span}")
    lines = [header, head1, head2]
    for rec in study_records(ds):
        row = []
        for k, w in zip(keys, key_w):
            v = rec[k]
            row.append((f"{v:.6g}" if isinstance(v, float) else str(v)).rjust(w))
        for (label, _, name, scale, digits), w in zip(cols, col_w):
            v = rec[name]
            row.append((str(v) if name in COUNT_METRICS else _fmt(v, scale, digits)).rjust(w))
        lines.append("  ".join(row))
    return "\n".join(lines)
