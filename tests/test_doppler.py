"""Doppler shift, line-of-sight velocity, homodyne lines and squaring recovery (thesis App. D)."""

import numpy as np
import pytest

from chirplidar.doppler import (
    OMEGA_EARTH_RAD_S,
    WGS84_A_M,
    DopplerLines,
    doppler_shift_hz,
    earth_rotation_velocity_mps,
    homodyne_doppler_spectrum_lines,
    line_of_sight_velocity_mps,
    squaring_recovery,
)


def test_doppler_shift_closed_form():
    # Thesis eq. 2.2.5, f_d = 2 v / lambda: 1 m/s at 1310 nm -> 1.5267 MHz.
    assert doppler_shift_hz(1.0, 1310e-9) == pytest.approx(2.0 / 1310e-9, rel=1e-15)
    assert doppler_shift_hz(1.0, 1310e-9) == pytest.approx(1.5267e6, abs=50.0)
    # App. D: a 10 MHz Doppler bandwidth corresponds to about 13 m/s at 1310 nm.
    assert doppler_shift_hz(13.0, 1310e-9) == pytest.approx(19.85e6, rel=1e-3)
    assert doppler_shift_hz(0.0, 1310e-9) == 0.0
    assert doppler_shift_hz(-2.0, 1550e-9) < 0                   # opening range: negative
    np.testing.assert_allclose(doppler_shift_hz(np.array([0.5, 1.0]), 1064e-9),
                               [0.5 * 2 / 1064e-9, 2 / 1064e-9])
    with pytest.raises(ValueError, match="wavelength_m"):
        doppler_shift_hz(1.0, 0.0)
    with pytest.raises(ValueError, match="velocity_mps"):
        doppler_shift_hz(np.nan, 1310e-9)


def test_line_of_sight_nadir_and_tilted():
    v = np.array([50.0, 0.0, 0.0])                               # horizontal, along +x (east)
    nadir = np.array([0.0, 0.0, -1.0])                           # local ENU, z up
    assert line_of_sight_velocity_mps(v, nadir) == 0.0
    phi = np.deg2rad(20.0)
    forward = np.array([np.sin(phi), 0.0, -np.cos(phi)])
    assert line_of_sight_velocity_mps(v, forward) == pytest.approx(50.0 * np.sin(phi), rel=1e-15)
    backward = np.array([-np.sin(phi), 0.0, -np.cos(phi)])
    assert line_of_sight_velocity_mps(v, backward) == pytest.approx(-50.0 * np.sin(phi))


def test_line_of_sight_vectorised_over_shots_and_target_motion():
    n = 5
    phi = np.deg2rad(np.linspace(0, 40, n))
    u = np.column_stack([np.sin(phi), np.zeros(n), -np.cos(phi)])
    vp = np.tile([30.0, 0.0, -1.0], (n, 1))
    vt = np.array([0.0, 0.0, 0.5])                               # target rising 0.5 m/s
    got = line_of_sight_velocity_mps(vp, u, target_velocity_mps=vt)
    expected = 30.0 * np.sin(phi) + 1.5 * np.cos(phi)            # descending onto a rising target
    np.testing.assert_allclose(got, expected, rtol=1e-14)
    assert got.shape == (n,)


