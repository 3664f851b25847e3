"""Mission studies (``chirplidar study``): a survey mission over a grid of one or two keys.

The scene: flat snow 100 m above the ellipsoid, no atmosphere and no effects; the mission: the
thesis field instrument on a UAV flying a straight line at ``altitude_mode = "above_ground"``
with one nadir beam, link tier, so the range of every shot is the altitude.

Reference values and their sources:
* received power: a Lambertian surface that intercepts the whole beam returns
  P_r = P_t T (rho / pi) A_tel / R^2 (the lidar range equation, thesis eq. 2.2.3): 20 dB less
  per decade of range;
* SNR: the link budget of one shot, ``chirplidar.api.simulate_shot(config, tier="link")`` on
  the mission's own instrument with its bench channel set to the same geometry (the thesis
  Chapter 4 point-target channel, ``channel.lab``), which shares none of the survey's geometry,
  sub-ray footprint or per-shot code;
* detection probability: its definition, the fraction of the point's shots with a surface in
  the beam whose SNR clears the point's threshold, read from the point's own results file;
* quantiles: numpy's ``np.median`` / ``np.percentile`` (linear method) on the whole file;
* height precision: the sample standard deviation, sqrt(sum (x - mean)^2 / (n - 1)) (ddof 1, what
  ``chirplidar coverage``'s ``height_error_std`` is and ``np.std(..., ddof=1)`` computes),
  undefined for fewer than two values; for height errors 1, 3, 5 cm it is exactly 2 cm (mean
  3 cm, squared deviations 4 + 0 + 4 cm^2, over n - 1 = 2); ddof 0 would give 1.63 cm.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from conftest import FLAT_SNOW, write_scene, write_uav_mission

from chirplidar.analysis.study import run_study
from chirplidar.analysis.study_grid import dim_name, key_units, parse_vary, toml_literal
from chirplidar.analysis.study_metrics import METRICS, point_metrics
from chirplidar.analysis.study_output import format_study, study_dataset, study_records, write_study
from chirplidar.analysis.study_plan import StudyPlan, plan_study
from chirplidar.cli import main
from chirplidar.config import ConfigError, config_with, load_mission, parse_set
from chirplidar.mission.results import read_netcdf
from chirplidar.mission.runner import run_mission
from chirplidar.units import power_dbm

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NADIR = 'pattern = "nadir"'
ALTITUDES = "platform.uav.altitude_m=100:1000:4:log"     # 100, 215, 464, 1000 m
SPAN = 2.0                                                # s: 40 shots per point at 20 Hz
JSON_KEYS = {"detection_probability", "median_snr_db", "median_received_power_dbm",
             "snr_p01_db", "snr_p10_db", "snr_p90_db", "range_rms_m", "height_precision_m",
             "flight_time_s", "shots", "detected_shots", "detection_threshold_db"}


@pytest.fixture(scope="module")
def flat(tmp_path_factory):
    """(directory, scene file, mission file): a 1.6 km line over flat snow, 300 m above the
    ground, 10 s at 20 Hz, 3 sub-rays per beam, nadir beam, link tier."""
    tmp = tmp_path_factory.mktemp("study")
    scene = write_scene(tmp, "flat", FLAT_SNOW, stem="flat_scene")
    mission = write_uav_mission(tmp, scene, "line", altitude=300.0, mode="above_ground",
                                beams=NADIR, stop="10.0", subrays=3, prf=20.0)
    return tmp, scene, mission


@pytest.fixture(scope="module")
def altitude_study(flat):
    """The altitude study 100..1000 m (log spacing), each point's results kept in memory."""
    _, _, mission = flat
    kept = {}

    def keep(point, path, metrics):
        kept[point.index] = (read_netcdf(path), metrics)

    ds = run_study(mission, [ALTITUDES], span_s=SPAN, tier="link", on_point=keep)
    return ds, kept


def strict_json(text: str):
    def bad(token):
        raise ValueError(f"non-JSON constant {token}")
    return json.loads(text, parse_constant=bad)


def leftovers(directory: Path) -> list[Path]:
    return sorted(directory.glob(".chirplidar-study-*"))


# ------------------------------------------------------------------------------- physics
def test_received_power_falls_20_db_per_decade(altitude_study):
    """Lambertian return, P_r proportional to 1/R^2 (module docstring): a straight line of
    median received power against log10(range) has slope -20 dB/decade within 0.5 dB, and each
    point lies on it within 0.05 dB."""
    ds, _ = altitude_study
    r = ds["platform_uav_altitude_m"].values       # above ground, nadir: range = altitude
    p = ds["median_received_power_dbm"].values
    slope, intercept = np.polyfit(np.log10(r), p, 1)
    print(f"median received power: {slope:.4f} dB/decade")   # seen: -20.0000
    assert slope == pytest.approx(-20.0, abs=0.5)
    assert np.max(np.abs(p - (slope * np.log10(r) + intercept))) < 0.05


