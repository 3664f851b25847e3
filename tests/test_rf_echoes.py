"""Footprint echoes in the rf tier: the coherent sum of delayed sub-returns (sloped / rough terrain).

All runs use the thesis Chapter 5 bench (missions/thesis_ch5_bench.toml): 22 MHz beat of the
22.7 km spool (eq. 5.2), chirp rate kappa = 200 MHz / 40 us, group index 1.458.
"""

import numpy as np
import pytest

from chirplidar import load_mission
from chirplidar.channel import simulate_lab
from chirplidar.channel.lab import lab_budget
from chirplidar.tiers.echoes import Echoes
from chirplidar.units import SPEED_OF_LIGHT_M_S
from conftest import CH5

# Per-mode modulator bias of the Chapter 5 prototypes (as in test_validation.py): homodyne at the
# null (in the mission file), direct and heterodyne at V_pi / 2 (Fig. 2.10 left).
DIRECT = ["sys.rsel=PIN", "mzm.Vdc=1.0"]
HETERODYNE = ["sys.CxMode=het", "mzm.Vdc=1.0"]
# Statistics runs: 1.2 GS/s instead of 3 GS/s (2.5x fewer samples). The 22 MHz beat and its width
# do not depend on it: the single-echo d_3dB is 0.5407 m at both rates (measured).
FAST = ["sims.Fs=1.2e9"]
STRONG = ["atm.Pattn=30"]  # Psig ~ -42 dBm: SNR ~ 66 dB, the noise is negligible at the peak


def _run(overrides, batch=1, echoes=None, seed=3, spectrum=False):
    cfg = load_mission(CH5, overrides)
    return simulate_lab(cfg, "rf", np.random.default_rng(seed), batch=batch, keep_spectrum=spectrum,
                       echoes=echoes)


def _metres_per_hz(overrides):
    """Range per beat frequency, c / (2 n_g kappa) (eq. 2.3.1 with the group index)."""
    bud = lab_budget(load_mission(CH5, overrides))
    return SPEED_OF_LIGHT_M_S / (2 * bud.group_index * bud.rate_hz_per_s), bud


def _uniform_footprint(spread_m, k, group_index):
    """Delay offsets (s) of k cell-centred sub-rays over a range spread dR: as a ray caster samples
    a footprint, each echo stands for a cell of width dR / k, so the cells tile exactly dR."""
    offsets_m = ((np.arange(k) + 0.5) / k - 0.5) * spread_m
    return 2 * group_index * offsets_m / SPEED_OF_LIGHT_M_S


# ---- 1. one echo of offset 0, weight 1, phase 0 is the echo-free shot ----

@pytest.mark.parametrize("overrides", [
    [],                                                     # homodyne: fast path vs general path
    ["channel.carrier_phase=random"],
    ['effects.enabled=["speckle", "doppler"]', "effects.speckle.cells=1",
     "effects.doppler.radial_velocity_mps=0.5"] + STRONG,  # (speckle peaks would saturate)
    ["lsr.Lw=2e4", 'effects.enabled=["phase_noise"]'],    # Wiener phase noise (general path)
    ["transmitter.amplifier=true", "transmitter.amplifier_gain_db=20",
     "transmitter.amplifier_noise_figure_db=6", "atm.Pattn=40"],  # ASE, below saturation
    ["sys.CxMode=phase_diversity"],
    DIRECT,
    ["sys.rsel=APD", "mzm.Vdc=1.0"],
    HETERODYNE,
    HETERODYNE + ["heterodyne.demodulation=synchronous"],
])
def test_single_zero_echo_reproduces_the_echo_free_shot(overrides):
    # 1.2 GS/s except heterodyne, whose 1 GHz IF needs the mission's 3 GS/s.
    overrides = overrides if "sys.CxMode=het" in overrides else FAST + overrides
    base = _run(overrides, batch=2)
    one = _run(overrides, batch=2, echoes=Echoes([0.0], [1.0], [0.0]))
    # Same seed, no draws by the echoes: equal up to float rounding (the homodyne fast path mixes
    # cached products, the echo path computes |A| and arg A: ~1e-14 dB apart).
    for key in ("SNR", "Crx", "Navg"):
        np.testing.assert_allclose(one[key], base[key], rtol=0, atol=1e-9, err_msg=key)
    for key in ("d_rx", "d_3dB"):
        np.testing.assert_allclose(one[key], base[key], rtol=0, atol=1e-9, err_msg=key)
    assert one["flags"] == base["flags"]


