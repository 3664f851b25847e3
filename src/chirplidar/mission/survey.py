"""From a mission's survey sections to per-shot geometry: the platform path, beams, shot clock,
chunks, and the rays cast on the scene's terrain.

Conventions
-----------
* Time: ``t_s = 0`` is the start of the path (UAV, aircraft) or the moment the satellite's nadir
  point crosses the scene centre; ``survey.start_s`` / ``stop_s`` select the span.
* Beams: body frame x forward, y right, z down (see :mod:`chirplidar.geometry.pointing`).
* Every shot-beam pair is one ray in the scene frame (:class:`frames.ProjectedRays`, true ranges
  through ``range_offset_m`` and ``metres_per_unit``). Its footprint is sampled by
  ``survey.subrays_per_beam`` sub-rays over the beam's 1/e^2 cone at the shot's range
  (:func:`footprints.footprint_subrays`, Gaussian weights).
* Seeds: chunk ``i`` draws from child ``i`` of ``SeedSequence(seed)``; inside a chunk the pointing
  jitter, the channel effects and the measurement noise each have their own named stream, so a
  chunk's result does not depend on which chunks ran before it, or where.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config.loader import ConfigError
from ..geometry import frames
from ..geometry.orbits import KeplerOrbit, TleOrbit
from ..geometry.paths import AircraftLines, OffTerrainError, UavPath, lawnmower, lawnmower_lines
from ..geometry.pointing import (Attitude, BeamPattern, ShotClock, conical_scan, nadir_beam,
                                 paired_beams_across_track, shot_geometry, shot_times)
from ..geometry.footprints import footprint_subrays
from ..geometry.raycast import cast_rays
from ..optics import beam_radius_m
from ..streams import stream

def chunk_seeds(seed: int, n_chunks: int) -> list[np.random.SeedSequence]:
    return np.random.SeedSequence(seed).spawn(n_chunks)


# ------------------------------------------------------------------------------------ planning
def _xy(points, coordinates: str, scene) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if coordinates == "scene_centre":
        p = p + np.asarray(scene.center_xy_m)
    return p


def orbit_over_scene(scene, orb, source: str) -> KeplerOrbit:
    """Kepler + J2 orbit whose geodetic nadir passes the scene centre at t = 0, at the height
    ``orb.altitude_m`` above the WGS-84 ellipsoid there.

    Start from the spherical solution (argument of latitude u with sin(lat) = sin(i) sin(u);
    RAAN from the longitude; a = R_E + altitude) and refine RAAN, the mean anomaly and the
    semi-major axis by Newton steps on the satellite's geodetic latitude, longitude and height
    (pyproj), to far below a millimetre.
    """
    from ..units import WGS84_A_M

    cx, cy = scene.center_xy_m
    lat_c, lon_c, _ = frames.projected_to_geodetic(np.array(cx), np.array(cy), np.array(0.0),
                                                   scene.epsg)
    lat_c, lon_c = float(lat_c), float(lon_c)
    inc = np.radians(orb.inclination_deg)
    s = np.sin(np.radians(lat_c)) / np.sin(inc)
    if abs(s) > 1.0:
        raise ConfigError(f"{source}: platform.orbit.inclination_deg = {orb.inclination_deg:g} "
                          f"never reaches the scene's latitude {lat_c:.3f} deg: the ground track "
                          "never crosses the scene")
    u = np.arcsin(s)
    if orb.pass_direction == "descending":
        u = np.pi - u
    raan = np.radians(lon_c) - np.arctan2(np.cos(inc) * np.sin(u), np.cos(u))

    def make(raan_rad, m_rad, a_m):
        return KeplerOrbit(a_m, orb.eccentricity, inc, raan_rad, 0.0, m_rad, 0.0, j2=orb.j2)

    def nadir(x):
        p = make(*x).positions(np.zeros(1))[0]
        lat, lon, h = frames.ecef_to_geodetic(p[0], p[1], p[2])
        return np.array([float(lat) - lat_c, (float(lon) - lon_c + 180.0) % 360.0 - 180.0,
                         (float(h) - orb.altitude_m) * 1e-5])   # 1 m ~ 1e-5 deg of arc

    x = np.array([raan, u, WGS84_A_M + orb.altitude_m])  # perigee argument 0: M ~ u for e ~ 0
    steps = np.array([1e-7, 1e-7, 1.0])
    for _ in range(12):
        f = nadir(x)
        if np.max(np.abs(f)) < 1e-10:  # degrees: 0.01 mm
            break
        jac = np.empty((3, 3))
        for k in range(3):
            dx = np.zeros(3)
            dx[k] = steps[k]
            jac[:, k] = (nadir(x + dx) - f) / steps[k]
        x = x - np.linalg.solve(jac, f)
    return make(*x)


@dataclass(frozen=True)
class SurveyPlan:
    """Everything fixed for a whole run: path, beams, attitude and the shot clock."""

    path: object
    beams: BeamPattern
    attitude: Attitude
    jitter_rad_rms: float
    t_s: ShotClock | np.ndarray   # (n_shots,) shot times [s] (a campaign's: an array)
    chunk_shots: int
    epsg: int
    target_height_m: float     # chord ends of the scene-frame rays (below / above the terrain)
    entry_height_m: float
    window_height_m: float     # the range window's prediction surface: the scene's mid-height
    doppler_steering: bool = False
    doppler_compensation: str = "none"
    chunk_starts: np.ndarray | None = None   # campaign: first shot of each chunk (per pass)
    pass_starts_s: np.ndarray | None = None  # campaign: start of each pass [s] (its track)

    @property
    def n_shots(self) -> int:
        return int(self.t_s.size)

    @property
    def n_chunks(self) -> int:
        if self.chunk_starts is not None:
            return max(1, len(self.chunk_starts))
        return max(1, -(-self.n_shots // self.chunk_shots))

    def chunk_times(self, index: int) -> np.ndarray:
        if self.chunk_starts is not None:
            if len(self.chunk_starts) == 0:
                return self.t_s[:0]
            a = self.chunk_starts[index]
            b = self.chunk_starts[index + 1] if index + 1 < len(self.chunk_starts) \
                else self.n_shots
            return self.t_s[a:b]
        return self.t_s[index * self.chunk_shots:(index + 1) * self.chunk_shots]

    def chunk_start(self, index: int) -> int:
        """Index of chunk ``index``'s first shot in :attr:`t_s`."""
        if self.chunk_starts is not None:
            return int(self.chunk_starts[index]) if len(self.chunk_starts) else 0
        return index * self.chunk_shots

    def locate(self, shot: int) -> tuple[int, int]:
        """(chunk, index within it) of shot ``shot`` of :attr:`t_s`."""
        if self.chunk_starts is not None:
            c = int(np.searchsorted(self.chunk_starts, shot, side="right")) - 1
            return c, shot - int(self.chunk_starts[c])
        return divmod(shot, self.chunk_shots)

    def track_of(self, t_s) -> np.ndarray:
        """(n,) track of each shot time: a campaign's pass number, else :func:`track_index`."""
        if self.pass_starts_s is not None:
            return np.searchsorted(self.pass_starts_s, np.asarray(t_s, float),
                                   side="right").astype(np.int64) - 1
        return track_index(self.path, t_s)


