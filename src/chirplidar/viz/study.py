"""Plots of a mission study (:mod:`chirplidar.analysis.study`): its metrics against the varied
keys, to a PNG.

* One varied key, or two where one of them has few values or is not numeric: four panels
  against the (numeric) key -- detection probability (and the covered fraction, dashed, when the
  study has one), median SNR with its 10-90 % band and the detection threshold (dashed), median
  received power, range RMS (and the height precision, dashed) of the detected shots -- with one
  line per value of the other key. A range RMS or height precision that rests on fewer than
  :data:`MIN_DETECTED_SHOTS` detected shots (the study's ``detected_shots``) is left out of its
  line and drawn as an open marker with its count beside it ("n=1"), said in the legend: one
  detected shot makes no precision, and a line through it would show a dip that is not there.
  Every panel spans at least :data:`MIN_SPAN` (1 dB, 1 cm, 5 %) centred on its data, so that
  a quantity that does not change (the received power against the line spacing) shows flat,
  not as its noise magnified into a trend.
* Two numeric keys of three or more values each: heat maps of the median SNR and the detection
  probability over the grid, with the contour where the median SNR equals the detection
  threshold.

Axis labels carry the key's unit, from its SI suffix (``_m`` m, ``_deg`` deg, ``_w`` W, ``_mps``
m/s, ``_db`` dB, ...). -inf values (zero signal) and NaN (no value) are left out: gaps in a
line, blank cells in a map.

:func:`study_figure` returns the figure (e.g. for a notebook), :func:`plot_study` writes it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._mpl import finite_or_nan, plt, save

#: Most values of a second key drawn as separate lines (with a legend).
MAX_SERIES = 8
#: Heat maps write each cell's value up to this many cells per axis.
MAX_ANNOTATED = 10
#: Range RMS and height precision from fewer detected shots are marked, not joined in a line.
MIN_DETECTED_SHOTS = 10
#: Smallest y span of a panel, by its unit: a flat quantity stays flat.
MIN_SPAN = {"dB": 1.0, "cm": 1.0, "%": 5.0}


def _units_label(ds, dim: str) -> str:
    from ..analysis.study_grid import key_units

    coord = ds[dim]
    key = str(coord.attrs.get("study_key", dim))
    mission_key = str(coord.attrs.get("mission_key", key))
    unit = key_units(mission_key)[1] if _numeric(ds, dim) else ""
    name = key if key == mission_key else f"{key} = {mission_key}"
    return f"{name} ({unit})" if unit else name


def _numeric(ds, dim: str) -> bool:
    return np.issubdtype(ds[dim].dtype, np.number)


def _log(ds, dim: str) -> bool:
    if ds[dim].attrs.get("spacing") == "log":
        return True
    if not _numeric(ds, dim) or ds.sizes[dim] < 3:
        return False
    v = np.asarray(ds[dim].values, float)
    return bool(np.all(v > 0) and np.allclose(np.diff(np.log(v)), np.log(v[1] / v[0]),
                                              rtol=1e-6))


def _fmt_value(v) -> str:
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.4g}"
    return str(v.item() if hasattr(v, "item") else v)


def _title(ds) -> str:
    mission = Path(str(ds.attrs.get("mission_file", "mission"))).name
    bits = [f"tier {ds.attrs.get('tier', '?')}", f"seed {int(ds.attrs.get('seed', 0))}"]
    bits.append(f"{float(ds.attrs['span_s']):g} s span" if "span_s" in ds.attrs
                else "whole mission")
    return f"Mission study: {mission} ({', '.join(bits)})"


def study_figure(ds, *, title: str | None = None):
    """The plot of the study dataset ``ds`` (:func:`chirplidar.analysis.study.run_study`) as a
    matplotlib Figure (module docstring); the caller closes it."""
    dims = list(ds["detection_probability"].dims)
    if not 1 <= len(dims) <= 2:
        raise ValueError(f"a study has one or two varied keys, got dims {dims}")
    if len(dims) == 2 and all(_numeric(ds, d) and ds.sizes[d] >= 3 for d in dims):
        return _heat_maps(ds, dims, title or _title(ds))
    return _line_panels(ds, dims, title or _title(ds))


def plot_study(ds, path, *, title: str | None = None) -> Path:
    """Draw the study dataset ``ds`` (:func:`chirplidar.analysis.study.run_study`) to the PNG
    ``path`` (module docstring) and return the path."""
    fig = study_figure(ds, title=title)
    try:
        return save(fig, path)
    finally:   # also when saving fails: no figure left registered in pyplot
        plt.close(fig)


def _min_span(ax, span: float) -> None:
    """Widen the y axis of ``ax`` to at least ``span``, centred on its autoscaled limits."""
    lo, hi = ax.get_ylim()
    if ax.get_yscale() == "linear" and np.isfinite(lo) and np.isfinite(hi) and hi - lo < span:
        mid = 0.5 * (lo + hi)
        ax.set_ylim(mid - 0.5 * span, mid + 0.5 * span)


def _value_ticks(axis, values) -> None:
    """A log axis labelled at the study's own values (up to 10 of them), in plain numbers."""
    from matplotlib.ticker import FixedLocator, NullLocator

    v = np.unique(np.asarray(values, float))
    if v.size > 10:
        step = int(np.ceil(v.size / 8))
        v = v[::step]
    axis.set_major_locator(FixedLocator(v))
    axis.set_minor_locator(NullLocator())
    axis.set_major_formatter(plt.FuncFormatter(lambda t, _: f"{t:.4g}"))