def test_echo_phase_rotates_the_homodyne_quadrature():
    # Balanced homodyne reads 2 R Im(E_LO E_s*) (tiers.common.optimal_phase): an extra echo phase
    # phi scales the beat power by cos^2(phi): -3.01 dB at pi / 4 (measured -3.009 dB).
    p0 = _run(STRONG, echoes=Echoes([0.0], [1.0], [0.0]))["Crx"]
    p45 = _run(STRONG, echoes=Echoes([0.0], [1.0], [np.pi / 4]))["Crx"]
    assert abs((p45 - p0)[0] - 10 * np.log10(0.5)) < 0.01


def test_per_shot_offsets_shift_the_measured_range():
    # One echo per shot at its own extra delay dtau: d_rx moves by c dtau / (2 n_g) (eq. 2.3.1).
    # Tolerance 5 mm: at SNR ~ 66 dB the range noise is sub-mm; the estimator's bias is common to
    # all shots (shifts of 0.4 to 1.9 beat-peak widths; measured errors <= 0.6 mm).
    dtau = np.array([[0.0], [2e-9], [-3e-9], [10e-9]])
    out = _run(STRONG, batch=4, echoes=Echoes(dtau, np.ones((4, 1)), np.zeros((4, 1))))
    n_g = load_mission(CH5).channel.group_index
    shift = SPEED_OF_LIGHT_M_S * dtau[:, 0] / (2 * n_g)
    np.testing.assert_allclose(out["d_rx"] - out["d_rx"][0], shift, atol=5e-3)


# ---- 2. independent phases add echoes in power ----

def test_two_random_phase_echoes_add_incoherently():
    """E|sum_k sqrt(w_k) e^{j phi_k} X_k|^2 = sum_k w_k |X_k|^2 for independent uniform phi_k.

    Balanced homodyne detects one quadrature: a single echo of phase phi gives cos^2(phi) |X|^2,
    whose mean over phi is 1/2 (the factor 2 of eq. 2.6.2, see test_validation). So the mean
    spectrum of 64 shots must equal (1/2) [w1 S0(f) + w2 S0(f - kappa dtau2)], S0 the echo-free
    spectrum at the optimal phase. The echoes are 3 FFT bins apart (0.58 m, about one d_3dB), so
    their lines overlap and a coherent sum would differ.
    """
    over = FAST + STRONG
    batch, shift_bins = 64, 3
    _, bud = _metres_per_hz(over)
    cfg = load_mission(CH5, over)
    df = 1.0 / cfg.simulation.duration_s                      # native bin, zero_pad_factor = 1
    dtau2 = shift_bins * df / bud.rate_hz_per_s               # kappa dtau2 = 3 bins exactly
    w = np.array([0.7, 0.3])
    phases = np.random.default_rng(42).uniform(0, 2 * np.pi, (batch, 2))
    two = _run(over, batch=batch, spectrum=True, seed=8,
               echoes=Echoes([0.0, dtau2], w, phases))["spectrum"]
    ref = _run(over, batch=8, spectrum=True, seed=9)["spectrum"]
    s0 = ref["psd_w_per_hz"].mean(axis=0) - ref["noise_psd_w_per_hz"].mean()
    expected = 0.5 * w[0] * s0
    expected[shift_bins:] += 0.5 * w[1] * s0[:-shift_bins]
    shots = two["psd_w_per_hz"] - two["noise_psd_w_per_hz"][:, None]
    window = expected >= 1e-2 * expected.max()               # both lines, down to -20 dB
    mean = shots[:, window].mean(axis=0)
    se = shots[:, window].std(axis=0, ddof=1) / np.sqrt(batch)
    z = (mean - expected[window]) / se
    # Per-bin z-scores of the mean of 64 shots: |z| < 5 (15 bins; the per-shot values are skewed,
    # so 5 rather than a Gaussian 4; measured max |z| = 1.2, power ratio 0.91 +- 0.067).
    assert window.sum() >= 6 and np.max(np.abs(z)) < 5.0, z
    total = shots[:, window].sum(axis=1)
    ratio = total.mean() / expected[window].sum()
    assert abs(ratio - 1) < 4 * total.std(ddof=1) / np.sqrt(batch) / expected[window].sum(), ratio
    # The peak sits between the lines, nearer the 0.7 one (bins of the echo-free beat and +3).
    k0 = int(np.argmax(s0))
    assert k0 <= int(np.argmax(shots.mean(axis=0))) <= k0 + shift_bins
    # Control: the same echoes with one common phase pi / 4 (cos^2 = 1/2, so the same mean
    # level) add coherently; where the lines overlap they fall outside the tolerance (measured
    # max |z| = 7.5): the check above distinguishes power from field addition.
    fixed = _run(over, batch=1, spectrum=True, seed=8,
                 echoes=Echoes([0.0, dtau2], w, [np.pi / 4, np.pi / 4]))["spectrum"]
    z_fixed = (fixed["psd_w_per_hz"][0, window] - fixed["noise_psd_w_per_hz"][0]
               - expected[window]) / se
    assert np.max(np.abs(z_fixed)) > 5.0, z_fixed


