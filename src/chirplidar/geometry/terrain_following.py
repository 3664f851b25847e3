"""Flyable terrain following: the lowest flight profile above a minimum clearance that respects a
platform's climb and descent rate limits.

Following the ground exactly ("above_ground" platforms) implies vertical speeds no fixed-wing UAV
flies over steep ice-sheet margins; :func:`flyable_profile` replaces it by the lowest profile the
aircraft can actually fly, and :func:`profile_report` gives the resulting height-above-ground and
vertical-rate ranges.
"""

from __future__ import annotations

import numpy as np

from .._checks import positive, real_array

__all__ = ["flyable_profile", "profile_report"]


def _path_arrays(distance_m, ground_m) -> tuple[np.ndarray, np.ndarray]:
    """Validated (n,) float arrays: finite, same shape, distance strictly increasing."""
    d = real_array("distance_m", distance_m)
    g = real_array("ground_m", ground_m)
    if d.ndim != 1 or d.size < 1:
        raise ValueError(f"distance_m must be a non-empty 1-D array, got shape {d.shape}")
    if g.shape != d.shape:
        raise ValueError(f"ground_m must have the shape of distance_m {d.shape}, got {g.shape}")
    if np.any(np.diff(d) <= 0.0):
        raise ValueError("distance_m must be strictly increasing")
    return d, g


def flyable_profile(
    distance_m, ground_m, clearance_m, speed_mps, max_climb_mps, max_descent_mps
) -> np.ndarray:
    """The lowest flyable flight heights over a terrain profile [m].

    Parameters
    ----------
    distance_m : (n,) array
        Along-path distance of the samples [m], strictly increasing.
    ground_m : (n,) array
        Terrain height at the samples [m] (any vertical datum; the result uses the same one).
    clearance_m : float
        Minimum height above ground [m], > 0. The profile never goes below it.
    speed_mps : float
        Horizontal speed [m/s], > 0; turns the rate limits into slope limits.
    max_climb_mps, max_descent_mps : float
        Largest climb and descent rates [m/s], both > 0.

    Returns
    -------
    z : (n,) array
        Flight heights [m], the pointwise lowest profile with ``z_i >= ground_i + clearance_m``
        and, between consecutive samples, ``-s_d <= (z_{i+1} - z_i) / (d_{i+1} - d_i) <= s_c``
        where ``s_c = max_climb_mps / speed_mps`` and ``s_d = max_descent_mps / speed_mps``.

    Notes
    -----
    With the lower bound ``L = ground + clearance`` the answer is the max-plus envelope

        z_i = max_j (L_j - c(d_i - d_j)),   c(x) = s_d * x for x >= 0,  c(x) = -s_c * x for x < 0,

    computed in two O(n) passes without a Python loop:

    * forward (descent limit), ``F_i = max_{j<=i} (L_j - s_d (d_i - d_j))
      = cummax(L + s_d d)_i - s_d d_i``;
    * backward (climb limit), ``B_i = max_{j>=i} (L_j - s_c (d_j - d_i))
      = revcummax(L - s_c d)_i + s_c d_i``;

    and ``z = max(F, B)``. Proof of optimality: for any feasible profile y and j <= i, the
    descent limit gives ``y_i >= y_j - s_d (d_i - d_j) >= L_j - s_d (d_i - d_j)``, so y >= F;
    for j >= i the climb limit gives ``y_j <= y_i + s_c (d_j - d_i)`` hence
    ``y_i >= L_j - s_c (d_j - d_i)``, so y >= B. Thus every feasible profile lies on or above z.
    Conversely z is feasible: z >= L (j = i terms), and each term ``L_j - c(d - d_j)`` is linear
    on every interval between samples with slope s_c or -s_d, so each satisfies the slope limits
    and so does their pointwise maximum. Hence z is the lowest feasible profile.

    Examples
    --------
    A 40 m step at 500 m, flown at 25 m/s with 5 m/s climb (slope 0.2): the climb starts
    40 / 0.2 = 200 m before the step.

    >>> d = np.arange(0.0, 1001.0, 100.0)
    >>> g = np.where(d >= 500.0, 40.0, 0.0)
    >>> flyable_profile(d, g, 100.0, 25.0, 5.0, 2.5)[:6].tolist()
    [100.0, 100.0, 100.0, 100.0, 120.0, 140.0]
    """
    d, g = _path_arrays(distance_m, ground_m)
    clearance = positive("clearance_m", clearance_m)
    speed = positive("speed_mps", speed_mps)
    s_climb = positive("max_climb_mps", max_climb_mps) / speed
    s_desc = positive("max_descent_mps", max_descent_mps) / speed

    lower = g + clearance
    # Distances from the first sample keep the cone terms small, limiting round-off.
    x = d - d[0]
    forward = np.maximum.accumulate(lower + s_desc * x) - s_desc * x
    backward = np.maximum.accumulate((lower - s_climb * x)[::-1])[::-1] + s_climb * x
    # The outer maximum with `lower` only removes sub-ulp round-off below the clearance.
    return np.maximum(np.maximum(forward, backward), lower)


def profile_report(distance_m, ground_m, z_m, speed_mps) -> dict:
    """Actual clearance and vertical-rate ranges of a flight profile.

    Parameters
    ----------
    distance_m, ground_m : (n,) arrays
        Along-path distance [m] (strictly increasing) and terrain height [m].
    z_m : (n,) array
        Flight heights [m], same datum as ``ground_m``.
    speed_mps : float
        Horizontal speed [m/s], > 0.

    Returns
    -------
    dict
        ``min_clearance_m`` and ``max_clearance_m``: range of ``z - ground`` [m];
        ``max_climb_mps`` and ``max_descent_mps``: largest climb and descent rates between
        consecutive samples [m/s], both >= 0 (0 when the profile never climbs or descends, or
        has a single sample).
    """
    d, g = _path_arrays(distance_m, ground_m)
    z = real_array("z_m", z_m)
    if z.shape != d.shape:
        raise ValueError(f"z_m must have the shape of distance_m {d.shape}, got {z.shape}")
    speed = positive("speed_mps", speed_mps)
    clearance = z - g
    rate = np.diff(z) / np.diff(d) * speed  # vertical speed [m/s], + up
    return {
        "min_clearance_m": float(clearance.min()),
        "max_clearance_m": float(clearance.max()),
        "max_climb_mps": float(max(rate.max(initial=0.0), 0.0)),
        "max_descent_mps": float(max((-rate).max(initial=0.0), 0.0)),
    }
