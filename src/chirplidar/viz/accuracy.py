"""Pareto plot of the accuracy-versus-time study (:mod:`chirplidar.analysis.accuracy`).

Seconds per shot (log) against the error of each setting's range RMS and mean SNR with respect to
the reference's (|range RMS - reference RMS|, |mean SNR - reference|), one marker and colour per tier and
knob family, every point labelled, each panel's Pareto front (no other setting is both faster and
more accurate) drawn as a grey step line, and the grey band the sampling noise of a difference
between two independent runs (2 standard errors). Top rows: the point-target study, one column per SNR
point; then the footprint (sub-rays) and turbulence (phase-screen size) studies; last row: the
pulsed study's range (GLAS bench: digitizer sample rate and range estimator), one column per SNR
point.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ._mpl import plt, save

from matplotlib.ticker import NullFormatter  # noqa: E402  (after _mpl chose the backend)

# (tier, family) -> colour, marker, legend text
STYLE = {
    ("rf", "reference"): ("black", "*", "rf reference (mission settings)"),
    ("rf", "sample_rate"): ("C0", "o", "rf: sample rate"),
    ("rf", "delay_method"): ("C1", "s", "rf: delay resampling"),
    ("rf", "peak_method"): ("C2", "^", "rf: peak interpolation"),
    ("rf", "zero_pad"): ("C3", "D", "rf: zero padding"),
    ("baseband", "baseband_rate"): ("C4", "v", "baseband: sample rate"),
    ("baseband", "precision"): ("C4", "X", "baseband: double precision"),
    ("link", "link"): ("C5", "P", "link (closed form)"),
    ("rf", "sub_rays"): ("C6", "o", "rf: sub-rays per footprint"),
    ("baseband", "sub_rays"): ("C9", "v", "baseband: sub-rays per footprint"),
    ("rf", "screen"): ("C7", "o", "rf: phase-screen pixels"),
    ("link", "screen"): ("C8", "P", "link: phase-screen pixels"),
    ("pulsed", "reference"): ("dimgrey", "*", "pulsed reference (4 GHz, Gaussian fit)"),
    ("pulsed", "pulse_sample_rate"): ("teal", "h", "pulsed: digitizer sample rate"),
    ("pulsed", "pulse_estimator"): ("magenta", "p", "pulsed: range estimator"),
}
_FALLBACK = ("grey", "x", "other")


def pareto_front(x: Sequence[float], y: Sequence[float]) -> np.ndarray:
    """Indices of the points no other point beats in both x and y (smaller is better), by x."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    order = ok[np.lexsort((y[ok], x[ok]))]
    front, best = [], math.inf
    for i in order:
        if y[i] < best:
            front.append(i)
            best = y[i]
    return np.array(front, dtype=int)


def _short(row: dict) -> str:
    """Point label: the knob's value, short."""
    s = str(row["setting"])
    if row["reference"]:
        return "ref"
    for prefix in ("rf ", "bb ", "link ", "baseband ", "peak ", "zero pad ", "Fs "):
        if s.startswith(prefix) and row["family"] not in ("link",):
            s = s[len(prefix):]
    if row["family"] == "pulse_estimator":
        s = s.split(" (")[0] + ("*" if "(mission)" in s else "")   # its rate: the mission's
    return s.replace(" sub-rays", "").replace(" (default rate)", "default").replace(
        " (default)", "*").replace("(default rate)", "default").replace(" (mission)", "*")


