"""Flight-plan writers: QGroundControl .plan against a schema written from the QGC docs, GeoJSON
parsed by shapely with geodesic lengths checked against pyproj.Geod.inv and a closed form."""

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from jsonschema import Draft202012Validator
from pyproj import Geod
from shapely.geometry import shape

from chirplidar.mission.flightplan import read_qgc_plan, write_geojson, write_qgc_plan

SCHEMA = json.loads((Path(__file__).parent / "data" / "qgc_plan.schema.json").read_text())
# Longitudes outside [-90, 90] catch a lon/lat swap (a swapped longitude is no valid latitude).
HOME = np.array([-150.25, 69.5, 812.0])
WPS = np.array([[-150.20, 69.51, 1012.0],
                [-150.10, 69.52, 1040.5],
                [-150.00, 69.53, 987.25],
                [-149.90, 69.54, 1100.0]])


@pytest.fixture
def plan_path(tmp_path):
    p = tmp_path / "survey.plan"
    write_qgc_plan(p, WPS, HOME, cruise_speed_mps=22.0)
    return p


def _validator():
    Draft202012Validator.check_schema(SCHEMA)
    return Draft202012Validator(SCHEMA)


def test_plan_validates_against_schema(plan_path):
    plan = json.loads(plan_path.read_text())
    errors = list(_validator().iter_errors(plan))
    assert errors == [], [e.message for e in errors]


@pytest.mark.parametrize("mutate", [
    lambda p: p["mission"]["items"][1].update(param=p["mission"]["items"][1].pop("params")),
    lambda p: p["mission"].update(cruisespeed=p["mission"].pop("cruiseSpeed")),
    lambda p: p.update(filetype=p.pop("fileType")),
    lambda p: p.update(fileType="Mission"),
    lambda p: p.pop("rallyPoints"),
    lambda p: p["mission"]["items"][1]["params"].pop(),
    lambda p: p["mission"]["items"][1].pop("AltitudeMode"),
    lambda p: p["mission"]["items"][1]["params"].__setitem__(4, -150.2),  # lon written as lat
    lambda p: p["mission"].update(plannedHomePosition=[HOME[0], HOME[1], HOME[2]]),
    lambda p: p["mission"].update(items=[]),
])
def test_schema_rejects_wrong_plans(plan_path, mutate):  # the schema can fail
    plan = json.loads(plan_path.read_text())
    bad = copy.deepcopy(plan)
    mutate(bad)
    assert not _validator().is_valid(bad)


def test_plan_content(plan_path):
    plan = json.loads(plan_path.read_text())
    m = plan["mission"]
    assert (plan["fileType"], plan["version"], m["version"]) == ("Plan", 1, 2)
    assert (m["firmwareType"], m["vehicleType"], m["cruiseSpeed"]) == (12, 1, 22.0)
    assert m["plannedHomePosition"] == [HOME[1], HOME[0], HOME[2]]
    items = m["items"]
    assert [it["command"] for it in items] == [22] + [16] * len(WPS) + [20]
    assert [it["doJumpId"] for it in items] == list(range(1, len(WPS) + 3))
    takeoff = items[0]
    assert takeoff["params"][4:6] == [HOME[1], HOME[0]]
    assert takeoff["params"][6] == pytest.approx(WPS[0, 2] - HOME[2])
    for it, wp in zip(items[1:-1], WPS):
        assert (it["frame"], it["AltitudeMode"], it["autoContinue"]) == (3, 1, True)
        assert it["params"][3] is None  # yaw NaN, written as null as QGC does
        assert it["Altitude"] == pytest.approx(wp[2] - HOME[2])
        assert it["params"][6] == it["Altitude"]


