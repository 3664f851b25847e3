"""Footprint sub-rays in the survey tiers (``mission.measure``): power conservation, speckle and
carrier-phase statistics against closed forms.

Sub-rays sample a beam's footprint; they are not scatterers. Reference values (closed forms):
* speckle off: the footprint returns its mean power, so the baseband and rf tiers' SNR equals the
  link budget's (the link tier is the closed form of the same chain; the baseband tier's peak
  reading of a 45 dB tone scatters by ~0.4 dB per shot, so a mean over >= 100 shots is good to
  ~0.1 dB; tolerance 0.5 dB);
* speckle on, one homodyne record: the field of a diffuse footprint is circular complex Gaussian
  (Goodman 2007 Ch. 3), the balanced pair reads |z|^2 sin^2(psi + arg z) = (Im z)^2: SNR / mean is
  chi-square of one degree of freedom, P(X < x) = erf(sqrt(x / 2)), mean 1/2 of the speckle-free
  optimum-phase SNR, whatever the static carrier phase (thesis eq. 3.3.12);
* a uniformly distributed static phase without speckle: SNR / optimum = sin^2 psi, the arcsine law
  P(F < x) = (2/pi) arcsin(sqrt(x)), mean 1/2;
* the mean spectrum of echoes with independent phases is the power-weighted sum of their lines
  (Goodman 2007 Ch. 4); tones spaced by 1/T over a record of length T are orthogonal.
Statistical tolerances are >= 3 standard errors of the sample sizes used (stated per test).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.special import erf

from chirplidar import load_mission
from chirplidar.config.loader import config_with
from chirplidar.channel import footprint
from chirplidar.mission import measure
from chirplidar.mission.preflight import prepare
from chirplidar.mission.survey import chunk_geometry, chunk_seeds
from chirplidar.channel import simulate_lab
from chirplidar.channel.lab import lab_budget
from chirplidar.tiers.echoes import Echoes, chirp_overlap, footprint_coherence, footprint_echoes
from chirplidar.tiers.link import static_phase_factor
from chirplidar.units import SPEED_OF_LIGHT_M_S
from conftest import FIELD, FLAT_SNOW, TWO_BEAMS, write_flat_uav_mission

# FIELD: missions/thesis_field_instrument.toml (1 speckle cell, K = 94, random carrier phase)
# 300 m range: a 10 MHz beat, so a 20 MHz band (a short baseband record) holds it; -20 dB of
# attenuation gives ~45 dB of optimum-phase SNR: deep fades stay far above the noise.
FAST = ["processing.averages=1", "processing.peak_search_max_hz=20e6",
        "channel.extra_attenuation_db=-20"]
CHI2_1 = erf(np.sqrt(0.05))                      # P(X < 0.1) for chi-square(1): 0.2482
ARCSINE = 2 / np.pi * np.arcsin(np.sqrt(0.05))   # P(sin^2 psi < 0.05): 0.1436


def _survey(tmp: Path, name: str, *, effects="[]", beams=TWO_BEAMS, stop=5.0, prf=20.0,
            terrain=FLAT_SNOW,
            overrides=(), subrays=7):
    """(config, scene, geometry, seeds) of the first chunk of a UAV line 400 m above a flat
    snow plane (range 300 m at nadir)."""
    mission = write_flat_uav_mission(tmp, name, altitude_m=400.0, beams=beams, prf=prf,
                                     stop=stop, subrays=subrays, effects=effects,
                                     terrain=terrain)
    config, scene, plan = prepare(mission, overrides=[*FAST, *overrides],
                                  cache_dir=tmp / "cache")
    seq = chunk_seeds(config.seed, plan.n_chunks)[0]
    geom = chunk_geometry(plan, scene, config, plan.chunk_times(0), seq,
                          config.survey.subrays_per_beam)
    return config, scene, geom, seq


def _lin(db):
    return 10 ** (np.asarray(db, float) / 10)


def _db(x):
    return 10 * np.log10(x)


# ----------------------------------------------------------------------------- footprint echoes
def _field(*overrides):
    return load_mission(FIELD, ["channel.distance_m=300", *FAST, *overrides])


def test_unresolved_footprint_is_one_echo_of_the_whole_power():
    """Sub-rays at one delay (a flat nadir footprint) with any power shares: one echo of weight 1
    and gain 1, so the tiers' beat power is the footprint's power. The former sum of sqrt(w_k)
    with common phase gave (sum_k sqrt(w_k))^2 = 5.9 here."""
    cfg = _field()
    bud = lab_budget(cfg)
    w = np.array([[0.3, 0.25, 0.2, 0.1, 0.08, 0.05, 0.02]])
    offs, pw, phase, gain = footprint_echoes(cfg, bud, w, np.zeros_like(w))
    assert pw.shape == (1, 1)
    np.testing.assert_allclose(offs, 0.0, atol=1e-18)
    np.testing.assert_allclose(gain, 1.0, rtol=1e-12)
    np.testing.assert_array_equal(phase, 0.0)
    # Unnormalised fractions (received power shares): the same echoes.
    _, pw2, _, gain2 = footprint_echoes(cfg, bud, 1e-9 * w, np.zeros_like(w))
    np.testing.assert_allclose(pw2 / pw2.sum(), 1.0)
    np.testing.assert_allclose(gain2, 1.0, rtol=1e-12)


def test_footprint_coherence_closed_form():
    """Two equal sub-rays dtau apart, rectangular chirp envelope, LO undelayed: the overlap is the
    return's chirp from f_start over B = kappa (T_r - tau), so the record energy of their common-
    phase beat is (1 + cos(2 pi f_c dtau) sinc(B dtau)) / 2 with f_c = f_start + B / 2."""
    cfg = _field("waveform.amplitude_duty_cycle=1.0")
    bud = lab_budget(cfg)
    tr = bud.train.rise_s
    band = bud.train.rate_hz_per_s * (tr - bud.delay_s)
    f_c = bud.train.f_start_hz + band / 2
    dtau = np.array([0.3e-9, 2e-9, 7e-9, 30e-9])
    a = np.full((dtau.size, 2), 0.5)
    d = np.column_stack([np.zeros_like(dtau), dtau])
    got = footprint_coherence(cfg, bud, a, d)
    ref = 0.5 * (1 + np.cos(2 * np.pi * f_c * dtau) * np.sinc(band * dtau))
    np.testing.assert_allclose(got, ref, atol=3e-3)   # midpoint rule on 2048 points


def test_spread_footprint_draws_the_mean_line():
    """A footprint spread over ~4 resolution cells without speckle: the baseband tier's line from
    the cell echoes has the peak of the mean (independent-phase) line, sum_k w_k x (sub-ray k's
    line) (Goodman), within 0.3 dB, and the same energy within 3 %; the sub-rays summed with one
    common phase (the smooth-surface field) miss the peak by dBs."""
    cfg = config_with(_field("processing.peak_search_max_hz=30e6", "channel.carrier_phase=optimal"),
                      {"channel.extra_attenuation_db": -40.0})
    bud = lab_budget(cfg)
    rng = np.random.default_rng(7)
    k = 24
    delta = 1.0 / (bud.train.rate_hz_per_s * chirp_overlap(cfg, bud)[2])   # one cell
    dtau = np.linspace(-2.0, 2.0, k) * delta
    w = np.exp(-0.5 * (dtau / (1.2 * delta)) ** 2)
    w /= w.sum()
    single = simulate_lab(cfg, "baseband", rng, batch=k, keep_spectrum=True,
                               echoes=Echoes(dtau[:, None], np.ones((k, 1)), np.zeros((k, 1))))
    psd = single["spectrum"]["psd_w_per_hz"]
    mean_line = np.sum(w[:, None] * psd, axis=0)
    offs, pw, phase, gain = footprint_echoes(cfg, bud, w[None], dtau[None])
    cfg_g = config_with(cfg, {"channel.extra_attenuation_db": -40.0 - _db(gain[0])})
    cells = simulate_lab(cfg_g, "baseband", rng, batch=1, keep_spectrum=True,
                              echoes=Echoes(offs[0], pw[0], phase[0]))["spectrum"]["psd_w_per_hz"][0]
    assert abs(_db(cells.max() / mean_line.max())) < 0.3
    assert cells.sum() / mean_line.sum() == pytest.approx(1.0, rel=0.03)
    smooth = simulate_lab(cfg, "baseband", rng, batch=1, keep_spectrum=True,
                               echoes=Echoes(dtau, w ** 2, np.zeros(k)))["spectrum"]["psd_w_per_hz"][0]
    # (the coherent sum's power, rescaled to the mean power as its energy would be)
    assert abs(_db(smooth.max() / mean_line.max() * mean_line.sum() / smooth.sum())) > 1.0


def test_subray_speckle_fields_are_circular_gaussian():
    """Per sub-ray E|z|^2 = 1; the footprint field sum_k sqrt(w_k) z_k is circular complex
    Gaussian of power sum_k w_k = 1: exponential intensity (P(I < 0.1) = 1 - e^-0.1 = 0.0952),
    independent quadratures of variance 1/2. n = 20000 shots (SE: mean 0.007, fraction 0.002)."""
    cfg = _field()
    n, k = 20000, 7
    geom = SimpleNamespace(sub_range_m=np.full((n, 1, k), 300.0), range_true_m=np.full((n, 1), 300.0))
    scene = SimpleNamespace(effects=["speckle"])
    seq = np.random.SeedSequence(11)
    z = footprint.subray_speckle_fields(cfg, scene, geom, seq)
    assert z.shape == (n, 1, k)
    assert abs(np.mean(np.abs(z) ** 2) - 1.0) < 0.01                 # SE 0.0027
    w = np.exp(-2.0 * np.linspace(0, 1, k) ** 2)
    w /= w.sum()
    field = np.sum(np.sqrt(w) * z[:, 0], axis=-1)
    inten = np.abs(field) ** 2
    assert abs(inten.mean() - 1.0) < 0.025                           # SE 0.007
    assert abs(np.mean(inten < 0.1) - (1 - np.exp(-0.1))) < 0.007    # SE 0.0021
    assert abs(np.var(field.real) - 0.5) < 0.02 and abs(np.var(field.imag) - 0.5) < 0.02
    assert abs(np.mean(field.real * field.imag)) < 0.015
    # Same seed, same fields; no speckle, no fields (and nothing drawn).
    np.testing.assert_array_equal(z, footprint.subray_speckle_fields(cfg, scene, geom, seq))
    assert footprint.subray_speckle_fields(cfg, SimpleNamespace(effects=[]), geom, seq) is None


# ------------------------------------------------------------------------------- carrier phase
def test_static_phase_factor_is_the_link_tiers_phase_power():
    """simulate_link at a static phase over the optimum = static_phase_factor (sin^2 psi for the
    balanced pair); matched phase-diversity arms do not fade."""
    for dist in (300.0, 300.0001, 300.0003):   # propagation phases of 0.15 and 0.46 um apart
        prop = _field("channel.carrier_phase=propagation", f"channel.distance_m={dist}")
        opt = config_with(prop, {"channel.carrier_phase": "optimal"})
        ratio = _lin(simulate_lab(prop, "link", np.random.default_rng(0))["SNR"][0]
                     - simulate_lab(opt, "link", np.random.default_rng(0))["SNR"][0])
        bud = lab_budget(prop)
        psi = -2 * np.pi * np.mod(bud.nu_hz * (bud.delay_s - bud.ref_delay_s), 1.0)
        assert ratio == pytest.approx(float(static_phase_factor(prop, psi)), rel=1e-9, abs=1e-12)
    psi = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    np.testing.assert_allclose(static_phase_factor(_field(), psi), np.sin(psi) ** 2)
    np.testing.assert_allclose(static_phase_factor(_field("sys.CxMode=phase_diversity"), psi), 1.0)
    np.testing.assert_array_equal(static_phase_factor(_field("sys.rsel=PIN", "mzm.Vdc=1.0"), psi), 1.0)


def test_link_static_phase_per_shot(tmp_path):
    """channel.carrier_phase = "propagation" on a jittered flat survey: each shot's SNR is the
    optimum's times sin^2 of its own -2 pi nu tau (no longer the node's one phase); over the
    survey the arcsine law (mean 1/2, P(F < 0.05) = 0.1436; 2000 shot-beams: SE 0.008)."""
    over = ["attitude.jitter_rad_rms=50e-6"]
    out = {}
    for cp in ("optimal", "propagation"):
        config, scene, geom, seq = _survey(tmp_path, "j", stop=50.0,
                                           overrides=[*over, f"channel.carrier_phase={cp}"])
        out[cp] = _lin(measure.measure_link(config, scene, geom, seq)["snr_db"])
    f = out["propagation"] / out["optimal"]
    _, r_mean, _, _ = footprint.received_power(config, scene, geom, seq)
    bud = lab_budget(config)
    tau = 2 * config.channel.group_index * r_mean / SPEED_OF_LIGHT_M_S
    psi = -2 * np.pi * np.mod(bud.nu_hz * tau, 1.0)          # reference_delay_s = 0 here
    np.testing.assert_allclose(f, np.sin(psi) ** 2, rtol=1e-6, atol=1e-9)
    assert f.size == 2000
    assert abs(f.mean() - 0.5) < 0.03
    assert abs(np.mean(f < 0.05) - ARCSINE) < 0.025


@pytest.mark.parametrize("cp,averages", [("optimal", 1), ("propagation", 1), ("optimal", 4),
                                         ("random", 1)])
def test_link_speckle_follows_the_one_record_law(tmp_path, cp, averages):
    """Speckle on, one homodyne record: SNR / (speckle-free optimum-phase SNR) is chi-square(1) / 2
    for any static carrier phase (the speckle field's phase is uniform) and for a random one; an
    optimum or propagation phase holds over the K chirps of a record, so K = 4 (power averaging)
    keeps the law. (Formerly the optimum phase kept only the speckle power: exponential.)
    8000 shot-beams: SE of the mean 0.016, of the fractions 0.005."""
    avg = f"processing.averages={averages}"
    ref = _lin(measure.measure_link(*_survey(tmp_path, "ref", stop=80.0, prf=50.0,
                                             overrides=["channel.carrier_phase=optimal", avg]))
               ["snr_db"])
    config, scene, geom, seq = _survey(tmp_path, "sp", effects='["speckle"]', stop=80.0,
                                       prf=50.0, overrides=[f"channel.carrier_phase={cp}", avg])
    snr = _lin(measure.measure_link(config, scene, geom, seq)["snr_db"])
    x = (snr / ref).ravel() * 2
    assert x.size == 8000
    assert abs(x.mean() - 1.0) < 0.05
    assert abs(np.mean(x < 0.1) - CHI2_1) < 0.025
    assert abs(np.mean(x < 1.0) - erf(np.sqrt(0.5))) < 0.025


# ------------------------------------------------------------------- baseband and rf against link
def test_baseband_without_speckle_conserves_power(tmp_path):
    """Flat snow, no speckle, the same carrier-phase setting in both tiers: the baseband tier's
    mean SNR is the link tier's within 0.5 dB at nadir and 20 degrees off nadir (before: 6.4 x at
    nadir, the sqrt(w) sub-rays summed in phase, and 0.19 x at 20 degrees, their propagation
    phases interfering). Random carrier phase: the baseband's mean over 400 shot-beams is the
    link's mean phase power within 3 SE (arcsine law, std/mean 0.71: 0.45 dB)."""
    config, scene, geom, seq = _survey(tmp_path, "f", overrides=["channel.carrier_phase=optimal"])
    link = _lin(measure.measure_link(config, scene, geom, seq)["snr_db"])
    bb = measure.measure_baseband(config, scene, geom, seq)
    snr = _lin(bb["snr_db"])
    assert np.all(bb["detected"] == 1)
    for j in range(2):
        assert abs(_db(snr[:, j].mean() / link[:, j].mean())) < 0.5
    # Ranges: the power-weighted mean range within the Cramer-Rao scatter (~2 mm here).
    _, r_mean, _, _ = footprint.received_power(config, scene, geom, seq)
    assert np.all(np.abs(np.mean(bb["range_measured"] - r_mean, axis=0)) < 0.005)

    config, scene, geom, seq = _survey(tmp_path, "f", stop=10.0,
                                       overrides=["channel.carrier_phase=random"])
    bb = _lin(measure.measure_baseband(config, scene, geom, seq)["snr_db"])
    ratio = (bb / (0.5 * link.mean(axis=0))).ravel()     # the link's mean phase power: 1/2
    assert ratio.size == 400
    assert abs(ratio.mean() - 1.0) < 3 * 0.71 / np.sqrt(ratio.size)
    assert abs(np.mean(ratio < 0.1) - ARCSINE) < 0.055          # P(2 sin^2 < 0.1); SE 0.018


