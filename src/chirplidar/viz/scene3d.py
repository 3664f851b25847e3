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
"""

from __future__ import annotations

import itertools
import math
import os
import warnings
from pathlib import Path

import numpy as np

from .. import _checks

__all__ = ["auto_vertical_exaggeration", "check_bounds_m", "render_track",
           "showable_variables"]

TRAJECTORY_DIM = "trajectory"
OBS_DIM = "obs"

CAMERA_AZIMUTH_DEG = 135.0      # clockwise from grid north (+y): south-east
CAMERA_ELEVATION_DEG = 35.0
SATELLITE_RATIO = 3.0           # platform height / scene extent above which beams are cut short
SEGMENT_FRACTION = 0.2          # length of the cut-short beams, fraction of the scene extent
MAX_SEGMENTS_PER_BEAM = 80      # satellite beam segments per beam (every k-th shot beyond;
                                # more would hide the footprints behind a curtain)
MAX_RAYS_PER_BEAM = 40          # aircraft: faint footprint-platform lines per beam (context only)
VE_RELIEF_FRACTION = 0.1        # auto exaggeration: relief appears as >= 10 % of the extent
VE_MAX = 100.0
NAN_COLOR = "#707070"
TRACK_COLOR = "#202020"
RAY_COLOR = "#8c6bb1"           # lavender: not in viridis / RdYlBu_r ends, nor grey
BACKGROUND = "white"

# Ice-like height colormap for single-material terrain: grey-blue lows to near-white highs.
_ICE_COLORS = ("#7f98ad", "#a9bfcf", "#d3e0e9", "#f4f7f9")
# Face colours for material-coloured terrain (names of chirplidar.geometry.terrain.MATERIAL_NAMES).
MATERIAL_COLORS = {
    "snow": "#eef2f5", "snow_fresh": "#ffffff", "firn": "#e3dccb", "blue_ice": "#9cc8e0",
    "open_water": "#2c6ea3", "rock": "#7b6a58", "thesis_target": "#d9a441",
}
_OTHER_MATERIAL_COLORS = ("#c7b8d6", "#b9d6b2", "#e0c0b0", "#b0c4de")
# Categorical colours of flag variables; `detected` gets fixed, meaningful ones.
_DETECTED_COLORS = {0: "#e66101", 1: "#1a9641", 2: "#5e3c99"}
_FLAG_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                "#17becf", "#bcbd22", "#7f7f7f")


# ------------------------------------------------------------------------------------ helpers
def _is_shot_var(var) -> bool:
    return (set(var.dims) == {TRAJECTORY_DIM, OBS_DIM}
            and (np.issubdtype(var.dtype, np.floating) or np.issubdtype(var.dtype, np.integer)))


def showable_variables(ds) -> list[str]:
    """Names of the per-shot numeric variables (dims ``(trajectory, obs)``) ``var`` may name."""
    return sorted(name for name, v in ds.variables.items() if _is_shot_var(v))


def _shot_array(ds, name: str) -> np.ndarray:
    """(n_beams, n_shots) float64 values of a per-shot variable."""
    v = ds[name]
    if set(v.dims) != {TRAJECTORY_DIM, OBS_DIM}:
        raise ValueError(f"ds: variable {name!r} must have dims ({TRAJECTORY_DIM!r}, {OBS_DIM!r}),"
                         f" got {v.dims}")
    return np.asarray(v.transpose(TRAJECTORY_DIM, OBS_DIM).values, dtype=np.float64)


def _flag_table(var) -> tuple[np.ndarray, list[str]] | None:
    """(flag_values, flag_meanings) of a CF flag variable, or None if it is not one."""
    values = var.attrs.get("flag_values")
    meanings = var.attrs.get("flag_meanings")
    if values is None or meanings is None or not np.issubdtype(var.dtype, np.integer):
        return None
    values = np.atleast_1d(np.asarray(values)).astype(np.int64)
    names = str(meanings).split()
    if len(names) != values.size:
        raise ValueError(f"ds: variable {var.name!r} has {values.size} flag_values but "
                         f"{len(names)} flag_meanings")
    return values, names


def _nice_floor(v: float) -> float:
    """Largest of 1, 2, 5 x 10^k not above v (v >= 1)."""
    k = math.floor(math.log10(v))
    for m in (5.0, 2.0, 1.0):
        if m * 10 ** k <= v:
            return m * 10 ** k
    return 10.0 ** k  # pragma: no cover - unreachable for v >= 1


def auto_vertical_exaggeration(relief_m: float, extent_m: float) -> float:
    """Vertical exaggeration that makes the relief visible.

    relief_m: height range of the terrain (else of the footprints), m. extent_m: horizontal extent
    of the scene, m. Rule: the factor that makes the relief ``VE_RELIEF_FRACTION`` (10 %) of the
    extent, rounded down to 1, 2 or 5 x 10^k and clipped to [1, ``VE_MAX``] (100). Flat-ish
    scenes (relief already >= 10 % of the extent, or no relief at all) get 1.
    """
    if not (np.isfinite(relief_m) and np.isfinite(extent_m)) or relief_m <= 0 or extent_m <= 0:
        return 1.0
    raw = VE_RELIEF_FRACTION * extent_m / relief_m
    if raw <= 1.0:
        return 1.0
    return _nice_floor(min(raw, VE_MAX))


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


def colour_range(finite: np.ndarray, symmetric: bool = True) -> tuple[float, float]:
    """(lo, hi) of a colour scale for finite values: the 1st-99th percentile for >= 100 values
    (outliers saturate), else the min-max. A degenerate percentile range falls back to the
    min-max (a count grid of mostly empty cells has percentiles 0..0: its counts must still be
    told apart); an all-equal field gets +-5 % around its value (0..1 for zeros), a range that
    holds the value. With ``symmetric`` the range is widened symmetric about 0 only when it
    straddles 0, i.e. when the values take both signs: non-negative values (counts, gaps,
    precisions) never get a range below 0, so never a diverging map (decibels pass
    ``symmetric=False``: 0 dB is no special value). Shared by the 3-D and plan views."""
    vmin, vmax = float(finite.min()), float(finite.max())
    lo, hi = vmin, vmax
    if finite.size >= 100:
        p_lo, p_hi = (float(v) for v in np.percentile(finite, [1.0, 99.0]))
        if p_hi > p_lo:
            lo, hi = p_lo, p_hi
    if hi <= lo:
        if lo == 0.0:
            return 0.0, 1.0
        pad = 0.05 * abs(lo)
        return lo - pad, lo + pad
    if symmetric and lo < 0.0 < hi:
        m = max(-lo, hi)
        lo, hi = -m, m
    return lo, hi


def _is_decibel(var) -> bool:
    return str(var.attrs.get("units", "")).strip().lower() == "db"


def units_label(long_name: str, units) -> str:
    """Colour-bar label "long_name (units)"; no brackets for dimensionless units ("1", "")."""
    units = "" if units is None else str(units).strip()
    return long_name if units in ("", "1") else f"{long_name} ({units})"


def _label(var) -> str:
    return units_label(str(var.attrs.get("long_name", var.name)), var.attrs.get("units", ""))


def _first_finite_per_obs(*arrays: np.ndarray) -> np.ndarray:
    """(n_obs, k) values from the first beam where all k arrays are finite; rows of NaN where no
    beam has them (the platform is the same for every beam, so any finite beam will do)."""
    stack = np.stack(arrays, axis=-1)                # (n_beams, n_obs, k)
    if stack.shape[0] == 0:
        return np.empty((0, stack.shape[2]))
    ok = np.all(np.isfinite(stack), axis=-1)         # (n_beams, n_obs)
    first = np.argmax(ok, axis=0)
    out = stack[first, np.arange(stack.shape[1])]
    out[~ok.any(axis=0)] = np.nan
    return out


def _every_kth(n: int, n_max: int) -> np.ndarray:
    return np.arange(0, n, max(1, math.ceil(n / n_max)))


def check_bounds_m(bounds, name: str = "bounds") -> tuple[float, float, float, float]:
    """``(xmin, ymin, xmax, ymax)`` as floats (projected metres): four finite numbers with
    xmin < xmax and ymin < ymax, else ValueError naming ``name``."""
    try:
        if isinstance(bounds, (str, bytes)):
            raise TypeError
        values = tuple(float(v) for v in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected four numbers XMIN, YMIN, XMAX, YMAX (projected "
                         f"metres), got {bounds!r}") from None
    if len(values) != 4:
        raise ValueError(f"{name}: expected four numbers XMIN, YMIN, XMAX, YMAX (projected "
                         f"metres), got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name}: XMIN, YMIN, XMAX, YMAX must be finite, got "
                         f"{', '.join(f'{v:g}' for v in values)}")
    xmin, ymin, xmax, ymax = values
    if xmin >= xmax or ymin >= ymax:
        raise ValueError(f"{name}: need XMIN < XMAX and YMIN < YMAX, got x {xmin:g} .. {xmax:g},"
                         f" y {ymin:g} .. {ymax:g}")
    return values


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


def _crop_terrain(terrain, bounds):
    """(vertices (n, 3) float64, faces (m, 3) int64, material codes (m,)) of the terrain's faces
    that overlap ``bounds`` (whole faces: the box is covered to its edges), or None if none does.
    Heightfields are cropped on their grid without building the whole mesh."""
    xmin, ymin, xmax, ymax = bounds
    g = getattr(terrain, "grid", None)
    fm = np.asarray(terrain.face_materials)
    if g is not None:
        gx, gy = g.x_m, g.y_m
        # cell i spans gx[i]..gx[i+1]: it overlaps when gx[i] <= xmax and gx[i+1] >= xmin
        i0 = max(int(np.searchsorted(gx, xmin, side="right")) - 1, 0)
        i1 = min(int(np.searchsorted(gx, xmax, side="right")), gx.size - 1)
        j0 = max(int(np.searchsorted(gy, ymin, side="right")) - 1, 0)
        j1 = min(int(np.searchsorted(gy, ymax, side="right")), gy.size - 1)
        if i1 <= i0 or j1 <= j0:
            return None
        cf = g.cell_face[j0:j1, i0:i1]
        ok = (cf >= 0).ravel()
        if not ok.any():
            return None
        ny, nx = j1 - j0 + 1, i1 - i0 + 1
        idx = np.arange(ny * nx).reshape(ny, nx)
        v00, v10 = idx[:-1, :-1].ravel()[ok], idx[:-1, 1:].ravel()[ok]
        v01, v11 = idx[1:, :-1].ravel()[ok], idx[1:, 1:].ravel()[ok]
        faces = np.empty((2 * v00.size, 3), dtype=np.int64)   # as HeightGrid.build_mesh
        faces[0::2] = np.column_stack([v00, v10, v11])
        faces[1::2] = np.column_stack([v00, v11, v01])
        first = cf.ravel()[ok]
        codes = np.empty(2 * first.size, dtype=fm.dtype)
        codes[0::2], codes[1::2] = fm[first], fm[first + 1]
        xx, yy = np.meshgrid(gx[i0:i1 + 1], gy[j0:j1 + 1])
        verts = np.column_stack([xx.ravel(), yy.ravel(), g.z_m[j0:j1 + 1, i0:i1 + 1].ravel()])
    else:
        verts = np.asarray(terrain.mesh.vertices, dtype=np.float64)
        faces = np.asarray(terrain.mesh.faces, dtype=np.int64)
        fx, fy = verts[faces, 0], verts[faces, 1]
        keep = ((fx.min(axis=1) <= xmax) & (fx.max(axis=1) >= xmin)
                & (fy.min(axis=1) <= ymax) & (fy.max(axis=1) >= ymin))
        if not keep.any():
            return None
        faces, codes = faces[keep], fm[keep]
    used = np.zeros(len(verts), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return verts[used], remap[faces], codes


# ------------------------------------------------------------------------------------ scene
class _Scene:
    """Everything to draw, in local display coordinates (float64, origin removed, z scaled)."""

    def __init__(self, ds, terrain, var: str, vertical_exaggeration, title, bounds=None):
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
        self.var = var
        self.n_beams = int(ds.sizes[TRAJECTORY_DIM])
        self.n_obs = int(ds.sizes[OBS_DIM])

        x, y = _shot_array(ds, "x"), _shot_array(ds, "y")
        # Footprint height: true surface; measured height where the truth is missing.
        h = _shot_array(ds, "h_li_true") if "h_li_true" in ds.variables \
            else np.full(x.shape, np.nan)
        if "h_li" in ds.variables:
            h = np.where(np.isfinite(h), h, _shot_array(ds, "h_li"))
        values = _shot_array(ds, var)

        self.bounds = None if bounds is None else check_bounds_m(bounds, "bounds")
        # terrain in float64 projected metres (cropped to the bounds: None if none is inside)
        tv = tf = codes = None
        if terrain is not None:
            mesh = getattr(terrain, "mesh", None)
            if mesh is None or not hasattr(terrain, "face_materials"):
                raise ValueError("terrain must be a chirplidar.geometry.terrain.Terrain, got "
                                 f"{type(terrain).__name__}")
            if self.bounds is not None:
                cropped = _crop_terrain(terrain, self.bounds)
                if cropped is not None:
                    tv, tf, codes = cropped
            else:
                tv = np.asarray(mesh.vertices, dtype=np.float64)
                tf = np.asarray(mesh.faces, dtype=np.int64)
                codes = np.asarray(terrain.face_materials)
        have_terrain = tv is not None
        finite_xy = np.isfinite(x) & np.isfinite(y)
        self.n_unplaced = int(np.count_nonzero(~finite_xy))
        placed = finite_xy
        self.n_outside = 0
        if self.bounds is not None:
            xmin, ymin, xmax, ymax = self.bounds
            with np.errstate(invalid="ignore"):
                placed = finite_xy & (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
            self.n_outside = int(np.count_nonzero(finite_xy & ~placed))
            if not placed.any():
                span = (f"footprints span x {x[finite_xy].min():.0f} .. {x[finite_xy].max():.0f}"
                        f", y {y[finite_xy].min():.0f} .. {y[finite_xy].max():.0f} m"
                        if finite_xy.any() else "no footprint has finite x and y")
                raise ValueError(f"bounds: no footprint lies inside x {xmin:.0f} .. {xmax:.0f}, "
                                 f"y {ymin:.0f} .. {ymax:.0f} m ({span})")

        if not have_terrain and not placed.any():
            raise ValueError("ds has no footprint with finite x and y and no terrain was given: "
                             "nothing to draw")
        # Heights missing for a placed footprint (e.g. no surface in the beam): draw at the
        # median surface height so the shot is still visible; counted in the legend.
        finite_h = h[placed & np.isfinite(h)]
        if have_terrain:
            z_ref = float(tv[:, 2].mean())
        elif finite_h.size:
            z_ref = float(np.median(finite_h))
        else:
            raise ValueError("ds has no finite h_li_true/h_li and no terrain was given: "
                             "cannot place the footprints in height")
        fill_h = float(np.median(finite_h)) if finite_h.size else z_ref
        self.n_height_filled = int(np.count_nonzero(placed & ~np.isfinite(h)))
        h = np.where(np.isfinite(h), h, fill_h)

        # local origin and horizontal extent (the bounds, when given)
        if self.bounds is not None:
            x_lo, y_lo, x_hi, y_hi = self.bounds
            relief = float(np.ptp(tv[:, 2])) if have_terrain else float(np.ptp(h[placed]))
        elif have_terrain:
            x_lo, y_lo = tv[:, 0].min(), tv[:, 1].min()
            x_hi, y_hi = tv[:, 0].max(), tv[:, 1].max()
            if placed.any():
                x_lo, x_hi = min(x_lo, x[placed].min()), max(x_hi, x[placed].max())
                y_lo, y_hi = min(y_lo, y[placed].min()), max(y_hi, y[placed].max())
            relief = float(np.ptp(tv[:, 2]))
        else:
            x_lo, x_hi, y_lo, y_hi = x[placed].min(), x[placed].max(), y[placed].min(), \
                y[placed].max()
            relief = float(np.ptp(h[placed]))
        self.origin = (0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi), z_ref)
        # camera box (local x, y): the bounds when given (heights: set below), else everything
        # drawn
        self.fit_xy = None if self.bounds is None else (
            (x_lo - self.origin[0], x_hi - self.origin[0]),
            (y_lo - self.origin[1], y_hi - self.origin[1]))
        self.fit_box = None
        # Display scale only: a single footprint without terrain still needs a size.
        self.extent = float(max(x_hi - x_lo, y_hi - y_lo)) or 100.0

        if vertical_exaggeration is None:
            ve = auto_vertical_exaggeration(relief, self.extent)
        else:
            try:
                ve = math.nan if isinstance(vertical_exaggeration, (bool, np.bool_)) \
                    else float(vertical_exaggeration)
            except (TypeError, ValueError):
                ve = math.nan
            if not (np.isfinite(ve) and ve > 0):
                raise ValueError("vertical_exaggeration must be a finite number > 0 or None, "
                                 f"got {vertical_exaggeration!r}")
        self.ve = ve
        x0, y0, z0 = self.origin

        def local(px, py, pz):
            return np.column_stack([np.ravel(px) - x0, np.ravel(py) - y0,
                                    (np.ravel(pz) - z0) * ve])

        # terrain
        self.terrain = None
        if have_terrain:
            names = tuple(terrain.material_names)
            used = np.unique(codes)
            self.terrain = {"points": local(tv[:, 0], tv[:, 1], tv[:, 2]), "faces": tf,
                            "z": tv[:, 2], "codes": codes, "names": names, "used": used}

        # footprints, split into shots with and without a value of `var`
        xyz = local(x, y, h).reshape(self.n_beams, self.n_obs, 3)
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

        # colouring of `var`
        dvar = ds[var]
        self.label = _label(dvar)
        flags = _flag_table(dvar)
        self.categories = None
        if flags is not None:
            fv, fm = flags
            idx = np.full(self.fp_values.shape, np.nan)
            for i, code in enumerate(fv):
                idx[self.fp_values == code] = i
            self.fp_scalars = idx
            if var == "detected":
                colors = [_DETECTED_COLORS.get(int(c), _FLAG_COLORS[i % 10])
                          for i, c in enumerate(fv)]
            else:
                colors = [_FLAG_COLORS[i % len(_FLAG_COLORS)] for i in range(fv.size)]
            self.categories = {"meanings": fm, "colors": colors}
            self.clim = (-0.5, fv.size - 0.5)
        else:
            self.fp_scalars = self.fp_values
            finite = self.fp_values[np.isfinite(self.fp_values)]
            symmetric = not _is_decibel(dvar)
            self.clim = colour_range(finite, symmetric) if finite.size else None
            # Diverging map with a pale-yellow centre: stays distinct from the ice-blue terrain
            # and the grey of no-value shots (coolwarm's grey centre does not).
            self.cmap = "RdYlBu_r" if symmetric and self.clim is not None \
                and self.clim[0] < 0 < self.clim[1] else "viridis"
        self.n_nan = int(np.count_nonzero(~np.isfinite(self.fp_scalars)))

        # platform
        self.track = None
        self.track_runs = []        # (start, stop) rows of self.track drawn as one line each
        self.rays = None
        self.satellite_km = None
        have_platform = all(n in ds.variables
                            for n in ("platform_x", "platform_y", "platform_altitude"))
        if have_platform:
            px, py, pz = (_shot_array(ds, n) for n in
                          ("platform_x", "platform_y", "platform_altitude"))
            track = _first_finite_per_obs(px, py, pz)
            # With bounds: the shots with a footprint inside. The line breaks where the crop
            # removed shots (a lawnmower leaving and re-entering the box), not at NaN fixes.
            shown = placed.any(axis=0) if self.bounds is not None else np.ones(self.n_obs, bool)
            rows = np.flatnonzero(np.all(np.isfinite(track), axis=1) & shown)
            track = track[rows]
            cropped_before = np.cumsum(~shown)[rows]
            breaks = np.flatnonzero(np.diff(cropped_before) != 0) + 1
            edges = [0, *breaks.tolist(), rows.size]
            self.track_runs = [(a, b) for a, b in itertools.pairwise(edges) if b > a]
            if track.shape[0]:
                height_above = float(np.median(track[:, 2])) - float(np.median(h[placed])) \
                    if placed.any() else float(np.median(track[:, 2])) - z0
                track_local = local(track[:, 0], track[:, 1], track[:, 2])
                # Visibility is decided on the drawn (exaggerated) height.
                satellite = height_above * ve > SATELLITE_RATIO * self.extent
                # beam lines: footprint -> platform of the same shot, for a subsample
                ray_ok = placed & np.all(np.isfinite(np.stack([px, py, pz], -1)), axis=-1)
                starts, ends = [], []
                for b in range(self.n_beams):
                    obs = np.flatnonzero(ray_ok[b])
                    obs = obs[_every_kth(obs.size, MAX_SEGMENTS_PER_BEAM if satellite
                                         else MAX_RAYS_PER_BEAM)]
                    starts.append(xyz[b, obs])
                    ends.append(local(px[b, obs], py[b, obs], pz[b, obs]))
                starts, ends = np.concatenate(starts), np.concatenate(ends)
                if satellite:
                    self.satellite_km = float(np.median(track[:, 2])) / 1e3
                    d = ends - starts
                    norm = np.linalg.norm(d, axis=1, keepdims=True)
                    norm[norm == 0] = 1.0
                    ends = starts + d / norm * (SEGMENT_FRACTION * self.extent)
                    self.rays = (starts, ends)
                else:
                    self.track = track_local
                    self.rays = (starts, ends)

        # texts
        n_shown = int(np.count_nonzero(placed))
        if self.n_beams * self.n_obs == 0:
            self.detected_text = "detected: n/a (no shots)"
        elif "detected" in ds.variables:
            det = _shot_array(ds, "detected")
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
                         + ("" if have_terrain or terrain is None else "; no terrain inside"))
        if self.n_nan:
            lines.append(f"grey: no {var} value ({self.n_nan} shots)")
        if self.n_unplaced:
            lines.append(f"{self.n_unplaced} shots without footprint x/y not drawn")
        if self.n_height_filled:
            lines.append(f"{self.n_height_filled} footprints without height drawn at "
                         f"{fill_h:.0f} m")
        if not have_platform:
            lines.append("no platform position in ds: track not drawn")
        lines.append(f"vertical exaggeration x{ve:g}")
        lines.append(f"origin x={x0:.0f} m, y={y0:.0f} m, z={z0:.0f} m ({epsg})")
        self.legend_text = "\n".join(lines)
        heading = title if title is not None else f"chirplidar: {self.label}"
        if self.satellite_km is not None:
            heading += (f"\nplatform at {self.satellite_km:.0f} km "
                        f"(beams cut to {SEGMENT_FRACTION * self.extent / 1e3:.2g} km)")
        self.title = heading


def _terrain_polydata(pv, t: dict):
    faces = np.column_stack([np.full(len(t["faces"]), 3, np.int64), t["faces"]]).ravel()
    poly = pv.PolyData(t["points"], faces)
    poly.point_data["height"] = t["z"]
    return poly.compute_normals(cell_normals=False, point_normals=True, split_vertices=False,
                                auto_orient_normals=False)


def _material_color(name: str, i: int) -> str:
    return MATERIAL_COLORS.get(name, _OTHER_MATERIAL_COLORS[i % len(_OTHER_MATERIAL_COLORS)])


def _populate(pv, pl, s: _Scene, window_size, camera=None) -> None:
    """Add the scene's actors to plotter ``pl`` and place the camera: ``camera`` =
    (azimuth_deg, elevation_deg, zoom), default the module's CAMERA_* constants and zoom 1."""
    from matplotlib.colors import LinearSegmentedColormap, ListedColormap, to_rgb

    pl.set_background(BACKGROUND)
    width_px, height_px = window_size
    font = int(np.clip(round(min(window_size) / 40), 8, 28))   # points = pixels at 72 dpi
    legend_entries = []

    if s.terrain is not None:
        t = s.terrain
        poly = _terrain_polydata(pv, t)
        if t["used"].size > 1:
            # Several materials: colour faces by material (water, rock, ice stand out).
            rgb = np.array([to_rgb(_material_color(n, i)) for i, n in enumerate(t["names"])])
            # Darken low faces a little so the relief reads through the flat material colours.
            zf = t["z"][t["faces"]].mean(axis=1)
            span = float(np.ptp(zf))
            shade = 0.75 + 0.25 * (zf - zf.min()) / span if span > 0 else np.ones_like(zf)
            poly.cell_data["material_rgb"] = np.clip(
                rgb[t["codes"]] * shade[:, None] * 255, 0, 255).astype(np.uint8)
            pl.add_mesh(poly, scalars="material_rgb", rgb=True, smooth_shading=True,
                        show_scalar_bar=False, ambient=0.3, diffuse=0.8)
            for c in t["used"]:
                legend_entries.append([t["names"][c], _material_color(t["names"][c], int(c))])
        else:
            z = t["z"]
            clim = (float(z.min()), float(z.max()))
            if clim[1] <= clim[0]:
                pl.add_mesh(poly, color=_ICE_COLORS[2], smooth_shading=True, ambient=0.3,
                            diffuse=0.8)
            else:
                ice = LinearSegmentedColormap.from_list("ice", _ICE_COLORS)
                pl.add_mesh(poly, scalars="height", cmap=ice, clim=clim, smooth_shading=True,
                            show_scalar_bar=False, ambient=0.3, diffuse=0.8)
            legend_entries.append([f"terrain ({t['names'][int(t['used'][0])]})",
                                   _ICE_COLORS[2]])

    # Footprints sit on the surface; lift them a little so the surface does not hide them.
    lift = np.array([0.0, 0.0, 0.002 * s.extent])
    # pixels: ~10 at a 1000-px window, smaller for many shots so tracks stay readable
    point_size = float(np.clip(min(window_size) / 100, 4, 12))
    if s.fp_xyz.shape[0] > 2000:
        point_size = max(3.0, 0.6 * point_size)
    ok = np.isfinite(s.fp_scalars)
    if ok.any():
        cloud = pv.PolyData(s.fp_xyz[ok] + lift)
        cloud.point_data[s.var] = s.fp_scalars[ok]
        bar = {"title": s.label, "vertical": False, "position_x": 0.45, "position_y": 0.02,
               "width": 0.5, "height": 0.1, "title_font_size": font,
               "label_font_size": max(6, font - 6), "color": "black", "fmt": "%.3g"}
        if s.categories is not None:
            n = len(s.categories["meanings"])
            bar.update(n_labels=0, fmt="%.0f")
            pl.add_mesh(cloud, scalars=s.var, cmap=ListedColormap(s.categories["colors"]),
                        clim=s.clim, n_colors=n, render_points_as_spheres=True,
                        point_size=point_size, scalar_bar_args=bar,
                        annotations={float(i): m for i, m in
                                     enumerate(s.categories["meanings"])})
        else:
            pl.add_mesh(cloud, scalars=s.var, cmap=s.cmap, clim=s.clim,
                        render_points_as_spheres=True, point_size=point_size,
                        scalar_bar_args=bar)
        for actor in pl.scalar_bars.values():
            actor.SetTextPositionToPrecedeScalarBar()
    if (~ok).any():
        grey = pv.PolyData(s.fp_xyz[~ok] + lift)
        pl.add_mesh(grey, color=NAN_COLOR, render_points_as_spheres=True,
                    point_size=0.75 * point_size)
        legend_entries.append([f"no {s.var} value", NAN_COLOR])

    if s.rays is not None and s.rays[0].shape[0]:
        starts, ends = s.rays
        pts = np.empty((2 * starts.shape[0], 3))
        pts[0::2], pts[1::2] = starts + lift, ends
        pl.add_mesh(pv.line_segments_from_points(pts), color=RAY_COLOR, opacity=0.5,
                    line_width=1.0)
        legend_entries.append(["beam to platform" if s.satellite_km is None
                               else "beam (toward platform)", RAY_COLOR])
    runs = [(a, b) for a, b in s.track_runs if b - a >= 2] if s.track is not None else []
    if runs:
        lines = np.concatenate([np.concatenate([[b - a], np.arange(a, b)]) for a, b in runs])
        pl.add_mesh(pv.PolyData(s.track, lines=lines), color=TRACK_COLOR, line_width=3.0)
        legend_entries.append(["platform track", TRACK_COLOR])
    elif s.track is not None:
        pl.add_mesh(pv.PolyData(s.track), color=TRACK_COLOR, point_size=8.0,
                    render_points_as_spheres=True)
        legend_entries.append(["platform", TRACK_COLOR])

    # Text sized to fit the window (Arial is ~0.5 px wide per character and point).
    title_lines = s.title.splitlines()
    title_font = min(font + 4, int(0.95 * width_px / (0.55 * max(map(len, title_lines)))))
    pl.add_actor(_text_actor(s.title, (0.5, 0.985), max(title_font, 6), "center", "top"))
    info_lines = s.legend_text.splitlines()
    info_font = min(font, int(0.42 * width_px / (0.55 * max(map(len, info_lines)))),
                    int(0.3 * height_px / (1.2 * len(info_lines))))
    info_font_size = max(info_font, 6)
    pl.add_actor(_text_actor(s.legend_text, (0.01, 0.015), info_font_size, "left", "bottom"))
    if legend_entries:
        pl.add_actor(_legend_box(legend_entries, window_size, info_font_size))

    # Camera from grid south-east at 35 deg elevation (or as asked), fitted to the scene, or to
    # the bounds' box (with the height range of what is drawn) when they are given.
    az_deg, el_deg, zoom = camera if camera is not None else (
        CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG, 1.0)
    az, el = math.radians(az_deg), math.radians(el_deg)
    direction = np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az),
                          math.sin(el)])
    # Looking straight down (or up) the vertical is no "up": the far side of the azimuth is.
    view_up = (0.0, 0.0, 1.0) if abs(el_deg) < 89.5 else (-math.sin(az), -math.cos(az), 0.0)
    if s.fit_box is None:
        b = np.array(pl.bounds, dtype=float).reshape(3, 2)
        focal = b.mean(axis=1)
        pl.camera_position = [tuple(focal + direction * max(s.extent, 1.0)), tuple(focal),
                              view_up]
        pl.reset_camera()
        pl.camera.zoom(1.05 * zoom)   # 5 % margin around the fitted scene
    else:
        _fit_box(pl, s.fit_box, direction, view_up, width_px / height_px)
        pl.camera.zoom(zoom)


