"""Conventions the plan view (:mod:`chirplidar.viz.planmap`) and the 3-D view
(:mod:`chirplidar.viz.scene3d`) share: the categorical colours of flag variables, the colour
range of continuous values, colour-bar labels, and a bounds box in projected metres."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DETECTED_COLORS", "FLAG_COLORS", "check_bounds_m", "colour_range", "units_label"]

# Categorical colours of flag variables; `detected` gets fixed, meaningful ones.
DETECTED_COLORS = {0: "#e66101", 1: "#1a9641", 2: "#5e3c99"}
FLAG_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
               "#17becf", "#bcbd22", "#7f7f7f")


def colour_range(finite: np.ndarray, symmetric: bool = True) -> tuple[float, float]:
    """(lo, hi) of a colour scale for finite values: the 1st-99th percentile for >= 100 values
    (outliers saturate), else the min-max. A degenerate percentile range falls back to the
    min-max (a count grid of mostly empty cells has percentiles 0..0: its counts must still be
    told apart); an all-equal field gets +-5 % around its value (0..1 for zeros), a range that
    holds the value. With ``symmetric`` the range is widened symmetric about 0 only when it
    straddles 0, i.e. when the values take both signs: non-negative values (counts, gaps,
    precisions) never get a range below 0, so never a diverging map (decibels pass
    ``symmetric=False``: 0 dB is no special value). Shared by the 3-D and plan views."""
    vmin, vmax = float(finite.min()), float(finite.max())
    lo, hi = vmin, vmax
    if finite.size >= 100:
        p_lo, p_hi = (float(v) for v in np.percentile(finite, [1.0, 99.0]))
        if p_hi > p_lo:
            lo, hi = p_lo, p_hi
    if hi <= lo:
        if lo == 0.0:
            return 0.0, 1.0
        pad = 0.05 * abs(lo)
        return lo - pad, lo + pad
    if symmetric and lo < 0.0 < hi:
        m = max(-lo, hi)
        lo, hi = -m, m
    return lo, hi

def units_label(long_name: str, units) -> str:
    """Colour-bar label "long_name (units)"; no brackets for dimensionless units ("1", "")."""
    units = "" if units is None else str(units).strip()
    return long_name if units in ("", "1") else f"{long_name} ({units})"

def check_bounds_m(bounds, name: str = "bounds") -> tuple[float, float, float, float]:
    """``(xmin, ymin, xmax, ymax)`` as floats (projected metres): four finite numbers with
    xmin < xmax and ymin < ymax, else ValueError naming ``name``."""
    try:
        if isinstance(bounds, (str, bytes)):
            raise TypeError
        values = tuple(float(v) for v in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected four numbers XMIN, YMIN, XMAX, YMAX (projected "
                         f"metres), got {bounds!r}") from None
    if len(values) != 4:
        raise ValueError(f"{name}: expected four numbers XMIN, YMIN, XMAX, YMAX (projected "
                         f"metres), got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name}: XMIN, YMIN, XMAX, YMAX must be finite, got "
                         f"{', '.join(f'{v:g}' for v in values)}")
    xmin, ymin, xmax, ymax = values
    if xmin >= xmax or ymin >= ymax:
        raise ValueError(f"{name}: need XMIN < XMAX and YMIN < YMAX, got x {xmin:g} .. {xmax:g},"
                         f" y {ymin:g} .. {ymax:g}")
    return values