def test_baseband_speckle_follows_the_one_record_law(tmp_path):
    """Speckle on, optimum carrier phase, one homodyne record: the baseband tier's SNR over the
    speckle-free link SNR is chi-square(1) / 2 like the link tier's (before: the sub-rays'
    uniform phases with amplitudes sqrt(w_k), a finite random-phasor sum; the link kept the
    optimum: 2.5 dB apart). 1600 shot-beams: SE of the mean 0.035 (of 1), of P(X < 0.1) 0.011."""
    ref_cfg = _survey(tmp_path, "r", stop=40.0, overrides=["channel.carrier_phase=optimal"])
    ref = _lin(measure.measure_link(*ref_cfg)["snr_db"])
    config, scene, geom, seq = _survey(tmp_path, "s", effects='["speckle"]', stop=40.0,
                                       overrides=["channel.carrier_phase=optimal"])
    for meas in (measure.measure_baseband, measure.measure_link):
        x = (2 * _lin(meas(config, scene, geom, seq)["snr_db"]) / ref).ravel()
        assert x.size == 1600
        assert abs(x.mean() - 1.0) < 0.11                       # 3 SE: 0.45 dB
        assert abs(np.mean(x < 0.1) - CHI2_1) < 0.035
        assert abs(np.mean(x < 1.0) - erf(np.sqrt(0.5))) < 0.035


