"""Doppler compensation in the combining DSP (issue 18, ``processing.doppler_recovery = "dsp"``).

Physics (thesis Appendices C and D): the phase-diversity (I/Q) arms read 2 Re(c_j Y), Y = E_LO E_s*
= C(t) exp(j (2 pi f_d t + phi)) with C real holding the beat at f_R: the complex record has lines
at f_d +- f_R. The DSP estimates f_d per shot (their centre of symmetry), removes it and reads f_R
off the folded spectrum. Without it the real record's lines at |f_R +- f_d| put the range off by
c f_d / (2 n kappa) (closed form: d = c f / (2 n kappa) for a beat f, group index n, chirp rate
kappa). Appendix D's squaring reads 2 f_R off y^2 instead, at a noise penalty.

Acceptance (issue 18): with the DSP compensation the range error under a Doppler shift up to the
beat's band stays within 1.5x the zero-Doppler error. Monte Carlo: RMS of d_error over 300 shots
per shift, its standard error by the delta method, SE(RMS) = std(e^2) / (2 RMS sqrt(n)); each shift
has its own seed (independent draws), and the bound is asserted with 3 SE to spare.

Bench: the Chapter 5 bench (missions/thesis_ch5_bench.toml: f_R = 22.0 MHz, kappa = 5.0 MHz/us,
fiber group index 1.458), 60 dB attenuation, the phase-diversity hybrid of Appendix C. Its
unbalanced arms also detect the LO's own power (the chirp envelope, 105 dB above the noise floor at
DC, 37 dB at 1 MHz, 10 dB at 3 MHz on this bench): Appendix C band-passes it out, so the processed
band starts at 3 MHz here (processing.highpass_hz) and the beat is read up to the chirp's start
frequency, 100 MHz (the default peak_search_max_hz of phase diversity).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from chirplidar import cli, load_mission
from chirplidar.channel import simulate_lab
from chirplidar.channel.lab import lab_budget
from chirplidar.receiver import HYBRID_90
from chirplidar.tiers.records import arms_to_complex, dsp_compensated_arms
from chirplidar.units import SPEED_OF_LIGHT_M_S
from conftest import CH5

WAVELENGTH_M = 1.31e-6  # thesis Table 4.4 lsr.Lo
BASE = ["atm.Pattn=60", "processing.highpass_hz=3e6"]
PD = ['system.coherent_mode="phase_diversity"']
#: Doppler shifts [Hz]: below f_R (where squaring also works), beyond it, and up to where the
#: upper line f_d + f_R (92 MHz) is still inside the 100 MHz processed band.
SHIFTS_HZ = (5e6, 15e6, 40e6, 70e6)
SHOTS = 300


def _cfg(*extra, f_d_hz: float = 0.0, mode=PD):
    v = f_d_hz * WAVELENGTH_M / 2  # eq. 2.2.5: f_d = 2 v / lambda
    dop = ['effects.enabled=["doppler"]', f"effects.doppler.radial_velocity_mps={v!r}"]
    return load_mission(CH5, [*BASE, *mode, *(dop if f_d_hz else []), *extra])


def _rms(e) -> tuple[float, float]:
    """RMS of ``e`` and its standard error (delta method on the mean of e^2)."""
    e2 = np.asarray(e, float) ** 2
    rms = float(np.sqrt(e2.mean()))
    return rms, float(e2.std(ddof=1) / (2 * rms * np.sqrt(e2.size)))


def _run(cfg, tier: str, seed: int, shots: int):
    return simulate_lab(cfg, tier, np.random.default_rng(seed), batch=shots)


def _offset_m(cfg, f_d_hz: float) -> float:
    """Closed form: the range error of a line f_d off the beat, c f_d / (2 n kappa)."""
    kappa = lab_budget(cfg).rate_hz_per_s
    return SPEED_OF_LIGHT_M_S * f_d_hz / (2 * cfg.channel.group_index * kappa)


# --- the DSP on synthetic arms -------------------------------------------------------------------


def _cross():
    r = (0.95, 0.9)  # unequal responsivities: the inversion must use each arm's own c_j
    return tuple(r[j] * HYBRID_90[j, 0] * np.conj(HYBRID_90[j, 1]) for j in (0, 1))


def test_arms_invert_to_the_complex_record():
    # Definition: x_j = 2 Re(c_j Y) for any complex Y; the 90-degree hybrid's arms determine Y.
    rng = np.random.default_rng(3)
    y = rng.standard_normal((2, 3, 64)) + 1j * rng.standard_normal((2, 3, 64))
    c = _cross()
    x1, x2 = (2 * np.real(cj * y) for cj in c)
    np.testing.assert_allclose(arms_to_complex(x1, x2, c), y, rtol=0, atol=1e-12)
    # A balanced 3 dB pair reads one quadrature twice (c2 = -c1): refused, not inverted.
    with pytest.raises(ValueError, match="same quadrature"):
        arms_to_complex(x1, x2, (c[0], -c[0]))


@pytest.mark.parametrize("f_d_hz", [-31.3e6, 7.7e6, 55.1e6])
def test_dsp_removes_a_known_shift_from_synthetic_arms(f_d_hz):
    # Y = C(t) exp(j 2 pi f_d t) with C = cos(2 pi f_R t) (Appendix D) plus white noise in each
    # arm (per-bin SNR of each line ~ 40 dB): the estimate is the true f_d within a tenth of the
    # 1 / T bin (the folded line would split beyond ~1 bin), and the compensated arms' summed
    # spectrum peaks at f_R, within one bin, in every record.
    fs, n, f_r = 250e6, 4096, 22.0e6
    t = np.arange(n) / fs
    rng = np.random.default_rng(11)
    c = _cross()
    y = np.cos(2 * np.pi * f_r * t) * np.exp(1j * (2 * np.pi * f_d_hz * t + 0.4))
    y = np.broadcast_to(y, (4, 2, n))
    arms = {k: 2 * np.real(c[j] * y) + 0.3 * rng.standard_normal(y.shape)
            for j, k in enumerate(("arm1", "arm2"))}
    out, est = dsp_compensated_arms(arms, c, fs, (3e6, 100e6), None)
    assert np.all(np.abs(est - f_d_hz) < 0.1 * fs / n), est
    spec = sum(np.abs(np.fft.rfft(out[k], axis=-1)) ** 2 for k in out).sum(axis=1)
    peak = np.argmax(spec, axis=-1) * fs / n
    assert np.all(np.abs(peak - f_r) <= fs / n), peak


# --- acceptance on the baseband tier --------------------------------------------------------------


def test_dsp_keeps_the_zero_doppler_range_error_up_to_the_band():
    t0 = time.perf_counter()
    ref = _run(_cfg(), "baseband", 1, SHOTS)  # the same receiver without Doppler or the DSP
    r0, se0 = _rms(ref["d_error"])
    rows = [("none", 0.0, r0, se0, float(np.mean(ref["SNR"])))]
    for i, f_d in enumerate((0.0, *SHIFTS_HZ)):
        out = _run(_cfg('processing.doppler_recovery="dsp"', f_d_hz=f_d), "baseband", 2 + i, SHOTS)
        assert not out["flags"], out["flags"]  # in band: neither ambiguous nor unlocked
        rms, se = _rms(out["d_error"])
        rows.append(("dsp", f_d, rms, se, float(np.mean(out["SNR"]))))
        ratio = rms / r0
        ratio_se = ratio * np.hypot(se / rms, se0 / r0)
        # Acceptance: within 1.5x the zero-Doppler error, with 3 standard errors to spare.
        assert ratio + 3 * ratio_se <= 1.5, (f_d, ratio, ratio_se)
        # No Doppler bias left: the mean error is that of the zero-Doppler shots within 3 SE
        # (each mean's SE is its std / sqrt(n)).
        mean_se = np.hypot(np.std(out["d_error"]), np.std(ref["d_error"])) / np.sqrt(SHOTS)
        assert abs(np.mean(out["d_error"]) - np.mean(ref["d_error"])) <= 3 * mean_se, f_d
    for rec, f_d, rms, se, snr in rows:
        print(f"baseband {rec:5s} f_d = {f_d / 1e6:5.1f} MHz: RMS d_error {rms * 1e3:6.2f} "
              f"+- {se * 1e3:4.2f} mm (x{rms / r0:4.2f}), mean SNR {snr:5.2f} dB")
    print(f"({time.perf_counter() - t0:.1f} s)")


def test_without_recovery_the_error_is_the_doppler_offset():
    # The same shifts below f_R without the DSP: the peak is one of |f_R +- f_d| (Appendix D), so
    # every shot is off by +- c f_d / (2 n kappa); its RMS is that offset (the zero-Doppler scatter,
    # ~2 cm, adds in quadrature: < 1e-4 relative at 100 m). Shows the acceptance test can fail.
    for i, f_d in enumerate(SHIFTS_HZ[:2]):
        cfg = _cfg(f_d_hz=f_d)
        out = _run(cfg, "baseband", 20 + i, 40)
        rms, _ = _rms(out["d_error"])
        print(f"baseband none  f_d = {f_d / 1e6:5.1f} MHz: RMS d_error {rms:8.3f} m, "
              f"closed form {_offset_m(cfg, f_d):8.3f} m")
        assert rms == pytest.approx(_offset_m(cfg, f_d), rel=1e-3)


def test_squaring_also_removes_the_offset_at_an_snr_penalty():
    # Appendix D's squaring (rf tier, balanced homodyne) at the shifts below f_R, searching above
    # 2 x 20 MHz (doppler_max_hz) for 2 f_R = 44 MHz: the mean error is the zero-Doppler one
    # within 3 SE (no Doppler bias). Its RMS against the homodyne's own zero-Doppler RMS and the
    # squared record's SNR are reported, not asserted: the squaring's penalty grows as the noise
    # beats with itself (Appendix D: "the noise level will be raised").
    shots = 60
    ref = _run(_cfg(mode=[]), "rf", 30, shots)
    r0, se0 = _rms(ref["d_error"])
    snr0 = float(np.mean(ref["SNR"]))
    print(f"rf homodyne none f_d = 0: RMS d_error {r0 * 1e3:.2f} +- {se0 * 1e3:.2f} mm, "
          f"SNR {snr0:.2f} dB")
    sq = ['processing.doppler_recovery="squaring"', "processing.doppler_max_hz=20e6"]
    for i, f_d in enumerate((0.0, *SHIFTS_HZ[:2])):
        out = _run(_cfg(*sq, f_d_hz=f_d, mode=[]), "rf", 31 + i, shots)
        assert "squaring_recovery" in out["flags"]
        rms, se = _rms(out["d_error"])
        mean_se = np.hypot(np.std(out["d_error"]), np.std(ref["d_error"])) / np.sqrt(shots)
        assert abs(np.mean(out["d_error"]) - np.mean(ref["d_error"])) <= 3 * mean_se, f_d
        assert rms < 0.01 * _offset_m(_cfg(mode=[]), 5e6)  # far below the uncompensated offset
        print(f"rf squaring f_d = {f_d / 1e6:5.1f} MHz: RMS d_error {rms * 1e3:6.2f} +- "
              f"{se * 1e3:4.2f} mm (x{rms / r0:4.2f}), SNR of y^2 {np.mean(out['SNR']):5.2f} dB "
              f"({np.mean(out['SNR']) - snr0:+.2f} dB)")


def test_rf_tier_compensates_the_same_way():
    # The rf tier's full-rate arms also hold the LO's own terms at and above the chirp's start
    # frequency; the DSP's band-pass keeps them out. A shift beyond f_R (40 MHz, where
    # squaring cannot work), 24 shots (an rf shot with the DSP costs ~0.25 s): the mean error is
    # the zero-Doppler one within 3 SE and the RMS ratio is consistent with the acceptance bound
    # (ratio - 3 SE <= 1.5; SE of a 24-shot RMS ~ 15 %: the baseband test above is the precise
    # one; 150-shot rf runs measured 1.00 and 1.06).
    shots = 24
    ref = _run(_cfg(), "rf", 40, shots)
    out = _run(_cfg('processing.doppler_recovery="dsp"', f_d_hz=40e6), "rf", 41, shots)
    r0, se0 = _rms(ref["d_error"])
    rms, se = _rms(out["d_error"])
    ratio = rms / r0
    ratio_se = ratio * np.hypot(se / rms, se0 / r0)
    print(f"rf phase diversity: RMS d_error {r0 * 1e3:.2f} mm (none, f_d = 0), "
          f"{rms * 1e3:.2f} mm (dsp, f_d = 40 MHz): x{ratio:.2f} +- {ratio_se:.2f}")
    mean_se = np.hypot(np.std(out["d_error"]), np.std(ref["d_error"])) / np.sqrt(shots)
    assert abs(np.mean(out["d_error"]) - np.mean(ref["d_error"])) <= 3 * mean_se
    assert ratio - 3 * ratio_se <= 1.5


# --- the link tier --------------------------------------------------------------------------------


def test_link_tier_reads_the_zero_doppler_shot():
    # With the DSP the link tier's shot is the zero-Doppler one (same SNR, the beat drawn about
    # f_R): the same seed gives the same outputs. Its scatter is the Cramer-Rao spread of a tone of
    # the overlap duration (Rife & Boorstyn 1974: sigma_f = sqrt(6 / (SNR B T)) / (2 pi T)),
    # within 3 SE of a standard deviation (SE = sigma / sqrt(2 n)).
    shots = 2000
    dsp = 'processing.doppler_recovery="dsp"'
    still = _run(_cfg(dsp), "link", 5, shots)
    for f_d in (*SHIFTS_HZ, -40e6):
        moving = _run(_cfg(dsp, f_d_hz=f_d), "link", 5, shots)
        for key in ("SNR", "d_error", "f_beat_hz"):
            np.testing.assert_array_equal(moving[key], still[key])
        assert not moving["flags"]
    cfg = _cfg(dsp)
    snr = 10 ** (still["SNR"][0] / 10)
    t_ov = still["t_overlap_s"][0]
    sigma_f = np.sqrt(6 / (snr * cfg.processing.rbw_hz * t_ov)) / (2 * np.pi * t_ov)
    sigma_d = _offset_m(cfg, sigma_f)
    assert abs(np.std(still["d_error"]) / sigma_d - 1) <= 3 / np.sqrt(2 * shots)
    # Without the DSP the line splits (a quarter of the power per arm) and the range moves by
    # the closed-form offset.
    plain = _run(_cfg(f_d_hz=5e6), "link", 5, shots)
    assert np.mean(plain["SNR"]) < np.mean(still["SNR"]) - 3.0
    assert _rms(plain["d_error"])[0] == pytest.approx(_offset_m(cfg, 5e6), rel=1e-2)


@pytest.mark.parametrize("tier", ["link", "baseband"])
def test_a_shift_beyond_the_band_is_flagged(tier):
    # f_d + f_R = 107 MHz lies above the 100 MHz processed band: the upper line is filtered out
    # and the estimate has no pair to centre on. No doppler_ambiguous: the complex record keeps
    # the sign of f_d beyond f_R.
    out = _run(_cfg('processing.doppler_recovery="dsp"', f_d_hz=85e6), tier, 1, 2)
    assert "doppler_beyond_dsp_band" in out["flags"]
    assert "doppler_ambiguous" not in out["flags"]


def test_dsp_without_phase_diversity_is_one_line(capsys):
    argv = ["shot", str(CH5), "--tier", "baseband", "--json",
            "--set", 'processing.doppler_recovery="dsp"']
    code = cli.main(argv)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith("chirplidar shot: ")
    assert "processing.doppler_recovery = 'dsp'" in lines[0]
    assert "system.coherent_mode = 'phase_diversity'" in lines[0]
