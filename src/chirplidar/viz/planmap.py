"""Plan-view (2-D) map of a survey in projected metres: hillshaded terrain, footprint tracks,
coverage-grid cells or coloured footprints, the survey region and crossovers.

The map is drawn in the projection of the run (EPSG:3413 Greenland, EPSG:3031 Antarctica):
axes in km of projected x and y, equal aspect, a scale bar of a round length, and a north arrow
along *true* north. In polar stereographic projections grid north (+y) is true north only on the
central meridian: in EPSG:3413 at 50 W true north points 5 deg clockwise of grid north, in
EPSG:3031 at 100 E it points 100 deg clockwise of it
(:func:`~chirplidar.viz.plan_basemap.true_north_bearing_deg`).

matplotlib is imported through :mod:`chirplidar.viz._mpl` (Agg backend unless pyplot is already in
use). Physics code never imports this module; the CLI imports it lazily (``chirplidar view
--plan``).

Public: :func:`plot_plan_map` (write a PNG), :func:`plan_map_figure` (the figure, e.g. for a
notebook). The map is built in three modules: :mod:`~chirplidar.viz.plan_basemap` (hillshade,
contours, axes, scale bar, north arrow; :func:`~chirplidar.viz.plan_basemap.hillshade`,
:func:`~chirplidar.viz.plan_basemap.true_north_bearing_deg`,
:func:`~chirplidar.viz.plan_basemap.scale_bar_length_m`), :mod:`~chirplidar.viz.plan_layers`
(grid cells, footprints, tracks, region, crossovers) and :mod:`~chirplidar.viz.plan_layout`
(view, figure size, colour bars, legend and summary box); this module puts them together.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .. import _checks
from ._mpl import plt, save
from .conventions import check_bounds_m
from .plan_basemap import (draw_terrain, epsg_code, format_length, format_map_axes, grid_epsg,
                           significant)
from .plan_layers import (check_crossovers, check_region, check_shot_var, check_shots,
                          check_terrain, check_tracks, draw_crossovers, draw_grid, draw_region,
                          draw_shots, draw_tracks, grid_layer)
from .plan_layout import (FIG_WIDTH_IN, TITLE_WRAP_CHARS, add_summary_and_legend, arrange_map,
                          default_view, widen_to_aspect)

__all__ = ["plan_map_figure", "plot_plan_map"]


def plan_map_figure(*, terrain=None, tracks=None, grid=None, var=None, shots=None,
                    shot_var=None, region=None, crossovers=None, summary=None, title=None,
                    bounds=None, epsg=None, figsize_in=None, region_label="region"):
    """The plan-view map as a matplotlib Figure (arguments as :func:`plot_plan_map`).

    The caller owns the figure (``matplotlib.pyplot.close(fig)`` when done).
    """
    terrain = check_terrain(terrain)
    track_list = check_tracks(tracks)
    shot_arrays = check_shots(shots)
    meta = check_shot_var(shot_var)
    polygons = check_region(region)
    cross = check_crossovers(crossovers)
    summary_text = _summary_text(summary)
    if not isinstance(region_label, str) or not region_label.strip():
        raise ValueError(f"region_label: expected a non-empty string, got {region_label!r}")
    if var is not None and grid is None:
        raise ValueError(f"var: {var!r} names a grid variable but no grid was given")
    grid_edges = None
    if grid is not None:
        xe, ye, *_ = grid_layer(grid, var)     # validates grid and var before drawing
        grid_edges = (np.array([xe.min(), xe.max()]), np.array([ye.min(), ye.max()]))
    if title is not None and not isinstance(title, str):
        raise ValueError(f"title: expected a string or None, got {type(title).__name__}")
    code = epsg_code(epsg, "epsg") if epsg is not None else grid_epsg(grid)
    if bounds is not None:
        view = check_bounds_m(bounds, "bounds")
    else:
        view = default_view(terrain, track_list, grid_edges, shot_arrays, polygons, cross)
    view = widen_to_aspect(view)
    title = _map_title(title, grid, var, shot_arrays, meta)
    figsize_in = _checked_figsize(figsize_in)

    # Layers first (into provisional axes), then the layout, which needs to know the colour
    # bars and legend rows they make.
    fig = plt.figure(figsize=figsize_in or (FIG_WIDTH_IN, 7.0))
    try:
        ax = fig.add_axes((0.1, 0.1, 0.8, 0.8))
        legend: list = []
        colorbars: list = []
        if terrain is not None:
            draw_terrain(ax, terrain, view, legend)
        if grid is not None:
            draw_grid(ax, grid, var, legend, colorbars)
        if track_list:
            draw_tracks(ax, track_list, legend)
        if shot_arrays is not None:
            draw_shots(ax, shot_arrays, meta, view, legend, colorbars)
        if polygons:
            draw_region(ax, polygons, region_label, legend)
        if cross is not None and cross[0].size:
            draw_crossovers(ax, cross, legend)
        # legend order: what the colours mean, then the lines and marks, contours last
        legend = [handle for _, handle in sorted(legend, key=lambda item: item[0])]
        ax_centre, fig_h, summary_cols, summary_h = arrange_map(
            fig, ax, view, figsize_in, title.count("\n") + 1, legend, colorbars, summary_text)
        # axes: km of the projection, exactly the view, equal scales (the layout keeps the aspect)
        format_map_axes(ax, view, code, title)
        add_summary_and_legend(fig, ax_centre, fig_h, summary_cols, summary_h, legend)
    except BaseException:   # a half-drawn figure must not stay registered in pyplot
        plt.close(fig)
        raise
    return fig


def _map_title(title, grid, var, shot_arrays, meta) -> str:
    """The heading (None: from ``var`` and the footprints' variable), lines wrapped."""
    if title is None:
        parts = ["Plan view"]
        if grid is not None:
            parts.append(str(grid[var].attrs.get("long_name", var)))
        if shot_arrays is not None:
            parts.append(f"footprints: {meta['long_name']}")
        title = ": ".join(parts[:2]) + ("; " + "; ".join(parts[2:]) if len(parts) > 2 else "")
    title_lines = [textwrap.fill(line, TITLE_WRAP_CHARS) for line in title.splitlines()]
    title = "\n".join(title_lines)
    return title


def _checked_figsize(figsize_in) -> tuple[float, float] | None:
    """(width, height) in inches, each >= 2, or None; ValueError otherwise."""
    if figsize_in is None:
        return None
    try:
        w_in, h_in = (float(v) for v in figsize_in)
    except (TypeError, ValueError):
        raise ValueError(f"figsize_in: expected (width, height) in inches, got "
                         f"{figsize_in!r}") from None
    if not (math.isfinite(w_in) and math.isfinite(h_in) and w_in >= 2 and h_in >= 2):
        raise ValueError(f"figsize_in: width and height must be >= 2 inches, got "
                         f"{figsize_in!r}")
    return w_in, h_in


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
            label, text = key[:-2], format_length(v)
        elif key.endswith("_db"):
            label, text = key[:-3], f"{v:.1f} dB"
        elif key.endswith("_deg"):
            label, text = key[:-4], f"{significant(v)} deg"
        elif key.endswith("_s"):
            label, text = key[:-2], f"{significant(v)} s"
        elif v == round(v) and abs(v) < 1e15:
            text = f"{round(v):,}"
        else:
            text = significant(v, 4)
        label = label.replace("_", " ")
        if key.endswith("_db"):
            label = label.replace("snr", "SNR")
        lines.append(f"{label}: {text}")
    return "\n".join(lines) if lines else None


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
