"""Range estimators of a pulsed altimeter's digitized waveform, their bound and the threshold's
detection and false-alarm probabilities.

Every estimator takes a batch of waveforms, (batch, n) primary photoelectrons per sample, at the
sample times ``t_s`` (n,) (the bins' centres), and is vectorised over the batch:

* :func:`threshold_crossing`: the first upward crossing of the detection threshold, linearly
  interpolated between the samples around it (a leading-edge discriminator);
* :func:`centroid`: the first moment (and the RMS width) of the background-subtracted samples
  over the crossing region (:func:`strongest_region`: the run above the threshold that holds
  the largest sample), widened by a few samples either side;
* :func:`gaussian_fit`: A exp(-(t - t0)^2 / 2 s^2) + b by weighted least squares, weights the
  inverse of the modelled variance slope x mu(t) + floor re-evaluated at each iteration
  (iteratively reweighted, Levenberg-Marquardt with a fixed number of iterations and batched
  4 x 4 solves; the Gaussian fit of GLAS's waveform processing, Brenner et al. 2003, GLAS
  ATBD "Derivation of range and range distributions from laser pulse waveform analysis").

:func:`arrival_time_crb_s` is the Cramer-Rao bound of the arrival time from the Fisher
information of independent samples of mean mu_k(t0) and variance v_k (Kay 1993, "Fundamentals of
Statistical Signal Processing I", eq. 3.33, the mean-information term).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammainc, ndtr
from scipy.stats import norm, poisson

_TINY = 1e-300


def threshold_crossing(waveforms, threshold, t_s):
    """(t_cross (batch,) s, index (batch,) int) of the first sample j with w_j >= thr_j whose
    predecessor lies below the threshold (sample 0 counts when it is above), interpolated
    linearly: t_{j-1} + (thr_j - w_{j-1}) / (w_j - w_{j-1}) dt. NaN and -1 where nothing
    crosses. ``threshold``: broadcast to the waveforms' shape."""
    w = np.asarray(waveforms, float)
    thr = np.broadcast_to(np.asarray(threshold, float), w.shape)
    t = np.asarray(t_s, float)
    above = w >= thr
    rising = above.copy()
    rising[:, 1:] &= ~above[:, :-1]
    hit = rising.any(axis=1)
    j = np.where(hit, np.argmax(rising, axis=1), -1)
    rows = np.arange(w.shape[0])
    jj = np.maximum(j, 1)
    w0, w1, th = w[rows, jj - 1], w[rows, jj], thr[rows, jj]
    frac = np.clip((th - w0) / np.where(w1 > w0, w1 - w0, 1.0), 0.0, 1.0)
    dt = t[1] - t[0] if t.size > 1 else 0.0
    t_cross = np.where(j == 0, t[0], t[jj - 1] + frac * dt)
    return np.where(hit, t_cross, np.nan), j


