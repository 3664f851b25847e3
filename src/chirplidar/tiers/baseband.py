"""The baseband tier: the dechirped beat generated directly at the detector's output rate.

The rf tier samples the modulator's field a(t) = cos(alpha + beta w(t) sin phi(t)) at GHz rates and
lets the photodiodes form the product a(t - tau_ref) a(t - tau). Here the Jacobi-Anger expansion
does that product analytically and keeps only what lies below the chirp's start frequency, the band
the beat is read in (tiers.baseband_product).

The optical side is the rf tier's, term by term: the coupler or hybrid arm j detects
r_j (|S_j0|^2 P_lo(t) + |S_j1|^2 P_sig(t) + 2 Re(S_j0 S_j1* E_lo E_sig*)), the signal's field is the
coherent sum of its footprint echoes with their carrier phases, the laser's Wiener phase is sampled
exactly at t - tau_ref and t - tau, Doppler is a phase ramp, speckle and the other effects come from
the same per-effect streams. Noise: shot noise of the slowly varying arm currents plus the circuit
noise, drawn at the baseband rate with the rf tier's own function (receiver.detectors.current_noise),
so the noise PSD is the rf tier's. ASE beating with the LO is a white current of PSD
4 |c|^2 P_lo(t) h S_ASE (c: the arm's coupler product). Processing is the rf tier's
(tiers.records.analyze_block) on the shorter record, block by block.

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
from functools import partial

import numpy as np
import scipy.fft
import scipy.linalg.blas

from .._threads import single_threaded_blas
from ..processing.spectrum import analyze_spectrum
from ..receiver import single_pole
from ..receiver.detectors import (
    DetectorNoise,
    balanced_noise,
    current_noise,
    current_noise_variance,
)
from ..streams import child_stream
from ..transmitter import wiener_phase
from ..units import ELEMENTARY_CHARGE_C
from .baseband_product import BeatProduct, band_top_hz, field_peak, shared_beat
from .budget import arm_cross, make_budget, receiver_coupler, responsivities
from .common import (
    detection_flags,
    echo_mean_offset_s,
    finish_outputs,
    optimal_phase,
    peak_search_max_hz,
)
from .model import Instrument, Measurements, Returns
from .records import analyze_block, concatenate_blocks, records_per_shot
from .registry import BASEBAND_SUPPORTS

DIRECT_POWER_AVERAGE = True  # draw eligible power averages per bin (tests switch it off to compare)
_BLOCK_ELEMENTS = 1 << 20  # shots x records x samples per block (bounds the memory: 8 MB per array)


def baseband_grid(config: Instrument, doppler_max_hz: float = 0.0) -> tuple[float, int]:
    """(sample rate in Hz, samples N) of the baseband record: ``simulation.baseband_rate_hz`` or
    twice the band top, raised to a fast FFT length over the record duration. A Doppler shift
    up to ``doppler_max_hz`` (the largest |f_d| of the batch) moves lines up to f_d above the
    band top: the grid reaches them, so they do not alias into the band (the rf tier's full
    rate never aliases them)."""
    sim = config.simulation
    if sim.baseband_rate_hz is not None:
        rate = sim.baseband_rate_hz
    else:
        rate = 2.0 * (band_top_hz(config) + doppler_max_hz)
    n = scipy.fft.next_fast_len(int(math.ceil(sim.duration_s * rate - 1e-9)), real=True)
    return n / sim.duration_s, n


def band_top_hz_or_nyquist(config: Instrument, fs_hz: float) -> float:
    """The band actually simulated: the band top, or the Nyquist frequency if that is lower."""
    if config.simulation.baseband_rate_hz is not None:
        return min(fs_hz / 2, config.processing.peak_search_max_hz or fs_hz / 2)
    return min(band_top_hz(config), fs_hz / 2)


def simulate_baseband(
    config: Instrument, returns: Returns, rng: np.random.Generator, *, keep_spectrum: bool = False
) -> Measurements:
    """Simulate the batch of ``returns`` at the detector's output rate; arrays of shape (batch,).

    Same outputs as :func:`~chirplidar.tiers.rf.simulate_rf`. Shots are processed in blocks of
    at most 2**20 shots x records x samples; the random draws depend on the seed and the batch
    only.
    """
    BASEBAND_SUPPORTS.check("baseband", config, returns)
    with single_threaded_blas():
        return _simulate_baseband(config, returns, rng, keep_spectrum)


def _simulate_baseband(config, returns, rng, keep_spectrum) -> Measurements:
    run = _BasebandRun(config, returns, rng, keep_spectrum)
    blocks = [
        run.block(slice(s0, min(run.batch, s0 + run.block_shots)))
        for s0 in range(0, run.batch, run.block_shots)
    ]
    if run.mode == "homodyne":
        # The rf tier reads the amplifier's drive from the full-rate difference current; the
        # baseband record lacks the sum-frequency terms, so take the bound the full-rate current
        # reaches over a record of many chirp cycles: 2 |c| sqrt(P_lo P_sig) max|a_lo| max|a_sig|.
        r = run.r
        diff_peak = run.sat_peak * field_peak(config, run.bud) ** 2 / (0.5 * (r[0] + r[1]))
        if diff_peak > config.balanced.saturation_power_w:
            run.flags.append("saturation")
    result, extra = concatenate_blocks(blocks)
    return finish_outputs(
        config,
        run.bud,
        result,
        extra,
        run.noise[0 if run.mode == "homodyne" else 1],
        run.flags,
        returns,
        tier="baseband",
        nyquist_hz=run.top,
        delay_offset_s=None
        if returns.echoes is None
        else echo_mean_offset_s((run.offsets, run.weights)),
    )


class _BasebandRun:
    """One batch through the baseband chain: the batch's set-up, then :meth:`block` by block
    (each block simulated and analysed before the next: memory is bounded by the block)."""

    def __init__(
        self, config: Instrument, returns: Returns, rng: np.random.Generator, keep_spectrum: bool
    ):
        self.config, self.returns, self.rng = config, returns, rng
        self.batch = returns.batch
        self.bud = bud = make_budget(config, returns)
        b = config.balanced
        self.fs, self.n = baseband_grid(config, float(np.max(np.abs(returns.doppler_hz))))
        self.k_avg, self.averaging = records_per_shot(config)
        self.top = band_top_hz_or_nyquist(config, self.fs)
        self.t = np.arange(self.n) / self.fs
        self.gate = bud.train.record_gate(self.t, config.simulation.duration_s)
        self.mode = mode = config.system.coherent_mode
        resp = responsivities(config, bud.nu_hz)
        self.r = r = (resp["balanced_1"], resp["balanced_2"])
        self.S = S = receiver_coupler(config, mode)
        self.cross = list(arm_cross(S, r))  # arm j: 2 Re(cross_j X)
        self.s_lo = bud.lo_power_scale(b.lo_power_w)
        self.s_sig = config.laser.power_w * bud.tx_gain * bud.h
        self.flags = detection_flags(config, bud, returns, nyquist_hz=self.top)
        if bud.f_beat_hz > self.top and "beat_out_of_band" not in self.flags:
            self.flags.append("beat_out_of_band")  # above the simulated band: it would alias
        self._phases(rng)
        self._footprint_delays()
        self._blocks(keep_spectrum)

    def _phases(self, rng: np.random.Generator) -> None:
        """The static carrier phase psi per record (drawn first), the shots' amplitudes, Doppler
        and the phase-noise stream."""
        config, returns, bud, batch = self.config, self.returns, self.bud, self.batch
        cp = returns.carrier_phase
        if cp == "random":
            psi = rng.uniform(0.0, 2 * np.pi, (batch, self.k_avg, 1))
        elif cp == "propagation":
            psi = np.full(
                (batch, 1, 1), -2 * np.pi * np.mod(bud.nu_hz * (bud.delay_s - bud.ref_delay_s), 1.0)
            )
        else:
            psi = np.full((batch, 1, 1), optimal_phase(self.mode))
        self.psi = psi + returns.phase_rad.reshape(batch, 1, 1)
        self.amp = np.sqrt(self.s_lo * self.s_sig * returns.power_factor).reshape(batch, 1, 1)
        self.doppler = returns.doppler_hz.reshape(batch, 1, 1)
        self.doppler_on = bool(np.any(self.doppler != 0))
        self.lw = config.laser.linewidth_hz
        self.pn_rng = child_stream(rng, "effect.phase_noise") if self.lw > 0 else None

    def _footprint_delays(self) -> None:
        """The echoes' delays (quantized like the rf tier's upsampled grid) and the product
        they share, or the per-shot product."""
        config, bud, sim = self.config, self.bud, self.config.simulation
        if self.returns.echoes is None:
            shape = (self.batch, 1)
            self.offsets, self.weights, self.phases = (
                np.zeros(shape),
                np.ones(shape),
                np.zeros(shape),
            )
        else:
            self.offsets, self.weights, self.phases = self.returns.echo_arrays()
        delays = bud.delay_s + self.offsets
        if bud.quantized:
            q = 1.0 / (sim.sample_rate_hz * sim.upsample_factor)
            delays = np.round(delays / q) * q
        self.delays = delays
        shared = bool(np.all(delays == delays[:1]))
        max_lag = float(np.max(np.mod(delays - bud.ref_delay_s, bud.train.period_s)))
        # None when every shot has the same delays: their products are cached (shared_beat).
        self.product = (
            None if shared else BeatProduct(config, bud.ref_delay_s, self.t, self.top, max_lag)
        )

    def _blocks(self, keep_spectrum: bool) -> None:
        """Block size, record buffers, noise terms and the analysis of a block."""
        config, bud, proc, b = self.config, self.bud, self.config.processing, self.config.balanced
        self.ase_current = []
        if bud.ase_psd_w_per_hz > 0:
            # LO x ASE beat: one-sided current PSD 4 |c|^2 P_lo(t) h S_ASE, written as the
            # equivalent shot-noise current PSD / (2 q) so that it follows the LO's slow power
            # like the shot noise.
            cross = self.cross
            c_noise = [cross[0] - cross[1]] if self.mode == "homodyne" else cross
            self.ase_current = [
                4 * abs(c) ** 2 * bud.h * bud.ase_psd_w_per_hz / (2 * ELEMENTARY_CHARGE_C)
                for c in c_noise
            ]
        k_avg, n = self.k_avg, self.n
        per_record = k_avg if (self.returns.carrier_phase == "random" or self.lw > 0) else 1
        self.coherent_avg = self.averaging == "coherent"
        # Records per shot in the block's largest arrays: K signals, or K noisy records to
        # power-average.
        rows = k_avg if (per_record > 1 or not self.coherent_avg) else 1
        self.block_shots = max(1, _BLOCK_ELEMENTS // (rows * n * max(1, self.offsets.shape[1])))
        # The noisy records and their FFT in the configured precision (phases are float64).
        self.dtype = np.float32 if config.simulation.baseband_precision == "single" else np.float64
        # Power averages drawn directly: the same signal in every record, stationary white noise
        # (a constant chirp envelope keeps the LO power and so the shot noise constant), native
        # bins.
        self.direct = (
            DIRECT_POWER_AVERAGE
            and not self.coherent_avg
            and k_avg > 1
            and per_record == 1
            and self.mode == "homodyne"
            and proc.zero_pad_factor == 1
            and proc.peak_method != "dtft"
            and bool(self.gate.all())
            and bool(np.all(bud.train.envelope_samples() == 1.0))
        )
        self.dark = b.solar_current_a + b.background_current_a + b.leakage_current_a
        # Noisy records are written in place into buffers reused from block to block.
        rec_shape = (min(self.block_shots, self.batch), 1 if self.coherent_avg else k_avg, n)
        self.bufs = [
            np.empty(rec_shape, self.dtype) for _ in range(1 if self.mode == "homodyne" else 2)
        ]
        self.analysis = partial(
            analyze_block,
            config,
            load_ohm=b.output_impedance_ohm,
            flags=self.flags,
            fs_hz=self.fs,
            transfer=single_pole(b.bandwidth_hz),
            search_max_hz=min(peak_search_max_hz(config, bud), self.top),
            keep_spectrum=keep_spectrum,
            averaging=self.averaging,
            arm_cross=None if self.mode == "homodyne" else self.cross,
        )
        # The detector noise (both arms, arm 1, arm 2) at the operating point the first block
        # sets (_BlockCurrents).
        self.circuit: list[DetectorNoise] | None = None
        self.sat_peak = 0.0
        self.z_gate = b.transimpedance_ohm * (self.gate if not self.gate.all() else 1.0)
        # Shot-noise terms whose variance is below 1e-6 of the dark and circuit floor are dropped
        # (the received signal's own shot noise against a mW LO): the noise level moves < 5e-6 dB.
        nz0 = balanced_noise(config, self.r[0], self.r[1], 0.0, 0.0)
        self.noise_floor = 1e-6 * (
            2 * self.dark + 0.5 * (nz0.thermal + nz0.amplifier) / ELEMENTARY_CHARGE_C
        )

    @property
    def noise(self) -> list[DetectorNoise]:
        """:attr:`circuit`, once the first block has set it."""
        if self.circuit is None:
            raise RuntimeError("baseband: the detector noise is set by the first block")
        return self.circuit

    def footprint(self, sl: slice):
        """Complex low-pass product C = sum_k sqrt(w_k) exp(-j phi_k) [a_lo a_k]_low (m, 1, N),
        the signal's slow power sum_k w_k <a_k^2> (m, 1, N) and the LO's (N,), for a block."""
        k = self.offsets.shape[1]
        weights, phases = self.weights, self.phases
        if self.product is None:
            parts = [
                shared_beat(
                    self.config,
                    self.bud.ref_delay_s,
                    self.bud.lag_s,
                    float(self.delays[0, kk]),
                    self.fs,
                    self.n,
                    self.top,
                )
                for kk in range(k)
            ]
            p_lo = parts[0][2]
            if k == 1 and not np.any(phases[sl]):
                return parts[0][0][None, None, :], parts[0][1][None, None, :], p_lo
            beats = [(parts[kk][0], parts[kk][1]) for kk in range(k)]
        else:
            p_lo = self.product.power_lo
            beats = [self.product.beat(self.delays[sl, kk, None]) for kk in range(k)]
        # Sums over the echoes (float64 and complex128 terms: a 0-d zero adds as 0.0 does).
        C, p_sig = np.zeros(()), np.zeros(())
        for kk, (bk, pk) in enumerate(beats):
            C = C + np.sqrt(weights[sl, kk, None]) * np.exp(-1j * phases[sl, kk, None]) * bk
            p_sig = p_sig + weights[sl, kk, None] * pk
        return C[:, None, :], p_sig[:, None, :], p_lo

    def block(self, sl: slice):
        """Simulate and analyse the shots ``sl``: :func:`analyze_block`'s result."""
        cur = _BlockCurrents(self, sl)
        m, k_avg, n, b = cur.m, self.k_avg, self.n, self.config.balanced
        cross, fs, dark = self.cross, self.fs, self.dark
        shape = (m, 1 if self.coherent_avg else k_avg, n)
        if self.mode != "homodyne":
            for j in (0, 1):
                one = tuple(1 if a == j else 0 for a in (0, 1))
                total = _dense(cur.current(one, cross[j]))  # an arm's own current: its noise
                if self.ase_current:
                    total = total + self.ase_current[j] * cur.p_lo
                nz = self.noise[1 + j]
                _noisy(
                    self.rng,
                    cur.current(one, cross[j], gain=self.z_gate),
                    total,
                    dark,
                    nz.thermal + nz.amplifier,
                    fs,
                    shape,
                    self.coherent_avg,
                    k_avg,
                    self.z_gate,
                    self.dtype,
                    out=self.bufs[j][:m],
                )
            return self.analysis({"arm1": self.bufs[0][:m], "arm2": self.bufs[1][:m]})
        # i1 - i2 and i1 + i2 from the arms' self terms and cross terms.
        self.sat_peak = max(
            self.sat_peak, float(np.max(self.amp[sl])) * 2 * abs(cross[0] - cross[1])
        )
        total = _dense(cur.current((1, 1), cross[0] + cross[1], floor=self.noise_floor))
        if self.ase_current:
            total = total + self.ase_current[0] * cur.p_lo
        nz = self.noise[0]
        if self.direct:
            # Noiseless records and each shot's noise variance per sample (V^2), drawn per bin.
            tot = np.broadcast_to(total, (m, 1, n))[:, 0, 0]
            var = current_noise_variance(tot, 2 * dark, nz.thermal + nz.amplifier, fs)
            diff = cur.current((1, -1), cross[0] - cross[1], gain=b.transimpedance_ohm)
            return self.analysis(
                {"main": np.broadcast_to(_dense(diff), (m, 1, n))},
                spectrum_analyzer=partial(
                    draw_power_average,
                    averages=k_avg,
                    rng=self.rng,
                    var_v2=b.transimpedance_ohm**2 * var,
                ),
            )
        diff = cur.current((1, -1), cross[0] - cross[1], gain=self.z_gate)
        _noisy(
            self.rng,
            diff,
            total,
            2 * dark,
            nz.thermal + nz.amplifier,
            fs,
            shape,
            self.coherent_avg,
            k_avg,
            self.z_gate,
            self.dtype,
            out=self.bufs[0][:m],
        )
        return self.analysis({"main": self.bufs[0][:m]})


