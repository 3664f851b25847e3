"""Accuracy-versus-time study (analysis.accuracy), its plot, the tiers timing and the screen knob.

Fast settings only (a few shots, a few knobs); no assertion on measured times.
"""

from __future__ import annotations

import csv
import math
import re

import numpy as np
import pytest

from chirplidar import load_mission
from chirplidar.analysis.accuracy import (COLUMNS, FAMILIES, HEX_COUNTS, STUDIES, accuracy_study,
                                          markdown_table, pattn_for_snr, slope_footprint_echoes,
                                          write_outputs)
from chirplidar.analysis.accuracy_pulsed import PULSED_FAMILIES
from chirplidar.benchmarks.timing import bench_tiers
from chirplidar.cli import main
from chirplidar.config import ConfigError, config_with

from conftest import BENCH, CH5, GLAS_BENCH, apd_circuit_variance

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NUMERIC = [c for c in COLUMNS if c not in ("study", "family", "tier", "setting", "knob", "value",
                                            "reference", "flags")]
# One SNR point, two processing knobs of the rf tier, the baseband and link tiers: ~1 s.
TINY = dict(snr_db=(30.0,), shots=4, batch=2,
            families=("peak_method", "zero_pad", "baseband_rate", "link"),
            peak_methods=("parabolic",), zero_pad_factors=(2,), baseband_rates_hz=(None,))


@pytest.fixture(scope="module")
def tiny_rows():
    return accuracy_study(CH5, **TINY)


def test_study_rows_have_the_columns_and_finite_values(tiny_rows):
    assert [r["setting"] for r in tiny_rows] == [
        "rf ref (3 GHz, dtft, zp1)", "peak parabolic", "zero pad x2", "baseband (default rate)",
        "link"]
    for r in tiny_rows:
        assert tuple(r) == COLUMNS
        for c in NUMERIC:
            assert isinstance(r[c], (int, float)) and math.isfinite(r[c]), (r["setting"], c)
        assert r["shots"] == 4 and r["s_per_shot"] > 0 and r["range_rms_m"] > 0
        assert abs(r["snr_target_db"] - 30.0) < 1e-9
    assert {r["tier"] for r in tiny_rows} == {"rf", "baseband", "link"}


def test_reference_row_has_zero_errors_and_others_are_relative_to_it(tiny_rows):
    ref = tiny_rows[0]
    assert ref["reference"] and sum(r["reference"] for r in tiny_rows) == 1
    assert ref["snr_error_db"] == 0.0 and ref["range_rms_diff_m"] == 0.0
    assert ref["snr_std_error_db"] == 0.0 and ref["cost_vs_reference"] == 1.0
    for r in tiny_rows[1:]:
        assert r["snr_error_db"] == pytest.approx(r["snr_mean_db"] - ref["snr_mean_db"])
        assert r["range_rms_diff_m"] == pytest.approx(r["range_rms_m"] - ref["range_rms_m"])
    # Zero padding only interpolates the same spectrum that the dtft peak already reads exactly:
    # the same shots (same seeds, same noise) give the same SNR to a small fraction of a dB.
    zp = next(r for r in tiny_rows if r["family"] == "zero_pad")
    assert abs(zp["snr_error_db"]) < 0.05
    # The SNR points are placed with the link tier: it reads the target.
    link = next(r for r in tiny_rows if r["tier"] == "link")
    assert link["snr_mean_db"] == pytest.approx(30.0, abs=0.01)


def test_outputs_are_written(tiny_rows, tmp_path):
    paths = write_outputs(tiny_rows, tmp_path / "out", header="# test")
    assert set(paths) == {"csv", "md", "png"}
    png = paths["png"]
    assert png.name == "accuracy_vs_time.png" and png.read_bytes()[:8] == PNG_MAGIC
    with paths["csv"].open() as fh:
        got = list(csv.DictReader(fh))
    assert tuple(got[0]) == COLUMNS and len(got) == len(tiny_rows)
    assert float(got[0]["snr_error_db"]) == 0.0
    md = paths["md"].read_text()
    assert md.startswith("# test") and md.count("\n| 30 dB |") == len(tiny_rows)
    assert markdown_table(tiny_rows) in md


