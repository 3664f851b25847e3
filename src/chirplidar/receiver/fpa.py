"""Focal-plane-array (FPA) receiver kernels: pixels, per-pixel noise, DSP combining, Doppler.

Fields are complex amplitudes in sqrt(W/m^2) on a focal grid (the ``optics.diffraction`` convention:
int |E|^2 du dv is the power in W). Per pixel k of a balanced heterodyne/homodyne pair:

* beat amplitude a_k = int_pixel E_s E_LO* dA [W]; powers P_s,k = int_pixel |E_s|^2 dA,
  P_LO,k = int_pixel |E_LO|^2 dA [W];
* beat line power S_k = 2 R^2 |a_k|^2 [A^2]: the balanced difference current is
  2 R |a_k| cos(w t + phi), whose mean square (the tone an FFT or a spectrum analyzer reads,
  thesis eq. 2.6.12) is 2 R^2 |a_k|^2;
* noise N_k = [2 q (R (P_LO,k + P_s,k) + I_dark,k) + S_th,k] B [A^2] (thesis Sec. 2.5, eqs.
  2.5.1-2.5.5: shot noise 2 q I of every DC current, thermal 4 k T / R_L);
* SNR_k = S_k / N_k. With perfect mixing (|a|^2 = P_s P_LO) and a strong LO (shot-limited),
  SNR -> R P_s / (q B) = eta P_s / (h nu B), the heterodyne shot-noise limit (Yariv, Optical
  Electronics, Sec. 11.2; Kingston 1978, Detection of optical and infrared radiation, Ch. 3).

Each pixel carries its share of the LO's shot noise (the shares add up to the whole LO's) but its
own thermal noise and dark current: N x N pixels pay N^2 times the thermal noise of one detector.

Combining (pixels on the last axis, (..., K); reshape (batch, N, N) to (batch, N * N)):
incoherent (sum of power spectra), maximal-ratio (Brennan 1959), equal-gain, selection, and
coherent combining with gains estimated from each pixel's own noisy beat. Doppler: estimated per
record from the data and removed by a frequency shift before coherent combining.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._checks import finite_array, integer, non_negative_array, positive, real_scalar
from ..units import ELEMENTARY_CHARGE_C


@dataclass(frozen=True)
class PixelFields:
    """Per-pixel integrals (rows y, columns x, as the focal field's last two axes).

    beat_w : complex (batch, N, N), a_k = int E_s E_LO* dA [W]
    signal_power_w : (batch, N, N), int |E_s|^2 dA [W]
    lo_power_w : (N, N), int |E_LO|^2 dA [W]
    """

    beat_w: np.ndarray
    signal_power_w: np.ndarray
    lo_power_w: np.ndarray


def _focal_grid(u_m, n: int) -> tuple[np.ndarray, float]:
    u = finite_array("u_m", u_m)
    if u.ndim != 1 or u.size != n or n < 2:
        raise ValueError(f"u_m must be 1-D with the field's {n} samples, got shape {u.shape}")
    du = float(u[1] - u[0])
    if du <= 0.0 or not np.allclose(np.diff(u), du, rtol=1e-9, atol=0.0):
        raise ValueError("u_m must be uniformly spaced and increasing")
    return u, du


def pixel_weights(u_m, n_pixels: int, pitch_m: float, fill_factor: float) -> np.ndarray:
    """(N, n) lengths [m] of focal-grid cell j inside pixel i's active span along one axis.

    Pixel i is centred at c_i = (i - (N - 1) / 2) p, active width w = sqrt(f) p (square active
    area f p^2); grid cell j spans u_j +- du / 2, the field taken constant over it, so
    int_pixel F dA = sum_yx W[i, y] W[l, x] F[y, x] exactly for that piecewise-constant field.
    """
    n_pix = integer("n_pixels", n_pixels, 1)
    p = positive("pitch_m", pitch_m)
    f = real_scalar("fill_factor", fill_factor)
    if not 0.0 < f <= 1.0:
        raise ValueError(f"fill_factor must be in (0, 1], got {f!r}")
    u, du = _focal_grid(u_m, np.size(u_m))
    lo_edge, hi_edge = u[0] - 0.5 * du, u[-1] + 0.5 * du
    half = 0.5 * n_pix * p
    if -half < lo_edge - 1e-9 * du or half > hi_edge + 1e-9 * du:
        raise ValueError(
            f"the FPA (n_pixels * pitch_m = {2 * half:.4g} m) is wider than the focal spot's "
            f"field (the focal grid spans {lo_edge:.4g} .. {hi_edge:.4g} m)"
        )
    c = (np.arange(n_pix) - 0.5 * (n_pix - 1)) * p
    w = np.sqrt(f) * p
    a = np.maximum(c[:, None] - 0.5 * w, u[None, :] - 0.5 * du)
    b = np.minimum(c[:, None] + 0.5 * w, u[None, :] + 0.5 * du)
    return np.clip(b - a, 0.0, None)


def pixelise(
    signal_field, lo_field, u_m, n_pixels: int, pitch_m: float, fill_factor: float
) -> PixelFields:
    """Beat amplitude and powers of each pixel of an N x N FPA centred on the optical axis.

    signal_field : complex (batch, n, n) or (n, n), E_s [sqrt(W/m^2)] on the grid u_m (both axes)
    lo_field : complex (n, n), E_LO [sqrt(W/m^2)]
    u_m : (n,) focal-plane coordinates [m], uniform
    a_k = int_k E_s E_LO* dA, P_s,k = int_k |E_s|^2 dA, P_LO,k = int_k |E_LO|^2 dA (W), the
    integrals over pixel k's active square (side sqrt(fill_factor) pitch_m).
    """
    es = finite_array("signal_field", signal_field, complex)
    elo = finite_array("lo_field", lo_field, complex)
    if elo.ndim != 2 or elo.shape[0] != elo.shape[1]:
        raise ValueError(f"lo_field must have shape (n, n), got {elo.shape}")
    squeeze = es.ndim == 2
    es = es[None] if squeeze else es
    if es.ndim != 3 or es.shape[1:] != elo.shape:
        raise ValueError(
            f"signal_field must have shape (batch, n, n) = (., {elo.shape}), got {es.shape}"
        )
    _focal_grid(u_m, elo.shape[0])
    w = pixel_weights(u_m, n_pixels, pitch_m, fill_factor)
    beat = np.einsum("iy,byx,lx->bil", w, es * np.conj(elo), w, optimize=True)
    ps = np.einsum("iy,byx,lx->bil", w, (es * np.conj(es)).real, w, optimize=True)
    plo = w @ (elo * np.conj(elo)).real @ w.T
    if squeeze:
        beat, ps = beat[0], ps[0]
    return PixelFields(beat_w=beat, signal_power_w=ps, lo_power_w=plo)


def pixel_noise_psd(
    lo_power_w, signal_power_w, responsivity_a_w: float, thermal_psd_a2_hz, dark_current_a
):
    """One-sided current noise PSD [A^2/Hz] of each balanced pixel (thesis Sec. 2.5):

    N_k / B = 2 q (R (P_LO,k + P_s,k) + I_dark,k) + S_th,k.
    thermal_psd_a2_hz, dark_current_a: per pixel (scalars or arrays broadcasting with the powers),
    e.g. ``receiver.thermal_psd(T, R_L)`` for one pixel's load.
    """
    r = positive("responsivity_a_w", responsivity_a_w)
    plo = non_negative_array("lo_power_w", lo_power_w)
    ps = non_negative_array("signal_power_w", signal_power_w)
    th = non_negative_array("thermal_psd_a2_hz", thermal_psd_a2_hz)
    dark = non_negative_array("dark_current_a", dark_current_a)
    return 2.0 * ELEMENTARY_CHARGE_C * (r * (plo + ps) + dark) + th


def pixel_signal_noise(
    beat_w,
    lo_power_w,
    signal_power_w,
    responsivity_a_w: float,
    bandwidth_hz: float,
    thermal_psd_a2_hz,
    dark_current_a,
) -> tuple[np.ndarray, np.ndarray]:
    """(S_k, N_k) [A^2]: beat line power 2 R^2 |a_k|^2 and noise power in the band B.

    SNR_k = S_k / N_k = 2 R^2 |a_k|^2 / ([2 q (R (P_LO,k + P_s,k) + I_dark) + S_th] B)
    (thesis eq. 2.6.12 with the noise of Sec. 2.5; Yariv, Optical Electronics, Sec. 11.2).
    """
    b = positive("bandwidth_hz", bandwidth_hz)
    a = finite_array("beat_w", beat_w, complex)
    psd = pixel_noise_psd(
        lo_power_w, signal_power_w, responsivity_a_w, thermal_psd_a2_hz, dark_current_a
    )
    s = 2.0 * responsivity_a_w**2 * np.abs(a) ** 2
    n = np.broadcast_to(psd * b, np.broadcast_shapes(s.shape, np.shape(psd)))
    return s, n


def _pixels(signal_a2, noise_a2) -> tuple[np.ndarray, np.ndarray]:
    s = non_negative_array("signal_a2", signal_a2)
    n = finite_array("noise_a2", noise_a2)
    if np.any(n <= 0.0):
        raise ValueError("noise_a2 must be > 0 in every pixel")
    s, n = np.broadcast_arrays(s, n)
    if s.ndim < 1 or s.shape[-1] < 1:
        raise ValueError(f"the pixel axis (last) must hold >= 1 pixel, got shape {s.shape}")
    return s, n


def incoherent_snr(signal_a2, noise_a2) -> np.ndarray:
    """SNR of the sum of the pixels' power spectra: sum_k S_k / sum_k N_k (pixels last axis).

    The beat lines add in power and so do the independent noises (post-detection integration,
    Goodman 2007, Speckle Phenomena in Optics, Sec. 5.3: M independent speckle pixels of equal
    mean give a gamma-distributed sum of order M, contrast 1 / sqrt(M)). The square-law statistic
    itself is :func:`summed_power_spectrum`. It is the mean line over the mean floor: K equal
    pixels of one coherent beat give MRC / K, while the summed floor fluctuates sqrt(K) times less
    (what a detection threshold on the summed spectrum gains back).
    """
    s, n = _pixels(signal_a2, noise_a2)
    return s.sum(axis=-1) / n.sum(axis=-1)


def mrc_snr(signal_a2, noise_a2) -> np.ndarray:
    """Maximal-ratio combining with known gains: SNR = sum_k S_k / N_k (Brennan 1959, Proc. IRE
    47, 1075, eq. for the maximal-ratio combiner; gains g_k = c_k* / N_k, Cauchy-Schwarz)."""
    s, n = _pixels(signal_a2, noise_a2)
    return (s / n).sum(axis=-1)


def equal_gain_snr(signal_a2, noise_a2) -> np.ndarray:
    """Equal-gain combining, co-phased with known phases: (sum_k sqrt(S_k))^2 / sum_k N_k.

    Brennan 1959: for M Rayleigh pixels of equal mean SNR g, E[SNR] = g (1 + (M - 1) pi / 4).
    """
    s, n = _pixels(signal_a2, noise_a2)
    return np.sqrt(s).sum(axis=-1) ** 2 / n.sum(axis=-1)


def selection_snr(signal_a2, noise_a2) -> np.ndarray:
    """Selection combining: SNR = max_k S_k / N_k (Brennan 1959; for M independent exponential
    SNRs of mean g, E[max] = g H_M, H_M = sum_{m=1}^M 1/m)."""
    s, n = _pixels(signal_a2, noise_a2)
    return (s / n).max(axis=-1)


def combining_gains(estimates, noise_a2, rule: str) -> np.ndarray:
    """Combiner gains g_k from per-pixel complex tone estimates c^_k (..., K).

    rule "mrc": g_k = conj(c^_k) / N_k (maximal ratio with estimated gains; Gans 1971, IEEE Trans.
    Commun. Technol. 19, 492); "egc": g_k = exp(-j arg c^_k) (equal gain, estimated phases).
    """
    c = finite_array("estimates", estimates, complex)
    n = finite_array("noise_a2", noise_a2)
    if np.any(n <= 0.0):
        raise ValueError("noise_a2 must be > 0 in every pixel")
    if rule == "mrc":
        return np.conj(c) / n
    if rule == "egc":
        return np.exp(-1j * np.angle(c))
    raise ValueError(f"rule must be 'mrc' or 'egc', got {rule!r}")


def estimated_mrc_factor(total_snr, pixels: int):
    """Mean SNR of maximal-ratio combining with gains estimated from the pixels' own beats,
    over the known-gain SNR G = sum_k SNR_k, to first order in the estimation noise:
    (G + 1) / (G + M) for M pixels (Gans 1971, IEEE Trans. Commun. Technol. 19, 492: each noisy
    estimate c^_k = c_k + e_k adds its noise to the combiner's output in every pixel, M in
    all, and to the signal only through c). G is the SNR of the estimates, the energy SNR
    E / N0 of the record the amplitudes are read from. Checked against the Monte Carlo of
    :func:`combining_gains` and :func:`combined_snr` (tests/test_fpa.py): 1 % high at G / M = 1.
    """
    g = non_negative_array("total_snr", total_snr)
    m = integer("pixels", pixels, 1)
    return (g + 1.0) / (g + m)


def combined_snr(gains, amplitudes, noise_a2) -> np.ndarray:
    """SNR of y = sum_k g_k x_k given the gains: |sum_k g_k c_k|^2 / sum_k |g_k|^2 N_k.

    c_k the pixels' true complex tone amplitudes (|c_k|^2 = S_k [A^2]), N_k their independent
    noise powers. With g_k = c_k* / N_k it is sum_k S_k / N_k (Cauchy-Schwarz: the maximum). For
    gains estimated from the data it is the SNR conditioned on the estimates (the tone power in
    the combined record over its noise floor; Gans 1971).
    """
    g = finite_array("gains", gains, complex)
    c = finite_array("amplitudes", amplitudes, complex)
    n = finite_array("noise_a2", noise_a2)
    num = np.abs((g * c).sum(axis=-1)) ** 2
    den = (np.abs(g) ** 2 * n).sum(axis=-1)
    if np.any(den <= 0.0):
        raise ValueError("gains must not all be zero (the combined noise is zero)")
    return num / den


def _records(records) -> np.ndarray:
    x = finite_array("records", records, complex)
    if x.ndim != 3 or x.shape[-1] < 2:
        raise ValueError(f"records must have shape (batch, pixels, samples >= 2), got {x.shape}")
    return x


def tone_amplitudes(records, f_hz, fs_hz: float) -> np.ndarray:
    """(batch, K) c^_k = (1/L) sum_t x_k(t) exp(-j 2 pi f t), t = n / fs: each pixel's complex
    amplitude at the (per record) frequency f_hz (batch,) or scalar; for a tone c e^{j 2 pi f t} in
    white noise it is the maximum-likelihood amplitude (Rife & Boorstyn 1974)."""
    x = _records(records)
    fs = positive("fs_hz", fs_hz)
    f = np.broadcast_to(finite_array("f_hz", f_hz), (x.shape[0],))
    t = np.arange(x.shape[-1]) / fs
    ph = np.exp(-2j * np.pi * f[:, None] * t[None, :])
    return np.einsum("bkt,bt->bk", x, ph) / x.shape[-1]


def summed_power_spectrum(records, zero_pad: int = 1) -> np.ndarray:
    """(batch, L zero_pad) sum_k |FFT(x_k)|^2: the incoherent (square-law) combining statistic,
    bins in numpy's FFT order."""
    x = _records(records)
    if not isinstance(zero_pad, int) or zero_pad < 1:
        raise ValueError(f"zero_pad must be an integer >= 1, got {zero_pad!r}")
    return (np.abs(np.fft.fft(x, x.shape[-1] * zero_pad, axis=-1)) ** 2).sum(axis=1)


def _peak_index(power: np.ndarray) -> np.ndarray:
    """Fractional index of each row's maximum, parabolic on the log power (Gaussian fit)."""
    m = power.shape[-1]
    k = np.argmax(power, axis=-1)
    rows = np.arange(power.shape[0])
    lp = np.log(np.maximum(power, 1e-300))
    y0, ym, yp = lp[rows, k], lp[rows, (k - 1) % m], lp[rows, (k + 1) % m]
    den = ym - 2.0 * y0 + yp
    safe = np.where(den < 0.0, den, -1.0)
    return k + np.where(den < 0.0, 0.5 * (ym - yp) / safe, 0.0)


def _peak_hz(power: np.ndarray, fs: float) -> np.ndarray:
    """Peak frequency [Hz] of each row of an FFT-ordered power spectrum."""
    m = power.shape[-1]
    return ((_peak_index(power) + m / 2) % m - m / 2) * fs / m


def estimate_doppler_hz(
    records, fs_hz: float, *, method: str, reference_hz=None, zero_pad: int = 8
):
    """(batch,) Doppler shift f_d [Hz] of each record from the data, common to all its pixels.

    Self-chirped homodyne (thesis Appendix D): with an I/Q pixel the complex record is
    x_k = c_k cos(2 pi f_R t) exp(j 2 pi f_d t) + n_k, two equal lines at f_d +- f_R.
    "symmetry": f_d = the centre of symmetry of P(f) = sum_k |FFT(x_k)|^2 (pixels summed
    incoherently, no phases needed): the peak of sum_f P'(f) P'(2 nu - f), P' = P - mean(P).
    "square": Appendix D's squaring: x_k^2 holds c_k^2 / 2 exp(j 4 pi f_d t), a line at 2 f_d
    whatever f_R; f_d = (peak of sum_k |FFT(x_k^2)|^2) / 2, |f_d| < fs / 4. Squaring multiplies the
    noise with itself: it needs a per-sample SNR near 1 (Appendix D: "the noise level will be
    raised"), where "symmetry" works at the per-bin SNR of the spectrum.
    "peak": one beat tone at f_ref + f_d with f_ref known (``reference_hz``): f_d = peak of P -
    f_ref (a lone tone does not separate f_R from f_d without a reference or a mirror line).
    """
    x = _records(records)
    fs = positive("fs_hz", fs_hz)
    if method not in ("symmetry", "square", "peak"):
        raise ValueError(f"method must be 'symmetry', 'square' or 'peak', got {method!r}")
    if (method == "peak") != (reference_hz is not None):
        raise ValueError("reference_hz is needed by method='peak' and applies to it only")
    if method == "symmetry":
        return _symmetry_centre_hz(summed_power_spectrum(x, zero_pad), fs)
    if method == "square":
        return 0.5 * _peak_hz(summed_power_spectrum(x * x, zero_pad), fs)
    ref = finite_array("reference_hz", reference_hz)
    return _peak_hz(summed_power_spectrum(x, zero_pad), fs) - ref


def compensate(records, f_d_hz, fs_hz: float) -> np.ndarray:
    """x_k(t) exp(-j 2 pi f_d t), t = n / fs, for every pixel k of each record (f_d (batch,))."""
    x = _records(records)
    fs = positive("fs_hz", fs_hz)
    f = np.broadcast_to(finite_array("f_d_hz", f_d_hz), (x.shape[0],))
    t = np.arange(x.shape[-1]) / fs
    return x * np.exp(-2j * np.pi * f[:, None, None] * t)


def coherent_combine(records, gains) -> np.ndarray:
    """(batch, L) y = sum_k g_k x_k: the combined record (gains (batch, K))."""
    x = _records(records)
    g = finite_array("gains", gains, complex)
    if g.shape != x.shape[:2]:
        raise ValueError(f"gains must have shape {x.shape[:2]} (batch, pixels), got {g.shape}")
    return np.einsum("bk,bkt->bt", g, x)


def _symmetry_centre_hz(power: np.ndarray, fs: float) -> np.ndarray:
    """Centre of symmetry [Hz] of each row of an FFT-ordered power spectrum: the peak of the
    linear self-convolution sum_f P'(f) P'(2 nu - f) of the floor-removed spectrum P' = P - mean.
    A pair of lines at f1, f2 gives 2 P1 P2 at 2 nu = f1 + f2 (each alone P^2 at 2 f)."""
    m = power.shape[-1]
    p = np.fft.fftshift(power, axes=-1)
    p = p - p.mean(axis=-1, keepdims=True)
    conv = np.fft.irfft(np.fft.rfft(p, 2 * m, axis=-1) ** 2, 2 * m, axis=-1)
    # index j of the shifted spectra's convolution holds k1 + k2 = j - m (signed bins)
    return 0.5 * (_peak_index(np.maximum(conv, 1e-300)) - m) * fs / m
