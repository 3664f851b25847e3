"""The effect registry and the effects in the transceiver chain (issue 3: registry, Doppler)."""

import json

import numpy as np
import pytest

from chirplidar import load_mission, simulate_shot
from chirplidar.channel.effects import EFFECTS, channel_returns
from chirplidar.config.models_effects import EFFECT_NAMES
from chirplidar.channel import simulate_lab
from conftest import BENCH, CH5, SMALL

WAVELENGTH_M = 1.31e-6  # thesis Table 4.4 lsr.Lo


def _cfg(*extra):
    return load_mission(CH5, ["atm.Pattn=60", *extra])


def _enable(*names):
    return f"effects.enabled={json.dumps(list(names))}"


def test_registry_and_config_name_the_same_effects():
    assert tuple(EFFECTS) == EFFECT_NAMES


def test_disabled_effects_cost_nothing_and_draw_nothing():
    rng = np.random.default_rng(5)
    state = rng.bit_generator.state
    returns = channel_returns(_cfg(), 4, rng)
    assert np.all(returns.power_factor == 1) and np.all(returns.doppler_hz == 0)
    assert rng.bit_generator.state == state  # the run's stream is untouched


def test_enabling_an_effect_leaves_the_other_streams_unchanged():
    # Speckle draws come from speckle's own stream: adding Doppler does not change them.
    both = _cfg(_enable("speckle", "doppler"), "effects.speckle.cells=1",
                "effects.doppler.radial_velocity_mps=1")
    alone = _cfg(_enable("speckle"), "effects.speckle.cells=1")
    a = channel_returns(both, 8, np.random.default_rng(9))
    b = channel_returns(alone, 8, np.random.default_rng(9))
    np.testing.assert_array_equal(a.power_factor, b.power_factor)
    # The detector noise is the same draw with and without phase noise (zero signal: pure noise).
    quiet = ["atm.Pattn=inf"]
    off = simulate_shot(_cfg(*quiet), seed=4)
    on = simulate_shot(_cfg(*quiet, "lsr.Lw=1e4", _enable("phase_noise")), seed=4)
    assert on["Navg"] == off["Navg"]


@pytest.mark.parametrize("velocity_mps", [1.0, 3.0, -2.0])
def test_doppler_moves_the_beat_by_2v_over_lambda(velocity_mps):
    # eq. 2.2.5 and Appendix D: the real homodyne output has lines at f_R +- f_d; the peak search
    # finds one of them, so the peak moves by |2 v / lambda| within one FFT bin.
    cfg = _cfg(_enable("doppler"), f"effects.doppler.radial_velocity_mps={velocity_mps}")
    still = simulate_shot(_cfg(), seed=1)
    moving = simulate_shot(cfg, seed=1)
    f_d = 2 * abs(velocity_mps) / WAVELENGTH_M
    bin_hz = 1 / cfg.simulation.duration_s
    assert abs(abs(moving["f_beat_hz"] - still["f_beat_hz"]) - f_d) < bin_hz
    # Each line carries a quarter of the optimum-phase power: -6 dB, and the link tier agrees.
    assert abs((still["SNR"] - moving["SNR"]) - 10 * np.log10(4)) < 1.0
    assert abs(simulate_shot(cfg, tier="link")["SNR"] - moving["SNR"]) < 1.0


def test_zero_velocity_is_no_doppler():
    cfg = _cfg(_enable("doppler"), "effects.doppler.radial_velocity_mps=0")
    assert simulate_shot(cfg, seed=2) == simulate_shot(_cfg(), seed=2)


def test_doppler_beyond_the_beat_is_flagged():
    # Appendix D: f_d > f_R folds the lower line through zero (sign ambiguity).
    cfg = _cfg(_enable("doppler"), "effects.doppler.radial_velocity_mps=20")  # 30.5 MHz > 22 MHz
    assert "doppler_ambiguous" in simulate_shot(cfg, tier="link")["flags"]


