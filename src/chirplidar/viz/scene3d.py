"""3-D view of a mission result with pyvista: terrain, platform track and coloured footprints.

Input is a results dataset of :mod:`chirplidar.mission.results` (``build_dataset`` /
``read_netcdf``) and optionally the :class:`chirplidar.geometry.terrain.Terrain` it was flown over.
pyvista (and VTK) are imported inside :func:`render_track` only, so importing this module is cheap
and physics code never pulls in a renderer.

Scene conventions
-----------------
* Coordinates are projected metres (EPSG:3413 / 3031, values up to ~3e6 m). A local origin (the
  centre of the terrain, else of the footprints) is subtracted in float64 before anything reaches
  VTK, which stores points as float32 (~0.25 m steps at 3e6 m; sub-cm within a few tens of km).
* Heights are scaled by the vertical exaggeration about the origin height (the terrain's mean
  vertex height, else the footprints' median height).
* The camera looks from grid south-east (+x, -y of the projection, not true south-east) at 35 deg
  elevation and is fitted to the scene (``camera_azimuth_deg``, ``camera_elevation_deg`` and
  ``zoom`` of :func:`render_track` change that). ``bounds`` crops the terrain and footprints to a
  box of projected metres and fits the camera to the box, so a short stretch of track fills the
  view.

The view is built in three modules: :mod:`~chirplidar.viz.scene3d_geometry` (the arrays: cropped
terrain mesh, local frame, footprint colours, platform track and beam lines),
:mod:`~chirplidar.viz.scene3d_actors` (the pyvista actors, texts and camera) and this one (the
scene of a run, checked options, rendering to a PNG or a window).
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np

from .. import _checks
from .conventions import check_bounds_m
from .scene3d_actors import (BACKGROUND, CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG,
                             add_footprints, add_terrain, add_texts, add_track_and_beams,
                             place_camera)
from .scene3d_geometry import (OBS_DIM, SEGMENT_FRACTION, TRAJECTORY_DIM, checked_exaggeration,
                               filled_heights, footprint_colouring, footprint_heights,
                               is_shot_variable, placed_footprints, platform_geometry,
                               scene_extent, shot_array, terrain_arrays, to_local)

__all__ = ["render_track", "showable_variables"]


def showable_variables(ds) -> list[str]:
    """Names of the per-shot numeric variables (dims ``(trajectory, obs)``) ``var`` may name."""
    return sorted(name for name, v in ds.variables.items() if is_shot_variable(v))


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _check_png(png) -> Path:
    path = _checks.png_path("png", png)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise ValueError(f"png: directory {directory} does not exist")
    return path


def _check_window_size(window_size) -> tuple[int, int]:
    try:
        w, h = window_size
        ok = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 16
                 for v in (w, h))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError("window_size must be two integers (width, height) >= 16 pixels, "
                         f"got {window_size!r}")
    return int(w), int(h)


def _check_camera(azimuth_deg, elevation_deg, zoom) -> tuple[float, float, float]:
    """(azimuth, elevation, zoom) with the module defaults for None, validated."""
    out = []
    for name, option, value, default in (
            ("camera_azimuth_deg", "--camera-azimuth", azimuth_deg, CAMERA_AZIMUTH_DEG),
            ("camera_elevation_deg", "--camera-elevation", elevation_deg, CAMERA_ELEVATION_DEG),
            ("zoom", "--zoom", zoom, 1.0)):
        if value is None:
            out.append(float(default))
            continue
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = math.nan
        if isinstance(value, (bool, np.bool_)) or not math.isfinite(v):
            raise ValueError(f"{name} ({option}) must be a finite number, got {value!r}")
        out.append(v)
    if not -90.0 <= out[1] <= 90.0:
        raise ValueError(f"camera_elevation_deg (--camera-elevation) must lie in [-90, 90] "
                         f"degrees above the horizon, got {out[1]:g}")
    if out[2] <= 0:
        raise ValueError(f"zoom (--zoom) must be > 0 (2: twice as close), got {out[2]:g}")
    return out[0], out[1], out[2]


def _check_scene_inputs(ds, var, title) -> None:
    """ValueError unless ``ds`` has footprint x, y and heights on dims (trajectory, obs), ``var``
    names one of its per-shot variables and ``title`` is a string or None."""
    for name in ("x", "y"):
        if name not in ds.variables:
            raise ValueError(f"ds lacks the footprint coordinate {name!r} (projected metres)")
    if TRAJECTORY_DIM not in ds.dims or OBS_DIM not in ds.dims:
        raise ValueError(f"ds must have dims ({TRAJECTORY_DIM!r}, {OBS_DIM!r}), "
                         f"got {tuple(ds.dims)}")
    showable = showable_variables(ds)
    if not isinstance(var, str) or var not in showable:
        raise ValueError(f"var: {var!r} cannot be shown; per-shot variables of ds: "
                         f"{', '.join(showable)}")
    if title is not None and not isinstance(title, str):
        raise ValueError(f"title must be a string or None, got {type(title).__name__}")
    if "h_li_true" not in ds.variables and "h_li" not in ds.variables:
        raise ValueError("ds lacks h_li_true and h_li: no footprint heights to draw")


class _Scene:
    """Everything to draw, in local display coordinates (float64, origin removed, z scaled)."""

    def __init__(self, ds, terrain, var: str, vertical_exaggeration, title, bounds=None):
        _check_scene_inputs(ds, var, title)
        self.var = var
        self.n_beams = int(ds.sizes[TRAJECTORY_DIM])
        self.n_obs = int(ds.sizes[OBS_DIM])

        x, y = shot_array(ds, "x"), shot_array(ds, "y")
        h = footprint_heights(ds, x.shape)
        values = shot_array(ds, var)
        self.bounds = None if bounds is None else check_bounds_m(bounds, "bounds")
        # terrain in float64 projected metres (cropped to the bounds: None if none is inside)
        tv, tf, codes = terrain_arrays(terrain, self.bounds)
        have_terrain = tv is not None
        placed, self.n_unplaced, self.n_outside = placed_footprints(x, y, self.bounds)
        if not have_terrain and not placed.any():
            raise ValueError("ds has no footprint with finite x and y and no terrain was given: "
                             "nothing to draw")
        h, z_ref, fill_h, self.n_height_filled = filled_heights(h, placed, tv)

        # local origin and horizontal extent (the bounds, when given)
        x_lo, y_lo, x_hi, y_hi, relief = scene_extent(x, y, h, placed, tv, self.bounds)
        self.origin = (0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi), z_ref)
        # camera box (local x, y): the bounds when given (heights: set below), else everything
        # drawn
        self.fit_xy = None if self.bounds is None else (
            (x_lo - self.origin[0], x_hi - self.origin[0]),
            (y_lo - self.origin[1], y_hi - self.origin[1]))
        self.fit_box = None
        # Display scale only: a single footprint without terrain still needs a size.
        self.extent = float(max(x_hi - x_lo, y_hi - y_lo)) or 100.0
        self.ve = ve = checked_exaggeration(vertical_exaggeration, relief, self.extent)

        self.terrain = None
        if have_terrain:
            self.terrain = {"points": to_local(self.origin, ve, tv[:, 0], tv[:, 1], tv[:, 2]),
                            "faces": tf, "z": tv[:, 2], "codes": codes,
                            "names": tuple(terrain.material_names), "used": np.unique(codes)}

        # footprints, split into shots with and without a value of `var`
        xyz = to_local(self.origin, ve, x, y, h).reshape(self.n_beams, self.n_obs, 3)
        self.fp_xyz = xyz[placed]
        if self.fit_xy is not None:
            # the ground in the box: heights of the cropped terrain and of the footprints (the
            # platform track may leave the frame: the box is what was asked for)
            zs = self.fp_xyz[:, 2]
            if self.terrain is not None:
                zs = np.concatenate([zs, self.terrain["points"][:, 2]])
            self.fit_box = np.array([self.fit_xy[0], self.fit_xy[1],
                                     (float(zs.min()), float(zs.max()))])
        self.fp_values = values[placed]
        colouring = footprint_colouring(ds[var], var, self.fp_values)
        self.label, self.categories = colouring["label"], colouring["categories"]
        self.fp_scalars, self.clim = colouring["scalars"], colouring["clim"]
        if "cmap" in colouring:
            self.cmap = colouring["cmap"]
        self.n_nan = int(np.count_nonzero(~np.isfinite(self.fp_scalars)))

        platform = platform_geometry(ds, placed, self.bounds, h, self.origin, ve, self.extent,
                                     xyz)
        self.track = self.rays = self.satellite_km = None
        self.track_runs = []        # (start, stop) rows of self.track drawn as one line each
        if platform is not None:
            self.track, self.track_runs = platform["track"], platform["track_runs"]
            self.rays, self.satellite_km = platform["rays"], platform["satellite_km"]
        self._write_texts(ds, placed, title, fill_h, terrain is not None and not have_terrain,
                          platform is not None)

    def _write_texts(self, ds, placed, title, fill_h: float, terrain_outside: bool,
                     have_platform: bool) -> None:
        """The legend's information lines (``legend_text``) and the heading (``title``)."""
        var = self.var
        x0, y0, z0 = self.origin
        n_shown = int(np.count_nonzero(placed))
        if self.n_beams * self.n_obs == 0:
            self.detected_text = "detected: n/a (no shots)"
        elif "detected" in ds.variables:
            det = shot_array(ds, "detected")
            if self.bounds is not None:
                self.detected_text = (f"detected: {100.0 * np.mean(det[placed] == 1):.1f} % of "
                                      f"the {n_shown} shots shown")
            else:
                self.detected_text = f"detected: {100.0 * np.mean(det == 1):.1f} % of shots"
        else:
            self.detected_text = "detected: n/a (no detected flag)"
        epsg = ds.attrs.get("epsg_code", "projected CRS")
        beams = f"{self.n_beams} beam{'s' if self.n_beams != 1 else ''}"
        lines = [f"{beams}, {self.n_beams * self.n_obs} shots", self.detected_text]
        if self.bounds is not None:
            bx0, by0, bx1, by1 = self.bounds
            lines.append(f"bounds x {bx0:.0f} .. {bx1:.0f} m, y {by0:.0f} .. {by1:.0f} m: "
                         f"{self.n_outside} shots outside not drawn"
                         + ("; no terrain inside" if terrain_outside else ""))
        if self.n_nan:
            lines.append(f"grey: no {var} value ({self.n_nan} shots)")
        if self.n_unplaced:
            lines.append(f"{self.n_unplaced} shots without footprint x/y not drawn")
        if self.n_height_filled:
            lines.append(f"{self.n_height_filled} footprints without height drawn at "
                         f"{fill_h:.0f} m")
        if not have_platform:
            lines.append("no platform position in ds: track not drawn")
        lines.append(f"vertical exaggeration x{self.ve:g}")
        lines.append(f"origin x={x0:.0f} m, y={y0:.0f} m, z={z0:.0f} m ({epsg})")
        self.legend_text = "\n".join(lines)
        heading = title if title is not None else f"chirplidar: {self.label}"
        if self.satellite_km is not None:
            heading += (f"\nplatform at {self.satellite_km:.0f} km "
                        f"(beams cut to {SEGMENT_FRACTION * self.extent / 1e3:.2g} km)")
        self.title = heading