# ----------------------------------------------------------------------------------- lines
def _line_panels(ds, dims, title):
    if len(dims) == 1:
        x_dim, s_dim = dims[0], None
    else:
        # x: a numeric key (the one with more values when both are); lines: the other.
        a, b = dims
        if _numeric(ds, a) != _numeric(ds, b):
            x_dim = a if _numeric(ds, a) else b
        else:
            x_dim = a if ds.sizes[a] >= ds.sizes[b] else b
        s_dim = b if x_dim == a else a
    numeric_x = _numeric(ds, x_dim)
    xs = np.asarray(ds[x_dim].values, float) if numeric_x else np.arange(ds.sizes[x_dim])
    series = [None] if s_dim is None else list(range(ds.sizes[s_dim]))
    if len(series) > MAX_SERIES:
        if _numeric(ds, s_dim):
            v = np.asarray(ds[s_dim].values, float)
            colours = plt.cm.viridis((v - v.min()) / (v.max() - v.min()))
        else:
            colours = plt.cm.viridis(np.linspace(0.0, 1.0, len(series)))
    else:
        colours = [f"C{i}" for i in range(len(series))]

    def values(name, k):
        da = ds[name].transpose(x_dim, *([s_dim] if s_dim else []))
        v = np.asarray(da.values, float)
        return finite_or_nan(v if s_dim is None else v[:, k])

    fig, axes = plt.subplots(2, 2, figsize=(11.0, 7.6), sharex=True, layout="constrained")
    ax_det, ax_snr, ax_pow, ax_rng = axes.ravel()
    thr_all = np.asarray(ds["detection_threshold_db"].values, float)
    constant_thr = bool(np.all(thr_all == thr_all.ravel()[0]))
    covered = "fraction_covered" in ds.data_vars
    has_counts = "detected_shots" in ds.data_vars     # study files before it lack it
    few_any = False
    reliable_rng = []
    for k, colour in zip(series, colours):
        label = (None if s_dim is None or len(series) > MAX_SERIES
                 else _fmt_value(ds[s_dim].values[k]))
        kw = {"color": colour, "marker": "o", "ms": 4, "lw": 1.6}
        ax_det.plot(xs, 100.0 * values("detection_probability", k), label=label, **kw)
        if covered:
            ax_det.plot(xs, 100.0 * values("fraction_covered", k), color=colour, ls="--",
                        marker="s", ms=3, lw=1.2)
        med = values("median_snr_db", k)
        ax_snr.plot(xs, med, label=label, **kw)
        lo, hi = values("snr_p10_db", k), values("snr_p90_db", k)
        band = np.isfinite(lo) & np.isfinite(hi)
        if np.any(band):
            ax_snr.fill_between(xs, np.where(band, lo, np.nan), np.where(band, hi, np.nan),
                                color=colour, alpha=0.18, lw=0)
        if not constant_thr:
            ax_snr.plot(xs, values("detection_threshold_db", k), color=colour, ls="--",
                        lw=1.0)
        ax_pow.plot(xs, values("median_received_power_dbm", k), label=label, **kw)
        rng_k = 100.0 * values("range_rms_m", k)
        hp_k = 100.0 * values("height_precision_m", k)
        few = np.zeros(xs.shape, bool)
        if has_counts:
            n_det = values("detected_shots", k)
            few = n_det < MIN_DETECTED_SHOTS
        ax_rng.plot(xs, np.where(few, np.nan, rng_k), label=label, **kw)
        ax_rng.plot(xs, np.where(few, np.nan, hp_k), color=colour, ls="--", marker="s", ms=3,
                    lw=1.2)
        reliable_rng.append(np.where(few, np.nan, rng_k))
        for y, marker in ((rng_k, "o"), (hp_k, "s")):
            weak = few & np.isfinite(y)
            if np.any(weak):
                few_any = True
                ax_rng.plot(xs[weak], y[weak], ls="none", marker=marker, ms=6, mfc="none",
                            mec=colour, mew=1.2)
        for i in np.flatnonzero(few & (np.isfinite(rng_k) | np.isfinite(hp_k))):
            y = rng_k[i] if np.isfinite(rng_k[i]) else hp_k[i]
            right = xs[i] > np.median(xs)      # the count on the inner side: not clipped
            ax_rng.annotate(f"n={int(n_det[i])}", (xs[i], y), xytext=(-5 if right else 5, 4),
                            textcoords="offset points", ha="right" if right else "left",
                            fontsize=7, color=colour)
    if constant_thr:
        ax_snr.axhline(thr_all.ravel()[0], color="0.35", ls="--", lw=1.1,
                       label=f"threshold {thr_all.ravel()[0]:g} dB")
    else:   # the threshold varies: dashed in each line's colour
        ax_snr.plot([], [], color="0.35", ls="--", lw=1.0, label="detection threshold")
    ax_det.set_ylabel("detection probability / covered (%)" if covered
                      else "detection probability (%)")
    ax_det.set_ylim(-3.0, 103.0)
    ax_snr.set_ylabel("median SNR (dB), 10-90 % band")
    ax_pow.set_ylabel("median received power (dBm)")
    ax_rng.set_ylabel("range RMS / height precision, detected (cm)")
    rng = np.concatenate(reliable_rng)
    rng = rng[np.isfinite(rng) & (rng > 0)]
    if rng.size and rng.max() / rng.min() > 20.0:
        ax_rng.set_yscale("log")
        ax_rng.yaxis.set_major_formatter(plt.FuncFormatter(lambda t, _: f"{t:g}"))
    from matplotlib.lines import Line2D

    rng_styles = [Line2D([], [], color="0.2", marker="o", ms=4, lw=1.6,
                         label="range error RMS"),
                  Line2D([], [], color="0.2", marker="s", ms=3, lw=1.2, ls="--",
                         label="height precision (std)")]
    if few_any:
        rng_styles.append(Line2D([], [], ls="none", marker="o", ms=6, mfc="none", mec="0.2",
                                 mew=1.2, label=f"open: < {MIN_DETECTED_SHOTS} detected "
                                 "shots (n=count), not joined"))
    ax_rng.legend(handles=rng_styles, fontsize=8, loc="best")
    xlabel = _units_label(ds, x_dim)
    for ax in axes.ravel():
        ax.grid(True, alpha=0.3)
        if numeric_x and _log(ds, x_dim):
            ax.set_xscale("log")
            _value_ticks(ax.xaxis, xs)
    for ax in axes[1]:
        ax.set_xlabel(xlabel)
        if not numeric_x:
            ax.set_xticks(xs)
            ax.set_xticklabels([_fmt_value(v) for v in ds[x_dim].values])
    if covered:
        cell = ds["fraction_covered"].attrs.get("cell_size_m")
        styles = [Line2D([], [], color="0.2", marker="o", ms=4, lw=1.6,
                         label="detection probability"),
                  Line2D([], [], color="0.2", marker="s", ms=3, lw=1.2, ls="--",
                         label="covered fraction" + (f" ({cell:g} m cells)" if cell else ""))]
        ax_det.legend(handles=styles, fontsize=8, loc="best")
    if s_dim is not None and len(series) > MAX_SERIES:
        if _numeric(ds, s_dim):
            v = np.asarray(ds[s_dim].values, float)
            norm, what = plt.Normalize(v.min(), v.max()), _units_label(ds, s_dim)
        else:
            norm, what = plt.Normalize(0, len(series) - 1), _units_label(ds, s_dim) + " (index)"
        sm = plt.cm.ScalarMappable(cmap="viridis", norm=norm)
        cb = fig.colorbar(sm, ax=axes.ravel().tolist(), shrink=0.6)
        cb.set_label(what)
    legend_title = (_units_label(ds, s_dim) if s_dim is not None and len(series) <= MAX_SERIES
                    else None)
    ax_snr.legend(title=legend_title, fontsize=8, title_fontsize=8, loc="best")
    fig.suptitle(title, fontsize=11)
    _min_span(ax_snr, MIN_SPAN["dB"])
    _min_span(ax_pow, MIN_SPAN["dB"])
    _min_span(ax_rng, MIN_SPAN["cm"])
    _min_span(ax_det, MIN_SPAN["%"])   # fixed at -3..103 %: already wider
    return fig


