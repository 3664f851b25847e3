"""Where each shot points: attitude, beam patterns, beam directions and per-shot platform
geometry (positions, velocities, beams and scene-frame rays of any platform of :mod:`.paths` or
:mod:`.orbits`).

Body frame: x forward (horizontal flight direction), y right, z down (nadir). A beam is an
``(off_nadir_rad, azimuth_rad)`` pair: off-nadir angle from body z, azimuth measured from body x
toward body y (0 = forward, +pi/2 = right of track). Attitude is applied as intrinsic Z-Y-X
rotations ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (positive roll = right wing down, so a nadir beam
looks left; positive pitch = nose up, a nadir beam looks forward; positive yaw = nose right).
Pointing jitter (optional, seeded generator) tilts each beam by independent normal angles of
``jitter_rad_rms`` about two axes perpendicular to it (total angular rms ``sqrt(2)`` times that).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from chirplidar import _checks
from chirplidar.geometry import frames

__all__ = [
    "Attitude",
    "BeamPattern",
    "ShotGeometry",
    "beam_directions",
    "conical_scan",
    "nadir_beam",
    "paired_beams_across_track",
    "shot_geometry",
    "shot_times",
    "zero_doppler_attitude",
]


def _unit_rows(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / n


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
        return np.stack(
            [
                np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                np.stack([-sp, cp * sr, cp * cr], -1),
            ],
            -2,
        )


@dataclass(frozen=True)
class BeamPattern:
    """Beams as (off_nadir_rad, azimuth_rad) pairs; azimuths advance at ``scan_rate_rad_s``.

    azimuth(t) = azimuth_rad + scan_rate_rad_s * t_s  (0 for a fixed pattern).
    """

    off_nadir_rad: np.ndarray
    azimuth_rad: np.ndarray
    scan_rate_rad_s: float = 0.0
    power_share: np.ndarray | None = None  # (n_beams,) transmitted power per beam, mean 1

    def __post_init__(self):
        o = _checks.real_array("off_nadir_rad", self.off_nadir_rad)
        a = _checks.real_array("azimuth_rad", self.azimuth_rad)
        if o.ndim != 1 or a.shape != o.shape or o.size == 0:
            raise ValueError(
                f"off_nadir_rad and azimuth_rad must be equal-length non-empty 1-D "
                f"arrays, got {o.shape} and {a.shape}"
            )
        if np.any((o < 0) | (o >= np.pi / 2)):
            raise ValueError("off_nadir_rad must lie in [0, pi/2)")
        object.__setattr__(self, "off_nadir_rad", o)
        object.__setattr__(self, "azimuth_rad", a)
        object.__setattr__(
            self, "scan_rate_rad_s", _checks.real_scalar("scan_rate_rad_s", self.scan_rate_rad_s)
        )
        share = (
            np.ones(o.shape)
            if self.power_share is None
            else _checks.positive_array("power_share", self.power_share)
        )
        if share.shape != o.shape:
            raise ValueError(
                f"power_share must have one value per beam {o.shape}, got {share.shape}"
            )
        object.__setattr__(self, "power_share", share / share.mean())

    @property
    def n_beams(self) -> int:
        return int(self.off_nadir_rad.size)


def nadir_beam() -> BeamPattern:
    return BeamPattern(np.array([0.0]), np.array([0.0]))


def paired_beams_across_track(
    pair_spacing_rad, within_pair_rad, stagger_rad=0.0, power_ratio=1.0
) -> BeamPattern:
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


def beam_directions(
    velocity_unit, up, attitude, beams, *, t_s=None, jitter_rad_rms=0.0, rng=None
) -> np.ndarray:
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
        raise ValueError(
            f"velocity_unit and up must both have shape (n, 3), got {v.shape} and {u.shape}"
        )
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
        raise ValueError(
            "velocity_unit must have a horizontal component (vertical or zero "
            "velocity leaves the flight direction undefined)"
        )
    fwd = fwd / fn[:, None]
    down = -u
    right = np.cross(down, fwd)
    az = np.broadcast_to(beams.azimuth_rad, (n, b))
    if beams.scan_rate_rad_s != 0.0:
        if t_s is None:
            raise ValueError("t_s is required for a scanning beam pattern")
        t = _checks.time_array("t_s", t_s)
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
        ref = np.where(
            np.abs(d[..., 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
        )
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
    return np.asarray(ShotClock.between(start_s, stop_s, prf_hz))


class ShotClock:
    """The shot times ``start_s + i / prf_hz``, ``i = 0 .. n - 1`` [s], without holding them:
    a one-hour flight at 9.4 kHz is 34 million of them (272 MB in every process of a run).

    Indexing with an int, a slice or an array of shot numbers computes those times, bit for
    bit the values of :func:`shot_times` (same arithmetic per element); other indices, and
    ``np.asarray``, build the whole array. ``size``, ``shape`` and ``len`` are the count.
    """

    ndim = 1

    def __init__(self, start_s: float, prf_hz: float, n: int):
        self.start_s = _checks.real_scalar("start_s", start_s)
        self.prf_hz = _checks.positive("prf_hz", prf_hz)
        self.size = _checks.integer("n", n, 0)
        self.shape = (self.size,)

    @classmethod
    def between(cls, start_s, stop_s, prf_hz) -> ShotClock:
        """The clock of :func:`shot_times` (same count and times)."""
        a = _checks.real_scalar("start_s", start_s)
        b = _checks.real_scalar("stop_s", stop_s)
        prf = _checks.positive("prf_hz", prf_hz)
        if b < a:
            raise ValueError(f"stop_s ({b}) must not be before start_s ({a})")
        return cls(a, prf, int(np.ceil((b - a) * prf - 1e-9)) if b > a else 0)

    def __len__(self) -> int:
        return self.size

    def _times(self, index) -> np.ndarray:
        return self.start_s + np.asarray(index) / self.prf_hz

    def __getitem__(self, key):
        if isinstance(key, slice):
            return self._times(np.arange(*key.indices(self.size)))
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            k = int(key) + (self.size if key < 0 else 0)
            if not 0 <= k < self.size:
                raise IndexError(f"shot {key} of {self.size}")
            return float(self._times(k))
        index = np.asarray(key)
        if index.dtype.kind in "iu":  # shots by number (no negative ones)
            if index.size and not (index.min() >= 0 and index.max() < self.size):
                raise IndexError(f"shots outside 0..{self.size - 1}")
            return self._times(index)
        return np.asarray(self)[key]

    def __array__(self, dtype=None, copy=None):
        t = self._times(np.arange(self.size))
        return t if dtype is None else t.astype(dtype)

    def __repr__(self) -> str:
        return f"ShotClock(start_s={self.start_s!r}, prf_hz={self.prf_hz!r}, n={self.size})"


@dataclass(frozen=True)
class ShotGeometry:
    """Per-shot platform state and beams.

    t_s (n,), position_m (n, 3) and velocity_mps (n, 3) in the platform's native ``frame``
    ("projected" scene frame or "ecef"); direction (n, n_beams, 3) unit beam directions in that
    frame's true-metre sense (ECEF, or for "projected" the local true frame with axes grid x,
    grid y, up); rays: :class:`frames.ProjectedRays` (n, n_beams) in the scene frame, or None
    when no ``epsg`` was given; axes_ecef: for a "projected" platform with the exact conversion,
    ``frames.grid_axes_ecef`` of the positions (ECEF position, grid x, grid y, up; each (n, 3)),
    else None.
    """

    t_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    direction: np.ndarray
    frame: str
    rays: frames.ProjectedRays | None = None
    axes_ecef: tuple | None = None


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


def shot_geometry(
    path,
    t_s,
    beams,
    attitude=None,
    *,
    epsg=None,
    jitter_rad_rms=0.0,
    rng=None,
    target_height_m=None,
    entry_height_m=None,
    doppler_steering: bool = False,
) -> ShotGeometry:
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
    t = _checks.time_array("t_s", t_s)
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
            frames.checked_epsg(epsg)
            rays = frames.ProjectedRays(
                np.zeros((0, nb, 3)),
                np.zeros((0, nb, 3)),
                np.zeros((0, nb)),
                np.zeros((0, nb)),
                np.zeros((0, nb), dtype=bool),
            )
        return ShotGeometry(t, empty3, empty3.copy(), np.zeros((0, nb, 3)), frame, rays)
    pos, vel = (
        path.states(t) if hasattr(path, "states") else (path.positions(t), path.velocities(t))
    )
    if frame == "projected":
        up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), pos.shape)
    else:
        lat, lon, _ = frames.ecef_to_geodetic(pos[:, 0], pos[:, 1], pos[:, 2])
        up = frames.local_up_ecef(lat, lon)
    vu = _unit_rows(vel)
    if doppler_steering:
        attitude = zero_doppler_attitude(attitude, vel, up)
    d = beam_directions(vu, up, attitude, beams, t_s=t, jitter_rad_rms=jitter_rad_rms, rng=rng)
    rays = axes = None
    if epsg is not None:
        origin = np.broadcast_to(pos[:, None, :], d.shape)
        if frame == "projected":
            # The grid axes once per shot (its beams share them; callers reuse them too).
            axes = frames.grid_axes_ecef(pos, epsg) if target_height_m is not None else None
            rays = frames.rays_projected_local(
                origin,
                d,
                epsg,
                target_height_m=target_height_m,
                entry_height_m=entry_height_m,
                axes=None if axes is None else tuple(a[:, None, :] for a in axes),
            )
        else:
            if target_height_m is None:
                raise ValueError(
                    "target_height_m is required to convert ECEF rays to the scene frame"
                )
            rays = frames.rays_projected_from_ecef(
                origin, d, epsg, target_height_m=target_height_m, entry_height_m=entry_height_m
            )
    return ShotGeometry(t, pos, vel, d, frame, rays, axes)
