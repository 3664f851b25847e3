"""No confident wrong answer: every implausible output carries a flag, in every tier, and the
numbers a tier cannot stand behind are null (JSON) / NaN (arrays) / the fill value (files).

Each case is built from shipped missions and ``--set`` style overrides, with a plausible control
shot that must carry no flag (so each check can fail). Reference values:

* Nyquist frequency = Fs / 2 (sampling theorem); the baseband tier's record holds the band up to
  the chirp's start frequency F1 + F0 (``tiers.baseband`` module docstring, "the band the beat is
  read in");
* the beat of a linear FM chirp at lag tau - tau_ref is kappa (tau - tau_ref), kappa = B / T_ramp;
  the chirps overlap (a tone exists) only for lags within a ramp of a whole period;
* a return a whole chirp period T beyond (or before) the reference reads the same beat as one
  inside [tau_ref, tau_ref + T): its range is ambiguous by c T / (2 n) (c the speed of light, n
  the group index); tau = 2 n R / c;
* saturation: the balanced pair's amplifier sees the differential optical power; for the 3 dB
  coupler (S = [[1, j], [j, 1]] / sqrt 2, excess loss T_c in power) it peaks at
  2 T_c sqrt(P_lo,pk P_sig,pk), P_pk = |a|_max^2 P_mean / <|a|^2> of the MZM field a(t): the rf
  tier's criterion against ``balanced.saturation_power_w``.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import write_flat_uav_mission

from chirplidar.api import simulate_shot
from chirplidar.cli import main
from chirplidar.config import load_mission
from chirplidar.mission.results import DETECTED_FLAG_MEANINGS, DETECTED_FLAG_VALUES, read_netcdf
from chirplidar.mission.runner import run_mission
from chirplidar.channel.lab import lab_budget
from chirplidar.transmitter import mzm_field
from chirplidar.units import SPEED_OF_LIGHT_M_S

ROOT = Path(__file__).resolve().parents[1]
CH5 = ROOT / "missions" / "thesis_ch5_bench.toml"
ICESAT_INSTRUMENT = ROOT / "missions" / "icesat2_instrument.toml"
TIERS = ("link", "baseband", "rf")
BEAT_KEYS = ("f_beat_hz", "d_rx", "d_lo", "d_hi", "d_error", "d_3dB")
RANGE_KEYS = ("d_rx", "d_lo", "d_hi", "d_error")
# 30 dB more received power than the field instrument's, at the optimum carrier phase (no
# fading): a UAV at a few km detects every shot with a surface in the beam.
LOUD = ["channel.extra_attenuation_db=-30", "channel.carrier_phase=optimal"]
TWO_BEAMS = 'pattern = "custom"\noff_nadir_deg = [0.0, 20.0]\nazimuth_deg = [90.0, 90.0]'


def _shot(overrides, tier, seed=1):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # the rf tier warns on saturation
        return simulate_shot(load_mission(CH5, list(overrides)), seed=seed, tier=tier)


def _json_shot(capsys, mission, *args):
    assert main(["shot", str(mission), "--json", *args]) == 0
    return json.loads(capsys.readouterr().out)


def _assert_plausible(r):
    """A normal shot: no flag, every Table 4.10 number and the beat finite."""
    assert r["flags"] == [], r["flags"]
    for key in BEAT_KEYS + ("SNR", "Crx", "d_res"):
        assert np.isfinite(r[key]), key


def _dst_at_lag(lag_s, extra=()):
    """channel.distance_m [m] of the CH5 bench whose delay is tau_ref + lag_s: tau = 2 n R / c."""
    cfg = load_mission(CH5, list(extra))
    return (cfg.system.reference_delay_s + lag_s) * SPEED_OF_LIGHT_M_S / (2 * cfg.channel.group_index)


# ------------------------------------------------------------------ 1. no LO, beat above Nyquist

@pytest.mark.parametrize("tier", ["link", "rf"])
def test_no_lo_reports_no_beat_or_range_in_the_shot_json(capsys, tier):
    rec = _json_shot(capsys, CH5, "--tier", tier, "--set", "COH.P_LO=0")
    assert "no_lo" in rec["flags"]
    for key in BEAT_KEYS + ("SNR", "Crx", "d_res"):
        assert rec[key] is None, key       # no beat, no range; SNR and Crx: zero power (-inf dB)
    assert rec["Psig"] is not None and rec["Navg"] is not None   # the budget and the noise stand
    ctl = _json_shot(capsys, CH5, "--tier", tier)
    assert "no_lo" not in ctl["flags"]
    assert all(ctl[k] is not None for k in BEAT_KEYS + ("SNR",))
    assert abs(ctl["d_error"]) < 1.0


@pytest.mark.parametrize("extra", [[], ["sys.CxMode=phase_diversity"]])
def test_no_lo_in_every_tier(extra):
    for tier in TIERS:
        r = _shot(extra + ["COH.P_LO=0"], tier)
        assert "no_lo" in r["flags"], tier
        assert all(np.isnan(r[k]) for k in BEAT_KEYS), tier
        assert r["SNR"] == -np.inf and r["Crx"] == -np.inf, tier
        _assert_plausible(_shot(extra, tier))


def test_no_chirp_drive_reports_no_beat_or_range_in_every_tier():
    """waveform.vpp_v = 0 (chrp.Vpp): no chirp on the modulator, so no beat (found by
    tests/test_bad_input.py: the link tier reported a 5.8 GHz beat and -118 km, flags [])."""
    for tier in TIERS:
        r = _shot(["chrp.Vpp=0"], tier)
        assert "no_chirp" in r["flags"], tier
        assert all(np.isnan(r[k]) for k in BEAT_KEYS), tier
        assert r["SNR"] == -np.inf, tier


def test_no_lo_heterodyne_link():
    het = ["sys.CxMode=het", "mzm.Vdc=1.0"]
    r = _shot(het + ["COH.P_LO=0"], "link")
    assert "no_lo" in r["flags"] and np.isnan(r["d_rx"]) and r["SNR"] == -np.inf
    assert "no_lo" not in _shot(het, "link")["flags"]


@pytest.mark.parametrize("tier", ["link", "rf"])
def test_beat_above_nyquist_is_flagged_and_not_read(tier):
    # Fs = 800 MS/s (Nyquist 400 MHz) still holds the 100-300 MHz chirp; a lag of 90 us of the
    # 106 us period (the next chirp overlaps by 16 us) predicts kappa x 90 us = 450 MHz.
    fs = ["sims.Fs=800e6"]
    cfg = load_mission(CH5, fs + [f"atm.dst={_dst_at_lag(90e-6)}"])
    bud = lab_budget(cfg)
    nyquist = cfg.simulation.sample_rate_hz / 2
    assert bud.f_beat_hz > nyquist and bud.lag_s > bud.train.period_s - bud.train.rise_s
    r = _shot(fs + [f"atm.dst={_dst_at_lag(90e-6)}"], tier)
    assert "beat_above_nyquist" in r["flags"] and "beat_out_of_band" in r["flags"]
    assert all(np.isnan(r[k]) for k in BEAT_KEYS)
    if tier == "rf":   # read off the spectrum: the peak found is not the beat
        assert np.isnan(r["SNR"]) and np.isnan(r["Crx"])
    _assert_plausible(_shot(fs, tier))


def test_beat_above_the_baseband_band_is_flagged_and_not_read():
    # 13.5 km: kappa x 25.3 us = 126 MHz, above the baseband record's band (F1 + F0 = 100 MHz).
    cfg = load_mission(CH5, ["atm.dst=13500"])
    bud = lab_budget(cfg)
    assert bud.f_beat_hz > bud.train.f_start_hz
    r = _shot(["atm.dst=13500"], "baseband")
    assert "beat_above_nyquist" in r["flags"]
    assert all(np.isnan(r[k]) for k in BEAT_KEYS) and np.isnan(r["SNR"])
    # The rf tier samples at 3 GS/s: the same beat is read there, with no flag.
    _assert_plausible(_shot(["atm.dst=13500"], "rf"))
    _assert_plausible(_shot([], "baseband"))


def test_no_chirp_overlap_reads_no_signal_in_every_tier():
    # A lag of 53 us lies between the 40 us ramp and the period minus the ramp (66 us): no tone.
    over = [f"atm.dst={_dst_at_lag(53e-6)}"]
    for tier in TIERS:
        r = _shot(over, tier)
        assert "no_overlap" in r["flags"], tier
        assert all(np.isnan(r[k]) for k in BEAT_KEYS) and r["SNR"] == -np.inf, tier


# ------------------------------------------------------------------------------ 2. saturation

def _saturation_psig_dbm(cfg):
    """Received power [dBm] at which the differential optical power peak reaches
    balanced.saturation_power_w (module docstring): P_sig = (P_sat <a^2> / (2 T_c a_pk^2))^2 / P_lo,
    a_pk from the MZM field sampled over one chirp."""
    bud = lab_budget(cfg)
    train = bud.train
    t = np.linspace(0.0, train.period_s, 400_001)
    a_pk = float(np.max(np.abs(mzm_field(cfg.modulator.bias_v + train.voltage(t), cfg.modulator.v_pi_v))))
    t_c = 10 ** (-cfg.balanced.coupler_excess_loss_db / 10)
    b = cfg.balanced
    p = (b.saturation_power_w * bud.mzm_mean_transmission / (2 * t_c * a_pk ** 2)) ** 2 / b.lo_power_w
    return 10 * np.log10(p / 1e-3)


@pytest.mark.parametrize("margin_db", [1.0, -1.0])
def test_link_flags_saturation_as_the_other_tiers_do(margin_db):
    cfg = load_mission(CH5)
    p0 = _shot([], "link")["Psig"]
    target = _saturation_psig_dbm(cfg) + margin_db
    over = [f"atm.Pattn={cfg.channel.extra_attenuation_db + p0 - target}"]
    for tier in TIERS:
        r = _shot(over, tier)
        assert abs(r["Psig"] - target) < 1e-6
        assert ("saturation" in r["flags"]) == (margin_db > 0), (tier, r["flags"])


# ------------------------------------------------------------------------------ 3. zero return

def test_zero_return_reports_no_beat_or_range_in_every_tier(capsys):
    for tier in TIERS:
        r = _shot(["atm.Pattn=inf"], tier)
        assert "no_return" in r["flags"], tier
        assert all(np.isnan(r[k]) for k in BEAT_KEYS), tier
        assert r["Psig"] == r["SNR"] == r["Crx"] == -np.inf, tier
    rec = _json_shot(capsys, CH5, "--tier", "link", "--set", "atm.Pattn=inf")
    assert rec["flags"] == ["no_return"] and all(rec[k] is None for k in BEAT_KEYS)


@pytest.fixture(scope="module")
def miss_mission(tmp_path_factory):
    """Beam 1 looks 55 deg off nadir towards +x from 2.5 km: it meets the ground 3.6 km ahead,
    beyond the 4 km scene's edge (the line starts 800 m before its centre): no surface."""
    tmp = tmp_path_factory.mktemp("miss")
    return write_flat_uav_mission(tmp, "miss", altitude_m=2500.0, prf=20.0, stop=0.5, subrays=3,
                                  beams='pattern = "custom"\noff_nadir_deg = [0.0, 55.0]\n'
                                        'azimuth_deg = [90.0, 90.0]')


