"""Satellite passes over a region: when the geodetic nadir track enters it, in which direction,
how close to the centre, the beams' ground tracks, the off-nadir angle to the centre and the sun.

Nadir: the sub-satellite point, the geodetic latitude and longitude of the ECEF position on
WGS-84. A pass is one overflight whose nadir enters the region (its polygon in a projected frame:
the scene's EPSG, or for a GeoJSON polygon an azimuthal equidistant frame centred on it).

Algorithm (:func:`find_passes`): the nadir every ~20 s over the window (vectorised), its
ellipsoidal (pyproj.Geod) distance to the region centre; local minima below the polygon's
circumradius about the centre plus one coarse step of nadir motion plus 1 km are candidates
(conservative: any nadir point inside the polygon is within the circumradius, and some sample
lies within a step of it). Per candidate: the closest approach by a bounded scalar minimiser; the
nadir every 1 s within (circumradius + 2 km) / ground speed of it, as a polyline intersected
with the polygon (a grazing pass that cuts a corner is found); entry and exit refined by
bisection of "nadir inside the polygon" to < 0.01 s. A pass cut by the window's start or end is
reported from / to that edge. Several entries of one overflight (a concave polygon) are one pass,
from the first entry to the last exit.

All times are seconds on the orbit's clock (``orbit.states(t_s)``, ``t_s`` seconds after
``orbit.epoch_mjd``); angles in degrees, distances in metres unless a name says km.
"""

from __future__ import annotations

import datetime as _dt
import json
import sys
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path

import numpy as np
import shapely
from pyproj import Geod, Transformer
from shapely.geometry import LineString, Point, box, shape

from .. import _checks
from ..geometry import earth_orientation as eo
from ..geometry import frames
from ..geometry.orbits import TleOrbit
from ..geometry.pointing import Attitude, BeamPattern, beam_directions, zero_doppler_attitude
from ..geometry.sun import sun_elevation_deg

__all__ = ["EpochOrbit", "OrbitSource", "Pass", "Region", "find_passes", "format_passes",
           "orbit_from_mission", "orbit_from_tle_file", "passes_report", "region_from_geojson",
           "region_from_scene"]

COARSE_STEP_S = 20.0        # nadir screen: ~150 km of track per step
FINE_STEP_S = 1.0           # polyline of the nadir and beam tracks (~7 km: sag < 1 m)
TIME_TOL_S = 0.01           # bisection bracket of entry and exit
DENSIFY_M = 200.0           # boundary spacing for the circumradius
_GEOD = Geod(ellps="WGS84")


@cache
def _to_xy(crs: str) -> Transformer:
    return Transformer.from_crs("EPSG:4326", crs, always_xy=True)


# ------------------------------------------------------------------------------------ region
@dataclass(frozen=True)
class Region:
    """A polygon (or multipolygon) in a projected frame ``crs`` [m], its centre (lon, lat)
    [deg] and height above the ellipsoid [m]; ``source`` names the file."""

    source: str
    crs: str
    shape_xy: object
    centre_lonlat: tuple[float, float]
    height_m: float = 0.0

    @property
    def name(self) -> str:
        return Path(self.source).name

    def to_xy(self, lon, lat):
        return _to_xy(self.crs).transform(np.asarray(lon, float), np.asarray(lat, float))

    def to_lonlat(self, x, y):
        return _to_xy(self.crs).transform(np.asarray(x, float), np.asarray(y, float),
                                          direction="INVERSE")

    @cached_property
    def circumradius_m(self) -> float:
        """Largest ellipsoidal distance [m] from the centre to the (densified) boundary."""
        xy = shapely.get_coordinates(shapely.segmentize(self.shape_xy.boundary, DENSIFY_M))
        lon, lat = self.to_lonlat(xy[:, 0], xy[:, 1])
        return float(np.max(_distance_m(self.centre_lonlat, lon, lat)))


def _distance_m(centre_lonlat, lon, lat) -> np.ndarray:
    lon = np.asarray(lon, float)
    c = [np.full(lon.shape, v) for v in centre_lonlat]
    return np.asarray(_GEOD.inv(c[0], c[1], lon, np.asarray(lat, float))[2])


_SCENES: dict = {}