# ---- 3. a sloped footprint broadens the beat ----

def _fwhm_m(f_hz, psd, m_per_hz):
    """3 dB width (m) of the highest peak of a spectrum: linear interpolation of the crossings."""
    i = int(np.argmax(psd))
    half = 0.5 * psd[i]
    lo = i
    while psd[lo - 1] >= half:
        lo -= 1
    hi = i
    while psd[hi + 1] >= half:
        hi += 1
    f_lo = f_hz[lo - 1] + (half - psd[lo - 1]) / (psd[lo] - psd[lo - 1]) * (f_hz[lo] - f_hz[lo - 1])
    f_hi = f_hz[hi] + (psd[hi] - half) / (psd[hi] - psd[hi + 1]) * (f_hz[hi + 1] - f_hz[hi])
    return (f_hi - f_lo) * m_per_hz


def test_sloped_footprint_broadens_the_beat():
    """19 sub-rays of equal weight and independent phases over a range spread dR = tan(slope) x
    footprint diameter. The beat frequencies span kappa dtau_span, i.e. dR in range units, so the
    shot-averaged spectrum is the single-echo line convolved with a rect of width dR: its 3 dB
    width is the single-echo d_3dB for dR = 0 and tends to dR for dR >> d_3dB.

    A single shot does not: its spectrum is a speckle pattern over dR whose grains are one
    resolution cell wide, and d_3dB reads the highest grain. Its mean grows with dR by ~30 %
    (measured 0.54, 0.67, 0.71 m for dR = 0, 2, 6 m) and saturates far below dR.
    """
    over = FAST + STRONG
    batch, k = 64, 19
    m_per_hz, bud = _metres_per_hz(over)
    single = _run(over, batch=2)["d_3dB"].mean()           # 0.5407 m (echo-free shot)
    # Footprint 10.4 m across on a 30 degree slope: dR = tan(30 deg) x 10.4 m = 6.0 m.
    spreads = [0.0, 2.0, np.tan(np.radians(30.0)) * 10.4]
    widths, per_shot = [], []
    for i, spread in enumerate(spreads):
        phases = np.random.default_rng(100 + i).uniform(0, 2 * np.pi, (batch, k))
        echoes = Echoes(_uniform_footprint(spread, k, bud.group_index), np.ones(k), phases)
        out = _run(over, batch=batch, spectrum=True, seed=20 + i, echoes=echoes)
        sp = out["spectrum"]
        widths.append(_fwhm_m(sp["f_hz"], sp["psd_w_per_hz"].mean(axis=0), m_per_hz))
        per_shot.append(out["d_3dB"].mean())
    # No spread: 19 echoes at one delay are one echo of random amplitude, the width is unchanged
    # (tight: at SNR ~ 60 dB the dtft width scatters by ~2 mm per shot).
    assert abs(per_shot[0] - single) < 0.01 * single, (per_shot[0], single)
    assert np.all(np.diff(widths) > 0), widths
    # dR = 6 m ~ 11 x d_3dB: within 10 % of dR. The width is read at half the mean spectrum's
    # maximum; the 64-shot mean still ripples by ~1/sqrt(64) = 12 % over its ~11 speckle grains,
    # and the highest ripple lifts the half level: a bias of a few % low (measured 5.90 m,
    # -1.7 %).
    assert abs(widths[-1] - spreads[-1]) < 0.10 * spreads[-1], widths
    # Per shot: broader than a point target (+4 standard errors of the 64-shot mean, ~0.03 m),
    # far below dR (speckle-limited).
    assert 1.05 * single < per_shot[-1] < 0.25 * spreads[-1], per_shot