def _panel(ax, rows: Sequence[dict], metric: str, title: str, handles: dict,
           cap_factor: float = 5.0):
    x = np.array([r["s_per_shot"] for r in rows], float)
    ref = next((r for r in rows if r["reference"]), None)
    if metric == "range":
        y = np.abs(np.array([r["range_rms_diff_m"] for r in rows], float))
        ax.set_ylabel("|range RMS - reference RMS| (m)")
        noise = 2 * np.sqrt(2) * ref["range_rms_se_m"] if ref else math.nan
        if ref is not None:
            title += f" (ref RMS {ref['range_rms_m'] * 1e3:.3g} mm)"
    elif metric == "snr":
        y = np.abs(np.array([r["snr_error_db"] for r in rows], float))
        ax.set_ylabel("|mean SNR - reference| (dB)")
        noise = (2 * np.sqrt(2) * ref["snr_std_db"] / np.sqrt(ref["shots"])) if ref else math.nan
    else:
        raise ValueError(f"metric must be 'range' or 'snr', got {metric!r}")
    if np.isfinite(noise) and noise > 0:
        # Two standard errors of a difference of two independent runs: below it an unpaired
        # setting (other sample rate, other tier) is not told apart from the reference.
        band = ax.axhspan(0.0, noise, color="0.85", zorder=0)
        handles.setdefault("2 s.e. of a difference of two independent runs", band)
    # Points far above the rest (a run with false peaks: range RMS of metres or km) are drawn at
    # the cap with their value written next to them, so they do not squash the other points.
    cap = (cap_factor * ref["range_rms_m"] if metric == "range" else 5.0) if ref else math.inf
    shown = np.minimum(y, cap)
    front = pareto_front(x, y)
    if front.size > 1:
        h = ax.plot(x[front], shown[front], color="0.45", ls="--", lw=1.4, drawstyle="steps-post",
                    zorder=1)[0]
        handles.setdefault("Pareto front", h)
    placed: list[tuple[float, float]] = []
    lx = np.log10(np.where(x > 0, x, np.nan))
    span_x = max(float(np.nanmax(lx) - np.nanmin(lx)), 1e-9) if np.isfinite(lx).any() else 1.0
    span_y = max(float(np.nanmax(shown[np.isfinite(shown)], initial=0.0)),
                 noise if np.isfinite(noise) else 0.0, 1e-12)
    for i in np.argsort(x, kind="stable"):
        r = rows[i]
        if not (np.isfinite(x[i]) and np.isfinite(y[i])):
            continue
        key = (r["tier"], "reference" if (r["reference"] and r["family"] not in
                                          ("sub_rays", "screen")) else r["family"])
        color, marker, text = STYLE.get(key, _FALLBACK)
        big = 15 if r["reference"] else 8
        clipped = y[i] > cap
        h = ax.plot(x[i], shown[i], ls="none", marker=marker, color=color, ms=big,
                    mec="black" if r["reference"] else color, zorder=3)[0]
        handles.setdefault(text, h)
        label = _short(r)
        if metric == "range" and r["range_rms_diff_m"] < -noise:
            label += " \u2193"     # a lower RMS than the reference's, beyond the noise
        if clipped:
            label += f" ({y[i]:.3g}{' m' if metric == 'range' else ' dB'}, off scale)"
        # Stack labels of points that sit close together (in axis fractions) instead of
        # printing them over each other.
        fx, fy = (lx[i] - np.nanmin(lx)) / span_x, shown[i] / span_y
        level = sum(1 for px, py in placed if abs(px - fx) < 0.12 and abs(py - fy) < 0.06)
        placed.append((fx, fy))
        ax.annotate(label, (x[i], shown[i]), xytext=(5, 4 + 10 * level),
                    textcoords="offset points", fontsize=9.5, color=color)
    ax.set_xscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    finite = shown[np.isfinite(shown)]
    top = max(float(finite.max()) if finite.size else 0.0, noise if np.isfinite(noise) else 0.0)
    ax.set_ylim(bottom=0.0, top=1.25 * top if top > 0 else 1.0)
    ax.set_xlabel("seconds per shot")
    ax.set_title(title, fontsize=11.5)
    ax.grid(True, which="major", alpha=0.3)


def plot_accuracy(rows: Sequence[dict], path: str | Path, *, title: str | None = None) -> Path:
    """Draw the study's rows (dicts with the columns of ``analysis.accuracy.COLUMNS``) to a PNG."""
    rows = list(rows)
    if not rows:
        raise ValueError("no rows to plot")
    point = [r for r in rows if r["study"] == "point target"]
    snrs = sorted({r["snr_target_db"] for r in point})
    bottom = []
    foot = [r for r in rows if r["study"] == "footprint"]
    turb = [r for r in rows if r["study"] == "turbulence"]
    if foot:
        s = foot[0]["snr_target_db"]
        bottom += [(foot, "range", f"footprint, 10 deg slope (SNR {s:g} dB): range"),
                   (foot, "snr", f"footprint (SNR {s:g} dB): mean SNR")]
    if turb:
        s = turb[0]["snr_target_db"]
        bottom += [(turb, "snr", f"turbulence, frozen flow (SNR {s:g} dB): mean SNR")]
    pulsed = [r for r in rows if r["study"] == "pulsed"]
    psnrs = sorted({r["snr_target_db"] for r in pulsed})
    ncols = max(len(snrs), len(bottom), len(psnrs), 1)
    nrows = (2 if snrs else 0) + (1 if bottom else 0) + (1 if psnrs else 0)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.6 * ncols, 4.6 * nrows + 1.2),
                             squeeze=False)
    handles: dict = {}
    for j, s in enumerate(snrs):
        sel = [r for r in point if r["snr_target_db"] == s]
        _panel(axes[0, j], sel, "range", f"point target, SNR {s:g} dB: range", handles)
        _panel(axes[1, j], sel, "snr", f"point target, SNR {s:g} dB: mean SNR", handles)
    row_b = (2 if snrs else 0)
    for j, (sel, metric, text) in enumerate(bottom):
        _panel(axes[row_b, j], sel, metric, text, handles)
    for j, s in enumerate(psnrs):
        sel = [r for r in pulsed if r["snr_target_db"] == s]
        # the threshold estimator's range walk (decimetres) would squash the other points
        _panel(axes[nrows - 1, j], sel, "range", f"pulsed (GLAS bench), SNR {s:g} dB: range",
               handles, cap_factor=1.0)
    used = {(0, j) for j in range(len(snrs))} | {(1, j) for j in range(len(snrs))} \
        if snrs else set()
    used |= {(row_b, j) for j in range(len(bottom))}
    used |= {(nrows - 1, j) for j in range(len(psnrs))}
    for i in range(nrows):
        for j in range(ncols):
            if (i, j) not in used:
                axes[i, j].set_visible(False)
    fig.legend(list(handles.values()), list(handles.keys()), loc="lower center",
               ncol=min(4, len(handles)), fontsize=11, frameon=False)
    fig.suptitle(title or "Accuracy against time: each fidelity knob against its reference "
                 "(dashed: Pareto front; *: default; \u2193: lower range RMS than the reference)", fontsize=14)
    fig.tight_layout(rect=(0, 0.07 if len(handles) > 4 else 0.04, 1, 0.96))
    return save(fig, path)
