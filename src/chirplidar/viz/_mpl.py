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

from ..units import power_dbm  # noqa: E402


def finite_or_nan(values) -> np.ndarray:
    """Float array with every non-finite value (±inf, e.g. dB of zero power) replaced by NaN.

    Matplotlib leaves gaps at NaN; -inf would stretch the axes or be silently dropped.
    """
    arr = np.array(values, dtype=float, copy=True)
    arr[~np.isfinite(arr)] = np.nan
    return arr


def dbm_from_w(power_w) -> np.ndarray:
    """dBm of power in W for plotting: zero power (-inf dBm) becomes NaN, a gap in the line."""
    return finite_or_nan(power_dbm(power_w))


def save(fig, path: str | Path) -> Path:
    """Write ``fig`` to ``path`` (parent folders created), close it, return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