# ---- 4. every receiver mode takes echoes; validation ----

@pytest.mark.parametrize("overrides", [DIRECT, HETERODYNE, ["sys.CxMode=phase_diversity"],
                                       ["lsr.Lw=2e4", 'effects.enabled=["phase_noise"]']])
def test_other_receivers_take_echoes(overrides):
    _, bud = _metres_per_hz(overrides)
    k = 7
    rng = np.random.default_rng(1)
    echoes = Echoes(_uniform_footprint(1.0, k, bud.group_index)[None, :] + rng.normal(0, 1e-10, (2, k)),
                    rng.uniform(0.5, 1.0, (2, k)), rng.uniform(0, 2 * np.pi, (2, k)))
    out = _run(overrides + ["atm.Pattn=20"], batch=2, echoes=echoes)
    assert np.all(np.isfinite(out["SNR"])) and np.all(out["SNR"] > 10), out["SNR"]
    assert np.all(np.abs(out["d_error"]) < 2.0), out["d_error"]


def test_echoes_validation():
    ok = {"delay_offset_s": [0.0, 1e-9], "power_weight": [1.0, 1.0], "phase_rad": [0.0, 0.0]}
    with pytest.raises(ValueError, match=r"echoes\.delay_offset_s must have shape \(batch, k\)"):
        Echoes(**{**ok, "delay_offset_s": np.zeros((2, 2, 2))})
    with pytest.raises(ValueError, match="echoes.phase_rad must have shape"):
        Echoes(**{**ok, "phase_rad": []})
    with pytest.raises(ValueError, match="number of echoes k"):
        Echoes(**{**ok, "phase_rad": [0.0, 0.0, 0.0]})
    with pytest.raises(ValueError, match="must share batch"):
        Echoes(**{**ok, "phase_rad": np.zeros((3, 2)), "power_weight": np.ones((4, 2))})
    with pytest.raises(ValueError, match="echoes.power_weight must be >= 0"):
        Echoes(**{**ok, "power_weight": [1.0, -0.1]})
    with pytest.raises(ValueError, match="positive sum for every shot"):
        Echoes(**{**ok, "power_weight": [[1.0, 0.0], [0.0, 0.0]]})
    with pytest.raises(ValueError, match="echoes.delay_offset_s must be finite"):
        Echoes(**{**ok, "delay_offset_s": [0.0, np.nan]})
    with pytest.raises(ValueError, match="echoes.phase_rad must be finite"):
        Echoes(**{**ok, "phase_rad": [0.0, np.inf]})
    with pytest.raises(ValueError, match="echoes.power_weight must be a real array"):
        Echoes(**{**ok, "power_weight": ["a", "b"]})
    cfg = load_mission(CH5)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"echoes\.phase_rad must have shape \(batch, k\) = \(2, 2\)"):
        simulate_lab(cfg, "rf", rng, batch=2, echoes=Echoes(**{**ok, "phase_rad": np.zeros((3, 2))}))
    with pytest.raises(ValueError, match="echoes must be a chirplidar.tiers.echoes.Echoes"):
        simulate_lab(cfg, "rf", rng, echoes=ok)


def test_echoes_are_copied_and_normalised():
    w = np.array([[2.0, 6.0]])
    e = Echoes(np.zeros(2), w, np.zeros(2))
    w[0, 0] = 100.0                                  # the caller's array is not aliased
    offsets, weights, phases = e.for_batch(1)
    np.testing.assert_array_equal(weights, [[0.25, 0.75]])
    assert offsets.shape == phases.shape == (1, 2) and e.k == 2
    with pytest.raises(ValueError):
        e.power_weight[0, 0] = 1.0                   # read-only
