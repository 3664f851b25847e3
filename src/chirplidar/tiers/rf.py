"""The rf tier: the full-rate time-domain chain of thesis Chapter 4 (LIDAR_main.m).

chirp at Fs -> MZM field -> LO / transmit split -> (amplifier) -> channel delay -> coupler or hybrid
-> photodiodes with shot, thermal and amplifier noise -> (RF dechirp) -> FFT peak analysis.

Optical fields are complex envelopes about the laser frequency in float64; the carrier is never
sampled. The return is one point target, or the coherent sum of a footprint's echoes
(tiers.echoes). Records have shape (batch, averages, N): no Python loop over samples or averages.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft

from ..receiver import single_pole
from ..receiver.detectors import apd_noise, balanced_noise, current_noise, pin_noise
from ..receiver.fields import Field, combine, port_coefficients, port_power
from ..streams import child_stream
from ..transmitter import mzm_field, wiener_phase
from .budget import (
    Budget,
    arm_cross,
    if_half_width_hz,
    make_budget,
    receiver_coupler,
    responsivities,
)
from .common import (
    detection_flags,
    echo_mean_offset_s,
    optimal_phase,
    peak_search_max_hz,
)
from .model import Instrument, Measurements, Returns
from .records import process_records


def _lowpass(x: np.ndarray, bandwidth_hz: float, fs_hz: float) -> np.ndarray:
    n = x.shape[-1]
    X = scipy.fft.rfft(x, axis=-1, workers=-1)
    X *= single_pole(bandwidth_hz).on_grid(n, fs_hz)
    return scipy.fft.irfft(X, n=n, axis=-1, workers=-1)


@lru_cache(maxsize=16)
def _modulator_fields(
    train,
    bias_v: float,
    v_pi_v: float,
    n: int,
    fs_hz: float,
    duration_s: float,
    delay_s: float,
    ref_delay_s: float,
):
    """Deterministic per instrument and geometry: the MZM field of the signal (delayed by tau) and of
    the LO / reference (delayed by tau_ref) on the record grid, and the record gate. Cached because a
    run or a sweep of attenuation, detector or seed reuses them shot after shot (read-only arrays)."""
    t = np.arange(n) / fs_hz
    a_sig = mzm_field(bias_v + train.voltage(t - delay_s), v_pi_v)
    a_lo = mzm_field(bias_v + train.voltage(t - ref_delay_s), v_pi_v)
    gate = train.record_gate(t, duration_s)
    if gate.all():
        gate = np.ones(1, dtype=bool)  # nothing to cut: multiplying by it is free
    # The products the coupler outputs are made of (see receiver.fields.port_coefficients).
    products = (a_lo * a_lo, a_sig * a_sig, a_lo * a_sig)
    for arr in (t, a_sig, a_lo, gate, *products):
        arr.setflags(write=False)
    return t, a_sig, a_lo, gate, products


def _echo_envelope(
    train,
    bias_v: float,
    v_pi_v: float,
    t: np.ndarray,
    bud: Budget,
    fs_hz: float,
    upsample: int,
    offsets: np.ndarray,
    weights: np.ndarray,
    phases: np.ndarray,
):
    """|A| and arg A of A(t) = sum_k sqrt(w_k) exp(j phi_k) a(t - tau - dtau_k), shape (batch, 1, N).

    ``offsets``, ``weights`` (normalised) and ``phases`` have shape (batch, k); a is the MZM field
    amplitude, evaluated exactly at each echo's delay (one waveform evaluation per echo, over (N,)
    when every shot has the same offsets, else over (batch, N)). Real and imaginary parts are
    accumulated separately in float64.
    """
    batch, k = offsets.shape
    shared = bool(np.all(offsets == offsets[:1]))
    delays = bud.delay_s + (offsets[:1] if shared else offsets)  # (1 or batch, k)
    if bud.quantized:
        # delay_method = 'resample' emulates the upxn grid: every echo lands on it too.
        q = 1.0 / (fs_hz * upsample)
        delays = np.round(delays / q) * q
    coef = np.sqrt(weights)
    c_re, c_im = coef * np.cos(phases), coef * np.sin(phases)  # (batch, k)
    if shared:
        # Echo fields (k, N), mixed per shot by a matrix product: one BLAS pass, no (batch, N)
        # temporaries per echo.
        a = np.empty((k, t.size))
        for j in range(k):
            a[j] = mzm_field(bias_v + train.voltage(t - delays[0, j]), v_pi_v)
        re, im = c_re @ a, c_im @ a
    else:
        re = np.zeros((batch, t.size))
        im = np.zeros((batch, t.size))
        for j in range(k):
            a = mzm_field(bias_v + train.voltage(t - delays[:, j, None]), v_pi_v)  # (batch, N)
            re += c_re[:, j, None] * a
            im += c_im[:, j, None] * a
    arg = np.arctan2(im, re)
    mag = re * re
    mag += im * im
    np.sqrt(mag, out=mag)  # |A| (values ~1: no need for hypot's overflow guard)
    return mag[:, None, :], arg[:, None, :]


@dataclass(frozen=True)
class _Grid:
    """The record grid of one batch: sample times, the modulator fields of the signal (delayed by
    tau) and of the LO (by tau_ref), the record gate, the coupler's products, the records' shape
    (batch, averages, N) and the sample rate."""

    t: np.ndarray
    a_sig: np.ndarray
    a_lo: np.ndarray
    gate: np.ndarray
    products: tuple
    shape: tuple
    fs: float


def _grid(config: Instrument, bud: Budget, batch: int) -> _Grid:
    sim = config.simulation
    fs = sim.sample_rate_hz
    # gate: no partial chirps, the rest of the record is zero.
    t, a_sig, a_lo, gate, products = _modulator_fields(
        bud.train,
        config.modulator.bias_v,
        config.modulator.v_pi_v,
        config.n_samples,
        fs,
        sim.duration_s,
        bud.delay_s,
        bud.ref_delay_s,
    )
    return _Grid(
        t, a_sig, a_lo, gate, products, (batch, config.processing.averages, config.n_samples), fs
    )


def simulate_rf(
    config: Instrument, returns: Returns, rng: np.random.Generator, *, keep_spectrum: bool = False
) -> Measurements:
    """Simulate the batch of ``returns`` through the full-rate chain; arrays of shape (batch,).

    With ``returns.echoes`` each shot's return is the coherent sum of k delayed echoes of its
    footprint instead of one point target; echoes draw nothing themselves.
    """
    bud = make_budget(config, returns)
    grid = _grid(config, bud, returns.batch)
    mode = config.system.coherent_mode if config.system.receiver == "coherent" else "direct"
    flags = detection_flags(config, bud, returns, nyquist_hz=grid.fs / 2)
    th_lo, th_sig = _laser_phase_noise(config, bud, grid, rng)
    sig, psi, dop_phase, s_sig = _signal_field(config, returns, bud, grid, rng, mode, th_sig)
    load = transfer = None
    if mode in ("homodyne", "phase_diversity"):
        simple = sig.noise is None and config.laser.linewidth_hz == 0 and returns.echoes is None
        records, noise, load, transfer = _coherent(
            config, bud, grid, rng, mode, sig, th_lo, -psi - dop_phase, s_sig, flags, simple
        )
    elif mode == "heterodyne":
        records, noise, load = _heterodyne(
            config,
            bud,
            rng,
            sig,
            grid.t,
            grid.shape,
            responsivities(config, bud.nu_hz),
            grid.gate,
            th_sig + dop_phase,
            psi,
        )
    else:
        records, noise, load = _direct(
            config, bud, rng, sig, grid.t, grid.shape, responsivities(config, bud.nu_hz), grid.gate
        )
    pn_reference = (
        bud.train.unit(grid.t - bud.ref_delay_s) if config.system.modulation == "pn_code" else None
    )
    return process_records(
        config,
        bud,
        records,
        noise,
        load,
        flags,
        returns,
        fs_hz=grid.fs,
        transfer=transfer,
        search_max_hz=peak_search_max_hz(config, bud),
        keep_spectrum=keep_spectrum,
        tier="rf",
        extra={},
        pn_reference=pn_reference,
        nyquist_hz=grid.fs / 2,
        delay_offset_s=echo_mean_offset_s(returns.echo_arrays()),
        arm_cross=_arm_cross(config, bud) if mode == "phase_diversity" else None,
    )


def _arm_cross(config: Instrument, bud: Budget) -> tuple[complex, complex]:
    """The 90-degree hybrid arms' cross coefficients (:func:`.budget.arm_cross`)."""
    resp = responsivities(config, bud.nu_hz)
    return arm_cross(
        receiver_coupler(config, "phase_diversity"), (resp["balanced_1"], resp["balanced_2"])
    )