@pytest.mark.parametrize("tier", TIERS)
def test_zero_return_survey_writes_fill_values(miss_mission, tmp_path, tier):
    res = run_mission(miss_mission, overrides=[f"survey.tier={tier}", "processing.averages=2",
                                               *LOUD],
                      out=tmp_path / f"{tier}.nc")
    ds = read_netcdf(res.path)
    det = ds["detected"].values
    assert np.all(det[1] == 2) and np.all(det[0] == 1)
    for name in ("range_measured", "range_error", "beat_frequency", "beat_width", "snr_db",
                 "h_li", "received_power"):
        assert np.all(np.isnan(ds[name].values[1])), name
        assert np.all(np.isfinite(ds[name].values[0])), name


# ----------------------------------------------------- 4. no sentinel SNR in satellite survey files

@pytest.fixture(scope="module")
def satellite_without_window(tmp_path_factory):
    """icesat2_instrument.toml flown at 600 km with no range window: the reference delay is the
    instrument's own (``system.reference_delay_s``), as without a range gate."""
    tmp = tmp_path_factory.mktemp("sat")
    text = ICESAT_INSTRUMENT.read_text()
    lines = [ln for ln in text.splitlines() if not ln.startswith("range_window_m")]
    assert len(lines) == len(text.splitlines()) - 1
    text = "\n".join(lines).replace('extends = "thesis_field_instrument.toml"',
                                    f'extends = "{ROOT / "missions" / "thesis_field_instrument.toml"}"')
    text = text.replace('file = "../scenes/antarctic_margin.toml"',
                        f'file = "{ROOT / "scenes" / "antarctic_margin.toml"}"')
    (tmp / "instrument.toml").write_text(text)
    mission = tmp / "sat600.toml"
    mission.write_text('extends = "instrument.toml"\nseed = 496\n[platform.orbit]\n'
                       'altitude_m = 600e3\neccentricity = 0.0\ninclination_deg = 92.0\n'
                       'pass_direction = "descending"\n[survey]\nstart_s = -0.3\nstop_s = 0.3\n'
                       'epoch_utc = "2026-11-01T00:00:00Z"\n')
    return mission


