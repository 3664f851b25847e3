"""Optics-specific argument checks; the generic ones live in :mod:`chirplidar._checks`."""

from __future__ import annotations

import numbers

import numpy as np

from .._checks import finite_array, non_negative_array, positive, positive_array, real_scalar

__all__ = [
    "finite_array",
    "non_negative_array",
    "positive",
    "positive_array",
    "real_scalar",
    "obstruction_ratio",
    "grid_size",
    "square_field",
]


def obstruction_ratio(value, name: str = "obstruction") -> float:
    """Central obstruction ratio alpha = d_secondary / D in [0, 1)."""
    v = real_scalar(name, value)
    if not 0.0 <= v < 1.0:
        raise ValueError(
            f"{name} (central obstruction diameter / aperture diameter) must be in "
            f"[0, 1), got {v!r}"
        )
    return v


def grid_size(value, name: str = "n", minimum: int = 16) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Integral,)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if v < minimum:
        raise ValueError(f"{name} must be >= {minimum} samples across the aperture, got {v}")
    return v


def square_field(name: str, value, dtype=complex) -> np.ndarray:
    """An array of shape (..., n, n) with n >= 2."""
    arr = finite_array(name, value, dtype)
    if arr.ndim < 2 or arr.shape[-1] != arr.shape[-2] or arr.shape[-1] < 2:
        raise ValueError(f"{name} must have shape (..., n, n) with n >= 2, got {arr.shape}")
    return arr