@pytest.mark.parametrize("cells", [1, 16])
def test_speckle_fading_of_the_homodyne_beat(cells):
    # Speckle power g ~ Gamma(M, 1/M) times the homodyne phase factor 2 sin^2(psi), psi uniform
    # (the speckle phase): E[g^2] = 1 + 1/M, E[(2 sin^2)^2] = 3/2, so the beat power's contrast is
    # sqrt(1.5 (1 + 1/M) - 1) (Goodman; closed form). Link tier: 4000 shots, rf: mean level.
    # The small 16 us record keeps 400 rf shots cheap; the beat is far above the noise.
    cfg = load_mission(BENCH, SMALL + ["atm.Pattn=30", "mzm.Vdc=2.0", _enable("speckle"),
                                       f"effects.speckle.cells={cells}"])
    link = simulate_lab(cfg, "link", np.random.default_rng(3), batch=4000)
    p = 10 ** (link["Crx"] / 10)
    expected = np.sqrt(1.5 * (1 + 1 / cells) - 1)
    assert abs(p.std() / p.mean() - expected) < 0.08
    rf = simulate_lab(cfg, "rf", np.random.default_rng(3), batch=400)
    p_rf = 10 ** (rf["Crx"] / 10)
    # Standard error of a 400-shot mean at contrast <= 1.41: 7 % (0.3 dB); of the contrast ~0.1.
    assert abs(10 * np.log10(p_rf.mean() / p.mean())) < 1.0
    assert abs(p_rf.std() / p_rf.mean() - expected) < 0.3
    # Psig reports each shot's own received power.
    assert np.std(rf["Psig"]) > 0


def _coupled(obstruction, target, beta_target=None):
    """Free-space bench with the coupling effect; focal length chosen to give ``beta_target``."""
    from chirplidar.optics import optimal_beta
    from chirplidar.optics.coupling import optimal_beta_monostatic

    d_tel, w0 = 0.2032, 4.6e-6  # Table 4.6 atm.D_tel; SMF-28 mode-field radius at 1310 nm
    if beta_target is None:
        beta_target = (optimal_beta_monostatic(obstruction) if target == "diffuse"
                       else optimal_beta(obstruction))
    focal = 0.5 * np.pi * d_tel * w0 / (WAVELENGTH_M * beta_target)
    return load_mission(CH5, ["atm.state=on", "atm.Pattn=0", "mzm.Vdc=2.0", _enable("coupling"),
                              f"effects.coupling.obstruction_ratio={obstruction}",
                              f"effects.coupling.focal_length_m={focal}",
                              "effects.coupling.mode_field_radius_m=4.6e-6",
                              "effects.coupling.fiber_numerical_aperture=0.14",  # SMF-28
                              f'effects.coupling.target="{target}"'])


def test_coupling_effect_diffuse_target_is_the_thesis_42_percent():
    # Thesis p. 59: "maximum theoretical coupling efficiency ... approximately 42%" = Winzer & Leeb
    # (1998) monostatic coupling of a diffuse target's speckle (0.4248, unobstructed, optimal beta).
    on = simulate_shot(_coupled(0.0, "diffuse"), tier="link")
    off = simulate_shot(load_mission(CH5, ["atm.state=on", "atm.Pattn=0", "mzm.Vdc=2.0"]),
                        tier="link")
    assert abs((on["Psig"] - off["Psig"]) - 10 * np.log10(0.42)) < 0.1


@pytest.mark.parametrize("obstruction", [0.0, 0.3])
def test_coupling_effect_specular_target_follows_ruilier(obstruction):
    # Plane-wave coupling with a central obstruction, closed form (Ruilier 1998):
    # eta = 2 [exp(-a^2 b^2) - exp(-b^2)]^2 / (b^2 (1 - a^2)), evaluated here at beta = 1.
    a, b = obstruction, 1.0
    eta = 2 * (np.exp(-a * a * b * b) - np.exp(-b * b)) ** 2 / (b * b * (1 - a * a))
    on = simulate_shot(_coupled(obstruction, "specular", beta_target=1.0), tier="link")
    off = simulate_shot(load_mission(CH5, ["atm.state=on", "atm.Pattn=0", "mzm.Vdc=2.0"]),
                        tier="link")
    assert abs((on["Psig"] - off["Psig"]) - 10 * np.log10(eta)) < 1e-6