def _fit_box(pl, box: np.ndarray, direction: np.ndarray, view_up, aspect: float,
             margin: float = 1.05) -> None:
    """Place the perspective camera looking along -direction at the centre of ``box`` (3, 2)
    (local coordinates), just far enough for its 8 corners to fit the view (VTK's reset_camera
    fits the bounding sphere instead, which leaves a flat box small from above). aspect: window
    width / height; margin: 5 % of room around the box."""
    focal = box.mean(axis=1)
    d = direction / np.linalg.norm(direction)
    up = np.asarray(view_up, dtype=float)
    right = np.cross(d, up)          # screen axes of a camera looking along -d
    right /= np.linalg.norm(right)
    up = np.cross(right, d)
    tan_v = math.tan(math.radians(pl.camera.view_angle) / 2.0) / margin
    tan_h = tan_v * aspect
    corners = np.array(np.meshgrid(*box, indexing="ij")).reshape(3, -1).T - focal
    toward = corners @ d             # corner's distance from the focal plane towards the camera
    distance = float(np.max(toward + np.maximum(np.abs(corners @ right) / tan_h,
                                                np.abs(corners @ up) / tan_v)))
    distance = max(distance, 1e-3 * float(np.ptp(box[:2], axis=1).max()), 1.0)
    pl.camera_position = [tuple(focal + d * distance), tuple(focal), tuple(up)]
    pl.reset_camera_clipping_range()


