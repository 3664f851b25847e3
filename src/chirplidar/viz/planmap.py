"""Plan-view (2-D) map of a survey in projected metres: hillshaded terrain, footprint tracks,
coverage-grid cells or coloured footprints, the survey region and crossovers.

The map is drawn in the projection of the run (EPSG:3413 Greenland, EPSG:3031 Antarctica):
axes in km of projected x and y, equal aspect, a scale bar of a round length, and a north arrow
along *true* north. In polar stereographic projections grid north (+y) is true north only on the
central meridian: in EPSG:3413 at 50 W true north points 5 deg clockwise of grid north, in
EPSG:3031 at 100 E it points 100 deg clockwise of it (:func:`true_north_bearing_deg`).

matplotlib is imported through :mod:`chirplidar.viz._mpl` (Agg backend unless pyplot is already in
use). Physics code never imports this module; the CLI imports it lazily (``chirplidar view
--plan``).

Public: :func:`plot_plan_map` (write a PNG), :func:`plan_map_figure` (the figure, e.g. for a
notebook), :func:`hillshade`, :func:`true_north_bearing_deg`, :func:`scale_bar_length_m`.
"""

from __future__ import annotations

import functools
import math
import textwrap
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .. import _checks
from ._mpl import plt, save
from .scene3d import _DETECTED_COLORS, _FLAG_COLORS, check_bounds_m, colour_range, units_label

__all__ = ["hillshade", "plan_map_figure", "plot_plan_map", "scale_bar_length_m",
           "true_north_bearing_deg"]

# Illumination of the hillshade: the cartographic convention, light from the upper left of the
# map (grid north-west), 45 deg above the horizon.
SUN_AZIMUTH_DEG = 315.0
SUN_ELEVATION_DEG = 45.0
MAX_SHADE_PX = 1500            # hillshade raster, pixels on a side (grids are decimated to it)
MAX_CONTOUR_PX = 300           # contours from a block-averaged grid: smooth, not every crevasse
MESH_RASTER_PX = 400           # mesh terrains (no grid): heights interpolated on this raster
MAX_MESH_VERTICES = 200_000    # mesh vertices fed to the interpolation (every k-th beyond)
MAX_TRACK_VERTICES = 4000      # drawn vertices per track (NaN breaks kept)
MAX_SHOTS_DRAWN = 200_000      # footprints drawn (every k-th beyond)
MARGIN_FRACTION = 0.04         # default view: what is drawn plus 4 % of its size on each side
NORTH_STEP_DEG = 0.01          # step along the meridian to find true north
GRID_ALPHA = 0.75              # coverage cells over the hillshade
TITLE_WRAP_CHARS = 80          # 11-pt title over a ~8-in wide map
MIN_ASPECT, MAX_ASPECT = 0.25, 2.5   # view height / width (the shorter side is widened)
# Layout in inches (figure 10 in wide by default; 120 dpi as _mpl.save writes)
FIG_WIDTH_IN = 10.0
MAX_AXES_HEIGHT_IN = 9.0
LEFT_IN = 1.05                 # y tick labels ("-2503.5") and the y label
RIGHT_PAD_IN = 0.15
TITLE_LINE_IN = 0.24
LEGEND_ROW_IN = 0.22
LEGEND_COLUMNS = 3
# Summary box below the map (never over the data): its lines in columns, read down each column
SUMMARY_FONT_PT = 8.5
SUMMARY_ROW_IN = 0.165         # one 8.5-pt line
SUMMARY_COL_GAP_IN = 0.35
SUMMARY_PAD_IN = 0.09          # inside the frame, each side
SUMMARY_GAP_IN = 0.1           # between the box and the legend above it
SUMMARY_MAX_COLUMNS = 4
CBAR_GAP_IN, CBAR_WIDTH_IN, CBAR_TICKS_IN, CBAR_LABEL_LINE_IN = 0.2, 0.18, 0.62, 0.22

TRACK_COLOR = "#1a1a1a"
REGION_COLOR = "#c51b7d"       # dark magenta: not in viridis, RdBu or the grey hillshade
CROSSOVER_COLOR = "#000000"
NAN_COLOR = "#8c8c8c"
CONTOUR_COLOR = "#5b4a3a"
FLAG01_COLORS = ("#d95f02", "#1b9e77")   # 0 (e.g. not covered): orange, 1: green
HALO = "white"


# ------------------------------------------------------------------------------------ helpers
def hillshade(z_m, x_m, y_m, *, azimuth_deg: float = SUN_AZIMUTH_DEG,
              elevation_deg: float = SUN_ELEVATION_DEG) -> np.ndarray:
    """Lambertian shade in [0, 1] of a heightfield lit by a distant sun.

    z_m (ny, nx): heights (m), row j at y_m[j] (rows increasing in y, as
    :class:`chirplidar.geometry.terrain.HeightGrid`); x_m (nx,), y_m (ny,): node coordinates (m),
    monotonic, uniform or not. azimuth_deg: direction the light comes from, clockwise from grid
    north (+y); elevation_deg: its angle above the horizon. The shade is the cosine of the angle
    between the surface normal (-dz/dx, -dz/dy, 1) and the direction to the sun, clipped at 0
    (slopes facing away); a flat surface gets sin(elevation). NaN heights give NaN around them.
    """
    z = np.asarray(z_m, dtype=np.float64)
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    if z.ndim != 2 or z.shape != (y.size, x.size) or min(z.shape) < 2:
        raise ValueError(f"z_m must be (ny, nx) = ({y.size}, {x.size}) with at least 2 nodes "
                         f"per axis, got {z.shape}")
    dz_dy, dz_dx = np.gradient(z, y, x)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    lx, ly, lz = math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)
    shade = (-dz_dx * lx - dz_dy * ly + lz) / np.sqrt(1.0 + dz_dx ** 2 + dz_dy ** 2)
    return np.clip(shade, 0.0, 1.0)


@functools.lru_cache(maxsize=8)
def _transformers(epsg: int):
    from pyproj import Transformer

    return (Transformer.from_crs(epsg, 4326, always_xy=True),
            Transformer.from_crs(4326, epsg, always_xy=True))


def true_north_bearing_deg(x_m: float, y_m: float, epsg) -> float:
    """Direction of true (geographic) north at the projected point (x_m, y_m), in degrees
    clockwise from grid north (+y of the projection), in (-180, 180].

    Computed with pyproj: the point to longitude/latitude, a step of 0.01 deg along its meridian
    towards the north pole (within 0.01 deg of the north pole: a step south, reversed), back to
    the projection. This is minus the meridian convergence of PROJ's ``get_factors``. In EPSG:3413
    (polar stereographic, central meridian 45 W) it is -(lon + 45 deg); in EPSG:3031 (0 E, south
    pole) it is lon. NaN at a pole, where north is no direction.
    """
    code = _epsg_code(epsg, "epsg")
    if code is None:
        raise ValueError("epsg: a projected EPSG code is needed to find true north")
    to_geo, to_map = _transformers(code)
    lon, lat = to_geo.transform(float(x_m), float(y_m))
    if not (math.isfinite(lon) and math.isfinite(lat)) or abs(lat) >= 90.0 - 1e-9:
        return math.nan
    sign = 1.0 if lat + NORTH_STEP_DEG <= 90.0 else -1.0
    x2, y2 = to_map.transform(lon, lat + sign * NORTH_STEP_DEG)
    dx, dy = sign * (x2 - float(x_m)), sign * (y2 - float(y_m))
    if not (math.isfinite(dx) and math.isfinite(dy)) or dx == dy == 0.0:
        return math.nan
    bearing = math.degrees(math.atan2(dx, dy))
    return 180.0 if bearing == -180.0 else bearing


