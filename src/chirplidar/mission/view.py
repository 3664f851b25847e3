"""``chirplidar view``: a results file with its scene's terrain, in 3-D through
:mod:`chirplidar.viz.scene3d` or as a plan-view map through :mod:`chirplidar.viz.planmap`."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .results import read_netcdf

BOUNDS_OPTION = "--bounds"


def result_terrain(ds):
    """The terrain a result was computed on: its scene as stored in the file
    (``scene_configuration``, with the mission's ``scene.<key>`` changes from ``configuration``;
    relative terrain paths are read beside ``scene_file``; cached generated terrain loads fast),
    or None with a warning when it cannot be rebuilt."""
    from ..config import ConfigError
    from ..config.loader import scene_overrides
    from .scene import load_scene, scene_from_text

    scene_file = ds.attrs.get("scene_file")
    text = ds.attrs.get("scene_configuration")
    try:
        changes = scene_overrides(str(ds.attrs.get("configuration", "")))
        if text:
            base = Path(scene_file).parent if scene_file else Path(".")
            return scene_from_text(str(text), base_dir=base, path=scene_file,
                                   overrides=changes).terrain
        if scene_file and Path(scene_file).is_file():
            return load_scene(scene_file, overrides=changes).terrain
    except (ConfigError, ValueError, OSError) as exc:   # TOMLDecodeError is a ValueError
        warnings.warn(f"the scene of this result cannot be rebuilt ({exc}): drawing it without "
                      "terrain", stacklevel=2)
        return None
    warnings.warn(f"this result names no scene (scene_file {scene_file!r}): drawing it without "
                  "terrain", stacklevel=2)
    return None


def parse_bounds(text: str) -> tuple[float, float, float, float]:
    """``"XMIN,YMIN,XMAX,YMAX"`` (projected metres) -> four floats, validated (finite,
    XMIN < XMAX, YMIN < YMAX); ValueError naming ``--bounds`` otherwise."""
    from ..viz.conventions import check_bounds_m

    parts = str(text).split(",")
    if len(parts) != 4:
        raise ValueError(f"{BOUNDS_OPTION}: expected XMIN,YMIN,XMAX,YMAX (four numbers in "
                         f"projected metres, comma-separated), got {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"{BOUNDS_OPTION}: expected XMIN,YMIN,XMAX,YMAX (four numbers in "
                         f"projected metres, comma-separated), got {text!r}") from None
    return check_bounds_m(values, BOUNDS_OPTION)


def _read_result(path):
    """A results file of ``chirplidar run`` read into memory; ValueError (one line naming the
    file) for anything else."""
    try:
        ds = read_netcdf(path)
    except OSError as exc:
        raise ValueError(f"{path}: not a readable NetCDF results file ({exc})") from None
    missing = [v for v in ("x", "y", "detected") if v not in ds.variables]
    if missing or ds.attrs.get("featureType") != "trajectory":
        raise ValueError(f"{path}: not a chirplidar results file (a CF trajectory with x, y, "
                         f"detected; missing {', '.join(missing) or 'featureType'})")
    return ds


def _check_var(ds, var: str, path) -> None:
    from ..viz.scene3d import showable_variables

    showable = showable_variables(ds)
    if var not in showable:  # before the terrain is loaded
        raise ValueError(f"--var {var}: {path} has no per-shot variable {var!r}; choose one of "
                         f"{', '.join(showable)}")


def _footprints(ds) -> tuple[np.ndarray, np.ndarray]:
    """(n_beams, n_shots) projected footprint x and y (m)."""
    return tuple(np.asarray(ds[n].transpose("trajectory", "obs").values, dtype=np.float64)
                 for n in ("x", "y"))


def _inside(x, y, bounds) -> np.ndarray:
    xmin, ymin, xmax, ymax = bounds
    with np.errstate(invalid="ignore"):
        return (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)


def _check_bounds_hit(ds, bounds, path) -> None:
    """ValueError naming --bounds when no footprint of ``ds`` lies inside ``bounds``."""
    x, y = _footprints(ds)
    if _inside(x, y, bounds).any():
        return
    ok = np.isfinite(x) & np.isfinite(y)
    span = (f"its footprints span x {x[ok].min():.0f} .. {x[ok].max():.0f}, "
            f"y {y[ok].min():.0f} .. {y[ok].max():.0f} m" if ok.any()
            else "it has no footprint with finite x and y")
    xmin, ymin, xmax, ymax = bounds
    raise ValueError(f"{BOUNDS_OPTION} {xmin:g},{ymin:g},{xmax:g},{ymax:g}: no footprint of "
                     f"{path} lies inside ({span})")


def view_result(path, *, var: str = "range_error", png=None, bounds=None,
                camera_azimuth_deg=None, camera_elevation_deg=None, zoom=None):
    """Draw ``path`` (a ``chirplidar run`` output) in 3-D; returns the PNG path or None (window).

    bounds: (xmin, ymin, xmax, ymax) in the results' projected metres: crop the terrain and the
    footprints to that box and fit the camera to it. camera_azimuth_deg, camera_elevation_deg,
    zoom: see :func:`chirplidar.viz.scene3d.render_track` (None: its defaults).
    """
    from ..viz.conventions import check_bounds_m
    from ..viz.scene3d import render_track

    ds = _read_result(path)
    _check_var(ds, var, path)
    if bounds is not None:
        bounds = check_bounds_m(bounds, BOUNDS_OPTION)
        _check_bounds_hit(ds, bounds, path)
    return render_track(ds, result_terrain(ds), var=var, png=png, bounds=bounds,
                        camera_azimuth_deg=camera_azimuth_deg,
                        camera_elevation_deg=camera_elevation_deg, zoom=zoom)


def _epsg(ds):
    """CRS of a results file: its ``epsg_code`` attribute ("EPSG:3413", checked by the map),
    else the EPSG code of its ``crs`` variable, else None."""
    code = ds.attrs.get("epsg_code")
    if code:
        return str(code)
    if "crs" in ds.variables and ds["crs"].attrs:
        from pyproj import CRS

        found = CRS.from_cf(dict(ds["crs"].attrs)).to_epsg()
        return None if found is None else int(found)
    return None


def _survey_region(ds):
    """The survey polygon of the global attribute ``survey_polygon_wkt`` (WKT in the results'
    projected metres) as a shapely geometry; None when absent, or (with a warning) unreadable."""
    text = ds.attrs.get("survey_polygon_wkt")
    if not text:
        return None
    import shapely.wkt
    from shapely.errors import ShapelyError

    try:
        geom = shapely.wkt.loads(str(text))
    except (ShapelyError, ValueError) as exc:
        warnings.warn(f"survey_polygon_wkt is not valid WKT ({exc}): no region outline",
                      stacklevel=3)
        return None
    if geom.geom_type not in ("Polygon", "MultiPolygon") or geom.is_empty:
        warnings.warn(f"survey_polygon_wkt is a {geom.geom_type}, not a polygon: no region "
                      "outline", stacklevel=3)
        return None
    return geom


def _plan_summary(ds, inside: np.ndarray, cropped: bool) -> dict:
    """Numbers for the map's summary box, over the footprints shown."""
    def shot(name):
        return np.asarray(ds[name].transpose("trajectory", "obs").values)[inside]

    n = int(np.count_nonzero(inside))
    out = {"shots_in_bounds" if cropped else "shots": n}
    if "detected" in ds.variables and n:
        det = shot("detected") == 1
        out["fraction_detected"] = float(np.mean(det))
        if "snr_db" in ds.variables and det.any():
            out["median_snr_db"] = float(np.nanmedian(shot("snr_db")[det]))
        if "range_error" in ds.variables and det.any():
            err = shot("range_error")[det]
            err = err[np.isfinite(err)]
            if err.size:
                out["range_error_rms_m"] = float(np.sqrt(np.mean(err ** 2)))
    return out


