"""Beat-spectrum plot of one shot, in the style of thesis Fig. 5.2 (spectrum-analyzer trace).

Input is the ``spectrum`` dict of :func:`chirplidar.api.simulate_shot` with ``return_spectrum=True``:
``f_hz`` (Hz), ``psd_w_per_hz`` (one-sided PSD, W/Hz), ``f_peak_hz``, ``f_lo_hz``, ``f_hi_hz``
(peak and its 3 dB points, Hz), ``noise_psd_w_per_hz`` (W/Hz) and ``rbw_hz`` (Hz).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ._mpl import dbm_from_w, plt, save

UNITS = ("dBm", "dBm/Hz")
_MAX_FULL_POINTS = 4096  # the full-span panel is drawn peak-held to about this many points


def _peak_hold(f_hz: np.ndarray, psd: np.ndarray, n_max: int) -> tuple[np.ndarray, np.ndarray]:
    """Decimate to about ``n_max`` points keeping each block's maximum (a spectrum analyzer's
    peak-detector display), so narrow lines stay visible in the full-span view."""
    n = f_hz.size
    if n <= n_max:
        return f_hz, psd
    k = math.ceil(n / n_max)
    m = (n // k) * k
    blocks = psd[:m].reshape(-1, k)
    idx = np.argmax(blocks, axis=1) + np.arange(blocks.shape[0]) * k
    return f_hz[idx], psd[idx]


def zoom_span_hz(spectrum: Mapping[str, Any]) -> tuple[float, float] | None:
    """Frequency window (Hz) around the peak for the zoomed panel, or None without a finite peak.

    Half-width: the larger of 10 peak 3 dB widths, 40 frequency bins and 40 RBW, clipped to the
    spectrum's frequency range.
    """
    f = np.asarray(spectrum["f_hz"], dtype=float)
    f_peak = float(spectrum.get("f_peak_hz", math.nan))
    if f.size < 2 or not math.isfinite(f_peak):
        return None
    df = float(np.median(np.diff(f)))
    width = float(spectrum.get("f_hi_hz", math.nan)) - float(spectrum.get("f_lo_hz", math.nan))
    width = width if math.isfinite(width) and width > 0 else 0.0
    half = max(10.0 * width, 40.0 * df, 40.0 * float(spectrum.get("rbw_hz", 0.0) or 0.0))
    return max(f[0], f_peak - half), min(f[-1], f_peak + half)


def plot_beat_spectrum(spectrum: Mapping[str, Any], path: str | Path, *,
                       outputs: Mapping[str, Any] | None = None, unit: str = "dBm",
                       title: str | None = None) -> Path:
    """Draw the beat spectrum to a PNG at ``path`` and return the path.

    ``unit``: ``"dBm"`` plots power in one resolution bandwidth (PSD x RBW, as a spectrum analyzer
    shows it, thesis Fig. 5.2) or ``"dBm/Hz"`` the PSD. Top panel: a zoom around the peak with the
    peak, its 3 dB points and the noise level marked; bottom panel: the full span (peak-held) with
    the zoom window shaded. ``outputs`` (the shot's result dict) adds SNR and range to the legend.
    """
    if unit not in UNITS:
        raise ValueError(f"unit must be one of {UNITS}, got {unit!r}")
    f = np.asarray(spectrum["f_hz"], dtype=float)
    psd = np.asarray(spectrum["psd_w_per_hz"], dtype=float)
    if f.shape != psd.shape or f.ndim != 1:
        raise ValueError(f"spectrum f_hz {f.shape} and psd_w_per_hz {psd.shape} must be 1-D, same length")
    rbw = float(spectrum["rbw_hz"])
    scale = rbw if unit == "dBm" else 1.0
    ylabel = (f"power in RBW = {rbw / 1e3:g} kHz (dBm)" if unit == "dBm"
              else "power spectral density (dBm/Hz)")
    noise_dbm = float(dbm_from_w(float(spectrum["noise_psd_w_per_hz"]) * scale))
    f_peak = float(spectrum.get("f_peak_hz", math.nan))
    f_lo = float(spectrum.get("f_lo_hz", math.nan))
    f_hi = float(spectrum.get("f_hi_hz", math.nan))
    span = zoom_span_hz(spectrum)

    fig, (ax_zoom, ax_full) = plt.subplots(2, 1, figsize=(8.0, 7.5),
                                           gridspec_kw={"height_ratios": [3, 2]})
    # Zoomed panel: the carrier as the spectrum analyzer was set to show it.
    if span is not None:
        sel = (f >= span[0]) & (f <= span[1])
        fz_mhz, pz = f[sel] / 1e6, dbm_from_w(psd[sel] * scale)
        ax_zoom.plot(fz_mhz, pz, color="C0", lw=1.0, label="beat spectrum")
        # Peak level: the highest bin between the 3 dB points (or the bin nearest the peak), so
        # the marker sits on the drawn trace even when the peak frequency is interpolated.
        in3 = (f >= f_lo) & (f <= f_hi) if math.isfinite(f_lo) and math.isfinite(f_hi) else np.zeros_like(sel)
        near = int(np.argmin(np.abs(f - f_peak)))
        peak_w = max(float(psd[near]), float(psd[in3].max()) if in3.any() else 0.0)
        peak_dbm = float(dbm_from_w(peak_w * scale))
        label = f"peak {f_peak / 1e6:.4f} MHz"
        if outputs is not None:
            snr = outputs.get("SNR")
            d_rx = outputs.get("d_rx")
            if snr is not None and math.isfinite(snr):
                label += f", SNR {snr:.1f} dB"
            if d_rx is not None and math.isfinite(d_rx):
                label += f", d_rx {d_rx:.3f} m"
        if math.isfinite(peak_dbm):
            ax_zoom.plot([f_peak / 1e6], [peak_dbm], "v", color="C3", ms=8, label=label)
            if math.isfinite(f_lo) and math.isfinite(f_hi):
                ax_zoom.plot([f_lo / 1e6, f_hi / 1e6], [peak_dbm - 3.0] * 2, "|-", color="C2",
                             ms=12, mew=1.5,
                             label=f"3 dB points ({(f_hi - f_lo) / 1e3:.1f} kHz)")
        ax_zoom.set_xlim(span[0] / 1e6, span[1] / 1e6)
    else:
        ax_zoom.text(0.5, 0.5, "no spectral peak found", ha="center", va="center",
                     transform=ax_zoom.transAxes)
    if math.isfinite(noise_dbm):
        for ax in (ax_zoom, ax_full):
            ax.axhline(noise_dbm, color="0.4", ls="--", lw=1.0,
                       label=f"noise level {noise_dbm:.1f} {unit}" if ax is ax_zoom else None)
    ax_zoom.set_xlabel("beat frequency (MHz)")
    ax_zoom.set_ylabel(ylabel)
    ax_zoom.grid(True, alpha=0.3)
    ax_zoom.legend(loc="upper right", fontsize=8)
    ax_zoom.set_title(title or "Dechirped beat spectrum")

    # Full span.
    ff, pf = _peak_hold(f, psd, _MAX_FULL_POINTS)
    ax_full.plot(ff / 1e6, dbm_from_w(pf * scale), color="C0", lw=0.7)
    if span is not None:
        ax_full.axvspan(span[0] / 1e6, span[1] / 1e6, color="C1", alpha=0.25, label="zoom window")
        ax_full.legend(loc="upper right", fontsize=8)
    if f.size:
        ax_full.set_xlim(f[0] / 1e6, f[-1] / 1e6)
    ax_full.set_xlabel("beat frequency (MHz)")
    ax_full.set_ylabel(unit)
    ax_full.set_title("full span (peak hold)", fontsize=9)
    ax_full.grid(True, alpha=0.3)
    fig.tight_layout()
    return save(fig, path)
