"""Coordinate frames of chirplidar and the conversions between them.

Frames
------
* **Scene (projected) frame** -- the frame of terrain, rays and outputs. ``x`` east-ish (grid
  easting), ``y`` north-ish (grid northing), ``z`` up, all in metres. ``x, y`` are the coordinates of
  a polar stereographic grid, EPSG:3413 (NSIDC Sea Ice Polar Stereographic North, Greenland; true
  scale at 70 N, central meridian -45) or EPSG:3031 (Antarctic Polar Stereographic; true scale at
  71 S). ``z`` is the height above the WGS-84 ellipsoid (not a geoid height). ``z`` is therefore
  along the local ellipsoid normal at ``(x, y)``.
* **ECEF** -- EPSG:4978, WGS-84 geocentric Cartesian, metres.
* **Geodetic** -- EPSG:4979, WGS-84 latitude, longitude (degrees) and ellipsoidal height (m).

The scene frame is **not** Euclidean. Horizontal grid distances are true distances times the
local map scale factor ``k`` (for EPSG:3413 ``k`` = 0.9699 at the pole, 1 at 70 N, 1.039 at 60 N,
pyproj ``Proj.get_factors``), vertical distances are unscaled, and a straight line in ECEF is a
curve in ``(x, y, h)`` (Earth curvature: the height along a straight chord sags by about
``L**2 / (8 R)`` for a horizontal span ``L``). Ranges are therefore never computed as a plain
Euclidean length in the scene frame. :class:`ProjectedRays` carries, per ray, the true (ECEF)
distance from the platform to the ray's scene-frame origin (``range_offset_m``) and the true
metres per scene-frame unit of length along the ray (``metres_per_unit``), so a hit found at scene
parameter ``t`` lies at true range ``range_offset_m + t * metres_per_unit``.

Satellite rays (:func:`rays_projected_from_ecef`): a ray from 500 km is converted by moving its
origin along the straight ECEF line down to an *entry height* just above the terrain, converting
that point and a second point where the ECEF line reaches a *target height* (below the terrain),
and using the chord between them as the scene-frame ray. The chord is exact at both ends
(``metres_per_unit`` is the ratio of the ECEF to the scene-frame chord length). In between, the
error is the sag of the ECEF line in ``(x, y, h)`` plus the variation of ``k`` along the chord.
With an entry height 5 km above the target height and a 2 deg off-nadir beam (horizontal span
175 m) the sag is 175**2 / (8 * 6.37e6) = 0.6 mm. Without an entry height (chord from the 500 km
origin to the ground) the sag of a 2 deg beam (span 17.5 km) is 6 m: always pass ``entry_height_m``
for satellites.

Aircraft and UAV rays (:func:`rays_projected_local`): directions are built in a true local
Cartesian frame aligned with the grid (horizontal axes along grid x, y, z up) and mapped to the
scene frame. Two modes:

* without ``target_height_m`` (flat approximation): horizontal components are scaled by ``k`` at
  the origin; ``metres_per_unit`` undoes it. Earth curvature is neglected: a surface of constant
  ellipsoidal height is flat in the scene frame but falls below the local tangent plane by
  ``L**2 / (2 R)`` at horizontal distance ``L = H tan(theta)``, so the range to the ground is
  too short by about ``(H tan theta)**2 / (2 R cos theta)``: 0 for nadir, 1.1 cm for H = 1 km at
  20 deg off nadir, 28 cm for H = 5 km at 20 deg.
* with ``target_height_m`` (exact at the chord ends): the origin goes to ECEF, the direction is expressed with the
  grid axes at the origin (grid x, grid y made orthogonal to the ellipsoid normal, i.e. the
  meridian convergence is included) and the ray is converted by
  :func:`rays_projected_from_ecef`. Use this for aircraft, or whenever cm matter off nadir.

Chord error, both ray functions: between its ends the chord departs from the true ray by at most
``L**2 / (8 R)``, ``L = (entry_height_m - target_height_m) * tan(theta)`` the horizontal span.
Keep entry and target heights tight around the terrain's relief: 1 km at 20 deg -> 2.6 mm,
5.5 km at 20 deg -> 8 cm, 5 km at 2 deg -> 0.6 mm. Ranges at the chord ends are exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from pyproj import Proj, Transformer

from chirplidar import _checks
from chirplidar.units import WGS84_A_M, WGS84_F

__all__ = [
    "SUPPORTED_EPSG",
    "WGS84_A_M",
    "WGS84_B_M",
    "WGS84_E2",
    "WGS84_F",
    "ProjectedRays",
    "checked_epsg",
    "ecef_to_geodetic",
    "ecef_to_projected",
    "enu_basis",
    "geodetic_to_ecef",
    "geodetic_to_projected",
    "grid_axes_ecef",
    "grid_convergence",
    "local_up_ecef",
    "projected_to_ecef",
    "projected_to_geodetic",
    "ray_ellipsoid_distance_m",
    "rays_projected_from_ecef",
    "rays_projected_local",
    "scale_factor",
]

#: Projected scene frames the project supports: Greenland and Antarctica polar stereographic.
SUPPORTED_EPSG = (3413, 3031)
#: WGS-84 derived constants (the defining ones are in chirplidar.units).
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

_ECEF = 4978
_GEODETIC = 4979
#: The smallest radius of curvature of the WGS-84 ellipsoid, b^2 / a (meridian at the equator),
#: less 30 km: it bounds the curvature of every surface of constant height above -30 km.
_MIN_CURVATURE_RADIUS_M = WGS84_B_M**2 / WGS84_A_M - 30e3


def checked_epsg(epsg) -> int:
    """``epsg`` as an int; ValueError unless it is one of ``SUPPORTED_EPSG``."""
    if isinstance(epsg, (bool, np.bool_)) or not isinstance(epsg, (int, np.integer)):
        raise ValueError(f"epsg must be an integer EPSG code, got {epsg!r}")  # noqa: TRY004 (project rule: ValueError)
    if int(epsg) not in SUPPORTED_EPSG:
        raise ValueError(
            f"epsg must be one of {SUPPORTED_EPSG} (polar stereographic scene frames), got {epsg}"
        )
    return int(epsg)


@cache
def _transformer(src: int, dst: int) -> Transformer:
    return Transformer.from_crs(f"EPSG:{src}", f"EPSG:{dst}", always_xy=True)


@cache
def _proj(epsg: int) -> Proj:
    return Proj(f"EPSG:{epsg}")


def _arrays(names, values):
    arrs = [_checks.real_array(n, v) for n, v in zip(names, values, strict=True)]
    try:
        return np.broadcast_arrays(*arrs)
    except ValueError:
        raise ValueError(
            f"{', '.join(names)} must have broadcastable shapes, got {[a.shape for a in arrs]}"
        ) from None


def _lat(lat):
    if np.any(np.abs(lat) > 90.0):
        raise ValueError("lat must lie in [-90, 90] degrees")
    return lat


def _transform(src, dst, a, b, c):
    t = _transformer(src, dst)
    shape = a.shape
    out = t.transform(a.ravel(), b.ravel(), c.ravel())
    return tuple(np.asarray(o, dtype=float).reshape(shape) for o in out)


def projected_to_geodetic(x, y, z, epsg):
    """Scene frame ``(x, y, z)`` [m, m, m above ellipsoid] -> ``(lat, lon, h)`` [deg, deg, m]."""
    code = checked_epsg(epsg)
    x, y, z = _arrays(("x", "y", "z"), (x, y, z))
    lon, lat, h = _transform(code, _GEODETIC, x, y, z)
    return lat, lon, h


def geodetic_to_projected(lat, lon, h, epsg):
    """``(lat, lon, h)`` [deg, deg, m above ellipsoid] -> scene frame ``(x, y, z)`` [m]."""
    code = checked_epsg(epsg)
    lat, lon, h = _arrays(("lat", "lon", "h"), (lat, lon, h))
    _lat(lat)
    return _transform(_GEODETIC, code, lon, lat, h)


def geodetic_to_ecef(lat, lon, h):
    """``(lat, lon, h)`` [deg, deg, m] -> ECEF ``(X, Y, Z)`` [m], each of the broadcast shape."""
    lat, lon, h = _arrays(("lat", "lon", "h"), (lat, lon, h))
    _lat(lat)
    return _transform(_GEODETIC, _ECEF, lon, lat, h)


def ecef_to_geodetic(x, y, z):
    """ECEF ``(X, Y, Z)`` [m] -> ``(lat, lon, h)`` [deg, deg, m above the ellipsoid]."""
    x, y, z = _arrays(("x", "y", "z"), (x, y, z))
    lon, lat, h = _transform(_ECEF, _GEODETIC, x, y, z)
    return lat, lon, h


def projected_to_ecef(xyz_m, epsg) -> np.ndarray:
    """Scene-frame points ``(..., 3)`` -> ECEF points ``(..., 3)`` [m] (one pyproj pipeline)."""
    code = checked_epsg(epsg)
    p = _xyz("xyz_m", xyz_m)
    return np.stack(_transform(code, _ECEF, p[..., 0], p[..., 1], p[..., 2]), axis=-1)


def ecef_to_projected(xyz_ecef_m, epsg) -> np.ndarray:
    """ECEF points ``(..., 3)`` -> scene-frame points ``(..., 3)`` [m] (one pyproj pipeline)."""
    code = checked_epsg(epsg)
    p = _xyz("xyz_ecef_m", xyz_ecef_m)
    return np.stack(_transform(_ECEF, code, p[..., 0], p[..., 1], p[..., 2]), axis=-1)


def _xyz(name, value) -> np.ndarray:
    a = _checks.real_array(name, value)
    if a.ndim < 1 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have a last axis of length 3, got shape {a.shape}")
    return a


def local_up_ecef(lat, lon) -> np.ndarray:
    """Unit ellipsoid normal (geodetic up) in ECEF, shape ``(..., 3)``; ``lat, lon`` in degrees."""
    lat, lon = _arrays(("lat", "lon"), (lat, lon))
    _lat(lat)
    phi, lam = np.radians(lat), np.radians(lon)
    return np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1)


def enu_basis(lat, lon) -> np.ndarray:
    """Local east, north, up unit vectors in ECEF, shape ``(..., 3, 3)``: rows east, north, up.

    ``lat, lon`` in degrees (geodetic). ``v_ecef = v_enu @ enu_basis(lat, lon)``.
    """
    lat, lon = _arrays(("lat", "lon"), (lat, lon))
    _lat(lat)
    phi, lam = np.radians(lat), np.radians(lon)
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    z = np.zeros_like(phi)
    east = np.stack([-sl, cl, z], axis=-1)
    north = np.stack([-sp * cl, -sp * sl, cp], axis=-1)
    up = np.stack([cp * cl, cp * sl, sp], axis=-1)
    return np.stack([east, north, up], axis=-2)


def scale_factor(x, y, epsg) -> np.ndarray:
    """Point scale factor ``k`` of the conformal scene projection at grid ``(x, y)`` [m]."""
    code = checked_epsg(epsg)
    x, y = _arrays(("x", "y"), (x, y))
    lat, lon, _ = projected_to_geodetic(x, y, np.zeros_like(x), code)
    f = _proj(code).get_factors(lon.ravel(), lat.ravel())
    return np.asarray(f.parallel_scale, dtype=float).reshape(x.shape)


def _ellipsoid_hit(o, d, height_m):
    """Distance along d from o to the ellipsoid with semi-axes (a + h, b + h); NaN if missed."""
    a, b = WGS84_A_M + height_m, WGS84_B_M + height_m
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    w = np.stack([1.0 / a, 1.0 / a, 1.0 / b], axis=-1)
    os, ds = o * w, d * w
    qa = np.sum(ds * ds, axis=-1)
    qb = 2.0 * np.sum(os * ds, axis=-1)
    qc = np.sum(os * os, axis=-1) - 1.0
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        # numerically stable root: q = -(b + sign(b) sq) / 2; roots q/qa and qc/q
        q = -0.5 * (qb + np.copysign(sq, qb))
        r1, r2 = q / qa, qc / q
    lo, hi = np.fmin(r1, r2), np.fmax(r1, r2)
    s = np.where(lo >= 0.0, lo, np.where(hi >= 0.0, hi, np.nan))
    return np.where(disc >= 0.0, s, np.nan)


def ray_ellipsoid_distance_m(origin_ecef, direction_ecef, height_m=0.0) -> np.ndarray:
    """Distance [m] along unit rays from ``origin_ecef`` to ellipsoidal height ``height_m``.

    First crossing in front of the origin; NaN where the ray never reaches that height. For
    ``height_m = 0`` the result is the exact ray/WGS-84 intersection (closed-form quadratic). For
    other heights it starts on the ellipsoid with semi-axes ``(a + h, b + h)`` and is refined by
    Newton steps on the geodetic height from pyproj (converged to < 1 mm).
    """
    o = _xyz("origin_ecef", origin_ecef)
    d = _unit("direction_ecef", direction_ecef)
    h = _checks.real_array("height_m", height_m)
    try:
        o, d = np.broadcast_arrays(o, d)
        h = np.broadcast_to(h, o.shape[:-1])
    except ValueError:
        raise ValueError(
            "origin_ecef, direction_ecef and height_m must have broadcastable shapes"
        ) from None
    s = _ellipsoid_hit(o, d, h)
    if np.any(h != 0.0):
        ok = np.isfinite(s)
        for _ in range(4):
            p = o + s[..., None] * d
            lat, lon, hh = ecef_to_geodetic(
                *(np.where(ok[..., None], p, o)[..., i] for i in range(3))
            )
            up = local_up_ecef(lat, lon)
            rate = np.sum(d * up, axis=-1)  # dh/ds
            with np.errstate(invalid="ignore", divide="ignore"):
                step = np.where(ok & (np.abs(rate) > 1e-12), (h - hh) / rate, 0.0)
                # Newton's error after this step is at most |h''| step^2 / (2 |h'|), and the
                # height's second derivative along a line is at most the largest curvature of
                # the ellipsoid, 1 / _MIN_CURVATURE_RADIUS_M: below 10 um the step is final.
                after = np.where(
                    ok, step * step / (2.0 * _MIN_CURVATURE_RADIUS_M * np.abs(rate)), 0.0
                )
            s = s + step
            if np.all(after < 1e-5):
                break
    return s


def _unit(name, value) -> np.ndarray:
    d = _xyz(name, value)
    n = np.linalg.norm(d, axis=-1)
    if np.any(np.abs(n - 1.0) > 1e-6):
        raise ValueError(f"{name} must be unit vectors (|d| = 1 within 1e-6)")
    return d / n[..., None]


@dataclass(frozen=True)
class ProjectedRays:
    """Rays in the scene (projected) frame with the bookkeeping for true ranges.

    origin_m : (..., 3) scene-frame ray origins [m].
    direction : (..., 3) scene-frame unit directions.
    range_offset_m : (...) true distance [m] from the platform to ``origin_m``.
    metres_per_unit : (...) true metres per scene-frame metre along ``direction``.
    valid : (...) bool, False where the ECEF ray never reaches the target height (upward or
        missing the Earth). Such rays stay finite (origin at the platform, direction straight up
        (0, 0, 1), offset 0, 1 m per unit) so a ray caster accepts them, and their
        :meth:`range_m` is ``inf`` (no return), like a miss.
    """

    origin_m: np.ndarray
    direction: np.ndarray
    range_offset_m: np.ndarray
    metres_per_unit: np.ndarray
    valid: np.ndarray

    def range_m(self, t_m) -> np.ndarray:
        """True range [m] to ``origin_m + t_m * direction``; ``t_m = inf`` (miss) gives inf."""
        t = np.asarray(t_m, dtype=float)
        with np.errstate(invalid="ignore"):
            r = self.range_offset_m + t * self.metres_per_unit
        return np.where(self.valid, r, np.inf)

    def range_to_points_m(self, points_m) -> np.ndarray:
        """True range [m] to scene-frame points ``(..., 3)`` lying on the rays (e.g. hits)."""
        p = np.asarray(points_m, dtype=float)
        with np.errstate(invalid="ignore"):
            t = np.sum((p - self.origin_m) * self.direction, axis=-1)
        return self.range_m(np.where(np.isfinite(t), t, np.inf))


def _ray_arrays(origin_name: str, origin, direction_name: str, direction):
    """Validated (..., 3) origins and unit directions, broadcast against each other."""
    o = _xyz(origin_name, origin)
    d = _unit(direction_name, direction)
    try:
        return np.broadcast_arrays(o, d)
    except ValueError:
        raise ValueError(
            f"{origin_name} and {direction_name} must have broadcastable shapes"
        ) from None


def rays_projected_from_ecef(
    origin_ecef, direction_ecef, epsg, *, target_height_m, entry_height_m=None, origin_m=None
) -> ProjectedRays:
    """Convert ECEF rays (e.g. from a satellite) into scene-frame rays.

    origin_ecef, direction_ecef : (..., 3) ECEF origins [m] and unit directions.
    target_height_m : ellipsoidal height [m] the second chord point is placed at; choose it below
        the lowest terrain of the scene (the chord is exact only between its two ends).
    entry_height_m : ellipsoidal height [m] the scene-frame origin is moved to (for origins above
        it); choose it just above the highest terrain. ``None`` keeps the ECEF origin (fine for
        aircraft altitudes, see the module docstring for the error at 500 km).
    origin_m : optional scene-frame coordinates of the origins, when the caller has them (the
        same points as ``origin_ecef``): their heights and, for rays whose chord starts at the
        origin, the chord's first end are taken from them instead of being converted.

    The scene-frame direction is the chord from the entry point to the target point (both
    converted exactly with pyproj); ``range_offset_m`` is the true ECEF distance from the origin to
    the entry point, ``metres_per_unit`` the ratio of the chord's ECEF to scene-frame length. Rays
    that never descend to ``target_height_m`` get ``valid = False`` (finite placeholder rays
    pointing up whose ``range_m`` is inf).
    """
    code = checked_epsg(epsg)
    o, d = _ray_arrays("origin_ecef", origin_ecef, "direction_ecef", direction_ecef)
    shape = o.shape[:-1]
    h_t = _checks.real_scalar("target_height_m", target_height_m)
    s_target = ray_ellipsoid_distance_m(o, d, np.full(shape, h_t))
    q0 = None if origin_m is None else np.broadcast_to(_xyz("origin_m", origin_m), o.shape)
    s_entry = np.zeros(shape)
    if entry_height_m is not None:
        h_e = _checks.real_scalar("entry_height_m", entry_height_m)
        if h_e <= h_t:
            raise ValueError(f"entry_height_m ({h_e}) must be above target_height_m ({h_t})")
        h0 = ecef_to_geodetic(o[..., 0], o[..., 1], o[..., 2])[2] if q0 is None else q0[..., 2]
        above = h0 > h_e
        if np.any(above):
            s_entry[above] = ray_ellipsoid_distance_m(o[above], d[above], h_e)
    valid = np.isfinite(s_target) & np.isfinite(s_entry) & (s_target > s_entry)
    s0 = np.where(valid, s_entry, 0.0)
    s1 = np.where(valid, s_target, 1.0)
    q1 = ecef_to_projected(o + s1[..., None] * d, code)
    if q0 is None:
        q0 = ecef_to_projected(o + s0[..., None] * d, code)
    else:  # chords that start at the origin keep the caller's coordinates
        q0 = q0.copy()
        moved = s0 != 0.0
        if np.any(moved):
            q0[moved] = ecef_to_projected(o[moved] + s0[moved, None] * d[moved], code)
    chord = q1 - q0
    length = np.linalg.norm(chord, axis=-1)
    up = np.array([0.0, 0.0, 1.0])
    v = valid[..., None]
    direction = np.where(v, chord / np.where(length > 0, length, 1.0)[..., None], up)
    mpu = np.where(valid, (s1 - s0) / np.where(length > 0, length, 1.0), 1.0)
    return ProjectedRays(q0, direction, np.where(valid, s0, 0.0), mpu, valid)


@cache
def _polar_aspect(epsg: int) -> tuple[float, float]:
    """(central meridian [deg], +1 north / -1 south pole) of a polar stereographic scene frame,
    read from pyproj's definition of the CRS."""
    operation = _proj(epsg).crs.coordinate_operation
    if operation is None:
        raise ValueError(f"EPSG:{epsg} has no projection parameters")
    params = {p.name: p.value for p in operation.params}
    return (
        float(params["Longitude of origin"]),
        float(np.sign(params["Latitude of standard parallel"])),
    )