def _laser_phase_noise(config: Instrument, bud: Budget, grid: _Grid, rng: np.random.Generator):
    """(theta_lo, theta_sig): the laser's Wiener phase at t - tau_ref and t - tau, drawn on the
    phase-noise effect's stream (zeros without a linewidth)."""
    batch, k_avg, _ = grid.shape
    lw = config.laser.linewidth_hz
    if lw <= 0:
        zero = np.zeros((batch, k_avg, 1))
        return zero, zero
    th_lo, th_sig = (
        th.reshape(grid.shape)
        for th in wiener_phase(
            [grid.t - bud.ref_delay_s, grid.t - bud.delay_s],
            lw,
            child_stream(rng, "effect.phase_noise"),
            batch * k_avg,
        )
    )
    return th_lo, th_sig


def _signal_field(
    config: Instrument,
    returns: Returns,
    bud: Budget,
    grid: _Grid,
    rng: np.random.Generator,
    mode: str,
    th_sig,
):
    """The received signal's :class:`Field` (a point target or the echoes' sum, with the
    transmitter's ASE), its static carrier phase psi relative to the LO, the Doppler phase ramp
    and the per-shot power scale |E_s|^2. Draws the random carrier phase, then the ASE."""
    batch, k_avg, _ = grid.shape
    per_shot = (batch, 1, 1)
    cp = returns.carrier_phase
    if cp == "random":
        psi = rng.uniform(0.0, 2 * np.pi, (batch, k_avg, 1))
    elif cp == "propagation":
        psi = np.full(
            (batch, k_avg, 1), -2 * np.pi * np.mod(bud.nu_hz * (bud.delay_s - bud.ref_delay_s), 1.0)
        )
    else:
        psi = np.full((batch, k_avg, 1), optimal_phase(mode))
    psi = psi + returns.phase_rad.reshape(per_shot)  # speckle phase
    s_sig = config.laser.power_w * bud.tx_gain * bud.h  # |E_s|^2 scale: mean = Psig
    s_sig = s_sig * returns.power_factor.reshape(per_shot)  # speckle power
    doppler = returns.doppler_hz.reshape(per_shot)
    # Carrier Doppler shift of the return (a phase ramp); absent unless the effect is enabled.
    dop_phase = 2 * np.pi * doppler * grid.t if np.any(doppler != 0) else 0.0
    ase = None
    if bud.ase_psd_w_per_hz > 0:
        sigma = np.sqrt(bud.ase_psd_w_per_hz * grid.fs * bud.h / 2.0)
        ase = sigma * (rng.standard_normal(grid.shape) + 1j * rng.standard_normal(grid.shape))
    echo_arrays = returns.echo_arrays()
    if echo_arrays is None:
        return (
            Field(np.sqrt(s_sig) * grid.a_sig, th_sig + psi + dop_phase, ase),
            psi,
            dop_phase,
            s_sig,
        )
    # The echoes' sum is a complex, time-varying envelope: Field keeps a real amplitude and a
    # phase, so it holds |A| and arg A. Laser phase noise: every echo takes the main delay's
    # Wiener phase th_sig. Echoes dtau apart differ in phase noise by a variance of
    # 2 pi linewidth |dtau| (2 pi x 100 kHz x 10 ns = 6e-3 rad^2): negligible.
    mag, arg = _echo_envelope(
        bud.train,
        config.modulator.bias_v,
        config.modulator.v_pi_v,
        grid.t,
        bud,
        grid.fs,
        config.simulation.upsample_factor,
        *echo_arrays,
    )
    return Field(np.sqrt(s_sig) * mag, arg + th_sig + psi + dop_phase, ase), psi, dop_phase, s_sig


