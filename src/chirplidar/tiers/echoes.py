"""Sub-returns of a beam footprint for the rf and baseband tiers (sloped or rough terrain).

A beam on real terrain spans a range of distances: a survey casts sub-rays over the beam's
divergence and hands the rf and baseband tiers, per shot, echoes built from them (extra
round-trip delay, power share and carrier phase of each): :class:`Echoes`. The tiers sum the
delayed echoes coherently, so the beat peak spreads over kappa x (the footprint's delay spread).

The sub-rays sample the footprint; they are not scatterers, and their optical path differences
(2 k0 (R_k - R_l), thousands of wavelengths) must not interfere: summed with amplitudes
sqrt(w_k) and their propagation phases they would return anything up to (sum_k sqrt(w_k))^2
times the power (6.4 times on flat snow with 7 sub-rays). :func:`footprint_echoes` builds the
echoes:

* speckle on: each sub-ray's patch returns its own speckle field sqrt(w_k) z_k (the speckle
  effect's draw per sub-ray, circular complex Gaussian for M = 1) at its own delay: mean power
  sum_k w_k, exponential for an unresolved footprint, the mean spectrum the power-weighted sum of
  the sub-rays' lines;
* speckle off: the mean return, deterministically: echoes on the chirp's resolution grid around
  the power-weighted mean delay, with the mean line's powers (:func:`footprint_cells`) and one
  common phase, their record energy held at the mean power (:func:`footprint_coherence`). An
  unresolved footprint is one echo of its whole power; a spread one draws the mean line.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .model import Instrument

_FIELDS = ("delay_offset_s", "power_weight", "phase_rad")


@dataclass(frozen=True)
class Echoes:
    """Sub-returns of each shot's footprint.

    delay_offset_s: (batch, k) or (k,) extra round-trip delay of each echo relative to the budget's
        delay (s, may be negative)
    power_weight:   (batch, k) or (k,) share of the received power in each echo (>= 0; normalised
        to sum 1 per shot by the rf tier)
    phase_rad:      (batch, k) or (k,) carrier phase of each echo (rad), added to the shot's own
        carrier phase (channel.carrier_phase, speckle, Doppler, laser phase noise).

    The tiers sum the echoes coherently, with amplitudes sqrt(w_k) (w normalised) and their phases:
    echoes are fields, not powers. Footprint samples are not scatterers, so a caller must not
    give them their optical propagation phases 2 pi nu dtau_k (the samples would interfere:
    anything from 0 to (sum_k sqrt(w_k))^2 times the power). The survey runs
    (:func:`footprint_echoes`) pass each sub-ray's speckle field for a diffuse
    surface (weight w_k |z_k|^2, phase arg z_k), and otherwise the mean line's resolution-cell
    echoes with one common phase; both keep the footprint's mean power.

    A (k,) array is shared by every shot of the batch. A single echo of offset 0, weight 1 and
    phase 0 is the echo-free shot. Arrays are stored as read-only float64.
    """

    delay_offset_s: np.ndarray
    power_weight: np.ndarray
    phase_rad: np.ndarray

    def __post_init__(self):
        ks, rows = set(), set()
        for name in _FIELDS:
            raw = getattr(self, name)
            try:
                arr = np.array(raw, dtype=np.float64)  # a copy: the caller may reuse its array
            except (TypeError, ValueError):
                raise ValueError(
                    f"echoes.{name} must be a real array of shape (batch, k) or (k,)"
                ) from None
            if arr.ndim not in (1, 2) or arr.shape[-1] == 0:
                raise ValueError(
                    f"echoes.{name} must have shape (batch, k) or (k,) with k >= 1; "
                    f"got shape {arr.shape}"
                )
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"echoes.{name} must be finite (got NaN or inf)")
            ks.add(arr.shape[-1])
            if arr.ndim == 2:
                rows.add(arr.shape[0])
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        shapes = ", ".join(f"{n} {getattr(self, n).shape}" for n in _FIELDS)
        if len(ks) > 1:
            raise ValueError(
                f"echoes fields must share the number of echoes k (last axis); got {shapes}"
            )
        if len(rows) > 1:
            raise ValueError(f"echoes fields of shape (batch, k) must share batch; got {shapes}")
        w = self.power_weight
        if np.any(w < 0):
            raise ValueError("echoes.power_weight must be >= 0")
        if np.any(np.sum(w, axis=-1) <= 0):
            raise ValueError("echoes.power_weight must have a positive sum for every shot")

    @property
    def k(self) -> int:
        """Number of echoes per shot."""
        return int(self.power_weight.shape[-1])

    def for_batch(self, batch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(delay_offset_s, normalised power weight, phase_rad), each of shape (batch, k).

        Raises ValueError when a (batch, k) field does not have ``batch`` rows.
        """
        out = []
        for name in _FIELDS:
            arr = getattr(self, name)
            if arr.ndim == 2 and arr.shape[0] != batch:
                raise ValueError(
                    f"echoes.{name} must have shape (batch, k) = ({batch}, {self.k}) "
                    f"or ({self.k},); got {arr.shape}"
                )
            out.append(np.broadcast_to(arr, (batch, self.k)))
        offsets, w, phases = out
        return offsets, w / np.sum(w, axis=-1, keepdims=True), phases


