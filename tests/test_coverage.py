"""``chirplidar coverage``: gridded coverage, gaps, precision and crossovers of results files.

References (every value below is derived in its test from these):
* lattice: footprints on a 10 m square lattice with a 200 m x 200 m square hole; cell counts are
  lattice-point counts; the largest empty circle is centred on the hole, its radius the distance
  to the hole's nearest lattice points, sqrt(105^2 + 5^2) m (plane geometry);
* sample standard deviation of N values +-e (N even, half each): e sqrt(N / (N - 1));
* crossing: two straight tracks flown at constant speed cross where their lines intersect, each
  at the time its along-track distance to that point takes;
* the demo's cell counts are checked against numpy's histogram2d of the file's x, y, detected.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import box

from chirplidar.analysis.coverage import CoverageError, compute_coverage
from chirplidar.cli import main
from chirplidar.mission.results import build_dataset, read_netcdf, write_netcdf

X0, Y0 = -200_000.0, -2_200_000.0      # EPSG:3413 metres, central West Greenland
DATE = "2026-01-01T00:00:00Z"


def _write(path: Path, per_shot: dict, *, epsg=3413, epoch="2026-07-01T00:00:00Z",
           polygon=None) -> Path:
    ds = build_dataset(per_shot, epsg=epsg, epoch_iso=epoch, config_toml="test = true",
                       seed=1, software_version="test", date_created=DATE)
    if polygon is not None:
        ds.attrs["survey_polygon_wkt"] = polygon.wkt
    write_netcdf(ds, path)
    return path


def _lattice():
    """(per-shot arrays, one beam) of the lattice survey: rows along x are tracks (time
    increasing along each row), 10 m apart; the hole 300 < x < 500, 200 < y < 400 (local m)."""
    gx, gy = np.meshgrid(5.0 + 10.0 * np.arange(100), 5.0 + 10.0 * np.arange(60))
    keep = ~((gx > 300) & (gx < 500) & (gy > 200) & (gy < 400))
    x, y = gx[keep], gy[keep]
    row = ((y - 5.0) / 10.0).round().astype(np.int32)
    n = x.size
    k = np.arange(n)
    detected = np.ones(n, np.int8)
    blind = (x > 800) & (x < 900) & (y > 400) & (y < 500)    # cell (8, 4): shots, no detection
    detected[blind] = 0
    # errors +-0.1 m alternating along x (10 per row and cell: half each sign per cell)
    err = np.where((((x - 5.0) / 10.0).round().astype(int) % 2) == 0, 0.1, -0.1)
    h_true = 100.0 + 0.001 * x
    snr = 15.0 + 10.0 * ((k * 0.6180339887) % 1.0)       # spread over 15..25 dB
    det = detected == 1
    return {"delta_time": k * 0.5, "x": X0 + x, "y": Y0 + y, "track": row,
            "h_li_true": h_true, "h_li": np.where(det, h_true + err, np.nan),
            "h_li_sigma": np.where(det, 0.2, np.nan), "snr_db": snr, "detected": detected,
            "platform_x": X0 + x, "platform_y": Y0 + y}, (x, y, detected, snr)


@pytest.fixture
def lattice_file(tmp_path):
    per_shot, raw = _lattice()
    region = box(X0, Y0, X0 + 1000.0, Y0 + 600.0)
    path = _write(tmp_path / "lattice.nc", {**per_shot, "beam": np.zeros(raw[0].size, int)},
                  polygon=region)
    return path, raw


def test_lattice_counts_fraction_gap_and_precision(lattice_file):
    path, (x, y, detected, snr) = lattice_file
    cov = compute_coverage([path], cell_m=100.0)
    g, s = cov.grid, cov.summary
    assert g.sizes == {"y": 6, "x": 10}
    assert np.allclose(g.x.values, X0 + 50.0 + 100.0 * np.arange(10))
    shots = g["shots"].values
    det = g["detected_shots"].values
    hole = np.zeros((6, 10), bool)
    hole[2:4, 3:5] = True
    assert np.all(shots[hole] == 0) and np.all(shots[~hole] == 100)   # 10 x 10 lattice points
    assert det[4, 8] == 0 and shots[4, 8] == 100
    assert s["cells_in_region"] == 60
    assert s["cells_covered"] == 60 - 4 - 1
    assert s["fraction_covered"] == pytest.approx(55 / 60)
    assert np.array_equal(g["covered"].values, ((det >= 1)).astype(np.int8))
    assert np.all(g["tracks"].values[~hole] == 10)        # ten lattice rows per cell
    # largest empty circle: centred on the hole, radius sqrt(105^2 + 5^2) (module docstring)
    assert s["largest_gap_m"] == pytest.approx(math.hypot(105.0, 5.0), abs=10.0)
    # the hole cells' centres are sqrt(55^2 + 5^2) from the nearest lattice point
    assert np.allclose(g["gap"].values[hole], math.hypot(55.0, 5.0), atol=100.0 / 20 / math.sqrt(2))   # half the diagonal of a C / 20 pixel
    # heights: +-0.1 m, 50 of each sign per cell -> sample std 0.1 sqrt(100 / 99)
    std = g["height_error_std"].values
    ok = ~hole
    ok[4, 8] = False
    assert np.allclose(std[ok], 0.1 * math.sqrt(100 / 99))
    assert np.allclose(g["height_precision_measured"].values[ok], 0.1 * math.sqrt(100 / 99) / 10)
    assert np.allclose(g["height_sigma_predicted"].values[ok], 0.2)
    assert np.allclose(g["height_precision_predicted"].values[ok], 0.02)
    assert s["median_height_precision_m"] == pytest.approx(0.1 * math.sqrt(100 / 99))
    # median SNR per cell within one 0.1 dB bin of numpy's median of the cell's shots
    ix, iy = (x // 100).astype(int), (y // 100).astype(int)
    med = g["median_snr_db"].values
    for j, i in ((0, 0), (4, 8), (5, 9), (1, 2)):
        sel = (ix == i) & (iy == j)
        assert med[j, i] == pytest.approx(np.median(snr[sel]), abs=0.1)
    assert s["median_detections_per_cell"] == 100
    assert s["along_track_spacing_m"] == pytest.approx(10.0, rel=2e-3)
    assert s["across_track_spacing_m"] == pytest.approx(10.0, rel=1e-6)
    assert s["crossovers"] == 0                  # parallel rows never cross
    assert s["region"]["kind"] == "survey"       # the default where the file carries one


def test_lattice_min_detections_and_bounds(lattice_file):
    path, _ = lattice_file
    assert compute_coverage([path], cell_m=100.0, min_detections=101).summary[
        "cells_covered"] == 0
    # a 200 m x 200 m box around the hole: only empty cells, the gap measured inside it
    cov = compute_coverage([path], cell_m=50.0, bounds=(X0 + 300, Y0 + 200, X0 + 500, Y0 + 400))
    assert cov.summary["cells_in_region"] == 16 and cov.summary["cells_covered"] == 0
    assert cov.summary["largest_gap_m"] == pytest.approx(math.hypot(105.0, 5.0), abs=5.0)


def _line(t0, x0, y0, x1, y1, speed, prf, h, track):
    n = int(math.hypot(x1 - x0, y1 - y0) / speed * prf) + 1
    s = np.arange(n) * speed / prf
    u = np.array([x1 - x0, y1 - y0]) / math.hypot(x1 - x0, y1 - y0)
    x, y = X0 + x0 + s * u[0], Y0 + y0 + s * u[1]
    return {"delta_time": t0 + np.arange(n) / prf, "x": x, "y": y,
            "track": np.full(n, track, np.int32), "h_li_true": np.full(n, 100.0),
            "h_li": np.full(n, h), "h_li_sigma": np.full(n, 0.05), "snr_db": np.full(n, 20.0),
            "detected": np.ones(n, np.int8), "platform_x": x, "platform_y": y}


def _cat(*parts):
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out["beam"] = np.zeros(out["x"].size, int)
    return out


def test_two_tracks_cross_once(tmp_path):
    # track 0 along +x at y = 0 from x = -500 (t = 0 s, 10 m/s, 10 Hz: 1 m apart); track 1
    # along +y at x = 123.4 from y = -500, starting at t = 200 s: they cross at (123.4, 0),
    # track 0 at t = 62.34 s, track 1 at t = 250 s.
    a = _line(0.0, -500, 0, 500, 0, 10.0, 10.0, 100.03, 0)
    b = _line(200.0, 123.4, -500, 123.4, 500, 10.0, 10.0, 99.98, 1)
    path = _write(tmp_path / "cross.nc", _cat(a, b))
    cov = compute_coverage([path], cell_m=50.0, bounds=(X0 - 500, Y0 - 500, X0 + 500, Y0 + 500))
    xo = cov.crossovers
    assert xo.sizes["crossover"] == 1 and cov.summary["crossovers"] == 1
    assert float(xo.x[0]) == pytest.approx(X0 + 123.4, abs=1.0)      # one shot spacing
    assert float(xo.y[0]) == pytest.approx(Y0, abs=1.0)
    assert float(xo.time_1[0]) == pytest.approx(62.34, abs=0.1)      # one shot interval
    assert float(xo.time_2[0]) == pytest.approx(250.0, abs=0.1)
    assert float(xo.time_between_visits[0]) == pytest.approx(250.0 - 62.34, abs=0.1)
    assert float(xo.dh[0]) == pytest.approx(99.98 - 100.03)          # later minus earlier
    assert float(xo.dh_true[0]) == pytest.approx(0.0)
    assert int(xo.track_1[0]) == 0 and int(xo.track_2[0]) == 1
    assert float(xo.distance_1[0]) <= 0.5 and float(xo.distance_2[0]) <= 0.5
    assert cov.summary["crossover_rms_m"] == pytest.approx(0.05)


def test_repeated_line_is_no_crossover_but_a_shallow_crossing_is(tmp_path):
    # the same line flown twice (50 mm apart: pointing noise) runs together, it does not cross;
    # a line at 10 degrees to it crosses it once, at (0, 0)
    a = _line(0.0, -500, 0, 500, 0, 10.0, 10.0, 100.0, 0)
    b = _line(200.0, 500, 0.05, -500, 0.05, 10.0, 10.0, 100.0, 1)
    c = _line(400.0, -500 * math.cos(math.radians(10)), -500 * math.sin(math.radians(10)),
              500 * math.cos(math.radians(10)), 500 * math.sin(math.radians(10)), 10.0, 10.0,
              100.0, 2)
    path = _write(tmp_path / "repeat.nc", _cat(a, b))
    cov = compute_coverage([path], cell_m=50.0, bounds=(X0 - 500, Y0 - 500, X0 + 500, Y0 + 500))
    assert cov.summary["crossovers"] == 0
    path = _write(tmp_path / "shallow.nc", _cat(a, c))
    xo = compute_coverage([path], cell_m=50.0,
                          bounds=(X0 - 500, Y0 - 500, X0 + 500, Y0 + 500)).crossovers
    assert xo.sizes["crossover"] == 1
    assert float(xo.x[0]) == pytest.approx(X0, abs=1.0 / math.sin(math.radians(10)))
    assert float(xo.y[0]) == pytest.approx(Y0, abs=1.0)


def test_crossing_between_files_counts_their_epochs(tmp_path):
    # the same two tracks in two files whose epochs are a day apart
    a = _line(0.0, -500, 0, 500, 0, 10.0, 10.0, 100.0, 0)
    b = _line(0.0, 123.4, -500, 123.4, 500, 10.0, 10.0, 100.0, 0)
    fa = _write(tmp_path / "a.nc", _cat(a), epoch="2026-07-01T00:00:00Z")
    fb = _write(tmp_path / "b.nc", _cat(b), epoch="2026-07-02T00:00:00Z")
    cov = compute_coverage([fb, fa], cell_m=50.0, bounds=(X0 - 500, Y0 - 500, X0 + 500, Y0 + 500))
    xo = cov.crossovers
    assert xo.sizes["crossover"] == 1
    assert float(xo.time_between_visits[0]) == pytest.approx(86400.0 + 50.0 - 62.34, abs=0.1)
    assert int(xo.file_1[0]) == 1 and int(xo.file_2[0]) == 0        # a.nc flew first
    assert cov.grid["tracks"].values.max() == 2                     # two files: two tracks


def test_revisits_three_passes_over_the_same_line(tmp_path):
    """The same 1 km line flown at t = 0, 3 days and 10 days (three files, epochs a day apart
    and shifted delta_times): every cell on it is seen by 3 tracks; intervals 3 and 7 days, so
    the median revisit is 5 days (closed form); cells off the line have none (NaN)."""
    day = 86400.0
    files = []
    for k, (epoch, t0) in enumerate((("2026-07-01T00:00:00Z", 0.0),
                                     ("2026-07-02T00:00:00Z", 2 * day),
                                     ("2026-07-03T00:00:00Z", 8 * day))):
        files.append(_write(tmp_path / f"pass{k}.nc", _cat(_line(t0, -500, 0, 500, 0, 10.0, 10.0,
                                                                 100.0, 0)), epoch=epoch))
    cov = compute_coverage(files, cell_m=50.0, bounds=(X0 - 500, Y0 - 500, X0 + 500, Y0 + 500))
    on_line = cov.grid["detected_tracks"].values == 3
    assert on_line.sum() == 20                                   # the row of cells at y = 0
    rev = cov.grid["revisit_median_s"].values
    assert np.allclose(rev[on_line], 5 * day, atol=100.0)        # within one line's duration
    assert np.all(np.isnan(rev[~on_line]))
    assert cov.summary["cells_revisited"] == 20
    assert cov.summary["median_revisit_s"] == pytest.approx(5 * day, abs=100.0)
    # the flight time excludes the pauses between passes: 3 x 100 s of shot clock (closed form)
    assert cov.summary["flight_time_s"] == pytest.approx(3 * 100.0, abs=0.5)


def test_demo_cells_against_histogram2d(tmp_path):
    """The demo survey (missions/greenland_uav.toml, as make demo flies it): cell counts over
    the survey bounds equal an independent count of the file's footprints (numpy.histogram2d),
    and GDAL (rasterio) reads the grid with its projection and cell size."""
    from chirplidar.mission.runner import run_mission

    root = Path(__file__).resolve().parents[1]
    res = run_mission(root / "missions" / "greenland_uav.toml", out=tmp_path / "demo.nc",
                      date_created=DATE)
    ds = res.dataset
    from shapely import wkt

    x0, y0, x1, y1 = wkt.loads(ds.attrs["survey_polygon_wkt"]).bounds
    out = tmp_path / "grid.nc"
    assert main(["coverage", str(res.path), "--cell-m", "100", "--bounds",
                 f"{x0},{y0},{x1},{y1}", "--out", str(out), "--json", "--no-progress"]) == 0
    grid = read_netcdf(out)
    x, y, det = (ds[k].values.ravel() for k in ("x", "y", "detected"))
    ex, ey = np.arange(x0, x1 + 50, 100.0), np.arange(y0, y1 + 50, 100.0)
    shots, _, _ = np.histogram2d(y, x, bins=[ey, ex])
    dets, _, _ = np.histogram2d(y[det == 1], x[det == 1], bins=[ey, ex])
    assert np.array_equal(grid["shots"].values, shots.astype(int))
    assert np.array_equal(grid["detected_shots"].values, dets.astype(int))
    assert grid["crs"].attrs["grid_mapping_name"] == "polar_stereographic"
    for name, var in grid.data_vars.items():
        if name != "crs":
            assert var.attrs["units"] and var.attrs["long_name"]
            assert var.attrs["grid_mapping"] == "crs"
    import xarray as xr

    xo = xr.open_dataset(out, group="crossovers")
    assert "dh" in xo and xo.sizes["crossover"] == 0
    xo.close()
    import rasterio

    with rasterio.open(f"NETCDF:{out}:detected_shots") as src:
        assert src.crs.to_epsg() == 3413
        assert (*src.res, src.bounds.left, src.bounds.bottom) == pytest.approx((100.0, 100.0,
                                                                               x0, y0))
        img = src.read(1)             # GDAL's rows run north to south
    assert np.array_equal(img[::-1], grid["detected_shots"].values)


def test_cli_json_png_and_bad_input(lattice_file, tmp_path, capsys):
    path, _ = lattice_file
    png = tmp_path / "map.png"
    assert main(["coverage", str(path), "--cell-m", "100", "--json", "--png", str(png),
                 "--no-progress"]) == 0
    s = json.loads(capsys.readouterr().out)
    for key in ("cells_in_region", "cells_covered", "fraction_covered", "largest_gap_m",
                "median_detections_per_cell", "median_height_precision_m",
                "along_track_spacing_m", "across_track_spacing_m", "track_length_m",
                "flight_time_s", "crossovers", "region"):
        assert key in s
    assert s["cells_covered"] == 55 and png.stat().st_size > 10_000

    def bad(*args):
        code = main(["coverage", *map(str, args), "--no-progress"])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
        return err

    assert "misses the results" in bad(path, "--cell-m", "100", "--bounds", "0,0,1000,1000")
    assert "--cell-m" in bad(path, "--cell-m", "0")
    assert "--cell-m" in bad(path, "--cell-m", "5000")
    assert "--bounds" in bad(path, "--cell-m", "10", "--bounds", "1,2,3")
    per_shot, raw = _lattice()
    south = _write(tmp_path / "south.nc", {**per_shot, "beam": np.zeros(raw[0].size, int),
                                           "x": per_shot["x"] - X0, "y": per_shot["y"] - Y0},
                   epsg=3031)
    assert "different projections" in bad(path, south, "--cell-m", "100")
    none = _write(tmp_path / "none.nc", {**per_shot, "beam": np.zeros(raw[0].size, int),
                                         "detected": np.zeros(raw[0].size, np.int8)})
    assert "no detected shot" in bad(none, "--cell-m", "100")
    assert "does not exist" in bad(tmp_path / "missing.nc", "--cell-m", "100")
    out = tmp_path / "g.nc"
    out.write_text("keep me")
    assert "exists" in bad(path, "--cell-m", "100", "--out", out)
    assert out.read_text() == "keep me"
    assert "given twice" in bad(path, path, "--cell-m", "100")
    (tmp_path / "adir.nc").mkdir()
    assert "is a directory" in bad(path, "--cell-m", "100", "--out", tmp_path / "adir.nc",
                                   "--overwrite")
    assert "must end in .png" in bad(path, "--cell-m", "100", "--png", tmp_path / "m.jpg")
    assert "does not exist" in bad(path, "--cell-m", "100", "--png", tmp_path / "no" / "m.png")
    new = tmp_path / "new.nc"
    (tmp_path / "adir.png").mkdir()
    assert "is a directory" in bad(path, "--cell-m", "100", "--out", new, "--png",
                                   tmp_path / "adir.png")
    assert not new.exists()                       # checked before any work: nothing written
    with pytest.raises(CoverageError, match="--region"):
        compute_coverage([none], cell_m=100.0, region=str(tmp_path / "region.txt"))


def test_tracks_on_cell_edges_are_flagged(tmp_path, capsys):
    """Lines flown along grid lines put their footprints in the cells on both sides: the
    summary says what fraction lies within C / 100 of an edge and the command warns. Reference:
    footprints scattered at random lie there with probability 1 - 0.98^2 = 3.96 %."""
    rows = [_line(100.0 * k, -500, 200.0 * k - 400.0, 500, 200.0 * k - 400.0, 10.0, 10.0, 100.0, k)
            for k in range(5)]                     # y = -400, -200, ..., 400: cell edges
    shots = _cat(*rows)
    shots["y"] = shots["y"] + 0.05 * (-1.0) ** np.arange(shots["y"].size)   # 5 cm pointing noise
    path = _write(tmp_path / "edges.nc", shots)
    args = ["coverage", str(path), "--cell-m", "50", "--json", "--no-progress",
            "--bounds", f"{X0 - 500},{Y0 - 500},{X0 + 500},{Y0 + 500}"]
    assert main(args) == 0
    out = capsys.readouterr()
    s = json.loads(out.out)
    assert s["footprints_on_cell_edges"] == 1.0
    assert s["cells_covered"] == 5 * 2 * 20         # two rows of 20 cells per line
    assert "cell edge" in out.err
    # shifted by half a cell: each line in one row, no warning
    assert main(["coverage", str(path), "--cell-m", "50", "--json", "--no-progress",
                 "--bounds", f"{X0 - 500},{Y0 - 525},{X0 + 500},{Y0 + 525}"]) == 0
    out = capsys.readouterr()
    s = json.loads(out.out)
    assert s["footprints_on_cell_edges"] < 0.05 and s["cells_covered"] == 5 * 20
    assert "cell edge" not in out.err
    rng = np.random.default_rng(3)
    n = 200_000
    scattered = {"delta_time": np.arange(n) * 0.01, "x": X0 + rng.uniform(-500, 500, n),
                 "y": Y0 + rng.uniform(-500, 500, n), "detected": np.ones(n, np.int8),
                 "beam": np.zeros(n, int)}
    p2 = _write(tmp_path / "scattered.nc", scattered)
    cov = compute_coverage([p2], cell_m=50.0, bounds=(X0 - 500, Y0 - 500, X0 + 500, Y0 + 500))
    assert cov.summary["footprints_on_cell_edges"] == pytest.approx(1 - 0.98 ** 2, abs=0.002)


def test_geojson_region(lattice_file, tmp_path):
    """A WGS-84 GeoJSON polygon: the lattice's west half, transformed with pyproj."""
    from pyproj import Transformer

    path, _ = lattice_file
    to_ll = Transformer.from_crs(3413, 4326, always_xy=True)
    ring = [to_ll.transform(X0 + px, Y0 + py) for px, py in
            ((0, 0), (500, 0), (500, 600), (0, 600), (0, 0))]
    gj = tmp_path / "west.geojson"
    gj.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {},
         "geometry": {"type": "Polygon", "coordinates": [ring]}}]}))
    cov = compute_coverage([path], cell_m=100.0, region=str(gj))
    assert cov.summary["region"]["kind"] == "geojson"
    assert cov.summary["cells_in_region"] == 30          # 5 x 6 cells of the west half
    assert cov.summary["cells_covered"] == 30 - 4        # the hole's four cells
    bowtie = tmp_path / "bowtie.geojson"
    bowtie.write_text(json.dumps({"type": "Polygon", "coordinates": [
        [ring[0], ring[2], ring[1], ring[3], ring[0]]]}))
    with pytest.raises(CoverageError, match="self-intersecting"):
        compute_coverage([path], cell_m=100.0, region=str(bowtie))
    far = tmp_path / "far.geojson"            # a polygon at 0 N 0 E: misses the scene
    far.write_text(json.dumps({"type": "Polygon", "coordinates": [
        [[0, 0], [0.1, 0], [0.1, 0.1], [0, 0.1], [0, 0]]]}))
    with pytest.raises(CoverageError, match="misses"):
        compute_coverage([path], cell_m=100.0, region=str(far))