def _coherent(
    config: Instrument,
    bud: Budget,
    grid: _Grid,
    rng: np.random.Generator,
    mode: str,
    sig: Field,
    th_lo,
    lo_phase,
    s_sig,
    flags: list,
    simple: bool,
):
    """Balanced homodyne or phase-diversity detection: (records, noise, load, transfer).
    ``lo_phase`` = -psi - Doppler phase; ``simple``: no phase noise, ASE or echoes, so the
    currents are fixed mixes of the three cached products."""
    b = config.balanced
    resp = responsivities(config, bud.nu_hz)
    s_lo = bud.lo_power_scale(b.lo_power_w)
    S = receiver_coupler(config, mode)
    dark = b.solar_current_a + b.background_current_a + b.leakage_current_a
    r1, r2 = resp["balanced_1"], resp["balanced_2"]
    if simple:
        # A balanced pair's LO and signal power terms cancel in the coefficients.
        cf = [port_coefficients(S[k, 0], S[k, 1], s_lo, s_sig, lo_phase) for k in (0, 1)]
        means = [float(np.mean(a)) for a in grid.products]
        mean_p = [
            float(np.mean(sum(np.asarray(c) * m for c, m in zip(cf[k], means, strict=True))))
            for k in (0, 1)
        ]
        arm = [[r1 * c for c in cf[0]], [r2 * c for c in cf[1]]]
        if mode == "homodyne":
            diff = combine([x - y for x, y in zip(*arm, strict=True)], grid.products)
            total = combine([x + y for x, y in zip(*arm, strict=True)], grid.products)
        else:
            i1, i2 = combine(arm[0], grid.products), combine(arm[1], grid.products)
    else:
        lo = Field(np.sqrt(s_lo) * grid.a_lo, th_lo)
        p1, p2 = (port_power(S[k, 0], S[k, 1], lo, sig) for k in (0, 1))
        i1, i2 = r1 * p1, r2 * p2
        diff, total = i1 - i2, i1 + i2
        mean_p = [float(np.mean(p1)), float(np.mean(p2))]
    # The RF amplifier saturates on what balancing leaves: the differential optical power.
    diff_peak = float(np.max(np.abs(diff))) / (0.5 * (r1 + r2)) if mode == "homodyne" else 0.0
    if diff_peak > b.saturation_power_w:
        flags.append("saturation")
        warnings.warn(
            f"balanced detector amplifier saturates: differential {diff_peak * 1e3:.3g} mW"
            f" > balanced.saturation_power_w = {b.saturation_power_w * 1e3:.3g} mW",
            stacklevel=3,
        )
    noise_any = balanced_noise(config, r1, r2, *mean_p)
    load, z, fs = b.output_impedance_ohm, b.transimpedance_ohm, grid.fs
    transfer = single_pole(b.bandwidth_hz)
    if mode == "homodyne":
        # The two photodiodes' shot noises and the circuit noise are independent Gaussians:
        # one draw with the summed variance has the same distribution.
        i = current_noise(
            rng, grid.shape, total, 2 * dark, noise_any.thermal + noise_any.amplifier, fs
        )
        i += diff
        i *= z
        return {"main": i if grid.gate.size == 1 else i * grid.gate}, noise_any, load, transfer
    arms = []
    for idx, ik in enumerate((i1, i2)):
        nz = balanced_noise(config, r1, r2, *mean_p, arm=idx)
        arms.append(
            z
            * (ik + current_noise(rng, grid.shape, ik, dark, nz.thermal + nz.amplifier, fs))
            * grid.gate
        )
    return (
        {"arm1": arms[0], "arm2": arms[1]},
        balanced_noise(config, r1, r2, *mean_p, arm=0),
        load,
        transfer,
    )


