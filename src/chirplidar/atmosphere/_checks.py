"""Atmosphere-specific argument checks; the generic ones live in :mod:`chirplidar._checks`."""

from __future__ import annotations

import numpy as np

from .._checks import (
    generator,
    integer,
    non_negative,
    non_negative_array,
    positive,
    positive_array,
    real_array,
    real_scalar,
)

__all__ = [
    "cn2_array",
    "generator",
    "integer",
    "non_negative",
    "non_negative_array",
    "outer_scale",
    "path_length_array",
    "positive",
    "positive_array",
    "real_array_or_none",
    "real_scalar",
    "scalar_or_array",
    "wave_kind",
    "wavenumber",
]


def outer_scale(name: str, value) -> float:
    """A von Karman outer scale (m, or a ratio): > 0, numpy.inf allowed (Kolmogorov)."""
    v = real_scalar(name, value, allow_inf=True)
    if not v > 0.0:
        raise ValueError(f"{name} must be > 0 (numpy.inf for Kolmogorov), got {v!r}")
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


def wavenumber(wavelength_m) -> float:
    """Optical wavenumber 2 pi / lambda (rad/m) of a wavelength (m) > 0."""
    return 2.0 * np.pi / positive("wavelength_m", wavelength_m)


def scalar_or_array(x):
    """A float for a 0-d input, else the float64 array."""
    x = np.asarray(x, dtype=float)
    return float(x) if x.ndim == 0 else x


def cn2_array(cn2):
    """Refractive-index structure constant(s) Cn^2 (m^-2/3) as float64: finite and > 0."""
    c = np.asarray(cn2, dtype=float)
    if not np.all(np.isfinite(c)) or np.any(c <= 0.0):
        raise ValueError(
            "cn2 must be finite and > 0 m^-2/3 (no turbulence means r0 = inf; "
            "skip the turbulence effect instead)"
        )
    return c


def path_length_array(path_length_m):
    """Path length(s) (m) as float64: finite and > 0."""
    length = np.asarray(path_length_m, dtype=float)
    if not np.all(np.isfinite(length)) or np.any(length <= 0.0):
        raise ValueError("path_length_m must be finite and > 0 m")
    return length