def scale_bar_length_m(view_width_m: float) -> float:
    """Round scale-bar length (m) for a view ``view_width_m`` wide: the largest 1, 2 or 5 x 10^k
    metres not above a fifth of the width (e.g. 6 km -> 1 km, 3 km -> 500 m, 80 km -> 10 km)."""
    w = float(view_width_m)
    if not math.isfinite(w) or w <= 0:
        raise ValueError(f"view_width_m must be a finite number > 0, got {view_width_m!r}")
    target = w / 5.0
    k = math.floor(math.log10(target))
    for m in (5.0, 2.0, 1.0):
        if m * 10.0 ** k <= target * (1 + 1e-12):
            return m * 10.0 ** k
    return 10.0 ** k  # pragma: no cover - unreachable


def _sig(value: float, digits: int = 3) -> str:
    """``value`` with ``digits`` significant digits, positional (no exponent), trailing zeros
    dropped: 999.6 -> "1000", 0.04619 -> "0.0462"."""
    return np.format_float_positional(float(value), precision=digits, unique=False,
                                      fractional=False, trim="-")


def _format_length(length_m: float) -> str:
    """A length with a unit that keeps it readable: 12 km, 350 m, 4.62 cm, 0.8 mm."""
    a = abs(length_m)
    if a >= 1000.0:
        return f"{_sig(length_m / 1000.0)} km"
    if a >= 1.0 or a == 0.0:
        return f"{_sig(length_m)} m"
    if a >= 0.01:
        return f"{_sig(length_m * 100.0)} cm"
    return f"{_sig(length_m * 1000.0)} mm"


def _km_tick(value_m: float, _pos=None) -> str:
    return np.format_float_positional(round(value_m / 1000.0, 6), trim="-")


def _epsg_code(epsg, name: str) -> int | None:
    """EPSG code (int) of ``epsg`` (int, "EPSG:3413", or anything pyproj reads), None for None;
    ValueError naming ``name`` unless it is a projected CRS with an EPSG code."""
    if epsg is None:
        return None
    if isinstance(epsg, (bool, np.bool_)):
        raise ValueError(  # noqa: TRY004 - bad input is a ValueError in this package
            f"{name}: expected an EPSG code such as 3413, got {epsg!r}")
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_epsg(int(epsg)) if isinstance(epsg, (int, np.integer)) \
            else CRS.from_user_input(epsg)
    except (CRSError, TypeError, ValueError):
        raise ValueError(f"{name}: {epsg!r} is not a coordinate reference system pyproj "
                         "knows") from None
    code = crs.to_epsg()
    if not crs.is_projected or code is None:
        raise ValueError(f"{name}: {epsg!r} must be a projected CRS with an EPSG code "
                         "(e.g. 3413 or 3031)")
    return int(code)


def _grid_epsg(grid) -> int | None:
    """EPSG code of a coverage grid: its ``epsg_code`` attribute, else its ``crs`` variable."""
    if grid is None:
        return None
    if grid.attrs.get("epsg_code"):
        return _epsg_code(str(grid.attrs["epsg_code"]), "grid.attrs['epsg_code']")
    if "crs" in grid.variables and grid["crs"].attrs:
        from pyproj import CRS
        from pyproj.exceptions import CRSError

        try:
            code = CRS.from_cf(dict(grid["crs"].attrs)).to_epsg()
        except CRSError:
            return None
        return None if code is None else int(code)
    return None


def _decimation_step(n: int, n_max: int) -> int:
    return max(1, math.ceil(n / n_max))


def _as_1d(name: str, values) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numbers") from None
    if arr.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array, got shape {arr.shape}")
    return arr


