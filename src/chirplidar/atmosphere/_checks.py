"""Atmosphere-specific argument checks; the generic ones live in :mod:`chirplidar._checks`."""

from __future__ import annotations

import numbers

import numpy as np

from .._checks import (
    generator,
    non_negative,
    non_negative_array,
    positive,
    positive_array,
    real_array,
    real_scalar,
)

__all__ = [
    "generator",
    "integer",
    "non_negative",
    "non_negative_array",
    "outer_scale",
    "positive",
    "positive_array",
    "real_array_or_none",
    "real_scalar",
    "wave_kind",
]


def outer_scale(name: str, value) -> float:
    """A von Karman outer scale (m, or a ratio): > 0, numpy.inf allowed (Kolmogorov)."""
    v = real_scalar(name, value, allow_inf=True)
    if not v > 0.0:
        raise ValueError(f"{name} must be > 0 (numpy.inf for Kolmogorov), got {v!r}")
    return v


def integer(name: str, value, minimum: int) -> int:
    """An integer >= ``minimum`` (grid sizes, sample counts, levels)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if v < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {v}")
    return v


def wave_kind(value) -> str:
    if value not in ("plane", "spherical"):
        raise ValueError(f"wave must be 'plane' or 'spherical', got {value!r}")
    return value


def real_array_or_none(name: str, value):
    """None passes through; anything else must be a finite real array (float64)."""
    if value is None:
        return None
    return real_array(name, value)