def test_median_snr_matches_a_single_shot_link_budget(altitude_study, flat):
    """The median SNR at each altitude agrees within 1 dB with one link-tier shot of the same
    instrument on its bench channel at that range (module docstring); seen: -0.025 dB.

    Why the median of the survey's shots is that shot's SNR: the instrument's carrier phase is
    "random" and it averages K = processing.averages = 94 chirps in power per record, so each
    record's SNR is the mean-phase SNR (what simulate_shot returns) times
    F = (2/K) sum_k sin^2(psi_k), whose mean is 1 and spread sqrt(1/(2K)) = 7 % (near-Gaussian
    for K = 94: median factor 1 within a few tenths of a percent; 40 shots' sample median within
    ~0.1 dB). The detector's roll-off at the higher beat frequency (the beat grows with range)
    is in both: it is physics, not error."""
    ds, _ = altitude_study
    _, scene_path, mission = flat
    from chirplidar.api import simulate_shot
    from chirplidar.mission.scene import load_scene

    cfg = load_mission(mission)
    scene = load_scene(scene_path)
    # the scene's snow reflectivity at the laser wavelength (what the survey's sub-rays use)
    rho = float(scene.material_reflectivity(cfg.laser.wavelength_m)[
        scene.material_names.index("snow")])
    assert cfg.channel.extra_attenuation_db == 0.0   # the field instrument has no attenuator
    assert cfg.channel.free_space and cfg.channel.carrier_phase == "random"
    diffs = []
    for alt, med in zip(ds["platform_uav_altitude_m"].values, ds["median_snr_db"].values):
        bench = config_with(cfg, {
            "channel.distance_m": float(alt),          # nadir over flat ground: range = altitude
            "channel.free_space": True,                # the free-space channel (atm.state = on)
            "channel.target_radius_m": 100.0,          # a disc far wider than the ~0.2 m beam:
                                                       # it intercepts the whole beam, as the
                                                       # flat snow does
            "channel.target_reflectivity": rho,        # the scene's snow at 1310 nm
            "channel.atmospheric_transmission": 1.0,   # the scene has no atmosphere
            "effects.enabled": [],                     # the scene enables no effect
        })                                             # T_opt, telescope, laser: the mission's
        with pytest.warns(UserWarning, match="lab channel"):   # on purpose: the bench channel
            ref = simulate_shot(bench, tier="link")["SNR"]
        diffs.append(med - ref)
        print(f"{alt:7.1f} m: study {med:.3f} dB, single shot {ref:.3f} dB")
    assert np.all(np.abs(diffs) < 1.0), diffs


def test_detection_probability_is_the_fraction_above_threshold(flat):
    """detection_probability = the fraction of the point's surface shots whose snr_db clears
    the point's threshold, from the point's own results file (the on_point hook). The threshold
    11.9 dB sits at the 1000 m point's median SNR, so that point detects a fraction strictly
    between 0 and 1."""
    _, _, mission = flat
    seen = {}

    def check(point, path, metrics):
        res = read_netcdf(path)
        det = res["detected"].values
        snr = res["snr_db"].values
        surface = det != 2
        above = np.count_nonzero(surface & (snr >= point.detection_threshold_db))
        seen[point.index] = (above / np.count_nonzero(surface), metrics)

    ds = run_study(mission, [ALTITUDES], overrides=["survey.detection_threshold_db=11.9"],
                   span_s=SPAN, tier="link", on_point=check)
    p = ds["detection_probability"].values
    for i, (expected, metrics) in sorted(seen.items()):
        assert p[i] == expected == metrics["detection_probability"]
    print("detection probabilities:", p)               # seen: 1, 1, 1, 0.475
    assert 0.0 < p[-1] < 1.0
    assert np.all(ds["detection_threshold_db"].values == 11.9)


def test_metrics_agree_with_numpy_on_the_whole_file(altitude_study):
    """Every metric of a point equals numpy on the point's whole results file: medians and
    percentiles exactly (np.median, np.percentile), RMS, std and counts to rounding."""
    ds, kept = altitude_study
    for index, (res, metrics) in kept.items():
        det = res["detected"].values.ravel()
        surface, ok = det != 2, det == 1
        snr = res["snr_db"].values.ravel()[surface]
        pw = power_dbm(res["received_power"].values.ravel()[surface])
        assert metrics["median_snr_db"] == np.median(snr)
        assert metrics["snr_p01_db"] == np.percentile(snr, 1)
        assert metrics["snr_p10_db"] == np.percentile(snr, 10)
        assert metrics["snr_p90_db"] == np.percentile(snr, 90)
        assert metrics["median_received_power_dbm"] == np.median(pw)
        err = res["range_error"].values.ravel()[ok]
        assert metrics["range_rms_m"] == pytest.approx(np.sqrt(np.mean(err ** 2)), rel=1e-12)
        dh = (res["h_li"] - res["h_li_true"]).values.ravel()[ok]
        assert dh.size >= 2
        assert metrics["height_precision_m"] == pytest.approx(np.std(dh, ddof=1), rel=1e-9)
        assert metrics["detected_shots"] == np.count_nonzero(ok)
        assert ds["detected_shots"].values[index] == np.count_nonzero(ok)
        t = res["delta_time"].values
        assert metrics["flight_time_s"] == pytest.approx(t.max() - t.min(), rel=1e-12)
        assert metrics["shots"] == det.size == 40
        assert ds["median_snr_db"].values[index] == metrics["median_snr_db"]


