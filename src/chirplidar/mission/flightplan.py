"""Survey flight-plan writers: GeoJSON for QGIS and QGroundControl ``.plan`` files.

Coordinates are WGS-84 longitude and latitude [deg] and heights [m] above the WGS-84 ellipsoid.
Both files are written atomically (a temporary file in the target folder, then ``os.replace``)
so a reader never sees a half-written plan.

QGroundControl format sources: the dev guide's "Plan File Format" page
(https://docs.qgroundcontrol.com/v4.4.3/en/qgc-dev-guide/file_formats/plan.html, source
https://github.com/mavlink/qgc-dev-guide/blob/master/en/file_formats/plan.md) and QGC's loader and
writer (src/MissionManager/PlanMasterController.cc, MissionController.cc, SimpleMissionItem.cc,
MissionItem.cc in https://github.com/mavlink/qgroundcontrol); the schema
tests/data/qgc_plan.schema.json is written from them. MAVLink enums:
https://mavlink.io/en/messages/common.html.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
from pyproj import Geod

from .._checks import positive, real_array

__all__ = ["read_qgc_plan", "write_geojson", "write_qgc_plan"]

_GEOD = Geod(ellps="WGS84")

# MAVLink enum values (https://mavlink.io/en/messages/common.html)
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_TAKEOFF = 22
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_AUTOPILOT_PX4 = 12
_MAV_TYPE = {"fixed_wing": 1, "multirotor": 2, "quadrotor": 2}  # MAV_TYPE_FIXED_WING, _QUADROTOR
QGC_ALTITUDE_MODE_RELATIVE = 1  # QGroundControlQmlGlobal::AltitudeModeRelative
_TAKEOFF_PITCH_DEG = 15.0  # NAV_TAKEOFF param1, minimum pitch; QGC's default
_HOVER_SPEED_MPS = 5.0  # multirotor default speed; unused by a fixed wing (see write_qgc_plan)


def _lonlat_rows(name: str, value, ncols: int, min_rows: int) -> np.ndarray:
    """A finite (k, ncols) array of lon [deg], lat [deg](, height [m]) rows, in range."""
    arr = real_array(name, value)
    if arr.ndim != 2 or arr.shape[1] != ncols or arr.shape[0] < min_rows:
        raise ValueError(f"{name} must have shape (k >= {min_rows}, {ncols}), got {arr.shape}")
    if np.any(np.abs(arr[:, 0]) > 180.0):
        raise ValueError(f"{name}: longitude (column 0) must lie in [-180, 180] deg")
    if np.any(np.abs(arr[:, 1]) > 90.0):
        raise ValueError(f"{name}: latitude (column 1) must lie in [-90, 90] deg")
    return arr


def _write_json_atomic(path, obj) -> None:
    """Serialise ``obj`` (strict JSON: NaN refused) to a temp file beside ``path``, fsync, then
    ``os.replace`` it over ``path``."""
    path = Path(path)
    text = json.dumps(obj, indent=2, allow_nan=False) + "\n"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)   # mkstemp makes 0600; a plan is as readable as any written file
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_geojson(path, lines_lonlat, waypoints_lonlatalt, properties: dict) -> None:
    """Write a survey plan as an RFC 7946 GeoJSON FeatureCollection (opens in QGIS).

    Parameters
    ----------
    path : str or Path
        Output file (conventionally ``.geojson``); its folder must exist.
    lines_lonlat : list of (k, 2) arrays
        Survey lines as (lon, lat) [deg] WGS-84, k >= 2 each; may be empty.
    waypoints_lonlatalt : (m, 3) array
        Flight path as (lon, lat [deg], ellipsoidal height [m]) in flight order, m >= 2.
    properties : dict
        Plan metadata (JSON-serialisable, string keys). RFC 7946 has no collection-level
        properties, so they are put on the flight-path feature.

    Features, in order: one ``LineString`` per survey line (properties ``feature``
    "survey_line", ``line_index``, ``length_m`` = geodesic length on the WGS-84 ellipsoid
    [m]); one 3-D ``LineString`` of the whole flight path (``feature`` "flight_path" plus
    ``properties``); one 3-D ``Point`` per waypoint (``feature`` "waypoint", ``index``,
    ``height_m``). Positions are [lon, lat(, height)] as RFC 7946 requires; lines crossing the
    antimeridian are not split (RFC 7946 section 3.1.9), which polar survey areas never need.
    """
    if isinstance(lines_lonlat, np.ndarray) and lines_lonlat.ndim == 2:
        raise ValueError("lines_lonlat must be a list of (k, 2) arrays, not a single array")
    try:
        lines = [_lonlat_rows(f"lines_lonlat[{i}]", ln, 2, 2) for i, ln in enumerate(lines_lonlat)]
    except TypeError:
        raise ValueError("lines_lonlat must be a list of (k, 2) arrays") from None
    wps = _lonlat_rows("waypoints_lonlatalt", waypoints_lonlatalt, 3, 2)
    if not isinstance(properties, dict) or not all(isinstance(k, str) for k in properties):
        raise ValueError("properties must be a dict with string keys")
    if "feature" in properties:
        raise ValueError("properties must not use the reserved key 'feature'")
    try:
        json.dumps(properties, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"properties must be JSON-serialisable (finite numbers): {exc}") from None

    features = []
    for i, ln in enumerate(lines):
        length = float(_GEOD.line_length(ln[:, 0], ln[:, 1]))
        features.append({
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": ln.tolist()},
            "properties": {"feature": "survey_line", "line_index": i, "length_m": length},
        })
    features.append({
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": wps.tolist()},
        "properties": {"feature": "flight_path", **properties},
    })
    for i, wp in enumerate(wps):
        features.append({
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": wp.tolist()},
            "properties": {"feature": "waypoint", "index": i, "height_m": float(wp[2])},
        })
    _write_json_atomic(path, {"type": "FeatureCollection", "features": features})


def _simple_item(jump_id: int, command: int, frame: int, params: list, altitude=None) -> dict:
    """A QGC ``SimpleItem``; items that specify an altitude carry QGC's altitude keys."""
    item = {"type": "SimpleItem", "autoContinue": True, "command": command,
            "doJumpId": jump_id, "frame": frame, "params": params}
    if altitude is not None:
        item.update({"AMSLAltAboveTerrain": None, "Altitude": altitude,
                     "AltitudeMode": QGC_ALTITUDE_MODE_RELATIVE})
    return item


