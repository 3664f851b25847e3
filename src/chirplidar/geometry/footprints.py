"""Beam footprints: a beam of finite divergence as a deterministic Fibonacci (golden-angle) spiral
of sub-rays with Gaussian weights exp(-2 theta^2/theta_d^2), and per-shot statistics of their
hits on a :class:`~chirplidar.geometry.terrain.Terrain` (:func:`.raycast.cast_rays`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .raycast import GOLDEN_ANGLE_RAD, cast_rays, validated_rays
from .terrain import Terrain

__all__ = [
    "FootprintStats",
    "footprint_statistics",
    "footprint_subrays",
    "subray_pattern",
    "weighted_range_stats",
]


@dataclass(frozen=True)
class FootprintStats:
    """Per-shot statistics over a beam's sub-rays (weights renormalised over the hits).

    Shots with no hit: range_mean_m, range_std_m, range_spread_m, incidence_mean_rad are inf and
    material_code is -1; hit_fraction is 0.
    """

    range_mean_m: np.ndarray  # weighted mean range of hitting sub-rays (m)
    range_std_m: np.ndarray  # weighted standard deviation of range (m)
    range_spread_m: np.ndarray  # max - min range of hitting sub-rays (m)
    incidence_mean_rad: np.ndarray  # weighted mean incidence (rad)
    material_code: np.ndarray  # weight-majority material code (-1 if no hit)
    hit_fraction: np.ndarray  # fraction of the beam's weight that hits terrain, [0, 1]


def _perpendicular_basis(d):
    """Two unit vectors e1, e2 with (e1, e2, d) orthonormal, for every row of unit d."""
    ref = np.where((np.abs(d[:, 2]) < 0.9)[:, None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    e1 = np.cross(ref, d)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(d, e1)
    return e1, e2


def subray_pattern(n_sub: int, extent_rad: float):
    """Fibonacci (golden-angle) spiral of n_sub angular offsets filling a disk of radius
    extent_rad: theta_k proportional to sqrt(k + 1/2), scaled so the outermost sub-ray sits
    exactly on the edge (theta = extent_rad); phi_k = k * golden angle. Returns (theta, phi).
    """
    k = np.arange(n_sub, dtype=np.float64)
    r = np.sqrt((k + 0.5) / n_sub)
    r = r / r[-1]
    return extent_rad * r, k * GOLDEN_ANGLE_RAD


def footprint_subrays(
    origins,
    directions,
    divergence_half_angle_rad,
    n_sub: int,
    rng=None,
    *,
    extent_factor: float = 1.0,
):
    """Sub-rays over a beam's divergence cone with Gaussian weights.

    divergence_half_angle_rad: 1/e^2 intensity half-angle theta_d of the beam (rad, > 0).
    The pattern is a Fibonacci spiral out to theta_max = extent_factor * theta_d (the
    outermost sub-ray exactly at theta_max); its ground footprint diameter is
    2 R tan(theta_max) at range R. Weights w = exp(-2 theta^2 / theta_d^2) (Gaussian beam
    intensity), normalised to sum 1 per shot. With ``rng`` (a numpy Generator) each shot's
    pattern is rotated by a random azimuth; without it the pattern is deterministic.

    Returns (origins (n*n_sub, 3), directions (n*n_sub, 3), weights (n, n_sub)); sub-rays of
    shot i are rows i*n_sub ... (i+1)*n_sub - 1.
    """
    o, d = validated_rays(origins, directions)
    th_d = float(divergence_half_angle_rad)
    if not np.isfinite(th_d) or th_d <= 0 or th_d >= np.pi / 4:
        raise ValueError(
            f"divergence_half_angle_rad must lie in (0, pi/4), got {divergence_half_angle_rad!r}"
        )
    if isinstance(n_sub, (bool, np.bool_)) or int(n_sub) != n_sub or n_sub < 1:
        raise ValueError(f"n_sub must be a positive integer, got {n_sub!r}")
    n_sub = int(n_sub)
    if not (np.isfinite(extent_factor) and extent_factor > 0):
        raise ValueError(f"extent_factor must be > 0, got {extent_factor!r}")
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator or None, got {type(rng)!r}")
    n = o.shape[0]
    if n_sub == 1:
        theta, phi = np.zeros(1), np.zeros(1)
    else:
        theta, phi = subray_pattern(n_sub, extent_factor * th_d)
    if rng is not None:
        phi = phi + rng.uniform(0.0, 2 * np.pi, n)[:, None]
    cp, sp = np.broadcast_to(np.cos(phi), (n, n_sub)), np.broadcast_to(np.sin(phi), (n, n_sub))
    e1, e2 = _perpendicular_basis(d)
    st, ct = np.sin(theta)[None, :, None], np.cos(theta)[None, :, None]
    sub = ct * d[:, None, :] + st * (
        cp[..., None] * e1[:, None, :] + sp[..., None] * e2[:, None, :]
    )
    w = np.exp(-2.0 * theta**2 / th_d**2)
    w = np.broadcast_to(w / w.sum(), (n, n_sub)).copy()
    return (np.repeat(o, n_sub, axis=0), sub.reshape(n * n_sub, 3), w)


def weighted_range_stats(weights, ranges_m):
    """Weighted mean and standard deviation of ranges over the last axis.

    weights (..., k) >= 0, zero for sub-rays that missed (their ranges may be inf); ranges_m
    (..., k). Returns (mean, std, total weight), each (...); mean and std are NaN where the
    total weight is 0.
    """
    tot = weights.sum(axis=-1)
    ok = tot > 0
    w = weights / np.where(ok, tot, 1.0)[..., None]
    r = np.where(weights > 0, ranges_m, 0.0)
    mean = np.sum(w * r, axis=-1)
    var = np.sum(w * (r - mean[..., None]) ** 2, axis=-1)
    return np.where(ok, mean, np.nan), np.where(ok, np.sqrt(var), np.nan), tot


def footprint_statistics(
    terrain: Terrain,
    origins,
    directions,
    divergence_half_angle_rad,
    n_sub: int,
    rng=None,
    *,
    extent_factor: float = 1.0,
) -> FootprintStats:
    """Per-shot statistics of a beam's sub-ray hits (see ``footprint_subrays``); vectorised.

    Mean, standard deviation and mean incidence are weighted by the Gaussian sub-ray weights
    renormalised over hitting sub-rays; the material is the one carrying most hit weight;
    hit_fraction is the hitting share of the beam weight.
    """
    so, sd, w = footprint_subrays(
        origins, directions, divergence_half_angle_rad, n_sub, rng, extent_factor=extent_factor
    )
    n, m = w.shape
    hits = cast_rays(terrain, so, sd)
    hit = hits.hit.reshape(n, m)
    wh = np.where(hit, w, 0.0)
    mean, std, frac = weighted_range_stats(wh, hits.ranges_m.reshape(n, m))
    anyhit = frac > 0
    wn = wh / np.where(anyhit, frac, 1.0)[:, None]
    r = np.where(hit, hits.ranges_m.reshape(n, m), 0.0)
    inc = np.where(hit, hits.incidence_rad.reshape(n, m), 0.0)
    rmax = np.max(np.where(hit, r, -np.inf), axis=1)
    rmin = np.min(np.where(hit, r, np.inf), axis=1)
    inc_mean = np.sum(wn * inc, axis=1)
    n_mat = len(terrain.material_names)
    codes = hits.material_codes.reshape(n, m)
    shot = np.broadcast_to(np.arange(n)[:, None], (n, m))
    per = np.bincount(
        (shot * n_mat + np.maximum(codes, 0))[hit], weights=wh[hit], minlength=n * n_mat
    ).reshape(n, n_mat)
    mat = np.where(anyhit, np.argmax(per, axis=1), -1).astype(np.int32)
    inf = np.inf
    return FootprintStats(
        range_mean_m=np.where(anyhit, mean, inf),
        range_std_m=np.where(anyhit, std, inf),
        range_spread_m=np.where(anyhit, rmax - np.where(anyhit, rmin, 0.0), inf),
        incidence_mean_rad=np.where(anyhit, inc_mean, inf),
        material_code=mat,
        hit_fraction=np.clip(frac, 0.0, 1.0),
    )
