"""The instruments of ``chirplidar compare`` against received power: range precision (top) and
detection probability (bottom), one curve per instrument, each instrument's sensitivity (50 %
detected) marked. A pulsed instrument's received power is its pulse's peak, a
chirped one's the mean during the record (:mod:`chirplidar.analysis.compare`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._mpl import plt, save


def plot_comparison(results, path) -> Path:
    """Save the figure of :func:`chirplidar.analysis.compare.compare_instruments`'s sweeps."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 7.0), sharex=True,
                                      constrained_layout=True)
    for k, r in enumerate(results):
        if r.sweep is None:
            continue
        colour = f"C{k % 10}"
        s = r.sweep
        label = f"{r.label} ({r.row.get('kind', '')}, {r.row.get('tier', '')} tier)"
        ok = np.isfinite(s.range_precision_m) & (s.range_precision_m > 0)
        top.semilogy(s.received_dbm[ok], s.range_precision_m[ok], "o-", color=colour, ms=3,
                     label=label)
        bottom.plot(s.received_dbm, s.detection_probability, "o-", color=colour, ms=3)
        sens = r.row.get("sensitivity_dbm", np.nan)
        if np.isfinite(sens):
            for ax in (top, bottom):
                ax.axvline(sens, color=colour, ls=":", lw=1)
            bottom.annotate(f"{sens:.1f} dBm", (sens, 0.5), xytext=(4, -12 - 11 * k),
                            textcoords="offset points", color=colour, fontsize=8)
    top.set_ylabel("range precision (m, robust std)")
    top.grid(True, which="both", alpha=0.3)
    top.legend(fontsize=8)
    top.set_title("Instruments on one mission: precision and detection against received power")
    bottom.set_ylabel("detection probability")
    bottom.set_xlabel("received signal power (dBm; pulsed: peak)")
    bottom.set_ylim(-0.03, 1.03)
    bottom.axhline(0.5, color="grey", lw=0.8)
    bottom.grid(True, alpha=0.3)
    return save(fig, path)