def grid_convergence(lon, epsg) -> tuple[np.ndarray, np.ndarray]:
    """(cos, sin) of the angle from true north to grid north at longitudes ``lon`` [deg].

    A polar stereographic grid's meridians are straight lines through the pole (Snyder 1987,
    *Map Projections: A Working Manual*, eqs. 21-30, 21-31), so grid north is true north turned
    by ``s (lon - lon_0)``, clockwise positive; ``s = +1`` for a north, ``-1`` for a south
    polar aspect. The grid axes in true east, north components are then ``x = (cos, -sin)``,
    ``y = (sin, cos)``; conformal, so they are exactly orthogonal.
    """
    lon0, sign = _polar_aspect(checked_epsg(epsg))
    gamma = sign * np.radians(np.asarray(lon, dtype=float) - lon0)
    return np.cos(gamma), np.sin(gamma)


def grid_axes_ecef(origin_m, epsg):
    """ECEF position and unit grid-x, grid-y and up axes at scene-frame points ``(..., 3)``.

    The position is one pyproj conversion; the axes are the local east and north turned by the
    grid convergence (:func:`grid_convergence`), orthogonal to the ellipsoid normal and to each
    other to rounding. Returns ``(origin_ecef, ex, ey, up)``, each ``(..., 3)``.
    """
    code = checked_epsg(epsg)
    o = _xyz("origin_m", origin_m)
    lat, lon, h = projected_to_geodetic(o[..., 0], o[..., 1], o[..., 2], code)
    origin_ecef = np.stack(geodetic_to_ecef(lat, lon, h), axis=-1)
    east, north, up = np.moveaxis(enu_basis(lat, lon), -2, 0)
    c, s = (a[..., None] for a in grid_convergence(lon, code))
    return origin_ecef, c * east - s * north, s * east + c * north, up