def test_footprint_and_screen_studies_run_small(tmp_path):
    rows = accuracy_study(CH5, snr_db=(30.0,), shots=2, batch=2, families=("sub_rays", "screen"),
                          sub_rays=(1,), sub_rays_reference=3, screen_pixels=(16,),
                          screen_reference=24, turbulence_shots=2)
    studies = [(r["study"], r["tier"], r["value"], r["reference"]) for r in rows]
    assert studies[0] == ("point target", "rf", "mission", True)   # the reference always runs
    assert ("footprint", "rf", "3", True) in studies and ("footprint", "baseband", "1", False) in studies
    assert ("turbulence", "rf", "24", True) in studies and ("turbulence", "link", "16", False) in studies
    for r in rows:
        assert math.isfinite(r["snr_mean_db"]) and math.isfinite(r["range_rms_m"])
        if r["reference"]:
            assert r["snr_error_db"] == 0.0
    paths = write_outputs(rows, tmp_path)
    assert paths["png"].read_bytes()[:8] == PNG_MAGIC


def test_footprint_echoes_are_centred_gaussian_samples():
    cfg = load_mission(CH5)
    for k in (1, 3, 7, 19, 37):
        off, w = slope_footprint_echoes(cfg, k, 10.0)
        assert off.shape == w.shape == (k,)
        assert w.sum() == pytest.approx(1.0) and np.all(w > 0)
        assert abs(np.sum(w * off)) < 1e-15                      # mean delay = the centre's
    off0, _ = slope_footprint_echoes(cfg, 19, 0.0)
    assert np.all(off0 == 0.0)                                   # a flat footprint: one range
    _, w7 = slope_footprint_echoes(cfg, 7, 10.0)
    assert 0.2 < w7[0] < 0.6                                     # the centre keeps a fair share
    assert HEX_COUNTS[:4] == (1, 7, 19, 37)


def test_pattn_for_snr_places_the_link_snr():
    cfg = load_mission(CH5)
    p = pattn_for_snr(cfg, 16.0)
    assert 70 < p < 90
    from chirplidar.channel import simulate_lab

    snr = simulate_lab(config_with(cfg, {"atm.Pattn": p}), "link", np.random.default_rng(0))["SNR"][0]
    assert snr == pytest.approx(16.0, abs=1e-2)


@pytest.mark.parametrize("kwargs, match", [
    (dict(snr_db=()), "snr_db"),
    (dict(snr_db=(10.0, float("nan"))), "snr_db"),
    (dict(snr_db=(10.0, 10.0)), "twice"),
    (dict(shots=1), "shots"),
    (dict(batch=0), "batch"),
    (dict(families=("nonsense",)), "families"),
    (dict(sample_rates_hz=(5e8,)), "chirp top"),
    (dict(upsample_factors=(0,)), "upsample_factors"),
    (dict(peak_methods=("cubic",)), "peak_methods"),
    (dict(zero_pad_factors=(1.5,)), "zero_pad_factors"),
    (dict(baseband_rates_hz=(-1.0,)), "baseband_rates_hz"),
    (dict(sub_rays=(5,)), "hexagonal"),
    (dict(sub_rays=(1, 37), sub_rays_reference=19), "sub_rays_reference"),
    (dict(slope_deg=95.0), "slope_deg"),
    (dict(screen_pixels=(8,)), "screen_pixels"),
    (dict(screen_pixels=(64,), screen_reference=32), "screen_reference"),
    (dict(turbulence_shots=1), "turbulence_shots"),
    (dict(pulse_sample_rates_hz=(0.1e9,)), "pulse sample rates"),     # 10 ns > the 5 ns pulse
    (dict(pulse_sample_rates_hz=(1e9, 4e9)), "pulse_reference_rate_hz"),
    (dict(pulse_estimators=("leading_edge",)), "pulse_estimators"),
    (dict(pulsed_snr_db=(20.0, 20.0)), "pulsed_snr_db"),
    (dict(pulsed_shots=1), "pulsed_shots"),
    (dict(pulsed_batch=0), "pulsed_batch"),
    (dict(pulsed_mission=CH5), "pulsed instrument"),
])
def test_bad_arguments_are_clear_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        accuracy_study(CH5, **kwargs)