def write_qgc_plan(path, waypoints_lonlatalt, home_lonlatalt, *, cruise_speed_mps,
                   vehicle_type="fixed_wing", altitude_reference="relative",
                   takeoff_altitude_m=None) -> None:
    """Write a QGroundControl ``.plan`` file (JSON) flying the waypoints in order.

    Parameters
    ----------
    path : str or Path
        Output file (conventionally ``.plan``); its folder must exist.
    waypoints_lonlatalt : (m, 3) array
        (lon, lat [deg] WGS-84, ellipsoidal height [m]) in flight order, m >= 1.
    home_lonlatalt : (3,) array
        Launch point (lon, lat [deg], ellipsoidal height [m]).
    cruise_speed_mps : float
        Mission cruise speed [m/s], > 0.
    vehicle_type : {"fixed_wing", "multirotor", "quadrotor"}
        Written as MAV_TYPE: 1 (fixed wing) or 2 (quadrotor).
    altitude_reference : {"relative"}
        Only altitudes relative to home are written (see Heights below).
    takeoff_altitude_m : float, optional
        Take-off climb height above home [m], > 0; default the first waypoint's height above
        home.

    The mission is for PX4 (``firmwareType`` 12, MAV_AUTOPILOT_PX4): item 1 a NAV_TAKEOFF (22)
    at home, then one NAV_WAYPOINT (16) per waypoint (frame 3 GLOBAL_RELATIVE_ALT,
    ``AltitudeMode`` 1 relative, params [hold 0 s, acceptance radius 0 = autopilot default,
    pass radius 0, yaw null = unchanged, lat, lon, height above home]), and a final
    NAV_RETURN_TO_LAUNCH (20): a PX4 fixed-wing NAV_LAND needs a planned approach (QGC's
    landing-pattern item), whereas RTL hands the return and landing to the autopilot's own
    configured behaviour, and is valid for multirotors too. ``doJumpId`` numbers the items from 1.

    Heights: the inputs are WGS-84 ellipsoidal heights. The mission altitudes are differences
    (waypoint height - home height), so the vertical datum cancels. ``plannedHomePosition``
    ([lat, lon, alt]) however carries the *ellipsoidal* height of the launch point, while QGC
    expects AMSL: the geoid undulation is not applied because no geoid grid ships with pyproj
    here. The home altitude only affects QGC's display and terrain checks, not the flown path,
    which is why absolute (AMSL) altitudes are refused.
    """
    wps, home, cruise, rel, takeoff = _checked_plan_inputs(
        waypoints_lonlatalt, home_lonlatalt, cruise_speed_mps, vehicle_type,
        altitude_reference, takeoff_altitude_m)
    h_lon, h_lat = float(home[0]), float(home[1])
    items = _mission_items(wps, rel, h_lon, h_lat, takeoff)
    plan = {
        "fileType": "Plan",
        "version": 1,
        # QGC checks only that this is a string; its own value keeps other importers happy.
        "groundStation": "QGroundControl",
        "mission": {
            "version": 2,
            "firmwareType": MAV_AUTOPILOT_PX4,
            "vehicleType": _MAV_TYPE[vehicle_type],
            "cruiseSpeed": cruise,
            # The dev guide lists hoverSpeed as required and QGC always saves it; a fixed wing
            # ignores it, so a typical multirotor value is written.
            "hoverSpeed": _HOVER_SPEED_MPS,
            "globalPlanAltitudeMode": QGC_ALTITUDE_MODE_RELATIVE,
            "plannedHomePosition": [h_lat, h_lon, float(home[2])],
            "items": items,
        },
        # QGC's loader requires both objects even when empty.
        "geoFence": {"version": 2, "polygons": [], "circles": []},
        "rallyPoints": {"version": 2, "points": []},
    }
    _write_json_atomic(path, plan)