class _BlockCurrents:
    """A block's optical product, phases and the arms' photocurrents (:meth:`current`)."""

    def __init__(self, run: _BasebandRun, sl: slice):
        self.run = run
        self.m = m = sl.stop - sl.start
        C, p_sig, p_lo = run.footprint(sl)
        self.C, self.p_sig, self.p_lo = C, p_sig, p_lo
        # Optical phase of E_lo E_sig*: laser phase noise, carrier phase, Doppler.
        theta = -run.psi[sl]
        if run.doppler_on:
            theta = theta - 2 * np.pi * run.doppler[sl] * run.t
        if run.pn_rng is not None:  # laser phase noise (a linewidth)
            bud = run.bud
            th_lo, th_sig = (
                x.reshape(m, run.k_avg, run.n)
                for x in wiener_phase(
                    [run.t - bud.ref_delay_s, run.t - bud.delay_s],
                    run.lw,
                    run.pn_rng,
                    m * run.k_avg,
                )
            )
            theta = theta + th_lo - th_sig
        self.sig_scale = sig_scale = run.s_sig * run.returns.power_factor[sl, None, None]
        if run.circuit is None:  # the arms' mean optical powers (the detector's operating point)
            S, r = run.S, run.r
            mean_sig = float(np.mean(sig_scale * np.mean(p_sig, axis=-1, keepdims=True)))
            mean_p = [
                float(abs(S[j, 0]) ** 2 * run.s_lo * np.mean(p_lo) + abs(S[j, 1]) ** 2 * mean_sig)
                for j in (0, 1)
            ]
            run.circuit = [
                balanced_noise(run.config, r[0], r[1], *mean_p, arm=a) for a in (None, 0, 1)
            ]
        self.outer = (
            not (np.iscomplexobj(C) or theta.shape[-1] > 1) and C.shape[0] == p_sig.shape[0] == 1
        )
        if self.outer:
            # One real product for every shot and a constant phase per record: each current is
            # per-record coefficients times three functions of time, i.e. one matrix product.
            self.rot = run.amp[sl] * np.exp(1j * theta)  # (m, 1 or K, 1)
            self.peak = float(np.max(np.abs(self.rot))) * float(np.max(np.abs(C)))
        else:
            self.X = run.amp[sl] * C * np.exp(1j * theta)  # E_lo E_sig*
            self.peak = float(np.max(np.abs(self.X)))
        self.sig_peak = float(np.max(sig_scale)) * float(np.max(p_sig))
        # Shots of equal received power and one shared product: their direct terms are one
        # function of time, so the noise's standard deviation is computed once, not per shot.
        self.sig_common = (
            float(sig_scale.flat[0])
            if p_sig.shape[0] == 1 and np.all(sig_scale == sig_scale.flat[0])
            else None
        )

    def current(self, signs, c, floor=None, gain=1.0):
        """``gain`` x sum_j signs_j i_j(t): the arms' direct-detection terms plus
        2 Re(c E_lo E_sig*), (N,), (m, 1 or K, N) or, for one shared product, a
        :class:`_LowRank` of the per-record coefficients and the functions of time; terms
        whose largest current is below ``floor`` (A) are left out (see the noise floor)."""
        run, p_sig, sig_scale = self.run, self.p_sig, self.sig_scale
        a_lo, a_sig = _arm_coefficients(run.r, run.S, signs, self.sig_peak, floor)
        if floor is not None and 2 * abs(c) * self.peak <= floor:
            c = 0.0
        lo = (a_lo * run.s_lo) * self.p_lo * gain
        common = self.sig_common
        if c == 0 and a_sig == 0:
            return lo
        if c == 0 and common is not None:  # the same for every shot
            return lo + (a_sig * common) * p_sig[0, 0] * gain
        if not self.outer:
            out = lo if a_sig == 0 else lo + (a_sig * sig_scale) * (p_sig * gain)
            return out if c == 0 else out + 2.0 * np.real(c * self.X) * gain
        rot = self.rot
        coef = np.stack(
            np.broadcast_arrays(
                np.ones(rot.shape), a_sig * sig_scale * np.ones(rot.shape), 2.0 * np.real(c * rot)
            ),
            axis=-1,
        )[:, :, 0, :]  # (m, 1 or K, 3)
        fns = np.stack(
            [np.broadcast_to(lo, (run.n,)), a_sig * p_sig[0, 0] * gain, self.C[0, 0] * gain]
        )  # (3, N)
        return _LowRank(coef, fns)