def beam_pattern(b) -> BeamPattern:
    if b.pattern == "nadir":
        return nadir_beam()
    if b.pattern == "paired":
        return paired_beams_across_track(np.radians(b.pair_spacing_deg),
                                         np.radians(b.within_pair_deg),
                                         np.radians(b.stagger_deg), b.pair_power_ratio)
    if b.pattern == "conical":
        return conical_scan(np.radians(b.cone_half_angle_deg), np.radians(b.scan_rate_deg_s))
    return BeamPattern(np.radians(b.off_nadir_deg), np.radians(b.azimuth_deg))


def _path(config, scene, source: str):
    pf = config.platform
    if pf.kind == "satellite":
        if pf.orbit is not None:
            return orbit_over_scene(scene, pf.orbit, source)
        try:
            return TleOrbit(pf.tle.line1, pf.tle.line2, config.survey.epoch_utc)
        except ValueError as exc:
            raise ConfigError(f"{source}: platform.tle.{exc}") from None
    sec = pf.uav if pf.kind == "uav" else pf.aircraft
    key = f"platform.{pf.kind}"
    hdg = np.radians(sec.heading_deg) if sec.heading_deg is not None else None
    try:
        if pf.kind == "uav":
            legs = None   # waypoints: every leg is a track of its own
            if sec.survey_polygon_m is not None:
                xy, legs = lawnmower(_xy(sec.survey_polygon_m, sec.coordinates, scene),
                                     sec.line_spacing_m, hdg)
            else:
                xy = _xy(sec.waypoints_m, sec.coordinates, scene)
            w = np.column_stack([xy, np.full(len(xy), sec.altitude_m)])
            ground = scene.ground_height_m if sec.altitude_mode == "above_ground" else None
            return UavPath(w, sec.speed_mps, sec.altitude_mode, ground, segment_tracks=legs,
                           max_climb_mps=sec.max_climb_mps, max_descent_mps=sec.max_descent_mps)
        if sec.survey_polygon_m is not None:
            lines = lawnmower_lines(_xy(sec.survey_polygon_m, sec.coordinates, scene),
                                    sec.line_spacing_m, hdg)
        else:
            pts = _xy(sec.waypoints_m, sec.coordinates, scene)
            if len(pts) % 2:
                raise ValueError("waypoints_m of an aircraft are (start, end) pairs of straight "
                                 f"lines: an even number is needed, got {len(pts)}")
            lines = [(pts[i], pts[i + 1]) for i in range(0, len(pts), 2)]
        return AircraftLines(lines, sec.altitude_m, sec.speed_mps, sec.turn_radius_m)
    except OffTerrainError as exc:
        x0, x1, y0, y1 = scene.bounds_xy
        raise ConfigError(f"{source}: {key}: {exc} (the scene {Path(scene.path).name} covers "
                          f"x {x0:.0f}..{x1:.0f} m, y {y0:.0f}..{y1:.0f} m"
                          f"{'; it has no-data holes' if getattr(scene.terrain, 'holes', 0) else ''}"
                          ")") from None
    except ValueError as exc:
        raise ConfigError(f"{source}: {key}: {exc}") from None