def view_plan(path, *, var: str = "range_error", png, bounds=None) -> Path:
    """Plan-view map of ``path`` (a ``chirplidar run`` output) written to ``png``.

    Hillshade of the run's terrain (:func:`result_terrain`), the footprint track of every beam,
    the footprints coloured by the per-shot variable ``var`` (NaN shots grey), the survey polygon
    outline when the file has the global attribute ``survey_polygon_wkt``, and a summary box
    (shots, detected fraction, median SNR and RMS range error of the detected shots shown).
    bounds: (xmin, ymin, xmax, ymax) in the results' projected metres frames the view (ValueError
    naming --bounds when no footprint lies inside); None: the footprints and the region.
    Returns the PNG path.
    """
    from ..viz.conventions import check_bounds_m
    from ..viz.planmap import plot_plan_map

    ds = _read_result(path)
    _check_var(ds, var, path)
    x, y = _footprints(ds)
    if bounds is not None:
        bounds = check_bounds_m(bounds, BOUNDS_OPTION)
        _check_bounds_hit(ds, bounds, path)
        inside = _inside(x, y, bounds)
    else:
        inside = np.isfinite(x) & np.isfinite(y)
    values = np.asarray(ds[var].transpose("trajectory", "obs").values, dtype=np.float64)
    attrs = dict(ds[var].attrs)
    shot_var = {"name": var, "long_name": str(attrs.get("long_name", var)),
                "units": str(attrs.get("units", ""))}
    if "flag_values" in attrs and "flag_meanings" in attrs:
        shot_var.update(flag_values=attrs["flag_values"], flag_meanings=attrs["flag_meanings"])
    title = str(ds.attrs.get("title", Path(path).name))
    title = f"{title}\n{Path(path).name}: footprints coloured by {var}"
    terrain = result_terrain(ds)
    return plot_plan_map(
        png, terrain=terrain, tracks=[(x[b], y[b]) for b in range(x.shape[0])],
        shots=(x.ravel(), y.ravel(), values.ravel()), shot_var=shot_var,
        region=_survey_region(ds), region_label="survey polygon",
        summary=_plan_summary(ds, inside, bounds is not None),
        title=title, bounds=bounds, epsg=_epsg(ds))