def _direct(config, bud: Budget, rng, sig: Field, t, shape, resp, gate):
    """PIN or APD direct detection followed by RF dechirp mixing (thesis Fig. 5.4)."""
    fs = config.simulation.sample_rate_hz
    p = np.broadcast_to(sig.power(), shape)
    rx = config.system.receiver
    if rx == "pin":
        c = config.pin
        i = resp["pin"] * p
        noise = pin_noise(config, resp["pin"], bud.psig_w)
        dark = c.solar_current_a + c.background_current_a + c.leakage_current_a
        i_n = i + current_noise(rng, shape, i, dark, noise.thermal + noise.amplifier, fs)
    else:
        a = config.apd
        i = resp["apd"] * p
        noise = apd_noise(config, resp["apd"], bud.psig_w)
        # Multiplied shot noise with excess factor F, referred to the primary photocurrent.
        f_ex = a.excess_noise_factor
        i_n = i + current_noise(
            rng,
            shape,
            f_ex * i,
            f_ex * (a.solar_current_a + a.background_current_a) + a.leakage_current_a / a.gain**2,
            noise.thermal + noise.amplifier,
            fs,
        )
    v = noise.gain_ohm * _lowpass(i_n, noise.bandwidth_hz, fs)
    if config.system.modulation == "pn_code":
        return {"main": v * gate}, noise, noise.load_ohm
    ref = bud.train.unit(t - bud.ref_delay_s)  # the generator's chirp, delayed (RF dechirp mixer)
    return {"main": v * ref * gate}, noise, noise.load_ohm