_GRAM_POINTS = 2048  # time grid of the footprint's coherence factor (over one record)
_GRAM_BLOCK = 1 << 21  # shots x sub-rays x points per block


def chirp_overlap(config: Instrument, bud):
    """The record's overlap of the two chirps on a grid: (instantaneous frequency of the return
    f(t) [Hz], beat amplitude envelope A(t) >= 0, duration of one chirp's overlap [s]: the
    equivalent rectangular duration (sum A)^2 / sum A^2 per chirp), where A > 0."""
    train = bud.train
    dur = config.simulation.duration_s
    dt = dur / _GRAM_POINTS
    t = (np.arange(_GRAM_POINTS) + 0.5) * dt
    tc_sig = train.time_in_chirp(t - bud.delay_s)
    env = (
        train.envelope(train.time_in_chirp(t - bud.ref_delay_s))
        * train.envelope(tc_sig)
        * train.record_gate(t, dur)
    )
    keep = env > 0
    if not np.any(keep):
        return np.zeros(0), np.zeros(0), 0.0
    a = env[keep]
    chirps = max(1, int(np.floor(dur / train.period_s + 1e-9)))
    t_eq = float(a.sum() ** 2 / np.sum(a * a)) * dt / chirps
    return train.f_start_hz + train.rate_hz_per_s * tc_sig[keep], a, t_eq


