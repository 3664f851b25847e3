"""The baseband tier against the rf reference and closed forms (issue 5)."""

import numpy as np
import pytest
from scipy import stats

from chirplidar import load_mission, simulate_shot
from chirplidar.analysis.crossval import Case, run_case, uniform_spread_echoes
from chirplidar.channel import simulate_lab
from chirplidar.tiers import baseband
from conftest import CH5


def _sweep_cases(snrs):
    return [Case("snr", f"SNR {s} dB", target_snr_db=s) for s in snrs]


def test_baseband_and_link_match_rf_across_homodyne_sweep():
    # Issue 5 acceptance on the thesis Ch. 5 bench: baseband within 0.5 dB of rf in SNR, the link
    # tier within 1.5 dB. Range RMS: 60 rf shots estimate it to 9 % (1 sigma), so this fast test
    # allows 25 %; tests marked slow hold it to the 10 % with 400 shots.
    for case in _sweep_cases((40, 30, 20, 10)):
        res = run_case(case, n_rf=60, n_baseband=240, seed=3)
        rf, bb, link = res["rf"], res["baseband"], res["link"]
        assert abs(bb["snr_db"] - rf["snr_db"]) <= 0.5, (case.label, res)
        assert abs(link["snr_db"] - rf["snr_db"]) <= 1.5, (case.label, res)
        assert rf["outliers"] == 0 and bb["outliers"] == 0, (case.label, res)
        assert abs(bb["rms_m"] / rf["rms_m"] - 1) <= 0.25, (case.label, res)


@pytest.mark.slow
def test_baseband_range_rms_within_ten_percent_of_rf():
    # The 10 % in range RMS, with 400 rf and 1600 baseband shots per point (sampling
    # error of the ratio about 4 %).
    for case in _sweep_cases((40, 30, 20, 10)):
        res = run_case(case, n_rf=400, n_baseband=1600, seed=11)
        assert abs(res["baseband"]["snr_db"] - res["rf"]["snr_db"]) <= 0.5, res
        assert abs(res["baseband"]["rms_m"] / res["rf"]["rms_m"] - 1) <= 0.10, (case.label, res)


@pytest.mark.parametrize("case", [
    Case("range", "beat 5 MHz", ("atm.dst=11001.3",), target_snr_db=20),
    Case("linewidth", "100 kHz", ("lsr.Lw=1e5", 'effects.enabled=["phase_noise"]'),
         target_snr_db=25),
    Case("doppler", "3 MHz", ('effects.enabled=["doppler"]', "effects.doppler.radial_velocity_mps=2"),
         target_snr_db=25),
    Case("speckle", "M = 1", ('effects.enabled=["speckle"]', "effects.speckle.cells=1"),
         target_snr_db=25),
    Case("footprint", "10 ns", target_snr_db=25, echoes=uniform_spread_echoes(10e-9),
         tiers=("rf", "baseband")),
], ids=lambda c: c.family)
def test_baseband_matches_rf_with_effects(case):
    # Same seeds in both tiers: speckle, carrier phase and effects are drawn identically shot for
    # shot; the tiers differ in their detector noise and in how they form the beat (full-rate
    # fields against the analytic low-pass product). 120 shots per tier: mean SNR to ~0.1 dB,
    # and each RMS to 1 / sqrt(2 x 120) = 6.5 %, so their ratio to ~9 % (1 sigma): 35 % is 3.8
    # sigmas (40 shots gave 16 % and failed on unlucky draws).
    n = 120
    res = run_case(case, n_rf=n, n_baseband=n, seed=5)
    rf, bb = res["rf"], res["baseband"]
    assert abs(bb["snr_db"] - rf["snr_db"]) <= 0.5, res
    # Outliers (noise peaks winning in deep speckle fades, Doppler lines) within 2 binomial sigmas.
    p = max(rf["outliers"], 1 / n)
    assert abs(bb["outliers"] - rf["outliers"]) <= 2 * np.sqrt(2 * p * (1 - p) / n) + 1 / n, res
    if rf["outliers"] < 0.05:   # inlier RMS is stable only without a heavy tail
        assert abs(bb["rms_m"] / rf["rms_m"] - 1) <= 0.35, res