def test_coupling_needs_free_space():
    from chirplidar import ConfigError

    with pytest.raises(ConfigError, match="free_space"):
        load_mission(CH5, [_enable("coupling"), "effects.coupling.obstruction_ratio=0",
                           "effects.coupling.focal_length_m=1", "effects.coupling.mode_field_radius_m=4.6e-6",
                           "effects.coupling.fiber_numerical_aperture=0.14",
                           'effects.coupling.target="diffuse"'])


def _turbulent(cn2, fading="mean", extra=()):
    # Free space over the Table 4.6 path (atm.dst = 1572 m), 8" telescope, beta = 1, specular
    # return (plane wave: the turbulent coupling is then exact, not scaled).
    d_tel, w0 = 0.2032, 4.6e-6
    focal = 0.5 * np.pi * d_tel * w0 / WAVELENGTH_M
    return load_mission(CH5, ["atm.state=on", "atm.Pattn=0", "mzm.Vdc=2.0", "atm.dst=1572",
                              "system.reference_delay_s=0", f"atm.Cn2={cn2}",
                              _enable("coupling", "turbulence"),
                              "effects.coupling.obstruction_ratio=0",
                              f"effects.coupling.focal_length_m={focal}",
                              "effects.coupling.mode_field_radius_m=4.6e-6",
                              "effects.coupling.fiber_numerical_aperture=0.14",
                              'effects.coupling.target="specular"',
                              f'effects.turbulence.fading="{fading}"',
                              "effects.turbulence.outer_scale_m=1e4", *extra])


def _cn2_for(d_over_r0, path_m=1572.0, d_tel=0.2032):
    # Invert the plane-wave Fried parameter r0 = (0.423 k^2 Cn2 L)^(-3/5) (Fried 1966).
    k = 2 * np.pi / WAVELENGTH_M
    return (d_tel / d_over_r0) ** (-5 / 3) / (0.423 * k * k * path_m)


def test_turbulence_effect_loss_is_the_mutual_coherence_coupling():
    # The chain's turbulent loss (a cached table, outer scale 1e4 m) against the direct
    # mutual-coherence integral <eta> = int C(d) exp(-D_phi(d)/2) (Kolmogorov, D_phi =
    # 6.88 (d/r0)^(5/3)), which tests/test_atmosphere.py checks against Monte Carlo screens.
    from chirplidar.atmosphere import turbulent_coupling_exact
    from chirplidar.optics import coupling_efficiency

    clear = simulate_shot(_turbulent(0.0), tier="link")["Psig"]
    for d_over_r0 in (0.3, 1.0, 3.0):
        loss_db = clear - simulate_shot(_turbulent(_cn2_for(d_over_r0)), tier="link")["Psig"]
        exact = turbulent_coupling_exact(d_over_r0, 1.0, 0.0)
        expected_db = -10 * np.log10(exact / coupling_efficiency(1.0, 0.0))
        # 3 %: the finite outer scale (L0 / D = 5e4) raises the coupling by up to 2.6 % at 3.
        assert abs(loss_db - expected_db) < 10 * np.log10(1.03), d_over_r0


def test_turbulence_frozen_flow_fading():
    cn2 = _cn2_for(3.0)
    still = _turbulent(cn2, "frozen_flow", ["effects.turbulence.transverse_speed_mps=0",
                                            "effects.turbulence.shot_interval_s=1e-4"])
    r = simulate_lab(still, "link", np.random.default_rng(2), batch=6)
    assert np.ptp(r["Psig"]) < 1e-9  # a screen that does not move: every shot sees the same phase
    moving = _turbulent(cn2, "frozen_flow", ["effects.turbulence.transverse_speed_mps=100",
                                             "effects.turbulence.shot_interval_s=1e-2"])
    r = simulate_lab(moving, "link", np.random.default_rng(2), batch=120)
    p = 10 ** (r["Psig"] / 10)
    mean = 10 ** (simulate_shot(_turbulent(cn2), tier="link")["Psig"] / 10)
    assert np.std(p) > 0.05 * np.mean(p)            # it fades
    assert abs(np.mean(p) / mean - 1) < 0.15        # around the mutual-coherence mean


