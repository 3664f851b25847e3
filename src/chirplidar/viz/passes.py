"""Map of satellite passes over a region (``chirplidar passes --png``).

Drawn in the region's projected frame (:class:`chirplidar.analysis.passes.Region`: the scene's
EPSG, or the azimuthal equidistant frame centred on a GeoJSON polygon), axes in km, equal aspect:
the region outline, its centre, and per pass the nadir track through the region (thick, an arrow
in the direction of flight, the pass number at its entry) and each beam's ground track (thin),
one colour per pass, the legend giving the pass's entry time (UTC) and direction.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from ._mpl import plt, save

__all__ = ["plot_passes"]

REGION_COLOR = "#c51b7d"       # dark magenta, as the plan maps' region outline
MARGIN_FRACTION = 0.08         # view: the region plus 8 % of its size on each side
# Layout in inches: y labels, the map, the legend at its right; x label below, title above
LEFT_IN, AXES_WIDTH_IN, LEGEND_WIDTH_IN, BOTTOM_IN, TOP_IN = 0.9, 7.0, 3.9, 0.7, 0.8


def _xy_km(region, lonlat) -> np.ndarray:
    a = np.asarray(lonlat, float).reshape(-1, 2)
    if not len(a):
        return np.zeros((0, 2))
    return np.column_stack(region.to_xy(a[:, 0], a[:, 1])) / 1e3


def _axis_labels(region) -> tuple[str, str]:
    if region.crs.upper().startswith("EPSG:"):
        return (f"x (km, {region.crs.upper()})", f"y (km, {region.crs.upper()})")
    lon, lat = region.centre_lonlat
    frame = f"azimuthal equidistant about {lat:.3f}, {lon:.3f}"
    return f"east (km, {frame})", f"north (km, {frame})"


def plot_passes(passes, region, path, *, window=None, satellite=None) -> Path:
    """Write the map of ``passes`` (list of :class:`~chirplidar.analysis.passes.Pass`) over
    ``region`` to the PNG ``path`` and return the path. ``window``: (start, end) ISO UTC strings
    for the title; ``satellite``: its name."""
    x0, y0, x1, y1 = (v / 1e3 for v in region.shape_xy.bounds)
    m = MARGIN_FRACTION * max(x1 - x0, y1 - y0)
    # Size the figure to the region's aspect: a map 7 in wide (3-8 in high) and the legend.
    aspect = min(max((y1 - y0 + 2 * m) / (x1 - x0 + 2 * m), 3.0 / 7.0), 8.0 / 7.0)
    w_in = LEFT_IN + AXES_WIDTH_IN + LEGEND_WIDTH_IN
    h_in = BOTTOM_IN + AXES_WIDTH_IN * aspect + TOP_IN
    fig, ax = plt.subplots(figsize=(w_in, h_in))
    fig.subplots_adjust(left=LEFT_IN / w_in, right=(LEFT_IN + AXES_WIDTH_IN) / w_in,
                        bottom=BOTTOM_IN / h_in, top=1.0 - TOP_IN / h_in)
    geoms = getattr(region.shape_xy, "geoms", [region.shape_xy])
    for i, g in enumerate(geoms):
        for j, ring in enumerate((g.exterior, *g.interiors)):
            x, y = np.asarray(ring.coords).T / 1e3
            ax.plot(x, y, color=REGION_COLOR, lw=1.8, label="region" if i == j == 0 else None)
    cx, cy = (v / 1e3 for v in region.to_xy(*region.centre_lonlat))
    ax.plot(cx, cy, "+", color=REGION_COLOR, ms=12, mew=1.8, label="region centre")
    for i, p in enumerate(passes):
        colour = f"C{i % 10}"
        for b in p.beams:
            xy = _xy_km(region, b["track_lonlat"])
            if len(xy) > 1:
                ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=0.7, alpha=0.8)
        xy = _xy_km(region, p.nadir_track_lonlat)
        when = p.start_utc[:19].replace("T", " ")
        ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=2.2,
                label=f"{i + 1}: {when} UTC, {p.direction}, {p.duration_s:.1f} s")
        if len(xy) > 1:
            ax.annotate("", xy=xy[-1], xytext=xy[-2],
                        arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 2.0})
            ax.annotate(str(i + 1), xy=xy[0], xytext=(-4, -4), textcoords="offset points",
                        ha="right", va="top", fontsize=9, color=colour, fontweight="bold")
    ax.set_xlim(x0 - m, x1 + m)
    ax.set_ylim(y0 - m, y1 + m)
    ax.set_aspect("equal")
    xl, yl = _axis_labels(region)
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.grid(True, lw=0.4, alpha=0.5)
    sat = f"{satellite} " if satellite else ""
    span = ", {} to {}".format(*(w.replace(".000Z", "Z") for w in window)) if window else ""
    ax.set_title("\n".join(textwrap.wrap(
        f"Passes of {sat}over {region.name}{span}: {len(passes)} pass"
        f"{'' if len(passes) == 1 else 'es'} (thick: nadir track, "
        f"{'thin: beam tracks, ' if any(p.beams for p in passes) else ''}arrow: direction of "
        "flight)", 90)), fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False,
              ncol=1 if len(passes) <= 30 else 2)
    return save(fig, path)