def test_baseband_propagation_phase_is_each_shots_own(tmp_path):
    """carrier_phase = "propagation": the baseband tier takes each shot's propagation phase (not
    its batch's), so shot by shot it reads the link tier's sin^2 psi: in the shots 10 dB or more
    above the noise the two tiers agree within the baseband's peak scatter (median 0.5 dB)."""
    config, scene, geom, seq = _survey(tmp_path, "p", stop=10.0,
                                       overrides=["attitude.jitter_rad_rms=50e-6",
                                                  "channel.carrier_phase=propagation"])
    link = measure.measure_link(config, scene, geom, seq)["snr_db"]
    bb = measure.measure_baseband(config, scene, geom, seq)["snr_db"]
    strong = link > 25.0
    assert strong.sum() > 250
    assert np.median(np.abs(bb[strong] - link[strong])) < 0.5
    assert np.corrcoef(_lin(bb).ravel(), _lin(link).ravel())[0, 1] > 0.95


def test_rf_without_speckle_conserves_power(tmp_path):
    """The rf tier takes the same footprint echoes: flat snow, no speckle, optimum phase, 3 shots
    x 2 beams within 0.5 dB of the link tier each (before: up to 6.4 x at nadir)."""
    config, scene, geom, seq = _survey(tmp_path, "rf", stop=0.15,
                                       overrides=["channel.carrier_phase=optimal"])
    link = measure.measure_link(config, scene, geom, seq)["snr_db"]
    rf = measure.measure_rf(config, scene, geom, seq)["snr_db"]
    assert rf.shape == (3, 2)
    np.testing.assert_allclose(rf, link, atol=0.5)
