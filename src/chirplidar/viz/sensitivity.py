"""Sweep and sensitivity plots: an output against another output (thesis Table 4.11 test sweeps) and
SNR against received power for several detection types (thesis Fig. 5.7).

Values in dB that are -inf (zero power) are left out of the plots, never drawn at an axis edge.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ._mpl import finite_or_nan, plt, save

# One colour per detection type, shared by simulated curves and measured points.
DETECTION_STYLE = {
    "homodyne": {"color": "C0", "marker": "o", "label": "self-chirped homodyne"},
    "heterodyne": {"color": "C2", "marker": "s", "label": "heterodyne"},
    "direct": {"color": "C3", "marker": "^", "label": "direct detection"},
}


def _axis_values(ds, name: str) -> tuple[np.ndarray, str]:
    """Values broadcast to dims (x, repeat) and an axis label for a sweep output or coordinate."""
    if name in ("x", ds.attrs.get("vary")):
        da = ds["x"]
        label = str(da.attrs.get("long_name", ds.attrs.get("vary", "x")))
        units = da.attrs.get("units")
        values = np.broadcast_to(np.asarray(da.values, dtype=float)[:, None],
                                 (ds.sizes["x"], ds.sizes.get("repeat", 1)))
    else:
        if name not in ds.data_vars:
            raise KeyError(f"'{name}' is not in the sweep; valid names: x, {', '.join(ds.data_vars)}")
        da = ds[name].transpose("x", ...)
        label = name
        units = da.attrs.get("units")
        values = np.asarray(da.values, dtype=float).reshape(ds.sizes["x"], -1)
    return finite_or_nan(values), f"{label} ({units})" if units else label


def plot_sweep(ds, path: str | Path, *, x: str = "Psig", y: str = "SNR",
               x_scale: str | None = None, title: str | None = None) -> Path:
    """Plot sweep output ``y`` against ``x`` to a PNG and return its path.

    ``ds`` is the :func:`chirplidar.api.sweep` dataset (dims ``x``, ``repeat``). ``x``/``y`` are
    Table 4.10 names or ``"x"`` (the varied parameter). With repeats, every repeat is a faint point
    and the mean over repeats (of the plotted values) is the line. ``x_scale`` ("lin" or "log")
    sets the x axis when it shows the varied parameter; default: ``ds.attrs["scale"]`` or linear.
    """
    xv, xlabel = _axis_values(ds, x)
    yv, ylabel = _axis_values(ds, y)
    fig, ax = plt.subplots(figsize=(7.0, 5.0))
    n_rep = yv.shape[1]
    if n_rep > 1:
        ax.plot(xv.ravel(), yv.ravel(), ".", color="C0", alpha=0.35, ms=4,
                label=f"{n_rep} repeats")
    with np.errstate(all="ignore"):
        counts = np.sum(np.isfinite(xv) & np.isfinite(yv), axis=1)
        ok = counts > 0
        xm = np.full(xv.shape[0], np.nan)
        ym = np.full(xv.shape[0], np.nan)
        xm[ok] = np.nanmean(np.where(np.isfinite(yv), xv, np.nan)[ok], axis=1)
        ym[ok] = np.nanmean(np.where(np.isfinite(xv), yv, np.nan)[ok], axis=1)
    order = np.argsort(xm[ok])
    ax.plot(xm[ok][order], ym[ok][order], "o-", color="C0", ms=4,
            label="mean" if n_rep > 1 else None)
    if x in ("x", ds.attrs.get("vary")) and (x_scale or ds.attrs.get("scale")) == "log":
        ax.set_xscale("log")
    vary = ds.attrs.get("vary", "")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title or f"{y} vs {x}" + (f" (sweep of {vary}, tier {ds.attrs.get('tier', '?')})"
                                          if vary else ""))
    ax.grid(True, alpha=0.3)
    if n_rep > 1:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def plot_sensitivity(path: str | Path,
                     simulated: Mapping[str, tuple[Sequence[float], Sequence[float]]],
                     measured: Mapping[str, tuple[Sequence[float], Sequence[float]]] | None = None,
                     *, shot_noise: tuple[Sequence[float], Sequence[float]] | None = None,
                     shot_noise_label: str = "shot-noise limit",
                     snr_line_db: float | None = 10.0, title: str | None = None) -> Path:
    """SNR (dB) against received signal power (dBm) for several detection types, to a PNG.

    ``simulated`` and ``measured`` map a detection type (``homodyne``, ``heterodyne``, ``direct`` or
    any other name) to ``(power_dbm, snr_db)``. Simulated curves are lines, measured points are
    open markers of the same colour. ``shot_noise`` is a ``(power_dbm, snr_db)`` line; a
    horizontal line marks ``snr_line_db``.
    """
    fig, ax = plt.subplots(figsize=(8.0, 5.5))
    data_p: list[np.ndarray] = []
    data_snr: list[np.ndarray] = []
    for i, (det, (p, snr)) in enumerate(simulated.items()):
        style = DETECTION_STYLE.get(det, {"color": f"C{4 + i}", "marker": "o", "label": det})
        p, snr = finite_or_nan(p), finite_or_nan(snr)
        data_p.append(p)
        data_snr.append(snr)
        order = np.argsort(p)
        ax.plot(p[order], snr[order], ".-", color=style["color"], lw=1.6, ms=5,
                label=f"{style['label']} (simulated)")
    for i, (det, (p, snr)) in enumerate((measured or {}).items()):
        style = DETECTION_STYLE.get(det, {"color": f"C{4 + i}", "marker": "o", "label": det})
        data_p.append(finite_or_nan(p))
        data_snr.append(finite_or_nan(snr))
        ax.plot(data_p[-1], data_snr[-1], style["marker"], mfc="none",
                color=style["color"], ms=6, label=f"{style['label']} (measured)")
    if shot_noise is not None:
        ax.plot(finite_or_nan(shot_noise[0]), finite_or_nan(shot_noise[1]), "k-", lw=1.0,
                label=shot_noise_label)
    if snr_line_db is not None:
        ax.axhline(snr_line_db, color="0.5", ls="--", lw=1.0, label=f"{snr_line_db:g} dB SNR")
    # Frame the curves and points; the shot-noise line may run far beyond them.
    all_p = np.concatenate(data_p) if data_p else np.array([])
    all_snr = np.concatenate(data_snr) if data_snr else np.array([])
    if np.isfinite(all_p).any():
        lo, hi = np.nanmin(all_p), np.nanmax(all_p)
        ax.set_xlim(lo - 3.0, hi + 3.0)
    if np.isfinite(all_snr).any():
        lo, hi = np.nanmin(all_snr), np.nanmax(all_snr)
        ax.set_ylim(min(lo, 0.0) - 3.0, hi + 8.0)
    ax.set_xlabel("received signal power Psig (dBm)")
    ax.set_ylabel("SNR (dB)")
    ax.set_title(title or "Sensitivity of direct, heterodyne and self-chirped detection")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return save(fig, path)
