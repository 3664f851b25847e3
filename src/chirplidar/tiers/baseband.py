"""The baseband tier: the dechirped beat generated directly at the detector's output rate.

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

The optical side is the rf tier's, term by term: the coupler or hybrid arm j detects
r_j (|S_j0|^2 P_lo(t) + |S_j1|^2 P_sig(t) + 2 Re(S_j0 S_j1* E_lo E_sig*)), the signal's field is the
coherent sum of its footprint echoes with their carrier phases, the laser's Wiener phase is sampled
exactly at t - tau_ref and t - tau, Doppler is a phase ramp, speckle and the other effects come from
the same per-effect streams. Noise: shot noise of the slowly varying arm currents plus the circuit
noise, drawn at the baseband rate with the rf tier's own function (receiver.detectors.current_noise),
so the noise PSD is the rf tier's. ASE beating with the LO is a white current of PSD
4 |c|^2 P_lo(t) h S_ASE (c: the arm's coupler product). Processing is the rf tier's
(tiers.common.analyze_block) on the shorter record, block by block.

Averaged records: a coherent average of K records is the mean of the K signals plus ONE noise record
of variance 1/K of a single record's (exact: a mean of Gaussians is Gaussian). A power average of K
records whose signal is the same in every record, with stationary noise and native FFT bins, is
drawn directly per bin: sum_k |S + N_k|^2 is (N sigma^2 / 2) times a noncentral chi-square of 2K
degrees of freedom (tiers.baseband.draw_power_average); otherwise the K records are simulated.

Speed: where every shot shares one product (a point target or one footprint for the batch), each
record is a few per-record coefficients times three functions of time, added to the noise by one
BLAS GEMM in place; the noisy records and their FFT are single precision
(``simulation.baseband_precision``; tests/test_baseband.py shows what it costs: <= 2e-4 dB in SNR,
3e-6 bin in beat frequency), the phases always double.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache, partial

import numpy as np
import scipy.fft
import scipy.linalg.blas
from scipy.special import jv

from .._threads import single_threaded_blas
from ..channel.effects import ShotReturns, channel_returns, effect_rng
from ..doppler import doppler_shift_hz
from ..processing.spectrum import analyze_spectrum
from ..receiver import COUPLER_3DB, HYBRID_90, single_pole
from ..receiver.detectors import balanced_noise, current_noise, current_noise_variance
from ..transmitter import wiener_phase
from ..transmitter.mzm import mzm_drive_angles
from ..units import ELEMENTARY_CHARGE_C
from .budget import coupler_field_transmission, make_budget, responsivities
from .common import (analyze_block, concatenate_blocks, detection_flags, echo_mean_offset_s,
                     finish_outputs, optimal_phase, peak_search_max_hz)
from .echoes import Echoes

_TABLE_POINTS = 4097        # Bessel tables over the envelope w in [0, 1] (linear interpolation:
                            # error < (1/4096)^2 / 8 of J'' ~ 1e-8 of the beat amplitude)
_HARMONIC_FLOOR = 1e-6      # harmonics whose amplitude is below this fraction of the fundamental
DIRECT_POWER_AVERAGE = True  # draw eligible power averages per bin (tests switch it off to compare)
_BLOCK_ELEMENTS = 1 << 20   # shots x records x samples per block (bounds the memory: 8 MB per array)


def band_top_hz(config, bud) -> float:
    """Top of the band the baseband tier simulates: ``processing.peak_search_max_hz``, else the
    chirp's start frequency F1 + F0 (the self-chirped product's other terms lie at and above it)."""
    top = config.processing.peak_search_max_hz
    if top is None:
        top = bud.train.f_start_hz
    if top <= config.processing.highpass_hz:
        raise ValueError(
            f"baseband tier: the band top {top:g} Hz (processing.peak_search_max_hz, else the "
            f"chirp's start frequency waveform.f_start_hz + f_offset_hz) must lie above "
            f"processing.highpass_hz = {config.processing.highpass_hz:g} Hz; set "
            "processing.peak_search_max_hz")
    return float(top)


def baseband_grid(config, bud) -> tuple[float, int]:
    """(sample rate in Hz, samples N) of the baseband record: ``simulation.baseband_rate_hz`` or
    twice the band top, raised to a fast FFT length over the record duration. A Doppler shift
    f_d (the ``doppler`` effect) moves lines up to f_d above the band top: the grid reaches them,
    so they do not alias into the band (the rf tier's full rate never aliases them)."""
    sim = config.simulation
    if sim.baseband_rate_hz is not None:
        rate = sim.baseband_rate_hz
    else:
        f_d = 0.0
        if "doppler" in config.effects.enabled:
            f_d = abs(doppler_shift_hz(config.effects.doppler.radial_velocity_mps,
                                       config.laser.wavelength_m))
        rate = 2.0 * (band_top_hz(config, bud) + f_d)
    n = scipy.fft.next_fast_len(int(math.ceil(sim.duration_s * rate - 1e-9)), real=True)
    return n / sim.duration_s, n


@lru_cache(maxsize=8)
def _bessel_table(beta: float, n_max: int) -> np.ndarray:
    """J_n(beta x) for n = 0..n_max on x = linspace(0, 1, _TABLE_POINTS); shape (n_max+1, points)."""
    table = jv(np.arange(n_max + 1)[:, None], beta * _TABLE_W[None, :])
    table.setflags(write=False)
    return table


_TABLE_W = np.linspace(0.0, 1.0, _TABLE_POINTS)   # the tables' envelope grid


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
        if ref > 0 and amp < _HARMONIC_FLOOR * ref and jv(n, beta) ** 2 < _HARMONIC_FLOOR * jv(1, beta) ** 2:
            break
        if amp > 0:
            keep.append(n)
    return keep


class _Product:
    """The low-pass product [a(t - tau_ref) a(t - tau)]_low and the signal's slow power, for one
    instrument on one baseband grid. The LO side is computed once; each delay costs one chirp-phase
    evaluation, one envelope and the table lookups."""

    def __init__(self, config, bud, t: np.ndarray, top_hz: float, max_lag_s: float):
        train = bud.train
        self.train = train
        self.alpha, self.beta = mzm_drive_angles(train, config.modulator.bias_v,
                                                 config.modulator.v_pi_v)
        self.t = t
        self.n_list = _harmonics(self.alpha, self.beta, train.rate_hz_per_s * max_lag_s, top_hz)
        n_max = max(self.n_list)
        self.table = _bessel_table(self.beta, n_max)
        self.table2 = _bessel_table(2.0 * self.beta, 0)[0]  # J0(2 beta w): the slow power
        tc_lo = train.time_in_chirp(t - bud.ref_delay_s)
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
def _shared_beat(config, delay_s: float, fs_hz: float, n: int):
    """The product for one delay on the whole record (cached: sweeps and batches of one geometry
    reuse it shot after shot; read-only arrays)."""
    bud = make_budget(config)
    t = np.arange(n) / fs_hz
    prod = _Product(config, bud, t, band_top_hz_or_nyquist(config, bud, fs_hz), bud.lag_s)
    beat, p_sig = prod.beat(np.array([delay_s]))
    for arr in (beat, p_sig, prod.power_lo):
        arr.setflags(write=False)
    return beat, p_sig, prod.power_lo


def band_top_hz_or_nyquist(config, bud, fs_hz: float) -> float:
    """The band actually simulated: the band top, or the Nyquist frequency if that is lower."""
    if config.simulation.baseband_rate_hz is not None:
        return min(fs_hz / 2, config.processing.peak_search_max_hz or fs_hz / 2)
    return min(band_top_hz(config, bud), fs_hz / 2)


def check_supported(config):
    """Raise ValueError naming the setting when the baseband tier does not model a configuration."""
    sysc, proc = config.system, config.processing
    if sysc.modulation != "fm_chirp":
        raise ValueError("the baseband tier models FM chirps; use --tier rf for system.modulation "
                         "= 'pn_code' (sys.MxMode = PN)")
    if sysc.receiver != "coherent" or sysc.coherent_mode not in ("homodyne", "phase_diversity"):
        raise ValueError(
            "the baseband tier models the self-chirped coherent receivers (system.receiver = "
            "'coherent' with coherent_mode 'homodyne' or 'phase_diversity'); direct and "
            f"heterodyne detection (receiver = {sysc.receiver!r}, coherent_mode = "
            f"{sysc.coherent_mode!r}) run in the rf and link tiers")
    if proc.doppler_recovery != "none":
        raise ValueError("processing.doppler_recovery = 'squaring' is modelled in the rf tier only "
                         "(use --tier rf): squaring the full-rate record folds in products the "
                         "baseband record does not hold")


def simulate_baseband(config, rng: np.random.Generator, *, batch: int = 1,
                      keep_spectrum: bool = False, echoes: Echoes | None = None,
                      shot_returns=None) -> dict:
    """Simulate ``batch`` independent shots at the detector's output rate; arrays of shape (batch,).

    Same interface and outputs as :func:`~chirplidar.tiers.rf.simulate_rf` (``echoes``: each
    shot's footprint as delayed sub-returns). ``shot_returns`` (optional
    :class:`~chirplidar.channel.effects.ShotReturns`, arrays (batch,)): per-shot returns from the
    caller's geometry (received power relative to the configuration's, carrier phase, Doppler),
    combined with the enabled effects' own; a survey batches shots of different ranges this way.
    Shots are processed in blocks of at most 2**20 shots x records x samples; the random draws
    depend on the seed and the batch only.
    """
    with single_threaded_blas():
        return _simulate_baseband(config, rng, batch, keep_spectrum, echoes, shot_returns)


def _simulate_baseband(config, rng, batch, keep_spectrum, echoes, shot_returns) -> dict:
    if echoes is not None and not isinstance(echoes, Echoes):
        raise ValueError(f"echoes must be a chirplidar.tiers.echoes.Echoes or None; "
                         f"got {type(echoes).__name__}")
    check_supported(config)
    bud = make_budget(config)
    sim, proc, b = config.simulation, config.processing, config.balanced
    fs, n = baseband_grid(config, bud)
    k_avg = proc.averages
    top = band_top_hz_or_nyquist(config, bud, fs)
    t = np.arange(n) / fs
    gate = bud.train.record_gate(t, sim.duration_s)
    mode = config.system.coherent_mode
    resp = responsivities(config, bud.nu_hz)
    r = (resp["balanced_1"], resp["balanced_2"])
    S = (COUPLER_3DB if mode == "homodyne" else HYBRID_90) * coupler_field_transmission(config)
    cross = [r[j] * S[j, 0] * np.conj(S[j, 1]) for j in (0, 1)]   # arm j: 2 Re(cross_j X)
    s_lo = bud.lo_power_scale(b.lo_power_w)
    s_sig = config.laser.power_w * bud.tx_gain * bud.h

    returns = channel_returns(config, batch, rng)   # enabled effects, on their own streams
    if shot_returns is not None:
        returns = ShotReturns(power_factor=returns.power_factor * shot_returns.power_factor,
                              phase_rad=returns.phase_rad + shot_returns.phase_rad,
                              doppler_hz=returns.doppler_hz + shot_returns.doppler_hz)
    flags = detection_flags(config, bud, returns, nyquist_hz=top)
    if bud.f_beat_hz > top and "beat_out_of_band" not in flags:
        flags.append("beat_out_of_band")   # above the simulated band: it would alias
    cp = config.channel.carrier_phase
    if cp == "random":
        psi = rng.uniform(0.0, 2 * np.pi, (batch, k_avg, 1))
    elif cp == "propagation":
        psi = np.full((batch, 1, 1), -2 * np.pi * np.mod(bud.nu_hz * (bud.delay_s - bud.ref_delay_s), 1.0))
    else:
        psi = np.full((batch, 1, 1), optimal_phase(mode))
    psi = psi + returns.phase_rad.reshape(batch, 1, 1)
    amp = np.sqrt(s_lo * s_sig * returns.power_factor).reshape(batch, 1, 1)
    doppler = returns.doppler_hz.reshape(batch, 1, 1)
    lw = config.laser.linewidth_hz
    pn_rng = effect_rng(rng, "phase_noise") if lw > 0 else None

    if echoes is None:
        offsets, weights, phases = np.zeros((batch, 1)), np.ones((batch, 1)), np.zeros((batch, 1))
    else:
        offsets, weights, phases = echoes.for_batch(batch)
    delays = bud.delay_s + offsets
    if bud.quantized:
        q = 1.0 / (sim.sample_rate_hz * sim.upsample_factor)
        delays = np.round(delays / q) * q
    shared = bool(np.all(delays == delays[:1]))
    max_lag = float(np.max(np.mod(delays - bud.ref_delay_s, bud.train.period_s)))
    product = None if shared else _Product(config, bud, t, top, max_lag)

    ase_current = []
    if bud.ase_psd_w_per_hz > 0:
        # LO x ASE beat: one-sided current PSD 4 |c|^2 P_lo(t) h S_ASE, written as the equivalent
        # shot-noise current PSD / (2 q) so that it follows the LO's slow power like the shot noise.
        c_noise = [cross[0] - cross[1]] if mode == "homodyne" else cross
        ase_current = [4 * abs(c) ** 2 * bud.h * bud.ase_psd_w_per_hz / (2 * ELEMENTARY_CHARGE_C)
                       for c in c_noise]

    per_record = (k_avg if (cp == "random" or lw > 0) else 1)
    coherent_avg = proc.averaging == "coherent"
    # Records per shot in the block's largest arrays: K signals, or K noisy records to power-average.
    rows = k_avg if (per_record > 1 or not coherent_avg) else 1
    block = max(1, _BLOCK_ELEMENTS // (rows * n * max(1, offsets.shape[1])))
    # The noisy records and their FFT in the configured precision (phases above are float64).
    dtype = np.float32 if sim.baseband_precision == "single" else np.float64
    # Power averages drawn directly: the same signal in every record, stationary white noise
    # (a constant chirp envelope keeps the LO power and so the shot noise constant), native bins.
    direct = (DIRECT_POWER_AVERAGE and not coherent_avg and k_avg > 1 and per_record == 1
              and mode == "homodyne" and proc.zero_pad_factor == 1 and proc.peak_method != "dtft"
              and bool(gate.all()) and bool(np.all(bud.train.envelope_samples() == 1.0)))
    dark = b.solar_current_a + b.background_current_a + b.leakage_current_a
    # Each block is simulated and analysed before the next: memory is bounded by the block. Its
    # noisy records are written in place into buffers reused from block to block.
    rec_shape = (min(block, batch), 1 if coherent_avg else k_avg, n)
    bufs = [np.empty(rec_shape, dtype) for _ in range(1 if mode == "homodyne" else 2)]
    search_max = min(peak_search_max_hz(config, bud), top)
    analysis = partial(analyze_block, config, load_ohm=b.output_impedance_ohm, flags=flags,
                       fs_hz=fs, transfer=single_pole(b.bandwidth_hz), search_max_hz=search_max,
                       keep_spectrum=keep_spectrum)
    blocks = []
    mean_p = circuit = None
    sat_peak = 0.0
    doppler_on = bool(np.any(doppler != 0))
    z_gate = b.transimpedance_ohm * (gate if not gate.all() else 1.0)
    # Shot-noise terms whose variance is below 1e-6 of the dark and circuit floor are dropped
    # (the received signal's own shot noise against a mW LO): the noise level moves < 5e-6 dB.
    nz0 = balanced_noise(config, r[0], r[1], 0.0, 0.0)
    noise_floor = 1e-6 * (2 * dark + 0.5 * (nz0.thermal + nz0.amplifier) / ELEMENTARY_CHARGE_C)
    def _footprint(sl):
        """Complex low-pass product C = sum_k sqrt(w_k) exp(-j phi_k) [a_lo a_k]_low (m, 1, N),
        the signal's slow power sum_k w_k <a_k^2> (m, 1, N) and the LO's (N,), for a block."""
        k = offsets.shape[1]
        if shared:
            parts = [_shared_beat(config, float(delays[0, kk]), fs, n) for kk in range(k)]
            p_lo = parts[0][2]
            if k == 1 and not np.any(phases[sl]):
                return parts[0][0][None, None, :], parts[0][1][None, None, :], p_lo
            beats = [(parts[kk][0], parts[kk][1]) for kk in range(k)]
        else:
            p_lo = product.power_lo
            beats = [product.beat(delays[sl, kk, None]) for kk in range(k)]
        C, p_sig = 0.0, 0.0
        for kk, (bk, pk) in enumerate(beats):
            C = C + np.sqrt(weights[sl, kk, None]) * np.exp(-1j * phases[sl, kk, None]) * bk
            p_sig = p_sig + weights[sl, kk, None] * pk
        return C[:, None, :], p_sig[:, None, :], p_lo

    for s0 in range(0, batch, block):
        sl = slice(s0, min(batch, s0 + block))
        m = sl.stop - sl.start
        C, p_sig, p_lo = _footprint(sl)
        # Optical phase of E_lo E_sig*: laser phase noise, carrier phase, Doppler.
        theta = -psi[sl]
        if doppler_on:
            theta = theta - 2 * np.pi * doppler[sl] * t
        if lw > 0:
            th_lo, th_sig = (x.reshape(m, k_avg, n) for x in wiener_phase(
                [t - bud.ref_delay_s, t - bud.delay_s], lw, pn_rng, m * k_avg))
            theta = theta + th_lo - th_sig
        sig_scale = s_sig * returns.power_factor[sl, None, None]         # (m, 1, 1)
        if mean_p is None:   # the arms' mean optical powers (the detector's operating point)
            mean_sig = float(np.mean(sig_scale * np.mean(p_sig, axis=-1, keepdims=True)))
            mean_p = [float(abs(S[j, 0]) ** 2 * s_lo * np.mean(p_lo) + abs(S[j, 1]) ** 2 * mean_sig)
                      for j in (0, 1)]
            circuit = [balanced_noise(config, r[0], r[1], *mean_p, arm=a) for a in (None, 0, 1)]
        outer = (not (np.iscomplexobj(C) or theta.shape[-1] > 1)
                 and C.shape[0] == p_sig.shape[0] == 1)
        if outer:
            # One real product for every shot and a constant phase per record: each current is
            # per-record coefficients times three functions of time, i.e. one matrix product.
            rot = amp[sl] * np.exp(1j * theta)                  # (m, 1 or K, 1)
            peak = float(np.max(np.abs(rot))) * float(np.max(np.abs(C)))
        else:
            X = amp[sl] * C * np.exp(1j * theta)                 # E_lo E_sig*, (m, 1 or K, N)
            peak = float(np.max(np.abs(X)))
        sig_peak = float(np.max(sig_scale)) * float(np.max(p_sig))
        # Shots of equal received power and one shared product: their direct terms are one
        # function of time, so the noise's standard deviation is computed once, not per shot.
        sig_common = (float(sig_scale.flat[0]) if p_sig.shape[0] == 1
                      and np.all(sig_scale == sig_scale.flat[0]) else None)

        def current(signs, c, floor=None, gain=1.0):
            """``gain`` x sum_j signs_j i_j(t): the arms' direct-detection terms plus
            2 Re(c E_lo E_sig*), (N,), (m, 1 or K, N) or, for one shared product, a
            :class:`_LowRank` of the per-record coefficients and the functions of time; terms
            whose largest current is below ``floor`` (A) are left out (see the noise floor)."""
            a_lo, a_sig = _arm_coefficients(r, S, signs, sig_peak, floor)
            if floor is not None and 2 * abs(c) * peak <= floor:
                c = 0.0
            lo = (a_lo * s_lo) * p_lo * gain
            if c == 0 and (a_sig == 0 or sig_common is not None):   # the same for every shot
                return lo if a_sig == 0 else lo + (a_sig * sig_common) * p_sig[0, 0] * gain
            if not outer:
                out = lo if a_sig == 0 else lo + (a_sig * sig_scale) * (p_sig * gain)
                return out if c == 0 else out + 2.0 * np.real(c * X) * gain
            coef = np.stack(np.broadcast_arrays(
                np.ones(rot.shape), a_sig * sig_scale * np.ones(rot.shape), 2.0 * np.real(c * rot)),
                axis=-1)[:, :, 0, :]                                      # (m, 1 or K, 3)
            fns = np.stack([np.broadcast_to(lo, (n,)), a_sig * p_sig[0, 0] * gain,
                            C[0, 0] * gain])                              # (3, N)
            return _LowRank(coef, fns)

        shape = (m, 1 if coherent_avg else k_avg, n)
        if mode == "homodyne":
            # i1 - i2 and i1 + i2 from the arms' self terms and cross terms.
            sat_peak = max(sat_peak, float(np.max(amp[sl])) * 2 * abs(cross[0] - cross[1]))
            total = _dense(current((1, 1), cross[0] + cross[1], floor=noise_floor))
            if ase_current:
                total = total + ase_current[0] * p_lo
            nz = circuit[0]
            if direct:
                # Noiseless records and each shot's noise variance per sample (V^2), drawn per bin.
                tot = np.broadcast_to(total, (m, 1, n))[:, 0, 0]
                var = current_noise_variance(tot, 2 * dark, nz.thermal + nz.amplifier, fs)
                diff = current((1, -1), cross[0] - cross[1], gain=b.transimpedance_ohm)
                blocks.append(analysis({"main": np.broadcast_to(_dense(diff), (m, 1, n))},
                                       spectrum_analyzer=partial(
                                           draw_power_average, averages=k_avg, rng=rng,
                                           var_v2=b.transimpedance_ohm ** 2 * var)))
            else:
                diff = current((1, -1), cross[0] - cross[1], gain=z_gate)
                _noisy(rng, diff, total, 2 * dark, nz.thermal + nz.amplifier, fs, shape,
                       coherent_avg, k_avg, z_gate, dtype, out=bufs[0][:m])
                blocks.append(analysis({"main": bufs[0][:m]}))
        else:
            for j in (0, 1):
                one = tuple(1 if a == j else 0 for a in (0, 1))
                total = _dense(current(one, cross[j]))    # an arm's own current: its noise
                if ase_current:
                    total = total + ase_current[j] * p_lo
                nz = circuit[1 + j]
                _noisy(rng, current(one, cross[j], gain=z_gate), total, dark,
                       nz.thermal + nz.amplifier, fs, shape, coherent_avg, k_avg, z_gate, dtype,
                       out=bufs[j][:m])
            blocks.append(analysis({"arm1": bufs[0][:m], "arm2": bufs[1][:m]}))
    if mode == "homodyne":
        # The rf tier reads the amplifier's drive from the full-rate difference current; the
        # baseband record lacks the sum-frequency terms, so take the bound the full-rate current
        # reaches over a record of many chirp cycles: 2 |c| sqrt(P_lo P_sig) max|a_lo| max|a_sig|.
        diff_peak = sat_peak * _field_peak(config, bud) ** 2 / (0.5 * (r[0] + r[1]))
        if diff_peak > b.saturation_power_w:
            flags.append("saturation")
    result, extra = concatenate_blocks(blocks)
    return finish_outputs(config, bud, result, extra, circuit[0 if mode == "homodyne" else 1],
                          flags, returns, tier="baseband", nyquist_hz=top,
                          delay_offset_s=None if echoes is None
                          else echo_mean_offset_s((offsets, weights)))


def draw_power_average(signal_v: np.ndarray, fs_hz: float, load_ohm: float, *, var_v2: np.ndarray,
                       averages: int, rng: np.random.Generator, averaging: str = "power",
                       zero_pad: int = 1, **kw):
    """Peak analysis of the power average of ``averages`` records, each the same signal plus its
    own white Gaussian noise of variance ``var_v2`` per sample, drawn directly per FFT bin.

    signal_v: (batch, 1, N) noiseless records (V); var_v2: (batch,) noise variance per sample.
    The noise's DFT bins are independent: complex circular Gaussians of E|N_k|^2 = N var, real
    ones at DC and Nyquist. So sum_j |S_k + N_jk|^2 is (N var / 2) chi'^2(2K, 2K |S_k|^2 / (N var))
    inside the band and N var chi'^2(K, K S_k^2 / (N var)) at DC and Nyquist (noncentral
    chi-square of the stated degrees of freedom and noncentrality). One draw per bin replaces K
    records and K FFTs; tests/test_baseband.py checks it against explicit averaging.
    """
    if averaging != "power" or zero_pad != 1:
        raise ValueError("draw_power_average: power averaging on native FFT bins only")
    n = signal_v.shape[-1]
    S = scipy.fft.rfft(signal_v[:, 0, :], axis=-1, workers=-1)
    scale = n * np.asarray(var_v2, float)[:, None]                   # E|N_k|^2, (batch, 1)
    s2 = S.real ** 2 + S.imag ** 2
    real_bins = np.zeros(S.shape[-1], bool)
    real_bins[0] = True
    if n % 2 == 0:
        real_bins[-1] = True
    k = averages
    total = np.empty_like(s2)
    inner = ~real_bins
    total[:, inner] = 0.5 * scale * rng.noncentral_chisquare(
        2 * k, 2 * k * s2[:, inner] / scale)
    total[:, real_bins] = scale * rng.noncentral_chisquare(k, k * s2[:, real_bins] / scale)
    psd = (2.0 / (n * fs_hz * load_ohm)) * total / k
    return analyze_spectrum(psd, fs_hz, n, zero_pad=1, **kw)


def _field_peak(config, bud) -> float:
    """max |cos(alpha + beta w sin phi)| over the drive: 1 if alpha +- beta spans a peak of |cos|."""
    alpha, beta = mzm_drive_angles(bud.train, config.modulator.bias_v, config.modulator.v_pi_v)
    lo, hi = alpha - abs(beta), alpha + abs(beta)
    if np.floor(hi / np.pi) > np.floor(lo / np.pi) or np.isclose(np.mod(lo, np.pi), 0.0):
        return 1.0
    return float(max(abs(np.cos(lo)), abs(np.cos(hi))))


def _arm_coefficients(r, S, signs, sig_peak_w: float, floor=None) -> tuple[float, float]:
    """(a_lo, a_sig) of sum_j signs_j r_j (|S_j0|^2 P_lo(t) + |S_j1|^2 P_sig(t)), the arms'
    direct-detection terms (A/W). A coefficient that cancels (a balanced pair's LO) is 0; so is
    the signal's when its largest current a_sig x ``sig_peak_w`` is below ``floor`` (A).
    """
    a_lo = sum(sg * r[j] * abs(S[j, 0]) ** 2 for j, sg in enumerate(signs))
    a_sig = sum(sg * r[j] * abs(S[j, 1]) ** 2 for j, sg in enumerate(signs))
    if abs(a_lo) <= 1e-12 * max(r):
        a_lo = 0.0
    if abs(a_sig) <= 1e-12 * max(r) or (floor is not None and abs(a_sig) * sig_peak_w <= floor):
        a_sig = 0.0
    return float(a_lo), float(a_sig)


def _noisy(rng, signal_v, total, dark_a, circuit_psd, fs, shape, coherent_avg, k_avg, gain, dtype,
           out):
    """Signal voltage ``signal_v`` plus the noise of ``total`` (A) times ``gain`` (the
    transimpedance times the record gate, V/A), written to ``out`` (m, 1 or K, N) of ``dtype``.

    Coherent averaging returns the mean of the K records: the mean signal plus one noise record of
    1/K the variance (current, dark and circuit terms all scale the variance linearly).
    """
    if coherent_avg and k_avg > 1:
        signal_v = _mean_records(signal_v)
        if np.ndim(total) == 3 and total.shape[1] > 1:
            total = total.mean(axis=1, keepdims=True)
        noise = current_noise(rng, shape, np.divide(total, k_avg), dark_a / k_avg,
                              circuit_psd / k_avg, fs, dtype=dtype, gain=gain, out=out)
    else:
        noise = current_noise(rng, shape, total, dark_a, circuit_psd, fs, dtype=dtype, gain=gain,
                              out=out)
    if isinstance(signal_v, _LowRank):
        signal_v.add_to(noise)
    else:
        noise += signal_v
    return noise


@dataclass(frozen=True)
class _LowRank:
    """Records coef @ fns: per-record coefficients (m, 1 or K, R) times R functions of time
    (R, N). Added to the noise records by one BLAS GEMM, in place (no (m, K, N) temporary)."""

    coef: np.ndarray
    fns: np.ndarray

    def dense(self) -> np.ndarray:
        return np.einsum("mkr,rn->mkn", self.coef, self.fns)

    def add_to(self, out: np.ndarray) -> None:
        """out += records, for C-contiguous float32/float64 ``out`` (m, K, N)."""
        rows = out.reshape(-1, out.shape[-1])                       # a view: out is contiguous
        coef = np.broadcast_to(self.coef, out.shape[:2] + self.coef.shape[-1:])
        coef = coef.reshape(-1, self.coef.shape[-1]).astype(out.dtype)
        gemm = scipy.linalg.blas.get_blas_funcs("gemm", (rows,))
        # BLAS is column-major: out^T (N, mK) += fns^T (N, R) @ coef^T (R, mK), in place.
        res = gemm(1.0, self.fns.T.astype(out.dtype), coef.T, beta=1.0, c=rows.T, overwrite_c=True)
        if not np.shares_memory(res, rows):
            rows[...] = res.T


def _dense(x):
    return x.dense() if isinstance(x, _LowRank) else x


def _mean_records(x):
    """The mean over the records axis (1) of records or of a :class:`_LowRank`."""
    if isinstance(x, _LowRank):
        return _LowRank(x.coef.mean(axis=1, keepdims=True), x.fns)
    if np.ndim(x) == 3 and x.shape[1] > 1:
        return x.mean(axis=1, keepdims=True)
    return x
