"""The base map of the plan view (:mod:`chirplidar.viz.planmap`): the hillshaded terrain with
height contours, the axes in km of the projection, a scale bar of a round length and a north
arrow along *true* north, and the number formats the map's texts share.

In polar stereographic projections grid north (+y) is true north only on the central meridian:
in EPSG:3413 at 50 W true north points 5 deg clockwise of grid north, in EPSG:3031 at 100 E it
points 100 deg clockwise of it (:func:`true_north_bearing_deg`).
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np

__all__ = ["hillshade", "scale_bar_length_m", "true_north_bearing_deg"]

# Illumination of the hillshade: the cartographic convention, light from the upper left of the
# map (grid north-west), 45 deg above the horizon.
SUN_AZIMUTH_DEG = 315.0
SUN_ELEVATION_DEG = 45.0
MAX_SHADE_PX = 1500            # hillshade raster, pixels on a side (grids are decimated to it)
MAX_CONTOUR_PX = 300           # contours from a block-averaged grid: smooth, not every crevasse
MESH_RASTER_PX = 400           # mesh terrains (no grid): heights interpolated on this raster
MAX_MESH_VERTICES = 200_000    # mesh vertices fed to the interpolation (every k-th beyond)
NORTH_STEP_DEG = 0.01          # step along the meridian to find true north
CONTOUR_COLOR = "#5b4a3a"
HALO = "white"


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
    code = epsg_code(epsg, "epsg")
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


def significant(value: float, digits: int = 3) -> str:
    """``value`` with ``digits`` significant digits, positional (no exponent), trailing zeros
    dropped: 999.6 -> "1000", 0.04619 -> "0.0462"."""
    return np.format_float_positional(float(value), precision=digits, unique=False,
                                      fractional=False, trim="-")


def format_length(length_m: float) -> str:
    """A length with a unit that keeps it readable: 12 km, 350 m, 4.62 cm, 0.8 mm."""
    a = abs(length_m)
    if a >= 1000.0:
        return f"{significant(length_m / 1000.0)} km"
    if a >= 1.0 or a == 0.0:
        return f"{significant(length_m)} m"
    if a >= 0.01:
        return f"{significant(length_m * 100.0)} cm"
    return f"{significant(length_m * 1000.0)} mm"


def km_tick(value_m: float, _pos=None) -> str:
    """Tick label of a coordinate in m: km, trailing zeros dropped."""
    return np.format_float_positional(round(value_m / 1000.0, 6), trim="-")


def epsg_code(epsg, name: str) -> int | None:
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


def grid_epsg(grid) -> int | None:
    """EPSG code of a coverage grid: its ``epsg_code`` attribute, else its ``crs`` variable."""
    if grid is None:
        return None
    if grid.attrs.get("epsg_code"):
        return epsg_code(str(grid.attrs["epsg_code"]), "grid.attrs['epsg_code']")
    if "crs" in grid.variables and grid["crs"].attrs:
        from pyproj import CRS
        from pyproj.exceptions import CRSError

        try:
            code = CRS.from_cf(dict(grid["crs"].attrs)).to_epsg()
        except CRSError:
            return None
        return None if code is None else int(code)
    return None


def decimation_step(n: int, n_max: int) -> int:
    """Step k of every k-th of ``n`` items that keeps at most about ``n_max``."""
    return max(1, math.ceil(n / n_max))


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
        step = decimation_step(max(i1 - i0, j1 - j0), MAX_SHADE_PX)
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
    v = v[::decimation_step(len(v), MAX_MESH_VERTICES)]
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


def draw_terrain(ax, terrain, view, legend) -> None:
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
    k = decimation_step(max(z.shape), MAX_CONTOUR_PX)
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
                         label=f"height contours, every {format_length(interval)}")))


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
    bar = AnchoredSizeBar(ax.transData, length, format_length(length), loc="lower left",
                          pad=0.4, borderpad=0.6, sep=3, frameon=True, color="black",
                          size_vertical=0.008 * view_height_m,
                          fontproperties=FontProperties(size=9))
    bar.patch.set_alpha(0.75)
    bar.patch.set_edgecolor("#999999")
    bar.set_gid("scale_bar")
    bar.set_zorder(10)
    ax.add_artist(bar)


def format_map_axes(ax, view, code: int | None, title: str) -> None:
    """Axes in km of the projection (EPSG ``code``, None when unknown), exactly the ``view``,
    equal scales, the ``title``, a scale bar and the north arrow (true north at the view's
    centre; grid north, labelled "N (grid)", without a CRS)."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    xmin, ymin, xmax, ymax = view
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal", adjustable="box")
    crs_text = f", EPSG:{code}" if code is not None else ""
    ax.set_xlabel(f"x (km{crs_text})", fontsize=10)
    ax.set_ylabel(f"y (km{crs_text})", fontsize=10)
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(FuncFormatter(km_tick))
        axis.set_major_locator(MaxNLocator(nbins=7, steps=[1, 2, 2.5, 5, 10]))
    ax.tick_params(labelsize=9)
    ax.set_title(title, fontsize=11)
    ax.set_facecolor("white")

    _draw_scale_bar(ax, xmax - xmin, ymax - ymin)
    cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
    bearing = true_north_bearing_deg(cx, cy, code) if code is not None else math.nan
    _draw_north_arrow(ax, 0.0 if math.isnan(bearing) else bearing, math.isnan(bearing))
