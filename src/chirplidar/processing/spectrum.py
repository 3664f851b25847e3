"""Calibrated spectra and peak analysis (thesis FFT_peak.m, eqs. 2.6.3-2.6.12).

Conventions (one-sided, what a spectrum analyzer displays):

* PSD  P_k = 2 |X_k|^2 / (N Fs R)  [W/Hz]; white noise of variance s^2 reads 2 s^2 / (Fs R).
* A tone A cos(2 pi f t) reads A^2 / (2 R) as ``P_peak * df`` with df = Fs / N (eq. 2.6.6).
* Noise level = mean PSD over a flat span beside the peak, times the RBW (eq. 2.6.11); the span
  moves out past a strong tone's own skirt (:func:`_noise_floor`).
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
_FINE_STEP = 1.0 / 16.0  # fine-grid step, in native bins (then parabolic refinement)
_THREEDB_SPAN = 4.0  # +- native bins searched for the 3 dB points on the fine grid
_CROSSING_WINDOW = 64  # +- bins of the spectrum searched first for the 3 dB points
# Noise windows (see _noise_floor): how many, stepped outward from the peak, are tried; how many
# beyond a window make its flat reference; the one-sided test level in standard errors (a flat
# strip fails it ~1 % of the time, periodogram bins being skewed, and the next window is read
# instead: no bias, the test does not see the window it picks; a skirt that passes it is
# steeper still in the window read); the fewest bins a window or test region needs.
_NOISE_WINDOWS = 16
_NOISE_REF_WINDOWS = 4
_NOISE_FLAT_Z = 3.0
_MIN_NOISE_BINS = 8
_REGION_BLOCK = 1 << 18  # bins gathered per pass of _region_stats (2 MB per array)


@dataclass(frozen=True)
class PeakResult:
    """Per-record results of spectral analysis (all arrays have the batch shape)."""

    f_peak_hz: np.ndarray
    peak_power_w: np.ndarray  # tone power as a spectrum analyzer reads it (Crx)
    noise_psd_w_per_hz: np.ndarray  # one-sided noise PSD beside the peak
    f_lo_hz: np.ndarray
    f_hi_hz: np.ndarray
    snr: np.ndarray  # linear, in the RBW
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
    kern = (
        np.exp(-1j * np.pi * u_safe * (n - 1) / n)
        * np.sin(np.pi * u_safe)
        / (n * np.sin(np.pi * u_safe / n))
    )
    kern = np.where(near, 1.0, kern)
    kern.setflags(write=False)
    return kern


def parabolic_vertex(y_m1: float, y0: float, y_p1: float) -> float:
    """Vertex offset of the parabola through three equally spaced points (in steps)."""
    den = y_m1 - 2.0 * y0 + y_p1
    if den >= 0 or not np.isfinite(den):
        return 0.0
    return float(np.clip(0.5 * (y_m1 - y_p1) / den, -0.5, 0.5))


def _parabolic_batch(y_m1, y0, y_p1):
    """Vectorised :func:`parabolic_vertex` (no vertex unless the parabola opens downward)."""
    den = y_m1 - 2.0 * y0 + y_p1
    ok = (den < 0) & np.isfinite(den)
    d = 0.5 * (y_m1 - y_p1) / np.where(ok, den, -1.0)
    return np.where(ok, np.clip(d, -0.5, 0.5), 0.0)


def _crossings(
    x: np.ndarray,
    y: np.ndarray,
    level: np.ndarray,
    start: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    window: int | None = None,
):
    """Per row b, where y[b] first falls below level[b] walking left and right from start[b]
    (linear interpolation), looking only within indices lo[b]..hi[b]; NaN where it never does.

    ``x`` is (L,) or (B, L); ``y`` is (B, L). With ``window``, rows are first searched within
    start +- window only (a crossing found there is the first one); the rows whose walk leaves
    that window are searched again in full. Same result, a fraction of the work for narrow peaks.
    """
    batch, n = y.shape
    width = 2 * window + 1 if window is not None else n
    if width >= n:
        return _crossings_full(x, y, level, start, lo, hi)
    c0 = np.clip(start - window, 0, n - width)
    cols = c0[:, None] + np.arange(width)
    yw = np.take_along_axis(y, cols, axis=1)
    xw = x[cols] if np.ndim(x) == 1 else np.take_along_axis(x, cols, axis=1)
    left, right = _crossings_full(xw, yw, level, start - c0, lo - c0, hi - c0)
    # A walk that found nothing inside the window but could go on beyond it: search in full.
    redo = np.flatnonzero((np.isnan(left) & (c0 > lo)) | (np.isnan(right) & (c0 + width - 1 < hi)))
    if redo.size:
        xr = x if np.ndim(x) == 1 else x[redo]
        left[redo], right[redo] = _crossings_full(
            xr, y[redo], level[redo], start[redo], lo[redo], hi[redo]
        )
    return left, right


def _crossings_full(x, y, level, start, lo, hi):
    """:func:`_crossings` over whole rows."""
    batch, n = y.shape
    idx = np.arange(n)
    below = (y < level[:, None]) & (idx >= lo[:, None]) & (idx <= hi[:, None])
    rows = np.arange(batch)
    xb = np.broadcast_to(x, y.shape)
    # Left: the largest j < start below the level; right: the smallest j > start.
    left = np.where(below & (idx < start[:, None]), idx, -1).max(axis=1)
    right = np.where(below & (idx > start[:, None]), idx, n).min(axis=1)
    start_ok = y[rows, start] >= level  # a walk that starts below the level finds nothing
    out = []
    for j, nb in ((left, left + 1), (right, right - 1)):
        found = (j >= 0) & (j < n) & start_ok
        jj, kk = np.clip(j, 0, n - 1), np.clip(nb, 0, n - 1)
        y0, y1 = y[rows, kk], y[rows, jj]  # y0 at or above the level, y1 below
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(y0 != y1, (y0 - level) / (y0 - y1), 0.0)
        val = xb[rows, kk] + frac * (xb[rows, jj] - xb[rows, kk])
        out.append(np.where(found, val, np.nan))
    return out


def _range_sums(y: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """sum(y[b, start[b]:stop[b]]) per row (empty ranges give 0): gathers the ranges when they
    are short, else one prefix sum over the rows."""
    batch, n = y.shape
    start = np.clip(start, 0, n)
    stop = np.clip(np.maximum(stop, start), 0, n)
    width = int(np.max(stop - start, initial=0))
    if width == 0:
        return np.zeros(batch)
    if 4 * width < n:
        cols = start[:, None] + np.arange(width)
        vals = np.take_along_axis(y, np.minimum(cols, n - 1), axis=1)
        return np.sum(vals, axis=1, where=cols < stop[:, None], dtype=float)
    cs = np.zeros((batch, n + 1))
    np.cumsum(y, axis=1, dtype=float, out=cs[:, 1:])
    rows = np.arange(batch)
    return cs[rows, stop] - cs[rows, start]


def _noise_floor(
    psd: np.ndarray,
    f: np.ndarray,
    f_pk: np.ndarray,
    first: int,
    last: int,
    span_hz: float,
    guard_hz: float,
    zero_pad: int,
):
    """Per row: the mean PSD over the nearest noise window that the tone's own skirt leaves flat,
    and its bin count (0 when no window holds enough bins: the caller falls back).

    Window j holds the bins guard + j w < |f - f_pk| <= guard + (j + 1) w (w = span / 2 - guard,
    both sides, within first..last); window 0 is the span beside the peak. A beat tone is not a
    line: it lasts as long as the two pulses overlap, and its rise and fall (the chirp's
    raised-cosine taper, a gate, a laser linewidth) spread it into a skirt that falls with
    |f - f_pk| but stays above the noise farther out the stronger the tone (on the Ch. 5 bench the
    taper's |f|^-6 skirt reaches past 1 MHz above ~60 dB SNR). The link tier's noise is the
    receiver's alone, and the thesis reads the noise over a flat region (Sec. 2.6), so window j is
    read only when the strip just inside it (window j - 1; for window 0, the outer half of the
    guard) exceeds windows j+2 .. j+1+_NOISE_REF_WINDOWS by no more than _NOISE_FLAT_Z standard
    errors: the skirt falls outward, so window j holds less of it than that strip. The tests
    never look at the window they choose, so choosing does not bias the reading; a flat spectrum
    (a weak tone) reads window 0, as a fixed span would. A skirt still above the noise in the
    last window (a rectangular pulse's |f|^-2 sidelobes or a wide linewidth's pedestal, strong)
    is read there: still high, but far less than beside the peak.
    """
    batch = psd.shape[0]
    width = 0.5 * span_hz - guard_hz
    if width <= 0:
        return np.zeros(batch), np.zeros(batch, int)
    # Region edges (distances from f_pk): the guard's outer strip, then the windows.
    edges = np.concatenate(
        [[guard_hz - min(width, 0.5 * guard_hz)], guard_hz + width * np.arange(_NOISE_WINDOWS + 1)]
    )
    # First the regions test 0 needs (strip, window 0, windows 2..1+R): most rows stop there.
    near = 3 + _NOISE_REF_WINDOWS
    noise, n_win = np.zeros(batch), np.zeros(batch, int)
    rows = np.arange(batch)
    for reach in (near, _NOISE_WINDOWS + 1):
        stats = _region_stats(psd[rows], f, f_pk[rows], first, last, edges[: reach + 1], zero_pad)
        flat, usable = _flat_windows(*stats, zero_pad)
        if reach == near:
            done = flat[:, 0]
            pick = np.zeros(rows.size, int)
        else:
            done = np.ones(rows.size, bool)
            # No flat window within reach: the farthest usable one.
            far = usable.shape[1] - 1 - np.argmax(usable[:, ::-1], axis=1)
            pick = np.where(flat.any(axis=1), np.argmax(flat, axis=1), far)
        r = np.arange(rows.size)
        cnt, s1 = stats[0][r, pick + 1], stats[1][r, pick + 1]
        ok = done & usable[r, pick]
        with np.errstate(invalid="ignore", divide="ignore"):
            noise[rows[done]] = np.where(ok, s1 / cnt, 0.0)[done]
        n_win[rows[done]] = np.where(ok, cnt, 0).astype(int)[done]
        rows = rows[~done]
        if not rows.size:
            break
    return noise, n_win


def _region_stats(
    psd, f, f_pk, first, last, edges, zero_pad: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per region edges[m] < |f - f_pk| <= edges[m + 1] (both sides, within the bins first..last):
    bin count, sum and sum of squares of the PSD, and the sums of products of bins one and two
    native bins (zero_pad, 2 zero_pad bins) apart, each pair counted in the region of its bin
    nearer the band's start: arrays (batch, edges.size - 1)."""
    batch, n_bins = psd.shape
    # Bins f_pk - e <= f and f <= f_pk + e, as the fixed span and guard always counted them.
    lo = np.clip(np.searchsorted(f, f_pk[:, None] - edges), first, last + 1)
    hi = np.clip(np.searchsorted(f, f_pk[:, None] + edges, side="right"), first, last + 1)
    cnt = (lo[:, :-1] - lo[:, 1:]) + (hi[:, 1:] - hi[:, :-1])
    sums = np.zeros((4, batch, edges.size - 1))
    lags = (zero_pad, 2 * zero_pad)
    # Each side separately, from its outermost (left) or innermost (right) edge: the prefix sums
    # never carry the tone's peak, whose rounding would swamp the noise sums, and are read only
    # up to the side's own last bin (nothing to mask; the lag products' last pairs reach up to
    # 2 zero_pad bins beyond it, which only blurs the region edges).
    for start, pos, sign in ((lo[:, -1], lo, -1.0), (hi[:, 0], hi, 1.0)):
        pos = pos - start[:, None]
        width = max(int(np.max(pos, initial=0)), 1)
        step = max(1, _REGION_BLOCK // width)  # rows per pass: temporaries stay small
        cols_all = start[:, None] + np.arange(width + lags[-1])
        for r0 in range(0, batch, step):
            r = slice(r0, r0 + step)
            vals = np.take_along_axis(psd[r], np.minimum(cols_all[r], n_bins - 1), axis=1)
            terms = [vals[:, :width], np.multiply(vals[:, :width], vals[:, :width], dtype=float)]
            terms += [
                np.multiply(vals[:, :width], vals[:, lag : lag + width], dtype=float)
                for lag in lags
            ]
            for y, out in zip(terms, sums, strict=True):
                cs = np.zeros((y.shape[0], width + 1))
                np.cumsum(y, axis=1, dtype=float, out=cs[:, 1:])
                c = np.take_along_axis(cs, pos[r], axis=1)
                out[r] += sign * (c[:, 1:] - c[:, :-1])
    return cnt, sums[0], sums[1], sums[2], sums[3]


def _flat_windows(cnt, s1, s2, p1, p2, zero_pad: int):
    """(flat, usable), (batch, windows): the test of :func:`_noise_floor` for each window j from
    the region statistics of :func:`_region_stats` (region 0: the guard's outer strip, region
    j + 1: window j). Window j's strip is region j; its reference, windows j+2 ..
    j+1+_NOISE_REF_WINDOWS pooled (not j+1: the window read when test j fails must not have made
    it fail)."""
    nj = cnt.shape[1] - 1
    c1, c2, q1, q2, cc = (
        np.concatenate([np.zeros((cnt.shape[0], 1)), np.cumsum(x, axis=1)], axis=1)
        for x in (s1, s2, p1, p2, cnt)
    )
    j = np.arange(nj)
    bottom, top = np.minimum(j + 3, nj + 1), np.minimum(j + 3 + _NOISE_REF_WINDOWS, nj + 1)
    r_cnt, r_s1, r_s2, r_p1, r_p2 = (x[:, top] - x[:, bottom] for x in (cc, c1, c2, q1, q2))
    t_cnt, t_s1 = cnt[:, :nj], s1[:, :nj]
    usable = cnt[:, 1:] >= _MIN_NOISE_BINS
    with np.errstate(invalid="ignore", divide="ignore"):
        r_mean = r_s1 / r_cnt
        m2 = r_mean**2
        # Relative variance of one bin (1 for a periodogram, 1/K for K power-averaged ones).
        var = np.clip(r_s2 / r_cnt - m2, 0.0, m2)
        # Neighbouring bins are correlated: zero_pad at a time by the padding, and over a few
        # native bins when the noise is gated (the LO pulse, the record gate): the mean of n
        # bins has the variance of n / (zero_pad (1 + 2 rho_1 + 2 rho_2)) independent ones.
        rho = sum(np.clip((p / r_cnt - m2) / var, 0.0, 1.0) for p in (r_p1, r_p2))
        se = np.sqrt(var / m2 * zero_pad * (1.0 + 2.0 * rho) * (1.0 / t_cnt + 1.0 / r_cnt))
        # Too few bins to test (band edges, a narrow band): no evidence of a skirt.
        untested = (t_cnt < _MIN_NOISE_BINS) | (r_cnt < _MIN_NOISE_BINS)
        flat = usable & (untested | (t_s1 / t_cnt <= r_mean * (1.0 + _NOISE_FLAT_Z * se)))
    return flat, usable


def analyze_records(
    v: np.ndarray,
    fs_hz: float,
    load_ohm: float,
    *,
    rbw_hz: float,
    highpass_hz: float,
    zero_pad: int,
    peak_method: str,
    noise_span_hz: float,
    noise_guard_hz: float,
    averaging: str = "coherent",
    transfer=None,
    keep_spectrum: bool = False,
    search_max_hz: float | None = None,
) -> PeakResult:
    """Spectrum, peak, 3 dB points, noise level and SNR of voltage records.

    Parameters
    ----------
    v : ndarray, shape (batch, averages, N), float64, volts across ``load_ohm``.
    transfer : callable f_hz -> complex gain (detector response of a linear chain), or None. Only
        its power gain |H(f)|^2 matters to the spectrum, so it is applied to the PSD.
    """
    v = np.asarray(v)
    if v.ndim != 3:
        raise ValueError("analyze_records expects (batch, averages, N) records")
    n = v.shape[-1]
    m = n * zero_pad
    if averaging == "coherent" and v.shape[1] > 1:
        v = v.mean(axis=1, keepdims=True)
    X = scipy.fft.rfft(v, n=m, axis=-1, workers=-1)
    # One-sided PSD in W/Hz (eqs. 2.6.3-2.6.4 made one-sided).
    power = X.real**2 + X.imag**2
    psd = (2.0 / (n * fs_hz * load_ohm)) * (
        power[:, 0] if power.shape[1] == 1 else power.mean(axis=1)
    )
    return analyze_spectrum(
        psd,
        fs_hz,
        n,
        zero_pad=zero_pad,
        rbw_hz=rbw_hz,
        highpass_hz=highpass_hz,
        peak_method=peak_method,
        noise_span_hz=noise_span_hz,
        noise_guard_hz=noise_guard_hz,
        transfer=transfer,
        keep_spectrum=keep_spectrum,
        search_max_hz=search_max_hz,
        dft=X,
        load_ohm=load_ohm,
    )


def _parabolic_peak(psd, f, kp, f_pk, p_pk, fs_hz: float, m: int):
    """(f_pk, p_pk): the peaks at bins ``kp`` refined by a parabola through the log PSD of the
    bin and its neighbours (bins fs_hz / m apart); the end bins keep ``f_pk`` and ``p_pk``."""
    n_bins = psd.shape[1]
    rows = np.arange(psd.shape[0])
    tiny = np.finfo(float).tiny
    inner = (kp > 0) & (kp < n_bins - 1)
    k0 = np.clip(kp, 1, n_bins - 2)
    lg = np.log(
        np.maximum(
            np.stack([psd[rows, k0 - 1], psd[rows, k0], psd[rows, k0 + 1]], dtype=float), tiny
        )
    )
    d = np.where(inner, _parabolic_batch(*lg), 0.0)
    f_pk = np.where(inner, f[kp] + d * fs_hz / m, f_pk)
    p_pk = np.where(inner, np.exp(lg[1] - 0.25 * (lg[0] - lg[2]) * d), p_pk)
    return f_pk, p_pk


def _dtft_peak(dft, kp, n, zero_pad, fs_hz, load_ohm, highpass_hz, search_max_hz, transfer):
    """(f_pk, p_pk, lo, hi): peak frequency (Hz) and PSD (W/Hz), and 3 dB points (Hz, NaN
    where none), from the records' DTFT on a fine grid about the padded-PSD peak bins ``kp``."""
    rows = np.arange(kp.shape[0])
    tiny = np.finfo(float).tiny
    df_native = fs_hz / n
    # Native-grid DFT is every zero_pad-th padded bin (coherent records only).
    k_nat = np.rint(kp / zero_pad).astype(int)
    top = n / 2 if search_max_hz is None else min(n / 2, search_max_hz / df_native)
    nu = k_nat[:, None] + _OFFSETS[None, :]  # (B, F)
    valid = (nu * df_native >= highpass_hz) & (nu <= top)
    native = dft[..., ::zero_pad]  # (B, A, n // 2 + 1)
    cols = k_nat[:, None] + _MREL[None, :]  # (B, 2 half_w + 1)
    inside = (cols >= 0) & (cols < native.shape[2])  # bins beyond the ends: 0
    near = np.take_along_axis(
        native,
        np.broadcast_to(
            np.clip(cols, 0, native.shape[2] - 1)[:, None, :], native.shape[:2] + cols.shape[1:]
        ),
        axis=2,
    )
    near = np.multiply(near, inside[:, None, :], dtype=complex)  # complex128 for BLAS
    fine = (near.reshape(-1, near.shape[2]) @ _dirichlet_kernel(n).T).reshape(
        near.shape[:2] + (-1,)
    )  # (B, A, F), one GEMM
    Pn = (fine.real**2 + fine.imag**2).sum(axis=1) * (
        2.0 / (n * fs_hz * load_ohm * native.shape[1])
    )
    if transfer is not None:
        Pn *= np.abs(transfer(nu * df_native)) ** 2
    Pm = np.where(valid, Pn, -np.inf)
    i = np.argmax(Pm, axis=1)
    n_fine = _OFFSETS.size
    has_nb = (i > 0) & (i < n_fine - 1)
    im, ip = np.clip(i - 1, 0, n_fine - 1), np.clip(i + 1, 0, n_fine - 1)
    has_nb &= valid[rows, im] & valid[rows, ip]
    lg = np.log(np.maximum(np.stack([Pn[rows, im], Pn[rows, i], Pn[rows, ip]]), tiny))
    d = np.where(has_nb, _parabolic_batch(*lg), 0.0)
    f_pk = (nu[rows, i] + d * _FINE_STEP) * df_native
    p_pk = np.where(d == 0.0, Pn[rows, i], np.exp(lg[1] - 0.25 * (lg[0] - lg[2]) * d))
    # 3 dB points on the fine DTFT, within its valid rows.
    v_lo = np.argmax(valid, axis=1)
    v_hi = n_fine - 1 - np.argmax(valid[:, ::-1], axis=1)
    lo, hi = _crossings(nu * df_native, Pn, 0.5 * p_pk, i, v_lo, v_hi)
    return f_pk, p_pk, lo, hi


def _whole_band_noise(noise, n_win, psd, f, f_pk, first, last, guard_hz: float) -> None:
    """Where fewer than ``_MIN_NOISE_BINS`` bins lie beside the peak, set ``noise`` (in place)
    to the mean PSD of the whole search band (bins first..last) without the guard bins."""
    g0 = np.clip(np.searchsorted(f, f_pk - guard_hz), first, last + 1)
    g1 = np.clip(np.searchsorted(f, f_pk + guard_hz, side="right"), first, last + 1)
    few = np.flatnonzero(n_win < _MIN_NOISE_BINS)
    if few.size:
        s_all = np.sum(psd[few, first : last + 1], axis=1, dtype=float) - _range_sums(
            psd[few], g0[few], g1[few]
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            noise[few] = s_all / ((last + 1 - first) - (g1[few] - g0[few]))


def _detected_psd(psd, transfer, f, m: int, fs_hz: float) -> np.ndarray:
    """A copy of ``psd`` times the detector's |transfer|^2 on the bins ``f`` (if any).

    Single-precision spectra (the baseband tier's) stay single for the passes over every bin;
    values read from them are taken in double.
    """
    dtype = np.float32 if np.asarray(psd).dtype == np.float32 else np.float64
    if transfer is not None:
        h = transfer.on_grid(m, fs_hz) if hasattr(transfer, "on_grid") else transfer(f)
        return np.multiply(psd, (h.real**2 + h.imag**2).astype(dtype), dtype=dtype)
    return np.array(psd, dtype=dtype)


def analyze_spectrum(
    psd: np.ndarray,
    fs_hz: float,
    n: int,
    *,
    zero_pad: int,
    rbw_hz: float,
    highpass_hz: float,
    peak_method: str,
    noise_span_hz: float,
    noise_guard_hz: float,
    transfer=None,
    keep_spectrum: bool = False,
    search_max_hz: float | None = None,
    dft: np.ndarray | None = None,
    load_ohm: float | None = None,
) -> PeakResult:
    """Peak, 3 dB points, noise level and SNR of one-sided PSDs (batch, m // 2 + 1) in W/Hz of
    records of ``n`` samples zero-padded to m = n x ``zero_pad`` (before the detector transfer).

    The 'dtft' method needs the records' DFT ``dft`` (batch, averages, m // 2 + 1) and
    ``load_ohm``; 'bin' and 'parabolic' read the PSD only. Every step is vectorised over the batch.
    """
    batch, n_bins = np.shape(psd)
    m = n * zero_pad
    f = np.arange(n_bins) * (fs_hz / m)
    psd = _detected_psd(psd, transfer, f, m, fs_hz)
    df_native = fs_hz / n
    search = f >= highpass_hz
    if search_max_hz is not None:
        search &= f <= search_max_hz
    if not np.any(search):
        raise ValueError(
            "no FFT bin between processing.highpass_hz (sys.f_highpass) and the peak search maximum"
        )
    first = int(np.argmax(search))
    last = int(n_bins - 1 - np.argmax(search[::-1]))
    rows = np.arange(batch)
    kp = first + np.argmax(psd[:, first : last + 1], axis=1)
    f_pk, p_pk = f[kp], psd[rows, kp].astype(float)
    lo = hi = None
    if peak_method == "parabolic":
        f_pk, p_pk = _parabolic_peak(psd, f, kp, f_pk, p_pk, fs_hz, m)
    elif peak_method == "dtft":
        if dft is None or load_ohm is None:
            raise ValueError("peak_method 'dtft' needs the records' DFT (use analyze_records)")
        f_pk, p_pk, lo, hi = _dtft_peak(
            dft, kp, n, zero_pad, fs_hz, load_ohm, highpass_hz, search_max_hz, transfer
        )
    elif peak_method != "bin":
        raise ValueError(
            f"processing.peak_method must be 'bin', 'parabolic' or 'dtft', got {peak_method!r}"
        )
    # 3 dB points on the (padded) spectrum where the fine grid has none.
    zeros, ends = np.zeros(batch, int), np.full(batch, n_bins - 1)
    s_lo, s_hi = _crossings(f, psd, 0.5 * p_pk, kp, zeros, ends, window=_CROSSING_WINDOW)
    lo = s_lo if lo is None else np.where(np.isnan(lo), s_lo, lo)
    hi = s_hi if hi is None else np.where(np.isnan(hi), s_hi, hi)
    lo = np.where(np.isnan(lo), f[first], lo)
    hi = np.where(np.isnan(hi), f[-1], hi)
    # Noise: mean PSD over a span beside the peak, guard bins excluded, within the search band
    # (the bins first..last), moved outward past the tone's own skirt (see _noise_floor).
    noise, n_win = _noise_floor(psd, f, f_pk, first, last, noise_span_hz, noise_guard_hz, zero_pad)
    _whole_band_noise(noise, n_win, psd, f, f_pk, first, last, noise_guard_hz)
    peak_w = p_pk * df_native  # tone power, eq. 2.6.6 with df = 1/T
    return PeakResult(
        f_peak_hz=np.asarray(f_pk, float),
        peak_power_w=np.asarray(peak_w, float),
        noise_psd_w_per_hz=noise,
        f_lo_hz=lo,
        f_hi_hz=hi,
        snr=peak_w / (noise * rbw_hz),
        spectrum_f_hz=f if keep_spectrum else None,
        spectrum_w_per_hz=psd.astype(float) if keep_spectrum else None,
    )