def test_streamed_quantiles_equal_in_memory_ones(tmp_path):
    """A file read 7 observations at a time with no memory to keep the shots (so quantiles come
    from the radix select over the blocks) gives the same bits as one read in memory and as
    numpy; several beams, several HDF5 chunks."""
    scene = write_scene(tmp_path, "flat", FLAT_SNOW)
    mission = write_uav_mission(tmp_path, scene, "two", altitude=900.0, mode="above_ground",
                                stop="3.0", subrays=3, prf=20.0,
                                extra="chunk_shots = 16")       # two beams, 0 and 20 deg
    res = run_mission(mission, out=tmp_path / "two.nc")
    streamed = point_metrics(res.path, detection_threshold_db=10.0, budget_bytes=0,
                             obs_block=7)
    in_memory = point_metrics(res.path, detection_threshold_db=10.0)
    # Quantiles and counts: the same bits. The sums (range RMS, the height spread's Chan
    # update) are accumulated over other blocks, so in another order: equal to rounding.
    sums = ("range_rms_m", "height_precision_m")
    assert {k: v for k, v in streamed.items() if k not in sums} == \
        {k: v for k, v in in_memory.items() if k not in sums}
    for k in sums:
        assert streamed[k] == pytest.approx(in_memory[k], rel=1e-12)
    ds = read_netcdf(res.path)
    det = ds["detected"].values.ravel()
    snr = ds["snr_db"].values.ravel()[det != 2]
    assert streamed["median_snr_db"] == np.median(snr)
    assert streamed["snr_p10_db"] == np.percentile(snr, 10)
    assert streamed["snr_p01_db"] == np.percentile(snr, 1)
    assert streamed["snr_p90_db"] == np.percentile(snr, 90)
    assert streamed["shots"] == det.size == 2 * 60


def test_zero_power_shots_read_minus_inf_without_warnings(tmp_path):
    """Shots with a surface but no signal (received_power 0, snr_db NaN) count as -inf dB(m):
    a median over mostly such shots is -inf, a high percentile finite; no NaN, no warning
    (pytest turns RuntimeWarnings into errors here). Synthetic file, 2 beams x 10 shots."""
    det = np.array([[2, 0, 0, 0, 0, 0, 0, 1, 1, 1], [0, 0, 0, 0, 0, 0, 0, 1, 1, 2]], np.int8)
    power = np.where(det == 1, 1e-9, np.where(det == 0, 0.0, np.nan))
    snr = np.where(det == 1, 20.0, np.nan)
    rng_err = np.where(det == 1, 0.01, np.nan)
    h_true = np.full(det.shape, 100.0)
    h = np.where(det == 1, 100.02, np.nan)
    t = np.broadcast_to(np.arange(10) * 0.05, det.shape)
    dims = ("trajectory", "obs")
    xr.Dataset({"detected": (dims, det), "received_power": (dims, power),
                "snr_db": (dims, snr), "range_error": (dims, rng_err), "h_li": (dims, h),
                "h_li_true": (dims, h_true), "delta_time": (dims, t)}).to_netcdf(
        tmp_path / "zero.nc")
    for budget in (None, 0):
        m = point_metrics(tmp_path / "zero.nc", detection_threshold_db=10.0,
                          budget_bytes=budget, obs_block=3)
        assert m["median_snr_db"] == -np.inf
        assert m["median_received_power_dbm"] == -np.inf
        assert m["snr_p10_db"] == -np.inf
        assert m["snr_p90_db"] == 20.0                  # 18 surface shots: ranks 15, 16
        assert m["detection_probability"] == 5 / 18
        assert m["range_rms_m"] == pytest.approx(0.01)
        assert m["height_precision_m"] == pytest.approx(0.0, abs=1e-9)
        assert m["flight_time_s"] == pytest.approx(0.45)
        assert m["shots"] == 20 and m["detected_shots"] == 5


@pytest.mark.parametrize("seed", range(20))
def test_quantiles_bitwise_equal_numpy(tmp_path, seed):
    """Random SNR and powers, an even number of surface shots (the median is the mean of the
    middle two, which np.median and a percentile's interpolation can round differently):
    in memory and streamed, the medians equal np.median and the 10/90 % points np.percentile,
    bit for bit."""
    rng = np.random.default_rng(seed)
    det = rng.choice(np.array([0, 1, 2], np.int8), size=(3, 41), p=[0.3, 0.6, 0.1])
    det[0, 0] = 2
    if np.count_nonzero(det != 2) % 2:                  # an even number of surface shots
        det[0, 1] = 2 if det[0, 1] != 2 else 1
    snr = np.where(det != 2, rng.normal(12.0, 5.0, det.shape), np.nan)
    power = np.where(det != 2, rng.lognormal(-20.0, 1.0, det.shape), np.nan)
    dims = ("trajectory", "obs")
    nan = np.full(det.shape, np.nan)
    xr.Dataset({"detected": (dims, det), "received_power": (dims, power),
                "snr_db": (dims, snr), "range_error": (dims, nan), "h_li": (dims, nan),
                "h_li_true": (dims, nan),
                "delta_time": (dims, np.broadcast_to(np.arange(41.0), det.shape))}).to_netcdf(
        tmp_path / "q.nc")
    surface = det != 2
    assert np.count_nonzero(surface) % 2 == 0
    s, p = snr[surface], power_dbm(power[surface])
    for budget in (None, 0):
        m = point_metrics(tmp_path / "q.nc", detection_threshold_db=10.0, budget_bytes=budget,
                          obs_block=5)
        assert m["median_snr_db"] == np.median(s)
        assert m["snr_p10_db"] == np.percentile(s, 10)
        assert m["snr_p90_db"] == np.percentile(s, 90)
        assert m["median_received_power_dbm"] == np.median(p)