def flight_section(config):
    """``[platform.uav]`` or ``[platform.aircraft]``, or None for a satellite."""
    pf = config.platform
    return pf.uav if pf.kind == "uav" else pf.aircraft if pf.kind == "aircraft" else None


def survey_polygon_xy(config, scene) -> np.ndarray | None:
    """(k, 2) projected x, y [m] of the mission's survey polygon (UAV or aircraft
    ``survey_polygon_m``), or None when the path is given by waypoints or an orbit."""
    sec = flight_section(config)
    if sec is None or sec.survey_polygon_m is None:
        return None
    return _xy(sec.survey_polygon_m, sec.coordinates, scene)


def track_index(path, t_s) -> np.ndarray:
    """(n,) track of each shot time: the survey line of a UAV or aircraft (-1 in turns and
    transits; a waypoint path's legs are numbered), 0 for a satellite pass."""
    if hasattr(path, "track_index"):
        return np.asarray(path.track_index(t_s), dtype=np.int64)
    return np.zeros(np.shape(t_s), dtype=np.int64)


#: The shot times of a run are held in memory (8 bytes each): 2e8 shots is 1.6 GB, six times a
#: one-hour UAV flight at 9.4 kHz.
MAX_SURVEY_SHOTS = 2e8


def plan_survey(config, scene, source: str) -> SurveyPlan:
    """The run's path, beams and shot clock; ConfigError (naming ``source`` and the key) on
    sections that are missing or a span the path cannot fly."""
    missing = [k for k in ("scene", "platform", "attitude", "beams", "survey")
               if getattr(config, k) is None]
    if missing:
        raise ConfigError(f"{source}: a survey run needs the sections "
                          f"{', '.join('[' + m + ']' for m in missing)}")
    sv = config.survey
    path = _path(config, scene, source)
    att = config.attitude
    beams = beam_pattern(config.beams)
    attitude = Attitude(np.radians(att.roll_deg), np.radians(att.pitch_deg),
                        np.radians(att.yaw_deg))
    chunk_starts = pass_starts = None
    if sv.start_utc is not None:
        segments = _campaign_segments(path, scene, beams, attitude, config, source)
        pieces = [shot_times(a, b, sv.prf_hz) for a, b in segments]
        t = np.concatenate(pieces) if pieces else np.zeros(0)
        # Each pass is one or more chunks (a chunk never spans two passes).
        sizes = [len(p) for p in pieces]
        first = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int) if sizes else []
        chunk_starts = np.array([f + k for f, m in zip(first, sizes)
                                 for k in range(0, m, sv.chunk_shots)], dtype=int)
        pass_starts = np.array([a for a, _ in segments], float)
    else:
        stop = sv.stop_s
        if stop is None:
            if not hasattr(path, "duration_s"):
                raise ConfigError(f"{source}: survey.stop_s is required for a satellite")
            stop = path.duration_s
        if isinstance(path, TleOrbit):
            try:
                path.check_window(sv.start_s, stop, "survey.epoch_utc")
            except ValueError as exc:
                raise ConfigError(f"{source}: {exc}") from None
        if hasattr(path, "duration_s") and stop > path.duration_s * (1 + 1e-12):
            raise ConfigError(f"{source}: survey.stop_s = {stop:g} s is after the end of the "
                              f"path ({path.duration_s:.1f} s)")
        if sv.start_s > stop:
            raise ConfigError(f"{source}: survey.start_s = {sv.start_s:g} s is after the end of "
                              f"the span ({stop:g} s" + (", the end of the path)" if sv.stop_s
                                                         is None else ", survey.stop_s)"))
        n_shots = (stop - sv.start_s) * sv.prf_hz
        if n_shots > MAX_SURVEY_SHOTS:
            raise ConfigError(f"{source}: survey.start_s..stop_s ({sv.start_s:g}..{stop:g} s) "
                              f"at survey.prf_hz = {sv.prf_hz:g} Hz is {n_shots:.3g} shots, more "
                              f"than a run holds ({MAX_SURVEY_SHOTS:.0e}): split it into "
                              "several runs")
        t = ShotClock.between(sv.start_s, stop, sv.prf_hz)
    z0, z1 = scene.height_range_m
    margin = 1.0 + 1e-3 * (z1 - z0)
    return SurveyPlan(path=path, beams=beams, attitude=attitude,
                      jitter_rad_rms=att.jitter_rad_rms, t_s=t, chunk_shots=sv.chunk_shots,
                      epsg=scene.epsg, target_height_m=z0 - margin, entry_height_m=z1 + margin,
                      window_height_m=0.5 * (z0 + z1), doppler_steering=att.doppler_steering,
                      doppler_compensation=sv.doppler_compensation,
                      chunk_starts=chunk_starts, pass_starts_s=pass_starts)