# ------------------------------------------------------------------------------- heat maps
def _edges(v: np.ndarray, log: bool) -> np.ndarray:
    """Cell edges around centres ``v`` (midpoints, geometric on a log axis)."""
    w = np.log(v) if log else v
    mid = 0.5 * (w[1:] + w[:-1])
    e = np.concatenate([[w[0] - (mid[0] - w[0])], mid, [w[-1] + (w[-1] - mid[-1])]])
    return np.exp(e) if log else e


def _heat_maps(ds, dims, title):
    x_dim, y_dim = dims
    x = np.asarray(ds[x_dim].values, float)
    y = np.asarray(ds[y_dim].values, float)
    order_x, order_y = np.argsort(x), np.argsort(y)
    x, y = x[order_x], y[order_y]
    log_x, log_y = _log(ds, x_dim), _log(ds, y_dim)

    def grid(name):   # (y, x) for pcolormesh
        v = np.asarray(ds[name].transpose(x_dim, y_dim).values, float)
        return v[order_x][:, order_y].T

    snr = grid("median_snr_db")
    margin = snr - grid("detection_threshold_db")
    panels = [("median_snr_db", finite_or_nan(snr), "median SNR (dB)", "viridis", None),
              ("detection_probability", finite_or_nan(100.0 * grid("detection_probability")),
               "detection probability (%)", "magma", (0.0, 100.0))]
    fig, axes = plt.subplots(1, 2, figsize=(12.0, 5.2), layout="constrained")
    xe, ye = _edges(x, log_x), _edges(y, log_y)
    annotate = x.size <= MAX_ANNOTATED and y.size <= MAX_ANNOTATED
    for ax, (name, z, label, cmap, lim) in zip(axes, panels):
        mesh = ax.pcolormesh(xe, ye, np.ma.masked_invalid(z), cmap=cmap, shading="flat",
                             vmin=None if lim is None else lim[0],
                             vmax=None if lim is None else lim[1])
        cb = fig.colorbar(mesh, ax=ax)
        cb.set_label(label)
        if annotate:
            finite = z[np.isfinite(z)]
            mid = 0.5 * (finite.min() + finite.max()) if finite.size else 0.0
            if lim is not None:
                mid = 0.5 * (lim[0] + lim[1])
            for j, yv in enumerate(y):
                for i, xv in enumerate(x):
                    v = z[j, i]
                    ax.text(xv, yv, "-" if not np.isfinite(v) else f"{v:.0f}", ha="center",
                            va="center", fontsize=7,
                            color="white" if np.isfinite(v) and v < mid else "black")
        m = finite_or_nan(margin)
        if np.nanmin(m, initial=np.inf) < 0 < np.nanmax(m, initial=-np.inf):
            colour = "white" if name == "median_snr_db" else "cyan"
            ax.contour(x, y, m, levels=[0.0], colors=colour, linewidths=2.0,
                       linestyles="--")
            ax.plot([], [], color=colour, ls="--", lw=2.0,
                    label="median SNR = detection threshold")
            leg = ax.legend(fontsize=8, loc="lower left", framealpha=0.85)
            leg.get_frame().set_facecolor("0.3")
            for text in leg.get_texts():
                text.set_color("white")
        if log_x:
            ax.set_xscale("log")
            _value_ticks(ax.xaxis, x)
        if log_y:
            ax.set_yscale("log")
            _value_ticks(ax.yaxis, y)
        ax.set_xlabel(_units_label(ds, x_dim))
        ax.set_ylabel(_units_label(ds, y_dim))
        ax.set_title(label.split(" (")[0], fontsize=10)
    fig.suptitle(title, fontsize=11)
    return fig