def test_line_of_sight_validation():
    v = np.array([1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="pointing_unit"):
        line_of_sight_velocity_mps(v, np.array([0.0, 0.0, -2.0]))
    with pytest.raises(ValueError, match="shape"):
        line_of_sight_velocity_mps(np.array([1.0, 0.0]), np.array([0.0, 0.0, -1.0]))
    with pytest.raises(ValueError, match="position_m"):
        line_of_sight_velocity_mps(v, np.array([0.0, 0.0, -1.0]), earth_rotation=True)
    with pytest.raises(ValueError, match="earth_rotation"):
        line_of_sight_velocity_mps(v, np.array([0.0, 0.0, -1.0]), position_m=np.ones(3))


def test_earth_rotation_at_the_equator():
    # A point on the equator moves east at omega_E a = 465.10 m/s (WGS 84 omega and a).
    r = np.array([WGS84_A_M, 0.0, 0.0])
    v = earth_rotation_velocity_mps(r)
    np.testing.assert_allclose(v, [0.0, OMEGA_EARTH_RAD_S * WGS84_A_M, 0.0], atol=1e-12)
    assert v[1] == pytest.approx(465.10, abs=0.01)
    # An inertial observer at rest, west of the target and looking east along the equator,
    # sees it recede at 465.1 m/s: closing velocity -465.1 m/s.
    east = np.array([0.0, 1.0, 0.0])
    los = line_of_sight_velocity_mps(np.zeros(3), east, earth_rotation=True, position_m=r)
    assert los == pytest.approx(-465.10, abs=0.01)
    # Looking straight down at the pole there is nothing to see of the rotation.
    pole = np.array([0.0, 0.0, 6356752.3])
    assert line_of_sight_velocity_mps(np.zeros(3), np.array([0.0, 0.0, -1.0]), earth_rotation=True,
                                      position_m=pole) == 0.0


def test_homodyne_lines_and_ambiguity_flag():
    lines = homodyne_doppler_spectrum_lines(100e6, 10e6)
    assert isinstance(lines, DopplerLines)
    assert (lines.lower_hz, lines.upper_hz, lines.ambiguous) == (90e6, 110e6, False)
    assert homodyne_doppler_spectrum_lines(100e6, -10e6) == lines   # the sign is not observable
    # Doppler beyond the beat (App. D: must stay below omega_B): the lower line folds and the
    # pair looks like a beat at f_d with Doppler f_R.
    folded = homodyne_doppler_spectrum_lines(100e6, 150e6)
    assert (folded.lower_hz, folded.upper_hz, folded.ambiguous) == (50e6, 250e6, True)
    assert homodyne_doppler_spectrum_lines(100e6, 100e6).ambiguous
    zero = homodyne_doppler_spectrum_lines(100e6, 0.0)
    assert (zero.lower_hz, zero.upper_hz, zero.ambiguous) == (100e6, 100e6, False)
    arr = homodyne_doppler_spectrum_lines(np.array([50e6, 100e6]), 60e6)
    np.testing.assert_array_equal(arr.ambiguous, [True, False])
    with pytest.raises(ValueError, match="f_beat_hz"):
        homodyne_doppler_spectrum_lines(-1.0, 0.0)


# A record on exact FFT bins: fs = 1.024 GS/s, 2^16 samples, 15.625 kHz bins.
FS = 1.024e9
N = 2**16
F_R = 100e6
T = np.arange(N) / FS


def _peak_hz(freqs, power, fmin):
    band = freqs > fmin
    return freqs[band][np.argmax(power[band])]


def _raw_power(y):
    spec = np.fft.rfft(y) / y.size
    return np.fft.rfftfreq(y.size, 1 / FS), 2 * np.abs(spec) ** 2


def test_constant_doppler_lines_and_squared_line():
    f_d = 5e6
    y = np.cos(2 * np.pi * f_d * T) * np.cos(2 * np.pi * F_R * T)
    freqs, raw = _raw_power(y)
    lines = homodyne_doppler_spectrum_lines(F_R, f_d)
    top2 = np.sort(freqs[np.argsort(raw)[-2:]])
    np.testing.assert_allclose(top2, [lines.lower_hz, lines.upper_hz])
    assert raw[np.argmin(np.abs(freqs - F_R))] < 1e-20               # nothing at f_R itself
    sq = squaring_recovery(y, FS)
    np.testing.assert_array_equal(sq.squared, y**2)
    k = lambda f: np.argmin(np.abs(sq.freqs_hz - f))
    # y^2 = 1/4 [1 + cos 2wd t + cos 2wB t + 1/2 cos 2(wB-wd)t + 1/2 cos 2(wB+wd)t] (App. D,
    # expanded directly): a tone A cos reads A^2/2.
    assert sq.power[k(2 * F_R)] == pytest.approx((1 / 4) ** 2 / 2, rel=1e-9)
    assert sq.power[k(2 * (F_R + f_d))] == pytest.approx((1 / 8) ** 2 / 2, rel=1e-9)
    assert sq.power[k(2 * f_d)] == pytest.approx((1 / 4) ** 2 / 2, rel=1e-9)
    assert sq.power[0] == pytest.approx((1 / 4) ** 2, rel=1e-9)


def test_squaring_recovers_the_beat_under_random_doppler():
    # App. D: Doppler that changes randomly with time spreads the raw beat, but the squared
    # record keeps a line at 2 f_R. f_d random per block of 4096 samples, 2-10 MHz, either sign.
    rng = np.random.default_rng(8)
    blocks = N // 4096
    f_d = rng.uniform(2e6, 10e6, blocks) * rng.choice([-1.0, 1.0], blocks)
    inst = np.repeat(f_d, 4096)
    phase = 2 * np.pi * np.cumsum(inst) / FS + rng.uniform(0, 2 * np.pi)
    y = np.cos(phase) * np.cos(2 * np.pi * F_R * T)
    freqs, raw = _raw_power(y)
    f_raw = _peak_hz(freqs, raw, 1e6)
    assert 2e6 - 0.5e6 <= abs(f_raw - F_R) <= 10e6 + 0.5e6          # a Doppler line f_R +- f_d
    assert raw[np.argmin(np.abs(freqs - F_R))] < 1e-3 * raw.max()
    sq = squaring_recovery(y, FS)
    f_sq = _peak_hz(sq.freqs_hz, sq.power, 4 * 10e6 + 5e6)          # above the 2 f_d baseband
    assert f_sq == 2 * F_R
    # The 1/4 cos(2 w_B t) line keeps its full power 1/32 (up to leakage of the per-block
    # Doppler sidebands into that bin).
    assert sq.power[np.argmin(np.abs(sq.freqs_hz - 2 * F_R))] == pytest.approx(1 / 32, rel=0.01)


def test_squaring_raises_the_noise_level():
    # App. D: "the noise level will be raised". Same Doppler-free tone in white noise: the SNR of
    # the 2 f_R line of y^2 is below the SNR of the f_R line of y.
    rng = np.random.default_rng(4)
    y = np.cos(2 * np.pi * F_R * T) + 1.0 * rng.standard_normal(N)
    freqs, raw = _raw_power(y)
    sq = squaring_recovery(y, FS)
    def snr(f, p, f0):
        k = np.argmin(np.abs(f - f0))
        floor = np.median(p[(f > f0 - 50e6) & (f < f0 + 50e6)])
        return p[k] / floor
    assert snr(sq.freqs_hz, sq.power, 2 * F_R) < 0.5 * snr(freqs, raw, F_R)


def test_squaring_batches_and_validates():
    rng = np.random.default_rng(0)
    rec = rng.standard_normal((3, 256))
    sq = squaring_recovery(rec, 1e6)
    assert sq.power.shape == (3, 129) and sq.freqs_hz.shape == (129,)
    np.testing.assert_allclose(sq.power[1], squaring_recovery(rec[1], 1e6).power)
    # Parseval: the one-sided mean-square bins sum to the mean of (y^2)^2.
    np.testing.assert_allclose(sq.power.sum(axis=-1), np.mean(rec**4, axis=-1), rtol=1e-12)
    odd = squaring_recovery(rng.standard_normal(255), 1e6)
    assert odd.power.sum() == pytest.approx(np.mean(odd.squared**2), rel=1e-12)
    with pytest.raises(ValueError, match="real"):
        squaring_recovery(np.ones(8, dtype=complex), 1e6)
    with pytest.raises(ValueError, match="fs_hz"):
        squaring_recovery(np.ones(8), 0.0)
    with pytest.raises(ValueError, match="2 samples"):
        squaring_recovery(np.ones(1), 1e6)