def _heterodyne(config, bud: Budget, rng, sig: Field, t, shape, resp, gate, th_sig, psi):
    """Heterodyne prototype (thesis Fig. 5.5): separate CW LO offset by f_LO, 3 dB coupler with one
    arm capped (or both arms balanced), IF band-pass, envelope or synchronous demodulation, RF
    dechirp mixing."""
    fs = config.simulation.sample_rate_hz
    b, h = config.balanced, config.heterodyne
    f_lo = b.lo_offset_hz
    th_lo = (
        wiener_phase([t], b.lo_linewidth_hz, rng, shape[0] * shape[1])[0].reshape(shape)
        if b.lo_linewidth_hz > 0
        else np.zeros((shape[0], shape[1], 1))
    )
    lo = Field(np.full(t.shape, np.sqrt(b.lo_power_w)), 2 * np.pi * f_lo * t + th_lo)
    S = receiver_coupler(config, "homodyne")
    p1 = port_power(S[0, 0], S[0, 1], lo, sig)
    r = resp["heterodyne"]
    dark = b.solar_current_a + b.background_current_a + b.leakage_current_a
    if h.capped_arm:
        i = r * p1
        noise = balanced_noise(config, r, r, float(np.mean(p1)), 0.0, arm=0)
        i_n = i + current_noise(rng, shape, i, dark, noise.thermal + noise.amplifier, fs)
    else:
        p2 = port_power(S[1, 0], S[1, 1], lo, sig)
        i = r * (p1 - p2)
        noise = balanced_noise(config, r, r, float(np.mean(p1)), float(np.mean(p2)))
        i_n = i + current_noise(
            rng, shape, r * (p1 + p2), 2 * dark, noise.thermal + noise.amplifier, fs
        )
    # IF band-pass around f_LO and complex envelope (analytic signal shifted down by f_LO).
    n = t.size
    half = if_half_width_hz(config, bud)
    X = scipy.fft.fft(i_n, axis=-1, workers=-1)
    f = scipy.fft.fftfreq(n, 1.0 / fs)
    keep = (f > max(f_lo - half, 0.0)) & (f < f_lo + half)
    X = np.where(keep, 2.0 * X, 0.0)
    z = scipy.fft.ifft(X, axis=-1, workers=-1) * np.exp(-2j * np.pi * f_lo * t)
    if h.demodulation == "envelope":
        base = np.abs(z)
    else:
        # Ideal coherent demodulation: the receiver knows the carrier phase (incl. phase noise).
        # With footprint echoes there is no single carrier phase: it locks to the phase of the
        # echoes' sum correlated with the main delay's envelope (rot below).
        d = z * np.exp(1j * (th_sig - th_lo + psi))
        a_ref = mzm_field(
            config.modulator.bias_v + bud.train.voltage(t - bud.delay_s), config.modulator.v_pi_v
        )
        rot = np.sum(d * a_ref, axis=-1, keepdims=True)
        base = np.real(d * np.exp(-1j * np.angle(rot)))
    ref = bud.train.unit(t - bud.ref_delay_s)
    return {"main": noise.gain_ohm * base * ref * gate}, noise, noise.load_ohm