def _campaign_segments(path, scene, beams, attitude, config, source) -> list[tuple[float, float]]:
    """(start, stop) [s after survey.epoch_utc] of every pass between survey.start_utc and
    stop_utc in which a beam can reach the scene: the passes whose nadir enters the scene's
    extent widened by the beams' largest ground offset from nadir (one pass over that reach
    never misses a beam's crossing), one PRF period added at each end."""
    from shapely.geometry import box

    from ..analysis.passes import Region, EpochOrbit, find_passes
    from ..geometry import earth_orientation as eo

    sv = config.survey
    epoch = eo.mjd_utc(sv.epoch_utc)
    t0 = (eo.mjd_utc(sv.start_utc) - epoch) * 86400.0
    t1 = (eo.mjd_utc(sv.stop_utc) - epoch) * 86400.0
    if isinstance(path, TleOrbit):
        try:
            path.check_window(t0, t1, "survey.start_utc / stop_utc")
        except ValueError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        orbit = path
    else:
        orbit = EpochOrbit(path, epoch)
    p0 = path.positions(np.array([0.0 if t0 <= 0 <= t1 else t0]))[0]
    height = float(frames.ecef_to_geodetic(*p0)[2])
    tilt = float(np.max(beams.off_nadir_rad)) + abs(float(np.max(np.abs(
        np.atleast_1d(attitude.pitch_rad))))) + abs(float(np.max(np.abs(
            np.atleast_1d(attitude.roll_rad)))))
    reach = height * np.tan(tilt) + 1000.0
    x0, x1, y0, y1 = scene.bounds_xy
    lat, lon = scene.center_lat_lon_deg
    region = Region(str(scene.path), f"EPSG:{scene.epsg}",
                    box(x0, y0, x1, y1).buffer(reach), (lon, lat), float(np.mean(
                        scene.height_range_m)))
    try:
        found = find_passes(orbit, region, eo.parse_utc(sv.start_utc), (t1 - t0) / 86400.0)
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if not found:
        raise ConfigError(f"{source}: no pass over the scene {Path(scene.path).name} between "
                          f"survey.start_utc = {sv.start_utc} and stop_utc = {sv.stop_utc}")
    dt = 1.0 / sv.prf_hz
    return [(p.t_entry_s - dt, p.t_exit_s + dt) for p in found]