def _decimate_track(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every k-th vertex (at most ~MAX_TRACK_VERTICES), keeping the last one, every NaN and the
    vertices next to a NaN, so the line still breaks where the track does."""
    n = x.size
    step = _decimation_step(n, MAX_TRACK_VERTICES)
    if step == 1:
        return x, y
    keep = np.zeros(n, dtype=bool)
    keep[::step] = True
    keep[-1] = True
    gap = ~(np.isfinite(x) & np.isfinite(y))
    if gap.any():
        keep |= gap
        keep[1:] |= gap[:-1]
        keep[:-1] |= gap[1:]
    return x[keep], y[keep]


def _block_mean(z: np.ndarray, k: int) -> np.ndarray:
    """Mean over k x k blocks (NaN ignored; trailing partial blocks dropped)."""
    ny, nx = (z.shape[0] // k) * k, (z.shape[1] // k) * k
    blocks = z[:ny, :nx].reshape(ny // k, k, nx // k, k)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # all-NaN blocks stay NaN: wanted
        return np.nanmean(blocks, axis=(1, 3))


def _nice_step(span: float, n_target: int) -> float:
    """1, 2 or 5 x 10^k step giving about n_target intervals over span (> 0)."""
    raw = span / n_target
    k = math.floor(math.log10(raw))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0 ** k >= raw:
            return m * 10.0 ** k
    return 10.0 ** (k + 1)  # pragma: no cover


# ------------------------------------------------------------------------------------ inputs
def _check_terrain(terrain):
    if terrain is None:
        return None
    if not (hasattr(terrain, "grid") and hasattr(terrain, "bounds")
            and hasattr(terrain, "face_materials")):
        raise ValueError("terrain: expected a chirplidar.geometry.terrain.Terrain, got "
                         f"{type(terrain).__name__}")
    return terrain


def _check_tracks(tracks) -> list[tuple[np.ndarray, np.ndarray]]:
    if tracks is None:
        return []
    if isinstance(tracks, (str, bytes)) or not hasattr(tracks, "__iter__"):
        raise ValueError("tracks: expected a list of (x, y) pairs of 1-D arrays (m)")
    out = []
    for i, item in enumerate(tracks):
        try:
            tx, ty = item
        except (TypeError, ValueError):
            raise ValueError(f"tracks[{i}]: expected an (x, y) pair of 1-D arrays (m)") from None
        tx, ty = _as_1d(f"tracks[{i}] x", tx), _as_1d(f"tracks[{i}] y", ty)
        if tx.shape != ty.shape:
            raise ValueError(f"tracks[{i}]: x and y differ in length ({tx.size} vs {ty.size})")
        out.append((tx, ty))
    return out


def _check_shots(shots):
    if shots is None:
        return None
    try:
        sx, sy, sv = shots
    except (TypeError, ValueError):
        raise ValueError("shots: expected (x, y, values), three 1-D arrays of equal length") \
            from None
    sx, sy, sv = _as_1d("shots x", sx), _as_1d("shots y", sy), _as_1d("shots values", sv)
    if not sx.size == sy.size == sv.size:
        raise ValueError(f"shots: x, y and values differ in length ({sx.size}, {sy.size}, "
                         f"{sv.size})")
    return sx, sy, sv


def _check_shot_var(shot_var) -> dict:
    """shot_var as a dict: ``name``, ``long_name``, ``units``, optional ``flag_values`` and
    ``flag_meanings`` (CF attributes of the variable)."""
    if shot_var is None:
        return {"name": "value", "long_name": "footprint value", "units": ""}
    if isinstance(shot_var, str):
        return {"name": shot_var, "long_name": shot_var, "units": ""}
    if isinstance(shot_var, Mapping):
        meta = dict(shot_var)
        name = str(meta.get("name", meta.get("long_name", "value")))
        meta.setdefault("name", name)
        meta.setdefault("long_name", name)
        meta.setdefault("units", "")
        return meta
    raise ValueError("shot_var: expected a name (str) or a mapping with long_name and units, got "
                     f"{type(shot_var).__name__}")


def _check_region(region):
    if region is None:
        return []
    kind = getattr(region, "geom_type", None)
    if kind == "Polygon":
        polygons = [region]
    elif kind == "MultiPolygon":
        polygons = list(region.geoms)
    else:
        raise ValueError("region: expected a shapely Polygon or MultiPolygon in projected "
                         f"metres, got {kind or type(region).__name__}")
    if region.is_empty:
        raise ValueError("region: the polygon is empty")
    return polygons


def _check_crossovers(crossovers):
    if crossovers is None:
        return None
    for name in ("x", "y"):
        if not hasattr(crossovers, "variables") or name not in crossovers.variables:
            raise ValueError(f"crossovers: expected an xarray.Dataset with variables x and y "
                             f"(m) along dim 'crossover'; {name!r} is missing")
    cx = np.ravel(np.asarray(crossovers["x"].values, dtype=np.float64))
    cy = np.ravel(np.asarray(crossovers["y"].values, dtype=np.float64))
    if cx.shape != cy.shape:
        raise ValueError("crossovers: x and y differ in length")
    ok = np.isfinite(cx) & np.isfinite(cy)
    return cx[ok], cy[ok]


def _flag_table(attrs: Mapping, values: np.ndarray, integer: bool):
    """(codes, labels) of a categorical variable, or None for a continuous one; labels are
    "<name>: <meaning>" (legend entries).

    Categorical: CF ``flag_values`` + ``flag_meanings`` attributes; or a 0/1 variable stored as a
    one-byte integer or bool (the coverage grid's ``covered`` and ``in_region``: counts are int32),
    meanings "no" / "yes".
    """
    name = str(attrs.get("name", "flag"))
    fv, fm = attrs.get("flag_values"), attrs.get("flag_meanings")
    if fv is not None and fm is not None:
        codes = np.atleast_1d(np.asarray(fv)).astype(np.int64)
        meanings = [m.replace("_", " ") for m in str(fm).split()]
        if len(meanings) != codes.size:
            raise ValueError(f"{name}: {codes.size} flag_values but {len(meanings)} "
                             "flag_meanings")
        return codes, [f"{name}: {m}" for m in meanings]
    if integer:
        finite = values[np.isfinite(values)]
        if finite.size == 0 or np.all(np.isin(finite, (0, 1))):
            return np.array([0, 1]), [f"{name}: no", f"{name}: yes"]
    return None


# ------------------------------------------------------------------------------------ layers
def _terrain_raster(terrain, view) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(x (nx,), y (ny,), z (ny, nx)) heights over the view (plus one node), at most
    MAX_SHADE_PX nodes on a side; None when the terrain does not reach the view."""
    xmin, ymin, xmax, ymax = view
    grid = terrain.grid
    if grid is not None:
        gx, gy = np.asarray(grid.x_m, float), np.asarray(grid.y_m, float)
        i0 = max(int(np.searchsorted(gx, xmin, side="right")) - 2, 0)
        i1 = min(int(np.searchsorted(gx, xmax, side="left")) + 2, gx.size)
        j0 = max(int(np.searchsorted(gy, ymin, side="right")) - 2, 0)
        j1 = min(int(np.searchsorted(gy, ymax, side="left")) + 2, gy.size)
        if i1 - i0 < 2 or j1 - j0 < 2:
            return None
        step = _decimation_step(max(i1 - i0, j1 - j0), MAX_SHADE_PX)
        x, y = gx[i0:i1:step], gy[j0:j1:step]
        z = np.asarray(grid.z_m[j0:j1:step, i0:i1:step], dtype=np.float64)
        if min(z.shape) < 2:
            return None
        return x, y, z
    # Mesh terrain: no grid; interpolate its vertex heights (linear, over their Delaunay
    # triangulation) on a raster. Good for plan views of smooth surfaces; overhangs and vertical
    # walls (several heights at one x, y) are averaged away.
    from scipy.interpolate import griddata
    from scipy.spatial import QhullError

    tb = np.asarray(terrain.bounds, dtype=np.float64)
    x0, x1 = max(xmin, tb[0, 0]), min(xmax, tb[1, 0])
    y0, y1 = max(ymin, tb[0, 1]), min(ymax, tb[1, 1])
    if x1 <= x0 or y1 <= y0:
        return None
    v = np.asarray(terrain.mesh.vertices, dtype=np.float64)
    pad_x, pad_y = 0.05 * (x1 - x0), 0.05 * (y1 - y0)
    near = ((v[:, 0] >= x0 - pad_x) & (v[:, 0] <= x1 + pad_x)
            & (v[:, 1] >= y0 - pad_y) & (v[:, 1] <= y1 + pad_y))
    v = v[near]
    v = v[::_decimation_step(len(v), MAX_MESH_VERTICES)]
    if len(v) < 3:
        return None
    n = MESH_RASTER_PX
    nx = max(2, round(n * (x1 - x0) / max(x1 - x0, y1 - y0)))
    ny = max(2, round(n * (y1 - y0) / max(x1 - x0, y1 - y0)))
    x, y = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
    xx, yy = np.meshgrid(x, y)
    try:
        z = griddata(v[:, :2], v[:, 2], (xx, yy), method="linear")
    except (QhullError, ValueError):  # all vertices on a line: no surface to shade
        return None
    return x, y, z


def _draw_terrain(ax, terrain, view, legend) -> None:
    """Grey hillshade (contrast-stretched, light so the layers above stay readable) and faint
    height contours at a round interval."""
    from matplotlib.colors import LinearSegmentedColormap, Normalize
    from matplotlib.lines import Line2D

    raster = _terrain_raster(terrain, view)
    if raster is None:
        return
    x, y, z = raster
    shade = hillshade(z, x, y)
    finite = shade[np.isfinite(shade)]
    if finite.size == 0:
        return
    lo, hi = (float(v) for v in np.percentile(finite, [1.0, 99.0]))
    if hi - lo < 0.1:   # flat or uniformly sloped: no contrast to stretch, a light grey
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 0.75, mid + 0.25
    greys = LinearSegmentedColormap.from_list("hillshade", ["#6e6e6e", "#f7f7f7"]) \
        .with_extremes(bad=(0.0, 0.0, 0.0, 0.0))
    shade = np.ma.masked_invalid(shade)
    dx, dy = np.diff(x), np.diff(y)
    uniform = np.ptp(dx) <= 1e-6 * abs(dx.mean()) and np.ptp(dy) <= 1e-6 * abs(dy.mean())
    kwargs = {"cmap": greys, "norm": Normalize(lo, hi), "zorder": 0, "rasterized": True}
    if uniform:
        # bilinear when the raster is coarser than the screen (no blocky cells when zoomed in)
        ax.imshow(shade, origin="lower", aspect="auto",
                  interpolation="bilinear" if max(shade.shape) < 1000 else "antialiased",
                  extent=(x[0] - dx[0] / 2, x[-1] + dx[0] / 2, y[0] - dy[0] / 2,
                          y[-1] + dy[0] / 2), **kwargs)
    else:
        ax.pcolormesh(x, y, shade, shading="nearest", **kwargs)

    # contours from a smoothed grid
    k = _decimation_step(max(z.shape), MAX_CONTOUR_PX)
    zc = _block_mean(z, k) if k > 1 else z
    if min(zc.shape) < 2:
        return
    xc = x[: (x.size // k) * k].reshape(-1, k).mean(axis=1) if k > 1 else x
    yc = y[: (y.size // k) * k].reshape(-1, k).mean(axis=1) if k > 1 else y
    zf = zc[np.isfinite(zc)]
    if zf.size == 0 or np.ptp(zf) <= 0:
        return
    interval = _nice_step(float(np.ptp(zf)), 10)
    levels = np.arange(math.ceil(zf.min() / interval) * interval, zf.max() + 1e-9, interval)
    if levels.size == 0:
        return
    ax.contour(xc, yc, np.ma.masked_invalid(zc), levels=levels, colors=CONTOUR_COLOR,
               linewidths=0.5, alpha=0.45, zorder=1)
    legend.append((6, Line2D([], [], color=CONTOUR_COLOR, lw=0.8, alpha=0.6,
                         label=f"height contours, every {_format_length(interval)}")))


def _cell_edges(coord: np.ndarray, cell_m: float | None, name: str) -> np.ndarray:
    """Cell edges (n + 1,) of cell-centre coordinates: centre -/+ cell/2 with the grid's
    ``cell_size_m``, else halfway between centres (extended by half a step at the ends)."""
    c = np.asarray(coord, dtype=np.float64)
    if c.ndim != 1 or c.size == 0 or not np.all(np.isfinite(c)):
        raise ValueError(f"grid: coordinate {name!r} must be 1-D, finite and not empty")
    if c.size > 1 and not (np.all(np.diff(c) > 0) or np.all(np.diff(c) < 0)):
        raise ValueError(f"grid: coordinate {name!r} must be strictly monotonic")
    if cell_m is not None:
        sign = 1.0 if c.size == 1 or c[1] > c[0] else -1.0
        return np.concatenate([c - sign * cell_m / 2, [c[-1] + sign * cell_m / 2]])
    if c.size == 1:
        raise ValueError(f"grid: one cell along {name!r} and no cell_size_m attribute: "
                         "cannot tell the cell's size")
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])


def _grid_layer(grid, var: str):
    """(x edges, y edges, masked float values, attrs, stored dtype) of grid variable ``var``."""
    if not hasattr(grid, "data_vars"):
        raise ValueError(f"grid: expected an xarray.Dataset, got {type(grid).__name__}")
    if var is None:
        raise ValueError("var: name the grid variable to colour, one of "
                         f"{', '.join(_grid_variables(grid))}")
    if not isinstance(var, str) or var not in grid.data_vars:
        raise ValueError(f"var: {var!r} is not a variable of grid; choose one of "
                         f"{', '.join(_grid_variables(grid))}")
    da = grid[var]
    if set(da.dims) != {"y", "x"}:
        raise ValueError(f"var: grid variable {var!r} must have dims ('y', 'x'), got {da.dims}")
    for c in ("x", "y"):
        if c not in grid.coords:
            raise ValueError(f"grid: coordinate {c!r} (cell centres, m) is missing")
    cell = grid.attrs.get("cell_size_m")
    if cell is not None:
        cell = float(cell)
        if not (math.isfinite(cell) and cell > 0):
            raise ValueError(f"grid: cell_size_m must be a number > 0, got {cell!r}")
    xe = _cell_edges(grid["x"].values, cell, "x")
    ye = _cell_edges(grid["y"].values, cell, "y")
    raw = da.transpose("y", "x").values
    values = raw.astype(np.float64)
    mask = ~np.isfinite(values)
    if var != "in_region" and "in_region" in grid.data_vars:
        mask |= grid["in_region"].transpose("y", "x").values == 0
    attrs = {"name": var, **da.attrs}
    attrs.setdefault("long_name", var)
    return xe, ye, np.ma.masked_array(values, mask=mask), attrs, raw.dtype


def _grid_variables(grid) -> list[str]:
    return sorted(n for n, v in grid.data_vars.items() if set(v.dims) == {"y", "x"})


def _continuous_style(values: np.ndarray, integer: bool, units=None):
    """(cmap, norm, extend, ticks) for continuous values: 1st-99th percentile range (min-max
    below 100 values or when the percentiles coincide, :func:`~chirplidar.viz.scene3d.colour_range`), a diverging map
    symmetric about 0 when values take both signs (errors), except for decibels (0 dB is no
    special value), whole-number bins for small counts."""
    from matplotlib.colors import BoundaryNorm, Normalize
    from matplotlib.ticker import MaxNLocator

    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return plt.get_cmap("viridis"), Normalize(0.0, 1.0), "neither", None
    if integer and finite.max() - finite.min() <= 12:
        lo, hi = int(finite.min()), int(finite.max())
        bounds = np.arange(lo - 0.5, hi + 1.0, 1.0)
        if bounds.size < 2:
            bounds = np.array([lo - 0.5, lo + 0.5])
        cmap = plt.get_cmap("viridis", bounds.size - 1)
        return cmap, BoundaryNorm(bounds, cmap.N), "neither", np.arange(lo, hi + 1)
    symmetric = str(units or "").strip().lower() != "db"
    lo, hi = colour_range(finite, symmetric)
    diverging = symmetric and lo < 0 < hi and finite.min() < 0 < finite.max()
    cmap = plt.get_cmap("RdBu_r" if diverging else "viridis")
    below, above = bool(finite.min() < lo), bool(finite.max() > hi)
    extend = {(True, True): "both", (True, False): "min", (False, True): "max"}.get(
        (below, above), "neither")
    ticks = MaxNLocator(integer=True) if integer else None
    return cmap, Normalize(lo, hi), extend, ticks


def _flag_colors(name: str, codes: np.ndarray) -> list[str]:
    if name == "detected":
        return [_DETECTED_COLORS.get(int(c), _FLAG_COLORS[i % len(_FLAG_COLORS)])
                for i, c in enumerate(codes)]
    if codes.size == 2 and set(codes.tolist()) == {0, 1}:
        return [FLAG01_COLORS[int(c)] for c in codes]
    return [_FLAG_COLORS[i % len(_FLAG_COLORS)] for i in range(codes.size)]


def _draw_grid(ax, grid, var, legend, colorbars) -> None:
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.patches import Patch

    xe, ye, values, attrs, dtype = _grid_layer(grid, var)
    integer = bool(np.issubdtype(dtype, np.integer) or dtype == bool)
    # one-byte integers and bools are flags (the grid's covered, in_region); counts are int32
    flags = _flag_table(attrs, values.filled(np.nan), integer and dtype.itemsize == 1)
    if flags is not None:
        codes, labels = flags
        colors = _flag_colors(var, codes)
        index = np.full(values.shape, np.nan)
        for i, c in enumerate(codes):
            index[values.filled(np.nan) == c] = i
        cmap = ListedColormap(colors).with_extremes(bad=(0.0, 0.0, 0.0, 0.0))
        ax.pcolormesh(xe, ye, np.ma.masked_array(index, mask=values.mask | np.isnan(index)),
                      cmap=cmap, norm=BoundaryNorm(np.arange(-0.5, codes.size), cmap.N),
                      alpha=GRID_ALPHA, zorder=2, rasterized=True, edgecolors="none")
        for color, label in zip(colors, labels):
            legend.append((0, Patch(facecolor=color, alpha=GRID_ALPHA, edgecolor="none",
                                    label=label)))
        return
    cmap, norm, extend, ticks = _continuous_style(values.compressed(), integer,
                                                  attrs.get("units"))
    cmap = cmap.with_extremes(bad=(0.0, 0.0, 0.0, 0.0))   # NaN / outside the region: clear
    mesh = ax.pcolormesh(xe, ye, values, cmap=cmap, norm=norm, alpha=GRID_ALPHA, zorder=2,
                         rasterized=True, edgecolors="none")
    colorbars.append({"mappable": mesh, "extend": extend, "ticks": ticks, "opaque": True,
                      "long_name": str(attrs["long_name"]), "units": attrs.get("units")})


def _draw_shots(ax, shots, meta, view, legend, colorbars) -> None:
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.lines import Line2D

    sx, sy, sv = shots
    xmin, ymin, xmax, ymax = view
    inside = ((sx >= xmin) & (sx <= xmax) & (sy >= ymin) & (sy <= ymax))
    idx = np.flatnonzero(inside)
    n_in = idx.size
    step = _decimation_step(n_in, MAX_SHOTS_DRAWN)
    idx = idx[::step]
    sx, sy, sv = sx[idx], sy[idx], sv[idx]
    # marker area (points^2): dots for sparse shots, a ~3-px band along dense tracks
    size = 12.0 if idx.size < 5000 else (6.0 if idx.size < 50_000 else 4.0)
    integer = bool(np.all(np.isfinite(sv)) and sv.size and np.all(sv == np.round(sv)))
    flags = _flag_table(meta, sv, False) if "flag_values" in meta else None
    nan = ~np.isfinite(sv)
    if flags is not None:
        codes, labels = flags
        index = np.full(sv.shape, np.nan)
        for i, c in enumerate(codes):
            index[sv == c] = i
        nan = np.isnan(index)
    # counted over all shots in the view, not only the drawn subsample
    n_nan = int(np.count_nonzero(~np.isfinite(shots[2][inside]))) if flags is None \
        else int(np.count_nonzero(~np.isin(shots[2][inside], codes)))
    if nan.any():
        ax.scatter(sx[nan], sy[nan], s=0.7 * size, c=NAN_COLOR, marker="o", linewidths=0,
                   zorder=3, rasterized=True)
        legend.append((1, Line2D([], [], ls="none", marker="o", ms=4, color=NAN_COLOR,
                             label=f"no {meta['name']} value ({n_nan:,} shots)")))
    ok = ~nan
    if flags is not None:
        colors = _flag_colors(str(meta["name"]), codes)
        cmap = ListedColormap(colors)
        # shot order, as for values: putting rare categories on top would make scattered
        # rare shots look pervasive where tracks are dense
        ax.scatter(sx[ok], sy[ok], s=size, c=index[ok], cmap=cmap,
                   norm=BoundaryNorm(np.arange(-0.5, codes.size), cmap.N), marker="o",
                   linewidths=0, zorder=4, rasterized=True)
        for color, label in zip(colors, labels):
            legend.append((0, Line2D([], [], ls="none", marker="o", ms=5, color=color,
                                 label=label)))
    elif ok.any():
        cmap, norm, extend, ticks = _continuous_style(sv[ok], integer, meta.get("units"))
        # shot order (the later pass on top): extremes on top would make noise look larger
        pts = ax.scatter(sx[ok], sy[ok], s=size, c=sv[ok], cmap=cmap, norm=norm, marker="o",
                         linewidths=0, zorder=4, rasterized=True)
        colorbars.append({"mappable": pts, "extend": extend, "ticks": ticks, "opaque": False,
                          "long_name": str(meta["long_name"]), "units": meta.get("units")})
    if step > 1:
        legend.append((2, Line2D([], [], ls="none", marker="o", ms=3, color="#444444",
                             label=f"footprints: 1 in {step} of {n_in:,} drawn")))


def _draw_north_arrow(ax, bearing_deg: float, grid_only: bool) -> None:
    """An arrow 30 points long in the upper-right corner along ``bearing_deg`` (clockwise from
    the +y axis; equal aspect: data and screen angles agree), "N" at its head. Offsets in points
    keep its direction on screen whatever the axes' width and height."""
    import matplotlib.patheffects as pe
    from matplotlib.text import OffsetFrom

    length_pt = 30.0
    ux, uy = math.sin(math.radians(bearing_deg)), math.cos(math.radians(bearing_deg))
    anchor = OffsetFrom(ax, (0.93, 0.86), unit="points")
    halo = [pe.withStroke(linewidth=3.0, foreground=HALO)]
    arrow = ax.annotate("", xy=(ux * length_pt / 2, uy * length_pt / 2), xycoords=anchor,
                        xytext=(-ux * length_pt / 2, -uy * length_pt / 2), textcoords=anchor,
                        arrowprops={"arrowstyle": "-|>,head_length=0.6,head_width=0.3",
                                    "color": "black", "lw": 1.6, "shrinkA": 0, "shrinkB": 0,
                                    "path_effects": halo},
                        zorder=10, annotation_clip=False)
    arrow.set_gid("north_arrow")
    label = "N (grid)" if grid_only else "N"
    text = ax.annotate(label, xy=(ux * (length_pt / 2 + 9), uy * (length_pt / 2 + 9)),
                       xycoords=anchor, ha="center", va="center", fontsize=11,
                       fontweight="bold", zorder=10, annotation_clip=False)
    text.set_path_effects(halo)
    text.set_gid("north_label")


def _draw_scale_bar(ax, view_width_m: float, view_height_m: float) -> None:
    from matplotlib.font_manager import FontProperties
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    length = scale_bar_length_m(view_width_m)
    bar = AnchoredSizeBar(ax.transData, length, _format_length(length), loc="lower left",
                          pad=0.4, borderpad=0.6, sep=3, frameon=True, color="black",
                          size_vertical=0.008 * view_height_m,
                          fontproperties=FontProperties(size=9))
    bar.patch.set_alpha(0.75)
    bar.patch.set_edgecolor("#999999")
    bar.set_gid("scale_bar")
    bar.set_zorder(10)
    ax.add_artist(bar)


def _summary_text(summary) -> str | None:
    """One line per number of ``summary``: fractions as %, *_m as lengths, *_db in dB, counts
    with thousands separators, strings as they are; None, NaN and values that are neither
    numbers nor strings (a producer's nested records, file lists) are skipped."""
    if summary is None:
        return None
    if not isinstance(summary, Mapping):
        raise ValueError(  # noqa: TRY004 - bad input is a ValueError in this package
            f"summary: expected a dict of numbers, got {type(summary).__name__}")
    lines = []
    for key, value in summary.items():
        if value is None:
            continue
        key = str(key)
        if isinstance(value, str):
            lines.append(f"{key.replace('_', ' ')}: {value}")
            continue
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
            continue
        v = float(value)
        if not math.isfinite(v):
            continue
        label = key
        if key.startswith("fraction_") or key.endswith("_fraction"):
            text = f"{100.0 * v:.1f} %"
        elif key.endswith("_m"):
            label, text = key[:-2], _format_length(v)
        elif key.endswith("_db"):
            label, text = key[:-3], f"{v:.1f} dB"
        elif key.endswith("_deg"):
            label, text = key[:-4], f"{_sig(v)} deg"
        elif key.endswith("_s"):
            label, text = key[:-2], f"{_sig(v)} s"
        elif v == round(v) and abs(v) < 1e15:
            text = f"{round(v):,}"
        else:
            text = _sig(v, 4)
        label = label.replace("_", " ")
        if key.endswith("_db"):
            label = label.replace("snr", "SNR")
        lines.append(f"{label}: {text}")
    return "\n".join(lines) if lines else None


def _default_view(terrain, tracks, grid_edges, shots, polygons, crossovers):
    """(xmin, ymin, xmax, ymax) of what is drawn, with a margin; terrain only if nothing else."""
    xs, ys = [], []
    for tx, ty in tracks:
        xs.append(tx)
        ys.append(ty)
    if grid_edges is not None:
        xs.append(grid_edges[0])
        ys.append(grid_edges[1])
    if shots is not None:
        xs.append(shots[0])
        ys.append(shots[1])
    for poly in polygons:
        b = poly.bounds
        xs.append(np.array([b[0], b[2]]))
        ys.append(np.array([b[1], b[3]]))
    if crossovers is not None:
        xs.append(crossovers[0])
        ys.append(crossovers[1])
    x = np.concatenate(xs) if xs else np.empty(0)
    y = np.concatenate(ys) if ys else np.empty(0)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.any():
        xmin, xmax, ymin, ymax = x[ok].min(), x[ok].max(), y[ok].min(), y[ok].max()
    elif terrain is not None:
        b = np.asarray(terrain.bounds, dtype=np.float64)
        xmin, ymin, xmax, ymax = b[0, 0], b[0, 1], b[1, 0], b[1, 1]
    else:
        raise ValueError("nothing to draw: give terrain, tracks, grid, shots, region or "
                         "crossovers (with finite coordinates)")
    size = max(xmax - xmin, ymax - ymin)
    # A single point still needs a view: 100 m around it (display scale only).
    margin = MARGIN_FRACTION * size if size > 0 else 50.0
    return (float(xmin - margin), float(ymin - margin), float(xmax + margin),
            float(ymax + margin))


def _widen_to_aspect(view):
    """The view with its shorter side widened (about its centre) so that height / width lies in
    [MIN_ASPECT, MAX_ASPECT]: a 500 km x 5 km satellite strip would be a sliver otherwise."""
    xmin, ymin, xmax, ymax = view
    w, h = xmax - xmin, ymax - ymin
    if h < MIN_ASPECT * w:
        pad = 0.5 * (MIN_ASPECT * w - h)
        return xmin, ymin - pad, xmax, ymax + pad
    if h > MAX_ASPECT * w:
        pad = 0.5 * (h / MAX_ASPECT - w)
        return xmin - pad, ymin, xmax + pad, ymax
    return view


def _display_units(spec: dict) -> tuple[str, float]:
    """(units, factor) for a colour bar: lengths in m whose colour range stays below 1 m are
    shown in cm (below 0.1 m: mm), the tick values multiplied by the factor."""
    units = "" if spec.get("units") is None else str(spec["units"]).strip()
    if units != "m":
        return units, 1.0
    norm = spec["mappable"].norm
    top = max(abs(float(norm.vmin)), abs(float(norm.vmax)))
    if top < 0.1:
        return "mm", 1000.0
    if top < 1.0:
        return "cm", 100.0
    return units, 1.0


def _wrap_label(label: str, length_in: float) -> str:
    """Colour-bar label wrapped to the bar's length (10-pt text, ~0.085 in per character)."""
    return textwrap.fill(label, max(12, int(length_in / 0.085)))


def _summary_columns(lines: list[str], width_in: float) -> list[list[str]]:
    """The summary's lines in the most columns (up to SUMMARY_MAX_COLUMNS) whose box fits in
    ``width_in``, filled down each column in order; one column when nothing wider fits."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    measure = TextToPath()
    prop = FontProperties(size=SUMMARY_FONT_PT)
    widths = [measure.get_text_width_height_descent(line, prop, ismath=False)[0] / 72.0
              for line in lines]
    for ncols in range(min(SUMMARY_MAX_COLUMNS, len(lines)), 1, -1):
        rows = math.ceil(len(lines) / ncols)
        if math.ceil(len(lines) / rows) < ncols:   # e.g. 5 lines in 4 columns: 3 are used
            continue
        cols = [slice(c * rows, (c + 1) * rows) for c in range(ncols)]
        total = (sum(max(widths[c]) for c in cols) + (ncols - 1) * SUMMARY_COL_GAP_IN
                 + 2 * SUMMARY_PAD_IN)
        if total * 1.05 <= width_in:     # 5 % for the renderer's hinting
            return [lines[c] for c in cols]
    return [lines]


def _summary_height_in(columns: list[list[str]]) -> float:
    return max(len(c) for c in columns) * SUMMARY_ROW_IN + 2 * SUMMARY_PAD_IN


def _layout(view, figsize_in, n_title_lines: int, cbar_label_lines: list[int],
            n_legend_rows: int, summary_h_in: float = 0.0):
    """Sizes in inches: (figure (w, h), axes rect, colour-bar rects), rects (left, bottom, width,
    height) from the figure's lower-left corner. The axes keep the view's aspect (equal scales)
    and fill FIG_WIDTH_IN less the margins, at most MAX_AXES_HEIGHT_IN tall (then the figure is
    narrower); with ``figsize_in`` the axes are the largest that fit, centred. Below the axes:
    the x label, the legend rows, and a summary box ``summary_h_in`` high."""
    xmin, ymin, xmax, ymax = view
    aspect = (ymax - ymin) / (xmax - xmin)
    top = TITLE_LINE_IN * n_title_lines + 0.2
    bottom = 0.62 + (LEGEND_ROW_IN * n_legend_rows + 0.12 if n_legend_rows else 0.0)
    if summary_h_in > 0:
        bottom += summary_h_in + SUMMARY_GAP_IN
    cbars_w = sum(CBAR_GAP_IN + CBAR_WIDTH_IN + CBAR_TICKS_IN + CBAR_LABEL_LINE_IN * n
                  for n in cbar_label_lines)
    right = cbars_w + RIGHT_PAD_IN
    if figsize_in is None:
        axes_w = FIG_WIDTH_IN - LEFT_IN - right
        axes_h = axes_w * aspect
        if axes_h > MAX_AXES_HEIGHT_IN:
            axes_h = MAX_AXES_HEIGHT_IN
            axes_w = axes_h / aspect
        fig_w, fig_h = LEFT_IN + axes_w + right, bottom + axes_h + top
        # whole pixels at 120 dpi: sizes in multiples of 1/120 in
        fig_w, fig_h = math.ceil(fig_w * 120) / 120, math.ceil(fig_h * 120) / 120
        left = LEFT_IN + 0.5 * (fig_w - LEFT_IN - axes_w - right)
    else:
        fig_w, fig_h = figsize_in
        avail_w, avail_h = fig_w - LEFT_IN - right, fig_h - bottom - top
        if avail_w < 1.0 or avail_h < 1.0:
            raise ValueError(f"figsize_in: {fig_w:g} x {fig_h:g} in leaves no room for the map "
                             "next to its title, labels, colour bars, legend and summary")
        axes_w, axes_h = min(avail_w, avail_h / aspect), min(avail_h, avail_w * aspect)
        left = LEFT_IN + 0.5 * (avail_w - axes_w)
    ax_bottom = bottom + 0.5 * (fig_h - bottom - top - axes_h)
    rects, x = [], left + axes_w
    for n in cbar_label_lines:
        rects.append((x + CBAR_GAP_IN, ax_bottom, CBAR_WIDTH_IN, axes_h))
        x += CBAR_GAP_IN + CBAR_WIDTH_IN + CBAR_TICKS_IN + CBAR_LABEL_LINE_IN * n
    return (fig_w, fig_h), (left, ax_bottom, axes_w, axes_h), rects


# ------------------------------------------------------------------------------------ public
def plan_map_figure(*, terrain=None, tracks=None, grid=None, var=None, shots=None,
                    shot_var=None, region=None, crossovers=None, summary=None, title=None,
                    bounds=None, epsg=None, figsize_in=None, region_label="region"):
    """The plan-view map as a matplotlib Figure (arguments as :func:`plot_plan_map`).

    The caller owns the figure (``matplotlib.pyplot.close(fig)`` when done).
    """
    import matplotlib.patheffects as pe
    from matplotlib.lines import Line2D
    from matplotlib.offsetbox import AnchoredOffsetbox, HPacker, TextArea, VPacker
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    terrain = _check_terrain(terrain)
    track_list = _check_tracks(tracks)
    shot_arrays = _check_shots(shots)
    meta = _check_shot_var(shot_var)
    polygons = _check_region(region)
    cross = _check_crossovers(crossovers)
    summary_text = _summary_text(summary)
    if not isinstance(region_label, str) or not region_label.strip():
        raise ValueError(f"region_label: expected a non-empty string, got {region_label!r}")
    if var is not None and grid is None:
        raise ValueError(f"var: {var!r} names a grid variable but no grid was given")
    grid_edges = None
    if grid is not None:
        xe, ye, *_ = _grid_layer(grid, var)     # validates grid and var before drawing
        grid_edges = (np.array([xe.min(), xe.max()]), np.array([ye.min(), ye.max()]))
    if title is not None and not isinstance(title, str):
        raise ValueError(f"title: expected a string or None, got {type(title).__name__}")
    code = _epsg_code(epsg, "epsg") if epsg is not None else _grid_epsg(grid)
    if bounds is not None:
        view = check_bounds_m(bounds, "bounds")
    else:
        view = _default_view(terrain, track_list, grid_edges, shot_arrays, polygons, cross)
    view = _widen_to_aspect(view)
    xmin, ymin, xmax, ymax = view

    if title is None:
        parts = ["Plan view"]
        if grid is not None:
            parts.append(str(grid[var].attrs.get("long_name", var)))
        if shot_arrays is not None:
            parts.append(f"footprints: {meta['long_name']}")
        title = ": ".join(parts[:2]) + ("; " + "; ".join(parts[2:]) if len(parts) > 2 else "")
    title_lines = [textwrap.fill(line, TITLE_WRAP_CHARS) for line in title.splitlines()]
    title = "\n".join(title_lines)
    n_title_lines = title.count("\n") + 1
    if figsize_in is not None:
        try:
            w_in, h_in = (float(v) for v in figsize_in)
        except (TypeError, ValueError):
            raise ValueError(f"figsize_in: expected (width, height) in inches, got "
                             f"{figsize_in!r}") from None
        if not (math.isfinite(w_in) and math.isfinite(h_in) and w_in >= 2 and h_in >= 2):
            raise ValueError(f"figsize_in: width and height must be >= 2 inches, got "
                             f"{figsize_in!r}")
        figsize_in = (w_in, h_in)

    # Layers first (into provisional axes), then the layout, which needs to know the colour
    # bars and legend rows they make.
    fig = plt.figure(figsize=figsize_in or (FIG_WIDTH_IN, 7.0))
    try:
        ax = fig.add_axes((0.1, 0.1, 0.8, 0.8))
        legend: list = []
        colorbars: list = []
        halo = [pe.withStroke(linewidth=2.6, foreground=HALO)]

        if terrain is not None:
            _draw_terrain(ax, terrain, view, legend)
        if grid is not None:
            _draw_grid(ax, grid, var, legend, colorbars)
        if track_list:
            for tx, ty in track_list:
                dx, dy = _decimate_track(tx, ty)
                ax.plot(dx, dy, color=TRACK_COLOR, lw=0.7, alpha=0.85, zorder=2.5,
                        solid_capstyle="round")
            legend.append((3, Line2D([], [], color=TRACK_COLOR, lw=1.0,
                                 label="footprint track" if len(track_list) == 1
                                 else f"footprint tracks ({len(track_list)})")))
        if shot_arrays is not None:
            _draw_shots(ax, shot_arrays, meta, view, legend, colorbars)
        if polygons:
            for poly in polygons:
                for ring in (poly.exterior, *poly.interiors):
                    rx, ry = ring.xy
                    ax.plot(rx, ry, color=REGION_COLOR, lw=1.6, ls=(0, (6, 3)), zorder=6,
                            path_effects=halo)
            legend.append((4, Line2D([], [], color=REGION_COLOR, lw=1.6, ls=(0, (6, 3)),
                                     label=region_label.strip())))
        if cross is not None and cross[0].size:
            ax.scatter(cross[0], cross[1], marker="x", s=30, c=CROSSOVER_COLOR, linewidths=1.2,
                       zorder=7, path_effects=halo)
            legend.append((5, Line2D([], [], ls="none", marker="x", ms=6, mew=1.2,
                                     color=CROSSOVER_COLOR,
                                     label=f"crossovers ({cross[0].size:,})")))

        # legend order: what the colours mean, then the lines and marks, contours last
        legend = [handle for _, handle in sorted(legend, key=lambda item: item[0])]

        # layout: axes at the view's aspect, colour bars of the axes' height on the right
        n_rows = math.ceil(len(legend) / LEGEND_COLUMNS)
        # the summary box goes below the map and its legend, where it hides nothing: its
        # lines in as many columns as the figure's width holds
        summary_cols = (_summary_columns(summary_text.splitlines(),
                                         (figsize_in or (FIG_WIDTH_IN,))[0] - 0.3)
                        if summary_text else [])
        summary_h = _summary_height_in(summary_cols) if summary_cols else 0.0
        probe = _layout(view, figsize_in, n_title_lines, [1] * len(colorbars), n_rows,
                        summary_h)
        if summary_cols and figsize_in is None and probe[0][0] < FIG_WIDTH_IN:
            # a tall view: the figure is narrower than FIG_WIDTH_IN; columns that fit it
            summary_cols = _summary_columns(summary_text.splitlines(), probe[0][0] - 0.3)
            summary_h = _summary_height_in(summary_cols)
        scales = [_display_units(c) for c in colorbars]
        labels = [_wrap_label(units_label(c["long_name"], units), probe[1][3])
                  for c, (units, _) in zip(colorbars, scales)]
        (fig_w, fig_h), ax_rect, cbar_rects = _layout(
            view, figsize_in, n_title_lines, [lab.count("\n") + 1 for lab in labels], n_rows,
            summary_h)
        fig.set_size_inches(fig_w, fig_h)

        def frac(rect):
            left, bottom, width, height = rect
            return (left / fig_w, bottom / fig_h, width / fig_w, height / fig_h)

        ax.set_position(frac(ax_rect))
        for spec, label, rect, (_, factor) in zip(colorbars, labels, cbar_rects, scales):
            cbar = fig.colorbar(spec["mappable"], cax=fig.add_axes(frac(rect)),
                                extend=spec["extend"], ticks=spec["ticks"])
            if factor != 1.0:   # small lengths in cm / mm: tick labels scaled, data unchanged
                cbar.formatter = FuncFormatter(lambda v, _pos, f=factor: _sig(v * f, 4))
            if spec["opaque"]:
                cbar.solids.set_alpha(1.0)   # the cells are drawn semi-transparent, not the scale
            cbar.set_label(label, fontsize=10)
            cbar.ax.tick_params(labelsize=9)

        # axes: km of the projection, exactly the view, equal scales (the layout keeps the aspect)
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal", adjustable="box")
        crs_text = f", EPSG:{code}" if code is not None else ""
        ax.set_xlabel(f"x (km{crs_text})", fontsize=10)
        ax.set_ylabel(f"y (km{crs_text})", fontsize=10)
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(FuncFormatter(_km_tick))
            axis.set_major_locator(MaxNLocator(nbins=7, steps=[1, 2, 2.5, 5, 10]))
        ax.tick_params(labelsize=9)
        ax.set_title(title, fontsize=11)
        ax.set_facecolor("white")

        _draw_scale_bar(ax, xmax - xmin, ymax - ymin)
        cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
        bearing = true_north_bearing_deg(cx, cy, code) if code is not None else math.nan
        _draw_north_arrow(ax, 0.0 if math.isnan(bearing) else bearing, math.isnan(bearing))
        ax_centre = (ax_rect[0] + 0.5 * ax_rect[2]) / fig_w
        legend_y_in = 0.06
        if summary_cols:
            # centred under the map, at the bottom of the figure (below the legend)
            text = {"fontsize": SUMMARY_FONT_PT, "parse_math": False}
            sep_pt = SUMMARY_ROW_IN * 72.0 - 1.2 * SUMMARY_FONT_PT
            columns = [VPacker(children=[TextArea(line, textprops=text) for line in col],
                               align="left", pad=0, sep=max(sep_pt, 0.0)) for col in summary_cols]
            packed = HPacker(children=columns, align="top", pad=0,
                             sep=SUMMARY_COL_GAP_IN * 72.0)
            box = AnchoredOffsetbox(loc="lower center", child=packed,
                                    pad=SUMMARY_PAD_IN * 72.0 / SUMMARY_FONT_PT, borderpad=0.0,
                                    prop={"size": SUMMARY_FONT_PT}, frameon=True,
                                    bbox_to_anchor=(ax_centre, 0.06 / fig_h),
                                    bbox_transform=fig.transFigure)
            box.patch.set_boxstyle("round,pad=0,rounding_size=0.4")
            box.patch.set_alpha(0.9)
            box.patch.set_edgecolor("#999999")
            box.set_gid("summary")
            fig.add_artist(box)
            legend_y_in += summary_h + SUMMARY_GAP_IN
        if legend:
            ncols = min(LEGEND_COLUMNS, len(legend))
            # matplotlib fills legend columns first: reorder so that it reads row by row
            legend = [h for c in range(ncols) for h in legend[c::ncols]]
            fig.legend(handles=legend, loc="lower center", ncols=ncols,
                       bbox_to_anchor=(ax_centre, legend_y_in / fig_h),
                       fontsize=8.5, frameon=False, borderaxespad=0.0, handlelength=2.2,
                       columnspacing=1.6)
    except BaseException:   # a half-drawn figure must not stay registered in pyplot
        plt.close(fig)
        raise
    return fig


def plot_plan_map(png, *, terrain=None, tracks=None, grid=None, var=None, shots=None,
                  shot_var=None, region=None, crossovers=None, summary=None, title=None,
                  bounds=None, epsg=None, figsize_in=None, region_label="region") -> Path:
    """Write a plan-view map of a survey to ``png`` and return its path.

    Parameters (all coordinates in projected metres of one CRS; every layer is optional, at least
    one must be given)
    ----------
    png : str or os.PathLike
        Output ``.png`` path (parent folders are created); written at 120 dpi.
    terrain : chirplidar.geometry.terrain.Terrain or None
        Drawn as a grey hillshade lit from grid north-west (azimuth 315 deg, 45 deg above the
        horizon, :func:`hillshade`), contrast-stretched (1st-99th percentile) and light, with faint
        height contours at a round interval (from a grid smoothed to <= 300 px). Heightfields
        (``terrain.grid``) are cropped to the view and decimated to <= 1500 nodes on a side; mesh
        terrains (``terrain.grid is None``) have their vertex heights linearly interpolated on a
        400-px raster (scipy ``griddata``, <= 200,000 vertices), adequate for plan views of
        single-valued surfaces.
    tracks : list of (x, y) 1-D arrays or None
        Footprint-centre tracks (m), thin dark lines; NaN breaks a line. Decimated to about 4000
        vertices per track for drawing (the vertices around NaN are kept).
    grid, var : xarray.Dataset, str
        Coverage grid (dims ``("y", "x")``, cell-centre coordinates ``x``, ``y`` in m; cell size
        from the ``cell_size_m`` attribute, else the coordinate spacing) and the variable to
        colour, e.g. ``"detected_shots"``, ``"covered"``, ``"gap"``,
        ``"height_precision_measured"``, ``"median_snr_db"``. Cells with ``in_region == 0`` and
        NaN cells are transparent. Continuous variables get a colour bar labelled
        ``long_name (units)`` (no brackets for dimensionless "1"), 1st-99th percentile range
        (the min-max when those coincide, as for a count grid of mostly empty cells; +-5 %
        around the value of an all-equal field, 0..1 for zeros; diverging, symmetric about 0,
        only when values take both signs: never for counts or other non-negative values),
        whole-number bins for integer counts spanning <= 12 values. Categorical variables (CF
        ``flag_values`` / ``flag_meanings``, or a 0/1 one-byte integer such as ``covered``) get
        legend entries instead of a colour bar.
    shots, shot_var : (x, y, values) 1-D arrays; str or mapping
        Footprints coloured by value (at most 200,000 drawn: every k-th beyond, said in the
        legend; only those inside the view). ``shot_var``: the values' name, or a mapping of CF
        attributes ``name``, ``long_name``, ``units`` (the colour-bar label) and optionally
        ``flag_values`` / ``flag_meanings`` (then categorical colours). NaN values are small
        grey dots (counted in the legend).
    region : shapely Polygon or MultiPolygon
        Survey region, a dashed magenta outline.
    region_label : str
        The region's legend entry (default "region"), e.g. "survey polygon", "scene extent",
        "--bounds box", "GeoJSON polygon": what the outline is.
    crossovers : xarray.Dataset
        Variables ``x``, ``y`` (m) along dim ``crossover``: small black crosses.
    summary : dict
        Numbers shown in a box below the map and its legend (where it hides nothing; in as many
        columns, up to 4, read down each, as the figure's width holds), one line each in the
        dict's order: keys
        ``fraction_*`` / ``*_fraction`` as %, ``*_m`` as lengths (km / m / cm / mm), ``*_db`` in
        dB, ``*_s`` in s, whole numbers with thousands separators, strings as they are; None,
        NaN and other values (dicts, lists) are skipped. Pass the few numbers worth a glance.
    title : str or None
        Heading (lines wrapped at 80 characters); None: from ``var`` and ``shot_var``.
    bounds : (xmin, ymin, xmax, ymax) or None
        View in metres; None: what is drawn (tracks, grid, shots, region, crossovers; else the
        terrain) plus a 4 % margin. Shown exactly at equal scales, except that a view more
        elongated than 4:1 (wide) or 1:2.5 (tall) is widened across to that ratio.
    epsg : int, str or None
        CRS of the coordinates, e.g. 3413 or "EPSG:3031"; None: the grid's ``epsg_code``
        attribute or ``crs`` variable. Used for the axis labels and the north arrow (true north
        at the view's centre, :func:`true_north_bearing_deg`); without a CRS the arrow shows grid
        north, labelled "N (grid)".
    figsize_in : (float, float) or None
        Figure size in inches (the map the largest that fits, centred); None: 10 in wide (less
        for tall views, whose map is at most 9 in high) and as high as the view's aspect needs.

    Axes are in km of the projection (tick labels = metres / 1000), equal aspect, with a scale
    bar of a round length (:func:`scale_bar_length_m`) in the lower-left corner and the north
    arrow in the upper-right one. Legend entries (tracks, region, crossovers, categories, no-value
    shots, contours) go below the map, the summary box below them. Bad input raises ValueError
    naming the argument.
    """
    path = _checks.png_path("png", png)
    fig = plan_map_figure(terrain=terrain, tracks=tracks, grid=grid, var=var, shots=shots,
                          shot_var=shot_var, region=region, crossovers=crossovers,
                          summary=summary, title=title, bounds=bounds, epsg=epsg,
                          figsize_in=figsize_in, region_label=region_label)
    return save(fig, path)
