"""Flight paths in the scene frame: UAV polylines, lawnmower survey patterns, and aircraft lines
joined by Dubins turns.

:class:`UavPath` and :class:`AircraftLines` live in the scene (projected) frame of
:mod:`chirplidar.geometry.frames` (``frame = "projected"``): x, y grid metres, z ellipsoidal
height. Their time origin ``t_s = 0`` is the start of the path. Speeds are along-path speeds in
scene-frame metres per second (the map scale factor k, |k - 1| < 4 % over Greenland, is
neglected for the speed; ray geometry and ranges correct for it, see ``frames``). Orbits are in
:mod:`.orbits`, attitude, beams and per-shot geometry in :mod:`.pointing`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Polygon, box

from chirplidar import _checks

__all__ = [
    "MAX_SURVEY_LINES",
    "AircraftLines",
    "OffTerrainError",
    "UavPath",
    "lawnmower",
    "lawnmower_lines",
    "lawnmower_width",
]


# --------------------------------------------------------------------------------------------
# Polyline with constant speed (UAV)
# --------------------------------------------------------------------------------------------


#: Ground height z [m] under scene-frame points (x, y) [m], arrays in and out.
GroundHeight = Callable[[np.ndarray, np.ndarray], Any]


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
    ground_height_m: GroundHeight | None = None
    segment_tracks: np.ndarray | None = None
    max_climb_mps: float | None = None
    max_descent_mps: float | None = None
    profile_step_m: float = 2.0
    frame: str = field(default="projected", init=False)
    # set by __post_init__: cumulative length [m] at each waypoint, and the climb-limited
    # profile (distance, flight height, ground) [m] or None
    _cum_m: np.ndarray = field(init=False, repr=False, compare=False)
    _profile: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(
        init=False, repr=False, compare=False
    )

    def __post_init__(self):
        w = _checks.real_array("waypoints_m", self.waypoints_m)
        if w.ndim != 2 or w.shape[1] != 3 or w.shape[0] < 2:
            raise ValueError(f"waypoints_m must have shape (k >= 2, 3), got {w.shape}")
        if self.segment_tracks is None:
            tracks = np.arange(w.shape[0] - 1)
        else:
            tracks = np.asarray(self.segment_tracks)
            if tracks.shape != (w.shape[0] - 1,) or not np.issubdtype(tracks.dtype, np.integer):
                raise ValueError(
                    f"segment_tracks must be {w.shape[0] - 1} integers (one per "
                    f"leg), got {tracks.dtype} {tracks.shape}"
                )
        seg = np.diff(w, axis=0)
        moves = np.linalg.norm(seg, axis=1) > 0.0
        w = w[np.concatenate([[True], moves])]
        if w.shape[0] < 2:
            raise ValueError("waypoints_m must contain at least two distinct points")
        object.__setattr__(self, "waypoints_m", w)
        object.__setattr__(self, "segment_tracks", tracks[moves].astype(np.int64))
        object.__setattr__(self, "speed_mps", _checks.positive("speed_mps", self.speed_mps))
        if self.altitude_mode not in ("absolute", "above_ground"):
            raise ValueError(
                f"altitude_mode must be 'absolute' or 'above_ground', got {self.altitude_mode!r}"
            )
        if self.altitude_mode == "above_ground" and not callable(self.ground_height_m):
            raise ValueError(
                "ground_height_m must be a callable (x, y) -> z when altitude_mode='above_ground'"
            )
        lengths = np.linalg.norm(np.diff(w, axis=0), axis=1)
        object.__setattr__(self, "_cum_m", np.concatenate([[0.0], np.cumsum(lengths)]))
        limits = (self.max_climb_mps, self.max_descent_mps)
        object.__setattr__(self, "_profile", None)
        if any(v is not None for v in limits):
            if None in limits:
                raise ValueError("max_climb_mps and max_descent_mps go together")
            if self.altitude_mode != "above_ground":
                raise ValueError(
                    "max_climb_mps / max_descent_mps shape an above_ground "
                    "profile; an absolute altitude does not follow the terrain"
                )
            object.__setattr__(self, "_profile", self._flyable())

    def _flyable(self):
        """(distance [m], flight height [m]) of the climb-limited profile (class docstring)."""
        from chirplidar.geometry.terrain_following import flyable_profile

        step = _checks.positive("profile_step_m", self.profile_step_m)
        s = np.union1d(np.arange(0.0, self.length_m, step), self._cum_m)
        p, _ = self._locate(s / self.speed_mps)
        ground = self._ground_m(p[:, 0], p[:, 1])
        if not np.any(np.isfinite(ground)):
            raise OffTerrainError(
                f"the path (x {p[:, 0].min():.0f}..{p[:, 0].max():.0f} m, y "
                f"{p[:, 1].min():.0f}..{p[:, 1].max():.0f} m) never passes over the terrain: "
                "altitude_mode = 'above_ground' has no ground to follow"
            )
        ok = np.isfinite(ground)  # off the terrain: hold the nearest known ground height
        ground = np.interp(s, s[ok], ground[ok])
        # Heights may differ from waypoint to waypoint: the clearance is the waypoints' own.
        clearance = np.interp(s, self._cum_m, self.waypoints_m[:, 2])
        z = flyable_profile(
            s,
            ground + clearance - clearance.min(),
            clearance.min(),
            self.speed_mps,
            self.max_climb_mps,
            self.max_descent_mps,
        )
        return s, z, ground

    def _ground_m(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground height [m] under (x, y) [m]; only above-ground paths, which have a sampler
        (``__post_init__`` checks it), ask."""
        ground = cast(GroundHeight, self.ground_height_m)
        return np.asarray(ground(x, y), dtype=float)

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
        t = _checks.time_array("t_s", t_s)
        if np.any((t < 0.0) | (t > self.duration_s * (1 + 1e-12))):
            raise ValueError(f"t_s must lie in [0, duration_s = {self.duration_s}] s")
        s = t * self.speed_mps
        return np.clip(
            np.searchsorted(self._cum_m, s, side="right") - 1, 0, len(self._cum_m) - 2
        ), s

    def _locate(self, t_s):
        i, s = self._segment(t_s)
        w = self.waypoints_m
        seg = w[i + 1] - w[i]
        u = seg / np.linalg.norm(seg, axis=1, keepdims=True)
        return w[i] + u * (s - self._cum_m[i])[:, None], u * self.speed_mps

    def track_index(self, t_s) -> np.ndarray:
        """(n,) track flown at ``t_s``: the leg's entry of ``segment_tracks`` (-1: a transit)."""
        tracks = cast(np.ndarray, self.segment_tracks)  # __post_init__ replaces None
        return tracks[self._segment(t_s)[0]]

    def positions(self, t_s) -> np.ndarray:
        """(n, 3) scene-frame positions [m] at times ``t_s`` (n,) [s] since the path start."""
        p, _ = self._locate(t_s)
        if self._profile is not None:
            p = p.copy()
            s, z, _ = self._profile
            p[:, 2] = np.interp(_checks.time_array("t_s", t_s) * self.speed_mps, s, z)
        elif self.altitude_mode == "above_ground":
            p = p.copy()
            p[:, 2] += self._ground_m(p[:, 0], p[:, 1])
        return p

    def velocities(self, t_s) -> np.ndarray:
        """(n, 3) velocities [m/s]; above ground, v_z adds the terrain slope along track (or
        the climb-limited profile's slope)."""
        p, v = self._locate(t_s)
        if self._profile is not None:
            s, z, _ = self._profile
            at = _checks.time_array("t_s", t_s) * self.speed_mps
            k = np.clip(np.searchsorted(s, at, side="right") - 1, 0, s.size - 2)
            v = v.copy()
            v[:, 2] = (z[k + 1] - z[k]) / (s[k + 1] - s[k]) * self.speed_mps
            return v
        if self.altitude_mode == "above_ground" and len(p):
            h = 0.5  # m, central-difference step along the horizontal velocity
            vh = np.linalg.norm(v[:, :2], axis=1)
            with np.errstate(invalid="ignore", divide="ignore"):
                e = np.where(vh[:, None] > 0, v[:, :2] / vh[:, None], 0.0)
            dz = (
                self._ground_m(p[:, 0] + h * e[:, 0], p[:, 1] + h * e[:, 1])
                - self._ground_m(p[:, 0] - h * e[:, 0], p[:, 1] - h * e[:, 1])
            ) / (2 * h)
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
        raise ValueError(
            f"polygon is not a simple valid polygon "
            f"({shapely.is_valid_reason(poly)}); self-intersecting outlines are refused"
        )
    if poly.area <= 0.0:
        raise ValueError("polygon has zero area")
    return poly