def _results_file(path, detected, dh_m, range_error_m):
    """A synthetic results file: one beam, the shots' ``detected`` flags, their height errors
    h_li - h_li_true and range errors (NaN where not detected)."""
    det = np.asarray([detected], np.int8)
    ok = det == 1
    h_true = np.full(det.shape, 100.0)
    h = np.where(ok, h_true + np.asarray([dh_m]), np.nan)
    err = np.where(ok, np.asarray([range_error_m]), np.nan)
    dims = ("trajectory", "obs")
    xr.Dataset({"detected": (dims, det), "received_power": (dims, np.full(det.shape, 1e-9)),
                "snr_db": (dims, np.where(ok, 20.0, 5.0)), "range_error": (dims, err),
                "h_li": (dims, h), "h_li_true": (dims, h_true),
                "delta_time": (dims, np.arange(det.size)[None, :] * 0.01)}).to_netcdf(path)
    return path


@pytest.mark.parametrize("budget, block", [(None, None), (0, 2)])
def test_height_precision_is_the_sample_std_and_needs_two_shots(tmp_path, budget, block):
    """height_precision_m is the sample standard deviation (ddof 1; module docstring): height
    errors 1, 3, 5 cm give exactly 2 cm (np.std ddof 1; ddof 0 would be 1.63 cm); one detected
    shot has no spread: NaN, not 0 cm; no detected shot: range_rms_m NaN too. detected_shots
    counts what they rest on. In one read and in blocks of 2 shots (the pairwise update)."""
    kw = {"detection_threshold_db": 10.0, "budget_bytes": budget, "obs_block": block}
    three = _results_file(tmp_path / "three.nc", [0, 1, 1, 0, 1, 0],
                          [0.0, 0.01, 0.03, 0.0, 0.05, 0.0], [0.0, 0.02, -0.02, 0.0, 0.01, 0.0])
    m = point_metrics(three, **kw)
    assert m["detected_shots"] == 3
    assert m["height_precision_m"] == pytest.approx(0.02, rel=1e-9)
    assert m["height_precision_m"] == pytest.approx(np.std([0.01, 0.03, 0.05], ddof=1),
                                                    rel=1e-9)
    assert m["range_rms_m"] == pytest.approx(np.sqrt((0.02 ** 2 * 2 + 0.01 ** 2) / 3), rel=1e-9)
    one = _results_file(tmp_path / "one.nc", [0, 0, 1, 0], [0.0, 0.0, 0.04, 0.0],
                        [0.0, 0.0, -0.03, 0.0])
    m = point_metrics(one, **kw)
    assert m["detected_shots"] == 1
    assert np.isnan(m["height_precision_m"])                   # not 0.00 cm
    assert m["range_rms_m"] == pytest.approx(0.03, rel=1e-9)   # the RMS of one error: |err|
    none = _results_file(tmp_path / "none.nc", [0, 0, 0], [0.0] * 3, [0.0] * 3)
    m = point_metrics(none, **kw)
    assert m["detected_shots"] == 0 and m["detection_probability"] == 0.0
    assert np.isnan(m["range_rms_m"]) and np.isnan(m["height_precision_m"])


# ---------------------------------------------------------------------- grid and dataset
def test_parse_vary_ranges_and_lists():
    """Ranges (linear, log, integers), lists of TOML literals and bare words, lists of lists,
    thesis names; the override text reads back equal through --set's parser."""
    a = parse_vary("platform.uav.altitude_m=100:1000:10")
    assert a.values == tuple(range(100, 1001, 100)) and a.spacing == "lin"
    assert a.dim == "platform_uav_altitude_m" and key_units(a.mission_key) == ("m", "m")
    b = parse_vary("lsr.Po=0.001:0.1:3:log")
    assert b.mission_key == "laser.power_w" and b.dim == "laser_power_w"
    assert b.values == pytest.approx((0.001, 0.01, 0.1)) and key_units(b.key)[0] == "W"
    c = parse_vary("scene.terrain.flat.material=snow,blue_ice")
    assert c.values == ("snow", "blue_ice") and c.spacing == "list"
    d = parse_vary("beams.off_nadir_deg=[0.0],[15.0, 2.0]")
    assert d.values == ([0.0], [15.0, 2.0])
    e = parse_vary("survey.detection_threshold_db=8,10.5")
    assert e.values == (8, 10.5) and key_units(e.key)[0] == "dB"
    for v in (300, 1e-13, 2.5, "blue_ice", [0.0, 15.0], True):
        assert parse_set(f"k={toml_literal(v)}")[1] == v
    assert dim_name("scene.atmosphere.ground_cn2_m_minus_2_3") == \
        "scene_atmosphere_ground_cn2_m_minus_2_3"
    assert key_units("scene.atmosphere.ground_cn2_m_minus_2_3")[0] == "m-2/3"
    assert key_units("platform.uav.speed_mps")[0] == "m s-1"
    assert key_units("beams.cone_half_angle_deg")[0] == "degree"


