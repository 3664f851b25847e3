"""chirplidar passes: satellite passes over a region against an independent computation with
skyfield (its own SGP4, TEME -> ITRS and WGS-84 sub-point), the CLI's outputs, the design
orbit's pass, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely
from pyproj import Geod, Transformer
from shapely.geometry import Polygon, box

from chirplidar.analysis.passes import (find_passes, orbit_from_tle_file, region_from_geojson,
                                        region_from_scene)
from chirplidar.cli import main
from chirplidar.config import load_mission
from chirplidar.geometry import earth_orientation as eo

try:
    import tomllib
except ModuleNotFoundError:   # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "antarctic_margin.toml"
MISSION = ROOT / "missions" / "icesat_like.toml"
# ICESat-2 (NORAD 43613), the public element set of 2026-10-04 (CelesTrak / Space-Track), as in
# tests/test_orbit.py.
ICESAT2_L1 = "1 43613U 18070A   26277.57046165  .00001587  00000+0  57409-4 0  9990"
ICESAT2_L2 = "2 43613  91.9994 320.5065 0005609  71.5392 288.6467 15.28297940449160"
START, DAYS = "2026-10-05T00:00:00Z", 30.0
BOX_LONLAT = box(119.2, -70.68, 120.8, -70.32)   # ~60 km x 40 km about 70.5 S, 120 E


def _tle(tmp: Path, l1=ICESAT2_L1, l2=ICESAT2_L2, name="ICESAT-2") -> Path:
    p = tmp / "icesat2.tle"
    p.write_text((f"{name}\n" if name else "") + f"{l1}\n{l2}\n")
    return p


def _geojson(tmp: Path, geom, name="box.geojson", wrap="Feature") -> Path:
    g = shapely.geometry.mapping(geom)
    obj = {"type": "Feature", "properties": {}, "geometry": g} if wrap == "Feature" else g
    p = tmp / name
    p.write_text(json.dumps(obj))
    return p


# ------------------------------------------------------------------ the independent reference
def _skyfield_lonlat(start_iso, seconds):
    """Reference nadir: skyfield's EarthSatellite (its own SGP4 and TEME -> ITRS, built-in UT1)
    and wgs84.geographic_position_of (the WGS-84 geodetic sub-point), at ``seconds`` after
    ``start_iso``: (lon, lat) in degrees."""
    from skyfield.api import EarthSatellite, load, wgs84

    ts = load.timescale(builtin=True)
    t0 = eo.parse_utc(start_iso)
    t = ts.utc(t0.year, t0.month, t0.day, t0.hour, t0.minute, t0.second + np.asarray(seconds))
    g = wgs84.geographic_position_of(EarthSatellite(ICESAT2_L1, ICESAT2_L2, ts=ts).at(t))
    return g.longitude.degrees, g.latitude.degrees


@pytest.fixture(scope="module")
def coarse():
    """The skyfield nadir every 60 s over the 30-day window."""
    s = np.arange(0.0, DAYS * 86400.0 + 1.0, 60.0)
    return (s, *_skyfield_lonlat(START, s))


def _sphere_km(lon, lat, centre_lonlat):
    p1, p2 = np.radians(lat), np.radians(centre_lonlat[1])
    c = np.sin(p1) * np.sin(p2) + np.cos(p1) * np.cos(p2) * np.cos(np.radians(
        lon - centre_lonlat[0]))
    return 6371.0 * np.arccos(np.clip(c, -1.0, 1.0))


def _near(s, lon, lat, centre_lonlat, reach_km, pad_s, step_s):
    """Times every ``step_s`` over the runs of consecutive samples ``s`` within ``reach_km`` of
    the centre (padded by ``pad_s``), one array per run."""
    idx = np.flatnonzero(_sphere_km(lon, lat, centre_lonlat) < reach_km)
    cut = (np.diff(idx) > 1) | (np.diff(s[idx]) > 1.5 * np.min(np.diff(s)))
    runs = np.split(idx, np.flatnonzero(cut) + 1) if idx.size else []
    return [np.arange(max(s[r[0]] - pad_s, 0.0), min(s[r[-1]] + pad_s, s[-1]), step_s)
            for r in runs]


def _reference_passes(coarse, inside, centre_lonlat, radius_km, step_s=0.1):
    """Passes from skyfield alone, narrowing down in three sampling stages, each conservative:
    the 60-s nadir within radius_km + 500 km of the centre (a step's motion is 456 km; great
    circle on a sphere), then the 2-s nadir within radius_km + 20 km, then the nadir every
    ``step_s`` and ``inside(lon, lat)``; entry / exit half way between the last sample outside
    and the first inside. [(entry_s, exit_s, ascending), ...] in s after START."""
    s, lon, lat = coarse
    mid = _near(s, lon, lat, centre_lonlat, radius_km + 500.0, 60.0, 2.0)
    if not mid:
        return []
    s2 = np.concatenate(mid)
    fine = _near(s2, *_skyfield_lonlat(START, s2), centre_lonlat, radius_km + 20.0, 2.0, step_s)
    if not fine:
        return []
    lo, la = _skyfield_lonlat(START, np.concatenate(fine))   # one call for all spans
    split = np.cumsum([f.size for f in fine])[:-1]
    out = []
    for tf, lo_k, la_k in zip(fine, np.split(lo, split), np.split(la, split)):
        ins = np.concatenate([[0], inside(lo_k, la_k).astype(int), [0]])
        starts, ends = np.flatnonzero(np.diff(ins) == 1), np.flatnonzero(np.diff(ins) == -1)
        for a, b in zip(starts, ends):   # sample a is the first inside, b - 1 the last
            out.append((tf[a] - step_s / 2, tf[b - 1] + step_s / 2, la_k[b - 1] > la_k[a]))
    return sorted(out)


def _seconds(iso):
    return (eo.mjd_utc(iso) - eo.mjd_utc(START)) * 86400.0


def _compare(ours, ref):
    assert len(ours) == len(ref) > 0
    d_in = [abs(_seconds(p.start_utc) - r[0]) for p, r in zip(ours, ref)]
    d_out = [abs(_seconds(p.end_utc) - r[1]) for p, r in zip(ours, ref)]
    assert max(d_in) < 2.0 and max(d_out) < 2.0
    assert [p.direction for p in ours] == ["ascending" if r[2] else "descending" for r in ref]
    return max(d_in + d_out)


def test_passes_over_the_scene_match_skyfield(tmp_path, coarse):
    # The scene's extent in its own frame, from the scene file (a grid of size_x_m x size_y_m
    # centred on the given centre), independently of chirplidar's region code.
    t = tomllib.loads(SCENE.read_text())["terrain"]
    to_ps = Transformer.from_crs("EPSG:4326", "EPSG:3031", always_xy=True)
    cx, cy = to_ps.transform(t["center_lon_deg"], t["center_lat_deg"])
    scene_box = box(cx - t["size_x_m"] / 2, cy - t["size_y_m"] / 2, cx + t["size_x_m"] / 2,
                    cy + t["size_y_m"] / 2)

    def inside(lon, lat):
        return shapely.contains_xy(scene_box, *to_ps.transform(lon, lat))

    ours = find_passes(orbit_from_tle_file(_tle(tmp_path), START).orbit,
                       region_from_scene(SCENE), START, DAYS)
    ref = _reference_passes(coarse, inside, (t["center_lon_deg"], t["center_lat_deg"]),
                            np.hypot(t["size_x_m"], t["size_y_m"]) / 2e3)
    assert _compare(ours, ref) < 0.2


def test_passes_over_a_geojson_box_match_skyfield(tmp_path, coarse):
    region = region_from_geojson(_geojson(tmp_path, BOX_LONLAT))
    source = orbit_from_tle_file(_tle(tmp_path), START)
    ours = find_passes(source.orbit, region, START, DAYS)
    ref = _reference_passes(coarse, lambda lo, la: shapely.contains_xy(BOX_LONLAT, lo, la),
                            (120.0, -70.5), 40.0)
    assert _compare(ours, ref) < 0.2
    # Closest approach and the off-nadir angle to the centre, from skyfield's ITRS position
    # (0.1 s around our closest time) and the centre on the ellipsoid (pyproj, EPSG:4978).
    from skyfield.api import EarthSatellite, load, wgs84
    from skyfield.framelib import itrs

    ts = load.timescale(builtin=True)
    sat = EarthSatellite(ICESAT2_L1, ICESAT2_L2, ts=ts)
    geod = Geod(ellps="WGS84")
    centre = np.array(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(
        *region.centre_lonlat, 0.0))
    for p in ours:
        tc = eo.parse_utc(p.closest_utc)
        tt = ts.utc(tc.year, tc.month, tc.day, tc.hour, tc.minute,
                    tc.second + tc.microsecond * 1e-6 + np.arange(-3.0, 3.01, 0.1))
        g = wgs84.geographic_position_of(sat.at(tt))
        d = geod.inv(np.full(tt.shape, region.centre_lonlat[0]),
                     np.full(tt.shape, region.centre_lonlat[1]), g.longitude.degrees,
                     g.latitude.degrees)[2]
        # skyfield's built-in UT1 - UTC (a prediction) differs from the IERS table's by 0.139 s
        # on 2026-10-26: the track moves by 465 m/s x cos(70.5 deg) x 0.139 s = 22 m.
        assert p.closest_distance_km == pytest.approx(np.min(d) / 1e3, abs=0.03)
        k = np.argmin(d)
        pos = sat.at(tt[k]).frame_xyz(itrs).m
        lat, lon = np.radians(g.latitude.degrees[k]), np.radians(g.longitude.degrees[k])
        down = -np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
        los = (centre - pos) / np.linalg.norm(centre - pos)
        assert p.off_nadir_to_centre_deg == pytest.approx(np.degrees(np.arccos(down @ los)),
                                                          abs=0.01)


def test_a_grazing_pass_is_found(tmp_path):
    # A thin triangle whose tip the 2026-10-26 11:48 UTC ascending track cuts over ~3 km
    # (< 0.5 s, well under a 20-s screen step) while its centroid lies ~40 km from the track.
    tc = "2026-10-26T11:48:49Z"
    (lo0, lo1), (la0, la1) = _skyfield_lonlat(tc, np.array([0.0, 1.0]))
    aeqd = Transformer.from_crs("EPSG:4326", f"+proj=aeqd +lat_0={la0} +lon_0={lo0} "
                                "+datum=WGS84", always_xy=True)
    ux, uy = aeqd.transform(lo1, la1)
    u = np.array([ux, uy]) / np.hypot(ux, uy)            # along track
    n = np.array([-u[1], u[0]])                          # across, to the left
    tri_xy = [3e3 * n, -60e3 * n + 30e3 * u, -60e3 * n - 30e3 * u]
    tri = Polygon(np.column_stack(aeqd.transform(*np.array(tri_xy).T, direction="INVERSE")))
    region = region_from_geojson(_geojson(tmp_path, tri, wrap="geometry"))
    start = "2026-10-26T11:40:00Z"
    ours = find_passes(orbit_from_tle_file(_tle(tmp_path), start).orbit, region, start,
                       20.0 / 1440.0)
    assert len(ours) == 1 and ours[0].duration_s < 1.0
    s = np.arange(-30.0, 30.0, 0.01)
    lo, la = _skyfield_lonlat(tc, s)
    ins = np.flatnonzero(shapely.contains_xy(tri, lo, la))
    ref_in, ref_out = s[ins[0]] - 0.005, s[ins[-1]] + 0.005
    t_c = eo.mjd_utc(tc)
    assert (eo.mjd_utc(ours[0].start_utc) - t_c) * 86400 == pytest.approx(ref_in, abs=0.05)
    assert (eo.mjd_utc(ours[0].end_utc) - t_c) * 86400 == pytest.approx(ref_out, abs=0.05)


# ------------------------------------------------------------------ the command line
def test_cli_json_has_the_keys(tmp_path, capsys):
    rc = main(["passes", "--tle", str(_tle(tmp_path)), "--region",
               str(_geojson(tmp_path, BOX_LONLAT)), "--start", "2026-10-21T00:00:00Z",
               "--days", "5", "--json"])
    out = capsys.readouterr().out
    assert rc == 0
    rep = json.loads(out)
    assert set(rep) >= {"passes", "window", "region", "tle_epoch_utc"}
    assert rep["window"] == {"start_utc": "2026-10-21T00:00:00.000Z",
                             "end_utc": "2026-10-26T00:00:00.000Z"}
    assert rep["region"]["source"].endswith("box.geojson")
    assert rep["region"]["centre_lonlat"] == pytest.approx([120.0, -70.5], abs=0.01)
    assert rep["tle_epoch_utc"].startswith("2026-10-04T13:41:27")   # day 277.57046165
    assert len(rep["passes"]) == 2
    keys = {"start_utc", "end_utc", "direction", "duration_s", "closest_utc",
            "closest_distance_km", "off_nadir_to_centre_deg", "sun_elevation_deg", "beams"}
    for p in rep["passes"]:
        assert keys <= set(p) and p["start_utc"].endswith("Z")
        assert p["beams"] == []   # a TLE file carries no beams


def test_cli_mission_finds_the_designed_pass_and_draws_it(tmp_path, capsys):
    png = tmp_path / "map.png"
    rc = main(["passes", str(MISSION), "--start", "2026-10-31T22:00:00Z", "--days", "0.25",
               "--json", "--png", str(png)])
    cap = capsys.readouterr()
    assert rc == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rep = json.loads(cap.out)
    cfg = load_mission(MISSION)
    epoch = eo.mjd_utc(cfg.survey.epoch_utc)   # the nadir crosses the scene centre then
    at_t0 = [p for p in rep["passes"]
             if abs(eo.mjd_utc(p["closest_utc"]) - epoch) * 86400 < 1.0]
    assert len(at_t0) == 1
    p = at_t0[0]
    assert p["closest_distance_km"] < 0.1 and p["off_nadir_to_centre_deg"] < 0.01
    assert p["direction"] == cfg.platform.orbit.pass_direction
    assert [b["beam"] for b in p["beams"]] == list(range(6))
    assert all(len(b["track_lonlat"]) >= 2 for b in p["beams"])
    assert rep["tle_epoch_utc"] is None


def test_cli_table_has_one_row_per_pass(tmp_path, capsys):
    rc = main(["passes", "--tle", str(_tle(tmp_path, name=None)), "--region",
               str(_geojson(tmp_path, BOX_LONLAT)), "--start", "2026-10-21T00:00:00Z",
               "--days", "5"])
    out = capsys.readouterr().out.splitlines()
    assert rc == 0
    assert "NORAD 43613" in out[0]
    assert len([ln for ln in out if ln.lstrip().startswith("2026-10-2")]) == 2


# ------------------------------------------------------------------ bad input
def _one_line_error(capsys, argv, code=2):
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == code
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


def test_bad_checksum_names_the_file(tmp_path, capsys):
    bad = ICESAT2_L1[:-1] + "1"
    tle = _tle(tmp_path, l1=bad)
    err = _one_line_error(capsys, ["passes", "--tle", str(tle), "--region", str(SCENE),
                                   "--start", START, "--days", "1"])
    assert str(tle) in err and "checksum" in err


def test_window_far_from_the_tle_epoch(tmp_path, capsys):
    err = _one_line_error(capsys, ["passes", "--tle", str(_tle(tmp_path)), "--region",
                                   str(_geojson(tmp_path, BOX_LONLAT)), "--start",
                                   "2027-03-01T00:00:00Z", "--days", "1"])
    assert "--start/--days" in err and "TLE epoch" in err


def test_region_that_is_not_a_polygon(tmp_path, capsys):
    line = _geojson(tmp_path, shapely.geometry.LineString([(119, -70), (121, -71)]),
                    name="line.geojson")
    err = _one_line_error(capsys, ["passes", "--tle", str(_tle(tmp_path)), "--region",
                                   str(line), "--start", START, "--days", "1"])
    assert "line.geojson" in err and "LineString" in err
    mission = _one_line_error(capsys, ["passes", "--tle", str(_tle(tmp_path)), "--region",
                                       str(MISSION), "--start", START, "--days", "1"])
    assert "not a scene file" in mission
    two = tmp_path / "two.geojson"
    two.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": shapely.geometry.mapping(BOX_LONLAT)}] * 2}))
    with pytest.raises(ValueError, match="2 features"):
        region_from_geojson(two)


def test_window_without_a_pass(tmp_path, capsys):
    rc = main(["passes", "--tle", str(_tle(tmp_path)), "--region",
               str(_geojson(tmp_path, BOX_LONLAT)), "--start", START, "--days", "2", "--json"])
    cap = capsys.readouterr()
    assert rc == 0
    assert json.loads(cap.out)["passes"] == []
    assert cap.err.count("\n") == 1
    assert "no pass of ICESAT-2 over box.geojson between 2026-10-05" in cap.err


@pytest.mark.parametrize("which", ["tle", "region", "mission"])
def test_missing_files(tmp_path, capsys, which):
    tle = _tle(tmp_path)
    argv = {"tle": ["--tle", str(tmp_path / "nope.tle"), "--region", str(SCENE)],
            "region": ["--tle", str(tle), "--region", str(tmp_path / "nope.geojson")],
            "mission": [str(tmp_path / "nope.toml")]}[which]
    err = _one_line_error(capsys, ["passes", *argv, "--start", START, "--days", "1"])
    assert "nope." in err


def test_tle_needs_a_region_and_one_orbit_source(tmp_path, capsys):
    tle = str(_tle(tmp_path))
    assert "--region" in _one_line_error(capsys, ["passes", "--tle", tle, "--start", START,
                                                  "--days", "1"])
    _one_line_error(capsys, ["passes", str(MISSION), "--tle", tle, "--start", START,
                             "--days", "1"])
    assert "--days" in _one_line_error(capsys, ["passes", "--tle", tle, "--region", str(SCENE),
                                                "--start", START, "--days", "0"])
    assert "--start" in _one_line_error(capsys, ["passes", "--tle", tle, "--region",
                                                 str(SCENE), "--start", "2026-10-05",
                                                 "--days", "1"])


def test_region_split_at_the_antimeridian(tmp_path):
    """A Ross Ice Shelf box split at 180 deg as RFC 7946 3.1.9 asks (two polygons, 165 E..180
    and 180..155 W): one region centred at 175 W (closed form: the box's middle longitude);
    ICESat-2 (92 deg) crosses it several times a day; a polygon genuinely wider than 180 deg
    is refused."""
    path = tmp_path / "ross.geojson"
    path.write_text(json.dumps({"type": "MultiPolygon", "coordinates": [
        [[[165.0, -82.0], [180.0, -82.0], [180.0, -78.0], [165.0, -78.0], [165.0, -82.0]]],
        [[[-180.0, -82.0], [-155.0, -82.0], [-155.0, -78.0], [-180.0, -78.0],
          [-180.0, -82.0]]]]}))
    region = region_from_geojson(path)
    assert region.centre_lonlat[0] == pytest.approx(-175.0, abs=0.5)
    orbit = orbit_from_tle_file(_tle(tmp_path), "2026-10-05T00:00:00Z").orbit
    passes = find_passes(orbit, region, "2026-10-05T00:00:00Z", 1.0)
    assert len(passes) >= 3
    wide = tmp_path / "wide.geojson"
    wide.write_text(json.dumps({"type": "Polygon", "coordinates": [
        [[-100.0, -70.0], [100.0, -70.0], [100.0, -65.0], [-100.0, -65.0], [-100.0, -70.0]]]}))
    with pytest.raises(ValueError, match="less than 180 deg of longitude"):
        region_from_geojson(wide)
