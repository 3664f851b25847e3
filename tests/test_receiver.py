"""The ``[receiver]`` architectures through the channel's focal-plane field (issue 18).

References: Ruilier 1998 (plane-wave fiber coupling, ``optics.coupling_efficiency``); Goodman
2007 Ch. 3 (a single mode of circular complex Gaussian speckle has exponential power, contrast
1); Siegman 1966 (the antenna theorem, ``optics.focal_plane.mean_mixing_efficiency_focal``).
"""

from __future__ import annotations

import numpy as np
import pytest

from chirplidar.channel.lab import lab_returns
from chirplidar.channel.receiver import receiver_optics, shot_pixels
from chirplidar.config import load_mission
from chirplidar.config.instrument import instrument_from_config
from chirplidar.config.loader import config_with
from chirplidar.optics import coupling_beta, coupling_efficiency, monostatic_diffuse_coupling
from chirplidar.optics.focal_plane import mean_mixing_efficiency_focal
from chirplidar.tiers.registry import TIERS
from conftest import ROOT, one_line_refusal

FIELD = ROOT / "missions" / "thesis_field_instrument.toml"
LAMBDA = 1310e-9  # thesis_ch5_bench.toml's laser
D_TEL, F_TEL = 0.05, 0.5
# Footprint radius ~1.1 cm at 50 m (beam 5 mm, 0.2 mrad): rho = lambda R / (pi w) ~ 1.9 mm,
# about 26 coherence radii across the 5 cm aperture (many grains; pupil_samples ~ 80).
CHANNEL = {"channel.distance_m": 50.0, "channel.telescope_diameter_m": D_TEL,
           "channel.beam_radius_m": 5e-3, "channel.divergence_half_angle_rad": 0.2e-3,
           "processing.averages": 1}
COMMON = {"receiver.focal_length_m": F_TEL, "receiver.obstruction_ratio": 0.0,
          "receiver.footprint": "beam"}
# Fiber mode radius at the plane-wave optimum beta = pi D w0 / (2 lambda f) = 1.121 (Ruilier).
W0_OPT = 1.1209 * 2 * LAMBDA * F_TEL / (np.pi * D_TEL)
FIBER = {"receiver.architecture": "fiber", "receiver.fiber.mode_field_radius_m": W0_OPT,
         "receiver.fiber.numerical_aperture": 0.14}
LAMBDA_F_D = LAMBDA * F_TEL / D_TEL
FPA = {"receiver.architecture": "fpa", "system.coherent_mode": "phase_diversity",
       "receiver.fpa.lo_profile": "flat_top", "receiver.fpa.lo_radius_m": 12 * LAMBDA_F_D,
       "receiver.fpa.pixels": 4, "receiver.fpa.pitch_m": 4 * LAMBDA_F_D,
       "receiver.fpa.fill_factor": 1.0, "receiver.fpa.noise_a_per_rthz": 2e-12,
       "receiver.fpa.dark_current_a": 1e-9, "receiver.fpa.combining": "mrc"}


def _large(side, lo_radius):
    return {"receiver.architecture": "large_detector", "receiver.large_detector.side_m": side,
            "receiver.large_detector.lo_profile": "flat_top",
            "receiver.large_detector.lo_radius_m": lo_radius}


@pytest.fixture(scope="module")
def field():
    return load_mission(FIELD)


def _config(base, *parts, speckle=True):
    over = {**CHANNEL, **COMMON, "effects.enabled": ["speckle"] if speckle else []}
    for p in parts:
        over.update(p)
    return config_with(base, over)


def test_fiber_plane_wave_coupling_is_ruiliers(field):
    """A plane wave (no speckle) into the fiber at the optimum, unobstructed and with a 0.25
    obstruction: the stage's gain is Ruilier's closed form (81.45 % unobstructed), divided by
    the fiber detector's noise ratio, which is 1 (the LO is all in the fiber)."""
    for alpha in (0.0, 0.25):
        cfg = _config(field, FIBER, {"receiver.obstruction_ratio": alpha}, speckle=False)
        g = lab_returns(cfg, 2, np.random.default_rng(0)).power_factor
        beta = coupling_beta(D_TEL, F_TEL, W0_OPT, LAMBDA)
        assert g == pytest.approx(coupling_efficiency(beta, alpha), rel=2e-3)
    assert coupling_efficiency(1.1209, 0.0) == pytest.approx(0.8145, abs=1e-4)


