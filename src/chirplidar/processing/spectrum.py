"""Calibrated spectra and peak analysis (thesis FFT_peak.m, eqs. 2.6.3-2.6.12).

Conventions (one-sided, what a spectrum analyzer displays):

* PSD  P_k = 2 |X_k|^2 / (N Fs R)  [W/Hz]; white noise of variance s^2 reads 2 s^2 / (Fs R).
* A tone A cos(2 pi f t) reads A^2 / (2 R) as ``P_peak * df`` with df = Fs / N (eq. 2.6.6).
* Noise level = mean PSD over a flat span beside the peak, times the RBW (eq. 2.6.11).
* SNR = tone power / (noise PSD * RBW) (eq. 2.6.12).

The thesis's own normalisation (P_f = V_f^2 / (R 2 BW), eqs. 2.6.3-2.6.4) is two-sided: both its
signal and its noise read 3 dB below these, so the SNR is the same; we report the one-sided values
because they equal a spectrum analyzer's readings (Crx, Navg).

The zero-padding factor (``sys.smoothx``) samples the same DTFT more finely; the ``dtft`` peak method
evaluates the DTFT itself near the peak, exactly, by Dirichlet-kernel interpolation of the FFT bins.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft

# Neighbouring bins used by the Dirichlet interpolation; truncation error ~ 1/(pi^2 L) of the
# noise level, far below the scatter of a single periodogram bin.
_KERNEL_HALF_WIDTH = 48
_FINE_STEP = 1.0 / 16.0      # fine-grid step, in native bins (then parabolic refinement)
_THREEDB_SPAN = 4.0          # +- native bins searched for the 3 dB points on the fine grid


@dataclass(frozen=True)
class PeakResult:
    """Per-record results of spectral analysis (all arrays have the batch shape)."""

    f_peak_hz: np.ndarray
    peak_power_w: np.ndarray       # tone power as a spectrum analyzer reads it (Crx)
    noise_psd_w_per_hz: np.ndarray # one-sided noise PSD beside the peak
    f_lo_hz: np.ndarray
    f_hi_hz: np.ndarray
    snr: np.ndarray                # linear, in the RBW
    spectrum_f_hz: np.ndarray | None = None
    spectrum_w_per_hz: np.ndarray | None = None


# The fine grid is a fixed set of offsets from the peak bin, so the kernel K(offset - m) depends on
# the record length only and is computed once per length.
_OFFSETS = np.arange(-_THREEDB_SPAN, _THREEDB_SPAN + _FINE_STEP / 2, _FINE_STEP)
_MREL = np.arange(-_KERNEL_HALF_WIDTH, _KERNEL_HALF_WIDTH + 1)


@lru_cache(maxsize=8)
def _dirichlet_kernel(n: int) -> np.ndarray:
    """K(u) = exp(-j pi u (n-1)/n) sin(pi u) / (n sin(pi u / n)) at u = offset - m (rows, cols)."""
    u = _OFFSETS[:, None] - _MREL[None, :]
    near = np.abs(u) < 1e-12
    u_safe = np.where(near, 1.0, u)
    kern = np.exp(-1j * np.pi * u_safe * (n - 1) / n) * np.sin(np.pi * u_safe) / (
        n * np.sin(np.pi * u_safe / n))
    kern = np.where(near, 1.0, kern)
    kern.setflags(write=False)
    return kern


def _dirichlet_dtft(X: np.ndarray, k: int, rows: np.ndarray, n: int) -> np.ndarray:
    """DTFT of a length-``n`` record at native bins ``k + _OFFSETS[rows]``, from its DFT ``X``.

    X(nu) = sum_m X_m K(nu - m), over the bins within _KERNEL_HALF_WIDTH of bin ``k``.
    """
    lo = max(k - _KERNEL_HALF_WIDTH, 0)
    hi = min(k + _KERNEL_HALF_WIDTH + 1, X.size)
    first_col = lo - (k - _KERNEL_HALF_WIDTH)
    kern = _dirichlet_kernel(n)[rows, first_col:first_col + (hi - lo)]
    return kern @ X[lo:hi]


def _parabolic(y_m1: float, y0: float, y_p1: float) -> float:
    """Vertex offset of the parabola through three equally spaced points (in steps)."""
    den = y_m1 - 2.0 * y0 + y_p1
    if den >= 0 or not np.isfinite(den):
        return 0.0
    return float(np.clip(0.5 * (y_m1 - y_p1) / den, -0.5, 0.5))


def _crossing(x: np.ndarray, y: np.ndarray, level: float, start: int, step: int) -> float | None:
    """First x where y falls below ``level`` walking from ``start`` by ``step`` (linear interp)."""
    seg = y[start::step] if step > 0 else y[start::-1]
    below = np.flatnonzero(seg < level)
    if below.size == 0 or below[0] == 0:
        return None
    j = start + step * int(below[0])          # first point below; j - step is at or above
    y0, y1 = y[j - step], y[j]
    frac = (y0 - level) / (y0 - y1) if y0 != y1 else 0.0
    return float(x[j - step] + frac * (x[j] - x[j - step]))


def analyze_records(v: np.ndarray, fs_hz: float, load_ohm: float, *, rbw_hz: float,
                    highpass_hz: float, zero_pad: int, peak_method: str, noise_span_hz: float,
                    noise_guard_hz: float, averaging: str = "coherent",
                    transfer=None, keep_spectrum: bool = False,
                    search_max_hz: float | None = None) -> PeakResult:
    """Spectrum, peak, 3 dB points, noise level and SNR of voltage records.

    Parameters
    ----------
    v : ndarray, shape (batch, averages, N), float64, volts across ``load_ohm``.
    transfer : callable f_hz -> complex gain (detector response of a linear chain), or None. Only
        its power gain |H(f)|^2 matters to the spectrum, so it is applied to the PSD.
    """
    v = np.asarray(v, dtype=float)
    if v.ndim != 3:
        raise ValueError("analyze_records expects (batch, averages, N) records")
    batch, n_avg, n = v.shape
    m = n * zero_pad
    if averaging == "coherent":
        v = v.mean(axis=1, keepdims=True)
    X = scipy.fft.rfft(v, n=m, axis=-1, workers=-1)
    f = np.arange(X.shape[-1]) * (fs_hz / m)
    # One-sided PSD in W/Hz (eqs. 2.6.3-2.6.4 made one-sided).
    power = X.real ** 2 + X.imag ** 2
    psd = (2.0 / (n * fs_hz * load_ohm)) * (power[:, 0] if power.shape[1] == 1 else power.mean(axis=1))
    if transfer is not None:
        h = transfer.on_grid(m, fs_hz) if hasattr(transfer, "on_grid") else transfer(f)
        psd *= h.real ** 2 + h.imag ** 2
    df_native = fs_hz / n
    search = f >= highpass_hz
    if search_max_hz is not None:
        search &= f <= search_max_hz
    if not np.any(search):
        raise ValueError("no FFT bin between processing.highpass_hz (sys.f_highpass) and the peak "
                         "search maximum")
    first = int(np.argmax(search))

    out = {k: np.empty(batch) for k in ("f", "p", "nz", "lo", "hi")}
    for b in range(batch):
        spec = psd[b]
        kp = int(np.argmax(np.where(search, spec, -np.inf)))
        f_pk, p_pk = f[kp], spec[kp]
        fine_nu = fine_p = None
        if peak_method == "parabolic" and 0 < kp < spec.size - 1:
            lg = np.log(np.maximum(spec[kp - 1:kp + 2], np.finfo(float).tiny))
            d = _parabolic(*lg)
            f_pk = f[kp] + d * fs_hz / m
            p_pk = float(np.exp(lg[1] - 0.25 * (lg[0] - lg[2]) * d))
        elif peak_method == "dtft":
            # Native-grid DFT is every zero_pad-th padded bin (coherent records only).
            k_nat = int(round(kp / zero_pad))
            top = n / 2 if search_max_hz is None else min(n / 2, search_max_hz / df_native)
            nu = k_nat + _OFFSETS
            rows = (nu * df_native >= highpass_hz) & (nu <= top)
            nu = nu[rows]
            Pn = np.zeros(nu.size)
            for a in range(X.shape[1]):
                Pn += np.abs(_dirichlet_dtft(X[b, a, ::zero_pad], k_nat, rows, n)) ** 2
            Pn *= 2.0 / (n * fs_hz * load_ohm * X.shape[1])
            if transfer is not None:
                Pn *= np.abs(transfer(nu * df_native)) ** 2
            i = int(np.argmax(Pn))
            if 0 < i < nu.size - 1:
                lg = np.log(np.maximum(Pn[i - 1:i + 2], np.finfo(float).tiny))
                d = _parabolic(*lg)
            else:
                d = 0.0
            f_pk = (nu[i] + d * _FINE_STEP) * df_native
            p_pk = float(Pn[i]) if d == 0.0 else float(np.exp(lg[1] - 0.25 * (lg[0] - lg[2]) * d))
            fine_nu, fine_p = nu, Pn
        # 3 dB points: on the fine DTFT if we have it, else on the (padded) spectrum.
        half = 0.5 * p_pk
        lo = hi = None
        if fine_nu is not None:
            i = int(np.argmax(fine_p))
            lo = _crossing(fine_nu * df_native, fine_p, half, i, -1)
            hi = _crossing(fine_nu * df_native, fine_p, half, i, +1)
        if lo is None:
            lo = _crossing(f, spec, half, kp, -1)
        if hi is None:
            hi = _crossing(f, spec, half, kp, +1)
        out["lo"][b] = f[first] if lo is None else lo
        out["hi"][b] = f[-1] if hi is None else hi
        # Noise: mean PSD over the span beside the peak, guard bins excluded.
        i0, i1 = np.searchsorted(f, (f_pk - 0.5 * noise_span_hz, f_pk + 0.5 * noise_span_hz + 1e-9))
        dist = np.abs(f[i0:i1] - f_pk)
        sel = (dist > noise_guard_hz) & search[i0:i1]
        if np.count_nonzero(sel) >= 8:
            out["nz"][b] = float(np.mean(spec[i0:i1][sel]))
        else:
            out["nz"][b] = float(np.mean(spec[(np.abs(f - f_pk) > noise_guard_hz) & search]))
        out["f"][b] = f_pk
        out["p"][b] = p_pk * df_native  # tone power, eq. 2.6.6 with df = 1/T
    noise_in_rbw = out["nz"] * rbw_hz
    return PeakResult(
        f_peak_hz=out["f"], peak_power_w=out["p"], noise_psd_w_per_hz=out["nz"],
        f_lo_hz=out["lo"], f_hi_hz=out["hi"], snr=out["p"] / noise_in_rbw,
        spectrum_f_hz=f if keep_spectrum else None,
        spectrum_w_per_hz=psd if keep_spectrum else None,
    )
