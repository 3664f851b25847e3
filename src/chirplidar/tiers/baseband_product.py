"""The baseband tier's low-pass optical product, the band it keeps and the field's peak.

The rf tier samples the modulator's field a(t) = cos(alpha + beta w(t) sin phi(t)) at GHz rates and
lets the photodiodes form the product a(t - tau_ref) a(t - tau). Here the Jacobi-Anger expansion
does that product analytically and keeps only what lies below the chirp's start frequency, the band
the beat is read in:

    [a_lo a_sig]_low = cos^2(alpha) J0(b_lo) J0(b_sig)
                       + sum_{n >= 1} 2 c_n J_n(b_lo) J_n(b_sig) cos(n (phi_lo - phi_sig)),

with b = beta w (the chirp envelope), c_n = sin^2(alpha) for odd n and cos^2(alpha) for even n,
and phi_lo - phi_sig the exact difference of the two chirps' phases (each from its own chirp start,
hold-time steps included): a tone at kappa x lag under the overlap envelope. Terms n != m beat at
multiples of the chirp frequency, above the band, and are left out; so are harmonics n f_B above
the band (they would alias).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import jv

from ..transmitter.mzm import mzm_drive_angles
from .budget import Budget, chirp_train
from .model import Instrument

# Bessel tables over the envelope w in [0, 1] (linear interpolation: error < (1/4096)^2 / 8 of
# J'' ~ 1e-8 of the beat amplitude).
_TABLE_POINTS = 4097
_HARMONIC_FLOOR = 1e-6  # harmonics whose amplitude is below this fraction of the fundamental


def band_top_hz(config: Instrument) -> float:
    """Top of the band the baseband tier simulates: ``processing.peak_search_max_hz``, else the
    chirp's start frequency F1 + F0 (the self-chirped product's other terms lie at and above it)."""
    top = config.processing.peak_search_max_hz
    if top is None:
        top = chirp_train(config.train).f_start_hz
    if top <= config.processing.highpass_hz:
        raise ValueError(
            f"baseband tier: the band top {top:g} Hz (processing.peak_search_max_hz, else the "
            f"chirp's start frequency waveform.f_start_hz + f_offset_hz) must lie above "
            f"processing.highpass_hz = {config.processing.highpass_hz:g} Hz; set "
            "processing.peak_search_max_hz"
        )
    return float(top)


def field_peak(config: Instrument, bud: Budget) -> float:
    """max |cos(alpha + beta w sin phi)| over the drive: 1 if alpha +- beta spans a peak of |cos|."""
    alpha, beta = mzm_drive_angles(bud.train, config.modulator.bias_v, config.modulator.v_pi_v)
    lo, hi = alpha - abs(beta), alpha + abs(beta)
    if np.floor(hi / np.pi) > np.floor(lo / np.pi) or np.isclose(np.mod(lo, np.pi), 0.0):
        return 1.0
    return float(max(abs(np.cos(lo)), abs(np.cos(hi))))


@lru_cache(maxsize=8)
def _bessel_table(beta: float, n_max: int) -> np.ndarray:
    """J_n(beta x) for n = 0..n_max on x = linspace(0, 1, _TABLE_POINTS); shape (n_max+1, points)."""
    table = jv(np.arange(n_max + 1)[:, None], beta * _TABLE_W[None, :])
    table.setflags(write=False)
    return table


_TABLE_W = np.linspace(0.0, 1.0, _TABLE_POINTS)  # the tables' envelope grid


def _lookup(table_row: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.interp(w, _TABLE_W, table_row)


def _harmonics(alpha: float, beta: float, f_beat_max_hz: float, top_hz: float) -> list[int]:
    """Harmonics n >= 1 of the beat to keep: non-zero coefficient, above the amplitude floor, below
    the band top (the first harmonic always)."""
    ref = jv(1, beta) ** 2 * np.sin(alpha) ** 2
    keep = [1]
    for n in range(2, 64):
        if f_beat_max_hz * n >= top_hz:
            break
        c = np.cos(alpha) ** 2 if n % 2 == 0 else np.sin(alpha) ** 2
        amp = c * jv(n, beta) ** 2
        if (
            ref > 0
            and amp < _HARMONIC_FLOOR * ref
            and jv(n, beta) ** 2 < _HARMONIC_FLOOR * jv(1, beta) ** 2
        ):
            break
        if amp > 0:
            keep.append(n)
    return keep


class BeatProduct:
    """The low-pass product [a(t - tau_ref) a(t - tau)]_low and the signal's slow power, for one
    instrument on one baseband grid. The LO side is computed once; each delay costs one chirp-phase
    evaluation, one envelope and the table lookups."""

    def __init__(
        self, config: Instrument, ref_delay_s: float, t: np.ndarray, top_hz: float, max_lag_s: float
    ):
        train = chirp_train(config.train)
        self.train = train
        self.alpha, self.beta = mzm_drive_angles(
            train, config.modulator.bias_v, config.modulator.v_pi_v
        )
        self.t = t
        self.n_list = _harmonics(self.alpha, self.beta, train.rate_hz_per_s * max_lag_s, top_hz)
        n_max = max(self.n_list)
        self.table = _bessel_table(self.beta, n_max)
        self.table2 = _bessel_table(2.0 * self.beta, 0)[0]  # J0(2 beta w): the slow power
        tc_lo = train.time_in_chirp(t - ref_delay_s)
        w_lo = train.envelope(tc_lo)
        self.phase_lo = train.phase(tc_lo)
        self.j_lo = [_lookup(self.table[n], w_lo) for n in range(n_max + 1)]
        self.power_lo = self.slow_power(w_lo)

    def slow_power(self, w: np.ndarray) -> np.ndarray:
        """<a^2> over the chirp phase at envelope w: (1 + cos(2 alpha) J0(2 beta w)) / 2."""
        return 0.5 * (1.0 + np.cos(2 * self.alpha) * _lookup(self.table2, w))

    def beat(self, delay_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """([a_lo a_sig]_low, <a_sig^2>) for signal delays ``delay_s`` of shape (..., 1)."""
        tc = self.train.time_in_chirp(self.t - delay_s)
        w = self.train.envelope(tc)
        dphi = self.phase_lo - self.train.phase(tc)
        ca2, sa2 = np.cos(self.alpha) ** 2, np.sin(self.alpha) ** 2
        out = ca2 * self.j_lo[0] * _lookup(self.table[0], w)
        for n in self.n_list:
            coef = 2.0 * (ca2 if n % 2 == 0 else sa2)
            out = out + coef * self.j_lo[n] * _lookup(self.table[n], w) * np.cos(n * dphi)
        return out, self.slow_power(w)


@lru_cache(maxsize=16)
def shared_beat(
    config: Instrument,
    ref_delay_s: float,
    lag_s: float,
    delay_s: float,
    fs_hz: float,
    n: int,
    top_hz: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The product for one delay on the whole record of ``n`` samples at ``fs_hz``, the LO
    delayed by ``ref_delay_s``, its harmonics chosen for the lag ``lag_s`` below the band top
    ``top_hz``: (beat, signal power, LO power), read-only (cached: sweeps and batches of one
    geometry reuse it shot after shot)."""
    t = np.arange(n) / fs_hz
    prod = BeatProduct(config, ref_delay_s, t, top_hz, lag_s)
    beat, p_sig = prod.beat(np.array([delay_s]))
    for arr in (beat, p_sig, prod.power_lo):
        arr.setflags(write=False)
    return beat, p_sig, prod.power_lo