def _populate(pv, pl, s: _Scene, window_size, camera=None) -> None:
    """Add the scene's actors to plotter ``pl`` and place the camera: ``camera`` =
    (azimuth_deg, elevation_deg, zoom), default the module's CAMERA_* constants and zoom 1."""
    pl.set_background(BACKGROUND)
    font = int(np.clip(round(min(window_size) / 40), 8, 28))   # points = pixels at 72 dpi
    legend_entries = []
    if s.terrain is not None:
        add_terrain(pv, pl, s.terrain, legend_entries)
    add_footprints(pv, pl, s, window_size, font, legend_entries)
    add_track_and_beams(pv, pl, s, legend_entries)
    add_texts(pl, s, window_size, font, legend_entries)
    place_camera(pl, s, camera, window_size)


class _QuietVtk:
    """Silence VTK's logger while rendering ("bad X server connection" without a display)."""

    def __enter__(self):
        try:
            from vtkmodules.vtkCommonCore import vtkLogger
        except ImportError:  # pragma: no cover - VTK without the logger
            self._logger = None
            return self
        self._logger = vtkLogger
        self._old = vtkLogger.GetCurrentVerbosityCutoff()
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
        return self

    def __exit__(self, *exc):
        if self._logger is not None:
            self._logger.SetStderrVerbosity(self._logger.ConvertToVerbosity(int(self._old)))
        return False