def _scene(path, overrides=None):
    """load_scene, remembering the last scene (the mission's orbit and region share it)."""
    from ..mission.scene import load_scene

    p = Path(path).resolve()
    key = (str(p), p.stat().st_mtime_ns if p.exists() else 0, repr(sorted((overrides or {})
                                                                           .items())))
    if key not in _SCENES:
        _SCENES.clear()
        _SCENES[key] = load_scene(p, overrides=overrides or {})
    return _SCENES[key]


def region_from_scene(path, overrides=None) -> Region:
    """The scene's terrain extent (a box in its EPSG frame), centre and ground height there
    (ConfigError, a ValueError, naming the file on a bad scene)."""
    from ..config.loader import tomllib

    try:   # a mission file given for a scene: say so in one line
        if "terrain" not in tomllib.loads(Path(path).read_text()):
            raise ValueError(f"{path}: not a scene file (no [terrain] section)")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        pass   # load_scene says what is wrong
    sc = _scene(path, overrides)
    x0, x1, y0, y1 = sc.bounds_xy
    lat, lon = sc.center_lat_lon_deg
    h = float(sc.ground_height_m(*sc.center_xy_m))
    if not np.isfinite(h):
        h = float(np.mean(sc.height_range_m))
    return Region(str(path), f"EPSG:{sc.epsg}", box(x0, y0, x1, y1), (lon, lat), h)


def region_from_geojson(path) -> Region:
    """A GeoJSON Polygon or MultiPolygon (a geometry, or a Feature, or a FeatureCollection of
    one feature) in WGS-84 lon/lat. Edges are straight in lon/lat (RFC 7946), densified to
    0.005 deg before projecting to the azimuthal equidistant frame centred on the polygon."""
    p = Path(path)
    try:
        obj = json.loads(p.read_text())
    except OSError as exc:
        raise ValueError(f"{p}: cannot read the region file ({exc.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{p}: not a GeoJSON file ({exc})") from None
    def kind(o):
        return (o.get("type") if isinstance(o, dict) else type(o).__name__) or "no geometry"

    if kind(obj) == "FeatureCollection":
        feats = obj.get("features") or []
        if len(feats) != 1:
            raise ValueError(f"{p}: a FeatureCollection of {len(feats)} features; the region "
                             "must be one Polygon or MultiPolygon")
        obj = feats[0]
    if kind(obj) == "Feature":
        obj = obj.get("geometry") or {}
    if kind(obj) not in ("Polygon", "MultiPolygon"):
        raise ValueError(f"{p}: the region must be a GeoJSON Polygon or MultiPolygon (a "
                         f"geometry, a Feature or a FeatureCollection of one); found "
                         f"{kind(obj)}")
    try:
        geom = shape(obj)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{p}: bad {kind(obj)} coordinates ({exc})") from None
    lon0, lat0, lon1, lat1 = geom.bounds
    if lon1 - lon0 > 180 and lon0 <= -180.0 + 1e-9 and lon1 >= 180.0 - 1e-9:
        # RFC 7946 3.1.9 splits a region at the antimeridian: put its western parts east of 180
        east = shapely.transform(geom, lambda a: np.column_stack(
            [np.where(a[:, 0] < 0, a[:, 0] + 360.0, a[:, 0]), a[:, 1]]))
        geom = shapely.union_all(shapely.get_parts(east))   # the two halves joined again
        lon0, lat0, lon1, lat1 = geom.bounds
    if not (geom.is_valid and geom.area > 0):
        raise ValueError(f"{p}: the {kind(obj)} is not a valid polygon of non-zero area"
                         f" ({shapely.is_valid_reason(geom)})")
    if lat0 < -90 or lat1 > 90 or lon1 - lon0 > 180:
        raise ValueError(f"{p}: coordinates must be WGS-84 lon, lat in degrees, spanning less "
                         f"than 180 deg of longitude (lon {lon0:g}..{lon1:g}, lat "
                         f"{lat0:g}..{lat1:g}); split at the antimeridian as RFC 7946 does")
    geom = shapely.segmentize(geom, 0.005)
    centre = ((lon0 + lon1) / 2, (lat0 + lat1) / 2)
    for _ in range(2):   # centre on the projected centroid (the lon/lat one is distorted)
        crs = f"+proj=aeqd +lat_0={centre[1]:.9f} +lon_0={centre[0]:.9f} +datum=WGS84 +units=m"
        t = _to_xy(crs)
        xy = shapely.transform(geom, lambda a, t=t: np.column_stack(t.transform(a[:, 0],
                                                                                a[:, 1])))
        c = xy.centroid
        centre = tuple(float(v) for v in t.transform(c.x, c.y, direction="INVERSE"))
    return Region(str(path), crs, xy, (centre[0], centre[1]), 0.0)


