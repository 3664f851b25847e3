"""Atmospheric transmission (extinction by absorption and scattering), power and field.

The thesis parameter ``atm.T_atm`` (Table 4.6) is a *one-way field* transmission: the one-way power
transmission is T_atm^2 and a monostatic round trip T_atm^4 (as in ``channel.lab``). An
extinction coefficient alpha (1/m, power) gives the Beer-Lambert one-way power transmission
exp(-alpha L) over a path of length L.
"""

from __future__ import annotations

import numpy as np

from ._checks import non_negative_array, real_array_or_none


def beer_lambert_transmission(extinction_per_m, path_length_m):
    """One-way power transmission exp(-alpha L) (W/W) for extinction alpha (1/m) over L (m).

    Float for scalar inputs, else float64 array of the broadcast shape.
    """
    alpha = non_negative_array("extinction_per_m", extinction_per_m)
    length = non_negative_array("path_length_m", path_length_m)
    out = np.exp(-alpha * length)
    return float(out) if out.ndim == 0 else out


def one_way_power_transmission(*, t_atm_field=None, extinction_per_m=None, path_length_m=None):
    """One-way power transmission (W/W) from exactly one source:

    * ``t_atm_field``: the thesis ``atm.T_atm`` (one-way field transmission in [0, 1]) -> T^2;
    * ``extinction_per_m`` and ``path_length_m``: Beer-Lambert exp(-alpha L).
    """
    t = real_array_or_none("t_atm_field", t_atm_field)
    if t is not None:
        if extinction_per_m is not None or path_length_m is not None:
            raise ValueError(
                "give either t_atm_field or extinction_per_m with path_length_m, not both"
            )
        if np.any((t < 0.0) | (t > 1.0)):
            raise ValueError("t_atm_field must lie in [0, 1] (one-way field transmission)")
        out = t * t
        return float(out) if out.ndim == 0 else out
    if extinction_per_m is None or path_length_m is None:
        raise ValueError("give t_atm_field, or both extinction_per_m and path_length_m")
    return beer_lambert_transmission(extinction_per_m, path_length_m)


def round_trip_power_transmission(*, t_atm_field=None, extinction_per_m=None, path_length_m=None):
    """Round-trip (monostatic) power transmission: the square of ``one_way_power_transmission``."""
    one = np.asarray(
        one_way_power_transmission(
            t_atm_field=t_atm_field, extinction_per_m=extinction_per_m, path_length_m=path_length_m
        )
    )
    out = one * one
    return float(out) if out.ndim == 0 else out