def footprint_coherence(config: Instrument, bud, amplitude, dtau_s) -> np.ndarray:
    """(m,) record energy of the common-phase beat sum_k a_k b_k(t) relative to one sub-ray's:
    <A^2(t) |sum_k a_k exp(j 2 pi f(t) dtau_k)|^2> / <A^2(t)>, for amplitudes with sum_k a_k = 1.

    b_k is the beat of a sub-ray delayed by dtau_k: the same tone as at dtau = 0 with the extra
    phase 2 pi f(t) dtau_k, f(t) the instantaneous chirp frequency of the return (f_start +
    kappa t_c), under the overlap envelope A(t) of the two chirps in the record (``bud``: the
    instrument at the shots' range). Two sub-rays' beats correlate as <A^2 cos(2 pi f dtau_kl)> /
    <A^2> = cos(2 pi f_c dtau_kl) sinc(B dtau_kl) for a linear chirp over the band B about f_c:
    1 for an unresolved footprint (the factor is then 1), -> 0 once the range spread is resolved
    (the factor -> sum_k a_k^2). ``amplitude`` (m, k) >= 0, summing to 1 per shot; ``dtau_s``
    (m, k) delay offsets (a common offset cancels). The beat's harmonics are left out.
    """
    a = np.asarray(amplitude, float)
    d = np.asarray(dtau_s, float)
    m, k = a.shape
    f, env, _ = chirp_overlap(config, bud)
    if f.size == 0 or m == 0:
        return np.ones(m)
    a2 = env * env / np.sum(env * env)
    out = np.empty(m)
    rows = max(1, _GRAM_BLOCK // (k * f.size))
    for s0 in range(0, m, rows):
        sl = slice(s0, min(m, s0 + rows))
        ph = 2 * np.pi * (d[sl, :, None] - d[sl, :1, None]) * f[None, None, :]  # (r, k, p)
        re = np.einsum("rk,rkp->rp", a[sl], np.cos(ph))
        im = np.einsum("rk,rkp->rp", a[sl], np.sin(ph))
        out[sl] = (re * re + im * im) @ a2
    return out


_CELL_MARGIN = 3  # resolution cells beyond the footprint's extreme delays
_CELL_FLOOR = 1e-3  # cells below this share of the strongest are left out (-30 dB)


def footprint_cells(config: Instrument, bud, share, dtau_s):
    """The mean (speckle-averaged) line of a footprint as echoes on the chirp's resolution grid:
    (delay offsets (m, J), powers (m, J)), J cells per shot (unused cells padded with power 0).

    A diffuse footprint's mean beat spectrum is sum_k w_k |T(f - kappa tau_k)|^2 (each sub-ray's
    line, weighted by its power share: the speckle phases average the cross terms away). Tones
    spaced by one resolution cell, delta = 1 / (kappa T_ov) (T_ov the equivalent rectangular
    overlap of one chirp), are orthogonal over the record, so echoes at tau_bar + j delta with
    powers W_j = sum_k w_k sinc^2((tau_k - tau_bar) / delta - j) draw that line exactly at the
    grid's frequencies, whatever their carrier or RF phases, with sum_j W_j = 1 (the sinc^2
    shifts sum to 1). tau_bar is the power-weighted mean delay: a footprint the chirp does not
    resolve is one echo there of the whole power (W_0 -> 1); a resolved one spreads over the
    cells in proportion to its power-weighted delays. ``share`` (m, k): power shares (sum 1),
    ``dtau_s`` (m, k) delay offsets.
    """
    w = np.asarray(share, float)
    d = np.asarray(dtau_s, float)
    m = w.shape[0]
    _, _, t_ov = chirp_overlap(config, bud)
    band = bud.train.rate_hz_per_s * t_ov
    tbar = np.sum(w * d, axis=-1, keepdims=True)  # (m, 1)
    if band <= 0 or m == 0:
        return tbar, np.ones((m, 1))
    delta = 1.0 / band
    x = np.where(w > 0, (d - tbar) / delta, 0.0)
    lo = np.floor(x.min(axis=-1)).astype(int) - _CELL_MARGIN
    hi = np.ceil(x.max(axis=-1)).astype(int) + _CELL_MARGIN
    j = lo[:, None] + np.arange(int(np.max(hi - lo)) + 1)  # (m, J): per shot
    cells = np.einsum("mk,mkj->mj", w, np.sinc(x[..., None] - j[:, None, :]) ** 2)
    cells = np.where(cells >= _CELL_FLOOR * cells.max(axis=-1, keepdims=True), cells, 0.0)
    # Each shot's cells in use first (a footprint split between two surfaces skips the gap).
    order = np.argsort(cells <= 0, axis=-1, kind="stable")
    cells = np.take_along_axis(cells, order, axis=-1)
    j = np.take_along_axis(j, order, axis=-1)
    used = np.any(cells > 0, axis=0)
    return tbar + j[:, used] * delta, cells[:, used]


def footprint_echoes(config: Instrument, bud, frac, dtau_s, fields=None):
    """A footprint's sub-rays as tier echoes: (delay_offset_s (m, J), power_weight (m, J),
    phase_rad (m, J), gain (m,)).

    The tiers sum the echoes as sum_j sqrt(u_j) exp(j phi_j) x (the signal delayed by the
    echo's offset), with the weights u normalised to sum 1 per shot, and scale the shot's received
    power by its power factor; ``gain`` is the factor to multiply that power factor with.
    ``frac`` (m, k): the sub-rays' received power shares w_k (unnormalised, each shot with one
    > 0); ``dtau_s`` (m, k) their delay offsets; ``bud``: the instrument at the shots' range.

    Sub-rays sample the footprint; they are not scatterers, so their optical path differences
    (2 k0 (R_k - R_l): thousands of wavelengths) must not interfere:

    * ``fields`` (m, k) complex (speckle on,
      ``chirplidar.channel.footprint.subray_speckle_fields``): each sub-ray's patch
      returns the field sqrt(w_k) z_k at its own delay. Echo weights w_k |z_k|^2, phases from
      arg z_k, gain sum_k w_k |z_k|^2 / sum_k w_k: an unresolved footprint's power is
      |sum_k sqrt(w_k) z_k|^2 (exponential of mean 1 for M = 1, circular Gaussian fields), a
      resolved one's lines carry w_k |z_k|^2; the mean spectrum is the power-weighted one.
    * no fields (speckle off): the mean return, deterministically, with one common phase: the
      resolution-cell echoes of :func:`footprint_cells` (one echo of the whole power at the
      power-weighted mean delay when the chirp does not resolve the footprint). ``gain`` =
      sum a_j^2 / :func:`footprint_coherence` (a_j = sqrt(W_j) / sum sqrt(W)) keeps the record's
      beat energy at the mean power's (about 1; it absorbs the window's taper and the truncated
      sinc^2 tails), so the footprint returns its mean power and a spread footprint broadens the
      line without interference gain or loss.
    """
    w = np.asarray(frac, float)
    tot = w.sum(axis=-1, keepdims=True)
    share = w / np.where(tot > 0, tot, 1.0)
    if fields is not None:
        z = np.asarray(fields)
        pw = share * (z.real**2 + z.imag**2)
        return np.asarray(dtau_s, float), pw, np.angle(z), pw.sum(axis=-1)
    delays, cells = footprint_cells(config, bud, share, dtau_s)
    a = np.sqrt(cells)
    a = a / a.sum(axis=-1, keepdims=True)
    coh = footprint_coherence(config, bud, a, delays)
    return delays, cells, np.zeros_like(cells), np.sum(a * a, axis=-1) / np.maximum(coh, 1e-300)