def test_non_homodyne_mission_is_refused():
    with pytest.raises(ValueError, match="homodyne"):
        accuracy_study(CH5, ["sys.rsel=PIN"], shots=2)


def test_write_outputs_refuses_empty_or_foreign_rows(tmp_path):
    with pytest.raises(ValueError, match="no rows"):
        write_outputs([], tmp_path)
    with pytest.raises(ValueError, match="columns"):
        write_outputs([{"setting": "x"}], tmp_path)


# ------------------------------------------------------------------------- screen_pixels knob

TURB = ['atm.state=on', "atm.dst=100", "atm.Cn2=3e-13", "atm.Wr=1e9",
        'effects.enabled=["coupling", "turbulence"]', "effects.coupling.obstruction_ratio=0.3",
        "effects.coupling.focal_length_m=1.0", "effects.coupling.mode_field_radius_m=4.6e-6",
        "effects.coupling.fiber_numerical_aperture=0.14", 'effects.coupling.target="specular"',
        'effects.turbulence.fading="frozen_flow"', "effects.turbulence.outer_scale_m=20",
        "effects.turbulence.transverse_speed_mps=10", "effects.turbulence.shot_interval_s=0.01"]


def _fading(overrides):
    from chirplidar.channel.effects import channel_returns

    cfg = load_mission(CH5, TURB + overrides)
    return channel_returns(cfg, 6, np.random.default_rng(5)).power_factor


def test_screen_pixels_unset_keeps_the_rule_and_set_changes_the_screen():
    default = _fading([])
    assert np.array_equal(default, _fading(["effects.turbulence.screen_pixels=64"]))  # the rule: 64
    coarse = _fading(["effects.turbulence.screen_pixels=16"])
    assert coarse.shape == default.shape and np.all(coarse > 0)
    assert not np.array_equal(coarse, default)


def test_screen_pixels_bounds_are_clear_errors():
    with pytest.raises(ConfigError, match="screen_pixels"):
        load_mission(CH5, TURB + ["effects.turbulence.screen_pixels=8"])          # below 16
    with pytest.raises(ValueError, match="coarser than r0"):
        # D/r0 ~ 25 over 10 m (Rytov variance 0.16: over 100 m it would be 1.07, outside the
        # weak-fluctuation theory, which the configuration refuses first)
        _fading(["atm.dst=10", "atm.Cn2=3e-11", "effects.turbulence.screen_pixels=16"])


# ------------------------------------------------------------------------------- tiers timing

def test_bench_tiers_keys_and_consistency():
    res = bench_tiers(BENCH, repeats=1, baseband_batch=4, link_batch=1000)
    assert set(res) == {"rf_shot_s", "baseband_shot_s", "link_shot_s", "baseband_speedup",
                        "link_shots_per_s"}
    assert all(math.isfinite(v) and v > 0 for v in res.values())
    assert res["baseband_speedup"] == pytest.approx(res["rf_shot_s"] / res["baseband_shot_s"])
    assert res["link_shots_per_s"] == pytest.approx(1.0 / res["link_shot_s"])
    with pytest.raises(ValueError, match="link_batch"):
        bench_tiers(BENCH, repeats=1, link_batch=0)


def test_cli_accuracy_rejects_bad_shots_and_lists_the_choices(capsys):
    assert main(["bench", "--what", "accuracy", "--shots", "1"]) == 2
    assert "--shots must be >= 2" in capsys.readouterr().err
    assert main(["bench", "--what", "nonsense"]) == 2
    err = capsys.readouterr().err
    assert "accuracy" in err and "tiers" in err


def test_cli_accuracy_bad_mission_override_is_an_error(tmp_path, capsys):
    code = main(["bench", "--what", "accuracy", "--shots", "2", "--set", "sys.rsel=PIN",
                 "--out", str(tmp_path), "--json"])
    assert code == 2
    assert "homodyne" in capsys.readouterr().err
    assert not (tmp_path / "accuracy_vs_time.png").exists()