# ------------------------------------------------------------------------------------ orbits
@dataclass(frozen=True)
class EpochOrbit:
    """A design orbit whose ``t_s = 0`` is the MJD (UTC) ``epoch_mjd``."""

    orbit: object
    epoch_mjd: float
    frame: str = field(default="ecef", init=False)

    def states(self, t_s):
        return self.orbit.states(t_s)


@dataclass(frozen=True)
class OrbitSource:
    """An orbit (``states(t_s)`` in ECEF, ``epoch_mjd``), the satellite's name, the element
    set's epoch (None for a design orbit), the mission's beams and attitude (None from a TLE
    file) and the mission's scene file and scene keys."""

    orbit: object
    name: str
    tle_epoch_utc: str | None = None
    beams: BeamPattern | None = None
    attitude: Attitude | None = None
    doppler_steering: bool = False
    scene_file: Path | None = None
    scene_overrides: dict | None = None


def orbit_from_tle_file(path, start_utc) -> OrbitSource:
    """SGP4 orbit of a TLE file: 2 lines, or 3 (a name line first); t_s = 0 at ``start_utc``.
    ValueError naming the file on a bad file or checksum."""
    p = Path(path)
    try:
        lines = [ln.rstrip() for ln in p.read_text().splitlines() if ln.strip()]
    except OSError as exc:
        raise ValueError(f"{p}: cannot read the TLE file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a TLE file (not text)") from None
    if len(lines) not in (2, 3):
        raise ValueError(f"{p}: a TLE file has 2 lines (line 1, line 2) or 3 (a name, then "
                         f"the two); found {len(lines)} non-empty lines")
    l1, l2 = lines[-2:]
    try:
        orbit = TleOrbit(l1, l2, start_utc)
    except ValueError as exc:
        raise ValueError(f"{p}: {exc}") from None
    name = lines[0].strip().removeprefix("0 ") if len(lines) == 3 else f"NORAD {l1[2:7].strip()}"
    return OrbitSource(orbit, name, eo.mjd_iso(orbit.tle_epoch_mjd))


def orbit_from_mission(path, start_utc) -> OrbitSource:
    """A satellite mission's orbit (its TLE, t_s = 0 at ``start_utc``; or its design orbit
    placed over its scene, t_s = 0 at ``survey.epoch_utc``), beams and attitude. ConfigError
    naming the file and key."""
    from ..config.loader import ConfigError, load_mission, scene_overrides
    from ..mission.survey import beam_pattern, orbit_over_scene

    src = str(path)
    if not Path(path).is_file():
        raise ConfigError(f"{src}: mission file does not exist")
    cfg = load_mission(path)
    pf = cfg.platform
    if pf is None or pf.kind != "satellite":
        raise ConfigError(f"{src}: passes need a satellite mission (platform.kind = "
                          f"'satellite'), found {'no [platform]' if pf is None else pf.kind}")
    beams = beam_pattern(cfg.beams) if cfg.beams is not None else None
    a = cfg.attitude
    att = None if a is None else Attitude(*np.radians([a.roll_deg, a.pitch_deg, a.yaw_deg]))
    steering = a is not None and a.doppler_steering
    scene = None if cfg.scene is None else (Path(path).parent / cfg.scene.file)
    changes = scene_overrides(cfg)
    if pf.tle is not None:
        try:
            orbit = TleOrbit(pf.tle.line1, pf.tle.line2, start_utc)
        except ValueError as exc:
            raise ConfigError(f"{src}: platform.tle.{exc}") from None
        return OrbitSource(orbit, f"NORAD {orbit.line1[2:7].strip()} ({Path(path).name})",
                           eo.mjd_iso(orbit.tle_epoch_mjd), beams, att, steering, scene, changes)
    if scene is None or cfg.survey is None:
        raise ConfigError(f"{src}: a design orbit ([platform.orbit]) is placed over the "
                          "mission's [scene] at survey.epoch_utc: both are needed")
    orbit = orbit_over_scene(_scene(scene, changes), pf.orbit, src)
    return OrbitSource(EpochOrbit(orbit, eo.mjd_utc(cfg.survey.epoch_utc)),
                       f"{Path(path).name} (design orbit)", None, beams, att, steering, scene,
                       changes)