def test_monostatic_fiber_mean_is_winzer_and_leeb(field):
    """The field trial's monostatic fiber telescope (the same fiber transmits): its mean
    coupling of the diffuse target's speckle through the focal-plane field is Winzer & Leeb's
    (1998) mean, 0.42 at the optimum (optics.monostatic_diffuse_coupling). 4000 shots of an
    exponential power: standard error 1.6 %; tolerance 3 SE + 1 % (the pupil grid's quadrature)."""
    n = 4000
    cfg = _config(field, FIBER, {"receiver.footprint": "monostatic",
                                 "receiver.transmit_mode_radius_m": W0_OPT})
    g = lab_returns(cfg, n, np.random.default_rng(9)).power_factor
    beta = coupling_beta(D_TEL, F_TEL, W0_OPT, LAMBDA)
    expected = monostatic_diffuse_coupling(beta, 0.0)
    assert expected == pytest.approx(0.42, abs=0.01)
    assert g.mean() == pytest.approx(expected, abs=3 * g.std() / np.sqrt(n) + 0.01 * expected)


def test_fiber_in_speckle_fades_with_contrast_one(field):
    """The fiber couples one mode of a circular complex Gaussian field: its power is
    exponential (Goodman 2007 Ch. 3), contrast std / mean = 1. 3000 shots: the contrast's
    standard error is about 1 / sqrt(3000) x 1.1; tolerance 4 / sqrt(N)."""
    n = 3000
    g = lab_returns(_config(field, FIBER), n, np.random.default_rng(1)).power_factor
    assert g.std() / g.mean() == pytest.approx(1.0, abs=4 / np.sqrt(n))


@pytest.mark.parametrize("side_lfd", [0.5, 1.0, 2.0])
def test_large_detector_mixing_follows_the_antenna_theorem(field, side_lfd):
    """A square detector of side L in the focal plane with a uniform LO over it, in speckle
    with many grains across the aperture: E|a|^2 / E[P_s P_LO] on the detector is the antenna
    theorem's <eta> (Siegman 1966; mean_mixing_efficiency_focal, its closed form) within 10 %
    (issue 18). 400 shots: the ratio's standard error is a few per cent. The focal grid is
    sampled 8 times per lambda f / D (a detector spanning few samples reads a field constant
    over it: eta -> 1)."""
    side = side_lfd * LAMBDA_F_D
    cfg = _config(field, _large(side, side), {"receiver.focal_sampling": 8.0})
    opt = receiver_optics(cfg)
    px = shot_pixels(cfg, opt, 400, np.random.default_rng(2))
    measured = np.mean(np.abs(px.beat_w) ** 2) / np.mean(px.signal_power_w * px.lo_power_w)
    expected = mean_mixing_efficiency_focal(side, D_TEL, LAMBDA, F_TEL, 0.0)
    assert measured == pytest.approx(expected, rel=0.10)


def test_fpa_pixels_tile_the_large_detector(field):
    """Linearity: 4 x 4 pixels of fill factor 1 tiling a square read, summed, the beat of one
    detector of the same area and LO (the same fields: the same seed)."""
    side = 16 * LAMBDA_F_D
    arr = _config(field, FPA)
    big = _config(field, _large(side, 12 * LAMBDA_F_D))
    pa, pb = (shot_pixels(c, receiver_optics(c), 20, np.random.default_rng(3)) for c in (arr, big))
    summed = pa.beat_w.reshape(20, -1).sum(axis=1)
    assert np.allclose(summed, pb.beat_w.reshape(20), rtol=1e-9, atol=1e-12 * np.abs(summed).max())


def test_fpa_combining_rules_order_as_theory_says(field):
    """Per shot: maximal ratio >= selection and maximal ratio >= incoherent (Cauchy-Schwarz,
    Brennan 1959); the FPA's mean gain beats the fiber's in speckle (more than one grain
    collected) and its fades are shallower (1 % quantile over the mean)."""
    rng = np.random.default_rng
    g = {rule: lab_returns(_config(field, FPA, {"receiver.fpa.combining": rule}), 500,
                           rng(4)).power_factor for rule in ("mrc", "selection", "incoherent")}
    assert np.all(g["mrc"] >= g["selection"] * (1 - 1e-12))
    assert np.all(g["mrc"] >= g["incoherent"] * (1 - 1e-12))
    fiber = lab_returns(_config(field, FIBER), 500, rng(4)).power_factor
    assert g["mrc"].mean() > fiber.mean()
    depth = {k: np.quantile(v, 0.01) / v.mean() for k, v in (("fpa", g["mrc"]), ("fiber", fiber))}
    print("fade depth p01 / mean:", depth)
    assert depth["fpa"] > 10 * depth["fiber"]


