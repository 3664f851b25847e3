"""Platforms, trajectories, attitude and beam patterns; per-shot platform geometry.

Trajectories
------------
* :class:`UavPath` and :class:`AircraftLines` live in the scene (projected) frame of
  :mod:`chirplidar.geometry.frames` (``frame = "projected"``): x, y grid metres, z ellipsoidal
  height. Their time origin ``t_s = 0`` is the start of the path. Speeds are along-path speeds in
  scene-frame metres per second (the map scale factor k, |k - 1| < 4 % over Greenland, is
  neglected for the speed; ray geometry and ranges correct for it, see ``frames``).
* :class:`KeplerOrbit` and :class:`TleOrbit` give ECEF states (``frame = "ecef"``).

Time and Earth rotation (KeplerOrbit): ``t_s`` is seconds on the same scale as ``epoch_s``. The
ECI frame is an inertial frame whose z axis is the Earth's rotation axis; the ECI -> ECEF rotation
angle is the linear model ``theta(t) = gmst_at_epoch_rad + OMEGA_EARTH_RAD_S * (t - epoch_s)``
(no precession, nutation, polar motion or UT1-UTC; ECI = ECEF at epoch by default). This is
adequate for shot geometry over a scene, not for absolute astronomy.

Beams and attitude
------------------
Body frame: x forward (horizontal flight direction), y right, z down (nadir). A beam is an
``(off_nadir_rad, azimuth_rad)`` pair: off-nadir angle from body z, azimuth measured from body x
toward body y (0 = forward, +pi/2 = right of track). Attitude is applied as intrinsic Z-Y-X
rotations ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (positive roll = right wing down, so a nadir beam
looks left; positive pitch = nose up, a nadir beam looks forward; positive yaw = nose right).
Pointing jitter (optional, seeded generator) tilts each beam by independent normal angles of
``jitter_rad_rms`` about two axes perpendicular to it (total angular rms ``sqrt(2)`` times that).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Polygon, box

from chirplidar import _checks
from chirplidar.doppler import earth_rotation_velocity_mps
from chirplidar.geometry import frames
from chirplidar.units import OMEGA_EARTH_RAD_S, WGS84_A_M

__all__ = [
    "J2_EARTH",
    "MU_EARTH_M3_S2",
    "OMEGA_EARTH_RAD_S",
    "R_EARTH_M",
    "AircraftLines",
    "Attitude",
    "BeamPattern",
    "KeplerOrbit",
    "ShotGeometry",
    "TleOrbit",
    "UavPath",
    "beam_directions",
    "conical_scan",
    "lawnmower",
    "lawnmower_lines",
    "lawnmower_width",
    "nadir_beam",
    "paired_beams_across_track",
    "shot_geometry",
    "shot_times",
    "zero_doppler_attitude",
]

#: Earth constants (Vallado, Fundamentals of Astrodynamics, 4th ed., Table D-1 / WGS-84); the
#: equatorial radius and rotation rate are the WGS-84 ones of chirplidar.units.
MU_EARTH_M3_S2 = 3.986004418e14
J2_EARTH = 1.08262668e-3
R_EARTH_M = WGS84_A_M


def _times(name, t_s) -> np.ndarray:
    t = _checks.real_array(name, t_s)
    if t.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array of times, got shape {t.shape}")
    return t


def _unit_rows(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / n


# --------------------------------------------------------------------------------------------
# Polyline with constant speed (UAV)
# --------------------------------------------------------------------------------------------


class OffTerrainError(ValueError):
    """A path that must follow the ground never passes over the terrain."""


@dataclass(frozen=True)
class UavPath:
    """Constant-speed flight along a 3-D polyline in the scene frame.

    waypoints_m : (k, 3) x, y [m] and z [m]: ellipsoidal height (``altitude_mode="absolute"``) or
        height above ground (``"above_ground"``; then ``ground_height_m`` is required: a callable
        ``(x, y) -> z`` [m] of arrays, e.g. a terrain's height sampler).
    speed_mps : along-path speed (measured along the waypoint polyline).
    segment_tracks : optional (k - 1,) integer track of each leg (waypoint i to i + 1): a survey
        line's number, or -1 for a transit between lines (see :func:`lawnmower`); by default
        every leg is its own track, numbered from 0. See :meth:`track_index`.
    max_climb_mps, max_descent_mps : above ground, the vertical-rate limits: the flight height
        is then the lowest profile that keeps at least the waypoints' height above the ground
        and respects them (:func:`terrain_following.flyable_profile` on the ground sampled every
        ``profile_step_m`` along the path, linear in between); without them the path follows
        the ground exactly.
    """

    waypoints_m: np.ndarray
    speed_mps: float
    altitude_mode: str = "absolute"
    ground_height_m: Callable | None = None
    segment_tracks: np.ndarray | None = None
    max_climb_mps: float | None = None
    max_descent_mps: float | None = None
    profile_step_m: float = 2.0
    frame: str = field(default="projected", init=False)

    def __post_init__(self):
        w = _checks.real_array("waypoints_m", self.waypoints_m)
        if w.ndim != 2 or w.shape[1] != 3 or w.shape[0] < 2:
            raise ValueError(f"waypoints_m must have shape (k >= 2, 3), got {w.shape}")
        if self.segment_tracks is None:
            tracks = np.arange(w.shape[0] - 1)
        else:
            tracks = np.asarray(self.segment_tracks)
            if tracks.shape != (w.shape[0] - 1,) or not np.issubdtype(tracks.dtype, np.integer):
                raise ValueError(f"segment_tracks must be {w.shape[0] - 1} integers (one per "
                                 f"leg), got {tracks.dtype} {tracks.shape}")
        seg = np.diff(w, axis=0)
        moves = np.linalg.norm(seg, axis=1) > 0.0
        w = w[np.concatenate([[True], moves])]
        if w.shape[0] < 2:
            raise ValueError("waypoints_m must contain at least two distinct points")
        object.__setattr__(self, "waypoints_m", w)
        object.__setattr__(self, "segment_tracks", tracks[moves].astype(np.int64))
        object.__setattr__(self, "speed_mps", _checks.positive("speed_mps", self.speed_mps))
        if self.altitude_mode not in ("absolute", "above_ground"):
            raise ValueError(f"altitude_mode must be 'absolute' or 'above_ground', "
                             f"got {self.altitude_mode!r}")
        if self.altitude_mode == "above_ground" and not callable(self.ground_height_m):
            raise ValueError("ground_height_m must be a callable (x, y) -> z when "
                             "altitude_mode='above_ground'")
        lengths = np.linalg.norm(np.diff(w, axis=0), axis=1)
        object.__setattr__(self, "_cum_m", np.concatenate([[0.0], np.cumsum(lengths)]))
        limits = (self.max_climb_mps, self.max_descent_mps)
        object.__setattr__(self, "_profile", None)
        if any(v is not None for v in limits):
            if None in limits:
                raise ValueError("max_climb_mps and max_descent_mps go together")
            if self.altitude_mode != "above_ground":
                raise ValueError("max_climb_mps / max_descent_mps shape an above_ground "
                                 "profile; an absolute altitude does not follow the terrain")
            object.__setattr__(self, "_profile", self._flyable())

    def _flyable(self):
        """(distance [m], flight height [m]) of the climb-limited profile (class docstring)."""
        from chirplidar.geometry.terrain_following import flyable_profile

        step = _checks.positive("profile_step_m", self.profile_step_m)
        s = np.union1d(np.arange(0.0, self.length_m, step), self._cum_m)
        p, _ = self._locate(s / self.speed_mps)
        ground = np.asarray(self.ground_height_m(p[:, 0], p[:, 1]), dtype=float)
        if not np.any(np.isfinite(ground)):
            raise OffTerrainError(
                f"the path (x {p[:, 0].min():.0f}..{p[:, 0].max():.0f} m, y "
                f"{p[:, 1].min():.0f}..{p[:, 1].max():.0f} m) never passes over the terrain: "
                "altitude_mode = 'above_ground' has no ground to follow")
        ok = np.isfinite(ground)   # off the terrain: hold the nearest known ground height
        ground = np.interp(s, s[ok], ground[ok])
        # Heights may differ from waypoint to waypoint: the clearance is the waypoints' own.
        clearance = np.interp(s, self._cum_m, self.waypoints_m[:, 2])
        z = flyable_profile(s, ground + clearance - clearance.min(), clearance.min(),
                            self.speed_mps, self.max_climb_mps, self.max_descent_mps)
        return s, z, ground

    def profile_report(self) -> dict | None:
        """Height above ground and vertical rates of the climb-limited profile
        (:func:`terrain_following.profile_report`), or None when the path follows the ground
        exactly or flies at an absolute altitude."""
        from chirplidar.geometry.terrain_following import profile_report

        if self._profile is None:
            return None
        s, z, ground = self._profile
        return profile_report(s, ground, z, self.speed_mps)

    @property
    def length_m(self) -> float:
        return float(self._cum_m[-1])

    @property
    def duration_s(self) -> float:
        return self.length_m / self.speed_mps

    def _segment(self, t_s):
        t = _times("t_s", t_s)
        if np.any((t < 0.0) | (t > self.duration_s * (1 + 1e-12))):
            raise ValueError(f"t_s must lie in [0, duration_s = {self.duration_s}] s")
        s = t * self.speed_mps
        return np.clip(np.searchsorted(self._cum_m, s, side="right") - 1, 0,
                       len(self._cum_m) - 2), s

    def _locate(self, t_s):
        i, s = self._segment(t_s)
        w = self.waypoints_m
        seg = w[i + 1] - w[i]
        u = seg / np.linalg.norm(seg, axis=1, keepdims=True)
        return w[i] + u * (s - self._cum_m[i])[:, None], u * self.speed_mps

    def track_index(self, t_s) -> np.ndarray:
        """(n,) track flown at ``t_s``: the leg's entry of ``segment_tracks`` (-1: a transit)."""
        return self.segment_tracks[self._segment(t_s)[0]]

    def positions(self, t_s) -> np.ndarray:
        """(n, 3) scene-frame positions [m] at times ``t_s`` (n,) [s] since the path start."""
        p, _ = self._locate(t_s)
        if self._profile is not None:
            p = p.copy()
            s, z, _ = self._profile
            p[:, 2] = np.interp(_times("t_s", t_s) * self.speed_mps, s, z)
        elif self.altitude_mode == "above_ground":
            p = p.copy()
            p[:, 2] += np.asarray(self.ground_height_m(p[:, 0], p[:, 1]), dtype=float)
        return p

    def velocities(self, t_s) -> np.ndarray:
        """(n, 3) velocities [m/s]; above ground, v_z adds the terrain slope along track (or
        the climb-limited profile's slope)."""
        p, v = self._locate(t_s)
        if self._profile is not None:
            s, z, _ = self._profile
            at = _times("t_s", t_s) * self.speed_mps
            k = np.clip(np.searchsorted(s, at, side="right") - 1, 0, s.size - 2)
            v = v.copy()
            v[:, 2] = (z[k + 1] - z[k]) / (s[k + 1] - s[k]) * self.speed_mps
            return v
        if self.altitude_mode == "above_ground" and len(p):
            h = 0.5  # m, central-difference step along the horizontal velocity
            vh = np.linalg.norm(v[:, :2], axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                e = np.where(vh[:, None] > 0, v[:, :2] / vh[:, None], 0.0)
            g = self.ground_height_m
            dz = (np.asarray(g(p[:, 0] + h * e[:, 0], p[:, 1] + h * e[:, 1]), float)
                  - np.asarray(g(p[:, 0] - h * e[:, 0], p[:, 1] - h * e[:, 1]), float)) / (2 * h)
            v = v.copy()
            v[:, 2] += dz * vh
        return v


# --------------------------------------------------------------------------------------------
# Lawnmower survey pattern
# --------------------------------------------------------------------------------------------


def _polygon(polygon_xy) -> Polygon:
    p = _checks.real_array("polygon", polygon_xy)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
        raise ValueError(f"polygon must have shape (k >= 3, 2), got {p.shape}")
    poly = Polygon(p)
    if not poly.is_valid:
        raise ValueError(f"polygon is not a simple valid polygon "
                         f"({shapely.is_valid_reason(poly)}); self-intersecting outlines are refused")
    if poly.area <= 0.0:
        raise ValueError("polygon has zero area")
    return poly


def _rotated_to_lines(poly: Polygon, heading_rad: float):
    """The polygon rotated so that lines of ``heading_rad`` run along +x', and that angle."""
    ang = np.pi / 2 - heading_rad   # the lines' direction from +x
    return affinity.rotate(poly, -ang, origin=(0, 0), use_radians=True), ang


def lawnmower_width(polygon_xy, heading_rad) -> float:
    """Width [m] of the polygon across lines of ``heading_rad`` (see :func:`lawnmower_lines`):
    a spacing of width / n lays exactly n lines."""
    rot, _ = _rotated_to_lines(_polygon(polygon_xy),
                               _checks.real_scalar("heading_rad", heading_rad))
    return float(rot.bounds[3] - rot.bounds[1])


#: A lawnmower of more lines than this is a typo (a spacing in km, or 1e-3 for 1e3), not a plan.
MAX_SURVEY_LINES = 10_000


def lawnmower_lines(polygon_xy, line_spacing_m, heading_rad):
    """Boustrophedon survey lines covering ``polygon_xy``; list of ``(start_xy, end_xy)``.

    heading_rad : direction of the lines, clockwise from grid north (+y): 0 -> lines along +y,
        pi/2 -> along +x. Lines are ``line_spacing_m`` apart; the first lies half a spacing inside
        the polygon's extent. Each line is the centre of a strip of width ``line_spacing_m``; it
        spans the full along-line extent of the polygon inside that strip, so the strips (flat
        buffers of half a spacing) cover the polygon. Concave polygons may give several pieces
        per strip. Successive lines alternate direction.
    """
    poly = _polygon(polygon_xy)
    dx = _checks.positive("line_spacing_m", line_spacing_m)
    hdg = _checks.real_scalar("heading_rad", heading_rad)
    rot, ang = _rotated_to_lines(poly, hdg)
    xmin, ymin, xmax, ymax = rot.bounds
    n_float = np.ceil((ymax - ymin) / dx - 1e-9)
    if n_float > MAX_SURVEY_LINES:
        raise ValueError(f"line_spacing_m = {dx:g} m gives {n_float:.3g} lines across the "
                         f"{ymax - ymin:.0f} m polygon (more than {MAX_SURVEY_LINES})")
    n = max(1, int(n_float))
    y0 = 0.5 * (ymin + ymax) - 0.5 * (n - 1) * dx  # centre the strips on the extent
    lines = []
    c, s = np.cos(ang), np.sin(ang)
    forward = True
    for j in range(n):  # loop over survey lines (not shots)
        yc = y0 + j * dx
        piece = rot.intersection(box(xmin - 1.0, yc - dx / 2, xmax + 1.0, yc + dx / 2))
        parts = [g for g in getattr(piece, "geoms", [piece]) if g.area > 0.0]
        spans = sorted((g.bounds[0], g.bounds[2]) for g in parts)
        if not spans:
            continue
        if not forward:
            spans = [(b, a) for a, b in reversed(spans)]
        for a, b in spans:
            p0 = (a * c - yc * s, a * s + yc * c)
            p1 = (b * c - yc * s, b * s + yc * c)
            lines.append((np.array(p0), np.array(p1)))
        forward = not forward
    return lines


def lawnmower(polygon_xy, line_spacing_m, heading_rad) -> tuple[np.ndarray, np.ndarray]:
    """Waypoints ``(2 m, 2)`` of a lawnmower covering the polygon (rows 2i, 2i+1 are line i)
    and the track of each of their ``2 m - 1`` legs: leg 2i is line i, leg 2i+1 the transit to
    the next line (-1), as :class:`UavPath` takes them (``segment_tracks``).

    See :func:`lawnmower_lines` for the conventions. A self-intersecting polygon raises
    ValueError naming ``polygon``.
    """
    lines = lawnmower_lines(polygon_xy, line_spacing_m, heading_rad)
    legs = np.full(2 * len(lines) - 1, -1, dtype=np.int64)
    legs[::2] = np.arange(len(lines))
    return np.array([p for ln in lines for p in ln], dtype=float).reshape(-1, 2), legs


# --------------------------------------------------------------------------------------------
# Aircraft lines joined by Dubins (CSC) turns
# --------------------------------------------------------------------------------------------


def _mod2pi(a):
    return np.mod(a, 2 * np.pi)


def _csc(p1, psi1, p2, psi2, r):
    """Shortest of LSL, RSR, LSR, RSL from pose 1 to pose 2: list of segment specs."""
    best = None

    def centre(p, psi, turn):  # turn +1 left, -1 right
        return p + turn * r * np.array([-np.sin(psi), np.cos(psi)])

    for t1, t2 in ((1, 1), (-1, -1), (1, -1), (-1, 1)):
        c1, c2 = centre(p1, psi1, t1), centre(p2, psi2, t2)
        d = c2 - c1
        dist = np.hypot(*d)
        if t1 == t2:
            theta = np.arctan2(d[1], d[0]) if dist > 0 else psi1
            L = dist
        else:
            if dist < 2 * r:
                continue
            L = np.sqrt(max(dist * dist - 4 * r * r, 0.0))
            theta = np.arctan2(d[1], d[0]) + t1 * np.arctan2(2 * r, L)
        a1 = _mod2pi(t1 * (theta - psi1))
        a2 = _mod2pi(t2 * (psi2 - theta))
        total = r * (a1 + a2) + L
        if best is None or total < best[0] - 1e-9:
            best = (total, c1, t1, a1, theta, L, c2, t2, a2)
    _, c1, t1, a1, theta, L, c2, t2, a2 = best
    q1 = c1 - t1 * r * np.array([-np.sin(theta), np.cos(theta)])  # exit point of arc 1
    return [("arc", c1, t1, psi1, a1), ("line", q1, theta, L), ("arc", c2, t2, theta, a2)]


@dataclass(frozen=True)
class AircraftLines:
    """Straight survey lines flown in order, joined by Dubins CSC turns of ``turn_radius_m``.

    lines : sequence of ``(start_xy, end_xy)`` [m] in the scene frame (e.g. from
        :func:`lawnmower_lines`). Each turn is the shortest of the LSL, RSR, LSR, RSL paths of
        radius ``turn_radius_m`` from the end pose of one line to the start pose of the next
        (semicircles when the line spacing equals twice the radius). Flight at constant
        ``altitude_m`` (ellipsoidal height) and ``speed_mps``; ``t_s = 0`` at the first line start.
    """

    lines: tuple
    altitude_m: float
    speed_mps: float
    turn_radius_m: float
    frame: str = field(default="projected", init=False)

    def __post_init__(self):
        try:
            arr = np.asarray([[np.asarray(a, float), np.asarray(b, float)] for a, b in self.lines])
        except (TypeError, ValueError):
            raise ValueError("lines must be a sequence of (start_xy, end_xy) pairs") from None
        if arr.ndim != 3 or arr.shape[1:] != (2, 2) or arr.shape[0] < 1:
            raise ValueError(f"lines must be a non-empty sequence of (start_xy, end_xy) pairs of "
                             f"2-vectors, got array shape {arr.shape}")
        arr = _checks.real_array("lines", arr)
        if np.any(np.linalg.norm(arr[:, 1] - arr[:, 0], axis=1) <= 0):
            raise ValueError("lines must have distinct start and end points")
        object.__setattr__(self, "lines", tuple((a.copy(), b.copy()) for a, b in arr))
        object.__setattr__(self, "altitude_m", _checks.real_scalar("altitude_m", self.altitude_m))
        object.__setattr__(self, "speed_mps", _checks.positive("speed_mps", self.speed_mps))
        r = _checks.positive("turn_radius_m", self.turn_radius_m)
        object.__setattr__(self, "turn_radius_m", r)
        segs = []  # (kind, line_index, spec)
        for i, (a, b) in enumerate(arr):
            psi = float(np.arctan2(*(b - a)[::-1]))
            segs.append(("line", i, (a, psi, float(np.linalg.norm(b - a)))))
            if i + 1 < len(arr):
                a2, b2 = arr[i + 1]
                psi2 = float(np.arctan2(*(b2 - a2)[::-1]))
                for spec in _csc(b, psi, a2, psi2, r):
                    if spec[0] == "arc":
                        segs.append(("arc", -1, spec[1:]))
                    else:
                        segs.append(("line", -1, spec[1:]))
        m = len(segs)
        kind = np.zeros(m, dtype=int)  # 0 straight, 1 arc
        line_idx = np.full(m, -1)
        p0 = np.zeros((m, 2))
        psi0 = np.zeros(m)
        centre = np.zeros((m, 2))
        turn = np.zeros(m)
        length = np.zeros(m)
        for j, (k, li, spec) in enumerate(segs):
            line_idx[j] = li
            if k == "line":
                p0[j], psi0[j], length[j] = spec
            else:
                c, t, psi, sweep = spec
                kind[j], centre[j], turn[j], psi0[j], length[j] = 1, c, t, psi, r * sweep
                p0[j] = c - t * r * np.array([-np.sin(psi), np.cos(psi)])
        object.__setattr__(self, "_seg", {"kind": kind, "line": line_idx, "p0": p0, "psi0": psi0,
                                              "centre": centre, "turn": turn, "length": length,
                                              "cum": np.concatenate([[0.0], np.cumsum(length)])})

    @property
    def duration_s(self) -> float:
        return float(self._seg["cum"][-1] / self.speed_mps)

    def _eval(self, t_s):
        t = _times("t_s", t_s)
        if np.any((t < 0.0) | (t > self.duration_s * (1 + 1e-12))):
            raise ValueError(f"t_s must lie in [0, duration_s = {self.duration_s}] s")
        g = self._seg
        s = t * self.speed_mps
        j = np.clip(np.searchsorted(g["cum"], s, side="right") - 1, 0, len(g["length"]) - 1)
        ds = s - g["cum"][j]
        r = self.turn_radius_m
        arc = g["kind"][j] == 1
        psi = g["psi0"][j] + np.where(arc, g["turn"][j] * ds / r, 0.0)
        u = np.stack([np.cos(psi), np.sin(psi)], axis=1)
        straight_p = g["p0"][j] + u * ds[:, None]
        arc_p = g["centre"][j] + g["turn"][j][:, None] * r * np.stack([np.sin(psi), -np.cos(psi)],
                                                                       axis=1)
        xy = np.where(arc[:, None], arc_p, straight_p)
        pos = np.column_stack([xy, np.full(len(t), self.altitude_m)])
        vel = np.column_stack([u * self.speed_mps, np.zeros(len(t))])
        return pos, vel, g["line"][j]

    def positions(self, t_s) -> np.ndarray:
        """(n, 3) scene-frame positions [m] at ``t_s`` (n,) [s]."""
        return self._eval(t_s)[0]

    def velocities(self, t_s) -> np.ndarray:
        """(n, 3) velocities [m/s] (horizontal, tangent to the path)."""
        return self._eval(t_s)[1]

    def track_index(self, t_s) -> np.ndarray:
        """(n,) index of the survey line flown at ``t_s``; -1 during turns."""
        return self._eval(t_s)[2]


# --------------------------------------------------------------------------------------------
# Orbits
# --------------------------------------------------------------------------------------------


def _rot3(theta):
    """Rotation matrices R3(theta) (n, 3, 3): frame rotation about z, v' = R v."""
    c, s = np.cos(theta), np.sin(theta)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, s, z], -1), np.stack([-s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def _eci_to_ecef(r, v, theta):
    """Rotate ECI states by the Earth rotation angle theta (n,) (Earth rotating at OMEGA)."""
    R = _rot3(theta)
    r_e = np.einsum("nij,nj->ni", R, r)
    v_e = np.einsum("nij,nj->ni", R, v) - earth_rotation_velocity_mps(r_e)
    return r_e, v_e


@dataclass(frozen=True)
class KeplerOrbit:
    """Keplerian orbit with J2 secular drift of RAAN and argument of perigee.

    Elements at ``epoch_s``: semi-major axis [m], eccentricity, inclination, RAAN, argument of
    perigee, mean anomaly [rad]. Secular rates (Vallado, Fundamentals of Astrodynamics, eqs. for
    the J2 secular effects, 9-41 and 9-42 in the 4th ed.), with ``n = sqrt(mu / a**3)``,
    ``p = a (1 - e**2)``::

        dRAAN/dt  = -3/2 n J2 (R_E / p)**2 cos(i)
        dargp/dt  =  3/4 n J2 (R_E / p)**2 (4 - 5 sin(i)**2)
        dM/dt     =  n + 3/4 n J2 (R_E / p)**2 sqrt(1 - e**2) (2 - 3 sin(i)**2)

    ``j2=False`` switches the drift off (pure two-body). Velocities are the exact time derivative
    of the modelled positions (including the drift terms). ECI -> ECEF uses the linear
    Earth-rotation model of the module docstring.

    What it is for: design studies (an orbit placed over a scene at any altitude and
    inclination, no element set needed). The secular rates leave out J2's short-period terms,
    drag and the higher harmonics: against SGP4 started from the same mean elements it drifts
    by ~2 km over a 10-minute pass (an orbit of 496 km, e ~ 0; measured in
    ``tests/test_orbit.py``), mostly along track. Flown missions and pass predictions use
    :class:`TleOrbit`.
    """

    semi_major_axis_m: float
    eccentricity: float
    inclination_rad: float
    raan_rad: float
    arg_perigee_rad: float
    mean_anomaly_rad: float
    epoch_s: float
    j2: bool = True
    gmst_at_epoch_rad: float = 0.0
    frame: str = field(default="ecef", init=False)

    def __post_init__(self):
        a = _checks.positive("semi_major_axis_m", self.semi_major_axis_m)
        e = _checks.real_scalar("eccentricity", self.eccentricity)
        if not 0.0 <= e < 1.0:
            raise ValueError(f"eccentricity must lie in [0, 1) (closed orbit), got {e}")
        if a * (1.0 - e) <= R_EARTH_M:
            raise ValueError(f"semi_major_axis_m and eccentricity put the perigee radius "
                             f"{a * (1 - e):.0f} m inside the Earth (R_E = {R_EARTH_M} m)")
        for name in ("inclination_rad", "raan_rad", "arg_perigee_rad", "mean_anomaly_rad",
                     "epoch_s", "gmst_at_epoch_rad"):
            object.__setattr__(self, name, _checks.real_scalar(name, getattr(self, name)))
        if not 0.0 <= self.inclination_rad <= np.pi:
            raise ValueError("inclination_rad must lie in [0, pi]")
        object.__setattr__(self, "semi_major_axis_m", a)
        object.__setattr__(self, "eccentricity", e)

    @property
    def mean_motion_rad_s(self) -> float:
        return float(np.sqrt(MU_EARTH_M3_S2 / self.semi_major_axis_m ** 3))

    @property
    def period_s(self) -> float:
        """Keplerian (anomalistic, two-body) period 2 pi sqrt(a^3 / mu) [s]."""
        return 2 * np.pi / self.mean_motion_rad_s

    @property
    def _k(self) -> float:
        if not self.j2:
            return 0.0
        p = self.semi_major_axis_m * (1 - self.eccentricity ** 2)
        return self.mean_motion_rad_s * J2_EARTH * (R_EARTH_M / p) ** 2

    @property
    def raan_rate_rad_s(self) -> float:
        return -1.5 * self._k * np.cos(self.inclination_rad)

    @property
    def arg_perigee_rate_rad_s(self) -> float:
        return 0.75 * self._k * (4 - 5 * np.sin(self.inclination_rad) ** 2)

    @property
    def mean_anomaly_rate_rad_s(self) -> float:
        """Secular rate of the mean anomaly: n plus its J2 term [rad/s]."""
        return self.mean_motion_rad_s + 0.75 * self._k * np.sqrt(1 - self.eccentricity ** 2) * (
            2 - 3 * np.sin(self.inclination_rad) ** 2)

    def states_eci(self, t_s):
        """ECI positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        t = _times("t_s", t_s)
        dt = t - self.epoch_s
        a, e, n = self.semi_major_axis_m, self.eccentricity, self.mean_motion_rad_s
        M = self.mean_anomaly_rad + self.mean_anomaly_rate_rad_s * dt
        E = M + e * np.sin(M)
        for _ in range(50):  # Newton on Kepler's equation, all shots at once
            dE = (E - e * np.sin(E) - M) / (1 - e * np.cos(E))
            E = E - dE
            if np.all(np.abs(dE) < 1e-14):
                break
        cE, sE = np.cos(E), np.sin(E)
        q = np.sqrt(1 - e * e)
        r_norm = a * (1 - e * cE)
        x, y = a * (cE - e), a * q * sE
        vf = np.sqrt(MU_EARTH_M3_S2 * a) / r_norm * (self.mean_anomaly_rate_rad_s / n)
        wdot = self.arg_perigee_rate_rad_s
        vx, vy = -vf * sE - wdot * y, vf * q * cE + wdot * x
        raan = self.raan_rad + self.raan_rate_rad_s * dt
        argp = self.arg_perigee_rad + wdot * dt
        i = self.inclination_rad
        cO, sO, cw, sw, ci, si = np.cos(raan), np.sin(raan), np.cos(argp), np.sin(argp), \
            np.cos(i), np.sin(i)
        P = np.stack([cO * cw - sO * sw * ci, sO * cw + cO * sw * ci, sw * si], axis=-1)
        Q = np.stack([-cO * sw - sO * cw * ci, -sO * sw + cO * cw * ci, cw * si], axis=-1)
        r = x[:, None] * P + y[:, None] * Q
        v = vx[:, None] * P + vy[:, None] * Q
        v = v + np.cross(np.array([0.0, 0.0, self.raan_rate_rad_s]), r)
        return r, v

    def earth_rotation_angle_rad(self, t_s) -> np.ndarray:
        return self.gmst_at_epoch_rad + OMEGA_EARTH_RAD_S * (_times("t_s", t_s) - self.epoch_s)

    def states(self, t_s):
        """ECEF positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        r, v = self.states_eci(t_s)
        return _eci_to_ecef(r, v, self.earth_rotation_angle_rad(t_s))

    def positions(self, t_s) -> np.ndarray:
        return self.states(t_s)[0]

    def velocities(self, t_s) -> np.ndarray:
        return self.states(t_s)[1]


#: Largest distance [days] between a TLE's epoch and the times it is propagated to. SGP4's
#: along-track error grows by ~1-3 km per day from the epoch (Vallado et al. 2006); beyond a
#: few weeks a fresher element set is needed, and a campaign of a season is a planning estimate.
TLE_MAX_AGE_DAYS = 120.0


@dataclass(frozen=True)
class TleOrbit:
    """SGP4 orbit from a two-line element set, in ITRS (ECEF) with Earth orientation.

    ``t_s`` is seconds after ``epoch_utc`` (ISO 8601 UTC, the run's time origin). SGP4 (the
    ``sgp4`` package) gives TEME states; :func:`earth_orientation.teme_to_itrs` rotates them to
    ITRS with UT1 - UTC and polar motion from the shipped IERS table.
    """

    line1: str
    line2: str
    epoch_utc: str
    frame: str = field(default="ecef", init=False)

    def __post_init__(self):
        from sgp4.api import Satrec

        from chirplidar.geometry import earth_orientation as eo

        l1, l2 = str(self.line1).rstrip(), str(self.line2).rstrip()
        for name, line, first in (("line1", l1, "1"), ("line2", l2, "2")):
            if len(line) != 69 or line[0] != first:
                raise ValueError(f"{name} is not line {first} of a TLE (69 characters starting "
                                 f"with '{first} ', got {len(line)}: {line[:20]!r}...)")
            digits = sum(int(c) for c in line[:68] if c.isdigit()) + line[:68].count("-")
            if not line[68].isdigit() or digits % 10 != int(line[68]):
                raise ValueError(f"{name}: TLE checksum fails (column 69 is {line[68]!r}, the "
                                 f"line's digits and minus signs sum to {digits} -> "
                                 f"{digits % 10}): a damaged or mistyped element set")
        if l1[2:7] != l2[2:7]:
            raise ValueError(f"line1 and line2 belong to different satellites "
                             f"({l1[2:7].strip()} and {l2[2:7].strip()})")
        sat = Satrec.twoline2rv(l1, l2)
        if sat.error:
            raise ValueError(f"line1/line2 are not a valid TLE (sgp4 error {sat.error})")
        t0 = eo.mjd_utc(eo.parse_utc(self.epoch_utc, "epoch_utc"))
        object.__setattr__(self, "line1", l1)
        object.__setattr__(self, "line2", l2)
        object.__setattr__(self, "_sat", sat)
        object.__setattr__(self, "_epoch_mjd", t0)

    @property
    def tle_epoch_mjd(self) -> float:
        """The element set's epoch, MJD (UTC)."""
        return float(self._sat.jdsatepoch - 2400000.5 + self._sat.jdsatepochF)

    @property
    def epoch_mjd(self) -> float:
        """The run's time origin ``epoch_utc``, MJD (UTC)."""
        return float(self._epoch_mjd)

    def check_window(self, t0_s: float, t1_s: float, key: str = "t_s") -> None:
        """ValueError naming ``key`` when [t0_s, t1_s] (s after ``epoch_utc``) reaches more than
        :data:`TLE_MAX_AGE_DAYS` from the TLE epoch."""
        age = np.array([t0_s, t1_s]) / 86400.0 + self.epoch_mjd - self.tle_epoch_mjd
        if np.max(np.abs(age)) > TLE_MAX_AGE_DAYS:
            raise ValueError(f"{key}: the window reaches {np.max(np.abs(age)):.1f} days from the "
                             f"TLE epoch; SGP4 is not trusted beyond {TLE_MAX_AGE_DAYS:.0f} days "
                             "(its error grows by km per day): use an element set from the "
                             "window's time")

    def states_teme(self, t_s):
        """TEME positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        t = _times("t_s", t_s)
        sat = self._sat
        d = self.epoch_mjd - self.tle_epoch_mjd + t / 86400.0   # days after the TLE epoch
        jd = np.full(t.shape, sat.jdsatepoch)
        fr = sat.jdsatepochF + d
        err, r, v = sat.sgp4_array(jd, fr)
        if np.any(err != 0):
            raise ValueError(f"t_s: SGP4 propagation failed (error codes "
                             f"{sorted(set(err[err != 0].tolist()))}: decayed or invalid orbit)")
        return np.asarray(r).reshape(-1, 3) * 1e3, np.asarray(v).reshape(-1, 3) * 1e3

    def states(self, t_s):
        """ITRS positions (n, 3) [m] and velocities (n, 3) [m/s] at ``t_s`` (n,) [s]."""
        from chirplidar.geometry.earth_orientation import teme_to_itrs

        t = _times("t_s", t_s)
        r, v = self.states_teme(t)
        return teme_to_itrs(r, v, self.epoch_mjd + t / 86400.0)

    def positions(self, t_s):
        return self.states(t_s)[0]

    def velocities(self, t_s):
        return self.states(t_s)[1]


# --------------------------------------------------------------------------------------------
# Attitude and beams
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Attitude:
    """Roll, pitch, yaw [rad]: scalars or (n,) arrays (one per shot)."""

    roll_rad: object = 0.0
    pitch_rad: object = 0.0
    yaw_rad: object = 0.0

    def matrices(self, n: int) -> np.ndarray:
        """(n, 3, 3) rotation body -> level frame, R = Rz(yaw) Ry(pitch) Rx(roll)."""
        vals = []
        for name in ("roll_rad", "pitch_rad", "yaw_rad"):
            a = _checks.real_array(name, getattr(self, name))
            if a.ndim > 1 or (a.ndim == 1 and a.shape[0] != n):
                raise ValueError(f"{name} must be a scalar or have shape ({n},), got {a.shape}")
            vals.append(np.broadcast_to(a, (n,)))
        r, p, y = vals
        cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
        return np.stack([
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1)], -2)


@dataclass(frozen=True)
class BeamPattern:
    """Beams as (off_nadir_rad, azimuth_rad) pairs; azimuths advance at ``scan_rate_rad_s``.

    azimuth(t) = azimuth_rad + scan_rate_rad_s * t_s  (0 for a fixed pattern).
    """

    off_nadir_rad: np.ndarray
    azimuth_rad: np.ndarray
    scan_rate_rad_s: float = 0.0
    power_share: np.ndarray | None = None   # (n_beams,) transmitted power per beam, mean 1

    def __post_init__(self):
        o = _checks.real_array("off_nadir_rad", self.off_nadir_rad)
        a = _checks.real_array("azimuth_rad", self.azimuth_rad)
        if o.ndim != 1 or a.shape != o.shape or o.size == 0:
            raise ValueError(f"off_nadir_rad and azimuth_rad must be equal-length non-empty 1-D "
                             f"arrays, got {o.shape} and {a.shape}")
        if np.any((o < 0) | (o >= np.pi / 2)):
            raise ValueError("off_nadir_rad must lie in [0, pi/2)")
        object.__setattr__(self, "off_nadir_rad", o)
        object.__setattr__(self, "azimuth_rad", a)
        object.__setattr__(self, "scan_rate_rad_s",
                           _checks.real_scalar("scan_rate_rad_s", self.scan_rate_rad_s))
        share = np.ones(o.shape) if self.power_share is None else \
            _checks.positive_array("power_share", self.power_share)
        if share.shape != o.shape:
            raise ValueError(f"power_share must have one value per beam {o.shape}, got "
                             f"{share.shape}")
        object.__setattr__(self, "power_share", share / share.mean())

    @property
    def n_beams(self) -> int:
        return int(self.off_nadir_rad.size)


def nadir_beam() -> BeamPattern:
    return BeamPattern(np.array([0.0]), np.array([0.0]))


def paired_beams_across_track(pair_spacing_rad, within_pair_rad, stagger_rad=0.0,
                              power_ratio=1.0) -> BeamPattern:
    """Three pairs of beams across track (ICESat-2-like), ordered left to right.

    Pair centres at across-track angles -pair_spacing_rad, 0, +pair_spacing_rad; the two beams of
    a pair at +-within_pair_rad / 2 about the centre and, along track, the left one
    ``stagger_rad`` / 2 ahead and the right one as far behind (ICESat-2 from ~496 km: pairs 3.3
    km apart, beams 90 m apart across and ~2.5 km along track -> pair_spacing_rad ~ 6.65e-3,
    within_pair_rad ~ 1.8e-4, stagger_rad ~ 5.0e-3). ``power_ratio``: the left (strong) beam of
    each pair carries this many times the right (weak) beam's power (ICESat-2: 4); the mean
    over the beams is the transmitter's per-beam power.
    """
    ps = _checks.positive("pair_spacing_rad", pair_spacing_rad)
    wp = _checks.positive("within_pair_rad", within_pair_rad)
    st = _checks.non_negative("stagger_rad", stagger_rad)
    ratio = _checks.positive("power_ratio", power_ratio)
    if wp >= ps:
        raise ValueError("within_pair_rad must be smaller than pair_spacing_rad")
    across = np.array([c + s * wp / 2 for c in (-ps, 0.0, ps) for s in (-1, 1)])
    along = np.tile([st / 2, -st / 2], 3)
    # Body direction (tan along, tan across, 1): the off-nadir angle and its azimuth.
    ta, tc = np.tan(along), np.tan(across)
    off = np.arctan(np.hypot(ta, tc))
    return BeamPattern(off, np.arctan2(tc, ta), power_share=np.tile([ratio, 1.0], 3))


def conical_scan(off_nadir_rad, scan_rate_rad_s, phase_rad=0.0) -> BeamPattern:
    """One beam on a cone of half angle ``off_nadir_rad`` whose azimuth advances with time."""
    _checks.positive("off_nadir_rad", off_nadir_rad)
    rate = _checks.real_scalar("scan_rate_rad_s", scan_rate_rad_s)
    if rate == 0.0:
        raise ValueError("scan_rate_rad_s must be non-zero for a conical scan")
    return BeamPattern(np.array([float(off_nadir_rad)]), np.array([float(phase_rad)]), rate)


def beam_directions(velocity_unit, up, attitude, beams, *, t_s=None, jitter_rad_rms=0.0,
                    rng=None) -> np.ndarray:
    """Unit beam directions (n, n_beams, 3) in the frame of ``velocity_unit`` and ``up``.

    velocity_unit, up : (n, 3) flight direction and local up (any common Cartesian frame, e.g.
        ECEF with the geodetic up, or a local true-metre frame with up = (0, 0, 1)). The body x
        axis is the part of the velocity perpendicular to ``up``.
    attitude : :class:`Attitude` (or None for level flight); beams : :class:`BeamPattern`.
    t_s : (n,) shot times [s], required for a scanning pattern.
    jitter_rad_rms, rng : pointing jitter per axis [rad rms] and its ``numpy.random.Generator``;
        no random numbers are drawn when ``jitter_rad_rms == 0``.
    """
    v = _checks.real_array("velocity_unit", velocity_unit)
    u = _checks.real_array("up", up)
    if v.ndim != 2 or v.shape[1] != 3 or u.shape != v.shape:
        raise ValueError(f"velocity_unit and up must both have shape (n, 3), got {v.shape} "
                         f"and {u.shape}")
    if not isinstance(beams, BeamPattern):
        raise ValueError("beams must be a BeamPattern")  # noqa: TRY004 (project rule: ValueError)
    n, b = v.shape[0], beams.n_beams
    sigma = _checks.non_negative("jitter_rad_rms", jitter_rad_rms)
    if sigma > 0 and not isinstance(rng, np.random.Generator):
        raise ValueError("rng must be a numpy.random.Generator when jitter_rad_rms > 0")
    if n == 0:
        return np.zeros((0, b, 3))
    up_n = np.linalg.norm(u, axis=1)
    if np.any(up_n == 0):
        raise ValueError("up must be non-zero vectors")
    u = u / up_n[:, None]
    fwd = v - np.sum(v * u, axis=1, keepdims=True) * u
    fn = np.linalg.norm(fwd, axis=1)
    if np.any(fn <= 1e-9 * np.maximum(np.linalg.norm(v, axis=1), 1e-300)) or np.any(fn == 0):
        raise ValueError("velocity_unit must have a horizontal component (vertical or zero "
                         "velocity leaves the flight direction undefined)")
    fwd = fwd / fn[:, None]
    down = -u
    right = np.cross(down, fwd)
    az = np.broadcast_to(beams.azimuth_rad, (n, b))
    if beams.scan_rate_rad_s != 0.0:
        if t_s is None:
            raise ValueError("t_s is required for a scanning beam pattern")
        t = _times("t_s", t_s)
        if t.shape != (n,):
            raise ValueError(f"t_s must have shape ({n},), got {t.shape}")
        az = az + beams.scan_rate_rad_s * t[:, None]
    th = np.broadcast_to(beams.off_nadir_rad, (n, b))
    d_body = np.stack([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)], axis=-1)
    if attitude is not None:
        if not isinstance(attitude, Attitude):
            raise ValueError("attitude must be an Attitude or None")
        d_body = np.einsum("nij,nbj->nbi", attitude.matrices(n), d_body)
    basis = np.stack([fwd, right, down], axis=1)  # (n, 3 body axes, 3 world comps)
    d = np.einsum("nbi,nij->nbj", d_body, basis)
    if sigma > 0:
        g = rng.normal(0.0, sigma, size=(n, b, 2))
        ref = np.where(np.abs(d[..., 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]),
                       np.array([1.0, 0.0, 0.0]))
        e1 = _unit_rows(np.cross(d, ref))
        e2 = np.cross(d, e1)
        delta = g[..., :1] * e1 + g[..., 1:] * e2
        ang = np.linalg.norm(delta, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            dirn = np.where(ang > 0, delta / ang, 0.0)
        d = np.cos(ang) * d + np.sin(ang) * dirn
    return _unit_rows(d)


# --------------------------------------------------------------------------------------------
# Shots
# --------------------------------------------------------------------------------------------


def shot_times(start_s, stop_s, prf_hz) -> np.ndarray:
    """Shot times ``start_s + i / prf_hz`` in ``[start_s, stop_s)`` (n,) [s]; empty if none."""
    a = _checks.real_scalar("start_s", start_s)
    b = _checks.real_scalar("stop_s", stop_s)
    prf = _checks.positive("prf_hz", prf_hz)
    if b < a:
        raise ValueError(f"stop_s ({b}) must not be before start_s ({a})")
    n = int(np.ceil((b - a) * prf - 1e-9)) if b > a else 0
    return a + np.arange(max(n, 0)) / prf


@dataclass(frozen=True)
class ShotGeometry:
    """Per-shot platform state and beams.

    t_s (n,), position_m (n, 3) and velocity_mps (n, 3) in the platform's native ``frame``
    ("projected" scene frame or "ecef"); direction (n, n_beams, 3) unit beam directions in that
    frame's true-metre sense (ECEF, or for "projected" the local true frame with axes grid x,
    grid y, up); rays: :class:`frames.ProjectedRays` (n, n_beams) in the scene frame, or None
    when no ``epsg`` was given.
    """

    t_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    direction: np.ndarray
    frame: str
    rays: frames.ProjectedRays | None = None


def zero_doppler_attitude(attitude, velocity, up) -> Attitude:
    """``attitude`` with each shot's pitch raised by atan(v_up / v_h): the pitch steering that
    makes every beam of the body's x-z and y-z planes perpendicular to the velocity (zero
    closing speed, no Doppler shift), as ICESat-2 points its beams.

    A beam at off-nadir angle theta in those planes, pitched by p, has the direction
    cos(theta) (cos p down + sin p forward) + sin(theta) right; the body x axis is the horizontal
    velocity, so v . right = 0 and the closing speed cos(theta) (v_h sin p - v_up cos p)
    vanishes for tan p = v_up / v_h. velocity, up: (n, 3) in one frame.
    """
    v = np.asarray(velocity, float)
    u = _unit_rows(np.asarray(up, float))
    v_up = np.sum(v * u, axis=1)
    v_h = np.linalg.norm(v - v_up[:, None] * u, axis=1)
    att = attitude if attitude is not None else Attitude()
    base = np.broadcast_to(_checks.real_array("pitch_rad", att.pitch_rad), v_up.shape)
    return Attitude(att.roll_rad, base + np.arctan2(v_up, v_h), att.yaw_rad)


def shot_geometry(path, t_s, beams, attitude=None, *, epsg=None, jitter_rad_rms=0.0, rng=None,
                  target_height_m=None, entry_height_m=None,
                  doppler_steering: bool = False) -> ShotGeometry:
    """Platform position, velocity and beam directions for each shot, and scene-frame rays.

    path : UavPath, AircraftLines, KeplerOrbit or TleOrbit. t_s : (n,) shot times [s] (may be
    empty: every output then has a zero-length shot axis). With ``epsg`` the rays are converted
    to the scene frame. ``target_height_m`` (ellipsoidal height below the lowest terrain) selects
    the exact conversion via ECEF and is required for ECEF platforms, which should also pass
    ``entry_height_m`` (above the highest terrain; must lie below the platform to have an
    effect), see :func:`frames.rays_projected_from_ecef`. Without it, scene-frame platforms use
    the flat approximation of :func:`frames.rays_projected_local` (error at 20 deg off nadir:
    1 cm from 1 km, 28 cm from 5 km above ground). ``doppler_steering`` pitches every shot by
    :func:`zero_doppler_attitude` on top of ``attitude``.
    """
    t = _times("t_s", t_s)
    n, nb = t.shape[0], beams.n_beams if isinstance(beams, BeamPattern) else None
    if nb is None:
        raise ValueError("beams must be a BeamPattern")
    frame = getattr(path, "frame", None)
    if frame not in ("projected", "ecef"):
        raise ValueError("path must be a UavPath, AircraftLines, KeplerOrbit or TleOrbit")
    if n == 0:
        empty3 = np.zeros((0, 3))
        rays = None
        if epsg is not None:
            frames._epsg(epsg)
            rays = frames.ProjectedRays(np.zeros((0, nb, 3)), np.zeros((0, nb, 3)),
                                        np.zeros((0, nb)), np.zeros((0, nb)),
                                        np.zeros((0, nb), dtype=bool))
        return ShotGeometry(t, empty3, empty3.copy(), np.zeros((0, nb, 3)), frame, rays)
    pos, vel = path.states(t) if hasattr(path, "states") else (path.positions(t),
                                                                 path.velocities(t))
    if frame == "projected":
        up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), pos.shape)
    else:
        lat, lon, _ = frames.ecef_to_geodetic(pos[:, 0], pos[:, 1], pos[:, 2])
        up = frames.local_up_ecef(lat, lon)
    vu = _unit_rows(vel)
    if doppler_steering:
        attitude = zero_doppler_attitude(attitude, vel, up)
    d = beam_directions(vu, up, attitude, beams, t_s=t, jitter_rad_rms=jitter_rad_rms, rng=rng)
    rays = None
    if epsg is not None:
        origin = np.broadcast_to(pos[:, None, :], d.shape)
        if frame == "projected":
            rays = frames.rays_projected_local(origin, d, epsg, target_height_m=target_height_m,
                                               entry_height_m=entry_height_m)
        else:
            if target_height_m is None:
                raise ValueError("target_height_m is required to convert ECEF rays to the scene "
                                 "frame")
            rays = frames.rays_projected_from_ecef(origin, d, epsg,
                                                   target_height_m=target_height_m,
                                                   entry_height_m=entry_height_m)
    return ShotGeometry(t, pos, vel, d, frame, rays)