def test_coherent_averaging_gains_the_number_of_chirps():
    # A stable beat adds in amplitude and the noise in power: K records gain 10 log10 K dB (the
    # rf tier's test_coherent_averaging_gains_the_number_of_chirps); the baseband tier draws one
    # noise record of 1/K the variance instead of K.
    one = load_mission(CH5, ["atm.Pattn=85"])
    eight = load_mission(CH5, ["atm.Pattn=85", "sys.avg=8"])
    s1 = simulate_lab(one, "baseband", np.random.default_rng(1), batch=200)["SNR"]
    s8 = simulate_lab(eight, "baseband", np.random.default_rng(2), batch=200)["SNR"]
    gain = 10 * np.log10(np.mean(10 ** (s8 / 10)) / np.mean(10 ** (s1 / 10)))
    assert abs(gain - 10 * np.log10(8)) < 0.5, gain


def test_direct_power_average_agrees_in_distribution_with_explicit(monkeypatch):
    # A constant chirp envelope (rdcyc = adcyc = 1) keeps the noise stationary, so 16 power-averaged
    # records are drawn per bin (noncentral chi-square). Against explicit averaging of 16 simulated
    # records, 800 shots each: the noise level (mean of the noise bins), its spread, the peak power
    # and the peak frequency agree (means within 3.5 standard errors, spreads within 15 %, about
    # 4 standard errors of a ratio of two standard deviations, sqrt(2) / sqrt(2 x 800) = 3.5 %
    # for Gaussian samples, and a two-sample Kolmogorov-Smirnov test does not reject at 0.1 %).
    ov = ["chrp.rdcyc=1.0", "chrp.adcyc=1.0", "sys.avg=16", 'processing.averaging="power"',
          'processing.peak_method="parabolic"', "atm.Pattn=88", "processing.peak_search_max_hz=1e8"]
    cfg = load_mission(CH5, ov)
    direct = simulate_lab(cfg, "baseband", np.random.default_rng(21), batch=800)
    monkeypatch.setattr(baseband, "DIRECT_POWER_AVERAGE", False)
    explicit = simulate_lab(cfg, "baseband", np.random.default_rng(22), batch=800)
    for key in ("Navg", "Crx", "SNR", "f_beat_hz"):
        a, b = direct[key], explicit[key]
        se = np.sqrt((a.var() + b.var()) / a.size)
        assert abs(a.mean() - b.mean()) <= 3.5 * se, (key, a.mean(), b.mean(), se)
        assert abs(a.std() / b.std() - 1) <= 0.15, (key, a.std(), b.std())
        assert stats.ks_2samp(a, b).pvalue > 1e-3, key


def test_direct_power_average_noise_bins_follow_the_gamma_law():
    # Closed form: the mean of K periodograms of white noise is gamma distributed per bin with
    # mean P and variance P^2 / K.
    rng = np.random.default_rng(4)
    n, k, fs, var = 2048, 12, 100e6, 3.0
    res = baseband.draw_power_average(np.zeros((64, 1, n)), fs, 1.0, var_v2=np.full(64, var),
                                      averages=k, rng=rng, rbw_hz=30e3, highpass_hz=1e6,
                                      peak_method="bin", noise_span_hz=4e6, noise_guard_hz=1e6,
                                      keep_spectrum=True)
    bins = res.spectrum_w_per_hz[:, 1:-1]
    p = 2.0 * var / fs                       # one-sided PSD of white noise of variance var
    assert abs(bins.mean() / p - 1) < 0.01
    assert abs(bins.var() / (p * p / k) - 1) < 0.03


def test_baseband_rejects_what_it_does_not_model():
    with pytest.raises(ValueError, match="the baseband tier does not model system.receiver = 'pin'"):
        simulate_lab(load_mission(CH5, ["sys.rsel=PIN"]), "baseband", np.random.default_rng(0))
    with pytest.raises(ValueError, match="pn_code"):
        simulate_lab(load_mission(CH5, ["sys.MxMode=PN"]), "baseband", np.random.default_rng(0))


def test_baseband_beat_above_its_band_is_flagged():
    # A 120 MHz beat lies above the band the baseband record holds (F1 = 100 MHz): flagged, as
    # the rf tier flags a beat beyond its search band.
    r = simulate_shot(load_mission(CH5, ["atm.dst=13500"]), tier="baseband")
    assert "beat_out_of_band" in r["flags"]


def test_baseband_same_seed_same_output():
    cfg = load_mission(CH5, ["atm.Pattn=80", "lsr.Lw=2e4", 'effects.enabled=["phase_noise"]'])
    a = simulate_lab(cfg, "baseband", np.random.default_rng(9), batch=5)
    b = simulate_lab(cfg, "baseband", np.random.default_rng(9), batch=5)
    for key in ("SNR", "d_rx", "Crx"):
        np.testing.assert_array_equal(a[key], b[key])