def _sat_run(mission, tmp_path, ref_s):
    res = run_mission(mission, overrides=[f"system.reference_delay_s={ref_s}"],
                      out=tmp_path / f"sat_{ref_s}.nc")
    ds = read_netcdf(res.path)
    n = load_mission(mission).channel.group_index
    lag = 2 * n * ds["range_true"].values / SPEED_OF_LIGHT_M_S - ref_s     # tau - tau_ref
    return ds, res.summary, lag


def test_satellite_without_overlap_writes_fill_snr_not_a_sentinel(satellite_without_window,
                                                                  tmp_path):
    # 600 km: tau ~ 4.0 ms; tau_ref = 3.95 ms puts every return ~50 us behind the reference,
    # between the 37.7 us ramp and the 100 us period minus the ramp: no chirp overlap.
    ds, summary, lag = _sat_run(satellite_without_window, tmp_path, 3.95e-3)
    rise = lab_budget(load_mission(satellite_without_window)).train.rise_s
    assert np.all((lag > rise) & (lag < 100e-6 - rise))
    det = ds["detected"].values
    assert np.all(det == 3) and summary["outside_range_gate"] == det.size
    assert np.all(np.isnan(ds["snr_db"].values))       # the fill value, never -300 dB


def test_satellite_straddling_the_overlap_edge(satellite_without_window, tmp_path):
    # tau_ref = 3.9607 ms: lags from ~37.2 to ~38.3 us, across the 37.7 us ramp: shots with
    # overlap have an SNR, shots without are flagged and have none.
    ds, _, lag = _sat_run(satellite_without_window, tmp_path, 3.9607e-3)
    rise = lab_budget(load_mission(satellite_without_window)).train.rise_s
    det, snr = ds["detected"].values, ds["snr_db"].values
    inside, beyond = lag < rise - 0.02e-6, lag > rise + 0.02e-6
    assert np.any(inside) and np.any(beyond)
    assert np.all(det[beyond] == 3) and np.all(np.isnan(snr[det == 3]))
    assert np.all(np.isfinite(snr[inside]))
    # The tone's SNR falls with the overlap (T_ov = ramp - lag) as T_ov^2: never a fixed floor.
    early = snr[lag < rise - 0.4e-6]
    late = snr[(lag > rise - 0.15e-6) & inside]
    assert np.median(early) > np.median(late) + 3.0