def render_track(ds, terrain=None, *, var: str = "range_error", png=None, show=None,
                 window_size=(1600, 1000), vertical_exaggeration=None, title=None, bounds=None,
                 camera_azimuth_deg=None, camera_elevation_deg=None, zoom=None):
    """Terrain, platform track and footprints coloured by `var`, with pyvista. Returns the PNG path (or None when only shown).

    Parameters
    ----------
    ds : xarray.Dataset
        Results of :func:`chirplidar.mission.results.build_dataset` / ``read_netcdf``: dims
        ``("trajectory", "obs")`` (one trajectory per beam). Used: ``x``, ``y`` (n_beams, n_shots),
        projected footprint centre, m (EPSG:3413/3031; required); ``h_li_true`` (else ``h_li``),
        footprint surface height above the WGS-84 ellipsoid, m; ``platform_x``, ``platform_y``
        (m, projected) and ``platform_altitude`` (m, ellipsoidal), same for every beam (optional:
        without them no track is drawn); ``detected`` (flag 0/1/2) for the detected fraction;
        ``var``. NaN in any of them means "no value for that shot".
    terrain : chirplidar.geometry.terrain.Terrain or None
        ``terrain.mesh`` (trimesh, vertices (n, 3) in the same projected metres, z = ellipsoidal
        height in m), ``terrain.face_materials`` (n_faces,) codes into
        ``terrain.material_names``. Drawn shaded: by material when it has more than one, else by
        height with an ice colormap. None: only the track and footprints.
    var : str
        Per-shot variable (dims ``(trajectory, obs)``) that colours the footprints, e.g.
        ``range_error`` (m), ``snr_db`` (dB), ``h_li`` (m), ``detected`` / ``surface_type`` (flags:
        categorical colours annotated with ``flag_meanings``). The scalar bar is titled
        ``long_name (units)``. Continuous values use the 1st-99th percentile range (min-max below
        100 shots), a diverging colormap symmetric about 0 when values take both signs (not
        for dB, whose 0 is no special value). Shots with NaN are drawn grey. Unknown names:
        ValueError listing the showable variables.
    png : str or os.PathLike or None
        Output ``.png`` path; its directory must exist. Given, the scene is rendered off-screen
        and written there.
    show : bool or None
        True: open an interactive window (needs a display, DISPLAY or WAYLAND_DISPLAY set;
        without one, ValueError unless ``png`` is given, then only the PNG is written, with a
        warning). False: never open a window. None: interactive only if there is a display and
        no ``png``. With neither a window nor ``png`` there is nothing to produce: ValueError.
    window_size : (int, int)
        Image / window size in pixels (width, height).
    vertical_exaggeration : float or None
        Factor on heights about the terrain's mean height (else the footprints' median height).
        None: automatic, :func:`auto_vertical_exaggeration`: the relief (terrain height range,
        else footprint height range) shown as 10 % of the horizontal extent, rounded down to
        1/2/5 x 10^k, clipped to [1, 100]; 1 for flat-ish scenes.
    title : str or None
        Heading; None gives ``"chirplidar: <long_name (units)>"``.
    bounds : (xmin, ymin, xmax, ymax) or None
        Box in projected metres (the frame of ``ds.x``/``ds.y``): only the terrain faces that
        overlap it, the footprints inside it (and their platform track, broken where it leaves
        the box, and beam lines) are drawn, and the camera is fitted to the box (its x-y extent
        with the height range of what is drawn); the vertical exaggeration and the local origin
        follow the box. ValueError when no footprint lies inside. None: the whole scene.
    camera_azimuth_deg : float or None
        Direction the camera looks from, clockwise from grid north (+y); None:
        ``CAMERA_AZIMUTH_DEG`` (135, grid south-east).
    camera_elevation_deg : float or None
        Camera elevation above the horizon in [-90, 90] degrees (90: straight down, map-like,
        the azimuth's far side up); None: ``CAMERA_ELEVATION_DEG`` (35).
    zoom : float or None
        Factor > 0 applied after fitting (2: twice as close); None: 1.

    Satellites: when the platform's median height above the footprints, times the vertical
    exaggeration, exceeds 3x the horizontal extent of the scene, the track is not drawn (the
    terrain would shrink to a dot); footprints get beam segments toward the platform of length
    0.2x the extent (every footprint up to 80 per beam, evenly subsampled beyond, so the
    segments do not hide the footprints), and the title states the platform altitude in km.
    Otherwise the track is drawn at its (exaggerated) height with faint beam lines to up to 40
    footprints per beam.

    Footprints are drawn as spheres at (x, y, h_li_true), lifted by 0.2 % of the extent so the
    surface does not hide them; where h_li_true is NaN, h_li, else the median footprint height
    (counted in the on-screen legend). Shots with NaN x/y are not drawn (counted too).

    Returns the PNG path (pathlib.Path), or None when only shown interactively.
    """
    import xarray as xr

    if not isinstance(ds, xr.Dataset):
        raise ValueError(f"ds must be an xarray.Dataset, got {type(ds).__name__}")  # noqa: TRY004
    size = _check_window_size(window_size)
    png_path = _check_png(png) if png is not None else None
    if show is not None and not isinstance(show, (bool, np.bool_)):
        raise ValueError(f"show must be True, False or None, got {show!r}")
    display = _has_display()
    if show is None:
        interactive = display and png_path is None
    elif show and not display:
        if png_path is None:
            raise ValueError("show=True needs a display (DISPLAY / WAYLAND_DISPLAY unset); "
                             "pass png=... to render off-screen")
        warnings.warn("show=True but there is no display: writing the PNG only", stacklevel=2)
        interactive = False
    else:
        interactive = bool(show)
    if png_path is None and not interactive:
        raise ValueError("png: no output path given and no interactive window to open "
                         "(no display, or show=False); pass png=...")

    camera = _check_camera(camera_azimuth_deg, camera_elevation_deg, zoom)
    scene = _Scene(ds, terrain, var, vertical_exaggeration, title, bounds=bounds)

    import pyvista as pv  # lazy: only the 3-D view needs VTK

    with _QuietVtk():
        if png_path is not None:
            pl = pv.Plotter(off_screen=True, window_size=size)
            try:
                _populate(pv, pl, scene, size, camera)
                pl.screenshot(str(png_path))
            finally:
                pl.close()
        if interactive:
            pl = pv.Plotter(window_size=size)
            _populate(pv, pl, scene, size, camera)
            pl.show()
    return png_path