def window_sums(waveforms, n: int):
    """(batch, m) sums over ``n`` consecutive samples centred on each sample (the samples
    beyond the record count as zero): a photon counter's detection window, which gathers a
    pulse's counts when its dead time leaves at most one count per sample."""
    w = np.asarray(waveforms, float)
    if n <= 1:
        return w
    c = np.cumsum(np.pad(w, ((0, 0), (n // 2 + 1, n - n // 2 - 1))), axis=1)
    return c[:, n:] - c[:, :-n]


def strongest_region(waveforms, threshold):
    """(start, stop) sample indices, each (batch,), of the run of samples at or above
    ``threshold`` that holds the waveform's largest sample ([start, stop)); -1, -1 where that
    sample lies below the threshold. A noise spike that crosses first does not capture it."""
    w = np.asarray(waveforms, float)
    thr = np.broadcast_to(np.asarray(threshold, float), w.shape)
    n = w.shape[1]
    idx = np.arange(n)[None, :]
    j_pk = np.argmax(w, axis=1)[:, None]
    above = w >= thr
    hit = np.take_along_axis(above, j_pk, axis=1)[:, 0]
    before = ~above & (idx < j_pk)
    start = np.where(before.any(axis=1), n - 1 - np.argmax(before[:, ::-1], axis=1) + 1, 0)
    after = ~above & (idx > j_pk)
    stop = np.where(after.any(axis=1), np.argmax(after, axis=1), n)
    return np.where(hit, start, -1), np.where(hit, stop, -1)


def centroid(waveforms, background, t_s, start, stop, pad_samples: int):
    """(t_c, rms width, valid), each (batch,): the first moment sum (w - b) t / sum (w - b) and
    the square root of the second central moment of the background-subtracted samples from
    ``pad_samples`` before ``start`` to ``pad_samples`` after ``stop`` (the crossing region,
    e.g. :func:`strongest_region`). Shots without a region (start -1) or with a non-positive
    sum are invalid (NaN)."""
    w = np.asarray(waveforms, float)
    b = np.broadcast_to(np.asarray(background, float), w.shape)
    t = np.asarray(t_s, float)
    j0, j1 = np.asarray(start)[:, None], np.asarray(stop)[:, None]
    idx = np.arange(w.shape[1])[None, :]
    window = (idx >= j0 - pad_samples) & (idx < j1 + pad_samples) & (j0 >= 0)
    x = np.where(window, w - b, 0.0)
    total = x.sum(axis=1)
    ok = total > 0
    safe = np.where(ok, total, 1.0)
    tc = (x @ t) / safe
    var = (x * (t[None, :] - tc[:, None]) ** 2).sum(axis=1) / safe
    width = np.sqrt(np.clip(var, 0.0, None))
    return np.where(ok, tc, np.nan), np.where(ok, width, np.nan), ok


@dataclass(frozen=True)
class GaussianFit:
    """A batch of Gaussian fits: centre t0 (s), RMS width s (s), amplitude A and background b
    (photoelectrons per sample), and ``valid``: converged, finite, A > 0 and t0 inside the
    fitted window."""

    t0_s: np.ndarray
    sigma_s: np.ndarray
    amplitude: np.ndarray
    background: np.ndarray
    valid: np.ndarray


def _gauss_model(p, x):
    u = (x - p[:, 1:2]) / p[:, 2:3]
    g = np.exp(-0.5 * u * u)
    a_g = p[:, 0:1] * g
    m = a_g + p[:, 3:4]
    jac = np.stack([g, a_g * u / p[:, 2:3], a_g * u * u / p[:, 2:3], np.ones_like(g)], axis=-1)
    return m, jac


def _fit_windows(w, t0, half):
    """(samples (batch, L), their indices (batch, L) as floats, in-window mask (batch, L)):
    each shot's samples within ``half`` of ``t0`` (sample units), gathered to a common length."""
    n = w.shape[1]
    length = int(min(n, 2 * np.ceil(half.max()) + 3))
    first = np.clip(np.round(t0).astype(np.int64) - length // 2, 0, n - length)
    idx = first[:, None] + np.arange(length)[None, :]
    x = idx.astype(float)
    return np.take_along_axis(w, idx, axis=1), x, np.abs(x - t0[:, None]) <= half[:, None]


def _lm_step(p, x, w, mask, slope, floor, lam):
    """One Levenberg-Marquardt step: (new parameters, |d t0|, step kept)."""
    m, jac = _gauss_model(p, x)
    weight = mask / (slope * np.maximum(m, 0.0) + floor)
    r = w - m
    chi2 = np.einsum("bn,bn->b", weight, r * r)
    wj = jac * weight[:, :, None]
    h = np.einsum("bni,bnj->bij", wj, jac)
    g = np.einsum("bni,bn->bi", wj, r)
    diag = np.einsum("bii->bi", h)
    damp = lam[:, None] * diag + 1e-12 * diag.sum(axis=1, keepdims=True) + _TINY
    delta = np.linalg.solve(h + damp[:, :, None] * np.eye(4), g[:, :, None])[:, :, 0]
    trial = p + delta
    trial[:, 2] = np.abs(trial[:, 2])
    m_new, _ = _gauss_model(trial, x)
    better = np.einsum("bn,bn->b", weight, (w - m_new) ** 2)
    better = np.isfinite(better) & (better <= chi2)
    return np.where(better[:, None], trial, p), np.abs(delta[:, 1]), better


def gaussian_fit(
    waveforms,
    t_s,
    init_t0_s,
    init_sigma_s,
    init_background,
    variance_slope,
    variance_floor,
    *,
    window_sigmas: float = 5.0,
    iterations: int = 30,
):
    """Weighted least-squares fit of A exp(-(t - t0)^2 / 2 s^2) + b to each waveform over the
    samples within ``window_sigmas`` x the initial width of the initial centre (at least 4
    samples either side): Levenberg-Marquardt steps (J^T W J + lambda diag) delta = J^T W r,
    a step kept only where it lowers the weighted residual (lambda / 3, else x 10), weights
    W = 1 / (variance_slope x max(mu, 0) + variance_floor) re-evaluated from the current model
    each iteration (the Poisson or excess-noise shot noise of the model plus a floor: circuit
    noise, quantisation). ``t_s``: uniformly spaced sample times. Returns :class:`GaussianFit`
    (valid: converged, |d t0| < 1e-3 sample at the last kept step); invalid shots hold NaN."""
    w = np.asarray(waveforms, float)
    t = np.asarray(t_s, float)
    dt = float(t[1] - t[0])
    batch = w.shape[0]
    t0 = (np.asarray(init_t0_s, float) - t[0]) / dt  # sample units: well-scaled equations
    s0 = np.maximum(np.asarray(init_sigma_s, float) / dt, 0.5)
    b0 = np.broadcast_to(np.asarray(init_background, float), (batch,))
    start = np.isfinite(t0) & np.isfinite(s0)
    t0, s0 = np.where(start, t0, 0.0), np.where(start, s0, 1.0)
    half = np.maximum(window_sigmas * s0, 4.0)
    ws, x, mask = _fit_windows(w, t0, half)
    near = np.where(mask, ws, -np.inf).max(axis=1)
    p = np.stack([np.maximum(near - b0, 1e-6), t0, s0, b0], axis=1)
    floor = np.broadcast_to(np.asarray(variance_floor, float), (batch,))[:, None]
    lam = np.full(batch, 1e-3)
    step_t0 = np.full(batch, np.inf)
    for _ in range(iterations):
        p, d_t0, better = _lm_step(p, x, ws, mask, variance_slope, floor, lam)
        # a step refused at a large damping: the fit sits at its minimum
        step_t0 = np.where(better, d_t0, np.where(lam > 1e6, 0.0, step_t0))
        lam = np.clip(np.where(better, lam / 3.0, lam * 10.0), 1e-9, 1e9)
    valid = (
        start
        & np.all(np.isfinite(p), axis=1)
        & (p[:, 0] > 0)
        & (step_t0 < 1e-3)
        & (np.abs(p[:, 1] - t0) <= half)
        & (p[:, 2] < 2 * half)
    )
    nan = np.where(valid, 1.0, np.nan)
    return GaussianFit(
        t0_s=(t[0] + p[:, 1] * dt) * nan,
        sigma_s=p[:, 2] * dt * nan,
        amplitude=p[:, 0] * nan,
        background=p[:, 3] * nan,
        valid=valid,
    )


def arrival_time_crb_s(dmu_dt0, variance):
    """1 / sqrt(sum_k (d mu_k / d t0)^2 / v_k) [s] (last axis: the samples): the Cramer-Rao
    bound of an arrival time t0 from independent samples of mean mu_k and variance v_k.

    For a symmetric pulse in a window symmetric about it the Fisher information's cross terms of
    t0 with the amplitude, width and background are sums of odd functions and vanish, so t0
    decouples and this bound holds with those parameters unknown too."""
    d = np.asarray(dmu_dt0, float)
    v = np.asarray(variance, float)
    return 1.0 / np.sqrt(np.sum(d * d / v, axis=-1))


def gaussian_false_alarm_probability(threshold_sigma: float, n_samples: int):
    """1 - (1 - Q(k))^N: the probability that any of N independent zero-signal Gaussian samples
    lies k = ``threshold_sigma`` standard deviations above its mean (Q(k) = 1 - Phi(k))."""
    q = norm.sf(threshold_sigma)
    return -np.expm1(n_samples * np.log1p(-q))


def gaussian_detection_probability(mean, std, threshold):
    """1 - prod_k Phi((thr_k - mu_k) / sigma_k) over the last axis: the probability that any
    independent Gaussian sample of mean mu_k and standard deviation sigma_k reaches its
    threshold (signal and false alarms alike)."""
    z = (np.asarray(threshold, float) - np.asarray(mean, float)) / np.asarray(std, float)
    return -np.expm1(np.sum(np.log(np.clip(ndtr(z), _TINY, 1.0)), axis=-1))


def poisson_min_count(mean_background, threshold_sigma: float):
    """The smallest count K with P(N >= K) <= Q(k) for a Poisson N of mean ``mean_background``
    (per sample): the photon-counting threshold with the false-alarm probability per sample of a
    Gaussian threshold k = ``threshold_sigma`` standard deviations up (K = 1 in the dark)."""
    mu = np.asarray(mean_background, float)
    q = norm.sf(threshold_sigma)
    k = np.where(mu > 0, poisson.isf(q, np.maximum(mu, _TINY)) + 1.0, 1.0)
    return np.maximum(k, 1.0).astype(np.int64)


def poisson_detection_probability(mean, min_count):
    """1 - prod_k P(N_k < K_k) over the last axis, N_k Poisson of mean mu_k: the probability
    that any sample counts ``min_count`` or more (thesis Table 2.5 for one sample, K = 1)."""
    mu = np.asarray(mean, float)
    k = np.broadcast_to(np.asarray(min_count), mu.shape)
    p_hit = np.where(mu > 0, gammainc(k, np.maximum(mu, _TINY)), 0.0)
    return -np.expm1(np.sum(np.log1p(-np.clip(p_hit, 0.0, 1.0 - 1e-16)), axis=-1))