def test_round_trip_waypoints(plan_path):
    back = read_qgc_plan(plan_path)
    assert back.shape == WPS.shape
    np.testing.assert_allclose(back[:, :2], WPS[:, :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(back[:, 2], WPS[:, 2] - HOME[2], rtol=0, atol=1e-9)


def test_multirotor_vehicle_type_and_takeoff_override(tmp_path):
    p = tmp_path / "mr.plan"
    write_qgc_plan(p, WPS, HOME, cruise_speed_mps=8.0, vehicle_type="multirotor",
                   takeoff_altitude_m=30.0)
    m = json.loads(p.read_text())["mission"]
    assert m["vehicleType"] == 2 and m["items"][0]["Altitude"] == 30.0
    assert _validator().is_valid(json.loads(p.read_text()))


def test_atomic_write_leaves_no_temp_and_keeps_old_file_on_error(tmp_path, plan_path):
    before = plan_path.read_text()
    with pytest.raises(ValueError):
        write_qgc_plan(plan_path, WPS[:, :2], HOME, cruise_speed_mps=22.0)
    assert plan_path.read_text() == before
    write_qgc_plan(plan_path, WPS[::-1], HOME, cruise_speed_mps=22.0)  # overwrite
    assert [f.name for f in tmp_path.iterdir()] == ["survey.plan"]


@pytest.mark.parametrize("kw,arg", [
    (dict(waypoints_lonlatalt=WPS[:, :2]), "waypoints_lonlatalt"),
    (dict(waypoints_lonlatalt=np.zeros((0, 3))), "waypoints_lonlatalt"),
    (dict(waypoints_lonlatalt=WPS[:, [1, 0, 2]] * [1, 3, 1]), "waypoints_lonlatalt"),  # lat 207
    (dict(waypoints_lonlatalt=np.where(WPS == WPS[0, 0], np.nan, WPS)), "waypoints_lonlatalt"),
    (dict(home_lonlatalt=HOME[:2]), "home_lonlatalt"),
    (dict(home_lonlatalt=[200.0, 69.0, 0.0]), "home_lonlatalt"),
    (dict(cruise_speed_mps=0.0), "cruise_speed_mps"),
    (dict(vehicle_type="blimp"), "vehicle_type"),
    (dict(altitude_reference="absolute"), "altitude_reference"),
    (dict(takeoff_altitude_m=-5.0), "takeoff_altitude_m"),
    (dict(home_lonlatalt=[-150.25, 69.5, 5000.0]), "waypoints_lonlatalt"),  # first wp below home
])
def test_plan_bad_inputs_raise_naming_argument(tmp_path, kw, arg):
    args = dict(waypoints_lonlatalt=WPS, home_lonlatalt=HOME, cruise_speed_mps=22.0)
    args.update(kw)
    with pytest.raises(ValueError, match=arg):
        write_qgc_plan(tmp_path / "x.plan", **args)
    assert not (tmp_path / "x.plan").exists()


# --- GeoJSON ------------------------------------------------------------------------------

LINE_70N = np.array([[-150.0, 70.0], [-150.0, 70.01]])  # 0.01 deg of latitude at 70 N


def _meridian_arc_closed_form(lat1, lat2):
    """Meridian arc [m] by the meridional radius of curvature M(phi) = a(1-e2)/(1-e2 sin^2)^1.5
    at the mid latitude (WGS-84), accurate to O(dphi^2) for short arcs."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    phi = math.radians(0.5 * (lat1 + lat2))
    M = a * (1 - e2) / (1 - e2 * math.sin(phi) ** 2) ** 1.5
    return M * math.radians(lat2 - lat1)


def test_geojson_features_parse_and_lengths(tmp_path):
    p = tmp_path / "plan.geojson"
    lines = [LINE_70N, WPS[:, :2]]
    write_geojson(p, lines, WPS, {"name": "test survey", "clearance_m": 120.0})
    fc = json.loads(p.read_text())
    assert fc["type"] == "FeatureCollection"
    feats = fc["features"]
    geoms = [shape(f["geometry"]) for f in feats]  # every feature parses
    assert all(g.is_valid and not g.is_empty for g in geoms)
    kinds = [f["properties"]["feature"] for f in feats]
    assert kinds == ["survey_line"] * 2 + ["flight_path"] + ["waypoint"] * len(WPS)

    geod = Geod(ellps="WGS84")
    _, _, dist = geod.inv(LINE_70N[0, 0], LINE_70N[0, 1], LINE_70N[1, 0], LINE_70N[1, 1])
    assert feats[0]["properties"]["length_m"] == pytest.approx(dist, rel=1e-12)  # Geod.inv
    assert dist == pytest.approx(_meridian_arc_closed_form(70.0, 70.01), rel=1e-6)  # closed form
    assert dist == pytest.approx(1115.5, abs=1.0)
    _, _, legs = geod.inv(WPS[:-1, 0], WPS[:-1, 1], WPS[1:, 0], WPS[1:, 1])
    assert feats[1]["properties"]["length_m"] == pytest.approx(float(np.sum(legs)), rel=1e-12)
    assert feats[1]["properties"]["line_index"] == 1

    path = feats[2]
    assert path["properties"]["name"] == "test survey"
    assert path["properties"]["clearance_m"] == 120.0
    assert geoms[2].has_z
    np.testing.assert_allclose(np.asarray(geoms[2].coords), WPS, rtol=0, atol=0)
    for i, (f, g) in enumerate(zip(feats[3:], geoms[3:])):
        assert f["properties"]["index"] == i and f["properties"]["height_m"] == WPS[i, 2]
        assert (g.x, g.y, g.z) == tuple(WPS[i])


def test_geojson_lon_lat_order(tmp_path):
    p = tmp_path / "plan.geojson"
    write_geojson(p, [LINE_70N], WPS, {})
    feats = json.loads(p.read_text())["features"]
    first = feats[0]["geometry"]["coordinates"][0]
    assert first == [-150.0, 70.0]  # lon first; a swap would put |value| > 90 as latitude
    pt = shape(feats[2]["geometry"])
    assert pt.x == WPS[0, 0] and pt.y == WPS[0, 1]


@pytest.mark.parametrize("kw,arg", [
    (dict(lines_lonlat=[LINE_70N[:, ::-1]]), "lines_lonlat"),  # swapped: lat -150
    (dict(lines_lonlat=[LINE_70N[:1]]), "lines_lonlat"),
    (dict(lines_lonlat=[np.c_[LINE_70N, [0.0, 0.0]]]), "lines_lonlat"),
    (dict(lines_lonlat=LINE_70N), "lines_lonlat"),
    (dict(lines_lonlat=5), "lines_lonlat"),
    (dict(waypoints_lonlatalt=WPS[:1]), "waypoints_lonlatalt"),
    (dict(waypoints_lonlatalt=WPS[:, :2]), "waypoints_lonlatalt"),
    (dict(waypoints_lonlatalt=WPS * [1, 1, np.inf]), "waypoints_lonlatalt"),
    (dict(properties=[("a", 1)]), "properties"),
    (dict(properties={"x": float("nan")}), "properties"),
    (dict(properties={"x": object()}), "properties"),
    (dict(properties={"feature": "mine"}), "properties"),
])
def test_geojson_bad_inputs_raise_naming_argument(tmp_path, kw, arg):
    args = dict(lines_lonlat=[LINE_70N], waypoints_lonlatalt=WPS, properties={})
    args.update(kw)
    with pytest.raises(ValueError, match=arg):
        write_geojson(tmp_path / "x.geojson", **args)
    assert list(tmp_path.iterdir()) == []
