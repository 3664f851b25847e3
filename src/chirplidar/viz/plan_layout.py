"""The layout of the plan view (:mod:`chirplidar.viz.planmap`): the view (what is drawn plus a
margin, widened to a readable aspect), the figure's size with the map at the view's aspect, the
colour bars on its right, the legend below it and the summary box at the bottom (never over the
data), all in inches at 120 dpi."""

from __future__ import annotations

import math
import textwrap

import numpy as np

from .conventions import units_label
from .plan_basemap import significant

MARGIN_FRACTION = 0.04         # default view: what is drawn plus 4 % of its size on each side
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


def default_view(terrain, tracks, grid_edges, shots, polygons, crossovers):
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


def widen_to_aspect(view):
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


def arrange_map(fig, ax, view, figsize_in, n_title_lines: int, legend: list, colorbars: list,
                summary_text: str | None) -> tuple[float, float, list, float]:
    """Size the figure, place the map's axes (at the view's aspect) and its colour bars (specs
    ``colorbars`` of the layers), leaving room below for ``legend`` (handles) and the summary
    box. Returns (the axes' centre as a figure fraction, the figure's height [in], the summary's
    columns, the summary box's height [in]) for :func:`add_summary_and_legend`."""
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
    _add_colorbars(fig, colorbars, labels, [frac(rect) for rect in cbar_rects], scales)
    return (ax_rect[0] + 0.5 * ax_rect[2]) / fig_w, fig_h, summary_cols, summary_h


def _add_colorbars(fig, colorbars: list, labels: list, rects: list, scales: list) -> None:
    """One colour bar per spec, in its rect (figure fractions), labelled; lengths below 1 m in
    cm or mm (tick labels scaled, data unchanged)."""
    from matplotlib.ticker import FuncFormatter

    for spec, label, rect, (_, factor) in zip(colorbars, labels, rects, scales):
        cbar = fig.colorbar(spec["mappable"], cax=fig.add_axes(rect),
                            extend=spec["extend"], ticks=spec["ticks"])
        if factor != 1.0:   # small lengths in cm / mm: tick labels scaled, data unchanged
            cbar.formatter = FuncFormatter(lambda v, _pos, f=factor: significant(v * f, 4))
        if spec["opaque"]:
            cbar.solids.set_alpha(1.0)   # the cells are drawn semi-transparent, not the scale
        cbar.set_label(label, fontsize=10)
        cbar.ax.tick_params(labelsize=9)


def add_summary_and_legend(fig, ax_centre: float, fig_h: float, summary_cols: list,
                           summary_h: float, legend: list) -> None:
    """The summary box (its lines in columns ``summary_cols``) centred under the map at the
    bottom of the figure, and the legend above it, read row by row."""
    from matplotlib.offsetbox import AnchoredOffsetbox, HPacker, TextArea, VPacker

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