def _checked_plan_inputs(waypoints_lonlatalt, home_lonlatalt, cruise_speed_mps, vehicle_type,
                         altitude_reference, takeoff_altitude_m) -> tuple:
    """The arguments of :func:`write_qgc_plan` checked: (waypoints, home, cruise speed,
    waypoint heights above home [m], take-off height above home [m]); ValueError otherwise."""
    wps = _lonlat_rows("waypoints_lonlatalt", waypoints_lonlatalt, 3, 1)
    home_arr = real_array("home_lonlatalt", home_lonlatalt)
    if home_arr.shape != (3,):
        raise ValueError(f"home_lonlatalt must have shape (3,), got {home_arr.shape}")
    home = _lonlat_rows("home_lonlatalt", home_arr[None, :], 3, 1)[0]
    cruise = positive("cruise_speed_mps", cruise_speed_mps)
    if vehicle_type not in _MAV_TYPE:
        raise ValueError(f"vehicle_type must be one of {sorted(_MAV_TYPE)}, got {vehicle_type!r}")
    if altitude_reference != "relative":
        raise ValueError("altitude_reference must be 'relative': absolute altitudes would need "
                         f"AMSL heights (no geoid model here), got {altitude_reference!r}")
    rel = wps[:, 2] - home[2]  # height above the launch point [m]
    if takeoff_altitude_m is None:
        if rel[0] <= 0.0:
            raise ValueError("waypoints_lonlatalt: the first waypoint is not above home; "
                             "give takeoff_altitude_m")
        takeoff = float(rel[0])
    else:
        takeoff = positive("takeoff_altitude_m", takeoff_altitude_m)
    return wps, home, cruise, rel, takeoff


def _mission_items(wps, rel, h_lon, h_lat, takeoff: float) -> list[dict]:
    """The ``.plan`` mission items: take-off at home, one waypoint each, return to launch."""
    items = [_simple_item(1, MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                          [_TAKEOFF_PITCH_DEG, 0, 0, None, h_lat, h_lon, takeoff], takeoff)]
    for (lon, lat, _), alt in zip(wps, rel):
        items.append(_simple_item(len(items) + 1, MAV_CMD_NAV_WAYPOINT,
                                  MAV_FRAME_GLOBAL_RELATIVE_ALT,
                                  [0, 0, 0, None, float(lat), float(lon), float(alt)],
                                  float(alt)))
    # RTL has no coordinate: QGC saves such commands in MAV_FRAME_MISSION with zero params.
    items.append(_simple_item(len(items) + 1, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_FRAME_MISSION,
                              [0, 0, 0, 0, 0, 0, 0]))
    return items


def read_qgc_plan(path) -> np.ndarray:
    """Waypoints of a ``.plan`` file as an (m, 3) array of (lon [deg], lat [deg], altitude [m]).

    Only NAV_WAYPOINT (16) ``SimpleItem`` entries are returned, in file order; the altitude is
    params[6] as written (relative to home for files from :func:`write_qgc_plan`).
    """
    try:
        with open(path, encoding="utf-8") as f:
            plan = json.load(f)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a QGroundControl plan (not JSON: {exc})") from None
    try:
        items = plan["mission"]["items"]
        rows = [(it["params"][5], it["params"][4], it["params"][6]) for it in items
                if it.get("type") == "SimpleItem" and it.get("command") == MAV_CMD_NAV_WAYPOINT]
    except (KeyError, IndexError, TypeError) as exc:
        raise ValueError(f"{path}: not a QGroundControl plan with mission items ({exc!r})") from None
    out = np.array([[math.nan if v is None else float(v) for v in r] for r in rows], dtype=float)
    return out.reshape(-1, 3)