# ------------------------------------------------------------------------------- pulsed study

C = 299_792_458.0                      # m/s (SI definition)
PULSED_SMALL = dict(families=PULSED_FAMILIES, pulsed_snr_db=(20.0, 30.0, 40.0),
                    pulse_sample_rates_hz=(0.25e9, 1e9), pulse_reference_rate_hz=4e9,
                    pulsed_shots=300, pulsed_batch=100)


@pytest.fixture(scope="module")
def pulsed_rows():
    return accuracy_study(CH5, pulsed_mission=GLAS_BENCH, **PULSED_SMALL)


def _by(rows, snr, label):
    return next(r for r in rows if r["snr_target_db"] == snr and r["setting"] == label)


def test_pulsed_study_rows_and_reference(pulsed_rows):
    assert set(PULSED_FAMILIES) == set(STUDIES["pulsed"]) and set(PULSED_FAMILIES) <= set(FAMILIES)
    # Only pulsed families asked for: no chirped row, and one pulsed reference per SNR point.
    assert {r["study"] for r in pulsed_rows} == {"pulsed"}
    assert {r["tier"] for r in pulsed_rows} == {"pulsed"}
    for snr in (20.0, 30.0, 40.0):
        sel = [r for r in pulsed_rows if r["snr_target_db"] == snr]
        assert [r["setting"] for r in sel] == [
            "pulsed ref (4 GHz, gaussian_fit)", "Fs 0.25 GHz", "Fs 1 GHz (mission)",
            "threshold (1 GHz)", "centroid (1 GHz)", "gaussian_fit (1 GHz) (mission)"]
        ref = sel[0]
        assert ref["reference"] and sum(r["reference"] for r in sel) == 1
        assert ref["range_rms_diff_m"] == 0.0 and ref["snr_error_db"] == 0.0
        for r in sel:
            assert tuple(r) == COLUMNS and r["shots"] == 300 and r["batch"] == 100
            assert r["s_per_shot"] > 0 and r["outlier_frac"] == 0.0
            # Shots the tier did not detect (NaN range) are left out and counted in the flags:
            # none from 30 dB up; at 20 dB the 0.25 GHz digitizer (a sample per 4 ns) misses a
            # few (~2 % in a 1000-shot run).
            missed = re.search(r"non_finite:(\d+)_range", r["flags"])
            missed = int(missed.group(1)) if missed else 0
            assert missed == 0 if snr > 20 else missed <= 0.05 * 300, (r["setting"], missed)
            for c in NUMERIC:
                assert math.isfinite(r[c]), (r["setting"], c)
        mission = _by(pulsed_rows, snr, "Fs 1 GHz (mission)")
        # The SNR points are placed with the tier's own SNR at the mission's settings.
        assert mission["snr_mean_db"] == pytest.approx(snr, abs=0.01)
        # Same settings, same seeds: the estimator family's mission row repeats it shot for shot,
        # and the estimators read the same waveforms (the tier's SNR does not depend on them).
        fit = _by(pulsed_rows, snr, "gaussian_fit (1 GHz) (mission)")
        assert fit["range_rms_m"] == mission["range_rms_m"]
        for e in ("threshold", "centroid"):
            assert _by(pulsed_rows, snr, f"{e} (1 GHz)")["snr_mean_db"] == mission["snr_mean_db"]


def _glas_circuit_variance(cfg, fs_hz):
    """:func:`conftest.apd_circuit_variance` of instruments/glas.toml at ``fs_hz``."""
    return apd_circuit_variance(cfg.apd, cfg.pulse_receiver.bandwidth_hz, fs_hz)