def _text_actor(text: str, position, font_size: int, halign: str, valign: str):
    """Black 2-D text at a normalized-viewport position, fixed size in points (pixels)."""
    from vtkmodules.vtkRenderingCore import vtkTextActor

    actor = vtkTextActor()
    actor.SetInput(text)
    actor.SetTextScaleModeToNone()
    prop = actor.GetTextProperty()
    prop.SetFontFamilyToArial()
    prop.SetFontSize(int(font_size))
    prop.SetColor(0.0, 0.0, 0.0)
    {"left": prop.SetJustificationToLeft, "center": prop.SetJustificationToCentered}[halign]()
    {"top": prop.SetVerticalJustificationToTop,
     "bottom": prop.SetVerticalJustificationToBottom}[valign]()
    actor.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
    actor.GetPositionCoordinate().SetValue(*position)
    return actor


def _legend_box(entries, window_size, font_size: int):
    """VTK legend with a colour swatch per entry and black text (pyvista's add_legend colours
    the text like the entry, unreadable for light colours), upper left below the title."""
    from matplotlib.colors import to_rgb
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkRenderingAnnotation import vtkLegendBoxActor

    leg = vtkLegendBoxActor()
    leg.SetNumberOfEntries(len(entries))
    for i, (label, color) in enumerate(entries):
        img = vtkImageData()
        img.SetDimensions(16, 16, 1)
        rgb = np.tile((np.array(to_rgb(color)) * 255).astype(np.uint8), (256, 1))
        arr = numpy_to_vtk(rgb, deep=True)
        arr.SetNumberOfComponents(3)
        img.GetPointData().SetScalars(arr)
        leg.SetEntry(i, img, str(label), [-1.0, -1.0, -1.0])  # negative: text keeps its colour
    leg.GetEntryTextProperty().SetColor(0.0, 0.0, 0.0)
    leg.BorderOn()
    leg.GetBoxProperty().SetColor(0.6, 0.6, 0.6)
    leg.UseBackgroundOn()
    leg.SetBackgroundColor(1.0, 1.0, 1.0)
    # The actor scales text to fit its box: size the box for the wanted font.
    n_chars = max(len(str(label)) for label, _ in entries)
    height = min(0.5, len(entries) * 1.4 * font_size / window_size[1])
    width = min(0.3, (0.55 * font_size * n_chars + 2.0 * font_size) / window_size[0])
    leg.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
    leg.GetPositionCoordinate().SetValue(0.01, 0.88 - height)
    leg.GetPosition2Coordinate().SetCoordinateSystemToNormalizedViewport()
    leg.GetPosition2Coordinate().SetValue(width, height)
    return leg


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


# ------------------------------------------------------------------------------------ public
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