def test_phase_diversity_baseband_matches_rf():
    # Both hybrid arms: the summed-spectra SNR and arm 1's own SNR (thesis Fig. 5.13). Each arm
    # also detects the LO's own power, 37 dB above the floor at 1 MHz: the search starts at
    # 3 MHz so that both tiers read the 22 MHz beat (the range within a 0.75 m resolution cell),
    # not that line (hundreds of metres off).
    cfg = load_mission(CH5, ["sys.CxMode=phase_diversity", "atm.Pattn=70",
                             "processing.highpass_hz=3e6"])
    rf = simulate_shot(cfg, seed=1)
    bb = simulate_lab(cfg, "baseband", np.random.default_rng(1), batch=20)
    assert abs(float(rf["d_error"])) < 0.5 and np.all(np.abs(bb["d_error"]) < 0.5)
    assert abs(np.mean(bb["SNR"]) - rf["SNR"]) < 0.5
    assert abs(np.mean(bb["arm1_SNR"]) - rf["arm1_SNR"]) < 0.5


@pytest.mark.parametrize("label, overrides, echoes", [
    ("SNR 71 dB", ("atm.Pattn=20",), None),
    ("SNR 11 dB", ("atm.Pattn=85",), None),
    ("footprint 10 ns", ("atm.Pattn=45",), uniform_spread_echoes(10e-9)),
    ("linewidth 100 kHz", ("atm.Pattn=45", "lsr.Lw=1e5", 'effects.enabled=["phase_noise"]'), None),
    ("Doppler + speckle", ("atm.Pattn=45", 'effects.enabled=["doppler", "speckle"]',
                           "effects.doppler.radial_velocity_mps=2", "effects.speckle.cells=1"), None),
    ("power average K=4", ("atm.Pattn=60", "sys.avg=4", "processing.averaging=power",
                           "channel.carrier_phase=random"), None),
    ("phase diversity", ("atm.Pattn=45", "system.coherent_mode=phase_diversity"), None),
    # Unequal quantum efficiencies: the LO's direct current no longer cancels and sits in the
    # record (DESIGN: a weak signal against a strong LO must survive the balanced subtraction).
    ("LO imbalance, Psig -107 dBm", ("atm.Pattn=95", "balanced.quantum_efficiency_2=0.6"), None),
])
def test_single_precision_costs_no_accuracy(label, overrides, echoes):
    # simulation.baseband_precision = "single" (the default) against "double" on the same draws
    # (the unit normals are float32 in both): the float32 records and FFT move SNR and Crx by far
    # less than 0.01 dB and the beat frequency by less than 1e-4 of a bin (measured: <= 2e-4 dB
    # and 3e-6 bin), while the shot-to-shot scatter of one shot's reading is 0.26 dB in SNR and
    # 2.2e-4 bin in beat frequency at 71 dB SNR (0.86 dB and 0.26 bin at 11 dB; 200 shots).
    out = {}
    for prec in ("single", "double"):
        cfg = load_mission(CH5, [*overrides, f"simulation.baseband_precision={prec}"])
        kw = {} if echoes is None else {"echoes": echoes}
        out[prec] = simulate_lab(cfg, "baseband", np.random.default_rng(21), batch=16, **kw)
    s, d = out["single"], out["double"]
    bin_hz = 1.0 / cfg.simulation.duration_s
    for key in ("SNR", "Crx", "Navg"):
        assert np.max(np.abs(s[key] - d[key])) < 0.01, (label, key)
    assert np.max(np.abs(s["f_beat_hz"] - d["f_beat_hz"])) < 1e-4 * bin_hz, label


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("k_coef", [1, 3])
def test_low_rank_records_add_in_place(dtype, k_coef):
    # The shared-product records (per-record coefficients x functions of time) are added to the
    # noise by one in-place GEMM: the same as the explicit sum, for both precisions, with the
    # coefficients of one record broadcast over K records.
    rng = np.random.default_rng(4)
    coef, fns = rng.standard_normal((5, k_coef, 3)), rng.standard_normal((3, 64))
    out = rng.standard_normal((5, 3, 64)).astype(dtype)
    want = out.astype(float) + np.einsum("mkr,rn->mkn", coef, fns)
    before = out.__array_interface__["data"][0]
    baseband._LowRank(coef, fns).add_to(out)
    assert out.dtype == dtype and out.__array_interface__["data"][0] == before
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-5 if dtype == np.float32 else 1e-12)