def test_baseband_and_link_agree_on_the_fpa(field):
    """The link tier's closed form and the baseband tier's records of the same FPA returns give
    the same median SNR (within 1 dB over 60 shots at 25-37 dB) for each rule the baseband
    tier models: its records are the combined record (maximal ratio, selection) or the pixels'
    spectra summed (incoherent)."""
    for rule in ("mrc", "selection", "incoherent"):
        cfg = _config(field, FPA, {"receiver.fpa.combining": rule, "processing.highpass_hz": 2.5e6,
                                   "channel.extra_attenuation_db": -30.0,
                                   "channel.distance_m": 120.0})
        ret = lab_returns(cfg, 60, np.random.default_rng(5))
        inst = instrument_from_config(cfg)
        snr = [np.median(TIERS[t].simulate(inst, ret, np.random.default_rng(6))["SNR"])
               for t in ("link", "baseband")]
        print(rule, snr)
        assert abs(snr[0] - snr[1]) < 1.0


def test_estimated_gains_cost_snr_in_the_link_tier(field):
    """mrc_estimated: the link tier multiplies the known-gain SNR by (G + 1) / (G + M)
    (Gans 1971; receiver.fpa.estimated_mrc_factor), so it reads below mrc, by little at high
    SNR."""
    out = {}
    for rule in ("mrc", "mrc_estimated"):
        cfg = _config(field, FPA, {"receiver.fpa.combining": rule})
        ret = lab_returns(cfg, 50, np.random.default_rng(7))
        out[rule] = TIERS["link"].simulate(instrument_from_config(cfg), ret,
                                           np.random.default_rng(8))["SNR"]
    assert np.all(out["mrc_estimated"] < out["mrc"])



def _sets(over: dict) -> list[str]:
    out = []
    for k, v in over.items():
        out += ["--set", f"{k}={v!r}" if isinstance(v, str) else f"{k}={v}"]
    return out


FPA_SETS = {**COMMON, **FPA}


@pytest.mark.parametrize(("change", "needles"), [
    ({"receiver.fpa.pitch_m": 0.01}, ("receiver.fpa.pitch_m", "focal spot")),
    ({"receiver.fpa.pixels": 0}, ("receiver.fpa.pixels", "at least one pixel")),
    ({"receiver.fpa.fill_factor": 0.0}, ("receiver.fpa.fill_factor",)),
    ({"receiver.fpa.fill_factor": 1.5}, ("receiver.fpa.fill_factor",)),
    ({"receiver.architecture": "fiber"}, ("[receiver.fiber]",)),
    ({"receiver.footprint": "monostatic"}, ("receiver.transmit_mode_radius_m",)),
    ({"system.coherent_mode": "homodyne"}, ("phase_diversity",)),
    ({"receiver.fpa.combining": "mrc_estimated", "survey.tier": None}, ("mrc_estimated",)),
])
def test_bad_receivers_are_one_line(capsys, change, needles):
    """Each refusal of the issue, through the CLI: one line naming the key, no traceback."""
    over = {**FPA_SETS, **change}
    tier = ["--tier", "link"]
    if "survey.tier" in over:
        over.pop("survey.tier")
        tier = ["--tier", "baseband"]
    one_line_refusal(["shot", str(FIELD), *tier, *_sets(over)], capsys, *needles)


def test_an_architecture_the_tier_does_not_model_is_one_line(capsys):
    one_line_refusal(["shot", str(FIELD), "--tier", "rf", *_sets(FPA_SETS)], capsys,
              "receiver.architecture = 'fpa'", "rf")


