"""The layers of the plan view (:mod:`chirplidar.viz.planmap`) above the base map: coverage-grid
cells, footprints coloured by a value, footprint tracks, the survey region and crossovers, with
the checks of their inputs and their legend entries and colour bars."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ._mpl import plt
from .conventions import DETECTED_COLORS, FLAG_COLORS, colour_range
from .plan_basemap import HALO, decimation_step

MAX_TRACK_VERTICES = 4000      # drawn vertices per track (NaN breaks kept)
MAX_SHOTS_DRAWN = 200_000      # footprints drawn (every k-th beyond)
GRID_ALPHA = 0.75              # coverage cells over the hillshade
TRACK_COLOR = "#1a1a1a"
REGION_COLOR = "#c51b7d"       # dark magenta: not in viridis, RdBu or the grey hillshade
CROSSOVER_COLOR = "#000000"
NAN_COLOR = "#8c8c8c"
FLAG01_COLORS = ("#d95f02", "#1b9e77")   # 0 (e.g. not covered): orange, 1: green


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
    step = decimation_step(n, MAX_TRACK_VERTICES)
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


def check_terrain(terrain):
    """``terrain`` (a Terrain: grid, bounds and face materials) or None; ValueError otherwise."""
    if terrain is None:
        return None
    if not (hasattr(terrain, "grid") and hasattr(terrain, "bounds")
            and hasattr(terrain, "face_materials")):
        raise ValueError("terrain: expected a chirplidar.geometry.terrain.Terrain, got "
                         f"{type(terrain).__name__}")
    return terrain


def check_tracks(tracks) -> list[tuple[np.ndarray, np.ndarray]]:
    """The tracks as a list of (x, y) float arrays of equal length (m); ValueError naming the
    bad one."""
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


def check_shots(shots):
    """(x, y, values) as three float arrays of equal length, or None; ValueError otherwise."""
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


def check_shot_var(shot_var) -> dict:
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


def check_region(region):
    """The region's polygons (a shapely Polygon or MultiPolygon, projected metres); [] for None."""
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


def check_crossovers(crossovers):
    """(x, y) of the crossovers with finite coordinates (a Dataset with x and y), or None."""
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


def grid_layer(grid, var: str):
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
    below 100 values or when the percentiles coincide,
    :func:`~chirplidar.viz.conventions.colour_range`), a diverging map symmetric about 0 when
    values take both signs (errors), except for decibels (0 dB is no special value),
    whole-number bins for small counts."""
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
        return [DETECTED_COLORS.get(int(c), FLAG_COLORS[i % len(FLAG_COLORS)])
                for i, c in enumerate(codes)]
    if codes.size == 2 and set(codes.tolist()) == {0, 1}:
        return [FLAG01_COLORS[int(c)] for c in codes]
    return [FLAG_COLORS[i % len(FLAG_COLORS)] for i in range(codes.size)]


def draw_grid(ax, grid, var, legend, colorbars) -> None:
    """Coverage-grid cells coloured by ``var``: categories with legend entries, or a colour
    bar spec appended to ``colorbars``; cells outside the region or NaN are clear."""
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.patches import Patch

    xe, ye, values, attrs, dtype = grid_layer(grid, var)
    integer = bool(np.issubdtype(dtype, np.integer) or dtype == np.bool_)
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


def draw_shots(ax, shots, meta, view, legend, colorbars) -> None:
    """Footprints inside the view coloured by value (every k-th beyond MAX_SHOTS_DRAWN),
    categories or a colour bar; shots without a value as small grey dots."""
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.lines import Line2D

    sx, sy, sv = shots
    xmin, ymin, xmax, ymax = view
    inside = ((sx >= xmin) & (sx <= xmax) & (sy >= ymin) & (sy <= ymax))
    idx = np.flatnonzero(inside)
    n_in = idx.size
    step = decimation_step(n_in, MAX_SHOTS_DRAWN)
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


def draw_tracks(ax, tracks, legend) -> None:
    """Footprint-centre tracks (m), thin dark lines, decimated for drawing."""
    from matplotlib.lines import Line2D

    for tx, ty in tracks:
        dx, dy = _decimate_track(tx, ty)
        ax.plot(dx, dy, color=TRACK_COLOR, lw=0.7, alpha=0.85, zorder=2.5,
                solid_capstyle="round")
    legend.append((3, Line2D([], [], color=TRACK_COLOR, lw=1.0,
                         label="footprint track" if len(tracks) == 1
                         else f"footprint tracks ({len(tracks)})")))


def draw_region(ax, polygons, region_label: str, legend) -> None:
    """The survey region, a dashed magenta outline with a white halo."""
    import matplotlib.patheffects as pe
    from matplotlib.lines import Line2D

    halo = [pe.withStroke(linewidth=2.6, foreground=HALO)]
    for poly in polygons:
        for ring in (poly.exterior, *poly.interiors):
            rx, ry = ring.xy
            ax.plot(rx, ry, color=REGION_COLOR, lw=1.6, ls=(0, (6, 3)), zorder=6,
                    path_effects=halo)
    legend.append((4, Line2D([], [], color=REGION_COLOR, lw=1.6, ls=(0, (6, 3)),
                             label=region_label.strip())))


def draw_crossovers(ax, cross, legend) -> None:
    """Crossovers (x, y arrays, m): small black crosses with a white halo."""
    import matplotlib.patheffects as pe
    from matplotlib.lines import Line2D

    halo = [pe.withStroke(linewidth=2.6, foreground=HALO)]
    ax.scatter(cross[0], cross[1], marker="x", s=30, c=CROSSOVER_COLOR, linewidths=1.2,
               zorder=7, path_effects=halo)
    legend.append((5, Line2D([], [], ls="none", marker="x", ms=6, mew=1.2,
                             color=CROSSOVER_COLOR,
                             label=f"crossovers ({cross[0].size:,})")))