# ------------------------------------------------------------------------------------ passes
@dataclass(frozen=True)
class Pass:
    """One pass: entry / exit / closest approach (ISO 8601 UTC), ``direction`` of the nadir
    (ascending: geodetic latitude increasing), distances in km, angles in degrees; ``beams``
    [{"beam": k, "track_lonlat": [[lon, lat], ...]}] and the nadir's track through the region."""

    start_utc: str
    end_utc: str
    direction: str
    duration_s: float
    closest_utc: str
    closest_distance_km: float
    off_nadir_to_centre_deg: float
    sun_elevation_deg: float
    beams: list
    nadir_track_lonlat: list
    t_entry_s: float = 0.0      # entry and exit on the orbit's clock (s after its epoch)
    t_exit_s: float = 0.0

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__ if not k.startswith("t_")}


def _nadir(orbit, t):
    p, v = orbit.states(np.atleast_1d(np.asarray(t, float)))
    lat, lon, _ = frames.ecef_to_geodetic(p[:, 0], p[:, 1], p[:, 2])
    return p, v, lat, lon


def _inside(orbit, region, t) -> np.ndarray:
    _, _, lat, lon = _nadir(orbit, t)
    return shapely.contains_xy(region.shape_xy, *region.to_xy(lon, lat))


def _bisect(orbit, region, a, b) -> np.ndarray:
    """Times [s] where the nadir crosses the polygon's edge, between times ``a`` and ``b`` on
    either side of it (one inside, one outside), by vectorised bisection to TIME_TOL_S."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ia = _inside(orbit, region, a)
    while a.size and np.max(np.abs(b - a)) > TIME_TOL_S:
        m = 0.5 * (a + b)
        same = _inside(orbit, region, m) == ia
        a, b = np.where(same, m, a), np.where(same, b, m)
    return 0.5 * (a + b)


def _clip(region, xy: np.ndarray) -> list:
    """[[lon, lat], ...] of the polyline ``xy`` (k, 2) inside the region."""
    if len(xy) < 2:
        return []
    parts = LineString(xy).intersection(region.shape_xy)
    pts = [c for g in getattr(parts, "geoms", [parts]) if g.geom_type == "LineString"
           for c in g.coords]
    if not pts:
        return []
    lon, lat = region.to_lonlat(*np.array(pts).T)
    return np.round(np.column_stack([lon, lat]), 7).tolist()


def _crossing_pieces(orbit, region, lo, hi):
    """(first entry estimate, time inside, last time inside, last exit estimate) from the 1 s
    nadir polyline over [lo, hi] against the polygon; None when it does not enter."""
    t = np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / FINE_STEP_S)) + 1))
    _, _, lat, lon = _nadir(orbit, t)
    xy = np.column_stack(region.to_xy(lon, lat))
    line = LineString(xy)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    spans = []
    inter = line.intersection(region.shape_xy)
    for g in getattr(inter, "geoms", [inter]):
        if g.geom_type == "LineString" and g.length > 0:
            s = sorted(line.project(Point(c)) for c in (g.coords[0], g.coords[-1]))
            spans.append(np.interp(s, cum, t))
    ok = [s for s in sorted(spans, key=lambda s: s[0])
          if _inside(orbit, region, [0.5 * (s[0] + s[1])])[0]]
    if not ok:
        return None
    return ok[0][0], 0.5 * (ok[0][0] + ok[0][1]), 0.5 * (ok[-1][0] + ok[-1][1]), ok[-1][1]


def find_passes(orbit, region: Region, start_utc, days, beams=None, attitude=None,
                region_height_m=0.0, *, doppler_steering: bool = False,
                progress: bool = False) -> list[Pass]:
    """Every pass of ``orbit`` whose nadir enters ``region`` between ``start_utc`` and
    ``days`` later (module docstring for the method), in time order; [] when none.

    beams (BeamPattern) and attitude (Attitude): the beams' ground tracks through the region, on
    the ellipsoid at ``region_height_m`` [m] (also the height of the centre point that the
    off-nadir angle points at); ``doppler_steering``: the mission's per-shot pitch
    (:func:`zero_doppler_attitude`). ValueError naming --start/--days for a window beyond the TLE's
    validity (``TleOrbit.check_window``)."""
    from scipy.optimize import minimize_scalar
    from tqdm import tqdm

    t0 = (eo.mjd_utc(eo.parse_utc(start_utc, "start_utc")) - orbit.epoch_mjd) * 86400.0
    t1 = t0 + _checks.positive("days", days) * 86400.0
    if hasattr(orbit, "check_window"):
        orbit.check_window(t0, t1, "--start/--days")
    t = np.linspace(t0, t1, int(np.ceil((t1 - t0) / COARSE_STEP_S)) + 1)
    lon = np.empty_like(t)
    lat = np.empty_like(t)
    chunks = np.array_split(np.arange(t.size), max(1, t.size // 4320))   # ~a day each
    for idx in tqdm(chunks, desc="passes", unit="day", disable=not progress, file=sys.stderr):
        lat[idx], lon[idx] = _nadir(orbit, t[idx])[2:]
    d = _distance_m(region.centre_lonlat, lon, lat)
    step = np.asarray(_GEOD.inv(lon[:-1], lat[:-1], lon[1:], lat[1:])[2]) if t.size > 1 else [0]
    reach = region.circumradius_m + 1e3
    pad = np.concatenate([[np.inf], d, [np.inf]])
    cand = np.flatnonzero((d <= pad[:-2]) & (d <= pad[2:]) & (d < reach + np.max(step)))

    def dist(x):
        _, _, la, lo = _nadir(orbit, x)
        return float(_distance_m(region.centre_lonlat, lo, la)[0])

    found = []
    for k in cand:
        a, b = t[max(k - 1, 0)], t[min(k + 1, t.size - 1)]
        tc = minimize_scalar(dist, bounds=(a, b), method="bounded",
                             options={"xatol": 1e-3}).x if b > a else a
        speed = np.max(step[max(k - 1, 0):k + 1]) / max(t[1] - t[0], 1e-9)
        half = 1.2 * (reach + 1e3) / max(speed, 1e3) + 2.0
        got = _crossing_pieces(orbit, region, max(t0, tc - half), min(t1, tc + half))
        if got is not None:
            found.append((tc, *got))
    if not found:
        return []
    ends = np.array([(f[1], f[2], f[3], f[4]) for f in found])
    before = np.maximum(ends[:, 0] - FINE_STEP_S, t0)
    after = np.minimum(ends[:, 3] + FINE_STEP_S, t1)
    # A pass under way at the window's edge starts (ends) there.
    entry = np.where(_inside(orbit, region, before), before, _bisect(orbit, region, ends[:, 1],
                                                                     before))
    exit_ = np.where(_inside(orbit, region, after), after, _bisect(orbit, region, ends[:, 2],
                                                                   after))
    passes, last = [], -np.inf
    for (tc, *_), ti, to in sorted(zip(found, entry, exit_), key=lambda r: r[1]):
        if ti <= last:   # the same overflight found twice
            continue
        last = to
        passes.append(_describe(orbit, region, float(tc), float(ti), float(to), t0, t1, beams,
                                attitude, float(region_height_m), doppler_steering))
    return passes


def _describe(orbit, region, tc, ti, to, t0, t1, beams, attitude, height, steering) -> Pass:
    p, v, lat, lon = _nadir(orbit, tc)
    enu = frames.enu_basis(lat, lon)[0]
    c = np.array(frames.geodetic_to_ecef(region.centre_lonlat[1], region.centre_lonlat[0],
                                         height), float)
    los = (c - p[0]) / np.linalg.norm(c - p[0])
    off = np.degrees(np.arccos(np.clip(-enu[2] @ los, -1.0, 1.0)))
    sun = sun_elevation_deg(region.centre_lonlat[1], region.centre_lonlat[0],
                            orbit.epoch_mjd + tc / 86400.0)
    tn = np.linspace(ti, to, max(2, int(np.ceil((to - ti) / FINE_STEP_S)) + 1))
    _, _, la, lo = _nadir(orbit, tn)
    nadir = np.round(np.column_stack([lo, la]), 7).tolist()
    tracks = []
    if beams is not None:
        def ground(tb):
            pb, vb, la_b, lo_b = _nadir(orbit, tb)
            up = frames.local_up_ecef(la_b, lo_b)
            att = zero_doppler_attitude(attitude, vb, up) if steering else attitude
            dirs = beam_directions(vb / np.linalg.norm(vb, axis=1, keepdims=True), up, att, beams,
                                   t_s=tb)
            origin = np.broadcast_to(pb[:, None, :], dirs.shape)
            hit = origin + frames.ray_ellipsoid_distance_m(origin, dirs, height)[..., None] * dirs
            return hit, la_b, lo_b

        hit, la_c, lo_c = ground(np.array([tc]))
        ok = np.isfinite(hit[0, :, 0])
        gl, gb, _ = frames.ecef_to_geodetic(*hit[0, ok].T)
        spread = np.max(_distance_m((lo_c[0], la_c[0]), gb, gl), initial=0.0)
        speed = np.linalg.norm(v[0]) * frames.WGS84_A_M / np.linalg.norm(p[0])
        ext = spread / speed + FINE_STEP_S   # beams ahead of / beside the nadir: widen the span
        tb = np.linspace(max(t0, ti - ext), min(t1, to + ext),
                         max(2, int(np.ceil((to - ti + 2 * ext) / FINE_STEP_S)) + 1))
        hit = ground(tb)[0]
        for k in range(beams.n_beams):
            h = hit[:, k][np.isfinite(hit[:, k, 0])]
            xy = np.empty((0, 2))
            if len(h):
                bl, bo, _ = frames.ecef_to_geodetic(*h.T)
                xy = np.column_stack(region.to_xy(bo, bl))
            tracks.append({"beam": k, "track_lonlat": _clip(region, xy)})
    utc = [eo.mjd_iso(orbit.epoch_mjd + x / 86400.0) for x in (ti, to, tc)]
    return Pass(utc[0], utc[1], "ascending" if v[0] @ enu[1] > 0 else "descending",
                round(to - ti, 3), utc[2],
                round(float(_distance_m(region.centre_lonlat, lon, lat)[0]) / 1e3, 4),
                round(float(off), 4), round(float(sun), 3), tracks, nadir, float(ti), float(to))


# ------------------------------------------------------------------------------------ reports
def passes_report(passes, region: Region, source: OrbitSource, start_utc, days) -> dict:
    """The JSON object of ``chirplidar passes --json``."""
    t = eo.parse_utc(start_utc, "start_utc")
    return {"passes": [p.to_json() for p in passes],
            "window": {"start_utc": eo.utc_iso(t),
                       "end_utc": eo.utc_iso(t + _dt.timedelta(days=float(days)))},
            "region": {"source": region.source, "crs": region.crs,
                       "centre_lonlat": [round(v, 7) for v in region.centre_lonlat],
                       "height_m": round(region.height_m, 2)},
            "satellite": source.name, "tle_epoch_utc": source.tle_epoch_utc}


def format_passes(report: dict) -> str:
    """A readable table of :func:`passes_report`, one row per pass."""
    w, r = report["window"], report["region"]
    lines = [(f"passes of {report['satellite']} over {Path(r['source']).name} (centre "
              f"{r['centre_lonlat'][1]:.4f}, {r['centre_lonlat'][0]:.4f}) from "
              f"{w['start_utc']} to {w['end_utc']}: {len(report['passes'])}"),
             (f"  {'entry (UTC)':<24} {'exit (UTC)':<24} {'direction':<10} {'dur s':>6} "
              f"{'closest (UTC)':<24} {'dist km':>8} {'off-nadir deg':>13} {'sun el deg':>10}")]
    for p in report["passes"]:
        lines.append(f"  {p['start_utc']:<24} {p['end_utc']:<24} {p['direction']:<10} "
                     f"{p['duration_s']:6.1f} {p['closest_utc']:<24} "
                     f"{p['closest_distance_km']:8.2f} {p['off_nadir_to_centre_deg']:13.3f} "
                     f"{p['sun_elevation_deg']:10.1f}")
    return "\n".join(lines)