# ------------------------------------------------------------------- 5. ambiguous by a period

@pytest.mark.parametrize("tier", TIERS)
def test_bench_return_a_period_beyond_the_reference_is_range_ambiguous(tier):
    cfg = load_mission(CH5)
    bud = lab_budget(cfg)
    period_m = SPEED_OF_LIGHT_M_S * bud.train.period_s / (2 * cfg.channel.group_index)  # cT/2n
    far = [f"atm.dst={cfg.channel.distance_m + period_m}"]
    assert lab_budget(load_mission(CH5, far)).lag_s == pytest.approx(bud.lag_s, abs=1e-12)
    r = _shot(far, tier)
    assert "range_ambiguous" in r["flags"]
    assert all(np.isnan(r[k]) for k in RANGE_KEYS)
    # The beat itself is measured: that of the lag within the period.
    assert r["f_beat_hz"] == pytest.approx(bud.f_beat_hz, rel=1e-4)
    assert np.isfinite(r["SNR"])
    _assert_plausible(_shot([], tier))


@pytest.fixture(scope="module")
def uav_1000(tmp_path_factory):
    """A UAV line 1000 m above flat snow at 100 m (900 m nadir range, tau ~ 6.0 us), two beams."""
    tmp = tmp_path_factory.mktemp("amb")
    return write_flat_uav_mission(tmp, "amb", altitude_m=1000.0, beams=TWO_BEAMS, prf=20.0,
                                  stop=1.0, subrays=3)



