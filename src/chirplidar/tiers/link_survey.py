"""The link tier over a survey chunk: a table of its closed form, per-shot fading and range draws.

Table. The link tier's closed form (:func:`~chirplidar.tiers.link.simulate_link`) is evaluated on
a grid of (range, attenuation) nodes spanning the chunk, each node the ideal reference target
(rho = 1 at normal incidence, a beam fully intercepted, no transmission losses: received fraction
``reference_fraction(R)``) behind that attenuation; each shot's SNR is the bilinear interpolation
in (range, dB) at its own range and at the attenuation that turns the reference power into its
own received power. Node spacing: 1 % in range, 3 dB in attenuation (interpolation error
< 0.05 dB: the SNR in dB is smooth in both).

Carrier phase ``random`` (the field instrument's setting): the nodes hold the mean over a uniform
carrier phase and each shot takes its own fading factor
(:func:`~chirplidar.tiers.link.carrier_fading_factor`), as the rf and baseband tiers draw the
phase per chirp. ``optimal`` and ``propagation``: the nodes hold the optimum phase and each shot
takes the factor of its own static phase (:func:`~chirplidar.tiers.link.static_phase_factor`):
the optimum, or -2 pi nu (tau - tau_ref) of the shot's own mean delay (over a survey, the
arcsine law), plus the speckle field's phase when that effect is on.

Footprint spread: the power-weighted range spread sigma_R of the sub-rays spreads the beat over
sigma_f = kappa 2 n sigma_R / c. The broadened line is approximated as a tone whose width is the
quadrature sum of the resolution width 0.886 / T_ov and the spread's FWHM 2.355 sigma_f: the
peak SNR drops, and the effective duration shortens, by that width ratio g. The measured beat is
drawn around the shot's own with the Cramer-Rao spread (Rife & Boorstyn 1974).

Doppler: a shift the record resolves (|f_d| >= 1 / T_ov) splits the homodyne line (Appendix D):
the SNR takes the link tier's split factor and the peak search takes one of |f_R +- f_d|; with
``processing.doppler_recovery = "dsp"`` nothing is split (the shot is the zero-Doppler one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..doppler import doppler_shift_hz
from ..processing.ranging import two_way_delay_s
from ..units import SPEED_OF_LIGHT_M_S, db_to_ratio
from .common import doppler_line_hz, optimal_phase
from .link import (
    carrier_fading_factor,
    crb_sigma_f_hz,
    overlap_duration_s,
    simulate_link,
    static_phase_factor,
)
from .model import CarrierPhase, Instrument, Returns

_RANGE_STEP = 0.01  # relative node spacing in range
_ATT_STEP_DB = 3.0  # node spacing in attenuation
_ATT_SPAN_DB = 90.0  # below the strongest shot by more than this: SNR extrapolated


@dataclass(frozen=True)
class SurveyPath:
    """What the table's nodes share with the survey: the path's group index, the received
    fraction of the ideal reference target at a range (``reference_fraction(range_m)``, W/W)
    and the survey's carrier-phase setting (the nodes hold the mean over a uniform phase for
    "random", else the optimum phase: each shot's static phase is applied per shot)."""

    group_index: float
    reference_fraction: Callable[[float], float]
    carrier_phase: CarrierPhase


def node_returns(
    instrument: Instrument,
    path: SurveyPath,
    range_m: float,
    attenuation_db: float,
    lag_s: float | None = None,
    doppler_hz: float = 0.0,
) -> Returns:
    """One node: the reference target at ``range_m`` behind ``attenuation_db``, the reference
    delayed so that tau - tau_ref = ``lag_s`` (a node nearer than the lag reads the lag it can),
    else by the instrument's own rule."""
    delay = float(two_way_delay_s(range_m, path.group_index))
    ref = None
    if lag_s is not None:
        ref = max(2.0 * path.group_index * range_m / SPEED_OF_LIGHT_M_S - lag_s, 0.0)
    h = float(db_to_ratio(-attenuation_db) * path.reference_fraction(range_m))
    # A node's own propagation phase would be arbitrary: the optimum, or the mean ("random").
    phase: CarrierPhase = "random" if path.carrier_phase == "random" else "optimal"
    return Returns(
        transmission=h,
        delay_s=delay,
        range_m=range_m,
        group_index=path.group_index,
        power_factor=1.0,
        phase_rad=0.0,
        doppler_hz=doppler_hz,
        carrier_phase=phase,
        reference_delay_s=ref,
        batch=1,
    )