@pytest.mark.parametrize("spec, words", [
    ("platform.uav.altitud_m=1:2:3", "did you mean: platform.uav.altitude_m"),
    ("platform.uav.altitude_m=100:1000:1", "N >= 2"),
    ("platform.uav.altitude_m=100:1000", "START:STOP:N"),
    ("platform.uav.altitude_m=100:x:3", "STOP"),
    ("platform.uav.altitude_m=100:1000:2.5", "integer"),
    ("platform.uav.altitude_m=0:1000:3:log", "> 0"),
    ("platform.uav.altitude_m=100:1000:3:cubic", "'lin' or 'log'"),
    ("platform.uav.altitude_m=300", "one value"),
    ("platform.uav.altitude_m=300,300", "twice"),
    ("platform.uav.altitude_m=300,,400", "empty"),
    ("platform.uav.altitude_m", "KEY=START:STOP:N"),
])
def test_parse_vary_refuses(spec, words):
    with pytest.raises(ConfigError, match=None) as err:
        parse_vary(spec)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_two_keys_dataset_netcdf_and_plot(flat, tmp_path):
    """Altitude x material: dims (3, 2), a string coordinate, units and long_name on every
    variable, the run's settings in the global attributes, a NetCDF file that reads back equal,
    the plot; blue ice (about 13 dB darker than snow at 1310 nm) has the lower SNR."""
    from chirplidar.viz.study import plot_study

    _, _, mission = flat
    out = tmp_path / "two.nc"
    ds = run_study(mission, ["platform.uav.altitude_m=100:1000:3",
                             "scene.terrain.flat.material=snow,blue_ice"],
                   overrides=["survey.prf_hz=10"], span_s=1.5, tier="link", seed=3, out=out)
    assert ds["median_snr_db"].dims == ("platform_uav_altitude_m",
                                        "scene_terrain_flat_material")
    assert ds["median_snr_db"].shape == (3, 2)
    assert list(ds["scene_terrain_flat_material"].values) == ["snow", "blue_ice"]
    assert list(ds["platform_uav_altitude_m"].values) == [100, 550, 1000]
    for name, var in ds.variables.items():
        assert "units" in var.attrs and "long_name" in var.attrs, name
    assert set(ds.data_vars) == set(METRICS) - {"fraction_covered"}
    assert ds["platform_uav_altitude_m"].attrs["study_key"] == "platform.uav.altitude_m"
    assert ds["platform_uav_altitude_m"].attrs["units"] == "m"
    assert ds.attrs["seed"] == 3 and ds.attrs["tier"] == "link" and ds.attrs["span_s"] == 1.5
    assert json.loads(ds.attrs["set_overrides"]) == ["survey.prf_hz=10"]
    assert np.all(ds["shots"].values == 15)
    snr = ds["median_snr_db"].values
    assert np.all(snr[:, 1] < snr[:, 0] - 10.0)
    back = xr.open_dataset(out)
    xr.testing.assert_identical(back.load(), ds)
    back.close()
    png = plot_study(ds, tmp_path / "two.png")
    assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 20_000
    assert not leftovers(tmp_path)
    with pytest.raises(FileExistsError):
        write_study(ds, out)


def test_two_numeric_keys_heat_map(flat, tmp_path):
    """Altitude x threshold (3 x 3): the heat-map plot; detection falls where the threshold
    rises above the median SNR."""
    from chirplidar.viz.study import plot_study

    _, _, mission = flat
    ds = run_study(mission, ["platform.uav.altitude_m=100:1000:3:log",
                             "survey.detection_threshold_db=5,15,30"], span_s=1.0, tier="link")
    p = ds["detection_probability"].values
    assert p.shape == (3, 3)
    assert np.all(np.diff(p, axis=1) <= 0)             # a higher threshold detects no more
    assert list(ds["detection_threshold_db"].values[0]) == [5, 15, 30]
    png = plot_study(ds, tmp_path / "heat.png")
    assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 20_000


def test_every_point_is_checked_before_any_run(flat, monkeypatch):
    """A bad value at the last point (an unknown material, an altitude span beyond the path)
    stops the study before the first run."""
    from chirplidar.mission import runner

    _, _, mission = flat

    def never(*args, **kwargs):
        raise AssertionError("a point ran before the study was checked")

    monkeypatch.setattr(runner, "run_mission", never)
    with pytest.raises(ConfigError, match="unknown material 'slush'"):
        run_study(mission, ["platform.uav.altitude_m=100,200",
                            "scene.terrain.flat.material=snow,slush"], tier="link")
    with pytest.raises(ConfigError, match="--span-s 11: beyond the mission's stop"):
        run_study(mission, ["platform.uav.altitude_m=100,200"], span_s=11.0)
    with pytest.raises(ConfigError, match="--span-s must be a finite number > 0"):
        run_study(mission, ["platform.uav.altitude_m=100,200"], span_s=0.0)
    with pytest.raises(ConfigError, match="also given in --set"):
        plan_study(mission, ["lsr.Po=0.01,0.02"], overrides=["laser.power_w=0.03"])
    with pytest.raises(ConfigError, match="given twice"):
        plan_study(mission, ["lsr.Po=0.01,0.02", "laser.power_w=0.01,0.02"])
    with pytest.raises(ConfigError, match="same seed"):
        plan_study(mission, ["seed=1,2"])
    with pytest.raises(ConfigError, match="at most 2 keys"):
        plan_study(mission, ["lsr.Po=0.01,0.02", "survey.prf_hz=10,20",
                             "platform.uav.speed_mps=10,20"])


def test_coverage_fraction_per_point(tmp_path):
    """--cell-m: fraction_covered is chirplidar.analysis.coverage's figure for the point's own
    results file over its survey polygon; lines 200 m apart cover fewer 40 m cells of a
    400 m x 400 m polygon than lines 100 m apart."""
    from chirplidar.analysis.coverage import compute_coverage

    scene = write_scene(tmp_path, "flat", FLAT_SNOW)
    poly = "[[-200.0, -200.0], [200.0, -200.0], [200.0, 200.0], [-200.0, 200.0]]"
    mission = write_uav_mission(tmp_path, scene, "mow", polygon=poly, altitude=200.0,
                                mode="above_ground", beams=NADIR, stop="40.0", prf=10.0,
                                subrays=1)
    # the whole lawnmower: no survey.stop_s (the end of the path)
    mission.write_text(mission.read_text().replace("stop_s = 40.0\n", ""))
    direct = {}

    def check(point, path, metrics):
        cov = compute_coverage([path], cell_m=40.0, region="survey")
        direct[point.index] = cov.summary["fraction_covered"]

    ds = run_study(mission, ["platform.uav.line_spacing_m=100,200"], cell_m=40.0,
                   tier="link", on_point=check)
    f = ds["fraction_covered"].values
    assert [f[0], f[1]] == [direct[(0,)], direct[(1,)]]
    print("fraction covered:", f)
    assert 0.0 < f[1] < f[0] <= 1.0
    assert ds["fraction_covered"].attrs["units"] == "1"


