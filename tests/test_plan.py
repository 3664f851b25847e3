"""chirplidar plan: the plan it writes, flown and gridded, meets the requirement; the files load
in QGroundControl (a schema written from its documentation) and QGIS (GeoJSON via shapely); what
the platform cannot fly is reported, never planned."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely.geometry

from chirplidar.analysis.coverage import compute_coverage
from chirplidar.cli import main
from chirplidar.mission.flightplan import read_qgc_plan
from chirplidar.mission.results import read_netcdf
from chirplidar.mission.runner import run_mission

ROOT = Path(__file__).resolve().parents[1]
UAV = ROOT / "missions" / "greenland_uav.toml"
SCHEMA = Path(__file__).resolve().parent / "data" / "qgc_plan.schema.json"
SMALL = ["platform.uav.survey_polygon_m=[[-300.0,-200.0],[300.0,-200.0],[300.0,200.0],"
         "[-300.0,200.0]]"]


def _validate(plan_file: Path) -> None:
    import jsonschema

    schema = json.loads(SCHEMA.read_text())
    jsonschema.Draft202012Validator(schema).validate(json.loads(plan_file.read_text()))


def test_demo_area_plan_meets_its_requirement_when_flown(tmp_path, capsys):
    """Issue 14's acceptance: plan the Greenland demo area for 95 % of 100 m cells; run the
    written mission and grid it: the requirement holds, the flight time is the plan's (5 %),
    the QGroundControl file validates, the GeoJSON parses, the climb limit holds."""
    out = tmp_path / "plan"
    code = main(["plan", str(UAV), "--cell-m", "100", "--min-covered", "0.95", "--out",
                 str(out), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0 and report["meets_requirement"]
    chosen = report["chosen"]
    res = run_mission(out / "mission.toml", out=tmp_path / "flown.nc",
                      cache_dir=tmp_path / "cache")
    cov = compute_coverage([res.path], cell_m=100.0).summary
    assert cov["fraction_covered"] >= 0.95
    assert cov["flight_time_s"] == pytest.approx(chosen["flight_time_s"], rel=0.05)
    _validate(out / "mission.plan")
    wp = read_qgc_plan(out / "mission.plan")
    assert len(wp) >= 2 * 19                             # every line's two ends at least
    gj = json.loads((out / "plan.geojson").read_text())
    shapes = [shapely.geometry.shape(f["geometry"]) for f in gj["features"]]
    lines = [s for s, f in zip(shapes, gj["features"]) if f["properties"]["feature"] ==
             "survey_line"]
    assert len(lines) == round(2000.0 / chosen["line_spacing_m"] + 0.499)
    assert all(-51.0 < s.centroid.x < -49.0 and 66.5 < s.centroid.y < 67.5 for s in lines)
    # the flown profile keeps the mission's climb and descent limits (3 and 4 m/s)
    ds = read_netcdf(res.path)
    rate = np.diff(ds["platform_altitude"].values[0]) / np.diff(ds["delta_time"].values[0])
    assert rate.max() <= 3.0 + 1e-6 and rate.min() >= -4.0 - 1e-6
    agl = ds["platform_altitude"].values[0] - ds["h_li_true"].values[0]
    assert np.nanmin(agl) >= 120.0 - 1.0                 # never below the clearance (1 m:
                                                         # the footprint is off nadir by jitter)


def test_unmeetable_requirement_reports_the_best_plan(tmp_path, capsys):
    """A 0.1 mm precision of a 100 m cell's mean height needs ~2e5 shots per cell at 4.6 cm
    each ((4.6 cm / 0.1 mm)^2), beyond lines an eighth of a cell apart (~3000 shots per cell
    at 0.2 m along track): exit 1, the best plan found is written and what it achieves is
    said."""
    out = tmp_path / "plan"
    code = main(["plan", str(UAV), "--cell-m", "100", "--min-covered", "0.9",
                 "--max-height-precision-m", "0.0001", "--out", str(out), "--set", *SMALL])
    text = capsys.readouterr()
    assert code == 1
    assert "cannot be met" in text.out and "precision of a cell's mean height" in text.out
    assert (out / "mission.plan").is_file()
    report = json.loads((out / "plan.json").read_text())
    assert not report["meets_requirement"] and report["chosen"]["shortfalls"]


def test_vary_altitude_picks_the_quickest_and_aircraft_waypoints_follow_turns(tmp_path,
                                                                              capsys):
    """Two altitudes on the small polygon: each gets its own fewest lines, the quickest
    feasible one is chosen (ties: the better covered). Then the same area flown by an
    aircraft (a child mission replacing the UAV): its mission.plan follows the simulated
    Dubins turns within the 2 m waypoint tolerance."""
    out = tmp_path / "plan"
    code = main(["plan", str(UAV), "--cell-m", "100", "--min-covered", "0.9", "--out", str(out),
                 "--vary", "platform.uav.altitude_m=80,200", "--set", *SMALL, "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0
    feasible = [c for c in report["candidates"] if c["feasible"]]
    quickest = min(c["flight_time_s"] for c in feasible)
    assert report["chosen"]["flight_time_s"] == quickest
    assert {c["overrides"]["platform.uav.altitude_m"] for c in report["candidates"]} == {80, 200}
    air = tmp_path / "aircraft.toml"
    air.write_text(f'extends = "{UAV.as_posix()}"\n[platform]\nkind = "aircraft"\n'
                   '[platform.aircraft]\ncoordinates = "scene_centre"\n'
                   'survey_polygon_m = [[-300.0, -200.0], [300.0, -200.0], [300.0, 200.0], '
                   '[-300.0, 200.0]]\nline_spacing_m = 100.0\nheading_deg = 90.0\n'
                   'speed_mps = 40.0\naltitude_m = 700.0\nturn_radius_m = 150.0\n')
    code = main(["plan", str(air), "--cell-m", "100", "--min-covered", "0.5", "--out",
                 str(tmp_path / "air")])
    capsys.readouterr()
    from chirplidar.geometry import frames
    from chirplidar.mission.preflight import prepare

    _, scene, plan = prepare(tmp_path / "air" / "mission.toml")
    wp = read_qgc_plan(tmp_path / "air" / "mission.plan")
    lat, lon, _ = frames.projected_to_geodetic(
        *plan.path.positions(np.linspace(0, plan.path.duration_s, 2000))[:, :2].T,
        np.zeros(2000), scene.epsg)
    xy = np.column_stack(frames.geodetic_to_projected(lat, lon, np.zeros(2000), scene.epsg)[:2])
    wxy = np.column_stack(frames.geodetic_to_projected(wp[:, 1], wp[:, 0], np.zeros(len(wp)),
                                                       scene.epsg)[:2])
    route = shapely.geometry.LineString(wxy)
    # 2 m of Douglas-Peucker on samples 0.5 s (20 m) apart, plus the sagitta of a 20 m chord
    # of the 150 m turn between samples (20^2 / (8 x 150) = 0.33 m)
    assert max(route.distance(shapely.geometry.Point(p)) for p in xy) < 2.0 + 20.0 ** 2 / 1200


def test_endurance_bounds_the_plan(tmp_path, capsys):
    """An endurance shorter than any covering flight: every candidate that covers is refused
    for its flight time; the report names the endurance."""
    code = main(["plan", str(UAV), "--cell-m", "100", "--min-covered", "0.95", "--out",
                 str(tmp_path / "p"), "--set", *SMALL, "platform.uav.endurance_s=60"])
    out = capsys.readouterr().out
    assert code == 1 and "exceeds the endurance 60 s" in out
    # a UAV turning on 80 m cannot fly lines 100 m apart (a U-turn needs 160 m)
    code = main(["plan", str(UAV), "--cell-m", "100", "--min-covered", "0.95", "--out",
                 str(tmp_path / "q"), "--set", *SMALL, "platform.uav.turn_radius_m=80"])
    out = capsys.readouterr().out
    assert code == 1 and "closer than twice the UAV's turn radius 80 m" in out


@pytest.mark.parametrize(("args", "match"), [
    (["--min-covered", "1.5"], "--min-covered must lie in"),
    (["--vary", "platform.uav.line_spacing_m=50,100"], "plan chooses platform.uav.line_spacing_m"),
    (["--vary", "platform.uav.altitud_m=50,100"], "altitud_m"),
])
def test_bad_plan_input_is_one_line(args, match, tmp_path, capsys):
    code = main(["plan", str(UAV), "--cell-m", "100", "--min-covered", "0.9", "--out",
                 str(tmp_path / "p"), *args])
    err = capsys.readouterr().err
    assert code == 2 and match in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_plan_refuses_satellites_and_waypoint_paths(tmp_path, capsys):
    code = main(["plan", str(ROOT / "missions" / "icesat_like.toml"), "--cell-m", "100",
                 "--min-covered", "0.9", "--out", str(tmp_path / "p")])
    assert code == 2 and "chirplidar passes" in capsys.readouterr().err
