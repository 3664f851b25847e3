"""Carrier fading in the link tier (``tiers.link.carrier_fading_factor``) against closed forms,
the baseband tier and the survey's link measurements.

Reference values (closed forms, not fits):
* one homodyne record with a uniform carrier phase psi: the beat power goes as sin^2 psi (thesis
  eq. 3.3.12); F = 2 sin^2 psi has mean 1 and P(F < x) = (2/pi) arcsin(sqrt(x/2)) (arcsine law);
* K records averaged in power: F = (2/K) sum sin^2 psi_k, variance 1/(2K);
* K records averaged coherently: F = (2/K) (sum sin psi_k)^2 -> chi-square of one degree of
  freedom, P(F < x) -> erf(sqrt(x/2)) (Monte Carlo: 0.2459 at K = 16, x = 0.1, vs 0.2482 limit);
* phase diversity with matched arms and power averaging: the summed arms do not fade (App. C).
Statistical tolerances are >= 3 standard errors of the sample sizes used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.special import erf

from chirplidar import load_mission
from chirplidar.config.loader import config_with
from chirplidar.channel import simulate_lab
from chirplidar.tiers.link import carrier_fading_factor
from conftest import FIELD, reference_target, write_flat_uav_mission

# FIELD (conftest): missions/thesis_field_instrument.toml, carrier_phase = "random"


def _field(*overrides):
    return load_mission(FIELD, ["channel.distance_m=120", *overrides])


def _fading(cfg, rng, n):
    """The link tier's fading factors for the configuration's own carrier-phase setting."""
    return carrier_fading_factor(cfg, cfg.channel.carrier_phase, rng, n)


def test_single_record_fading_is_the_arcsine_law():
    f = _fading(_field("processing.averages=1"), np.random.default_rng(1), 40000)
    assert abs(f.mean() - 1.0) < 0.015                       # SE 0.0035
    # P(F < 0.1) = (2/pi) arcsin(sqrt(0.05)) = 0.1436 (SE 0.0018)
    assert abs(np.mean(f < 0.1) - 2 / np.pi * np.arcsin(np.sqrt(0.05))) < 0.01


def test_power_average_narrows_and_coherent_average_keeps_the_fading():
    k = 94
    f = _fading(_field(f"processing.averages={k}"), np.random.default_rng(2), 20000)
    assert abs(f.mean() - 1.0) < 0.005
    assert f.std() == pytest.approx(np.sqrt(1 / (2 * k)), rel=0.03)
    coh = _field("processing.averages=16", "processing.averaging=coherent")
    f = _fading(coh, np.random.default_rng(3), 40000)
    assert abs(f.mean() - 1.0) < 0.025                       # SE 0.007 (variance ~ 2)
    assert abs(np.mean(f < 0.1) - erf(np.sqrt(0.05))) < 0.015  # SE 0.002, + K = 16 offset 0.002


def test_no_fading_without_a_random_phase_or_with_phase_diversity():
    rng = np.random.default_rng(4)
    state = rng.bit_generator.state
    for over in (["channel.carrier_phase=optimal"], ["channel.carrier_phase=propagation"],
                 ["sys.rsel=PIN", "mzm.Vdc=1.0"]):
        assert np.all(_fading(_field(*over), rng, 10) == 1.0)
    assert rng.bit_generator.state == state                  # no draws
    pd = _field("sys.CxMode=phase_diversity", "processing.averages=1")
    np.testing.assert_allclose(_fading(pd, rng, 1000), 1.0, rtol=1e-12)


def test_link_fading_matches_baseband_detection_at_threshold():
    # One homodyne record, no speckle, mean SNR 13 dB at the survey's UAV range: the baseband
    # tier draws the carrier phase per record; the link tier's mean SNR times its fading factor
    # must detect (SNR >= 10 dB) the same fraction: P(2 sin^2 psi >= 10^-0.3) =
    # 1 - (2/pi) arcsin(sqrt(10^-0.3 / 2)) = 0.666. Without the fading the link detects 100 %.
    base = reference_target(_field("processing.averages=1"), **{"channel.distance_m": 120.0})
    snr0 = simulate_lab(base, "link", np.random.default_rng(0))["SNR"][0]
    cfg = config_with(base, {"channel.extra_attenuation_db": float(snr0 - 13.0)})
    mean_snr = simulate_lab(cfg, "link", np.random.default_rng(0))["SNR"][0]
    assert mean_snr == pytest.approx(13.0, abs=0.01)   # the signal's own shot noise: 1e-4 dB
    n = 600
    bb = simulate_lab(cfg, "baseband", np.random.default_rng(5), batch=n)["SNR"]
    link = mean_snr + 10 * np.log10(_fading(cfg, np.random.default_rng(6), n))
    expected = 1 - 2 / np.pi * np.arcsin(np.sqrt(10 ** -0.3 / 2))
    # SE of a 600-shot fraction: 0.019; the baseband's noise adds ~0.3 to the linear SNR (~+0.01)
    assert abs(np.mean(bb >= 10.0) - expected) < 0.06
    assert abs(np.mean(link >= 10.0) - expected) < 0.06
    # Mean SNR: the fading has mean 1 (baseband within its noise bias, E1 of the study: +0.1 dB)
    assert abs(10 * np.log10(np.mean(10 ** (bb / 10))) - 13.0) < 0.4


def _flat_survey(tmp: Path) -> Path:
    return write_flat_uav_mission(tmp, "flat", altitude_m=220.0, beams='pattern = "nadir"',
                                  prf=100.0, stop=20.0, subrays=7)


def test_survey_link_tier_fades_one_record_shots(tmp_path):
    """measure_link with K = 1 and a random carrier phase: SNR / SNR(optimum phase) = sin^2 psi
    shot by shot (flat snow, no speckle: the optimum-phase SNR is deterministic)."""
    from chirplidar.mission.measure import measure_link
    from chirplidar.mission.preflight import prepare
    from chirplidar.mission.survey import chunk_geometry, chunk_seeds

    mission = _flat_survey(tmp_path)
    out = {}
    for cp in ("random", "optimal"):
        config, scene, plan = prepare(mission, overrides=["processing.averages=1",
                                                          f"channel.carrier_phase={cp}"],
                                      cache_dir=tmp_path / "c")
        seq = chunk_seeds(config.seed, plan.n_chunks)[0]
        geom = chunk_geometry(plan, scene, config, plan.chunk_times(0), seq,
                              config.survey.subrays_per_beam)
        out[cp] = 10 ** (measure_link(config, scene, geom, seq)["snr_db"] / 10)
    r = (out["random"] / out["optimal"]).ravel()
    assert r.size >= 1500
    assert abs(r.mean() - 0.5) < 0.03                        # SE 0.009
    # P(sin^2 psi < 0.05) = (2/pi) arcsin(sqrt(0.05)) = 0.1436 (SE 0.009)
    assert abs(np.mean(r < 0.05) - 2 / np.pi * np.arcsin(np.sqrt(0.05))) < 0.03