# ------------------------------------------------------------------- table and plot (no runs)
# The numbers of the trial's altitude study (chirplidar study missions/greenland_uav.toml
# --vary platform.uav.altitude_m=50:800:5:log --span-s 60, link tier, seed 2026): at 800 m one
# of 6000 shot-beams is detected.
ALT_SPEC = "platform.uav.altitude_m=50:800:5:log"
ALT_METRICS = {
    "detection_probability": [0.971, 0.895, 0.637, 0.146, 1 / 6000],
    "median_snr_db": [24.0, 18.0, 11.8, 5.5, -1.3],
    "snr_p10_db": [15.9, 9.8, 3.6, -2.7, -9.5],
    "snr_p90_db": [29.4, 23.3, 17.2, 10.8, 4.1],
    "median_received_power_dbm": [-81.7, -87.7, -93.7, -99.7, -105.8],
    "range_rms_m": [0.0267, 0.0424, 0.0622, 0.0828, 0.0387],
    "height_precision_m": [0.0267, 0.0424, 0.0622, 0.0829, np.nan],
    "detected_shots": [5825, 5371, 3824, 876, 1],
}


def _study(spec: str, values: dict) -> xr.Dataset:
    """A study dataset of one varied key from given metric values (no run): study_dataset of a
    StudyPlan with that axis; 6000 shots, 60 s and a 10 dB threshold at every point."""
    axis = parse_vary(spec)
    n = len(axis.values)
    plan = StudyPlan(mission_path=Path("greenland_uav.toml"), axes=(axis,), points=(),
                     overrides=(), seed=2026, tier="link", span_s=60.0, cell_m=None)
    metrics = {name: np.full(n, np.nan) for name in METRICS}
    metrics.update(shots=np.full(n, 6000, np.int64), flight_time_s=np.full(n, 60.0),
                   detection_threshold_db=np.full(n, 10.0))
    for name, v in values.items():
        metrics[name] = np.asarray(v, np.int64 if name == "detected_shots" else float)
    return study_dataset(plan, metrics, date_created="2026-01-01T00:00:00Z")


def test_table_and_records_show_the_detected_shots():
    ds = _study(ALT_SPEC, ALT_METRICS)
    assert ds["detected_shots"].attrs["units"] == "1" and ds["detected_shots"].dtype == np.int64
    lines = format_study(ds).splitlines()
    head, last = lines[1], lines[-1]

    def cell(column):   # columns are right-aligned under their heading
        end = head.index(column) + len(column)
        return last[:end].split()[-1]

    assert cell("platform.uav.altitude_m") == "800" and cell("detected") == "1"
    assert cell("h prec") == "-"                       # NaN from one shot, not 0.00
    assert cell("range RMS") == "3.87"
    rec = study_records(ds)[-1]
    assert rec["detected_shots"] == 1 and isinstance(rec["detected_shots"], int)
    assert np.isnan(rec["height_precision_m"])


def _panels(fig):
    ax_det, ax_snr, ax_pow, ax_rng = fig.axes[:4]
    return ax_det, ax_snr, ax_pow, ax_rng


def test_plot_marks_points_on_few_detected_shots():
    """The 800 m point rests on 1 detected shot: left out of the range-RMS line (no dip drawn),
    an open marker with "n=1" beside it, and the legend says what open markers are."""
    from chirplidar.viz.study import MIN_DETECTED_SHOTS, study_figure

    fig = study_figure(_study(ALT_SPEC, ALT_METRICS))
    try:
        ax_rng = _panels(fig)[3]
        rms_line = ax_rng.lines[0]
        y = np.asarray(rms_line.get_ydata(), float)
        assert np.allclose(y[:4], [2.67, 4.24, 6.22, 8.28]) and np.isnan(y[4])
        open_marks = [ln for ln in ax_rng.lines if ln.get_markerfacecolor() == "none"]
        assert len(open_marks) == 1
        assert list(open_marks[0].get_xdata()) == [800.0]
        assert list(open_marks[0].get_ydata()) == pytest.approx([3.87])
        assert [t.get_text() for t in ax_rng.texts] == ["n=1"]
        legend = [t.get_text() for t in ax_rng.get_legend().get_texts()]
        assert f"open: < {MIN_DETECTED_SHOTS} detected shots (n=count), not joined" in legend
    finally:
        plt_close(fig)
    enough = dict(ALT_METRICS, detected_shots=[5825, 5371, 3824, 876, 10],
                  height_precision_m=[0.0267, 0.0424, 0.0622, 0.0829, 0.05])
    fig = study_figure(_study(ALT_SPEC, enough))
    try:
        ax_rng = _panels(fig)[3]
        assert np.isfinite(np.asarray(ax_rng.lines[0].get_ydata(), float)).all()
        assert not [ln for ln in ax_rng.lines if ln.get_markerfacecolor() == "none"]
        assert not ax_rng.texts
    finally:
        plt_close(fig)


def plt_close(fig):
    from chirplidar.viz._mpl import plt

    plt.close(fig)


