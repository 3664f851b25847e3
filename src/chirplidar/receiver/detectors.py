"""Photodetector models: DC operating point, noise PSDs and the output chain of each receiver.

``DetectorNoise`` holds the one-sided current PSDs referred to the photodiode; multiplied by the
transimpedance squared and divided by the load they give the output PSDs reported as Ns, Nt, Ne.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..units import ELEMENTARY_CHARGE_C
from . import shot_psd, thermal_psd


@dataclass(frozen=True)
class DetectorNoise:
    shot: float  # A^2/Hz, from signal, LO, dark and background currents
    thermal: float  # A^2/Hz, Johnson noise of the load (and APD feedback / detector resistance)
    amplifier: float  # A^2/Hz, amplifier equivalent input noise (NEP or TIA current/voltage noise)
    gain_ohm: float  # transimpedance: output volts per photocurrent ampere
    load_ohm: float  # load the output power is referred to
    bandwidth_hz: float
    beat: float = 0.0  # A^2/Hz, optical-amplifier ASE beating with the LO or the signal

    @property
    def total(self) -> float:
        return self.shot + self.thermal + self.amplifier + self.beat

    def output_psd_w_per_hz(self, current_psd):
        return np.asarray(current_psd) * self.gain_ohm**2 / self.load_ohm


def balanced_noise(
    cfg,
    resp1: float,
    resp2: float,
    mean_power_1_w: float,
    mean_power_2_w: float,
    *,
    arm: int | None = None,
) -> DetectorNoise:
    """Balanced photodetector (Table 4.8). ``arm`` = 0 or 1 for one photodiode read alone."""
    b = cfg.balanced
    dark = b.solar_current_a + b.background_current_a + b.leakage_current_a
    i1, i2 = resp1 * mean_power_1_w, resp2 * mean_power_2_w
    if arm is None:
        shot, r_mean = shot_psd(i1 + i2 + 2 * dark), 0.5 * (resp1 + resp2)
    else:
        shot, r_mean = shot_psd((i1, i2)[arm] + dark), (resp1, resp2)[arm]
    thermal = (
        thermal_psd(b.noise_temperature_k, b.output_impedance_ohm) if b.noise_temperature_k else 0.0
    )
    return DetectorNoise(
        shot=float(shot),
        thermal=thermal,
        amplifier=(b.nep_w_per_rthz * r_mean) ** 2,
        gain_ohm=b.transimpedance_ohm,
        load_ohm=b.output_impedance_ohm,
        bandwidth_hz=b.bandwidth_hz,
    )


def pin_noise(cfg, resp: float, mean_power_w: float) -> DetectorNoise:
    p = cfg.pin
    dark = p.solar_current_a + p.background_current_a + p.leakage_current_a
    thermal = (
        thermal_psd(p.noise_temperature_k, p.output_impedance_ohm) if p.noise_temperature_k else 0.0
    )
    return DetectorNoise(
        shot=float(shot_psd(resp * mean_power_w + dark)),
        thermal=thermal,
        amplifier=(p.nep_w_per_rthz * resp) ** 2,
        gain_ohm=p.transimpedance_ohm,
        load_ohm=p.output_impedance_ohm,
        bandwidth_hz=p.bandwidth_hz,
    )


def apd_noise(cfg, resp: float, mean_power_w: float) -> DetectorNoise:
    """APD with transimpedance amplifier (Table 4.7, eqs. 2.5.1-2.5.5).

    Bulk currents (signal, background, solar) are multiplied: 2 q I M^2 F; surface leakage is not.
    Referred to the primary photocurrent, the multiplied shot term is 2 q I F (the M^2 divides out)
    and the circuit terms divide by M^2. Amplifier voltage noise sees the input admittance
    1/Rfb + 1/Ro + j 2 pi fo (Cdet + Cfb), evaluated at the receiver centre frequency ``fo``.
    """
    a = cfg.apd
    m, f_excess = a.gain, a.excess_noise_factor
    bulk = resp * mean_power_w + a.solar_current_a + a.background_current_a
    shot = float(shot_psd(bulk)) * f_excess + float(shot_psd(a.leakage_current_a)) / m**2
    thermal = (
        thermal_psd(a.feedback_temperature_k, a.feedback_resistance_ohm)
        + thermal_psd(a.detector_temperature_k, a.dynamic_resistance_ohm)
    ) / m**2
    admittance2 = (1 / a.feedback_resistance_ohm + 1 / a.dynamic_resistance_ohm) ** 2 + (
        2 * np.pi * a.center_frequency_hz * (a.detector_capacitance_f + a.feedback_capacitance_f)
    ) ** 2
    amp = (
        a.amp_current_noise_a_per_rthz**2 + a.amp_voltage_noise_v_per_rthz**2 * admittance2
    ) / m**2
    bandwidth = 1.0 / (2 * np.pi * a.feedback_resistance_ohm * a.feedback_capacitance_f)
    # Referred to the primary photocurrent, the transimpedance includes the gain M.
    return DetectorNoise(
        shot=shot,
        thermal=thermal,
        amplifier=float(amp),
        gain_ohm=a.feedback_resistance_ohm * m,
        load_ohm=a.feedback_resistance_ohm,
        bandwidth_hz=bandwidth,
    )


def current_noise_variance(
    current_a, dark_a: float, circuit_psd: float, fs_hz: float
) -> np.ndarray:
    """Variance per sample (A^2) of shot noise of ``current_a`` + ``dark_a`` plus white circuit
    noise of one-sided PSD ``circuit_psd``, sampled at ``fs_hz``: q (I + I_dark) Fs + S Fs / 2."""
    per_amp = ELEMENTARY_CHARGE_C * fs_hz
    var = np.multiply(current_a, per_amp, dtype=np.float64)
    var += per_amp * dark_a + 0.5 * circuit_psd * fs_hz
    return var


def unit_normals(
    rng: np.random.Generator, shape: int | Sequence[int], out: np.ndarray | None = None
) -> np.ndarray:
    """Independent standard normals of ``shape`` (float32), by the Box-Muller transform.

    Pairs (r cos a, r sin a) with r = sqrt(-2 ln(1 - u)), a = 2 pi v, u ~ U[0, 1) in float64 (so
    the tail reaches sqrt(2 ln 2**53) = 8.6 sigma) and v ~ U[0, 1) in float32 are exactly
    Gaussian and independent (Box & Muller 1958). Vectorised float32 log, sin and cos make it
    about twice as fast here as numpy's float32 ziggurat, and receiver noise is the largest
    single cost of a baseband shot; ``bench --what tiers`` measures it. ``out``: an optional
    C-contiguous float32 array of ``shape`` to fill (and return).
    """
    shape = tuple(int(k) for k in np.atleast_1d(shape))  # an int n is the shape (n,)
    size = math.prod(shape)
    half = (size + 1) // 2
    r = np.subtract(1.0, rng.random(half))  # (0, 1], exactly: np.log is vectorised, log1p not
    np.log(r, out=r)
    r *= -2.0
    np.sqrt(r, out=r)
    r = r.astype(np.float32)
    a = rng.random(half, dtype=np.float32)
    a *= np.float32(2.0 * np.pi)
    if out is not None and (
        out.shape != shape or out.dtype != np.float32 or not out.flags.c_contiguous
    ):
        raise ValueError(
            f"unit_normals: out must be a C-contiguous float32 array of shape "
            f"{shape}, got {out.dtype} {out.shape}"
        )
    flat = out.reshape(-1) if out is not None and size % 2 == 0 else np.empty(2 * half, np.float32)
    np.cos(a, out=flat[:half])
    np.sin(a, out=flat[half:])
    flat[:half] *= r
    flat[half:] *= r
    if out is None:
        return flat[:size].reshape(shape)
    if size % 2:
        out.reshape(-1)[:] = flat[:size]
    return out


def current_noise(
    rng: np.random.Generator,
    shape,
    current_a,
    dark_a: float,
    circuit_psd: float,
    fs_hz: float,
    dtype=np.float64,
    gain=1.0,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Shot noise of a time-varying current plus white circuit noise, in one Gaussian draw (A).

    Shot: one-sided PSD 2 q I(t), i.e. variance q (I(t) + I_dark) Fs per sample; circuit: one-sided
    PSD S, variance S Fs / 2. Independent Gaussians, so their sum is one Gaussian. For a balanced
    pair pass I1 + I2: the difference of two independent noises has the summed variance. The draw
    always has the full record shape (batch, averages, N), whatever the shape of the current:
    every record gets its own noise. Unit normals come from :func:`unit_normals` (float32: a noise
    sample needs no 53-bit mantissa); the variance is float64, the result ``dtype``, times
    ``gain`` (e.g. a transimpedance in V/A, scalar or broadcastable over the samples). The rf
    tier calls it at the full rate, the baseband tier at the detector output rate with the
    current's slow part. ``out``: an optional C-contiguous array of the record shape and
    ``dtype`` to fill.
    """
    sigma = current_noise_variance(current_a, dark_a, circuit_psd, fs_hz)  # variance ...
    np.maximum(sigma, 0.0, out=sigma)  # (rounding can leave -1e-30 A)
    np.sqrt(sigma, out=sigma)  # ... then its square root, in place
    sigma = sigma * gain
    full = np.broadcast_shapes(tuple(shape), np.shape(sigma))
    if np.dtype(dtype) == np.float32:
        unit = unit_normals(rng, full, out=out)
        unit *= sigma.astype(np.float32) if np.ndim(sigma) else np.float32(sigma)
        return unit
    return np.multiply(unit_normals(rng, full), sigma, dtype=dtype, out=out)
