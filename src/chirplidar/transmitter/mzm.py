"""Mach-Zehnder modulator, thesis eq. 2.4.16: E_out = E_0 cos(pi V / (2 V_pi)).

With the drive V = V_b + A w sin(phi), write alpha = pi V_b / (2 V_pi) and beta = pi A / (2 V_pi).
The Jacobi-Anger expansion gives the closed forms used by the link tier (phase-averaged):

* field fundamental (at the chirp frequency): -2 sin(alpha) J1(beta w) sin(phi)
* mean power transmission: (1 + cos(2 alpha) J0(2 beta w)) / 2
* power fundamental (what direct detection sees): -sin(2 alpha) J1(2 beta w) sin(phi)

At the null bias (alpha = pi/2) the field is odd in the drive, so the optical power is modulated at
twice the chirp frequency while the field carries the chirp itself: the self-chirped homodyne
product of two fields then beats at the difference of the chirps (thesis Sec. 3.1, Fig. 2.10).
"""

from __future__ import annotations

import numpy as np
from scipy.special import j0, j1, jv


def mzm_field(v_v: np.ndarray, v_pi_v: float) -> np.ndarray:
    """Field transmission (real, may be negative) for total drive voltage ``v_v`` (bias included)."""
    return np.cos(0.5 * np.pi * np.asarray(v_v) / v_pi_v)


def mzm_drive_angles(train, bias_v: float, v_pi_v: float) -> tuple[float, float]:
    """(alpha, beta) of the drive V_b + A w sin(phi): pi (V_b + dc) / (2 V_pi), pi A / (2 V_pi)."""
    alpha = 0.5 * np.pi * (bias_v + train.dc_v) / v_pi_v
    beta = 0.5 * np.pi * train.amplitude_v / v_pi_v
    return alpha, beta


def mzm_mean_power_transmission(train, bias_v: float, v_pi_v: float) -> float:
    """Period-averaged <|E_out/E_0|^2> for a chirp or PN train."""
    alpha, beta = mzm_drive_angles(train, bias_v, v_pi_v)
    w = train.envelope_samples()
    if hasattr(train, "chip_rate_hz"):  # +-1 chips: average the two levels
        on = 0.5 * (np.cos(alpha + beta * w) ** 2 + np.cos(alpha - beta * w) ** 2)
        return float(np.mean(on))
    return float(np.mean(0.5 * (1.0 + np.cos(2 * alpha) * j0(2 * beta * w))))


def mzm_peak_power_transmission(train, bias_v: float, v_pi_v: float) -> float:
    """Largest instantaneous |E_out/E_0|^2 = max cos^2(alpha + beta w s) over the drive
    (|s| <= 1, w up to the envelope's largest): 1 when the swing reaches a transmission peak
    (alpha + beta w s a multiple of pi), else the larger end of the swing."""
    alpha, beta = mzm_drive_angles(train, bias_v, v_pi_v)
    swing = abs(beta) * float(np.max(np.abs(train.envelope_samples())))
    lo, hi = alpha - swing, alpha + swing
    if np.floor(hi / np.pi) >= np.ceil(lo / np.pi):  # a multiple of pi inside [lo, hi]
        return 1.0
    return float(max(np.cos(lo) ** 2, np.cos(hi) ** 2))


def mzm_fundamental_field(train, bias_v: float, v_pi_v: float, w: np.ndarray) -> np.ndarray:
    """Amplitude of the field's component at the chirp phase, |2 sin(alpha) J1(beta w)|."""
    alpha, beta = mzm_drive_angles(train, bias_v, v_pi_v)
    return np.abs(2.0 * np.sin(alpha) * j1(beta * np.asarray(w)))


def mzm_power_fundamental(train, bias_v: float, v_pi_v: float, w: np.ndarray) -> np.ndarray:
    """Amplitude of the power's component at the chirp phase, |sin(2 alpha) J1(2 beta w)|."""
    alpha, beta = mzm_drive_angles(train, bias_v, v_pi_v)
    return np.abs(np.sin(2 * alpha) * j1(2 * beta * np.asarray(w)))


def mzm_harmonic_dominates(train, bias_v: float, v_pi_v: float, *, field: bool) -> bool:
    """Whether, at full drive (w = 1), the component at twice the chirp phase outweighs the
    fundamental, so the strongest beat is the harmonic's (at 2 f_R, read as twice the range):
    the field's |2 cos(alpha) J2(beta)| against |2 sin(alpha) J1(beta)| (coherent receivers),
    or the power's |cos(2 alpha) J2(2 beta)| against |sin(2 alpha) J1(2 beta)| (direct
    detection). A bias near the field's peak (alpha ~ 0) or the power's quadrature-free
    points does this."""
    alpha, beta = mzm_drive_angles(train, bias_v, v_pi_v)
    if field:
        fundamental, harmonic = 2 * np.sin(alpha) * j1(beta), 2 * np.cos(alpha) * jv(2, beta)
    else:
        fundamental = np.sin(2 * alpha) * j1(2 * beta)
        harmonic = np.cos(2 * alpha) * jv(2, 2 * beta)
    return bool(abs(harmonic) > abs(fundamental))
