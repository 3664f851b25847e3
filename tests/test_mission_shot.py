"""``shot`` and ``sweep`` on a survey mission: one shot of the survey at the mission's geometry
(``chirplidar.mission.shot``), never the instrument file's lab-bench channel."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import ROOT, TWO_BEAMS, write_scene, write_uav_mission

from chirplidar.api import simulate_mission_shot
from chirplidar.cli import main
from chirplidar.config import load_mission
from chirplidar.mission import measure, preflight, runner, survey
from chirplidar.mission.results import read_netcdf
from chirplidar.mission.shot import simulate_mission_shot as raw_mission_shot
from chirplidar.units import db_to_ratio

GREENLAND = str(ROOT / "missions" / "greenland_uav.toml")
BENCH_SPOOL_M = 11350.0   # channel.distance_m of the lab bench (thesis_bench.toml), 11.35 km
# A short rf stretch of the Greenland demo (4 shots at t = 0, 0.05, 0.1, 0.15 s), one chirp each.
RF_SHORT = ["survey.stop_s=0.2", "survey.prf_hz=20", "processing.averages=1"]


def _json(text):
    def bad(token):
        raise ValueError(f"non-JSON constant {token}")
    return json.loads(text, parse_constant=bad)


def _flat_mission(tmp_path, name="flat", *, beams='pattern = "nadir"', stop="2.0",
                  altitude=300.0):
    """UAV ``altitude`` above flat snow (100 m high) in a 4 km scene with no atmosphere and no
    effects, flying along x from 800 m before the scene centre."""
    scene = write_scene(tmp_path, name, 'flat height_m = 100.0\nmaterial = "snow"',
                        stem=f"{name}_scene")
    return write_uav_mission(tmp_path, scene, name, altitude=altitude, mode="above_ground",
                             beams=beams, stop=stop, prf=20.0)


# ------------------------------------------------------------------------------ the demo mission

def test_greenland_shot_is_at_flight_height_not_the_bench_spool(capsys):
    assert main(["shot", GREENLAND, "--tier", "link", "--json"]) == 0
    rec = _json(capsys.readouterr().out)
    assert rec["mission_geometry"] is True and rec["tier"] == "link"
    assert rec["t_s"] == 0.0 and rec["beam"] == 0 and rec["surface"] == "blue_ice"
    # The mission flies 120 m above the ground (platform.uav.altitude_m, above_ground) with a
    # nadir beam: the range is the platform's height over the scene's ground under the footprint.
    cfg, scene, _ = preflight.prepare(GREENLAND)
    assert cfg.platform.uav.altitude_m == 120.0
    ground = float(scene.ground_height_m(np.array([rec["x_m"]]), np.array([rec["y_m"]]))[0])
    assert rec["platform_height_m"] - ground == pytest.approx(120.0, abs=0.05)
    assert rec["range_m"] == pytest.approx(120.0, abs=2.0)
    assert rec["d_rx"] == pytest.approx(rec["range_m"], abs=2.0)
    assert abs(rec["d_rx"] - BENCH_SPOOL_M) > 10_000
    assert rec["SNR"] > 10.0 and rec["Psig"] > -100.0   # the bench spool read -41 dB, -133 dBm


def test_greenland_rf_shot_is_at_flight_height(capsys):
    assert main(["shot", GREENLAND, "--set", "processing.averages=1", "--json"]) == 0
    rec = _json(capsys.readouterr().out)
    assert rec["mission_geometry"] is True and rec["tier"] == "rf"
    assert rec["range_m"] == pytest.approx(120.0, abs=2.0)
    assert rec["d_rx"] == pytest.approx(rec["range_m"], abs=2.0)   # rf: the beat's range


def test_greenland_text_output_names_the_survey_shot(capsys):
    assert main(["shot", GREENLAND, "--tier", "link", "--at-s", "30", "--beam", "0"]) == 0
    out = capsys.readouterr().out
    assert "survey shot t = 30 s (shot 3000), beam 0: range 120" in out


def test_rf_shot_is_the_runs_rf_shot():
    """The shot path and ``measure_rf`` run the same function for the shot's configuration and
    echoes (``measure.rf_shot_setup``) on the same stream: identical results."""
    cfg, scene, plan = preflight.prepare(GREENLAND, overrides=RF_SHORT)
    seq = survey.chunk_seeds(cfg.seed, plan.n_chunks)[0]
    geom = survey.chunk_geometry(plan, scene, cfg, plan.chunk_times(0), seq,
                                 cfg.survey.subrays_per_beam)
    run = measure.measure_rf(cfg, scene, geom, seq)
    for k in (0, 2):
        shot = raw_mission_shot(GREENLAND, tier="rf", at_s=float(plan.t_s[k]), overrides=RF_SHORT)
        assert shot["geometry"]["shot_index"] == k
        assert float(db_to_ratio(shot["SNR"][0])) == pytest.approx(
            float(db_to_ratio(run["snr_db"][k, 0])), rel=1e-12)
        assert shot["f_beat_hz"][0] == run["beat_frequency"][k, 0]
        assert shot["d_rx"][0] == run["range_measured"][k, 0]


def test_measure_rf_outputs_unchanged_by_the_refactor():
    """``measure_rf`` of the short stretch's chunk, against values recorded by running the code
    before the per-shot set-up moved into ``measure.rf_shot_setup`` (git HEAD 6e814b3's
    ``mission/measure.py``, same call; float64 reprs). Exact on the recording machine; a fresh
    install's numpy/scipy round differently in the last bits, and issue 19's geometry (grid
    axes in closed form, one pyproj pipeline per conversion) moves ranges by < 4 nm, hence
    rtol 1e-8."""
    before = {
        "snr_db": [11.385000516712358, 10.139941709483368, 11.034932497008533, 13.314175778847199],
        "range_measured": [120.06877137370203, 120.27916859180908, 120.18651676009112,
                           119.93661513816048],
        "beat_frequency": [4006128.4510077564, 4013148.413582772, 4010057.0590628856,
                           4001719.020902627],
        "beat_width": [22949.31619976435, 10530.914008178219, 20689.67235172924,
                       22318.032979507458],
        "received_power": [1.804609465823287e-12, 1.8580745572661566e-12,
                           1.8580718983544638e-12, 1.8580747534289733e-12],
    }
    cfg, scene, plan = preflight.prepare(GREENLAND, overrides=RF_SHORT)
    seq = survey.chunk_seeds(cfg.seed, plan.n_chunks)[0]
    geom = survey.chunk_geometry(plan, scene, cfg, plan.chunk_times(0), seq,
                                 cfg.survey.subrays_per_beam)
    out = measure.measure_rf(cfg, scene, geom, seq)
    for key, values in before.items():
        np.testing.assert_allclose(out[key][:, 0], values, rtol=1e-8, atol=0, err_msg=key)
    assert np.array_equal(out["detected"][:, 0], [1, 1, 1, 1])


# ------------------------------------------------------------------------------ flat snow

def test_altitude_sweep_is_lambertian_on_flat_snow(tmp_path, capsys):
    mission = _flat_mission(tmp_path)
    code = main(["sweep", str(mission), "--vary", "platform.uav.altitude_m", "--start", "100",
                 "--stop", "1000", "--n", "4", "--scale", "log", "--tier", "link", "--json",
                 "--no-progress"])
    assert code == 0
    recs = _json(capsys.readouterr().out)
    alt = np.array([r["x"] for r in recs])
    rng = np.array([r["range_m"] for r in recs])
    psig = np.array([r["Psig"] for r in recs])
    assert all(r["mission_geometry"] and r["surface"] == "snow" for r in recs)
    # Nadir over flat ground, altitude above ground: the range is the altitude.
    np.testing.assert_allclose(rng, alt, atol=0.01)
    # Lambertian return (target.lambertian_power_fraction): P_r = P_t rho T A cos(theta) /
    # (pi R^2): -20 dB per decade of range.
    slope = np.diff(psig) / np.diff(np.log10(rng))
    np.testing.assert_allclose(slope, -20.0, atol=0.5)
    # Absolute value. Factors: P_t = the transmitted power (Ptx); rho = the scene's snow
    # reflectivity at the laser wavelength; T = T_opt^2 (channel.optical_transmission, out and
    # back) x the atmosphere's round trip (1: extinction 0) x channel.extra_attenuation_db (0 dB
    # in flight); A = pi D^2 / 4 (channel.telescope_diameter_m); cos(theta) = 1 (nadir, flat);
    # the footprint's sub-ray weights sum to 1 and all hit; no effects (no speckle).
    cfg, scene, _ = preflight.prepare(mission)
    ch = cfg.channel
    assert ch.extra_attenuation_db == 0.0
    rho = scene.material_reflectivity(cfg.laser.wavelength_m)[
        scene.terrain.material_names.index("snow")]
    area = 0.25 * math.pi * ch.telescope_diameter_m ** 2
    ptx_w = 1e-3 * 10 ** (np.array([r["Ptx"] for r in recs]) / 10)
    closed = ptx_w * rho * ch.optical_transmission ** 2 * area / (math.pi * rng ** 2)
    np.testing.assert_allclose(psig, 10 * np.log10(closed / 1e-3), atol=0.5)


def test_link_shot_equals_the_runs_shot(tmp_path):
    """Psig and SNR of a link shot against a ``chirplidar run`` of the same mission at that time
    and beam. The run multiplies each shot's SNR by its own carrier-phase fading draw (random
    phase), which one call of the tier does not reproduce: with ``channel.carrier_phase =
    "optimal"`` and no speckle both are deterministic, so the SNRs agree to the run's node-table
    interpolation (< 0.05 dB, ``measure`` module docstring) and Psig to rounding."""
    mission = _flat_mission(tmp_path, "agree", beams=TWO_BEAMS)
    over = ["channel.carrier_phase=optimal"]
    res = runner.run_mission(mission, overrides=over, out=tmp_path / "agree.nc")
    ds = read_netcdf(res.path)
    for at_s, beam in ((0.5, 0), (1.25, 1)):
        shot = simulate_mission_shot(mission, overrides=over, tier="link", at_s=at_s, beam=beam)
        assert shot["t_s"] == at_s and shot["beam"] == beam
        traj = int(np.flatnonzero(ds["beam"].values == beam)[0])
        obs = int(np.flatnonzero(np.isclose(ds["delta_time"].values[traj], at_s))[0])
        p_run = float(ds["received_power"].values[traj, obs])
        assert shot["Psig"] == pytest.approx(10 * math.log10(p_run / 1e-3), abs=1e-6)
        assert shot["SNR"] == pytest.approx(float(ds["snr_db"].values[traj, obs]), abs=0.05)
        assert shot["range_m"] == pytest.approx(float(ds["range_true"].values[traj, obs]),
                                                abs=1e-6)
    # beam 1 is 20 deg off nadir: the range grows as 1 / cos(20 deg).
    assert shot["range_m"] == pytest.approx(300.0 / math.cos(math.radians(20.0)), rel=1e-3)


# ------------------------------------------------------------------------------ bad input

@pytest.mark.parametrize("args, words", [
    (["--at-s", "1e6"], ["--at-s", "outside the survey span"]),
    (["--at-s", "-5"], ["--at-s", "outside the survey span"]),
    (["--beam", "3"], ["--beam 3", "1 beam"]),
])
def test_bad_shot_choice_exits_2_with_one_line(tmp_path, capsys, args, words):
    mission = _flat_mission(tmp_path)
    assert main(["shot", str(mission), "--tier", "link", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert all(w in err for w in words), err


def test_no_surface_under_the_beam_exits_2(tmp_path, capsys):
    # Beam 1 looks 55 deg off nadir towards +x from 2.5 km: it would meet the ground 3.6 km
    # ahead, beyond the 4 km scene's edge (the platform starts 800 m before its centre).
    mission = _flat_mission(tmp_path, "miss", altitude=2500.0, beams='pattern = "custom"\n'
                            'off_nadir_deg = [0.0, 55.0]\nazimuth_deg = [90.0, 90.0]')
    assert main(["shot", str(mission), "--tier", "link", "--at-s", "0", "--beam", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no surface" in err and "beam 1" in err


def test_sweep_of_unknown_key_and_bench_options(tmp_path, capsys):
    mission = _flat_mission(tmp_path)
    assert main(["sweep", str(mission), "--vary", "platform.uav.altitude_mm", "--start", "100",
                 "--stop", "200", "--n", "2", "--tier", "link", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "altitude_mm" in err and "Traceback" not in err
    # --at-s and --beam pick a survey shot: refused on a lab-bench mission.
    bench = str(ROOT / "missions" / "thesis_bench.toml")
    assert main(["shot", bench, "--tier", "link", "--at-s", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "[survey]" in err


def test_bench_mission_shot_is_unchanged(capsys):
    bench = str(ROOT / "missions" / "thesis_bench.toml")
    assert load_mission(bench).survey is None
    assert main(["shot", bench, "--tier", "link", "--json", "--seed", "3"]) == 0
    rec = _json(capsys.readouterr().out)
    assert "mission_geometry" not in rec and "range_m" not in rec