def test_squaring_recovery_removes_the_doppler_range_error():
    # Appendix D: y^2 holds (1/4) cos(2 w_B t), which the Doppler shift does not move; with the
    # search above 2 x the largest Doppler (10 MHz, the thesis's example) the beat is f_R again.
    base = [_enable("doppler"), "effects.doppler.radial_velocity_mps=3"]  # f_d = 4.58 MHz
    plain = simulate_shot(_cfg(*base), seed=1)
    squared = simulate_shot(_cfg(*base, 'processing.doppler_recovery="squaring"',
                                 "processing.doppler_max_hz=10e6"), seed=1)
    still = simulate_shot(_cfg(), seed=1)
    bin_hz = 1 / 106e-6  # thesis_ch5_bench record
    assert abs(abs(plain["f_beat_hz"] - still["f_beat_hz"]) - 2 * 3 / WAVELENGTH_M) < bin_hz
    assert abs(squared["f_beat_hz"] - still["f_beat_hz"]) < bin_hz
    assert "squaring_recovery" in squared["flags"]
    with pytest.raises(ValueError, match="use --tier rf"):
        simulate_shot(_cfg(*base, 'processing.doppler_recovery="squaring"',
                           "processing.doppler_max_hz=10e6"), tier="link")


def test_speckle_decorrelates_as_the_footprint_moves():
    # Matched single-mode transceiver: rho = exp(-2 s^2 [1/W^2 + (pi W / (lambda R))^2])
    # (docs/targets.md); s = 0 repeats the speckle, s >> W forgets it, in between the lag-1
    # correlation of the power factors is rho (AR(1) field sequence, 4000 shots: SE ~0.02).
    from chirplidar.channel.effects import speckle_shot_correlation

    def returns(shift):
        cfg = _cfg(_enable("speckle"), "effects.speckle.cells=1",
                   f"effects.speckle.shift_per_shot_m={shift}")
        return cfg, channel_returns(cfg, 4000, np.random.default_rng(8))

    _, same = returns(0.0)
    assert np.ptp(same.power_factor) == 0 and np.ptp(same.phase_rad) == 0
    for shift in (5e-4, 1.0):
        cfg, r = returns(shift)
        rho = speckle_shot_correlation(cfg)
        lag1 = np.corrcoef(r.power_factor[:-1], r.power_factor[1:])[0, 1]
        assert abs(lag1 - rho) < 0.06, (shift, rho, lag1)
    assert speckle_shot_correlation(returns(1.0)[0]) < 1e-6
    # A genuinely partial case: 0.5 mm on this bench. With W = 4.5 m at R = 11.35 km the curvature
    # term dominates: 1/e decorrelation at s = lambda R / (sqrt(2) pi W) = 0.74 mm.
    assert 0.2 < speckle_shot_correlation(returns(5e-4)[0]) < 0.9


def test_fiber_acceptance_is_flagged():
    # SMF-28 NA 0.14: an f/1 cone (marginal ray 26.6 deg, sin = 0.45) overfills it; f/5 does not.
    ok = _coupled(0.0, "diffuse")  # optimal beta: f = 1.03 m, D/2f = 0.099 < 0.14
    assert "fiber_acceptance_exceeded" not in simulate_shot(ok, tier="link")["flags"]
    fast = _coupled(0.0, "diffuse", beta_target=5.0)  # f = 0.2 m: D/2f = 0.5
    assert "fiber_acceptance_exceeded" in simulate_shot(fast, tier="link")["flags"]
