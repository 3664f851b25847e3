"""Shared matplotlib setup: a non-interactive backend and dB helpers for plotting."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import matplotlib

# Plots are written to files. Select Agg unless pyplot is already in use with an interactive
# backend (e.g. inside a notebook), so that importing viz never pops up or breaks a GUI session.
if "matplotlib.pyplot" not in sys.modules and not os.environ.get("MPLBACKEND"):
    matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def finite_or_nan(values) -> np.ndarray:
    """Float array with every non-finite value (±inf, e.g. dB of zero power) replaced by NaN.

    Matplotlib leaves gaps at NaN; -inf would stretch the axes or be silently dropped.
    """
    arr = np.array(values, dtype=float, copy=True)
    arr[~np.isfinite(arr)] = np.nan
    return arr


def dbm_from_w(power_w) -> np.ndarray:
    """dBm of power in W; zero or negative power gives NaN (a gap in a plot), never a warning."""
    p = np.asarray(power_w, dtype=float)
    out = np.full(p.shape, np.nan)
    pos = p > 0
    out[pos] = 10.0 * np.log10(p[pos]) + 30.0
    return out


def save(fig, path: str | Path) -> Path:
    """Write ``fig`` to ``path`` (parent folders created), close it, return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