def test_plot_panels_keep_a_minimum_span():
    """A quantity that does not change (received power against the line spacing: +-0.005 dB
    of noise) spans at least 1 dB, centred on the data; range RMS at least 1 cm; a panel whose
    data spans more keeps its autoscaled limits."""
    from chirplidar.viz.study import study_figure

    flat = {"detection_probability": [0.859, 0.862, 0.855, 0.855],
            "median_snr_db": [16.6, 17.0, 16.4, 16.4],
            "snr_p10_db": [16.5, 16.9, 16.3, 16.3], "snr_p90_db": [16.7, 17.1, 16.5, 16.5],
            "median_received_power_dbm": [-89.265, -89.26, -89.255, -89.26],
            "range_rms_m": [0.04810, 0.04812, 0.04811, 0.04810],
            "height_precision_m": [0.04810, 0.04812, 0.04811, 0.04810],
            "detected_shots": [5152, 5175, 5127, 5127]}
    fig = study_figure(_study("platform.uav.line_spacing_m=100,150,200,300", flat))
    try:
        _, ax_snr, ax_pow, ax_rng = _panels(fig)
        for ax, span, centre in ((ax_pow, 1.0, -89.26), (ax_rng, 1.0, 4.811)):
            lo, hi = ax.get_ylim()
            assert hi - lo == pytest.approx(span, rel=1e-9), ax.get_ylabel()
            assert 0.5 * (lo + hi) == pytest.approx(centre, abs=0.01 * span)
        lo, hi = ax_snr.get_ylim()            # the 10 dB threshold line is in view too
        assert lo < 10.0 and hi > 17.1 and hi - lo > 1.0
    finally:
        plt_close(fig)
    fig = study_figure(_study(ALT_SPEC, ALT_METRICS))
    try:
        lo, hi = _panels(fig)[2].get_ylim()
        assert lo < -105.8 and hi > -81.7 and hi - lo < 30.0      # autoscaled: 24.1 dB + 5 %
    finally:
        plt_close(fig)


# ------------------------------------------------------------------------------------ CLI
def test_cli_json_table_and_out(flat, tmp_path, capsys):
    _, _, mission = flat
    out = tmp_path / "study.nc"
    args = ["study", str(mission), "--vary", "platform.uav.altitude_m=100:1000:3",
            "--span-s", "1", "--tier", "link", "--no-progress"]
    assert main([*args, "--json", "--out", str(out)]) == 0
    recs = strict_json(capsys.readouterr().out)
    assert len(recs) == 3
    for rec in recs:
        assert set(rec) == JSON_KEYS | {"platform.uav.altitude_m"}
        assert isinstance(rec["shots"], int) and rec["shots"] == 20
        assert isinstance(rec["detected_shots"], int) and 0 <= rec["detected_shots"] <= 20
    assert [r["platform.uav.altitude_m"] for r in recs] == [100, 550, 1000]
    assert out.is_file()
    # the file exists: refused without --overwrite, before any run
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and len(err.strip().splitlines()) == 1
    assert main([*args, "--out", str(out), "--overwrite"]) == 0
    table = capsys.readouterr().out
    assert "platform.uav.altitude_m" in table and "SNR p50" in table
    assert len(table.strip().splitlines()) == 3 + 3
    # MISSION after --set
    assert main(["study", "--set", "survey.prf_hz=10", str(mission), "--vary",
                 "lsr.Po=0.002,0.004", "--span-s", "1", "--tier", "link", "--json",
                 "--no-progress"]) == 0
    recs = strict_json(capsys.readouterr().out)
    assert [r["lsr.Po"] for r in recs] == [0.002, 0.004] and recs[0]["shots"] == 10
    assert not leftovers(tmp_path)


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize("plot, out, words", [
    ("/proc/x.png", "s.nc", "--plot /proc/x.png: cannot write in /proc"),
    ("DIR/plot.png", "s.nc", "--plot DIR/plot.png: is a directory"),
    ("p.png", "DIR/s.nc", "--out DIR/s.nc: is a directory"),
    ("p.png", "/proc/s.nc", "--out /proc/s.nc: cannot write in /proc"),
])
def test_cli_unwritable_plot_or_out_refused_before_any_run(flat, tmp_path, capsys, monkeypatch,
                                                           plot, out, words):
    """--plot in /proc (which refuses new files, also to root, for whom os.access says yes),
    --plot or --out naming an existing directory (with --overwrite): one line, exit 2, before
    the first point runs; no file written."""
    from chirplidar.mission import runner

    _, _, mission = flat

    def never(*args, **kwargs):
        raise AssertionError("a point ran before --plot / --out were checked")

    monkeypatch.setattr(runner, "run_mission", never)
    (tmp_path / "DIR").mkdir()
    (tmp_path / "DIR" / "plot.png").mkdir()
    (tmp_path / "DIR" / "s.nc").mkdir()

    def at(name):
        return name if name.startswith("/") else str(tmp_path / name)

    argv = ["study", str(mission), "--vary", "platform.uav.altitude_m=100,200", "--span-s",
            "1", "--tier", "link", "--no-progress", "--plot", at(plot), "--out", at(out),
            "--overwrite"]
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert words.replace("DIR", str(tmp_path / "DIR")) in lines[0]
    assert "Traceback" not in captured.err and captured.out == ""
    assert not (tmp_path / "s.nc").exists() and not (tmp_path / "p.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DIR"]   # no probe file left