# ------------------------------------------------------------------------------------ geometry
@dataclass(frozen=True)
class ChunkGeometry:
    """Per shot (n) and beam (b) and, for footprints, sub-ray (k). Misses: inf ranges, code -1."""

    t_s: np.ndarray              # (n,)
    track: np.ndarray            # (n,) survey line or pass (:func:`track_index`)
    platform_xyh: np.ndarray     # (n, 3) scene x, y [m] and ellipsoidal height [m]
    off_nadir_rad: np.ndarray    # (n, b)
    azimuth_rad: np.ndarray      # (n, b) clockwise from true north
    closing_speed_mps: np.ndarray  # (n, b) platform velocity along the beam (approaching > 0)
    doppler_speed_mps: np.ndarray  # (n, b) the part of it the receiver sees as a Doppler shift
    rays: frames.ProjectedRays   # (n, b)
    range_true_m: np.ndarray     # (n, b) centre ray
    range_predicted_m: np.ndarray  # (n, b) centre ray to the plan's window_height_m surface
    beam_power_share: np.ndarray   # (b,) each beam's share of the transmitter power (mean 1)
    hit_xyz_m: np.ndarray        # (n, b, 3) centre ray hit in the scene frame
    incidence_rad: np.ndarray    # (n, b)
    material: np.ndarray         # (n, b) int codes, -1 on a miss
    beam_radius_m: np.ndarray    # (n, b) 1/e^2 radius at the centre range (nan on a miss)
    sub_range_m: np.ndarray      # (n, b, k)
    sub_weight: np.ndarray       # (n, b, k) Gaussian beam weights, sum 1 per shot-beam
    sub_incidence_rad: np.ndarray  # (n, b, k)
    sub_material: np.ndarray     # (n, b, k)

    def point_at_range(self, range_m) -> np.ndarray:
        """Scene-frame point (n, b, 3) at true ``range_m`` (n, b) along each centre ray."""
        r = self.rays
        t = (np.asarray(range_m, float) - r.range_offset_m) / r.metres_per_unit
        return r.origin_m + t[..., None] * r.direction


def _angles(path_frame: str, pos, d, epsg, axes=None):
    """Off-nadir angle, azimuth from true north and ECEF beam directions for (n, b) beams
    (``axes``: the positions' ``frames.grid_axes_ecef`` when already computed)."""
    if path_frame == "ecef":
        lat, lon, _ = frames.ecef_to_geodetic(pos[:, 0], pos[:, 1], pos[:, 2])
        enu = frames.enu_basis(lat, lon)  # (n, 3, 3) rows east, north, up
        e, nth, u = (np.einsum("nbj,nj->nb", d, enu[:, i]) for i in range(3))
    else:
        # d is in the true local frame of grid x, grid y and up: east and north are its
        # horizontal part turned by the grid convergence (grid north = true north + gamma).
        if axes is None:
            lon = frames.projected_to_geodetic(pos[:, 0], pos[:, 1], pos[:, 2], epsg)[1]
        else:   # the ellipsoid normal's longitude is the geodetic longitude
            lon = np.degrees(np.arctan2(axes[3][:, 1], axes[3][:, 0]))
        c, s = (a[:, None] for a in frames.grid_convergence(lon, epsg))
        e = c * d[..., 0] + s * d[..., 1]
        nth = -s * d[..., 0] + c * d[..., 1]
        u = d[..., 2]
    return np.arccos(np.clip(-u, -1.0, 1.0)), np.mod(np.arctan2(e, nth), 2 * np.pi)