def draw_power_average(
    signal_v: np.ndarray,
    fs_hz: float,
    load_ohm: float,
    *,
    var_v2: np.ndarray,
    averages: int,
    rng: np.random.Generator,
    averaging: str = "power",
    zero_pad: int = 1,
    **kw,
):
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
    scale = n * np.asarray(var_v2, float)[:, None]  # E|N_k|^2, (batch, 1)
    s2 = S.real**2 + S.imag**2
    real_bins = np.zeros(S.shape[-1], bool)
    real_bins[0] = True
    if n % 2 == 0:
        real_bins[-1] = True
    k = averages
    total = np.empty_like(s2)
    inner = ~real_bins
    total[:, inner] = 0.5 * scale * rng.noncentral_chisquare(2 * k, 2 * k * s2[:, inner] / scale)
    total[:, real_bins] = scale * rng.noncentral_chisquare(k, k * s2[:, real_bins] / scale)
    psd = (2.0 / (n * fs_hz * load_ohm)) * total / k
    return analyze_spectrum(psd, fs_hz, n, zero_pad=1, **kw)


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


def _noisy(
    rng, signal_v, total, dark_a, circuit_psd, fs, shape, coherent_avg, k_avg, gain, dtype, out
):
    """Signal voltage ``signal_v`` plus the noise of ``total`` (A) times ``gain`` (the
    transimpedance times the record gate, V/A), written to ``out`` (m, 1 or K, N) of ``dtype``.

    Coherent averaging returns the mean of the K records: the mean signal plus one noise record of
    1/K the variance (current, dark and circuit terms all scale the variance linearly).
    """
    if coherent_avg and k_avg > 1:
        signal_v = _mean_records(signal_v)
        if np.ndim(total) == 3 and total.shape[1] > 1:
            total = total.mean(axis=1, keepdims=True)
        noise = current_noise(
            rng,
            shape,
            np.divide(total, k_avg),
            dark_a / k_avg,
            circuit_psd / k_avg,
            fs,
            dtype=dtype,
            gain=gain,
            out=out,
        )
    else:
        noise = current_noise(
            rng, shape, total, dark_a, circuit_psd, fs, dtype=dtype, gain=gain, out=out
        )
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
        rows = out.reshape(-1, out.shape[-1])  # a view: out is contiguous
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