@pytest.mark.parametrize("tier", ["link", "rf"])
def test_survey_return_before_the_reference_is_range_ambiguous(uav_1000, tmp_path, tier):
    # tau_ref = 10 us > tau ~ 6-6.4 us: the lag wraps to ~102 us of the 106 us period, where the
    # chirps overlap again; its beat lies in the processed band (below Nyquist, 1.5 GHz) and
    # was read as a range c T / 2n too far. (The baseband tier's band, F1 + F0 = 100 MHz, does
    # not hold kappa x 102 us: there it is outside the range gate, 3.)
    over = [f"survey.tier={tier}", "processing.averages=2", "survey.stop_s=0.1" if tier == "rf"
            else "survey.stop_s=1.0"]
    res = run_mission(uav_1000, overrides=over + LOUD + ["system.reference_delay_s=10e-6"],
                      out=tmp_path / "amb.nc")
    ds = read_netcdf(res.path)
    det = ds["detected"].values
    assert np.all(det == 5)
    assert res.summary["detected"] == 0
    assert np.all(np.isnan(ds["range_measured"].values)) and np.all(np.isnan(ds["h_li"].values))
    assert ds["detected"].attrs["flag_meanings"].split()[5] == "range_ambiguous"
    assert list(ds["detected"].attrs["flag_values"]) == [0, 1, 2, 3, 4, 5]
    ctl = run_mission(uav_1000, overrides=over + LOUD + ["system.reference_delay_s=0"],
                      out=tmp_path / "ctl.nc")
    cds = read_netcdf(ctl.path)
    assert np.all(cds["detected"].values == 1)
    assert np.max(np.abs(cds["range_error"].values)) < 1.0


def test_survey_shot_json_flags_range_ambiguous(uav_1000, capsys):
    rec = _json_shot(capsys, uav_1000, "--tier", "link", "--set", *LOUD,
                     "system.reference_delay_s=10e-6")
    assert "range_ambiguous" in rec["flags"] and all(rec[k] is None for k in RANGE_KEYS)
    ctl = _json_shot(capsys, uav_1000, "--tier", "link", "--set", *LOUD)
    assert ctl["flags"] == [] and abs(ctl["d_error"]) < 1.0


def test_detected_codes_schema():
    assert DETECTED_FLAG_VALUES.tolist() == [0, 1, 2, 3, 4, 5]
    assert DETECTED_FLAG_MEANINGS.split() == [
        "below_detection_threshold", "detected", "no_surface_in_beam", "outside_range_gate",
        "doppler_displaced", "range_ambiguous"]


# ----------------------------------------- 6. out of band / no overlap: 3, not below threshold

@pytest.mark.parametrize("tier", TIERS)
def test_out_of_band_survey_returns_are_outside_the_range_gate(uav_1000, tmp_path, tier):
    # Beats kappa x 6.0-6.4 us ~ 30-32 MHz, above a 20 MHz processed band.
    over = [f"survey.tier={tier}", "processing.averages=2", "survey.stop_s=0.1", *LOUD]
    res = run_mission(uav_1000, overrides=over + ["processing.peak_search_max_hz=20e6"],
                      out=tmp_path / "oob.nc")
    ds = read_netcdf(res.path)
    assert np.all(ds["detected"].values == 3)
    assert np.all(np.isnan(ds["range_measured"].values))
    ctl = run_mission(uav_1000, overrides=over, out=tmp_path / "ctl.nc")
    assert np.all(read_netcdf(ctl.path)["detected"].values == 1)


@pytest.mark.parametrize("tier", TIERS)
def test_no_overlap_survey_returns_are_outside_the_range_gate(tmp_path, tier):
    # 7 km above flat snow: tau ~ 46.7 us (tau_ref = 0), between the 40 us ramp and the period
    # minus the ramp (66 us): no chirp overlap, and not ambiguous (0 <= tau - tau_ref < T).
    mission = write_flat_uav_mission(tmp_path, "high", altitude_m=7100.0,
                                     beams='pattern = "nadir"', prf=20.0, stop=0.1, subrays=3)
    over = [f"survey.tier={tier}", "processing.averages=2"]
    res = run_mission(mission, overrides=over, out=tmp_path / "high.nc")
    ds = read_netcdf(res.path)
    tau = 2 * 1.00027 * ds["range_true"].values / SPEED_OF_LIGHT_M_S
    assert np.all((tau > 40.1e-6) & (tau < 65.9e-6))
    assert np.all(ds["detected"].values == 3)
    assert np.all(np.isnan(ds["snr_db"].values)) and np.all(np.isnan(ds["range_measured"].values))
