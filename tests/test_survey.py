"""Survey runs (``chirplidar run``): geometry, measurements, results files and bad input.

Reference values:
* flat terrain: the range along the ellipsoid normal from a platform at ellipsoidal height H to
  the surface of ellipsoidal height h is exactly H - h (definition of geodetic height); an
  off-nadir range is computed independently here with pyproj (bisection on the geodetic height
  along the straight ECEF ray);
* sloped plane: a footprint of diameter D on a plane tilted by alpha to the beam's normal plane
  spans tan(alpha) D in range (plane geometry);
* footprint-broadened beat: a line whose ranges spread with standard deviation sigma_R has a
  beat spread of kappa 2 sigma_R / c (kappa the chirp rate, c the speed of light).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from conftest import reference_target, write_scene, write_uav_mission
from pyproj import Transformer

from chirplidar.cli import main
from chirplidar.config.loader import ConfigError
from chirplidar.mission.results import read_netcdf
from chirplidar.mission.runner import run_mission

ROOT = Path(__file__).resolve().parents[1]
ICESAT = ROOT / "missions" / "icesat_like.toml"
DATE = "2026-01-01T00:00:00Z"   # fixed date_created: identical files for identical runs


# "Noise off": 60 dB more signal lowers the Cramer-Rao range scatter 1000-fold (to < 0.1 mm).
QUIET = ["channel.extra_attenuation_db=-60"]


def _geodetic_range(x, y, h, az, off, epsg, h_target):
    """Independent range: platform (x, y, h) -> ECEF with pyproj, the beam from the local
    east-north-up frame (azimuth from true north, off-nadir angle), bisection on the geodetic
    height along the straight ECEF ray until it equals h_target."""
    to_geo = Transformer.from_crs(epsg, 4326, always_xy=True)
    lon, lat = to_geo.transform(x, y)
    to_ecef = Transformer.from_crs(4979, 4978, always_xy=True)
    to_geod = Transformer.from_crs(4978, 4979, always_xy=True)
    p = np.array(to_ecef.transform(lon, lat, h))
    la, lo = np.radians(lat), np.radians(lon)
    east = np.array([-np.sin(lo), np.cos(lo), 0.0])
    north = np.array([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)])
    up = np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    d = np.sin(off) * (np.sin(az) * east + np.cos(az) * north) - np.cos(off) * up
    lo_t, hi_t = 0.0, 3.0 * (h - h_target) / np.cos(off) + 10.0
    for _ in range(80):
        mid = 0.5 * (lo_t + hi_t)
        q = p + mid * d
        if to_geod.transform(*q)[2] > h_target:
            lo_t = mid
        else:
            hi_t = mid
    return 0.5 * (lo_t + hi_t)


@pytest.fixture(scope="module")
def flat_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("flat")
    scene = write_scene(tmp, "flat", 'flat height_m = 100.0\nmaterial = "snow"')
    mission = write_uav_mission(tmp, scene, altitude=1100.0)
    res = run_mission(mission, overrides=QUIET, out=tmp / "flat.nc", cache_dir=tmp / "cache",
                      date_created=DATE)
    return tmp, mission, res


def test_flat_terrain_ranges_exact_and_heights(flat_run):
    _, _, res = flat_run
    ds = res.dataset
    assert ds.sizes["trajectory"] == 2 and ds.sizes["obs"] == 200
    nadir, tilted = ds.isel(trajectory=0), ds.isel(trajectory=1)
    # nadir along the ellipsoid normal: exactly H - h = 1000 m
    np.testing.assert_allclose(nadir["range_true"], 1000.0, atol=1e-3)
    np.testing.assert_allclose(tilted["off_nadir_angle"], np.radians(20.0), atol=1e-9)
    for k in (0, 57, 199):
        ref = _geodetic_range(float(tilted["platform_x"][k]), float(tilted["platform_y"][k]),
                              float(tilted["platform_altitude"][k]),
                              float(tilted["azimuth_angle"][k]), float(tilted["off_nadir_angle"][k]),
                              3413, 100.0)
        assert abs(float(tilted["range_true"][k]) - ref) < 1e-3
    assert np.all(ds["detected"] == 1)
    for b in range(2):
        err = ds["h_li"].isel(trajectory=b) - 100.0
        assert abs(float(err.mean())) <= 0.01
        np.testing.assert_allclose(ds["h_li_true"].isel(trajectory=b), 100.0, atol=1e-6)


def test_results_file_is_cf_and_round_trips(flat_run):
    tmp, _, res = flat_run
    back = read_netcdf(res.path)
    xr.testing.assert_identical(res.dataset, back)
    for name, var in back.variables.items():
        assert "long_name" in var.attrs, name
        if "grid_mapping_name" not in var.attrs:
            assert "units" in var.attrs, name
    assert back.attrs["Conventions"] == "CF-1.8"
    assert back.attrs["featureType"] == "trajectory"
    assert "[survey]" in back.attrs["configuration"] and "seed" in back.attrs
    assert back.attrs["scene_configuration"].strip().startswith("name")
    assert back["crs"].attrs["grid_mapping_name"] == "polar_stereographic"


def test_same_seed_same_output(flat_run):
    tmp, mission, res = flat_run
    again = run_mission(mission, overrides=QUIET, out=tmp / "again.nc", cache_dir=tmp / "cache",
                        date_created=DATE)
    a, b = res.dataset.copy(), again.dataset.copy()
    for d in (a, b):
        d.attrs.pop("history")
    xr.testing.assert_identical(a, b)
    other = run_mission(mission, overrides=QUIET, out=tmp / "other.nc", seed=6,
                        cache_dir=tmp / "cache", date_created=DATE)
    assert not np.array_equal(other.dataset["range_measured"], res.dataset["range_measured"])


def test_sloped_plane_spread_and_rf_broadening(tmp_path):
    """Footprint range spread = tan(slope) x footprint diameter; the rf beat broadens with it."""
    from chirplidar.channel.footprint import sub_ray_power_fractions
    from chirplidar.mission.preflight import prepare
    from chirplidar.mission.survey import chunk_geometry
    from chirplidar.channel.lab import lab_budget
    from chirplidar.units import SPEED_OF_LIGHT_M_S

    slope = 30.0
    # Wide beam (10 mrad) so the footprint (20 m from 1 km) spans far more than the 0.75 m
    # range resolution of the 200 MHz chirp.
    wide = ["channel.divergence_half_angle_rad=0.01", "processing.averages=1",
            "survey.prf_hz=50", *QUIET]
    sloped = write_scene(tmp_path, "slope", f'sloped slope_deg = {slope}\nazimuth_deg = 90.0\n'
                    'height_m = 100.0\nmaterial = "snow"')
    beams = 'pattern = "nadir"'
    ms = write_uav_mission(tmp_path, sloped, "ms", altitude=1100.0, beams=beams, stop="0.4",
                      subrays=128)
    config, scene, plan = prepare(ms, overrides=wide, cache_dir=tmp_path / "c")
    g = chunk_geometry(plan, scene, config, plan.t_s, np.random.SeedSequence(1), 128)
    diam = 2 * g.range_true_m[:, 0] * np.tan(
        float(g.beam_radius_m[0, 0]) / float(g.range_true_m[0, 0]))
    r = g.sub_range_m[:, 0]
    spread = r.max(axis=1) - r.min(axis=1)
    # Across the beam's normal plane the footprint diameter is diam; on a plane tilted by
    # alpha the ranges of its two edges differ by tan(alpha) diam (to first order in the cone).
    np.testing.assert_allclose(spread, np.tan(np.radians(slope)) * diam, rtol=0.05)

    # rf tier: the footprint's sub-rays as delayed echoes with independent phases (as
    # measure_rf passes them for a speckled surface). One shot's spectrum is a speckle pattern
    # across the spread (its own 3 dB width reads one grain), so the line shape is the spectrum
    # averaged over shots: it must widen to the spread of the footprint's beat frequencies.
    from chirplidar.tiers.echoes import Echoes
    from chirplidar.channel import simulate_lab

    bud = lab_budget(config)
    frac = sub_ray_power_fractions(config, scene, g)[0, 0]
    keep = frac > 0
    r0 = float(np.sum(frac * r[0]) / frac.sum())
    dtau = 2 * config.channel.group_index * (r[0][keep] - r0) / SPEED_OF_LIGHT_M_S
    cfg = reference_target(config, **{"channel.distance_m": r0,
                                      "simulation.sample_rate_hz": 1.2e9,
                                      "channel.extra_attenuation_db": -20.0})
    rng = np.random.default_rng(3)
    batch = 48

    def mean_spectrum(delays):
        phases = rng.uniform(0, 2 * np.pi, (batch, delays.size))
        out = simulate_lab(cfg, "rf", rng, batch=batch, keep_spectrum=True,
                          echoes=Echoes(delays, frac[keep], phases))
        return out["spectrum"]["f_hz"], np.mean(out["spectrum"]["psd_w_per_hz"], axis=0)

    def width(f, psd):
        """Frequency span holding the central 76 % of the line's power (the FWHM for a
        Gaussian line); quantiles are robust to the residual speckle ripple of a finite average,
        which biases a half-maximum width low."""
        k = int(np.argmax(psd))
        span = (f > f[k] - 3e6) & (f < f[k] + 3e6)   # +-3 MHz: the line and its skirts
        c = np.cumsum(psd[span])
        c = c / c[-1]
        fs = f[span]
        return np.interp(0.88, c, fs) - np.interp(0.12, c, fs)

    f, flat_psd = mean_spectrum(np.zeros(keep.sum()))
    _, slope_psd = mean_spectrum(dtau)
    # Reference: independent-phase echoes add in power, so the mean spectrum is the flat line
    # shifted to each echo's beat kappa dtau_k and weighted by its power.
    k0 = int(np.argmax(flat_psd))
    w = frac[keep] / frac[keep].sum()
    ref = sum(wk * np.interp(f - bud.rate_hz_per_s * dk, f - f[k0] + f[k0], flat_psd)
              for wk, dk in zip(w, dtau))
    w_flat, w_slope, w_ref = width(f, flat_psd), width(f, slope_psd), width(f, ref)
    spread_f = bud.rate_hz_per_s * (dtau.max() - dtau.min())
    assert w_slope > 4 * w_flat                      # broadened ...
    assert w_slope == pytest.approx(w_ref, rel=0.15)  # ... to the footprint's beat spread
    assert w_slope < spread_f + w_flat
    # The survey's rf tier runs the same chain per shot and reports each shot's width.
    ms1 = write_uav_mission(tmp_path, sloped, "ms1", altitude=1100.0, beams=beams, stop="0.1")
    run = run_mission(ms1, overrides=[*wide, "survey.subrays_per_beam=19",
                                      "simulation.sample_rate_hz=1.2e9"], tier="rf",
                      out=tmp_path / "rf.nc", cache_dir=tmp_path / "c", date_created=DATE)
    assert np.all(run.dataset["detected"] == 1)
    assert np.all(np.isfinite(run.dataset["beat_width"]))


def test_satellite_range_against_pyproj(tmp_path):
    scene = write_scene(tmp_path, "ant", 'flat height_m = 500.0\nmaterial = "snow"', epsg=3031,
                   lat=-67.75, lon=62.9, size=30000.0, res=1000.0)
    m = tmp_path / "sat.toml"
    m.write_text(f'extends = "{ICESAT}"\n[scene]\nfile = "{scene.name}"\n')
    res = run_mission(m, overrides=["survey.start_s=-0.01", "survey.stop_s=0.01",
                                    "system.reference_delay_s=3.33e-3"],
                      out=tmp_path / "sat.nc", cache_dir=tmp_path / "c", date_created=DATE)
    ds = res.dataset
    assert ds.sizes["trajectory"] == 6
    for b in (0, 2, 5):
        t = ds.isel(trajectory=b, obs=int(ds.sizes["obs"]) // 2)
        assert 480e3 < float(t["range_true"]) < 520e3
        ref = _geodetic_range(float(t["platform_x"]), float(t["platform_y"]),
                              float(t["platform_altitude"]), float(t["azimuth_angle"]),
                              float(t["off_nadir_angle"]), 3031, 500.0)
        assert abs(float(t["range_true"]) - ref) < 0.01


def test_cli_run_and_view(flat_run, tmp_path):
    tmp, mission, res = flat_run
    out = tmp_path / "cli.nc"
    assert main(["run", str(mission), "--out", str(out), "--no-progress", "--set", *QUIET]) == 0
    png = tmp_path / "view.png"
    assert main(["view", str(out), "--png", str(png), "--var", "snr_db"]) == 0
    import matplotlib.image as mpimg

    img = mpimg.imread(png)[..., :3]
    flat = img.reshape(-1, 3)
    background = np.median(flat, axis=0)
    assert np.mean(np.any(np.abs(flat - background) > 0.05, axis=1)) > 0.05
    assert len(np.unique(np.round(flat * 255).astype(int), axis=0)) > 100


def test_existing_output_needs_overwrite(flat_run, capsys):
    tmp, mission, res = flat_run
    before = res.path.read_bytes()
    mtime = os.stat(res.path).st_mtime_ns
    code = main(["run", str(mission), "--out", str(res.path), "--no-progress"])
    assert code == 2
    assert "--overwrite" in capsys.readouterr().err
    assert res.path.read_bytes() == before and os.stat(res.path).st_mtime_ns == mtime


def test_view_refuses_what_is_not_a_results_file(tmp_path, capsys):
    text = tmp_path / "notes.nc"
    text.write_text("not netcdf")
    other = tmp_path / "other.nc"
    xr.Dataset({"a": ("t", np.arange(3.0))}).to_netcdf(other)
    for path, why in ((text, "not a readable NetCDF"), (other, "not a chirplidar results")):
        for extra in ([], ["--plan"]):
            assert main(["view", str(path), "--png", str(tmp_path / "v.png"), *extra]) == 2
            err = capsys.readouterr().err.strip()
            assert why in err and len(err.splitlines()) == 1


def test_self_intersecting_polygon_is_refused(tmp_path):
    scene = write_scene(tmp_path, "flat3", 'flat height_m = 100.0\nmaterial = "snow"')
    bowtie = "[[-500.0, -500.0], [500.0, 500.0], [500.0, -500.0], [-500.0, 500.0]]"
    m = write_uav_mission(tmp_path, scene, polygon=bowtie)
    with pytest.raises(ConfigError, match=r"m\.toml.*platform\.uav\.survey_polygon_m.*self-intersect"):
        run_mission(m, out=tmp_path / "x.nc", cache_dir=tmp_path / "c")
    assert not (tmp_path / "x.nc").exists()


def test_path_that_misses_the_scene(tmp_path):
    scene = write_scene(tmp_path, "flat4", 'flat height_m = 100.0\nmaterial = "snow"')
    m = write_uav_mission(tmp_path, scene, waypoints="[[10000.0, 10000.0], [12000.0, 10000.0]]")
    with pytest.raises(ConfigError, match=r"m\.toml.*\[platform\].*never crosses the scene"):
        run_mission(m, out=tmp_path / "x.nc", cache_dir=tmp_path / "c")


def test_missing_scene_file_named(tmp_path):
    m = write_uav_mission(tmp_path, tmp_path / "nowhere.toml")
    with pytest.raises(ConfigError, match=r"scene\.file: nowhere\.toml does not exist"):
        run_mission(m, out=tmp_path / "x.nc")


def test_shipped_missions_plan(tmp_path):
    """Both shipped missions load, plan and cross their scenes (no shots simulated)."""
    from chirplidar.mission.preflight import prepare

    for name, beams in (("greenland_uav", 1), ("icesat_like", 6)):
        config, scene, plan = prepare(ROOT / "missions" / f"{name}.toml")
        assert plan.beams.n_beams == beams and plan.n_shots > 0


def test_turbulence_sees_the_scene_profile():
    """The turbulence effect's constant Cn^2 reproduces the Fried parameter of the scene's HV-5/7
    profile along the slant path (r0 ~ (Cn^2 L)^(-3/5), Andrews & Phillips 2005)."""
    from chirplidar.atmosphere import fried_parameter
    from chirplidar.config.loader import config_with
    from chirplidar.channel.footprint import equivalent_cn2
    from chirplidar.mission.preflight import prepare
    from chirplidar.mission.survey import chunk_geometry

    config, scene, plan = prepare(ROOT / "missions" / "greenland_uav.toml",
                                  overrides=["survey.stop_s=2"])
    g = chunk_geometry(plan, scene, config, plan.t_s, np.random.SeedSequence(0), 1)
    config = config_with(config, {
        "effects.coupling.obstruction_ratio": 0.2, "effects.coupling.focal_length_m": 0.6,
        "effects.coupling.mode_field_radius_m": 4.6e-6,
        "effects.coupling.fiber_numerical_aperture": 0.14, "effects.coupling.target": "diffuse"})
    lam = config.laser.wavelength_m
    r_med = float(np.median(g.range_true_m))
    cn2 = equivalent_cn2(config, scene, g, r_med)
    z_g = float(np.median(g.hit_xyz_m[..., 2]))
    z_p = float(np.median(g.platform_xyh[:, 2]))
    r0_scene = float(scene.fried_parameter_m(lam, z_g, z_p, 0.0, wave="spherical"))
    assert cn2 > 0
    assert fried_parameter(cn2, lam, r_med, wave="spherical") == pytest.approx(r0_scene, rel=1e-3)


def test_lawnmower_tracks_polygon_and_height_sigma(tmp_path):
    """A lawnmower run carries its lines as ``track`` (-1 on the transits), its survey polygon as
    WKT in projected metres, and ``h_li_sigma``. Reference for the sigma: the link tier draws
    each detected shot's beat around the true one with the Cramer-Rao spread (Rife & Boorstyn
    1974) that ``h_li_sigma`` states, so over many nadir shots on flat ground (height error =
    range error, no footprint spread) the measured scatter equals the predicted one within the
    sampling error of a standard deviation (1/sqrt(2 N))."""
    from shapely import wkt

    scene = write_scene(tmp_path, "flat", 'flat height_m = 100.0\nmaterial = "snow"')
    poly = "[[-500.0, -300.0], [500.0, -300.0], [500.0, 300.0], [-500.0, 300.0]]"
    mission = write_uav_mission(tmp_path, scene, polygon=poly, altitude=300.0, mode="above_ground",
                                beams='pattern = "nadir"', stop="130.0", prf=50.0, subrays=1)
    ds = run_mission(mission, out=tmp_path / "lm.nc", date_created=DATE).dataset
    # lines 200 m apart over 600 m: 3 lines of 1000 m (50 s each at 20 m/s), 2 transits of 10 s
    t = ds["delta_time"].values[0]
    track = ds["track"].values[0]
    expected = np.select([t < 50, t < 60, t < 110, t < 120], [0, -1, 1, -1], 2)
    assert np.array_equal(track, expected)
    # the polygon is given about the scene centre, the centre of the (square) scene extent
    x0, y0, x1, y1 = wkt.loads(ds.attrs["survey_polygon_wkt"]).bounds
    ex0, ey0, ex1, ey1 = wkt.loads(ds.attrs["scene_extent_wkt"]).bounds
    assert (x1 - x0, y1 - y0) == pytest.approx((1000.0, 600.0))
    assert (ex1 - ex0, ey1 - ey0) == pytest.approx((4000.0, 4000.0))
    assert (0.5 * (x0 + x1), 0.5 * (y0 + y1)) == pytest.approx(
        (0.5 * (ex0 + ex1), 0.5 * (ey0 + ey1)), abs=1e-6)
    det = ds["detected"].values == 1
    sig = ds["h_li_sigma"].values
    assert np.all(np.isnan(sig[~det])) and np.all(sig[det] > 0)
    err = (ds["h_li"] - ds["h_li_true"]).values[det]
    n = err.size
    predicted = np.sqrt(np.mean(sig[det] ** 2))
    assert n > 3000
    assert np.std(err) == pytest.approx(predicted, rel=4 / np.sqrt(2 * n))


def test_scene_keys_in_the_mission(tmp_path):
    """``scene.<key>`` in a mission (or --set) changes that key of the scene file for this run;
    a misspelt one is an error naming it."""
    from chirplidar.mission.preflight import prepare

    scene = write_scene(tmp_path, "flat", 'flat height_m = 100.0\nmaterial = "snow"')
    mission = write_uav_mission(tmp_path, scene, altitude=300.0, mode="above_ground",
                                beams='pattern = "nadir"', stop="2.0", subrays=1)
    _, sc, _ = prepare(mission, overrides=["scene.terrain.flat.material=blue_ice",
                                           "scene.terrain.flat.height_m=250.0"])
    assert {sc.material_names[c] for c in np.unique(sc.terrain.face_materials)} == {"blue_ice"}
    assert sc.height_range_m == pytest.approx((250.0, 250.0))
    with pytest.raises(ConfigError, match="terrain.flat.hieght_m"):
        prepare(mission, overrides=["scene.terrain.flat.hieght_m=250.0"])
    ds = run_mission(mission, out=tmp_path / "m.nc", date_created=DATE,
                     overrides=["scene.terrain.flat.material=blue_ice"]).dataset
    assert 'material = "blue_ice"' in ds.attrs["configuration"]
    names = dict(zip(ds["surface_type"].attrs["flag_values"].tolist(),
                     ds["surface_type"].attrs["flag_meanings"].split()))
    assert {names[c] for c in np.unique(ds["surface_type"].values)} == {"blue_ice"}
    # the views rebuild the scene the run flew over: the file's text with the mission's changes
    from chirplidar.mission.view import result_terrain

    moved = run_mission(mission, out=tmp_path / "h.nc", date_created=DATE,
                        overrides=["scene.terrain.flat.height_m=250.0"]).dataset
    lo, hi = result_terrain(moved).bounds
    assert (lo[2], hi[2]) == pytest.approx((250.0, 250.0))


def test_shot_clock_is_the_shot_times_without_holding_them():
    # Reference: shot_times' array (start + i / prf), bit for bit, for every kind of index.
    from chirplidar.geometry.pointing import ShotClock, shot_times

    t = shot_times(3.5, 1000.0, 9433.96)
    clock = ShotClock.between(3.5, 1000.0, 9433.96)
    assert clock.size == len(clock) == t.size and clock.shape == t.shape
    assert np.array_equal(np.asarray(clock), t)
    for key in (slice(0, 100), slice(5000, None), slice(-7, None), slice(10, 2000, 3),
                slice(0, 0), np.array([0, 17, t.size - 1]), t > 500.0):
        assert np.array_equal(clock[key], t[key])
    assert clock[0] == t[0] and clock[-1] == t[-1] and clock[12345] == t[12345]
    with pytest.raises(IndexError):
        clock[t.size]
    with pytest.raises(IndexError):
        clock[np.array([t.size])]
    assert ShotClock.between(2.0, 2.0, 100.0).size == 0 == shot_times(2.0, 2.0, 100.0).size
    with pytest.raises(ValueError, match="stop_s"):
        ShotClock.between(2.0, 1.0, 100.0)