def interp_table(x_nodes, y_nodes, table, x, y):
    """Bilinear interpolation (linear extrapolation along y beyond the nodes)."""
    ix = np.clip(np.searchsorted(x_nodes, x) - 1, 0, max(len(x_nodes) - 2, 0))
    iy = np.clip(np.searchsorted(y_nodes, y) - 1, 0, max(len(y_nodes) - 2, 0))
    if len(x_nodes) == 1:
        fx, ix1 = np.zeros_like(x), ix
    else:
        ix1 = ix + 1
        fx = np.clip((x - x_nodes[ix]) / (x_nodes[ix1] - x_nodes[ix]), 0.0, 1.0)
    if len(y_nodes) == 1:
        fy, iy1 = np.zeros_like(y), iy
    else:
        iy1 = iy + 1
        fy = (y - y_nodes[iy]) / (y_nodes[iy1] - y_nodes[iy])
    a = table[ix, iy] * (1 - fy) + table[ix, iy1] * fy
    c = table[ix1, iy] * (1 - fy) + table[ix1, iy1] * fy
    return a * (1 - fx) + c * fx


def range_nodes(r_lo: float, r_hi: float) -> np.ndarray:
    """The table's range nodes covering [r_lo, r_hi]: r_k = exp(k x _RANGE_STEP) on one lattice
    for every chunk of a run (at most 34 nodes: every s-th lattice node, k a multiple of s), so
    that neighbouring chunks share nodes and :func:`node_snr` evaluates each once per process."""
    if r_hi <= r_lo:
        return np.array([r_lo])
    k0 = int(np.floor(np.log(r_lo) / _RANGE_STEP))
    k1 = int(np.ceil(np.log(r_hi) / _RANGE_STEP))
    stride = max(1, -(-(k1 - k0) // 32))
    k0, k1 = (k0 // stride) * stride, -(-k1 // stride) * stride
    return np.exp(np.arange(k0, k1 + 1, stride) * _RANGE_STEP)


#: node_snr's memo: (instrument, path, range, attenuation, lag) -> (SNR dB, T_ov s).
_NODES: dict = {}
_NODES_MAX = 1 << 16


def node_snr(
    instrument: Instrument,
    path: SurveyPath,
    range_m: float,
    attenuation_db: float,
    lag_s: float | None,
    rng: np.random.Generator,
) -> tuple[float, float]:
    """(SNR [dB], T_ov [s]) of one table node from the link tier's closed form, remembered for
    the process (the instrument is frozen and hashable; the path's reference target follows from
    its telescope): a run's chunks share the lattice's nodes (:func:`range_nodes`) and compute
    each once. The closed form draws nothing the node uses: the value does not depend on ``rng``."""
    key = (instrument, path.group_index, path.carrier_phase, range_m, attenuation_db, lag_s)
    hit = _NODES.get(key)
    if hit is None:
        out = simulate_link(
            instrument, node_returns(instrument, path, range_m, attenuation_db, lag_s), rng
        )
        hit = (float(out["SNR"][0]), float(out["t_overlap_s"][0]))
        if len(_NODES) >= _NODES_MAX:
            _NODES.clear()
        _NODES[key] = hit
    return hit


def link_table(
    instrument: Instrument,
    path: SurveyPath,
    r_lo,
    r_hi,
    a_lo,
    a_hi,
    doppler: bool,
    lag_s: float | None = None,
):
    """SNR [dB] on (range, attenuation) nodes and T_ov [s] per range node, plus the SNR factor
    of a resolved Doppler split, from the link tier's closed form. ``lag_s``: every node's
    tau - tau_ref (a range window's centre); None: the instrument's reference delay."""
    r_nodes = range_nodes(r_lo, r_hi)
    a0 = np.floor(a_lo / _ATT_STEP_DB) * _ATT_STEP_DB
    a1 = max(
        np.ceil(min(a_hi, a_lo + _ATT_SPAN_DB) / _ATT_STEP_DB) * _ATT_STEP_DB, a0 + _ATT_STEP_DB
    )
    a_nodes = np.arange(a0, a1 + 0.5 * _ATT_STEP_DB, _ATT_STEP_DB)
    snr_db = np.empty((r_nodes.size, a_nodes.size))
    t_ov = np.empty(r_nodes.size)
    rng = np.random.default_rng(0)  # the nodes' own draws are not used (SNR is deterministic)
    for i, r in enumerate(r_nodes):  # tens of closed-form evaluations per chunk, not per shot
        for j, a in enumerate(a_nodes):
            snr_db[i, j], t_ov[i] = node_snr(instrument, path, float(r), float(a), lag_s, rng)
    split = 1.0
    if doppler and instrument.system.receiver == "coherent":
        # Appendix D: a resolved Doppler shift splits the real homodyne line; the factor is the
        # link tier's own (it depends on the carrier-phase convention), read at one node
        # (the first range node with a tone: a node whose chirps do not overlap has none).
        i0 = int(np.argmax(np.isfinite(snr_db[:, 0])))
        lam = instrument.laser.wavelength_m
        f_d = doppler_shift_hz(20.0 / t_ov[i0] * lam / 2, lam)
        node = node_returns(instrument, path, float(r_nodes[i0]), float(a_nodes[0]), lag_s, f_d)
        on = simulate_link(instrument, node, rng)["SNR"][0]
        split = float(db_to_ratio(on - snr_db[i0, 0])) if np.isfinite(snr_db[i0, 0]) else np.nan
    # A node without a tone (no chirp overlap at its lag, no LO) has SNR 0 (-inf dB): NaN here,
    # never a sentinel dB value; the shots that meet one are evaluated by unread_nodes.
    snr_db = np.where(np.isfinite(snr_db), snr_db, np.nan)
    return r_nodes, a_nodes, snr_db, t_ov, split


def overlap_at(instrument: Instrument, bud, lag_s) -> np.ndarray:
    """The link tier's chirp overlap T_ov [s] at each lag, interpolated from 129 lags spanning
    them (T_ov is piecewise linear in the lag)."""
    lo, hi = float(np.min(lag_s)), float(np.max(lag_s))
    grid = np.linspace(lo, hi, 129) if hi > lo else np.array([lo])
    t_grid = overlap_duration_s(instrument, bud, grid)
    return np.interp(lag_s, grid, t_grid) if grid.size > 1 else np.full(np.shape(lag_s), t_grid[0])


def static_phase(
    instrument: Instrument, carrier_phase: CarrierPhase, bud, delay_s, ref_delay_s
) -> np.ndarray:
    """Per-shot static carrier phase [rad] of the setting "optimal" (the receiver's optimum) or
    "propagation" (-2 pi nu (tau - tau_ref) of each shot's own mean delay: a moving platform's
    range changes by many wavelengths from shot to shot)."""
    delay_s = np.asarray(delay_s, float)
    if carrier_phase == "propagation":
        return -2 * np.pi * np.mod(bud.nu_hz * (delay_s - ref_delay_s), 1.0)
    return np.full(
        delay_s.shape,
        optimal_phase(
            instrument.receiver_kind if instrument.system.receiver == "coherent" else "direct"
        ),
    )


def unread_nodes(
    instrument: Instrument,
    path: SurveyPath,
    bud,
    unread,
    snr,
    t_ov,
    split,
    r_m,
    att_db,
    lag_s,
    no_overlap,
    doppler: bool,
):
    """(SNR, T_ov, Doppler split factor) per shot, for shots whose table interpolation met a
    node without a tone (its own lag has no chirp overlap: SNR 0, or no LO), instead of a
    sentinel dB value: nodes at one lag with overlap (the median of these shots' own) and each
    shot's own overlap scaling the tone, as with a range window (SNR with the square of T_ov).
    Shots whose own chirps do not overlap have no tone: SNR 0 (written as the fill value,
    flagged ``outside_range_gate``); so has every shot when no node has a tone (no LO)."""
    snr, t_ov = np.array(snr, float), np.array(np.broadcast_to(t_ov, snr.shape), float)
    split = np.array(np.broadcast_to(split, snr.shape), float)
    t_shot = overlap_at(instrument, bud, lag_s[unread])
    snr_u = np.zeros(t_shot.shape)
    split_u = np.ones(t_shot.shape)
    tone = ~no_overlap[unread]
    if instrument.system.receiver == "coherent" and instrument.balanced.lo_power_w <= 0:
        tone[:] = False  # no LO: nothing to beat with
    if np.any(tone):
        r_u, a_u = r_m[unread], att_db[unread]
        r_nodes, a_nodes, table, t_nodes, split_n = link_table(
            instrument,
            path,
            float(r_u.min()),
            float(r_u.max()),
            float(a_u.min()),
            float(a_u.max()),
            doppler,
            float(np.median(lag_s[unread][tone])),
        )
        s = db_to_ratio(interp_table(r_nodes, a_nodes, table, r_u[tone], a_u[tone]))
        s = s * (t_shot[tone] / np.interp(r_u[tone], r_nodes, t_nodes)) ** 2
        snr_u[tone] = np.where(np.isfinite(s), s, 0.0)
        split_u[tone] = split_n if np.isfinite(split_n) else 1.0
    snr[unread], t_ov[unread], split[unread] = snr_u, t_shot, split_u
    return snr, t_ov, split


@dataclass(frozen=True)
class ShotStreams:
    """The survey's random streams the link tier draws from (one each, per chunk)."""

    fading: np.random.Generator
    noise: np.random.Generator
    sideband: np.random.Generator


def mean_snr(
    instrument: Instrument,
    path: SurveyPath,
    bud,
    range_m,
    att_db,
    lag_s,
    no_overlap,
    doppler: bool,
    window_lag_s: float | None,
):
    """(SNR, T_ov [s], Doppler split factor) per shot from the table: at the nodes' carrier
    phase, before fading and footprint spread. ``window_lag_s``: the range window's centre lag
    (the nodes' lag; each shot's own overlap then scales its tone), or None."""
    r_nodes, a_nodes, table, t_nodes, split = link_table(
        instrument,
        path,
        float(range_m.min()),
        float(range_m.max()),
        float(att_db.min()),
        float(att_db.max()),
        doppler,
        window_lag_s,
    )
    snr = db_to_ratio(interp_table(r_nodes, a_nodes, table, range_m, att_db))
    t_ov = np.interp(range_m, r_nodes, t_nodes)
    if window_lag_s is not None:
        # Nodes at the window's centre lag; each shot's own lag sets its overlap T_ov, and
        # the tone's amplitude scales with it (SNR with its square).
        t_shot = overlap_at(instrument, bud, lag_s)
        snr = snr * (t_shot / t_ov) ** 2
        t_ov = t_shot
    # A shot whose own chirps do not overlap has no tone, whatever nodes it lies between (the
    # lattice's end nodes may lie beyond the chunk's ranges, at lags with overlap).
    unread = ~np.isfinite(snr) | no_overlap
    if np.any(unread):
        snr, t_ov, split = unread_nodes(
            instrument,
            path,
            bud,
            unread,
            snr,
            t_ov,
            split,
            range_m,
            att_db,
            lag_s,
            no_overlap,
            doppler,
        )
    return snr, t_ov, split


def survey_shots(
    instrument: Instrument,
    path: SurveyPath,
    bud,
    streams: ShotStreams,
    *,
    range_m,
    range_std_m,
    att_db,
    delay_s,
    ref_delay_s,
    lag_s,
    f_beat_hz,
    no_overlap,
    phase_rad,
    doppler_hz,
    doppler: bool,
    window_lag_s: float | None,
) -> dict:
    """The link tier's measurements of a chunk's shots with a return (arrays (m,)): ``snr``
    (linear, 0 for no tone), ``f_meas_hz`` (the peak found), ``t_eff_s`` (the broadened tone's
    duration) and ``width_hz`` (its 3 dB width). Inputs per shot: power-weighted mean range and
    its spread, attenuation relative to the reference target, delay, reference delay, lag,
    beat, no-overlap mask, the effects' carrier phase (speckle) and Doppler shift."""
    snr, t_ov, split = mean_snr(
        instrument, path, bud, range_m, att_db, lag_s, no_overlap, doppler, window_lag_s
    )
    # The combining DSP removes the shift before reading (tiers.link: no split).
    dsp = instrument.processing.doppler_recovery == "dsp"
    resolved = (np.abs(doppler_hz) >= 1.0 / t_ov) & (not dsp)
    # Carrier fading about the nodes' mean phase power, or each shot's static phase (with the
    # speckle field's phase, when that effect is on) about the optimum; a resolved Doppler
    # split replaces it.
    if path.carrier_phase == "random":
        fade = carrier_fading_factor(instrument, path.carrier_phase, streams.fading, snr.size)
    else:
        fade = static_phase_factor(
            instrument,
            static_phase(instrument, path.carrier_phase, bud, delay_s, ref_delay_s) + phase_rad,
        )
    snr = np.where(resolved, snr * split, snr * fade)
    # Footprint spread: a broadened line of width ratio g (module docstring).
    sigma_f = bud.rate_hz_per_s * 2.0 * path.group_index * range_std_m / SPEED_OF_LIGHT_M_S
    g = np.sqrt(1.0 + (2.355 * sigma_f * t_ov / 0.886) ** 2)
    snr = snr / g
    t_eff = t_ov / g
    noise = streams.noise.standard_normal(snr.shape)
    line = doppler_line_hz(
        instrument, bud, f_beat_hz, np.where(resolved, doppler_hz, 0.0), streams.sideband
    )
    f_meas = line + crb_sigma_f_hz(snr, instrument.processing.rbw_hz, t_eff) * noise
    # 0.886 / t_eff: the 3 dB width of a rectangular-envelope tone of duration t_eff.
    return {"snr": snr, "f_meas_hz": f_meas, "t_eff_s": t_eff, "width_hz": 0.886 / t_eff}