def test_fpa_dsp_doppler_compensation_keeps_the_range_error(field):
    """Issue 18's Doppler acceptance through an FPA: each pixel's complex record carries the
    shot's Doppler shift; the combining DSP estimates it and removes it (doppler_recovery =
    "dsp"), so the range error under shifts of +-10 and 15 MHz (beyond the 4 MHz beat at 120 m)
    stays within 1.5x the zero-Doppler error (200 baseband shots each; ratio plus 3 standard
    errors). Both lines f_d +- f_R must clear the 3 MHz high-pass that keeps the hybrid's own LO
    power out (a 5 MHz shift puts one at 1 MHz: flagged doppler_beyond_dsp_band). Without the
    compensation a 10 MHz shift moves the range by c f_d / (2 n kappa), ~200 m."""
    lam = LAMBDA

    def rms(f_d, recovery):
        over = {"effects.enabled": ["speckle", "doppler"], "processing.highpass_hz": 3e6,
                "channel.extra_attenuation_db": -20.0, "channel.distance_m": 120.0,
                "effects.doppler.radial_velocity_mps": f_d * lam / 2,
                "processing.doppler_recovery": recovery}
        cfg = _config(field, FPA, over)
        ret = lab_returns(cfg, 200, np.random.default_rng(11))
        err = TIERS["baseband"].simulate(instrument_from_config(cfg), ret,
                                         np.random.default_rng(12))["d_error"]
        err = np.asarray(err, float)
        r = float(np.sqrt(np.mean(err ** 2)))
        # SE of an RMS from n draws: about RMS / sqrt(2 n) for near-Gaussian errors
        return r, r / np.sqrt(2 * err.size)

    zero, zero_se = rms(0.0, "none")
    for f_d in (10e6, -10e6, 15e6):
        r, se = rms(f_d, "dsp")
        print(f"f_d {f_d / 1e6:g} MHz: {r * 1e3:.2f} mm vs {zero * 1e3:.2f} mm")
        assert r / zero - 3 * np.hypot(se / zero, r * zero_se / zero**2) <= 1.5
    off, _ = rms(10e6, "none")
    assert off > 50.0


def test_rf_tier_flies_the_large_detector_as_the_link_tier_does(field):
    """The rf tier takes a single detector's gain and beat phase like the link tier: a plane
    wave (deterministic gain) on a large detector, homodyne at the optimum phase, reads the
    link tier's SNR within 1 dB (12 shots)."""
    cfg = _config(field, _large(4 * LAMBDA_F_D, 3 * LAMBDA_F_D),
                  {"channel.carrier_phase": "optimal", "channel.distance_m": 120.0,
                   "channel.extra_attenuation_db": -20.0}, speckle=False)
    ret = lab_returns(cfg, 12, np.random.default_rng(13))
    inst = instrument_from_config(cfg)
    snr = [float(np.median(TIERS[t].simulate(inst, ret, np.random.default_rng(14))["SNR"]))
           for t in ("link", "rf")]
    print("link, rf:", snr)
    assert abs(snr[0] - snr[1]) < 1.0


def test_estimated_gains_in_a_survey_cost_their_factor_once(tmp_path):
    """A link-tier survey with mrc_estimated reads the known-gain (mrc) survey's SNR times
    (G + 1) / (G + M) once (the survey's table nodes carry it), G = SNR x RBW x T of each shot
    (T from its line width 0.886 / T): medians within 0.3 dB, 2 s of the UAV receivers mission."""
    import xarray as xr

    from chirplidar.mission.runner import run_mission
    from chirplidar.receiver.fpa import estimated_mrc_factor

    mission = ROOT / "missions" / "greenland_uav_receivers.toml"
    snr, width = {}, {}
    for rule in ("mrc", "mrc_estimated"):
        out = tmp_path / f"{rule}.nc"
        run_mission(mission, out=out, overrides=["survey.stop_s=2",
                                                 f"receiver.fpa.combining={rule!r}"])
        with xr.open_dataset(out) as ds:
            snr[rule] = 10 ** (ds["snr_db"].values.ravel() / 10)
            width[rule] = ds["beat_width"].values.ravel()
    rbw = load_mission(mission).processing.rbw_hz
    g = snr["mrc"] * rbw * 0.886 / width["mrc"]
    expected = snr["mrc"] * estimated_mrc_factor(g, 16)
    diff = 10 * np.log10(np.median(snr["mrc_estimated"]) / np.median(expected))
    print("median est vs expected (dB):", diff)
    assert abs(diff) < 0.3