def _rotated_to_lines(poly: Polygon, heading_rad: float):
    """The polygon rotated so that lines of ``heading_rad`` run along +x', and that angle."""
    ang = np.pi / 2 - heading_rad  # the lines' direction from +x
    return affinity.rotate(poly, -ang, origin=(0, 0), use_radians=True), ang


def lawnmower_width(polygon_xy, heading_rad) -> float:
    """Width [m] of the polygon across lines of ``heading_rad`` (see :func:`lawnmower_lines`):
    a spacing of width / n lays exactly n lines."""
    rot, _ = _rotated_to_lines(
        _polygon(polygon_xy), _checks.real_scalar("heading_rad", heading_rad)
    )
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
        raise ValueError(
            f"line_spacing_m = {dx:g} m gives {n_float:.3g} lines across the "
            f"{ymax - ymin:.0f} m polygon (more than {MAX_SURVEY_LINES})"
        )
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
    if best is None:  # pragma: no cover - LSL and RSR always exist
        raise ValueError("no Dubins CSC path between the poses")
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
    # set by __post_init__: the flight's segments (lines and arcs) as arrays
    _seg: dict[str, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        try:
            arr = np.asarray([[np.asarray(a, float), np.asarray(b, float)] for a, b in self.lines])
        except (TypeError, ValueError):
            raise ValueError("lines must be a sequence of (start_xy, end_xy) pairs") from None
        if arr.ndim != 3 or arr.shape[1:] != (2, 2) or arr.shape[0] < 1:
            raise ValueError(
                f"lines must be a non-empty sequence of (start_xy, end_xy) pairs of "
                f"2-vectors, got array shape {arr.shape}"
            )
        arr = _checks.real_array("lines", arr)
        if np.any(np.linalg.norm(arr[:, 1] - arr[:, 0], axis=1) <= 0):
            raise ValueError("lines must have distinct start and end points")
        object.__setattr__(self, "lines", tuple((a.copy(), b.copy()) for a, b in arr))
        object.__setattr__(self, "altitude_m", _checks.real_scalar("altitude_m", self.altitude_m))
        object.__setattr__(self, "speed_mps", _checks.positive("speed_mps", self.speed_mps))
        r = _checks.positive("turn_radius_m", self.turn_radius_m)
        object.__setattr__(self, "turn_radius_m", r)
        segs: list[tuple[str, int, tuple]] = []  # (kind, line_index, spec)
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
        object.__setattr__(
            self,
            "_seg",
            {
                "kind": kind,
                "line": line_idx,
                "p0": p0,
                "psi0": psi0,
                "centre": centre,
                "turn": turn,
                "length": length,
                "cum": np.concatenate([[0.0], np.cumsum(length)]),
            },
        )

    @property
    def duration_s(self) -> float:
        return float(self._seg["cum"][-1] / self.speed_mps)

    def _eval(self, t_s):
        t = _checks.time_array("t_s", t_s)
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
        arc_p = g["centre"][j] + g["turn"][j][:, None] * r * np.stack(
            [np.sin(psi), -np.cos(psi)], axis=1
        )
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