def rays_projected_local(
    origin_m, direction_true, epsg, *, target_height_m=None, entry_height_m=None, axes=None
) -> ProjectedRays:
    """Scene-frame rays from origins in the scene frame and directions in true local metres.

    origin_m : (..., 3) scene-frame origins [m] (aircraft, UAV).
    direction_true : (..., 3) unit directions in the true local Cartesian frame whose axes are
        grid x, grid y and up at the origin (angles in it are true angles, e.g. a 20 deg
        off-nadir beam).
    target_height_m, entry_height_m : if ``target_height_m`` is given the conversion is exact
        (via ECEF, see the module docstring and :func:`rays_projected_from_ecef`); otherwise the
        flat approximation: horizontal components scaled by the scale factor ``k`` at the origin,
        ``metres_per_unit`` converting scene-frame lengths back to true metres.
    axes : optional ``grid_axes_ecef`` of the origins, already computed (e.g. once per shot for
        its beams; broadcastable to the origins' shape): the same values, not computed again.
    """
    code = checked_epsg(epsg)
    o, d = _ray_arrays("origin_m", origin_m, "direction_true", direction_true)
    if target_height_m is not None:
        o_ecef, ex, ey, up = (
            grid_axes_ecef(o, code) if axes is None else (np.broadcast_to(a, o.shape) for a in axes)
        )
        d_ecef = d[..., :1] * ex + d[..., 1:2] * ey + d[..., 2:] * up
        d_ecef = d_ecef / np.linalg.norm(d_ecef, axis=-1, keepdims=True)
        return rays_projected_from_ecef(
            o_ecef,
            d_ecef,
            code,
            target_height_m=target_height_m,
            entry_height_m=entry_height_m,
            origin_m=o,
        )
    k = scale_factor(o[..., 0], o[..., 1], code)
    dp = np.concatenate([d[..., :2] * k[..., None], d[..., 2:]], axis=-1)
    n = np.linalg.norm(dp, axis=-1)
    shape = o.shape[:-1]
    return ProjectedRays(
        o.copy(), dp / n[..., None], np.zeros(shape), 1.0 / n, np.ones(shape, dtype=bool)
    )