@pytest.mark.parametrize("snr", [30.0, 40.0])
def test_pulsed_threshold_estimator_reads_short_by_the_range_walk(pulsed_rows, snr):
    # Closed form of the range walk: the mean return is a Gaussian of sigma_r^2 = sigma_p^2 +
    # sigma_h^2 (pulse FWHM tau = 5 ns, thesis Table 2.1; detector -3 dB at B = 200 MHz:
    # sigma_h = sqrt(ln 2) / (2 pi B)) and peak A = N dt / (sqrt(2 pi) sigma_r) per sample (N the
    # signal photoelectrons, eq. 2.2.4, read off the tier at the row's attenuation). Its leading
    # edge crosses the threshold T at t0 - sigma_r sqrt(2 ln(A / T)); the estimator refers the
    # crossing to the half maximum, t0 - sigma_r sqrt(2 ln 2): with T below A / 2 the crossing
    # comes early and the range reads short (d_error = true - measured > 0) by
    #     c / 2 x sigma_r (sqrt(2 ln(A / T)) - sqrt(2 ln 2)).
    # T = 5 sigma of the noise per sample at night (threshold_sigma = 5, no background): the
    # circuit variance plus the 8-bit AGC's quantisation LSB^2 / 12, LSB = (A + 5 sqrt(F A +
    # sigma_c^2)) / 2^8. Noise on the edge and the linear interpolation of the edge's convex
    # foot only make the first crossing earlier: the bias is at least the walk (less 3 standard
    # errors) and, measured, a few per cent above it; we allow 25 %.
    from chirplidar.channel import simulate_lab

    cfg = load_mission(GLAS_BENCH)
    row = _by(pulsed_rows, snr, "threshold (1 GHz)")
    fs = cfg.digitizer.sample_rate_hz
    n_signal = float(simulate_lab(config_with(cfg, {"channel.extra_attenuation_db":
                                                    row["pattn_db"]}),
                                  "pulsed", np.random.default_rng(0))["n_signal"][0])
    sigma_p = 5e-9 / (2 * np.sqrt(2 * np.log(2)))
    sigma_h = np.sqrt(np.log(2)) / (2 * np.pi * 200e6)
    sigma_r = np.hypot(sigma_p, sigma_h)
    peak = n_signal / (fs * np.sqrt(2 * np.pi) * sigma_r)
    var_c = _glas_circuit_variance(cfg, fs)
    lsb = (peak + 5 * np.sqrt(cfg.apd.excess_noise_factor * peak + var_c)) / 2**8
    threshold = 5 * np.sqrt(var_c + lsb**2 / 12)
    walk = C / 2 * sigma_r * (np.sqrt(2 * np.log(peak / threshold)) - np.sqrt(2 * np.log(2)))
    n = row["shots"]
    std = math.sqrt(max(row["range_rms_m"] ** 2 - row["range_bias_m"] ** 2, 0.0) * n / (n - 1))
    assert walk - 3 * std / math.sqrt(n) < row["range_bias_m"] < 1.25 * walk, (row, walk)
    # the other estimators have no such bias (within 4 standard errors of their RMS)
    for label in ("centroid (1 GHz)", "gaussian_fit (1 GHz) (mission)"):
        other = _by(pulsed_rows, snr, label)
        assert abs(other["range_bias_m"]) < 4 * other["range_rms_m"] / math.sqrt(n)


def test_pulsed_finer_sampling_is_not_worse(pulsed_rows):
    # Finer sampling of the 5 ns pulse never reads a larger range RMS than coarser sampling,
    # within 3 standard errors of the difference of two independent runs.
    for snr in (20.0, 30.0, 40.0):
        order = [_by(pulsed_rows, snr, s) for s in
                 ("Fs 0.25 GHz", "Fs 1 GHz (mission)", "pulsed ref (4 GHz, gaussian_fit)")]
        for coarse, fine in zip(order, order[1:]):
            se = math.hypot(coarse["range_rms_se_m"], fine["range_rms_se_m"])
            assert fine["range_rms_m"] <= coarse["range_rms_m"] + 3 * se, (snr, coarse, fine)
        assert order[0]["s_per_shot"] > 0 and order[2]["s_per_shot"] > 0


def test_pulsed_rows_are_written_and_plotted(pulsed_rows, tmp_path):
    paths = write_outputs(pulsed_rows, tmp_path)
    with paths["csv"].open() as fh:
        got = list(csv.DictReader(fh))
    assert len(got) == len(pulsed_rows) and {g["study"] for g in got} == {"pulsed"}
    assert paths["md"].read_text().count("| pulsed |") == len(pulsed_rows)
    assert paths["png"].read_bytes()[:8] == PNG_MAGIC