#: Footprint sub-rays cast at a time (:func:`chunk_geometry`): ~25 MB of temporaries.
_SUBRAY_BATCH = 1 << 17


def chunk_geometry(plan: SurveyPlan, scene, config, t_s, seq: np.random.SeedSequence,
                   n_sub: int) -> ChunkGeometry:
    """Cast every shot's beams and footprint sub-rays on the scene terrain."""
    n, b = t_s.size, plan.beams.n_beams
    jit = stream(seq, "jitter") if plan.jitter_rad_rms > 0 else None
    sg = shot_geometry(plan.path, t_s, plan.beams, plan.attitude, epsg=plan.epsg,
                       jitter_rad_rms=plan.jitter_rad_rms, rng=jit,
                       target_height_m=plan.target_height_m, entry_height_m=plan.entry_height_m,
                       doppler_steering=plan.doppler_steering)
    rays = sg.rays
    if sg.frame == "ecef":
        platform = frames.ecef_to_projected(sg.position_m, plan.epsg) if n else np.zeros((0, 3))
    else:
        platform = sg.position_m
    if n:
        off, az = _angles(sg.frame, sg.position_m, sg.direction, plan.epsg, sg.axes_ecef)
    else:
        off = az = np.zeros((0, b))
    closing = np.einsum("nj,nbj->nb", sg.velocity_mps, sg.direction)
    seen = closing
    if plan.doppler_compensation == "lo_offset":
        # Each beam's LO shifted by the Doppler of its nominal (jitter-free) pointing.
        nominal = sg.direction if plan.jitter_rad_rms == 0 else shot_geometry(
            plan.path, t_s, plan.beams, plan.attitude,
            doppler_steering=plan.doppler_steering).direction
        seen = closing - np.einsum("nj,nbj->nb", sg.velocity_mps, nominal)
    o = rays.origin_m.reshape(-1, 3)
    d = rays.direction.reshape(-1, 3)
    centre = cast_rays(scene.terrain, o, d)
    valid = rays.valid.reshape(-1)
    t_hit = np.where(valid & centre.hit, centre.ranges_m, np.inf)
    rng_true = rays.range_m(t_hit.reshape(n, b))
    # The range window's prediction: where the chord reaches the window surface's height (the
    # chord's height is linear in its parameter between its two end heights).
    with np.errstate(divide="ignore", invalid="ignore"):
        t_pred = (plan.window_height_m - rays.origin_m[..., 2]) / rays.direction[..., 2]
    rng_pred = rays.range_m(np.where(np.isfinite(t_pred), t_pred, np.inf))
    hit = np.isfinite(rng_true)
    mat = np.where(hit, centre.material_codes.reshape(n, b), -1)
    inc = np.where(hit, centre.incidence_rad.reshape(n, b), np.inf)
    ch = config.channel
    w = np.where(hit, beam_radius_m(ch.beam_radius_m, ch.divergence_half_angle_rad,
                                    np.where(hit, rng_true, 1.0)), np.nan)
    # Footprint: a cone of survey.footprint_extent times the beam's 1/e^2 half-angle at the
    # median range of the chunk (the pattern's angular size; every shot's own footprint scales
    # with its own range).
    if np.any(hit):
        r_med = float(np.median(rng_true[hit]))
        theta = float(beam_radius_m(ch.beam_radius_m, ch.divergence_half_angle_rad, r_med)) / r_med
    else:
        theta = max(ch.divergence_half_angle_rad, 1e-9)
    # Cast in batches of about _SUBRAY_BATCH rays: a chunk's temporaries stay a few tens of MB
    # whatever its size (each ray's result does not depend on its batch).
    step = max(1, _SUBRAY_BATCH // max(n_sub, 1))
    parts = []
    for a in range(0, max(n * b, 1), step):
        so, sd, sw = footprint_subrays(o[a:a + step], d[a:a + step], theta, n_sub, rng=None,
                                       extent_factor=config.survey.footprint_extent)
        hits = cast_rays(scene.terrain, so, sd)
        parts.append((sw, np.where(hits.hit, hits.ranges_m, np.inf), hits.incidence_rad,
                      hits.material_codes))
    sw, t_sub, sub_inc, sub_mat = (np.concatenate(p) for p in zip(*parts, strict=True))
    k = sw.shape[1]
    t_sub = t_sub.reshape(n, b, k)
    t_sub = np.where(valid.reshape(n, b, 1), t_sub, np.inf)
    with np.errstate(invalid="ignore"):
        sub_r = rays.range_offset_m[..., None] + t_sub * rays.metres_per_unit[..., None]
    sub_r = np.where(np.isfinite(t_sub), sub_r, np.inf)
    return ChunkGeometry(
        t_s=t_s, track=plan.track_of(t_s), platform_xyh=np.asarray(platform, float), off_nadir_rad=off, azimuth_rad=az,
        closing_speed_mps=closing, doppler_speed_mps=seen, rays=rays, range_true_m=rng_true, range_predicted_m=rng_pred,
        beam_power_share=plan.beams.power_share,
        hit_xyz_m=np.where(hit[..., None], centre.points_m.reshape(n, b, 3), np.nan),
        incidence_rad=inc, material=mat, beam_radius_m=w, sub_range_m=sub_r,
        sub_weight=sw.reshape(n, b, k), sub_incidence_rad=sub_inc.reshape(n, b, k),
        sub_material=sub_mat.reshape(n, b, k))


def check_crosses_scene(plan: SurveyPlan, scene, config, source: str, n_probe: int = 64):
    """ConfigError unless some probe shot over the span hits the terrain (before any work)."""
    if plan.n_shots == 0:
        return
    idx = np.unique(np.linspace(0, plan.n_shots - 1, min(n_probe, plan.n_shots)).astype(int))
    t = plan.t_s[idx]
    try:
        g = chunk_geometry(plan, scene, config, t, np.random.SeedSequence(0), 1)
    except ValueError as exc:
        raise ConfigError(f"{source}: [platform]: {exc}") from None
    if not np.any(np.isfinite(g.range_true_m)):
        x0, x1, y0, y1 = scene.bounds_xy
        px, py = g.platform_xyh[:, 0], g.platform_xyh[:, 1]
        ground = scene.ground_height_m(px, py)
        under = np.isfinite(ground)
        over_scene = bool(np.any((px >= x0) & (px <= x1) & (py >= y0) & (py <= y1)))
        if under.any() and np.all(g.platform_xyh[under, 2] <= ground[under]):
            raise ConfigError(
                f"{source}: [platform] the path flies below the terrain: the platform at "
                f"{g.platform_xyh[under, 2].min():.0f}..{g.platform_xyh[under, 2].max():.0f} m "
                f"over ground at {ground[under].min():.0f}..{ground[under].max():.0f} m "
                "(ellipsoidal heights); raise its altitude_m or fly altitude_mode = "
                "'above_ground'")
        raise ConfigError(
            f"{source}: [platform] " + (
                "the beams point off the scene" if over_scene else "the path never crosses the "
                "scene") + f" {Path(scene.path).name}: no beam of {idx.size} shots spread "
            f"over the survey span hits the terrain (beams up to "
            f"{np.degrees(np.nanmax(g.off_nadir_rad)):.3g} deg off nadir; platform x {px.min():.0f}..{px.max():.0f} m, y {py.min():.0f}..{py.max():.0f} m; "
            f"scene x {x0:.0f}..{x1:.0f} m, y {y0:.0f}..{y1:.0f} m)")