def test_cli_plot_that_cannot_be_saved_leaves_no_study_file(flat, tmp_path, capsys,
                                                            monkeypatch):
    """Saving the plot fails after every point has run (a full disk: OSError ENOSPC): the table
    is still printed, then one error line, exit 1, and no study file (the plot is drawn first)."""
    import errno

    from chirplidar.viz import study as viz_study

    _, _, mission = flat

    def full_disk(ds, path, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(viz_study, "plot_study", full_disk)
    out, png = tmp_path / "s.nc", tmp_path / "s.png"
    argv = ["study", str(mission), "--vary", "platform.uav.altitude_m=100,200", "--span-s",
            "1", "--tier", "link", "--no-progress", "--plot", str(png), "--out", str(out)]
    assert main(argv) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0] == (f"chirplidar study: error: --plot {png}: cannot save the plot (No "
                        f"space left on device); the study file {out} was not written")
    assert "platform.uav.altitude_m" in captured.out            # the table: results not lost
    assert not out.exists() and not png.exists() and not leftovers(tmp_path)
    assert not any(tmp_path.glob(".s.nc.*"))


@pytest.mark.parametrize("vary, extra, words", [
    (["platform.uav.altitud_m=100:1000:3"], [],
     "unknown key 'platform.uav.altitud_m' (did you mean: platform.uav.altitude_m,"),
    (["platform.uav.altitude_m=100:1000:1"], [], "N >= 2"),
    (["scene.terrain.flat.material=snow,slush"], [], "unknown material 'slush'"),
    (["lsr.Po=0.01,0.02", "survey.prf_hz=10,20", "platform.uav.speed_mps=10,20"], [],
     "at most 2 keys"),
    (["lsr.Po=0.01,0.02", "lsr.Po=0.03,0.04"], [], "given twice"),
    (["lsr.Po=0.01,0.02"], ["--span-s", "30"], "beyond the mission's stop"),
    (["lsr.Po=0.01,0.02"], ["--span-s", "-1"], "--span-s must be"),
    ([], [], "--vary"),
])
def test_cli_bad_input_exits_2_with_one_line(flat, tmp_path, capsys, vary, extra, words):
    _, _, mission = flat
    out = tmp_path / "bad.nc"
    argv = ["study", str(mission), *[a for v in vary for a in ("--vary", v)], *extra,
            "--tier", "link", "--no-progress", "--out", str(out), "--plot",
            str(tmp_path / "bad.png")]
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], captured.err
    assert "Traceback" not in captured.err and captured.out == ""
    assert not out.exists() and not (tmp_path / "bad.png").exists()
    assert not leftovers(tmp_path) and not any(tmp_path.glob(".bad.nc.*"))


def test_cli_plot_two_keys(flat, tmp_path, capsys):
    _, _, mission = flat
    png = tmp_path / "study.png"
    assert main(["study", str(mission), "--vary", "platform.uav.altitude_m=100:1000:3",
                 "--vary", "scene.terrain.flat.material=snow,blue_ice", "--span-s", "1",
                 "--tier", "link", "--plot", str(png), "--no-progress"]) == 0
    assert png.read_bytes()[:8] == PNG_MAGIC
    assert "wrote" in capsys.readouterr().err


# ----------------------------------------------------------------------------------- slow
@pytest.mark.slow
def test_streamed_metrics_of_a_whole_demo_run_equal_numpy(tmp_path):
    """The Greenland demo mission, whole (159 000 shots, more than the one-chunk budget keeps):
    the quantiles come from the radix select and equal numpy's on the whole file; the sums
    agree to rounding."""
    mission = Path(__file__).resolve().parents[1] / "missions" / "greenland_uav.toml"
    res = run_mission(mission, out=tmp_path / "demo.nc", tier="link")
    m = point_metrics(res.path, detection_threshold_db=10.0)
    ds = read_netcdf(res.path)
    det = ds["detected"].values.ravel()
    surface, ok = det != 2, det == 1
    assert 16 * np.count_nonzero(surface) > 20000 * 8 * 7    # beyond the in-memory budget
    snr = ds["snr_db"].values.ravel()[surface]
    snr = np.where(np.isfinite(snr), snr, -np.inf)
    assert m["median_snr_db"] == np.median(snr)
    assert m["snr_p10_db"] == np.percentile(snr, 10)
    assert m["snr_p90_db"] == np.percentile(snr, 90)
    pw = ds["received_power"].values.ravel()[surface]
    assert m["median_received_power_dbm"] == np.median(power_dbm(pw))
    assert m["detection_probability"] == np.count_nonzero(ok) / np.count_nonzero(surface)
    err = ds["range_error"].values.ravel()[ok]
    assert m["range_rms_m"] == pytest.approx(np.sqrt(np.mean(err ** 2)), rel=1e-9)
    dh = (ds["h_li"] - ds["h_li_true"]).values.ravel()[ok]
    assert m["height_precision_m"] == pytest.approx(np.std(dh, ddof=1), rel=1e-9)


@pytest.mark.slow
def test_workers_give_the_serial_study(flat):
    """--workers 2 (a local Dask cluster per point) gives the same study as a serial one:
    the same seed and chunk streams at every point."""
    _, _, mission = flat
    args = (mission, ["platform.uav.altitude_m=100,1000"])
    kw = {"overrides": ["survey.chunk_shots=10"], "span_s": 2.0, "tier": "link"}
    serial = run_study(*args, **kw)
    parallel = run_study(*args, workers=2, **kw)
    for name in serial.data_vars:
        np.testing.assert_array_equal(serial[name].values, parallel[name].values)
